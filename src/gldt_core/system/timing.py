"""Per-stage wall-clock accounting (decode, preprocess, GD, LD, tracking) for summaries and benches.

Only running sums and counts are kept, so a 10,000-frame run costs the same memory as a
ten-frame one.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager

#: The stages reported, in the order a frame passes through them.
STAGES = ("decode", "preprocess", "gd", "ld", "tracking", "render")


class StageTimer:
    """Accumulates seconds and call counts per named stage."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.calls: dict[str, int] = {}

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self.add(name, time.perf_counter() - start)

    def add(self, name: str, seconds: float, count: bool = True) -> None:
        """Book ``seconds`` to ``name``; ``count=False`` adds to a call already counted."""
        self.seconds[name] = self.seconds.get(name, 0.0) + float(seconds)
        self.calls[name] = self.calls.get(name, 0) + (1 if count else 0)

    def total(self) -> float:
        return sum(self.seconds.values())

    def reset(self) -> None:
        self.seconds.clear()
        self.calls.clear()

    def breakdown(self, frames: int) -> list[tuple[str, float, float, int]]:
        """Rows ``(stage, ms per frame over all frames, share of total, calls)`` in stage order."""
        total = self.total() or 1.0
        names = [s for s in STAGES if s in self.seconds] + sorted(set(self.seconds) - set(STAGES))
        return [(n, 1000.0 * self.seconds[n] / max(frames, 1), self.seconds[n] / total, self.calls[n]) for n in names]

    def format(self, frames: int) -> str:
        """One line: ``gd 20.1 ms/frame (61%), ld ...``."""
        return ", ".join(f"{name} {ms:.1f} ms/frame ({share:.0%})" for name, ms, share, _ in self.breakdown(frames))
