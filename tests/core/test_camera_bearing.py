"""Camera geometry: REP-103 bearing signs, distortion against OpenCV, rates, covariance, bad input."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from gldt_core.camera import (
    CameraModel,
    CameraModelError,
    bearing,
    bearing_covariance,
    bearing_jacobian,
    bearing_rate,
    bearings,
    line_of_sight,
    line_of_sight_covariance,
    project,
)

WIDTH, HEIGHT = 1280, 720
K = [800.0, 0.0, 641.5, 0.0, 805.0, 357.25, 0.0, 0.0, 1.0]
# Realistic calibrations: a wide lens with barrel distortion, a rational model of a wider lens, a fisheye.
DISTORTIONS = {
    "plumb_bob": [-0.28, 0.07, 1e-3, -5e-4, 0.0],
    "rational_polynomial": [1.2, 0.2, 1e-3, -5e-4, 0.0, 1.6, 0.5, 0.02],
    "equidistant": [-0.01, 0.02, -0.005, 0.001],
}
MODELS = sorted(DISTORTIONS)


def model_of(name: str) -> CameraModel:
    return CameraModel.from_camera_info(K, DISTORTIONS[name], name)


def opencv_project(name: str, rays: np.ndarray) -> np.ndarray:
    """OpenCV's projection of optical-frame directions (N, 3) to pixels (N, 2): the reference."""
    camera = model_of(name)
    coefficients = np.asarray(DISTORTIONS[name], dtype=np.float64)
    points = np.ascontiguousarray(rays, dtype=np.float64).reshape(-1, 1, 3)
    if name == "equidistant":
        pixels, _ = cv2.fisheye.projectPoints(points, np.zeros(3), np.zeros(3), camera.k, coefficients)
    else:
        pixels, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), camera.k, coefficients)
    return np.asarray(pixels, dtype=np.float64).reshape(-1, 2)


