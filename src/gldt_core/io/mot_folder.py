"""A MOTChallenge sequence folder: ``img1/`` frames, ``gt/gt.txt`` and ``seqinfo.ini``."""

from __future__ import annotations

import configparser
import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from gldt_core.io.frame import Frame, FrameSource, empty_ground_truth, rows_by_frame

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".bmp")


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
    """Frames of a MOTChallenge folder; ground truth from ``gt/gt.txt`` or the ``gt`` argument."""

    def __init__(self, path: str | os.PathLike[str], gt: str | os.PathLike[str] | None = None) -> None:
        import cv2

        from gldt_core.io.mot import read_mot

        self.path = Path(path)
        if not self.path.is_dir():
            raise FileNotFoundError(f"MOT folder not found: {self.path}")
        info = read_seqinfo(self.path / "seqinfo.ini")
        self.name = info.get("name", self.path.name)
        image_dir = self.path / info.get("imDir", "img1")
        if not image_dir.is_dir():
            raise FileNotFoundError(f"{self.path}: no image folder {image_dir.name}/")
        extension = info.get("imExt")
        self._images = sorted(
            p
            for p in image_dir.iterdir()
            if p.suffix.lower() in ((extension.lower(),) if extension else IMAGE_EXTENSIONS)
        )
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
            first = cv2.imread(str(self._images[0]), cv2.IMREAD_COLOR)
            if first is None:
                raise ValueError(f"cannot read image {self._images[0]}")
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
        import cv2

        for index, image_path in enumerate(self._images):
            image = cv2.imread(str(image_path), cv2.IMREAD_COLOR)
            if image is None:
                raise ValueError(f"cannot read image {image_path}")
            yield Frame(index, index / self.fps, image, self._by_frame.get(index, empty_ground_truth()))
