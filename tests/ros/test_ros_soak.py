"""The soak benchmark's bookkeeping (issue #9): restamping, frame grouping, memory/track report.

The soak itself runs for minutes and is a benchmark (``make soak-graph``); these tests check,
on fake samples and hand-made CDR bytes, the parts whose mistakes would make its numbers lie.
"""

from __future__ import annotations

import struct
from types import SimpleNamespace

import pytest

pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

from gldt_core.io.bag import IMAGE_TYPES
from gldt_core.io.cdr import header_stamp_ns, with_header_stamp
from gldt_ros.bench.soak import (
    Sample,
    build_report,
    format_report,
    group_frames,
    parse_importtime,
    rss_summary,
)

MIB = 1024 * 1024


def cdr_with_stamp(stamp_ns: int, payload: bytes = b"frame_id\x00rest", little_endian: bool = True) -> bytes:
    seconds, nanoseconds = divmod(stamp_ns, 1_000_000_000)
    header = b"\x00\x01\x00\x00" if little_endian else b"\x00\x00\x00\x00"
    return header + struct.pack("<iI" if little_endian else ">iI", seconds, nanoseconds) + payload


@pytest.mark.parametrize("little_endian", [True, False])
def test_with_header_stamp_replaces_only_the_stamp(little_endian: bool) -> None:
    original = cdr_with_stamp(1_500_000_000, little_endian=little_endian)
    patched = with_header_stamp(original, 123_456_789_012)
    assert header_stamp_ns(patched) == 123_456_789_012
    assert patched[:4] == original[:4] and patched[12:] == original[12:]


def test_group_frames_puts_the_image_last_and_drops_imageless_frames() -> None:
    def message(topic: str, msgtype: str, stamp: int) -> SimpleNamespace:
        return SimpleNamespace(topic=topic, msgtype=msgtype, data=cdr_with_stamp(stamp))

    image, info, truth = (
        "sensor_msgs/msg/CompressedImage",
        "sensor_msgs/msg/CameraInfo",
        "gldt_msgs/msg/GroundTruthArray",
    )
    messages = [
        message("img", image, 0),
        message("info", info, 0),
        message("gt", truth, 0),
        message("info", info, 33),
        message("img", image, 33),
        message("gt", truth, 66),  # no image at this stamp
    ]
    frames = group_frames(messages, IMAGE_TYPES)
    assert [[m.topic for m in frame] for frame in frames] == [["info", "gt", "img"], ["info", "img"]]


def sample(t_s: float, rss_mib: dict[str, float], pids: dict[str, int] | None = None, **tracks) -> Sample:
    rss: dict[str, int | None] = {name: int(value * MIB) for name, value in rss_mib.items()}
    return Sample(t_s=t_s, rss=rss, pids=pids or {name: 1 for name in rss}, **tracks)


def test_rss_growth_is_measured_from_the_first_sample_after_warmup() -> None:
    samples = [
        sample(0.0, {"a": 50.0, "b": 100.0}),  # still warming up: ignored as a start
        sample(30.0, {"a": 100.0, "b": 200.0}),
        sample(60.0, {"a": 130.0, "b": 190.0}),
        sample(90.0, {"a": 110.0, "b": 202.0}),
    ]
    summary = rss_summary(samples, warmup_s=30.0)
    assert summary["a"]["start_mib"] == pytest.approx(100.0)
    assert summary["a"]["growth_pct"] == pytest.approx(10.0)
    assert summary["a"]["peak_mib"] == pytest.approx(130.0)
    assert summary["b"]["growth_pct"] == pytest.approx(1.0)
    assert summary["TOTAL"]["growth_pct"] == pytest.approx(100.0 * 12.0 / 300.0)
    assert summary["TOTAL"]["peak_mib"] == pytest.approx(320.0)
    report = build_report(samples, 30.0, {}, {"frames_published": 100, "tracks_received": 97}, {})
    assert report["rss_goal_met"] is False  # node a grew 10 % > 5 %
    assert report["frames_dropped"] == 3
    assert "+10.0%" in format_report(report)


def test_a_restarted_node_is_flagged_and_a_missing_one_has_no_growth() -> None:
    samples = [
        sample(30.0, {"a": 100.0, "b": 100.0}, pids={"a": 1, "b": 2}),
        sample(60.0, {"a": 100.0, "b": 100.0}, pids={"a": 1, "b": 3}),
    ]
    samples[-1].rss["a"] = None
    summary = rss_summary(samples, warmup_s=0.0)
    assert summary["b"]["restarted"] and not summary["a"]["restarted"]
    assert summary["a"]["growth_pct"] is None
    assert "TOTAL" not in summary
    assert build_report(samples, 0.0, {}, {}, {})["rss_goal_met"] is False


def test_track_table_compares_first_and_last_window_after_warmup() -> None:
    samples = [
        sample(5.0, {"a": 1.0}, tracks_messages=150, tracks_mean=9.0, tracks_max=9, predictions_max=9),
        sample(35.0, {"a": 1.0}, tracks_messages=150, tracks_mean=1.0, tracks_max=1, predictions_max=2),
        sample(65.0, {"a": 1.0}, tracks_messages=50, tracks_mean=3.0, tracks_max=4, predictions_max=6),
    ]
    table = build_report(samples, 30.0, {}, {}, {})["track_table"]
    assert table["windows"] == 2
    assert table["tracks_mean"] == pytest.approx((150 * 1.0 + 50 * 3.0) / 200)
    assert (table["predictions_max_first_window"], table["predictions_max_last_window"]) == (2, 6)


def test_importtime_charges_self_time_to_root_packages() -> None:
    stderr = (
        "import time: self [us] | cumulative | imported package\n"
        "import time:      1000 |       1000 |     onnxruntime.capi\n"
        "import time:       500 |       3500 |   onnxruntime\n"
        "import time:      2000 |       2000 |     cv2\n"
        "import time:       100 |       5600 | gldt_ros.nodes.x\n"
    )
    total, top = parse_importtime(stderr)
    assert total == pytest.approx(3.6)
    assert top[0] == ("cv2", pytest.approx(2.0)) and top[1] == ("onnxruntime", pytest.approx(1.5))


def test_readiness_is_known_for_exactly_the_graphs_nodes() -> None:
    """The start-up report waits for each node's last subscription: one per node of the graph."""
    from gldt_ros.bench.soak import LAST_SUBSCRIPTION
    from gldt_ros.interface.graph import NODES

    assert set(LAST_SUBSCRIPTION) == set(NODES)
