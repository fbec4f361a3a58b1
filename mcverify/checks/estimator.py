"""Checks of Monte Carlo estimators: unbiasedness, variance, convergence rate."""

from __future__ import annotations

import dataclasses
import inspect
import time

import numpy as np

from .. import _validate as validate
from .. import stats
from ..errors import InvalidArgument
from ..result import CheckResult

__all__ = ["check_unbiased", "check_variance", "check_convergence"]

#: Tail index below which the variance is taken as infinite: the one-sided 99.9 % upper
#: confidence bound of the Hill estimate must stay above 2 for the CLT to be trusted.
_FINITE_VARIANCE_INDEX = 2.0
#: Fewest samples for the tail test: Hill's estimator uses the sqrt(n) largest values,
#: and below ~30 of them its confidence bound is not worth a verdict.
_MIN_TAIL_SAMPLES = 1000
#: Relative rounding allowance of a mean of float64 values: numpy sums pairwise, so the
#: sum of n values errs by about log2(n)·ε relative to the sum of |x|; 64·ε (1.4e-14)
#: covers n up to 2^64. Spreads and differences within it are rounding, not evidence.
_ROUNDING = 64 * np.finfo(np.float64).eps


def _rounding(samples) -> float:
    """The relative rounding allowance of ``samples`` (validated): ``_ROUNDING`` in
    float32's precision where they are float32. A float32 renderer's perfect estimator
    (p ∝ f) is constant only to float32's ulps (0.1f ± 7e-9), which float64's allowance
    took for a bias and a variance. Float16, 64 of whose ulps are 6 %, gets one ulp
    (9.8e-4): with float64's, a float16 estimator constant at 0.1 (0.0999755859375)
    failed as a bias, told to draw more samples (a mutation review's found-not-fixed)."""
    dtype = validate.numpy_dtype(samples)
    if dtype == np.float32:
        return 64 * float(np.finfo(np.float32).eps)
    if dtype == np.float16:
        return float(np.finfo(np.float16).eps)
    return _ROUNDING


def _expected(v) -> tuple[float, float]:
    """``expected`` validated as a real number, and how far the true value may lie from
    it given as float32 (np.float32(0.1), a float32 renderer's reference): half a
    float32 ulp of it; 0 for any other type. It widens only the comparison with ``v``:
    float32's 64-eps allowance for samples, taken for a float32 expected value until
    7 December, let float64 estimates of spread below 7.6e-6 of the value through with a
    bias of that size (0.5 + 3e-6 against np.float32(0.5): passed, "constant to
    rounding"). Validated first: a float32 array (a Dr.Jit mi.Float, numpy's (1,)
    float32) reached np.float32 and raised numpy's bare TypeError, "only 0-dimensional
    arrays can be converted to Python scalars" (an outside review)."""
    x = validate.real("expected", v)
    v = validate.scalar(v)          # a 0-d tensor's number, its type kept
    if np.asarray(v).dtype != np.float32:
        return x, 0.0
    return x, 0.5 * float(np.spacing(np.abs(np.float32(v))))


def _takes(name: str, fn, args: tuple, takes: str) -> None:
    """InvalidArgument naming ``name`` where ``fn`` cannot be called with ``args``: a
    wrong signature is the caller's mistake, named before any work (it raised Python's
    bare TypeError from inside the check). A callable without a signature to read (a
    builtin) is called as it is."""
    try:
        inspect.signature(fn).bind(*args)
    except TypeError:
        raise InvalidArgument(f"{name}={validate._show(fn)}: must take {takes}") from None
    except ValueError:
        pass


