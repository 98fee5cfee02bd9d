"""Live event streams from Zenoh: EventPackets (CDR) on `evstream/<camera>/events`, or a ROS 2 node's
`event_camera_msgs/EventPacket` published through rmw_zenoh (`<domain>/<topic>/event_camera_msgs::msg::
dds_::EventPacket_/<type hash>`).

`ZenohSubscription(keyexpr, ...)` yields, per Zenoh sample, a `LivePacket` (a camera's validated
`EventChunk` with its sequence number and source time) or an `End` (the publisher's end-of-stream mark,
a DELETE on its key). A wildcard key gives several cameras; each has its own decoder and counters
(`CameraStats`), and the camera is the key segment before `events`.

Flow control is Zenoh's: `flow="block"` receives into a bounded FIFO (`handlers.FifoChannel`) — when
the consumer falls behind, the FIFO fills, Zenoh stops reading the link and a publisher using
`CongestionControl.BLOCK` is held back: nothing is lost (archiving). `flow="ring"` keeps the newest
`depth` samples (`handlers.RingChannel`, drop-oldest): the consumer stays live and the sequence gaps
count what it missed (viewing).

Bad input is counted and skipped with a warning, never fatal: payloads over `max_packet_bytes` (checked
on the received length before anything is copied; a message longer than the payload limit plus 64 KiB
of headers is dropped by the transport while being reassembled, unseen and uncounted), bytes
that are not a CDR EventPacket, undecodable events, coordinates outside the sensor, time going back.
"""

from __future__ import annotations

import copy
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np
import zenoh

from evstream.codecs.attachment import OURS, AttachmentError, decode_attachment
from evstream.codecs.event_packet import PacketError, decode_packet
from evstream.codecs.packets import PacketDecoder
from evstream.events import EventChunk, EventError, Geometry, concat
from evstream.events import _first_invalid as first_invalid

from ._base import MAX_SENSOR_SIDE
from .zenoh_session import DEFAULT_MAX_PACKET_BYTES, open_session

__all__ = ["FLOWS", "CameraStats", "End", "LivePacket", "ZenohSubscription", "camera_of", "now_ns"]

FLOWS = ("block", "ring")
MAX_ATTACHMENT_BYTES = 256
ROS_TYPE_MARK = "::msg::dds_::"
NO_TIME = -(1 << 62)  # the time before a camera's first packet: any event time follows it


def now_ns() -> int:
    """Wall-clock ns: source times in attachments are on this clock (one machine, or NTP-synced ones)."""
    return time.time_ns()


def camera_of(key: str) -> str:
    """The camera a key belongs to: the segment before the last `events` (`evstream/cam1/events/clean`
    -> cam1). rmw_zenoh keys lose their domain, type and hash first (`0/cam1/events/<type>/<hash>` ->
    cam1). Without an `events` segment, the remaining segments joined by '_'."""
    parts = [p for p in key.split("/") if p]
    if len(parts) >= 3 and ROS_TYPE_MARK in parts[-2]:
        parts = parts[1:-2]
    idx = [i for i, p in enumerate(parts) if p == "events"]
    if idx and idx[-1] > 0:
        return parts[idx[-1] - 1]
    return "_".join(parts) or "camera"


WARM_S = 1.0  # latency percentiles are also given without the first second (the chain's start-up)


