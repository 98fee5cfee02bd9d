"""`--start-us` in the native .npz: the writer flushes each column's deflate stream every block of events
and adds a `seek` index; a reader bisects it and inflates from the block holding the start. The events
are exactly those of decoding from the start and dropping the earlier ones; files without the index
(older files, other writers, stored members) are read from the start; the bytes before the block are
not read, and the blocks after it are checked against their CRCs."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest
from evstream.sources import native, npz_writer, open_source
from hypothesis import given
from hypothesis import strategies as st
from seek_checks import assert_same, read_range

from evstream.events import EventChunk, EventError, Geometry, concat
from evstream.testing import random_stream
from evstream.transforms import TimeRangeSource
from evstream.writers import convert

G = Geometry(64, 48)
SHIPPED = "recordings/turntable.npz"


def bursty(seed, n) -> EventChunk:
    """n labelled events in time order with bursts of equal times (some straddle block boundaries)."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.choice([0, 0, 0, 1, 5, 40], n)).astype(np.int64) + int(rng.integers(0, 10**6))
    return EventChunk.from_arrays(t, rng.integers(0, G.width, n), rng.integers(0, G.height, n),
                                  rng.integers(0, 2, n), G, label=rng.integers(0, 3, n).astype(np.uint8))


@pytest.mark.filterwarnings("ignore:.*no event in the time range")  # starts past the end: said, and tested elsewhere
@given(st.integers(0, 2**32 - 1), st.integers(1, 5000), st.integers(1, 700), st.floats(-0.05, 1.05),
       st.sampled_from([None, 0.1, 0.5]), st.sampled_from([{}, {"chunk_events": 333}, {"chunk_us": 250}]))
def test_native_files_seek_to_the_same_events(tmp_path_factory, seed, n, block, share, length, options):
    """Random streams written with blocks of any size (small ones: many blocks), read from starts before,
    inside and after the recording, with and without an end, in chunks by count or by time."""
    path = tmp_path_factory.mktemp("native") / "r.npz"
    s = bursty(seed, n)
    with pytest.MonkeyPatch.context() as m:
        m.setattr(native, "SEEK_BLOCK_EVENTS", block)
        native.save(path, s)
    t0, t1 = int(s.t[0]), int(s.t[-1])
    start = t0 + int(share * (t1 - t0))
    end = None if length is None else start + int(length * (t1 - t0)) + 1
    got, want, seeks = read_range(path, start, end, **options)
    assert_same(got, want)
    first_block = int(np.searchsorted(s.t[np.minimum(np.arange(block, n + block, block), n) - 1], start))
    assert seeks == (first_block > 0)  # it seeks whenever a whole block lies before the start


