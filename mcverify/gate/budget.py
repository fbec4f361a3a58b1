"""A time-budgeted gate: choose each sampler check's n so the whole run fits the budget.

``plan_budget`` measures this machine in a short calibration (``measure_cost``: every
check tagged ``SCALABLE`` at a small sample count and at growing ones until its cost per
sample shows, which separates its fixed cost, such as the cubature, from its cost per
sample; every other check and the canaries run once, since their cost is fixed), then
gives each scalable check an equal share of the time left:
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

#: Calibration: every sampler check runs at ``_N_SMALL`` samples twice (the first run also
#: pays JIT compilation or loading the kernel cache; the faster counts), then at 4×, 16×,
#: ... that until the larger run takes at least ``_MIN_LARGE_S`` and 3× the smaller one,
#: or reaches ``_N_CAP``. Two close sample counts do not do: on a loaded 2-core machine
#: the cosine check timed at 2^16 and 2^18 gave 0.1 to 150 ns a sample from one run to
#: the next, and 0.1 ns let a 3 s budget choose 10⁹ samples (53 s).
_N_SMALL = 1 << 16
#: The share of the budget calibration (with start-up) may use before it stops timing.
_CALIBRATION_SHARE = 2.0 / 3.0
_N_CAP = 1 << 22
_MIN_LARGE_S = 0.02


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
    startup_seconds: float = 0.0

    @property
    def n_overrides(self) -> tuple[tuple[str, int], ...]:
        return tuple(sorted(self.n_samples.items()))

    def to_dict(self) -> dict:
        return {"budget_seconds": self.budget, "n_samples": dict(self.n_samples),
                "per_sample_ns": dict(self.per_sample_ns),
                "fixed_seconds": dict(self.fixed_seconds),
                "other_seconds": self.other_seconds,
                "startup_seconds": self.startup_seconds,
                "calibration_seconds": self.calibration_seconds,
                "predicted_seconds": self.predicted_seconds, "notes": list(self.notes)}


def _timed(check: Check, seed: int) -> float:
    t0 = time.perf_counter()
    check.run(seed)
    return time.perf_counter() - t0


def measure_cost(run_at, timer=time.perf_counter) -> tuple[float, float]:
    """(fixed seconds, seconds per sample) of a check, where ``run_at(n)`` runs it at n
    samples; see ``_N_SMALL``. The cost per sample is at least half the larger run's
    time per sample, so a load spike on the small runs cannot make it small: a run sized
    by it takes at most about twice its share. Where the fixed cost still dominates at
    ``_N_CAP`` (cubature), the estimate errs towards fewer samples."""
    def timed(n: int) -> float:
        t0 = timer()
        run_at(n)
        return timer() - t0

    t_small = min(timed(_N_SMALL), timed(_N_SMALL))
    n = 4 * _N_SMALL
    t_large = timed(n)
    while n < _N_CAP and (t_large < 3 * t_small or t_large < _MIN_LARGE_S):
        n *= 4
        t_large = timed(n)
    per = max((t_large - t_small) / (n - _N_SMALL), 0.5 * t_large / n)
    return max(t_small - per * _N_SMALL, 0.0), per


def plan_budget(suite: str, pattern: str | None, budget: float, *, seed: int = 0,
                canary: bool = True, n_min: int = 1 << 17, n_max: int = 1_000_000_000,
                startup: float = 0.0) -> BudgetPlan:
    """Sample counts for the checks of ``suite`` selected by ``pattern`` so that
    ``startup`` (seconds already spent, e.g. since the process started), calibration
    and the run take about ``budget`` seconds on this machine."""
    if not budget > 0:
        raise InvalidArgument(f"--budget {budget}: must be a positive number of seconds")
    from .suites import canaries

    t0 = time.perf_counter()
    chosen = select(build_suite(suite), pattern)
    scalable = [c.name for c in chosen if SCALABLE in c.tags]
    suites_at: dict[int, dict[str, Check]] = {}

    def check_at(name: str, n: int) -> Check:
        if n not in suites_at:
            suites_at[n] = {c.name: c for c in build_suite(
                suite, tuple((x, n) for x in scalable))}
        return suites_at[n][name]

    per, fixed = {}, {}
    # Calibration may use at most two thirds of the budget (start-up included; on a quiet
    # machine the default suite's takes ~10 s, ~12 s with start-up): on cores that
    # other processes keep busy every timed run is slow, and timing all checks took 167 s
    # of a 20 s budget. Checks left untimed run at the minimum n.
    untimed, stopped_at = [], None
    for name in scalable:
        elapsed = startup + time.perf_counter() - t0
        if elapsed > _CALIBRATION_SHARE * budget:
            untimed.append(name)
            stopped_at = elapsed if stopped_at is None else stopped_at
            continue
        s = check_seed(seed, name)
        fixed[name], per[name] = measure_cost(lambda n, name=name: check_at(name, n).run(s))
    other = sum(_timed(c, check_seed(seed, c.name)) for c in chosen if SCALABLE not in c.tags)
    if canary:
        other += sum(_timed(c, check_seed(seed, "canary:" + c.name)) for c in canaries())
    spent = time.perf_counter() - t0
    n_samples, predicted, notes = allocate(budget, startup + spent, other, fixed, per,
                                           n_min=n_min, n_max=n_max, untimed=len(untimed))
    if untimed:
        n_samples.update((name, n_min) for name in untimed)
        notes += (f"calibration stopped timing sampler checks when start-up and calibration "
                  f"had taken "
                  f"{stopped_at:.1f}s, past two thirds of the {budget:g}s budget "
                  f"({_CALIBRATION_SHARE * budget:.1f}s"
                  + ("; the last timed check ran past it" if per else
                     ": start-up alone took longer, no check was timed") + "): "
                  f"{len(untimed)} of {len(scalable)} sampler checks were not timed and run "
                  f"at the minimum n = {n_min:,} (their time is not in the prediction)",)
    return BudgetPlan(budget, n_samples, {k: v * 1e9 for k, v in per.items()}, fixed, other,
                      spent, predicted, notes, startup)


def allocate(budget: float, spent: float, other: float, fixed: dict[str, float],
             per_sample: dict[str, float], *, n_min: int, n_max: int, untimed: int = 0
             ) -> tuple[dict[str, int], float, tuple[str, ...]]:
    """Equal shares of the time left (``budget - spent - other``) to the checks whose
    cost is ``fixed[name] + per_sample[name] · n`` seconds: ``(n per check, predicted
    total seconds, notes)``. A check whose cost at ``n_min`` is at least its share runs at
    ``n_min``, and the others share what that leaves (with equal shares, a check with 6 s
    of cubature and a 4 s share overran it by 2 s while the others took their full
    shares: a 20 s budget planned at 22 s). ``untimed``: sampler checks calibration left
    untimed (they run at ``n_min``, outside ``fixed``)."""
    left = budget - spent - other
    notes = []
    n_samples = {}
    if fixed:
        floor = {x: fixed[x] + per_sample[x] * n_min for x in fixed}
        rest, room = list(fixed), left
        while rest:
            share = room / len(rest)
            low = [x for x in rest if floor[x] >= share]
            if not low:
                break
            rest = [x for x in rest if x not in low]
            room -= sum(floor[x] for x in low)
        for name in fixed:
            # in floats, capped before the int (a budget of 1e308 s made an infinite n)
            n = (min((share - fixed[name]) / max(per_sample[name], 1e-15), n_max)
                 if name in rest else 0)
            n_samples[name] = min(max(int(n), n_min), n_max)
    too_small = (f"budget {budget:g}s is too small: start-up and calibration took "
                 f"{spent:.1f}s and the fixed-size checks {other:.1f}s; ")
    short = left < sum(floor.values()) if fixed else left < 0
    if short and (fixed or untimed):
        # untimed ones scale with n too, but run at the minimum (it said "no selected
        # check scales with n" of 28 untimed sampler checks)
        notes.append(too_small + f"every sampler check runs at the minimum n = {n_min:,}")
    elif short:             # nothing scales with n: said, as where the sampler checks' are
        notes.append(too_small + "no selected check scales with n, so the run takes about "
                     f"{spent + other:.1f}s")
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
