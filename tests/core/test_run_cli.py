"""``gldt run`` argument and start-up errors: one line, exit code 2, nothing written."""

from __future__ import annotations

import pytest

from gldt_core.cli import main


def run_cli(argv, capsys):
    code = main(argv)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_missing_input_fails_with_one_line(tmp_path, capsys):
    out = tmp_path / "tracks.txt"
    code, _, err = run_cli(["run", "--video", str(tmp_path / "nope.mp4"), "--out", str(out)], capsys)
    assert code == 2
    assert err.strip().count("\n") == 0 and "input not found" in err and "nope.mp4" in err
    assert not out.exists()


def test_bad_config_fails_before_any_frame(tmp_path, capsys):
    video = tmp_path / "clip.mp4"
    video.write_bytes(b"not really a video")
    config = tmp_path / "cfg.yaml"
    config.write_text("scheduler: {n_global: -3}\n")
    out = tmp_path / "tracks.txt"
    code, _, err = run_cli(["run", "--video", str(video), "--out", str(out), "--config", str(config)], capsys)
    assert code == 2
    assert err.strip().count("\n") == 0 and "n_global" in err and "cfg.yaml" in err
    assert not out.exists()


def test_missing_model_file_fails_at_start(tmp_path, capsys):
    video = tmp_path / "clip.mp4"
    video.write_bytes(b"x")
    config = tmp_path / "cfg.yaml"
    config.write_text(f"detector: {{global_model: {tmp_path / 'missing.onnx'}}}\n")
    code, _, err = run_cli(
        ["run", "--video", str(video), "--out", str(tmp_path / "t.txt"), "--config", str(config)], capsys
    )
    assert code == 2
    assert err.strip().count("\n") == 0 and "model file not found" in err and "missing.onnx" in err


def test_source_is_required_and_exclusive(tmp_path):
    with pytest.raises(SystemExit):
        main(["run", "--out", str(tmp_path / "t.txt")])
    with pytest.raises(SystemExit):
        main(["run", "--video", "a.mp4", "--bag", "b.mcap", "--out", str(tmp_path / "t.txt")])


def test_max_frames_must_be_positive(tmp_path, capsys):
    code, _, err = run_cli(
        ["run", "--video", "synth:seed=1,frames=5", "--out", str(tmp_path / "t.txt"), "--max-frames", "0"], capsys
    )
    assert code == 2 and "--max-frames" in err
