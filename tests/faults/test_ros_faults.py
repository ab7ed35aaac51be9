"""The ROS graph survives bad input and a node dying mid-replay, and loses no recorded data.

Bad camera input (garbage JPEG, unsupported encoding, empty or short images, a resolution change,
NaN camera_info) costs the node that frame only; frames after it are still tracked. A frame that
cannot be decoded is answered at once, with the tracks' predictions (``SOURCE_UNREADABLE``), so a
lockstep player never waits for it. A node
killed mid-replay is restarted by ``pipeline``, the graph answers again, and the recording stays
readable with every message it received.
"""

from __future__ import annotations

import importlib
import time
from functools import partial
from pathlib import Path

import cv2
import numpy as np
import pytest

from support import PIPELINE, REPO_ROOT, isolated_ros_env

rclpy = pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

from rclpy.executors import MultiThreadedExecutor  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402

from gldt_ros.interface.graph import NODES  # noqa: E402
from gldt_ros.runtime.spin import start_spin_thread  # noqa: E402

RELIABLE = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)


class InProcessGraph:
    """The graph's nodes in this process, plus a probe that publishes camera input and counts tracks."""

    def __init__(self, transport: str = "compressed") -> None:
        from gldt_msgs.msg import TrackArray
        from sensor_msgs.msg import CameraInfo, CompressedImage, Image

        rclpy.init()
        # The buffer reads one camera input (``image_transport``); the probe publishes both kinds.
        # Every frame waits for its detections (as in lockstep): the tests ask which detector
        # answered, and a cold model's first runs here (no warm-up frame) can outlast the deadline;
        # every GD pair is fused, as offline.
        args = ["--ros-args", "-p", "camera_qos:=reliable", "-p", f"image_transport:={transport}"]
        args += ["-p", "answer_deadline:=0.0", "-p", "tile_budget:=0.0"]
        by_name = {name: importlib.import_module(module).create_node(cli_args=args) for name, module in NODES.items()}
        self.nodes = list(by_name.values())
        self.buffer, self.tracker = by_name["frame_pair_buffer"], by_name["jptrack_tracker"]
        self.probe = rclpy.create_node("fault_probe")
        self.tracks: list = []
        self.probe.create_subscription(TrackArray, "gldt/tracks", self.tracks.append, RELIABLE)
        self.raw = self.probe.create_publisher(Image, "/camera/image_raw", RELIABLE)
        self.compressed = self.probe.create_publisher(CompressedImage, "/camera/image_raw/compressed", RELIABLE)
        self.info = self.probe.create_publisher(CameraInfo, "/camera/camera_info", RELIABLE)
        self.executor = MultiThreadedExecutor(num_threads=4)
        for node in [*self.nodes, self.probe]:
            self.executor.add_node(node)
        self.thread = start_spin_thread(self.executor)
        deadline = time.monotonic() + 10
        camera = self.raw if transport == "raw" else self.compressed
        while time.monotonic() < deadline and camera.get_subscription_count() == 0:
            time.sleep(0.05)
        self.stamp = 0

    def header(self):
        from std_msgs.msg import Header

        self.stamp += 1
        header = Header(frame_id="camera")
        header.stamp.sec, header.stamp.nanosec = divmod(self.stamp * 33_333_333, 1_000_000_000)
        return header

    def send_and_wait(self, publish, expect_answer: bool, timeout_s: float = 20.0) -> None:
        before = len(self.tracks)
        publish()
        deadline = time.monotonic() + (timeout_s if expect_answer else 1.5)
        while time.monotonic() < deadline and len(self.tracks) == before:
            time.sleep(0.02)
        assert (len(self.tracks) > before) == expect_answer, f"expected answer={expect_answer}"

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=2.0)
        # Destroying nodes while the spin thread still runs a callback leaves that callback's
        # task failing with "cannot use Destroyable", reported at exit as never retrieved.
        self.thread.join(timeout=5.0)
        for node in [*self.nodes, self.probe]:
            node.destroy_node()
        rclpy.shutdown()


