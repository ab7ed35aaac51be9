"""``gldt bench tracking-tune``: choose JPTrack's defaults on the TUNING profiles only, by the worst.

Every combination of a small grid of :class:`gldt_core.track.JPTrackConfig` fields runs on the
tuning profiles of ``gldt bench tracking`` (never the held-out ones), beside boxmot's ByteTrack
with DIoU association, the strongest peer, on the same streams. A variant's score is its WORST
tuning profile: the smallest HOTA margin over that peer (IDF1 margin and IDSW ratio reported
beside it), so a setting that wins big on one generator and loses on another ranks low. The
held-out profiles then tell whether the choice generalises: run ``gldt bench tracking``.

``--grid "t_h=0.4,0.5;new_track_thresh=0.45,0.6"``: fields separated by ``;``, values by ``,``.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
from typing import Any


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``gldt bench tracking-tune``."""
    parser = subparsers.add_parser(
        "tracking-tune",
        help="JPTrack settings on the tuning profiles, ranked by their worst profile against ByteTrack+DIoU",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--grid", required=True, help='e.g. "t_h=0.4,0.5;new_track_thresh=0.45,0.6"')
    parser.add_argument("--sequences", type=int, default=6, help="sequences per synthetic profile (default 6)")
    parser.add_argument("--seconds", type=float, default=20.0, help="duration of each synthetic sequence (default 20)")
    parser.add_argument("--detector-clips", type=int, default=0, help="clips of real-detector-val (0 = all)")
    parser.add_argument("--detector-frames", type=int, default=None, help="frames per real clip (default: all)")
    parser.add_argument("--halmstad", default=None, help="Halmstad visible dataset folder")
    parser.add_argument("--seed", type=int, default=0, help="base seed of the synthetic streams")
    parser.set_defaults(func=run_tune)


def parse_grid(text: str) -> list[dict[str, Any]]:
    """``"a=1,2;b=x"`` -> every combination as ``{field: value}``, values typed as the
    :class:`JPTrackConfig` field's default (bool, int, float); one line naming a bad field or value."""
    from gldt_core.track import JPTrackConfig

    defaults = JPTrackConfig()
    fields = {f.name for f in dataclasses.fields(JPTrackConfig)}
    axes: list[list[tuple[str, Any]]] = []
    for part in filter(None, (p.strip() for p in text.split(";"))):
        name, _, values = part.partition("=")
        name = name.strip()
        if name not in fields:
            raise ValueError(f"--grid: {name!r} is not a JPTrackConfig field")
        kind = type(getattr(defaults, name))
        axis = []
        for raw in filter(None, (v.strip() for v in values.split(","))):
            try:
                value: Any = raw.lower() in ("1", "true", "yes") if kind is bool else kind(raw)
            except ValueError:
                raise ValueError(f"--grid: {name}={raw!r} is not a {kind.__name__}") from None
            axis.append((name, value))
        if not axis:
            raise ValueError(f"--grid: {name} has no values")
        axes.append(axis)
    if not axes:
        raise ValueError("--grid: no field given")
    return [dict(combo) for combo in itertools.product(*axes)]


def tuning_profile_names() -> list[str]:
    """The TUNING profiles of ``gldt bench tracking``, in its order (held-out ones are never built)."""
    from gldt_core.bench.tracking import REAL_PROFILES
    from gldt_core.eval.streams import PROFILES, TUNING

    return [p.name for p in PROFILES if p.role == TUNING] + [n for n, split in REAL_PROFILES.items() if split == "val"]


def run_tune(args: argparse.Namespace) -> int:
    """Run the grid on the tuning profiles; print the variants ranked by their worst profile."""
    from threadpoolctl import threadpool_limits

    from gldt_core.bench.tracking import DIOU_PEER, _peer_factories, _track, build_profiles
    from gldt_core.eval import evaluate_many
    from gldt_core.eval.streams import TUNING
    from gldt_core.track import JPTrack, JPTrackConfig

    variants = parse_grid(args.grid)
    args.quick = False
    runs, notes = build_profiles(args, tuning_profile_names())
    runs = {name: run for name, run in runs.items() if run.role == TUNING and run.sequences}
    for note in notes:
        print(f"  {note}")
    print(f"  tuning profiles: {', '.join(runs)}; {len(variants)} variants")
    peers, peer_note = _peer_factories(False)
    if DIOU_PEER not in peers:
        raise ValueError(f"the tuning needs the peer {DIOU_PEER}: {peer_note}")

    def evaluate(make: Any, run: Any) -> dict[str, float]:
        pairs = {s.name: (s.gt, _track(make, s)) for s in run.sequences}
        return evaluate_many(pairs)["combined"]

    rows = []
    with threadpool_limits(limits=1):
        peer = {name: evaluate(peers[DIOU_PEER], run) for name, run in runs.items()}
        for variant in variants:
            config = JPTrackConfig(**variant)

            def make(size: tuple[int, int], fps: float, config: JPTrackConfig = config) -> JPTrack:
                return JPTrack(dataclasses.replace(config, image_size=size))

            margins = {}
            for name, run in runs.items():
                ours = evaluate(make, run)
                margins[name] = (
                    100 * (ours["HOTA"] - peer[name]["HOTA"]),
                    100 * (ours["IDF1"] - peer[name]["IDF1"]),
                    ours["IDSW"] / max(1, peer[name]["IDSW"]),
                )
            worst = min(margins, key=lambda n: margins[n][0])
            rows.append((margins[worst][0], variant, worst, margins))
            print(f"  ran {variant}", flush=True)
    rows.sort(key=lambda row: -row[0])
    print("\nvariants by their worst tuning profile (HOTA margin over ByteTrack+DIoU, points); per profile:")
    print("HOTA margin / IDF1 margin / IDSW ratio")
    for worst_margin, variant, worst, margins in rows:
        cells = "  ".join(f"{n} {h:+.2f}/{i:+.2f}/{r:.2f}" for n, (h, i, r) in margins.items())
        print(f"{worst_margin:+7.2f} ({worst}) {variant}\n          {cells}")
    return 0
