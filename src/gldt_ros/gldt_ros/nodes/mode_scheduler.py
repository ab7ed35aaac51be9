"""mode_scheduler: owns the GD/LD mode and the ROIs (paper: N_g, N_l, N_m; ROI manager).

For every frame the tracker sends its predictions (``TrackPredictions``); the scheduler runs the
core :class:`~gldt_core.schedule.scheduler.ModeScheduler` on them and publishes its decision
(``SchedulerState``, plus the ROIs alone on ``gldt/rois``). Detections coming back for a LOCAL
frame are counted per ROI and reported to the state machine, which drives the N_m rule.

In ``lockstep`` (deterministic replay) a new frame is only planned once the previous LOCAL
frame's detections have been reported, so the decision never depends on message timing. The wait
ends early when the tracker's predictions for a later frame say it never tracked the awaited one
(the player gave up on that frame, say because a detector died), and at ``report_timeout`` at
the latest.
"""

from __future__ import annotations

import time
from collections import deque
from typing import Any

import numpy as np
from gldt_msgs.msg import DetectionArray, RoiArray, SchedulerState, TrackPredictions

from gldt_core.schedule.roi import RoiParams
from gldt_core.schedule.scheduler import ModeScheduler, SchedulerConfig
from gldt_ros.interface import qos, topics
from gldt_ros.interface.convert import rois_to_msgs, stamp_seconds
from gldt_ros.interface.graph import WARM_UP_FRAME_ID
from gldt_ros.runtime.node_base import STALE_DROPPED, GldtNode, run_node


