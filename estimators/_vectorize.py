"""numpy front ends for the numba scalar kernels: one generic block loop serves them all.

A kernel takes ``(x, p)``: ``x`` a tuple of float64 coordinates (a point), ``p`` an
indexable of parameters, and returns a tuple (a point) or a float (a density). The path
tracer calls the same kernels on tuples, so each warp has one implementation.

Each front end runs one loop over blocks of ``_BLOCK`` rows on numba's threads (a
range of blocks a thread, ``mcnumba.threads``). Within a block, the input rows are first
moved into a column-major scratch block (one contiguous run per coordinate), the kernel
reads those columns and writes its results to a second one, and these are moved back to
rows: eight rows at a time, as vector shuffles (``_transpose``). Unit-stride columns are
what lets LLVM vectorise a branch-light kernel (measured, cosine hemisphere, one thread: 9 ns a point against
42 ns for one kernel call per row; the loop is compiled with IEEE division, as numba
compiles a parallel loop's body: with numba's default error model LLVM did not
vectorise it, 25 ns); the shuffles replace the gathers and scalar stores
LLVM wrote for the row accesses (measured on AMD Zen 4, 1e6 points, one thread: the
cosine hemisphere's sampling 6.9 -> 5.7 ms, its pdf 4.4 -> 3.0 ms, bits unchanged).
Each row is computed independently of every other, so the output is bit-identical
whatever the thread count.

The loop of each kernel is a small generated module in the kernel cache
(``$MCVERIFY_CACHE``, default ``~/.cache/mcverify/kernels``), compiled by numba with
``cache=True``: a loop taking the kernel as an argument, or a closure over it, cannot
be cached by numba, and a loop costs seconds to compile, which every fresh
process (every ``mcverify check``) would pay again for each warp. The module's name
carries a hash of the kernel's source file, of this one, of ``_fastmath`` and of
``_compile_options`` (numba's cache tracks only the file of the cached function, not its
callees), so an edited kernel gets a new loop.

With ``inline=True`` the loop inlines its kernel (numba's ``inline="always"`` on the
kernel's Python function, compiled with IEEE division): LLVM's inliner leaves a kernel
above its size threshold (Beckmann's, with its ``fast_log1p``) as a call, and a call in
the loop stops vectorisation. It is not the default because it slows kernels whose
branches LLVM flattens only when it optimises them alone (measured, one thread: the
concentric disk map 9 -> 19 ns a point, the triangle inverse 4 -> 11 ns).

``fused_front_end`` runs a sampler and the density of its points in one such loop (the
warps' ``sample_X.with_pdf``): the density reads each point from the block's scratch as
the output stores it, so the pair is bit for bit the two front ends' calls, without the
points going out to memory and coming back (measured on Zen 4, 1e6 cosine-hemisphere
points, two threads: 4.6 ms for the two calls, 3.1 ms in one pass).

float32 input gives float32 output. Each coordinate is widened to float64 as it is read,
the kernel computes in float64, and the result is rounded once as it is stored: float32
arithmetic inside the kernels would lose several ulps in the cancellations they avoid
in float64 (``1 - x² - y²`` at the horizon, ``1 - cos θ`` at the pole), and the tests
hold the float32 path to half a float32 ulp of the float64 one.
"""

from __future__ import annotations

import functools
import glob
import hashlib
import inspect

import numpy as np
from numba import types
from numba.extending import overload

from mcnumba.threads import run_ranges

from . import _compile_options, _fastmath, _transpose
from ._compile_options import exact
from ._generated import first_call, load
from .warp_params import check_params, param_count

#: Rows per block: scratch of up to 4 float64 columns stays in L1 (16 KB), and a block
#: is large enough for the per-block overhead to vanish.
_BLOCK = 512


@exact(inline="always")
def _column1(c, t):
    return (c[0, t],)


@exact(inline="always")
def _column2(c, t):
    return (c[0, t], c[1, t])


@exact(inline="always")
def _column3(c, t):
    return (c[0, t], c[1, t], c[2, t])


@exact(inline="always")
def _put_value(o, t, r):
    o[0, t] = r


@exact(inline="always")
def _put1(o, t, r):
    o[0, t] = r[0]


@exact(inline="always")
def _put2(o, t, r):
    o[0, t] = r[0]
    o[1, t] = r[1]


