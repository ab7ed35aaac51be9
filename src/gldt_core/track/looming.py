"""Filtered time to collision from looming: a Kalman filter on the inverse image size of each track.

The looming model
-----------------
An object of fixed size ``S`` at range ``R`` has image size ``s = f S / R`` (``f`` the focal length in
pixels). Closing at constant speed ``v`` (``dR/dt = -v``), its **inverse size** ``q = 1/s = R / (f S)``
is linear in time, ``dq/dt = -v / (f S)``, and the time to collision is exactly::

    TTC = R / v = -q / (dq/dt)

whatever ``f`` and ``S``. Dividing the size by a differentiated size (``s / (ds/dt)``) is the same
quantity, but ``ds/dt`` of a detector's boxes is noise-dominated: a box that jitters by a pixel
flips the sign of a frame-to-frame rate, so the validity of such a TTC flaps and a receding target
gets a short TTC now and then.

The filter
----------
:class:`LoomingFilter` runs a two-state constant-velocity Kalman filter on ``x = [q, dq/dt]``:

* **Process noise**: ``q`` follows ``q + t dq/dt`` exactly for a constant closing speed; changes of
  that speed (and the target turning, which changes its apparent size) enter as a random walk of
  ``dq/dt`` (continuous white-noise acceleration). Its spectral density is scaled by ``q^2`` so that
  the filter behaves the same at every range: ``rate_noise`` (1/s per sqrt(s)) is how fast the
  relative rate ``(dq/dt) / q = -1/TTC`` may wander between manoeuvres.
* **Manoeuvres**: a small ``rate_noise`` gives an accurate TTC for a steady approach but follows a
  target that stops or turns back slowly. The filter keeps a running mean (time constant
  ``maneuver_window_s``) of its normalised innovations, which are white and zero-mean while the
  model holds; when a change of closing speed makes them one-sided, the mean leaves 0 by more than
  ``maneuver_z`` of its own standard deviations and the process noise is raised to
  ``maneuver_rate_noise`` until it comes back.
* **Measurement noise** is heteroscedastic, from a pixel noise model of the size:
  ``sigma_s = max(size_noise_floor_px, size_noise_fraction * s)``, and to first order
  ``sigma_q = sigma_s / s^2``. ``s`` there is the filter's predicted size (the measured one for the
  first measurement), so a noisy small measurement does not weigh itself. The defaults are above the
  noise of the synthetic tests (``max(0.5 px, 3 %)``): a model that underestimates the detector's box
  jitter makes noise look like an approach, and ``valid`` can then turn on for a hovering target.
* **Adaptive noise**: detectors differ in how much their boxes jitter (a global detector working
  on a downscaled frame jitters by 10 % and more). The filter keeps a running mean (time constant
  ``noise_window_s``) of its squared normalised innovations, which is 1 while the noise model holds,
  and scales the measurement variance by it once it exceeds ``noise_scale_from``: noise that the model
  underestimates would otherwise read as a significant approach.
* **Detector changes**: the GL-DT system alternates a global and a local detector, whose boxes of
  one object differ in scale. A measurement from another source than the last one (``source``)
  first inflates the variance of ``q`` by ``(source_scale_std * q)^2``: the step is absorbed by the
  level, and the rate keeps what the frames before had shown.
* **Outliers** (a box that jumps for one frame) are down-weighted Huber-style: an innovation beyond
  ``outlier_gate`` standard deviations has its measurement variance inflated so that it counts as
  exactly ``outlier_gate`` sigma.

The estimate
------------
:class:`LoomingEstimate` carries ``ttc = -q / (dq/dt)`` (``inf`` when not closing), ``ttc_sigma``
(delta method, ``J = [-1/qdot, q/qdot^2]``, ``sigma^2 = J P J^T``) and ``valid``. The TTC is only
as good as the rate: ``ttc_sigma / ttc`` is about ``sigma_qdot / |qdot|``. A planner that wants a
conservative number uses ``ttc - k * ttc_sigma`` (or :attr:`LoomingEstimate.ttc_lower`, ``k = 2``);
``ttc_sigma`` errs on the large side when the box noise is below the noise model.

``valid`` has **hysteresis** so that it does not flap:

* it turns on only on a frame with a measurement, after at least ``min_measurements`` of them over
  at least ``min_track_s`` seconds, when the approach is significant even at its slow end: the
  rate ``z_on`` standard deviations slower than the estimate still closes, and within
  ``max_ttc_on_s`` (``qdot + z_on * sigma_qdot < -q / max_ttc_on_s``; this implies
  ``qdot + z_on * sigma_qdot < 0`` and a finite, positive TTC);
* it stays on while ``qdot + z_off * sigma_qdot < 0`` (``z_off < z_on``) and
  ``ttc <= max_ttc_off_s``, on measured and coasting frames alike (coasting grows ``sigma_qdot``
  until the approach is no longer significant);
* it is never on for a target that is not closing (``qdot >= 0``: receding or constant size).

The ``max_ttc`` bounds are there because a hovering target's noise-driven rate excursions give long
TTCs: a TTC far beyond what a planner acts on says little, and looming cannot tell a slow approach
from no approach at all within a few seconds.

:class:`LoomingTracks` keeps one filter per track id and forgets the ids that disappear.
``tests/core/test_track_looming.py`` measures the TTC error against the true TTC and against what
an ideal straight-line fit of the same noisy sizes could reach, the flips of ``valid``, and the
behaviour on receding and constant-size targets, at 15, 30 and 60 Hz.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass


@dataclass(frozen=True)
class LoomingConfig:
    """Parameters of :class:`LoomingFilter` (see the module docstring for the model)."""

    size_noise_floor_px: float = 0.75
    """Smallest standard deviation of a measured size (px): the pixel quantisation and jitter of a box."""

    size_noise_fraction: float = 0.05
    """Standard deviation of a measured size as a fraction of the size (box fit, target aspect)."""

    rate_noise: float = 0.01
    """Random walk of ``(dq/dt) / q`` in 1/s per sqrt(s) on a steady approach."""

    maneuver_rate_noise: float = 0.1
    """The same random walk while a manoeuvre is detected."""

    maneuver_window_s: float = 0.5
    """Time constant (s) of the running mean of normalised innovations that detects a manoeuvre."""

    maneuver_z: float = 4.0
    """A manoeuvre is detected when that running mean is this many of its standard deviations off 0."""

    initial_rate_std: float = 0.5
    """Prior standard deviation of ``(dq/dt) / q`` (1/s) at a track's first measurement (prior mean 0)."""

    z_on: float = 2.0
    """Standard deviations of ``dq/dt`` by which the approach must be significant for ``valid`` to turn on."""

    z_off: float = 1.0
    """Standard deviations by which ``dq/dt`` must stay below 0 for ``valid`` to stay on (``< z_on``)."""

    min_measurements: int = 8
    """Measurements a filter needs before ``valid`` may turn on."""

    min_track_s: float = 0.5
    """Seconds since a filter's first measurement before ``valid`` may turn on."""

    max_ttc_on_s: float = 20.0
    """Longest TTC (s), at the slow end of the rate (``z_on`` sigma), at which ``valid`` may turn on."""

    max_ttc_off_s: float = 30.0
    """Longest TTC (s) at which ``valid`` stays on (``>= max_ttc_on_s``)."""

    outlier_gate: float = 4.0
    """Innovations beyond this many standard deviations are down-weighted (``inf`` disables)."""

    noise_window_s: float = 1.0
    """Time constant (s) of the running mean of squared normalised innovations that scales the
    measurement noise up when a detector's boxes jitter more than the noise model says."""

    noise_scale_from: float = 1.5
    """That running mean scales the measurement noise only once it exceeds this (chance alone
    keeps it within about 1 +- 0.3 over a one-second window)."""

    source_scale_std: float = 0.3
    """Standard deviation of the scale between two detectors' boxes of one object (as a fraction):
    when a track's sizes start coming from another detector (GD and LD boxes of one drone differ
    by 20 % and more), the inverse size's variance grows by this much, so the jump re-levels
    ``q`` instead of reading as an approach or a retreat."""

    def __post_init__(self) -> None:
        positive = (
            "size_noise_floor_px",
            "rate_noise",
            "maneuver_rate_noise",
            "maneuver_window_s",
            "maneuver_z",
            "initial_rate_std",
            "max_ttc_on_s",
            "outlier_gate",
            "source_scale_std",
            "noise_window_s",
            "noise_scale_from",
        )
        for name in positive:
            value = getattr(self, name)
            if not value > 0:
                raise ValueError(f"LoomingConfig.{name} must be positive, got {value}")
        if not self.size_noise_fraction >= 0:
            raise ValueError(f"LoomingConfig.size_noise_fraction must be >= 0, got {self.size_noise_fraction}")
        if not 0 <= self.z_off < self.z_on:
            raise ValueError(f"LoomingConfig needs 0 <= z_off < z_on, got z_off={self.z_off}, z_on={self.z_on}")
        if not self.max_ttc_off_s >= self.max_ttc_on_s:
            raise ValueError(
                f"LoomingConfig needs max_ttc_off_s >= max_ttc_on_s, got {self.max_ttc_off_s} < {self.max_ttc_on_s}"
            )
        if not self.min_track_s >= 0:
            raise ValueError(f"LoomingConfig.min_track_s must be >= 0, got {self.min_track_s}")
        if self.min_measurements < 1:
            raise ValueError(f"LoomingConfig.min_measurements must be >= 1, got {self.min_measurements}")


