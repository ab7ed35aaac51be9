"""``gldt bench thresholds``: the grid is parsed strictly, and each pair's thresholds really reach
the detectors and JPTrack (detector doubles that score every drone 0.2, the real tracker)."""

from __future__ import annotations

import numpy as np
import pytest

from gldt_core.bench.thresholds import ThresholdPair, config_for, format_table, parse_grid, sweep
from gldt_core.system.config import SystemConfig
from gldt_core.system.runner import SimpleFrame

FPS = 30.0
SIZE = (640, 512)
FRAMES = 60
SCORE = 0.2  # what the doubles score every box: below the old 0.25 / 0.3 thresholds


def target_box(frame: int) -> np.ndarray:
    cx, cy = 100.0 + 3.0 * frame, 250.0
    return np.array([cx - 10, cy - 10, cx + 10, cy + 10])


def stamped(frame: int) -> np.ndarray:
    image = np.zeros((SIZE[1], SIZE[0], 3), dtype=np.uint8)
    image[0, 0, 0] = frame
    return image


class Clip:
    """One moving box per frame; ``gt`` empty for a bird clip (every drone track there is false)."""

    def __init__(self, name: str, with_truth: bool) -> None:
        self.name = name
        self.fps = FPS
        rows = [[k + 1, 1, *target_box(k)[:2], 20, 20, 1, 1, 1, -1] for k in range(FRAMES)]
        self.gt = np.array(rows, dtype=float) if with_truth else np.zeros((0, 10))

    def __len__(self) -> int:
        return FRAMES

    def __iter__(self):
        return (SimpleFrame(k, k / FPS, stamped(k)) for k in range(FRAMES))


class LowScoreGlobal:
    def __init__(self, threshold: float) -> None:
        self.threshold = threshold

    def detect(self, previous_bgr, current_bgr):
        if SCORE < self.threshold:
            return np.zeros((0, 6))
        return np.array([[*target_box(int(current_bgr[0, 0, 0])), SCORE, 1]])


class LowScoreLocal:
    def __init__(self, threshold: float) -> None:
        self.threshold = threshold

    def detect_rois(self, frame_bgr, rois):
        box = target_box(int(frame_bgr[0, 0, 0]))
        rows = [
            [*box, SCORE, 1, r]
            for r, roi in enumerate(np.asarray(rois).reshape(-1, 4))
            if SCORE >= self.threshold and roi[0] <= box[0] and box[2] <= roi[2]
        ]
        return np.array(rows[:1], dtype=float).reshape(-1, 7)


def make_detectors(config):
    threshold = config.detector.score_threshold
    return LowScoreGlobal(threshold), LowScoreLocal(threshold)


def test_grid_parsing_refuses_what_it_cannot_read():
    assert parse_grid("0.1:0.25, 0.25:0.3") == [ThresholdPair(0.1, 0.25), ThresholdPair(0.25, 0.3)]
    for bad in ("0.1", "0.1:x", "0.1:0.2:0.3", "1.5:0.2", ""):
        with pytest.raises(ValueError, match="--grid"):
            parse_grid(bad)


def test_config_for_sets_both_trackers_and_keeps_the_rest():
    config = config_for(SystemConfig(), ThresholdPair(0.12, 0.27))
    assert config.detector.score_threshold == 0.12
    assert config.tracker.jptrack["t_h"] == config.tracker.jptrack["new_track_thresh"] == 0.27
    assert config.tracker.bytetrack["track_thresh"] == config.tracker.bytetrack["new_track_thresh"] == 0.27
    assert config.scheduler == SystemConfig().scheduler and config.detector.classes == (1,)


def test_each_pair_reaches_detector_and_tracker():
    grid = [ThresholdPair(0.25, 0.3), ThresholdPair(0.1, 0.3), ThresholdPair(0.1, 0.15)]
    rows = sweep([Clip("drone", True)], [Clip("bird", False)], SystemConfig(), grid, make_detectors)
    dropped_by_detector, dropped_by_tracker, kept = rows
    # 0.2 boxes: the detector's 0.25 drops them; with 0.1 they reach JPTrack, whose t_h of 0.3
    # still starts no track; with 0.15 it tracks the drone, and the bird clip's box too.
    assert dropped_by_detector["MOTA"] == 0.0 and dropped_by_detector["false_boxes_per_frame"] == 0.0
    assert dropped_by_tracker["MOTA"] == 0.0 and dropped_by_tracker["false_boxes_per_frame"] == 0.0
    assert dropped_by_detector["gd_share"] == 1.0
    assert kept["MOTA"] > 80.0 and kept["IDSW"] == 0
    assert kept["false_boxes_per_frame"] > 0.8
    assert kept["gd_share"] < 1.0  # a stable track hands frames to the local detector
    table = format_table(rows)
    assert "det 0.1 / trk 0.15" in table and table.count("\n") == len(rows) + 1


def test_only_rows_published_as_drones_count_as_false_drones() -> None:
    from gldt_core.track.class_evidence import drone_track_rows

    rows = np.full((5, 10), -1.0)
    rows[:, 7] = [1, 2, 3, -1, 1]  # drone, bird, airplane, no evidence yet, drone
    assert drone_track_rows(rows) == 3
    assert drone_track_rows(np.zeros((0, 10))) == 0
