"""The offline GL-DT system: detectors, mode scheduler and tracker composed in one process.

:class:`GLDTSystem` (:mod:`.gldt_system`) runs one frame at a time; :mod:`.runner` drives it over
a frame source; :mod:`.steps` holds the per-frame steps the ROS nodes share with it, so the node
graph and the offline system give the same tracks; :mod:`.config` loads the YAML that configures
both.
"""

from gldt_core.system.config import DetectorSettings, SystemConfig, TrackerSettings, config_from_dict, load_config
from gldt_core.system.gldt_system import GLDTSystem, SystemState
from gldt_core.system.timing import StageTimer

__all__ = [
    "DetectorSettings",
    "GLDTSystem",
    "StageTimer",
    "SystemConfig",
    "SystemState",
    "TrackerSettings",
    "config_from_dict",
    "load_config",
]
