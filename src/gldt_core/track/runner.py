"""Run a tracker over a MOTChallenge detection table (used by ``gldt track`` and the benchmark)."""

from __future__ import annotations

import inspect
import time
from typing import Protocol

import numpy as np


class FrameTracker(Protocol):
    def update(self, dets: np.ndarray, t: float) -> np.ndarray: ...


def track_detection_rows(
    tracker: FrameTracker,
    det_rows: np.ndarray,
    fps: float,
    num_frames: int | None = None,
    timings: list[float] | None = None,
) -> np.ndarray:
    """Feed MOT det rows ``(N, >=7)`` frame by frame (``t = (frame - 1) / fps``) and return MOT
    track rows ``frame, id, x, y, w, h, score, -1, -1, -1``.

    Every frame from 1 to the last one is an update, including frames without detections, so
    tracks coast through gaps with the right elapsed time. Once one empty frame has been fed to a
    tracker that holds no track at all (``tracker.tracks`` empty), the rest of the gap is skipped:
    updating it with nothing again changes nothing (the one empty update also ends any low-score
    birth chain, :mod:`gldt_core.track.birth`). Time and memory therefore follow the rows, not the largest frame number.
    Per-update wall times (seconds) are appended to ``timings`` when given.
    """
    if not np.isfinite(fps) or fps <= 0:
        raise ValueError(f"fps must be a positive number, got {fps}")
    rows = np.asarray(det_rows, dtype=np.float64).reshape(-1, det_rows.shape[1] if det_rows.size else 10)
    frames = rows[:, 0].astype(np.int64)
    order = np.argsort(frames, kind="stable")
    rows, frames = rows[order], frames[order]
    last = int(frames.max(initial=0))
    if num_frames is None:
        num_frames = last
    with_rows, first_row = np.unique(frames, return_index=True)
    row_end = np.append(first_row[1:], len(rows))
    try:
        accepts_frame = "frame" in inspect.signature(tracker.update).parameters
    except (TypeError, ValueError):
        accepts_frame = False
    out: list[np.ndarray] = []
    f, next_block, previous_empty = 1, 0, False
    while f <= num_frames:
        while next_block < len(with_rows) and with_rows[next_block] < f:
            next_block += 1
        if next_block < len(with_rows) and with_rows[next_block] == f:
            block = rows[first_row[next_block] : row_end[next_block]]
        else:
            block = rows[:0]
            if previous_empty and not getattr(tracker, "tracks", True):  # nothing to coast: jump the gap
                f = int(with_rows[next_block]) if next_block < len(with_rows) else num_frames + 1
                continue
        previous_empty = len(block) == 0
        dets = np.empty((len(block), 5))
        dets[:, 0] = block[:, 2]
        dets[:, 1] = block[:, 3]
        dets[:, 2] = block[:, 2] + block[:, 4]
        dets[:, 3] = block[:, 3] + block[:, 5]
        dets[:, 4] = block[:, 6]
        start = time.perf_counter()
        if accepts_frame:
            result = tracker.update(dets, (f - 1) / fps, frame=f)  # type: ignore[call-arg]
        else:
            result = tracker.update(dets, (f - 1) / fps)
        if timings is not None:
            timings.append(time.perf_counter() - start)
        if len(result):
            table = np.full((len(result), 10), -1.0)
            table[:, 0] = f
            table[:, 1] = result[:, 4]
            table[:, 2] = result[:, 0]
            table[:, 3] = result[:, 1]
            table[:, 4] = result[:, 2] - result[:, 0]
            table[:, 5] = result[:, 3] - result[:, 1]
            table[:, 6] = result[:, 5]
            out.append(table)
        f += 1
    return np.vstack(out) if out else np.zeros((0, 10))
