"""ONNX export: torch and onnxruntime agree (max |diff| <= 1e-4) on random inputs and a real frame."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
import pytest
import torch

from gldt_core.detect import DetectorConfigError, GlobalDetector, LocalDetector
from gldt_core.detect.postprocess import letterbox, rect_input_size, to_blob
from gldt_core.export.dynamic_sides import DYNAMIC_SIDES, make_sides_dynamic
from gldt_core.export.onnx_export import OPSET, example_inputs, export_onnx, torch_vs_onnx
from gldt_core.paths import halmstad_root
from gldt_core.training.models import Detector, ModelSpec

HALMSTAD = halmstad_root()
TINY = dict(channels=(4, 8, 8, 16, 16), depth=1, num_classes=3, reg_max=8)

# Single-threaded: on shared CPUs OpenMP barriers make multi-threaded small ops much slower.
torch.set_num_threads(1)


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Detector, Path]]:
    torch.manual_seed(0)
    out = tmp_path_factory.mktemp("onnx")
    models = {
        "global": Detector(ModelSpec(**TINY, stff_levels=(2, 3, 4), stff_windows=(4, 4, 2))).eval(),
        "local": Detector(
            ModelSpec(**TINY, dual_frame=False, stff_levels=(), stff_windows=(), head_levels=(2, 3))
        ).eval(),
    }
    # Non-trivial BN statistics, as after training, so the check is not only on fresh init.
    for model in models.values():
        for m in model.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                m.running_mean.uniform_(-0.5, 0.5)
                m.running_var.uniform_(0.5, 2.0)
    paths = {}
    for name, model in models.items():
        path = out / f"{name}.onnx"
        size = (128, 96) if name == "global" else (64, 64)
        export_onnx(model, path, *size, {"name": name, "task": name})
        paths[name] = (model, path)
    return paths


def test_global_export_matches_torch_at_several_sizes(exported) -> None:
    model, path = exported["global"]
    proto = onnx.load(str(path))
    assert proto.opset_import[0].version >= 17 and OPSET >= 17
    assert [i.name for i in proto.graph.input] == ["previous", "current"]
    for w, h in ((128, 96), (192, 64)):
        assert torch_vs_onnx(model, path, example_inputs(model, w, h, seed=w)) <= 1e-4


def test_local_export_has_dynamic_batch_and_sides(exported) -> None:
    model, path = exported["local"]
    for batch in (1, 4):
        assert torch_vs_onnx(model, path, example_inputs(model, 64, 64, batch=batch, seed=batch)) <= 1e-4
    for side in (32, 96):  # a smaller and a larger multiple of the card's input_multiple (32)
        assert torch_vs_onnx(model, path, example_inputs(model, side, side, batch=2, seed=side)) <= 1e-4
    assert json.loads(path.with_suffix(".json").read_text())["dynamic"] == DYNAMIC_SIDES


def test_a_fixed_size_local_export_gets_dynamic_sides_with_the_same_outputs(exported, tmp_path: Path) -> None:
    """The shipped local models were exported with a fixed side and their checkpoints are not in
    the repo: ``gldt export --dynamic-sides`` rewrites the declared shape, and the graph then agrees
    with torch at every side, the old one included."""
    model, dynamic = exported["local"]
    proto = onnx.load(str(dynamic))
    for dim, side in zip(proto.graph.input[0].type.tensor_type.shape.dim[2:], (64, 64)):
        dim.ClearField("dim_param")
        dim.dim_value = side  # as the shipped files were: a fixed 64 x 64
    fixed = tmp_path / "fixed.onnx"
    onnx.save(proto, str(fixed))
    fixed.with_suffix(".json").write_text(dynamic.with_suffix(".json").read_text())
    out = tmp_path / "made_dynamic.onnx"
    assert make_sides_dynamic(fixed, out) == 0.0
    for side in (32, 64, 128):
        assert torch_vs_onnx(model, out, example_inputs(model, side, side, batch=2, seed=side)) <= 1e-4
    card = json.loads(out.with_suffix(".json").read_text())
    assert (
        card["dynamic"] == DYNAMIC_SIDES and card["name"] == "made_dynamic" and card["size_bytes"] == out.stat().st_size
    )
    ld = LocalDetector(out, second_stage=None)
    assert (ld.input_side, ld.input_multiple) == (64, 32)
    _, global_path = exported["global"]
    with pytest.raises(ValueError, match="not an exported local detector"):
        make_sides_dynamic(global_path, tmp_path / "global.onnx")
    assert not (tmp_path / "global.onnx").exists()


def test_card_is_written_and_embedded(exported) -> None:
    _, path = exported["global"]
    card = json.loads(path.with_suffix(".json").read_text())
    assert card["inputs"] == ["previous", "current"] and card["strides"] == [4, 8, 16, 32]
    assert card["classes"] == ["drone", "bird", "airplane"] and card["class_ids"] == [1, 2, 3]
    embedded = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
    assert json.loads(embedded["gldt_card"])["input_multiple"] == card["input_multiple"] == 32


def test_runtime_wrappers_load_exported_models(exported) -> None:
    _, gpath = exported["global"]
    _, lpath = exported["local"]
    gd = GlobalDetector(gpath, score_threshold=0.0, second_stage=None)
    dets = gd.detect(np.zeros((100, 150, 3), np.uint8), np.zeros((100, 150, 3), np.uint8))
    assert dets.dtype == np.float32 and dets.shape[1] == 9
    ld = LocalDetector(lpath, second_stage=None)
    assert ld.input_side == 64
    with pytest.raises(DetectorConfigError, match="local detector needs one"):
        LocalDetector(gpath, second_stage=None)


@pytest.mark.skipif(
    not (HALMSTAD / "videos").is_dir(),
    reason=f"needs the real Halmstad clips in {HALMSTAD} (../shared beside the checkout)",
)
def test_export_matches_torch_on_a_real_frame_pair(exported) -> None:
    import cv2

    cap = cv2.VideoCapture(str(HALMSTAD / "videos" / "V_DRONE_004.mp4"))
    frames = [cap.read()[1] for _ in range(2)]
    cap.release()
    model, path = exported["global"]
    w, h = rect_input_size(frames[1].shape[1], frames[1].shape[0], 256, model.spec.input_multiple)
    blobs = [torch.from_numpy(to_blob([letterbox(f, w, h)[0]])) for f in frames]
    assert torch_vs_onnx(model, path, tuple(blobs)) <= 1e-4
    lmodel, lpath = exported["local"]
    crops = torch.from_numpy(
        to_blob([cv2.resize(frames[1][y : y + 300, x : x + 300], (64, 64)) for x, y in ((0, 0), (300, 200))])
    )
    assert torch_vs_onnx(lmodel, lpath, (crops,)) <= 1e-4
