"""`prefetch(a, i)`: ask for the cache line of `a[i]` ahead of a write to it (x86 PREFETCHW).

A streaming kernel whose state does not fit the L2 cache (the 1280×720 maps) waits on a cache miss
at each random access; its next accesses are known some events ahead (the next events' pixels, the
FIFO entries about to expire), so issuing them early overlaps those misses. A hint only: it never
faults, even out of bounds, and changes no result.
"""

from ..jit import intrinsic, njit

# A map larger than this does not stay in the L2 cache (1 MiB per core on the machines measured) beside
# the other maps and the events: kernels over it prefetch.
FAR_BYTES = 1 << 20


@intrinsic
def _prefetch(typingctx, a, i):
    from llvmlite import ir  # typing time: numba is loaded (evstream.jit)
    from numba import types
    from numba.core import cgutils

    if not isinstance(a, types.Array):
        return None

    def codegen(context, builder, signature, args):
        ary, idx = args
        data = context.make_array(signature.args[0])(context, builder, ary).data
        byte = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [byte, i32, i32, i32]),
                                            "llvm.prefetch.p0")
        # (address, write, locality 3 = keep in all levels, data cache)
        builder.call(fn, [builder.bitcast(builder.gep(data, [idx]), byte), ir.Constant(i32, 1), ir.Constant(i32, 3),
                          ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return types.void(a, types.intp), codegen


@njit(cache=True, nogil=True, inline="always")
def prefetch(a, i):
    """Hint that `a[i]` will be written soon (any `i`: an address outside `a` is not touched)."""
    _prefetch(a, i)
