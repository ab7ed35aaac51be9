"""PMR: probability-driven memory recovery of lost tracks (eqs. 16-22).

For each lost track a scikit-learn ``GaussianMixture`` is fitted on its history features
``Y = [x_abs, y_abs, x_rel, y_rel, vx, vy, theta, w]`` (eq. 16) with
``K = min(2, max(1, floor(n / 3)))`` components (eq. 18). A detection j is scored against it by
``P_final = P_match * C_time`` (eqs. 20-22), with ``C_time`` the mean of the time-decay weights
``w_i = exp(-gamma (t_now - t_i))`` (eqs. 17, 21), and recovers the track when
``P_final > tau_t``.

The paper leaves three things ill-posed; our choices and why:

1. **P_match is a density, not a probability.** A Gaussian density has units (1/px^2 ...), so a
   fixed ``tau_t = 0.6`` would mean something different for every feature scaling and box size.
   We use the mixture density *relative to its mode*, ``P_match = min(1, p(x) / max_j p(mu_j))``
   with ``p(x) = sum_k pi_k N(x; mu_k, Sigma_k)`` and the mode taken at the components' means
   (:func:`mixture_scale`): it is unit-free, lies in [0, 1], equals 1 where the likelier
   hypothesis puts the target, and ``tau_t`` becomes a Mahalanobis gate (with one component
   ``P_match = exp(-d^2 / 2)``, so ``P_final > 0.6`` with ``C_time`` near 0.9 accepts a match
   within about 0.9 sigma). The weighted sum of peak-normalised components, ``sum_k pi_k
   exp(-d_k^2 / 2)``, used before, stays below the larger weight at a component's mean once the
   two hypotheses part (a turning target), so such a track could never pass ``tau_t``
   (``docs/experiment-log.md``, Tracking, 2026-12-04).
2. **Lost targets keep moving.** History positions describe where the target *was*; after a
   two-second occlusion the detection is elsewhere. Each sample's position feature is therefore
   its constant-velocity extrapolation to the loss time ``t_L`` (``p_i + v_i (t_L - t_i)``), and at
   query time every component is propagated exactly by the linear map ``p <- p + v * dt`` (mean
   and covariance, using the fitted position/velocity cross-covariances). A maneuvering target
   yields two components with different velocities, i.e. two hypotheses of where it is now. The
   mixture is fitted once, lazily, the first time a lost track (lost for at least
   ``JPTrackConfig.pmr_min_lost_s``) has a candidate detection near its prediction, and refitted
   only after the track has been updated again: never every frame.
3. **What a detection can be compared on.** A single detection has a position but no velocity or
   heading of its own, and its time weight is 1 by definition; putting those into the query would
   make every detection an outlier. ``P_match`` is therefore the marginal of the propagated mixture
   on the observed position dimensions ``(x_abs, y_abs)``; ``vx, vy`` shape it through the
   propagation, ``theta`` and the ROI-relative position shape the component split, and ``w``
   enters through ``C_time`` (eq. 21). ``x_rel, y_rel`` are relative to the ROI the detection came
   from (``rois`` in ``update``) or, in global mode, to the image.

The covariance of each propagated component gets a floor ``(pos_std_size * box size)^2 +
(vel_std * dt)^2`` (velocity in px per reference frame): detector jitter and unmodelled
acceleration, without which a perfectly straight history would give a zero-width gate.
Units: velocities in px per reference frame (``ref_fps``), time in seconds, ``gamma`` per second.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from gldt_core.track.fastpath import ARRAYS, FLOATS, Ops, V, on_floats

#: Columns of the fitted feature vector (eq. 16).
FEATURES = ("x_abs", "y_abs", "x_rel", "y_rel", "vx", "vy", "theta", "w")


@dataclass
class PmrModel:
    """A fitted mixture, stored as the few arrays the query needs."""

    t_loss: float
    weights: np.ndarray  # (K,)
    mean_pv: np.ndarray  # (K, 4): x, y, vx, vy (velocity per reference frame)
    cov_pv: np.ndarray  # (K, 4, 4)
    mean_w_at_loss: float  # mean of exp(-gamma (t_L - t_i)) over the history
    size: float  # mean box size at loss (px)
    n_samples: int


_CONTROLLER = None
#: EM settings shared by both backends (scikit-learn's names).
REG_COVAR = 1e-4
MAX_ITER = 50
TOL = 1e-3


def _single_thread():
    """BLAS threads only slow a 30x8 EM down (and badly so on a loaded machine): use one."""
    global _CONTROLLER
    if _CONTROLLER is None:
        from threadpoolctl import ThreadpoolController

        _CONTROLLER = ThreadpoolController()
    return _CONTROLLER.limit(limits=1)


def k_adaptive(n_samples: int) -> int:
    """Eq. 18: ``min(2, max(1, floor(n / 3)))``."""
    return min(2, max(1, n_samples // 3))


def history_features(history: np.ndarray, t_loss: float, gamma: float, ref_fps: float) -> np.ndarray:
    """Eq. 16 features ``(n, 8)`` from a track history (rows of ``state.HISTORY_FIELDS``)."""
    t, cx, cy, xr, yr, vx, vy = (history[:, i] for i in range(7))
    dt_s = t_loss - t
    v_ref_x = vx / ref_fps
    v_ref_y = vy / ref_fps
    x_abs = cx + vx * dt_s
    y_abs = cy + vy * dt_s
    theta = np.arctan2(v_ref_y, v_ref_x)
    # Unwrap theta around its circular mean so a heading near +-pi is not split in two.
    mean_dir = np.arctan2(np.sin(theta).mean(), np.cos(theta).mean())
    theta = mean_dir + (theta - mean_dir + np.pi) % (2 * np.pi) - np.pi
    w = np.exp(-gamma * dt_s)
    return np.column_stack([x_abs, y_abs, xr, yr, v_ref_x, v_ref_y, theta, w])


def fit_pmr(
    history: np.ndarray,
    t_loss: float,
    gamma: float,
    ref_fps: float,
    seed: int = 0,
    backend: str = "numpy",
) -> PmrModel:
    """Fit the mixture of eq. 19 by EM on a lost track's history.

    ``backend="sklearn"`` runs ``sklearn.mixture.GaussianMixture``; ``"numpy"`` (default) runs
    :func:`em_full_covariance`, the same algorithm (same initialisation from the same seed, same
    E/M steps, regularisation and stopping rule) without scikit-learn's per-iteration validation,
    whose cost per EM iteration exceeds the iteration itself on an 8-feature history. The test
    ``tests/core/test_track_pmr.py`` checks both give the same mixture.
    """
    if backend not in ("numpy", "sklearn"):
        raise ValueError(f"PMR backend must be 'numpy' or 'sklearn', got {backend!r}")

    feats = history_features(history, t_loss, gamma, ref_fps)
    n = len(feats)
    k = k_adaptive(n)
    size = float(np.mean(history[-5:, 7] + history[-5:, 8]) * 0.5)
    center = feats.mean(0)
    diff = feats - center
    if k == 1 or n < 2:
        # One component: EM's fixed point is the sample mean and (biased) covariance, so it is
        # computed directly (what GaussianMixture(1) returns, without its overhead).
        means = center[None, :]
        covs = (diff.T @ diff / n + np.eye(8) * REG_COVAR)[None, :, :]
        weights = np.ones(1)
    else:
        # Features live on very different scales (px, [0,1], rad); standardise for EM, map back.
        # feats.std(0), spelled out to reuse ``diff`` (numpy's own steps: same values).
        scale = np.sqrt(np.add.reduce(diff * diff, axis=0) / n)
        scale[scale < 1e-6] = 1.0
        if backend == "sklearn":
            from sklearn.mixture import GaussianMixture

            gmm = GaussianMixture(
                n_components=k,
                covariance_type="full",
                reg_covar=REG_COVAR,
                max_iter=MAX_ITER,
                tol=TOL,
                random_state=seed,
                init_params="random_from_data",
            )
            with _single_thread():
                gmm.fit(diff / scale)
            w_std, m_std, c_std = gmm.weights_, gmm.means_, gmm.covariances_
        else:
            w_std, m_std, c_std = em_full_covariance(diff / scale, k, seed)
        means = m_std * scale + center
        covs = c_std * np.outer(scale, scale)[None, :, :]
        weights = w_std
    idx = [0, 1, 4, 5]
    return PmrModel(
        t_loss=t_loss,
        weights=np.asarray(weights, dtype=np.float64),
        mean_pv=np.asarray(means[:, idx], dtype=np.float64),
        cov_pv=np.asarray(covs[:, idx][:, :, idx], dtype=np.float64),
        mean_w_at_loss=float(np.mean(feats[:, 7])),
        size=size,
        n_samples=n,
    )


def c_time(model: PmrModel, t: float, gamma: float) -> float:
    """Eq. 21 at time ``t``: mean over the history of ``exp(-gamma (t - t_i))``."""
    return float(np.exp(-gamma * max(t - model.t_loss, 0.0)) * model.mean_w_at_loss)


def p_match(
    model: PmrModel, centers: np.ndarray, t: float, ref_fps: float, pos_std_size: float, vel_std: float
) -> np.ndarray:
    """Eq. 20 (relative to the mixture's mode, see the module doc) for detection centres ``(D, 2)`` at ``t``."""
    return p_match_many([model], centers, t, ref_fps, pos_std_size, vel_std)[0]


def floor_variance(size: V, steps: V | float, pos_std_size: float, vel_std: float) -> V:
    """The variance added to a propagated position (module docstring): detector jitter of
    ``pos_std_size`` box sizes plus ``vel_std`` px per reference frame of unmodelled velocity
    change over ``steps`` reference frames."""
    pos_std = pos_std_size * size
    drift = vel_std * steps
    return pos_std * pos_std + drift * drift


def propagated_position(
    ops: Ops[V],
    mean: Sequence[V] | np.ndarray,
    cov: Sequence[Sequence[V]] | np.ndarray,
    steps: V | float,
    floor: V | float,
) -> tuple[V, V, V, V, V, V]:
    """A component's position ``steps`` reference frames after the loss, by ``A = [[I, steps I]]``:
    the mean ``A m`` and the 2x2 block of ``A C A^T`` written out, the floor added to its diagonal.
    ``mean[i]`` and ``cov[i][j]`` are the entries of the fitted ``(x, y, vx, vy)`` Gaussian.
    Returns ``(mu_x, mu_y, sxx, syy, sxy, det)``, the determinant floored at 1e-12."""
    mx, my, mvx, mvy = mean
    mu_x = mx + steps * mvx
    mu_y = my + steps * mvy
    # (A C A^T)_ij = C_ij + s (C_i,j+2 + C_i+2,j) + s^2 C_i+2,j+2 for i, j in {0, 1}.
    s2 = steps * steps
    sxx = cov[0][0] + steps * (cov[0][2] + cov[2][0]) + s2 * cov[2][2] + floor
    syy = cov[1][1] + steps * (cov[1][3] + cov[3][1]) + s2 * cov[3][3] + floor
    sxy = cov[0][1] + steps * (cov[0][3] + cov[2][1]) + s2 * cov[2][3]
    return mu_x, mu_y, sxx, syy, sxy, ops.maximum(sxx * syy - sxy * sxy, 1e-12)


def match_exponent(position: tuple[V, V, V, V, V, V], x: V, y: V) -> V:
    """``-d^2 / 2`` of point ``(x, y)`` under a :func:`propagated_position` (``d``: Mahalanobis)."""
    mu_x, mu_y, sxx, syy, sxy, det = position
    dx = x - mu_x
    dy = y - mu_y
    return -0.5 * ((syy * dx * dx - 2.0 * sxy * dx * dy + sxx * dy * dy) / det)


def mixture_scale(model: PmrModel, steps: float, floor: float) -> tuple[list[float], float]:
    """``(coefficients, mode)`` of a mixture propagated ``steps`` reference frames with ``floor``:
    :func:`p_match_many` scores a point ``min(1, sum_k coefficient_k exp(-d_k^2 / 2) / mode)``,
    the density relative to its highest value at a component's mean (module docstring, 1.). The
    coefficients are ``pi_k / sqrt(det_k)`` (the densities' common ``2 pi`` cancels)."""
    positions = [
        propagated_position(FLOATS, mean, cov, steps, floor)
        for mean, cov in zip(model.mean_pv.tolist(), model.cov_pv.tolist())
    ]
    coefficients = [w / math.sqrt(position[5]) for w, position in zip(model.weights.tolist(), positions)]
    mode = max(
        sum(c * math.exp(match_exponent(position, at[0], at[1])) for c, position in zip(coefficients, positions))
        for at in positions
    )
    return coefficients, mode


def p_match_many(
    models: list[PmrModel],
    centers: np.ndarray,
    t: float,
    ref_fps: float,
    pos_std_size: float,
    vel_std: float,
) -> np.ndarray:
    """:func:`p_match` of every model at once, ``(len(models), D)``.

    The components of all models are scored together: on arrays (every component against every
    centre in one numpy pass) or, for a few pairs (:func:`gldt_core.track.fastpath.on_floats`),
    pair by pair on Python floats; the exponentials are one ``np.exp`` call either way. A model's
    mixture sum adds its components in order (``w_0 l_0 + w_1 l_1``).
    """
    centers = np.asarray(centers, dtype=np.float64).reshape(-1, 2)
    if not models:
        return np.zeros((0, len(centers)))
    counts = [len(m.weights) for m in models]
    steps_m, floor_m = _propagation(models, t, ref_fps, pos_std_size, vel_std)
    scales = [mixture_scale(m, st, fl) for m, st, fl in zip(models, steps_m, floor_m)]
    if on_floats(sum(counts) * len(centers)):
        points = centers.tolist()
        exponents = []
        for m, steps, floor in zip(models, steps_m, floor_m):
            for mean, cov in zip(m.mean_pv.tolist(), m.cov_pv.tolist()):
                position = propagated_position(FLOATS, mean, cov, steps, floor)
                exponents += [match_exponent(position, x, y) for x, y in points]
        like = np.exp(np.array(exponents)).tolist()
        out = []
        row = 0
        for coefficients, mode in scales:
            mixture = [0.0] * len(points)
            for w in coefficients:
                mixture = [acc + w * v for acc, v in zip(mixture, like[row * len(points) : (row + 1) * len(points)])]
                row += 1
            out.append([min(1.0, v / mode) for v in mixture])
        return np.array(out).reshape(len(models), len(points))
    mean = np.concatenate([m.mean_pv for m in models]).T  # (4, sum K)
    cov = np.concatenate([m.cov_pv for m in models]).transpose(1, 2, 0)  # (4, 4, sum K)
    position = propagated_position(ARRAYS, mean, cov, np.repeat(steps_m, counts), np.repeat(floor_m, counts))
    columns = tuple(v[:, None] for v in position)
    like = np.exp(match_exponent(columns, centers[None, :, 0], centers[None, :, 1]))
    weighted = np.concatenate([coefficients for coefficients, _ in scales])[:, None] * like
    sums = np.add.reduceat(weighted, np.cumsum([0] + counts[:-1]), axis=0)
    return np.minimum(1.0, sums / np.array([mode for _, mode in scales])[:, None])


def mode_density(models: list[PmrModel], t: float, ref_fps: float, pos_std_size: float, vel_std: float) -> np.ndarray:
    """Each propagated mixture's highest position density at ``t`` (its value at the likelier
    component's mean, without the common ``1 / 2 pi``): ``P_match * mode_density`` is the
    mixture's density at a point, which compares hypotheses of different spread (a track lost a
    frame ago against one lost for seconds) where ``P_match``, relative to each one's own mode,
    does not."""
    steps_m, floor_m = _propagation(models, t, ref_fps, pos_std_size, vel_std)
    return np.array([mixture_scale(m, st, fl)[1] for m, st, fl in zip(models, steps_m, floor_m)])


def _propagation(
    models: list[PmrModel], t: float, ref_fps: float, pos_std_size: float, vel_std: float
) -> tuple[list[float], list[float]]:
    """Each model's reference frames since its loss at ``t`` and the floor variance for them."""
    steps_m = [max(t - m.t_loss, 0.0) * ref_fps for m in models]
    return steps_m, [floor_variance(m.size, st, pos_std_size, vel_std) for m, st in zip(models, steps_m)]


@functools.lru_cache(maxsize=1024)
def _init_indices(n: int, k: int, seed: int) -> np.ndarray:
    """scikit-learn's ``random_from_data`` initial samples; a pure function of ``(n, k, seed)``,
    cached because building a RandomState costs more than a whole EM iteration."""
    out = np.random.RandomState(seed).choice(n, size=k, replace=False)
    out.flags.writeable = False
    return out


def em_full_covariance(x: np.ndarray, k: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """EM for a full-covariance Gaussian mixture, step for step scikit-learn's GaussianMixture
    with ``init_params="random_from_data"``, ``n_init=1`` and the module's REG_COVAR/MAX_ITER/TOL.

    Returns ``(weights (k,), means (k, d), covariances (k, d, d))``.
    """
    n = len(x)
    resp = np.zeros((n, k))
    resp[_init_indices(n, k, seed), np.arange(k)] = 1.0
    weights, means, covs = _gaussian_parameters(x, resp)
    weights = weights / n
    prec_chol = _precision_cholesky(covs)
    lower_bound = -np.inf
    for _ in range(MAX_ITER):
        previous = lower_bound
        log_prob_norm, log_resp = _e_step(x, weights, means, prec_chol)
        weights, means, covs = _gaussian_parameters(x, np.exp(log_resp))
        weights = weights / weights.sum()
        prec_chol = _precision_cholesky(covs)
        lower_bound = log_prob_norm
        if abs(lower_bound - previous) < TOL:
            break
    return weights, means, covs


def _gaussian_parameters(x: np.ndarray, resp: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """scikit-learn's M step, all components in one batched product."""
    nk = np.add.reduce(resp, axis=0) + _TEN_EPS
    means = resp.T @ x / nk[:, None]
    k, d = means.shape
    diff = x[None, :, :] - means[:, None, :]  # (k, n, d)
    covs = (resp.T[:, None, :] * diff.transpose(0, 2, 1)) @ diff / nk[:, None, None]
    covs.reshape(k, d * d)[:, :: d + 1] += REG_COVAR  # the diagonals
    return nk, means, covs


def _precision_cholesky(covs: np.ndarray) -> np.ndarray:
    """Upper-triangular precision factors ``inv(cholesky(cov)).T`` of all components at once."""
    chol = np.linalg.cholesky(covs)
    return np.linalg.solve(chol, _identities(*covs.shape[:2])).transpose(0, 2, 1)


@functools.lru_cache(maxsize=16)
def _identities(k: int, d: int) -> np.ndarray:
    """``k`` stacked ``d x d`` identity matrices (read-only, built once per shape)."""
    out = np.broadcast_to(np.eye(d), (k, d, d)).copy()
    out.flags.writeable = False
    return out


_LOG_2PI = float(np.log(2 * np.pi))
_TEN_EPS = 10 * np.finfo(np.float64).eps


def _e_step(x: np.ndarray, weights: np.ndarray, means: np.ndarray, prec_chol: np.ndarray) -> tuple[float, np.ndarray]:
    """scikit-learn's E step (log responsibilities and mean log-likelihood), batched over components."""
    d = x.shape[1]
    y = x @ prec_chol - (means[:, None, :] @ prec_chol)  # (k, n, d)
    log_det = np.log(np.diagonal(prec_chol, axis1=1, axis2=2)).sum(axis=1)
    log_prob = -0.5 * (d * _LOG_2PI + np.einsum("knd,knd->nk", y, y)) + log_det
    weighted = log_prob + np.log(weights)
    # The ufunc reductions behind ndarray.max/.sum/np.mean, without their Python wrappers.
    top = np.maximum.reduce(weighted, axis=1, keepdims=True)
    log_norm = (top + np.log(np.add.reduce(np.exp(weighted - top), axis=1, keepdims=True)))[:, 0]
    return float(np.add.reduce(log_norm)) / len(log_norm), weighted - log_norm[:, None]
