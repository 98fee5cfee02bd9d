"""ROS 2 `event_camera_msgs/msg/EventPacket` <-> CDR bytes, in plain Python (one packet format for MCAP and Zenoh).

The message (event_camera_msgs, ROS 2):

    std_msgs/Header header   # builtin_interfaces/Time stamp (int32 sec, uint32 nanosec), string frame_id
    uint32 height
    uint32 width
    uint64 seq               # sequence number, to detect lost packets
    uint64 time_base         # ns; meaning depends on the encoding (see `evstream.codecs.packets`)
    string encoding          # "evt3", "mono", ...
    bool is_bigendian
    uint8[] events           # the encoded events

Serialized as ROS 2 does (XCDR1, "plain CDR"): a 4-byte encapsulation header (0x00 0x01 little-endian,
0x00 0x00 big-endian) then the fields, each aligned to its own size (8 for uint64) counted from the end
of the header; strings are a uint32 length including a terminating NUL, then the bytes and the NUL.
Decoding checks every length against the bytes that remain before slicing anything, so a malformed or
hostile packet gives a `PacketError` naming the field and byte offset, never a huge allocation.
"""

from __future__ import annotations

import functools
import struct
from dataclasses import dataclass

from ..events import EventError, shown

__all__ = ["DATATYPE", "HEADER_MSGDEFS", "MAX_PACKET_BYTES", "MSGDEF", "EventPacket", "PacketError", "decode_packet",
           "encode_packet"]

DATATYPE = "event_camera_msgs/msg/EventPacket"

