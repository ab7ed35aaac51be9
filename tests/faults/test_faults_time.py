"""Time faults: timestamps going backwards or repeating, a 5 s gap, 15 Hz vs 30 Hz, long silences.

What the trackers document (``gldt_core.track.base.MultiStageTracker.update`` and
``track.boxes.validate_time``): time must strictly increase; a repeated or earlier stamp is a
``ValueError`` naming the field ``t``. What the pipeline documents (``GLDTSystem``): time going
backwards (or not advancing) and a frame-size change re-initialise tracker and scheduler with
one warning; black or saturated frames are just frames. The tests check those promises plus the
properties behind them: a refused frame leaves the tracker untouched, and a track that survives
a gap is *at* its new detection (never a far extrapolation, never another object's id).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from functools import lru_cache

import numpy as np
import pytest

from gldt_core.schedule.scheduler import Mode
from gldt_core.track import ByteTrack, JPTrack, JPTrackConfig, TrackState

TRACKERS: list[Callable[[], object]] = [ByteTrack, JPTrack, lambda: JPTrack(JPTrackConfig(use_pmr=False))]
IDS = ["bytetrack", "jptrack", "jcma-only"]


def targets_at(t: float, n: int = 3, speed: float = 60.0, size: float = 24.0) -> np.ndarray:
    """``n`` well separated targets moving right at ``speed`` px/s; ``[x1, y1, x2, y2, 0.9]``."""
    rows = []
    for i in range(n):
        x, y = 200.0 + 400.0 * i + speed * t, 150.0 + 250.0 * i
        rows.append([x, y, x + size, y + 0.6 * size, 0.9])
    return np.asarray(rows)


def centres(rows: np.ndarray) -> np.ndarray:
    return np.column_stack([(rows[:, 0] + rows[:, 2]) / 2, (rows[:, 1] + rows[:, 3]) / 2])


def nearest_object(track_rows: np.ndarray, det_rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each output row: index of the nearest detection and the centre distance to it."""
    d = np.linalg.norm(centres(track_rows)[:, None, :] - centres(det_rows)[None, :, :], axis=2)
    return d.argmin(axis=1), d.min(axis=1)


def run_stream(tracker, times: np.ndarray, dets_of: Callable[[float], np.ndarray]) -> list[np.ndarray]:
    return [tracker.update(dets_of(float(t)), float(t)) for t in times]


# --------------------------------------------------------------------------- stamps out of order
@pytest.mark.parametrize("make", TRACKERS, ids=IDS)
@pytest.mark.parametrize("fault", ["backwards", "repeated"])
def test_bad_stamp_is_refused_and_leaves_the_tracker_untouched(make, fault: str) -> None:
    tracker = make()
    times = np.arange(10) / 30.0
    run_stream(tracker, times, targets_at)
    before = [(tr.track_id, tr.state, tr.kf.mean.copy(), tr.hits) for tr in tracker.tracks]
    bad_t = times[-1] - 0.5 if fault == "backwards" else times[-1]
    with pytest.raises(ValueError, match="field t") as info:
        tracker.update(targets_at(bad_t), bad_t, frame=10)
    assert "frame 10" in str(info.value)
    assert ("backwards" if fault == "backwards" else "repeated") in str(info.value)
    after = [(tr.track_id, tr.state, tr.kf.mean, tr.hits) for tr in tracker.tracks]
    assert [a[:2] for a in after] == [b[:2] for b in before]
    assert all(np.array_equal(a[2], b[2]) and a[3] == b[3] for a, b in zip(after, before))
    # the stream goes on as if the bad frame never came: same three ids, at the detections
    out = tracker.update(targets_at(times[-1] + 1 / 30), times[-1] + 1 / 30)
    assert sorted(out[:, 4].astype(int).tolist()) == [1, 2, 3]
    _, dist = nearest_object(out, targets_at(times[-1] + 1 / 30))
    assert dist.max() < 3.0


@pytest.mark.parametrize("make", TRACKERS, ids=IDS)
def test_reset_after_a_backwards_jump_starts_a_clean_stream(make) -> None:
    tracker = make()
    run_stream(tracker, np.arange(10) / 30.0, targets_at)
    tracker.reset()
    out = run_stream(tracker, np.arange(3) / 30.0, targets_at)[-1]
    assert sorted(out[:, 4].astype(int).tolist()) == [1, 2, 3]