@exact(inline="always")
def _put3(o, t, r):
    o[0, t] = r[0]
    o[1, t] = r[1]
    o[2, t] = r[2]


@exact(inline="always")
def _nan_or1(x, v):
    return v if x[0] == x[0] else x[0]


@exact(inline="always")
def _nan_or2(x, v):
    return v if (x[0] == x[0]) & (x[1] == x[1]) else np.nan


@exact(inline="always")
def _nan_or3(x, v):
    return v if (x[0] == x[0]) & (x[1] == x[1]) & (x[2] == x[2]) else np.nan


@exact(inline="always")
def _row_ok1(x):
    return x[0] == x[0]


@exact(inline="always")
def _row_ok2(x):
    return (x[0] == x[0]) & (x[1] == x[1])


@exact(inline="always")
def _row_ok3(x):
    return (x[0] == x[0]) & (x[1] == x[1]) & (x[2] == x[2])


@exact(inline="always")
def _unit_ok1(u):
    return (u[0] >= 0.0) & (u[0] <= 1.0)


@exact(inline="always")
def _unit_ok2(u):
    return (u[0] >= 0.0) & (u[0] <= 1.0) & (u[1] >= 0.0) & (u[1] <= 1.0)


@exact(inline="always")
def _nan_row1(ok, r):
    return r if ok else (np.nan,)


@exact(inline="always")
def _nan_row2(ok, r):
    return r if ok else (np.nan, np.nan)


@exact(inline="always")
def _nan_row3(ok, r):
    return r if ok else (np.nan, np.nan, np.nan)


#: A point (or an inverse's u) from an input with a NaN coordinate is NaN in every
#: coordinate: half of one (the sphere's (NaN, NaN, z) of u = (0.3, NaN), the triangle's
#: (NaN, y)) looked like a coordinate the NaN had not touched, and the cosine
#: hemisphere's inverse of (x, y, NaN) was a finite u. Applied by the front ends' loops,
#: as ``_NAN_OR``.
_ROW_OK = {1: "_row_ok1", 2: "_row_ok2", 3: "_row_ok3"}
#: A sampler's u outside [0, 1] (NaN included) gives a NaN point: the warps extrapolated
#: it to points off their domain (u = -0.5: the sphere's (0, 0, 2), the interval's a -
#: (b - a) / 2), silently. u = 1 itself is kept (a float32 u rounds to it).
_UNIT_OK = {1: "_unit_ok1", 2: "_unit_ok2"}
_NAN_ROW = {1: "_nan_row1", 2: "_nan_row2", 3: "_nan_row3"}

_COLUMNS = {1: "_column1", 2: "_column2", 3: "_column3"}
#: A density's value at a point with a NaN coordinate is NaN, whatever the kernel's
#: tests make of it (``x >= 0`` is false for NaN, so most would say 0, the sphere's
#: 1/4π): a NaN point from a broken sampler stays visible. Applied by the front ends'
#: loops; the kernels, which the path tracer calls on points it made, are unchanged.
_NAN_OR = {1: "_nan_or1", 2: "_nan_or2", 3: "_nan_or3"}
_PUTS = {1: "_put1", 2: "_put2", 3: "_put3"}


# The generated loops, from fragments: the block loop of one kernel, and of a sampler
# followed by its density (``fused_front_end``).
_HEAD = '''"""Generated by estimators._vectorize: the block loop of {kernel}{and_density}."""
import numpy as np
from numba import njit

from {module} import {kernel} as kernel
from estimators._transpose import (LANES, load_rows{n_in} as load, store_fence,
                                   store_rows{n_out} as store, stream_rows{n_out} as stream)
from estimators._vectorize import _BLOCK, {column} as column, {put} as put
from estimators._vectorize import {nan_or} as nan_or
from estimators._vectorize import {row_ok} as row_ok, {nan_row} as nan_row
{inline}
'''

_BLOCK_IN = '''    n = x.shape[0]
    n_in = {n_in}
    n_out = {n_out}
    pt = {params}
    c = np.empty((n_in, _BLOCK))
    o = np.empty((n_out, _BLOCK)){scratch}
    for b in range(b0, b1):
        lo = b * _BLOCK
        m = min(_BLOCK, n - lo)
        whole = m - m % LANES
        for t in range(0, whole, LANES):
            load(x, lo + t, c, t)
        for t in range(whole, m):
            for j in range(n_in):
                c[j, t] = x[lo + t, j]
        for t in range(m):
            put(o, t, {call})
'''

