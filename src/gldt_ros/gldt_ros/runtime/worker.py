"""A node's long work on a thread of its own, so the thread that spins the process stays free.

The global detector works on a frame pair for longer than a camera frame period. In a process of
its own that only delays its own callbacks; in a process shared with other nodes
(:mod:`gldt_ros.runtime.node_group`) it would hold up every node of the process for as long. A
:class:`KeepNewestWorker` takes such work off the spinning thread: the subscription callback
hands the message over and returns at once, the worker runs it, and the result goes back to the
spinning thread (:meth:`gldt_ros.runtime.node_base.GldtNode.call_on_spin_thread`) to be published
there, in publication order with the process's other messages.

Items wait in a queue of ``depth``; one that arrives while it is full replaces the oldest waiting
one, which is never worked on, as a subscription's KEEP_LAST history of that depth would drop it:
a detector slower than the camera skips to the newest pair instead of working through a backlog.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable
from typing import Generic, TypeVar

Item = TypeVar("Item")


class KeepNewestWorker(Generic[Item]):
    """Runs ``work(item)`` on a daemon thread for the items :meth:`submit` hands it, oldest first,
    keeping at most ``depth`` waiting (module docstring). An exception escaping ``work`` ends the
    worker and goes to ``on_error`` (on the worker's thread), which must end or restart the node:
    a node whose worker is gone would still look alive."""

    def __init__(
        self, work: Callable[[Item], None], depth: int, on_error: Callable[[BaseException], None], name: str
    ) -> None:
        if depth < 1:
            raise ValueError(f"a worker's queue depth must be >= 1, got {depth}")
        self._work = work
        self._on_error = on_error
        self._waiting: deque[Item] = deque(maxlen=depth)
        self._ready = threading.Condition()
        self._busy = False
        self._stopped = False
        self.replaced = 0  # items dropped unworked because newer ones filled the queue
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def submit(self, item: Item) -> None:
        """Queue ``item``; when the queue is full the oldest waiting item is dropped."""
        with self._ready:
            if self._stopped:
                return
            if len(self._waiting) == self._waiting.maxlen:
                self.replaced += 1
            self._waiting.append(item)
            self._ready.notify()

    def idle(self) -> bool:
        """Whether nothing is waiting or being worked on."""
        with self._ready:
            return not self._waiting and not self._busy

    def alive(self) -> bool:
        """Whether the worker's thread still runs (it ends on :meth:`stop` or an error)."""
        return self._thread.is_alive()

    def stop(self, timeout_s: float = 1.0) -> None:
        """Drop what waits and end the thread, waiting at most ``timeout_s`` for the item in
        progress: one that takes longer still finishes afterwards, on the daemon thread, and its
        result must then be dropped by whoever receives it (a node that is being destroyed does)."""
        with self._ready:
            self._stopped = True
            self._waiting.clear()
            self._ready.notify()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout_s)

    def _run(self) -> None:
        while True:
            with self._ready:
                while not self._waiting and not self._stopped:
                    self._ready.wait()
                if self._stopped:
                    return
                item = self._waiting.popleft()
                self._busy = True
            try:
                self._work(item)
            except BaseException as error:  # noqa: BLE001 - handed to on_error, which ends the node
                with self._ready:
                    self._stopped, self._busy = True, False
                    self._waiting.clear()
                self._on_error(error)
                return
            with self._ready:
                self._busy = False
