"""MCAP logs: replay the `event_camera_msgs/msg/EventPacket` channels (evt3, mono) of an MCAP file —
evstream's archives and other tools' recordings (`ros2 bag record` with the mcap storage, Foxglove).

The file is read front to back as a stream (no index needed), so a file whose writer was killed — no
summary, no footer, maybe half a chunk at the end — replays up to its last complete chunk; a
`TruncatedFileWarning` says how many messages and events were recovered and where reading stopped.

Which channels: `topic=` names one. Otherwise, in an evstream archive, the event topics of its camera
(`/<camera>/events` and, when kept, `/<camera>/events/noise/<class>`) merged back into one stream with
each event's noise class in `cls`; in any other file, the first EventPacket channel (others are
skipped, with a warning naming them). Packets are decoded as `evstream.codecs.packets` describes.
"""

from __future__ import annotations

import builtins
import json
import os
import warnings
from collections.abc import Iterator

import numpy as np
from mcap.records import Channel, Chunk, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk

from evstream.codecs.event_packet import DATATYPE, PacketError, decode_packet
from evstream.codecs.packets import PacketDecoder
from evstream.events import EventChunk, EventError, Geometry, NoiseClass, Validator, counted

from ._base import MAX_SENSOR_SIDE, EventWarning

NAME = "MCAP (ROS 2 EventPacket)"
FORMAT = "mcap"
MAGIC = b"\x89MCAP0\r\n"
DEFAULT_CHUNK_EVENTS = 50_000
PACKET_DATATYPES = (DATATYPE, "event_camera_msgs/EventPacket")
# channel metadata written by sinks.mcap_sink (kept here too: sources do not import sinks)
META_CLASS = "evstream.noise_class"
META_PACKET_US = "evstream.packet_us"
META_TIME_BASE = "evstream.time_base"
_CLASS_CODES = {"signal": NoiseClass.SIGNAL, "background": NoiseClass.BACKGROUND, "hot_pixel": NoiseClass.HOT_PIXEL}


class TruncatedFileWarning(EventWarning):
    """The file ends early or is damaged: what came before was recovered."""


def probe(head: bytes, path: str) -> bool:
    return head.startswith(MAGIC)


class _Scan:
    """Counts and the place reading stopped, shared by one pass over the file."""

    def __init__(self):
        self.messages = 0
        self.stopped_at: int | None = None
        self.reason = ""
        self.fraction = 0.0  # bytes read / file size


class _Clamped:
    """A file whose `read(n)` asks for no more than the bytes left: a file object allocates the n bytes
    it is asked for before reading, and the mcap reader passes lengths from the file (a damaged string
    length asked for 3 GB from a 5 KB file)."""

    def __init__(self, f, size: int):
        self.f = f
        self.size = size

    def read(self, n: int = -1) -> bytes:
        if n is None or n < 0:
            return self.f.read()
        return self.f.read(max(0, min(n, self.size - self.f.tell())))

    def __getattr__(self, name):
        return getattr(self.f, name)


def _records(path: str, scan: _Scan) -> Iterator:
    """Every record of the file in order, chunks opened; stops (recording where and why) at damage."""
    with builtins.open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        reader = StreamReader(_Clamped(f, size), emit_chunks=True, record_size_limit=max(size, 1))
        it = iter(reader.records)
        while True:
            offset = f.tell()
            try:
                rec = next(it)
                scan.fraction = f.tell() / max(1, size)
            except StopIteration:
                return
            except Exception as e:  # mcap raises several kinds at a cut record: EndOfFile, struct.error, ...
                if offset <= 8:
                    raise EventError(f"{path}: not a readable MCAP file: {type(e).__name__}: {e}") from None
                scan.stopped_at, scan.reason = offset, _reason(e)
                return
            if isinstance(rec, Chunk):
                try:
                    _check_chunk_size(rec)
                    inner = breakup_chunk(rec, validate_crc=True)
                except Exception as e:  # a damaged chunk: zstd, lz4 or CRC errors
                    if f.tell() < size:  # the file goes on: damage in the middle, not a writer cut short
                        raise EventError(f"{path} at byte {offset}: damaged MCAP chunk ({_reason(e)}) with "
                                         f"{size - f.tell()} more bytes after it; `mcap recover` rewrites "
                                         "the file without it") from None
                    scan.stopped_at, scan.reason = offset, _reason(e)
                    return
                yield from inner
            else:
                yield rec


