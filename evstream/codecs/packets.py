"""Events <-> `EventPacket`s: how evstream fills `time_base`, the header stamp and the payload, and how it
reads packets back (ours and other tools').

Writing (`to_packet`), for both encodings: `time_base` = header stamp = the packet's first event time
in ns (event_camera_codecs' encoders set time_base to the packet's start sensor time the same way).

- `evt3`: the payload is the sensor's 24-bit µs clock as a camera sends it (event_camera_codecs' EVT3
  encoder writes the same words): a packet opens with a TIME_HIGH word where the previous packet of its
  topic left the clock, steps forward to its first event (wraps spelled 4095 -> 0), then TIME_LOW,
  ADDR_Y and the events. So a stateful decoder fed the packets in order (event_camera_codecs, faery over
  the concatenated payloads, `Evt3Decoder`) follows the clock across any gap, and each packet also
  decodes alone: its times shifted so the first event lands on `time_base`.
- `mono`: dt = t − time_base in ns (uint32), so a mono packet spans at most 4.29 s.

Reading (`PacketDecoder`): event_camera_msgs leaves `time_base` undefined for evt3, so packets from
other tools are decoded as one stream (state across packets, `time_base` ignored, as event_camera_codecs
does); packets evstream wrote (`absolute=True`, told by channel metadata) decode alone, each placed by
its `time_base`, which survives any gap between packets. Mono: t = time_base + dt.
"""

from __future__ import annotations

import struct

import numpy as np

from . import evt3, mono
from .event_packet import EventPacket, PacketError

__all__ = ["ENCODINGS", "EVT3_EPOCH_US", "PacketDecoder", "PacketEncoder", "evt3_sensor_clock", "to_packet"]

ENCODINGS = ("evt3", "mono")
EVT3_EPOCH_US = 1 << 24  # the EVT3 clock wraps every 2^24 µs ≈ 16.8 s
_NS_PER_US = 1000


def evt3_sensor_clock(t, x, y, p, from_time_high: int | None = None,
                      encoder: evt3.Evt3Encoder | None = None) -> bytes:
    """EVT3 bytes of one packet on the 24-bit sensor clock, decodable alone.

    The packet opens with a TIME_HIGH word: the clock's time-high where the previous packet of the stream
    left it (`from_time_high`, absolute: t >> 12), or the first event's own when None; then TIME_HIGH steps
    up to the first event (wraps spelled 4095 -> 0, as a camera sends them), TIME_LOW, ADDR_Y and the
    events. Built on `evt3.Evt3Encoder` (`encoder`, reused across packets so its word buffer is too),
    restarted at that time-high (state = [started, time-high, time-low, y]).
    """
    if len(t) == 0:
        return b""
    t0 = int(t[0])
    if t0 < 0:
        raise ValueError(f"evt3: event 0 has t={t0} µs; EVT3 needs t >= 0")
    high = t0 >> 12 if from_time_high is None else int(from_time_high)
    if high > t0 >> 12:
        raise ValueError(f"evt3: the clock is at time-high {high}, past the first event (t={t0} µs)")
    enc = encoder if encoder is not None else evt3.Evt3Encoder()
    enc.state[:] = (1, high, -1, -1)
    # The clock starts where the previous packet left it, not at the first event: the encoder sizes its
    # word buffer by the TIME_HIGH steps from `last_t` on, and those steps cross the gap before this
    # packet (4 words a wrap). From t0, a 10-hour pause before a packet of 3 events wrote ~8,600 words
    # into a buffer of 20: heap corruption, a segfault in `evstream archive`. Sized from there, Unix-µs
    # timestamps (AEDAT4) cost nothing either: only the span from the clock counts.
    enc.last_t = high << 12
    return struct.pack("<H", 0x8000 | (high & 0xFFF)) + enc.encode(t, x, y, p)


