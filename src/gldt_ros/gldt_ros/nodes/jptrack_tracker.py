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
not updated, so a skip is never a miss. Frame ticks whose stamp does not advance (a camera or bag
that went back in time, or repeated a stamp) re-initialise the tracker, as the offline system
does, and the warm-up frame leaves the tracker as it found it.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from gldt_msgs.msg import DetectionArray, FrameTick, TrackArray, TrackPredictions
from sensor_msgs.msg import CameraInfo
from visualization_msgs.msg import MarkerArray

from gldt_core.camera import CameraModel
from gldt_core.system.config import SystemConfig, TrackerSettings
from gldt_core.system.gldt_system import accepts_keyword, build_tracker
from gldt_core.system.stamps import StampOrder
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

#: Skip notices (no detector ran) -> the source of the predicted TrackArray that answers them.
PREDICTED_SOURCE = {
    DetectionArray.MODE_SKIPPED: TrackArray.SOURCE_PREDICTED,
    DetectionArray.MODE_UNREADABLE: TrackArray.SOURCE_UNREADABLE,
}

#: The diagnostics condition raised while bearings cannot be computed.
CAMERA_INFO_WARNING = "camera_info"


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
        self._last_tracked_stamp = Time()  # zero: nothing tracked yet
        # Frames ticked (or announced) and not answered yet, header stamp [ns] -> (their detections
        # once they came, when the frame was ticked): answered strictly in stamp order.
        self._pending: dict[int, tuple[DetectionArray | None, float]] = {}
        self.order_timeout_s = float(self.param("input_order_timeout"))
        self._process = self.guarded(self.on_detections, "detections")
        self.create_subscription(DetectionArray, topics.DETECTIONS, self.on_detections_arrived, qos.RELIABLE)
        self.create_timer(ORDER_CHECK_PERIOD_S, self._answer_in_order)
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
            self._pending.clear()
        self._last_tick_stamp = t
        self._check_time(t, tick.frame_index)
        self._pending[stamp_nanoseconds(tick.header.stamp)] = (None, time.monotonic())
        while len(self._pending) > PENDING_LIMIT:
            del self._pending[min(self._pending)]
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
        self._pending[stamp_nanoseconds(message.header.stamp)] = (message, time.monotonic())
        self._answer_in_order()

    def _answer_in_order(self) -> None:
        """Process the pending frames' detections in stamp order, up to the first frame still
        without them; one that waited ``input_order_timeout`` is given up (a detector restarted, or
        its queue dropped the pair) and no longer holds the later ones back."""
        while self._pending:
            stamp = min(self._pending)
            message, since = self._pending[stamp]
            if message is None:
                if time.monotonic() - since < self.order_timeout_s:
                    return
                self.warn_throttled("order timeout", f"no detections for the frame stamped {stamp} ns; answering on")
            del self._pending[stamp]
            if message is not None:
                self._process(message)

    def on_detections(self, message: DetectionArray) -> None:
        t = stamp_seconds(message.header.stamp)
        self._check_time(t, message.frame_index)
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
        self.track_publisher.publish(array)
        if bool(self.param("publish_markers")) and self.marker_publisher.get_subscription_count() > 0:
            self.marker_publisher.publish(markers_for(array))
        if message.header.frame_id == WARM_UP_FRAME_ID:  # it leaves no state behind
            self.tracker.reset()
            self.stream = PlannerStream()
            self._order.forget()
            self._last_tick_stamp = None
            self._last_tracked_stamp = Time()
            self._pending.clear()


def create_node(cli_args: list[str] | None = None) -> TrackerNode:
    return TrackerNode(cli_args=cli_args)


def main() -> int:
    return run_node(create_node)


if __name__ == "__main__":
    raise SystemExit(main())
