"""``pipeline`` itself under faults (issue 31): killed with SIGKILL, two replays on one host,
damaged bags. Each test runs the installed command as a user would."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import pytest

from support import REAL_BAG, PipelineRun, isolated_ros_env

pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

from gldt_ros.interface.graph import DEFAULT_PROCESS_LAYOUT, PROCESS_LAYOUTS  # noqa: E402


def wait_for_a_recorded_track(run: PipelineRun, record: Path, timeout_s: float = 120.0) -> None:
    """Until ``record`` holds a readable ``/gldt/tracks`` message (the replay is under way)."""
    deadline = time.monotonic() + timeout_s
    while not recorded_frames(record):
        assert run.process.poll() is None, "pipeline ended before recording anything:\n" + run.text
        assert time.monotonic() < deadline, f"no track recorded after {timeout_s:g} s:\n" + run.text
        time.sleep(0.05)


#: The node processes of ``pipeline``'s default layout (some hold several nodes).
NODE_PROCESSES = len(PROCESS_LAYOUTS[DEFAULT_PROCESS_LAYOUT])


def node_pids(run: PipelineRun) -> set[int]:
    """Pids of the node processes ``pipeline`` said it started ("started NAME (pid N...)")."""
    return {int(line.rsplit("(pid ", 1)[1].split(")")[0].split(",")[0]) for line in run.lines if "(pid " in line}


def recorded_frames(path: Path) -> list[int]:
    """``frame_index`` of every ``/gldt/tracks`` message readable in ``path``, in recording order
    (a recording cut by a kill ends in damage: what was read before it counts)."""
    from gldt_core.io.recording import iter_recorded

    frames: list[int] = []
    if not path.is_file():
        return frames
    try:
        for _, message, _ in iter_recorded(path, "gldt/tracks"):
            frames.append(int(message.frame_index))
    except ValueError:
        pass
    return frames


def last_track_log_time_ns(path: Path) -> int:
    from gldt_core.io.recording import iter_recorded

    last = -1
    try:
        for _, _, log_time_ns in iter_recorded(path, "gldt/tracks"):
            last = log_time_ns
    except ValueError:
        pass
    return last


def child_pids(pid: int) -> set[int]:
    """Direct children of ``pid`` (every thread's), from /proc."""
    children: set[int] = set()
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            children.update(int(c) for c in (task / "children").read_text().split())
        except OSError:
            continue
    return children


def alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie waiting for its reaper does not)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def test_sigkill_of_pipeline_keeps_the_recording_and_ends_its_nodes(tmp_path: Path) -> None:
    """``kill -9`` of the pipeline alone: every node process (and the warm spare) ends within a
    few seconds, and the recording reads back with the frames answered up to the last second."""
    record = tmp_path / "graph.mcap"
    run = PipelineRun(
        ["--bag", str(REAL_BAG), "--lockstep", "--record", str(record), "--spare-delay", "0"], isolated_ros_env()
    )
    try:
        wait_for_a_recorded_track(run, record)
        readable_before = len(recorded_frames(record))
        time.sleep(0.5)  # the kill lands between two of the writer's flushes, mid-replay
        started = node_pids(run)
        pids = child_pids(run.process.pid) | started
        assert run.process.poll() is None and not any(line.startswith("pipeline: sent ") for line in run.lines), (
            "the replay ended before the kill; it must land mid-replay:\n" + run.text
        )
        killed_ns = time.time_ns()
        os.kill(run.process.pid, signal.SIGKILL)
    finally:
        if run.process.poll() is None and "killed_ns" not in locals():
            run.process.kill()
        run.wait(30.0)
    assert len(started) == NODE_PROCESSES and len(pids) >= NODE_PROCESSES + 1, (
        f"expected {NODE_PROCESSES} node processes and the spare, got {pids}:\n{run.text}"
    )
    deadline = time.monotonic() + 8.0
    while any(alive(pid) for pid in pids) and time.monotonic() < deadline:
        time.sleep(0.1)
    left = sorted(pid for pid in pids if alive(pid))
    for pid in left:  # do not leave them to disturb other tests
        os.kill(pid, signal.SIGKILL)
    assert not left, f"node processes {left} outlived the killed pipeline:\n{run.text}"
    frames = recorded_frames(record)
    assert len(frames) >= readable_before and frames == sorted(set(frames)), frames
    assert frames == list(range(frames[0], frames[0] + len(frames))), f"frames lost inside the recording: {frames}"
    behind_s = (killed_ns - last_track_log_time_ns(record)) / 1e9
    assert behind_s <= 1.5, f"the recording ends {behind_s:.2f} s before the kill (the writer flushes every second)"


