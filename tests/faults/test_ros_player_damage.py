"""The graph's player under damaged bags (issue 31, point 2): it reads them as the offline reader
does, skips a message it cannot read with one warning, replays everything readable, and
``pipeline`` exits 3 (with one line saying why) when frames were lost or unanswered, 0 otherwise.
Each test runs the installed command in lockstep with the bag's own stamps, so the recorded
tracks name the frames that were answered."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from support import REAL_BAG, isolated_ros_env, replay_in_lockstep

pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

#: 4 bytes of CDR encapsulation and 5 of nothing: too short to hold a header.
NINE_BYTES = b"\x00\x01\x00\x00" + b"\x00" * 5
BROKEN_FRAME = 10


def image_stamps(bag: Path) -> list[int]:
    """Header stamps of the bag's readable image messages, read as the player reads them (by log
    time, up to any damage), skipping those too short to hold a header."""
    from gldt_core.io.bag import IMAGE_TYPES, bag_messages
    from gldt_core.io.cdr import header_stamp_ns

    stamps = []
    try:
        for message in bag_messages(bag, log_time_order=True):
            if message.msgtype in IMAGE_TYPES and len(message.data) > len(NINE_BYTES):
                stamps.append(header_stamp_ns(message.data))
    except ValueError:
        pass
    return stamps


def recorded_track_stamps(record: Path) -> list[int]:
    from gldt_core.io.recording import iter_recorded

    return [
        int(message.header.stamp.sec) * 1_000_000_000 + int(message.header.stamp.nanosec)
        for _, message, _ in iter_recorded(record, "gldt/tracks")
    ]


def with_nine_byte_image(path: Path) -> tuple[Path, int, int]:
    """A copy of the sample bag as one MCAP file whose image number :data:`BROKEN_FRAME` is 9
    bytes; returns the file, that message's log time and its original stamp."""
    from gldt_core.io.bag import IMAGE_TYPES, bag_messages
    from gldt_core.io.cdr import header_stamp_ns
    from gldt_core.io.mcap_file import McapWriter

    writer = McapWriter(path)
    images = 0
    broken: tuple[int, int] | None = None
    try:
        for message in bag_messages(REAL_BAG):
            data = message.data
            if message.msgtype in IMAGE_TYPES:
                if images == BROKEN_FRAME:
                    broken = (message.log_time_ns, header_stamp_ns(data))
                    data = NINE_BYTES
                images += 1
            writer.write(message.topic, message.msgtype, data, message.log_time_ns)
    finally:
        writer.close()
    assert broken is not None
    return path, broken[0], broken[1]


def test_a_nine_byte_image_costs_that_frame_alone_and_exit_status_3(tmp_path: Path) -> None:
    bag, log_time_ns, lost_stamp = with_nine_byte_image(tmp_path / "nine_bytes.mcap")
    record = tmp_path / "graph.mcap"
    completed = replay_in_lockstep(bag, record, 60)
    output = completed.stdout + completed.stderr
    assert completed.returncode == 3, output[-4000:]
    warnings = [line for line in output.splitlines() if "skipped an unreadable" in line]
    assert len(warnings) == 1, output[-4000:]
    assert "/camera/image_raw/compressed" in warnings[0] and str(log_time_ns) in warnings[0], warnings[0]
    frames = image_stamps(bag)
    assert lost_stamp not in frames and len(frames) == len(image_stamps(REAL_BAG)) - 1
    # Every other frame was sent and answered; the broken one was never sent, so nothing waited for it.
    assert f"sent {len(frames)} frames" in output and " 0 frames without an answer" in output, output[-4000:]
    assert recorded_track_stamps(record) == frames
    reason = [line for line in output.splitlines() if line.startswith("pipeline: frames lost or unanswered:")]
    assert len(reason) == 1 and "1 unreadable bag message(s) skipped (1 of them frames)" in reason[0], reason


