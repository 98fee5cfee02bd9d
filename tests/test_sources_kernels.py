"""The readers' small numba kernels and the EVT3 encoder against plain-Python references."""

import numpy as np
from evstream.sources._base import Unwrapper, _first_at_or_after
from hypothesis import given
from hypothesis import strategies as st

from evstream.codecs import evt3


def reference_unwrap(values, bits):
    out, offset, last = [], 0, None
    for v in values:
        if last is not None and last - v > 1 << (bits - 1):
            offset += 1 << bits
        last = v
        out.append(v + offset)
    return out


@given(st.sampled_from([23, 32]), st.lists(st.lists(st.integers(0, 2**32 - 1), max_size=40), max_size=4))
def test_unwrap_matches_reference_across_calls(bits, parts):
    parts = [[v % (1 << bits) for v in part] for part in parts]
    u = Unwrapper(bits)
    got = [int(v) for part in parts for v in u(np.array(part, np.uint32))]
    assert got == reference_unwrap([v for part in parts for v in part], bits)


def test_unwrap_counts_wraps_and_a_drop_of_exactly_half_is_no_wrap():
    u = Unwrapper(4)  # period 16, half 8
    out = u(np.array([8, 0, 15, 2, 9, 1, 0], np.uint32))  # 8 -> 0, 9 -> 1: a drop of half is no wrap
    assert out.dtype == np.int64 and out.tolist() == [8, 0, 15, 18, 25, 17, 16] and u.wraps == 1
    assert u(np.array([9, 0], np.uint32)).tolist() == [25, 32] and u.wraps == 2  # carried across calls


@given(st.lists(st.integers(-50, 50), max_size=30), st.integers(-60, 60), st.integers(0, 3))
def test_first_at_or_after_matches_reference(ts, boundary, start):
    t = np.array(ts, np.int64)
    want = next((i for i in range(start, len(ts)) if ts[i] >= boundary), -1)
    assert _first_at_or_after(t, boundary, start) == want


def reference_encode_evt3(t, x, y, p):
    """EVT3 words as the encoder documents them, in plain Python."""
    words = []
    started, high, low, row = False, 0, -1, -1

    def advance(frm, to):
        cur = frm
        while to >> 12 > cur >> 12:
            end = cur | 0xFFF
            while end - cur > 2047:
                cur += 2047
                words.append(0x8000 | cur & 0xFFF)
            words.extend([0x8FFF, 0x8000])
            cur = end + 1
        while to - cur > 2047:
            cur += 2047
            words.append(0x8000 | cur & 0xFFF)
        words.append(0x8000 | to & 0xFFF)

    n, i = len(t), 0
    t, x, y, p = (list(map(int, a)) for a in (t, x, y, p))
    while i < n:
        h, lo = t[i] >> 12, t[i] & 0xFFF
        if not started or h != high:
            advance(high if started else 0, h)
            started, high, low = True, h, -1
        if lo != low:
            words.append(0x6000 | lo)
            low = lo
        if y[i] != row:
            words.append(y[i])
            row = y[i]

        def same_run(m, i=i):
            return m < n and t[m] == t[i] and y[m] == y[i] and p[m] == p[i] and x[m] > x[m - 1]

        if same_run(i + 1) and same_run(i + 2) and x[i + 2] < x[i] + 12:
            words.append(0x3000 | p[i] << 11 | x[i])
            base, m = x[i], i
            while True:
                mask = 0
                while m < n and (m == i or same_run(m)) and x[m] < base + 12:
                    mask |= 1 << (x[m] - base)
                    m += 1
                words.append(0x4000 | mask)
                base += 12
                if not (same_run(m) and x[m] < base + 12):
                    break
            i = m
        else:
            words.append(0x2000 | p[i] << 11 | x[i])
            i += 1
    return np.array(words, "<u2").tobytes()


@st.composite
def rows_of_events(draw):
    n = draw(st.integers(0, 80))
    steps = np.array(draw(st.lists(st.sampled_from([0, 0, 0, 0, 0, 1, 5, 5000, 20_000_000]),
                                   min_size=n, max_size=n)), np.int64)
    t = np.cumsum(steps)
    dx = np.array(draw(st.lists(st.integers(0, 40), min_size=n, max_size=n)), np.int64)
    y = np.array(draw(st.lists(st.integers(0, 2), min_size=n, max_size=n)), np.int64)
    p = np.array(draw(st.lists(st.integers(0, 1), min_size=n, max_size=n)), np.int64)
    x = dx
    if draw(st.booleans()):  # rows: one (y, p) per timestamp, x rising in small steps, as a camera sends
        group = np.cumsum(steps != 0)
        y, p = group % 3, group % 2
        x = np.cumsum(dx % 4 + (dx % 9 == 0) * 13) % 2048
    return t, x.astype(np.uint16), y.astype(np.uint16), p.astype(np.uint8)


@given(rows_of_events())
def test_encoder_matches_reference_word_for_word(ev):
    assert evt3.encode(*ev) == reference_encode_evt3(*ev)
