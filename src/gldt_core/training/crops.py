"""Training crops for the second stage, cut from the Halmstad clips and from synthetic scenes
(numpy + OpenCV + onnxruntime).

For each sampled frame of a clip or scene the crops come from four sources, so the classifier learns
what it will be shown at run time and what it must tell apart:

* ``global``: the shipped global detector's candidates at a low score on the frame pair (the
  hard negatives: the birds, airplanes and clouds it takes for drones);
* ``local``: the local detector's candidates on tiles covering the frame;
* ``jitter``: every annotated object (drone, bird, airplane) boxed loosely and off-centre, the
  way the detectors box them, so the box correction learns the annotations' boxes;
* ``random``: empty sky and ground away from every object.

Each candidate is labelled from the annotations: the class of the object it sits on (IoU >= 0.2,
or centre inside it at a comparable size), background when it touches none (IoU < 0.05 and
centre outside every box), and left out in between. Its box-quality target is its IoU with that
object's annotated box (0 on background), and its box-correction target is that annotated box in
the same crop-relative terms as the candidate's own (:func:`encode_boxes`; zeros on background).
Clips and scenes are cut one at a time into ``CACHE/<key>/<name>.npz``, so a build that stops resumes.
Synthetic scenes (:class:`SceneCrops`) add drones of other looks and sizes than the Halmstad
ones: without them the second stage, having seen only real drones, rejected nearly every drone
of the 1080p synthetic scenes that the global detector found.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gldt_core.detect.second_stage import CONTEXT, crop_windows, cut_crops, encode_boxes
from gldt_core.eval.detection_metrics import box_iou
from gldt_core.sim.spec import SceneSpec

SOURCES = ("global", "local", "jitter", "random")


@dataclass(frozen=True)
class CropSpec:
    """How crops are sampled; part of the cache key."""

    frame_step: int = 5
    global_candidates: int = 10
    local_candidates: int = 6
    local_every: int = 2  # the local detector runs on every n-th sampled frame
    jitter_copies: int = 2
    random_boxes: int = 2
    candidate_score: float = 0.01
    seed: int = 0
    version: int = 3  # what a crop file holds: 2 = box geometry and box quality, 3 = and the annotated box
    context: float = CONTEXT  # a crop covers this many times the candidate's longer side

    def __post_init__(self) -> None:
        if not self.context > 0:
            raise ValueError(f"data.crops.context must be > 0 (the crop's side over the box's), got {self.context!r}")

    def key(self, global_model: Path, local_model: Path) -> str:
        fields = asdict(self)
        if fields["context"] == CONTEXT:
            del fields["context"]  # the crops cut before the option was added keep their key
        digest = hashlib.sha1(json.dumps(fields, sort_keys=True).encode())
        for model in (global_model, local_model):
            digest.update(hashlib.sha1(Path(model).read_bytes()).digest())
        return digest.hexdigest()[:12]


@dataclass
class CropSet:
    """Crops with labels: ``crops (N, 6, S, S) uint8``, ``labels (N,)`` 0-3, ``geometry (N, 4)`` the
    candidate's box relative to its crop (:func:`encode_boxes`), ``quality (N,)`` its IoU with its
    object's box (0 on background), ``target (N, 4)`` that object's annotated box relative to the
    same crop (zeros on background), ``scores (N,)`` detector score (NaN when not a detector
    candidate), ``sources (N,)`` index into :data:`SOURCES`, ``clips (N,)`` index into ``clip_names``."""

    crops: np.ndarray
    labels: np.ndarray
    geometry: np.ndarray
    quality: np.ndarray
    target: np.ndarray
    scores: np.ndarray
    sources: np.ndarray
    clips: np.ndarray
    clip_names: list[str]

    def __len__(self) -> int:
        return len(self.labels)

    def subset(self, mask: np.ndarray) -> CropSet:
        return CropSet(
            self.crops[mask],
            self.labels[mask],
            self.geometry[mask],
            self.quality[mask],
            self.target[mask],
            self.scores[mask],
            self.sources[mask],
            self.clips[mask],
            self.clip_names,
        )


def label_boxes(
    boxes: np.ndarray, gt_boxes: np.ndarray, gt_classes: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``labels (N,)`` (-1: left out), ``quality (N,)`` (IoU with the object's box, 0 on
    background) and ``matched (N,)`` (the index of that object in ``gt_boxes``, -1 where none)
    for candidate ``boxes`` on one frame."""
    labels = np.zeros(len(boxes), dtype=np.int64)
    quality = np.zeros(len(boxes))
    matched = np.full(len(boxes), -1, dtype=np.int64)
    if len(boxes) == 0 or len(gt_boxes) == 0:
        return labels, quality, matched
    iou = box_iou(boxes, gt_boxes)
    cx = (boxes[:, 0] + boxes[:, 2]) / 2
    cy = (boxes[:, 1] + boxes[:, 3]) / 2
    inside = (
        (cx[:, None] >= gt_boxes[None, :, 0])
        & (cx[:, None] <= gt_boxes[None, :, 2])
        & (cy[:, None] >= gt_boxes[None, :, 1])
        & (cy[:, None] <= gt_boxes[None, :, 3])
    )
    size = np.sqrt(np.prod(np.clip(boxes[:, 2:] - boxes[:, :2], 1e-3, None), axis=1))
    gt_size = np.sqrt(np.prod(np.clip(gt_boxes[:, 2:] - gt_boxes[:, :2], 1e-3, None), axis=1))
    ratio = size[:, None] / gt_size[None, :]
    on_object = (iou >= 0.2) | (inside & (ratio > 0.25) & (ratio < 4.0))
    score = np.where(on_object, iou + inside, -1.0)
    best = score.argmax(axis=1)
    has = on_object[np.arange(len(boxes)), best]
    labels[has] = gt_classes[best[has]]
    quality[has] = iou[np.flatnonzero(has), best[has]]
    matched[has] = best[has]
    ambiguous = ~has & ((iou.max(axis=1) >= 0.05) | inside.any(axis=1))
    labels[ambiguous] = -1
    return labels, quality, matched


