"""frame_pair_buffer: the only node that holds full-resolution camera frames.

It decodes camera images (``sensor_msgs/Image`` in any supported encoding on ``camera/image_raw``,
or JPEG/PNG ``CompressedImage`` on ``camera/image_raw/compressed``: one of them, by
``image_transport``), keeps the current and previous frame, and announces each frame to the
tracker with a pixel-free ``FrameTick``. When the mode scheduler answers with its decision for
that frame, it sends either the resized frame pair to the global detector (GLOBAL) or the ROI
crops to the local detector (LOCAL). Full frames therefore never cross a topic.

Two things keep a GD frame's path short. While the tracker and the scheduler decide, the buffer
already letterboxes the frame when the last decision was GLOBAL (in a GD stretch the next one
almost always is). And once the global detector has answered the previous frame's pair, it holds
that frame, so the pair goes out with an empty ``previous`` image (``FramePair.msg``): half the
bytes, with the same boxes.

When the CPU cannot run the global detector on every frame, the graph degrades by plan, not by
losing frames at random: a GLOBAL frame decided while the global detector still works on an
earlier pair (``skip_global_when_busy``; a pair unanswered for ``global_answer_timeout`` no longer
counts) is not sent; a ``DetectionArray`` with ``MODE_SKIPPED`` goes to the tracker instead, which
answers the frame with its predictions, in camera order (the tracker orders its inputs by its
frame ticks). An image that cannot be decoded is announced the same way (``MODE_UNREADABLE``), at
once, so a lockstep replay never waits for it. Both are counted in the diagnostics
(``frames_skipped``, ``frames_unreadable``).

A frame whose stamp does not advance (a camera or bag that went back in time) starts the stream
afresh: it is paired with itself, as the offline system pairs a re-initialised stream's first
frame. The warm-up frame ``pipeline`` sends (:data:`~gldt_ros.interface.graph.WARM_UP_FRAME_ID`)
leaves no state: after its decision the buffer starts afresh, from frame 0.
"""

from __future__ import annotations

import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

import numpy as np
from gldt_msgs.msg import DetectionArray, FramePair, FrameTick, RoiCrops, SchedulerState, TrackArray
from sensor_msgs.msg import CompressedImage, Image

from gldt_core.detect import GlobalDetector, LocalDetector
from gldt_core.detect.postprocess import Letterbox
from gldt_core.system.stamps import StaleMessage
from gldt_ros.interface import qos, topics
from gldt_ros.interface.convert import bgr_to_image, image_to_bgr, msgs_to_rois, stamp_nanoseconds, track_array_to_rows
from gldt_ros.interface.graph import WARM_UP_FRAME_ID
from gldt_ros.runtime.node_base import PAIRS_SKIPPED, GldtNode, run_node

#: Frames kept while waiting for the scheduler's answer (the answer normally comes within one).
PENDING_FRAMES = 8

#: Frame pairs the publisher keeps for resending (see ``__init__``).
PAIRS_KEPT = 2

#: Diagnostics counters of this node: GLOBAL frames skipped by plan (the global detector was busy),
#: and camera images that could not be decoded (answered as skipped).
FRAMES_SKIPPED = "frames_skipped"
FRAMES_UNREADABLE = "frames_unreadable"

#: Unanswered pairs remembered for counting skips; older ones are forgotten uncounted (a detector
#: that is down answers none, which is not a skip).
PAIRS_TRACKED = 64

#: It sends frames (pairs, crops) of a MiB or more: its process uses the large-segment DDS profile.
PUBLISHES_FRAMES = True


@dataclass
class BufferedFrame:
    """A camera frame waiting for (or just past) its scheduler decision."""

    header: Any
    image: np.ndarray
    #: The global detector's input made from it while its decision was pending (and mapping),
    #: kept with the frame so that it leaves the buffer with it.
    prepared: tuple[np.ndarray, Letterbox] | None = None
    #: The first frame after the camera's time went back: it has no predecessor.
    first_of_stream: bool = False


