"""gldt_ros.runtime.heap_trim: the node processes give freed heap pages back to the OS without the fixed
mmap threshold that made every large buffer fault its pages in afresh."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import threading

import pytest

pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

from gldt_ros.runtime.heap_trim import (  # noqa: E402
    HEAP_TRIM_PERIOD_ENV,
    glibc_malloc_trim,
    start_heap_trimming,
    trim_period_from_env,
)

GLIBC = glibc_malloc_trim() is not None


def test_the_period_comes_from_the_environment_and_a_bad_one_names_the_variable() -> None:
    assert trim_period_from_env({}) == 0.0
    assert trim_period_from_env({HEAP_TRIM_PERIOD_ENV: " 2.5 "}) == 2.5
    assert trim_period_from_env({HEAP_TRIM_PERIOD_ENV: "0"}) == 0.0
    for bad in ("often", "-1", "nan", "inf"):
        with pytest.raises(ValueError, match=HEAP_TRIM_PERIOD_ENV):
            trim_period_from_env({HEAP_TRIM_PERIOD_ENV: bad})


def test_no_period_starts_no_thread() -> None:
    assert start_heap_trimming(0.0) is None


def test_the_thread_trims_until_told_to_stop(monkeypatch: pytest.MonkeyPatch) -> None:
    import gldt_ros.runtime.heap_trim as heap_trim

    calls: list[int] = []
    third_call = threading.Event()

    def fake_trim(pad: int) -> int:
        calls.append(pad)
        if len(calls) >= 3:
            third_call.set()
        return 1

    monkeypatch.setattr(heap_trim, "glibc_malloc_trim", lambda: fake_trim)
    stop = threading.Event()
    thread = start_heap_trimming(0.01, stop)
    assert thread is not None and thread.daemon and thread.name == "gldt-heap-trim"
    assert third_call.wait(10.0), "malloc_trim was not called again and again"
    stop.set()
    thread.join(5.0)
    assert not thread.is_alive()
    assert set(calls) == {0}, "trims everything above the live data (pad 0)"


@pytest.mark.skipif(not GLIBC, reason="malloc_trim is glibc's; other C libraries have nothing to call")
def test_trimming_returns_a_heap_pinned_by_small_live_allocations() -> None:
    """What the nodes suffer without it: with glibc's defaults, frame-sized buffers come from the
    heap once the first one is freed; a small allocation made after each keeps the heap from
    shrinking at its top, so freeing the frames leaves the resident size where it was. One
    ``malloc_trim(0)`` (what the trimming thread calls) gives those pages back."""
    script = textwrap.dedent(
        """
        import numpy as np, psutil
        from gldt_ros.runtime.heap_trim import glibc_malloc_trim
        rss = lambda: psutil.Process().memory_info().rss / 2**20
        np.ones(6 << 20, np.uint8)  # freed at once: glibc raises its mmap threshold above a frame
        frames, pins = [], []
        for _ in range(24):
            frames.append(np.ones(6 << 20, np.uint8))  # a decoded 1080p frame, touched
            # A small allocation that outlives it: malloc'd (pymalloc stops at 512 bytes) and too
            # big for the crumbs the imports left free, so it lands above the frame.
            pins.append(bytearray(64 << 10))
        del frames
        before = rss()
        glibc_malloc_trim()(0)
        print(before, rss())
        """
    )
    completed = subprocess.run(
        [sys.executable, "-c", script],
        capture_output=True,
        text=True,
        timeout=60,
        env={**_clean_malloc_env(), "PYTHONPATH": ":".join(sys.path)},
    )
    assert completed.returncode == 0, completed.stderr
    before_mib, after_mib = (float(v) for v in completed.stdout.split())
    assert before_mib - after_mib > 100, f"trim returned only {before_mib - after_mib:.0f} of 144 MiB freed"


def _clean_malloc_env() -> dict[str, str]:
    import os

    return {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_") and k != "GLIBC_TUNABLES"}


@pytest.mark.parametrize("period, trims", [("1", True), ("", False)])
def test_a_node_process_trims_when_the_pipeline_asks_it_to(period: str, trims: bool) -> None:
    """``run_node`` starts the thread from ``GLDT_HEAP_TRIM_PERIOD`` (which ``pipeline`` sets)
    before the node exists; the node here reports the threads it finds and stops."""
    from gldt_ros.launcher.pipeline import node_environment

    script = textwrap.dedent(
        """
        import threading
        from gldt_ros.runtime.node_base import run_node

        def report_threads():
            raise ValueError("threads " + ",".join(sorted(t.name for t in threading.enumerate())))

        raise SystemExit(run_node(report_threads))
        """
    )
    env = node_environment(tune_malloc=False)
    env[HEAP_TRIM_PERIOD_ENV] = period
    completed = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=60)
    assert completed.returncode == 1, completed.stdout + completed.stderr
    assert ("gldt-heap-trim" in completed.stdout) == (trims and GLIBC), completed.stdout
