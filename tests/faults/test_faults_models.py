"""Model faults: a missing, truncated or wrong-shaped ONNX file fails at start with one line.

``gldt_core.detect.session`` documents that an unusable model raises
:class:`~gldt_core.detect.DetectorConfigError` (a ``ValueError``) at construction, naming the
file and what was expected, instead of failing on the first frame. The models here are built
in the test with the ``onnx`` helper API (tiny graphs with the wrappers' input/output layout),
so the test does not depend on the shipped weights.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from support import REPO_ROOT

onnx = pytest.importorskip("onnx", reason="the onnx package builds the test models (pip install onnx)")
from onnx import TensorProto, helper  # noqa: E402

from gldt_core.detect import DetectorConfigError, GlobalDetector, LocalDetector  # noqa: E402

OPSET = 13


def _zeros_output(inputs: list[str], out_shape: tuple, batch: bool, base: np.ndarray | None = None) -> list:
    """Nodes computing zeros of ``out_shape`` that still read every input (no unused input).

    Without a batch axis every input is summed to a scalar; with one (``batch``) each input is
    averaged per sample, ``(N,)``, reshaped to ``(N, 1, 1)`` and broadcast onto the output."""
    nodes, terms = [], []
    for name in inputs:
        if batch:
            nodes.append(helper.make_node("ReduceMean", [name], [f"{name}_r"], axes=[1, 2, 3], keepdims=0))
        else:
            nodes.append(helper.make_node("ReduceSum", [name], [f"{name}_r"], keepdims=0))
        terms.append(f"{name}_r")
    static = [1 if isinstance(d, str) else d for d in out_shape]
    nodes.append(
        helper.make_node("Constant", [], ["zero"], value=helper.make_tensor("z", TensorProto.FLOAT, [], [0.0]))
    )
    values = np.zeros(int(np.prod(static)), np.float32) if base is None else np.asarray(base, np.float32).reshape(-1)
    nodes.append(
        helper.make_node(
            "Constant", [], ["base"], value=helper.make_tensor("b", TensorProto.FLOAT, static, values.tolist())
        )
    )
    total = terms[0]
    for k, term in enumerate(terms[1:]):
        nodes.append(helper.make_node("Add", [total, term], [f"acc{k}"]))
        total = f"acc{k}"
    nodes.append(helper.make_node("Mul", [total, "zero"], ["nothing"]))
    if batch:
        nodes.append(
            helper.make_node(
                "Constant",
                [],
                ["shape"],
                value=helper.make_tensor("s", TensorProto.INT64, [len(static)], [-1] + [1] * (len(static) - 1)),
            )
        )
        nodes.append(helper.make_node("Reshape", ["nothing", "shape"], ["nothing_b"]))
        nodes.append(helper.make_node("Add", ["base", "nothing_b"], ["output"]))
    else:
        nodes.append(helper.make_node("Add", ["base", "nothing"], ["output"]))
    return nodes


def _save(
    path: Path, inputs: list[tuple[str, list]], output_shape: list, batch: bool = False, base: np.ndarray | None = None
) -> Path:
    graph_inputs = [helper.make_tensor_value_info(name, TensorProto.FLOAT, shape) for name, shape in inputs]
    output = helper.make_tensor_value_info("output", TensorProto.FLOAT, output_shape)
    nodes = _zeros_output([name for name, _ in inputs], tuple(output_shape), batch, base)
    graph = helper.make_graph(nodes, "tiny", graph_inputs, [output])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def global_model(path: Path, channels: int = 3, n_inputs: int = 2, output_shape=(1, 6, 4)) -> Path:
    names = ["previous", "current", "extra"][:n_inputs]
    return _save(path, [(n, [1, channels, "H", "W"]) for n in names], list(output_shape))


def constant_global_model(path: Path, anchors: list[list[float]]) -> Path:
    """A global model that outputs the same anchors on every frame: ``[x1, y1, x2, y2, drone, bird]``
    with boxes normalised to the network input (the exported models' format)."""
    values = np.asarray(anchors, np.float32).T[None]  # (1, 6, A)
    return _save(path, [(n, [1, 3, "H", "W"]) for n in ("previous", "current")], list(values.shape), base=values)


def local_model(path: Path, height=64, width=64, n_inputs: int = 1, output_shape=("N", 6, 4)) -> Path:
    names = ["crops", "extra"][:n_inputs]
    return _save(path, [(n, ["N", 3, height, width]) for n in names], list(output_shape), batch=True)


def _one_line(error: BaseException) -> str:
    text = str(error)
    assert "\n" not in text.strip(), f"not one line: {text!r}"
    assert "Traceback" not in text
    return text


# --------------------------------------------------------------------------- the builders are right
def test_tiny_valid_models_load_and_run(tmp_path: Path) -> None:
    gd = GlobalDetector(global_model(tmp_path / "global.onnx"), second_stage=None)
    frame = np.zeros((120, 160, 3), np.uint8)
    assert gd.detect(frame, frame).shape == (0, 9)
    ld = LocalDetector(local_model(tmp_path / "local.onnx"), second_stage=None)
    assert ld.input_side == 64
    assert ld.detect_rois(frame, np.array([[0, 0, 64, 64], [50, 40, 150, 110]])).shape == (0, 10)


# --------------------------------------------------------------------------- missing and truncated
@pytest.mark.parametrize("cls", [GlobalDetector, LocalDetector])
def test_missing_model_names_the_file(tmp_path: Path, cls) -> None:
    path = tmp_path / "nowhere" / "model.onnx"
    with pytest.raises(DetectorConfigError) as info:
        cls(path)
    text = _one_line(info.value)
    assert str(path) in text and "not found" in text


@pytest.mark.parametrize(
    "cls, build", [(GlobalDetector, global_model), (LocalDetector, local_model)], ids=["global", "local"]
)
@pytest.mark.parametrize("keep", [0.0, 0.02, 0.5, 0.95])
def test_truncated_model_fails_at_construction_naming_the_file(tmp_path: Path, cls, build, keep: float) -> None:
    valid = build(tmp_path / "valid.onnx").read_bytes()
    path = tmp_path / f"truncated_{int(keep * 100)}.onnx"
    path.write_bytes(valid[: int(len(valid) * keep)])
    with pytest.raises(DetectorConfigError) as info:
        cls(path)
    text = _one_line(info.value)
    assert str(path) in text


@pytest.mark.parametrize(
    "cls, build, shape",
    [(GlobalDetector, global_model, "(1, 3, H, W)"), (LocalDetector, local_model, "(N, 3, S, S)")],
    ids=["global", "local"],
)
@pytest.mark.parametrize("fault", ["missing", "truncated"])
def test_missing_or_truncated_model_message_also_names_the_expected_shape(
    tmp_path: Path, cls, build, shape: str, fault: str
) -> None:
    path = tmp_path / "model.onnx"
    if fault == "truncated":
        path.write_bytes(build(tmp_path / "valid.onnx").read_bytes()[:100])
    with pytest.raises(DetectorConfigError) as info:
        cls(path)
    text = _one_line(info.value)
    assert str(path) in text and shape in text


def test_a_non_onnx_file_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "weights.onnx"
    path.write_text("this is a PyTorch checkpoint, not ONNX\n")
    with pytest.raises(DetectorConfigError) as info:
        GlobalDetector(path)
    assert str(path) in _one_line(info.value)


# --------------------------------------------------------------------------- wrong shapes
@pytest.mark.parametrize(
    "kwargs, expected",
    [
        ({"channels": 1}, "(1, 3, H, W)"),
        ({"channels": 4}, "(1, 3, H, W)"),
        ({"n_inputs": 3}, "(1, 3, H, W)"),
        ({"output_shape": (1, 6)}, "(batch, 4 + num_classes, anchors)"),
        ({"output_shape": (1, 4, 10)}, "(batch, 4 + num_classes, anchors)"),
    ],
    ids=["one_channel", "four_channels", "three_inputs", "output_rank_2", "no_class_rows"],
)
def test_wrong_shaped_global_model_names_file_and_expected_shape(tmp_path: Path, kwargs: dict, expected: str) -> None:
    path = global_model(tmp_path / "wrong_global.onnx", **kwargs)
    with pytest.raises(DetectorConfigError) as info:
        GlobalDetector(path)
    text = _one_line(info.value)
    assert str(path) in text and expected in text


@pytest.mark.parametrize(
    "kwargs, expected",
    [
        ({"width": 32}, "(N, 3, S, S)"),
        ({"height": "S", "width": "S"}, "no square input_size and input_multiple"),
        ({"n_inputs": 2}, "(N, 3, S, S)"),
        ({"output_shape": ("N", 3, 4)}, "(batch, 4 + num_classes, anchors)"),
    ],
    ids=["not_square", "dynamic_sides_without_a_card", "two_inputs", "no_class_rows"],
)
def test_wrong_shaped_local_model_names_file_and_expected_shape(tmp_path: Path, kwargs: dict, expected: str) -> None:
    path = local_model(tmp_path / "wrong_local.onnx", **kwargs)
    with pytest.raises(DetectorConfigError) as info:
        LocalDetector(path)
    text = _one_line(info.value)
    assert str(path) in text and expected in text


# --------------------------------------------------------------------------- through the CLI
def _tiny_video(path: Path) -> Path:
    import cv2

    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (64, 48))
    for k in range(3):
        writer.write(np.full((48, 64, 3), 40 * k, np.uint8))
    writer.release()
    assert path.is_file() and path.stat().st_size > 0
    return path


