"""Row-summed count maps: the vector row update and the column sum against plain numpy."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from evstream.denoise.rowsum import column_sum, lanes, padded_map, row_add, row_full
from evstream.jit import Kernel, njit  # numba's own njit cannot type the kernels inside until evstream.jit taught it


@njit
def _apply(a, pos, delta, L):
    for i in range(len(pos)):
        row_add(a, pos[i], delta[i], L)


@njit
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


if isinstance(column_sum, Kernel):  # compiled, as stages call it (tests/mutation.py runs it as plain Python)
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