def test_a_bag_cut_in_its_data_replays_every_readable_frame_and_exit_status_3(tmp_path: Path) -> None:
    from gldt_core.io.bag import BagSource, bag_channel_types

    bag = tmp_path / "cut"
    shutil.copytree(REAL_BAG, bag)
    (mcap,) = bag.glob("*.mcap")
    content = mcap.read_bytes()
    mcap.write_bytes(content[: int(len(content) * 0.6)])
    assert bag_channel_types(bag) == {}  # no summary: the player learns the channels from the messages
    frames = image_stamps(bag)
    assert len(BagSource(bag)) <= len(frames) < len(image_stamps(REAL_BAG))
    record = tmp_path / "graph.mcap"
    completed = replay_in_lockstep(bag, record, 60)
    output = completed.stdout + completed.stderr
    assert completed.returncode == 3, output[-4000:]
    assert "every graph link matched" in output, output[-4000:]  # the link wait happened
    assert f"sent {len(frames)} frames" in output and " 0 frames without an answer" in output, output[-4000:]
    assert recorded_track_stamps(record) == frames
    reason = [line for line in output.splitlines() if line.startswith("pipeline: frames lost or unanswered:")]
    assert len(reason) == 1 and "the bag ends in damage" in reason[0] and "runs past the end" in reason[0], reason


def test_a_clean_replay_exits_0(tmp_path: Path) -> None:
    record = tmp_path / "graph.mcap"
    completed = replay_in_lockstep(REAL_BAG, record, 60)
    output = completed.stdout + completed.stderr
    assert completed.returncode == 0, output[-4000:]
    assert "frames lost" not in output and "unreadable" not in output and "damage" not in output, output[-4000:]
    assert recorded_track_stamps(record) == image_stamps(REAL_BAG)


def test_the_loss_line_names_each_cause() -> None:
    from gldt_ros.launcher.replay import loss_reason

    assert loss_reason(0, 0, None, 0, lockstep=True) is None
    assert loss_reason(0, 0, None, 2, lockstep=False) == "2 frame(s) without tracks (sent but never answered)"
    line = loss_reason(3, 1, "bag B is damaged", 1, lockstep=True)
    assert line is not None
    assert line.startswith("3 unreadable bag message(s) skipped (1 of them frames); the bag ends in damage")
    assert "1 frame(s) without tracks (given up" in line


def test_a_bag_cut_only_in_its_summary_replays_in_full_and_exits_0(tmp_path: Path) -> None:
    from gldt_core.io.bag import bag_channel_types

    bag = tmp_path / "no_summary"
    shutil.copytree(REAL_BAG, bag)
    (mcap,) = bag.glob("*.mcap")
    content = mcap.read_bytes()
    mcap.write_bytes(content[:-200])
    assert bag_channel_types(bag) == {}
    record = tmp_path / "graph.mcap"
    completed = replay_in_lockstep(bag, record, 60)
    output = completed.stdout + completed.stderr
    assert completed.returncode == 0, output[-4000:]
    assert recorded_track_stamps(record) == image_stamps(REAL_BAG)


def test_a_paced_replay_counts_frames_sent_but_never_answered(tmp_path: Path) -> None:
    """The player alone, with no graph to answer: every frame it sent is unanswered, and says so."""
    import threading

    import rclpy

    from gldt_ros.launcher.pipeline import parse_args
    from gldt_ros.launcher.replay import GraphDriver

    class Publisher:
        sent = 0

        def get_subscription_count(self) -> int:
            return 1

        def publish(self, data: bytes) -> None:
            Publisher.sent += 1

    bag, _, _ = with_nine_byte_image(tmp_path / "nine_bytes.mcap")
    rclpy.init(domain_id=int(isolated_ros_env()["ROS_DOMAIN_ID"]))
    try:
        driver = GraphDriver(parse_args(["--bag", str(bag), "--rate", "20", "--frame-timeout", "1"]))
        driver._publisher = lambda topic, _type: Publisher()  # type: ignore[method-assign]
        driver.graph_nodes = []
        try:
            summary = driver.replay(threading.Event(), lambda: [])
        finally:
            driver.close()
            driver.destroy_node()
    finally:
        rclpy.shutdown()
    frames = len(image_stamps(bag))
    assert f"sent {frames} frames" in summary and f"{frames} frames without an answer" in summary, summary
    assert driver.loss == (
        "1 unreadable bag message(s) skipped (1 of them frames); "
        f"{frames} frame(s) without tracks (sent but never answered)"
    )