@pytest.mark.parametrize("fault", ["missing", "truncated", "one_channel"])
def test_gldt_detect_with_a_bad_model_exits_2_with_one_line(tmp_path: Path, capsys, fault: str) -> None:
    from gldt_core.cli import main

    model = tmp_path / f"{fault}.onnx"
    if fault == "truncated":
        model.write_bytes(global_model(tmp_path / "ok.onnx").read_bytes()[:200])
    elif fault == "one_channel":
        global_model(model, channels=1)
    video = _tiny_video(tmp_path / "clip.mp4")
    out = tmp_path / "dets.txt"
    code = main(["detect", "--video", str(video), "--model", str(model), "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and f"{fault}.onnx" in err and "Traceback" not in err
    assert not out.exists()


@pytest.mark.parametrize("fault", ["missing", "truncated", "three_inputs"])
def test_gldt_run_with_a_bad_configured_model_exits_2_before_any_frame(tmp_path: Path, capsys, fault: str) -> None:
    from gldt_core.cli import main

    model = tmp_path / f"{fault}.onnx"
    if fault == "truncated":
        model.write_bytes(global_model(tmp_path / "ok.onnx").read_bytes()[:300])
    elif fault == "three_inputs":
        global_model(model, n_inputs=3)
    local = local_model(tmp_path / "local.onnx")
    config = tmp_path / "bad_model.yaml"
    config.write_text(f"detector:\n  global_model: {model}\n  local_model: {local}\n")
    out = tmp_path / "tracks.txt"
    code = main(
        ["run", "--video", "synth:seed=1,frames=2", "--config", str(config), "--out", str(out), "--no-progress"]
    )
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and f"{fault}.onnx" in err and "Traceback" not in err
    assert not out.exists()


def test_python_m_gldt_core_run_with_a_truncated_model_prints_no_traceback(tmp_path: Path) -> None:
    """The real process: nothing but our one line on stderr (no onnxruntime log spew either)."""
    model = tmp_path / "cut.onnx"
    model.write_bytes(global_model(tmp_path / "ok.onnx").read_bytes()[:150])
    config = tmp_path / "cfg.yaml"
    config.write_text(f"detector:\n  global_model: {model}\nscheduler:\n  local_enabled: false\n")
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "gldt_core",
            "run",
            "--video",
            "synth:seed=1,frames=2",
            "--config",
            str(config),
            "--out",
            str(tmp_path / "t.txt"),
            "--no-progress",
        ],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=REPO_ROOT,
    )
    assert result.returncode == 2, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "cut.onnx" in lines[0], result.stderr
    assert "Traceback" not in result.stderr and result.stdout == ""


