"""``gldt bench detection``: accuracy and latency of the detectors, with and without the second stage.

Rows: AM-YOLO and the local model each with the second stage (``+2nd``, as the GL-DT system
runs them) and alone, AM-YOLO's twin without STFF (alone), and ``fused+2nd``: the two ``+2nd``
rows' boxes of each frame fused by the mean of their calibrated scores
(:mod:`gldt_core.detect.fusion`; a box one detector misses counts 0 there), which costs both
detectors' time. ``fused+2nd`` is the system's default GD frame (``detector.tile_fusion``) where
a frame is letterboxed at 0.8 of its size or more (the real 640x512 clips); ``AM-YOLO+2nd`` is
its GD frame below that (1080p).

Accuracy (drone class, IoU-matched as in COCO; see :mod:`gldt_core.eval.detection_metrics`):

* real: every ``--frame-step``-th frame of the held-out Halmstad drone clips of *both*
  validation splits (``val`` and ``val_b`` of :mod:`gldt_core.eval.halmstad_split`, disjoint,
  never trained on), so a figure can be shown not to belong to one split; precision and recall
  at each model's operating threshold (its default unless ``--score-threshold``), and false
  drone detections per frame on the held-out bird/airplane clips at that threshold;
* synthetic: frames of the ``gldt_core.sim.presets`` "test" scenes (1080p), never trained on.

The detectors are asked about drones only, as the GL-DT system asks them (``--all-classes``: about
every class, keeping the boxes whose best class is drone). A line per model then says where the
drones went: found, boxed under another class, boxed badly or missed, and what its false drones
at the operating threshold are (:func:`gldt_core.eval.detection_metrics.error_breakdown`).

The global models see each frame with its predecessor; the local model covers the frame with
300 px ROI tiles (one batch per frame) since no tracker is there to place ROIs. Latency is the
median wall time of one detector call (pre-processing, inference, decoding, NMS) on a 1920x1080
frame (global) and on a batch of 4 ROIs of 300x300 (local), measured in the same run, with the
ratios between them printed so machine noise cancels. PR and recall-confidence curves are saved as
PNG (like the paper's Fig. 7).
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from gldt_core.detect import GlobalDetector, LocalDetector


#: The row of both detectors' calibrated boxes fused (the mean of their scores), and the rows it fuses.
FUSED = "fused+2nd"
FUSED_PAIR = ("AM-YOLO+2nd", "local+2nd")


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("detection", help="AP50 / AP50:95 / AP_small / PR AUC / latency of the detectors")
    parser.add_argument("--real-root", default=None, help="Halmstad clips (skipped when absent)")
    parser.add_argument("--frame-step", type=int, default=10, help="evaluate every N-th frame of each real clip")
    parser.add_argument(
        "--max-clips", type=int, default=None, help="limit the held-out clips per category (quick runs)"
    )
    parser.add_argument("--synthetic-scenes", type=int, default=6, help="synthetic test scenes (0 to skip)")
    parser.add_argument("--synthetic-frames", type=int, default=60, help="frames evaluated per synthetic scene")
    parser.add_argument(
        "--score-threshold",
        type=float,
        default=None,
        help="operating threshold for precision, recall and false drones (default: each model's own: "
        "0.5 with the second stage, 0.25 without)",
    )
    parser.add_argument(
        "--second-stage",
        default="beside",
        help="second-stage classifier for the +2nd rows: beside (next to each model), a path, or none (no +2nd rows)",
    )
    parser.add_argument("--global-model", default=None, help="AM-YOLO ONNX (default: shipped)")
    parser.add_argument("--nostff-model", default=None, help="no-STFF ablation ONNX (default: shipped)")
    parser.add_argument("--local-model", default=None, help="local ONNX (default: shipped)")
    parser.add_argument(
        "--threads", type=int, default=None, help="onnxruntime intra-op threads (default: onnxruntime's)"
    )
    parser.add_argument(
        "--long-side",
        type=int,
        default=None,
        help="global models' input long side in px (default: each model card's; a multiple of 64), "
        "e.g. 1280 to ask whether small drones are missed for want of resolution",
    )
    parser.add_argument(
        "--all-classes",
        action="store_true",
        help="ask the detectors about every class and keep the boxes whose best class is drone; "
        "default: ask about drones only, as the GL-DT system does",
    )
    parser.add_argument(
        "--latency-runs", type=int, default=30, help="timed runs per model and thread count (0: accuracy only)"
    )
    parser.add_argument(
        "--latency-threads", type=int, nargs="+", default=[1, 2], help="onnxruntime thread counts to time"
    )
    parser.add_argument(
        "--out", default="out/bench_detection", help="folder for the PNG curves and a JSON of all numbers"
    )
    parser.add_argument(
        "--update-cards",
        action="store_true",
        help="write the measured numbers into the models' JSON cards (field 'benchmark')",
    )
    parser.set_defaults(func=_run)


def _detectors(args: argparse.Namespace, threshold: float | None) -> dict[str, GlobalDetector | LocalDetector]:
    """The rows of the table: each detector with the second stage (unless ``--second-stage none``) and alone."""
    from gldt_core.detect import DRONE_CLASS_ID, GlobalDetector, LocalDetector, shipped_model_path

    common: dict[str, Any] = {
        "score_threshold": threshold,
        "num_threads": args.threads,
        "classes": None if args.all_classes else (DRONE_CLASS_ID,),
    }
    second = None if args.second_stage == "none" else args.second_stage
    global_model = args.global_model or shipped_model_path("global")
    local_model = args.local_model or shipped_model_path("local")
    detectors: dict[str, GlobalDetector | LocalDetector] = {}
    if second is not None:
        detectors["AM-YOLO+2nd"] = GlobalDetector(global_model, long_side=args.long_side, second_stage=second, **common)
    detectors["AM-YOLO"] = GlobalDetector(global_model, long_side=args.long_side, second_stage=None, **common)
    detectors["no-STFF"] = GlobalDetector(
        args.nostff_model or shipped_model_path("global_nostff"), long_side=args.long_side, second_stage=None, **common
    )
    if second is not None:
        detectors["local+2nd"] = LocalDetector(local_model, second_stage=second, **common)
    detectors["local"] = LocalDetector(local_model, second_stage=None, **common)
    return detectors


def _operating_threshold(args: argparse.Namespace, detector: GlobalDetector | LocalDetector) -> float:
    """``--score-threshold``, else the detector's default (calibrated with a second stage)."""
    from gldt_core.detect.second_stage import default_score_threshold

    if args.score_threshold is not None:
        return float(args.score_threshold)
    return default_score_threshold(detector.second_stage is not None)


