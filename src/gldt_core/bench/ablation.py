"""``gldt bench ablation``: the paper's Table IV, plus where the time goes, in one run.

Four rows per dataset - GD+ByteTrack, GD+LD+ByteTrack, GD+JPTrack, GD+LD+JPTrack - with IDSW,
IDF1, MOTA, MOTP, HOTA (TrackEval definitions, percent) and FPS, on

* synthetic 1080p test scenes (``gldt_core.sim.presets``, test split), and
* the Halmstad validation clips (:mod:`gldt_core.eval.halmstad_split`), skipped with a reason if absent.

All four rows share the same detector instances and the same decoded frames, and take turns frame
by frame so that the machine's drift hits them alike: their FPS are comparable. GD+JPTrack
*is* "the global detector on every frame", so the speed ratio GD+LD+JPTrack / GD+JPTrack is the
GL-DT schedule's gain, measured in the same run. Frames are kept JPEG-encoded in memory and
decoded as they are played, like a video would be; each frame's decode time (``decode`` stage) is
booked to every row.

``--oracle`` keeps all of that but hands the systems each frame's ground truth in place of the
detectors' boxes (:mod:`gldt_core.bench.oracle`): the schedule's GD share and speed-up, and the
tracker's scores, with a detector that never errs, at the configured detectors' cost.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

#: (label, local detection on, tracker) in the paper's order.
VARIANTS = (
    ("GD+ByteTrack", False, "bytetrack"),
    ("GD+LD+ByteTrack", True, "bytetrack"),
    ("GD+JPTrack", False, "jptrack"),
    ("GD+LD+JPTrack", True, "jptrack"),
)
METRICS = ("IDSW", "IDF1", "MOTA", "MOTP", "HOTA")
#: The GL-DT system as shipped, the row every comparison is about.
GLDT = "GD+LD+JPTrack"
#: Keys of the ``--json`` report that carry a split's name after them (``gldt bench seeds`` reads
#: them): the rows on its drone clips and which clips; what GD+LD+JPTrack published as drones on
#: its bird/airplane clips (per frame, by clip, track by track) and which clips.
ROWS_KEY = "halmstad_"
CLIPS_KEY = "clips_"
FALSE_ROWS_KEY = "false_drone_track_rows_per_frame_"
FALSE_ROWS_BY_CLIP_KEY = "false_drone_track_rows_by_clip_"
FALSE_TRACKS_KEY = "false_drone_tracks_"
OTHER_CLIPS_KEY = "other_clips_"


def parse_variants(text: str | None) -> tuple[str, ...]:
    """``--variants`` (labels of :data:`VARIANTS`, comma-separated) -> labels in the paper's order;
    ``None`` -> all four. One clear error naming an unknown label."""
    labels = [label for label, _, _ in VARIANTS]
    if text is None:
        return tuple(labels)
    chosen = [item.strip() for item in text.split(",") if item.strip()]
    unknown = [item for item in chosen if item not in labels]
    if unknown or not chosen:
        raise ValueError(f"--variants {text!r}: expected labels among {', '.join(labels)}")
    return tuple(label for label in labels if label in chosen)


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``gldt bench ablation``."""
    parser = subparsers.add_parser(
        "ablation",
        help="Table IV: GD vs GD+LD, ByteTrack vs JPTrack, with FPS and a speed breakdown",
        description="Run the four detector/tracker combinations of the paper's Table IV on synthetic "
        "1080p test scenes and Halmstad validation clips; print metrics, FPS, the GL-DT vs "
        "GD-every-frame speed ratio and the per-stage time breakdown.",
    )
    parser.add_argument("--scenes", type=int, default=3, help="synthetic test scenes (default 3; 0 = none)")
    parser.add_argument("--frames", type=int, default=300, help="frames per synthetic scene (default 300)")
    parser.add_argument("--clips", type=int, default=4, help="Halmstad validation drone clips (default 4; 0 = none)")
    parser.add_argument(
        "--split",
        default="val",
        choices=("val", "val_b"),
        help="which of the two disjoint validation splits the clips come from (default val)",
    )
    parser.add_argument(
        "--other-clips",
        type=int,
        default=0,
        help="bird/airplane clips of the split on which GD+LD+JPTrack's drone track rows are counted "
        "(all false) and each such track listed with its detections' mean class probabilities (default 0 = none)",
    )
    parser.add_argument("--clip-frames", type=int, default=None, help="frames per clip (default: all)")
    parser.add_argument(
        "--halmstad",
        default=None,
        help="Halmstad dataset root (default: $GLDT_HALMSTAD, else ../shared/data/halmstad-visible beside the "
        "checkout; skipped with a message when absent)",
    )
    parser.add_argument("--config", metavar="CFG.yaml", help="GL-DT system configuration (defaults: Table I)")
    parser.add_argument(
        "--oracle",
        action="store_true",
        help="hand the GL-DT systems the ground truth instead of the detectors' boxes (each configured "
        "detector still runs, for its time): the schedule's GD share and speed-up with a perfect detector "
        "on this machine",
    )
    parser.add_argument(
        "--variants",
        metavar="LABEL[,LABEL]",
        default=None,
        help=f"run only these of the four rows (default all; e.g. {GLDT}, the shipped system alone, "
        "for its accuracy at a quarter of the cost: the speed ratio needs GD+JPTrack beside it)",
    )
    parser.add_argument("--json", metavar="OUT.json", help="also write all numbers as JSON")
    parser.set_defaults(func=handle_ablation)


