"""numba kernels behind the domains: map a point to parameter space, screen it, bin it.

One pass per chunk of samples replaces several numpy passes (finite?, inside?, to
parameters, bin along each axis); float32 points are read as they are. Domains are
identified by a small integer ``kind`` with float parameters ``args``; ``domains.py``
holds the numpy front ends.

The passes are serial ``nogil`` loops over a range of rows (blocks, parts) that
``mcnumba.threads`` runs on several threads, one contiguous range each, compiled with
IEEE division as numba compiles a ``prange`` body. As ``prange`` loops they compiled in
two to three times the time (numba's parfor passes, then the outlined body compiled
again; empty cache, AMD Zen 1: the histogram of float64 points 22.5 -> 8.4 s of CPU with
``_point_status``, and 21.4 -> 18.5 ms for 2^20 points on one thread).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from mcnumba.threads import LOOP, run_ranges, run_split, threads_for

INTERVAL, SQUARE, DISK, SPHERE, HEMISPHERE = 0, 1, 2, 3, 4
#: Coordinates of a point of each kind (``_to_point_rows`` writes that many a row).
_POINT_DIM = {INTERVAL: 1, SQUARE: 2, DISK: 2, SPHERE: 3, HEMISPHERE: 3}
#: Status codes of ``classify``: a valid point, a NaN/Inf coordinate, outside the domain,
#: a rejected draw (a row of NaN, when the caller accepts rejected draws).
VALID, NONFINITE, OUTSIDE, REJECTED = 0, 1, 2, 3
N_STATUS = 4
#: The histogram kernel splits its rows into this many fixed parts, each with its own
#: counts (summed at the end: integer sums, so the result does not depend on threads).
_PARTS = 16
#: The fewest rows worth a thread of their own (a few ns a row; handing a range to
#: another thread costs about 50 µs).
_ROWS_PER_THREAD = 16384
_S_MAX = 1.0 - 2.0 ** -52
#: The largest double below 1: a point's z where 1 - w rounds to 1 with w > 0.
_BELOW_ONE = 1.0 - 2.0 ** -53
_INV_TWO_PI = 1.0 / (2.0 * math.pi)


# Cephes' atan (S. L. Moshier): a rational approximation on [0, 0.66] after one range
# reduction, accurate to about one ulp (max error 2.2e-16 against atan2 over 2e5 points
# and the axes), with no libm call; libm's atan2 was the largest single cost of binning
# a point on the sphere.
_ATAN_P = (-8.750608600031904122785e-1, -1.615753718733365076637e1,
           -7.500855792314704667340e1, -1.228866684490136173410e2,
           -6.485021904942025371773e1)
_ATAN_Q = (2.485846490142306297962e1, 1.650270098316988542046e2,
           4.328810604912902668951e2, 4.853903996359136964868e2,
           1.945506571482613964425e2)
_MOREBITS = 6.123233995736765886130e-17


@njit(cache=True, inline="always")
def _atan01(a):
    """atan(a) for 0 <= a <= 1."""
    big = a > 0.66
    t = (a - 1.0) / (a + 1.0) if big else a
    z = t * t
    p = (((_ATAN_P[0] * z + _ATAN_P[1]) * z + _ATAN_P[2]) * z + _ATAN_P[3]) * z + _ATAN_P[4]
    q = ((((z + _ATAN_Q[0]) * z + _ATAN_Q[1]) * z + _ATAN_Q[2]) * z + _ATAN_Q[3]) * z + _ATAN_Q[4]
    r = t * (z * p / q) + t
    return (0.25 * math.pi + (r + 0.5 * _MOREBITS)) if big else r


@njit(cache=True, inline="always")
def _azimuth(x, y):
    """φ / 2π in [0, 1] of the direction (x, y), φ = atan2(y, x) taken to [0, 2π)."""
    ax, ay = abs(x), abs(y)
    hi = max(ax, ay)
    phi = _atan01(min(ax, ay) / hi) if hi > 0.0 else 0.0
    if ay > ax:
        phi = 0.5 * math.pi - phi
    if x < 0.0:
        phi = math.pi - phi
    if y < 0.0:
        phi = 2.0 * math.pi - phi if phi > 0.0 else 0.0
    return phi * _INV_TWO_PI


@njit(cache=True, inline="always")
def _pseudo_azimuth(x, y):
    """A monotone stand-in for φ / 2π in [0, 1] of the direction (x, y): the "diamond
    angle" ``y / (|x| + |y|)`` walked around the four quadrants, one division and no
    transcendental function. It orders directions as φ does, so the cell ``[φ_k,
    φ_k+1)`` is ``[pseudo(φ_k), pseudo(φ_k+1))`` (``pseudo_azimuth_edges``) and binning
    needs no arc tangent (which was a third of a sphere point's binning time)."""
    s = abs(x) + abs(y)
    p = y / s if s > 0.0 else 0.0            # [-1, 1]
    a = p if x >= 0.0 else 2.0 - p           # x >= 0: [-1, 1]; x < 0: [1, 3]
    if a < 0.0:
        a += 4.0
    return 0.25 * a


@njit(cache=True)
def _pseudo_azimuth_edges_kernel(e, out):
    for k in range(e.shape[0]):
        phi = 2.0 * math.pi * e[k]
        out[k] = _pseudo_azimuth(math.cos(phi), math.sin(phi))


def pseudo_azimuth_edges(e: np.ndarray) -> np.ndarray:
    """Azimuth cell edges (φ / 2π, increasing from 0 to 1) as ``_pseudo_azimuth``
    values: the same cells, found without an arc tangent."""
    e = np.asarray(e, dtype=np.float64)
    out = np.empty_like(e)
    _pseudo_azimuth_edges_kernel(e, out)
    out[0], out[-1] = 0.0, 1.0
    return np.maximum.accumulate(out)


@njit(cache=True, inline="always")
def _interval_tol(tol, a, b, x):
    """How far outside ``[a, b]`` a point of ``x``'s type still counts as inside:
    ``tol`` of the width, or one ulp of the ends' magnitude in that type, whichever is
    more. An end a float32 point cannot hold exactly (100.1) is held as its nearest
    float32, half a float32 ulp (3.8e-6) away: ``tol`` of a width of 0.1 is 1e-6, and a
    correct float32 sampler on ``Interval(100.1, 100.2)`` failed, its draws at ``u = 0``
    "outside the interval" (an outside review, 7 December)."""
    return max(tol * (b - a), np.finfo(x.dtype).eps * max(abs(a), abs(b)))


@njit(cache=True, inline="always")
def _one_minus_z(r2, z, half):
    """1 - z of a unit vector with x² + y² = ``r2``, keeping the tangential components'
    precision at both poles: (x² + y²) / (1 + z) for z > 0 (float32 points there have
    z = 1 to within an ulp, so 1 - z would be 0 or 6e-8), and on the sphere 2 - (x² +
    y²) / (1 - z) for z < 0, where float32 points have z = -1 to within an ulp (a
    correct float32 cone of cos θ_max = 0.999999 about -z failed with p = 0 until
    7 December, its points binned in the last row while the cubature spread their mass
    below it; an outside review). The hemisphere's z < 0 lies within its tolerance."""
    if z > 0.0:
        return r2 / (1.0 + z)
    if half:
        return 1.0 - z
    return 2.0 - r2 / (1.0 - z)


@njit(cache=True, inline="always")
def _locate(kind, args, tol, x, i, rejection, exact):
    """(status, s0, s1) of the point ``x[i]`` (float32 or float64; computed in float64).
    ``s1`` is φ / 2π with ``exact``, else ``_pseudo_azimuth`` (binning). With
    ``rejection``, a row of NaN is a rejected draw."""
    d = x.shape[1]
    x0 = np.float64(x[i, 0])
    x1 = np.float64(x[i, 1]) if d > 1 else 0.0
    x2 = np.float64(x[i, 2]) if d > 2 else 0.0
    # all finite <=> 0·x0 + 0·x1 + 0·x2 == 0 (0·±Inf and 0·NaN are NaN): one branch, where
    # a loop over the coordinates cost ~14 ns a point (most of a point's binning time)
    if not x0 * 0.0 + x1 * 0.0 + x2 * 0.0 == 0.0:
        n_nan = math.isnan(x0) + math.isnan(x1) + math.isnan(x2)     # absent axes are 0
        if rejection and n_nan == d:
            return REJECTED, 0.0, 0.0
        return NONFINITE, 0.0, 0.0
    if kind == INTERVAL:
        a, b = args[0], args[1]
        t = _interval_tol(tol, a, b, x)
        if x0 < a - t or x0 > b + t:
            return OUTSIDE, 0.0, 0.0
        return VALID, (x0 - a) / (b - a), 0.0
    if kind == SQUARE:
        if x0 < -tol or x0 > 1.0 + tol or x1 < -tol or x1 > 1.0 + tol:
            return OUTSIDE, 0.0, 0.0
        return VALID, x0, x1
    r2 = x0 * x0 + x1 * x1
    s1 = _azimuth(x0, x1) if exact else _pseudo_azimuth(x0, x1)
    if kind == DISK:
        if r2 > 1.0 + tol:
            return OUTSIDE, 0.0, 0.0
        return VALID, r2, s1
    # SPHERE / HEMISPHERE: unit vectors (|norm - 1| <= tol, compared squared: no root);
    # s0 = (1 - z) / span, span 2 or 1 (``_one_minus_z``).
    n2 = r2 + x2 * x2
    if n2 < (1.0 - tol) * (1.0 - tol) or n2 > (1.0 + tol) * (1.0 + tol):
        return OUTSIDE, 0.0, 0.0
    if kind == HEMISPHERE and x2 < -tol:
        return OUTSIDE, 0.0, 0.0
    w = _one_minus_z(r2, x2, kind == HEMISPHERE)
    return VALID, w if kind == HEMISPHERE else 0.5 * w, s1


@njit(**LOOP)
def _to_point_rows(kind, args, s, out, i0, i1):
    """``to_point_kernel`` for rows ``i0`` to ``i1``."""
    for i in range(i0, i1):
        s0 = s[i, 0]
        if kind == INTERVAL:
            # Within half an ulp of an end, a + (b - a)·s rounds to the end itself: on
            # Interval(1000, 1001) the cubature's nodes beside a read the pdf at a, where
            # a correct pdf may be singular (0.5 / sqrt(x - a)), and the check failed,
            # "pdf returned ... NaN/Inf values" (on Interval(0, 1), where x = s, it
            # passed; until 7 December, an outside review). Such a point rounds to the
            # end's neighbour inside instead; only s = 0 and s = 1 are the ends.
            a, b = args[0], args[1]
            x = a + (b - a) * s0
            if s0 > 0.0 and x <= a:
                x = np.nextafter(a, b)
            elif s0 < 1.0 and x >= b:
                x = np.nextafter(b, a)
            out[i, 0] = x
            continue
        s1 = s[i, 1]
        if kind == SQUARE:
            out[i, 0] = s0
            out[i, 1] = s1
            continue
        phi = 2.0 * math.pi * s1
        c, sn = math.cos(phi), math.sin(phi)
        if kind == DISK:
            r = math.sqrt(s0)
            out[i, 0] = r * c
            out[i, 1] = r * sn
            continue
        # 1 - z = span·s0, and 1 - z² = w (2 - w): no cancellation at the pole.
        w = (2.0 if kind == SPHERE else 1.0) * s0
        r = math.sqrt(max(0.0, w * (2.0 - w)))
        out[i, 0] = r * c
        out[i, 1] = r * sn
        # Within 2^-54 of the north pole 1 - w rounds to 1: the cubature's nodes and
        # corners there read the pdf at the pole itself, where a correct pdf may be
        # singular (uniform in θ: 1 / (2π² sin θ)), and the check failed with "pdf
        # returned ... NaN/Inf values" (found by an outside review). Such a point
        # rounds down to the largest double below 1 instead; only s0 = 0 is the pole.
        out[i, 2] = min(1.0 - w, _BELOW_ONE) if w > 0.0 else 1.0


def to_point_kernel(kind, args, s, out):
    """Fill ``out`` (n, dim) with the points of the parameters ``s`` (n, m): the inverse
    of ``_locate`` (one fused pass; the cubature maps millions of nodes through it)."""
    # the loop writes the kind's coordinates unchecked: a wrong kind or width would
    # write past the rows of ``out``
    if (kind not in _POINT_DIM or out.ndim != 2 or out.shape[1] < _POINT_DIM[kind]
            or s.ndim != 2 or s.shape[1] < min(2, _POINT_DIM[kind])
            or s.shape[0] > out.shape[0]):
        raise ValueError(f"to_point_kernel: kind {kind}, parameters of shape {s.shape}, "
                         f"points of shape {out.shape}")
    run_ranges(_to_point_rows, s.shape[0], kind, args, s, out, grain=_ROWS_PER_THREAD)


#: Slots of ``cell_lookup`` per cell, and how far a slot reaches past its ends: the slot
#: of ``s`` is ``int(s · slots)``, which rounding may move by one ulp of ``s · slots``.
_SLOTS_PER_CELL = 8
_SLOT_MARGIN = 2.0 ** -40


def cell_lookup(e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lookup tables for ``_find_cell`` over ``8 × cells`` uniform slots of [0, 1) (each
    widened by ``_SLOT_MARGIN`` at both ends): ``lut``, the cell holding the slot's
    widened left end; ``cut``, the one edge inside the slot (2.0 if none; -1.0 if
    several, which ``_find_cell`` then scans)."""
    e = np.asarray(e, dtype=np.float64)
    slots = _SLOTS_PER_CELL * (e.size - 1)
    j = np.arange(slots)
    lo = np.maximum(j / slots - _SLOT_MARGIN, 0.0)
    hi = (j + 1) / slots + _SLOT_MARGIN
    lut = np.searchsorted(e, lo, side="right") - 1
    inner = e[1:-1]                        # e[0] = 0 and e[-1] = 1 are never crossed
    first = np.searchsorted(inner, lo, side="right")
    count = np.searchsorted(inner, hi, side="left") - first
    cut = np.full(slots, 2.0)
    one = count == 1
    cut[one] = inner[first[one]]
    cut[count > 1] = -1.0
    return np.clip(lut, 0, e.size - 2).astype(np.int64), cut


@njit(cache=True, inline="always")
def _slot(s, slots):
    """The look-up slot of ``s`` in [0, 1) (negative ``s`` as 0): ``int(s · slots)``, the
    rule ``cell_lookup``'s margins assume; unsigned, so indexing with it takes no
    wrap-around branch for negative indices."""
    return np.uint64(min(int(max(s, 0.0) * slots), slots - 1))


@njit(cache=True, inline="always")
def _find_cell(e, lut, cut, s):
    """Index of the cell ``[e[k], e[k+1])`` holding ``s`` in [0, 1): the slot's cell,
    one further if ``s`` is past the slot's one inner edge (two independent loads and a
    compare, no search; a table look-up and a forward scan over the edges were most of a
    point's binning time). Only a slot with several edges takes the branch to a scan."""
    j = _slot(s, lut.shape[0])
    c = cut[j]
    if c >= 0.0:
        return lut[j] + (s >= c)
    k = lut[j]
    last = e.shape[0] - 2
    while k < last and s >= e[k + 1]:
        k += 1
    return k


#: Points per block of ``histogram_kernel``: one vectorised pass computes a block's
#: binning parameters into scratch (2 × 4 KB, in L1), a second bins them.
_BIN_BLOCK = 256


@njit(cache=True, inline="always")
def _clamp(s):
    return min(max(s, 0.0), _S_MAX)


@njit(cache=True, inline="always")
def _block_params(kind, args, tol, x, lo, m, s0, s1, c, exact):
    """``s0[t], s1[t]``: the clamped parameters of point ``lo + t`` (those of ``_locate``,
    ``exact`` as there: a constant where this is inlined), and ``s0[t] = -1`` where the
    point is not valid (``s1[t] = 0`` then: both parameters index tables safely).
    ``c`` (3, ``_BIN_BLOCK``) is scratch.
    The block's coordinates are first copied into the contiguous rows of ``c``, then
    branch-free loops, one per kind, which LLVM vectorises (a point's parameters and its
    status took ~5 ns one at a time, with the branches of ``_locate``; 1.9 here). Read
    straight from the rows of ``x`` (stride 2 or 3), the loops were vectorised for
    Intel's Ice Lake but not for AMD's Zen 4, whose cost model prices those strided
    loads higher: one thread, 1e6 hemisphere points, 3.9 -> 1.9 ms there."""
    d = x.shape[1]
    c0, c1, c2 = c[0], c[1 if d > 1 else 0], c[2 if d > 2 else 0]
    if d == 3:                  # one loop per width: an inner loop over d was not unrolled
        for t in range(m):
            c0[t], c1[t], c2[t] = x[lo + t, 0], x[lo + t, 1], x[lo + t, 2]
    elif d == 2:
        for t in range(m):
            c0[t], c1[t] = x[lo + t, 0], x[lo + t, 1]
    else:
        for t in range(m):
            c0[t] = x[lo + t, 0]
    if kind == INTERVAL:
        a, b = args[0], args[1]
        t_ = _interval_tol(tol, a, b, x)
        for t in range(m):
            x0 = c0[t]
            ok = (x0 * 0.0 == 0.0) & (x0 >= a - t_) & (x0 <= b + t_)
            s0[t] = _clamp((x0 - a) / (b - a)) if ok else -1.0
            s1[t] = 0.0
    elif kind == SQUARE:
        for t in range(m):
            x0, x1 = c0[t], c1[t]
            ok = ((x0 * 0.0 + x1 * 0.0 == 0.0) & (x0 >= -tol) & (x0 <= 1.0 + tol)
                  & (x1 >= -tol) & (x1 <= 1.0 + tol))
            s0[t] = _clamp(x0) if ok else -1.0
            s1[t] = _clamp(x1) if ok else 0.0
    elif kind == DISK:
        for t in range(m):
            x0, x1 = c0[t], c1[t]
            r2 = x0 * x0 + x1 * x1
            ok = (x0 * 0.0 + x1 * 0.0 == 0.0) & (r2 <= 1.0 + tol)
            s0[t] = _clamp(r2) if ok else -1.0
            phi = _azimuth(x0, x1) if exact else _pseudo_azimuth(x0, x1)
            s1[t] = _clamp(phi) if ok else 0.0
    elif kind == SPHERE or kind == HEMISPHERE:
        lo2, hi2 = (1.0 - tol) * (1.0 - tol), (1.0 + tol) * (1.0 + tol)
        half = kind == HEMISPHERE
        for t in range(m):
            x0, x1, x2 = c0[t], c1[t], c2[t]
            r2 = x0 * x0 + x1 * x1
            n2 = r2 + x2 * x2
            ok = ((x0 * 0.0 + x1 * 0.0 + x2 * 0.0 == 0.0) & (n2 >= lo2) & (n2 <= hi2)
                  & ((x2 >= -tol) | (not half)))
            w = _one_minus_z(r2, x2, half)
            s0[t] = _clamp(w if half else 0.5 * w) if ok else -1.0
            phi = _azimuth(x0, x1) if exact else _pseudo_azimuth(x0, x1)
            s1[t] = _clamp(phi) if ok else 0.0
    else:                       # no fast path: every point through ``_locate``
        for t in range(m):
            s0[t], s1[t] = -1.0, 0.0


@njit(cache=True, inline="always")
def _block_cells(s0, s1, m, lut0, cut0, lut1, cut1, n1, two, cells):
    """``cells[t]``: the flat cell of the parameters ``(s0[t], s1[t])`` by ``_find_cell``'s
    table look-up, or -1 where ``s0[t] < 0`` (not valid) or a slot holds several edges
    (left to ``_find_cell``'s scan). One branch-free loop over the block (scalar on
    Zen 4, whose cost model prices the tables' gathers high), then a counting loop that
    only adds: the look-ups no longer wait on the counts' stores (one thread,
    1e6 hemisphere points, with the parameters' copy in ``_block_params``: the
    histogram 11.8 -> 7.2 ms on Zen 4)."""
    L0, L1 = lut0.shape[0], lut1.shape[0]
    for t in range(m):
        a, b = s0[t], s1[t]     # in [0, 1); an invalid point's: -1, 0
        j0, j1 = _slot(a, L0), _slot(b, L1)
        c0, c1 = cut0[j0], cut1[j1]
        k = lut0[j0] + (a >= c0)
        if two:
            k = k * n1 + lut1[j1] + (b >= c1)
        ok = (a >= 0.0) & (c0 >= 0.0) & ((c1 >= 0.0) | (not two))
        cells[t] = k if ok else -1


@njit(cache=True)
def _point_status(kind, args, tol, x, i, rejection, exact):
    """``_locate`` of one point, as a call: inlined into ``histogram_kernel`` its
    branches kept LLVM from vectorising ``_block_params`` (5.4 against 3.0 ms for 1e6
    hemisphere points on two threads)."""
    return _locate(kind, args, tol, x, i, rejection, exact)


@njit(**LOOP)
def _to_param_blocks(kind, args, tol, x, out_s, out_status, rejection, b0, b1):
    """``to_param_kernel`` for the blocks of ``_BIN_BLOCK`` rows ``b0`` to ``b1``."""
    n = x.shape[0]
    s0 = np.empty(_BIN_BLOCK)
    s1 = np.empty(_BIN_BLOCK)
    c = np.empty((3, _BIN_BLOCK))
    for blk in range(b0, b1):
        lo = blk * _BIN_BLOCK
        m = min(_BIN_BLOCK, n - lo)
        _block_params(kind, args, tol, x, lo, m, s0, s1, c, True)
        for t in range(m):
            st, a, b = VALID, s0[t], s1[t]
            if a < 0.0:
                st, a, b = _point_status(kind, args, tol, x, lo + t, rejection, True)
                a, b = _clamp(a), _clamp(b)
            out_status[lo + t] = st
            out_s[lo + t, 0] = a
            out_s[lo + t, 1] = b


def to_param_kernel(kind, args, tol, x, out_s, out_status, rejection):
    """Fill ``out_s`` (n, 2) with clamped parameters (φ / 2π exact) and ``out_status``
    (n,) codes: ``_block_params`` a block at a time, ``_locate`` for invalid points."""
    run_ranges(_to_param_blocks, -(-x.shape[0] // _BIN_BLOCK), kind, args, tol, x, out_s,
               out_status, rejection, grain=_ROWS_PER_THREAD // _BIN_BLOCK)


@njit(**LOOP)
def _histogram_parts(kind, args, tol, x, e0, lut0, cut0, e1, lut1, cut1, param_dim, rejection,
                     part_counts, part_status, part_first, q0, q1):
    """``histogram_kernel``'s parts ``q0`` to ``q1``, each counted into its own row of
    ``part_counts``, ``part_status`` and ``part_first``."""
    n = x.shape[0]
    n1 = e1.shape[0] - 1 if param_dim == 2 else 1
    s0 = np.empty(_BIN_BLOCK)
    s1 = np.empty(_BIN_BLOCK)
    c = np.empty((3, _BIN_BLOCK))
    cells = np.empty(_BIN_BLOCK, dtype=np.int64)
    for q in range(q0, q1):
        stop = n * (q + 1) // _PARTS
        for lo in range(n * q // _PARTS, stop, _BIN_BLOCK):
            m = min(_BIN_BLOCK, stop - lo)
            _block_params(kind, args, tol, x, lo, m, s0, s1, c, False)
            _block_cells(s0, s1, m, lut0, cut0, lut1, cut1, n1, param_dim == 2, cells)
            for t in range(m):
                k = cells[t]
                if k < 0:               # not valid, or a slot with several edges
                    a, b = s0[t], s1[t]
                    if a < 0.0:
                        st, a, b = _point_status(kind, args, tol, x, lo + t, rejection,
                                                 False)
                        if st != VALID:  # valid points are counted at the end
                            part_status[q, st] += 1
                            if part_first[q, st] < 0:
                                part_first[q, st] = lo + t
                            continue
                        a, b = _clamp(a), _clamp(b)
                    k = _find_cell(e0, lut0, cut0, a)
                    if param_dim == 2:
                        k = k * n1 + _find_cell(e1, lut1, cut1, b)
                part_counts[q, k] += 1


def histogram_kernel(kind, args, tol, x, e0, lut0, cut0, e1, lut1, cut1, param_dim, rejection,
                     counts):
    """One pass over the points ``x`` (n, the domain's dim): adds each valid point to
    ``counts`` (flat, row-major cells); returns the status counts and the first index
    of each status (-1 if none). ``lut*``, ``cut*`` from ``cell_lookup``. Each block's
    parameters come from ``_block_params``; the few points it finds invalid get their
    status from ``_locate``. The rows are cut into ``_PARTS`` fixed parts, whole parts
    a thread: the sums are the same whatever the thread count."""
    n = x.shape[0]
    part_counts = np.zeros((_PARTS, counts.shape[0]), dtype=np.int64)
    part_status = np.zeros((_PARTS, N_STATUS), dtype=np.int64)
    part_first = np.full((_PARTS, N_STATUS), -1, dtype=np.int64)
    t = min(threads_for(n, _ROWS_PER_THREAD), _PARTS)
    run_split(_histogram_parts, [_PARTS * i // t for i in range(t + 1)], kind, args, tol, x,
              e0, lut0, cut0, e1, lut1, cut1, param_dim, rejection, part_counts,
              part_status, part_first)
    counts += part_counts.sum(axis=0)
    n_status = part_status.sum(axis=0)
    n_status[VALID] = n - n_status.sum()
    seen = part_first >= 0
    first = np.where(seen.any(axis=0), part_first[seen.argmax(axis=0), np.arange(N_STATUS)],
                     -1)
    return n_status, first


@njit(cache=True)
def screen_density(p, scale, out):
    """``out = p · scale`` with NaN/Inf and negative values of ``p`` set to 0, in one
    pass (the cubature calls this on every batch of pdf values); returns the counts of
    non-finite and negative values and the first index of either (-1 if none)."""
    nonfinite, negative, first = 0, 0, -1
    for i in range(p.shape[0]):
        v = p[i]
        if v * 0.0 == 0.0 and v >= 0.0:
            out[i] = v * scale
        else:
            out[i] = 0.0
            if v * 0.0 == 0.0:
                negative += 1
            else:
                nonfinite += 1
            if first < 0:
                first = i
    return nonfinite, negative, first
