"""GL-DT system configuration: dataclasses with Table I defaults, loadable from YAML.

A YAML file only needs the keys it changes; everything else keeps the paper's value. Unknown
keys and wrong types are refused with one line naming the file and the key, because a typo in a
threshold would otherwise silently run the defaults.

Example (every key shown with its default)::

    scheduler: {n_global: 30, n_local: 120, n_miss: 10, local_enabled: true}
    roi: {size: 300, tau_overlap: 0.2, tau_distance: 700, tau_safe: 0.8,
          reference_height: 1080}   # size and tau_distance are pixels of this many lines, scaled
                                    # to each frame's height; null = pixels of every frame
    detector:
      global_model: null      # path to an ONNX file; null = the shipped model
                              # (a relative path: beside this YAML, else from the working directory)
      local_model: null
      score_threshold: 0.1    # null = the detector's own default (0.5 calibrated; 0.25 without second stage)
      providers: [CPUExecutionProvider]
      classes: [1]            # MOT class codes to detect and track (1 drone, 2 bird, 3 airplane); null = all
      nms_iou: 0.5            # duplicate removal across overlapping ROIs
      nested_threshold: 0.8   # drop a box nested in a better one (share of the smaller inside); null = keep
      feature_reuse: null     # AM-YOLO's split pair (gldt export --feature-reuse):
                              # null = when present, false = never, true = required
      second_stage: beside    # crop classifier re-scoring both detectors' candidates:
                              # beside = second_stage.onnx next to the global model, a path, or null
      tile_fusion: true       # GD frames also run the local model over tiles of the frame and
                              # fuse its calibrated boxes with AM-YOLO's (gldt_core.detect.fusion);
                              # needs the second stage; frames letterboxed below 0.8 (1080p) skip it
    tracker:
      name: jptrack           # or bytetrack
      params: {}              # for the named tracker's config
      jptrack: {t_h: 0.55, new_track_thresh: 0.55}   # per-tracker parameters (see SHIPPED_DETECTOR_SCORES)
      bytetrack: {track_thresh: 0.55, new_track_thresh: 0.55}
    track_lost_frames: null   # keep an ROI on a lost track this many frames; null = n_miss
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gldt_core.schedule.roi import RoiParams
from gldt_core.schedule.scheduler import SchedulerConfig

TRACKER_NAMES = ("jptrack", "bytetrack")

#: Score thresholds matched to the shipped detectors. With the second stage, a detection's score
#: is the calibrated probability that it is a drone boxed at IoU 0.5
#: (:mod:`gldt_core.detect.second_stage`), so one number means the same everywhere: a detection
#: may start or extend a track at the first association stage when it is somewhat more likely a
#: drone than not (0.55), and the detectors report down to 0.1 for the trackers' second,
#: low-score stage. The value follows a rule on `gldt bench thresholds` (validation clips that
#: the ablation's first clips are not): the highest tracker threshold of the grid whose MOTA and
#: IDF1 stay within 0.5 of the grid's best *and whose next step up does too*, so that it keeps a
#: step's margin from the threshold where tracks stop being confirmed (docs/experiment-log.md).
#: Without the second stage (``detector.second_stage: null``) the raw detector scores are
#: under-confident and the former 0.25 fits them (``configs/run/no_second_stage.yaml``).
SHIPPED_DETECTOR_SCORES: dict[str, dict[str, float]] = {
    "jptrack": {"t_h": 0.55, "new_track_thresh": 0.55},
    "bytetrack": {"track_thresh": 0.55, "new_track_thresh": 0.55},
}

#: Lowest score the GL-DT system's detectors report: the trackers' low threshold (``t_l`` 0.1).
#: ByteTrack-style matching keeps a track alive through frames where its target scores between
#: the low and the high threshold; a detector that drops those boxes itself (its own default is
#: 0.5) leaves that second association stage empty.
SHIPPED_DETECTOR_SCORE_THRESHOLD = 0.1


@dataclass(frozen=True)
class DetectorSettings:
    """Which detector models to load and how to filter what they report.

    ``classes`` defaults to drones only (MOTChallenge code 1): birds and airplanes are the
    classic false positives the detectors are trained to name, not targets to track. The
    detectors are asked about these classes only: a box is a drone when its drone score passes,
    even where the model scores a bird higher at the same place (see
    :func:`gldt_core.detect.postprocess.decode_output`).
    """

    global_model: str | None = None
    local_model: str | None = None
    score_threshold: float | None = SHIPPED_DETECTOR_SCORE_THRESHOLD
    providers: tuple[str, ...] = ("CPUExecutionProvider",)
    classes: tuple[int, ...] | None = (1,)
    nms_iou: float = 0.5
    nested_threshold: float | None = 0.8
    feature_reuse: bool | None = None
    second_stage: str | None = "beside"
    tile_fusion: bool = True

    def __post_init__(self) -> None:
        if self.score_threshold is not None and not 0.0 <= self.score_threshold <= 1.0:
            raise ValueError(f"detector.score_threshold must be in [0, 1], got {self.score_threshold!r}")
        if not 0.0 < self.nms_iou <= 1.0:
            raise ValueError(f"detector.nms_iou must be in (0, 1], got {self.nms_iou!r}")
        if self.nested_threshold is not None and not 0.0 < self.nested_threshold <= 1.0:
            raise ValueError(f"detector.nested_threshold must be in (0, 1] or null, got {self.nested_threshold!r}")
        if not self.providers:
            raise ValueError("detector.providers must name at least one onnxruntime provider")
        if self.tile_fusion and self.second_stage is None:
            raise ValueError(
                "detector.tile_fusion needs the second stage (it averages calibrated scores): "
                "with second_stage: null set tile_fusion: false"
            )


@dataclass(frozen=True)
class TrackerSettings:
    """Which tracker to build (``jptrack`` or ``bytetrack``) and its keyword parameters.

    ``params`` go to the named tracker; ``jptrack`` / ``bytetrack`` hold per-tracker parameters
    that survive switching the tracker (the ablation runs both with one config), and ``params``
    wins where both name a key.
    """

    name: str = "jptrack"
    params: Mapping[str, Any] = field(default_factory=dict)
    jptrack: Mapping[str, Any] = field(default_factory=lambda: dict(SHIPPED_DETECTOR_SCORES["jptrack"]))
    bytetrack: Mapping[str, Any] = field(default_factory=lambda: dict(SHIPPED_DETECTOR_SCORES["bytetrack"]))

    def __post_init__(self) -> None:
        if self.name not in TRACKER_NAMES:
            raise ValueError(f"tracker.name must be one of {', '.join(TRACKER_NAMES)}, got {self.name!r}")

    def parameters(self) -> dict[str, Any]:
        """Keyword parameters for the named tracker's config."""
        return {**dict(getattr(self, self.name)), **dict(self.params)}


