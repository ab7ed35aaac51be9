"""Camera input, stamps and time of the graph (issue #30): one image transport, never both; the
player sends camera_info before the frame it belongs to, restamps the bag to now unless told to
keep its stamps, and publishes /clock; ``pipeline`` hands ``--ros-args`` to its nodes, so a graph
run with ``use_sim_time`` and a remapped camera topic completes.
"""

from __future__ import annotations

import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from support import PIPELINE, SYNTH_BAG, isolated_ros_env

rclpy = pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402

from gldt_ros.interface import qos, topics  # noqa: E402

WIDTH, HEIGHT = 320, 240
#: The test bags' frame stamps: 20 Hz from 0.5 s, as a bag recorded from a fresh clock has.
STAMPS_NS = [500_000_000 + 50_000_000 * i for i in range(6)]


def sky(index: int) -> np.ndarray:
    frame = np.full((HEIGHT, WIDTH, 3), 190, np.uint8)
    frame[100:108, 40 + 10 * index : 52 + 10 * index] = 30
    return frame


# ------------------------------------------------------------------ one camera input, never both


def buffer_ticks(context: Context, transport: str | None, frames: int = 4) -> tuple[Any, list[int]]:
    """A frame_pair_buffer (``image_transport`` given, or its default) fed by a camera that publishes
    every frame both raw and compressed; returns the node and the stamps [ns] of its FrameTicks."""
    import cv2
    from gldt_msgs.msg import FrameTick
    from sensor_msgs.msg import CompressedImage, Image
    from std_msgs.msg import Header

    from gldt_ros.interface.convert import bgr_to_image, stamp_nanoseconds
    from gldt_ros.nodes.frame_pair_buffer import FramePairBuffer

    arguments = ["--ros-args", "-p", "camera_qos:=reliable"]
    arguments += ["-p", f"image_transport:={transport}"] if transport else []
    buffer = FramePairBuffer(cli_args=arguments, context=context)
    camera = rclpy.create_node("dual_camera", context=context)
    ticks: list[int] = []
    camera.create_subscription(
        FrameTick, topics.FRAME_TICKS, lambda t: ticks.append(stamp_nanoseconds(t.header.stamp)), qos.RELIABLE
    )
    raw = camera.create_publisher(Image, topics.IMAGE_RAW, qos.RELIABLE)
    compressed = camera.create_publisher(CompressedImage, topics.IMAGE_COMPRESSED, qos.RELIABLE)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(buffer)
    executor.add_node(camera)
    try:
        deadline = time.monotonic() + 10.0
        # Discovery: the buffer's one camera subscription matched, and the probe's tick subscription.
        while time.monotonic() < deadline and (
            raw.get_subscription_count() + compressed.get_subscription_count() == 0
            or buffer.ticks.get_subscription_count() == 0
        ):
            executor.spin_once(timeout_sec=0.05)
        for index in range(frames):
            header = Header(frame_id="camera")
            header.stamp.sec, header.stamp.nanosec = divmod(STAMPS_NS[index], 1_000_000_000)
            raw.publish(bgr_to_image(sky(index), header))
            jpeg = CompressedImage(header=header, format="jpeg")
            jpeg.data = cv2.imencode(".jpg", sky(index))[1].tobytes()
            compressed.publish(jpeg)
        quiet_until = time.monotonic() + 1.5
        while time.monotonic() < quiet_until:
            count = len(ticks)
            executor.spin_once(timeout_sec=0.05)
            if len(ticks) != count:
                quiet_until = time.monotonic() + 1.5
        return buffer, ticks
    finally:
        executor.shutdown()
        camera.destroy_node()