def test_real_recordings_written_natively_seek_to_the_same_events(real_data, tmp_path):
    """Real recordings converted to the native format (`convert`, the format's writer), then read from
    several starts: the same events as reading them whole; a seek wherever a block lies before the start."""
    for name in ("prophesee_gen3_vga_evt2_faery.raw", "dvs128_lifetime_garfield.mat", "dvxplorer_320x240_tonic.npy"):
        out = tmp_path / f"{name}.npz"
        convert(real_data / name, out)
        first_block_ends = int(np.load(out)["seek"]["t_max"][0])
        everything = concat(list(open_source(out)))
        t0, t1 = int(everything.t[0]), int(everything.t[-1])
        seeks_seen = 0
        for share in (0.13, 0.5, 0.91):
            start = t0 + int(share * (t1 - t0)) + 1
            got, want, seeks = read_range(out, start, start + (t1 - t0) // 5)
            assert seeks == (start > first_block_ends), name
            seeks_seen += seeks
            assert len(want) > 0
            assert_same(got, want)
        assert seeks_seen, name


def test_older_native_files_and_stored_ones_are_read_from_the_start(tmp_path):
    """Files without the index (the shipped recording and any file numpy's savez wrote, compressed or not)
    read from their start: the same events, no seek."""
    s = bursty(3, 200_000)
    old = tmp_path / "old.npz"
    np.savez_compressed(old, t=s.t, x=s.x, y=s.y, p=s.p, label=s.label, width=np.int64(G.width),
                        height=np.int64(G.height), meta=np.array("{}"))
    stored = tmp_path / "stored.npz"
    native.save(stored, s, compress=False)
    for path in (old, stored, SHIPPED):
        everything = concat(list(open_source(path)))
        start = int(everything.t[len(everything) * 3 // 4])
        got, want, seeks = read_range(path, start)
        assert not seeks
        assert_same(got, want)


def test_a_file_zipped_again_is_read_from_the_start(tmp_path):
    """Members compressed again by another zip writer (the seek index carried along, now stale) or stored:
    its flush points are gone, so the file is read from the start, with the same events."""
    s = bursty(7, 200_000)
    path = tmp_path / "r.npz"
    native.save(path, s)
    for method in (zipfile.ZIP_DEFLATED, zipfile.ZIP_STORED):
        again = tmp_path / f"again{method}.npz"
        with zipfile.ZipFile(path) as zi, zipfile.ZipFile(again, "w", method) as zo:
            for name in zi.namelist():
                zo.writestr(name, zi.read(name))
        got, want, seeks = read_range(again, int(s.t[150_000]))
        assert not seeks
        assert_same(got, want)


def compressed_spans(path, column):
    """(start of the member's data in the file, its seek index) of `column` in a native file."""
    z = zipfile.ZipFile(path)
    info = z.getinfo(f"{column}.npy")
    with open(path, "rb") as f:
        f.seek(info.header_offset + 26)
        lengths = np.frombuffer(f.read(4), "<u2")
    return info.header_offset + 30 + int(lengths.sum()), np.load(path)["seek"]


@pytest.mark.filterwarnings("error::UserWarning")  # a damaged file is an error, not also "no event in the range"
def test_a_seek_inflates_no_byte_before_its_block_and_checks_those_after(tmp_path):
    """Bytes of every column's first block (after its .npy header) damaged: reading from the start fails on them, a
    seek past them gives every event of the range (it never read them). A byte damaged after the seek point: an
    error naming the file, whether the damage lands in a block's CRC or its deflate stream."""
    s = bursty(4, 300_000)
    good = tmp_path / "good.npz"
    native.save(good, s)
    blob = bytearray(good.read_bytes())
    for column in ("t", "x", "y", "p", "label"):
        start, index = compressed_spans(good, column)
        for k in range(2000, int(index[f"{column}_at"][1]) - 10, 997):  # block 0's bytes after the .npy header
            blob[start + k] ^= 0x55
    early = tmp_path / "early.npz"
    early.write_bytes(bytes(blob))
    with pytest.raises(EventError, match="early.npz"):
        list(open_source(early))
    start_us = int(s.t[200_000])
    got, want, seeks = read_range(good, start_us)
    assert seeks
    got_early = concat(list(TimeRangeSource(open_source(early), start_us, None)))
    assert_same(got_early, want)
    assert_same(got, want)

    start, index = compressed_spans(good, "x")
    k = int(np.searchsorted(index["t_max"], start_us))
    for at in (int(index["x_at"][k + 1]) + 100, int(index["x_at"][k]) + 30):
        blob = bytearray(good.read_bytes())
        blob[start + at] ^= 0x01
        late = tmp_path / "late.npz"
        late.write_bytes(bytes(blob))
        with pytest.raises(EventError, match="late.npz.*(damaged|unreadable)"):
            list(TimeRangeSource(open_source(late), start_us, None))
    # a block read after the seek point whose bytes are not those written: its CRC says so
    arrays = dict(np.load(good))
    arrays["seek"]["y_crc"][k + 1] ^= 1
    rewrite(tmp_path / "crc.npz", arrays)
    with pytest.raises(EventError, match=r"crc.npz: unreadable native file: array 'y': .*fail the CRC check of their "
                                         r"block 1 from the seek point"):
        list(TimeRangeSource(open_source(tmp_path / "crc.npz"), start_us, None))


def rewrite(path, arrays):
    with open(path, "wb") as f:
        w = npz_writer.NpzWriter(f)
        for k, a in arrays.items():
            w.add(k, a, native.SEEK_BLOCK_EVENTS if k in native.COLUMNS else None)
        w.close()


def test_a_seek_index_that_does_not_fit_the_file_is_refused(tmp_path):
    """An index whose blocks do not cover the events, or whose times go back, is damage: one error line."""
    s = bursty(5, 150_000)
    path = tmp_path / "r.npz"
    native.save(path, s)
    index = np.load(path)["seek"]
    for broken in (index[:-1], np.concatenate([index[1:2], index[1:]])):
        bad = tmp_path / "bad.npz"
        rewrite(bad, {**np.load(path), "seek": broken})
        with pytest.raises(EventError, match="bad.npz: unreadable native file: array 'seek'"):
            TimeRangeSource(open_source(bad), int(s.t[-10]), None)


def test_the_writer_is_an_ordinary_npz_its_bytes_fixed_by_the_data(tmp_path, monkeypatch):
    """numpy, the zip module and our reader read what it writes, with ZIP64 records too (forced here by
    lowering the limit); the same events give the same bytes."""
    s = random_stream(6, 100_000, G, mean_dt_us=3)
    a, b = tmp_path / "a.npz", tmp_path / "b.npz"
    native.save(a, s, {"k": 1})
    native.save(b, s, {"k": 1})
    assert a.read_bytes() == b.read_bytes()
    monkeypatch.setattr(npz_writer, "ZIP64_LIMIT", 100)
    big = tmp_path / "zip64.npz"
    native.save(big, s, {"k": 1})
    for path in (a, big):
        assert zipfile.ZipFile(path).testzip() is None
        z = np.load(path)
        assert z["t"].tolist() == s.t.tolist() and int(z["width"]) == G.width and z["meta"].ndim == 0
        assert_same(concat(list(open_source(path))), s)
        got, want, seeks = read_range(path, int(s.t[90_000]))
        assert seeks
        assert_same(got, want)
