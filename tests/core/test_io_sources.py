"""One frame-source interface over MOT folders, videos with MOT gt, bags and synthetic scenes."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from gldt_core.io.mot import write_mot
from gldt_core.io.sources import Frame, open_source, source_kind
from gldt_core.sim import SceneRenderer, SceneSpec
from support import HALMSTAD


def _write_video(path: Path, frames: int, size: tuple[int, int] = (96, 64)) -> list[np.ndarray]:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, size)
    images = []
    for k in range(frames):
        image = np.full((size[1], size[0], 3), 40 + 10 * k, np.uint8)
        writer.write(image)
        images.append(image)
    writer.release()
    return images


def test_mot_folder_frames_come_with_their_ground_truth(tmp_path: Path) -> None:
    from gldt_core.sim.writer import write_mot_sequence

    spec = SceneSpec(seed=4, frames=5, size=(320, 240), targets=2)
    renderer = SceneRenderer(spec)
    write_mot_sequence(renderer, tmp_path / "seq", jpeg_quality=95)
    source = open_source(tmp_path / "seq")
    assert source_kind(tmp_path / "seq") == "mot"
    assert len(source) == 5 and source.size == (320, 240) and source.fps == 30.0
    frames = list(source)
    assert [f.index for f in frames] == list(range(5))
    assert frames[3].stamp == pytest.approx(3 / 30.0)
    for frame in frames:
        assert isinstance(frame, Frame) and frame.image.shape == (240, 320, 3)
        assert np.array_equal(frame.ground_truth, renderer.ground_truth(frame.index))
        # JPEG at quality 95 stays close to the rendered frame.
        assert np.abs(frame.image.astype(int) - renderer.render(frame.index)).mean() < 4


def test_video_with_mot_gt_in_halmstad_layout(tmp_path: Path) -> None:
    (tmp_path / "videos").mkdir()
    (tmp_path / "gt").mkdir()
    video = tmp_path / "videos" / "CLIP.avi"
    images = _write_video(video, 6)
    write_mot(
        tmp_path / "gt" / "CLIP.txt", np.array([[2, 1, 10, 12, 8, 6, 1, 1, 1, -1], [6, 1, 11, 13, 8, 6, 1, 1, 1, -1]])
    )
    source = open_source(video)
    assert source_kind(video) == "video"
    assert len(source) == 6 and source.size == (96, 64) and source.fps == pytest.approx(25.0)
    frames = list(source)
    assert len(frames) == 6
    assert [len(f.ground_truth) for f in frames] == [0, 1, 0, 0, 0, 1]
    assert frames[5].ground_truth[0, 2] == 11
    assert abs(int(frames[2].image.mean()) - int(images[2].mean())) <= 3


def test_video_whose_gt_runs_past_its_frames_is_rejected(tmp_path: Path) -> None:
    video = tmp_path / "short.avi"
    _write_video(video, 4)
    gt = tmp_path / "gt.txt"
    write_mot(gt, np.array([[9, 1, 1, 1, 4, 4, 1, 1, 1, -1]]))
    with pytest.raises(ValueError, match="reaches frame 9 but video short.avi has 4 frames"):
        open_source(video, gt=gt)


def test_unknown_and_missing_sources_give_clear_errors(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="source not found"):
        open_source(tmp_path / "nope.mp4")
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(ValueError, match="unknown source type"):
        open_source(tmp_path / "notes.txt")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="neither a MOT folder"):
        open_source(tmp_path / "empty")
    with pytest.raises(ValueError, match="unknown synth field"):
        open_source("synth:seed=1,frames=2,colour=red")


def test_synth_uri_source_matches_the_renderer() -> None:
    source = open_source("synth:seed=6,frames=3,targets=2,size=320x180")
    renderer = SceneRenderer(SceneSpec(seed=6, frames=3, targets=2, size=(320, 180)))
    frames = list(source)
    assert len(source) == 3 and source.camera_matrix is not None
    assert np.array_equal(frames[2].image, renderer.render(2))
    assert np.array_equal(source.ground_truth, renderer.ground_truth())


@pytest.mark.skipif(not (HALMSTAD / "videos").is_dir(), reason=f"Halmstad clips not present at {HALMSTAD}")
def test_real_halmstad_clip_decodes_with_one_gt_box_per_drone_frame() -> None:
    source = open_source(HALMSTAD / "videos" / "V_DRONE_001.mp4")
    assert source.size == (640, 512) and source.fps == pytest.approx(30.0, abs=0.1)
    count = 0
    boxes = 0
    for frame in source:
        count += 1
        boxes += len(frame.ground_truth)
        if len(frame.ground_truth):
            assert np.all(frame.ground_truth[:, 0] == frame.index + 1)
    assert count == len(source)
    assert boxes == len(source.ground_truth) > 0
