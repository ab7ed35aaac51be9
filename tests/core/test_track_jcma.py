"""JCMA's cost terms (eqs. 9-15) on configurations whose value is known by hand."""

from __future__ import annotations

import numpy as np
import pytest

from gldt_core.track.jcma import JcmaWeights, TrackMotion, jcma_cost, relational_cost


def motion_for(pred_boxes: np.ndarray, v_avg: np.ndarray | None = None, has_motion: bool = False) -> TrackMotion:
    n = len(pred_boxes)
    centres = (pred_boxes[:, :2] + pred_boxes[:, 2:]) / 2
    v = np.zeros((n, 2)) if v_avg is None else np.asarray(v_avg, dtype=float)
    return TrackMotion.from_fields(
        pred_xyxy=pred_boxes,
        last_obs_c=centres - v,
        elapsed_ref=np.ones(n),
        v_avg=v,
        v_last=v.copy(),
        has_motion=np.full(n, has_motion),
    )


ONLY_IOU = JcmaWeights(w_iou=1, w_dist=0, w_motion=0, w_rel=0)
ONLY_DIST = JcmaWeights(w_iou=0, w_dist=1, w_motion=0, w_rel=0)


def test_iou_term_is_one_minus_iou() -> None:
    track = np.array([[0.0, 0.0, 10.0, 10.0]])
    det = np.array([[5.0, 0.0, 15.0, 10.0]])  # overlap 50 of union 150
    cost, gate = jcma_cost(motion_for(track), det, np.zeros((1, 2)), np.array([0]), ONLY_IOU)
    assert cost[0, 0] == pytest.approx(1 - 50 / 150)
    assert gate[0, 0]


def test_distance_term_uses_the_adaptive_scale_of_eq_12() -> None:
    track = np.array([[0.0, 0.0, 10.0, 10.0]])
    dets = np.array([[15.0, 0.0, 25.0, 10.0], [0.0, 40.0, 10.0, 50.0]])
    cost, gate = jcma_cost(motion_for(track), dets, np.zeros((1, 2)), np.array([0]), ONLY_DIST)
    # s = (10 + 10 + 10 + 10) / 4 * 2 = 20: 15 px -> 0.75, 40 px -> clipped to 1.
    np.testing.assert_allclose(cost[0], [0.75, 1.0])
    # Neither overlapping nor within s: not allowed to match at all.
    assert gate[0, 0] and not gate[0, 1]


def test_motion_term_penalises_reversal_and_speed_change() -> None:
    track = np.array([[100.0, 100.0, 110.0, 110.0]])
    v = np.array([[3.0, 0.0]])  # px per reference frame, to the right
    ahead = np.array([[103.0, 100.0, 113.0, 110.0]])
    behind = np.array([[97.0, 100.0, 107.0, 110.0]])
    direction_only = JcmaWeights(w_iou=0, w_dist=0, w_motion=1, w_rel=0, b_speed=0, b_direction=1, b_acceleration=0)
    motion = motion_for(track, v, has_motion=True)
    c_ahead, _ = jcma_cost(motion, ahead, np.zeros((1, 2)), np.array([0]), direction_only)
    c_behind, _ = jcma_cost(motion, behind, np.zeros((1, 2)), np.array([0]), direction_only)
    # Expected velocity ahead: +6 px/frame from the last observation (same direction): 0.
    assert c_ahead[0, 0] == pytest.approx(0.0, abs=1e-9)
    # Behind: expected velocity 0 px/frame -> below min_speed, direction undefined: 0 by choice;
    # a clear reversal 10 px back gives pi rad -> clipped to 1.
    far_behind = np.array([[87.0, 100.0, 97.0, 110.0]])
    c_rev, _ = jcma_cost(motion, far_behind, np.zeros((1, 2)), np.array([0]), direction_only)
    assert c_behind[0, 0] == pytest.approx(0.0)
    assert c_rev[0, 0] == pytest.approx(1.0)
    speed_only = JcmaWeights(w_iou=0, w_dist=0, w_motion=1, w_rel=0, b_speed=1, b_direction=0, b_acceleration=0)
    c_speed, _ = jcma_cost(motion, far_behind, np.zeros((1, 2)), np.array([0]), speed_only)
    # Last observation at x = 102 (centre 105 minus one frame of motion); detection centre at 92:
    # |v_exp - v_avg| / max(50, 2 + v_avg) = |10 - 3| / 50
    assert c_speed[0, 0] == pytest.approx(7.0 / 50.0)


