"""``gldt bench ablation --oracle``: the detectors still run (their time is what the schedule
pays) but the pipelines get the ground truth, so the run measures the schedule's ceiling."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gldt_core.bench.ablation import CachedSequence, format_table, run_dataset
from gldt_core.bench.oracle import (
    ORACLE_CLASS,
    ORACLE_SCORE,
    GroundTruthFeed,
    OracleGlobalDetector,
    OracleLocalDetector,
    target_boxes_by_frame,
)
from gldt_core.system.config import SystemConfig
from gldt_core.system.runner import SimpleFrame


def gt_row(
    frame: int, track: int, x: float, y: float, w: float, h: float, considered: int = 1, cls: int = 1
) -> list[float]:
    return [frame, track, x, y, w, h, considered, cls, 1, -1]


class CountingGlobal:
    """A global detector that finds nothing and counts its calls (no ``detect_pair``)."""

    def __init__(self) -> None:
        self.calls = 0

    def detect(self, previous_bgr, current_bgr) -> np.ndarray:
        self.calls += 1
        return np.zeros((0, 6), dtype=np.float32)


class PairingGlobal(CountingGlobal):
    """One with ``detect_pair``: returns its own carry, which the oracle must pass through."""

    def detect_pair(self, previous_bgr, current_bgr, carry=None):
        self.calls += 1
        self.last_carry_in = carry
        return np.array([[1, 1, 5, 5, 0.3, 1]], dtype=np.float32), ("carry", self.calls)


class CountingLocal:
    def __init__(self) -> None:
        self.calls = 0
        self.rois_seen: list[np.ndarray] = []

    def detect_rois(self, frame_bgr, rois) -> np.ndarray:
        self.calls += 1
        self.rois_seen.append(np.asarray(rois).copy())
        return np.zeros((0, 7), dtype=np.float32)


def test_targets_are_the_rows_the_metrics_score_as_xyxy() -> None:
    gt = np.array(
        [
            gt_row(1, 1, 10, 20, 4, 6),
            gt_row(1, 2, 50, 50, 8, 8, cls=2),  # a bird: not a target
            gt_row(1, 3, 70, 70, 8, 8, considered=0),  # not considered
            gt_row(2, 4, 30, 40, 5, 5, cls=-1),  # unlabelled counts as a drone
        ]
    )
    boxes = target_boxes_by_frame(gt)
    assert sorted(boxes) == [1, 2]
    np.testing.assert_allclose(boxes[1], [[10, 20, 14, 26]])
    np.testing.assert_allclose(boxes[2], [[30, 40, 35, 45]])


def test_the_feed_holds_each_played_frames_truth_and_nothing_after() -> None:
    feed = GroundTruthFeed()
    gt = np.array([gt_row(1, 1, 0, 0, 2, 2), gt_row(3, 1, 4, 4, 2, 2)])
    frames = [SimpleFrame(index=i, stamp=i / 30, image=None) for i in range(3)]
    seen = [feed.boxes.copy() for _ in feed.play(frames, gt)]
    np.testing.assert_allclose(seen[0], [[0, 0, 2, 2]])
    assert seen[1].shape == (0, 4)  # frame 2 has no target
    np.testing.assert_allclose(seen[2], [[4, 4, 6, 6]])
    assert feed.boxes.shape == (0, 4)


def test_the_global_oracle_runs_the_detector_and_returns_the_truth_with_its_carry() -> None:
    feed = GroundTruthFeed()
    feed.boxes = np.array([[10.0, 10, 20, 20], [30, 30, 34, 36]])
    inner = PairingGlobal()
    oracle = OracleGlobalDetector(inner, feed)
    frame = np.zeros((8, 8, 3), np.uint8)
    dets, carry = oracle.detect_pair(frame, frame, ("carry", 0))
    assert inner.calls == 1 and inner.last_carry_in == ("carry", 0) and carry == ("carry", 1)
    np.testing.assert_allclose(dets[:, :4], feed.boxes)
    assert (dets[:, 4] == ORACLE_SCORE).all() and (dets[:, 5] == ORACLE_CLASS).all()
    plain = OracleGlobalDetector(CountingGlobal(), feed)
    dets, carry = plain.detect_pair(frame, frame, None)
    assert plain.detector.calls == 1 and carry is None and len(dets) == 2
    assert len(plain.detect(frame, frame)) == 2 and plain.detector.calls == 2


def test_the_local_oracle_sees_only_targets_inside_an_roi_each_once() -> None:
    feed = GroundTruthFeed()
    feed.boxes = np.array(
        [
            [10.0, 10, 20, 20],  # centre (15, 15): ROI 0 only
            [140, 140, 150, 150],  # centre (145, 145): ROIs 0 and 1, reported once for ROI 0
            [260, 260, 270, 270],  # centre (265, 265): ROI 1
            [500, 10, 510, 20],  # in no ROI: unseen
        ]
    )
    inner = CountingLocal()
    oracle = OracleLocalDetector(inner, feed)
    rois = np.array([[0, 0, 200, 200], [100, 100, 300, 300]])
    dets = oracle.detect_rois(np.zeros((400, 600, 3), np.uint8), rois)
    assert inner.calls == 1
    np.testing.assert_array_equal(inner.rois_seen[0], rois)
    np.testing.assert_allclose(dets[:, :4], feed.boxes[:3])
    np.testing.assert_array_equal(dets[:, 6], [0, 0, 1])
    assert dets.shape == (3, 7) and dets.dtype == np.float32
    assert oracle.detect_rois(np.zeros((400, 600, 3), np.uint8), np.zeros((0, 4))).shape == (0, 7)
    assert inner.calls == 2


def blank_sequence(frames: int, size: tuple[int, int] = (640, 512)) -> CachedSequence:
    """``frames`` grey frames (the detectors here never look) and one drone drifting right."""
    ok, buffer = cv2.imencode(".jpg", np.full((size[1], size[0], 3), 128, np.uint8))
    assert ok
    gt = np.array([gt_row(k + 1, 1, 100 + 0.5 * k, 200, 12, 10) for k in range(frames)])
    return CachedSequence("blank", 30.0, [buffer] * frames, [k / 30 for k in range(frames)], gt)


def test_an_oracle_ablation_runs_every_detector_call_and_tracks_the_truth() -> None:
    """200 frames of one steady drone: with perfect boxes the schedule is Table I's cycle
    (30 GD, 120 LD, 30 GD, 20 LD), and every detector call the schedule makes still happens."""
    sequence = blank_sequence(200)
    gd, ld = CountingGlobal(), CountingLocal()
    listed = run_dataset([sequence], SystemConfig(), (gd, ld), oracle=True)
    rows = {row["variant"]: row for row in listed}
    gl_dt = rows["GD+LD+JPTrack"]
    assert gl_dt["gd_frames"] == 60 and rows["GD+LD+ByteTrack"]["gd_frames"] == 60
    assert gl_dt["roi_coverage"] == pytest.approx(1.0)
    for row in rows.values():
        assert row["MOTA"] > 95.0 and row["IDSW"] == 0, row
    # Two GD-only rows on all 200 frames, two GL-DT rows on their 60 GD frames; LD on the rest.
    assert gd.calls == 2 * 200 + 2 * 60
    assert ld.calls == 2 * 140
    assert "without the decode stage" in format_table("oracle", listed)
    # The same detectors without the oracle find nothing, so nothing is tracked.
    plain = {
        row["variant"]: row for row in run_dataset([sequence], SystemConfig(), (CountingGlobal(), CountingLocal()))
    }
    assert plain["GD+LD+JPTrack"]["MOTA"] <= 0.0 and plain["GD+LD+JPTrack"]["gd_frames"] == 200


def test_the_ratio_without_decode_takes_the_shared_stage_out_of_each_rows_time() -> None:
    from gldt_core.bench.ablation import _ratio_without_decode

    ours = {"fps": 1000.0 / 16.0, "stage_ms": {"decode": 7.0, "gd": 4.0, "ld": 3.0}}
    peer = {"fps": 1000.0 / 26.0, "stage_ms": {"decode": 7.0, "gd": 17.0}}
    assert _ratio_without_decode(ours, peer) == pytest.approx(19.0 / 9.0)
    no_decode = {"fps": 50.0, "stage_ms": {"gd": 20.0}}
    assert _ratio_without_decode(no_decode, peer) is None
