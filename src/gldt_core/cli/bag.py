"""``gldt bag``: convert a video + gt, a MOT folder or a synthetic scene into a rosbag2 MCAP."""

from __future__ import annotations

import argparse
from collections.abc import Iterator


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``gldt bag``."""
    parser = subparsers.add_parser(
        "bag",
        help="convert a video/MOT folder/synthetic scene to a rosbag2 MCAP with ground truth",
        description="Write /camera/image_raw[/compressed], /camera/camera_info and "
        "/gldt/ground_truth from any frame source (video + MOT gt, MOT folder, synth:seed=N,frames=K).",
    )
    parser.add_argument(
        "--from",
        dest="source",
        required=True,
        metavar="SOURCE",
        help="VIDEO (gt found at ../gt/NAME.txt), MOTDIR, or synth:seed=N,frames=K[,targets=T]",
    )
    parser.add_argument("--out", required=True, metavar="BAG", help="output bag folder (must not exist)")
    parser.add_argument("--gt", default=None, help="ground-truth MOT file (overrides the default)")
    parser.add_argument("--raw", action="store_true", help="sensor_msgs/Image bgr8 instead of JPEG")
    parser.add_argument("--jpeg-quality", type=int, default=90, help="JPEG quality (default 90)")
    parser.add_argument("--start", type=int, default=0, help="first frame to copy (0-based, default 0)")
    parser.add_argument("--max-frames", type=int, default=None, help="copy at most this many frames")
    parser.add_argument(
        "--hfov",
        type=float,
        default=60.0,
        help="horizontal field of view (deg) for camera_info when the source has no K",
    )
    parser.add_argument("--force", action="store_true", help="replace an existing bag")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Convert; returns 0."""
    import itertools

    from gldt_core.cli import CliError
    from gldt_core.io.bag import default_camera_matrix, write_bag
    from gldt_core.io.sources import Frame, open_source

    if args.start < 0:
        raise CliError(f"--start must be >= 0, got {args.start}")
    if args.max_frames is not None and args.max_frames < 1:
        raise CliError(f"--max-frames must be >= 1, got {args.max_frames}")
    source = open_source(args.source, gt=args.gt)
    stop = None if args.max_frames is None else args.start + args.max_frames

    def renumbered() -> Iterator[Frame]:
        for frame in itertools.islice(source, args.start, stop):
            rows = frame.ground_truth.copy()
            index = frame.index - args.start
            if len(rows):
                rows[:, 0] = index + 1
            yield Frame(index, frame.stamp - args.start / source.fps, frame.image, rows)

    camera = source.camera_matrix if source.camera_matrix is not None else default_camera_matrix(source.size, args.hfov)
    summary = write_bag(
        args.out,
        renumbered(),
        size=source.size,
        camera_matrix=camera,
        compressed=not args.raw,
        jpeg_quality=args.jpeg_quality,
        overwrite=args.force,
    )
    print(
        f"wrote {summary.path}: {summary.frames} frames, {summary.ground_truth_rows} gt rows, "
        f"{summary.bytes / 1e6:.1f} MB ({'JPEG' if summary.compressed else 'raw bgr8'})"
    )
    return 0
