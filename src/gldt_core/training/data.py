"""Training data for the detectors: real Halmstad frame pairs and synthetic scenes, with augmentation.

Frames are decoded once (cv2.VideoCapture) and kept JPEG-encoded in a pickle cache, so a sample
costs a JPEG decode instead of a video seek. A *sample* is always a pair (previous, current)
with the current frame's boxes, so the same store feeds AM-YOLO (both frames) and the local model
(current frame only).

Augmentation for the global model is applied identically to both frames of a pair (same crop,
scale, flip and photometric change); otherwise the network could learn the augmentation as
"motion". The local model sees 300x300 windows placed the way the runtime places ROIs (target in the
central part of the window) plus random windows as hard negatives, resized to its input size.

Classes: index 0 drone, 1 bird, 2 airplane (helicopters are folded into airplane).
"""

from __future__ import annotations

import hashlib
import multiprocessing
import os
import pickle
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

import cv2
import numpy as np
import torch
from torch.utils.data import Dataset

from gldt_core.io.mot import read_mot
from gldt_core.training.paste import ObjectBank, paste_objects

if TYPE_CHECKING:
    from gldt_core.sim.spec import SceneSpec

#: MOT class code (Halmstad gt column 8) -> model class index.
MOT_CLASS_TO_INDEX = {1: 0, 2: 1, 3: 2, 4: 2}
CLASS_NAMES = ("drone", "bird", "airplane")
PAD_VALUE = 114


@dataclass(frozen=True)
class CopyPaste:
    """Copy-paste augmentation settings (see :mod:`.paste`): with ``probability`` a training sample
    gets 1 to ``max_objects`` objects from ``bank`` pasted in."""

    bank: ObjectBank
    probability: float
    max_objects: int

    def apply(
        self, images: list[np.ndarray], boxes: np.ndarray, rng: np.random.Generator, scale: float
    ) -> tuple[list[np.ndarray], np.ndarray]:
        if self.probability <= 0 or rng.random() >= self.probability:
            return images, boxes
        return paste_objects(images, boxes, self.bank, rng, scale, count=int(rng.integers(1, self.max_objects + 1)))


@dataclass
class FramePair:
    """One training sample: JPEG bytes of frame t-1 and t, and the boxes of frame t."""

    source: str  # clip name or synthetic scene id
    frame: int  # 1-based index of the current frame
    previous: bytes
    current: bytes
    boxes: np.ndarray  # (M, 5) class, x1, y1, x2, y2 in frame pixels

    def images(self) -> tuple[np.ndarray, np.ndarray]:
        return _decode(self.previous), _decode(self.current)

    def current_image(self) -> np.ndarray:
        """Frame t alone, for the single-frame local model (decoding is most of a sample's cost)."""
        return _decode(self.current)


def _encode(image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 95])
    if not ok:
        raise ValueError("could not JPEG-encode a frame")
    return buf.tobytes()


def _decode(data: bytes) -> np.ndarray:
    """The BGR frame :func:`_encode` stored."""
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if image is None:
        raise ValueError("could not decode a JPEG frame")
    return image


def gt_boxes_by_frame(gt_path: Path) -> dict[int, np.ndarray]:
    """MOT gt -> ``{frame: (M, 5) [class_index, x1, y1, x2, y2]}`` (unknown classes dropped)."""
    rows = read_mot(gt_path)
    out: dict[int, list[list[float]]] = {}
    for row in rows:
        cls = MOT_CLASS_TO_INDEX.get(int(row[7]))
        if cls is None:
            continue
        x, y, w, h = row[2:6]
        out.setdefault(int(row[0]), []).append([cls, x, y, x + w, y + h])
    return {f: np.asarray(v, dtype=np.float32) for f, v in out.items()}


def load_clip_pairs(video: Path, gt_path: Path, frame_step: int, include_empty: bool = True) -> list[FramePair]:
    """Decode one clip and keep every ``frame_step``-th frame (from frame 2) with its predecessor."""
    boxes = gt_boxes_by_frame(gt_path)
    cap = cv2.VideoCapture(str(video))
    if not cap.isOpened():
        raise FileNotFoundError(f"cannot open video {video}")
    pairs: list[FramePair] = []
    previous: np.ndarray | None = None
    index = 0
    try:
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            index += 1
            if previous is not None and (index - 2) % frame_step == 0:
                b = boxes.get(index, np.zeros((0, 5), np.float32))
                if len(b) or include_empty:
                    pairs.append(FramePair(video.stem, index, _encode(previous), _encode(frame), b))
            previous = frame
    finally:
        cap.release()
    return pairs


