"""Issue 31: a node that stops answering is noticed by its missing heartbeat and restarted.

The watch itself (:class:`gldt_ros.launcher.heartbeat.Heartbeats`) is tested on an injected clock;
the supervisor's use of it (:meth:`gldt_ros.launcher.pipeline.NodeProcesses.supervise`) on stand-in
processes that really are stopped with SIGSTOP. The whole graph, a node SIGSTOPped mid-replay, is
``tests/faults/test_ros_stalled_node.py``.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
from types import SimpleNamespace
from typing import Any

import pytest

from gldt_ros.launcher.heartbeat import (
    GOAL_S,
    HEARTBEAT_LIMIT_S,
    MISSED_PERIODS,
    PERIOD_KEY,
    PID_KEY,
    WATCH_GAP_S,
    Heartbeats,
)


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def watch(beats: Heartbeats, clock: FakeClock, seconds: float, step_s: float = 0.1) -> dict[str, float]:
    """Let ``seconds`` pass, looking every ``step_s`` as the supervisor does; the last look's answer."""
    silent = beats.silent()
    for _ in range(round(seconds / step_s)):
        clock.now += step_s
        silent = beats.silent()
    return silent


def status_values(pid: int | None = None, period_s: float | None = None, **others: str) -> list[SimpleNamespace]:
    values = {"inputs": "3", **others}
    if pid is not None:
        values[PID_KEY] = str(pid)
    if period_s is not None:
        values[PERIOD_KEY] = f"{period_s:g}"
    return [SimpleNamespace(key=key, value=value) for key, value in values.items()]


def test_the_limit_leaves_time_to_restart_within_the_goal() -> None:
    from gldt_ros.interface.params import SCHEMA

    periods = {spec.default for specs in SCHEMA.values() for spec in specs if spec.name == "diagnostics_period"}
    assert len(periods) == 1
    (period,) = periods
    # The default period must leave a node a good second of slack before it is judged, and the
    # judgement (every 0.2 s) must come well before the 2 s of the issue.
    assert HEARTBEAT_LIMIT_S - float(period) >= 0.9
    assert HEARTBEAT_LIMIT_S + 0.2 < GOAL_S
    assert MISSED_PERIODS * float(period) <= HEARTBEAT_LIMIT_S


def test_a_node_is_judged_only_once_its_process_has_sent_a_status() -> None:
    clock = FakeClock()
    beats = Heartbeats(clock=clock)
    beats.started("tracker", 41)
    for _ in range(20):  # start-up, model loading: never silent before the first status
        clock.now += 0.5
        assert beats.silent() == {}
    beats.note_status("tracker", status_values(pid=41, period_s=0.5))
    assert watch(beats, clock, HEARTBEAT_LIMIT_S - 0.1) == {}
    assert watch(beats, clock, 0.2) == {"tracker": pytest.approx(HEARTBEAT_LIMIT_S + 0.1)}
    beats.note_status("tracker", status_values(pid=41))
    assert beats.silent() == {}


def test_a_restart_starts_over_and_the_old_process_no_longer_counts() -> None:
    clock = FakeClock()
    beats = Heartbeats(clock=clock)
    beats.started("local_detector", 7)
    beats.beat("local_detector", 7)
    beats.started("local_detector", 8)  # the restart
    for _ in range(10):
        clock.now += 0.5
        beats.note_status("local_detector", status_values(pid=7))  # a late status of the killed process
        assert beats.silent() == {}, "the new process was judged before its first status"
    beats.note_status("local_detector", status_values(pid=8))
    clock.now += 0.5
    beats.note_status("local_detector", status_values(pid=7))
    assert set(watch(beats, clock, HEARTBEAT_LIMIT_S)) == {"local_detector"}


def test_statuses_of_unknown_nodes_or_without_a_pid() -> None:
    clock = FakeClock()
    beats = Heartbeats(clock=clock)
    beats.note_status("someone_else", status_values(pid=1))  # never started by this pipeline
    beats.started("mode_scheduler", 12)
    beats.note_status("mode_scheduler", status_values())  # no pid in it: taken as the current process's
    beats.note_status("mode_scheduler", [SimpleNamespace(key=PID_KEY, value="x")])  # unreadable: as without
    assert set(watch(beats, clock, HEARTBEAT_LIMIT_S + 0.1)) == {"mode_scheduler"}