# --------------------------------------------------------------------------------- sequences
class CachedSequence:
    """Frames of one sequence held JPEG-encoded (quality 95) plus its MOTChallenge ground truth."""

    def __init__(self, name: str, fps: float, encoded: list[Any], stamps: list[float], gt: Any) -> None:
        self.name = name
        self.fps = fps
        self.encoded = encoded
        self.stamps = stamps
        self.gt = gt

    def __len__(self) -> int:
        return len(self.encoded)

    def __iter__(self):
        import cv2

        from gldt_core.system.runner import SimpleFrame

        for index, (buffer, stamp) in enumerate(zip(self.encoded, self.stamps)):
            yield SimpleFrame(index=index, stamp=stamp, image=cv2.imdecode(buffer, cv2.IMREAD_COLOR))


def _encode(image: Any) -> Any:
    import cv2

    ok, buffer = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 95])
    if not ok:
        raise ValueError("could not JPEG-encode a frame for the benchmark cache")
    return buffer


def cache_source(source: Any, name: str, max_frames: int | None = None) -> CachedSequence:
    """Decode a :class:`gldt_core.io.sources.FrameSource` once into a JPEG cache with its ground truth."""
    import numpy as np

    encoded: list[np.ndarray] = []
    stamps: list[float] = []
    gt_rows: list[np.ndarray] = []
    for frame in source:
        if max_frames is not None and len(encoded) >= max_frames:
            break
        encoded.append(_encode(frame.image))
        stamps.append(float(frame.stamp))
        truth = getattr(frame, "ground_truth", None)
        if truth is not None and len(truth):
            gt_rows.append(np.asarray(truth, dtype=np.float64).reshape(-1, 10))
    gt = np.vstack(gt_rows) if gt_rows else np.zeros((0, 10))
    return CachedSequence(name, float(getattr(source, "fps", 30.0) or 30.0), encoded, stamps, gt)


def synthetic_sequences(scenes: int, frames: int) -> list[CachedSequence]:
    """The first ``scenes`` 1080p scenes of the synthetic *test* split (never trained on)."""
    from gldt_core.io.synth_source import SynthSource
    from gldt_core.sim import presets

    return [
        cache_source(SynthSource(spec), spec.name or f"synthetic-{spec.seed}")
        for spec in presets.split("test", count=scenes, frames=frames)
    ]


