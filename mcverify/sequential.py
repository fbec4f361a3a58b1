"""Group-sequential checks: look at the evidence after batches of samples (or passes),
stop as soon as a subject is clearly wrong, and keep the false-alarm rate at α.

A check that streams its data in ``batches`` equal batches looks at the cumulative data
after 1, 2, 4, … batches and after all of them (doubling keeps the number of looks small,
log₂ K + 1, so the final look keeps almost all of α). At each look it computes its usual
p-value on everything so far; the looks are combined by α-spending
(``stats.spending_weights``, O'Brien–Fleming type) into one valid p-value
(``stats.sequential_p_value``), and the check stops at the first look where that is at
most ``stop_alpha``. A correct subject runs its full budget; a clearly wrong one is
rejected after the first batches, reported as "decided at batch k of K".
"""

from __future__ import annotations

import dataclasses
from typing import Callable

from . import _validate as validate
from . import stats
from .errors import InvalidArgument
from .result import CheckResult

__all__ = ["looks", "run_sequential"]


def looks(batches: int) -> list[int]:
    """Batch counts after which a check with ``batches`` batches looks: 1, 2, 4, … and
    ``batches`` itself."""
    out, b = [], 1
    while b < batches:
        out.append(b)
        b *= 2
    return out + [batches]


def run_sequential(look: Callable[[int], CheckResult], *, batches: int, alpha: float,
                   stop_alpha: float | None = None, min_batches: int = 1,
                   spending: str = "obrien-fleming") -> CheckResult:
    """Run a check as a group-sequential test.

    Parameters
    ----------
    look : callable
        ``look(b) -> CheckResult``: the check on the first ``b`` batches (the caller
        draws batches lazily, so stopping early saves their cost).
    batches : int
        K, the full budget in batches.
    alpha : float
        Level the spending function is designed for (the check's level, or the level it
        has to reach to be rejected in its suite).
    stop_alpha : float, optional
        Stop at the first look whose sequential p-value is <= this (default ``alpha``).
        Above ``alpha`` it stops at ``alpha``: a check that stopped at a p-value it does
        not reject at would pass a subject on part of its budget (stop_alpha = 0.3 passed
        a bias that the full budget rejected at p = 2e-7).
    min_batches : int
        First look after this many batches (a test that needs several batches, such as
        a variance across passes).
    spending : str
        The α-spending function (``stats.spending_function``): ``"obrien-fleming"``
        (default: keeps nearly all of α for the final look) or ``"power:RHO"``.

    Returns
    -------
    CheckResult
        The last look's result with ``p_value`` the sequential p-value, ``passed``
        re-decided at the check's ``alpha``, and ``details["sequential"]``: ``batch``
        (k), ``batches`` (K), ``looks``, ``p_looks``, ``weights``, ``stopped_early``. A
        deterministic failure (NaN samples, a wrong normalisation) stops at once.
    """
    k_total = validate.integer("batches", batches, minimum=1)
    alpha = validate.probability("alpha", alpha)
    stop = alpha if stop_alpha is None else min(validate.probability("stop_alpha", stop_alpha),
                                                alpha)
    at = [b for b in looks(k_total) if b >= min_batches] or [k_total]
    try:
        weights = stats.spending_weights([b / k_total for b in at], alpha, spending)
    except ValueError as e:
        raise InvalidArgument(str(e)) from None
    ps: list[float] = []
    for j, b in enumerate(at):
        r = look(b)
        ps.append(1.0 if r.p_value is None else float(r.p_value))
        p_seq = stats.sequential_p_value(ps, weights[:j + 1])
        if r.failures or p_seq <= stop:
            break
    early = b < k_total
    info = {"batch": b, "batches": k_total, "looks": at[:j + 1], "p_looks": ps,
            "weights": weights.tolist(), "spending": spending, "design_alpha": alpha, "stop_alpha": stop,
            "stopped_early": early}
    note = f"decided at batch {b} of {k_total}" + (" (stopped early)" if early else "")
    p = None if r.p_value is None else p_seq
    return dataclasses.replace(
        r, p_value=p, passed=CheckResult.decide(p, r.alpha, r.failures),
        details=dict(r.details, sequential=info), messages=r.messages + (note,))
