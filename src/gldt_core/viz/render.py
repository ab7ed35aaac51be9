"""Overlay video and run plot for ``gldt run --render`` / ``--plot``.

The video is written to a temporary name and renamed when closed, so an interrupted run never
leaves a truncated file under the requested name.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from gldt_core.viz.overlay import draw_overlay

if TYPE_CHECKING:
    import cv2


class OverlayVideoWriter:
    """MP4 writer that opens on the first frame; later frames of another size are resized to it."""

    def __init__(self, path: str | os.PathLike[str], fps: float) -> None:
        self.path = Path(path)
        if self.path.suffix.lower() not in (".mp4", ".avi", ".mkv"):
            raise ValueError(f"--render: output must end in .mp4, .avi or .mkv, got {self.path.name}")
        self.fps = float(fps) if fps and fps > 0 else 30.0
        self._temporary = self.path.with_name(self.path.stem + ".part" + self.path.suffix)
        self._writer: cv2.VideoWriter | None = None
        self._size: tuple[int, int] | None = None

    def write(self, frame: np.ndarray, tracks: np.ndarray, mode: str, rois: np.ndarray, index: int) -> None:
        import cv2

        image = draw_overlay(frame, tracks, mode, rois, frame_index=index)
        if self._writer is None or self._size is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._size = (image.shape[1], image.shape[0])
            fourcc = cv2.VideoWriter.fourcc(*("mp4v" if self.path.suffix.lower() == ".mp4" else "MJPG"))
            self._writer = cv2.VideoWriter(str(self._temporary), fourcc, self.fps, self._size)
            if not self._writer.isOpened():
                raise ValueError(f"--render: cannot open a video writer for {self.path}")
        if (image.shape[1], image.shape[0]) != self._size:
            image = cv2.resize(image, self._size, interpolation=cv2.INTER_AREA)
        self._writer.write(image)

    def close(self, keep: bool = True) -> None:
        """Finish the file (``keep``) or throw the partial one away."""
        if self._writer is not None:
            self._writer.release()
            self._writer = None
        if self._temporary.exists():
            if keep:
                os.replace(self._temporary, self.path)
            else:
                self._temporary.unlink()


def save_run_plot(path: str | os.PathLike[str], modes: np.ndarray, rows: np.ndarray, frames: int, title: str) -> None:
    """Two-panel PNG: detector mode per frame and the number of tracks per frame."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    counts = np.bincount(rows[:, 0].astype(np.int64) - 1, minlength=frames)[:frames] if len(rows) else np.zeros(frames)
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(10, 4), sharex=True)
    top.fill_between(np.arange(frames), np.asarray(modes, dtype=float), step="mid", color="tab:orange")
    top.set_yticks([0, 1], ["LD", "GD"])
    top.set_title(title)
    bottom.step(np.arange(frames), counts, where="mid", color="tab:blue")
    bottom.set_ylabel("tracks")
    bottom.set_xlabel("frame")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(path.stem + ".part" + path.suffix)
    fig.savefig(temporary, dpi=100)
    plt.close(fig)
    os.replace(temporary, path)
