import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from evstream.events import EventChunk, EventError, Geometry, NoiseClass, Validator, concat
from evstream.testing import random_stream

G = Geometry(8, 6)


def chunk(t, x=None, y=None, p=None, **kw):
    n = len(t)
    return EventChunk.from_arrays(t, x if x is not None else [0] * n, y if y is not None else [0] * n,
                                  p if p is not None else [1] * n, G, **kw)


def test_dtypes_and_default_watermark():
    c = chunk([1, 2, 5])
    assert (c.t.dtype, c.x.dtype, c.y.dtype, c.p.dtype) == (np.int64, np.uint16, np.uint16, np.uint8)
    assert c.t_end == 5 and len(c) == 3 and c.cls is None


def test_mismatched_lengths_rejected():
    with pytest.raises(EventError, match="'x' has 2 entries"):
        EventChunk.from_arrays([1, 2, 3], [0, 0], [0, 0, 0], [0, 0, 0], G)


def test_slice_takes_next_timestamp_as_watermark_and_select_keeps_it():
    c = chunk([1, 2, 5, 9], t_end=12)
    assert c[0:2].t_end == 5
    assert c[2:].t_end == 12
    assert c[np.array([True, False, True, False])].t_end == 12
    with pytest.raises(IndexError):
        c[1]


@given(st.integers(0, 10_000), st.integers(0, 200))
def test_structured_round_trip(seed, n):
    s = random_stream(seed, n, G).replace(cls=np.zeros(n, np.uint8))
    back = EventChunk.from_structured(s.to_structured(), G, t_end=s.t_end)
    for f in ("t", "x", "y", "p", "cls", "label"):
        assert np.array_equal(getattr(back, f), getattr(s, f))
        assert getattr(back, f).dtype == getattr(s, f).dtype


@given(st.integers(0, 10_000), st.integers(0, 300), st.lists(st.integers(0, 300), max_size=5))
def test_concat_of_slices_is_identity(seed, n, cuts):
    s = random_stream(seed, n, G)
    bounds = sorted({0, n, *[min(c, n) for c in cuts]})
    back = concat([s[a:b] for a, b in zip(bounds[:-1], bounds[1:])], G)
    assert np.array_equal(back.t, s.t)
    if n:
        assert np.array_equal(back.label, s.label) and back.t_end == s.t_end


def test_concat_drops_optional_field_missing_somewhere():
    a = chunk([1], label=[0])
    b = chunk([2])
    assert concat([a, b]).label is None


def test_validator_names_file_and_offset_for_bad_coordinates():
    v = Validator(G, "rec.raw")
    v(chunk([1, 2]))
    with pytest.raises(EventError, match=r"rec.raw: event 3: \(8, 0\) outside the 8x6 sensor"):
        v(chunk([3, 4], x=[0, 8]))


def test_validator_policies_for_time_going_back():
    with pytest.raises(EventError, match="event 2: timestamp 3 µs goes back from 5"):
        Validator(G, "f")(chunk([1, 5, 3]))
    v = Validator(G, "f", "drop")
    out = v(chunk([1, 5, 3, 6]))
    assert out.t.tolist() == [1, 5, 6] and v.dropped == 1
    v = Validator(G, "f", "sort")
    assert v(chunk([1, 5, 3, 6])).t.tolist() == [1, 3, 5, 6]
    assert v(chunk([2, 7])).t.tolist() == [7] and v.dropped == 1  # across chunks: dropped, counted


def test_validator_rejects_polarity_out_of_range():
    with pytest.raises(EventError, match="polarity 2"):
        Validator(G, "f")(chunk([1], p=[2]))


def test_geometry_checks():
    with pytest.raises(ValueError):
        Geometry(0, 5)
    assert Geometry(346, 260).n_pixels == 89960


def test_class_counts():
    c = chunk([1, 2, 3], label=[0, 2, 2])
    assert c.class_counts("label").tolist() == [1, 0, 2]
    assert c.class_counts("cls") is None
    assert NoiseClass.HOT_PIXEL == 2


@given(seed=st.integers(0, 2**32), n=st.integers(0, 400), labelled=st.booleans())
def test_of_class_matches_a_boolean_mask(seed, n, labelled):
    s = random_stream(seed, n)
    cls = np.random.default_rng(seed).integers(0, 3, n).astype(np.uint8)
    s = s.replace(cls=cls, label=s.label if labelled else None)
    for c in NoiseClass:
        got, want = s.of_class(c), s[cls == c]
        for f in ("t", "x", "y", "p", "cls", "label"):
            a, b = getattr(got, f), getattr(want, f)
            assert (a is None and b is None) or np.array_equal(a, b), f
            assert a is None or a.dtype == getattr(s, f).dtype
        assert got.t_end == s.t_end and got.geometry == s.geometry
    unclassified = s.replace(cls=None)
    assert unclassified.of_class(NoiseClass.SIGNAL) is unclassified and len(unclassified.of_class(2)) == 0


def first_invalid_reference(t, x, y, p, width, height, last_t):
    """Plain Python: the first event outside the sensor or with polarity > 1, and the first going back in t
    (before that event); -1 where none."""
    back = -1
    for i in range(len(t)):
        if x[i] >= width or y[i] >= height or p[i] > 1:
            return i, back
        if back < 0 and t[i] < (t[i - 1] if i else last_t):
            back = i
    return -1, back


@given(seed=st.integers(0, 2**32), n=st.integers(0, 60), last_t=st.integers(-5, 40))
def test_first_invalid_kernel_matches_reference(seed, n, last_t):
    from evstream.events import _first_invalid

    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, 50, n)).astype(np.int64)
    t[rng.random(n) < 0.05] = rng.integers(0, 50)  # a few steps back
    x = rng.integers(0, 9, n).astype(np.uint16)  # 8 is outside the 8x6 sensor
    y = rng.integers(0, 6 + (rng.random() < 0.3), n).astype(np.uint16)
    p = (rng.random(n) < 0.5).astype(np.uint8) + (rng.random(n) < 0.02).astype(np.uint8) * 2
    x[rng.random(n) < 0.9] %= 8  # most inside
    got = _first_invalid(t, x, y, p, 8, 6, last_t)
    assert tuple(got) == first_invalid_reference(t, x, y, p, 8, 6, last_t)


def test_with_classes_is_replace_without_the_field_checks():
    s = random_stream(4, 50, G).replace(label=np.ones(50, np.uint8))
    codes = (np.arange(50) % 3).astype(np.uint8)
    fast, slow = s.with_classes(codes), s.replace(cls=codes)
    for name in ("t", "x", "y", "p", "cls", "label", "geometry", "t_end"):
        assert getattr(fast, name) is getattr(slow, name) or getattr(fast, name) == getattr(slow, name)
    assert s.cls is None  # the original is untouched
    for bad in (codes.astype(np.int64), codes[:-1], codes.reshape(5, 10)):
        with pytest.raises(EventError):
            s.with_classes(bad)
