"""Spinning an executor on a background thread without a traceback at shutdown.

``Executor.spin`` checks ``context.ok()`` and then builds a wait set. When the context is shut
down between the two (rclpy's SIGINT handler does that from the signal, the owner's ``finally``
does it on a normal stop), building the wait set raises ``RCLError`` ("the given context is not
valid") on the spin thread, which Python prints as an unhandled thread exception. That is a stop,
not a crash: :func:`spin_until_shutdown` swallows exactly that case and re-raises anything that
happens while the context is still valid.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any


def spin_until_shutdown(executor: Any, still_running: Callable[[], bool] | None = None) -> None:
    """Spin ``executor`` until it or its context is shut down; errors caused by that shutdown
    racing the spin loop are not errors, everything else propagates. ``still_running`` tells
    whether the executor is still meant to run (default: :func:`executor_still_running`, which
    reads rclpy's own executors)."""
    from rclpy.executors import ExternalShutdownException

    running = still_running if still_running is not None else lambda: executor_still_running(executor)
    try:
        executor.spin()
    except ExternalShutdownException:
        pass
    except RuntimeError:  # rclpy's RCLError and InvalidHandle both derive from RuntimeError
        if running():
            raise


def executor_still_running(executor: Any) -> bool:
    """Whether neither ``executor`` nor its context has been shut down."""
    context = getattr(executor, "_context", None)
    context_ok = context.ok() if context is not None else True
    return context_ok and not getattr(executor, "_is_shutdown", False)


def start_spin_thread(executor: Any, name: str = "gldt-spin") -> threading.Thread:
    """Start a daemon thread running :func:`spin_until_shutdown` on ``executor`` and return it."""
    thread = threading.Thread(target=spin_until_shutdown, args=(executor,), name=name, daemon=True)
    thread.start()
    return thread