def _jittered(gt_boxes: np.ndarray, copies: int, rng: np.random.Generator) -> np.ndarray:
    if len(gt_boxes) == 0 or copies == 0:
        return np.zeros((0, 4))
    boxes = np.repeat(gt_boxes, copies, axis=0)
    w = boxes[:, 2] - boxes[:, 0]
    h = boxes[:, 3] - boxes[:, 1]
    scale = rng.uniform(0.4, 1.4, size=(len(boxes), 2))
    cx = (boxes[:, 0] + boxes[:, 2]) / 2 + rng.uniform(-0.3, 0.3, len(boxes)) * w
    cy = (boxes[:, 1] + boxes[:, 3]) / 2 + rng.uniform(-0.3, 0.3, len(boxes)) * h
    nw, nh = w * scale[:, 0], h * scale[:, 1]
    return np.stack([cx - nw / 2, cy - nh / 2, cx + nw / 2, cy + nh / 2], axis=1)


def _random_boxes(count: int, width: int, height: int, rng: np.random.Generator) -> np.ndarray:
    side = rng.uniform(8, 60, size=(count, 2))
    x = rng.uniform(0, width - side[:, 0])
    y = rng.uniform(0, height - side[:, 1])
    return np.stack([x, y, x + side[:, 0], y + side[:, 1]], axis=1)