_Item = TypeVar("_Item")
_Result = TypeVar("_Result")


def _map_in_order(work: Callable[[_Item], _Result], items: Sequence[_Item], workers: int) -> list[_Result]:
    """``[work(i) for i in items]``, spread over ``workers`` processes when > 1 (order kept, so the
    cached data set is the same whatever the worker count).

    The workers come from a fork server, not a fork of this process: a fork copies OpenCV's and
    torch's thread pools without their threads, and a worker that touched such a pool could
    wait forever (as the DataLoader's workers did: see ``training.train``)."""
    if workers <= 1 or len(items) <= 1:
        return [work(item) for item in items]
    context = multiprocessing.get_context("forkserver")
    with ProcessPoolExecutor(max_workers=min(workers, len(items)), mp_context=context) as pool:
        return list(pool.map(work, items))


def _cached(cache: Path, build: Callable[[], list[FramePair]]) -> list[FramePair]:
    """The pickled pairs at ``cache``, built and written atomically on the first call."""
    if cache.is_file():
        with cache.open("rb") as fh:
            return pickle.load(fh)
    pairs = build()
    cache.parent.mkdir(parents=True, exist_ok=True)
    tmp = cache.with_name(f"{cache.name}.{os.getpid()}.tmp")  # concurrent builders must not share one
    with tmp.open("wb") as fh:
        pickle.dump(pairs, fh, protocol=pickle.HIGHEST_PROTOCOL)
    tmp.replace(cache)
    return pairs


class _ClipLoader:
    """Picklable ``clip name -> pairs`` for the worker processes of :func:`load_halmstad`."""

    def __init__(self, root: Path, frame_step: int):
        self.root, self.frame_step = Path(root), frame_step

    def __call__(self, clip: str) -> list[FramePair]:
        return load_clip_pairs(self.root / "videos" / f"{clip}.mp4", self.root / "gt" / f"{clip}.txt", self.frame_step)


def load_halmstad(
    root: Path, clips: Iterable[str], frame_step: int, cache_dir: Path, workers: int = 0
) -> list[FramePair]:
    """Frame pairs from the named clips, cached on disk keyed by (clips, step); ``workers``
    processes decode clips side by side."""
    clips = sorted(clips)
    key = hashlib.sha1(("|".join(clips) + f"|{frame_step}").encode()).hexdigest()[:12]
    build = lambda: [p for pairs in _map_in_order(_ClipLoader(root, frame_step), clips, workers) for p in pairs]  # noqa: E731
    return _cached(Path(cache_dir) / f"halmstad_{key}.pkl", build)


class _SceneLoader:
    """Picklable ``scene spec -> pairs`` for the worker processes of :func:`load_synthetic`."""

    def __init__(self, frame_step: int, scale: float):
        self.frame_step, self.scale = frame_step, scale

    def __call__(self, spec: SceneSpec) -> list[FramePair]:
        from gldt_core.sim import SceneRenderer

        pairs: list[FramePair] = []
        for t, previous, current, rows in SceneRenderer(spec).sampled_pairs(self.frame_step, self.scale):
            boxes = [
                [MOT_CLASS_TO_INDEX.get(int(r[7]), 0), r[2], r[3], r[2] + r[4], r[3] + r[5]]
                for r in rows
                if int(r[7]) in MOT_CLASS_TO_INDEX
            ]
            pairs.append(
                FramePair(
                    spec.name, t + 1, _encode(previous), _encode(current), np.asarray(boxes, np.float32).reshape(-1, 5)
                )
            )
        return pairs


def load_synthetic(
    split: str, num_scenes: int, frames_per_scene: int, frame_step: int, scale: float, cache_dir: Path, workers: int = 0
) -> list[FramePair]:
    """Frame pairs from the ``gldt_core.sim`` preset split, resized by ``scale`` and cached on disk.

    ``scale`` puts the synthetic 1080p frames at the resolution the detector sees them at run time
    (1/3 for the global model's 640-wide input, 1 for the local model's native-resolution ROIs),
    so one augmentation scale range fits real and synthetic pairs alike. ``workers`` processes
    render scenes side by side.
    """
    from gldt_core.sim import presets

    key = f"sim_{split}_{num_scenes}_{frames_per_scene}_{frame_step}_{scale:.4f}"
    specs = presets.split(split, count=num_scenes, frames=frames_per_scene)
    build = lambda: [p for pairs in _map_in_order(_SceneLoader(frame_step, scale), specs, workers) for p in pairs]  # noqa: E731
    return _cached(Path(cache_dir) / f"{key}.pkl", build)