def check_unbiased(samples, expected, *, alpha: float = 0.01, name: str = "unbiased",
                   batches: int | None = None, stop_alpha: float | None = None) -> CheckResult:
    """One-sample t-test that per-sample estimates ``f(X)/p(X)`` have mean ``expected``.

    The t-test leans on the central limit theorem, which needs finite variance. An
    importance sampler whose pdf falls to zero faster than the integrand has infinite
    variance: its mean still converges, but the t-test's p-values are meaningless. So the
    tail is measured first (Hill's estimator on the largest deviations); if even the
    upper 99.9 % bound of the tail index is below 2, the check fails with
    "infinite variance" instead of trusting the CLT.

    Parameters
    ----------
    samples : 1-D array or callable
        i.i.d. per-sample estimates (at least 2); or ``draw(b)``, the estimates of batch
        ``b`` (see ``batches``; without it, one batch: ``draw(0)``).
    expected : float
        The true value of the integral.
    alpha : float
        Significance level (a suite corrects it for multiplicity).
    batches : int, optional
        With ``samples`` a callable ``draw(b) -> 1-D array`` (the estimates of batch
        ``b``, independent of the other batches): a group-sequential test over
        ``batches`` batches (:mod:`mcverify.sequential`). It stops drawing as soon as the
        bias is clear; ``details["sequential"]`` says at which batch it decided.
    stop_alpha : float, optional
        Sequential only: stop early when the sequential p-value reaches this (default
        ``alpha``; a suite passes the level the check must reach within it; above
        ``alpha``, ``alpha``: stopping early never passes a subject).

    Examples
    --------
    >>> import numpy as np, mcverify as mv
    >>> x = np.random.default_rng(0).random(100_000) * np.pi
    >>> mv.check_unbiased(np.pi * np.sin(x), 2.0).passed   # ∫₀^π sin = 2
    True
    >>> draw = lambda b: 1.1 * np.random.default_rng(b).random(10_000)   # mean 0.55
    >>> r = mv.check_unbiased(draw, 0.5, batches=16)
    >>> r.passed, r.details["sequential"]["batch"]    # a 10 % bias: decided at batch 1
    (False, 1)
    """
    name = validate.label(name, "unbiased")
    if stop_alpha is not None:      # checked with or without batches, which use it
        validate.probability("stop_alpha", stop_alpha)
    if callable(samples):
        from ..sequential import run_sequential

        k = validate.integer("batches", 1 if batches is None else batches, minimum=1)
        alpha = validate.probability("alpha", alpha)
        validate.real("expected", expected)     # before any draw: a batch may be a render
        _takes("samples", samples, (0,), "(batch), the batch's index, and return its "
               "estimates")
        drawn: list[np.ndarray] = []

        def look(b):
            t0 = time.perf_counter()
            while len(drawn) < b:
                v = samples(len(drawn))
                validate.samples_1d(f"samples({len(drawn)})", v)
                # its own dtype: float32 rounds as float32
                drawn.append(np.asarray(validate.host(v)))
            r = check_unbiased(np.concatenate(drawn), expected, alpha=alpha, name=name)
            upper = r.details.get("tail_index_upper")
            # An early look neither stops nor counts where its verdict is no
            # deterministic failure, and the final look judges on every estimate:
            # - a heavy tail: the tail test is a statistical one (a 99.9 % bound); taken
            #   at every look it failed a finite-variance estimator (Pareto index 2.2,
            #   16 batches of 2000) on 8 of 300 seeds, the one-shot check on the same
            #   estimates on none (and the look's t-test would be invalid);
            # - estimates constant at a value other than expected: a rare-hit estimator
            #   (p = 0.01, batches of 200) has a first batch of zeros 13 % of the time,
            #   and stopping there failed it on 60 of 400 seeds at α = 0.05; the later
            #   batches are the samples the message asks for.
            if b < k and (upper is not None and upper < _FINITE_VARIANCE_INDEX
                          or r.details.get("constant")):
                r = dataclasses.replace(r, p_value=None, passed=True, failures=tuple(
                    f for f in r.failures
                    if not f.startswith(("variance appears infinite", "every sample is "))))
            return dataclasses.replace(r, seconds=time.perf_counter() - t0)

        t0 = time.perf_counter()
        r = run_sequential(look, batches=k, alpha=alpha, stop_alpha=stop_alpha)
        return dataclasses.replace(r, seconds=time.perf_counter() - t0)
    if batches is not None:
        raise InvalidArgument(f"batches={batches}: only with samples given as a callable "
                              "draw(batch) -> estimates")
    t0 = time.perf_counter()
    x = validate.samples_1d("samples", samples)
    # a float32 expected value (np.float32(np.pi), a float32 renderer's reference) is
    # itself rounded to float32's ulps: float64 samples constant at 0.1 failed against
    # np.float32(0.1), "expected is 0.100000001490116" (until 7 December); the true value
    # lies within `given` of it
    rounding = _rounding(samples)
    expected, given = _expected(expected)
    alpha = validate.probability("alpha", alpha)
    failures, messages = [], []
    finite = np.isfinite(x)
    if not finite.all():
        failures.append(f"{np.count_nonzero(~finite)} of {x.size} samples are NaN/Inf "
                        f"(first at index {int(np.flatnonzero(~finite)[0])})")
        x = x[finite]
    with np.errstate(over="ignore", invalid="ignore"):
        scale = float(np.mean(np.abs(x))) if x.size else 0.0
        spread = stats.scaled_std(x) if x.size > 1 else 0.0
    if not (np.isfinite(scale) and np.isfinite(spread)):
        failures.append(f"the samples' mean or variance overflows float64 (largest |x| = "
                        f"{np.abs(x).max():.3g}): rescale the estimates (e.g. divide f "
                        "by a constant) before testing")
        return CheckResult(name=name, passed=False, p_value=None, statistic=None,
                           alpha=alpha, n_samples=int(x.size),
                           seconds=time.perf_counter() - t0,
                           details={"expected": expected}, failures=tuple(failures))
    tol = rounding * max(abs(expected), scale)
    if x.size > 1 and spread <= tol:
        # Constant to rounding (a perfect estimator, p ∝ f): its standard error is rounding
        # noise (1e-19 for 0.1), so the t-test would accuse any last-bit difference.
        # Compare the value itself, within rounding.
        mean = float(np.mean(x))
        ok = abs(mean - expected) <= tol + given
        if not ok:
            # No test can tell these from an estimator that is rarely anything else (a
            # light hit with probability p: all n samples miss it with probability
            # (1 - p)^n, 5 % at n·p = 3): say so, as the failure's likely innocent cause.
            failures.append(f"every sample is {mean:.15g} (to rounding), but expected is "
                            f"{expected:.15g} (an estimator whose other values are rare, "
                            "such as a small light's hits, gives this by chance unless "
                            "n is several times 1/p: draw more samples)")
        return CheckResult(name=name, passed=CheckResult.decide(None, alpha, failures),
                           p_value=None, statistic=None, alpha=alpha, n_samples=int(x.size),
                           seconds=time.perf_counter() - t0,
                           details={"mean": mean, "std_error": 0.0, "expected": expected,
                                    "bias": mean - expected, "constant": True,
                                    "rounding_tolerance": tol + given},
                           messages=("the samples are constant to rounding: compared "
                                     f"exactly, within {tol + given:.2g}",),
                           failures=tuple(failures))
    # against the nearest value the float32 expected may stand for (a composite null:
    # its p-value is the largest over them)
    near = expected + float(np.clip(np.mean(x) - expected, -given, given)) \
        if given and x.size > 1 else expected
    tt = stats.ttest_mean(x, near) if x.size > 1 else None
    tail = stats.hill_tail_index(x) if x.size >= _MIN_TAIL_SAMPLES else None
    if tt is None:      # NaN/Inf removed: the failure above says how many
        failures.append(f"{x.size} finite sample(s) left: the t-test needs at least 2")
    elif tail is None:
        messages.append(f"{x.size} samples: too few to test for a heavy tail; the t-test "
                        "assumes finite variance")
    heavy = tail is not None and tail.upper < _FINITE_VARIANCE_INDEX
    if heavy:
        failures.append(f"variance appears infinite (Hill tail index {tail.index:.2f}, "
                        f"99.9 % upper bound {tail.upper:.2f} < 2): the t-test would be "
                        "invalid; check that the pdf does not vanish where f does not")
    elif tail is not None and tail.index < _FINITE_VARIANCE_INDEX:
        # infinite variance more likely than not, not ruled in by the 99.9 % bound: the
        # t-test's verdict either way is then no evidence (x^-0.75, index 4/3, failed
        # it on 5 of 40 seeds of 10,000 at α = 0.01 saying only "the mean converges
        # slowly"; an outside review)
        messages.append(f"heavy tail (Hill index {tail.index:.2f}, below 2; 99.9 % upper "
                        f"bound {tail.upper:.2f}): the variance may be infinite, and then "
                        "the t-test's p-value is not valid either way; draw more samples "
                        "to settle the tail, or check that the pdf does not vanish where "
                        "f does not")
    elif tail is not None and tail.index < 4:
        messages.append(f"heavy tail (index {tail.index:.2f}): the mean converges slowly")
    p = tt.p_value if tt is not None else None     # no test: not p = 1
    if tt is not None and p <= alpha:
        messages.append(f"mean {tt.mean:.6g} ± {tt.std_error:.2g} differs from {expected:.6g} "
                        f"by {abs(tt.statistic):.1f} standard errors")
    details = {"mean": tt.mean if tt else None, "std_error": tt.std_error if tt else None,
               "expected": expected, "bias": (tt.mean - expected) if tt else None,
               "tail_index": tail.index if tail else None,
               "tail_index_upper": tail.upper if tail else None,
               "max_sample_share": tail.max_share if tail else None}
    return CheckResult(name=name, passed=CheckResult.decide(p, alpha, failures), p_value=p,
                       statistic=tt.statistic if tt else None, alpha=alpha,
                       n_samples=int(x.size), seconds=time.perf_counter() - t0,
                       details=details, messages=tuple(messages), failures=tuple(failures))