@dataclass(frozen=True)
class LoomingEstimate:
    """Time to collision of one track at one frame.

    ``ttc`` in seconds (``inf`` when the target is not closing, ``0`` when the filter's inverse size
    has reached 0), ``ttc_sigma`` its standard deviation (delta method; ``inf`` when not closing),
    ``valid`` the hysteresis flag of the module docstring. ``inverse_size`` (1/px),
    ``inverse_size_rate`` (1/(px s)) and ``inverse_size_rate_sigma`` are the filter's state;
    ``measurements`` how many sizes it has taken; ``maneuvering`` whether the manoeuvre detector
    has raised the process noise.
    """

    ttc: float
    ttc_sigma: float
    valid: bool
    inverse_size: float
    inverse_size_rate: float
    inverse_size_rate_sigma: float
    measurements: int
    maneuvering: bool = False

    @property
    def ttc_lower(self) -> float:
        """A conservative TTC: ``ttc - 2 ttc_sigma``, not below 0 (``inf`` when not closing)."""
        if math.isinf(self.ttc):
            return math.inf
        return max(0.0, self.ttc - 2.0 * self.ttc_sigma)

    @property
    def approach_z(self) -> float:
        """How many standard deviations ``dq/dt`` is below zero (positive: closing)."""
        if self.inverse_size_rate_sigma > 0:
            return -self.inverse_size_rate / self.inverse_size_rate_sigma
        return math.inf if self.inverse_size_rate < 0 else 0.0


