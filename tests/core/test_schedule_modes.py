"""The GD/LD mode state machine: N_g, N_l, N_m and the ROI plans it hands out."""

from __future__ import annotations

import numpy as np
import pytest

from gldt_core.schedule.scheduler import Mode, ModeScheduler, SchedulerConfig

SIZE = (1920, 1080)
ONE_TRACK = np.array([[950.0, 530.0, 970.0, 550.0, 4.0]])
NO_TRACK = np.zeros((0, 5))


def run(scheduler: ModeScheduler, frames: int, predictions=ONE_TRACK, hits: bool = True):
    modes = []
    for k in range(frames):
        plan = scheduler.plan_frame(k / 30.0, SIZE, predictions)
        modes.append(plan.mode)
        counts = np.full(len(plan.layout), 1 if hits else 0)
        scheduler.report_detections(plan, counts)
    return modes


def test_starts_in_gd_for_n_global_frames_then_switches_to_ld():
    cfg = SchedulerConfig(n_global=30, n_local=120, n_miss=10)
    modes = run(ModeScheduler(cfg), 31)
    assert modes[:30] == [Mode.GLOBAL] * 30
    assert modes[30] is Mode.LOCAL


def test_steady_cycle_is_n_global_gd_then_n_local_ld():
    cfg = SchedulerConfig(n_global=30, n_local=120, n_miss=10)
    modes = run(ModeScheduler(cfg), 2 * 150 + 1)
    expected = ([Mode.GLOBAL] * 30 + [Mode.LOCAL] * 120) * 2 + [Mode.GLOBAL]
    assert modes == expected


def test_stays_in_gd_while_no_track_is_stable():
    scheduler = ModeScheduler(SchedulerConfig(n_global=5))
    modes = run(scheduler, 40, predictions=NO_TRACK)
    assert modes == [Mode.GLOBAL] * 40
    # As soon as a stable track appears (already past N_g) LD starts on the next frame.
    plan = scheduler.plan_frame(2.0, SIZE, ONE_TRACK)
    assert plan.mode is Mode.LOCAL and len(plan.layout) == 1


def test_returns_to_gd_at_once_after_n_miss_frames_without_detection():
    cfg = SchedulerConfig(n_global=3, n_local=100, n_miss=4)
    scheduler = ModeScheduler(cfg)
    run(scheduler, 3)  # the GD stretch
    misses = run(scheduler, 4, hits=False)
    assert misses == [Mode.LOCAL] * 4
    assert scheduler.state.frames_without_detection == 4
    plan = scheduler.plan_frame(1.0, SIZE, ONE_TRACK)
    assert plan.mode is Mode.GLOBAL
    assert "no detection" in plan.reason
    assert scheduler.state.frames_without_detection == 0


def test_a_hit_resets_the_miss_counter():
    cfg = SchedulerConfig(n_global=1, n_local=100, n_miss=3)
    scheduler = ModeScheduler(cfg)
    run(scheduler, 1)
    for _ in range(5):  # miss, miss, hit, repeated: never 3 misses in a row
        assert run(scheduler, 2, hits=False) == [Mode.LOCAL] * 2
        assert run(scheduler, 1, hits=True) == [Mode.LOCAL]
    assert scheduler.state.frames_without_detection == 0


def test_hits_in_only_one_of_several_rois_count_as_a_hit():
    cfg = SchedulerConfig(n_global=1, n_miss=2)
    scheduler = ModeScheduler(cfg)
    two_far = np.array([[100, 100, 120, 120, 1], [1500, 800, 1520, 820, 2]], dtype=float)
    run(scheduler, 1, predictions=two_far)
    for _ in range(10):
        plan = scheduler.plan_frame(0.0, SIZE, two_far)
        assert plan.mode is Mode.LOCAL and len(plan.layout) == 2
        scheduler.report_detections(plan, [0, 1])


def test_ld_without_any_stable_track_falls_back_to_gd():
    scheduler = ModeScheduler(SchedulerConfig(n_global=2))
    run(scheduler, 3)
    assert scheduler.mode is Mode.LOCAL
    plan = scheduler.plan_frame(1.0, SIZE, NO_TRACK)
    assert plan.mode is Mode.GLOBAL and len(plan.layout) == 0


def test_ld_rois_are_centred_on_predictions():
    scheduler = ModeScheduler(SchedulerConfig(n_global=1))
    run(scheduler, 1)
    plan = scheduler.plan_frame(0.1, SIZE, ONE_TRACK)
    roi = plan.rois[0]
    assert abs((roi[0] + roi[2]) / 2 - 960) <= 1 and abs((roi[1] + roi[3]) / 2 - 540) <= 1
    assert scheduler.state.roi_groups == ((4,),)
    np.testing.assert_array_equal(scheduler.state.rois, plan.rois)