@pytest.mark.parametrize("transport", [None, "raw", "compressed"], ids=["default", "raw", "compressed"])
def test_a_camera_publishing_raw_and_compressed_feeds_each_frame_once(context: Context, transport: str | None) -> None:
    buffer, ticks = buffer_ticks(context, transport)
    try:
        assert ticks == STAMPS_NS[:4], "each frame must enter the graph exactly once, in order"
        camera_topics = {s.topic_name for s in buffer.subscriptions} & {
            "/camera/image_raw",
            "/camera/image_raw/compressed",
        }
        expected = "/camera/image_raw/compressed" if transport == "compressed" else "/camera/image_raw"
        assert camera_topics == {expected}
        assert buffer.frames_dropped == 0
    finally:
        buffer.destroy_node()


def test_image_transport_auto_is_refused(context: Context) -> None:
    """ "auto" subscribed to both; it is gone, and a parameter file that still says it fails loudly."""
    from gldt_ros.nodes.frame_pair_buffer import FramePairBuffer

    with pytest.raises(ValueError, match="image_transport"):
        FramePairBuffer(cli_args=["--ros-args", "-p", "image_transport:=auto"], context=context)


# ------------------------------------------------------------------ the player


def write_bag(path: Path, *, info_delay_ns: int = 0, transports: tuple[str, ...] = ("compressed",)) -> Path:
    """A small bag: per frame, its image(s) logged first, then camera_info ``info_delay_ns`` later
    (0: the same log time, as ``gldt bag`` writes them), each stamped as its frame."""
    import cv2
    from rosbags.rosbag2 import StoragePlugin, Writer

    from gldt_core.io.bag import CAMERA_INFO_TYPE, COMPRESSED_TOPIC, COMPRESSED_TYPE, IMAGE_TOPIC, IMAGE_TYPE
    from gldt_core.io.ros_types import typestore

    store = typestore()
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connections = {}
        if "raw" in transports:
            connections[IMAGE_TYPE] = writer.add_connection(IMAGE_TOPIC, IMAGE_TYPE, typestore=store)
        if "compressed" in transports:
            connections[COMPRESSED_TYPE] = writer.add_connection(COMPRESSED_TOPIC, COMPRESSED_TYPE, typestore=store)
        info = writer.add_connection("/camera/camera_info", CAMERA_INFO_TYPE, typestore=store)
        for index, stamp in enumerate(STAMPS_NS):
            seconds, nanoseconds = divmod(stamp, 1_000_000_000)
            header = store.types["std_msgs/msg/Header"](
                stamp=store.types["builtin_interfaces/msg/Time"](sec=seconds, nanosec=nanoseconds), frame_id="camera"
            )
            if IMAGE_TYPE in connections:
                image = store.types[IMAGE_TYPE](
                    header=header,
                    height=HEIGHT,
                    width=WIDTH,
                    encoding="bgr8",
                    is_bigendian=0,
                    step=WIDTH * 3,
                    data=sky(index).reshape(-1),
                )
                writer.write(connections[IMAGE_TYPE], stamp, store.serialize_cdr(image, IMAGE_TYPE))
            if COMPRESSED_TYPE in connections:
                jpeg = cv2.imencode(".jpg", sky(index))[1].reshape(-1)
                image = store.types[COMPRESSED_TYPE](header=header, format="jpeg", data=jpeg)
                writer.write(connections[COMPRESSED_TYPE], stamp, store.serialize_cdr(image, COMPRESSED_TYPE))
            k = np.array([300.0, 0, WIDTH / 2, 0, 300.0, HEIGHT / 2, 0, 0, 1])
            camera_info = store.types[CAMERA_INFO_TYPE](
                header=header,
                height=HEIGHT,
                width=WIDTH,
                distortion_model="plumb_bob",
                d=np.zeros(5),
                k=k,
                r=np.eye(3).reshape(-1),
                p=np.array([300.0, 0, WIDTH / 2, 0, 0, 300.0, HEIGHT / 2, 0, 0, 0, 1, 0]),
                binning_x=0,
                binning_y=0,
                roi=store.types["sensor_msgs/msg/RegionOfInterest"](
                    x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
                ),
            )
            writer.write(info, stamp + info_delay_ns, store.serialize_cdr(camera_info, CAMERA_INFO_TYPE))
    return path


