"""The planner's stream: every live track every frame, ids without holes, one REMOVED entry each."""

from __future__ import annotations

import math
from collections import defaultdict

import numpy as np
import pytest

from gldt_core.camera import CameraModel
from gldt_core.system.config import SystemConfig
from gldt_core.system.gldt_system import build_tracker
from gldt_core.track.planner_stream import STATE_CODES, PlannerStream, PlannerTrack
from support import REPO_ROOT

FPS = 30.0
SIZE = (1280, 720)


def run_stream(frames: list[np.ndarray], camera: CameraModel | None = None, restart_at: int | None = None):
    """Feed ``frames`` (each ``(N, 5)`` detections) through JPTrack and the stream; returns the
    stream's entries per frame and the tracker's output rows per frame."""
    tracker = build_tracker(SystemConfig(), SIZE)
    stream = PlannerStream()
    entries, outputs = [], []
    for index, dets in enumerate(frames):
        if index == restart_at:
            tracker.reset()
            stream.restart()
        t = index / FPS
        rows = np.asarray(tracker.update(dets, t), dtype=np.float64).reshape(-1, 6)
        probabilities = np.tile([0.8, 0.15, 0.05], (len(dets), 1))
        entries.append(stream.step(tracker.tracks, t, rows, dets, probabilities, camera))
        outputs.append(rows)
    return entries, outputs


def target(index: int, x0: float = 200.0, vx: float = 90.0, y: float = 300.0, size: float = 24.0) -> list[float]:
    x = x0 + vx * index / FPS
    return [x, y, x + size, y + size * 0.6, 0.9]


def frames_with_gap(total: int, gap: range, end: int) -> list[np.ndarray]:
    return [
        np.array([target(i)]) if i < end and i not in gap else np.zeros((0, 5), dtype=np.float64) for i in range(total)
    ]


def by_id(entries: list[list[PlannerTrack]]) -> dict[int, list[tuple[int, PlannerTrack]]]:
    lives: dict[int, list[tuple[int, PlannerTrack]]] = defaultdict(list)
    for frame, frame_entries in enumerate(entries):
        for entry in frame_entries:
            lives[entry.track_id].append((frame, entry))
    return lives


def assert_no_holes_and_one_removal(entries: list[list[PlannerTrack]]) -> None:
    for track_id, life in by_id(entries).items():
        frames = [frame for frame, _ in life]
        assert frames == list(range(frames[0], frames[0] + len(frames))), f"id {track_id} has a hole: {frames}"
        states = [entry.state for _, entry in life]
        assert states.count("removed") <= 1, f"id {track_id} removed twice"
        if "removed" in states:
            assert states[-1] == "removed", f"id {track_id} published after its removal"
        assert "tentative" not in states


def test_a_missed_detection_keeps_the_track_in_the_stream_as_coasting() -> None:
    entries, _ = run_stream(frames_with_gap(40, range(15, 19), end=40))
    lives = by_id(entries)
    assert len(lives) == 1
    ((track_id, life),) = lives.items()
    states = {frame: entry for frame, entry in life}
    for frame in range(15, 19):
        assert states[frame].state == "lost"
        assert states[frame].frames_since_update == frame - 14
        assert not states[frame].matched
    assert states[19].state in ("confirmed", "recovered") and states[19].matched
    # Coasting: the box follows the prediction, the position uncertainty grows each missed frame.
    variance = [states[f].covariance[0, 0] for f in range(14, 19)]
    assert all(later > earlier for earlier, later in zip(variance, variance[1:]))
    assert states[17].center_x > states[15].center_x  # moving right on its velocity
    assert_no_holes_and_one_removal(entries)


def test_an_expired_track_leaves_the_stream_once_with_a_removed_state() -> None:
    entries, _ = run_stream(frames_with_gap(200, range(0), end=30))
    lives = by_id(entries)
    ((track_id, life),) = lives.items()
    last_frame, last = life[-1]
    assert last.state == "removed"
    assert last_frame < 199, "the lost track should expire within the run"
    assert all(track_id not in {e.track_id for e in frame} for frame in entries[last_frame + 1 :])
    assert_no_holes_and_one_removal(entries)


def test_matched_entries_are_exactly_the_trackers_output_rows() -> None:
    rng = np.random.default_rng(3)
    frames = []
    for i in range(90):
        rows = [target(i, x0=100, vx=60), target(i, x0=900, vx=-40, y=200, size=30)]
        rows = [r for r in rows if rng.random() > 0.2]  # random misses
        clutter = [[rng.uniform(0, 1200), rng.uniform(0, 650), 0, 0, rng.uniform(0.1, 0.9)] for _ in range(2)]
        for c in clutter:
            c[2], c[3] = c[0] + 10, c[1] + 8
        frames.append(np.array(rows + clutter, dtype=np.float64).reshape(-1, 5))
    entries, outputs = run_stream(frames)
    for frame_entries, rows in zip(entries, outputs):
        matched = sorted(
            (e.track_id, e.center_x - e.width / 2, e.center_y - e.height / 2) for e in frame_entries if e.matched
        )
        expected = sorted((int(r[4]), r[0], r[1]) for r in rows)
        assert [m[0] for m in matched] == [e[0] for e in expected]
        np.testing.assert_allclose([m[1:] for m in matched], [e[1:] for e in expected], atol=1e-9)
    assert_no_holes_and_one_removal(entries)
    assert any(e.state == "lost" for frame in entries for e in frame)


