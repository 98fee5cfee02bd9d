"""MCAP sink: cleaned events, removed noise per class, frames and provenance in one MCAP file that ROS 2
(`ros2 bag`), Foxglove and Rerun open.

Channels (`<camera>` defaults to "camera"):

| topic                                   | schema (encoding)                              | what                    |
|-----------------------------------------|------------------------------------------------|-------------------------|
| `/<camera>/events`                      | event_camera_msgs/msg/EventPacket (ros2msg/cdr) | events classed SIGNAL   |
| `/<camera>/events/noise/background`     | same                                           | removed: background     |
| `/<camera>/events/noise/hot_pixel`      | same                                           | removed: hot pixels     |
| `/<camera>/frames`                      | foxglove.RawImage (protobuf), mono8            | frames (paper's look)   |
| `/<camera>/events/points`               | foxglove.PointCloud (protobuf)                 | X-Y-T points, `class`   |
| `/tf_static`                            | tf2_msgs/msg/TFMessage (ros2msg/cdr)           | `world` -> `<camera>`   |

The noise channels exist with `keep_noise`; the topic carries each event's noise class, so every event
and its class can be read back, and ROS 2 tools still see plain EventPackets. Packets hold the events of
one cell of a fixed event-time grid (`packet_us`, anchored at t = 0; at most `max_packet_events` per
packet), written cell by cell across all event topics, so a reader can merge the classes back into one
stream holding a single cell at a time. Metadata records: `evstream` (provenance: pipeline, source,
geometry, packet grid; at the start) and `evstream.stats` (run statistics; at the end).

3D viewers place a point cloud by its `frame_id` (the camera) in a tree of transforms: with points, the
archive carries a static identity transform `world` -> `<camera>` on `/tf_static`, as a ROS 2 system
publishes it; Foxglove and RViz take `world` as the fixed frame. Without it, Rerun 0.41's 3D view has
no path from "camera" to its root ("tf#/") and draws nothing. Rerun's loader puts an image of frame
`<camera>` in a frame `<camera>_image_plane` (the child of a camera calibration's pinhole; we have no
calibration), and one frame it cannot reach sends its 3D view back to "tf#/": with frames, a second
identity transform `<camera>` -> `<camera>_image_plane` connects it (other tools ignore the extra
frame). Points carry their class's colour (`red`, `green`, `blue`, `alpha`) beside `class`.

Crash safety: the archive is written beside its target (`OUT.mcap.part`, `safe_write`) and renamed onto
it when whole, so a failed run leaves an older `OUT.mcap` as it was. The first chunk (zstd) is closed as
soon as it holds a message, later ones every `chunk_bytes` of messages or `flush_s` seconds, whichever
comes first, each handed to the OS: a killed writer loses at most the last `flush_s` of messages, and
`sources.mcap_log` reads what came before from the `.part` file (it has no footer).
"""

from __future__ import annotations

import collections
import contextlib
import datetime
import importlib.metadata
import json
import re
import struct
import time
from typing import Any

import mcap.writer
import numpy as np
import zstandard
from evstream.sinks.colours import CLASS_COLOURS
from mcap.opcode import Opcode
from mcap.records import MessageIndex
from mcap.writer import CompressionType, Writer

from evstream.codecs.event_packet import DATATYPE, HEADER_MSGDEFS, MSGDEF, encode_packet
from evstream.codecs.packets import ENCODINGS, PacketEncoder
from evstream.events import N_CLASSES, EventChunk, EventError, Frame, Geometry, NoiseClass
from evstream.pipeline import Batch, RunStats
from evstream.safe_write import AtomicOutput

__all__ = ["META_CLASS", "META_PACKET_US", "META_TIME_BASE", "McapSink", "topics"]

# channel metadata keys (a reader tells our packets and their class by them)
META_CLASS = "evstream.noise_class"
META_PACKET_US = "evstream.packet_us"
META_TIME_BASE = "evstream.time_base"
TIME_BASE_FIRST_EVENT = "first_event_ns"

CLASS_NAMES = {NoiseClass.SIGNAL: "signal", NoiseClass.BACKGROUND: "background",
               NoiseClass.HOT_PIXEL: "hot_pixel"}