@dataclass
class CameraStats:
    """What one camera's stream did: packets and events taken, sequence gaps, bad packets, restarts."""

    packets: int = 0
    events: int = 0
    bytes: int = 0
    gaps: int = 0  # places where sequence numbers jumped forward
    missing: int = 0  # packets those jumps skipped (lost, or dropped by a ring)
    malformed: int = 0
    oversized: int = 0
    bad_attachments: int = 0
    restarts: int = 0  # sequence numbers starting again: the publisher restarted
    ended: bool = False
    segment_events: list[int] = field(default_factory=lambda: [0])  # events between restarts
    latencies_ms: list[float] = field(default_factory=list)  # receive time - source time, per packet
    warm_index: int | None = None  # first latency of a packet received >= WARM_S after the first one
    first_receive_s: float | None = None
    first_seq: int | None = None
    last_seq: int | None = None
    last_t: int | None = None
    decoder: PacketDecoder | None = None

    def as_dict(self) -> dict:
        out = {k: getattr(self, k) for k in ("packets", "events", "bytes", "gaps", "missing", "malformed",
                                              "oversized", "bad_attachments", "restarts", "ended",
                                              "segment_events", "first_seq", "last_seq")}
        if self.latencies_ms:
            lat = np.asarray(self.latencies_ms)
            out.update(latency_p50_ms=float(np.percentile(lat, 50)), latency_p99_ms=float(np.percentile(lat, 99)),
                       latency_max_ms=float(lat.max()))
            if self.warm_index is not None:  # steady state: without the chain's start-up
                warm = lat[self.warm_index :]
                out.update(latency_warm_p50_ms=float(np.percentile(warm, 50)),
                           latency_warm_p99_ms=float(np.percentile(warm, 99)))
        return out

    def add_latency(self, latency_ms: float, now_s: float) -> None:
        if self.first_receive_s is None:
            self.first_receive_s = now_s
        if self.warm_index is None and now_s - self.first_receive_s >= WARM_S:
            self.warm_index = len(self.latencies_ms)
        self.latencies_ms.append(latency_ms)
        if len(self.latencies_ms) > 1_000_000:  # bounded: keep the recent half
            del self.latencies_ms[:500_000]
            if self.warm_index is not None:
                self.warm_index = max(0, self.warm_index - 500_000)


@dataclass
class LivePacket:
    """One received packet: the camera's events (a validated chunk) and where they came from."""

    camera: str
    key: str
    chunk: EventChunk
    seq: int | None
    source_time_ns: int | None
    restart: bool = False  # first packet after the publisher restarted (pipeline state should reset)


@dataclass
class End:
    """The publisher marked the end of this camera's stream."""

    camera: str
    key: str


def _joins(batch: list[LivePacket], batch_events: int, item: LivePacket, max_events: int) -> bool:
    """Whether `item` continues `batch`'s stream (`batch_events` events so far): same camera and sensor, no
    restart, within `max_events`."""
    first = batch[0]
    return (item.camera == first.camera and not item.restart and item.chunk.geometry == first.chunk.geometry
            and batch_events + len(item.chunk) <= max_events)


def _joined(batch: list[LivePacket]) -> LivePacket:
    if len(batch) == 1:
        return batch[0]
    first, last = batch[0], batch[-1]
    chunk = concat([p.chunk for p in batch], first.chunk.geometry)
    return LivePacket(first.camera, first.key, chunk, last.seq, first.source_time_ns, first.restart)


