"""The project's one MCAP reader and writer: raw CDR messages in and out of one ``.mcap`` file.

Every MCAP file GL-DT touches goes through here: :class:`gldt_core.io.bag.BagSource` (frames of a
rosbag2 bag), :mod:`gldt_core.io.recording` (what the graph recorded) and the graph's player and
recorder (:mod:`gldt_ros.launcher.replay`). Messages stay CDR bytes; decoding them is the caller's
business (the rosbags typestore of :mod:`gldt_core.io.ros_types`, or rclpy).

Reading (:func:`read_mcap`) is a strict streaming walk over the records of the data section, not
a summary-driven reader: a recorder that was killed leaves no summary, and one damaged byte must
not make the whole recording unreadable. Every record length is checked against what is left, so
damage is found where it is, every message before it is still yielded, and then
:class:`McapDamageError` says where and why (never a silent skip). The walk stops at the DataEnd
record: the summary after it only indexes what was already read, so a file cut inside its summary
loses nothing. Messages come in file order (the order they were recorded in) or, for a player, in
log-time order, merged chunk by chunk so memory stays bounded by the chunks that overlap in time.

Writing (:class:`McapWriter`) appends CDR bytes with their ROS 2 schemas, in chunks closed and
flushed at least once a second, so a writer killed at any moment leaves a file whose chunks hold
everything up to the last second and read back without a summary.
"""

from __future__ import annotations

import heapq
import os
import struct
import threading
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

MCAP_MAGIC = b"\x89MCAP0\r\n"

_OP_FOOTER = 0x02
_OP_SCHEMA = 0x03
_OP_CHANNEL = 0x04
_OP_MESSAGE = 0x05
_OP_CHUNK = 0x06
_OP_DATA_END = 0x0F

_RECORD_HEAD = struct.Struct("<BQ")  # opcode, body length
_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_CHUNK_TIMES = struct.Struct("<QQ")  # first and last message log time of a chunk
_FOOTER = struct.Struct("<BQQQI")  # opcode, length, summary start, summary offset start, summary CRC
_FOOTER_BODY_LENGTH = 20

#: Chunk bytes read to learn its message times (the rest of a chunk is skipped when ordering).
_CHUNK_TIMES_PEEK = _CHUNK_TIMES.size
#: Where a message record's log time starts (after its channel id and sequence), and the bytes
#: read to learn it.
_MESSAGE_LOG_TIME_AT = 6
_MESSAGE_TIME_PEEK = _MESSAGE_LOG_TIME_AT + 8


class McapDamageError(ValueError):
    """An MCAP file damaged (truncated or corrupt) at byte ``offset`` of ``path``."""

    def __init__(self, path: Path, offset: int, reason: str) -> None:
        super().__init__(f"{path}: {reason} (byte {offset})")
        self.path = path
        self.offset = offset
        self.reason = reason


def ros2_type_name(schema_name: str) -> str:
    """The ROS 2 type name ``pkg/msg/Name`` of a schema named so or ``pkg/Name``."""
    parts = schema_name.split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return schema_name


@dataclass(frozen=True)
class McapChannel:
    """A channel of an MCAP file: topic, ROS 2 type name (``pkg/msg/Name``) and message encoding."""

    topic: str
    msgtype: str
    encoding: str


@dataclass(frozen=True)
class McapMessage:
    """One message: the file, the byte offset of its record, its channel, log time [ns] and raw bytes.

    For a message inside a compressed chunk, ``offset`` counts from the chunk's first record as
    though the chunk were stored uncompressed (exact for uncompressed chunks).
    """

    path: Path
    offset: int
    channel: McapChannel
    log_time_ns: int
    data: bytes

    @property
    def topic(self) -> str:
        return self.channel.topic

    @property
    def msgtype(self) -> str:
        return self.channel.msgtype


