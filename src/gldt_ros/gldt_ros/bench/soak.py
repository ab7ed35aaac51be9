"""Soak and start-up benchmark of the GL-DT node graph (issues #8 and #9); not a unit test.

Usage (workspace on the paths)::

    scripts/with_ros_env.sh python -m gldt_ros.bench.soak --minutes 10 [--bag BAG] [--rate 30] [--json OUT]
    scripts/with_ros_env.sh python -m gldt_ros.bench.soak --startup-only [--import-times]

It starts the graph's node processes exactly as ``pipeline`` does
(:class:`gldt_ros.launcher.pipeline.NodeProcesses`), then loops the bag's frames at ``--rate`` Hz
for ``--minutes``. Every frame is restamped ``first_stamp + i / rate`` so that time only ever goes
forward for the tracker: a replayed bag with its original stamps would make the tracker reset at
every loop and hide a table that grows.

It reports:

* start-up (#8): wall time from launching the node processes to every node being ready, and to
  the first ``/gldt/tracks`` message holding at least one track while the bag plays in real
  time; per node, when it appeared in the graph (interpreter + imports + ``rclpy.init``) and
  when it was ready (plus model loading); ``--import-times`` adds ``python -X importtime`` per node;
* memory (#9): resident set size of every node process (by pid) at the first sample after
  ``--warmup`` seconds, at the end, and its peak; growth goal <= 5 %;
* the track table: size of each ``TrackArray`` (reported tracks) and ``TrackPredictions``
  (confirmed, recovered and recently lost tracks: what the tracker keeps alive) over time, and
  the number of distinct track ids born;
* dropped frames: camera frames published minus ``/gldt/tracks`` messages received, plus each
  node's own ``inputs`` / ``dropped`` counters from ``/diagnostics``.

The report functions at the top need neither ROS nor psutil, so they can be tested on fake samples.
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import subprocess
import sys
import threading
import time
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

MIB = 1024.0 * 1024.0

#: Memory growth of a node between the first and the last sample that issue #9 accepts [%].
GROWTH_GOAL_PCT = 5.0
#: Launch-to-first-track time that issue #8 accepts [s].
STARTUP_GOAL_S = 5.0


# --------------------------------------------------------------------------------------------
# Samples and report (pure functions)
# --------------------------------------------------------------------------------------------


@dataclass
class Sample:
    """One periodic observation of the running graph.

    ``t_s`` counts from the start of the replay; ``rss`` maps node name to resident bytes (None
    when the process was gone); ``tracks_*`` describe the ``/gldt/tracks`` messages received since
    the previous sample, ``predictions_max`` the largest ``TrackPredictions`` in that window.
    """

    t_s: float
    rss: dict[str, int | None]
    pids: dict[str, int]
    frames_published: int = 0
    tracks_received: int = 0
    tracks_messages: int = 0
    tracks_mean: float = 0.0
    tracks_max: int = 0
    predictions_max: int = 0


def rss_summary(samples: Sequence[Sample], warmup_s: float) -> dict[str, dict[str, Any]]:
    """Per node: RSS at the first sample at or after ``warmup_s``, at the last sample, peak, growth.

    The start is taken after warm-up because the first frames still allocate for good (ONNX
    arenas, DDS buffers, caches); growth after that is what a long flight would keep paying.
    A node whose pid changed in between (it was restarted) is flagged: its growth means nothing.
    """
    if not samples:
        return {}
    after = [s for s in samples if s.t_s >= warmup_s] or [samples[-1]]
    first, last = after[0], samples[-1]
    summary: dict[str, dict[str, Any]] = {}
    for name in first.rss:
        start, end = first.rss.get(name), last.rss.get(name)
        peak_values = [value for s in samples if (value := s.rss.get(name)) is not None]
        growth = 100.0 * (end - start) / start if start and end is not None else None
        summary[name] = {
            "start_mib": start / MIB if start is not None else None,
            "end_mib": end / MIB if end is not None else None,
            "peak_mib": max(peak_values) / MIB if peak_values else None,
            "growth_pct": growth,
            "restarted": first.pids.get(name) != last.pids.get(name),
            "start_t_s": first.t_s,
            "end_t_s": last.t_s,
        }
    starts = [v["start_mib"] for v in summary.values()]
    ends = [v["end_mib"] for v in summary.values()]
    if all(v is not None for v in starts + ends):
        total_start, total_end = sum(starts), sum(ends)
        summary["TOTAL"] = {
            "start_mib": total_start,
            "end_mib": total_end,
            "peak_mib": max((_total(s) for s in samples), default=0) / MIB,
            "growth_pct": 100.0 * (total_end - total_start) / total_start if total_start else None,
            "restarted": any(v["restarted"] for v in summary.values()),
            "start_t_s": first.t_s,
            "end_t_s": last.t_s,
        }
    return summary


def _total(sample: Sample) -> int:
    """Sum of the nodes' RSS in one sample (0 if a node was missing: it cannot be the peak)."""
    values = [value for value in sample.rss.values() if value is not None]
    return sum(values) if len(values) == len(sample.rss) else 0


