"""Rewrite the 6-D window permutes of an older AM-YOLO export into 4-D ones (same outputs, faster).

STFF cuts each feature map into S x S windows and puts them back afterwards. Exports made before
:func:`gldt_core.training.stff.window_partition` took its 4-D form hold each of these as one
``Reshape -> Transpose`` over a 6-D tensor, and onnxruntime's CPU Transpose moves a 6-D permute
element by element: at the P2 level (the largest feature map) that can cost more than the
attention it feeds (docs/experiment-log.md). The same permutation is an NHWC transpose plus a swap
of contiguous ``S*C`` blocks, both 4-D, which onnxruntime does at memory speed.

The shipped models were trained, and their checkpoints are not in the repo, so instead of
re-exporting from torch this rewrites the graph itself: each matched ``Transpose`` is replaced by
the 4-D chain, and the shapes it needs are gathered from the original ``Reshape``'s own shape
input, so dynamic input sizes keep working. That assumes the shape entries are the actual sizes
(no ``0`` = "copy" and no ``-1`` = "infer"), as torch's exporter writes them for these windows;
:func:`rewrite_model_file` runs the old and the new graph on the same inputs and refuses to write
a model whose outputs differ or that fails to run.

Needs the ``onnx`` package (the ``test``/``train`` extras), not torch; the run time never calls it.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

#: ``(B, C, nH, S, nW, S) -> (B, nH, nW, S, S, C)``: cutting NCHW features into window tokens.
PARTITION_PERM = (0, 2, 4, 3, 5, 1)
#: ``(B, nH, nW, S, S, C) -> (B, C, nH, S, nW, S)``: putting window tokens back as NCHW.
REVERSE_PERM = (0, 5, 1, 3, 2, 4)
#: Largest output difference accepted between the original and the rewritten graph.
MAX_ABS_DIFF = 1e-5


def _perm(node: Any) -> tuple[int, ...] | None:
    for attribute in node.attribute:
        if attribute.name == "perm":
            return tuple(attribute.ints)
    return None


class _Builder:
    """Makes uniquely named nodes next to one original node."""

    def __init__(self, prefix: str):
        self.prefix = prefix
        self.nodes: list[Any] = []
        self.count = 0

    def _name(self, what: str) -> str:
        self.count += 1
        return f"{self.prefix}/window4d_{what}_{self.count}"

    def node(self, op: str, inputs: list[str], output: str | None = None, **attributes: Any) -> str:
        from onnx import helper

        name = self._name(op)
        output = output or name + "_out"
        self.nodes.append(helper.make_node(op, inputs, [output], name=name, **attributes))
        return output

    def ints(self, values: list[int]) -> str:
        from onnx import TensorProto, helper

        name = self._name("const")
        tensor = helper.make_tensor(name + "_value", TensorProto.INT64, [len(values)], values)
        self.nodes.append(helper.make_node("Constant", [], [name + "_out"], name=name, value=tensor))
        return name + "_out"

    def dims(self, shape: str, indices: list[int]) -> str:
        """The entries ``indices`` of a 1-D shape tensor, as a 1-D tensor."""
        return self.node("Gather", [shape, self.ints(indices)], axis=0)

    def product(self, shape: str, first: int, second: int) -> str:
        return self.node("Mul", [self.dims(shape, [first]), self.dims(shape, [second])])

    def concat(self, parts: list[str]) -> str:
        return self.node("Concat", parts, axis=0)


def _partition_chain(build: _Builder, data: str, shape6: str, output: str) -> None:
    """NCHW ``data`` (``shape6`` = [B, C, nH, S, nW, S]) to ``output`` = (B, nH, nW, S, S, C)."""
    nhwc = build.node("Transpose", [data], perm=[0, 2, 3, 1])
    rows = build.node(
        "Reshape", [nhwc, build.concat([build.ints([-1]), build.dims(shape6, [3, 4]), build.product(shape6, 5, 1)])]
    )
    swapped = build.node("Transpose", [rows], perm=[0, 2, 1, 3])  # (B*nH, nW, S, S*C)
    build.node("Reshape", [swapped, build.dims(shape6, list(PARTITION_PERM))], output=output)


def _reverse_chain(build: _Builder, data: str, shape6: str, output: str) -> None:
    """Tokens ``data`` (``shape6`` = [B, nH, nW, S, S, C]) to ``output`` = (B, C, nH, S, nW, S)."""
    rows = build.node(
        "Reshape", [data, build.concat([build.ints([-1]), build.dims(shape6, [2, 3]), build.product(shape6, 4, 5)])]
    )
    swapped = build.node("Transpose", [rows], perm=[0, 2, 1, 3])  # (B*nH, S, nW, S*C) = NHWC
    nhwc_shape = build.concat(
        [build.dims(shape6, [0]), build.product(shape6, 1, 3), build.product(shape6, 2, 4), build.dims(shape6, [5])]
    )
    nchw = build.node("Transpose", [build.node("Reshape", [swapped, nhwc_shape])], perm=[0, 3, 1, 2])
    build.node("Reshape", [nchw, build.dims(shape6, list(REVERSE_PERM))], output=output)


def rewrite_window_transposes(model: Any) -> int:
    """Replace every 6-D window ``Reshape -> Transpose`` of ``model`` (an ``onnx.ModelProto``) in place.

    Returns how many transposes were rewritten (0 for a model that has none, e.g. an export made
    with the 4-D :func:`~gldt_core.training.stff.window_partition`, or a single-frame model).
    """
    graph = model.graph
    producer = {output: node for node in graph.node for output in node.output}
    consumers: dict[str, int] = {}
    for node in graph.node:
        for name in node.input:
            consumers[name] = consumers.get(name, 0) + 1
    graph_outputs = {output.name for output in graph.output}
    rewritten: list[Any] = []
    dropped: set[int] = set()
    count = 0
    for node in graph.node:
        perm = _perm(node) if node.op_type == "Transpose" else None
        source = producer.get(node.input[0]) if perm in (PARTITION_PERM, REVERSE_PERM) else None
        if source is None or source.op_type != "Reshape":
            rewritten.append(node)
            continue
        build = _Builder(node.output[0])  # output names are unique in a graph; node names need not be
        data, shape6 = source.input[0], source.input[1]
        chain = _partition_chain if perm == PARTITION_PERM else _reverse_chain
        chain(build, data, shape6, node.output[0])
        rewritten.extend(build.nodes)
        count += 1
        if consumers.get(source.output[0], 0) == 1 and source.output[0] not in graph_outputs:
            dropped.add(id(source))
    kept = [node for node in rewritten if id(node) not in dropped]
    del graph.node[:]
    graph.node.extend(kept)
    return count


def _random_feeds(session: Any, sizes: list[tuple[int, int]], seed: int) -> list[dict[str, np.ndarray]]:
    """Inputs for each ``(width, height)`` (fixed dims of the model win over the requested ones)."""
    rng = np.random.default_rng(seed)
    feeds = []
    for width, height in sizes:
        feed = {}
        for spec in session.get_inputs():
            shape = [
                dim if isinstance(dim, int) else default for dim, default in zip(spec.shape, (2, 3, height, width))
            ]
            feed[spec.name] = rng.random(shape, dtype=np.float32)
        feeds.append(feed)
    return feeds


def output_difference(
    before: np.ndarray, after: np.ndarray, what: str = "rewritten model", error: type[ValueError] = ValueError
) -> float:
    """Max absolute difference between an output of a model and the same output of its rewrite
    (NaN in the same places counts as equal; NaN in different places as an infinite difference).
    A changed shape raises ``error``, naming ``what`` changed it."""
    if before.shape != after.shape:
        raise error(f"{what} changed an output shape: {before.shape} -> {after.shape}")
    if not np.array_equal(np.isnan(before), np.isnan(after)):
        return math.inf  # NaN where the original had a number, or the other way round
    finite = ~np.isnan(before)
    return float(np.abs(before[finite] - after[finite]).max(initial=0.0))


def compare_models(original: Path | str, rewritten: Path | str, sizes: list[tuple[int, int]], seed: int = 0) -> float:
    """Max :func:`output_difference` of two ONNX models on the same random inputs of each size."""
    import onnxruntime as ort

    sessions = [ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]) for path in (original, rewritten)]
    worst = 0.0
    for feed in _random_feeds(sessions[0], sizes, seed):
        before, after = (session.run(None, feed) for session in sessions)
        for a, b in zip(before, after):
            worst = max(worst, output_difference(a, b))
    return worst


def rewrite_model_file(
    model: Path | str, out: Path | str, sizes: list[tuple[int, int]] | None = None
) -> tuple[int, float]:
    """Write ``model`` with 4-D window permutes to ``out`` (card next to it); ``(rewritten, max diff)``.

    Raises ``ValueError`` and writes nothing when the rewritten graph's outputs differ from the
    original's by more than :data:`MAX_ABS_DIFF` on random inputs of every size in ``sizes``.
    """
    import onnx

    model, out = Path(model), Path(out)
    if not model.is_file():
        raise FileNotFoundError(f"model not found: {model}")
    proto = onnx.load(str(model))
    count = rewrite_window_transposes(proto)
    onnx.checker.check_model(proto)

    def same_outputs(candidate: Path) -> float:
        diff = compare_models(model, candidate, sizes or [(640, 384), (320, 256)])
        if diff > MAX_ABS_DIFF:
            raise ValueError(
                f"rewriting {model} changed its outputs by {diff:.3g} (limit {MAX_ABS_DIFF:g}); nothing written"
            )
        return diff

    diff = write_checked_model(proto, model, out, same_outputs)
    update_sidecar_card(
        model,
        out,
        {
            "window_transposes": (
                f"{count} 6-D window permutes rewritten as 4-D chains (gldt export --rewrite-windows); "
                f"outputs within {diff:.1e} of the original"
            )
        },
    )
    return count, diff


def write_checked_model(proto: Any, model: Path, out: Path, check: Callable[[Path], float]) -> float:
    """Save ``proto``, a rewrite of ``model``, to ``out`` only once ``check`` passed on it (saved
    beside ``out`` under a temporary name; it raises ``ValueError`` to refuse); returns what
    ``check`` returned (the outputs' largest difference from ``model``)."""
    import onnx

    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    onnx.save(proto, str(tmp))
    try:
        result = check(tmp)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    os.replace(tmp, out)
    return result


def update_sidecar_card(model: Path, out: Path, fields: dict[str, Any], card: dict[str, Any] | None = None) -> None:
    """Write ``out``'s JSON card: ``model``'s (its sidecar, else ``card``; neither: none written)
    with ``fields``, the new file's SHA-256 and size, and its name where the file has another."""
    sidecar = model.with_suffix(".json")
    if sidecar.is_file():
        card = json.loads(sidecar.read_text())
    if card is None:
        return
    card = dict(card, **fields)
    card.update({"sha256": hashlib.sha256(out.read_bytes()).hexdigest(), "size_bytes": out.stat().st_size})
    if out.stem != model.stem:
        card["name"] = out.stem
    out.with_suffix(".json").write_text(json.dumps(card, indent=2, sort_keys=True) + "\n")
