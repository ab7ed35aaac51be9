"""``gldt bench tracking-returns``: where JPTrack's lost track was when its object came back.

``gldt bench tracking`` counts most of JPTrack's identity switches as "birth after a detection
gap": an object missed for a while comes back and gets a new id. That can have two causes, with
different fixes: the lost track was already forgotten (memory too short), or it was still held
but PMR did not accept the returning detection (gate too tight, or the prediction too far off).
For every such switch this replays the tracker and, on the frame the new id starts, looks up the
object's previous track: whether it is still held, how far the object's ground-truth centre is
from the track's Kalman prediction (in box sizes, and in the standard deviations of PMR's floor,
``gldt_core.track.pmr.floor_variance``), and the ``P_final`` PMR would give that centre, against
``tau_t``. For a well-calibrated 2-D Gaussian the median of the distance would be 1.18 sigma, and
``P_final > tau_t`` (about 0.8 sigma at the usual time weight) would accept 27 % of true returns.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

#: Median Mahalanobis distance of a 2-D Gaussian: sqrt(2 ln 2).
CALIBRATED_MEDIAN_SIGMA = float(np.sqrt(2.0 * np.log(2.0)))


@dataclasses.dataclass(frozen=True)
class ReturnPosition:
    """The previous track of an object that came back under a new id, on that id's first frame."""

    sequence: str
    frame: int
    held: bool  # the previous track was still in the tracker (lost, waiting for PMR)
    lost_s: float = float("nan")  # how long it had been without a detection
    sigmas: float = float("nan")  # object centre to the track's prediction, in PMR floor std
    sizes: float = float("nan")  # the same distance in box sizes
    p_final: float = float("nan")  # PMR's score for the object's centre (eqs. 20-22)


class _Watch:
    """A JPTrack that, on the frames asked for, records where the named lost tracks are."""

    def __init__(self, tracker: Any, wanted: dict[int, list[tuple[int, float, float, float]]], sequence: str) -> None:
        self.tracker = tracker
        self.wanted = wanted  # frame -> [(previous track id, object centre x, y, size)]
        self.sequence = sequence
        self.found: list[ReturnPosition] = []

    @property
    def tracks(self) -> Any:
        return self.tracker.tracks

    def update(self, dets: np.ndarray, t: float, frame: int = 0) -> np.ndarray:
        """JPTrack's update; ``frame`` is the MOT frame number (``track_detection_rows`` passes it)."""
        for previous_id, x, y, size in self.wanted.get(frame, ()):
            self.found.append(self._where(previous_id, x, y, size, t, frame))
        return self.tracker.update(dets, t)

    def _where(self, previous_id: int, x: float, y: float, size: float, t: float, frame: int) -> ReturnPosition:
        from gldt_core.track.pmr import floor_variance

        c = self.tracker.config
        held = [track for track in self.tracker.tracks if track.track_id == previous_id]
        if not held:
            return ReturnPosition(self.sequence, frame, held=False)
        track = held[0]
        # The filter is still at the previous frame (this runs before the update): predict to t.
        cx, cy, w, h, vx, vy = (float(v) for v in track.kf.mean[:6])
        ahead = t - track.kf_t
        cx, cy = cx + vx * ahead, cy + vy * ahead
        steps = (t - track.last_update_t) * c.ref_fps
        sigma = float(np.sqrt(floor_variance(0.5 * (w + h), steps, c.pmr_pos_std_size, c.pmr_vel_std)))
        distance = float(np.hypot(x - cx, y - cy))
        return ReturnPosition(
            self.sequence,
            frame,
            held=True,
            lost_s=t - track.last_update_t,
            sigmas=distance / max(sigma, 1e-9),
            sizes=distance / max(size, 1e-9),
            p_final=float(self.tracker.lost_track_p_final(track, np.array([[x, y]]), t)[0]),
        )


