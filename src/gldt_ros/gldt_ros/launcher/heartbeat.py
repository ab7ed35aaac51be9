"""Heartbeats of the node processes: how ``pipeline`` notices a node that stopped answering.

A node process that hangs (SIGSTOP, a deadlock, a callback that never returns) does not exit, so
the supervisor's ``process.poll()`` never sees it and the graph stalls. Every node publishes its
``/diagnostics`` status every ``diagnostics_period`` (0.5 s by default) from a timer of its
executor (:class:`gldt_ros.runtime.node_base.GldtNode`), and a timer only runs while the node
serves its callbacks: that status is the node's heartbeat. ``pipeline``'s driver hands each status
it receives to :class:`Heartbeats` (``GraphDriver._on_diagnostics``); the supervisor
(:meth:`gldt_ros.launcher.pipeline.NodeProcesses.supervise`) asks it which nodes are silent, kills
them and restarts them like nodes that died.

Only a process that has sent a status counts: a node is silent from its first status on, never
while it starts, loads its models and warms up (it publishes once it spins). Each status carries
the pid of the node process (:data:`PID_KEY`), so a status of the process before a restart, or of
a same-named node of another graph, is no heartbeat of the current one.

Pure logic without ROS: the clock is injected, the status values are anything with ``key`` and
``value``.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Protocol

#: The issue's goal: a node that stops answering is detected, and restarted, within 2 s.
GOAL_S = 2.0
#: Seconds without a status after which a node counts as silent: :data:`GOAL_S` less a margin for
#: the supervisor's look (every 0.2 s) and the kill. With the default ``diagnostics_period`` of
#: 0.5 s a node may take up to a second longer than usual to publish (a long callback, a busy
#: machine) before it is judged.
HEARTBEAT_LIMIT_S = 1.5
#: A node whose own ``diagnostics_period`` is longer than the default is judged after missing this
#: many of its periods instead (detection then takes longer than :data:`GOAL_S`).
MISSED_PERIODS = 3
#: A gap this long between two looks means the watcher itself was away (``pipeline`` stopped with
#: Ctrl-Z, or starved of CPU); the statuses it missed meanwhile are no node's fault, so every
#: node's silence starts over then.
WATCH_GAP_S = 1.0
#: Diagnostics keys of every node's status: the pid of its process, and its ``diagnostics_period``.
PID_KEY = "pid"
PERIOD_KEY = "diagnostics_period"


class KeyValue(Protocol):
    """One value of a status (``diagnostic_msgs/KeyValue``)."""

    key: str
    value: str


@dataclass
class _Record:
    pid: int | None  # the node's current process
    last_beat: float | None = None  # arrival of its newest status; None before its first
    period_s: float | None = None  # the diagnostics_period it announced


class Heartbeats:
    """When each node's current process last sent a status, and which are silent for too long.

    Thread-safe: statuses arrive on the driver's executor thread, the supervisor looks from its own.
    """

    def __init__(self, limit_s: float = HEARTBEAT_LIMIT_S, clock: Callable[[], float] = time.monotonic) -> None:
        self.limit_s = limit_s
        self._clock = clock
        self._records: dict[str, _Record] = {}
        self._last_look: float | None = None
        self._lock = threading.Lock()

    def started(self, name: str, pid: int | None) -> None:
        """Node ``name``'s process ``pid`` was (re)started: it is not judged before its first status."""
        with self._lock:
            self._records[name] = _Record(pid)

    def beat(self, name: str, pid: int | None = None, period_s: float | None = None) -> None:
        """A status of node ``name`` from process ``pid`` (``None``: unknown, taken as the current
        one) arrived now. Statuses of nodes never :meth:`started`, or of another process, do not count."""
        with self._lock:
            record = self._records.get(name)
            if record is None or (pid is not None and record.pid is not None and pid != record.pid):
                return
            record.last_beat = self._clock()
            if period_s is not None:
                record.period_s = period_s

    def note_status(self, name: str, values: Iterable[KeyValue]) -> None:
        """:meth:`beat` from a status's values (:data:`PID_KEY`, :data:`PERIOD_KEY`, where present)."""
        pid: int | None = None
        period_s: float | None = None
        for pair in values:
            try:
                if pair.key == PID_KEY:
                    pid = int(pair.value)
                elif pair.key == PERIOD_KEY:
                    period_s = float(pair.value)
            except ValueError:
                continue
        self.beat(name, pid, period_s)

    def limit_for(self, name: str) -> float:
        """Seconds of silence after which node ``name`` counts as silent."""
        with self._lock:
            record = self._records.get(name)
            return self._limit(record.period_s if record is not None else None)

    def _limit(self, period_s: float | None) -> float:
        return self.limit_s if period_s is None else max(self.limit_s, MISSED_PERIODS * period_s)

    def silent(self) -> dict[str, float]:
        """The nodes whose current process sent a status once but none for longer than their limit
        (:meth:`limit_for`), with the seconds since their last one. After a gap of more than
        :data:`WATCH_GAP_S` since the previous look, none (and every node's silence starts over)."""
        now = self._clock()
        with self._lock:
            away = self._last_look is not None and now - self._last_look > WATCH_GAP_S
            self._last_look = now
            if away:
                for record in self._records.values():
                    if record.last_beat is not None:
                        record.last_beat = now
                return {}
            return {
                name: now - record.last_beat
                for name, record in self._records.items()
                if record.last_beat is not None and now - record.last_beat > self._limit(record.period_s)
            }
