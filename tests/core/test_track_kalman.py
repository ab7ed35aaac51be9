"""The numpy constant-velocity Kalman filter is filterpy's algebra with real elapsed time; JPTrack's
pixel floors are parameters of its model (ByteTrack's reference filter has none: the comparison
with boxmot's is in test_track_bytetrack_reference.py)."""

from __future__ import annotations

import filterpy.kalman as filterpy_kalman
import numpy as np
import pytest

from gldt_core.track import ByteTrack, JPTrack, JPTrackConfig
from gldt_core.track.kalman import BYTETRACK_MODEL, ConstantVelocityKalman, KalmanModel

#: JPTrack's filter, with its default floors.
JPTRACK_MODEL = JPTrackConfig().kalman_model()


@pytest.mark.parametrize(
    "model", [KalmanModel(), JPTRACK_MODEL, BYTETRACK_MODEL], ids=["plain", "jptrack", "bytetrack"]
)
def test_predict_and_update_equal_filterpy_with_irregular_time_steps(model: KalmanModel) -> None:
    rng = np.random.default_rng(3)
    ours = ConstantVelocityKalman(np.array([100.0, 50.0, 20.0, 12.0]), model=model)
    ref = filterpy_kalman.KalmanFilter(dim_x=8, dim_z=4)
    ref.x = ours.state.copy().reshape(8, 1)
    ref.P = ours.state_covariance.copy()
    ref.H = np.hstack([np.eye(4), np.zeros((4, 4))])
    truth = np.array([100.0, 50.0, 20.0, 12.0])
    for step in range(40):
        dt = float(rng.choice([1 / 30, 1 / 15, 0.1, 0.2]))
        f, q = ours.transition(dt)
        ref.F = f
        ref.Q = np.diag(q)
        ref.predict()
        ours.predict(dt)
        np.testing.assert_allclose(ours.state, ref.x.ravel(), rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(ours.state_covariance, ref.P, rtol=1e-9, atol=1e-9)
        truth = truth + np.array([90.0, -30.0, 0.0, 0.0]) * dt
        if step % 5 != 4:  # some steps coast without a measurement
            z = truth + rng.normal(0, 1.0, 4)
            ref.R = ours.measurement_noise()
            ref.update(ours.measured(z).reshape(4, 1))
            ours.update(z)
            np.testing.assert_allclose(ours.state, ref.x.ravel(), rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(ours.state_covariance, ref.P, rtol=1e-9, atol=1e-7)


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


def _share_followed_on_a_shaking_camera(model: KalmanModel) -> float:
    """A 6 px drone crossing at 6 px per frame while the camera shakes it by 3 px per frame, fed
    its exact boxes: the share of frames (after the first 20) where the filtered box overlaps the
    measurement by IoU >= 0.5 (the metrics' match threshold)."""
    rng = np.random.default_rng(7)
    size, fps = 6.0, 30.0
    shake = rng.normal(0.0, 3.0, (150, 2))
    measured = [np.array([100 + 6.0 * k + shake[k, 0], 300 + 1.5 * k + shake[k, 1], size, size]) for k in range(150)]
    kf = ConstantVelocityKalman(measured[0], model=model)
    ious = []
    for k in range(1, 150):
        kf.predict(1.0 / fps)
        kf.update(measured[k])
        ious.append(_box_iou_cxcywh(kf.mean[:4], measured[k]))
    return float(np.mean(np.array(ious[20:]) >= 0.5))


def test_a_small_target_on_a_shaking_camera_is_followed_not_trailed() -> None:
    """The shake moves a 6 px target as far as a 60 px one. With size-proportional noise alone
    (ByteTrack's, no floors) the filter smooths the shake away and its box misses IoU 0.5 on a
    third of the frames; with JPTrack's pixel floor under the centre's process noise, on none."""
    assert _share_followed_on_a_shaking_camera(JPTRACK_MODEL) > 0.95
    assert _share_followed_on_a_shaking_camera(KalmanModel()) < 0.8


def test_a_steady_target_keeps_a_smooth_velocity() -> None:
    """The floor lifts position noise, not velocity noise: a 24 px drone in steady flight seen with
    1 px of jitter keeps a velocity within a few px/s (what the avoidance planner reads)."""
    errors = []
    for seed in range(10):
        rng = np.random.default_rng(seed)
        velocity = np.array([60.0, 20.0])
        kf = ConstantVelocityKalman(np.array([200.0, 300.0, 24.0, 16.0]), model=JPTRACK_MODEL)
        for k in range(1, 150):
            centre = np.array([200.0, 300.0]) + velocity * k / 30 + rng.normal(0, 1.0, 2)
            kf.predict(1 / 30)
            kf.update(np.array([*centre, 24.0, 16.0]))
            if k > 60:
                errors.append(kf.mean[4:6] - velocity)
    assert np.sqrt(np.mean(np.square(errors))) < 3.0


def test_the_floors_leave_boxes_of_32_px_and_more_to_bytetrack() -> None:
    """From 32 px on JPTrack's noise is ByteTrack's (1/20 and 1/160 of the size, ten times that
    for a new track's velocity); below, only the centre's position noise and a new track's centre
    velocity are lifted to their floors in pixels, never the sizes or their velocities."""
    big = ConstantVelocityKalman(np.array([500.0, 500.0, 200.0, 180.0]), model=JPTRACK_MODEL)
    np.testing.assert_allclose(
        np.sqrt(np.diag(big.covariance)[4:]) / 30, 10 * np.array([200.0, 180.0, 200.0, 180.0]) / 160
    )
    _, q = big.transition(1 / 30)
    sizes = np.array([200.0, 180.0, 200.0, 180.0])
    np.testing.assert_allclose(q[:4], (sizes / 20) ** 2)
    np.testing.assert_allclose(q[4:], (sizes / 160 * 30) ** 2)
    edge = ConstantVelocityKalman(np.array([500.0, 500.0, 32.0, 32.0]), model=JPTRACK_MODEL)  # both floors end
    _, q = edge.transition(1 / 30)
    np.testing.assert_allclose(np.sqrt(q[:4]), 32.0 / 20)
    np.testing.assert_allclose(np.sqrt(np.diag(edge.covariance)[4:]) / 30, 10 * 32.0 / 160)
    small = ConstantVelocityKalman(np.array([500.0, 500.0, 6.0, 6.0]), model=JPTRACK_MODEL)
    _, q = small.transition(1 / 30)
    np.testing.assert_allclose(np.sqrt(q[:2]), 1.5)  # the centre: the floor
    np.testing.assert_allclose(np.sqrt(q[2:4]), 0.5)  # the size: the filter's old floor, as before
    np.testing.assert_allclose(np.sqrt(q[4:]) / 30, 0.5 / 8)  # velocities: unchanged
    birth_velocity_std = np.sqrt(np.diag(small.covariance)[4:]) / 30
    np.testing.assert_allclose(birth_velocity_std, [2.0, 2.0, 10 * 0.5 / 8, 10 * 0.5 / 8])


def _flickering_width(model: KalmanModel) -> tuple[float, float]:
    """A still box whose detections are alternately tight and loose (20 and 32 px wide), as a
    small drone's are: the spread of the filtered width over the last 60 frames, and the largest
    distance of the filtered centre from the true one."""
    kf = ConstantVelocityKalman(np.array([300.0, 200.0, 26.0, 20.0]), model=model)
    widths, centre_error = [], 0.0
    for k in range(1, 120):
        kf.predict(1 / 30)
        w = 20.0 if k % 2 else 32.0
        kf.update(np.array([300.0, 200.0, w, 0.77 * w]))
        widths.append(kf.mean[2])
        centre_error = max(centre_error, float(np.hypot(kf.mean[0] - 300.0, kf.mean[1] - 200.0)))
    return float(np.std(widths[60:])), centre_error


def test_jptrack_trusts_a_measured_size_less_than_a_measured_position() -> None:
    """A detector's box size flickers from frame to frame on a small drone (tight, then loose):
    JPTrack's filter takes 5 times ByteTrack's measurement noise for the size, so its width
    flickers a third as much, and the centre is as exact as before."""
    plain_spread, plain_error = _flickering_width(JPTrackConfig(kf_size_measurement_factor=1.0).kalman_model())
    spread, error = _flickering_width(JPTRACK_MODEL)
    assert JPTRACK_MODEL.size_measurement_factor == 5.0
    assert spread < plain_spread / 3 and spread < 1.0  # the detections' width: std 6 px
    assert error == pytest.approx(plain_error, abs=1e-9) and error < 1e-6
    r = np.sqrt(
        np.diag(ConstantVelocityKalman(np.array([0.0, 0.0, 40.0, 20.0]), model=JPTRACK_MODEL).measurement_noise())
    )
    np.testing.assert_allclose(r, [40.0 / 20, 20.0 / 20, 5 * 40.0 / 20, 5 * 20.0 / 20])


def test_a_size_trusted_less_still_follows_an_approaching_drone() -> None:
    """A drone closing in grows 2 % a frame (its size doubles in 1.2 s): the filter's size velocity
    keeps the filtered box within 2 % of the measured one."""
    kf = ConstantVelocityKalman(np.array([300.0, 200.0, 20.0, 15.0]), model=JPTRACK_MODEL)
    for k in range(1, 90):
        size = 20.0 * 1.02**k
        kf.predict(1 / 30)
        kf.update(np.array([300.0, 200.0, size, 0.75 * size]))
        if k >= 30:
            assert kf.mean[2] / size == pytest.approx(1.0, abs=0.02)


def test_without_floors_the_noise_is_proportional_to_the_size_at_any_size() -> None:
    small = ConstantVelocityKalman(np.array([500.0, 500.0, 6.0, 4.0]))
    _, q = small.transition(1 / 30)
    sizes = np.array([6.0, 4.0, 6.0, 4.0])
    np.testing.assert_allclose(np.sqrt(q[:4]), sizes / 20)
    np.testing.assert_allclose(np.sqrt(q[4:]) / 30, sizes / 160)
    np.testing.assert_allclose(np.sqrt(np.diag(small.covariance)), np.r_[2 * sizes / 20, 10 * sizes / 160 * 30])
    np.testing.assert_allclose(np.sqrt(np.diag(small.measurement_noise())), sizes / 20)


def test_the_trackers_give_their_tracks_their_own_filter() -> None:
    box = np.array([[100.0, 100.0, 106.0, 104.0, 0.9]])
    jp, bt = JPTrack(), ByteTrack()
    jp.update(box, 0.0)
    bt.update(box, 0.0)
    assert jp.tracks[0].kf.model == JPTRACK_MODEL and jp.tracks[0].kf.model.min_centre_process_std_px == 1.5
    assert bt.tracks[0].kf.model == BYTETRACK_MODEL
    floorless = JPTrack(
        JPTrackConfig(
            kf_min_std_px=0.0,
            kf_centre_process_floor_px=0.0,
            kf_birth_velocity_floor_px=0.0,
            kf_size_measurement_factor=1.0,
        )
    )
    floorless.update(box, 0.0)
    assert floorless.tracks[0].kf.model == KalmanModel()


def test_the_aspect_ratio_filter_reads_as_cx_cy_w_h() -> None:
    """ByteTrack's [cx, cy, a, h] state is shown as [cx, cy, w, h] (w = a h) with the covariance
    of that map: a first-order check against finite differences of the map."""
    rng = np.random.default_rng(11)
    kf = ConstantVelocityKalman(np.array([300.0, 200.0, 24.0, 16.0]), model=BYTETRACK_MODEL)
    for k in range(1, 12):
        kf.predict(1 / 30)
        kf.update(np.array([300.0 + 4 * k, 200.0 - 2 * k, 24.0 + 0.5 * k, 16.0 + 0.3 * k]) + rng.normal(0, 0.3, 4))
    a, h, va, vh = kf.state[2], kf.state[3], kf.state[6], kf.state[7]
    np.testing.assert_allclose(kf.mean[[0, 1, 3, 4, 5, 7]], kf.state[[0, 1, 3, 4, 5, 7]])
    assert kf.mean[2] == pytest.approx(a * h) and kf.mean[6] == pytest.approx(va * h + a * vh)

    def view(s: np.ndarray) -> np.ndarray:
        return np.array([s[0], s[1], s[2] * s[3], s[3], s[4], s[5], s[6] * s[3] + s[2] * s[7], s[7]])

    eps = 1e-6
    jac = np.column_stack([(view(kf.state + eps * e) - view(kf.state - eps * e)) / (2 * eps) for e in np.eye(8)])
    np.testing.assert_allclose(kf.covariance, jac @ kf.state_covariance @ jac.T, rtol=1e-6, atol=1e-9)
    assert kf.measured(np.array([1.0, 2.0, 30.0, 20.0])).tolist() == [1.0, 2.0, 1.5, 20.0]


def test_stop_height_velocity_keeps_a_coasting_box_at_its_size() -> None:
    for model in (BYTETRACK_MODEL, KalmanModel()):
        kf = ConstantVelocityKalman(np.array([100.0, 100.0, 20.0, 20.0]), model=model)
        for k in range(1, 10):
            kf.predict(1 / 30)
            kf.update(np.array([100.0, 100.0, 20.0 + k, 20.0 + k]))
        assert kf.state[7] > 0
        kf.stop_height_velocity()
        h = kf.mean[3]
        kf.predict(0.5)
        assert kf.state[7] == 0.0 and kf.mean[3] == pytest.approx(h)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"min_std_px": -0.1},
        {"min_centre_process_std_px": float("nan")},
        {"aspect_ratio": True, "min_std_px": 0.5},
        {"size_measurement_factor": 0.0},
        {"size_measurement_factor": float("inf")},
        {"aspect_ratio": True, "size_measurement_factor": 2.0},
    ],
)
def test_a_model_refuses_bad_noise_settings_and_any_on_the_reference_filter(kwargs) -> None:
    with pytest.raises(ValueError):
        KalmanModel(**kwargs)


def test_filters_of_different_models_are_batched_each_with_its_own() -> None:
    from gldt_core.track.kalman import predict_many, update_many

    boxes = [np.array([100.0, 80.0, 12.0, 8.0]), np.array([300.0, 200.0, 40.0, 30.0])]
    models = [BYTETRACK_MODEL, JPTRACK_MODEL, KalmanModel()]
    singles = [ConstantVelocityKalman(b, model=m) for b in boxes for m in models]
    batch = [ConstantVelocityKalman(b, model=m) for b in boxes for m in models]
    for f in singles:
        f.predict(0.1)
        f.update(f.mean[:4] + 1.0)
    predict_many(batch, np.full(len(batch), 0.1))
    update_many(batch, np.array([f.mean[:4] + 1.0 for f in batch]))
    for a, b in zip(singles, batch):
        np.testing.assert_allclose(b.state, a.state, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(b.covariance, a.covariance, rtol=1e-10, atol=1e-9)
