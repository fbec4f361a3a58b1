"""Numerical stability of a sampler, by property-based search (hypothesis).

A χ² test draws uniform numbers at random, so it almost never meets the inputs where
samplers break: u = 0, the largest float below 1, subnormals, a few ulps from either
end, combinations of those across coordinates. ``check_stability`` tries every corner
of such edge values first, then lets hypothesis search the unit cube (its shrinking
brings a failure down to the simplest u that shows it), and holds each u to the
contract a renderer relies on: the point is finite and inside the domain, its density
finite and not negative, its inverse finite and inside [0, 1]."""

from __future__ import annotations

import contextlib
import itertools
import random
import threading
import time

import numpy as np

from .. import _validate as validate
from ..domains import as_domain, why_outside
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
#: The most dimensions whose 3^d corners of 0, ½ and the largest float below 1 are all
#: tried (59049 u); a path-space sampler's 30 would be 2e14, which exhausted the memory.
MAX_CORNER_DIM = 10


def _corners(edges, k: int):
    """(u rows as tuples, how they were chosen): every combination of ``edges`` up to
    d = 3, of 0, ½ and the top ones up to ``MAX_CORNER_DIM``; beyond it every coordinate
    at one edge value, and each coordinate alone at each with the others at ½."""
    if k <= 3:
        return list(itertools.product(edges, repeat=k)), f"the {len(edges)}^{k} corners"
    ends = (0.0, 0.5, edges[-1])
    if k <= MAX_CORNER_DIM:
        return list(itertools.product(ends, repeat=k)), f"the 3^{k} corners"
    rows = [(e,) * k for e in edges]
    rows += [tuple(e if j == i else 0.5 for j in range(k)) for i in range(k) for e in edges
             if e != 0.5]
    return rows, (f"{len(rows)} corners (each edge value on all {k} coordinates, and on "
                  "each alone)")


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


def _first_problem(rows, sample, pdf, inverse, domain, rejection):
    """(index, what is wrong) of the first row of u (k, d) that breaks the contract, or
    None. The rows go to each callable together; where one raises, row by row, to name
    the u it raised at."""
    with np.errstate(all="ignore"):     # the findings are reported, not warned about
        found = _batch(rows, sample, pdf, inverse, domain, rejection)
        if found is None or found[0] >= 0:
            return found
        if len(rows) == 1:
            return 0, found[1]
        for i in range(len(rows)):
            one = _batch(rows[i:i + 1], sample, pdf, inverse, domain, rejection)
            if one is not None:
                return i, one[1]
        # no single u shows it: the callable breaks on several rows at once (it returns
        # one point whatever it is given, or cannot take a batch), which every other
        # check hands it; reported at the first u, not dropped as a pass
        return 0, f"{found[1]} (given {len(rows)} u in one call; one u at a time it does not)"
    return None


def _call(what, fn, arg, raw=None):
    """(what ``fn(arg)`` returned as an array, None), or (None, why that is a finding):
    it raised, or (pdf, inverse) returned something that is not real numbers. ``raw``, a
    list, is given what ``fn`` returned as it was (a Dr.Jit array's hint differs)."""
    try:
        v = fn(arg)
        if raw is not None:
            raw.append(v)
    except Exception as e:  # noqa: BLE001 - a callable that raises at some u is the finding
        # numba refusing the batch is no fault of the u it was found at: say what it got
        given, row = ("uniform numbers u", "draw") if what == "sample" else \
            ("points x", "point")
        validate.compiled_note(e, what, fn, arg, given, row)
        validate.tensor_note(e, what, arg, given)
        validate.arguments_note(e, what, fn, arg, given, row)
        notes = getattr(e, "__notes__", ())
        return None, f"{what} raised {type(e).__name__}: {e}" + "".join(
            f" ({n})" for n in notes[-1:])
    try:        # a ragged list (numpy's bare ValueError), masked values (read as data)
        if what == "sample":                # (points, pdf): numpy's "inhomogeneous shape"
            validate.not_a_tuple(what, v, len(arg))
        a = validate.as_array(lambda: f"{what} returned {v!r:.80}", v)
    except InvalidArgument as e:
        return None, str(e)
    if what == "sample":                    # the domain's own conversion judges points,
        if a.dtype == np.float16 or not validate.real_dtype(a.dtype):   # not these:
            # None (object) became NaN, a rejected draw; float16 is refused everywhere
            return None, (f"sample returned dtype {a.dtype} points, not float32 or "
                          "float64 numbers")
        return a, None
    if not validate.real_dtype(a.dtype):    # as every other check: complex was read as
        # its real part (np.emath.sqrt(z - 1) as a pdf, 0, passed until 7 December),
        # booleans as 0 and 1, None as NaN
        return None, f"{what} returned dtype {a.dtype} values, not real numbers"
    return np.asarray(a, dtype=np.float64), None


