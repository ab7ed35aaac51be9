"""What a node's /diagnostics status says (issue #30): skipped frame pairs and stale drops are
counted in its values and make it WARN when they happen; a node can raise and clear a named WARN
condition (``GldtNode.set_warning``), published at once."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

from diagnostic_msgs.msg import DiagnosticStatus  # noqa: E402
from rclpy.context import Context  # noqa: E402


def values(status: DiagnosticStatus) -> dict[str, str]:
    return {pair.key: pair.value for pair in status.values}


def published(node: Any) -> list[DiagnosticStatus]:
    """Make the node's diagnostics publisher record its statuses instead of sending them."""
    sent: list[DiagnosticStatus] = []
    node._diagnostics.publish = lambda array: sent.extend(array.status)
    return sent


def test_a_named_warning_is_raised_published_at_once_and_cleared(context: Context) -> None:
    from gldt_ros.nodes.mode_scheduler import ModeSchedulerNode

    node = ModeSchedulerNode(context=context)
    try:
        sent = published(node)
        node._publish_diagnostics()
        assert node.diagnostics_status().level == DiagnosticStatus.OK
        node.set_warning("camera_info", "no valid camera_info: bearings invalid")
        node._publish_if_links_changed()  # the next link check (every 0.1 s) sends the change
        assert len(sent) == 2 and sent[-1].level == DiagnosticStatus.WARN
        assert "camera_info: no valid camera_info" in sent[-1].message
        assert values(sent[-1])["warning:camera_info"] == "no valid camera_info: bearings invalid"
        node.set_warning("camera_info", "no valid camera_info: bearings invalid")
        node._publish_if_links_changed()
        assert len(sent) == 2, "raising the same warning again sends nothing"
        node._publish_diagnostics()
        assert sent[-1].level == DiagnosticStatus.WARN, "a warning stays until it is cleared"
        node.set_warning("camera_info", None)
        node._publish_if_links_changed()
        assert sent[-1].level == DiagnosticStatus.OK and sent[-1].message == "ok"
        assert "warning:camera_info" not in values(sent[-1])
    finally:
        node.destroy_node()


def test_stale_drops_are_counted_and_warn(context: Context) -> None:
    from gldt_core.system.stamps import StaleMessage
    from gldt_ros.nodes.mode_scheduler import ModeSchedulerNode

    node = ModeSchedulerNode(context=context)
    try:

        def late(_message: Any) -> None:
            raise StaleMessage("frame 3 stamped 1.000 s arrived after 2.000 s; stale, dropped")

        def bad(_message: Any) -> None:
            raise ValueError("not stale, just bad")

        node.guarded(late, "predictions")(None)
        node.guarded(bad, "predictions")(None)
        status = node.diagnostics_status()
        assert values(status)["stale_dropped"] == "1" and values(status)["dropped"] == "2"
        assert values(status)["pairs_skipped"] == "0"
        assert status.level == DiagnosticStatus.WARN and "1 stale input(s) dropped" in status.message
    finally:
        node.destroy_node()


def test_a_scheduler_counts_the_stale_frames_it_skips_after_a_report_timeout(context: Context) -> None:
    """In lockstep the scheduler waits for a LOCAL frame's detections; when they never come, it
    plans the newest queued frame and drops the ones queued before it as stale."""
    from gldt_msgs.msg import Track, TrackPredictions
    from std_msgs.msg import Header

    from gldt_ros.nodes.mode_scheduler import ModeSchedulerNode

    node = ModeSchedulerNode(
        cli_args=["--ros-args", "-p", "lockstep:=true", "-p", "global_frames:=1", "-p", "report_timeout:=0.1"],
        context=context,
    )
    try:
        sent = published(node)
        node._publish_diagnostics()

        def predictions(index: int) -> TrackPredictions:
            header = Header(frame_id="camera")
            header.stamp.sec, header.stamp.nanosec = 1, index * 33_333_333
            track = Track(id=1, state=Track.STATE_CONFIRMED, center_x=320.0, center_y=200.0, width=12.0, height=8.0)
            # last_tracked_stamp: the tracker did track the awaited frame (it was not given up).
            return TrackPredictions(
                header=header, frame_index=index, width=640, height=512, tracks=[track], last_tracked_stamp=header.stamp
            )

        index = 0
        while node._awaiting_report is None and index < 10:  # GLOBAL until the scheduler goes LOCAL
            node.on_predictions(predictions(index))
            index += 1
        assert node._awaiting_report is not None, "the scheduler never went LOCAL; nothing to time out"
        for later in range(index, index + 3):
            node.on_predictions(predictions(later))
        assert len(node._queue) == 3
        node._awaiting_since -= 1.0  # as if report_timeout had passed
        node._check_report_timeout()
        assert node.events["stale_dropped"] == 2
        status = node.diagnostics_status()
        assert status.level == DiagnosticStatus.WARN and values(status)["stale_dropped"] == "2"
        node._publish_diagnostics()
        node._publish_diagnostics()
        assert sent[-2].level == DiagnosticStatus.WARN, "the period they happened in is WARN"
        assert sent[-1].level == DiagnosticStatus.OK, "a period without any is OK again"
        assert values(sent[-1])["stale_dropped"] == "2", "the total stays in the values"
    finally:
        node.destroy_node()


