"""onnxruntime wrappers of the shipped detectors: :class:`GlobalDetector` and :class:`LocalDetector`.

No torch here: the models were exported by ``gldt export`` and are run with onnxruntime on
whatever execution providers the platform has (CPU by default; CUDA or TensorRT on a Jetson).
Both wrappers return boxes in full-frame pixels with MOTChallenge class codes (1 drone, 2 bird,
3 airplane) so the tracker never sees network-input coordinates.

A model that cannot be used (missing file, not ONNX, inputs that do not match what the wrapper
feeds) raises :class:`DetectorConfigError` at construction, naming the file and the expectation,
rather than failing on the first frame.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gldt_core.detect.feature_reuse import FeatureReuse, features_path, load_feature_reuse, reuse_path
from gldt_core.detect.postprocess import ensure_bgr, rect_input_size
from gldt_core.detect.staged import GlobalCarry

MODELS_DIR = Path(__file__).resolve().parent.parent / "models"
DEFAULT_GLOBAL_MODEL = MODELS_DIR / "global_amyolo.onnx"
DEFAULT_LOCAL_MODEL = MODELS_DIR / "local_p2.onnx"
CARD_KEY = "gldt_card"
DRONE_CLASS_ID = 1  # MOTChallenge class code of drones


class DetectorConfigError(ValueError):
    """The detector model or its configuration cannot be used; the message names file and expectation."""


def _read_card(session: Any, path: Path) -> dict[str, Any]:
    """The model card embedded in the ONNX metadata, else the sidecar JSON, else {}."""
    meta = session.get_modelmeta().custom_metadata_map
    if CARD_KEY in meta:
        try:
            return json.loads(meta[CARD_KEY])
        except json.JSONDecodeError as error:
            raise DetectorConfigError(f"{path}: embedded model card is not valid JSON ({error})") from error
    sidecar = path.with_suffix(".json")
    if sidecar.is_file():
        try:
            return json.loads(sidecar.read_text())
        except json.JSONDecodeError as error:
            raise DetectorConfigError(f"{sidecar}: model card is not valid JSON ({error})") from error
    return {}


GLOBAL_INPUT_EXPECTATION = "inputs (previous, current), each (1, 3, H, W) float32 RGB"
LOCAL_INPUT_EXPECTATION = "one input (N, 3, S, S) float32 RGB ROI crops"


def open_session(
    model_path: Path | str,
    providers: Sequence[str],
    num_threads: int | None,
    expectation: str = "",
    optimize_graph: bool = True,
) -> tuple[Any, dict[str, Any]]:
    """Create an onnxruntime session and read the model card; errors become :class:`DetectorConfigError`.

    ``expectation`` (the input shapes the caller needs) is named in every error, so a user who
    points the wrong file at a detector learns what the file should have been. Without
    ``optimize_graph`` the session opens about 4x faster (no graph rewriting) but runs slower:
    for callers that only need the model's input geometry and card.
    """
    wanted = f"; expected an ONNX model exported by `gldt export` with {expectation}" if expectation else ""
    import onnxruntime as ort

    path = Path(model_path)
    if not path.is_file():
        raise DetectorConfigError(
            f"{path}: detector model not found{wanted or ' (expected an ONNX file exported by `gldt export`)'}"
        )
    available = ort.get_available_providers()
    providers = list(providers)
    if not providers:
        raise DetectorConfigError(f"{path}: no execution providers given; available: {available}")
    unknown = [p for p in providers if p not in available]
    if unknown:
        raise DetectorConfigError(
            f"{path}: execution providers {unknown} are not available in this onnxruntime build; available: {available}"
        )
    options = ort.SessionOptions()
    if num_threads is not None:
        if num_threads < 1:
            raise DetectorConfigError(f"num_threads must be >= 1 or None, got {num_threads}")
        options.intra_op_num_threads = int(num_threads)
    options.log_severity_level = 3
    # onnxruntime's intra-op threads busy-wait for work between operators (fast) and, by default,
    # also for a while after run() returns. Here several sessions share two cores: AM-YOLO's split
    # pair runs two sessions per frame, GD and LD alternate, and in the ROS graph each detector is
    # its own process beside the decoder. The threads of the session that just finished then spin
    # on the core the next session or process needs. Stopping them when a run ends took AM-YOLO
    # from about 43 to 21 ms a GD-stretch frame in `gldt bench latency` at 2 threads (README).
    options.add_session_config_entry("session.force_spinning_stop", "1")
    if not optimize_graph:
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    try:
        session = ort.InferenceSession(str(path), options, providers=providers)
    except Exception as error:  # onnxruntime raises several private exception types
        raise DetectorConfigError(
            f"{path}: cannot load ONNX model ({type(error).__name__}: {str(error).splitlines()[0][:200]}){wanted}"
        ) from error
    return session, _read_card(session, path)


def _check_image_input(path: Path, inp: Any, expectation: str) -> None:
    shape = inp.shape
    if len(shape) != 4 or shape[1] != 3 or "float" not in inp.type:
        raise DetectorConfigError(f"{path}: input {inp.name!r} has shape {shape} ({inp.type}); expected {expectation}")


def _class_ids(card: dict[str, Any], num_classes: int) -> np.ndarray:
    ids = card.get("class_ids") or list(range(1, num_classes + 1))
    if len(ids) < num_classes:
        raise DetectorConfigError(f"model card lists {len(ids)} class_ids but the model outputs {num_classes} classes")
    return np.asarray(ids[:num_classes], dtype=np.float32)


def _output_classes(session: Any, path: Path, card: dict[str, Any]) -> int:
    """Number of classes: from the output shape when static, else from the model card."""
    out = session.get_outputs()[0]
    expected = "expected (batch, 4 + num_classes, anchors)"
    if len(out.shape) != 3:
        raise DetectorConfigError(f"{path}: output {out.name!r} has shape {out.shape}; {expected}")
    if isinstance(out.shape[1], int):
        if out.shape[1] < 5:
            raise DetectorConfigError(f"{path}: output {out.name!r} has shape {out.shape}; {expected}")
        return out.shape[1] - 4
    classes = card.get("classes") or card.get("class_ids")
    if not classes:
        raise DetectorConfigError(
            f"{path}: output {out.name!r} has a dynamic class axis and no model card lists the classes; {expected}"
        )
    return len(classes)


def _drop_degenerate(dets: np.ndarray) -> np.ndarray:
    """Remove boxes that clipping to the frame reduced to zero width or height."""
    return dets[(dets[:, 2] > dets[:, 0]) & (dets[:, 3] > dets[:, 1])]


class _OnnxDetector:
    """What both detectors share: a checked onnxruntime session, its model card, the class ids of
    its outputs and the score/IoU thresholds. Subclasses check their own inputs in between."""

    EXPECTATION = ""

    def _open(
        self,
        model_path: Path | str | None,
        default_path: Path,
        providers: Sequence[str],
        num_threads: int | None,
        score_threshold: float,
        iou_threshold: float,
        optimize_graph: bool = True,
    ) -> list[Any]:
        """Open the model; returns its session inputs for the subclass to check."""
        if not 0.0 <= score_threshold <= 1.0:
            raise DetectorConfigError(f"score_threshold must be in [0, 1], got {score_threshold}")
        self.model_path = Path(model_path) if model_path is not None else default_path
        self.providers, self.num_threads = tuple(providers), num_threads
        self._session, self.card = open_session(
            self.model_path, providers, num_threads, self.EXPECTATION, optimize_graph
        )
        self._reopen_optimized = False  # set by a subclass that opened the file unoptimised only to check it
        self.score_threshold = float(score_threshold)
        self.iou_threshold = float(iou_threshold)
        return list(self._session.get_inputs())

    @property
    def session(self) -> Any:
        """The model's onnxruntime session. One opened without graph optimisation only to check the
        file and read its card (``_reopen_optimized``) is reopened optimised when first asked for."""
        if self._reopen_optimized:
            self._session, _ = open_session(self.model_path, self.providers, self.num_threads, self.EXPECTATION, True)
            self._reopen_optimized = False
        return self._session

    def _read_classes(self, classes: Sequence[int] | None) -> None:
        """Class ids of the output channels (after the inputs were found usable), and the channels
        of the ``classes`` (MOT codes) the caller asks about; None asks about every class."""
        self.class_ids = _class_ids(self.card, _output_classes(self._session, self.model_path, self.card))
        self.classes = None if classes is None else tuple(int(c) for c in classes)
        self.class_channels: np.ndarray | None = None
        if self.classes is not None:
            known = [int(c) for c in self.class_ids]
            unknown = [c for c in self.classes if c not in known]
            if unknown or not self.classes:
                raise DetectorConfigError(
                    f"{self.model_path}: classes {list(self.classes)} asked for, but the model outputs classes {known} (MOT codes)"
                )
            self.class_channels = np.array([known.index(c) for c in self.classes], dtype=np.int64)


class GlobalDetector(_OnnxDetector):
    """AM-YOLO on a (previous, current) pair of full frames; boxes in full-frame pixels.

    The frame is letterboxed into a rectangular input whose long side is ``long_side`` (default:
    the card's training long side) and whose sides are multiples of the card's ``input_multiple``;
    a 1920x1080 frame becomes 640x384 with the default 640. ``optimize_graph=False`` is for
    callers that only letterbox frames for it (:meth:`input_size`): it opens 4x faster.

    ``feature_reuse`` (None: when available) runs the split pair written by ``gldt export MODEL
    --feature-reuse`` instead of the full model, with the same boxes; :meth:`detect_pair` then
    hands each GD frame's features to the next (:mod:`gldt_core.detect.feature_reuse`).
    """

    EXPECTATION = GLOBAL_INPUT_EXPECTATION

    def __init__(
        self,
        model_path: Path | str | None = None,
        providers: Sequence[str] = ("CPUExecutionProvider",),
        score_threshold: float = 0.25,
        num_threads: int | None = None,
        iou_threshold: float = 0.5,
        long_side: int | None = None,
        max_detections: int = 300,
        optimize_graph: bool = True,
        classes: Sequence[int] | None = None,
        feature_reuse: bool | None = None,
    ):
        if feature_reuse and not optimize_graph:
            raise DetectorConfigError(
                "feature_reuse=True runs the model, but optimize_graph=False opens it for its geometry only"
            )
        # Where a split pair lies next to the model, the model is checked first, opened unoptimised
        # (4x faster) so errors name the file given, and optimised only if the pair cannot be used
        # or someone asks for ``session``. Without one it is opened optimised straight away.
        path = Path(model_path) if model_path is not None else DEFAULT_GLOBAL_MODEL
        split_first = (
            optimize_graph
            and feature_reuse is not False
            and features_path(path).is_file()
            and reuse_path(path).is_file()
        )
        inputs = self._open(
            model_path,
            DEFAULT_GLOBAL_MODEL,
            providers,
            num_threads,
            score_threshold,
            iou_threshold,
            optimize_graph and not split_first,
        )
        if len(inputs) not in (1, 2):
            raise DetectorConfigError(
                f"{self.model_path}: has {len(inputs)} inputs; a global detector needs (previous, current) frames, each (1, 3, H, W)"
            )
        for inp in inputs:
            _check_image_input(self.model_path, inp, "(1, 3, H, W) float32 RGB frames (previous, current)")
        self.input_names = [i.name for i in inputs]
        self.dual_frame = len(inputs) == 2
        self.multiple = int(self.card.get("input_multiple", 64))
        fixed = inputs[0].shape[2:]
        self.fixed_size = tuple(fixed[::-1]) if all(isinstance(d, int) for d in fixed) else None
        size = self.card.get("input_size", [640, 384])
        self.long_side = int(long_side or self.card.get("runtime_long_side", max(size)))
        if self.long_side % self.multiple:
            raise DetectorConfigError(
                f"{self.model_path}: long_side {self.long_side} must be a multiple of {self.multiple}"
            )
        self._read_classes(classes)
        self.max_detections = int(max_detections)
        self.feature_reuse: FeatureReuse | None = None
        if split_first or (optimize_graph and feature_reuse):  # required but absent: a clear error
            self.feature_reuse = load_feature_reuse(self.model_path, providers, num_threads, feature_reuse)
        if split_first:
            if self.feature_reuse is None:  # the full model runs every pair: optimise it now, not on the first frame
                self._session, _ = open_session(self.model_path, providers, num_threads, self.EXPECTATION, True)
            else:
                self._reopen_optimized = True

    def input_size(self, frame_w: int, frame_h: int) -> tuple[int, int]:
        """Network input ``(w, h)`` used for a frame of this size."""
        if self.fixed_size is not None:
            return self.fixed_size  # type: ignore[return-value]
        return rect_input_size(frame_w, frame_h, self.long_side, self.multiple)

    def detect(self, previous_bgr: np.ndarray | None, current_bgr: np.ndarray) -> np.ndarray:
        """``(N, 6)`` float32 ``[x1, y1, x2, y2, score, class_id]`` in full-frame pixels.

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

        A stream caller passes that :class:`~gldt_core.detect.staged.GlobalCarry` back as
        ``carry`` on the next frame, so each frame of a GD stretch is letterboxed once instead of
        twice (a 1080p resize is a few ms) and, with the split model, runs the backbone's first
        stages once instead of twice; ``frame_pair_buffer`` and ``global_detector`` do the same in
        the ROS graph. ``carry`` must come from the frame ``previous_bgr``; one of another input
        size (the frame size changed) is ignored and the previous frame processed afresh.
        """
        if carry is not None and not isinstance(carry, GlobalCarry):
            raise TypeError(
                f"carry must be the GlobalCarry an earlier detect_pair returned, got {type(carry).__name__}"
            )
        current = ensure_bgr(current_bgr, "current frame")
        previous = current if previous_bgr is None else ensure_bgr(previous_bgr, "previous frame")
        if previous.shape != current.shape:
            raise ValueError(
                f"previous frame {previous.shape[1]}x{previous.shape[0]} and current frame {current.shape[1]}x{current.shape[0]} differ in size"
            )
        from gldt_core.detect.staged import detect_global_streamed, prepare_global_input

        current_input, mapping = prepare_global_input(self, current)
        previous_features = None
        if previous is current:
            previous_input = current_input
        elif carry is not None and carry.input.shape == current_input.shape:
            previous_input, previous_features = carry.input, carry.features
        else:
            previous_input = prepare_global_input(self, previous)[0]
        detections, current_features = detect_global_streamed(
            self, previous_input, current_input, mapping, current.shape[1], current.shape[0], previous_features
        )
        return detections, GlobalCarry(current_input, current_features)


class LocalDetector(_OnnxDetector):
    """The local P2 detector on square ROIs of one frame, run as ONE onnxruntime batch."""

    EXPECTATION = LOCAL_INPUT_EXPECTATION

    def __init__(
        self,
        model_path: Path | str | None = None,
        providers: Sequence[str] = ("CPUExecutionProvider",),
        score_threshold: float = 0.25,
        num_threads: int | None = None,
        iou_threshold: float = 0.5,
        max_detections_per_roi: int = 100,
        classes: Sequence[int] | None = None,
    ):
        inputs = self._open(model_path, DEFAULT_LOCAL_MODEL, providers, num_threads, score_threshold, iou_threshold)
        if len(inputs) != 1:
            raise DetectorConfigError(
                f"{self.model_path}: has {len(inputs)} inputs; a local detector needs one (N, 3, S, S) batch of ROI crops"
            )
        inp = inputs[0]
        _check_image_input(self.model_path, inp, "(N, 3, S, S) float32 RGB ROI crops with a fixed square size S")
        h, w = inp.shape[2], inp.shape[3]
        if not (isinstance(h, int) and isinstance(w, int) and h == w):
            raise DetectorConfigError(
                f"{self.model_path}: input {inp.name!r} has shape {inp.shape}; expected (N, 3, S, S) with a fixed square S"
            )
        self.input_name = inp.name
        self.input_side = int(h)
        self._read_classes(classes)
        self.max_detections_per_roi = int(max_detections_per_roi)

    @staticmethod
    def _check_rois(rois: np.ndarray, frame_w: int, frame_h: int) -> np.ndarray:
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
                f"roi {int(np.flatnonzero(outside)[0])} {rois[outside][0].tolist()} lies outside the {frame_w}x{frame_h} frame"
            )
        return rois

    @staticmethod
    def crop(frame: np.ndarray, roi: np.ndarray) -> np.ndarray:
        """The ROI's pixels; parts outside the frame are filled with the letterbox grey."""
        h, w = frame.shape[:2]
        x1, y1, x2, y2 = (int(v) for v in roi)
        out = np.full((y2 - y1, x2 - x1, 3), 114, dtype=np.uint8)
        sx1, sy1, sx2, sy2 = max(x1, 0), max(y1, 0), min(x2, w), min(y2, h)
        out[sy1 - y1 : sy2 - y1, sx1 - x1 : sx2 - x1] = frame[sy1:sy2, sx1:sx2]
        return out

    def detect_rois(self, frame_bgr: np.ndarray, rois: np.ndarray) -> np.ndarray:
        """``(N, 7)`` float32 ``[x1, y1, x2, y2, score, class_id, roi_index]`` in full-frame pixels."""
        frame = ensure_bgr(frame_bgr, "frame")
        h, w = frame.shape[:2]
        rois = self._check_rois(rois, w, h)
        if len(rois) == 0:
            return np.zeros((0, 7), dtype=np.float32)
        from gldt_core.detect.staged import detect_local_crops

        return detect_local_crops(self, [self.crop(frame, roi) for roi in rois], rois, w, h)


def shipped_model_path(kind: str) -> Path:
    """Path of a shipped model: ``global``, ``global_nostff``, ``local``, ``global_balanced``, ``local_balanced``
    or ``global_nostff_balanced``."""
    names = {
        "global": DEFAULT_GLOBAL_MODEL,
        "local": DEFAULT_LOCAL_MODEL,
        "global_nostff": MODELS_DIR / "global_nostff.onnx",
        # Opt-in pair trained with half of the draws synthetic (configs/run/balanced_models.yaml),
        # and the balanced AM-YOLO's twin without STFF (the STFF ablation on that data mix).
        "global_balanced": MODELS_DIR / "global_amyolo_balanced.onnx",
        "local_balanced": MODELS_DIR / "local_p2_balanced.onnx",
        "global_nostff_balanced": MODELS_DIR / "global_nostff_balanced.onnx",
    }
    if kind not in names:
        raise ValueError(f"unknown shipped model {kind!r}; choose one of {sorted(names)}")
    return names[kind]


def default_num_threads() -> int | None:
    """Honour GLDT_ORT_THREADS for runs that share the CPU with other work."""
    value = os.environ.get("GLDT_ORT_THREADS")
    return int(value) if value else None
