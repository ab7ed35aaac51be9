"""GLDTSystem wiring with test doubles: detectors that report ground truth, a tiny tracker.

The doubles are deliberately simple so the assertions are about the pipeline's own logic:
which detector runs when, on which frame pair, with which ROIs, and how bad input is handled.
Each synthetic frame carries its own index in pixel (0, 0) so a detector double can tell
exactly which frames it was handed.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import pytest

from gldt_core.schedule.scheduler import Mode, SchedulerConfig
from gldt_core.system.config import SystemConfig
from gldt_core.system.gldt_system import GLDTSystem

FPS = 30.0
DRONE, BIRD = 1, 2  # MOTChallenge class codes the detectors report


def stamp_frame(index: int, size=(1920, 1080), value: int = 0) -> np.ndarray:
    frame = np.full((size[1], size[0], 3), value, dtype=np.uint8)
    frame[0, 0, 0] = index % 256
    frame[0, 0, 1] = index // 256
    return frame


def frame_index_of(frame: np.ndarray) -> int:
    return int(frame[0, 0, 0]) + 256 * int(frame[0, 0, 1])


class Scene:
    """Targets moving at constant velocity; ``boxes(k)`` -> (K, 4) boxes visible at frame k."""

    def __init__(self, starts, velocities, size=20.0, frame_size=(1920, 1080), visible=None):
        self.starts = np.asarray(starts, dtype=float)
        self.velocities = np.asarray(velocities, dtype=float)
        self.size = size
        self.frame_size = frame_size
        self.visible = visible or (lambda k, i: True)

    def boxes(self, k: int) -> np.ndarray:
        centres = self.starts + self.velocities * k
        out = []
        for i, (cx, cy) in enumerate(centres):
            if self.visible(k, i) and 0 <= cx < self.frame_size[0] and 0 <= cy < self.frame_size[1]:
                out.append([cx - self.size / 2, cy - self.size / 2, cx + self.size / 2, cy + self.size / 2])
        return np.array(out, dtype=float).reshape(-1, 4)


@dataclass
class GroundTruthGlobal:
    """Reports every visible target; records the frame pairs it was given."""

    scene: Scene
    pairs: list = field(default_factory=list)

    def detect(self, previous_bgr, current_bgr):
        prev, cur = frame_index_of(previous_bgr), frame_index_of(current_bgr)
        self.pairs.append((prev, cur))
        boxes = self.scene.boxes(cur)
        return np.hstack([boxes, np.full((len(boxes), 1), 0.9), np.full((len(boxes), 1), DRONE)])


@dataclass
class GroundTruthLocal:
    """Reports the targets whose centre lies in an ROI, tagged with that ROI's index."""

    scene: Scene
    calls: list = field(default_factory=list)

    def detect_rois(self, frame_bgr, rois):
        cur = frame_index_of(frame_bgr)
        rois = np.asarray(rois).reshape(-1, 4)
        self.calls.append((cur, rois.copy()))
        rows = []
        for box in self.scene.boxes(cur):
            cx, cy = (box[0] + box[2]) / 2, (box[1] + box[3]) / 2
            for r, (x1, y1, x2, y2) in enumerate(rois):
                if x1 <= cx < x2 and y1 <= cy < y2:
                    rows.append([*box, 0.95, DRONE, r])
                    break
        return np.array(rows, dtype=float).reshape(-1, 7)


@dataclass
class _Track:
    track_id: int
    box_xyxy: np.ndarray
    velocity_px_s: np.ndarray
    last_t: float
    hits: int = 1
    frames_since_update: int = 0
    score: float = 0.0

    @property
    def state(self) -> str:
        if self.frames_since_update > 0:
            return "LOST"
        return "CONFIRMED" if self.hits >= 3 else "TENTATIVE"

    def box_at(self, t: float) -> np.ndarray:
        dt = t - self.last_t
        return self.box_xyxy + np.tile(self.velocity_px_s, 2) * dt


