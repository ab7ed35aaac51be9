"""local_detector: the P2 local model on all ROI crops of a frame, as one batch.

Crops arrive from ``frame_pair_buffer`` (only in LOCAL mode); detections are mapped back to
full-frame pixels by each crop's ROI offset, and duplicates across overlapping ROIs are removed
with the same NMS the offline GL-DT system uses.
"""

from __future__ import annotations

import time
from typing import Any

from gldt_msgs.msg import Detection, DetectionArray, RoiCrops

from gldt_core.detect import LocalDetector
from gldt_core.system.steps import drop_nested, merge_local_detections
from gldt_ros.interface import qos, topics
from gldt_ros.interface.convert import detections_to_msgs, image_to_bgr, msgs_to_rois
from gldt_ros.interface.params import detector_kwargs, parse_classes
from gldt_ros.runtime.node_base import GldtNode, run_node


class LocalDetectorNode(GldtNode):
    def __init__(self, **kwargs: Any) -> None:
        super().__init__("local_detector", **kwargs)
        self.detector = LocalDetector(**detector_kwargs(self.param))
        self.classes = parse_classes(self.param("classes"))
        self.create_subscription(RoiCrops, topics.ROI_CROPS, self.guarded(self.on_crops, "ROI crops"), qos.RELIABLE)
        self.publisher = self.create_publisher(DetectionArray, topics.DETECTIONS, qos.RELIABLE)

    def on_crops(self, message: RoiCrops) -> None:
        start = time.perf_counter()
        rois = msgs_to_rois(message.rois)
        crops = [image_to_bgr(crop) for crop in message.crops]
        # Sent only where the detector has a second stage to look at motion with.
        previous = [image_to_bgr(crop) for crop in message.previous_crops] or None
        raw = self.detector.detect_crops(
            crops, rois, int(message.full_width), int(message.full_height), previous_crops=previous
        )
        detections = merge_local_detections(raw, self.classes, float(self.param("nms_iou")))
        detections = drop_nested(detections, float(self.param("nested_threshold")))
        self.publisher.publish(
            DetectionArray(
                header=message.header,
                frame_index=message.frame_index,
                mode=DetectionArray.MODE_LOCAL,
                processing_time=time.perf_counter() - start,
                detections=detections_to_msgs(detections, Detection.SOURCE_LOCAL),
                rois=list(message.rois),
            )
        )


def create_node(cli_args: list[str] | None = None) -> LocalDetectorNode:
    return LocalDetectorNode(cli_args=cli_args)


def main() -> int:
    return run_node(create_node)


if __name__ == "__main__":
    raise SystemExit(main())
