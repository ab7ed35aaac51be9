"""Export a trained checkpoint to ONNX (opset >= 17) plus a JSON model card.

* Global (AM-YOLO): inputs ``previous`` and ``current``, each ``(1, 3, H, W)`` float RGB in [0, 1];
  ``H`` and ``W`` are dynamic (any multiple of the card's ``input_multiple``) so the runtime can feed
  a rectangular input that matches the frame's aspect ratio (e.g. 640x384 for 1080p).
* Local: input ``images`` ``(N, 3, S, S)`` with a dynamic batch ``N`` (all ROIs of a frame at once)
  and dynamic sides: ``S`` any multiple of the card's ``input_multiple`` up to its ``input_size``,
  as small as the frame's ROIs allow (:mod:`gldt_core.export.dynamic_sides`).
* Output ``detections`` ``(B, 4 + nc, A)``: xyxy boxes normalised to the input width/height (multiply
  by ``(W, H, W, H)`` for input pixels) and per-class scores.

The model card is written next to the ONNX file (same stem, ``.json``) *and* embedded in the ONNX
metadata (key ``gldt_card``), so the runtime can check a model against what it expects even when
the JSON file is lost.
"""

from __future__ import annotations

import hashlib
import json
import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch

from gldt_core.detect.session import CARD_KEY
from gldt_core.export.dynamic_sides import DYNAMIC_SIDES
from gldt_core.training.data import CLASS_NAMES
from gldt_core.training.models import Detector

OPSET = 17
#: Model class index -> MOTChallenge class code (1 drone, 2 bird, 3 airplane).
CLASS_IDS = (1, 2, 3)


def _input_names(model: Detector) -> list[str]:
    return ["previous", "current"] if model.spec.dual_frame else ["images"]


def example_inputs(model: Detector, width: int, height: int, batch: int = 1, seed: int = 0) -> tuple[torch.Tensor, ...]:
    g = torch.Generator().manual_seed(seed)
    n = 2 if model.spec.dual_frame else 1
    return tuple(torch.rand(batch, 3, height, width, generator=g) for _ in range(n))


def export_onnx(model: Detector, path: Path, width: int, height: int, card: dict[str, Any]) -> dict[str, Any]:
    """Write ``path`` (ONNX) and ``path.with_suffix('.json')`` (card); returns the completed card."""
    import onnx

    model = model.eval()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    names = _input_names(model)
    if model.spec.dual_frame:
        dynamic = {name: {2: "height", 3: "width"} for name in names}
        dynamic["detections"] = {2: "anchors"}
    else:
        dynamic = {"images": {0: "batch", 2: "height", 3: "width"}, "detections": {0: "batch", 2: "anchors"}}
    tmp = path.with_name(path.name + ".tmp")
    with torch.no_grad(), warnings.catch_warnings():
        # Shape checks in forward() run on concrete sizes while tracing; the exported graph keeps
        # dynamic sizes (verified against torch at several sizes by the tests), so these are noise.
        warnings.simplefilter("ignore", torch.jit.TracerWarning)
        torch.onnx.export(
            model,
            example_inputs(model, width, height),
            str(tmp),
            input_names=names,
            output_names=["detections"],
            dynamic_axes=dynamic,
            opset_version=OPSET,
            do_constant_folding=True,
            dynamo=False,
        )
    proto = onnx.load(str(tmp))
    onnx.checker.check_model(proto)
    graph_inputs = [i.name for i in proto.graph.input]
    if graph_inputs != names:
        # An unused input (the no-STFF ablation ignores `previous`) is pruned by the exporter; the
        # runtime reads the actual inputs, so record them rather than fail.
        names = graph_inputs
    card = dict(card)
    card.update(
        {
            "format": "onnx",
            "opset": OPSET,
            "inputs": names,
            "input_layout": "NCHW float32 RGB in [0, 1]",
            "output": (
                "detections (B, 4 + num_classes, anchors): "
                "x1, y1, x2, y2 normalised to the input width/height, then per-class scores"
            ),
            "box_format": "xyxy_normalized",
            "input_size": [width, height],
            "input_multiple": model.spec.input_multiple,
            "dynamic": "height/width" if model.spec.dual_frame else DYNAMIC_SIDES,
            "strides": list(model.spec.strides),
            "classes": list(CLASS_NAMES[: model.spec.num_classes]),
            "class_ids": list(CLASS_IDS[: model.spec.num_classes]),
            "spec": model.spec.to_dict(),
        }
    )
    meta = proto.metadata_props.add()
    meta.key = CARD_KEY
    meta.value = json.dumps(card, sort_keys=True)
    onnx.save(proto, str(tmp))
    os.replace(tmp, path)
    card["sha256"] = hashlib.sha256(path.read_bytes()).hexdigest()
    card["size_bytes"] = path.stat().st_size
    card_path = path.with_suffix(".json")
    tmp_card = card_path.with_name(card_path.name + ".tmp")
    tmp_card.write_text(json.dumps(card, indent=2, sort_keys=True) + "\n")
    os.replace(tmp_card, card_path)
    return card


def torch_vs_onnx(model: Detector, onnx_path: Path, inputs: tuple[torch.Tensor, ...]) -> float:
    """Max absolute difference between torch and onnxruntime outputs on ``inputs``."""
    import onnxruntime as ort

    session = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"])
    names = [i.name for i in session.get_inputs()]
    feed_all = dict(zip(_input_names(model), (x.numpy() for x in inputs)))
    feed = {name: feed_all[name] for name in names}
    (ort_out,) = session.run(["detections"], feed)
    with torch.no_grad():
        torch_out = model.eval()(*inputs).numpy()
    if ort_out.shape != torch_out.shape:
        raise ValueError(f"shape mismatch: onnxruntime {ort_out.shape} vs torch {torch_out.shape}")
    return float(np.abs(ort_out - torch_out).max())
