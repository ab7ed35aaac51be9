"""``/gldt/tracks`` entries from the core's planner stream, and their RViz markers.

The stream itself (which tracks, states, classes, time to collision, bearings) is built in the core
by :class:`gldt_core.track.planner_stream.PlannerStream`; this module only fills messages.
"""

from __future__ import annotations

from gldt_msgs.msg import Track, TrackArray
from visualization_msgs.msg import Marker, MarkerArray

from gldt_core.track.planner_stream import STATE_CODES, PlannerTrack

#: Length of a marker ray [m]. Display only: a monocular camera does not measure range.
MARKER_RAY_LENGTH_M = 10.0
#: Colour (r, g, b) of a marker by ``Track.class_id``; unknown classes are grey.
MARKER_COLOURS = {
    Track.CLASS_DRONE: (1.0, 0.2, 0.1),
    Track.CLASS_BIRD: (0.2, 0.8, 0.2),
    Track.CLASS_AIRPLANE: (0.2, 0.5, 1.0),
}


def planner_track_to_msg(entry: PlannerTrack) -> Track:
    """One :class:`PlannerTrack` -> ``gldt_msgs/Track`` (every field; see ``Track.msg``)."""
    message = Track(
        id=int(entry.track_id),
        state=STATE_CODES[entry.state],
        center_x=float(entry.center_x),
        center_y=float(entry.center_y),
        width=float(entry.width),
        height=float(entry.height),
        velocity_x=float(entry.velocity_x),
        velocity_y=float(entry.velocity_y),
        covariance=[float(v) for v in entry.covariance.reshape(64)],
        age=float(entry.age_s),
        hits=int(entry.hits),
        frames_since_update=int(entry.frames_since_update),
        score=float(entry.score),
        class_id=int(entry.class_id),
        class_confidence=float(entry.class_confidence),
    )
    if entry.bearing is not None:
        message.bearing_valid = True
        message.line_of_sight = list(entry.bearing.line_of_sight)
        message.azimuth, message.elevation = entry.bearing.azimuth, entry.bearing.elevation
        message.azimuth_rate, message.elevation_rate = entry.bearing.azimuth_rate, entry.bearing.elevation_rate
        message.bearing_covariance = list(entry.bearing.covariance)
    looming = entry.looming
    if looming.valid:
        message.time_to_collision_valid = True
        message.time_to_collision = float(looming.ttc)
        message.time_to_collision_sigma = float(looming.ttc_sigma)
    return message


def markers_for(array: TrackArray) -> MarkerArray:
    """One ray per track with a bearing, in the optical frame of ``array.header`` (an ARROW from
    the camera along the line of sight, coloured by class) and its id at the ray's end. Removed
    tracks and tracks without a bearing get no marker."""
    from geometry_msgs.msg import Point

    markers = [Marker(header=array.header, ns="gldt_tracks", id=0, action=Marker.DELETEALL)]
    for track in array.tracks:
        if not track.bearing_valid or track.state == Track.STATE_REMOVED:
            continue
        tip = Point(**{axis: MARKER_RAY_LENGTH_M * value for axis, value in zip("xyz", track.line_of_sight)})
        ray = Marker(header=array.header, ns="gldt_tracks", id=2 * track.id + 1, type=Marker.ARROW, action=Marker.ADD)
        ray.points = [Point(x=0.0, y=0.0, z=0.0), tip]
        ray.scale.x, ray.scale.y, ray.scale.z = 0.03, 0.08, 0.2  # shaft and head diameters, head length [m]
        ray.color.r, ray.color.g, ray.color.b = MARKER_COLOURS.get(track.class_id, (0.6, 0.6, 0.6))
        ray.color.a = 1.0 if track.frames_since_update == 0 else 0.4  # coasting rays are faint
        label = Marker(
            header=array.header, ns="gldt_tracks", id=2 * track.id + 2, type=Marker.TEXT_VIEW_FACING, action=Marker.ADD
        )
        label.pose.position = tip
        label.scale.z = 0.5
        label.color.r = label.color.g = label.color.b = label.color.a = 1.0
        label.text = f"#{track.id}"
        if track.time_to_collision_valid:
            label.text += f" TTC {track.time_to_collision:.1f}s"
        markers += [ray, label]
    return MarkerArray(markers=markers)
