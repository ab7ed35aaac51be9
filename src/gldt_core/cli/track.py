"""``gldt track``: run JPTrack or ByteTrack over a MOTChallenge detection file.

Reads ``frame,-1,x,y,w,h,score,...`` lines (frame 1-based; line order does not matter, frames are
grouped by number), runs one tracker update per frame from 1 to the last frame at
``t = (frame - 1) / fps`` (frames without detections are empty updates, so gaps take real time),
and writes ``frame,id,x,y,w,h,score,-1,-1,-1`` atomically.
"""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``gldt track``."""
    parser = subparsers.add_parser(
        "track",
        help="track detections (MOTChallenge det.txt) with JPTrack or ByteTrack",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--dets", required=True, help="MOTChallenge detections (frame,-1,x,y,w,h,score,...)")
    parser.add_argument("--out", required=True, help="output MOTChallenge tracks file")
    parser.add_argument("--tracker", choices=("jptrack", "bytetrack"), default="jptrack")
    parser.add_argument("--fps", type=float, default=30.0, help="frame rate of the stream (default 30)")
    parser.add_argument("--no-jcma", action="store_true", help="JPTrack: IoU association instead of JCMA")
    parser.add_argument("--no-pmr", action="store_true", help="JPTrack: disable PMR recovery")
    parser.add_argument(
        "--image-size",
        type=int,
        nargs=2,
        metavar=("W", "H"),
        default=(1920, 1080),
        help="image size for PMR's relative positions (default 1920 1080)",
    )
    parser.set_defaults(func=run_track)


def run_track(args: argparse.Namespace) -> int:
    """Handler of ``gldt track``."""
    import math

    from gldt_core.io.mot import read_mot, write_mot
    from gldt_core.track import ByteTrack, ByteTrackConfig, JPTrack, JPTrackConfig
    from gldt_core.track.runner import track_detection_rows

    if not math.isfinite(args.fps) or args.fps <= 0:
        raise ValueError(f"--fps must be a positive number, got {args.fps}")
    if min(args.image_size) < 1:
        width, height = args.image_size
        raise ValueError(f"--image-size must be two positive integers W H, got {width} {height}")
    from gldt_core.cli._paths import check_output_path

    check_output_path(args.out, "--out")
    rows = read_mot(args.dets)
    size = (int(args.image_size[0]), int(args.image_size[1]))
    tracker: ByteTrack | JPTrack
    if args.tracker == "bytetrack":
        tracker = ByteTrack(ByteTrackConfig(image_size=size))
    else:
        tracker = JPTrack(JPTrackConfig(use_jcma=not args.no_jcma, use_pmr=not args.no_pmr, image_size=size))
    try:
        tracks = track_detection_rows(tracker, rows, args.fps)
    except ValueError as error:
        raise ValueError(f"{args.dets}: {error}") from None
    write_mot(args.out, tracks)
    ids = len(set(tracks[:, 1].astype(int).tolist())) if len(tracks) else 0
    frames = int(rows[:, 0].max()) if len(rows) else 0
    print(
        f"{args.tracker}: {frames} frames, {len(rows)} detections -> {len(tracks)} boxes, {ids} tracks; "
        f"wrote {args.out}"
    )
    return 0
