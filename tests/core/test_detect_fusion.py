"""gldt_core.detect.fusion: two detectors' calibrated boxes fused by the mean of their scores."""

from __future__ import annotations

import numpy as np
import pytest

from gldt_core.detect.fusion import MATCH_IOU, fuse_detections, greedy_pairs


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
