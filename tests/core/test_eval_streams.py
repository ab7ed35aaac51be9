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