class SentLog:
    """Stands in for the player's publishers: records (topic, stamp [ns]) in publishing order, the
    warm-up frame apart (in :attr:`warm_ups`; ``on_warm_up`` answers it, as the graph would)."""

    def __init__(self, on_warm_up: Any = None) -> None:
        self.sent: list[tuple[str, int]] = []
        self.warm_ups: list[tuple[str, int]] = []
        self.on_warm_up = on_warm_up

    def publisher(self, topic: str) -> Any:
        from gldt_core.io.cdr import header_frame_id, header_stamp_ns
        from gldt_ros.interface.graph import WARM_UP_FRAME_ID

        log = self

        class Publisher:
            def get_subscription_count(self) -> int:
                return 1

            def publish(self, data: bytes) -> None:
                if header_frame_id(data) == WARM_UP_FRAME_ID:
                    log.warm_ups.append((topic.lstrip("/"), header_stamp_ns(data)))
                    if log.on_warm_up is not None:
                        log.on_warm_up()
                    return
                log.sent.append((topic.lstrip("/"), header_stamp_ns(data)))

        return Publisher()

    def clock(self, message: Any) -> None:
        self.sent.append(("clock", message.clock.sec * 1_000_000_000 + message.clock.nanosec))

    def of(self, topic: str) -> list[int]:
        return [stamp for name, stamp in self.sent if name == topic]


@pytest.fixture
def player() -> Iterator[None]:
    """rclpy's default context, on a domain of its own: the player's node is created in it."""
    rclpy.init(domain_id=int(isolated_ros_env()["ROS_DOMAIN_ID"]))
    try:
        yield
    finally:
        rclpy.shutdown()


def play(bag: Path, *options: str) -> tuple[SentLog, int]:
    """Replay ``bag`` with ``pipeline``'s player, with no graph (nothing to link with, and in
    lockstep every frame counts as answered at once); returns what it published, in order, and the
    wall time [ns] just before it started."""
    from gldt_ros.launcher.pipeline import parse_args
    from gldt_ros.launcher.replay import GraphDriver, ReplayClock

    driver = GraphDriver(parse_args(["--bag", str(bag), *options]))
    log = SentLog(on_warm_up=lambda: setattr(driver, "_warm_up_answered", True))
    publishers: dict[str, Any] = {}
    driver._publisher = lambda topic, _type: publishers.setdefault(topic, log.publisher(topic))  # type: ignore[method-assign]
    driver._wait_answer = lambda *_: True  # type: ignore[method-assign]
    driver.graph_nodes = []
    driver.clock = ReplayClock(driver)
    driver.clock.publisher.publish = log.clock
    started = time.time_ns()
    try:
        summary = driver.replay(threading.Event(), lambda: [])
    finally:
        driver.close()
        driver.destroy_node()
    assert f"sent {len(STAMPS_NS)} frames" in summary, summary
    # One warm-up frame before the replay (the bag's first image), stamped before the first frame.
    assert [topic for topic, _ in log.warm_ups] == [IMAGE], log.warm_ups
    assert log.warm_ups[0][1] < log.of(IMAGE)[0] or log.of(IMAGE)[0] == 0
    return log, started


IMAGE = "camera/image_raw/compressed"
INFO = "camera/camera_info"


@pytest.mark.parametrize("info_delay_ns", [0, 10_000_000], ids=["same-log-time", "logged-after-the-image"])
def test_camera_info_reaches_the_graph_before_the_first_frame(player: None, tmp_path: Path, info_delay_ns: int) -> None:
    """Frame 0 gets its bearing only if its camera_info is there first; a bag logs it beside the
    image (same log time, image first) or later."""
    log, _ = play(write_bag(tmp_path / "bag", info_delay_ns=info_delay_ns), "--lockstep", "--keep-bag-stamps")
    order = [name for name, _ in log.sent if name in (IMAGE, INFO)]
    assert order.index(INFO) < order.index(IMAGE), order
    assert log.of(IMAGE) == STAMPS_NS
    if info_delay_ns == 0:  # each frame's own camera_info right before it
        assert order == [INFO, IMAGE] * len(STAMPS_NS), order