@pytest.mark.parametrize("seed", range(5))
def test_random_streams_never_leave_holes(seed: int) -> None:
    rng = np.random.default_rng(seed)
    frames = []
    for _ in range(120):
        n = int(rng.integers(0, 6))
        x = rng.uniform(0, 1200, n)
        y = rng.uniform(0, 650, n)
        w = rng.uniform(6, 40, n)
        frames.append(np.column_stack([x, y, x + w, y + w, rng.uniform(0.05, 1.0, n)]))
    entries, _ = run_stream(frames)
    assert_no_holes_and_one_removal(entries)


def test_a_restart_closes_every_open_id_and_never_reuses_one() -> None:
    frames = frames_with_gap(60, range(0), end=60)
    entries, _ = run_stream(frames, restart_at=30)
    before = {e.track_id for frame in entries[:30] for e in frame}
    closing = [e for e in entries[30] if e.state == "removed"]
    assert {e.track_id for e in closing} == before
    after = {e.track_id for frame in entries[31:] for e in frame}
    assert after and min(after) > max(before)
    assert_no_holes_and_one_removal(entries)


def test_class_and_bearing_ride_along_coasting_entries() -> None:
    camera = CameraModel.from_fov(SIZE[0], SIZE[1], math.radians(90))
    entries, _ = run_stream(frames_with_gap(30, range(20, 23), end=30), camera=camera)
    coasting = [e for e in entries[21] if e.state == "lost"]
    assert coasting and coasting[0].class_id == 1
    assert coasting[0].class_confidence == pytest.approx(0.8)
    assert coasting[0].bearing is not None
    ray = np.array(coasting[0].bearing.line_of_sight)
    assert np.linalg.norm(ray) == pytest.approx(1.0)
    assert coasting[0].bearing.azimuth > 0  # left half of the image: REP-103 azimuth is positive
    without_camera, _ = run_stream(frames_with_gap(5, range(0), end=5))
    assert all(e.bearing is None for frame in without_camera for e in frame)


def test_state_codes_match_the_track_message() -> None:
    text = (REPO_ROOT / "msg_defs" / "gldt_msgs" / "msg" / "Track.msg").read_text(encoding="utf-8")
    for name, code in STATE_CODES.items():
        assert f"uint8 STATE_{name.upper()} = {code}" in text


def test_a_frame_no_detector_measured_is_the_tracks_prediction_and_not_a_miss() -> None:
    """Every other frame skipped (as the graph does while the global detector is busy): the
    skipped frames hold every track at the filter's prediction for their time, in its last state,
    and the tracks come out exactly as if the skipped frames had never existed."""
    frames = [np.array([target(i), target(i, x0=700.0, vx=-60.0, y=420.0)]) for i in range(30)]
    tracker, stream = build_tracker(SystemConfig(), SIZE), PlannerStream()
    peer, peer_stream = build_tracker(SystemConfig(), SIZE), PlannerStream()
    for index, dets in enumerate(frames):
        t = index / FPS
        if index >= 10 and index % 2:
            before = [(tr.track_id, tr.state, tr.frames_since_update, tr.kf_t) for tr in tracker.tracks]
            entries = stream.predicted(tracker.tracks, t)
            assert [(tr.track_id, tr.state, tr.frames_since_update, tr.kf_t) for tr in tracker.tracks] == before
            predicted = {int(row[4]): row[:4] for row in tracker.predict(t)}
            assert {e.track_id for e in entries} == set(predicted) and len(entries) == 2
            for entry in entries:
                x1, y1, x2, y2 = predicted[entry.track_id]
                assert entry.state == "confirmed" and entry.frames_since_update == 0
                assert entry.center_x == pytest.approx((x1 + x2) / 2) and entry.width == pytest.approx(x2 - x1)
            continue
        probabilities = np.tile([0.8, 0.15, 0.05], (len(dets), 1))
        rows = np.asarray(tracker.update(dets, t), dtype=np.float64).reshape(-1, 6)
        stream.step(tracker.tracks, t, rows, dets, probabilities)
        peer_rows = np.asarray(peer.update(dets, t), dtype=np.float64).reshape(-1, 6)
        peer_stream.step(peer.tracks, t, peer_rows, dets, probabilities)
        np.testing.assert_array_equal(rows, peer_rows)


def test_a_predicted_frame_closes_the_ids_a_restart_dropped() -> None:
    tracker = build_tracker(SystemConfig(), SIZE)
    stream = PlannerStream()
    dets = np.array([target(0)])
    for index in range(3):
        rows = np.asarray(tracker.update(np.array([target(index)]), index / FPS), dtype=np.float64).reshape(-1, 6)
        stream.step(tracker.tracks, index / FPS, rows, dets, np.tile([0.8, 0.15, 0.05], (1, 1)))
    tracker.reset()
    stream.restart()
    closing = stream.predicted(tracker.tracks, 3 / FPS)
    assert [e.state for e in closing] == ["removed"]
