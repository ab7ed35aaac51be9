"""A node that will not stop on SIGINT: ``pipeline`` gets its threads' stacks into the log, then kills it."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import time
from typing import Any

import pytest

pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

from gldt_ros.runtime.stack_dump import STACK_DUMP_SIGNAL  # noqa: E402

#: A stand-in node: registers the dump as run_node does, then ignores SIGINT inside a named function.
STUCK_NODE = textwrap.dedent(
    """
    import signal, sys, time
    from gldt_ros.runtime.stack_dump import dump_stacks_on_request
    dump_stacks_on_request()
    signal.signal(signal.SIGINT, signal.SIG_IGN)

    def stuck_in_teardown():
        print("ready", flush=True)
        while True:
            time.sleep(0.05)

    stuck_in_teardown()
    """
)


def start_stuck_node() -> subprocess.Popen[bytes]:
    process = subprocess.Popen([sys.executable, "-c", STUCK_NODE], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert process.stdout is not None and process.stdout.readline().strip() == b"ready"
    return process


def test_a_node_prints_every_threads_stack_on_the_signal_and_keeps_running() -> None:
    process = start_stuck_node()
    try:
        process.send_signal(STACK_DUMP_SIGNAL)
        time.sleep(0.5)
        assert process.poll() is None, "the dump must not stop the node"
    finally:
        process.kill()
        _, err = process.communicate(timeout=10)
    assert b"stuck_in_teardown" in err and (b"Current thread" in err or b"Thread 0x" in err), err.decode(
        errors="replace"
    )[-2000:]


def test_stop_dumps_the_stacks_of_a_node_that_ignores_sigint_before_killing_it(
    capsys: pytest.CaptureFixture[str], node_processes_of: Any
) -> None:
    process = start_stuck_node()
    children = node_processes_of({"local_detector": process})
    started = time.monotonic()
    unclean = children.stop(grace_s=0.5)
    took = time.monotonic() - started
    _, err = process.communicate(timeout=10)
    out = capsys.readouterr().out
    assert unclean == 1
    assert "node local_detector did not stop within 0.5 s of SIGINT" in out
    assert "exited with code" in out
    assert b"stuck_in_teardown" in err, err.decode(errors="replace")[-2000:]
    assert took < 8.0, "SIGTERM must follow the dump, not wait for SIGKILL's deadline"


def test_a_node_that_stops_on_sigint_gets_no_dump(capsys: pytest.CaptureFixture[str], node_processes_of: Any) -> None:
    process = subprocess.Popen(
        # Python's own SIGINT handler set explicitly: under a test run started as a background
        # job SIGINT is inherited ignored, and this stand-in would not stop on it.
        [
            sys.executable,
            "-c",
            "import signal, time\nsignal.signal(signal.SIGINT, signal.default_int_handler)\n"
            "print('ready', flush=True)\ntime.sleep(60)",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert process.stdout is not None and process.stdout.readline().strip() == b"ready"
    children = node_processes_of({"tracker": process})
    assert children.stop(grace_s=5.0) == 0
    assert "did not stop" not in capsys.readouterr().out
