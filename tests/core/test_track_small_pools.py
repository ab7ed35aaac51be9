"""Each tracker formula gives the same numbers on Python floats (small inputs) as on numpy arrays.

The formulas are written once and evaluated either way; :mod:`gldt_core.track.fastpath` holds the
one switch (``MAX_FLOAT_ITEMS``). These tests set it so that everything runs on floats, then on
arrays, over random inputs (hypothesis), and compare: exactly where both evaluations do the same
IEEE operations, and to 1e-14 for JCMA's cost, whose direction term uses ``atan2`` (numpy's own
SIMD kernel on AVX-512 machines, the C library's on floats) and whose eq. 15 sum is a BLAS product
on arrays (FMA, kernels that depend on alignment).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gldt_core.eval.streams import StreamParams, detections_from_gt
from gldt_core.sim import scene_ground_truth
from gldt_core.track import JPTrack, JPTrackConfig, Track, TrackState, fastpath
from gldt_core.track.boxes import iou_pairs_above, iou_xyxy, validate_detections
from gldt_core.track.jcma import JcmaWeights, TrackMotion, jcma_cost, relational_cost
from gldt_core.track.kalman import predict_many
from gldt_core.track.pmr import fit_pmr, p_match_many
from gldt_core.track.runner import track_detection_rows
from gldt_core.track.state import box_rows, boxes_xyxy

SEEDS = st.integers(0, 2**32 - 1)


@contextmanager
def evaluated_on(kind: str) -> Iterator[None]:
    """Every formula on Python floats (``"floats"``) or on numpy arrays (``"arrays"``)."""
    saved = fastpath.MAX_FLOAT_ITEMS
    fastpath.MAX_FLOAT_ITEMS = 10**9 if kind == "floats" else -1
    try:
        yield
    finally:
        fastpath.MAX_FLOAT_ITEMS = saved


def both_ways(fn: Callable[..., Any], *args: Any) -> tuple[Any, Any]:
    """``fn(*args)`` evaluated on floats, then on arrays."""
    with evaluated_on("floats"):
        on_floats = fn(*args)
    with evaluated_on("arrays"):
        on_arrays = fn(*args)
    return on_floats, on_arrays


def random_boxes(rng: np.random.Generator, n: int, near: np.ndarray | None = None) -> np.ndarray:
    """Boxes on a small patch (so that pairs overlap, touch and miss), or jittered copies of
    ``near``'s boxes (some exact copies)."""
    if near is None:
        xy = rng.uniform(0, 120, (n, 2))
        return np.hstack([xy, xy + rng.uniform(2, 40, (n, 2))])
    boxes = near[rng.integers(0, len(near), n)] + rng.normal(0, rng.choice([0.5, 5.0, 40.0]), (n, 4))
    boxes[:, 2:] = np.maximum(boxes[:, 2:], boxes[:, :2] + 1.0)
    boxes[rng.random(n) < 0.2] = near[0]
    return boxes


def random_pool(rng: np.random.Generator, n_t: int, n_d: int) -> tuple[np.ndarray, TrackMotion, np.ndarray]:
    """Predicted track boxes, their motion and detections, with the corner cases the cost special-
    cases: no motion history, zero velocities (stationary targets), a detection exactly on a
    track's predicted or last observed centre."""
    boxes = random_boxes(rng, n_t)
    centres = (boxes[:, :2] + boxes[:, 2:]) * 0.5
    dets = random_boxes(rng, n_d, near=boxes)
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
    return boxes, TrackMotion.from_fields(boxes, last_c, elapsed, v_avg, v_last, has), dets