def test_a_node_with_a_longer_period_gets_more_time() -> None:
    clock = FakeClock()
    beats = Heartbeats(clock=clock)
    beats.started("global_detector", 3)
    beats.note_status("global_detector", status_values(pid=3, period_s=2.0))
    assert beats.limit_for("global_detector") == MISSED_PERIODS * 2.0
    assert watch(beats, clock, MISSED_PERIODS * 2.0 - 0.1) == {}
    assert set(watch(beats, clock, 0.2)) == {"global_detector"}


def test_a_watcher_that_was_away_judges_no_one_for_it() -> None:
    """``pipeline`` itself stopped (Ctrl-Z) or starved: the statuses it missed are not the nodes'
    fault. Their silence starts over at its next look."""
    clock = FakeClock()
    beats = Heartbeats(clock=clock)
    for pid, name in enumerate(["a", "b"]):
        beats.started(name, pid)
        beats.beat(name, pid)
    assert beats.silent() == {}
    clock.now += WATCH_GAP_S + 5.0
    assert beats.silent() == {}
    clock.now += 0.2
    beats.beat("a", 0)
    for _ in range(int(HEARTBEAT_LIMIT_S / 0.2)):
        assert beats.silent() == {}
        clock.now += 0.2
        beats.beat("a", 0)
    assert set(beats.silent()) == {"b"}


# --- the supervisor --------------------------------------------------------------------------------


def _stand_in_graph(
    monkeypatch: pytest.MonkeyPatch, clock: FakeClock, max_restarts: int, processes: str = "per-node"
) -> Any:
    """``NodeProcesses`` whose five nodes are sleeping stand-ins (one per node's process, as
    ``processes`` places them), watched on ``clock``."""
    from gldt_ros.launcher import pipeline

    monkeypatch.setattr(
        pipeline, "process_command", lambda group, args: [sys.executable, "-c", "import time; time.sleep(60)"]
    )
    monkeypatch.setattr(pipeline, "Heartbeats", lambda: Heartbeats(clock=clock))
    args = argparse.Namespace(
        max_restarts=max_restarts, spare=False, spare_delay=0.0, tune_malloc=False, executor=None, processes=processes
    )
    children = pipeline.NodeProcesses(args)
    children.supervising = True
    return children


def _beat_all_but(children: Any, victim: str) -> None:
    for name, process in children.processes.items():
        if name != victim:
            children.heartbeats.note_status(name, status_values(pid=process.pid))


def _stop_all(children: Any) -> None:
    for process in children.processes.values():
        if process.poll() is None:  # a group's process may come twice: killed the first time
            process.kill()
            process.wait()