class FramePairBuffer(GldtNode):
    def __init__(self, **kwargs: Any) -> None:
        super().__init__("frame_pair_buffer", **kwargs)
        # The global detector's own preprocessing (letterbox to its input), so the pair the
        # detector node receives is exactly what it would have made from the full frames. Only
        # its geometry is used here, so its graph is not optimised (a faster start and restart).
        self.global_input = GlobalDetector(
            model_path=self.param("global_model_path") or None, num_threads=1, optimize_graph=False
        )
        self.crop = LocalDetector.crop
        self._frames: OrderedDict[int, BufferedFrame] = OrderedDict()
        self._index = 0
        self._size: tuple[int, int] | None = None
        self._last_stamp: int | None = None  # of the last decoded frame [ns]
        self._previous_index: int | None = None
        # (frame index, letterboxed input) of the last GD frame: the next GD frame's predecessor,
        # so a GD stretch letterboxes each 1080p frame once, not twice (as GLDTSystem does).
        self._last_prepared: tuple[int, np.ndarray] | None = None
        # The mode of the last decision; a stream starts in GLOBAL (no tracks yet), so its first
        # frame is letterboxed ahead too.
        self._last_mode: int = SchedulerState.MODE_GLOBAL
        # (frame index, stamp in ns) of the last pair the global detector answered: that frame's
        # image need not travel again as the next pair's previous one.
        self._global_answered: tuple[int, int] | None = None
        # Pairs sent to the global detector and not answered yet, frame index -> stamp [ns]: one
        # that a later pair's answer overtakes was skipped (the detector keeps only the newest).
        self._pairs_unanswered: OrderedDict[int, int] = OrderedDict()
        self.skip_when_busy = bool(self.param("skip_global_when_busy"))
        self.answer_timeout_s = float(self.param("global_answer_timeout"))
        # (frame index, stamp [ns], monotonic time sent) of the pair the global detector works on.
        self._pair_in_flight: tuple[int, int, float] | None = None
        # One camera input, never both: a driver that publishes raw and compressed would otherwise
        # feed every frame twice (and each twin resets the scheduler: its stamp is not newer).
        transport = self.param("image_transport")
        message_type, topic = (
            (CompressedImage, topics.IMAGE_COMPRESSED) if transport == "compressed" else (Image, topics.IMAGE_RAW)
        )
        camera = self.create_subscription(
            message_type, topic, self.guarded(self.on_image, "image"), qos.camera_qos(self.param("camera_qos"))
        )
        self.get_logger().info(
            f"camera input: {message_type.__name__} on {camera.topic_name} (image_transport: {transport})"
        )
        self.create_subscription(
            SchedulerState, topics.SCHEDULER_STATE, self.guarded(self.on_decision, "decision"), qos.RELIABLE
        )
        self.ticks = self.create_publisher(FrameTick, topics.FRAME_TICKS, qos.RELIABLE)
        # A pair is 2 MB, and a reliable writer keeps its last `depth` samples for resending. The
        # global detector only wants the newest pair (its pair_queue_depth), so two are enough;
        # with qos.RELIABLE's thirty, this process's memory grows in steps as the writer's history
        # fills (python -m gldt_ros.bench.soak shows it).
        self.pairs = self.create_publisher(FramePair, topics.FRAME_PAIRS, qos.newest_first(PAIRS_KEPT))
        self.crops = self.create_publisher(RoiCrops, topics.ROI_CROPS, qos.RELIABLE)
        # Skip notices (MODE_SKIPPED) for the tracker, on the detectors' topic.
        self.skips = self.create_publisher(DetectionArray, topics.DETECTIONS, qos.RELIABLE)
        # Debug overlay: drawn here, where the full frame is, and only while someone watches.
        self.debug_image = self.create_publisher(Image, topics.DEBUG_IMAGE, 2)
        self._decisions: OrderedDict[int, tuple[str, np.ndarray]] = OrderedDict()
        self.create_subscription(TrackArray, topics.TRACKS, self.guarded(self.on_tracks, "tracks"), qos.RELIABLE)
        self.create_subscription(DetectionArray, topics.DETECTIONS, self.on_detections, qos.RELIABLE)

    def on_image(self, message: Any) -> None:
        try:
            frame = image_to_bgr(message)
        except ValueError:
            # Answered at once (the tracker predicts it), so nothing waits for a frame that never comes.
            self.count_event(FRAMES_UNREADABLE)
            self.skips.publish(self._skip_notice(message.header, self._index, DetectionArray.MODE_UNREADABLE))
            self._index += 1
            raise
        size = (frame.shape[1], frame.shape[0])
        if self._size is not None and size != self._size:
            self.get_logger().warning(
                f"frame size changed from {self._size[0]}x{self._size[1]} to {size[0]}x{size[1]}; "
                "the next global frame is paired with itself"
            )
            self._frames.clear()
            self._previous_index = None
            self._last_prepared = None
        stamp = stamp_nanoseconds(message.header.stamp)
        # The camera's time went back (or repeated): the stream restarted, as the tracker and the
        # scheduler take it too; like the offline system, this frame is paired with itself.
        restarted = self._last_stamp is not None and stamp <= self._last_stamp
        if restarted:
            self.get_logger().warning(f"camera time did not advance at frame {self._index}; it is paired with itself")
        self._size, self._last_stamp = size, stamp
        index = self._index
        self._index += 1
        buffered = BufferedFrame(message.header, frame, first_of_stream=restarted)
        self._frames[index] = buffered
        while len(self._frames) > PENDING_FRAMES:
            self._frames.popitem(last=False)
        self.ticks.publish(FrameTick(header=message.header, frame_index=index, width=size[0], height=size[1]))
        if self._last_mode == SchedulerState.MODE_GLOBAL:
            # Done while the tracker and the scheduler decide this frame; in a GD stretch the
            # decision is GLOBAL again, and the pair leaves as soon as it comes.
            buffered.prepared = self.global_input.prepare(frame)

    def on_decision(self, decision: SchedulerState) -> None:
        index = int(decision.frame_index)
        if index not in self._frames:
            raise StaleMessage(f"scheduler decision for frame {index}, which is no longer buffered")
        buffered = self._frames[index]
        header, frame = buffered.header, buffered.image
        if buffered.first_of_stream:
            self._previous_index = None  # paired with itself
        previous_buffered = self._frames.get(self._previous_index) if self._previous_index is not None else None
        previous = previous_buffered.image if previous_buffered is not None else frame
        self._last_mode = decision.mode
        if decision.mode == SchedulerState.MODE_GLOBAL and self.global_detector_busy():
            self.count_event(FRAMES_SKIPPED)
            self.skips.publish(self._skip_notice(header, index, DetectionArray.MODE_SKIPPED))
            if buffered.prepared is not None:  # the next pair's previous input, made already
                self._last_prepared = (index, buffered.prepared[0])
        elif decision.mode == SchedulerState.MODE_GLOBAL:
            prepared_current, letterbox = buffered.prepared or self.global_input.prepare(frame)
            if self._previous_index is None:
                prepared_previous = prepared_current
            elif self.detector_holds_frame(self._previous_index):
                prepared_previous = None  # the global detector answered that frame's pair last
            elif self._last_prepared is not None and self._last_prepared[0] == self._previous_index:
                prepared_previous = self._last_prepared[1]
            else:
                prepared_previous, _ = self.global_input.prepare(previous)
            self._last_prepared = (index, prepared_current)
            previous_image = (
                Image(header=header) if prepared_previous is None else bgr_to_image(prepared_previous, header)
            )
            self._note_pair_sent(index, stamp_nanoseconds(header.stamp))
            self.pairs.publish(
                FramePair(
                    header=header,
                    frame_index=index,
                    previous_frame_index=self._previous_index if self._previous_index is not None else index,
                    full_width=frame.shape[1],
                    full_height=frame.shape[0],
                    scale=float(letterbox.scale),
                    pad_x=int(letterbox.pad_x),
                    pad_y=int(letterbox.pad_y),
                    previous=previous_image,
                    current=bgr_to_image(prepared_current, header),
                )
            )
        else:
            rois = msgs_to_rois(decision.rois)
            crops = [bgr_to_image(self.crop(frame, roi), header) for roi in rois]
            # The previous frame at the same ROIs lets the local detector's second stage see motion
            # (the offline system gives it the previous frame too; the first frame pairs with itself).
            previous_crops = [bgr_to_image(self.crop(previous, roi), header) for roi in rois]
            self.crops.publish(
                RoiCrops(
                    header=header,
                    frame_index=index,
                    full_width=frame.shape[1],
                    full_height=frame.shape[0],
                    rois=list(decision.rois),
                    crops=crops,
                    previous_crops=previous_crops,
                )
            )
        self._decisions[index] = (
            "GD" if decision.mode == SchedulerState.MODE_GLOBAL else "LD",
            msgs_to_rois(decision.rois),
        )
        while len(self._decisions) > PENDING_FRAMES:
            self._decisions.popitem(last=False)
        # Every frame becomes the next frame's predecessor, LD frames included, so the first GD
        # frame after an LD stretch still gets a true consecutive pair.
        for stale in [i for i in self._frames if i < index]:
            del self._frames[stale]
        buffered.prepared = None  # used or not, it is done with
        self._previous_index = index
        if header.frame_id == WARM_UP_FRAME_ID:
            self._start_afresh()

    def _start_afresh(self) -> None:
        """Forget the stream (after the warm-up frame, :data:`WARM_UP_FRAME_ID`): the next frame is
        frame 0 again, paired with itself."""
        self._frames.clear()
        self._decisions.clear()
        self._index = 0
        self._size = None
        self._last_stamp = None
        self._previous_index = None
        self._last_prepared = None
        self._last_mode = SchedulerState.MODE_GLOBAL
        self._global_answered = None
        self._pairs_unanswered.clear()
        self._pair_in_flight = None

    def on_detections(self, array: DetectionArray) -> None:
        """Note which frame the global detector answered last (see :meth:`detector_holds_frame`),
        count the pairs it skipped to get there, and whether it is free again."""
        if array.mode == DetectionArray.MODE_GLOBAL and array.header.frame_id != WARM_UP_FRAME_ID:
            index, stamp_ns = int(array.frame_index), stamp_nanoseconds(array.header.stamp)
            ours = self._pairs_unanswered.get(index) == stamp_ns  # a pair this stream sent
            self._global_answered = (index, stamp_ns)
            self._count_skipped_pairs(index, stamp_ns)
            flight = self._pair_in_flight
            if ours and flight is not None and stamp_ns >= flight[1]:
                self._pair_in_flight = None

    def global_detector_busy(self) -> bool:
        """Whether a GLOBAL frame is to be skipped by plan: ``skip_global_when_busy`` is set and a
        pair sent less than ``global_answer_timeout`` ago is unanswered."""
        flight = self._pair_in_flight
        return self.skip_when_busy and flight is not None and time.monotonic() - flight[2] < self.answer_timeout_s

    @staticmethod
    def _skip_notice(header: Any, index: int, mode: int) -> DetectionArray:
        """The message telling the tracker that no detector runs on frame ``index`` and why
        (``mode``: ``MODE_SKIPPED`` or ``MODE_UNREADABLE``); it answers with predictions."""
        return DetectionArray(header=header, frame_index=index, mode=mode)

    def _note_pair_sent(self, index: int, stamp_ns: int) -> None:
        self._pair_in_flight = (index, stamp_ns, time.monotonic())
        self._pairs_unanswered[index] = stamp_ns
        while len(self._pairs_unanswered) > PAIRS_TRACKED:
            self._pairs_unanswered.popitem(last=False)

    def _count_skipped_pairs(self, index: int, stamp_ns: int) -> None:
        """The global detector answered the pair of frame ``index``: the pairs sent before it and
        still unanswered were skipped (its queue keeps the newest ``pair_queue_depth``), and are
        counted as ``pairs_skipped`` in the diagnostics. Stamps, not indices, say "before": a
        restarted buffer counts frames from 0 again."""
        if self._pairs_unanswered.get(index) != stamp_ns:
            return  # not a pair of this stream (or long forgotten)
        skipped = [i for i, stamp in self._pairs_unanswered.items() if stamp < stamp_ns]
        for i in [*skipped, index]:
            del self._pairs_unanswered[i]
        if skipped:
            self.count_event(PAIRS_SKIPPED, len(skipped))
            self.warn_throttled(
                "pairs skipped",
                f"the global detector skipped {len(skipped)} frame pair(s) before frame {index} "
                "(it is slower than the camera; pair_queue_depth keeps only the newest)",
            )

    def detector_holds_frame(self, index: int) -> bool:
        """Whether the global detector's last answered pair had frame ``index`` of this stream as
        its current frame (index and stamp, so a restarted buffer's new frame 0 is not taken for
        the old one). The detector keeps that frame until its next pair, which is this one."""
        if index not in self._frames or self._global_answered is None:
            return False
        return self._global_answered == (index, stamp_nanoseconds(self._frames[index].header.stamp))

    def on_tracks(self, array: TrackArray) -> None:
        """Publish the debug overlay (boxes, ids, mode, ROIs) of the frame these tracks are for."""
        if self.debug_image.get_subscription_count() == 0:
            return
        index = int(array.frame_index)
        if index not in self._frames:
            return  # already evicted: the overlay is best effort
        from gldt_core.viz.overlay import draw_overlay

        buffered = self._frames[index]
        mode, rois = self._decisions.get(index, ("GD", np.zeros((0, 4), np.int64)))
        rows = track_array_to_rows(array)
        overlay = draw_overlay(buffered.image, rows[:, :5], mode, rois if len(rois) else None, index)
        self.debug_image.publish(bgr_to_image(overlay, buffered.header))


def create_node(cli_args: list[str] | None = None) -> FramePairBuffer:
    return FramePairBuffer(cli_args=cli_args)


def main() -> int:
    return run_node(create_node, publishes_frames=PUBLISHES_FRAMES)


if __name__ == "__main__":
    raise SystemExit(main())