_CAMERA_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
_NEVER = 1 << 62  # mcap's own chunk_size: we close chunks ourselves
BULK_MCAP_VERSIONS = ("1.6.",)  # mcap releases whose Writer internals McapSink._add_packets knows
_MESSAGE_HEAD = struct.Struct("<BQHIQQ")  # an MCAP Message record up to its data: opcode, length, channel, seq, times


class _Zstd:
    """What mcap's writer calls to compress a chunk (`zstandard.compress`), at our level."""

    def __init__(self, level: int):
        self._compressor = zstandard.ZstdCompressor(level=level)

    def compress(self, data: bytes) -> bytes:
        return self._compressor.compress(data)


@contextlib.contextmanager
def _zstd_level(shim: _Zstd):
    """mcap's writer compresses chunks at zstd's default level 3 and has no setting for it; on EVT3 level 1
    runs about 6x faster for files about 2 % larger, which decides whether an archive keeps up with a
    camera. So our chunk closes (the only places mcap compresses, as we close every chunk ourselves) swap
    in a level-1 compressor for their duration."""
    saved = mcap.writer.zstandard
    mcap.writer.zstandard = shim
    try:
        yield
    finally:
        mcap.writer.zstandard = saved


def topics(camera: str = "camera") -> dict[str, str]:
    """Topic names by role: events, noise/background, noise/hot_pixel, frames, points."""
    return {
        "signal": f"/{camera}/events",
        "background": f"/{camera}/events/noise/background",
        "hot_pixel": f"/{camera}/events/noise/hot_pixel",
        "frames": f"/{camera}/frames",
        "points": f"/{camera}/events/points",
        "transforms": "/tf_static",
    }


def _file_descriptor_set(message_class) -> bytes:
    """The protobuf schema of `message_class` and its imports, as MCAP's protobuf profile wants it."""
    from google.protobuf.descriptor_pb2 import FileDescriptorSet

    fds = FileDescriptorSet()
    seen: set[str] = set()

    def add(fd) -> None:
        for dep in fd.dependencies:
            if dep.name not in seen:
                seen.add(dep.name)
                add(dep)
        fd.CopyToProto(fds.file.add())

    add(message_class.DESCRIPTOR.file)
    return fds.SerializeToString()


def render_mono8(frame: Frame) -> np.ndarray:
    """The paper's look as mono8 (H, W): 128 background, 255 where ON outnumber OFF, 0 where OFF do."""
    signed = frame.image
    out = np.full(signed.shape, 128, np.uint8)
    out[signed > 0] = 255
    out[signed < 0] = 0
    return out


FRAME_FORMATS = ("foxglove", "ros2")
IMAGE_DATATYPE = "sensor_msgs/msg/Image"
IMAGE_MSGDEF = """\
std_msgs/Header header
uint32 height
uint32 width
string encoding
uint8 is_bigendian
uint32 step
uint8[] data
""" + HEADER_MSGDEFS


def ros2_image(img: np.ndarray, stamp_ns: int, frame_id: str) -> bytes:
    """ROS 2 `sensor_msgs/msg/Image` in little-endian CDR: frames `ros2 bag play` can republish.

    A gray (H, W) picture goes out as rgb8 (three equal channels; zstd takes the repeat back): Rerun's
    loader shows a mono8 Image as a depth map, rgb8 as a picture."""
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    h, w, _ = img.shape
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    fid = frame_id.encode() + b"\x00"
    head = struct.pack("<4siiI", b"\x00\x01\x00\x00", sec, nanosec, len(fid)) + fid
    head += b"\x00" * (-(len(head) - 4) % 4) + struct.pack("<III", h, w, 5) + b"rgb8\x00"
    head += b"\x00"  # is_bigendian
    head += b"\x00" * (-(len(head) - 4) % 4) + struct.pack("<II", 3 * w, 3 * h * w)
    return head + np.ascontiguousarray(img, np.uint8).tobytes()


WORLD_FRAME = "world"
TF_DATATYPE = "tf2_msgs/msg/TFMessage"
_SEP = "=" * 80 + "\n"
TF_MSGDEF = (
    "geometry_msgs/TransformStamped[] transforms\n"
    + _SEP + "MSG: geometry_msgs/TransformStamped\nstd_msgs/Header header\nstring child_frame_id\nTransform transform\n"
    + _SEP + "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
    + _SEP + "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"
    + _SEP + "MSG: geometry_msgs/Transform\nVector3 translation\nQuaternion rotation\n"
    + _SEP + "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n"
    + _SEP + "MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n"
)


