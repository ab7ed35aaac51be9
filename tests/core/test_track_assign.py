"""The trackers' matcher: ByteTrack's reference semantics (lapjv with a cost limit), not "as many
pairs as possible", which swaps the ids of targets flying side by side."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from gldt_core.track import ByteTrack, JPTrack
from gldt_core.track.assignment import assign


def total_cost(pairs: list[tuple[int, int]], cost: np.ndarray, limit: float) -> float:
    """Matched costs plus limit / 2 for every row and column left unmatched."""
    unmatched = cost.shape[0] + cost.shape[1] - 2 * len(pairs)
    return sum(cost[r, c] for r, c in pairs) + 0.5 * limit * unmatched


def best_by_brute_force(cost: np.ndarray, allowed: np.ndarray, limit: float) -> float:
    n_rows, n_cols = cost.shape
    best = total_cost([], cost, limit)
    for size in range(1, min(n_rows, n_cols) + 1):
        for rows in itertools.combinations(range(n_rows), size):
            for cols in itertools.permutations(range(n_cols), size):
                pairs = list(zip(rows, cols))
                if all(allowed[r, c] for r, c in pairs):
                    best = min(best, total_cost(pairs, cost, limit))
    return best


def test_the_swap_that_matches_more_pairs_loses_to_the_cheaper_single_pair() -> None:
    # Track A is on detection 0 (cost 0.004); B, missed, could only take detection 0 (0.588),
    # and A could take the newcomer (0.588). Matching both (1.176) would swap the ids.
    cost = np.array([[0.004, 0.588], [0.588, 1.144]])
    allowed = np.array([[True, True], [True, False]])
    assert assign(cost, allowed, 0.7) == [(0, 0)]


@pytest.mark.parametrize("seed", range(80))
def test_assign_reaches_the_brute_force_optimum(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n_rows, n_cols = rng.integers(1, 5, size=2)
    limit = float(rng.uniform(0.3, 1.0))
    cost = rng.uniform(0.0, 1.2, size=(n_rows, n_cols))
    allowed = (cost <= limit) & (rng.random((n_rows, n_cols)) < rng.uniform(0.2, 0.9))
    pairs = assign(cost, allowed, limit)
    assert len({r for r, _ in pairs}) == len(pairs) == len({c for _, c in pairs})
    assert all(allowed[r, c] for r, c in pairs)
    assert total_cost(pairs, cost, limit) == pytest.approx(best_by_brute_force(cost, allowed, limit), abs=1e-9)


def test_pairs_without_rivals_are_matched_directly_even_at_the_limit() -> None:
    cost = np.array([[0.7, 0.9], [0.9, 0.1]])
    allowed = cost <= 0.7
    assert assign(cost, allowed, 0.7) == [(0, 0), (1, 1)]
    assert assign(np.zeros((0, 3)), np.zeros((0, 3), dtype=bool), 0.7) == []


@pytest.mark.parametrize(
    "tracker, size, gap",
    # JPTrack: 10 px drones edge to edge. ByteTrack matches on IoU only, so its pair overlaps
    # (20 px boxes 12 px apart), or the swap would never be allowed and the test could not fail.
    [(JPTrack, 10, 10), (ByteTrack, 20, 12)],
)
def test_side_by_side_targets_keep_their_ids_when_one_is_missed_beside_a_newcomer(tracker, size: int, gap: int) -> None:
    tr = tracker()
    for frame in range(21):
        xa = 100 + 2 * frame
        dets = [[xa, 200, xa + size, 200 + size, 0.9], [xa + gap, 200, xa + gap + size, 200 + size, 0.9]]
        if frame == 20:  # B missed; a new object appears as far left of A as B was right of it
            dets = [[xa, 200, xa + size, 200 + size, 0.9], [xa - gap, 200, xa - gap + size, 200 + size, 0.9]]
        out = tr.update(np.array(dets, dtype=float), frame / 30)
        if frame == 19:
            ids_before = {int(row[4]): row[0] for row in out}
    assert sorted(ids_before) == [1, 2]
    shown = {int(row[4]): row[0] for row in out}
    assert 1 in shown and shown[1] == pytest.approx(140.0, abs=0.5), shown
    assert 2 not in shown, f"track 2 (missed) took a detection: {shown}"