def halmstad_sequences(
    root: str, clips: int, clip_frames: int | None, split: str = "val", category: str = "drone"
) -> list[CachedSequence]:
    """The first ``clips`` validation clips of ``split`` (never trained on by the shipped models):
    ``V_DRONE`` clips, or with ``category="other"`` the bird and airplane clips, alternating."""
    from pathlib import Path

    from gldt_core.eval.halmstad_split import halmstad_split
    from gldt_core.io.sources import open_source

    root_path = Path(root)
    validation = halmstad_split(root_path)[split]
    if category == "drone":
        names = [n for n in validation if n.startswith("V_DRONE")][:clips]
    else:
        birds = [n for n in validation if n.startswith("V_BIRD")]
        airplanes = [n for n in validation if n.startswith("V_AIRPLANE")]
        mixed = [n for pair in zip(birds, airplanes) for n in pair] + birds[len(airplanes) :] + airplanes[len(birds) :]
        names = mixed[:clips]
    out = []
    for name in names:
        source = open_source(root_path / "videos" / f"{name}.mp4", gt=root_path / "gt" / f"{name}.txt")
        out.append(cache_source(source, name, clip_frames))
    return out


# --------------------------------------------------------------------------------- running
def run_dataset(
    sequences: list[CachedSequence],
    config: Any,
    detectors: tuple[Any, Any],
    progress: bool = False,
    oracle: bool = False,
    variants: tuple[str, ...] | None = None,
) -> list[dict[str, Any]]:
    """The four variants (or the labels in ``variants``) over ``sequences``; one dict per variant
    (metrics in %, FPS, breakdown).

    ``oracle``: the detectors run as usual but the systems get each frame's ground truth in
    place of their boxes (:mod:`gldt_core.bench.oracle`).

    The four variants take turns frame by frame (:func:`run_frames_interleaved`) rather than each
    running the sequences in turn: a shared machine's speed drifts from one minute to the next,
    and the speed ratio between variants is only fair when each saw the same machine.
    """
    import sys

    from gldt_core.eval.halmstad_split import LOOSE_IOU
    from gldt_core.eval.mot_metrics import evaluate_many
    from gldt_core.system.gldt_system import GLDTSystem, build_tracker
    from gldt_core.system.runner import run_frames_interleaved

    global_detector, local_detector = detectors
    feed = None
    if oracle:
        from gldt_core.bench.oracle import GroundTruthFeed, OracleGlobalDetector, OracleLocalDetector

        feed = GroundTruthFeed()
        global_detector, local_detector = (
            OracleGlobalDetector(global_detector, feed),
            OracleLocalDetector(local_detector, feed),
        )
    runs = [
        _VariantRun(label, config.with_changes(local_enabled=on, tracker=name))
        for label, on, name in VARIANTS
        if variants is None or label in variants
    ]
    for sequence in sequences:
        drones_by_frame = _drone_centres_by_frame(sequence.gt)
        systems: list[GLDTSystem] = []
        callbacks: list[Callable[[Any, Any], None] | None] = []
        for run in runs:
            local_enabled = run.config.scheduler.local_enabled
            system = GLDTSystem(
                run.config,
                global_detector=global_detector,
                local_detector=local_detector if local_enabled else None,
                tracker=build_tracker(run.config),
                timer=run.timer,
            )

            run.start_sequence()

            def watch_schedule(
                frame: Any,
                _tracks: Any,
                system: GLDTSystem = system,
                run: _VariantRun = run,
                drones_by_frame: dict[int, Any] = drones_by_frame,
            ) -> None:
                plan = system.last_plan
                if plan is None:
                    return
                run.note_mode(plan.mode.value, plan.reason)
                centres = drones_by_frame.get(int(frame.index) + 1)
                if plan.mode.value != "LD" or centres is None:
                    return
                run.coverage[0] += int(_inside_any(centres, plan.rois).sum())
                run.coverage[1] += len(centres)

            systems.append(system)
            callbacks.append(watch_schedule if local_enabled else None)
        frames = feed.play(sequence, sequence.gt) if feed is not None else sequence
        for run, result in zip(runs, run_frames_interleaved(systems, frames, on_frame=callbacks)):
            run.frames += result.frames
            run.seconds += result.seconds
            run.gd_frames += result.global_frames
            run.pairs[sequence.name] = (sequence.gt, result.rows)
        if progress:
            speeds = ", ".join(f"{run.label} {run.fps:.1f}" for run in runs)
            print(f"ablation: {sequence.name} done (FPS so far: {speeds})", file=sys.stderr, flush=True)
    rows = []
    for run in runs:
        evaluated = evaluate_many(run.pairs)
        metrics = evaluated["combined"]
        row: dict[str, Any] = {"variant": run.label, "frames": run.frames, "fps": run.fps}
        row["gd_frames"] = run.gd_frames
        row["gd_share"] = run.gd_frames / run.frames if run.frames else 0.0
        row["roi_coverage"] = run.coverage[0] / run.coverage[1] if run.coverage[1] else None
        row["search_gd_frames"] = run.search_gd_frames
        row["back_to_gd"] = dict(run.back_to_gd)
        row.update(_in_percent(metrics))
        row["stage_ms"] = {name: ms for name, ms, _, _ in run.timer.breakdown(run.frames)}
        row["per_clip"] = {name: _in_percent(m) for name, m in evaluated["per_sequence"].items()}
        loose = evaluate_many(run.pairs, threshold=LOOSE_IOU)["combined"]
        row["at_loose_iou"] = {
            "threshold": LOOSE_IOU,
            **_in_percent(loose),
            "FN": int(loose["FN"]),
            "FP": int(loose["FP"]),
        }
        row["FN"], row["FP"] = int(metrics["FN"]), int(metrics["FP"])
        rows.append(row)
    return rows


