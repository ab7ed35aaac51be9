"""The benchmark's stream profiles each have the property they claim (gldt_core.eval.streams)."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest
from scipy.stats import ks_2samp

from gldt_core.eval.streams import (
    CLUTTER_SOURCE,
    HELD_OUT,
    PROFILES,
    TUNING,
    EgoMotion,
    StreamParams,
    apply_ego_motion,
    crossing_multi_target_gt,
    detections_from_gt,
    ego_motion_path,
    profile_by_name,
    profile_sequences,
)


def _centres(rows: np.ndarray) -> np.ndarray:
    return rows[:, 2:4] + rows[:, 4:6] / 2


def _chains(rows: np.ndarray, max_gap: int = 3) -> list[np.ndarray]:
    """Greedy frame-to-frame linking of boxes (nearest centre within two box sizes, gaps of up to
    ``max_gap`` frames): the tracks a tracker could make of them, as arrays of rows."""
    rows = rows[np.argsort(rows[:, 0], kind="stable")]
    open_chains: list[list[np.ndarray]] = []
    done: list[list[np.ndarray]] = []
    for frame in np.unique(rows[:, 0]):
        block = rows[rows[:, 0] == frame]
        still = []
        for chain in open_chains:
            if frame - chain[-1][0] > max_gap:
                done.append(chain)
            else:
                still.append(chain)
        open_chains = still
        taken: set[int] = set()
        for chain in sorted(open_chains, key=len, reverse=True):
            last = chain[-1]
            reach = 2.0 * max(last[4], last[5]) * (frame - last[0])
            distance = np.hypot(*(_centres(block) - _centres(last[None])).T)
            for index in np.argsort(distance):
                if int(index) not in taken and distance[index] <= reach:
                    chain.append(block[index])
                    taken.add(int(index))
                    break
        open_chains += [[block[i]] for i in range(len(block)) if i not in taken]
    return [np.asarray(chain) for chain in done + open_chains]


def _runs_of_false(flags: np.ndarray) -> list[int]:
    runs, current = [], 0
    for flag in flags:
        if not flag:
            current += 1
        elif current:
            runs.append(current)
            current = 0
    return runs + ([current] if current else [])


# ------------------------------------------------------------------------------------- catalogue
def test_profiles_declare_tuning_and_held_out_and_span_frame_rates() -> None:
    names = [p.name for p in PROFILES]
    assert len(PROFILES) >= 4 and len(set(names)) == len(names)
    roles = [p.role for p in PROFILES]
    assert set(roles) == {TUNING, HELD_OUT}
    assert roles.count(TUNING) == 2 and roles.count(HELD_OUT) >= 3
    rates = {p.fps for p in PROFILES}
    assert all(15 <= r <= 60 for r in rates) and min(rates) == 15 and max(rates) == 60 and len(rates) >= 3
    assert any(p.ego_motion is not None for p in PROFILES)
    assert any(p.params.clutter_tracks_rate > 0 for p in PROFILES)
    assert profile_by_name("crossing").name == "crossing"
    with pytest.raises(ValueError, match="known"):
        profile_by_name("nope")


@pytest.mark.parametrize("profile", PROFILES, ids=lambda p: p.name)
def test_sequences_are_deterministic_per_seed_and_last_the_same_time_at_any_rate(profile) -> None:
    a = profile_sequences(profile, 4, 2, 3.0)
    b = profile_sequences(profile, 4, 2, 3.0)
    c = profile_sequences(profile, 5, 2, 3.0)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x.gt, y.gt)
        np.testing.assert_array_equal(x.dets, y.dets)
    assert any(x.dets.shape != z.dets.shape or not np.array_equal(x.dets, z.dets) for x, z in zip(a, c))
    for sequence in a:
        assert sequence.frames == round(3.0 * profile.fps) and sequence.fps == profile.fps
        assert sequence.size == profile.size
        assert sequence.gt[:, 0].max() <= sequence.frames and sequence.dets[:, 0].max() <= sequence.frames
        targets = len(np.unique(sequence.gt[sequence.gt[:, 7] == 1, 1]))
        assert profile.targets[0] - 1 <= targets <= profile.targets[1]  # a target may stay out of view


def test_crossing_ground_truth_is_a_function_of_time_so_the_frame_rate_resamples_it() -> None:
    slow = crossing_multi_target_gt(11, 91, targets=4, fps=30.0)
    fast = crossing_multi_target_gt(11, 181, targets=4, fps=60.0)
    # Frame k at 30 Hz is t = (k - 1) / 30 = frame 2k - 1 at 60 Hz.
    for row in slow[slow[:, 0] % 10 == 1]:
        twin = fast[(fast[:, 0] == 2 * row[0] - 1) & (fast[:, 1] == row[1])]
        np.testing.assert_allclose(twin[0, 2:6], row[2:6], atol=1e-6)
    # Twice the frames for the same duration: the per-frame step halves.
    one = slow[slow[:, 1] == 1]
    two = fast[fast[:, 1] == 1]
    step_slow = np.median(np.hypot(*np.diff(_centres(one), axis=0).T))
    step_fast = np.median(np.hypot(*np.diff(_centres(two), axis=0).T))
    assert step_fast == pytest.approx(step_slow / 2, rel=0.1)


@pytest.mark.parametrize("seed", range(6))
def test_crossing_targets_pass_through_each_other_and_the_farther_one_is_occluded(seed: int) -> None:
    targets = 2 + seed % 4
    fps = 30.0
    gt = crossing_multi_target_gt(seed, 600, targets=targets, fps=fps)
    assert set(np.unique(gt[:, 1]).astype(int)) <= set(range(1, targets + 1))
    crossed = False
    for a, b in itertools.combinations(range(1, targets + 1), 2):
        ra, rb = gt[gt[:, 1] == a], gt[gt[:, 1] == b]
        common = np.intersect1d(ra[:, 0], rb[:, 0])
        if len(common) < 2 * fps:
            continue
        ca = _centres(ra[np.isin(ra[:, 0], common)])
        cb = _centres(rb[np.isin(rb[:, 0], common)])
        relative = ca - cb
        closest = int(np.argmin(np.hypot(*relative.T)))
        before, after = closest - int(fps), closest + int(fps)
        if before < 0 or after >= len(common):
            continue
        if np.hypot(*relative[closest]) < 0.5 * min(ra[:, 4].min(), rb[:, 4].min()) and (
            relative[before] @ relative[after] < 0
        ):
            crossed = True
            frame = common[closest]
            visibility = gt[(gt[:, 0] == frame) & np.isin(gt[:, 1], [a, b]), 8]
            assert visibility.min() < 0.5  # the farther one is hidden behind the nearer one
    assert crossed


def test_at_fps_rescales_what_lasts_in_time_and_keeps_per_frame_behaviour() -> None:
    base = StreamParams(clutter_tracks_rate=0.01)
    assert base.at_fps(30.0) == base
    fast = base.at_fps(60.0)
    assert fast.burst_rate == pytest.approx(base.burst_rate / 2)
    assert fast.burst_frames == (2 * base.burst_frames[0], 2 * base.burst_frames[1])
    assert fast.clutter_tracks_frames == (120, 600) and fast.clutter_tracks_rate == pytest.approx(0.005)
    assert fast.clutter_tracks_speed == pytest.approx((0.75, 4.0))
    assert (fast.miss_rate, fast.fp_rate, fast.jitter_frac) == (base.miss_rate, base.fp_rate, base.jitter_frac)
    with pytest.raises(ValueError):
        base.at_fps(0.0)


# ------------------------------------------------------------------------------------- failure modes
def test_persistent_clutter_forms_long_lived_moving_false_tracks_iid_clutter_does_not() -> None:
    gt = crossing_multi_target_gt(3, 900, targets=2)
    quiet = dict(burst_rate=0.0, miss_rate=0.0, distractor_rate=0.0, jitter_frac=0.02)
    drifting = StreamParams(fp_rate=0.0, clutter_tracks_rate=0.01, **quiet)
    iid = StreamParams(fp_rate=2.0, **quiet)
    for params, long_lived in ((drifting, True), (iid, False)):
        dets = detections_from_gt(gt, 8, (1920, 1080), params)
        clutter = dets[dets[:, 1] == CLUTTER_SOURCE]
        assert len(clutter) > 300
        chains = _chains(clutter)
        longest = max(chains, key=len)
        if long_lived:
            assert len(longest) >= 60  # 2 s of one false object, detected on most frames
            travel = np.hypot(*(_centres(longest[-1:]) - _centres(longest[:1]))[0])
            assert travel > 50  # it moves like a target, it is not a static blob
            steps = np.hypot(*np.diff(_centres(longest), axis=0).T) / np.diff(longest[:, 0])
            assert np.median(steps) > 1.0
        else:
            assert len(longest) <= 6


def test_ego_motion_moves_gt_and_detections_together_as_one_rigid_motion() -> None:
    size = (1920, 1080)
    gt = crossing_multi_target_gt(5, 200, targets=4)
    exact = StreamParams(
        burst_rate=0.0, miss_rate=0.0, jitter_frac=0.0, jitter_px=0.0, size_jitter_frac=0.0, fp_rate=0.0
    )
    dets = detections_from_gt(gt, 2, size, exact)
    path = ego_motion_path(9, 200, 30.0, EgoMotion())
    assert np.abs(path[:, :2]).max() > 30 and np.abs(path[:, 2]).max() > np.radians(0.3)
    moved_gt = apply_ego_motion(gt, path, size)
    moved_dets = apply_ego_motion(dets, path, size)
    assert len(moved_gt) > 0.8 * len(gt)
    # An exact detection of object g stays exactly on g's moved box.
    for row in moved_dets[::7]:
        twin = moved_gt[(moved_gt[:, 0] == row[0]) & (moved_gt[:, 1] == row[1])]
        np.testing.assert_allclose(twin[0, 2:6], row[2:6], atol=1e-9)
    # The boxes moved, but distances between objects in a frame did not (one rigid motion).
    key = {(int(r[0]), int(r[1])): r for r in gt}
    shift = [np.hypot(*(_centres(r[None]) - _centres(key[(int(r[0]), int(r[1]))][None]))[0]) for r in moved_gt]
    assert np.mean(shift) > 20
    for frame in (50, 120, 190):
        now = moved_gt[moved_gt[:, 0] == frame]
        before = np.asarray([key[(frame, int(i))] for i in now[:, 1]])
        if len(now) >= 2:
            d_now = np.hypot(*(_centres(now[:1]) - _centres(now[1:])).T)
            d_before = np.hypot(*(_centres(before[:1]) - _centres(before[1:])).T)
            np.testing.assert_allclose(d_now, d_before, atol=1e-6)


def test_the_ego_motion_profile_applies_its_motion_to_gt_and_detections() -> None:
    profile = profile_by_name("ego-motion-25hz")
    still = dataclasses.replace(profile, ego_motion=None)
    moving_seq = profile_sequences(profile, 2, 1, 6.0)[0]
    still_seq = profile_sequences(still, 2, 1, 6.0)[0]
    # Same seeds: the same objects, seen from a camera that moves.
    index = {(int(r[0]), int(r[1])): r for r in still_seq.gt}
    shifts = [_centres(r[None])[0] - _centres(index[(int(r[0]), int(r[1]))][None])[0] for r in moving_seq.gt]
    assert np.median(np.hypot(*np.asarray(shifts).T)) > 10

    # A detection of object g is as close to g's moved box as it was to g's still box.
    def residual(seq) -> float:
        boxes = {(int(r[0]), int(r[1])): r for r in seq.gt}
        gaps = [
            np.hypot(*(_centres(d[None]) - _centres(boxes[(int(d[0]), int(d[1]))][None]))[0])
            for d in seq.dets
            if d[1] > 0 and (int(d[0]), int(d[1])) in boxes
        ]
        return float(np.median(gaps))

    assert residual(moving_seq) == pytest.approx(residual(still_seq), rel=0.25)


def test_score_distributions_differ_between_profiles() -> None:
    scores = {}
    for profile in PROFILES:
        dets = np.vstack([s.dets for s in profile_sequences(profile, 0, 2, 8.0)])
        scores[profile.name] = dets[dets[:, 1] > 0, 6]  # true detections only
        assert len(scores[profile.name]) > 200
    for a, b in itertools.combinations(scores, 2):
        assert ks_2samp(scores[a], scores[b]).statistic > 0.1, (a, b)
    # A wide spread: the Beta profiles put true detections on both sides of 0.5 and outside the bands.
    wide = scores["occlusion-15hz"]
    assert 0.5 < np.mean(wide < 0.5) < 0.85 and np.mean(wide < 0.15) > 0.05


def test_the_occlusion_profile_has_long_miss_bursts_of_visible_targets() -> None:
    profile = profile_by_name("occlusion-15hz")
    longest = 0
    for sequence in profile_sequences(profile, 1, 3, 20.0):
        for target in np.unique(sequence.gt[:, 1]):
            frames = sequence.gt[(sequence.gt[:, 1] == target) & (sequence.gt[:, 8] >= 0.9), 0]
            detected = np.isin(frames, sequence.dets[sequence.dets[:, 1] == target, 0])
            longest = max([longest, *_runs_of_false(detected)])
    assert longest >= 1.0 * profile.fps  # at least one second without a detection of a visible target


def test_the_drifting_clutter_profile_holds_false_objects_for_seconds() -> None:
    profile = profile_by_name("drifting-clutter-60hz")
    sequence = profile_sequences(profile, 0, 1, 15.0)[0]
    clutter = sequence.dets[sequence.dets[:, 1] == CLUTTER_SOURCE]
    longest = max(_chains(clutter), key=len)
    assert longest[-1, 0] - longest[0, 0] >= 2.0 * profile.fps
