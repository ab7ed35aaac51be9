"""Raw CDR messages: what can be read from their bytes without deserialising them.

A player and a recorder handle messages as the CDR bytes :mod:`gldt_core.io.mcap_file` reads and
writes; deserialising a full image only to learn its stamp would cost a copy of every frame.
"""

from __future__ import annotations

import struct

#: Bytes before ``header.stamp`` in a CDR message: the 4-byte encapsulation header (its second
#: byte says the byte order).
ENCAPSULATION_SIZE = 4
_LITTLE_ENDIAN_KINDS = (0x01, 0x03)  # CDR_LE, PL_CDR_LE


def _stamp_format(cdr: bytes) -> str:
    """The ``struct`` format of ``header.stamp`` (``int32 sec, uint32 nanosec``) in this message's
    byte order; ValueError when the message is too short to hold a header."""
    if len(cdr) < ENCAPSULATION_SIZE + 8:
        raise ValueError(f"CDR message of {len(cdr)} bytes is too short to hold a header")
    return "<iI" if cdr[1] in _LITTLE_ENDIAN_KINDS else ">iI"


def header_stamp_ns(cdr: bytes) -> int:
    """``header.stamp`` [ns] of a CDR message whose first field is a ``std_msgs/Header`` (images,
    camera_info, every ``gldt_msgs`` array)."""
    seconds, nanoseconds = struct.unpack_from(_stamp_format(cdr), cdr, ENCAPSULATION_SIZE)
    return seconds * 1_000_000_000 + nanoseconds


def header_frame_id(cdr: bytes) -> str:
    """``header.frame_id`` of a CDR message whose first field is a ``std_msgs/Header``."""
    _, start, length = _frame_id_span(cdr)
    return cdr[start : start + length - 1].decode("utf-8", errors="replace")


def _frame_id_span(cdr: bytes) -> tuple[str, int, int]:
    """``(byte order, offset of header.frame_id's characters, their count with the terminating
    NUL)`` of such a message; ValueError when it ends before them."""
    order = _stamp_format(cdr)[0]
    start = ENCAPSULATION_SIZE + 8
    if len(cdr) < start + 4:
        raise ValueError(f"CDR message of {len(cdr)} bytes is too short to hold a header")
    (length,) = struct.unpack_from(order + "I", cdr, start)
    if length == 0 or len(cdr) < start + 4 + length:
        raise ValueError(f"CDR message of {len(cdr)} bytes ends inside its header's frame_id")
    return order, start + 4, length


def with_header_stamp(cdr: bytes, stamp_ns: int) -> bytes:
    """Copy of such a message with ``header.stamp`` replaced, patched in the bytes (no
    deserialisation of the image it may carry)."""
    seconds, nanoseconds = divmod(int(stamp_ns), 1_000_000_000)
    patched = bytearray(cdr)
    struct.pack_into(_stamp_format(cdr), patched, ENCAPSULATION_SIZE, seconds, nanoseconds)
    return bytes(patched)


def after_header_fields(cdr: bytes, fmt: str) -> tuple[int | float, ...]:
    """The fields right after the ``std_msgs/Header`` of a CDR message, as ``struct`` format
    ``fmt`` without byte order (e.g. ``"QB"``: a ``uint64`` then a ``uint8``, as ``TrackArray``'s
    ``frame_index`` and ``source``), each aligned as CDR aligns it (to its own size, counted from
    the end of the encapsulation header); ValueError when the message is too short."""
    order, start, length = _frame_id_span(cdr)
    offset = start + length - ENCAPSULATION_SIZE  # past the header: stamp, frame_id's length and characters
    values = []
    for code in fmt:
        size = struct.calcsize(code)
        offset += -offset % size
        if ENCAPSULATION_SIZE + offset + size > len(cdr):
            raise ValueError(f"CDR message of {len(cdr)} bytes ends inside its fields after the header")
        values.append(struct.unpack_from(order + code, cdr, ENCAPSULATION_SIZE + offset)[0])
        offset += size
    return tuple(values)