def jpeg_message(frame: np.ndarray, header):
    from sensor_msgs.msg import CompressedImage

    ok, data = cv2.imencode(".jpg", frame)
    assert ok
    message = CompressedImage(header=header, format="jpeg")
    message.data = data.tobytes()
    return message


def raw_message(frame: np.ndarray, encoding: str, header, data: bytes | None = None):
    from sensor_msgs.msg import Image

    channels = 1 if frame.ndim == 2 else frame.shape[2]
    message = Image(
        header=header, height=frame.shape[0], width=frame.shape[1], encoding=encoding, step=frame.shape[1] * channels
    )
    message.data = frame.tobytes() if data is None else data
    return message


@pytest.fixture()
def graph():
    """Function-scoped: its nodes share the DDS domain, so they must be gone before other tests run."""
    graph = InProcessGraph()
    yield graph
    graph.close()


@pytest.fixture()
def raw_graph():
    """The graph reading ``camera/image_raw`` (the default transport)."""
    graph = InProcessGraph("raw")
    yield graph
    graph.close()


def sky(width: int, height: int) -> np.ndarray:
    frame = np.zeros((height, width, 3), np.uint8)
    frame[:] = (200, 170, 140)
    cv2.circle(frame, (width // 2, height // 2), 6, (40, 40, 40), -1)
    return frame


def test_bad_raw_images_cost_only_that_frame(raw_graph: InProcessGraph) -> None:
    graph = raw_graph
    frame = sky(640, 480)
    graph.send_and_wait(partial(graph.raw.publish, raw_message(frame, "bgr8", graph.header())), True)
    dropped = graph.buffer.frames_dropped
    bad_inputs = [
        lambda: graph.raw.publish(raw_message(frame, "yuv422", graph.header())),
        lambda: graph.raw.publish(raw_message(frame, "bgr8", graph.header(), data=frame.tobytes()[:1000])),
        lambda: graph.raw.publish(raw_message(np.zeros((0, 0, 3), np.uint8), "bgr8", graph.header())),
    ]
    for publish in bad_inputs:
        graph.send_and_wait(publish, expect_answer=True)
        assert graph.tracks[-1].source == graph.tracks[-1].SOURCE_UNREADABLE
    assert graph.buffer.frames_dropped == dropped + len(bad_inputs)
    assert graph.buffer.events["frames_unreadable"] == len(bad_inputs)
    # The node is still up, and every supported encoding is processed after the bad frames.
    for encoding, payload in (("bgr8", frame), ("rgb8", frame[:, :, ::-1].copy()), ("mono8", frame[:, :, 0].copy())):
        graph.send_and_wait(partial(graph.raw.publish, raw_message(payload, encoding, graph.header())), True)


def test_bad_camera_input_costs_only_that_frame(graph: InProcessGraph) -> None:
    from sensor_msgs.msg import CameraInfo

    frame = sky(640, 480)
    graph.send_and_wait(lambda: graph.compressed.publish(jpeg_message(frame, graph.header())), True)
    dropped = graph.buffer.frames_dropped
    graph.send_and_wait(
        lambda: graph.compressed.publish(_garbage_jpeg(graph.header())), expect_answer=True, timeout_s=2.0
    )
    assert graph.tracks[-1].source == graph.tracks[-1].SOURCE_UNREADABLE
    assert graph.buffer.frames_dropped == dropped + 1
    graph.send_and_wait(lambda: graph.compressed.publish(jpeg_message(frame, graph.header())), True)
    assert graph.tracks[-1].source == graph.tracks[-1].SOURCE_GLOBAL
    # A resolution change mid-stream re-initialises and goes on.
    graph.send_and_wait(lambda: graph.compressed.publish(jpeg_message(sky(1280, 720), graph.header())), True)
    # Unusable camera_info: one WARN in the tracker's diagnostics, bearings invalid, tracks flow.
    good_k = [900.0, 0.0, 640.0, 0.0, 900.0, 360.0, 0.0, 0.0, 1.0]
    assert "camera_info" in graph.tracker.warnings()  # none received yet

    def publish_info(usable: bool, **fields) -> None:
        graph.info.publish(CameraInfo(width=1280, height=720, **fields))
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline and (graph.tracker.camera is not None) != usable:
            time.sleep(0.02)

    publish_info(True, k=good_k, distortion_model="plumb_bob", d=[0.0] * 5)
    graph.send_and_wait(lambda: graph.compressed.publish(jpeg_message(sky(1280, 720), graph.header())), True)
    assert graph.tracker.camera is not None and "camera_info" not in graph.tracker.warnings()
    broken = {
        "NaN in K": {"k": [float("nan")] * 9, "distortion_model": "plumb_bob", "d": [0.0] * 5},
        "zeros in K": {"k": [0.0] * 9, "distortion_model": "plumb_bob", "d": [0.0] * 5},
        "D of the wrong length": {"k": good_k, "distortion_model": "plumb_bob", "d": [0.1, 0.01, 0.0]},
        "unknown distortion model": {"k": good_k, "distortion_model": "kannala_brandt_9", "d": [0.0] * 9},
    }
    for case, fields in broken.items():
        publish_info(False, **fields)
        graph.send_and_wait(lambda: graph.compressed.publish(jpeg_message(sky(1280, 720), graph.header())), True)
        assert graph.tracker.camera is None, case
        warning = graph.tracker.warnings().get("camera_info", "")
        assert "camera_info" in warning and "\n" not in warning, f"{case}: {warning!r}"
        assert graph.tracker.diagnostics_status().level == graph.tracker.diagnostics_status().WARN, case
        assert all(not t.bearing_valid for t in graph.tracks[-1].tracks), case


def _garbage_jpeg(header):
    from sensor_msgs.msg import CompressedImage

    message = CompressedImage(header=header, format="jpeg")
    message.data = b"\xff\xd8 definitely not a jpeg"
    return message


@pytest.mark.parametrize("victim", NODES)
def test_killed_node_is_restarted_and_the_recording_keeps_everything(tmp_path: Path, victim: str) -> None:
    """Issue 9: kill any one node mid-replay; the graph answers again once the new process is linked.

    The lockstep driver gives up the frame in flight when the supervisor restarts the node, waits
    until the new process is matched on every link, then sends the next frame: that frame must be
    answered, and the recording must hold every track message, in frame order. How many seconds
    all this takes depends on the machine, so it is measured by ``python -m gldt_ros.bench.restart``,
    not asserted here.
    """
    from gldt_ros.bench.restart import recorded_track_times, run_with_kill
    from gldt_ros.runtime.shm_cleanup import SHM_DIRECTORY

    record = tmp_path / "graph.mcap"
    # The 150-frame bag replays in a few seconds on a fast machine: kill early enough that the
    # kill lands mid-replay there. On a slow machine it may land before the first frame, which
    # the driver must handle just the same.
    # --spare-delay 0: the spare must be warm before the kill for the restart to use it.
    run = run_with_kill(
        victim,
        REPO_ROOT / "bags" / "halmstad_v_drone_001",
        record,
        [str(PIPELINE), "--spare-delay", "0", "--processes", "per-node"],
        env=isolated_ros_env(),
        kill_after_s=1.5,
    )
    text = run.text
    # The frame in flight when the node died is given up: pipeline says so and exits 3 (frames
    # unanswered); 0 only where the kill fell between frames.
    lost = run.lines_with("frames lost or unanswered")
    assert run.returncode == (3 if lost else 0), text
    assert all("restart" in line for line in lost), text
    assert len(run.times_of(f"{victim} exited")) == 1, text
    assert (
        len(run.lines_with(f"started {victim} (pid")) == 2
        and "the warm spare" in run.lines_with(f"started {victim}")[1]
    ), "the restart should use the warm spare (gldt_ros.runtime.spare):\n" + text
    assert len(run.times_of(f"{victim} ready")) == 2, f"{victim} should have come up twice (start + restart):\n" + text
    summary = run.lines_with("pipeline: sent ")[0]
    received = int(summary.split(" track messages")[0].rsplit(" ", 1)[1])
    stamps_ns = [stamp for stamp, _ in recorded_track_times(record)]
    assert len(stamps_ns) == received, "the recording lost track messages"
    assert stamps_ns == sorted(stamps_ns), "tracks out of frame order"
    relinked = run.lines_with("graph linked again")
    assert len(relinked) == 1 and victim in relinked[0], (
        f"the driver did not relink the graph after restarting {victim}:\n" + text
    )
    first_after = int(relinked[0].rsplit("next frame stamped ", 1)[1])
    assert first_after in stamps_ns, f"the first frame after the relink went unanswered:\n{text}"
    resumed = [stamp for stamp in stamps_ns if stamp >= first_after]
    assert len(resumed) >= 20, f"only {len(resumed)} frames tracked after the restart"
    # A SIGKILLed process cannot remove its shared-memory segment; the supervisor must (#9: a
    # robot that restarts nodes for weeks must not leak /dev/shm).
    assert run.victim_segments, f"{victim} held no Fast DDS segment when killed (shared-memory transport off?)"
    left = [name for name in run.victim_segments if (SHM_DIRECTORY / name).exists()]
    assert not left, f"segments of the killed {victim} are still in {SHM_DIRECTORY}: {left}\n{text}"


def test_a_killed_group_of_nodes_restarts_as_one_process(tmp_path: Path) -> None:
    """``--processes grouped``: SIGKILL the process that hosts several nodes mid-replay. It is
    restarted once, as one process from the warm spare, every node of it comes up again, the
    driver relinks the graph for all of them, and the replay goes on in frame order."""
    from gldt_ros.bench.restart import recorded_track_times, run_with_kill
    from gldt_ros.interface.graph import GROUPED, PROCESS_LAYOUTS

    group = next(group for group in PROCESS_LAYOUTS[GROUPED] if len(group) > 1)
    label = "+".join(group)
    record = tmp_path / "graph.mcap"
    run = run_with_kill(
        label,
        REPO_ROOT / "bags" / "halmstad_v_drone_001",
        record,
        [str(PIPELINE), "--spare-delay", "0", "--processes", GROUPED],
        env=isolated_ros_env(),
        kill_after_s=1.5,
    )
    text = run.text
    lost = run.lines_with("frames lost or unanswered")
    assert run.returncode == (3 if lost else 0), text
    assert len(run.times_of(f"{label} exited")) == 1, text
    started = run.lines_with(f"started {label} (pid")
    assert len(started) == 2 and "the warm spare" in started[1], text
    for name in group:
        assert len(run.times_of(f"{name} ready")) == 2, f"{name} should have come up twice:\n{text}"
    relinked = run.lines_with("graph linked again")
    assert len(relinked) == 1 and all(name in relinked[0] for name in group), text
    stamps_ns = [stamp for stamp, _ in recorded_track_times(record)]
    assert stamps_ns == sorted(stamps_ns), "tracks out of frame order"
    first_after = int(relinked[0].rsplit("next frame stamped ", 1)[1])
    assert len([stamp for stamp in stamps_ns if stamp >= first_after]) >= 20, text


def test_debug_overlay_is_published_while_someone_watches(graph: InProcessGraph) -> None:
    from sensor_msgs.msg import Image

    overlays: list = []
    subscription = graph.probe.create_subscription(Image, "gldt/debug_image", overlays.append, 10)
    deadline = time.monotonic() + 10
    while graph.buffer.debug_image.get_subscription_count() == 0 and time.monotonic() < deadline:
        time.sleep(0.05)
    frame = sky(640, 480)
    graph.send_and_wait(lambda: graph.compressed.publish(jpeg_message(frame, graph.header())), True)
    deadline = time.monotonic() + 10
    while not overlays and time.monotonic() < deadline:
        time.sleep(0.05)
    graph.probe.destroy_subscription(subscription)
    assert overlays, "no debug overlay while subscribed"
    assert (overlays[-1].width, overlays[-1].height, overlays[-1].encoding) == (640, 480, "bgr8")
    drawn = np.frombuffer(bytes(overlays[-1].data), np.uint8).reshape(480, 640, 3)
    assert np.any(drawn != frame), "the overlay should draw the mode banner onto the frame"
