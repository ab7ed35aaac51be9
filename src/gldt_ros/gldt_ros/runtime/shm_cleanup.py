"""Remove the shared-memory segments that killed Fast DDS processes leave in ``/dev/shm``.

Every Fast DDS participant with the shared-memory transport creates a data segment
(``fastrtps_<16 hex>``, about 0.5 MB here, 8 MiB for the processes on
``fastdds_profile_frames.xml``) and a lock file beside it (``..._el``) that it holds
with ``flock`` for as long as it lives. A process that exits cleanly removes both; one killed by
SIGKILL (or the OOM killer) cannot, so every crash of a node leaks its segment until the machine
reboots. ``pipeline`` restarts dead nodes, so on a robot that runs for weeks the leak is the
supervisor's to mend: after a restart it removes every segment whose lock nobody holds, which is
what ``fastdds shm clean`` does by hand (that tool is not part of the PyPI install).

Not touched: the port files (``fastrtps_port<N>``), which this Fast DDS version shares between
processes without a lock file that would tell a dead port from a live one, and any segment whose
lock file is younger than :data:`MIN_AGE_S` (a starting process may have created the lock file
but not yet taken the lock on it).
"""

from __future__ import annotations

import fcntl
import os
import re
import time
from pathlib import Path

#: Where Fast DDS keeps its shared memory on Linux.
SHM_DIRECTORY = Path("/dev/shm")

#: Lock files of data segments (Fast DDS 2.x names them ``fastrtps_``, 3.x ``fastdds_``).
SEGMENT_LOCK = re.compile(r"^(fastrtps|fastdds)_[0-9a-f]{16}_el$")

#: Lock files younger than this are left alone (see the module docstring). Fast DDS takes the lock
#: right after creating the file, so a second is a wide margin; ``pipeline`` looks again this long
#: after a restart, and waits for that look at shutdown, so a node killed early in its life (its
#: lock file still young at the first look) does not leak its segment.
MIN_AGE_S = 2.0


def lock_is_held(lock_file: Path) -> bool:
    """Whether some process holds ``lock_file`` with ``flock`` (its segment's owner is alive)."""
    try:
        with lock_file.open("rb") as handle:
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                return True
            fcntl.flock(handle, fcntl.LOCK_UN)
            return False
    except OSError:
        return True  # removed meanwhile by its owner, or not ours to open: leave it


def segment_lock_files(directory: Path) -> list[Path]:
    """The data segments' lock files in ``directory``, sorted (none if it cannot be read)."""
    try:
        names = sorted(os.listdir(directory))
    except OSError:
        return []
    return [directory / name for name in names if SEGMENT_LOCK.match(name)]


def remove_dead_segments(directory: Path = SHM_DIRECTORY, min_age_s: float = MIN_AGE_S) -> list[str]:
    """Remove the data segments (and their lock files) that no living process holds; return the
    segment names removed. Never raises: a file that vanishes or cannot be removed is skipped."""
    now = time.time()
    removed: list[str] = []
    for lock_file in segment_lock_files(directory):
        try:
            if now - lock_file.stat().st_mtime < min_age_s:
                continue
        except OSError:
            continue
        if lock_is_held(lock_file):
            continue
        segment = lock_file.name[: -len("_el")]
        for path in (directory / segment, lock_file):
            try:
                path.unlink()
            except FileNotFoundError:
                pass
            except OSError:
                break
        else:
            removed.append(segment)
    return removed


def segments_held_by(pid: int, directory: Path = SHM_DIRECTORY) -> list[str]:
    """The data segments whose lock process ``pid`` holds (from ``/proc/locks``), so a test or a
    benchmark can check that what a killed node leaves behind is gone afterwards."""
    inodes: set[int] = set()
    try:
        lines = Path("/proc/locks").read_text().splitlines()
    except OSError:
        return []
    for line in lines:
        fields = line.split()
        # "1: FLOCK  ADVISORY  WRITE 1234 00:1a:5678 0 EOF"
        if len(fields) >= 6 and fields[1] == "FLOCK" and fields[4] == str(pid):
            inodes.add(int(fields[5].rsplit(":", 1)[1]))
    if not inodes:
        return []
    held: list[str] = []
    for lock_file in segment_lock_files(directory):
        try:
            if lock_file.stat().st_ino in inodes:
                held.append(lock_file.name[: -len("_el")])
        except OSError:
            continue
    return held
