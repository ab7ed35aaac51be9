"""The Fast DDS profiles of the graph.

``config/fastdds_profile.xml`` (the file says what each setting is for) is what ``pipeline``
points Fast DDS at, through :data:`DDS_PROFILE_VARIABLE`, unless the user exported a profile of
their own. The processes that publish frames (frame_pair_buffer, and the ``pipeline`` process
itself, which plays the camera) switch to its twin ``config/fastdds_profile_frames.xml``, whose
larger shared-memory segment carries a frame pair in one piece instead of 512 KiB fragments; the
segment is allocated whole, so the other nodes keep the small one. A process that hosts several
nodes (:mod:`gldt_ros.runtime.node_group`) switches to ``config/fastdds_profile_group.xml``, the
frames twin whose participant does not match its own endpoints: its nodes pass messages to each
other in-process (:mod:`gldt_ros.runtime.local_delivery`).

A restarted node keeps Fast DDS's choice of participant id, which after a crash is the dead
process's, so it opens the dead process's shared-memory ports (the profile's 100 ms health check
bounds what that costs). Giving it a fresh id instead was tried, more than once: each time a
restarted node sometimes went deaf to one of its inputs for good and the lockstep replay stalled
(``docs/experiment-log.md`` has the runs).
"""

from __future__ import annotations

import os
from pathlib import Path

from gldt_ros.interface.graph import shipped_config

#: Environment variable through which Fast DDS (rmw_fastrtps_cpp) loads default participant settings.
DDS_PROFILE_VARIABLE = "FASTRTPS_DEFAULT_PROFILES_FILE"


def shipped_profile() -> Path:
    """``share/gldt_ros/config/fastdds_profile.xml`` of the installed package (or the source tree)."""
    return shipped_config("fastdds_profile.xml")


def shipped_frames_profile() -> Path:
    """``share/gldt_ros/config/fastdds_profile_frames.xml``: the shipped profile with an 8 MiB
    shared-memory segment, for processes that publish frames."""
    return shipped_config("fastdds_profile_frames.xml")


def shipped_group_profile() -> Path:
    """``share/gldt_ros/config/fastdds_profile_group.xml``: the frames twin whose participant
    ignores its own endpoints, for a process whose nodes pass messages in-process."""
    return shipped_config("fastdds_profile_group.xml")


def use_group_profile_if_shipped() -> bool:
    """In a process that hosts several nodes, swap the shipped profile (or its frames twin) for
    the group profile; a profile the user exported, or none, is left alone. Returns whether the
    group profile is in use, i.e. whether DDS leaves the process's own links to it. Must run
    before ``rclpy.init``."""
    current = os.environ.get(DDS_PROFILE_VARIABLE, "")
    if current and Path(current) in (shipped_profile(), shipped_frames_profile()):
        current = os.environ[DDS_PROFILE_VARIABLE] = str(shipped_group_profile())
    return bool(current) and Path(current) == shipped_group_profile()


def use_frames_profile_if_shipped() -> str:
    """In a process that publishes frames, swap the shipped profile for its large-segment twin;
    a profile the user exported, or none at all (a node started by hand), is left alone.
    Returns the profile in use ("" for none). Must run before ``rclpy.init``."""
    current = os.environ.get(DDS_PROFILE_VARIABLE, "")
    if current and Path(current) == shipped_profile():
        current = os.environ[DDS_PROFILE_VARIABLE] = str(shipped_frames_profile())
    return current


def profile_for_children(environment: dict[str, str]) -> dict[str, str]:
    """``environment`` with the frames or group twin swapped back for the shipped profile: a process
    that switched to one (:func:`use_frames_profile_if_shipped`) passes the small-segment profile on to
    the nodes it starts, which switch again only if they publish frames themselves."""
    current = environment.get(DDS_PROFILE_VARIABLE, "")
    if current and Path(current) in (shipped_frames_profile(), shipped_group_profile()):
        environment = dict(environment, **{DDS_PROFILE_VARIABLE: str(shipped_profile())})
    return environment


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
