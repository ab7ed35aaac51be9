"""``gldt run``: track drones in a video, an image folder or a ROS 2 bag; write MOTChallenge tracks.

Example::

    gldt run --video clip.mp4 --out tracks.txt --render overlay.mp4 --plot run.png

Prints one summary line (frames, FPS, share of frames on the global detector) and where the
time went. Bad input (missing file, bad config, unreadable model, an output path that cannot be
written: a folder, a read-only place) fails before the first frame with one line and exit status 2.

Damaged input does not end a run quietly: an image or a video frame that cannot be decoded is
skipped with a warning (the tracker coasts over the gap), reading goes on past it, and a video that
ends before its declared frame count is reported. Everything read is tracked and written as usual;
the summary says how many frames were lost and the exit status is then 3, so a script can tell a
complete run (0) from one with lost frames (3) and from bad input (2).
"""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``gldt run``."""
    parser = subparsers.add_parser(
        "run",
        help="detect and track drones in a video / image folder / ROS 2 bag",
        description="Run the GL-DT system (GD/LD scheduler + tracker) over a recording and write "
        "MOTChallenge tracks (frame,id,x,y,w,h,score,-1,-1,-1).",
        epilog="Exit status: 0 every frame was read; 2 bad input (nothing is processed); 3 the run "
        "finished and wrote its outputs but frames of the input could not be read (skipped or "
        "missing at the end of a video); the summary says how many.",
    )
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument(
        "--video", metavar="IN", help="video file (mp4, avi, ...) or a synthetic scene 'synth:seed=3,frames=90'"
    )
    source.add_argument(
        "--frames",
        metavar="DIR",
        help="folder of images (jpg/png/bmp, frames in name order) or a MOTChallenge sequence folder",
    )
    source.add_argument("--bag", metavar="BAG", help="ROS 2 bag (MCAP) with an image topic")
    parser.add_argument("--out", metavar="TRACKS.txt", required=True, help="MOTChallenge tracks to write")
    parser.add_argument("--render", metavar="OUT.mp4", help="also write an overlay video (boxes, ids, mode, ROIs)")
    parser.add_argument("--plot", metavar="OUT.png", help="also write a plot of the mode and track count per frame")
    parser.add_argument("--config", metavar="CFG.yaml", help="GL-DT system configuration (defaults: paper Table I)")
    parser.add_argument("--gt", metavar="GT.txt", help="ground truth for a video; prints MOTA/IDF1/HOTA at the end")
    parser.add_argument("--max-frames", type=int, metavar="N", help="stop after N frames")
    parser.add_argument(
        "--no-progress", action="store_true", help="no progress bar (none either where stderr is not a terminal)"
    )
    parser.add_argument(
        "--prefetch",
        type=int,
        default=2,
        metavar="N",
        help="read and decode up to N frames ahead in a background thread "
        "(default 2; 0: decode inline, one frame at a time)",
    )
    parser.set_defaults(func=handle_run)


def handle_run(args: argparse.Namespace) -> int:
    """Run the GL-DT system over the chosen source; returns 0 on success."""
    import logging
    import sys
    from pathlib import Path

    import numpy as np

    from gldt_core.cli import CliError
    from gldt_core.io.frame import Frame
    from gldt_core.io.mot import read_mot, write_mot
    from gldt_core.system.config import load_config
    from gldt_core.system.gldt_system import GLDTSystem
    from gldt_core.system.runner import run_frames
    from gldt_core.viz.render import OverlayVideoWriter, save_run_plot

    logging.basicConfig(level=logging.WARNING, format="gldt run: %(levelname)s: %(message)s")
    if args.max_frames is not None and args.max_frames < 1:
        raise CliError(f"--max-frames must be >= 1, got {args.max_frames}")
    if args.prefetch < 0:
        raise CliError(f"--prefetch must be >= 0, got {args.prefetch}")
    input_text = args.video or args.frames or args.bag
    input_path = Path(input_text)
    if not input_text.startswith("synth:") and not input_path.exists():
        raise FileNotFoundError(f"input not found: {input_path}")
    if args.gt is not None and not Path(args.gt).is_file():
        raise FileNotFoundError(f"ground truth not found: {args.gt}")
    from gldt_core.cli._paths import check_output_path, remove_quietly

    out_path = check_output_path(args.out, "--out")
    plot_path = check_output_path(args.plot, "--plot") if args.plot else None
    if args.render:
        check_output_path(args.render, "--render")

    config = load_config(args.config)
    system = GLDTSystem(config)  # loads the models now: a bad model file fails here

    from gldt_core.io.sources import open_source

    source = open_source(input_text, gt=args.gt)
    fps = float(getattr(source, "fps", 0.0) or 30.0)
    try:
        total = len(source)
    except TypeError:
        total = None
    if args.max_frames is not None and total is not None:
        total = min(total, args.max_frames)

    writer = OverlayVideoWriter(args.render, fps) if args.render else None
    progress = None
    if not args.no_progress and sys.stderr.isatty():  # a log file gets no carriage-return updates
        from tqdm import tqdm

        progress = tqdm(total=total, unit="frame", desc="gldt run", file=sys.stderr, leave=False)

    def on_frame(frame: Frame, tracks: np.ndarray) -> None:
        if writer is not None:
            with system.timer.stage("render"):
                plan = system.last_plan
                assert plan is not None, "on_frame runs after the frame was processed"
                writer.write(frame.image, tracks, plan.mode.value, plan.rois, int(frame.index) + 1)
        if progress is not None:
            progress.update(1)
            progress.set_postfix_str(system.state.mode.value, refresh=False)

    completed = False
    try:
        result = run_frames(
            system,
            source,
            max_frames=args.max_frames,
            on_frame=on_frame,
            collect_ground_truth=True,
            prefetch=args.prefetch,
        )
        completed = True
    finally:
        if progress is not None:
            progress.close()
        if writer is not None:
            writer.close(keep=completed)
        source.close()

    if result.frames == 0:
        raise CliError(f"{input_path}: no frames could be read")
    lost = int(getattr(source, "lost_frames", 0) or 0)
    try:
        write_mot(out_path, result.rows)  # removes its temporary file when writing fails
    except OSError as error:
        raise CliError(f"--out {args.out}: cannot write the tracks ({error.strerror or error})") from None
    plot_error = None
    if plot_path is not None:
        try:
            save_run_plot(plot_path, result.modes, result.rows, result.frames, title=input_path.name)
        except OSError as error:
            # save_run_plot writes <stem>.part<suffix> and renames it; leave no part file behind.
            remove_quietly(plot_path.with_name(plot_path.stem + ".part" + plot_path.suffix))
            plot_error = f"--plot {args.plot}: cannot write the plot ({error.strerror or error}); tracks were written"

    track_ids = len(np.unique(result.rows[:, 1])) if len(result.rows) else 0
    print(
        f"gldt run: {result.frames} frames, {result.fps:.1f} FPS, GD on {result.global_share:.0%} of frames, "
        f"{track_ids} track id{'s' if track_ids != 1 else ''} -> {args.out}"
        + (f" (re-initialised {result.reinitialisations}x)" if result.reinitialisations else "")
        + (f"; {lost} frame{'s' if lost != 1 else ''} of the input could not be read (exit status 3)" if lost else "")
    )
    print("gldt run: time per stage: " + system.timer.format(result.frames))
    if result.prefetch_ms is not None:
        print(
            "gldt run: frames were read and decoded ahead in a background thread "
            f"({result.prefetch_ms:.1f} ms/frame there); "
            "'decode' above is what the loop still waited for (--prefetch 0 decodes inline)"
        )

    ground_truth = read_mot(args.gt) if args.gt else result.ground_truth
    if ground_truth is not None and len(ground_truth):
        from gldt_core.eval.mot_metrics import evaluate_sequence

        metrics = evaluate_sequence(ground_truth, result.rows)
        print(
            f"gldt run: MOTA {100 * metrics['MOTA']:.1f}  IDF1 {100 * metrics['IDF1']:.1f}  "
            f"HOTA {100 * metrics['HOTA']:.1f}  IDSW {int(metrics['IDSW'])}"
        )
    if plot_error is not None:
        raise CliError(plot_error)
    return 3 if lost else 0
