"""The attachment beside each live EventPacket: sequence number and source time, in a fixed binary layout.

evstream's own (16 bytes, little-endian): `uint64 seq`, `int64 source_time_ns` (wall-clock ns when the
packet was published; latency = receive time - source time on one clock).

rmw_zenoh's (what a ROS 2 node publishing through rmw_zenoh_cpp attaches), written with Zenoh's
serializer: `int64 sequence_number`, `int64 source_timestamp` (ns), then the publisher GID as a
sequence: a LEB128 length (16 on Jazzy and later, 24 before) and that many bytes. Both are read here;
anything else is an `AttachmentError` (a caller may still use the packet and its CDR `seq`).
No pickle: plain `struct` on bytes, every length checked first.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from ..events import EventError

__all__ = ["OURS", "RMW_ZENOH", "Attachment", "AttachmentError", "decode_attachment", "encode_attachment",
           "encode_rmw_attachment"]

OURS = "evstream"
RMW_ZENOH = "rmw_zenoh"
_OURS = struct.Struct("<Qq")
_RMW_HEAD = struct.Struct("<qq")
MAX_GID_BYTES = 64


class AttachmentError(EventError):
    """An attachment that is neither evstream's nor rmw_zenoh's layout."""


@dataclass(frozen=True)
class Attachment:
    seq: int
    source_time_ns: int
    kind: str  # OURS or RMW_ZENOH
    gid: bytes = b""


def encode_attachment(seq: int, source_time_ns: int) -> bytes:
    """evstream's 16-byte attachment."""
    return _OURS.pack(int(seq), int(source_time_ns))


def encode_rmw_attachment(seq: int, source_time_ns: int, gid: bytes = bytes(16)) -> bytes:
    """rmw_zenoh's attachment (for tests and tools that speak to ROS 2 subscribers)."""
    if len(gid) >= 128:
        raise ValueError("gid too long for a one-byte LEB128 length")
    return _RMW_HEAD.pack(int(seq), int(source_time_ns)) + bytes((len(gid),)) + bytes(gid)


def _leb128(buf: bytes, pos: int) -> tuple[int, int]:
    value = shift = 0
    for i in range(pos, min(len(buf), pos + 10)):
        b = buf[i]
        value |= (b & 0x7F) << shift
        if not b & 0x80:
            return value, i + 1
        shift += 7
    raise AttachmentError(f"attachment: unterminated LEB128 length at byte {pos}")


def decode_attachment(buf: bytes) -> Attachment:
    """Read evstream's or rmw_zenoh's attachment, told apart by their sizes (16 vs 17 + GID bytes)."""
    n = len(buf)
    if n == _OURS.size:
        seq, t = _OURS.unpack(buf)
        return Attachment(seq, t, OURS)
    if n > _RMW_HEAD.size:
        seq, t = _RMW_HEAD.unpack_from(buf)
        gid_len, pos = _leb128(buf, _RMW_HEAD.size)
        if gid_len > MAX_GID_BYTES or pos + gid_len != n:
            raise AttachmentError(f"attachment of {n} bytes: GID length {gid_len} at byte 16 does not fit")
        if seq < 0:
            raise AttachmentError(f"attachment: negative sequence number {seq}")
        return Attachment(seq, t, RMW_ZENOH, bytes(buf[pos:]))
    raise AttachmentError(f"attachment of {n} bytes: neither evstream's (16) nor rmw_zenoh's layout")
