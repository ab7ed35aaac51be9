"""Rate limit for repeated error lines ("one clear log line", not one per frame at 30 Hz).

An overloaded or misconfigured graph can reject every frame for the same reason (a camera on the
wrong encoding, decisions arriving after their frame left the buffer). Each rejection is still
counted in ``/diagnostics``, but the log gets the first line of each kind at once and then at most
one line per ``period_s`` saying how many like it were suppressed. Errors are of the same kind when
they differ only in numbers (frame indices, stamps, sizes), so different faults are never hidden
behind each other.
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable

_NUMBER = re.compile(r"\d+(?:\.\d+)?")
#: Distinct kinds remembered; beyond this the memory is cleared (errors with unbounded variety).
MAX_KINDS = 256


class LogThrottle:
    """``text_for(key, message)`` returns the line to log now, or None to suppress it."""

    def __init__(self, period_s: float = 1.0, clock: Callable[[], float] = time.monotonic) -> None:
        self.period_s = float(period_s)
        self._clock = clock
        self._kinds: dict[tuple[str, str], tuple[float, int]] = {}

    def text_for(self, key: str, message: str) -> str | None:
        kind = (key, _NUMBER.sub("#", message))
        now = self._clock()
        last, suppressed = self._kinds.get(kind, (float("-inf"), 0))
        if now - last < self.period_s:
            self._kinds[kind] = (last, suppressed + 1)
            return None
        if len(self._kinds) >= MAX_KINDS and kind not in self._kinds:
            self._kinds.clear()
        self._kinds[kind] = (now, 0)
        if suppressed:
            return f"{message} ({suppressed} more like this in the last {now - last:.1f} s)"
        return message