def _in_percent(metrics: dict[str, Any]) -> dict[str, Any]:
    """The :data:`METRICS` of an evaluation as the ablation reports them: percent, IDSW a count."""
    return {key: int(metrics[key]) if key == "IDSW" else 100.0 * float(metrics[key]) for key in METRICS}


class _VariantRun:
    """What one ablation variant has accumulated so far over the sequences."""

    def __init__(self, label: str, config: Any) -> None:
        from gldt_core.system.timing import StageTimer

        self.label = label
        self.config = config
        self.timer = StageTimer()
        self.frames = 0
        self.seconds = 0.0
        self.gd_frames = 0
        self.coverage = [0, 0]  # drones inside an ROI, drones on LD frames
        self.pairs: dict[str, Any] = {}  # sequence name -> (ground truth, track rows)
        # GD frames of each sequence before its first LD frame (the initial search), and the
        # switches from LD back to GD by the scheduler's reason: why GD keeps its share of frames.
        self.search_gd_frames = 0
        self.back_to_gd: dict[str, int] = {}
        self._last_mode: str | None = None
        self._searching = True

    def start_sequence(self) -> None:
        self._last_mode = None
        self._searching = True

    def note_mode(self, mode: str, reason: str) -> None:
        """Record one frame's mode (``"GD"``/``"LD"``) and the scheduler's reason for it."""
        self._searching = self._searching and mode == "GD"
        self.search_gd_frames += int(self._searching)
        if self._last_mode == "LD" and mode == "GD":
            self.back_to_gd[reason] = self.back_to_gd.get(reason, 0) + 1
        self._last_mode = mode

    @property
    def fps(self) -> float:
        return self.frames / self.seconds if self.seconds else 0.0


def _drone_centres_by_frame(gt: Any) -> dict[int, Any]:
    """``{frame: (K, 2) centres}`` of the ground-truth targets the metrics score (drones)."""
    from gldt_core.bench.oracle import target_boxes_by_frame

    return {frame: (boxes[:, :2] + boxes[:, 2:]) / 2 for frame, boxes in target_boxes_by_frame(gt).items()}