def track_table_summary(samples: Sequence[Sample], warmup_s: float) -> dict[str, Any]:
    """Track-table size over time: mean and max of reported / kept-alive tracks, first vs last window.

    A table that leaks shows as a ``predictions_max`` (or ``tracks_max``) that keeps rising from
    the first window after warm-up to the last one, while the bag's content repeats.
    """
    windows = [s for s in samples if s.t_s >= warmup_s and s.tracks_messages > 0]
    if not windows:
        return {"windows": 0}
    weights = sum(s.tracks_messages for s in windows)
    return {
        "windows": len(windows),
        "tracks_mean": sum(s.tracks_mean * s.tracks_messages for s in windows) / weights,
        "tracks_max": max(s.tracks_max for s in windows),
        "tracks_max_first_window": windows[0].tracks_max,
        "tracks_max_last_window": windows[-1].tracks_max,
        "predictions_max": max(s.predictions_max for s in windows),
        "predictions_max_first_window": windows[0].predictions_max,
        "predictions_max_last_window": windows[-1].predictions_max,
    }


def build_report(
    samples: Sequence[Sample],
    warmup_s: float,
    startup: dict[str, Any],
    replay: dict[str, Any],
    diagnostics: dict[str, dict[str, str]],
) -> dict[str, Any]:
    """Everything the soak measured, as one JSON-able dict (``--json`` writes it as is)."""
    rss = rss_summary(samples, warmup_s)
    nodes = {name: v for name, v in rss.items() if name != "TOTAL"}
    growths = [v["growth_pct"] for v in nodes.values() if v["growth_pct"] is not None]
    published, received = replay.get("frames_published", 0), replay.get("tracks_received", 0)
    return {
        "startup": startup,
        "replay": replay,
        "rss": rss,
        "rss_goal_met": bool(growths) and len(growths) == len(nodes) and max(growths) <= GROWTH_GOAL_PCT,
        "track_table": track_table_summary(samples, warmup_s),
        "frames_dropped": max(published - received, 0),
        "frames_dropped_pct": 100.0 * max(published - received, 0) / published if published else None,
        "diagnostics": diagnostics,
        "samples": [asdict(s) for s in samples],
    }