@dataclass(frozen=True)
class SystemConfig:
    """Everything :class:`~gldt_core.system.gldt_system.GLDTSystem` needs besides the models."""

    scheduler: SchedulerConfig = field(default_factory=SchedulerConfig)
    detector: DetectorSettings = field(default_factory=DetectorSettings)
    tracker: TrackerSettings = field(default_factory=TrackerSettings)
    track_lost_frames: int | None = None

    def __post_init__(self) -> None:
        if self.track_lost_frames is not None and (
            isinstance(self.track_lost_frames, bool)
            or not isinstance(self.track_lost_frames, int)
            or self.track_lost_frames < 0
        ):
            raise ValueError(f"track_lost_frames must be an integer >= 0, got {self.track_lost_frames!r}")

    @property
    def lost_frames_kept(self) -> int:
        """How long a lost track keeps its ROI (defaults to ``n_miss``, the LD give-up time)."""
        return self.scheduler.n_miss if self.track_lost_frames is None else self.track_lost_frames

    def with_changes(self, *, local_enabled: bool | None = None, tracker: str | None = None) -> SystemConfig:
        """Copy with the two switches the ablation flips (LD on/off, tracker name)."""
        scheduler = self.scheduler
        if local_enabled is not None:
            scheduler = dataclasses.replace(scheduler, local_enabled=local_enabled)
        tracker_settings = self.tracker
        if tracker is not None and tracker != self.tracker.name:
            tracker_settings = dataclasses.replace(self.tracker, name=tracker, params={})
        return dataclasses.replace(self, scheduler=scheduler, tracker=tracker_settings)


