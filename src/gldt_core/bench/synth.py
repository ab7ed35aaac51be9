"""``gldt bench synth``: synthetic scene generation speed on one core, against peers in the same run.

Peers measured in the same process on the same frames: (1) a naive generator with plain cv2
(copy a background, draw one Gaussian noise image with ``cv2.randn``, add it, draw the targets as
filled circles): what per-frame rendering costs without our precomputed canvas and noise window;
(2) JPEG encoding of our frames (what compressed bags and ``img1/*.jpg`` add on top).
"""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``gldt bench synth``."""
    parser = subparsers.add_parser("synth", help="synthetic scene generation speed (frames/s, one core)")
    parser.add_argument("--frames", type=int, default=90, help="frames to render (default 90)")
    parser.add_argument("--size", default="1920x1080", help="frame size (default 1920x1080)")
    parser.add_argument("--targets", type=int, default=3, help="UAVs per scene (default 3)")
    parser.add_argument("--seeds", default="0,1,2", help="comma-separated scene seeds (default 0,1,2)")
    parser.add_argument("--jpeg-quality", type=int, default=90, help="JPEG quality of the peer (default 90)")
    parser.add_argument("--threads", type=int, default=1, help="cv2 threads (default 1: one core)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Measure and print; returns 0 (the 20 frames/s target is reported, not enforced)."""
    import time

    import cv2
    import numpy as np

    from gldt_core.sim.render import SceneRenderer
    from gldt_core.sim.spec import SceneSpec, parse_size

    cv2.setNumThreads(int(args.threads))
    size = parse_size(args.size)
    seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    if args.frames < 1 or not seeds:
        raise ValueError("--frames must be >= 1 and --seeds non-empty")
    width, height = size
    total_render = total_setup = total_naive = total_jpeg = 0.0
    jpeg_bytes = 0
    frames_done = 0
    for seed in seeds:
        spec = SceneSpec(seed=seed, frames=args.frames, size=size, targets=args.targets)
        start = time.perf_counter()
        renderer = SceneRenderer(spec)
        _ = renderer.canvas
        renderer.render(0)  # warm the shared noise field
        total_setup += time.perf_counter() - start

        start = time.perf_counter()
        rendered = []
        for frame in range(args.frames):
            image, _ = renderer.render_with_truth(frame)
            if frame % 10 == 0:
                rendered.append(image)
        total_render += time.perf_counter() - start

        background = renderer.canvas[:height, :width].copy()
        gt = renderer.ground_truth()
        noise = np.empty((height, width, 3), np.int16)
        start = time.perf_counter()
        for frame in range(args.frames):
            image = background.copy()
            for row in gt[gt[:, 0] == frame + 1]:
                centre = (int(row[2] + row[4] / 2), int(row[3] + row[5] / 2))
                cv2.circle(image, centre, max(1, int(row[4] / 2)), (40, 40, 40), -1, cv2.LINE_AA)
            # OpenCV takes scalar mean and deviation for every channel; its stubs list arrays only.
            cv2.randn(noise, 0, 4)  # type: ignore[call-overload]
            image = cv2.add(image, noise, dtype=cv2.CV_8U)
        total_naive += time.perf_counter() - start

        start = time.perf_counter()
        for image in rendered:
            ok, encoded = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, args.jpeg_quality])
            jpeg_bytes += len(encoded)
        total_jpeg += (time.perf_counter() - start) * args.frames / max(len(rendered), 1)
        frames_done += args.frames

    render_fps = frames_done / total_render
    naive_fps = frames_done / total_naive
    jpeg_fps = frames_done / total_jpeg
    print(
        f"gldt bench synth: {len(seeds)} scenes x {args.frames} frames, {width}x{height}, "
        f"{args.targets} targets, cv2 threads={args.threads}"
    )
    print(f"  scene setup (geometry + canvas): {1000 * total_setup / len(seeds):8.1f} ms/scene")
    print(f"  render (no JPEG):                {render_fps:8.1f} frames/s  ({1000 / render_fps:.1f} ms/frame)")
    print(
        f"  peer naive cv2 generator:        {naive_fps:8.1f} frames/s  -> render/naive = {render_fps / naive_fps:.2f}x"
    )
    sampled = len(seeds) * -(-args.frames // 10)
    print(
        f"  peer JPEG encode q{args.jpeg_quality}:           {jpeg_fps:8.1f} frames/s  -> render/jpeg = "
        f"{render_fps / jpeg_fps:.2f}x (avg {jpeg_bytes / sampled / 1024:.0f} KiB/frame)"
    )
    with_setup = frames_done / (total_render + total_setup)
    print(f"  render incl. scene setup:        {with_setup:8.1f} frames/s")
    verdict = "PASS" if render_fps >= 20.0 else "FAIL"
    print(f"  target >= 20 frames/s at this size: {verdict}")
    return 0
