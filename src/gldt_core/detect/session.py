"""Opening and checking a detector model: the onnxruntime session, its model card, its classes.

Everything the detectors of :mod:`gldt_core.detect` (and the split pair of
:mod:`gldt_core.detect.feature_reuse`) need before the first frame: :func:`open_session` creates
the session and reads the model card, and :class:`OnnxDetector` holds what both detectors share
(session, card, the MOT class codes of the output channels, score and IoU thresholds).

A model that cannot be used (missing file, not ONNX, inputs or outputs that do not match what the
detector feeds and reads) raises :class:`DetectorConfigError` when it is opened, naming the file
and the expectation, rather than failing on the first frame.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

#: ONNX metadata key of the model card that ``gldt export`` embeds (:mod:`gldt_core.export.onnx_export`).
CARD_KEY = "gldt_card"


class DetectorConfigError(ValueError):
    """The detector model or its configuration cannot be used; the message names file and expectation."""


def read_card(session: Any, path: Path) -> dict[str, Any]:
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
    ``optimize_graph`` the session opens much faster (no graph rewriting) but runs slower: for
    callers that only need the model's input geometry and card.
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
    # also for a while after run() returns. Here several sessions share few cores: AM-YOLO's split
    # pair runs two sessions per frame, GD and LD alternate, and in the ROS graph each detector is
    # its own process beside the decoder. The threads of the session that just finished would then
    # spin on the core the next session or process needs, so they stop when a run ends
    # (`gldt bench latency` measures the effect; see docs/experiment-log.md).
    options.add_session_config_entry("session.force_spinning_stop", "1")
    if not optimize_graph:
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    try:
        session = ort.InferenceSession(str(path), options, providers=providers)
    except Exception as error:  # onnxruntime raises several private exception types
        raise DetectorConfigError(
            f"{path}: cannot load ONNX model ({type(error).__name__}: {str(error).splitlines()[0][:200]}){wanted}"
        ) from error
    return session, read_card(session, path)


def check_image_input(path: Path, model_input: Any, expectation: str) -> None:
    """Refuse a session input that is not a float ``(batch, 3, H, W)`` image."""
    shape = model_input.shape
    if len(shape) != 4 or shape[1] != 3 or "float" not in model_input.type:
        raise DetectorConfigError(
            f"{path}: input {model_input.name!r} has shape {shape} ({model_input.type}); expected {expectation}"
        )


def output_class_count(session: Any, path: Path, card: dict[str, Any]) -> int:
    """Number of classes: from the output shape when static, else from the model card."""
    out = session.get_outputs()[0]
    expected = "expected (batch, 4 + num_classes, anchors)"
    if len(out.shape) != 3:
        raise DetectorConfigError(f"{path}: output {out.name!r} has shape {out.shape}; {expected}")
    if isinstance(out.shape[1], int):
        if out.shape[1] < 5:
            raise DetectorConfigError(f"{path}: output {out.name!r} has shape {out.shape}; {expected}")
        return int(out.shape[1]) - 4
    classes = card.get("classes") or card.get("class_ids")
    if not classes:
        raise DetectorConfigError(
            f"{path}: output {out.name!r} has a dynamic class axis and no model card lists the classes; {expected}"
        )
    return len(classes)


def class_ids(card: dict[str, Any], num_classes: int) -> np.ndarray:
    """MOT class code of each output channel: the card's ``class_ids``, else 1, 2, 3, ..."""
    ids = card.get("class_ids") or list(range(1, num_classes + 1))
    if len(ids) < num_classes:
        raise DetectorConfigError(f"model card lists {len(ids)} class_ids but the model outputs {num_classes} classes")
    return np.asarray(ids[:num_classes], dtype=np.float32)


def check_score_threshold(score_threshold: object) -> None:
    """:class:`DetectorConfigError` in one line unless ``score_threshold`` is a number in [0, 1]."""
    if not isinstance(score_threshold, (int, float)) or not 0.0 <= score_threshold <= 1.0:
        raise DetectorConfigError(f"score_threshold must be in [0, 1], got {score_threshold}")


class OnnxDetector:
    """What both detectors share: a checked onnxruntime session, its model card, the class ids of
    its outputs and the score/IoU thresholds. Subclasses check their own inputs in between
    :meth:`_open` and :meth:`_read_classes`."""

    #: The inputs the subclass feeds, named in every error about its model file.
    EXPECTATION = ""

    model_path: Path
    card: dict[str, Any]
    score_threshold: float
    iou_threshold: float
    class_ids: np.ndarray
    classes: tuple[int, ...] | None
    class_channels: np.ndarray | None

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
        check_score_threshold(score_threshold)
        self.model_path = Path(model_path) if model_path is not None else default_path
        self.providers, self.num_threads = tuple(providers), num_threads
        self._session, self.card = open_session(
            self.model_path, providers, num_threads, self.EXPECTATION, optimize_graph
        )
        self._reopen_optimized = False  # set by a subclass that opened the file unoptimised only to check it
        self.score_threshold = float(score_threshold)
        self.iou_threshold = float(iou_threshold)
        return list(self._session.get_inputs())

    def _open_optimized(self) -> None:
        """Open the (already checked) model file again, with graph optimisation."""
        self._session, _ = open_session(self.model_path, self.providers, self.num_threads, self.EXPECTATION, True)
        self._reopen_optimized = False

    @property
    def session(self) -> Any:
        """The model's onnxruntime session. One opened without graph optimisation only to check the
        file and read its card (``_reopen_optimized``) is reopened optimised when first asked for."""
        if self._reopen_optimized:
            self._open_optimized()
        return self._session

    def _read_classes(self, classes: Sequence[int] | None) -> None:
        """Class ids of the output channels (after the inputs were found usable), and the channels
        of the ``classes`` (MOT codes) the caller asks about; None asks about every class."""
        self.class_ids = class_ids(self.card, output_class_count(self._session, self.model_path, self.card))
        self.classes = None if classes is None else tuple(int(c) for c in classes)
        self.class_channels = None
        if self.classes is not None:
            known = [int(c) for c in self.class_ids]
            unknown = [c for c in self.classes if c not in known]
            if unknown or not self.classes:
                raise DetectorConfigError(
                    f"{self.model_path}: classes {list(self.classes)} asked for, "
                    f"but the model outputs classes {known} (MOT codes)"
                )
            self.class_channels = np.array([known.index(c) for c in self.classes], dtype=np.int64)

    def _label(self, detections: np.ndarray) -> np.ndarray:
        """Replace the channel index in column 5 of decoded ``detections`` by its MOT class code."""
        if len(detections):
            detections[:, 5] = self.class_ids[detections[:, 5].astype(np.int64)]
        return detections