class NearestTracker:
    """Greedy nearest-centre tracker with constant-velocity prediction (a test double)."""

    def __init__(self, gate_px: float = 60.0, max_lost: int = 30) -> None:
        self.gate_px = gate_px
        self.max_lost = max_lost
        self.reset()

    def reset(self) -> None:
        self.tracks: list[_Track] = []
        self._next_id = 1

    def predict(self, t: float) -> np.ndarray:
        return np.array([[*tr.box_at(t), tr.track_id] for tr in self.tracks], dtype=float).reshape(-1, 5)

    def update(self, dets: np.ndarray, t: float) -> np.ndarray:
        dets = np.asarray(dets, dtype=float).reshape(-1, 5)
        unmatched = list(range(len(dets)))
        out = []
        for tr in self.tracks:
            pred = tr.box_at(t)
            pc = (pred[:2] + pred[2:]) / 2
            best, best_d = None, self.gate_px
            for j in unmatched:
                dc = (dets[j, :2] + dets[j, 2:4]) / 2
                d = float(np.linalg.norm(dc - pc))
                if d < best_d:
                    best, best_d = j, d
            if best is None:
                tr.frames_since_update += 1
                continue
            unmatched.remove(best)
            dt = max(t - tr.last_t, 1e-6)
            new_c = (dets[best, :2] + dets[best, 2:4]) / 2
            old_c = (tr.box_xyxy[:2] + tr.box_xyxy[2:]) / 2
            tr.velocity_px_s = (new_c - old_c) / dt
            tr.box_xyxy, tr.last_t, tr.score = dets[best, :4].copy(), t, float(dets[best, 4])
            tr.hits += 1
            tr.frames_since_update = 0
            if tr.hits >= 3:
                out.append([*tr.box_xyxy, tr.track_id, tr.score])
        for j in unmatched:
            self.tracks.append(_Track(self._next_id, dets[j, :4].copy(), np.zeros(2), t, score=float(dets[j, 4])))
            self._next_id += 1
        self.tracks = [tr for tr in self.tracks if tr.frames_since_update <= self.max_lost]
        return np.array(out, dtype=float).reshape(-1, 6)


def make_pipeline(scene: Scene, **scheduler_kwargs):
    config = SystemConfig(scheduler=SchedulerConfig(**scheduler_kwargs))
    gd, ld, tracker = GroundTruthGlobal(scene), GroundTruthLocal(scene), NearestTracker()
    return GLDTSystem(config, global_detector=gd, local_detector=ld, tracker=tracker), gd, ld, tracker


def run(pipeline: GLDTSystem, frames: range, size=(1920, 1080), t_of=lambda k: k / FPS):
    modes, outputs = [], []
    for k in frames:
        outputs.append(pipeline.process(stamp_frame(k, size), t_of(k)))
        modes.append(pipeline.state.mode)
    return modes, outputs


def test_schedule_follows_n_global_and_n_local_with_one_steady_target():
    scene = Scene([[300, 500]], [[4, 1]])
    pipeline, gd, ld, _ = make_pipeline(scene, n_global=30, n_local=120)
    modes, outputs = run(pipeline, range(301))
    assert modes[:30] == [Mode.GLOBAL] * 30
    assert modes[30:150] == [Mode.LOCAL] * 120
    assert modes[150:180] == [Mode.GLOBAL] * 30
    assert modes[180:300] == [Mode.LOCAL] * 120
    assert pipeline.state.global_frames == 61 and pipeline.state.local_frames == 240
    assert pipeline.global_share == pytest.approx(61 / 301)
    # One identity for the whole run, and the LD detector was called once per LD frame.
    ids = {int(row[4]) for out in outputs for row in out}
    assert ids == {1}
    assert len(ld.calls) == 240 and len(gd.pairs) == 61


def test_every_gd_frame_gets_the_true_previous_frame_even_after_ld():
    scene = Scene([[300, 500]], [[3, 0]])
    pipeline, gd, _, _ = make_pipeline(scene, n_global=5, n_local=10)
    run(pipeline, range(60))
    assert gd.pairs[0] == (0, 0)  # first frame: no predecessor, paired with itself
    assert all(prev == cur - 1 for prev, cur in gd.pairs[1:])
    gd_frames = [cur for _, cur in gd.pairs]
    assert 15 in gd_frames  # the first GD frame after the first LD stretch (5 GD + 10 LD)


def test_ld_rois_are_batched_and_contain_the_predicted_targets():
    scene = Scene([[300, 300], [1500, 800], [340, 320]], [[2, 0], [-2, 0], [2, 0]])
    pipeline, _, ld, _ = make_pipeline(scene, n_global=5)
    run(pipeline, range(40))
    assert ld.calls
    for frame, rois in ld.calls:
        boxes = scene.boxes(frame)
        # The two close targets share a window; the far one has its own.
        assert len(rois) == 2
        for box in boxes:
            cx, cy = (box[0] + box[2]) / 2, (box[1] + box[3]) / 2
            assert any(x1 <= cx < x2 and y1 <= cy < y2 for x1, y1, x2, y2 in rois)


