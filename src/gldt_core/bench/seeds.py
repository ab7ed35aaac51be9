"""``gldt bench seeds``: variants of a model compared over several training seeds, not one.

A second stage trained twice from the same config with two seeds can differ by more than two
configs do, above all in its false drones per frame (docs/experiment-log.md, "grey crops over four
seeds"). A variant judged on one or two seeds is judged on its luck. This command reads the
``report.json`` files that ``gldt bench detection --out DIR`` writes, one per trained seed, groups
them by variant, and prints for each variant the mean, lowest and highest over its seeds of

* the second stage's accuracy on its calibration clips (from its model card, as recorded in the
  report; absent in reports written before the report carried it),
* the worst validation split's AP50 and false drones per frame on bird/airplane clips, for one
  row of the detection bench (``--row``, default ``fused+2nd``, the default GD frame), and
* precision and recall at the operating threshold on each split;

and then, for the same row, how many false drones each bird/airplane clip gave over a seed's
bench (every clip that gave one in any seed of any variant): whether a variant's fewer false
drones are fewer everywhere or on one clip.

It reads end-to-end reports the same way: the JSON of ``gldt bench ablation --json OUT.json``
(one per seed and split, e.g. ``--scenes 0 --clips 99 --other-clips 99 --variants GD+LD+JPTrack``)
gives the shipped system's MOTA, IDF1, HOTA and IDSW on the split's drone clips and its false
drone track rows per frame on its bird/airplane clips, and those rows clip by clip. A variant may
list both kinds of report; reports are compared with the first of their own kind and split.

The first variant is the peer: each other variant's mean is printed as a difference from it,
beside the peer's own spread over its seeds (highest minus lowest), so a difference the seeds
alone would make is plain to see. Nothing is trained or run here.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from gldt_core.bench.ablation import (
    CLIPS_KEY,
    FALSE_ROWS_BY_CLIP_KEY,
    FALSE_ROWS_KEY,
    GLDT,
    OTHER_CLIPS_KEY,
    ROWS_KEY,
)
from gldt_core.bench.detection import FUSED

#: The detection bench's row read by default: AM-YOLO's and the tiled local model's calibrated
#: boxes fused, what a GD frame reports.
DEFAULT_ROW = FUSED


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "seeds",
        help="compare model variants over several training seeds (reads gldt bench detection reports)",
        description="Each figure of each variant as 'mean [lowest-highest] nN' over its N seeds; for each "
        "variant after the first, its mean minus the first's, and the first's spread over its seeds "
        "(highest minus lowest; '-' with fewer than two seeds): a difference within that spread is what "
        "the seeds alone would make. Reports must come from runs over the same clips.",
    )
    parser.add_argument(
        "--variant",
        action="append",
        required=True,
        metavar="NAME=REPORT[,REPORT...]",
        help="a variant and the report.json of each of its seeds (or the --out folders holding them); "
        "repeat for each variant, the peer first",
    )
    parser.add_argument(
        "--row",
        default=DEFAULT_ROW,
        help=f"detection bench row to read (default {DEFAULT_ROW}; a report lacking it names the rows it has)",
    )
    parser.add_argument("--json", default=None, help="also write the summary here")
    parser.set_defaults(func=_run)


def parse_variant(text: str) -> tuple[str, list[Path]]:
    """``NAME=A,B`` -> (NAME, [A/report.json or A, ...]); one clear error for anything else."""
    name, sep, paths = text.partition("=")
    items = [item.strip() for item in paths.split(",")]
    if not sep or not name.strip() or not all(items):
        raise ValueError(f"--variant {text!r}: expected NAME=REPORT[,REPORT...] without empty reports")
    return name.strip(), [Path(item) / "report.json" if Path(item).is_dir() else Path(item) for item in items]


def _table(value: Any, source: str, what: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise ValueError(f"{source}: {what} missing or not a table")
    return value


def _number(table: dict[str, Any], key: str, source: str, what: str) -> float:
    value = table.get(key)
    if not isinstance(value, int | float) or isinstance(value, bool):
        raise ValueError(f"{source}: {what} has no number {key!r}")
    return float(value)


def seed_figures(report: Any, row: str, source: str = "report") -> dict[str, float]:
    """The figures of one seed's detection report for ``row``: worst split's AP50 and false drones
    per frame, precision and recall on each split, and the calibration accuracy when recorded."""
    datasets = _table(_table(report, source, "the report").get("datasets"), source, "datasets")
    splits = sorted(name for name in datasets if name.startswith("real-"))
    if not splits:
        raise ValueError(f"{source}: no real validation split in its datasets")
    false_drones = report.get("false_drones_per_frame")
    figures: dict[str, float] = {}
    ap50, worst_false = [], []
    for split in splits:
        rows = _table(datasets[split], source, split)
        if row not in rows:
            raise ValueError(f"{source}: no row {row!r} for {split} (rows: {', '.join(rows)})")
        metrics = _table(rows[row], source, f"{split} {row}")
        ap50.append(_number(metrics, "ap50", source, f"{split} {row}"))
        figures[f"precision {split}"] = _number(metrics, "precision_at_threshold", source, f"{split} {row}")
        figures[f"recall {split}"] = _number(metrics, "recall_at_threshold", source, f"{split} {row}")
        if false_drones is not None:
            split_false = _table(
                _table(false_drones, source, "false_drones_per_frame").get(split), source, f"false drones of {split}"
            )
            worst_false.append(_number(split_false, row, source, f"false drones of {split}"))
    figures["worst split AP50"] = min(ap50)
    if worst_false:
        figures["worst split false drones/frame"] = max(worst_false)
    calibration = ((report.get("second_stage") or {}).get("calibration_clip_figures") or {}).get("accuracy")
    if calibration is not None:
        figures["calibration accuracy"] = float(calibration)
    return figures


#: What an end-to-end report gives of the GL-DT row on each split's drone clips.
END_TO_END_METRICS = ("MOTA", "IDF1", "HOTA", "IDSW")


def is_end_to_end(report: Any) -> bool:
    """Whether ``report`` is a ``gldt bench ablation --json`` report with real clips in it."""
    return isinstance(report, dict) and any(key.startswith((ROWS_KEY, FALSE_ROWS_KEY)) for key in report)


def end_to_end_figures(report: dict[str, Any], source: str = "report") -> dict[str, float]:
    """The GL-DT row's figures of one seed's ablation report: ``"<metric> <split>"`` for each
    split's drone clips, ``"false drone track rows/frame <split>"`` for its bird/airplane clips."""
    figures: dict[str, float] = {}
    for key, value in report.items():
        if key.startswith(ROWS_KEY):
            split = key.removeprefix(ROWS_KEY)
            listed = value if isinstance(value, list) else []
            rows = {row.get("variant"): row for row in listed if isinstance(row, dict)}
            if GLDT not in rows:
                raise ValueError(f"{source}: no {GLDT} row for {split} (run the ablation with it)")
            for metric in END_TO_END_METRICS:
                figures[f"{metric} {split}"] = _number(rows[GLDT], metric, source, f"{split} {GLDT}")
        elif key.startswith(FALSE_ROWS_KEY):
            split = key.removeprefix(FALSE_ROWS_KEY)
            figures[f"false drone track rows/frame {split}"] = _number(report, key, source, "the report")
    return figures


