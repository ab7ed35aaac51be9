"""Letterbox / rect sizing / NMS / decoding used by the onnxruntime wrappers (numpy only)."""

from __future__ import annotations

import numpy as np
import pytest

from gldt_core.detect.postprocess import (
    decode_output,
    ensure_bgr,
    letterbox,
    nms,
    rect_input_size,
    tile_rois,
    to_blob,
    unletterbox,
)
from gldt_core.eval.halmstad_split import split_clips


def test_rect_input_size_for_1080p_and_halmstad() -> None:
    assert rect_input_size(1920, 1080, 640, 64) == (640, 384)
    assert rect_input_size(1920, 1080, 640, 32) == (640, 384)  # 360 rounds up to 384
    assert rect_input_size(640, 512, 640, 64) == (640, 512)
    assert rect_input_size(512, 640, 640, 64) == (512, 640)
    with pytest.raises(ValueError, match="positive"):
        rect_input_size(0, 10, 640, 64)


def test_letterbox_roundtrip_maps_boxes_back() -> None:
    frame = np.zeros((1080, 1920, 3), np.uint8)
    frame[500:530, 900:960] = 255
    image, lb = letterbox(frame, 640, 384)
    assert image.shape == (384, 640, 3) and lb.scale == pytest.approx(1 / 3) and lb.pad_y == 12 and lb.pad_x == 0
    ys, xs = np.nonzero(image[..., 0] > 128)
    box_in = np.array([[xs.min(), ys.min(), xs.max() + 1, ys.max() + 1, 0.9, 0]], np.float32)
    back = unletterbox(box_in, lb, 1920, 1080)
    assert np.allclose(back[0, :4], [900, 500, 960, 530], atol=3.5)
    assert back[0, 4] == pytest.approx(0.9)


def test_to_blob_is_rgb_nchw_unit_range() -> None:
    img = np.zeros((4, 6, 3), np.uint8)
    img[..., 0] = 255  # blue in BGR
    blob = to_blob([img, img])
    assert blob.shape == (2, 3, 4, 6) and blob.dtype == np.float32
    assert blob[0, 2].max() == 1.0 and blob[0, 0].max() == 0.0  # blue ends up in the last (B of RGB) channel


def test_ensure_bgr_converts_gray_and_rejects_bad_frames() -> None:
    gray = np.full((20, 30), 77, np.uint8)
    out = ensure_bgr(gray)
    assert out.shape == (20, 30, 3) and (out == 77).all()
    assert ensure_bgr(np.zeros((20, 30, 4), np.uint8)).shape == (20, 30, 3)
    with pytest.raises(ValueError, match="uint8"):
        ensure_bgr(np.zeros((20, 30, 3), np.float32))
    with pytest.raises(ValueError, match="HxWx3"):
        ensure_bgr(np.zeros((20, 30, 2), np.uint8))
    with pytest.raises(ValueError, match="too small"):
        ensure_bgr(np.zeros((4, 30, 3), np.uint8))


def test_nms_keeps_best_of_overlapping_boxes() -> None:
    boxes = np.array([[0, 0, 10, 10], [1, 1, 11, 11], [50, 50, 60, 60], [0, 0, 10, 10.5]], np.float32)
    scores = np.array([0.5, 0.9, 0.4, 0.3], np.float32)
    assert nms(boxes, scores, 0.5).tolist() == [1, 2]
    assert nms(np.zeros((0, 4)), np.zeros(0), 0.5).size == 0


def test_decode_output_thresholds_picks_class_and_suppresses() -> None:
    # 3 anchors, 2 classes: rows x1, y1, x2, y2, s0, s1.
    out = np.array(
        [
            [10, 11, 100],
            [10, 11, 100],
            [20, 21, 120],
            [20, 21, 120],
            [0.8, 0.1, 0.05],
            [0.1, 0.7, 0.6],
        ],
        np.float32,
    )
    dets = decode_output(out, 0.3, 0.5)
    assert dets.shape == (2, 6)
    assert dets[0].tolist() == pytest.approx([10, 10, 20, 20, 0.8, 0])
    assert dets[1].tolist() == pytest.approx([100, 100, 120, 120, 0.6, 1])
    assert decode_output(out, 0.95).shape == (0, 6)
    with pytest.raises(ValueError, match="4 \\+ nc"):
        decode_output(np.zeros((3, 5), np.float32), 0.5)


def test_decode_output_asked_about_some_classes_scores_them_by_their_own_score() -> None:
    # Anchor 0: bird 0.6 over drone 0.4 (the held-out drone a bird label loses); anchor 1: drone.
    out = np.array(
        [
            [10, 100],
            [10, 100],
            [20, 120],
            [20, 120],
            [0.4, 0.7],  # drone
            [0.6, 0.1],  # bird
            [0.05, 0.2],  # airplane
        ],
        np.float32,
    )
    assert decode_output(out, 0.3)[:, 5].tolist() == [0.0, 1.0]  # every class: anchor 0 (second by score) is a bird
    drones = decode_output(out, 0.3, channels=np.array([0]))
    assert drones[:, 4].tolist() == pytest.approx([0.7, 0.4]) and drones[:, 5].tolist() == [0.0, 0.0]
    others = decode_output(out, 0.15, channels=np.array([1, 2]))  # the best among bird and airplane
    assert others[:, 5].tolist() == [1.0, 2.0] and others[:, 4].tolist() == pytest.approx([0.6, 0.2])
    for bad in ([], [3], [-1]):
        with pytest.raises(ValueError, match="channels must be a non-empty list of class indices below 3"):
            decode_output(out, 0.3, channels=np.array(bad, dtype=np.int64))