# A chunk's claimed size is allocated before it is inflated: a claim is held to what its bytes can hold.
# Writers close chunks at about 1 MiB (mcap's default) to 4 MiB (ours) plus one message; zstd packs a
# run of one byte about 32,000:1, so only a claim past both bounds is refused as damaged.
MAX_CHUNK_BYTES = 64 << 20
MAX_CHUNK_RATIO = 32_768


def _check_chunk_size(rec: Chunk) -> None:
    if rec.uncompressed_size > max(MAX_CHUNK_BYTES, MAX_CHUNK_RATIO * len(rec.data)):
        raise ValueError(f"its {counted(len(rec.data), 'compressed byte')} claim "
                         f"{counted(rec.uncompressed_size, 'byte')}")


def _reason(e: Exception) -> str:
    text = str(e) or type(e).__name__
    return "the file ends inside a record" if type(e).__name__ == "EndOfFile" else text


class McapLogSource:
    """Replays EventPackets from an MCAP file in chunks of about `chunk_events` events.

    `timestamps` is the policy for times that go back (a camera's EVT3 may step back a little; the
    default sorts within a chunk, as the RAW reader does); evstream's archives never go back."""

    format = FORMAT

    def __init__(self, path, topic: str | None = None, geometry: Geometry | None = None,
                 timestamps: str = "sort", chunk_events: int = DEFAULT_CHUNK_EVENTS):
        self.path = os.fspath(path)
        self.topic = topic
        self.timestamps = timestamps
        self.chunk_events = int(chunk_events)
        if self.chunk_events <= 0:
            raise ValueError("chunk_events must be positive")
        self.meta: dict = {}
        self._scan: _Scan | None = None
        self.truncated = False
        self.recovered_messages = 0
        self.recovered_events = 0
        self.counters: dict = {}
        self._selected: dict[int, NoiseClass | None] | None = None
        first = self._first_packet()
        self.archive = bool(self._selected) and all(c is not None for c in self._selected.values())
        self.has_labels = False
        if geometry is None:
            if first.width == 0 or first.height == 0:
                raise EventError(f"{self.path}: the EventPackets carry no sensor size (width/height 0); "
                                 "pass a geometry")
            if max(first.width, first.height) > MAX_SENSOR_SIDE:
                raise EventError(f"{self.path}: the EventPackets claim a {first.width}x{first.height} sensor, larger "
                                 f"than any event camera ({MAX_SENSOR_SIDE} a side); pass a geometry if it is real")
            geometry = Geometry(first.width, first.height)
        self.geometry = geometry

    # -- channel selection ---------------------------------------------------------------------------------
    def _select(self, ch: Channel, schemas: dict[int, Schema], selected: dict, skipped: set) -> None:
        schema = schemas.get(ch.schema_id)
        if schema is None or schema.name not in PACKET_DATATYPES or ch.message_encoding != "cdr":
            return
        if self.topic is not None:
            if ch.topic == self.topic:
                selected[ch.id] = _CLASS_CODES.get(ch.metadata.get(META_CLASS, ""))
            return
        cls = _CLASS_CODES.get(ch.metadata.get(META_CLASS, ""))
        ours = [c for c in selected.values() if c is not None]
        if not selected:
            selected[ch.id] = cls
            self._camera = _camera_of(ch.topic)
        elif cls is not None and ours and _camera_of(ch.topic) == self._camera:
            selected[ch.id] = cls
        else:
            skipped.add(ch.topic)

    def _first_packet(self):
        """Read up to the first selected packet: channels, evstream metadata, the sensor size."""
        scan = self._scan = _Scan()
        schemas: dict[int, Schema] = {}
        selected: dict[int, NoiseClass | None] = {}
        skipped: set[str] = set()
        for rec in _records(self.path, scan):
            if isinstance(rec, Schema):
                schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                self._select(rec, schemas, selected, skipped)
            elif isinstance(rec, Metadata) and rec.name == "evstream":
                self.meta = dict(rec.metadata)
            elif isinstance(rec, Message) and rec.channel_id in selected:
                self._selected = selected
                return self._decode(rec, 0)
        what = f"topic {self.topic!r}" if self.topic else "event_camera_msgs/msg/EventPacket channel"
        where = (f" before the file breaks off at byte {scan.stopped_at} ({scan.reason})" if scan.stopped_at is not None
                 else "")
        raise EventError(f"{self.path}: no {what} with messages{where}")

    def _decode(self, msg: Message, offset: int):
        try:
            return decode_packet(msg.data)
        except PacketError as e:
            raise EventError(f"{self.path}: message {offset} (channel {msg.channel_id}, log time "
                             f"{msg.log_time} ns): {e}") from None

    # -- reading ----------------------------------------------------------------------------------------------
    def set_time_range(self, start_us: int | None, end_us: int | None) -> bool:
        """Skip the packets before `start_us` undecoded where the file says where their events lie: evstream
        archives place each packet by its time base (its first event) in one cell of a `packet_us` grid,
        so a packet whose cell ends at or before `start_us` holds nothing in the range. Other files' EVT3
        packets are one stateful stream (each needs the ones before it): read from the start, as are
        the records themselves (the file is read front to back, so a cut file still replays)."""
        self._seek_us = start_us
        return start_us is not None and self.archive

    def info(self) -> dict:
        return {"format": self.format, "path": self.path, "meta": self.meta, "archive": self.archive,
                "truncated": self.truncated, "recovered_messages": self.recovered_messages}

    @property
    def fraction_read(self) -> float | None:
        """How far into the file reading has got (0..1), once iteration started."""
        return None if self._scan is None else self._scan.fraction

    def __iter__(self) -> Iterator[EventChunk]:
        scan = self._scan = _Scan()
        schemas: dict[int, Schema] = {}
        selected: dict[int, NoiseClass | None] = {}
        skipped: set[str] = set()
        absolute: dict[int, bool] = {}
        decoders: dict[int, PacketDecoder] = {}
        packet_us = {}
        merge = _Merger(self)
        check = Validator(self.geometry, self.path, self.timestamps)
        self.recovered_messages = self.recovered_events = 0
        n_msg = 0
        seek = getattr(self, "_seek_us", None)
        for rec in _records(self.path, scan):
            if isinstance(rec, Schema):
                schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                if rec.id not in selected:
                    self._select(rec, schemas, selected, skipped)
                    if rec.id in selected:
                        absolute[rec.id] = rec.metadata.get(META_TIME_BASE) == "first_event_ns"
                        decoders[rec.id] = PacketDecoder(absolute=absolute[rec.id])
                        packet_us[rec.id] = int(rec.metadata.get(META_PACKET_US, "0") or 0)
            elif isinstance(rec, Message):
                n_msg += 1
                if rec.channel_id not in selected:
                    continue
                packet = self._decode(rec, n_msg - 1)
                cell_us = packet_us[rec.channel_id]
                if (seek is not None and absolute[rec.channel_id] and cell_us > 0
                        and (packet.time_base // 1000 // cell_us + 1) * cell_us <= seek):
                    continue  # the packet's grid cell ends before the range: its events are not decoded
                try:
                    t, x, y, p = decoders[rec.channel_id].decode(packet)
                except PacketError as e:
                    raise EventError(f"{self.path}: message {n_msg - 1} on channel {rec.channel_id}: {e}") from None
                self.recovered_messages += 1
                self.recovered_events += len(t)
                cls = selected[rec.channel_id]
                for chunk in merge.add(t, x, y, p, cls, cell_us):
                    yield check(chunk)
        for chunk in merge.finish():
            yield check(chunk)
        self.counters = {}
        for d in decoders.values():
            for k, v in d.counters.items():
                self.counters[k] = self.counters.get(k, 0) + v
        if skipped:
            warnings.warn(f"{self.path}: skipped other EventPacket channels {sorted(skipped)} "
                          "(choose one with topic=)", EventWarning, stacklevel=2)
        if scan.stopped_at is not None:
            self.truncated = True
            warnings.warn(
                f"{self.path}: stopped at byte {scan.stopped_at} ({scan.reason}); recovered "
                f"{counted(self.recovered_messages, 'event packet')} "
                f"({counted(self.recovered_events, 'event')}) before it",
                TruncatedFileWarning, stacklevel=2)


def _camera_of(topic: str) -> str:
    """The camera part of an evstream event topic (`/<camera>/events[/noise/<class>]`)."""
    parts = topic.strip("/").split("/")
    return parts[0] if parts else ""


class _Merger:
    """Puts packets back into one stream: evstream archives cell by cell (classes merged by time, `cls`
    set), other files packet by packet; yields chunks of about `chunk_events` events."""

    def __init__(self, source: McapLogSource):
        self.source = source
        self.cell: int | None = None
        self.cell_parts: list = []  # (t, x, y, p, cls) of the cell being read
        self.out: list = []  # released parts waiting to fill a chunk
        self.n_out = 0
        classes = set((source._selected or {}).values())
        # an archive's classes come back in `cls` (a lone noise topic too); a lone signal topic has none
        self.with_cls = source.archive and classes != {NoiseClass.SIGNAL}

    def add(self, t, x, y, p, cls, cell_us: int) -> Iterator[EventChunk]:
        if not len(t):
            return
        c = np.full(len(t), 0 if cls is None else int(cls), np.uint8)
        if self.with_cls and cell_us > 0:
            cell = int(t[0]) // cell_us
            if self.cell is not None and cell != self.cell:
                yield from self._release(cell * cell_us)
            self.cell = cell
            self.cell_parts.append((t, x, y, p, c))
            return
        self.out.append((t, x, y, p, c))
        self.n_out += len(t)
        if self.n_out >= self.source.chunk_events:
            yield self._chunk(int(t[-1]))

    def _release(self, watermark: int) -> Iterator[EventChunk]:
        parts = self.cell_parts
        self.cell_parts = []
        if len(parts) == 1:
            merged = parts[0]
        else:
            cat = [np.concatenate([q[k] for q in parts]) for k in range(5)]
            order = np.argsort(cat[0], kind="stable")  # by time; equal times: signal, background, hot
            merged = tuple(a[order] for a in cat)
        self.out.append(merged)
        self.n_out += len(merged[0])
        if self.n_out >= self.source.chunk_events:
            yield self._chunk(watermark)

    def _chunk(self, t_end: int) -> EventChunk:
        parts = self.out
        self.out, self.n_out = [], 0
        arrays = [np.concatenate([q[k] for q in parts]) if len(parts) > 1 else parts[0][k] for k in range(5)]
        t_end = max(t_end, int(arrays[0][-1]))
        return EventChunk.from_arrays(*arrays[:4], self.source.geometry,
                                      cls_=arrays[4] if self.with_cls else None, t_end=t_end)

    def finish(self) -> Iterator[EventChunk]:
        if self.cell_parts:
            yield from self._release(np.iinfo(np.int64).min)
        if self.out:
            yield self._chunk(np.iinfo(np.int64).min)


def open(path, **options) -> McapLogSource:  # noqa: A001 - the format-module interface
    return McapLogSource(path, **options)


def read_metadata(path) -> dict[str, dict[str, str]]:
    """Every metadata record of the file by name (an archive's `evstream` provenance and `evstream.stats`)."""
    out: dict[str, dict[str, str]] = {}
    for rec in _records(os.fspath(path), _Scan()):
        if isinstance(rec, Metadata):
            out[rec.name] = dict(rec.metadata)
    return out


def provenance(path) -> dict:
    """The archive's `evstream` metadata with JSON values decoded where they are JSON."""
    out = {}
    for k, v in read_metadata(path).get("evstream", {}).items():
        try:
            out[k] = json.loads(v)
        except ValueError:
            out[k] = v
    return out