def _drones(detections: list) -> list:
    """The drone rows ``(N, 5)`` of each frame's ``(N, 6)`` detections."""
    from gldt_core.detect import DRONE_CLASS_ID

    return [d[d[:, 5] == DRONE_CLASS_ID][:, :5] for d in detections]


def _run_detector(detector: GlobalDetector | LocalDetector, frames_prev_cur: list[tuple], roi_side: int) -> list:
    """Detections of every class ``(N, 6)`` (``x1, y1, x2, y2, score, MOT class``) per evaluated frame."""
    import numpy as np

    from gldt_core.detect.video import frame_detections

    out = []
    for previous, current in frames_prev_cur:
        dets = frame_detections(detector, previous, current, roi_side)
        out.append(dets[:, :6] if len(dets) else np.zeros((0, 6), np.float32))
    return out


def _row_outputs(
    detectors: dict[str, GlobalDetector | LocalDetector], rows: list[str], frames_prev_cur: list[tuple], roi_side: int
) -> dict[str, list]:
    """Each row's detections per frame (:func:`_run_detector`); the :data:`FUSED` row is the
    :data:`FUSED_PAIR`'s, fused frame by frame (:func:`gldt_core.detect.fusion.fuse_detections`)."""
    from gldt_core.detect.fusion import fuse_detections

    outputs = {name: _run_detector(detectors[name], frames_prev_cur, roi_side) for name in rows if name != FUSED}
    if FUSED in rows:
        first, second = (outputs[name] for name in FUSED_PAIR)
        outputs[FUSED] = [fuse_detections(a, b) for a, b in zip(first, second, strict=True)]
    return outputs


