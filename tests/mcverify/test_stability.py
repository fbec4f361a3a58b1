"""check_stability: the property-based search for a u at which a sampler, its pdf or its
inverse breaks. Fragile samplers of our own fail at the u that shows it; every warp of
the subject passes; the search is reproducible by seed."""

import os

import numpy as np
import pytest

import mcverify as mv
from estimators.warps import WARPS


def _sphere_from_z(z, u):
    r = np.sqrt(1.0 - z * z)
    phi = 2.0 * np.pi * u[:, 1]
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def test_an_exponential_by_log_u_fails_at_u_zero():
    r = mv.check_stability(lambda u: -np.log(u), mv.Interval(0, 800), sample_dim=1,
                           max_examples=200)
    assert not r.passed and r.details["u"] == [0.0]
    assert "is not finite" in r.failures[0] and r.p_value is None
    # it stops at the first failure, and says so (it read "1 values of u tried: the 9^1
    # corners of edge values, then a search of up to 200", a search that never ran)
    assert r.messages == ("1 value of u tried until the first failure, of the 9^1 corners "
                          "of edge values, then a search of up to 200 (seed 0)",)
    assert mv.check_stability(lambda u: u, mv.Interval(0, 1), sample_dim=1,
                              max_examples=10).messages[0].startswith("19 values of u tried: ")


def test_a_point_off_the_domain_a_density_at_the_horizon_and_an_inverse_past_one():
    # z a hair above 1 at u = 0: sqrt of a negative number
    r = mv.check_stability(lambda u: _sphere_from_z(1.0000000000000002 - 0.1 * u[:, 0], u),
                           "sphere", max_examples=200)
    assert not r.passed and r.details["u"][0] == 0.0
    # the cosine lobe's "pdf" divided by cos θ: infinite where u reaches the horizon
    cos = WARPS["cosine_hemisphere"]
    r = mv.check_stability(cos.sample, "hemisphere", pdf=lambda x: 1.0 / (np.pi * x[:, 2]),
                           max_examples=200)
    assert not r.passed and "pdf" in r.details["problem"]
    # an inverse that overshoots 1 near the top end
    r = mv.check_stability(lambda u: u, mv.Interval(0, 1), sample_dim=1,
                           inverse=lambda x: x * 1.0000001, max_examples=500)
    assert not r.passed and "is not in [0, 1]" in r.details["problem"]
    assert r.details["u"][0] > 0.99


def test_a_sampler_that_raises_and_one_that_rounds_to_one_in_float32():
    def raises(u):
        if np.any(u == 0.0):
            raise ZeroDivisionError("u = 0")
        return u
    r = mv.check_stability(raises, mv.Interval(0, 1), sample_dim=1, max_examples=50)
    assert not r.passed and "sample raised ZeroDivisionError" in r.details["problem"]
    # float64 u near 1 rounded to float32 becomes 1: log(1 - u) = -inf
    r = mv.check_stability(lambda u: -np.log1p(-u.astype(np.float32)), mv.Interval(0, 200),
                           sample_dim=1, max_examples=200)
    assert not r.passed and r.details["u"][0] > 0.999


def test_rejected_draws_pass_only_with_rejection():
    half = lambda u: np.where(u[:, :1] < 0.5, np.nan, u[:, :1])     # noqa: E731
    assert not mv.check_stability(half, "interval", sample_dim=1, max_examples=50).passed
    assert mv.check_stability(half, "interval", sample_dim=1, rejection=True,
                              max_examples=50).passed


@pytest.mark.parametrize("name", sorted(WARPS))
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_every_warp_of_the_subject_is_stable(name, dtype):
    """The corners of the edge values and 100 searched u each, float64 and float32 u."""
    w = WARPS[name]
    p = tuple(float(v) for v in w.defaults)
    dom_name, args = w.domain_spec(*p)
    dom = mv.Interval(*args) if dom_name == "interval" else dom_name
    r = mv.check_stability(lambda u: w.sample(u, *p), dom, sample_dim=w.sample_dim,
                           pdf=lambda x: w.pdf(x, *p),
                           inverse=None if w.invert is None else (lambda x: w.invert(x, *p)),
                           dtype=dtype, max_examples=100, seed=2)
    assert r.passed, r.failures


