"""EventPacket CDR codec, the mono encoding and evstream's packet conventions, checked against independent
implementations: mcap_ros2's CDR serializer and parser, faery's EVT3 decoder, plain-Python references."""

from __future__ import annotations

import re

import numpy as np
import pytest
from codec_checks import packet_room
from hypothesis import given
from hypothesis import strategies as st
from mcap_ros2._dynamic import generate_dynamic, serialize_dynamic

from evstream.codecs import event_packet, evt3, mono, packets
from evstream.codecs.event_packet import (
    DATATYPE,
    MSGDEF,
    EventPacket,
    PacketError,
    decode_packet,
    encode_packet,
)

ROS_DECODE = generate_dynamic(DATATYPE, MSGDEF)[DATATYPE]
ROS_ENCODE = serialize_dynamic(DATATYPE, MSGDEF)[DATATYPE]

names = st.text(st.characters(blacklist_characters="\x00", blacklist_categories=("Cs",)), max_size=12)
event_packets = st.builds(
    EventPacket,
    events=st.binary(max_size=64),
    encoding=names,
    width=st.integers(0, 2**32 - 1),
    height=st.integers(0, 2**32 - 1),
    seq=st.integers(0, 2**64 - 1),
    time_base=st.integers(0, 2**64 - 1),
    stamp_ns=st.integers(-(2**31) * 10**9, 2**31 * 10**9 - 1),
    frame_id=names,
    is_bigendian=st.booleans(),
)