# --------------------------------------------------------------------------- a 5 s gap
@pytest.mark.parametrize("make", TRACKERS, ids=IDS)
@pytest.mark.parametrize("motion", ["constant", "reversed"])
def test_after_a_5s_gap_tracks_are_at_their_detections_or_new(make, motion: str) -> None:
    """Targets move for 1 s, the camera delivers nothing for 5 s, then frames resume. With
    ``reversed`` the targets came back the way they went, so a constant-velocity extrapolation is
    600 px off. Every reported box must sit on a detection, and an id that continues must belong
    to the same object as before the gap."""
    tracker = make()
    before_times = np.arange(30) / 30.0
    outputs = run_stream(tracker, before_times, targets_at)
    owner = {
        int(row[4]): int(i) for i, row in zip(nearest_object(outputs[-1], targets_at(before_times[-1]))[0], outputs[-1])
    }
    assert len(owner) == 3
    old_ids = set(owner)

    def after(t: float) -> np.ndarray:
        if motion == "constant":
            return targets_at(t)
        return targets_at(2 * before_times[-1] - t)  # mirrored: moving left, back where they started

    resume = before_times[-1] + 5.0
    for t in resume + np.arange(15) / 30.0:
        dets = after(float(t))
        out = tracker.update(dets, float(t))
        if len(out) == 0:
            continue
        which, dist = nearest_object(out, dets)
        assert dist.max() < 0.5 * 24.0, f"t={t:.2f}: a track is {dist.max():.0f} px from every detection"
        for row, obj in zip(out, which):
            track_id = int(row[4])
            if track_id in old_ids:
                assert owner[track_id] == int(obj), f"id {track_id} jumped to another object after the gap"
    # all three objects are tracked again within half a second
    assert len(out) == 3
    for tr in tracker.tracks:
        assert np.all(np.isfinite(tr.kf.mean)) and np.all(np.isfinite(tr.kf.covariance))


@pytest.mark.parametrize("make", TRACKERS, ids=IDS)
def test_static_target_across_a_gap_does_not_invent_motion(make) -> None:
    tracker = make()
    box = np.array([[500.0, 400.0, 520.0, 412.0, 0.9]])
    for t in np.arange(20) / 30.0:
        tracker.update(box, float(t))
    out = tracker.update(box, 20 / 30.0 + 5.0)
    assert len(out) <= 1
    for tr in tracker.tracks:
        assert np.hypot(*tr.velocity_px_s) < 5.0, "a static target gained speed over the gap"
        assert np.allclose(tr.box_xyxy, box[0, :4], atol=2.0)
    predicted = tracker.predict(20 / 30.0 + 6.0)
    assert np.allclose(predicted[:, :4], box[0, :4], atol=5.0)


@pytest.mark.parametrize("make", TRACKERS, ids=IDS)
def test_empty_frames_during_a_gap_never_report_extrapolated_boxes(make) -> None:
    """While nothing is detected the tracker coasts internally but reports no box (no invented
    motion on the output), and lost tracks are forgotten after their memory."""
    tracker = make()
    run_stream(tracker, np.arange(30) / 30.0, targets_at)
    outputs = run_stream(tracker, 1.0 + np.arange(1, 301) / 30.0, lambda t: np.zeros((0, 5)))
    assert all(len(out) == 0 for out in outputs)
    assert all(tr.state is TrackState.LOST for tr in tracker.tracks)
    assert len(tracker.tracks) == 0, "lost tracks outlived a 10 s silence"


@pytest.mark.parametrize("make, recovers", [(TRACKERS[0], False), (TRACKERS[1], True), (TRACKERS[2], False)], ids=IDS)
@pytest.mark.parametrize("gap_s", [2.5, 6.0])
def test_missed_detections_then_return_give_recovered_or_new_ids_never_teleported(
    make, recovers: bool, gap_s: float
) -> None:
    """Frames keep coming but nothing is detected for ``gap_s``. Within PMR's memory (lost window
    1 s + 3 s) JPTrack recovers the same ids, in state RECOVERED, at the new detections;
    ByteTrack and JCMA-only (1 s buffer) and JPTrack after its memory start new ids."""
    tracker = make()
    times = np.arange(60) / 30.0
    run_stream(tracker, times, targets_at)
    t = float(times[-1])
    for _ in range(int(round(gap_s * 30))):
        t += 1 / 30
        assert len(tracker.update(np.zeros((0, 5)), t)) == 0
    seen: set[int] = set()
    for k in range(5):
        t += 1 / 30
        dets = targets_at(t)
        out = tracker.update(dets, t)
        if len(out):
            _, dist = nearest_object(out, dets)
            assert dist.max() < 3.0, f"a reported box is {dist.max():.0f} px from every detection"
        seen.update(out[:, 4].astype(int).tolist())
        if k == 0 and recovers and gap_s < 4.0:
            states = {tr.track_id: tr.state for tr in tracker.tracks}
            assert sorted(out[:, 4].astype(int).tolist()) == [1, 2, 3]
            assert all(states[i] is TrackState.RECOVERED for i in (1, 2, 3))
    expected_old = recovers and gap_s < 4.0
    assert seen == ({1, 2, 3} if expected_old else {4, 5, 6}), seen