class PacketEncoder:
    """Events -> EventPackets for one topic: `seq` counts from 0, time_base = stamp = first event time (ns).

    EVT3 packets continue one sensor clock: each opens where the previous one left the clock and steps
    forward, so a stateful decoder fed the packets in order never sees the clock jump (any gap, wraps
    included), and each packet still decodes alone.
    """

    def __init__(self, *, width: int, height: int, encoding: str = "evt3", frame_id: str = ""):
        if encoding not in ENCODINGS:
            raise ValueError(f"unknown event encoding {encoding!r}; choose from {', '.join(ENCODINGS)}")
        self.width, self.height, self.encoding, self.frame_id = width, height, encoding, frame_id
        self.seq = 0
        self._time_high: int | None = None  # where the last EVT3 packet left the clock
        self._evt3 = evt3.Evt3Encoder()
        self._scratch = np.empty(0, np.uint16)  # encode_many's words, reused

    def encode(self, t, x, y, p) -> EventPacket:
        if len(t) == 0:
            raise ValueError("a packet needs at least one event")
        t0_ns = int(t[0]) * _NS_PER_US
        if self.encoding == "evt3":
            payload = evt3_sensor_clock(t, x, y, p, self._time_high, self._evt3)
            self._time_high = int(t[-1]) >> 12
        else:
            payload = mono.encode(t, x, y, p, t0_ns)
        packet = EventPacket(events=payload, encoding=self.encoding, width=self.width, height=self.height,
                             seq=self.seq, time_base=t0_ns, stamp_ns=t0_ns, frame_id=self.frame_id)
        self.seq += 1
        return packet

    def encode_many(self, t, x, y, p, bounds) -> list[EventPacket]:
        """The packets of events bounds[j]:bounds[j+1] (each at least one event), as `encode` one after the
        other would make them, byte for byte; EVT3 payloads in one kernel call (views of one buffer), so a
        batch of packets gives up the GIL once. An event EVT3 cannot carry raises as `encode` does, the
        packets before it made."""
        bounds = np.ascontiguousarray(bounds, np.int64)
        m = len(bounds) - 1
        if self.encoding != "evt3" or m < 1 or len(t) == 0:
            return [self.encode(t[a:b], x[a:b], y[a:b], p[a:b]) for a, b in zip(bounds[:-1], bounds[1:])]
        t = np.ascontiguousarray(t, np.int64)
        x = np.ascontiguousarray(x, np.uint16)
        y = np.ascontiguousarray(y, np.uint16)
        p = np.ascontiguousarray(p, np.uint8)
        # room for each packet's worst case (Evt3Encoder's): 4 words an event, the TIME_HIGH steps from where
        # the clock was (wraps 5 words each) and the opening word
        last_high = t[bounds[1:] - 1] >> 12
        high = np.empty(m, np.int64)
        high[0] = int(t[bounds[0]]) >> 12 if self._time_high is None else self._time_high
        high[1:] = last_high[:-1]
        wraps = np.maximum((last_high >> 12) - (high >> 12), 0)
        ramp = np.maximum(5 * (wraps + 1) + (last_high - high) // evt3._MAX_HIGH_STEP + 2, 0)
        if wraps.max() > evt3.MAX_WRAPS_PER_CALL:  # refused one by one, with the reason
            return [self.encode(t[a:b], x[a:b], y[a:b], p[a:b]) for a, b in zip(bounds[:-1], bounds[1:])]
        room = 4 * int(bounds[-1] - bounds[0]) + m + int(ramp.sum())
        if len(self._scratch) < room:
            self._scratch = np.empty(room, np.uint16)
        ends = np.empty(m, np.int64)
        done = evt3._encode_packets_kernel(t, x, y, p, bounds, np.int64(-1 if self._time_high is None
                                                                          else self._time_high), self._scratch, ends)
        data = self._scratch[: ends[done - 1] if done else 0].tobytes()
        view = memoryview(data)
        starts = [0, *ends[: done - 1].tolist()] if done else []
        packets = []
        for j, (a, w0, w1) in enumerate(zip(bounds[:done].tolist(), starts, ends[:done].tolist())):
            t0_ns = int(t[a]) * _NS_PER_US
            packets.append(EventPacket(events=view[2 * w0 : 2 * w1], encoding="evt3", width=self.width,
                                       height=self.height, seq=self.seq + j, time_base=t0_ns, stamp_ns=t0_ns,
                                       frame_id=self.frame_id))
        if done:
            self.seq += done
            self._evt3.events_in += int(bounds[done] - bounds[0])  # an error later names the event as `encode`
            self._time_high = int(t[bounds[done] - 1]) >> 12
        for a, b in zip(bounds[done:-1].tolist(), bounds[done + 1 :].tolist()):  # what the kernel left: one by one
            packets.append(self.encode(t[a:b], x[a:b], y[a:b], p[a:b]))
        return packets


def to_packet(t, x, y, p, *, width: int, height: int, encoding: str = "evt3", seq: int = 0,
              frame_id: str = "") -> EventPacket:
    """One packet on its own (the clock starts at its first event); time_base = stamp = t[0] in ns."""
    enc = PacketEncoder(width=width, height=height, encoding=encoding, frame_id=frame_id)
    enc.seq = seq
    return enc.encode(t, x, y, p)


class PacketDecoder:
    """Decodes the packets of one channel, in order, into (t µs, x, y, p) arrays.

    `absolute` True: evstream's packets (each EVT3 packet decoded alone and placed by its time_base).
    False: other tools' packets (one EVT3 stream across packets; time_base ignored for evt3).
    `counters` sums the EVT3 decoder's counters (unknown words, triggers, time steps back, ...).
    """

    def __init__(self, absolute: bool = False):
        self.absolute = absolute
        self._stream = evt3.Evt3Decoder()
        self.counters = dict.fromkeys(evt3.COUNTER_NAMES, 0)

    def decode(self, packet: EventPacket):
        enc = packet.encoding  # exact, as event_camera_codecs matches it: "EVT3" is not "evt3"
        if enc == "evt3":
            if packet.is_bigendian:
                raise PacketError("evt3 packet marked big-endian: EVT3 words are little-endian")
            if self.absolute:
                dec = evt3.Evt3Decoder()
                t, x, y, p = dec.decode(packet.events)
                if len(t):  # time_base is the first event's time: that places the packet's clock
                    t += packet.time_base // _NS_PER_US - int(t[0])  # the decoder's own new array
                counts = dec.counters
            else:
                before = self._stream.counters
                t, x, y, p = self._stream.decode(packet.events)
                counts = {k: v - before[k] for k, v in self._stream.counters.items()}
            for k, v in counts.items():
                self.counters[k] += v
            return t, x, y, p
        if enc == "mono":
            try:
                return mono.decode(packet.events, packet.time_base, packet.is_bigendian)
            except ValueError as e:
                raise PacketError(str(e)) from None
        hint = "; encoding names are lower case, as in ROS 2's event_camera_codecs" if enc.lower() in ENCODINGS else ""
        raise PacketError(f"unsupported event encoding {packet.encoding!r} (readable: {', '.join(ENCODINGS)}){hint}")