def _batch(rows, sample, pdf, inverse, domain, rejection):
    """``_first_problem`` of one call per callable: (-1, message) where one raised."""
    # a copy: a sampler remapping u in place (u *= 2; u -= 1) changed the corners kept
    # here, reported at u = -1.0 and re-tried changed until 7 December
    raw = []
    x, raised = _call("sample", sample, rows.copy(), raw)
    if raised:
        return -1, raised
    n, dim = rows.shape[0], domain.dim
    if dim > 1 and x.shape == (dim, n) and x.shape != (n, dim):
        # reshaped to (n, dim), a (dim, n) array's rows mixed coordinates of several
        # points: a correct cosine sampler returning mi.Vector3f (numpy's (3, n)) failed
        # at u = [0, 0], "its length is 1.22, not 1: normalise the direction"
        return -1, (f"sample returned shape {x.shape} for {n} u: expected ({n}, {dim})"
                    + validate.transposed(raw[0]))
    try:
        x = domain.points(x)
    except (ValueError, TypeError) as e:
        return -1, f"sample returned {x!r}, not points of the {domain!r}: {e}"
    if x.shape[0] != rows.shape[0]:
        return -1, f"sample returned {x.shape[0]} points for {rows.shape[0]} u"
    rejected = np.all(np.isnan(x), axis=1) if rejection else np.zeros(len(x), bool)
    problems = {}                   # row -> the first thing wrong there
    finite = np.all(np.isfinite(x), axis=1)
    inside = domain.inside(x)
    for i in np.flatnonzero(~rejected & ~(finite & inside)):
        problems[i] = (f"point {x[i].tolist()} is not finite" if not finite[i] else
                       f"point {x[i].tolist()} lies outside the {domain!r}"
                       + why_outside(domain, x[i]))
    good = np.flatnonzero(~rejected & finite & inside)
    if pdf is not None and len(good):
        p, raised = _call("pdf", pdf, x[good])
        if raised:
            return -1, raised
        p = p.reshape(-1)
        if p.size == 1:             # one number: that density everywhere (a constant pdf)
            p = np.broadcast_to(p, len(good))
        if p.size != len(good):
            return -1, f"pdf returned {p.size} values for {len(good)} points"
        for j in np.flatnonzero(~(np.isfinite(p) & (p >= 0.0))):
            problems.setdefault(good[j], f"pdf {float(p[j])!r} at x={x[good[j]].tolist()} "
                                         "(must be finite and >= 0)")
    if inverse is not None and len(good):
        raw_back = []
        back, raised = _call("inverse", inverse, x[good], raw_back)
        if raised:
            return -1, raised
        m, k = len(good), rows.shape[1]
        if k > 1 and back.shape == (k, m) and back.shape != (m, k):
            # flattened row by row, a (k, n) inverse paired each point with others' u:
            # Mitsuba's concentric disk inverse (mi.Point2f, numpy's (2, n)) was reported
            # as [-2.4e-07, -2.4e-07] at x = (-0.707, -0.707), its own [-2.4e-07, 0]
            return -1, (f"inverse returned shape {back.shape} for {m} "
                        f"point{'s' * (m != 1)}: expected ({m}, {k})"
                        + validate.transposed(raw_back[0]))
        if back.size != len(good) * rows.shape[1]:
            return -1, (f"inverse returned {back.size} values for {len(good)} points of "
                        f"{rows.shape[1]} uniform numbers each")
        back = back.reshape(len(good), rows.shape[1])
        ok = np.all(np.isfinite(back) & (back >= 0.0) & (back <= 1.0), axis=1)
        for j in np.flatnonzero(~ok):
            problems.setdefault(good[j], f"inverse {back[j].tolist()} of "
                                         f"x={x[good[j]].tolist()} is not in [0, 1]")
    if not problems:
        return None
    i = min(problems)
    return int(i), problems[i]