def read_truth(path: Path) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Frame (1-based) -> (xyxy boxes, MOT class codes) of a Halmstad ground-truth file."""
    from gldt_core.io.mot import read_mot

    rows = read_mot(path)
    out: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for frame in np.unique(rows[:, 0]).astype(int):
        sel = rows[rows[:, 0] == frame]
        boxes = np.concatenate([sel[:, 2:4], sel[:, 2:4] + sel[:, 4:6]], axis=1)
        out[int(frame)] = (boxes, sel[:, 7].astype(np.int64))
    return out


#: A sampled frame as the cutter sees it: (previous frame, frame, annotated xyxy boxes, MOT class codes).
SampledFrame = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def cut_frames(
    frames: Iterable[SampledFrame], name: str, spec: CropSpec, global_detector: object, local_detector: object
) -> dict[str, np.ndarray]:
    """All crops of the sampled ``frames`` of one clip or scene ``name`` (see the module
    docstring), as arrays for :class:`CropSet`."""
    from gldt_core.detect.video import frame_detections

    rng = np.random.default_rng([spec.seed, int(hashlib.sha1(name.encode()).hexdigest()[:8], 16)])
    keys = ("crops", "labels", "geometry", "quality", "target", "scores", "sources")
    parts: dict[str, list[np.ndarray]] = {k: [] for k in keys}
    for sampled, (prev, frame, gt_boxes, gt_classes) in enumerate(frames, start=1):
        gt_classes = np.where(gt_classes >= 3, 3, gt_classes)  # any other aircraft counts as airplane
        found: list[tuple[np.ndarray, str, np.ndarray | None]] = []
        dets = frame_detections(global_detector, prev, frame)  # type: ignore[arg-type]
        dets = dets[np.argsort(-dets[:, 4], kind="stable")[: spec.global_candidates]]
        found.append((dets[:, :4], "global", dets[:, 4]))
        if spec.local_candidates and sampled % spec.local_every == 0:
            dets = frame_detections(local_detector, prev, frame)  # type: ignore[arg-type]
            dets = dets[np.argsort(-dets[:, 4], kind="stable")[: spec.local_candidates]]
            found.append((dets[:, :4], "local", dets[:, 4]))
        found.append((_jittered(gt_boxes, spec.jitter_copies, rng), "jitter", None))
        found.append((_random_boxes(spec.random_boxes, frame.shape[1], frame.shape[0], rng), "random", None))
        all_boxes = np.concatenate([np.asarray(b, dtype=np.float64).reshape(-1, 4) for b, _, _ in found])
        scores = [np.full(len(b), np.nan) if s is None else np.asarray(s, dtype=np.float64) for b, _, s in found]
        sources = [np.full(len(b), SOURCES.index(source), dtype=np.int8) for b, source, _ in found]
        labels, quality, matched = label_boxes(all_boxes, gt_boxes, gt_classes)
        keep = labels >= 0
        if not keep.any():
            continue
        windows = crop_windows(all_boxes[keep], spec.context)
        parts["crops"].append(cut_crops(prev, frame, windows))
        parts["labels"].append(labels[keep])
        parts["geometry"].append(encode_boxes(all_boxes[keep], windows))
        parts["quality"].append(quality[keep])
        objects = matched[keep]
        target = np.zeros((len(objects), 4))
        on = objects >= 0
        if on.any():
            target[on] = encode_boxes(np.asarray(gt_boxes, dtype=np.float64)[objects[on]], windows[on])
        parts["target"].append(target)
        parts["scores"].append(np.concatenate(scores)[keep])
        parts["sources"].append(np.concatenate(sources)[keep])
    if not parts["crops"]:
        raise ValueError(f"{name}: no crops (no decodable frames?)")
    return {
        "crops": np.concatenate(parts["crops"]),
        "labels": np.concatenate(parts["labels"]).astype(np.int8),
        "geometry": np.concatenate(parts["geometry"]).astype(np.float32),
        "quality": np.concatenate(parts["quality"]).astype(np.float32),
        "target": np.concatenate(parts["target"]).astype(np.float32),
        "scores": np.concatenate(parts["scores"]).astype(np.float32),
        "sources": np.concatenate(parts["sources"]),
    }


def clip_frames(root: Path, clip: str, frame_step: int) -> Iterator[SampledFrame]:
    """Every ``frame_step``-th frame of a Halmstad clip with the frame before it and its annotations."""
    from gldt_core.detect.video import iter_video_frames

    truth = read_truth(root / "gt" / f"{clip}.txt")
    previous = None
    for index, frame in enumerate(iter_video_frames(root / "videos" / f"{clip}.mp4"), start=1):
        prev, previous = (frame if previous is None else previous), frame
        if (index - 1) % frame_step:
            continue
        gt_boxes, gt_classes = truth.get(index, (np.zeros((0, 4)), np.zeros(0, dtype=np.int64)))
        yield prev, frame, gt_boxes, gt_classes


@dataclass(frozen=True)
class SceneCrops:
    """A synthetic scene (:mod:`gldt_core.sim`) to cut crops from, its frames resized by ``scale``:
    1/3 puts a 1080p frame at the global detector's 640-wide input, where its second stage cuts
    crops at run time; 2/3 near the scale of a local detector's 1080p ROIs."""

    scene: SceneSpec
    scale: float

    @property
    def name(self) -> str:
        return f"{self.scene.name}-{self.scene.frames}f-x{self.scale:.3f}"


