"""Argument validators shared by the public functions: each raises ``InvalidArgument``
naming the parameter, the value received and what is valid, before any work is done."""

from __future__ import annotations

import numbers

import numpy as np

from .errors import InvalidArgument


def _show(v) -> str:
    r = repr(v)
    return r if len(r) <= 60 else r[:57] + "..."


def callable_(name: str, v) -> None:
    if not callable(v):
        raise InvalidArgument(f"{name}={_show(v)}: must be callable "
                              f"(got {type(v).__name__})")


def integer(name: str, v, *, minimum: int | None = None) -> int:
    if isinstance(v, bool) or not isinstance(v, numbers.Integral):
        raise InvalidArgument(f"{name}={_show(v)}: must be an integer")
    if minimum is not None and v < minimum:
        raise InvalidArgument(f"{name}={v}: must be >= {minimum}")
    return int(v)


def probability(name: str, v) -> float:
    if isinstance(v, bool) or not isinstance(v, numbers.Real) or not (0.0 < v < 1.0):
        raise InvalidArgument(f"{name}={_show(v)}: must be a number strictly between 0 and 1")
    return float(v)


def real(name: str, v, *, finite: bool = True) -> float:
    if isinstance(v, bool) or not isinstance(v, numbers.Real):
        raise InvalidArgument(f"{name}={_show(v)}: must be a real number")
    if finite and not np.isfinite(v):
        raise InvalidArgument(f"{name}={v}: must be finite")
    return float(v)


def seed(name: str, v) -> int:
    return integer(name, v, minimum=0)


def resolution(name: str, v, param_dim: int) -> tuple[int, ...] | None:
    if v is None:
        return None
    if isinstance(v, numbers.Integral) and not isinstance(v, bool):
        v = (int(v),) * param_dim
    try:
        t = tuple(v)
    except TypeError:
        raise InvalidArgument(f"{name}={_show(v)}: must be an int or a tuple of "
                              f"{param_dim} ints") from None
    if len(t) != param_dim:
        raise InvalidArgument(f"{name}={_show(v)}: this domain needs {param_dim} entries")
    if any(isinstance(r, bool) or not isinstance(r, numbers.Integral) or r < 1 for r in t):
        raise InvalidArgument(f"{name}={_show(v)}: every entry must be an integer >= 1")
    return tuple(int(r) for r in t)


def points(name: str, x, n: int, dim: int) -> np.ndarray:
    """Output of a user callable as an (n, dim) array (float32 kept, anything else as
    float64), or InvalidArgument."""
    a = np.asarray(x)
    if a.dtype == object or not (np.issubdtype(a.dtype, np.floating)
                                 or np.issubdtype(a.dtype, np.integer)):
        raise InvalidArgument(f"{name} returned dtype {a.dtype}: expected real numbers")
    if dim == 1 and a.shape == (n,):
        a = a.reshape(n, 1)
    if a.shape != (n, dim):
        raise InvalidArgument(f"{name} returned shape {a.shape}: expected ({n}, {dim})"
                              + (" or (n,)" if dim == 1 else ""))
    return a if a.dtype == np.float32 else a.astype(np.float64, copy=False)


def values(name: str, v, n: int) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    if a.shape == (n, 1):
        a = a.reshape(n)
    if a.shape != (n,):
        raise InvalidArgument(f"{name} returned shape {a.shape}: expected ({n},)")
    return a


def samples_1d(name: str, v, *, minimum: int = 2) -> np.ndarray:
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidArgument(f"{name}: must be a 1-D array of numbers") from None
    if a.ndim != 1:
        raise InvalidArgument(f"{name}: must be 1-D, got shape {a.shape}")
    if a.size < minimum:
        raise InvalidArgument(f"{name}: needs at least {minimum} values, got {a.size}")
    return a
