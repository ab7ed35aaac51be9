"""``gldt eval``: MOT metrics (HOTA, DetA, AssA, MOTA, MOTP, IDF1, IDSW, FP, FN, Frag).

``--gt`` and ``--pred`` are two MOTChallenge files, or two folders: the gt folder holds
``SEQ.txt`` files or MOTChallenge ``SEQ/gt/gt.txt`` folders, the pred folder ``SEQ.txt`` files.
Sequences are combined the way TrackEval combines them. Ground-truth class 1 (drone) is the
target; classes 2-4 (bird, airplane, helicopter) are distractors: predictions on them are neither
rewarded nor counted as false positives. Printed values are percentages; ``--json`` prints
fractions (TrackEval's internal convention) for machines.
"""

from __future__ import annotations

import argparse

TABLE_COLUMNS = ("HOTA", "DetA", "AssA", "MOTA", "MOTP", "IDF1", "IDSW", "FP", "FN", "Frag")
PERCENT = {"HOTA", "DetA", "AssA", "MOTA", "MOTP", "IDF1"}


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``gldt eval``."""
    parser = subparsers.add_parser(
        "eval",
        help="MOT metrics of tracks against ground truth (files or folders)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--gt", required=True, help="ground-truth MOT file or folder")
    parser.add_argument("--pred", required=True, help="predicted tracks MOT file or folder")
    parser.add_argument("--json", action="store_true", help="print JSON (fractions) instead of a table")
    parser.add_argument("--target-classes", default="1", help="comma-separated gt classes to score (default 1)")
    parser.add_argument(
        "--distractor-classes",
        default="2,3,4",
        help="comma-separated distractor gt classes (default 2,3,4; empty for none)",
    )
    parser.set_defaults(func=run_eval)


def _classes(text: str, option: str) -> tuple[int, ...]:
    try:
        return tuple(int(part) for part in text.split(",") if part.strip())
    except ValueError:
        raise ValueError(f"{option} must be comma-separated integers, got {text!r}") from None


def find_sequences(gt: str, pred: str) -> dict[str, tuple[str, str]]:
    """``{name: (gt_file, pred_file)}`` for a file pair or a pair of folders."""
    from pathlib import Path

    gt_path, pred_path = Path(gt), Path(pred)
    if not gt_path.exists():
        raise FileNotFoundError(f"ground truth not found: {gt_path}")
    if not pred_path.exists():
        raise FileNotFoundError(f"predictions not found: {pred_path}")
    if gt_path.is_file() != pred_path.is_file():
        raise ValueError("--gt and --pred must both be files or both be folders")
    if gt_path.is_file():
        return {gt_path.stem: (str(gt_path), str(pred_path))}
    sequences: dict[str, tuple[str, str]] = {}
    for entry in sorted(gt_path.iterdir()):
        if entry.is_file() and entry.suffix == ".txt":
            name, gt_file = entry.stem, entry
        elif entry.is_dir() and (entry / "gt" / "gt.txt").is_file():
            name, gt_file = entry.name, entry / "gt" / "gt.txt"
        else:
            continue
        pred_file = pred_path / f"{name}.txt"
        if not pred_file.is_file():
            raise FileNotFoundError(f"no predictions for sequence {name}: {pred_file} is missing")
        sequences[name] = (str(gt_file), str(pred_file))
    if not sequences:
        raise FileNotFoundError(f"no ground-truth sequences (SEQ.txt or SEQ/gt/gt.txt) in {gt_path}")
    return sequences


def format_table(per_sequence: dict[str, dict[str, float]], combined: dict[str, float]) -> str:
    """Fixed-width table: one row per sequence and a COMBINED row; ratios in percent."""
    names = list(per_sequence) + ["COMBINED"]
    width = max(12, max(len(n) for n in names))
    head = f"{'sequence':<{width}} " + " ".join(f"{c:>7}" for c in TABLE_COLUMNS)
    lines = [head, "-" * len(head)]
    for name in names:
        metrics = combined if name == "COMBINED" else per_sequence[name]
        cells = [f"{100 * metrics[c]:7.2f}" if c in PERCENT else f"{int(metrics[c]):7d}" for c in TABLE_COLUMNS]
        lines.append(f"{name:<{width}} " + " ".join(cells))
    return "\n".join(lines)


def run_eval(args: argparse.Namespace) -> int:
    """Handler of ``gldt eval``."""
    import json

    from gldt_core.eval import evaluate_many
    from gldt_core.io.mot import read_mot

    targets = _classes(args.target_classes, "--target-classes")
    distractors = _classes(args.distractor_classes, "--distractor-classes")
    if not targets:
        raise ValueError("--target-classes must name at least one class")
    pairs = find_sequences(args.gt, args.pred)
    data = {}
    for name, (gt_file, pred_file) in pairs.items():
        data[name] = (read_mot(gt_file), read_mot(pred_file))
    try:
        result = evaluate_many(data, target_classes=targets, distractor_classes=distractors)
    except ValueError as error:
        raise ValueError(f"{args.pred}: {error}") from None
    if args.json:
        print(json.dumps(result, indent=2, sort_keys=True))
    else:
        print(format_table(result["per_sequence"], result["combined"]))
    return 0
