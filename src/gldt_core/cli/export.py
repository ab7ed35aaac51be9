"""``gldt export CHECKPOINT --out MODEL.onnx``: ONNX (opset 17) + JSON model card (needs torch)."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "export",
        help="export a trained detector checkpoint to ONNX plus a JSON model card (needs torch)",
        description=(
            "Export best.pt/last.pt from `gldt train` to ONNX. The global model gets inputs previous/current "
            "with dynamic height/width; the local model gets a dynamic batch and sides. The card (same stem, "
            ".json) records input size, strides, classes, training data and validation metrics, and the "
            "torch-vs-onnxruntime check."
        ),
    )
    parser.add_argument(
        "checkpoint",
        help="checkpoint written by `gldt train` (or an .onnx model with --int8, --rewrite-windows or --dynamic-sides)",
    )
    parser.add_argument(
        "--out", default=None, help="output .onnx path (card written next to it); not with --feature-reuse"
    )
    parser.add_argument("--name", default=None, help="model name for the card (default: file stem)")
    parser.add_argument(
        "--size",
        type=int,
        nargs=2,
        metavar=("W", "H"),
        default=None,
        help="example/nominal input size (default: global 640 384, local from the config)",
    )
    parser.add_argument("--note", default="", help="free text for the card (e.g. how the model was trained)")
    parser.add_argument(
        "--int8",
        action="store_true",
        help="quantize an exported .onnx (static int8, calibrated on Halmstad training clips; no torch needed)",
    )
    parser.add_argument("--calibration-root", default=None, help="Halmstad clips for --int8 calibration")
    parser.add_argument(
        "--rewrite-windows",
        action="store_true",
        help=(
            "rewrite an exported .onnx's 6-D STFF window permutes as 4-D ones "
            "(same outputs, checked; faster in onnxruntime; no torch needed)"
        ),
    )
    parser.add_argument(
        "--dynamic-sides",
        action="store_true",
        help=(
            "give an exported local .onnx with a fixed input size dynamic sides, so ROIs smaller than its input "
            "are run at the smallest size that holds them (same outputs at the old size, checked; no torch needed)"
        ),
    )
    parser.add_argument(
        "--feature-reuse",
        action="store_true",
        help=(
            "split an exported AM-YOLO .onnx into NAME.features.onnx and NAME.reuse.onnx next to it, so a stream of "
            "GD frames computes the shared backbone's first stages once per frame "
            "(same outputs, checked; no torch needed)"
        ),
    )
    parser.set_defaults(func=_run)


def _write_feature_reuse(model: Path) -> None:
    try:
        import onnx  # noqa: F401
    except ImportError as error:
        raise ValueError(
            f"--feature-reuse needs the onnx package (pip install onnx; in the test and train extras): {error}"
        ) from error
    from gldt_core.export.feature_split import write_feature_reuse

    result = write_feature_reuse(model)
    print(
        f"wrote {result.features_model.name} and {result.reuse_model.name} next to {model}: "
        f"features {result.split_tensor!r} ({result.channels} channels, stride {result.stride}) "
        f"reused across GD frames; outputs within {result.max_abs_diff:.1e}"
    )


def _refresh_or_drop_split_pair(model: Path) -> None:
    """After ``model`` was (over)written: a split pair next to it belongs to the file it replaced.

    Split the new file instead; where that cannot be done (a quantized graph the split does not
    recognise, outputs that would change), remove the old pair, so that the runtime runs the new
    model whole rather than warn about a stale pair on every start.
    """
    from gldt_core.detect.feature_reuse import features_path, reuse_path
    from gldt_core.export.feature_split import FeatureSplitError

    stale = [path for path in (features_path(model), reuse_path(model)) if path.is_file()]
    if not stale:
        return
    try:
        _write_feature_reuse(model)
    except FeatureSplitError as error:
        for path in stale:
            path.unlink()
        print(
            f"removed {' and '.join(p.name for p in stale)}: split from the file {model} replaced, "
            f"and the new one cannot be split ({error})"
        )


def _run(args: argparse.Namespace) -> int:
    modes = [
        flag
        for flag, on in (
            ("--int8", args.int8),
            ("--rewrite-windows", args.rewrite_windows),
            ("--feature-reuse", args.feature_reuse),
            ("--dynamic-sides", args.dynamic_sides),
        )
        if on
    ]
    if len(modes) > 1:
        raise ValueError(
            f"{' and '.join(modes)} are separate steps: run one export per step, each on the file the last one wrote"
        )
    if args.feature_reuse:
        if Path(args.checkpoint).suffix != ".onnx":
            raise ValueError(f"--feature-reuse splits an exported .onnx model, got {args.checkpoint}")
        if args.out is not None:
            raise ValueError(
                "--feature-reuse writes NAME.features.onnx and NAME.reuse.onnx next to the model "
                "(where the runtime looks); drop --out"
            )
        _write_feature_reuse(Path(args.checkpoint))
        return 0
    if args.out is None:
        raise ValueError("--out is required (the .onnx file to write)")
    if args.dynamic_sides:
        from gldt_core.export.dynamic_sides import make_sides_dynamic

        if Path(args.checkpoint).suffix != ".onnx":
            raise ValueError(f"--dynamic-sides rewrites an exported .onnx model, got {args.checkpoint}")
        diff = make_sides_dynamic(args.checkpoint, args.out)
        print(f"wrote {args.out}: input sides dynamic, outputs within {diff:.1e} of {args.checkpoint}")
        return 0
    if args.rewrite_windows:
        from gldt_core.detect.feature_reuse import features_path
        from gldt_core.export.window_rewrite import rewrite_model_file

        if Path(args.checkpoint).suffix != ".onnx":
            raise ValueError(f"--rewrite-windows rewrites an exported .onnx model, got {args.checkpoint}")
        count, diff = rewrite_model_file(args.checkpoint, args.out)
        print(f"wrote {args.out}: {count} window permutes rewritten, outputs within {diff:.1e} of {args.checkpoint}")
        if features_path(Path(args.checkpoint)).is_file() or features_path(Path(args.out)).is_file():
            _write_feature_reuse(Path(args.out))  # the new file gets its own split pair; an old one would not match it
        return 0

    if args.int8:
        from gldt_core.export.quantize import quantize_model

        if Path(args.checkpoint).suffix != ".onnx":
            raise ValueError(f"--int8 quantizes an exported .onnx model, got {args.checkpoint}")
        from gldt_core.paths import halmstad_root

        out = quantize_model(args.checkpoint, args.out, args.calibration_root or str(halmstad_root()))
        print(f"wrote {out} ({out.stat().st_size / 1e6:.2f} MB)")
        _refresh_or_drop_split_pair(out)
        return 0

    try:
        from gldt_core.export.onnx_export import example_inputs, export_onnx, torch_vs_onnx
        from gldt_core.training.train import load_checkpoint
    except ImportError as error:
        raise ValueError(f"export needs torch and onnx (pip install torch==2.13.0 onnx): {error}") from error

    out = Path(args.out)
    if out.suffix != ".onnx":
        raise ValueError(f"--out must end with .onnx, got {out}")
    model, ckpt = load_checkpoint(args.checkpoint)
    task = ckpt.get("task", "global" if model.spec.dual_frame else "local")
    if args.size:
        width, height = args.size
    elif task == "global":
        width, height = 640, 384
    else:
        side = int(ckpt["config"]["data"]["val_size"][0])
        width, height = side, side
    card = {
        "name": args.name or out.stem,
        "task": task,
        "architecture": "AM-YOLO (dual-frame, STFF)"
        if model.spec.stff_levels
        else ("YOLO11-style, no STFF" if task == "global" else "YOLO11-P2-style local ROI detector"),
        "checkpoint_epoch": ckpt.get("epoch"),
        "validation_during_training": ckpt.get("metrics"),
        "training_data": ckpt.get("data"),
        "training_wall_s": ckpt.get("train_wall_s"),
        "training_wall_s_by_device": ckpt.get("train_wall_s_by_device"),
        "training_config": ckpt.get("config"),
        "note": args.note,
    }
    log = Path(args.checkpoint).with_name("log.csv")
    if log.is_file():  # the per-epoch curve, so the card shows how training went, not just one epoch
        import csv

        with log.open() as fh:
            card["training_log"] = [
                {k: (round(float(v), 4) if v not in ("", None) else None) for k, v in row.items()}
                for row in csv.DictReader(fh)
            ]
    if task == "local":
        card["roi_side"] = int(ckpt["config"]["data"].get("val_roi", 300))
    card = export_onnx(model, out, width, height, card)
    diffs = []
    for seed in (0, 1):
        diffs.append(
            torch_vs_onnx(
                model, out, example_inputs(model, width, height, batch=1 if task == "global" else 4, seed=seed)
            )
        )
    print(
        f"wrote {out} ({card['size_bytes'] / 1e6:.2f} MB) and {out.with_suffix('.json')}; "
        f"torch vs onnxruntime max |diff| {max(diffs):.2e}"
    )
    if task == "global" and model.spec.stff_levels:
        _write_feature_reuse(out)
    return 0
