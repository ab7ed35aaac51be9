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

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from gldt_core.track.boxes import iou_xyxy

#: Pools of at most this many (track, detection) pairs, with at most SMALL_POOL_CONTEXT context
#: objects, are costed on Python floats (:func:`jcma_cost_rows`): at a handful of targets the
#: ~100 numpy calls of the vectorised path cost ~10x more than the arithmetic itself.
SMALL_POOL_PAIRS = 16
SMALL_POOL_CONTEXT = 8


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
    if is_small_pool(n_t, n_d, len(context_c)):
        rows = np.column_stack([t_boxes, motion.last_obs_c, motion.elapsed_ref, motion.v_avg, motion.v_last])
        return jcma_cost_rows(
            rows.tolist(),
            motion.has_motion.tolist(),
            np.asarray(dets_xyxy).tolist(),
            np.asarray(context_c).tolist(),
            context_index.tolist(),
            weights,
        )
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


def relational_cost(ci: np.ndarray, cj: np.ndarray, context_c: np.ndarray, context_index: np.ndarray) -> np.ndarray:
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


def is_small_pool(n_tracks: int, n_dets: int, n_context: int) -> bool:
    """Whether :func:`jcma_cost_rows` (Python floats) is the cheaper way to cost this pool."""
    return n_tracks * n_dets <= SMALL_POOL_PAIRS and n_context <= SMALL_POOL_CONTEXT


