"""``gldt bench planner``: what a planner subscribed to ``/gldt/tracks`` gets, on real clips.

The GL-DT system (shipped models, default configuration) runs over the bundled real sample bag and
the drone clips of both Halmstad validation splits (never trained on); each frame its tracker's
tracks go through :class:`gldt_core.track.planner_stream.PlannerStream`, exactly as the tracker
node does. Printed per sequence, per split and as the worst sequence:

* the stream: track-frames, the share of them coasting, ids with holes (must be 0) against the
  holes the same ids would have in a stream of matched tracks only (the peer: what the graph
  published before coasting tracks), and how many ids ended with a ``removed`` entry;
* time to collision: validity flips per track-frame and the share of valid track-frames, for the
  filtered estimate (:mod:`gldt_core.track.looming`) and for the peer, the looming rule on the
  tracker's raw Kalman size rate (``size / (d size / dt)``, valid while the box grows), on the same
  tracks in the same run; and the share of valid track-frames whose ground-truth box was not
  approaching (1/size fitted over +-1 s of ground truth gives no collision within 60 s).
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

from gldt_core.track.boxes import iou_xyxy

#: Ground-truth looming: a box is "approaching" when 1/size fitted over this window (s) gives a
#: time to collision within :data:`APPROACH_HORIZON_S`.
TRUTH_WINDOW_S = 1.0
APPROACH_HORIZON_S = 60.0
#: A stream entry and a ground-truth box are the same object from this IoU on.
TRUTH_IOU = 0.3
SAMPLE_BAG = "bags/halmstad_v_drone_001"


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``gldt bench planner``."""
    parser = subparsers.add_parser(
        "planner",
        help="the /gldt/tracks stream on real clips: coasting, holes, time-to-collision stability",
        description="Run the GL-DT system on the sample bag and on Halmstad validation clips of both "
        "splits, build the planner's stream each frame and print its invariants and the time-to-"
        "collision stability, against the matched-only stream and the raw size-rate TTC.",
    )
    parser.add_argument("--clips", type=int, default=3, help="drone clips per validation split (default 3)")
    parser.add_argument("--clip-frames", type=int, default=None, help="frames per clip (default: all)")
    parser.add_argument("--halmstad", default=None, help="Halmstad dataset root (clips skipped when absent)")
    parser.add_argument("--bag", default=SAMPLE_BAG, help=f"a bag to run as well (default {SAMPLE_BAG}; '' = none)")
    parser.set_defaults(func=handle_planner)


@dataclass
class StreamCounts:
    """What one sequence's stream looked like; sums over sequences with :meth:`add`."""

    frames: int = 0
    track_frames: int = 0
    coasting: int = 0
    ids: int = 0
    holes: int = 0
    matched_only_holes: int = 0
    removed: int = 0
    without_class: int = 0
    flips: dict[str, int] = field(default_factory=lambda: {"filtered": 0, "raw rate": 0})
    valid: dict[str, int] = field(default_factory=lambda: {"filtered": 0, "raw rate": 0})
    valid_with_truth: dict[str, int] = field(default_factory=lambda: {"filtered": 0, "raw rate": 0})
    valid_not_approaching: dict[str, int] = field(default_factory=lambda: {"filtered": 0, "raw rate": 0})

    def add(self, other: StreamCounts) -> None:
        for name in ("frames", "track_frames", "coasting", "ids", "holes", "matched_only_holes", "removed"):
            setattr(self, name, getattr(self, name) + getattr(other, name))
        self.without_class += other.without_class
        for table in ("flips", "valid", "valid_with_truth", "valid_not_approaching"):
            for key, value in getattr(other, table).items():
                getattr(self, table)[key] += value

    def flip_rate(self, rule: str) -> float:
        return self.flips[rule] / self.track_frames if self.track_frames else 0.0

    def valid_share(self, rule: str) -> float:
        return self.valid[rule] / self.track_frames if self.track_frames else 0.0

    def false_share(self, rule: str) -> float:
        judged = self.valid_with_truth[rule]
        return self.valid_not_approaching[rule] / judged if judged else 0.0


