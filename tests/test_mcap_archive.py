"""MCAP archives for real: write with `McapSink`, read back with `sources.mcap_log`, and open the same
files with the independent readers other tools use (mcap, mcap_ros2, faery, Rerun's MCAP loader)."""

from __future__ import annotations

import dataclasses
import re
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from evstream.sinks.mcap_sink import McapSink, topics
from evstream.sources import mcap_log, open_source
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer as Ros2Writer

from evstream.codecs import evt3, mono
from evstream.codecs.event_packet import DATATYPE, MSGDEF
from evstream.events import EventChunk, EventError, Frame, Geometry, NoiseClass, concat
from evstream.pipeline import Batch, Pipeline, RunStats
from evstream.testing import random_bounds, random_stream, split

G = Geometry(64, 48)


def classified(seed, n, geometry=G, t0_us=0) -> EventChunk:
    """A random stream whose `cls` is its ground truth (what a perfect denoiser would write)."""
    s = random_stream(seed, n, geometry, t0_us=t0_us)
    return dataclasses.replace(s, cls=s.label.copy())


def archive(path, chunks, **kwargs) -> McapSink:
    sink = McapSink(path, **{"frames": False, **kwargs})
    Pipeline([]).run(chunks, [sink])
    return sink


def canonical(s: EventChunk) -> EventChunk:
    """The order an archive gives back: by time; equal times by class; otherwise stream order."""
    return s[np.lexsort((s.classes(), s.t))]


def assert_same(got: EventChunk, want: EventChunk, with_cls=True):
    assert len(got) == len(want)
    for f in "txyp":
        np.testing.assert_array_equal(getattr(got, f), getattr(want, f), err_msg=f)
    if with_cls:
        np.testing.assert_array_equal(got.cls, want.cls)


def test_an_unknown_class_is_refused_by_name(tmp_path):
    s = classified(1, 50)
    cls = s.cls.copy()
    cls[20] = 7
    sink = McapSink(tmp_path / "a.mcap", frames=False)
    with pytest.raises(EventError, match="event 20 has noise class 7"):
        sink.write(Batch(s.replace(cls=cls), [], RunStats()))


# -- round trip ---------------------------------------------------------------------------------------------
@given(seed=st.integers(0, 10_000), n=st.integers(1, 3000), packet_us=st.sampled_from([1, 700, 5_000, 10**6]),
       max_packet=st.sampled_from([1, 37, 200_000]), t0=st.sampled_from([0, 16_777_000, 10**11]),
       encoding=st.sampled_from(["evt3", "mono"]))
def test_events_and_classes_round_trip(tmp_path_factory, seed, n, packet_us, max_packet, t0, encoding):
    s = classified(seed, n, t0_us=t0)
    path = tmp_path_factory.mktemp("rt") / "a.mcap"
    archive(path, split(s, random_bounds(seed, n)), keep_noise=True, packet_us=packet_us,
            max_packet_events=max_packet, encoding=encoding)
    src = open_source(path, chunk_events=int(np.random.default_rng(seed).integers(1, 5000)))
    assert src.archive and src.geometry == G
    got = concat(list(src))
    assert_same(got, canonical(s))
    assert not src.truncated


def _packets_in_file_order(path):
    with open(path, "rb") as f:
        reader = make_reader(f)
        return [(channel.topic, msg.log_time, bytes(msg.data))
                for _, channel, msg in reader.iter_messages(log_time_order=False)]


@given(seed=st.integers(0, 10_000), n=st.integers(1, 400))
def test_archive_content_does_not_depend_on_chunking(tmp_path_factory, seed, n):
    s = classified(seed, n)
    folder = tmp_path_factory.mktemp("ci")
    archive(folder / "one.mcap", [s], keep_noise=True, packet_us=500, max_packet_events=7)
    archive(folder / "single.mcap", [s[i : i + 1] for i in range(n)], keep_noise=True, packet_us=500,
            max_packet_events=7)
    archive(folder / "random.mcap", split(s, random_bounds(seed, n)), keep_noise=True, packet_us=500,
            max_packet_events=7)
    one = _packets_in_file_order(folder / "one.mcap")
    assert one == _packets_in_file_order(folder / "single.mcap") == _packets_in_file_order(folder / "random.mcap")


def test_one_noise_topic_reads_back_with_its_class(tmp_path):
    s = classified(12, 3000)
    archive(tmp_path / "a.mcap", [s], keep_noise=True)
    got = concat(list(open_source(tmp_path / "a.mcap", topic="/camera/events/noise/hot_pixel")))
    assert_same(got, s[s.cls == 2])
    assert set(got.cls.tolist()) == {2}


