"""The neighbourhood reads of the learned features as one vector operation (an LLVM intrinsic).

For an event at padded map index `centre` with tick `tick`, polarity `pi` and DC bin `b` (modulo 256),
from the 8 neighbours' words (features.py: bits 0-31 (tick << 1) | polarity, bits 48-55 the pixel's
last active bin modulo 256) and activity bitmaps (`bins`: bit k set if the pixel was active in bin
last - k), it counts the neighbours whose last event is within 125 ticks (any polarity), within 625 and
3125 ticks with the same polarity, and sums their DC components: the bins among b - 63 .. b in which
each was active (its bitmap shifted by b - last; a pixel idle for 1 s or more (62500 ticks) has none,
which also keeps the modulo-256 difference exact). The same for the event's own pixel: DC_own, and its
bitmap as of bin b (the caller sets bit 0 and stores it back).

The 8 words come from three unaligned loads of 4 words (the rows above and below from column -1, the
event's row from column -1: lanes 0 and 2, lane 1 is the pixel itself), likewise the bitmaps, shuffled
into vectors of 8 int64 lanes; the tests are vector compares counted with a popcount of the mask, the
DC components a vector popcount and a sum.

Why: as 8 scalar reads with ~14 integer operations each this pass was 35-45 of the kernel's ~53 ns per
event, and the DC counts needed a FIFO of activations expired bin by bin; as one vector pass (AVX-512
on this machine) it costs a few ns. LLVM lowers the same IR on any x86-64 (narrower vectors), so the
result does not depend on the CPU, only the speed does. `reference_nb8` is the plain-Python
definition the tests compare it with.

The loads read 2 words past the event's right neighbour: the maps' padding (2 columns each side) keeps
them inside the event's padded row.
"""

from __future__ import annotations

from ...jit import intrinsic

SUPPORT_TICKS = (125, 625, 3125)  # nb8 any polarity within 2 ms; same polarity within 10 ms, 50 ms
DC_IDLE_TICKS = 62_500            # 1 s: a pixel idle this long has no active bin among the last 64
FIELD_BITS = 12  # the packed result: s2 | s10 << 12 | s50 << 24 | dc_nb << 36 | dc_own << 48


