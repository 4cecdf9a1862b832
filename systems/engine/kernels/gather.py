"""Which neighbours of a sponsor have not moved yet, sixteen at a time: the scan at the heart of the
breadth-first cascade (kernels.chainmail), as one vector gather instead of sixteen loads and branches.

A drag frame reads about fourteen neighbour entries per moving element and finds all but one or two
already moved (thesis 5.2.4: each element moves once). `unmoved_mask` answers "which of these entries
lead to an element whose stamp is not the current generation" for up to sixteen consecutive CSR
entries with one vector load of the neighbour ids, one gather of their stamps and one compare, giving a
bit mask; the cascade then checks only the entries whose bit is set, lowest first (`lowest_bit`), which
is the order of the entries themselves, so the result is the one an entry-by-entry scan gives.

The vector form needs int32 neighbour ids, int32 or byte stamps, and sixteen readable ids from `start`
on: the CSR copy the cascade walks is padded with sixteen zeros (Workspace.narrow_csr), so a row near
the end reads element 0's stamp in lanes that the count masks off (the 3-D loop's rows of sixteen are
whole). A byte stamp is gathered as the low byte of four, so a byte-stamp array must have three readable
bytes after its end (a Workspace's has). Other dtypes take a plain loop with the same result. LLVM
lowers the gather to one instruction where the CPU has one (AVX-512, AVX2) and to sixteen loads
elsewhere.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic, overload

LANES = 16


def _splat(builder, value, vty):
    i32 = ir.IntType(32)
    v = builder.insert_element(ir.Constant(vty, ir.Undefined), value, ir.Constant(i32, 0))
    return builder.shuffle_vector(
        v, ir.Constant(vty, ir.Undefined), ir.Constant(ir.VectorType(i32, LANES), [0] * LANES)
    )


@intrinsic
def _gather_ne16(typingctx, indices, start, stamp, gen):
    """Bits k (0..15) set where stamp[indices[start + k]] != gen; int32 ids, int32 or byte stamps, no bounds
    checks."""
    ok = (
        isinstance(indices, types.Array)
        and isinstance(stamp, types.Array)
        and indices.dtype == types.int32
        and stamp.dtype in (types.int32, types.uint8)
        and indices.ndim == 1
        and stamp.ndim == 1
        and isinstance(start, types.Integer)
        and isinstance(gen, types.Integer)
    )
    if not ok:
        return None
    sig = types.int64(indices, start, stamp, gen)
    width = stamp.dtype.bitwidth // 8  # bytes a stamp

    def codegen(context, builder, signature, args):
        ity, sty, stty, gty = signature.args
        ids_arr = context.make_array(ity)(context, builder, args[0])
        stamp_arr = context.make_array(stty)(context, builder, args[2])
        i1, i32, i64 = ir.IntType(1), ir.IntType(32), ir.IntType(64)
        v_i32 = ir.VectorType(i32, LANES)
        v_i64 = ir.VectorType(i64, LANES)
        v_i1 = ir.VectorType(i1, LANES)
        first = context.cast(builder, args[1], sty, types.intp)
        ids_ptr = cgutils.get_item_pointer(context, builder, ity, ids_arr, [first], wraparound=False, boundscheck=False)
        ids = builder.load(builder.bitcast(ids_ptr, v_i32.as_pointer()), align=4)
        # addresses of the stamps: base + width * id (LLVM folds this into the gather's scaled index); a
        # byte stamp is read as the low byte of four (the array holds three bytes more than its stamps)
        base = _splat(builder, builder.ptrtoint(stamp_arr.data, i64), v_i64)
        addr = builder.add(base, builder.mul(builder.sext(ids, v_i64), ir.Constant(v_i64, [width] * LANES)))
        v_ptr = ir.VectorType(i32.as_pointer(), LANES)
        ptrs = builder.inttoptr(addr, v_ptr)
        fnty = ir.FunctionType(v_i32, [v_ptr, i32, v_i1, v_i32])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "llvm.masked.gather.v16i32.v16p0")
        all_lanes = ir.Constant(v_i1, [1] * LANES)
        stamps = builder.call(fn, [ptrs, ir.Constant(i32, width), all_lanes, ir.Constant(v_i32, ir.Undefined)])
        if width == 1:
            stamps = builder.and_(stamps, ir.Constant(v_i32, [0xFF] * LANES))
        g = context.cast(builder, args[3], gty, types.int32)
        ne = builder.icmp_unsigned("!=", stamps, _splat(builder, g, v_i32))
        return builder.zext(builder.bitcast(ne, ir.IntType(LANES)), i64)

    return sig, codegen


@intrinsic
def lowest_bit(typingctx, x):
    """Index of the lowest set bit of x; the width of x's type when x == 0 (defined, so a caller may compute
    it before testing x)."""
    if not isinstance(x, types.Integer):
        return None
    sig = x(x)

    def codegen(context, builder, signature, args):
        (v,) = args
        fnty = ir.FunctionType(v.type, [v.type, ir.IntType(1)])
        fn = cgutils.get_or_insert_function(builder.module, fnty, f"llvm.cttz.i{v.type.width}")
        return builder.call(fn, [v, ir.Constant(ir.IntType(1), 0)])

    return sig, codegen


def unmoved_mask(indices, start, count, stamp, gen):
    """Bit k (k < count <= 16) set where stamp[indices[start + k]] != gen (numba only)."""
    raise NotImplementedError("unmoved_mask is called from numba kernels")


@overload(unmoved_mask, inline="always")
def _unmoved_mask(indices, start, count, stamp, gen):
    vector = indices.dtype == types.int32 and stamp.dtype in (types.int32, types.uint8)
    if vector and indices.ndim == 1 and stamp.ndim == 1:

        def vector(indices, start, count, stamp, gen):
            return _gather_ne16(indices, start, stamp, gen) & ((np.int64(1) << count) - 1)

        return vector

    def scalar(indices, start, count, stamp, gen):
        return _scan_mask(indices, start, count, stamp, gen)

    return scalar


@njit(cache=True)
def _scan_mask(indices, start, count, stamp, gen):
    # a function of its own rather than code inlined at every use: numba's inliner loses track of the
    # loop's variables when one kernel inlines the overload twice
    m = np.int64(0)
    for k in range(count):
        m |= np.int64(stamp[indices[start + k]] != gen) << k
    return m


@njit(cache=True)
def mask_of(indices, start, count, stamp, gen):
    """unmoved_mask callable from Python (tests compare it with a plain scan)."""
    return unmoved_mask(indices, start, count, stamp, gen)
