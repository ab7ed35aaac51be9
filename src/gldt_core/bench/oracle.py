"""Ground truth in place of the detectors' boxes, at the detectors' own cost: the schedule's ceiling.

``gldt bench ablation --oracle`` asks how fast and how good the GL-DT schedule could be on this
machine if the detectors were perfect. Each detector still runs on every frame it is given, so
every frame costs what it costs with the shipped models, but what the GL-DT system receives is the
ground truth of that frame: all target boxes on a GD frame, the target boxes whose centre lies
in an ROI on an LD frame. The scheduler, the ROIs and the tracker then act as they would behind
a detector that misses nothing and invents nothing.

The GL-DT speed-up over the global detector on every frame is set by two things: how often the
schedule has to fall back to GD, and what an LD frame costs beside a GD frame. The first depends
on the detector (a drone it scores low is not tracked, so GD keeps searching); the oracle removes
that dependence and leaves what Table I's counters and this CPU allow.

Two limits of the stand-in: LD boxes still pass the system's NMS across ROIs (GD boxes pass
none), so two targets overlapping on an LD frame lose one box there; and the truth handed out is
that of the frame the feed yielded last, so frames must be processed one at a time, as the
ablation does (a reader that decodes ahead would hand out a later frame's truth).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import Any

import numpy as np

#: Score given to every ground-truth box: above any tracker threshold the configs use.
ORACLE_SCORE = 0.95
#: Class id the oracle's boxes carry (drone, as in the ground truth and the models' cards).
ORACLE_CLASS = 1.0


def target_boxes_by_frame(gt: Any) -> dict[int, np.ndarray]:
    """``{frame (1-based): (K, 4) xyxy}`` of the ground-truth targets the metrics score.

    The same rows :mod:`gldt_core.eval.mot_metrics` counts as targets: class 1 (drone) or
    unlabelled (``-1``), and column 6 ("considered") non-zero.
    """
    gt = np.asarray(gt, dtype=np.float64).reshape(-1, 10)
    gt = gt[((gt[:, 7] == 1) | (gt[:, 7] == -1)) & (gt[:, 6] != 0)]
    boxes = np.column_stack([gt[:, 2], gt[:, 3], gt[:, 2] + gt[:, 4], gt[:, 3] + gt[:, 5]])
    return {int(f): boxes[gt[:, 0] == f] for f in np.unique(gt[:, 0])}


def as_detections(boxes: np.ndarray, roi_index: np.ndarray | None = None) -> np.ndarray:
    """Ground-truth ``(K, 4)`` boxes as detector rows: ``[x1, y1, x2, y2, score, class]``, plus the
    ROI column of the local detector's rows when ``roi_index`` is given."""
    columns = 6 if roi_index is None else 7
    out = np.empty((len(boxes), columns), dtype=np.float32)
    out[:, :4] = boxes
    out[:, 4] = ORACLE_SCORE
    out[:, 5] = ORACLE_CLASS
    if roi_index is not None:
        out[:, 6] = roi_index
    return out


class GroundTruthFeed:
    """The ground truth of the frame being played, for the oracle detectors to hand out.

    :meth:`play` wraps a sequence's frames and sets :attr:`boxes` before each frame is yielded,
    so every GL-DT system that processes that frame (the ablation interleaves four) sees its truth;
    every system must be done with a frame before the next one is drawn (no read-ahead).
    """

    def __init__(self) -> None:
        self.boxes = np.zeros((0, 4))

    def play(self, frames: Iterable[Any], gt: Any) -> Iterator[Any]:
        """Yield ``frames`` (objects with a 0-based ``index``), with :attr:`boxes` set to each one's truth."""
        by_frame = target_boxes_by_frame(gt)
        empty = np.zeros((0, 4))
        try:
            for frame in frames:
                self.boxes = by_frame.get(int(frame.index) + 1, empty)
                yield frame
        finally:
            self.boxes = empty


class OracleGlobalDetector:
    """Runs ``detector`` for its time, returns the frame's ground truth as ``(K, 6)`` detections."""

    def __init__(self, detector: Any, feed: GroundTruthFeed) -> None:
        self.detector = detector
        self.feed = feed

    def detect(self, previous_bgr: np.ndarray | None, current_bgr: np.ndarray) -> np.ndarray:
        self.detector.detect(previous_bgr, current_bgr)
        return as_detections(self.feed.boxes)

    def detect_pair(
        self, previous_bgr: np.ndarray | None, current_bgr: np.ndarray, carry: Any = None
    ) -> tuple[np.ndarray, Any]:
        """As the real ``detect_pair``, with the real carry, so feature reuse costs what it costs
        (a detector without ``detect_pair`` runs ``detect`` and carries nothing, as the GL-DT
        system would run it)."""
        detect_pair = getattr(self.detector, "detect_pair", None)
        if detect_pair is None:
            self.detector.detect(previous_bgr, current_bgr)
            return as_detections(self.feed.boxes), None
        _, next_carry = detect_pair(previous_bgr, current_bgr, carry)
        return as_detections(self.feed.boxes), next_carry


class OracleLocalDetector:
    """Runs ``detector`` on the ROIs for its time, returns the truth inside them as ``(N, 7)``.

    A target belongs to the first ROI that holds its centre (the real detector reports a target
    seen by two overlapping ROIs twice, and the GL-DT system merges the two; one copy is the merged
    result); a target in no ROI is not seen, as it would not be by the real local detector.
    """

    def __init__(self, detector: Any, feed: GroundTruthFeed) -> None:
        self.detector = detector
        self.feed = feed

    def detect_rois(self, frame_bgr: np.ndarray, rois: np.ndarray) -> np.ndarray:
        self.detector.detect_rois(frame_bgr, rois)
        rois = np.asarray(rois, dtype=np.float64).reshape(-1, 4)
        boxes = self.feed.boxes
        if not len(rois) or not len(boxes):
            return np.zeros((0, 7), dtype=np.float32)
        x = (boxes[:, 0] + boxes[:, 2])[:, None] / 2
        y = (boxes[:, 1] + boxes[:, 3])[:, None] / 2
        inside = (x >= rois[:, 0]) & (x < rois[:, 2]) & (y >= rois[:, 1]) & (y < rois[:, 3])
        seen = inside.any(axis=1)
        return as_detections(boxes[seen], inside[seen].argmax(axis=1))
