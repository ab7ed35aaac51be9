"""GD/LD mode scheduler: a small state machine that never touches an image or a model.

Paper (Methods): run the global detector (GD, frame pair ``F_t, F_t-1``) for ``N_g`` frames;
once tracks are stable switch to the local detector (LD) on ROIs built around the
Kalman-predicted targets; go back to GD after ``N_l`` LD frames, and at once when no ROI has had
a detection for ``N_m`` consecutive frames.

The scheduler only sees three kinds of event, so the ROS graph can run it in its own node with
detectors and tracker elsewhere:

* :meth:`ModeScheduler.plan_frame` - "frame t arrived" together with the tracker's predictions
  for ``t``; returns the :class:`FramePlan` (mode, ROIs) for that frame.
* :meth:`ModeScheduler.report_detections` - "detections for frame t", as a count per ROI.
* :meth:`ModeScheduler.reset` - the stream restarted (size change, time going backwards).

Reading of the paper's counters (documented decisions):

* ``N_l`` is the longest run of consecutive LD frames (the issue's "go back to GD after N_l
  frames"), so a steady cycle is ``N_g`` GD frames + ``N_l`` LD frames (30 + 120: 20 % GD).
* "Tracks are stable" = at least one confirmed track has a prediction for this frame. If none
  exists after ``N_g`` GD frames, GD simply continues until one does: LD has nothing to look at.
* ``N_m`` is not in Table I; we default to 10 frames (1/3 s at 30 fps): long enough to ride out
  one or two missed detections of a small target, short enough that a lost target costs well
  under a second before the global search resumes.
* An LD frame whose report never arrives (a dropped message in ROS) does not count as a miss.
* A prediction with a NaN or infinite coordinate or id is dropped with a warning before the
  mode is decided: one diverged track must not stop LD for the others, nor switch to LD alone.
"""

from __future__ import annotations

import enum
import logging
from dataclasses import dataclass, field

import numpy as np

from gldt_core.schedule.roi import EMPTY_LAYOUT, RoiLayout, RoiParams, plan_rois

LOG = logging.getLogger("gldt.scheduler")

#: Table I.
DEFAULT_N_GLOBAL = 30
DEFAULT_N_LOCAL = 120
#: Not in Table I; see module docstring.
DEFAULT_N_MISS = 10


# Not a StrEnum: that would change str() and f-strings of a mode from "Mode.GLOBAL" to "GD".
class Mode(str, enum.Enum):  # noqa: UP042
    """Which detector runs on a frame."""

    GLOBAL = "GD"
    LOCAL = "LD"


@dataclass(frozen=True)
class SchedulerConfig:
    """Mode-switch counters and ROI geometry (paper Table I, plus our ``n_miss``)."""

    n_global: int = DEFAULT_N_GLOBAL
    n_local: int = DEFAULT_N_LOCAL
    n_miss: int = DEFAULT_N_MISS
    local_enabled: bool = True
    roi: RoiParams = field(default_factory=RoiParams)

    def __post_init__(self) -> None:
        for name in ("n_global", "n_local", "n_miss"):
            value = getattr(self, name)
            if not (isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value >= 1):
                raise ValueError(f"scheduler.{name} must be an integer >= 1, got {value!r}")


@dataclass(frozen=True)
class FramePlan:
    """What to run on one frame: the mode and, in LD, the windows (``(R, 4)`` int xyxy)."""

    frame_index: int
    stamp: float
    mode: Mode
    layout: RoiLayout
    reason: str

    @property
    def rois(self) -> np.ndarray:
        return self.layout.rois


@dataclass(frozen=True)
class SchedulerState:
    """Snapshot for logs, the overlay and tests."""

    mode: Mode
    frames_in_mode: int
    frames_without_detection: int
    rois: np.ndarray
    roi_groups: tuple[tuple[int, ...], ...]
    frames_seen: int
    global_frames: int
    last_reason: str


