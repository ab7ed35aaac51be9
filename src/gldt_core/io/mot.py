"""MOTChallenge text files: ground truth, detections and tracks.

One line per box, comma separated: ``frame, id, x, y, w, h, score, a, b, c`` with ``frame``
1-based and ``x, y`` the 0-based top-left corner in pixels. Ground truth uses the last three
columns as ``considered, class, visibility``; detections have ``id = -1``. Files with fewer than
ten columns are padded with ``-1`` (MOT16 gt has nine, Halmstad gt has nine) so every reader sees
the same ``(N, 10)`` layout.

Malformed lines raise :class:`MotFormatError`, a ``ValueError`` naming the file and the line, so
a bad file never turns into a silently wrong result.
"""

from __future__ import annotations

import contextlib
import math
import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np

MOT_COLUMNS = 10
MIN_COLUMNS = 6

#: Column indices of the ``(N, 10)`` array returned by :func:`read_mot`.
FRAME, ID, X, Y, W, H, SCORE, COL7, COL8, COL9 = range(MOT_COLUMNS)


class MotFormatError(ValueError):
    """A MOTChallenge file line that cannot be parsed; the message names file and line."""


def parse_mot_lines(lines: Iterable[str], source: str = "<lines>") -> np.ndarray:
    """Parse MOTChallenge lines into an ``(N, 10)`` float64 array (blank lines skipped).

    ``source`` is only used in error messages.
    """
    rows: list[list[float]] = []
    for line_number, raw in enumerate(lines, start=1):
        text = raw.strip()
        if not text or text.startswith("#"):
            continue
        fields = [f.strip() for f in text.replace(" ", ",").split(",") if f.strip() != ""]
        if len(fields) < MIN_COLUMNS:
            raise MotFormatError(
                f"{source}:{line_number}: expected at least {MIN_COLUMNS} comma-separated "
                f"fields (frame,id,x,y,w,h,...), got {len(fields)}: {text!r}"
            )
        try:
            values = [float(f) for f in fields[:MOT_COLUMNS]]
        except ValueError:
            raise MotFormatError(f"{source}:{line_number}: non-numeric field in {text!r}") from None
        if not all(math.isfinite(v) for v in values):
            raise MotFormatError(f"{source}:{line_number}: NaN or infinite value in {text!r}")
        frame = values[FRAME]
        if frame < 1 or frame != int(frame):
            raise MotFormatError(f"{source}:{line_number}: frame must be a 1-based integer, got {fields[0]!r}")
        if values[W] < 0 or values[H] < 0:
            raise MotFormatError(f"{source}:{line_number}: negative box width/height in {text!r}")
        values.extend([-1.0] * (MOT_COLUMNS - len(values)))
        rows.append(values)
    if not rows:
        return np.zeros((0, MOT_COLUMNS), dtype=np.float64)
    return np.asarray(rows, dtype=np.float64)


def read_mot(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a MOTChallenge file into an ``(N, 10)`` float64 array sorted by frame (stable)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"MOT file not found: {path}")
    with path.open("r", encoding="utf-8") as handle:
        table = parse_mot_lines(handle, source=str(path))
    order = np.argsort(table[:, FRAME], kind="stable")
    return table[order]


def format_mot_row(row: np.ndarray | list[float]) -> str:
    """Format one 10-column row; frame and id as integers, coordinates with 2 decimals."""
    frame, track_id, x, y, w, h, score, c7, c8, c9 = (float(v) for v in row)
    return f"{int(frame)},{int(track_id)},{x:.2f},{y:.2f},{w:.2f},{h:.2f},{score:.4g},{c7:.4g},{c8:.4g},{c9:.4g}"


def write_mot(path: str | os.PathLike[str], rows: np.ndarray) -> None:
    """Write an ``(N, >=6)`` array as MOTChallenge lines (missing columns filled with -1).

    The file is written to a temporary name and renamed, so a crash never leaves half a file; when
    writing fails (``OSError``) the temporary file is removed before the error propagates.
    """
    path = Path(path)
    table = np.asarray(rows, dtype=np.float64)
    if table.size == 0:
        table = np.zeros((0, MOT_COLUMNS), dtype=np.float64)
    table = np.atleast_2d(table)
    if table.shape[1] < MIN_COLUMNS:
        raise ValueError(f"write_mot({path}): rows need at least {MIN_COLUMNS} columns, got {table.shape[1]}")
    if table.shape[1] < MOT_COLUMNS:
        pad = np.full((table.shape[0], MOT_COLUMNS - table.shape[1]), -1.0)
        table = np.hstack([table, pad])
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(path.name + ".part")
    try:
        with temporary.open("w", encoding="utf-8") as handle:
            for row in table[:, :MOT_COLUMNS]:
                handle.write(format_mot_row(row) + "\n")
        os.replace(temporary, path)
    except OSError:
        with contextlib.suppress(OSError):
            temporary.unlink()
        raise


def xywh_to_xyxy(boxes: np.ndarray) -> np.ndarray:
    """Convert ``[x, y, w, h]`` (top-left, size) boxes to ``[x1, y1, x2, y2]``."""
    boxes = np.asarray(boxes, dtype=np.float64)
    out = boxes.copy()
    out[..., 2] = boxes[..., 0] + boxes[..., 2]
    out[..., 3] = boxes[..., 1] + boxes[..., 3]
    return out


def xyxy_to_xywh(boxes: np.ndarray) -> np.ndarray:
    """Convert ``[x1, y1, x2, y2]`` boxes to ``[x, y, w, h]`` (top-left, size)."""
    boxes = np.asarray(boxes, dtype=np.float64)
    out = boxes.copy()
    out[..., 2] = boxes[..., 2] - boxes[..., 0]
    out[..., 3] = boxes[..., 3] - boxes[..., 1]
    return out
