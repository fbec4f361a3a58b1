"""Numerical stability of a sampler, by property-based search (hypothesis).

A χ² test draws uniform numbers at random, so it almost never meets the inputs where
samplers break: u = 0, the largest float below 1, subnormals, a few ulps from either
end, combinations of those across coordinates. ``check_stability`` tries every corner
of such edge values first, then lets hypothesis search the unit cube (its shrinking
brings a failure down to the simplest u that shows it), and holds each u to the
contract a renderer relies on: the point is finite and inside the domain, its density
finite and not negative, its inverse finite and inside [0, 1]."""

from __future__ import annotations

import itertools
import random
import time

import numpy as np

from .. import _validate as validate
from ..domains import as_domain
from ..errors import InvalidArgument
from ..result import CheckResult
from .sampler import _name_of

#: Edge values of each coordinate of u tried in every combination before the search:
#: zero, the smallest subnormal and normal, tiny values, 2^-24 and 2^-53, a half, and
#: the largest floats below 1 in float32 (1 - 2^-24) and float64 (1 - 2^-53).
EDGES = (0.0, 5e-324, 2.2250738585072014e-308, 1e-300, 2.0 ** -53, 2.0 ** -24, 0.5,
         1.0 - 2.0 ** -24, 1.0 - 2.0 ** -53)
#: float32: the values above that float32 holds (its subnormals and ends).
EDGES32 = (0.0, 1e-45, 1.1754944e-38, 2.0 ** -24, 0.5, 1.0 - 2.0 ** -24)


def _u_strategy(dim: int, dtype):
    from hypothesis import strategies as st

    width = 32 if dtype == np.float32 else 64
    edges = EDGES32 if dtype == np.float32 else EDGES
    near = float(np.asarray(1e-6, dtype=dtype))          # representable in the width
    far = float(np.asarray(1.0 - 1e-6, dtype=dtype))
    one = st.one_of(st.sampled_from(edges),
                    st.floats(0.0, 1.0, exclude_max=True, width=width),
                    st.floats(0.0, near, width=width),
                    st.floats(far, 1.0, exclude_max=True, width=width))
    return st.tuples(*([one] * dim))


def _first_problem(u, sample, pdf, inverse, domain, rejection, dtype) -> str | None:
    """What is wrong at u (a tuple), or None: the contract of one sample."""
    with np.errstate(all="ignore"):     # the findings are reported, not warned about
        return _problem_at(np.asarray([u], dtype=dtype), sample, pdf, inverse, domain,
                           rejection)


def _problem_at(row, sample, pdf, inverse, domain, rejection) -> str | None:
    try:
        x = np.asarray(sample(row))
    except Exception as e:  # noqa: BLE001 - a sampler that raises at some u is the finding
        return f"sample raised {type(e).__name__}: {e}"
    try:
        x = domain.points(x)
    except (ValueError, TypeError) as e:
        return f"sample returned {x!r}, not one point of the {domain!r}: {e}"
    if x.shape[0] != 1:
        return f"sample returned {x.shape[0]} points for one u"
    if rejection and np.all(np.isnan(x)):
        return None                                     # a rejected draw
    if not np.all(np.isfinite(x)):
        return f"point {x[0].tolist()} is not finite"
    if not domain.inside(x)[0]:
        return f"point {x[0].tolist()} lies outside the {domain!r}"
    if pdf is not None:
        try:
            p = np.asarray(pdf(x), dtype=np.float64).reshape(-1)
        except Exception as e:  # noqa: BLE001
            return f"pdf raised {type(e).__name__}: {e} at x={x[0].tolist()}"
        if p.size == 1 and not (np.isfinite(p[0]) and p[0] >= 0.0):
            return f"pdf {p[0]!r} at x={x[0].tolist()} (must be finite and >= 0)"
    if inverse is not None:
        try:
            back = np.asarray(inverse(x), dtype=np.float64).reshape(-1)
        except Exception as e:  # noqa: BLE001
            return f"inverse raised {type(e).__name__}: {e} at x={x[0].tolist()}"
        if not (np.all(np.isfinite(back)) and np.all((back >= 0.0) & (back <= 1.0))):
            return f"inverse {back.tolist()} of x={x[0].tolist()} is not in [0, 1]"
    return None