_BLOCK_OUT = '''        if streaming:
            for t in range(0, whole, LANES):
                {stream}({o}, t, {out}, lo + t)
            store_fence()
        else:
            for t in range(0, whole, LANES):
                {store}({o}, t, {out}, lo + t)
        for t in range(whole, m):
            for j in range({o}.shape[0]):
                {out}[lo + t, j] = {o}[j, t]
'''

_LOOP_SOURCE = (_HEAD + '''

@njit(cache=True, nogil=True, error_model="numpy")
def loop(x, p, out, streaming, b0, b1):
''' + _BLOCK_IN + _BLOCK_OUT.format(o="o", out="out", store="store", stream="stream"))

_FUSED_SOURCE = (_HEAD + '''from {density_module} import {density} as density
from estimators._transpose import store_rows1, stream_rows1
from estimators._vectorize import _as_stored, {point} as point
{inline_density}

@njit(cache=True, nogil=True, error_model="numpy")
def loop(x, p, out, pdf_out, streaming, b0, b1):
''' + _BLOCK_IN + '''        for t in range(m):
            for j in range(n_out):          # the point as ``out`` holds it
                o[j, t] = _as_stored(out, o[j, t])
            q[0, t] = nan_or(point(o, t), density(point(o, t), pt))
''' + _BLOCK_OUT.format(o="o", out="out", store="store", stream="stream")
    + _BLOCK_OUT.format(o="q", out="pdf_out", store="store_rows1", stream="stream_rows1"))


_INLINE = '''
# The same Python function, inlined by numba into the loop: LLVM's inliner leaves a
# kernel above its size threshold as a call, and a call stops vectorisation.
{name} = njit(inline="always", error_model="numpy")({name}.py_func)
'''


def _as_stored(out, v):
    """``v`` as ``out`` stores it, back in float64 (rounded to float32 for a float32
    ``out``): a fused loop's density sees the point the caller gets."""


@overload(_as_stored, inline="always")
def _as_stored_overload(out, v):
    if out.dtype == types.float32:
        return lambda out, v: np.float64(np.float32(v))
    return lambda out, v: v


def _module(prefix: str, source: str, functions):
    """The generated module of ``source``, named by a hash of it and of the files that
    define ``functions`` (numba's cache tracks only the file of the cached function, not
    its callees): an edited kernel gets a new loop."""
    h = hashlib.sha256(source.encode())
    paths = [inspect.getsourcefile(f) for f in functions]
    for path in dict.fromkeys(paths + [__file__, _fastmath.__file__, _transpose.__file__,
                                       _compile_options.__file__]):
        with open(path, "rb") as f:
            h.update(f.read())
    return load(f"{prefix}_{h.hexdigest()[:16]}", source)


def _params(count: int) -> str:
    """The loop's parameters as a tuple of ``count`` floats, read once from the array
    ``p``: a kernel given the array itself took and dropped a reference to it at every
    point, and LLVM vectorised no loop around that (measured, one thread: the uniform
    interval's density 22.8 -> 2.5 ns a point, the exponential's sampling 82.7 -> 11.8)."""
    return "(" + "".join(f"p[{i}], " for i in range(count)) + ")"


@functools.lru_cache(maxsize=None)
def _loop(kernel, n_in: int, put: str, inline: bool, n_params: int, unit: bool = False):
    """The compiled block loop ``loop(x, p, out, streaming, b0, b1)``: ``out[i] =
    kernel(x[i], p)`` for every row of blocks ``b0`` to ``b1`` of the (n, n_in)
    C-contiguous ``x``, ``p`` an array of ``n_params`` floats; ``out`` is (n, n_out) of
    the input's dtype (a density's is (n, 1)), streamed into (``_transpose``) if
    ``streaming``. ``inline``: numba inlines the kernel's Python function into the loop."""
    fn = kernel.py_func
    # n_out a literal: LLVM unrolls the copy out of the scratch block (with out.shape[1]
    # it did not: cosine-hemisphere pdf 0.93 -> 0.54 ms, its sampling 2.2 -> 1.9 ms for
    # 1e6 points on two threads)
    n_out = 1 if put == "_put_value" else next(k for k, v in _PUTS.items() if v == put)
    call = "kernel(column(c, t), pt)"
    if put == "_put_value":
        call = f"nan_or(column(c, t), {call})"
    elif unit or n_in > 1 or n_out > 1:     # a 1-D warp's NaN u is its NaN point already
        call = f"nan_row(row_ok(column(c, t)), {call})"
    source = _LOOP_SOURCE.format(module=fn.__module__, kernel=fn.__name__, and_density="",
                                 column=_COLUMNS[n_in], put=put, n_in=n_in, n_out=n_out,
                                 nan_or=_NAN_OR[n_in],
                                 row_ok=_UNIT_OK[n_in] if unit else _ROW_OK[n_in],
                                 nan_row=_NAN_ROW[n_out], call=call,
                                 inline=_INLINE.format(name="kernel") if inline else "",
                                 params=_params(n_params), scratch="")
    return _module(f"estimators_loop_{fn.__name__.strip('_')}", source, [fn]).loop


