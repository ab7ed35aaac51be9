"""``gldt bench thresholds``: choose the detector and tracker score thresholds on held-out clips.

The shipped detectors are small and under-confident: AM-YOLO scores most drones it finds well
below the 0.5 the trackers' defaults assume. Which of those boxes reach the tracker (the detector's
``score_threshold``) and which may start or extend a track at the first association stage (the
tracker's high threshold ``t_h`` / ``track_thresh`` and its new-track threshold) decides whether
the GL-DT schedule ever gets a stable track to hand to the local detector. This benchmark runs
GD+LD+JPTrack for each ``DETECTOR:TRACKER`` pair of a grid and prints, per pair:

* MOTA, IDF1, HOTA, IDSW and the share of GD frames on *tuning* drone clips, and
* false track boxes per frame on bird/airplane clips (every drone track there is false),

each as a difference to the first pair of the grid, measured in the same run.

The tuning clips are Halmstad *validation* clips (never trained on), but not the ones
``gldt bench ablation`` reports on: it evaluates the first ``--clips`` drone clips (4 by
default), this benchmark skips the first ``--skip`` (also 4) and uses the next ones, so a
threshold chosen here is then checked on clips it was not chosen on.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

#: The grid printed by default: the GL-DT system's shipped pair first (the peer), then the pairs
#: around it that the choice in ``SHIPPED_DETECTOR_SCORES`` was made from.
DEFAULT_GRID = "0.1:0.55,0.1:0.5,0.1:0.6,0.1:0.65,0.2:0.55,0.1:0.25"


@dataclass(frozen=True)
class ThresholdPair:
    """Lowest score a detector reports, and the tracker's high / new-track threshold."""

    detector: float
    tracker: float

    @property
    def label(self) -> str:
        return f"det {self.detector:g} / trk {self.tracker:g}"


def parse_grid(text: str) -> list[ThresholdPair]:
    """``"0.1:0.25,0.25:0.3"`` -> pairs; one-line ``ValueError`` naming the bad item."""
    pairs = []
    for item in (part.strip() for part in text.split(",")):
        if not item:
            continue
        try:
            detector, tracker = (float(value) for value in item.split(":"))
        except ValueError:
            raise ValueError(f"--grid: {item!r} is not DETECTOR:TRACKER (two numbers, e.g. 0.1:0.25)") from None
        if not (0.0 <= detector <= 1.0 and 0.0 <= tracker <= 1.0):
            raise ValueError(f"--grid: {item!r}: thresholds must lie in [0, 1]")
        pairs.append(ThresholdPair(detector, tracker))
    if not pairs:
        raise ValueError("--grid: no DETECTOR:TRACKER pair given")
    return pairs


def config_for(base: Any, pair: ThresholdPair) -> Any:
    """``base`` with the pair's detector threshold and both trackers' high/new thresholds."""
    import dataclasses

    tracker = dataclasses.replace(
        base.tracker,
        jptrack={**dict(base.tracker.jptrack), "t_h": pair.tracker, "new_track_thresh": pair.tracker},
        bytetrack={**dict(base.tracker.bytetrack), "track_thresh": pair.tracker, "new_track_thresh": pair.tracker},
    )
    detector = dataclasses.replace(base.detector, score_threshold=pair.detector)
    return dataclasses.replace(base, detector=detector, tracker=tracker)


def sweep(
    drone_sequences: Sequence[Any],
    other_sequences: Sequence[Any],
    base_config: Any,
    grid: Sequence[ThresholdPair],
    make_detectors: Callable[[Any], tuple[Any, Any]],
) -> list[dict[str, Any]]:
    """GD+LD+JPTrack for each pair; one dict per pair (metrics in %, false boxes per frame).

    ``make_detectors(config)`` builds the (global, local) detectors for a pair's config: the
    detector threshold lives inside the detectors, so each pair gets its own.
    """
    from gldt_core.eval.mot_metrics import evaluate_many
    from gldt_core.system.gldt_system import GLDTSystem, build_tracker
    from gldt_core.system.runner import run_frames
    from gldt_core.track.class_evidence import drone_track_rows

    rows = []
    for pair in grid:
        config = config_for(base_config, pair).with_changes(local_enabled=True, tracker="jptrack")
        global_detector, local_detector = make_detectors(config)
        results: dict[str, Any] = {}
        frames = global_frames = seconds = 0.0
        false_boxes = other_frames = 0
        for sequence in [*drone_sequences, *other_sequences]:
            system = GLDTSystem(
                config, global_detector=global_detector, local_detector=local_detector, tracker=build_tracker(config)
            )
            result = run_frames(system, sequence)
            if any(sequence is s for s in drone_sequences):
                results[sequence.name] = (sequence.gt, result.rows)
                frames += result.frames
                global_frames += result.global_frames
                seconds += result.seconds
            else:
                false_boxes += drone_track_rows(result.rows)
                other_frames += result.frames
        metrics = evaluate_many(results)["combined"] if results else {}
        row: dict[str, Any] = {"detector": pair.detector, "tracker": pair.tracker, "label": pair.label}
        for key in ("MOTA", "IDF1", "HOTA"):
            row[key] = 100.0 * float(metrics[key]) if metrics else float("nan")
        row["IDSW"] = int(metrics["IDSW"]) if metrics else 0
        row["gd_share"] = global_frames / frames if frames else float("nan")
        row["fps"] = frames / seconds if seconds else float("nan")
        row["false_boxes_per_frame"] = false_boxes / other_frames if other_frames else float("nan")
        rows.append(row)
    return rows


