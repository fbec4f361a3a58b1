"""Monte Carlo estimators of ``∫ f``: the seed's content, each returning an ``Estimate``.

- ``uniform``: ``(b − a)/N Σ f(X_i)``, X uniform on [a, b] (or a box in d dimensions);
- ``importance``: ``1/N Σ f(X_i)/p(X_i)``, with ``sample(u)`` the same sampler contract
  as ``mcverify.check_sampler`` (uniform u of shape (n, k) -> points), so one sampler
  serves both;
- ``stratified`` (jittered), ``rqmc`` (scrambled Sobol, scipy.stats.qmc), ``mis``
  (multi-sample MIS, balance or power heuristic), ``russian_roulette`` (divides by the
  survival probability) and ``antithetic`` variates.

Every estimator takes ``seed``; ``Estimate.samples`` holds the i.i.d. per-sample (or
per-replicate) estimates whose mean is ``value``, for ``mcverify.check_unbiased``.

References: M. Pharr, W. Jakob, G. Humphreys, *Physically Based Rendering*, 4th ed.,
ch. 2 (Monte Carlo integration) and §8 (sampling and reconstruction); E. Veach, PhD
thesis (1997), ch. 9 (multiple importance sampling); A. B. Owen, *Monte Carlo theory,
methods and examples* (2013), ch. 10 and 17 (variance reduction, RQMC).
"""

from __future__ import annotations

import functools
import inspect
import math
import numbers
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from ._memory import physical_bytes

__all__ = ["Estimate", "uniform", "importance", "stratified", "rqmc", "mis",
           "russian_roulette", "antithetic"]


@dataclass(frozen=True)
class Estimate:
    """``value`` ± ``std_error`` from ``n`` evaluations of f. ``samples``: the
    independent terms averaged into ``value`` (per sample, per stratum pair or per
    replicate). Identically distributed except ``stratified``'s: each stratum pair
    has its own mean, so a t-test on them (``check_unbiased``) counts the spread between
    strata as noise and has about the power of plain MC with n/2 samples."""

    value: float
    std_error: float
    n: int
    samples: np.ndarray = field(repr=False, default=None)


def _at_scale(v: np.ndarray) -> tuple[np.ndarray, float]:
    """``v`` divided by its largest magnitude, and that magnitude (1 where v is all 0):
    squares of terms of 1e-170 underflowed to 0 and of 1e155 overflowed to inf."""
    top = float(np.max(np.abs(v))) if v.size else 0.0
    top = top if 0.0 < top < np.inf else 1.0
    return v / top, top


def _standard_error(terms: np.ndarray) -> float:
    """The standard error of the mean of ``terms``, their sample standard deviation over
    √n, at the terms' own scale (until 7 December np.std of terms of 1e-170 was 0 and of
    1e155 inf: an estimate said to be exact, or to have no error bound). inf for one
    term or an infinite one (p = 0 where f is not), NaN where a term is NaN."""
    if terms.size < 2 or not np.isfinite(terms).all():
        return np.nan if np.isnan(terms).any() else np.inf
    unit, top = _at_scale(terms)
    return float(np.std(unit, ddof=1) / np.sqrt(terms.size) * top)


def _from_terms(terms, n_evals=None) -> Estimate:
    terms = np.asarray(terms, dtype=np.float64).ravel()
    return Estimate(float(np.mean(terms)), _standard_error(terms), int(n_evals or terms.size),
                    terms)


def _bound(name: str, v) -> np.ndarray:
    """A bound as a 1-D float64 array, or a ValueError naming it: strings were read as
    numbers ("0" as 0), None as NaN, booleans as 0 and 1, and complex numbers or
    ragged lists raised Python's or numpy's message."""
    try:
        raw = np.asarray(v)
    except ValueError as e:
        raise ValueError(f"{name}={v!r:.60}: not an array of numbers ({e})") from None
    if raw.dtype.kind not in "iuf":
        raise ValueError(f"{name}={v!r:.60}: expected real numbers, got an array of "
                         f"{raw.dtype}")
    return np.atleast_1d(raw.astype(np.float64))