class _Fields:
    """Bounds-checked little-endian reads from one record body (MCAP's primitive types)."""

    def __init__(self, body: bytes, what: str) -> None:
        self.body, self.position, self.what = body, 0, what

    def take(self, size: int) -> bytes:
        if size < 0 or self.position + size > len(self.body):
            raise ValueError(f"{self.what} record is shorter than its fields")
        start, self.position = self.position, self.position + size
        return self.body[start : self.position]

    def integer(self, fmt: str) -> int:
        value: int = struct.unpack("<" + fmt, self.take(struct.calcsize(fmt)))[0]
        return value

    def string(self) -> str:
        try:
            return self.take(self.integer("I")).decode("utf-8")
        except UnicodeDecodeError:
            raise ValueError(f"{self.what} record holds a string that is not UTF-8") from None


def _schema_record(body: bytes) -> tuple[int, str]:
    """``(schema id, name)`` of a Schema record body."""
    fields = _Fields(body, "schema")
    return fields.integer("H"), fields.string()


def _channel_record(body: bytes) -> tuple[int, int, str, str]:
    """``(channel id, schema id, topic, message encoding)`` of a Channel record body."""
    fields = _Fields(body, "channel")
    channel_id, schema_id = fields.integer("H"), fields.integer("H")
    return channel_id, schema_id, fields.string(), fields.string()


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    if compression == "":
        return data
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == "lz4":
        import lz4.frame

        return bytes(lz4.frame.decompress(data))
    raise ValueError(f"chunk compression {compression!r} is not supported (zstd, lz4 or none)")


