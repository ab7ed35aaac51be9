"""Where a lockstep frame's time goes in the ROS graph, hop by hop (issue #8).

Usage: ``python -m gldt_ros.bench.hops [--bag BAG] [-- PIPELINE_ARGS ...]`` (with the workspace on
the paths, e.g. ``scripts/with_ros_env.sh python -m gldt_ros.bench.hops``).

It replays the bag through ``pipeline --lockstep`` (``--live``: at the bag's own rate) while a probe
node in this process subscribes to the camera topic and to every small message of a frame's chain
(tick, predictions, scheduler decision, detections, tracks) and notes when each arrives, keyed by
the camera stamp all of them copy. The frame pairs and ROI crops are left out on purpose: a probe
decoding them would compete for the two cores with the detector that is timed. Per mode (GD and LD
frames apart) it prints the median time between consecutive arrivals, the detectors' own
``processing_time`` and the total from camera to tracks. The chain is:

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
import threading
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

from gldt_ros.interface import topics

#: The probed topics in chain order; the camera comes first and is whichever one the bag has.
CHAIN = (topics.FRAME_TICKS, topics.TRACK_PREDICTIONS, topics.SCHEDULER_STATE, topics.DETECTIONS, topics.TRACKS)
CAMERA_TOPICS = (topics.IMAGE_RAW, topics.IMAGE_COMPRESSED)


def complete_frames(
    arrivals: Mapping[int, Mapping[str, float]], chain: Sequence[str]
) -> dict[int, Mapping[str, float]]:
    """The frames (by stamp) whose messages reached every topic of ``chain``."""
    return {stamp: times for stamp, times in arrivals.items() if all(topic in times for topic in chain)}


def stage_medians(arrivals: Mapping[int, Mapping[str, float]], chain: Sequence[str]) -> list[tuple[str, str, float]]:
    """Median seconds from each topic of ``chain`` to the next, over the frames (stamps) that
    reached every topic of it; empty if none did."""
    complete = complete_frames(arrivals, chain).values()
    if not complete:
        return []
    return [
        (first, second, statistics.median(times[second] - times[first] for times in complete))
        for first, second in zip(chain, chain[1:])
    ]


def slowest_frames(
    arrivals: Mapping[int, Mapping[str, float]], chain: Sequence[str], count: int
) -> list[tuple[int, float, list[float]]]:
    """The ``count`` complete frames slowest from the first topic of ``chain`` to the last:
    ``(stamp, total, [seconds per stage])``, slowest first. Medians hide stalls; a stall of a
    lockstep frame holds up the whole replay, so these say which hop the replay waits on."""
    complete = complete_frames(arrivals, chain)
    ranked = sorted(complete.items(), key=lambda item: item[1][chain[-1]] - item[1][chain[0]], reverse=True)
    return [
        (stamp, times[chain[-1]] - times[chain[0]], [times[b] - times[a] for a, b in zip(chain, chain[1:])])
        for stamp, times in ranked[:count]
    ]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m gldt_ros.bench.hops", description=__doc__.split("\n\n")[0])
    parser.add_argument("--bag", type=Path, default=Path("bags/halmstad_v_drone_001"), help="bag to replay")
    parser.add_argument(
        "--worst", type=int, default=5, help="also list this many slowest frames stage by stage (0: none)"
    )
    parser.add_argument(
        "--live",
        action="store_true",
        help="replay at the bag's own rate (pipeline --rate 1) instead of --lockstep: where a live frame's time goes, "
        "and which stage its slowest frames waited on",
    )
    parser.add_argument("pipeline_args", nargs="*", help="more `pipeline` arguments (after --)")
    args = parser.parse_args(argv)

    import rclpy
    from gldt_msgs.msg import DetectionArray, FrameTick, SchedulerState, TrackArray, TrackPredictions
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import CompressedImage, Image

    from gldt_ros.bench.graph import graph_run
    from gldt_ros.interface import qos
    from gldt_ros.interface.convert import stamp_nanoseconds
    from gldt_ros.runtime.spin import start_spin_thread

    rclpy.init()
    probe = rclpy.create_node("gldt_hop_probe")
    arrivals: dict[int, dict[str, float]] = {}
    modes: dict[int, str] = {}
    detector_seconds: dict[int, float] = {}
    lock = threading.Lock()

    def note(topic: str):
        def callback(message) -> None:
            now = time.monotonic()
            stamp = stamp_nanoseconds(message.header.stamp)
            with lock:
                arrivals.setdefault(stamp, {}).setdefault(topic, now)
                if isinstance(message, SchedulerState):
                    modes[stamp] = "GD" if message.mode == SchedulerState.MODE_GLOBAL else "LD"
                if isinstance(message, DetectionArray):
                    detector_seconds[stamp] = message.processing_time

        return callback

    types = {
        topics.FRAME_TICKS: FrameTick,
        topics.TRACK_PREDICTIONS: TrackPredictions,
        topics.SCHEDULER_STATE: SchedulerState,
        topics.DETECTIONS: DetectionArray,
        topics.TRACKS: TrackArray,
        topics.IMAGE_RAW: Image,
        topics.IMAGE_COMPRESSED: CompressedImage,
    }
    for topic in (*CAMERA_TOPICS, *CHAIN):
        probe.create_subscription(types[topic], topic, note(topic), qos.RELIABLE)
    executor = SingleThreadedExecutor()
    executor.add_node(probe)
    spinner = start_spin_thread(executor)
    pacing = ["--rate", "1"] if args.live else ["--lockstep"]
    summary = graph_run(args.bag, [*pacing, *args.pipeline_args])  # exits naming what failed
    with lock:
        camera = next((t for t in CAMERA_TOPICS if any(t in times for times in arrivals.values())), None)
        if camera is None:
            raise SystemExit("bench_hops: the probe received no camera frame")
        print(f"bench_hops: {args.bag.name}; {summary.removeprefix('pipeline: ')}")
        chain = (camera, *CHAIN)
        for mode in ("GD", "LD"):
            frames = {stamp: times for stamp, times in arrivals.items() if modes.get(stamp) == mode}
            complete = complete_frames(frames, chain)
            if not complete:
                continue
            print(f"{mode} frames ({len(complete)}), median ms:")
            for first, second, seconds in stage_medians(complete, chain):
                print(f"  {first:>28} -> {second:<24} {1000 * seconds:7.1f}")
            own = [detector_seconds[s] for s in complete if s in detector_seconds]
            print(f"  {'detector processing_time':>28}    {'':<24} {1000 * statistics.median(own):7.1f}")
            total = statistics.median(times[chain[-1]] - times[chain[0]] for times in complete.values())
            print(f"  {'camera -> tracks':>28}    {'':<24} {1000 * total:7.1f}")
        if args.worst > 0:
            names = " | ".join(topic.rsplit("/", 1)[-1] for topic in chain[1:])
            print(f"slowest frames, ms from the previous topic to: {names}")
            for stamp, total, stages in slowest_frames(arrivals, chain, args.worst):
                steps = " | ".join(f"{1000 * seconds:.0f}" for seconds in stages)
                print(f"  {modes.get(stamp, '?')} frame stamped {stamp}: {1000 * total:.0f} ms = {steps}")
    executor.shutdown()
    spinner.join(timeout=5.0)
    probe.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
