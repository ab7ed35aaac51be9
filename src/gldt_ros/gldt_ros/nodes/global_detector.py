"""global_detector: AM-YOLO on frame pairs, only for frames the scheduler put in GLOBAL mode.

It receives the pair already resized to the model's input by ``frame_pair_buffer`` and maps the
boxes back to full-frame pixels with the pair's scale, exactly as the offline detector does.
Like the offline GL-DT system it keeps the last pair's current-frame features (AM-YOLO's split pair,
``gldt export --feature-reuse``) and reuses them when the next pair's previous frame is that very
image, which in a GD stretch it is; any other pair (one skipped, a restarted buffer) recomputes them.
Once it has answered a pair, the buffer sends the next one without its previous image (it is the
frame kept here); should that frame be gone (this node restarted in between), the current frame is
paired with itself, as on a stream's first frame, and a warning says so.

With ``tile_fusion`` the local model's tile pass follows AM-YOLO's on each pair. Live, a pair whose
AM-YOLO pass ends too late for the tile pass to fit within ``tile_budget`` of its arrival skips it
and is answered with AM-YOLO's boxes alone (:class:`gldt_core.detect.fusion.TilePassBudget`;
counted as ``tiles_skipped``): on a slow machine fewer pairs reach the tracker after its answer
deadline. A lockstep replay sets the budget to 0, so every pair is fused, as offline.

The model runs on a thread of its own (:class:`gldt_ros.runtime.worker.KeepNewestWorker`), and the
detections are published from the thread that spins the node: in a process it shares with other
nodes (``pipeline --processes one-process``) they keep answering frames while it works, as they
would with the detector in another process.
"""

from __future__ import annotations

import functools
import time
from typing import Any

import numpy as np
from gldt_msgs.msg import Detection, DetectionArray, FramePair

from gldt_core.detect import GlobalCarry, GlobalDetector
from gldt_core.detect.fusion import TilePassBudget, build_tile_detector
from gldt_core.detect.postprocess import Letterbox
from gldt_core.detect.second_stage import GLOBAL_COLUMNS
from gldt_core.system.steps import drop_nested, filter_classes
from gldt_ros.interface import qos, topics
from gldt_ros.interface.convert import detections_to_msgs, image_to_bgr
from gldt_ros.interface.graph import WARM_UP_FRAME_ID
from gldt_ros.interface.params import detector_kwargs, parse_classes
from gldt_ros.runtime.node_base import GldtNode, run_node
from gldt_ros.runtime.worker import KeepNewestWorker

#: Blank pairs run before the node reports ready (:meth:`GlobalDetectorNode.warm_up`): the first
#: computes the previous frame's features too, the second reuses them, as in a GD stretch.
WARM_UP_RUNS = 2
#: Diagnostics counter: pairs answered without their tile pass (``tile_budget``).
TILES_SKIPPED = "tiles_skipped"


