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
