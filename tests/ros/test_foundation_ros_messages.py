"""Every gldt_msgs type goes through rclpy (publish -> DDS -> subscribe) with its fields intact."""

from __future__ import annotations

import importlib
import math
import time
from typing import Any

import pytest

from support import MSG_DIR

rclpy = pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

MESSAGE_NAMES = sorted(path.stem for path in MSG_DIR.glob("*.msg"))


def _value_for(field_type: str, seed: int) -> Any:
    """A non-default value for a rosidl field type string (e.g. 'float64', 'sequence<gldt_msgs/Roi>')."""
    if field_type.startswith("sequence<"):
        inner = field_type[len("sequence<") :].rstrip(">").split(",")[0]
        return [_value_for(inner, seed + k) for k in range(2)]
    if "[" in field_type and field_type.endswith("]"):
        inner, size = field_type[:-1].split("[")
        return [_value_for(inner, seed + k) for k in range(int(size))]
    if field_type in ("float", "double", "float32", "float64"):
        return 0.5 + seed
    if field_type == "boolean":
        return True
    if field_type in ("octet", "uint8", "char"):
        return (seed % 250) + 1
    if field_type.startswith(("int", "uint")):
        return seed + 3
    if field_type == "string":
        return f"value-{seed}"
    package, name = field_type.split("/")
    message_class = getattr(importlib.import_module(f"{package}.msg"), name)
    return _filled(message_class, seed)


def _filled(message_class: Any, seed: int = 1) -> Any:
    message = message_class()
    for index, (name, field_type) in enumerate(message_class.get_fields_and_field_types().items()):
        setattr(message, name, _value_for(field_type, seed + index))
    return message


def _as_plain(value: Any) -> Any:
    if hasattr(value, "get_fields_and_field_types"):
        return {name: _as_plain(getattr(value, name)) for name in value.get_fields_and_field_types()}
    if isinstance(value, (list, tuple)) or type(value).__name__ in ("array", "ndarray"):
        return [_as_plain(v) for v in value]
    if isinstance(value, float):
        return round(value, 5)
    return value


@pytest.fixture(scope="module")
def node():
    rclpy.init()
    node = rclpy.create_node("gldt_message_roundtrip_test")
    yield node
    node.destroy_node()
    rclpy.shutdown()


def test_every_message_file_is_built() -> None:
    gldt_msgs = importlib.import_module("gldt_msgs.msg")
    missing = [name for name in MESSAGE_NAMES if not hasattr(gldt_msgs, name)]
    assert MESSAGE_NAMES, f"no .msg files found in {MSG_DIR}"
    assert not missing, f"gldt_msgs lacks built types for {missing}: rerun colcon build"


@pytest.mark.parametrize("name", MESSAGE_NAMES)
def test_message_roundtrip_through_rclpy(node, name: str) -> None:
    message_class = getattr(importlib.import_module("gldt_msgs.msg"), name)
    sent = _filled(message_class, seed=7)
    received: list[Any] = []
    topic = f"/test/roundtrip/{name.lower()}"
    subscription = node.create_subscription(message_class, topic, received.append, 10)
    publisher = node.create_publisher(message_class, topic, 10)
    deadline = time.monotonic() + 10.0
    while not received and time.monotonic() < deadline:
        publisher.publish(sent)
        rclpy.spin_once(node, timeout_sec=0.1)
    node.destroy_publisher(publisher)
    node.destroy_subscription(subscription)
    assert received, f"no {name} message came back through DDS within 10 s"
    assert _as_plain(received[0]) == _as_plain(sent)


def test_track_constants_and_units_are_documented() -> None:
    text = (MSG_DIR / "Track.msg").read_text()
    for token in ("STATE_TENTATIVE", "STATE_CONFIRMED", "STATE_LOST", "STATE_RECOVERED", "[rad]", "[px/s]", "[s]"):
        assert token in text, f"Track.msg should document {token}"
    track_class = importlib.import_module("gldt_msgs.msg").Track
    assert len(track_class().covariance) == 64
    assert not math.isnan(track_class().time_to_collision)
