"""The built-in subjects and suites: where the judge meets the subjects.

A suite is a list of named checks run at one family-wise α (Holm across checks), plus
the *canaries*: known-wrong samplers that must be rejected, or the gate itself fails
("judge has no teeth"). Each check's seed derives from the suite seed and the check's
name, so selecting checks with ``-k`` does not change any check's result.
"""

from __future__ import annotations

import fnmatch
import time
import zlib
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy import stats as sps

from . import checks
from .domains import Interval
from .provenance import provenance
from .result import CheckResult, SuiteResult

__all__ = ["Check", "SUITES", "build_suite", "run_suite", "canaries", "check_seed"]


@dataclass(frozen=True)
class Check:
    """A named, seeded check: ``run(seed) -> CheckResult``."""

    name: str
    run: Callable[[int], CheckResult]
    tags: tuple[str, ...] = ()


@dataclass(frozen=True)
class Profile:
    """How hard a suite looks: samples per sampler check, parameter sweep density."""

    n_samples: int
    sweep: bool
    mitsuba_samples: int


SUITES = {
    # "default": the CI gate, each subject at its default parameters, 1e6 samples.
    "default": Profile(n_samples=1_000_000, sweep=False, mitsuba_samples=1_000_000),
    # "full": nightly, parameter sweeps (extremes included) at 2e6 samples.
    "full": Profile(n_samples=2_000_000, sweep=True, mitsuba_samples=2_000_000),
}


def check_seed(suite_seed: int, name: str) -> int:
    """Seed of one check: stable across runs, independent of which checks are selected."""
    return int(np.random.SeedSequence([suite_seed, zlib.crc32(name.encode())]).generate_state(1)[0])


def _domain(spec):
    name, args = spec
    return Interval(*args) if name == "interval" else name


def _sweep_values(warp):
    """Parameter sets for the full suite: defaults, then each range's ends and middle."""
    sets = [warp.defaults]
    for i, (lo, hi) in enumerate(warp.ranges):
        log = warp.params[i] in warp.log_scale
        mid = float(np.sqrt(lo * hi)) if log and lo > 0 else 0.5 * (lo + hi)
        for value in (lo, mid, hi):
            p = list(warp.defaults)
            p[i] = value
            if warp.name == "ggx_vndf" and i > 0:
                continue  # the direction is swept by the property tests
            sets.append(tuple(p))
    seen, out = set(), []
    for s in sets:
        if s not in seen:
            seen.add(s)
            out.append(s)
    return out


def _warp_checks(profile: Profile) -> list[Check]:
    from estimators.warps import WARPS

    out = []
    for warp in WARPS.values():
        for params in (_sweep_values(warp) if profile.sweep else [warp.defaults]):
            tag = ",".join(f"{k}={v:g}" for k, v in zip(warp.params, params))
            label = f"{warp.name}({tag})" if tag else warp.name

            def run_sampler(seed, w=warp, p=params, label=label):
                return checks.check_sampler(
                    lambda u: w.sample(u, *p), lambda x: w.pdf(x, *p),
                    _domain(w.domain_spec(*p)), n_samples=profile.n_samples, seed=seed,
                    sample_dim=w.sample_dim, name="sampler:" + label)

            out.append(Check("sampler:" + label, run_sampler, ("estimators", "warp")))
            if warp.invert is not None:
                def run_inverse(seed, w=warp, p=params, label=label):
                    return checks.check_inverse(
                        lambda u: w.sample(u, *p), lambda x: w.invert(x, *p), w.sample_dim,
                        seed=seed, atol=1e-9, name="inverse:" + label)

                out.append(Check("inverse:" + label, run_inverse, ("estimators", "inverse")))
    return out


def _scipy_checks(profile: Profile) -> list[Check]:
    """scipy.stats distributions sampled by inverting their CDF (``ppf``)."""
    subjects = [("beta(2,5)", sps.beta(2, 5), Interval(0.0, 1.0)),
                ("norm", sps.norm(), Interval(-9.0, 9.0)),
                ("triang(0.3)", sps.triang(0.3), Interval(0.0, 1.0))]
    out = []
    for label, dist, dom in subjects:
        def run(seed, d=dist, dom=dom, label=label):
            return checks.check_sampler(lambda u: d.ppf(u[:, 0]), lambda x: d.pdf(x[:, 0]), dom,
                                        n_samples=profile.n_samples, seed=seed,
                                        name="scipy:" + label)

        out.append(Check("scipy:" + label, run, ("scipy",)))
    return out


