"""global_detector reuses the last pair's features only when the next pair's previous frame is
that very image, and its boxes equal the full model's either way."""

from __future__ import annotations

from collections.abc import Callable
from itertools import islice
from typing import Any

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

from rclpy.context import Context  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from support import REAL_BAG  # noqa: E402

#: Every pair fused whatever its timing, as in a lockstep replay (``tile_budget``).
ALWAYS_FUSE = [Parameter("tile_budget", value=0.0)]


def bag_pairs(count: int) -> tuple[list, int, int, Callable[..., Any]]:
    """The real bag's first ``count`` frames letterboxed as frame_pair_buffer does, their full
    width and height, and ``pair(previous, current, with_previous=True)`` building a FramePair of
    two of them (``with_previous=False``: sent without the previous image, as the buffer does once
    the detector answered that frame)."""
    from gldt_msgs.msg import FramePair
    from sensor_msgs.msg import Image
    from std_msgs.msg import Header

    from gldt_core.detect import GlobalDetector
    from gldt_core.io.sources import open_source
    from gldt_ros.interface.convert import bgr_to_image

    frames = [frame.image for frame in islice(open_source(str(REAL_BAG)), count)]
    geometry = GlobalDetector(num_threads=1, optimize_graph=False)
    prepared = [geometry.prepare(frame) for frame in frames]
    height, width = frames[0].shape[:2]

    def pair(previous: int, current: int, with_previous: bool = True) -> FramePair:
        header = Header(frame_id="camera")
        header.stamp.nanosec = current * 33_333_333
        letterbox = prepared[current][1]
        return FramePair(
            header=header,
            frame_index=current,
            previous_frame_index=previous,
            full_width=width,
            full_height=height,
            scale=float(letterbox.scale),
            pad_x=int(letterbox.pad_x),
            pad_y=int(letterbox.pad_y),
            previous=bgr_to_image(prepared[previous][0], header) if with_previous else Image(header=header),
            current=bgr_to_image(prepared[current][0], header),
        )

    return prepared, width, height, pair


def as_published(rows: np.ndarray) -> np.ndarray:
    """A detector's rows after the node's steps: the system's nested-box suppression."""
    from gldt_core.system.config import DetectorSettings
    from gldt_core.system.steps import drop_nested

    return drop_nested(rows, DetectorSettings().nested_threshold)


def test_pairs_in_a_gd_stretch_reuse_features_and_others_recompute_them(monkeypatch: pytest.MonkeyPatch) -> None:
    from gldt_core.detect import GlobalDetector
    from gldt_ros.nodes.global_detector import GlobalDetectorNode

    prepared, width, height, pair = bag_pairs(5)

    context = Context()
    rclpy.init(context=context)
    try:
        node = GlobalDetectorNode(context=context, parameter_overrides=ALWAYS_FUSE)
        reuse = node.detector.feature_reuse
        assert reuse is not None, "the shipped AM-YOLO comes with its split pair"
        runs: list[int] = []
        original = reuse.features

        def counted_features(blob: np.ndarray) -> Any:
            runs.append(1)
            return original(blob)

        monkeypatch.setattr(reuse, "features", counted_features)
        published: list = []
        full = GlobalDetector(
            num_threads=1,
            score_threshold=node.detector.score_threshold,
            classes=node.detector.classes,
            feature_reuse=False,
            tile_detector=node.detector.tile_detector,  # the default node fuses tiles too
        )
        # A GD stretch 0-1-2, then a pair whose previous frame (3) was never a current one here
        # (skipped, or an LD frame), then 3-4 again in a stretch.
        sequence = [(0, 0), (0, 1), (1, 2), (3, 4)]
        for previous, current in sequence:
            published.append(node.detect(pair(previous, current)))
        assert len(runs) == 2  # the first pair and the one after the gap
        for (previous, current), message in zip(sequence, published):
            expected = as_published(
                full.detect_prepared(prepared[previous][0], prepared[current][0], prepared[current][1], width, height)[
                    0
                ]
            )
            boxes = np.array([[d.center_x, d.center_y, d.width, d.height, d.score] for d in message.detections])
            centres = np.c_[(expected[:, 0] + expected[:, 2]) / 2, (expected[:, 1] + expected[:, 3]) / 2]
            sizes = np.c_[expected[:, 2] - expected[:, 0], expected[:, 3] - expected[:, 1]]
            assert len(boxes) == len(expected) > 0
            np.testing.assert_allclose(boxes, np.c_[centres, sizes, expected[:, 4]], atol=1e-4)
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


