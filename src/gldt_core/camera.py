"""Camera geometry for planners: pixel -> line of sight, bearing, bearing rate and their covariance.

An avoidance planner wants angles, not pixels. :class:`CameraModel` holds what
``sensor_msgs/CameraInfo`` says about the lens: the pinhole parameters of ``K`` and the distortion
model ``D``. :func:`line_of_sight` undoes the distortion and gives the unit vector from the camera
towards a pixel; :func:`bearing` turns it into azimuth and elevation.

Frames and signs (REP-103, REP-105)
-----------------------------------
* The line of sight is expressed in the camera's **optical frame** (REP-103 suffix ``_optical``):
  ``x`` right, ``y`` down, ``z`` forward along the optical axis. A pixel ``(u, v)`` (``u`` to the
  right, ``v`` down from the top-left corner) in front of the camera has ``z > 0``.
* Angles follow REP-103's right-hand rule in the camera **body frame** (``x`` forward, ``y`` left,
  ``z`` up): counter-clockwise is positive. With the line of sight ``(x, y, z)`` in the optical frame::

      azimuth   = atan2(-x, z)               # positive to the LEFT of the optical axis
      elevation = atan2(-y, hypot(x, z))     # positive UP

  Azimuth is the rotation about the body ``z`` (up) axis from the optical axis to the line of sight,
  elevation the angle above the plane through the optical axis and the camera's ``x`` (right) axis. A
  target up and to the left of the image centre has positive azimuth and positive elevation. Rates
  (:func:`bearing_rate`) carry the same signs.

Distortion models (``CameraInfo.distortion_model`` and ``CameraInfo.d``, as ROS's
``image_geometry`` and OpenCV define them):

* ``plumb_bob``: ``[k1, k2, t1, t2, k3]`` (Brown-Conrady, OpenCV's 5 coefficients); an empty ``D``
  or an empty model name means no distortion.
* ``rational_polynomial``: ``[k1, k2, t1, t2, k3, k4, k5, k6]`` (OpenCV's 8 coefficients).
* ``equidistant``: ``[k1, k2, k3, k4]`` (OpenCV's fisheye model, ``cv2.fisheye``); rays more than
  90 degrees off the optical axis are handled (the ray is built from the angle, not from ``tan``).

The inverse of each distortion is computed with Newton's method on the model's own equations
(analytic Jacobian, iterated to machine precision), in numpy, for one pixel or many;
``tests/core/test_camera_bearing.py`` checks every model against OpenCV's ``cv2.projectPoints`` /
``cv2.fisheye.projectPoints``. A pixel where the model cannot be inverted (far outside the calibrated
image, where the polynomial folds back) gets a NaN line of sight and NaN angles. The skew term
``K[0][1]`` is ignored, as ``image_geometry`` and ``cv2.undistortPoints`` ignore it.

Uncertainty: :func:`bearing_covariance` (and :func:`line_of_sight_covariance`) propagate a pixel
covariance through the Jacobian of the pixel -> bearing map, taken by central differences of the
full model (distortion included): ``C_bearing = J C_pixel J^T`` (first order).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

NO_DISTORTION = ""
"""``CameraInfo.distortion_model`` of an uncalibrated or distortion-free camera; read as ``plumb_bob``."""

DISTORTION_COEFFICIENTS = {"plumb_bob": 5, "rational_polynomial": 8, "equidistant": 4}
"""Number of ``D`` coefficients of each supported distortion model."""

NEWTON_ITERATIONS = 50
"""Most Newton steps when undoing distortion (converges in a handful where the model is invertible)."""

NEWTON_TOLERANCE = 1e-12
"""Residual (normalised image coordinates, or radians for ``equidistant``) below which Newton stops."""

INVERSION_TOLERANCE = 1e-9
"""Residual above which a pixel counts as outside the invertible region (its line of sight is NaN)."""

JACOBIAN_STEP_PX = 1e-2
"""Pixel step of the central differences behind :func:`bearing_jacobian` and the covariances."""


class CameraModelError(ValueError):
    """A camera model cannot be built from the given input; the message names the bad field."""


def _checked_distortion(model: object, d: object, model_name: str, d_name: str) -> tuple[str, tuple[float, ...]]:
    """The distortion model (``''`` read as ``plumb_bob``) and its coefficients, or :class:`CameraModelError`."""
    if not isinstance(model, str):
        raise CameraModelError(f"{model_name} must be a string, got {model!r}")
    if model not in DISTORTION_COEFFICIENTS and model != NO_DISTORTION:
        raise CameraModelError(
            f"{model_name} {model!r} is not supported (use one of {', '.join(DISTORTION_COEFFICIENTS)}, or '' for none)"
        )
    try:
        coefficients = tuple(float(c) for c in np.asarray(d, dtype=np.float64).reshape(-1))
    except (TypeError, ValueError):
        raise CameraModelError(f"{d_name} must be numbers, got {d!r}") from None
    model = model or "plumb_bob"
    expected = DISTORTION_COEFFICIENTS[model]
    if len(coefficients) != expected and not (model == "plumb_bob" and not coefficients):
        allowed = f"{expected} (or 0)" if model == "plumb_bob" else str(expected)
        raise CameraModelError(
            f"{d_name} must have {allowed} values for distortion model {model!r}, got {len(coefficients)}"
        )
    if not all(math.isfinite(c) for c in coefficients):
        raise CameraModelError(f"{d_name} holds NaN or infinite values")
    return model, coefficients


@dataclass(frozen=True)
class CameraModel:
    """Pinhole parameters and lens distortion of one camera (``sensor_msgs/CameraInfo``).

    ``fx, fy`` (focal lengths) and ``cx, cy`` (principal point) are in pixels; ``distortion_model``
    is one of :data:`DISTORTION_COEFFICIENTS` and ``d`` its coefficients in ROS/OpenCV order (empty:
    no distortion, ``plumb_bob`` only). Construction validates every field and raises
    :class:`CameraModelError` naming the first bad one.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    distortion_model: str = "plumb_bob"
    d: tuple[float, ...] = field(default=())

    def __post_init__(self) -> None:
        for name in ("fx", "fy", "cx", "cy"):
            value = getattr(self, name)
            try:
                number = float(value)
            except (TypeError, ValueError):
                raise CameraModelError(f"{name} must be a number, got {value!r}") from None
            if not math.isfinite(number):
                raise CameraModelError(f"{name} must be finite, got {value!r}")
            object.__setattr__(self, name, number)
        if self.fx <= 0 or self.fy <= 0:
            raise CameraModelError(f"focal length must be positive, got fx={self.fx}, fy={self.fy}")
        model, coefficients = _checked_distortion(self.distortion_model, self.d, "distortion model", "d")
        object.__setattr__(self, "distortion_model", model)
        object.__setattr__(self, "d", coefficients)

    # ---------------------------------------------------------------- constructors
    @classmethod
    def from_camera_info(cls, k: ArrayLike, d: ArrayLike = (), distortion_model: str = NO_DISTORTION) -> CameraModel:
        """Build from the raw ``CameraInfo`` fields ``k`` (9 values, row-major), ``d`` and ``distortion_model``.

        Raises :class:`CameraModelError` with one line naming the bad field (``camera_info.k``,
        ``camera_info.d`` or ``camera_info.distortion_model``).
        """
        try:
            values = np.asarray(k, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise CameraModelError(f"camera_info.k must be 9 numbers, got {k!r}") from None
        if values.size != 9:
            raise CameraModelError(f"camera_info.k must have 9 values, got {values.size}")
        if not np.all(np.isfinite(values)):
            raise CameraModelError("camera_info.k holds NaN or infinite values")
        if not np.any(values):
            raise CameraModelError("camera_info.k is all zeros (an uncalibrated camera): focal length unknown")
        fx, fy, cx, cy = (float(values[i]) for i in (0, 4, 2, 5))
        if fx <= 0 or fy <= 0:
            raise CameraModelError(f"camera_info.k has non-positive focal length (fx={fx}, fy={fy})")
        model, coefficients = _checked_distortion(distortion_model, d, "camera_info.distortion_model", "camera_info.d")
        return cls(fx, fy, cx, cy, model, coefficients)

    @classmethod
    def from_fov(cls, width: int, height: int, horizontal_fov_rad: float) -> CameraModel:
        """Distortion-free, square-pixel model with the optical centre in the image centre."""
        if not (width > 0 and height > 0):
            raise CameraModelError(f"image size must be positive, got width={width}, height={height}")
        if not 0 < horizontal_fov_rad < math.pi:
            raise CameraModelError(f"horizontal_fov_rad must be in (0, pi), got {horizontal_fov_rad}")
        fx = (width / 2.0) / math.tan(horizontal_fov_rad / 2.0)
        return cls(fx, fx, width / 2.0, height / 2.0)

    # ---------------------------------------------------------------- views
    @property
    def k(self) -> np.ndarray:
        """The 3x3 camera matrix (no skew)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def has_distortion(self) -> bool:
        """Whether any distortion coefficient is non-zero."""
        return any(c != 0.0 for c in self.d)


# -------------------------------------------------------------------- distortion models
def _radial_tangential(
    coefficients: Sequence[float], x: np.ndarray, y: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``plumb_bob`` / ``rational_polynomial`` forward map of normalised coordinates and its Jacobian.

    Returns ``xd, yd, dxd/dx, dxd/dy, dyd/dx, dyd/dy``.
    """
    k1, k2, p1, p2, k3, k4, k5, k6 = (list(coefficients) + [0.0] * 8)[:8]
    r2 = x * x + y * y
    numerator = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    denominator = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
    d_numerator = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
    d_denominator = k4 + r2 * (2.0 * k5 + 3.0 * k6 * r2)
    g = numerator / denominator
    dg = (d_numerator * denominator - numerator * d_denominator) / (denominator * denominator)  # dg/d(r2)
    xd = x * g + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * g + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    cross = 2.0 * x * y * dg + 2.0 * p1 * x + 2.0 * p2 * y
    return (
        xd,
        yd,
        g + 2.0 * x * x * dg + 2.0 * p1 * y + 6.0 * p2 * x,
        cross,
        cross,
        g + 2.0 * y * y * dg + 6.0 * p1 * y + 2.0 * p2 * x,
    )


def _equidistant_theta_d(coefficients: Sequence[float], theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``equidistant`` distorted angle ``theta_d(theta)`` and its derivative."""
    k1, k2, k3, k4 = coefficients
    t2 = theta * theta
    theta_d = theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
    derivative = 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))
    return theta_d, derivative


MONOTONIC_SEARCH_RADIUS = 20.0
"""Largest undistorted normalised radius (about 87 degrees off axis) searched for a fold of the radial map."""


@functools.lru_cache(maxsize=64)
def _monotonic_radius(coefficients: tuple[float, ...]) -> float:
    """Undistorted normalised radius where the radial map ``r -> r g(r^2)`` first stops increasing.

    Beyond it the distortion polynomial folds back: a pixel there would belong to two rays, and the
    calibration (fitted inside the image) says nothing about it.
    """
    k1, k2, _, _, k3, k4, k5, k6 = (list(coefficients) + [0.0] * 8)[:8]
    radial_only = (k1, k2, 0.0, 0.0, k3, k4, k5, k6)
    r = np.linspace(0.0, MONOTONIC_SEARCH_RADIUS, 200_001)
    _, _, slope, _, _, _ = _radial_tangential(radial_only, r, np.zeros_like(r))
    folds = np.flatnonzero(~(slope > 0))
    return float(r[folds[0]]) if folds.size else math.inf


@functools.lru_cache(maxsize=64)
def _monotonic_angle(coefficients: tuple[float, ...]) -> float:
    """Angle off axis where the ``equidistant`` map ``theta -> theta_d`` first stops increasing (at most pi)."""
    theta = np.linspace(0.0, math.pi, 100_001)
    _, slope = _equidistant_theta_d(coefficients, theta)
    folds = np.flatnonzero(~(slope > 0))
    return float(theta[folds[0]]) if folds.size else math.pi


def _undistort_radial_tangential(
    coefficients: Sequence[float], xd: np.ndarray, yd: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted normalised ``(x, y)`` for distorted ``(xd, yd)`` (NaN where Newton fails)."""
    x, y = xd, yd
    for _ in range(NEWTON_ITERATIONS):
        fx_, fy_, a, b, c, d = _radial_tangential(coefficients, x, y)
        rx, ry = fx_ - xd, fy_ - yd
        active = ~(np.abs(rx) + np.abs(ry) < NEWTON_TOLERANCE)  # a converged pixel stays as it is
        if not np.any(active):
            break
        det = a * d - b * c
        with np.errstate(divide="ignore", invalid="ignore"):
            x = np.where(active, x - (d * rx - b * ry) / det, x)
            y = np.where(active, y - (a * ry - c * rx) / det, y)
    fx_, fy_, *_ = _radial_tangential(coefficients, x, y)
    converged = np.abs(fx_ - xd) + np.abs(fy_ - yd) < INVERSION_TOLERANCE
    bad = ~(converged & (np.hypot(x, y) < _monotonic_radius(tuple(coefficients))))
    return np.where(bad, np.nan, x), np.where(bad, np.nan, y)


def _los_equidistant(coefficients: Sequence[float], xd: np.ndarray, yd: np.ndarray) -> np.ndarray:
    """Unit lines of sight for distorted normalised ``(xd, yd)`` under the fisheye model."""
    theta_d = np.hypot(xd, yd)
    theta = theta_d.copy()
    for _ in range(NEWTON_ITERATIONS):
        value, derivative = _equidistant_theta_d(coefficients, theta)
        residual = value - theta_d
        active = ~(np.abs(residual) < NEWTON_TOLERANCE)
        if not np.any(active):
            break
        with np.errstate(divide="ignore", invalid="ignore"):
            theta = np.where(active, theta - residual / derivative, theta)
    value, _ = _equidistant_theta_d(coefficients, theta)
    converged = np.abs(value - theta_d) < INVERSION_TOLERANCE
    bad = ~(converged & (theta >= 0) & (theta < _monotonic_angle(tuple(coefficients))))
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(theta_d > 0, np.sin(theta) / theta_d, 1.0)
    los = np.stack([xd * scale, yd * scale, np.cos(theta)], axis=-1)
    return np.where(bad[..., np.newaxis], np.nan, los)


# -------------------------------------------------------------------- public geometry
def line_of_sight(model: CameraModel, u: ArrayLike, v: ArrayLike) -> np.ndarray:
    """Unit line of sight towards pixel ``(u, v)`` in the camera optical frame, distortion undone.

    Optical frame (REP-103): ``x`` right, ``y`` down, ``z`` forward. ``u`` and ``v`` may be scalars
    (result shape ``(3,)``) or arrays that broadcast together (result shape ``(*shape, 3)``). NaN
    where the distortion model cannot be inverted.
    """
    uu, vv = np.broadcast_arrays(np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64))
    xd = (uu.reshape(-1) - model.cx) / model.fx
    yd = (vv.reshape(-1) - model.cy) / model.fy
    if model.distortion_model == "equidistant":
        los = _los_equidistant(model.d, xd, yd)
    else:
        x, y = _undistort_radial_tangential(model.d, xd, yd) if model.has_distortion else (xd, yd)
        rays = np.stack([x, y, np.ones_like(x)], axis=-1)
        los = rays / np.linalg.norm(rays, axis=-1, keepdims=True)
    return los.reshape(*uu.shape, 3)


def project(model: CameraModel, los: ArrayLike) -> np.ndarray:
    """Pixel ``(u, v)`` of a direction in the optical frame (inverse of :func:`line_of_sight`).

    ``los`` has shape ``(3,)`` or ``(..., 3)`` and need not be unit; the result has shape ``(2,)`` or
    ``(..., 2)``. Directions behind the camera (``z <= 0``) give NaN, except under ``equidistant``,
    which projects rays up to 180 degrees off axis.
    """
    rays = np.asarray(los, dtype=np.float64)
    x, y, z = rays[..., 0], rays[..., 1], rays[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        if model.distortion_model == "equidistant":
            rho = np.hypot(x, y)
            theta = np.arctan2(rho, z)
            theta_d, _ = _equidistant_theta_d(model.d, theta)
            scale = np.where(rho > 0, theta_d / rho, 0.0)
            xd, yd = x * scale, y * scale
        else:
            behind = z <= 0
            xn, yn = x / z, y / z
            xd, yd, *_ = _radial_tangential(model.d, xn, yn)
            xd = np.where(behind, np.nan, xd)
            yd = np.where(behind, np.nan, yd)
    return np.stack([model.fx * xd + model.cx, model.fy * yd + model.cy], axis=-1)


def angles_of(los: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth (left +) and elevation (up +) of optical-frame directions, REP-103 signs (module docstring)."""
    rays = np.asarray(los, dtype=np.float64)
    x, y, z = rays[..., 0], rays[..., 1], rays[..., 2]
    return np.arctan2(-x, z), np.arctan2(-y, np.hypot(x, z))


def bearings(model: CameraModel, u: ArrayLike, v: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised :func:`bearing`: azimuth and elevation arrays (radians) for arrays of pixels."""
    return angles_of(line_of_sight(model, u, v))


def bearing(model: CameraModel, u: float, v: float) -> tuple[float, float]:
    """Azimuth (positive LEFT) and elevation (positive UP) of pixel ``(u, v)`` in radians.

    ``azimuth = atan2(-x, z)``, ``elevation = atan2(-y, hypot(x, z))`` with ``(x, y, z)`` the
    :func:`line_of_sight` in the optical frame (REP-103 counter-clockwise angles).
    """
    azimuth, elevation = bearings(model, u, v)
    return float(azimuth), float(elevation)


def bearing_jacobian(model: CameraModel, u: float, v: float, step_px: float = JACOBIAN_STEP_PX) -> np.ndarray:
    """2x2 Jacobian ``d(azimuth, elevation) / d(u, v)`` (rad/px) at pixel ``(u, v)``, distortion included.

    Central differences with a step of ``step_px`` pixels (rows: azimuth, elevation; columns: u, v).
    """
    h = float(step_px)
    azimuth, elevation = bearings(model, [u + h, u - h, u, u], [v, v, v + h, v - h])
    return np.array(
        [
            [(azimuth[0] - azimuth[1]) / (2 * h), (azimuth[2] - azimuth[3]) / (2 * h)],
            [(elevation[0] - elevation[1]) / (2 * h), (elevation[2] - elevation[3]) / (2 * h)],
        ]
    )


def bearing_rate(model: CameraModel, u: float, v: float, du_dt: float, dv_dt: float) -> tuple[float, float]:
    """Azimuth and elevation rates (rad/s, signs of :func:`bearing`) of a pixel moving at ``(du/dt, dv/dt)`` px/s."""
    rate = bearing_jacobian(model, u, v) @ np.array([du_dt, dv_dt], dtype=np.float64)
    return float(rate[0]), float(rate[1])


def _checked_covariance(pixel_covariance: ArrayLike) -> np.ndarray:
    covariance = np.asarray(pixel_covariance, dtype=np.float64)
    if covariance.shape != (2, 2):
        raise ValueError(f"pixel covariance must be 2x2, got shape {covariance.shape}")
    if not np.all(np.isfinite(covariance)):
        raise ValueError("pixel covariance holds NaN or infinite values")
    return covariance


def bearing_covariance(model: CameraModel, u: float, v: float, pixel_covariance: ArrayLike) -> np.ndarray:
    """2x2 covariance of ``(azimuth, elevation)`` (rad^2) for a pixel with covariance ``pixel_covariance`` (px^2).

    First-order propagation ``J C J^T`` through :func:`bearing_jacobian`.
    """
    jacobian = bearing_jacobian(model, u, v)
    result: np.ndarray = jacobian @ _checked_covariance(pixel_covariance) @ jacobian.T
    return result


def line_of_sight_covariance(model: CameraModel, u: float, v: float, pixel_covariance: ArrayLike) -> np.ndarray:
    """3x3 covariance of the unit :func:`line_of_sight` (optical frame) for a pixel covariance (px^2).

    Rank 2 (the vector stays unit); first-order propagation through central differences.
    """
    h = JACOBIAN_STEP_PX
    los = line_of_sight(model, [u + h, u - h, u, u], [v, v, v + h, v - h])
    jacobian = np.stack([(los[0] - los[1]) / (2 * h), (los[2] - los[3]) / (2 * h)], axis=1)
    result: np.ndarray = jacobian @ _checked_covariance(pixel_covariance) @ jacobian.T
    return result
