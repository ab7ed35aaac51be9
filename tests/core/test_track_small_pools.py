"""The small-pool fast paths (Python floats) give what the vectorised numpy paths give.

At a handful of targets the tracker runs on Python floats where numpy's per-call overhead would
dominate (JCMA's cost, PMR's match and pre-gate, box conversions, input checks). Each test forces
the vectorised path by setting the size threshold to 0 and compares: exactly where both paths
do the same IEEE operations, and to 1e-14 where they need not round alike: eq. 15's BLAS product
(FMA, alignment-dependent kernels), and the costs' transcendental functions, which numpy computes
with its own SIMD kernels on AVX-512 machines (a few ulp from Python's libm; bit-identical on
AVX2-only ones).
"""

from __future__ import annotations

import numpy as np
import pytest

from gldt_core.eval.streams import StreamParams, detections_from_gt
from gldt_core.sim import scene_ground_truth
from gldt_core.track import JPTrack, JPTrackConfig, Track, TrackState, base, boxes, jcma, jptrack, pmr, state
from gldt_core.track.boxes import validate_detections
from gldt_core.track.jcma import JcmaWeights, TrackMotion, jcma_cost, relational_cost
from gldt_core.track.kalman import predict_many
from gldt_core.track.pmr import fit_pmr, p_match_many
from gldt_core.track.runner import track_detection_rows
from gldt_core.track.state import boxes_xyxy


def random_pool(rng: np.random.Generator, n_t: int, n_d: int) -> tuple[TrackMotion, np.ndarray]:
    """Tracks and detections on a small patch (so pairs overlap, touch and miss), with the corner
    cases the cost special-cases: no motion history, zero velocities (stationary targets), a
    detection exactly on a track's predicted or last observed centre."""
    xy = rng.uniform(0, 120, (n_t, 2))
    boxes = np.hstack([xy, xy + rng.uniform(2, 40, (n_t, 2))])
    centres = (boxes[:, :2] + boxes[:, 2:]) * 0.5
    dets = boxes[rng.integers(0, n_t, n_d)] + rng.normal(0, rng.choice([0.5, 5.0, 40.0]), (n_d, 4))
    dets[:, 2:] = np.maximum(dets[:, 2:], dets[:, :2] + 1.0)
    if rng.random() < 0.3:
        dets[0] = boxes[0]  # exactly on a track: zero-length vectors, IoU 1
    v_avg = rng.normal(0, rng.choice([0.3, 3.0, 30.0]), (n_t, 2))
    v_last = v_avg + rng.normal(0, 2.0, (n_t, 2))
    still = rng.random(n_t) < 0.2
    v_avg[still] = 0.0
    v_last[still] = 0.0
    last_c = centres - v_avg * rng.uniform(0.5, 2.0)
    if rng.random() < 0.3:
        last_c[0] = (dets[0, :2] + dets[0, 2:]) * 0.5  # detection on the last observation
    has = rng.random(n_t) < rng.choice([0.0, 0.5, 1.0])
    elapsed = rng.choice([1.0, 2.0, 0.5, 7.0], n_t)
    return TrackMotion(boxes, last_c, elapsed, v_avg, v_last, has), dets


def vectorised(monkeypatch: pytest.MonkeyPatch, *args):
    with monkeypatch.context() as m:
        m.setattr(jcma, "SMALL_POOL_PAIRS", 0)
        return jcma_cost(*args)


