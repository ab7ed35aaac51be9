"""``gldt run`` end to end with the shipped detectors on a small synthetic scene."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gldt_core.cli import main
from gldt_core.io.mot import read_mot


def check_full_run(tmp_path, capsys, frames: int, size: str) -> None:
    out, video, plot = tmp_path / "tracks.txt", tmp_path / "overlay.mp4", tmp_path / "run.png"
    config = tmp_path / "cfg.yaml"
    config.write_text("scheduler: {n_global: 5, n_local: 10}\n")
    width, height = (int(v) for v in size.split("x"))
    code = main(
        [
            "run",
            "--video",
            f"synth:seed=7,frames={frames},size={size},targets=2",
            "--out",
            str(out),
            "--render",
            str(video),
            "--plot",
            str(plot),
            "--config",
            str(config),
            "--no-progress",
        ]
    )
    captured = capsys.readouterr()
    assert code == 0, captured.err
    summary = [line for line in captured.out.splitlines() if " FPS, GD on " in line]
    assert len(summary) == 1 and summary[0].startswith(f"gldt run: {frames} frames, ")
    assert "time per stage: decode" in captured.out
    rows = read_mot(out)
    if len(rows):
        assert rows[:, 0].min() >= 1 and rows[:, 0].max() <= frames
        assert np.all(rows[:, 4] > 0) and np.all(rows[:, 8:] == -1)
        assert set(np.unique(rows[:, 7])) <= {1.0, 2.0, 3.0, -1.0}  # the track's class, -1 unknown
    capture = cv2.VideoCapture(str(video))
    assert int(capture.get(cv2.CAP_PROP_FRAME_COUNT)) == frames
    ok, image = capture.read()
    capture.release()
    assert ok and image.shape == (height, width, 3)
    assert cv2.imread(str(plot)) is not None
    assert not list(tmp_path.glob("*.part*"))


def test_run_writes_tracks_overlay_plot_and_summary(tmp_path, capsys):
    check_full_run(tmp_path, capsys, frames=4, size="320x256")


@pytest.mark.slow
def test_run_longer_scene_through_gd_and_ld(tmp_path, capsys):
    check_full_run(tmp_path, capsys, frames=60, size="640x512")


def test_run_max_frames_stops_early(tmp_path, capsys):
    out = tmp_path / "tracks.txt"
    code = main(
        [
            "run",
            "--video",
            "synth:seed=3,frames=30,size=320x256",
            "--out",
            str(out),
            "--max-frames",
            "3",
            "--no-progress",
        ]
    )
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "gldt run: 3 frames" in captured.out
    rows = read_mot(out)
    assert len(rows) == 0 or rows[:, 0].max() <= 3