_SCHEDULER_KEYS = {"n_global": int, "n_local": int, "n_miss": int, "local_enabled": bool}
_ROI_KEYS = {"size": int, "tau_overlap": float, "tau_distance": float, "tau_safe": float, "reference_height": float}
_DETECTOR_KEYS = {
    "global_model": str,
    "local_model": str,
    "score_threshold": float,
    "providers": list,
    "classes": list,
    "nms_iou": float,
    "nested_threshold": float,
    "feature_reuse": bool,
    "second_stage": str,
    "tile_fusion": bool,
}
_TRACKER_KEYS = {"name": str, "params": dict, "jptrack": dict, "bytetrack": dict}
_TOP_KEYS = {"scheduler", "roi", "detector", "tracker", "track_lost_frames"}


def _checked(section: Mapping[str, Any] | None, allowed: Mapping[str, type], where: str) -> dict[str, Any]:
    """Validate one YAML section: known keys, right types (ints accepted for floats, null allowed)."""
    if section is None:
        return {}
    if not isinstance(section, Mapping):
        raise ValueError(f"{where}: expected a mapping, got {type(section).__name__}")
    out: dict[str, Any] = {}
    for key, value in section.items():
        if key not in allowed:
            raise ValueError(f"{where}.{key}: unknown key (known: {', '.join(sorted(allowed))})")
        want = allowed[key]
        if value is None:
            out[key] = None
            continue
        ok = isinstance(value, want) and not (want is int and isinstance(value, bool))
        if want is float and isinstance(value, (int, float)) and not isinstance(value, bool):
            value, ok = float(value), math.isfinite(float(value))
        if not ok:
            raise ValueError(f"{where}.{key}: expected {want.__name__}, got {value!r}")
        out[key] = value
    return out


def _checked_tracker_parameters(section: Mapping[str, Any], tracker: str, where: str) -> dict[str, Any]:
    """Validate parameter overrides for ``tracker`` against its config dataclass: known fields, and
    each value of its field's type (the type of the field's default; ints accepted for floats,
    YAML lists for tuples). Without this a wrong type fails deep inside the tracker
    ("'<=' not supported ...") instead of naming the key."""
    from gldt_core import track

    if tracker not in TRACKER_NAMES:
        return dict(section)  # TrackerSettings names the bad tracker
    config_class = track.JPTrackConfig if tracker == "jptrack" else track.ByteTrackConfig
    defaults = {f.name: getattr(config_class(), f.name) for f in dataclasses.fields(config_class)}
    out: dict[str, Any] = {}
    for key, value in section.items():
        if key not in defaults:
            raise ValueError(f"{where}.{key}: unknown {tracker} parameter (known: {', '.join(sorted(defaults))})")
        out[key] = _typed_like(value, defaults[key], f"{where}.{key}")
    try:
        config_class(**out)  # its own range checks, at load time rather than at the first frame
    except ValueError as error:
        raise ValueError(f"{where}: {error}") from None
    return out


def _typed_like(value: Any, default: Any, where: str) -> Any:
    """``value`` checked (and converted) to the type of ``default``; ValueError naming ``where``."""
    shown = "null" if value is None else repr(value)
    if isinstance(default, bool):
        if isinstance(value, bool):
            return value
        raise ValueError(f"{where}: expected bool (true/false), got {shown}")
    if isinstance(default, int):
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        raise ValueError(f"{where}: expected int, got {shown}")
    if isinstance(default, float):
        if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
            return float(value)
        raise ValueError(f"{where}: expected float, got {shown}")
    if isinstance(default, str):
        if isinstance(value, str):
            return value
        raise ValueError(f"{where}: expected str, got {shown}")
    if isinstance(default, tuple):
        kinds = "/".join(sorted({type(v).__name__ for v in default}))
        expected = f"a list of {len(default)} positive {kinds}s"
        if not isinstance(value, (list, tuple)) or len(value) != len(default):
            raise ValueError(f"{where}: expected {expected}, got {shown}")
        items = tuple(_typed_like(v, d, where) for v, d in zip(value, default))
        if any(v <= 0 for v in items):
            raise ValueError(f"{where}: expected {expected}, got {shown}")
        return items
    return value


