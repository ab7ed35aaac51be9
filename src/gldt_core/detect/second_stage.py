"""The second stage: a crop classifier that re-scores and re-boxes the detectors' candidates.

The detectors (AM-YOLO on frame pairs, the P2 local model on ROIs) find nearly every drone
somewhere in their candidates, but rank them poorly: a bird or a second, badly placed box on a
drone often scores above a good box. The second stage looks at each candidate again: a square
crop around it from the current frame and the same crop from the previous frame (so motion is
seen: a bird flaps, an airplane glides), both resized to ``size x size``, and the candidate's box
relative to the crop (:func:`encode_boxes`) go through a small CNN that answers

* class probabilities over background / drone / bird / airplane,
* where the object's annotated box lies, as a correction to the candidate's box in the crop's
  terms (:func:`encode_boxes`; a model without this output keeps the detector's boxes), and
* the quality of the box: its predicted IoU with the object's annotated box (of the corrected
  box where the model corrects boxes).

The correction (opt-in, a model trained with ``model.box_correction``) learns the margin the
Halmstad annotators leave around a drone from the training clips' annotations, the way a
two-stage detector's second stage refines its proposals. That margin differs from clip to clip,
so the shipped model has no correction and keeps the detector's boxes.

The drone probability, the predicted IoU and the detector's score multiply into one
:func:`evidence`, and a monotone logistic calibration fitted on calibration clips the classifier
never trained on (the model card's ``calibration``) turns it into the probability that the
candidate is a drone boxed at IoU 0.5, so that one threshold means the same in the detector,
the scheduler and the tracker.

The crop geometry (:func:`crop_windows`, :func:`cut_crops`, :func:`encode_boxes`) is the one
implementation used both to cut training crops and at run time.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gldt_core.detect.postprocess import nms
from gldt_core.detect.session import DetectorConfigError, open_session

#: Classifier outputs, in order; index 0 is background. The MOT class codes are the indices.
CLASS_NAMES = ("background", "drone", "bird", "airplane")
NUM_CLASSES = len(CLASS_NAMES)
#: Detector rows end in the probabilities of drone, bird and airplane (given an object).
PROBABILITY_COLUMNS = NUM_CLASSES - 1
#: A global detection row: ``[x1, y1, x2, y2, score, class_id, p_drone, p_bird, p_airplane]``.
GLOBAL_COLUMNS = 6 + PROBABILITY_COLUMNS
#: A local detection row: ``[x1, y1, x2, y2, score, class_id, roi_index, p_drone, p_bird, p_airplane]``.
LOCAL_COLUMNS = 7 + PROBABILITY_COLUMNS
#: The detectors' own score threshold where no second stage re-scores their boxes.
UNCALIBRATED_THRESHOLD = 0.25

CROP_SIZE = 64
#: A crop covers ``CONTEXT`` times the candidate's longer side, and never less than ``MIN_SIDE`` px.
CONTEXT = 3.0
MIN_SIDE = 32.0
MAX_SIDE = 512.0


def crop_windows(boxes: np.ndarray, context: float = CONTEXT, min_side: float = MIN_SIDE) -> np.ndarray:
    """``(N, 3)`` ``[cx, cy, side]`` of the square crop around each ``[x1, y1, x2, y2]`` box."""
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    cx = (boxes[:, 0] + boxes[:, 2]) / 2
    cy = (boxes[:, 1] + boxes[:, 3]) / 2
    longer = np.maximum(boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1])
    side = np.clip(context * longer, min_side, MAX_SIDE)
    return np.stack([cx, cy, side], axis=1)


def cut_crops(previous: np.ndarray, frame: np.ndarray, windows: np.ndarray, size: int = CROP_SIZE) -> np.ndarray:
    """``(N, 6, size, size)`` uint8: each window of the previous then the current BGR frame.

    Pixels outside the frame repeat its border, so a candidate at the edge gets a full crop.
    """
    import cv2

    windows = np.asarray(windows, dtype=np.float64).reshape(-1, 3)
    out = np.empty((len(windows), 6, size, size), dtype=np.uint8)
    for i, (cx, cy, side) in enumerate(windows):
        scale = size / side
        # Maps the window's top-left corner to (0, 0) and its side to ``size`` pixels.
        matrix = np.array(
            [
                [scale, 0.0, -(cx - side / 2) * scale + 0.5 * scale - 0.5],
                [0.0, scale, -(cy - side / 2) * scale + 0.5 * scale - 0.5],
            ]
        )
        for offset, image in ((0, previous), (3, frame)):
            crop = cv2.warpAffine(image, matrix, (size, size), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            out[i, offset : offset + 3] = crop.transpose(2, 0, 1)
    return out


def encode_boxes(boxes: np.ndarray, windows: np.ndarray) -> np.ndarray:
    """A box relative to its crop window, ``(N, 4)``: centre offset over the window side, log of
    width and height over the side (what the quality head is told about the box)."""
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    side = windows[:, 2]
    w = np.maximum(boxes[:, 2] - boxes[:, 0], 1e-3)
    h = np.maximum(boxes[:, 3] - boxes[:, 1], 1e-3)
    return np.stack(
        [
            ((boxes[:, 0] + boxes[:, 2]) / 2 - windows[:, 0]) / side,
            ((boxes[:, 1] + boxes[:, 3]) / 2 - windows[:, 1]) / side,
            np.log(w / side),
            np.log(h / side),
        ],
        axis=1,
    )


def decode_boxes(encoded: np.ndarray, windows: np.ndarray) -> np.ndarray:
    """``(N, 4)`` ``[x1, y1, x2, y2]``: the inverse of :func:`encode_boxes` for the same windows."""
    encoded = np.asarray(encoded, dtype=np.float64).reshape(-1, 4)
    windows = np.asarray(windows, dtype=np.float64).reshape(-1, 3)
    side = windows[:, 2]
    cx = windows[:, 0] + encoded[:, 0] * side
    cy = windows[:, 1] + encoded[:, 1] * side
    w = np.exp(np.clip(encoded[:, 2], -20, 2)) * side
    h = np.exp(np.clip(encoded[:, 3], -20, 2)) * side
    return np.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], axis=1)


def encoded_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(N,)`` IoU of row-paired boxes given in the terms of :func:`encode_boxes` for one window
    per row (IoU does not depend on where the window lies or how large it is)."""
    unit = np.tile([0.0, 0.0, 1.0], (len(np.asarray(a).reshape(-1, 4)), 1))
    first, second = decode_boxes(a, unit), decode_boxes(b, unit)
    lo = np.maximum(first[:, :2], second[:, :2])
    hi = np.minimum(first[:, 2:], second[:, 2:])
    inter = np.prod(np.clip(hi - lo, 0.0, None), axis=1)
    union = np.prod(first[:, 2:] - first[:, :2], axis=1) + np.prod(second[:, 2:] - second[:, :2], axis=1) - inter
    return np.asarray(inter / np.maximum(union, 1e-12))