def jcma_cost_rows(
    track_rows: Sequence[Sequence[float]],
    has_motion: Sequence[bool],
    det_rows: Sequence[Sequence[float]],
    context: Sequence[Sequence[float]],
    context_index: Sequence[int],
    weights: JcmaWeights,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`jcma_cost` for a small pool given as Python rows, computed on Python floats.

    ``track_rows[i]`` starts with the fields of :class:`TrackMotion` in order (predicted box x1, y1,
    x2, y2, last observed centre x, y, elapsed reference frames, v_avg x, y, v_last x, y; further
    entries are ignored), ``det_rows[j]`` with the detection box, ``context[k]`` is an (x, y) centre.
    A caller that already holds these numbers as floats (JPTrack) skips six small arrays per call.

    Every term is the vectorised path's IEEE operations in the same order, so the values are the
    same (``tests/test_track_small_pools.py`` compares both paths), with two deliberate details:

    * ``hypot`` is numpy's, evaluated in one batched call (``math.hypot`` is a different, more
      accurate algorithm that differs from libm's in the last bit for ~0.5 % of inputs);
      ``math.atan2`` is libm's ``atan2``, which is what ``np.arctan2`` calls on strided views
      on AVX2 machines. On AVX-512 ones numpy has its own SIMD ``hypot``/``arctan2`` kernels, and
      the two paths can differ by a few ulp (~1e-16 in a cost; the tests allow 1e-14).
    * The cosine sum of eq. 15 is added sequentially over k. The vectorised path does it as one BLAS
      product, whose last bit depends on the kernel OpenBLAS picks (FMA, and for a single row or
      column even on the arrays' memory alignment), so that term agrees to ~1e-15, not bit for bit.

    ``min``/``max`` are written as conditional expressions (same values for these finite inputs,
    a fraction of a builtin call's cost).
    """
    w = weights
    t_rows = [row[:4] for row in track_rows]
    d_rows = [row[:4] for row in det_rows]
    n_t, n_d = len(t_rows), len(d_rows)
    if n_t == 0 or n_d == 0:
        return np.zeros((n_t, n_d)), np.zeros((n_t, n_d), dtype=bool)
    ci = [((x1 + x2) * 0.5, (y1 + y2) * 0.5) for x1, y1, x2, y2 in t_rows]
    cj = [((x1 + x2) * 0.5, (y1 + y2) * 0.5) for x1, y1, x2, y2 in d_rows]
    ctx = list(context) if len(context) > 1 else []
    n_k = len(ctx)
    has = list(has_motion)
    any_motion = True in has

    # Every vector whose length is needed, for one np.hypot call, in this order: centre offsets
    # (T*D); with motion, expected velocities (T*D), accelerations (T*D) and mean velocities (T);
    # with context, the track-side (T*K) and detection-side (K*D) relational vectors.
    xs = [jx - ix for ix, _ in ci for jx, _ in cj]
    ys = [jy - iy for _, iy in ci for _, jy in cj]
    if any_motion:
        v_avg = [(row[7], row[8]) for row in track_rows]
        v_exp = [((jx - row[4]) / row[6], (jy - row[5]) / row[6]) for row in track_rows for jx, jy in cj]
        accel = [
            ((vx - row[9]) / row[6], (vy - row[10]) / row[6])
            for i, row in enumerate(track_rows)
            for vx, vy in v_exp[i * n_d : (i + 1) * n_d]
        ]
        xs += [v[0] for v in v_exp] + [a[0] for a in accel] + [v[0] for v in v_avg]
        ys += [v[1] for v in v_exp] + [a[1] for a in accel] + [v[1] for v in v_avg]
    if n_k:
        xs += [kx - ix for ix, _ in ci for kx, _ in ctx] + [kx - jx for kx, _ in ctx for jx, _ in cj]
        ys += [ky - iy for _, iy in ci for _, ky in ctx] + [ky - jy for _, ky in ctx for _, jy in cj]
    norms = np.hypot(np.array(xs), np.array(ys)).tolist()
    n_p = n_t * n_d
    dist = norms[:n_p]
    if any_motion:
        speed_exp = norms[n_p : 2 * n_p]
        accel_norm = norms[2 * n_p : 3 * n_p]
        speed_avg = norms[3 * n_p : 3 * n_p + n_t]

    # Eq. 15's unit vectors: rows a_i (own context object zeroed, as the vectorised path's mask
    # does) and columns b_j, so C_rel is a running sum over k of a_ik . b_kj.
    rel_rows: list[list[float]] = []  # per track i: [a_i0x, a_i0y, a_i1x, ...]
    rel_cols: list[list[float]] = []  # per detection j: [b_0jx, b_0jy, b_1jx, ...]
    counts: list[int] = []
    if n_k:
        m = n_k * (n_t + n_d)
        units: list[float] = []
        for x, y, r in zip(xs[-m:], ys[-m:], norms[-m:]):
            if r > 1e-9:
                units += (x / r, y / r)
            else:
                units += (0.0, 0.0)
        for i, own in enumerate(context_index):
            row = units[2 * i * n_k : 2 * (i + 1) * n_k]
            inside = 0 <= own < n_k
            if inside:
                row[2 * own] *= 0.0
                row[2 * own + 1] *= 0.0
            rel_rows.append(row)
            counts.append(n_k - 1 if inside else n_k)
        b_units = units[2 * n_t * n_k :]
        rel_cols = [
            [v for k in range(n_k) for v in b_units[2 * (k * n_d + j) : 2 * (k * n_d + j) + 2]] for j in range(n_d)
        ]

    pi, two_pi, half_pi = math.pi, 2.0 * math.pi, math.pi / 2.0
    w_iou, w_dist, w_motion, w_rel = w.w_iou, w.w_dist, w.w_motion, w.w_rel
    b_speed, b_dir, b_acc = w.b_speed, w.b_direction, w.b_acceleration
    min_speed, accel_scale = w.min_speed, w.accel_scale
    det_geom = [(x1, y1, x2, y2, (x2 - x1) * (y2 - y1), (x2 - x1) + (y2 - y1)) for x1, y1, x2, y2 in d_rows]
    cost: list[float] = []
    gate: list[bool] = []
    for i, (ax1, ay1, ax2, ay2) in enumerate(t_rows):
        area_t = (ax2 - ax1) * (ay2 - ay1)
        size_t = (ax2 - ax1) + (ay2 - ay1)
        moving = any_motion and has[i]
        if moving:
            sa = speed_avg[i]
            ang_avg = math.atan2(v_avg[i][1], v_avg[i][0])
            offset = w.speed_offset + sa
            speed_den = offset if offset > w.speed_floor else w.speed_floor
            sa_slow = sa < min_speed
        count = counts[i] if n_k else 0
        rel_row = rel_rows[i] if n_k else []
        for j, (bx1, by1, bx2, by2, area_d, size_d) in enumerate(det_geom):
            p = i * n_d + j
            # Eq. 10 (geometry.iou_xyxy's operations).
            iw = (ax2 if ax2 < bx2 else bx2) - (ax1 if ax1 > bx1 else bx1)
            ih = (ay2 if ay2 < by2 else by2) - (ay1 if ay1 > by1 else by1)
            inter = (iw if iw > 0.0 else 0.0) * (ih if ih > 0.0 else 0.0)
            union = area_t + area_d - inter
            c_iou = 1.0 - (inter / (union if union > 1e-12 else 1e-12) if union > 0 else 0.0)
            # Eqs. 11-12.
            scale = (size_t + size_d) / 4.0 * 2.0
            c_dist = dist[p] / (scale if scale > 1e-9 else 1e-9)
            if c_dist > 1.0:
                c_dist = 1.0
            c = w_iou * c_iou + w_dist * c_dist
            # Eqs. 13-14; a track without motion history adds 0 (when another track has one).
            if moving:
                se = speed_exp[p]
                c_speed = abs(se - sa) / speed_den
                if c_speed > 1.0:
                    c_speed = 1.0
                if se < min_speed or sa_slow:
                    c_dir = 0.0
                else:
                    vx, vy = v_exp[p]
                    c_dir = abs((math.atan2(vy, vx) - ang_avg + pi) % two_pi - pi) / half_pi
                    if c_dir > 1.0:
                        c_dir = 1.0
                c_acc = accel_norm[p] / accel_scale
                if c_acc > 1.0:
                    c_acc = 1.0
                c += w_motion * (b_speed * c_speed + b_dir * c_dir + b_acc * c_acc)
            elif any_motion:
                c += w_motion * 0.0
            # Eq. 15.
            c_rel = 0.0
            if count:
                total = 0.0
                for u, v in zip(rel_row, rel_cols[j]):
                    total += u * v
                c_rel = 1.0 - total / count
            cost.append(c + w_rel * c_rel)
            gate.append(c_iou < 1.0 or c_dist < 1.0)
    return np.array(cost).reshape(n_t, n_d), np.array(gate).reshape(n_t, n_d)
