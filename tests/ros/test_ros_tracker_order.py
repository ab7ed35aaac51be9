"""jptrack_tracker answers frames in camera order: the global detector, the local detector and the
buffer's skip notices are three writers, and a notice for frame t+1 can reach the tracker before
the global detector's detections for frame t. Frames are answered in the order they were ticked,
and one whose detections never come is given up after ``input_order_timeout``.

With ``answer_deadline`` set (live), a frame whose detections have not come by then is answered
with predictions at once, and its detections, when they come, still update the tracks."""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import pytest

rclpy = pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

from rclpy.context import Context  # noqa: E402

#: The live tests' answer_deadline [s].
DEADLINE_S = 0.05


def make_tracker(context: Any, deadline_s: float) -> Any:
    from rclpy.parameter import Parameter

    from gldt_ros.nodes.jptrack_tracker import TrackerNode

    node: Any = TrackerNode(
        context=context,
        parameter_overrides=[
            Parameter("input_order_timeout", value=0.2),
            Parameter("answer_deadline", value=deadline_s),
        ],
    )
    node.published = []
    node.track_publisher.publish = node.published.append
    node.prediction_publisher.publish = lambda _message: None
    return node


@pytest.fixture
def context() -> Iterator[Any]:
    context = Context()
    rclpy.init(context=context)
    try:
        yield context
    finally:
        rclpy.shutdown(context=context)


@pytest.fixture
def tracker(context: Any) -> Iterator[Any]:
    """A tracker that waits for every frame's detections (answer_deadline 0, as in lockstep)."""
    node = make_tracker(context, 0.0)
    yield node
    node.destroy_node()


@pytest.fixture
def live_tracker(context: Any) -> Iterator[Any]:
    node = make_tracker(context, DEADLINE_S)
    yield node
    node.destroy_node()


def header(index: int) -> Any:
    from std_msgs.msg import Header

    stamped = Header(frame_id="camera")
    stamped.stamp.sec, stamped.stamp.nanosec = 1, index * 33_333_333
    return stamped


def tick(node: Any, index: int) -> None:
    from gldt_msgs.msg import FrameTick

    node.on_tick(FrameTick(header=header(index), frame_index=index, width=640, height=512))


def detections(index: int, mode: int) -> Any:
    from gldt_msgs.msg import Detection, DetectionArray

    # A drone that speeds up and jitters, so every measurement moves the filter.
    x, y = 100.0 + index * index, 200.0 + (3.0 if index % 2 else -3.0)
    found = [Detection(center_x=x, center_y=y, width=20.0, height=12.0, score=0.9, class_id=1)]
    return DetectionArray(header=header(index), frame_index=index, mode=mode, detections=found if mode != 2 else [])


def test_a_notice_that_overtakes_the_frame_before_it_waits_for_it(tracker: Any) -> None:
    from gldt_msgs.msg import DetectionArray, TrackArray

    for index in range(3):
        tick(tracker, index)
    tracker.on_detections_arrived(detections(0, DetectionArray.MODE_GLOBAL))
    tracker.on_detections_arrived(detections(2, DetectionArray.MODE_SKIPPED))  # overtakes frame 1
    assert [int(a.frame_index) for a in tracker.published] == [0], "frame 2 must wait for frame 1"
    tracker.on_detections_arrived(detections(1, DetectionArray.MODE_GLOBAL))
    assert [int(a.frame_index) for a in tracker.published] == [0, 1, 2]
    assert [int(a.source) for a in tracker.published] == [
        TrackArray.SOURCE_GLOBAL,
        TrackArray.SOURCE_GLOBAL,
        TrackArray.SOURCE_PREDICTED,
    ]
    assert tracker.frames_dropped == 0, "frame 1's detections were not taken for late ones"


def test_a_frame_whose_detections_never_come_is_given_up(tracker: Any) -> None:
    from gldt_msgs.msg import DetectionArray

    for index in range(2):
        tick(tracker, index)
    tracker.on_detections_arrived(detections(1, DetectionArray.MODE_LOCAL))
    assert tracker.published == []
    time.sleep(0.3)  # past input_order_timeout
    tracker._answer_in_order()
    assert [int(a.frame_index) for a in tracker.published] == [1]


def past_deadline(node: Any) -> None:
    time.sleep(DEADLINE_S * 1.5)
    node._answer_in_order()  # what the node's timer does


def answers(node: Any) -> list[tuple[int, int]]:
    return [(int(a.frame_index), int(a.source)) for a in node.published]


def boxes(array: Any) -> list[tuple[int, int, float, float, float, float]]:
    return [(t.id, t.state, t.center_x, t.center_y, t.width, t.height) for t in array.tracks]


