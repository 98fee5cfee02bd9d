"""Row-summed count maps: the vector row update and the column sum against plain numpy."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from evstream.denoise.rowsum import (
    _add_4,
    _add_8,
    _add_16,
    _add_32,
    _full_4,
    _full_8,
    _full_16,
    _full_32,
    column_sum,
    lanes,
    padded_map,
    reference_add,
    reference_full,
    row_add,
    row_full,
)
from evstream.jit import Kernel, njit  # numba's own njit cannot type the kernels inside until evstream.jit taught it


def _apply(a, pos, delta, L):
    for i in range(len(pos)):
        row_add(a, pos[i], delta[i], L)


def _full(a, pos, L, limit):
    out = np.empty(len(pos), np.bool_)
    for i in range(len(pos)):
        out[i] = row_full(a, pos[i], L, limit)
    return out


def _columns(a, q, stride, L):
    out = np.empty(len(q), np.int64)
    for i in range(len(q)):
        out[i] = column_sum(a, q[i], stride, L)
    return out


def _vector_ops(a, pos, delta, n, limit, out):
    """Each vector add, then each vector test, of the four widths at `pos` (into `out`)."""
    _add_4(a, pos, delta, n)
    _add_8(a, pos + 1, delta, n)
    _add_16(a, pos + 2, delta, n)
    _add_32(a, pos + 3, delta, n)
    out[0] = _full_4(a, pos, n, limit)
    out[1] = _full_8(a, pos, n, limit)
    out[2] = _full_16(a, pos, n, limit)
    out[3] = _full_32(a, pos, n, limit)


def _reference_ops(a, pos, delta, n, limit, out):
    for k, cells in enumerate((4, 8, 16, 32)):
        reference_add(a, pos + k, delta, n, cells)
    for k, cells in enumerate((4, 8, 16, 32)):
        out[k] = reference_full(a, pos, n, limit, cells)


# compiled, as the stages call them (tests/mutation.py runs them as plain Python, the intrinsics by their twins)
if isinstance(row_add, Kernel):
    _apply, _full, _vector_ops = njit(_apply), njit(_full), njit(_vector_ops)
if isinstance(column_sum, Kernel):
    _columns = njit(_columns)


@pytest.mark.parametrize("dtype", [np.int32, np.uint16, np.uint8, np.int64])
@given(seed=st.integers(0, 2**32), L=st.sampled_from([1, 3, 5, 7, 8, 9, 16, 17, 33]))
def test_row_add_matches_a_slice_add(dtype, seed, L):
    rng = np.random.default_rng(seed)
    a = rng.integers(0, 50, 300 + L + lanes(dtype)).astype(dtype)
    ref = a.copy()
    pos, delta = rng.integers(0, 300, 200), rng.integers(-3, 4, 200)
    _apply(a, pos, delta, L)
    for p, d in zip(pos, delta):
        ref[p : p + L] += np.array(d).astype(dtype)  # wraps like the map's cells
    assert np.array_equal(a, ref)  # includes the padding: the lanes past L are left alone


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.int32, np.int64])
@given(seed=st.integers(0, 2**32), L=st.sampled_from([1, 3, 5, 7, 8, 9, 16, 17, 33]), top=st.booleans())
def test_row_full_matches_a_slice_test(dtype, seed, L, top):
    """Whether one of the L cells is >= the limit (the type's largest value when `top`, as the density stage
    asks): the lanes past L (set to the limit here) are not looked at."""
    rng = np.random.default_rng(seed)
    limit = int(np.iinfo(dtype).max) if top else int(rng.integers(1, 6))
    a = np.where(rng.random(300 + L + lanes(dtype)) < 0.02, limit, rng.integers(0, limit, 300 + L + lanes(dtype)))
    a = a.astype(dtype)
    pos = rng.integers(0, 300, 200)
    a[pos[:20] + L] = limit  # the cell just past the row
    expected = [bool((a[p : p + L] >= limit).any()) for p in pos]
    assert _full(a, pos, L, limit).tolist() == expected


@given(seed=st.integers(0, 2**32), L=st.sampled_from([1, 3, 5, 9]))
def test_column_sum_and_the_padded_map(seed, L):
    rng = np.random.default_rng(seed)
    r, w, h = L // 2, 11, 7
    a = padded_map(w, h, r, np.int32, planes=2)
    assert len(a) == 2 * (h + 2 * r) * (w + 2 * r) + lanes(np.int32) and not a.any()
    stride = w + 2 * r
    a[: -lanes(np.int32)] = rng.integers(0, 9, len(a) - lanes(np.int32))
    q = rng.integers(0, (h + 2 * r - L + 1) * stride, 100)
    expected = [sum(int(a[k + j * stride]) for j in range(L)) for k in q]
    assert _columns(a, q, stride, L).tolist() == expected


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.int32, np.int64])
def test_the_vector_intrinsics_match_their_plain_twins(dtype):
    """`_add_N` and `_full_N` against `reference_add` / `reference_full` (the plain twins tests/mutation.py runs
    the kernels with): each width's lanes, the cells past them left alone, n from -1 to past 32, deltas that
    wrap the cells, limits below, at and past the type's largest value (taken as a cell)."""
    rng = np.random.default_rng(7)
    top = int(np.iinfo(dtype).max)
    for n in range(-1, 35):
        for _ in range(6):
            a = rng.integers(0, min(top, 1000) + 1, 100).astype(dtype)
            a[rng.random(100) < 0.1] = top
            pos, delta = int(rng.integers(0, 30)), int(rng.choice([-2, -1, 0, 1, 3]))
            past = top + 3 if top < 2**62 else top  # an int64 limit: the kernels pass one
            limit = int(rng.choice([1, 5, top, past, int(rng.integers(0, top + 1))]))
            got, want = a.copy(), a.copy()
            got_full, want_full = np.zeros(4, np.bool_), np.zeros(4, np.bool_)
            _vector_ops(got, pos, delta, n, limit, got_full)
            _reference_ops(want, pos, delta, n, limit, want_full)
            assert np.array_equal(got, want), (n, pos, delta)
            assert got_full.tolist() == want_full.tolist(), (n, pos, limit)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.int32, np.int64])
