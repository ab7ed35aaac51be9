"""The GL-DT pipeline: GD/LD mode scheduler, adaptive ROIs, and the composed per-frame runner.

The ROI manager (:mod:`.roi`) and the scheduler (:mod:`.scheduler`) hold no models and no
images, so the ROS nodes reuse them unchanged; :class:`GLDTPipeline` (:mod:`.pipeline`) composes
them with detectors and a tracker in one process; :mod:`.runner` drives it over a recording.
"""

from gldt_core.pipeline.config import DetectorSettings, PipelineConfig, TrackerSettings, config_from_dict, load_config
from gldt_core.pipeline.pipeline import GLDTPipeline, PipelineState
from gldt_core.pipeline.roi import RoiLayout, RoiParams, plan_rois
from gldt_core.pipeline.scheduler import FramePlan, Mode, ModeScheduler, SchedulerConfig, SchedulerState
from gldt_core.pipeline.timing import StageTimer

__all__ = [
    "DetectorSettings",
    "FramePlan",
    "GLDTPipeline",
    "Mode",
    "ModeScheduler",
    "PipelineConfig",
    "PipelineState",
    "RoiLayout",
    "RoiParams",
    "SchedulerConfig",
    "SchedulerState",
    "StageTimer",
    "TrackerSettings",
    "config_from_dict",
    "load_config",
    "plan_rois",
]
