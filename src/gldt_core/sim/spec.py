"""The description of one synthetic scene: everything a renderer needs to reproduce it bit for bit.

A scene is fully determined by its :class:`SceneSpec`; the seed picks the sky, the motions, the
airframes and the noise, so the same spec gives the same pixels and the same ground truth on any
machine (numpy's ``PCG64`` streams and OpenCV drawing are deterministic).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, TypedDict

import numpy as np

#: MOTChallenge class ids used in the ground truth (same as the Halmstad clips).
CLASS_DRONE = 1
CLASS_BIRD = 2

#: Ids of birds start here so they never collide with drone ids (1..targets).
BIRD_ID_BASE = 1001

MIN_FRAME_SIDE = 64


@dataclass(frozen=True)
class SceneSpec:
    """One reproducible scene.

    ``target_size`` is the range of airframe spans (wingspan / rotor-tip to rotor-tip) in pixels;
    ``None`` means :func:`default_target_size`, which covers FT-like dots (a 6 px drone is
    < 0.002 % of a 1080p frame) up to MOT-FLY-like close passes; :attr:`span_range` is the
    resolved range. ``birds`` ``None`` lets the seed decide (0-3 distractor birds, class 2 in gt).
    ``jpeg_quality`` ``None`` renders clean frames; a number round-trips each frame through JPEG so
    training images carry compression artefacts.
    """

    seed: int
    frames: int
    size: tuple[int, int] = (1920, 1080)
    targets: int = 3
    fps: float = 30.0
    target_size: tuple[float, float] | None = None
    birds: int | None = None
    jpeg_quality: int | None = None
    name: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        if self.target_size is None:
            object.__setattr__(self, "target_size", default_target_size(self.size))
        if len(self.size) == 2 and all(float(v).is_integer() for v in self.size):
            object.__setattr__(self, "size", (int(self.size[0]), int(self.size[1])))
        validate_spec(self)

    @property
    def span_range(self) -> tuple[float, float]:
        """``target_size`` after ``__post_init__`` filled in the default: never ``None``."""
        assert self.target_size is not None, "__post_init__ sets target_size"
        return self.target_size

    @property
    def width(self) -> int:
        return int(self.size[0])

    @property
    def height(self) -> int:
        return int(self.size[1])

    def with_(self, **changes: Any) -> SceneSpec:
        """A copy with some fields changed (validated again by ``__post_init__``)."""
        return replace(self, **changes)

    def rng(self, *stream: int) -> np.random.Generator:
        """An independent random stream of this scene, keyed by small integers.

        Keying streams (sky, motion of target i, noise of frame k, ...) instead of drawing from one
        generator in sequence keeps every part reproducible on its own, which is what makes random
        access to frame k possible.
        """
        return np.random.default_rng([int(self.seed) & 0xFFFFFFFF, *(int(s) for s in stream)])


class SpecExtras(TypedDict, total=False):
    """The :class:`SceneSpec` fields that scene helpers take as extra keyword arguments."""

    target_size: tuple[float, float] | None
    birds: int | None
    jpeg_quality: int | None
    name: str


def default_target_size(size: tuple[int, int]) -> tuple[float, float]:
    """6-60 px spans, capped at a quarter of the short side so small frames stay valid."""
    if len(size) != 2:
        return (6.0, 60.0)
    high = float(min(60.0, max(2.0, min(size) / 4.0)))
    return (min(6.0, high), high)


def validate_spec(spec: SceneSpec) -> None:
    """Raise a ``ValueError`` naming the field when a spec cannot be rendered."""
    if int(spec.seed) != spec.seed or spec.seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {spec.seed!r}")
    if int(spec.frames) != spec.frames or spec.frames < 1:
        raise ValueError(f"frames must be a positive integer, got {spec.frames!r}")
    if len(spec.size) != 2:
        raise ValueError(f"size must be (width, height), got {spec.size!r}")
    width, height = spec.size
    if int(width) != width or int(height) != height:
        raise ValueError(f"size must be integer pixels, got {spec.size!r}")
    if width < MIN_FRAME_SIDE or height < MIN_FRAME_SIDE:
        raise ValueError(f"size {width}x{height} is too small: both sides must be >= {MIN_FRAME_SIDE} px")
    if width > 8192 or height > 8192:
        raise ValueError(f"size {width}x{height} is too large: both sides must be <= 8192 px")
    if int(spec.targets) != spec.targets or not 0 <= spec.targets <= 64:
        raise ValueError(f"targets must be an integer in 0..64, got {spec.targets!r}")
    if not spec.fps > 0:
        raise ValueError(f"fps must be positive, got {spec.fps!r}")
    if len(spec.span_range) != 2:
        raise ValueError(f"target_size must be (min, max) px, got {spec.target_size!r}")
    low, high = spec.span_range
    if not 2.0 <= low <= high:
        raise ValueError(f"target_size must be (min, max) with 2 <= min <= max px, got {spec.target_size!r}")
    if high > min(width, height) / 2:
        raise ValueError(
            f"target_size max {high} px is bigger than half the frame ({width}x{height}); targets must fit in the frame"
        )
    if spec.birds is not None and not 0 <= spec.birds <= 64:
        raise ValueError(f"birds must be in 0..64 or None, got {spec.birds!r}")
    if spec.jpeg_quality is not None and not 1 <= spec.jpeg_quality <= 100:
        raise ValueError(f"jpeg_quality must be in 1..100 or None, got {spec.jpeg_quality!r}")


def parse_size(text: str) -> tuple[int, int]:
    """Parse ``WIDTHxHEIGHT`` (e.g. ``1920x1080``) with a clear error."""
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
        raise ValueError(f"size must look like 1920x1080, got {text!r}")
    return int(parts[0]), int(parts[1])


def parse_range(text: str) -> tuple[int, int]:
    """Parse ``N`` or ``A-B`` into an inclusive integer range."""
    parts = text.split("-")
    try:
        values = [int(p) for p in parts]
    except ValueError:
        raise ValueError(f"expected N or A-B, got {text!r}") from None
    if len(values) == 1:
        return values[0], values[0]
    if len(values) != 2 or values[0] > values[1]:
        raise ValueError(f"expected N or A-B with A <= B, got {text!r}")
    return values[0], values[1]