def clip_false_track_rows(report: dict[str, Any]) -> dict[str, float]:
    """``"<split> <clip>" -> false drone track rows`` of an ablation report's bird/airplane clips."""
    counts: dict[str, float] = {}
    for key, rows in sorted(report.items()):
        if key.startswith(FALSE_ROWS_BY_CLIP_KEY):
            split = key.removeprefix(FALSE_ROWS_BY_CLIP_KEY)
            counts.update({f"{split} {clip}": float(count) for clip, count in sorted((rows or {}).items())})
    return counts


def clip_false_drones(report: dict[str, Any], row: str) -> dict[str, float]:
    """``"<split> <clip>" -> false drones`` of ``row`` on each bird/airplane clip of the report
    (empty for a report written before the bench listed them by clip)."""
    by_clip = report.get("false_drones_by_clip") or {}
    counts: dict[str, float] = {}
    for split, rows in sorted(by_clip.items()):
        for clip, count in sorted(((rows or {}).get(row) or {}).items()):
            counts[f"{split} {clip}"] = float(count)
    return counts


def run_settings(report: dict[str, Any], row: str) -> tuple[Any, ...]:
    """What must be the same for two reports to be compared: the clips of each split, and the
    row's operating threshold (a detection report), or whether the ground truth stood in for the
    detectors' boxes (an ablation report)."""
    if is_end_to_end(report):
        clips = tuple(
            sorted((key, tuple(value)) for key, value in report.items() if key.startswith((CLIPS_KEY, OTHER_CLIPS_KEY)))
        )
        return clips, bool(report.get("oracle"))
    clips = tuple(sorted((key, tuple(value)) for key, value in report.items() if key.endswith("_clips")))
    return clips, (report.get("operating_thresholds") or {}).get(row)


def report_scope(report: dict[str, Any]) -> str:
    """Which reports compare with each other: detection reports, or ablation reports of one split."""
    if not is_end_to_end(report):
        return "gldt bench detection"
    splits = sorted(
        key.removeprefix(prefix) for key in report for prefix in (ROWS_KEY, FALSE_ROWS_KEY) if key.startswith(prefix)
    )
    return "gldt bench ablation on " + ", ".join(dict.fromkeys(splits))