def _inside_any(centres: Any, rois: Any) -> Any:
    """Boolean per centre: inside at least one ROI."""
    import numpy as np

    rois = np.asarray(rois, dtype=np.float64).reshape(-1, 4)
    if not len(rois):
        return np.zeros(len(centres), dtype=bool)
    x, y = centres[:, :1], centres[:, 1:2]
    return ((x >= rois[:, 0]) & (x < rois[:, 2]) & (y >= rois[:, 1]) & (y < rois[:, 3])).any(axis=1)


def format_table(title: str, rows: list[dict[str, Any]]) -> str:
    """Table IV layout plus FPS and GD share."""
    header = f"{'model':<17}{'IDSW':>6}{'IDF1':>8}{'MOTA':>8}{'MOTP':>8}{'HOTA':>8}{'FPS':>8}{'GD%':>6}{'ROIcov':>8}"
    lines = [title, header]
    for r in rows:
        cover = "-" if r.get("roi_coverage") is None else f"{100 * r['roi_coverage']:.0f}%"
        lines.append(
            f"{r['variant']:<17}{r['IDSW']:>6d}{r['IDF1']:>8.2f}{r['MOTA']:>8.2f}{r['MOTP']:>8.2f}"
            f"{r['HOTA']:>8.2f}{r['fps']:>8.1f}{100 * r['gd_share']:>5.0f}%{cover:>8}"
        )
    lines.append("(ROIcov: share of ground-truth drones on LD frames whose centre lies inside an ROI)")
    by_name = {r["variant"]: r for r in rows}
    ours, gd_only = by_name.get(GLDT), by_name.get("GD+JPTrack")
    if ours is not None:
        loose = ours.get("at_loose_iou")
        if loose is not None:
            lines.append(
                f"{GLDT} at IoU {loose['threshold']:g} (loose ground-truth boxes): MOTA {loose['MOTA']:.2f}, "
                f"IDF1 {loose['IDF1']:.2f}, FN {loose['FN']}, FP {loose['FP']}; "
                f"at 0.5: FN {ours['FN']}, FP {ours['FP']} "
                f"(a box around the drone that misses the annotation's size counts as both)"
            )
        if gd_only is not None:
            ratio = ours["fps"] / gd_only["fps"] if gd_only["fps"] else float("nan")
            lines.append(
                f"{GLDT} vs GD+JPTrack: MOTA {ours['MOTA'] - gd_only['MOTA']:+.2f}, "
                f"speed x{ratio:.2f} (GL-DT schedule vs global detector on every frame, same run)"
            )
        lines.append(
            f"{GLDT} GD frames: {ours['gd_frames']}, of which {ours['search_gd_frames']} before a sequence's "
            f"first LD frame; back from LD to GD: "
            + (", ".join(f"{count}x {reason}" for reason, count in sorted(ours["back_to_gd"].items())) or "never")
        )
        undecoded = None if gd_only is None else _ratio_without_decode(ours, gd_only)
        if undecoded is not None:
            lines.append(
                f"without the decode stage (frames handed over decoded, as a camera driver publishing raw "
                f"images does): speed x{undecoded:.2f}"
            )
    for row in (ours, gd_only):
        if row is not None:
            stages = ", ".join(f"{k} {v:.1f}" for k, v in row["stage_ms"].items())
            lines.append(f"{row['variant']:<13} time per frame (ms): {stages}")
    if ours is not None and "GD+LD+ByteTrack" in by_name:
        lines += per_clip_lines(ours, by_name["GD+LD+ByteTrack"])
    return "\n".join(lines)


