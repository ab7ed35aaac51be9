"""``gldt train global|local|second-stage --config CFG``: train a detector or the second stage (needs torch)."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "train",
        help="train the global (AM-YOLO) or local detector, or the second stage, from a YAML config (needs torch)",
        description="Train a detector (writes config.yaml, log.csv, curves.png, last.pt and best.pt to the run "
        "directory) or the second stage (last.pt after every epoch, then second_stage.onnx and its card).",
    )
    parser.add_argument("task", choices=("global", "local", "second-stage"), help="which model to train")
    parser.add_argument(
        "--resume",
        default=None,
        help="continue the run whose last.pt this is (weights, optimiser, schedule, data order, time spent); "
        "for a second-stage ensemble, its run directory",
    )
    parser.add_argument(
        "--init-from",
        default=None,
        help="detectors: start this config's schedule from the weights of another run's best.pt or last.pt",
    )
    parser.add_argument(
        "--stop-after-s",
        type=float,
        default=None,
        help="detectors: end this session at an epoch's end, before the epoch that would end past this many "
        "seconds (judged by the last one's length), then --resume its last.pt; unlike --max-wall-s it does "
        "not shorten the schedule",
    )
    parser.add_argument("--config", required=True, help="training YAML (see src/gldt_core/configs/)")
    parser.add_argument("--out", default=None, help="run directory (default: out_dir from the config)")
    parser.add_argument("--seed", type=int, default=None, help="override the config's seed")
    parser.add_argument("--epochs", type=int, default=None, help="override train.epochs")
    parser.add_argument("--steps-per-epoch", type=int, default=None, help="override train.steps_per_epoch")
    parser.add_argument("--device", default=None, help="override train.device: auto, cpu, cuda, cuda:N")
    parser.add_argument(
        "--workers",
        type=int,
        default=None,
        help="override data.load_workers and train.loader_workers (worker processes for decoding and augmentation)",
    )
    parser.add_argument(
        "--max-wall-s",
        type=float,
        default=None,
        help="override train.max_wall_s: finish the schedule within this many seconds",
    )
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    parser.set_defaults(func=_run)


def _with_common_overrides(config: dict, args: argparse.Namespace) -> dict:
    """``--seed``, ``--epochs`` and ``--max-wall-s`` over a training config (detectors and second stage alike)."""
    if args.seed is not None:
        config["seed"] = args.seed
    if args.epochs is not None:
        config["train"]["epochs"] = args.epochs
    if args.max_wall_s is not None:
        config["train"]["max_wall_s"] = args.max_wall_s
    return config


def _run(args: argparse.Namespace) -> int:
    if args.task == "second-stage":
        return _run_second_stage(args)
    try:
        from gldt_core.training.train import load_config, train
    except ImportError as error:  # torch is an optional extra
        raise ValueError(f"training needs torch (pip install torch==2.13.0 onnx): {error}") from error

    config = _with_common_overrides(load_config(args.config), args)
    if args.steps_per_epoch is not None:
        config["train"]["steps_per_epoch"] = args.steps_per_epoch
    if args.device is not None:
        config["train"]["device"] = args.device
    if args.workers is not None:
        config["data"]["load_workers"] = config["train"]["loader_workers"] = args.workers
    best = train(
        args.task,
        config,
        out_dir=args.out,
        progress=not args.no_progress,
        resume=args.resume,
        init_from=args.init_from,
        stop_after_s=args.stop_after_s,
    )
    print(f"best checkpoint: {best}")
    return 0


def _run_second_stage(args: argparse.Namespace) -> int:
    try:
        from gldt_core.training.second_stage import ENSEMBLE_MEMBERS, load_config, train_second_stage
    except ImportError as error:  # torch is an optional extra
        raise ValueError(f"training needs torch (pip install torch==2.13.0 onnx): {error}") from error

    config = load_config(args.config)
    for member in config.get(ENSEMBLE_MEMBERS, [config]):  # an ensemble's overrides go to each member
        _with_common_overrides(member, args)
    for name in ("steps_per_epoch", "device", "workers", "init_from", "stop_after_s"):
        if getattr(args, name.replace("-", "_")) is not None:
            raise ValueError(f"--{name.replace('_', '-')} applies to the detectors, not the second stage")
    result = train_second_stage(config, out_dir=args.out, resume=args.resume, progress=not args.no_progress)
    print(f"second stage: {result}")
    return 0
