"""Sampling by CDF inversion (the seed's inversion method): ``X = P⁻¹(ξ)``.

- ``DiscreteDistribution``: a CDF table and binary search; the chosen index, its
  probability, and ``ξ`` remapped to [0, 1) for reuse.
- ``PiecewiseConstant1D`` / ``PiecewiseConstant2D``: piecewise-constant densities
  (marginal + conditional in 2-D, as for environment maps), with sample, pdf, invert.
- ``InvertedCDF``: any user pdf on [a, b]: the CDF is tabulated by adaptive quadrature
  with error control, and inverted by Newton's method safeguarded by bisection.

The piecewise-constant kernels are numba scalar functions; the ones the path tracer
calls directly are public (``sample_discrete_kernel``, ``sample_pc2d_kernel``,
``pc2d_pdf_kernel``); the classes are their numpy front ends.

References: M. Pharr, W. Jakob, G. Humphreys, *Physically Based Rendering*, 4th ed.,
§A.4 (sampling 1-D functions, piecewise-constant 2-D distributions).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np

from ._compile_options import exact
from .warps import ONE_MINUS_EPSILON

__all__ = ["DiscreteDistribution", "PiecewiseConstant1D", "PiecewiseConstant2D", "InvertedCDF"]

# The scalar kernels (the path tracer calls them per ray) skip reference counting: they
# allocate nothing, and a row of a 2-D table taken as a view (``conditional[row]``) cost
# an atomic increment and decrement of the table's count per call, shared by every
# thread: sampling an envmap's 2-D table took 87 ns a call with them, 50 without (one
# thread; ``benchmarks/perf_tracer.py envmap`` had put the 1-D sampler at 19 % of the
# kernel's time). IEEE arithmetic whoever calls first (``_compile_options``).
_scalar = exact(_nrt=False)


def _reals(values, name: str) -> np.ndarray:
    """``values`` as float64, or a ValueError naming ``name`` (complex numbers, strings,
    objects and ragged lists gave numpy's or Python's message, naming nothing)."""
    try:
        a = np.asarray(values)
    except ValueError as e:
        raise ValueError(f"{name}: not an array of numbers ({e})") from None
    if a.dtype.kind not in "biuf":
        raise ValueError(f"{name}: expected real numbers, got an array of {a.dtype}")
    return a.astype(np.float64)


def _finite_nonnegative(w: np.ndarray, name: str) -> None:
    """A ValueError naming ``w``'s first entry that is NaN, infinite or negative, by its
    index (a row and column in 2-D), and its value: "entries must be finite and >= 0"
    alone left a user to search a 4096 × 2048 environment map for its one NaN pixel."""
    bad = ~(np.isfinite(w) & (w >= 0))
    if bad.any():
        at = np.unravel_index(int(np.argmax(bad)), w.shape)
        where = at[0] if len(at) == 1 else tuple(int(i) for i in at)
        raise ValueError(f"{name}: entry {where} is {float(w[at])!r}; entries must be "
                         "finite and >= 0")


def _cdf_of(weights: np.ndarray, name: str) -> tuple[np.ndarray, float]:
    w = _reals(weights, name)
    if w.ndim != 1 or w.size == 0:
        raise ValueError(f"{name}: expected a non-empty 1-D array, got shape {w.shape}")
    _finite_nonnegative(w, name)
    with np.errstate(over="ignore"):
        cdf = np.concatenate([[0.0], np.cumsum(w)])
    total = norm = cdf[-1]
    if np.isinf(norm):             # finite weights whose sum overflows: scale them first
        scale = w.max()
        cdf = np.concatenate([[0.0], np.cumsum(w / scale)])
        norm = cdf[-1]
        with np.errstate(over="ignore"):
            total = norm * scale   # the sum itself is beyond float64: inf
    if norm > 0:
        cdf /= norm
    else:  # all zero: sample uniformly, as pbrt does
        cdf = np.linspace(0.0, 1.0, w.size + 1)
    cdf[-1] = 1.0
    return cdf, float(total)


def _table_integral(values: np.ndarray, total: float, width: float = 1.0) -> float:
    """∫ of a table's piecewise-constant density over a domain of ``width``: the mean of
    the (finite, non-negative) ``values``, their sum ``total`` over their count, times
    ``width``; the mean taken of values / max, times max, where the sum overflows. One
    rule for ``PiecewiseConstant1D`` and ``PiecewiseConstant2D``."""
    with np.errstate(over="ignore"):
        integral = total * width / values.size
        if np.isfinite(integral):
            return float(integral)
        m = float(values.max())
        return float(np.mean(values / m)) * m * width


@exact(inline="always")
def _search(cdf, u, lo, hi):
    """Largest i in [lo, hi] with cdf[i] <= u (lo if none): a binary search."""
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if cdf[mid] <= u:
            lo = mid
        else:
            hi = mid - 1
    return lo


@_scalar
def _find_interval_kernel(cdf, u):
    """Largest i with cdf[i] <= u, clamped to [0, len(cdf) - 2]; skips zero-width
    intervals so a zero-probability entry is never chosen."""
    return _search(cdf, u, 0, cdf.shape[0] - 2)


@_scalar
def sample_discrete_kernel(cdf, u):
    """(index, probability, remapped u in [0, 1))."""
    i = _find_interval_kernel(cdf, u)
    p, r = _remap(cdf, i, u)
    return i, p, r


@exact(inline="always")
def _remap(cdf, i, u):
    """(probability of entry i, u remapped to [0, 1) within it)."""
    p = cdf[i + 1] - cdf[i]
    r = (u - cdf[i]) / p if p > 0 else 0.0
    return p, min(max(r, 0.0), ONE_MINUS_EPSILON)


def _cdf_rows(v: np.ndarray) -> np.ndarray:
    """``_cdf_of(row)[0]`` for every row of ``v`` (finite, >= 0) at once, bit for bit:
    numpy's cumsum along a row adds in the same order as over a 1-D array. A Python
    loop over rows took 25 s for a (10⁶, 1) image."""
    h, w = v.shape
    cdf = np.zeros((h, w + 1))
    with np.errstate(over="ignore"):
        np.cumsum(v, axis=1, out=cdf[:, 1:])
    norm = cdf[:, -1].copy()
    over = np.isinf(norm)          # rows whose sum overflows: the row over its maximum
    if over.any():
        vo = v[over]
        cdf[over, 1:] = np.cumsum(vo / vo.max(axis=1, keepdims=True), axis=1)
        norm[over] = cdf[over, -1]
    pos = norm > 0
    cdf[pos] /= norm[pos, None]
    cdf[~pos] = np.linspace(0.0, 1.0, w + 1)     # all zero: uniform, as _cdf_of
    cdf[:, -1] = 1.0
    return cdf


@exact()
def _guides_kernel(cdfs, guides):
    """Each row's guide as ``_guided`` computes it (the largest i with cdf[i] <= g / n,
    clipped to [0, n - 1]), in one merge-like pass a row."""
    n = cdfs.shape[1] - 1
    for r in range(cdfs.shape[0]):
        i = 0
        for g in range(n):
            t = g / n
            while i + 1 <= n and cdfs[r, i + 1] <= t:
                i += 1
            guides[r, g] = min(i, n - 1)


def _guided_rows(cdfs: np.ndarray) -> np.ndarray:
    """``_guided`` of each row of ``cdfs`` (h, n + 1): (h, 2n + 1)."""
    n = cdfs.shape[1] - 1
    out = np.empty((cdfs.shape[0], 2 * n + 1))
    out[:, :n + 1] = cdfs
    _guides_kernel(cdfs, out[:, n + 1:])
    return out


def _guided(cdf: np.ndarray) -> np.ndarray:
    """A piecewise-constant density's table: its CDF over n pieces (n + 1 values)
    followed by a guide of n entries, ``guide[g]`` the piece that ``u = g / n`` falls in
    (as ``_find_interval_kernel`` finds it), stored as floats so that the table is one
    array. The guide narrows a sample's search to the pieces between ``guide[g - 2]``
    and ``guide[g + 2]``: one or two steps where a whole binary search took ~10
    dependent loads (an envmap's two searches were 14 % of a render's time)."""
    n = cdf.size - 1
    guide = np.clip(np.searchsorted(cdf, np.arange(n) / n, side="right") - 1, 0, n - 1)
    return np.concatenate([cdf, guide.astype(np.float64)])


@exact(inline="always")
def _pieces(table):
    return (table.shape[0] - 1) // 2


@_scalar
def _find_piece_kernel(table, u):
    """``_find_interval_kernel`` on a table's CDF, searching only where the guide says:
    the same piece for every u. ``g = int(u·n)`` is ``floor(u·n)`` or one above (the
    product's rounding), and ``g / n`` may round either way, so the guide entries two
    cells either side bracket the piece."""
    n = _pieces(table)
    if not u >= 0.0:                         # below the CDF (or NaN): piece 0, as before
        return 0
    if not u < 1.0:                          # at or past the end (u·n may overflow int)
        return _search(table, u, int(table[2 * n]), n - 1)
    g = min(int(u * n), n - 1)
    lo = int(table[n + 1 + max(g - 2, 0)])
    hi = int(table[n + 1 + g + 2]) if g + 2 < n else n - 1
    return _search(table, u, lo, hi)


@_scalar
def _sample_pc1d_kernel(table, u):
    """Piecewise-constant density on [0, 1] with n pieces: (x, pdf, piece)."""
    n = _pieces(table)
    if u != u:       # NaN: no piece (it read as u = 0: x = 0, density 0 after a zero piece)
        return u, 0.0, 0
    # u outside [0, 1) as its nearest end: u = 1 found the last piece even where it has
    # no weight (x of density 0)
    u = min(max(u, 0.0), ONE_MINUS_EPSILON)
    i = _find_piece_kernel(table, u)
    p, r = _remap(table, i, u)
    x = min((i + r) / n, ONE_MINUS_EPSILON)
    # x must lie in piece i as the pdf finds it (int(x·n)): (i + 0) / n times n rounds
    # to just below i for some i and n (u = 0 after zero-weight pieces: x was given
    # density 0 at 3258 of the 79,401 first positive pieces of n < 400), and i + r with
    # r near 1 rounds up to i + 1
    while min(int(x * n), n - 1) < i:
        x = np.nextafter(x, 2.0)
    while int(x * n) > i:
        x = np.nextafter(x, -1.0)
    return x, p * n, i


@_scalar
def _pc1d_pdf_kernel(table, x):
    n = _pieces(table)
    if not (x >= 0.0 and x <= 1.0):          # outside, or NaN (no index from it)
        return 0.0
    i = min(int(x * n), n - 1)
    return (table[i + 1] - table[i]) * n


@_scalar
def _invert_pc1d_kernel(table, x):
    n = _pieces(table)
    x = min(max(x, 0.0), 1.0) if x == x else x       # int(x·n) of a huge x overflows
    i = min(max(int(x * n), 0), n - 1)
    t = x * n - i
    return min(max(table[i] + t * (table[i + 1] - table[i]), 0.0), ONE_MINUS_EPSILON)


@_scalar
def sample_pc2d_kernel(marginal, conditional, u0, u1):
    """Piecewise-constant density on [0, 1]² ((ny, nx) pieces; ``marginal`` and each
    row of ``conditional`` a table of ``_guided``): pick the row y from the marginal
    with u1, then x within the row with u0. Returns (x, y, pdf)."""
    y, py, row = _sample_pc1d_kernel(marginal, u1)
    x, px, _ = _sample_pc1d_kernel(conditional[row], u0)
    return x, y, px * py


@_scalar
def pc2d_pdf_kernel(marginal, conditional, x, y):
    if not (x >= 0.0 and x <= 1.0 and y >= 0.0 and y <= 1.0):     # NaN included
        return 0.0
    ny = _pieces(marginal)
    row = min(int(y * ny), ny - 1)
    return _pc1d_pdf_kernel(marginal, y) * _pc1d_pdf_kernel(conditional[row], x)


@_scalar
def _invert_pc2d_kernel(marginal, conditional, x, y):
    ny = _pieces(marginal)
    row = min(max(int(min(max(y, 0.0), 1.0) * ny), 0), ny - 1)
    return _invert_pc1d_kernel(conditional[row], x), _invert_pc1d_kernel(marginal, y)


@exact()
def _pc1d_batch_kernel(table, u, mode):
    """mode 0: sample u -> (x, pdf); 1: pdf(x); 2: invert x -> u."""
    out = np.empty((u.shape[0], 2))
    for i in range(u.shape[0]):
        if mode == 0:
            x, p, _ = _sample_pc1d_kernel(table, u[i])
            out[i, 0], out[i, 1] = x, p
        elif mode == 1:
            out[i, 0] = _pc1d_pdf_kernel(table, u[i])
        else:
            out[i, 0] = _invert_pc1d_kernel(table, u[i])
    return out


@exact()
def _pc2d_batch_kernel(mcdf, ccdf, pts, mode):
    """mode 0: sample u -> (x, y, pdf); 1: pdf(x, y); 2: invert (x, y) -> u."""
    out = np.empty((pts.shape[0], 3))
    for i in range(pts.shape[0]):
        a, b = pts[i, 0], pts[i, 1]
        if mode == 0:
            out[i, 0], out[i, 1], out[i, 2] = sample_pc2d_kernel(mcdf, ccdf, a, b)
        elif mode == 1:
            out[i, 0] = pc2d_pdf_kernel(mcdf, ccdf, a, b)
        else:
            out[i, 0], out[i, 1] = _invert_pc2d_kernel(mcdf, ccdf, a, b)
    return out


def _interval(who: str, a, b) -> tuple[float, float]:
    """``a``, ``b`` as floats: real numbers with a < b and b - a finite and at least
    2^-1022 (a string or None raised numpy's TypeError from isfinite, naming nothing;
    -1e308 to 1e308 gave InvertedCDF NaN nodes, blamed on the pdf; a width of 5e-324 a
    density of inf)."""
    for label, v in (("a", a), ("b", b)):
        if isinstance(v, np.ndarray) and v.ndim == 0:
            v = v[()]
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Real):
            raise ValueError(f"{who}(a={a!r:.40}, b={b!r:.40}): {label} must be a real number")
    a, b = float(a), float(b)
    with np.errstate(over="ignore"):
        width = b - a
    if not (np.isfinite(a) and np.isfinite(b) and b > a and np.isfinite(width)
            and width >= 2.0 ** -1022):
        raise ValueError(f"{who}(a={a}, b={b}): need finite a < b with b - a finite and at "
                         "least 2^-1022")
    return a, b


def _unit(u, name="u") -> np.ndarray:
    """A 1-D distribution's points as (n,): (n,), (n, 1) or a scalar; any other shape is
    refused (an (n, 2) array was flattened into 2n points), and so are numbers that are
    not real (strings and complex numbers raised numpy's or Python's message)."""
    a = _reals(u, name)
    if a.ndim > 2 or (a.ndim == 2 and a.shape[1] != 1):
        raise ValueError(f"{name}: expected shape (n,) or (n, 1), got {a.shape}")
    return np.ascontiguousarray(a.reshape(-1))


def _nan_where_nan(x, values) -> np.ndarray:
    """``values`` (n,) with NaN in each row where a coordinate of ``x`` ((n,) or (n, d))
    is NaN: a NaN point has a NaN density and a NaN u a NaN sample, as in the warps,
    rather than the 0 or the table's end that a search makes of it."""
    bad = np.isnan(x) if x.ndim == 1 else np.isnan(x).any(axis=1)
    return np.where(bad, np.nan, values)


def _nan_rows(x, values) -> np.ndarray:
    """``values`` (n, k) with every column NaN in each row where a coordinate of ``x``
    (n, d) is NaN: half a NaN input no longer gives half a point."""
    return np.where(np.isnan(x).any(axis=1)[:, None], np.nan, values)


def _pairs(u, name="u") -> np.ndarray:
    """A 2-D distribution's points as (n, 2): (n, 2) or one pair (2,); any other shape
    is refused ((4, 3) was read as six pairs, (4,) as two), and so are numbers that are
    not real."""
    a = _reals(u, name)
    if a.shape == (2,):
        a = a.reshape(1, 2)
    if a.ndim != 2 or a.shape[1] != 2:
        raise ValueError(f"{name}: expected shape (n, 2), got {a.shape}")
    return np.ascontiguousarray(a)


class DiscreteDistribution:
    """Discrete distribution over ``0 .. n-1`` with probabilities ∝ ``weights``."""

    def __init__(self, weights):
        self.cdf, self.total = _cdf_of(weights, "weights")

    @property
    def pmf(self) -> np.ndarray:
        return np.diff(self.cdf)

    def sample(self, u):
        """``u`` (n,) -> (index (n,), probability (n,), u remapped to [0, 1) (n,))."""
        u = _unit(u)
        if np.isnan(u).any():
            raise ValueError(f"u: NaN at index {int(np.argmax(np.isnan(u)))} (an index "
                             "cannot carry it)")
        # u outside [0, 1) as its nearest end. Zero-probability entries have zero-width
        # CDF steps: searchsorted(right) never lands on them for u < 1 (u = 1 chose the
        # last entry even where its weight is 0)
        u = np.clip(u, 0.0, ONE_MINUS_EPSILON)
        i = np.clip(np.searchsorted(self.cdf, u, side="right") - 1, 0, self.cdf.size - 2)
        p = self.cdf[i + 1] - self.cdf[i]
        r = np.where(p > 0, (u - self.cdf[i]) / np.where(p > 0, p, 1), 0.0)
        return i, p, np.clip(r, 0.0, ONE_MINUS_EPSILON)

    def invert(self, index, u_remapped):
        """Inverse of ``sample``: (index, remapped u) -> u. ``index`` holds integers
        (a float 0.7 was read as entry 0), ``u_remapped`` numbers in [0, 1]; the two
        arrays have one shape (or one of them is a single value)."""
        idx = _reals(index, "index")
        if not np.all(np.isfinite(idx) & (idx == np.floor(idx))):
            bad = idx.ravel()[np.argmax(~(np.isfinite(idx) & (idx == np.floor(idx))).ravel())]
            raise ValueError(f"index: {float(bad)!r} is not an integer (an entry of the "
                             "distribution)")
        # the range is checked before the cast: 1e300 became -2^63 in int64, and the
        # message named that number, not the index given
        n = self.cdf.size - 1
        outside = (idx.ravel() < 0) | (idx.ravel() >= n)
        if outside.any():
            bad = float(idx.ravel()[np.argmax(outside)])
            bad = int(bad) if abs(bad) < 2.0 ** 53 else bad
            raise ValueError(f"index: {bad!r} is not an entry of the distribution (0 to "
                             f"{n - 1}); -1 wrapped to the last one before")
        index = idx.astype(np.int64)
        u_remapped = _reals(u_remapped, "u_remapped")
        try:
            index, u_remapped = np.broadcast_arrays(index, u_remapped)
        except ValueError:
            raise ValueError(f"index (shape {index.shape}) and u_remapped (shape "
                             f"{u_remapped.shape}): expected one shape") from None
        outside = (u_remapped < 0) | (u_remapped > 1)          # NaN: neither, stays NaN
        if outside.any():
            # cdf[i] + 1.5 p_i is a u of another entry, which sample maps to that entry
            bad = u_remapped.ravel()[np.argmax(outside.ravel())]
            raise ValueError(f"u_remapped: {float(bad)!r} is outside [0, 1] (what sample "
                             "returns is in [0, 1)); it gave a u of another entry")
        return np.clip(self.cdf[index] + u_remapped * self.pmf[index], 0.0,
                       ONE_MINUS_EPSILON)


class PiecewiseConstant1D:
    """Density on [a, b] proportional to ``values`` on n equal pieces (|values| are used,
    as pbrt does for signed functions)."""

    def __init__(self, values, a: float = 0.0, b: float = 1.0):
        a, b = _interval("PiecewiseConstant1D", a, b)
        self.values = np.abs(_reals(values, "values"))
        self.cdf, total = _cdf_of(self.values, "values")
        self.table = _guided(self.cdf)        # what the kernels read
        self.a, self.b = float(a), float(b)
        #: ∫ |f| over [a, b] (the normalisation of the density): the mean of |values|
        #: times b - a, the mean taken of values / max where their sum overflows.
        self.integral = _table_integral(self.values, total, b - a)

    def sample(self, u):
        """``u`` (n,) or (n, 1) -> points (n, 1) on [a, b], each in the piece the kernel
        drew it from as ``pdf`` finds it."""
        r = _pc1d_batch_kernel(self.table, _unit(u), 0)[:, 0]
        x = self.a + (self.b - self.a) * r
        if (self.a, self.b) != (0.0, 1.0):
            x = self._in_piece(x, r)
        return x.reshape(-1, 1)

    def _in_piece(self, x, r):
        """``x`` moved by ulps into the piece of ``r`` (the kernel's unit-interval point)
        as ``pdf`` finds it from (x - a) / (b - a): the affine map's rounding put a point
        drawn at the start of a piece after zero-weight pieces one ulp into the last of
        them, of density 0 (an outside review: 4-10 % of u on the CDF's steps, u = 0
        among them, on intervals other than [0, 1]). 64 ulps of x first, then 64 of the
        larger bound: the map's rounding is an ulp of a or b, thousands of x's own ulps
        where a piece starts near 0 (on [-3, 0.6] with 18 pieces the 16th starts at 0,
        and u = 0 after 15 zero-weight pieces was left at x = 3e-322, of density 0).
        Steps of fixed size: steps that doubled ran to inf where pieces are narrower
        than an ulp of x ([1e15, 1e15 + 1] in 1000 pieces), which the fixed ones only
        straddle."""
        n = self.values.size
        drawn = np.isfinite(r)
        i = np.minimum((np.where(drawn, r, 0.0) * n).astype(np.int64), n - 1)
        coarse = float(np.spacing(max(abs(self.a), abs(self.b))))
        for k in range(128):
            t = np.clip(np.where(drawn, (x - self.a) / (self.b - self.a), 0.0), 0.0, 1.0)
            j = np.minimum((t * n).astype(np.int64), n - 1)
            low, high = drawn & (j < i), drawn & (j > i)
            if not (low.any() or high.any()):
                break
            if k < 64:
                x = np.where(low, np.nextafter(x, np.inf),
                             np.where(high, np.nextafter(x, -np.inf), x))
            else:
                x = np.where(low, x + coarse, np.where(high, x - coarse, x))
        return np.clip(x, self.a, self.b)

    def pdf(self, x):
        """Density at points (n,) or (n, 1); 0 outside [a, b], tested on x itself: the
        map (x - a) / (b - a) rounds an ulp beyond b to 1 (b = 0.6 with a = -3), which
        was given the last piece's density."""
        x = _unit(x, "x")
        t = (x - self.a) / (self.b - self.a)
        p = _pc1d_batch_kernel(self.table, t, 1)[:, 0] / (self.b - self.a)
        return _nan_where_nan(t, np.where((x < self.a) | (x > self.b), 0.0, p))

    def invert(self, x):
        t = (_unit(x, "x") - self.a) / (self.b - self.a)
        return _pc1d_batch_kernel(self.table, t, 2)[:, :1]


class PiecewiseConstant2D:
    """Density on [0, 1]² proportional to ``values[row, col]`` (rows along y): the
    marginal over rows and one conditional per row."""

    def __init__(self, values):
        v = np.abs(_reals(values, "values"))
        if v.ndim != 2 or 0 in v.shape:
            raise ValueError(f"values: expected a non-empty 2-D array, got shape {v.shape}")
        _finite_nonnegative(v, "values")      # by its pixel, not the sum of its row
        self.values = v
        with np.errstate(over="ignore"):
            rows = v.sum(axis=1)
        # finite values whose row sums overflow: the rows of v / max(v) (the CDFs do not
        # depend on the scale)
        scale = v.max() if np.all(np.isfinite(v)) and not np.all(np.isfinite(rows)) else 1.0
        self.marginal_cdf, total = _cdf_of(rows if scale == 1.0 else (v / scale).sum(axis=1),
                                           "values")
        self.conditional_cdf = _cdf_rows(v)
        # what the kernels (and the path tracer's envmap) read: each CDF with its guide
        self.marginal_table = _guided(self.marginal_cdf)
        self.conditional_table = _guided_rows(self.conditional_cdf)
        # the mean of |values|: of values / max, times max, where their sum overflows
        # (rows of finite sums whose total overflows too: (2, 1) of 1e308 gave inf)
        with np.errstate(over="ignore"):
            self.integral = _table_integral(v, total * scale)

    def sample(self, u):
        """``u`` (n, 2) -> points (n, 2) = (x, y); a NaN in either coordinate of a u gives
        (NaN, NaN) (a NaN u1 had drawn x from row 0: a finite x beside a NaN y)."""
        u = _pairs(u)
        return _nan_rows(u, _pc2d_batch_kernel(self.marginal_table, self.conditional_table,
                                               u, 0)[:, :2])

    def pdf(self, x):
        x = _pairs(x, "x")
        return _nan_where_nan(x, _pc2d_batch_kernel(self.marginal_table,
                                                    self.conditional_table, x, 1)[:, 0])

    def invert(self, x):
        """Points (n, 2) -> u (n, 2); a point with a NaN coordinate gives (NaN, NaN)."""
        x = _pairs(x, "x")
        return _nan_rows(x, _pc2d_batch_kernel(self.marginal_table, self.conditional_table,
                                               x, 2)[:, :2])


@dataclass(frozen=True)
class _Table:
    knots: np.ndarray
    cdf: np.ndarray        # normalised CDF at the knots
    error: float           # bound on the CDF error (sum of quadrature error estimates)


def _gl01(order):
    x, w = np.polynomial.legendre.leggauss(order)
    return 0.5 * (x + 1.0), 0.5 * w


_GL_X, _GL_W = _gl01(10)
#: Most pieces an InvertedCDF table refines to before it gives up (refusing the pdf).
_MAX_PIECES = 1_000_000
_GL20_X, _GL20_W = _gl01(20)


class InvertedCDF:
    """Sample any pdf on [a, b] by inverting its numerically integrated CDF.

    Parameters
    ----------
    pdf : callable
        Vectorised ``pdf(x: (n,)) -> (n,)`` (that shape, real numbers), non-negative;
        need not be normalised.
    a, b : float
        Finite support.
    pieces : int
        Initial CDF table pieces; pieces are halved until 10- and 20-point
        Gauss–Legendre agree to ``tol`` (relative to the total, shared by length) and
        no endpoint value hides a step or tail the nodes missed.
    tol : float
        Relative tolerance of the tabulated CDF; ``cdf_error`` reports what was
        achieved (the sum of |GL10 − GL20| over pieces, relative to the total).
    max_rounds : int
        Rounds of halving at most; a CDF still above ``tol`` after them is refused,
        naming ``max_rounds`` (the default always ends: pieces stop at 1e-13 of the
        interval).

    Notes
    -----
    Sampling solves ``F(x) = ξ`` in the piece located by binary search on the table:
    ``F(x) = F(x_k) + ∫_{x_k}^x p``, the integral by 10-point Gauss–Legendre, with
    Newton steps ``x ← x − (F(x) − ξ)/p(x)`` kept inside a shrinking bisection
    bracket, so it converges even where p vanishes or jumps.

    Examples
    --------
    >>> import numpy as np
    >>> d = InvertedCDF(np.sin, 0.0, np.pi)          # p(x) = sin(x) / 2
    >>> x = d.sample(np.array([0.5]))
    >>> bool(np.isclose(x[0, 0], np.pi / 2))          # the median
    True
    """

    def __init__(self, pdf, a: float, b: float, *, pieces: int = 256, tol: float = 1e-10,
                 max_rounds: int = 60):
        if not callable(pdf):
            raise ValueError(f"pdf={pdf!r}: must be callable")
        a, b = _interval("InvertedCDF", a, b)
        for label, v in (("pieces", pieces), ("max_rounds", max_rounds)):
            if isinstance(v, bool) or not isinstance(v, numbers.Integral) or v < 1:
                raise ValueError(f"{label}={v!r}: must be an integer >= 1")
        if pieces > _MAX_PIECES:     # was refused as "did not converge", after the work
            raise ValueError(f"pieces={pieces}: at most {_MAX_PIECES:,} (the table's "
                             "limit; pieces are refined from there as the pdf needs)")
        if isinstance(tol, bool) or not isinstance(tol, numbers.Real) or not 0 < tol < 1:
            raise ValueError(f"tol={tol!r}: must be a number in (0, 1)")
        if tol < 1e-15:              # ran for seconds, then called the pdf not integrable
            raise ValueError(f"tol={tol!r}: below 1e-15 the rules' own rounding (about "
                             "1e-16 of the total) is above it: use tol >= 1e-15")
        self._f = pdf
        self._coarse = None
        self.a, self.b = float(a), float(b)
        self.total = 1.0
        lo = np.linspace(self.a, self.b, pieces + 1)
        hi, lo = lo[1:], lo[:-1]
        done_lo, done_hi, done_m, done_e = [], [], [], []
        scale, accepted, peak = 1e-300, 0.0, 0.0
        for _ in range(max_rounds):
            if lo.size > _MAX_PIECES:
                self._refuse_coarse(tol, f"did not converge within {_MAX_PIECES:,} pieces")
                raise ValueError(f"pdf: its CDF on [{self.a}, {self.b}] did not converge to "
                                 f"tol={tol} within {_MAX_PIECES:,} pieces (a pdf that is "
                                 "not integrable, or a feature narrower than 1e-13 of the "
                                 "interval)")
            m10, m20, fmin, fmax = self._piece_rules(lo, hi)
            peak = max(peak, float(fmax.max()))
            with np.errstate(over="ignore"):
                found = accepted + float(m20.sum())
            if not math.isfinite(found):
                # a pdf of finite values whose integral is beyond float64 (1e308 on
                # [0, 100]): the CDF table was NaN, and sample returned any point
                raise ValueError(f"pdf: its integral over [{self.a}, {self.b}] overflows "
                                 f"float64 (values up to {float(fmax.max()):.3g}); scale "
                                 "it down: it need not be normalised")
            # the budget scales with the mass found so far: a first round that saw only a
            # narrow peak's tails (mass ~0) no longer asks every piece for ~0 error
            scale = max(scale, found)
            f_ends = self._eval(np.concatenate([lo, hi])).reshape(2, -1)
            err = np.abs(m20 - m10)
            # the piece's share of the interval first: tol·scale·(hi - lo) overflowed on
            # a wide interval (-1e300 to 1e300), an infinite budget refined no piece, and
            # a smooth pdf was then refused as not integrable
            budget = tol * scale * ((hi - lo) / (self.b - self.a)) + 1e-300
            # Endpoint test: a step or a tail at a piece's end that no node saw.
            hidden = (((f_ends.max(0) > 4 * fmax) | (f_ends.min(0) < 0.25 * fmin))
                      & (np.maximum(f_ends.max(0), fmax) * (hi - lo) > budget))
            bad = ((err > budget) | hidden) & ((hi - lo) > 1e-13 * (self.b - self.a))
            done_lo.append(lo[~bad]), done_hi.append(hi[~bad])
            done_m.append(m20[~bad]), done_e.append(err[~bad])
            accepted += float(m20[~bad].sum())
            if not bad.any():
                break
            mid = 0.5 * (lo[bad] + hi[bad])
            lo, hi = np.concatenate([lo[bad], mid]), np.concatenate([mid, hi[bad]])
        else:
            # only a lowered max_rounds ends here (pieces stop halving at 1e-13 of the
            # interval within 45 rounds): the pieces left were given an error of inf, and a
            # step at 1/π with max_rounds=10 was refused as "not integrable"
            self._refuse_coarse(tol, f"did not converge within max_rounds={max_rounds} "
                                "rounds of halving")
            raise ValueError(f"max_rounds={max_rounds}: the CDF of pdf on [{self.a}, "
                             f"{self.b}] did not reach tol={tol} within {max_rounds} rounds "
                             f"of halving ({lo.size:,} pieces still above it); raise "
                             "max_rounds (the default, 60, always ends)")
        lo, hi = np.concatenate(done_lo), np.concatenate(done_hi)
        masses, errors = np.concatenate(done_m), np.concatenate(done_e)
        order = np.argsort(lo)
        lo, hi, masses, errors = lo[order], hi[order], masses[order], errors[order]
        if np.any(masses < 0) or not np.all(np.isfinite(masses)):
            raise ValueError("pdf: must be finite and non-negative on [a, b]")
        total = masses.sum()
        if total <= 0:               # or has all its mass between the rules' nodes
            raise ValueError(f"pdf: every value the rules took on [{self.a}, {self.b}] was 0 "
                             f"({lo.size:,} pieces): a pdf that is 0 there, or a peak "
                             f"narrower than the pieces that no node met (raise pieces=)")
        if peak < 2.0 ** -1022:
            # subnormal values keep fewer than 52 bits: e^-x on [740, 745] was refused as
            # "not integrable" (an error bound of 0.81), and a constant 1e-320 gave a
            # density 1.2 % off with a cdf_error of 0
            raise ValueError(f"pdf: its values on [{self.a}, {self.b}] are at most "
                             f"{peak:.3g}, below float64's normal range (2.2e-308), where "
                             "they keep too few digits to integrate; scale it up: it need "
                             "not be normalised")
        # over the running sum's own end, which is then exactly 1: over the total (a
        # pairwise sum, a few ulps from it) the CDF ended at 1 - 2^-52 and was set to 1 at
        # b, a step of 2^-52 in the last piece whatever its mass, and u = 1 - 2^-53 (the
        # clamp of u = 1) was solved there: b = 800, of density 0, for e^-x on [0, 800]
        running = np.cumsum(masses)
        cdf = np.concatenate([[0.0], running]) / running[-1]
        cdf[-1] = 1.0
        error = float(errors.sum() / total)
        if not error <= max(1000.0 * tol, 1e-6):
            # pieces stop splitting at 1e-13 of the interval and are kept with their
            # error: 1/x on (0, 1) built with a CDF error of 0.017, x^-0.9 0.0016 (its
            # total 2 % low) until 4 December; 1/sqrt(x) reaches 2e-9
            self._refuse_coarse(tol, f"has an error bound of {error:.3g}")
            raise ValueError(f"pdf: its CDF on [{self.a}, {self.b}] has an error bound of "
                             f"{error:.3g} (tol={tol}): a pdf that is not integrable there, "
                             "or a singularity too steep for pieces of 1e-13 of the "
                             "interval")
        self.total = float(total)
        self._table = _Table(np.concatenate([lo, [hi[-1]]]), cdf, error)

    def _refuse_coarse(self, tol, failure):
        """A ValueError blaming the precision of the pdf's values, where it returned
        float32 or float16 ones and its CDF table failed (``failure``, in words): each
        step of their rounding (a relative 6e-8 in float32) is a jump the refinement
        chases, and e^-x as float32 on [0, 5] was refused after seconds as "a pdf that
        is not integrable, or a feature narrower than 1e-13 of the interval"."""
        if self._coarse is None:
            return
        step = float(np.finfo(self._coarse).eps) / 2
        raise ValueError(f"pdf: returns {self._coarse} values, each rounded to {step:.2g} "
                         f"of itself: its CDF on [{self.a}, {self.b}] {failure} at "
                         f"tol={tol}, likely the steps of that rounding, too fine to "
                         "resolve (or a pdf not integrable there, which float64 would "
                         "not mend); return float64 values, or raise tol well above that "
                         "rounding")

    def _eval(self, x):
        """``pdf(x)`` for x (n,): (n,) real numbers, or a ValueError (complex values and
        strings were read as numbers, the imaginary part dropped with a warning, and any
        shape of n values was flattened: an (n/2, 2) array as if it were (n,))."""
        raw = self._f(x)
        v = _reals(raw, "pdf")
        kind = getattr(raw, "dtype", None)
        if kind is not None and kind.kind == "f" and kind.itemsize < 8:
            self._coarse = kind           # float32 or float16 values (_refuse_coarse)
        if v.shape != np.shape(x):
            raise ValueError(f"pdf returned shape {v.shape} for {np.size(x)} points: expected "
                             f"({np.size(x)},), one value a point")
        return v

    def _piece_rules(self, lo, hi):
        """Two masses of each piece, 20-point Gauss–Legendre over it and 10-point over
        each half, and the node range. (10 points against 20 over the same piece agree
        on a step between their two central nodes: both weigh its sides half and half.)"""
        out = []
        mid = 0.5 * (lo + hi)
        for a, b, xs, ws in ((lo, mid, _GL_X, _GL_W), (mid, hi, _GL_X, _GL_W),
                             (lo, hi, _GL20_X, _GL20_W)):
            t = a[:, None] + (b - a)[:, None] * xs[None, :]
            f = self._eval(t.ravel()).reshape(t.shape)
            bad = ~(f >= 0) | ~np.isfinite(f)
            if bad.any():
                i = np.argmax(bad.ravel())
                raise ValueError(f"pdf: must be finite and non-negative on [a, b], got "
                                 f"pdf({t.ravel()[i]!r}) = {f.ravel()[i]!r}")
            out.append(((f @ ws) * (b - a), f.min(1), f.max(1)))
        (left, _, _), (right, _, _), (m20, fmin, fmax) = out
        return left + right, m20, fmin, fmax

    @property
    def cdf_error(self) -> float:
        """Achieved bound on the tabulated CDF's error (absolute, in probability)."""
        return self._table.error

    def _f_norm(self, x):
        return self._eval(x) / self.total

    def _partial(self, lo, x):
        """∫_{lo}^{x} p / total, vectorised by Gauss–Legendre."""
        h = x - lo
        t = lo[:, None] + h[:, None] * _GL_X[None, :]
        return h * (self._f_norm(t.ravel()).reshape(t.shape) @ _GL_W)

    def cdf(self, x):
        x = np.clip(_unit(x, "x"), self.a, self.b)
        k = np.clip(np.searchsorted(self._table.knots, x, side="right") - 1, 0,
                    self._table.knots.size - 2)
        return np.clip(self._table.cdf[k] + self._partial(self._table.knots[k], x), 0.0, 1.0)

    def pdf(self, x):
        x = _unit(x, "x")
        inside = (x >= self.a) & (x <= self.b)
        return _nan_where_nan(x, np.where(inside, self._f_norm(np.clip(x, self.a, self.b)), 0.0))

    def invert(self, x):
        return np.clip(self.cdf(x), 0.0, ONE_MINUS_EPSILON).reshape(-1, 1)

    def sample(self, u, *, max_iter: int = 60, xtol: float = 1e-14):
        """``u`` (n,) or (n, 1) -> points (n, 1): ``F⁻¹(u)``. ``max_iter`` (an integer
        >= 1) Newton-bisection steps at most, stopping where a step moves x by at most
        ``xtol`` (a number >= 0) times max(|a|, |b|)."""
        # max_iter = 0 or -3 returned the table's linear interpolation (off by 1e-4) and
        # xtol = NaN stopped after one step, without a word; max_iter = 2.5 raised a
        # TypeError from range()
        if (isinstance(max_iter, bool) or not isinstance(max_iter, numbers.Integral)
                or max_iter < 1):
            raise ValueError(f"max_iter={max_iter!r}: must be an integer >= 1")
        if (isinstance(xtol, bool) or not isinstance(xtol, numbers.Real)
                or not (math.isfinite(xtol) and xtol >= 0)):
            raise ValueError(f"xtol={xtol!r}: must be a finite number >= 0")
        # u outside [0, 1) as its nearest end, as PiecewiseConstant1D: u = 1 (which a
        # float32 u rounds to) found the last piece even where the pdf is 0 there, and
        # returned b, of density 0; NaN stays NaN
        u = np.clip(_unit(u), 0.0, ONE_MINUS_EPSILON)
        tab = self._table
        k = np.clip(np.searchsorted(tab.cdf, u, side="right") - 1, 0, tab.knots.size - 2)
        lo, hi = tab.knots[k].copy(), tab.knots[k + 1].copy()
        base = tab.cdf[k]
        width = tab.cdf[k + 1] - base
        # Start from linear interpolation inside the piece.
        frac = np.where(width > 0, (u - base) / np.where(width > 0, width, 1.0), 0.5)
        x = lo + np.clip(frac, 0.0, 1.0) * (hi - lo)
        left = tab.knots[k]
        # relative to the interval's magnitude, with no floor of 1: with max(1, |a|, |b|)
        # a line in metres, [5e-7, 5e-7 + 1e-10], stopped after one Newton step, its
        # samples 8e-9 off in u where the same pdf in nm came within 1e-12 (an outside
        # review)
        tol = xtol * max(abs(self.a), abs(self.b))
        active = np.arange(u.size)          # iterate only where not yet converged
        for _ in range(max_iter):
            xa, la, ha = x[active], lo[active], hi[active]
            g = base[active] + self._partial(left[active], xa) - u[active]
            ha = np.where(g > 0, xa, ha)
            la = np.where(g <= 0, xa, la)
            p = self._f_norm(xa)
            newton = xa - g / np.where(p > 0, p, np.inf)
            # the bracket is closed: at a root (g = 0) Newton stays put (xa is la), where
            # an open bracket sent it to bisection and away from the root again, ~20
            # steps of 11 pdf evaluations each down to xtol
            ok = (p > 0) & (newton >= la) & (newton <= ha)
            x_new = np.where(ok, newton, 0.5 * (la + ha))
            moving = np.abs(x_new - xa) > tol
            x[active], lo[active], hi[active] = x_new, la, ha
            active = active[moving]
            if active.size == 0:
                break
        return _nan_where_nan(u, x).reshape(-1, 1)
