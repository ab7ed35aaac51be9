"""Preset splits and the ``gldt synth`` command."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gldt_core.cli import main
from gldt_core.io.mot import read_mot
from gldt_core.sim import presets, scene_ground_truth


def test_test_seeds_never_appear_in_train_or_val_even_for_large_splits() -> None:
    train = {s.seed for s in presets.split("train", count=5000)}
    val = {s.seed for s in presets.split("val", count=500)}
    test = {s.seed for s in presets.split("test", count=500)}
    assert not train & test and not val & test and not train & val


def test_smaller_split_is_a_prefix_and_specs_are_valid() -> None:
    big = presets.split("train", count=12, frames=30)
    small = presets.split("train", count=4, frames=30)
    assert big[:4] == small
    assert {s.targets for s in big} == {1, 2, 3}
    for spec in big:
        low, high = spec.target_size
        assert 3 <= low <= high <= 80
    with pytest.raises(ValueError, match="unknown split"):
        presets.split("holdout")


def test_synth_writes_a_mot_sequence_matching_the_ground_truth(tmp_path: Path) -> None:
    out = tmp_path / "seq"
    code = main(
        [
            "synth",
            "--out",
            str(out),
            "--seed",
            "3",
            "--frames",
            "6",
            "--size",
            "320x240",
            "--targets",
            "2",
            "--target-size",
            "4-20",
            "--preview",
        ]
    )
    assert code == 0
    images = sorted((out / "img1").glob("*.jpg"))
    assert [p.name for p in images] == [f"{k:06d}.jpg" for k in range(1, 7)]
    info = (out / "seqinfo.ini").read_text()
    assert "seqLength=6" in info and "imWidth=320" in info and "imHeight=240" in info
    expected = scene_ground_truth(seed=3, frames=6, size=(320, 240), targets=2, target_size=(4.0, 20.0))
    assert np.array_equal(read_mot(out / "gt" / "gt.txt"), expected)
    assert (out / "preview.png").stat().st_size > 10_000
    assert not list(tmp_path.glob(".*partial*"))


def test_synth_refuses_bad_input_with_one_line_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["synth", "--out", str(tmp_path / "a"), "--frames", "0"]) == 2
    assert "frames must be a positive integer" in capsys.readouterr().err
    assert main(["synth", "--out", str(tmp_path / "b"), "--frames", "2", "--target-size", "10-2000"]) == 2
    assert "bigger than half the frame" in capsys.readouterr().err
    assert main(["synth", "--out", str(tmp_path / "missing" / "c"), "--frames", "2"]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main(["synth", "--out", str(tmp_path / "d"), "--frames", "2", "--size", "big"]) == 2
    assert "1920x1080" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())
    with pytest.raises(SystemExit):
        main(["synth", "--no-such-option"])


def test_synth_does_not_overwrite_without_force(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "seq"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    assert main(["synth", "--out", str(out), "--frames", "2", "--size", "160x120"]) == 2
    assert "not empty" in capsys.readouterr().err
    assert (out / "keep.txt").read_text() == "mine"


def test_synth_from_a_preset_split_and_bench_smoke(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "seq"
    assert (
        main(["synth", "--split", "test", "--index", "2", "--frames", "3", "--size", "320x180", "--out", str(out)]) == 0
    )
    spec = presets.split("test", count=3, frames=3, size=(320, 180))[2]
    assert spec.name in (out / "seqinfo.ini").read_text()
    gt = read_mot(out / "gt" / "gt.txt")
    expected = scene_ground_truth(
        seed=spec.seed, frames=3, size=(320, 180), targets=spec.targets, target_size=spec.target_size
    )
    assert np.array_equal(gt, expected)
    capsys.readouterr()
    assert main(["bench", "synth", "--frames", "3", "--size", "320x180", "--seeds", "0"]) == 0
    report = capsys.readouterr().out
    assert "render/naive =" in report and "render/jpeg =" in report and "frames/s" in report
