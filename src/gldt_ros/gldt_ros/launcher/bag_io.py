"""Raw MCAP replay and recording for the graph, with no rosbag2 installation.

Messages stay CDR bytes end to end: the player publishes the bytes stored in the bag
(``publisher.publish(raw)`` is accepted by rclpy) and the recorder writes the bytes it receives
with ``raw=True`` subscriptions, so no message is ever deserialised on the way. Schemas for the
MCAP file come from the rosbags typestore, which knows the stock Jazzy types and ``gldt_msgs``.
"""

from __future__ import annotations

import importlib
import struct
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class RawMessage:
    """One message of a bag: topic, ROS type name (``pkg/msg/Name``), log time [ns] and CDR bytes."""

    topic: str
    msgtype: str
    log_time_ns: int
    data: bytes


def find_mcap_file(path: Path) -> Path:
    """Accept a ``.mcap`` file or a rosbag2 folder holding exactly one."""
    path = Path(path)
    if path.is_file():
        return path
    if path.is_dir():
        files = sorted(path.glob("*.mcap"))
        if len(files) == 1:
            return files[0]
        raise ValueError(f"bag folder {path} must hold exactly one .mcap file, found {len(files)}")
    raise FileNotFoundError(f"bag not found: {path}")


def iter_bag(path: Path) -> Iterator[RawMessage]:
    """Yield every message of an MCAP bag in log-time order.

    A truncated or corrupt file yields what can be read and then raises ``ValueError`` naming the
    file, so a replay keeps everything before the damage.
    """
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    mcap_path = find_mcap_file(path)
    with mcap_path.open("rb") as stream:
        reader = make_reader(stream)
        try:
            for schema, channel, message in reader.iter_messages(log_time_order=True):
                msgtype = schema.name if schema is not None else ""
                if msgtype.count("/") == 1:
                    package, name = msgtype.split("/")
                    msgtype = f"{package}/msg/{name}"
                yield RawMessage(channel.topic, msgtype, message.log_time, bytes(message.data))
        except (McapError, struct.error, EOFError, ValueError) as error:
            raise ValueError(f"bag {mcap_path} is damaged after the messages already read: {error}") from error


def bag_topics(path: Path) -> dict[str, str]:
    """``topic -> pkg/msg/Name`` of every channel in the bag's summary (empty if it has none)."""
    from mcap.reader import make_reader

    with find_mcap_file(path).open("rb") as stream:
        try:
            summary = make_reader(stream).get_summary()
        except Exception:  # noqa: BLE001 - a damaged summary: topics are then found while playing
            return {}
    if summary is None:
        return {}
    topics: dict[str, str] = {}
    for channel in summary.channels.values():
        schema = summary.schemas.get(channel.schema_id)
        if schema is None:
            continue
        name = schema.name
        if name.count("/") == 1:
            package, message = name.split("/")
            name = f"{package}/msg/{message}"
        topics[channel.topic] = name
    return topics


def header_stamp_ns(cdr: bytes) -> int:
    """``header.stamp`` of a CDR message whose first field is a ``std_msgs/Header`` (images, arrays)."""
    if len(cdr) < 12:
        raise ValueError(f"CDR message of {len(cdr)} bytes is too short to hold a header")
    little_endian = cdr[1] in (0x01, 0x03)
    seconds, nanoseconds = struct.unpack_from("<iI" if little_endian else ">iI", cdr, 4)
    return seconds * 1_000_000_000 + nanoseconds


def message_class(msgtype: str) -> type:
    """Import the rclpy message class of ``pkg/msg/Name``; ``ValueError`` if it is not installed."""
    parts = msgtype.split("/")
    if len(parts) != 3 or parts[1] != "msg":
        raise ValueError(f"not a ROS 2 message type name: {msgtype!r}")
    try:
        return getattr(importlib.import_module(f"{parts[0]}.msg"), parts[2])
    except (ImportError, AttributeError):
        raise ValueError(f"message type {msgtype} is not installed here") from None


IMAGE_TYPES_SET = frozenset({"sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage"})


class McapRecorder:
    """Append CDR messages to an MCAP file, flushing each chunk so a crash loses little.

    Chunks are small (256 KiB) so that a recorder killed mid-stream leaves a file whose complete
    chunks are all readable by a streaming MCAP reader.
    """

    def __init__(self, path: Path, chunk_size: int = 256 * 1024) -> None:
        from mcap.writer import CompressionType, Writer

        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._stream = self.path.open("wb")
        self._writer = Writer(self._stream, chunk_size=chunk_size, compression=CompressionType.NONE)
        self._writer.start(profile="ros2", library="gldt_ros")
        self._channels: dict[str, int] = {}
        self._lock = threading.Lock()
        self.count = 0

    def _channel(self, topic: str, msgtype: str) -> int:
        if topic not in self._channels:
            from gldt_core.io.ros_types import typestore

            definition, _ = typestore().generate_msgdef(msgtype, ros_version=2)
            schema_id = self._writer.register_schema(name=msgtype, encoding="ros2msg", data=definition.encode("utf-8"))
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="cdr", schema_id=schema_id
            )
        return self._channels[topic]

    def write(self, topic: str, msgtype: str, data: bytes, log_time_ns: int) -> None:
        """Write one message; thread-safe (subscriptions may run on several threads)."""
        with self._lock:
            channel = self._channel(topic, msgtype)
            self._writer.add_message(
                channel_id=channel,
                log_time=log_time_ns,
                publish_time=log_time_ns,
                data=bytes(data),
                sequence=self.count,
            )
            self.count += 1
            self._stream.flush()

    def close(self) -> None:
        """Write the summary and footer (idempotent)."""
        with self._lock:
            if not self._stream.closed:
                self._writer.finish()
                self._stream.close()
