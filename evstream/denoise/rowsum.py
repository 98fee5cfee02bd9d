"""Row-summed count maps: exact L×L box counts in one vector update and L reads.

A map cell (row Y, column X) of a (H + 2r, W + 2r) padded map holds the count of events on row Y over
the L = 2r + 1 columns X - r .. X + r. An event at (x, y) adds to the L contiguous cells of padded row
y + r starting at column x (`row_add`); the L×L box count around (x, y) is the sum of L cells down
padded column x + r from row y (`column_sum`). Both the coarse (density) and the fine (DC) stage keep
their exact neighbourhood counts this way.

`row_add` does the L cells as one unaligned read-modify-write of a vector (on the density filter
this alone took 48 to 57 M events/s at 346×260) of the fewest cells, a power of two, that hold L (at
most 32 bytes; wider rows take several): 8 uint16 cells (16 bytes) for L = 5, not 16. A wider vector
reaches past the L cells into the next cache line more often, and over a map larger than the cache that
line is one more miss (32 bytes against 16 and 8 for the fine stage: cascade at 1280×720 1.6–1.8 ns per
event slower). The map must have one 32-byte vector's worth of cells after its last row (`padded_map`
adds them). `row_full` tests the same L cells against a limit in one vector compare: a map of narrow
cells (the coarse stage's uint8) widens before an add would pass its type's largest value.
"""

from __future__ import annotations

import numpy as np

from ..jit import intrinsic, njit
from ..nowrap import ix

VECTOR_BYTES = 32
MAX_RADIUS_PX = 32  # the widest neighbourhood a stage takes (L = 65): far past any of use, and a bounded map


def lanes(dtype) -> int:
    """Cells per vector update for a map of `dtype`."""
    return VECTOR_BYTES // np.dtype(dtype).itemsize


def padded_map(width: int, height: int, radius: int, dtype, planes: int = 1) -> np.ndarray:
    """A zeroed flat map of `planes` × (height + 2r) × (width + 2r) cells plus one vector of tail."""
    return np.zeros(planes * (height + 2 * radius) * (width + 2 * radius) + lanes(dtype), dtype)


