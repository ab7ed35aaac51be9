"""What one frame-pair hop costs between two processes, per Fast DDS profile (issue #8).

Usage: ``python -m gldt_ros.bench.pair_hop [--rounds 60]`` (with the workspace on the paths, e.g.
``scripts/with_ros_env.sh python -m gldt_ros.bench.pair_hop``).

A sender process publishes ``gldt_msgs/FramePair`` messages of a given image size and waits for
an echo process to answer each with a tiny ``FrameTick``; the round trip is timed. Each writer
profile is measured with the echo process on the shipped small-message profile, as in the graph
(only frame_pair_buffer and the player get ``fastdds_profile_frames.xml``). The peer is the
empty pair (1x1 images) in the same run: what any hop costs, whatever its size.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

from gldt_ros.runtime.dds_profile import DDS_PROFILE_VARIABLE, shipped_frames_profile, shipped_profile

PAIR_TOPIC = "bench_pair_hop/pairs"
ECHO_TOPIC = "bench_pair_hop/echo"
#: (height, width) of each image of the pair: the peer; 300x300, as many bytes as the ROI crops of
#: a LOCAL frame with two ROIs (540 KB, just over Fast DDS's default 512 KiB segment); the two
#: letterbox sizes of the global detector's pairs (1080p and 640x512 cameras).
SIZES = ((1, 1), (300, 300), (384, 640), (512, 640))


def _qos():
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(depth=2, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)


def run_echo() -> int:
    """Answer every frame pair with a FrameTick carrying its header, until killed."""
    import rclpy
    from gldt_msgs.msg import FramePair, FrameTick
    from rclpy.executors import SingleThreadedExecutor

    from gldt_ros.runtime.spin import spin_until_shutdown

    rclpy.init()
    node = rclpy.create_node("bench_pair_hop_echo")
    reply = node.create_publisher(FrameTick, ECHO_TOPIC, _qos())

    def answer(pair: FramePair) -> None:
        reply.publish(FrameTick(header=pair.header))

    node.create_subscription(FramePair, PAIR_TOPIC, answer, _qos())
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        spin_until_shutdown(executor)
    except KeyboardInterrupt:
        pass
    return 0


def run_sender(rounds: int) -> int:
    """Time ``rounds`` round trips per size in :data:`SIZES`; print one line per size."""
    import threading

    import numpy as np
    import rclpy
    from gldt_msgs.msg import FramePair, FrameTick
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import Header

    from gldt_ros.interface.convert import bgr_to_image
    from gldt_ros.runtime.spin import start_spin_thread

    rclpy.init()
    node = rclpy.create_node("bench_pair_hop_sender")
    pairs = node.create_publisher(FramePair, PAIR_TOPIC, _qos())
    answered = threading.Event()
    node.create_subscription(FrameTick, ECHO_TOPIC, lambda _: answered.set(), _qos())
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    thread = start_spin_thread(executor)
    deadline = time.monotonic() + 20.0
    while (
        pairs.get_subscription_count() == 0 or node.count_publishers(ECHO_TOPIC) == 0
    ) and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.5)  # let the reliable links settle (heartbeats) before timing
    status = 0
    for height, width in SIZES:
        image = bgr_to_image(np.zeros((height, width, 3), np.uint8), Header())
        times_ms = []
        for _ in range(rounds):
            answered.clear()
            start = time.perf_counter()
            pairs.publish(FramePair(header=Header(), previous=image, current=image))
            if answered.wait(5.0):
                times_ms.append(1000.0 * (time.perf_counter() - start))
            time.sleep(0.01)
        if not times_ms:
            print(f"SIZE {height}x{width} no answer", flush=True)
            status = 1
            continue
        p50, p90 = np.percentile(times_ms, [50, 90])
        print(f"SIZE {height}x{width} {2 * height * width * 3} {p50:.2f} {p90:.2f} {len(times_ms)}", flush=True)
    executor.shutdown(timeout_sec=2.0)
    thread.join(timeout=2.0)
    node.destroy_node()
    rclpy.shutdown()
    return status


def measure(writer_profile: Path, reader_profile: Path, rounds: int) -> dict[tuple[int, int], tuple[float, float]]:
    """Round-trip (p50, p90) ms per image size with the sender on ``writer_profile``."""
    module = [sys.executable, "-m", "gldt_ros.bench.pair_hop"]
    echo_env = dict(os.environ, **{DDS_PROFILE_VARIABLE: str(reader_profile)})
    echo = subprocess.Popen([*module, "--echo"], env=echo_env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        sender_env = dict(os.environ, **{DDS_PROFILE_VARIABLE: str(writer_profile)})
        completed = subprocess.run(
            [*module, "--sender", "--rounds", str(rounds)], env=sender_env, capture_output=True, text=True, timeout=600
        )
    finally:
        echo.terminate()
        echo.wait(timeout=10)
    results = {}
    for line in completed.stdout.splitlines():
        fields = line.split()
        if len(fields) == 6 and fields[0] == "SIZE":
            height, width = (int(v) for v in fields[1].split("x"))
            results[(height, width)] = (float(fields[3]), float(fields[4]))
    if completed.returncode != 0 or len(results) != len(SIZES):
        raise SystemExit(f"bench_pair_hop: sender failed:\n{completed.stdout[-2000:]}{completed.stderr[-2000:]}")
    return results


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m gldt_ros.bench.pair_hop", description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=60, help="round trips per image size and profile")
    parser.add_argument("--repeats", type=int, default=2, help="times each profile is measured, alternating")
    parser.add_argument("--echo", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--sender", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.echo:
        return run_echo()
    if args.sender:
        return run_sender(args.rounds)
    profiles = {"fastdds_profile.xml": shipped_profile(), "fastdds_profile_frames.xml": shipped_frames_profile()}
    print(
        f"bench_pair_hop: frame-pair round trip between two processes, median (p90) ms of {args.rounds}; "
        "the echo process on fastdds_profile.xml"
    )
    for repeat in range(args.repeats):
        for name, writer in profiles.items():
            results = measure(writer, shipped_profile(), args.rounds)
            empty = results[SIZES[0]][0]
            cells = [
                f"{height}x{width} pair {p50:5.1f} ({p90:5.1f}) x{p50 / empty:4.1f}"
                for (height, width), (p50, p90) in results.items()
            ]
            print(f"  writer on {name:28s} run {repeat + 1}: " + " | ".join(cells), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