def test_the_search_is_reproducible_by_seed():
    f = lambda u: np.where(u[:, :1] > 0.9999, np.inf, u[:, :1])   # noqa: E731
    a = mv.check_stability(f, "interval", sample_dim=1, max_examples=300, seed=4)
    b = mv.check_stability(f, "interval", sample_dim=1, max_examples=300, seed=4)
    assert not a.passed and a.details == b.details


@pytest.mark.parametrize("call, needle", [
    (lambda: mv.check_stability(3, "interval"), "sample"),
    (lambda: mv.check_stability(np.sqrt, "interval", dtype=np.float16), "dtype"),
    (lambda: mv.check_stability(np.sqrt, "interval", max_examples=-1), "max_examples"),
    (lambda: mv.check_stability(np.sqrt, "interval", rejection="yes"), "rejection"),
    (lambda: mv.check_stability(np.sqrt, "interval", pdf=5), "pdf"),
    (lambda: mv.check_stability(np.sqrt, "cube"), "cube"),
])
def test_bad_arguments_are_named(call, needle):
    with pytest.raises(mv.InvalidArgument, match=needle):
        call()


def test_what_a_pdf_or_inverse_returns_is_judged_too():
    """A pdf of strings or of the wrong length, an inverse of the wrong width, fail with
    what they returned; a constant pdf (one number) is that density everywhere."""
    same = lambda u: u                                        # noqa: E731
    r = mv.check_stability(same, "interval", sample_dim=1, max_examples=5,
                           pdf=lambda x: np.array(["a"] * len(x)))
    assert not r.passed and "not real numbers" in r.details["problem"]
    r = mv.check_stability(same, "interval", sample_dim=1, max_examples=5,
                           pdf=lambda x: np.ones(3))
    assert not r.passed and "pdf returned 3 values" in r.details["problem"]
    assert mv.check_stability(same, "interval", sample_dim=1, max_examples=5,
                              pdf=lambda x: 1.0).passed
    r = mv.check_stability(same, "interval", sample_dim=1, max_examples=5,
                           inverse=lambda x: np.ones(len(x) + 1))
    assert not r.passed and "inverse returned" in r.details["problem"]


def test_a_sampler_that_breaks_only_on_a_batch_of_u_fails():
    """The corners go to the sampler in one call; where that call breaks but no single u
    does (a sampler that returns one point whatever it is given), the batch's finding
    is the failure: until 6 December it was dropped and such a sampler passed."""
    first_only = lambda u: -np.log1p(-u[:1, :1])              # noqa: E731
    r = mv.check_stability(first_only, mv.Interval(0, 1e4), sample_dim=1, max_examples=20)
    assert not r.passed and "1 points for 9 u" in r.details["problem"]
    assert "one u at a time it does not" in r.details["problem"]
    # a pdf written for one point at a time
    r = mv.check_stability(lambda u: u[:, :1], "interval", sample_dim=1, max_examples=20,
                           pdf=lambda x: 2.0 * x.item())
    assert not r.passed and "pdf raised ValueError" in r.details["problem"]


def test_a_ragged_or_masked_return_is_a_finding_not_a_crash():
    """A ragged list raised numpy's bare ValueError out of the check until 6 December,
    and masked values were read as data: np.ma.sqrt of a negative number keeps the
    negative number under its mask, a point inside Interval(-1, 1), and passed."""
    r = mv.check_stability(lambda u: [[0.5, 0.5], [0.5]], "square", max_examples=5)
    assert not r.passed and "not an array of numbers" in r.details["problem"]
    r = mv.check_stability(lambda u: np.ma.sqrt(0.5 - u[:, :1]), mv.Interval(-1, 1),
                           sample_dim=1, max_examples=20)
    assert not r.passed and "masked" in r.details["problem"]
    r = mv.check_stability(lambda u: u[:, :1], "interval", sample_dim=1, max_examples=20,
                           pdf=lambda x: -np.ma.log(x[:, 0]))   # inf at 0, masked
    assert not r.passed and "pdf returned" in r.details["problem"]


