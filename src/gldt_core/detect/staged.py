"""The detectors split at the process boundary of the ROS graph.

``GlobalDetector.detect`` = :func:`prepare_global_input` on both frames (letterbox to the network
input) + :func:`detect_global_streamed` (given the previous GD frame's features when at hand);
``LocalDetector.detect_rois`` = ``LocalDetector.crop`` on each ROI + :func:`detect_local_crops`. The ROS graph runs the first half in
``frame_pair_buffer`` (the only node holding full frames) and the second half in the detector
nodes, and the offline wrappers call these same functions, so both give identical boxes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from gldt_core.detect.postprocess import Letterbox, decode_output, ensure_bgr, letterbox, to_blob, unletterbox


def _drop_degenerate(detections: np.ndarray) -> np.ndarray:
    from gldt_core.detect.runtime import _drop_degenerate as drop

    return drop(detections)


def prepare_global_input(detector: Any, frame_bgr: np.ndarray) -> tuple[np.ndarray, Letterbox]:
    """Letterbox one full frame to the global detector's network input; returns image and mapping."""
    frame = ensure_bgr(frame_bgr, "frame")
    height, width = frame.shape[:2]
    input_w, input_h = detector.input_size(width, height)
    return letterbox(frame, input_w, input_h)


@dataclass(frozen=True, eq=False)
class GlobalCarry:
    """What one GD frame leaves for the next one: its letterboxed network input and, when the
    detector reuses features (:mod:`gldt_core.detect.feature_reuse`), the backbone features
    computed from that input. Valid only for the frame that comes right after it."""

    input: np.ndarray
    features: np.ndarray | None = None


def detect_global_streamed(
    detector: Any,
    previous_input: np.ndarray,
    current_input: np.ndarray,
    mapping: Letterbox,
    frame_width: int,
    frame_height: int,
    previous_features: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Run AM-YOLO on an already letterboxed pair: ``(N, 6)`` float32 boxes in full-frame pixels,
    and the current frame's features for the next GD frame.

    ``previous_features`` must have been returned for ``previous_input`` (the caller keys them by
    frame); ones of the wrong shape are ignored and recomputed. The features returned are None
    when the detector has no split model to reuse them with.
    """
    if previous_input.shape != current_input.shape:
        raise ValueError(
            f"letterboxed previous {previous_input.shape} and current {current_input.shape} inputs differ in shape"
        )
    input_h, input_w = current_input.shape[:2]
    reuse = getattr(detector, "feature_reuse", None)
    current_features = None
    if reuse is not None:
        current_blob = to_blob([current_input])
        if not reuse.accepts(previous_features, input_h, input_w):
            previous_blob = current_blob if previous_input is current_input else to_blob([previous_input])
            previous_features = reuse.features(previous_blob)
        output, current_features = reuse.detect(current_blob, previous_features)
    elif detector.dual_frame:
        feed = dict(zip(detector.input_names, (to_blob([previous_input]), to_blob([current_input]))))
        (output,) = detector.session.run(None, feed)
    else:
        (output,) = detector.session.run(None, {detector.input_names[0]: to_blob([current_input])})
    detections = decode_output(
        output[0],
        detector.score_threshold,
        detector.iou_threshold,
        detector.max_detections,
        box_scale=(input_w, input_h),
        channels=detector.class_channels,
    )
    detections = _drop_degenerate(unletterbox(detections, mapping, frame_width, frame_height))
    if len(detections):
        detections[:, 5] = detector.class_ids[detections[:, 5].astype(np.int64)]
    return detections.astype(np.float32), current_features


def detect_local_crops(
    detector: Any,
    crops: Sequence[np.ndarray],
    rois: np.ndarray,
    frame_width: int,
    frame_height: int,
) -> np.ndarray:
    """The local model on ROI crops (one batch); ``(N, 7)`` ``[x1,y1,x2,y2,score,class,roi]`` full-frame px."""
    rois = np.asarray(rois, dtype=np.int64).reshape(-1, 4)
    if len(crops) != len(rois):
        raise ValueError(f"{len(crops)} crops but {len(rois)} ROIs")
    if len(rois) == 0:
        return np.zeros((0, 7), dtype=np.float32)
    inputs, mappings = [], []
    for crop, roi in zip(crops, rois):
        expected = (int(roi[3] - roi[1]), int(roi[2] - roi[0]))
        if crop.shape[:2] != expected:
            raise ValueError(f"crop of shape {crop.shape[:2]} does not match its ROI {roi.tolist()} ({expected})")
        image, mapping = letterbox(ensure_bgr(crop, "ROI crop"), detector.input_side, detector.input_side)
        inputs.append(image)
        mappings.append(mapping)
    (output,) = detector.session.run(None, {detector.input_name: to_blob(inputs)})
    results = []
    for index, (out, mapping, roi) in enumerate(zip(output, mappings, rois)):
        side = detector.input_side
        detections = decode_output(
            out,
            detector.score_threshold,
            detector.iou_threshold,
            detector.max_detections_per_roi,
            box_scale=(side, side),
            channels=detector.class_channels,
        )
        if not len(detections):
            continue
        detections = unletterbox(detections, mapping, int(roi[2] - roi[0]), int(roi[3] - roi[1]))
        detections[:, [0, 2]] += roi[0]
        detections[:, [1, 3]] += roi[1]
        detections[:, [0, 2]] = detections[:, [0, 2]].clip(0, frame_width)
        detections[:, [1, 3]] = detections[:, [1, 3]].clip(0, frame_height)
        detections = _drop_degenerate(detections)  # boxes in the padding of ROIs that stick out of the frame
        detections[:, 5] = detector.class_ids[detections[:, 5].astype(np.int64)]
        results.append(np.concatenate((detections, np.full((len(detections), 1), index, dtype=np.float32)), 1))
    if not results:
        return np.zeros((0, 7), dtype=np.float32)
    return np.concatenate(results).astype(np.float32)
