"""Element access to C-contiguous arrays by one flat index, for the kernels' hot loops:
``ary[r, c]`` multiplies by the array's run-time row stride and, for a signed index,
adds numba's wrap-around of negative indices (a shift, an and, an add per access);
with the row width a constant (or hoisted out of the loop) a flat index is one add."""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.extending import intrinsic


def _c_array(ary, i):
    return (isinstance(ary, types.Array) and ary.layout == "C"
            and isinstance(i, types.Integer))


@intrinsic
def flat_get(typingctx, ary, i):
    """Element ``i`` of the C-contiguous array ``ary`` read as one flat run (row r,
    column c of a 2-D array at r · width + c). No bounds or sign check: ``i`` must lie
    in [0, ary.size)."""
    if not _c_array(ary, i):
        return None
    sig = ary.dtype(ary, types.intp)

    def codegen(context, builder, signature, args):
        data = context.make_array(signature.args[0])(context, builder, args[0]).data
        return builder.load(builder.gep(data, [args[1]]))

    return sig, codegen


@intrinsic
def flat_add(typingctx, ary, i, v):
    """``ary`` read as one flat run: element ``i`` += ``v`` (as ``flat_get``, unchecked)."""
    if not (_c_array(ary, i) and isinstance(v, types.Float) and ary.dtype == v):
        return None
    sig = types.void(ary, types.intp, ary.dtype)

    def codegen(context, builder, signature, args):
        data = context.make_array(signature.args[0])(context, builder, args[0]).data
        ptr = builder.gep(data, [args[1]])
        builder.store(builder.fadd(builder.load(ptr), args[2]), ptr)
        return context.get_dummy_value()

    return sig, codegen


_V4 = ir.VectorType(ir.DoubleType(), 4)


@intrinsic
def flat_add4(typingctx, ary, i, w, a, b, c, d):
    """``ary`` (float64) read as one flat run: elements i..i+3 += w·(a, b, c, d), as
    one <4 x double> load, multiply, add and store (the same roundings as four scalar
    ``flat_add``: w·a, then the sum; no fused multiply-add). Unchecked, as ``flat_get``."""
    if not (_c_array(ary, i) and ary.dtype == types.float64
            and all(isinstance(x, types.Float) for x in (w, a, b, c, d))):
        return None
    f8 = types.float64
    sig = types.void(ary, types.intp, f8, f8, f8, f8, f8)

    def codegen(context, builder, signature, args):
        data = context.make_array(signature.args[0])(context, builder, args[0]).data
        ptr = builder.bitcast(builder.gep(data, [args[1]]), _V4.as_pointer())
        lanes = ir.Constant(_V4, ir.Undefined)
        for k, x in enumerate(args[3:7]):
            lanes = builder.insert_element(lanes, x, ir.Constant(ir.IntType(32), k))
        splat = ir.Constant(_V4, ir.Undefined)
        splat = builder.insert_element(splat, args[2], ir.Constant(ir.IntType(32), 0))
        zeros = ir.Constant(ir.VectorType(ir.IntType(32), 4), [0] * 4)
        splat = builder.shuffle_vector(splat, ir.Constant(_V4, ir.Undefined), zeros)
        old = builder.load(ptr, align=8)
        builder.store(builder.fadd(old, builder.fmul(splat, lanes)), ptr, align=8)
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def flat_get_bits(typingctx, ary, i):
    """Element ``i`` of the C-contiguous float64 array ``ary`` (read as ``flat_get``)
    reinterpreted as an int64: integers stored bit for bit in a float array."""
    if not (_c_array(ary, i) and ary.dtype == types.float64):
        return None
    sig = types.int64(ary, types.intp)

    def codegen(context, builder, signature, args):
        data = context.make_array(signature.args[0])(context, builder, args[0]).data
        ptr = builder.bitcast(builder.gep(data, [args[1]]), ir.IntType(64).as_pointer())
        return builder.load(ptr)

    return sig, codegen