def _as_ros(pk: EventPacket) -> dict:
    sec, nanosec = pk.stamp
    return {"header": {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": pk.frame_id},
            "height": pk.height, "width": pk.width, "seq": pk.seq, "time_base": pk.time_base,
            "encoding": pk.encoding, "is_bigendian": pk.is_bigendian, "events": pk.events}


# -- CDR --------------------------------------------------------------------------------------------------
@given(event_packets)
def test_cdr_round_trip_and_bytes_match_mcap_ros2(pk):
    data = encode_packet(pk)
    assert decode_packet(data) == pk
    assert data == ROS_ENCODE(_as_ros(pk))  # byte for byte what mcap_ros2 serializes
    msg = ROS_DECODE(data)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == pk.stamp
    assert (msg.header.frame_id, msg.encoding, msg.width, msg.height) == (pk.frame_id, pk.encoding, pk.width,
                                                                          pk.height)
    assert (msg.seq, msg.time_base, msg.is_bigendian, bytes(msg.events)) == (pk.seq, pk.time_base,
                                                                             pk.is_bigendian, pk.events)


@given(event_packets)
def test_big_endian_encapsulation_round_trips(pk):
    data = encode_packet(pk, big_endian=True)
    assert data[:2] == b"\x00\x00"
    assert decode_packet(data) == pk
    assert ROS_DECODE(data).seq == pk.seq  # mcap_ros2 reads big-endian CDR too


def test_every_truncation_is_a_clear_error():
    data = encode_packet(EventPacket(events=bytes(range(40)), frame_id="cam", seq=7, width=346, height=260))
    for cut in range(len(data)):
        with pytest.raises(PacketError, match="EventPacket"):
            decode_packet(data[:cut])


def test_hostile_lengths_fail_before_allocating():
    good = bytearray(encode_packet(EventPacket(events=b"abcd", frame_id="c")))
    bad = bytearray(good)
    bad[-8:-4] = (0xFFFFFFF0).to_bytes(4, "little")  # events length: 4 GiB
    with pytest.raises(PacketError, match="events needs 4294967280 bytes"):
        decode_packet(bytes(bad))
    bad = bytearray(good)
    bad[12:16] = (1 << 30).to_bytes(4, "little")  # frame_id length
    with pytest.raises(PacketError, match="bad string length"):
        decode_packet(bytes(bad))
    with pytest.raises(PacketError, match="exceeds the limit"):
        decode_packet(bytes(good), max_bytes=10)
    with pytest.raises(PacketError, match="encapsulation"):
        decode_packet(b"\x00\x02\x00\x00" + bytes(good[4:]))
    bad = bytearray(good)
    bad[8:12] = (2_000_000_000).to_bytes(4, "little")  # nanosec >= 1e9
    with pytest.raises(PacketError, match="nanosec"):
        decode_packet(bytes(bad))


def test_encoder_refuses_values_that_do_not_fit():
    for kwargs in ({"seq": -1}, {"width": 2**32}, {"time_base": 2**64}, {"frame_id": "a\x00b"},
                   {"stamp_ns": 2**31 * 10**9}):
        with pytest.raises(PacketError):
            encode_packet(EventPacket(events=b"", **kwargs))



def _reads(frame_id: str, encoding: str, n_events: int) -> list[tuple[str, int, int]]:
    """(field, size, offset) of each read of a packet, as plain CDR lays it out: every field aligned to
    its size counted from the end of the 4-byte encapsulation header; a string is its uint32 length, then
    its bytes and a NUL."""
    fields = [("header.stamp.sec", 4), ("header.stamp.nanosec", 4), ("the length of header.frame_id", 4),
              ("header.frame_id", len(frame_id.encode()) + 1), ("height", 4), ("width", 4), ("seq", 8),
              ("time_base", 8), ("the length of encoding", 4), ("encoding", len(encoding.encode()) + 1),
              ("is_bigendian", 1), ("the length of events", 4), ("events", n_events)]
    out, pos = [], 4
    for what, size in fields:
        align = 1 if what in ("header.frame_id", "encoding", "events") else size
        pos += -(pos - 4) % align
        out.append((what, size, pos))
        pos += size
    return out


@pytest.mark.parametrize("big_endian", [False, True])
@pytest.mark.parametrize("frame_id,encoding", [("cam", "evt3"), ("camera", "mono"), ("", "x")])
def test_every_truncation_names_the_field_and_its_offset(big_endian, frame_id, encoding):
    data = encode_packet(EventPacket(events=bytes(range(13)), encoding=encoding, frame_id=frame_id, seq=7),
                         big_endian=big_endian)
    reads = _reads(frame_id, encoding, 13)
    assert reads[-1][1] + reads[-1][2] == len(data)
    for cut in range(len(data)):
        if cut < 4:
            want = f"^EventPacket of {cut} bytes is shorter than its 4-byte CDR header$"
        else:
            what, size, pos = next(r for r in reads if r[2] + r[1] > cut)
            want = f"^EventPacket truncated: {re.escape(what)} needs {size} bytes at offset {pos}, "
            if cut >= pos:  # (a cut inside the padding before a field leaves a negative count)
                want += f"{cut - pos} remain \\(packet of {cut} bytes\\)$"
        with pytest.raises(PacketError, match=want):
            decode_packet(data[:cut])
    assert decode_packet(data, max_bytes=len(data)).seq == 7


def test_every_field_at_its_limits_round_trips_byte_for_byte():
    for pk in (EventPacket(events=b"\xff", encoding="e" * 65535, width=2**32 - 1, height=2**32 - 1, seq=2**64 - 1,
                           time_base=2**64 - 1, stamp_ns=-(2**31) * 10**9, frame_id="f" * 65535, is_bigendian=True),
               EventPacket(events=b"", stamp_ns=2**31 * 10**9 - 1, width=2**31, height=2**31, seq=2**63,
                           time_base=2**63)):
        assert decode_packet(encode_packet(pk, big_endian=True)) == pk
        data = encode_packet(pk)
        assert decode_packet(data) == pk and data == ROS_ENCODE(_as_ros(pk))


def test_encoder_names_the_value_that_does_not_fit(monkeypatch):
    for name, bits in (("height", 32), ("width", 32), ("seq", 64), ("time_base", 64)):
        for bad in (-1, 2**bits):
            with pytest.raises(PacketError, match=rf"^EventPacket.{name} = {bad} does not fit uint{bits}$"):
                encode_packet(EventPacket(events=b"", **{name: bad}))
    for stamp_ns in (-(2**31) * 10**9 - 1, 2**31 * 10**9):
        with pytest.raises(PacketError,
                           match=rf"^EventPacket.stamp_ns = {stamp_ns} is outside the int32 seconds range$"):
            encode_packet(EventPacket(events=b"", stamp_ns=stamp_ns))
    for name in ("frame_id", "encoding"):
        with pytest.raises(PacketError, match=rf"^EventPacket.{name} contains a NUL character$"):
            encode_packet(EventPacket(events=b"", **{name: "a\x00"}))
        with pytest.raises(PacketError, match=rf"^EventPacket.{name} is 65536 bytes long; the limit is 65535$"):
            encode_packet(EventPacket(events=b"", **{name: "é" * 32768}))
    monkeypatch.setattr(event_packet, "MAX_PACKET_BYTES", 64)  # the 1 GiB limit, made small enough to test
    assert decode_packet(encode_packet(EventPacket(events=bytes(64)))).events == bytes(64)
    with pytest.raises(PacketError, match=r"^EventPacket.events is 65 bytes; the limit is 64$"):
        encode_packet(EventPacket(events=bytes(65)))


def _with(data: bytes, offset: int, raw: bytes) -> bytes:
    return data[:offset] + raw + data[offset + len(raw):]


def test_decoder_names_each_bad_value_and_its_offset():
    data = encode_packet(EventPacket(events=b"abcd", frame_id="cam", encoding="evt3"))
    reads = {what: pos for what, _, pos in _reads("cam", "evt3", 4)}
    u32 = lambda v: v.to_bytes(4, "little")  # noqa: E731
    flag = reads["is_bigendian"]
    for raw, at, why in (
        (u32(10**9), 8, f"EventPacket header.stamp.nanosec = {10**9} at offset 8 is not < 1e9"),
        (u32(2**32 - 1), 8, f"EventPacket header.stamp.nanosec = {2**32 - 1} at offset 8 is not < 1e9"),
        (u32(0), 12, "EventPacket header.frame_id: bad string length 0 at offset 12"),
        (u32(2**32 - 1), 12, f"EventPacket header.frame_id: bad string length {2**32 - 1} at offset 12"),
        (u32(65537), reads["the length of encoding"],
         f"EventPacket encoding: bad string length 65537 at offset {reads['the length of encoding']}"),
        (b"x", 19, "EventPacket header.frame_id: string at offset 16 lacks its terminating NUL"),
        (b"\xff", 17, "EventPacket header.frame_id: not UTF-8 at offset 16"),
        (b"\x02", flag, f"EventPacket is_bigendian = 2 at offset {flag} is not a bool"),
        (b"\xff", flag, f"EventPacket is_bigendian = 255 at offset {flag} is not a bool"),
        (b"\x00\x02", 0, "EventPacket: unsupported CDR encapsulation 0002 (plain CDR 0000 or 0001 expected)"),
    ):
        with pytest.raises(PacketError, match=f"^{re.escape(why)}$"):
            decode_packet(_with(data, at, raw))
    with pytest.raises(PacketError, match=rf"^EventPacket of {len(data)} bytes exceeds the limit of {len(data) - 1}$"):
        decode_packet(data, max_bytes=len(data) - 1)
    assert decode_packet(_with(data, 8, u32(10**9 - 1))).stamp_ns == 10**9 - 1
    assert decode_packet(_with(data, flag, b"\x01")).is_bigendian is True


# -- mono -------------------------------------------------------------------------------------------------
def mono_reference(data: bytes, time_base: int):
    """event_camera_msgs' mono layout, word by word, in plain Python."""
    out = []
    for i in range(0, len(data), 8):
        w = int.from_bytes(data[i : i + 8], "little")
        out.append(((time_base + (w & 0xFFFFFFFF)) // 1000, (w >> 32) & 0xFFFF, (w >> 48) & 0x7FFF, w >> 63))
    return out


@st.composite
def event_arrays(draw, max_x=65535, max_y=2047, span_us=4_000_000):
    n = draw(st.integers(0, 200))
    seed = draw(st.integers(0, 2**32 - 1))
    t0 = draw(st.integers(0, 2**40))
    rng = np.random.default_rng(seed)
    t = t0 + np.sort(rng.integers(0, span_us, n))
    return (t.astype(np.int64), rng.integers(0, max_x + 1, n).astype(np.uint16),
            rng.integers(0, max_y + 1, n).astype(np.uint16), rng.integers(0, 2, n).astype(np.uint8))


@given(event_arrays(max_y=32767))
def test_mono_round_trip_against_reference(ev):
    t, x, y, p = ev
    base = int(t[0]) * 1000 if len(t) else 0
    data = mono.encode(t, x, y, p, base)
    assert len(data) == 8 * len(t)
    got = mono.decode(data, base)
    for a, b in zip(got, ev):
        np.testing.assert_array_equal(a, b)
    assert mono_reference(data, base) == list(zip(*(a.tolist() for a in ev)))


def test_mono_refuses_what_it_cannot_carry():
    with pytest.raises(ValueError, match="dt must be"):
        mono.encode([0, 5_000_000], [1, 1], [1, 1], [0, 1], 0)  # 5 s > 2^32 ns
    with pytest.raises(ValueError, match="whole number"):
        mono.decode(b"\x00" * 12, 0)



def _mono_words(events, order: str) -> bytes:
    """Mono words built field by field in plain Python (dt ns, x, y, p), in byte order `order`."""
    return b"".join((dt | x << 32 | y << 48 | p << 63).to_bytes(8, order) for dt, x, y, p in events)


@pytest.mark.parametrize("big_endian", [False, True])
def test_mono_decode_reads_either_byte_order_into_its_dtypes(big_endian):
    base = 7_000_123_000
    events = [(0, 0, 0, 0), (999, 65535, 0x7FFF, 1), (mono.MAX_SPAN_NS, 300, 200, 1), (4_567_000, 1, 2, 0)]
    data = _mono_words(events, "big" if big_endian else "little")
    t, x, y, p = mono.decode(data, base, big_endian)
    assert (t.dtype, x.dtype, y.dtype, p.dtype) == (np.int64, np.uint16, np.uint16, np.uint8)
    assert t.tolist() == [(base + dt) // 1000 for dt, *_ in events]
    assert (x.tolist(), y.tolist(), p.tolist()) == tuple(list(c) for c in list(zip(*events))[1:])
    packet = EventPacket(events=data, encoding="mono", time_base=base, is_bigendian=big_endian)
    for got, want in zip(packets.PacketDecoder().decode(packet), (t, x, y, p)):
        assert got.dtype == want.dtype
        np.testing.assert_array_equal(got, want)


def test_mono_encode_takes_each_field_to_its_limit_and_not_past_it():
    t_us = 5_000_000  # t·1000 overflows int32: the times are widened before scaling
    widest = t_us * 1000 - mono.MAX_SPAN_NS  # dt = 2^32 - 1 ns, the largest
    for t in ([t_us], np.array([t_us], np.int32), np.array([t_us], np.uint32)):
        data = mono.encode(t, [65535], [0x7FFF], [1], widest)
        assert data == _mono_words([(mono.MAX_SPAN_NS, 65535, 0x7FFF, 1)], "little")
    for t, x, y, p in (([2, 3, 0], [4, 4, 4], [5, 5, 5], [0, 1, 0]), ([2, 3, 4], [4, 4, 4], [5, 5, 0x8000], [0, 1, 0]),
                       ([2, 3, 4], [4, 4, 4], [5, 5, 5], [0, 1, 2]),  # event 2 before the base, too low, no polarity
                       ([2, 3, 4], [4, 4, 65536], [5, 5, 5], [0, 1, 0]),  # x spilled into y's bits (session 9)
                       ([2, 3, 4], [4, 4, -1], [5, 5, 5], [0, 1, 0]), ([2, 3, 4], [4, 4, 4], [5, 5, -1], [0, 1, 0]),
                       ([2, 3, 4], [4, 4, 4], [5, 5, 5], [0, 1, -1])):  # negatives filled every field above them
        with pytest.raises(ValueError, match=rf"^mono.encode: event 2 \(t={t[2]} µs, x={x[2]}, y={y[2]}, p={p[2]}\) "
                                             r"cannot be written with time_base 1000 ns: dt must be 0..2\^32-1 ns, "
                                             r"x < 65536, y < 32768, p 0 or 1$"):
            mono.encode(t, np.array(x, np.int64), np.array(y, np.int64), np.array(p, np.int64), 1000)
    with pytest.raises(ValueError, match="dt must be"):
        mono.encode([1], [1], [1], [1], 1001)  # before the time base
    with pytest.raises(ValueError, match=r"^mono.encode: arrays differ in length \(t 2, x 2, y 1, p 2\)$"):
        mono.encode([1, 2], [1, 2], [1], [0, 1], 0)


# -- packets: evstream's conventions ---------------------------------------------------------------------
def _cut(ev, n_packets, seed):
    rng = np.random.default_rng(seed)
    n = len(ev[0])
    bounds = np.unique(np.concatenate([[0, n], rng.integers(1, max(n, 2), n_packets)]))
    bounds = bounds[bounds <= n]
    return [tuple(a[i:j] for a in ev) for i, j in zip(bounds[:-1], bounds[1:]) if j > i]


@given(event_arrays(max_x=2047, span_us=60_000_000), st.integers(1, 8), st.integers(0, 99))
def test_evt3_packets_decode_alone_and_as_one_stream(ev, n_packets, seed):
    parts = _cut(ev, n_packets, seed)
    enc = packets.PacketEncoder(width=2048, height=2048)
    pks = [enc.encode(*part) for part in parts]
    alone = packets.PacketDecoder(absolute=True)
    got = [alone.decode(decode_packet(encode_packet(pk))) for pk in pks]
    for a, b in zip(got, parts):
        for u, v in zip(a, b):
            np.testing.assert_array_equal(u, v)
    for i, (pk, part) in enumerate(zip(pks, parts)):
        assert pk.seq == i and pk.time_base == pk.stamp_ns == int(part[0][0]) * 1000
        first = int.from_bytes(pk.events[:2], "little")
        opening = part[0][0] if i == 0 else parts[i - 1][0][-1]  # where the clock was left
        assert first == 0x8000 | ((int(opening) >> 12) & 0xFFF)
    if parts:  # one stateful decoder over consecutive packets (event_camera_codecs' way), any gap
        stream = packets.PacketDecoder(absolute=False)
        t_stream = np.concatenate([stream.decode(pk)[0] for pk in pks])
        t_all = np.concatenate([part[0] for part in parts])
        np.testing.assert_array_equal(t_stream, t_all - (int(t_all[0]) >> 24 << 24))
        assert stream.counters["time_back"] == 0


@given(event_arrays(max_x=2047, span_us=60_000_000), st.integers(1, 12), st.integers(0, 99), st.booleans(),
       st.sampled_from([0, 5, 2047]))
def test_packets_encoded_at_once_are_those_encoded_one_by_one(ev, n_packets, seed, continued, bad_x):
    """`encode_many` (one kernel call for a batch's EVT3 packets) makes the packets `encode` makes one after
    the other, byte for byte, continuing the clock from where the previous batch left it, in one kernel call
    with a scratch of the packets' worst cases (`packet_room`); an event EVT3 cannot carry (x >= 2048) is
    refused with `encode`'s words, the packets before it made."""
    t, x, y, p = ev
    if not len(t):
        return
    if bad_x:
        x = x.copy()
        x[len(x) // 2] = 2048
    bounds = np.unique(np.concatenate([[0, len(t)], np.random.default_rng(seed).integers(1, len(t) + 1, n_packets)]))
    one, many = packets.PacketEncoder(width=2048, height=2048), packets.PacketEncoder(width=2048, height=2048)
    if continued:  # a previous batch left the clock earlier
        one.encode(t[:1] - 5_000_000 if t[0] >= 5_000_000 else t[:1], x[:1] % 2048, y[:1], p[:1])
        many.encode_many(t[:1] - 5_000_000 if t[0] >= 5_000_000 else t[:1], x[:1] % 2048, y[:1], p[:1], [0, 1])
    want, error = [], None
    for a, b in zip(bounds[:-1], bounds[1:]):
        try:
            want.append(encode_packet(one.encode(t[a:b], x[a:b], y[a:b], p[a:b])))
        except ValueError as e:
            error = str(e)
            break
    if error is None:
        before, high = len(many._scratch), -1 if many._time_high is None else many._time_high
        got = many.encode_many(t, x, y, p, bounds)
        assert [encode_packet(pk) for pk in got] == want
        assert (many.seq, many._time_high) == (one.seq, one._time_high)
        # in one kernel call (the payloads are views of one buffer), its scratch sized for the packets' worst cases
        assert all(isinstance(pk.events, memoryview) and pk.events.obj is got[0].events.obj for pk in got)
        rooms = [packet_room(t, a, b, high if a == 0 else int(t[a - 1]) >> 12) for a, b in zip(bounds[:-1], bounds[1:])]
        assert len(many._scratch) == max(before, sum(rooms))
    else:
        with pytest.raises(ValueError) as raised:
            many.encode_many(t, x, y, p, bounds)
        assert str(raised.value) == error


@pytest.mark.parametrize("encoding", ["evt3", "mono"])
def test_encode_many_takes_what_encode_takes(encoding):
    """`encode_many` in either encoding makes the packets `encode` makes one by one (mono's too); no bounds
    but 0 make no packet, events or none; one EVT3 packet is written by the kernel too; an empty packet and
    a negative x, y or p given as int64 (not wrapped into range) are refused with `encode`'s words."""
    ev = (np.array([5, 9, 9, 4200, 4200, 70_000]), np.array([1, 2, 3, 2047, 0, 5]), np.array([3, 3, 3, 0, 2047, 1]),
          np.array([0, 1, 1, 1, 0, 1]))
    new = lambda: packets.PacketEncoder(width=2048, height=2048, encoding=encoding)  # noqa: E731
    one = new()
    want = [encode_packet(one.encode(*(a[i:j] for a in ev))) for i, j in ((0, 1), (1, 4), (4, 6))]
    many = new()
    assert [encode_packet(pk) for pk in many.encode_many(*ev, [0, 1, 4, 6])] == want and many.seq == 3
    assert new().encode_many(*ev, [0]) == [] == new().encode_many(*(a[:0] for a in ev), [0])
    if encoding == "evt3":  # one packet in one kernel call too, its scratch sized from where the clock stands
        late = (ev[0][1:] + 3 * (1 << 24), *(a[1:] for a in ev[1:]))
        many = new()
        many.encode_many(*(a[:1] for a in ev), [0, 1])  # leaves the clock at time-high 0
        got = many.encode_many(*late, [0, 5])
        assert isinstance(got[0].events, memoryview) and len(many._scratch) == packet_room(late[0], 0, 5, 0)
    for bounds in ([0, 0], [0, 0, 0]):
        with pytest.raises(ValueError, match="^a packet needs at least one event$"):
            new().encode_many(*(a[:0] for a in ev), bounds)
    for field in (1, 2, 3):
        bad = [np.array(a, np.int64) for a in ev]
        bad[field][4] = -1
        by_one = new()
        by_one.encode(*(a[:4] for a in bad))
        with pytest.raises(ValueError) as refused:
            by_one.encode(*(a[4:] for a in bad))
        with pytest.raises(ValueError, match=f"^{re.escape(str(refused.value))}$"):
            new().encode_many(*bad, [0, 4, 6])


def test_encode_many_from_any_bounds_and_up_to_the_largest_jump():
    """EVT3 `encode_many` (one kernel call): bounds that start past event 0 (its scratch is still the packets'
    worst cases, and a later error counts only the events written); a fresh encoder's clock from the first
    event; a jump of exactly MAX_WRAPS_PER_CALL wraps in the kernel too, one more refused with `encode`'s
    words after the packets before it."""
    wrap, top = 1 << 24, evt3.MAX_WRAPS_PER_CALL
    ev = (np.array([5, 9, 9, 4200, 3 * wrap + 7, 3 * wrap + 8]), np.array([1, 2, 3, 2047, 0, 5]),
          np.array([3, 3, 3, 0, 2047, 1]), np.array([0, 1, 1, 1, 0, 1]))
    new = lambda: packets.PacketEncoder(width=2048, height=2048)  # noqa: E731
    cases = [([1, 3, 4], ev), ([0, 2], tuple(a[4:] for a in ev)),
             ([0, 1, 2], (np.array([5, top * wrap + 5]), *(a[:2] for a in ev[1:])))]
    for bounds, (t, x, y, p) in cases:
        one, many = new(), new()
        want = [encode_packet(one.encode(t[a:b], x[a:b], y[a:b], p[a:b])) for a, b in zip(bounds[:-1], bounds[1:])]
        got = many.encode_many(t, x, y, p, bounds)
        assert [encode_packet(pk) for pk in got] == want and all(isinstance(pk.events, memoryview) for pk in got)
        rooms = [packet_room(t, a, b, -1 if a == bounds[0] else int(t[a - 1]) >> 12)
                 for a, b in zip(bounds[:-1], bounds[1:])]
        assert len(many._scratch) == sum(rooms) and many.seq == one.seq
        bad = (np.array([t[-1]]), np.array([0]), np.array([2048]), np.array([0]))
        with pytest.raises(ValueError) as refused:
            one.encode(*bad)
        with pytest.raises(ValueError, match=f"^{re.escape(str(refused.value))}$"):
            many.encode(*bad)
    t = np.array([5, 6, (top + 1) * wrap + 5])
    many = new()
    with pytest.raises(ValueError, match=rf"^encode: timestamps jump from 0 to {(top + 1) * wrap + 5} µs "):
        many.encode_many(t, *(a[:3] for a in ev[1:]), [0, 2, 3])
    assert many.seq == 1 and many._time_high == 0


def test_faery_decodes_our_packets_identically(tmp_path):
    import faery  # declared (dev) dependency: a broken install fails
    rng = np.random.default_rng(5)
    n = 30_000
    t = np.sort(rng.integers(3_000_000, 50_000_000, n)).astype(np.int64)  # crosses two 24-bit wraps
    x = rng.integers(0, 1280, n).astype(np.uint16)
    y = rng.integers(0, 720, n).astype(np.uint16)
    p = rng.integers(0, 2, n).astype(np.uint8)
    t[500:560], y[500:560], p[500:560], x[500:560] = t[500], 7, 1, np.arange(100, 160)  # vectors
    t[560:] = np.maximum(t[560:], t[500])
    t[20_000:] += 40_000_000  # a 40 s gap: two unspoken wraps between two packets
    enc = packets.PacketEncoder(width=1280, height=720)
    body = b"".join(enc.encode(t[a : a + 997], x[a : a + 997], y[a : a + 997], p[a : a + 997]).events
                    for a in range(0, n, 997))
    path = tmp_path / "packets.raw"
    path.write_bytes(b"% evt 3.0\n% format EVT3;height=720;width=1280\n% end\n" + body)
    ev = np.concatenate([c for c in faery.events_stream_from_file(path) if len(c)])
    epoch = int(t[0]) >> 24 << 24
    np.testing.assert_array_equal(ev["t"].astype(np.int64) + epoch, t)
    np.testing.assert_array_equal(ev["x"], x)
    np.testing.assert_array_equal(ev["y"], y)
    np.testing.assert_array_equal(ev["on"].astype(np.uint8), p)
    np.testing.assert_array_equal(evt3.decode(body)[0] + epoch, t)


def test_unknown_encoding_and_unknown_words():
    with pytest.raises(ValueError, match="unknown event encoding"):
        packets.to_packet([1], [1], [1], [1], width=4, height=4, encoding="evt9")
    with pytest.raises(PacketError, match="unsupported event encoding"):
        packets.PacketDecoder().decode(EventPacket(events=b"", encoding="evt9"))
    pk = packets.to_packet(np.array([5, 9]), np.array([1, 2]), np.array([3, 3]), np.array([0, 1]), width=4, height=4)
    junk = EventPacket(events=pk.events[:2] + b"\x00\xd0\x00\x90" + pk.events[2:], time_base=pk.time_base)
    dec = packets.PacketDecoder(absolute=True)
    t, x, y, p = dec.decode(junk)  # 0xD and 0x9 word types are unknown: skipped and counted
    assert t.tolist() == [5, 9] and x.tolist() == [1, 2]
    assert dec.counters["unknown"] == 2


def test_unix_time_packets_stay_small_in_memory():
    """AEDAT4 stamps events in Unix µs (~1.7e15): a packet must not size its buffers by that."""
    import tracemalloc

    t = np.arange(1000, dtype=np.int64) * 7 + 1_700_000_000_000_000
    z = np.zeros(1000, np.uint16)
    enc = packets.PacketEncoder(width=4, height=4)
    enc.encode(t, z, z, z.astype(np.uint8))  # compile
    tracemalloc.start()
    try:
        pk = enc.encode(t + 10**6, z, z, z.astype(np.uint8))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1_000_000
    np.testing.assert_array_equal(packets.PacketDecoder(absolute=True).decode(pk)[0], t + 10**6)


def test_evt3_sensor_clock_alone():
    """Without an encoder, from the first event's time-high; empty, negative or a clock past the first event."""
    t, x, y, p = np.array([5000, 5000, 9000]), np.array([1, 2, 3]), np.array([4, 4, 6]), np.array([1, 0, 1])
    data = packets.evt3_sensor_clock(t, x, y, p)
    assert data[:2] == (0x8000 | 1).to_bytes(2, "little")
    assert [a.tolist() for a in evt3.decode(data)] == [t.tolist(), x.tolist(), y.tolist(), p.tolist()]
    assert packets.evt3_sensor_clock(t, x, y, p, from_time_high=0) == (0x8000).to_bytes(2, "little") + data
    assert packets.evt3_sensor_clock(t[:0], x[:0], y[:0], p[:0]) == b""
    with pytest.raises(ValueError, match=r"^evt3: event 0 has t=-1 µs; EVT3 needs t >= 0$"):
        packets.evt3_sensor_clock(np.array([-1]), x[:1], y[:1], p[:1])
    with pytest.raises(ValueError, match=r"^evt3: the clock is at time-high 2, past the first event \(t=5000 µs\)$"):
        packets.evt3_sensor_clock(t, x, y, p, from_time_high=2)


def test_packet_opening_one_microsecond_past_its_time_high_decodes_alone():
    """A first event at time-low 1 still gets its TIME_LOW word, and one on row 1 its ADDR_Y (the clock's low
    and row start as none, not 0 or 1): packets one by one and at once."""
    for low in (0, 1, 2):
        for row in (0, 1, 2):
            ev = (np.array([(7 << 12) | low, (7 << 12) | low, (9 << 12) | 1]), np.array([3, 8, 9], np.uint16),
                  np.array([row, row, 2], np.uint16), np.array([0, 1, 1], np.uint8))
            alone = packets.to_packet(*ev, width=16, height=16)
            at_once = packets.PacketEncoder(width=16, height=16).encode_many(*ev, [0, 3])
            for pk in (alone, *at_once):
                got = packets.PacketDecoder(absolute=True).decode(pk)
                assert [a.tolist() for a in got] == [a.tolist() for a in ev]


def test_to_packet_and_the_encoder_fill_every_field():
    one = (np.array([5, 9]), np.array([1, 2]), np.array([3, 3]), np.array([0, 1]))
    pk = packets.to_packet(*one, width=640, height=480)
    assert (pk.encoding, pk.width, pk.height, pk.seq, pk.time_base, pk.stamp_ns, pk.frame_id, pk.is_bigendian) == (
        "evt3", 640, 480, 0, 5000, 5000, "", False)
    pk = packets.to_packet(*one, width=3, height=4, encoding="mono", seq=7, frame_id="cam0")
    assert (pk.encoding, pk.width, pk.height, pk.seq, pk.frame_id) == ("mono", 3, 4, 7, "cam0")
    enc = packets.PacketEncoder(width=3, height=4)
    assert [enc.encode(*one).seq for _ in range(3)] == [0, 1, 2] and enc.encode(*one).frame_id == ""
    with pytest.raises(ValueError, match=r"^unknown event encoding 'EVT3'; choose from evt3, mono$"):
        packets.PacketEncoder(width=3, height=4, encoding="EVT3")
    with pytest.raises(ValueError, match=r"^a packet needs at least one event$"):
        enc.encode(*(a[:0] for a in one))


def test_packet_encoder_names_a_bad_event_by_its_place_in_the_stream():
    """Its packets continue one EVT3 encoder: event 1 of the second packet is the stream's event 4."""
    enc = packets.PacketEncoder(width=4096, height=16)
    enc.encode(np.array([1, 2, 3]), np.array([0, 1, 2]), np.array([0, 0, 0]), np.array([0, 0, 0]))
    with pytest.raises(ValueError, match=r"^encode: event 4 \(t=5 µs, previous 4 µs, x=3000,"):
        enc.encode(np.array([4, 5]), np.array([0, 3000]), np.array([0, 0]), np.array([0, 0]))


def test_packet_decoder_reads_other_tools_packets_as_one_stream_by_default():
    """Default (not absolute): time_base ignored for evt3; absolute: each packet placed by it, in int64 µs."""
    pk = packets.to_packet(np.array([5, 9]), np.array([1, 2]), np.array([3, 3]), np.array([0, 1]), width=4, height=4)
    moved = EventPacket(events=pk.events, time_base=3_000_000_123_456_789)
    assert packets.PacketDecoder().decode(moved)[0].tolist() == [5, 9]
    t = packets.PacketDecoder(absolute=True).decode(moved)[0]
    assert t.dtype == np.int64 and t.tolist() == [3_000_000_123_456, 3_000_000_123_460]


@pytest.mark.parametrize("absolute", [False, True])
def test_packet_decoder_sums_the_counters_of_every_packet(absolute):
    enc = packets.PacketEncoder(width=4, height=4)
    dec = packets.PacketDecoder(absolute=absolute)
    for i in range(3):
        pk = enc.encode(np.array([5, 9]) + 10 * i, np.array([1, 2]), np.array([3, 3]), np.array([0, 1]))
        junk = b"\x00\xd0" * (i + 1)  # i + 1 words of the unknown type 0xD after the opening TIME_HIGH
        dec.decode(EventPacket(events=pk.events[:2] + junk + pk.events[2:], time_base=pk.time_base))
        assert dec.counters["unknown"] == (i + 1) * (i + 2) // 2


def test_packet_decoder_errors_name_what_is_wrong():
    with pytest.raises(PacketError, match=r"^evt3 packet marked big-endian: EVT3 words are little-endian$"):
        packets.PacketDecoder().decode(EventPacket(events=b"", encoding="evt3", is_bigendian=True))
    with pytest.raises(PacketError, match=r"^mono.decode: 12 bytes is not a whole number of 8-byte events$"):
        packets.PacketDecoder().decode(EventPacket(events=bytes(12), encoding="mono"))
    with pytest.raises(PacketError, match=r"^unsupported event encoding 'evt9' \(readable: evt3, mono\)$"):
        packets.PacketDecoder().decode(EventPacket(events=b"", encoding="evt9"))
    with pytest.raises(PacketError, match=r"^unsupported event encoding 'Mono' \(readable: evt3, mono\); encoding "
                                          r"names are lower case, as in ROS 2's event_camera_codecs$"):
        packets.PacketDecoder().decode(EventPacket(events=b"", encoding="Mono"))
