"""``gldt bench latency``: detector ONNX files timed side by side, interleaved, in one run.

Choosing between model variants (fp32 or int8, a 256 or a 224 px local input, another width)
means comparing milliseconds that differ little, and a shared machine drifts by more than that
between runs. So every model runs once per round, rounds repeat, and each model's median is
printed with its ratio to the first model given (the peer). A global model (two inputs: previous
and current frame) is timed on a GD stretch of 1080p frames (each frame paired with the one
before, as the GL-DT system runs it), a local model (one batched input) on four 300 px ROIs of a
frame, both including pre- and post-processing, as the system calls them.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

#: The four ROIs timed for a local model (the issue's "batch of 4 ROI crops").
ROIS_1080P = ((100, 100, 400, 400), (800, 300, 1100, 600), (1400, 500, 1700, 800), (300, 700, 600, 1000))


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``gldt bench latency``."""
    parser = subparsers.add_parser(
        "latency",
        help="time detector ONNX files side by side (interleaved rounds, ratio to the first)",
        description=__doc__.split("\n\n")[1].replace("\n", " "),
    )
    parser.add_argument(
        "models", nargs="+", type=Path, help="ONNX files exported by `gldt export` (the first is the peer)"
    )
    parser.add_argument("--rounds", type=int, default=40, help="timed rounds; each runs every model once (default 40)")
    parser.add_argument("--threads", type=int, default=1, help="onnxruntime intra-op threads (default 1)")
    parser.set_defaults(func=_run)


def gd_stretch_call(detector: Any, frames: list[Any]) -> Callable[[], Any]:
    """One call = the next frame of a GD stretch over ``frames`` (each with the one before it),
    handing each frame's carry (letterboxed input, reusable features) to the next as the GL-DT
    system does."""
    state: dict[str, Any] = {"index": 0, "carry": None}

    def call() -> Any:
        index = state["index"] = state["index"] + 1
        previous, current = frames[(index - 1) % len(frames)], frames[index % len(frames)]
        detections, state["carry"] = detector.detect_pair(previous, current, state["carry"])
        return detections

    return call


def detector_calls(path: Path, threads: int) -> list[tuple[str, str, Callable[[], Any]]]:
    """``(label, kind, call)`` rows for one model: what it is (``global``/``local``, told by its
    card or else its inputs) and one timed call. An AM-YOLO with a split pair (``gldt export --feature-reuse``)
    gets a second row without it, so the reuse shows as a ratio measured in the same rounds."""
    import numpy as np

    from gldt_core.detect import GlobalDetector, LocalDetector
    from gldt_core.detect.session import open_session

    session, card = open_session(path, ("CPUExecutionProvider",), None, optimize_graph=False)
    inputs = session.get_inputs()
    rng = np.random.default_rng(0)
    frames = [rng.integers(90, 170, size=(1080, 1920, 3), dtype=np.uint8) for _ in range(2)]
    # The card says which it is; without one, a local model has one input of a fixed square size
    # and a global one (AM-YOLO takes two frames, its no-STFF ablation one) a dynamic height and width.
    if "task" in card:
        is_global = card["task"] != "local"
    else:
        is_global = len(inputs) == 2 or not all(isinstance(side, int) for side in inputs[0].shape[2:])
    if is_global:
        detector = GlobalDetector(model_path=path, num_threads=threads)
        rows = [(str(path), "global", gd_stretch_call(detector, frames))]
        if detector.feature_reuse is not None:
            full = GlobalDetector(model_path=path, num_threads=threads, feature_reuse=False)
            rows.append((f"{path} (no feature reuse)", "global", gd_stretch_call(full, frames)))
        return rows
    local = LocalDetector(model_path=path, num_threads=threads)
    rois = np.array(ROIS_1080P)
    return [(str(path), "local", lambda: local.detect_rois(frames[0], rois))]


def interleaved_medians(calls: list[Callable[[], Any]], rounds: int, warmup: int = 3) -> list[float]:
    """Median milliseconds of each call, timed round-robin so drift hits every call alike."""
    times: list[list[float]] = [[] for _ in calls]
    for round_index in range(warmup + rounds):
        for call, samples in zip(calls, times):
            started = time.perf_counter()
            call()
            if round_index >= warmup:
                samples.append((time.perf_counter() - started) * 1e3)
    return [statistics.median(samples) for samples in times]


def _run(args: argparse.Namespace) -> int:
    if args.rounds < 1 or args.threads < 1:
        raise ValueError(f"--rounds and --threads must be >= 1, got {args.rounds} and {args.threads}")
    models = []
    for path in args.models:  # e.g. a shell glob over models/ also lists the split pairs' parts
        if path.name.endswith((".features.onnx", ".reuse.onnx")):
            print(
                f"skipping {path}: a part of a split AM-YOLO (gldt export --feature-reuse), "
                "timed with the model it was split from"
            )
        else:
            models.append(path)
    if not models:
        raise ValueError("no detector model to time among the files given")
    rows = [row for path in models for row in detector_calls(path, args.threads)]
    labels, kinds, calls = zip(*rows)
    medians = interleaved_medians(list(calls), args.rounds)
    print(
        f"latency, median of {args.rounds} interleaved rounds, onnxruntime threads={args.threads} "
        "(global: a frame of a GD stretch of 1080p frames; local: 4 ROIs of 300 px), ratio to the first row:"
    )
    for label, kind, median in zip(labels, kinds, medians):
        print(f"  {label:66s} {kind:6s} {median:7.1f} ms  x{median / medians[0]:.2f}")
    return 0