class _Walk:
    """The records of one MCAP file in file order; raises :class:`McapDamageError` at damage."""

    def __init__(self, path: Path, stream: BinaryIO) -> None:
        self.path = path
        self.stream = stream
        self.size = os.fstat(stream.fileno()).st_size
        self.schemas: dict[int, str] = {}
        self.channels: dict[int, McapChannel] = {}

    def damage(self, offset: int, reason: str) -> McapDamageError:
        return McapDamageError(self.path, offset, reason)

    def data_records(self, body_limit: int | None = None) -> Iterator[tuple[int, int, bytes]]:
        """``(offset, opcode, body)`` of every record of the data section, up to DataEnd.

        With ``body_limit`` only the first ``body_limit`` bytes of each body are read (the rest is
        skipped), for a quick look at every record's head.
        """
        self.stream.seek(0)
        if self.stream.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            raise self.damage(0, "not an MCAP file (bad magic at the start)")
        offset = len(MCAP_MAGIC)
        while True:
            head = self.stream.read(_RECORD_HEAD.size)
            if len(head) < _RECORD_HEAD.size:
                raise self.damage(offset, "file ends before the data section does (truncated)")
            opcode, length = _RECORD_HEAD.unpack(head)
            end = offset + _RECORD_HEAD.size + length
            if end > self.size:
                raise self.damage(
                    offset, f"record of {length} bytes runs past the end of the file (truncated or corrupt)"
                )
            if opcode in (_OP_DATA_END, _OP_FOOTER):
                return
            if body_limit is None:
                body = self.stream.read(length)
            else:
                body = self.stream.read(min(length, body_limit))
                self.stream.seek(end)
            yield offset, opcode, body
            offset = end

    def messages_of(self, offset: int, opcode: int, body: bytes) -> Iterator[McapMessage]:
        """The messages of one data-section record (a chunk's, in order), noting schemas and channels."""
        try:
            if opcode == _OP_CHUNK:
                yield from self._chunk(body, offset)
                return
            message = self._record(opcode, body, offset, chunk_times=None)
        except McapDamageError:
            raise
        except ValueError as error:
            raise self.damage(offset, str(error)) from None
        if message is not None:
            yield message

    def _chunk(self, body: bytes, offset: int) -> Iterator[McapMessage]:
        fields = _Fields(body, "chunk")
        start_time, end_time, uncompressed_size = fields.integer("Q"), fields.integer("Q"), fields.integer("Q")
        crc, compression = fields.integer("I"), fields.string()
        records_length = fields.integer("Q")
        # Offsets inside the chunk are reported from the chunk's first record in the file (exact for
        # uncompressed chunks) so that "byte N" points at the damage.
        base = offset + _RECORD_HEAD.size + fields.position
        if records_length != len(body) - fields.position:
            raise ValueError(
                f"chunk says its records are {records_length} bytes, it holds {len(body) - fields.position}"
            )
        try:
            records = _decompress(compression, fields.take(records_length), uncompressed_size)
        except ValueError:
            raise
        except Exception as error:  # noqa: BLE001 - any codec failure is damage in this chunk
            raise ValueError(f"chunk cannot be decompressed ({compression}: {error})") from None
        if len(records) != uncompressed_size:
            raise ValueError(f"chunk holds {len(records)} bytes, its header says {uncompressed_size}")
        if crc and zlib.crc32(records) != crc:
            raise ValueError("chunk CRC mismatch")
        position = 0
        while position < len(records):
            if position + _RECORD_HEAD.size > len(records):
                raise self.damage(base + position, "chunk ends inside a record header")
            opcode, length = _RECORD_HEAD.unpack_from(records, position)
            if opcode not in (_OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE):
                raise self.damage(
                    base + position,
                    f"chunk holds a record of opcode 0x{opcode:02x}, "
                    "not a schema, channel or message (corrupt framing)",
                )
            body_start = position + _RECORD_HEAD.size
            if body_start + length > len(records):
                raise self.damage(
                    base + position, f"chunk record of {length} bytes runs past the chunk end (corrupt framing)"
                )
            try:
                message = self._record(
                    opcode,
                    records[body_start : body_start + length],
                    base + position,
                    chunk_times=(start_time, end_time),
                )
            except ValueError as error:
                raise self.damage(base + position, str(error)) from None
            if message is not None:
                yield message
            position = body_start + length

    def _record(self, opcode: int, body: bytes, offset: int, chunk_times: tuple[int, int] | None) -> McapMessage | None:
        if opcode == _OP_SCHEMA:
            schema_id, name = _schema_record(body)
            self.schemas[schema_id] = name
        elif opcode == _OP_CHANNEL:
            channel_id, schema_id, topic, encoding = _channel_record(body)
            if schema_id and schema_id not in self.schemas:
                raise ValueError(f"channel {topic!r} refers to unknown schema {schema_id}")
            self.channels[channel_id] = McapChannel(topic, ros2_type_name(self.schemas.get(schema_id, "")), encoding)
        elif opcode == _OP_MESSAGE:
            if len(body) < _MESSAGE_HEAD.size:
                raise ValueError(f"message record of {len(body)} bytes is shorter than its header")
            channel_id, _, log_time, _ = _MESSAGE_HEAD.unpack_from(body)
            channel = self.channels.get(channel_id)
            if channel is None:
                raise ValueError(f"message on unknown channel {channel_id} (corrupt record)")
            if chunk_times is not None and chunk_times[1] and not chunk_times[0] <= log_time <= chunk_times[1]:
                raise ValueError(
                    f"message time {log_time} ns lies outside its chunk's "
                    f"{chunk_times[0]}..{chunk_times[1]} ns (corrupt record)"
                )
            return McapMessage(self.path, offset, channel, log_time, body[_MESSAGE_HEAD.size :])
        return None  # indexes, metadata, attachments: nothing a message needs

    def earliest_log_times(self) -> list[int]:
        """The earliest log time each chunk or message record of the data section can hold, in file
        order, read from the record heads alone. Stops quietly at damage (reading meets it again)."""
        earliest: list[int] = []
        try:
            for _, opcode, head in self.data_records(body_limit=max(_CHUNK_TIMES_PEEK, _MESSAGE_TIME_PEEK)):
                if opcode == _OP_CHUNK:
                    if len(head) < _CHUNK_TIMES.size:
                        break
                    start_time, end_time = _CHUNK_TIMES.unpack_from(head)
                    # A chunk without an end time does not vouch for its start time either.
                    earliest.append(start_time if end_time else 0)
                elif opcode == _OP_MESSAGE:
                    if len(head) < _MESSAGE_TIME_PEEK:
                        break
                    earliest.append(struct.unpack_from("<Q", head, _MESSAGE_LOG_TIME_AT)[0])
        except McapDamageError:
            pass
        return earliest