def log_softmax(logits: np.ndarray) -> np.ndarray:
    shifted = logits - logits.max(axis=1, keepdims=True)
    return shifted - np.log(np.exp(shifted).sum(axis=1, keepdims=True))


def evidence(class_logits: np.ndarray, quality_logits: np.ndarray, detector_scores: np.ndarray) -> np.ndarray:
    """``(N,)`` the evidence that a candidate is a drone boxed at IoU 0.5: the classifier's drone
    probability times the predicted IoU of the box times the detector's score. Three views of one
    candidate, combined as independent ones; the calibration maps it to a probability."""
    drone = np.exp(log_softmax(np.asarray(class_logits, dtype=np.float64))[:, 1])
    quality = 1.0 / (1.0 + np.exp(-np.asarray(quality_logits, dtype=np.float64).reshape(-1)))
    return drone * quality * np.clip(np.asarray(detector_scores, dtype=np.float64), 0.0, 1.0)


@dataclass(frozen=True)
class Calibration:
    """``p = sigmoid(slope * log(evidence) + bias)``: the probability that a candidate with this
    :func:`evidence` is a drone boxed at IoU 0.5. Monotone (``slope > 0``), so it keeps the
    evidence's ranking, and fitted on clips the classifier never trained on."""

    slope: float
    bias: float

    def probability(self, evidence_values: np.ndarray) -> np.ndarray:
        z = self.slope * np.log(np.clip(evidence_values, 1e-9, 1.0)) + self.bias
        return 1.0 / (1.0 + np.exp(-np.clip(z, -50, 50)))

    @classmethod
    def from_card(cls, card: dict[str, Any], where: str) -> Calibration:
        entry = card.get("calibration")
        if not isinstance(entry, dict) or "slope" not in entry or "bias" not in entry:
            raise DetectorConfigError(
                f"{where}: model card has no calibration (slope, bias); re-run the classifier's fit"
            )
        slope = float(entry["slope"])
        if not slope > 0:
            raise DetectorConfigError(f"{where}: calibration slope {slope} must be positive (a monotone map)")
        return cls(slope, float(entry["bias"]))