def _fmt(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def format_report(report: dict[str, Any]) -> str:
    """Human-readable tables of :func:`build_report`'s dict."""
    lines: list[str] = []
    startup = report.get("startup", {})
    if startup:
        lines.append("start-up (from launching the node processes):")
        lines.append(f"  all nodes ready       : {_fmt(startup.get('ready_s'), '6.2f')} s")
        first = startup.get("first_track_s")
        verdict = (
            "" if first is None else (" (goal <= 5 s: met)" if first <= STARTUP_GOAL_S else " (goal <= 5 s: NOT met)")
        )
        lines.append(f"  first non-empty track : {_fmt(first, '6.2f')} s{verdict}")
        lines.append(f"  ready -> first track  : {_fmt(startup.get('ready_to_first_track_s'), '6.2f')} s")
        if startup.get("interpreter_to_launch_s") is not None:
            lines.append(f"  (this process's own start before the launch: {startup['interpreter_to_launch_s']:.2f} s)")
        per_node = startup.get("nodes", {})
        if per_node:
            lines.append(f"  {'node':<18} {'in graph [s]':>12} {'ready [s]':>10}")
            for name, times in per_node.items():
                lines.append(
                    f"  {name:<18} {_fmt(times.get('visible_s'), '12.2f')} {_fmt(times.get('ready_s'), '10.2f')}"
                )
        imports = startup.get("import_times", {})
        if imports:
            lines.append("  python -X importtime, one node module at a time (ms per package, self times):")
            for name, info in imports.items():
                top = ", ".join(f"{pkg} {ms:.0f}" for pkg, ms in info["top"])
                lines.append(f"    {name:<18} total {info['total_ms']:6.0f} ms, wall {info['wall_s']:.2f} s: {top}")
    rss = report.get("rss", {})
    if rss:
        lines.append("resident memory per node process [MiB] (start = first sample after warm-up):")
        lines.append(f"  {'node':<18} {'start':>8} {'end':>8} {'peak':>8} {'growth':>8}")
        for name, v in rss.items():
            flag = "  restarted" if v["restarted"] else ""
            lines.append(
                f"  {name:<18} {_fmt(v['start_mib'], '8.1f')} {_fmt(v['end_mib'], '8.1f')} "
                f"{_fmt(v['peak_mib'], '8.1f')} {_fmt(v['growth_pct'], '+7.1f')}%{flag}"
            )
        first = next(iter(rss.values()))
        lines.append(
            f"  window {first['start_t_s']:.0f} s -> {first['end_t_s']:.0f} s of replay; "
            f"goal: every node <= {GROWTH_GOAL_PCT:g} % growth: {'met' if report.get('rss_goal_met') else 'NOT met'}"
        )
    table = report.get("track_table", {})
    if table.get("windows"):
        lines.append(
            f"track table: reported tracks mean {table['tracks_mean']:.2f}, max {table['tracks_max']} "
            f"(first window {table['tracks_max_first_window']}, last {table['tracks_max_last_window']}); "
            f"kept alive (predictions) max {table['predictions_max']} "
            f"(first window {table['predictions_max_first_window']}, last {table['predictions_max_last_window']})"
        )
    replay = report.get("replay", {})
    if replay:
        lines.append(
            f"replay: {replay.get('frames_published', 0)} frames in {replay.get('elapsed_s', 0.0):.1f} s "
            f"({replay.get('fps', 0.0):.1f} fps, asked {replay.get('rate_hz', 0.0):g} Hz, "
            f"{replay.get('late_frames', 0)} published late), "
            f"{replay.get('tracks_received', 0)} track messages, {replay.get('track_ids', 0)} distinct track ids, "
            f"restarts {replay.get('restarts', {})}"
        )
        if replay.get("latency_p50_ms") is not None:
            lines.append(
                f"  camera-to-tracks latency p50 {replay['latency_p50_ms']:.0f} ms, "
                f"p99 {replay['latency_p99_ms']:.0f} ms"
            )
        pct = report.get("frames_dropped_pct")
        lines.append(
            f"dropped frames (published - tracks received): {report.get('frames_dropped', 0)} ({_fmt(pct, '.1f')} %)"
        )
    diagnostics = report.get("diagnostics", {})
    if diagnostics:
        counters = ", ".join(
            f"{name} {v.get('inputs', '?')} in / {v.get('dropped', '?')} dropped" for name, v in diagnostics.items()
        )
        lines.append(f"  node counters (/diagnostics): {counters}")
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# Bag frames, restamped
# --------------------------------------------------------------------------------------------


def group_frames(messages: Sequence[Any], image_types: frozenset[str]) -> list[list[Any]]:
    """Group bag messages (``topic``, ``msgtype``, ``data``) into frames by header stamp.

    Within a frame the image goes last, so camera_info and ground truth are there when the graph
    processes it. Frames without an image are dropped (they would not make the graph run).
    """
    from gldt_core.io.cdr import header_stamp_ns

    frames: OrderedDict[int, list[Any]] = OrderedDict()
    for message in messages:
        try:
            stamp = header_stamp_ns(message.data)
        except ValueError:
            continue
        frames.setdefault(stamp, []).append(message)
    grouped = []
    for group in frames.values():
        group.sort(key=lambda m: m.msgtype in image_types)
        if group[-1].msgtype in image_types:
            grouped.append(group)
    return grouped


# --------------------------------------------------------------------------------------------
# Import times (python -X importtime)
# --------------------------------------------------------------------------------------------

_IMPORTTIME = re.compile(r"import time:\s+(\d+)\s+\|\s+(\d+)\s+\|( *)(\S+)")


def parse_importtime(stderr: str, top_n: int = 6) -> tuple[float, list[tuple[str, float]]]:
    """Total ms and the ``top_n`` heaviest root packages of ``-X importtime`` output.

    Each module's *self* time is charged to its root package (``onnxruntime.capi.x`` ->
    ``onnxruntime``): self times add up to the whole import time without double counting, and
    say which library costs it, where cumulative times would charge everything to the node module.
    """
    per_package: dict[str, float] = {}
    for match in _IMPORTTIME.finditer(stderr):
        self_us, module = int(match.group(1)), match.group(4)
        root = module.split(".")[0]
        per_package[root] = per_package.get(root, 0.0) + self_us / 1000.0
    top = sorted(per_package.items(), key=lambda item: item[1], reverse=True)[:top_n]
    return sum(per_package.values()), top


def measure_import_times(node_modules: Mapping[str, str]) -> dict[str, dict[str, Any]]:
    """``python -X importtime -c 'import MODULE'`` for each node's module, one after another
    (``node_modules`` maps node names to modules, as :data:`gldt_ros.interface.graph.NODES` does)."""
    results: dict[str, dict[str, Any]] = {}
    for name, module in node_modules.items():
        start = time.perf_counter()
        completed = subprocess.run(
            [sys.executable, "-X", "importtime", "-c", f"import {module}"],
            capture_output=True,
            text=True,
            timeout=300,
            check=False,
        )
        wall = time.perf_counter() - start
        total, top = parse_importtime(completed.stderr)
        results[name] = {"total_ms": total, "wall_s": wall, "top": top}
    return results


# --------------------------------------------------------------------------------------------
# The running graph
# --------------------------------------------------------------------------------------------


class TrackWindow:
    """Statistics of the ``/gldt/tracks`` and ``/gldt/track_predictions`` messages since the last roll."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.first_track_at: float | None = None
        self.track_ids: set[int] = set()
        self._reset()

    def _reset(self) -> None:
        self.messages = 0
        self.total = 0
        self.maximum = 0
        self.predictions_max = 0

    def on_tracks(self, message: Any) -> None:
        count = len(message.tracks)
        with self._lock:
            if count and self.first_track_at is None:
                self.first_track_at = time.monotonic()
            self.messages += 1
            self.total += count
            self.maximum = max(self.maximum, count)
            self.track_ids.update(int(track.id) for track in message.tracks)

    def on_predictions(self, message: Any) -> None:
        with self._lock:
            self.predictions_max = max(self.predictions_max, len(message.tracks))

    def roll(self) -> dict[str, Any]:
        """Return this window's statistics and start a new window."""
        with self._lock:
            stats = {
                "tracks_messages": self.messages,
                "tracks_mean": self.total / self.messages if self.messages else 0.0,
                "tracks_max": self.maximum,
                "predictions_max": self.predictions_max,
            }
            self._reset()
        return stats


def node_rss(processes: dict[str, Any]) -> tuple[dict[str, int | None], dict[str, int]]:
    """Resident bytes and pid of every node process (None for one that is gone)."""
    import psutil

    rss: dict[str, int | None] = {}
    pids: dict[str, int] = {}
    for name, process in processes.items():
        pids[name] = process.pid
        try:
            rss[name] = psutil.Process(process.pid).memory_info().rss if process.poll() is None else None
        except psutil.Error:
            rss[name] = None
    return rss, pids


#: The subscription each node's constructor creates last: once it is visible the node is ready.
LAST_SUBSCRIPTION = {
    "frame_pair_buffer": "gldt/tracks",
    "mode_scheduler": "gldt/detections",
    "global_detector": "gldt/frame_pairs",
    "local_detector": "gldt/roi_crops",
    "jptrack_tracker": "camera/camera_info",
}


def wait_ready_per_node(
    driver: Any, children: Any, launch: float, timeout_s: float
) -> dict[str, dict[str, float | None]]:
    """Record, per node, when it appeared in the graph and when its last subscription did.

    A node's name shows once its interpreter has imported everything and ``rclpy`` created the
    node; the last subscription its constructor creates (:data:`LAST_SUBSCRIPTION`) shows once
    its models are loaded.
    """
    from gldt_ros.interface.graph import NODES

    times: dict[str, dict[str, float | None]] = {name: {"visible_s": None, "ready_s": None} for name in NODES}
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and not children.dead():
        now = time.monotonic() - launch
        for name, _namespace in driver.get_node_names_and_namespaces():
            if name in times and times[name]["visible_s"] is None:
                times[name]["visible_s"] = now
        for name, entry in times.items():
            if entry["visible_s"] is None or entry["ready_s"] is not None:
                continue
            try:
                subscribed = {topic for topic, _ in driver.get_subscriber_names_and_types_by_node(name, "/")}
            except Exception:  # noqa: BLE001, S112 - the node may vanish between the two calls; next poll
                continue
            if "/" + LAST_SUBSCRIPTION[name] in subscribed:
                entry["ready_s"] = now
        if all(entry["ready_s"] is not None for entry in times.values()):
            break
        time.sleep(0.05)
    return times


def play(
    driver: Any, frames: list[list[Any]], rate_hz: float, duration_s: float, stop: threading.Event, on_frame: Any = None
) -> dict[str, Any]:
    """Publish the frames in a loop at ``rate_hz`` for ``duration_s``, restamped ``first + i / rate``.

    A frame that could not be published on time is published at once and counted as late (the
    player itself fell behind, e.g. on a loaded machine); it never bursts to catch up.
    """
    from gldt_core.io.bag import IMAGE_TYPES
    from gldt_core.io.cdr import header_stamp_ns, with_header_stamp

    period_ns = round(1e9 / rate_hz)
    first_stamp = header_stamp_ns(frames[0][-1].data)
    began = start = time.monotonic()
    published = late = 0
    while not stop.is_set() and time.monotonic() - began < duration_s:
        due = start + published / rate_hz
        delay = due - time.monotonic()
        if delay > 0:
            stop.wait(delay)
        elif delay < -1.0 / rate_hz:
            late += 1
            start = time.monotonic() - published / rate_hz  # re-anchor: no burst to catch up
        stamp = first_stamp + published * period_ns
        for message in frames[published % len(frames)]:
            data = with_header_stamp(message.data, stamp)
            if message.msgtype in IMAGE_TYPES:
                driver.note_published(stamp)
            driver._publisher(message.topic, message.msgtype).publish(data)
        published += 1
        if on_frame is not None:
            on_frame(published)
    elapsed = time.monotonic() - began
    return {
        "frames_published": published,
        "late_frames": late,
        "elapsed_s": elapsed,
        "fps": published / max(elapsed, 1e-9),
    }


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    from gldt_core.paths import REPO_ROOT

    parser = argparse.ArgumentParser(prog="python -m gldt_ros.bench.soak", description=__doc__.split("\n\n")[0])
    parser.add_argument("--bag", type=Path, default=REPO_ROOT / "bags" / "halmstad_v_drone_001")
    parser.add_argument("--minutes", type=float, default=10.0, help="replay duration (default 10)")
    parser.add_argument("--rate", type=float, default=30.0, help="frames per second published (default 30)")
    parser.add_argument(
        "--warmup",
        type=float,
        default=60.0,
        help="seconds of replay before the first memory sample counts "
        "(frame_pair_buffer fills its buffers for most of the first minute)",
    )
    parser.add_argument("--sample-period", type=float, default=5.0, help="seconds between memory samples")
    parser.add_argument("--params", type=Path, default=None, help="ROS parameter YAML (default: the package's)")
    parser.add_argument("--startup-only", action="store_true", help="stop at the first non-empty track (issue #8)")
    parser.add_argument("--import-times", action="store_true", help="also measure each node module's import time")
    parser.add_argument("--max-restarts", type=int, default=0, help="restarts of a node that dies (default 0: stop)")
    parser.add_argument(
        "--default-malloc",
        action="store_true",
        help="nodes with glibc's default malloc settings (the A/B peer of pipeline's tuned ones)",
    )
    parser.add_argument("--json", type=Path, help="write the full report (with every sample) here")
    args = parser.parse_args(argv)
    if args.rate <= 0 or args.minutes <= 0 or args.sample_period <= 0:
        parser.error("--rate, --minutes and --sample-period must be positive")
    return args


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv if argv is not None else sys.argv[1:])
    import psutil

    interpreter_start = psutil.Process().create_time()
    report = run_soak(args, interpreter_start)
    if args.import_times:  # after the graph stopped, so the nodes do not compete with it
        from gldt_ros.interface.graph import NODES

        report["startup"]["import_times"] = measure_import_times(NODES)
    print(format_report(report), flush=True)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=1))
        print(f"soak_graph: report written to {args.json}", flush=True)
    return 0 if report["startup"].get("ready_s") is not None else 1


