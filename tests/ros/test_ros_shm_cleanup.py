"""gldt_ros.runtime.shm_cleanup: only segments whose owner is dead are removed (issue #9, no /dev/shm leak).

Fast DDS marks a live segment by holding ``flock`` on its ``_el`` file; these tests build such
files in a temporary folder and hold (or do not hold) the lock, as a live (or dead) owner would.
"""

from __future__ import annotations

import fcntl
import os
import time
from pathlib import Path

import pytest

pytest.importorskip("rclpy", reason="gldt_ros is installed with the ROS wheels that `make test` installs")

from gldt_ros.runtime.shm_cleanup import remove_dead_segments, segments_held_by  # noqa: E402


def make_segment(directory: Path, name: str, age_s: float = 60.0) -> Path:
    """A segment file and its lock file, both ``age_s`` old; returns the lock file."""
    (directory / name).write_bytes(b"\0" * 64)
    lock = directory / f"{name}_el"
    lock.touch()
    then = time.time() - age_s
    for path in (directory / name, lock):
        os.utime(path, (then, then))
    return lock


def test_a_segment_nobody_holds_is_removed_with_its_lock(tmp_path: Path) -> None:
    make_segment(tmp_path, "fastrtps_0123456789abcdef")
    assert remove_dead_segments(tmp_path) == ["fastrtps_0123456789abcdef"]
    assert list(tmp_path.iterdir()) == []


def test_a_held_segment_is_kept(tmp_path: Path) -> None:
    lock = make_segment(tmp_path, "fastrtps_00000000000000aa")
    with lock.open("rb") as owner:  # another open file description: flock conflicts as between processes
        fcntl.flock(owner, fcntl.LOCK_EX | fcntl.LOCK_NB)
        assert remove_dead_segments(tmp_path) == []
        assert segments_held_by(os.getpid(), tmp_path) == ["fastrtps_00000000000000aa"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fastrtps_00000000000000aa", "fastrtps_00000000000000aa_el"]
    assert segments_held_by(os.getpid(), tmp_path) == []
    assert remove_dead_segments(tmp_path) == ["fastrtps_00000000000000aa"]


def test_a_young_lock_file_is_left_to_its_starting_owner(tmp_path: Path) -> None:
    make_segment(tmp_path, "fastdds_00000000000000bb", age_s=0.0)
    assert remove_dead_segments(tmp_path, min_age_s=5.0) == []
    assert remove_dead_segments(tmp_path, min_age_s=0.0) == ["fastdds_00000000000000bb"]


def test_ports_and_other_files_are_not_touched(tmp_path: Path) -> None:
    keep = [
        "fastrtps_port7411",
        "sem.fastrtps_port7411_mutex",
        "fastrtps_not_a_segment_el",
        "other_0123456789abcdef_el",
    ]
    for name in keep:
        (tmp_path / name).write_bytes(b"")
        os.utime(tmp_path / name, (0, 0))
    assert remove_dead_segments(tmp_path) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(keep)


def test_a_missing_directory_is_not_an_error(tmp_path: Path) -> None:
    assert remove_dead_segments(tmp_path / "absent") == []
