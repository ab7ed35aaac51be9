"""``gldt bench latency``: detector ONNX files timed side by side, interleaved, in one run.

Choosing between model variants (fp32 or int8, a 256 or a 224 px local input, another width)
means comparing milliseconds that differ by 10-20 %, and this shared machine drifts by more than
that between runs. So every model runs once per round, rounds repeat, and each model's median is
printed with its ratio to the first model given (the peer). A global model (two inputs: previous
and current frame) is timed on a 1080p frame pair, a local model (one batched input) on four
300 px ROIs of that frame, both including pre- and post-processing, as the pipeline calls them.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path
from typing import Any, Callable

#: The four ROIs timed for a local model (the issue's "batch of 4 ROI crops").
ROIS_1080P = ((100, 100, 400, 400), (800, 300, 1100, 600), (1400, 500, 1700, 800), (300, 700, 600, 1000))


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``gldt bench latency``."""
    parser = subparsers.add_parser(
        "latency",
        help="time detector ONNX files side by side (interleaved rounds, ratio to the first)",
        description=__doc__.split("\n\n")[1].replace("\n", " "),
    )
    parser.add_argument("models", nargs="+", type=Path, help="ONNX files exported by `gldt export` (the first is the peer)")
    parser.add_argument("--rounds", type=int, default=40, help="timed rounds; each runs every model once (default 40)")
    parser.add_argument("--threads", type=int, default=1, help="onnxruntime intra-op threads (default 1)")
    parser.set_defaults(func=_run)


def detector_call(path: Path, threads: int) -> tuple[str, Callable[[], Any]]:
    """``(kind, call)``: what the model is (``global``/``local``, told by its inputs) and one timed call."""
    import numpy as np
    import onnxruntime as ort

    from gldt_core.detect import GlobalDetector, LocalDetector
    from gldt_core.detect.runtime import DetectorConfigError

    if not path.is_file():
        raise DetectorConfigError(f"{path}: detector model not found")
    try:
        inputs = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).get_inputs()
    except Exception as error:  # onnxruntime raises several private exception types
        raise DetectorConfigError(f"{path}: cannot load ONNX model ({type(error).__name__})") from error
    rng = np.random.default_rng(0)
    frame = rng.integers(90, 170, size=(1080, 1920, 3), dtype=np.uint8)
    # Local models have one input of a fixed square size; global ones (AM-YOLO takes two frames,
    # its no-STFF ablation one) have a dynamic height and width.
    if len(inputs) == 2 or not all(isinstance(side, int) for side in inputs[0].shape[2:]):
        detector = GlobalDetector(model_path=path, num_threads=threads)
        return "global", lambda: detector.detect(frame, frame)
    local = LocalDetector(model_path=path, num_threads=threads)
    rois = np.array(ROIS_1080P)
    return "local", lambda: local.detect_rois(frame, rois)


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
    kinds, calls = zip(*(detector_call(path, args.threads) for path in args.models))
    medians = interleaved_medians(list(calls), args.rounds)
    print(f"latency, median of {args.rounds} interleaved rounds, onnxruntime threads={args.threads} "
          "(global: a 1080p frame pair; local: 4 ROIs of 300 px), ratio to the first model:")
    for path, kind, median in zip(args.models, kinds, medians):
        print(f"  {str(path):48s} {kind:6s} {median:7.1f} ms  x{median / medians[0]:.2f}")
    return 0