@functools.lru_cache(maxsize=None)
def _fused_loop(kernel, density, n_in: int, n_out: int, inline: bool, inline_density: bool,
                n_params: int):
    """The compiled block loop ``loop(x, p, out, pdf_out, streaming, b0, b1)`` of a
    sampler and its density: ``out[i] = kernel(x[i], p)`` and ``pdf_out[i, 0] =
    density(out[i], p)`` (the point as ``out`` stores it, read back in float64)."""
    fn, fd = kernel.py_func, density.py_func
    source = _FUSED_SOURCE.format(
        module=fn.__module__, kernel=fn.__name__, and_density=f" and {fd.__name__}",
        column=_COLUMNS[n_in], put=_PUTS[n_out], n_in=n_in, n_out=n_out,
        nan_or=_NAN_OR[n_out], row_ok=_UNIT_OK[n_in], nan_row=_NAN_ROW[n_out],
        call="nan_row(row_ok(column(c, t)), kernel(column(c, t), pt))",
        params=_params(n_params),
        scratch="\n    q = np.empty((1, _BLOCK))",     # the densities' block
        inline=_INLINE.format(name="kernel") if inline else "",
        density_module=fd.__module__, density=fd.__name__, point=_COLUMNS[n_out],
        inline_density=_INLINE.format(name="density") if inline_density else "")
    return _module(f"estimators_fused_{fn.__name__.strip('_')}", source, [fn, fd]).loop


def as_rows(name: str, x, n_in: int) -> np.ndarray:
    """``x`` as a C-contiguous (n, n_in) array, float32 kept as float32 and anything
    else as float64 (1-D accepted when n_in is 1)."""
    try:
        a = np.asarray(x)
    except ValueError as e:
        # a ragged list (rows of 1 and 2 numbers): numpy's "setting an array element
        # with a sequence", which named no front end
        raise ValueError(f"{name}: not an array of numbers ({e})") from None
    # complex, object (None read as NaN), strings, bools: numpy's cast dropped the
    # imaginary part with a warning, or raised a message that named no front end
    if a.dtype.kind not in "fiu":
        raise ValueError(f"{name}: expected real numbers (float or integer), got an "
                         f"array of dtype {a.dtype}")
    a = a.astype(np.float64, copy=False) if a.dtype != np.float32 else a
    if a.ndim == 1 and n_in == 1:
        a = a.reshape(-1, 1)
    if a.ndim != 2 or a.shape[1] != n_in:
        raise ValueError(f"{name}: expected an array of shape (n, {n_in}), got {a.shape}")
    return np.ascontiguousarray(a)


def _last_level_cache_bytes(default: int = 32 << 20) -> int:
    """The largest CPU cache's size (Linux sysfs), or ``default`` where unknown."""
    sizes = []
    for path in glob.glob("/sys/devices/system/cpu/cpu0/cache/index*/size"):
        try:
            with open(path) as f:
                text = f.read().strip()
            sizes.append(int(text[:-1]) << {"K": 10, "M": 20, "G": 30}[text[-1]])
        except (OSError, ValueError, KeyError, IndexError):
            pass
    return max(sizes, default=default)


#: Outputs of at least this many bytes are written with streaming stores: half the
#: last-level cache. An output that large would evict most of what the cache holds, and
#: a normal store first reads each line it writes (measured on AMD Zen 4, 32 MB L3, the
#: cosine hemisphere's sampling and then its pdf, two threads: 1e6 points, 24 MB out,
#: 5.1 -> 4.1 ms streaming; 6e5 points 3.1 -> 2.9 ms; 3e5 points, 7 MB, 0.64 -> 0.95 ms,
#: the pdf then reading from memory what the cache held). glibc's memcpy switches to
#: streaming stores at a threshold of the same kind (3/4 of the shared cache).
STREAM_BYTES = _last_level_cache_bytes() // 2


