"""AM-YOLO with the previous GD frame's backbone features instead of recomputing them.

:mod:`gldt_core.export.feature_split` (export time) writes two files next to an AM-YOLO export
``NAME.onnx``: ``NAME.features.onnx`` (a frame -> the features up to STFF's first level) and
``NAME.reuse.onnx`` (current frame + those features of the previous frame -> detections and the
current frame's features). Their outputs equal the original model's (checked when written), so
:class:`~gldt_core.detect.global_detector.GlobalDetector` uses them whenever they are there and
were made from that very file (the features model's metadata holds both files' SHA-256). A stream
of GD frames then runs the stem and the stride-4 stage once per frame instead of twice.

No onnx and no torch here: this only opens and runs the two files with onnxruntime.
"""

from __future__ import annotations

import hashlib
import json
import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TypeGuard

import numpy as np

from gldt_core.detect.session import DetectorConfigError, open_session

LOG = logging.getLogger("gldt.detect")

#: Input and output names shared by the split models and the original AM-YOLO export.
CURRENT_INPUT = "current"
PREVIOUS_FEATURES = "previous_features"
CURRENT_FEATURES = "current_features"
#: Metadata entry of the features model that pairs it with its source and reuse model.
METADATA_KEY = "gldt_feature_reuse"


def features_path(model: Path) -> Path:
    """``NAME.features.onnx`` next to ``NAME.onnx``."""
    return model.with_name(model.stem + ".features.onnx")


def reuse_path(model: Path) -> Path:
    """``NAME.reuse.onnx`` next to ``NAME.onnx``."""
    return model.with_name(model.stem + ".reuse.onnx")


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


class FeatureReuse:
    """The two onnxruntime sessions of a split AM-YOLO and the shape of the features they pass."""

    def __init__(self, features_session: Any, reuse_session: Any, channels: int, stride: int, source: Path):
        self.features_session = features_session
        self.reuse_session = reuse_session
        self.channels = int(channels)
        self.stride = int(stride)
        self.source = source

    def accepts(self, features: np.ndarray | None, input_height: int, input_width: int) -> TypeGuard[np.ndarray]:
        """Whether ``features`` can stand for a previous frame of this network input size."""
        expected = (1, self.channels, input_height // self.stride, input_width // self.stride)
        return features is not None and features.shape == expected and features.dtype == np.float32

    def features(self, blob: np.ndarray) -> np.ndarray:
        """The features of one ``(1, 3, H, W)`` network input (a frame with nothing to reuse)."""
        (features,) = self.features_session.run(None, {CURRENT_INPUT: blob})
        return features

    def detect(self, current_blob: np.ndarray, previous_features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(raw model output, current features)`` for the current input and the previous frame's features."""
        output, current_features = self.reuse_session.run(
            None, {CURRENT_INPUT: current_blob, PREVIOUS_FEATURES: previous_features}
        )
        return output, current_features


def load_feature_reuse(
    model_path: Path,
    providers: Sequence[str],
    num_threads: int | None,
    wanted: bool | None,
) -> FeatureReuse | None:
    """The split pair of ``model_path`` if it should be used, else None.

    ``wanted``: None uses the pair when both files are there, load and were made from this model
    (a stale or unreadable pair is skipped with a warning: the full model gives the same boxes,
    only slower); True requires it (such files raise :class:`DetectorConfigError`); False never
    loads it.
    """
    if wanted is False:
        return None
    features_file, reuse_file = features_path(model_path), reuse_path(model_path)
    regenerate = f"`gldt export {model_path} --feature-reuse` writes them"
    missing = [str(p) for p in (features_file, reuse_file) if not p.is_file()]
    if missing:
        if wanted:
            raise DetectorConfigError(
                f"{model_path}: feature reuse asked for, but {', '.join(missing)} not found; {regenerate}"
            )
        return None

    def unusable(problem: str) -> FeatureReuse | None:
        """Raise if the pair was required; else warn and use none (the full model runs)."""
        if wanted:
            raise DetectorConfigError(f"{model_path}: {problem}; {regenerate}")
        LOG.warning("%s: %s; running the full model on every frame pair (%s)", model_path, problem, regenerate)
        return None

    try:
        features_session, _ = open_session(
            features_file, providers, num_threads, "input (1, 3, H, W) float32 RGB 'current'"
        )
        raw = features_session.get_modelmeta().custom_metadata_map.get(METADATA_KEY)
        pairing = json.loads(raw) if raw else None
    except (
        DetectorConfigError,
        json.JSONDecodeError,
    ) as error:  # a truncated copy, an LFS pointer, a provider that cannot build it
        return unusable(f"cannot use {features_file.name} ({str(error).splitlines()[0][:200]})")
    if not isinstance(pairing, dict) or not {"source_sha256", "reuse_sha256", "channels", "stride"} <= set(pairing):
        return unusable(f"{features_file} has no valid '{METADATA_KEY}' metadata")
    if pairing["source_sha256"] != _sha256(model_path):
        return unusable(f"{features_file} was made from another version of {model_path.name}")
    if pairing["reuse_sha256"] != _sha256(reuse_file):
        return unusable(f"{reuse_file} is not the file {features_file.name} was written with")
    try:
        reuse_session, _ = open_session(
            reuse_file, providers, num_threads, "inputs 'current' (1, 3, H, W) and 'previous_features'"
        )
    except DetectorConfigError as error:
        return unusable(f"cannot use {reuse_file.name} ({str(error).splitlines()[0][:200]})")
    names = {i.name for i in reuse_session.get_inputs()}
    if names != {CURRENT_INPUT, PREVIOUS_FEATURES}:
        return unusable(f"{reuse_file} has inputs {sorted(names)}, expected {[CURRENT_INPUT, PREVIOUS_FEATURES]}")
    return FeatureReuse(features_session, reuse_session, pairing["channels"], pairing["stride"], model_path)