def _real_frames(root, clips: list[str], step: int) -> tuple[list, list]:
    """(previous, current) frame pairs and drone gt boxes for every ``step``-th frame of the clips."""
    from pathlib import Path

    import numpy as np

    from gldt_core.detect.video import iter_video_frames
    from gldt_core.io.mot import read_mot

    pairs, gts = [], []
    for clip in clips:
        gt = read_mot(Path(root) / "gt" / f"{clip}.txt")
        previous = None
        for index, frame in enumerate(iter_video_frames(Path(root) / "videos" / f"{clip}.mp4"), start=1):
            if index % step == 0 and previous is not None:
                rows = gt[(gt[:, 0] == index) & (gt[:, 7] == 1)]
                boxes = np.column_stack((rows[:, 2], rows[:, 3], rows[:, 2] + rows[:, 4], rows[:, 3] + rows[:, 5]))
                pairs.append((previous, frame))
                gts.append(boxes)
            previous = frame
    return pairs, gts


def _synthetic_frames(scenes: int, frames: int) -> tuple[list, list]:
    import numpy as np

    from gldt_core.sim import SceneRenderer, presets

    pairs, gts = [], []
    for spec in presets.split("test", count=scenes, frames=frames):
        renderer = SceneRenderer(spec)
        previous = renderer.render(0)
        for k in range(1, spec.frames):
            current, rows = renderer.render_with_truth(k)
            if k % 3 == 0:  # every third frame keeps memory bounded
                rows = np.asarray(rows).reshape(-1, 10)
                rows = rows[rows[:, 7] == 1]
                pairs.append((previous, current))
                gts.append(np.column_stack((rows[:, 2], rows[:, 3], rows[:, 2] + rows[:, 4], rows[:, 3] + rows[:, 5])))
            previous = current
    return pairs, gts


def _counts_by_clip(counts: list[int], frames_per_clip: dict[str, int]) -> dict[str, int]:
    """Per-frame ``counts`` of clips laid end to end (``frames_per_clip``, in order) summed per clip."""
    if len(counts) != sum(frames_per_clip.values()):
        raise ValueError(f"{len(counts)} frame counts for {sum(frames_per_clip.values())} frames")
    out, start = {}, 0
    for clip, frames in frames_per_clip.items():
        out[clip] = sum(counts[start : start + frames])
        start += frames
    return out


def clips_most_first(by_clip: dict[str, int]) -> str:
    """``"V_AIRPLANE_049 14, V_AIRPLANE_019 11"``: the clips with a count above 0, most first; "" for none."""
    found = sorted(((n, clip) for clip, n in by_clip.items() if n), key=lambda item: (-item[0], item[1]))
    return ", ".join(f"{clip} {n}" for n, clip in found)


def _breakdown_line(dataset: str, model: str, errors: dict, threshold: float) -> str:
    """One line of :func:`~gldt_core.eval.detection_metrics.error_breakdown`, as shares of the drones."""
    n = max(errors["num_gt"], 1.0)
    share = lambda key: f"{100 * errors[key] / n:5.1f} %"  # noqa: E731
    return (
        f"  {dataset:16s} {model:8s} found {share('found')}, called another class {share('other_class')}, "
        f"box off {share('poorly_placed')}, missed {share('missed')}; "
        f"false drones at {threshold}: {int(errors['fp_on_object'])} on an object, "
        f"{int(errors['fp_background'])} on background"
    )


def _second_stage_call(stage: Any, frame: Any) -> Any:
    """One call of the second stage on 10 candidates spread over ``frame`` (crops, model, calibration, NMS)."""
    import functools

    import numpy as np

    rng = np.random.default_rng(1)
    xy = rng.uniform(50, [frame.shape[1] - 80, frame.shape[0] - 80], size=(10, 2))
    size = rng.uniform(10, 60, size=(10, 1))
    candidates = np.column_stack([xy, xy + size, rng.uniform(0.01, 0.9, 10), np.ones(10)])
    return functools.partial(stage.rescore, np.roll(frame, 2, axis=1), frame, candidates)


