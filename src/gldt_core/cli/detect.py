"""``gldt detect --video IN.mp4 --out DETS.txt``: MOTChallenge detections for every frame (onnxruntime)."""

from __future__ import annotations

import argparse
from functools import partial
from typing import Any


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "detect",
        help="run a detector on every frame of a video and write MOTChallenge detections",
        description=(
            "Writes `frame,-1,x,y,w,h,score,-1,-1,-1` lines (frame 1-based, full-frame pixels). The global "
            "detector pairs each frame with its predecessor and, as gldt run's GD frames do by default, fuses "
            "AM-YOLO's boxes with the local model's over tiles of the frame, at this command's --score-threshold "
            "(--no-tile-fusion: AM-YOLO alone); "
            "the local detector tiles the frame into ROIs."
        ),
    )
    parser.add_argument("--video", required=True, help="input video (anything OpenCV decodes)")
    parser.add_argument("--out", required=True, help="output MOTChallenge detection file")
    parser.add_argument("--detector", choices=("global", "local"), default="global")
    parser.add_argument("--model", default=None, help="ONNX model (default: the shipped one)")
    parser.add_argument(
        "--score-threshold",
        type=float,
        default=None,
        help="lowest score written (default: 0.5 of the calibrated drone probability with the second stage, "
        "0.25 without)",
    )
    parser.add_argument(
        "--second-stage",
        default="beside",
        help="crop classifier that re-scores and re-boxes the candidates: 'beside' (second_stage.onnx next to the "
        "model, the default), a path, or 'none'",
    )
    parser.add_argument(
        "--no-tile-fusion",
        action="store_true",
        help="global detector: AM-YOLO's boxes alone, not fused with the shipped local model's over 300 px tiles "
        "(detector.tile_fusion; the fusion needs the second stage, so --second-stage none implies this)",
    )
    parser.add_argument(
        "--classes", choices=("drone", "all"), default="drone", help="write drone boxes only (default) or every class"
    )
    parser.add_argument("--threads", type=int, default=None, help="onnxruntime intra-op threads")
    parser.add_argument(
        "--providers", default="CPUExecutionProvider", help="comma-separated onnxruntime execution providers"
    )
    parser.add_argument("--no-progress", action="store_true")
    parser.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from gldt_core.detect import DRONE_CLASS_ID, GlobalDetector, LocalDetector
    from gldt_core.detect.fusion import build_tile_detector
    from gldt_core.detect.video import detect_frames, iter_video_frames
    from gldt_core.io.mot import write_mot

    providers = tuple(p.strip() for p in args.providers.split(",") if p.strip())
    # Asked about drones only, a box is a drone whenever its drone score passes (decode_output).
    settings: dict[str, Any] = {
        "providers": providers,
        "score_threshold": args.score_threshold,
        "num_threads": args.threads,
        "classes": (DRONE_CLASS_ID,) if args.classes == "drone" else None,
        "second_stage": None if args.second_stage == "none" else args.second_stage,
    }
    detector: GlobalDetector | LocalDetector
    if args.detector == "local":
        detector = LocalDetector(model_path=args.model, **settings)
    else:
        fuse = not args.no_tile_fusion and settings["second_stage"] is not None
        # The tile detector is built once AM-YOLO has opened, so its errors come first.
        tiles = partial(build_tile_detector, None, settings) if fuse else None
        detector = GlobalDetector(model_path=args.model, tile_detector=tiles, **settings)
    frames = tqdm(
        iter_video_frames(args.video), desc=f"detect ({args.detector})", unit="frame", disable=args.no_progress
    )
    roi = int(getattr(detector, "card", {}).get("roi_side", 300))
    rows = detect_frames(frames, detector, roi_side=roi)
    if args.classes == "drone":
        rows = rows[rows[:, 7] == DRONE_CLASS_ID]
    rows[:, 7] = -1  # MOTChallenge detection files carry -1 in the last three columns
    write_mot(args.out, rows)
    frames_seen = int(rows[:, 0].max()) if len(rows) else 0
    print(f"wrote {len(rows)} detections to {args.out} (last frame with a detection: {frames_seen})")
    return 0