def _file_order(walk: _Walk) -> Iterator[McapMessage]:
    for offset, opcode, body in walk.data_records():
        yield from walk.messages_of(offset, opcode, body)


def _log_time_order(walk: _Walk) -> Iterator[McapMessage]:
    """Messages by log time, ties in file order: a record's messages wait in a heap until no record
    still unread can hold an earlier one. Records are read in file order, so every channel is known
    before its messages; at damage, the messages already read come out (in order) before the error."""
    earliest = walk.earliest_log_times()
    earliest_unread = earliest + [2**64]  # earliest_unread[k]: the earliest time records k.. can hold
    for k in range(len(earliest) - 1, -1, -1):
        earliest_unread[k] = min(earliest_unread[k], earliest_unread[k + 1])
    waiting: list[tuple[int, int, int, McapMessage]] = []  # (log time, record offset, index in record, message)
    records_read = 0
    try:
        for offset, opcode, body in walk.data_records():
            for index, message in enumerate(walk.messages_of(offset, opcode, body)):
                heapq.heappush(waiting, (message.log_time_ns, offset, index, message))
            if opcode in (_OP_CHUNK, _OP_MESSAGE):
                records_read += 1
            bound = earliest_unread[min(records_read, len(earliest))]
            while waiting and waiting[0][0] <= bound:
                yield heapq.heappop(waiting)[3]
    except McapDamageError:
        while waiting:
            yield heapq.heappop(waiting)[3]
        raise
    while waiting:
        yield heapq.heappop(waiting)[3]


def read_mcap(path: str | os.PathLike[str], *, log_time_order: bool = False) -> Iterator[McapMessage]:
    """Every message of the MCAP file ``path``, in file order or (``log_time_order``) by log time.

    Damage (truncation anywhere before the summary, corrupt record framing, a chunk that does not
    decompress or fails its CRC, a message on an unknown channel) raises :class:`McapDamageError`
    once every message read before it has been yielded.
    """
    path = Path(path)
    with path.open("rb") as stream:
        walk = _Walk(path, stream)
        yield from (_log_time_order(walk) if log_time_order else _file_order(walk))


def summary_channel_types(path: str | os.PathLike[str]) -> dict[str, str]:
    """``topic -> pkg/msg/Name`` of every channel with a schema that the file's summary lists.

    Empty when the file has no summary or a damaged one (a cut recording): the channels are then
    only learnt while reading the messages.
    """
    with Path(path).open("rb") as stream:
        size = os.fstat(stream.fileno()).st_size
        tail = _FOOTER.size + len(MCAP_MAGIC)
        if size < len(MCAP_MAGIC) + tail:
            return {}
        stream.seek(size - tail)
        footer = stream.read(tail)
        opcode, length, summary_start, _, _ = _FOOTER.unpack_from(footer)
        if footer[_FOOTER.size :] != MCAP_MAGIC or opcode != _OP_FOOTER or length != _FOOTER_BODY_LENGTH:
            return {}
        if not len(MCAP_MAGIC) <= summary_start <= size - tail:
            return {}
        stream.seek(summary_start)
        summary = stream.read(size - tail - summary_start)
    schemas: dict[int, str] = {}
    channels: list[tuple[int, str]] = []
    position = 0
    try:
        while position < len(summary):
            if position + _RECORD_HEAD.size > len(summary):
                return {}
            opcode, length = _RECORD_HEAD.unpack_from(summary, position)
            body_start = position + _RECORD_HEAD.size
            if body_start + length > len(summary):
                return {}
            body = summary[body_start : body_start + length]
            if opcode == _OP_SCHEMA:
                schema_id, name = _schema_record(body)
                schemas[schema_id] = name
            elif opcode == _OP_CHANNEL:
                _, schema_id, topic, _ = _channel_record(body)
                channels.append((schema_id, topic))
            position = body_start + length
    except ValueError:
        return {}
    return {topic: ros2_type_name(schemas[schema_id]) for schema_id, topic in channels if schema_id in schemas}


