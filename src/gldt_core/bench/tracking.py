"""``gldt bench tracking``: JPTrack against our ByteTrack and boxmot's trackers, on stream profiles
that one noise model cannot overfit, plus tracker speed.

Every tracker sees the same detection streams, from several independent **profiles**
(:data:`gldt_core.eval.streams.PROFILES`; ``--profiles a,b`` picks some):

* ``ours`` (TUNING): our own stream model (:class:`gldt_core.eval.streams.StreamParams` defaults:
  burst misses, two score bands, jitter, i.i.d. clutter, detected birds) on the synthetic
  scenes of :func:`gldt_core.sim.scene_ground_truth` (3 drones + birds, 1080p, 30 Hz);
* ``crossing`` (TUNING): 2-5 targets that cross and occlude each other
  (:func:`gldt_core.eval.streams.crossing_multi_target_gt`), our model with more low scores;
* ``occlusion-15hz`` (HELD OUT): 15 Hz, 720p, 1-4 s occlusion bursts, Beta(2,3) scores, strong
  jitter and clutter;
* ``drifting-clutter-60hz`` (HELD OUT): 60 Hz, false objects that persist 2-10 s and move like
  targets, Beta(5,2) scores;
* ``ego-motion-25hz`` (HELD OUT): 25 Hz, a camera pan/roll random walk applied to every box (gt
  and detections alike), near-uniform Beta(1.2,1.2) scores, drifting clutter;
* ``real-detector-val`` (TUNING) and ``real-detector-val_b`` (HELD OUT): what the shipped global
  detector (AM-YOLO with its second stage) reports on every frame at score >= 0.05 on the V_DRONE
  clips of the Halmstad validation split ``val``, and of the disjoint split ``val_b``
  (:mod:`gldt_core.eval.detector_streams`; cached on disk per model, ``--detector-clips`` (per
  split) and ``--detector-frames`` bound the work; skipped with a reason when the clips are absent).

TUNING profiles are where tracker defaults may be tuned; HELD OUT ones never are. Trackers get
``t = (frame - 1) / fps`` at each profile's own frame rate. In the same process and on the same
streams run our ByteTrack (the original paper's thresholds, and boxmot's defaults for the
faithfulness line), JPTrack (JCMA only), JPTrack (JCMA + PMR) and, when boxmot is installed
(benchmark-only dependency, ``make bench-peers``), boxmot's ByteTrack with IoU and with DIoU
association, OC-SORT and BoT-SORT without re-identification (no appearance model, no weights; its
camera-motion compensation is off too, as it needs images). Peers keep their defaults except that
their frame-counted lifetimes follow the stream's frame rate.

The report gives, per profile, HOTA, IDF1, MOTA, IDSW, DetA, AssA, FP, FN (and MOTP, Frag); per
tracker its WORST profile (the headline, not a mean); the issue's targets per profile (JPTrack
JCMA+PMR above ByteTrack+DIoU in HOTA and IDF1 with no more IDSW; against our ByteTrack IDSW
<= 0.5x and IDF1 >= +10 points), each OK or MISSED; the identity switches of JPTrack JCMA+PMR
and ByteTrack+DIoU by event (:mod:`gldt_core.eval.id_events`), JPTrack's recoveries onto another
target by what brought the lost track back (first stage, PMR, relink); and the per-frame
update time (mean, p99) at 3 and 50 targets on one core. BLAS is limited to one thread for the
whole run. ``--quick`` is a smoke run (1 short sequence per profile, 1 real clip of 60 frames).
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from collections.abc import Sequence

    import numpy as np

    from gldt_core.eval.id_events import IdSwitchEvent
    from gldt_core.eval.streams import StreamSequence

DEFAULT_HALMSTAD = None  # resolved by gldt_core.paths.halmstad_root() when used
#: The profile of real detector output (held out), beside the synthetic ones.
#: The real detector's streams, one profile per Halmstad validation split: defaults may be tuned
#: on ``val``'s clips; ``val_b``'s are held out.
REAL_PROFILES = {"real-detector-val": "val", "real-detector-val_b": "val_b"}
OURS_BYTETRACK, JPTRACK_FULL, DIOU_PEER = "ByteTrack (ours)", "JPTrack JCMA+PMR", "boxmot ByteTrack (DIoU)"
#: The metrics kept for each sequence (the JSON's ``accuracy_per_sequence``; fractions, IDSW a count).
SEQUENCE_METRICS = ("HOTA", "IDF1", "MOTA", "IDSW")
#: Our ByteTrack at boxmot's defaults, and boxmot's ByteTrack (IoU): the faithfulness check.
OURS_AT_BOXMOT, IOU_PEER = "ByteTrack (ours, boxmot's)", "boxmot ByteTrack (IoU)"
#: Trackers whose identity switches are broken down by event.
EVENT_TRACKERS = (JPTRACK_FULL, DIOU_PEER)
#: A recovery onto another target whose new id has no recorded re-attachment before it.
UNATTRIBUTED = "unattributed"


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``gldt bench tracking``."""
    parser = subparsers.add_parser(
        "tracking",
        help="JPTrack vs ByteTrack vs boxmot peers on tuning and held-out stream profiles: metrics and update time",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--profiles", help="comma-separated profiles to run (default: all)")
    parser.add_argument("--sequences", type=int, default=6, help="sequences per synthetic profile (default 6)")
    parser.add_argument("--seconds", type=float, default=20.0, help="duration of each synthetic sequence (default 20)")
    parser.add_argument("--halmstad", default=DEFAULT_HALMSTAD, help="Halmstad visible dataset folder")
    parser.add_argument(
        "--detector-clips",
        type=int,
        default=0,
        help="Halmstad validation drone clips per real-detector profile (0 = all)",
    )
    parser.add_argument(
        "--detector-frames", type=int, default=None, help="frames per real-detector clip (default: whole clips)"
    )
    parser.add_argument("--speed-frames", type=int, default=300, help="frames of each speed stream")
    parser.add_argument("--seed", type=int, default=0, help="base seed of the synthetic streams")
    parser.add_argument("--no-peers", action="store_true", help="skip the boxmot peers")
    parser.add_argument(
        "--quick", action="store_true", help="smoke run: 1 sequence of 4 s per profile, 1 real clip of 60 frames"
    )
    parser.add_argument("--json", help="also write all numbers to this JSON file")
    parser.set_defaults(func=run_bench)


def _profile_names() -> list[str]:
    from gldt_core.eval.streams import PROFILES

    return [p.name for p in PROFILES] + list(REAL_PROFILES)


def select_profiles(option: str | None) -> list[str]:
    """The profiles named by ``--profiles`` (all when None), in the benchmark's order."""
    known = _profile_names()
    if option is None:
        return known
    asked = [name.strip() for name in option.split(",") if name.strip()]
    unknown = [name for name in asked if name not in known]
    if unknown or not asked:
        raise ValueError(f"--profiles: unknown {', '.join(unknown) or '(none given)'} (known: {', '.join(known)})")
    return [name for name in known if name in asked]


# --------------------------------------------------------------------------------------------
def _sim_source():
    """``(generator, description)``: the sim package's ground truth or our fallback generator."""
    import importlib

    try:
        sim = importlib.import_module("gldt_core.sim")
        generator = sim.scene_ground_truth
        return generator, "gldt_core.sim.scene_ground_truth (1920x1080)"
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


def _frames(fps: float, at_30: int) -> int:
    """A frame count that lasts as long at ``fps`` as ``at_30`` frames do at 30 Hz."""
    return max(1, round(at_30 * fps / 30.0))


def _peer_factories(no_peers: bool) -> tuple[dict, str]:
    """``{name: make(size, fps)}`` of the boxmot peers and a note on what runs."""
    if no_peers:
        return {}, "boxmot peers skipped (--no-peers)"
    try:
        import boxmot  # noqa: F401
        from boxmot import BotSort as BoxBotSort
        from boxmot import ByteTrack as BoxByteTrack
        from boxmot import OcSort as BoxOcSort
    except Exception as error:  # any import failure means: peer missing, bench goes on
        return {}, f"boxmot peers MISSING ({type(error).__name__}: {error}); install boxmot (bench-only)"
    import logging

    logging.getLogger("boxmot").setLevel(logging.WARNING)  # one INFO block per tracker otherwise
    version = getattr(boxmot, "__version__", "?")

    def botsort(size: tuple[int, int], fps: float) -> BoxmotPeer:
        # No appearance model (use_embeddings=False: no ReID weights loaded or downloaded) and no
        # camera-motion compensation (use_cmc=False: it registers images, a stream has none).
        return BoxmotPeer(BoxBotSort(use_embeddings=False, use_cmc=False, frame_rate=round(fps)), size)

    factories = {
        IOU_PEER: lambda size, fps: BoxmotPeer(BoxByteTrack(frame_rate=round(fps)), size),
        DIOU_PEER: lambda size, fps: BoxmotPeer(BoxByteTrack(asso_func="diou", frame_rate=round(fps)), size),
        "boxmot OC-SORT": lambda size, fps: BoxmotPeer(BoxOcSort(max_age=_frames(fps, 30)), size),
        "boxmot BoT-SORT (no ReID)": botsort,
    }
    return factories, (
        f"boxmot {version} peers with their default parameters (lifetimes in frames follow the stream's rate); "
        "BoT-SORT without ReID (use_embeddings=False, no weights) and without camera-motion compensation "
        "(use_cmc=False: it needs images)"
    )


def _our_factories() -> dict:
    from gldt_core.track import ByteTrack, ByteTrackConfig, JPTrack, JPTrackConfig

    return {
        OURS_BYTETRACK: lambda size, fps: ByteTrack(ByteTrackConfig(image_size=size, frame_rate=round(fps))),
        OURS_AT_BOXMOT: lambda size, fps: ByteTrack(ByteTrackConfig.boxmot(image_size=size, frame_rate=round(fps))),
        "JPTrack JCMA": lambda size, fps: JPTrack(JPTrackConfig(use_pmr=False, image_size=size)),
        JPTRACK_FULL: lambda size, fps: JPTrack(JPTrackConfig(image_size=size)),
    }


class ProfileRun:
    """One profile's sequences and what the report says about it."""

    def __init__(self, name: str, role: str, description: str, parameters: dict, sequences: list) -> None:
        self.name = name
        self.role = role
        self.description = description
        self.parameters = parameters
        self.sequences: list[StreamSequence] = sequences

    def summary(self) -> str:
        import numpy as np

        seqs = self.sequences
        frames = sum(s.frames for s in seqs)
        rates = sorted({f"{s.fps:g}" for s in seqs})
        targets = [len(np.unique(s.gt[s.gt[:, 7] == 1, 1])) for s in seqs]
        span = (
            f"{min(targets)}-{max(targets)}"
            if targets and min(targets) != max(targets)
            else str(max(targets, default=0))
        )
        role = "TUNING" if self.role == "tuning" else "HELD OUT"
        return (
            f"{self.name} [{role}]: {self.description}; {len(seqs)} sequence(s), {frames} frames at "
            f"{'/'.join(rates)} Hz, targets per sequence: {span}"
        )


def build_profiles(args: argparse.Namespace, names: list[str]) -> tuple[dict[str, ProfileRun], list[str]]:
    """The selected profiles' sequences (``{name: ProfileRun}``) and notes on what was skipped."""
    import dataclasses

    from gldt_core.eval.streams import profile_by_name, profile_sequences

    runs: dict[str, ProfileRun] = {}
    notes: list[str] = []
    for name in names:
        if name in REAL_PROFILES:
            run, note = _real_profile(args, name)
            notes.append(note)
            if run is not None:
                runs[name] = run
            continue
        profile = profile_by_name(name)
        sequences = profile_sequences(profile, args.seed, args.sequences, args.seconds)
        parameters = dataclasses.asdict(profile)
        if profile.generator == "scene":
            parameters["generator"] = _sim_source()[1]
        runs[name] = ProfileRun(name, profile.role, profile.description, parameters, sequences)
    return runs, notes


def _real_profile(args: argparse.Namespace, name: str) -> tuple[ProfileRun | None, str]:
    """The real detector's streams on the V_DRONE clips of one validation split
    (:data:`REAL_PROFILES`): ``val`` for tuning, ``val_b`` held out."""
    from pathlib import Path

    from gldt_core.eval.detector_streams import (
        DEFAULT_SCORE_THRESHOLD,
        halmstad_detector_sequences,
        halmstad_drone_clips,
        shipped_detector_cache,
    )
    from gldt_core.eval.streams import HELD_OUT, TUNING
    from gldt_core.paths import halmstad_root

    root = Path(args.halmstad or halmstad_root())
    if not (root / "videos").is_dir() or not (root / "gt").is_dir():
        return None, f"{name}: SKIPPED, no Halmstad videos/ and gt/ under {root}"
    cache = shipped_detector_cache(score_threshold=DEFAULT_SCORE_THRESHOLD)
    split = REAL_PROFILES[name]
    clips = halmstad_drone_clips(root, args.detector_clips, split)
    if not clips:
        return None, f"{name}: SKIPPED, no V_DRONE validation clips under {root}"
    sequences = halmstad_detector_sequences(
        root,
        cache,
        args.detector_clips,
        args.detector_frames,
        log=lambda line: print(f"  {line}", flush=True),
        split=split,
    )
    parameters = {
        "detector": cache.description,
        "cache": str(cache.directory),
        "clips": [f"{clip_split}/{clip}" for clip_split, clip in clips],
        "frames_per_clip": args.detector_frames,
        "score_threshold": DEFAULT_SCORE_THRESHOLD,
    }
    description = (
        f"{cache.description} on every frame of the Halmstad V_DRONE clips of validation split {split} (640x512)"
    )
    note = f"{name}: {len(sequences)} clips, detector streams cached in {cache.directory}"
    role = TUNING if split == "val" else HELD_OUT
    return ProfileRun(name, role, description, parameters, sequences), note


def _track(
    make: Any,
    sequence: StreamSequence,
    timings: list[float] | None = None,
    reattachments: list[tuple[float, int, str]] | None = None,
) -> np.ndarray:
    """One tracker over one sequence, at the sequence's own frame rate; given ``reattachments``,
    the tracker (one of ours) records in it how its lost tracks come back
    (``MultiStageTracker.reattachments``)."""
    from gldt_core.track.runner import track_detection_rows

    tracker = make(sequence.size, sequence.fps)
    if reattachments is not None:
        tracker.reattachments = reattachments
    return track_detection_rows(tracker, sequence.dets, sequence.fps, num_frames=sequence.frames, timings=timings)


def recoveries_by_mechanism(
    events: Sequence[IdSwitchEvent], reattachments: Sequence[tuple[float, int, str]], fps: float
) -> dict[str, int]:
    """The identity switches of category "recovery onto another target" (a lost track re-attached
    to another object) counted by what brought the track back: the latest entry of the tracker's
    ``reattachments`` for the new id at or before the switch's frame (``t = (frame - 1) / fps``),
    one of :data:`gldt_core.track.base.REATTACHMENTS`, or "unattributed" when there is none."""
    from gldt_core.eval.id_events import RECOVERY_OTHER
    from gldt_core.track.base import REATTACHMENTS

    counts = dict.fromkeys((*REATTACHMENTS, UNATTRIBUTED), 0)
    by_id: dict[int, list[tuple[float, str]]] = {}
    for t, track_id, how in reattachments:
        by_id.setdefault(int(track_id), []).append((t, how))
    for event in events:
        if event.category != RECOVERY_OTHER:
            continue
        t_switch = (event.frame - 1) / fps + 1e-9
        before = [how for t, how in by_id.get(int(event.new_id), []) if t <= t_switch]
        counts[before[-1] if before else UNATTRIBUTED] += 1
    return counts


def _run_accuracy(runs: dict[str, ProfileRun], factories: dict) -> tuple[dict, dict, dict]:
    """``results[profile][tracker]`` metrics, ``per_sequence[profile][tracker][sequence]`` the
    :data:`SEQUENCE_METRICS` of each sequence, and ``kept[profile][tracker]`` = [(gt, pred, dets,
    fps, reattachments)] of :data:`EVENT_TRACKERS` (``reattachments``: JPTrack's record of how its
    lost tracks came back; None for the others)."""
    import numpy as np

    from gldt_core.eval import evaluate_many

    results: dict = {}
    per_sequence: dict = {}
    kept: dict = {}
    for profile, run in runs.items():
        results[profile], per_sequence[profile], kept[profile] = {}, {}, {}
        for tracker_name, make in factories.items():
            timings: list[float] = []
            pairs = {}
            for sequence in run.sequences:
                log: list[tuple[float, int, str]] | None = [] if tracker_name == JPTRACK_FULL else None
                pred = _track(make, sequence, timings, log)
                pairs[sequence.name] = (sequence.gt, pred)
                if tracker_name in EVENT_TRACKERS:
                    kept[profile].setdefault(tracker_name, []).append(
                        (sequence.gt, pred, sequence.dets, sequence.fps, log)
                    )
            evaluated = evaluate_many(pairs)
            metrics = evaluated["combined"]
            metrics["t_mean_ms"] = 1000 * float(np.mean(timings)) if timings else 0.0
            results[profile][tracker_name] = metrics
            per_sequence[profile][tracker_name] = {
                name: {key: m[key] for key in SEQUENCE_METRICS} for name, m in evaluated["per_sequence"].items()
            }
        print(f"  ran {profile}", flush=True)
    return results, per_sequence, kept


def sequence_margins(per_sequence: dict, ours: str, peer: str) -> dict:
    """Per profile, ``ours`` against ``peer`` sequence by sequence: on how many sequences it is
    behind on HOTA and on IDF1, and its worst margin of each with the sequence it comes from. A
    total over a profile's sequences can hide the ones a tracker loses. Profiles where either
    tracker did not run are left out."""
    from gldt_core.eval.margins import margins_by_sequence

    out: dict = {}
    for profile, trackers in per_sequence.items():
        if ours not in trackers or peer not in trackers:
            continue
        hota = margins_by_sequence(trackers[ours], trackers[peer], "HOTA")
        if hota is None:  # no sequence in common
            continue
        entry: dict = {"sequences": len(hota.margins)}
        for margins in (hota, margins_by_sequence(trackers[ours], trackers[peer], "IDF1")):
            assert margins is not None  # the same sequences as HOTA's
            worst, margin = margins.worst
            entry[f"behind_{margins.metric}"] = margins.behind
            entry[f"worst_{margins.metric}"] = {"sequence": worst, "margin": margin}
        out[profile] = entry
    return out


def _print_sequence_margins(margins: dict, ours: str, peer: str) -> None:
    if not margins:
        return
    print(f"\n[{ours} against {peer}, sequence by sequence: where it is behind, and its worst margin]")
    head = (
        f"{'profile':<23}{'seqs':>5}{'HOTA behind':>13}{'worst':>8}  {'sequence':<26}"
        f"{'IDF1 behind':>12}{'worst':>8}  sequence"
    )
    print(head)
    print("-" * len(head))
    for profile, e in margins.items():
        hota, idf1 = e["worst_HOTA"], e["worst_IDF1"]
        print(
            f"{profile:<23}{e['sequences']:>5}{e['behind_HOTA']:>13}{100 * hota['margin']:>+8.2f}  "
            f"{hota['sequence']:<26}{e['behind_IDF1']:>12}{100 * idf1['margin']:>+8.2f}  {idf1['sequence']}"
        )


def _id_switch_breakdown(kept: dict) -> tuple[dict, dict]:
    """Per profile and tracker of :data:`EVENT_TRACKERS`, summed over the sequences: the identity
    switches by event category (:func:`gldt_core.eval.id_events.classify_id_switches`) and, for
    a tracker that records how its lost tracks come back, its recoveries onto another target by
    mechanism (:func:`recoveries_by_mechanism`)."""
    from gldt_core.eval.id_events import CATEGORIES, classify_id_switches

    events: dict = {}
    mechanisms: dict = {}
    for profile, per_tracker in kept.items():
        events[profile], mechanisms[profile] = {}, {}
        for tracker, runs in per_tracker.items():
            total = dict.fromkeys(CATEGORIES, 0)
            by_mechanism: dict[str, int] = {}
            for gt, pred, dets, fps, reattachments in runs:
                report = classify_id_switches(gt, pred, dets, fps)
                for category, count in report.counts.items():
                    total[category] += count
                if reattachments is not None:
                    for how, count in recoveries_by_mechanism(report.events, reattachments, fps).items():
                        by_mechanism[how] = by_mechanism.get(how, 0) + count
            events[profile][tracker] = total
            if by_mechanism:  # a tracker that records them
                mechanisms[profile][tracker] = by_mechanism
    return events, mechanisms


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
                track_detection_rows(make((1920, 1080), 30.0), dets, 30.0, num_frames=frames, timings=timings)
                arr = np.asarray(timings) * 1000.0
                run = (float(arr.mean()), float(np.percentile(arr, 99)))
                best = run if best is None or run[0] < best[0] else best
            assert best is not None, "SPEED_REPEATS >= 1"
            speed[targets][name] = {"mean_ms": best[0], "p99_ms": best[1]}
    return speed, description


def _print_accuracy(results: dict, runs: dict[str, ProfileRun]) -> None:
    columns = ("HOTA", "IDF1", "MOTA", "IDSW", "DetA", "AssA", "FP", "FN", "MOTP", "Frag")
    counts = ("IDSW", "FP", "FN", "Frag")
    for profile, per_tracker in results.items():
        print(f"\n[{runs[profile].summary()}]")
        head = f"{'tracker':<28}" + "".join(f"{c:>8}" for c in columns)
        print(head)
        print("-" * len(head))
        for tracker, m in per_tracker.items():
            cells = "".join(f"{int(m[c]):8d}" if c in counts else f"{100 * m[c]:8.2f}" for c in columns)
            print(f"{tracker:<28}{cells}")


def worst_profiles(results: dict, roles: dict[str, str]) -> dict:
    """Per tracker: its lowest HOTA and IDF1 over all profiles and over the held-out ones, with
    the profile each comes from (the headline of the benchmark)."""
    worst: dict = {}
    trackers = next(iter(results.values())).keys() if results else []
    for tracker in trackers:
        entry: dict = {}
        for scope, names in (("all", list(results)), ("held_out", [p for p in results if roles[p] != "tuning"])):
            for metric in ("HOTA", "IDF1"):
                if not names:
                    continue
                profile = min(names, key=lambda p: results[p][tracker][metric])
                entry[f"{scope}_{metric}"] = {"profile": profile, "value": results[profile][tracker][metric]}
        worst[tracker] = entry
    return worst


def _print_worst(worst: dict) -> None:
    print("\n[worst profile per tracker: the headline (every profile counts; not a mean)]")
    head = f"{'tracker':<28}{'HOTA':>8}  {'profile':<24}{'IDF1':>8}  {'profile':<24}{'held-out HOTA':>14}"
    print(head)
    print("-" * len(head))
    for tracker, entry in worst.items():
        hota, idf1 = entry["all_HOTA"], entry["all_IDF1"]
        held = entry.get("held_out_HOTA")
        held_cell = f"{100 * held['value']:14.2f}" if held else f"{'-':>14}"
        print(
            f"{tracker:<28}{100 * hota['value']:8.2f}  {hota['profile']:<24}"
            f"{100 * idf1['value']:8.2f}  {idf1['profile']:<24}{held_cell}"
        )


def _ok(flag: bool) -> str:
    return "OK" if flag else "MISSED"


def target_lines(results: dict, worst: dict, speed: dict) -> list[str]:
    """The issue's targets, per profile and on the worst profile, then the speed targets."""
    lines = []
    for profile, per in results.items():
        j = per[JPTRACK_FULL]
        if DIOU_PEER in per:
            d = per[DIOU_PEER]
            lines.append(
                f"[{profile}] vs ByteTrack+DIoU: HOTA {100 * j['HOTA']:.2f} vs {100 * d['HOTA']:.2f} "
                f"({_ok(j['HOTA'] > d['HOTA'])}), IDF1 {100 * j['IDF1']:.2f} vs {100 * d['IDF1']:.2f} "
                f"({_ok(j['IDF1'] > d['IDF1'])}), IDSW {int(j['IDSW'])} vs {int(d['IDSW'])} "
                f"({_ok(j['IDSW'] <= d['IDSW'])})"
            )
        else:
            lines.append(f"[{profile}] vs ByteTrack+DIoU: not run (boxmot peers missing or skipped)")
        b = per[OURS_BYTETRACK]
        ratio = j["IDSW"] / max(1, b["IDSW"])
        gain = 100 * (j["IDF1"] - b["IDF1"])
        # A tracker that keeps few tracks has few switches to make: the same count per 1000
        # matched boxes reads the two at equal coverage (context only; the target is the count).
        per_matched = (
            f"; per 1000 matched boxes {1000 * j['IDSW'] / max(1, j['TP']):.1f} vs "
            f"{1000 * b['IDSW'] / max(1, b['TP']):.1f}"
            if "TP" in j and "TP" in b
            else ""
        )
        lines.append(
            f"[{profile}] vs our ByteTrack: IDSW {int(j['IDSW'])}/{int(b['IDSW'])} = {ratio:.2f} "
            f"(<= 0.50: {_ok(ratio <= 0.5)}{per_matched}), IDF1 {100 * b['IDF1']:.2f} -> {100 * j['IDF1']:.2f} = "
            f"{gain:+.2f} points (>= +10: {_ok(gain >= 10)})"
        )
        if IOU_PEER in per and OURS_AT_BOXMOT in per:
            mine, ref = per[OURS_AT_BOXMOT], per[IOU_PEER]
            tolerance = max(1.0, 0.05 * ref["IDSW"])
            faithful = abs(mine["IDSW"] - ref["IDSW"]) <= tolerance and abs(mine["MOTA"] - ref["MOTA"]) <= 0.005
            lines.append(
                f"[{profile}] our ByteTrack at boxmot's defaults vs boxmot ByteTrack: IDSW {int(mine['IDSW'])} vs "
                f"{int(ref['IDSW'])}, MOTA {100 * mine['MOTA']:.2f} vs {100 * ref['MOTA']:.2f} "
                f"(within 5 % and 0.5: {_ok(faithful)})"
            )
    if DIOU_PEER in worst:
        for metric in ("HOTA", "IDF1"):
            mine, peer = worst[JPTRACK_FULL][f"all_{metric}"], worst[DIOU_PEER][f"all_{metric}"]
            lines.append(
                f"[worst profile] {metric}: JPTrack {100 * mine['value']:.2f} ({mine['profile']}) vs "
                f"ByteTrack+DIoU {100 * peer['value']:.2f} ({peer['profile']}) ({_ok(mine['value'] > peer['value'])})"
            )
    for targets, per in speed.items():
        j, b = per[JPTRACK_FULL], per[OURS_BYTETRACK]
        ratio = j["mean_ms"] / max(1e-9, b["mean_ms"])
        budget = 1.0 if targets == 3 else 10.0
        lines.append(
            f"[speed {targets} targets] JPTrack {j['mean_ms']:.3f} ms mean (budget {budget:g}: "
            f"{_ok(j['mean_ms'] <= budget)}), {ratio:.2f}x our ByteTrack"
            + (f" (target <= 3x: {_ok(ratio <= 3)})" if targets == 3 else "")
        )
    return lines


def _print_events(events: dict, mechanisms: dict) -> None:
    from gldt_core.eval.id_events import CATEGORIES, RECOVERY_OTHER

    print("\n[identity switches by event (gldt_core.eval.id_events), per profile; total = IDSW]")
    head = f"{'profile':<23}{'tracker':<25}{'total':>6}" + "".join(f"{c[:12]:>13}" for c in CATEGORIES)
    print(head)
    print("-" * len(head))
    for profile, per in events.items():
        for tracker, counts in per.items():
            cells = "".join(f"{counts.get(c, 0):13d}" for c in CATEGORIES)
            print(f"{profile:<23}{tracker:<25}{sum(counts.values()):6d}{cells}")
    print("(" + "; ".join(f"{c[:12]} = {c}" for c in CATEGORIES if len(c) > 12) + ")")
    rows = [(profile, tracker, counts) for profile, per in mechanisms.items() for tracker, counts in per.items()]
    if not rows:
        return
    columns = list(rows[0][2])
    print(f"\n[{RECOVERY_OTHER}, by what brought the lost track back]")
    head = f"{'profile':<23}{'tracker':<25}" + "".join(f"{c:>14}" for c in columns)
    print(head)
    print("-" * len(head))
    for profile, tracker, counts in rows:
        print(f"{profile:<23}{tracker:<25}" + "".join(f"{counts.get(c, 0):14d}" for c in columns))


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


def run_bench(args: argparse.Namespace) -> int:
    """Handler of ``gldt bench tracking``."""
    import json
    import os
    import platform
    import time

    from threadpoolctl import threadpool_limits

    if args.quick:
        args.sequences, args.seconds, args.detector_clips, args.speed_frames = 1, 4.0, 1, 60
        args.detector_frames = 60 if args.detector_frames is None else min(args.detector_frames, 60)
    if args.sequences < 0 or args.detector_clips < 0:
        raise ValueError("--sequences and --detector-clips must be >= 0")
    if not args.seconds > 0 or args.speed_frames < 2:
        raise ValueError("--seconds must be > 0 and --speed-frames >= 2")
    if args.detector_frames is not None and args.detector_frames < 2:
        raise ValueError("--detector-frames must be >= 2")
    names = select_profiles(args.profiles)
    start = time.time()
    print("gldt bench tracking")
    print(
        f"  machine: {platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}; "
        "BLAS limited to 1 thread"
    )
    runs, notes = build_profiles(args, names)
    runs = {name: run for name, run in runs.items() if run.sequences}
    with threadpool_limits(limits=1):
        ours = _our_factories()
        peers, peer_note = _peer_factories(args.no_peers)
        factories = {**ours, **peers}
        for note in notes + [peer_note]:
            print(f"  {note}")
        print("  profiles (TUNING: defaults may be tuned on them; HELD OUT: never tuned on):")
        for run in runs.values():
            print(f"    {run.summary()}")
        if not runs:
            raise ValueError("no streams to run: every selected profile was skipped or empty")
        results, per_sequence, kept = _run_accuracy(runs, factories)
        _print_accuracy(results, runs)
        worst = worst_profiles(results, {name: run.role for name, run in runs.items()})
        _print_worst(worst)
        margins = sequence_margins(per_sequence, JPTRACK_FULL, DIOU_PEER)
        _print_sequence_margins(margins, JPTRACK_FULL, DIOU_PEER)
        events, mechanisms = _id_switch_breakdown(kept)
        _print_events(events, mechanisms)
        speed, speed_source = _run_speed(factories, args.speed_frames, args.seed)
        print(
            f"\n[update time per frame, ms, one core; streams from {speed_source}, {args.speed_frames} frames "
            f"at 30 Hz, our stream model, best of {SPEED_REPEATS}]"
        )
        head = f"{'tracker':<28}{'3 mean':>9}{'3 p99':>9}{'50 mean':>9}{'50 p99':>9}"
        print(head)
        print("-" * len(head))
        for name in factories:
            a, b = speed[3][name], speed[50][name]
            print(f"{name:<28}{a['mean_ms']:9.3f}{a['p99_ms']:9.3f}{b['mean_ms']:9.3f}{b['p99_ms']:9.3f}")
        kalman = _kalman_microbench()
        for n in (3, 50):
            line = f"Kalman predict+update of {n} tracks per frame: ours (batched) {kalman[f'ours_{n}_us']:.1f} us"
            if f"filterpy_{n}_us" in kalman:
                ratio = kalman[f"filterpy_{n}_us"] / kalman[f"ours_{n}_us"]
                line += f", filterpy loop {kalman[f'filterpy_{n}_us']:.1f} us ({ratio:.1f}x ours)"
            print(("\n" if n == 3 else "") + line)
        print("\n[targets, per profile (JPTrack = JPTrack JCMA+PMR)]")
        lines = target_lines(results, worst, speed)
        for line in lines:
            print("  " + line)
    print(f"\n(total {time.time() - start:.0f} s)")
    if args.json:
        payload = {
            "notes": notes + [peer_note],
            "profiles": {
                name: {
                    "role": run.role,
                    "description": run.description,
                    "parameters": run.parameters,
                    "sequences": [
                        {
                            "name": s.name,
                            "frames": s.frames,
                            "fps": s.fps,
                            "size": list(s.size),
                            "detections": len(s.dets),
                        }
                        for s in run.sequences
                    ],
                }
                for name, run in runs.items()
            },
            "accuracy": results,
            "accuracy_per_sequence": per_sequence,
            "sequence_margins": margins,
            "worst": worst,
            "id_events": events,
            "recoveries_by_mechanism": mechanisms,
            "speed": {str(k): v for k, v in speed.items()},
            "kalman": kalman,
            "targets": lines,
        }
        tmp = args.json + ".part"
        with open(tmp, "w", encoding="utf-8") as handle:
            json.dump(payload, handle, indent=2, sort_keys=True, default=str)
        os.replace(tmp, args.json)
    return 0
