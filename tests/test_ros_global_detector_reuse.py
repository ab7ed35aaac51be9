"""global_detector reuses the last pair's features only when the next pair's previous frame is
that very image, and its boxes equal the full model's either way."""

from __future__ import annotations

from itertools import islice
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

from rclpy.context import Context  # noqa: E402

REAL_BAG = Path(__file__).resolve().parents[1] / "bags" / "halmstad_v_drone_001"


def test_pairs_in_a_gd_stretch_reuse_features_and_others_recompute_them() -> None:
    from gldt_msgs.msg import FramePair
    from std_msgs.msg import Header

    from gldt_core.data import open_source
    from gldt_core.detect import GlobalDetector
    from gldt_core.detect.staged import detect_global_streamed, prepare_global_input
    from gldt_ros.convert import bgr_to_image
    from gldt_ros.nodes.global_detector import GlobalDetectorNode

    frames = [frame.image for frame in islice(open_source(str(REAL_BAG)), 5)]
    geometry = GlobalDetector(num_threads=1, optimize_graph=False)
    prepared = [prepare_global_input(geometry, frame) for frame in frames]
    height, width = frames[0].shape[:2]

    def pair(previous: int, current: int) -> FramePair:
        header = Header(frame_id="camera")
        header.stamp.nanosec = current * 33_333_333
        letterbox = prepared[current][1]
        return FramePair(
            header=header, frame_index=current, previous_frame_index=previous, full_width=width, full_height=height,
            scale=float(letterbox.scale), pad_x=int(letterbox.pad_x), pad_y=int(letterbox.pad_y),
            previous=bgr_to_image(prepared[previous][0], header), current=bgr_to_image(prepared[current][0], header),
        )

    context = Context()
    rclpy.init(context=context)
    try:
        node = GlobalDetectorNode(context=context)
        reuse = node.detector.feature_reuse
        assert reuse is not None, "the shipped AM-YOLO comes with its split pair"
        runs: list[int] = []
        original = reuse.features
        reuse.features = lambda blob: (runs.append(1), original(blob))[1]  # type: ignore[method-assign]
        published: list = []
        node.publisher.publish = published.append  # type: ignore[method-assign]
        full = GlobalDetector(
            num_threads=1, score_threshold=node.detector.score_threshold, classes=node.detector.classes, feature_reuse=False
        )
        # A GD stretch 0-1-2, then a pair whose previous frame (3) was never a current one here
        # (skipped, or an LD frame), then 3-4 again in a stretch.
        sequence = [(0, 0), (0, 1), (1, 2), (3, 4)]
        for previous, current in sequence:
            node.on_pair(pair(previous, current))
        assert len(runs) == 2  # the first pair and the one after the gap
        for (previous, current), message in zip(sequence, published):
            expected, _ = detect_global_streamed(
                full, prepared[previous][0], prepared[current][0], prepared[current][1], width, height
            )
            boxes = np.array([[d.center_x, d.center_y, d.width, d.height, d.score] for d in message.detections])
            centres = np.c_[(expected[:, 0] + expected[:, 2]) / 2, (expected[:, 1] + expected[:, 3]) / 2]
            sizes = np.c_[expected[:, 2] - expected[:, 0], expected[:, 3] - expected[:, 1]]
            assert len(boxes) == len(expected) > 0
            np.testing.assert_allclose(boxes, np.c_[centres, sizes, expected[:, 4]], atol=1e-4)
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
