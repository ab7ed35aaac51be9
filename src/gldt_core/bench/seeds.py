"""``gldt bench seeds``: variants of a model compared over several training seeds, not one.

A second stage trained twice from the same config with two seeds can differ by more than two
configs do: the shipped config's false drones per frame on ``val_b`` ran from 0.056 to 0.112 over
four seeds (docs/experiment-log.md, "grey crops over four seeds"). A variant judged on one or two
seeds is judged on its luck. This command reads the ``report.json`` files that ``gldt bench
detection --out DIR`` writes, one per trained seed, groups them by variant, and prints for each
variant the mean, lowest and highest over its seeds of

* the second stage's accuracy on its calibration clips (from its model card, as recorded in the
  report; absent in reports written before the report carried it),
* the worst validation split's AP50 and false drones per frame on bird/airplane clips, for one
  row of the detection bench (``--row``, default ``fused+2nd``, the default GD frame), and
* precision and recall at the operating threshold on each split.

The first variant is the peer: each other variant's mean is printed as a difference from it,
beside the peer's own spread over its seeds (highest minus lowest), so a difference the seeds
alone would make is plain to see. Nothing is trained or run here.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

#: The detection bench's row read by default: AM-YOLO's and the tiled local model's calibrated
#: boxes fused, what a GD frame reports.
DEFAULT_ROW = "fused+2nd"


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "seeds", help="compare model variants over several training seeds (reads gldt bench detection reports)"
    )
    parser.add_argument(
        "--variant",
        action="append",
        required=True,
        metavar="NAME=REPORT[,REPORT...]",
        help="a variant and the report.json of each of its seeds (or the --out folders holding them); "
        "repeat for each variant, the peer first",
    )
    parser.add_argument("--row", default=DEFAULT_ROW, help=f"detection bench row to read (default {DEFAULT_ROW})")
    parser.add_argument("--json", default=None, help="also write the summary here")
    parser.set_defaults(func=_run)


def parse_variant(text: str) -> tuple[str, list[Path]]:
    """``NAME=A,B`` -> (NAME, [A/report.json or A, ...]); one clear error for anything else."""
    name, sep, paths = text.partition("=")
    if not sep or not name.strip() or not paths.strip():
        raise ValueError(f"--variant {text!r}: expected NAME=REPORT[,REPORT...]")
    reports = []
    for item in paths.split(","):
        path = Path(item.strip())
        reports.append(path / "report.json" if path.is_dir() else path)
    return name.strip(), reports


def seed_figures(report: dict[str, Any], row: str, source: str = "report") -> dict[str, float]:
    """The figures of one seed's detection report for ``row``: worst split's AP50 and false drones
    per frame, precision and recall on each split, and the calibration accuracy when recorded."""
    datasets = report.get("datasets") or {}
    splits = sorted(name for name in datasets if name.startswith("real-"))
    if not splits:
        raise ValueError(f"{source}: no real validation split in its datasets")
    figures: dict[str, float] = {}
    ap50, false_drones = [], []
    for split in splits:
        if row not in datasets[split]:
            raise ValueError(f"{source}: no row {row!r} for {split} (rows: {', '.join(datasets[split])})")
        metrics = datasets[split][row]
        ap50.append(float(metrics["ap50"]))
        figures[f"precision {split}"] = float(metrics["precision_at_threshold"])
        figures[f"recall {split}"] = float(metrics["recall_at_threshold"])
        per_frame = (report.get("false_drones_per_frame") or {}).get(split, {})
        if row in per_frame:
            false_drones.append(float(per_frame[row]))
    figures["worst split AP50"] = min(ap50)
    if false_drones:
        figures["worst split false drones/frame"] = max(false_drones)
    calibration = ((report.get("second_stage") or {}).get("calibration_clip_figures") or {}).get("accuracy")
    if calibration is not None:
        figures["calibration accuracy"] = float(calibration)
    return figures


def summarise(seeds: list[dict[str, float]]) -> dict[str, dict[str, float]]:
    """Per figure: mean, lowest, highest and how many seeds have it."""
    names = sorted({name for figures in seeds for name in figures})
    out: dict[str, dict[str, float]] = {}
    for name in names:
        values = [figures[name] for figures in seeds if name in figures]
        out[name] = {"mean": sum(values) / len(values), "min": min(values), "max": max(values), "seeds": len(values)}
    return out


def format_summary(summaries: dict[str, dict[str, dict[str, float]]]) -> str:
    """One table: a line per figure, a column per variant (mean [lowest-highest] over its seeds);
    for each variant after the first, its mean's difference from the first's, and the first's spread."""
    names = list(summaries)
    peer = names[0]
    figures = sorted({figure for summary in summaries.values() for figure in summary})
    header = f"{'figure':34s} " + " ".join(f"{name[:26]:>26s}" for name in names)
    if len(names) > 1:
        header += f"  {'difference from ' + peer[:18]:>34s}  {peer[:12] + ' spread':>19s}"
    lines = [header]
    for figure in figures:
        cells = []
        for name in names:
            entry = summaries[name].get(figure)
            cells.append(
                f"{entry['mean']:.4f} [{entry['min']:.3f}-{entry['max']:.3f}] n{int(entry['seeds'])}" if entry else "-"
            )
        line = f"{figure:34s} " + " ".join(f"{cell:>26s}" for cell in cells)
        base = summaries[peer].get(figure)
        if len(names) > 1 and base is not None:
            differences = [
                f"{summaries[name][figure]['mean'] - base['mean']:+.4f}" if figure in summaries[name] else "-"
                for name in names[1:]
            ]
            line += f"  {', '.join(differences):>34s}  {base['max'] - base['min']:>19.4f}"
        lines.append(line)
    return "\n".join(lines)


def _run(args: argparse.Namespace) -> int:
    summaries: dict[str, dict[str, dict[str, float]]] = {}
    for text in args.variant:
        name, paths = parse_variant(text)
        if name in summaries:
            raise ValueError(f"--variant {name!r} given twice")
        seeds = []
        for path in paths:
            try:
                report = json.loads(path.read_text())
            except FileNotFoundError:
                raise ValueError(
                    f"{path}: no such report (gldt bench detection --out DIR writes DIR/report.json)"
                ) from None
            except json.JSONDecodeError as error:
                raise ValueError(f"{path}: not a JSON report ({error.msg}, line {error.lineno})") from None
            seeds.append(seed_figures(report, args.row, str(path)))
        summaries[name] = summarise(seeds)
    print(f"row {args.row}: mean [lowest-highest] over each variant's seeds")
    print(format_summary(summaries))
    if args.json:
        Path(args.json).write_text(json.dumps({"row": args.row, "variants": summaries}, indent=2))
    return 0
