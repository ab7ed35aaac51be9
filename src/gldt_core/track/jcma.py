"""JCMA: the joint cost of eqs. 9-15 for all (track, detection) pairs of an association pool.

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

Each term is written once, in :func:`pair_cost` (eqs. 9-14) and :func:`unit_vector` (eq. 15), on
operands that are Python floats or numpy arrays (:mod:`gldt_core.track.fastpath`). :func:`jcma_cost`
evaluates them on arrays broadcast over every pair of the pool, or, for a small pool
(:func:`gldt_core.track.fastpath.on_floats`), pair by pair on floats. The mean of eq. 15 is a
running sum over k on floats and one matrix product on arrays.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Generic

import numpy as np

from gldt_core.track.boxes import centre_size, iou, midpoint
from gldt_core.track.fastpath import ARRAYS, FLOATS, Mask, Ops, V, on_floats


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


#: The columns of :attr:`TrackMotion.table`.
MOTION_COLUMNS = ("x1", "y1", "x2", "y2", "last_cx", "last_cy", "elapsed_ref", "vx_avg", "vy_avg", "vx_last", "vy_last")


@dataclass(slots=True)
class TrackMotion:
    """What the cost needs of each track of the pool. ``rows[i]`` starts with track i's
    :data:`MOTION_COLUMNS` (predicted box at the frame time; last observed centre; reference frames
    since that observation, > 0; mean and last filtered velocity in px per reference frame), further
    entries are ignored; ``has_motion[i]``: whether track i has at least two observations. Plain
    Python rows, so that a small pool is costed without building arrays."""

    rows: Sequence[Sequence[float]]
    has_motion: Sequence[bool]

    @classmethod
    def from_fields(
        cls,
        pred_xyxy: np.ndarray,
        last_obs_c: np.ndarray,
        elapsed_ref: np.ndarray,
        v_avg: np.ndarray,
        v_last: np.ndarray,
        has_motion: np.ndarray,
    ) -> TrackMotion:
        """From per-field arrays: ``(T, 4)``, ``(T, 2)``, ``(T,)``, ``(T, 2)``, ``(T, 2)``, ``(T,)``."""
        table = np.column_stack([pred_xyxy, last_obs_c, elapsed_ref, v_avg, v_last]).astype(np.float64)
        return cls(table.tolist(), np.asarray(has_motion, dtype=bool).tolist())

    def table(self) -> np.ndarray:
        """The rows' :data:`MOTION_COLUMNS` as a ``(T, 11)`` array."""
        return np.array(self.rows, dtype=np.float64).reshape(len(self.rows), -1)[:, : len(MOTION_COLUMNS)]


@dataclass(slots=True)
class TrackTerms(Generic[V]):
    """One track's part of the pair cost (or, as arrays, every track's)."""

    x1: V
    y1: V
    x2: V
    y2: V
    cx: V
    cy: V
    size: V  # w + h
    last_cx: V
    last_cy: V
    elapsed: V
    speed_avg: V
    heading_avg: V
    speed_scale: V  # the denominator of C_speed
    slow: Mask  # mean speed below min_speed: no direction
    vx_last: V
    vy_last: V


def track_terms(
    ops: Ops[V],
    w: JcmaWeights,
    x1: V,
    y1: V,
    x2: V,
    y2: V,
    last_cx: V,
    last_cy: V,
    elapsed: V,
    vx_avg: V,
    vy_avg: V,
    vx_last: V,
    vy_last: V,
) -> TrackTerms[V]:
    """The quantities of eqs. 10-14 that depend on the track alone (arguments: :data:`MOTION_COLUMNS`)."""
    cx, cy, width, height = centre_size(x1, y1, x2, y2)
    speed_avg = ops.hypot(vx_avg, vy_avg)
    return TrackTerms(
        x1,
        y1,
        x2,
        y2,
        cx,
        cy,
        width + height,
        last_cx,
        last_cy,
        elapsed,
        speed_avg,
        ops.atan2(vy_avg, vx_avg),
        ops.maximum(w.speed_floor, w.speed_offset + speed_avg),
        speed_avg < w.min_speed,
        vx_last,
        vy_last,
    )


