"""A time-budgeted gate: choose each sampler check's n so the whole run fits the budget.

``plan_budget`` measures this machine in a short calibration (every check tagged
``SCALABLE`` run at two small sample counts, the smaller twice, which separates its
fixed cost, such as the cubature, from its cost per sample; every other check and the
canaries run once, since their cost is fixed), then gives each scalable check an equal share of the time left:
``n = (share - fixed) / per_sample``, within ``[n_min, n_max]``. The chosen n are the
suite's ``n_overrides``: the run itself stays seeded (each result is a function of its
seed and n only, and n goes into the JSON), so rerunning with the same n reproduces it
on any machine. ``power_bought`` says what the n buys: the uniform contamination each
sampler check catches at 95 % power (``mcverify.detectable_contamination``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from ..checks import detectable_contamination
from ..errors import InvalidArgument
from .suites import SCALABLE, Check, build_suite, check_seed, select

__all__ = ["BudgetPlan", "plan_budget", "allocate", "power_bought"]

#: Calibration sample counts: large enough that the per-sample cost shows above the
#: fixed cost, small enough that calibrating ~30 checks takes seconds.
_N_CAL = (1 << 16, 1 << 18)


@dataclass(frozen=True)
class BudgetPlan:
    """The chosen sample counts and the measurements behind them."""

    budget: float
    n_samples: dict[str, int]
    per_sample_ns: dict[str, float]
    fixed_seconds: dict[str, float]
    other_seconds: float
    calibration_seconds: float
    predicted_seconds: float
    notes: tuple[str, ...] = field(default=())

    @property
    def n_overrides(self) -> tuple[tuple[str, int], ...]:
        return tuple(sorted(self.n_samples.items()))

    def to_dict(self) -> dict:
        return {"budget_seconds": self.budget, "n_samples": dict(self.n_samples),
                "per_sample_ns": dict(self.per_sample_ns),
                "fixed_seconds": dict(self.fixed_seconds),
                "other_seconds": self.other_seconds,
                "calibration_seconds": self.calibration_seconds,
                "predicted_seconds": self.predicted_seconds, "notes": list(self.notes)}


def _timed(check: Check, seed: int) -> float:
    t0 = time.perf_counter()
    check.run(seed)
    return time.perf_counter() - t0


def plan_budget(suite: str, pattern: str | None, budget: float, *, seed: int = 0,
                canary: bool = True, n_min: int = 1 << 17,
                n_max: int = 1_000_000_000) -> BudgetPlan:
    """Sample counts for the checks of ``suite`` selected by ``pattern`` so that
    calibration plus the run take about ``budget`` seconds on this machine."""
    if not budget > 0:
        raise InvalidArgument(f"--budget {budget}: must be a positive number of seconds")
    from .suites import canaries

    t0 = time.perf_counter()
    chosen = select(build_suite(suite), pattern)
    scalable = [c.name for c in chosen if SCALABLE in c.tags]
    runs = [{c.name: c for c in build_suite(suite, tuple((name, n) for name in scalable))}
            for n in _N_CAL]
    per, fixed = {}, {}
    for name in scalable:
        s = check_seed(seed, name)
        # small, large, small again: the first run also pays JIT compilation or loading
        # the kernel cache, which the run proper will not.
        first = _timed(runs[0][name], s)
        t_large = _timed(runs[1][name], s)
        t_small = min(first, _timed(runs[0][name], s))
        per[name] = max((t_large - t_small) / (_N_CAL[1] - _N_CAL[0]), 1e-10)
        fixed[name] = max(t_small - per[name] * _N_CAL[0], 0.0)
    other = sum(_timed(c, check_seed(seed, c.name)) for c in chosen if SCALABLE not in c.tags)
    if canary:
        other += sum(_timed(c, check_seed(seed, "canary:" + c.name)) for c in canaries())
    spent = time.perf_counter() - t0
    n_samples, predicted, notes = allocate(budget, spent, other, fixed, per, n_min=n_min,
                                           n_max=n_max)
    return BudgetPlan(budget, n_samples, {k: v * 1e9 for k, v in per.items()}, fixed, other,
                      spent, predicted, notes)


def allocate(budget: float, spent: float, other: float, fixed: dict[str, float],
             per_sample: dict[str, float], *, n_min: int, n_max: int
             ) -> tuple[dict[str, int], float, tuple[str, ...]]:
    """Equal shares of the time left (``budget - spent - other``) to the checks whose
    cost is ``fixed[name] + per_sample[name] · n`` seconds: ``(n per check, predicted
    total seconds, notes)``."""
    left = budget - spent - other
    notes = []
    n_samples = {}
    if fixed:
        share = left / len(fixed)
        for name in fixed:
            n = int((share - fixed[name]) / per_sample[name]) if share > fixed[name] else 0
            n_samples[name] = min(max(n, n_min), n_max)
        if left < sum(fixed[x] + per_sample[x] * n_min for x in fixed):
            notes.append(f"budget {budget:g}s is too small: calibration took {spent:.1f}s and "
                         f"the fixed-size checks {other:.1f}s; every sampler check runs at "
                         f"the minimum n = {n_min:,}")
    predicted = spent + other + sum(fixed[x] + per_sample[x] * n_samples[x] for x in fixed)
    return n_samples, predicted, tuple(notes)


def power_bought(results, alpha: float, n_checks: int | None = None) -> dict[str, float]:
    """For each sampler check result: the mixture weight ε of uniform contamination it
    catches with 95 % power at the level Holm gives the most significant of the family
    (α / ``n_checks``, default the number of results: the worst case, so the figure is
    an upper bound); None where the pdf is itself uniform (a uniform admixture changes
    nothing)."""
    level = alpha / max(n_checks or len(results), 1)
    out = {}
    for r in results:
        if "histogram" in r.artifacts and "expected" in r.artifacts["histogram"]:
            eps = detectable_contamination(r, alpha=level)
            out[r.name] = eps if eps != float("inf") else None
    return out