def check_stability(sample, domain, *, sample_dim: int | None = None, pdf=None,
                    inverse=None, rejection: bool = False, dtype=np.float64,
                    max_examples: int = 2000, seed: int = 0,
                    name: str | None = None) -> CheckResult:
    """Property-based stress test of a sampler's numerical stability.

    Every combination of the edge values ``EDGES`` (``EDGES32`` with ``dtype=np.float32``)
    across u's coordinates is tried (9^d: 9, 81, 729 for d = 1, 2, 3; for d > 3 the
    corners of 0, ½ and the largest float below 1), then hypothesis searches
    ``max_examples`` more u in [0, 1)^d, weighted towards both ends, seeded by ``seed``
    (the same seed, the same examples). Each u must give a finite point inside
    ``domain`` (a row of NaN is a rejected draw with ``rejection=True``), a ``pdf``
    there, if given, finite and not negative, and an ``inverse``, if given, finite and
    in [0, 1]; a callable that raises fails too. The first failure found is shrunk to
    the simplest u that shows it and reported in ``failures`` and ``details["u"]``.

    Not a statistical test: ``p_value`` is None, and a pass says only that no such u
    was found among those tried. ``sample`` is called with one row at a time.

    Examples
    --------
    >>> import numpy as np, mcverify as mv
    >>> fragile = lambda u: np.sqrt(-np.log(u))          # u = 0 gives inf
    >>> r = mv.check_stability(fragile, mv.Interval(0, 50), sample_dim=1)
    >>> r.passed, r.details["u"]
    (False, [0.0])
    """
    t0 = time.perf_counter()
    validate.callable_("sample", sample)
    dom = as_domain(domain)
    k = validate.integer("sample_dim", dom.sample_dim if sample_dim is None else sample_dim,
                         minimum=1)
    if pdf is not None:
        validate.callable_("pdf", pdf)
    if inverse is not None:
        validate.callable_("inverse", inverse)
    rejection = validate.boolean("rejection", rejection)
    if dtype not in (np.float32, np.float64):
        raise InvalidArgument(f"dtype={dtype!r}: np.float32 or np.float64")
    m = validate.integer("max_examples", max_examples, minimum=0)
    seed = validate.seed("seed", seed)
    name = validate.label(name, f"stability:{_name_of(sample, 'sample')}")

    def problem(u):
        return _first_problem(u, sample, pdf, inverse, dom, rejection, dtype)

    edges = EDGES32 if dtype == np.float32 else EDGES
    corner_values = edges if k <= 3 else (0.0, 0.5, edges[-1])
    tried, found = 0, None
    for u in itertools.product(corner_values, repeat=k):
        tried += 1
        if problem(u) is not None:
            found = u
            break
    if found is None and m > 0:
        from hypothesis import HealthCheck, Phase, errors, find, settings

        count = [0]

        def fails(u):
            count[0] += 1
            return problem(u) is not None

        rules = settings(max_examples=m, database=None, deadline=None,
                         suppress_health_check=list(HealthCheck),
                         phases=(Phase.generate, Phase.shrink))
        try:
            found = find(_u_strategy(k, dtype), fails, settings=rules,
                         random=random.Random(seed))
        except errors.NoSuchExample:
            pass
        tried += count[0]
    failures, details = [], {"examples": tried, "seed": seed, "sample_dim": k,
                             "dtype": np.dtype(dtype).name, "u": None, "problem": None}
    if found is not None:
        what = problem(found)
        u = [float(v) for v in found]
        details.update(u=u, problem=what)
        failures.append(f"u={u}: {what}")
    messages = (f"{tried} values of u tried: the {len(corner_values)}^{k} corners of edge "
                f"values, then a search of up to {m} (seed {seed})",)
    return CheckResult(name=name, passed=not failures, p_value=None, statistic=None,
                       alpha=0.0, n_samples=tried, seconds=time.perf_counter() - t0,
                       details=details, messages=messages, failures=tuple(failures))