def _box(a, b):
    a, b = _bound("a", a), _bound("b", b)
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError(f"a, b: expected scalars or 1-D arrays of one shape, got "
                         f"{a.shape} and {b.shape}")
    if a.size == 0:                # stratified divided by d = 0 (ZeroDivisionError)
        raise ValueError("a, b: empty bounds; need at least one dimension")
    if not np.all(np.isfinite(a) & np.isfinite(b) & (b > a)):
        raise ValueError(f"a={a.tolist()}, b={b.tolist()}: need finite a < b")
    with np.errstate(over="ignore"):
        width = b - a
        volume = np.prod(width)
    # a = -1e308, b = 1e308: the points were inf and f's NaN at them was blamed on f
    if not (np.all(np.isfinite(width)) and np.isfinite(volume)):
        raise ValueError(f"a={a.tolist()}, b={b.tolist()}: b - a (and the box's volume, "
                         "their product) must be finite in float64")
    return a, b


def _count(n, name="n", minimum=1, memory=True):
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < minimum:
        raise ValueError(f"{name}={n!r}: must be an integer >= {minimum}")
    have = physical_bytes() if memory else None
    if have is not None and 8 * int(n) > have:
        # one float64 a point is more than the machine holds (10**13 ended in numpy's
        # "Unable to allocate 72.8 TiB", naming no argument)
        raise ValueError(f"{name}={n!r}: {8 * int(n) / 2**30:.3g} GiB for one float64 a "
                         f"point, more than this machine's {have / 2**30:.3g} GiB")
    return int(n)


def _fits(n: int, d: int, names: str) -> None:
    """A ValueError naming ``names`` where n points of d float64 coordinates are more than
    the machine holds: ``_count`` bounds n alone, and n = 1000 with sample_dim = 10**9
    (or a box of 10**6 dimensions) ended in numpy's "Unable to allocate 7.28 TiB",
    naming no argument."""
    have = physical_bytes()
    if have is not None and 8 * n * d > have:
        raise ValueError(f"{names}: {n} points of {d} coordinates, {8 * n * d / 2**30:.3g} "
                         f"GiB of float64, more than this machine's {have / 2**30:.3g} GiB")


def _values(name: str, v, n: int, x=None) -> np.ndarray:
    """What ``name`` returned for n points as (n,) float64, or ValueError: a scalar or a
    wrong length had been averaged as if it were n values (``lambda x: 2.0`` gave n = 1).
    A NaN is refused, naming the first point ``x[i]`` that gave it: it made the value and
    the standard error NaN without saying where."""
    try:
        # (inside: a ragged list raised numpy's message from iscomplexobj, naming nothing)
        complex_ = np.iscomplexobj(v)
        a = None if complex_ else np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name} returned {type(v).__name__} that is no array of real "
                         f"numbers ({e})") from None
    if complex_:                 # numpy drops the imaginary part with a warning only
        raise ValueError(f"{name} returned complex values: expected real numbers")
    if a.shape not in ((n,), (n, 1)):     # (n, 1): one value a row, as check_sampler reads it
        raise ValueError(f"{name} returned shape {a.shape} for {n} points: expected ({n},) "
                         f"or ({n}, 1)")
    a = a.reshape(-1)
    nan = np.isnan(a)
    if nan.any():
        i = int(np.argmax(nan))
        at = "" if x is None else f" ({_show_point(x[i])})"
        raise ValueError(f"{name} returned NaN at point {i}{at}, {int(nan.sum())} of {n} "
                         "points: an estimate needs a number at every point")
    return a


def _show_point(p) -> str:
    try:
        return "x = " + np.array2string(np.asarray(p, dtype=np.float64), precision=17,
                                        separator=", ")
    except (TypeError, ValueError):
        return f"x = {p!r:.60}"