def raw_rate_ttc_valid(track: Any) -> bool:
    """The peer: looming on the tracker's Kalman size rate, valid whenever the box grows."""
    w, h, _, _, vw, vh = (float(v) for v in track.kf.mean[2:8])
    if w <= 0 or h <= 0:
        return False
    size = math.sqrt(w * h)
    return 0.5 * size * (vw / w + vh / h) > 1e-6


def truth_approaching(gt: np.ndarray, fps: float) -> dict[tuple[int, int], bool]:
    """``(frame, gt id) -> approaching`` from a line fitted to 1/size over +-TRUTH_WINDOW_S."""
    out: dict[tuple[int, int], bool] = {}
    half = max(2, int(round(TRUTH_WINDOW_S * fps)))
    for object_id in np.unique(gt[:, 1]).astype(int):
        rows = gt[gt[:, 1] == object_id]
        rows = rows[np.argsort(rows[:, 0])]
        frames = rows[:, 0]
        inverse = 1.0 / np.sqrt(np.maximum(rows[:, 4] * rows[:, 5], 1e-6))
        for frame in frames:
            window = np.abs(frames - frame) <= half
            if window.sum() < half:  # too little ground truth around this frame to judge
                continue
            t = frames[window] / fps
            slope, intercept = np.polyfit(t, inverse[window], 1)
            q = intercept + slope * frame / fps
            out[(int(frame), object_id)] = bool(slope < 0 and -q / slope <= APPROACH_HORIZON_S)
    return out


def run_sequence(sequence: Any, detectors: tuple[Any, Any], config: Any) -> StreamCounts:
    """Run the GL-DT system on one cached sequence and count its planner stream."""
    from gldt_core.system.gldt_system import GLDTSystem
    from gldt_core.system.runner import run_frames
    from gldt_core.track.base import MultiStageTracker
    from gldt_core.track.planner_stream import PlannerStream

    system = GLDTSystem(config, global_detector=detectors[0], local_detector=detectors[1])
    stream = PlannerStream()
    counts = StreamCounts()
    lives: dict[int, list[int]] = {}
    matched_lives: dict[int, list[int]] = {}
    last_valid: dict[str, dict[int, bool]] = {"filtered": {}, "raw rate": {}}
    gt = np.asarray(sequence.gt, dtype=np.float64).reshape(-1, 10)
    drones = gt[gt[:, 7] == 1] if len(gt) else gt
    approaching = truth_approaching(drones, sequence.fps) if len(drones) else {}

    restarts = [0]

    def on_frame(frame: Any, _tracks: np.ndarray) -> None:
        state = system.state
        if state.reinitialisations != restarts[0]:  # the system re-initialised its tracker
            restarts[0] = state.reinitialisations
            stream.restart()
        tracker = cast(MultiStageTracker, system.tracker)  # built by the system: one of ours
        entries = stream.step(
            tracker.tracks,
            float(frame.stamp),
            state.tracks,
            state.detections,
            state.class_probabilities,
            source=state.mode,
        )
        by_id = {stream.published_id(track): track for track in tracker.tracks}
        index = int(frame.index)
        counts.frames += 1
        truth = drones[drones[:, 0] == index + 1]
        truth_boxes = np.column_stack([truth[:, 2], truth[:, 3], truth[:, 2] + truth[:, 4], truth[:, 3] + truth[:, 5]])
        for entry in entries:
            lives.setdefault(entry.track_id, []).append(index)
            if entry.state == "removed":
                counts.removed += 1
                continue
            if entry.matched:
                matched_lives.setdefault(entry.track_id, []).append(index)
            counts.track_frames += 1
            counts.coasting += entry.state == "lost"
            counts.without_class += entry.class_id < 0 and entry.hits > 1
            track = by_id.get(entry.track_id)
            rules = {
                "filtered": bool(entry.looming.valid),
                "raw rate": track is not None and raw_rate_ttc_valid(track),
            }
            judged = None
            if len(truth_boxes):
                box = (
                    entry.center_x - entry.width / 2,
                    entry.center_y - entry.height / 2,
                    entry.center_x + entry.width / 2,
                    entry.center_y + entry.height / 2,
                )
                overlap = iou_xyxy(np.array([box]), truth_boxes)[0]
                best = int(np.argmax(overlap))
                if overlap[best] >= TRUTH_IOU:
                    judged = approaching.get((index + 1, int(truth[best, 1])))
            for rule, valid in rules.items():
                previous = last_valid[rule].get(entry.track_id)
                counts.flips[rule] += previous is not None and previous != valid
                last_valid[rule][entry.track_id] = valid
                counts.valid[rule] += valid
                if valid and judged is not None:
                    counts.valid_with_truth[rule] += 1
                    counts.valid_not_approaching[rule] += not judged

    run_frames(system, sequence, on_frame=on_frame)
    counts.ids = len(lives)
    counts.holes = sum(_holes(frames) for frames in lives.values())
    counts.matched_only_holes = sum(_holes(frames) for frames in matched_lives.values())
    return counts


