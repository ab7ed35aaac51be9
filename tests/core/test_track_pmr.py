"""PMR (eqs. 16-22): the mixture, its EM, the time weights and the recovery score."""

from __future__ import annotations

import numpy as np
import pytest

from gldt_core.track.pmr import c_time, em_full_covariance, fit_pmr, history_features, k_adaptive, p_match

sklearn_mixture = pytest.importorskip("sklearn.mixture")


def make_history(n: int, seed: int, turn: bool) -> np.ndarray:
    """Rows t, cx, cy, x_rel, y_rel, vx, vy (px/s), w, h of a target at 30 Hz."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 30.0
    vx = np.where(np.arange(n) < n // 2, 90.0, 90.0 if not turn else -60.0) + rng.normal(0, 3, n)
    vy = np.where(np.arange(n) < n // 2, 0.0, 0.0 if not turn else 45.0) + rng.normal(0, 3, n)
    cx = 200 + np.cumsum(vx) / 30.0
    cy = 300 + np.cumsum(vy) / 30.0
    return np.column_stack([t, cx, cy, cx / 1920, cy / 1080, vx, vy, np.full(n, 20.0), np.full(n, 14.0)])


@pytest.mark.parametrize("n", range(1, 13))
def test_k_adaptive_is_eq_18(n: int) -> None:
    assert k_adaptive(n) == min(2, max(1, int(np.floor(n / 3))))


@pytest.mark.parametrize("seed, n, turn", [(0, 30, True), (1, 30, False), (2, 9, True), (3, 17, False)])
def test_numpy_em_is_scikit_learns_gaussian_mixture(seed: int, n: int, turn: bool) -> None:
    feats = history_features(make_history(n, seed, turn), t_loss=n / 30.0, gamma=0.1, ref_fps=30.0)
    x = (feats - feats.mean(0)) / np.where(feats.std(0) < 1e-6, 1.0, feats.std(0))
    k = k_adaptive(n)
    gmm = sklearn_mixture.GaussianMixture(
        n_components=k,
        covariance_type="full",
        reg_covar=1e-4,
        max_iter=50,
        tol=1e-3,
        random_state=seed,
        init_params="random_from_data",
    ).fit(x)
    weights, means, covs = em_full_covariance(x, k, seed)
    np.testing.assert_allclose(weights, gmm.weights_, atol=1e-8)
    np.testing.assert_allclose(means, gmm.means_, atol=1e-8)
    np.testing.assert_allclose(covs, gmm.covariances_, atol=1e-8)


def test_both_backends_give_the_same_model() -> None:
    history = make_history(30, 4, True)
    a = fit_pmr(history, 1.0, 0.1, 30.0, backend="numpy")
    b = fit_pmr(history, 1.0, 0.1, 30.0, backend="sklearn")
    np.testing.assert_allclose(a.weights, b.weights, atol=1e-8)
    np.testing.assert_allclose(a.mean_pv, b.mean_pv, atol=1e-6)
    np.testing.assert_allclose(a.cov_pv, b.cov_pv, atol=1e-6)
    with pytest.raises(ValueError, match="backend"):
        fit_pmr(history, 1.0, 0.1, 30.0, backend="torch")


def test_c_time_is_the_mean_time_decay_weight() -> None:
    history = make_history(20, 5, False)
    t_loss = float(history[-1, 0])
    model = fit_pmr(history, t_loss, 0.1, 30.0)
    for t in (t_loss, t_loss + 0.5, t_loss + 2.0):
        expected = np.mean(np.exp(-0.1 * (t - history[:, 0])))
        assert c_time(model, t, 0.1) == pytest.approx(expected, rel=1e-12)


def test_p_match_follows_the_target_while_it_is_lost() -> None:
    history = make_history(30, 6, False)  # flying right at 90 px/s
    t_loss = float(history[-1, 0])
    model = fit_pmr(history, t_loss, 0.1, 30.0)
    last = history[-1, 1:3]
    t = t_loss + 1.5
    ahead = last + np.array([90.0 * 1.5, 0.0])
    centres = np.array([ahead, last, ahead + [0.0, 150.0]])
    p = p_match(model, centres, t, 30.0, pos_std_size=0.5, vel_std=0.5)
    assert np.all((p >= 0) & (p <= 1))
    assert p[0] > 0.8  # where constant velocity puts it
    assert p[1] < 0.2 and p[2] < 0.05  # where it was, and far off its path


def test_where_the_likelier_hypothesis_puts_the_target_p_match_is_one() -> None:
    """Two hypotheses after a turn: P_match is the mixture's density relative to its mode
    (``tests/core/test_track_fastpaths.py`` checks it against matrix algebra), so the likelier
    hypothesis's place scores 1. A weighted sum of peak-normalised components stayed below the
    larger weight there, which ``P_final > tau_t`` (0.6, at a time weight of 0.8) never passed."""
    history = make_history(30, 7, True)
    t_loss = float(history[-1, 0])
    model = fit_pmr(history, t_loss, 0.1, 30.0)
    assert len(model.weights) == 2 and model.weights.max() < 0.75
    steps = 30.0
    means = model.mean_pv[:, :2] + steps * model.mean_pv[:, 2:4]
    p = p_match(model, np.vstack([means, means.mean(axis=0) + [0.0, 400.0]]), t_loss + 1.0, 30.0, 0.5, 2.0)
    assert p[:2].max() == pytest.approx(1.0)
    assert p[:2].min() > 0.0 and p[2] < 1e-3  # the other hypothesis counts; far off both, nothing


def test_a_turn_gives_two_components_and_two_hypotheses() -> None:
    history = make_history(30, 7, True)
    t_loss = float(history[-1, 0])
    model = fit_pmr(history, t_loss, 0.1, 30.0)
    assert len(model.weights) == 2
    velocities = model.mean_pv[:, 2:4] * 30.0  # back to px/s
    assert np.max(velocities[:, 0]) > 60 and np.min(velocities[:, 0]) < 0