def classifier_path_for(detector_model: Path | str) -> Path:
    """Where the second stage of a detector lies: ``second_stage.onnx`` in the detector's folder."""
    return Path(detector_model).resolve().parent / "second_stage.onnx"


class SecondStage:
    """The crop classifier over candidates: :meth:`rescore` one image pair, :meth:`rescore_many` several.

    ``candidates`` are detector rows ``[x1, y1, x2, y2, score, ...]`` in the pixels of the images
    given; the answer keeps at most ``max_candidates`` of them over all pairs of one call
    (highest detector score first), with their boxes (corrected where the model corrects boxes), as rows
    ``[x1, y1, x2, y2, p, class_id, p_drone, p_bird, p_airplane]``: ``p`` the calibrated
    probability of the tracked ``classes``, ``class_id`` the most probable of the tracked classes
    (a box is a drone when its drone probability passes), then the probabilities of the three
    object classes given that it is an object (they sum to 1: the evidence a track gathers).
    Rows under ``score_threshold`` are dropped, and duplicates removed by NMS at IoU ``nms_iou``,
    pair by pair. Boxes nested in a better one stay (a detection metric wants the well-placed
    box under a better-scored nested one); the GL-DT system drops them before its tracker
    (:func:`gldt_core.system.steps.drop_nested`).
    """

    EXPECTATION = (
        f"inputs (N, 6, {CROP_SIZE}, {CROP_SIZE}) float crops in [0, 255] and (N, 4) box geometry, "
        "outputs (N, 4) class logits, (N, 1) box-quality logits and, where it corrects boxes, (N, 4) box corrections"
    )
    #: Detector score down to which candidates are handed to the second stage (the crops it was trained on).
    CANDIDATE_SCORE = 0.01
    #: The calibrated probability that makes a drone: more likely than not.
    DEFAULT_THRESHOLD = 0.5

    def __init__(
        self,
        model_path: Path | str,
        *,
        providers: Sequence[str] = ("CPUExecutionProvider",),
        num_threads: int | None = 1,
        score_threshold: float = DEFAULT_THRESHOLD,
        classes: Sequence[int] | None = (1,),
        max_candidates: int = 12,
        nms_iou: float = 0.5,
    ) -> None:
        path = Path(model_path)
        if not path.is_file():
            raise DetectorConfigError(
                f"{path}: second-stage classifier not found (it belongs beside the detector model; "
                "to run without it: detector.second_stage: null and detector.tile_fusion: false in a config, "
                "second_stage:=none tile_fusion:=false on a node, --second-stage none for gldt detect)"
            )
        self.session, self.card = open_session(path, providers, num_threads, self.EXPECTATION)
        self.model_path = path
        inputs = self.session.get_inputs()
        outputs = self.session.get_outputs()
        if len(inputs) != 2 or len(outputs) not in (2, 3) or list(inputs[0].shape[1:]) != [6, CROP_SIZE, CROP_SIZE]:
            raise DetectorConfigError(f"{path}: not a second-stage classifier; expected {self.EXPECTATION}")
        self.input_names = [i.name for i in inputs]
        #: Whether the model corrects the detector's boxes toward the annotations' (a third output).
        self.corrects_boxes = len(outputs) == 3
        self.calibration = Calibration.from_card(self.card, str(path))
        self.context = float(self.card.get("context", CONTEXT))
        self.min_side = float(self.card.get("min_side", MIN_SIDE))
        if not 0.0 <= float(score_threshold) <= 1.0:
            raise DetectorConfigError(f"second stage: score_threshold must be in [0, 1], got {score_threshold!r}")
        self.score_threshold = float(score_threshold)
        self.classes = tuple(int(c) for c in classes) if classes else (1, 2, 3)
        bad = [c for c in self.classes if not 1 <= c < NUM_CLASSES]
        if bad:
            raise DetectorConfigError(f"classes {bad} unknown to the second stage (1 drone, 2 bird, 3 airplane)")
        if int(max_candidates) < 1:
            raise DetectorConfigError(f"second stage: max_candidates must be >= 1, got {max_candidates!r}")
        self.max_candidates = int(max_candidates)
        self.nms_iou = float(nms_iou)

    def classify(self, crops: np.ndarray, geometry: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Class logits ``(N, 4)``, box-quality logits ``(N,)`` and the corrected boxes ``(N, 4)``
        (in the terms of :func:`encode_boxes`; ``geometry`` itself where the model corrects no
        boxes) of crops cut by :func:`cut_crops` around boxes whose :func:`encode_boxes` is ``geometry``."""
        feed = dict(zip(self.input_names, (crops.astype(np.float32), geometry.astype(np.float32))))
        outputs = self.session.run(None, feed)
        logits, quality = outputs[0], outputs[1]
        corrected = np.asarray(geometry, dtype=np.float64)
        if self.corrects_boxes:
            corrected = corrected + np.asarray(outputs[2], dtype=np.float64).reshape(-1, 4)
        return np.asarray(logits, dtype=np.float64), np.asarray(quality, dtype=np.float64).reshape(-1), corrected

    def rescore(self, previous: np.ndarray | None, frame: np.ndarray, candidates: np.ndarray) -> np.ndarray:
        """The rows of one image pair (``previous`` None: the frame with itself)."""
        return self.rescore_many([(previous, frame, candidates)])[0]

    def rescore_many(self, items: Sequence[tuple[np.ndarray | None, np.ndarray, np.ndarray]]) -> list[np.ndarray]:
        """One ``(M, 9)`` float32 array per ``(previous, frame, candidates)``, all crops in one batch."""
        arrays = []
        for _, _, candidates in items:
            candidates = np.asarray(candidates, dtype=np.float64)
            if candidates.size == 0:
                candidates = np.zeros((0, 5))
            if candidates.ndim != 2 or candidates.shape[1] < 5:
                raise ValueError(
                    f"candidates must be (N, >=5) [x1, y1, x2, y2, score, ...], got shape {candidates.shape}"
                )
            arrays.append(candidates[:, :5])
        # The ``max_candidates`` best by detector score over all pairs.
        item_of = np.concatenate([np.full(len(a), i) for i, a in enumerate(arrays)]) if arrays else np.zeros(0, int)
        scores = np.concatenate([a[:, 4] for a in arrays]) if arrays else np.zeros(0)
        chosen = np.sort(np.argsort(-scores, kind="stable")[: self.max_candidates])
        flat = np.concatenate(arrays) if arrays else np.zeros((0, 5))
        crops, geometry, windows, owners = [], [], [], []
        for i, (previous, frame, _) in enumerate(items):
            picked = chosen[item_of[chosen] == i]
            if len(picked) == 0:
                continue
            window = crop_windows(flat[picked, :4], self.context, self.min_side)
            crops.append(cut_crops(frame if previous is None else previous, frame, window))
            geometry.append(encode_boxes(flat[picked, :4], window))
            windows.append(window)
            owners.append(picked)
        results = [np.zeros((0, 6 + PROBABILITY_COLUMNS), dtype=np.float32) for _ in items]
        if crops:
            logits, quality, corrected = self.classify(np.concatenate(crops), np.concatenate(geometry))
            picked_all = np.concatenate(owners)
            boxes = decode_boxes(corrected, np.concatenate(windows)) if self.corrects_boxes else flat[picked_all, :4]
            probabilities = np.exp(log_softmax(logits))
            score = self._score(logits, quality, probabilities, scores[picked_all])
            objects = probabilities[:, 1:] / np.maximum(probabilities[:, 1:].sum(axis=1, keepdims=True), 1e-12)
            tracked = np.asarray(self.classes)
            class_id = tracked[objects[:, tracked - 1].argmax(axis=1)]
            rows = np.concatenate([boxes, score[:, None], class_id[:, None], objects], axis=1)
            for i in range(len(items)):
                mine = rows[item_of[picked_all] == i]
                mine = mine[mine[:, 4] >= self.score_threshold]
                if len(mine):
                    mine = mine[nms(mine[:, :4], mine[:, 4], self.nms_iou)]
                results[i] = mine.astype(np.float32)
        return results

    def _score(
        self, logits: np.ndarray, quality: np.ndarray, probabilities: np.ndarray, detector_scores: np.ndarray
    ) -> np.ndarray:
        """The calibrated probability of a tracked class (see :class:`Calibration`)."""
        calibrated = self.calibration.probability(evidence(logits, quality, detector_scores))
        if self.classes == (1,):
            return calibrated
        # The calibration is fitted for drones; other tracked classes get their classifier
        # probability, and a drone never less than its calibrated one.
        others = [c for c in self.classes if c != 1]
        return np.maximum(calibrated if 1 in self.classes else 0.0, probabilities[:, others].sum(axis=1))


def one_hot_probabilities(class_ids: np.ndarray) -> np.ndarray:
    """``(N, 3)`` probabilities of drone, bird, airplane that say only what the detector's label says."""
    class_ids = np.asarray(class_ids).astype(np.int64).reshape(-1)
    out = np.zeros((len(class_ids), PROBABILITY_COLUMNS), dtype=np.float32)
    known = (class_ids >= 1) & (class_ids < NUM_CLASSES)
    out[np.flatnonzero(known), class_ids[known] - 1] = 1.0
    return out


#: Where a detector finds its second stage when told nothing else: beside its own model file.
BESIDE = "beside"
SecondStageChoice = SecondStage | Path | str | None


def load_second_stage(
    choice: SecondStageChoice,
    detector_model: Path,
    *,
    providers: Sequence[str],
    score_threshold: float,
    classes: Sequence[int] | None,
) -> SecondStage | None:
    """The second stage a detector runs: None (none), a :class:`SecondStage`, a path, or
    :data:`BESIDE` (``second_stage.onnx`` in the detector model's folder). A missing file is a
    :class:`DetectorConfigError` that names it and how to run without."""
    if choice is None or isinstance(choice, SecondStage):
        return choice
    path = classifier_path_for(detector_model) if choice == BESIDE else Path(choice)
    if not path.is_file():
        where = f"beside the detector model {detector_model}" if choice == BESIDE else "at the path given"
        raise DetectorConfigError(
            f"{path}: second-stage classifier not found {where}; "
            "to run the detector alone: detector.second_stage: null and detector.tile_fusion: false in a config, "
            "second_stage:=none tile_fusion:=false on a node, --second-stage none for gldt detect, "
            "second_stage=None in Python"
        )
    return SecondStage(path, providers=providers, score_threshold=score_threshold, classes=classes)


def attach_second_stage(
    choice: SecondStageChoice,
    detector_model: Path,
    *,
    providers: Sequence[str],
    score_threshold: float,
    classes: Sequence[int] | None,
) -> tuple[SecondStage | None, float]:
    """A detector's second stage (:func:`load_second_stage`) and the score its model decodes
    candidates down to (:func:`candidate_threshold`)."""
    stage = load_second_stage(
        choice, detector_model, providers=providers, score_threshold=score_threshold, classes=classes
    )
    return stage, candidate_threshold(stage, score_threshold)


def candidate_threshold(stage: SecondStage | None, score_threshold: float) -> float:
    """The score a detector's model decodes candidates down to: :attr:`SecondStage.CANDIDATE_SCORE`
    where ``stage`` re-scores them (never above ``score_threshold``), else the threshold itself."""
    return min(SecondStage.CANDIDATE_SCORE, score_threshold) if stage is not None else score_threshold


def default_score_threshold(with_second_stage: bool) -> float:
    """A detector's own threshold: 0.5 of the calibrated probability with a second stage, else
    :data:`UNCALIBRATED_THRESHOLD` for the raw, under-confident detector score."""
    return SecondStage.DEFAULT_THRESHOLD if with_second_stage else UNCALIBRATED_THRESHOLD
