"""Training the second stage (:mod:`gldt_core.detect.second_stage`): a crop classifier with box
correction and box-quality heads.

``gldt train second-stage --config CFG [--resume CKPT]``. The Halmstad training clips are split
again by name: most train the classifier, every ``calibration_period``-th clip of each category
is kept for the calibration (the monotone map from the evidence to the probability of a drone
boxed at IoU 0.5) and for the figures in the model card. The validation splits of
:mod:`gldt_core.eval.halmstad_split` are never read here.

Training is resumable: ``last.pt`` holds the model, the optimiser, the schedule's step, the epoch
reached and the accumulated training time, and each epoch's data order and augmentation are a
function of (seed, epoch) alone, so a run stopped after any epoch and resumed gives the same
weights as one that ran through (the schedule is part of the checkpoint: a longer run is one
configured longer from its start). A resume checks the checkpoint against the config before anything is written.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from gldt_core.detect.second_stage import (
    CLASS_NAMES,
    CONTEXT,
    CROP_SIZE,
    MIN_SIDE,
    NUM_CLASSES,
    Calibration,
    encoded_iou,
    evidence,
)
from gldt_core.eval.halmstad_split import clip_category, halmstad_split
from gldt_core.training.crops import SOURCES, CropSet, CropSpec, SceneCrops, build_crops
from gldt_core.training.resume import ResumeError, read_checkpoint

DEFAULTS: dict[str, Any] = {
    "seed": 0,
    "threads": 1,
    "out_dir": "runs/second_stage",
    # box_correction: a head that moves each candidate's box toward its object's annotated box
    # (opt-in: learnt from the training clips' annotation margins, which differ from clip to clip).
    # input_norm "border": each crop's channels less their mean over the crop's border ring (the sky
    # around the object), so that the classifier sees the object against its background and not the
    # background's colour, which differs by recording day and so by clip (opt-in; "none": 0-255 to [-1, 1]).
    "model": {"channels": [16, 32, 64, 96], "hidden": 128, "box_correction": False, "input_norm": "none"},
    "data": {
        "halmstad_root": None,
        "cache_dir": "/tmp/gldt-cache",
        "calibration_period": 5,
        "crops": asdict(CropSpec()),
        "global_model": None,
        "local_model": None,
        # Scenes of the synthetic train split cut into crops too, all for fitting (never for the
        # calibration, which stays on real clips); scene i at scales[i % len(scales)].
        "synthetic": {"scenes": 0, "frames": 60, "scales": [1 / 3, 2 / 3]},
    },
    "train": {
        "epochs": 12,
        "batch_size": 128,
        "lr": 0.003,
        "weight_decay": 0.0005,
        "quality_weight": 1.0,
        "box_weight": 1.0,
        # > 0: focal loss on the classes (class_loss): the crops already classified right weigh less.
        "focal_gamma": 0.0,
        # Colour augmentation (augment; 0: off): each crop's blue, green and red scaled by gains
        # drawn in [1 - colour_jitter, 1 + colour_jitter], and grayscale_p of the crops turned grey.
        # The sky's colour differs from one recording day to the next and so from clip to clip.
        "colour_jitter": 0.0,
        "grayscale_p": 0.0,
        # Distillation (opt-in, out_of_fold_answers()): teacher names a second-stage config (an
        # ensemble's or a single one, a path relative to this config's file), trained here out of
        # fold: the fit clips are dealt into teacher_folds folds and each fold's crops are answered
        # by a teacher trained on the other folds, so that its answers are what it says of clips it
        # has not seen. The class loss is then (1 - distill_weight) of the cross-entropy plus
        # distill_weight of the KL divergence from the teacher's class probabilities at
        # distill_temperature, and the box quality's target the same mix of the box's IoU and the
        # teacher's predicted IoU.
        "teacher": None,
        "teacher_folds": 2,
        "distill_weight": 0.0,
        "distill_temperature": 2.0,
        "max_wall_s": None,
    },
}


#: The key of an ensemble config that lists its members (:func:`load_config`).
ENSEMBLE_MEMBERS = "members"

#: Fewest optimiser steps the one-cycle schedule is defined for.
MIN_STEPS = 10


#: The crop normalisations CropClassifier knows (``model.input_norm``).
INPUT_NORMS = ("none", "border")

#: Width in pixels of the border ring whose mean ``input_norm: border`` takes from each channel.
BORDER_RING = 6


def conv(cin: int, cout: int, stride: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride, 1, bias=False), nn.BatchNorm2d(cout), nn.SiLU())


class CropClassifier(nn.Module):
    """``(N, 6, 64, 64)`` crops (0-255, previous then current BGR) and ``(N, 4)`` box geometry
    (:func:`~gldt_core.detect.second_stage.encode_boxes`) -> class logits ``(N, 4)``, box-quality
    logit ``(N, 1)`` (the predicted IoU of the box with its object's, as a logit) and, with
    ``box_correction``, the box correction ``(N, 4)`` (added to the geometry, it is the object's
    annotated box; the quality is then the corrected box's). ``input_norm`` (:data:`INPUT_NORMS`)
    says how the crops are scaled before the first convolution."""

    def __init__(
        self, channels: list[int], hidden: int, box_correction: bool = False, input_norm: str = "none"
    ) -> None:
        super().__init__()
        if input_norm not in INPUT_NORMS:
            raise ValueError(f"model.input_norm must be one of {', '.join(INPUT_NORMS)}, got {input_norm!r}")
        self.input_norm = input_norm
        c0, c1, c2, c3 = channels
        self.features = nn.Sequential(
            conv(6, c0, 2),  # 32
            conv(c0, c1, 2),  # 16
            conv(c1, c1, 1),
            conv(c1, c2, 2),  # 8
            conv(c2, c2, 1),
            conv(c2, c3, 2),  # 4
        )
        self.neck = nn.Sequential(nn.Flatten(), nn.Linear(c3 * (CROP_SIZE // 16) ** 2, hidden), nn.SiLU())
        self.classes = nn.Linear(hidden, NUM_CLASSES)
        # The box is known only as numbers, so the quality head sees them beside the image features.
        self.quality = nn.Sequential(nn.Linear(hidden + 4, hidden // 2), nn.SiLU(), nn.Linear(hidden // 2, 1))
        self.correction: nn.Sequential | None = None
        if box_correction:
            self.correction = nn.Sequential(nn.Linear(hidden + 4, hidden // 2), nn.SiLU(), nn.Linear(hidden // 2, 4))
            last = self.correction[-1]
            assert isinstance(last, nn.Linear)
            # A correction starts at none: an untrained head keeps the detector's boxes.
            nn.init.zeros_(last.weight)
            nn.init.zeros_(last.bias)

    def normalise(self, crops: torch.Tensor) -> torch.Tensor:
        """The crops as the first convolution sees them: 0-255 mapped to [-1, 1], or with
        ``input_norm: border`` each channel less its mean over the crop's border ring, on the
        same scale (part of the exported model, so the runtime feeds 0-255 crops either way)."""
        if self.input_norm == "none":
            return crops / 127.5 - 1.0
        ring = BORDER_RING
        inner = crops[:, :, ring:-ring, ring:-ring]
        ring_sum = crops.sum(dim=(2, 3), keepdim=True) - inner.sum(dim=(2, 3), keepdim=True)
        ring_pixels = crops.shape[2] * crops.shape[3] - inner.shape[2] * inner.shape[3]
        return (crops - ring_sum / ring_pixels) / 127.5

    def forward(self, crops: torch.Tensor, geometry: torch.Tensor) -> tuple[torch.Tensor, ...]:
        x = self.neck(self.features(self.normalise(crops)))
        with_box = torch.cat([x, geometry], dim=1)
        heads = (self.classes(x), self.quality(with_box))
        return heads if self.correction is None else (*heads, self.correction(with_box))

    def outputs(
        self, crops: torch.Tensor, geometry: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """Class logits, quality logit and box correction (None without the correction head)."""
        out = self(crops, geometry)
        return out[0], out[1], out[2] if len(out) == 3 else None


class CropClassifierEnsemble(nn.Module):
    """Several :class:`CropClassifier` as one model with the same inputs and outputs: the mean of
    the members' class log-probabilities (as logits: their normalised geometric mean) and of their
    quality logits. Members that differ in seed or in how they see a crop (``input_norm``, grey
    crops) err on different clips, and the calibration is fitted on the mean. Members that correct
    boxes are refused: the ensemble averages classes and box quality only."""

    def __init__(self, members: Sequence[CropClassifier]) -> None:
        super().__init__()
        if len(members) < 2:
            raise ValueError(f"an ensemble needs at least two members, got {len(members)}")
        if any(member.correction is not None for member in members):
            raise ValueError("ensemble members cannot correct boxes (model.box_correction)")
        self.members = nn.ModuleList(members)
        self.correction: nn.Sequential | None = None

    def forward(self, crops: torch.Tensor, geometry: torch.Tensor) -> tuple[torch.Tensor, ...]:
        outputs = [member(crops, geometry) for member in self.members]
        log_probabilities = torch.stack([torch.log_softmax(out[0], dim=1) for out in outputs]).mean(dim=0)
        return log_probabilities, torch.stack([out[1] for out in outputs]).mean(dim=0)

    def outputs(
        self, crops: torch.Tensor, geometry: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """Class logits and quality logit as :meth:`CropClassifier.outputs`; no box correction."""
        log_probabilities, quality = self(crops, geometry)
        return log_probabilities, quality, None


#: What the calibration, the figures and the export take: one classifier or an ensemble of them.
Classifier = CropClassifier | CropClassifierEnsemble


def places_in_category(names: Iterable[str], category: Callable[[str], str]) -> dict[str, int]:
    """Each name's place (0, 1, 2, ...) among the names of its ``category``, in name order: what
    dealing the clips of each category round a number of piles counts."""
    places: dict[str, int] = {}
    seen: dict[str, int] = {}
    for name in sorted(names):
        kind = category(name)
        places[name] = seen.get(kind, 0)
        seen[kind] = places[name] + 1
    return places


def split_for_calibration(clips: list[str], period: int) -> tuple[list[str], list[str]]:
    """(fit clips, calibration clips): every ``period``-th clip of each category, from the first, calibrates."""
    places = places_in_category(clips, clip_category)
    fit = [clip for clip in sorted(clips) if places[clip] % period]
    calibration = [clip for clip in sorted(clips) if places[clip] % period == 0]
    return fit, calibration


def synthetic_scenes(settings: dict[str, Any]) -> list[SceneCrops]:
    """The synthetic scenes of the ``train`` split to cut crops from (``data.synthetic``); the
    benchmarks draw theirs from the ``test`` split, whose seeds never meet these."""
    from gldt_core.sim import presets

    count, scales = int(settings["scenes"]), [float(scale) for scale in settings["scales"]]
    if count and (not scales or any(not 0 < scale <= 1 for scale in scales)):
        raise ValueError(f"data.synthetic.scales must be in (0, 1], got {settings['scales']}")
    specs = presets.split("train", count=count, frames=int(settings["frames"]))
    return [SceneCrops(spec, scales[index % len(scales)]) for index, spec in enumerate(specs)]


def augment(
    crops: np.ndarray,
    geometry: np.ndarray,
    target: np.ndarray,
    rng: np.random.Generator,
    colour: tuple[float, float] = (0.0, 0.0),
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Horizontal flips (of the crop, its box and its object's box) and brightness/contrast
    jitter, the same for both frames; with ``colour`` (:func:`colour_augmentation`, ``(jitter,
    grayscale_p)``) also per-channel gains in ``[1 - jitter, 1 + jitter]`` and, for a share
    ``grayscale_p`` of the crops, grey (BT.601 luma in every channel), again the same for both
    frames. Without ``colour`` the random draws are exactly those of the flips and jitter alone."""
    crops = crops.astype(np.float32)
    geometry = geometry.astype(np.float32)
    target = target.astype(np.float32)
    flip = rng.random(len(crops)) < 0.5
    crops[flip] = crops[flip, :, :, ::-1]
    geometry[flip, 0] = -geometry[flip, 0]
    target[flip, 0] = -target[flip, 0]
    gain = rng.uniform(0.75, 1.25, size=(len(crops), 1, 1, 1)).astype(np.float32)
    bias = rng.uniform(-25, 25, size=(len(crops), 1, 1, 1)).astype(np.float32)
    jitter, grayscale_p = colour
    if jitter > 0 or grayscale_p > 0:
        n, channels, height, width = crops.shape
        frames = crops.reshape(n, channels // 3, 3, height, width)  # (previous, current) x BGR
        if jitter > 0:
            channel_gain = rng.uniform(1 - jitter, 1 + jitter, size=(n, 1, 3, 1, 1)).astype(np.float32)
            frames *= channel_gain
        if grayscale_p > 0:
            grey = rng.random(n) < grayscale_p
            luma = np.tensordot(frames[grey], np.array([0.114, 0.587, 0.299], np.float32), axes=([2], [0]))
            frames[grey] = luma[:, :, None]
        crops = frames.reshape(n, channels, height, width)
    return np.clip(crops * gain + bias, 0, 255), geometry, target


def crop_context(config: dict[str, Any]) -> float:
    """How many times a candidate's longer side its crop covers (``data.crops.context``)."""
    return float(config["data"]["crops"]["context"])


def _train_number(config: dict[str, Any], key: str) -> float:
    """``train.<key>`` as a float; NaN where it is not a number, so that the caller's range check
    refuses it in one line with the value as given."""
    try:
        return float(config["train"][key])
    except (TypeError, ValueError):
        return float("nan")


def focal_gamma(config: dict[str, Any]) -> float:
    """``train.focal_gamma`` (:func:`class_loss`); ValueError in one line when negative or not a number."""
    gamma = _train_number(config, "focal_gamma")
    if not gamma >= 0:
        raise ValueError(f"train.focal_gamma must be >= 0, got {config['train']['focal_gamma']!r}")
    return gamma


def colour_augmentation(config: dict[str, Any]) -> tuple[float, float]:
    """``(train.colour_jitter, train.grayscale_p)`` for :func:`augment`; ValueError in one line
    when the jitter is outside ``[0, 1)`` or the share outside ``[0, 1]``."""
    train = config["train"]
    jitter, grayscale_p = _train_number(config, "colour_jitter"), _train_number(config, "grayscale_p")
    if not 0 <= jitter < 1:
        raise ValueError(f"train.colour_jitter must be in [0, 1), got {train['colour_jitter']!r}")
    if not 0 <= grayscale_p <= 1:
        raise ValueError(f"train.grayscale_p must be in [0, 1], got {train['grayscale_p']!r}")
    return jitter, grayscale_p


def distillation(config: dict[str, Any]) -> tuple[float, float]:
    """``(train.distill_weight, train.distill_temperature)``, checked against ``train.teacher`` and
    ``train.teacher_folds``; ValueError in one line where they disagree or are out of range."""
    train = config["train"]
    teacher = train["teacher"]
    weight, temperature = _train_number(config, "distill_weight"), _train_number(config, "distill_temperature")
    if teacher is not None and not isinstance(teacher, str):
        raise ValueError(f"train.teacher must be a second-stage config's path, got {teacher!r}")
    if not 0 <= weight <= 1:
        raise ValueError(f"train.distill_weight must be in [0, 1], got {train['distill_weight']!r}")
    if not temperature > 0:
        raise ValueError(f"train.distill_temperature must be > 0, got {train['distill_temperature']!r}")
    if (teacher is not None) != (weight > 0):
        raise ValueError("train.teacher and train.distill_weight > 0 go together: give both or neither")
    folds = train["teacher_folds"]
    if isinstance(folds, bool) or not isinstance(folds, int) or folds < 2:
        raise ValueError(f"train.teacher_folds must be an integer >= 2, got {folds!r}")
    if teacher is not None and config["model"].get("box_correction"):
        raise ValueError("a classifier that corrects boxes cannot learn from a teacher (it rates uncorrected boxes)")
    return weight, temperature


def teacher_members(config: dict[str, Any]) -> list[dict[str, Any]]:
    """The configs of the classifiers that make ``train.teacher`` (one, or an ensemble's members);
    [] without a teacher. ValueError in one line for a teacher that cuts other crops, corrects
    boxes or learns from a teacher itself."""
    path = config["train"]["teacher"]
    if path is None:
        return []
    teacher = load_config(path)
    members = teacher.get(ENSEMBLE_MEMBERS, [teacher])
    for member in members:
        if member["data"] != config["data"]:
            raise ValueError(f"train.teacher {path} cuts other crops than this config (its data section differs)")
        if member["model"].get("box_correction"):
            raise ValueError(f"train.teacher {path} corrects boxes, so its quality rates other boxes")
        if member["train"]["teacher"] is not None:
            raise ValueError(f"train.teacher {path} learns from a teacher itself")
        check_member(member)
    return members


def clip_folds(crops: CropSet, folds: int) -> np.ndarray:
    """``(N,)`` the fold of each crop: the clips of each category (the name less its number) that
    have crops here, in name order, dealt round the folds, so every fold holds clips of every
    category."""
    present = [crops.clip_names[index] for index in np.unique(crops.clips)]  # clip_names names other subsets' too
    places = places_in_category(present, lambda name: name.rsplit("_", 1)[0])  # synthetic scenes too
    fold_of = {crops.clip_names.index(name): place % folds for name, place in places.items()}
    return np.array([fold_of[int(clip)] for clip in crops.clips], dtype=np.int64).reshape(-1)


def out_of_fold_answers(
    members: list[dict[str, Any]],
    folds: int,
    temperature: float,
    fit_set: CropSet,
    calibration_set: CropSet,
    out: Path,
    progress: bool = True,
) -> tuple[np.ndarray, np.ndarray, float] | None:
    """What a teacher made of ``members`` (:func:`teacher_members`) says of each fit crop, trained
    without that crop's clip: for each of ``folds`` folds (:func:`clip_folds`), the members are
    trained on the other folds' crops into ``out/teacher_fold_K/member_I`` and answer the fold's
    crops at ``temperature`` (:func:`teacher_answers`); also the seconds all members trained for.
    A member whose ``last.pt`` there was written under the same config is continued (a finished
    one is only read back). None where a member's ``train.max_wall_s`` stopped it."""
    fold = clip_folds(fit_set, folds)
    log_probabilities = np.zeros((len(fold), NUM_CLASSES), np.float32)
    predicted_iou = np.zeros(len(fold), np.float32)
    seconds = 0.0
    for k in range(folds):
        held = fold == k
        if not held.any() or held.all():
            raise ValueError(
                f"teacher fold {k} holds {int(held.sum())} of {len(held)} fit crops; every fold needs some"
            )
        models = []
        for index, member in enumerate(members):
            member_out = out / f"teacher_fold_{k}" / f"member_{index}"
            checkpoint = None
            if (member_out / "last.pt").is_file():
                saved = read_checkpoint(member_out / "last.pt")
                checkpoint = saved if saved.get("config") == member else None
            fitted = fit_classifier(member, fit_set.subset(~held), calibration_set, member_out, checkpoint, progress)
            if fitted is None:
                return None
            models.append(fitted[0])
            seconds += fitted[1]["cpu_seconds_total"]
        teacher = models[0] if len(models) == 1 else CropClassifierEnsemble(models)
        log_probabilities[held], predicted_iou[held] = teacher_answers(teacher, fit_set.subset(held), temperature)
    return log_probabilities, predicted_iou, seconds


def teacher_answers(teacher: Classifier, crops: CropSet, temperature: float) -> tuple[np.ndarray, np.ndarray]:
    """What ``teacher`` says of each crop (without augmentation), as the distillation's targets:
    class log-probabilities at ``temperature`` ``(N, 4)`` and predicted IoU ``(N,)``."""
    logits, quality, _ = predict(teacher, crops)
    log_probabilities = torch.log_softmax(torch.from_numpy(logits) / temperature, dim=1).numpy()
    return log_probabilities, (1.0 / (1.0 + np.exp(-quality))).astype(np.float32)


def class_loss(
    logits: torch.Tensor, labels: torch.Tensor, class_weights: torch.Tensor, focal_gamma: float
) -> torch.Tensor:
    """Cross-entropy weighted by class (the weighted mean over the batch, as torch's), each crop's
    term scaled by ``(1 - p)^focal_gamma`` of its true class's probability ``p`` (focal loss:
    crops the model already gets right count less, the confident mistakes as much as before);
    ``focal_gamma`` 0 is plain weighted cross-entropy."""
    if focal_gamma == 0:
        return nn.functional.cross_entropy(logits, labels, weight=class_weights)
    log_p = nn.functional.log_softmax(logits, dim=1).gather(1, labels[:, None]).squeeze(1)
    weight = class_weights[labels]
    return (weight * (1 - log_p.exp()).pow(focal_gamma) * -log_p).sum() / weight.sum()


def losses(
    outputs: tuple[torch.Tensor, torch.Tensor, torch.Tensor | None],
    batch: tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor],
    class_weights: torch.Tensor,
    weights: tuple[float, float],
    context: float = CONTEXT,
    focal_gamma: float = 0.0,
    teacher: tuple[torch.Tensor, torch.Tensor] | None = None,
    distill: tuple[float, float] = (0.0, 1.0),
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Class loss (:func:`class_loss`); binary cross-entropy of the quality logit against
    the box's IoU with its object's annotated box (0 on background); with a correction head, L1 of
    the corrected box against the annotated one on object crops, and the quality target is then
    the corrected box's IoU (held fixed). ``batch``: labels, geometry, annotated boxes (both
    :func:`~gldt_core.detect.second_stage.encode_boxes`), IoU of the uncorrected boxes. The L1
    weighs a centre offset (in crop sides) by the crops' ``context``, so that it counts in the box's
    own sides, as the log width and height do. With ``teacher`` (:func:`teacher_answers` of the
    batch) and ``distill`` ``(weight, temperature)`` (:func:`distillation`), the class loss is
    ``(1 - weight)`` of the above plus ``weight`` of the KL divergence from the teacher's class
    probabilities at the temperature (times its square, so its gradients keep their scale), and
    the quality target the same mix of the IoU and the teacher's predicted IoU."""
    logits, quality, correction = outputs
    labels, geometry, target, iou = batch
    quality_weight, box_weight = weights
    ce = class_loss(logits, labels, class_weights, focal_gamma)
    box = torch.zeros(())
    objects = labels > 0
    if correction is not None:
        scale = torch.tensor((context, context, 1.0, 1.0), dtype=geometry.dtype)
        corrected = geometry + correction
        if objects.any():
            box = box_weight * ((corrected[objects] - target[objects]).abs() * scale).sum(dim=1).mean()
        chosen = objects.numpy()
        refined = np.zeros(len(labels), dtype=np.float32)
        refined[chosen] = encoded_iou(corrected.detach().numpy()[chosen], target.numpy()[chosen])
        iou = torch.from_numpy(refined)
    if teacher is not None:
        weight, temperature = distill
        teacher_log_probabilities, teacher_iou = teacher
        student = torch.log_softmax(logits / temperature, dim=1)
        kl = nn.functional.kl_div(student, teacher_log_probabilities, reduction="batchmean", log_target=True)
        ce = (1 - weight) * ce + weight * temperature**2 * kl
        iou = (1 - weight) * iou + weight * teacher_iou
    bce = nn.functional.binary_cross_entropy_with_logits(quality.reshape(-1), iou)
    return ce, quality_weight * bce, box


def model_signature(config: dict[str, Any]) -> dict[str, Any]:
    """What a checkpoint must share with the config to be resumed or exported under it."""
    model = dict(config["model"])
    if not model.get("box_correction"):
        model.pop("box_correction", None)  # a model without it is the one from before the option
    if model.get("input_norm", "none") == "none":
        model.pop("input_norm", None)  # likewise
    return {"model": model, "crop_size": CROP_SIZE, "context": crop_context(config), "min_side": MIN_SIDE}


def load_resume(path: Path, config: dict[str, Any]) -> dict[str, Any]:
    """The checkpoint at ``path``, checked against ``config``; :class:`ResumeError` with one line otherwise."""
    checkpoint = read_checkpoint(path)
    if checkpoint.get("kind") != "second_stage":
        raise ResumeError(f"cannot resume: {path} is not a second-stage checkpoint")
    if checkpoint.get("signature") != model_signature(config):
        raise ResumeError(
            f"cannot resume: {path} was trained with {checkpoint.get('signature')}, "
            f"the config asks for {model_signature(config)}"
        )
    return checkpoint


def _save(path: Path, payload: dict[str, Any]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    torch.save(payload, tmp)
    tmp.replace(path)


def predict(model: Classifier, crops: CropSet, batch: int = 512) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Class logits ``(N, 4)``, quality logits ``(N,)`` and corrected boxes ``(N, 4)`` (in the
    terms of :func:`~gldt_core.detect.second_stage.encode_boxes`) of a crop set, in eval mode."""
    model.eval()
    logits, quality, corrected = [], [], []
    with torch.no_grad():
        for start in range(0, len(crops), batch):
            geometry = torch.from_numpy(crops.geometry[start : start + batch].astype(np.float32))
            out = model.outputs(torch.from_numpy(crops.crops[start : start + batch].astype(np.float32)), geometry)
            logits.append(out[0].numpy())
            quality.append(out[1].numpy().reshape(-1))
            corrected.append((geometry if out[2] is None else geometry + out[2]).numpy())
    return np.concatenate(logits), np.concatenate(quality), np.concatenate(corrected)


def box_iou_after(model: Classifier, crops: CropSet, corrected: np.ndarray) -> np.ndarray:
    """``(N,)`` each crop's box IoU with its object's annotated box after the model's correction
    (the stored IoU where the model corrects nothing; 0 on background)."""
    if model.correction is None:
        return np.asarray(crops.quality, dtype=np.float64)
    return np.where(crops.labels > 0, encoded_iou(corrected, crops.target), 0.0)


def calibrate(model: Classifier, crops: CropSet) -> dict[str, Any]:
    """Fit the logistic calibration on the detector candidates of the calibration clips.

    A candidate is positive when it sits on a drone and its corrected box overlaps the drone's
    annotated box at IoU >= 0.5, the event a drone AP50 counts. Returns the card entry with the
    expected calibration error before (the raw evidence) and after.
    """
    from sklearn.linear_model import LogisticRegression

    candidates = np.isin(crops.sources, [SOURCES.index("global"), SOURCES.index("local")])
    subset = crops.subset(candidates)
    logits, quality, corrected = predict(model, subset)
    positive = (subset.labels == 1) & (box_iou_after(model, subset, corrected) >= 0.5)
    if positive.all() or not positive.any():
        raise ValueError(
            f"cannot calibrate: {int(positive.sum())} of {len(positive)} detector candidates of the calibration "
            "clips are drones boxed at IoU 0.5; both kinds are needed"
        )
    raw = evidence(logits, quality, subset.scores)
    fit = LogisticRegression(C=100.0, max_iter=2000).fit(np.log(np.clip(raw, 1e-9, 1.0))[:, None], positive)
    slope, bias = float(fit.coef_[0][0]), float(fit.intercept_[0])
    if not slope > 0:
        raise ValueError(f"cannot calibrate: the evidence does not rise with the chance of a drone (slope {slope})")
    calibrated = Calibration(slope, bias).probability(raw)
    return {
        "slope": slope,
        "bias": bias,
        "evidence": "P(drone) x predicted IoU x detector score",
        "fitted_on": "detector candidates of the calibration clips",
        "candidates": int(len(positive)),
        "positives": int(positive.sum()),
        "ece_before": expected_calibration_error(raw, positive),
        "ece_after": expected_calibration_error(calibrated, positive),
    }


def expected_calibration_error(probability: np.ndarray, outcome: np.ndarray, bins: int = 10) -> float:
    """Mean |predicted - observed| over equal-width probability bins, weighted by bin size."""
    edges = np.linspace(0, 1, bins + 1)
    which = np.clip(np.digitize(probability, edges[1:-1]), 0, bins - 1)
    total = 0.0
    for b in range(bins):
        sel = which == b
        if sel.any():
            total += sel.sum() * abs(probability[sel].mean() - outcome[sel].mean())
    return float(total / max(len(probability), 1))


def evaluate(model: Classifier, crops: CropSet) -> dict[str, float]:
    """Accuracy, recall per class, the box-quality error on drones and the drones' boxes against
    their annotations before and after the correction, for the card and the log."""
    logits, quality, corrected = predict(model, crops)
    predicted = logits.argmax(axis=1)
    out: dict[str, float] = {"accuracy": float((predicted == crops.labels).mean())}
    for index, name in enumerate(CLASS_NAMES):
        sel = crops.labels == index
        if sel.any():
            out[f"recall_{name}"] = float((predicted[sel] == index).mean())
    drones = crops.labels == 1
    if drones.any():
        predicted_iou = 1.0 / (1.0 + np.exp(-quality[drones]))
        after = box_iou_after(model, crops, corrected)[drones]
        out["drone_quality_mean_abs_error"] = float(np.mean(np.abs(predicted_iou - after)))
        out["drone_iou_mean_before"] = float(crops.quality[drones].mean())
        out["drone_iou_mean_after"] = float(after.mean())
        out["drone_at_iou_0.5_before"] = float((crops.quality[drones] >= 0.5).mean())
        out["drone_at_iou_0.5_after"] = float((after >= 0.5).mean())
    return out


def train_second_stage(
    config: dict[str, Any], out_dir: Path | None = None, resume: Path | None = None, progress: bool = True
) -> Path:
    """Train (or resume) the classifier, calibrate it, export ``second_stage.onnx``; returns the ONNX
    path (``last.pt`` where ``train.max_wall_s`` stopped the run). An ensemble config
    (:func:`load_config`) goes to :func:`train_ensemble`."""
    if ENSEMBLE_MEMBERS in config:
        return train_ensemble(config, out_dir, resume, progress)
    checkpoint = load_resume(resume, config) if resume is not None else None  # before anything is written
    out = Path(out_dir or config["out_dir"])
    torch.set_num_threads(int(config["threads"]))
    check_member(config)
    fit_set, calibration_set, about = training_crops(config, progress)
    fitted = fit_classifier(config, fit_set, calibration_set, out, checkpoint, progress)
    if fitted is None:
        return out / "last.pt"
    model, history = fitted
    return calibrate_and_export(model, calibration_set, {"config": config, **about, **history}, out)


def train_ensemble(
    config: dict[str, Any], out_dir: Path | None = None, resume: Path | None = None, progress: bool = True
) -> Path:
    """Train (or resume) each member of an ensemble config into ``member_N/`` of the run
    directory, then calibrate the :class:`CropClassifierEnsemble` of them and export it as one
    ``second_stage.onnx``. ``resume`` is the run directory: each member goes on from its
    ``member_N/last.pt`` where there is one (a finished member is only read back)."""
    members = config[ENSEMBLE_MEMBERS]
    checkpoints: list[dict[str, Any] | None] = [None] * len(members)
    if resume is not None:  # before anything is written
        folder = Path(resume)
        if not folder.is_dir():
            raise ResumeError(f"cannot resume: {folder} is not an ensemble's run directory (member_N/last.pt in it)")
        found = [folder / f"member_{i}" / "last.pt" for i in range(len(members))]
        if not any(path.is_file() for path in found):
            raise ResumeError(f"cannot resume: {folder} holds no member_N/last.pt")
        checkpoints = [load_resume(path, member) if path.is_file() else None for path, member in zip(found, members)]
    out = Path(out_dir or config["out_dir"])
    torch.set_num_threads(int(members[0]["threads"]))
    for member in members:
        check_member(member)
    # The members share their crops (load_config checks that their data sections agree).
    fit_set, calibration_set, about = training_crops(members[0], progress)
    models, histories = [], []
    for index, (member, checkpoint) in enumerate(zip(members, checkpoints)):
        fitted = fit_classifier(member, fit_set, calibration_set, out / f"member_{index}", checkpoint, progress, out)
        if fitted is None:
            return out / f"member_{index}" / "last.pt"
        models.append(fitted[0])
        histories.append({"config": member, **fitted[1]})
    training = {
        **about,
        "members": histories,
        "epochs": min(history["epochs"] for history in histories),
        "cpu_seconds_total": round(sum(history["cpu_seconds_total"] for history in histories), 1),
    }
    return calibrate_and_export(CropClassifierEnsemble(models), calibration_set, training, out)


def check_member(config: dict[str, Any]) -> None:
    """A config's model and training options, checked before any crop is cut."""
    focal_gamma(config)
    colour_augmentation(config)
    distillation(config)
    CropClassifier(**config["model"])
    teacher_members(config)


def training_crops(config: dict[str, Any], progress: bool = True) -> tuple[CropSet, CropSet, dict[str, Any]]:
    """The fit and calibration crops of a config, and what the model card says of them."""
    from gldt_core.detect.shipped import DEFAULT_GLOBAL_MODEL, DEFAULT_LOCAL_MODEL
    from gldt_core.paths import halmstad_root

    data = config["data"]
    root = Path(data["halmstad_root"] or halmstad_root())
    spec = CropSpec(**data["crops"])
    global_model = Path(data["global_model"] or DEFAULT_GLOBAL_MODEL)
    local_model = Path(data["local_model"] or DEFAULT_LOCAL_MODEL)
    fit_clips, calibration_clips = split_for_calibration(halmstad_split(root)["train"], int(data["calibration_period"]))
    scenes = synthetic_scenes(data["synthetic"])
    crops = build_crops(
        root,
        fit_clips + calibration_clips,
        spec,
        Path(data["cache_dir"]),
        global_model,
        local_model,
        progress,
        scenes=scenes,
    )
    is_fit = np.isin(np.asarray(crops.clip_names)[crops.clips], fit_clips + [scene.name for scene in scenes])
    fit_set, calibration_set = crops.subset(is_fit), crops.subset(~is_fit)
    about = {
        "crop_spec": asdict(spec),
        "fit_clips": fit_clips,
        "fit_scenes": [scene.name for scene in scenes],
        "calibration_clips": calibration_clips,
        "crops": {"fit": len(fit_set), "calibration": len(calibration_set)},
        "candidate_models": [global_model.name, local_model.name],
    }
    return fit_set, calibration_set, about


def calibrate_and_export(model: Classifier, calibration_set: CropSet, training: dict[str, Any], out: Path) -> Path:
    """Fit the calibration of a trained ``model``, then write ``out/second_stage.onnx`` and its card."""
    card = {
        "kind": "second_stage",
        "classes": list(CLASS_NAMES),
        "crop_size": CROP_SIZE,
        "context": float(training["crop_spec"]["context"]),
        "min_side": MIN_SIDE,
        "calibration": calibrate(model, calibration_set),
        "calibration_clip_figures": evaluate(model, calibration_set),
        "training": training,
    }
    return export_second_stage(model, out / "second_stage.onnx", card)


def fit_classifier(
    config: dict[str, Any],
    fit_set: CropSet,
    calibration_set: CropSet,
    out: Path,
    checkpoint: dict[str, Any] | None = None,
    progress: bool = True,
    resume_from: Path | None = None,
) -> tuple[CropClassifier, dict[str, Any]] | None:
    """Train on ``fit_set`` for ``train.epochs`` (from ``checkpoint``'s epoch when given), writing
    ``out/last.pt`` after every epoch; returns the model and its history, or None when
    ``train.max_wall_s`` stopped it early (resume from ``resume_from``, by default ``out/last.pt``)."""
    seed = int(config["seed"])
    torch.manual_seed(seed)
    model = CropClassifier(**config["model"])
    tcfg = config["train"]
    gamma, context, colour = focal_gamma(config), crop_context(config), colour_augmentation(config)
    distill = distillation(config)
    members, folds = teacher_members(config), int(tcfg["teacher_folds"])
    # What the checkpoint records of the teacher, so a resume under another one is refused.
    teacher = {"members": members, "folds": folds} if members else None
    optimizer = torch.optim.AdamW(model.parameters(), lr=float(tcfg["lr"]), weight_decay=float(tcfg["weight_decay"]))
    batch = int(tcfg["batch_size"])
    steps_per_epoch = math.ceil(len(fit_set) / batch)
    total_steps = int(tcfg["epochs"]) * steps_per_epoch
    if total_steps < MIN_STEPS:
        raise ValueError(
            f"{len(fit_set)} crops in batches of {batch} for {tcfg['epochs']} epochs make {total_steps} steps; "
            f"the schedule needs at least {MIN_STEPS}"
        )
    scheduler = torch.optim.lr_scheduler.OneCycleLR(
        optimizer, max_lr=float(tcfg["lr"]), total_steps=total_steps, pct_start=0.1
    )
    counts = np.bincount(fit_set.labels, minlength=NUM_CLASSES).astype(np.float64)
    class_weights = torch.tensor(np.sqrt(counts.sum() / np.maximum(counts, 1) / NUM_CLASSES), dtype=torch.float32)
    epoch, wall_total, log = 0, 0.0, []
    if checkpoint is not None:
        if checkpoint.get("total_steps") != total_steps:
            raise ResumeError(
                f"cannot resume: the checkpoint was scheduled for {checkpoint.get('total_steps')} steps, "
                f"this config and crop set give {total_steps}"
            )
        if checkpoint.get("teacher") != teacher:
            raise ResumeError(
                "cannot resume: the checkpoint learnt from another teacher than this config's "
                f"{config['train']['teacher']}"
            )
        try:
            model.load_state_dict(checkpoint["model"])
            optimizer.load_state_dict(checkpoint["optimizer"])
            scheduler.load_state_dict(checkpoint["scheduler"])
            epoch, wall_total, log = int(checkpoint["epoch"]), float(checkpoint["wall_s"]), list(checkpoint["log"])
        except (KeyError, RuntimeError, ValueError, TypeError) as error:
            raise ResumeError(
                f"cannot resume: the checkpoint's state does not fit ({type(error).__name__}: {error})"
            ) from None
    answers = None
    if teacher is not None:
        answers = out_of_fold_answers(members, folds, distill[1], fit_set, calibration_set, out, progress)
        if answers is None:
            return None  # a teacher's train.max_wall_s stopped it
    out.mkdir(parents=True, exist_ok=True)
    max_wall = tcfg.get("max_wall_s")
    session_start = time.perf_counter()
    while epoch < int(tcfg["epochs"]):
        started = time.perf_counter()
        rng = np.random.default_rng([seed, epoch])  # the data order and augmentation of this epoch
        order = rng.permutation(len(fit_set))
        model.train()
        totals = np.zeros(3)
        for step in range(steps_per_epoch):
            idx = np.sort(order[step * batch : (step + 1) * batch])
            x, geometry, target = augment(fit_set.crops[idx], fit_set.geometry[idx], fit_set.target[idx], rng, colour)
            geometry_t = torch.from_numpy(geometry)
            ce, quality, box = losses(
                model.outputs(torch.from_numpy(x), geometry_t),
                (
                    torch.from_numpy(fit_set.labels[idx]),
                    geometry_t,
                    torch.from_numpy(target),
                    torch.from_numpy(fit_set.quality[idx].astype(np.float32)),
                ),
                class_weights,
                (float(tcfg["quality_weight"]), float(tcfg["box_weight"])),
                context,
                gamma,
                None if answers is None else (torch.from_numpy(answers[0][idx]), torch.from_numpy(answers[1][idx])),
                distill,
            )
            optimizer.zero_grad()
            (ce + quality + box).backward()
            optimizer.step()
            scheduler.step()
            totals += [ce.item(), quality.item(), box.item()]
        epoch += 1
        wall_total += time.perf_counter() - started
        row = {
            "epoch": epoch,
            "ce": totals[0] / steps_per_epoch,
            "quality": totals[1] / steps_per_epoch,
            "box": totals[2] / steps_per_epoch,
            "wall_s": round(wall_total, 1),
        }
        row.update({f"calibration_{k}": round(v, 4) for k, v in evaluate(model, calibration_set).items()})
        log.append(row)
        if progress:
            print(f"[second-stage] {json.dumps(row)}", flush=True)
        _save(
            out / "last.pt",
            {
                "kind": "second_stage",
                "signature": model_signature(config),
                "config": config,
                "model": model.state_dict(),
                "optimizer": optimizer.state_dict(),
                "scheduler": scheduler.state_dict(),
                "epoch": epoch,
                "total_steps": total_steps,
                "teacher": teacher,
                "wall_s": wall_total,
                "log": log,
            },
        )
        if (
            max_wall is not None
            and time.perf_counter() - session_start > float(max_wall)
            and epoch < int(tcfg["epochs"])
        ):
            print(
                f"[second-stage] stopped after epoch {epoch} (max_wall_s); "
                f"resume with --resume {resume_from or out / 'last.pt'}"
            )
            return None
    history: dict[str, Any] = {"epochs": epoch, "cpu_seconds_total": round(wall_total, 1), "log": log}
    if answers is not None:
        history["teacher"] = {
            "config": tcfg["teacher"],
            "folds": folds,
            "cpu_seconds_total": round(answers[2], 1),
        }
    return model, history


def export_second_stage(model: Classifier, path: Path, card: dict[str, Any]) -> Path:
    """Write the ONNX model and its sidecar card; checks onnxruntime against torch first."""
    import onnxruntime as ort

    model = model.eval()
    tmp = path.with_name(path.name + ".tmp")
    example = (torch.rand(3, 6, CROP_SIZE, CROP_SIZE) * 255, torch.randn(3, 4) * 0.3)
    outputs = ["class_logits", "quality_logit"] + ([] if model.correction is None else ["box_correction"])
    with torch.no_grad():
        torch.onnx.export(
            model,
            example,
            str(tmp),
            input_names=["crops", "geometry"],
            output_names=outputs,
            dynamic_axes={n: {0: "n"} for n in ("crops", "geometry", *outputs)},
            opset_version=17,
            dynamo=False,
        )
        expected = [t.numpy() for t in model(*example)]
    session = ort.InferenceSession(str(tmp), providers=["CPUExecutionProvider"])
    got = session.run(None, {"crops": example[0].numpy(), "geometry": example[1].numpy()})
    worst = max(float(np.abs(a - b).max()) for a, b in zip(expected, got))
    if worst > 1e-3:
        raise RuntimeError(f"exported second stage differs from torch by {worst}")
    tmp.replace(path)
    path.with_suffix(".json").write_text(json.dumps(card, indent=1) + "\n")
    return path


def load_config(path: Path | str) -> dict[str, Any]:
    """The YAML config over :data:`DEFAULTS`; unknown keys are refused with their path.

    An ensemble config has ``members`` (and optionally ``out_dir``): each member a mapping with
    ``config``, a second-stage config's path relative to the ensemble's file, and any keys of that
    config to change for this member. It loads as ``{"out_dir": ..., "members": [config, ...]}``;
    the members must cut the same crops (their ``data`` sections agree)."""
    import yaml

    from gldt_core.training.train import merge_config

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"config not found: {path}")
    loaded = yaml.safe_load(path.read_text()) or {}
    if not isinstance(loaded, dict):
        raise ValueError(f"{path}: expected a mapping at the top level")
    if ENSEMBLE_MEMBERS not in loaded:
        config = merge_config(json.loads(json.dumps(DEFAULTS)), loaded)
        if isinstance(config["train"]["teacher"], str):  # a path relative to this file, as members' are
            config["train"]["teacher"] = str(path.parent / config["train"]["teacher"])
        return config
    unknown = sorted(set(loaded) - {ENSEMBLE_MEMBERS, "out_dir"})
    if unknown:
        raise ValueError(f"{path}: an ensemble config has only members and out_dir, not {', '.join(unknown)}")
    entries = loaded[ENSEMBLE_MEMBERS]
    if not isinstance(entries, list) or len(entries) < 2:
        raise ValueError(f"{path}: members must list at least two member configs")
    members: list[dict[str, Any]] = []
    for index, entry in enumerate(entries):
        if not isinstance(entry, dict) or not isinstance(entry.get("config"), str):
            raise ValueError(f"{path}: members[{index}] must be a mapping with config: PATH (and keys to change)")
        member = load_config(path.parent / entry["config"])
        if ENSEMBLE_MEMBERS in member:
            raise ValueError(f"{path}: members[{index}] is an ensemble itself")
        member = merge_config(member, {key: value for key, value in entry.items() if key != "config"})
        if member["model"].get("box_correction"):
            raise ValueError(f"{path}: members[{index}] corrects boxes, which an ensemble cannot average")
        if members and member["data"] != members[0]["data"]:
            raise ValueError(
                f"{path}: members[{index}]'s data section differs from members[0]'s; they share one crop set"
            )
        members.append(member)
    return {"out_dir": str(loaded.get("out_dir", "runs/second_stage_ensemble")), ENSEMBLE_MEMBERS: members}
