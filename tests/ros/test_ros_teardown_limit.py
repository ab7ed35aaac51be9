"""A node whose rclpy teardown hangs ends itself after TEARDOWN_LIMIT_S, even holding the GIL,
and ``pipeline`` reports that as a hung teardown, not as a failed node."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import time
from typing import Any

import pytest

pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

from gldt_ros.runtime.teardown_limit import TEARDOWN_TIMEOUT_EXIT, limit_teardown  # noqa: E402

#: Stands in for a teardown stuck in C code that holds the GIL (PyDLL keeps it across the call).
STUCK_TEARDOWN = textwrap.dedent(
    """
    import ctypes, signal
    from gldt_ros.runtime.teardown_limit import limit_teardown
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # as a node stuck in destroy_node does not answer SIGINT
    assert limit_teardown(1)
    print("ready", flush=True)
    def stuck_in_destroy_node():
        ctypes.PyDLL(None).sleep(30)
    stuck_in_destroy_node()
    """
)


def test_a_teardown_stuck_holding_the_gil_ends_with_its_own_status_and_stacks() -> None:
    started = time.monotonic()
    completed = subprocess.run([sys.executable, "-c", STUCK_TEARDOWN], capture_output=True, timeout=20)
    took = time.monotonic() - started
    assert completed.returncode == TEARDOWN_TIMEOUT_EXIT, completed.stderr.decode(errors="replace")[-2000:]
    assert took < 10, "the kernel's alarm, not the 30 s sleep, must end it"
    assert b"stuck_in_destroy_node" in completed.stderr, "faulthandler should name where it hung"


def test_a_teardown_that_finishes_in_time_exits_normally() -> None:
    code = "from gldt_ros.runtime.teardown_limit import limit_teardown\nassert limit_teardown(2)\nprint('done')"
    completed = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=20)
    assert completed.returncode == 0 and completed.stdout.strip() == "done"


def test_a_limit_below_one_second_is_refused() -> None:
    with pytest.raises(ValueError, match="at least 1 s"):
        limit_teardown(0)


def test_pipeline_reports_a_hung_teardown_without_counting_the_node_as_failed(
    capsys: pytest.CaptureFixture[str], node_processes_of: Any
) -> None:
    process = subprocess.Popen(
        [sys.executable, "-c", STUCK_TEARDOWN], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL
    )
    assert (
        process.stdout is not None and process.stdout.readline().strip() == b"ready"
    )  # SIGINT only once it is ignored
    assert node_processes_of({"global_detector": process}).stop(grace_s=10.0) == 0
    out = capsys.readouterr().out
    assert "node global_detector stopped, but its rclpy teardown hung" in out
    assert "exited with code" not in out
