"""The Rerun sink's kernels (sinks/rerun_sink.py) against the numpy formulations they replaced, compiled
and as plain Python, on random sorted streams: the points grouped by class and time bin, and the class
counts per statistics bin."""

from __future__ import annotations

import numpy as np
from evstream.sinks.rerun_sink import class_counts_per_bin, points_by_class
from hypothesis import given, settings
from hypothesis import strategies as st

N = 3


def _stream(seed, n, span_digits, n_classes):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, 10**span_digits, n)).astype(np.int64) + int(rng.integers(-10**6, 10**6))
    x = rng.integers(0, 65535, n).astype(np.uint16)
    y = rng.integers(0, 65535, n).astype(np.uint16)
    cls = rng.integers(0, n_classes, n).astype(np.uint8)
    return t, x, y, cls


def points_reference(t, x, y, cls, origin_us, bin_us, scale):
    """As `_log_points` computed it with numpy masks: per class (points, row lengths, row ends), and the
    slab's row ends."""
    rel = t - origin_us
    bins = rel // bin_us
    change = np.flatnonzero(np.diff(bins)) + 1
    slab_us = rel[np.append(change, len(t)) - 1]
    pos = np.empty((len(t), 3), np.float32)
    pos[:, 0], pos[:, 1], pos[:, 2] = x, y, rel * -scale
    per_class = []
    for c in range(N):
        sel = np.flatnonzero(cls == c)
        cut = np.flatnonzero(np.diff(bins[sel])) + 1
        lengths = np.diff(np.concatenate(([0], cut, [len(sel)]))) if len(sel) else np.zeros(0, np.int64)
        last = np.append(cut, len(sel)) - 1 if len(sel) else np.zeros(0, np.int64)
        per_class.append((pos[sel], lengths, rel[sel][last]))
    return per_class, slab_us


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 3000), span_digits=st.integers(1, 8),
       n_classes=st.sampled_from([1, 3, 4]), bin_us=st.integers(1, 5000), scale=st.floats(1e-6, 1e-1),
       origin_us=st.integers(-10**6, 10**6))
def test_points_by_class_matches_the_numpy_masks(seed, n, span_digits, n_classes, bin_us, scale, origin_us):
    """Class 3 (none of the sink's) is left out by both. (The sink logs no empty batch.)"""
    t, x, y, cls = _stream(seed, n, span_digits, n_classes)
    want, want_slab = points_reference(t, x, y, cls, origin_us, bin_us, scale)
    for kernel in (points_by_class, points_by_class.py_func):
        pos, count, n_rows, row_len, row_us, slab_us = kernel(t, x, y, cls, origin_us, bin_us, scale, N)
        assert np.array_equal(slab_us, want_slab)
        start = 0
        for c, (points, lengths, ends) in enumerate(want):
            assert np.array_equal(pos[start:start + count[c]], points)
            assert np.array_equal(row_len[c, :n_rows[c]], lengths)
            assert np.array_equal(row_us[c, :n_rows[c]], ends)
            start += count[c]
        assert start == len(pos)


def counts_reference(t, cls, t0, bin_us, open_bin):
    """As `StatsBins.push` computed it: the distinct bins (local to the open one) and a bincount."""
    local = (t - t0) // bin_us - open_bin
    step = np.flatnonzero(np.diff(local)) + 1
    bins = local[np.concatenate(([0], step))]
    which = np.zeros(len(local), np.int64)
    which[step] = 1
    which = np.cumsum(which)
    return bins, np.bincount(which * N + cls, minlength=len(bins) * N).reshape(len(bins), N)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 3000), span_digits=st.integers(1, 8),
       bin_us=st.integers(1, 20_000), open_bin=st.integers(-3, 3))
def test_class_counts_per_bin_matches_a_bincount(seed, n, span_digits, bin_us, open_bin):
    t, _, _, cls = _stream(seed, n, span_digits, N)
    t0 = int(t[0]) - int(np.random.default_rng(seed).integers(0, 5000))
    want = counts_reference(t, cls, t0, bin_us, open_bin)
    for kernel in (class_counts_per_bin, class_counts_per_bin.py_func):
        bins, per = kernel(t, cls, t0, bin_us, open_bin, N)
        assert np.array_equal(bins, want[0]) and np.array_equal(per, want[1])


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_rows=st.integers(0, 30), with_ids=st.booleans())
def test_columns_are_what_points3d_columns_partitioned_builds(seed, n_rows, with_ids):
    """`_columns` (one partition by offsets) sends the same columns as `rr.Points3D.columns(...).partition`:
    the same component descriptors, the same Arrow list arrays (rows of the given lengths)."""
    import rerun as rr
    from evstream.sinks.rerun_sink import _columns

    rng = np.random.default_rng(seed)
    lengths = rng.integers(0, 50, n_rows)
    n = int(lengths.sum())
    fields = {"positions": rng.random((n, 3), np.float32) * 300}
    if with_ids:
        fields["class_ids"] = rng.integers(0, N, n).astype(np.uint8)
    ours = _columns(rr.Points3D, lengths, **fields)
    theirs = list(rr.Points3D.columns(**fields).partition(lengths))
    assert [c.component_descriptor() for c in ours] == [c.component_descriptor() for c in theirs]
    assert len(ours) == (2 if with_ids else 1)
    for a, b in zip(ours, theirs):
        assert a.as_arrow_array().equals(b.as_arrow_array())
        assert len(a.as_arrow_array()) == n_rows
