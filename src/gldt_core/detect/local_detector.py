"""The local detector: the P2 model on square ROIs of one frame, all ROIs in ONE onnxruntime batch.

Its work on a frame is split in two public halves, so that the ROS graph can run them in
different processes and still give the boxes of the offline GL-DT system:

- :meth:`LocalDetector.crop` cuts one ROI out of the full frame (run by ``frame_pair_buffer``,
  the only node that holds full frames);
- :meth:`LocalDetector.detect_crops` runs the model on the crops as one batch and maps the boxes
  back to full-frame pixels (run by the ``local_detector`` node).

:meth:`LocalDetector.detect_rois` is the two in one call, for the offline system and the
benchmarks. Boxes are full-frame pixels with MOTChallenge class codes.

The second stage (:mod:`gldt_core.detect.second_stage`) re-scores the candidates on the ROI crops
of the current and the previous frame, so both halves of the split give the same rows wherever
they run.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gldt_core.detect.postprocess import (
    PAD_VALUE,
    decode_output,
    drop_degenerate,
    ensure_bgr,
    letterbox,
    nms,
    tile_rois,
    to_blob,
    unletterbox,
)
from gldt_core.detect.second_stage import (
    BESIDE,
    LOCAL_COLUMNS,
    PROBABILITY_COLUMNS,
    SecondStageChoice,
    attach_second_stage,
    candidate_threshold,
    default_score_threshold,
    one_hot_probabilities,
)
from gldt_core.detect.session import DetectorConfigError, OnnxDetector, check_image_input, check_score_threshold
from gldt_core.detect.shipped import DEFAULT_LOCAL_MODEL

LOCAL_INPUT_EXPECTATION = "one input (N, 3, S, S) float32 RGB ROI crops"
#: Column of a local detection row that holds the index of its ROI.
ROI_INDEX_COLUMN = 6


class LocalDetector(OnnxDetector):
    """The local P2 detector on square ROIs of one frame, run as ONE onnxruntime batch."""

    EXPECTATION = LOCAL_INPUT_EXPECTATION

    def __init__(
        self,
        model_path: Path | str | None = None,
        providers: Sequence[str] = ("CPUExecutionProvider",),
        score_threshold: float | None = None,
        num_threads: int | None = None,
        iou_threshold: float = 0.5,
        max_detections_per_roi: int = 100,
        classes: Sequence[int] | None = None,
        second_stage: SecondStageChoice = BESIDE,
    ):
        if score_threshold is None:
            score_threshold = default_score_threshold(second_stage is not None)
        inputs = self._open(model_path, DEFAULT_LOCAL_MODEL, providers, num_threads, score_threshold, iou_threshold)
        if len(inputs) != 1:
            raise DetectorConfigError(
                f"{self.model_path}: has {len(inputs)} inputs; "
                "a local detector needs one (N, 3, S, S) batch of ROI crops"
            )
        model_input = inputs[0]
        check_image_input(self.model_path, model_input, "(N, 3, S, S) float32 RGB ROI crops")
        self.input_name = model_input.name
        self.input_side, self.input_multiple = self._input_geometry(model_input)
        # The scale the model learned its objects at (an ROI of ``roi_side`` px to the input):
        # smaller ROIs are padded, not enlarged, so their targets keep that size.
        self.max_scale = self.input_side / float(self.card.get("roi_side", self.input_side))
        self._read_classes(classes)
        self.max_detections_per_roi = int(max_detections_per_roi)
        self.second_stage, self.decode_threshold = attach_second_stage(
            second_stage,
            self.model_path,
            providers=providers,
            score_threshold=self.score_threshold,
            classes=self.classes,
        )

    def at_score_threshold(self, score_threshold: float) -> LocalDetector:
        """This detector at another score threshold, sharing its opened model and second stage
        (their onnxruntime sessions hold no state between calls): the LD frames' detector and the
        GD frame's tile detector (:func:`~gldt_core.detect.fusion.build_tile_detector`) open each
        file once."""
        check_score_threshold(score_threshold)
        twin = copy.copy(self)
        twin.score_threshold = float(score_threshold)
        if self.second_stage is not None:
            twin.second_stage = copy.copy(self.second_stage)
            twin.second_stage.score_threshold = twin.score_threshold
        twin.decode_threshold = candidate_threshold(twin.second_stage, twin.score_threshold)
        return twin

    def _input_geometry(self, model_input: Any) -> tuple[int, int | None]:
        """``(S, multiple)``: the square input side the ROIs are scaled for, and, for a model whose
        height and width are dynamic, the multiple its input sides must be (None: a fixed S).
        A dynamic model takes S and the multiple from its card (``input_size``, ``input_multiple``)."""
        h, w = model_input.shape[2], model_input.shape[3]
        if isinstance(h, int) and isinstance(w, int):
            if h != w:
                raise DetectorConfigError(
                    f"{self.model_path}: input {model_input.name!r} has shape {model_input.shape}; "
                    "expected (N, 3, S, S) with a square S"
                )
            return int(h), None
        size = self.card.get("input_size")
        multiple = self.card.get("input_multiple")
        if not (isinstance(size, list) and len(size) == 2 and size[0] == size[1] and isinstance(multiple, int)):
            raise DetectorConfigError(
                f"{self.model_path}: input {model_input.name!r} has dynamic sides {model_input.shape}, but its card "
                "gives no square input_size and input_multiple to scale the ROIs for"
            )
        side = int(size[0])
        if multiple < 1 or side % multiple:
            raise DetectorConfigError(f"{self.model_path}: card input_size {size} is not a multiple of {multiple}")
        return side, multiple

    def batch_side(self, crop_sides: Sequence[int]) -> int:
        """The square input side of one batch of crops whose longer sides are ``crop_sides``: the
        model's S, or for a model with dynamic sides the smallest multiple that holds every crop
        at :attr:`max_scale`. On a 640x512 frame a scaled ROI of 142 px fits 128 instead of the
        256 that a 300 px ROI of a 1080p frame needs: the padding is not computed."""
        if self.input_multiple is None or not crop_sides:
            return self.input_side
        scaled = max(min(self.input_side, int(round(side * self.max_scale))) for side in crop_sides)
        multiple = self.input_multiple
        return min(self.input_side, max(multiple, -(-scaled // multiple) * multiple))

    @staticmethod
    def _check_rois(rois: np.ndarray, frame_w: int, frame_h: int) -> np.ndarray:
        """``rois`` as an ``(R, 4)`` int array of ``[x1, y1, x2, y2]``; ValueError for ROIs that are
        malformed, empty or inverted, or wholly outside the ``frame_w`` x ``frame_h`` frame."""
        rois = np.asarray(rois)
        if rois.size == 0:
            return np.zeros((0, 4), dtype=np.int64)
        if rois.ndim != 2 or rois.shape[1] != 4:
            raise ValueError(f"rois must be an (R, 4) array of [x1, y1, x2, y2], got shape {rois.shape}")
        if not np.all(np.isfinite(rois)):
            raise ValueError("rois contain NaN or infinite values")
        rois = np.round(rois).astype(np.int64)
        bad = (rois[:, 2] <= rois[:, 0]) | (rois[:, 3] <= rois[:, 1])
        if bad.any():
            raise ValueError(f"roi {int(np.flatnonzero(bad)[0])} is empty or inverted: {rois[bad][0].tolist()}")
        outside = (rois[:, 2] <= 0) | (rois[:, 3] <= 0) | (rois[:, 0] >= frame_w) | (rois[:, 1] >= frame_h)
        if outside.any():
            raise ValueError(
                f"roi {int(np.flatnonzero(outside)[0])} {rois[outside][0].tolist()} "
                f"lies outside the {frame_w}x{frame_h} frame"
            )
        return rois

    @staticmethod
    def crop(frame: np.ndarray, roi: np.ndarray) -> np.ndarray:
        """First half of the split: the ROI's pixels; parts outside the frame are filled with the
        letterbox grey."""
        h, w = frame.shape[:2]
        x1, y1, x2, y2 = (int(v) for v in roi)
        out = np.full((y2 - y1, x2 - x1, 3), PAD_VALUE, dtype=np.uint8)
        sx1, sy1, sx2, sy2 = max(x1, 0), max(y1, 0), min(x2, w), min(y2, h)
        out[sy1 - y1 : sy2 - y1, sx1 - x1 : sx2 - x1] = frame[sy1:sy2, sx1:sx2]
        return out

    def detect_crops(
        self,
        crops: Sequence[np.ndarray],
        rois: np.ndarray,
        frame_width: int,
        frame_height: int,
        previous_crops: Sequence[np.ndarray] | None = None,
    ) -> np.ndarray:
        """Second half of the split: the model on the ROI crops (:meth:`crop`) as one batch.

        Returns ``(N, 10)`` float32 ``[x1, y1, x2, y2, score, class_id, roi_index, p_drone, p_bird,
        p_airplane]`` in pixels of the ``frame_width`` x ``frame_height`` frame the crops were cut
        from. ``previous_crops`` (the same ROIs cut from the previous frame; None: the crops
        themselves) let the second stage see motion.
        """
        rois = np.asarray(rois, dtype=np.int64).reshape(-1, 4)
        if len(crops) != len(rois):
            raise ValueError(f"{len(crops)} crops but {len(rois)} ROIs")
        if previous_crops is not None and len(previous_crops) != len(crops):
            raise ValueError(f"{len(previous_crops)} previous crops but {len(crops)} crops")
        if len(rois) == 0:
            return np.zeros((0, LOCAL_COLUMNS), dtype=np.float32)
        side = self.batch_side([max(int(r[2] - r[0]), int(r[3] - r[1])) for r in rois])
        inputs, mappings, pairs = [], [], []
        for index, (crop, roi) in enumerate(zip(crops, rois)):
            expected = (int(roi[3] - roi[1]), int(roi[2] - roi[0]))
            crop = ensure_bgr(crop, "ROI crop")
            if crop.shape[:2] != expected:
                raise ValueError(f"crop of shape {crop.shape[:2]} does not match its ROI {roi.tolist()} ({expected})")
            previous = crop if previous_crops is None else ensure_bgr(previous_crops[index], "previous ROI crop")
            if previous.shape != crop.shape:
                raise ValueError(f"previous crop of shape {previous.shape[:2]} does not match its ROI {roi.tolist()}")
            image, mapping = letterbox(crop, side, side, self.max_scale)
            inputs.append(image)
            mappings.append(mapping)
            pairs.append((previous, crop))
        (output,) = self.session.run(None, {self.input_name: to_blob(inputs)})
        candidates = []
        for out, mapping, roi in zip(output, mappings, rois):
            detections = decode_output(
                out,
                self.decode_threshold,
                self.iou_threshold,
                self.max_detections_per_roi,
                box_scale=(side, side),
                channels=self.class_channels,
            )
            # Boxes in the crop's pixels; those in the padding of ROIs that stick out are dropped later.
            candidates.append(self._label(unletterbox(detections, mapping, int(roi[2] - roi[0]), int(roi[3] - roi[1]))))
        if self.second_stage is not None:
            rescored = self.second_stage.rescore_many([(p, c, d) for (p, c), d in zip(pairs, candidates)])
        else:
            rescored = [np.concatenate([d, one_hot_probabilities(d[:, 5])], axis=1) for d in candidates]
        results = []
        for index, (detections, roi) in enumerate(zip(rescored, rois)):
            if not len(detections):
                continue
            detections = detections.astype(np.float64)
            detections[:, [0, 2]] = (detections[:, [0, 2]] + roi[0]).clip(0, frame_width)
            detections[:, [1, 3]] = (detections[:, [1, 3]] + roi[1]).clip(0, frame_height)
            detections = drop_degenerate(detections)
            roi_column = np.full((len(detections), 1), index, dtype=np.float64)
            results.append(
                np.concatenate((detections[:, :6], roi_column, detections[:, 6 : 6 + PROBABILITY_COLUMNS]), 1)
            )
        if not results:
            return np.zeros((0, LOCAL_COLUMNS), dtype=np.float32)
        return np.concatenate(results).astype(np.float32)

    def detect_rois(
        self, frame_bgr: np.ndarray, rois: np.ndarray, previous_bgr: np.ndarray | None = None
    ) -> np.ndarray:
        """``(N, 10)`` float32 rows of :meth:`detect_crops` in full-frame pixels; ``previous_bgr``
        (same size; None: the frame itself) is cut at the same ROIs for the second stage."""
        frame = ensure_bgr(frame_bgr, "frame")
        h, w = frame.shape[:2]
        rois = self._check_rois(rois, w, h)
        if len(rois) == 0:
            return np.zeros((0, LOCAL_COLUMNS), dtype=np.float32)
        previous_crops = None
        if previous_bgr is not None and self.second_stage is not None:
            previous = ensure_bgr(previous_bgr, "previous frame")
            if previous.shape != frame.shape:
                raise ValueError(f"previous frame {previous.shape[:2]} and frame {frame.shape[:2]} differ in size")
            previous_crops = [self.crop(previous, roi) for roi in rois]
        return self.detect_crops([self.crop(frame, roi) for roi in rois], rois, w, h, previous_crops)

    def detect_tiles(
        self, frame_bgr: np.ndarray, previous_bgr: np.ndarray | None = None, side: int = 300
    ) -> np.ndarray:
        """``(N, 9)`` rows of :meth:`detect_rois` without the ROI index, over ``side x side`` tiles
        that cover the whole frame (:func:`~gldt_core.detect.postprocess.tile_rois`: no tracker
        is there to place ROIs), the tile seams merged by NMS at IoU 0.5."""
        h, w = frame_bgr.shape[:2]
        rows = np.delete(self.detect_rois(frame_bgr, tile_rois(w, h, side), previous_bgr), ROI_INDEX_COLUMN, axis=1)
        return rows[nms(rows[:, :4], rows[:, 4], 0.5)] if len(rows) else rows
