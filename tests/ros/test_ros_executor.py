"""gldt_ros.runtime.executor: choosing a node's executor, the events executor's spin loop, and a node
process stopping on SIGINT whichever executor spins it."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time

import pytest

rclpy = pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

from rclpy.executors import ExternalShutdownException  # noqa: E402
from std_msgs.msg import Header  # noqa: E402

from gldt_ros.interface.graph import default_params_file  # noqa: E402
from gldt_ros.launcher.pipeline import node_environment, parse_args  # noqa: E402
from gldt_ros.runtime.executor import (  # noqa: E402
    EVENTS,
    EXECUTOR_ENV,
    SINGLE,
    EventsSpinner,
    background_executor,
    events_executor_available,
    executor_kind,
    spin_node,
)
from gldt_ros.runtime.heap_trim import HEAP_TRIM_PERIOD_ENV  # noqa: E402


def test_the_events_executor_is_the_default_and_rclpys_python_one_is_there_to_opt_in() -> None:
    assert events_executor_available(), "the pinned ros-jazzy-rclpy 7.1.6 ships rclpy.experimental.EventsExecutor"
    assert executor_kind({}) == EVENTS
    assert executor_kind({EXECUTOR_ENV: ""}) == EVENTS


def test_without_the_events_executor_the_default_falls_back_to_single(monkeypatch: pytest.MonkeyPatch) -> None:
    import gldt_ros.runtime.executor as executor_module

    monkeypatch.setattr(executor_module, "events_executor_available", lambda: False)
    assert executor_module.executor_kind({}) == SINGLE
    with pytest.raises(ValueError, match="no rclpy.experimental.EventsExecutor"):
        executor_module.executor_kind({EXECUTOR_ENV: "events"})


def test_the_environment_chooses_the_executor() -> None:
    assert executor_kind({EXECUTOR_ENV: "single"}) == SINGLE
    assert executor_kind({EXECUTOR_ENV: " Events "}) == EVENTS


def test_an_unknown_executor_is_named_with_the_choices() -> None:
    with pytest.raises(ValueError, match=r"GLDT_EXECUTOR='threads'.*events, single"):
        executor_kind({EXECUTOR_ENV: "threads"})


def test_pipeline_passes_its_executor_to_the_node_processes(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(EXECUTOR_ENV, raising=False)
    assert parse_args([]).executor == EVENTS
    assert parse_args(["--executor", "single"]).executor == SINGLE
    monkeypatch.setenv(EXECUTOR_ENV, "single")
    assert parse_args([]).executor == SINGLE, "an exported choice is the default"
    assert node_environment(tune_malloc=False, executor=EVENTS)[EXECUTOR_ENV] == EVENTS
    monkeypatch.setenv(EXECUTOR_ENV, "bogus")
    with pytest.raises(SystemExit):
        parse_args([])


def test_the_events_loop_serves_subscriptions_and_timers_and_stops_at_shutdown() -> None:
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("gldt_executor_test", context=context)
    received: list[str] = []
    ticks: list[float] = []
    publisher = node.create_publisher(Header, "gldt_executor_test/echo", 10)
    node.create_subscription(Header, "gldt_executor_test/echo", lambda msg: received.append(msg.frame_id), 10)
    node.create_timer(0.05, lambda: ticks.append(time.monotonic()))
    outcome: list[BaseException | None] = []

    def spin() -> None:
        try:
            spin_node(node, EVENTS)
            outcome.append(None)
        except ExternalShutdownException as stop:
            outcome.append(stop)
        except RuntimeError as stop:  # a take racing the shutdown; run_node treats it as a stop too
            if not context.ok():
                outcome.append(stop)

    thread = threading.Thread(target=spin, daemon=True)
    thread.start()
    try:
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline and (len(received) < 3 or len(ticks) < 3):
            publisher.publish(Header(frame_id=f"m{len(received)}"))
            time.sleep(0.05)
        assert len(received) >= 3, f"subscription callbacks: {received}"
        assert len(ticks) >= 3, f"timer callbacks: {len(ticks)}"
    finally:
        stopped_at = time.monotonic()
        rclpy.shutdown(context=context)
        thread.join(timeout=3.0)
    assert not thread.is_alive(), "the spin loop did not notice the shutdown"
    assert time.monotonic() - stopped_at < 1.5
    assert len(outcome) == 1, "spin_node ended with something other than a stop"
    node.destroy_node()


def test_a_background_spinner_stops_when_shut_down_while_its_context_lives_on() -> None:
    """``pipeline`` shuts its executor down, joins the spin thread, and only then rclpy: the loop
    must end on the executor's shutdown alone (a bare EventsExecutor's spin_once keeps waiting)."""
    rclpy.init()
    try:
        executor, spin = background_executor(EVENTS)
        assert isinstance(executor, EventsSpinner)
        node = rclpy.create_node("gldt_background_executor_test")
        executor.add_node(node)
        thread = threading.Thread(target=spin, daemon=True)
        thread.start()
        time.sleep(0.3)
        assert thread.is_alive()
        stopped_at = time.monotonic()
        assert executor.shutdown(timeout_sec=2.0)
        thread.join(timeout=3.0)
        assert not thread.is_alive(), "the spin thread outlived the executor's shutdown"
        assert time.monotonic() - stopped_at < 1.5
        node.destroy_node()
    finally:
        rclpy.shutdown()


@pytest.mark.parametrize("kind", [EVENTS, SINGLE])
def test_a_node_process_stops_cleanly_on_sigint(kind: str) -> None:
    """The stop a launch file or ``pipeline`` sends: exit 0 within a few seconds, either executor."""
    command = [
        sys.executable,
        "-m",
        "gldt_ros.nodes.mode_scheduler",
        "--ros-args",
        "--params-file",
        str(default_params_file()),
    ]
    command += ["-r", f"__ns:=/gldt_executor_{kind}"]
    process = subprocess.Popen(
        command,
        env=node_environment(tune_malloc=False, executor=kind),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        assert process.stdout is not None
        first_line = process.stdout.readline()
        assert "mode_scheduler ready" in first_line, first_line
        time.sleep(0.5)  # a few timer periods of spinning
        process.send_signal(signal.SIGINT)
        output, _ = process.communicate(timeout=10.0)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == 0, output
    assert "Traceback" not in output, output
    assert "FATAL" not in output, output  # a KeyboardInterrupt inside a callback of the events executor


@pytest.mark.parametrize(
    "variable, value, complaint",
    [
        (EXECUTOR_ENV, "threads", "GLDT_EXECUTOR='threads': expected one of events, single"),
        (HEAP_TRIM_PERIOD_ENV, "often", "GLDT_HEAP_TRIM_PERIOD='often' is not a number of seconds"),
    ],
)
def test_a_bad_process_setting_stops_a_node_at_start_in_one_line(variable: str, value: str, complaint: str) -> None:
    env = node_environment(tune_malloc=False)
    env[variable] = value
    completed = subprocess.run(
        [sys.executable, "-m", "gldt_ros.nodes.mode_scheduler"], env=env, capture_output=True, text=True, timeout=60
    )
    assert completed.returncode == 1
    assert completed.stdout.strip().splitlines() == [f"[gldt] cannot start: {complaint}"], (
        completed.stdout + completed.stderr
    )


def test_a_callback_cut_short_by_shutdown_is_a_stop_but_a_runtime_error_before_it_is_not() -> None:
    """Ctrl-C mid-callback makes its publish fail with RuntimeError ("publisher's context is
    invalid"); the events executor would log that as FATAL, so the guard lets it pass, but only
    once the context is down."""
    from gldt_ros.nodes import mode_scheduler

    context = rclpy.Context()
    rclpy.init(context=context)
    node = mode_scheduler.ModeSchedulerNode(context=context)

    def publish_fails(_message: object) -> None:
        raise RuntimeError("publisher's context is invalid")

    guarded = node.guarded(publish_fails, "test input")
    try:
        with pytest.raises(RuntimeError, match="context is invalid"):
            guarded(object())
    finally:
        rclpy.shutdown(context=context)
    guarded(object())  # the context is down: a stop
    assert node.frames_dropped == 0, "a stop is not a dropped input"
    node.destroy_node()


def test_a_timer_cut_short_by_shutdown_is_a_stop_but_a_runtime_error_before_it_is_not() -> None:
    """The nodes' timers publish too (diagnostics, links): the same rule as for subscriptions."""
    from gldt_ros.nodes import mode_scheduler

    context = rclpy.Context()
    rclpy.init(context=context)
    node = mode_scheduler.ModeSchedulerNode(context=context)
    calls: list[int] = []

    def publish_fails() -> None:
        calls.append(1)
        raise RuntimeError("publisher's context is invalid")

    timer = node.create_timer(3600.0, publish_fails)
    try:
        with pytest.raises(RuntimeError, match="context is invalid"):
            timer.callback()
    finally:
        rclpy.shutdown(context=context)
    timer.callback()  # the context is down: a stop
    assert len(calls) == 2
    node.destroy_node()


def test_a_documented_error_in_a_timer_is_logged_and_counted_and_the_node_goes_on() -> None:
    """The tracker answers late frames from its deadline timer: a ValueError there must not end
    the process (a subscription's is logged and counted by ``guarded``; a timer's the same way)."""
    from gldt_ros.nodes import mode_scheduler
    from gldt_ros.runtime.node_base import TIMER_ERRORS

    context = rclpy.Context()
    rclpy.init(context=context)
    node = mode_scheduler.ModeSchedulerNode(context=context)
    calls: list[int] = []

    def answer_fails() -> None:
        calls.append(1)
        raise ValueError("track 3: covariance not finite")

    timer = node.create_timer(3600.0, answer_fails)
    try:
        timer.callback()
        timer.callback()
        assert len(calls) == 2 and node.events[TIMER_ERRORS] == 2
        status = node.diagnostics_status()
        assert "2 timer callback(s) failed" in status.message
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)
