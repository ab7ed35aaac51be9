"""``gldt bench tracking-returns``: where the previous track was when an object came back under a
new id, measured on a constructed stream whose answer is known."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from gldt_core.bench.tracking_returns import return_positions, run_returns, summary_lines
from gldt_core.track import JPTrack, JPTrackConfig

FPS = 30.0
SIZE = 20.0
FRAMES = 150
GAP = range(41, 86)  # 1.5 s without a detection


def stream(jump_y: float) -> tuple[np.ndarray, np.ndarray]:
    """One object flying right at 2 px a frame, undetected during :data:`GAP`, and ``jump_y`` px
    off its line after the gap (MOT gt and detection rows)."""
    gt, dets = [], []
    for frame in range(1, FRAMES + 1):
        x, y = 100.0 + 2.0 * frame, 300.0 + (jump_y if frame > GAP[-1] else 0.0)
        gt.append([frame, 1, x, y, SIZE, SIZE, 1, 1, 1, -1])
        if frame not in GAP:
            dets.append([frame, 1, x, y, SIZE, SIZE, 0.9, -1, -1, -1])
    return np.asarray(gt, dtype=np.float64), np.asarray(dets, dtype=np.float64)


def make() -> JPTrack:
    return JPTrack(JPTrackConfig(image_size=(1280, 720)))


def test_an_object_back_far_from_its_lost_track_is_measured_where_it_came_back() -> None:
    gt, dets = stream(jump_y=400.0)  # beyond the relink's recovery radius (about 360 px here)
    [found] = return_positions(gt, dets, FPS, make, "jump")
    # The new id's first row is its first or second detection after the gap (output once confirmed).
    assert found.held and GAP[-1] + 1 <= found.frame <= GAP[-1] + 2
    assert found.lost_s == pytest.approx((found.frame - (GAP[0] - 1)) / FPS)  # since its last detection
    # The Kalman prediction went on along the line: the object is about 400 px (20 sizes) off it.
    assert 19.0 < found.sizes < 21.5
    assert found.sigmas > 1.0 and found.p_final < JPTrackConfig().tau_t


def test_an_object_back_where_its_track_expected_it_keeps_its_id_and_gives_no_return() -> None:
    gt, dets = stream(jump_y=0.0)
    assert return_positions(gt, dets, FPS, make, "straight") == []


def test_the_summary_counts_the_returns_past_the_gate() -> None:
    gt, dets = stream(jump_y=400.0)
    lines = summary_lines("jump", return_positions(gt, dets, FPS, make), tau_t=0.6)
    assert lines[0] == "jump: 1 births after a gap; previous track still held in 1"
    assert lines[-1].endswith("above tau_t 0.6: 0 of 1")


def test_an_unknown_profile_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    args = argparse.Namespace(profiles="ours,nope", sequences=1, seconds=1.0, seed=0)
    assert run_returns(args) == 2
    out = capsys.readouterr().out.strip()
    assert "\n" not in out and "'ours,nope'" in out
