"""The Fast DDS profile of the graph, and the copies a restarted node starts with.

``config/fastdds_profile.xml`` (the file says what each setting buys and what was measured) is
what ``pipeline`` points Fast DDS at, through :data:`DDS_PROFILE_VARIABLE`, unless the user
exported a profile of their own.

A restarted node gets a copy of it with a participant id of its own. Fast DDS otherwise gives a
new process the lowest free participant id, which after a crash is the dead process's. Its
shared-memory port is named after that id, so the new process inherits the dead one's port, and
the other processes keep writing into their old mapping of it until their watchdog (which runs
once a second) finds its listener frozen. Measured with ``gldt_ros.bench_restart --repeats 5`` on
the 2-core dev machine, both with the profile's 100 ms health check: from the relink to the
first ``/gldt/tracks`` took 0.15-0.65 s (median per node) with the dead process's id and
0.13-0.17 s with a fresh one; the worst restart to tracks took 2.10 s and 0.93 s. A fresh id used
to leave a restarted node deaf to some peers in 2-3 of 10 runs while the health check took 1 s;
with the 100 ms check none of 35 kill runs (7 per node) hung, and every one answered 0.13-0.22 s
after the relink.
"""

from __future__ import annotations

import itertools
import os
import shutil
import tempfile
from pathlib import Path

#: Environment variable through which Fast DDS (rmw_fastrtps_cpp) loads default participant settings.
DDS_PROFILE_VARIABLE = "FASTRTPS_DEFAULT_PROFILES_FILE"

#: Participant ids handed to restarted nodes, in turn. Fast DDS numbers a domain's participants
#: from 0 up (at most 120 per domain and host), so the upper half stays clear of the ids a graph
#: and its tools take at start; if an id is taken anyway, Fast DDS moves on to the next free one.
RESTART_PARTICIPANT_IDS = range(60, 120)

_RTPS_OPENING = "<rtps>"


def shipped_profile() -> Path:
    """``share/gldt_ros/config/fastdds_profile.xml`` of the installed package (or the source tree)."""
    from gldt_ros.pipeline import default_params_file

    return default_params_file().with_name("fastdds_profile.xml")


def use_graph_dds_profile() -> str:
    """Point Fast DDS at the shipped profile for this process and the nodes it starts, unless the
    user exported a profile of their own; returns the profile in use. Other RMW implementations
    ignore the variable. Must run before ``rclpy.init``."""
    return os.environ.setdefault(DDS_PROFILE_VARIABLE, str(shipped_profile()))


def with_participant_id(profile_xml: str, participant_id: int) -> str:
    """``profile_xml`` with ``participant_id`` set in its participant profile (the first
    ``<rtps>`` element); raises ``ValueError`` if the text has none."""
    if not 0 <= participant_id < 120:
        raise ValueError(f"participant id {participant_id} is outside Fast DDS's range 0..119")
    if _RTPS_OPENING not in profile_xml:
        raise ValueError(f"the profile has no {_RTPS_OPENING} element to set a participant id in")
    return profile_xml.replace(_RTPS_OPENING, f"{_RTPS_OPENING}\n      <participantID>{participant_id}</participantID>", 1)


class RestartProfiles:
    """Writes, for each restart, a copy of the shipped profile with the next id of
    :data:`RESTART_PARTICIPANT_IDS`, into a temporary folder removed by :meth:`close`.

    Only while the shipped profile is the one in use: a profile the user exported is theirs, and
    restarted nodes then start with it unchanged (Fast DDS picks their ids).
    """

    def __init__(self) -> None:
        self._ids = itertools.cycle(RESTART_PARTICIPANT_IDS)
        self._folder: Path | None = None

    def environment_for_restart(self) -> dict[str, str]:
        """The environment entries a restarted node starts with (none under a user's profile)."""
        shipped = shipped_profile()
        if os.environ.get(DDS_PROFILE_VARIABLE) != str(shipped):
            return {}
        participant_id = next(self._ids)
        try:
            if self._folder is None:
                self._folder = Path(tempfile.mkdtemp(prefix="gldt_dds_"))
            copy = self._folder / f"fastdds_profile_participant_{participant_id}.xml"
            copy.write_text(with_participant_id(shipped.read_text(), participant_id))
        except (OSError, ValueError) as error:
            # A restart must not fail for want of a faster one: fall back to the shipped profile.
            print(f"pipeline: no profile copy for the restart ({error}); Fast DDS picks the id", flush=True)
            return {}
        return {DDS_PROFILE_VARIABLE: str(copy)}

    def close(self) -> None:
        if self._folder is not None:
            shutil.rmtree(self._folder, ignore_errors=True)
            self._folder = None
