"""Repeated node errors: the first of each kind at once, then one line per period with a count."""

from __future__ import annotations

from gldt_ros.runtime.log_throttle import LogThrottle


def test_repeats_are_suppressed_and_counted_but_other_kinds_pass() -> None:
    now = [100.0]
    throttle = LogThrottle(period_s=1.0, clock=lambda: now[0])
    first = "scheduler decision for frame 7877, which is no longer buffered"
    assert throttle.text_for("decision", first) == first
    now[0] += 0.1
    assert throttle.text_for("decision", "scheduler decision for frame 7878, which is no longer buffered") is None
    # Another fault (or the same text on another input) is never hidden behind the first one.
    assert throttle.text_for("image", "unsupported encoding 'yuv422'") == "unsupported encoding 'yuv422'"
    assert throttle.text_for("decision", "roi 2 is empty") == "roi 2 is empty"
    now[0] += 0.2
    assert throttle.text_for("decision", "scheduler decision for frame 7879, which is no longer buffered") is None
    now[0] += 1.0
    line = throttle.text_for("decision", "scheduler decision for frame 7990, which is no longer buffered")
    assert line == "scheduler decision for frame 7990, which is no longer buffered (2 more like this in the last 1.3 s)"