def _density(name: str, v, n: int, x=None) -> np.ndarray:
    """``_values`` of a pdf, which must be >= 0 (a negative one gave a negative estimate
    without a word)."""
    a = _values(name, v, n, x)
    if (a < 0).any():
        i = int(np.argmax(a < 0))
        raise ValueError(f"{name} returned {a[i]:.6g} at point {i}: a density is >= 0")
    return a


def _points(name: str, x, n: int) -> np.ndarray:
    """What ``sample`` returned for n uniforms as an array of n points (a shorter array
    had been reported as f's wrong shape), the array that f and the pdfs then take: a
    list of points, checked as an array, went to them as the list, and ``x[:, 0]`` in f
    raised Python's "list indices must be integers or slices, not tuple"."""
    try:
        a = np.asarray(x)
    except ValueError as e:       # a ragged list: numpy's message, naming nothing
        raise ValueError(f"{name} returned {type(x).__name__} that is no array of points "
                         f"({e})") from None
    if a.dtype.kind not in "biuf":
        # strings or complex points reached f, whose error named neither (np.sin's
        # "ufunc 'sin' not supported for the input types")
        raise ValueError(f"{name} returned points of dtype {a.dtype}: expected real numbers")
    if a.shape[:1] != (n,):
        raise ValueError(f"{name} returned shape {a.shape} for {n} uniforms: expected "
                         f"{n} points (rows)")
    return a


def _checked(fn):
    """Name a bad ``seed`` or a non-callable ``f``, ``sample`` or ``pdf`` before any work
    (they raised a bare TypeError from the call or from numpy's SeedSequence, and a
    negative seed numpy's message, which named no parameter)."""
    sig = inspect.signature(fn)

    @functools.wraps(fn)
    def checked(*args, **kwargs):
        given = sig.bind(*args, **kwargs).arguments
        for name in ("f", "sample", "pdf"):
            if name in given and not callable(given[name]):
                raise ValueError(f"{name}={given[name]!r:.60}: must be callable")
        seed = given.get("seed", 0)
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"seed={seed!r}: must be an integer >= 0")
        return fn(*args, **kwargs)

    return checked


def _call_f(f, x, scalar_box):
    x = x[:, 0] if scalar_box else x
    return _values("f", f(x), x.shape[0], x)


@_checked
def uniform(f, a, b, n: int, *, seed: int = 0) -> Estimate:
    """``(b − a)/N Σ f(X_i)`` with X_i uniform on [a, b].

    ``a``, ``b`` scalars (``f`` takes (n,)) or arrays of d bounds (a box; ``f`` takes
    (n, d)). The estimator is unbiased: ``E[F_N] = ∫ f`` (the seed's proof).

    Examples
    --------
    >>> import numpy as np
    >>> e = uniform(np.sin, 0.0, np.pi, 100_000, seed=1)
    >>> abs(e.value - 2.0) < 4 * e.std_error
    True
    """
    lo, hi = _box(a, b)
    n = _count(n)
    _fits(n, lo.size, f"n={n}, a, b ({lo.size} dimensions)")
    x = lo + (hi - lo) * np.random.default_rng(seed).random((n, lo.size))
    return _from_terms(np.prod(hi - lo) * _call_f(f, x, np.ndim(a) == 0))


