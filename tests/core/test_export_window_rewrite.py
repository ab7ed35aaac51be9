"""`gldt export --rewrite-windows`: 6-D STFF window permutes rewritten as 4-D ones, outputs unchanged."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper

from gldt_core.detect.shipped import MODELS_DIR
from gldt_core.export import window_rewrite
from gldt_core.export.window_rewrite import PARTITION_PERM, REVERSE_PERM, rewrite_model_file, rewrite_window_transposes

WINDOW = 4


def _old_style_windows_model() -> onnx.ModelProto:
    """NCHW -> window tokens -> NCHW through 6-D permutes with shapes computed at run time,
    the way torch exported STFF before its 4-D window_partition."""
    nodes = []
    consts = {}

    def const(name: str, values: list[int]) -> str:
        if name not in consts:
            nodes.append(
                helper.make_node(
                    "Constant",
                    [],
                    [name],
                    value=helper.make_tensor(name + "_v", TensorProto.INT64, [len(values)], values),
                )
            )
            consts[name] = name
        return name

    def dim(i: int) -> str:
        out = f"dim{i}"
        nodes.append(helper.make_node("Gather", ["shape", const(f"i{i}", [i])], [out], axis=0))
        return out

    nodes.append(helper.make_node("Shape", ["x"], ["shape"]))
    n, c, h, w = dim(0), dim(1), dim(2), dim(3)
    s = const("s", [WINDOW])
    nodes.append(helper.make_node("Div", [h, s], ["nh"]))
    nodes.append(helper.make_node("Div", [w, s], ["nw"]))
    nodes.append(helper.make_node("Concat", [n, c, "nh", s, "nw", s], ["shape6"], axis=0))
    nodes.append(helper.make_node("Reshape", ["x", "shape6"], ["x6"]))
    nodes.append(helper.make_node("Transpose", ["x6"], ["t6"], perm=list(PARTITION_PERM)))
    nodes.append(
        helper.make_node("Concat", [const("m1", [-1]), const("ss", [WINDOW * WINDOW]), c], ["tok_shape"], axis=0)
    )
    nodes.append(helper.make_node("Reshape", ["t6", "tok_shape"], ["tokens"]))
    nodes.append(helper.make_node("Concat", [n, "nh", "nw", s, s, c], ["back6"], axis=0))
    nodes.append(helper.make_node("Reshape", ["tokens", "back6"], ["b6"]))
    nodes.append(helper.make_node("Transpose", ["b6"], ["r6"], perm=list(REVERSE_PERM)))
    nodes.append(helper.make_node("Reshape", ["r6", "shape"], ["y"]))
    graph = helper.make_graph(
        nodes,
        "windows",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, ["n", "c", "h", "w"])],
        [
            helper.make_tensor_value_info("tokens", TensorProto.FLOAT, ["windows", "pixels", "c"]),
            helper.make_tensor_value_info("y", TensorProto.FLOAT, ["n", "c", "h", "w"]),
        ],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    return model


def _run(model: onnx.ModelProto, x: np.ndarray) -> list[np.ndarray]:
    session = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    return session.run(None, {"x": x})


def _six_dim_transposes(model: onnx.ModelProto) -> int:
    return sum(
        1
        for node in model.graph.node
        if node.op_type == "Transpose"
        and tuple(next(a.ints for a in node.attribute if a.name == "perm")) in (PARTITION_PERM, REVERSE_PERM)
    )


def test_rewrite_keeps_tokens_and_round_trip_identical_at_every_size() -> None:
    original = _old_style_windows_model()
    rewritten = onnx.ModelProto()
    rewritten.CopyFrom(original)
    assert rewrite_window_transposes(rewritten) == 2
    onnx.checker.check_model(rewritten)
    assert _six_dim_transposes(rewritten) == 0
    # The 6-D Reshapes feeding the replaced transposes are gone, not left dangling.
    assert not any(node.op_type == "Reshape" and node.output[0] in ("x6", "b6") for node in rewritten.graph.node)
    rng = np.random.default_rng(0)
    for shape in [(1, 3, 8, 12), (2, 5, 16, 4), (1, 16, 96, 160)]:
        x = rng.standard_normal(shape).astype(np.float32)
        tokens_before, y_before = _run(original, x)
        tokens_after, y_after = _run(rewritten, x)
        assert np.array_equal(tokens_after, tokens_before)
        assert np.array_equal(y_after, x) and np.array_equal(y_before, x)
        # Token 1 of window 0 is the second pixel of the top-left window's first row.
        assert np.array_equal(tokens_after[0, 1], x[0, :, 0, 1])


def test_a_model_without_the_pattern_is_left_alone() -> None:
    path = MODELS_DIR / "local_p2.onnx"
    model = onnx.load(str(path))
    before = [node.name for node in model.graph.node]
    assert rewrite_window_transposes(model) == 0
    assert [node.name for node in model.graph.node] == before


@pytest.mark.parametrize("name", ["global_amyolo", "global_amyolo_balanced"])
def test_shipped_am_yolo_models_hold_no_six_dim_window_permutes(name: str) -> None:
    model = onnx.load(str(MODELS_DIR / f"{name}.onnx"))
    # Exported since training/stff.py writes 4-D window permutes, or an older export rewritten.
    assert _six_dim_transposes(model) == 0


def test_rewrite_file_writes_model_and_card(tmp_path: Path) -> None:
    source = tmp_path / "old.onnx"
    onnx.save(_old_style_windows_model(), str(source))
    source.with_suffix(".json").write_text(json.dumps({"name": "old", "input_size": [8, 8]}))
    out = tmp_path / "new.onnx"
    count, diff = rewrite_model_file(source, out, sizes=[(8, 8), (12, 4)])
    assert (count, diff) == (2, 0.0)
    card = json.loads(out.with_suffix(".json").read_text())
    assert card["name"] == "new" and card["size_bytes"] == out.stat().st_size and len(card["sha256"]) == 64


def test_rewrite_file_refuses_a_graph_whose_outputs_change(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    source = tmp_path / "old.onnx"
    onnx.save(_old_style_windows_model(), str(source))

    def wrong_chain(build, data, shape6, output):  # tokens in the wrong order: windows not cut at all
        build.node("Reshape", [data, build.dims(shape6, list(PARTITION_PERM))], output=output)

    monkeypatch.setattr(window_rewrite, "_partition_chain", wrong_chain)
    out = tmp_path / "new.onnx"
    with pytest.raises(ValueError, match="changed its outputs"):
        rewrite_model_file(source, out, sizes=[(8, 8)])
    assert not out.exists() and not out.with_name("new.onnx.tmp").exists()


def test_cli_rejects_a_checkpoint_and_a_missing_model(tmp_path: Path) -> None:
    def gldt(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "gldt_core", "export", *args], capture_output=True, text=True)

    result = gldt(str(tmp_path / "last.pt"), "--rewrite-windows", "--out", str(tmp_path / "x.onnx"))
    assert result.returncode != 0 and "rewrites an exported .onnx" in result.stderr
    result = gldt(str(tmp_path / "missing.onnx"), "--rewrite-windows", "--out", str(tmp_path / "x.onnx"))
    assert result.returncode != 0 and "model not found" in result.stderr and "missing.onnx" in result.stderr


def test_static_shapes_and_shared_reshapes_are_handled() -> None:
    """A shape given as an initializer and a 6-D Reshape read by a second node too: the same
    outputs, and the shared Reshape stays."""
    shape6 = [1, 2, 2, WINDOW, 3, WINDOW]
    nodes = [
        helper.make_node("Reshape", ["x", "shape6"], ["x6"]),
        helper.make_node("Transpose", ["x6"], ["t6"], name="cut", perm=list(PARTITION_PERM)),
        helper.make_node("Identity", ["x6"], ["x6_copy"]),  # a second reader of the 6-D view
        helper.make_node("Reshape", ["t6", "back6"], ["b6"]),
        helper.make_node("Transpose", ["b6"], ["y6"], name="paste", perm=list(REVERSE_PERM)),
    ]
    graph = helper.make_graph(
        nodes,
        "static",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 2, 2 * WINDOW, 3 * WINDOW])],
        [
            helper.make_tensor_value_info("y6", TensorProto.FLOAT, shape6),
            helper.make_tensor_value_info("x6_copy", TensorProto.FLOAT, shape6),
            helper.make_tensor_value_info("t6", TensorProto.FLOAT, [1, 2, 3, WINDOW, WINDOW, 2]),
        ],
        initializer=[
            helper.make_tensor("shape6", TensorProto.INT64, [6], shape6),
            helper.make_tensor("back6", TensorProto.INT64, [6], [1, 2, 3, WINDOW, WINDOW, 2]),
        ],
    )
    original = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    original.ir_version = 8
    rewritten = onnx.ModelProto()
    rewritten.CopyFrom(original)
    assert rewrite_window_transposes(rewritten) == 2
    onnx.checker.check_model(rewritten)
    assert any(node.output[0] == "x6" for node in rewritten.graph.node)  # still read by Identity
    assert not any(node.output[0] == "b6" and node.op_type == "Reshape" for node in rewritten.graph.node)
    x = np.random.default_rng(1).standard_normal((1, 2, 2 * WINDOW, 3 * WINDOW)).astype(np.float32)
    before = ort.InferenceSession(original.SerializeToString(), providers=["CPUExecutionProvider"]).run(None, {"x": x})
    after = ort.InferenceSession(rewritten.SerializeToString(), providers=["CPUExecutionProvider"]).run(None, {"x": x})
    for a, b in zip(before, after):
        assert np.array_equal(a, b)


def test_nan_where_the_original_had_numbers_is_an_infinite_difference(tmp_path: Path) -> None:
    def model(op: str) -> Path:
        nodes = [helper.make_node("Sub", ["x", "x"], ["zero"]), helper.make_node(op, ["zero", "zero"], ["y"])]
        graph = helper.make_graph(
            nodes,
            op,
            [helper.make_tensor_value_info("x", TensorProto.FLOAT, ["n", "c", "h", "w"])],
            [helper.make_tensor_value_info("y", TensorProto.FLOAT, ["n", "c", "h", "w"])],
        )
        proto = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
        proto.ir_version = 8
        path = tmp_path / f"{op}.onnx"
        onnx.save(proto, str(path))
        return path

    zeros, nans = model("Add"), model("Div")  # 0 + 0 against 0 / 0
    assert window_rewrite.compare_models(zeros, nans, [(4, 4)]) == float("inf")
    assert window_rewrite.compare_models(nans, nans, [(4, 4)]) == 0.0