def _mitsuba_checks(profile: Profile) -> list[Check]:
    from . import mitsuba as mv_mitsuba

    choice = mv_mitsuba.choose_variant()
    vectorised = not choice.variant.startswith("scalar")
    # A scalar variant calls Python per sample (~1.5 µs): 10x fewer samples keeps the
    # gate fast; the test still has power against gross errors.
    n = profile.mitsuba_samples if vectorised else profile.mitsuba_samples // 10
    out = []
    for w in mv_mitsuba.mitsuba_warps():
        def run(seed, w=w):
            return checks.check_sampler(w.sample, w.pdf, w.domain, n_samples=n, seed=seed,
                                        sample_dim=w.sample_dim, name="sampler:" + w.name)

        out.append(Check("sampler:" + w.name, run, ("mitsuba",)))
        if w.invert is not None:
            def run_inv(seed, w=w):
                # float32 round trips lose up to ~2e-4 near the poles (Beckmann at
                # z = 1 - 2e-7): conditioning of float32 points, not a wrong inverse.
                return checks.check_inverse(w.sample, w.invert, w.sample_dim,
                                            n_samples=min(n, 100_000), seed=seed, atol=1e-3,
                                            name="inverse:" + w.name)

            out.append(Check("inverse:" + w.name, run_inv, ("mitsuba",)))
    return out


def _estimator_checks(profile: Profile) -> list[Check]:
    try:
        from estimators import subjects
    except ImportError:
        return []
    return [Check(c.name, c.run, ("estimators", "mc")) for c in subjects.estimator_checks(
        checks, n=200_000 if not profile.sweep else 1_000_000)]


def canaries(n_samples: int = 1_000_000) -> list[Check]:
    """Planted bugs the judge must reject on every run of the gate.

    Each is a known-wrong sampler whose rejection probability at 1e6 samples is 1 to
    many decimal places (see tests/mcverify/test_power.py): contamination of a cosine
    sampler by 2 % uniform directions, GGX sampled at α = 0.30 against the pdf of
    α = 0.32, and a cosine pdf scaled by 1.03.
    """
    from estimators import warps as W

    def mixture(u):
        x = W.sample_cosine_hemisphere(u)
        flip = np.random.default_rng(7).random(u.shape[0]) < 0.02
        x[flip] = W.sample_uniform_hemisphere(u[flip])
        return x

    subjects = [
        ("cosine+2%uniform", mixture, W.cosine_hemisphere_pdf),
        ("ggx(0.30)-vs-pdf(0.32)", lambda u: W.sample_ggx(u, 0.30), lambda x: W.ggx_pdf(x, 0.32)),
        ("cosine-pdf*1.03", W.sample_cosine_hemisphere,
         lambda x: 1.03 * W.cosine_hemisphere_pdf(x)),
    ]
    out = []
    for label, smp, pdf in subjects:
        def run(seed, s=smp, p=pdf, label=label):
            return checks.check_sampler(s, p, "hemisphere", n_samples=n_samples, seed=seed,
                                        name=label)

        out.append(Check(label, run, ("canary",)))
    return out


def build_suite(name: str = "default") -> list[Check]:
    """The checks of a built-in suite."""
    profile = SUITES[name]
    return (_warp_checks(profile) + _estimator_checks(profile) + _scipy_checks(profile)
            + _mitsuba_checks(profile))


def select(checks_: list[Check], pattern: str | None) -> list[Check]:
    """Checks whose name contains ``pattern`` (or matches it as a glob with * ? [ ])."""
    if not pattern:
        return checks_
    if any(c in pattern for c in "*?["):
        return [c for c in checks_ if fnmatch.fnmatch(c.name, pattern)]
    return [c for c in checks_ if pattern in c.name]


def _run_guarded(check: Check, seed: int) -> CheckResult:
    """Run a check; a subject that raises is a failed check naming the exception."""
    t0 = time.perf_counter()
    try:
        return check.run(seed)
    except Exception as e:  # noqa: BLE001 - any subject error is a finding, not a crash
        return CheckResult(name=check.name, passed=False, p_value=None, statistic=None,
                           alpha=0.0, n_samples=0, seconds=time.perf_counter() - t0,
                           details={"seed": seed, "exception": type(e).__name__},
                           failures=(f"raised {type(e).__name__}: {e}",))


def run_suite(checks_: list[Check], *, name: str = "default", seed: int = 0,
              alpha: float = 0.01, correction: str = "holm", canary: bool = True,
              progress: Callable[[int, int, CheckResult], None] | None = None,
              extra_provenance: dict | None = None) -> SuiteResult:
    """Run checks and canaries; judge the checks at family-wise ``alpha``."""
    t0 = time.perf_counter()
    results = []
    total = len(checks_) + (3 if canary else 0)
    for i, c in enumerate(checks_):
        r = _run_guarded(c, check_seed(seed, c.name))
        results.append(r)
        if progress:
            progress(i + 1, total, r)
    bitten = []
    if canary:
        for j, c in enumerate(canaries()):
            r = _run_guarded(c, check_seed(seed, "canary:" + c.name))
            bitten.append(r)
            if progress:
                progress(len(checks_) + j + 1, total, r)
    prov = provenance(suite=name, seed=seed, alpha=alpha, correction=correction,
                      **(extra_provenance or {}))
    return SuiteResult.judge(name, results, alpha=alpha, correction=correction,
                             seconds=time.perf_counter() - t0, provenance=prov,
                             canary=tuple(bitten))
