"""QoS profiles of the graph, in one place so every node agrees.

Camera input follows the usual driver convention (sensor-data: best effort, shallow) and can be
switched to reliable for drivers and bag players that publish reliably. Detections and tracks
are reliable (a planner must not silently miss a track update). Scheduler state is
transient-local so a late joiner (a restarted node, a debugging tool) gets the latest decision.
"""

from __future__ import annotations

from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)


def camera_qos(policy: str) -> QoSProfile:
    """QoS for camera images and camera_info: ``sensor_data`` (default) or ``reliable``."""
    if policy == "sensor_data":
        return qos_profile_sensor_data
    if policy == "reliable":
        return QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
    raise ValueError(f"camera_qos must be 'sensor_data' or 'reliable', got {policy!r}")


RELIABLE = QoSProfile(depth=30, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)


def newest_first(depth: int) -> QoSProfile:
    """Reliable, keeping only the ``depth`` newest samples: for an input whose handler is slower
    than its rate, where working on the newest sample beats working through a backlog (a frame
    pair that waited behind three others would give the planner tracks 300 ms old)."""
    return QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)


LATCHED_STATE = QoSProfile(
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
    history=HistoryPolicy.KEEP_LAST,
)