def test_target_leaving_sends_ld_back_to_gd_after_n_miss_frames():
    # Target vanishes at frame 50 (in LD since frame 10).
    scene = Scene([[900, 500]], [[1, 0]], visible=lambda k, i: k < 50)
    pipeline, _, _, _ = make_pipeline(scene, n_global=10, n_local=200, n_miss=5)
    modes, _ = run(pipeline, range(70))
    assert modes[10:55] == [Mode.LOCAL] * 45  # frames 50..54: five misses
    assert modes[55] is Mode.GLOBAL
    assert all(m is Mode.GLOBAL for m in modes[55:])


def test_gd_only_configuration_never_calls_the_local_detector():
    scene = Scene([[300, 500]], [[4, 1]])
    pipeline, gd, ld, _ = make_pipeline(scene, local_enabled=False)
    modes, _ = run(pipeline, range(100))
    assert modes == [Mode.GLOBAL] * 100 and not ld.calls and len(gd.pairs) == 100


def test_frame_size_change_reinitialises_and_warns(caplog):
    scene = Scene([[300, 200]], [[1, 1]], frame_size=(640, 512))
    pipeline, gd, _, tracker = make_pipeline(scene, n_global=3)
    run(pipeline, range(10), size=(1920, 1080))
    with caplog.at_level(logging.WARNING, logger="gldt.system"):
        modes, outputs = run(pipeline, range(10, 30), size=(640, 512))
    assert any("frame size changed from 1920x1080 to 640x512" in r.getMessage() for r in caplog.records)
    state = pipeline.state
    assert state.reinitialisations == 1 and state.frame_size == (640, 512)
    assert modes[0] is Mode.GLOBAL
    # The first frame after the change is paired with itself, never with a 1080p frame.
    assert (10, 10) in gd.pairs
    assert outputs[-1].shape[1] == 6 and len(outputs[-1]) == 1


def test_time_going_backwards_reinitialises(caplog):
    scene = Scene([[300, 500]], [[1, 0]])
    pipeline, _, _, _ = make_pipeline(scene, n_global=3)
    run(pipeline, range(5))
    with caplog.at_level(logging.WARNING, logger="gldt.system"):
        pipeline.process(stamp_frame(5), 0.0)
    assert pipeline.state.reinitialisations == 1
    assert any("time did not advance (0.133 s -> 0.000 s)" in r.getMessage() for r in caplog.records)


def test_dropped_frames_are_counted_and_tracking_continues():
    scene = Scene([[300, 500]], [[3, 0]])
    pipeline, _, _, _ = make_pipeline(scene, n_global=3)
    frames = [k for k in range(80) if not 40 <= k < 46]  # six frames lost in LD
    modes, outputs = run(pipeline, frames)
    assert pipeline.state.dropped_frame_gaps == 1
    ids = {int(row[4]) for out in outputs for row in out}
    assert ids == {1}


def test_black_saturated_and_empty_frames_keep_running():
    scene = Scene([[300, 500]], [[1, 0]], visible=lambda k, i: False)
    pipeline, gd, _, _ = make_pipeline(scene, n_global=3)
    for k in range(200):
        out = pipeline.process(stamp_frame(k, value=255 if k % 2 else 0), k / FPS)
        assert out.shape == (0, 6)
    assert pipeline.state.mode is Mode.GLOBAL and len(gd.pairs) == 200


def test_bad_frames_raise_value_error_naming_the_frame():
    scene = Scene([[300, 500]], [[1, 0]])
    pipeline, _, _, _ = make_pipeline(scene)
    pipeline.process(stamp_frame(0), 0.0)
    with pytest.raises(ValueError, match="frame 1"):
        pipeline.process(np.zeros((1080, 1920, 3), dtype=np.float32), 0.1)
    with pytest.raises(ValueError, match="frame 1.*timestamp"):
        pipeline.process(stamp_frame(1), float("nan"))


def test_stage_timings_cover_gd_ld_and_tracking():
    scene = Scene([[300, 500]], [[2, 0]])
    pipeline, _, _, _ = make_pipeline(scene, n_global=5)
    run(pipeline, range(30))
    calls = pipeline.timer.calls
    assert calls["gd"] == 5 and calls["ld"] == 25 and calls["tracking"] == 30 and calls["preprocess"] == 30
    names = [row[0] for row in pipeline.timer.breakdown(30)]
    assert names[:4] == ["preprocess", "gd", "ld", "tracking"]