# --------------------------------------------------------------------------- degenerate model output
@pytest.mark.parametrize(
    "anchor",
    [
        [0.40, 0.000, 0.45, 0.020, 0.9, 0.0],  # inside the letterbox padding band: zero height once clipped
        [1.10, 0.300, 1.20, 0.400, 0.9, 0.0],  # right of the frame: zero width once clipped
        [0.50, 0.300, 0.40, 0.400, 0.9, 0.0],  # inverted x
        [float("nan"), 0.3, 0.40, 0.400, 0.9, 0.0],  # NaN coordinate with a confident score
    ],
    ids=["padding_band", "outside_frame", "inverted", "nan_box"],
)
def test_degenerate_boxes_from_a_real_model_never_stop_the_pipeline(tmp_path: Path, anchor: list[float]) -> None:
    from gldt_core.schedule import SchedulerConfig
    from gldt_core.system import GLDTSystem, SystemConfig

    good = [0.30, 0.30, 0.34, 0.34, 0.9, 0.0]  # a real target, 6x5 px in a 160x120 frame
    detector = GlobalDetector(
        constant_global_model(tmp_path / "odd.onnx", [good, anchor]), score_threshold=0.5, second_stage=None
    )
    pipeline = GLDTSystem(SystemConfig(scheduler=SchedulerConfig(local_enabled=False)), global_detector=detector)
    frame = np.zeros((120, 160, 3), np.uint8)
    for k in range(5):
        tracks = pipeline.process(frame, k / 30.0)
    assert len(tracks) == 1, "the valid detection must still be tracked"
    fed = pipeline.state.detections
    assert np.all(np.isfinite(fed)) and np.all(fed[:, 2] > fed[:, 0]) and np.all(fed[:, 3] > fed[:, 1])


def test_a_nan_box_never_suppresses_a_valid_detection(tmp_path: Path) -> None:
    good = [0.30, 0.30, 0.34, 0.34, 0.90, 0.0]
    nan_box = [float("nan"), 0.30, 0.40, 0.40, 0.95, 0.0]
    detector = GlobalDetector(
        constant_global_model(tmp_path / "nan_first.onnx", [good, nan_box]), score_threshold=0.5, second_stage=None
    )
    frame = np.zeros((120, 160, 3), np.uint8)
    dets = detector.detect(frame, frame)
    assert np.all(np.isfinite(dets))
    assert len(dets) == 1, f"the valid detection was lost: {dets.tolist()}"