def return_positions(
    gt: np.ndarray, dets: np.ndarray, fps: float, make_tracker: Any, sequence: str = ""
) -> list[ReturnPosition]:
    """One :class:`ReturnPosition` per "birth after a detection gap" identity switch of the tracker
    ``make_tracker()`` (a JPTrack) on MOT ``dets`` against MOT ``gt`` at ``fps``."""
    from gldt_core.eval.id_events import BIRTH_GAP, classify_id_switches
    from gldt_core.track.runner import track_detection_rows

    frames = int(max(gt[:, 0].max(initial=0), dets[:, 0].max(initial=0)))
    pred = track_detection_rows(make_tracker(), dets, fps, num_frames=frames)
    wanted: dict[int, list[tuple[int, float, float, float]]] = {}
    for event in classify_id_switches(gt, pred, dets, fps, sequence=sequence).events:
        if event.category != BIRTH_GAP:
            continue
        rows = gt[(gt[:, 1] == event.gt_id) & (gt[:, 0] == event.new_first_frame)]
        if len(rows):
            x, y, w, h = (float(v) for v in rows[0, 2:6])
            wanted.setdefault(event.new_first_frame, []).append((event.prev_id, x + w / 2, y + h / 2, (w + h) / 2))
    watch = _Watch(make_tracker(), wanted, sequence)
    track_detection_rows(watch, dets, fps, num_frames=frames)
    return watch.found


def summary_lines(name: str, found: Sequence[ReturnPosition], tau_t: float) -> list[str]:
    """The report of one profile."""
    held = [r for r in found if r.held]
    lines = [f"{name}: {len(found)} births after a gap; previous track still held in {len(held)}"]
    if held:
        sigmas, sizes = np.array([r.sigmas for r in held]), np.array([r.sizes for r in held])
        lost, p_final = np.array([r.lost_s for r in held]), np.array([r.p_final for r in held])

        def quartiles(values: np.ndarray) -> str:
            return " / ".join(f"{v:.2f}" for v in np.percentile(values, [25, 50, 75]))

        lines += [
            f"  lost for (s), quartiles        {quartiles(lost)}",
            f"  distance, PMR floor sigmas     {quartiles(sigmas)} (calibrated median {CALIBRATED_MEDIAN_SIGMA:.2f})",
            f"  distance, box sizes            {quartiles(sizes)}",
            f"  P_final of the object's centre {quartiles(p_final)}; above tau_t {tau_t:g}: "
            f"{int((p_final > tau_t).sum())} of {len(held)}",
        ]
    return lines


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``gldt bench tracking-returns``."""
    parser = subparsers.add_parser(
        "tracking-returns",
        help="where JPTrack's lost track was when its object came back under a new id",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--profiles", default="ours,crossing,ego-motion-25hz", help="synthetic stream profiles")
    parser.add_argument("--sequences", type=int, default=6, help="sequences per profile (default 6)")
    parser.add_argument("--seconds", type=float, default=20.0, help="duration of each sequence (default 20)")
    parser.add_argument("--seed", type=int, default=0, help="base seed of the streams")
    parser.set_defaults(func=run_returns)


def run_returns(args: argparse.Namespace) -> int:
    from gldt_core.eval.streams import PROFILES, profile_by_name, profile_sequences
    from gldt_core.track import JPTrack, JPTrackConfig

    names = [name.strip() for name in args.profiles.split(",") if name.strip()]
    known = [profile.name for profile in PROFILES]
    unknown = [name for name in names if name not in known]
    if unknown or not names:
        print(f"gldt bench tracking-returns: --profiles {args.profiles!r}: expected some of {', '.join(known)}")
        return 2
    print("gldt bench tracking-returns (JPTrack defaults)")
    for name in names:
        profile = profile_by_name(name)
        found: list[ReturnPosition] = []
        for sequence in profile_sequences(profile, args.seed, args.sequences, args.seconds):
            size = sequence.size

            def make(size: tuple[int, int] = size) -> JPTrack:
                return JPTrack(JPTrackConfig(image_size=size))

            found += return_positions(sequence.gt, sequence.dets, sequence.fps, make, sequence.name)
        for line in summary_lines(f"{name} [{profile.role}]", found, JPTrackConfig().tau_t):
            print(line)
    return 0
