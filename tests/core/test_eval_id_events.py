"""Identity-switch breakdown (gldt_core.eval.id_events): each category on a hand-made stream,
the total equal to CLEAR's IDSW on random and tracked streams, and the breakdown of JPTrack and
ByteTrack on default benchmark streams."""

from __future__ import annotations

import numpy as np
import pytest

from gldt_core.eval import evaluate_sequence
from gldt_core.eval.id_events import (
    BIRTH_DETECTED,
    BIRTH_GAP,
    CATEGORIES,
    FRAGMENT_RETURN,
    OTHER,
    RECOVERY_CLUTTER,
    RECOVERY_OTHER,
    SWAP,
    IdSwitchReport,
    classify_id_switches,
    detection_provenance,
    format_id_switch_table,
    merge_reports,
)
from gldt_core.eval.streams import detections_from_gt, simple_multi_target_gt
from gldt_core.track import ByteTrack, ByteTrackConfig, JPTrack, JPTrackConfig
from gldt_core.track.runner import track_detection_rows

FPS = 30.0
SIZE = 20.0


def box(frame: int, ident: int, x: float, y: float, cls: int = 1, w: float = SIZE) -> list[float]:
    return [frame, ident, x, y, w, w, 1, cls, 1, -1]


def target_x(frame: int) -> float:
    """Every object flies right at 2 px/frame, each on its own lane (:func:`lane`)."""
    return 100.0 + 2.0 * frame


def lane(obj: int) -> float:
    return 100.0 + 200.0 * obj


def gt_of(objects: list[int], frames: int, extra: list[list[float]] | None = None) -> np.ndarray:
    rows = [box(f, g, target_x(f), lane(g)) for f in range(1, frames + 1) for g in objects]
    return np.asarray(rows + (extra or []), dtype=np.float64)


def on(obj: int, track: int, frames: range, dx: float = 0.0) -> list[list[float]]:
    """Track ``track`` placed exactly on object ``obj`` (shifted by ``dx`` px) for ``frames``."""
    return [box(f, track, target_x(f) + dx, lane(obj)) for f in frames]


def dets_of(gt: np.ndarray, missing: dict[int, range] | None = None, provenance: bool = True) -> np.ndarray:
    """One detection per target gt row (the gt box), except the frames in ``missing[obj]``."""
    rows = []
    for row in gt:
        frame, obj = int(row[0]), int(row[1])
        if row[7] != 1 or (missing and obj in missing and frame in missing[obj]):
            continue
        rows.append([frame, obj if provenance else -1, *row[2:6], 0.9, -1, -1, -1])
    return np.asarray(rows, dtype=np.float64)


def classify(gt: np.ndarray, pred: list[list[float]], dets: np.ndarray, **kwargs: float) -> IdSwitchReport:
    pred_rows = np.asarray(pred, dtype=np.float64)
    report = classify_id_switches(gt, pred_rows, dets, FPS, **kwargs)  # type: ignore[arg-type]
    assert report.total == evaluate_sequence(gt, pred_rows)["IDSW"]
    assert sum(report.counts.values()) == report.total
    assert tuple(report.counts) == CATEGORIES
    return report


def only(report: IdSwitchReport) -> list[tuple[int, int, int, int, str]]:
    return [(e.frame, e.gt_id, e.prev_id, e.new_id, e.category) for e in report.events]


# --- one hand-made stream per category ------------------------------------------------------------
def test_two_targets_crossing_with_swapped_ids_are_swaps() -> None:
    # Objects 1 and 2 fly towards each other on one lane and cross at frame 50; the tracker's
    # boxes follow them but exchange ids at the crossing.
    frames = 100
    gt_rows, pred = [], []
    for f in range(1, frames + 1):
        x1, x2 = 100.0 + 4.0 * f, 500.0 - 4.0 * f
        gt_rows += [box(f, 1, x1, 300), box(f, 2, x2, 300)]
        a, b = (x1, x2) if f <= 50 else (x2, x1)
        pred += [box(f, 7, a + 1, 300), box(f, 8, b + 1, 300)]
    gt = np.asarray(gt_rows)
    report = classify(gt, pred, dets_of(gt))
    assert report.total == 2
    assert report.counts[SWAP] == 2
    assert {(e.gt_id, e.prev_id, e.new_id) for e in report.events} == {(1, 7, 8), (2, 8, 7)}
    assert all("was on gt" in e.reason for e in report.events)