def per_clip_lines(ours: dict[str, Any], peer: dict[str, Any]) -> list[str]:
    """Each clip's IDF1, HOTA and IDSW of two ablation rows side by side, worst IDF1 margin first:
    a total over the clips can hide the clips where a variant loses. Empty without per-clip figures."""
    from gldt_core.eval.margins import margins_by_sequence

    ours_clips, peer_clips = ours.get("per_clip") or {}, peer.get("per_clip") or {}
    idf1 = margins_by_sequence(ours_clips, peer_clips, "IDF1")
    if idf1 is None:
        return []
    a, b = ours["variant"], peer["variant"]
    lines = [
        f"per clip, worst IDF1 margin first: {a} vs {b}",
        f"{'clip':<16}{'IDF1':>17}{'HOTA':>17}{'IDSW':>12}",
    ]
    for name in idf1.margins:
        x, y = ours_clips[name], peer_clips[name]
        lines.append(
            f"{name:<16}{x['IDF1']:>7.2f} vs {y['IDF1']:>6.2f}{x['HOTA']:>7.2f} vs {y['HOTA']:>6.2f}"
            f"{x['IDSW']:>5d} vs {y['IDSW']:>3d}"
        )
    lines.append(f"{a} has the lower IDF1 on {idf1.behind} of {len(idf1.margins)} clips")
    return lines


def _ratio_without_decode(ours: dict[str, Any], peer: dict[str, Any]) -> float | None:
    """The speed ratio of two ablation rows with their (shared) decode time taken out: each row's
    wall-clock time per frame (``1 / fps``) minus its ``decode`` stage. None without a decode stage.

    Every row pays the same decode for every frame, which caps the ratio however cheap LD frames
    are. A camera driver that publishes raw images spares the perception stack that cost, and
    this is the ratio it would see.
    """
    if "decode" not in ours["stage_ms"] or "decode" not in peer["stage_ms"] or not ours["fps"] or not peer["fps"]:
        return None
    ours_ms = 1000.0 / ours["fps"] - ours["stage_ms"]["decode"]
    peer_ms = 1000.0 / peer["fps"] - peer["stage_ms"]["decode"]
    return peer_ms / ours_ms if ours_ms > 0 and peer_ms > 0 else None


class LastClassEvidence:
    """Each track's class evidence as it stood when the track was last reported
    (:class:`~gldt_core.track.class_evidence.ClassEvidence` forgets a track some time after)."""

    def __init__(self, evidence: Any) -> None:
        self.evidence = evidence
        self._said: dict[int, Any] = {}

    def note(self, _frame: Any, tracks: Any) -> None:
        """``run_frames``' ``on_frame``: ``tracks`` ``(M, >=5)`` ``[x1, y1, x2, y2, id, ...]``."""
        for track_id in (int(row[4]) for row in tracks):
            self._said[track_id] = self.evidence.probabilities(track_id)

    def probabilities(self, track_id: int) -> Any:
        return self._said.get(track_id)


def false_drone_tracks(
    sequences: list[CachedSequence], config: Any, detectors: tuple[Any, Any]
) -> tuple[dict[str, int], int, list[dict[str, Any]]]:
    """What GD+LD+JPTrack publishes as drones on clips without drones: the track rows per clip,
    the frames of all the clips together, and each such track with the mean class probabilities of
    the detections it was matched with (``None`` where it has none)."""
    from gldt_core.system.gldt_system import GLDTSystem, build_tracker
    from gldt_core.system.runner import run_frames
    from gldt_core.track.class_evidence import drone_track_rows, drone_tracks

    system_config = config.with_changes(local_enabled=True, tracker="jptrack")
    rows: dict[str, int] = {}
    tracks: list[dict[str, Any]] = []
    frames = 0
    for sequence in sequences:
        system = GLDTSystem(
            system_config,
            global_detector=detectors[0],
            local_detector=detectors[1],
            tracker=build_tracker(system_config),
        )
        last = LastClassEvidence(system.class_evidence)
        result = run_frames(system, sequence, on_frame=last.note)
        rows[sequence.name] = drone_track_rows(result.rows)
        for track_id, count, probabilities in drone_tracks(result.rows, last.probabilities):
            mean = None if probabilities is None else [round(float(p), 4) for p in probabilities]
            tracks.append({"clip": sequence.name, "track_id": track_id, "rows": count, "mean_probabilities": mean})
        frames += result.frames
    return rows, frames, tracks


