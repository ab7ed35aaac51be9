"""Bearing, bearing rate and looming time to collision against scenes of known geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gldt_core.camera import PinholeIntrinsics, bearing, bearing_rate, time_to_collision


def project(intrinsics: PinholeIntrinsics, point_camera: np.ndarray) -> tuple[float, float]:
    """Pinhole projection of a point in the optical frame (x right, y down, z forward)."""
    x, y, z = point_camera
    return intrinsics.fx * x / z + intrinsics.cx, intrinsics.fy * y / z + intrinsics.cy


def direction(azimuth: float, elevation: float) -> np.ndarray:
    """Unit ray with the given azimuth (right +) and elevation (up +), optical frame."""
    return np.array(
        [math.cos(elevation) * math.sin(azimuth), -math.sin(elevation), math.cos(elevation) * math.cos(azimuth)]
    )


@pytest.mark.parametrize("azimuth_deg, elevation_deg", [(0, 0), (12.5, -3.0), (-30, 20), (40, 25)])
def test_bearing_recovers_the_angles_of_a_projected_target(azimuth_deg: float, elevation_deg: float) -> None:
    intrinsics = PinholeIntrinsics.from_fov(1920, 1080, math.radians(90))
    azimuth, elevation = math.radians(azimuth_deg), math.radians(elevation_deg)
    u, v = project(intrinsics, 250.0 * direction(azimuth, elevation))
    got_azimuth, got_elevation = bearing(intrinsics, u, v)
    assert got_azimuth == pytest.approx(azimuth, abs=1e-9)
    assert got_elevation == pytest.approx(elevation, abs=1e-9)


def test_bearing_rate_matches_a_target_crossing_at_known_angular_speed() -> None:
    intrinsics = PinholeIntrinsics(fx=1400.0, fy=1400.0, cx=960.0, cy=540.0)
    omega = math.radians(5.0)  # rad/s, target sweeping right at constant range, level
    dt = 1e-3
    u0, v0 = project(intrinsics, 300.0 * direction(0.2, 0.05))
    u1, v1 = project(intrinsics, 300.0 * direction(0.2 + omega * dt, 0.05))
    rate_az, rate_el = bearing_rate(intrinsics, (u0 + u1) / 2, (v0 + v1) / 2, (u1 - u0) / dt, (v1 - v0) / dt)
    assert rate_az == pytest.approx(omega, rel=1e-3)
    assert rate_el == pytest.approx(0.0, abs=1e-4)


def test_time_to_collision_of_an_approaching_drone() -> None:
    # A 0.5 m drone closing at 10 m/s from 100 m: true TTC 10 s; image size s = f * 0.5 / range.
    focal = 1400.0
    size = lambda rng: focal * 0.5 / rng  # noqa: E731
    dt = 0.01
    rate = (size(100.0 - 10.0 * dt) - size(100.0)) / dt
    assert time_to_collision(size(100.0), rate) == pytest.approx(10.0, rel=1e-2)
    assert time_to_collision(size(100.0), -rate) is None, "a receding target is no collision threat"
    assert time_to_collision(0.0, rate) is None


def test_camera_info_validation_names_the_problem() -> None:
    with pytest.raises(ValueError, match="NaN"):
        PinholeIntrinsics.from_k([float("nan")] * 9)
    with pytest.raises(ValueError, match="focal"):
        PinholeIntrinsics.from_k([0, 0, 320, 0, 0, 240, 0, 0, 1])
    with pytest.raises(ValueError, match="9 values"):
        PinholeIntrinsics.from_k([1, 2, 3])
