"""The one frame type every source yields, and the interface all frame sources share."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np


def empty_ground_truth() -> np.ndarray:
    """A (0, 10) MOT table: a frame with no labelled object."""
    return np.zeros((0, 10), dtype=np.float64)


@dataclass
class Frame:
    """One camera frame with its timestamp and ground truth.

    ``index`` is 0-based (MOT frame number minus one); ``stamp`` is seconds since the start of the
    sequence (or the bag's header stamp); ``image`` is HxWx3 uint8 BGR; ``ground_truth`` holds the
    MOT rows (K, 10) of this frame, possibly empty.
    """

    index: int
    stamp: float
    image: np.ndarray
    ground_truth: np.ndarray = field(default_factory=empty_ground_truth)


class FrameSource(ABC):
    """Frames from a MOT folder, a video + gt file, a bag or a synthetic scene, all alike.

    ``fps`` and ``size`` (width, height) are known up front; ``len()`` is the frame count
    (sources that cannot know it raise ``TypeError`` like any unsized object);
    ``camera_matrix`` is a 3x3 K when the source has one (bags, synthetic scenes).
    """

    fps: float
    size: tuple[int, int]
    camera_matrix: np.ndarray | None = None
    name: str = ""
    #: Frames the last pass could not read (skipped with a warning, or missing at the end of a
    #: video that declared more); sources that can lose frames update it while they are read.
    lost_frames: int = 0

    @abstractmethod
    def __iter__(self) -> Iterator[Frame]:
        """Yield the frames in order."""

    @abstractmethod
    def __len__(self) -> int:
        """Number of frames."""

    @property
    @abstractmethod
    def ground_truth(self) -> np.ndarray:
        """All MOT rows (N, 10) of the sequence, sorted by frame."""

    def close(self) -> None:
        """Release files or decoders; a source that holds none keeps this default, which does nothing."""
        return None

    def __enter__(self) -> FrameSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def rows_by_frame(rows: np.ndarray) -> dict[int, np.ndarray]:
    """Group MOT rows by 0-based frame index."""
    groups: dict[int, np.ndarray] = {}
    if len(rows) == 0:
        return groups
    frames = rows[:, 0].astype(int) - 1
    order = np.argsort(frames, kind="stable")
    sorted_rows, sorted_frames = rows[order], frames[order]
    boundaries = np.flatnonzero(np.diff(sorted_frames)) + 1
    for chunk, frame_rows in zip(np.split(sorted_frames, boundaries), np.split(sorted_rows, boundaries)):
        groups[int(chunk[0])] = frame_rows
    return groups
