"""The neighbourhood reads of the learned features as one vector operation (an LLVM intrinsic).

For an event at padded map index `centre` with tick `tick`, polarity `pi` and DC bin `b` (modulo 256),
from the per-pixel words (features.py: bits 0-23 (tick << 1) | polarity of its last event, 24-31 its
last active bin modulo 256, 32-47 its events in the last 20 ms, 48-63 the ON ones among them) and
activity bitmaps (`bins`: bit k set if the pixel was active in bin last - k), it counts the 8
neighbours whose last event is within 125 ticks (any polarity), within 625 and 3125 ticks with the
same polarity, and sums their DC components: the bins among b - 63 .. b in which each was active (its
bitmap shifted by b - last; a pixel idle for 1 s or more (62500 ticks) has none, which also keeps the
modulo-256 difference exact). The same for the event's own pixel: DC_own, and its bitmap as of bin b
(the caller sets bit 0 and stores it back). And the 5×5 box's 20 ms counts: all events and ON events.

The words come from five unaligned loads of 8 (the rows -2 .. +2, each from column -2): the box sums
the five rows' high halves (count | ON count << 16, as 32-bit lanes: a box holds far fewer than 65536
events in 20 ms) over columns -2 .. +2; the 8 neighbours are shuffled out of rows -1 .. +1 into one
vector of 8 int64 lanes. The bitmaps come from three loads of 4 (rows -1 .. +1 from column -1). The
tests are vector compares counted with a popcount of the mask, the DC components a vector popcount
and a sum.

Why: as 8 scalar reads with ~14 integer operations each this pass was 35-45 of the kernel's ~53 ns per
event, and the DC counts needed a FIFO of activations expired bin by bin; as one vector pass (AVX-512
on this machine) it costs a few ns. The box counts were a row-summed map (5 reads down a column, a
vector add on each event and each expiry, 4 bytes per pixel); in the words they cost 2 more row loads
and one vector sum, and an expiry updates one cell. LLVM lowers the same IR on any x86-64 (narrower
vectors), so the result does not depend on the CPU, only the speed does. `reference_nb8` is the
plain-Python definition the tests compare it with.

The word loads read up to 5 words past the box's last column: the map's padding (2 columns each side)
and `WORD_TAIL` words after its last row keep them inside the map.
"""

from __future__ import annotations

from ...jit import intrinsic

SUPPORT_TICKS = (125, 625, 3125)  # nb8 any polarity within 2 ms; same polarity within 10 ms, 50 ms
DC_IDLE_TICKS = 62_500            # 1 s: a pixel idle this long has no active bin among the last 64
FIELD_BITS = 12  # the packed result: s2 | s10 << 12 | s50 << 24 | dc_nb << 36 | dc_own << 48
TICK_MASK = 0xFFFFFF  # a word's bits 0-23: (tick << 1) | polarity
BIN_SHIFT = 24        # bits 24-31: the last active DC bin modulo 256
COUNT_SHIFT = 32      # bits 32-47: events in the last 20 ms; bits 48-63: the ON ones
WORD_TAIL = 8         # words after the map's last row (the row loads read past its end)


