"""The numpy constant-velocity Kalman filter is filterpy's algebra with real elapsed time."""

from __future__ import annotations

import numpy as np
import pytest

from gldt_core.track.kalman import ConstantVelocityKalman

filterpy_kalman = pytest.importorskip("filterpy.kalman")


def test_predict_and_update_equal_filterpy_with_irregular_time_steps() -> None:
    rng = np.random.default_rng(3)
    ours = ConstantVelocityKalman(np.array([100.0, 50.0, 20.0, 12.0]))
    ref = filterpy_kalman.KalmanFilter(dim_x=8, dim_z=4)
    ref.x = ours.mean.copy().reshape(8, 1)
    ref.P = ours.covariance.copy()
    ref.H = np.hstack([np.eye(4), np.zeros((4, 4))])
    truth = np.array([100.0, 50.0, 20.0, 12.0])
    for step in range(40):
        dt = float(rng.choice([1 / 30, 1 / 15, 0.1, 0.2]))
        f, q = ours.transition(dt)
        ref.F = f
        ref.Q = np.diag(q)
        ref.predict()
        ours.predict(dt)
        np.testing.assert_allclose(ours.mean, ref.x.ravel(), rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(ours.covariance, ref.P, rtol=1e-9, atol=1e-9)
        truth = truth + np.array([90.0, -30.0, 0.0, 0.0]) * dt
        if step % 5 != 4:  # some steps coast without a measurement
            z = truth + rng.normal(0, 1.0, 4)
            ref.R = ours.measurement_noise()
            ref.update(z.reshape(4, 1))
            ours.update(z)
            np.testing.assert_allclose(ours.mean, ref.x.ravel(), rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(ours.covariance, ref.P, rtol=1e-9, atol=1e-7)


def _track_constant_velocity(fps: float, seconds: float) -> ConstantVelocityKalman:
    kf = ConstantVelocityKalman(np.array([0.0, 0.0, 20.0, 20.0]))
    velocity = np.array([120.0, 45.0])  # px/s
    for k in range(1, int(round(seconds * fps)) + 1):
        kf.predict(1.0 / fps)
        kf.update(np.array([*(velocity * k / fps), 20.0, 20.0]))
    return kf


def test_velocity_is_in_pixels_per_second_whatever_the_frame_rate() -> None:
    for fps in (15.0, 30.0, 60.0):
        kf = _track_constant_velocity(fps, 2.0)
        np.testing.assert_allclose(kf.mean[4:6], [120.0, 45.0], rtol=0.02)


def test_prediction_uncertainty_depends_on_elapsed_time_not_on_the_number_of_steps() -> None:
    one = ConstantVelocityKalman(np.array([0.0, 0.0, 20.0, 20.0]))
    many = ConstantVelocityKalman(np.array([0.0, 0.0, 20.0, 20.0]))
    one.mean[4:6] = many.mean[4:6] = [30.0, -10.0]
    one.predict(0.5)
    for _ in range(15):
        many.predict(0.5 / 15)
    np.testing.assert_allclose(one.mean, many.mean, atol=1e-9)
    # Position variance differs only by the dt^2 terms of the velocity variance, not by the count.
    assert one.covariance[0, 0] == pytest.approx(many.covariance[0, 0], rel=0.35)


def test_predicted_does_not_change_the_filter() -> None:
    kf = ConstantVelocityKalman(np.array([10.0, 10.0, 8.0, 8.0]))
    kf.mean[4] = 60.0
    before_mean, before_cov = kf.mean.copy(), kf.covariance.copy()
    mean, cov = kf.predicted(0.25)
    assert mean[0] == pytest.approx(25.0)
    np.testing.assert_array_equal(kf.mean, before_mean)
    np.testing.assert_array_equal(kf.covariance, before_cov)
    assert cov[0, 0] > before_cov[0, 0]


def test_vectorised_prediction_equals_one_filter_at_a_time() -> None:
    from gldt_core.track.kalman import predict_many

    rng = np.random.default_rng(5)
    singles, batch = [], []
    for _ in range(6):
        box = np.array([*rng.uniform(0, 500, 2), *rng.uniform(2, 60, 2)])
        a, b = ConstantVelocityKalman(box), ConstantVelocityKalman(box)
        a.mean[4:] = b.mean[4:] = rng.normal(0, 50, 4)
        singles.append(a)
        batch.append(b)
    dts = np.array([0.0, 1 / 30, 0.1, 0.5, 1 / 15, 2.0])
    for f, dt in zip(singles, dts):
        f.predict(float(dt))
    predict_many(batch, dts)
    for a, b in zip(singles, batch):
        np.testing.assert_allclose(b.mean, a.mean, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(b.covariance, a.covariance, rtol=1e-12, atol=1e-9)


def test_vectorised_update_equals_one_filter_at_a_time() -> None:
    from gldt_core.track.kalman import update_many

    rng = np.random.default_rng(6)
    singles, batch, boxes = [], [], []
    for _ in range(5):
        box = np.array([*rng.uniform(0, 500, 2), *rng.uniform(2, 60, 2)])
        a, b = ConstantVelocityKalman(box), ConstantVelocityKalman(box)
        a.predict(0.1)
        b.predict(0.1)
        boxes.append(box + rng.normal(0, 2, 4))
        singles.append(a)
        batch.append(b)
    for f, z in zip(singles, boxes):
        f.update(z)
    update_many(batch, np.asarray(boxes))
    for a, b in zip(singles, batch):
        np.testing.assert_allclose(b.mean, a.mean, rtol=1e-10, atol=1e-9)
        np.testing.assert_allclose(b.covariance, a.covariance, rtol=1e-9, atol=1e-9)


def _box_iou_cxcywh(a: np.ndarray, b: np.ndarray) -> float:
    ax1, ay1, ax2, ay2 = a[0] - a[2] / 2, a[1] - a[3] / 2, a[0] + a[2] / 2, a[1] + a[3] / 2
    bx1, by1, bx2, by2 = b[0] - b[2] / 2, b[1] - b[3] / 2, b[0] + b[2] / 2, b[1] + b[3] / 2
    inter = max(0.0, min(ax2, bx2) - max(ax1, bx1)) * max(0.0, min(ay2, by2) - max(ay1, by1))
    return inter / (a[2] * a[3] + b[2] * b[3] - inter)


def test_a_small_target_on_a_shaking_camera_is_followed_not_trailed() -> None:
    """A 6 px drone crossing at 6 px per frame while the camera shakes it by 3 px per frame (the
    shake moves a 6 px target as far as a 60 px one), fed its exact boxes: with ByteTrack's
    size-proportional noise alone the filter smoothed the shake away and its box overlapped the
    measurement by IoU < 0.5 (the metrics' match threshold) on a third of the frames; with the
    pixel floor under the centre's process noise, on none."""
    rng = np.random.default_rng(7)
    size, fps = 6.0, 30.0
    shake = rng.normal(0.0, 3.0, (150, 2))
    measured = [np.array([100 + 6.0 * k + shake[k, 0], 300 + 1.5 * k + shake[k, 1], size, size]) for k in range(150)]
    kf = ConstantVelocityKalman(measured[0])
    ious = []
    for k in range(1, 150):
        kf.predict(1.0 / fps)
        kf.update(measured[k])
        ious.append(_box_iou_cxcywh(kf.mean[:4], measured[k]))
    assert np.mean(np.array(ious[20:]) >= 0.5) > 0.95, np.mean(np.array(ious[20:]) >= 0.5)


def test_a_steady_target_keeps_a_smooth_velocity() -> None:
    """The floor lifts position noise, not velocity noise: a 24 px drone in steady flight seen with
    1 px of jitter keeps a velocity within a few px/s (what the avoidance planner reads)."""
    errors = []
    for seed in range(10):
        rng = np.random.default_rng(seed)
        velocity = np.array([60.0, 20.0])
        kf = ConstantVelocityKalman(np.array([200.0, 300.0, 24.0, 16.0]))
        for k in range(1, 150):
            centre = np.array([200.0, 300.0]) + velocity * k / 30 + rng.normal(0, 1.0, 2)
            kf.predict(1 / 30)
            kf.update(np.array([*centre, 24.0, 16.0]))
            if k > 60:
                errors.append(kf.mean[4:6] - velocity)
    assert np.sqrt(np.mean(np.square(errors))) < 3.0


def test_the_floors_leave_boxes_of_32_px_and_more_to_bytetrack() -> None:
    """From 32 px on the noise is ByteTrack's (1/20 and 1/160 of the size, ten times that for a
    new track's velocity); below, only the centre's position noise and a new track's centre
    velocity are lifted to their floors in pixels, never the sizes or their velocities."""
    big = ConstantVelocityKalman(np.array([500.0, 500.0, 200.0, 180.0]))
    np.testing.assert_allclose(
        np.sqrt(np.diag(big.covariance)[4:]) / 30, 10 * np.array([200.0, 180.0, 200.0, 180.0]) / 160
    )
    _, q = big.transition(1 / 30)
    sizes = np.array([200.0, 180.0, 200.0, 180.0])
    np.testing.assert_allclose(q[:4], (sizes / 20) ** 2)
    np.testing.assert_allclose(q[4:], (sizes / 160 * 30) ** 2)
    edge = ConstantVelocityKalman(np.array([500.0, 500.0, 32.0, 32.0]))  # where both floors end
    _, q = edge.transition(1 / 30)
    np.testing.assert_allclose(np.sqrt(q[:4]), 32.0 / 20)
    np.testing.assert_allclose(np.sqrt(np.diag(edge.covariance)[4:]) / 30, 10 * 32.0 / 160)
    small = ConstantVelocityKalman(np.array([500.0, 500.0, 6.0, 6.0]))
    _, q = small.transition(1 / 30)
    np.testing.assert_allclose(np.sqrt(q[:2]), 1.5)  # the centre: the floor
    np.testing.assert_allclose(np.sqrt(q[2:4]), 0.5)  # the size: the filter's old floor, as before
    np.testing.assert_allclose(np.sqrt(q[4:]) / 30, 0.5 / 8)  # velocities: unchanged
    birth_velocity_std = np.sqrt(np.diag(small.covariance)[4:]) / 30
    np.testing.assert_allclose(birth_velocity_std, [2.0, 2.0, 10 * 0.5 / 8, 10 * 0.5 / 8])
