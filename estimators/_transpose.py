"""Rows of points to columns and back, eight points at a time, in vector registers.

The array front ends (``_vectorize``) take points as rows, ``(n, k)`` C-contiguous, and
compute on columns (one contiguous run per coordinate) so that LLVM vectorises the
kernel. Reading row coordinates one by one, LLVM vectorises the loads as gathers
(``vgatherqpd``: the stride ``k`` is a run-time value to it) and the stores back to rows
as scalar moves; on AMD Zen 4 these two took about 45 % of the cosine hemisphere's
sampling time (perf, one thread). The intrinsics here move ``LANES`` rows as one vector:
``load_rows{k}`` reads ``LANES · k`` consecutive values and splits them into ``k``
columns by shuffles, ``store_rows{k}`` interleaves ``k`` columns into rows and writes
them as one vector (x86-64: ``vpermt2pd``). Values are moved, not changed: float32 is
widened exactly to float64 on the way in and rounded to nearest once on the way out,
as the scalar conversions ``np.float64(v)`` and ``np.float32(v)`` do.

``stream_rows{k}`` stores as ``store_rows{k}`` does, with streaming (non-temporal)
stores, which write whole cache lines to memory without first reading them in: the
front ends use them for outputs too large for the cache (``_vectorize.STREAM_BYTES``),
laid out from a 64-byte boundary, and end each block with ``store_fence``.

The caller keeps every access in bounds: ``LANES`` whole rows from row ``i`` of the
source or destination, ``LANES`` columns from ``t`` in the scratch block.
"""

from __future__ import annotations

import platform

from llvmlite import ir
from numba import types
from numba.extending import intrinsic

#: Points moved by one call: eight float64 fill an AVX-512 register.
LANES = 8

_FLOATS = (types.float32, types.float64)


def _vector(element, n):
    return ir.VectorType(element, n)


def _mask(indices):
    indices = list(indices)
    return ir.Constant(_vector(ir.IntType(32), len(indices)), indices)


def _row_array(a):
    return (isinstance(a, types.Array) and a.dtype in _FLOATS and a.ndim == 2
            and a.layout == "C")


def _scratch(a):
    return isinstance(a, types.Array) and a.dtype == types.float64 and a.ndim == 2 \
        and a.layout == "C"


def _pointer(builder, base, index, vector):
    return builder.bitcast(builder.gep(base, [index]), vector.as_pointer())


def _column_start(context, builder, array, j, t):
    """The element index of ``array[j, t]`` in a C-contiguous 2-D ``array``."""
    intp = context.get_value_type(types.intp)
    return builder.add(builder.mul(ir.Constant(intp, j), builder.extract_value(array.shape, 1)),
                       t)


def _operands(context, builder, signature, args, rows_at: int, columns_at: int):
    """A mover's operands: the rows' and the scratch's array structs, the row index ``i``
    and the column index ``t`` as intp (each index follows its array in the arguments),
    and the rows' dtype."""
    types_ = signature.args
    rows = context.make_array(types_[rows_at])(context, builder, args[rows_at])
    columns = context.make_array(types_[columns_at])(context, builder, args[columns_at])
    i = context.cast(builder, args[rows_at + 1], types_[rows_at + 1], types.intp)
    t = context.cast(builder, args[columns_at + 1], types_[columns_at + 1], types.intp)
    return rows, columns, i, t, types_[rows_at].dtype


