"""`gldt bench latency`: model files timed side by side, in interleaved rounds, with clear errors."""

from __future__ import annotations

from pathlib import Path

import pytest

from gldt_core.bench.latency import interleaved_medians
from gldt_core.cli import main
from gldt_core.detect import shipped_model_path


def test_rounds_interleave_every_call_and_medians_follow_the_work() -> None:
    order: list[str] = []

    def work(name: str, spins: int):
        def call() -> None:
            order.append(name)
            total = 0
            for value in range(spins):
                total += value

        return call

    medians = interleaved_medians([work("small", 2_000), work("large", 200_000)], rounds=5, warmup=2)
    assert order == ["small", "large"] * 7, "each round must run every call once, in order"
    assert medians[1] > medians[0]


def test_global_and_local_models_are_timed_against_the_first(capsys: pytest.CaptureFixture[str]) -> None:
    local, global_, single = (shipped_model_path(kind) for kind in ("local", "global", "global_nostff"))
    assert main(["bench", "latency", str(local), str(global_), str(single), "--rounds", "2"]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("  ")]
    assert len(lines) == 4
    assert str(local) in lines[0] and " local " in lines[0] and lines[0].rstrip().endswith("x1.00")
    assert str(global_) in lines[1] and " global " in lines[1] and "no feature reuse" not in lines[1]
    # AM-YOLO ships with its split pair, so it is also timed without it, in the same rounds.
    assert f"{global_} (no feature reuse)" in lines[2] and " global " in lines[2]
    assert str(single) in lines[3] and " global " in lines[3], "the single-frame global model is a global model"
    assert "no feature reuse" not in lines[3], "the single-frame model has nothing to reuse"


def test_parts_of_a_split_model_are_skipped_not_timed(capsys: pytest.CaptureFixture[str]) -> None:
    from gldt_core.detect.feature_reuse import features_path, reuse_path

    global_ = shipped_model_path("global")
    assert main(["bench", "latency", str(features_path(global_)), str(reuse_path(global_)), "--rounds", "1"]) == 2
    out, err = capsys.readouterr()
    assert out.count("skipping") == 2 and "no detector model to time" in err


def test_a_missing_or_broken_model_is_one_clear_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "absent.onnx"
    assert main(["bench", "latency", str(missing)]) == 2
    assert f"{missing}: detector model not found" in capsys.readouterr().err
    broken = tmp_path / "broken.onnx"
    broken.write_bytes(b"not an onnx model")
    assert main(["bench", "latency", str(broken)]) == 2
    err = capsys.readouterr().err
    assert f"{broken}: cannot load ONNX model" in err and len(err.strip().splitlines()) == 1
