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
by more than the box's own size. Fed the ground truth of the synthetic test scenes
(`gldt bench ablation --scenes 3 --clips 0 --oracle`), JPTrack on every frame scored 58.7 MOTA;
with the floors, 98.6. A floor on the velocity noise instead followed the targets as well but made
every velocity follow the detections' jitter, and the avoidance planner reads those velocities;
the position floor leaves them as smooth as ByteTrack's (tests/test_track_kalman.py). A new
track's centre velocity starts with a pixel floor on its uncertainty too
(:data:`MIN_BIRTH_CENTRE_VELOCITY_STD_PX`). README, "A pixel floor under the filter's position
noise", has the measurements.

Why numpy and not ``filterpy.kalman.KalmanFilter`` (which the issue names): the algebra is
identical (``tests/test_track_kalman.py`` checks our predict/update against filterpy's to 1e-9),
but a tracker runs the filter for every track on every frame, and filterpy can only do that one
track at a time. :func:`predict_many` / :func:`update_many` advance and correct all tracks of a
frame with one batched numpy step each; ``gldt bench tracking`` measures that against a loop of
filterpy filters at 3 and 50 tracks (the "Kalman" line of its output).
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
#: ByteTrack's 1/20 of the size reaches it at 30 px. 1.5 gave more MOTA than 1.0 with the shipped
#: detectors on the real validation clips (README).
MIN_CENTRE_PROCESS_STD_PX = 1.5
#: Smallest standard deviation of a new track's centre velocity (px per reference frame). A drone
#: can cross the image at a few pixels per frame whatever its size, but ByteTrack's 10/160 of the
#: size says a new 6 px box is almost surely still (0.4 px per frame; 0.625 with this filter's
#: 0.5 px floor; ByteTrack's value reaches 2 px per frame at 32 px). With the position floor above taking the innovations, such a filter learnt
#: a fast small target's velocity too slowly for PMR to bring the track back after an occlusion
#: (tests/test_track_lost.py).
MIN_BIRTH_CENTRE_VELOCITY_STD_PX = 2.0

_H = np.hstack([np.eye(4), np.zeros((4, 4))])


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
        """Transition matrix F and process noise Q (diagonal, as a vector) for ``dt`` seconds."""
        f = np.eye(8)
        f[0, 4] = f[1, 5] = f[2, 6] = f[3, 7] = dt
        return f, self._process_noise(dt)

    def _process_noise(self, dt: float) -> np.ndarray:
        w, h = self.mean[2], self.mean[3]
        steps = max(dt, 0.0) * self.ref_fps
        # The expression predict_many uses, on the same floors (_NOISE_FLOOR): one source for both.
        sizes = np.array([w, h, w, h, w, h, w, h])
        return (np.maximum(_NOISE_FLOOR, _NOISE_WEIGHT * sizes) * _noise_unit(self.ref_fps)) ** 2 * steps

    def predicted(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Mean and covariance ``dt`` seconds ahead, without changing the filter.

        ``F P F^T`` is done as two block row/column operations (F = [[I, dt I], [0, I]]), which is
        exactly the matrix product and a few times cheaper for 8x8."""
        mean = self.mean.copy()
        cov = self.covariance.copy()
        if dt <= 0.0:
            return mean, cov
        q = self._process_noise(dt)
        mean[:4] += dt * mean[4:]
        mean[2:4] = np.maximum(mean[2:4], 1e-3)
        cov[:4, :] += dt * cov[4:, :]
        cov[:, :4] += dt * cov[:, 4:]
        cov.reshape(64)[::9] += q  # the diagonal (cov is a fresh contiguous copy)
        return mean, cov

    def predict(self, dt: float) -> None:
        """Advance the filter by ``dt`` seconds."""
        if dt <= 0.0:
            return
        self.mean, self.covariance = self.predicted(dt)

    def measurement_noise(self) -> np.ndarray:
        """R: ByteTrack's size-proportional measurement noise (4x4)."""
        std = _size_std(self.mean[2], self.mean[3], STD_WEIGHT_POSITION)
        return np.diag(std**2)

    def update(self, box_cxcywh: np.ndarray) -> None:
        """Fuse one measured box ``[cx, cy, w, h]``."""
        p = self.covariance
        s = p[:4, :4] + self.measurement_noise()
        gain = np.linalg.solve(s, p[:4, :]).T  # P H^T S^-1 (S symmetric)
        innovation = np.asarray(box_cxcywh, dtype=np.float64) - self.mean[:4]
        self.mean = self.mean + gain @ innovation
        self.covariance = p - gain @ s @ gain.T
        self.mean[2:4] = np.maximum(self.mean[2:4], 1e-3)


def predict_many(filters: list[ConstantVelocityKalman], dts: np.ndarray) -> None:
    """Advance many filters at once (one vectorised step instead of a Python loop of 8x8 ops);
    the result is exactly that of calling ``predict`` on each (see tests/test_track_kalman.py)."""
    n = len(filters)
    if n == 0:
        return
    dt = np.maximum(np.asarray(dts, dtype=np.float64), 0.0)
    ref = _common_ref_fps(filters)
    means = np.array([f.mean for f in filters])
    covs = np.array([f.covariance for f in filters])
    steps = dt * ref
    # Process noise of all 8 state entries in one expression: position stds
    # max(floor, w_pos * size), velocity stds max(floor, w_vel * size) * ref_fps (times 1.0 for
    # positions, which is exact), squared, times the elapsed reference frames.
    if np.ndim(ref):
        unit = np.ones((n, 8))
        unit[:, 4:] = ref[:, None]
    else:
        unit = _noise_unit(ref)
    q = (np.maximum(_NOISE_FLOOR, _NOISE_WEIGHT * means[:, _NOISE_SIZE]) * unit) ** 2
    q *= steps[:, None]
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


def update_many(filters: list[ConstantVelocityKalman], boxes_cxcywh: np.ndarray) -> None:
    """Fuse one measured box into each filter at once (one batched solve instead of one per
    track); exactly ``update`` applied to each (see tests/test_track_kalman.py)."""
    n = len(filters)
    if n == 0:
        return
    means = np.array([f.mean for f in filters])
    covs = np.array([f.covariance for f in filters])
    r = np.maximum(MIN_STD_PX, STD_WEIGHT_POSITION * means[:, _WHWH]) ** 2
    s = covs[:, :4, :4].copy()
    s.reshape(n, 16)[:, ::5] += r  # the diagonals, as a strided view (no fancy indexing)
    gain = np.linalg.solve(s, covs[:, :4, :]).transpose(0, 2, 1)  # (n, 8, 4)
    innovation = np.asarray(boxes_cxcywh, dtype=np.float64) - means[:, :4]
    means = means + np.einsum("nij,nj->ni", gain, innovation)
    covs = covs - gain @ s @ gain.transpose(0, 2, 1)
    np.maximum(means[:, 2:4], 1e-3, out=means[:, 2:4])
    for f, m, c in zip(filters, means, covs):
        f.mean = m
        f.covariance = c