# --------------------------------------------------------------------------- 15 Hz vs 30 Hz
def _identities(tracker, fps: float, seconds: float = 3.0) -> tuple[dict[int, set[int]], int]:
    """object index -> set of track ids reported for it; and the number of output rows."""
    ids: dict[int, set[int]] = {0: set(), 1: set(), 2: set()}
    rows = 0
    for t in np.arange(int(seconds * fps)) / fps:
        dets = targets_at(float(t), speed=90.0)
        out = tracker.update(dets, float(t))
        which, dist = nearest_object(out, dets) if len(out) else (np.zeros(0, int), np.zeros(0))
        assert np.all(dist < 3.0)
        for obj, row in zip(which, out):
            ids[int(obj)].add(int(row[4]))
        rows += len(out)
    return ids, rows


@pytest.mark.parametrize("make", TRACKERS, ids=IDS)
def test_15hz_and_30hz_streams_of_the_same_motion_give_the_same_identities(make) -> None:
    ids_30, rows_30 = _identities(make(), 30.0)
    ids_15, rows_15 = _identities(make(), 15.0)
    assert ids_30 == ids_15
    assert all(len(v) == 1 for v in ids_30.values()), f"identity switches at 30 Hz: {ids_30}"
    assert rows_15 > 0 and rows_30 > 0


@pytest.mark.parametrize("make", TRACKERS, ids=IDS)
def test_15hz_and_30hz_estimate_the_same_velocity(make) -> None:
    velocities = []
    for fps in (30.0, 15.0):
        tracker = make()
        for t in np.arange(int(2 * fps)) / fps:
            tracker.update(targets_at(float(t), speed=90.0), float(t))
        velocities.append(np.array([tr.velocity_px_s for tr in sorted(tracker.tracks, key=lambda tr: tr.track_id)]))
    assert np.allclose(velocities[0], velocities[1], atol=10.0)
    assert np.allclose(velocities[0][:, 0], 90.0, atol=10.0)


# --------------------------------------------------------------------------- the pipeline
SIZE = (1920, 1080)


@lru_cache(maxsize=2)
def _scene_gt(frames: int) -> np.ndarray:
    from gldt_core.sim import scene_ground_truth

    gt = scene_ground_truth(seed=11, frames=frames, size=SIZE, targets=3, birds=0)
    return gt[(gt[:, 7] == 1) & (gt[:, 8] > 0.3)]


class GroundTruthDetectors:
    """Global and local detector doubles that report the scene's visible drones for ``frame``
    (set by the test before each ``process``); ``silent`` frames report nothing."""

    def __init__(self, frames: int) -> None:
        self.gt = _scene_gt(frames)
        self.frame = 0
        self.silent = False
        self.scale = 1.0

    def boxes(self) -> np.ndarray:
        if self.silent:
            return np.zeros((0, 4))
        rows = self.gt[self.gt[:, 0] == self.frame + 1]
        xywh = rows[:, 2:6] * self.scale
        return np.column_stack([xywh[:, 0], xywh[:, 1], xywh[:, 0] + xywh[:, 2], xywh[:, 1] + xywh[:, 3]])

    def detect(self, previous_bgr: np.ndarray, current_bgr: np.ndarray) -> np.ndarray:
        assert previous_bgr.shape == current_bgr.shape
        boxes = self.boxes()
        return np.column_stack([boxes, np.full(len(boxes), 0.9), np.ones(len(boxes))])

    def detect_rois(self, frame_bgr: np.ndarray, rois: np.ndarray) -> np.ndarray:
        boxes = self.boxes()
        out = []
        c = centres(boxes) if len(boxes) else np.zeros((0, 2))
        for r, (x1, y1, x2, y2) in enumerate(np.asarray(rois).reshape(-1, 4)):
            inside = (c[:, 0] >= x1) & (c[:, 0] < x2) & (c[:, 1] >= y1) & (c[:, 1] < y2)
            for b in boxes[inside]:
                out.append([*b, 0.9, 1.0, float(r)])
        return np.asarray(out, dtype=np.float64).reshape(-1, 7)


def _pipeline(detectors: GroundTruthDetectors, tracker: str = "jptrack"):
    from gldt_core.system.config import SystemConfig, TrackerSettings
    from gldt_core.system.gldt_system import GLDTSystem

    config = SystemConfig(tracker=TrackerSettings(name=tracker))
    return GLDTSystem(config, global_detector=detectors, local_detector=detectors)