def ros2_static_transforms(edges: list[tuple[str, str]], stamp_ns: int = 0) -> bytes:
    """ROS 2 `tf2_msgs/msg/TFMessage` (little-endian CDR): one identity transform per (parent, child)."""
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    out = b"\x00\x01\x00\x00" + struct.pack("<I", len(edges))
    for parent, child in edges:
        out += struct.pack("<ii", sec, nanosec)
        for name in (parent, child):
            raw = name.encode() + b"\x00"
            out += b"\x00" * (-(len(out) - 4) % 4) + struct.pack("<I", len(raw)) + raw
        out += b"\x00" * (-(len(out) - 4) % 8)  # float64 alignment, counted after the encapsulation header
        out += struct.pack("<7d", 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)
    return out


_POINT = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("class", "u1"), ("red", "u1"), ("green", "u1"),
                   ("blue", "u1"), ("alpha", "u1"), ("_", "u1", 3)])
_POINT_COLOURS = np.array([CLASS_COLOURS[c] for c in sorted(CLASS_COLOURS)], np.uint8)


class _EventTopic:
    """Events of one class waiting for their grid cell to close; hands them out cell by cell."""

    def __init__(self, channel_id: int):
        self.channel_id = channel_id
        self.encoder: PacketEncoder | None = None  # made when the sensor size is known
        self.parts: collections.deque = collections.deque()  # (t, x, y, p) views, in stream order

    def add(self, t, x, y, p) -> None:
        if len(t):
            self.parts.append((t, x, y, p))

    def take_before(self, t_limit: int) -> list[tuple[np.ndarray, ...]]:
        """Remove and return the parts (t, x, y, p) of the events with t < t_limit, in stream order (views:
        no copy; the part holding t_limit is cut there)."""
        taken = []
        while self.parts:
            part = self.parts[0]
            t = part[0]
            if t[0] >= t_limit:
                break
            if t[-1] < t_limit:
                taken.append(self.parts.popleft())
                continue
            cut = int(np.searchsorted(t, t_limit, side="left"))
            taken.append(tuple(a[:cut] for a in part))
            self.parts[0] = tuple(a[cut:] for a in part)
            break
        return taken


