"""A MOTChallenge sequence folder (``img1/`` frames, ``gt/gt.txt`` and ``seqinfo.ini``) or a plain
folder of images (``.jpg``/``.jpeg``/``.png``/``.bmp``, frames in the order of their names).

An image that cannot be read is skipped with one warning line naming the file: the frame keeps its
number and time, so the tracker coasts over the gap, and :attr:`MotFolderSource.lost_frames`
counts the skipped frames for the caller's summary.
"""

from __future__ import annotations

import configparser
import logging
import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from gldt_core.io.frame import Frame, FrameSource, empty_ground_truth, rows_by_frame

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".bmp")

_log = logging.getLogger(__name__)


def image_files(folder: Path, extensions: tuple[str, ...] = IMAGE_EXTENSIONS) -> list[Path]:
    """The image files directly in ``folder`` with one of ``extensions``, sorted by name."""
    wanted = tuple(e.lower() for e in extensions)
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in wanted and p.is_file())


class _CaseKeepingParser(configparser.ConfigParser):
    """A ``ConfigParser`` that keeps keys as written (``seqinfo.ini`` keys are camelCase)."""

    def optionxform(self, optionstr: str) -> str:
        return optionstr


def read_seqinfo(path: Path) -> dict[str, str]:
    """The ``[Sequence]`` section of a ``seqinfo.ini`` (empty when the file is absent)."""
    if not path.is_file():
        return {}
    parser = _CaseKeepingParser()
    try:
        parser.read(path, encoding="utf-8")
    except configparser.Error as error:
        raise ValueError(f"{path}: not a valid seqinfo.ini ({error})") from None
    if "Sequence" not in parser:
        raise ValueError(f"{path}: no [Sequence] section")
    return dict(parser["Sequence"])


def write_seqinfo(
    path: Path,
    name: str,
    fps: float,
    length: int,
    size: tuple[int, int],
    image_dir: str = "img1",
    image_ext: str = ".jpg",
) -> None:
    """Write a MOTChallenge ``seqinfo.ini``."""
    fps_text = f"{fps:g}"
    text = (
        "[Sequence]\n"
        f"name={name}\nimDir={image_dir}\nframeRate={fps_text}\nseqLength={length}\n"
        f"imWidth={size[0]}\nimHeight={size[1]}\nimExt={image_ext}\n"
    )
    temporary = path.with_name(path.name + ".part")
    temporary.write_text(text, encoding="utf-8")
    os.replace(temporary, path)


class MotFolderSource(FrameSource):
    """Frames of a MOTChallenge folder, or of a plain folder of images (no ``seqinfo.ini`` nor
    ``img1/``); ground truth from ``gt/gt.txt`` or the ``gt`` argument."""

    def __init__(self, path: str | os.PathLike[str], gt: str | os.PathLike[str] | None = None) -> None:

        from gldt_core.io.mot import read_mot

        self.path = Path(path)
        if not self.path.is_dir():
            raise FileNotFoundError(f"MOT folder not found: {self.path}")
        info = read_seqinfo(self.path / "seqinfo.ini")
        self.name = info.get("name", self.path.name)
        image_dir = self.path / info.get("imDir", "img1")
        if not info and not image_dir.is_dir() and image_files(self.path):
            image_dir = self.path  # a plain folder of images
        if not image_dir.is_dir():
            raise FileNotFoundError(f"{self.path}: no image folder {image_dir.name}/")
        extension = info.get("imExt")
        self._images = image_files(image_dir, (extension,) if extension else IMAGE_EXTENSIONS)
        self.lost_frames = 0
        if not self._images:
            raise ValueError(f"{image_dir}: no image files")
        if "seqLength" in info and int(info["seqLength"]) != len(self._images):
            raise ValueError(
                f"{self.path}: seqinfo.ini says seqLength={info['seqLength']} but "
                f"{image_dir.name}/ holds {len(self._images)} images"
            )
        try:
            self.fps = float(info.get("frameRate", 30.0))
        except ValueError:
            raise ValueError(f"{self.path}/seqinfo.ini: frameRate is not a number") from None
        if "imWidth" in info and "imHeight" in info:
            self.size = (int(info["imWidth"]), int(info["imHeight"]))
        else:
            first = next((i for i in map(_read_image, self._images) if i is not None), None)
            if first is None:
                raise ValueError(f"{image_dir}: none of its {len(self._images)} images can be read")
            self.size = (first.shape[1], first.shape[0])
        gt_path = Path(gt) if gt is not None else self.path / "gt" / "gt.txt"
        if gt is not None and not gt_path.is_file():
            raise FileNotFoundError(f"ground-truth file not found: {gt_path}")
        self._gt = read_mot(gt_path) if gt_path.is_file() else empty_ground_truth()
        if len(self._gt) and self._gt[:, 0].max() > len(self._images):
            raise ValueError(
                f"{gt_path}: ground truth reaches frame {int(self._gt[:, 0].max())} but the "
                f"sequence has {len(self._images)} frames"
            )
        self._by_frame = rows_by_frame(self._gt)

    def __len__(self) -> int:
        return len(self._images)

    @property
    def ground_truth(self) -> np.ndarray:
        return self._gt

    def __iter__(self) -> Iterator[Frame]:
        self.lost_frames = 0
        for index, image_path in enumerate(self._images):
            image = _read_image(image_path)
            if image is None:
                self.lost_frames += 1
                _log.warning(
                    "cannot read image %s (frame %d); skipped, the tracker coasts over it", image_path, index + 1
                )
                continue
            yield Frame(index, index / self.fps, image, self._by_frame.get(index, empty_ground_truth()))


def _read_image(path: Path) -> np.ndarray | None:
    """The image at ``path`` as HxWx3 BGR, or None when it cannot be read or decoded."""
    import cv2

    try:
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    except cv2.error:
        return None
    return image if image is not None and image.size else None