@intrinsic
def nb8_support(typingctx, word, bins, centre, wp, tick, pi, b8):
    """(s2 | s10 << 12 | s50 << 24 | dc_nb << 36 | dc_own << 48, the pixel's bitmap as of bin b) for
    the pixel `word[centre]` of maps of padded width `wp` (module docstring). `word` and `bins` must
    be C-contiguous int64 arrays of the same shape."""
    from llvmlite import ir  # typing time: numba is loaded (evstream.jit)
    from numba import types
    from numba.core import cgutils

    for a in (word, bins):
        if not (isinstance(a, types.Array) and a.layout == "C" and a.dtype == types.int64):
            return None
    sig = types.UniTuple(types.int64, 2)(word, bins, types.intp, types.intp, types.int64, types.int64,
                                         types.int64)

    def codegen(context, builder, signature, args):
        w_ary, b_ary, c, w, tk, p, bin8 = args
        w_data = context.make_array(signature.args[0])(context, builder, w_ary).data
        b_data = context.make_array(signature.args[1])(context, builder, b_ary).data
        i8, i32, i64 = ir.IntType(8), ir.IntType(32), ir.IntType(64)
        v4, v8 = ir.VectorType(i64, 4), ir.VectorType(i64, 8)
        one = ir.Constant(c.type, 1)
        starts = (builder.sub(builder.sub(c, w), one), builder.sub(builder.add(c, w), one), builder.sub(c, one))

        def lanes(*idx):
            return ir.Constant(ir.VectorType(i32, len(idx)), list(idx))

        def gather(data):  # (the 8 neighbours as one vector, the pixel itself)
            up, down, mid = (builder.load(builder.bitcast(builder.gep(data, [s]), v4.as_pointer()), align=8)
                             for s in starts)
            rows = builder.shuffle_vector(up, down, lanes(0, 1, 2, 4, 5, 6, 0, 0))
            mid8 = builder.shuffle_vector(mid, mid, lanes(0, 1, 2, 3, 0, 1, 2, 3))
            return (builder.shuffle_vector(rows, mid8, lanes(0, 1, 2, 3, 4, 5, 8, 10)),
                    builder.extract_element(mid, ir.Constant(i32, 1)))

        v, v_own = gather(w_data)
        bm, bm_own = gather(b_data)

        def splat(value):
            if isinstance(value, int):
                return ir.Constant(v8, [value] * 8)
            undef = ir.Constant(v8, ir.Undefined)
            first = builder.insert_element(undef, value, ir.Constant(i32, 0))
            return builder.shuffle_vector(first, undef, lanes(*[0] * 8))

        def const(value, vec):
            return splat(value) if vec else ir.Constant(i64, value)

        def age_of(x, vec):  # ticks since the pixel's last event
            tick = splat(tk) if vec else tk
            return builder.sub(tick, builder.lshr(builder.and_(x, const(0xFFFFFFFF, vec)), const(1, vec)))

        def dc_bitmap(x, bits, age, vec):  # the bitmap as of bin b: bit j = active in bin b - j
            shift = builder.and_(builder.sub(splat(bin8) if vec else bin8,
                                             builder.and_(builder.lshr(x, const(48, vec)), const(0xFF, vec))),
                                 const(0xFF, vec))
            ok = builder.and_(builder.icmp_unsigned("<", shift, const(64, vec)),
                              builder.icmp_signed("<", age, const(DC_IDLE_TICKS, vec)))
            moved = builder.shl(bits, builder.and_(shift, const(63, vec)))
            return builder.select(ok, moved, const(0, vec))

        age = age_of(v, True)
        same = builder.icmp_unsigned("==", builder.and_(builder.xor(v, splat(p)), splat(1)), splat(0))
        popcount8 = builder.module.declare_intrinsic("llvm.ctpop", [i8])

        def count(mask):  # lanes set in an 8-lane mask
            return builder.zext(builder.call(popcount8, [builder.bitcast(mask, i8)]), i64)

        def within(ticks):
            return builder.icmp_signed("<", age, splat(ticks))

        s2 = count(within(SUPPORT_TICKS[0]))
        s10 = count(builder.and_(within(SUPPORT_TICKS[1]), same))
        s50 = count(builder.and_(within(SUPPORT_TICKS[2]), same))
        popcount_v = cgutils.get_or_insert_function(builder.module, ir.FunctionType(v8, [v8]), "llvm.ctpop.v8i64")
        reduce_add = cgutils.get_or_insert_function(builder.module, ir.FunctionType(i64, [v8]),
                                                    "llvm.vector.reduce.add.v8i64")
        dc_nb = builder.call(reduce_add, [builder.call(popcount_v, [dc_bitmap(v, bm, age, True)])])
        own = dc_bitmap(v_own, bm_own, age_of(v_own, False), False)
        dc_own = builder.call(builder.module.declare_intrinsic("llvm.ctpop", [i64]), [own])
        out = s2
        for k, field in enumerate((s10, s50, dc_nb, dc_own), 1):
            out = builder.or_(out, builder.shl(field, ir.Constant(i64, k * FIELD_BITS)))
        return context.make_tuple(builder, signature.return_type, [out, own])

    return sig, codegen


def reference_nb8(word, bins, centre: int, wp: int, tick: int, pi: int, b8: int) -> tuple[int, int]:
    """`nb8_support` in plain Python, pixel by pixel."""

    def bitmap(q):  # active bins b - 63 .. b of pixel q, as bits 0 .. 63
        v = int(word[q])
        shift = (b8 - ((v >> 48) & 0xFF)) % 256
        idle = tick - ((v & 0xFFFFFFFF) >> 1) >= DC_IDLE_TICKS
        return 0 if idle or shift >= 64 else (int(bins[q]) << shift) & (2**64 - 1)

    s2 = s10 = s50 = dc = 0
    for q in (centre - wp - 1, centre - wp, centre - wp + 1, centre - 1, centre + 1,
              centre + wp - 1, centre + wp, centre + wp + 1):
        v = int(word[q])
        age = tick - ((v & 0xFFFFFFFF) >> 1)
        same = (v & 1) == pi
        s2 += age < SUPPORT_TICKS[0]
        s10 += age < SUPPORT_TICKS[1] and same
        s50 += age < SUPPORT_TICKS[2] and same
        dc += bin(bitmap(q)).count("1")
    own = bitmap(centre)
    packed = s2 | s10 << FIELD_BITS | s50 << 2 * FIELD_BITS | dc << 3 * FIELD_BITS
    return packed | bin(own).count("1") << 4 * FIELD_BITS, own - (1 << 64 if own >= 1 << 63 else 0)