def test_ctrl_c_of_pipeline_stops_cleanly_and_keeps_the_recording(tmp_path: Path) -> None:
    """SIGINT to the pipeline pid alone, mid-replay at the camera's pace (the player publishing
    ``/clock`` between frames): one line, no traceback, exit 0, every node stopped, and the
    recording closed with what was answered."""
    record = tmp_path / "graph.mcap"
    run = PipelineRun(["--bag", str(REAL_BAG), "--rate", "1.0", "--record", str(record)], isolated_ros_env())
    try:
        wait_for_a_recorded_track(run, record)
        started = node_pids(run)
        assert run.process.poll() is None and not any(line.startswith("pipeline: sent ") for line in run.lines), (
            "the replay ended before the interrupt; it must land mid-replay:\n" + run.text
        )
        time.sleep(1.0)  # well into the paced replay (150 frames at 30 Hz take 5 s)
        os.kill(run.process.pid, signal.SIGINT)
        code = run.wait(60.0)
    finally:
        if run.process.poll() is None:
            run.process.kill()
    assert code == 0, run.text
    assert "Traceback" not in run.text and "FATAL" not in run.text, run.text
    assert any("interrupted, stopping" in line for line in run.lines), run.text
    assert len(started) == NODE_PROCESSES and not [pid for pid in started if alive(pid)], run.text
    frames = recorded_frames(record)
    assert frames and frames == sorted(set(frames)), frames


def test_two_replays_at_once_each_record_only_their_own_frames(tmp_path: Path) -> None:
    """Without ROS_DOMAIN_ID each ``--bag`` run takes a free domain of its own and says so; two
    lockstep replays of one bag, started a second apart, each record the bag's frames once."""
    from gldt_core.io.bag import BagSource

    frames = len(BagSource(REAL_BAG))
    env = isolated_ros_env()
    del env["ROS_DOMAIN_ID"]
    runs = []
    for k in range(2):
        runs.append(
            PipelineRun(["--bag", str(REAL_BAG), "--lockstep", "--record", str(tmp_path / f"run{k}.mcap")], env)
        )
        time.sleep(1.0)
    try:
        codes = [run.wait(300.0) for run in runs]
    finally:
        for run in runs:
            if run.process.poll() is None:
                run.process.kill()
    domains = []
    for run, code in zip(runs, codes):
        assert code == 0, run.text
        isolated = [line for line in run.lines if line.startswith("pipeline: isolated on ROS_DOMAIN_ID ")]
        assert len(isolated) == 1, run.text
        domains.append(int(isolated[0].split("ROS_DOMAIN_ID ")[1].split(",")[0]))
        assert "not awaited" not in run.text, run.text
    assert domains[0] != domains[1]
    for k in range(2):
        recorded = recorded_frames(tmp_path / f"run{k}.mcap")
        assert recorded == list(range(frames)), f"run {k} recorded frames {recorded}"


def test_a_domain_asked_for_is_kept_and_a_live_graph_keeps_the_environments() -> None:
    import argparse

    from gldt_ros.launcher.pipeline import choose_domain

    saved = os.environ.get("ROS_DOMAIN_ID")
    try:
        os.environ["ROS_DOMAIN_ID"] = "17"
        assert choose_domain(argparse.Namespace(domain_id=None, bag=REAL_BAG)) is None
        assert choose_domain(argparse.Namespace(domain_id=None, bag=None)) is None
        assert os.environ["ROS_DOMAIN_ID"] == "17"
        line = choose_domain(argparse.Namespace(domain_id=42, bag=REAL_BAG))
        assert line is not None and "42" in line and os.environ["ROS_DOMAIN_ID"] == "42"
        del os.environ["ROS_DOMAIN_ID"]
        assert choose_domain(argparse.Namespace(domain_id=None, bag=None)) is None
        assert "ROS_DOMAIN_ID" not in os.environ
        line = choose_domain(argparse.Namespace(domain_id=None, bag=REAL_BAG))
        assert line is not None and 101 <= int(os.environ["ROS_DOMAIN_ID"]) <= 232
    finally:
        if saved is None:
            os.environ.pop("ROS_DOMAIN_ID", None)
        else:
            os.environ["ROS_DOMAIN_ID"] = saved