@intrinsic
def nb8_support(typingctx, word, bins, centre, wp, tick, pi, b8):
    """(s2 | s10 << 12 | s50 << 24 | dc_nb << 36 | dc_own << 48, the pixel's bitmap as of bin b, the
    box's count | ON count << 16) for the pixel `word[centre]` of maps of padded width `wp` (module
    docstring). `word` and `bins` must be C-contiguous int64 arrays of the same layout."""
    from llvmlite import ir  # typing time: numba is loaded (evstream.jit)
    from numba import types
    from numba.core import cgutils

    for a in (word, bins):
        if not (isinstance(a, types.Array) and a.layout == "C" and a.dtype == types.int64):
            return None
    sig = types.UniTuple(types.int64, 3)(word, bins, types.intp, types.intp, types.int64, types.int64,
                                         types.int64)

    def codegen(context, builder, signature, args):
        w_ary, b_ary, c, w, tk, p, bin8 = args
        w_data = context.make_array(signature.args[0])(context, builder, w_ary).data
        b_data = context.make_array(signature.args[1])(context, builder, b_ary).data
        i1, i8, i32, i64 = ir.IntType(1), ir.IntType(8), ir.IntType(32), ir.IntType(64)
        v4, v8, v16 = ir.VectorType(i64, 4), ir.VectorType(i64, 8), ir.VectorType(i32, 16)
        one, two = ir.Constant(c.type, 1), ir.Constant(c.type, 2)

        def lanes(*idx):
            return ir.Constant(ir.VectorType(i32, len(idx)), list(idx))

        def load(data, at, vec):
            return builder.load(builder.bitcast(builder.gep(data, [at]), vec.as_pointer()), align=8)

        # the words: rows -2 .. +2 from column -2 (lane 2 of row 0 is the pixel itself)
        w2 = builder.add(w, w)
        rows = [load(w_data, builder.sub(builder.add(c, off), two), v8)
                for off in (builder.neg(w2), builder.neg(w), ir.Constant(c.type, 0), w, w2)]
        box = builder.bitcast(rows[0], v16)
        for r in rows[1:]:
            box = builder.add(box, builder.bitcast(r, v16))
        box = builder.lshr(builder.bitcast(box, v8), ir.Constant(v8, [COUNT_SHIFT] * 8))
        box = builder.select(ir.Constant(ir.VectorType(i1, 8), [1] * 5 + [0] * 3), box, ir.Constant(v8, [0] * 8))
        reduce_add = cgutils.get_or_insert_function(builder.module, ir.FunctionType(i64, [v8]),
                                                    "llvm.vector.reduce.add.v8i64")
        box = builder.call(reduce_add, [box])
        rows_nb = builder.shuffle_vector(rows[1], rows[3], lanes(1, 2, 3, 9, 10, 11, 0, 0))
        v = builder.shuffle_vector(rows_nb, rows[2], lanes(0, 1, 2, 3, 4, 5, 9, 11))
        v_own = builder.extract_element(rows[2], ir.Constant(i32, 2))
        # the bitmaps: rows -1, +1 and 0 from column -1 (lane 1 of the last is the pixel itself)
        up, down, mid = (load(b_data, at, v4) for at in (builder.sub(builder.sub(c, w), one),
                                                         builder.sub(builder.add(c, w), one), builder.sub(c, one)))
        rows_b = builder.shuffle_vector(up, down, lanes(0, 1, 2, 4, 5, 6, 0, 0))
        mid8 = builder.shuffle_vector(mid, mid, lanes(0, 1, 2, 3, 0, 1, 2, 3))
        bm = builder.shuffle_vector(rows_b, mid8, lanes(0, 1, 2, 3, 4, 5, 8, 10))
        bm_own = builder.extract_element(mid, ir.Constant(i32, 1))

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
            return builder.sub(tick, builder.lshr(builder.and_(x, const(TICK_MASK, vec)), const(1, vec)))

        def dc_bitmap(x, bits, age, vec):  # the bitmap as of bin b: bit j = active in bin b - j
            last = builder.and_(builder.lshr(x, const(BIN_SHIFT, vec)), const(0xFF, vec))
            shift = builder.and_(builder.sub(splat(bin8) if vec else bin8, last), const(0xFF, vec))
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
        dc_nb = builder.call(reduce_add, [builder.call(popcount_v, [dc_bitmap(v, bm, age, True)])])
        own = dc_bitmap(v_own, bm_own, age_of(v_own, False), False)
        dc_own = builder.call(builder.module.declare_intrinsic("llvm.ctpop", [i64]), [own])
        out = s2
        for k, field in enumerate((s10, s50, dc_nb, dc_own), 1):
            out = builder.or_(out, builder.shl(field, ir.Constant(i64, k * FIELD_BITS)))
        return context.make_tuple(builder, signature.return_type, [out, own, box])

    return sig, codegen


def reference_nb8(word, bins, centre: int, wp: int, tick: int, pi: int, b8: int) -> tuple[int, int, int]:
    """`nb8_support` in plain Python, pixel by pixel."""

    def bitmap(q):  # active bins b - 63 .. b of pixel q, as bits 0 .. 63
        v = int(word[q])
        shift = (b8 - ((v >> BIN_SHIFT) & 0xFF)) % 256
        idle = tick - ((v & TICK_MASK) >> 1) >= DC_IDLE_TICKS
        return 0 if idle or shift >= 64 else (int(bins[q]) << shift) & (2**64 - 1)

    s2 = s10 = s50 = dc = 0
    for q in (centre - wp - 1, centre - wp, centre - wp + 1, centre - 1, centre + 1,
              centre + wp - 1, centre + wp, centre + wp + 1):
        v = int(word[q])
        age = tick - ((v & TICK_MASK) >> 1)
        same = (v & 1) == pi
        s2 += age < SUPPORT_TICKS[0]
        s10 += age < SUPPORT_TICKS[1] and same
        s50 += age < SUPPORT_TICKS[2] and same
        dc += bin(bitmap(q)).count("1")
    own = bitmap(centre)
    packed = s2 | s10 << FIELD_BITS | s50 << 2 * FIELD_BITS | dc << 3 * FIELD_BITS
    box = [(int(word[centre + dy * wp + dx]) % 2**64) >> COUNT_SHIFT for dy in range(-2, 3) for dx in range(-2, 3)]
    n_all, n_on = sum(c & 0xFFFF for c in box), sum(c >> 16 for c in box)
    return (packed | bin(own).count("1") << 4 * FIELD_BITS, own - (1 << 64 if own >= 1 << 63 else 0),
            n_all | n_on << 16)