def test_a_pair_sent_without_its_previous_frame_uses_the_one_held_or_else_the_frame_itself() -> None:
    """frame_pair_buffer leaves the previous image out once this node answered that frame: the
    boxes must be those of the full pair. A node that does not hold the frame (restarted) pairs
    the current frame with itself and says so, instead of failing on the empty image."""
    from gldt_core.detect import GlobalDetector
    from gldt_ros.nodes.global_detector import GlobalDetectorNode

    prepared, width, height, pair = bag_pairs(3)

    def boxes(message) -> np.ndarray:
        return np.array([[d.center_x, d.center_y, d.width, d.height, d.score] for d in message.detections]).reshape(
            -1, 5
        )

    def expected(previous: int, current: int) -> np.ndarray:
        rows = as_published(
            full.detect_prepared(prepared[previous][0], prepared[current][0], prepared[current][1], width, height)[0]
        )
        return np.c_[
            (rows[:, 0] + rows[:, 2]) / 2,
            (rows[:, 1] + rows[:, 3]) / 2,
            rows[:, 2] - rows[:, 0],
            rows[:, 3] - rows[:, 1],
            rows[:, 4],
        ]

    context = Context()
    rclpy.init(context=context)
    try:
        node = GlobalDetectorNode(context=context, parameter_overrides=ALWAYS_FUSE)
        published: list = []
        warnings: list[str] = []
        node.warn_throttled = lambda key, text: warnings.append(text)  # type: ignore[method-assign]
        full = GlobalDetector(
            num_threads=1,
            score_threshold=node.detector.score_threshold,
            classes=node.detector.classes,
            feature_reuse=False,
            tile_detector=node.detector.tile_detector,  # the default node fuses tiles too
        )
        published.append(node.detect(pair(0, 1, with_previous=True)))
        published.append(node.detect(pair(1, 2, with_previous=False)))  # frame 1 is held here
        assert not warnings
        np.testing.assert_allclose(boxes(published[-1]), expected(1, 2), atol=1e-4)
        assert len(published[-1].detections) > 0

        published.append(node.detect(pair(0, 1, with_previous=False)))  # asks for frame 0; this node holds frame 2
        assert len(warnings) == 1 and "without its previous frame 0" in warnings[0] and "itself" in warnings[0]
        np.testing.assert_allclose(boxes(published[-1]), expected(1, 1), atol=1e-4)
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