def random_context(rng: np.random.Generator, boxes: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Eq. 15's objects: the pool itself (None), its centres plus others with some tracks not
    among them (index -1), or a lone object."""
    centres = (boxes[:, :2] + boxes[:, 2:]) * 0.5
    kind = rng.integers(0, 3)
    if kind == 0:
        return None, None
    if kind == 1:
        extra = rng.uniform(0, 120, (int(rng.integers(0, 3)), 2))
        index = np.where(rng.random(len(boxes)) < 0.5, np.arange(len(boxes)), -1)
        return np.vstack([centres, extra]), index
    return centres[:1], np.zeros(len(boxes), dtype=np.int64)


@settings(max_examples=300, deadline=None)
@given(seed=SEEDS, n_t=st.integers(1, 6), n_d=st.integers(1, 6))
def test_jcma_cost_is_the_same_on_floats_and_arrays(seed: int, n_t: int, n_d: int) -> None:
    rng = np.random.default_rng(seed)
    boxes, motion, dets = random_pool(rng, n_t, n_d)
    context, index = random_context(rng, boxes)
    # Only arithmetic, comparisons and the C library's hypot: bit for bit.
    geometric = JcmaWeights(w_motion=0.0, w_rel=0.0)
    on_floats, on_arrays = both_ways(jcma_cost, motion, dets, context, index, geometric)
    np.testing.assert_array_equal(on_floats[0], on_arrays[0])
    np.testing.assert_array_equal(on_floats[1], on_arrays[1])
    # With the direction (atan2) and relational (BLAS sum) terms: to a few ulp.
    on_floats, on_arrays = both_ways(jcma_cost, motion, dets, context, index, JcmaWeights())
    np.testing.assert_allclose(on_floats[0], on_arrays[0], rtol=0, atol=1e-14)
    np.testing.assert_array_equal(on_floats[1], on_arrays[1])
    assert on_floats[0].shape == (n_t, n_d) and on_floats[1].dtype == bool


@settings(max_examples=200, deadline=None)
@given(seed=SEEDS, n_t=st.integers(1, 5), n_d=st.integers(1, 5))
def test_the_relational_term_on_floats_is_relational_cost(seed: int, n_t: int, n_d: int) -> None:
    rng = np.random.default_rng(seed)
    boxes, motion, dets = random_pool(rng, n_t, n_d)
    centres = (boxes[:, :2] + boxes[:, 2:]) * 0.5
    only_rel = JcmaWeights(w_iou=0, w_dist=0, w_motion=0, w_rel=1)
    with evaluated_on("floats"):
        cost, _ = jcma_cost(motion, dets, None, None, only_rel)
    expected = relational_cost(centres, (dets[:, :2] + dets[:, 2:]) * 0.5, centres, np.arange(n_t))
    np.testing.assert_allclose(cost, expected, rtol=0, atol=1e-14)


@settings(max_examples=200, deadline=None)
@given(seed=SEEDS, n_a=st.integers(1, 7), n_b=st.integers(1, 7), thresh=st.sampled_from([0.0, 0.3, 0.85]))
def test_iou_is_the_same_on_floats_and_arrays(seed: int, n_a: int, n_b: int, thresh: float) -> None:
    rng = np.random.default_rng(seed)
    a = random_boxes(rng, n_a)
    b = random_boxes(rng, n_b, near=a)
    on_floats, on_arrays = both_ways(iou_xyxy, a, b)
    np.testing.assert_array_equal(on_floats, on_arrays)
    pairs = both_ways(iou_pairs_above, a, b, thresh)
    assert pairs[0] == pairs[1] == [(int(i), int(j)) for i, j in zip(*np.nonzero(on_arrays > thresh))]
    assert both_ways(iou_pairs_above, a.tolist(), b.tolist(), thresh) == pairs  # rows of floats alike


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


@settings(max_examples=100, deadline=None)
@given(seed=SEEDS, n=st.integers(1, 12))
def test_track_boxes_are_the_same_on_floats_and_arrays(seed: int, n: int) -> None:
    tracks = lost_tracks(np.random.default_rng(seed), n)
    expected = np.array([tr.box_xyxy for tr in tracks])
    on_floats, on_arrays = both_ways(boxes_xyxy, tracks)
    np.testing.assert_array_equal(on_floats, expected)
    np.testing.assert_array_equal(on_arrays, expected)
    assert box_rows(tracks) == [tuple(row) for row in expected.tolist()]


def pmr_history(n: int, rng: np.random.Generator) -> np.ndarray:
    t = np.arange(n) / 30.0
    vx = rng.normal(0, 60, n) + np.where(np.arange(n) < n // 2, 90.0, -40.0)
    vy = rng.normal(0, 20, n)
    cx = 300 + np.cumsum(vx) / 30.0
    cy = 200 + np.cumsum(vy) / 30.0
    return np.column_stack([t, cx, cy, cx / 1920, cy / 1080, vx, vy, np.full(n, 16.0), np.full(n, 11.0)])


@settings(max_examples=60, deadline=None)
@given(seed=SEEDS, n_models=st.integers(1, 3), n_centres=st.integers(1, 5))
def test_p_match_is_the_same_on_floats_and_arrays(seed: int, n_models: int, n_centres: int) -> None:
    rng = np.random.default_rng(seed)
    models = [
        fit_pmr(pmr_history(int(rng.integers(2, 31)), rng), float(rng.uniform(0.5, 1.5)), 0.1, 30.0)
        for _ in range(n_models)
    ]
    centres = rng.uniform(150, 450, (n_centres, 2))
    on_floats, on_arrays = both_ways(p_match_many, models, centres, float(rng.uniform(1.0, 3.0)), 30.0, 0.5, 2.0)
    np.testing.assert_array_equal(on_floats, on_arrays)


@settings(max_examples=100, deadline=None)
@given(seed=SEEDS, n_lost=st.integers(1, 5), n_centres=st.integers(1, 5))
def test_pmr_pre_gate_is_the_same_on_floats_and_arrays(seed: int, n_lost: int, n_centres: int) -> None:
    rng = np.random.default_rng(seed)
    lost = lost_tracks(rng, n_lost)
    centres = rng.uniform(-50, 500, (n_centres, 2))
    on_floats, on_arrays = both_ways(JPTrack()._worth_modelling, lost, centres, 0.4)
    assert on_floats == on_arrays


def test_pmr_pre_gate_decides_both_ways() -> None:
    rng = np.random.default_rng(4)
    decided = set()
    for _ in range(50):
        decided.update(JPTrack()._worth_modelling(lost_tracks(rng, 3), rng.uniform(-50, 500, (3, 2)), 0.4))
    assert decided == {True, False}


CELLS = st.one_of(
    st.floats(-50, 150), st.sampled_from([float("nan"), float("inf"), float("-inf"), -0.1, 0.0, 1.0, 1.5])
)


@settings(max_examples=300, deadline=None)
@given(rows=st.lists(st.tuples(CELLS, CELLS, CELLS, CELLS, CELLS), min_size=1, max_size=6))
def test_input_check_is_the_same_on_floats_and_arrays(rows: list[tuple[float, ...]]) -> None:
    dets = np.array(rows, dtype=np.float64)

    def check() -> str | np.ndarray:
        try:
            return validate_detections(dets, 0.0, 3)
        except ValueError as error:
            return str(error)

    on_floats, on_arrays = both_ways(check)
    if isinstance(on_floats, str) or isinstance(on_arrays, str):
        assert on_floats == on_arrays
    else:
        np.testing.assert_array_equal(on_floats, on_arrays)


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
def test_input_check_names_the_bad_field_either_way(bad: tuple[int, int, float]) -> None:
    dets = np.array([[10.0, 10.0, 20.0, 20.0, 0.9], [30.0, 5.0, 42.0, 17.0, 0.4], [0.0, 0.0, 1.0, 1.0, 1.0]])
    np.testing.assert_array_equal(validate_detections(dets, 0.0, 3), dets)
    row, col, value = bad
    dets[row, col] = value
    messages = []
    for kind in ("floats", "arrays"):
        with evaluated_on(kind), pytest.raises(ValueError, match=f"frame 3: detection {row} field") as error:
            validate_detections(dets, 0.0, 3)
        messages.append(str(error.value))
    assert messages[0] == messages[1]


@settings(max_examples=100, deadline=None)
@given(seed=SEEDS, n=st.integers(1, 8), with_rois=st.booleans())
def test_relative_positions_are_the_same_on_floats_and_arrays(seed: int, n: int, with_rois: bool) -> None:
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 1900, (n, 2))
    dets = np.column_stack([xy, xy + rng.uniform(1, 20, (n, 2)), rng.uniform(0, 1, n)])
    rois = None
    if with_rois:
        corner = xy - rng.uniform(0, 200, (n, 2))
        rois = np.hstack([corner, corner + rng.choice([0.0, 320.0, 640.0], (n, 1))])  # some degenerate
    tracker = JPTrack(JPTrackConfig(image_size=(1920, 1080)))
    on_floats, on_arrays = both_ways(tracker._relative_positions, dets, rois)
    assert on_floats == on_arrays
    if not with_rois:
        assert on_floats[0] == ((dets[0, 0] + dets[0, 2]) * 0.5 / 1920, (dets[0, 1] + dets[0, 3]) * 0.5 / 1080)


@pytest.mark.parametrize("config", [JPTrackConfig(), JPTrackConfig(use_pmr=False), JPTrackConfig(tau_t=0.3)])
def test_tracker_output_is_the_same_with_every_formula_on_arrays(config: JPTrackConfig) -> None:
    gt = scene_ground_truth(5004, 150, targets=4)
    hard = StreamParams(burst_rate=0.05, miss_rate=0.15, fp_rate=1.0, low_score_rate=0.4)
    dets = detections_from_gt(gt, 4, (1920, 1080), hard)
    fast = track_detection_rows(JPTrack(config), dets, 30.0, num_frames=150)
    with evaluated_on("arrays"):
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
