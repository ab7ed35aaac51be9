"""Track birth from persistent low-score detections (gldt_core.track.birth) and its use in the
trackers: a steady low-score target gets a track after K frames, flickering clutter does not."""

from __future__ import annotations

import numpy as np
import pytest

from gldt_core.track.birth import GATE_MIN_PX, LowScoreBirth
from gldt_core.track.bytetrack import ByteTrack, ByteTrackConfig
from gldt_core.track.jptrack import JPTrack, JPTrackConfig


def box(cx: float, cy: float, size: float = 10.0, score: float = 0.2) -> list[float]:
    return [cx - size / 2, cy - size / 2, cx + size / 2, cy + size / 2, score]


def feed(birth: LowScoreBirth, frames: list[list[list[float]]]) -> list[list[int]]:
    """Born rows per frame, every detection offered as unclaimed."""
    out = []
    for rows in frames:
        dets = np.asarray(rows, dtype=np.float64).reshape(-1, 5)
        out.append(birth.update(dets, np.arange(len(dets))))
    return out


def test_a_chain_is_born_on_its_kth_consecutive_frame_and_not_before() -> None:
    born = feed(LowScoreBirth(4), [[box(100 + 3 * k, 50)] for k in range(6)])
    assert born == [[], [], [], [0], [], []], (
        "born on frame 4; the chain then ends (it became a track), a new one starts"
    )


def test_a_missed_frame_restarts_the_chain() -> None:
    frames = [[box(100, 50)], [box(101, 50)], [], [box(102, 50)], [box(103, 50)], [box(104, 50)]]
    assert feed(LowScoreBirth(3), frames) == [[], [], [], [], [], [0]]


def test_a_detection_beyond_the_gate_starts_a_new_chain() -> None:
    """10 px boxes: the gate is 1.5 diagonals (21 px) + GATE_MIN_PX; a 40 px jump every frame
    (flicker from one clutter spot to another) never chains."""
    jumps = [[box(100 + 40 * (k % 2), 50)] for k in range(8)]
    assert all(not rows for rows in feed(LowScoreBirth(3), jumps))
    near = 1.5 * np.hypot(10, 10) + GATE_MIN_PX - 1.0
    assert feed(LowScoreBirth(2), [[box(100, 50)], [box(100 + near, 50)]]) == [[], [0]]


def test_two_targets_chain_independently_and_rows_refer_to_this_frame() -> None:
    frames = [[box(100, 50), box(400, 300)], [box(402, 301), box(101, 50)], [box(102, 51), box(404, 302)]]
    born = feed(LowScoreBirth(3), frames)
    assert born[:2] == [[], []] and sorted(born[2]) == [0, 1]


def test_only_unclaimed_rows_take_part() -> None:
    birth = LowScoreBirth(2)
    dets = np.asarray([box(100, 50), box(300, 50)], dtype=np.float64)
    assert birth.update(dets, np.array([1])) == []
    assert birth.update(dets, np.array([1])) == [1], "row 0 was claimed by a track both times"


def test_bad_chain_length_is_refused() -> None:
    with pytest.raises(ValueError, match="frames >= 1"):
        LowScoreBirth(0)
    with pytest.raises(ValueError, match="low_score_birth_frames must be >= 0"):
        JPTrack(JPTrackConfig(low_score_birth_frames=-1))


def steady_low_score_target(frames: int, score: float = 0.18) -> list[np.ndarray]:
    """A 12 px drone crossing the frame at 4 px per frame, always scored below 0.25."""
    return [np.asarray([box(200 + 4 * k, 300, 12.0, score)], dtype=np.float64) for k in range(frames)]


@pytest.mark.parametrize(
    "tracker_class, config_class, thresholds",
    [
        (JPTrack, JPTrackConfig, {"t_h": 0.25, "new_track_thresh": 0.25}),
        (ByteTrack, ByteTrackConfig, {"track_thresh": 0.25, "new_track_thresh": 0.25}),
    ],
)
def test_a_steady_low_score_target_gets_one_track_only_with_low_score_birth(
    tracker_class, config_class, thresholds
) -> None:
    for k_frames in (0, 6):
        tracker = tracker_class(config_class(**thresholds, low_score_birth_frames=k_frames))
        outputs = [tracker.update(dets, k / 30.0) for k, dets in enumerate(steady_low_score_target(40))]
        shown = [k for k, rows in enumerate(outputs) if len(rows)]
        if k_frames == 0:
            assert shown == [], "without the rule no detection below new_track_thresh starts a track"
            continue
        assert shown[0] == k_frames - 1, "the track appears on the K-th sighting"
        assert shown == list(range(k_frames - 1, 40)), "then it is kept by the low-score stage every frame"
        ids = {int(rows[0, 4]) for rows in outputs if len(rows)}
        assert len(ids) == 1, f"one identity for one target, got {ids}"


def test_flickering_low_score_clutter_starts_no_track() -> None:
    """Low-score boxes that land somewhere else every frame (noise, not a target) never chain."""
    rng = np.random.default_rng(3)
    tracker = JPTrack(JPTrackConfig(t_h=0.25, new_track_thresh=0.25, low_score_birth_frames=6))
    for k in range(200):
        points = rng.uniform([0, 0], [1920, 1080], size=(3, 2))
        dets = np.asarray([box(x, y, 8.0, 0.15) for x, y in points], dtype=np.float64)
        assert len(tracker.update(dets, k / 30.0)) == 0, f"frame {k}: a false track from random clutter"


def test_reset_forgets_the_chains() -> None:
    tracker = JPTrack(JPTrackConfig(t_h=0.25, new_track_thresh=0.25, low_score_birth_frames=3))
    stream = steady_low_score_target(3)
    tracker.update(stream[0], 0.0)
    tracker.update(stream[1], 1 / 30)
    tracker.reset()
    assert len(tracker.update(stream[2], 2 / 30)) == 0, "a chain from before reset() must not count"


def test_the_system_config_passes_the_rule_to_its_tracker(tmp_path) -> None:
    """`tracker.jptrack.low_score_birth_frames` in a GL-DT system YAML reaches the tracker; the
    shipped configuration leaves the rule off (measured worse with the shipped detectors)."""
    from gldt_core.system.config import load_config
    from gldt_core.system.gldt_system import build_tracker

    path = tmp_path / "birth.yaml"
    path.write_text("tracker:\n  jptrack: {t_h: 0.25, new_track_thresh: 0.25, low_score_birth_frames: 12}\n")
    tracker = build_tracker(load_config(path))
    assert tracker.config.low_score_birth_frames == 12
    assert build_tracker(load_config(None)).config.low_score_birth_frames == 0
