"""What the EVT2 and EVT3 encoders may write, in plain Python: the reference of their `_check_kernel`s,
and the checks both codecs' tests share."""

import numpy as np
import pytest
from hypothesis import example
from hypothesis import strategies as st

LIMIT = 2048  # x and y fit in 11 bits in both formats


def reference_check(t, x, y, p, prev) -> int:
    """Index of the first event that cannot be written (time before `prev` or before the previous
    event, x or y outside 0..2047, p not 0 or 1), else -1."""
    for i in range(len(t)):
        if int(t[i]) < prev or not 0 <= int(x[i]) < LIMIT or not 0 <= int(y[i]) < LIMIT or int(p[i]) not in (0, 1):
            return i
        prev = int(t[i])
    return -1


# most events valid (x and y often at 2047, p at 1), a few broken in one field, right past its limit
_valid = st.tuples(st.sampled_from([0, 1, LIMIT - 2, LIMIT - 1]) | st.integers(0, LIMIT - 1),
                   st.sampled_from([0, 1, LIMIT - 2, LIMIT - 1]) | st.integers(0, LIMIT - 1), st.integers(0, 1))
_fault = st.sampled_from([None] * 12 + ["t", "x", "y", "p"])
_past = {"x": st.sampled_from([LIMIT, LIMIT + 1, 0xFFFF]), "y": st.sampled_from([LIMIT, LIMIT + 1, 0xFFFF]),
         "p": st.sampled_from([2, 255])}


@st.composite
def checked_events(draw, n_max=30):
    """(t int64, x uint16, y uint16, p uint8, prev) arrays, each event valid or broken in one field."""
    n = draw(st.integers(0, n_max))
    t0 = draw(st.integers(-3, 100))
    prev = draw(st.sampled_from([0, 0, t0, t0 + 1]) | st.integers(-5, 60))
    t, rows = [], []
    for _ in range(n):
        x, y, p = draw(_valid)
        step = draw(st.sampled_from([0, 1]) | st.integers(0, 40))
        fault = draw(_fault)
        if fault == "t":
            step = -draw(st.integers(1, 3))
        elif fault == "x":
            x = draw(_past["x"])
        elif fault == "y":
            y = draw(_past["y"])
        elif fault == "p":
            p = draw(_past["p"])
        t.append((t[-1] if t else t0) + step)
        rows.append((x, y, p))
    a = np.array(rows, np.int64).reshape(-1, 3)
    return np.array(t, np.int64), a[:, 0].astype(np.uint16), a[:, 1].astype(np.uint16), a[:, 2].astype(np.uint8), prev


def _boundary(t=(0, 1, 1), x=(2047, 0, 5), y=(0, 2047, 5), p=(1, 0, 1), prev=0):
    return (np.array(t, np.int64), np.array(x, np.uint16), np.array(y, np.uint16), np.array(p, np.uint8), prev)


# every limit on its own, right at it and right past it (hypothesis runs these first, every time)
BOUNDARY_CASES = [
    _boundary(), _boundary(x=(2047, 2048, 0)), _boundary(y=(0, 2047, 2048)), _boundary(p=(1, 2, 0)),
    _boundary(t=(3, 2, 4)), _boundary(prev=1), _boundary(x=(0xFFFF, 0, 0)), _boundary(t=(-1, 0, 0), prev=-1),
]


def with_boundary_examples(f):
    """Hypothesis runs every BOUNDARY_CASES entry first, every time."""
    for case in BOUNDARY_CASES:
        f = example(case)(f)
    return f


def assert_events_equal(got, want):
    for name, g, w in zip("txyp", got, want):
        assert g.dtype == w.dtype, name
        np.testing.assert_array_equal(g, w, err_msg=name)


def check_kernel_agrees_with_reference(codec, ev):
    """`codec._check_kernel` against `reference_check`; and a fresh `codec.encode` refuses exactly that event
    (or round-trips through `codec.decode` when every event is valid)."""
    t, x, y, p, prev = ev
    want = reference_check(t, x, y, p, prev)
    assert codec._check_kernel(t, x, y, p, np.int64(prev)) == want
    if prev == 0 and len(t):  # a fresh encoder's `prev`: the public path names the same event
        if want < 0:
            assert_events_equal(codec.decode(codec.encode(t, x, y, p)), (t, x, y, p))
        else:
            with pytest.raises(ValueError, match=f"event {want} "):
                codec.encode(t, x, y, p)


def packet_room(t, a: int, b: int, high: int) -> int:
    """Packet a:b's worst case in words, as `PacketEncoder.encode_many` sizes its buffer: the opening
    TIME_HIGH, 4 words an event, the TIME_HIGH steps from where the clock stands (5 words a wrap, one
    more wrap's worth, the steps of at most 2047 and 2)."""
    h = int(t[a]) >> 12 if high < 0 else high
    t_last = int(t[b - 1])
    return 1 + 4 * (b - a) + 5 * ((t_last >> 24) - (h >> 12) + 1) + ((t_last >> 12) - h) // 2047 + 2
