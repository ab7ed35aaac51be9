"""``gldt synth``: write a synthetic scene as a MOTChallenge sequence, a bag and/or a preview."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from gldt_core.sim.spec import SceneSpec


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``gldt synth``."""
    parser = subparsers.add_parser(
        "synth",
        help="render a synthetic air-to-air UAV scene (MOT folder, bag, preview)",
        description="Render a deterministic synthetic scene of small UAVs with exact ground truth. "
        "Writes a MOTChallenge sequence (img1/, gt/gt.txt, seqinfo.ini) to --out; --bag also "
        "writes a rosbag2 MCAP; --preview writes a contact sheet PNG.",
    )
    parser.add_argument("--out", help="output folder for the MOTChallenge sequence")
    parser.add_argument("--seed", type=int, default=0, help="scene seed (default 0)")
    parser.add_argument("--frames", type=int, default=90, help="number of frames (default 90)")
    parser.add_argument("--size", default="1920x1080", help="WIDTHxHEIGHT (default 1920x1080)")
    parser.add_argument(
        "--targets", default="1-3", help="number of UAVs, N or A-B (the seed picks within the range; default 1-3)"
    )
    parser.add_argument("--target-size", default="6-60", help="UAV span range in px, A-B (default 6-60)")
    parser.add_argument("--birds", type=int, default=None, help="distractor birds (default: seed decides)")
    parser.add_argument("--fps", type=float, default=30.0, help="frame rate (default 30)")
    parser.add_argument(
        "--split", choices=["train", "val", "test"], help="take the scene from a preset split instead (with --index)"
    )
    parser.add_argument("--index", type=int, default=0, help="scene index within --split")
    parser.add_argument(
        "--jpeg-quality", type=int, default=95, help="JPEG quality of img1/*.jpg and compressed bag images (default 95)"
    )
    parser.add_argument(
        "--bag",
        nargs="?",
        const="",
        default=None,
        metavar="BAG",
        help="also write a rosbag2 MCAP (default path: OUT/bag)",
    )
    parser.add_argument("--raw", action="store_true", help="bag images as sensor_msgs/Image bgr8, not JPEG")
    parser.add_argument(
        "--preview",
        nargs="?",
        const="",
        default=None,
        metavar="PNG",
        help="write a contact sheet PNG (default: OUT/preview.png or ./synth-preview.png)",
    )
    parser.add_argument("--force", action="store_true", help="replace existing outputs")
    parser.set_defaults(func=run)


def build_spec(args: argparse.Namespace) -> SceneSpec:
    """The scene spec from the command-line options (validated by SceneSpec)."""
    from gldt_core.sim.spec import SceneSpec, parse_range, parse_size

    if args.split:
        from gldt_core.sim.presets import split

        specs = split(args.split, count=args.index + 1, frames=args.frames, size=parse_size(args.size))
        return specs[args.index]
    low, high = parse_range(args.targets)
    if low < 0:
        raise ValueError(f"--targets must be >= 0, got {args.targets!r}")
    size_low, size_high = parse_range(args.target_size)
    seed_rng_targets = low if low == high else low + (args.seed * 2654435761 % (high - low + 1))
    return SceneSpec(
        seed=args.seed,
        frames=args.frames,
        size=parse_size(args.size),
        targets=seed_rng_targets,
        fps=args.fps,
        target_size=(float(size_low), float(size_high)),
        birds=args.birds,
    )


def run(args: argparse.Namespace) -> int:
    """Render and write what was asked; returns 0."""
    from pathlib import Path

    import cv2

    from gldt_core.cli import CliError
    from gldt_core.sim.render import SceneRenderer
    from gldt_core.sim.writer import write_mot_sequence

    if args.out is None and args.preview is None and not args.bag:
        raise CliError("nothing to do: give --out DIR, --bag BAG and/or --preview [PNG]")
    if args.bag is not None and args.out is None and not args.bag:
        raise CliError("--bag without a path needs --out DIR (the bag goes to OUT/bag)")
    if not 1 <= args.jpeg_quality <= 100:
        raise CliError(f"--jpeg-quality must be in 1..100, got {args.jpeg_quality}")
    spec = build_spec(args)
    renderer = SceneRenderer(spec)
    if args.out is not None:
        summary = write_mot_sequence(renderer, Path(args.out), jpeg_quality=args.jpeg_quality, overwrite=args.force)
        print(f"wrote {summary}")
    if args.bag is not None:
        from gldt_core.io.bag import write_bag
        from gldt_core.io.synth_source import SynthSource

        bag_path = Path(args.bag) if args.bag else Path(args.out) / "bag"
        source = SynthSource(spec)
        result = write_bag(
            bag_path,
            source,
            size=source.size,
            camera_matrix=source.camera_matrix,
            compressed=not args.raw,
            jpeg_quality=args.jpeg_quality,
            overwrite=args.force,
        )
        print(f"wrote bag {result.path} ({result.frames} frames, {result.bytes / 1e6:.1f} MB)")
    if args.preview is not None:
        from gldt_core.sim.preview import scene_preview

        if args.preview:
            preview_path = Path(args.preview)
        elif args.out is not None:
            preview_path = Path(args.out) / "preview.png"
        else:
            preview_path = Path(f"synth-preview-seed{spec.seed}.png")
        if not preview_path.parent.is_dir():
            raise FileNotFoundError(f"preview folder {preview_path.parent} does not exist")
        sheet = scene_preview(renderer)
        temporary = preview_path.with_name(preview_path.name + ".part.png")
        if not cv2.imwrite(str(temporary), sheet):
            raise CliError(f"cannot write {preview_path}")
        temporary.replace(preview_path)
        print(f"wrote preview {preview_path}")
    return 0
