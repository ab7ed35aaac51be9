"""A node that will not stop says where it is stuck: every thread's stack on SIGUSR1.

``pipeline`` stops its nodes with SIGINT and, past the grace period, SIGTERM and SIGKILL. A node
killed that way takes the reason with it. Each node therefore registers faulthandler on
:data:`STACK_DUMP_SIGNAL`, and ``pipeline`` sends that signal before it escalates, so the log
shows the stuck threads' stacks. faulthandler writes them from its C signal handler without the
GIL, so the dump comes even when the stuck thread holds it.
"""

from __future__ import annotations

import faulthandler
import signal

#: Signal on which a node prints every thread's Python stack to stderr.
STACK_DUMP_SIGNAL = signal.SIGUSR1


def dump_stacks_on_request() -> None:
    """Print all threads' stacks to stderr whenever :data:`STACK_DUMP_SIGNAL` arrives."""
    faulthandler.register(STACK_DUMP_SIGNAL, all_threads=True)