def test_a_sampler_returning_points_and_pdf_is_told_to_return_the_points():
    """A BSDF's sample(u) -> (points, pdf), check_pdf_consistency's sampler, failed as
    numpy's "inhomogeneous shape" (an outside review)."""
    r = mv.check_stability(lambda u: (u, np.ones(len(u))), "square", max_examples=5)
    assert not r.passed
    assert ("sample returned a tuple of 2 arrays, (points, pdf) as check_pdf_consistency's "
            "sampler returns them: this check takes the points alone") in r.details["problem"]


def test_points_returned_transposed_are_a_finding_not_mixed_rows():
    """A (3, n) return (np.stack(..., axis=0), or Dr.Jit's mi.Vector3f as numpy sees it)
    was reshaped to (n, 3), each row mixing coordinates of several points: a correct
    cosine sampler failed at u = [0, 0], "its length is 1.224745, not 1 within 1e-05:
    normalise the direction" (an outside review)."""
    def cosine_rows(u):                                     # (3, n), a Dr.Jit layout
        r, phi = np.sqrt(u[:, 0]), 2.0 * np.pi * u[:, 1]
        return np.stack([r * np.cos(phi), r * np.sin(phi),
                         np.sqrt(np.maximum(0.0, 1.0 - u[:, 0]))])
    r = mv.check_stability(cosine_rows, "hemisphere", max_examples=5)
    assert not r.passed and "normalise" not in r.details["problem"]
    assert "sample returned shape (3, 1) for 1 u: expected (1, 3); transposed? return points.T" \
        in r.details["problem"]
    r = mv.check_stability(lambda u: cosine_rows(u).T, "hemisphere", max_examples=5)
    assert r.passed, r.failures


def test_an_inverse_returned_transposed_is_a_finding_not_mixed_rows():
    """An inverse returning (k, n) (Dr.Jit's mi.Point2f as numpy reads it) was flattened
    and read row by row, pairing each point with other points' u: an inverse wrong at
    x = (1 - 2^-53, 0) only was reported as [1.5, 1.5] there, its own value [1.0, 1.5],
    and a correct one passed, where check_inverse refuses it (an outside review)."""
    def inverse_rows(x):
        back = x.copy()
        back[x[:, 0] > 0.99, 1] = 1.5               # planted: wrong where x0 is near 1
        return back.T

    r = mv.check_stability(lambda u: u.copy(), "square", inverse=inverse_rows, max_examples=5)
    assert not r.passed and "[1.5, 1.5]" not in r.details["problem"]
    assert ("inverse returned shape (2, 1) for 1 point: expected (1, 2); transposed? "
            "return points.T") in r.details["problem"]
    r = mv.check_stability(lambda u: u.copy(), "square", inverse=lambda x: x.T.copy(),
                           max_examples=5)
    assert not r.passed and "transposed?" in r.details["problem"]

def test_a_path_space_sampler_of_many_dimensions_is_checked_in_bounded_memory():
    """3^d corners were built for every d until 6 December: sample_dim=30 (a path-space
    sampler) asked for 2e14 rows and ran out of memory. Above MAX_CORNER_DIM each edge
    value goes on every coordinate and on each alone; a log(u) in the 30th still fails."""
    from mcverify.checks.stability import MAX_CORNER_DIM, _corners, EDGES
    rows, _ = _corners(EDGES, 30)
    assert len(rows) == 9 + 30 * 8 and MAX_CORNER_DIM < 30
    r = mv.check_stability(lambda u: -np.log(u[:, 29:]), mv.Interval(0, 1e4), sample_dim=30,
                           max_examples=20)
    assert not r.passed and r.details["u"][29] == 0.0 and "not finite" in r.details["problem"]
    ok = mv.check_stability(lambda u: -np.log1p(-u[:, 29:]), mv.Interval(0, 1e4),
                            sample_dim=30, max_examples=20)
    assert ok.passed and "249 corners" in ok.messages[0]


def test_points_of_none_or_float16_are_a_finding():
    """Points of None became NaN, with rejection=True a rejected draw at every u, and
    float16 points (refused by every other check) were judged: both passed until
    6 December."""
    r = mv.check_stability(lambda u: [None] * len(u), "interval", sample_dim=1,
                           rejection=True, max_examples=20)
    assert not r.passed and "dtype object" in r.details["problem"]
    r = mv.check_stability(lambda u: u.astype(np.float16), "square", max_examples=20)
    assert not r.passed and "dtype float16" in r.details["problem"]


