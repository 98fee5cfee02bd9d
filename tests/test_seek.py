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
from seek_checks import assert_same, read_range

from evstream.codecs import evt2, evt3
from evstream.events import EventChunk, EventError, Geometry, concat
from evstream.pipeline import Pipeline
from evstream.testing import random_stream
from evstream.transforms import TimeRangeSource

G = Geometry(64, 48)


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


def seek_in_blocks(dec, data: bytes, start_us: int, block: int) -> list:
    """`data` fed to `dec` `block` bytes at a time: `skip_before` until a block reaches start_us, `decode`
    from there on; the decoded (t, x, y, p) of each block."""
    parts, seeking = [], True
    for a in range(0, len(data), block):
        piece = data[a:a + block]
        if seeking:
            piece = dec.skip_before(piece, start_us)
            if piece is None:
                continue
            seeking = False
        parts.append(dec.decode(piece))
    return parts


def test_skip_before_in_blocks_of_any_size():
    s = spread(5, 2000, 50_000_000)
    data = evt3.encode(s.t, s.x, s.y, s.p)
    start = 20_000_000
    for block in (1, 3, 64, 1001):
        t = np.concatenate([q[0] for q in seek_in_blocks(evt3.Evt3Decoder(), data, start, block)])
        np.testing.assert_array_equal(t[t >= start], s.t[s.t >= start])