def test_tiles_cover_the_frame_with_overlap() -> None:
    rois = tile_rois(1920, 1080, 300)
    covered = np.zeros((1080, 1920), bool)
    for x1, y1, x2, y2 in rois:
        assert x2 - x1 == 300 and y2 - y1 == 300 and x1 >= 0 and y1 >= 0 and x2 <= 1920 and y2 <= 1080
        covered[y1:y2, x1:x2] = True
    assert covered.all()
    assert tile_rois(200, 100, 300).tolist() == [[0, 0, 300, 300]]


def test_halmstad_split_is_disjoint_and_holds_out_two_in_five() -> None:
    names = [f"V_DRONE_{i:03d}" for i in range(10)] + [f"V_BIRD_{i:03d}" for i in range(5)]
    split = split_clips(names)
    assert set(split["train"]).isdisjoint(split["val"])
    assert set(split["train"]).isdisjoint(split["val_b"])
    assert set(split["val"]).isdisjoint(split["val_b"])
    assert sorted(split["train"] + split["val"] + split["val_b"]) == sorted(names)
    assert split["val"] == ["V_DRONE_002", "V_DRONE_007", "V_BIRD_002"]
    assert split["val_b"] == ["V_DRONE_004", "V_DRONE_009", "V_BIRD_004"]
    with pytest.raises(ValueError, match="not a Halmstad clip"):
        split_clips(["clip1"])


def test_halmstad_split_follows_the_annotations_not_which_videos_are_present(tmp_path) -> None:
    """A copy without some videos (the val_b clips left off a GPU machine) splits the same way;
    listing by video would shift every later clip of a category into another split."""
    from gldt_core.eval.halmstad_split import halmstad_split

    (tmp_path / "gt").mkdir()
    (tmp_path / "videos").mkdir()
    names = [f"V_DRONE_{i:03d}" for i in range(12)] + [f"V_BIRD_{i:03d}" for i in range(6)]
    for name in names:
        (tmp_path / "gt" / f"{name}.txt").write_text("")
        (tmp_path / "videos" / f"{name}.mp4").write_bytes(b"")
    full = halmstad_split(tmp_path)
    for name in full["val_b"] + ["V_DRONE_000"]:
        (tmp_path / "videos" / f"{name}.mp4").unlink()
    assert halmstad_split(tmp_path) == full == split_clips(names)
    with pytest.raises(FileNotFoundError, match="is not a directory"):
        halmstad_split(tmp_path / "elsewhere")


def test_nms_can_also_drop_a_box_nested_in_a_better_one() -> None:
    boxes = np.array([[100.0, 100, 180, 140], [120, 110, 160, 130], [300, 300, 320, 320]])
    scores = np.array([0.9, 0.8, 0.7])
    # IoU of the inner box with the outer one is 0.25: plain NMS keeps both.
    assert nms(boxes, scores, 0.5).tolist() == [0, 1, 2]
    assert nms(boxes, scores, 0.5, nested_threshold=0.8).tolist() == [0, 2]
    # Nested the other way round (the inner box scores higher): the outer one goes.
    assert nms(boxes, np.array([0.8, 0.9, 0.7]), 0.5, nested_threshold=0.8).tolist() == [1, 2]


def test_letterbox_pads_rather_than_enlarges_past_max_scale() -> None:
    crop = np.full((142, 142, 3), 200, np.uint8)
    image, mapping = letterbox(crop, 256, 256, max_scale=256 / 300)
    assert image.shape == (256, 256, 3) and mapping.scale == pytest.approx(256 / 300)
    inside = int(round(142 * 256 / 300))
    assert (image[mapping.pad_y : mapping.pad_y + inside, mapping.pad_x : mapping.pad_x + inside] == 200).all()
    assert image[0, 0, 0] != 200  # padding
    assert letterbox(np.zeros((600, 600, 3), np.uint8), 256, 256, max_scale=256 / 300)[1].scale == pytest.approx(
        256 / 600
    )


def test_the_system_drops_nested_detections_before_the_tracker_and_keeps_their_columns() -> None:
    from gldt_core.system.steps import drop_nested

    rows = np.array(
        [
            [100.0, 100, 180, 140, 0.6, 1, 0.9, 0.1, 0.0],
            [120, 110, 160, 130, 0.8, 1, 0.8, 0.2, 0.0],
            [0, 0, 9, 9, 0.2, 1, 1, 0, 0],
        ]
    )
    kept = drop_nested(rows, 0.8)
    np.testing.assert_array_equal(kept, rows[1:])  # the outer box goes; order and columns stay
    np.testing.assert_array_equal(drop_nested(rows, None), rows)
    np.testing.assert_array_equal(drop_nested(rows, 1.0), rows)