def check_variance(samples, expected_variance: float = 0.0, *, alpha: float = 0.01,
                   name: str = "variance") -> CheckResult:
    """Test the variance of per-sample estimates.

    ``expected_variance=0`` is the seed's "perfect estimate": with ``p ∝ f`` every
    sample ``f(X)/p(X)`` equals the integral, so the check passes iff the samples agree
    to rounding. Otherwise a large-sample z-test of ``Var = expected_variance`` that
    uses the fourth moment (no normality assumed).

    Examples
    --------
    >>> import numpy as np, mcverify as mv
    >>> u = np.random.default_rng(0).random(10_000)
    >>> x = np.sqrt(u)                        # p(x) = 2x, f(x) = x: f/p = 1/2
    >>> mv.check_variance(x / (2 * x)).passed
    True
    """
    t0 = time.perf_counter()
    x = validate.samples_1d("samples", samples)
    ev = validate.real("expected_variance", expected_variance)
    if ev < 0:
        raise InvalidArgument(f"expected_variance={ev}: must be >= 0")
    alpha = validate.probability("alpha", alpha)
    name = validate.label(name, "variance")
    failures = []
    if not np.all(np.isfinite(x)):
        failures.append(f"{np.count_nonzero(~np.isfinite(x))} samples are NaN/Inf")
        x = x[np.isfinite(x)]
    if x.size < 2:
        failures.append(f"{x.size} finite sample(s) left: a variance needs at least 2")
        # no statistic, None as every check gives it (NaN was written "nan" in the JSON)
        return CheckResult(name=name, passed=False, p_value=None, statistic=None,
                           alpha=alpha, n_samples=int(x.size),
                           seconds=time.perf_counter() - t0,
                           details={"variance": None, "expected_variance": ev},
                           failures=tuple(failures))
    with np.errstate(over="ignore", invalid="ignore"):
        r = stats.variance_test(x, ev, rounding=_rounding(samples))
    messages = []
    if ev == 0.0:
        # judged on the samples' own scale: neither an underflowing nor an overflowing
        # variance matters to it, only how it is shown
        p = None
        if r.p_value == 0.0:
            failures.append(f"expected zero variance (p ∝ f), measured "
                            f"{_variance_shown(r.variance, x)}")
    elif not (np.isfinite(r.variance) and (np.isfinite(r.statistic)
                                           or r.statistic == -np.inf)):
        failures.append(f"the samples' variance or its standard error overflows float64 "
                        f"(largest |x| = {np.abs(x).max():.3g}): rescale the estimates "
                        "(e.g. divide f by a constant) before testing")
        p = None
    else:
        p = r.p_value
        if p <= alpha:
            why = ("the samples are constant" if r.statistic == -np.inf else
                   f"{abs(r.statistic):.3g} standard errors {'above' if r.statistic > 0 else 'below'} it")
            messages.append(f"sample variance {r.variance:.6g} against the expected "
                            f"{ev:.6g}: {why} (p = {p:.3g})")
    # a constant has variance 0 at any scale (1e300 squared overflowed to inf in the
    # details of a passing result; a read-only review)
    variance = 0.0 if x.size and np.all(x == x.flat[0]) else r.variance
    return CheckResult(name=name, passed=CheckResult.decide(p, alpha, failures), p_value=p,
                       statistic=r.statistic, alpha=alpha, n_samples=int(x.size),
                       seconds=time.perf_counter() - t0,
                       details={"variance": variance, "expected_variance": ev},
                       messages=tuple(messages), failures=tuple(failures))