def scene_frames(item: SceneCrops, frame_step: int) -> Iterator[SampledFrame]:
    """Every ``frame_step``-th frame of a synthetic scene (from its second), rendered, resized by
    ``item.scale``, with the frame before it and its drones and birds."""
    from gldt_core.sim import SceneRenderer

    for _, previous, frame, rows in SceneRenderer(item.scene).sampled_pairs(frame_step, item.scale):
        boxes = np.concatenate([rows[:, 2:4], rows[:, 2:4] + rows[:, 4:6]], axis=1)
        yield previous, frame, boxes, rows[:, 7].astype(np.int64)


def build_crops(
    root: Path,
    clips: Iterable[str],
    spec: CropSpec,
    cache_dir: Path,
    global_model: Path,
    local_model: Path,
    progress: bool = True,
    scenes: Sequence[SceneCrops] = (),
) -> CropSet:
    """The crops of the Halmstad ``clips`` and then of the synthetic ``scenes``, cut once per
    clip or scene into the cache and loaded from it afterwards; ``clip_names`` names both."""
    items: list[str | SceneCrops] = [*sorted(clips), *scenes]
    folder = Path(cache_dir) / f"crops_{spec.key(global_model, local_model)}"
    folder.mkdir(parents=True, exist_ok=True)
    detectors: tuple[object, object] | None = None
    arrays: list[dict[str, np.ndarray]] = []
    names: list[str] = []
    for number, item in enumerate(items):
        name = item if isinstance(item, str) else item.name
        names.append(name)
        path = folder / f"{name}.npz"
        if not path.is_file():
            if detectors is None:
                from gldt_core.detect import GlobalDetector, LocalDetector

                # The detectors alone: their candidates are what the second stage learns to judge.
                options: dict[str, Any] = {
                    "score_threshold": spec.candidate_score,
                    "classes": [1],
                    "num_threads": 1,
                    "second_stage": None,
                }
                detectors = (GlobalDetector(global_model, **options), LocalDetector(local_model, **options))
            frames = (
                clip_frames(root, item, spec.frame_step)
                if isinstance(item, str)
                else scene_frames(item, spec.frame_step)
            )
            cut = cut_frames(frames, name, spec, *detectors)
            tmp = path.with_suffix(".tmp.npz")
            np.savez(tmp, **cut)  # type: ignore[arg-type]
            tmp.replace(path)
            if progress:
                print(f"[crops] {number + 1}/{len(items)} {name}: {len(cut['labels'])} crops", flush=True)
        with np.load(path) as data:
            arrays.append({k: data[k] for k in data.files})
    return CropSet(
        crops=np.concatenate([a["crops"] for a in arrays]),
        labels=np.concatenate([a["labels"] for a in arrays]).astype(np.int64),
        geometry=np.concatenate([a["geometry"] for a in arrays]),
        quality=np.concatenate([a["quality"] for a in arrays]),
        target=np.concatenate([a["target"] for a in arrays]),
        scores=np.concatenate([a["scores"] for a in arrays]),
        sources=np.concatenate([a["sources"] for a in arrays]),
        clips=np.concatenate([np.full(len(a["labels"]), i, dtype=np.int32) for i, a in enumerate(arrays)]),
        clip_names=names,
    )