class McapSink:
    """Writes every batch into an MCAP file (see the module docstring for channels and guarantees).

    `keep_noise`: also write the events classed noise, one channel per class (nothing is lost).
    `frames`: write the framer's frames. `points`: a PointCloud per batch, at most `point_budget` points.
    `metadata`: provenance written at the start (values JSON-encoded when not strings).
    """

    # `_add_packets` writes into mcap's Writer internals; only the versions whose files it was checked to
    # match byte for byte (tests/test_mcap_archive.py) take that path, any other adds packets through
    # `Writer.add_message` one at a time (what the tests compare with).
    _ONE_BY_ONE = not importlib.metadata.version("mcap").startswith(BULK_MCAP_VERSIONS)

    def __init__(self, path, *, camera: str = "camera", encoding: str = "evt3", keep_noise: bool = False,
                 frames: bool = True, frame_format: str = "foxglove", points: bool = False,
                 point_budget: int = 50_000,
                 packet_us: int = 10_000, max_packet_events: int = 200_000, chunk_bytes: int = 4 << 20,
                 flush_s: float = 1.0, zstd_level: int = 1, metadata: dict[str, Any] | None = None,
                 geometry: Geometry | None = None, inputs=()):
        if not _CAMERA_NAME.match(camera):
            raise ValueError(f"camera name {camera!r}: letters, digits and '_', starting with a letter")
        if encoding not in ENCODINGS:
            raise ValueError(f"unknown event encoding {encoding!r}; choose from {', '.join(ENCODINGS)}")
        if encoding == "mono" and packet_us > 4_000_000:
            raise ValueError("mono packets span at most 4.29 s: packet_us must be <= 4000000")
        for name, v in (("packet_us", packet_us), ("max_packet_events", max_packet_events),
                        ("chunk_bytes", chunk_bytes), ("point_budget", point_budget)):
            if int(v) <= 0:
                raise ValueError(f"{name} must be positive, got {v}")
        self.path = str(path)
        self.camera = camera
        self.encoding = encoding
        self.keep_noise = keep_noise
        if frame_format not in FRAME_FORMATS:
            raise ValueError(f"unknown frame format {frame_format!r}; choose from {', '.join(FRAME_FORMATS)}")
        self.frames = frames
        self.frame_format = frame_format
        self.points = points
        self.point_budget = int(point_budget)
        self.packet_us = int(packet_us)
        self.max_packet_events = int(max_packet_events)
        self.chunk_bytes = int(chunk_bytes)
        self.flush_s = float(flush_s)
        self._zstd = _Zstd(int(zstd_level))
        self.topics = topics(camera)
        self.geometry = geometry
        self.messages = 0
        self.packets = 0
        self.events_written = np.zeros(len(NoiseClass), np.int64)
        self.frames_written = 0
        self._t_first: int | None = None
        self._pending_bytes = 0
        self._last_flush = time.monotonic()
        self._first_flushed = True
        self._closed = False
        self._first_flushed = False
        # beside the target until whole (`safe_write`); an input given as the target is refused here
        self._output = AtomicOutput(self.path, inputs, keep_partial=True)
        self.part = str(self._output.part)
        self.interrupted = False  # set by `interrupt`: closed whole, but set aside, not put in place
        self.written: str | None = None  # where the archive is once closed (path, or the partial file)
        self._file = open(self.part, "wb")  # noqa: SIM115 - closed in close()
        self._writer = Writer(self._file, chunk_size=_NEVER, compression=CompressionType.ZSTD)
        ros2_only = not points and (not frames or frame_format == "ros2")
        profile = "ros2" if ros2_only else ""  # "ros2": every channel is ROS 2 CDR
        self._writer.start(profile=profile, library="evstream")
        self._register(metadata or {})
        self._file.flush()

    # -- setup ----------------------------------------------------------------------------------------
    def _register(self, metadata: dict[str, Any]) -> None:
        w = self._writer
        packet_schema = w.register_schema(DATATYPE, "ros2msg", MSGDEF.encode())
        classes = [NoiseClass.SIGNAL] + ([NoiseClass.BACKGROUND, NoiseClass.HOT_PIXEL] if self.keep_noise else [])
        self._event_topics: dict[NoiseClass, _EventTopic] = {}
        for c in classes:
            meta = {META_CLASS: CLASS_NAMES[c], META_TIME_BASE: TIME_BASE_FIRST_EVENT,
                    META_PACKET_US: str(self.packet_us)}
            cid = w.register_channel(self.topics[CLASS_NAMES[c]], "cdr", packet_schema, meta)
            self._event_topics[c] = _EventTopic(cid)
        if self.frames and self.frame_format == "ros2":
            sid = w.register_schema(IMAGE_DATATYPE, "ros2msg", IMAGE_MSGDEF.encode())
            self._frames_channel = w.register_channel(self.topics["frames"], "cdr", sid)
        elif self.frames:
            from foxglove_schemas_protobuf.RawImage_pb2 import RawImage  # protobuf: only for frames (start-up)

            sid = w.register_schema("foxglove.RawImage", "protobuf", _file_descriptor_set(RawImage))
            self._frames_channel = w.register_channel(self.topics["frames"], "protobuf", sid)
        if self.points:
            from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud

            sid = w.register_schema("foxglove.PointCloud", "protobuf", _file_descriptor_set(PointCloud))
            self._points_channel = w.register_channel(self.topics["points"], "protobuf", sid)
            sid = w.register_schema(TF_DATATYPE, "ros2msg", TF_MSGDEF.encode())
            tf_channel = w.register_channel(self.topics["transforms"], "cdr", sid)
            edges = [(WORLD_FRAME, self.camera)]
            if self.frames:  # where Rerun's loader puts the camera's images (see the module docstring)
                edges.append((self.camera, f"{self.camera}_image_plane"))
            w.add_message(tf_channel, log_time=0, publish_time=0, data=ros2_static_transforms(edges))
            self.messages += 1
        meta = {
            "format": "evstream MCAP archive v1",
            "camera": self.camera,
            "encoding": self.encoding,
            "packet_us": str(self.packet_us),
            "keep_noise": json.dumps(self.keep_noise),
            "topics": json.dumps({k: v for k, v in self.topics.items()
                                  if (k not in ("background", "hot_pixel") or self.keep_noise)
                                  and (k != "frames" or self.frames)
                                  and (k not in ("points", "transforms") or self.points)}),
            "created_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        }
        if self.geometry is not None:
            meta.update(width=str(self.geometry.width), height=str(self.geometry.height))
        meta.update({k: v if isinstance(v, str) else json.dumps(v, default=str) for k, v in metadata.items()})
        w.add_metadata("evstream", meta)

    # -- writing -----------------------------------------------------------------------------------
    def write(self, batch: Batch) -> None:
        if self._closed:
            raise RuntimeError("McapSink: write after close")
        chunk = batch.events
        if self.geometry is None:
            self.geometry = chunk.geometry
        if len(chunk):
            if self._t_first is None:
                self._t_first = int(chunk.t[0])
            self._route(chunk)
            if self.points:
                self._write_points(chunk)
        self._emit_cells(chunk.t_end if not len(chunk) else max(int(chunk.t_end), int(chunk.t[-1])))
        if self.frames:
            for frame in batch.frames:
                self._write_frame(frame)
        self._maybe_flush()

    def _route(self, chunk: EventChunk) -> None:
        """Hand each event to its class's topic (SIGNAL when unclassified; noise only with keep_noise)."""
        cls = chunk.cls
        if cls is not None and len(cls) and cls.max() >= N_CLASSES:
            bad = int(np.argmax(cls >= N_CLASSES))
            raise EventError(f"McapSink: event {bad} has noise class {int(cls[bad])}; "
                             f"known classes are 0..{N_CLASSES - 1}")
        for c, topic in self._event_topics.items():
            ev = chunk.of_class(c)
            topic.add(ev.t, ev.x, ev.y, ev.p)

    def _emit_cells(self, watermark: int) -> None:
        """Write the packets of every grid cell that the watermark has closed: cell by cell, in each cell the
        topics in order, a cell of a topic in packets of at most `max_packet_events`. (One pass per batch:
        each topic's closed events are taken at once, cut at the cell edges and encoded in one call, then
        the packets merged by cell and added to the file's chunk at once.)"""
        cell_end = (watermark // self.packet_us) * self.packet_us  # cells ending at or before this are closed
        rows = []  # (cell, topic's rank, class, topic, packet, events)
        for rank, (c, topic) in enumerate(self._event_topics.items()):
            parts = topic.take_before(cell_end)
            if not parts:
                continue
            t, x, y, p = parts[0] if len(parts) == 1 else tuple(np.concatenate(column) for column in zip(*parts))
            cells = t // self.packet_us
            bounds = np.flatnonzero(cells[1:] != cells[:-1]) + 1
            bounds = np.concatenate(([0], bounds, [len(t)]))
            if (np.diff(bounds) > self.max_packet_events).any():  # a cell too full for one packet: cut it
                bounds = np.concatenate([np.arange(a, b, self.max_packet_events)
                                         for a, b in zip(bounds[:-1].tolist(), bounds[1:].tolist())] + [[len(t)]])
            if topic.encoder is None:
                g = self.geometry
                topic.encoder = PacketEncoder(width=g.width, height=g.height, encoding=self.encoding,
                                              frame_id=self.camera)
            packets = topic.encoder.encode_many(t, x, y, p, bounds)
            rows += [(cell, rank, c, topic, packet, n) for cell, packet, n in
                     zip(cells[bounds[:-1]].tolist(), packets, np.diff(bounds).tolist())]
        if len(self._event_topics) > 1:
            rows.sort(key=lambda row: row[:2])  # stable: a cell's packets of one topic stay in order
        if rows:
            self._add_packets(rows)

    def _add_packets(self, rows) -> None:
        """Add the packets to the chunk in progress as mcap's `Writer.add_message` one by one would (same
        records, message index and statistics), in one write: ~1 µs a packet instead of ~10."""
        w = self._writer
        stats = getattr(w, "_Writer__statistics", None)
        chunk = getattr(w, "_Writer__chunk_builder", None)
        buffer = getattr(getattr(chunk, "record_writer", None), "_buffer", None)
        pieces = []
        one_by_one = self._ONE_BY_ONE or buffer is None or stats is None  # another mcap: its own way
        offset = None if one_by_one else buffer.tell()
        for _, _, c, topic, packet, n in rows:
            data = encode_packet(packet)
            t_ns = packet.stamp_ns
            if one_by_one:
                w.add_message(topic.channel_id, log_time=t_ns, data=data, publish_time=t_ns,
                              sequence=packet.seq & 0xFFFFFFFF)
            else:
                ch = topic.channel_id
                pieces += (_MESSAGE_HEAD.pack(Opcode.MESSAGE, 22 + len(data), ch, packet.seq & 0xFFFFFFFF,
                                              t_ns, t_ns), data)
                if stats.message_count == 0:
                    stats.message_start_time = t_ns
                else:
                    stats.message_start_time = min(t_ns, stats.message_start_time)
                stats.message_end_time = max(t_ns, stats.message_end_time)
                stats.channel_message_counts[ch] += 1
                stats.message_count += 1
                if chunk.num_messages == 0:
                    chunk.message_start_time = t_ns
                else:
                    chunk.message_start_time = min(chunk.message_start_time, t_ns)
                chunk.message_end_time = max(chunk.message_end_time, t_ns)
                index = chunk.message_indices.get(ch)
                if not index:
                    index = chunk.message_indices[ch] = MessageIndex(channel_id=ch, records=[])
                index.records.append((t_ns, offset))
                chunk.num_messages += 1
                offset += 31 + len(data)
            self.packets += 1
            self.messages += 1
            self.events_written[c] += n
            self._pending_bytes += len(data)
        if pieces:
            buffer.write(b"".join(pieces))

    def _write_frame(self, frame: Frame) -> None:
        img = render_mono8(frame)
        t_ns = int(frame.t_end) * 1000
        if self.frame_format == "ros2":
            data = ros2_image(img, t_ns, self.camera)
            self._writer.add_message(self._frames_channel, log_time=t_ns, data=data, publish_time=t_ns,
                                     sequence=self.frames_written & 0xFFFFFFFF)
            self.frames_written += 1
            self.messages += 1
            self._pending_bytes += len(data)
            return
        from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

        msg = RawImage(frame_id=self.camera, width=img.shape[1], height=img.shape[0], encoding="mono8",
                       step=img.shape[1], data=img.tobytes())
        msg.timestamp.seconds, msg.timestamp.nanos = divmod(t_ns, 1_000_000_000)
        data = msg.SerializeToString()
        self._writer.add_message(self._frames_channel, log_time=t_ns, data=data, publish_time=t_ns,
                                 sequence=self.frames_written & 0xFFFFFFFF)
        self.frames_written += 1
        self.messages += 1
        self._pending_bytes += len(data)

    def _write_points(self, chunk: EventChunk) -> None:
        n = len(chunk)
        idx = np.arange(n) if n <= self.point_budget else np.linspace(0, n - 1, self.point_budget).astype(np.int64)
        rec = np.zeros(len(idx), _POINT)
        rec["x"] = chunk.x[idx]
        rec["y"] = chunk.y[idx]
        rec["z"] = (chunk.t[idx] - self._t_first) * 1e-3  # ms since the first event: the T axis
        cls = chunk.classes()[idx]
        rec["class"] = cls
        rec["red"], rec["green"], rec["blue"] = (_POINT_COLOURS[cls, k] for k in range(3))
        rec["alpha"] = 255
        t_ns = int(chunk.t[-1]) * 1000
        from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
        from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud

        msg = PointCloud(frame_id=self.camera, point_stride=_POINT.itemsize, data=rec.tobytes())
        msg.timestamp.seconds, msg.timestamp.nanos = divmod(t_ns, 1_000_000_000)
        msg.pose.orientation.w = 1.0
        for name in ("x", "y", "z", "class", "red", "green", "blue", "alpha"):
            kind = PackedElementField.FLOAT32 if _POINT[name] == np.float32 else PackedElementField.UINT8
            msg.fields.add(name=name, offset=_POINT.fields[name][1], type=kind)
        data = msg.SerializeToString()
        self._writer.add_message(self._points_channel, log_time=t_ns, data=data, publish_time=t_ns)
        self.messages += 1
        self._pending_bytes += len(data)

    def _maybe_flush(self) -> None:
        now = time.monotonic()
        if self._pending_bytes >= self.chunk_bytes or (self._pending_bytes and now - self._last_flush >= self.flush_s):
            self.flush()
        elif self._pending_bytes and not self._first_flushed:  # the first packets on disk at once: a kill
            self.flush()  # in the first flush_s (or 4 MiB) recovered nothing

    def tick(self) -> None:
        """Close the chunk in progress if `flush_s` has passed: for live sources, call it when no batch comes
        (the sink is not thread-safe: call it from the thread that writes)."""
        if not self._closed:
            self._maybe_flush()

    def flush(self) -> None:
        """Close the chunk in progress and hand everything written so far to the OS."""
        with _zstd_level(self._zstd):
            self._writer.flush()  # finalizes the chunk, writes it and its message indexes, flushes the file
        self._pending_bytes = 0
        self._last_flush = time.monotonic()
        self._first_flushed = True

    # -- closing -----------------------------------------------------------------------------------------
    def close(self, stats: RunStats | None = None) -> None:
        """Write what is still waiting (the open cells), the statistics, the summary and the footer, and put
        the archive in place (renamed onto `path`; a full disk: one error naming it, nothing left there).
        After `interrupt`, the archive is closed as well but kept as PATH-STEM.partial.mcap instead,
        `path` left as it was (`written` says where)."""
        if self._closed:
            return
        try:
            self._finish(stats)
        except BaseException as e:
            self._output.keep_partial = self._holds_something()
            raised = self._output.failed(e)
            if raised is not e:
                raise raised from None
            raise
        if self.interrupted:
            self.written = str(self._output.set_aside())
            return
        self._output.commit()
        self.written = str(self.path)

    def abandon(self) -> None:
        """Drop the archive unfinished (a sink never closed): its file closed and removed, `path` untouched."""
        self._closed = True
        try:
            self._file.close()
        finally:
            self._output.discard(keep=False)

    def interrupt(self) -> None:
        """The run is being cut short (Ctrl-C in a file command): `close` still writes a whole archive of
        what came, but sets it aside (`safe_write.AtomicOutput.set_aside`) rather than replacing `path`.
        A live archive, which ends by Ctrl-C, does not call this."""
        self.interrupted = True

    def fail(self, stats: RunStats | None, error: BaseException) -> None:
        """After a failed run: the archive closed (readable up to the failure) but not put in place; the
        file at `path` stays as it was. Raises the error to report (a full disk as one line naming `path`;
        else `error`, saying where the partial archive is)."""
        try:
            if not self._closed:
                self._finish(stats)
        except Exception:  # the disk, most likely: the partial file is what it is
            pass
        self._output.keep_partial = self._holds_something()  # an archive of nothing is not kept
        raised = self._output.failed(error)
        if raised is not error:
            raise raised from None

    def _holds_something(self) -> bool:
        """Whether the file holds an event packet or a frame: a failed run's archive is kept only then
        (one that failed at the input's first bytes leaves no OUT.mcap.N.part behind)."""
        return bool(self.packets or self.frames_written)

    def _finish(self, stats: RunStats | None) -> None:
        try:
            if self.geometry is not None:
                self._emit_cells(1 << 62)
            summary = {
                "packets": self.packets,
                "frames": self.frames_written,
                **{f"events_{CLASS_NAMES[c]}": int(self.events_written[c]) for c in NoiseClass},
            }
            if stats is not None:
                summary.update({f"run_{k}": v for k, v in stats.as_dict().items()})
            self._writer.add_metadata("evstream.stats", {k: json.dumps(v) for k, v in summary.items()})
            with _zstd_level(self._zstd):
                self._writer.finish()
        finally:
            self._closed = True
            self._file.close()

    def __enter__(self):
        return self

    def __exit__(self, kind, e, tb):
        if e is None:
            self.close()
        else:
            self.fail(None, e)