def image_grid(step: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """Pixels over the whole image, corners included."""
    u, v = np.meshgrid(np.arange(0, WIDTH + 1, step, dtype=float), np.arange(0, HEIGHT + 1, step, dtype=float))
    return u.ravel(), v.ravel()


def direction(azimuth: float, elevation: float) -> np.ndarray:
    """Unit ray in the optical frame with REP-103 azimuth (left +) and elevation (up +)."""
    return np.array(
        [-math.cos(elevation) * math.sin(azimuth), -math.sin(elevation), math.cos(elevation) * math.cos(azimuth)]
    )


# --------------------------------------------------------------------------- signs and frames
@pytest.mark.parametrize("name", MODELS)
def test_bearing_signs_follow_rep_103(name: str) -> None:
    camera = model_of(name)
    centre_az, centre_el = bearing(camera, camera.cx, camera.cy)
    assert centre_az == pytest.approx(0.0, abs=1e-12) and centre_el == pytest.approx(0.0, abs=1e-12)
    left, right = bearing(camera, camera.cx - 200, camera.cy), bearing(camera, camera.cx + 200, camera.cy)
    up, down = bearing(camera, camera.cx, camera.cy - 150), bearing(camera, camera.cx, camera.cy + 150)
    assert left[0] > 0 > right[0], "azimuth is counter-clockwise about up: positive to the left"
    assert up[1] > 0 > down[1], "elevation is positive up"
    # Off the axes only by the lens's tangential (decentring) terms.
    assert left[1] == pytest.approx(0.0, abs=1e-3) and up[0] == pytest.approx(0.0, abs=1e-3)
    # Up and to the left: both positive; the line of sight there points left (-x) and up (-y), forward (+z).
    az, el = bearing(camera, camera.cx - 300, camera.cy - 200)
    los = line_of_sight(camera, camera.cx - 300, camera.cy - 200)
    assert az > 0 and el > 0
    assert los[0] < 0 and los[1] < 0 and los[2] > 0


@pytest.mark.parametrize("azimuth_deg, elevation_deg", [(0, 0), (12.5, -3.0), (-30, 20), (40, 25)])
def test_bearing_recovers_the_angles_of_a_projected_target(azimuth_deg: float, elevation_deg: float) -> None:
    camera = CameraModel.from_fov(1920, 1080, math.radians(90))
    azimuth, elevation = math.radians(azimuth_deg), math.radians(elevation_deg)
    u, v = project(camera, 250.0 * direction(azimuth, elevation))
    got_azimuth, got_elevation = bearing(camera, float(u), float(v))
    assert got_azimuth == pytest.approx(azimuth, abs=1e-9)
    assert got_elevation == pytest.approx(elevation, abs=1e-9)


@pytest.mark.parametrize("name", MODELS)
def test_line_of_sight_is_a_unit_vector_in_front_of_the_camera(name: str) -> None:
    u, v = image_grid()
    los = line_of_sight(model_of(name), u, v)
    assert los.shape == (u.size, 3)
    assert np.all(np.isfinite(los))
    np.testing.assert_allclose(np.linalg.norm(los, axis=1), 1.0, atol=1e-12)
    assert np.all(los[:, 2] > 0)


def test_line_of_sight_accepts_scalars_and_arrays_alike() -> None:
    camera = model_of("plumb_bob")
    u, v = np.meshgrid(np.linspace(10, 1200, 5), np.linspace(20, 700, 4))
    many = line_of_sight(camera, u, v)
    assert many.shape == (4, 5, 3)
    assert line_of_sight(camera, 100.0, 200.0).shape == (3,)
    for i in range(4):
        for j in range(5):
            np.testing.assert_array_equal(many[i, j], line_of_sight(camera, u[i, j], v[i, j]))
    az, el = bearings(camera, u, v)
    assert az.shape == el.shape == (4, 5)
    assert (float(az[2, 3]), float(el[2, 3])) == bearing(camera, float(u[2, 3]), float(v[2, 3]))


# --------------------------------------------------------------------------- distortion against OpenCV
@pytest.mark.parametrize("name", MODELS)
def test_distorted_pixel_to_line_of_sight_and_back_through_opencv(name: str) -> None:
    u, v = image_grid()
    los = line_of_sight(model_of(name), u, v)
    back = opencv_project(name, los)
    error = np.hypot(back[:, 0] - u, back[:, 1] - v)
    assert error.max() < 1e-3, f"{name}: worst round trip {error.max():.2e} px"


@pytest.mark.parametrize("name", MODELS)
def test_line_of_sight_recovers_the_ray_opencv_projected(name: str) -> None:
    rng = np.random.default_rng(7)
    rays = np.column_stack([rng.uniform(-0.7, 0.7, 500), rng.uniform(-0.4, 0.4, 500), np.ones(500)])
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    pixels = opencv_project(name, rays)
    los = line_of_sight(model_of(name), pixels[:, 0], pixels[:, 1])
    np.testing.assert_allclose(los, rays, atol=1e-9)
    # The forward model agrees with OpenCV's too.
    np.testing.assert_allclose(project(model_of(name), rays), pixels, atol=1e-6)


def test_distortion_changes_the_bearing_of_an_off_centre_pixel() -> None:
    """The model is not ignored: at a corner, barrel distortion moves the bearing by degrees."""
    distorted = model_of("plumb_bob")
    pinhole = CameraModel.from_camera_info(K)
    az_d, el_d = bearing(distorted, 20.0, 20.0)
    az_p, el_p = bearing(pinhole, 20.0, 20.0)
    assert abs(az_d) - abs(az_p) > math.radians(3), "barrel distortion: the corner is further out than pinhole says"
    assert abs(el_d) - abs(el_p) > math.radians(1)


def test_fisheye_rays_beyond_ninety_degrees() -> None:
    camera = CameraModel.from_camera_info(
        [300, 0, 640, 0, 300, 360, 0, 0, 1], DISTORTIONS["equidistant"], "equidistant"
    )
    ray = direction(math.radians(100), 0.0)  # behind the image plane, 100 degrees to the left
    assert ray[2] < 0
    u, v = project(camera, ray)
    np.testing.assert_allclose(line_of_sight(camera, u, v), ray, atol=1e-9)
    assert bearing(camera, float(u), float(v))[0] == pytest.approx(math.radians(100), abs=1e-9)


def test_pixels_where_the_distortion_folds_back_give_nan() -> None:
    # r_d = r (1 - 0.4 r^2) peaks at r_d = 0.61: no ray maps to a normalised radius of 0.8.
    camera = CameraModel.from_camera_info([500, 0, 320, 0, 500, 240, 0, 0, 1], [-0.4, 0, 0, 0, 0], "plumb_bob")
    assert np.all(np.isnan(line_of_sight(camera, 320 + 0.8 * 500, 240)))
    assert np.all(np.isfinite(line_of_sight(camera, 320 + 0.5 * 500, 240)))


def test_empty_distortion_means_none() -> None:
    u, v = image_grid(80)
    reference = line_of_sight(CameraModel.from_camera_info(K, [0.0] * 5, "plumb_bob"), u, v)
    for d, model_name in (([], ""), ([], "plumb_bob"), ((), "")):
        camera = CameraModel.from_camera_info(K, d, model_name)
        assert camera.distortion_model == "plumb_bob" and not camera.has_distortion
        np.testing.assert_array_equal(line_of_sight(camera, u, v), reference)


# --------------------------------------------------------------------------- rates and covariance
def test_bearing_rate_matches_a_target_crossing_at_known_angular_speed() -> None:
    camera = CameraModel(fx=1400.0, fy=1400.0, cx=960.0, cy=540.0)
    omega = math.radians(5.0)  # rad/s, target sweeping LEFT (positive azimuth rate) at constant range, level
    dt = 1e-3
    u0, v0 = project(camera, 300.0 * direction(0.2, 0.05))
    u1, v1 = project(camera, 300.0 * direction(0.2 + omega * dt, 0.05))
    rate_az, rate_el = bearing_rate(camera, (u0 + u1) / 2, (v0 + v1) / 2, (u1 - u0) / dt, (v1 - v0) / dt)
    assert u1 < u0, "moving left in the image"
    assert rate_az == pytest.approx(omega, rel=1e-3)
    assert rate_el == pytest.approx(0.0, abs=1e-4)


@pytest.mark.parametrize("name", MODELS)
def test_bearing_rate_through_distortion_matches_opencv_motion(name: str) -> None:
    """A target rising and moving right at known angular rates, imaged through OpenCV's model."""
    rate_true = np.array([-0.3, 0.2])  # rad/s: azimuth decreasing (to the right), elevation increasing
    start = np.array([0.5, 0.3])
    dt = 1e-4
    rays = np.array([direction(*(start + rate_true * s)) for s in (-dt / 2, dt / 2)])
    (u0, v0), (u1, v1) = opencv_project(name, rays)
    got = bearing_rate(model_of(name), (u0 + u1) / 2, (v0 + v1) / 2, (u1 - u0) / dt, (v1 - v0) / dt)
    np.testing.assert_allclose(got, rate_true, rtol=1e-4)


@pytest.mark.parametrize("name", MODELS)
def test_bearing_covariance_matches_monte_carlo(name: str) -> None:
    camera = model_of(name)
    u, v = 90.0, 610.0  # near a corner, where distortion bends the map most
    pixel_covariance = np.array([[4.0, 1.5], [1.5, 2.5]])  # px^2
    rng = np.random.default_rng(3)
    samples = rng.multivariate_normal([u, v], pixel_covariance, size=40_000)
    azimuth, elevation = bearings(camera, samples[:, 0], samples[:, 1])
    monte_carlo = np.cov(np.vstack([azimuth, elevation]))
    predicted = bearing_covariance(camera, u, v, pixel_covariance)
    np.testing.assert_allclose(predicted, monte_carlo, rtol=0.03, atol=0.03 * np.abs(monte_carlo).max())
    # Not a pinhole answer: distortion changes the covariance by far more than the tolerance.
    pinhole = bearing_covariance(CameraModel.from_camera_info(K), u, v, pixel_covariance)
    assert np.abs(pinhole - predicted).max() > 0.1 * np.abs(predicted).max()


def test_line_of_sight_covariance_matches_monte_carlo() -> None:
    camera = model_of("rational_polynomial")
    u, v = 1100.0, 150.0
    pixel_covariance = np.diag([3.0, 1.0])
    rng = np.random.default_rng(5)
    samples = rng.multivariate_normal([u, v], pixel_covariance, size=40_000)
    monte_carlo = np.cov(line_of_sight(camera, samples[:, 0], samples[:, 1]).T)
    predicted = line_of_sight_covariance(camera, u, v, pixel_covariance)
    assert predicted.shape == (3, 3)
    np.testing.assert_allclose(predicted, monte_carlo, atol=0.03 * np.abs(monte_carlo).max())
    assert np.linalg.matrix_rank(predicted, tol=1e-6 * np.abs(predicted).max()) == 2


def test_bearing_jacobian_of_a_pinhole_at_the_centre() -> None:
    camera = CameraModel(fx=1000.0, fy=800.0, cx=500.0, cy=400.0)
    np.testing.assert_allclose(bearing_jacobian(camera, 500.0, 400.0), [[-1e-3, 0.0], [0.0, -1.25e-3]], rtol=1e-6)
    with pytest.raises(ValueError, match="2x2"):
        bearing_covariance(camera, 500.0, 400.0, np.eye(3))


# --------------------------------------------------------------------------- bad input
GOOD_D = [0.0] * 5


@pytest.mark.parametrize(
    "k, d, model, field, words",
    [
        ([1, 2, 3], GOOD_D, "plumb_bob", "camera_info.k", "9 values"),
        ([800, 0, 640, 0, 800, 360, 0, 0, 1, 0], GOOD_D, "plumb_bob", "camera_info.k", "9 values"),
        ([float("nan")] * 9, GOOD_D, "plumb_bob", "camera_info.k", "NaN"),
        ([800, 0, 640, 0, math.inf, 360, 0, 0, 1], GOOD_D, "plumb_bob", "camera_info.k", "infinite"),
        ([0] * 9, GOOD_D, "plumb_bob", "camera_info.k", "all zeros"),
        ([0, 0, 320, 0, 0, 240, 0, 0, 1], GOOD_D, "plumb_bob", "camera_info.k", "focal length"),
        ([-800, 0, 640, 0, 800, 360, 0, 0, 1], GOOD_D, "plumb_bob", "camera_info.k", "focal length"),
        (K, [0.1, 0.0, 0.0, 0.0], "plumb_bob", "camera_info.d", "5 (or 0) values"),
        (K, GOOD_D, "rational_polynomial", "camera_info.d", "8 values"),
        (K, [], "rational_polynomial", "camera_info.d", "8 values"),
        (K, GOOD_D, "equidistant", "camera_info.d", "4 values"),
        (K, [0.1, float("nan"), 0.0, 0.0, 0.0], "plumb_bob", "camera_info.d", "NaN"),
        (K, GOOD_D, "fisheye", "camera_info.distortion_model", "'fisheye' is not supported"),
        (K, GOOD_D, "Plumb_Bob", "camera_info.distortion_model", "not supported"),
    ],
)
def test_bad_camera_info_names_the_field(k: list[float], d: list[float], model: str, field: str, words: str) -> None:
    with pytest.raises(CameraModelError) as error:
        CameraModel.from_camera_info(k, d, model)
    message = str(error.value)
    assert field in message and words in message, message
    assert "\n" not in message
    assert isinstance(error.value, ValueError)


def test_bad_direct_construction_and_field_of_view_name_the_field() -> None:
    cases = [
        (lambda: CameraModel(fx=0.0, fy=800.0, cx=1.0, cy=1.0), "focal length"),
        (lambda: CameraModel(fx=800.0, fy=800.0, cx=math.nan, cy=1.0), "cx"),
        (lambda: CameraModel(800.0, 800.0, 1.0, 1.0, "equidistant", (0.1,)), "d must have 4 values"),
        (lambda: CameraModel(800.0, 800.0, 1.0, 1.0, "kannala", ()), "distortion model 'kannala'"),
        (lambda: CameraModel.from_fov(640, 480, math.pi), "horizontal_fov_rad"),
        (lambda: CameraModel.from_fov(640, 480, 0.0), "horizontal_fov_rad"),
        (lambda: CameraModel.from_fov(0, 480, 1.0), "image size"),
    ]
    for build, words in cases:
        with pytest.raises(CameraModelError, match=words):
            build()


def test_from_fov_puts_the_edges_at_half_the_field_of_view() -> None:
    camera = CameraModel.from_fov(1920, 1080, math.radians(90))
    assert bearing(camera, 0.0, 540.0)[0] == pytest.approx(math.radians(45))
    assert bearing(camera, 1920.0, 540.0)[0] == pytest.approx(-math.radians(45))