def pair_cost(
    ops: Ops[V], w: JcmaWeights, t: TrackTerms[V], x1: V, y1: V, x2: V, y2: V, moving: Mask | None
) -> tuple[V, Mask]:
    """Eq. 9 without its relational term, and the geometric gate, for track ``t`` and detection box
    ``x1..y2``. ``moving``: whether the track has a motion history (None: no track of the pool has
    one, so C_motion is 0 for every pair and is not computed)."""
    cx, cy, width, height = centre_size(x1, y1, x2, y2)
    c_iou = 1.0 - iou(ops, t.x1, t.y1, t.x2, t.y2, x1, y1, x2, y2)  # eq. 10
    dist = ops.hypot(cx - t.cx, cy - t.cy)  # eqs. 11-12
    scale = (t.size + (width + height)) / 4.0 * 2.0
    c_dist = ops.minimum(1.0, dist / ops.maximum(scale, 1e-9))
    cost = w.w_iou * c_iou + w.w_dist * c_dist
    if moving is not None:  # eqs. 13-14, velocities in px per reference frame
        vx = (cx - t.last_cx) / t.elapsed
        vy = (cy - t.last_cy) / t.elapsed
        speed = ops.hypot(vx, vy)
        c_speed = ops.minimum(1.0, abs(speed - t.speed_avg) / t.speed_scale)
        turn = abs((ops.atan2(vy, vx) - t.heading_avg + math.pi) % (2.0 * math.pi) - math.pi)
        c_direction = ops.where((speed < w.min_speed) | t.slow, 0.0, ops.minimum(1.0, turn / (math.pi / 2.0)))
        accel = ops.hypot((vx - t.vx_last) / t.elapsed, (vy - t.vy_last) / t.elapsed)
        c_accel = ops.minimum(1.0, accel / w.accel_scale)
        c_motion = w.b_speed * c_speed + w.b_direction * c_direction + w.b_acceleration * c_accel
        cost = cost + w.w_motion * ops.where(moving, c_motion, 0.0)
    return cost, (c_iou < 1.0) | (c_dist < 1.0)


def unit_vector(ops: Ops[V], x: V, y: V) -> tuple[V, V]:
    """``(x, y)`` scaled to length 1; a zero-length vector (below 1e-9) stays (0, 0)."""
    length = ops.hypot(x, y)
    scale = ops.maximum(length, 1e-9)
    keep = length > 1e-9
    return ops.where(keep, x / scale, 0.0), ops.where(keep, y / scale, 0.0)


def jcma_cost(
    motion: TrackMotion,
    dets_xyxy: np.ndarray,
    context_c: np.ndarray | None,
    context_index: np.ndarray | None,
    weights: JcmaWeights,
) -> tuple[np.ndarray, np.ndarray]:
    """Cost matrix ``(T, D)`` of eq. 9 and the geometric gate mask (True = may match).

    ``context_c`` ``(K, 2)`` holds the centres of the objects k of eq. 15 and ``context_index[i]``
    the row of track i in it (excluded from its own sum; -1: none). ``None`` for both: the objects
    are the pool's tracks at their predicted centres (JPTrack's choice, see the module docstring).
    """
    n_t, n_d = len(motion.rows), len(dets_xyxy)
    if n_t == 0 or n_d == 0:
        return np.zeros((n_t, n_d)), np.zeros((n_t, n_d), dtype=bool)
    if (context_c is None) != (context_index is None):
        raise ValueError("give both context_c and context_index, or neither")
    if on_floats(n_t * n_d):
        return _cost_on_floats(
            motion.rows,
            motion.has_motion,
            np.asarray(dets_xyxy).tolist(),
            None if context_c is None else np.asarray(context_c).tolist(),
            None if context_index is None else np.asarray(context_index).tolist(),
            weights,
        )
    return _cost_on_arrays(
        motion.table(),
        np.asarray(motion.has_motion, dtype=bool),
        np.asarray(dets_xyxy, dtype=np.float64),
        None if context_c is None else np.asarray(context_c, dtype=np.float64).reshape(-1, 2),
        None if context_index is None else np.asarray(context_index, dtype=np.int64),
        weights,
    )


