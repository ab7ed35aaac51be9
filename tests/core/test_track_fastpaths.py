"""The batched and vectorised implementations give what the straightforward per-item code gives.

Each test keeps a simple reference formula (matrices written out, one item at a time) and
compares: exact equality where the batched code does the same IEEE operations, a 1e-12 tolerance
where the summation order may differ. (That each formula gives the same numbers on Python floats as
on arrays is tests/core/test_track_small_pools.py.)
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from gldt_core.track import Track, TrackState
from gldt_core.track.boxes import iou_pairs_above, iou_xyxy
from gldt_core.track.jcma import relational_cost
from gldt_core.track.kalman import ConstantVelocityKalman, predict_many
from gldt_core.track.pmr import PmrModel, _init_indices, fit_pmr, mode_density, p_match, p_match_many
from gldt_core.track.state import boxes_xyxy


def reference_density(
    model: PmrModel, t: float, ref_fps: float, pos_std_size: float, vel_std: float
) -> tuple[Callable[[np.ndarray], np.ndarray], np.ndarray]:
    """PMR's propagated position mixture with the propagation written as matrices (A m, A C A^T):
    its density function over ``(D, 2)`` points, and its components' means."""
    steps = max(t - model.t_loss, 0.0) * ref_fps
    a = np.zeros((2, 4))
    a[0, 0] = a[1, 1] = 1.0
    a[0, 2] = a[1, 3] = steps
    mu = model.mean_pv @ a.T
    cov = np.einsum("ij,kjl,ml->kim", a, model.cov_pv, a)
    floor = (pos_std_size * model.size) ** 2 + (vel_std * steps) ** 2
    cov[:, 0, 0] += floor
    cov[:, 1, 1] += floor

    def density(points: np.ndarray) -> np.ndarray:
        out = np.zeros(len(points))
        for w, m, c in zip(model.weights, mu, cov):
            d = points - m
            d2 = np.einsum("ni,ij,nj->n", d, np.linalg.inv(c), d)
            out += w * np.exp(-0.5 * d2) / (2.0 * np.pi * np.sqrt(np.linalg.det(c)))
        return out

    return density, mu


def reference_p_match(
    model: PmrModel, centers: np.ndarray, t: float, ref_fps: float, pos_std_size: float, vel_std: float
) -> np.ndarray:
    """PMR's P_match: the mixture's density relative to its highest value at a component's
    mean, at most 1."""
    density, mu = reference_density(model, t, ref_fps, pos_std_size, vel_std)
    return np.minimum(1.0, density(centers) / density(mu).max())


