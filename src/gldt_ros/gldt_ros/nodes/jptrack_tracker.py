"""jptrack_tracker: JPTrack on the detections of each frame, publishing ``/gldt/tracks``.

Besides the tracks it answers every ``FrameTick`` with the Kalman predictions of the tracks
worth an ROI at that frame's time (``TrackPredictions`` for the mode scheduler), using the same
core function as the offline GL-DT system.

``/gldt/tracks`` is the planner's stream (:class:`gldt_core.track.planner_stream.PlannerStream`):
every live track in every frame, coasting ones included, each id closed by one ``REMOVED`` entry,
with its class and a filtered time to collision; with a usable ``/camera/camera_info`` also its
line of sight, REP-103 bearing and bearing covariance. Until then (or after a camera_info that
cannot be used) the node's diagnostics say WARN and bearings are marked invalid; tracks flow.

A frame that ``frame_pair_buffer`` skipped (``DetectionArray.MODE_SKIPPED``: the global detector
was still busy; ``MODE_UNREADABLE``: the image could not be decoded) is answered too, with every
track at its prediction (``TrackArray.SOURCE_PREDICTED`` / ``SOURCE_UNREADABLE``); the tracker is
not updated, so a skip is never a miss.

Every frame is answered within ``answer_deadline`` of its capture (its stamp's age on this node's
clock; of its tick where the stamp is on another clock, or with ``answer_deadline_from:
arrival``), exactly once and in camera order: a frame whose
detections have not come by then (the global detector ran long on a busy CPU, or an earlier frame's
detections still hold it back) is answered with the tracks' predictions
(``TrackArray.SOURCE_LATE``), and its detections, when they come, still update the tracks in camera
order, without a second answer; the next frame's answer shows their effect. Lockstep replays wait
instead (``answer_deadline: 0``). Such frames are counted in the diagnostics (``frames_late``).

Frame ticks whose stamp does not advance (a camera or bag that went back in time, or repeated a
stamp) re-initialise the tracker, as the offline system does; the detections of the stream before
that are still on their way (numbered before the restart, stamped ahead of the new stream's ticks)
are then dropped as stale, so they neither move the new stream's tracks nor answer one of its
frames. The warm-up frame leaves the tracker as it found it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from gldt_msgs.msg import DetectionArray, FrameTick, TrackArray, TrackPredictions
from sensor_msgs.msg import CameraInfo
from std_msgs.msg import Header
from visualization_msgs.msg import MarkerArray

from gldt_core.camera import CameraModel
from gldt_core.system.config import SystemConfig, TrackerSettings
from gldt_core.system.gldt_system import accepts_keyword, build_tracker
from gldt_core.system.stamps import StaleMessage, StampOrder
from gldt_core.system.steps import stable_predictions
from gldt_core.track.planner_stream import PlannerStream, PlannerTrack
from gldt_ros.interface import qos, topics
from gldt_ros.interface.convert import (
    detection_array_class_probabilities,
    detection_array_to_tracker_input,
    msgs_to_rois,
    stamp_nanoseconds,
    stamp_seconds,
    track_to_msg,
)
from gldt_ros.interface.graph import WARM_UP_FRAME_ID
from gldt_ros.interface.track_fields import markers_for, planner_track_to_msg
from gldt_ros.runtime.node_base import GldtNode, run_node

#: Frames waiting for their detections at most (the oldest is given up beyond it).
PENDING_LIMIT = 64
#: How often a frame that waits for an earlier one's detections is checked against ``input_order_timeout``.
ORDER_CHECK_PERIOD_S = 0.1
#: Shortest wait the deadline timer is armed for [s] (a frame already due is answered at once).
DEADLINE_TIMER_MIN_S = 0.0005
#: The deadline timer's period while no frame waits [s]. It is pushed this far out rather than
#: cancelled: rclpy's Python executors raise in their spin thread when a timer they found ready is
#: cancelled by another callback before they call it.
DEADLINE_TIMER_IDLE_S = 3600.0
#: Oldest age [s] of a frame's stamp, on this node's clock when its tick comes, taken as the time
#: since its capture; a stamp older, or ahead of the clock, is on another clock (a camera's own, a
#: bag's), and the frame's deadline counts from its tick instead.
STAMP_AGE_TRUSTED_S = 1.0

#: Skip notices (no detector ran) -> the source of the predicted TrackArray that answers them.
PREDICTED_SOURCE = {
    DetectionArray.MODE_SKIPPED: TrackArray.SOURCE_PREDICTED,
    DetectionArray.MODE_UNREADABLE: TrackArray.SOURCE_UNREADABLE,
}

#: The diagnostics condition raised while bearings cannot be computed.
CAMERA_INFO_WARNING = "camera_info"
#: Diagnostics counter: frames answered by prediction at ``answer_deadline``.
FRAMES_LATE = "frames_late"


@dataclass
class PendingFrame:
    """A frame ticked (or whose detections came first) and not processed yet."""

    header: Header
    frame_index: int
    since: float  # monotonic time it was captured, its deadline's origin (TrackerNode.frame_since)
    arrived: float  # monotonic time its tick (or its detections) came, the order timeout's origin
    message: DetectionArray | None = None  # its detections (or skip notice), once they came
    answered: bool = False  # published already (by prediction at the deadline, or long ago)


@dataclass(frozen=True)
class StreamRestart:
    """Where the camera's time went back: the new stream's first frame index and the newest
    stamp [ns] ticked in the stream before, whose late detections are told apart by these two."""

    first_index: int
    earlier_newest_ns: int

    def left_over(self, frame_index: int, stamp_ns: int, newest_tick_ns: int) -> bool:
        """Whether detections for (``frame_index``, ``stamp_ns``) belong to the stream before: numbered
        before the restart and stamped where the earlier stream was, ahead of the new stream's
        ticks (detections may overtake their own tick, but not with an earlier number)."""
        return frame_index < self.first_index and newest_tick_ns < stamp_ns <= self.earlier_newest_ns


class TrackerNode(GldtNode):
    def __init__(self, **kwargs: Any) -> None:
        super().__init__("jptrack_tracker", **kwargs)
        self.config = SystemConfig(
            tracker=TrackerSettings(name=self.param("tracker")), track_lost_frames=int(self.param("lost_frames_kept"))
        )
        self.tracker = build_tracker(self.config)
        self.stream = PlannerStream()
        self._takes_rois = accepts_keyword(self.tracker.update, "rois")
        self._frame_size: tuple[int, int] | None = None
        self.camera: CameraModel | None = None
        self.set_warning(CAMERA_INFO_WARNING, "no camera_info received yet: bearings invalid")
        self._order = StampOrder()
        self._last_tick_stamp: float | None = None
        self._newest_tick_ns = -1  # the newest tick's stamp in this stream
        self._restart: StreamRestart | None = None  # the last time the stream went back, while it matters
        self._last_tracked_stamp = Time()  # zero: nothing tracked yet
        # Frames ticked (or announced) and not processed yet, by header stamp [ns]: processed and
        # answered strictly in stamp order.
        self._pending: dict[int, PendingFrame] = {}
        self.order_timeout_s = float(self.param("input_order_timeout"))
        self.answer_deadline_s = float(self.param("answer_deadline"))
        self.deadline_from_capture = self.param("answer_deadline_from") == "capture"
        if 0 < self.answer_deadline_s >= self.order_timeout_s:
            raise ValueError(
                f"answer_deadline ({self.answer_deadline_s:g} s) must be below input_order_timeout "
                f"({self.order_timeout_s:g} s), or 0: a frame would be given up before its deadline"
            )
        # The stamp of the newest frame answered in this stream: a frame at or before it is never
        # answered again (its tick or detections may still come: given up, or overtaken).
        self._answered_through = -1
        self._process = self.guarded(self.process_frame, "detections")
        self._drop_left_over = self.guarded(self._refuse_left_over, "detections")
        self.create_subscription(DetectionArray, topics.DETECTIONS, self.on_detections_arrived, qos.RELIABLE)
        self._order_timer = self.create_timer(ORDER_CHECK_PERIOD_S, self._answer_in_order)
        # A timer armed for the next waiting frame's deadline (no polling while none waits).
        self._deadline_timer = None
        if self.answer_deadline_s > 0:
            self._deadline_timer = self.create_timer(DEADLINE_TIMER_IDLE_S, self._answer_in_order)
        self.create_subscription(FrameTick, topics.FRAME_TICKS, self.guarded(self.on_tick, "frame tick"), qos.RELIABLE)
        self.create_subscription(
            CameraInfo,
            topics.CAMERA_INFO,
            self.guarded(self.on_camera_info, "camera_info"),
            qos.camera_qos(self.param("camera_qos")),
        )
        self.track_publisher = self.create_publisher(TrackArray, topics.TRACKS, qos.RELIABLE)
        self.prediction_publisher = self.create_publisher(TrackPredictions, topics.TRACK_PREDICTIONS, qos.RELIABLE)
        self.marker_publisher = self.create_publisher(MarkerArray, topics.TRACK_MARKERS, qos.RELIABLE)

    def on_camera_info(self, message: CameraInfo) -> None:
        try:
            camera = CameraModel.from_camera_info(message.k, message.d, message.distortion_model)
        except ValueError as error:
            self.camera = None
            text = f"camera_info ignored, bearings invalid until a usable one arrives: {error}"
            self.set_warning(CAMERA_INFO_WARNING, text)
            raise ValueError(text) from None
        if camera != self.camera:
            self.camera = camera
            self.set_warning(CAMERA_INFO_WARNING, None)

    def on_tick(self, tick: FrameTick) -> None:
        t = stamp_seconds(tick.header.stamp)
        size = (int(tick.width), int(tick.height))
        if size != self._frame_size:
            # Distance costs are normalised by the image size, as GLDTSystem does per stream.
            if self._frame_size is not None:
                self.get_logger().warning(f"frame size changed to {size[0]}x{size[1]}; tracker re-initialised")
            self.tracker = build_tracker(self.config, size)
            self.stream.restart()
            self._frame_size = size
            self._order.forget()
        elif self._last_tick_stamp is not None and t <= self._last_tick_stamp:
            # Ticks come from one writer, in camera order: this is the camera's time, not a late message.
            self.get_logger().warning(
                f"frame {tick.frame_index}: time did not advance ({self._last_tick_stamp:.3f} s -> {t:.3f} s); "
                "tracker re-initialised"
            )
            self.tracker.reset()
            self.stream.restart()
            self._order.forget()
            earlier_newest = max([self._newest_tick_ns, *self._pending])
            self._restart = StreamRestart(int(tick.frame_index), earlier_newest)
            self._pending.clear()
            self._answered_through = -1
            self._newest_tick_ns = -1
        self._last_tick_stamp = t
        self._check_time(t, tick.frame_index)
        stamp = stamp_nanoseconds(tick.header.stamp)
        self._newest_tick_ns = max(self._newest_tick_ns, stamp)
        if self._restart is not None and stamp > self._restart.earlier_newest_ns:
            self._restart = None  # the new stream is past every stamp of the one before
        # (Its detections may have overtaken it; a skip notice may even have been answered already.)
        if stamp not in self._pending and stamp > self._answered_through:
            self._pending[stamp] = PendingFrame(
                tick.header, int(tick.frame_index), self.frame_since(stamp), time.monotonic()
            )
        while len(self._pending) > PENDING_LIMIT:
            del self._pending[min(self._pending)]
        if self._deadline_timer is not None:
            self._arm_deadline_timer(self._first_unanswered())
        predictions = stable_predictions(self.tracker, t, self.config.lost_frames_kept)
        by_id = {int(track.track_id): track for track in self.tracker.tracks}
        messages = []
        for x1, y1, x2, y2, track_id in predictions:
            message = track_to_msg(by_id[int(track_id)])
            message.center_x, message.center_y = (x1 + x2) / 2, (y1 + y2) / 2
            message.width, message.height = x2 - x1, y2 - y1
            messages.append(message)
        self.prediction_publisher.publish(
            TrackPredictions(
                header=tick.header,
                frame_index=tick.frame_index,
                width=tick.width,
                height=tick.height,
                tracks=messages,
                last_tracked_stamp=self._last_tracked_stamp,
            )
        )

    def frame_since(self, stamp_ns: int) -> float:
        """The monotonic time a frame stamped ``stamp_ns`` was captured, which its ``answer_deadline``
        counts from: now less its stamp's age on this node's clock, when that age is plausible
        (:data:`STAMP_AGE_TRUSTED_S`; the frame may have waited behind others on its way here),
        else now, its tick's arrival; always now with ``answer_deadline_from: arrival`` (a replay
        whose stamps keep the bag's pace at another rate)."""
        now = time.monotonic()
        if not self.deadline_from_capture:
            return now
        age = (self.get_clock().now().nanoseconds - stamp_ns) / 1e9
        return now - age if 0.0 <= age <= STAMP_AGE_TRUSTED_S else now

    def _check_time(self, t: float, frame_index: int) -> None:
        """Drop late messages (StaleMessage: logged and counted by ``guarded``); reset the tracker
        when the stream really restarted (:class:`gldt_core.system.stamps.StampOrder`)."""
        last = self._order.last_stamp
        if self._order.check(t, frame_index):
            self.get_logger().warning(
                f"frame {frame_index}: stream restarted ({last:.3f} s -> {t:.3f} s); tracker reset"
            )
            self.tracker.reset()
            self.stream.restart()

    def on_detections_arrived(self, message: DetectionArray) -> None:
        """Detections (or a skip notice) for a frame: processed once every earlier frame ticked
        has been (the global detector, the local detector and the buffer's notices are three
        writers, and one can overtake another), or at once for a frame no earlier one waits for."""
        stamp = stamp_nanoseconds(message.header.stamp)
        restart = self._restart
        if restart is not None and restart.left_over(int(message.frame_index), stamp, self._newest_tick_ns):
            self._drop_left_over(message)
            return
        frame = self._pending.get(stamp)
        if frame is None:
            # Before its tick, or after the frame was answered and let go (given up, evicted): then
            # its detections may still update the tracker, in their turn, but it is not answered again.
            frame = PendingFrame(
                message.header,
                int(message.frame_index),
                self.frame_since(stamp),
                time.monotonic(),
                answered=stamp <= self._answered_through,
            )
            self._pending[stamp] = frame
        frame.message = message
        self._answer_in_order()

    def _refuse_left_over(self, message: DetectionArray) -> None:
        """Raise the :class:`StaleMessage` that ``guarded`` logs and counts for detections of the
        stream before the last restart (:meth:`StreamRestart.left_over`)."""
        raise StaleMessage(
            f"frame {message.frame_index} stamped {stamp_seconds(message.header.stamp):.3f} s belongs to the "
            "stream before the camera's time went back; stale, dropped"
        )

    def _answer_in_order(self) -> None:
        """Process the pending frames' detections in stamp order, up to the first frame still
        without them; one that waited ``input_order_timeout`` is given up (a detector restarted, or
        its queue dropped the pair) and no longer holds the later ones back. Then answer by
        prediction, in stamp order, the frames still waiting ``answer_deadline`` after their capture."""
        now = time.monotonic()
        while self._pending:
            stamp = min(self._pending)
            frame = self._pending[stamp]
            if frame.message is None:
                if now - frame.arrived < self.order_timeout_s:
                    break
                self.warn_throttled("order timeout", f"no detections for the frame stamped {stamp} ns; answering on")
            del self._pending[stamp]
            if frame.message is not None:
                self._process(frame)
        if self._deadline_timer is None:
            return
        waiting = None  # the first frame still unanswered once the due ones are
        for stamp in sorted(self._pending):
            frame = self._pending[stamp]
            if frame.answered:
                continue
            if frame.header.frame_id == WARM_UP_FRAME_ID or now - frame.since < self.answer_deadline_s:
                waiting = frame
                break  # the later ones were captured later still (the warm-up frame waits: it is start-up)
            frame.answered = True
            self.count_event(FRAMES_LATE)
            t = stamp_seconds(frame.header.stamp)
            late = DetectionArray(header=frame.header, frame_index=frame.frame_index, mode=DetectionArray.MODE_SKIPPED)
            self._publish(late, TrackArray.SOURCE_LATE, self.stream.predicted(self.tracker.tracks, t, self.camera))
        self._arm_deadline_timer(waiting)

    def _first_unanswered(self) -> PendingFrame | None:
        """The pending frame the answers wait on: the first unanswered one in stamp order."""
        return next((frame for _, frame in sorted(self._pending.items()) if not frame.answered), None)

    def _arm_deadline_timer(self, first: PendingFrame | None) -> None:
        """Arm the deadline timer for ``first``, the frame the answers wait on
        (:meth:`_first_unanswered`), or push it out of the way when none waits (or the warm-up
        frame, which has no deadline, holds the others back)."""
        timer = self._deadline_timer
        if timer is None:
            return
        if first is not None and first.header.frame_id != WARM_UP_FRAME_ID:
            remaining = max(first.since + self.answer_deadline_s - time.monotonic(), DEADLINE_TIMER_MIN_S)
        else:
            remaining = DEADLINE_TIMER_IDLE_S
        timer.timer_period_ns = int(remaining * 1e9)
        timer.reset()

    def process_frame(self, frame: PendingFrame) -> None:
        """Process a pending frame's detections, in its turn (``guarded``, as a callback is)."""
        if frame.message is not None:
            self.on_detections(frame.message, answered=frame.answered)

    def on_detections(self, message: DetectionArray, answered: bool = False) -> None:
        """Update the tracker with a frame's detections and answer it (with predictions for a
        skip notice); a frame ``answered`` already at the deadline only updates the tracker."""
        t = stamp_seconds(message.header.stamp)
        self._check_time(t, message.frame_index)
        if answered and message.mode in PREDICTED_SOURCE:
            return  # answered by prediction already, and a notice updates nothing
        if message.mode in PREDICTED_SOURCE:
            # Not accepted as the newest stamp: an earlier frame's detections still coming count.
            predicted = self.stream.predicted(self.tracker.tracks, t, self.camera)
            self._publish(message, PREDICTED_SOURCE[message.mode], predicted)
            return
        self._order.accept(t)
        detections = detection_array_to_tracker_input(message)
        if self._takes_rois:
            # PMR's x_rel / y_rel features are relative to the ROI a detection came from.
            rois = msgs_to_rois(message.rois).astype(np.float64)
            detection_rois = rois[[d.roi_index for d in message.detections]] if len(rois) else None
            output = self.tracker.update(detections, t, rois=detection_rois)
        else:
            output = self.tracker.update(detections, t)
        rows = np.asarray(output, dtype=np.float64).reshape(-1, 6)
        if answered:
            self.stream.absorb(rows, detections, detection_array_class_probabilities(message))
            return
        entries = self.stream.step(
            self.tracker.tracks,
            t,
            rows,
            detections,
            detection_array_class_probabilities(message),
            self.camera,
            source=int(message.mode),
        )
        source = TrackArray.SOURCE_LOCAL if message.mode == DetectionArray.MODE_LOCAL else TrackArray.SOURCE_GLOBAL
        self._publish(message, source, entries)

    def _publish(self, message: DetectionArray, source: int, entries: list[PlannerTrack]) -> None:
        """Publish the frame's planner entries (and markers) as the answer to ``message``'s frame."""
        tracks = [planner_track_to_msg(entry) for entry in entries]
        array = TrackArray(header=message.header, frame_index=message.frame_index, source=source, tracks=tracks)
        self._last_tracked_stamp = message.header.stamp
        self._answered_through = max(self._answered_through, stamp_nanoseconds(message.header.stamp))
        self.track_publisher.publish(array)
        if bool(self.param("publish_markers")) and self.marker_publisher.get_subscription_count() > 0:
            self.marker_publisher.publish(markers_for(array))
        if message.header.frame_id == WARM_UP_FRAME_ID:  # it leaves no state behind
            self.tracker.reset()
            self.stream = PlannerStream()
            self._order.forget()
            self._last_tick_stamp = None
            self._newest_tick_ns = -1
            self._restart = None
            self._last_tracked_stamp = Time()
            self._pending.clear()
            self._answered_through = -1


def create_node(cli_args: list[str] | None = None) -> TrackerNode:
    return TrackerNode(cli_args=cli_args)


def main() -> int:
    return run_node(create_node)


if __name__ == "__main__":
    raise SystemExit(main())