def test_the_player_restamps_to_now_and_keeps_the_intervals(player: None, tmp_path: Path) -> None:
    log, started = play(write_bag(tmp_path / "bag"), "--lockstep")
    images = log.of(IMAGE)
    assert started <= images[0] <= time.time_ns(), "the first frame is stamped when the replay starts"
    assert np.diff(images).tolist() == np.diff(STAMPS_NS).tolist(), "intervals exact to the nanosecond"
    for name, stamp in log.sent:
        if name == INFO:
            assert stamp in images, "camera_info keeps its frame's (new) stamp"


def test_keep_bag_stamps_replays_the_recorded_stamps(player: None, tmp_path: Path) -> None:
    log, _ = play(write_bag(tmp_path / "bag"), "--lockstep", "--keep-bag-stamps")
    assert log.of(IMAGE) == STAMPS_NS
    assert log.warm_ups[0][1] == max(0, STAMPS_NS[0] - 1_000_000_000)
    assert sorted(set(log.of(INFO))) == STAMPS_NS


def test_lockstep_clock_steps_to_each_frame_before_it_is_sent(player: None, tmp_path: Path) -> None:
    log, _ = play(write_bag(tmp_path / "bag"), "--lockstep", "--keep-bag-stamps")
    clock = log.of("clock")
    assert clock == STAMPS_NS, "one /clock per frame, at its stamp"
    for stamp in STAMPS_NS:
        assert log.sent.index(("clock", stamp)) < log.sent.index((IMAGE, stamp))


def test_paced_clock_runs_with_the_bag_between_frames(player: None, tmp_path: Path) -> None:
    """At the bag's pace the clock moves between frames too (timers of a sim-time node keep
    firing), never backwards, and is at least at each frame's stamp when the frame goes out."""
    log, started = play(write_bag(tmp_path / "bag"), "--rate", "1.0")
    clock = log.of("clock")
    images = log.of(IMAGE)
    assert clock == sorted(clock) and len(set(clock)) == len(clock), "strictly increasing"
    assert len(clock) > 2 * len(images), "ticks between the frames"
    assert started <= clock[0], "restamped: the clock runs on the replay's time, not the bag's"
    for stamp in images:
        before = [value for name, value in log.sent[: log.sent.index((IMAGE, stamp))] if name == "clock"]
        assert before and before[-1] >= stamp - 1_000_000, "the clock reached the frame's time"


def test_a_bag_with_both_transports_is_played_on_the_one_the_graph_reads(player: None, tmp_path: Path) -> None:
    from gldt_ros.launcher.pipeline import node_ros_args, parse_args

    bag = write_bag(tmp_path / "bag", transports=("raw", "compressed"))
    args = parse_args(["--bag", str(bag)])
    assert args.image_transport == "compressed", "the offline reader's choice, so graph and gldt run agree"
    assert "image_transport:=compressed" in node_ros_args("frame_pair_buffer", args)
    log, _ = play(bag, "--lockstep")
    assert len(log.of(IMAGE)) == len(STAMPS_NS) and not log.of("camera/image_raw")
    raw_only = write_bag(tmp_path / "raw", transports=("raw",))
    assert parse_args(["--bag", str(raw_only)]).image_transport == "raw"


# ------------------------------------------------------------------ pipeline's --ros-args