@pytest.mark.parametrize("seed", range(4))
def test_small_pool_path_equals_the_vectorised_path(seed: int, monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(seed)
    no_rel = JcmaWeights(w_rel=0.0)
    for _ in range(400):
        n_t, n_d = int(rng.integers(1, 5)), int(rng.integers(1, 5))
        if n_t * n_d > jcma.SMALL_POOL_PAIRS:
            continue
        motion, dets = random_pool(rng, n_t, n_d)
        centres = (motion.pred_xyxy[:, :2] + motion.pred_xyxy[:, 2:]) * 0.5
        context, index = centres, np.arange(n_t)
        if rng.random() < 0.3:  # context objects that are not the pool's tracks
            context = np.vstack([centres, rng.uniform(0, 120, (int(rng.integers(0, 3)), 2))])
            index = np.where(rng.random(n_t) < 0.5, index, -1)
        if rng.random() < 0.1:  # a lone track: no relational context
            context, index = centres[:1], np.zeros(n_t, dtype=np.int64)
        # Every term but eq. 15's BLAS product is the same formula; numpy's AVX-512 kernels for
        # its transcendental functions may round a few ulp away from libm (see module docstring).
        small = jcma_cost(motion, dets, context, index, no_rel)
        big = vectorised(monkeypatch, motion, dets, context, index, no_rel)
        np.testing.assert_allclose(small[0], big[0], rtol=0, atol=1e-14)
        np.testing.assert_array_equal(small[1], big[1])
        # Eq. 15: sequential sum vs the BLAS product (FMA, alignment-dependent kernels).
        full = jcma_cost(motion, dets, context, index, JcmaWeights())
        full_big = vectorised(monkeypatch, motion, dets, context, index, JcmaWeights())
        np.testing.assert_allclose(full[0], full_big[0], rtol=0, atol=1e-14)
        np.testing.assert_array_equal(full[1], full_big[1])
        assert full[0].shape == (n_t, n_d) and full[1].dtype == bool


def test_small_pool_relational_term_matches_relational_cost() -> None:
    rng = np.random.default_rng(7)
    only_rel = JcmaWeights(w_iou=0, w_dist=0, w_motion=0, w_rel=1)
    for _ in range(300):
        n_t, n_d = int(rng.integers(1, 5)), int(rng.integers(1, 5))
        if n_t * n_d > jcma.SMALL_POOL_PAIRS:
            continue
        motion, dets = random_pool(rng, n_t, n_d)
        centres = (motion.pred_xyxy[:, :2] + motion.pred_xyxy[:, 2:]) * 0.5
        cost, _ = jcma_cost(motion, dets, centres, np.arange(n_t), only_rel)
        expected = relational_cost(centres, (dets[:, :2] + dets[:, 2:]) * 0.5, centres, np.arange(n_t))
        np.testing.assert_allclose(cost, expected, rtol=0, atol=1e-14)


def pmr_history(n: int, rng: np.random.Generator) -> np.ndarray:
    t = np.arange(n) / 30.0
    vx = rng.normal(0, 60, n) + np.where(np.arange(n) < n // 2, 90.0, -40.0)
    vy = rng.normal(0, 20, n)
    cx = 300 + np.cumsum(vx) / 30.0
    cy = 200 + np.cumsum(vy) / 30.0
    return np.column_stack([t, cx, cy, cx / 1920, cy / 1080, vx, vy, np.full(n, 16.0), np.full(n, 11.0)])


def test_small_p_match_equals_the_stacked_path(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(3)
    for _ in range(60):
        models = [
            fit_pmr(pmr_history(int(rng.integers(2, 31)), rng), float(rng.uniform(0.5, 1.5)), 0.1, 30.0)
            for _ in range(int(rng.integers(1, 4)))
        ]
        centres = rng.uniform(150, 450, (int(rng.integers(1, 5)), 2))
        t = float(rng.uniform(1.0, 3.0))
        small = p_match_many(models, centres, t, 30.0, 0.5, 2.0)
        with monkeypatch.context() as m:
            m.setattr(pmr, "SMALL_MATCH_PAIRS", 0)
            big = p_match_many(models, centres, t, 30.0, 0.5, 2.0)
        if len(models) > 1:  # the stacked path: the same sums in the same order
            np.testing.assert_array_equal(small, big)
        else:  # numpy's one-model shortcut is a BLAS product
            np.testing.assert_allclose(small, big, rtol=1e-14, atol=1e-300)


def lost_tracks(rng: np.random.Generator, n: int) -> list[Track]:
    tracks = []
    for i in range(n):
        xy = rng.uniform(0, 400, 2)
        tr = Track(
            i + 1, np.array([*xy, *(xy + rng.uniform(4, 30, 2))]), 0.9, 0.0, TrackState.CONFIRMED, 30.0, 30, (0.5, 0.5)
        )
        tr.kf.mean[4:6] = rng.normal(0, 200, 2) * (rng.random() < 0.8)  # some stationary
        tr.last_update_t = float(rng.choice([0.0, -0.5, -2.0]))
        tracks.append(tr)
    predict_many([tr.kf for tr in tracks], np.full(n, 0.4))
    return tracks


def test_small_pmr_pre_gate_equals_the_vectorised_one(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(4)
    tracker = JPTrack()
    decided = set()
    for _ in range(200):
        lost = lost_tracks(rng, int(rng.integers(1, 6)))
        centres = rng.uniform(-50, 500, (int(rng.integers(1, 6)), 2))
        small = tracker._worth_modelling(lost, centres, 0.4)
        with monkeypatch.context() as m:
            m.setattr(jptrack, "SMALL_GATE_PAIRS", 0)
            big = tracker._worth_modelling(lost, centres, 0.4)
        assert small == big
        decided.update(small)
    assert decided == {True, False}


def test_box_conversions_equal_the_property_exactly() -> None:
    rng = np.random.default_rng(5)
    tracks = lost_tracks(rng, 3 * state.SMALL_BOX_COUNT)
    expected = np.array([tr.box_xyxy for tr in tracks])
    for n in (1, state.SMALL_BOX_COUNT, len(tracks)):  # both sides of the threshold
        np.testing.assert_array_equal(boxes_xyxy(tracks[:n]), expected[:n])
        assert state.box_rows(tracks[:n]) == [tuple(row) for row in expected[:n].tolist()]


@pytest.mark.parametrize(
    "bad",
    [
        (0, 0, float("nan")),
        (1, 2, float("inf")),
        (2, 0, float("-inf")),
        (0, 2, -5.0),
        (1, 3, -5.0),
        (2, 4, 1.5),
        (0, 4, -0.1),
    ],
)
def test_input_check_fast_path_reports_the_same_errors(
    bad: tuple[int, int, float], monkeypatch: pytest.MonkeyPatch
) -> None:
    dets = np.array([[10.0, 10.0, 20.0, 20.0, 0.9], [30.0, 5.0, 42.0, 17.0, 0.4], [0.0, 0.0, 1.0, 1.0, 1.0]])
    np.testing.assert_array_equal(validate_detections(dets, 0.0, 3), dets)
    row, col, value = bad
    dets[row, col] = value
    with pytest.raises(ValueError) as small:
        validate_detections(dets, 0.0, 3)
    with monkeypatch.context() as m:
        m.setattr(boxes, "SMALL_VALIDATE_ROWS", 0)
        with pytest.raises(ValueError) as big:
            validate_detections(dets, 0.0, 3)
    assert str(small.value) == str(big.value)


def test_relative_positions_fast_path_is_exact(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(6)
    xy = rng.uniform(0, 1900, (7, 2))
    dets = np.column_stack([xy, xy + rng.uniform(1, 20, (7, 2)), rng.uniform(0, 1, 7)])
    tracker = JPTrack(JPTrackConfig(image_size=(1920, 1080)))
    small = tracker._relative_positions(dets, None, 0.0, None)
    with monkeypatch.context() as m:
        m.setattr(base, "SMALL_REL_ROWS", 0)
        assert tracker._relative_positions(dets, None, 0.0, None) == small


@pytest.mark.parametrize("config", [JPTrackConfig(), JPTrackConfig(use_pmr=False), JPTrackConfig(tau_t=0.3)])
def test_tracker_output_is_the_same_with_every_fast_path_off(
    config: JPTrackConfig, monkeypatch: pytest.MonkeyPatch
) -> None:
    gt = scene_ground_truth(5004, 150, targets=4)
    hard = StreamParams(burst_rate=0.05, miss_rate=0.15, fp_rate=1.0, low_score_rate=0.4)
    dets = detections_from_gt(gt, 4, (1920, 1080), hard)
    fast = track_detection_rows(JPTrack(config), dets, 30.0, num_frames=150)
    with monkeypatch.context() as m:
        for module, name in [
            (jcma, "SMALL_POOL_PAIRS"),
            (pmr, "SMALL_MATCH_PAIRS"),
            (jptrack, "SMALL_GATE_PAIRS"),
            (state, "SMALL_BOX_COUNT"),
            (boxes, "SMALL_VALIDATE_ROWS"),
            (boxes, "SCALAR_IOU_PAIRS"),
            (base, "SCALAR_IOU_PAIRS"),
            (base, "SMALL_REL_ROWS"),
        ]:
            m.setattr(module, name, 0)
        slow = track_detection_rows(JPTrack(config), dets, 30.0, num_frames=150)
    assert len(fast) > 50
    np.testing.assert_array_equal(fast, slow)


def test_motion_rows_are_not_reused_across_a_reset() -> None:
    """The per-frame motion cache is keyed by time and hits; a reset (ids restart, time may
    repeat) must not serve rows of the forgotten tracks."""
    gt = scene_ground_truth(5005, 60, targets=3)
    dets = detections_from_gt(gt, 5, (1920, 1080), StreamParams())
    tracker = JPTrack()
    first = track_detection_rows(tracker, dets, 30.0, num_frames=60)
    tracker.reset()
    again = track_detection_rows(tracker, dets, 30.0, num_frames=60)
    np.testing.assert_array_equal(first, again)
    np.testing.assert_array_equal(again, track_detection_rows(JPTrack(), dets, 30.0, num_frames=60))


def test_uniform_time_step_prediction_equals_one_filter_at_a_time() -> None:
    """predict_many as the tracker calls it (every filter advances by the same dt) is exactly
    ``predict`` on each filter, including the strided-diagonal noise update and a zero step."""
    from gldt_core.track.kalman import ConstantVelocityKalman

    rng = np.random.default_rng(8)
    boxes = np.column_stack([rng.uniform(0, 500, (6, 2)), rng.uniform(2, 40, (6, 2))])
    singles = [ConstantVelocityKalman(b) for b in boxes]
    batch = [ConstantVelocityKalman(b) for b in boxes]
    for a, b in zip(singles, batch):
        a.mean[4:] = b.mean[4:] = rng.normal(0, 80, 4)
    for dt in (1 / 30, 0.1, 0.0, 1 / 15):
        for f in singles:
            f.predict(dt)
        predict_many(batch, np.full(len(batch), dt))
        for a, b in zip(singles, batch):
            np.testing.assert_array_equal(b.mean, a.mean)
            np.testing.assert_array_equal(b.covariance, a.covariance)
