"""Constant-velocity Kalman filters of a box, batched over tracks, whose transition uses real time.

Two parameterisations, chosen by the filter's :class:`KalmanModel`:

* ``[cx, cy, w, h]`` (JPTrack's): state ``[cx, cy, w, h, vcx, vcy, vw, vh]``, noise standard
  deviations proportional to the width for ``cx`` and ``w`` and to the height for ``cy`` and
  ``h`` (BoT-SORT's xywh filter), with optional floors in pixels (below);
* ``[cx, cy, a, h]`` with ``a = w / h`` (``aspect_ratio=True``, ByteTrack's): the reference
  filter of ByteTrack (Zhang et al.'s ``kalman_filter.py``, boxmot's ``KalmanFilterXYAH``). Every
  noise is proportional to the height, and the aspect ratio is nearly fixed: a new track's ratio
  is trusted to 0.01, it drifts by 0.01 a frame and a measured ratio is trusted to 0.1 only, so a
  box keeps roughly the shape of its first detection. Its ``state`` and ``state_covariance`` are
  in that parameterisation; ``mean`` and ``covariance`` show them as ``[cx, cy, w, h, ...]`` like
  the other model's (``w = a h``, the covariance through the Jacobian of that map), refreshed at
  every step, for the code that reads boxes and velocities. With ``[cx, cy, w, h]`` the state
  arrays are ``mean`` and ``covariance`` themselves.

Both use ByteTrack's standard deviations: 1/20 of the size for positions (and the measurement),
1/160 of the size per frame for velocities, twice and ten times those for a new track. They are
converted to continuous time: velocities are per second via ``ref_fps`` (the 30 Hz of the paper's
cameras), and process noise grows linearly with ``dt * ref_fps`` (a random walk), so a 15 Hz
stream, a 30 Hz stream and a stream with dropped frames get the same uncertainty for the same
elapsed time. At ``ref_fps`` with no drops a step is exactly one reference frame, the reference
filter's step (``tests/core/test_track_bytetrack_reference.py`` checks ours against boxmot's).

The floors of the ``[cx, cy, w, h]`` model, all 0 (off) unless given; JPTrack sets them
(:class:`~gldt_core.track.jptrack.JPTrackConfig`, ``kf_*``) for small targets:

* ``min_std_px``: every size-proportional standard deviation is at least this (velocities at
  this times 1/8, their weights' ratio), which keeps the filter well conditioned on 2 px boxes;
* ``min_centre_process_std_px``: the process noise of the box centre (px per reference frame).
  Size-proportional noise suits pedestrians filmed from a still camera. Air to air, the camera
  shakes and turns, and that moves every target in the image by the same pixels whatever its
  size: a 6 px drone jumps as far as a 60 px one. With 1/20 of 6 px the filter took such jumps
  for measurement noise, smoothed them away, and its box trailed the target by more than the
  box's own size: fed the ground truth of the synthetic test scenes, JPTrack then fell far short
  of following them perfectly, which it does with the floor. A floor on the velocity noise
  instead followed the targets as well but made every velocity follow the detections' jitter,
  and the avoidance planner reads those velocities; the position floor leaves them smooth
  (tests/core/test_track_kalman.py);
* ``min_birth_centre_velocity_std_px``: the uncertainty of a new track's centre velocity (px per
  reference frame). A drone can cross the image at a few pixels per frame whatever its size, but
  10/160 of the size says a new 6 px box is almost surely still (0.4 px per frame). With the
  position floor taking the innovations, such a filter learnt a fast small target's velocity too
  slowly for PMR to bring the track back after an occlusion (tests/core/test_track_lost.py).

Besides the floors, ``size_measurement_factor`` (1 unless given) multiplies the measurement noise of
``w`` and ``h`` (and its floor), the position's staying ByteTrack's. A detector's box of a small
target is tight on one frame and loose on the next; JPTrack trusts the measured size less than
the measured position (5), and the size velocity still follows a target closing in.

The measurements behind the floors and the factor are in docs/experiment-log.md (Tracking).

Why numpy and not ``filterpy.kalman.KalmanFilter`` (which the issue names): the algebra is
identical (``tests/core/test_track_kalman.py`` checks our predict/update against filterpy's), but a
tracker runs the filter for every track on every frame, and filterpy can only do that one track at
a time. :func:`predict_many` / :func:`update_many` advance and correct all tracks of a frame with
one batched numpy step each, and a single filter's ``predict``/``update`` are those steps on a
batch of one; ``gldt bench tracking`` measures them against a loop of filterpy filters at 3 and 50
tracks (the "Kalman" line of its output).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

STD_WEIGHT_POSITION = 1.0 / 20.0
STD_WEIGHT_VELOCITY = 1.0 / 160.0
#: ByteTrack's ``[cx, cy, a, h]`` filter: standard deviations of the aspect ratio ``a`` (no unit)
#: and of its velocity (per reference frame): process noise, measurement noise, a new track's.
ASPECT_PROCESS_STD = 1e-2
ASPECT_VELOCITY_PROCESS_STD = 1e-5
ASPECT_MEASUREMENT_STD = 1e-1
ASPECT_BIRTH_STD = 1e-2
ASPECT_VELOCITY_BIRTH_STD = 1e-5


@dataclass(frozen=True)
class KalmanModel:
    """What a filter estimates and how much noise it assumes (module docstring).

    ``aspect_ratio``: ByteTrack's ``[cx, cy, a, h]`` state instead of ``[cx, cy, w, h]``. The
    floors, in pixels (per reference frame for the velocity one), apply to ``[cx, cy, w, h]``
    only; 0 turns each off. ``size_measurement_factor`` scales the measurement noise of ``w`` and
    ``h`` (``[cx, cy, w, h]`` only; 1 is ByteTrack's).
    """

    aspect_ratio: bool = False
    min_std_px: float = 0.0
    min_centre_process_std_px: float = 0.0
    min_birth_centre_velocity_std_px: float = 0.0
    size_measurement_factor: float = 1.0

    def __post_init__(self) -> None:
        floors = (self.min_std_px, self.min_centre_process_std_px, self.min_birth_centre_velocity_std_px)
        if not all(math.isfinite(f) and f >= 0.0 for f in floors):
            raise ValueError(f"Kalman floors must be finite and >= 0, got {floors}")
        if not (math.isfinite(self.size_measurement_factor) and self.size_measurement_factor > 0.0):
            raise ValueError(f"size_measurement_factor must be finite and > 0, got {self.size_measurement_factor!r}")
        if self.aspect_ratio and (any(floors) or self.size_measurement_factor != 1.0):
            raise ValueError(
                "the [cx, cy, a, h] filter is ByteTrack's reference filter: it has no pixel floors or size factor"
            )

    @functools.cached_property
    def tables(self) -> _Tables:
        """The model's noise as per-entry arrays (built once per model)."""
        return _tables(self)


#: ByteTrack's reference filter.
BYTETRACK_MODEL = KalmanModel(aspect_ratio=True)


@dataclass(frozen=True)
class _Tables:
    """Per state entry: the column of the state its noise scales with, the std weight and floor
    (process noise; velocity entries per reference frame); the same per measured entry (R); the
    smallest ``w, h`` or ``a, h`` after a step."""

    size_col: np.ndarray
    weight: np.ndarray
    floor: np.ndarray
    r_size_col: np.ndarray
    r_weight: np.ndarray
    r_floor: np.ndarray
    min_size: float


def _tables(model: KalmanModel) -> _Tables:
    wp, wv = STD_WEIGHT_POSITION, STD_WEIGHT_VELOCITY
    if model.aspect_ratio:
        # std = max(floor, weight * h): zero weight and a floor give the aspect ratio's constants.
        return _Tables(
            size_col=np.full(8, 3),
            weight=np.array([wp, wp, 0.0, wp, wv, wv, 0.0, wv]),
            floor=np.array([0.0, 0.0, ASPECT_PROCESS_STD, 0.0, 0.0, 0.0, ASPECT_VELOCITY_PROCESS_STD, 0.0]),
            r_size_col=np.full(4, 3),
            r_weight=np.array([wp, wp, 0.0, wp]),
            r_floor=np.array([0.0, 0.0, ASPECT_MEASUREMENT_STD, 0.0]),
            min_size=1e-4,  # boxmot's clamp of a and h
        )
    size_floor = model.min_std_px
    centre_floor = max(size_floor, model.min_centre_process_std_px)
    velocity_floor = size_floor * (wv / wp)
    return _Tables(
        size_col=np.array([2, 3, 2, 3, 2, 3, 2, 3]),
        weight=np.array([wp] * 4 + [wv] * 4),
        floor=np.array([centre_floor] * 2 + [size_floor] * 2 + [velocity_floor] * 4),
        r_size_col=np.array([2, 3, 2, 3]),
        r_weight=np.array([wp, wp] + [wp * model.size_measurement_factor] * 2),
        r_floor=np.array([size_floor, size_floor] + [size_floor * model.size_measurement_factor] * 2),
        min_size=1e-3,
    )


def _birth_state(box_cxcywh: np.ndarray, ref_fps: float, model: KalmanModel) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of a new track at ``box_cxcywh`` in the model's parameterisation."""
    cx, cy, w, h = (float(v) for v in box_cxcywh[:4])
    wp, wv = STD_WEIGHT_POSITION, STD_WEIGHT_VELOCITY
    mean = np.zeros(8)
    if model.aspect_ratio:
        mean[:4] = cx, cy, w / h, h
        np.maximum(mean[2:4], model.tables.min_size, out=mean[2:4])
        std = np.array(
            [
                2 * wp * h,
                2 * wp * h,
                ASPECT_BIRTH_STD,
                2 * wp * h,
                10 * wv * h * ref_fps,
                10 * wv * h * ref_fps,
                ASPECT_VELOCITY_BIRTH_STD * ref_fps,
                10 * wv * h * ref_fps,
            ]
        )
        return mean, np.diag(std**2)
    mean[:4] = cx, cy, w, h
    floor = model.min_std_px
    sw, sh = max(floor, wp * w), max(floor, wp * h)
    vfloor = floor * (wv / wp)
    vw, vh = max(vfloor, wv * w) * 10 * ref_fps, max(vfloor, wv * h) * 10 * ref_fps
    vmin = model.min_birth_centre_velocity_std_px * ref_fps
    std = np.array([2 * sw, 2 * sh, 2 * sw, 2 * sh, max(vw, vmin), max(vh, vmin), vw, vh])
    return mean, np.diag(std**2)


class ConstantVelocityKalman:
    """One track's filter. ``state``/``state_covariance`` are the filter; ``mean``/``covariance``
    the same as ``[cx, cy, w, h, vcx, vcy, vw, vh]`` (the state arrays themselves for that model),
    always of the same instant. Change the state only through this module's functions."""

    __slots__ = ("mean", "covariance", "state", "state_covariance", "ref_fps", "model")

    def __init__(self, box_cxcywh: np.ndarray, ref_fps: float = 30.0, model: KalmanModel | None = None) -> None:
        self.ref_fps = float(ref_fps)
        self.model = model if model is not None else KalmanModel()
        self.state, self.state_covariance = _birth_state(
            np.asarray(box_cxcywh, dtype=np.float64), self.ref_fps, self.model
        )
        self.mean, self.covariance = self.state, self.state_covariance
        if self.model.aspect_ratio:
            _set_states([self], self.state[None, :], self.state_covariance[None, :, :])

    def transition(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Transition matrix F and process noise Q (diagonal, as a vector) of the state for ``dt``
        seconds: the model of :meth:`predict` as matrices (what a textbook filter such as
        filterpy's takes)."""
        f = np.eye(8)
        f[0, 4] = f[1, 5] = f[2, 6] = f[3, 7] = dt
        steps = np.array([max(dt, 0.0) * self.ref_fps])
        return f, _process_noise(self.state[None, :], steps, _noise_unit(self.ref_fps), self.model.tables)[0]

    def predicted(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """``mean`` and ``covariance`` ``dt`` seconds ahead (now, for ``dt <= 0``), without changing
        the filter."""
        means, covs = predicted_many([self], np.array([dt]))
        return means[0], covs[0]

    def predict(self, dt: float) -> None:
        """Advance the filter by ``dt`` seconds."""
        predict_many([self], np.array([dt]))

    def measurement_noise(self) -> np.ndarray:
        """R (4x4) of the measured ``[cx, cy, w, h]`` or ``[cx, cy, a, h]``: ByteTrack's
        size-proportional measurement noise."""
        return np.diag(_measurement_variances(self.state[None, :], self.model.tables)[0])

    def measured(self, box_cxcywh: np.ndarray) -> np.ndarray:
        """A box ``[cx, cy, w, h]`` as this filter measures it."""
        return _measured(np.asarray(box_cxcywh, dtype=np.float64).reshape(1, 4), self.model)[0]

    def update(self, box_cxcywh: np.ndarray) -> None:
        """Fuse one measured box ``[cx, cy, w, h]``."""
        update_many([self], np.asarray(box_cxcywh, dtype=np.float64).reshape(1, 4))

    def stop_height_velocity(self) -> None:
        """Set the height's velocity to 0 (:func:`stop_height_velocities`)."""
        stop_height_velocities([self])


def stop_height_velocities(filters: list[ConstantVelocityKalman]) -> None:
    """Set the height's velocity of each filter to 0: ByteTrack's reference does so for a lost
    track before each prediction, so a coasting box keeps its last size."""
    stop_velocities(filters, (7,))


def stop_velocities(filters: list[ConstantVelocityKalman], columns: tuple[int, ...]) -> None:
    """Set the given velocity columns (4-7) of each filter's state to 0."""
    cols = list(columns)
    moving = [f for f in filters if any(f.state[c] != 0.0 for c in cols)]
    if not moving:
        return
    if _same_model(moving) is None:
        for idx in _by_model(moving):
            stop_velocities([moving[i] for i in idx], columns)
        return
    states = np.array([f.state for f in moving])
    states[:, cols] = 0.0
    _set_states(moving, states, np.array([f.state_covariance for f in moving]))


def _process_noise(states: np.ndarray, steps: np.ndarray, unit: np.ndarray, tables: _Tables) -> np.ndarray:
    """Diagonal process noise ``(n, 8)`` of filters with states ``states`` over ``steps``
    reference frames: stds ``max(floor, weight * size)`` times ``ref_fps`` for velocities
    (``unit``: 1 for positions, which is exact), squared, times the steps."""
    q = (np.maximum(tables.floor, tables.weight * states[:, tables.size_col]) * unit) ** 2
    q *= steps[:, None]
    return q


def _propagate(states: np.ndarray, covs: np.ndarray, dt: np.ndarray, ref: float | np.ndarray, tables: _Tables) -> None:
    """Predict stacked states ``(n, 8)`` and covariances ``(n, 8, 8)`` (fresh arrays, changed in
    place) ``dt`` seconds ahead (``(n,)``, >= 0; ``ref``: one ``ref_fps`` or one per filter).

    ``F P F^T`` is done as two block row/column operations (F = [[I, dt I], [0, I]]), which is
    exactly the matrix product and a few times cheaper for 8x8."""
    n = len(states)
    if np.ndim(ref):
        unit = np.ones((n, 8))
        unit[:, 4:] = np.asarray(ref)[:, None]
    else:
        unit = _noise_unit(float(ref))
    q = _process_noise(states, dt * ref, unit, tables)
    dt_col = dt[:, None]
    states[:, :4] += dt_col * states[:, 4:]
    moved = dt > 0
    if moved.all():
        np.maximum(states[:, 2:4], tables.min_size, out=states[:, 2:4])
    else:
        states[moved, 2:4] = np.maximum(states[moved, 2:4], tables.min_size)
    dt_3 = dt_col[:, :, None]
    covs[:, :4, :] += dt_3 * covs[:, 4:, :]
    covs[:, :, :4] += dt_3 * covs[:, :, 4:]
    covs.reshape(n, 64)[:, ::9] += q  # the diagonals, as a strided view (no fancy indexing)


def _same_model(filters: list[ConstantVelocityKalman]) -> KalmanModel | None:
    """The filters' model when they share one (always, within one tracker: the same object), else
    None."""
    model = filters[0].model
    for f in filters:
        if f.model is not model and f.model != model:
            return None
    return model


def _by_model(filters: list[ConstantVelocityKalman]) -> list[list[int]]:
    """Indices of the filters grouped by model, in order of first appearance."""
    groups: dict[KalmanModel, list[int]] = {}
    for i, f in enumerate(filters):
        groups.setdefault(f.model, []).append(i)
    return list(groups.values())


def _predicted_states(filters: list[ConstantVelocityKalman], dts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """States ``(n, 8)`` and their covariances ``(n, 8, 8)`` ``dts`` seconds ahead; the filters
    share one model."""
    states = np.array([f.state for f in filters])
    covs = np.array([f.state_covariance for f in filters])
    dt = np.maximum(np.asarray(dts, dtype=np.float64), 0.0)
    _propagate(states, covs, dt, _common_ref_fps(filters), filters[0].model.tables)
    return states, covs


def predicted_many(filters: list[ConstantVelocityKalman], dts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``mean`` ``(n, 8)`` and ``covariance`` ``(n, 8, 8)`` of many filters, each ``dts[i]``
    seconds ahead (no step for ``dts[i] <= 0``), in one vectorised step; the filters do not change."""
    if not filters:
        return np.zeros((0, 8)), np.zeros((0, 8, 8))
    model = _same_model(filters)
    if model is None:
        means, covs = np.zeros((len(filters), 8)), np.zeros((len(filters), 8, 8))
        dts = np.asarray(dts, dtype=np.float64)
        for idx in _by_model(filters):
            means[idx], covs[idx] = predicted_many([filters[i] for i in idx], dts[idx])
        return means, covs
    states, covs = _predicted_states(filters, dts)
    if model.aspect_ratio:
        return _aspect_view(states, covs)
    return states, covs


def predict_many(filters: list[ConstantVelocityKalman], dts: np.ndarray) -> None:
    """Advance many filters at once (:func:`predicted_many`, kept)."""
    if not filters:
        return
    if _same_model(filters) is None:
        dts = np.asarray(dts, dtype=np.float64)
        for idx in _by_model(filters):
            predict_many([filters[i] for i in idx], dts[idx])
        return
    states, covs = _predicted_states(filters, dts)
    _set_states(filters, states, covs)


def _set_states(filters: list[ConstantVelocityKalman], states: np.ndarray, covs: np.ndarray) -> None:
    """Store new states (one model) and refresh ``mean``/``covariance``."""
    if filters[0].model.aspect_ratio:
        means, views = _aspect_view(states, covs)
        for f, s, c, m, v in zip(filters, states, covs, means, views):
            f.state, f.state_covariance, f.mean, f.covariance = s, c, m, v
        return
    for f, s, c in zip(filters, states, covs):
        f.state = f.mean = s
        f.state_covariance = f.covariance = c


def _aspect_view(states: np.ndarray, covs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``[cx, cy, a, h, vcx, vcy, va, vh]`` states ``(n, 8)`` and covariances as
    ``[cx, cy, w, h, vcx, vcy, vw, vh]``: ``w = a h``, ``vw = va h + a vh``, the covariance
    through the Jacobian J of that map, ``J P J^T``."""
    a, h, va, vh = states[:, 2], states[:, 3], states[:, 6], states[:, 7]
    means = states.copy()
    means[:, 2] = a * h
    means[:, 6] = va * h + a * vh
    jac = np.zeros((len(states), 8, 8))
    jac[:, _DIAGONAL, _DIAGONAL] = 1.0
    jac[:, 2, 2], jac[:, 2, 3] = h, a
    jac[:, 6, 2], jac[:, 6, 3], jac[:, 6, 6], jac[:, 6, 7] = vh, va, h, a
    return means, jac @ covs @ jac.transpose(0, 2, 1)


_DIAGONAL = np.arange(8)


@functools.lru_cache(maxsize=8)
def _noise_unit(ref_fps: float) -> np.ndarray:
    """``[1, 1, 1, 1, ref, ref, ref, ref]``: the per-entry factor of the process noise stds, built
    once per reference rate (read-only)."""
    out = np.array([1.0, 1.0, 1.0, 1.0, ref_fps, ref_fps, ref_fps, ref_fps])
    out.flags.writeable = False
    return out


def _common_ref_fps(filters: list[ConstantVelocityKalman]) -> float | np.ndarray:
    """The filters' ``ref_fps`` as one float when they agree (always, within one tracker), else
    one per filter: a scalar saves building and broadcasting an array every frame."""
    ref = filters[0].ref_fps
    if all(f.ref_fps == ref for f in filters):
        return ref
    return np.array([f.ref_fps for f in filters])


def _measurement_variances(states: np.ndarray, tables: _Tables) -> np.ndarray:
    """Diagonal of R ``(n, 4)``: ByteTrack's size-proportional measurement noise of each state."""
    return np.maximum(tables.r_floor, tables.r_weight * states[:, tables.r_size_col]) ** 2


def _measured(boxes_cxcywh: np.ndarray, model: KalmanModel) -> np.ndarray:
    """Boxes ``(n, 4)`` ``[cx, cy, w, h]`` as the model measures them."""
    if not model.aspect_ratio:
        return boxes_cxcywh
    z = boxes_cxcywh.copy()
    z[:, 2] = boxes_cxcywh[:, 2] / boxes_cxcywh[:, 3]
    return z


def update_many(filters: list[ConstantVelocityKalman], boxes_cxcywh: np.ndarray) -> None:
    """Fuse one measured box ``[cx, cy, w, h]`` into each filter at once (one batched solve
    instead of one per track); exactly ``update`` applied to each (see tests/core/test_track_kalman.py)."""
    n = len(filters)
    if n == 0:
        return
    boxes = np.asarray(boxes_cxcywh, dtype=np.float64)
    model = _same_model(filters)
    if model is None:
        boxes = boxes.reshape(n, 4)
        for idx in _by_model(filters):
            update_many([filters[i] for i in idx], boxes[idx])
        return
    tables = model.tables
    states = np.array([f.state for f in filters])
    covs = np.array([f.state_covariance for f in filters])
    s = covs[:, :4, :4].copy()
    s.reshape(n, 16)[:, ::5] += _measurement_variances(states, tables)  # the diagonals, as a strided view
    gain = np.linalg.solve(s, covs[:, :4, :]).transpose(0, 2, 1)  # (n, 8, 4): P H^T S^-1 (S symmetric)
    innovation = (_measured(boxes.reshape(n, 4), model) if model.aspect_ratio else boxes) - states[:, :4]
    states = states + np.einsum("nij,nj->ni", gain, innovation)
    covs = covs - gain @ s @ gain.transpose(0, 2, 1)
    np.maximum(states[:, 2:4], tables.min_size, out=states[:, 2:4])
    _set_states(filters, states, covs)