def test_pipeline_hands_its_ros_args_to_every_node_after_its_own() -> None:
    from gldt_ros.interface.graph import NODES
    from gldt_ros.launcher.pipeline import node_arguments, parse_args, player_ros_args

    user = ["-p", "use_sim_time:=true", "-r", "camera/image_raw:=/cam/image"]
    args = parse_args(["--lockstep", "--ros-args", *user, "--", "--frame-timeout", "7"])
    assert args.frame_timeout == 7.0, "options after the ROS arguments' -- are pipeline's again"
    for name in NODES:
        command = node_arguments(name, args)
        at = next(i for i in range(len(command)) if command[i : i + len(user)] == user)
        assert command.index("--params-file") < at, "after the parameter file, so the user's values win"
        assert not [a for a in command[at + len(user) :] if a.startswith(("use_sim_time", "camera/"))]
        if name == "frame_pair_buffer":  # and after pipeline's own overrides
            assert command.index("camera_qos:=reliable") < at
    assert player_ros_args(args) == ["--ros-args", *user], "the player gets them too (it plays the camera)"


@pytest.mark.parametrize("remap", ["__node:=x", "jptrack_tracker:__node:=x", "__ns:=/cam"])
def test_pipeline_refuses_remaps_that_would_rename_the_graph(remap: str, capsys: pytest.CaptureFixture[str]) -> None:
    from gldt_ros.launcher.pipeline import parse_args

    with pytest.raises(SystemExit):
        parse_args(["--ros-args", "-r", remap])
    assert "--namespace" in capsys.readouterr().err


# ------------------------------------------------------------------ the graph under sim time


def stamp_ns(stamp: Any) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def test_a_sim_time_replay_onto_a_remapped_camera_topic_completes(tmp_path: Path) -> None:
    """``pipeline --bag --ros-args -p use_sim_time:=true -r ...``: every frame answered. Nodes and
    recorder take their time from the player's /clock (their stamps lie in the bag's time, with
    ``--keep-bag-stamps`` far from the wall clock's), and the camera remap reached the buffer."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    from gldt_core.io.bag import BagSource
    from gldt_core.io.recording import iter_recorded
    from gldt_ros.interface.graph import NODES
    from gldt_ros.runtime.spin import start_spin_thread

    env = isolated_ros_env()
    bag_stamps = [round(frame.stamp * 1e9) for frame in BagSource(SYNTH_BAG)]
    assert bag_stamps[-1] < 3600 * 1_000_000_000, "the bag's stamps must be far from the wall clock for this test"
    context = Context()
    rclpy.init(context=context, domain_id=int(env["ROS_DOMAIN_ID"]))
    diagnostics: dict[str, list[int]] = {}
    try:
        probe = rclpy.create_node("sim_time_probe", context=context)
        latched = QoSProfile(
            depth=50, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
        )

        def on_diagnostics(array: DiagnosticArray) -> None:
            for status in array.status:
                diagnostics.setdefault(status.name.removeprefix("gldt/"), []).append(stamp_ns(array.header.stamp))

        probe.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, latched)
        # Which publishers of /diagnostics the probe discovered during the run: tells "never
        # discovered" from "discovered, but no message arrived" if a node's statuses are missing.
        discovered: set[str] = set()
        probe.create_timer(
            0.2, lambda: discovered.update(i.node_name for i in probe.get_publishers_info_by_topic("/diagnostics"))
        )
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(probe)
        thread = start_spin_thread(executor)
        record = tmp_path / "graph.mcap"
        remapped = "/remapped/image/compressed"
        completed = subprocess.run(
            [str(PIPELINE), "--bag", str(SYNTH_BAG), "--lockstep", "--keep-bag-stamps", "--record", str(record)]
            + ["--ros-args", "-p", "use_sim_time:=true", "-p", "diagnostics_period:=0.2"]
            + ["-r", f"camera/image_raw/compressed:={remapped}"],
            capture_output=True,
            text=True,
            timeout=600,
            env=env,
        )
        executor.shutdown(timeout_sec=2.0)
        thread.join(timeout=5.0)
        probe.destroy_node()
    finally:
        rclpy.shutdown(context=context)
    output = completed.stdout + completed.stderr
    assert completed.returncode == 0, output[-4000:]
    assert f"sent {len(bag_stamps)} frames" in output and "0 frames without an answer" in output, output[-4000:]
    assert f"camera input: CompressedImage on {remapped}" in output, "the remap did not reach frame_pair_buffer"
    tracks = list(iter_recorded(record, "gldt/tracks"))
    assert [stamp_ns(message.header.stamp) for _, message, _ in tracks] == bag_stamps, "--keep-bag-stamps"
    for _, message, log_time in tracks:  # the recorder's clock is the replay's
        assert bag_stamps[0] <= log_time <= bag_stamps[-1], (log_time, stamp_ns(message.header.stamp))
    for name in NODES:
        in_bag_time = [s for s in diagnostics.get(name, []) if bag_stamps[0] < s <= bag_stamps[-1]]
        assert in_bag_time, (
            f"{name}: no diagnostics stamped in the replay's time: {diagnostics.get(name)}; "
            f"statuses from {sorted(diagnostics)}, publishers discovered {sorted(discovered)}"
        )


def test_a_default_replay_is_stamped_now(tmp_path: Path) -> None:
    """Without --keep-bag-stamps the tracks carry the replay's time (a planner's staleness check
    accepts them), with the bag's intervals."""
    from gldt_core.io.bag import BagSource
    from gldt_core.io.recording import iter_recorded

    bag_stamps = np.array([round(frame.stamp * 1e9) for frame in BagSource(SYNTH_BAG)], dtype=np.int64)
    record = tmp_path / "graph.mcap"
    started = time.time_ns()
    completed = subprocess.run(
        [str(PIPELINE), "--bag", str(SYNTH_BAG), "--lockstep", "--record", str(record)],
        capture_output=True,
        text=True,
        timeout=600,
        env=isolated_ros_env(),
    )
    assert completed.returncode == 0, (completed.stdout + completed.stderr)[-4000:]
    stamps = np.array([stamp_ns(m.header.stamp) for _, m, _ in iter_recorded(record, "gldt/tracks")], dtype=np.int64)
    assert len(stamps) == len(bag_stamps)
    assert started <= stamps[0] <= time.time_ns()
    np.testing.assert_array_equal(stamps - stamps[0], bag_stamps - bag_stamps[0])