def test_a_frame_whose_detections_are_late_is_answered_at_the_deadline(live_tracker: Any) -> None:
    from gldt_msgs.msg import DetectionArray, TrackArray

    tick(live_tracker, 0)
    live_tracker.on_detections_arrived(detections(0, DetectionArray.MODE_GLOBAL))
    tick(live_tracker, 1)
    live_tracker._answer_in_order()
    assert answers(live_tracker) == [(0, TrackArray.SOURCE_GLOBAL)], "answered before its deadline"
    past_deadline(live_tracker)
    assert answers(live_tracker) == [(0, TrackArray.SOURCE_GLOBAL), (1, TrackArray.SOURCE_LATE)]
    live_tracker.on_detections_arrived(detections(1, DetectionArray.MODE_GLOBAL))
    assert len(live_tracker.published) == 2, "a frame answered at the deadline is not answered twice"
    assert live_tracker.frames_dropped == 0, "its late detections were dropped"


def test_late_detections_still_update_the_tracks(context: Any, live_tracker: Any) -> None:
    """Frame 1's detections come after its deadline: frame 2's answer is the one a tracker that
    waited for them gives (same ids, states and boxes), and frame 1's answer was its prediction."""
    from gldt_msgs.msg import DetectionArray, TrackArray

    waited = make_tracker(context, 0.0)
    try:
        for index in range(6):
            tick(waited, index)
            waited.on_detections_arrived(detections(index, DetectionArray.MODE_GLOBAL))
        for index in range(6):
            tick(live_tracker, index)
            if index == 3:
                past_deadline(live_tracker)
            live_tracker.on_detections_arrived(detections(index, DetectionArray.MODE_GLOBAL))
        assert [source for _, source in answers(live_tracker)] == [TrackArray.SOURCE_GLOBAL] * 3 + [
            TrackArray.SOURCE_LATE
        ] + [TrackArray.SOURCE_GLOBAL] * 2
        assert live_tracker.published[3].tracks, "the late frame's answer holds the tracks' predictions"
        for frame in (4, 5):
            assert boxes(live_tracker.published[frame]) == boxes(waited.published[frame]), f"frame {frame}"
    finally:
        waited.destroy_node()


def test_frames_behind_a_late_one_are_answered_at_their_deadline_in_order(live_tracker: Any) -> None:
    from gldt_msgs.msg import DetectionArray, TrackArray

    for index in range(3):
        tick(live_tracker, index)
    live_tracker.on_detections_arrived(detections(0, DetectionArray.MODE_GLOBAL))
    live_tracker.on_detections_arrived(detections(2, DetectionArray.MODE_LOCAL))  # waits behind frame 1
    assert answers(live_tracker) == [(0, TrackArray.SOURCE_GLOBAL)]
    past_deadline(live_tracker)
    assert answers(live_tracker) == [
        (0, TrackArray.SOURCE_GLOBAL),
        (1, TrackArray.SOURCE_LATE),
        (2, TrackArray.SOURCE_LATE),
    ]
    live_tracker.on_detections_arrived(detections(1, DetectionArray.MODE_SKIPPED))
    tick(live_tracker, 3)
    live_tracker.on_detections_arrived(detections(3, DetectionArray.MODE_LOCAL))
    assert answers(live_tracker)[3:] == [(3, TrackArray.SOURCE_LOCAL)], "one answer per frame, in order"
    assert live_tracker.frames_dropped == 0


def test_the_warm_up_frame_is_not_answered_at_the_deadline(live_tracker: Any) -> None:
    """Start-up: the first inference of each model may take seconds; the warm-up frame waits for it."""
    from gldt_msgs.msg import DetectionArray, FrameTick, TrackArray

    from gldt_ros.interface.graph import WARM_UP_FRAME_ID

    warm = header(0)
    warm.frame_id = WARM_UP_FRAME_ID
    live_tracker.on_tick(FrameTick(header=warm, frame_index=0, width=640, height=512))
    past_deadline(live_tracker)
    assert live_tracker.published == []
    live_tracker.on_detections_arrived(DetectionArray(header=warm, frame_index=0, mode=DetectionArray.MODE_GLOBAL))
    assert answers(live_tracker) == [(0, TrackArray.SOURCE_GLOBAL)]