def test_lost_track_reattached_to_the_other_target_is_a_recovery() -> None:
    gt = gt_of([1, 2], 60)
    pred = on(1, 5, range(1, 11)) + on(2, 6, range(1, 21)) + on(2, 5, range(21, 61)) + on(1, 9, range(25, 61))
    report = classify(gt, pred, dets_of(gt))
    assert only(report) == [(21, 2, 6, 5, RECOVERY_OTHER), (25, 1, 5, 9, BIRTH_DETECTED)]
    recovery = report.events[0]
    assert "lost 10 frames" in recovery.reason and recovery.prev_fate == "ended at 20"
    # Id 5 reporting a box on nothing during frames 11-20 makes it a recovery from clutter, and
    # id 5 staying on object 1 until it jumps makes it a swap.
    pred = on(1, 5, range(1, 11)) + on(2, 6, range(1, 21)) + on(2, 5, range(21, 61))
    pred += [box(f, 5, 800, 800) for f in range(11, 21)]
    report = classify(gt, pred, dets_of(gt))
    assert only(report) == [(21, 2, 6, 5, RECOVERY_CLUTTER)]
    pred = on(1, 5, range(1, 21)) + on(2, 6, range(1, 21)) + on(2, 5, range(21, 61))
    report = classify(gt, pred, dets_of(gt))
    assert only(report) == [(21, 2, 6, 5, SWAP)]
    # One missed frame of id 5 before the jump: a lost track at the default lost_gap_frames = 1,
    # a swap when holes of one frame are tolerated.
    pred = on(1, 5, range(1, 20)) + on(2, 6, range(1, 21)) + on(2, 5, range(21, 61))
    assert only(classify(gt, pred, dets_of(gt))) == [(21, 2, 6, 5, RECOVERY_OTHER)]
    assert only(classify(gt, pred, dets_of(gt), lost_gap_frames=2)) == [(21, 2, 6, 5, SWAP)]


def test_clutter_or_bird_track_taking_over_is_recovery_from_clutter() -> None:
    bird = [box(f, 1001, 900, 900, cls=2) for f in range(1, 61)]
    gt = gt_of([1], 60, bird)
    dets = dets_of(gt)
    # id 3 follows clutter (far from anything) until frame 20, then sits on object 1.
    pred = on(1, 2, range(1, 16)) + [box(f, 3, 1500, 40) for f in range(1, 21)] + on(1, 3, range(21, 61))
    report = classify(gt, pred, dets)
    assert only(report) == [(21, 1, 2, 3, RECOVERY_CLUTTER)]
    assert "clutter" in report.events[0].reason
    # id 4 follows the bird (its rows are removed by the distractor rule) and then the drone.
    pred = on(1, 2, range(1, 16)) + [box(f, 4, 901, 900) for f in range(1, 21)] + on(1, 4, range(21, 61))
    report = classify(gt, pred, dets)
    assert only(report) == [(21, 1, 2, 4, RECOVERY_CLUTTER)]
    assert "distractor" in report.events[0].reason


def test_miss_burst_then_new_id_is_a_birth_after_a_detection_gap() -> None:
    gt = gt_of([1], 60)
    pred = on(1, 1, range(1, 11)) + on(1, 2, range(24, 61))
    report = classify(gt, pred, dets_of(gt, missing={1: range(11, 21)}))
    assert only(report) == [(24, 1, 1, 2, BIRTH_GAP)]
    assert "undetected 11-20" in report.events[0].reason
    assert report.events[0].new_first_frame == 24 and report.events[0].prev_last_match == 10
    # Without the burst the same output is a birth while detected.
    report = classify(gt, pred, dets_of(gt))
    assert only(report) == [(24, 1, 1, 2, BIRTH_DETECTED)]
    # Two missed frames are not a gap at the default min_gap_frames = 3, but are at 2.
    report = classify(gt, pred, dets_of(gt, missing={1: range(11, 13)}))
    assert report.events[0].category == BIRTH_DETECTED
    report = classify(gt, pred, dets_of(gt, missing={1: range(11, 13)}), min_gap_frames=2)
    assert report.events[0].category == BIRTH_GAP
    # A burst the old id survived (it resumed after it) is not why it ended later.
    pred = on(1, 1, range(1, 5)) + on(1, 1, range(13, 31)) + on(1, 2, range(32, 61))
    report = classify(gt, pred, dets_of(gt, missing={1: range(5, 13)}))
    assert only(report) == [(32, 1, 1, 2, BIRTH_DETECTED)]
    # A duplicate born (next to the object) before the burst survives it and takes over: the old
    # id did die in the burst, but the new one was not born during or after it.
    pred = on(1, 1, range(1, 21)) + on(1, 2, range(15, 25), dx=12) + on(1, 2, range(25, 61))
    report = classify(gt, pred, dets_of(gt, missing={1: range(21, 29)}))
    assert only(report) == [(25, 1, 1, 2, BIRTH_DETECTED)]
    pred = on(1, 1, range(1, 21)) + on(1, 2, range(22, 25), dx=12) + on(1, 2, range(25, 61))
    report = classify(gt, pred, dets_of(gt, missing={1: range(21, 29)}))
    assert only(report) == [(25, 1, 1, 2, BIRTH_GAP)]