def test_a_sampler_that_is_not_a_function_of_u_fails_with_its_first_finding():
    """A sampler that fails at random, not at a u (one drawing its own random numbers),
    escaped as hypothesis's FlakyFailure, or failed with the problem None, until
    6 December."""
    for seed in range(3):
        rng = np.random.default_rng(5)

        def flaky(u):
            x = u[:, :1].copy()
            if len(u) == 1 and rng.random() < 0.05:
                x[:] = np.nan
            return x
        r = mv.check_stability(flaky, "interval", sample_dim=1, max_examples=500, seed=seed)
        assert not r.passed and r.details["problem"].startswith("point [nan] is not finite")
        assert "not a function of u" in r.details["problem"]


def test_a_sampler_drawing_from_the_global_generators_is_not_pinned_by_the_search():
    """hypothesis reseeds numpy's and Python's global generators for every example it
    runs, so a sampler drawing its own numbers from them (np.random.rand, random.random:
    a rejection loop) saw the same numbers at every searched u: one returning NaN on 2 %
    of its draws passed, whatever the seed, until 7 December. Now the search continues
    one stream seeded by ``seed`` (the same seed, the same verdict) and the caller's
    global generators are left as they were. Not statistical: each seed's stream is
    fixed, and 2 % of 500 draws all missing (p = 4e-5) is not among these seeds."""
    import random

    def with_numpy(u):
        x = u[:, :1].copy()
        x[np.random.rand(len(x)) < 0.02] = np.nan
        return x

    def with_python(u):
        x = u[:, :1].copy()
        for i in range(len(x)):
            if random.random() < 0.02:
                x[i] = np.nan
        return x

    for sample in (with_numpy, with_python):
        for seed in range(3):
            np.random.seed(11)
            random.seed(11)
            a = mv.check_stability(sample, "interval", sample_dim=1, max_examples=500,
                                   seed=seed)
            assert np.random.rand() == np.random.RandomState(11).rand()
            assert random.random() == random.Random(11).random()
            assert not a.passed and "point [nan] is not finite" in a.details["problem"]
            np.random.seed(12)
            random.seed(12)
            b = mv.check_stability(sample, "interval", sample_dim=1, max_examples=500,
                                   seed=seed)
            assert a.details == b.details


