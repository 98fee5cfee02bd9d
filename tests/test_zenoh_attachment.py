"""Attachments (evstream's and rmw_zenoh's, the latter checked against Zenoh's own serializer), camera names
from keys, packetizing a stream for publication, and the subscriber's handling of samples in one process."""

from __future__ import annotations

import re

import numpy as np
import pytest
import zenoh.ext as zext
from evstream.sources.zenoh_sub import camera_of
from hypothesis import given
from hypothesis import strategies as st

from evstream.cli.publish import packetize
from evstream.codecs.attachment import (
    OURS,
    RMW_ZENOH,
    AttachmentError,
    decode_attachment,
    encode_attachment,
    encode_rmw_attachment,
)
from evstream.events import EventChunk, Geometry, concat

i64 = st.integers(-(1 << 63), (1 << 63) - 1)


@given(st.integers(0, (1 << 64) - 1), i64)
def test_our_attachment_round_trips(seq, t):
    a = decode_attachment(encode_attachment(seq, t))
    assert (a.seq, a.source_time_ns, a.kind) == (seq, t, OURS)


@given(st.integers(0, (1 << 63) - 1), i64, st.sampled_from([16, 24]))
def test_rmw_attachment_matches_zenoh_serializer(seq, t, gid_len):
    gid = bytes(range(gid_len))
    theirs = zext.z_serialize((zext.Int64(seq), zext.Int64(t), gid)).to_bytes()  # how rmw_zenoh writes it
    assert encode_rmw_attachment(seq, t, gid) == theirs
    a = decode_attachment(theirs)
    assert (a.seq, a.source_time_ns, a.kind, a.gid) == (seq, t, RMW_ZENOH, gid)


def test_rmw_attachment_refuses_a_gid_its_one_byte_length_cannot_say():
    theirs = zext.z_serialize((zext.Int64(1), zext.Int64(2), bytes(127))).to_bytes()
    assert encode_rmw_attachment(1, 2, bytes(127)) == theirs  # 127: the longest a one-byte LEB128 holds
    with pytest.raises(ValueError, match="^gid too long for a one-byte LEB128 length$"):
        encode_rmw_attachment(1, 2, bytes(128))


@pytest.mark.parametrize("bad", [b"", b"\x01" * 15, b"\x00" * 16 + b"\x05abc", b"\x00" * 16 + b"\xff" * 12,
                                 b"\x00" * 17])
def test_bad_attachments_are_errors(bad):
    if len(bad) == 17:  # a GID of length 0 is well formed
        assert decode_attachment(bad).gid == b""
        return
    with pytest.raises(AttachmentError):
        decode_attachment(bad)



@pytest.mark.parametrize("gid_len", [0, 1, 17, 63, 64, 65, 127, 128, 200, 16_383, 16_384, 20_000])
def test_rmw_gid_length_is_read_as_leb128_whatever_its_size(gid_len):
    """Zenoh writes the GID's length as LEB128 (2 bytes from 128, 3 from 16,384): read back exactly, and a
    GID longer than 64 bytes is refused naming the length it read."""
    theirs = zext.z_serialize((zext.Int64(5), zext.Int64(-6), bytes(range(256)) * (gid_len // 256) +
                               bytes(range(gid_len % 256)))).to_bytes()
    if gid_len <= 64:
        a = decode_attachment(theirs)
        assert (a.seq, a.source_time_ns, a.kind, len(a.gid)) == (5, -6, RMW_ZENOH, gid_len)
    else:
        with pytest.raises(AttachmentError, match=rf"^attachment of {len(theirs)} bytes: GID length {gid_len} at "
                                                  "byte 16 does not fit$"):
            decode_attachment(theirs)


def test_bad_attachments_say_what_is_wrong():
    for bad, why in ((b"\x01" * 15, "attachment of 15 bytes: neither evstream's (16) nor rmw_zenoh's layout"),
                     (b"\x00" * 16 + b"\x80" * 10 + b"\x00", "attachment: unterminated LEB128 length at byte 16"),
                     (b"\xff" * 16 + b"\x00", "attachment: negative sequence number -1")):
        with pytest.raises(AttachmentError, match=f"^{re.escape(why)}$"):
            decode_attachment(bad)


@pytest.mark.parametrize("key,camera", [
    ("evstream/cam1/events", "cam1"),
    ("evstream/cam1/events/clean", "cam1"),
    ("0/dvs/events/event_camera_msgs::msg::dds_::EventPacket_/RIHS01_" + "0" * 64, "dvs"),
    ("3/robot/left/events/event_camera_msgs::msg::dds_::EventPacket_/TypeHashNotSupported", "left"),
    ("0/events/event_camera_msgs::msg::dds_::EventPacket_/RIHS01_x", "events"),
    ("lab/stream", "lab_stream"),
])
def test_camera_of_key(key, camera):
    assert camera_of(key) == camera


@given(st.lists(st.integers(0, 30_000), min_size=1, max_size=300), st.integers(1, 40), st.integers(100, 5000))
def test_packetize_cuts_on_the_grid_and_keeps_every_event(dts, n_chunks, packet_us):
    t = np.cumsum(np.asarray(dts, np.int64))
    g = Geometry(16, 16)
    ev = EventChunk.from_arrays(t, t % 16, (t // 16) % 16, t % 2, g)
    cuts = np.linspace(0, len(t), min(n_chunks, len(t)) + 1).astype(int)
    packets = list(packetize([ev[a:b] for a, b in zip(cuts[:-1], cuts[1:])], packet_us))
    assert np.array_equal(concat(packets, g).t, t)
    cells = [set((p.t // packet_us).tolist()) for p in packets]
    assert all(len(c) == 1 for c in cells)  # one grid cell per packet
    assert len({next(iter(c)) for c in cells}) == len(cells)  # each cell once


def test_encoding_names_are_lower_case_as_in_event_camera_codecs():
    """event_camera_codecs matches "evt3" and "mono" exactly; so does PacketDecoder (live and MCAP)."""
    import dataclasses

    from evstream.codecs.event_packet import PacketError
    from evstream.codecs.packets import PacketDecoder, to_packet

    t = np.arange(10, dtype=np.int64) * 7
    x = y = np.arange(10, dtype=np.uint16)
    p = np.ones(10, np.uint8)
    for enc in ("evt3", "mono"):
        packet = to_packet(t, x, y, p, width=16, height=16, encoding=enc)
        for absolute in (True, False):
            assert np.array_equal(PacketDecoder(absolute=absolute).decode(packet)[0], t)
            for other in (enc.upper(), enc.capitalize()):
                with pytest.raises(PacketError, match="lower case"):
                    PacketDecoder(absolute=absolute).decode(dataclasses.replace(packet, encoding=other))