def test_local_enabled_without_local_detector_is_refused():
    scene = Scene([[300, 500]], [[2, 0]])
    with pytest.raises(ValueError, match="no local detector"):
        GLDTSystem(SystemConfig(), global_detector=GroundTruthGlobal(scene), tracker=NearestTracker())


def test_run_frames_collects_mot_rows_modes_and_decode_time():
    from gldt_core.system.runner import SimpleFrame, run_frames

    scene = Scene([[300, 500]], [[4, 1]])
    pipeline, _, _, _ = make_pipeline(scene, n_global=10, n_local=20)
    gt = np.array([[k + 1, 1, *scene.boxes(k)[0][:2], 20, 20, 1, 1, 1, -1] for k in range(50)])
    frames = (SimpleFrame(k, k / FPS, stamp_frame(k), gt[k : k + 1]) for k in range(50))
    result = run_frames(pipeline, frames, collect_ground_truth=True, max_frames=45)
    assert result.frames == 45
    assert result.modes.tolist() == [True] * 10 + [False] * 20 + [True] * 10 + [False] * 5
    assert result.global_share == pytest.approx(20 / 45)
    # Tracks appear once confirmed (3rd hit), numbered 1-based like the ground truth.
    assert result.rows[:, 0].min() == 3 and result.rows[:, 0].max() == 45
    np.testing.assert_allclose(result.rows[result.rows[:, 0] == 20, 2:6], gt[19:20, 2:6])
    assert result.ground_truth.shape == (45, 10)
    assert "decode" in result.stage_ms and pipeline.timer.calls["decode"] == 45


def test_interleaved_runs_give_each_pipeline_what_a_run_of_its_own_gives():
    """run_frames_interleaved takes turns frame by frame and changes no pipeline's results."""
    from gldt_core.system.runner import SimpleFrame, run_frames, run_frames_interleaved

    scene = Scene([[300, 500], [1400, 700]], [[4, 1], [-3, 2]])

    def frames():
        return (SimpleFrame(k, k / FPS, stamp_frame(k)) for k in range(60))

    def pipelines():
        return [
            make_pipeline(scene, n_global=10, n_local=20)[0],
            make_pipeline(scene, n_global=5, local_enabled=False)[0],
        ]

    alone = [run_frames(pipeline, frames()) for pipeline in pipelines()]
    turns: list[tuple[int, int]] = []
    callbacks = [lambda frame, _tracks, i=i: turns.append((i, int(frame.index))) for i in range(2)]
    interleaved_pipelines = pipelines()
    together = run_frames_interleaved(interleaved_pipelines, frames(), on_frame=callbacks)
    assert turns == [(i, k) for k in range(60) for i in range(2)]
    for own, shared, pipeline in zip(alone, together, interleaved_pipelines):
        np.testing.assert_array_equal(shared.rows, own.rows)
        assert shared.modes.tolist() == own.modes.tolist() and shared.frames == own.frames == 60
        # Each frame is decoded once, and that time is booked to every pipeline.
        assert pipeline.timer.calls["decode"] == 60 and shared.seconds > 0
    assert together[0].global_share == pytest.approx(20 / 60) and together[1].global_share == 1.0
    with pytest.raises(ValueError, match="2 on_frame callbacks for 1 systems"):
        run_frames_interleaved(pipelines()[:1], frames(), on_frame=callbacks)


