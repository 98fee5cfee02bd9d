"""EVT2 codec: the numba decoder against a plain-Python reference, streaming splits, round trips,
faery agreement and the real Gen3 recording."""

import numpy as np
import pytest
from codec_checks import assert_events_equal, check_kernel_agrees_with_reference, checked_events, with_boundary_examples
from hypothesis import example, given
from hypothesis import strategies as st

from evstream.codecs import evt2


def reference_decode(data: bytes):
    words = np.frombuffer(data[: len(data) // 4 * 4], "<u4").tolist()
    high = loops = 0
    has_high = False
    last = None
    out = []
    counts = dict.fromkeys(evt2.COUNTER_NAMES, 0)
    for w in words:
        kind = w >> 28
        if kind in (0, 1):
            if not has_high:
                counts["no_time"] += 1
                continue
            t = (loops << 34) + (high << 6) + ((w >> 22) & 63)
            if last is not None and t < last:
                counts["time_back"] += 1
            last = t
            out.append((t, (w >> 11) & 0x7FF, w & 0x7FF, kind))
        elif kind == 8:
            new = w & 0xFFFFFFF
            if has_high and high - new >= 1 << 27:
                loops += 1
                counts["wraps"] += 1
            high, has_high = new, True
        elif kind == 0xA:
            counts["trigger"] += 1
        elif kind == 0xE:
            counts["others"] += 1
        elif kind == 0xF:
            counts["continued"] += 1
        else:
            counts["unknown"] += 1
    a = np.array(out, np.int64).reshape(-1, 4)
    return (a[:, 0], a[:, 1].astype(np.uint16), a[:, 2].astype(np.uint16), a[:, 3].astype(np.uint8)), counts


word = st.one_of(
    st.integers(0, 0xFFFFFFFF),
    st.builds(lambda k, pay: (k << 28) | pay, st.sampled_from([0, 1, 8, 8, 0xA]), st.integers(0, 0xFFFFFFF)),
)


H = 0x8 << 28  # EV_TIME_HIGH


def _cd(low: int) -> int:
    return 1 << 28 | low << 22 | 5 << 11 | 7  # CD_ON at (5, 7), time low bits `low`


# wraps (a drop of 2^27 is one, 2^27 - 1 is not), time going back and every other type, each twice
COUNTED = [H | 0xFFFFFFF, H | 0x10, _cd(63), _cd(0), _cd(63), _cd(0), H | (0x10 + (1 << 27)), H | 0x10,
           H | (0x10 + (1 << 27) - 1), H | 0x10, _cd(1)] + [k << 28 for k in (0xA, 0xA, 0xE, 0xE, 0xF, 0xF, 2, 2)]


@given(st.lists(word, max_size=200), st.integers(0, 3))
@example([H | 5] + [(k << 28) | 0x0123456 for k in range(16)], 0)  # every type, the unknown ones too
@example(COUNTED, 0)
def test_decoder_matches_reference_on_random_words(words, tail):
    data = np.array(words, "<u4").tobytes() + b"\x01" * tail
    want, counts = reference_decode(data)
    dec = evt2.Evt2Decoder()
    assert_events_equal(dec.decode(data), want)
    assert dec.counters == counts and dec.pending_bytes == tail


@given(st.lists(word, max_size=150), st.lists(st.integers(0, 601), max_size=6))
@example([H | 0xFFFFFFF, H | 0x10, 1 << 28 | 0x0400801, 0x0400801, 1 << 28 | 0x0C00801], [8])  # cut after a wrap
def test_decoder_is_split_invariant(words, cuts):
    data = np.array(words, "<u4").tobytes()
    edges = [0, *sorted(c for c in cuts if c <= len(data)), len(data)]
    dec = evt2.Evt2Decoder()
    parts = [dec.decode(data[a:b]) for a, b in zip(edges[:-1], edges[1:])]
    got = tuple(np.concatenate([p[k] for p in parts]) for k in range(4))
    assert_events_equal(got, evt2.decode(data))


@st.composite
def event_streams(draw):
    n = draw(st.integers(0, 200))
    gaps = draw(st.lists(st.one_of(st.integers(0, 100), st.integers(0, 1 << 33)), min_size=n, max_size=n))
    t = draw(st.integers(0, 1 << 35)) + np.cumsum(np.array(gaps, np.int64))
    rows = draw(st.lists(st.tuples(st.integers(0, 2047), st.integers(0, 2047), st.integers(0, 1)),
                         min_size=n, max_size=n))
    a = np.array(rows, np.int64).reshape(-1, 3)
    return t, a[:, 0].astype(np.uint16), a[:, 1].astype(np.uint16), a[:, 2].astype(np.uint8)


def _at(*t):
    n = len(t)
    return np.array(t, np.int64), np.full(n, 3, np.uint16), np.full(n, 4, np.uint16), np.ones(n, np.uint8)


@given(event_streams())
@example(_at(5 << 34 | 64, 6 << 34 | 64, 9 << 34 | 128))  # TIME_HIGH wraps after a non-zero high, once and 3x
def test_encode_round_trips_exactly(ev):
    data = evt2.encode(*ev)
    assert_events_equal(evt2.decode(data), ev)
    assert_events_equal(reference_decode(data)[0], ev)


def test_encode_rejects_time_going_back():
    with pytest.raises(ValueError, match="event 1"):
        evt2.encode(np.array([5, 4]), np.array([0, 0]), np.array([0, 0]), np.array([0, 0]))


def test_faery_decodes_our_encoding_identically(tmp_path):
    import faery  # declared (dev) dependency: a broken install fails
    rng = np.random.default_rng(4)
    n = 20_000
    t = np.sort(rng.integers(0, 3_000_000_000, n))
    ev = (t, rng.integers(0, 1280, n).astype(np.uint16), rng.integers(0, 720, n).astype(np.uint16),
          rng.integers(0, 2, n).astype(np.uint8))
    path = tmp_path / "a.raw"
    path.write_bytes(b"% evt 2.0\n% format EVT2;height=720;width=1280\n% end\n" + evt2.encode(*ev))
    got = np.concatenate(list(faery.events_stream_from_file(path)))
    assert_events_equal((got["t"].astype(np.int64), got["x"], got["y"], got["on"].astype(np.uint8)), ev)


def test_real_gen3_file(real_data):
    data = (real_data / "prophesee_gen3_vga_evt2_faery.raw").read_bytes()
    body = data[data.index(b"% evt 2.0\n") + len(b"% evt 2.0\n"):]
    dec = evt2.Evt2Decoder()
    parts = [dec.decode(body[i : i + 10_001]) for i in range(0, len(body), 10_001)]
    t, x, y, p = (np.concatenate([q[k] for q in parts]) for k in range(4))
    assert len(t) == 521_252 and t[-1] - t[0] == 95_871  # SOURCES.md: 95.9 ms
    assert x.max() < 640 and y.max() < 480 and abs(p.mean() - 0.357) < 0.001
    assert dec.counters["unknown"] == 0 and dec.counters["time_back"] == 0


@given(event_streams(), st.lists(st.integers(0, 200), max_size=5))
def test_streaming_encoder_output_concatenates_to_one_stream(ev, cuts):
    n = len(ev[0])
    edges = [0, *sorted(c for c in cuts if c <= n), n]
    enc = evt2.Evt2Encoder()
    data = b"".join(enc.encode(*(a[i:j] for a in ev)) for i, j in zip(edges[:-1], edges[1:]))
    assert_events_equal(evt2.decode(data), ev)


@given(checked_events())
@with_boundary_examples
def test_check_kernel_matches_reference_on_random_events(ev):
    """The numba check against plain Python, events crowding every limit (x = 2047 and 2048, p = 2,
    a step back in time, a first event before `prev`); and the encoder refuses exactly that event."""
    check_kernel_agrees_with_reference(evt2, ev)


def test_encoder_spells_a_wrap_top_then_zero():
    """Crossing a TIME_HIGH wrap, the encoder writes the 28-bit top and then 0, as a camera's counter
    does, before the new time high."""
    t0, t1 = 0xFFFFFFF << 6, (1 << 34) + (5 << 6)
    words = np.frombuffer(evt2.encode(*_at(t0, t1)), "<u4").tolist()
    cd = 1 << 28 | 3 << 11 | 4
    assert words == [H | 0xFFFFFFF, cd, H | 0xFFFFFFF, H, H | 5, cd]


def test_encoder_opens_on_time_high_1_and_takes_any_integer_dtype():
    """A first event at 64..127 µs still gets its TIME_HIGH (the encoder's 'none written yet' is -1, not 0 or
    1); times and coordinates of any integer dtype give the same words; an empty call gives no bytes."""
    t, x, y, p = [64, 64, 127, 5000], [0, 2047, 3, 4], [5, 6, 2047, 0], [0, 1, 1, 0]
    ev = np.array(t, np.int64), np.array(x, np.uint16), np.array(y, np.uint16), np.array(p, np.uint8)
    want = evt2.encode(*ev)
    assert np.frombuffer(want, "<u4")[0] == H | 1
    assert_events_equal(evt2.decode(want), ev)
    wide = np.array(t, np.uint64), np.array(x, np.int64), np.array(y, np.int32), np.array(p, np.int16)
    assert evt2.encode(*wide) == want
    assert evt2.encode(*([],) * 4) == b""


def test_encoder_refuses_negative_coordinates_and_names_an_event_by_its_place_in_the_stream():
    for field in range(1, 4):  # x, y or p of -1 (as int64, not wrapped into range) is not written
        ev = [np.array([10, 11]), np.array([1, 2]), np.array([1, 2]), np.array([0, 1])]
        ev[field][1] = -1
        with pytest.raises(ValueError, match=r"^encode: event 1 \(t=11 µs, x="):
            evt2.encode(*ev)
    enc = evt2.Evt2Encoder()
    enc.encode(*_at(1, 2, 3))
    enc.encode(*_at(4, 5))
    with pytest.raises(ValueError, match=r"^encode: event 6 \(t=5 µs, x=3, y=4, p=1\) cannot be written: EVT2 needs "
                                         r"non-decreasing t >= 0, x and y < 2048, p 0 or 1$"):
        enc.encode(*_at(6, 5))
    with pytest.raises(ValueError, match=r"^encode: arrays differ in length \(t 2, x 2, y 2, p 1\)$"):
        enc.encode(*(a[: 1 if k == 3 else 2] for k, a in enumerate(_at(7, 8))))


def reference_skip(words: list[int], start_us: int):
    """Plain-Python `_skip_kernel`: the index of the first TIME_HIGH whose period can reach start_us (its
    base + 63 >= start_us, a wrap at that word counted in), and the time base and wraps standing before it."""
    high = loops = wraps = 0
    has_high = False
    for i, w in enumerate(words):
        if w >> 28 == 8:
            new = w & 0xFFFFFFF
            wrap = has_high and high - new >= 1 << 27
            if ((loops + wrap) << 34) + (new << 6) + 63 >= start_us:
                return i, (loops << 34) + (high << 6), wraps
            high, loops, wraps, has_high = new, loops + wrap, wraps + wrap, True
    return len(words), (loops << 34) + (high << 6), wraps


@given(st.lists(word, max_size=200), st.integers(-1, 3 << 34), st.integers(1, 9))
@example([H | 0xFFFFFFF, _cd(1), H | 5, _cd(2), H | 6, _cd(3)], (1 << 34) + (6 << 6), 2)  # past a wrap
@example([H | 7, _cd(1), H | 7, _cd(2)], (7 << 6) + 63, 1)  # the first TIME_HIGH's last µs
@example([H | 1 << 27, _cd(1), H, _cd(2), H | 1 << 26, H | (1 << 26) + 5, _cd(3), H | 0xFFFFFFF, H | 1, _cd(4),
          H | 2, _cd(5)], (2 << 34) + (2 << 6), 3)  # a drop of exactly 2^27 wraps, a rise never; 2 wraps skipped
def test_skip_before_matches_reference(words, start_us, n_blocks):
    """Skipping ahead, the bytes left start at the reference's TIME_HIGH (in blocks of any size too), the
    time base and wraps are the reference's, and decoding on gives what decoding from the start gives."""
    data = np.array(words, "<u4").tobytes()
    i, time_us, wraps = reference_skip(words, start_us)
    dec = evt2.Evt2Decoder()
    rest = dec.skip_before(data, start_us)
    assert rest == (None if i == len(words) else data[4 * i:])
    assert (dec.time_us, dec.counters["wraps"]) == (time_us, wraps)
    fresh = evt2.Evt2Decoder()
    fresh.decode(data[: 4 * i])
    assert_events_equal(dec.decode(rest or b""), fresh.decode(data[4 * i:]))
    step = max(4, len(data) // n_blocks)
    blocks = [data[a : a + step] for a in range(0, len(data), step)]
    dec = evt2.Evt2Decoder()
    left = None
    while blocks and left is None:
        left = dec.skip_before(blocks.pop(0), start_us)
    assert (left or b"") + b"".join(blocks) == (b"" if i == len(words) else data[4 * i:])


def reference_encode(t, x, y, p, high=-1):
    """Plain-Python EVT2 encoder (the kernel's reference), from time-high `high` (-1: none written yet):
    (its words, the last time-high written). A TIME_HIGH (t >> 6, 28 bits) before each event whose differs
    from the last written, each 28-bit wrap on the way (from 0 at the start) spelled as the top and then 0;
    then the event's CD word (polarity, t's 6 low bits, x, y)."""
    words = []
    for ti, xi, yi, pi in zip(*(map(int, a) for a in (t, x, y, p))):
        if ti >> 6 != high:
            period = max(high, 0) >> 28
            words += [H | 0xFFFFFFF, H] * ((ti >> 34) - period)
            high = ti >> 6
            words.append(H | high & 0xFFFFFFF)
        words.append(pi << 28 | (ti & 63) << 22 | xi << 11 | yi)
    return words, high


_STEPS = st.lists(st.sampled_from([0, 0, 1, 63, 64, (1 << 34) - 64, 1 << 34, 3 << 34]), max_size=40)
_FIRST = st.sampled_from([0, 63, 64, (1 << 34) - 1, 1 << 34, (3 << 34) + 5]) | st.integers(0, 1 << 36)


@given(st.one_of(event_streams(), st.builds(lambda t0, g: _at(*(t0 + np.cumsum([0, *g]))), _FIRST, _STEPS)),
       st.lists(st.integers(0, 200), max_size=4))
@example(_at(0, 0, 64, (1 << 34) - 1, 1 << 34, 4 << 34), [3])
@example(_at((1 << 34) + 5, (3 << 34) + 64), [])  # the first event past a wrap: wraps from 0
def test_encoder_matches_its_reference_word_by_word(ev, cuts):
    """The encoder kernel (through `Evt2Encoder`, which carries the last time-high over calls) against
    `reference_encode`, cut into calls anywhere: the same words, and the same time-high left."""
    t, x, y, p = ev
    n = len(t)
    edges = [0, *sorted(c for c in cuts if c <= n), n]
    enc, high = evt2.Evt2Encoder(), -1
    for a, b in zip(edges[:-1], edges[1:]):
        want, high = reference_encode(t[a:b], x[a:b], y[a:b], p[a:b], high)
        assert np.frombuffer(enc.encode(t[a:b], x[a:b], y[a:b], p[a:b]), "<u4").tolist() == want
        assert enc.state.tolist() == [high]