def _cost_on_arrays(
    table: np.ndarray,
    has: np.ndarray,
    dets: np.ndarray,
    context_c: np.ndarray | None,
    context_index: np.ndarray | None,
    w: JcmaWeights,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`jcma_cost` with tracks as ``(T, 1)`` and detections as ``(D,)`` columns."""
    t = track_terms(ARRAYS, w, *(table[:, k, None] for k in range(len(MOTION_COLUMNS))))
    moving = has[:, None] if has.any() else None
    cost, gate = pair_cost(ARRAYS, w, t, dets[:, 0], dets[:, 1], dets[:, 2], dets[:, 3], moving)
    ci = np.column_stack([t.cx[:, 0], t.cy[:, 0]])
    cj = midpoint(dets[:, :2], dets[:, 2:4])
    if context_c is None or context_index is None:
        context_c, context_index = ci, np.arange(len(ci))
    return cost + w.w_rel * relational_cost(ci, cj, context_c, context_index), np.asarray(gate)


def relational_cost(ci: np.ndarray, cj: np.ndarray, context_c: np.ndarray, context_index: np.ndarray) -> np.ndarray:
    """Eq. 15 for all pairs, on arrays: ``1 - mean_k cos(c_k - c_i, c_k - c_j)`` over context
    objects k != i (``ci`` ``(T, 2)``, ``cj`` ``(D, 2)``, ``context_c`` ``(K, 2)``).

    The cosine sum is one matrix product of unit vectors, ``(T, 2K) @ (2K, D)``, so the cost stays
    small at 50 targets.
    """
    n_t, n_d, n_k = len(ci), len(cj), len(context_c)
    if n_k <= 1:
        return np.zeros((n_t, n_d))
    context_c = np.asarray(context_c, dtype=np.float64)
    ax, ay = unit_vector(ARRAYS, context_c[None, :, 0] - ci[:, 0, None], context_c[None, :, 1] - ci[:, 1, None])
    bx, by = unit_vector(ARRAYS, context_c[:, 0, None] - cj[None, :, 0], context_c[:, 1, None] - cj[None, :, 1])
    a_unit = np.stack([ax, ay], axis=-1)  # (T, K, 2)
    b_unit = np.stack([bx, by], axis=1)  # (K, 2, D)
    mask = np.ones((n_t, n_k))
    valid = context_index >= 0
    if valid.all():
        mask[np.arange(n_t), context_index] = 0.0
    else:
        mask[np.flatnonzero(valid), context_index[valid]] = 0.0
    a_unit *= mask[..., None]
    total = a_unit.reshape(n_t, 2 * n_k) @ b_unit.reshape(2 * n_k, n_d)
    counts = mask.sum(1)
    has = counts > 0
    if has.all():
        return 1.0 - total / counts[:, None]
    out = np.zeros((n_t, n_d))
    out[has] = 1.0 - total[has] / counts[has, None]
    return out


def _cost_on_floats(
    track_rows: Sequence[Sequence[float]],
    has_motion: Sequence[bool],
    det_rows: Sequence[Sequence[float]],
    context: Sequence[Sequence[float]] | None,
    context_index: Sequence[int] | None,
    w: JcmaWeights,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`jcma_cost` pair by pair on Python floats (rows as in :func:`jcma_cost`'s arrays)."""
    tracks = [track_terms(FLOATS, w, *row[: len(MOTION_COLUMNS)]) for row in track_rows]
    n_t, n_d = len(tracks), len(det_rows)
    if context is None or context_index is None:
        context, context_index = [(t.cx, t.cy) for t in tracks], range(n_t)
    relational = _relational_on_floats(tracks, det_rows, context, context_index)
    cost: list[float] = []
    gate: list[bool] = []
    for i, (t, has) in enumerate(zip(tracks, has_motion)):
        # A track without motion history adds no motion term (the array path adds 0 for it).
        moving = True if has else None
        for j, (x1, y1, x2, y2, *_) in enumerate(det_rows):
            c, g = pair_cost(FLOATS, w, t, x1, y1, x2, y2, moving)
            cost.append(c + w.w_rel * relational[i][j])
            gate.append(bool(g))
    return np.array(cost).reshape(n_t, n_d), np.array(gate).reshape(n_t, n_d)


def _relational_on_floats(
    tracks: Sequence[TrackTerms[float]],
    det_rows: Sequence[Sequence[float]],
    context: Sequence[Sequence[float]],
    context_index: Sequence[int],
) -> list[list[float]]:
    """:func:`relational_cost` on Python floats, with the cosine sum added k by k."""
    n_k = len(context)
    if n_k <= 1:
        return [[0.0] * len(det_rows) for _ in tracks]
    det_centres = [centre_size(x1, y1, x2, y2)[:2] for x1, y1, x2, y2, *_ in det_rows]
    # to_context[k][j]: unit vector from detection j to object k.
    to_context = [[unit_vector(FLOATS, kx - jx, ky - jy) for jx, jy in det_centres] for kx, ky in context]
    out = []
    for t, own in zip(tracks, context_index):
        # The unit vectors from track i to each object k, its own object zeroed as the array path's mask does.
        from_track = [unit_vector(FLOATS, kx - t.cx, ky - t.cy) for kx, ky in context]
        inside = 0 <= own < n_k
        if inside:
            ox, oy = from_track[own]
            from_track[own] = (ox * 0.0, oy * 0.0)
        count = n_k - 1 if inside else n_k
        row = []
        for j in range(len(det_centres)):
            total = 0.0
            for (ax, ay), column in zip(from_track, to_context):
                bx, by = column[j]
                total += ax * bx
                total += ay * by
            row.append(1.0 - total / count if count else 0.0)
        out.append(row)
    return out