def test_new_id_after_the_object_left_the_view_is_a_birth_after_a_gap() -> None:
    gt = gt_of([1], 60)
    gt = gt[(gt[:, 0] < 21) | (gt[:, 0] > 40)]  # out of view in frames 21-40
    pred = on(1, 1, range(1, 21)) + on(1, 2, range(42, 61))
    report = classify(gt, pred, dets_of(gt, missing={1: range(41, 42)}))
    assert only(report) == [(42, 1, 1, 2, BIRTH_GAP)]
    assert "undetected 21-41 (20 out of the gt)" in report.events[0].reason


def test_new_id_while_detections_continued_is_a_birth_while_detected() -> None:
    gt = gt_of([1, 2], 60)
    pred = on(1, 1, range(1, 31)) + on(2, 2, range(1, 61)) + on(1, 3, range(32, 61))
    report = classify(gt, pred, dets_of(gt))
    assert only(report) == [(32, 1, 1, 3, BIRTH_DETECTED)]
    assert report.events[0].prev_fate == "ended at 30"
    # A duplicate born on the object (IoU < 0.5 while id 1 holds it) that takes over when id 1
    # ends: still a birth while detected, born where it first appeared.
    pred = on(1, 1, range(1, 31)) + on(2, 2, range(1, 61)) + on(1, 3, range(20, 31), dx=12) + on(1, 3, range(31, 61))
    report = classify(gt, pred, dets_of(gt))
    assert only(report) == [(31, 1, 1, 3, BIRTH_DETECTED)]
    assert report.events[0].new_first_frame == 20


def test_switch_and_switch_back_counts_twice_and_the_return_is_a_fragment_return() -> None:
    gt = gt_of([1], 40)
    # id 1 misses frames 11-13; a new id 2 holds the object meanwhile; id 1 comes back.
    pred = on(1, 1, range(1, 11)) + on(1, 2, range(11, 14)) + on(1, 1, range(14, 41))
    report = classify(gt, pred, dets_of(gt))
    assert evaluate_sequence(gt, np.asarray(pred))["IDSW"] == 2  # TrackEval counts the return too
    assert only(report) == [(11, 1, 1, 2, BIRTH_DETECTED), (14, 1, 2, 1, FRAGMENT_RETURN)]
    assert report.events[0].prev_fate == "absent until 14"
    # The intruder staying on the object until frame 19 keeps the match (previous-match bonus);
    # id 1 shadows it unmatched and its return at frame 20 is still a fragment return.
    pred_dup = pred + on(1, 2, range(14, 20), dx=3)
    report = classify(gt, pred_dup, dets_of(gt))
    assert only(report) == [(11, 1, 1, 2, BIRTH_DETECTED), (20, 1, 2, 1, FRAGMENT_RETURN)]


def test_long_unmatched_shadow_that_takes_over_is_other() -> None:
    gt = gt_of([1], 90)
    # id 2 trails the object 12 px behind (IoU < 0.5) from frame 1 and snaps onto it at frame 70,
    # 20 frames after id 1 ended: no single moment explains it.
    pred = on(1, 1, range(1, 51)) + on(1, 2, range(1, 70), dx=-12) + on(1, 2, range(70, 91))
    report = classify(gt, pred, dets_of(gt))
    assert only(report) == [(70, 1, 1, 2, OTHER)]
    # A shorter shadow (arrived within recent_s) is a birth.
    pred = on(1, 1, range(1, 51)) + on(1, 2, range(50, 70), dx=-12) + on(1, 2, range(70, 91))
    report = classify(gt, pred, dets_of(gt))
    assert report.events[0].category == BIRTH_DETECTED


