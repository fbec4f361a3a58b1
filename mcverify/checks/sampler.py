"""Checks of samplers: distribution against pdf, CDF-inversion round trip, two-sample.

The sampler contract (shared with ``estimators.mc.importance``): ``sample(u)`` maps
uniform numbers ``u`` of shape (n, k) to points (n, d); ``pdf(x)`` maps (n, d) points to
(n,) densities with respect to the domain's measure.
"""

from __future__ import annotations

import time

import numpy as np

from .. import _domain_kernels as K
from .. import _validate as v
from .. import stats
from ..errors import InvalidArgument
from ..domains import Domain, as_domain
from ..quadrature import gauss_legendre_01, integrate_cells, merge_leaves
from ..result import CheckResult

__all__ = ["check_sampler", "check_inverse", "check_same_distribution"]

#: Cells re-integrated more finely when their χ² contribution exceeds this (a 5σ cell):
#: under a correct pdf this only happens where the quadrature missed a narrow feature.
_SUSPICIOUS = 25.0
_MAX_SUSPICIOUS_CELLS = 256


def _name_of(f, default):
    return getattr(f, "__name__", None) or default


def _draw(sample, rng, n, k, dim, name="sample"):
    u = rng.random((n, k))
    return u, v.points(name, sample(u), n, dim)


def _status_failures(n_status, first, x, u, domain: Domain, what="sample"):
    """Failure messages for NaN/Inf points and points outside the domain."""
    failures = []
    for code, text in ((K.NONFINITE, "are NaN/Inf"),
                       (K.OUTSIDE, f"lie outside the {domain.name} domain")):
        if n_status[code]:
            i = int(first[code])
            origin = "" if np.isnan(u[i]).all() else f"u={u[i].tolist()} -> "
            failures.append(f"{int(n_status[code])} {what}s {text} "
                            f"(first: {origin}x={x[i].tolist()})")
    return failures


def _screen(x, u, domain: Domain, what="sample"):
    """Valid points' parameters, and failure messages (NaN/Inf, outside domain)."""
    s, status = domain.classify(x)
    codes = np.bincount(status, minlength=3)
    first = np.array([np.argmax(status == c) if codes[c] else -1 for c in range(3)])
    return s[status == K.VALID], _status_failures(codes, first, x, u, domain, what)


def _histogram(x, u, domain: Domain, edges, what="sample"):
    """Counts per cell of the points ``x`` (one numba pass), and failure messages."""
    e1 = edges[1] if len(edges) == 2 else np.array([0.0, 1.0])
    counts, codes, first = K.histogram_kernel(
        domain.kind, domain.args, domain.tolerance, domain.points(x),
        edges[0], K.cell_lookup(edges[0]), e1, K.cell_lookup(e1), len(edges))
    shape = tuple(e.size - 1 for e in edges)
    return (counts.reshape(shape).astype(np.float64), int(codes[K.VALID]),
            _status_failures(codes, first, x, u, domain, what))


def _edges(pilot_s, resolution):
    """Cell edges per parameter axis: quantiles of ``0.5·F_pilot + 0.5·uniform``.

    The pilot is an independent sample, so the χ² test stays valid conditionally on the
    edges. Half the cells follow the sampler's own mass (resolving a narrow peak, such as
    GGX at α = 1e-3, that a uniform grid would lump into one cell) and half are uniform
    (keeping resolution where the pilot put little mass).
    """
    edges = []
    for j, r in enumerate(resolution):
        q = np.linspace(0.0, 1.0, r + 1)
        if pilot_s is None or pilot_s.shape[0] == 0:
            edges.append(q)
            continue
        ps = np.sort(pilot_s[:, j])
        cand = np.union1d(ps, np.linspace(0.0, 1.0, 4 * r + 1))
        g = 0.5 * np.searchsorted(ps, cand, side="right") / ps.size + 0.5 * cand
        e = np.interp(q, g, cand)
        e[0], e[-1] = 0.0, 1.0
        e = np.unique(e)
        edges.append(e)
    return edges


