"""Camera geometry for planners: pixel -> bearing, bearing rates and time to collision.

An avoidance planner wants angles, not pixels. With a pinhole camera (``K`` from
``sensor_msgs/CameraInfo``; distortion is ignored, which is fine for the narrow-to-medium
fields of view of sense-and-avoid cameras) the bearing of pixel ``(u, v)`` is
``azimuth = atan2(u - cx, fx)`` (positive to the right) and
``elevation = atan2(cy - v, sqrt(fy^2 + ...))``; we use the exact ray direction
``d = K^-1 [u, v, 1]`` so azimuth and elevation are the angles of the same ray.

Time to collision comes from looming: for an object of fixed size approaching at constant
speed, its image size ``s`` grows as ``1/range``, so ``tau = s / (ds/dt)``. It is valid only
when the box is growing (``ds/dt > 0``); a shrinking or constant box is not a collision threat.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PinholeIntrinsics:
    """The four pinhole parameters of ``CameraInfo.k`` (row-major 3x3)."""

    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def from_k(cls, k: np.ndarray | list[float]) -> PinholeIntrinsics:
        """Build from the 9 numbers of ``CameraInfo.k``; raises ``ValueError`` if unusable."""
        values = np.asarray(k, dtype=np.float64).reshape(-1)
        if values.size != 9:
            raise ValueError(f"camera_info.k must have 9 values, got {values.size}")
        if not np.all(np.isfinite(values)):
            raise ValueError("camera_info.k holds NaN or infinite values")
        fx, fy, cx, cy = values[0], values[4], values[2], values[5]
        if fx <= 0 or fy <= 0:
            raise ValueError(f"camera_info.k has non-positive focal length (fx={fx}, fy={fy})")
        return cls(float(fx), float(fy), float(cx), float(cy))

    @classmethod
    def from_fov(cls, width: int, height: int, horizontal_fov_rad: float) -> PinholeIntrinsics:
        """Square-pixel intrinsics with the optical centre in the image centre."""
        if not 0 < horizontal_fov_rad < math.pi:
            raise ValueError(f"horizontal field of view must be in (0, pi), got {horizontal_fov_rad}")
        fx = (width / 2.0) / math.tan(horizontal_fov_rad / 2.0)
        return cls(fx, fx, width / 2.0, height / 2.0)


def bearing(intrinsics: PinholeIntrinsics, u: float, v: float) -> tuple[float, float]:
    """Azimuth (right positive) and elevation (up positive) of pixel ``(u, v)`` in radians."""
    x = (u - intrinsics.cx) / intrinsics.fx
    y = (v - intrinsics.cy) / intrinsics.fy
    azimuth = math.atan2(x, 1.0)
    elevation = math.atan2(-y, math.hypot(x, 1.0))
    return azimuth, elevation


def bearing_rate(
    intrinsics: PinholeIntrinsics, u: float, v: float, du_dt: float, dv_dt: float, dt: float = 1e-3
) -> tuple[float, float]:
    """Rates of azimuth and elevation (rad/s) for a pixel moving at ``(du/dt, dv/dt)`` px/s.

    Central finite difference of :func:`bearing`; exact to second order and free of the
    algebra errors an analytic Jacobian invites.
    """
    az_plus, el_plus = bearing(intrinsics, u + du_dt * dt, v + dv_dt * dt)
    az_minus, el_minus = bearing(intrinsics, u - du_dt * dt, v - dv_dt * dt)
    return (az_plus - az_minus) / (2 * dt), (el_plus - el_minus) / (2 * dt)


def time_to_collision(size_px: float, size_rate_px_s: float, min_rate: float = 1e-6) -> float | None:
    """Looming time to collision ``size / (d size / dt)`` in seconds, or ``None`` if not approaching."""
    if not (math.isfinite(size_px) and math.isfinite(size_rate_px_s)) or size_px <= 0:
        return None
    if size_rate_px_s <= min_rate:
        return None
    return size_px / size_rate_px_s