# --- provenance ------------------------------------------------------------------------------------
def test_provenance_from_column_one_or_by_iou() -> None:
    bird = [box(f, 1001, 600, 600, cls=2) for f in range(1, 4)]
    gt = gt_of([1, 2], 3, bird)
    dets = np.asarray(
        [
            [1, -1, target_x(1) + 2, lane(1), SIZE, SIZE, 0.9, -1, -1, -1],  # object 1
            [1, -1, 601, 600, SIZE, SIZE, 0.5, -1, -1, -1],  # the bird
            [1, -1, 1200, 900, SIZE, SIZE, 0.4, -1, -1, -1],  # clutter
            [2, -1, target_x(2), lane(2), SIZE, SIZE, 0.8, -1, -1, -1],  # object 2
            [2, -1, target_x(2) + 15, lane(1), SIZE, SIZE, 0.8, -1, -1, -1],  # IoU < 0.5 with 1
        ]
    )
    assert detection_provenance(gt, dets).tolist() == [1, -2, -1, 2, -1]
    given = dets.copy()
    given[:, 1] = [1, -2, -1, 2, 1]
    assert detection_provenance(gt, given).tolist() == [1, -2, -1, 2, 1]


def test_given_provenance_is_trusted_over_iou() -> None:
    gt = gt_of([1], 60)
    pred = on(1, 1, range(1, 11)) + on(1, 2, range(24, 61))
    dets = dets_of(gt)
    poor = (dets[:, 0] >= 11) & (dets[:, 0] <= 20)
    dets[poor, 2] += 15  # badly placed detections during frames 11-20 (IoU < 0.5)
    assert classify(gt, pred, dets).events[0].category == BIRTH_DETECTED  # column 1 says: detected
    unlabelled = dets.copy()
    unlabelled[:, 1] = -1
    assert classify(gt, pred, unlabelled).events[0].category == BIRTH_GAP  # by IoU: not detected