def run_soak(args: argparse.Namespace, interpreter_start: float) -> dict[str, Any]:
    """Start the graph, measure start-up, play the bag in a loop while sampling; return the report."""
    import rclpy
    from gldt_msgs.msg import TrackArray, TrackPredictions

    from gldt_core.io.bag import IMAGE_TYPES, bag_messages
    from gldt_ros.interface import qos, topics
    from gldt_ros.interface.graph import NODES
    from gldt_ros.launcher.pipeline import NodeProcesses, _supervise_until
    from gldt_ros.launcher.pipeline import parse_args as pipeline_args
    from gldt_ros.runtime.dds_profile import use_frames_profile_if_shipped, use_graph_dds_profile
    from gldt_ros.runtime.executor import background_executor

    pipeline_argv = ["--bag", str(args.bag), "--max-restarts", str(args.max_restarts)] + (
        ["--default-malloc"] if args.default_malloc else []
    )
    pargs = pipeline_args(pipeline_argv + (["--params", str(args.params)] if args.params else []))
    frames = group_frames(list(bag_messages(args.bag, log_time_order=True)), IMAGE_TYPES)
    if not frames:
        raise SystemExit(f"soak_graph: no image frames in {args.bag}")

    use_graph_dds_profile()
    use_frames_profile_if_shipped()  # this process plays the camera
    rclpy.init()
    driver = SoakDriver(pargs)
    window = TrackWindow()
    driver.create_subscription(TrackArray, topics.TRACKS, window.on_tracks, qos.RELIABLE)
    driver.create_subscription(TrackPredictions, topics.TRACK_PREDICTIONS, window.on_predictions, qos.RELIABLE)
    executor, spin_executor = background_executor(pargs.executor)
    executor.add_node(driver)
    spin = threading.Thread(target=spin_executor, daemon=True)
    stop = threading.Event()
    samples: list[Sample] = []
    startup: dict[str, Any] = {}
    replay: dict[str, Any] = {}
    children = None
    try:
        spin.start()
        launch = time.monotonic()
        startup["interpreter_to_launch_s"] = time.time() - interpreter_start
        children = NodeProcesses(pargs)
        startup["nodes"] = wait_ready_per_node(driver, children, launch, pargs.startup_timeout)
        if not driver.wait_for_nodes(list(NODES), pargs.startup_timeout, children.dead):
            return build_report(samples, args.warmup, startup, replay, driver.node_statuses())
        ready = time.monotonic()
        startup["ready_s"] = ready - launch
        children.supervising = args.max_restarts > 0
        if children.supervising:
            threading.Thread(target=_supervise_until, args=(children, stop, driver.note_restarted), daemon=True).start()
        driver._prepare_publishers(stop)
        duration = 60.0 if args.startup_only else 60.0 * args.minutes
        replay_start = time.monotonic()
        next_sample = [replay_start]

        def on_frame(published: int) -> None:
            """Between frames: stop at the first track (--startup-only), take due samples, watch for deaths."""
            now = time.monotonic()
            if args.startup_only and window.first_track_at is not None:
                stop.set()
            if not args.startup_only and now >= next_sample[0]:
                next_sample[0] = now + args.sample_period
                samples.append(take_sample(now - replay_start, children, published, driver, window))
            if children.dead():
                print(f"soak_graph: node(s) {', '.join(children.dead())} exited; stopping", flush=True)
                stop.set()

        replay = play(driver, frames, args.rate, duration, stop, on_frame)
        replay["bag"] = str(args.bag)
        driver.drain(replay["frames_published"], stop, limit_s=10.0)
        if not args.startup_only:
            samples.append(
                take_sample(time.monotonic() - replay_start, children, replay["frames_published"], driver, window)
            )
        if window.first_track_at is not None:
            startup["first_track_s"] = window.first_track_at - launch
            startup["ready_to_first_track_s"] = window.first_track_at - ready
        replay.update(driver.replay_stats(args.rate, window, children))
    finally:
        stop.set()
        if children is not None:
            children.stop()
        executor.shutdown(timeout_sec=2.0)
        driver.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return build_report(samples, args.warmup, startup, replay, driver.node_statuses())