def test_new_tracks_have_no_motion_cost() -> None:
    track = np.array([[100.0, 100.0, 110.0, 110.0]])
    det = np.array([[60.0, 100.0, 70.0, 110.0]])
    weights = JcmaWeights(w_iou=0, w_dist=0, w_motion=1, w_rel=0)
    cost, _ = jcma_cost(
        motion_for(track, [[3.0, 0.0]], has_motion=False), det, np.zeros((1, 2)), np.array([0]), weights
    )
    assert cost[0, 0] == 0.0


def test_relational_cost_prefers_the_detection_that_keeps_the_formation() -> None:
    tracks = np.array([[0.0, 0.0], [100.0, 0.0]])
    dets = np.array([[0.0, 0.0], [100.0, 0.0]])
    rel = relational_cost(tracks, dets, tracks, np.array([0, 1]))
    # Detection at its own track's place: the other object is seen in the same direction (cos 1).
    assert rel[0, 0] == pytest.approx(0.0) and rel[1, 1] == pytest.approx(0.0)
    # Detection on top of the other object: zero vector contributes cos 0 -> cost 1.
    assert rel[0, 1] == pytest.approx(1.0) and rel[1, 0] == pytest.approx(1.0)
    # Behind the other object, seen from the opposite side: cos -1 -> cost 2.
    rel2 = relational_cost(tracks[:1], np.array([[200.0, 0.0]]), tracks, np.array([0]))
    assert rel2[0, 0] == pytest.approx(2.0)


def test_a_lone_track_has_no_relational_cost() -> None:
    rel = relational_cost(
        np.array([[5.0, 5.0]]), np.array([[50.0, 9.0], [1.0, 2.0]]), np.array([[5.0, 5.0]]), np.array([0])
    )
    np.testing.assert_array_equal(rel, np.zeros((1, 2)))


def test_full_cost_is_the_weighted_sum_of_table_one() -> None:
    rng = np.random.default_rng(0)
    tracks = np.column_stack([rng.uniform(0, 200, (4, 2)), np.zeros((4, 2))])
    tracks[:, 2:] = tracks[:, :2] + rng.uniform(8, 30, (4, 2))
    dets = tracks[[1, 0, 3]] + rng.normal(0, 3, (3, 4))
    motion = motion_for(tracks, rng.normal(0, 3, (4, 2)), has_motion=True)
    centres = (tracks[:, :2] + tracks[:, 2:]) / 2
    index = np.arange(4)
    parts = []
    for single in (JcmaWeights(1, 0, 0, 0), JcmaWeights(0, 1, 0, 0), JcmaWeights(0, 0, 1, 0), JcmaWeights(0, 0, 0, 1)):
        parts.append(jcma_cost(motion, dets, centres, index, single)[0])
    total, _ = jcma_cost(motion, dets, centres, index, JcmaWeights())
    np.testing.assert_allclose(total, 0.3 * parts[0] + 0.3 * parts[1] + 0.2 * parts[2] + 0.2 * parts[3])


def test_the_default_context_is_the_pool_itself() -> None:
    """No context given: the objects of eq. 15 are the pool's tracks at their predicted centres,
    each track leaving itself out."""
    rng = np.random.default_rng(3)
    for n in (3, 7):  # one pool costed on Python floats, one on arrays
        tracks = np.column_stack([rng.uniform(0, 200, (n, 2)), np.zeros((n, 2))])
        tracks[:, 2:] = tracks[:, :2] + rng.uniform(8, 30, (n, 2))
        dets = tracks[rng.integers(0, n, n)] + rng.normal(0, 3, (n, 4))
        motion = motion_for(tracks, rng.normal(0, 3, (n, 2)), has_motion=True)
        centres = (tracks[:, :2] + tracks[:, 2:]) / 2
        default = jcma_cost(motion, dets, None, None, JcmaWeights())
        explicit = jcma_cost(motion, dets, centres, np.arange(n), JcmaWeights())
        np.testing.assert_array_equal(default[0], explicit[0])
        np.testing.assert_array_equal(default[1], explicit[1])


def test_context_and_its_index_come_together() -> None:
    motion = motion_for(np.array([[0.0, 0.0, 10.0, 10.0]]))
    with pytest.raises(ValueError, match="both"):
        jcma_cost(motion, np.array([[0.0, 0.0, 10.0, 10.0]]), np.zeros((1, 2)), None, JcmaWeights())
