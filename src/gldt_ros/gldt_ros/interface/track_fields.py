"""Planner-facing fields of a track (bearing, bearing rate, time to collision) and RViz markers."""

from __future__ import annotations

import math
from typing import Any

from gldt_msgs.msg import Track, TrackArray
from visualization_msgs.msg import Marker, MarkerArray

from gldt_core.camera import PinholeIntrinsics, bearing, bearing_rate, time_to_collision


def fill_planner_fields(message: Track, track: Any, intrinsics: PinholeIntrinsics | None) -> None:
    """Set bearing, bearing rate and TTC (and their validity flags) on a ``Track`` message.

    TTC uses the growth rate of the box's geometric size ``sqrt(w h)``, from the Kalman state
    (``vw, vh`` at indices 6, 7 of an 8-dim state) when the track has one.
    """
    state = getattr(track, "mean", None)
    if state is None and hasattr(track, "kf"):
        state = getattr(track.kf, "mean", None)
    width, height = message.width, message.height
    if state is not None and len(state) >= 8 and width > 0 and height > 0:
        size = math.sqrt(width * height)
        size_rate = 0.5 * size * (float(state[6]) / width + float(state[7]) / height)
        ttc = time_to_collision(size, size_rate)
        message.time_to_collision_valid = ttc is not None
        message.time_to_collision = float(ttc) if ttc is not None else 0.0
    if intrinsics is None:
        message.bearing_valid = False
        return
    message.azimuth, message.elevation = bearing(intrinsics, message.center_x, message.center_y)
    message.azimuth_rate, message.elevation_rate = bearing_rate(
        intrinsics, message.center_x, message.center_y, message.velocity_x, message.velocity_y
    )
    message.bearing_valid = True


def markers_for(array: TrackArray) -> MarkerArray:
    """One rectangle (LINE_STRIP in image pixels, frame = camera frame) and one id label per track."""
    from geometry_msgs.msg import Point

    markers = [Marker(header=array.header, ns="gldt_tracks", id=0, action=Marker.DELETEALL)]
    for track in array.tracks:
        x1, y1 = track.center_x - track.width / 2, track.center_y - track.height / 2
        x2, y2 = x1 + track.width, y1 + track.height
        box = Marker(
            header=array.header, ns="gldt_tracks", id=2 * track.id + 1, type=Marker.LINE_STRIP, action=Marker.ADD
        )
        box.points = [Point(x=x, y=y, z=0.0) for x, y in ((x1, y1), (x2, y1), (x2, y2), (x1, y2), (x1, y1))]
        box.scale.x = 2.0
        box.color.r, box.color.g, box.color.a = 0.1, 1.0, 1.0
        label = Marker(
            header=array.header, ns="gldt_tracks", id=2 * track.id + 2, type=Marker.TEXT_VIEW_FACING, action=Marker.ADD
        )
        label.pose.position.x, label.pose.position.y = x1, y1 - 8.0
        label.scale.z = 12.0
        label.color.r = label.color.g = label.color.b = label.color.a = 1.0
        label.text = f"#{track.id}"
        markers += [box, label]
    return MarkerArray(markers=markers)
