"""AP / PR metrics used by `gldt bench detection` and training validation (numpy only)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gldt_core.eval.detection_metrics import (
    average_precision,
    box_iou,
    detection_summary,
    match,
    pr_auc,
    recall_at_confidence,
)


def box(x: float, y: float, w: float, h: float, score: float | None = None) -> list[float]:
    return [x, y, x + w, y + h] + ([score] if score is not None else [])


def test_perfect_detections_give_ap_one() -> None:
    gts = [np.array([box(10, 10, 20, 20)]), np.array([box(50, 50, 8, 8), box(0, 0, 30, 30)])]
    dets = [np.array([g + [0.9] for g in gt.tolist()]) for gt in gts]
    summary = detection_summary(dets, gts)
    assert summary["ap50"] == pytest.approx(1.0)
    assert summary["ap50_95"] == pytest.approx(1.0)
    assert summary["ap_small"] == pytest.approx(1.0)
    assert summary["pr_auc"] == pytest.approx(1.0)


def test_false_positive_ranked_first_halves_precision() -> None:
    gts = [np.array([box(10, 10, 20, 20)])]
    dets = [np.array([box(100, 100, 20, 20, 0.95), box(10, 10, 20, 20, 0.5)])]
    result = match(dets, gts, 0.5)
    assert result.true_positive.tolist() == [False, True]
    assert average_precision(result) == pytest.approx(0.5)


def test_half_recall_and_duplicates() -> None:
    gts = [np.array([box(10, 10, 20, 20), box(60, 60, 20, 20)])]
    dets = [np.array([box(10, 10, 20, 20, 0.9), box(11, 10, 20, 20, 0.8)])]  # duplicate on the same object
    result = match(dets, gts, 0.5)
    assert result.true_positive.tolist() == [True, False]
    # Recall reaches 0.5 at precision 1: 51 of the 101 recall points (0, 0.01, ..., 0.5).
    assert average_precision(result) == pytest.approx(51 / 101)
    assert recall_at_confidence(result, np.array([0.0, 0.85, 0.95])).tolist() == [0.5, 0.5, 0.0]


def test_iou_threshold_matters_for_ap50_95() -> None:
    gts = [np.array([box(0, 0, 10, 10)])]
    dets = [np.array([box(2, 0, 10, 10, 0.9)])]  # IoU = 80 / 120 = 0.667
    assert box_iou(dets[0][:, :4], gts[0])[0, 0] == pytest.approx(80 / 120)
    summary = detection_summary(dets, gts)
    assert summary["ap50"] == pytest.approx(1.0)
    assert summary["ap50_95"] == pytest.approx(4 / 10)  # thresholds 0.50, 0.55, 0.60, 0.65


def test_small_area_ignores_large_objects() -> None:
    gts = [np.array([box(0, 0, 100, 100), box(200, 200, 10, 10)])]
    dets = [np.array([box(0, 0, 100, 100, 0.9)])]  # only the large one is found
    summary = detection_summary(dets, gts)
    assert summary["ap_small"] == pytest.approx(0.0)
    assert math.isnan(detection_summary([np.zeros((0, 5))], [np.array([box(0, 0, 100, 100)])])["ap_small"])


def test_pr_auc_and_mismatched_lists() -> None:
    gts = [np.array([box(0, 0, 10, 10)]), np.array([box(0, 0, 10, 10)])]
    dets = [np.array([box(0, 0, 10, 10, 0.9)]), np.zeros((0, 5))]
    assert pr_auc(match(dets, gts, 0.5)) == pytest.approx(0.5)
    with pytest.raises(ValueError, match="2 detection lists but 1"):
        match(dets, gts[:1], 0.5)


def test_error_breakdown_puts_each_drone_in_one_bucket_and_sorts_the_false_positives() -> None:
    from gldt_core.eval.detection_metrics import error_breakdown

    gts = [np.array([[0, 0, 10, 10], [100, 100, 110, 110], [200, 200, 210, 210], [300, 300, 310, 310]], float)]
    dets = [
        np.array(
            [
                [0, 0, 10, 10, 0.9, 1],  # found
                [1, 1, 11, 11, 0.8, 1],  # a second box on the found drone: a false positive on an object
                [100, 100, 110, 110, 0.7, 2],  # right box, called a bird
                [203, 203, 213, 213, 0.6, 1],  # IoU 0.32: the box is off (and a false positive on an object)
                [500, 500, 510, 510, 0.5, 1],  # background
                [600, 600, 610, 610, 0.1, 1],  # background, under the operating threshold
            ]
        )
    ]
    out = error_breakdown(dets, gts, target_class=1, score_threshold=0.25)
    assert out["num_gt"] == 4
    assert (out["found"], out["other_class"], out["poorly_placed"], out["missed"]) == (1, 1, 1, 1)
    assert (out["fp_on_object"], out["fp_background"]) == (2, 1)


def test_error_breakdown_takes_empty_frames_and_checks_lengths() -> None:
    from gldt_core.eval.detection_metrics import error_breakdown

    out = error_breakdown(
        [np.zeros((0, 6)), np.array([[5, 5, 9, 9, 0.9, 1]])], [np.zeros((0, 4)), np.zeros((0, 4))], 1, 0.25
    )
    assert out["num_gt"] == 0 and out["fp_background"] == 1 and out["fp_on_object"] == 0
    with pytest.raises(ValueError, match="2 detection lists but 1"):
        error_breakdown([np.zeros((0, 6))] * 2, [np.zeros((0, 4))], 1, 0.25)


def test_the_loose_reading_matches_boxes_that_miss_the_annotations_size() -> None:
    """Detections tight around targets annotated 1.6x as large (IoU 0.39): AP50 0, AP at 0.3 1."""
    truth = [np.array([[100.0, 100.0, 132.0, 126.0]]), np.array([[300.0, 200.0, 340.0, 232.0]])]
    tight = []
    for (x1, y1, x2, y2), score in zip((t[0] for t in truth), (0.9, 0.8)):
        cx, cy, w, h = (x1 + x2) / 2, (y1 + y2) / 2, (x2 - x1) / 1.6, (y2 - y1) / 1.6
        tight.append(np.array([[cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2, score]]))
    summary = detection_summary(tight, truth, loose_iou=0.3)
    assert summary["ap50"] == 0.0 and summary["ap_loose"] == pytest.approx(1.0)
    assert "ap_loose" not in detection_summary(tight, truth)
