"""Planner-side fields of /gldt/tracks and the example threat monitor's choice."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

from gldt_msgs.msg import Track, TrackArray  # noqa: E402

from gldt_core.camera import PinholeIntrinsics  # noqa: E402
from gldt_ros.examples.threat_monitor import describe, most_urgent  # noqa: E402
from gldt_ros.interface.track_fields import fill_planner_fields, markers_for  # noqa: E402

INTRINSICS = PinholeIntrinsics.from_fov(1920, 1080, math.radians(90))


def track_message(**fields) -> Track:
    message = Track(state=Track.STATE_CONFIRMED, center_x=960.0, center_y=540.0, width=20.0, height=10.0)
    for name, value in fields.items():
        setattr(message, name, value)
    return message


def test_bearing_fields_follow_camera_geometry() -> None:
    # A target 45 degrees right of the axis on the horizon of a 90-degree camera sits on the right edge.
    message = track_message(center_x=1920.0, velocity_x=0.0, velocity_y=0.0)
    fill_planner_fields(message, SimpleNamespace(mean=np.zeros(8)), INTRINSICS)
    assert message.bearing_valid
    assert message.azimuth == pytest.approx(math.radians(45.0), abs=1e-9)
    assert message.elevation == pytest.approx(0.0, abs=1e-9)


def test_bearing_invalid_without_camera_info() -> None:
    message = track_message()
    fill_planner_fields(message, SimpleNamespace(mean=np.zeros(8)), None)
    assert not message.bearing_valid


def test_time_to_collision_from_growing_box() -> None:
    state = np.zeros(8)
    state[6], state[7] = 2.0, 1.0  # w grows 2 px/s (of 20), h 1 px/s (of 10): 10 % per second
    message = track_message()
    fill_planner_fields(message, SimpleNamespace(mean=state), INTRINSICS)
    assert message.time_to_collision_valid
    assert message.time_to_collision == pytest.approx(10.0, rel=1e-6)
    state[6] = state[7] = -1.0
    receding = track_message()
    fill_planner_fields(receding, SimpleNamespace(mean=state), INTRINSICS)
    assert not receding.time_to_collision_valid


def test_most_urgent_prefers_smallest_time_to_collision() -> None:
    far = track_message(id=1, time_to_collision_valid=True, time_to_collision=9.0)
    near = track_message(id=2, time_to_collision_valid=True, time_to_collision=2.5)
    lost = track_message(id=3, state=Track.STATE_LOST, time_to_collision_valid=True, time_to_collision=0.5)
    urgent = most_urgent([far, near, lost])
    assert urgent is not None and urgent.id == 2
    assert "TTC 2.5 s" in describe(near)
    near.class_id, near.class_confidence = Track.CLASS_BIRD, 0.8
    assert "(bird 0.80)" in describe(near)
    near.class_id = Track.CLASS_UNKNOWN
    assert "(class unknown)" in describe(near)
    assert most_urgent([lost]) is None


def test_markers_have_a_box_and_label_per_track() -> None:
    array = TrackArray(tracks=[track_message(id=4), track_message(id=9)])
    markers = markers_for(array).markers
    assert len(markers) == 1 + 2 * 2
    assert {m.text for m in markers if m.text} == {"#4", "#9"}
