"""`gldt detect`: MOTChallenge detections for every frame of a video, and clear errors."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from gldt_core.cli import main
from gldt_core.io.mot import read_mot


@pytest.fixture(scope="module")
def video(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("vid") / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30, (320, 256))
    rng = np.random.default_rng(0)
    for k in range(5):
        frame = np.clip(rng.normal(160, 10, (256, 320, 3)), 0, 255).astype(np.uint8)
        frame[100:110, 60 + 8 * k : 76 + 8 * k] = 20
        writer.write(frame)
    writer.release()
    return path


@pytest.mark.parametrize("detector", ["global", "local"])
def test_detect_writes_mot_detections_for_every_frame(video: Path, tmp_path: Path, detector: str) -> None:
    out = tmp_path / f"{detector}.txt"
    code = main(
        [
            "detect",
            "--video",
            str(video),
            "--out",
            str(out),
            "--detector",
            detector,
            "--score-threshold",
            "0.0",
            "--classes",
            "all",
            "--no-progress",
            "--threads",
            "1",
        ]
    )
    assert code == 0
    rows = read_mot(out)
    assert len(rows) > 0
    assert set(np.unique(rows[:, 0]).astype(int).tolist()) == {1, 2, 3, 4, 5}
    assert (rows[:, 1] == -1).all() and (rows[:, 7:] == -1).all()
    assert (rows[:, 4] > 0).all() and (rows[:, 5] > 0).all()
    assert (rows[:, 2] >= 0).all() and (rows[:, 2] + rows[:, 4] <= 320 + 1e-3).all()
    assert ((rows[:, 6] >= 0) & (rows[:, 6] <= 1)).all()


def test_detect_reports_unreadable_video_and_missing_model(
    tmp_path: Path, video: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(b"not a video")
    assert main(["detect", "--video", str(bad), "--out", str(tmp_path / "o.txt"), "--no-progress"]) == 2
    assert "bad.mp4" in capsys.readouterr().err
    assert (
        main(["detect", "--video", str(video), "--out", str(tmp_path / "o.txt"), "--model", str(tmp_path / "m.onnx")])
        == 2
    )
    assert "m.onnx" in capsys.readouterr().err
    assert not (tmp_path / "o.txt").exists()


def test_global_detect_fuses_tiles_as_gldt_run_does_unless_told_not_to(video: Path, tmp_path: Path) -> None:
    """By default `gldt detect` writes the boxes of gldt run's GD frames (AM-YOLO fused with the
    local model over tiles, ``detector.tile_fusion``); ``--no-tile-fusion`` writes AM-YOLO's alone."""
    from gldt_core.detect import GlobalDetector
    from gldt_core.detect.fusion import build_tile_detector
    from gldt_core.detect.video import detect_frames, iter_video_frames

    common = ["--video", str(video), "--score-threshold", "0.02", "--classes", "all", "--threads", "1"]
    kwargs = {"score_threshold": 0.02, "classes": None, "num_threads": 1}
    expected = {
        "fused": GlobalDetector(tile_detector=build_tile_detector(None, dict(kwargs)), **kwargs),
        "alone": GlobalDetector(**kwargs),
    }
    written = {}
    for name, flags in (("fused", []), ("alone", ["--no-tile-fusion"])):
        out = tmp_path / f"{name}.txt"
        assert main(["detect", *common, "--out", str(out), "--no-progress", *flags]) == 0
        written[name] = read_mot(out)
        rows = detect_frames(iter_video_frames(str(video)), expected[name])
        assert len(written[name]) == len(rows)
        np.testing.assert_allclose(np.sort(written[name][:, 6]), np.sort(rows[:, 6]), atol=1e-4)
    # Without the second stage there are no calibrated scores to fuse: AM-YOLO alone either way.
    raw = {}
    for name, flags in (("raw", []), ("raw_alone", ["--no-tile-fusion"])):
        out = tmp_path / f"{name}.txt"
        assert main(["detect", *common, "--out", str(out), "--no-progress", "--second-stage", "none", *flags]) == 0
        raw[name] = read_mot(out)
    np.testing.assert_array_equal(raw["raw"], raw["raw_alone"])
    assert len(written["fused"]) != len(written["alone"]) or not np.allclose(
        np.sort(written["fused"][:, 6]), np.sort(written["alone"][:, 6])
    ), "the fused rows are not AM-YOLO's"
