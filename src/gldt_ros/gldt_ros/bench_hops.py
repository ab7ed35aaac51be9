"""Where a lockstep frame's time goes in the ROS graph, hop by hop (issue #8).

Usage: ``python -m gldt_ros.bench_hops [--bag BAG] [-- PIPELINE_ARGS ...]`` (with the workspace on
the paths, e.g. ``scripts/with_ros_env.sh python -m gldt_ros.bench_hops``).

It replays the bag through ``pipeline --lockstep`` while a probe node in this process subscribes to
the camera topic and to every small message of a frame's chain (tick, predictions, scheduler
decision, detections, tracks) and notes when each arrives, keyed by the camera stamp all of them
copy. The frame pairs and ROI crops are left out on purpose: a probe decoding them would compete
for the two cores with the detector that is timed. Per mode (GD and LD frames apart) it prints the
median time between consecutive arrivals, the detectors' own ``processing_time`` and the total
from camera to tracks. The chain is:

    camera -> frame_pair_buffer -(tick)-> jptrack_tracker -(predictions)-> mode_scheduler
      -(decision)-> frame_pair_buffer -(pair | crops)-> detector -(detections)-> jptrack_tracker -> tracks

so "decision -> detections" holds the buffer's letterbox or crops, the pair or crops hop and the
detector; minus the detector's own time it is what that hop costs. The times are arrivals at the
probe, so two messages sent almost together (detections, then tracks) can arrive in either order
and a stage can come out slightly negative.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import threading
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

#: The probed topics in chain order; the camera comes first and is whichever one the bag has.
CHAIN = ("gldt/frame_ticks", "gldt/track_predictions", "gldt/scheduler/state", "gldt/detections", "gldt/tracks")
CAMERA_TOPICS = ("camera/image_raw", "camera/image_raw/compressed")


def stage_medians(arrivals: Mapping[int, Mapping[str, float]], chain: Sequence[str]) -> list[tuple[str, str, float]]:
    """Median seconds from each topic of ``chain`` to the next, over the frames (stamps) that
    reached every topic of it; empty if none did."""
    complete = [times for times in arrivals.values() if all(topic in times for topic in chain)]
    if not complete:
        return []
    return [
        (first, second, statistics.median(times[second] - times[first] for times in complete))
        for first, second in zip(chain, chain[1:])
    ]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="bench_hops", description=__doc__.split("\n\n")[0])
    parser.add_argument("--bag", type=Path, default=Path("bags/halmstad_v_drone_001"), help="bag to replay")
    parser.add_argument("pipeline_args", nargs="*", help="more `pipeline` arguments (after --)")
    args = parser.parse_args(argv)

    import shutil

    import rclpy
    from gldt_msgs.msg import DetectionArray, FrameTick, SchedulerState, TrackArray, TrackPredictions
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CompressedImage, Image

    pipeline = shutil.which("pipeline")
    if pipeline is None:
        raise SystemExit("bench_hops: `pipeline` not on PATH; run through scripts/with_ros_env.sh")
    rclpy.init()
    probe = rclpy.create_node("gldt_hop_probe")
    arrivals: dict[int, dict[str, float]] = {}
    modes: dict[int, str] = {}
    detector_seconds: dict[int, float] = {}
    lock = threading.Lock()

    def note(topic: str):
        def callback(message) -> None:
            now = time.monotonic()
            stamp = message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec
            with lock:
                arrivals.setdefault(stamp, {}).setdefault(topic, now)
                if isinstance(message, SchedulerState):
                    modes[stamp] = "GD" if message.mode == SchedulerState.MODE_GLOBAL else "LD"
                if isinstance(message, DetectionArray):
                    detector_seconds[stamp] = message.processing_time

        return callback

    reliable = QoSProfile(depth=30, reliability=ReliabilityPolicy.RELIABLE)
    types = {"gldt/frame_ticks": FrameTick, "gldt/track_predictions": TrackPredictions,
             "gldt/scheduler/state": SchedulerState, "gldt/detections": DetectionArray, "gldt/tracks": TrackArray,
             "camera/image_raw": Image, "camera/image_raw/compressed": CompressedImage}
    for topic in (*CAMERA_TOPICS, *CHAIN):
        probe.create_subscription(types[topic], topic, note(topic), reliable)
    executor = SingleThreadedExecutor()
    executor.add_node(probe)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    completed = subprocess.run(
        [pipeline, "--bag", str(args.bag), "--lockstep", *args.pipeline_args], capture_output=True, text=True, check=False
    )
    summary = [line for line in completed.stdout.splitlines() if "replayed" in line]
    if completed.returncode != 0 or not summary:
        raise SystemExit(f"bench_hops: pipeline failed:\n{completed.stdout[-2000:]}{completed.stderr[-2000:]}")
    with lock:
        camera = next((t for t in CAMERA_TOPICS if any(t in times for times in arrivals.values())), None)
        if camera is None:
            raise SystemExit("bench_hops: the probe received no camera frame")
        print(f"bench_hops: {args.bag.name}; {summary[-1].removeprefix('pipeline: ')}")
        chain = (camera, *CHAIN)
        for mode in ("GD", "LD"):
            frames = {stamp: times for stamp, times in arrivals.items() if modes.get(stamp) == mode}
            stages = stage_medians(frames, chain)
            if not stages:
                continue
            complete = [s for s, times in frames.items() if all(t in times for t in chain)]
            print(f"{mode} frames ({len(complete)}), median ms:")
            for first, second, seconds in stages:
                print(f"  {first:>28} -> {second:<24} {1000 * seconds:7.1f}")
            own = [detector_seconds[s] for s in complete if s in detector_seconds]
            print(f"  {'detector processing_time':>28}    {'':<24} {1000 * statistics.median(own):7.1f}")
            total = statistics.median(frames[s][chain[-1]] - frames[s][chain[0]] for s in complete)
            print(f"  {'camera -> tracks':>28}    {'':<24} {1000 * total:7.1f}")
    executor.shutdown()
    spinner.join(timeout=5.0)
    probe.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