class GlobalDetectorNode(GldtNode):
    def __init__(self, **kwargs: Any) -> None:
        super().__init__("global_detector", **kwargs)
        settings = detector_kwargs(self.param)
        tiles = None
        if self.param("tile_fusion"):  # the local model over tiles too (gldt_core.detect.fusion),
            # built once AM-YOLO has opened, so its errors come first
            tiles = functools.partial(build_tile_detector, self.param("tile_model_path") or None, settings)
        self.detector = GlobalDetector(**settings, tile_detector=tiles)
        self.tile_budget = TilePassBudget(float(self.param("tile_budget"))) if tiles is not None else None
        if self.tile_budget is not None:
            self.events[TILES_SKIPPED] = 0  # reported from the start, as the base counters are
        self.classes = parse_classes(self.param("classes"))
        # On a small CPU AM-YOLO takes longer than a frame period, so during a GD stretch at 30 Hz
        # pairs arrive faster than it answers, and queueing them puts whole seconds between camera
        # and tracks. By default it skips to the newest pair instead.
        pairs_qos = qos.newest_first(int(self.param("pair_queue_depth")))
        self.publisher = self.create_publisher(DetectionArray, topics.DETECTIONS, qos.RELIABLE)
        self.last_pair: GlobalCarry | None = None  # the last pair's current input and its features
        self.last_pair_index: int | None = None  # and that pair's frame index
        self.warm_up()
        # guarded() counts and times each pair on the worker's thread; the diagnostics timer reads
        # those counters on the spinning thread: single attribute updates and deque appends, each
        # atomic under the GIL, and a status a frame late is harmless.
        self.worker: KeepNewestWorker[tuple[float, FramePair]] = KeepNewestWorker(
            self.guarded(self.answer, "frame pair"),
            depth=int(self.param("pair_queue_depth")),
            on_error=self.fail_from_thread,
            name="gldt-global-detector",
        )
        # Last, once warm: pipeline takes the graph as up when this subscription is matched.
        self.create_subscription(FramePair, topics.FRAME_PAIRS, self.on_pair, pairs_qos)

    def on_pair(self, pair: FramePair) -> None:
        """Hand ``pair`` to the worker with the monotonic time it arrived (``tile_budget`` counts from it)."""
        self.worker.submit((time.monotonic(), pair))

    def destroy_node(self) -> None:
        self.closing = True  # before the stop: a pair still in the model's hands is dropped, not published
        self.worker.stop()
        super().destroy_node()

    def warm_up(self) -> None:
        """Run the model on blank pairs of a 1080p camera's input size before the node reports
        ready. The first runs after loading take several times as long (onnxruntime allocates its
        buffers), and at 30 Hz the camera's first pairs were skipped while they ran."""
        width, height = self.detector.input_size(1920, 1080)
        blank = np.zeros((height, width, 3), np.uint8)
        features = None
        for _ in range(WARM_UP_RUNS):
            _, features = self.detector.detect_prepared(
                blank, blank, Letterbox(1.0, 0, 0, width, height), width, height, features
            )

    def reusable_features(self, previous: np.ndarray) -> np.ndarray | None:
        """The features kept from the last pair if its current input is exactly ``previous``."""
        last = self.last_pair
        if last is None or last.features is None or last.input.shape != previous.shape:
            return None
        return last.features if np.array_equal(last.input, previous) else None

    def held_previous(self, pair: FramePair, current: np.ndarray) -> GlobalCarry:
        """The previous frame of a pair sent without it: the last pair's current frame, kept here.
        If that is not the frame asked for, the current frame stands in for it (a warning says so)."""
        last, index = self.last_pair, int(pair.previous_frame_index)
        if last is not None and self.last_pair_index == index and last.input.shape == current.shape:
            return last
        self.warn_throttled(
            "previous frame missing",
            f"frame pair {pair.frame_index} came without its previous frame {index}, which this node does not hold "
            f"(it holds {self.last_pair_index}; restarted since?): pairing frame {pair.frame_index} with itself",
        )
        return GlobalCarry(current)

    def answer(self, arrived_pair: tuple[float, FramePair]) -> None:
        """The worker's work: detect on a pair (with the time it arrived), and publish the
        detections from the spinning thread."""
        arrived, pair = arrived_pair
        self.call_on_spin_thread(functools.partial(self.publisher.publish, self.detect(pair, arrived)))

    def tiles_wanted(self, arrived: float, tiles_started: list[float]) -> bool:
        """Asked once AM-YOLO's boxes of a pair that arrived at ``arrived`` (monotonic) are in:
        whether its tile pass still fits ``tile_budget``; if so its start goes to ``tiles_started``."""
        now = time.monotonic()
        if self.tile_budget is not None and not self.tile_budget.wanted(now - arrived):
            self.count_event(TILES_SKIPPED)
            return False
        tiles_started.append(now)
        return True

    def detect(self, pair: FramePair, arrived: float | None = None) -> DetectionArray:
        """The detections of ``pair``, in full-frame pixels; the features of its current frame are
        kept for the next pair. ``arrived``: the monotonic time the pair came (None: now)."""
        start = time.perf_counter()
        arrived = time.monotonic() if arrived is None else arrived
        tiles_started: list[float] = []
        current = image_to_bgr(pair.current)
        if pair.previous.height == 0:  # sent without it: the frame kept from the last pair
            held = self.held_previous(pair, current)
            previous, previous_features = held.input, held.features
        else:
            previous = image_to_bgr(pair.previous)
            previous_features = self.reusable_features(previous)
        letterbox = Letterbox(pair.scale, int(pair.pad_x), int(pair.pad_y), current.shape[1], current.shape[0])
        self.last_pair, self.last_pair_index = None, None
        raw, current_features = self.detector.detect_prepared(
            previous,
            current,
            letterbox,
            int(pair.full_width),
            int(pair.full_height),
            previous_features,
            tiles_wanted=functools.partial(self.tiles_wanted, arrived, tiles_started),
        )
        if tiles_started and self.tile_budget is not None:
            self.tile_budget.record(time.monotonic() - tiles_started[0])
        if pair.header.frame_id != WARM_UP_FRAME_ID:  # it leaves no state behind
            self.last_pair, self.last_pair_index = GlobalCarry(current, current_features), int(pair.frame_index)
        detections = drop_nested(
            filter_classes(raw, GLOBAL_COLUMNS, self.classes), float(self.param("nested_threshold"))
        )
        return DetectionArray(
            header=pair.header,
            frame_index=pair.frame_index,
            mode=DetectionArray.MODE_GLOBAL,
            processing_time=time.perf_counter() - start,
            detections=detections_to_msgs(detections, Detection.SOURCE_GLOBAL),
        )


def create_node(cli_args: list[str] | None = None) -> GlobalDetectorNode:
    return GlobalDetectorNode(cli_args=cli_args)


def main() -> int:
    return run_node(create_node)


if __name__ == "__main__":
    raise SystemExit(main())
