"""A video file with a MOTChallenge ground-truth file (the Halmstad clips: videos/X.mp4 + gt/X.txt)."""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from gldt_core.io.frame import Frame, FrameSource, empty_ground_truth, rows_by_frame

VIDEO_EXTENSIONS = (".mp4", ".avi", ".mkv", ".mov", ".m4v", ".webm")

#: Reads in a row that may fail before a video counts as ended early (a damaged stretch longer
#: than this ends the read; the frames short of the declared count are then reported lost).
MAX_CONSECUTIVE_FAILURES = 25

_log = logging.getLogger(__name__)


def default_gt_path(video: Path) -> Path | None:
    """``../gt/<stem>.txt`` (Halmstad layout) or ``<stem>.txt`` beside the video, if present."""
    for candidate in (video.parent.parent / "gt" / f"{video.stem}.txt", video.with_suffix(".txt")):
        if candidate.is_file():
            return candidate
    return None


class VideoSource(FrameSource):
    """Decoded frames of a video; frame k of the gt is the k-th frame of the container (1-based).

    A gt that refers to frames beyond the container's frame count is an error (checked up front).
    Damage does not end the run quietly: a frame that fails to decode is skipped and reading goes
    on (``VideoCapture.read`` failing once does not mean the end while the container declares more
    frames; up to :data:`MAX_CONSECUTIVE_FAILURES` reads in a row are tried), the skipped frame
    keeps its number so the tracker coasts over it, and once the video is read
    :attr:`lost_frames` counts the frames skipped or missing at the end (short of the declared
    frame count or of the ground truth's last frame), reported in one warning line.
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
            self._count = max(int(capture.get(cv2.CAP_PROP_FRAME_COUNT)), 0)
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
        self.lost_frames = 0

    def __len__(self) -> int:
        return self._count

    @property
    def ground_truth(self) -> np.ndarray:
        return self._gt

    def __iter__(self) -> Iterator[Frame]:
        import cv2

        self.lost_frames = 0
        capture = cv2.VideoCapture(str(self.path))
        index = 0  # the container's frame number (0-based) of the next read
        skipped: list[int] = []  # frames that failed to decode with readable frames after them
        failures: list[int] = []  # the failed reads since the last frame that decoded
        try:
            while True:
                ok, image = capture.read()
                if ok and image is not None:
                    skipped.extend(failures)
                    failures = []
                    yield Frame(index, index / self.fps, image, self._by_frame.get(index, empty_ground_truth()))
                else:
                    failures.append(index)
                    declared_more = self._count <= 0 or index + 1 < self._count
                    if not declared_more or len(failures) >= MAX_CONSECUTIVE_FAILURES:
                        break
                index += 1
        finally:
            capture.release()
        decoded_end = failures[0] if failures else index  # one past the last frame slot read
        expected = max(self._count, int(self._gt[:, 0].max()) if len(self._gt) else 0)
        missing_at_end = max(0, expected - decoded_end)
        self.lost_frames = len(skipped) + missing_at_end
        if self.lost_frames:
            parts = []
            if skipped:
                shown = ", ".join(str(k + 1) for k in skipped[:5]) + (", ..." if len(skipped) > 5 else "")
                were = "was" if len(skipped) == 1 else "were"
                parts.append(f"{len(skipped)} failed to decode and {were} skipped (frame {shown})")
            if missing_at_end:
                parts.append(
                    f"the video ended after frame {decoded_end} of {expected}"
                    + (" declared" if expected == self._count else " the ground truth names")
                )
            _log.warning(
                "%s: %d of %d frames could not be read: %s",
                self.path.name,
                self.lost_frames,
                max(expected, decoded_end),
                "; ".join(parts),
            )