def test_a_stopped_node_is_killed_and_restarted_like_a_dead_one(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    clock = FakeClock()
    children = _stand_in_graph(monkeypatch, clock, max_restarts=5)
    noted: list[tuple[str, ...]] = []
    try:
        victim = "jptrack_tracker"
        _beat_all_but(children, "")
        stopped = children.processes[victim]
        os.kill(stopped.pid, signal.SIGSTOP)
        for _ in range(int(HEARTBEAT_LIMIT_S / 0.2)):
            clock.now += 0.2
            _beat_all_but(children, victim)
            assert children.supervise(noted.append) == []
        clock.now += 0.2
        _beat_all_but(children, victim)
        assert children.supervise(noted.append) == [victim]
        assert noted == [(victim,)] and stopped.returncode == -signal.SIGKILL
        assert children.restarts == {name: int(name == victim) for name in children.processes}
        restarted = children.processes[victim]
        assert restarted.pid != stopped.pid and restarted.poll() is None
        out = capsys.readouterr().out
        assert f"pipeline: node {victim} sent no heartbeat for 1.6 s; killing and restarting (1/5)" in out, out
        assert f"pipeline: started {victim} (pid {restarted.pid})" in out
        # The new process loads its models before its first status: not judged meanwhile.
        for _ in range(20):
            clock.now += 0.2
            _beat_all_but(children, victim)
            assert children.supervise(noted.append) == []
        assert children.dead() == [] and children.restarts[victim] == 1
    finally:
        _stop_all(children)


def test_a_group_of_nodes_is_one_process_killed_and_restarted_as_a_whole(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--processes grouped``: one silent member takes its whole process down once, and the group
    comes back as one new process that every member names, each member's restart counted."""
    from gldt_ros.interface.graph import GROUPED, PROCESS_LAYOUTS

    clock = FakeClock()
    children = _stand_in_graph(monkeypatch, clock, max_restarts=5, processes=GROUPED)
    noted: list[tuple[str, ...]] = []
    try:
        group = next(group for group in PROCESS_LAYOUTS[GROUPED] if "jptrack_tracker" in group)
        assert len(group) > 1 and len({id(p) for p in children.processes.values()}) == len(PROCESS_LAYOUTS[GROUPED])
        stopped = children.processes["jptrack_tracker"]
        assert all(children.processes[name] is stopped for name in group)
        _beat_all_but(children, "")
        os.kill(stopped.pid, signal.SIGSTOP)
        for _ in range(int(HEARTBEAT_LIMIT_S / 0.2)):
            clock.now += 0.2
            _beat_all_but(children, "jptrack_tracker")  # its group mates answer from their own timers
            assert children.supervise(noted.append) == []
        clock.now += 0.2
        _beat_all_but(children, "jptrack_tracker")
        assert sorted(children.supervise(noted.append)) == sorted(group)
        assert noted == [tuple(group)] and stopped.returncode == -signal.SIGKILL
        restarted = children.processes["jptrack_tracker"]
        assert restarted.pid != stopped.pid and all(children.processes[name] is restarted for name in group)
        assert children.restarts == {name: int(name in group) for name in children.processes}
        out = capsys.readouterr().out
        assert out.count("sent no heartbeat") == 1, out
        assert f"pipeline: started {'+'.join(group)} (pid {restarted.pid})" in out, out
        # A member that dies by itself takes the group down as well: one restart, not one per member.
        restarted.kill()
        restarted.wait()
        assert sorted(children.supervise(noted.append)) == sorted(group)
        assert children.restarts == {name: 2 * int(name in group) for name in children.processes}
        assert capsys.readouterr().out.count("exited with code") == 1
    finally:
        _stop_all(children)


def test_a_stopped_node_without_restarts_left_is_killed_and_dead(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    clock = FakeClock()
    children = _stand_in_graph(monkeypatch, clock, max_restarts=0)
    try:
        victim = "mode_scheduler"
        _beat_all_but(children, "")
        os.kill(children.processes[victim].pid, signal.SIGSTOP)
        for _ in range(int(HEARTBEAT_LIMIT_S / 0.2) + 1):
            clock.now += 0.2
            _beat_all_but(children, victim)
            assert children.supervise() == []
        assert children.dead() == [victim]
        assert "sent no heartbeat for 1.6 s; killing it, no restart left" in capsys.readouterr().out
    finally:
        _stop_all(children)


def test_every_node_status_carries_its_pid_and_period() -> None:
    """What the watch reads: each node's own process id and ``diagnostics_period``."""
    pytest.importorskip("rclpy")
    code = (
        "import os, sys, rclpy\n"
        "from gldt_ros.nodes import mode_scheduler\n"
        "rclpy.init()\n"
        "node = mode_scheduler.create_node(cli_args=['--ros-args', '-p', 'diagnostics_period:=0.7'])\n"
        "values = {pair.key: pair.value for pair in node.diagnostics_status().values}\n"
        "print(values[sys.argv[1]] == str(os.getpid()), values[sys.argv[2]])\n"
        "node.destroy_node(); rclpy.shutdown()\n"
    )
    from support import isolated_ros_env

    command = [sys.executable, "-c", code, PID_KEY, PERIOD_KEY]
    out = subprocess.run(command, capture_output=True, text=True, env=isolated_ros_env(), timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["True", "0.7"], out.stdout