class ModeSchedulerNode(GldtNode):
    def __init__(self, **kwargs: Any) -> None:
        super().__init__("mode_scheduler", **kwargs)
        self.scheduler = ModeScheduler(
            SchedulerConfig(
                n_global=int(self.param("global_frames")),
                n_local=int(self.param("local_frames")),
                n_miss=int(self.param("miss_frames")),
                roi=RoiParams(
                    roi_size=int(self.param("roi_size")),
                    reference_height=float(self.param("roi_reference_height")) or None,
                ),
            )
        )
        self.lockstep = bool(self.param("lockstep"))
        self._size: tuple[int, int] | None = None
        self._last_stamp: float | None = None
        self._plans: dict[int, Any] = {}
        self._awaiting_report: int | None = None  # frame index of the LOCAL frame whose detections are awaited
        self._awaiting_since = 0.0
        self.create_timer(0.05, self._check_report_timeout)
        self._queue: deque[TrackPredictions] = deque()
        self.create_subscription(
            TrackPredictions, topics.TRACK_PREDICTIONS, self.guarded(self.on_predictions, "predictions"), qos.RELIABLE
        )
        self.create_subscription(
            DetectionArray, topics.DETECTIONS, self.guarded(self.on_detections, "detections"), qos.RELIABLE
        )
        self.state_publisher = self.create_publisher(SchedulerState, topics.SCHEDULER_STATE, qos.RELIABLE)
        self.latched_publisher = self.create_publisher(SchedulerState, topics.SCHEDULER_LATEST, qos.LATCHED_STATE)
        self.roi_publisher = self.create_publisher(RoiArray, topics.ROIS, qos.RELIABLE)

    def on_predictions(self, message: TrackPredictions) -> None:
        self._queue.append(message)
        self._drain()

    def _awaited_frame_given_up(self) -> bool:
        """The player sends frame t+1 only after tracks for frame t or after giving frame t up. So
        predictions for a later frame from a tracker that never tracked the awaited frame mean it
        was given up, and its detections (if they ever come) no longer matter: plan on now instead
        of stalling every following frame until ``report_timeout``. The newest queued predictions
        carry what the tracker knows last. Stamps, not frame indices: a restarted frame buffer
        counts frames from 0 again."""
        if self._awaiting_report is None:
            return False
        awaited_stamp = self._plans[self._awaiting_report].stamp
        newest = self._queue[-1]
        return (
            stamp_seconds(newest.header.stamp) > awaited_stamp
            and stamp_seconds(newest.last_tracked_stamp) < awaited_stamp
        )

    def _check_report_timeout(self) -> None:
        """Never wait forever for a LOCAL frame's detections: a dropped frame must not stall the graph.

        Frames that queued up meanwhile are stale (the frame buffer keeps only the newest few, so
        their decisions could no longer be served, and each LOCAL one would wait again): only the
        newest is planned, and the others count as stale drops in the diagnostics."""
        if self._awaiting_report is not None and time.monotonic() - self._awaiting_since > float(
            self.param("report_timeout")
        ):
            stale = len(self._queue) - 1
            skipped = f"; skipping {stale} stale queued frame(s)" if stale > 0 else ""
            self.warn_throttled(
                "report-timeout",
                f"no detections for LOCAL frame {self._awaiting_report}; planning on without them{skipped}",
            )
            while len(self._queue) > 1:
                self._queue.popleft()
            self.count_event(STALE_DROPPED, stale)
            self._awaiting_report = None
            self._drain()

    def _drain(self) -> None:
        while self._queue:
            if self.lockstep and self._awaiting_report is not None:
                if not self._awaited_frame_given_up():
                    return
                self.warn_throttled(
                    "abandoned-frame",
                    f"LOCAL frame {self._awaiting_report} was given up (never tracked); "
                    "planning on without its detections",
                )
                self._awaiting_report = None
            self._plan(self._queue.popleft())

    def _plan(self, message: TrackPredictions) -> None:
        stamp = stamp_seconds(message.header.stamp)
        size = (int(message.width), int(message.height))
        if (self._size is not None and size != self._size) or (
            self._last_stamp is not None and stamp <= self._last_stamp
        ):
            self.get_logger().warning(
                f"frame {message.frame_index}: size change or time going backwards; scheduler reset"
            )
            self.scheduler.reset()
            self._plans.clear()
        self._size, self._last_stamp = size, stamp
        predictions = np.array(
            [
                (
                    t.center_x - t.width / 2,
                    t.center_y - t.height / 2,
                    t.center_x + t.width / 2,
                    t.center_y + t.height / 2,
                    t.id,
                )
                for t in message.tracks
            ],
            dtype=np.float64,
        ).reshape(-1, 5)
        plan = self.scheduler.plan_frame(stamp, size, predictions)
        index = int(message.frame_index)
        self._plans[index] = plan
        for old in [i for i in self._plans if i < index - 30]:
            del self._plans[old]
        local = plan.mode.name == "LOCAL"
        if local:
            self._awaiting_report = index
            self._awaiting_since = time.monotonic()
        state = self.scheduler.state
        roi_msgs = rois_to_msgs(plan.rois, plan.layout.groups)
        decision = SchedulerState(
            header=message.header,
            frame_index=index,
            mode=SchedulerState.MODE_LOCAL if local else SchedulerState.MODE_GLOBAL,
            frames_in_mode=state.frames_in_mode,
            frames_without_detection=state.frames_without_detection,
            rois=roi_msgs,
            reason=plan.reason,
        )
        self.state_publisher.publish(decision)
        self.latched_publisher.publish(decision)
        if local:
            self.roi_publisher.publish(RoiArray(header=message.header, frame_index=index, rois=roi_msgs))
        if message.header.frame_id == WARM_UP_FRAME_ID:  # it leaves no state behind
            self.scheduler.reset()
            self._plans.clear()
            self._size, self._last_stamp, self._awaiting_report = None, None, None

    def on_detections(self, message: DetectionArray) -> None:
        index = int(message.frame_index)
        plan = self._plans.get(index)
        if plan is None or message.mode != DetectionArray.MODE_LOCAL:
            return
        counts = np.zeros(len(plan.rois), dtype=np.int64)
        for detection in message.detections:
            if 0 <= detection.roi_index < len(counts):
                counts[detection.roi_index] += 1
        self.scheduler.report_detections(plan, counts)
        if self._awaiting_report == index:
            self._awaiting_report = None
            self._drain()


def create_node(cli_args: list[str] | None = None) -> ModeSchedulerNode:
    return ModeSchedulerNode(cli_args=cli_args)


def main() -> int:
    return run_node(create_node)


if __name__ == "__main__":
    raise SystemExit(main())
