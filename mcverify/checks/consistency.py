"""Consistency of what a sampler reports with each draw and what its other functions say.

A renderer's sampler returns more than a point: the density it drew it with, and often a
weight (a BSDF's ``f · cos / pdf``). The integrator divides by that returned pdf, while
multiple importance sampling evaluates ``pdf(x)`` for the same point from another
strategy. When the two disagree (a Jacobian applied on one path only, a pdf of the
half-vector returned for the direction, a selection probability missed), every image is
biased, yet ``check_sampler`` passes: the points do follow ``pdf``. ``check_pdf_consistency``
draws seeded points and holds each returned pdf to ``pdf(x)``, and each returned weight
to ``f(x) / pdf(x)``, within a relative tolerance that admits rounding only."""

from __future__ import annotations

import time

import numpy as np

from .. import _validate as validate
from ..errors import InvalidArgument
from ..result import CheckResult
from .sampler import _name_of

#: Default relative tolerance: two float64 computations of one density agree to far
#: better than 1e-6; float32 ones (Mitsuba's GGX at α = 0.01, 80°: 6e-5) to 1e-3.
RTOL64, RTOL32 = 1e-6, 1e-3


def _not_half(what: str, a: np.ndarray) -> np.ndarray:
    """``a``, or InvalidArgument where it is float16: its rounding (5e-4) is neither
    float64's tolerance nor safely inside float32's."""
    if a.dtype == np.float16:
        raise InvalidArgument(f"{what}: float16 values; judge a float32 or float64 version "
                              "(float16's 11-bit significand rounds by up to 5e-4, which "
                              "the default tolerances would read as disagreement)")
    return a


def _parts(out, n: int):
    """(x, pdf, weight or None) from what ``sample`` returned, or InvalidArgument."""
    if not isinstance(out, (tuple, list)) or len(out) not in (2, 3):
        raise InvalidArgument(
            f"sample returned {validate._show(out)}: expected a tuple (points, pdf) or "
            "(points, pdf, weight); a sampler that returns points only is check_sampler's "
            "subject")
    x = validate.as_array(lambda: f"sample's points {validate._show(out[0])}", out[0])
    if x.ndim not in (1, 2) or x.shape[0] != n or x.shape[1:] == (0,):
        # the width is read from the array: a transposed (d, n) one was "expected (n, n)"
        raise InvalidArgument(
            f"sample's points: shape {x.shape}, expected ({n}, d), a row of d >= 1 "
            f"coordinates per draw, or ({n},) on an interval"
            + (validate.transposed(out[0]) if x.ndim == 2 and x.shape[1] == n else ""))
    x = validate.points("sample", x, n, x.shape[1] if x.ndim == 2 else 1)
    p_raw = _not_half("sample's pdf", validate.as_array("sample's pdf", out[1]))
    p = validate.values("sample's pdf", out[1], n)     # out[1]: a Dr.Jit array's width
    w_raw = None if len(out) == 2 else out[2]          # as given: a Dr.Jit array's hint
    return x, p, p_raw.dtype, w_raw


def _channels(what: str, v, n: int, dtypes: list) -> np.ndarray:
    """A weight or value as (n, c) float64: (n,) is one channel, one number that value
    for every row (a constant, as a constant pdf is)."""
    a = _not_half(what, validate.as_array(what, v))
    if not validate.real_dtype(a.dtype):
        raise InvalidArgument(f"{what}: dtype {a.dtype}, expected real numbers")
    dtypes.append(a.dtype)
    if validate.drjit(v) and a.ndim in (1, 2) and a.shape[-1] == 1:
        # a Dr.Jit array of width 1 is one value for every row, as for the pdf: a constant
        # albedo's mi.Color3f (numpy's (3, 1)) or an mi.Float was refused (a read-only
        # review)
        a = np.full(n, a[0]) if a.ndim == 1 else np.broadcast_to(a[:, 0], (n, a.shape[0]))
    if a.shape == ():
        a = np.full(n, a)
    if a.shape == (n,):
        a = a.reshape(n, 1)
    if a.ndim != 2 or a.shape[0] != n:
        # a (channels, n) array, Dr.Jit's mi.Color3f as numpy reads it, got no hint
        raise InvalidArgument(f"{what}: shape {a.shape}, expected ({n},) or ({n}, channels)"
                              + (validate.transposed(v, noun="values")
                                 if a.ndim == 2 and a.shape[1] == n else ""))
    return a.astype(np.float64, copy=False)