@pytest.mark.parametrize("kind", ["events", "single"])
def test_the_node_answers_at_the_deadline_by_itself(live_tracker: Any, kind: str) -> None:
    """The deadline timer, spun by either executor a node process may spin, answers a frame whose
    detections never come: not before its deadline, and before the order timeout would give it up."""
    from gldt_msgs.msg import TrackArray
    from rclpy.executors import SingleThreadedExecutor

    if kind == "events":
        EventsExecutor = pytest.importorskip("rclpy.experimental", reason="rclpy >= 7.1.4").EventsExecutor
    else:
        EventsExecutor = None

    answered_at: list[float] = []
    live_tracker.track_publisher.publish = lambda array: (
        answered_at.append(time.monotonic()),
        live_tracker.published.append(array),
    )
    executor = (EventsExecutor or SingleThreadedExecutor)(context=live_tracker.context)
    executor.add_node(live_tracker)
    live_tracker._order_timer.cancel()  # the deadline timer alone
    try:
        ticked = time.monotonic()
        tick(live_tracker, 0)
        while not live_tracker.published and time.monotonic() - ticked < 0.15:  # the order timeout: 0.2 s
            executor.spin_once(timeout_sec=0.01)
        assert answers(live_tracker) == [(0, TrackArray.SOURCE_LATE)]
        assert answered_at[0] - ticked >= DEADLINE_S
    finally:
        executor.shutdown()


def test_the_deadline_counts_from_the_capture_when_the_stamp_is_on_the_nodes_clock(live_tracker: Any) -> None:
    """A frame stamped a deadline ago on the node's clock (it waited on its way to the tracker) is
    due when its tick comes; one stamped on another clock (far in the past, or ahead) counts from
    its tick."""
    from gldt_msgs.msg import FrameTick, TrackArray

    now_ns = live_tracker.get_clock().now().nanoseconds
    stamps = {0: now_ns - 10**10, 1: now_ns - int(DEADLINE_S * 1.2e9), 2: now_ns + 10**9}
    for index, stamp_ns in stamps.items():
        stamped = header(index)
        stamped.stamp.sec, stamped.stamp.nanosec = divmod(stamp_ns, 10**9)
        live_tracker.on_tick(FrameTick(header=stamped, frame_index=index, width=640, height=512))
        live_tracker._answer_in_order()
        if index == 0:
            past_deadline(live_tracker)  # another clock: from its tick on
    assert answers(live_tracker) == [(0, TrackArray.SOURCE_LATE), (1, TrackArray.SOURCE_LATE)]
    past_deadline(live_tracker)
    assert answers(live_tracker)[2:] == [(2, TrackArray.SOURCE_LATE)]


def test_the_deadline_timer_is_never_cancelled(live_tracker: Any) -> None:
    """rclpy's Python executors take a timer they found ready after running other callbacks; one
    cancelled meanwhile (say by a frame's detections arriving) raises in their spin thread. With
    nothing left to wait for, the timer is pushed out instead, and calling it still works."""
    from gldt_msgs.msg import DetectionArray

    timer = live_tracker._deadline_timer
    tick(live_tracker, 0)
    live_tracker.on_detections_arrived(detections(0, DetectionArray.MODE_GLOBAL))  # nothing waits now
    assert not timer.is_canceled()
    assert timer.time_until_next_call() > 10**9 * 60
    with timer.handle:
        timer.handle.call_timer()  # what the executor does with a timer it found ready


def test_detections_of_a_frame_given_up_after_its_deadline_answer_are_not_answered_again(live_tracker: Any) -> None:
    """Frames answered at the deadline, then given up at input_order_timeout: when their
    detections come at last, they update the tracker but publish nothing."""
    from gldt_msgs.msg import DetectionArray, TrackArray

    for index in range(3):
        tick(live_tracker, index)
    past_deadline(live_tracker)
    time.sleep(0.25)  # past input_order_timeout (0.2 s): given up
    live_tracker._answer_in_order()
    assert live_tracker._pending == {}
    for index in range(3):
        live_tracker.on_detections_arrived(detections(index, DetectionArray.MODE_GLOBAL))
    assert answers(live_tracker) == [(index, TrackArray.SOURCE_LATE) for index in range(3)]
    assert live_tracker.tracker.tracks, "their detections still reached the tracker"
    tick(live_tracker, 3)
    live_tracker.on_detections_arrived(detections(3, DetectionArray.MODE_GLOBAL))
    assert answers(live_tracker)[3:] == [(3, TrackArray.SOURCE_GLOBAL)]


def test_a_skip_notice_answered_before_its_tick_leaves_no_frame_waiting(live_tracker: Any) -> None:
    """The notice for frame 1 overtakes frame 1's tick and is answered at once; the tick that
    follows must not open a second wait for frame 1 (later frames would be answered late)."""
    from gldt_msgs.msg import DetectionArray, TrackArray

    tick(live_tracker, 0)
    live_tracker.on_detections_arrived(detections(0, DetectionArray.MODE_GLOBAL))
    live_tracker.on_detections_arrived(detections(1, DetectionArray.MODE_SKIPPED))
    tick(live_tracker, 1)
    tick(live_tracker, 2)
    live_tracker.on_detections_arrived(detections(2, DetectionArray.MODE_GLOBAL))
    assert answers(live_tracker) == [
        (0, TrackArray.SOURCE_GLOBAL),
        (1, TrackArray.SOURCE_PREDICTED),
        (2, TrackArray.SOURCE_GLOBAL),
    ]
    assert live_tracker._pending == {}


