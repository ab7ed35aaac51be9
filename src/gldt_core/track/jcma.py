"""JCMA: the joint cost of eqs. 9-15, vectorised over all (track, detection) pairs.

``Cost = w1 C_iou + w2 C_dist + w3 C_motion + w4 C_rel`` with

* ``C_iou = 1 - IoU(T_i, D_j)`` on the Kalman-predicted box (eq. 10);
* ``C_dist = min(1, |c_i - c_j| / s_ij)``, ``s_ij = 2 (w_i + h_i + w_j + h_j) / 4`` (eqs. 11-12);
* ``C_motion = b1 C_speed + b2 C_direction + b3 C_acceleration`` (eqs. 13-14);
* ``C_rel = 1 - mean_k cos((c_k - c_i), (c_k - c_j))`` over the other tracks k (eq. 15).

Choices where the paper is loose, and why:

* Units. The constants of eq. 14 (50, 2, 30) are pixels per frame of the paper's 30 Hz cameras.
  Time here is seconds, so every velocity is measured in pixels per *reference frame*
  (``ref_fps`` = 30 Hz): a 15 Hz camera or a dropped frame then gives the same cost for the same
  motion, which frame-count velocities would not.
* ``v_expected`` is the velocity the track would need to reach detection j: the displacement from
  the track's last *observed* centre to ``c_j`` divided by the elapsed time (the paper's
  ``|c_j - c_i|`` read as a velocity; using the predicted centre would measure the residual, not a
  velocity). ``v_avg`` is the mean of the filtered velocities over the last ``state.MOTION_WINDOW`` (10)
  observations, ``a_expected = (v_expected - v_last) / elapsed``.
* Direction is undefined for a (nearly) stationary target, so ``C_direction = 0`` when either
  speed is below ``min_speed`` px/frame; tracks with a single observation have no motion history
  and get ``C_motion = 0``.
* The "other objects" k of eq. 15 are the other tracks of the association pool, at their predicted
  centres; ``M = 0`` (a lone track) gives ``C_rel = 0``. A zero-length vector contributes cos = 0.
* Gating (the paper gives none): a pair whose cost exceeds the stage threshold, or that neither
  overlaps nor lies within ``s_ij`` (``C_iou = 1`` and ``C_dist = 1``), cannot match. Without the
  gate the Hungarian step would marry any leftover detection to any leftover track.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gldt_core.track.geometry import iou_xyxy

#: Cost given to forbidden pairs (finite so linear_sum_assignment stays feasible).
FORBIDDEN = 1e6


@dataclass(frozen=True)
class JcmaWeights:
    """Table I defaults: w1..w4 of eq. 9 and b1..b3 of eq. 13."""

    w_iou: float = 0.3
    w_dist: float = 0.3
    w_motion: float = 0.2
    w_rel: float = 0.2
    b_speed: float = 0.4
    b_direction: float = 0.4
    b_acceleration: float = 0.2
    speed_floor: float = 50.0
    speed_offset: float = 2.0
    accel_scale: float = 30.0
    min_speed: float = 1.0


@dataclass
class TrackMotion:
    """Per-track arrays the cost needs, each with one row per track of the pool."""

    pred_xyxy: np.ndarray  # (T, 4) predicted boxes at the frame time
    last_obs_c: np.ndarray  # (T, 2) last observed centre
    elapsed_ref: np.ndarray  # (T,) reference frames since the last observation (>0)
    v_avg: np.ndarray  # (T, 2) mean filtered velocity, px per reference frame
    v_last: np.ndarray  # (T, 2) last filtered velocity, px per reference frame
    has_motion: np.ndarray  # (T,) bool: at least two observations


def jcma_cost(
    motion: TrackMotion,
    dets_xyxy: np.ndarray,
    context_c: np.ndarray,
    context_index: np.ndarray,
    weights: JcmaWeights,
) -> tuple[np.ndarray, np.ndarray]:
    """Cost matrix ``(T, D)`` of eq. 9 and the geometric gate mask (True = may match).

    ``context_c`` holds the predicted centres of the pool's tracks (the objects k of eq. 15) and
    ``context_index[i]`` the row of track i in it (excluded from its own sum).
    """
    t_boxes = motion.pred_xyxy
    n_t, n_d = len(t_boxes), len(dets_xyxy)
    if n_t == 0 or n_d == 0:
        return np.zeros((n_t, n_d)), np.zeros((n_t, n_d), dtype=bool)
    c_iou = 1.0 - iou_xyxy(t_boxes, dets_xyxy)

    ci = (t_boxes[:, :2] + t_boxes[:, 2:4]) * 0.5
    cj = (dets_xyxy[:, :2] + dets_xyxy[:, 2:4]) * 0.5
    wh_i = t_boxes[:, 2:4] - t_boxes[:, :2]
    wh_j = dets_xyxy[:, 2:4] - dets_xyxy[:, :2]
    diff = cj[None, :, :] - ci[:, None, :]
    dist = np.hypot(diff[..., 0], diff[..., 1])
    scale = (wh_i.sum(1)[:, None] + wh_j.sum(1)[None, :]) / 4.0 * 2.0
    c_dist = np.minimum(1.0, dist / np.maximum(scale, 1e-9))

    c_motion = _motion_cost(motion, cj, weights)
    c_rel = relational_cost(ci, cj, context_c, context_index)

    # Summed in eq. 9's order, so the result is bit-identical to the one-expression form; a pool
    # without motion history adds C_motion = 0 (x + 0.0 == x), i.e. nothing.
    cost = weights.w_iou * c_iou + weights.w_dist * c_dist
    if c_motion is not None:
        cost += weights.w_motion * c_motion
    cost += weights.w_rel * c_rel
    gate = ~((c_iou >= 1.0) & (c_dist >= 1.0))
    return cost, gate


def _motion_cost(motion: TrackMotion, cj: np.ndarray, weights: JcmaWeights) -> np.ndarray | None:
    """C_motion (eqs. 13-14), velocities in px per reference frame; ``None`` when no track of the
    pool has a motion history (then every pair's C_motion is 0: tentative tracks, first frames)."""
    has = motion.has_motion
    if not has.any():
        return None
    v_exp = (cj[None, :, :] - motion.last_obs_c[:, None, :]) / motion.elapsed_ref[:, None, None]
    speed_exp = np.hypot(v_exp[..., 0], v_exp[..., 1])
    speed_avg = np.hypot(motion.v_avg[:, 0], motion.v_avg[:, 1])
    c_speed = np.minimum(
        1.0,
        np.abs(speed_exp - speed_avg[:, None])
        / np.maximum(weights.speed_floor, weights.speed_offset + speed_avg)[:, None],
    )
    ang_exp = np.arctan2(v_exp[..., 1], v_exp[..., 0])
    ang_avg = np.arctan2(motion.v_avg[:, 1], motion.v_avg[:, 0])
    d_theta = np.abs((ang_exp - ang_avg[:, None] + np.pi) % (2.0 * np.pi) - np.pi)
    c_dir = np.minimum(1.0, d_theta / (np.pi / 2.0))
    c_dir[(speed_exp < weights.min_speed) | (speed_avg[:, None] < weights.min_speed)] = 0.0
    accel = (v_exp - motion.v_last[:, None, :]) / motion.elapsed_ref[:, None, None]
    c_acc = np.minimum(1.0, np.hypot(accel[..., 0], accel[..., 1]) / weights.accel_scale)
    c_motion = weights.b_speed * c_speed + weights.b_direction * c_dir + weights.b_acceleration * c_acc
    if not has.all():
        c_motion[~has] = 0.0
    return c_motion


def relational_cost(
    ci: np.ndarray, cj: np.ndarray, context_c: np.ndarray, context_index: np.ndarray
) -> np.ndarray:
    """Eq. 15 for all pairs: ``1 - mean_k cos(c_k - c_i, c_k - c_j)`` over context objects k != i.

    The cosine sum is one matrix product of unit vectors, ``(T, 2K) @ (2K, D)``, so the cost stays
    small at 50 targets; a zero-length vector is a zero unit vector (cos 0).
    """
    n_t, n_d, n_k = len(ci), len(cj), len(context_c)
    if n_k <= 1:
        return np.zeros((n_t, n_d))
    a = context_c[None, :, :] - ci[:, None, :]  # (T, K, 2)
    b = context_c[:, None, :] - cj[None, :, :]  # (K, D, 2)
    na = np.hypot(a[..., 0], a[..., 1])
    nb = np.hypot(b[..., 0], b[..., 1])
    a_unit = np.where(na[..., None] > 1e-9, a / np.maximum(na, 1e-9)[..., None], 0.0)
    b_unit = np.where(nb[..., None] > 1e-9, b / np.maximum(nb, 1e-9)[..., None], 0.0)
    mask = np.ones((n_t, n_k))
    valid = context_index >= 0
    if valid.all():
        mask[np.arange(n_t), context_index] = 0.0
    else:
        mask[np.flatnonzero(valid), context_index[valid]] = 0.0
    a_unit *= mask[..., None]
    total = a_unit.reshape(n_t, 2 * n_k) @ b_unit.transpose(0, 2, 1).reshape(2 * n_k, n_d)
    counts = mask.sum(1)
    has = counts > 0
    if has.all():
        return 1.0 - total / counts[:, None]
    out = np.zeros((n_t, n_d))
    out[has] = 1.0 - total[has] / counts[has, None]
    return out