def summarise(seeds: list[dict[str, float]]) -> dict[str, dict[str, float]]:
    """Per figure: mean, lowest, highest and how many seeds have it."""
    names = sorted({name for figures in seeds for name in figures})
    out: dict[str, dict[str, float]] = {}
    for name in names:
        values = [figures[name] for figures in seeds if name in figures]
        out[name] = {"mean": sum(values) / len(values), "min": min(values), "max": max(values), "seeds": len(values)}
    return out


def format_summary(summaries: dict[str, dict[str, dict[str, float]]], title: str = "figure", decimals: int = 4) -> str:
    """One table: a line per figure, a column per variant (mean [lowest-highest] over its seeds);
    for each variant after the first, its mean's difference from the first's, and the first's
    spread ('-' where the first has fewer than two seeds for that figure). ``title`` heads the
    figures' column; means and differences carry ``decimals`` digits, the range one fewer."""
    names = list(summaries)
    peer = names[0]
    figures = sorted({figure for summary in summaries.values() for figure in summary})
    places = max(decimals - 1, 0)
    header = f"{title:34s} " + " ".join(f"{name[:26]:>26s}" for name in names)
    header += "".join(f"  {name[:12] + ' - ' + peer[:12]:>27s}" for name in names[1:])
    if len(names) > 1:
        header += f"  {peer[:12] + ' spread':>19s}"
    lines = [header]
    for figure in figures:
        cells = []
        for name in names:
            entry = summaries[name].get(figure)
            if entry is None:
                cells.append("-")
                continue
            low, high = f"{entry['min']:.{places}f}", f"{entry['max']:.{places}f}"
            cells.append(f"{entry['mean']:.{decimals}f} [{low}-{high}] n{int(entry['seeds'])}")
        line = f"{figure:34s} " + " ".join(f"{cell:>26s}" for cell in cells)
        base = summaries[peer].get(figure)
        for name in names[1:]:
            other = summaries[name].get(figure)
            line += f"  {other['mean'] - base['mean']:>+27.{decimals}f}" if other and base else f"  {'-':>27s}"
        if len(names) > 1:
            spread = f"{base['max'] - base['min']:.{decimals}f}" if base and base["seeds"] >= 2 else "-"
            line += f"  {spread:>19s}"
        lines.append(line)
    return "\n".join(lines)


def _read(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(
            f"{path}: no such report (gldt bench detection --out DIR writes DIR/report.json, "
            "gldt bench ablation --json OUT.json an end-to-end one)"
        ) from None
    except json.JSONDecodeError as error:
        raise ValueError(f"{path}: not a JSON report ({error.msg}, line {error.lineno})") from None


def _run(args: argparse.Namespace) -> int:
    summaries: dict[str, dict[str, dict[str, float]]] = {}
    by_clip: dict[str, dict[str, dict[str, float]]] = {}
    track_rows_by_clip: dict[str, dict[str, dict[str, float]]] = {}
    first: dict[str, tuple[Path, tuple[Any, ...]]] = {}
    for text in args.variant:
        name, paths = parse_variant(text)
        if name in summaries:
            raise ValueError(f"--variant {name!r} given twice")
        seeds, clip_counts, clip_rows = [], [], []
        for path in paths:
            report = _read(path)
            if is_end_to_end(report):
                seeds.append(end_to_end_figures(report, str(path)))
                if rows := clip_false_track_rows(report):
                    clip_rows.append(rows)
            else:
                seeds.append(seed_figures(report, args.row, str(path)))
                if counts := clip_false_drones(report, args.row):
                    clip_counts.append(counts)
            scope, settings = report_scope(report), run_settings(report, args.row)
            if scope not in first:
                first[scope] = (path, settings)
            elif settings != first[scope][1]:
                raise ValueError(
                    f"{path}: benched on other clips or at other settings than {first[scope][0]} ({scope})"
                )
        summaries[name] = summarise(seeds)
        by_clip[name] = summarise(clip_counts)
        track_rows_by_clip[name] = summarise(clip_rows)
    rows_read = f"row {args.row} (detection reports), {GLDT} (ablation reports)"
    print(f"{rows_read}: mean [lowest-highest] nN over each variant's N seeds")
    print(format_summary(summaries))
    for table, what in (
        (by_clip, f"false drones by bird/airplane clip, row {args.row} (each seed's count over its bench's frames)"),
        (track_rows_by_clip, f"false drone track rows by bird/airplane clip, {GLDT} (each seed's rows over the clip)"),
    ):
        # Only the clips where some seed of some variant called something a drone.
        named = {clip for summary in table.values() for clip, entry in summary.items() if entry["max"] > 0}
        if named:
            print(f"\n{what}:")
            kept = {name: {clip: table[name][clip] for clip in named & set(table[name])} for name in table}
            print(format_summary(kept, title="split clip", decimals=1))
    if args.json:
        out = {
            "row": args.row,
            "variants": summaries,
            "false_drones_by_clip": by_clip,
            "false_drone_track_rows_by_clip": track_rows_by_clip,
        }
        Path(args.json).write_text(json.dumps(out, indent=2))
    return 0
