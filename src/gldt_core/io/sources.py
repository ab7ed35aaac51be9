"""One way to read frames with timestamps and ground truth from every kind of source.

:func:`open_source` takes a MOTChallenge folder (``img1/``, ``gt/gt.txt``, ``seqinfo.ini``), a
plain folder of images (frames in name order), a video file with a MOT gt file (Halmstad clips:
``videos/X.mp4`` finds ``gt/X.txt``), a rosbag2 folder or ``.mcap`` file, or
``synth:seed=N,frames=K``; each returns a :class:`FrameSource` yielding :class:`Frame` objects
the same way. A frame that cannot be read is skipped with a warning (its number stays unused, so
the tracker coasts over it); ``source.lost_frames`` counts them once the source was read.
"""

from __future__ import annotations

import os
from pathlib import Path

from gldt_core.io.frame import Frame, FrameSource, empty_ground_truth

__all__ = ["Frame", "FrameSource", "empty_ground_truth", "open_source", "source_kind"]


def source_kind(path: str | os.PathLike[str]) -> str:
    """``mot``, ``images`` (a plain folder of images), ``video``, ``bag`` or ``synth`` for a path;
    ValueError when it is none of them."""
    from gldt_core.io.video import VIDEO_EXTENSIONS

    text = str(path)
    if text.startswith("synth:"):
        return "synth"
    candidate = Path(text)
    if not candidate.exists():
        raise FileNotFoundError(f"source not found: {candidate}")
    if candidate.is_dir():
        if (candidate / "metadata.yaml").is_file():
            return "bag"
        if (candidate / "seqinfo.ini").is_file() or (candidate / "img1").is_dir():
            return "mot"
        from gldt_core.io.mot_folder import image_files

        if image_files(candidate):
            return "images"
        raise ValueError(
            f"{candidate}: neither a MOT folder (img1/, seqinfo.ini), a folder of images (jpg, png, bmp) "
            "nor a bag (metadata.yaml)"
        )
    if candidate.suffix.lower() == ".mcap":
        return "bag"
    if candidate.suffix.lower() in VIDEO_EXTENSIONS:
        return "video"
    raise ValueError(f"{candidate}: unknown source type (expected a video, a MOT folder or a bag)")


def open_source(path: str | os.PathLike[str], gt: str | os.PathLike[str] | None = None) -> FrameSource:
    """Open any supported source; ``gt`` overrides the ground-truth file (video and MOT folders)."""
    kind = source_kind(path)
    if kind == "synth":
        from gldt_core.io.synth_source import SynthSource, parse_synth_uri

        return SynthSource(parse_synth_uri(str(path)))
    if gt is not None and kind == "bag":
        raise ValueError("a bag carries its own ground truth; --gt applies to videos and MOT folders")
    if kind == "bag":
        from gldt_core.io.bag import BagSource

        return BagSource(path)
    if kind in ("mot", "images"):
        from gldt_core.io.mot_folder import MotFolderSource

        return MotFolderSource(path, gt)
    from gldt_core.io.video import VideoSource

    return VideoSource(path, gt)
