"""A software prefetch for numba kernels: ask the CPU to start loading a row of an array that a kernel
will read soon, without waiting for it.

The breadth-first cascade (kernels.chainmail) knows which elements it will serve next (they wait in its
queue) long before it reads their rows; on meshes larger than the caches those reads are the cost of the
cascade, so it asks for them a few sponsors ahead. A prefetch changes no value and never faults (an
address past the end is only a hint), so it changes no result.
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic


@intrinsic
def prefetch(typingctx, arr, row):
    """Start loading arr[row] into the caches, for reading (for a 2-D array its first and last items: a
    row of three float64 crosses a cache line in three rows of eight)."""
    if not isinstance(arr, types.Array) or not isinstance(row, types.Integer):
        return None
    sig = types.void(arr, row)

    def codegen(context, builder, signature, args):
        aryty, rowty = signature.args
        ary = context.make_array(aryty)(context, builder, args[0])
        i = context.cast(builder, args[1], rowty, types.intp)
        i8p = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        fnty = ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "llvm.prefetch.p0")
        ends = [ir.Constant(i.type, 0)]
        if aryty.ndim == 2:  # a row may straddle two cache lines: ask for its last item's too
            ends.append(builder.sub(cgutils.unpack_tuple(builder, ary.shape, 2)[1], ir.Constant(i.type, 1)))
        for last in ends:
            idx = [i] + [last] * (aryty.ndim - 1)
            ptr = cgutils.get_item_pointer(context, builder, aryty, ary, idx, wraparound=False, boundscheck=False)
            # read (0), keep in all cache levels (3), data cache (1)
            builder.call(fn, [builder.bitcast(ptr, i8p), ir.Constant(i32, 0), ir.Constant(i32, 3), ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return sig, codegen