@pytest.mark.slow
def test_resident_memory_is_flat_over_ten_thousand_frames():
    """Issue 7: RSS must not grow beyond 5 % over 10,000 frames (targets come and go)."""
    import psutil

    # Three targets that wrap around the frame, each visible 80 % of the time.
    size = (640, 512)
    scene = Scene(
        [[50, 100], [600, 300], [300, 450]],
        [[3, 0.5], [-2, 0], [1, -1]],
        frame_size=size,
        visible=lambda k, i: (k // 97 + i) % 5 != 0,
    )

    class Wrapped(Scene):
        def boxes(self, k):
            return Scene.boxes(self, k % 150)

    wrapped = Wrapped(scene.starts, scene.velocities, frame_size=size, visible=scene.visible)
    # The shipped JPTrack (PMR memories, histories) is part of what must stay flat.
    pipeline = GLDTSystem(
        SystemConfig(), global_detector=GroundTruthGlobal(wrapped), local_detector=GroundTruthLocal(wrapped)
    )
    process = psutil.Process()
    frame_buffer = stamp_frame(0, size)

    def run(start: int, stop: int) -> None:
        # Output is dropped: the point is the pipeline's own state, not a growing result list.
        for k in range(start, stop):
            frame_buffer[0, 0, 0], frame_buffer[0, 0, 1] = k % 256, k // 256
            pipeline.process(frame_buffer, k / FPS)

    run(0, 1000)
    baseline = process.memory_info().rss
    run(1000, 10000)
    assert pipeline.state.frame_index == 10000
    assert pipeline.state.local_frames > 5000  # the LD path was exercised, not just GD
    assert process.memory_info().rss <= baseline * 1.05


@pytest.mark.parametrize("tracker_name", ["jptrack", "bytetrack"])
def test_real_trackers_keep_one_identity_through_gd_ld_switches(tracker_name):
    """With perfect detections the shipped trackers must keep ids across every mode switch."""
    scene = Scene([[200, 300], [1700, 700]], [[5, 1], [-1, -1]])  # >500 px apart throughout
    config = SystemConfig(scheduler=SchedulerConfig(n_global=10, n_local=40)).with_changes(tracker=tracker_name)
    gd, ld = GroundTruthGlobal(scene), GroundTruthLocal(scene)
    pipeline = GLDTSystem(config, global_detector=gd, local_detector=ld)
    modes, outputs = run(pipeline, range(160))
    # 160 frames = 3 full cycles of 10 GD + 40 LD, then 10 GD.
    assert modes.count(Mode.GLOBAL) == 4 * 10 and modes.count(Mode.LOCAL) == 3 * 40
    final = outputs[-1]
    assert len(final) == 2
    assert {int(i) for out in outputs for i in out[:, 4]} == {int(i) for i in final[:, 4]}
    # Two separate ROIs in LD (the targets are far apart), each fed to the tracker.
    assert all(len(rois) == 2 for _, rois in ld.calls)
    assert pipeline.tracker.__class__.__name__.lower() == tracker_name


def test_bad_roi_index_from_local_detector_is_reported():
    scene = Scene([[300, 500]], [[1, 0]])

    class BadLocal(GroundTruthLocal):
        def detect_rois(self, frame_bgr, rois):
            out = super().detect_rois(frame_bgr, rois)
            out[:, 6] = 5
            return out

    config = SystemConfig(scheduler=SchedulerConfig(n_global=3))
    pipeline = GLDTSystem(
        config, global_detector=GroundTruthGlobal(scene), local_detector=BadLocal(scene), tracker=NearestTracker()
    )
    with pytest.raises(ValueError, match="roi_index"):
        run(pipeline, range(10))


def test_unknown_tracker_params_fail_at_construction():
    from gldt_core.system.config import TrackerSettings

    config = SystemConfig(tracker=TrackerSettings(name="jptrack", params={"gama": 0.2}))
    scene = Scene([[300, 500]], [[1, 0]])
    with pytest.raises(ValueError, match="unknown jptrack parameter.*gama"):
        GLDTSystem(config, global_detector=GroundTruthGlobal(scene), local_detector=GroundTruthLocal(scene))


class ScriptedSequence:
    """A sequence for the ablation: stamped frames (:func:`stamp_frame`) and the given ground truth."""

    fps = FPS

    def __init__(self, name: str, gt: np.ndarray, frames: int) -> None:
        self.name, self.gt, self.frames = name, gt, frames

    def __len__(self) -> int:
        return self.frames

    def __iter__(self):
        from gldt_core.system.runner import SimpleFrame

        return (SimpleFrame(k, k / FPS, stamp_frame(k)) for k in range(self.frames))


def scene_ground_truth(scene: Scene, frames: int) -> np.ndarray:
    """MOT ground-truth rows of the scene's targets over its first ``frames`` frames."""
    return np.array(
        [
            [k + 1, i + 1, b[0], b[1], b[2] - b[0], b[3] - b[1], 1, 1, 1, -1]
            for k in range(frames)
            for i, b in enumerate(scene.boxes(k))
        ]
    )


def test_ablation_runs_four_variants_on_shared_detectors():
    from gldt_core.bench.ablation import VARIANTS, format_table, run_dataset

    scene = Scene([[200, 300], [1500, 800]], [[4, 1], [-3, 0]])
    frames = 80
    gt = scene_ground_truth(scene, frames)

    gd, ld = GroundTruthGlobal(scene), GroundTruthLocal(scene)
    config = SystemConfig(scheduler=SchedulerConfig(n_global=10, n_local=30))
    rows = run_dataset([ScriptedSequence("doubles", gt, frames)], config, (gd, ld))
    assert [r["variant"] for r in rows] == [v[0] for v in VARIANTS]
    by_name = {r["variant"]: r for r in rows}
    assert by_name["GD+JPTrack"]["gd_share"] == 1.0 and by_name["GD+ByteTrack"]["gd_share"] == 1.0
    # 80 frames of 10 GD + 30 LD: 20 GD frames.
    assert by_name["GD+LD+JPTrack"]["gd_share"] == pytest.approx(20 / 80)
    assert "ld" in by_name["GD+LD+JPTrack"]["stage_ms"] and "ld" not in by_name["GD+JPTrack"]["stage_ms"]
    # Perfect detections: every variant tracks both targets without a switch (tracks start
    # after confirmation, so MOTA stays a little under 100).
    for row in rows:
        assert row["IDSW"] == 0 and row["MOTA"] > 90.0 and row["frames"] == frames
    # 10 GD frames of search, then LD until N_l = 30 sends it back once (frames 41-50 are GD).
    assert by_name["GD+LD+JPTrack"]["search_gd_frames"] == 10
    assert by_name["GD+LD+JPTrack"]["back_to_gd"] == {"LD ran 30 frames": 1}
    # The ROIs follow both targets on every LD frame; GD-only rows have no coverage figure.
    assert by_name["GD+LD+JPTrack"]["roi_coverage"] == 1.0 and by_name["GD+JPTrack"]["roi_coverage"] is None
    # GD frames: 4 variants; LD frames only for the two GD+LD variants.
    assert len(gd.pairs) == 2 * frames + 2 * 20 and len(ld.calls) == 2 * 60
    table = format_table("doubles", rows)
    assert "GD+LD+JPTrack vs GD+JPTrack" in table and "speed x" in table
    assert "20, of which 10 before a sequence's first LD frame; back from LD to GD: 1x LD ran 30 frames" in table
    # One clip: its own figures are the totals, and the table lists it.
    for row in rows:
        assert list(row["per_clip"]) == ["doubles"]
        for key in ("IDF1", "MOTA", "HOTA", "IDSW"):
            assert row["per_clip"]["doubles"][key] == pytest.approx(row[key])
    assert "per clip, worst IDF1 margin first: GD+LD+JPTrack vs GD+LD+ByteTrack" in table


def test_ablation_runs_only_the_variants_asked_for_with_the_same_figures():
    """``--variants GD+LD+JPTrack``: the shipped system alone, for its accuracy at a fraction of the
    cost; its row is the one the four-variant run gives, and the table leaves out the comparisons
    it has no peer for."""
    from gldt_core.bench.ablation import GLDT, format_table, parse_variants, run_dataset

    scene = Scene([[200, 300], [1500, 800]], [[4, 1], [-3, 0]])
    frames = 60
    gt = scene_ground_truth(scene, frames)
    config = SystemConfig(scheduler=SchedulerConfig(n_global=10, n_local=30))
    all_rows = run_dataset(
        [ScriptedSequence("doubles", gt, frames)], config, (GroundTruthGlobal(scene), GroundTruthLocal(scene))
    )
    gd, ld = GroundTruthGlobal(scene), GroundTruthLocal(scene)
    alone = run_dataset([ScriptedSequence("doubles", gt, frames)], config, (gd, ld), variants=parse_variants(GLDT))
    assert [row["variant"] for row in alone] == [GLDT]
    full = {row["variant"]: row for row in all_rows}[GLDT]
    for key in ("IDSW", "IDF1", "MOTA", "MOTP", "HOTA", "gd_frames", "search_gd_frames", "back_to_gd", "FN", "FP"):
        assert alone[0][key] == full[key], key
    assert len(gd.pairs) == 20  # 60 frames of 10 GD + 30 LD: one system's GD frames only
    table = format_table("doubles", alone)
    assert "GD frames: 20, of which 10" in table and "speed x" not in table and "per clip" not in table
    assert parse_variants(None) == ("GD+ByteTrack", "GD+LD+ByteTrack", "GD+JPTrack", "GD+LD+JPTrack")
    assert parse_variants("GD+LD+JPTrack, GD+JPTrack") == ("GD+JPTrack", "GD+LD+JPTrack")  # the paper's order
    for bad in ("GD+LD", ""):
        with pytest.raises(ValueError, match="^--variants .*: expected labels among GD\\+ByteTrack"):
            parse_variants(bad)


def test_ablation_reads_each_row_again_at_a_loose_iou_too():
    """Boxes tight around targets annotated 1.6x as large (IoU 0.39): at 0.5 each is a miss and a
    false positive, at the loose IoU (0.3) a match; the table says both."""
    from gldt_core.bench.ablation import format_table, run_dataset
    from gldt_core.eval.halmstad_split import LOOSE_IOU

    scene = Scene([[200, 300], [1500, 800]], [[4, 1], [-3, 0]])
    frames = 40

    def loose(b: np.ndarray) -> list[float]:
        cx, cy, w, h = (b[0] + b[2]) / 2, (b[1] + b[3]) / 2, 1.6 * (b[2] - b[0]), 1.6 * (b[3] - b[1])
        return [cx - w / 2, cy - h / 2, w, h]

    gt = np.array(
        [
            [k + 1, i + 1, *loose(np.asarray(b)), 1, 1, 1, -1]
            for k in range(frames)
            for i, b in enumerate(scene.boxes(k))
        ]
    )

    config = SystemConfig(scheduler=SchedulerConfig(n_global=10, n_local=30))
    sequence = ScriptedSequence("loose", gt, frames)
    rows = run_dataset([sequence], config, (GroundTruthGlobal(scene), GroundTruthLocal(scene)))
    ours = {r["variant"]: r for r in rows}["GD+LD+JPTrack"]
    assert LOOSE_IOU < 1 / 1.6**2 < 0.5
    assert ours["MOTA"] < 0.0 and ours["FN"] > 0 and ours["FP"] > 0
    assert ours["at_loose_iou"]["threshold"] == LOOSE_IOU and ours["at_loose_iou"]["MOTA"] > 90.0
    assert ours["at_loose_iou"]["FP"] == 0
    assert f"GD+LD+JPTrack at IoU {LOOSE_IOU:g} (loose ground-truth boxes): MOTA" in format_table("loose", rows)


def test_ablation_per_clip_lines_put_the_clips_a_variant_loses_first():
    from gldt_core.bench.ablation import per_clip_lines

    def clip(idf1: float, idsw: int) -> dict:
        return {"IDF1": idf1, "HOTA": idf1 - 10.0, "IDSW": idsw, "MOTA": 50.0, "MOTP": 70.0}

    ours = {"variant": "A", "per_clip": {"V_1": clip(90.0, 0), "V_2": clip(60.0, 3), "V_3": clip(80.0, 1)}}
    peer = {"variant": "B", "per_clip": {"V_1": clip(85.0, 1), "V_2": clip(70.0, 0), "V_3": clip(80.5, 1)}}
    lines = per_clip_lines(ours, peer)
    assert [line.split()[0] for line in lines[2:5]] == ["V_2", "V_3", "V_1"]  # margins -10, -0.5, +5
    assert lines[-1] == "A has the lower IDF1 on 2 of 3 clips"
    assert per_clip_lines({"variant": "A"}, peer) == []  # rows from before per-clip figures


def test_ablation_plays_each_sequence_once_for_all_four_variants():
    """The variants take turns frame by frame on one playback of each sequence, so a drift of the
    machine's speed during the run cannot favour the variants that happened to run first."""
    from gldt_core.bench.ablation import VARIANTS, run_dataset
    from gldt_core.system.runner import SimpleFrame

    scene = Scene([[400, 300]], [[2, 1]])
    frames = 20
    gt = np.array([[k + 1, 1, *scene.boxes(k)[0][:2], 20, 20, 1, 1, 1, -1] for k in range(frames)])
    started: list[str] = []

    class Sequence:
        fps = FPS

        def __init__(self, name: str) -> None:
            self.name, self.gt = name, gt

        def __len__(self) -> int:
            return frames

        def __iter__(self):
            started.append(self.name)
            return (SimpleFrame(k, k / FPS, stamp_frame(k)) for k in range(frames))

    config = SystemConfig(scheduler=SchedulerConfig(n_global=5, n_local=10))
    rows = run_dataset(
        [Sequence("first"), Sequence("second")], config, (GroundTruthGlobal(scene), GroundTruthLocal(scene))
    )
    assert started == ["first", "second"]
    assert [row["variant"] for row in rows] == [v[0] for v in VARIANTS]
    assert all(row["frames"] == 2 * frames for row in rows)


def test_only_configured_classes_reach_the_tracker():
    scene = Scene([[300, 500], [900, 500]], [[2, 0], [2, 0]])

    class BirdToo(GroundTruthGlobal):
        def detect(self, previous_bgr, current_bgr):
            out = super().detect(previous_bgr, current_bgr)
            out[1:, 5] = BIRD  # the second target is a bird
            return out

    config = SystemConfig(scheduler=SchedulerConfig(local_enabled=False))
    pipeline = GLDTSystem(config, global_detector=BirdToo(scene), tracker=NearestTracker())
    _, outputs = run(pipeline, range(10))
    assert {len(out) for out in outputs[3:]} == {1}
    assert pipeline.state.detections.shape == (1, 5)
    assert outputs[-1][0, 0] < 600  # the drone, not the bird at x=900+


def test_invalid_detections_are_dropped_and_counted():
    scene = Scene([[300, 500]], [[2, 0]])

    class Faulty(GroundTruthGlobal):
        def detect(self, previous_bgr, current_bgr):
            good = super().detect(previous_bgr, current_bgr)
            bad = np.array([[np.nan, 1, 5, 5, 0.9, DRONE], [50, 50, 40, 60, 0.9, DRONE]])
            return np.vstack([good, bad])

    config = SystemConfig(scheduler=SchedulerConfig(local_enabled=False))
    pipeline = GLDTSystem(config, global_detector=Faulty(scene), tracker=NearestTracker())
    _, outputs = run(pipeline, range(6))
    assert pipeline.state.invalid_detections == 12
    assert len(outputs[-1]) == 1 and np.all(np.isfinite(pipeline.state.detections))


def test_false_drone_tracks_lists_each_track_with_what_its_detections_said():
    """A clip "without drones" whose two objects the detectors call drones: both tracks are listed,
    their rows add up to the clip's count, and their evidence is the detectors' (one-hot) drone."""
    from gldt_core.bench.ablation import false_drone_tracks, format_false_drone_tracks

    scene = Scene([[200, 300], [1500, 800]], [[4, 1], [-3, 0]])
    frames = 40
    config = SystemConfig(scheduler=SchedulerConfig(n_global=10, n_local=30))
    detectors = (GroundTruthGlobal(scene), GroundTruthLocal(scene))
    by_clip, counted, tracks = false_drone_tracks(
        [ScriptedSequence("V_AIRPLANE_X", np.zeros((0, 10)), frames)], config, detectors
    )
    assert counted == frames
    assert len(tracks) == 2 and {t["clip"] for t in tracks} == {"V_AIRPLANE_X"}
    assert sum(t["rows"] for t in tracks) == by_clip["V_AIRPLANE_X"] > frames
    assert all(t["mean_probabilities"] == [1.0, 0.0, 0.0] for t in tracks)
    line = format_false_drone_tracks(tracks)
    assert line.startswith("false drone tracks (mean P drone/bird/airplane of their detections): V_AIRPLANE_X #")
    assert line.count("rows 1.00/0.00/0.00") == 2
    assert format_false_drone_tracks([]).endswith(": none")
    assert format_false_drone_tracks([{"clip": "c", "track_id": 4, "rows": 3, "mean_probabilities": None}]).endswith(
        "c #4 3 rows no class evidence"
    )


def test_a_tracks_evidence_is_kept_as_it_was_when_last_reported():
    """ClassEvidence forgets a track some time after its last report; the ablation's list does not."""
    from gldt_core.bench.ablation import LastClassEvidence
    from gldt_core.track.class_evidence import ClassEvidence

    evidence = ClassEvidence(forget_after_frames=2)
    last = LastClassEvidence(evidence)
    track = np.array([[100, 100, 120, 115, 7, 0.8]])
    evidence.update(track, track[:, :5], np.array([[0.2, 0.1, 0.7]]))
    last.note(None, track)
    for _ in range(4):
        evidence.update(np.zeros((0, 6)), np.zeros((0, 5)), np.zeros((0, 3)))
        last.note(None, np.zeros((0, 6)))
    assert evidence.probabilities(7) is None
    np.testing.assert_allclose(last.probabilities(7), [0.2, 0.1, 0.7])
    assert last.probabilities(8) is None
