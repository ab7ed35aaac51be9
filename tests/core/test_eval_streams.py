"""Detection streams built from ground truth: the failure modes the tracking benchmark relies on."""

from __future__ import annotations

import numpy as np
import pytest

from gldt_core.eval import evaluate_sequence
from gldt_core.eval.streams import StreamParams, detections_from_gt, simple_multi_target_gt


def test_streams_are_deterministic_per_seed_and_differ_between_seeds() -> None:
    gt = simple_multi_target_gt(0, 200)
    a = detections_from_gt(gt, 5, (1920, 1080))
    b = detections_from_gt(gt, 5, (1920, 1080))
    c = detections_from_gt(gt, 6, (1920, 1080))
    np.testing.assert_array_equal(a, b)
    assert a.shape != c.shape or not np.array_equal(a, c)


def test_misses_come_in_bursts() -> None:
    gt = simple_multi_target_gt(1, 3000, targets=1)
    params = StreamParams(miss_rate=0.0, fp_rate=0.0, distractor_rate=0.0)
    dets = detections_from_gt(gt, 1, (1920, 1080), params)
    present = np.zeros(3001, dtype=bool)
    present[dets[:, 0].astype(int)] = True
    missing = ~present[1:]
    runs, current = [], 0
    for m in missing:
        if m:
            current += 1
        elif current:
            runs.append(current)
            current = 0
    assert runs and min(runs) >= params.burst_frames[0] and max(runs) <= params.burst_frames[1]
    # The burst rate is per frame outside bursts: about rate * frames bursts.
    assert 0.3 * params.burst_rate * 3000 < len(runs) < 2.0 * params.burst_rate * 3000


def test_a_perfect_stream_tracks_perfectly_and_scores_are_in_their_bands() -> None:
    gt = simple_multi_target_gt(2, 100, targets=2)
    clean = StreamParams(
        burst_rate=0.0, miss_rate=0.0, jitter_frac=0.0, jitter_px=0.0, size_jitter_frac=0.0, fp_rate=0.0
    )
    dets = detections_from_gt(gt, 0, (1920, 1080), clean)
    assert len(dets) == len(gt)
    low = (dets[:, 6] >= 0.15) & (dets[:, 6] <= 0.5)
    high = (dets[:, 6] >= 0.55) & (dets[:, 6] <= 0.95)
    assert np.all(low | high) and 0.1 < low.mean() < 0.3
    pred = dets.copy()
    pred[:, 1] = gt[:, 1]  # same order as gt: give them the true ids
    res = evaluate_sequence(gt, pred)
    assert res["HOTA"] == pytest.approx(1.0) and res["IDSW"] == 0


def test_false_positives_and_distractors_are_added() -> None:
    gt = simple_multi_target_gt(3, 300, targets=1)
    bird = gt.copy()
    bird[:, 1] = 1001
    bird[:, 7] = 2
    bird[:, 2] += 300
    both = np.vstack([gt, bird])
    params = StreamParams(burst_rate=0.0, miss_rate=0.0, fp_rate=0.5, distractor_rate=0.5)
    dets = detections_from_gt(both, 3, (1920, 1080), params)
    extra = len(dets) - len(gt)
    # About 0.5 clutter + 0.5 bird detections per frame over 300 frames.
    assert 200 < extra < 400


def test_column_one_says_where_each_detection_came_from() -> None:
    gt = simple_multi_target_gt(4, 200, targets=3)
    bird = gt[gt[:, 1] == 1].copy()
    bird[:, 1] = 1001
    bird[:, 7] = 2
    bird[:, 3] += 200
    both = np.vstack([gt, bird])
    params = StreamParams(fp_rate=0.5, distractor_rate=0.5, clutter_tracks_rate=0.02)
    dets = detections_from_gt(both, 7, (1920, 1080), params)
    sources = set(np.unique(dets[:, 1]).astype(int))
    assert {1, 2, 3, -1, -2} == sources
    index = {(int(r[0]), int(r[1])): r for r in both}
    for row in dets:
        source = int(row[1])
        if source == -1:
            continue
        truth = index[(int(row[0]), 1001 if source == -2 else source)]
        centre = row[2:4] + row[4:6] / 2
        true_centre = truth[2:4] + truth[4:6] / 2
        assert np.hypot(*(centre - true_centre)) < 1.0 * max(truth[4], truth[5]) + 3  # jitter, not another object
    # Independent and persistent clutter both say -1.
    assert (dets[:, 1] == -1).sum() > 100


def test_the_new_failure_modes_leave_the_default_stream_unchanged() -> None:
    gt = simple_multi_target_gt(5, 150, targets=2)
    plain = detections_from_gt(gt, 3, (1920, 1080))
    drifting = detections_from_gt(gt, 3, (1920, 1080), StreamParams(clutter_tracks_rate=0.05))
    # The persistent clutter draws from its own generator: every other row is the same.
    assert len(drifting) > len(plain)
    kept = np.array([any(np.array_equal(r, p) for p in drifting) for r in plain])
    assert kept.all()
    beta = detections_from_gt(gt, 3, (1920, 1080), StreamParams(score_beta=(2.0, 5.0), low_score_rate=0.0))
    true = beta[beta[:, 1] > 0, 6]
    assert 0.15 < true.mean() < 0.45 and (true < 0.15).any()