def take_sample(t_s: float, children: Any, published: int, driver: Any, window: TrackWindow) -> Sample:
    rss, pids = node_rss(children.processes)
    return Sample(
        t_s=t_s, rss=rss, pids=pids, frames_published=published, tracks_received=driver.tracks_received, **window.roll()
    )


def _soak_driver_class() -> type:
    from gldt_ros.launcher.replay import GraphDriver

    class SoakDriver(GraphDriver):
        """``GraphDriver`` plus the replay statistics of the soak report."""

        def replay_stats(self, rate_hz: float, window: TrackWindow, children: Any) -> dict[str, Any]:
            stats: dict[str, Any] = {"rate_hz": rate_hz, "tracks_received": self.tracks_received}
            stats["track_ids"] = len(window.track_ids)
            stats["restarts"] = {name: count for name, count in children.restarts.items() if count}
            with self._answered_cv:
                latencies = sorted(self.latencies_s)
            if latencies:
                stats["latency_p50_ms"] = 1000.0 * statistics.median(latencies)
                stats["latency_p99_ms"] = 1000.0 * latencies[min(len(latencies) - 1, int(0.99 * len(latencies)))]
            return stats

    return SoakDriver


def SoakDriver(args: argparse.Namespace) -> Any:
    """Build the soak's driver node (the class is made lazily: ``rclpy`` is imported only to run)."""
    return _soak_driver_class()(args)


if __name__ == "__main__":
    sys.exit(main())