# The dependencies every message with a `std_msgs/Header` carries in its ros2msg schema text.
HEADER_MSGDEFS = """\
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""

# The ROS 2 message definition text (ros2msg schema encoding) with its dependencies, as `ros2 bag` stores it.
MSGDEF = """\
std_msgs/Header header
uint32 height
uint32 width
uint64 seq
uint64 time_base
string encoding
bool is_bigendian
uint8[] events
""" + HEADER_MSGDEFS

MAX_PACKET_BYTES = 1 << 30  # a packet larger than 1 GiB is refused before anything is allocated
MAX_STRING_BYTES = 1 << 16  # frame_id and encoding are short names
_NS = 1_000_000_000
_CDR_BE, _CDR_LE = 0, 1


class PacketError(EventError):
    """Bytes that are not a well-formed EventPacket (names the field and byte offset)."""


@dataclass(frozen=True)
class EventPacket:
    """One EventPacket. `stamp_ns` is the header stamp in ns (sec·1e9 + nanosec); `events` the payload."""

    events: bytes
    encoding: str = "evt3"
    width: int = 0
    height: int = 0
    seq: int = 0
    time_base: int = 0
    stamp_ns: int = 0
    frame_id: str = ""
    is_bigendian: bool = False

    @property
    def stamp(self) -> tuple[int, int]:
        """The header stamp as (sec, nanosec), nanosec in 0..1e9-1 (sec negative before the epoch)."""
        return divmod(int(self.stamp_ns), _NS)


def _check_uint(name: str, value, bits: int) -> int:
    v = int(value)
    if not 0 <= v < (1 << bits):
        raise PacketError(f"EventPacket.{name} = {shown(value)} does not fit uint{bits}")
    return v


def _string(name: str, s: str) -> bytes:
    raw = s.encode("utf-8")
    if b"\x00" in raw:
        raise PacketError(f"EventPacket.{name} contains a NUL character")
    if len(raw) >= MAX_STRING_BYTES:
        raise PacketError(f"EventPacket.{name} is {len(raw)} bytes long; the limit is {MAX_STRING_BYTES - 1}")
    return raw + b"\x00"


def _pad(offset: int, size: int) -> int:
    """Padding bytes to align body `offset` (counted after the 4-byte header) to `size`."""
    return -offset % size


@functools.lru_cache(maxsize=256)
def _layout(frame_id: str, encoding: str, big_endian: bool) -> tuple[struct.Struct, bytes, bytes]:
    """The packet's CDR up to its payload as one struct, with the NUL-terminated strings it carries: the
    strings set every offset and padding, so each (frame_id, encoding) has one layout (a packet then
    costs one pack, not a dozen small ones)."""
    fid = _string("frame_id", frame_id)
    enc = _string("encoding", encoding)
    off = 12 + len(fid)  # body offset (counted after the 4-byte header): stamp (8) + length (4) + frame_id
    pad1 = _pad(off, 4)
    off += pad1 + 8  # height, width
    pad2 = _pad(off, 8)
    off += pad2 + 20 + len(enc) + 1  # seq, time_base, length, encoding, is_bigendian
    pad3 = _pad(off, 4)
    e = ">" if big_endian else "<"
    return struct.Struct(f"{e}4siiI{len(fid)}s{pad1}xII{pad2}xQQI{len(enc)}sB{pad3}xI"), fid, enc


def encode_packet(packet: EventPacket, *, big_endian: bool = False) -> bytes:
    """CDR bytes of `packet` (little-endian encapsulation unless `big_endian`)."""
    sec, nanosec = packet.stamp
    if not -(1 << 31) <= sec < (1 << 31):
        raise PacketError(f"EventPacket.stamp_ns = {packet.stamp_ns} is outside the int32 seconds range")
    events = memoryview(packet.events).cast("B")
    if len(events) > MAX_PACKET_BYTES:
        raise PacketError(f"EventPacket.events is {len(events)} bytes; the limit is {MAX_PACKET_BYTES}")
    layout, fid, enc = _layout(packet.frame_id, packet.encoding, big_endian)
    head = layout.pack(bytes((0, 0 if big_endian else 1, 0, 0)), sec, nanosec, len(fid), fid,
                       _check_uint("height", packet.height, 32), _check_uint("width", packet.width, 32),
                       _check_uint("seq", packet.seq, 64), _check_uint("time_base", packet.time_base, 64),
                       len(enc), enc, 1 if packet.is_bigendian else 0, len(events))
    return head + events


class _Reader:
    """Bounds-checked reads of CDR fields; every error names the field and the byte offset."""

    __slots__ = ("buf", "pos", "e")

    def __init__(self, buf: memoryview, little_endian: bool):
        self.buf = buf
        self.pos = 4
        self.e = "<" if little_endian else ">"

    def _need(self, n: int, what: str) -> None:
        if n > len(self.buf) - self.pos:
            raise PacketError(
                f"EventPacket truncated: {what} needs {n} bytes at offset {self.pos}, "
                f"{len(self.buf) - self.pos} remain (packet of {len(self.buf)} bytes)"
            )

    def align(self, size: int) -> None:
        self.pos += _pad(self.pos - 4, size)

    def scalar(self, fmt: str, size: int, what: str):
        if size > 1:
            self.align(size)
        self._need(size, what)
        (v,) = struct.unpack_from(self.e + fmt, self.buf, self.pos)
        self.pos += size
        return v

    def string(self, what: str) -> str:
        n = self.scalar("I", 4, f"the length of {what}")
        if n == 0 or n > MAX_STRING_BYTES:
            raise PacketError(f"EventPacket {what}: bad string length {n} at offset {self.pos - 4}")
        self._need(n, what)
        raw = bytes(self.buf[self.pos : self.pos + n])
        if raw[-1] != 0:
            raise PacketError(f"EventPacket {what}: string at offset {self.pos} lacks its terminating NUL")
        self.pos += n
        try:
            return raw[:-1].decode("utf-8")
        except UnicodeDecodeError:
            raise PacketError(f"EventPacket {what}: not UTF-8 at offset {self.pos - n}") from None


def decode_packet(data, *, max_bytes: int = MAX_PACKET_BYTES) -> EventPacket:
    """An `EventPacket` from CDR bytes (bytes, bytearray or memoryview); `PacketError` if malformed."""
    buf = memoryview(data).cast("B")
    if len(buf) > max_bytes:
        raise PacketError(f"EventPacket of {len(buf)} bytes exceeds the limit of {max_bytes}")
    if len(buf) < 4:
        raise PacketError(f"EventPacket of {len(buf)} bytes is shorter than its 4-byte CDR header")
    kind = buf[1]
    if buf[0] != 0 or kind not in (_CDR_BE, _CDR_LE):
        raise PacketError(f"EventPacket: unsupported CDR encapsulation {bytes(buf[:2]).hex()} "
                          "(plain CDR 0000 or 0001 expected)")
    r = _Reader(buf, kind == _CDR_LE)
    sec = r.scalar("i", 4, "header.stamp.sec")
    nanosec = r.scalar("I", 4, "header.stamp.nanosec")
    if nanosec >= _NS:
        raise PacketError(f"EventPacket header.stamp.nanosec = {nanosec} at offset {r.pos - 4} is not < 1e9")
    frame_id = r.string("header.frame_id")
    height = r.scalar("I", 4, "height")
    width = r.scalar("I", 4, "width")
    seq = r.scalar("Q", 8, "seq")
    time_base = r.scalar("Q", 8, "time_base")
    encoding = r.string("encoding")
    flag = r.scalar("B", 1, "is_bigendian")
    if flag > 1:
        raise PacketError(f"EventPacket is_bigendian = {flag} at offset {r.pos - 1} is not a bool")
    n = r.scalar("I", 4, "the length of events")
    r._need(n, "events")
    events = bytes(buf[r.pos : r.pos + n])
    return EventPacket(events=events, encoding=encoding, width=width, height=height, seq=seq,
                       time_base=time_base, stamp_ns=sec * _NS + nanosec, frame_id=frame_id,
                       is_bigendian=bool(flag))
