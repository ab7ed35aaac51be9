"""The second stage: crop geometry, the runtime classifier, how the detectors use it, and bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gldt_core.detect import DetectorConfigError, GlobalDetector, LocalDetector, shipped_model_path
from gldt_core.detect.second_stage import (
    CROP_SIZE,
    GLOBAL_COLUMNS,
    LOCAL_COLUMNS,
    Calibration,
    SecondStage,
    classifier_path_for,
    crop_windows,
    cut_crops,
    encode_boxes,
    evidence,
)
from gldt_core.paths import halmstad_root

HALMSTAD = halmstad_root()


@settings(max_examples=60, deadline=None)
@given(st.floats(0, 600), st.floats(0, 400), st.floats(2, 120), st.floats(2, 120))
def test_a_candidate_sits_centred_in_its_window_a_third_of_its_side(x: float, y: float, w: float, h: float) -> None:
    box = np.array([[x, y, x + w, y + h]])
    geometry = encode_boxes(box, crop_windows(box))[0]
    np.testing.assert_allclose(geometry[:2], 0.0, atol=1e-9)
    longer = max(w, h)
    side = max(3.0 * longer, 32.0)
    np.testing.assert_allclose(np.exp(geometry[2:]) * side, [w, h], rtol=1e-9)


def test_crop_window_is_three_sides_and_never_below_the_minimum() -> None:
    windows = crop_windows(np.array([[100, 100, 140, 120], [0, 0, 4, 4]]))
    np.testing.assert_allclose(windows[0], [120, 110, 120])
    np.testing.assert_allclose(windows[1], [2, 2, 32])


def test_cut_crops_centres_the_object_and_stacks_previous_then_current() -> None:
    previous = np.zeros((200, 300, 3), np.uint8)
    frame = np.zeros((200, 300, 3), np.uint8)
    frame[90:110, 140:160] = (255, 0, 0)  # a 20 px blue square, centred at (150, 100)
    previous[90:110, 130:150] = (0, 255, 0)  # a green one 10 px to the left
    crops = cut_crops(previous, frame, crop_windows(np.array([[140, 90, 160, 110]])))
    assert crops.shape == (1, 6, CROP_SIZE, CROP_SIZE) and crops.dtype == np.uint8
    blue = crops[0, 3] > 128
    rows, cols = np.nonzero(blue)
    # The window is 60 px wide, so the 20 px square covers the middle third of the crop.
    assert abs(rows.mean() - (CROP_SIZE - 1) / 2) < 0.6 and abs(cols.mean() - (CROP_SIZE - 1) / 2) < 0.6
    assert 0.28 < blue.mean() ** 0.5 < 0.39
    green_cols = np.nonzero(crops[0, 1] > 128)[1]
    assert green_cols.mean() < cols.mean() - 8  # the previous frame's object, left of the current one


def test_cut_crops_repeats_the_border_at_the_frame_edge() -> None:
    frame = np.full((100, 100, 3), 40, np.uint8)
    frame[:, :2] = 200
    crops = cut_crops(frame, frame, crop_windows(np.array([[0, 40, 10, 50]])))
    left_half = crops[0, 3, :, :24]  # frame x < 2 (the bright columns) and the 11 px left of the frame
    assert (left_half > 150).all()  # outside the frame: the edge column, repeated


def test_evidence_multiplies_the_three_views_and_the_calibration_keeps_its_order() -> None:
    logits = np.array([[0.0, 0.0, -50.0, -50.0], [0.0, 50.0, 0.0, 0.0], [50.0, 0.0, 0.0, 0.0]])
    quality = np.array([0.0, 50.0, 0.0])
    values = evidence(logits, quality, np.array([0.8, 0.5, 0.9]))
    np.testing.assert_allclose(values, [0.5 * 0.5 * 0.8, 0.5, 0.0], atol=1e-9)
    calibration = Calibration(0.7, 1.7)
    grid = np.linspace(0.0, 1.0, 50)
    p = calibration.probability(grid)
    assert np.all(np.diff(p) > 0) and np.all((p > 0) & (p < 1))


def test_a_card_without_calibration_is_refused_in_one_line() -> None:
    with pytest.raises(DetectorConfigError, match="no calibration") as error:
        Calibration.from_card({}, "x.onnx")
    assert "\n" not in str(error.value)
    with pytest.raises(DetectorConfigError, match="must be positive"):
        Calibration.from_card({"calibration": {"slope": -1.0, "bias": 0.0}}, "x.onnx")


@pytest.fixture(scope="module")
def shipped_stage() -> SecondStage:
    return SecondStage(classifier_path_for(shipped_model_path("global")), score_threshold=0.0)


def test_the_shipped_second_stage_lies_beside_the_detectors_with_its_card() -> None:
    path = classifier_path_for(shipped_model_path("global"))
    assert path == classifier_path_for(shipped_model_path("local"))
    assert path.is_file() and path.stat().st_size < 15 * 1024 * 1024
    card = json.loads(path.with_suffix(".json").read_text())
    assert card["classes"] == ["background", "drone", "bird", "airplane"]
    assert card["calibration"]["slope"] > 0 and card["calibration"]["ece_after"] < card["calibration"]["ece_before"]
    training = card["training"]
    assert training["cpu_seconds_total"] > 0 and training["epochs"] >= 1
    from gldt_core.eval.halmstad_split import halmstad_split

    if not HALMSTAD.is_dir():
        pytest.skip(f"Halmstad clips not found at {HALMSTAD}: cannot check the split the card names")
    split = halmstad_split(HALMSTAD)
    seen = set(training["fit_clips"]) | set(training["calibration_clips"])
    assert seen == set(split["train"]), "the second stage trained on other clips than the training split"


def test_rescore_rows_are_calibrated_keep_the_detector_boxes_and_are_capped(shipped_stage: SecondStage) -> None:
    rng = np.random.default_rng(3)
    frame = np.clip(rng.normal(170, 8, size=(240, 320, 3)), 0, 255).astype(np.uint8)
    frame[100:112, 150:170] = 20
    xy = rng.uniform(10, 200, size=(30, 2))
    candidates = np.column_stack([xy, xy + 20, rng.uniform(0.01, 0.9, 30), np.ones(30)])
    rows = shipped_stage.rescore(frame, frame, candidates)
    assert rows.shape[1] == GLOBAL_COLUMNS and 0 < len(rows) <= shipped_stage.max_candidates
    assert np.all((rows[:, 4] >= 0) & (rows[:, 4] <= 1))
    np.testing.assert_allclose(rows[:, 6:].sum(axis=1), 1.0, atol=1e-5)
    assert np.all(rows[:, 5] == 1)  # asked about drones: every row is a drone row, scored by P(drone)
    for row in rows:  # each row is one of the candidates, its box unchanged
        assert np.isclose(candidates[:, :4], row[:4], atol=1e-4).all(axis=1).any()
    strict = SecondStage(shipped_stage.model_path, score_threshold=0.9)
    assert np.all(strict.rescore(frame, frame, candidates)[:, 4] >= 0.9)
    assert shipped_stage.rescore(None, frame, np.zeros((0, 6))).shape == (0, GLOBAL_COLUMNS)
    with pytest.raises(ValueError, match="candidates must be"):
        shipped_stage.rescore(frame, frame, np.zeros((3, 2)))


def test_rescore_many_equals_one_pair_at_a_time(shipped_stage: SecondStage) -> None:
    rng = np.random.default_rng(4)
    frames = [np.clip(rng.normal(150, 20, size=(120, 160, 3)), 0, 255).astype(np.uint8) for _ in range(2)]
    candidates = [np.array([[20.0, 20, 40, 35, 0.5, 1]]), np.array([[60.0, 50, 80, 70, 0.3, 1]])]
    together = shipped_stage.rescore_many([(f, f, c) for f, c in zip(frames, candidates)])
    for frame, cands, rows in zip(frames, candidates, together):
        np.testing.assert_allclose(rows, shipped_stage.rescore(frame, frame, cands), atol=1e-5)


def test_a_detector_without_its_classifier_says_so_in_one_line(tmp_path: Path) -> None:
    model = tmp_path / "global.onnx"
    model.write_bytes(shipped_model_path("global").read_bytes())
    with pytest.raises(DetectorConfigError, match="second_stage.onnx: second-stage classifier not found") as error:
        GlobalDetector(model)
    assert "\n" not in str(error.value) and "second_stage: null" in str(error.value)
    plain = GlobalDetector(model, second_stage=None, score_threshold=0.0)
    frame = np.full((256, 320, 3), 128, np.uint8)
    rows = plain.detect(frame, frame)
    assert rows.shape[1] == GLOBAL_COLUMNS
    assert plain.score_threshold == 0.0 and plain.decode_threshold == 0.0


def test_a_file_that_is_no_classifier_is_refused(tmp_path: Path) -> None:
    with pytest.raises(DetectorConfigError, match="not a second-stage classifier|expected"):
        SecondStage(shipped_model_path("local"))
    broken = tmp_path / "second_stage.onnx"
    broken.write_bytes(b"not onnx")
    with pytest.raises(DetectorConfigError):
        SecondStage(broken)


def test_default_thresholds_mean_calibrated_probability_with_the_second_stage() -> None:
    with_stage = GlobalDetector(num_threads=1)
    alone = GlobalDetector(num_threads=1, second_stage=None)
    assert with_stage.score_threshold == SecondStage.DEFAULT_THRESHOLD == 0.5
    assert with_stage.decode_threshold == SecondStage.CANDIDATE_SCORE
    assert alone.score_threshold == 0.25 and alone.second_stage is None


def test_local_crops_with_previous_crops_equal_the_offline_call() -> None:
    """The ROS split (crops sent with the previous frame's crops) gives the offline rows."""
    rng = np.random.default_rng(5)
    previous = np.clip(rng.normal(160, 10, size=(512, 640, 3)), 0, 255).astype(np.uint8)
    frame = np.roll(previous, 2, axis=1)
    frame[200:214, 300:322] = 25
    rois = np.array([[150, 60, 450, 360], [380, 250, 680, 550]])  # the second sticks out of the frame
    detector = LocalDetector(num_threads=1, score_threshold=0.0, classes=[1])
    offline = detector.detect_rois(frame, rois, previous)
    split = detector.detect_crops(
        [LocalDetector.crop(frame, r) for r in rois],
        rois,
        640,
        512,
        previous_crops=[LocalDetector.crop(previous, r) for r in rois],
    )
    assert offline.shape[1] == LOCAL_COLUMNS and len(offline) > 0
    np.testing.assert_array_equal(offline, split)
    assert set(np.unique(offline[:, 6]).astype(int)) <= {0, 1}
    with pytest.raises(ValueError, match="previous crops"):
        detector.detect_crops([LocalDetector.crop(frame, rois[0])], rois[:1], 640, 512, previous_crops=[])
