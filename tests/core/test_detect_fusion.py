"""gldt_core.detect.fusion: two detectors' calibrated boxes fused by the mean of their scores."""

from __future__ import annotations

import numpy as np
import pytest

from gldt_core.detect.fusion import MATCH_IOU, fuse_detections, greedy_pairs
from gldt_core.detect.session import DetectorConfigError


def rows(*boxes: tuple[float, ...]) -> np.ndarray:
    """Detection rows ``x1, y1, x2, y2, score, class, p_drone, p_bird, p_airplane``."""
    return np.array(boxes, dtype=np.float64).reshape(-1, 9)


def test_a_box_both_report_is_one_box_with_the_mean_score_and_the_score_weighted_corners() -> None:
    first = rows((10, 10, 30, 30, 0.9, 1, 0.9, 0.1, 0.0))
    second = rows((12, 10, 32, 30, 0.3, 2, 0.3, 0.6, 0.1))
    fused = fuse_detections(first, second)
    assert fused.shape == (1, 9)
    assert fused[0, 4] == pytest.approx(0.6)
    assert fused[0, 0] == pytest.approx(0.75 * 10 + 0.25 * 12)
    assert fused[0, 2] == pytest.approx(0.75 * 30 + 0.25 * 32)
    assert fused[0, 5] == 1, "the class of the higher-scoring box"
    np.testing.assert_allclose(fused[0, 6:], [0.6, 0.35, 0.05], atol=1e-6)


def test_a_box_only_one_detector_reports_keeps_its_place_and_half_its_score() -> None:
    first = rows((10, 10, 30, 30, 0.9, 1, 0.9, 0.1, 0.0))
    second = rows((200, 200, 220, 220, 0.8, 1, 0.8, 0.2, 0.0))
    fused = fuse_detections(first, second)
    np.testing.assert_allclose(fused[:, :4], [[10, 10, 30, 30], [200, 200, 220, 220]])
    np.testing.assert_allclose(fused[:, 4], [0.45, 0.4])
    np.testing.assert_allclose(fused[:, 6:], np.concatenate([first[:, 6:], second[:, 6:]]), atol=1e-6)


def test_boxes_below_the_match_iou_are_not_paired() -> None:
    # IoU of these two: 10 x 20 overlap of 20 x 20 boxes -> 200 / 600 = 0.333; at 0.4 apart.
    first, second = rows((0, 0, 20, 20, 0.8, 1, 1, 0, 0)), rows((10, 0, 30, 20, 0.8, 1, 1, 0, 0))
    assert len(fuse_detections(first, second, match_iou=MATCH_IOU)) == 1
    assert len(fuse_detections(first, second, match_iou=0.4)) == 2


def test_each_box_pairs_once_best_overlap_first() -> None:
    """Two boxes of one detector on one box of the other: the closer one pairs, the other is alone."""
    first = rows((0, 0, 20, 20, 0.8, 1, 1, 0, 0), (2, 0, 22, 20, 0.6, 1, 1, 0, 0))
    second = rows((1.5, 0, 21.5, 20, 0.8, 1, 1, 0, 0))
    fused = fuse_detections(first, second)
    assert len(fused) == 2
    assert fused[0, 4] == pytest.approx(0.7), "the pair: (0.6 + 0.8) / 2 with the closer box"
    assert fused[1, 4] == pytest.approx(0.4), "the farther box alone"
    assert greedy_pairs(np.array([[0.9, 0.8], [0.85, 0.5]]), 0.3) == [(0, 0), (1, 1)]
    assert greedy_pairs(np.array([[0.9, 0.8], [0.85, 0.1]]), 0.3) == [(0, 0)], "no second choice below the IoU"


