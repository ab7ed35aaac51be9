"""A node's teardown after its spin has ended gets a few seconds, not forever.

rclpy's ``Node.destroy_node`` rarely, but sometimes, never returns at the end of a replay: stack
dumps (:mod:`gldt_ros.runtime.stack_dump`) caught it inside ``Publisher.destroy`` (rclpy's own
executors, after a killed and restarted frame_pair_buffer) and inside the type-description
service's destroy (the events executor). By then the node has stopped serving and every
message it owed is out, so waiting longer only costs the caller ``pipeline``'s grace period and a
SIGKILL. The stuck call holds the GIL, so no Python timer can end it: the limit is the kernel's
``alarm`` with libc's ``_exit`` as the SIGALRM handler, which exits with status
:data:`TEARDOWN_TIMEOUT_EXIT` (the signal's number, passed to the handler) without Python.
faulthandler prints every thread's stack half a second before, so the log says where it hung.
"""

from __future__ import annotations

import ctypes
import faulthandler
import signal
import sys

#: Whole seconds a node's teardown may take once its spin has ended.
TEARDOWN_LIMIT_S = 3
#: Exit status of a node whose teardown ran past the limit (SIGALRM's number, given to ``_exit``).
TEARDOWN_TIMEOUT_EXIT = int(signal.SIGALRM)


def limit_teardown(seconds: int = TEARDOWN_LIMIT_S) -> bool:
    """Arm the limit for the rest of this process's life; ``False`` where libc offers no
    ``alarm``/``_exit`` (not Linux), which leaves the teardown unbounded as before."""
    if seconds < 1:
        raise ValueError(f"teardown limit must be at least 1 s, got {seconds}")
    try:
        libc = ctypes.CDLL(None)
        install, alarm, hard_exit = libc.signal, libc.alarm, libc._exit
    except (OSError, AttributeError):
        return False
    install.argtypes = [ctypes.c_int, ctypes.c_void_p]
    install.restype = ctypes.c_void_p
    install(int(signal.SIGALRM), ctypes.cast(hard_exit, ctypes.c_void_p).value)
    faulthandler.dump_traceback_later(max(seconds - 0.5, 0.5), exit=False, file=sys.stderr)
    alarm.argtypes = [ctypes.c_uint]
    alarm(int(seconds))
    return True