class McapWriter:
    """Append CDR messages to an MCAP file with their ROS 2 schemas, never more than
    ``flush_interval_s`` behind.

    Crash safety: messages gather in a chunk in memory, and the chunk is closed and handed to the
    OS (written and flushed) at least every ``flush_interval_s`` seconds (1 s by default) by a
    background thread, as well as whenever it reaches ``chunk_size`` bytes. A writer killed at any
    moment (SIGKILL, the OOM killer) therefore leaves a file without a summary whose complete
    chunks hold every message written up to ``flush_interval_s`` before the kill, and
    :func:`read_mcap` reads them back (then reports the cut).

    fsync policy: the same thread ``os.fsync``-s the file after each periodic flush that wrote
    something, outside the lock writers take (a callback never waits on the disk), and
    :meth:`close` fsyncs once more after the summary; so a power loss, too, costs at most about
    ``flush_interval_s`` of messages on a disk that honours fsync.

    Schemas come from the rosbags typestore (:func:`gldt_core.io.ros_types.typestore`: stock
    Jazzy types and ``gldt_msgs``).
    """

    def __init__(
        self, path: str | os.PathLike[str], chunk_size: int = 256 * 1024, flush_interval_s: float = 1.0
    ) -> None:
        from mcap.writer import CompressionType, Writer

        if not flush_interval_s > 0:
            raise ValueError(f"flush_interval_s must be positive, got {flush_interval_s}")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._stream = self.path.open("wb")
        self._writer = Writer(self._stream, chunk_size=chunk_size, compression=CompressionType.NONE)
        self._writer.start(profile="ros2", library="gldt")
        self._stream.flush()
        self._channels: dict[str, int] = {}
        self._lock = threading.Lock()
        self.count = 0
        self.flush_interval_s = flush_interval_s
        self._flushed_count = 0
        self._closing = threading.Event()
        self._flusher = threading.Thread(target=self._flush_periodically, name="gldt-mcap-flush", daemon=True)
        self._flusher.start()

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
        """Write one message (``msgtype`` is ``pkg/msg/Name``); thread-safe (callbacks may run on
        several threads)."""
        with self._lock:
            if self._stream.closed:
                raise ValueError(f"{self.path}: the recording is closed")
            channel = self._channel(topic, msgtype)
            self._writer.add_message(
                channel_id=channel,
                log_time=log_time_ns,
                publish_time=log_time_ns,
                data=bytes(data),
                sequence=self.count,
            )
            self.count += 1

    def flush(self, sync: bool = True) -> bool:
        """Close the chunk in progress and hand it to the OS (``sync``: and fsync it); whether
        anything was new since the last flush."""
        with self._lock:
            if self._stream.closed or self.count == self._flushed_count:
                return False
            self._writer.flush()  # closes the chunk, writes it and its message index, flushes the stream
            self._flushed_count = self.count
            descriptor = self._stream.fileno()
        if sync:
            try:
                os.fsync(descriptor)
            except OSError:
                pass  # closed meanwhile (close fsyncs itself) or a file system without fsync
        return True

    def _flush_periodically(self) -> None:
        while not self._closing.wait(self.flush_interval_s):
            self.flush()

    def close(self) -> None:
        """Write the summary and footer and fsync (idempotent)."""
        self._closing.set()
        if self._flusher.is_alive() and self._flusher is not threading.current_thread():
            self._flusher.join()
        with self._lock:
            if not self._stream.closed:
                self._writer.finish()
                self._stream.flush()
                os.fsync(self._stream.fileno())
                self._stream.close()