def test_checks_in_threads_keep_their_own_streams():
    """The seeded global streams are process-wide: two checks of a sampler drawing from
    np.random, run at once from two threads (the sampler yielding the interpreter
    between its draws), give each the verdict it gives alone."""
    import threading
    import time as _time

    def drawing(u):
        x = u[:, :1].copy()
        for i in range(len(x)):
            _time.sleep(0)
            if np.random.rand() < 0.02:
                x[i] = np.nan
        return x

    alone = [mv.check_stability(drawing, "interval", sample_dim=1, max_examples=300,
                                seed=s).details for s in (0, 1)]
    out = [None, None]

    def run(s):
        out[s] = mv.check_stability(drawing, "interval", sample_dim=1, max_examples=300,
                                    seed=s).details

    threads = [threading.Thread(target=run, args=(s,)) for s in (0, 1)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert out == alone


def test_the_search_does_not_read_the_callers_modules(tmp_path, monkeypatch):
    """hypothesis draws floats among the constants of every module loaded from outside
    site-packages (the user's project, mcverify from a checkout) and caches them in
    ``./.hypothesis/constants``: the u searched at a seed changed when the caller had
    imported one more module of its own, and calling ``check_stability`` (a script, a
    test under the pytest plugin) left ``.hypothesis/`` in the current directory, until
    7 December."""
    seen = []

    def sample(u):
        seen.append(u.copy())
        return u[:, :1]

    def searched():
        seen.clear()
        r = mv.check_stability(sample, "interval", sample_dim=1, max_examples=200, seed=3)
        assert r.passed
        return np.concatenate(seen).ravel()

    before = searched()
    (tmp_path / "mcv_local_constants.py").write_text(
        "".join(f"C{i} = {float(v)!r}\n" for i, v in enumerate(np.linspace(0.01, 0.99, 60))))
    monkeypatch.syspath_prepend(str(tmp_path))
    import mcv_local_constants  # noqa: F401
    assert np.array_equal(before, searched())

    import subprocess
    import sys

    from estimators._generated import cache_dir
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    env = {k: v for k, v in os.environ.items() if k != "HYPOTHESIS_STORAGE_DIRECTORY"}
    env.setdefault("MCVERIFY_CACHE", cache_dir())
    env["PYTHONPATH"] = root
    project = tmp_path / "project"
    project.mkdir()
    r = subprocess.run([sys.executable, "-c", "import numpy as np, mcverify as mv; "
                        "assert mv.check_stability(np.sqrt, 'interval', max_examples=50)"
                        ".passed"], cwd=project, env=env, capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr
    assert not (project / ".hypothesis").exists()


def test_a_complex_or_boolean_pdf_or_inverse_is_a_finding():
    """A pdf through ``np.emath.sqrt`` (complex where its argument is negative) was read
    by its real part, with numpy's ComplexWarning: sqrt(z - 1) on the hemisphere is
    0 + i·sqrt(1 - z), a real part of 0, and passed; booleans were read as 0 and 1. Every
    other check refuses them ("expected real numbers"); here they pass until 7 December."""
    import warnings

    def hemisphere(u):
        z = 1.0 - u[:, 0]
        return _sphere_from_z(z, u)

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = mv.check_stability(hemisphere, "hemisphere", max_examples=5,
                               pdf=lambda x: np.emath.sqrt(x[:, 2] - 1.0))
        assert not r.passed and "dtype complex128" in r.details["problem"]
        assert r.details["problem"].startswith("pdf returned")
        r = mv.check_stability(hemisphere, "hemisphere", max_examples=5,
                               inverse=lambda x: np.emath.sqrt(x[:, :2]))
        assert not r.passed and r.details["problem"].startswith("inverse returned dtype")
        r = mv.check_stability(lambda u: u, "interval", sample_dim=1, max_examples=5,
                               pdf=lambda x: x[:, 0] >= 0.0)
        assert not r.passed and "dtype bool" in r.details["problem"]


def test_a_sampler_that_changes_its_u_in_place_is_reported_at_the_u_it_was_given():
    """The corners went to the sampler as the very array the check kept: one remapping
    u in place (``u *= 2; u -= 1``, to [-1, 1)) was reported at u = [-1.0], outside the
    unit cube, and its rows were re-tried changed, until 7 December."""
    def remaps(u):
        u *= 2.0
        u -= 1.0
        return np.sqrt(u[:, :1])                  # NaN below u = 0.5
    r = mv.check_stability(remaps, "interval", sample_dim=1, max_examples=50)
    assert not r.passed and r.details["u"] == [0.0]
    assert r.details["problem"] == "point [nan] is not finite"

    def top(u):
        u *= 2.0
        u -= 1.0
        return np.where(u[:, :1] == 1.0 - 2.0 ** -52, np.inf, np.abs(u[:, :1]))
    r = mv.check_stability(top, "interval", sample_dim=1, max_examples=50)
    assert not r.passed and r.details["u"] == [1.0 - 2.0 ** -53]


def test_the_callers_hypothesis_verbosity_does_not_print_the_search(capsys):
    """The search's settings inherited the caller's hypothesis profile: under pytest's
    ``--hypothesis-verbosity=verbose`` (or a verbose profile loaded by a conftest) every
    searched u was printed, about 600 lines of ``Test case: test(v=...)`` for 100 u,
    until 7 December; the check's own result says what it found."""
    from hypothesis import Verbosity, settings

    before = settings.get_current_profile_name()
    settings.register_profile("mcverify-test-verbose", verbosity=Verbosity.verbose)
    settings.load_profile("mcverify-test-verbose")
    try:
        r = mv.check_stability(lambda u: u[:, :1], "interval", sample_dim=1,
                               max_examples=100)
    finally:
        settings.load_profile(before)
    assert r.passed
    out = capsys.readouterr()
    assert out.out == "" and out.err == ""


def test_a_stability_check_inside_a_hypothesis_test_runs():
    """A renderer's own property test, "for every roughness the sampler is stable"
    (``check_stability`` inside ``@given``), raised hypothesis's FailedHealthCheck
    ``nested_given`` from the search, naming none of mcverify, until 7 December. The
    search is mcverify's, not a nested test of the caller's: it runs, and finds."""
    from hypothesis import given, settings, strategies as st

    verdicts = []

    @settings(max_examples=3, database=None)
    @given(st.floats(0.5, 2.0))
    def stable_for_every_sigma(sigma):
        ok = mv.check_stability(lambda u: -np.log1p(-u[:, :1]) / sigma,
                                mv.Interval(0.0, 100.0), sample_dim=1, max_examples=30)
        bad = mv.check_stability(lambda u: np.where(u[:, :1] > 0.25, np.nan, sigma * u[:, :1]),
                                 mv.Interval(0.0, 2.0), sample_dim=1, max_examples=30,
                                 seed=1)
        verdicts.append((ok.passed, bad.passed))

    stable_for_every_sigma()
    assert verdicts and all(v == (True, False) for v in verdicts)


def test_a_hypothesis_without_the_private_names_still_searches(monkeypatch):
    """The search empties hypothesis's private cache of constants: a hypothesis that
    renamed it (CONSTANTS_CACHE, Constants) made every check_stability raise
    AttributeError; it now searches with hypothesis as it is."""
    from hypothesis.internal.conjecture import providers

    monkeypatch.setattr(providers, "CONSTANTS_CACHE", object(), raising=False)
    r = mv.check_stability(lambda u: -np.log(u), "interval", sample_dim=1, max_examples=50)
    assert not r.passed and r.details["u"] == [0.0]


@pytest.mark.parametrize("sample, dom, k, dtype, u", [
    # the corners alone (max_examples=0): float32's largest below 1 is among them
    (lambda u: u / (1.0 - u), mv.Interval(0, 1e7), 1, np.float32, [1.0 - 2.0 ** -24]),
    # float64's largest below 1, rounded to float32 (1.0) inside a sampler of 4 numbers
    (lambda u: -np.log1p(-u[:, 3:].astype(np.float32)), mv.Interval(0, 200), 4,
     np.float64, [0.0, 0.0, 0.0, 1.0 - 2.0 ** -53]),
    # the smallest subnormal in the third of three coordinates (1 / u overflows)
    (lambda u: np.where(u[:, 2:] > 0, 1.0 / np.where(u[:, 2:] > 0, u[:, 2:], 1.0), 0.0),
     mv.Interval(0, 1e300), 3, np.float64, [0.0, 0.0, 5e-324]),
])
def test_the_corners_alone_reach_each_edge_value(sample, dom, k, dtype, u):
    """With no search (max_examples=0) the corners find what only an edge value shows:
    float32's 1 - 2^-24, float64's 1 - 2^-53 among the 3^d corners of d = 4, the
    smallest subnormal in each of three coordinates (a mutation review: each could be
    left out, or float32 given float64's edges, with every test passing)."""
    with np.errstate(all="ignore"):
        r = mv.check_stability(sample, dom, sample_dim=k, dtype=dtype, max_examples=0)
    assert not r.passed and r.details["u"] == u, r.details


def test_float32_corners_are_float32_s_own_values():
    """float32's corners are its own: float64's 1 - 2^-53 cast to float32 is 1.0, outside
    [0, 1), where -log(1 - u) is rightly infinite (a mutation review)."""
    r = mv.check_stability(lambda u: -np.log1p(-u), mv.Interval(0, 200), sample_dim=1,
                           dtype=np.float32, max_examples=0)
    assert r.passed, r.failures


def test_float32_u_is_handed_as_float32():
    """dtype=np.float32 gives the corners and the searched u as float32 arrays (a
    mutation review: float64 corners or searched u passed every test)."""
    seen = set()

    def sample(u):
        seen.add(u.dtype)
        return u

    r = mv.check_stability(sample, "square", sample_dim=2, dtype=np.float32,
                           max_examples=20)
    assert r.passed and seen == {np.dtype(np.float32)}, seen


@pytest.mark.parametrize("pdf, inverse, needle", [
    (lambda x: x[:, 0] - 0.1, None, "pdf -0.1 at x=[0.0] (must be finite and >= 0)"),
    (None, lambda x: x ** 2 - 2.0 ** -60, "inverse [-8.673617379884035e-19] of x=[0.0] "
                                          "is not in [0, 1]"),
    (None, lambda x: np.sqrt(x - 1e-300), "inverse [nan] of x=[0.0] is not in [0, 1]"),
])
def test_a_negative_pdf_a_negative_or_nan_inverse_are_findings(pdf, inverse, needle):
    """Each at u = 0 (a mutation review: none of the three was held by a test)."""
    r = mv.check_stability(np.sqrt, mv.Interval(0, 1), sample_dim=1, pdf=pdf,
                           inverse=inverse, max_examples=0)
    assert not r.passed and r.details["u"] == [0.0], r.details
    assert r.details["problem"] == needle, r.details


def test_an_inverse_of_exactly_one_is_inside():
    """A float32 inverse of x = 1 - 2^-53 returns 1.0: inside [0, 1], the contract's
    closed interval (a mutation review: [0, 1) passed every test)."""
    r = mv.check_stability(lambda u: u, mv.Interval(0, 1), sample_dim=1,
                           inverse=lambda x: x.astype(np.float32), max_examples=0)
    assert r.passed, r.failures


def test_a_row_nan_in_some_coordinates_is_no_rejected_draw():
    """With rejection=True a rejected draw is NaN in every coordinate; x NaN alone is a
    finding (a mutation review: a row with any NaN read as rejected passed)."""
    def sample(u):
        x = u.copy()
        x[u[:, 0] < 0.5, 0] = np.nan
        return x

    r = mv.check_stability(sample, "square", sample_dim=2, rejection=True, max_examples=0)
    assert not r.passed and "is not finite" in r.details["problem"], r.details


@pytest.mark.parametrize("generator", ["numpy", "python"])
def test_the_global_generators_are_seeded_by_seed(generator):
    """Different seeds give a sampler drawing from np.random or random different streams:
    the first corner failing differs (a mutation review: a fixed seed passed every test,
    the same seed giving the same finding). Not statistical: each seed's stream is fixed;
    NaN on 5 % of 81 corner draws."""
    import random

    def sample(u):
        x = u.copy()
        for i in range(len(x)):
            if (np.random.rand() if generator == "numpy" else random.random()) < 0.05:
                x[i] = np.nan
        return x

    found = [tuple(mv.check_stability(sample, "square", sample_dim=2, max_examples=0,
                                      seed=s).details["u"]) for s in range(4)]
    assert len(set(found)) > 1, found


def test_the_search_is_seeded_by_seed():
    """The searched u follow the seed: the same seed the same u, another seed others (a
    mutation review: hypothesis's random seeded by a constant passed every test)."""
    def searched(seed):
        seen = []

        def sample(u):
            if len(u) == 1:
                seen.append(float(u[0, 0]))
            return u
        mv.check_stability(sample, "interval", sample_dim=1, max_examples=30, seed=seed)
        return seen

    a, b, c = searched(0), searched(0), searched(1)
    assert a == b != c


def test_a_failure_found_by_the_search_is_shrunk_to_a_simple_u():
    """NaN for u in (0.6, 0.9), a band no corner reaches: the search finds it and shrinks
    it to [0.0, 0.75] whatever the seed (a mutation review: the search's u reported
    unshrunk passed every test)."""
    def band(u):
        return np.where((u > 0.6) & (u < 0.9), np.nan, u)

    for seed in range(2):
        r = mv.check_stability(band, "square", sample_dim=2, max_examples=300, seed=seed)
        assert not r.passed and r.details["u"] == [0.0, 0.75], r.details


@pytest.mark.parametrize("lo, hi", [(1e-7, 1e-6), (1.0 - 1e-6, 1.0 - 1e-7)])
def test_the_search_reaches_a_band_a_millionth_from_either_end(lo, hi):
    """NaN for u in a band within 1e-6 of 0 or of 1 that no corner reaches: the search,
    weighted towards both ends, finds it at each seed within 200 examples (a mutation
    review: the weighting's width could be 0.1, not 1e-6, with every test passing). Not
    statistical: each seed's search is fixed."""
    def band(u):
        return np.where((u > lo) & (u < hi), np.nan, u)

    for seed in range(3):
        r = mv.check_stability(band, "interval", sample_dim=1, max_examples=200, seed=seed)
        assert not r.passed and lo < r.details["u"][0] < hi, r.details
