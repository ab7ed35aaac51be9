"""Overlay drawing, the overlay video writer and the run plot."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gldt_core.system.runner import tracks_to_mot
from gldt_core.viz.overlay import colour_for_id, draw_overlay
from gldt_core.viz.render import OverlayVideoWriter, save_run_plot


def test_overlay_draws_tracks_rois_and_leaves_input_untouched():
    frame = np.zeros((512, 640, 3), dtype=np.uint8)
    tracks = np.array([[100, 100, 140, 130, 7, 0.9]])
    rois = np.array([[300, 200, 600, 500]])
    out = draw_overlay(frame, tracks, "LD", rois, frame_index=3)
    assert frame.max() == 0  # a copy was drawn on
    assert tuple(out[100, 120]) == colour_for_id(7)  # top edge of the track box
    assert out[200, 450].any()  # top edge of the ROI
    assert not out[300, 450].any()  # inside the ROI stays untouched
    assert out[:60, :200].any()  # the mode label


def test_overlay_accepts_no_tracks_and_no_rois():
    frame = np.zeros((100, 100, 3), dtype=np.uint8)
    out = draw_overlay(frame, np.zeros((0, 6)), "GD", None)
    assert out.shape == frame.shape


def test_colours_differ_between_neighbouring_ids():
    assert len({colour_for_id(i) for i in range(1, 20)}) == 19


def test_video_writer_writes_all_frames_and_resizes_odd_sizes(tmp_path):
    path = tmp_path / "overlay.mp4"
    writer = OverlayVideoWriter(path, fps=30)
    for k in range(12):
        size = (640, 512) if k < 8 else (320, 256)
        frame = np.full((size[1], size[0], 3), 40, dtype=np.uint8)
        writer.write(frame, np.array([[10, 10, 50, 50, 1, 0.5]]), "GD", np.zeros((0, 4)), k)
    assert not path.exists()  # only the temporary exists until close
    writer.close()
    capture = cv2.VideoCapture(str(path))
    frames = 0
    while True:
        ok, image = capture.read()
        if not ok:
            break
        assert image.shape == (512, 640, 3)
        frames += 1
    capture.release()
    assert frames == 12
    assert not list(tmp_path.glob("*.part*"))


def test_video_writer_discards_partial_file_on_failure(tmp_path):
    path = tmp_path / "overlay.mp4"
    writer = OverlayVideoWriter(path, fps=30)
    writer.write(np.zeros((64, 64, 3), np.uint8), np.zeros((0, 6)), "GD", None, 0)
    writer.close(keep=False)
    assert not path.exists() and not list(tmp_path.iterdir())


def test_video_writer_refuses_unknown_extension(tmp_path):
    with pytest.raises(ValueError, match="--render"):
        OverlayVideoWriter(tmp_path / "out.gif", fps=30)


def test_run_plot_is_written(tmp_path):
    rows = tracks_to_mot(np.array([[0, 0, 10, 10, 1, 0.9]]), 2)
    path = tmp_path / "run.png"
    save_run_plot(path, np.array([True, True, False, False]), rows, 4, "test")
    image = cv2.imread(str(path))
    assert image is not None and image.shape[0] > 100


def test_tracks_to_mot_layout():
    rows = tracks_to_mot(np.array([[10, 20, 40, 60, 5, 0.75]]), 9)
    np.testing.assert_allclose(rows, [[9, 5, 10, 20, 30, 40, 0.75, -1, -1, -1]])