#: The search sets process-wide state (numpy's and Python's global generators,
#: hypothesis's constants): checks run from several threads take turns, so that each
#: keeps its own stream (re-entrant: a sampler may run a check of its own).
_PROCESS_STATE = threading.RLock()


@contextlib.contextmanager
def _global_generators(seed: int):
    """numpy's and Python's global generators seeded by ``seed`` for the check, and the
    caller's put back after it: a sampler drawing its own numbers from them (a rejection
    loop on ``np.random.rand``) gives the same verdict for the same seed, and the check
    leaves the caller's streams where they were."""
    saved = np.random.get_state(), random.getstate()
    np.random.set_state(np.random.RandomState(np.random.MT19937(seed)).get_state())
    random.seed(seed)
    try:
        yield
    finally:
        np.random.set_state(saved[0])
        random.setstate(saved[1])


@contextlib.contextmanager
def _without_local_constants():
    """hypothesis (from 6.131) draws floats among the constants of every module loaded
    from outside site-packages, and caches them in ``./.hypothesis/constants``: the u
    searched at a seed changed with the modules the caller had imported (and their
    text), and a script or test calling ``check_stability`` left ``.hypothesis/`` in its
    current directory. Here it draws among its own constants only; its cache of the
    constants allowed per strategy is emptied before and after, so that neither run
    sees the other's."""
    try:
        from hypothesis.internal.conjecture import providers
    except ImportError:
        providers = None
    local = getattr(providers, "_get_local_constants", None)
    try:            # private names: a hypothesis that renamed one searches as it is
        none = providers.Constants()
        cache = providers.CONSTANTS_CACHE.cache
        cache.clear()
    except Exception:       # noqa: BLE001 - incl. an older hypothesis (providers None)
        local = None
    if local is None:
        yield
        return
    providers._get_local_constants = lambda: none
    try:
        yield
    finally:
        providers._get_local_constants = local
        cache.clear()


@contextlib.contextmanager
def _outside_the_callers_test():
    """The search is mcverify's own, not a test nested in the caller's: called inside
    the caller's ``@given`` test ("stable for every roughness"), hypothesis failed its
    ``nested_given`` health check, raised from the search, until 7 December."""
    from hypothesis import control

    context = getattr(control, "_current_build_context", None)
    if context is None:
        yield
        return
    with context.with_value(None):
        yield


