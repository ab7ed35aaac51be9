"""Conversions between gldt_core arrays/objects and gldt_msgs messages.

Kept free of node logic so they can be property-tested. Array layouts are the core's:
detections ``[x1, y1, x2, y2, score, class_id(, roi_index), p_drone, p_bird, p_airplane]``,
ROIs ``[x1, y1, x2, y2]``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
from gldt_msgs.msg import Detection, DetectionArray, Roi, Track, TrackArray
from sensor_msgs.msg import Image, RegionOfInterest

from gldt_core.detect.second_stage import GLOBAL_COLUMNS, LOCAL_COLUMNS, PROBABILITY_COLUMNS
from gldt_core.io.imaging import decode_compressed_image, decode_raw_image, encode_bgr8
from gldt_core.system.steps import state_name
from gldt_core.track.planner_stream import STATE_CODES


def stamp_seconds(stamp: Any) -> float:
    """``builtin_interfaces/Time`` -> seconds as a float (the core's time base)."""
    return stamp.sec + stamp.nanosec * 1e-9


def stamp_nanoseconds(stamp: Any) -> int:
    """``builtin_interfaces/Time`` -> integer nanoseconds: an exact key for a frame's messages."""
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def image_to_bgr(message: Any) -> np.ndarray:
    """Decode ``sensor_msgs/Image`` or ``CompressedImage`` into a BGR array (``ImageDecodeError`` if not)."""
    if hasattr(message, "encoding"):
        return decode_raw_image(
            message.data, message.width, message.height, message.encoding, message.step, bool(message.is_bigendian)
        )
    return decode_compressed_image(message.data, getattr(message, "format", "jpeg"))


def bgr_to_image(frame: np.ndarray, header: Any) -> Image:
    """Build a ``bgr8`` ``sensor_msgs/Image`` with the given header."""
    data, width, height, step = encode_bgr8(frame)
    message = Image(header=header, height=height, width=width, encoding="bgr8", is_bigendian=0, step=step)
    message.data = data
    return message


def detections_to_msgs(detections: np.ndarray, source: int) -> list[Detection]:
    """Global rows ``(N, 9)`` or local rows ``(N, 10)`` (see :mod:`gldt_core.detect.second_stage`:
    box, score, class, the ROI index for local ones, three class probabilities) -> ``Detection``s."""
    detections = np.asarray(detections, dtype=np.float64)
    columns = LOCAL_COLUMNS if source == Detection.SOURCE_LOCAL else GLOBAL_COLUMNS
    out = []
    for row in detections.reshape(-1, columns):
        x1, y1, x2, y2, score, class_id = row[:6]
        out.append(
            Detection(
                center_x=float((x1 + x2) / 2),
                center_y=float((y1 + y2) / 2),
                width=float(x2 - x1),
                height=float(y2 - y1),
                score=float(score),
                class_id=int(class_id),
                source=source,
                roi_index=int(row[6]) if source == Detection.SOURCE_LOCAL else -1,
                class_probabilities=[float(p) for p in row[columns - PROBABILITY_COLUMNS :]],
            )
        )
    return out


def detection_array_to_tracker_input(message: DetectionArray) -> np.ndarray:
    """``DetectionArray`` -> ``(N, 5)`` ``[x1, y1, x2, y2, score]`` for ``tracker.update``."""
    rows = [
        (
            d.center_x - d.width / 2,
            d.center_y - d.height / 2,
            d.center_x + d.width / 2,
            d.center_y + d.height / 2,
            d.score,
        )
        for d in message.detections
    ]
    return np.asarray(rows, dtype=np.float64).reshape(-1, 5)


def detection_array_class_probabilities(message: DetectionArray) -> np.ndarray:
    """``(N, 3)`` drone, bird, airplane probabilities of the detections, in their order."""
    rows = [list(d.class_probabilities) for d in message.detections]
    return np.asarray(rows, dtype=np.float64).reshape(-1, PROBABILITY_COLUMNS)


def rois_to_msgs(rois: np.ndarray, track_ids: Sequence[Sequence[int]] | None = None) -> list[Roi]:
    """``(R, 4)`` ``[x1, y1, x2, y2]`` -> ``Roi`` messages."""
    out = []
    for index, (x1, y1, x2, y2) in enumerate(np.asarray(rois, dtype=np.int64).reshape(-1, 4)):
        region = RegionOfInterest(x_offset=int(x1), y_offset=int(y1), width=int(x2 - x1), height=int(y2 - y1))
        ids = [int(i) for i in track_ids[index]] if track_ids is not None else []
        out.append(Roi(region=region, track_ids=ids))
    return out


def msgs_to_rois(rois: Iterable[Roi]) -> np.ndarray:
    """``Roi`` messages -> ``(R, 4)`` int ``[x1, y1, x2, y2]``."""
    rows = [
        (r.region.x_offset, r.region.y_offset, r.region.x_offset + r.region.width, r.region.y_offset + r.region.height)
        for r in rois
    ]
    return np.asarray(rows, dtype=np.int64).reshape(-1, 4)


def state_code(state: Any) -> int:
    """``Track.STATE_*`` for a core ``TrackState`` (by name, so enum values may be anything)."""
    name = state_name(state).lower()
    if name not in STATE_CODES:
        raise ValueError(f"unknown track state {state!r}")
    return STATE_CODES[name]


def track_to_msg(track: Any) -> Track:
    """A core ``Track`` object -> ``gldt_msgs/Track``: its box, motion and life (what the mode
    scheduler plans ROIs from). The planner's stream is built by
    :func:`gldt_ros.interface.track_fields.planner_track_to_msg`."""
    x1, y1, x2, y2 = (float(v) for v in track.box_xyxy)
    vx, vy = (float(v) for v in track.velocity_px_s[:2])
    covariance = np.zeros(64)
    cov = np.asarray(getattr(track, "covariance", np.zeros((8, 8))), dtype=np.float64)
    if cov.size == 64:
        covariance = cov.reshape(64)
    return Track(
        id=int(track.track_id),
        state=state_code(track.state),
        center_x=(x1 + x2) / 2,
        center_y=(y1 + y2) / 2,
        width=x2 - x1,
        height=y2 - y1,
        velocity_x=vx,
        velocity_y=vy,
        covariance=covariance.tolist(),
        age=float(track.age_s),
        hits=int(track.hits),
        frames_since_update=int(track.frames_since_update),
        score=float(track.score),
        class_id=Track.CLASS_UNKNOWN,
    )


def track_array_to_rows(message: TrackArray) -> np.ndarray:
    """``TrackArray`` -> ``(M, 6)`` ``[x1, y1, x2, y2, track_id, score]`` (the tracker's output layout)."""
    rows = [
        (
            t.center_x - t.width / 2,
            t.center_y - t.height / 2,
            t.center_x + t.width / 2,
            t.center_y + t.height / 2,
            t.id,
            t.score,
        )
        for t in message.tracks
    ]
    return np.asarray(rows, dtype=np.float64).reshape(-1, 6)