def _holes(frames: list[int]) -> int:
    """Gaps in an id's sorted frame list (each run of missing frames counts once)."""
    return sum(1 for a, b in zip(frames, frames[1:]) if b > a + 1)


def format_rows(rows: list[tuple[str, StreamCounts]]) -> str:
    header = (
        f"{'sequence':<26} {'frames':>6} {'trk-fr':>7} {'coast%':>7} {'ids':>4} {'holes':>6} {'peer':>5} "
        f"{'removed':>7} {'flips/tf':>9} {'peer':>7} {'valid%':>7} {'peer':>6} {'false%':>7} {'peer':>6}"
    )
    lines = [header, "-" * len(header)]
    for name, c in rows:
        coast = 100.0 * c.coasting / c.track_frames if c.track_frames else 0.0
        lines.append(
            f"{name:<26} {c.frames:>6} {c.track_frames:>7} {coast:>7.1f} {c.ids:>4} {c.holes:>6} "
            f"{c.matched_only_holes:>5} {c.removed:>7} {c.flip_rate('filtered'):>9.3f} {c.flip_rate('raw rate'):>7.3f} "
            f"{100 * c.valid_share('filtered'):>7.1f} {100 * c.valid_share('raw rate'):>6.1f} "
            f"{100 * c.false_share('filtered'):>7.1f} {100 * c.false_share('raw rate'):>6.1f}"
        )
    return "\n".join(lines)


def handle_planner(args: argparse.Namespace) -> int:
    """Run the benchmark and print its table."""
    from pathlib import Path

    from gldt_core.bench.ablation import cache_source, halmstad_sequences
    from gldt_core.eval.halmstad_split import DEFAULT_ROOT
    from gldt_core.io.sources import open_source
    from gldt_core.system.config import load_config
    from gldt_core.system.gldt_system import build_detectors

    config = load_config(None)
    detectors = build_detectors(config)
    groups: list[tuple[str, list[Any]]] = []
    if args.bag:
        if not Path(args.bag).is_dir():
            print(f"bench planner: bag not found: {args.bag}")
            return 2
        groups.append(("sample bag", [cache_source(open_source(args.bag), Path(args.bag).name, args.clip_frames)]))
    root = Path(args.halmstad) if args.halmstad else Path(DEFAULT_ROOT)
    if args.clips > 0 and (root / "videos").is_dir():
        for split in ("val", "val_b"):
            groups.append((split, halmstad_sequences(str(root), args.clips, args.clip_frames, split)))
    elif args.clips > 0:
        print(f"bench planner: no Halmstad clips under {root}; the sample bag only")
    rows: list[tuple[str, StreamCounts]] = []
    worst: tuple[str, StreamCounts] | None = None
    for label, sequences in groups:
        total = StreamCounts()
        for sequence in sequences:
            counts = run_sequence(sequence, detectors, config)
            rows.append((f"  {sequence.name}", counts))
            total.add(counts)
            if worst is None or counts.flip_rate("filtered") > worst[1].flip_rate("filtered"):
                worst = (f"worst: {sequence.name}", counts)
        rows.append((f"{label} (all)", total))
    if worst is not None:
        rows.append(worst)
    print("planner stream (GL-DT, shipped models); holes/peer: id holes in the full stream / in a matched-only")
    print("stream; flips/tf: TTC validity flips per track-frame, filtered / raw size rate; false%: valid TTC")
    print("on a ground-truth box that is not approaching, share of judged valid track-frames")
    print(format_rows(rows))
    return 0