def check_stability(sample, domain, *, sample_dim: int | None = None, pdf=None,
                    inverse=None, rejection: bool = False, dtype=np.float64,
                    max_examples: int = 2000, seed: int = 0,
                    name: str | None = None) -> CheckResult:
    """Property-based stress test of a sampler's numerical stability.

    Every combination of the edge values ``EDGES`` (``EDGES32`` with ``dtype=np.float32``)
    across u's coordinates is tried (9^d: 9, 81, 729 for d = 1, 2, 3; for d > 3 the
    3^d corners of 0, ½ and the largest float below 1; beyond ``MAX_CORNER_DIM``, where
    those would not fit in memory, every coordinate at one edge value, and each alone at
    each edge value with the others at ½), then hypothesis searches
    ``max_examples`` more u in [0, 1)^d, weighted towards both ends, seeded by ``seed``
    (the same seed, the same examples). Each u must give a finite point inside
    ``domain`` (a row of NaN is a rejected draw with ``rejection=True``), a ``pdf``
    there, if given, finite and not negative, and an ``inverse``, if given, finite and
    in [0, 1]; a callable that raises fails too. The first failure found is shrunk to
    the simplest u that shows it and reported in ``failures`` and ``details["u"]``.

    Not a statistical test: ``p_value`` is None, and a pass says only that no such u
    was found among those tried. The corners go to each callable in one call (row by
    row only where one raises, to name the u), the searched u one row at a time.

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
        hit = _first_problem(np.asarray([u], dtype=dtype), sample, pdf, inverse, dom,
                             rejection)
        return None if hit is None else hit[1]

    # a sampler drawing from the global generators: seeded, the caller's kept
    with _PROCESS_STATE, _global_generators(seed):
        edges = EDGES32 if dtype == np.float32 else EDGES
        rows, chosen = _corners(edges, k)
        corners = np.array(rows, dtype=dtype)
        hit = _first_problem(corners, sample, pdf, inverse, dom, rejection)
        tried, found, what = len(corners), None, None
        if hit is not None:
            tried, found, what = hit[0] + 1, tuple(corners[hit[0]].tolist()), hit[1]
        if found is None and m > 0:
            from hypothesis import HealthCheck, Phase, Verbosity, errors, find, settings

            count, first = [0], []          # first: the first (u, problem) the search met

            # hypothesis reseeds the global generators for each example it runs: a
            # sampler drawing from them saw the same numbers at every u (one returning
            # NaN on 2 % of its draws passed); each example continues the check's stream
            stream = [np.random.get_state(), random.getstate()]

            def fails(u):
                count[0] += 1
                np.random.set_state(stream[0])
                random.setstate(stream[1])
                what = problem(u)
                stream[:] = np.random.get_state(), random.getstate()
                if what is not None and not first:
                    first.append((u, what))
                return what is not None

            # quiet whatever the caller's profile: a verbose one (pytest's
            # --hypothesis-verbosity=verbose) printed every u searched until 7 December
            rules = settings(max_examples=m, database=None, deadline=None,
                             suppress_health_check=list(HealthCheck),
                             phases=(Phase.generate, Phase.shrink),
                             verbosity=Verbosity.quiet)
            try:
                with _without_local_constants(), _outside_the_callers_test():
                    found = find(_u_strategy(k, dtype), fails, settings=rules,
                                 random=random.Random(seed))
                np.random.set_state(stream[0])      # the re-check continues the stream
                random.setstate(stream[1])
                what = problem(found)
            except errors.NoSuchExample:
                pass
            except errors.Flaky:            # hypothesis's own traceback until 6 December
                found = None
            if first and what is None:
                # the same u failed once and not again: a sampler drawing its own random
                # numbers (or keeping state) is no function of u, the contract QMC needs
                found, what = first[0][0], (f"{first[0][1]}; not reproduced when called "
                                            "again with the same u: the result is not a "
                                            "function of u")
            tried += count[0]
    failures, details = [], {"examples": tried, "seed": seed, "sample_dim": k,
                             "dtype": np.dtype(dtype).name, "u": None, "problem": None}
    if found is not None:
        u = [float(v) for v in found]
        details.update(u=u, problem=what)
        failures.append(f"u={u}: {what}")
    plan = f"{chosen} of edge values, then a search of up to {m} (seed {seed})"
    tried_text = f"{tried} value{'' if tried == 1 else 's'} of u tried"
    messages = (f"{tried_text} until the first failure, of {plan}" if failures
                else f"{tried_text}: {plan}",)
    return CheckResult(name=name, passed=not failures, p_value=None, statistic=None,
                       alpha=0.0, n_samples=tried, seconds=time.perf_counter() - t0,
                       details=details, messages=messages, failures=tuple(failures))
