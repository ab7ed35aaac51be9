"""The global detector: AM-YOLO (or its no-STFF ablation) on a (previous, current) pair of full frames.

Its work on a frame pair is split in two public halves, so that the ROS graph can run them in
different processes and still give the boxes of the offline GL-DT system:

- :meth:`GlobalDetector.prepare` letterboxes one full frame to the network input (run by
  ``frame_pair_buffer``, the only node that holds full frames);
- :meth:`GlobalDetector.detect_prepared` runs the model on a letterboxed pair and maps the boxes
  back to full-frame pixels (run by the ``global_detector`` node).

:meth:`GlobalDetector.detect` and :meth:`GlobalDetector.detect_pair` are these two halves in one
call, for the offline system and the benchmarks. Boxes are full-frame pixels with MOTChallenge
class codes (1 drone, 2 bird, 3 airplane), so the tracker never sees network-input coordinates.

The second stage (:mod:`gldt_core.detect.second_stage`, by default ``second_stage.onnx`` beside
the model) re-scores and re-boxes the model's candidates on the same letterboxed pair, so both
halves of the split give the same rows wherever they run.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gldt_core.detect.feature_reuse import FeatureReuse, features_path, load_feature_reuse, reuse_path
from gldt_core.detect.fusion import fuse_with_tiles
from gldt_core.detect.local_detector import LocalDetector
from gldt_core.detect.postprocess import (
    Letterbox,
    decode_output,
    drop_degenerate,
    ensure_bgr,
    letterbox,
    rect_input_size,
    to_blob,
    unletterbox,
)
from gldt_core.detect.second_stage import (
    BESIDE,
    SecondStageChoice,
    attach_second_stage,
    default_score_threshold,
    one_hot_probabilities,
)
from gldt_core.detect.session import DetectorConfigError, OnnxDetector, check_image_input
from gldt_core.detect.shipped import DEFAULT_GLOBAL_MODEL

GLOBAL_INPUT_EXPECTATION = "inputs (previous, current), each (1, 3, H, W) float32 RGB"


@dataclass(frozen=True, eq=False)
class GlobalCarry:
    """What one GD frame leaves for the next one: its letterboxed network input and, when the
    detector reuses features (:mod:`gldt_core.detect.feature_reuse`), the backbone features
    computed from that input. Valid only for the frame that comes right after it."""

    input: np.ndarray
    features: np.ndarray | None = None


class GlobalDetector(OnnxDetector):
    """AM-YOLO on a (previous, current) pair of full frames; boxes in full-frame pixels.

    The frame is letterboxed into a rectangular input whose long side is ``long_side`` (default:
    the card's training long side) and whose sides are multiples of the card's ``input_multiple``;
    a 1920x1080 frame becomes 640x384 with the default 640. ``optimize_graph=False`` is for
    callers that only letterbox frames for it (:meth:`prepare`, :meth:`input_size`): it opens
    much faster.

    ``feature_reuse`` (None: when available) runs the split pair written by ``gldt export MODEL
    --feature-reuse`` instead of the full model, with the same boxes; :meth:`detect_pair` and
    :meth:`detect_prepared` then hand each GD frame's features to the next
    (:mod:`gldt_core.detect.feature_reuse`).

    ``tile_detector`` (a :class:`LocalDetector` with the same second stage, its own score
    threshold at most half of this one's) also runs the local model over tiles of each letterboxed
    frame and fuses its boxes with AM-YOLO's (:func:`gldt_core.detect.fusion.fuse_with_tiles`):
    the model's candidates are then kept down to half of ``score_threshold``, which applies to
    the fused score. It may also be a function that builds it: it is called once this detector's
    own model has opened, so a broken global model is the error a user sees first.
    """

    EXPECTATION = GLOBAL_INPUT_EXPECTATION

    def __init__(
        self,
        model_path: Path | str | None = None,
        providers: Sequence[str] = ("CPUExecutionProvider",),
        score_threshold: float | None = None,
        num_threads: int | None = None,
        iou_threshold: float = 0.5,
        long_side: int | None = None,
        max_detections: int = 300,
        optimize_graph: bool = True,
        classes: Sequence[int] | None = None,
        feature_reuse: bool | None = None,
        second_stage: SecondStageChoice = BESIDE,
        tile_detector: LocalDetector | Callable[[], LocalDetector] | None = None,
    ):
        if feature_reuse and not optimize_graph:
            raise DetectorConfigError(
                "feature_reuse=True runs the model, but optimize_graph=False opens it for its geometry only"
            )
        # Where a split pair lies next to the model, the model is checked first, opened unoptimised
        # (much faster) so errors name the file given, and optimised only if the pair cannot be
        # used or someone asks for ``session``. Without one it is opened optimised straight away.
        path = Path(model_path) if model_path is not None else DEFAULT_GLOBAL_MODEL
        split_first = (
            optimize_graph
            and feature_reuse is not False
            and features_path(path).is_file()
            and reuse_path(path).is_file()
        )
        if score_threshold is None:
            score_threshold = default_score_threshold(second_stage is not None)
        if not optimize_graph:
            tile_detector = None  # opened for its geometry only: it never scores boxes
        # With tiles, a box one detector misses counts half its score: keep candidates down to half.
        own_threshold = score_threshold / 2 if tile_detector is not None else score_threshold
        inputs = self._open(
            model_path,
            DEFAULT_GLOBAL_MODEL,
            providers,
            num_threads,
            own_threshold,
            iou_threshold,
            optimize_graph and not split_first,
        )
        if len(inputs) not in (1, 2):
            raise DetectorConfigError(
                f"{self.model_path}: has {len(inputs)} inputs; "
                "a global detector needs (previous, current) frames, each (1, 3, H, W)"
            )
        for model_input in inputs:
            check_image_input(self.model_path, model_input, "(1, 3, H, W) float32 RGB frames (previous, current)")
        if callable(tile_detector) and not isinstance(tile_detector, LocalDetector):
            tile_detector = tile_detector()
            if not isinstance(tile_detector, LocalDetector):
                raise TypeError(
                    f"tile_detector: the function returned {type(tile_detector).__name__}, not a LocalDetector"
                )
        if tile_detector is not None and tile_detector.score_threshold > own_threshold + 1e-9:
            raise DetectorConfigError(
                f"tile_detector: its score threshold {tile_detector.score_threshold:g} must be at most "
                f"{own_threshold:g}, half the fused threshold {score_threshold:g}"
            )
        self.tile_detector: LocalDetector | None = tile_detector
        self.input_names = [i.name for i in inputs]
        self.dual_frame = len(inputs) == 2
        self.multiple = int(self.card.get("input_multiple", 64))
        fixed_h, fixed_w = inputs[0].shape[2:]
        self.fixed_size: tuple[int, int] | None = (
            (fixed_w, fixed_h) if isinstance(fixed_w, int) and isinstance(fixed_h, int) else None
        )
        size = self.card.get("input_size", [640, 384])
        self.long_side = int(long_side or self.card.get("runtime_long_side", max(size)))
        if self.long_side % self.multiple:
            raise DetectorConfigError(
                f"{self.model_path}: long_side {self.long_side} must be a multiple of {self.multiple}"
            )
        self._read_classes(classes)
        self.max_detections = int(max_detections)
        # A detector opened for its geometry only (optimize_graph=False) never scores boxes.
        self.second_stage, self.decode_threshold = attach_second_stage(
            second_stage if optimize_graph else None,
            self.model_path,
            providers=providers,
            score_threshold=self.score_threshold,
            classes=self.classes,
        )
        self.feature_reuse: FeatureReuse | None = None
        if split_first or (optimize_graph and feature_reuse):  # required but absent: a clear error
            self.feature_reuse = load_feature_reuse(self.model_path, providers, num_threads, feature_reuse)
        self.score_threshold = float(score_threshold)  # the fused rows' threshold where tiles run
        if split_first:
            if self.feature_reuse is None:  # the full model runs every pair: optimise it now, not on the first frame
                self._open_optimized()
            else:
                self._reopen_optimized = True

    def input_size(self, frame_w: int, frame_h: int) -> tuple[int, int]:
        """Network input ``(w, h)`` used for a frame of this size."""
        if self.fixed_size is not None:
            return self.fixed_size
        return rect_input_size(frame_w, frame_h, self.long_side, self.multiple)

    def prepare(self, frame_bgr: np.ndarray) -> tuple[np.ndarray, Letterbox]:
        """First half of the split: one full frame letterboxed to the network input, and the
        mapping that takes the boxes found in it back to the frame."""
        frame = ensure_bgr(frame_bgr, "frame")
        height, width = frame.shape[:2]
        input_w, input_h = self.input_size(width, height)
        return letterbox(frame, input_w, input_h)

    def detect_prepared(
        self,
        previous_input: np.ndarray,
        current_input: np.ndarray,
        mapping: Letterbox,
        frame_width: int,
        frame_height: int,
        previous_features: np.ndarray | None = None,
        tiles_wanted: Callable[[], bool] | None = None,
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Second half of the split: the model on an already letterboxed pair (:meth:`prepare`).

        Returns ``(N, 9)`` float32 ``[x1, y1, x2, y2, score, class_id, p_drone, p_bird, p_airplane]``
        in full-frame pixels (``mapping`` is the current frame's, ``frame_width`` x
        ``frame_height`` its size; the class probabilities are the second stage's, else one-hot
        from the model's label), and the
        current frame's features for the next GD frame. ``previous_features`` must have been
        returned for ``previous_input`` (the caller keys them by frame); ones of the wrong shape
        are ignored and recomputed. The features returned are None when the detector has no
        split model to reuse them with.

        ``tiles_wanted``, with a ``tile_detector`` and a pair whose tiles run, is asked once
        AM-YOLO's boxes are in: False skips the tile pass for this pair, and AM-YOLO's boxes are
        cut at ``score_threshold`` alone (as without tile fusion). A live caller uses it for a
        pair that is already late.
        """
        if previous_input.shape != current_input.shape:
            raise ValueError(
                f"letterboxed previous {previous_input.shape} and current {current_input.shape} inputs differ in shape"
            )
        input_h, input_w = current_input.shape[:2]
        current_features = None
        if self.feature_reuse is not None:
            current_blob = to_blob([current_input])
            if not self.feature_reuse.accepts(previous_features, input_h, input_w):
                previous_blob = current_blob if previous_input is current_input else to_blob([previous_input])
                previous_features = self.feature_reuse.features(previous_blob)
            output, current_features = self.feature_reuse.detect(current_blob, previous_features)
        elif self.dual_frame:
            feed = dict(zip(self.input_names, (to_blob([previous_input]), to_blob([current_input]))))
            (output,) = self.session.run(None, feed)
        else:
            (output,) = self.session.run(None, {self.input_names[0]: to_blob([current_input])})
        detections = self._label(
            decode_output(
                output[0],
                self.decode_threshold,
                self.iou_threshold,
                self.max_detections,
                box_scale=(input_w, input_h),
                channels=self.class_channels,
            )
        )
        if self.second_stage is not None:
            detections = self.second_stage.rescore(previous_input, current_input, detections)
        else:
            detections = np.concatenate([detections, one_hot_probabilities(detections[:, 5])], axis=1)
        detections = drop_degenerate(unletterbox(detections, mapping, frame_width, frame_height))
        if self.tile_detector is not None:
            detections = fuse_with_tiles(
                detections,
                self.tile_detector,
                previous_input,
                current_input,
                mapping,
                frame_width,
                frame_height,
                wanted=tiles_wanted,
            )
            detections = detections[detections[:, 4] >= self.score_threshold]
        return detections.astype(np.float32), current_features

    def detect(self, previous_bgr: np.ndarray | None, current_bgr: np.ndarray) -> np.ndarray:
        """``(N, 9)`` float32 ``[x1, y1, x2, y2, score, class_id, p_drone, p_bird, p_airplane]`` in full-frame pixels.

        ``previous_bgr`` may be None on the first frame (the current frame is used for both).
        Grayscale frames are converted to BGR; frames of different sizes are rejected.
        """
        return self.detect_pair(previous_bgr, current_bgr)[0]

    def detect_pair(
        self,
        previous_bgr: np.ndarray | None,
        current_bgr: np.ndarray,
        carry: GlobalCarry | None = None,
    ) -> tuple[np.ndarray, GlobalCarry]:
        """:meth:`detect` that also returns what the next GD frame can reuse of this one.

        A stream caller passes that :class:`GlobalCarry` back as ``carry`` on the next frame, so
        each frame of a GD stretch is letterboxed once instead of twice and, with the split model,
        runs the backbone's first stages once instead of twice; ``frame_pair_buffer`` and
        ``global_detector`` do the same in the ROS graph. ``carry`` must come from the frame
        ``previous_bgr``; one of another input size (the frame size changed) is ignored and the
        previous frame processed afresh.
        """
        if carry is not None and not isinstance(carry, GlobalCarry):
            raise TypeError(
                f"carry must be the GlobalCarry an earlier detect_pair returned, got {type(carry).__name__}"
            )
        current = ensure_bgr(current_bgr, "current frame")
        previous = current if previous_bgr is None else ensure_bgr(previous_bgr, "previous frame")
        if previous.shape != current.shape:
            raise ValueError(
                f"previous frame {previous.shape[1]}x{previous.shape[0]} and "
                f"current frame {current.shape[1]}x{current.shape[0]} differ in size"
            )
        current_input, mapping = self.prepare(current)
        previous_features = None
        if previous is current:
            previous_input = current_input
        elif carry is not None and carry.input.shape == current_input.shape:
            previous_input, previous_features = carry.input, carry.features
        else:
            previous_input = self.prepare(previous)[0]
        detections, current_features = self.detect_prepared(
            previous_input, current_input, mapping, current.shape[1], current.shape[0], previous_features
        )
        return detections, GlobalCarry(current_input, current_features)