def test_the_fused_scores_do_not_depend_on_which_detector_comes_first() -> None:
    rng = np.random.default_rng(3)
    corners = rng.uniform(0, 300, (12, 2))
    boxes = np.column_stack([corners, corners + rng.uniform(8, 40, (12, 2))])
    a = np.column_stack([boxes[:7], rng.uniform(0.05, 1, 7), np.ones(7)])
    b = np.column_stack([boxes[5:] + rng.normal(0, 2, (7, 4)), rng.uniform(0.05, 1, 7), np.ones(7)])
    one, other = fuse_detections(a, b), fuse_detections(b, a)
    assert sorted(np.round(one[:, 4], 6)) == sorted(np.round(other[:, 4], 6))
    assert one[:, 4].sum() == pytest.approx((a[:, 4].sum() + b[:, 4].sum()) / 2, rel=1e-5), "the mean keeps the mass"


def test_empty_inputs_and_bad_shapes() -> None:
    one = rows((0, 0, 10, 10, 0.8, 1, 1, 0, 0))
    assert fuse_detections(rows(), rows()).shape == (0, 9)
    np.testing.assert_allclose(fuse_detections(one, rows())[:, 4], [0.4])
    with pytest.raises(ValueError, match="same C >= 5"):
        fuse_detections(one, one[:, :6])
    with pytest.raises(ValueError, match="match_iou"):
        fuse_detections(one, one, match_iou=0.0)


