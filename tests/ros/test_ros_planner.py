"""Planner-side fields of /gldt/tracks, their markers and the example threat monitor's choice."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

from gldt_msgs.msg import Track, TrackArray  # noqa: E402

from gldt_core.camera import CameraModel  # noqa: E402
from gldt_core.system.config import SystemConfig  # noqa: E402
from gldt_core.system.gldt_system import build_tracker  # noqa: E402
from gldt_core.track.planner_stream import PlannerStream  # noqa: E402
from gldt_ros.examples.threat_monitor import describe, most_urgent  # noqa: E402
from gldt_ros.interface.track_fields import markers_for, planner_track_to_msg  # noqa: E402

CAMERA = CameraModel.from_fov(1920, 1080, math.radians(90))


def stream_messages(frames: int, camera: CameraModel | None, miss: range = range(0)) -> list[list[Track]]:
    """A target left of the image centre, growing (approaching), through JPTrack and the stream."""
    tracker = build_tracker(SystemConfig(), (1920, 1080))
    stream = PlannerStream()
    out = []
    for index in range(frames):
        t = index / 30.0
        size = 12.0 / (1.0 - t / 6.0)  # TTC 6 s at t = 0, closing at constant speed
        x = 500.0
        dets = np.zeros((0, 5)) if index in miss else np.array([[x, 300.0, x + size, 300.0 + size, 0.9]])
        rows = np.asarray(tracker.update(dets, t), dtype=np.float64).reshape(-1, 6)
        probabilities = np.tile([0.1, 0.85, 0.05], (len(dets), 1))
        entries = stream.step(tracker.tracks, t, rows, dets, probabilities, camera)
        out.append([planner_track_to_msg(entry) for entry in entries])
    return out


def test_messages_carry_line_of_sight_rep103_angles_and_covariance() -> None:
    last = stream_messages(10, CAMERA)[-1][0]
    assert last.bearing_valid and last.state == Track.STATE_CONFIRMED
    ray = np.array(last.line_of_sight)
    assert np.linalg.norm(ray) == pytest.approx(1.0)
    assert ray[0] < 0 and ray[1] < 0 and ray[2] > 0  # left of and above the centre, in front
    assert last.azimuth > 0 and last.elevation > 0  # REP-103: left and up are positive
    assert last.azimuth == pytest.approx(math.atan2(-ray[0], ray[2]))
    covariance = np.array(last.bearing_covariance).reshape(2, 2)
    assert covariance[0, 0] > 0 and covariance[1, 1] > 0
    np.testing.assert_allclose(covariance, covariance.T)
    assert last.class_id == Track.CLASS_BIRD and last.class_confidence == pytest.approx(0.85)


def test_bearing_invalid_without_camera_info() -> None:
    last = stream_messages(5, None)[-1][0]
    assert not last.bearing_valid and list(last.line_of_sight) == [0.0, 0.0, 0.0]


def test_time_to_collision_with_sigma_on_an_approaching_target() -> None:
    frames = stream_messages(90, CAMERA)
    last = frames[-1][0]
    assert last.time_to_collision_valid
    true_ttc = 6.0 - 89 / 30.0
    assert last.time_to_collision == pytest.approx(true_ttc, rel=0.2)
    assert 0 < last.time_to_collision_sigma < last.time_to_collision


def test_a_coasting_track_stays_in_the_messages() -> None:
    frames = stream_messages(30, CAMERA, miss=range(20, 24))
    coasting = frames[22][0]
    assert coasting.state == Track.STATE_LOST and coasting.frames_since_update == 3
    assert coasting.bearing_valid
    assert "coasting 3 frames" in describe(coasting)


def track_message(**fields) -> Track:
    message = Track(state=Track.STATE_CONFIRMED, center_x=960.0, center_y=540.0, width=20.0, height=10.0)
    for name, value in fields.items():
        setattr(message, name, value)
    return message


def test_most_urgent_plans_for_the_pessimistic_time_to_collision() -> None:
    steady = track_message(id=1, time_to_collision_valid=True, time_to_collision=3.0, time_to_collision_sigma=0.1)
    uncertain = track_message(id=2, time_to_collision_valid=True, time_to_collision=4.0, time_to_collision_sigma=1.0)
    assert most_urgent([steady, uncertain]).id == 2  # 4 - 2 x 1 < 3 - 2 x 0.1
    coasting = track_message(
        id=3, state=Track.STATE_LOST, time_to_collision_valid=True, time_to_collision=1.0, time_to_collision_sigma=0.1
    )
    assert most_urgent([steady, uncertain, coasting]).id == 3  # a missed detection is still an obstacle
    removed = track_message(id=4, state=Track.STATE_REMOVED, time_to_collision_valid=True, time_to_collision=0.5)
    assert most_urgent([removed]) is None
    assert "TTC 4.0 +- 1.0 s" in describe(uncertain)
    uncertain.class_id, uncertain.class_confidence = Track.CLASS_BIRD, 0.8
    assert "(bird 0.80)" in describe(uncertain)
    uncertain.class_id = Track.CLASS_UNKNOWN
    assert "(class unknown)" in describe(uncertain)


def test_markers_are_rays_in_the_optical_frame() -> None:
    frames = stream_messages(10, CAMERA)
    array = TrackArray(tracks=frames[-1])
    array.header.frame_id = "camera_optical_frame"
    markers = markers_for(array).markers
    rays = [m for m in markers if m.type == m.ARROW and m.action == m.ADD]
    assert len(rays) == 1 and rays[0].header.frame_id == "camera_optical_frame"
    start, tip = rays[0].points
    assert (start.x, start.y, start.z) == (0.0, 0.0, 0.0)
    direction = np.array([tip.x, tip.y, tip.z])
    np.testing.assert_allclose(direction / np.linalg.norm(direction), frames[-1][0].line_of_sight, atol=1e-9)
    labels = [m for m in markers if m.type == m.TEXT_VIEW_FACING]
    assert labels[0].text.startswith(f"#{frames[-1][0].id}")
    # Without a bearing there is no direction to draw: no pixel coordinates in a metric frame.
    assert [m.action for m in markers_for(TrackArray(tracks=stream_messages(3, None)[-1])).markers] == [
        markers[0].DELETEALL
    ]