def test_the_deadline_timer_waits_for_the_frame_the_answers_wait_on(live_tracker: Any) -> None:
    """Behind the warm-up frame (no deadline) the timer is not armed to fire at once, again and
    again, for the frames queued after it."""
    from gldt_msgs.msg import FrameTick

    from gldt_ros.interface.graph import WARM_UP_FRAME_ID

    warm = header(0)
    warm.frame_id = WARM_UP_FRAME_ID
    live_tracker.on_tick(FrameTick(header=warm, frame_index=0, width=640, height=512))
    tick(live_tracker, 1)
    past_deadline(live_tracker)
    assert live_tracker.published == [], "nothing is answered past the warm-up frame"
    assert live_tracker._deadline_timer.time_until_next_call() > 10**9 * 60


def restarted_header(index: int) -> Any:
    """Frame ``index``'s header in a stream that restarted at frame 5 with its clock back at 0 s."""
    stamped = header(index)
    stamped.stamp.sec, stamped.stamp.nanosec = 0, (index - 5) * 33_333_333
    return stamped


@pytest.mark.parametrize("deadline_s", [0.0, DEADLINE_S])
def test_an_earlier_streams_late_detections_do_not_reach_the_restarted_one(context: Any, deadline_s: float) -> None:
    """The camera's time goes back at frame 5 (a bag played again, a driver restarted) while the
    detections of frames 3 and 4 of the stream before are still on their way. When they come they
    are dropped: they neither update the restarted stream's tracks nor answer a frame, and every
    frame of the new stream is answered once, in order (the tracks of the stream before close
    with REMOVED)."""
    from gldt_msgs.msg import DetectionArray, FrameTick, Track, TrackArray

    node = make_tracker(context, deadline_s)
    try:
        for index in range(5):
            tick(node, index)
        for index in range(3):
            node.on_detections_arrived(detections(index, DetectionArray.MODE_GLOBAL))
        node.published.clear()
        for index in range(5, 8):
            node.on_tick(FrameTick(header=restarted_header(index), frame_index=index, width=640, height=512))
        for index in (3, 4):  # the stream before: stamped 1.1 and 1.13 s, ahead of every new tick
            node.on_detections_arrived(detections(index, DetectionArray.MODE_GLOBAL))
        for index in range(5, 10):
            if index >= 8:
                node.on_tick(FrameTick(header=restarted_header(index), frame_index=index, width=640, height=512))
            late = detections(index, DetectionArray.MODE_GLOBAL)
            late.header = restarted_header(index)
            late.detections[0].center_x = 500.0 + index  # far from where frames 0-4 had it
            node.on_detections_arrived(late)
        assert answers(node) == [(index, TrackArray.SOURCE_GLOBAL) for index in range(5, 10)]
        live = [track for array in node.published for track in array.tracks if track.state != Track.STATE_REMOVED]
        assert live and all(track.center_x > 400.0 for track in live), "the stream before moved a track"
        assert node._pending == {}
        assert node.events["stale_dropped"] == 2
    finally:
        node.destroy_node()


def test_a_deadline_past_the_order_timeout_is_refused(context: Any) -> None:
    with pytest.raises(ValueError, match="answer_deadline"):
        make_tracker(context, 0.3)  # input_order_timeout is 0.2 s


def test_a_deadline_from_arrival_ignores_the_stamp(context: Any) -> None:
    """A replay at another rate keeps the bag's pace in the stamps: pipeline counts from arrival."""
    from rclpy.parameter import Parameter

    from gldt_ros.nodes.jptrack_tracker import TrackerNode

    node: Any = TrackerNode(
        context=context,
        parameter_overrides=[
            Parameter("input_order_timeout", value=0.2),
            Parameter("answer_deadline", value=DEADLINE_S),
            Parameter("answer_deadline_from", value="arrival"),
        ],
    )
    try:
        stamp_ns = node.get_clock().now().nanoseconds - int(DEADLINE_S * 1.5e9)  # "captured" past its deadline
        before = time.monotonic()
        assert node.frame_since(stamp_ns) >= before
    finally:
        node.destroy_node()


def test_pipeline_counts_the_deadline_from_arrival_at_another_rate() -> None:
    from gldt_core.paths import REPO_ROOT
    from gldt_ros.launcher.pipeline import node_ros_args, parse_args

    bag = str(REPO_ROOT / "bags" / "halmstad_v_drone_001")
    at_rate_2 = node_ros_args("jptrack_tracker", parse_args(["--bag", bag, "--rate", "2"]))
    assert "answer_deadline_from:=arrival" in at_rate_2
    assert "answer_deadline_from:=arrival" not in node_ros_args("jptrack_tracker", parse_args(["--bag", bag]))