NO_ESTIMATE = LoomingEstimate(
    ttc=math.inf,
    ttc_sigma=math.inf,
    valid=False,
    inverse_size=math.nan,
    inverse_size_rate=math.nan,
    inverse_size_rate_sigma=math.inf,
    measurements=0,
)
"""The estimate of a track that has had no size measurement yet."""


class LoomingFilter:
    """Kalman filter on ``[q, dq/dt]`` (``q = 1 / size``) of one track; see the module docstring.

    Call :meth:`update` on a frame with a measured size and :meth:`coast` on a frame without; both
    return the :class:`LoomingEstimate` at that time. Times are in seconds and must not go back
    (an earlier time is treated as the last one).
    """

    def __init__(self, config: LoomingConfig | None = None) -> None:
        self.config = config or LoomingConfig()
        self.reset()

    def reset(self) -> None:
        """Forget everything: the next measurement starts a new filter."""
        self._t: float | None = None
        self._t0 = math.nan
        self._q = math.nan
        self._qd = math.nan
        self._p00 = self._p01 = self._p11 = math.nan
        self._count = 0
        self._source: object = None
        self._noise_scale = 1.0
        self._nis = 1.0
        self._valid = False
        self._nu = 0.0
        self._maneuver = False

    @property
    def initialised(self) -> bool:
        """Whether the filter has had a measurement since it was made or reset."""
        return self._t is not None

    @property
    def estimate(self) -> LoomingEstimate:
        """The estimate at the last time the filter was advanced to."""
        if self._t is None:
            return NO_ESTIMATE
        return self._estimate()

    # ---------------------------------------------------------------- steps
    def _size_sigma_q(self, size: float) -> float:
        config = self.config
        sigma_s = max(config.size_noise_floor_px, config.size_noise_fraction * size)
        return sigma_s / (size * size)

    def _predict(self, t: float) -> None:
        assert self._t is not None
        dt = t - self._t
        if not dt > 0:
            return
        self._t = t
        q, qd = self._q, self._qd
        p00, p01, p11 = self._p00, self._p01, self._p11
        # F = [[1, dt], [0, 1]]; P <- F P F^T + Q, Q = qc [[dt^3/3, dt^2/2], [dt^2/2, dt]].
        rate_noise = self.config.maneuver_rate_noise if self._maneuver else self.config.rate_noise
        qc = (rate_noise * q) ** 2
        self._q = q + dt * qd
        self._p00 = p00 + 2 * dt * p01 + dt * dt * p11 + qc * dt**3 / 3
        self._p01 = p01 + dt * p11 + qc * dt * dt / 2
        self._p11 = p11 + qc * dt

    def update(self, t: float, size_px: float, source: object = None) -> LoomingEstimate:
        """Advance to ``t`` and take the measured image size ``size_px`` (any linear size, e.g. ``sqrt(w h)``)
        from the detector ``source`` (any label; ``None``: unknown, the same as the last).

        A size that is not a positive finite number is no measurement: the frame coasts.
        """
        t = float(t)
        size = float(size_px)
        if not (math.isfinite(size) and size > 0):
            return self.coast(t)
        z = 1.0 / size
        if self._t is None:
            sigma_q = self._size_sigma_q(size)
            self._source = source
            self._t = self._t0 = t
            self._q, self._qd = z, 0.0
            self._p00 = sigma_q * sigma_q
            self._p01 = 0.0
            self._p11 = (self.config.initial_rate_std * z) ** 2
            self._count = 1
            return self._settle(measured=True)
        dt = t - self._t
        self._predict(max(t, self._t))
        if source is not None and self._source is not None and source != self._source:
            self._p00 += (self.config.source_scale_std * self._q) ** 2
        if source is not None:
            self._source = source
        predicted_size = 1.0 / self._q if self._q > 0 else size
        sigma_q = self._size_sigma_q(predicted_size)
        innovation = z - self._q
        base_s = self._p00 + sigma_q * sigma_q
        self._detect_maneuver(dt, innovation / math.sqrt(base_s))
        self._adapt_noise(dt, innovation / math.sqrt(base_s))
        s = self._p00 + self._noise_scale * sigma_q * sigma_q  # innovation variance
        gate = self.config.outlier_gate
        if innovation * innovation > gate * gate * s:  # Huber: count as exactly `gate` sigma
            s = innovation * innovation / (gate * gate)
        k0, k1 = self._p00 / s, self._p01 / s
        self._q += k0 * innovation
        self._qd += k1 * innovation
        p00, p01, p11 = self._p00, self._p01, self._p11
        self._p00 = (1 - k0) * p00
        self._p01 = (1 - k0) * p01
        self._p11 = p11 - k1 * p01
        self._count += 1
        return self._settle(measured=True)

    def _adapt_noise(self, dt: float, normalised_innovation: float) -> None:
        """Update the running variance of normalised innovations and the noise scale (>= 1).

        The spread around the running mean of the manoeuvre detector, not the raw second moment:
        a bias (the rate still converging, a manoeuvre) is the model's business, not noise."""
        if not dt > 0:
            return
        alpha = -math.expm1(-dt / self.config.noise_window_s)
        # Clipped, so that one outlier (the Huber gate's business) cannot inflate the noise for long.
        gate = self.config.outlier_gate
        sample = min((normalised_innovation - self._nu) ** 2, gate * gate)
        self._nis = (1 - alpha) * self._nis + alpha * sample
        # A mean of chi-square(1) samples over a window scatters by +-0.3: only a mean clearly above 1
        # says the model underestimates the noise.
        self._noise_scale = self._nis if self._nis > self.config.noise_scale_from else 1.0

    def _detect_maneuver(self, dt: float, normalised_innovation: float) -> None:
        """Update the running mean of normalised innovations and the manoeuvre flag."""
        if not dt > 0:
            return
        alpha = -math.expm1(-dt / self.config.maneuver_window_s)
        self._nu = (1 - alpha) * self._nu + alpha * normalised_innovation
        # Standard deviation of that mean for white unit-variance innovations at this frame interval.
        self._maneuver = abs(self._nu) > self.config.maneuver_z * math.sqrt(alpha / (2 - alpha))

    def coast(self, t: float) -> LoomingEstimate:
        """Advance to ``t`` without a measurement (prediction only: the uncertainty grows)."""
        if self._t is None:
            return NO_ESTIMATE
        self._predict(max(float(t), self._t))
        return self._settle(measured=False)

    # ---------------------------------------------------------------- estimate
    def _ttc(self) -> float:
        q, qd = self._q, self._qd
        if not qd < 0:
            return math.inf
        return -q / qd if q > 0 else 0.0

    def _settle(self, measured: bool) -> LoomingEstimate:
        config = self.config
        q, qd = self._q, self._qd
        sigma_qd = math.sqrt(max(self._p11, 0.0))
        closing = qd < 0 and q > 0
        assert self._t is not None
        if self._valid:
            self._valid = closing and qd + config.z_off * sigma_qd < 0 and self._ttc() <= config.max_ttc_off_s
        else:
            self._valid = (
                measured
                and closing
                and self._count >= config.min_measurements
                and self._t - self._t0 >= config.min_track_s
                and qd + config.z_on * sigma_qd < -q / config.max_ttc_on_s
            )
        return self._estimate()

    def _estimate(self) -> LoomingEstimate:
        q, qd = self._q, self._qd
        ttc = self._ttc()
        if qd < 0:
            j0, j1 = -1.0 / qd, q / (qd * qd)
            variance = j0 * j0 * self._p00 + 2 * j0 * j1 * self._p01 + j1 * j1 * self._p11
            ttc_sigma = math.sqrt(max(variance, 0.0))
        else:
            ttc_sigma = math.inf
        return LoomingEstimate(
            ttc=ttc,
            ttc_sigma=ttc_sigma,
            valid=self._valid,
            inverse_size=q,
            inverse_size_rate=qd,
            inverse_size_rate_sigma=math.sqrt(max(self._p11, 0.0)),
            measurements=self._count,
            maneuvering=self._maneuver,
        )