class _Density:
    """Parameter-space density ``pdf(to_point(s)) · jacobian`` that records bad values."""

    def __init__(self, pdf, domain):
        self.pdf, self.domain = pdf, domain
        self.negative = 0
        self.nonfinite = 0
        self.example = None

    def __call__(self, s):
        x = self.domain.to_point(s)
        p = v.values("pdf", self.pdf(x), x.shape[0])
        bad_nan = ~np.isfinite(p)
        bad_neg = p < 0
        if bad_nan.any() or bad_neg.any():
            self.nonfinite += int(bad_nan.sum())
            self.negative += int(bad_neg.sum())
            if self.example is None:
                i = int(np.flatnonzero(bad_nan | bad_neg)[0])
                self.example = (x[i].tolist(), float(p[i]))
            p = np.where(bad_nan | bad_neg, 0.0, p)
        return p * self.domain.jacobian


#: Density evaluations allowed per round of re-integrating suspicious cells.
_REFINE_BUDGET = 4_000_000


def _refine_suspicious(density, edges, counts, integral, n, m):
    """Re-integrate, from a finer start level, the cells whose χ² contribution exceeds
    ``_SUSPICIOUS`` (largest first, within an evaluation budget). Under a correct pdf a
    5σ cell only arises where the rule's nodes missed a narrow feature; under a wrong pdf
    the new integral agrees with the old one and the cell stays as damning as it was."""
    mass, error = integral.mass.copy(), integral.error.copy()
    n_evals, unconverged, leaves = integral.n_evals, integral.unconverged, integral.leaves
    for start in ((6, 12) if m == 1 else (3, 6)):
        e = n * mass
        contrib = np.where(e > 0, (counts - e) ** 2 / np.maximum(e, 1e-300),
                           np.where(counts > 0, np.inf, 0.0)).ravel()
        sus = np.flatnonzero(contrib > _SUSPICIOUS)
        if sus.size == 0:
            break
        per_cell = 2 ** (start * m) * (1 + 2 ** m) * (5 if m == 1 else 3) ** m
        cap = int(min(_MAX_SUSPICIOUS_CELLS, max(1, _REFINE_BUDGET // per_cell)))
        sus = sus[np.argsort(-contrib[sus], kind="stable")][:cap]
        r = integrate_cells(density, edges, n_samples=n, start_level=start, cells=sus,
                            keep_leaves=(m == 1))
        mass.ravel()[sus] = r.mass.ravel()[sus]
        error.ravel()[sus] = r.error.ravel()[sus]
        if m == 1:
            keep = ~np.isin(leaves[3], sus)
            leaves = merge_leaves(*(np.concatenate([a[keep], b]) for a, b in zip(leaves, r.leaves)))
        n_evals += r.n_evals
        unconverged += r.unconverged
    return mass, error, n_evals, unconverged, leaves


def _cdf_from_leaves(density, leaves, s, total):
    """CDF at points ``s`` (1-D): mass of leaves to the left plus a Gauss–Legendre
    integral inside the leaf (leaves are where the density is smooth)."""
    lo, w, lm, _ = leaves
    cum = np.concatenate([[0.0], np.cumsum(lm)])
    i = np.clip(np.searchsorted(lo, s, side="right") - 1, 0, lo.size - 1)
    nodes, weights = gauss_legendre_01(8)
    h = np.clip(s - lo[i], 0.0, w[i])
    t = lo[i][:, None] + h[:, None] * nodes[None, :]
    f = density(t.reshape(-1, 1)).reshape(t.shape)
    return np.clip((cum[i] + h * (f @ weights)) / total, 0.0, 1.0)


def _worst_cells(domain, edges, counts, expected, k=5):
    e = expected.ravel()
    o = counts.ravel()
    contrib = np.where(e > 0, (o - e) ** 2 / np.maximum(e, 1e-300), np.where(o > 0, np.inf, 0))
    out = []
    for flat in np.argsort(-contrib)[:k]:
        if contrib[flat] == 0:
            break
        idx = np.unravel_index(flat, counts.shape)
        lo = [float(edges[j][i]) for j, i in enumerate(idx)]
        hi = [float(edges[j][i + 1]) for j, i in enumerate(idx)]
        centre = domain.to_point(np.array([[(a + b) / 2 for a, b in zip(lo, hi)]]))[0]
        out.append({"cell": [int(i) for i in idx], "param_lo": lo, "param_hi": hi,
                    "point": centre.tolist(), "observed": float(o[flat]),
                    "expected": float(e[flat]), "contribution": float(contrib[flat])})
    return out


def _histogram_test_iv(domain, n_samples, resolution, alpha, seed, sample_dim, *,
                       min_samples):
    """Validate the arguments shared by the histogram tests; returns them normalised."""
    dom = as_domain(domain)
    n = v.integer("n_samples", n_samples, minimum=min_samples)
    res = v.resolution("resolution", resolution, dom.param_dim)
    k = dom.sample_dim if sample_dim is None else v.integer("sample_dim", sample_dim, minimum=1)
    v.memory("n_samples", n, 8 * (k + 3 * dom.dim + 4),
             "uniform numbers, points, their parameters and cells")
    return dom, n, res, v.probability("alpha", alpha), v.seed("seed", seed), k


def check_sampler(sample, pdf, domain, *, n_samples: int = 1_000_000, resolution=None,
                  alpha: float = 0.01, seed: int = 0, sample_dim: int | None = None,
                  pilot: bool = True, name: str | None = None) -> CheckResult:
    """Test that ``sample`` draws from the distribution whose density is ``pdf``.

    Parameters
    ----------
    sample : callable
        ``sample(u)``: uniform ``u`` of shape (n, k) -> points (n, d).
    pdf : callable
        ``pdf(x)``: points (n, d) -> (n,) density w.r.t. the domain's measure.
    domain : str or Domain
        ``"interval"``, ``"square"``, ``"disk"``, ``"sphere"``, ``"hemisphere"`` or a
        ``Domain`` object such as ``mcverify.Interval(a, b)``.
    n_samples : int
        Samples drawn (1e6 by default: ε = 1 % contamination is then visible at
        ~10σ in the marginal tests).
    resolution : int or tuple, optional
        Histogram cells per parameter axis (default: ``domain.default_resolution``,
        about 100 samples per cell).
    alpha : float
        Significance level of this check (a suite corrects it for multiplicity).
    seed : int
        Seed of the uniform numbers; the same seed gives the same result.
    sample_dim : int, optional
        k, the uniform numbers per sample (default ``domain.sample_dim``).
    pilot : bool
        Place cell edges by an independent pilot sample (see Notes).

    Returns
    -------
    CheckResult
        ``p_value`` combines the sub-tests by Bonferroni. ``failures`` lists NaN/Inf
        samples, samples outside the domain, negative/NaN pdf values, samples in cells
        where the pdf integrates to zero, and a pdf whose integral differs from 1 by more
        than the quadrature's error bound (at least 1e-4).

    Notes
    -----
    Sub-tests, each on the same samples: Pearson's χ² on the full grid (low-expectation
    cells pooled); on 2-D domains also χ² of the two marginal histograms (few cells,
    hence high power against smooth deviations such as a mixture with another
    distribution); on 1-D domains the Kolmogorov–Smirnov test of ``F(X)`` against
    uniform, with ``F`` integrated from the pdf (binning-free).

    .. math:: E_j = n \\int_{C_j} p(x)\\, dx, \\qquad X^2 = \\sum_j (O_j - E_j)^2 / E_j

    Expected counts come from adaptive Gauss–Legendre cubature with a statistical
    tolerance (:mod:`mcverify.quadrature`), so pdfs with discontinuities inside cells
    stay calibrated.

    References
    ----------
    W. Jakob et al., Mitsuba 3, ``mitsuba.chi2``; M. Pharr, W. Jakob, G. Humphreys,
    *Physically Based Rendering*, 4th ed., sampling tests; H. B. Mann, A. Wald (1942),
    on the choice of the number of class intervals.

    Examples
    --------
    >>> import numpy as np, mcverify as mv
    >>> r = mv.check_sampler(lambda u: u ** 0.5, lambda x: 2 * x[:, 0], "interval",
    ...                      n_samples=100_000, seed=1)
    >>> r.passed   # x = sqrt(u) has density 2x on [0, 1]
    True
    """
    t0 = time.perf_counter()
    v.callable_("sample", sample)
    v.callable_("pdf", pdf)
    dom, n, res, alpha, seed, k = _histogram_test_iv(domain, n_samples, resolution, alpha,
                                                     seed, sample_dim, min_samples=1)
    name = name or f"sampler:{_name_of(sample, 'sample')}"
    m = dom.param_dim
    res = res or dom.default_resolution(n)

    main_seq, pilot_seq = np.random.SeedSequence(seed).spawn(2)
    pilot_s = None
    if pilot:
        n_pilot = int(min(max(n // 10, 1000), 100_000))
        pu, px = _draw(sample, np.random.default_rng(pilot_seq), n_pilot, k, dom.dim)
        pilot_s, _ = _screen(px, pu, dom)
    edges = _edges(pilot_s, res)
    u, x = _draw(sample, np.random.default_rng(main_seq), n, k, dom.dim)
    counts, n_valid, failures = _histogram(x, u, dom, edges)

    density = _Density(pdf, dom)
    integral = integrate_cells(density, edges, n_samples=max(n_valid, 1), keep_leaves=(m == 1))
    mass, error, n_evals, unconverged, leaves = _refine_suspicious(
        density, edges, counts, integral, max(n_valid, 1), m)
    if density.negative or density.nonfinite:
        failures.append(f"pdf returned {density.negative} negative and {density.nonfinite} "
                        f"NaN/Inf values (first: pdf({density.example[0]}) = "
                        f"{density.example[1]})")
    total, err_bound = float(mass.sum()), float(error.sum())
    norm_tol = max(1e-4, 2.0 * err_bound)
    if not abs(total - 1.0) <= norm_tol:
        failures.append(f"pdf integrates to {total:.6g} over the {dom.name} domain, not 1 "
                        f"(quadrature error bound {err_bound:.2g})")
    messages = []
    if unconverged:
        messages.append(f"quadrature stopped at its depth limit on {unconverged} leaves "
                        f"(error bound {err_bound:.2g})")

    expected = mass * n_valid
    sub = {}
    full = stats.chi2_gof(counts, expected)
    sub["chi2"] = full
    note = v.few_bins_note("n_samples", n, full.n_bins) if n_valid else None
    if note:
        messages.append(note)
    if full.observed_in_empty:
        failures.append(f"{full.observed_in_empty} samples fell in cells where the pdf "
                        "integrates to 0")
    if m == 2:
        for axis, label in ((1, "chi2_axis0"), (0, "chi2_axis1")):
            sub[label] = stats.chi2_gof(counts.sum(axis=axis), expected.sum(axis=axis))
    elif n_valid > 0 and leaves is not None and total > 0:
        s, _ = _screen(x, u, dom)
        sub["ks"] = stats.ks_uniform(_cdf_from_leaves(density, leaves, s[:, 0], total))
    p_value = stats.bonferroni_min([r.p_value for r in sub.values()]) if n_valid else 1.0
    if n_valid == 0:
        failures.append("no valid samples to test")

    worst = _worst_cells(dom, edges, counts, expected)
    if p_value <= alpha and worst:
        w = worst[0]
        messages.append(f"largest discrepancy at x≈{np.round(w['point'], 4).tolist()}: "
                        f"observed {w['observed']:.0f}, expected {w['expected']:.1f}")
    details = {
        "domain": repr(dom), "resolution": list(res), "sample_dim": k,
        "tests": {key: {"statistic": r.statistic, "p_value": r.p_value,
                        **({"dof": r.dof, "n_bins": r.n_bins, "n_pooled": r.n_pooled}
                           if isinstance(r, stats.Chi2Result) else {})}
                  for key, r in sub.items()},
        "pdf_integral": total, "quadrature_error": err_bound, "pdf_evaluations": n_evals,
        "n_valid": n_valid, "worst_cells": worst, "seed": seed,
    }
    histogram = {"edges": [e.tolist() for e in edges], "observed": counts,
                 "expected": expected}
    return CheckResult(name=name, passed=CheckResult.decide(p_value, alpha, failures),
                       p_value=p_value, statistic=full.statistic, alpha=alpha, n_samples=n,
                       seconds=time.perf_counter() - t0, details=details,
                       messages=tuple(messages), failures=tuple(failures),
                       artifacts={"histogram": histogram})


def check_inverse(sample, inverse, sample_dim: int, *, n_samples: int = 100_000,
                  seed: int = 0, atol: float = 1e-7, name: str | None = None) -> CheckResult:
    """Round trip of a CDF inversion: ``inverse(sample(u)) ≈ u``.

    Passes iff every component satisfies ``|u' - u| <= atol`` (1e-7 by default: about
    one float32 ulp near 1, so any wrong inverse fails while float64 code has a wide
    margin; tighten it to hold float64 code to float64 accuracy). Reports the worst
    error in absolute terms and in float64 ulps of ``u``, with its ``u -> x -> u'`` chain.

    Examples
    --------
    >>> import numpy as np, mcverify as mv
    >>> r = mv.check_inverse(np.sqrt, np.square, 1, n_samples=1000)
    >>> r.passed, r.details["max_abs_error"] < 1e-15
    (True, True)
    """
    t0 = time.perf_counter()
    v.callable_("sample", sample)
    v.callable_("inverse", inverse)
    k = v.integer("sample_dim", sample_dim, minimum=1)
    n = v.integer("n_samples", n_samples, minimum=1)
    seed = v.seed("seed", seed)
    atol = v.real("atol", atol, minimum=0.0)
    v.memory("n_samples", n, 8 * 4 * k, "uniform numbers, points and round trips")
    name = name or f"inverse:{_name_of(inverse, 'inverse')}"
    u = np.random.default_rng(seed).random((n, k))
    x = np.asarray(sample(u))
    u2 = np.asarray(inverse(x), dtype=np.float64)
    if u2.shape == (n,) and k == 1:
        u2 = u2.reshape(n, 1)
    if u2.shape != (n, k):
        raise InvalidArgument(f"inverse returned shape {u2.shape}: expected ({n}, {k})")
    err = np.abs(u2 - u)
    err = np.where(np.isfinite(err), err, np.inf)
    per = err.max(axis=1)
    i = int(np.argmax(per))
    ulps = err / np.spacing(np.maximum(np.abs(u), np.finfo(np.float64).tiny))
    failures = []
    bad = int(np.count_nonzero(per > atol))
    xi = np.asarray(x[i]).tolist() if np.ndim(x) > 1 else float(np.asarray(x)[i])
    chain = f"u={u[i].tolist()} -> x={xi} -> u'={u2[i].tolist()}"
    if bad:
        failures.append(f"{bad} of {n} round trips off by more than atol={atol:g}; "
                        f"worst {per[i]:.3g}: {chain}")
    details = {"max_abs_error": float(per[i]), "max_ulps": float(ulps[i].max()),
               "median_abs_error": float(np.median(per)), "n_bad": bad, "atol": atol,
               "worst": {"u": u[i].tolist(), "x": xi, "u_prime": u2[i].tolist()},
               "seed": seed}
    return CheckResult(name=name, passed=not failures, p_value=None, statistic=float(per[i]),
                       alpha=0.0, n_samples=n, seconds=time.perf_counter() - t0,
                       details=details, messages=(f"worst round trip: {chain}",),
                       failures=tuple(failures))


def check_same_distribution(sample_a, sample_b, domain, *, n_samples: int = 1_000_000,
                            resolution=None, alpha: float = 0.01, seed: int = 0,
                            sample_dim: int | None = None,
                            name: str | None = None) -> CheckResult:
    """Two-sample test that two samplers draw from the same distribution.

    For regression-checking a sampler without a closed-form pdf against its previous
    version, or ours against Mitsuba's. ``sample_a``/``sample_b`` are sampler callables
    (fed independent uniform numbers) or arrays of points. Sub-tests, combined by
    Bonferroni: χ² homogeneity on a shared histogram (edges from both samples' pooled
    quantiles would depend on the data, so uniform parameter cells are used), on 2-D
    domains χ² of both marginals, and in 1-D the two-sample Kolmogorov–Smirnov test.

    Examples
    --------
    >>> import numpy as np, mcverify as mv
    >>> a = lambda u: np.sqrt(u[:, :1])               # density 2x on [0, 1]
    >>> b = lambda u: np.maximum(u[:, :1], u[:, 1:])  # max of two uniforms: also 2x
    >>> mv.check_same_distribution(a, b, "interval", n_samples=50_000,
    ...                            sample_dim=2).passed
    True
    """
    t0 = time.perf_counter()
    dom, n, res, alpha, seed, k = _histogram_test_iv(domain, n_samples, resolution, alpha,
                                                     seed, sample_dim, min_samples=2)
    name = name or "same_distribution"
    seqs = np.random.SeedSequence(seed).spawn(2)
    draws, failures = [], []
    for label, smp, seq in (("sample_a", sample_a, seqs[0]), ("sample_b", sample_b, seqs[1])):
        if callable(smp):
            u, x = _draw(smp, np.random.default_rng(seq), n, k, dom.dim, name=label)
        else:
            try:
                x = np.asarray(smp, dtype=np.float64)
            except (TypeError, ValueError):
                x = None
            if x is None or x.ndim not in (1, 2) or x.shape[0] < 2:
                raise InvalidArgument(f"{label}: must be a sampler callable or an array "
                                      f"of points (n, {dom.dim})")
            x = v.points(label, x, x.shape[0], dom.dim)
            u = np.full((x.shape[0], 1), np.nan)
        draws.append((label, x, u))
    res = res or dom.default_resolution(min(x.shape[0] for _, x, _ in draws))
    edges = _edges(None, res)
    hists = []
    for label, x, u in draws:
        h, _, f = _histogram(x, u, dom, edges, what=label + " point")
        hists.append(h)
        failures += f
    ha, hb = hists
    sub = {"chi2": stats.chi2_homogeneity(ha, hb)}
    if dom.param_dim == 2:
        sub["chi2_axis0"] = stats.chi2_homogeneity(ha.sum(axis=1), hb.sum(axis=1))
        sub["chi2_axis1"] = stats.chi2_homogeneity(ha.sum(axis=0), hb.sum(axis=0))
    else:
        sa, sb = (_screen(x, u, dom)[0][:, 0] for _, x, u in draws)
        sub["ks"] = stats.ks_2samp(sa, sb)
    p_value = stats.bonferroni_min([r.p_value for r in sub.values()])
    details = {"domain": repr(dom), "resolution": list(res), "seed": seed,
               "tests": {key: {"statistic": r.statistic, "p_value": r.p_value}
                         for key, r in sub.items()}}
    histogram = {"edges": [e.tolist() for e in edges], "a": ha, "b": hb}
    return CheckResult(name=name, passed=CheckResult.decide(p_value, alpha, failures),
                       p_value=p_value, statistic=sub["chi2"].statistic, alpha=alpha,
                       n_samples=n, seconds=time.perf_counter() - t0, details=details,
                       failures=tuple(failures), artifacts={"histogram": histogram})