@_checked
def importance(f, sample, pdf, n: int, *, seed: int = 0, sample_dim: int = 1) -> Estimate:
    """``1/N Σ f(X_i)/p(X_i)`` with ``X_i = sample(u_i)``.

    ``sample(u: (n, sample_dim)) -> points``; ``pdf(points) -> (n,)``; ``f(points) ->
    (n,)``; each of the two may also return (n, 1), one value a row, as
    ``mcverify.check_sampler`` reads a pdf (``lambda x: 2 * x`` of (n, 1) points), and
    the estimate is the same; any other shape is refused. Points where ``f = 0`` contribute 0 even if ``p = 0`` there. A sample with
    ``p = 0`` but ``f ≠ 0`` is impossible for a correct sampler and yields inf, which
    ``mcverify.check_unbiased`` reports.
    """
    n = _count(n)
    k = _count(sample_dim, "sample_dim")
    _fits(n, k, f"n={n}, sample_dim={k}")
    u = np.random.default_rng(seed).random((n, k))
    x = _points("sample", sample(u), n)
    fx = _values("f", f(x), n, x)
    px = _density("pdf", pdf(x), n, x)
    with np.errstate(divide="ignore", invalid="ignore"):
        terms = np.where(fx == 0.0, 0.0, fx / px)
    return _from_terms(terms)


