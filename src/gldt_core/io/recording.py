"""Read what the ROS graph recorded (``pipeline --record OUT.mcap``) back into core arrays.

The recording holds CDR messages of the graph's own types, read with
:func:`gldt_core.io.mcap_file.read_mcap` and decoded with the rosbags typestore (no ROS needed), so
offline tools (``gldt eval``, the demo, the equivalence test) can compare the graph's
``/gldt/tracks`` with an offline run.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from gldt_core.io.cdr import after_header_fields
from gldt_core.io.mcap_file import McapDamageError, read_mcap
from gldt_core.track.planner_stream import MATCHED_STATES, STATE_CODES

TRACKS_TOPIC_SUFFIX = "gldt/tracks"


def track_array_frame_and_source(cdr: bytes) -> tuple[int, int]:
    """``(frame_index, source)`` of a ``gldt_msgs/TrackArray`` read from its CDR bytes without
    deserialising its tracks (``source``: ``TrackArray.SOURCE_*``); ValueError when too short."""
    frame_index, source = after_header_fields(cdr, "QB")
    return int(frame_index), int(source)


def iter_recorded(path: str | os.PathLike[str], topic_suffix: str) -> Iterator[tuple[str, Any, int]]:
    """Yield ``(topic, message, log_time_ns)`` for every message whose topic ends with ``topic_suffix``,
    in the order they were recorded.

    A recording cut short or damaged (the recorder was killed) yields every complete message
    before the damage, then raises ``ValueError`` naming the file.
    """
    from gldt_core.io.ros_types import typestore

    store = typestore()
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"recording not found: {path}")
    try:
        for message in read_mcap(path):
            if message.topic.endswith(topic_suffix):
                yield message.topic, store.deserialize_cdr(message.data, message.msgtype), message.log_time_ns
    except McapDamageError as damage:
        raise ValueError(
            f"recording {path} is damaged after the messages already read: {damage.reason} (byte {damage.offset})"
        ) from None


def recorded_track_rows(path: str | os.PathLike[str]) -> np.ndarray:
    """MOTChallenge rows ``frame, id, x, y, w, h, score, -1, -1, -1`` of every recorded ``TrackArray``.

    Only the tracks matched with a detection in their frame, as the tracker's output and the MOT
    files of ``gldt run`` hold them: the coasting and removed entries of the planner's stream
    (:mod:`gldt_core.track.planner_stream`) are not rows a MOT metric should count. A frame no
    detector measured (a live replay's ``SOURCE_PREDICTED`` and ``SOURCE_LATE`` answers) gives the
    tracks matched in the last measured frame, at their predicted boxes: what a planner was shown.
    ``frame`` is ``frame_index + 1`` (MOTChallenge is 1-based), rows in recording order.
    """
    matched_codes = {STATE_CODES[name] for name in MATCHED_STATES}
    rows: list[tuple[float, ...]] = []
    for _, array, _ in iter_recorded(path, TRACKS_TOPIC_SUFFIX):
        frame = int(array.frame_index) + 1
        for track in array.tracks:
            if int(track.state) not in matched_codes or int(track.frames_since_update) != 0:
                continue
            rows.append(
                (
                    frame,
                    int(track.id),
                    track.center_x - track.width / 2,
                    track.center_y - track.height / 2,
                    track.width,
                    track.height,
                    float(track.score),
                    -1.0,
                    -1.0,
                    -1.0,
                )
            )
    return np.asarray(rows, dtype=np.float64).reshape(-1, 10)