def format_table(rows: list[dict[str, Any]]) -> str:
    """One line per pair, with its difference to the first (the peer)."""
    peer = rows[0]
    lines = [
        f"{'thresholds':<20}{'MOTA':>8}{'IDF1':>8}{'HOTA':>8}{'IDSW':>6}{'GD%':>6}{'FPS':>7}{'false/frame':>13}"
        "   vs first: MOTA, IDF1, false/frame"
    ]
    for row in rows:
        lines.append(
            f"{row['label']:<20}{row['MOTA']:>8.1f}{row['IDF1']:>8.1f}{row['HOTA']:>8.1f}{row['IDSW']:>6d}"
            f"{100 * row['gd_share']:>5.0f}%{row['fps']:>7.1f}{row['false_boxes_per_frame']:>13.3f}"
            f"   {row['MOTA'] - peer['MOTA']:+6.1f} {row['IDF1'] - peer['IDF1']:+6.1f} "
            f"{row['false_boxes_per_frame'] - peer['false_boxes_per_frame']:+7.3f}"
        )
    lines.append("(false/frame: track boxes published as drones per frame on bird/airplane clips, all of them false)")
    return "\n".join(lines)


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``gldt bench thresholds``."""
    parser = subparsers.add_parser(
        "thresholds",
        help="detector/tracker score thresholds on held-out tuning clips (MOTA vs false tracks)",
        description="Run GD+LD+JPTrack on Halmstad validation clips that the ablation does not report on, "
        "once per DETECTOR:TRACKER threshold pair; print MOTA, IDF1, HOTA, GD share and false track boxes "
        "per frame on bird/airplane clips, each against the first pair.",
    )
    parser.add_argument(
        "--grid", default=DEFAULT_GRID, help=f"DETECTOR:TRACKER pairs, first is the peer (default {DEFAULT_GRID})"
    )
    parser.add_argument("--skip", type=int, default=4, help="validation drone clips left for the ablation (default 4)")
    parser.add_argument("--clips", type=int, default=4, help="tuning drone clips after those (default 4)")
    parser.add_argument("--other-clips", type=int, default=4, help="validation bird/airplane clips (default 4)")
    parser.add_argument("--clip-frames", type=int, default=150, help="frames per clip (default 150)")
    parser.add_argument("--halmstad", default=None, help="Halmstad dataset root (default: the shared data)")
    parser.add_argument("--config", metavar="CFG.yaml", help="GL-DT system configuration the pairs are applied to")
    parser.add_argument("--json", metavar="OUT.json", help="also write the rows as JSON")
    parser.set_defaults(func=handle_thresholds)


def handle_thresholds(args: argparse.Namespace) -> int:
    import json
    from pathlib import Path

    from gldt_core.bench.ablation import cache_source
    from gldt_core.eval.halmstad_split import halmstad_split
    from gldt_core.io.sources import open_source
    from gldt_core.paths import halmstad_root
    from gldt_core.system.config import load_config
    from gldt_core.system.gldt_system import build_detectors

    for name in ("skip", "clips", "other_clips", "clip_frames"):
        if getattr(args, name) < 0:
            raise ValueError(f"--{name.replace('_', '-')} must be >= 0, got {getattr(args, name)}")
    grid = parse_grid(args.grid)
    root = Path(args.halmstad or halmstad_root())
    if not (root / "videos").is_dir():
        raise FileNotFoundError(f"Halmstad clips not found: {root / 'videos'} is not a directory (--halmstad)")
    validation = halmstad_split(root)["val"]
    drones = [n for n in validation if n.startswith("V_DRONE")][args.skip : args.skip + args.clips]
    others = [n for n in validation if not n.startswith("V_DRONE")][: args.other_clips]
    if not drones:
        raise ValueError(f"no validation drone clips left after skipping {args.skip}")

    def load(name: str) -> Any:
        source = open_source(root / "videos" / f"{name}.mp4", gt=root / "gt" / f"{name}.txt")
        return cache_source(source, name, args.clip_frames or None)

    rows = sweep([load(n) for n in drones], [load(n) for n in others], load_config(args.config), grid, build_detectors)
    print(
        f"tuning clips: {', '.join(drones)}; bird/airplane clips: {', '.join(others) or 'none'}; "
        f"{args.clip_frames or 'all'} frames each"
    )
    print(format_table(rows))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))
    return 0
