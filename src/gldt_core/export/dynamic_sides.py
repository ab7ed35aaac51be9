"""Give an exported local model dynamic input sides, so the runtime feeds it no more padding than
its ROIs need.

The local detector scales each ROI by the card's ``input_size / roi_side`` and pads it to a square.
On a 640x512 frame the ROI is 142 px (Table I's 300 px of a 1080-line frame, scaled), which fills
121 px of the 256 px input: three quarters of the model's work went on padding. With dynamic
sides :class:`gldt_core.detect.local_detector.LocalDetector` picks the smallest multiple of the
card's ``input_multiple`` that holds the batch's ROIs (128 there, 256 on a 1080p frame).

Local models exported since this module exist have dynamic sides already
(:func:`gldt_core.export.onnx_export.export_onnx`). The shipped ones were trained and their
checkpoints are not in the repo, so :func:`make_sides_dynamic` rewrites the graph's declared input
shape instead: the network computes its anchor grids from the input's shape at run time, so
nothing else changes. It refuses to write a model whose outputs at the original size differ from
the original's, or that does not run at a smaller size with the anchors that size must have.

Needs the ``onnx`` package (the ``test``/``train`` extras), not torch; the run time never calls it.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from gldt_core.detect.session import CARD_KEY
from gldt_core.export.window_rewrite import compare_models, update_sidecar_card, write_checked_model

#: Largest output difference accepted between the original and the rewritten graph.
MAX_ABS_DIFF = 1e-6
#: How the card's ``dynamic`` field names the dynamic dimensions of such a model.
DYNAMIC_SIDES = "batch/height/width"


def make_sides_dynamic(model: Path | str, out: Path | str) -> float:
    """Write ``model`` (an exported local detector) with dynamic input height and width to ``out``,
    its card (embedded and next to it) saying so; returns the largest output difference from the
    original at its own size. ``ValueError`` (nothing written) for another kind of model, or for
    outputs that differ or a smaller size that does not run."""
    import onnx

    model, out = Path(model), Path(out)
    if not model.is_file():
        raise FileNotFoundError(f"model not found: {model}")
    proto = onnx.load(str(model))
    card = json.loads({p.key: p.value for p in proto.metadata_props}.get(CARD_KEY, "{}"))
    inputs = list(proto.graph.input)
    if card.get("task") != "local" or len(inputs) != 1 or len(inputs[0].type.tensor_type.shape.dim) != 4:
        raise ValueError(f"{model}: not an exported local detector (one (N, 3, S, S) input and a local card)")
    dims = inputs[0].type.tensor_type.shape.dim
    side, multiple, strides = dims[2].dim_value, int(card.get("input_multiple", 0)), card.get("strides", [])
    if not side or dims[3].dim_value != side or multiple < 1 or side % multiple or not strides:
        raise ValueError(f"{model}: expected a fixed square input that is a multiple of the card's input_multiple")
    dims[2].ClearField("dim_value")
    dims[2].dim_param = "height"
    dims[3].ClearField("dim_value")
    dims[3].dim_param = "width"
    for output in proto.graph.output:  # detections (N, 4 + classes, anchors): the anchors follow the sides
        anchors_dim = output.type.tensor_type.shape.dim[2]
        anchors_dim.ClearField("dim_value")
        anchors_dim.dim_param = "anchors"
    del proto.graph.value_info[:]  # shapes inferred at the fixed size would pin it again
    card["dynamic"] = DYNAMIC_SIDES
    for prop in proto.metadata_props:
        if prop.key == CARD_KEY:
            prop.value = json.dumps(card, sort_keys=True)
    onnx.checker.check_model(proto)

    def same_outputs_and_anchors(candidate: Path) -> float:
        diff = compare_models(model, candidate, [(side, side)])
        if diff > MAX_ABS_DIFF:
            raise ValueError(f"{model}: dynamic sides changed its outputs by {diff:.3g}; nothing written")
        smaller = max(multiple, side // 2 // multiple * multiple)
        anchors = _anchors(candidate, smaller)
        expected = sum((smaller // int(stride)) ** 2 for stride in strides)
        if anchors != expected:
            raise ValueError(
                f"{model}: at {smaller} px it gave {anchors} anchors, expected {expected}; nothing written"
            )
        return diff

    diff = write_checked_model(proto, model, out, same_outputs_and_anchors)
    update_sidecar_card(model, out, {"dynamic": DYNAMIC_SIDES}, card)
    return diff


def _anchors(path: Path, side: int) -> int:
    """The anchor count of the model at ``path`` on one ``side`` x ``side`` input."""
    import onnxruntime as ort

    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    name = session.get_inputs()[0].name
    (detections,) = session.run(None, {name: np.zeros((1, 3, side, side), np.float32)})
    return int(detections.shape[2])