class ZenohSubscription:
    """Iterate over live packets on `keyexpr` (see the module docstring).

    `session`: an open Zenoh session to use, else one is opened from `listen`/`connect`/`mode`.
    `flow`: "block" (FIFO of `depth` samples, backpressure) or "ring" (newest `depth`, drop-oldest).
    `geometry`: sensor size for packets that give none (width/height 0). `idle_s`: stop after that long
    without a sample. `should_stop`: polled between samples (Ctrl-C). `warn`: where warnings go.
    """

    def __init__(self, keyexpr: str, *, session: zenoh.Session | None = None, listen=(), connect=(),
                 mode: str | None = None, multicast: bool = False, flow: str = "block", depth: int = 64,
                 max_packet_bytes: int = DEFAULT_MAX_PACKET_BYTES, geometry: Geometry | None = None,
                 idle_s: float | None = None, should_stop: Callable[[], bool] | None = None,
                 warn: Callable[[str], None] | None = None, max_warnings: int = 10):
        if flow not in FLOWS:
            raise ValueError(f"flow {flow!r}: choose from {', '.join(FLOWS)}")
        if depth < 1:
            raise ValueError(f"depth must be >= 1, got {depth}")
        self.keyexpr = keyexpr
        self.flow = flow
        self.max_packet_bytes = int(max_packet_bytes)
        self.geometry = geometry
        self.idle_s = idle_s
        self.should_stop = should_stop or (lambda: False)
        self._warn = warn or (lambda msg: print(f"evstream: warning: {msg}", file=sys.stderr, flush=True))
        self.max_warnings = max_warnings
        self.warnings = 0
        self.cameras: dict[str, CameraStats] = {}
        self.unattributed_malformed = 0
        self._stopped = threading.Event()
        self._own_session = session is None
        # the transport drops anything larger than a packet we would take while reassembling it; a session
        # given here should have been opened with the same `max_packet_bytes`
        self.session = session or open_session(mode=mode, listen=listen, connect=connect, multicast=multicast,
                                               max_packet_bytes=self.max_packet_bytes)
        try:
            handler = zenoh.handlers.FifoChannel(depth) if flow == "block" else zenoh.handlers.RingChannel(depth)
            self._sub = self.session.declare_subscriber(keyexpr, handler)
        except zenoh.ZError as e:
            self.close()
            raise ValueError(f"cannot subscribe to {keyexpr!r}: {str(e).split(' at /')[0]}") from None

    # -- iteration --------------------------------------------------------------------------------
    def stop(self) -> None:
        self._stopped.set()

    def __iter__(self) -> Iterator[LivePacket | End]:
        return self.batches(0)

    def batches(self, max_events: int) -> Iterator[LivePacket | End]:
        """As iterating, but a camera's packets that are already waiting in the FIFO when one is taken come
        as one `LivePacket` (events concatenated, up to `max_events`; its `source_time_ns` the first's, its
        `seq` the last's): a consumer that fell behind pays its per-packet costs once for the backlog, and
        nothing waits for a batch to fill. Each packet is still checked and counted alone (`handle`)."""
        last = time.monotonic()
        poll_s = 0.0002
        batch: list[LivePacket] = []
        batch_events = 0
        while not self._stopped.is_set() and not self.should_stop():
            sample = self._sub.try_recv()
            if sample is None:
                if batch:  # nothing more waiting: hand on what was taken
                    yield _joined(batch)
                    batch, batch_events = [], 0
                    continue
                if self.idle_s is not None and time.monotonic() - last > self.idle_s:
                    return
                time.sleep(poll_s)
                poll_s = min(poll_s * 2, 0.002)
                continue
            last = time.monotonic()
            poll_s = 0.0002
            item = self.handle(sample)
            if item is None:
                continue
            if batch and not (isinstance(item, LivePacket) and _joins(batch, batch_events, item, max_events)):
                yield _joined(batch)
                batch, batch_events = [], 0
            if isinstance(item, LivePacket) and len(item.chunk) < max_events:
                batch.append(item)
                batch_events += len(item.chunk)
            else:
                yield item
        if batch:
            yield _joined(batch)

    def handle(self, sample) -> LivePacket | End | None:
        """One Zenoh sample -> a packet, an end mark, or None (bad input, counted and warned about)."""
        key = str(sample.key_expr)
        camera = camera_of(key)
        st = self.cameras.get(camera)
        if st is None:
            st = self.cameras[camera] = CameraStats()
        if sample.kind == zenoh.SampleKind.DELETE:
            st.ended = True
            att = sample.attachment
            if att is not None and len(att) <= MAX_ATTACHMENT_BYTES and st.last_seq is not None:
                try:
                    a = decode_attachment(att.to_bytes())
                except AttachmentError:
                    a = None
                # our end mark carries the count of packets sent: those after the last one taken were lost
                if a is not None and a.kind == OURS and a.seq > st.last_seq + 1:
                    st.gaps += 1
                    st.missing += a.seq - st.last_seq - 1
            return End(camera, key)
        n = len(sample.payload)
        if n > self.max_packet_bytes:
            st.oversized += 1
            self.warn(f"{key}: packet of {n:,} bytes exceeds --max-packet-bytes {self.max_packet_bytes:,}; skipped")
            return None
        seq = source_ns = kind = None
        att = sample.attachment
        if att is not None:
            if len(att) > MAX_ATTACHMENT_BYTES:
                st.bad_attachments += 1
                self.warn(f"{key}: attachment of {len(att):,} bytes ignored")
            else:
                try:
                    a = decode_attachment(att.to_bytes())
                    seq, source_ns, kind = a.seq, a.source_time_ns, a.kind
                except AttachmentError as e:
                    st.bad_attachments += 1
                    self.warn(f"{key}: {e}; ignored")
        try:
            packet = decode_packet(sample.payload.to_bytes(), max_bytes=self.max_packet_bytes)
        except PacketError as e:
            return self._malformed(st, key, str(e))
        if seq is None:
            seq = packet.seq
        # Nothing about the camera's sequence changes until the packet is accepted: a rejected packet
        # (a hostile one claiming seq 2^64-1, say) must not count a gap, a restart or reset the pipeline.
        restart = st.last_seq is not None and seq <= st.last_seq
        geometry = self.geometry
        if packet.width and packet.height:
            if max(packet.width, packet.height) > MAX_SENSOR_SIDE:  # one such packet took 13 GiB a stage
                return self._malformed(st, key, f"sensor size {packet.width}x{packet.height}: larger than any "
                                                f"event camera ({MAX_SENSOR_SIDE} a side)")
            try:
                geometry = Geometry(packet.width, packet.height)
            except ValueError as e:
                return self._malformed(st, key, f"sensor size: {e}")
        if geometry is None:
            return self._malformed(st, key, "packet gives no sensor size (width/height 0); pass --geometry")
        if st.decoder is None or restart:
            decoder = PacketDecoder(absolute=kind == OURS)
        elif st.decoder.absolute:
            decoder = st.decoder  # each packet decodes alone: no stream state to spoil
        else:
            decoder = copy.deepcopy(st.decoder)  # one EVT3 stream across packets: kept only if accepted
        last_t = None if restart else st.last_t
        try:
            t, x, y, p = decoder.decode(packet)
        except (PacketError, EventError, ValueError) as e:
            return self._malformed(st, key, f"events: {e}")
        chunk = EventChunk.from_arrays(t, x, y, p, geometry)
        if len(t):  # one pass over the events (numpy took five, a diff array among them)
            bad, back = first_invalid(chunk.t, chunk.x, chunk.y, chunk.p, geometry.width, geometry.height,
                                      NO_TIME if last_t is None else last_t)
            if back >= 0:  # before the first off-sensor event (first_invalid stops there): named first
                return self._malformed(st, key, "event time goes back")
            if bad >= 0:  # (the decoders give polarities 0 and 1 only: what is bad is a coordinate)
                return self._malformed(st, key, f"event outside the {geometry} sensor")
            last_t = int(t[-1])
        # accepted: now the sequence, the decoder and the counters move on
        self._track_seq(st, seq)
        st.decoder, st.last_t = decoder, last_t
        st.packets += 1
        st.events += len(t)
        st.bytes += n
        st.segment_events[-1] += len(t)
        if kind == OURS and source_ns is not None:
            st.add_latency((now_ns() - source_ns) * 1e-6, time.monotonic())
        return LivePacket(camera, key, chunk, seq, source_ns, restart)

    @staticmethod
    def _track_seq(st: CameraStats, seq: int) -> bool:
        """Count a gap or a restart for an accepted packet's `seq`; True on a restart."""
        restart = False
        if st.first_seq is None:
            st.first_seq = seq
        if st.last_seq is not None:
            if seq > st.last_seq + 1:
                st.gaps += 1
                st.missing += seq - st.last_seq - 1
            elif seq <= st.last_seq:
                st.restarts += 1
                st.ended = False
                st.segment_events.append(0)
                restart = True
        st.last_seq = seq
        return restart

    def _malformed(self, st: CameraStats, key: str, why: str) -> None:
        st.malformed += 1
        self.warn(f"{key}: malformed packet skipped: {why}")
        return None

    def warn(self, msg: str) -> None:
        self.warnings += 1
        if self.warnings <= self.max_warnings:
            self._warn(msg)
        elif self.warnings == self.max_warnings + 1:
            self._warn("more warnings follow; counts are in the summary")

    # -- summary ----------------------------------------------------------------------------------
    def totals(self) -> dict:
        keys = ("packets", "events", "gaps", "missing", "malformed", "oversized", "bad_attachments", "restarts")
        return {k: sum(getattr(s, k) for s in self.cameras.values()) for k in keys}

    def close(self) -> None:
        self._stopped.set()
        sub = getattr(self, "_sub", None)
        if sub is not None:
            try:
                sub.undeclare()
            except zenoh.ZError:
                pass
            self._sub = None
        if self._own_session and self.session is not None:
            self.session.close()
            self.session = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
