"""GLDTSystem: one frame in, tracks out - detectors, mode scheduler and tracker composed in-process.

Per frame: ask the tracker where its stable tracks will be at ``t``; let the scheduler pick GD
or LD (and the ROIs); run the global detector on the frame pair ``(F_t-1, F_t)`` or the local
detector on all ROIs as one batch; feed the detections to the tracker; report the per-ROI hit
counts back to the scheduler. The previous frame is kept on *every* frame, so the first GD
frame after an LD stretch still gets a true consecutive pair. On the very first frame (and after
a re-initialisation) there is no predecessor and the frame is paired with itself: GD then sees
no motion cue for one frame, which is the best that can be done.

The ROS nodes run the same pieces in separate processes: :class:`ModeScheduler` and
:func:`plan_rois` need no images or models; only the wiring here is offline-specific.

Bad input keeps the system running and says so: a frame of another size re-initialises
(warning), time going backwards re-initialises (warning), a dropped frame (a timestamp gap) is
counted and handled by the tracker's time-based prediction, black or saturated frames are just
frames. Inputs that are not frames at all (wrong shape/dtype, NaN time) raise ``ValueError``.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING, Any, Protocol, cast

import numpy as np

from gldt_core.detect.second_stage import GLOBAL_COLUMNS, LOCAL_COLUMNS, PROBABILITY_COLUMNS
from gldt_core.schedule.roi import EMPTY_LAYOUT, RoiLayout
from gldt_core.schedule.scheduler import FramePlan, Mode, ModeScheduler
from gldt_core.system.config import SystemConfig
from gldt_core.system.steps import (
    detections_per_roi,
    drop_nested,
    filter_classes,
    merge_local_detections,
    stable_predictions,
    valid_detection_mask,
    with_class_probabilities,
)
from gldt_core.system.timing import StageTimer
from gldt_core.track.class_evidence import ClassEvidence

if TYPE_CHECKING:
    from gldt_core.detect.global_detector import GlobalCarry
    from gldt_core.track.base import MultiStageTracker

LOG = logging.getLogger("gldt.system")

#: A gap longer than this many nominal frame periods counts as dropped frames.
_GAP_FACTOR = 1.5


class GlobalDetectorLike(Protocol):
    def detect(self, previous_bgr: np.ndarray, current_bgr: np.ndarray) -> np.ndarray: ...


class LocalDetectorLike(Protocol):
    def detect_rois(self, frame_bgr: np.ndarray, rois: np.ndarray) -> np.ndarray: ...


class TrackerLike(Protocol):
    def update(self, detections: np.ndarray, t_seconds: float) -> np.ndarray: ...

    def predict(self, t_seconds: float) -> np.ndarray: ...

    def reset(self) -> None: ...


class RoiTrackerLike(TrackerLike, Protocol):
    """A tracker whose ``update`` also takes the window each detection came from (PMR's eq. 16)."""

    def update(self, detections: np.ndarray, t_seconds: float, *, rois: np.ndarray | None = None) -> np.ndarray: ...


@dataclass(frozen=True)
class SystemState:
    """What the system is doing now; for the overlay, logs, ROS diagnostics and tests."""

    frame_index: int  # frames processed since start (not reset by re-initialisation)
    mode: Mode  # mode of the last processed frame
    frames_in_mode: int
    frames_without_detection: int
    rois: np.ndarray  # (R, 4) windows of the last frame (empty in GD)
    roi_groups: tuple[tuple[int, ...], ...]
    tracks: np.ndarray  # (M, 6) output of the last frame
    detections: np.ndarray  # (N, 5) detections fed to the tracker on the last frame
    class_probabilities: np.ndarray  # (N, 3) their drone, bird and airplane probabilities
    global_frames: int
    local_frames: int
    reinitialisations: int
    dropped_frame_gaps: int
    invalid_detections: int  # non-finite / empty boxes from a detector, dropped
    frame_size: tuple[int, int] | None


def accepts_keyword(function: Any, name: str) -> bool:
    """Whether ``function`` takes keyword ``name`` (trackers may or may not use ROIs)."""
    import inspect

    try:
        parameters = inspect.signature(function).parameters
    except (TypeError, ValueError):
        return False
    return name in parameters or any(p.kind is inspect.Parameter.VAR_KEYWORD for p in parameters.values())


def build_tracker(config: SystemConfig, image_size: tuple[int, int] | None = None) -> MultiStageTracker:
    """The tracker the config names (JPTrack or ByteTrack), built from its params.

    ``image_size`` (width, height) gives the trackers the frame's size, for the relative
    positions PMR models (eq. 16) where no ROI frames a target; unknown parameter names are
    refused with the list of known ones.
    """
    import dataclasses

    from gldt_core import track

    settings = config.tracker
    jptrack = settings.name == "jptrack"
    config_class: type[track.JPTrackConfig | track.ByteTrackConfig] = (
        track.JPTrackConfig if jptrack else track.ByteTrackConfig
    )
    params = settings.parameters()
    known = {f.name for f in dataclasses.fields(config_class)}
    unknown = sorted(set(params) - known)
    if unknown:
        raise ValueError(
            f"tracker.params: unknown {settings.name} parameter(s) {', '.join(unknown)} "
            f"(known: {', '.join(sorted(known))})"
        )
    if image_size is not None and "image_size" in known:
        params["image_size"] = (int(image_size[0]), int(image_size[1]))
    try:
        if jptrack:
            return track.JPTrack(track.JPTrackConfig(**params))
        return track.ByteTrack(track.ByteTrackConfig(**params))
    except TypeError as error:  # wrong value types inside the dataclass
        raise ValueError(f"tracker.params: {error}") from None


def build_detectors(config: SystemConfig) -> tuple[GlobalDetectorLike, LocalDetectorLike | None]:
    """The shipped (or configured) ONNX detectors; raises one-line errors for bad model files."""
    from pathlib import Path

    settings = config.detector
    models = [("global_model", settings.global_model), ("local_model", settings.local_model)]
    if settings.second_stage not in (None, "beside"):
        models.append(("second_stage", settings.second_stage))
    for key, path in models:
        if path is not None and not Path(path).is_file():
            raise FileNotFoundError(f"detector.{key}: model file not found: {path}")

    from gldt_core import detect

    # The detectors are asked about the tracked classes only (see decode_output's ``channels``).
    kwargs: dict[str, Any] = {
        "providers": tuple(settings.providers),
        "classes": settings.classes,
        "second_stage": settings.second_stage,
    }
    if settings.score_threshold is not None:
        kwargs["score_threshold"] = settings.score_threshold
    tile_detector = None
    if settings.tile_fusion:  # built once AM-YOLO has opened, so its errors come first
        from gldt_core.detect.fusion import build_tile_detector

        tile_detector = partial(build_tile_detector, settings.local_model, kwargs)
    global_detector = detect.GlobalDetector(
        model_path=settings.global_model, feature_reuse=settings.feature_reuse, tile_detector=tile_detector, **kwargs
    )
    local_detector = None
    if config.scheduler.local_enabled:
        tiles = global_detector.tile_detector
        if tiles is not None:  # the same model and second stage at the LD frames' threshold: opened once
            from gldt_core.detect.second_stage import default_score_threshold

            threshold = settings.score_threshold
            if threshold is None:
                threshold = default_score_threshold(settings.second_stage is not None)
            local_detector = tiles.at_score_threshold(threshold)
        else:
            local_detector = detect.LocalDetector(model_path=settings.local_model, **kwargs)
    return global_detector, local_detector


class GLDTSystem:
    """Global-local detection + tracking, one frame at a time.

    Detectors and tracker are injectable (tests, the ablation, other backends); by default the
    shipped ONNX detectors and the tracker named in the config are built.
    """

    def __init__(
        self,
        config: SystemConfig | None = None,
        *,
        global_detector: GlobalDetectorLike | None = None,
        local_detector: LocalDetectorLike | None = None,
        tracker: TrackerLike | None = None,
        timer: StageTimer | None = None,
    ) -> None:
        self.config = config or SystemConfig()
        if global_detector is None:
            built_global, built_local = build_detectors(self.config)
            global_detector = built_global
            local_detector = local_detector if local_detector is not None else built_local
        if self.config.scheduler.local_enabled and local_detector is None:
            raise ValueError("local detection is enabled (scheduler.local_enabled) but no local detector was given")
        self.global_detector = global_detector
        self.local_detector = local_detector
        self._local_takes_previous = local_detector is not None and accepts_keyword(
            local_detector.detect_rois, "previous_bgr"
        )
        # A tracker we build is rebuilt for each stream's frame size (its costs are normalised
        # by it); an injected one is the caller's and is only reset.
        self._owns_tracker = tracker is None
        self.tracker = tracker if tracker is not None else build_tracker(self.config)
        self._tracker_size: tuple[int, int] | None = None
        self._tracker_takes_rois = accepts_keyword(self.tracker.update, "rois")
        self.scheduler = ModeScheduler(self.config.scheduler)
        self.timer = timer or StageTimer()
        self._frame_index = 0
        self._global_frames = 0
        self._local_frames = 0
        self._reinitialisations = 0
        self._gaps = 0
        self._invalid_detections = 0
        self._size: tuple[int, int] | None = None
        self._previous: np.ndarray | None = None
        # What the previous frame left for this one when it was a GD frame: its letterboxed
        # network input and backbone features (GlobalDetector.detect_pair); None after LD frames
        # and resets.
        self._previous_carry: GlobalCarry | None = None
        self._last_t: float | None = None
        self._period: float | None = None
        self._last_plan: FramePlan | None = None
        self._tracks = np.zeros((0, 6))
        self._track_classes = np.zeros((0, 2))
        self._detections = np.zeros((0, 5))
        self._probabilities = np.zeros((0, PROBABILITY_COLUMNS))
        self.class_evidence = ClassEvidence()

    # ------------------------------------------------------------------ state
    @property
    def state(self) -> SystemState:
        sched = self.scheduler.state
        layout = self._last_plan.layout if self._last_plan is not None else EMPTY_LAYOUT
        return SystemState(
            frame_index=self._frame_index,
            mode=self._last_plan.mode if self._last_plan is not None else sched.mode,
            frames_in_mode=sched.frames_in_mode,
            frames_without_detection=sched.frames_without_detection,
            rois=layout.rois.copy(),
            roi_groups=layout.groups,
            tracks=self._tracks.copy(),
            detections=self._detections.copy(),
            class_probabilities=self._probabilities.copy(),
            global_frames=self._global_frames,
            local_frames=self._local_frames,
            reinitialisations=self._reinitialisations,
            dropped_frame_gaps=self._gaps,
            invalid_detections=self._invalid_detections,
            frame_size=self._size,
        )

    @property
    def last_plan(self) -> FramePlan | None:
        return self._last_plan

    def reset(self) -> None:
        """Forget the stream (tracks, frame pair, scheduler); counters of the run are kept."""
        self.tracker.reset()
        self.class_evidence.reset()
        self.scheduler.reset()
        self._previous = None
        self._previous_carry = None
        self._size = None
        self._last_t = None
        self._period = None
        self._last_plan = None

    def _reinitialise(self, why: str) -> None:
        LOG.warning("frame %d: %s; re-initialising tracker and scheduler", self._frame_index, why)
        self._reinitialisations += 1
        self.reset()

    # ------------------------------------------------------------------ frame
    def _check_input(self, frame: np.ndarray, t: float) -> tuple[np.ndarray, tuple[int, int]]:
        """The validated frame and its ``(width, height)``; re-initialises on a size or time jump."""
        from gldt_core.io.imaging import validate_bgr_frame

        frame = validate_bgr_frame(frame, what=f"frame {self._frame_index}")
        if not isinstance(t, (int, float, np.floating, np.integer)) or not math.isfinite(float(t)):
            raise ValueError(f"frame {self._frame_index}: timestamp must be a finite number of seconds, got {t!r}")
        size = (int(frame.shape[1]), int(frame.shape[0]))
        if self._size is not None and size != self._size:
            self._reinitialise(f"frame size changed from {self._size[0]}x{self._size[1]} to {size[0]}x{size[1]}")
        elif self._last_t is not None and float(t) <= self._last_t:
            self._reinitialise(f"time did not advance ({self._last_t:.3f} s -> {float(t):.3f} s)")
        elif self._last_t is not None:
            dt = float(t) - self._last_t
            if self._period is not None and dt > _GAP_FACTOR * self._period:
                self._gaps += 1
                LOG.info("frame %d: %.3f s gap (dropped frames?)", self._frame_index, dt)
            # Nominal period = the shortest step seen, so one long gap cannot redefine it.
            self._period = dt if self._period is None else min(self._period, dt)
        self._size = size
        return frame, size

    def _count_invalid(self, raw: np.ndarray, columns: int) -> np.ndarray:
        """Detector output as ``(N, columns)`` floats (class probabilities added where a detector
        reports none); counts the rows the steps will drop."""
        raw = with_class_probabilities(raw, columns)
        invalid = int((~valid_detection_mask(raw)).sum()) if len(raw) else 0
        if invalid:
            self._invalid_detections += invalid
            LOG.debug("frame %d: dropped %d invalid detection(s)", self._frame_index, invalid)
        return raw

    def _detect_global(
        self, previous: np.ndarray, frame: np.ndarray, carry: GlobalCarry | None
    ) -> tuple[np.ndarray, GlobalCarry | None]:
        """The global detector on ``(previous, frame)``, reusing what the previous GD frame left
        (``carry``: letterboxed input, backbone features) when the detector offers
        ``detect_pair`` (the shipped one does; test doubles need not); returns this frame's carry."""
        detect_pair = getattr(self.global_detector, "detect_pair", None)
        if detect_pair is None:
            return self.global_detector.detect(previous, frame), None
        return detect_pair(previous, frame, carry)

    def _detect_local(self, previous: np.ndarray, frame: np.ndarray, rois: np.ndarray) -> np.ndarray:
        """The local detector on this frame's ROIs, with the previous frame for its second stage
        where it takes one (the shipped one does; test doubles need not)."""
        assert self.local_detector is not None
        if self._local_takes_previous:
            return cast(Any, self.local_detector).detect_rois(frame, rois, previous_bgr=previous)
        return self.local_detector.detect_rois(frame, rois)

    def process(self, frame: np.ndarray, t: float) -> np.ndarray:
        """Run one frame (HxWx3 uint8 BGR, ``t`` seconds); returns ``(M, 6)`` ``[x1,y1,x2,y2,id,score]``."""
        timer = self.timer
        with timer.stage("preprocess"):
            frame, size = self._check_input(frame, t)
            t = float(t)
            previous = self._previous if self._previous is not None else frame
            if self._owns_tracker and self._tracker_size != size:
                self.tracker = build_tracker(self.config, size)
                self._tracker_size = size
            predictions = stable_predictions(self.tracker, t, self.config.lost_frames_kept)
            plan = self.scheduler.plan_frame(t, size, predictions)

        # The carry belongs to the previous frame; this frame's replaces it only once the frame
        # is complete, together with ``_previous`` (a frame that raises leaves neither).
        carry, self._previous_carry = self._previous_carry, None
        next_carry = None
        if plan.mode is Mode.GLOBAL:
            with timer.stage("gd"):
                raw, next_carry = self._detect_global(previous, frame, carry)
                raw = self._count_invalid(raw, GLOBAL_COLUMNS)
                raw = filter_classes(raw, GLOBAL_COLUMNS, self.config.detector.classes)
                raw = drop_nested(raw, self.config.detector.nested_threshold)
            detections = raw[:, :5]
            probabilities = raw[:, GLOBAL_COLUMNS - PROBABILITY_COLUMNS :]
            detection_rois = None
            self._global_frames += 1
        else:
            # The scheduler plans LD frames only when local detection is enabled, and then
            # __init__ made sure there is a local detector.
            assert self.local_detector is not None
            with timer.stage("ld"):
                raw = self._count_invalid(self._detect_local(previous, frame, plan.rois), LOCAL_COLUMNS)
                raw = merge_local_detections(raw, self.config.detector.classes, self.config.detector.nms_iou)
                raw = drop_nested(raw, self.config.detector.nested_threshold)
                try:
                    counts = detections_per_roi(raw, len(plan.layout))
                except ValueError as error:
                    raise ValueError(f"frame {self._frame_index}: {error}") from None
            detections = raw[:, :5]
            probabilities = raw[:, LOCAL_COLUMNS - PROBABILITY_COLUMNS :]
            detection_rois = plan.rois[raw[:, 6].astype(np.int64)].astype(np.float64)
            self._local_frames += 1

        with timer.stage("tracking"):
            if self._tracker_takes_rois:
                # accepts_keyword checked this tracker's update for ``rois``.
                output = cast(RoiTrackerLike, self.tracker).update(detections, t, rois=detection_rois)
            else:
                output = self.tracker.update(detections, t)
            tracks = np.asarray(output, dtype=np.float64).reshape(-1, 6)
            classes = self.class_evidence.update(tracks, detections, probabilities)
        if plan.mode is Mode.LOCAL:
            self.scheduler.report_detections(plan, counts)

        # Keep our own copy: callers (decoders, ROS buffers, overlay code) may reuse theirs.
        # The copy is the system's overhead, so it is booked to this frame's preprocess stage.
        copy_start = time.perf_counter()
        if self._previous is None or self._previous.shape != frame.shape:
            self._previous = frame.copy()
        else:
            np.copyto(self._previous, frame)
        timer.add("preprocess", time.perf_counter() - copy_start, count=False)
        self._previous_carry = next_carry
        self._last_t = t
        self._last_plan = plan
        self._tracks = tracks
        self._track_classes = classes
        self._detections = detections
        self._probabilities = probabilities
        self._frame_index += 1
        return tracks

    @property
    def track_classes(self) -> np.ndarray:
        """``(M, 2)`` ``[class_id, confidence]`` of the tracks the last :meth:`process` returned, in
        their order: the class evidence of each track's life (1 drone, 2 bird, 3 airplane, -1 none)."""
        return self._track_classes.copy()

    @property
    def global_share(self) -> float:
        """Fraction of processed frames that ran the global detector."""
        total = self._global_frames + self._local_frames
        return self._global_frames / total if total else 0.0

    def layout(self) -> RoiLayout:
        return self._last_plan.layout if self._last_plan is not None else EMPTY_LAYOUT