def _show(v) -> str:
    """A row in six significant digits (details keep every digit)."""
    return "[" + ", ".join(f"{c:.6g}" for c in np.asarray(v, dtype=np.float64).reshape(-1)) + "]"


def _relative(a, b, tiny):
    """|a - b| / max(|a|, |b|), 0 where they differ by at most ``tiny`` (subnormal
    rounding: below the smallest normal number the relative precision shrinks, and
    two correct computations of a pdf near 1e-318 differ by 5e-6 relative), inf where
    either is not finite."""
    with np.errstate(all="ignore"):     # inf - inf: NaN, the last line's inf
        r = np.abs(a - b) / np.maximum(np.abs(a), np.abs(b))
        r = np.where((np.abs(a - b) <= tiny) & np.isfinite(a), 0.0, r)
    return np.where(np.isfinite(a) & np.isfinite(b), r, np.inf)


#: A returned pdf this large is no density a sampler draws by, but a delta lobe's stand-in
#: (the narrowest lobes the judge meets, GGX at α = 1e-4, peak at 1/(π α²) = 3e7).
DELTA_STAND_IN = 1e15


def _report(rel, tol, rows, u, x, what, differ, returned, expected, failures, details):
    """A failure (and ``details["worst_<what>"]``) for the rows whose relative error
    ``rel`` exceeds ``tol``, naming the worst with its u, x and both values."""
    bad = np.flatnonzero(rel > tol)
    if not bad.size:
        return
    j = int(bad[np.argmax(rel[bad])])
    i = int(rows[j])
    got, want = returned[j], expected[j]
    with np.errstate(all="ignore"):     # 0 / 0 is a channel that agrees
        r = np.where(want != 0, got / np.where(want != 0, want, 1.0),
                     np.where(got == 0, 1.0, np.inf))
    # a weight's channels each get theirs (until 7 December only one-channel values had
    # a ratio, and a BSDF weight off by π in every channel showed none; an outside review)
    ratio = f" (ratio {r[0]:.6g})" if got.size == 1 else f" (ratios {_show(r)})"
    failures.append(f"{bad.size} of {rows.size} {differ} by more than rtol={tol:g}; worst "
                    f"at u={_show(u[i])}: x={_show(x[i])}, returned {_show(got)}, "
                    f"expected {_show(want)}{ratio}")
    details[f"worst_{what}"] = {"u": u[i].tolist(), "x": x[i].tolist(),
                                "returned": got.tolist(), "expected": want.tolist()}