def test_local_disabled_means_gd_on_every_frame():
    modes = run(ModeScheduler(SchedulerConfig(n_global=2, local_enabled=False)), 50)
    assert modes == [Mode.GLOBAL] * 50


def test_stale_or_wrong_reports():
    scheduler = ModeScheduler(SchedulerConfig(n_global=1, n_miss=2))
    run(scheduler, 1)
    first = scheduler.plan_frame(0.0, SIZE, ONE_TRACK)
    second = scheduler.plan_frame(0.1, SIZE, ONE_TRACK)
    scheduler.report_detections(first, [0])  # late report for an older frame: ignored
    assert scheduler.state.frames_without_detection == 0
    with pytest.raises(ValueError, match="1 ROIs but 2 counts"):
        scheduler.report_detections(second, [0, 0])


def test_missing_reports_do_not_count_as_misses():
    scheduler = ModeScheduler(SchedulerConfig(n_global=1, n_miss=2, n_local=50))
    run(scheduler, 1)
    for k in range(20):
        assert scheduler.plan_frame(k, SIZE, ONE_TRACK).mode is Mode.LOCAL


def test_state_counts_frames_and_reset_restarts():
    scheduler = ModeScheduler(SchedulerConfig(n_global=3, n_local=5))
    run(scheduler, 10)
    state = scheduler.state
    assert state.frames_seen == 10
    assert state.global_frames == 3 + 2  # 3 GD, 5 LD, then GD again for 2 frames
    assert state.mode is Mode.GLOBAL and state.frames_in_mode == 2
    scheduler.reset()
    state = scheduler.state
    assert state.mode is Mode.GLOBAL and state.frames_seen == 0 and len(state.rois) == 0


@pytest.mark.parametrize("field", ["n_global", "n_local", "n_miss"])
def test_bad_counters_are_rejected(field):
    with pytest.raises(ValueError, match=field):
        SchedulerConfig(**{field: 0})


def test_a_diverged_prediction_is_dropped_and_ld_goes_on_for_the_others(caplog: pytest.LogCaptureFixture) -> None:
    scheduler = ModeScheduler(SchedulerConfig(n_global=2, n_local=50, n_miss=5))
    run(scheduler, 2)
    good = np.array([[900.0, 500.0, 920.0, 520.0, 1]])
    diverged = np.array([[np.nan, 500.0, 920.0, 520.0, 2]])
    with caplog.at_level("WARNING", logger="gldt.scheduler"):
        for _ in range(20):
            plan = scheduler.plan_frame(0.0, (1920, 1080), np.vstack([good, diverged]))
            scheduler.report_detections(plan, [1] * len(plan.rois))
            assert plan.mode is Mode.LOCAL and plan.layout.groups == ((1,),)
    assert "NaN or infinite" in caplog.text and "[2.0]" in caplog.text
    assert scheduler.state.frames_in_mode == 20


def test_only_diverged_predictions_do_not_start_ld() -> None:
    scheduler = ModeScheduler(SchedulerConfig(n_global=2))
    run(scheduler, 2)
    plan = scheduler.plan_frame(0.0, (1920, 1080), np.array([[np.inf, 0.0, 10.0, 10.0, 1]]))
    assert plan.mode is Mode.GLOBAL


def test_a_failed_roi_plan_leaves_the_scheduler_as_it_was() -> None:
    scheduler = ModeScheduler(SchedulerConfig(n_global=2))
    run(scheduler, 2)
    before = scheduler.state
    duplicate_ids = np.array([[0.0, 0.0, 10.0, 10.0, 1], [50.0, 50.0, 60.0, 60.0, 1]])
    with pytest.raises(ValueError, match="duplicate track ids"):
        scheduler.plan_frame(0.0, (1920, 1080), duplicate_ids)
    after = scheduler.state
    assert (after.mode, after.frames_in_mode, after.frames_seen) == (
        before.mode,
        before.frames_in_mode,
        before.frames_seen,
    )
    with pytest.raises(TypeError):
        scheduler.plan_frame(None, (1920, 1080), duplicate_ids[:1])  # a bad stamp, same promise
    after = scheduler.state
    assert (after.mode, after.frames_in_mode, after.frames_seen) == (
        before.mode,
        before.frames_in_mode,
        before.frames_seen,
    )
    assert scheduler.plan_frame(0.0, (1920, 1080), duplicate_ids[:1]).mode is Mode.LOCAL