def test_signal_only_archive_keeps_stream_order_and_drops_nothing_else(tmp_path):
    s = classified(3, 5000)
    sink = archive(tmp_path / "a.mcap", split(s, random_bounds(1, len(s))))
    got = concat(list(open_source(tmp_path / "a.mcap")))
    assert_same(got, s[s.cls == 0], with_cls=False)
    assert got.cls is None
    assert sink.events_written.tolist() == [int((s.cls == 0).sum()), 0, 0]
    names = {c.topic for c in make_reader(open(tmp_path / "a.mcap", "rb")).get_summary().channels.values()}
    assert names == {"/camera/events"}  # noise not kept: no noise topics


def test_packets_follow_the_grid_and_the_watermark(tmp_path):
    s = classified(4, 4000)
    archive(tmp_path / "a.mcap", split(s, random_bounds(2, len(s))), keep_noise=True, packet_us=2_000)
    with open(tmp_path / "a.mcap", "rb") as f:
        reader = make_reader(f)
        cells = []
        for _, channel, msg in reader.iter_messages(log_time_order=False):
            t = DecoderFactory().decoder_for("cdr", reader.get_summary().schemas[channel.schema_id])(msg.data)
            ts = evt3.decode(bytes(t.events))[0]
            ts = ts + (t.time_base // 1000 - ts[0])  # decoded alone, placed by time_base (docs/archive.md)
            assert t.time_base == msg.log_time == msg.publish_time
            assert (t.header.stamp.sec * 10**9 + t.header.stamp.nanosec) == t.time_base
            assert ts[0] // 2000 == ts[-1] // 2000  # one grid cell per packet
            cells.append(ts[0] // 2000)
    assert cells == sorted(cells)  # written cell by cell across all topics


# -- interop ------------------------------------------------------------------------------------------------
def test_mcap_ros2_and_faery_decode_our_packets(tmp_path):
    import faery  # declared (dev) dependency: a broken install fails
    from mcap.reader import make_reader as reader_of

    s = classified(5, 20_000, Geometry(346, 260), t0_us=16_000_000)  # crosses the 24-bit wrap
    path = tmp_path / "a.mcap"
    archive(path, split(s, random_bounds(5, len(s))), keep_noise=True, packet_us=3_000)
    by_topic: dict[str, list] = {}
    with open(path, "rb") as f:
        for schema, channel, _, msg in reader_of(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
                log_time_order=False):
            assert schema.name == DATATYPE and channel.message_encoding == "cdr"
            assert (msg.width, msg.height, msg.encoding) == (346, 260, "evt3")
            assert msg.header.frame_id == "camera"
            by_topic.setdefault(channel.topic, []).append(msg)
    names = topics("camera")
    for cls, key in ((0, "signal"), (1, "background"), (2, "hot_pixel")):
        msgs = by_topic[names[key]]
        assert [m.seq for m in msgs] == list(range(len(msgs)))
        body = b"".join(bytes(m.events) for m in msgs)
        raw = tmp_path / f"{key}.raw"
        raw.write_bytes(b"% evt 3.0\n% format EVT3;height=260;width=346\n% end\n" + body)
        ev = np.concatenate([c for c in faery.events_stream_from_file(raw) if len(c)])
        want = s[s.cls == cls]
        epoch = int(want.t[0]) >> 24 << 24
        np.testing.assert_array_equal(ev["t"].astype(np.int64) + epoch, want.t)
        np.testing.assert_array_equal(ev["x"], want.x)
        np.testing.assert_array_equal(ev["y"], want.y)
        np.testing.assert_array_equal(ev["on"].astype(np.uint8), want.p)


def _frames(n=4, geometry=G):
    rng = np.random.default_rng(0)
    out = []
    for i in range(n):
        counts = rng.integers(0, 3, (2, geometry.height, geometry.width)).astype(np.uint16)
        out.append(Frame(10_000 * i, 10_000 * (i + 1), int(counts.sum()), counts))
    return out


def paper_look(counts: np.ndarray) -> np.ndarray:
    """The frame as docs/framing.md describes it, written here rather than taken from the sink: mid-grey
    128, white 255 where a pixel's ON events outnumber its OFF events, black 0 where OFF outnumber ON."""
    off, on = counts[0].astype(np.int64), counts[1].astype(np.int64)
    return np.select([on > off, off > on], [255, 0], 128).astype(np.uint8)


@pytest.mark.parametrize("frame_format", ["foxglove", "ros2"])
def test_rerun_mcap_loader_shows_the_frames(tmp_path, frame_format):
    frames = _frames()
    s = classified(6, 500)
    path = tmp_path / "f.mcap"
    points_on = frame_format == "foxglove"
    sink = McapSink(path, frames=True, frame_format=frame_format, points=points_on)
    stats = RunStats()
    sink.write(Batch(s, frames[:2], stats))
    sink.write(Batch(EventChunk.empty(G, t_end=s.t_end, with_cls=True), frames[2:], stats))
    sink.close(stats)
    rrd = tmp_path / "f.rrd"
    rerun = Path(sys.executable).parent / "rerun"
    subprocess.run([str(rerun), "mcap", "convert", str(path), "-o", str(rrd)], check=True, capture_output=True,
                   timeout=120)
    from rerun.chunk import RrdReader

    images, points = [], 0
    for chunk in RrdReader(str(rrd)).stream():
        rb = chunk.to_record_batch()
        if chunk.entity_path == "/camera/frames" and "Image:buffer" in rb.schema.names:
            images += rb.column(rb.schema.names.index("Image:buffer")).to_pylist()
        if chunk.entity_path == "/camera/events/points" and "Points3D:positions" in rb.schema.names:
            points += sum(len(r) for r in rb.column(rb.schema.names.index("Points3D:positions")).to_pylist() if r)
    assert len(images) == len(frames)
    for buf, frame in zip(images, frames):
        pixels = np.asarray(buf[0], np.uint8).reshape(G.height, G.width, -1)  # mono8, or rgb8 for ros2
        for c in range(pixels.shape[2]):
            np.testing.assert_array_equal(pixels[:, :, c], paper_look(frame.counts))
    assert points == (len(s) if points_on else 0)
    with open(path, "rb") as f:  # frames as sensor_msgs/Image keep the whole file ROS 2 (the mcap profile says so)
        assert make_reader(f).get_header().profile == ("ros2" if frame_format == "ros2" else "")


def test_ros2_image_bytes_match_mcap_ros2():
    from evstream.sinks.mcap_sink import IMAGE_DATATYPE, IMAGE_MSGDEF, ros2_image
    from mcap_ros2._dynamic import serialize_dynamic

    img = np.arange(12, dtype=np.uint8).reshape(3, 4)
    rgb = np.repeat(img[:, :, None], 3, axis=2)
    want = serialize_dynamic(IMAGE_DATATYPE, IMAGE_MSGDEF)[IMAGE_DATATYPE](
        {"header": {"stamp": {"sec": 5, "nanosec": 123456789}, "frame_id": "cam"}, "height": 3, "width": 4,
         "encoding": "rgb8", "is_bigendian": 0, "step": 12, "data": rgb.tobytes()})
    assert ros2_image(img, 5_123_456_789, "cam") == want


def test_provenance_and_stats_metadata(tmp_path):
    s = classified(7, 1000)
    path = tmp_path / "m.mcap"
    sink = McapSink(path, keep_noise=True, frames=False,
                    metadata={"pipeline": {"stages": [{"kind": "paper"}]}, "source": "x.npz"})
    Pipeline([]).run([s], [sink])
    meta = mcap_log.read_metadata(path)
    prov = mcap_log.provenance(path)
    assert prov["pipeline"] == {"stages": [{"kind": "paper"}]} and prov["source"] == "x.npz"
    assert prov["keep_noise"] is True and prov["packet_us"] == 10_000
    assert int(meta["evstream.stats"]["events_background"]) == int((s.cls == 1).sum())
    assert int(meta["evstream.stats"]["run_events_in"]) == len(s)
    with open(path, "rb") as f:
        chunk_indexes = make_reader(f).get_summary().chunk_indexes
    assert chunk_indexes and {c.compression for c in chunk_indexes} == {"zstd"}
    import mcap.writer
    import zstandard

    assert mcap.writer.zstandard is zstandard  # our level-1 compressor was swapped in only while closing chunks


# -- other tools' files ---------------------------------------------------------------------------------------
def _foreign(path, packets_spec, topic="/dvs/events"):
    """An MCAP written by mcap_ros2's own writer, the way a ROS 2 driver fills EventPackets."""
    with open(path, "wb") as f:
        w = Ros2Writer(f)
        schema = w.register_msgdef(DATATYPE, MSGDEF)
        for i, (encoding, payload, time_base) in enumerate(packets_spec):
            msg = {"header": {"stamp": {"sec": 1_700_000_000 + i, "nanosec": 0}, "frame_id": "dvs"},
                   "height": 480, "width": 640, "seq": i, "time_base": time_base, "encoding": encoding,
                   "is_bigendian": False, "events": payload}
            w.write_message(topic, schema, msg, log_time=(1_700_000_000 + i) * 10**9)
        w.finish()


def test_reads_other_tools_evt3_as_one_stream_and_mono_by_time_base(tmp_path):
    rng = np.random.default_rng(8)
    n = 3000
    t = np.sort(rng.integers(0, 40_000_000, n)).astype(np.int64)
    x, y, p = rng.integers(0, 640, n), rng.integers(0, 480, n), rng.integers(0, 2, n)
    body = evt3.encode(t, x, y, p)  # a camera's stream, cut at arbitrary byte boundaries between packets
    cuts = [0, 1001, 1002, 2500, len(body)]
    _foreign(tmp_path / "e.mcap", [("evt3", body[a:b], 12345) for a, b in zip(cuts[:-1], cuts[1:])])
    src = open_source(tmp_path / "e.mcap")
    assert not src.archive and src.geometry == Geometry(640, 480)
    got = concat(list(src))
    np.testing.assert_array_equal(got.t, t)
    np.testing.assert_array_equal(got.x, x)
    base = 1_700_000_000 * 10**9
    k = int(np.searchsorted(t, 4_000_000))  # a mono packet spans at most 4.29 s
    t_abs = t[:k] + base // 1000
    _foreign(tmp_path / "m.mcap", [("mono", mono.encode(t_abs, x[:k], y[:k], p[:k], base), base)])
    got = concat(list(open_source(tmp_path / "m.mcap")))
    np.testing.assert_array_equal(got.t, t_abs)
    np.testing.assert_array_equal(got.y, y[:k])


def test_picks_one_channel_and_names_the_others(tmp_path):
    t = np.arange(10, dtype=np.int64) * 100
    body = evt3.encode(t, t % 640, t % 480, t % 2)
    path = tmp_path / "two.mcap"
    with open(path, "wb") as f:
        w = Ros2Writer(f)
        schema = w.register_msgdef(DATATYPE, MSGDEF)
        for topic, payload in (("/left/events", body), ("/right/events", body[:8])):
            msg = {"header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": "x"}, "height": 480, "width": 640,
                   "seq": 0, "time_base": 0, "encoding": "evt3", "is_bigendian": False, "events": payload}
            w.write_message(topic, schema, msg, log_time=1)
        w.finish()
    with pytest.warns(UserWarning, match="/right/events"):
        assert len(concat(list(open_source(path)))) == 10
    assert len(concat(list(open_source(path, topic="/right/events")))) < 10
    with pytest.raises(Exception, match="no topic '/nope'"):
        open_source(path, topic="/nope")


# -- damaged files ---------------------------------------------------------------------------------------
def test_truncated_archive_recovers_every_complete_chunk(tmp_path):
    s = classified(9, 30_000)
    path = tmp_path / "full.mcap"
    sink = McapSink(path, keep_noise=False, frames=False, chunk_bytes=2_000, packet_us=1_000)
    Pipeline([]).run(split(s, random_bounds(9, len(s), max_chunks=40)), [sink])
    data = path.read_bytes()
    want = s[s.cls == 0]
    chunks = _chunks(path)  # (end offset, messages) of every chunk, by mcap's own stream reader
    assert len(chunks) > 5
    ends = [e for e, _ in chunks]
    for k, cut in enumerate([ends[2] + 7, ends[4] - 3, (ends[-2] + ends[-1]) // 2]):
        part = tmp_path / f"cut{k}.mcap"
        part.write_bytes(data[:cut])
        n_msgs = sum(m for e, m in chunks if e <= cut)
        with pytest.warns(mcap_log.TruncatedFileWarning, match=f"recovered {n_msgs:,} event packets"):
            src = open_source(part)
            got = concat(list(src))
        assert src.truncated and src.recovered_messages == n_msgs
        assert_same(got, want[: len(got)], with_cls=False)  # a prefix, nothing invented
        assert len(got) > 0


def _chunks(path):
    from mcap.records import Chunk, Message
    from mcap.stream_reader import StreamReader, breakup_chunk

    out = []
    with open(path, "rb") as f:
        for rec in StreamReader(f, emit_chunks=True).records:
            if isinstance(rec, Chunk):
                out.append((f.tell(), sum(isinstance(r, Message) for r in breakup_chunk(rec))))
    return out


def test_garbage_and_empty_files_are_clear_errors(tmp_path):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(mcap_log.MAGIC + b"\xff" * 20)
    with pytest.raises(Exception, match="bad.mcap"):
        open_source(bad)
    empty = tmp_path / "empty.mcap"
    McapSink(empty, frames=False).close()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(Exception, match="no event_camera_msgs/msg/EventPacket channel with messages"):
            open_source(empty)


def test_sink_refuses_bad_settings(tmp_path):
    for kwargs in ({"camera": "1cam"}, {"encoding": "evt9"}, {"packet_us": 0}, {"camera": "a/b"}):
        with pytest.raises(ValueError):
            McapSink(tmp_path / "x.mcap", **kwargs)
    assert NoiseClass.HOT_PIXEL == 2


def test_tick_closes_the_chunk_when_the_stream_goes_quiet(tmp_path):
    import time

    s = classified(13, 2000)
    path = tmp_path / "live.mcap"
    sink = McapSink(path, frames=False, flush_s=0.05)
    part = Path(sink.part)  # the archive is written beside its name until closed
    stats = RunStats()
    sink.write(Batch(s[:1000], [], stats))  # the first chunk goes to disk at once
    sink._last_flush = time.monotonic()
    sink.write(Batch(s[1000:], [], stats))  # cells closed, packets in the chunk in progress
    sink._last_flush = time.monotonic()
    sink.write(Batch(EventChunk.empty(G, t_end=s.t_end + 10**6, with_cls=True), [], stats))
    before = part.stat().st_size
    time.sleep(0.06)
    sink.tick()  # nothing new came, but the chunk is due: it goes to disk
    assert part.stat().st_size > before
    assert sum(1 for _ in mcap_log._records(str(part), mcap_log._Scan())) > 0
    assert not path.exists()
    sink.close(stats)
    assert path.exists() and not part.exists()


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 3000), packet_us=st.sampled_from([1, 37, 1000, 10_000]),
       keep_noise=st.booleans(), max_events=st.sampled_from([1, 5, 200_000]),
       encoding=st.sampled_from(["evt3", "mono"]), gap_us=st.sampled_from([0, 1 << 24, 40 << 24]))
def test_packets_added_at_once_are_the_file_mcap_writes_one_by_one(tmp_path_factory, seed, n, packet_us, keep_noise,
                                                                    max_events, encoding, gap_us):
    """The sink encodes a batch's packets in one call and adds them to the chunk in one write; the file is
    byte for byte the one mcap's `Writer.add_message` makes taking them one at a time (records, message
    indexes, statistics, chunking), whatever the chunking of the stream, cells cut by `max_packet_events`,
    gaps of whole 24-bit clock wraps."""
    folder = tmp_path_factory.mktemp("bulk")
    s = classified(seed, n)
    s = s.replace(t=s.t + np.where(np.arange(n) >= n // 2, gap_us, 0))  # a silence in the middle
    chunks = split(s, random_bounds(seed, n))
    files = []
    for one_by_one in (False, True):
        out = folder / f"{one_by_one}.mcap"
        sink = McapSink(out, keep_noise=keep_noise, frames=False, packet_us=packet_us, max_packet_events=max_events,
                        encoding=encoding, flush_s=1e9, chunk_bytes=4 << 10, geometry=G)
        sink._ONE_BY_ONE = one_by_one
        for chunk in chunks:
            sink.write(Batch(chunk, [], RunStats()))
        sink.close(None)  # no run statistics: no wall time in the file
        files.append(re.sub(rb"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\+00:00", b"T" * 25, out.read_bytes()))
    assert files[0] == files[1]


def test_the_installed_mcap_takes_the_bulk_path():
    """The byte-for-byte test above compares something only when the installed mcap is one whose Writer
    internals `_add_packets` knows; a newer mcap fails here until someone checks it and lists it."""
    import importlib.metadata

    from evstream.sinks.mcap_sink import BULK_MCAP_VERSIONS

    version = importlib.metadata.version("mcap")
    assert not McapSink._ONE_BY_ONE, (f"mcap {version} is not in BULK_MCAP_VERSIONS {BULK_MCAP_VERSIONS}: check "
                                      "McapSink._add_packets against its Writer.add_message, then list it")


def test_an_archive_cut_inside_its_only_chunk_says_why_nothing_was_recovered(tmp_path, capsys):
    """A 0.5 s recording is one chunk (--flush-s 1): cut at 97 % there is nothing whole to read, and the
    error said only 'breaks off at byte 734', where the chunk starts, not that the chunk runs past the end."""
    from evstream.cli import main

    whole = tmp_path / "bar.mcap"
    assert main(["archive", str(Path(__file__).resolve().parents[1] / "recordings" / "bar.npz"), str(whole), "-q"]) == 0
    data = whole.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 97 // 100])
    capsys.readouterr()
    assert main(["info", str(cut)]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"evstream: error: {cut}: no event_camera_msgs/msg/EventPacket channel with messages before "
                          "the file breaks off at byte ") and "(CHUNK record has length" in err, err
    assert err.count("\n") == 1
