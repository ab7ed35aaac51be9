"""Message-order policy for consumers of stamped streams (the tracker node).

In a ROS graph, messages of one camera stream can reach the tracker out of order: the global and
the local detector are separate processes, a restarted node answers late, and an overloaded graph
delivers a detection seconds after newer ones. The tracker must never move back in time, yet a
stream that really restarted (a bag played again, a camera driver restarted) must not be dropped
forever. :class:`StampOrder` tells the two apart:

* a message newer than the last accepted one is accepted;
* an older one within ``stale_window_s`` is a late message: dropped;
* an older one beyond the window is dropped too, unless ``restart_after`` such messages arrive in a
  row with nothing newer in between: then the stream restarted and the consumer must reset. A single
  very late message (an overloaded graph) therefore never wipes the tracks.
"""

from __future__ import annotations


class StaleMessage(ValueError):
    """A message stamped at or before the last accepted one; the consumer drops it."""


class StampOrder:
    """Accept, drop or reset on each stamp; see the module docstring."""

    def __init__(self, stale_window_s: float = 1.0, restart_after: int = 3) -> None:
        if stale_window_s < 0 or restart_after < 1:
            raise ValueError(f"need stale_window_s >= 0 and restart_after >= 1, got {stale_window_s}, {restart_after}")
        self.stale_window_s = float(stale_window_s)
        self.restart_after = int(restart_after)
        self.last_stamp: float | None = None
        self._behind_in_a_row = 0

    def check(self, t: float, frame_index: int) -> bool:
        """True when the stream restarted (reset the consumer, then process the message); raises
        :class:`StaleMessage` for a message to drop; False for an in-order message."""
        if self.last_stamp is None or t > self.last_stamp:
            self._behind_in_a_row = 0
            return False
        lag = self.last_stamp - t
        if lag >= self.stale_window_s:
            self._behind_in_a_row += 1
            if self._behind_in_a_row >= self.restart_after:
                self.forget()
                return True
        raise StaleMessage(
            f"frame {frame_index} stamped {t:.3f} s arrived after {self.last_stamp:.3f} s; stale, dropped"
            + (
                f" ({self._behind_in_a_row} of {self.restart_after} in a row before a restart is assumed)"
                if lag >= self.stale_window_s
                else ""
            )
        )

    def accept(self, t: float) -> None:
        """Record ``t`` as the newest stamp processed."""
        self.last_stamp = float(t)

    def forget(self) -> None:
        """Start afresh (new stream, new frame size)."""
        self.last_stamp = None
        self._behind_in_a_row = 0