def clip_boxes(boxes: np.ndarray, w: int, h: int, min_visible: float = 0.4, min_size: float = 1.0) -> np.ndarray:
    """Clip boxes to the image; drop those mostly outside or degenerate."""
    if len(boxes) == 0:
        return boxes.reshape(0, 5)
    out = boxes.copy()
    area = (out[:, 3] - out[:, 1]) * (out[:, 4] - out[:, 2])
    out[:, [1, 3]] = out[:, [1, 3]].clip(0, w)
    out[:, [2, 4]] = out[:, [2, 4]].clip(0, h)
    bw, bh = out[:, 3] - out[:, 1], out[:, 4] - out[:, 2]
    keep = (bw >= min_size) & (bh >= min_size) & (bw * bh >= min_visible * np.maximum(area, 1e-6))
    return out[keep]


def affine_crop(image: np.ndarray, scale: float, x0: float, y0: float, out_w: int, out_h: int) -> np.ndarray:
    """Crop the window of ``out / scale`` frame pixels at ``(x0, y0)`` and resize to ``out_w x out_h``."""
    m = np.array([[scale, 0, -x0 * scale], [0, scale, -y0 * scale]], dtype=np.float32)
    interp = cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR
    return cv2.warpAffine(
        image, m, (out_w, out_h), flags=interp, borderMode=cv2.BORDER_CONSTANT, borderValue=(PAD_VALUE,) * 3
    )


def photometric(images: list[np.ndarray], rng: np.random.Generator) -> list[np.ndarray]:
    """The same random gain/bias/hue-ish channel gains for every image of a sample."""
    gain = rng.uniform(0.7, 1.3)
    bias = rng.uniform(-25, 25)
    channel = rng.uniform(0.9, 1.1, size=3)
    lut = [np.clip(np.arange(256) * gain * c + bias, 0, 255).astype(np.uint8) for c in channel]
    out = []
    for im in images:
        out.append(np.dstack([cv2.LUT(im[..., i], lut[i]) for i in range(3)]))
    return out


def to_tensor(image_bgr: np.ndarray) -> torch.Tensor:
    """BGR uint8 -> (3, H, W) float RGB in [0, 1] (the exported model's input convention)."""
    return torch.from_numpy(np.ascontiguousarray(image_bgr[..., ::-1].transpose(2, 0, 1))).float() / 255.0


def _transform_boxes(boxes: np.ndarray, scale: float, x0: float, y0: float) -> np.ndarray:
    out = boxes.copy()
    out[:, [1, 3]] = (out[:, [1, 3]] - x0) * scale
    out[:, [2, 4]] = (out[:, [2, 4]] - y0) * scale
    return out