def test_the_buffer_counts_the_pairs_the_global_detector_skipped(context: Context) -> None:
    """With the planned skip off (every GLOBAL frame's pair is sent), three pairs go out after the
    first; the detector answers only the third (its queue keeps the newest pair): two were skipped."""
    from gldt_msgs.msg import DetectionArray, SchedulerState
    from rclpy.parameter import Parameter
    from std_msgs.msg import Header

    from gldt_ros.interface.convert import bgr_to_image
    from gldt_ros.nodes.frame_pair_buffer import FramePairBuffer

    node = FramePairBuffer(context=context, parameter_overrides=[Parameter("skip_global_when_busy", value=False)])
    try:
        node.pairs.publish = lambda _pair: None
        sent = published(node)
        node._publish_diagnostics()
        images = []
        for index in range(4):
            header = Header(frame_id="camera")
            header.stamp.sec, header.stamp.nanosec = 0, index * 33_333_333
            frame = np.full((240, 320, 3), 180, np.uint8)
            frame[50 + index : 60 + index, 100:110] = 30
            images.append(bgr_to_image(frame, header))
            node.on_image(images[-1])
            node.on_decision(SchedulerState(header=header, frame_index=index, mode=SchedulerState.MODE_GLOBAL))
        node.on_detections(DetectionArray(header=images[0].header, frame_index=0, mode=DetectionArray.MODE_GLOBAL))
        assert node.events["pairs_skipped"] == 0, "the first pair was answered"
        node.on_detections(DetectionArray(header=images[3].header, frame_index=3, mode=DetectionArray.MODE_GLOBAL))
        assert node.events["pairs_skipped"] == 2, "pairs 1 and 2 were never answered"
        node.on_detections(DetectionArray(header=images[3].header, frame_index=3, mode=DetectionArray.MODE_LOCAL))
        assert node.events["pairs_skipped"] == 2, "local answers say nothing about pairs"
        node._publish_diagnostics()
        assert sent[-1].level == DiagnosticStatus.WARN and "2 frame pair(s) skipped" in sent[-1].message
        assert values(sent[-1])["pairs_skipped"] == "2"
        node._publish_diagnostics()
        assert sent[-1].level == DiagnosticStatus.OK
    finally:
        node.destroy_node()


def test_a_decision_for_a_frame_no_longer_buffered_is_a_stale_drop(context: Context) -> None:
    from gldt_msgs.msg import SchedulerState
    from std_msgs.msg import Header

    from gldt_ros.nodes.frame_pair_buffer import FramePairBuffer

    node = FramePairBuffer(context=context)
    try:
        decision = SchedulerState(header=Header(frame_id="camera"), frame_index=42, mode=SchedulerState.MODE_GLOBAL)
        node.guarded(node.on_decision, "decision")(decision)
        assert node.events["stale_dropped"] == 1 and node.frames_dropped == 1
    finally:
        node.destroy_node()


def test_every_timer_of_a_node_runs_on_the_steady_clock_under_sim_time(context: Context) -> None:
    """With use_sim_time and no /clock yet, a ROS-time timer never fires: the diagnostics (and the
    link reports ``pipeline`` waits for) must not depend on it."""
    from rclpy.clock import ClockType

    from gldt_ros.nodes.mode_scheduler import ModeSchedulerNode

    node = ModeSchedulerNode(cli_args=["--ros-args", "-p", "use_sim_time:=true"], context=context)
    try:
        assert node.get_clock().ros_time_is_active, "the node follows /clock"
        assert node.timers and all(timer.clock.clock_type == ClockType.STEADY_TIME for timer in node.timers)
    finally:
        node.destroy_node()