def history(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 30.0
    vx = np.where(np.arange(n) < n // 2, 90.0, -40.0) + rng.normal(0, 3, n)
    vy = rng.normal(0, 20, n)
    cx = 300 + np.cumsum(vx) / 30.0
    cy = 200 + np.cumsum(vy) / 30.0
    return np.column_stack([t, cx, cy, cx / 1920, cy / 1080, vx, vy, np.full(n, 16.0), np.full(n, 11.0)])


def test_batched_p_match_equals_each_model_alone() -> None:
    models = [
        fit_pmr(history(n, s), n / 30.0 + dt, 0.1, 30.0)
        for n, s, dt in [(30, 1, 0.0), (4, 2, 0.3), (12, 3, -0.2), (2, 4, 0.1)]
    ]
    assert {len(m.weights) for m in models} == {1, 2}  # both component counts are stacked
    rng = np.random.default_rng(0)
    centres = rng.uniform(150, 450, (7, 2))
    t = 1.4
    batched = p_match_many(models, centres, t, 30.0, 0.5, 2.0)
    assert batched.shape == (4, 7)
    for row, model in zip(batched, models):
        np.testing.assert_allclose(row, reference_p_match(model, centres, t, 30.0, 0.5, 2.0), rtol=1e-10, atol=1e-12)
    assert p_match_many([], centres, t, 30.0, 0.5, 2.0).shape == (0, 7)


def test_mode_density_is_the_mixtures_highest_density_at_a_mean() -> None:
    """``P_match * mode_density`` is the density itself (without ``1 / 2 pi``): what JPTrack's
    relink compares across lost tracks of different spread."""
    models = [fit_pmr(history(n, s), n / 30.0, 0.1, 30.0) for n, s in [(30, 1), (4, 2), (12, 3)]]
    centres = np.random.default_rng(1).uniform(150, 450, (5, 2))
    modes = mode_density(models, 1.4, 30.0, 0.5, 2.0)
    for model, mode in zip(models, modes):
        density, mu = reference_density(model, 1.4, 30.0, 0.5, 2.0)
        assert mode / (2.0 * np.pi) == pytest.approx(density(mu).max(), rel=1e-10)
        unclipped = density(centres) <= density(mu).max()
        np.testing.assert_allclose(
            (p_match(model, centres, 1.4, 30.0, 0.5, 2.0) * mode / (2.0 * np.pi))[unclipped],
            density(centres)[unclipped],
            rtol=1e-9,
        )


def test_single_model_path_equals_the_stacked_path() -> None:
    models = [fit_pmr(history(30, 5), 1.0, 0.1, 30.0), fit_pmr(history(30, 6), 0.9, 0.1, 30.0)]
    centres = np.array([[340.0, 205.0], [600.0, 100.0], [310.0, 190.0]])
    stacked = p_match_many(models, centres, 1.6, 30.0, 0.5, 2.0)
    for row, model in zip(stacked, models):
        np.testing.assert_allclose(p_match(model, centres, 1.6, 30.0, 0.5, 2.0), row, rtol=1e-13, atol=1e-15)


def test_cached_em_initialisation_is_scikit_learns_random_draw() -> None:
    for n, k, seed in [(30, 2, 0), (7, 2, 3), (9, 1, 1)]:
        expected = np.random.RandomState(seed).choice(n, size=k, replace=False)
        np.testing.assert_array_equal(_init_indices(n, k, seed), expected)
        assert _init_indices(n, k, seed) is _init_indices(n, k, seed)


def reference_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ix1 = np.maximum(a[:, None, 0], b[None, :, 0])
    iy1 = np.maximum(a[:, None, 1], b[None, :, 1])
    ix2 = np.minimum(a[:, None, 2], b[None, :, 2])
    iy2 = np.minimum(a[:, None, 3], b[None, :, 3])
    inter = np.clip(ix2 - ix1, 0, None) * np.clip(iy2 - iy1, 0, None)
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    union = area_a[:, None] + area_b[None, :] - inter
    return np.where(union > 0, inter / np.maximum(union, 1e-12), 0.0)


@pytest.mark.parametrize("n_a, n_b", [(1, 1), (3, 5), (40, 17)])
def test_iou_equals_the_reference_formula_exactly(n_a: int, n_b: int) -> None:
    rng = np.random.default_rng(n_a * 100 + n_b)
    xy = rng.uniform(0, 60, (n_a, 2))
    a = np.hstack([xy, xy + rng.uniform(1, 30, (n_a, 2))])
    xy = rng.uniform(0, 60, (n_b, 2))
    b = np.hstack([xy, xy + rng.uniform(1, 30, (n_b, 2))])
    b[0] = a[0]  # identical boxes: IoU exactly 1
    got = iou_xyxy(a, b)
    np.testing.assert_array_equal(got, reference_iou(a, b))
    assert got[0, 0] == 1.0


def test_boxes_xyxy_equals_each_tracks_property_exactly() -> None:
    rng = np.random.default_rng(2)
    tracks = []
    for i in range(5):
        xy = rng.uniform(0, 500, 2)
        tracks.append(
            Track(
                i + 1,
                np.array([*xy, *(xy + rng.uniform(2, 40, 2))]),
                0.9,
                0.0,
                TrackState.CONFIRMED,
                30.0,
                30,
                (0.5, 0.5),
            )
        )
    predict_many([tr.kf for tr in tracks], np.full(5, 0.1))
    np.testing.assert_array_equal(boxes_xyxy(tracks), np.array([tr.box_xyxy for tr in tracks]))
    assert boxes_xyxy([]).shape == (0, 4)


def test_prediction_with_mixed_reference_rates_equals_one_filter_at_a_time() -> None:
    boxes = [np.array([100.0, 80.0, 12.0, 9.0]), np.array([300.0, 40.0, 30.0, 20.0])]
    singles = [ConstantVelocityKalman(b, ref_fps=r) for b, r in zip(boxes, (30.0, 15.0))]
    batch = [ConstantVelocityKalman(b, ref_fps=r) for b, r in zip(boxes, (30.0, 15.0))]
    for f in singles + batch:
        f.mean[4:6] = [40.0, -25.0]
    dts = np.array([0.1, 0.25])
    for f, dt in zip(singles, dts):
        f.predict(float(dt))
    predict_many(batch, dts)
    for a, b in zip(singles, batch):
        np.testing.assert_allclose(b.mean, a.mean, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(b.covariance, a.covariance, rtol=1e-12, atol=1e-9)


def test_relational_cost_with_tracks_outside_the_context() -> None:
    """context_index -1 (a track that is not one of the context objects) uses all of them."""
    ci = np.array([[0.0, 0.0], [50.0, 10.0]])
    cj = np.array([[5.0, 1.0], [48.0, 12.0], [200.0, 0.0]])
    context = np.array([[0.0, 0.0], [100.0, 0.0], [0.0, 100.0]])
    rel = relational_cost(ci, cj, context, np.array([0, -1]))
    for i, own in enumerate([0, -1]):
        for j in range(len(cj)):
            cosines = []
            for k, ck in enumerate(context):
                if k == own:
                    continue
                u, v = ck - ci[i], ck - cj[j]
                nu, nv = np.hypot(*u), np.hypot(*v)
                cosines.append(0.0 if nu <= 1e-9 or nv <= 1e-9 else float(u @ v) / (nu * nv))
            assert rel[i, j] == pytest.approx(1.0 - np.mean(cosines), abs=1e-12)


@pytest.mark.parametrize("n_a, n_b", [(3, 4), (6, 7), (12, 9)])  # the last one takes the numpy path
def test_iou_pairs_above_equals_thresholding_the_iou_matrix(n_a: int, n_b: int) -> None:
    rng = np.random.default_rng(n_a + 10 * n_b)
    xy = rng.uniform(0, 40, (n_a, 2))
    a = np.hstack([xy, xy + rng.uniform(5, 20, (n_a, 2))])
    b = a[rng.integers(0, n_a, n_b)] + rng.normal(0, 1.5, (n_b, 4))
    b[:, 2:] = np.maximum(b[:, 2:], b[:, :2] + 1.0)
    b[0] = a[0]  # IoU exactly 1
    iou = iou_xyxy(a, b)
    for thresh in (0.0, 0.5, 0.85, float(iou[1, 1]), float(np.sort(iou.ravel())[-3])):
        expected = [(int(i), int(j)) for i, j in zip(*np.nonzero(iou > thresh))]
        assert iou_pairs_above(a, b, thresh) == expected


def test_tracker_prediction_is_each_tracks_own_prediction() -> None:
    """``tracker.predict(t)`` predicts every shown track in one batch: exactly each track's
    ``predicted_xyxy(t)``, and the filters do not move."""
    from gldt_core.eval.streams import StreamParams, detections_from_gt
    from gldt_core.sim import scene_ground_truth
    from gldt_core.track import JPTrack
    from gldt_core.track.runner import track_detection_rows

    gt = scene_ground_truth(5006, 40, targets=4)
    tracker = JPTrack()
    track_detection_rows(tracker, detections_from_gt(gt, 6, (1920, 1080), StreamParams()), 30.0, num_frames=40)
    before = [tr.kf.mean.copy() for tr in tracker.tracks]
    for t in (40 / 30, 41 / 30, 39 / 30 + 0.7, 39 / 30 - 0.1):
        rows = tracker.predict(t)
        window = tracker.config.lost_window_s + 1e-9
        shown = [
            tr
            for tr in tracker.tracks
            if tr.is_active or (tr.state is TrackState.LOST and t - tr.last_update_t <= window)
        ]
        assert len(shown) > 0 and rows.shape == (len(shown), 5)
        expected = np.array([[*tr.predicted_xyxy(t), float(tr.track_id)] for tr in shown])
        np.testing.assert_array_equal(rows, expected)
    for tr, mean in zip(tracker.tracks, before):
        np.testing.assert_array_equal(tr.kf.mean, mean)
