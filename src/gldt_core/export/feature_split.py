"""Split an AM-YOLO export so a stream of GD frames runs the shared backbone's first stages once per frame.

AM-YOLO batches the previous and the current frame through one weight-shared backbone and fuses
them with STFF from the first fused level on. Up to that level the previous frame's features are
the same tensor the *current* frame produced one GD frame earlier, so in a run of consecutive GD
frames (the scheduler's N_g stretches, or every frame while nothing is tracked) recomputing them
is wasted work: the stem and the stride-4 stage, the backbone's highest-resolution layers.

This rewrites the exported graph (no torch, no retraining) into two models written next to it:

- ``NAME.features.onnx``: ``current`` image -> the first fused level's features (stem + stages);
- ``NAME.reuse.onnx``: ``current`` image + ``previous_features`` -> the original ``detections``
  plus ``current_features``, which the caller keeps for the next GD frame.

The split point is found, not named: the first tensor the graph cuts back into its two frames
(``Slice`` on axis 0), which is where STFF first needs them apart. :func:`write_feature_reuse`
runs the original model and the pair on the same random frames and refuses to write files whose
detections or features differ by more than :data:`MAX_ABS_DIFF`. The features model's metadata
records both files' SHA-256, so the runtime (:mod:`gldt_core.detect.feature_reuse`) never pairs
them with a model they were not made from.

Needs the ``onnx`` package (the ``test``/``train`` extras); the run time never calls it.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gldt_core.detect.feature_reuse import (
    CURRENT_FEATURES,
    CURRENT_INPUT,
    METADATA_KEY,
    PREVIOUS_FEATURES,
    features_path,
    reuse_path,
)
from gldt_core.export.window_rewrite import output_difference

#: Largest difference accepted between the original model and the split pair (they are equal in
#: practice: the same kernels on the same numbers, one frame per batch instead of two).
MAX_ABS_DIFF = 1e-5
#: Frame sizes (w, h) the check runs the models on: the 1080p letterbox, a real clip, a small one.
CHECK_SIZES = ((640, 384), (640, 512), (320, 256))


class FeatureSplitError(ValueError):
    """The model cannot be split for feature reuse (not a dual-frame AM-YOLO export, or the split
    pair would not reproduce it); nothing was written."""


@dataclass(frozen=True)
class SplitResult:
    """What :func:`write_feature_reuse` wrote and measured."""

    features_model: Path
    reuse_model: Path
    split_tensor: str
    channels: int
    stride: int
    max_abs_diff: float


def _constant_ints(graph: Any, name: str) -> list[int] | None:
    """Values of a constant int tensor (initializer or ``Constant`` node output), else None."""
    from onnx import numpy_helper

    for initializer in graph.initializer:
        if initializer.name == name:
            return [int(v) for v in numpy_helper.to_array(initializer).ravel()]
    for node in graph.node:
        if node.op_type == "Constant" and name in node.output:
            for attribute in node.attribute:
                if attribute.name == "value":
                    return [int(v) for v in numpy_helper.to_array(attribute.t).ravel()]
    return None


def _is_batch_slice(graph: Any, node: Any) -> bool:
    """A ``Slice`` along axis 0 only (the cut of a two-frame batch back into its frames)."""
    if node.op_type != "Slice" or len(node.input) < 4:
        return False
    return _constant_ints(graph, node.input[3]) == [0]


def find_split(model: Any) -> tuple[Any, str, str, str]:
    """``(frame_concat_node, previous_input, current_input, split_tensor)`` of an AM-YOLO graph.

    ``frame_concat_node`` stacks the two graph inputs into one batch (current first, as the
    torch model does); ``split_tensor`` is the first tensor in graph order cut along axis 0.
    """
    graph = model.graph
    inputs = [i.name for i in graph.input]
    if len(inputs) != 2:
        raise FeatureSplitError(
            f"feature reuse needs a dual-frame model with inputs (previous, current); this one has {inputs}"
        )
    concats = [n for n in graph.node if n.op_type == "Concat" and set(n.input) == set(inputs) and len(n.input) == 2]
    if len(concats) != 1:
        raise FeatureSplitError(f"expected one Concat stacking the inputs {inputs} into a batch, found {len(concats)}")
    concat = concats[0]
    if concat.input[0] != CURRENT_INPUT:
        raise FeatureSplitError(f"expected the batch to start with input {CURRENT_INPUT!r}, found {list(concat.input)}")
    previous = concat.input[1]
    if sum(previous in n.input for n in graph.node) != 1:
        raise FeatureSplitError(
            f"input {previous!r} is used outside the frame batch; it cannot be replaced by features"
        )
    # The tensors computed from the stacked frames (not from their shapes), in graph order.
    batched = {concat.output[0]}
    for node in graph.node:
        if node.op_type != "Shape" and any(name in batched for name in node.input):
            batched.update(node.output)
    slices = [n for n in graph.node if _is_batch_slice(graph, n) and n.input[0] in batched]
    if not slices:
        raise FeatureSplitError("no Slice along the batch axis: the frames are never taken apart, nothing to reuse")
    split = slices[0].input[0]
    others = [n.name or n.op_type for n in graph.node if split in n.input and not _is_batch_slice(graph, n)]
    if others:
        raise FeatureSplitError(f"tensor {split!r} also feeds {others}, which would see one frame instead of two")
    return concat, previous, CURRENT_INPUT, split


def split_model(model: Any) -> tuple[Any, str]:
    """The reuse model made from ``model`` (an ``onnx.ModelProto``, left unchanged) and its split tensor."""
    import copy

    from onnx import TensorProto, helper

    reuse = copy.deepcopy(model)
    graph = reuse.graph
    concat, previous, current, split = find_split(reuse)
    stacked = concat.output[0]
    for node in graph.node:
        for index, name in enumerate(node.input):
            if name == stacked:
                node.input[index] = current  # the stem and first stages now see the current frame alone
    graph.node.remove(concat)
    paired = split + "/with_previous_features"
    for node in graph.node:
        if _is_batch_slice(graph, node) and node.input[0] == split:
            node.input[0] = paired
    producer = next(i for i, n in enumerate(graph.node) if split in n.output)
    graph.node.insert(
        producer + 1,
        helper.make_node("Concat", [split, PREVIOUS_FEATURES], [paired], axis=0, name="/feature_reuse/Concat"),
    )
    graph.node.insert(
        producer + 2, helper.make_node("Identity", [split], [CURRENT_FEATURES], name="/feature_reuse/Identity")
    )
    old_previous = next(i for i in graph.input if i.name == previous)
    graph.input.remove(old_previous)
    shape: list[str | int] = [1, "feature_channels", "feature_height", "feature_width"]
    graph.input.append(helper.make_tensor_value_info(PREVIOUS_FEATURES, TensorProto.FLOAT, shape))
    graph.output.append(helper.make_tensor_value_info(CURRENT_FEATURES, TensorProto.FLOAT, shape))
    return reuse, split


def _features_model(reuse_file: Path, split: str, out: Path) -> None:
    """The part of the reuse model that makes ``split`` from the current frame alone."""
    import onnx
    import onnx.utils

    onnx.utils.extract_model(str(reuse_file), str(out), [CURRENT_INPUT], [split])
    proto = onnx.load(str(out))
    # Shapes the extraction inferred: what onnx's shape inference writes varies between onnx
    # versions, and onnxruntime infers them itself, so leave them out (reproducible bytes).
    del proto.graph.value_info[:]
    proto.graph.output[0].name = CURRENT_FEATURES
    for node in proto.graph.node:
        node.output[:] = [CURRENT_FEATURES if name == split else name for name in node.output]
    onnx.checker.check_model(proto)
    onnx.save(proto, str(out))


def compare_split(original: Path, features_file: Path, reuse_file: Path, seed: int = 0) -> tuple[float, int, int]:
    """``(max difference, channels, stride)`` of the split pair against the original model.

    Each size runs original(previous, current) against reuse(features(previous), current), and
    checks that the reuse model's ``current_features`` equal features(current), which the next
    frame will be given.
    """
    import onnxruntime as ort

    def session(path: Path) -> Any:
        return ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])

    full, features, reuse = session(original), session(features_file), session(reuse_file)
    (previous_name,) = [i.name for i in full.get_inputs() if i.name != CURRENT_INPUT]
    rng = np.random.default_rng(seed)
    worst, channels, stride = 0.0, 0, 0
    for width, height in CHECK_SIZES:
        previous = rng.random((1, 3, height, width), dtype=np.float32)
        current = rng.random((1, 3, height, width), dtype=np.float32)
        (expected,) = full.run(None, {previous_name: previous, CURRENT_INPUT: current})[:1]
        (previous_features,) = features.run(None, {CURRENT_INPUT: previous})
        detections, current_features = reuse.run(None, {CURRENT_INPUT: current, PREVIOUS_FEATURES: previous_features})
        (fresh_features,) = features.run(None, {CURRENT_INPUT: current})
        worst = max(
            worst,
            output_difference(expected, detections, "splitting the model", FeatureSplitError),
            output_difference(fresh_features, current_features, "splitting the model", FeatureSplitError),
        )
        channels = int(previous_features.shape[1])
        stride = height // int(previous_features.shape[2])
        if stride * previous_features.shape[2] != height or stride * previous_features.shape[3] != width:
            raise FeatureSplitError(f"features {previous_features.shape} do not tile a {width}x{height} input evenly")
    return worst, channels, stride


def write_feature_reuse(model: Path | str) -> SplitResult:
    """Write ``NAME.features.onnx`` and ``NAME.reuse.onnx`` next to ``model``; see the module doc.

    Raises :class:`FeatureSplitError` and leaves nothing behind when the model cannot be split or
    the pair does not reproduce it within :data:`MAX_ABS_DIFF`.
    """
    import onnx

    model = Path(model)
    if not model.is_file():
        raise FileNotFoundError(f"model not found: {model}")
    proto = onnx.load(str(model))
    reuse, split = split_model(proto)
    onnx.checker.check_model(reuse)
    final_features, final_reuse = features_path(model), reuse_path(model)
    tmp_features = final_features.with_name(final_features.name + ".tmp")
    tmp_reuse = final_reuse.with_name(final_reuse.name + ".tmp")
    try:
        onnx.save(reuse, str(tmp_reuse))
        _features_model(tmp_reuse, split, tmp_features)
        diff, channels, stride = compare_split(model, tmp_features, tmp_reuse)
        if diff > MAX_ABS_DIFF:
            raise FeatureSplitError(
                f"the split pair changes {model}'s outputs by {diff:.3g} (limit {MAX_ABS_DIFF:g}); nothing written"
            )
        # The features model carries the pairing: which file it goes with, made from what.
        features_proto = onnx.load(str(tmp_features))
        entry = features_proto.metadata_props.add()
        entry.key = METADATA_KEY
        entry.value = json.dumps(
            {
                "source_model": model.name,
                "source_sha256": hashlib.sha256(model.read_bytes()).hexdigest(),
                "reuse_model": final_reuse.name,
                "reuse_sha256": hashlib.sha256(tmp_reuse.read_bytes()).hexdigest(),
                "split_tensor": split,
                "channels": channels,
                "stride": stride,
                "max_abs_diff": diff,
                "command": f"gldt export {model.name} --feature-reuse",
            },
            sort_keys=True,
        )
        onnx.save(features_proto, str(tmp_features))
    except BaseException:
        tmp_features.unlink(missing_ok=True)
        tmp_reuse.unlink(missing_ok=True)
        raise
    os.replace(tmp_reuse, final_reuse)
    os.replace(tmp_features, final_features)
    return SplitResult(final_features, final_reuse, split, channels, stride, diff)
