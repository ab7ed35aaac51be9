"""Named splits of synthetic scenes used everywhere (detector training, tracking benchmarks, CI).

Seeds are drawn from disjoint ranges per split (train 0-99_999, val 100_000-199_999, test
1_000_000+), so no test scene can ever appear in training whatever the split sizes are.
Each split mixes FT-like scenes (tiny far targets, < 0.1 % of the frame) with MOT-FLY-like ones
(bigger, closer targets), 1-3 UAVs, at 1080p 30 fps, each frame JPEG round-tripped at a quality
between 70 and 95 like real compressed footage (``spec.with_(jpeg_quality=None)`` for clean frames).
"""

from __future__ import annotations

from gldt_core.sim.spec import SceneSpec

SEED_BASES = {"train": 0, "val": 100_000, "test": 1_000_000}
SPLIT_SIZES = {"train": 64, "val": 12, "test": 16}
SPLIT_FRAMES = {"train": 300, "val": 300, "test": 450}

#: (name, target span range px): FT-like far targets and MOT-FLY-like nearer ones.
REGIMES = (("ft", (4.0, 24.0)), ("motfly", (12.0, 80.0)), ("mixed", (6.0, 60.0)))


def split(
    name: str, count: int | None = None, frames: int | None = None, size: tuple[int, int] = (1920, 1080)
) -> list[SceneSpec]:
    """The scene specs of split ``name`` (``train``, ``val`` or ``test``).

    ``count`` and ``frames`` override the default number of scenes and frames per scene; the
    seeds of the first scenes never change, so a smaller split is a prefix of a bigger one.
    """
    if name not in SEED_BASES:
        raise ValueError(f"unknown split {name!r}; expected one of {sorted(SEED_BASES)}")
    count = SPLIT_SIZES[name] if count is None else int(count)
    if count < 0:
        raise ValueError(f"count must be >= 0, got {count}")
    if count > 99_999:
        raise ValueError(f"count {count} exceeds the seed range of a split (99999)")
    frames = SPLIT_FRAMES[name] if frames is None else int(frames)
    specs = []
    for index in range(count):
        regime, target_size = REGIMES[index % len(REGIMES)]
        targets = 1 + (index * 7 // 3) % 3
        seed = SEED_BASES[name] + index
        specs.append(
            SceneSpec(
                seed=seed,
                frames=frames,
                size=size,
                targets=targets,
                target_size=_fit(target_size, size),
                jpeg_quality=70 + (index * 11) % 26,
                name=f"{name}-{index:04d}-{regime}",
            )
        )
    return specs


def _fit(target_size: tuple[float, float], size: tuple[int, int]) -> tuple[float, float]:
    """Scale a 1080p size range to another frame height (keeping at least 3 px)."""
    factor = min(size) / 1080.0
    low = max(3.0, target_size[0] * factor)
    return low, max(low, min(target_size[1] * factor, min(size) / 2))


def splits() -> dict[str, list[SceneSpec]]:
    """All three splits with their default sizes."""
    return {name: split(name) for name in SEED_BASES}
