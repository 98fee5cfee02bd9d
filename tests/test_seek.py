"""`--start-us` seeks where the format allows (EVT2/EVT3 by following the decoder's state without decoding
events, .npy/.mat by bisection on the time column, evstream MCAP archives by their packets' grid cells):
the events are exactly those of decoding from the start and dropping the earlier ones."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from evstream.sinks.mcap_sink import McapSink
from evstream.sources import open_source, prophesee_raw
from evstream.sources._base import EventWarning
from hypothesis import given
from hypothesis import strategies as st

from evstream.codecs import evt2, evt3
from evstream.events import EventChunk, Geometry, concat
from evstream.pipeline import Pipeline
from evstream.testing import random_stream
from evstream.transforms import TimeRangeSource

G = Geometry(64, 48)


def read_range(path, start_us, end_us=None, **options):
    """(events of the seeking read, events of a read from the start with the earlier ones dropped, seeks?)"""
    source = TimeRangeSource(open_source(path, **options), start_us, end_us)
    got = list(source)
    everything = concat(list(open_source(path, **options)), source.geometry)
    keep = everything.t >= start_us
    if end_us is not None:
        keep &= everything.t < end_us
    return concat(got, source.geometry), everything[keep], source.seeks


def assert_same(got: EventChunk, want: EventChunk):
    assert len(got) == len(want)
    for f in ("t", "x", "y", "p", "cls"):
        a, b = getattr(got, f), getattr(want, f)
        assert (a is None) == (b is None), f
        if a is not None:
            np.testing.assert_array_equal(a, b, err_msg=f)


def spread(seed, n, span_us, t0_us=0) -> EventChunk:
    """n events over span_us µs (bursts and gaps: several EVT3 wraps of 16.8 s when span_us is long)."""
    rng = np.random.default_rng(seed)
    t = np.sort(t0_us + rng.integers(0, span_us, n)).astype(np.int64)
    return EventChunk.from_arrays(t, rng.integers(0, G.width, n), rng.integers(0, G.height, n),
                                  rng.integers(0, 2, n), G)


# -- real recordings ------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["prophesee_gen3_vga_evt2_faery.raw", "prophesee_gen41_hd_evt3_expelliarmus.raw",
                                  "dvxplorer_320x240_tonic.npy", "dvs128_lifetime_building.mat"])
def test_real_recordings_seek_to_the_same_events(real_data, name):
    path = real_data / name
    everything = concat(list(open_source(path)))
    t0, t1 = int(everything.t[0]), int(everything.t[-1])
    for share in (0.0, 0.13, 0.5, 0.91):
        start = t0 + int(share * (t1 - t0)) + 1
        got, want, seeks = read_range(path, start, start + (t1 - t0) // 5)
        assert seeks, name
        assert len(want) > 0
        assert_same(got, want)


# -- EVT2 / EVT3 ----------------------------------------------------------------------------------
@given(st.integers(0, 2**32 - 1), st.sampled_from(["evt2", "evt3"]), st.floats(0, 1.05))
def test_raw_files_seek_across_clock_wraps(tmp_path_factory, seed, version, share):
    """70 s of sparse events: four wraps of EVT3's 24-bit clock before most starts."""
    path = tmp_path_factory.mktemp("raw") / "r.raw"
    s = spread(seed, 3000, 70_000_000, t0_us=int(np.random.default_rng(seed).integers(0, 10**7)))
    prophesee_raw.save(path, s, version=version)
    start = int(s.t[0]) + int(share * (int(s.t[-1]) - int(s.t[0])))
    got, want, seeks = read_range(path, start, block_bytes=1024 + 2 * (seed % 7))  # odd block sizes too
    assert seeks
    assert_same(got, want)


def test_evt2_clock_wraps_at_2_to_the_34_us(tmp_path):
    s = spread(1, 400, 40_000_000, t0_us=(1 << 34) - 20_000_000)  # the 34-bit clock wraps in the middle
    path = tmp_path / "r.raw"
    prophesee_raw.save(path, s, version="evt2", t_origin_us=0)
    for start in (int(s.t[0]), 1 << 34, (1 << 34) + 7_000_001, int(s.t[-1])):
        got, want, _ = read_range(path, start)
        assert_same(got, want)