def _make_load(k: int):
    @intrinsic
    def load(typingctx, rows, i, columns, t):
        if not (_row_array(rows) and _scratch(columns)):
            return None

        def codegen(context, builder, signature, args):
            src, dst, i, t, dtype = _operands(context, builder, signature, args, 0, 2)
            intp = context.get_value_type(types.intp)
            element = context.get_data_type(dtype)
            double = ir.DoubleType()
            first = builder.mul(i, ir.Constant(intp, k))
            v = builder.load(_pointer(builder, src.data, first, _vector(element, LANES * k)),
                             align=dtype.bitwidth // 8)
            if dtype == types.float32:
                v = builder.fpext(v, _vector(double, LANES * k))
            for j in range(k):
                column = v if k == 1 else builder.shuffle_vector(
                    v, ir.Constant(_vector(double, LANES * k), ir.Undefined),
                    _mask(j + k * r for r in range(LANES)))
                at = _column_start(context, builder, dst, j, t)
                builder.store(column, _pointer(builder, dst.data, at, _vector(double, LANES)),
                              align=8)
            return context.get_dummy_value()

        return types.void(rows, i, columns, t), codegen

    load.__doc__ = (f"columns[j, t:t+{LANES}] = rows[i:i+{LANES}, j] for j < {k}, float64 "
                    "columns from float32 or float64 rows.")
    return load


def _make_store(k: int, stream: bool):
    @intrinsic
    def store(typingctx, columns, t, rows, i):
        if not (_scratch(columns) and _row_array(rows)):
            return None

        def codegen(context, builder, signature, args):
            dst, src, i, t, dtype = _operands(context, builder, signature, args, 2, 0)
            intp = context.get_value_type(types.intp)
            element = context.get_data_type(dtype)
            double = ir.DoubleType()
            lane = _vector(double, LANES)
            cols = [builder.load(_pointer(builder, src.data,
                                          _column_start(context, builder, src, j, t), lane),
                                 align=8)
                    for j in range(k)]
            interleave = _mask(r + LANES * j for r in range(LANES) for j in range(k))
            if k == 1:
                v = cols[0]
            elif k == 2:
                v = builder.shuffle_vector(cols[0], cols[1], interleave)
            else:       # shufflevector takes two operands of one type: pair (0, 1), (2, -)
                pair = builder.shuffle_vector(cols[0], cols[1], _mask(range(2 * LANES)))
                third = builder.shuffle_vector(cols[2], ir.Constant(lane, ir.Undefined),
                                               _mask(list(range(LANES)) + [LANES] * LANES))
                v = builder.shuffle_vector(pair, third, interleave)
            if dtype == types.float32:
                v = builder.fptrunc(v, _vector(element, LANES * k))
            first = builder.mul(i, ir.Constant(intp, k))
            size = LANES * k * dtype.bitwidth // 8
            at = _pointer(builder, dst.data, first, _vector(element, LANES * k))
            if stream:          # the group's start: a multiple of `size` past a 64-byte line
                done = builder.store(v, at, align=min(64, size & -size))
                done.set_metadata("nontemporal", builder.module.add_metadata(
                    [ir.Constant(ir.IntType(32), 1)]))
            else:
                builder.store(v, at, align=dtype.bitwidth // 8)
            return context.get_dummy_value()

        return types.void(columns, t, rows, i), codegen

    store.__doc__ = (f"rows[i:i+{LANES}, j] = columns[j, t:t+{LANES}] for j < {k}, float64 "
                     "columns to float32 (rounded to nearest) or float64 rows."
                     + (" Streaming (non-temporal) stores: ``rows`` must start on a 64-byte "
                        f"boundary and ``i`` be a multiple of {LANES}; ``store_fence`` "
                        "before the rows are read elsewhere." if stream else ""))
    return store


@intrinsic
def store_fence(typingctx):
    """Orders this thread's streaming stores before its later stores (x86-64 ``sfence``;
    elsewhere a sequentially consistent fence), so that a thread that joins it sees them."""
    def codegen(context, builder, signature, args):
        if platform.machine().lower() in ("x86_64", "amd64"):
            fn = builder.module.declare_intrinsic("llvm.x86.sse.sfence", (),
                                                  ir.FunctionType(ir.VoidType(), ()))
            builder.call(fn, ())
        else:
            builder.fence("seq_cst")
        return context.get_dummy_value()

    return types.void(), codegen


load_rows1, load_rows2, load_rows3 = (_make_load(k) for k in (1, 2, 3))
store_rows1, store_rows2, store_rows3 = (_make_store(k, False) for k in (1, 2, 3))
stream_rows1, stream_rows2, stream_rows3 = (_make_store(k, True) for k in (1, 2, 3))
