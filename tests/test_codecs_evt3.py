"""EVT3 codec: the numba decoder against a plain-Python spec-literal reference, streaming splits,
encode -> decode round trips, faery agreement, and the real Gen4.1 recording."""

import numpy as np
import pytest
from codec_checks import (
    assert_events_equal,
    check_kernel_agrees_with_reference,
    checked_events,
    packet_room,
    with_boundary_examples,
)
from hypothesis import example, given
from hypothesis import strategies as st

from evstream.codecs import evt3

WRAP = 1 << 24


def reference_decode(data: bytes):
    """Spec-literal EVT3 decode, word by word, in plain Python (the kernel's reference)."""
    words = np.frombuffer(data[: len(data) // 2 * 2], "<u2").tolist()
    high = low = y = base = pol = loops = 0
    has_high = False
    out = []
    counts = dict.fromkeys(evt3.COUNTER_NAMES, 0)
    last = None
    for w in words:
        kind, pay = w >> 12, w & 0xFFF
        t = loops * WRAP + high * 4096 + low
        hits = []  # (x, p) of the events this word carries
        if kind == 0x2:
            hits = [(pay & 0x7FF, pay >> 11)]
        elif kind == 0x0:
            y = pay & 0x7FF
        elif kind in (0x4, 0x5):
            width = 12 if kind == 0x4 else 8
            hits = [(base + b, pol) for b in range(width) if pay >> b & 1]
            base += width
        elif kind == 0x3:
            base, pol = pay & 0x7FF, pay >> 11
        elif kind == 0x6:
            low = pay
        elif kind == 0x8:
            if has_high and high - pay >= 4080:
                loops += 1
                counts["wraps"] += 1
            high, has_high = pay, True
        elif kind == 0xA:
            counts["trigger"] += 1
        elif kind == 0xE:
            counts["others"] += 1
        elif kind in (0x7, 0xF):
            counts["continued"] += 1
        else:
            counts["unknown"] += 1
        for xx, pp in hits:
            if not has_high:
                counts["no_time"] += 1
                continue
            if last is not None and t < last:
                counts["time_back"] += 1
            last = t
            out.append((t, xx, y, pp))
    a = np.array(out, np.int64).reshape(-1, 4)
    return (a[:, 0], a[:, 1].astype(np.uint16), a[:, 2].astype(np.uint16), a[:, 3].astype(np.uint8)), counts


# words biased towards the meaningful types, with garbage types mixed in
word = st.one_of(
    st.integers(0, 0xFFFF),
    st.builds(lambda k, pay: (k << 12) | pay, st.sampled_from([0x0, 0x2, 0x3, 0x4, 0x5, 0x6, 0x8]),
              st.integers(0, 0xFFF)),
)


@given(st.lists(word, max_size=300), st.integers(0, 1))
def test_decoder_matches_reference_on_random_words(words, odd_tail):
    data = np.array(words, "<u2").tobytes() + b"\x07" * odd_tail
    want, counts = reference_decode(data)
    dec = evt3.Evt3Decoder()
    got = dec.decode(data)
    assert_events_equal(got, want)
    assert dec.counters == counts
    assert dec.pending_bytes == odd_tail


@given(st.lists(word, max_size=200), st.lists(st.integers(0, 401), max_size=6))
def test_decoder_is_split_invariant(words, cuts):
    data = np.array(words, "<u2").tobytes()
    edges = [0, *sorted(c for c in cuts if c <= len(data)), len(data)]
    dec = evt3.Evt3Decoder()
    parts = [dec.decode(data[a:b]) for a, b in zip(edges[:-1], edges[1:])]
    got = tuple(np.concatenate([p[k] for p in parts]) for k in range(4))
    assert_events_equal(got, evt3.decode(data))


def test_decoder_accepts_numpy_and_memoryview_and_grows_for_dense_vectors():
    # one TIME_HIGH then 5000 full VECT_12 words: 60,000 events from 5,003 words
    words = [0x8001, 0x6002, 0x0007, 0x3800] + [0x4FFF] * 5000
    arr = np.array(words, "<u2")
    t, x, y, p = evt3.decode(arr)
    assert len(t) == 60_000 and (t == 4096 + 2).all() and (y == 7).all() and (p == 1).all()
    assert np.array_equal(x[:13].astype(int), np.arange(13))
    assert_events_equal(evt3.decode(memoryview(arr.tobytes())), (t, x, y, p))


def test_skipped_words_are_counted_not_decoded():
    words = [0x8000, 0x6010, 0x0003, 0xA101, 0x2005, 0xE123, 0x7001, 0xF0FF, 0x1234, 0x9000, 0x2806]
    dec = evt3.Evt3Decoder()
    t, x, y, p = dec.decode(np.array(words, "<u2").tobytes())
    assert t.tolist() == [16, 16] and x.tolist() == [5, 6] and p.tolist() == [0, 1]
    c = dec.counters
    assert (c["trigger"], c["others"], c["continued"], c["unknown"]) == (1, 1, 2, 2)


def test_time_low_stepping_back_is_kept_and_counted():
    words = [0x8005, 0x6000 | 811, 0x0000, 0x2001, 0x6000 | 800, 0x2002]
    dec = evt3.Evt3Decoder()
    t, *_ = dec.decode(np.array(words, "<u2").tobytes())
    assert t.tolist() == [5 * 4096 + 811, 5 * 4096 + 800]
    assert dec.counters["time_back"] == 1


def test_time_high_wrap_is_unwrapped_and_small_drops_are_not_wraps():
    words = [0x8FFF, 0x6001, 0x0000, 0x2001, 0x8000, 0x2002, 0x8FFF, 0x2003, 0x8FF0, 0x2004]
    dec = evt3.Evt3Decoder()
    t, *_ = dec.decode(np.array(words, "<u2").tobytes())
    top = 4095 * 4096 + 1
    assert t.tolist() == [top, WRAP + 1, WRAP + top, WRAP + 0xFF0 * 4096 + 1]
    assert dec.counters["wraps"] == 1 and dec.counters["time_back"] == 1


def test_events_before_the_first_time_high_are_skipped():
    words = [0x6005, 0x0001, 0x2001, 0x8001, 0x2002]
    dec = evt3.Evt3Decoder()
    t, x, *_ = dec.decode(np.array(words, "<u2").tobytes())
    assert x.tolist() == [2] and t.tolist() == [4096 + 5] and dec.counters["no_time"] == 1



def test_words_before_the_first_time_high_set_the_row_time_low_and_vector_base():
    """Before any TIME_HIGH, events are counted, not decoded, but ADDR_Y, TIME_LOW, VECT_BASE_X and the
    vector words (which move the base on) set what the events after it take."""
    words = [0x0005, 0x6007, 0x3800 | 100, 0x4801, 0x4000, 0x51FF, 0x2001,  # row 5, low 7, base 100 ON, 2+0+8+1 events
             0x8003, 0x4003, 0x2002]  # then time-high 3: a vector at base 100 + 12 + 12 + 8 and one event at x 2
    dec = evt3.Evt3Decoder()
    t, x, y, p = dec.decode(np.array(words, "<u2").tobytes())
    assert t.tolist() == [3 * 4096 + 7] * 3 and x.tolist() == [132, 133, 2]
    assert y.tolist() == [5, 5, 5] and p.tolist() == [1, 1, 0] and dec.counters["no_time"] == 11
    assert_events_equal((t, x, y, p), reference_decode(np.array(words, "<u2").tobytes())[0])


before_time_high = st.builds(lambda k, pay: (k << 12) | pay, st.sampled_from([0x0, 0x2, 0x3, 0x4, 0x5, 0x6, 0xA]),
                             st.integers(0, 0xFFF))
events_only = st.builds(lambda k, pay: (k << 12) | pay, st.sampled_from([0x2, 0x4, 0x5, 0x6]), st.integers(0, 0xFFF))


@given(st.lists(before_time_high, min_size=1, max_size=30), st.integers(0, 0xFFF), st.lists(events_only, max_size=30))
def test_decoder_matches_reference_after_a_long_run_without_time_high(prefix, high, rest):
    data = np.array([*prefix, 0x8000 | high, *rest], "<u2").tobytes()
    want, counts = reference_decode(data)
    dec = evt3.Evt3Decoder()
    assert_events_equal(dec.decode(data), want)
    assert dec.counters == counts


def test_a_block_opening_on_an_event_keeps_the_wraps_before_it():
    dec = evt3.Evt3Decoder()
    t, *_ = dec.decode(np.array([0x8FFF, 0x6001, 0x0000, 0x2001, 0x8000, 0x6002], "<u2").tobytes())
    assert t.tolist() == [4095 * 4096 + 1]
    t, *_ = dec.decode(np.array([0x2003, 0x8001, 0x2004], "<u2").tobytes())
    assert t.tolist() == [WRAP + 2, WRAP + 4096 + 2]



def test_every_step_back_is_counted_events_and_vectors_alike():
    """A step back is an event (or a non-empty vector) earlier than the one before it: equal times and an
    empty vector are not; each one counts."""
    words = [0x8001, 0x6032, 0x0002, 0x300A, 0x4003,  # x 10, 11 at 4096 + 50
             0x6028, 0x4001,  # x 22 at + 40: back (1)
             0x601E, 0x5001, 0x4002, 0x4000, 0x2001,  # x 34 at + 30: back (2); x 43, x 1 at + 30; an empty vector
             0x6014, 0x2002, 0x2003]  # x 2 at + 20: back (3); x 3 at + 20
    data = np.array(words, "<u2").tobytes()
    dec = evt3.Evt3Decoder()
    t, x, *_ = dec.decode(data)
    assert (t - 4096).tolist() == [50, 50, 40, 30, 30, 30, 20, 20] and x.tolist() == [10, 11, 22, 34, 43, 1, 2, 3]
    assert dec.counters["time_back"] == 3 == reference_decode(data)[1]["time_back"]


def test_a_wrap_is_a_time_high_drop_of_4080_or_more():
    words = [0x8FF0, 0x600A, 0x0001, 0x2001,  # 0xFF0 -> 0: a drop of 4080, a wrap
             0x8000, 0x2002, 0x8FEF, 0x2003,
             0x8000, 0x2004,  # 0xFEF -> 0: a drop of 4079, a step back
             0x8FFF, 0x8000, 0x2005]  # 0xFFF -> 0: the second wrap
    data = np.array(words, "<u2").tobytes()
    dec = evt3.Evt3Decoder()
    t, *_ = dec.decode(data)
    assert t.tolist() == [0xFF0 * 4096 + 10, WRAP + 10, WRAP + 0xFEF * 4096 + 10, WRAP + 10, 2 * WRAP + 10]
    assert (dec.counters["wraps"], dec.counters["time_back"]) == (2, 1)
    assert_events_equal((t, *_), reference_decode(data)[0])


# -- encoder --------------------------------------------------------------------------------------
@st.composite
def event_streams(draw):
    n = draw(st.integers(0, 300))
    gaps = draw(st.lists(st.one_of(st.just(0), st.integers(0, 50), st.integers(0, 40_000_000)),
                         min_size=n, max_size=n))
    t0 = draw(st.one_of(st.integers(0, 10), st.integers(0, 3 * WRAP)))
    t = t0 + np.cumsum(np.array(gaps, np.int64))
    rows = draw(st.lists(st.tuples(st.integers(0, 2047), st.integers(0, 2047), st.integers(0, 1)),
                         min_size=n, max_size=n))
    a = np.array(rows, np.int64).reshape(-1, 3)
    x, y, p = a[:, 0].astype(np.uint16), a[:, 1].astype(np.uint16), a[:, 2].astype(np.uint8)
    # make vector-friendly runs: copy (t, y, p) of a run start over the next events, x increasing
    if n > 10 and draw(st.booleans()):
        i = draw(st.integers(0, n - 10))
        k = draw(st.integers(3, 10))
        steps = draw(st.lists(st.integers(1, 14), min_size=k, max_size=k))
        xs = np.minimum(int(x[i]) % 1500 + np.cumsum(steps), 2047)
        if np.all(np.diff(xs) > 0):
            t[i : i + k] = t[i]
            t[i + k :] = np.maximum(t[i + k :], t[i])
            y[i : i + k], p[i : i + k], x[i : i + k] = y[i], p[i], xs
    return t, x, y, p


@given(event_streams())
def test_encode_round_trips_exactly(ev):
    data = evt3.encode(*ev)
    assert_events_equal(evt3.decode(data), ev)
    assert_events_equal(reference_decode(data)[0], ev)
    if len(ev[0]):
        first = np.frombuffer(data[:2], "<u2")[0]
        assert first >> 12 == 0x8  # self-contained: starts with a time base


def test_encode_uses_vectors_for_rows_of_events():
    x = np.arange(100, 160, dtype=np.uint16)
    n = len(x)
    ev = (np.full(n, 77, np.int64), x, np.full(n, 3, np.uint16), np.ones(n, np.uint8))
    data = evt3.encode(*ev)
    words = np.frombuffer(data, "<u2")
    # TIME_HIGH, TIME_LOW, ADDR_Y, VECT_BASE_X, 5 x VECT_12
    assert len(words) == 9 and (words[4:] >> 12 == 0x4).all()
    assert_events_equal(evt3.decode(data), ev)


@pytest.mark.parametrize("bad, msg", [
    (dict(t=[5, 4]), "event 1"), (dict(t=[-1, 0]), "event 0"), (dict(x=[0, 2048]), "event 1"),
    (dict(p=[2, 0]), "event 0"),
])
def test_encode_rejects_what_evt3_cannot_carry(bad, msg):
    ev = dict(t=[0, 1], x=[0, 1], y=[0, 0], p=[0, 1]) | bad
    with pytest.raises(ValueError, match=msg):
        evt3.encode(**{k: np.array(v) for k, v in ev.items()})


def _faery_decode(tmp_path, data: bytes, name="a.raw"):
    import faery  # declared (dev) dependency: a broken install fails
    path = tmp_path / name
    path.write_bytes(b"% evt 3.0\n% format EVT3;height=2048;width=2048\n% end\n" + data)
    chunks = [c for c in faery.events_stream_from_file(path) if len(c)]
    ev = np.concatenate(chunks) if chunks else np.zeros(0, [("t", "<u8"), ("x", "<u2"), ("y", "<u2"),
                                                            ("on", "?")])
    return ev["t"].astype(np.int64), ev["x"], ev["y"], ev["on"].astype(np.uint8)


def test_faery_decodes_our_encoding_identically(tmp_path):
    rng = np.random.default_rng(3)
    n = 50_000
    # sparse and dense stretches, rows for vectors, gaps across several 24-bit wraps
    t = np.sort(np.concatenate([rng.integers(0, 5_000, n // 2), rng.integers(20_000_000, 90_000_000, n // 2)]))
    x = rng.integers(0, 2048, n).astype(np.uint16)
    y = rng.integers(0, 2048, n).astype(np.uint16)
    p = rng.integers(0, 2, n).astype(np.uint8)
    t[100:160], y[100:160], p[100:160] = t[100], 9, 1
    x[100:160] = np.arange(300, 360)
    t[160:] = np.maximum(t[160:], t[100])
    ev = (t, x, y, p)
    data = evt3.encode(*ev)
    assert_events_equal(_faery_decode(tmp_path, data), ev)
    assert_events_equal(evt3.decode(data), ev)


@given(event_streams())
def test_faery_agrees_on_random_streams(tmp_path_factory, ev):
    data = evt3.encode(*ev)
    assert_events_equal(_faery_decode(tmp_path_factory.mktemp("f"), data), ev)


# -- the real recording ---------------------------------------------------------------------------
def _raw_body(path):
    data = path.read_bytes()
    i = 0
    while data[i : i + 1] == b"%":
        i = data.index(b"\n", i) + 1
    return data[i:]


def test_real_gen41_file_decodes_spec_literally(real_data, tmp_path):
    path = real_data / "prophesee_gen41_hd_evt3_expelliarmus.raw"
    body = _raw_body(path)
    dec = evt3.Evt3Decoder()
    parts = [dec.decode(body[i : i + 65_537]) for i in range(0, len(body), 65_537)]
    t, x, y, p = (np.concatenate([q[k] for q in parts]) for k in range(4))
    # SOURCES.md: 219,596 events, t = 11,718,656 ... 11,727,457 µs (evlib's spec-literal decode)
    assert len(t) == 219_596
    assert (int(t.min()), int(t.max())) == (11_718_656, 11_727_457)
    assert x.max() < 1280 and y.max() < 720
    assert abs(p.mean() - 0.526) < 0.001
    assert dec.counters["unknown"] == 0
    import faery  # declared (dev) dependency: a broken install fails
    ev = np.concatenate(list(faery.events_stream_from_file(path)))
    np.testing.assert_array_equal(ev["x"], x)
    np.testing.assert_array_equal(ev["y"], y)
    np.testing.assert_array_equal(ev["on"], p.astype(bool))
    # faery keeps the larger TIME_LOW where the stream steps back: 1,455 events differ by 1-11 µs
    diff = ev["t"].astype(np.int64) - t
    assert int((diff != 0).sum()) == 1455 and diff.min() >= 0 and diff.max() <= 11
    # and what we encode from it, faery decodes to our events
    ts = np.maximum.accumulate(t)
    assert_events_equal(_faery_decode(tmp_path, evt3.encode(ts, x, y, p)), (ts, x, y, p))


@given(event_streams(), st.lists(st.integers(0, 300), max_size=5))
def test_streaming_encoder_output_concatenates_to_one_stream(ev, cuts):
    n = len(ev[0])
    edges = [0, *sorted(c for c in cuts if c <= n), n]
    enc = evt3.Evt3Encoder()
    data = b"".join(enc.encode(*(a[i:j] for a in ev)) for i, j in zip(edges[:-1], edges[1:]))
    assert_events_equal(evt3.decode(data), ev)
    if n:
        with pytest.raises(ValueError, match="cannot be written"):
            enc.encode(ev[0][-1:] - 1, ev[1][-1:], ev[2][-1:], ev[3][-1:])


@given(checked_events())
@with_boundary_examples
def test_check_kernel_matches_reference_on_random_events(ev):
    """The numba check against plain Python, events crowding every limit (x = 2047 and 2048, p = 2,
    a step back in time, a first event before `prev`); and the encoder refuses exactly that event."""
    check_kernel_agrees_with_reference(evt3, ev)


def _kinds(data: bytes) -> list[int]:
    return (np.frombuffer(data, "<u2") >> 12).tolist()


def _time_high_steps_are_forward_or_wraps(data: bytes):
    """Each TIME_HIGH after the first steps forward by at most 2047 (under half the 12-bit range; 0 where
    the clock already stands at 4095 before a wrap) or wraps 4095 -> 0, so no decoder can take a step for a
    wrap or a wrap for a step back; no word is unknown."""
    words = np.frombuffer(data, "<u2")
    highs = (words[words >> 12 == 0x8] & 0xFFF).astype(np.int64).tolist()
    for a, b in zip(highs[:-1], highs[1:]):
        assert 0 <= b - a <= 2047 or (a, b) == (4095, 0), (a, b)
    dec = evt3.Evt3Decoder()
    dec.decode(data)
    assert dec.counters == dict.fromkeys(evt3.COUNTER_NAMES, 0) | {"wraps": dec.counters["wraps"]}


@pytest.mark.parametrize("t", [
    [0, 3 * WRAP + 3000 * 4096 + 5],  # from the bottom of a period: steps up to the wrap, then past it
    [4095 * 4096, WRAP + 2047 * 4096, WRAP + 2048 * 4096 + 7],  # a wrap from the top; a step of exactly 2047
    [5, 5 + 2048 * 4096, 9 * WRAP],
])
def test_encoder_time_high_steps_stay_under_half_the_range(t):
    t = np.array(t, np.int64)
    n = len(t)
    ev = (t, np.arange(n, dtype=np.uint16), np.zeros(n, np.uint16), np.zeros(n, np.uint8))
    data = evt3.encode(*ev)
    _time_high_steps_are_forward_or_wraps(data)
    assert_events_equal(evt3.decode(data), ev)


@given(event_streams())
def test_encoder_time_high_steps_stay_under_half_the_range_on_random_streams(ev):
    _time_high_steps_are_forward_or_wraps(evt3.encode(*ev))


@pytest.mark.parametrize("x, p, kinds", [
    ([0, 1, 2, 24], [1] * 4, [0x3, 0x4, 0x2]),  # the 4th is 12 past the vector's span: an ADDR_X of its own
    ([0, 1, 2, 23], [1] * 4, [0x3, 0x4, 0x4]),  # the 4th in the next 12: a second VECT_12
    ([0, 1, 2, 2], [1] * 4, [0x3, 0x4, 0x2]),  # a repeated pixel ends the run: its own ADDR_X
    ([0, 1, 2, 2, 3], [1] * 5, [0x3, 0x4, 0x2, 0x2]),
    ([5, 6, 7], [0, 1, 0], [0x2, 0x2, 0x2]),  # a vector is one polarity
    ([5, 3, 7], [1] * 3, [0x2, 0x2, 0x2]),  # x must increase
    ([5, 6, 6], [1] * 3, [0x2, 0x2, 0x2]),  # strictly: three events of two pixels do not pay for a vector
    ([0, 1, 12], [1] * 3, [0x2, 0x2, 0x2]),  # the third 12 past the first: not within one vector word
    ([0, 1, 11], [1] * 3, [0x3, 0x4]),  # the third 11 past it: the word's last pixel
])
def test_encoder_puts_runs_of_three_increasing_pixels_in_vectors_and_nothing_else(x, p, kinds):
    """Runs of >= 3 events with the same t, y, p and strictly increasing x within 12 pixels go into vector
    words (encode's promise); anything else is ADDR_X words, and every event comes back, repeats too."""
    n = len(x)
    ev = (np.full(n, 77, np.int64), np.array(x, np.uint16), np.full(n, 3, np.uint16), np.array(p, np.uint8))
    data = evt3.encode(*ev)
    assert _kinds(data) == [0x8, 0x6, 0x0, *kinds]
    assert_events_equal(evt3.decode(data), ev)


def test_streaming_encoder_adds_only_what_changed():
    """A later call at the same time and row adds the event's ADDR_X word alone: the encoder carries the
    time high, time low and row over calls."""
    enc = evt3.Evt3Encoder()
    one = lambda t, x, y: enc.encode(np.array([t]), np.array([x]), np.array([y]), np.array([1]))  # noqa: E731
    assert _kinds(one(5000, 1, 2)) == [0x8, 0x6, 0x0, 0x2]
    assert _kinds(one(5000, 3, 2)) == [0x2]
    assert _kinds(one(5001, 3, 2)) == [0x6, 0x2]
    assert _kinds(one(5001, 3, 4)) == [0x0, 0x2]
    assert _kinds(one(9000, 3, 4)) == [0x8, 0x6, 0x2]


def test_encoder_messages_say_what_is_wrong():
    enc = evt3.Evt3Encoder()
    with pytest.raises(ValueError, match=r"^encode: arrays differ in length \(t 2, x 1, y 2, p 2\)$"):
        enc.encode(np.zeros(2), np.zeros(1), np.zeros(2), np.zeros(2))
    big = evt3.MAX_WRAPS_PER_CALL + 1
    with pytest.raises(ValueError, match=(
            rf"^encode: timestamps jump from 0 to {big * WRAP} µs \({big:,} wraps of the 24-bit clock, 5 words "
            r"each\): subtract a time origin first \(RAW writers keep it in the header\)$")):
        enc.encode(np.array([big * WRAP]), np.zeros(1), np.zeros(1), np.zeros(1))
    with pytest.raises(ValueError, match=(
            r"^encode: event 1 \(t=7 µs, previous 7 µs, x=3, y=2, p=2\) cannot be written: EVT3 needs "
            r"non-decreasing t >= 0, x and y < 2048, p 0 or 1$")):
        enc.encode(np.array([7, 7]), np.array([1, 3]), np.array([2, 2]), np.array([0, 2]))
    # a negative row or column is refused (as the unsigned 16-bit value it is cast to), never written
    for field in ("x", "y"):
        ev = dict(t=np.array([3]), x=np.array([4]), y=np.array([5]), p=np.array([0])) | {field: np.array([-1])}
        with pytest.raises(ValueError, match=rf"^encode: event 0 \(.*{field}=65535.*cannot be written"):
            evt3.encode(**ev)


def test_encoder_takes_any_integer_dtype_and_names_the_last_call_s_time():
    """Times and coordinates of any integer dtype give the same words (uint64 times: the encoder works in
    int64); a call whose first event goes back before the previous call's last names that time."""
    t, x, y, p = [64, 64, 127, 5000], [0, 2047, 3, 4], [5, 6, 2047, 0], [0, 1, 1, 0]
    ev = np.array(t, np.int64), np.array(x, np.uint16), np.array(y, np.uint16), np.array(p, np.uint8)
    want = evt3.encode(*ev)
    assert_events_equal(evt3.decode(want), ev)
    for wide in ((np.array(t, np.uint64), np.array(x, np.int64), np.array(y, np.int32), np.array(p, np.int16)),
                 (np.array(t, np.uint32), *(np.array(a, np.uint64) for a in (x, y, p)))):
        assert evt3.encode(*wide) == want
    enc = evt3.Evt3Encoder()
    enc.encode(*ev)
    with pytest.raises(ValueError, match=r"^encode: event 4 \(t=4999 µs, previous 5000 µs, x=1, y=2, p=0\) "):
        enc.encode(np.array([4999, 6000]), np.array([1, 1]), np.array([2, 2]), np.array([0, 0]))


def test_encoder_word_buffer_is_each_call_s_worst_case_and_is_kept():
    """The buffer the encoder writes into is grown to a call's worst case (4 words an event and the TIME_HIGH
    steps from the last call's time, as the packets' `packet_room` less their opening word) when it is
    shorter, and otherwise kept, the same array (no fresh pages per call). A larger estimate gives the same
    words, a smaller one may not fit: only its length shows either."""
    rng = np.random.default_rng(21)
    far = 40 * WRAP + 7
    calls = [[5, 9], [20, 30],  # the second needs exactly the first's room: kept
             [far],  # 40 wraps from 30 µs
             np.sort(rng.integers(far, 42 * WRAP + 5, 100)),  # 100 events over 2 wraps from 40 wraps on
             [42 * WRAP + 6] * 3]
    enc, last_t, sent = evt3.Evt3Encoder(), 0, []
    for t in calls:
        t = np.asarray(t, np.int64)
        ev = (t, rng.integers(0, 2048, len(t)).astype(np.uint16), rng.integers(0, 2048, len(t)).astype(np.uint16),
              rng.integers(0, 2, len(t)).astype(np.uint8))
        before = enc._scratch
        room = packet_room(t, 0, len(t), last_t >> 12) - 1
        data = enc.encode(*ev)
        assert len(enc._scratch) == max(len(before), room) and (enc._scratch is before) == (len(before) >= room)
        assert len(data) // 2 <= room
        sent.append((data, ev))
        last_t = int(t[-1])
    assert_events_equal(evt3.decode(b"".join(d for d, _ in sent)),
                        tuple(np.concatenate([e[i] for _, e in sent]) for i in range(4)))


def test_encoder_takes_the_largest_jump_it_allows():
    """MAX_WRAPS_PER_CALL wraps of the clock in one call are written (and decode back); one more is refused."""
    t = np.array([5, evt3.MAX_WRAPS_PER_CALL * WRAP + 5], np.int64)
    ev = (t, np.array([1, 2], np.uint16), np.array([3, 4], np.uint16), np.array([0, 1], np.uint8))
    data = evt3.encode(*ev)
    assert_events_equal(evt3.decode(data), ev)
    with pytest.raises(ValueError, match="wraps of the 24-bit clock"):
        evt3.encode(t + np.array([0, WRAP]), *ev[1:])


# -- packets: one kernel call for a batch ------------------------------------------------------------
def check_packets_kernel(t, x, y, p, bounds, high: int):
    """`_encode_packets_kernel` against the packets written one by one (`evt3_sensor_clock`, each from where
    the previous left the clock), for an `out` as long as encode_many makes it and, for each packet j, one
    word short of j's worst case and exactly it: the kernel writes the packets before the first whose worst
    case does not fit, exactly as one by one, and nothing past `out`."""
    from evstream.codecs.packets import evt3_sensor_clock

    t = np.asarray(t, np.int64)
    want, rooms, h = [], [], high
    for a, b in zip(bounds[:-1], bounds[1:]):
        want.append(evt3_sensor_clock(t[a:b], x[a:b], y[a:b], p[a:b], None if h < 0 else h))
        rooms.append(packet_room(t, a, b, h))
        h = int(t[b - 1]) >> 12
    starts = np.cumsum([0] + [len(w) // 2 for w in want])
    lengths = {sum(rooms), *(int(starts[j]) + rooms[j] + d for j in range(len(want)) for d in (-1, 0))}
    for length in sorted(lengths):
        done_want = next((j for j in range(len(want)) if starts[j] + rooms[j] > length), len(want))
        buffer = np.full(length + int(starts[-1]) + 64, 0xABCD, np.uint16)  # what lies past `out`
        ends = np.zeros(len(want), np.int64)
        done = evt3._encode_packets_kernel(t, x, y, p, np.asarray(bounds, np.int64), np.int64(high),
                                           buffer[:length], ends)
        assert done == done_want, (length, rooms)
        np.testing.assert_array_equal(ends[:done], starts[1 : done + 1])
        assert buffer[: starts[done]].tobytes() == b"".join(want[:done])
        assert (buffer[length:] == 0xABCD).all()


@pytest.mark.parametrize("offset, high", [
    (0, -1),  # the first event at t = 0, the clock from it
    (5 * 4096, 0),  # the clock left at time-high 0 by an earlier batch
    (2 * WRAP + 3 * 4096, 2 * 4096 + 1),  # past two wraps, the clock behind the first event
])
def test_packets_kernel_writes_each_packet_with_room_for_its_worst_case(offset, high):
    t = offset + np.array([0, 10, 5000, 2 * WRAP + 77, 2 * WRAP + 78, 2 * WRAP + 78, 3 * WRAP + 5], np.int64)
    n = len(t)
    x, y, p = np.arange(n, dtype=np.uint16) * 3, np.full(n, 7, np.uint16), np.arange(n, dtype=np.uint8) % 2
    check_packets_kernel(t, x, y, p, [0, 2, 3, 6, 7], high)


@given(event_streams(), st.integers(1, 8), st.integers(0, 99), st.sampled_from(["first", "zero", "behind"]))
def test_packets_kernel_writes_each_packet_with_room_for_its_worst_case_on_random_streams(ev, n_packets, seed,
                                                                                         clock):
    t, x, y, p = ev
    if not len(t):
        return
    rng = np.random.default_rng(seed)
    bounds = np.unique(np.concatenate([[0, len(t)], rng.integers(1, len(t) + 1, n_packets)])).tolist()
    high = {"first": -1, "zero": 0, "behind": max(0, (int(t[0]) >> 12) - int(rng.integers(0, 3 * 4096)))}[clock]
    check_packets_kernel(t, x, y, p, bounds, high)


def test_packets_kernel_stops_at_a_packet_without_events():
    """A packet with no event is not written (the kernel would read its first and last event outside it):
    the kernel stops there, and encode_many then says what `encode` says of it."""
    from evstream.codecs.packets import PacketEncoder

    t = np.array([10, 20, 30, 5000], np.int64)
    x = y = np.array([1, 2, 3, 4], np.uint16)
    p = np.array([0, 1, 0, 1], np.uint8)
    for bounds, done in (([0, 2, 2, 4], 1), ([0, 4, 4], 1), ([0, 0, 4], 0)):
        ends = np.zeros(len(bounds) - 1, np.int64)
        out = np.zeros(100, np.uint16)
        assert evt3._encode_packets_kernel(t, x, y, p, np.array(bounds, np.int64), np.int64(-1), out, ends) == done
        with pytest.raises(ValueError, match="^a packet needs at least one event$"):
            PacketEncoder(width=64, height=48).encode_many(t, x, y, p, bounds)


# -- the encoder word by word ----------------------------------------------------------------------
def reference_time_highs(frm: int, to: int) -> list[int]:
    """The TIME_HIGH words from absolute time-high `frm` to `to`: within a period (4096 time-highs) steps of
    at most 2047 up; a wrap spelled 4095 then 0 (4095 again where the clock stands on it); the target last
    (again where a wrap's 0 is the target)."""
    highs, cur = [], frm
    while cur >> 12 < to >> 12:
        top = cur | 0xFFF
        while top - cur > 2047:
            cur += 2047
            highs.append(cur)
        highs += [top, top + 1]
        cur = top + 1
    while to - cur > 2047:
        cur += 2047
        highs.append(cur)
    return [0x8000 | (h & 0xFFF) for h in highs + [to]]


def reference_encode(t, x, y, p, state=(False, 0, -1, -1)):
    """Plain-Python EVT3 encoder (the kernel's reference), from `state` (started, time-high, time-low, row):
    (its words, the state after). A new time-high is reached by `reference_time_highs` (from 0 at the
    start) and forgets the time low; a TIME_LOW or ADDR_Y only when it changes; the events of a run (same
    t, y and p, x strictly increasing) from event i go into VECT_BASE_X and VECT_12 words when its first
    three are within 12 pixels, 12 pixels a word, for as long as the run reaches the next word's 12;
    any other event is one ADDR_X."""
    t, x, y, p = (list(map(int, a)) for a in (t, x, y, p))
    started, high, low, row = state
    words, i, n = [], 0, len(t)
    while i < n:
        if not started or t[i] >> 12 != high:
            words += reference_time_highs(high if started else 0, t[i] >> 12)
            started, high, low = True, t[i] >> 12, -1
        if t[i] & 0xFFF != low:
            low = t[i] & 0xFFF
            words.append(0x6000 | low)
        if y[i] != row:
            row = y[i]
            words.append(row)
        end = i + 1  # the run from i
        while end < n and (t[end], y[end], p[end]) == (t[i], y[i], p[i]) and x[end] > x[end - 1]:
            end += 1
        if end - i >= 3 and x[i + 2] < x[i] + 12:
            words.append(0x3000 | p[i] << 11 | x[i])
            base = x[i]
            while i < end and x[i] < base + 12:
                mask = 0
                while i < end and x[i] < base + 12:
                    mask |= 1 << (x[i] - base)
                    i += 1
                words.append(0x4000 | mask)
                base += 12
        else:
            words.append(0x2000 | p[i] << 11 | x[i])
            i += 1
    return words, (started, high, low, row)


@st.composite
def dense_streams(draw):
    """Streams made of runs (same t, y and p, x stepping up by 1..13: inside one vector word, onto the next
    word's first pixel, across two, just past one), the time stepping between runs by 0, a TIME_LOW, a
    TIME_HIGH, the largest step and wraps; few rows, so runs often continue one another."""
    runs = draw(st.lists(st.tuples(
        st.sampled_from([0, 0, 0, 1, 4095, 4096, 2047 * 4096, 2048 * 4096, WRAP - 1, WRAP, 3 * WRAP + 5]),
        st.sampled_from([0, 3, 3, 2047]), st.sampled_from([0, 1, 1]), st.integers(0, 2047),
        st.lists(st.sampled_from([1, 1, 1, 2, 9, 10, 11, 12, 13]), max_size=8)), max_size=12))
    t = draw(st.sampled_from([0, 4095, 4095 * 4096 + 7, WRAP - 1]) | st.integers(0, 3 * WRAP))
    events = []
    for gap, y, p, x0, steps in runs:
        t += gap
        events += [(t, x, y, p) for x in np.cumsum([x0, *steps]).tolist() if x < 2048]
    a = np.array(events, np.int64).reshape(-1, 4)
    return a[:, 0], a[:, 1].astype(np.uint16), a[:, 2].astype(np.uint16), a[:, 3].astype(np.uint8)


@pytest.mark.parametrize("frm, to", [
    (0, 0), (5, 5), (0, 2047), (0, 2048), (4095, 4095), (4095, 4096), (4095, 4097), (4094, 4096), (0, 4096),
    (2048, 4096 + 2047), (2048, 4096 + 2048), (0, 3 * 4096 + 5), (1, 8191),
])
def test_time_high_steps_match_their_reference(frm, to):
    """`_advance_time_high` word by word: at and past the largest step, from and onto the top of a period,
    across one and several wraps."""
    out = np.zeros(64, np.uint16)
    k = evt3._advance_time_high(out, np.int64(3), np.int64(frm), np.int64(to))
    want = reference_time_highs(frm, to)
    assert out[3:k].tolist() == want and k == 3 + len(want) and not out[:3].any() and not out[k:].any()


@given(st.one_of(dense_streams(), event_streams()), st.lists(st.integers(0, 300), max_size=4))
@example((np.array([4095 * 4096 + 9, *[WRAP] * 5]), np.array([5, 0, 1, 2, 12, 36], np.uint16), np.full(6, 5, np.uint16),
          np.ones(6, np.uint8)), [])
@example((np.array([4095 * 4096 + 9, *[WRAP] * 5]), np.array([5, 0, 1, 2, 12, 36], np.uint16), np.full(6, 5, np.uint16),
          np.ones(6, np.uint8)), [3])
@example((np.array([5, 9, 9, 4096 + 3]), np.array([1, 2, 3, 4], np.uint16), np.full(4, 5, np.uint16),
          np.ones(4, np.uint8)), [1, 2])
@example((np.full(3, 7), np.array([0, 1, 2], np.uint16), np.array([5, 6, 5], np.uint16), np.ones(3, np.uint8)), [])
def test_encoder_matches_its_reference_word_by_word(ev, cuts):
    """The encoder kernel (through `Evt3Encoder`, whose state carries over calls) against `reference_encode`,
    on streams crowded with runs and random ones, cut into calls anywhere (a run cut by a call is two runs).
    The examples: from the top of a period onto the next one's 0, then a run at x 0, 1, 2 (a vector), 12 (the
    first pixel of its second word), 36 (past that word: an ADDR_X); then the same cut after 0 and 1; calls
    that go on in time-high 0 (a started encoder at time-high 0 writes no TIME_HIGH again); a run broken by
    its second event's row."""
    t, x, y, p = ev
    n = len(t)
    edges = [0, *sorted(c for c in cuts if c <= n), n]
    enc, state = evt3.Evt3Encoder(), (False, 0, -1, -1)
    for a, b in zip(edges[:-1], edges[1:]):
        want, state = reference_encode(t[a:b], x[a:b], y[a:b], p[a:b], state)
        assert np.frombuffer(enc.encode(t[a:b], x[a:b], y[a:b], p[a:b]), "<u2").tolist() == want
        assert (bool(enc.state[0]), *enc.state[1:].tolist()) == state


def test_decode_kernel_runs_until_the_words_or_the_room_run_out():
    """The kernel alone: words before the first TIME_HIGH do not stop it; it stops before a word once fewer
    than 12 events' room (one word's most) is left, and says how many words it took."""
    words = np.array([0x0003, 0x6005, 0x2001, 0x8001, 0x2002, 0x2003], np.uint16)  # ADDR_Y, TIME_LOW, no-time event
    for cap, want in ((24, (2, 6)), (13, (2, 6)), (12, (1, 5))):
        dec = evt3.Evt3Decoder()
        out = np.zeros(cap, np.int64), np.zeros(cap, np.uint16), np.zeros(cap, np.uint16), np.zeros(cap, np.uint8)
        assert evt3._decode_kernel(words, dec.state, dec._counters, *out) == want
        n = want[0]
        assert out[0][:n].tolist() == [4096 + 5] * n and out[1][:n].tolist() == [2, 3][:n]
        assert out[2][:n].tolist() == [3] * n
        assert dec.counters["no_time"] == 1
