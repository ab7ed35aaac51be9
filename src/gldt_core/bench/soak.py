"""``gldt bench soak``: a long real-time replay through GLDTSystem; memory, track table, drops.

A sense-and-avoid stack must run for the whole flight, so this replays a synthetic 1080p scene
at the camera rate (``--fps``, default 30 Hz) for ``--minutes`` (default 10) and watches what
grows. The scene is rendered once and kept JPEG-encoded (``--loop-frames`` frames); it is played
forwards then backwards (ping-pong), so motion stays continuous and the tracker keeps its
identities instead of seeing every target teleport at each loop. Each frame is decoded from JPEG
like a camera or bag frame would be.

Real time works like a ROS subscriber with a queue of one: frame ``k`` becomes available at
``k / fps`` seconds after the start; when the system finishes a frame it takes the newest
available one, and every frame that arrived meanwhile and was overtaken counts as *dropped*.
Processed + dropped = frames the camera delivered.

Detectors: the shipped ONNX models when present (``--detector auto`` or ``shipped``); otherwise
(or with ``--detector oracle``) ground-truth detectors that report the rendered drones, so the
soak still exercises scheduler, ROIs and tracker when the weights are not there.

Printed: resident memory (psutil) at start (after the first frame) and end, growth in percent,
growth after the warm-up (from the sample at 10 % of the run), the track table (live tracks at the
end, the most at any time, ids issued), frames processed/dropped, and the per-frame cost as a
ratio of the frame period (the peer every number is compared against: >1 means it cannot keep up).
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from gldt_core.system.gldt_system import GLDTSystem


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``gldt bench soak``."""
    parser = subparsers.add_parser(
        "soak",
        help="long real-time replay through the GL-DT system: memory growth, track table, dropped frames",
        description="Replay a looped synthetic 1080p scene through GLDTSystem at a fixed rate and "
        "report resident memory (start/end/growth), track-table size and processed/dropped frames.",
    )
    parser.add_argument("--minutes", type=float, default=10.0, help="replay length in minutes (default 10)")
    parser.add_argument("--fps", type=float, default=30.0, help="camera rate in frames/s (default 30)")
    parser.add_argument("--loop-frames", type=int, default=90, help="frames rendered and looped (default 90)")
    parser.add_argument("--seed", type=int, default=21, help="synthetic scene seed (default 21)")
    parser.add_argument("--size", default="1920x1080", help="frame size (default 1920x1080)")
    parser.add_argument("--targets", type=int, default=3, help="UAVs in the scene (default 3)")
    parser.add_argument(
        "--detector",
        choices=("auto", "shipped", "oracle"),
        default="auto",
        help="auto: shipped models if present, else ground-truth detectors (default auto)",
    )
    parser.add_argument(
        "--tracker", choices=("jptrack", "bytetrack"), default=None, help="tracker (default: the config's, jptrack)"
    )
    parser.add_argument("--config", metavar="CFG.yaml", help="GL-DT system configuration (defaults: Table I)")
    parser.add_argument(
        "--sample-every",
        type=float,
        default=None,
        help="seconds between RSS samples (default: 1/60 of the run, 0.5-10 s)",
    )
    parser.add_argument("--json", metavar="OUT.json", help="also write all numbers and the RSS samples as JSON")
    parser.set_defaults(func=handle_soak)


class OracleDetectors:
    """Global and local detectors that report the drones of the current scene frame.

    ``rows`` (MOT ground truth of the frame being processed) is set by the soak loop before each
    ``process`` call; drones less than 30 % visible are not reported, like a real detector."""

    def __init__(self) -> None:
        import numpy as np

        self._np = np
        self.rows = np.zeros((0, 10))

    def _boxes(self):
        np = self._np
        rows = self.rows[(self.rows[:, 7] == 1) & (self.rows[:, 8] > 0.3)]
        x, y, w, h = rows[:, 2], rows[:, 3], rows[:, 4], rows[:, 5]
        return np.column_stack([x, y, x + w, y + h])

    def detect(self, previous_bgr, current_bgr):
        np = self._np
        boxes = self._boxes()
        return np.column_stack([boxes, np.full(len(boxes), 0.9), np.ones(len(boxes))])

    def detect_rois(self, frame_bgr, rois):
        np = self._np
        boxes = self._boxes()
        cx, cy = (boxes[:, 0] + boxes[:, 2]) / 2, (boxes[:, 1] + boxes[:, 3]) / 2
        out = []
        for index, (x1, y1, x2, y2) in enumerate(np.asarray(rois).reshape(-1, 4)):
            inside = (cx >= x1) & (cx < x2) & (cy >= y1) & (cy < y2)
            out.extend([*box, 0.9, 1.0, float(index)] for box in boxes[inside])
        return np.asarray(out, dtype=np.float64).reshape(-1, 7)


