"""Zenoh publisher: events as EventPackets (CDR, evt3) with evstream's attachment, frames as foxglove.RawImage.

`PacketPublisher(session, key)` puts one packet per call: `event_camera_msgs/EventPacket` bytes (the
same codec and packet conventions as the MCAP archive, `evstream.codecs.packets`) with the 16-byte
attachment `uint64 seq, int64 source_time_ns` (`evstream.codecs.attachment`). `end()` marks the end of
the stream with a DELETE on the key, which subscribers turn into `End`.

`ZenohSink` is the pipeline sink around it: each batch's SIGNAL events (the cleaned stream; all events
with `classes="all"`) on `key`, frames on `frames_key`. A packet carries the source time of the packet
it was cleaned from, so latency is measured from the camera's publication to the cleaned republish.
Congestion control BLOCK (default) waits for slow links and FIFO subscribers instead of dropping.
"""

from __future__ import annotations

import time

import numpy as np
import zenoh
from evstream.sinks.mcap_sink import render_mono8
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

from evstream.codecs.attachment import encode_attachment
from evstream.codecs.event_packet import encode_packet
from evstream.codecs.packets import to_packet
from evstream.events import EventChunk, Frame, NoiseClass
from evstream.pipeline import Batch, RunStats

__all__ = ["CONGESTION", "PacketPublisher", "ZenohSink", "frames_key_for", "linger"]

CONGESTION = {"block": zenoh.CongestionControl.BLOCK, "drop": zenoh.CongestionControl.DROP}
MAX_PACKET_EVENTS = 1_000_000  # a larger batch is split: bounded packets for every subscriber


def frames_key_for(events_key: str) -> str:
    """`evstream/cam/events/clean` -> `evstream/cam/frames`."""
    parts = events_key.split("/")
    if "events" in parts:
        i = len(parts) - 1 - parts[::-1].index("events")
        return "/".join(parts[:i] + ["frames"])
    return events_key + "/frames"


def linger(publishers, timeout_s: float) -> bool:
    """After the end marks: keep the session open until no subscriber matches any of `publishers` (those
    that stop at the end have taken everything and left) or `timeout_s` passes; True if they all left.

    Closing a session drops what Zenoh still holds for it on the way (in the router's queues under
    backpressure), so a publisher must not close before its subscribers have read the stream.
    """
    deadline = time.monotonic() + timeout_s
    while any(p.matching for p in publishers):
        if time.monotonic() > deadline:
            return False
        time.sleep(0.02)
    return True


class PacketPublisher:
    """Publishes EventPackets on one key, numbering them from 0 (a restart starts at 0 again)."""

    def __init__(self, session: zenoh.Session, key: str, *, congestion: str = "block", express: bool = False,
                 encoding: str = "evt3", frame_id: str = ""):
        if congestion not in CONGESTION:
            raise ValueError(f"congestion {congestion!r}: choose from {', '.join(CONGESTION)}")
        self.key = key
        self.encoding = encoding
        self.frame_id = frame_id
        self.seq = 0
        self.packets = 0
        self.events = 0
        self.bytes = 0
        # put while no subscriber matched the key (before or after the put): nobody received them. What a
        # subscriber that died held or had on the way is not among them: Zenoh does not tell (docs/live.md).
        self.unmatched_packets = 0
        self.unmatched_events = 0
        self._pub = session.declare_publisher(key, congestion_control=CONGESTION[congestion], express=express,
                                              priority=zenoh.Priority.DATA)

    @property
    def matching(self) -> bool:
        """Whether a subscriber matches the key now."""
        return self._pub.matching_status.matching

    def wait_matching(self, timeout_s: float) -> bool:
        """Wait until a subscriber matches the key (a put before that goes nowhere); True if one does."""
        deadline = time.monotonic() + timeout_s
        while not self._pub.matching_status.matching:
            if time.monotonic() > deadline:
                return False
            time.sleep(0.01)
        return True

    def put_events(self, t, x, y, p, *, width: int, height: int, source_time_ns: int | None = None) -> None:
        for a in range(0, len(t), MAX_PACKET_EVENTS):
            sl = slice(a, a + MAX_PACKET_EVENTS)
            packet = to_packet(t[sl], x[sl], y[sl], p[sl], width=width, height=height, encoding=self.encoding,
                               seq=self.seq, frame_id=self.frame_id)
            data = encode_packet(packet)
            src = time.time_ns() if source_time_ns is None else int(source_time_ns)
            matched = self.matching  # 1.5 µs: a BLOCK put can wait long while the last subscriber goes away
            self._pub.put(data, attachment=encode_attachment(self.seq, src))
            n = min(MAX_PACKET_EVENTS, len(t) - a)
            if not (matched and self.matching):
                self.unmatched_packets += 1
                self.unmatched_events += n
            self.seq += 1
            self.packets += 1
            self.events += n
            self.bytes += len(data)

    def end(self) -> None:
        """Mark the end of the stream: a DELETE on the key, whose attachment's `seq` is the number of packets
        sent (the next seq), so a subscriber counts packets lost just before the end in `missing` too."""
        self._pub.delete(attachment=encode_attachment(self.seq, time.time_ns()))

    def close(self) -> None:
        """Nothing to do: the publisher goes with its session. (Undeclaring it explicitly was seen to
        lose packets that subscribers had not taken in yet, so it is left to `Session.close`.)"""


class ZenohSink:
    """A pipeline sink republishing the cleaned stream (SIGNAL events) and frames over Zenoh.

    `close` marks the end of the stream (subscribers see `End`), so a chain of nodes ends in order.
    """

    def __init__(self, session: zenoh.Session, key: str, *, frames_key: str | None = None, classes: str = "signal",
                 congestion: str = "block", frame_id: str = ""):
        if classes not in ("signal", "all"):
            raise ValueError(f"classes {classes!r}: signal or all")
        self.classes = classes
        self.publisher = PacketPublisher(session, key, congestion=congestion, frame_id=frame_id)
        self.frames_key = frames_key
        self._frames = (session.declare_publisher(frames_key, congestion_control=CONGESTION[congestion])
                        if frames_key else None)
        self.frames_published = 0
        self._closed = False

    def write(self, batch: Batch, *, source_time_ns: int | None = None) -> None:
        ev: EventChunk = batch.events
        if self.classes == "signal" and ev.cls is not None and len(ev):
            ev = ev.of_class(NoiseClass.SIGNAL)
        if len(ev):
            g = ev.geometry
            self.publisher.put_events(ev.t, ev.x, ev.y, ev.p, width=g.width, height=g.height,
                                      source_time_ns=source_time_ns)
        if self._frames is not None:
            for frame in batch.frames:
                self._put_frame(frame)

    def _put_frame(self, frame: Frame) -> None:
        img = render_mono8(frame)
        t_ns = int(frame.t_end) * 1000
        msg = RawImage(frame_id=self.publisher.frame_id, width=img.shape[1], height=img.shape[0], encoding="mono8",
                       step=img.shape[1], data=np.ascontiguousarray(img).tobytes())
        msg.timestamp.seconds, msg.timestamp.nanos = divmod(t_ns, 1_000_000_000)
        self._frames.put(msg.SerializeToString(), encoding=zenoh.Encoding("application/protobuf")
                         .with_schema("foxglove.RawImage"),
                         attachment=encode_attachment(self.frames_published, time.time_ns()))
        self.frames_published += 1

    def close(self, stats: RunStats | None = None) -> None:
        if self._closed:
            return
        self._closed = True
        self.publisher.end()
        self.publisher.close()