class ModeScheduler:
    """Decides GD or LD (and the ROIs) for each frame from counters and track predictions."""

    def __init__(self, config: SchedulerConfig | None = None) -> None:
        self.config = config or SchedulerConfig()
        self.reset()

    def reset(self) -> None:
        """Back to the start state: GD, all counters zero, no ROIs."""
        self._mode = Mode.GLOBAL
        self._frames_in_mode = 0  # frames already planned in the current mode
        self._misses = 0  # consecutive reported LD frames with no detection in any ROI
        self._layout = EMPTY_LAYOUT
        self._frames_seen = 0
        self._global_frames = 0
        self._last_reason = "start"

    @property
    def mode(self) -> Mode:
        return self._mode

    @property
    def state(self) -> SchedulerState:
        return SchedulerState(
            mode=self._mode,
            frames_in_mode=self._frames_in_mode,
            frames_without_detection=self._misses,
            rois=self._layout.rois.copy(),
            roi_groups=self._layout.groups,
            frames_seen=self._frames_seen,
            global_frames=self._global_frames,
            last_reason=self._last_reason,
        )

    def _switch(self, mode: Mode, reason: str) -> None:
        self._mode = mode
        self._frames_in_mode = 0
        self._misses = 0
        self._last_reason = reason
        if mode is Mode.GLOBAL:
            self._layout = EMPTY_LAYOUT

    def plan_frame(
        self,
        stamp: float,
        frame_size: tuple[int, int],
        predictions: np.ndarray,
    ) -> FramePlan:
        """Decide the mode for the frame at ``stamp`` and, in LD, its ROIs.

        ``predictions``: ``(K, 5)`` ``[x1, y1, x2, y2, track_id]`` Kalman-predicted boxes at
        ``stamp`` of the *stable* (confirmed) tracks only; ``frame_size``: ``(width, height)``.
        """
        stamp = float(stamp)  # converted first: nothing below may fail after the state changed
        predictions = np.asarray(predictions, dtype=np.float64).reshape(-1, 5)
        finite = np.isfinite(predictions).all(axis=1)
        if not finite.all():
            LOG.warning(
                "frame %d: dropped %d prediction(s) with NaN or infinite values (track ids %s)",
                self._frames_seen,
                int((~finite).sum()),
                predictions[~finite, 4].tolist(),
            )
            predictions = predictions[finite]
        cfg = self.config
        mode, reason = self._mode, None
        if mode is Mode.GLOBAL:
            if cfg.local_enabled and self._frames_in_mode >= cfg.n_global and len(predictions):
                mode, reason = Mode.LOCAL, f"{len(predictions)} stable track(s) after {cfg.n_global} GD frames"
        elif self._frames_in_mode >= cfg.n_local:
            mode, reason = Mode.GLOBAL, f"LD ran {cfg.n_local} frames"
        elif self._misses >= cfg.n_miss:
            mode, reason = Mode.GLOBAL, f"no detection in any ROI for {cfg.n_miss} frames"
        elif len(predictions) == 0:
            mode, reason = Mode.GLOBAL, "no stable track left to look at"

        layout = EMPTY_LAYOUT
        if mode is Mode.LOCAL:
            # Planned before any state changes, so a plan_rois error leaves the scheduler as it was.
            layout = plan_rois(
                predictions[:, :4],
                predictions[:, 4].astype(np.int64),
                frame_size,
                cfg.roi.at_resolution(int(frame_size[1])),
                previous_groups=self._layout.groups if reason is None else (),
            )
        if reason is not None:
            self._switch(mode, reason)
        if mode is Mode.LOCAL:
            self._layout = layout
        else:
            self._global_frames += 1
        plan = FramePlan(
            frame_index=self._frames_seen,
            stamp=stamp,
            mode=self._mode,
            layout=self._layout,
            reason=self._last_reason,
        )
        self._frames_in_mode += 1
        self._frames_seen += 1
        return plan

    def report_detections(self, plan: FramePlan, detections_per_roi: np.ndarray | list[int]) -> None:
        """Feed back how many detections each ROI of ``plan`` produced (ignored for GD frames).

        Reports for a frame other than the latest planned one are ignored: in ROS they can
        arrive late, and a stale report must not reset the miss counter of a newer frame.
        """
        if plan.mode is not Mode.LOCAL or self._mode is not Mode.LOCAL:
            return
        if plan.frame_index != self._frames_seen - 1:
            return
        counts = np.asarray(detections_per_roi, dtype=np.int64).reshape(-1)
        if counts.size != len(plan.layout):
            raise ValueError(
                f"report_detections: plan for frame {plan.frame_index} has {len(plan.layout)} ROIs "
                f"but {counts.size} counts were reported"
            )
        self._misses = 0 if int(counts.sum()) > 0 else self._misses + 1
