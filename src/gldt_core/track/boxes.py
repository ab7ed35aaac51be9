"""Box helpers shared by the trackers: vectorised IoU, centres and input validation."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


def iou_xyxy(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU matrix ``(len(a), len(b))`` of ``[x1, y1, x2, y2]`` boxes."""
    if len(a) == 0 or len(b) == 0:
        return np.zeros((len(a), len(b)))
    # np.maximum(x, 0) rather than np.clip: same values, a fraction of clip's call overhead (these
    # matrices hold a few elements, so call overhead, not arithmetic, is the cost).
    ax1, ay1, ax2, ay2 = a[:, 0, None], a[:, 1, None], a[:, 2, None], a[:, 3, None]
    iw = np.minimum(ax2, b[:, 2]) - np.maximum(ax1, b[:, 0])
    ih = np.minimum(ay2, b[:, 3]) - np.maximum(ay1, b[:, 1])
    inter = np.maximum(iw, 0.0) * np.maximum(ih, 0.0)
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    union = area_a[:, None] + area_b[None, :] - inter
    return np.where(union > 0, inter / np.maximum(union, 1e-12), 0.0)


#: Up to this many box pairs, :func:`iou_pairs_above` loops in Python (cheaper than ~20 numpy calls).
SCALAR_IOU_PAIRS = 64


def iou_pairs_above(a: np.ndarray, b: np.ndarray, thresh: float) -> list[tuple[int, int]]:
    """Index pairs ``(i, j)`` with ``IoU(a[i], b[j]) > thresh``, row-major order.

    For a few pairs (duplicate removal at a handful of targets) the IoU is evaluated with Python
    floats: the same IEEE operations in the same order as :func:`iou_xyxy`, so the same values and
    decisions, without numpy's per-call overhead on 2x3 matrices.
    """
    if len(a) * len(b) > SCALAR_IOU_PAIRS:
        return [(int(i), int(j)) for i, j in zip(*np.nonzero(iou_xyxy(a, b) > thresh))]
    return iou_row_pairs_above(np.asarray(a).tolist(), np.asarray(b).tolist(), thresh)


def iou_row_pairs_above(
    a: Sequence[Sequence[float]], b: Sequence[Sequence[float]], thresh: float
) -> list[tuple[int, int]]:
    """:func:`iou_pairs_above` for boxes given as rows of Python floats (no array round trip).

    ``min``/``max`` are conditional expressions (same values for finite boxes, no builtin call),
    and with ``thresh >= 0`` a pair that does not overlap (IoU 0) is rejected before dividing."""
    out = []
    skip_disjoint = thresh >= 0.0
    b_rows = [(x1, y1, x2, y2, (x2 - x1) * (y2 - y1)) for x1, y1, x2, y2 in b]
    for i, (ax1, ay1, ax2, ay2) in enumerate(a):
        area_a = (ax2 - ax1) * (ay2 - ay1)
        for j, (bx1, by1, bx2, by2, area_b) in enumerate(b_rows):
            iw = (ax2 if ax2 < bx2 else bx2) - (ax1 if ax1 > bx1 else bx1)
            ih = (ay2 if ay2 < by2 else by2) - (ay1 if ay1 > by1 else by1)
            if skip_disjoint and (iw <= 0.0 or ih <= 0.0):
                continue
            inter = (iw if iw > 0.0 else 0.0) * (ih if ih > 0.0 else 0.0)
            union = area_a + area_b - inter
            if union > 0 and inter / (union if union > 1e-12 else 1e-12) > thresh:
                out.append((i, j))
    return out


def xyxy_to_cxcywh(boxes: np.ndarray) -> np.ndarray:
    """``[x1, y1, x2, y2]`` -> ``[cx, cy, w, h]`` (any leading shape)."""
    out = np.empty_like(boxes, dtype=np.float64)
    out[..., 0] = (boxes[..., 0] + boxes[..., 2]) * 0.5
    out[..., 1] = (boxes[..., 1] + boxes[..., 3]) * 0.5
    out[..., 2] = boxes[..., 2] - boxes[..., 0]
    out[..., 3] = boxes[..., 3] - boxes[..., 1]
    return out


def cxcywh_to_xyxy(boxes: np.ndarray) -> np.ndarray:
    """``[cx, cy, w, h]`` -> ``[x1, y1, x2, y2]`` (any leading shape)."""
    out = np.empty_like(boxes, dtype=np.float64)
    out[..., 0] = boxes[..., 0] - boxes[..., 2] * 0.5
    out[..., 1] = boxes[..., 1] - boxes[..., 3] * 0.5
    out[..., 2] = boxes[..., 0] + boxes[..., 2] * 0.5
    out[..., 3] = boxes[..., 1] + boxes[..., 3] * 0.5
    return out


_FIELDS = ("x1", "y1", "x2", "y2", "score")
#: Up to this many detections :func:`validate_detections` checks on Python floats first.
SMALL_VALIDATE_ROWS = 32


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
    if len(arr) <= SMALL_VALIDATE_ROWS and all(
        -math.inf < x1 < x2 < math.inf and -math.inf < y1 < y2 < math.inf and 0.0 <= s <= 1.0
        for x1, y1, x2, y2, s in arr.tolist()
    ):
        # The checks below on Python floats in one pass (a few detections: cheaper than ~10 numpy
        # calls). Passing them implies every check below passes; a failure falls through to them
        # so the error names the first bad detection and field exactly as before.
        return arr
    finite = np.isfinite(arr)
    if not finite.all():
        row, col = np.argwhere(~finite)[0]
        raise ValueError(f"{_where(t, frame)}: detection {row} field {_FIELDS[col]} is NaN or infinite")
    bad_w = arr[:, 2] <= arr[:, 0]
    bad_h = arr[:, 3] <= arr[:, 1]
    if bad_w.any() or bad_h.any():
        row = int(np.flatnonzero(bad_w | bad_h)[0])
        field = "x2" if bad_w[row] else "y2"
        raise ValueError(
            f"{_where(t, frame)}: detection {row} field {field}: box has non-positive size ({arr[row, :4].tolist()})"
        )
    bad_s = (arr[:, 4] < 0.0) | (arr[:, 4] > 1.0)
    if bad_s.any():
        row = int(np.flatnonzero(bad_s)[0])
        raise ValueError(f"{_where(t, frame)}: detection {row} field score={arr[row, 4]:g} is outside [0, 1]")
    return arr