@pytest.mark.parametrize("codec,word", [(evt2, 4), (evt3, 2)])
def test_skip_before_returns_the_words_from_the_first_that_can_be_in_range(codec, word):
    """Decoding what `skip_before` leaves gives the events at or after the start, and some before it
    only from the TIME_HIGH period holding the start; the words skipped hold no event at or after it."""
    s = spread(3, 5000, 60_000_000)
    data = codec.encode(s.t, s.x, s.y, s.p)
    for start in (0, 17_000_000, 33_333_333, 61_000_000):
        dec = codec.Evt2Decoder() if codec is evt2 else codec.Evt3Decoder()
        rest = dec.skip_before(data, start)
        skipped = len(data) - (0 if rest is None else len(rest))
        assert skipped % word == 0
        before = codec.decode(data[:skipped])[0]
        assert np.all(before < start)
        if rest is not None:
            t = dec.decode(rest)[0]
            np.testing.assert_array_equal(t, s.t[len(before):])
            assert np.all(t[t < start] >= start - 4096)  # at most one TIME_HIGH period (EVT3: 4096 µs) early
        else:
            assert start > s.t[-1]


def test_skip_before_in_blocks_of_any_size():
    s = spread(5, 2000, 50_000_000)
    data = evt3.encode(s.t, s.x, s.y, s.p)
    start = 20_000_000
    for block in (1, 3, 64, 1001):
        dec = evt3.Evt3Decoder()
        parts, seeking = [], True
        for a in range(0, len(data), block):
            piece = data[a:a + block]
            if seeking:
                piece = dec.skip_before(piece, start)
                if piece is None:
                    continue
                seeking = False
            parts.append(dec.decode(piece)[0])
        t = np.concatenate(parts)
        np.testing.assert_array_equal(t[t >= start], s.t[s.t >= start])


# -- NumPy ----------------------------------------------------------------------------------------
def test_npy_bisects_and_refuses_a_file_out_of_time_order(tmp_path):
    s = spread(2, 5000, 1_000_000)
    path = tmp_path / "e.npy"
    np.save(path, s.to_structured())
    got, want, seeks = read_range(path, 400_000, 700_000)
    assert seeks and len(want) > 1000
    assert_same(got, want)
    # an event in the range before the bisection point: no seek, the same events still
    a = s.to_structured()
    a["t"][10] = 650_000
    np.save(path, a)
    with pytest.warns(EventWarning, match="dropped"):
        got, want, seeks = read_range(path, 400_000, 700_000, timestamps="drop")
    assert not seeks
    assert_same(got, want)


def test_npy_in_seconds_seeks_to_the_rounded_microsecond(tmp_path):
    s = spread(4, 3000, 2_000_000)
    a = np.zeros(len(s), [("t", "<f8"), ("x", "<u2"), ("y", "<u2"), ("p", "u1")])
    a["t"], a["x"], a["y"], a["p"] = s.t * 1e-6 + 3e-7, s.x, s.y, s.p
    path = tmp_path / "s.npy"
    np.save(path, a)
    for start in (int(s.t[100]), int(s.t[100]) + 1, 1_234_567):
        got, want, seeks = read_range(path, start)
        assert seeks
        assert_same(got, want)


# -- MCAP -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("encoding", ["evt3", "mono"])
def test_mcap_archive_skips_the_packets_before_the_range(tmp_path, encoding):
    s = random_stream(6, 6000, G, mean_dt_us=300)
    s = dataclasses.replace(s, cls=s.label.copy())
    path = tmp_path / "a.mcap"
    Pipeline([]).run([s[a:a + 700] for a in range(0, len(s), 700)],
                     [McapSink(path, frames=False, encoding=encoding, packet_us=20_000)])
    t0, t1 = int(s.t[0]), int(s.t[-1])
    for start in (t0, t0 + (t1 - t0) // 3 + 7, t0 + (t1 - t0) * 9 // 10):
        got, want, seeks = read_range(path, start)
        assert seeks
        assert_same(got, want)
        source = TimeRangeSource(open_source(path), start)
        list(source)
        if start > t0 + 40_000:  # packets of the cells before the start were not decoded
            assert source.recovered_events < len(s) - np.count_nonzero(s.t < start - 20_000)
