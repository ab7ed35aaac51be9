"""Where to look next: the GD/LD mode scheduler and the ROI manager.

Neither holds a model or an image: the scheduler (:mod:`.scheduler`) is a state machine over
per-frame detection counts, the ROI manager (:mod:`.roi`) a set of pure functions of the
tracker's predictions. The offline system and the ROS ``mode_scheduler`` node use them unchanged.
"""

from gldt_core.schedule.roi import RoiLayout, RoiParams, plan_rois
from gldt_core.schedule.scheduler import FramePlan, Mode, ModeScheduler, SchedulerConfig, SchedulerState

__all__ = [
    "FramePlan",
    "Mode",
    "ModeScheduler",
    "RoiLayout",
    "RoiParams",
    "SchedulerConfig",
    "SchedulerState",
    "plan_rois",
]
