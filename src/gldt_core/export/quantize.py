"""Static int8 (QDQ) quantization of an exported detector with onnxruntime (no torch).

Calibration uses frames of the Halmstad *training* clips only (never the held-out ones), so the
accuracy cost can be measured honestly with ``gldt bench detection --local-model/--global-model``.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from gldt_core.detect.postprocess import letterbox, rect_input_size, to_blob
from gldt_core.detect.session import read_card


def calibration_frames(root: Path | str, count: int, seed: int = 0) -> Iterator[np.ndarray]:
    """``count`` (previous, current)-free single BGR frames from training clips, spread over clips."""
    import cv2

    from gldt_core.eval.halmstad_split import halmstad_split

    clips = halmstad_split(root)["train"]
    rng = np.random.default_rng(seed)
    for clip in rng.choice(clips, size=min(count, len(clips)), replace=False):
        cap = cv2.VideoCapture(str(Path(root) / "videos" / f"{clip}.mp4"))
        cap.set(cv2.CAP_PROP_POS_FRAMES, int(rng.integers(0, 250)))
        ok, frame = cap.read()
        cap.release()
        if ok:
            yield frame


def quantize_model(model: Path | str, out: Path | str, root: Path | str, count: int = 32) -> Path:
    """Write an int8 QDQ copy of ``model`` to ``out`` (card copied with a ``quantized`` note)."""
    import onnxruntime as ort
    from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static

    model, out = Path(model), Path(out)
    if not model.is_file():
        raise FileNotFoundError(f"model not found: {model}")
    session = ort.InferenceSession(str(model), providers=["CPUExecutionProvider"])
    inputs = session.get_inputs()
    card = read_card(session, model)
    # A local model (its card says so; without a card, one input of a fixed square side) gets
    # ROI crops at its full input side, a global one whole frames.
    local_side = inputs[0].shape[2] if isinstance(inputs[0].shape[2], int) else int(card.get("input_size", [256])[0])
    local = card["task"] == "local" if "task" in card else len(inputs) == 1 and isinstance(inputs[0].shape[2], int)
    feeds = []
    for frame in calibration_frames(root, count):
        if local:
            side = local_side
            h, w = frame.shape[:2]
            crop = frame[max(0, h // 2 - 150) : h // 2 + 150, max(0, w // 2 - 150) : w // 2 + 150]
            feeds.append({inputs[0].name: to_blob([letterbox(crop, side, side)[0]])})
        else:
            w, h = rect_input_size(frame.shape[1], frame.shape[0], 640, 64)
            blob = to_blob([letterbox(frame, w, h)[0]])
            feeds.append({i.name: blob for i in inputs})
    if not feeds:
        raise ValueError(f"no calibration frames could be read under {root}")

    class Reader(CalibrationDataReader):
        def __init__(self) -> None:
            self.items = iter(feeds)

        def get_next(self):  # noqa: ANN201 - onnxruntime's interface
            return next(self.items, None)

    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    quantize_static(
        str(model),
        str(tmp),
        Reader(),
        quant_format=QuantFormat.QDQ,
        per_channel=True,
        activation_type=QuantType.QUInt8,
        weight_type=QuantType.QInt8,
    )
    tmp.replace(out)
    card_path = model.with_suffix(".json")
    if card_path.is_file():
        card = json.loads(card_path.read_text())
        card.pop("benchmark", None)
        card.update(
            {
                "name": out.stem,
                "quantized": f"static int8 QDQ (onnxruntime), calibrated on {len(feeds)} training-clip frames",
                "size_bytes": out.stat().st_size,
            }
        )
        out.with_suffix(".json").write_text(json.dumps(card, indent=2, sort_keys=True) + "\n")
    return out