def test_the_node_warms_the_model_up_before_it_is_ready_and_keeps_nothing_of_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Blank pairs at a 1080p camera's input size, the second reusing the first one's features
    (both sessions of the split pair run); none of it may pass for a real previous frame."""
    import gldt_ros.nodes.global_detector as module

    calls: list[tuple[tuple[int, ...], bool]] = []
    original = module.GlobalDetector.detect_prepared

    def counting(detector, previous, current, mapping, width, height, previous_features=None):
        calls.append((current.shape, previous_features is not None))
        return original(detector, previous, current, mapping, width, height, previous_features)

    monkeypatch.setattr(module.GlobalDetector, "detect_prepared", counting)
    context = Context()
    rclpy.init(context=context)
    try:
        node = module.GlobalDetectorNode(context=context)
        width, height = node.detector.input_size(1920, 1080)
        assert calls == [((height, width, 3), False)] + [((height, width, 3), True)] * (module.WARM_UP_RUNS - 1)
        assert node.last_pair is None and node.last_pair_index is None
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


def test_the_default_node_publishes_the_offline_systems_fused_rows() -> None:
    """Tile fusion is on by default on the node (``tile_fusion``) and offline
    (``detector.tile_fusion``), and both fuse the same rows: the node gets the letterboxed pair,
    and a 640x512 frame is its own network input. ``tile_fusion:=false`` leaves AM-YOLO alone."""
    from gldt_core.system.config import load_config
    from gldt_core.system.gldt_system import build_detectors
    from gldt_ros.nodes.global_detector import GlobalDetectorNode

    prepared, width, height, pair = bag_pairs(4)
    config = load_config(None)
    assert config.detector.tile_fusion
    offline, _ = build_detectors(config)
    context = Context()
    rclpy.init(context=context)
    try:
        node = GlobalDetectorNode(context=context, parameter_overrides=ALWAYS_FUSE)
        assert node.detector.tile_detector is not None
        for previous, current in [(0, 1), (1, 2), (2, 3)]:
            message = node.detect(pair(previous, current))
            rows = as_published(offline.detect(prepared[previous][0], prepared[current][0]))  # type: ignore[attr-defined]
            boxes = np.array([[d.center_x, d.center_y, d.width, d.height, d.score] for d in message.detections])
            assert len(boxes) == len(rows) > 0
            np.testing.assert_allclose(boxes[:, 4], rows[:, 4], atol=1e-4)
            np.testing.assert_allclose(boxes[:, 0], (rows[:, 0] + rows[:, 2]) / 2, atol=1e-3)
        node.destroy_node()
        alone = GlobalDetectorNode(context=context, parameter_overrides=[Parameter("tile_fusion", value=False)])
        assert alone.detector.tile_detector is None
        alone.destroy_node()
    finally:
        rclpy.shutdown(context=context)


def test_a_pair_too_late_for_its_tile_pass_is_answered_with_am_yolos_boxes_alone() -> None:
    """Live (``tile_budget`` > 0), a pair whose AM-YOLO pass ends too late for the tile pass to fit
    is published with AM-YOLO's boxes alone, as ``tile_fusion:=false`` would, and counted; the
    first pair always runs the pass (its time is not known yet)."""
    from gldt_ros.nodes.global_detector import TILES_SKIPPED, GlobalDetectorNode

    _, _, _, pair = bag_pairs(4)
    context = Context()
    rclpy.init(context=context)
    try:
        node = GlobalDetectorNode(context=context, parameter_overrides=[Parameter("tile_budget", value=1e-6)])
        fused = GlobalDetectorNode(context=context, parameter_overrides=ALWAYS_FUSE)
        alone = GlobalDetectorNode(context=context, parameter_overrides=[Parameter("tile_fusion", value=False)])

        def scores(message: Any) -> list[float]:
            return [round(d.score, 4) for d in message.detections]

        first = node.detect(pair(0, 1))
        assert scores(first) == scores(fused.detect(pair(0, 1))) and node.events[TILES_SKIPPED] == 0
        for previous, current in [(1, 2), (2, 3)]:
            late = node.detect(pair(previous, current))
            assert scores(late) == scores(alone.detect(pair(previous, current)))
        assert node.events[TILES_SKIPPED] == 2
        assert scores(first) != scores(alone.detect(pair(0, 1))), "the tile pass changes this pair's boxes"
        for each in (node, fused, alone):
            each.destroy_node()
    finally:
        rclpy.shutdown(context=context)


def test_a_lockstep_replay_fuses_every_pair_and_a_paced_one_keeps_the_budget() -> None:
    """A lockstep replay must equal the offline run, so no pair's tile pass may depend on timing."""
    from gldt_core.paths import REPO_ROOT
    from gldt_ros.launcher.pipeline import node_ros_args, parse_args

    bag = str(REPO_ROOT / "bags" / "halmstad_v_drone_001")
    assert "tile_budget:=0.0" in node_ros_args("global_detector", parse_args(["--bag", bag, "--lockstep"]))
    assert "tile_budget:=0.0" not in node_ros_args("global_detector", parse_args(["--bag", bag, "--rate", "1"]))
