"""gldt_ros.runtime.spin: a spin thread ends quietly when shutdown races it, and loudly otherwise.

The race it guards against failed a CI run: SIGINT shut the context down between the executor's
``context.ok()`` check and its wait-set construction, and the spin thread printed an RCLError
traceback although the pipeline stopped as asked.
"""

from __future__ import annotations

import threading
import time

import pytest

rclpy = pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

from rclpy._rclpy_pybind11 import RCLError  # noqa: E402
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor  # noqa: E402

from gldt_ros.runtime.spin import spin_until_shutdown, start_spin_thread  # noqa: E402


class _Context:
    def __init__(self, ok: bool) -> None:
        self._ok = ok

    def ok(self) -> bool:
        return self._ok


class _RaisingExecutor:
    """Stands in for an executor whose spin loop raises ``error`` with its context in ``context_ok``."""

    def __init__(self, error: BaseException, context_ok: bool, is_shutdown: bool = False) -> None:
        self._context = _Context(context_ok)
        self._is_shutdown = is_shutdown
        self.error = error

    def spin(self) -> None:
        raise self.error


def test_an_error_caused_by_the_context_shutting_down_is_a_stop() -> None:
    invalid = RCLError("failed to initialize wait set: the given context is not valid")
    spin_until_shutdown(_RaisingExecutor(invalid, context_ok=False))
    spin_until_shutdown(_RaisingExecutor(invalid, context_ok=True, is_shutdown=True))
    spin_until_shutdown(_RaisingExecutor(ExternalShutdownException(), context_ok=False))


def test_an_error_while_the_context_is_valid_propagates() -> None:
    with pytest.raises(RCLError):
        spin_until_shutdown(_RaisingExecutor(RCLError("a real failure"), context_ok=True))
    with pytest.raises(ValueError):
        spin_until_shutdown(_RaisingExecutor(ValueError("a bug in a callback"), context_ok=False))


def test_a_caller_can_say_when_the_executor_is_meant_to_run() -> None:
    """gldt_ros.runtime.executor's EventsSpinner is no rclpy executor: it passes its own ``running``."""
    invalid = RCLError("failed to take: the given context is not valid")
    spin_until_shutdown(_RaisingExecutor(invalid, context_ok=True), still_running=lambda: False)
    with pytest.raises(RCLError):
        spin_until_shutdown(_RaisingExecutor(invalid, context_ok=False), still_running=lambda: True)


def test_a_real_spin_thread_ends_without_an_exception_when_its_context_is_shut_down() -> None:
    """Shut the context down under a live spin loop many times; no thread may raise."""
    escaped: list[BaseException | None] = []
    previous_hook = threading.excepthook
    threading.excepthook = lambda hook_args: escaped.append(hook_args.exc_value)
    try:
        for attempt in range(20):
            context = rclpy.Context()
            rclpy.init(context=context)
            node = rclpy.create_node(f"spin_probe_{attempt}", context=context)
            node.create_timer(0.0005, lambda: None)  # keeps the loop rebuilding wait sets
            executor = SingleThreadedExecutor(context=context)
            executor.add_node(node)
            thread = start_spin_thread(executor)
            time.sleep(0.005 * (attempt % 4))
            context.shutdown()  # what rclpy's SIGINT handler does, from another thread
            thread.join(timeout=5.0)
            assert not thread.is_alive(), "the spin thread did not end after its context shut down"
            executor.shutdown(timeout_sec=1.0)
            node.destroy_node()
    finally:
        threading.excepthook = previous_hook
    assert escaped == []