# ------------------------------------------------------------------ the end of a paced replay


class _Answers:
    """Stands in for the graph driver's count of answers, which its subscription raises."""

    def __init__(self, received: int = 0) -> None:
        self.tracks_received = received


def test_a_paced_replay_ends_when_its_last_answer_comes_not_a_quiet_period_later() -> None:
    """``pipeline`` prints the replay's time: it must end with the last answer. It used to wait a
    whole quiet period after any answer still missing, one second more than the replay took."""
    from gldt_ros.launcher.replay import GraphDriver

    answers, stop = _Answers(), threading.Event()
    threading.Timer(0.05, lambda: setattr(answers, "tracks_received", 3)).start()
    start = time.monotonic()
    GraphDriver.drain(answers, 3, stop, quiet_s=30.0)  # type: ignore[arg-type]
    assert time.monotonic() - start < 15.0, "it returned at the last answer, long before the quiet period"
    assert answers.tracks_received == 3


def test_a_paced_replay_whose_answers_stop_gives_up_after_the_quiet_period() -> None:
    from gldt_ros.launcher.replay import GraphDriver

    answers, stop = _Answers(1), threading.Event()
    done = threading.Event()

    def drain() -> None:
        GraphDriver.drain(answers, 3, stop, quiet_s=0.2)  # type: ignore[arg-type]
        done.set()

    threading.Thread(target=drain, daemon=True).start()
    assert done.wait(20.0), "a graph that went quiet is not waited for forever"
    stop.set()