class GlobalPairDataset(Dataset):
    """Frame pairs for AM-YOLO. Training: consistent random crops; validation: whole frames letterboxed."""

    def __init__(
        self,
        pairs: list[FramePair],
        size: tuple[int, int],
        train: bool,
        seed: int = 0,
        scale_range: tuple[float, float] = (0.5, 1.3),
        target_bias: float = 0.75,
        copy_paste: CopyPaste | None = None,
    ):
        self.pairs, self.size, self.train = pairs, size, train
        self.seed, self.scale_range, self.target_bias = seed, scale_range, target_bias
        self.copy_paste = copy_paste
        self.epoch = 0
        self.sample_weights: list[float] | None = None  # per-pair draw weights; None draws uniformly

    def __len__(self) -> int:
        return len(self.pairs)

    def __getitem__(self, index: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        pair = self.pairs[index]
        previous, current = pair.images()
        out_w, out_h = self.size
        h, w = current.shape[:2]
        if self.train:
            rng = np.random.default_rng((self.seed, self.epoch, index))
            scale = rng.uniform(*self.scale_range)
            win_w, win_h = out_w / scale, out_h / scale
            if len(pair.boxes) and rng.random() < self.target_bias:
                b = pair.boxes[rng.integers(len(pair.boxes))]
                cx, cy = rng.uniform(b[1], b[3]), rng.uniform(b[2], b[4])
                x0 = cx - rng.uniform(0.1, 0.9) * win_w
                y0 = cy - rng.uniform(0.1, 0.9) * win_h
            else:
                x0 = rng.uniform(min(0, w - win_w), max(0, w - win_w))
                y0 = rng.uniform(min(0, h - win_h), max(0, h - win_h))
            images = [affine_crop(im, scale, x0, y0, out_w, out_h) for im in (previous, current)]
            boxes = _transform_boxes(pair.boxes, scale, x0, y0)
            if rng.random() < 0.5:
                images = [im[:, ::-1] for im in images]
                boxes[:, [1, 3]] = out_w - boxes[:, [3, 1]]
            if self.copy_paste is not None:
                images, boxes = self.copy_paste.apply(images, boxes, rng, scale)
            images = photometric(images, rng)
        else:
            scale = min(out_w / w, out_h / h)
            x0 = -(out_w / scale - w) / 2
            y0 = -(out_h / scale - h) / 2
            images = [affine_crop(im, scale, x0, y0, out_w, out_h) for im in (previous, current)]
            boxes = _transform_boxes(pair.boxes, scale, x0, y0)
        boxes = clip_boxes(boxes, out_w, out_h)
        return to_tensor(images[0]), to_tensor(images[1]), torch.from_numpy(boxes).float()


class LocalCropDataset(Dataset):
    """ROI windows for the local model: around targets (as the runtime places them) or random (hard negatives)."""

    def __init__(
        self,
        pairs: list[FramePair],
        input_size: int,
        roi: int,
        train: bool,
        seed: int = 0,
        negative_fraction: float = 0.3,
        copy_paste: CopyPaste | None = None,
    ):
        self.pairs, self.input_size, self.roi, self.train = pairs, input_size, roi, train
        self.seed, self.negative_fraction = seed, negative_fraction
        self.copy_paste = copy_paste
        self.epoch = 0
        self.sample_weights: list[float] | None = None  # per-pair draw weights; None draws uniformly

    def __len__(self) -> int:
        return len(self.pairs)

    def __getitem__(self, index: int) -> tuple[torch.Tensor, torch.Tensor]:
        pair = self.pairs[index]
        current = pair.current_image()
        h, w = current.shape[:2]
        epoch = self.epoch if self.train else 0
        rng = np.random.default_rng((self.seed, epoch, index, 7))
        roi = self.roi * (rng.uniform(0.8, 1.25) if self.train else 1.0)
        drones = pair.boxes[pair.boxes[:, 0] == 0] if len(pair.boxes) else pair.boxes
        pool = drones if len(drones) else pair.boxes
        if len(pool) and rng.random() >= self.negative_fraction:
            b = pool[rng.integers(len(pool))]
            cx, cy = (b[1] + b[3]) / 2, (b[2] + b[4]) / 2
            # Target centre anywhere in the central ~80 % of the window (the runtime's safe zone).
            x0 = cx - roi * rng.uniform(0.15, 0.85)
            y0 = cy - roi * rng.uniform(0.15, 0.85)
        else:
            x0 = rng.uniform(min(0, w - roi), max(0, w - roi))
            y0 = rng.uniform(min(0, h - roi), max(0, h - roi))
        scale = self.input_size / roi
        image = affine_crop(current, scale, x0, y0, self.input_size, self.input_size)
        boxes = _transform_boxes(pair.boxes, scale, x0, y0)
        if self.train:
            if rng.random() < 0.5:
                image = image[:, ::-1]
                boxes[:, [1, 3]] = self.input_size - boxes[:, [3, 1]]
            if self.copy_paste is not None:
                (image,), boxes = self.copy_paste.apply([image], boxes, rng, scale)
            image = photometric([image], rng)[0]
        boxes = clip_boxes(boxes, self.input_size, self.input_size)
        return to_tensor(image), torch.from_numpy(boxes).float()


def collate_pairs(
    batch: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]],
) -> tuple[torch.Tensor, torch.Tensor, list[torch.Tensor]]:
    prev, cur, boxes = zip(*batch)
    return torch.stack(prev), torch.stack(cur), list(boxes)


def collate_crops(batch: list[tuple[torch.Tensor, torch.Tensor]]) -> tuple[torch.Tensor, list[torch.Tensor]]:
    images, boxes = zip(*batch)
    return torch.stack(images), list(boxes)