def format_false_drone_tracks(tracks: list[dict[str, Any]]) -> str:
    """One line: each false drone track, most rows first, with what the classifier said of it."""

    def said(track: dict[str, Any]) -> str:
        mean = track["mean_probabilities"]
        return "no class evidence" if mean is None else "/".join(f"{p:.2f}" for p in mean)

    ordered = sorted(tracks, key=lambda track: -track["rows"])
    return "false drone tracks (mean P drone/bird/airplane of their detections): " + (
        ", ".join(f"{t['clip']} #{t['track_id']} {t['rows']} rows {said(t)}" for t in ordered) or "none"
    )


def handle_ablation(args: argparse.Namespace) -> int:
    """Run the ablation; prints one table per dataset."""
    import json
    import os
    from pathlib import Path

    from gldt_core.bench.detection import clips_most_first
    from gldt_core.system.config import load_config
    from gldt_core.system.gldt_system import build_detectors

    for name in ("scenes", "frames", "clips", "other_clips"):
        if getattr(args, name) < 0:
            raise ValueError(f"--{name} must be >= 0, got {getattr(args, name)}")
    variants = parse_variants(args.variants)
    config = load_config(args.config)
    detectors = build_detectors(config.with_changes(local_enabled=True))
    report: dict[str, Any] = {"oracle": bool(args.oracle), "variants": list(variants)}
    oracle_note = " (oracle: ground truth in place of the detectors' boxes, at their cost)" if args.oracle else ""

    if args.scenes:
        sequences = synthetic_sequences(args.scenes, args.frames)
        rows = run_dataset(sequences, config, detectors, progress=True, oracle=args.oracle, variants=variants)
        report["synthetic_1080p"] = rows
        print(format_table(f"synthetic 1080p test scenes: {len(sequences)} x {args.frames} frames{oracle_note}", rows))
    if args.clips:
        from gldt_core.paths import halmstad_root

        args.halmstad = args.halmstad or str(halmstad_root())
        if not Path(args.halmstad, "videos").is_dir():
            print(f"halmstad: skipped, {args.halmstad}/videos not found")
        else:
            sequences = halmstad_sequences(args.halmstad, args.clips, args.clip_frames, args.split)
            rows = run_dataset(sequences, config, detectors, progress=True, oracle=args.oracle, variants=variants)
            report[ROWS_KEY + args.split] = rows
            report[CLIPS_KEY + args.split] = [sequence.name for sequence in sequences]
            total = sum(len(s) for s in sequences)
            print(
                format_table(
                    f"Halmstad validation drone clips of {args.split} (640x512): {len(sequences)} clips, "
                    f"{total} frames{oracle_note}",
                    rows,
                )
            )
    if args.other_clips and not args.oracle:
        from gldt_core.paths import halmstad_root

        root = args.halmstad or str(halmstad_root())
        others = halmstad_sequences(root, args.other_clips, args.clip_frames, args.split, category="other")
        by_clip, frames, tracks = false_drone_tracks(others, config, detectors)
        rate = sum(by_clip.values()) / frames if frames else float("nan")
        report[FALSE_ROWS_KEY + args.split] = rate
        report[FALSE_ROWS_BY_CLIP_KEY + args.split] = by_clip
        report[FALSE_TRACKS_KEY + args.split] = tracks
        report[OTHER_CLIPS_KEY + args.split] = [sequence.name for sequence in others]
        where = clips_most_first(by_clip)
        print(
            f"bird/airplane clips of {args.split} ({', '.join(s.name for s in others)}): GD+LD+JPTrack publishes "
            f"{rate:.3f} drone track rows per frame (all false)" + (f"; rows on {where}" if where else "")
        )
        print(format_false_drone_tracks(tracks))
    if args.json:
        path = Path(args.json)
        temporary = path.with_name(path.name + ".part")
        temporary.write_text(json.dumps(report, indent=2))
        os.replace(temporary, path)
    return 0