def real_pairs(count: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """(previous, current) pairs of the real 640x512 sample bag, a drone in every frame."""
    from itertools import islice

    from gldt_core.io.sources import open_source
    from gldt_core.paths import REPO_ROOT

    frames = [frame.image for frame in islice(open_source(str(REPO_ROOT / "bags" / "halmstad_v_drone_001")), count)]
    return list(zip(frames[:-1], frames[1:], strict=True))[::5]


@pytest.fixture(scope="module")
def fused_detector() -> object:
    from gldt_core.detect import GlobalDetector
    from gldt_core.detect.fusion import build_tile_detector

    settings = {"score_threshold": 0.1, "num_threads": 1, "classes": (1,)}
    return GlobalDetector(**settings, tile_detector=build_tile_detector(None, settings))


def test_a_gd_frame_with_tiles_is_both_detectors_fused_then_cut_at_the_threshold(fused_detector: object) -> None:
    """The fused rows of a 640x512 frame (its own network input) are AM-YOLO's and the local
    model's over tiles of the frame, each down to half the threshold, fused, cut at the threshold."""
    from gldt_core.detect import GlobalDetector, LocalDetector

    alone = GlobalDetector(score_threshold=0.05, num_threads=1, classes=(1,))
    tiles = LocalDetector(score_threshold=0.05, num_threads=1, classes=(1,))
    found = 0
    for previous, current in real_pairs(16):
        expected = fuse_detections(alone.detect(previous, current), tiles.detect_tiles(current, previous))
        expected = expected[expected[:, 4] >= 0.1]
        fused = fused_detector.detect(previous, current)  # type: ignore[attr-defined]
        np.testing.assert_allclose(fused, expected, atol=1e-4)
        found += int((fused[:, 4] >= 0.5).any())
    assert found >= 2, "the drone of the sample bag is found at the calibrated 0.5 in some of these frames"


def test_a_frame_letterboxed_below_the_tiles_scale_keeps_the_global_boxes(fused_detector: object) -> None:
    """A 1080p frame is letterboxed at 1/3: no tiles; the rows are AM-YOLO's at the threshold."""
    import cv2

    from gldt_core.detect import GlobalDetector

    previous, current = (cv2.resize(frame, (1920, 1080)) for frame in real_pairs(6)[0])
    alone = GlobalDetector(score_threshold=0.1, num_threads=1, classes=(1,))
    np.testing.assert_allclose(
        fused_detector.detect(previous, current),  # type: ignore[attr-defined]
        alone.detect(previous, current),
        atol=1e-5,
    )


def test_a_pair_whose_tile_pass_is_not_wanted_keeps_the_global_boxes_at_the_threshold(fused_detector: object) -> None:
    """A live pair too late for its tile pass (``tiles_wanted`` says no) is answered with
    AM-YOLO's rows alone, cut at the threshold as without tile fusion; asked once AM-YOLO's
    boxes are in, and never with tiles off."""
    from gldt_core.detect import GlobalDetector

    alone = GlobalDetector(score_threshold=0.1, num_threads=1, classes=(1,))
    asked = []

    def late() -> bool:
        asked.append(True)
        return False

    differs = 0
    for previous, current in real_pairs(16):
        previous_input, _ = fused_detector.prepare(previous)  # type: ignore[attr-defined]
        current_input, mapping = fused_detector.prepare(current)  # type: ignore[attr-defined]
        height, width = current.shape[:2]
        rows, _ = fused_detector.detect_prepared(  # type: ignore[attr-defined]
            previous_input, current_input, mapping, width, height, tiles_wanted=late
        )
        np.testing.assert_allclose(rows, alone.detect(previous, current), atol=1e-4)
        fused, _ = fused_detector.detect_prepared(  # type: ignore[attr-defined]
            previous_input, current_input, mapping, width, height, tiles_wanted=lambda: True
        )
        differs += int(len(fused) != len(rows) or not np.allclose(fused, rows, atol=1e-4))
    assert len(asked) == 3
    assert differs >= 1, "with the tile pass the rows change on some of these frames"
    alone.detect_prepared(previous_input, current_input, mapping, width, height, tiles_wanted=late)
    assert len(asked) == 3, "a detector without tiles never asks"


def test_a_pair_letterboxed_below_the_tiles_scale_is_never_asked_about_its_tile_pass(fused_detector: object) -> None:
    """A 1080p pair has no tile pass to skip: a live node must not count it as skipped."""
    import cv2

    previous, current = (cv2.resize(frame, (1920, 1080)) for frame in real_pairs(6)[0])
    previous_input, _ = fused_detector.prepare(previous)  # type: ignore[attr-defined]
    current_input, mapping = fused_detector.prepare(current)  # type: ignore[attr-defined]

    def never() -> bool:
        raise AssertionError("asked about a tile pass that does not run")

    fused_detector.detect_prepared(  # type: ignore[attr-defined]
        previous_input, current_input, mapping, 1920, 1080, tiles_wanted=never
    )


def test_the_tile_pass_budget_runs_a_pass_only_where_its_expected_time_still_fits() -> None:
    from gldt_core.detect.fusion import TilePassBudget

    budget = TilePassBudget(0.065)
    assert budget.wanted(0.200), "the first pair always runs it: nothing is known of its time yet"
    budget.record(0.020)
    assert budget.wanted(0.044) and not budget.wanted(0.046)
    budget.record(0.900)  # one slow pass among fast ones does not move the median far
    budget.record(0.020)
    assert budget.expected_s() == pytest.approx(0.020)
    assert budget.wanted(0.040)


def test_a_budget_that_skipped_many_pairs_in_a_row_measures_the_pass_again() -> None:
    from gldt_core.detect.fusion import TILE_PASS_REMEASURE, TilePassBudget

    budget = TilePassBudget(0.065)
    budget.wanted(0.0)
    budget.record(0.080)  # longer than the whole budget: every pair would skip it for good
    assert [budget.wanted(0.0) for _ in range(TILE_PASS_REMEASURE)] == [False] * TILE_PASS_REMEASURE
    assert budget.wanted(0.0), "the machine may be faster now: one pass is run to find out"
    assert not budget.wanted(0.0)


def test_a_zero_budget_always_fuses_and_a_negative_one_is_refused() -> None:
    from gldt_core.detect.fusion import TilePassBudget

    budget = TilePassBudget(0.0)
    budget.record(1.0)
    assert [budget.wanted(5.0) for _ in range(50)] == [True] * 50
    with pytest.raises(ValueError, match="tile pass budget"):
        TilePassBudget(-0.01)
    with pytest.raises(ValueError, match="tile pass budget"):
        TilePassBudget(float("nan"))


def test_a_tile_detector_that_cuts_above_half_the_threshold_is_refused() -> None:
    from gldt_core.detect import DetectorConfigError, GlobalDetector, LocalDetector

    with pytest.raises(DetectorConfigError, match="at most 0.05"):
        GlobalDetector(score_threshold=0.1, tile_detector=LocalDetector(score_threshold=0.1))
    from gldt_core.detect.fusion import build_tile_detector

    with pytest.raises(DetectorConfigError, match="needs the second stage"):
        build_tile_detector(None, {"second_stage": None, "score_threshold": 0.1})


def test_tile_fusion_is_a_config_key_on_by_default_that_needs_the_second_stage(tmp_path: object) -> None:
    from pathlib import Path

    from gldt_core.system.config import load_config

    folder = Path(str(tmp_path))
    assert load_config(None).detector.tile_fusion, "on by default"
    (folder / "off.yaml").write_text("detector: {tile_fusion: false}\n")
    assert not load_config(folder / "off.yaml").detector.tile_fusion
    # The second stage off alone leaves the default fusion on: one line that says what to set.
    (folder / "bad.yaml").write_text("detector: {second_stage: null}\n")
    with pytest.raises(ValueError, match="tile_fusion needs the second stage") as error:
        load_config(folder / "bad.yaml")
    assert "\n" not in str(error.value) and "tile_fusion: false" in str(error.value)
    (folder / "alone.yaml").write_text("detector: {second_stage: null, tile_fusion: false}\n")
    assert load_config(folder / "alone.yaml").detector.second_stage is None


def test_the_global_model_opens_before_the_tile_detector_is_built(tmp_path: object) -> None:
    """A broken global model is the error a user sees, not one of the tile detector's: the function
    that builds it is called only once AM-YOLO has opened, and what it returns must be a
    LocalDetector."""
    from pathlib import Path

    from gldt_core.detect import GlobalDetector
    from gldt_core.detect.session import DetectorConfigError

    calls: list[int] = []

    def tiles() -> object:
        calls.append(1)
        return object()

    missing = Path(str(tmp_path)) / "missing.onnx"
    with pytest.raises((DetectorConfigError, FileNotFoundError), match="missing.onnx"):
        GlobalDetector(missing, tile_detector=tiles, num_threads=1)  # type: ignore[arg-type]
    assert calls == []
    with pytest.raises(TypeError, match="not a LocalDetector"):
        GlobalDetector(tile_detector=tiles, num_threads=1)  # type: ignore[arg-type]
    assert calls == [1]


def test_the_systems_ld_detector_shares_the_tile_detectors_models_and_detects_at_its_own_threshold() -> None:
    """With tile fusion the offline system opens the local model and its second stage once: the LD
    frames' detector is the tile detector at the LD threshold, and finds what a detector opened on
    its own at that threshold finds."""
    from gldt_core.detect import LocalDetector
    from gldt_core.system.config import load_config
    from gldt_core.system.gldt_system import build_detectors

    config = load_config(None)
    assert config.detector.tile_fusion and config.scheduler.local_enabled
    global_detector, local_detector = build_detectors(config)
    tiles = global_detector.tile_detector  # type: ignore[attr-defined]
    assert isinstance(local_detector, LocalDetector) and isinstance(tiles, LocalDetector)
    assert local_detector.session is tiles.session
    assert local_detector.second_stage is not None and tiles.second_stage is not None
    assert local_detector.second_stage.session is tiles.second_stage.session
    threshold = config.detector.score_threshold
    assert threshold is not None
    assert local_detector.score_threshold == threshold and tiles.score_threshold == threshold / 2
    assert tiles.second_stage.score_threshold == threshold / 2, "the twin's threshold is its own"
    alone = LocalDetector(classes=config.detector.classes, score_threshold=threshold)
    rois = np.array([[150, 100, 450, 400], [0, 0, 300, 300]])
    found = 0
    for previous, current in real_pairs(16):
        mine = local_detector.detect_rois(current, rois, previous)
        np.testing.assert_allclose(mine, alone.detect_rois(current, rois, previous), atol=1e-5)
        low = tiles.detect_rois(current, rois, previous)
        assert len(low) >= len(mine) and (low[:, 4] >= threshold / 2).all()
        found += len(mine)
    assert found >= 1, "the sample bag's drone is found in some of these ROIs"
    with pytest.raises(DetectorConfigError, match=r"score_threshold must be in \[0, 1\], got 1.5"):
        tiles.at_score_threshold(1.5)
