"""Per-frame steps of GL-DT shared by :class:`GLDTSystem` and the ROS nodes.

The ROS graph splits a frame's work over processes (tracker, scheduler, detectors); each node
calls the same function here that the in-process :class:`GLDTSystem` calls, which is what makes a lockstep
replay through the graph reproduce the offline run exactly.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from gldt_core.detect.postprocess import nms
from gldt_core.detect.second_stage import LOCAL_COLUMNS, PROBABILITY_COLUMNS, one_hot_probabilities


def state_name(state: Any) -> str:
    """Upper-case name of a track state (an enum member or a string): trackers that are not ours
    may use their own enum, so states are compared by name."""
    return str(getattr(state, "name", state)).upper()


def stable_predictions(tracker: Any, t: float, keep_lost_frames: int) -> np.ndarray:
    """Predicted ``[x1, y1, x2, y2, id]`` at ``t`` of the tracks worth an ROI.

    Confirmed and recovered tracks, plus lost ones for ``keep_lost_frames`` frames, so LD can
    re-find a target it missed once instead of dropping its window at the first miss.
    """
    predictions = np.asarray(tracker.predict(t), dtype=np.float64).reshape(-1, 5)
    tracks = getattr(tracker, "tracks", None)
    if tracks is None or len(predictions) == 0:
        return predictions
    wanted = set()
    for track in tracks:
        state = state_name(getattr(track, "state", ""))
        if state in ("CONFIRMED", "RECOVERED") or (
            state == "LOST" and int(getattr(track, "frames_since_update", 0)) <= keep_lost_frames
        ):
            wanted.add(int(track.track_id))
    mask = np.array([int(i) in wanted for i in predictions[:, 4]], dtype=bool)
    return predictions[mask]


def valid_detection_mask(raw: np.ndarray) -> np.ndarray:
    """True for rows with finite box and score and positive width and height.

    A detector fault (NaN box, inverted box) must cost one detection, never the tracker's state.
    """
    raw = np.asarray(raw, dtype=np.float64)
    if raw.size == 0:
        return np.zeros(len(raw), dtype=bool)
    return np.all(np.isfinite(raw[:, :5]), axis=1) & (raw[:, 2] > raw[:, 0]) & (raw[:, 3] > raw[:, 1])


def with_class_probabilities(raw: np.ndarray, columns: int) -> np.ndarray:
    """Detector rows as ``(N, columns)`` floats. Rows without the three class-probability columns
    (an injected detector that reports ``columns - 3``) get one-hot ones from their class id."""
    raw = np.asarray(raw, dtype=np.float64)
    if raw.size == 0:
        return np.zeros((0, columns))
    width = raw.shape[-1] if raw.ndim == 2 else columns
    raw = raw.reshape(-1, width)
    if width == columns - PROBABILITY_COLUMNS:
        return np.concatenate([raw, one_hot_probabilities(np.nan_to_num(raw[:, 5]))], axis=1)
    if width != columns:
        raise ValueError(f"detector rows have {width} columns; expected {columns} (or {columns - PROBABILITY_COLUMNS})")
    return raw


def filter_classes(raw: np.ndarray, columns: int, classes: Sequence[int] | None) -> np.ndarray:
    """Drop invalid rows (see :func:`valid_detection_mask`), then keep detections whose class id
    (column 5) is in ``classes`` (all when None)."""
    raw = np.asarray(raw, dtype=np.float64).reshape(-1, columns)
    if len(raw):
        raw = raw[valid_detection_mask(raw)]
    if classes is not None and len(raw):
        raw = raw[np.isin(raw[:, 5].astype(np.int64), np.asarray(classes, dtype=np.int64))]
    return raw


def merge_local_detections(raw: np.ndarray, classes: Sequence[int] | None, nms_iou: float) -> np.ndarray:
    """Class filter, then NMS across overlapping ROIs: ``(N, 10)`` local detections for the tracker."""
    raw = filter_classes(raw, LOCAL_COLUMNS, classes)
    if len(raw) > 1:
        raw = raw[nms(raw[:, :4], raw[:, 4], nms_iou)]
    return raw


def drop_nested(raw: np.ndarray, nested_threshold: float | None) -> np.ndarray:
    """Detector rows without the boxes nested in a better-scored one (more than
    ``nested_threshold`` of the smaller box inside the other; None keeps all).

    The second stage calls a part of a close drone, or the drone with sky around it, a drone too;
    such boxes overlap the whole one below NMS's IoU and would start tracks of their own."""
    raw = np.asarray(raw, dtype=np.float64)
    if nested_threshold is None or len(raw) < 2:
        return raw
    return raw[np.sort(nms(raw[:, :4], raw[:, 4], 1.0, nested_threshold))]


def detections_per_roi(local_detections: np.ndarray, roi_count: int) -> np.ndarray:
    """How many (merged) local detections each ROI produced, for the scheduler's N_m rule."""
    roi_index = np.asarray(local_detections, dtype=np.float64).reshape(-1, LOCAL_COLUMNS)[:, 6].astype(np.int64)
    if len(roi_index) and (roi_index.min() < 0 or roi_index.max() >= roi_count):
        raise ValueError(f"local detector returned roi_index {sorted(set(roi_index.tolist()))} for {roi_count} ROIs")
    return np.bincount(roi_index, minlength=roi_count)[:roi_count]