def _latency(fn, runs: int) -> float:
    import time

    import numpy as np

    for _ in range(3):
        fn()
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times) * 1000.0)


def _plot(curves: dict, path_pr, path_rc, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from gldt_core.eval.detection_metrics import pr_auc, pr_curve, recall_at_confidence

    thresholds = np.linspace(0, 1, 101)
    for path, kind in ((path_pr, "pr"), (path_rc, "rc")):
        fig, ax = plt.subplots(figsize=(5, 4))
        for name, result in curves.items():
            if kind == "pr":
                precision, recall, _ = pr_curve(result)
                ax.plot(recall, precision, label=f"{name} (AUC {pr_auc(result):.3f})")
                ax.set_xlabel("recall"), ax.set_ylabel("precision")
            else:
                ax.plot(thresholds, recall_at_confidence(result, thresholds), label=name)
                ax.set_xlabel("confidence"), ax.set_ylabel("recall")
        ax.set_xlim(0, 1)
        ax.set_ylim(0, 1.02)
        ax.set_title(title)
        ax.legend()
        ax.grid(alpha=0.3)
        fig.tight_layout()
        tmp = path.with_name(path.name + ".tmp.png")
        fig.savefig(tmp, dpi=100)
        plt.close(fig)
        tmp.replace(path)


def _run(args: argparse.Namespace) -> int:
    import functools
    import json
    from pathlib import Path

    import numpy as np

    from gldt_core.bench.latency import gd_stretch_call
    from gldt_core.detect import DRONE_CLASS_ID, GlobalDetector
    from gldt_core.eval.detection_metrics import detection_summary, error_breakdown, match, precision_recall_at
    from gldt_core.eval.halmstad_split import LOOSE_IOU, VALIDATION_SPLITS, halmstad_split

    if args.frame_step < 1:
        raise ValueError(f"--frame-step must be >= 1, got {args.frame_step}")
    if args.long_side is not None and args.update_cards:
        raise ValueError("--update-cards records the models as they run by default; drop --long-side to use it")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    # Accuracy uses a low threshold so the PR curves span the whole range.
    detectors = _detectors(args, threshold=0.01)
    roi_side = int(detectors["local"].card.get("roi_side", 300))
    thresholds = {name: _operating_threshold(args, detector) for name, detector in detectors.items()}
    report: dict = {"operating_thresholds": thresholds, "datasets": {}}
    rescoring = next((d.second_stage for d in detectors.values() if d.second_stage is not None), None)
    if rescoring is not None:  # which stage this was, and its figures on the calibration clips (`gldt bench seeds`)
        report["second_stage"] = {
            "path": str(rescoring.model_path),
            "calibration_clip_figures": rescoring.card.get("calibration_clip_figures"),
        }

    datasets: dict[str, tuple[list, list]] = {}
    negatives: dict[str, dict[str, list]] = {}  # split -> bird/airplane clip -> its frame pairs
    from gldt_core.paths import halmstad_root

    root = Path(args.real_root or halmstad_root())
    if (root / "videos").is_dir():
        split = halmstad_split(root)
        for split_name in VALIDATION_SPLITS:
            clips = split[split_name]
            drone = [c for c in clips if c.startswith("V_DRONE")][: args.max_clips]
            other = [c for c in clips if c.startswith("V_BIRD")][: args.max_clips] + [
                c for c in clips if c.startswith("V_AIRPLANE")
            ][: args.max_clips]
            dname = f"real-{split_name.replace('_', '-')}"
            datasets[dname] = _real_frames(root, drone, args.frame_step)
            negatives[dname] = {clip: _real_frames(root, [clip], args.frame_step)[0] for clip in other}
            report[f"{dname}_clips"] = drone + other
    else:
        print(f"real clips not found under {root}: skipping the real-data rows")
    if args.synthetic_scenes > 0:
        datasets["synthetic-test"] = _synthetic_frames(args.synthetic_scenes, args.synthetic_frames)

    print(
        f"{'dataset':14s} {'model':11s} {'frames':>6s} {'gt':>5s} "
        f"{'AP50':>6s} {'AP50:95':>7s} {'APsmall':>7s} {'PR-AUC':>6s} {'thresh':>6s} {'prec':>6s} {'recall':>6s}"
    )
    breakdowns: list[str] = []
    rows = list(detectors)
    if all(name in detectors for name in FUSED_PAIR):
        rows.append(FUSED)
        thresholds[FUSED] = thresholds[FUSED_PAIR[0]]  # calibrated scores, as the rows it fuses
    for dname, (pairs, gts) in datasets.items():
        curves = {}
        report["datasets"][dname] = {}
        for name, every_class in _row_outputs(detectors, rows, pairs, roi_side).items():
            dets = _drones(every_class)
            summary = detection_summary(dets, gts, loose_iou=LOOSE_IOU if dname.startswith("real-") else None)
            curves[name] = match(dets, gts, 0.5)
            precision, recall = precision_recall_at(curves[name], thresholds[name])
            summary.update({"precision_at_threshold": precision, "recall_at_threshold": recall})
            report["datasets"][dname][name] = summary
            errors = error_breakdown(every_class, gts, DRONE_CLASS_ID, thresholds[name])
            report.setdefault("errors", {}).setdefault(dname, {})[name] = errors
            breakdowns.append(_breakdown_line(dname, name, errors, thresholds[name]))
            print(
                f"{dname:14s} {name:11s} {len(pairs):6d} {int(summary['num_gt']):5d} {summary['ap50']:6.3f} "
                f"{summary['ap50_95']:7.3f} {summary['ap_small']:7.3f} {summary['pr_auc']:6.3f} "
                f"{thresholds[name]:6.2f} {precision:6.3f} {recall:6.3f}"
            )
        _plot(curves, out / f"pr_{dname}.png", out / f"recall_confidence_{dname}.png", f"drone, {dname}")
        a, b = report["datasets"][dname]["AM-YOLO"]["ap50"], report["datasets"][dname]["no-STFF"]["ap50"]
        line = f"{dname}: AM-YOLO - no-STFF AP50 margin {a - b:+.3f}"
        if "AM-YOLO+2nd" in detectors:
            line += f"; the second stage adds {report['datasets'][dname]['AM-YOLO+2nd']['ap50'] - a:+.3f} to AM-YOLO"
        print(line)
    real = [d for d in datasets if d.startswith("real-")]
    if len(real) == 2:
        print("the two disjoint validation splits (AP50; gap; worst):")
        for name in rows:
            values = [report["datasets"][d][name]["ap50"] for d in real]
            loose = [report["datasets"][d][name]["ap_loose"] for d in real]
            print(
                f"  {name:11s} {values[0]:.3f} / {values[1]:.3f}; "
                f"gap {abs(values[0] - values[1]):.3f}; worst {min(values):.3f}; "
                f"at IoU {LOOSE_IOU:g} (loose ground-truth boxes) {loose[0]:.3f} / {loose[1]:.3f}"
            )
    if breakdowns:
        print("where the drones went (IoU 0.5; every reported box) and the false drones at the operating threshold:")
        print("\n".join(breakdowns))

    report["false_drones_per_frame"] = {}
    report["false_drones_by_clip"] = {}
    for dname, by_clip in negatives.items():
        pairs = [pair for clip_pairs in by_clip.values() for pair in clip_pairs]
        if not pairs:
            continue
        report["false_drones_per_frame"][dname] = {}
        report["false_drones_by_clip"][dname] = {}
        for name, every_class in _row_outputs(detectors, rows, pairs, roi_side).items():
            counts = [int((d[:, 4] >= thresholds[name]).sum()) for d in _drones(every_class)]
            rate = float(np.mean(counts))
            report["false_drones_per_frame"][dname][name] = rate
            by_clip_counts = _counts_by_clip(counts, {clip: len(p) for clip, p in by_clip.items()})
            report["false_drones_by_clip"][dname][name] = by_clip_counts
            where = clips_most_first(by_clip_counts)
            print(
                f"bird/airplane clips of {dname} ({len(counts)} frames): {name:11s} false drone detections per frame "
                f"at score >= {thresholds[name]:.2f}: {rate:.3f}" + (f"; on {where}" if where else "")
            )

    frame_1080 = np.full((1080, 1920, 3), 128, np.uint8)
    rng = np.random.default_rng(0)
    frame_1080[:] = rng.integers(90, 170, size=(1080, 1920, 1), dtype=np.uint8)
    # The global models are timed per frame of a GD stretch (each frame paired with the one
    # before, carrying its letterboxed input and reusable features), as the GL-DT system runs them.
    stretch = [frame_1080, np.roll(frame_1080, 3, axis=1)]
    rois = np.array([[100, 100, 400, 400], [800, 300, 1100, 600], [1400, 500, 1700, 800], [300, 700, 600, 1000]])
    report["latency_ms"] = {}
    if args.latency_runs < 1:
        print(f"latency: not timed (--latency-runs {args.latency_runs})")
    for threads in args.latency_threads if args.latency_runs >= 1 else []:
        args_t = argparse.Namespace(**{**vars(args), "threads": threads})
        timed = _detectors(args_t, threshold=None)
        latency = {
            f"{name} {'1080p frame' if isinstance(detector, GlobalDetector) else '4 ROIs'}": _latency(
                gd_stretch_call(detector, stretch)
                if isinstance(detector, GlobalDetector)
                else functools.partial(detector.detect_rois, frame_1080, rois),
                args.latency_runs,
            )
            for name, detector in timed.items()
        }
        stage = next((d.second_stage for d in timed.values() if d.second_stage is not None), None)
        if stage is not None:
            latency["second stage, 10 candidates"] = _latency(_second_stage_call(stage, frame_1080), args.latency_runs)
        report["latency_ms"][f"threads={threads}"] = latency
        in_w, in_h = timed["AM-YOLO"].input_size(1920, 1080)  # type: ignore[union-attr]
        print(
            f"latency (median of {args.latency_runs}, onnxruntime threads={threads}; "
            f"global input {in_w}x{in_h}, local input {timed['local'].input_side}):"  # type: ignore[union-attr]
        )
        for key, value in latency.items():
            print(f"  {key:30s} {value:7.1f} ms")
        print(
            f"  ratio AM-YOLO / no-STFF: {latency['AM-YOLO 1080p frame'] / latency['no-STFF 1080p frame']:.2f}; "
            f"local 4 ROIs / AM-YOLO frame: {latency['local 4 ROIs'] / latency['AM-YOLO 1080p frame']:.2f}"
        )
    tmp = out / "report.json.tmp"
    tmp.write_text(json.dumps(report, indent=2))
    tmp.replace(out / "report.json")
    print(f"curves and report.json written to {out}")
    if args.update_cards:
        _update_cards(detectors, report, args)
    return 0


def _update_cards(detectors: dict, report: dict, args: argparse.Namespace) -> None:
    """Record this run's numbers in each model's sidecar JSON card (atomically); a ``+2nd`` row goes
    into its detector's card under ``with_second_stage``."""
    import json
    import shlex
    import sys

    def figures(name: str) -> dict:
        return {
            "datasets": {d: v[name] for d, v in report["datasets"].items()},
            "false_drones_per_frame_on_bird_airplane_val_clips": {
                d: v.get(name) for d, v in report.get("false_drones_per_frame", {}).items()
            },
            "operating_threshold": report["operating_thresholds"][name],
            "latency_ms": {t: v[k] for t, v in report["latency_ms"].items() for k in v if k.startswith(name + " ")},
        }

    for name, detector in detectors.items():
        if name.endswith("+2nd"):
            continue
        card_path = detector.model_path.with_suffix(".json")
        card = json.loads(card_path.read_text()) if card_path.is_file() else {}
        card["benchmark"] = {
            "command": "gldt " + " ".join(shlex.quote(a) for a in sys.argv[1:]),
            **figures(name),
            "latency_note": "median wall time incl. pre/post-processing, onnxruntime CPU, shared 2-core machine",
        }
        if name + "+2nd" in detectors:
            card["benchmark"]["with_second_stage"] = figures(name + "+2nd")
        tmp = card_path.with_name(card_path.name + ".tmp")
        tmp.write_text(json.dumps(card, indent=2, sort_keys=True) + "\n")
        tmp.replace(card_path)
        print(f"updated {card_path}")
