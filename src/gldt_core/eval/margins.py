"""One tracker's metric against another's, sequence by sequence.

A total over many sequences can hide the sequences where a tracker loses, so the benchmarks that
compare two trackers (`gldt bench tracking`, `gldt bench ablation`) also report the margin on
each sequence they share, worst first, and on how many of them the first tracker is behind.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass


@dataclass(frozen=True)
class SequenceMargins:
    """``ours - peer`` of one metric on every sequence both have, worst (lowest) margin first."""

    metric: str
    margins: dict[str, float]

    @property
    def behind(self) -> int:
        """Sequences where ``ours`` scores lower than the peer."""
        return sum(margin < 0 for margin in self.margins.values())

    @property
    def worst(self) -> tuple[str, float]:
        """The sequence with the lowest margin and that margin; the first by name on a tie."""
        name = next(iter(self.margins))
        return name, self.margins[name]


def margins_by_sequence(
    ours: Mapping[str, Mapping[str, float]], peer: Mapping[str, Mapping[str, float]], metric: str
) -> SequenceMargins | None:
    """The margins of ``metric`` on the sequences in both ``ours`` and ``peer`` (each a mapping
    from sequence name to its metrics); None when they share no sequence."""
    names = sorted(set(ours) & set(peer))
    if not names:
        return None
    margins = {name: float(ours[name][metric]) - float(peer[name][metric]) for name in names}
    order = sorted(names, key=lambda name: margins[name])  # stable: ties stay in name order
    return SequenceMargins(metric, {name: margins[name] for name in order})
