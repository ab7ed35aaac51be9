"""Streams of real detector output for the tracking benchmark, cached on disk.

``gldt bench tracking`` scores trackers on streams a noise model made (:mod:`.streams`) and on
what the shipped global detector really reports: AM-YOLO with its second stage, run the way
:class:`gldt_core.system.gldt_system.GLDTSystem` runs it on a GD frame (the pair (previous,
current) through ``detect_pair``, invalid rows and other classes dropped, nested boxes dropped),
on every frame, at a low score threshold (:data:`DEFAULT_SCORE_THRESHOLD`) so the trackers' own
thresholds decide. The rows are MOTChallenge det lines ``frame, -1, x, y, w, h, score, -1, -1, -1``
(provenance unknown: ``-1``).

Running the detector over the Halmstad validation clips costs minutes on a small machine, so each
clip's stream is written to ``<root>/<key>/<clip>.txt`` with a ``<clip>.json`` beside it (frames
done, whether the clip was finished, fps, size). ``root`` is ``$GLDT_CACHE/detector_streams``
(default ``/tmp/gldt-cache/detector_streams``); ``key`` hashes the bytes of every model file the
detector reads (model, its card, the feature-reuse pair, the second stage and its card) and the
settings that shape the rows, so a changed model or threshold lands in a new folder and is
recomputed, never served stale. A stream asked for with ``max_frames`` is served from any cached
stream that covers at least that many frames.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

#: Score threshold of the cached streams: low, so the trackers' own thresholds decide.
DEFAULT_SCORE_THRESHOLD = 0.05
#: Version of the cached file layout; part of the key.
STREAM_FORMAT = 1


def cache_root() -> Path:
    """``$GLDT_CACHE/detector_streams``, or ``/tmp/gldt-cache/detector_streams``."""
    return Path(os.environ.get("GLDT_CACHE") or "/tmp/gldt-cache") / "detector_streams"


def stream_key(files: Iterable[Path], settings: Mapping[str, Any]) -> str:
    """A short hash of the files' names and bytes and of ``settings`` (JSON-able)."""
    digest = hashlib.sha256(f"format {STREAM_FORMAT}\n".encode())
    for path in files:
        digest.update(f"{Path(path).name}\n".encode())
        with open(path, "rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
    digest.update(json.dumps(dict(settings), sort_keys=True, default=str).encode())
    return digest.hexdigest()[:16]


def global_model_files(model: Path, second_stage: str | None) -> list[Path]:
    """The files a global detector built from ``model`` reads (those that exist)."""
    from gldt_core.detect.feature_reuse import features_path, reuse_path
    from gldt_core.detect.second_stage import BESIDE, classifier_path_for

    candidates = [model, model.with_suffix(".json"), features_path(model), reuse_path(model)]
    if second_stage is not None:
        stage = classifier_path_for(model) if second_stage == BESIDE else Path(second_stage)
        candidates += [stage, stage.with_suffix(".json")]
    return [path for path in candidates if path.is_file()]


@dataclass(frozen=True)
class DetectorStream:
    """One clip's detections; ``from_cache`` says whether the detector ran for it now."""

    name: str
    rows: np.ndarray
    frames: int
    fps: float
    size: tuple[int, int]
    from_cache: bool


def detect_frames(
    detector: Any,
    images: Iterable[np.ndarray],
    classes: Sequence[int] | None = (1,),
    nested_threshold: float | None = 0.8,
    max_frames: int | None = None,
) -> tuple[np.ndarray, int]:
    """MOT det rows of ``detector`` on every frame of ``images`` (GD frames of :class:`GLDTSystem`:
    ``detect_pair`` with the carry where the detector has it, else ``detect``) and the number of
    frames read."""
    from gldt_core.detect.second_stage import GLOBAL_COLUMNS
    from gldt_core.system.steps import drop_nested, filter_classes, with_class_probabilities

    detect_pair = getattr(detector, "detect_pair", None)
    previous: np.ndarray | None = None
    carry = None
    blocks: list[np.ndarray] = []
    frames = 0
    for image in images:
        if max_frames is not None and frames >= max_frames:
            break
        frames += 1
        pair_previous = image if previous is None else previous
        if detect_pair is not None:
            raw, carry = detect_pair(pair_previous, image, carry)
        else:
            raw = detector.detect(pair_previous, image)
        raw = with_class_probabilities(raw, GLOBAL_COLUMNS)
        raw = filter_classes(raw, GLOBAL_COLUMNS, classes)
        raw = drop_nested(raw, nested_threshold)
        previous = image
        if not len(raw):
            continue
        table = np.full((len(raw), 10), -1.0)
        table[:, 0] = frames
        table[:, 2:4] = raw[:, 0:2]
        table[:, 4:6] = raw[:, 2:4] - raw[:, 0:2]
        table[:, 6] = raw[:, 4]
        blocks.append(table)
    return (np.vstack(blocks) if blocks else np.zeros((0, 10))), frames


class DetectorStreamCache:
    """Detector streams of named clips under ``root / key``, computed once per model.

    ``make_detector`` is called at most once, and only when some clip is not cached.
    """

    def __init__(
        self,
        key: str,
        make_detector: Callable[[], Any],
        root: Path | None = None,
        classes: Sequence[int] | None = (1,),
        nested_threshold: float | None = 0.8,
        description: str = "detector",
    ) -> None:
        self.key = key
        self.directory = Path(root if root is not None else cache_root()) / key
        self._make_detector = make_detector
        self._detector: Any = None
        self.classes = classes
        self.nested_threshold = nested_threshold
        self.description = description
        self.computed_seconds = 0.0

    def _cached(self, name: str, max_frames: int | None) -> DetectorStream | None:
        from gldt_core.io.mot import read_mot

        rows_path, meta_path = self.directory / f"{name}.txt", self.directory / f"{name}.json"
        if not (rows_path.is_file() and meta_path.is_file()):
            return None
        try:
            meta = json.loads(meta_path.read_text(encoding="utf-8"))
            rows = read_mot(rows_path)
        except (OSError, ValueError):
            return None  # unreadable: recompute
        if meta.get("key") != self.key or meta.get("detections") != len(rows):
            return None
        frames = int(meta["frames"])
        if not meta.get("complete") and (max_frames is None or frames < max_frames):
            return None
        if max_frames is not None:
            frames = min(frames, max_frames)
            rows = rows[rows[:, 0] <= frames]
        size = (int(meta["size"][0]), int(meta["size"][1]))
        return DetectorStream(name, rows, frames, float(meta["fps"]), size, True)

    def stream(
        self,
        name: str,
        images: Callable[[], Iterable[np.ndarray]],
        fps: float,
        size: tuple[int, int],
        max_frames: int | None = None,
        total_frames: int | None = None,
    ) -> DetectorStream:
        """The stream of clip ``name``: from the cache, or computed from ``images()`` and cached.

        ``total_frames`` (the clip's length, when known) marks a stream that stops at
        ``max_frames`` as complete when that is the whole clip.
        """
        from gldt_core.io.mot import read_mot, write_mot

        cached = self._cached(name, max_frames)
        if cached is not None:
            return cached
        if self._detector is None:
            self._detector = self._make_detector()
        start = time.perf_counter()
        rows, frames = detect_frames(self._detector, images(), self.classes, self.nested_threshold, max_frames)
        self.computed_seconds += time.perf_counter() - start
        complete = max_frames is None or frames < max_frames or (total_frames is not None and frames >= total_frames)
        self.directory.mkdir(parents=True, exist_ok=True)
        write_mot(self.directory / f"{name}.txt", rows)
        rows = read_mot(self.directory / f"{name}.txt")  # as rounded on disk: every run sees the same rows
        meta = {
            "key": self.key,
            "name": name,
            "frames": frames,
            "complete": bool(complete),
            "fps": float(fps),
            "size": [int(size[0]), int(size[1])],
            "detections": len(rows),
            "detector": self.description,
        }
        temporary = self.directory / f"{name}.json.part"
        temporary.write_text(json.dumps(meta, indent=1), encoding="utf-8")
        os.replace(temporary, self.directory / f"{name}.json")
        return DetectorStream(name, rows, frames, float(fps), (int(size[0]), int(size[1])), False)


def shipped_detector_cache(
    config: Any = None, score_threshold: float = DEFAULT_SCORE_THRESHOLD, root: Path | None = None
) -> DetectorStreamCache:
    """The cache of the configured (by default the shipped) global detector with its second
    stage, at ``score_threshold``; the detector is built only when a clip must be computed. The
    streams are AM-YOLO's boxes alone (``tile_fusion`` off): the tracking benchmark's real
    profiles were defined and measured on them."""
    from gldt_core.detect.shipped import DEFAULT_GLOBAL_MODEL
    from gldt_core.system.config import SystemConfig
    from gldt_core.system.gldt_system import build_detectors

    config = config or SystemConfig()
    settings = dataclasses.replace(config.detector, score_threshold=float(score_threshold), tile_fusion=False)
    config = dataclasses.replace(config, detector=settings).with_changes(local_enabled=False)
    model = Path(settings.global_model) if settings.global_model else Path(DEFAULT_GLOBAL_MODEL)
    files = global_model_files(model, settings.second_stage)
    shaping = {
        "score_threshold": settings.score_threshold,
        "classes": list(settings.classes) if settings.classes is not None else None,
        "nested_threshold": settings.nested_threshold,
        "second_stage": settings.second_stage,
        "tile_fusion": settings.tile_fusion,
    }
    key = stream_key(files, shaping)
    stage = "with second stage" if settings.second_stage is not None else "without second stage"
    return DetectorStreamCache(
        key,
        lambda: build_detectors(config)[0],
        root=root,
        classes=settings.classes,
        nested_threshold=settings.nested_threshold,
        description=f"{model.name} {stage}, score >= {settings.score_threshold:g}",
    )


def halmstad_drone_clips(root: Path, clips: int = 0, split: str | None = None) -> list[tuple[str, str]]:
    """``[(split, clip)]``: the V_DRONE clips of one validation split, or of both alternating
    ``val`` and ``val_b`` (so the first ``clips`` come from both); ``clips`` 0 = all."""
    from gldt_core.eval.halmstad_split import halmstad_split

    splits = halmstad_split(root)
    val = [("val", n) for n in splits["val"] if n.startswith("V_DRONE")]
    val_b = [("val_b", n) for n in splits["val_b"] if n.startswith("V_DRONE")]
    if split is not None:
        chosen = {"val": val, "val_b": val_b}.get(split)
        if chosen is None:
            raise ValueError(f"unknown validation split {split!r} (val, val_b)")
        return chosen[:clips] if clips > 0 else chosen
    mixed = [pair for both in zip(val, val_b) for pair in both] + val[len(val_b) :] + val_b[len(val) :]
    return mixed[:clips] if clips > 0 else mixed


def halmstad_detector_sequences(
    root: Path,
    cache: DetectorStreamCache,
    clips: int = 0,
    max_frames: int | None = None,
    log: Callable[[str], None] | None = None,
    split: str | None = None,
) -> list[Any]:
    """:class:`gldt_core.eval.streams.StreamSequence` s of the real detector on the Halmstad
    validation drone clips (:func:`halmstad_drone_clips`), ground truth from ``gt/<clip>.txt``
    (class 1 drones) up to the frames the stream covers."""
    from gldt_core.eval.streams import StreamSequence
    from gldt_core.io.mot import read_mot
    from gldt_core.io.video import VideoSource

    sequences = []
    for clip_split, name in halmstad_drone_clips(root, clips, split):
        video = VideoSource(root / "videos" / f"{name}.mp4", root / "gt" / f"{name}.txt")

        def images(video: VideoSource = video) -> Iterable[np.ndarray]:
            return (frame.image for frame in video)

        start = time.perf_counter()
        stream = cache.stream(name, images, video.fps, video.size, max_frames, total_frames=len(video))
        if log is not None and not stream.from_cache:
            log(
                f"detector stream {name} ({clip_split}): {stream.frames} frames, {len(stream.rows)} detections, "
                f"{time.perf_counter() - start:.1f} s (cached in {cache.directory})"
            )
        gt = read_mot(root / "gt" / f"{name}.txt")
        gt = gt[gt[:, 0] <= stream.frames]
        sequences.append(StreamSequence(name, gt, stream.rows, stream.fps, stream.size, stream.frames))
    return sequences
