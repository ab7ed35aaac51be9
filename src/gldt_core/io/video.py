"""A video file with a MOTChallenge ground-truth file (the Halmstad clips: videos/X.mp4 + gt/X.txt)."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from gldt_core.io.frame import Frame, FrameSource, empty_ground_truth, rows_by_frame

VIDEO_EXTENSIONS = (".mp4", ".avi", ".mkv", ".mov", ".m4v", ".webm")


def default_gt_path(video: Path) -> Path | None:
    """``../gt/<stem>.txt`` (Halmstad layout) or ``<stem>.txt`` beside the video, if present."""
    for candidate in (video.parent.parent / "gt" / f"{video.stem}.txt", video.with_suffix(".txt")):
        if candidate.is_file():
            return candidate
    return None


class VideoSource(FrameSource):
    """Decoded frames of a video; frame k of the gt is the k-th decoded frame (1-based).

    A gt that refers to frames the video does not have is an error (checked against the
    container's frame count up front, and against the decoded count at the end).
    """

    def __init__(self, path: str | os.PathLike[str], gt: str | os.PathLike[str] | None = None) -> None:
        import cv2

        from gldt_core.io.mot import read_mot

        self.path = Path(path)
        if not self.path.is_file():
            raise FileNotFoundError(f"video not found: {self.path}")
        self.name = self.path.stem
        capture = cv2.VideoCapture(str(self.path))
        try:
            if not capture.isOpened():
                raise ValueError(f"cannot open video {self.path}")
            self.fps = float(capture.get(cv2.CAP_PROP_FPS)) or 30.0
            self.size = (int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT)))
            self._count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
        finally:
            capture.release()
        gt_path = Path(gt) if gt is not None else default_gt_path(self.path)
        if gt_path is not None and not gt_path.is_file():
            raise FileNotFoundError(f"ground-truth file not found: {gt_path}")
        self.gt_path = gt_path
        self._gt = read_mot(gt_path) if gt_path is not None else empty_ground_truth()
        if len(self._gt) and self._count > 0 and self._gt[:, 0].max() > self._count:
            raise ValueError(
                f"{gt_path}: ground truth reaches frame {int(self._gt[:, 0].max())} but video "
                f"{self.path.name} has {self._count} frames"
            )
        self._by_frame = rows_by_frame(self._gt)

    def __len__(self) -> int:
        return self._count

    @property
    def ground_truth(self) -> np.ndarray:
        return self._gt

    def __iter__(self) -> Iterator[Frame]:
        import cv2

        capture = cv2.VideoCapture(str(self.path))
        index = 0
        try:
            while True:
                ok, image = capture.read()
                if not ok:
                    break
                yield Frame(index, index / self.fps, image, self._by_frame.get(index, empty_ground_truth()))
                index += 1
        finally:
            capture.release()
        if len(self._gt) and self._gt[:, 0].max() > index:
            raise ValueError(
                f"{self.gt_path}: ground truth reaches frame {int(self._gt[:, 0].max())} but only "
                f"{index} frames could be decoded from {self.path.name}"
            )