def test_each_vector_op_reaches_only_its_first_lanes(dtype):
    """Each width's add and test reach the first m = min(n, its cells, the vector's cells) cells from pos (none
    for n <= 0), as numpy slices say here: in the mutation run the intrinsics are their plain twins
    (tests/mutation.py), where the test above compares a twin with itself, so the twins meet a definition of
    their own (an add of one cell for n = 0, or of n cells past a narrow vector's, must fail)."""
    rng = np.random.default_rng(11)
    top = int(np.iinfo(dtype).max)
    for n in range(-1, 35):
        for _ in range(4):
            a = rng.integers(0, min(top, 1000) + 1, 100).astype(dtype)
            a[rng.random(100) < 0.1] = top
            pos, delta = int(rng.integers(0, 30)), int(rng.choice([-2, -1, 1, 3]))
            limit = int(rng.choice([1, 5, top, int(rng.integers(0, top + 1))]))
            got, want = a.copy(), a.copy()
            got_full, want_full = np.zeros(4, np.bool_), np.zeros(4, np.bool_)
            _vector_ops(got, pos, delta, n, limit, got_full)
            reach = [max(0, min(n, cells, lanes(dtype))) for cells in (4, 8, 16, 32)]
            for k, m in enumerate(reach):  # the adds, at pos, pos + 1, ...
                want[pos + k : pos + k + m] = (want[pos + k : pos + k + m].astype(np.int64) + delta).astype(dtype)
            for k, m in enumerate(reach):  # then the tests, all at pos
                want_full[k] = bool((want[pos : pos + m].astype(np.int64) >= limit).any())
            assert np.array_equal(got, want), (n, pos, delta)
            assert got_full.tolist() == want_full.tolist(), (n, pos, limit)