# --- equality with CLEAR's IDSW --------------------------------------------------------------------
def _random_sequence(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Objects on random walks, some leaving and coming back, a bird; predictions are noisy copies
    whose ids are randomly exchanged, dropped, duplicated or reused, with frames without any gt
    or any prediction."""
    frames = int(rng.integers(20, 80))
    objects = int(rng.integers(1, 5))
    pos = rng.uniform(50, 400, size=(objects + 1, 2))
    gt, pred = [], []
    ids = list(range(1, objects + 1))
    next_id = objects + 1
    for f in range(1, frames + 1):
        pos += rng.normal(0, 6, size=pos.shape)
        if rng.random() < 0.1:  # an empty-gt frame
            gt_here = []
        else:
            gt_here = [g for g in range(objects) if rng.random() < 0.9]
        for g in gt_here:
            gt.append(box(f, g + 1, pos[g, 0], pos[g, 1]))
        gt.append(box(f, 1001, pos[objects, 0], pos[objects, 1], cls=2))
        if rng.random() < 0.1:  # a frame without predictions
            continue
        if rng.random() < 0.15 and objects > 1:  # exchange two ids
            a, b = rng.choice(objects, 2, replace=False)
            ids[a], ids[b] = ids[b], ids[a]
        if rng.random() < 0.08:  # a new id for one object
            ids[int(rng.integers(objects))] = next_id
            next_id += 1
        used = set()
        for g in range(objects):
            if rng.random() < 0.15 or ids[g] in used:
                continue
            used.add(ids[g])
            pred.append(box(f, ids[g], *(pos[g] + rng.normal(0, 4, 2))))
        if rng.random() < 0.5:  # clutter or the bird's own track, ids never in use this frame
            extra = int(next_id + 1000 + rng.integers(3))
            where = pos[objects] if rng.random() < 0.5 else rng.uniform(0, 500, 2)
            pred.append(box(f, extra, *where))
    gt_rows = np.asarray(gt, dtype=np.float64).reshape(-1, 10)
    pred_rows = np.asarray(pred, dtype=np.float64).reshape(-1, 10)
    dets = dets_of(gt_rows, provenance=bool(rng.random() < 0.5))
    keep = rng.random(len(dets)) > 0.2
    return gt_rows, pred_rows, dets[keep]


def test_total_equals_clear_idsw_on_random_sequences() -> None:
    rng = np.random.default_rng(2906)
    totals = []
    for _ in range(150):
        gt, pred, dets = _random_sequence(rng)
        for threshold in (0.5, 0.3):
            report = classify_id_switches(gt, pred, dets, FPS, iou_threshold=threshold)
            assert report.total == evaluate_sequence(gt, pred, threshold=threshold)["IDSW"]
            assert sum(report.counts.values()) == report.total
            assert all(e.category in CATEGORIES and e.prev_id != e.new_id for e in report.events)
            totals.append(report.total)
    assert sum(totals) > 300 and max(totals) > 10  # the streams do make switches


def _tracked(tracker: str, gt: np.ndarray, dets: np.ndarray, frames: int) -> np.ndarray:
    size = (1920, 1080)
    made = (
        ByteTrack(ByteTrackConfig(image_size=size))
        if tracker == "ByteTrack"
        else JPTrack(JPTrackConfig(image_size=size))
    )
    return track_detection_rows(made, dets, FPS, num_frames=frames)


@pytest.mark.parametrize("tracker", ["ByteTrack", "JPTrack"])
def test_total_equals_clear_idsw_on_tracked_streams(tracker: str) -> None:
    for seed in range(6):
        gt = simple_multi_target_gt(seed, 300, targets=4)
        dets = detections_from_gt(gt, 50 + seed, (1920, 1080))
        pred = _tracked(tracker, gt, dets, 300)
        report = classify_id_switches(gt, pred, dets, FPS)
        assert report.total == evaluate_sequence(gt, pred)["IDSW"]
        # Without provenance (a real detector's rows) it is found by IoU; written into column 1,
        # that provenance gives the same events.
        unlabelled = dets.copy()
        unlabelled[:, 1] = -1
        by_iou = classify_id_switches(gt, pred, unlabelled, FPS)
        assert by_iou.total == report.total
        labelled = unlabelled.copy()
        labelled[:, 1] = detection_provenance(gt, unlabelled)
        assert np.any(labelled[:, 1] > 0)
        assert only(classify_id_switches(gt, pred, labelled, FPS)) == only(by_iou)


def test_total_equals_clear_idsw_with_birds_and_occlusion() -> None:
    sim = pytest.importorskip("gldt_core.sim")
    gt = sim.scene_ground_truth(3, 300)
    dets = detections_from_gt(gt, 11, (1920, 1080))
    for tracker in ("ByteTrack", "JPTrack"):
        pred = _tracked(tracker, gt, dets, int(gt[:, 0].max()))
        report = classify_id_switches(gt, pred, dets, FPS)
        assert report.total == evaluate_sequence(gt, pred)["IDSW"]


# --- the breakdown on default benchmark streams ----------------------------------------------------
def test_breakdown_of_jptrack_and_bytetrack_on_default_streams() -> None:
    reports: dict[str, list[IdSwitchReport]] = {"ByteTrack (ours)": [], "JPTrack JCMA+PMR": []}
    for k in range(3):
        gt = simple_multi_target_gt(1000 + k, 600)
        dets = detections_from_gt(gt, k, (1920, 1080))
        for name, runs in reports.items():
            pred = _tracked("ByteTrack" if name.startswith("Byte") else "JPTrack", gt, dets, 600)
            report = classify_id_switches(gt, pred, dets, FPS, sequence=f"sim{k:02d}")
            assert report.total == evaluate_sequence(gt, pred)["IDSW"]
            runs.append(report)
    merged = {name: merge_reports(runs) for name, runs in reports.items()}
    table = format_id_switch_table(merged)
    print("\n" + table)
    for name, report in merged.items():
        assert report.total == sum(r.total for r in reports[name]) > 0
        assert sum(report.counts.values()) == report.total
        assert report.counts[OTHER] <= max(1, report.total // 10), (name, report.counts)
        assert {e.sequence for e in report.events} <= {"sim00", "sim01", "sim02"}
        # Every birth really is a new id: its first row is after the object's previous match.
        for e in report.events:
            if e.category in (BIRTH_GAP, BIRTH_DETECTED):
                assert e.new_first_frame <= e.frame
    lines = table.splitlines()
    assert all(any(line.startswith(c) for line in lines) for c in CATEGORIES)
    assert lines[-1].split()[1:] == [str(merged[n].total) for n in merged]


def test_table_lists_categories_per_tracker() -> None:
    gt = gt_of([1], 40)
    pred = on(1, 1, range(1, 11)) + on(1, 2, range(11, 14)) + on(1, 1, range(14, 41))
    report = classify(gt, pred, dets_of(gt))
    table = format_id_switch_table({"A": report, "B": IdSwitchReport()})
    rows = {line.split("  ")[0].strip(): line for line in table.splitlines()}
    assert rows[BIRTH_DETECTED].split()[-3:] == ["1", "(50%)", "0"]
    assert rows[FRAGMENT_RETURN].split()[-3:] == ["1", "(50%)", "0"]
    assert rows["total"].split()[-2:] == ["2", "0"]