def config_from_dict(data: Mapping[str, Any] | None, source: str = "config") -> SystemConfig:
    """Build a :class:`SystemConfig` from a parsed YAML mapping; errors name ``source`` and key."""
    data = data or {}
    if not isinstance(data, Mapping):
        raise ValueError(f"{source}: the top level must be a mapping, got {type(data).__name__}")
    for key in data:
        if key not in _TOP_KEYS:
            raise ValueError(f"{source}: {key}: unknown key (known: {', '.join(sorted(_TOP_KEYS))})")
    try:
        sched = _checked(data.get("scheduler"), _SCHEDULER_KEYS, f"{source}: scheduler")
        roi = _checked(data.get("roi"), _ROI_KEYS, f"{source}: roi")
        det = _checked(data.get("detector"), _DETECTOR_KEYS, f"{source}: detector")
        trk = _checked(data.get("tracker"), _TRACKER_KEYS, f"{source}: tracker")
        roi_params = RoiParams(
            **{
                ("roi_size" if k == "size" else k): v
                for k, v in roi.items()
                if v is not None or k == "reference_height"
            }
        )
        scheduler = SchedulerConfig(roi=roi_params, **{k: v for k, v in sched.items() if v is not None})
        if det.get("providers") is not None:
            det["providers"] = tuple(str(p) for p in det["providers"])
        if det.get("classes") is not None:
            det["classes"] = tuple(int(c) for c in det["classes"])
        # null is meaningful for these keys (shipped model / every class), so it is kept.
        keep_null = ("global_model", "local_model", "score_threshold", "classes", "second_stage", "nested_threshold")
        detector = DetectorSettings(**{k: v for k, v in det.items() if v is not None or k in keep_null})
        for section in ("jptrack", "bytetrack", "params"):
            if trk.get(section) is not None:
                name = section if section != "params" else trk.get("name") or TrackerSettings.name
                trk[section] = _checked_tracker_parameters(trk[section], name, f"{source}: tracker.{section}")
        tracker = TrackerSettings(**{k: v for k, v in trk.items() if v is not None})
        lost = data.get("track_lost_frames")
        return SystemConfig(scheduler=scheduler, detector=detector, tracker=tracker, track_lost_frames=lost)
    except ValueError as error:
        message = str(error)
        raise ValueError(message if message.startswith(source) else f"{source}: {message}") from None


def load_config(path: str | Path | None) -> SystemConfig:
    """Read a YAML config (``None``: all defaults). Raises FileNotFoundError / ValueError in one line."""
    if path is None:
        return SystemConfig()
    import yaml

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"config file not found: {path}")
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        where = f"{path}:{mark.line + 1}" if mark is not None else str(path)
        raise ValueError(f"{where}: not valid YAML ({getattr(error, 'problem', error)})") from None
    return with_models_found_beside(config_from_dict(data, source=str(path)), path.parent)


def with_models_found_beside(config: SystemConfig, folder: Path) -> SystemConfig:
    """``config`` with each relative model path that names a file under ``folder`` (the YAML's
    own folder) made to point there.

    Why: a config that ships next to its models (``gldt_core/configs/run/balanced_models.yaml``)
    must work from any working directory. A relative path with no such file keeps meaning a path
    from the working directory.
    """
    detector = config.detector
    global_model = _found_beside(detector.global_model, folder)
    local_model = _found_beside(detector.local_model, folder)
    second_stage = detector.second_stage
    if second_stage != "beside":
        second_stage = _found_beside(second_stage, folder)
    if (global_model, local_model, second_stage) == (
        detector.global_model,
        detector.local_model,
        detector.second_stage,
    ):
        return config
    return dataclasses.replace(
        config,
        detector=dataclasses.replace(
            detector, global_model=global_model, local_model=local_model, second_stage=second_stage
        ),
    )


def _found_beside(model: str | None, folder: Path) -> str | None:
    """``model`` resolved under ``folder`` when it is a relative path naming a file there, else as given."""
    if model is not None and not Path(model).is_absolute() and (folder / model).is_file():
        return str((folder / model).resolve())
    return model
