"""``gldt bench tracking``: the paper's Table III ablation plus tracker speed, against peers.

Builds detection streams from ground truth (:mod:`gldt_core.eval.streams`: misses in bursts,
box jitter, low-score detections, clutter and detected birds) for

* synthetic 1080p scenes of :func:`gldt_core.sim.scene_ground_truth` (3 drones plus birds), or,
  when that module is missing, the plain generator ``simple_multi_target_gt`` (said in the output);
* the real drone ground truth ``V_DRONE_*.txt`` of the Halmstad clips (skipped with a reason when
  the folder is absent),

then runs, on the same streams in the same process: our ByteTrack, JPTrack (JCMA only), JPTrack
(JCMA + PMR) and, when boxmot is installed (benchmark-only dependency), boxmot's ByteTrack with
IoU association, with DIoU association, and OC-SORT. It prints IDSW, IDF1, MOTA, MOTP, HOTA (the
Table III columns) plus DetA/AssA per stream group, the issue's target ratios, and per-frame update
time (mean, p99) at 3 and at 50 targets. BLAS is limited to one thread for the whole run.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import numpy as np

DEFAULT_HALMSTAD = None  # resolved by gldt_core.paths.halmstad_root() when used


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``gldt bench tracking``."""
    parser = subparsers.add_parser(
        "tracking",
        help="JPTrack vs ByteTrack vs boxmot peers: Table III metrics and update time",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--halmstad", default=DEFAULT_HALMSTAD, help="Halmstad visible dataset folder")
    parser.add_argument("--real-clips", type=int, default=0, help="number of V_DRONE clips (0 = all)")
    parser.add_argument("--sim-scenes", type=int, default=8, help="number of synthetic scenes")
    parser.add_argument("--sim-frames", type=int, default=600, help="frames per synthetic scene")
    parser.add_argument("--speed-frames", type=int, default=300, help="frames of each speed stream")
    parser.add_argument("--seed", type=int, default=0, help="base seed of scenes and detection noise")
    parser.add_argument("--no-peers", action="store_true", help="skip the boxmot peers")
    parser.add_argument("--quick", action="store_true", help="tiny run (smoke test): 1 scene, 2 clips")
    parser.add_argument("--json", help="also write all numbers to this JSON file")
    parser.set_defaults(func=run_bench)


# --------------------------------------------------------------------------------------------
def _sim_source():
    """``(generator, description)``: the sim package's ground truth or our fallback generator."""
    import importlib

    try:
        sim = importlib.import_module("gldt_core.sim")
        generator = sim.scene_ground_truth
        return generator, "gldt_core.sim.scene_ground_truth (3 drones + birds, 1920x1080)"
    except (ImportError, AttributeError):
        from gldt_core.eval.streams import simple_multi_target_gt

        return simple_multi_target_gt, "fallback simple_multi_target_gt (gldt_core.sim not available)"


class BoxmotPeer:
    """Adapter giving a boxmot tracker our ``update(dets, t)`` interface (ids shifted to >= 1)."""

    def __init__(self, tracker: Any, image_size: tuple[int, int]) -> None:
        import numpy as np

        self._tracker = tracker
        self._image = np.zeros((image_size[1], image_size[0], 3), dtype=np.uint8)

    def update(self, dets: np.ndarray, t: float) -> np.ndarray:
        import numpy as np

        table = np.zeros((len(dets), 6), dtype=np.float32)
        table[:, :5] = dets[:, :5]
        out = np.asarray(self._tracker.update(table, self._image))
        if out.size == 0:
            return np.zeros((0, 6))
        return np.column_stack([out[:, :4], out[:, 4] + 1, out[:, 5]]).astype(np.float64)


def _peer_factories(no_peers: bool) -> tuple[dict, str]:
    if no_peers:
        return {}, "boxmot peers skipped (--no-peers)"
    try:
        import boxmot  # noqa: F401
        from boxmot import ByteTrack as BoxByteTrack
        from boxmot import OcSort as BoxOcSort
    except Exception as error:  # any import failure means: peer missing, bench goes on
        return {}, f"boxmot peers MISSING ({type(error).__name__}: {error}); install boxmot (bench-only)"
    import logging

    logging.getLogger("boxmot").setLevel(logging.WARNING)  # one INFO block per tracker otherwise
    version = getattr(boxmot, "__version__", "?")
    factories = {
        "boxmot ByteTrack (IoU)": lambda size: BoxmotPeer(BoxByteTrack(), size),
        "boxmot ByteTrack (DIoU)": lambda size: BoxmotPeer(BoxByteTrack(asso_func="diou"), size),
        "boxmot OC-SORT": lambda size: BoxmotPeer(BoxOcSort(), size),
    }
    return factories, f"boxmot {version} peers with their default parameters"


def _our_factories() -> dict:
    from gldt_core.track import ByteTrack, ByteTrackConfig, JPTrack, JPTrackConfig

    return {
        "ByteTrack (ours)": lambda size: ByteTrack(ByteTrackConfig(image_size=size)),
        "JPTrack JCMA": lambda size: JPTrack(JPTrackConfig(use_pmr=False, image_size=size)),
        "JPTrack JCMA+PMR": lambda size: JPTrack(JPTrackConfig(image_size=size)),
    }


def _load_sequences(args: argparse.Namespace) -> tuple[dict, list[str]]:
    """``{group: {name: (gt, image_size)}}`` and notes about what was used or skipped."""
    from pathlib import Path

    from gldt_core.io.mot import read_mot

    notes: list[str] = []
    groups: dict[str, dict] = {"synthetic": {}, "real": {}}
    generator, description = _sim_source()
    notes.append(f"synthetic streams: {args.sim_scenes} scenes x {args.sim_frames} frames from {description}")
    for k in range(args.sim_scenes):
        gt = generator(args.seed + 1000 + k, args.sim_frames)
        groups["synthetic"][f"sim{k:02d}"] = (gt, (1920, 1080))
    from gldt_core.paths import halmstad_root

    gt_dir = Path(args.halmstad or halmstad_root()) / "gt"
    files = sorted(gt_dir.glob("V_DRONE_*.txt")) if gt_dir.is_dir() else []
    if not files:
        notes.append(f"real streams SKIPPED: no V_DRONE_*.txt under {gt_dir}")
    else:
        if args.real_clips > 0:
            files = files[: args.real_clips]
        notes.append(f"real streams: {len(files)} Halmstad V_DRONE clips (640x512, 30 fps)")
        for path in files:
            groups["real"][path.stem] = (read_mot(path), (640, 512))
    return {g: seqs for g, seqs in groups.items() if seqs}, notes


def _run_accuracy(groups: dict, factories: dict, seed: int) -> dict:
    import numpy as np

    from gldt_core.eval import evaluate_many
    from gldt_core.eval.streams import detections_from_gt
    from gldt_core.track.runner import track_detection_rows

    streams = {}
    for g_index, seqs in enumerate(groups.values()):
        for s_index, (name, (gt, size)) in enumerate(seqs.items()):
            streams[name] = detections_from_gt(gt, seed + 7919 * g_index + s_index, size)
    results: dict = {}
    for tracker_name, make in factories.items():
        results[tracker_name] = {}
        everything = {}
        for group, seqs in groups.items():
            pairs = {}
            timings: list[float] = []
            for name, (gt, size) in seqs.items():
                pred = track_detection_rows(
                    make(size), streams[name], 30.0, num_frames=int(gt[:, 0].max()), timings=timings
                )
                pairs[name] = (gt, pred)
            metrics = evaluate_many(pairs)["combined"]
            metrics["t_mean_ms"] = 1000 * float(np.mean(timings))
            results[tracker_name][group] = metrics
            everything.update(pairs)
        if len(groups) > 1:
            results[tracker_name]["all"] = evaluate_many(everything)["combined"]
        print(f"  ran {tracker_name}", flush=True)
    return results


#: Timed runs per tracker and stream; the fastest run's mean and p99 are reported. On a shared
#: machine (other tenants) the same tracker on the same stream takes noticeably different times
#: from one run to the next, so the fastest of several is the estimate of its own cost.
SPEED_REPEATS = 5


def _run_speed(factories: dict, frames: int, seed: int) -> tuple[dict, str]:
    import numpy as np

    from gldt_core.eval.streams import StreamParams, detections_from_gt
    from gldt_core.track.runner import track_detection_rows

    generator, description = _sim_source()
    speed: dict = {}
    for targets in (3, 50):
        gt = generator(seed + 5000 + targets, frames, targets=targets)
        dets = detections_from_gt(gt, seed + targets, (1920, 1080), StreamParams())
        speed[targets] = {}
        for name, make in factories.items():
            best = None
            for _ in range(SPEED_REPEATS):
                timings: list[float] = []
                track_detection_rows(make((1920, 1080)), dets, 30.0, num_frames=frames, timings=timings)
                arr = np.asarray(timings) * 1000.0
                run = (float(arr.mean()), float(np.percentile(arr, 99)))
                best = run if best is None or run[0] < best[0] else best
            assert best is not None, "SPEED_REPEATS >= 1"
            speed[targets][name] = {"mean_ms": best[0], "p99_ms": best[1]}
    return speed, description


def _kalman_microbench() -> dict:
    """Per-frame Kalman cost (predict + update of every track) at 3 and 50 tracks: our batched
    numpy filter against a loop of filterpy filters doing the same algebra."""
    import timeit

    import numpy as np

    from gldt_core.track.kalman import ConstantVelocityKalman, predict_many, update_many

    result: dict = {}
    try:
        from filterpy.kalman import KalmanFilter
    except ImportError:
        KalmanFilter = None  # noqa: N806
    rng = np.random.default_rng(0)
    for n in (3, 50):
        boxes = np.column_stack([rng.uniform(0, 1000, (n, 2)), rng.uniform(8, 40, (n, 2))])
        ours = [ConstantVelocityKalman(b) for b in boxes]
        dts = np.full(n, 1 / 30)

        def step_ours(
            ours: list[ConstantVelocityKalman] = ours, dts: np.ndarray = dts, boxes: np.ndarray = boxes
        ) -> None:
            predict_many(ours, dts)
            update_many(ours, boxes)

        result[f"ours_{n}_us"] = timeit.timeit(step_ours, number=200) / 200 * 1e6
        if KalmanFilter is None:
            continue
        refs = []
        for f in ours:
            ref = KalmanFilter(dim_x=8, dim_z=4)
            ref.H = np.hstack([np.eye(4), np.zeros((4, 4))])
            ref.P = f.covariance.copy()
            ref.x = f.mean.copy().reshape(8, 1)
            refs.append((ref, f))

        def step_filterpy(refs: list[tuple[Any, ConstantVelocityKalman]] = refs, boxes: np.ndarray = boxes) -> None:
            for (ref, f), z in zip(refs, boxes):
                fm, q = f.transition(1 / 30)
                ref.F = fm
                ref.Q = np.diag(q)
                ref.predict()
                ref.R = f.measurement_noise()
                ref.update(z.reshape(4, 1))

        result[f"filterpy_{n}_us"] = timeit.timeit(step_filterpy, number=200) / 200 * 1e6
    return result


def _print_accuracy(results: dict) -> None:
    columns = ("IDSW", "IDF1", "MOTA", "MOTP", "HOTA", "DetA", "AssA", "FP", "FN", "Frag")
    groups = list(next(iter(results.values())).keys())
    for group in groups:
        print(f"\n[{group}]")
        head = f"{'tracker':<26}" + "".join(f"{c:>8}" for c in columns)
        print(head)
        print("-" * len(head))
        for tracker, per_group in results.items():
            m = per_group[group]
            cells = "".join(
                f"{int(m[c]):8d}" if c in ("IDSW", "FP", "FN", "Frag") else f"{100 * m[c]:8.2f}" for c in columns
            )
            print(f"{tracker:<26}{cells}")


def _print_targets(results: dict, speed: dict, peer_names: list[str]) -> list[str]:
    lines = []
    base, full = "ByteTrack (ours)", "JPTrack JCMA+PMR"
    for group in next(iter(results.values())).keys():
        b, j = results[base][group], results[full][group]
        ratio = j["IDSW"] / max(1, b["IDSW"])
        gain = 100 * (j["IDF1"] - b["IDF1"])
        lines.append(
            f"[{group}] IDSW JPTrack/ByteTrack = {j['IDSW']}/{b['IDSW']} = {ratio:.2f} "
            f"(target <= 0.50: {'OK' if ratio <= 0.5 else 'MISSED'}); "
            f"IDF1 {100 * b['IDF1']:.2f} -> {100 * j['IDF1']:.2f} = {gain:+.2f} points "
            f"(target >= +10: {'OK' if gain >= 10 else 'MISSED'})"
        )
        peers = [p for p in peer_names if p in results]
        if peers:
            best_hota = max(peers, key=lambda p: results[p][group]["HOTA"])
            best_idf1 = max(peers, key=lambda p: results[p][group]["IDF1"])
            ph, pi = results[best_hota][group]["HOTA"], results[best_idf1][group]["IDF1"]
            lines.append(
                f"[{group}] vs best peer: HOTA {100 * j['HOTA']:.2f} vs {100 * ph:.2f} ({best_hota}), "
                f"IDF1 {100 * j['IDF1']:.2f} vs {100 * pi:.2f} ({best_idf1}) "
                f"(target >=: {'OK' if j['HOTA'] >= ph and j['IDF1'] >= pi else 'MISSED'})"
            )
    for targets, per in speed.items():
        j, b = per[full], per[base]
        ratio = j["mean_ms"] / max(1e-9, b["mean_ms"])
        budget = 1.0 if targets == 3 else 10.0
        lines.append(
            f"[speed {targets} targets] JPTrack {j['mean_ms']:.3f} ms mean (budget {budget:g}: "
            f"{'OK' if j['mean_ms'] <= budget else 'MISSED'}), {ratio:.2f}x our ByteTrack "
            + ("(target <= 3x: " + ("OK" if ratio <= 3 else "MISSED") + ")" if targets == 3 else "")
        )
    return lines


def run_bench(args: argparse.Namespace) -> int:
    """Handler of ``gldt bench tracking``."""
    import json
    import os
    import platform
    import time

    from threadpoolctl import threadpool_limits

    if args.quick:
        args.sim_scenes, args.sim_frames, args.real_clips, args.speed_frames = 1, 120, 2, 60
    for option in ("sim_scenes", "real_clips"):
        if getattr(args, option) < 0:
            raise ValueError(f"--{option.replace('_', '-')} must be >= 0")
    if args.sim_frames < 2 or args.speed_frames < 2:
        raise ValueError("--sim-frames and --speed-frames must be >= 2")
    start = time.time()
    with threadpool_limits(limits=1):
        ours = _our_factories()
        peers, peer_note = _peer_factories(args.no_peers)
        factories = {**ours, **peers}
        groups, notes = _load_sequences(args)
        print("gldt bench tracking")
        print(
            f"  machine: {platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}; "
            "BLAS limited to 1 thread"
        )
        for note in notes + [peer_note]:
            print(f"  {note}")
        if not groups:
            raise ValueError("no streams to run: no synthetic scenes and no real clips")
        results = _run_accuracy(groups, factories, args.seed)
        _print_accuracy(results)
        speed, speed_source = _run_speed(factories, args.speed_frames, args.seed)
        print(
            f"\n[update time per frame, ms; streams from {speed_source}, {args.speed_frames} frames, "
            f"best of {SPEED_REPEATS}]"
        )
        head = f"{'tracker':<26}{'3 mean':>9}{'3 p99':>9}{'50 mean':>9}{'50 p99':>9}"
        print(head)
        print("-" * len(head))
        for name in factories:
            a, b = speed[3][name], speed[50][name]
            print(f"{name:<26}{a['mean_ms']:9.3f}{a['p99_ms']:9.3f}{b['mean_ms']:9.3f}{b['p99_ms']:9.3f}")
        kalman = _kalman_microbench()
        for n in (3, 50):
            line = f"Kalman predict+update of {n} tracks per frame: ours (batched) {kalman[f'ours_{n}_us']:.1f} us"
            if f"filterpy_{n}_us" in kalman:
                ratio = kalman[f"filterpy_{n}_us"] / kalman[f"ours_{n}_us"]
                line += f", filterpy loop {kalman[f'filterpy_{n}_us']:.1f} us ({ratio:.1f}x ours)"
            print(("\n" if n == 3 else "") + line)
        print("\n[targets of issue 4]")
        target_lines = _print_targets(results, speed, list(peers))
        for line in target_lines:
            print("  " + line)
    print(f"\n(total {time.time() - start:.0f} s)")
    if args.json:
        payload = {
            "notes": notes + [peer_note],
            "accuracy": results,
            "speed": {str(k): v for k, v in speed.items()},
            "kalman": kalman,
            "targets": target_lines,
        }
        tmp = args.json + ".part"
        with open(tmp, "w", encoding="utf-8") as handle:
            json.dump(payload, handle, indent=2, sort_keys=True)
        os.replace(tmp, args.json)
    return 0