def check_pdf_consistency(sample, pdf, *, sample_dim: int, f=None, n_samples: int = 100_000,
                          rtol: float | None = None, rejection: bool = False, seed: int = 0,
                          name: str | None = None) -> CheckResult:
    """Test that the pdf (and weight) a sampler returns with each point agree with
    ``pdf(x)`` (and ``f(x) / pdf(x)``).

    Parameters
    ----------
    sample : callable
        ``sample(u)``: uniform ``u`` of shape (n, sample_dim) -> ``(x, p)`` or
        ``(x, p, weight)``: points (n, d), the density each was drawn with (n,), and
        optionally its weight (n,) or (n, channels), e.g. a BSDF's ``f · cos / pdf``.
    pdf : callable
        ``pdf(x)``: points (n, d) -> (n,), the density another strategy's MIS weight
        reads.
    sample_dim : int
        Uniform numbers per draw.
    f : callable, optional
        ``f(x)`` -> (n,) or (n, channels), the value the weight divides by the pdf
        (a BSDF's ``f · cos``). Required to check a returned weight; given without one, an
        error.
    n_samples : int
        Draws (1e5 by default; the check is exact per row, not statistical).
    rtol : float, optional
        Relative tolerance of each comparison, ``|a - b| <= rtol · max(|a|, |b|)``. By
        default 1e-6, or 1e-3 where any array ``sample``, ``pdf`` or ``f``
        returns is float32 (float16 is refused).
    rejection : bool
        A row of NaN points is a rejected draw and skipped (otherwise a failure).
    seed, name
        As in every check.

    Rows whose returned weight is 0 in every channel, or (no weight returned) whose
    returned pdf is 0, are the sampler's "no sample" answer (Mitsuba's BSDFs below the
    horizon keep a pdf there and return weight 0): no estimator reads their pdf, so they
    are skipped and counted in ``details["no_sample"]``. A pdf of 0 returned with a
    non-zero weight is compared (and fails where ``pdf(x)`` is not 0): the path goes on
    with that weight while MIS reads no density for the draw. That such answers come at
    the right rate is ``check_sampler``'s question (with ``rejection=True``), not this
    one's.

    Not a statistical test: ``p_value`` is None; the check fails on any row out of
    tolerance, or with a negative pdf on either side, and reports how many, the worst,
    and its ``u``.

    Examples
    --------
    >>> import numpy as np, mcverify as mv
    >>> def cosine(u):                      # returns the density of θ, not of the direction
    ...     r, phi = np.sqrt(u[:, 0]), 2 * np.pi * u[:, 1]
    ...     z = np.sqrt(1 - u[:, 0])
    ...     x = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    ...     return x, 2 * z * np.sqrt(u[:, 0])
    >>> r = mv.check_pdf_consistency(cosine, lambda x: x[:, 2] / np.pi, sample_dim=2)
    >>> r.passed
    False
    """
    t0 = time.perf_counter()
    validate.callable_("sample", sample)
    validate.callable_("pdf", pdf)
    if f is not None:
        validate.callable_("f", f)
    k = validate.integer("sample_dim", sample_dim, minimum=1)
    n = validate.integer("n_samples", n_samples, minimum=1)
    if rtol is not None:
        rtol = validate.real("rtol", rtol, minimum=0.0)
    rejection = validate.boolean("rejection", rejection)
    seed = validate.seed("seed", seed)
    validate.memory("n_samples", n, 8 * (3 * k + 8), "uniform numbers, points and pdfs",
                    width=("sample_dim", k), least=min(n, 1000))
    name = validate.label(name, f"pdf_consistency:{_name_of(sample, 'sample')}")

    u = np.random.default_rng(seed).random((n, k))
    # a copy: a sampler remapping u in place (np.sqrt(u, out=u), u *= 2) was reported at
    # the u as it had changed it, which draws another point (a mutation review)
    x, p, p_dtype, w_raw = _parts(validate.draw("sample", sample, u.copy()), n)
    dtypes = [x.dtype, p_dtype]
    if f is not None and w_raw is None:
        raise InvalidArgument("f given, but sample returns no weight to check against it: "
                              "return (points, pdf, weight), or leave f out")
    w = None if w_raw is None else _channels("sample's weight", w_raw, n, dtypes)

    failures, messages = [], []
    finite = np.all(np.isfinite(x), axis=1)
    rejected = rejection & np.all(np.isnan(x), axis=1)
    bad_points = int(np.count_nonzero(~finite & ~rejected))
    if bad_points:
        i = int(np.flatnonzero(~finite & ~rejected)[0])
        # a row NaN in some coordinates only is no rejected draw, rejection or not
        hint = ("" if not np.isnan(x[i]).any() else
                "; a rejected draw is a row of NaN in every coordinate" if rejection
                else "; rejection=True reads NaN rows as rejected draws"
                if np.isnan(x[i]).all() else "")
        failures.append(f"{bad_points} points not finite (first x={_show(x[i])} at "
                        f"u={_show(u[i])}){hint}")
    # with a weight, the weight says "no sample": a pdf of 0 returned with a non-zero
    # weight is a draw the path goes on with while MIS reads no density for it
    no_sample = finite & ((p == 0.0) if w is None else np.all(w == 0.0, axis=1))
    rows = np.flatnonzero(finite & ~no_sample)
    details = {"n_compared": int(rows.size), "rejected": int(np.count_nonzero(rejected)),
               "no_sample": int(np.count_nonzero(no_sample)), "seed": seed}
    statistic = 0.0
    if rows.size:
        xs = x[rows]
        q_out = validate.call("pdf", pdf, xs)
        q_raw = _not_half("pdf", validate.as_array(
            lambda: f"pdf returned {validate._show(q_out)}", q_out))
        q = validate.values("pdf", q_out, rows.size)   # q_out: a Dr.Jit array's width
        dtypes.append(q_raw.dtype)      # a float32 pdf(x) is float32's rounding too
        value = None
        if f is not None:
            value = _channels("f", validate.call("f", f, xs), rows.size, dtypes)
            if value.shape[1] != w.shape[1]:
                raise InvalidArgument(f"f returned {value.shape[1]} channels, the weight has "
                                      f"{w.shape[1]}")
        single = any(d == np.float32 for d in dtypes)
        tol = rtol if rtol is not None else (RTOL32 if single else RTOL64)
        # differences within 16 of the coarsest type's smallest subnormals are rounding
        tiny = 16 * float(np.finfo(np.float32 if single else np.float64).smallest_subnormal)
        details["rtol"] = tol
        unbounded = np.flatnonzero(~(np.isfinite(p[rows]) & np.isfinite(q)))
        # equal on both sides, yet no density; inf on both sides was "differ", ratio nan
        for bad, what, key in ((np.flatnonzero((p[rows] < 0.0) | (q < 0.0)), "a negative pdf",
                                "negative_pdf"),
                               (unbounded, "a pdf that is not finite", "nonfinite_pdf")):
            if bad.size:
                j = int(bad[0])
                i = int(rows[j])
                failures.append(
                    f"{bad.size} of {rows.size} draws have {what} (returned or pdf(x)); "
                    f"first at u={_show(u[i])}: x={_show(x[i])}, returned {p[i]:.9g}, "
                    f"pdf(x) {q[j]:.9g}")
                details[key] = int(bad.size)
        rel = _relative(p[rows], q, tiny)
        statistic = float(np.max(rel))
        details["max_pdf_rel_error"] = statistic
        rel_finite = rel.copy()
        rel_finite[unbounded] = 0.0         # reported above, not as a difference
        n_failed = len(failures)
        _report(rel_finite, tol, rows, u, x, "pdf", "returned pdfs differ from pdf(x)",
                p[rows][:, None], q[:, None], failures, details)
        if len(failures) > n_failed and np.max(p[rows][rel_finite > tol]) >= DELTA_STAND_IN:
            # a delta lobe's draw returned with a huge stand-in pdf (some renderers return
            # 1e30 or 1/ε): the ratio said so, not what to do (an outside review)
            failures[-1] += (f"; a returned pdf of {DELTA_STAND_IN:g} or more looks like a "
                             "delta lobe's stand-in: return such draws as rows of NaN and "
                             "check with rejection=True")
        if value is not None:
            with np.errstate(all="ignore"):
                expected = value / q[:, None]
            relw = np.max(_relative(w[rows], expected, tiny), axis=1)
            # no density on either side, yet a weight: f(x) / 0 is no number to compare
            # with (until 7 December "expected [nan] (ratio nan)"), so say what it is
            void = np.flatnonzero((q == 0.0) & (p[rows] == 0.0))
            if void.size:
                j = int(void[0])
                i = int(rows[j])
                failures.append(
                    f"{void.size} of {rows.size} returned weights differ from f(x) / pdf(x) "
                    "= f(x) / 0: the draw returned a pdf of 0 and pdf(x) is 0 too, a "
                    "weight with no density for MIS to read (a delta lobe's "
                    "draws: return them as NaN points with rejection=True); first at "
                    f"u={_show(u[i])}: x={_show(x[i])}, returned weight {_show(w[i])}, "
                    f"f(x) {_show(value[j])}")
                details["weight_without_density"] = int(void.size)
            # pdf(x) = 0 where the returned pdf is not: a pdf failure above
            relw = np.where((q > 0.0) | (p[rows] == 0.0), relw, 0.0)
            relw[void] = 0.0        # reported above, not as a difference
            worst = np.inf if void.size else float(np.max(relw))
            details["max_weight_rel_error"] = worst
            statistic = max(statistic, worst)
            _report(relw, tol, rows, u, x, "weight",
                    "returned weights differ from f(x) / pdf(x)", w[rows], expected,
                    failures, details)
        elif w is not None:
            messages.append("weights returned but not compared: pass f to check them")
    elif details["no_sample"] and w is None:
        # (points, pdf) with every pdf 0 (an array left unfilled) never samples: no
        # evidence of agreement. Weights all 0 are a black BSDF's answer; draws all
        # rejected (a delta lobe's NaN rows) have nothing to agree on
        failures.append(f"no row to compare: {details['no_sample']} of {n} draws returned "
                        f"a pdf of 0 (no-sample answers) and {details['rejected']} were "
                        "rejected; a sampler that never samples fails")
    else:
        # a black BSDF's weights all 0 land here too, not only rejected draws
        messages.append(f"no row to compare: {details['no_sample']} of {n} draws returned "
                        f"a weight of 0 (no-sample answers) and {details['rejected']} were "
                        "rejected")
    messages.append(f"compared {rows.size} of {n} draws ({details['no_sample']} no-sample "
                    f"answers, {details['rejected']} rejected)")
    return CheckResult(name=name, passed=not failures, p_value=None, statistic=statistic,
                       alpha=0.0, n_samples=n, seconds=time.perf_counter() - t0,
                       details=details, messages=tuple(messages), failures=tuple(failures))
