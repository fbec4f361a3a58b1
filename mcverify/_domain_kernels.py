"""numba kernels behind the domains: map a point to parameter space, screen it, bin it.

One pass per sample replaces several numpy passes over 1e6 points (finite?, inside?,
to parameters, bin along each axis). Domains are identified by a small integer
``kind`` with float parameters ``args``; ``domains.py`` holds the numpy front ends.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

INTERVAL, SQUARE, DISK, SPHERE, HEMISPHERE = 0, 1, 2, 3, 4
#: Status codes of ``classify``: a valid point, a NaN/Inf coordinate, outside the domain.
VALID, NONFINITE, OUTSIDE = 0, 1, 2
_S_MAX = 1.0 - 2.0 ** -52
_INV_TWO_PI = 1.0 / (2.0 * math.pi)


@njit(cache=True)
def _azimuth(x, y):
    phi = math.atan2(y, x)
    if phi < 0.0:
        phi += 2.0 * math.pi
    return phi * _INV_TWO_PI


@njit(cache=True)
def _classify_kernel(kind, args, tol, x):
    """(status, s0, s1) of one point ``x``."""
    for j in range(x.shape[0]):
        if not math.isfinite(x[j]):
            return NONFINITE, 0.0, 0.0
    if kind == INTERVAL:
        a, b = args[0], args[1]
        t = tol * (b - a)
        if x[0] < a - t or x[0] > b + t:
            return OUTSIDE, 0.0, 0.0
        return VALID, (x[0] - a) / (b - a), 0.0
    if kind == SQUARE:
        if x[0] < -tol or x[0] > 1.0 + tol or x[1] < -tol or x[1] > 1.0 + tol:
            return OUTSIDE, 0.0, 0.0
        return VALID, x[0], x[1]
    if kind == DISK:
        r2 = x[0] * x[0] + x[1] * x[1]
        if r2 > 1.0 + tol:
            return OUTSIDE, 0.0, 0.0
        return VALID, r2, _azimuth(x[0], x[1])
    # SPHERE / HEMISPHERE: unit vectors; s0 = (1 - z) / span, span 2 or 1.
    norm = math.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2])
    if abs(norm - 1.0) > tol:
        return OUTSIDE, 0.0, 0.0
    if kind == HEMISPHERE:
        if x[2] < -tol:
            return OUTSIDE, 0.0, 0.0
        return VALID, 1.0 - x[2], _azimuth(x[0], x[1])
    return VALID, 0.5 * (1.0 - x[2]), _azimuth(x[0], x[1])


@njit(cache=True, parallel=True)
def to_param_kernel(kind, args, tol, x, out_s, out_status):
    """Fill ``out_s`` (n, 2) with clamped parameters and ``out_status`` (n,) codes."""
    for i in prange(x.shape[0]):
        st, s0, s1 = _classify_kernel(kind, args, tol, x[i])
        out_status[i] = st
        out_s[i, 0] = min(max(s0, 0.0), _S_MAX)
        out_s[i, 1] = min(max(s1, 0.0), _S_MAX)


def cell_lookup(e: np.ndarray) -> np.ndarray:
    """Lookup table for ``_find_cell``: for each of ``8 × cells`` uniform slots of [0, 1),
    the cell holding the slot's left end."""
    slots = 8 * (e.size - 1)
    return (np.searchsorted(e, np.arange(slots) / slots, side="right") - 1).astype(np.int64)


@njit(cache=True)
def _find_cell(e, lut, s):
    """Index of the cell ``[e[k], e[k+1])`` holding ``s``: the table gives the cell of
    the slot's left end, a short forward scan passes edges inside the slot (no
    data-dependent branches of a binary search to mispredict)."""
    k = lut[min(int(s * lut.shape[0]), lut.shape[0] - 1)]
    last = e.shape[0] - 2
    while k < last and s >= e[k + 1]:
        k += 1
    return k


@njit(cache=True)
def histogram_kernel(kind, args, tol, x, e0, lut0, e1, lut1, param_dim):
    """One pass: counts per cell (flat, row-major), status counts, first bad index of
    each status (-1 if none). ``lut*`` from ``cell_lookup``."""
    n0 = e0.shape[0] - 1
    n1 = e1.shape[0] - 1 if param_dim == 2 else 1
    counts = np.zeros(n0 * n1, dtype=np.int64)
    n_status = np.zeros(3, dtype=np.int64)
    first = np.full(3, -1, dtype=np.int64)
    for i in range(x.shape[0]):
        st, s0, s1 = _classify_kernel(kind, args, tol, x[i])
        n_status[st] += 1
        if st != VALID:
            if first[st] < 0:
                first[st] = i
            continue
        s0 = min(max(s0, 0.0), _S_MAX)
        k = _find_cell(e0, lut0, s0)
        if param_dim == 2:
            k = k * n1 + _find_cell(e1, lut1, min(max(s1, 0.0), _S_MAX))
        counts[k] += 1
    return counts, n_status, first