def test_evt3_skip_reads_a_block_inside_the_period_holding_the_start_word_by_word():
    """A block that begins inside the TIME_HIGH period holding start_us and has no TIME_HIGH of its own:
    the period carried over from the blocks before already reaches the start, so the block is read word
    by word; its events at or after the start are kept, not skipped with the block."""
    n = 1000
    t = 8192 + 3 * np.arange(n)  # all in one TIME_HIGH period, 8192 .. 12287 µs
    s = EventChunk.from_arrays(t, np.arange(n) % G.width, np.arange(n) // G.width % G.height, np.arange(n) % 2, G)
    data = evt3.encode(s.t, s.x, s.y, s.p)
    for block in (64, 502, 2000):
        for start in (8192 + 3 * 400 + 1, 11_000):
            got = np.concatenate([q[0] for q in seek_in_blocks(evt3.Evt3Decoder(), data, start, block)])
            np.testing.assert_array_equal(got[got >= start], s.t[s.t >= start])


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
    # under the 'error' policy reading from the start refuses the file; the seek skips that part unchecked
    with pytest.raises(EventError, match="goes back"):
        list(open_source(path))
    source = TimeRangeSource(open_source(path), 400_000, 700_000)
    assert source.seeks
    assert_same(concat(list(source)), s[(s.t >= 400_000) & (s.t < 700_000)])


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


def rows_of_events(seed, n_rows, span_us) -> EventChunk:
    """Runs of events along rows at one time (EVT3 writes them as vector words), over clock wraps."""
    rng = np.random.default_rng(seed)
    t, x, y, p = [], [], [], []
    for tr in np.sort(rng.integers(0, span_us, n_rows)):
        x0, k = int(rng.integers(0, G.width - 30)), int(rng.integers(1, 30))
        t += [tr] * k
        x += list(range(x0, x0 + k))
        y += [int(rng.integers(0, G.height))] * k
        p += [int(rng.integers(0, 2))] * k
    return EventChunk.from_arrays(t, x, y, p, G)


@given(st.integers(0, 2**32 - 1), st.integers(0, 50_000_000), st.integers(1, 300))
def test_evt3_skip_restores_rows_and_vector_bases(seed, start, block):
    """The row, time low and vector base before the period where the range can begin are read back from
    the words before it, in this block or carried over from earlier ones."""
    s = rows_of_events(seed, 300, 50_000_000)
    data = evt3.encode(s.t, s.x, s.y, s.p)
    parts = seek_in_blocks(evt3.Evt3Decoder(), data, start, block)
    t, x, y, p = (np.concatenate([q[k] for q in parts]) if parts else np.zeros(0) for k in range(4))
    keep, sel = t >= start, s.t >= start
    for got, want in ((t, s.t), (x, s.x), (y, s.y), (p, s.p)):
        np.testing.assert_array_equal(got[keep], want[sel])


def _word(kind, payload):
    return (kind << 12) | payload


@given(st.integers(0, 2**32 - 1), st.integers(1, 40))
def test_evt3_skip_follows_state_words_across_periods(seed, block):
    """Hand-made EVT3 words where the row, time low and vector base carry over TIME_HIGH words (a camera
    need not repeat them): the events after any start are those of decoding everything."""
    rng = np.random.default_rng(seed)
    words = [_word(0x8, 0)]
    high = 0
    for _ in range(60):
        for _ in range(int(rng.integers(0, 6))):
            kind = int(rng.choice([0x0, 0x2, 0x3, 0x4, 0x5, 0x6, 0xE]))
            if kind == 0x0:
                payload = int(rng.integers(0, G.height))
            elif kind in (0x2, 0x3):
                payload = int(rng.integers(0, 12)) | int(rng.integers(0, 2)) << 11
            else:
                payload = int(rng.integers(0, 4096))
            words.append(_word(kind, payload))
        high = (high + int(rng.integers(1, 1500))) % 4096  # a wrap now and then (a drop of >= 4080: rare)
        words.append(_word(0x8, high))
    data = np.array(words, "<u2").tobytes()
    t_all = evt3.decode(data)[0]
    for start in (0, int(np.median(t_all)) if len(t_all) else 1, int(t_all.max()) if len(t_all) else 2):
        parts = seek_in_blocks(evt3.Evt3Decoder(), data, start, 2 * block)
        want = [a[t_all >= start] for a in evt3.decode(data)]
        got = [np.concatenate([q[k] for q in parts]) if parts else np.zeros(0, a.dtype) for k, a in enumerate(want)]
        keep = got[0] >= start
        for g, w in zip(got, want):
            np.testing.assert_array_equal(g[keep], w)


def test_evt3_skip_counts_the_clock_wraps_and_other_words_like_decoding():
    """Seeking counts each 24-bit clock wrap it passes once, as decoding does; the OTHERS words decoding
    meets are counted one by one."""
    words = []
    for _ in range(3):  # three laps of the 12-bit TIME_HIGH: two wraps (4095 -> 0)
        for high in (0, 1000, 2000, 3000, 4095):
            words += [_word(0x8, high), _word(0x6, 5), _word(0x0, 3), _word(0x2, 4), _word(0xE, 1)]
    data = np.array(words, "<u2").tobytes()
    full = evt3.Evt3Decoder()
    t_all = full.decode(data)[0]
    assert full.counters["wraps"] == 2 and full.counters["others"] == 15
    for start in (int(t_all[7]), int(t_all[-1])):
        for block in (2, 6, 40):
            dec = evt3.Evt3Decoder()
            t = np.concatenate([q[0] for q in seek_in_blocks(dec, data, start, block)])
            np.testing.assert_array_equal(t[t >= start], t_all[t_all >= start])
            assert dec.counters["wraps"] == 2


def reference_skip(words: list[int], start_us: int) -> int:
    """The EVT3 skip's definition, word by word in plain Python: the index of the first TIME_HIGH or
    TIME_LOW word that sets the time to start_us or later once there is a time base (len(words): none)."""
    high = low = loops = 0
    has_high = False
    for i, w in enumerate(words):
        kind, payload = w >> 12, w & 0xFFF
        if kind == 0x8:
            wrap = has_high and high - payload >= 4080
            if (loops + wrap) * (1 << 24) + payload * 4096 + low >= start_us:
                return i
            loops, high, has_high = loops + wrap, payload, True
        elif kind == 0x6:
            if has_high and loops * (1 << 24) + high * 4096 + payload >= start_us:
                return i
            low = payload
    return len(words)


def evt3_periods(rng, n_periods: int) -> tuple[list[int], list[int]]:
    """Hand-made EVT3 words: rows, vector bases, vectors, events, time lows and OTHERS between TIME_HIGH
    words that step forward, step back, and wrap (a drop of 4080 or more) often; and the times the
    TIME_HIGH and TIME_LOW words set and each period's last microsecond (the starts worth seeking to)."""
    words, times = [_word(0x6, int(rng.integers(0, 4096)))], []  # a time low before any time base
    high, low, loops, has_high = 0, words[0] & 0xFFF, 0, False
    for _ in range(n_periods):
        roll = rng.random()
        if roll < 0.25:  # a wrap: from the top of the range (through 4095 if below it) to the bottom
            if high < 4080:
                steps = [4095, int(rng.integers(0, 16))]
            else:
                steps = [int(rng.integers(0, high - 4079))]
        elif roll < 0.35:
            steps = [max(0, high - int(rng.integers(1, 200)))]  # a step back, not a wrap
        else:
            steps = [min(4095, high + int(rng.integers(1, 1500)))]
        for payload in steps:
            if has_high and high - payload >= 4080:
                loops += 1
            high, has_high = payload, True
            words.append(_word(0x8, payload))
            times += [loops * (1 << 24) + high * 4096 + low, loops * (1 << 24) + high * 4096 + 4095]
        for _ in range(int(rng.integers(0, 7))):
            kind = int(rng.choice([0x0, 0x2, 0x3, 0x4, 0x5, 0x6, 0x6, 0xE]))
            payload = int(rng.choice([0, 4095, int(rng.integers(0, 4096))]))  # a period's first and last µs too
            words.append(_word(kind, payload))
            if kind == 0x6:
                low = payload
                times.append(loops * (1 << 24) + high * 4096 + low)
    return words, times


@given(st.integers(0, 2**32 - 1), st.integers(1, 40))
def test_evt3_skip_matches_its_plain_python_definition(seed, block):
    """The skip kernel (its TIME_HIGH pass, `_restore` and `_follow`) against the definition, fed in blocks:
    it stops at exactly the word `reference_skip` names, with the decoder's registers and wrap count as
    decoding every word before it leaves them, and counts nothing else. The starts are the times each
    time word sets, the microsecond after (a wrap, a step back or a time low just short of the start) and
    the last microsecond of a period (one that reaches the start only there)."""
    rng = np.random.default_rng(seed)
    words, times = evt3_periods(rng, 40)
    data = np.array(words, "<u2").tobytes()
    starts = {0, max(times) + 1, *(t + d for t in rng.choice(times, 16) for d in (0, 1))}
    for start in sorted(starts):
        want = reference_skip(words, start)
        before = evt3.Evt3Decoder()
        before.decode(data[: 2 * want])
        dec, skipped = evt3.Evt3Decoder(), 0
        for a in range(0, len(data), 2 * block):
            rest = dec.skip_before(data[a : a + 2 * block], start)
            skipped += len(data[a : a + 2 * block]) - (0 if rest is None else len(rest))
            if rest is not None:
                break
        assert skipped == 2 * want, start
        np.testing.assert_array_equal(dec.state[:7], before.state[:7])
        assert dec.counters == dict.fromkeys(evt3.COUNTER_NAMES, 0) | {"wraps": before.counters["wraps"]}