def _vector_add(cells: int):
    """An intrinsic `add(a, pos, delta, n)`: a[pos : pos + n] += delta for n <= the vector's cells, as one
    unaligned load, add and store of a vector of `cells` cells (fewer if that passes VECTOR_BYTES)."""

    def add(typingctx, a, pos, delta, n):
        from llvmlite import ir  # typing time: numba is loaded (evstream.jit)
        from numba.core import types

        if not (isinstance(a, types.Array) and a.layout == "C" and isinstance(a.dtype, types.Integer)):
            return None
        dtype = a.dtype
        width = min(cells, VECTOR_BYTES // (dtype.bitwidth // 8))

        def codegen(context, builder, signature, args):
            ary, p, d, k = args
            data = context.make_array(signature.args[0])(context, builder, ary).data
            cell = context.get_value_type(dtype)
            vec = ir.VectorType(cell, width)
            ptr = builder.bitcast(builder.gep(data, [p]), vec.as_pointer())
            zero = ir.Constant(cell, 0)
            step = ir.Constant(vec, [0] * width)
            for lane in range(width):  # [delta] * n + [0] * (width - n); folds when n is a constant
                on = builder.icmp_signed(">", k, ir.Constant(k.type, lane))
                step = builder.insert_element(step, builder.select(on, d, zero), ir.Constant(ir.IntType(32), lane))
            builder.store(builder.add(builder.load(ptr, align=1), step), ptr, align=1)
            return context.get_dummy_value()

        return types.void(a, types.intp, dtype, types.intp), codegen

    add.__name__ = add.__qualname__ = f"_add_{cells}"
    return intrinsic(add)


_add_4, _add_8, _add_16, _add_32 = (_vector_add(c) for c in (4, 8, 16, 32))


def _vector_full(cells: int):
    """An intrinsic `full(a, pos, n, limit)`: whether one of a[pos : pos + n] (n <= the vector's cells) is
    >= limit, as one unaligned load, compare and mask test of a vector of `cells` cells (as `_vector_add`)."""

    def full(typingctx, a, pos, n, limit):
        from llvmlite import ir  # typing time: numba is loaded (evstream.jit)
        from numba.core import types

        if not (isinstance(a, types.Array) and a.layout == "C" and isinstance(a.dtype, types.Integer)):
            return None
        dtype = a.dtype
        width = min(cells, VECTOR_BYTES // (dtype.bitwidth // 8))

        def codegen(context, builder, signature, args):
            ary, p, k, top = args
            data = context.make_array(signature.args[0])(context, builder, ary).data
            cell = context.get_value_type(dtype)
            vec = ir.VectorType(cell, width)
            i32 = ir.IntType(32)
            cells_v = builder.load(builder.bitcast(builder.gep(data, [p]), vec.as_pointer()), align=1)
            one = builder.insert_element(ir.Constant(vec, ir.Undefined), builder.trunc(top, cell), ir.Constant(i32, 0))
            tops = builder.shuffle_vector(one, ir.Constant(vec, ir.Undefined), ir.Constant(ir.VectorType(i32, width),
                                                                                          [0] * width))
            at_top = builder.icmp_unsigned(">=", cells_v, tops) if not dtype.signed else \
                builder.icmp_signed(">=", cells_v, tops)
            lanes_in = ir.Constant(ir.VectorType(ir.IntType(1), width), [0] * width)
            for lane in range(width):  # lane < n; folds when n is a constant
                on = builder.icmp_signed(">", k, ir.Constant(k.type, lane))
                lanes_in = builder.insert_element(lanes_in, on, ir.Constant(i32, lane))
            hit = builder.bitcast(builder.and_(at_top, lanes_in), ir.IntType(width))
            return builder.icmp_unsigned("!=", hit, ir.Constant(ir.IntType(width), 0))

        return types.boolean(a, types.intp, types.intp, types.int64), codegen

    full.__name__ = full.__qualname__ = f"_full_{cells}"
    return intrinsic(full)


_full_4, _full_8, _full_16, _full_32 = (_vector_full(c) for c in (4, 8, 16, 32))


@intrinsic
def _lanes_of(typingctx, a):
    """Cells per VECTOR_BYTES vector of `a`'s dtype, as a compile-time constant (`a.itemsize` is read at run time)."""
    from numba.core import types

    width = VECTOR_BYTES // (a.dtype.bitwidth // 8)

    def codegen(context, builder, signature, args):
        return context.get_constant(types.intp, width)

    return types.intp(a), codegen


def reference_add(a, pos, delta, n, cells):
    """`_vector_add(cells)`'s add in plain Python (its tests' reference; the plain twin tests/mutation.py
    runs in its place): the first n of the vector's lanes from pos, at most min(cells, VECTOR_BYTES //
    itemsize), gain delta, wrapping like the cells."""
    m = max(0, min(n, cells, lanes(a.dtype)))
    a[pos : pos + m] = (a[pos : pos + m].astype(np.int64) + int(delta)).astype(a.dtype)


def reference_full(a, pos, n, limit, cells):
    """`_vector_full(cells)`'s test in plain Python (as `reference_add`): whether one of the first n lanes
    from pos is >= limit, the limit taken as a cell (truncated to the cells' type) and compared in it."""
    m = max(0, min(n, cells, lanes(a.dtype)))
    return bool((a[pos : pos + m] >= np.array(limit).astype(a.dtype)).any())


@njit(cache=True, nogil=True, inline="always")
def row_add(a, pos, delta, L):
    """a[pos : pos + L] += delta, in vectors of the fewest cells, a power of two, that hold L (at most
    VECTOR_BYTES each; `a` needs one such vector of cells after pos + L). The tests on L fold away when L is
    a compile-time constant, as in the stages' kernels."""
    width = _lanes_of(a)
    if L <= width:
        if L <= 4:
            _add_4(a, pos, delta, L)
        elif L <= 8:
            _add_8(a, pos, delta, L)
        elif L <= 16:
            _add_16(a, pos, delta, L)
        else:
            _add_32(a, pos, delta, L)
    else:
        for k in range(0, L, width):
            _add_32(a, pos + k, delta, min(width, L - k))


@njit(cache=True, nogil=True, inline="always")
def row_full(a, pos, L, limit):
    """Whether one of a[pos : pos + L] is >= limit (its vectors as `row_add`'s)."""
    width = _lanes_of(a)
    if L <= width:
        if L <= 4:
            return _full_4(a, pos, L, limit)
        if L <= 8:
            return _full_8(a, pos, L, limit)
        if L <= 16:
            return _full_16(a, pos, L, limit)
        return _full_32(a, pos, L, limit)
    hit = False
    for k in range(0, L, width):
        hit |= _full_32(a, pos + k, min(width, L - k), limit)
    return hit


@njit(cache=True, nogil=True, inline="always")
def box_area(x, y, radius, width, height):
    """Pixels of the (2r + 1)² box around (x, y) that lie on the width × height sensor."""
    return ((min(x + radius, width - 1) - max(x - radius, 0) + 1)
            * (min(y + radius, height - 1) - max(y - radius, 0) + 1))


@njit(cache=True, nogil=True, inline="always")
def column_sum(a, q, stride, L):
    """a[q] + a[q + stride] + ... (L cells down a column), as int64."""
    total = np.int64(0)
    for k in range(L):
        total += a[ix(q + k * stride)]
    return total
