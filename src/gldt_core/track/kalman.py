"""Constant-velocity Kalman filter on ``[cx, cy, w, h]`` whose transition uses real elapsed time.

State ``x = [cx, cy, w, h, vcx, vcy, vw, vh]`` in pixels and pixels per second; covariance 8x8.
Noise follows ByteTrack's (and BoT-SORT's xywh) choice of standard deviations proportional to the
box size (1/20 of the size for position, 1/160 of the size per frame for velocity), converted to
continuous time: velocities are per second via ``ref_fps`` (the 30 Hz of the paper's cameras), and
process noise grows linearly with ``dt * ref_fps`` (a random walk), so a 15 Hz stream, a 30 Hz
stream and a stream with dropped frames get the same uncertainty for the same elapsed time. At
30 Hz with no drops, for boxes of 32 px and more, it is ByteTrack's filter exactly (up to the xywh
parameterisation).

One departure, for small boxes: the process noise of the box centre has a floor in pixels
(:data:`MIN_CENTRE_PROCESS_STD_PX`). Size-proportional noise suits pedestrians filmed from a
still camera. Air to air, the camera shakes and turns, and that moves every target in the image by
the same pixels whatever its size: a 6 px drone jumps as far as a 60 px one. With 1/20 of 6 px the
filter took such jumps for measurement noise, smoothed them away, and its box trailed the target
by more than the box's own size: fed the ground truth of the synthetic test scenes, JPTrack then
fell far short of following them perfectly, which it does with the floor. A floor on the velocity noise instead
followed the targets as well but made every velocity follow the detections' jitter, and the
avoidance planner reads those velocities; the position floor leaves them as smooth as ByteTrack's
(tests/core/test_track_kalman.py). A new track's centre velocity starts with a pixel floor on its
uncertainty too (:data:`MIN_BIRTH_CENTRE_VELOCITY_STD_PX`). The measurements behind both floors
are in docs/experiment-log.md (Tracking).

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

import numpy as np

STD_WEIGHT_POSITION = 1.0 / 20.0
STD_WEIGHT_VELOCITY = 1.0 / 160.0
#: Smallest position standard deviation (px): keeps the filter well conditioned on 2 px boxes.
MIN_STD_PX = 0.5
#: Smallest process-noise standard deviation of the box centre (px per reference frame): how far
#: the camera's own shake and turn can move any target between two frames (module docstring).
#: ByteTrack's 1/20 of the size reaches it at 30 px. Chosen on the real validation clips with the
#: shipped detectors (docs/experiment-log.md).
MIN_CENTRE_PROCESS_STD_PX = 1.5
#: Smallest standard deviation of a new track's centre velocity (px per reference frame). A drone
#: can cross the image at a few pixels per frame whatever its size, but ByteTrack's 10/160 of the
#: size says a new 6 px box is almost surely still (0.4 px per frame; 0.625 with this filter's
#: 0.5 px floor; ByteTrack's value reaches 2 px per frame at 32 px). With the position floor above
#: taking the innovations, such a filter learnt a fast small target's velocity too slowly for PMR
#: to bring the track back after an occlusion (tests/core/test_track_lost.py).
MIN_BIRTH_CENTRE_VELOCITY_STD_PX = 2.0


def _size_std(w: float, h: float, weight: float) -> np.ndarray:
    floor = MIN_STD_PX * (weight / STD_WEIGHT_POSITION)
    sw = max(floor, weight * float(w))
    sh = max(floor, weight * float(h))
    return np.array([sw, sh, sw, sh])


#: Columns w, h, w, h of the state: the per-coordinate sizes the noise scales with.
_WHWH = np.array([2, 3, 2, 3])
#: Per state entry: the size column its noise scales with, the std weight and the std floor.
_NOISE_SIZE = np.array([2, 3, 2, 3, 2, 3, 2, 3])
_NOISE_WEIGHT = np.array([STD_WEIGHT_POSITION] * 4 + [STD_WEIGHT_VELOCITY] * 4)
_NOISE_FLOOR = np.array(
    [MIN_CENTRE_PROCESS_STD_PX] * 2 + [MIN_STD_PX] * 2 + [MIN_STD_PX * (STD_WEIGHT_VELOCITY / STD_WEIGHT_POSITION)] * 4
)


class ConstantVelocityKalman:
    """One track's filter. ``mean`` and ``covariance`` are public and always of the same instant."""

    __slots__ = ("mean", "covariance", "ref_fps")

    def __init__(self, box_cxcywh: np.ndarray, ref_fps: float = 30.0) -> None:
        self.ref_fps = float(ref_fps)
        w, h = float(box_cxcywh[2]), float(box_cxcywh[3])
        self.mean = np.zeros(8)
        self.mean[:4] = box_cxcywh
        std_pos = 2.0 * _size_std(w, h, STD_WEIGHT_POSITION)
        std_vel = 10.0 * _size_std(w, h, STD_WEIGHT_VELOCITY) * self.ref_fps
        std_vel[:2] = np.maximum(std_vel[:2], MIN_BIRTH_CENTRE_VELOCITY_STD_PX * self.ref_fps)
        self.covariance = np.diag(np.concatenate([std_pos, std_vel]) ** 2)

    def transition(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Transition matrix F and process noise Q (diagonal, as a vector) for ``dt`` seconds: the
        model of :meth:`predict` as matrices (what a textbook filter such as filterpy's takes)."""
        f = np.eye(8)
        f[0, 4] = f[1, 5] = f[2, 6] = f[3, 7] = dt
        steps = np.array([max(dt, 0.0) * self.ref_fps])
        return f, _process_noise(self.mean[None, :], steps, _noise_unit(self.ref_fps))[0]

    def predicted(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Mean and covariance ``dt`` seconds ahead (now, for ``dt <= 0``), without changing the filter."""
        means, covs = predicted_many([self], np.array([dt]))
        return means[0], covs[0]

    def predict(self, dt: float) -> None:
        """Advance the filter by ``dt`` seconds."""
        predict_many([self], np.array([dt]))

    def measurement_noise(self) -> np.ndarray:
        """R: ByteTrack's size-proportional measurement noise (4x4)."""
        return np.diag(_measurement_variances(self.mean[None, :])[0])

    def update(self, box_cxcywh: np.ndarray) -> None:
        """Fuse one measured box ``[cx, cy, w, h]``."""
        update_many([self], np.asarray(box_cxcywh, dtype=np.float64).reshape(1, 4))


def _process_noise(means: np.ndarray, steps: np.ndarray, unit: np.ndarray) -> np.ndarray:
    """Diagonal process noise ``(n, 8)`` of filters with states ``means`` over ``steps`` reference
    frames: position stds ``max(floor, w_pos * size)``, velocity stds ``max(floor, w_vel * size)``
    times ``ref_fps`` (``unit``: 1 for positions, which is exact), squared, times the steps."""
    q = (np.maximum(_NOISE_FLOOR, _NOISE_WEIGHT * means[:, _NOISE_SIZE]) * unit) ** 2
    q *= steps[:, None]
    return q


def _propagate(means: np.ndarray, covs: np.ndarray, dt: np.ndarray, ref: float | np.ndarray) -> None:
    """Predict stacked states ``(n, 8)`` and covariances ``(n, 8, 8)`` (fresh arrays, changed in
    place) ``dt`` seconds ahead (``(n,)``, >= 0; ``ref``: one ``ref_fps`` or one per filter).

    ``F P F^T`` is done as two block row/column operations (F = [[I, dt I], [0, I]]), which is
    exactly the matrix product and a few times cheaper for 8x8."""
    n = len(means)
    if np.ndim(ref):
        unit = np.ones((n, 8))
        unit[:, 4:] = np.asarray(ref)[:, None]
    else:
        unit = _noise_unit(float(ref))
    q = _process_noise(means, dt * ref, unit)
    dt_col = dt[:, None]
    means[:, :4] += dt_col * means[:, 4:]
    moved = dt > 0
    if moved.all():
        np.maximum(means[:, 2:4], 1e-3, out=means[:, 2:4])
    else:
        means[moved, 2:4] = np.maximum(means[moved, 2:4], 1e-3)
    dt_3 = dt_col[:, :, None]
    covs[:, :4, :] += dt_3 * covs[:, 4:, :]
    covs[:, :, :4] += dt_3 * covs[:, :, 4:]
    covs.reshape(n, 64)[:, ::9] += q  # the diagonals, as a strided view (no fancy indexing)


def predicted_many(filters: list[ConstantVelocityKalman], dts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Means ``(n, 8)`` and covariances ``(n, 8, 8)`` of many filters, each ``dts[i]`` seconds
    ahead (no step for ``dts[i] <= 0``), in one vectorised step; the filters do not change."""
    if not filters:
        return np.zeros((0, 8)), np.zeros((0, 8, 8))
    means = np.array([f.mean for f in filters])
    covs = np.array([f.covariance for f in filters])
    _propagate(means, covs, np.maximum(np.asarray(dts, dtype=np.float64), 0.0), _common_ref_fps(filters))
    return means, covs


def predict_many(filters: list[ConstantVelocityKalman], dts: np.ndarray) -> None:
    """Advance many filters at once (:func:`predicted_many`, kept)."""
    means, covs = predicted_many(filters, dts)
    for f, m, c in zip(filters, means, covs):
        f.mean = m
        f.covariance = c


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


def _measurement_variances(means: np.ndarray) -> np.ndarray:
    """Diagonal of R ``(n, 4)``: ByteTrack's size-proportional measurement noise of each state."""
    return np.maximum(MIN_STD_PX, STD_WEIGHT_POSITION * means[:, _WHWH]) ** 2


def update_many(filters: list[ConstantVelocityKalman], boxes_cxcywh: np.ndarray) -> None:
    """Fuse one measured box into each filter at once (one batched solve instead of one per
    track); exactly ``update`` applied to each (see tests/core/test_track_kalman.py)."""
    n = len(filters)
    if n == 0:
        return
    means = np.array([f.mean for f in filters])
    covs = np.array([f.covariance for f in filters])
    s = covs[:, :4, :4].copy()
    s.reshape(n, 16)[:, ::5] += _measurement_variances(means)  # the diagonals, as a strided view
    gain = np.linalg.solve(s, covs[:, :4, :]).transpose(0, 2, 1)  # (n, 8, 4): P H^T S^-1 (S symmetric)
    innovation = np.asarray(boxes_cxcywh, dtype=np.float64) - means[:, :4]
    means = means + np.einsum("nij,nj->ni", gain, innovation)
    covs = covs - gain @ s @ gain.transpose(0, 2, 1)
    np.maximum(means[:, 2:4], 1e-3, out=means[:, 2:4])
    for f, m, c in zip(filters, means, covs):
        f.mean = m
        f.covariance = c
