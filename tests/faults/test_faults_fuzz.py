"""Property tests (hypothesis): arbitrary detections, ROI predictions and messages never raise
anything but the documented errors.

Documented behaviour this checks (read from the modules, not assumed):

* trackers (``gldt_core.track.base.MultiStageTracker.update``, ``track.boxes``): any finite
  ``(N, 5)`` array with positive-size boxes and scores in ``[0, 1]`` is accepted; NaN/inf, a
  non-positive size or a score outside ``[0, 1]`` is a ``ValueError`` naming the frame and the
  field; a refused frame changes nothing.
* ROI manager (``gldt_core.schedule.roi.plan_rois``): windows are clipped to the frame
  (``0 <= x1 < x2 <= width``) and each target sits in its group's window; non-finite boxes are a
  ``ValueError``.
* message conversion: compressed image payloads decode or raise ``ImageDecodeError``; ground
  truth survives the ``gldt_msgs/GroundTruthArray`` CDR round trip that bags use.

Example counts are bounded so the whole file runs in a few seconds.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gldt_core.track import ByteTrack, JPTrack, JPTrackConfig

TRACKERS = {"bytetrack": ByteTrack, "jptrack": JPTrack, "jcma-only": lambda: JPTrack(JPTrackConfig(use_pmr=False))}
FIELDS = ("x1", "y1", "x2", "y2", "score")
FUZZ = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])

coordinate = st.floats(min_value=-2000.0, max_value=6000.0, allow_nan=False, allow_infinity=False)
extent = st.floats(min_value=1e-3, max_value=2000.0, allow_nan=False, allow_infinity=False)
score = st.floats(min_value=0.0, max_value=1.0, allow_nan=False)


@st.composite
def detection_frames(draw, max_frames: int = 12, max_boxes: int = 10) -> list[tuple[float, np.ndarray]]:
    """A stream of (dt, detections): arbitrary counts, boxes and scores, strictly increasing time.

    Half the boxes of a frame may be small moves of the previous frame's boxes so the stream
    exercises matching, not only births."""
    frames = []
    previous = np.zeros((0, 5))
    for _ in range(draw(st.integers(1, max_frames))):
        dt = draw(st.floats(min_value=1e-3, max_value=3.0, allow_nan=False))
        rows = []
        for row in previous[: draw(st.integers(0, len(previous)))]:
            dx, dy = draw(st.floats(-30, 30)), draw(st.floats(-30, 30))
            rows.append([row[0] + dx, row[1] + dy, row[2] + dx, row[3] + dy, draw(score)])
        for _ in range(draw(st.integers(0, max_boxes))):
            x, y, w, h = draw(coordinate), draw(coordinate), draw(extent), draw(extent)
            rows.append([x, y, x + w, y + h, draw(score)])
        dets = np.asarray(rows, dtype=np.float64).reshape(-1, 5)
        dets = dets[(dets[:, 2] > dets[:, 0]) & (dets[:, 3] > dets[:, 1])]  # x + w may round back to x
        frames.append((dt, dets))
        previous = dets
    return frames


def _check_tracker_state(tracker) -> None:
    for tr in tracker.tracks:
        assert np.all(np.isfinite(tr.kf.mean)), f"track {tr.track_id}: non-finite Kalman mean"
        assert np.all(np.isfinite(tr.kf.covariance)), f"track {tr.track_id}: non-finite covariance"
        assert np.all(np.diag(tr.kf.covariance) >= 0)
        assert np.allclose(tr.kf.covariance, tr.kf.covariance.T, rtol=1e-6, atol=1e-6 * np.abs(tr.kf.covariance).max())
        assert tr.kf.mean[2] > 0 and tr.kf.mean[3] > 0


@pytest.mark.parametrize("name", list(TRACKERS))
@FUZZ
@given(stream=detection_frames())
def test_any_valid_detection_stream_is_tracked_without_error(name: str, stream) -> None:
    tracker = TRACKERS[name]()
    t = 0.0
    for k, (dt, dets) in enumerate(stream):
        t += dt
        out = tracker.update(dets, t, frame=k)
        assert out.ndim == 2 and out.shape[1] == 6
        assert len(out) <= len(dets), "more tracks reported than detections this frame"
        assert np.all(np.isfinite(out))
        ids = out[:, 4].astype(int)
        assert len(set(ids.tolist())) == len(ids), "an id reported twice in one frame"
        assert np.all(ids >= 1)
        assert np.all(out[:, 2] > out[:, 0]) and np.all(out[:, 3] > out[:, 1])
        predicted = tracker.predict(t + 0.5)
        assert predicted.shape[1] == 5 and np.all(np.isfinite(predicted))
        _check_tracker_state(tracker)


@st.composite
def corrupted_frame(draw):
    """A valid frame of 1..6 boxes with exactly one field of one row made invalid."""
    n = draw(st.integers(1, 6))
    rows = []
    for _ in range(n):
        x, y = draw(st.floats(0, 1800)), draw(st.floats(0, 1000))
        rows.append([x, y, x + draw(st.floats(1, 100)), y + draw(st.floats(1, 100)), draw(score)])
    dets = np.asarray(rows)
    row = draw(st.integers(0, n - 1))
    kind = draw(st.sampled_from(["nan", "inf", "-inf", "zero_width", "negative_height", "score_high", "score_low"]))
    if kind in ("nan", "inf", "-inf"):
        col = draw(st.integers(0, 4))
        dets[row, col] = {"nan": np.nan, "inf": np.inf, "-inf": -np.inf}[kind]
        fields = {FIELDS[col]}
    elif kind == "zero_width":
        dets[row, 2] = dets[row, 0] - draw(st.floats(0, 50))
        fields = {"x2"}
    elif kind == "negative_height":
        dets[row, 3] = dets[row, 1] - draw(st.floats(0.001, 50))
        fields = {"y2"}
    elif kind == "score_high":
        dets[row, 4] = draw(st.floats(min_value=1.0, max_value=1e9, exclude_min=True))
        fields = {"score"}
    else:
        dets[row, 4] = draw(st.floats(min_value=-1e9, max_value=0.0, exclude_max=True))
        fields = {"score"}
    return dets, fields, row


@pytest.mark.parametrize("name", list(TRACKERS))
@FUZZ
@given(case=corrupted_frame(), frame=st.integers(0, 10_000))
def test_invalid_detections_raise_value_error_naming_frame_and_field_and_change_nothing(name, case, frame) -> None:
    dets, fields, row = case
    tracker = TRACKERS[name]()
    good = np.array([[100.0, 100.0, 130.0, 120.0, 0.9], [500.0, 300.0, 520.0, 315.0, 0.8]])
    tracker.update(good, 0.0)
    tracker.update(good + [2, 0, 2, 0, 0], 1 / 30)
    before = [(tr.track_id, tr.state, tr.kf.mean.copy()) for tr in tracker.tracks]
    with pytest.raises(ValueError) as info:
        tracker.update(dets, 2 / 30, frame=frame)
    message = str(info.value)
    assert f"frame {frame}" in message
    assert f"detection {row} field" in message, message  # the corrupted row ...
    assert any(f"field {f}" in message for f in fields), message  # ... and its field are named
    after = [(tr.track_id, tr.state, tr.kf.mean) for tr in tracker.tracks]
    assert [a[:2] for a in after] == [b[:2] for b in before]
    assert all(np.array_equal(a[2], b[2]) for a, b in zip(after, before))
    out = tracker.update(good + [4, 0, 4, 0, 0], 2 / 30)  # the same instant, now valid: accepted
    assert sorted(out[:, 4].astype(int).tolist()) == [1, 2]


@pytest.mark.parametrize("name", list(TRACKERS))
@settings(max_examples=25, deadline=None)
@given(shape=st.sampled_from([(3,), (2, 4), (2, 6), (1, 5, 1), (5, 0)]))
def test_wrong_detection_shapes_are_value_errors(name: str, shape) -> None:
    tracker = TRACKERS[name]()
    dets = np.ones(shape)
    if dets.size == 0:
        assert tracker.update(dets, 0.0).shape == (0, 6)  # empty is an empty frame
        return
    with pytest.raises(ValueError, match="shape"):
        tracker.update(dets, 0.0, frame=3)


# --------------------------------------------------------------------------- ROI manager
@st.composite
def predictions(draw):
    width = draw(st.integers(16, 4000))
    height = draw(st.integers(16, 3000))
    n = draw(st.integers(0, 14))
    boxes = []
    for _ in range(n):
        cx = draw(st.floats(-300, width + 300))
        cy = draw(st.floats(-300, height + 300))
        w, h = draw(st.floats(0.5, 500)), draw(st.floats(0.5, 500))
        boxes.append([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2])
    ids = draw(st.lists(st.integers(0, 10_000), min_size=n, max_size=n, unique=True))
    return np.asarray(boxes, dtype=np.float64).reshape(-1, 4), ids, (width, height)


@st.composite
def roi_params(draw):
    from gldt_core.schedule.roi import RoiParams

    return RoiParams(
        roi_size=draw(st.integers(16, 640)),
        tau_overlap=draw(st.floats(0.0, 1.0)),
        tau_distance=draw(st.floats(1.0, 3000.0)),
        tau_safe=draw(st.floats(0.05, 1.0)),
    )


def _check_layout(layout, boxes: np.ndarray, ids: list[int], frame_size: tuple[int, int]) -> None:
    width, height = frame_size
    rois = layout.rois
    assert rois.dtype.kind == "i" and rois.shape == (len(layout.groups), 4)
    assert np.all(rois[:, 0] >= 0) and np.all(rois[:, 1] >= 0)
    assert np.all(rois[:, 2] <= width) and np.all(rois[:, 3] <= height)
    assert np.all(rois[:, 2] > rois[:, 0]) and np.all(rois[:, 3] > rois[:, 1])
    grouped = [i for group in layout.groups for i in group]
    assert sorted(grouped) == sorted(ids), "every target in exactly one window"
    centre = {i: ((b[0] + b[2]) / 2, (b[1] + b[3]) / 2) for i, b in zip(ids, boxes)}
    for roi, group in zip(rois, layout.groups):
        for i in group:
            cx, cy = centre[i]
            # a centre outside the frame cannot be in a clipped window; clamp it to the frame edge
            cx, cy = min(max(cx, 0.0), width), min(max(cy, 0.0), height)
            assert roi[0] <= cx <= roi[2] and roi[1] <= cy <= roi[3], (
                f"target {i} centre ({cx:.1f}, {cy:.1f}) outside its window {roi.tolist()}"
            )


@settings(max_examples=120, deadline=None)
@given(case=predictions(), params=roi_params(), drift=st.floats(-400, 400))
def test_plan_rois_keeps_windows_in_the_frame_around_every_target(case, params, drift: float) -> None:
    from gldt_core.schedule.roi import plan_rois

    boxes, ids, frame_size = case
    layout = plan_rois(boxes, ids, frame_size, params)
    _check_layout(layout, boxes, ids, frame_size)
    # next frame: targets drift, some vanish; last frame's groups are carried over
    moved = boxes.copy()
    moved[:, [0, 2]] += drift * np.linspace(-1, 1, len(boxes))[:, None] if len(boxes) else 0
    keep = list(range(0, len(boxes), 2)) if len(boxes) > 2 else list(range(len(boxes)))
    kept_ids = [ids[k] for k in keep]
    layout2 = plan_rois(moved[keep], kept_ids, frame_size, params, layout.groups)
    _check_layout(layout2, moved[keep], kept_ids, frame_size)


@settings(max_examples=30, deadline=None)
@given(bad=st.sampled_from([np.nan, np.inf, -np.inf]), position=st.integers(0, 3), n=st.integers(1, 5))
def test_plan_rois_refuses_non_finite_predictions(bad: float, position: int, n: int) -> None:
    from gldt_core.schedule.roi import plan_rois

    boxes = np.tile([100.0, 100.0, 120.0, 110.0], (n, 1)) + np.arange(n)[:, None] * 50
    boxes[n - 1, position] = bad
    with pytest.raises(ValueError, match="NaN or infinite"):
        plan_rois(boxes, list(range(n)), (640, 480))


# --------------------------------------------------------------------------- message conversion
@settings(max_examples=60, deadline=None)
@given(
    data=st.binary(min_size=0, max_size=2048), fmt=st.sampled_from(["jpeg", "png", "", "rgb8; jpeg compressed bgr8"])
)
def test_arbitrary_compressed_payloads_decode_or_raise_image_decode_error(data: bytes, fmt: str) -> None:
    from gldt_core.io.imaging import ImageDecodeError, decode_compressed_image

    try:
        image = decode_compressed_image(data, fmt)
    except ImageDecodeError as error:
        assert str(fmt) in str(error) or "bytes" in str(error)
        return
    assert image.ndim == 3 and image.shape[2] == 3 and image.dtype == np.uint8 and image.size > 0


@settings(max_examples=25, deadline=None)
@given(cut=st.integers(0, 400), flips=st.lists(st.integers(0, 399), max_size=20))
def test_truncated_or_bit_flipped_jpeg_decodes_or_raises_image_decode_error(cut: int, flips: list[int]) -> None:
    import cv2

    from gldt_core.io.imaging import ImageDecodeError, decode_compressed_image

    image = np.zeros((32, 48, 3), np.uint8)
    image[8:24, 10:30] = (30, 200, 90)
    ok, encoded = cv2.imencode(".jpg", image)
    assert ok
    data = bytearray(encoded.tobytes())
    for position in flips:
        if position < len(data):
            data[position] ^= 0x5A
    data = data[: max(0, len(data) - cut)]
    try:
        decoded = decode_compressed_image(bytes(data), "jpeg")
    except ImageDecodeError:
        return
    assert decoded.dtype == np.uint8 and decoded.ndim == 3 and decoded.shape[2] == 3


ground_truth_row = st.tuples(
    st.integers(0, 2**32 - 1),  # id
    st.floats(-5000, 5000),
    st.floats(-5000, 5000),  # x, y (top-left)
    st.floats(0, 3000),
    st.floats(0, 3000),  # w, h
    st.sampled_from([1, 2, 3, 4]),  # class
    st.floats(0.0, 1.0),  # visibility
)


@settings(max_examples=60, deadline=None)
@given(rows=st.lists(ground_truth_row, max_size=12), index=st.integers(0, 10**6), stamp=st.floats(0, 1e5))
def test_ground_truth_survives_the_bag_message_round_trip(rows, index: int, stamp: float) -> None:
    from gldt_core.io import bag
    from gldt_core.io.ros_types import typestore
    from gldt_core.io.sources import Frame

    store = typestore()
    table = np.array(
        [[index + 1, i, x, y, w, h, 1, c, v, -1] for i, x, y, w, h, c, v in rows], dtype=np.float64
    ).reshape(-1, 10)
    frame = Frame(index=index, stamp=stamp, image=np.zeros((1, 1, 3), np.uint8), ground_truth=table)
    message = bag._ground_truth(store, bag._header(store, stamp), frame)
    raw = store.serialize_cdr(message, bag.GROUND_TRUTH_TYPE)
    back = bag._gt_rows(store.deserialize_cdr(raw, bag.GROUND_TRUTH_TYPE))
    assert back.shape == table.shape
    if len(table):
        assert np.array_equal(back[:, [0, 1, 7]], table[:, [0, 1, 7]])
        assert np.allclose(back[:, 2:6], table[:, 2:6], rtol=1e-12, atol=1e-9)
        assert np.allclose(back[:, 8], table[:, 8], atol=1e-6)
