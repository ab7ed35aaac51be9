"""Run a detector over every frame of a video and collect MOTChallenge detection rows.

Shared by ``gldt detect`` and ``gldt bench detection`` (:func:`frame_detections`) so both produce
exactly the same boxes. The global detector sees each frame with its predecessor (the first frame
is paired with itself). The local detector has no tracker to place ROIs here, so it covers the
frame with overlapping ``roi x roi`` tiles (one batch per frame) and merges tile seams with NMS.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from gldt_core.detect.global_detector import GlobalDetector
from gldt_core.detect.local_detector import LocalDetector


def iter_video_frames(path: Path | str) -> Iterator[np.ndarray]:
    """Decoded BGR frames of a video; FileNotFoundError / ValueError when it cannot be read."""
    import cv2

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"video not found: {path}")
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise ValueError(f"cannot open video {path} (not a video OpenCV can decode)")
    try:
        count = 0
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            count += 1
            yield frame
        if count == 0:
            raise ValueError(f"video {path} has no decodable frames")
    finally:
        cap.release()


def frame_detections(
    detector: GlobalDetector | LocalDetector, previous: np.ndarray | None, frame: np.ndarray, roi_side: int = 300
) -> np.ndarray:
    """``(N, 9)`` ``[x1, y1, x2, y2, score, class_id, p_drone, p_bird, p_airplane]`` of one frame:
    the global detector on the pair ``(previous, frame)`` (None: the frame with itself), the local
    one on ``roi_side`` tiles covering the frame, tile seams merged by NMS."""
    if isinstance(detector, GlobalDetector):
        return detector.detect(previous, frame)
    return detector.detect_tiles(frame, previous, roi_side)


def detect_frames(
    frames: Iterator[np.ndarray],
    detector: GlobalDetector | LocalDetector,
    roi_side: int = 300,
    on_frame: Callable[[int, np.ndarray], None] | None = None,
) -> np.ndarray:
    """MOT rows ``frame, -1, x, y, w, h, score, class_id, -1, -1`` (frame 1-based) for all frames."""
    if not isinstance(detector, GlobalDetector | LocalDetector):
        raise TypeError(f"detector must be a GlobalDetector or a LocalDetector, got {type(detector).__name__}")
    rows: list[np.ndarray] = []
    previous = None
    for index, frame in enumerate(frames, start=1):
        dets = frame_detections(detector, previous, frame, roi_side)
        previous = frame
        if on_frame is not None:
            on_frame(index, dets)
        if len(dets):
            out = np.full((len(dets), 10), -1.0)
            out[:, 0] = index
            out[:, 2:4] = dets[:, :2]
            out[:, 4:6] = dets[:, 2:4] - dets[:, :2]
            out[:, 6] = dets[:, 4]
            out[:, 7] = dets[:, 5]
            rows.append(out)
    return np.concatenate(rows) if rows else np.zeros((0, 10))
