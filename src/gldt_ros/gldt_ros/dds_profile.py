"""The Fast DDS profile of the graph.

``config/fastdds_profile.xml`` (the file says what each setting buys and what was measured) is
what ``pipeline`` points Fast DDS at, through :data:`DDS_PROFILE_VARIABLE`, unless the user
exported a profile of their own.

A restarted node keeps Fast DDS's choice of participant id, which after a crash is the dead
process's, so it opens the dead process's shared-memory ports (the profile's 100 ms health check
bounds what that costs). Giving it a fresh id instead was tried three times, and each time a
restarted node sometimes went deaf to one of its inputs and the lockstep replay stalled. The
last try, with the 100 ms check, restarted in 0.53-0.77 s (median per node, worst 0.93 s), and
passed 35 kill runs in a row, but a fresh-clone CI run then stalled: the restarted local
detector took 10 ROI batches and then no more.
"""

from __future__ import annotations

import os
from pathlib import Path

#: Environment variable through which Fast DDS (rmw_fastrtps_cpp) loads default participant settings.
DDS_PROFILE_VARIABLE = "FASTRTPS_DEFAULT_PROFILES_FILE"


def shipped_profile() -> Path:
    """``share/gldt_ros/config/fastdds_profile.xml`` of the installed package (or the source tree)."""
    from gldt_ros.pipeline import default_params_file

    return default_params_file().with_name("fastdds_profile.xml")


def use_graph_dds_profile() -> str:
    """Point Fast DDS at the shipped profile for this process and the nodes it starts, unless the
    user exported a profile of their own; returns the profile in use.

    The profile announces participants every 250 ms instead of every 3 s, has writers send
    heartbeats every 100 ms instead of every 3 s, and health-checks leftover shared-memory ports
    after 100 ms instead of 1 s: a restarted node is matched, and gets what it missed, within its
    own start-up time. Other RMW implementations ignore the variable. Must run before
    ``rclpy.init``.
    """
    return os.environ.setdefault(DDS_PROFILE_VARIABLE, str(shipped_profile()))
