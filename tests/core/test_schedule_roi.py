"""Geometric checks of the ROI manager (paper: merge > tau_o, split > tau_d, safe zone tau_s)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gldt_core.schedule.roi import (
    RoiParams,
    clip_roi,
    overlap_matrix,
    plan_rois,
    roi_of_each_box,
    roi_overlap,
    safe_zone,
)

FRAME_1080P = (1920, 1080)


def box_at(cx: float, cy: float, size: float = 20.0) -> list[float]:
    return [cx - size / 2, cy - size / 2, cx + size / 2, cy + size / 2]


def contains(outer, inner, tol: float = 1e-6) -> bool:
    return (
        inner[0] >= outer[0] - tol
        and inner[1] >= outer[1] - tol
        and inner[2] <= outer[2] + tol
        and inner[3] <= outer[3] + tol
    )


def assert_inside_frame(rois: np.ndarray, frame_size: tuple[int, int]) -> None:
    assert np.all(rois[:, 0] >= 0) and np.all(rois[:, 1] >= 0)
    assert np.all(rois[:, 2] <= frame_size[0]) and np.all(rois[:, 3] <= frame_size[1])
    assert np.all(rois[:, 2] > rois[:, 0]) and np.all(rois[:, 3] > rois[:, 1])


def test_overlap_is_intersection_over_smaller_area():
    big = [0, 0, 600, 600]
    small_inside = [100, 100, 400, 400]
    assert roi_overlap(big, small_inside) == pytest.approx(1.0)
    # Two 300x300 windows shifted by 150 px in x share half of each.
    assert roi_overlap([0, 0, 300, 300], [150, 0, 450, 300]) == pytest.approx(0.5)
    assert roi_overlap([0, 0, 300, 300], [300, 0, 600, 300]) == 0.0


def test_safe_zone_covers_tau_s_of_the_area():
    zone = safe_zone([0, 0, 300, 300], 0.8)
    area = (zone[2] - zone[0]) * (zone[3] - zone[1])
    assert area == pytest.approx(0.8 * 300 * 300)
    assert (zone[0] + zone[2]) / 2 == pytest.approx(150)


def test_single_target_gets_default_window_centred_on_it():
    layout = plan_rois(np.array([box_at(960, 540)]), [7], FRAME_1080P)
    assert len(layout) == 1
    roi = layout.rois[0]
    assert roi[2] - roi[0] == 300 and roi[3] - roi[1] == 300
    assert (roi[0] + roi[2]) / 2 == pytest.approx(960, abs=1)
    assert (roi[1] + roi[3]) / 2 == pytest.approx(540, abs=1)
    assert layout.groups == ((7,),)


def test_two_close_targets_share_one_window_holding_both_in_safe_zone():
    boxes = np.array([box_at(900, 500), box_at(980, 520)])
    layout = plan_rois(boxes, [1, 2], FRAME_1080P)
    assert len(layout) == 1 and layout.groups == ((1, 2),)
    zone = safe_zone(layout.rois[0], 0.8)
    for b in boxes:
        assert contains(zone, b)


def test_far_apart_targets_get_separate_windows():
    boxes = np.array([box_at(300, 500), box_at(1500, 500)])
    layout = plan_rois(boxes, [1, 2], FRAME_1080P)
    assert len(layout) == 2
    assert roi_overlap(layout.rois[0], layout.rois[1]) == 0.0


def test_two_targets_crossing_merge_expand_then_split():
    """Targets fly towards each other, cross, and separate; the layout follows tau_o / tau_d."""
    params = RoiParams()
    groups: tuple = ()
    history = []
    for step in range(0, 121):
        # Both start 1200 px apart, cross at x=960 at step 60, end 1200 px apart again.
        offset = 600 - 10 * step
        boxes = np.array([box_at(960 - offset, 540), box_at(960 + offset, 540)])
        layout = plan_rois(boxes, [1, 2], FRAME_1080P, params, previous_groups=groups)
        groups = layout.groups
        distance = abs(2 * offset)
        history.append((distance, len(layout), layout))
        # Every target is inside some window at all times.
        assert np.all(roi_of_each_box(boxes, layout.rois) >= 0)
        assert_inside_frame(layout.rois, FRAME_1080P)
        if len(layout) == 1:
            zone = safe_zone(layout.rois[0], params.tau_safe)
            for b in boxes:
                assert contains(zone, b)
            assert distance <= params.tau_distance
    # Far apart at the start: two windows; merged when their 300 px windows overlap > 0.2.
    assert history[0][1] == 2
    merged_steps = [i for i, (_, n, _) in enumerate(history) if n == 1]
    assert merged_steps, "windows never merged while the targets crossed"
    first_merge = merged_steps[0]
    # They merge only once the default windows overlap > tau_o: centres < 240 px apart.
    assert history[first_merge][0] < 300 * (1 - params.tau_overlap) + 1e-6
    # After crossing, the shared window is kept (and expanded) beyond the merge distance ...
    expanded = [h for h in history[60:] if h[1] == 1 and h[0] > 300]
    assert expanded, "shared window was not kept while the targets separated"
    assert max(h[2].rois[0][2] - h[2].rois[0][0] for h in expanded) > 300
    # ... and split once they are more than tau_d apart.
    for distance, count, _ in history[60:]:
        if distance > params.tau_distance:
            assert count == 2
    assert history[-1][1] == 2


def test_target_at_frame_edge_gets_full_size_window_inside_frame():
    boxes = np.array([[0, 1060, 20, 1080], [1900, 0, 1920, 20]], dtype=float)
    layout = plan_rois(boxes, [1, 2], FRAME_1080P)
    assert len(layout) == 2
    assert_inside_frame(layout.rois, FRAME_1080P)
    assert np.all(layout.rois[:, 2] - layout.rois[:, 0] == 300)
    assert np.all(layout.rois[:, 3] - layout.rois[:, 1] == 300)
    for b, r in zip(boxes, roi_of_each_box(boxes, layout.rois)):
        assert r >= 0 and contains(layout.rois[r], b)


def test_target_partly_outside_frame_is_clipped_not_lost():
    boxes = np.array([[-15, 500, 10, 520]], dtype=float)
    layout = plan_rois(boxes, [3], (640, 512))
    assert_inside_frame(layout.rois, (640, 512))
    assert layout.rois[0][0] == 0


def test_ten_targets_every_one_covered_and_no_redundant_windows():
    rng = np.random.default_rng(3)
    centres = rng.uniform([50, 50], [1870, 1030], size=(10, 2))
    boxes = np.array([box_at(x, y, 24) for x, y in centres])
    params = RoiParams()
    layout = plan_rois(boxes, list(range(10, 20)), FRAME_1080P, params)
    assert 1 <= len(layout) <= 10
    assert_inside_frame(layout.rois, FRAME_1080P)
    # Each id in exactly one group; each group's targets inside its window.
    all_ids = sorted(i for g in layout.groups for i in g)
    assert all_ids == list(range(10, 20))
    for roi, group in zip(layout.rois, layout.groups):
        for i in group:
            assert contains(roi, boxes[i - 10])
        member_centres = centres[[i - 10 for i in group]]
        diff = member_centres[:, None] - member_centres[None]
        assert np.sqrt((diff**2).sum(-1)).max() <= params.tau_distance
    # No two windows overlap more than tau_o unless merging them would break tau_d.
    for a in range(len(layout)):
        for b in range(a + 1, len(layout)):
            if roi_overlap(layout.rois[a], layout.rois[b]) > params.tau_overlap:
                merged = centres[[i - 10 for i in layout.groups[a] + layout.groups[b]]]
                diff = merged[:, None] - merged[None]
                assert np.sqrt((diff**2).sum(-1)).max() > params.tau_distance


def test_ten_targets_in_a_tight_cluster_share_one_window():
    centres = [(960 + 15 * i, 540 + (-1) ** i * 10) for i in range(10)]
    boxes = np.array([box_at(x, y) for x, y in centres])
    layout = plan_rois(boxes, None, FRAME_1080P)
    assert len(layout) == 1
    zone = safe_zone(layout.rois[0], 0.8)
    assert all(contains(zone, b) for b in boxes)


def test_frame_smaller_than_window_gives_whole_frame():
    layout = plan_rois(np.array([box_at(100, 80)]), [1], (200, 160))
    assert layout.rois.tolist() == [[0, 0, 200, 160]]


def test_no_targets_gives_no_windows():
    layout = plan_rois(np.zeros((0, 4)), [], FRAME_1080P)
    assert len(layout) == 0 and layout.rois.shape == (0, 4)


def test_group_with_vanished_member_shrinks_back():
    boxes = np.array([box_at(900, 540), box_at(1200, 540)])
    layout = plan_rois(boxes, [1, 2], FRAME_1080P, previous_groups=((1, 2),))
    assert len(layout) == 1 and layout.rois[0][2] - layout.rois[0][0] > 300
    layout = plan_rois(boxes[:1], [1], FRAME_1080P, previous_groups=layout.groups)
    assert layout.groups == ((1,),)
    assert layout.rois[0][2] - layout.rois[0][0] == 300


def test_clip_roi_never_shrinks_inside_a_large_frame():
    roi = clip_roi([1800.4, 900.2, 2100.4, 1200.2], FRAME_1080P)
    # Shifted back inside the frame, flush with the right and bottom edges, not cut.
    assert roi[2] == 1920 and roi[3] == 1080
    assert 300 <= roi[2] - roi[0] <= 301 and 300 <= roi[3] - roi[1] <= 301
    assert clip_roi([10.0, 20.0, 310.0, 320.0], FRAME_1080P).tolist() == [10, 20, 310, 320]


@pytest.mark.parametrize(
    "bad",
    [
        dict(tau_overlap=1.5),
        dict(tau_safe=0.0),
        dict(tau_distance=-1.0),
        dict(roi_size=4),
    ],
)
def test_bad_params_raise_value_error_naming_field(bad):
    with pytest.raises(ValueError, match=next(iter(bad))):
        RoiParams(**bad)


def test_bad_boxes_raise():
    with pytest.raises(ValueError, match="NaN"):
        plan_rois(np.array([[math.nan, 0, 1, 1]]), [1], FRAME_1080P)
    with pytest.raises(ValueError, match="track ids"):
        plan_rois(np.array([box_at(5, 5)]), [1, 2], FRAME_1080P)


def test_overlap_matrix_is_roi_overlap_of_every_pair():
    rng = np.random.default_rng(5)
    corners = rng.uniform(0, 400, size=(12, 2))
    rois = np.concatenate([corners, corners + rng.uniform(0, 300, size=(12, 2))], axis=1)
    rois[3] = [50, 50, 50, 80]  # empty: overlaps nothing
    matrix = overlap_matrix(rois)
    for a in range(len(rois)):
        for b in range(len(rois)):
            assert matrix[a, b] == pytest.approx(roi_overlap(rois[a], rois[b]), abs=1e-12)


def test_expanded_windows_keep_their_targets_in_the_safe_zone_after_rounding():
    rng = np.random.default_rng(12)
    params = RoiParams()
    for _ in range(50):
        centre = rng.uniform([500, 300], [1400, 700])
        boxes = np.array(
            [box_at(*(centre + rng.uniform(-250, 250, size=2)), size=rng.uniform(8, 40)) for _ in range(3)]
        )
        layout = plan_rois(boxes, [1, 2, 3], FRAME_1080P, params, previous_groups=((1, 2, 3),))
        assert len(layout) == 1
        zone = safe_zone(layout.rois[0], params.tau_safe)
        assert all(contains(zone, b) for b in boxes)


def test_windows_clipped_onto_each_other_are_merged_not_cropped_twice():
    # Four targets near the corners of a frame smaller than one window: one crop, not four copies.
    small = (280, 280)
    boxes = np.array([box_at(20, 20), box_at(260, 20), box_at(20, 260), box_at(260, 260)])
    layout = plan_rois(boxes, [1, 2, 3, 4], small)
    assert layout.rois.tolist() == [[0, 0, 280, 280]] and layout.groups == ((1, 2, 3, 4),)
    # A 320x256 frame (thermal-camera size), targets 280 px apart: apart their windows would
    # overlap 0.93 once shifted inside the frame, so they share one.
    layout = plan_rois(np.array([box_at(20, 128), box_at(300, 128)]), [1, 2], (320, 256))
    assert len(layout) == 1
    # Near the right edge of a 1080p frame: no two windows overlap by more than tau_o.
    layout = plan_rois(np.array([box_at(1605, 540), box_at(1910, 540)]), [1, 2], FRAME_1080P)
    for a in range(len(layout)):
        for b in range(a + 1, len(layout)):
            assert roi_overlap(layout.rois[a], layout.rois[b]) <= RoiParams().tau_overlap


def _reference_layout(boxes: np.ndarray, frame_size: tuple[int, int], params: RoiParams) -> list[tuple[int, ...]]:
    """plan_rois' steps written plainly (one id per box, no previous groups): split, then merge
    the most overlapping pair of clipped windows, one pair at a time, re-measuring everything."""
    from gldt_core.schedule.roi import roi_for_boxes

    centres = (boxes[:, :2] + boxes[:, 2:4]) * 0.5

    def spread(group):
        pts = centres[list(group)]
        return max((float(np.hypot(*(p - q))) for p in pts for q in pts), default=0.0)

    def window(group):
        return clip_roi(roi_for_boxes(boxes[list(group)], params), frame_size)

    groups = [[i] for i in range(len(boxes))]
    while True:
        best = None
        for a in range(len(groups)):
            for b in range(a + 1, len(groups)):
                overlap = roi_overlap(window(groups[a]), window(groups[b]))
                if overlap <= params.tau_overlap or spread(groups[a] + groups[b]) > params.tau_distance:
                    continue
                if best is None or overlap > best[0]:
                    best = (overlap, a, b)
        if best is None:
            return sorted(tuple(sorted(g)) for g in groups)
        _, a, b = best
        groups[a] = groups[a] + groups[b]
        del groups[b]


@pytest.mark.parametrize("seed", range(30))
def test_plan_rois_merges_like_the_plain_greedy_loop(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    frame_size = [(1920, 1080), (640, 512), (320, 256)][seed % 3]
    count = int(rng.integers(2, 12))
    centres = rng.uniform([0, 0], frame_size, size=(count, 2))
    boxes = np.array([box_at(x, y, float(rng.uniform(6, 40))) for x, y in centres])
    layout = plan_rois(boxes, None, frame_size)
    assert sorted(layout.groups) == _reference_layout(boxes, frame_size, RoiParams())


def test_table_one_pixel_sizes_scale_with_the_frame_height() -> None:
    from gldt_core.schedule.roi import MIN_SCALED_ROI

    params = RoiParams()
    assert params.at_resolution(1080) is params
    small = params.at_resolution(512)
    assert small.roi_size == round(300 * 512 / 1080) and small.tau_distance == pytest.approx(700 * 512 / 1080)
    assert (small.tau_overlap, small.tau_safe) == (params.tau_overlap, params.tau_safe)
    assert params.at_resolution(200).roi_size == MIN_SCALED_ROI
    assert RoiParams(reference_height=None).at_resolution(512).roi_size == 300
    with pytest.raises(ValueError, match="reference_height"):
        RoiParams(reference_height=0)


def test_the_scheduler_plans_rois_of_the_scaled_size() -> None:
    from gldt_core.schedule.scheduler import Mode, ModeScheduler, SchedulerConfig

    scheduler = ModeScheduler(SchedulerConfig(n_global=1))
    prediction = np.array([[300.0, 200, 330, 220, 1]])
    plans = [scheduler.plan_frame(t / 30, (640, 512), prediction) for t in range(3)]
    local = [p for p in plans if p.mode is Mode.LOCAL]
    assert local, "the scheduler never went local"
    side = local[-1].rois[0, 2] - local[-1].rois[0, 0]
    assert abs(side - round(300 * 512 / 1080)) <= 1
