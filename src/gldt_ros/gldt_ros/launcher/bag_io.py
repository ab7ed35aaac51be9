"""The ROS side of replaying and recording bags: the rclpy message class of a bag's type name.

Everything else about bags is ROS-free and lives in ``gldt_core.io``: the player reads raw CDR
messages with :func:`gldt_core.io.bag.bag_messages`, the recorder writes them with
:class:`gldt_core.io.mcap_file.McapWriter`, and :func:`gldt_core.io.cdr.header_stamp_ns` reads a
message's stamp from its bytes. Messages stay CDR bytes end to end (``publisher.publish(raw)`` and
``raw=True`` subscriptions), so rclpy only needs the class of each type to create the endpoints.
"""

from __future__ import annotations

import importlib


def message_class(msgtype: str) -> type:
    """Import the rclpy message class of ``pkg/msg/Name``; ``ValueError`` if it is not installed."""
    parts = msgtype.split("/")
    if len(parts) != 3 or parts[1] != "msg":
        raise ValueError(f"not a ROS 2 message type name: {msgtype!r}")
    try:
        module = importlib.import_module(f"{parts[0]}.msg")
        message_type: type = getattr(module, parts[2])
    except (ImportError, AttributeError):
        raise ValueError(f"message type {msgtype} is not installed here") from None
    return message_type