def _variance_shown(variance: float, x: np.ndarray) -> str:
    """A variance that is not 0 as text: itself where float64 holds it, else the standard
    deviation (estimates of 1e-200 have a variance that underflows to 0, of 1e200 one
    that overflows)."""
    if np.isfinite(variance) and variance > 0.0:
        return f"{variance:.3g}"
    return f"a standard deviation of {stats.scaled_std(x, ddof=1):.3g}"


def _rmse_rounding(v) -> float:
    """The relative RMSE below which estimates ``v`` are exact to rounding: float64's
    ``_ROUNDING``, or where ``v`` is float32 4 of float32's eps (4.8e-7: a float32
    perfect estimator's mean, summed pairwise in float32, errs by up to 1.2 eps; 64 of
    them, ``_rounding``'s allowance for one value, would take a float32 estimator of
    real noise, RMSE 4e-6 at large N, for an exact one)."""
    if validate.numpy_dtype(v) == np.float32:
        return 4 * float(np.finfo(np.float32).eps)
    return _ROUNDING


def _estimate(estimate, n: int, seed: int) -> tuple[float, float]:
    """One estimate as a float and its relative rounding (``_rmse_rounding``), or
    InvalidArgument saying what ``estimate`` returned."""
    out = validate.host(estimate(n, seed))     # a tensor's values (validate.host)
    try:    # None would become NaN, a complex number lose its imaginary part
        value = None if out is None or np.iscomplexobj(out) else \
            np.asarray(out, dtype=np.float64)
    except (TypeError, ValueError):
        value = None
    if value is None or value.size != 1 or isinstance(out, (str, bytes)):
        raise InvalidArgument(f"estimate(n={n}, seed={seed}) returned {validate._show(out)}: "
                              "expected one number")
    return float(value.reshape(())), _rmse_rounding(out)


