"""Box formulas shared by the trackers (corners and centres, IoU) and their input checks.

Each formula is written once, on operands that may be Python floats or numpy arrays (see
:mod:`gldt_core.track.fastpath`): :func:`corners`, :func:`midpoint`, :func:`centre_size` and
:func:`relative_centre` use only arithmetic, :func:`iou` also the ``minimum``/``maximum``/``where``
of an ops namespace.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from gldt_core.track.fastpath import ARRAYS, FLOATS, Ops, V, on_floats


def corners(cx: V, cy: V, w: V, h: V) -> tuple[V, V, V, V]:
    """``[cx, cy, w, h]`` -> ``(x1, y1, x2, y2)``."""
    half_w = 0.5 * w
    half_h = 0.5 * h
    return cx - half_w, cy - half_h, cx + half_w, cy + half_h


def midpoint(a: V, b: V) -> V:
    """Half way from ``a`` to ``b`` (coordinates, or arrays of points such as ``(N, 2)`` corners)."""
    return (a + b) * 0.5


def centre_size(x1: V, y1: V, x2: V, y2: V) -> tuple[V, V, V, V]:
    """``[x1, y1, x2, y2]`` -> ``(cx, cy, w, h)``."""
    return midpoint(x1, x2), midpoint(y1, y2), x2 - x1, y2 - y1


def relative_centre(
    x1: V, y1: V, x2: V, y2: V, x0: V | float, y0: V | float, w: V | float, h: V | float
) -> tuple[V, V]:
    """Centre of box ``x1..y2`` in the coordinates of a window with top-left corner ``(x0, y0)`` and
    size ``w x h``: (0, 0) at that corner, (1, 1) at the opposite one."""
    cx, cy, _, _ = centre_size(x1, y1, x2, y2)
    return (cx - x0) / w, (cy - y0) / h


def iou(ops: Ops[V], ax1: V, ay1: V, ax2: V, ay2: V, bx1: V, by1: V, bx2: V, by2: V) -> V:
    """Intersection over union of boxes ``a`` and ``b`` (0 when the union is empty)."""
    iw = ops.minimum(ax2, bx2) - ops.maximum(ax1, bx1)
    ih = ops.minimum(ay2, by2) - ops.maximum(ay1, by1)
    inter = ops.maximum(iw, 0.0) * ops.maximum(ih, 0.0)
    union = (ax2 - ax1) * (ay2 - ay1) + (bx2 - bx1) * (by2 - by1) - inter
    return ops.where(union > 0, inter / ops.maximum(union, 1e-12), 0.0)


def iou_xyxy(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU matrix ``(len(a), len(b))`` of ``[x1, y1, x2, y2]`` boxes."""
    if len(a) == 0 or len(b) == 0:
        return np.zeros((len(a), len(b)))
    if on_floats(len(a) * len(b)):
        rows_b = np.asarray(b).tolist()
        return np.array([[iou(FLOATS, *box_a, *box_b) for box_b in rows_b] for box_a in np.asarray(a).tolist()])
    return iou(ARRAYS, a[:, 0, None], a[:, 1, None], a[:, 2, None], a[:, 3, None], b[:, 0], b[:, 1], b[:, 2], b[:, 3])


def iou_pairs_above(
    a: np.ndarray | Sequence[Sequence[float]], b: np.ndarray | Sequence[Sequence[float]], thresh: float
) -> list[tuple[int, int]]:
    """Index pairs ``(i, j)`` with ``IoU(a[i], b[j]) > thresh``, row-major order (boxes as arrays
    or as rows of Python floats)."""
    if on_floats(len(a) * len(b)):
        rows_a = a.tolist() if isinstance(a, np.ndarray) else a
        rows_b = b.tolist() if isinstance(b, np.ndarray) else b
        return [
            (i, j)
            for i, box_a in enumerate(rows_a)
            for j, box_b in enumerate(rows_b)
            if iou(FLOATS, *box_a, *box_b) > thresh
        ]
    above = iou_xyxy(np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)) > thresh
    return [(int(i), int(j)) for i, j in zip(*np.nonzero(above))]


_FIELDS = ("x1", "y1", "x2", "y2", "score")


def _where(t: float, frame: int | None) -> str:
    return f"frame {frame}" if frame is not None else f"t={t:.6f} s"


def validate_time(t: float, last_t: float | None, frame: int | None) -> float:
    """Check the timestamp is finite and strictly after the previous one."""
    try:
        t = float(t)
    except (TypeError, ValueError):
        raise ValueError(f"{_where(0.0, frame)}: timestamp t={t!r} is not a number") from None
    if not math.isfinite(t):
        raise ValueError(f"{_where(t, frame)}: timestamp t is NaN or infinite")
    if last_t is not None and t <= last_t:
        what = "repeated" if t == last_t else "went backwards"
        raise ValueError(
            f"{_where(t, frame)}: field t: time {what} (t={t:.6f} s after t={last_t:.6f} s); "
            "frames must arrive in order with increasing timestamps"
        )
    return t


def is_valid_detection(x1: V, y1: V, x2: V, y2: V, score: V) -> V | bool:
    """A finite box of positive size with a score in [0, 1] (NaN fails every comparison)."""
    return (
        (-math.inf < x1)
        & (x1 < x2)
        & (x2 < math.inf)
        & (-math.inf < y1)
        & (y1 < y2)
        & (y2 < math.inf)
        & (0.0 <= score)
        & (score <= 1.0)
    )


def validate_detections(dets: np.ndarray | None, t: float, frame: int | None) -> np.ndarray:
    """Return ``dets`` as an ``(N, 5)`` float64 array or raise a ValueError naming frame and field.

    ``None`` or an empty array is an empty frame (valid: tracks coast on their prediction).
    """
    if dets is None:
        return np.zeros((0, 5))
    arr = np.asarray(dets, dtype=np.float64)
    if arr.size == 0:
        return np.zeros((0, 5))
    if arr.ndim != 2 or arr.shape[1] != 5:
        raise ValueError(
            f"{_where(t, frame)}: detections must be an (N, 5) array [x1, y1, x2, y2, score], got shape {arr.shape}"
        )
    if on_floats(len(arr)):
        valid = all(is_valid_detection(*row) for row in arr.tolist())
    else:
        valid = bool(np.all(is_valid_detection(arr[:, 0], arr[:, 1], arr[:, 2], arr[:, 3], arr[:, 4])))
    if not valid:
        raise ValueError(f"{_where(t, frame)}: {_first_problem(arr)}")
    return arr


def _first_problem(arr: np.ndarray) -> str:
    """What is wrong with an invalid detection array: the first non-finite value, else the first
    box of non-positive size, else the first score outside [0, 1]."""
    finite = np.isfinite(arr)
    if not finite.all():
        row, col = np.argwhere(~finite)[0]
        return f"detection {row} field {_FIELDS[col]} is NaN or infinite"
    bad_w = arr[:, 2] <= arr[:, 0]
    bad_h = arr[:, 3] <= arr[:, 1]
    if bad_w.any() or bad_h.any():
        row = int(np.flatnonzero(bad_w | bad_h)[0])
        field = "x2" if bad_w[row] else "y2"
        return f"detection {row} field {field}: box has non-positive size ({arr[row, :4].tolist()})"
    row = int(np.flatnonzero((arr[:, 4] < 0.0) | (arr[:, 4] > 1.0))[0])
    return f"detection {row} field score={arr[row, 4]:g} is outside [0, 1]"
