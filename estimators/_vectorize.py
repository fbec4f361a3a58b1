"""numpy front ends for the numba scalar kernels: one generic loop serves them all.

float32 input gives float32 output, computed in float64 and rounded once (so the two
paths agree to half a float32 ulp). A kernel takes ``(x, p)``: ``x`` an indexable point (an array row or a tuple), ``p`` an
indexable of parameters, and returns a tuple (a point) or a float (a density). The
path tracer calls the same kernels on tuples, so each warp has one implementation.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=False)
def _apply_point_kernel(kernel, x, p, n_out):
    n = x.shape[0]
    out = np.empty((n, n_out), dtype=x.dtype)
    for i in range(n):
        r = kernel(x[i], p)
        for j in range(n_out):
            out[i, j] = r[j]
    return out


@njit(cache=False)
def _apply_value_kernel(kernel, x, p):
    n = x.shape[0]
    out = np.empty(n, dtype=x.dtype)
    for i in range(n):
        out[i] = kernel(x[i], p)
    return out


def as_rows(name: str, x, n_in: int) -> np.ndarray:
    """``x`` as a C-contiguous (n, n_in) float64 array (1-D accepted when n_in is 1)."""
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 1 and n_in == 1:
        a = a.reshape(-1, 1)
    if a.ndim != 2 or a.shape[1] != n_in:
        raise ValueError(f"{name}: expected an array of shape (n, {n_in}), got {a.shape}")
    return np.ascontiguousarray(a)


def params_array(params) -> np.ndarray:
    return np.asarray(params, dtype=np.float64).reshape(-1) if len(params) else np.zeros(1)


def point_front_end(kernel, n_in: int, n_out: int, name: str, doc: str = ""):
    """Array function ``f(x, *params) -> (n, n_out)`` around a point kernel."""

    def front(x, *params):
        rows = as_rows(name, x, n_in)
        out = _apply_point_kernel(kernel, rows, params_array(params), n_out)
        return out.astype(np.float32) if np.asarray(x).dtype == np.float32 else out

    front.__name__ = front.__qualname__ = name
    front.__doc__ = doc
    front.kernel = kernel
    return front


def value_front_end(kernel, n_in: int, name: str, doc: str = ""):
    """Array function ``f(x, *params) -> (n,)`` around a density kernel."""

    def front(x, *params):
        rows = as_rows(name, x, n_in)
        out = _apply_value_kernel(kernel, rows, params_array(params))
        return out.astype(np.float32) if np.asarray(x).dtype == np.float32 else out

    front.__name__ = front.__qualname__ = name
    front.__doc__ = doc
    front.kernel = kernel
    return front
