"""global_detector: AM-YOLO on frame pairs, only for frames the scheduler put in GLOBAL mode.

It receives the pair already resized to the model's input by ``frame_pair_buffer`` and maps the
boxes back to full-frame pixels with the pair's scale, exactly as the offline detector does.
"""

from __future__ import annotations

import time
from typing import Any

from gldt_msgs.msg import Detection, DetectionArray, FramePair

from gldt_ros import qos, topics
from gldt_ros.convert import detections_to_msgs, image_to_bgr
from gldt_ros.node_base import GldtNode, run_node


class GlobalDetectorNode(GldtNode):
    def __init__(self, **kwargs: Any) -> None:
        super().__init__("global_detector", **kwargs)
        from gldt_core.detect import GlobalDetector

        self.detector = GlobalDetector(
            model_path=self.param("model_path") or None,
            providers=tuple(p.strip() for p in self.param("providers").split(",") if p.strip()),
            score_threshold=float(self.param("score_threshold")),
            num_threads=int(self.param("num_threads")) or None,
        )
        self.create_subscription(FramePair, topics.FRAME_PAIRS, self.guarded(self.on_pair, "frame pair"), qos.RELIABLE)
        self.publisher = self.create_publisher(DetectionArray, topics.DETECTIONS, qos.RELIABLE)

    def on_pair(self, pair: FramePair) -> None:
        start = time.perf_counter()
        detections = self.detector.detect_prepared(
            image_to_bgr(pair.previous), image_to_bgr(pair.current), (pair.scale_x, pair.scale_y)
        )
        self.publisher.publish(
            DetectionArray(
                header=pair.header,
                frame_index=pair.frame_index,
                mode=DetectionArray.MODE_GLOBAL,
                processing_time=time.perf_counter() - start,
                detections=detections_to_msgs(detections, Detection.SOURCE_GLOBAL),
            )
        )


def create_node(cli_args: list[str] | None = None) -> GlobalDetectorNode:
    return GlobalDetectorNode(cli_args=cli_args)


def main() -> int:
    return run_node(create_node)


if __name__ == "__main__":
    raise SystemExit(main())