@pytest.mark.parametrize("tracker", ["jptrack", "bytetrack"])
def test_pipeline_survives_backwards_and_repeated_stamps_with_one_warning_each(
    tracker: str, caplog: pytest.LogCaptureFixture
) -> None:
    frames = 90
    detectors = GroundTruthDetectors(frames)
    pipeline = _pipeline(detectors, tracker)
    image = np.zeros((SIZE[1], SIZE[0], 3), np.uint8)
    stamps = list(np.arange(frames) / 30.0)
    stamps[40] = stamps[39]  # repeated
    stamps[60] = stamps[59] - 1.0  # backwards by a second
    outputs = []
    with caplog.at_level(logging.WARNING, logger="gldt.system"):
        for k, t in enumerate(stamps):
            detectors.frame = k
            outputs.append(pipeline.process(image, t))
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 2, warnings  # one per fault: frame 40 and frame 60
    assert "frame 40" in warnings[0] and "frame 60" in warnings[1]
    assert pipeline.state.reinitialisations == 2
    assert pipeline.state.frame_index == frames
    assert len(outputs[-1]) >= 2, "tracking did not resume after the time faults"


@pytest.mark.parametrize("tracker", ["jptrack", "bytetrack"])
def test_pipeline_resolution_change_mid_stream_reinitialises_once_and_keeps_tracking(
    tracker: str, caplog: pytest.LogCaptureFixture
) -> None:
    frames = 120
    detectors = GroundTruthDetectors(frames)
    pipeline = _pipeline(detectors, tracker)
    full = np.zeros((SIZE[1], SIZE[0], 3), np.uint8)
    half = np.zeros((SIZE[1] // 2, SIZE[0] // 2, 3), np.uint8)
    rows_after = 0
    with caplog.at_level(logging.WARNING, logger="gldt.system"):
        for k in range(frames):
            detectors.frame = k
            small = k >= 60
            detectors.scale = 0.5 if small else 1.0
            out = pipeline.process(half if small else full, k / 30.0)
            if k >= 60 and len(out):
                # every box reported after the change is on a detection of the new size, none is
                # a leftover of the 1080p stream
                _, dist = nearest_object(out, np.column_stack([detectors.boxes(), np.ones(len(detectors.boxes()))]))
                assert dist.max() < 10.0, f"frame {k}: track {dist.max():.0f} px from every detection"
                rows_after += len(out)
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "1920x1080" in warnings[0] and "960x540" in warnings[0]
    assert pipeline.state.reinitialisations == 1 and pipeline.state.frame_size == (960, 540)
    assert rows_after >= frames - 60, "tracking did not resume after the resolution change"


def test_pipeline_on_black_and_saturated_frames_and_a_long_silence(caplog: pytest.LogCaptureFixture) -> None:
    """Detections stop for 10 s (300 frames) while frames alternate black/white: no tracks are
    invented, the track table empties, GD takes over; when targets return they are tracked again."""
    frames = 420
    detectors = GroundTruthDetectors(frames)
    pipeline = _pipeline(detectors)
    black = np.zeros((SIZE[1], SIZE[0], 3), np.uint8)
    white = np.full((SIZE[1], SIZE[0], 3), 255, np.uint8)
    table_sizes = []
    modes = []
    with caplog.at_level(logging.WARNING, logger="gldt.system"):
        for k in range(frames):
            detectors.frame = k
            detectors.silent = 60 <= k < 360
            out = pipeline.process(black if k % 2 else white, k / 30.0)
            if detectors.silent:
                assert len(out) == 0, f"frame {k}: a track was reported with no detection"
                modes.append(pipeline.state.mode)
            table_sizes.append(len(pipeline.tracker.tracks))
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert table_sizes[359] == 0, "lost tracks were never forgotten"
    assert max(table_sizes) <= 6
    n_miss = pipeline.config.scheduler.n_miss
    assert all(m is Mode.GLOBAL for m in modes[n_miss + 2 :]), "LD kept searching empty windows through the silence"
    assert len(out) >= 2, "targets were not tracked again after the silence"


def test_stamp_order_drops_late_messages_and_resets_only_on_a_real_restart() -> None:
    """The tracker node's policy: one very late message (overloaded graph) never resets the tracks;
    a stream that went back in time for several messages in a row did restart."""
    from gldt_core.system.stamps import StaleMessage, StampOrder

    order = StampOrder(stale_window_s=1.0, restart_after=3)
    assert order.check(10.0, 0) is False
    order.accept(10.0)
    with pytest.raises(StaleMessage, match="frame 1 stamped 9.900 s"):
        order.check(9.9, 1)  # late within the window
    for _ in range(2):
        with pytest.raises(StaleMessage, match="in a row"):
            order.check(5.0, 2)  # far behind, but maybe just very late
    assert order.check(10.1, 3) is False  # something newer: the run of old stamps is broken
    order.accept(10.1)
    for _ in range(2):
        with pytest.raises(StaleMessage):
            order.check(0.5, 4)
    assert order.check(0.5, 4) is True  # third in a row: the stream restarted
    assert order.last_stamp is None and order.check(0.6, 5) is False