class LoomingTracks:
    """One :class:`LoomingFilter` per track id.

    :meth:`update` takes a frame's time, ``(track_id, size_px or None)`` pairs (``None``: the
    track is coasting, no measurement this frame) and the frame's detector ``source``; it returns
    each id's :class:`LoomingEstimate`. A track id absent from a call is forgotten (a later one
    with the same id starts afresh).
    """

    def __init__(self, config: LoomingConfig | None = None) -> None:
        self.config = config or LoomingConfig()
        self._filters: dict[int, LoomingFilter] = {}

    def __len__(self) -> int:
        return len(self._filters)

    def reset(self) -> None:
        """Forget every track."""
        self._filters.clear()

    def update(
        self, t: float, observations: Iterable[tuple[int, float | None]], source: object = None
    ) -> dict[int, LoomingEstimate]:
        """Advance every listed track to ``t``; measured sizes (from detector ``source``) update,
        ``None`` coasts."""
        filters: dict[int, LoomingFilter] = {}
        estimates: dict[int, LoomingEstimate] = {}
        for track_id, size in observations:
            looming = self._filters.get(track_id) or filters.get(track_id) or LoomingFilter(self.config)
            filters[track_id] = looming
            estimates[track_id] = looming.coast(t) if size is None else looming.update(t, size, source)
        self._filters = filters
        return estimates
