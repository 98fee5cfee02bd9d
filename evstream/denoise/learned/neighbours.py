"""The 8-neighbour pass of the learned features as one vector operation (an LLVM intrinsic).

For an event at padded map index `centre` with tick `tick` and polarity `pi`, over the 8 neighbours'
words (features.py: bits 0-31 (tick << 1) | polarity, bits 56-62 active DC bins) it counts those whose
last event is within 125 ticks (any polarity), within 625 and 3125 ticks with the same polarity, and
sums their DC counts. The 8 words come from three unaligned loads of 4 words (the rows above and below
from column -1, the event's row from column -1: its lanes 0 and 2), shuffled into one vector of 8
int64 lanes; the tests are vector compares whose masks are counted with a popcount.

Why: as 8 scalar reads with ~14 integer operations each this pass was 35-45 of the kernel's ~53 ns per
event; as one vector pass (AVX-512 on this machine: about 15 instructions) it costs a few ns. LLVM
lowers the same IR on any x86-64 (narrower vectors), so the result does not depend on the CPU; only
the speed does. `reference_nb8` is the plain-Python definition the tests compare it with.

The loads read 2 words past the event's right neighbour: the map's padding (2 columns each side)
keeps them inside the event's padded row.
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

SUPPORT_TICKS = (125, 625, 3125)  # nb8 any polarity within 2 ms; same polarity within 10 ms, 50 ms
FIELD_BITS = 16  # the packed result: s2 | s10 << 16 | s50 << 32 | dc_nb << 48


@intrinsic
def nb8_support(typingctx, word, centre, wp, tick, pi):
    """s2 | s10 << 16 | s50 << 32 | dc_nb << 48 over the 8 neighbours of `word[centre]` in a map of
    padded width `wp` (module docstring). `word` must be a C-contiguous int64 array."""
    if not (isinstance(word, types.Array) and word.layout == "C" and word.dtype == types.int64):
        return None
    sig = types.int64(word, types.intp, types.intp, types.int64, types.int64)

    def codegen(context, builder, signature, args):
        ary, c, w, tk, p = args
        data = context.make_array(signature.args[0])(context, builder, ary).data
        i32, i64 = ir.IntType(32), ir.IntType(64)
        v4, v8 = ir.VectorType(i64, 4), ir.VectorType(i64, 8)
        one = ir.Constant(c.type, 1)

        def load4(pos):  # word[pos : pos + 4], unaligned
            ptr = builder.bitcast(builder.gep(data, [pos]), v4.as_pointer())
            return builder.load(ptr, align=8)

        def lanes(*idx):
            return ir.Constant(ir.VectorType(i32, len(idx)), list(idx))

        up = load4(builder.sub(builder.sub(c, w), one))
        down = load4(builder.sub(builder.add(c, w), one))
        mid = load4(builder.sub(c, one))  # lanes 0 and 2: the left and right neighbours
        rows = builder.shuffle_vector(up, down, lanes(0, 1, 2, 4, 5, 6, 0, 0))
        mid8 = builder.shuffle_vector(mid, mid, lanes(0, 1, 2, 3, 0, 1, 2, 3))
        v = builder.shuffle_vector(rows, mid8, lanes(0, 1, 2, 3, 4, 5, 8, 10))

        def splat(value):
            if isinstance(value, int):
                return ir.Constant(v8, [value] * 8)
            undef = ir.Constant(v8, ir.Undefined)
            first = builder.insert_element(undef, value, ir.Constant(i32, 0))
            return builder.shuffle_vector(first, undef, lanes(*[0] * 8))

        tf = builder.and_(v, splat(0xFFFFFFFF))
        age = builder.sub(splat(tk), builder.lshr(tf, splat(1)))
        same = builder.icmp_unsigned("==", builder.and_(builder.xor(tf, splat(p)), splat(1)), splat(0))
        i8 = ir.IntType(8)
        popcount = builder.module.declare_intrinsic("llvm.ctpop", [i8])

        def count(mask):  # lanes set in an 8-lane mask
            return builder.zext(builder.call(popcount, [builder.bitcast(mask, i8)]), i64)

        def within(ticks):
            return builder.icmp_signed("<", age, splat(ticks))

        s2 = count(within(SUPPORT_TICKS[0]))
        s10 = count(builder.and_(within(SUPPORT_TICKS[1]), same))
        s50 = count(builder.and_(within(SUPPORT_TICKS[2]), same))
        reduce_add = cgutils.get_or_insert_function(builder.module, ir.FunctionType(i64, [v8]),
                                                    "llvm.vector.reduce.add.v8i64")
        dc = builder.call(reduce_add, [builder.lshr(v, splat(56))])
        out = builder.or_(s2, builder.shl(s10, ir.Constant(i64, FIELD_BITS)))
        out = builder.or_(out, builder.shl(s50, ir.Constant(i64, 2 * FIELD_BITS)))
        return builder.or_(out, builder.shl(dc, ir.Constant(i64, 3 * FIELD_BITS)))

    return sig, codegen


def reference_nb8(word, centre: int, wp: int, tick: int, pi: int) -> int:
    """`nb8_support` in plain Python, neighbour by neighbour."""
    s2 = s10 = s50 = dc = 0
    for q in (centre - wp - 1, centre - wp, centre - wp + 1, centre - 1, centre + 1,
              centre + wp - 1, centre + wp, centre + wp + 1):
        v = int(word[q])
        age = tick - ((v & 0xFFFFFFFF) >> 1)
        same = (v & 1) == pi
        s2 += age < SUPPORT_TICKS[0]
        s10 += age < SUPPORT_TICKS[1] and same
        s50 += age < SUPPORT_TICKS[2] and same
        dc += v >> 56
    return s2 | s10 << FIELD_BITS | s50 << 2 * FIELD_BITS | dc << 3 * FIELD_BITS