def _output(n: int, n_out: int, dtype, total: int | None = None) -> tuple[np.ndarray, bool]:
    """An uninitialised (n, n_out) array for a front end's results, and whether the loop
    streams into it: when the loop writes ``STREAM_BYTES`` or more (``total`` bytes, by
    default this array's), and then the array starts on a 64-byte line, as streaming
    stores of whole vectors require."""
    dtype = np.dtype(dtype)
    nbytes = n * n_out * dtype.itemsize
    if (nbytes if total is None else total) < STREAM_BYTES:
        return np.empty((n, n_out), dtype), False
    raw = np.empty(nbytes + 64, np.uint8)
    skip = -raw.ctypes.data % 64
    return raw[skip:skip + nbytes].view(dtype).reshape(n, n_out), True


def _run(loop, rows, *args):
    """``loop(rows, *args, b0, b1)`` over every block of ``rows``, on numba's threads
    (``mcnumba.threads.run_ranges``). The first call per dtype compiles (or loads numba's
    cache) under the kernel cache's lock, so processes starting together compile each
    loop once."""
    name_dtype = f"{loop.__module__}.{rows.dtype}"
    with first_call(name_dtype, name_dtype):
        run_ranges(loop, (rows.shape[0] + _BLOCK - 1) // _BLOCK, rows, *args)


def _front_end(kernel, n_in: int, n_out: int, put, name: str, doc: str, squeeze: bool,
               inline: bool, unit: bool = False):
    count = param_count(name)

    def front(x, *params):
        p = check_params(name, params)
        rows = as_rows(name, x, n_in)
        out, streaming = _output(rows.shape[0], n_out, rows.dtype)
        _run(_loop(kernel, n_in, put, inline, count, unit), rows, p, out, streaming)
        return out[:, 0] if squeeze else out

    front.__name__ = front.__qualname__ = name
    front.__doc__ = doc
    front.kernel = kernel
    front.loop = functools.partial(_loop, kernel, n_in, put, inline, count, unit)  # compiled loop
    return front


def fused_front_end(kernel, density, n_in: int, n_out: int, name: str, doc: str = "", *,
                    inline: bool = False, inline_density: bool = False):
    """Array function ``f(u, *params) -> (x, pdf)`` around a point kernel and the density
    kernel of its points, in one pass: the same values as ``x = sample(u, *params)``
    then ``pdf(x, *params)`` from their front ends, bit for bit (the density reads each
    point as ``x`` holds it, float32 included), without writing the points out and
    reading them back in between."""
    count = param_count(name)

    def front(u, *params):
        p = check_params(name, params)
        rows = as_rows(name, u, n_in)
        n, size = rows.shape[0], rows.dtype.itemsize
        total = n * (n_out + 1) * size
        out, streaming = _output(n, n_out, rows.dtype, total)
        pdf_out, _ = _output(n, 1, rows.dtype, total)
        loop = _fused_loop(kernel, density, n_in, n_out, inline, inline_density, count)
        _run(loop, rows, p, out, pdf_out, streaming)
        return out, pdf_out[:, 0]

    front.__name__ = front.__qualname__ = name
    front.__doc__ = doc
    front.loop = functools.partial(_fused_loop, kernel, density, n_in, n_out, inline,
                                   inline_density, count)
    return front


def point_front_end(kernel, n_in: int, n_out: int, name: str, doc: str = "", *,
                    inline: bool = False, unit: bool = False):
    """Array function ``f(x, *params) -> (n, n_out)`` around a point kernel;
    ``inline``: see ``_loop``; ``unit``: x is a sampler's u, and a row outside [0, 1]
    gives NaN (``_UNIT_OK``)."""
    return _front_end(kernel, n_in, n_out, _PUTS[n_out], name, doc, False, inline, unit)


def value_front_end(kernel, n_in: int, name: str, doc: str = "", *, inline: bool = False):
    """Array function ``f(x, *params) -> (n,)`` around a density kernel."""
    return _front_end(kernel, n_in, 1, "_put_value", name, doc, True, inline)