def ping_pong(k: int, n: int) -> int:
    """Scene frame shown at global frame ``k`` when ``n`` frames play forwards then backwards."""
    if n <= 1:
        return 0
    period = 2 * (n - 1)
    phase = k % period
    return phase if phase < n else period - phase


def _build_system(args: argparse.Namespace) -> tuple[GLDTSystem, OracleDetectors | None, str]:
    """``(system, oracle or None, detector description)``."""
    from gldt_core.system.config import load_config
    from gldt_core.system.gldt_system import GLDTSystem

    config = load_config(args.config)
    if args.tracker is not None:
        config = config.with_changes(tracker=args.tracker)
    if args.detector in ("auto", "shipped"):
        try:
            return GLDTSystem(config), None, "shipped ONNX models"
        except (FileNotFoundError, ValueError) as error:  # DetectorConfigError is a ValueError
            if args.detector == "shipped":
                raise
            note = f"ground-truth detectors (shipped models unavailable: {str(error).splitlines()[0]})"
    else:
        note = "ground-truth detectors (--detector oracle)"
    oracle = OracleDetectors()
    return GLDTSystem(config, global_detector=oracle, local_detector=oracle), oracle, note


def handle_soak(args: argparse.Namespace) -> int:
    """Run the soak and print the report; returns 0."""
    import gc
    import json
    import time

    import cv2

    from gldt_core.cli import CliError

    try:
        import psutil
    except ImportError:
        raise CliError("gldt bench soak needs psutil to read resident memory: pip install psutil") from None

    from gldt_core.sim.render import SceneRenderer
    from gldt_core.sim.spec import SceneSpec, parse_size

    if not args.minutes > 0 or not args.fps > 0:
        raise ValueError(f"--minutes and --fps must be > 0, got {args.minutes} and {args.fps}")
    if args.loop_frames < 2:
        raise ValueError(f"--loop-frames must be >= 2, got {args.loop_frames}")
    if args.sample_every is not None and not args.sample_every > 0:
        raise ValueError(f"--sample-every must be > 0, got {args.sample_every}")
    size = parse_size(args.size)
    process = psutil.Process()

    system, oracle, detector_note = _build_system(args)
    renderer = SceneRenderer(SceneSpec(seed=args.seed, frames=args.loop_frames, size=size, targets=args.targets))
    encoded, truth = [], []
    for k in range(args.loop_frames):
        image, rows = renderer.render_with_truth(k)
        ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 90])
        if not ok:
            raise ValueError(f"frame {k}: JPEG encoding failed")
        encoded.append(data)
        truth.append(rows)
    del image
    gc.collect()
    rss_setup = process.memory_info().rss

    duration = 60.0 * args.minutes
    period = 1.0 / args.fps
    sample_every = args.sample_every or min(10.0, max(0.5, duration / 60.0))
    processed = dropped = 0
    busy = 0.0
    max_tracks = 0
    max_id = 0
    last_index = -1
    samples: list[tuple[float, int]] = []
    rss_start = None
    next_sample = 0.0
    start = time.perf_counter()
    while True:
        now = time.perf_counter() - start
        if now >= duration:
            break
        newest = int(now * args.fps)
        if newest <= last_index:
            time.sleep(max(0.0, (last_index + 1) * period - now))
            continue
        dropped += newest - last_index - 1
        last_index = newest
        scene_frame = ping_pong(newest, args.loop_frames)
        begin = time.perf_counter()
        frame = cv2.imdecode(encoded[scene_frame], cv2.IMREAD_COLOR)
        assert frame is not None, "the soak decodes the JPEGs it encoded itself"
        if oracle is not None:
            oracle.rows = truth[scene_frame]
        tracks = system.process(frame, newest * period)
        if len(tracks):
            max_id = max(max_id, int(tracks[:, 4].max()))
        busy += time.perf_counter() - begin
        processed += 1
        max_tracks = max(max_tracks, len(getattr(system.tracker, "tracks", ())))
        if rss_start is None:
            rss_start = process.memory_info().rss
            samples.append((now, rss_start))
            next_sample = now + sample_every
        elif now >= next_sample:
            samples.append((now, process.memory_info().rss))
            next_sample += sample_every
    elapsed = time.perf_counter() - start
    delivered = int(min(elapsed, duration) * args.fps) + 1  # frames 0..floor(t * fps) were available
    dropped += max(0, delivered - 1 - last_index)  # frames after the last processed one
    rss_end = process.memory_info().rss
    samples.append((elapsed, rss_end))

    rss_start = rss_start or rss_end
    warm = next((rss for t, rss in samples if t >= 0.1 * duration), rss_start)
    growth = 100.0 * (rss_end - rss_start) / rss_start
    growth_warm = 100.0 * (rss_end - warm) / warm
    tracks_now = len(getattr(system.tracker, "tracks", ()))
    cost_ms = 1000.0 * busy / max(processed, 1)
    load = cost_ms / (1000.0 * period)
    state = system.state
    mib = 1024.0 * 1024.0

    print(
        f"gldt bench soak: {args.minutes:g} min at {args.fps:g} Hz, {size[0]}x{size[1]}, "
        f"{args.loop_frames}-frame scene (seed {args.seed}) played ping-pong; detectors: {detector_note}; "
        f"tracker: {system.config.tracker.name}"
    )
    print(
        f"  frames: {delivered} delivered, {processed} processed, {dropped} dropped "
        f"({100.0 * dropped / max(delivered, 1):.1f} %), {state.reinitialisations} re-initialisations, "
        f"GD on {system.global_share:.0%} of processed frames"
    )
    print(
        f"  per-frame cost {cost_ms:.1f} ms (decode + system) = {load:.2f}x the {1000.0 * period:.1f} ms "
        f"frame period ({'keeps up' if load <= 1.0 else 'cannot keep up: frames are dropped'})"
    )
    print(
        f"  RSS: {rss_setup / mib:.1f} MiB after set-up, {rss_start / mib:.1f} MiB at start (first frame), "
        f"{rss_end / mib:.1f} MiB at end: growth {growth:+.2f} % ({growth_warm:+.2f} % after the first 10 %); "
        f"min/max over {len(samples)} samples {min(r for _, r in samples) / mib:.1f}/"
        f"{max(r for _, r in samples) / mib:.1f} MiB"
    )
    print(f"  track table: {tracks_now} live tracks at end, at most {max_tracks}, highest id reported {max_id}")
    if args.json:
        import os
        from pathlib import Path

        out = Path(args.json)
        report = {
            "minutes": args.minutes,
            "fps": args.fps,
            "size": list(size),
            "loop_frames": args.loop_frames,
            "seed": args.seed,
            "detectors": detector_note,
            "tracker": system.config.tracker.name,
            "frames_delivered": delivered,
            "frames_processed": processed,
            "frames_dropped": dropped,
            "reinitialisations": state.reinitialisations,
            "global_share": system.global_share,
            "cost_ms_per_frame": cost_ms,
            "load": load,
            "rss_setup_bytes": rss_setup,
            "rss_start_bytes": rss_start,
            "rss_end_bytes": rss_end,
            "rss_growth_percent": growth,
            "rss_growth_after_warmup_percent": growth_warm,
            "rss_samples": [[round(t, 3), rss] for t, rss in samples],
            "tracks_at_end": tracks_now,
            "max_tracks": max_tracks,
            "highest_track_id": max_id,
        }
        temp = out.with_name(f".{out.name}.partial")
        temp.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
        os.replace(temp, out)
        print(f"  wrote {out}")
    return 0
