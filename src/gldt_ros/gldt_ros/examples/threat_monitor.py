"""threat_monitor: an example planner-side subscriber that prints the most urgent threat per frame.

Urgency: the smallest pessimistic time to collision (``time_to_collision - 2 sigma``) among tracks
with a valid one; without any, the track closest to the optical axis. Coasting (LOST) tracks count:
an obstacle the detector missed for a few frames is still there. Removed tracks do not. Run it
beside the graph: ``ros2 run gldt_ros threat_monitor``.
"""

from __future__ import annotations

import math
from typing import Any

from gldt_msgs.msg import Track, TrackArray
from rclpy.node import Node

from gldt_ros.interface import qos, topics
from gldt_ros.runtime.node_base import run_node


def most_urgent(tracks: list[Track]) -> Track | None:
    """The track an avoidance planner should look at first (see module docstring)."""
    live = [t for t in tracks if t.state in (Track.STATE_CONFIRMED, Track.STATE_RECOVERED, Track.STATE_LOST)]
    with_ttc = [t for t in live if t.time_to_collision_valid]
    if with_ttc:
        return min(with_ttc, key=pessimistic_time_to_collision)
    with_bearing = [t for t in live if t.bearing_valid]
    if with_bearing:
        return min(with_bearing, key=lambda t: math.hypot(t.azimuth, t.elevation))
    return live[0] if live else None


def pessimistic_time_to_collision(track: Track) -> float:
    """Two standard deviations below the estimate: what a cautious planner plans for [s]."""
    return max(track.time_to_collision - 2.0 * track.time_to_collision_sigma, 0.0)


CLASS_NAMES = {Track.CLASS_DRONE: "drone", Track.CLASS_BIRD: "bird", Track.CLASS_AIRPLANE: "airplane"}


def describe(track: Track) -> str:
    kind = CLASS_NAMES.get(track.class_id)
    parts = [f"track {track.id}" + (f" ({kind} {track.class_confidence:.2f})" if kind else " (class unknown)")]
    if track.state == Track.STATE_LOST:
        parts.append(f"coasting {track.frames_since_update} frames")
    if track.bearing_valid:
        parts.append(f"az {math.degrees(track.azimuth):+.1f} deg (left +) el {math.degrees(track.elevation):+.1f} deg")
    else:
        parts.append(f"at ({track.center_x:.0f}, {track.center_y:.0f}) px")
    if track.time_to_collision_valid:
        parts.append(f"TTC {track.time_to_collision:.1f} +- {track.time_to_collision_sigma:.1f} s")
    return ", ".join(parts)


class ThreatMonitor(Node):
    def __init__(self, **kwargs: Any) -> None:
        super().__init__("threat_monitor", **kwargs)
        self.create_subscription(TrackArray, topics.TRACKS, self.on_tracks, qos.RELIABLE)

    def on_tracks(self, array: TrackArray) -> None:
        threat = most_urgent(list(array.tracks))
        text = describe(threat) if threat is not None else "no threat"
        print(f"frame {array.frame_index}: {text}", flush=True)


def create_node(cli_args: list[str] | None = None) -> ThreatMonitor:
    return ThreatMonitor(cli_args=cli_args)


def main() -> int:
    return run_node(create_node)


if __name__ == "__main__":
    raise SystemExit(main())
