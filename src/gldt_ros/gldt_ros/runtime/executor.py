"""Which rclpy executor a node process spins, and the loop that spins it.

rclpy's Python executors rebuild a wait set of every subscription, timer, parameter service and
guard condition on each callback, in Python. In a graph of several nodes on few cores that work
sits on every hop of a frame's chain, and profiles of a lockstep replay find the nodes spending a
large share of their busy time in ``Executor.wait_for_ready_callbacks``. rclpy's C++
``EventsExecutor`` (``rclpy.experimental``, in Jazzy since rclpy 7.1.4) dispatches from
middleware events instead, which shortens each small hop (``python -m gldt_ros.bench.hops``
measures them) and so the whole lockstep replay (``python -m gldt_ros.bench.graph``).

``events`` is therefore the default; ``GLDT_EXECUTOR=single`` (or ``pipeline --executor single``)
selects rclpy's Python executors instead: ``rclpy.spin`` in the nodes and a thread pool in
``pipeline``. Without ``rclpy.experimental.EventsExecutor`` (rclpy older than 7.1.4) the default
falls back to ``single``.

Either executor can, rarely, leave a node stuck in rclpy's teardown (``Node.destroy_node``,
``Publisher.destroy``) after its spin has ended. Every node's teardown is therefore bounded
(:mod:`gldt_ros.runtime.teardown_limit`), so such a hang costs a few seconds and is reported with
the stuck threads' stacks (:mod:`gldt_ros.runtime.stack_dump`) instead of failing the run. The
history of these choices is in ``docs/experiment-log.md``.

The events executor is driven by :meth:`EventsSpinner.spin`, a loop of ``spin_once`` with a
timeout, never by its own ``spin()``: in rclpy 7.1.5 (the ros-jazzy-rclpy 7.1.6 wheel), ``spin()``
dispatched nothing and kept the GIL (a timer callback never ran and another thread's
``threading.Timer`` never fired), while ``spin_once`` works and lets other threads run. The
timeout bounds how long a stop can go unnoticed if a shutdown's wake-up were ever missed.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Mapping
from typing import Any

#: Environment variable naming the executor of every node process (``pipeline`` sets it for its children).
EXECUTOR_ENV = "GLDT_EXECUTOR"
EVENTS = "events"
SINGLE = "single"
EXECUTOR_CHOICES = (EVENTS, SINGLE)
#: What a node spins when ``$GLDT_EXECUTOR`` is not set, where this rclpy has it (module docstring).
DEFAULT_EXECUTOR = EVENTS
#: Longest wait of one ``spin_once`` of the events executor, seconds.
EVENTS_POLL_S = 0.2


def events_executor_available() -> bool:
    """Whether this rclpy ships ``rclpy.experimental.EventsExecutor`` (Jazzy's rclpy >= 7.1.4)."""
    try:
        from rclpy.experimental import EventsExecutor  # noqa: F401
    except ImportError:
        return False
    return True


def executor_kind(environ: Mapping[str, str] | None = None) -> str:
    """The executor a node should spin: ``$GLDT_EXECUTOR`` if set, else ``events`` where this
    rclpy has it and ``single`` where not (module docstring). An unknown value, or ``events``
    asked for explicitly on an rclpy without it, is a configuration error, named."""
    environ = os.environ if environ is None else environ
    requested = environ.get(EXECUTOR_ENV, "").strip().lower()
    if not requested:
        return DEFAULT_EXECUTOR if events_executor_available() else SINGLE
    if requested not in EXECUTOR_CHOICES:
        raise ValueError(f"{EXECUTOR_ENV}={environ[EXECUTOR_ENV]!r}: expected one of {', '.join(EXECUTOR_CHOICES)}")
    if requested == EVENTS and not events_executor_available():
        raise ValueError(
            f"{EXECUTOR_ENV}=events: this rclpy has no rclpy.experimental.EventsExecutor (needs rclpy >= 7.1.4)"
        )
    return requested


class EventsSpinner:
    """rclpy's ``EventsExecutor`` driven by ``spin_once`` with a timeout (never its ``spin()``,
    see the module docstring) until :meth:`shutdown` or the context's shutdown.

    Shaped like an rclpy executor where callers use one (``add_node``, ``spin``, ``shutdown``);
    like theirs, ``spin`` lets the exceptions of a shutdown that races it propagate
    (:func:`gldt_ros.runtime.spin.spin_until_shutdown` treats them as a stop, given :meth:`running`).
    """

    def __init__(self, context: Any | None = None) -> None:
        import rclpy
        from rclpy.experimental import EventsExecutor

        self.context = context if context is not None else rclpy.get_default_context()
        self.executor = EventsExecutor(context=self.context)
        self._stopped = threading.Event()

    def add_node(self, node: Any) -> None:
        self.executor.add_node(node)

    def running(self) -> bool:
        return self.context.ok() and not self._stopped.is_set()

    def spin(self) -> None:
        while self.running():
            self.executor.spin_once(timeout_sec=EVENTS_POLL_S)

    def shutdown(self, timeout_sec: float | None = None) -> bool:
        """Stop :meth:`spin` (within one poll) and shut the executor down."""
        self._stopped.set()
        return bool(self.executor.shutdown(timeout_sec=timeout_sec))


def quiet_sigint_for_events_executor() -> None:
    """Make SIGINT stop an events-executor node through rclpy alone, without a KeyboardInterrupt.

    Call before ``rclpy.init``. rclpy's SIGINT handler shuts the contexts down (which wakes the
    executor) and then calls the handler that was installed before it: Python's default one
    raises KeyboardInterrupt wherever the main thread happens to be. With the events executor
    that is mostly inside a callback the C++ executor is running (a diagnostics or link timer),
    which then logs "Exception in 'timers' callback" as FATAL for what is an ordinary stop. This
    installs a no-op handler for rclpy to chain to; the spin loop then ends on the context's
    shutdown.
    """
    import signal

    signal.signal(signal.SIGINT, lambda _signum, _frame: None)


def spin_node(node: Any, kind: str) -> None:
    """Spin ``node`` on the ``kind`` executor until its context shuts down (Ctrl-C, SIGTERM via
    rclpy's handler, ``rclpy.shutdown``). Shutdown exceptions propagate, for the caller to
    treat as a stop, as they do from ``rclpy.spin``."""
    spin_nodes([node], kind)


def spin_nodes(nodes: list[Any], kind: str) -> None:
    """:func:`spin_node` for several nodes of one context, on one executor (a process that
    hosts a group of the graph's nodes, :mod:`gldt_ros.runtime.node_group`)."""
    import rclpy

    if kind == SINGLE:
        # rclpy's global executor, not an explicit SingleThreadedExecutor: with the latter a node
        # sometimes failed to stop on SIGINT within pipeline's grace period.
        executor = rclpy.get_global_executor()
        for node in nodes[1:]:
            executor.add_node(node)
        rclpy.spin(nodes[0])
        return
    spinner = EventsSpinner(nodes[0].context)
    for node in nodes:
        spinner.add_node(node)
    try:
        spinner.spin()
    finally:
        spinner.shutdown()


def background_executor(kind: str, threads: int = 4) -> tuple[Any, Callable[[], None]]:
    """``(executor, spin)`` for a process that spins its node on a background thread while its
    main thread works (``pipeline``'s player and recorder, the soak's driver): an
    :class:`EventsSpinner` for ``events``, else a ``MultiThreadedExecutor`` of ``threads``.
    ``spin`` runs until shutdown and treats a shutdown's races as a stop."""
    from gldt_ros.runtime.spin import spin_until_shutdown

    if kind == SINGLE:
        from rclpy.executors import MultiThreadedExecutor

        threaded = MultiThreadedExecutor(num_threads=threads)
        return threaded, lambda: spin_until_shutdown(threaded)
    spinner = EventsSpinner()
    return spinner, lambda: spin_until_shutdown(spinner, spinner.running)