@_checked
def stratified(f, a, b, n: int, *, seed: int = 0) -> Estimate:
    """Jittered sampling, one uniform sample in each stratum of a grid of about n: m =
    ⌊n^(1/d)⌋ strata on each axis but the first, and on the first m₀: n / m^(d-1) rounded (a
    half to even, as Python's ``round``), then made even by adding 1 where it is odd, at
    least 2 (only that axis is paired below; n = 106 in 2-D: m = 10, 10.6 rounds to 11, m₀ =
    12, 120 samples; n = 105: 10.5 rounds to 10, 100). The standard error comes from
    collapsing neighbouring strata in pairs along the first axis (the 'collapsed strata'
    estimator, conservative: it counts the change of f between paired strata as noise, so
    for a smooth f it overstates the error: 2.6× for ∫eˣ at n = 64, measured over 400
    seeds), so ``samples`` holds the stratum-pair means. Conservative in expectation (E[SE²]
    >= the variance), not estimate by estimate: where f jumps, the jump sits in one pair of
    strata and the SE is often 0 (a step at 0.37, n = 64, 1000 seeds: E[SE²] 1.5× the
    variance, but SE = 0 in 669 and value ± 1.96·SE covered the integral in
    331); use ``uniform`` or ``rqmc`` for an interval there.
    ``Estimate.n`` is the grid's m₀ · m^(d-1) samples: within a few per cent of n where m
    is large; at most 2n in any dimension (until 4 December every axis took the even
    number nearest n^(1/d), so at least 2^d samples: 2^20 for n = 1000 in 20-D)."""
    lo, hi = _box(a, b)
    n = _count(n, minimum=2)
    d = lo.size
    _fits(2 * n, d, f"n={n}, a, b ({d} dimensions)")     # the grid: at most 2n strata
    m = max(1, int(n ** (1.0 / d) + 1e-9))       # + 1e-9: 1000 ** (1/3) is 9.999...
    m0 = max(2, int(round(n / m ** (d - 1))))
    m0 += m0 % 2
    sizes = np.array([m0] + [m] * (d - 1))
    # each stratum's index on every axis, the last axis fastest (meshgrid's "ij" order,
    # which pairs strata along the first axis below); np.meshgrid took at most 32 axes
    # (RuntimeError in 33 to 64 dimensions, numpy's 64-dimension limit above)
    flat = np.arange(int(np.prod(sizes)))
    grid = np.empty((flat.size, d), dtype=np.int64)
    for k in range(d - 1, -1, -1):
        flat, grid[:, k] = np.divmod(flat, sizes[k])
    rng = np.random.default_rng(seed)
    t = (grid + rng.random(grid.shape)) / sizes
    vals = np.prod(hi - lo) * _call_f(f, lo + (hi - lo) * t, np.ndim(a) == 0)
    # Pair strata along the first axis: (2k, 2k+1).
    paired = vals.reshape(m0 // 2, 2, -1)
    pairs = paired.mean(axis=1).ravel()
    value = float(vals.mean())
    unit, top = _at_scale(paired[:, 0] - paired[:, 1])
    se = float(np.sqrt(np.sum(unit ** 2)) / vals.size * top)
    return Estimate(value, se, int(vals.size), pairs)


@_checked
def rqmc(f, a, b, n: int, *, seed: int = 0, replicates: int = 16) -> Estimate:
    """Randomised QMC: ``replicates`` independently scrambled Sobol point sets of ``n``
    points (n a power of two, for the net property); the value is their mean and the
    standard error their spread (``samples`` = the replicate estimates).

    scipy's scrambled Sobol points are multiples of 2^-bits (30): uniform on that grid,
    so E[x] = 1/2 - 2^-31, a bias ``check_unbiased`` saw in 1-D (∫x: -4.7e-10 with a
    standard error below it). Each point gets a uniform offset within its 2^-bits cell,
    which makes it exactly uniform on [0, 1) and keeps the net (elementary intervals of
    n <= 2^bits points are whole cells)."""
    from scipy.stats import qmc   # here: importing scipy.stats costs ~1.2 s (Zen 1)

    lo, hi = _box(a, b)
    # scipy's own messages named neither n nor the dimension ("At most 2**30=... distinct
    # points can be generated", "Maximum allowed dimension exceeded" for n = 2^64); the
    # Sobol limit, the more specific, before the memory bound of _count
    n = _count(n, memory=False)
    if n & (n - 1):
        raise ValueError(f"n={n}: must be a power of two for Sobol points")
    if n > 2 ** 30:
        raise ValueError(f"n={n}: at most 2^30 = {2 ** 30} Sobol points a replicate (scipy's "
                         "30-bit Sobol sequence); raise replicates instead")
    n = _count(n)
    if lo.size > qmc.Sobol.MAXDIM:
        raise ValueError(f"a, b: {lo.size} dimensions, Sobol points have at most "
                         f"{qmc.Sobol.MAXDIM}")
    r = _count(replicates, "replicates", minimum=2)
    _fits(n, lo.size, f"n={n}, a, b ({lo.size} dimensions)")
    # the replicates' seeds one at a time: spawn(r) at once built r SeedSequence objects
    # (~460 bytes each, where the memory check counts 8 a replicate: replicates=10**9 ran
    # out of memory; an outside review); one at a time they are the same children
    root = np.random.SeedSequence(seed)
    reps = []
    for _ in range(r):
        rng = np.random.default_rng(root.spawn(1)[0])
        sobol = qmc.Sobol(lo.size, scramble=True, seed=rng)
        pts = sobol.random(n)
        pts = np.minimum(pts + rng.random(pts.shape) * 2.0 ** -getattr(sobol, "bits", 30),
                         1.0 - 2.0 ** -53)
        reps.append(np.prod(hi - lo) * _call_f(f, lo + (hi - lo) * pts, np.ndim(a) == 0).mean())
    e = _from_terms(reps)
    return Estimate(e.value, e.std_error, n * r, e.samples)


def _mis_terms(fx, p, counts, i, ex):
    """Technique i's terms ``w_i f / p_i`` at its samples from every technique's pdf
    ``p`` (techniques × samples), with ``w_i = (n_i p_i)^β / Σ_j (n_j p_j)^β``.

    Computed from ratios, never from n_j p_j or a power of it: f n_i r_i^(β-1) /
    (t Σ_j r_j^β) / m, with m = max_j p_j, r_j = n_j (p_j / m) / t and t = max_j n_j p_j
    / m. Formed as products, n_j p_j overflowed (a pdf above 1.8e308 / n_j) and a power of
    it with a large β; an infinite pdf (a delta strategy's) made inf / inf: each gave a
    NaN estimate without a word. Limits where the formula has none:
    - own pdf 0, another's not: (0 / t)^(β-1) is 0 for β > 1 and 1 for balance, so the
      balance term is f n_i / Σ n_j p_j (it was 0 · f / 0 = NaN);
    - a pdf of inf at the point: the term is f / inf = 0 (w_i ≤ 1 over an infinite
      p_i; or w_i = 0 where another technique's density is infinite), so a delta
      strategy's samples add nothing and the others' are weighed as without it;
    - every pdf 0: f / 0, as in ``importance`` (inf where f is not 0)."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        m = p.max(axis=0)
        finite = np.isfinite(m) & (m > 0)
        q = counts[:, None] * (p / np.where(finite, m, 1.0))     # n_j p_j / m, finite
        t = q.max(axis=0)
        r = q / np.where(finite, t, 1.0)                         # in [0, 1]
        s = t * np.sum(r ** ex, axis=0)
        inner = fx * (counts[i] * r[i] ** (ex - 1.0) / s) / m
        return np.where(fx == 0.0, 0.0, np.where(finite, inner, fx / m))


@_checked
def mis(f, techniques, *, seed: int = 0, heuristic: str = "balance",
        beta: float | None = None) -> Estimate:
    """Multi-sample MIS (Veach): ``Σ_i 1/n_i Σ_k w_i(X_ik) f(X_ik)/p_i(X_ik)``.

    ``techniques``: a list (or any iterable) of ``(sample, pdf, n_i, sample_dim)``;
    every technique's pdf is evaluated at every technique's samples. ``heuristic``: ``"balance"``
    (``w_i = n_i p_i / Σ_j n_j p_j``) or ``"power"`` (exponent ``beta``, 2 by default);
    a ``beta`` other than 1 with the balance heuristic is refused (it has no exponent).
    The weights are computed from ratios of the pdfs (``_mis_terms``): a pdf of inf (a
    delta strategy's) contributes its limit, 0, and huge pdfs do not overflow.
    ``samples`` holds g = gcd(n_i) i.i.d. estimates of the integral, replicate r the
    MIS estimate from the r-th n_i / g samples of each technique (where all n_i are
    equal, per index k the sum over techniques of their k-th terms); their mean is
    ``value``. Coprime n_i give one replicate, too few for ``check_unbiased``.
    """
    if heuristic not in ("balance", "power"):
        raise ValueError(f"heuristic={heuristic!r}: expected 'balance' or 'power'")
    # any iterable of techniques (a generator raised a bare TypeError from len())
    if isinstance(techniques, (str, bytes)) or not isinstance(techniques, Iterable):
        raise ValueError(f"techniques={techniques!r:.60}: expected a list of (sample, pdf, "
                         "n, sample_dim)")
    techniques = list(techniques)
    if not techniques:
        raise ValueError("techniques: need at least one (sample, pdf, n, sample_dim)")
    if heuristic == "balance" and beta is not None and (isinstance(beta, bool) or beta != 1):
        # until 7 December beta=3 with the balance heuristic was ignored without a word
        raise ValueError(f"beta={beta!r}: the balance heuristic has no exponent (it is the "
                         "power heuristic at beta=1); pass heuristic='power' to use beta")
    if heuristic == "power" and beta is None:
        beta = 2.0
    if heuristic == "power" and (isinstance(beta, bool) or not isinstance(beta, numbers.Real)
                                 or not (math.isfinite(beta) and beta > 0)):
        # beta <= 0 gives a technique weight where its pdf is 0: biased (0.875 for 1)
        raise ValueError(f"beta={beta!r}: the power heuristic needs a finite beta > 0")
    for i, t in enumerate(techniques):
        if not isinstance(t, (tuple, list)) or len(t) != 4:
            raise ValueError(f"techniques[{i}]: expected (sample, pdf, n, sample_dim), got "
                             f"{t!r:.80}")
        for j, what in ((0, "sample"), (1, "pdf")):
            if not callable(t[j]):
                raise ValueError(f"techniques[{i}] {what}={t[j]!r:.60}: must be callable")
    ex = 1.0 if heuristic == "balance" else float(beta)
    seqs = np.random.SeedSequence(seed).spawn(len(techniques))
    # each named with its technique ("n_i=0" alone did not say which of them)
    counts = [_count(t[2], f"techniques[{i}] n_i") for i, t in enumerate(techniques)]
    for i, (t, c) in enumerate(zip(techniques, counts)):
        k = _count(t[3], f"techniques[{i}] sample_dim")
        _fits(c, k, f"techniques[{i}]: n_i={c}, sample_dim={k}")
    value, errors, cols = 0.0, [], []
    for (sample, _pdf, n_i, k), s in zip(techniques, seqs):
        x = _points(f"techniques[{len(cols)}] sample",
                    sample(np.random.default_rng(s).random((n_i, int(k)))), n_i)
        fx = _values("f", f(x), n_i, x)
        pj = np.stack([_density(f"techniques[{j}] pdf", t[1](x), n_i, x)
                       for j, t in enumerate(techniques)])
        terms = _mis_terms(fx, pj, np.asarray(counts, dtype=np.float64), len(cols), ex)
        value += terms.mean()
        errors.append(_standard_error(terms))
        cols.append(terms)
    # g = gcd(n_i) replicates, each the estimate from n_i / g consecutive samples of
    # every technique: i.i.d., their mean the value (per index k where the n_i are
    # equal); until 7 December None unless every n_i was equal (1000 and 500: a
    # renderer's usual split left check_unbiased nothing to test)
    g = math.gcd(*counts)
    samples = np.sum([c.reshape(g, -1).mean(axis=1) for c in cols], axis=0)
    # each technique's error at its own scale, added in quadrature without squaring
    # (the sum of their variances underflowed to 0 for terms of 1e-160); an infinite
    # term's error is inf, as in ``importance`` (its variance inf - inf was NaN)
    se = np.nan if np.isnan(errors).any() else math.hypot(*errors)
    return Estimate(float(value), float(se), int(sum(counts)), samples)


@_checked
def russian_roulette(f, sample, pdf, n: int, q: float, *, seed: int = 0,
                     sample_dim: int = 1) -> Estimate:
    """Importance sampling where each term survives with probability ``q`` and is then
    divided by ``q`` (else 0): unbiased, and f is evaluated only for survivors."""
    if isinstance(q, bool) or not isinstance(q, numbers.Real) or not 0.0 < q <= 1.0:
        raise ValueError(f"q={q!r}: survival probability must be a number in (0, 1]")
    n = _count(n)
    k = _count(sample_dim, "sample_dim")
    _fits(n, k, f"n={n}, sample_dim={k}")
    rng = np.random.default_rng(seed)
    u = rng.random((n, k))
    alive = rng.random(n) < q
    terms = np.zeros(n)
    if alive.any():
        m = int(alive.sum())
        x = _points("sample", sample(u[alive]), m)
        fx, px = _values("f", f(x), m, x), _density("pdf", pdf(x), m, x)
        with np.errstate(divide="ignore", invalid="ignore"):
            terms[alive] = np.where(fx == 0.0, 0.0, fx / px) / q
    return _from_terms(terms)


@_checked
def antithetic(f, a, b, n: int, *, seed: int = 0) -> Estimate:
    """Antithetic variates: pairs ``(X, a + b − X)``; ``samples`` holds pair means (i.i.d.),
    whose variance is below plain MC's for monotone f."""
    lo, hi = _box(a, b)
    n = _count(n, minimum=2)
    half = n // 2
    _fits(half, lo.size, f"n={n}, a, b ({lo.size} dimensions)")
    t = np.random.default_rng(seed).random((half, lo.size))
    scalar = np.ndim(a) == 0
    vol = np.prod(hi - lo)
    y1 = vol * _call_f(f, lo + (hi - lo) * t, scalar)
    y2 = vol * _call_f(f, lo + (hi - lo) * (1.0 - t), scalar)
    e = _from_terms(0.5 * (y1 + y2))
    return Estimate(e.value, e.std_error, 2 * half, e.samples)