def check_convergence(estimate, expected, *, ns=(256, 1024, 4096, 16384, 65536),
                      n_seeds: int = 64, expected_slope: float = -0.5,
                      alternative: str = "two-sided", alpha: float = 0.01, seed: int = 0,
                      name: str = "convergence") -> CheckResult:
    """RMSE against N over independent seeds; tests the log-log slope.

    Parameters
    ----------
    estimate : callable
        ``estimate(n, seed) -> float``: one estimate from ``n`` samples.
    expected : float
        The true value.
    ns : sequence of int
        Sample counts (powers of two suit Sobol sequences).
    n_seeds : int
        Independent estimates per N (64: the log RMSE then has a standard error of
        about 0.09 for Gaussian errors).
    expected_slope : float
        −0.5 for i.i.d. Monte Carlo.
    alternative : {"two-sided", "less"}
        ``"two-sided"``: pass iff the slope is consistent with ``expected_slope``.
        ``"less"``: the claim is "at least as steep as ``expected_slope``" (RQMC,
        stratified sampling): fail iff the slope is significantly shallower; a steeper
        one never fails. To verify a faster rate, claim it: ``expected_slope=-1.0``
        fails an "RQMC" that converges as plain MC (−0.5), while ``-0.5`` shows only
        that it is no slower than MC (plain MC passes that too).

    Notes
    -----
    Least squares of :math:`\\log \\mathrm{RMSE}` on :math:`\\log N`; the standard
    error is the jackknife's over the seeds (``stats.loglog_slope``), the test Student's
    t with ``n_seeds - 1`` degrees of freedom; the confidence interval is at
    ``1 - alpha``.

    Examples
    --------
    >>> import numpy as np, mcverify as mv
    >>> est = lambda n, s: np.mean(np.random.default_rng(s).random(n))
    >>> mv.check_convergence(est, 0.5, n_seeds=32).passed    # RMSE ∝ N^-1/2
    True
    """
    t0 = time.perf_counter()
    validate.callable_("estimate", estimate)
    rounding = _ROUNDING                # raised to float32's by float32 estimates
    expected, given = _expected(expected)   # a float32 expected: its own rounding, absolute
    if isinstance(ns, (str, bytes)) or not hasattr(ns, "__iter__"):
        raise InvalidArgument(f"ns={ns!r}: must be a sequence of sample counts")
    ns = [validate.integer(f"ns[{i}]", n, minimum=1) for i, n in enumerate(ns)]
    expected_slope = validate.real("expected_slope", expected_slope)
    twice = next((n for i, n in enumerate(ns) if n in ns[:i]), None)
    if twice is not None:   # it said "need at least 3 distinct" of 3 distinct and a repeat
        raise InvalidArgument(f"ns={ns}: {twice} is given twice; give each sample count "
                              "once")
    if len(ns) < 3:
        raise InvalidArgument(f"ns={ns}: need at least 3 distinct sample counts")
    r = validate.integer("n_seeds", n_seeds, minimum=4)
    alpha = validate.probability("alpha", alpha)
    name = validate.label(name, "convergence")
    if alternative not in ("two-sided", "less"):
        raise InvalidArgument(f"alternative={alternative!r}: expected 'two-sided' or 'less'")
    seeds = np.random.SeedSequence(validate.seed("seed", seed)).generate_state(r * len(ns))
    _takes("estimate", estimate, (1, 2), "(n, seed), the sample count and a seed, and "
           "return one estimate")
    values = np.empty((len(ns), r))
    for i, n in enumerate(ns):
        for j in range(r):
            values[i, j], rj = _estimate(estimate, n, int(seeds[i * r + j]))
            rounding = max(rounding, rj)
    with np.errstate(over="ignore", invalid="ignore"):
        err = values - expected
    failures = []
    if not np.all(np.isfinite(err)):
        bad = np.argwhere(~np.isfinite(err))[0]
        failures.append(f"{np.count_nonzero(~np.isfinite(err))} estimates are NaN/Inf or "
                        f"overflow when expected is subtracted (first: N={ns[bad[0]]}, seed "
                        f"index {bad[1]})")
        err = np.where(np.isfinite(err), err, 0.0)
    # squared at the largest error's scale (the slope does not depend on it): squared as
    # they were, errors of 1e-155 underflowed (a correct estimator failed, "slope 0.000")
    # and finite ones of 1e160 overflowed, until 7 December
    scale = float(np.max(np.abs(err))) or 1.0
    e2 = (err / scale) ** 2
    rmse = scale * np.sqrt(e2.mean(axis=1))
    # float32 estimates (or expected) are exact to float32's rounding: until 7 December
    # np.float32(0.1) against 0.1 at every N was fitted, "slope 0.000, expected -0.5"
    exact = [] if failures else [n for n, e in zip(ns, rmse)
                                 if e <= rounding * max(abs(expected), 1e-300) + given]
    # to rounding: the same points summed in a seed's order differ in the last bits
    spread = np.ptp(values, axis=1) if not failures else None
    if not (exact or failures) and np.all(spread <= rounding * np.max(np.abs(values), axis=1)):
        # one error at each N, no spread: the jackknife's standard error was 0, so a
        # midpoint rule passed expected_slope=-1.0, alternative="less" at p = 1 with
        # "99% CI [-2.000, -2.000]" (until 7 December)
        failures.append(f"estimate(n, seed) returned the same value (to rounding) for all "
                        f"{r} seeds at every N (N={ns[0]}: {values[0, 0]:.15g}): it ignores "
                        "its seed (a "
                        "point set that is not randomised, such as unscrambled Sobol or a "
                        "fixed shift), so its error at each N is one number, with no spread "
                        "over seeds to test a slope; randomise it per seed (scrambled "
                        "Sobol, or a random shift modulo 1)")
    if exact or failures:
        if exact:
            failures.append(f"RMSE is 0 (to rounding) at N={exact}: the estimator is exact "
                            "there, so the log-log slope is undefined; test an exact "
                            "estimator with check_variance(samples, 0) instead")
        return CheckResult(name=name, passed=False, p_value=None, statistic=None,
                           alpha=alpha, n_samples=int(sum(ns) * r),
                           seconds=time.perf_counter() - t0,
                           details={"ns": ns, "rmse": rmse.tolist(), "n_seeds": r,
                                    "expected_slope": expected_slope,
                                    "alternative": alternative},
                           failures=tuple(failures))
    fit = stats.loglog_slope(ns, e2, expected=expected_slope, alternative=alternative,
                             confidence=1.0 - alpha)
    if alternative == "two-sided":
        p = fit.p_value
    else:
        # The claim "slope <= expected" is the null, as every check's claim is: small p
        # (evidence of a shallower slope) means failure: P(T >= t), the upper tail of
        # the fit's t (1 - fit.p_value read exactly 0 below 1e-16; an outside review)
        p = float(stats.t_upper_tail(fit.statistic, r - 1))
    msg = (f"slope {fit.slope:.3f} ({100 * (1 - alpha):.4g}% CI [{fit.ci_low:.3f}, "
           f"{fit.ci_high:.3f}]), "
           f"expected {'<' if alternative == 'less' else ''}{expected_slope}")
    return CheckResult(name=name, passed=CheckResult.decide(p, alpha, failures), p_value=p,
                       statistic=fit.slope, alpha=alpha, n_samples=int(sum(ns) * r),
                       seconds=time.perf_counter() - t0,
                       details={"ns": ns, "rmse": rmse.tolist(), "slope": fit.slope,
                                "slope_std_error": fit.std_error,
                                "ci": [fit.ci_low, fit.ci_high],
                                "expected_slope": expected_slope, "alternative": alternative,
                                "n_seeds": r},
                       messages=(msg,), failures=tuple(failures))
