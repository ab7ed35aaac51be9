"""Hand freed heap memory back to the OS every few seconds (glibc's ``malloc_trim``).

Why: a node process churns through large buffers every frame (a decoded 1080p frame is 6 MB,
a letterboxed pair 1.5 MB, the global detector's input blob 3 MB). With glibc's defaults those
come from the heap and are reused, but the heap only ever shrinks from its top, so small
long-lived allocations left between the big ones pin it and the resident size grows in steps
over a long run (``python -m gldt_ros.bench.soak`` measures it). A fixed mmap threshold
(``MALLOC_MMAP_THRESHOLD_``) would bound the heap as well, but gives each big buffer its own
fresh ``mmap``, whose pages fault in one by one on first touch: every frame's decode and
letterbox pay for it (``python -m gldt_ros.bench.hops`` shows the camera-to-tick hop grow).

``malloc_trim(0)`` instead returns every whole free page anywhere in the heap (``madvise``),
so the resident size tracks what is live while the buffers keep coming from the heap. It runs
in a daemon thread: ctypes releases the GIL for the call, so the node's callbacks keep running.

``GLDT_HEAP_TRIM_PERIOD`` (seconds; ``pipeline`` sets it for its node processes, 0 or unset: off)
turns it on. Where the C library is not glibc there is nothing to call, and it stays off.
"""

from __future__ import annotations

import ctypes
import os
import threading
from collections.abc import Callable

#: Environment variable holding the trim period in seconds (0 or unset: no trimming).
HEAP_TRIM_PERIOD_ENV = "GLDT_HEAP_TRIM_PERIOD"
#: The period ``pipeline`` gives its node processes: short enough that the resident size sampled
#: by a soak run sits within a few frames of what is live, long enough to cost nothing measurable.
DEFAULT_PERIOD_S = 1.0


def glibc_malloc_trim() -> Callable[[int], int] | None:
    """glibc's ``malloc_trim`` through ctypes, or None where the C library has none (musl, macOS).

    Looked up among the symbols the process already has, as :mod:`gldt_ros.runtime.teardown_limit` finds
    ``alarm``: ``ctypes.util.find_library`` would run ``ldconfig`` in a subprocess at every node's start."""
    try:
        function = ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError):
        return None
    function.argtypes = [ctypes.c_size_t]
    function.restype = ctypes.c_int
    return function


def trim_period_from_env(environ: dict[str, str] | None = None) -> float:
    """The period from :data:`HEAP_TRIM_PERIOD_ENV`: 0 when unset; ValueError naming the variable
    when it is not a finite number >= 0."""
    raw = (os.environ if environ is None else environ).get(HEAP_TRIM_PERIOD_ENV, "").strip()
    if not raw:
        return 0.0
    try:
        period = float(raw)
    except ValueError:
        raise ValueError(f"{HEAP_TRIM_PERIOD_ENV}={raw!r} is not a number of seconds") from None
    if not period >= 0 or period == float("inf"):
        raise ValueError(f"{HEAP_TRIM_PERIOD_ENV}={raw!r}: expected a finite number of seconds >= 0")
    return period


def start_heap_trimming(period_s: float, stop: threading.Event | None = None) -> threading.Thread | None:
    """Call ``malloc_trim(0)`` every ``period_s`` seconds in a daemon thread until ``stop`` is set
    (or the process ends); returns the thread, or None when ``period_s`` is 0 or there is no glibc."""
    trim = glibc_malloc_trim() if period_s > 0 else None
    if trim is None:
        return None
    stop = stop or threading.Event()

    def trim_until_stopped() -> None:
        while not stop.wait(period_s):
            trim(0)

    thread = threading.Thread(target=trim_until_stopped, name="gldt-heap-trim", daemon=True)
    thread.start()
    return thread
