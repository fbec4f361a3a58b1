"""The judge's teeth: correct subjects pass, planted bugs fail (seeded, α = 0.01)."""

import json
import warnings

import numba
import numpy as np
import pytest
from scipy import stats as scipy_stats

import mcverify as mv
from estimators import warps as W
from mcverify.checks.sampler import STREAM_BLOCK as STREAM_BLOCK_FOR_TESTS
from mcverify.result import json_text


def cosine(u):
    return W.sample_cosine_hemisphere(u)


def mixture(eps, base=W.sample_cosine_hemisphere, other=W.sample_uniform_hemisphere):
    def sample(u):
        x = base(u)
        flip = np.random.default_rng(99).random(u.shape[0]) < eps
        x[flip] = other(u[flip])
        return x
    return sample


def test_correct_sampler_passes_and_is_deterministic():
    a = mv.check_sampler(cosine, W.cosine_hemisphere_pdf, "hemisphere", seed=4)
    b = mv.check_sampler(cosine, W.cosine_hemisphere_pdf, "hemisphere", seed=4)
    assert a.passed and a.p_value == b.p_value and a.statistic == b.statistic
    assert abs(a.details["pdf_integral"] - 1) < 1e-6


# Each planted bug, and the sub-test that must catch it: a deterministic failure (its
# message), or a statistical sub-test whose p-value falls below its Bonferroni share of
# α = 0.01 (the check's p-value is the Bonferroni minimum over its sub-tests).
@pytest.mark.parametrize("label,sample,pdf,domain,caught_by", [
    ("pdf*1.03", cosine, lambda x: 1.03 * W.cosine_hemisphere_pdf(x), "hemisphere",
     "failure:pdf integrates to 1.03"),
    # 1 % uniform directions shift the polar angle: the θ marginal sees it first
    ("mixture 1%", mixture(0.01), W.cosine_hemisphere_pdf, "hemisphere", "test:chi2_axis0"),
    ("ggx 0.30 vs 0.32", lambda u: W.sample_ggx(u, 0.30), lambda x: W.ggx_pdf(x, 0.32),
     "hemisphere", "test:chi2"),
    ("cone wrong angle", lambda u: W.sample_uniform_cone(u, 0.80),
     lambda x: W.uniform_cone_pdf(x, 0.81), "sphere",
     "failure:fell in cells where the pdf integrates to 0"),
    ("tent shifted", lambda u: W.sample_tent(u, 1.0) + 0.01,
     lambda x: W.tent_pdf(x, 1.0), mv.Interval(-1.5, 1.5), "test:ks"),
    ("uniform vs cosine", W.sample_uniform_hemisphere, W.cosine_hemisphere_pdf, "hemisphere",
     "test:chi2"),
])
def test_planted_bugs_are_rejected(label, sample, pdf, domain, caught_by):
    r = mv.check_sampler(sample, pdf, domain, seed=1)
    assert not r.passed, (label, r.p_value, r.failures)
    kind, what = caught_by.split(":", 1)
    if kind == "failure":
        assert any(what in f for f in r.failures), (label, r.failures)
    else:
        tests = r.details["tests"]
        assert tests[what]["p_value"] < r.alpha / len(tests), (label, tests)


def test_nan_outside_and_negative_pdf_are_failures_with_examples():
    def bad(u):
        x = W.sample_cosine_hemisphere(u)
        x[:3] = np.nan
        x[3:5, 2] = -0.5
        return x
    r = mv.check_sampler(bad, W.cosine_hemisphere_pdf, "hemisphere", n_samples=20_000)
    assert not r.passed
    text = " ".join(r.failures)
    assert "3 samples are NaN/Inf" in text and "2 samples lie outside" in text
    r = mv.check_sampler(cosine, lambda x: x[:, 2] / np.pi - 0.01, "hemisphere",
                         n_samples=20_000)
    assert any("negative" in f for f in r.failures)


@pytest.mark.parametrize("scale,flip,domain,needle", [
    (1 + 1e-3, 1, "hemisphere", "its length is 1.001, not 1 within 1e-05: normalise the direction"),
    (1 - 1e-3, 1, "sphere", "its length is 0.999, not 1 within 1e-05"),
    (1.0, -1, "hemisphere", "is below the horizon: the hemisphere is z >= 0 about the normal, "
     "in the local frame (a lobe that transmits is judged on the sphere)"),
])
def test_a_point_outside_says_what_puts_it_there(scale, flip, domain, needle):
    """A direction 1e-3 off unit length, z = 0.66, failed as "outside the hemisphere"
    and no more, which sent the user after the frame (an outside review)."""
    r = mv.check_sampler(lambda u: W.sample_cosine_hemisphere(u) * [scale, scale, flip * scale],
                         W.cosine_hemisphere_pdf, domain, n_samples=10_000)
    assert not r.passed and any(f"lie outside the {domain} domain" in f and needle in f
                                for f in r.failures), r.failures
    r = mv.check_stability(lambda u: W.sample_cosine_hemisphere(u) * [scale, scale, flip * scale],
                           domain, max_examples=5)
    assert not r.passed and needle in r.details["problem"], r.details["problem"]
    r = mv.check_sampler(lambda u: 1.01 * W.sample_uniform_disk_polar(u),
                         W.uniform_disk_pdf, "disk", n_samples=10_000)
    assert any("; its radius is 1.009639, beyond 1" in f for f in r.failures), r.failures

def _tilted_cosine(u):
    """A cosine lobe about (0.6, 0, 0.8), as a light's or a BSDF lobe's directions."""
    x = W.sample_cosine_hemisphere(u)
    c, s = 0.8, 0.6
    return np.stack([c * x[:, 0] + s * x[:, 2], x[:, 1], -s * x[:, 0] + c * x[:, 2]], axis=1)


def _tilted_cosine_pdf(x):
    return np.maximum(0.6 * x[:, 0] + 0.8 * x[:, 2], 0.0) / np.pi


def test_directions_reversed_on_the_sphere_are_named_as_a_guess():
    """A sampler returning every direction reversed (a BSDF reflecting -wi, a light
    sampler's light-to-point direction) failed as "the sampler puts mass where the pdf
    has none" and no more (an outside review); a sampler wrong in half its draws (y and
    z swapped) gets no such guess."""
    r = mv.check_sampler(lambda u: -_tilted_cosine(u), _tilted_cosine_pdf, "sphere",
                         n_samples=100_000)
    text = " ".join(r.failures)
    assert not r.passed
    assert ("the sampler puts mass where the pdf has none; the pdf is positive at -x for "
            "10000 of them: directions reversed (towards the surface or the light, not "
            "away)?") in text, text
    r = mv.check_sampler(lambda u: _tilted_cosine(u)[:, [0, 2, 1]], _tilted_cosine_pdf,
                         "sphere", n_samples=100_000)
    text = " ".join(r.failures)
    assert not r.passed and "the sampler puts mass where the pdf has none" in text, text
    assert "the pdf is positive at" not in text, text

def _y_up_cosine(u):
    """A cosine lobe about +y, a y-up renderer's local frame."""
    return W.sample_cosine_hemisphere(u)[:, [0, 2, 1]]


@pytest.mark.parametrize("sample,pdf,domain,guess", [
    (_y_up_cosine, lambda x: np.maximum(x[:, 1], 0.0) / np.pi, "hemisphere",
     "; all 20000 points of a call have y >= 0: a hemisphere about +y (a y-up renderer's)? "
     "the checks' hemisphere is about +z: rotate into the local frame, (x, y, z) -> "
     "(x, -z, y)"),
    (lambda u: -W.sample_cosine_hemisphere(u), W.cosine_hemisphere_pdf, "hemisphere",
     "; all 20000 points of a call have z <= 0: directions reversed or mirrored in the "
     "surface (about -z, not +z)?"),
    (lambda u: np.stack([np.sqrt(u[:, 0]), 2 * np.pi * u[:, 1] - np.pi], axis=1),
     W.uniform_disk_pdf, "disk",
     "; all 20000 points of a call have x in [0, 1] and y in [-π, 2π]: (r, φ) polar "
     "coordinates? return (r cos φ, r sin φ)"),
    (lambda u: np.stack([np.sqrt(u[:, 0]), 360 * u[:, 1]], axis=1), W.uniform_disk_pdf,
     "disk", "; all 20000 points of a call have x in [0, 1] and y in [-180, 360]: (r, φ) "
     "polar coordinates in degrees? return (r cos φ, r sin φ) of np.radians(φ)"),
], ids=["y-up", "reversed", "r-phi", "r-phi-degrees"])
def test_points_outside_in_another_convention_get_a_guess(sample, pdf, domain, guess):
    """An outside review: a y-up cosine sampler was told 'its z = -0.58 is below the
    horizon', polar disk points (r, φ) 'its radius is 5.7, beyond 1', and no more; where
    every point of a call fits another convention, the failure now names it."""
    r = mv.check_sampler(sample, pdf, domain, n_samples=20_000, seed=1)
    note = next(f for f in r.failures if "outside the" in f)
    assert not r.passed and note.endswith(guess), note


@pytest.mark.parametrize("sample,pdf,domain", [
    (W.sample_uniform_sphere, W.uniform_sphere_pdf, "hemisphere"),
    (lambda u: 1.01 * W.sample_uniform_disk_polar(u), W.uniform_disk_pdf, "disk"),
    (lambda u: 1.001 * W.sample_cosine_hemisphere(u), W.cosine_hemisphere_pdf, "hemisphere"),
    (lambda u: np.where(u[:, :1] > 0.99, [[1.0, 1.0, -1.0]], 1.0)
     * W.sample_cosine_hemisphere(u), W.cosine_hemisphere_pdf, "hemisphere"),
], ids=["sphere", "disk-too-wide", "too-long", "one-percent-below"])
def test_points_outside_in_no_other_convention_get_no_guess(sample, pdf, domain):
    r = mv.check_sampler(sample, pdf, domain, n_samples=20_000, seed=1)
    note = next(f for f in r.failures if "outside the" in f)
    assert not r.passed and "of a call have" not in note, note


def _polar_cosine(u):
    r, phi = np.sqrt(u[:, 0]), 2 * np.pi * u[:, 1]
    return np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1 - u[:, 0])], axis=1)


def test_same_distribution_names_a_marginals_parameter_as_check_sampler_does():
    """A marginal's cell was "at parameter 0 in [...]", which told no one that it is
    1 - z on the hemisphere (an outside review)."""
    def wider(u):
        return _polar_cosine(np.stack([u[:, 0] ** 1.05, u[:, 1]], axis=1))
    r = mv.check_same_distribution(_polar_cosine, wider, "hemisphere", n_samples=200_000)
    assert not r.passed
    assert r.messages[-1].startswith("largest discrepancy at 1 - z in ["), r.messages
    assert "(the first axis' marginal)" in r.messages[-1], r.messages

def test_samples_where_pdf_integrates_to_zero():
    # Sampler covers the whole disk, pdf claims only the right half.
    r = mv.check_sampler(W.sample_uniform_disk_polar,
                         lambda x: np.where(x[:, 0] > 0, 2 / np.pi, 0.0), "disk",
                         n_samples=50_000)
    assert not r.passed
    assert any("integrates to 0" in f for f in r.failures)


def test_a_float32_sampler_with_a_pdf_compiled_for_float64_points_passes():
    """The zero-density screen read the pdf at the pilot's points as drawn, float32 here,
    and a pdf compiled for float64 rows only raised numba's TypeError where the check had
    passed (a read-only review); it reads them in float64."""
    @numba.njit("float64[:](float64[:, ::1])")
    def pdf(x):
        return 2.0 * x[:, 0]

    r = mv.check_sampler(lambda u: np.sqrt(u).astype(np.float32), pdf, "interval",
                         n_samples=100_000, seed=1)
    assert r.passed, r.summary()


def test_a_pdf_singular_at_the_intervals_edge_is_not_read_there():
    """The arcsine law, x = (1 - cos πu) / 2, pdf 1/(π√(x(1 - x))): the Kolmogorov–Smirnov
    CDF read the pdf at x = 0, where it is infinite and which no point reaches, so numpy
    warned of a division by zero in the user's pdf, and under -W error the check raised
    it (an outside review). α = 0.01, seed 0."""
    def pdf(x):
        return 1.0 / (np.pi * np.sqrt(x[:, 0] * (1.0 - x[:, 0])))

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = mv.check_sampler(lambda u: (1.0 - np.cos(np.pi * u)) / 2.0, pdf, "interval",
                             n_samples=20_000, seed=0)
    assert r.passed, r.summary()


def test_samples_where_the_pdf_is_zero_fail_where_their_cell_has_mass():
    """A hemisphere sampler that folds 1 % of its directions just below the horizon
    (z in (-0.01, 0]) checked on the sphere against its pdf, 0 below: the cell that
    straddles the equator holds those points in place of the ones missing above it, and
    until 7 December the check passed at p = 1. The pilot's points where the pdf is 0
    about the point now fail; the correct sampler, whose points on z = 0 have density
    beside them, passes, as does one on the square whose every point sits on its
    support's edge (pdf 1 for x > 0, points with x = 0 exactly)."""
    def sphere(z, phi):
        r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
        return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)

    def upper(x):
        return np.where(x[:, 2] >= 0, 1 / (2 * np.pi), 0.0)

    def folded(u):
        return sphere(np.where(u[:, 0] < 0.01, -u[:, 0], u[:, 0]), 2 * np.pi * u[:, 1])

    for seed in (0, 1):
        r = mv.check_sampler(folded, upper, "sphere", n_samples=200_000, seed=seed)
        assert not r.passed
        (f,) = r.failures
        assert "lie where the pdf is 0" in f and "first x = [" in f, f
        r = mv.check_sampler(lambda u: sphere(u[:, 0], 2 * np.pi * u[:, 1]), upper,
                             "sphere", n_samples=200_000, seed=seed)
        assert r.passed, r.summary()
    edge = mv.check_sampler(lambda u: np.stack([0 * u[:, 0], u[:, 1]], 1),
                            lambda x: np.where(x[:, 0] > 0, 1.0, 0.0), "square",
                            n_samples=20_000)
    assert not any("lie where the pdf is 0" in f for f in edge.failures), edge.failures


def test_inverse_round_trip_and_wrong_inverse():
    ok = mv.check_inverse(lambda u: W.sample_uniform_cone(u, 0.5),
                          lambda x: W.invert_uniform_cone(x, 0.5), 2, atol=1e-12)
    assert ok.passed and ok.details["max_abs_error"] < 1e-12
    bad = mv.check_inverse(lambda u: W.sample_uniform_cone(u, 0.5),
                           lambda x: W.invert_uniform_cone(x, 0.6), 2)
    assert not bad.passed and "u=" in bad.failures[0] and "-> u'=" in bad.failures[0]
    # the worst round trip is said once: in the failure, not again as a message (an
    # outside review); a passing check gives it as its message
    assert not any("-> u'=" in m for m in bad.messages), bad.messages
    assert ok.messages[0].startswith("worst round trip: u=")


def test_a_sampler_remapping_u_in_place_is_held_to_the_u_it_was_given():
    """A sampler warping u in place (u *= 2; u -= 1, to [-1, 1)) and its correct inverse
    failed every round trip, held to the u as changed (a mutation review)."""
    def sample(u):
        u *= 2.0
        u -= 1.0
        return u[:, 0]

    r = mv.check_inverse(sample, lambda x: (np.asarray(x).reshape(-1, 1) + 1.0) / 2.0, 1,
                         n_samples=1000)
    assert r.passed, r.failures

def _disk32(u):
    """The polar disk warp computed in float32 throughout, as a renderer would."""
    u = np.asarray(u).astype(np.float32)
    r, phi = np.sqrt(u[:, 0]), np.float32(2 * np.pi) * u[:, 1]
    return np.stack([r * np.cos(phi), r * np.sin(phi)], 1)


def _disk32_inverse(x, scale=1.0):
    x = np.asarray(x, np.float32)
    phi = np.arctan2(x[:, 1], x[:, 0])
    phi = np.where(phi < 0, phi + np.float32(2 * np.pi), phi)
    r2 = (x[:, 0] * x[:, 0] + x[:, 1] * x[:, 1]) * np.float32(scale)
    return np.stack([r2, phi / np.float32(2 * np.pi)], 1)


def test_a_float32_round_trip_is_held_to_float32_accuracy():
    """A float32 warp and its float32 inverse lose a few float32 ulps (here 2.1e-7 at
    u = 0.9987); until 7 December the default atol of 1e-7 failed them on 3729 of 1e5
    round trips. Float32 gets 1e-6 by default; an inverse 4e-6 off still fails, and
    float64 code keeps 1e-7."""
    ok = mv.check_inverse(_disk32, _disk32_inverse, 2)
    assert ok.passed, ok.failures
    assert ok.details["atol"] == 1e-6 and ok.details["max_abs_error"] > 1e-7
    bad = mv.check_inverse(_disk32, lambda x: _disk32_inverse(x, 1 + 4e-6), 2)
    assert not bad.passed and "atol=1e-06" in bad.failures[0]
    r = mv.check_inverse(lambda u: u, lambda x: x + 2e-7, 1, n_samples=1000)
    assert not r.passed and r.details["atol"] == 1e-7
    # an explicit atol is the caller's, float32 or not
    assert not mv.check_inverse(_disk32, _disk32_inverse, 2, atol=1e-7).passed


def test_inverse_reports_the_largest_error_in_ulps_where_it_is():
    """``max_ulps`` is the largest error in ulps of u over every round trip. Until
    6 December it was the ulps of the chain worst in absolute error: an inverse off by
    a constant 2^-40 showed 8192 ulps (that chain's u was near 1) where its error at
    the smallest u, 1.9e-4, was 3.4e7 ulps, so a float64 CDF inversion losing all its digits near
    u = 0 looked good in ulps."""
    u = np.random.default_rng(0).random((1000, 1))        # the check's own u (seed 0)
    r = mv.check_inverse(lambda u: u, lambda x: x + 2.0 ** -40, 1, n_samples=1000)
    err = np.abs((u + 2.0 ** -40) - u)
    i = int(np.argmin(u[:, 0]))
    assert r.details["max_ulps"] == float(err[i, 0] / np.spacing(u[i, 0]))
    assert r.details["max_ulps"] > 1e6
    assert r.details["worst_ulps"]["u"] == u[i].tolist()
    # the chain worst in absolute error keeps its place in failures and "worst"
    assert r.details["max_abs_error"] == float(err.max())


def test_same_distribution_two_sample():
    same = mv.check_same_distribution(W.sample_uniform_disk_polar,
                                      W.sample_uniform_disk_concentric, "disk",
                                      n_samples=200_000, seed=3)
    assert same.passed
    diff = mv.check_same_distribution(W.sample_cosine_hemisphere, mixture(0.03), "hemisphere",
                                      n_samples=500_000, seed=3)
    assert not diff.passed
    # a failure says where: the cell of the rejecting χ² test (grid or marginal) with
    # both samples' counts (it used to say nothing at all)
    assert any(m.startswith("largest discrepancy at ") and "sample_a" in m and "sample_b"
               in m for m in diff.messages), diff.messages
    assert not any("largest" in m for m in same.messages)


def test_same_distribution_resolves_a_narrow_lobe():
    """Cells placed from independent pilot draws, as check_sampler places them: on a
    uniform grid a GGX lobe at α = 0.005 fell into the first row, and a sampler 10 %
    too wide passed at 3e5 samples (an outside review). Seeded, α = 0.01."""
    wide = lambda u: W.sample_ggx(u, 0.0055)        # noqa: E731
    narrow = lambda u: W.sample_ggx(u, 0.005)       # noqa: E731
    r = mv.check_same_distribution(narrow, wide, "hemisphere", n_samples=300_000, seed=1)
    assert not r.passed and r.p_value < 1e-6, r.summary()
    same = mv.check_same_distribution(narrow, lambda u: W.sample_ggx(u[:, ::-1], 0.005),
                                      "hemisphere", n_samples=300_000, seed=1)
    assert same.passed, same.summary()
    # one side an array of points: the sampler side's pilot places the cells
    pts = narrow(np.random.default_rng(7).random((300_000, 2)))
    assert not mv.check_same_distribution(pts, wide, "hemisphere", n_samples=300_000,
                                          seed=1).passed
    assert mv.check_same_distribution(pts, narrow, "hemisphere", n_samples=300_000,
                                      seed=1).passed


def test_same_distribution_says_when_its_histogram_has_no_power():
    """Three points a side pool into one bin: the test cannot fail, and says so (as
    check_sampler does), for arrays and for samplers."""
    rng = np.random.default_rng(0)
    r = mv.check_same_distribution(rng.random((3, 2)), 0.1 * rng.random((3, 2)), "square")
    assert r.passed and any(m.startswith("len(sample_a)=3: the χ² test pooled its "
                                         "histogram into 1 bin(s)") for m in r.messages)
    r = mv.check_same_distribution(lambda u: u, lambda u: u ** 2, "square", n_samples=20)
    assert any(m.startswith("n_samples=20: the χ² test pooled") for m in r.messages)


def test_same_distribution_counts_the_points_it_compared():
    """Two arrays of 5000 and 7000 points were reported with n_samples = 1e6, the
    default no sampler drew (the JSON and the report's table said so); the result now
    counts the smaller side, and details name both."""
    rng = np.random.default_rng(0)
    r = mv.check_same_distribution(rng.random((5000, 1)), rng.random((7000, 1)), "interval")
    assert r.n_samples == 5000
    assert r.details["n_per_side"] == {"sample_a": 5000, "sample_b": 7000}
    r = mv.check_same_distribution(lambda u: u, rng.random((7000, 1)), "interval",
                                   n_samples=3000)
    assert r.n_samples == 3000
    assert r.details["n_per_side"] == {"sample_a": 3000, "sample_b": 7000}
    r = mv.check_same_distribution(lambda u: u, lambda u: u, "interval", n_samples=2000)
    assert r.n_samples == 2000


def test_same_distribution_refuses_arrays_drawn_from_the_same_random_numbers():
    """The old and the new version's points saved with one seed are the same point in
    most rows: the new one's u0 1 % smaller for a quarter of u1 passed with the seed
    shared (p = 1) where independent draws fail it (p = 3e-7); a float32 port drawn so
    passed at p = 1 too. Both are refused now, naming the paired rows; arrays
    of independent draws with atoms (a clamp, three values) are not (α of the refusal:
    1e-9)."""
    def new(u):
        v = u.copy()
        v[u[:, 1] < 0.25, 0] *= 0.99
        return W.sample_cosine_hemisphere(v)

    u = np.random.default_rng(0).random((200_000, 2))
    old = W.sample_cosine_hemisphere(u)
    assert not mv.check_same_distribution(
        old, new(np.random.default_rng(100).random((200_000, 2))), "hemisphere").passed
    for other in (new(u), W.sample_cosine_hemisphere(u.astype(np.float32)).astype(np.float32)):
        with pytest.raises(mv.InvalidArgument, match=r"sample_a and sample_b: \d+ of their "
                           r"first 65535 rows are the same point .* against 0 .* another seed"):
            mv.check_same_distribution(old, other, "hemisphere")
    for seed in range(20):
        rng = np.random.default_rng(seed)
        for draw in (lambda: rng.choice([0.0, 0.5, 1.0], size=(3000, 1), p=[.5, .3, .2]),
                     lambda: np.minimum(1.3 * rng.random((3000, 1)), 1.0)):
            mv.check_same_distribution(draw(), draw(), "interval")


def test_same_distribution_takes_independent_stratified_arrays_in_their_order():
    """Jittered 1-D strata of two independent seeds, in their order: rows i of both lie
    in one stratum, within 2^-20 of each other in 35 % of rows at 200,000 strata (96 %
    warped), and the shared-seed refusal took them for paired draws (a read-only review).
    A pair of rows is now paired only where it is also 1000 times closer than row i of
    the one to row i + 1 of the other, which strata are not: they pass, uniform and
    warped, and at 10^7 strata they are compared too."""
    n = 200_000

    def strata(seed, count=n):
        return (np.arange(count) + np.random.default_rng(seed).random(count)) / count

    assert mv.check_same_distribution(strata(1), strata(2), "interval").passed
    warp = lambda u: -np.log1p(-0.99 * u)       # noqa: E731
    assert mv.check_same_distribution(warp(strata(1)), warp(strata(2)),
                                      mv.Interval(0.0, 5.0)).passed
    fine = [strata(s, 10 ** 7)[:70_000] * 140 for s in (1, 2)]
    assert mv.check_same_distribution(*fine, "interval").passed


def test_same_distribution_of_two_samplers_that_reject_everything_says_so():
    """Two samplers that rejected every draw passed check_same_distribution with no
    message, and numpy's "invalid value" warning leaked from the χ² test's 0/0 (an
    outside review). The verdict stands (they agree), but it now says on what."""
    nothing = lambda u: np.full((len(u), 1), np.nan)     # noqa: E731
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = mv.check_same_distribution(nothing, nothing, "interval", n_samples=1000,
                                       rejection=True)
    assert r.passed and any(m.startswith("neither side accepted a draw") for m in r.messages)


def test_unbiased_on_the_seed_integrals():
    rng = np.random.default_rng(5)
    x = rng.random(200_000) * np.pi
    assert mv.check_unbiased(np.pi * np.sin(x), 2.0).passed        # ∫₀^π sin = 2
    assert mv.check_unbiased(np.pi * np.cos(x), 0.0).passed         # E[cos x] = 0
    assert not mv.check_unbiased(np.pi * np.sin(x) * 1.01, 2.0).passed


@pytest.mark.parametrize("draw", [
    lambda r: 1000.0 * (r.random(10_000) < 0.001),                 # a rare light hit
    lambda r: (r.random(10_000) < 0.005) * r.exponential(200.0, 10_000),
], ids=["hit 1e-3", "exponential 5e-3"])
def test_unbiased_holds_its_level_on_skewed_estimates(draw):
    """Mostly zeros with a rare large value (mean 1): the plain t-test's two-sided p-value
    failed these correct estimators on the low side at 3.4 % and 3.0 % at α = 0.01 (2000
    seeds, an outside review); Hall's skewness correction gives 1.15 % and 0.85 %. Over
    1000 seeds the false alarms must stay within the binomial 99.9 % upper bound of α
    (21; the plain t-test had 33 and 31 here), and a 50 % bias is still found."""
    fails = sum(not mv.check_unbiased(draw(np.random.default_rng(s)), 1.0).passed
                for s in range(1000))
    assert fails <= scipy_stats.binom.ppf(0.999, 1000, 0.01), fails
    found = sum(not mv.check_unbiased(1.5 * draw(np.random.default_rng(s)), 1.0).passed
                for s in range(1000, 1100))
    assert found >= 5, found


def test_unbiased_finds_a_rare_hit_estimator_far_too_low():
    """Hall's cubic flattens on the side opposite the skew: a hit estimator at a quarter
    of its mean (hits of 1000 among 10,000 samples, 4 where 16 are expected) was found
    on 27 % of seeds, the plain t-test's 98 % (a review of the change); 3 hits could
    never fail (p = 0.074). Beyond 1 + γS/3 = 1/2 the statistic now grows as a line:
    found on at least half of 100 seeds at α = 0.01 (75 % measured), and fewer hits
    always give a smaller p."""
    low = [1000.0 * (np.random.default_rng(s).random(10_000) < 0.0004) for s in range(100)]
    assert sum(not mv.check_unbiased(x, 1.6).passed for x in low) >= 50
    p = []
    for k in range(1, 16):
        x = np.zeros(10_000)
        x[:k] = 1000.0
        p.append(mv.check_unbiased(x, 1.6).p_value)
    assert all(a < b for a, b in zip(p, p[1:])), p


def test_unbiased_says_why_all_zero_estimates_of_a_rare_hit_fail():
    """A correct estimator of a small light (hit with probability 1e-4, 10,000 samples)
    returned only zeros on this seed, as it does on e^-1 of them: the failure said only
    "every sample is 0", as if the estimator were a wrong constant (an outside review).
    It now names the likely cause and the remedy; a hit makes the t-test decide."""
    hits = lambda s: 1e4 * (np.random.default_rng(s).random(10_000) < 1e-4)   # noqa: E731
    r = mv.check_unbiased(hits(0), 1.0)
    assert not hits(0).any() and not r.passed
    assert "rare" in r.failures[0] and "draw more samples" in r.failures[0], r.failures
    assert all(hits(s).any() and mv.check_unbiased(hits(s), 1.0).passed for s in (1, 2, 3))


def test_unbiased_detects_infinite_variance():
    # ∫₀¹ x^-0.75 dx = 4 sampled uniformly: f/p = x^-0.75 has tail index 4/3 < 2.
    u = np.random.default_rng(6).random(500_000)
    r = mv.check_unbiased(u ** -0.75, 4.0)
    assert not r.passed and any("infinite" in f for f in r.failures)


def test_unbiased_does_not_call_bounded_russian_roulette_infinite_variance():
    """Russian roulette with q = 0.01 of f = x on [0, 1]: values 0 or up to 100, bounded,
    about 100 survivors in 10,000 samples. Hill's estimator took its sqrt(n) = 100
    largest deviations, all the survivors down to 0, and read a tail index near 0.5:
    "variance appears infinite" on 20 of 40 seeds (an outside review). Its k is now at
    most a tenth of the samples off the median: at α = 0.01 none of 40 seeds is called
    heavy and the t-test's false alarms stay within the binomial 99.9 % bound (4), while
    roulette of an infinite-variance x^-0.75 with enough survivors (q = 0.1, n = 1e5)
    is still reported on every one of 5 seeds."""
    def roulette(s, q, n, f):
        r = np.random.default_rng(s)
        return np.where(r.random(n) < q, f(r.random(n)) / q, 0.0)
    results = [mv.check_unbiased(roulette(s, 0.01, 10_000, lambda x: x), 0.5)
               for s in range(40)]
    assert not any("infinite" in f for r in results for f in r.failures)
    assert sum(not r.passed for r in results) <= scipy_stats.binom.ppf(0.999, 40, 0.01)
    for s in range(5):
        r = mv.check_unbiased(roulette(s, 0.1, 100_000, lambda x: x ** -0.75), 4.0)
        assert not r.passed and r.failures[0].startswith("variance appears infinite")


def test_unbiased_says_the_variance_may_be_infinite_below_index_2():
    """A correct estimator of infinite variance, x^-0.75 sampled uniformly (∫ = 4, tail
    index 4/3), whose Hill estimate on this seed is 1.58 with a 99.9 % bound of 2.07,
    just above 2: the tail test cannot call it, and the t-test failed it by 7.6
    standard errors (as on 5 of 40 seeds at α = 0.01) with the note "the mean
    converges slowly", as if the t-test held (an outside review). Below index 2 the
    note now says the variance may be infinite and the p-value not valid either way;
    a light tail (uniform) gets no such note."""
    r = mv.check_unbiased(np.random.default_rng(1004).random(10_000) ** -0.75, 4.0)
    assert not r.passed and not r.failures and r.details["tail_index_upper"] > 2.0
    assert any("the variance may be infinite" in m for m in r.messages), r.messages
    r = mv.check_unbiased(np.random.default_rng(1004).random(10_000), 0.5)
    assert not any("infinite" in m for m in r.messages), r.messages


@pytest.mark.parametrize("finite", [0, 1])
def test_unbiased_of_fewer_than_two_finite_samples_reports_no_p_value(finite):
    """Estimates that are all NaN but for `finite` of them: no t-test can run, yet the
    result had p_value 1.0 ("FAIL unbiased p=1") and the note "0 samples: too few to
    test for a heavy tail; the t-test assumes finite variance", as if a t-test had been
    done (an outside review). It now has no p-value and says why, as check_variance
    does."""
    r = mv.check_unbiased(np.r_[np.full(100, np.nan), np.ones(finite)], 1.0)
    assert not r.passed and r.p_value is None and not r.messages
    assert r.failures[-1] == f"{finite} finite sample(s) left: the t-test needs at least 2"


def test_zero_variance_when_p_proportional_to_f():
    u = np.random.default_rng(7).random(10_000)
    x = np.sqrt(u)                                  # p(x) = 2x on [0, 1]
    assert mv.check_variance(x / (2 * x)).passed    # f = x: f/p = 1/2 always
    r = mv.check_variance(x ** 2 / (2 * x))
    # the reason, not "overflows float64" (an outside review: the zero-variance test's
    # statistic is +inf, which the overflow guard took for an overflow)
    assert not r.passed and r.failures == (
        f"expected zero variance (p ∝ f), measured {np.var(x / 2, ddof=1):.3g}",), r.failures


@pytest.mark.parametrize("scale", [1e-200, 1e-170, 1e200, 1e300])
def test_zero_variance_is_judged_at_the_samples_own_scale(scale):
    """check_variance(x, 0) compared the variance of x itself with (1e-12 · max|x|)²:
    noise of 1e-170 or 1e-200 has a variance that underflows to 0 and passed as a
    perfect estimator, and at 1e200 the tolerance's square raised Python's bare
    OverflowError (an outside review). It is now judged on x / max|x|: noise fails,
    naming its standard deviation where float64 cannot hold its variance, and a
    constant, or one to rounding, passes at any scale."""
    u = np.random.default_rng(3).random(1000)
    r = mv.check_variance(scale * u)
    assert not r.passed and r.failures[0].startswith("expected zero variance"), r.failures
    assert f"{scale * np.std(u, ddof=1):.3g}" in r.failures[0], r.failures
    constant = mv.check_variance(np.full(1000, scale))
    assert constant.passed and constant.details["variance"] == 0.0, constant.details
    assert mv.check_variance(scale * (1 + 1e-15 * (np.arange(1000) % 3))).passed


def test_a_perfect_float16_estimator_is_constant_to_float16_rounding():
    """Float16 estimates of 0.1 are 0.0999755859375, 2.4e-4 off: compared within
    float64's rounding they failed as a bias, with the advice to draw more samples (a
    mutation review's found-not-fixed). Float16 values are compared within one of their
    ulps (9.8e-4); 0.3 % off, three ulps, still fails, and so does a spread of 1 %."""
    assert mv.check_unbiased(np.full(1000, 0.1, dtype=np.float16), 0.1).passed
    assert mv.check_variance(np.full(1000, 0.1, dtype=np.float16), 0.0).passed
    assert not mv.check_unbiased(np.full(1000, 0.1003, dtype=np.float16), 0.1).passed
    noisy = (0.1 * (1 + 0.01 * np.random.default_rng(0).standard_normal(1000)))
    assert not mv.check_variance(noisy.astype(np.float16), 0.0).passed


def test_a_perfect_float32_estimator_is_constant_to_float32_rounding():
    """A float32 renderer's f/p with p ∝ f is constant only to float32's ulps: its
    estimates of 0.1 are 0.1f ± an ulp (7e-9). Both checks allowed float64's rounding
    only, so check_unbiased failed them by 278 standard errors, check_unbiased of
    np.full(n, np.float32(0.1)) against 0.1 failed ("every sample is
    0.100000001490116"), and check_variance(·, 0) measured a variance of 5.5e-18 (an
    outside review). Float32 values are now compared within 64 of their own ulps."""
    u = np.random.default_rng(0).random(100_000).astype(np.float32)
    x = np.sqrt(u)                                          # p(x) = 2x, float32
    est = (np.float32(0.2) * x) / (np.float32(2.0) * x)     # f = 0.2 x: f/p = 0.1
    assert est.dtype == np.float32 and np.ptp(est) > 0
    assert mv.check_unbiased(est, 0.1).passed
    assert mv.check_variance(est, 0.0).passed
    assert mv.check_unbiased(np.full(1000, 0.1, dtype=np.float32), 0.1).passed
    draw = lambda b: est[b * 10_000:(b + 1) * 10_000]      # noqa: E731
    assert mv.check_unbiased(draw, 0.1, batches=4).passed
    # what float32 cannot hide still fails: 0.1 % off, and a spread of 1e-4
    assert not mv.check_unbiased(np.full(1000, 0.1001, dtype=np.float32), 0.1).passed
    wobble = (est * (1 + 1e-4 * (u - np.float32(0.5)))).astype(np.float32)
    assert not mv.check_variance(wobble, 0.0).passed
    # float64 keeps float64's allowance
    assert not mv.check_unbiased(np.full(1000, float(np.float32(0.1))), 0.1).passed
    assert not mv.check_variance(est.astype(np.float64), 0.0).passed


def test_a_float32_expected_value_is_compared_within_float32_rounding():
    """The expected value may be float32 too (np.float32(0.1), a float32 renderer's
    reference): float64 samples constant at 0.1 failed against it until 7 December,
    "every sample is 0.1 (to rounding), but expected is 0.100000001490116". Its own
    rounding is allowed now; a float64 expected keeps float64's allowance."""
    assert mv.check_unbiased(np.full(1000, 0.1), np.float32(0.1)).passed
    draw = lambda b: np.full(1000, np.pi)                   # noqa: E731
    assert mv.check_unbiased(draw, np.float32(np.pi), batches=2).passed
    assert not mv.check_unbiased(np.full(1000, 0.1), np.float32(0.1001)).passed
    assert not mv.check_unbiased(np.full(1000, 0.1), float(np.float32(0.1))).passed


@pytest.mark.parametrize("call", [
    lambda e: mv.check_unbiased(np.full(1000, 0.1), e),
    lambda e: mv.check_convergence(lambda n, s: 0.1, e, ns=[64, 256], n_seeds=4),
], ids=["check_unbiased", "check_convergence"])
def test_a_float32_array_as_expected_is_refused_naming_it(call):
    """A float32 array as `expected` (a Dr.Jit mi.Float of width 1, the sum of a
    Dr.Jit integrand, reads as float32 (1,) in numpy) reached the float32 rounding
    allowance before validation and raised numpy's bare TypeError, "only 0-dimensional
    arrays can be converted to Python scalars" (an outside review)."""
    for bad in (np.array([0.1], dtype=np.float32), np.full(3, 0.1, dtype=np.float32)):
        with pytest.raises(mv.InvalidArgument, match=r"^expected=.*: must be a real number"):
            call(bad)


@pytest.mark.parametrize("scale", [1e-160, 1e-200, 1e-300, 1e-305])
def test_unbiased_at_tiny_scales_tests_the_mean(scale):
    """Estimates near the bottom of float64's range: their squares underflow, and the
    spread came out 0, so a correct estimator failed as "constant" (an outside review:
    from 1e-200 down). The spread is computed scaled; the verdicts are the unit scale's."""
    x = np.random.default_rng(0).random(100_000)
    for bias, passed in ((1.0, True), (1.01, False)):
        r = mv.check_unbiased(x * scale, 0.5 * bias * scale)
        ref = mv.check_unbiased(x, 0.5 * bias)
        assert r.passed is passed and ref.passed is passed, (scale, bias, r.summary())
        assert not r.details.get("constant"), r.messages
        assert r.p_value == pytest.approx(ref.p_value, rel=1e-6, abs=1e-300)


@pytest.mark.parametrize("scale", [1e-170, 1e300])
def test_unbiased_largest_sample_share_is_scale_free(scale):
    """details["max_sample_share"] squared the deviations unscaled: at 1e300 they
    overflowed (NaN, with numpy's overflow warnings), at 1e-170 they underflowed (0,
    "no sample dominates"); an outside review. It is the unit scale's now."""
    x = np.random.default_rng(0).random(1000)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = mv.check_unbiased(x * scale, 0.5 * scale)
    want = mv.check_unbiased(x, 0.5).details["max_sample_share"]
    assert r.details["max_sample_share"] == pytest.approx(want, rel=1e-9)


def test_a_known_variance_is_tested_at_its_level_and_a_wrong_one_says_why():
    """Fair coin flips and ±1 signs: (X − μ)² is constant, μ₄ = σ⁴, and the test's
    standard error was 0 (an exact comparison: 59 of 100 seeds failed at α = 0.01). With
    the sample variance's exact variance, 200 seeds give no false alarm (the test is
    conservative there; measured 0 in 1000); uniform and exponential samples keep the
    level (12 and 10 in 1000 at α = 0.01, not asserted here). A wrong claim fails
    saying by how much, scaled data does not overflow, constant data is no variance."""
    coin = [not mv.check_variance(np.random.default_rng(s).integers(0, 2, 10_000)
                                  .astype(float), 0.25).passed for s in range(200)]
    sign = [not mv.check_variance(np.random.default_rng(s).choice([-1.0, 1.0], 20_000),
                                  1.0).passed for s in range(50)]
    assert sum(coin) <= 5 and sum(sign) <= 3, (sum(coin), sum(sign))   # binomial: p < 1e-3
    u = np.random.default_rng(0).random(100_000)
    wrong = mv.check_variance(u, 1.03 / 12)
    assert not wrong.passed and not wrong.failures
    assert "standard errors below it" in wrong.messages[0], wrong.messages
    assert mv.check_variance(u * 1e100, 1e200 / 12).passed     # (s²)² overflowed before
    big = mv.check_variance(u * 1e160, 1e300)
    assert not big.passed and "overflows float64" in big.failures[0], big.failures
    const = mv.check_variance(np.full(1000, 1e-3), 5e-9)       # np.isclose passed it
    assert not const.passed and "samples are constant" in const.messages[0], const.messages


@pytest.mark.parametrize("samples", [np.full(10, np.nan), np.r_[np.inf, 1.0, np.nan]])
def test_variance_of_too_few_finite_samples_fails_saying_so(samples):
    """All but one sample NaN/Inf: a failed check naming both problems (it was a
    ZeroDivisionError), with no statistic: None, as every check's verdict without one
    (it was NaN, the string "nan" in its JSON where a number or null is read)."""
    r = mv.check_variance(samples, 1.0)
    assert not r.passed and any("NaN/Inf" in f for f in r.failures)
    assert r.statistic is None and json.loads(json_text(r.to_dict()))["statistic"] is None
    assert any("a variance needs at least 2" in f for f in r.failures), r.failures


def test_convergence_slope():
    def est(n, s):
        return np.mean(np.random.default_rng(s).random(n))
    assert mv.check_convergence(est, 0.5, n_seeds=32).passed

    def biased(n, s):   # a constant bias: RMSE stops falling, slope -> 0
        return np.mean(np.random.default_rng(s).random(n)) + 0.01
    assert not mv.check_convergence(biased, 0.5, n_seeds=32).passed
    # the interval it prints is at 1 - alpha (it always said 99 %)
    r = mv.check_convergence(biased, 0.5, n_seeds=32, alpha=0.2)
    assert r.messages[0].startswith(f"slope {r.statistic:.3f} (80% CI ["), r.messages
    # "less" far in its tail: p was 1 - cdf, exactly 0 below 1e-16 (an outside review)
    r = mv.check_convergence(biased, 0.5, n_seeds=32, expected_slope=-1.0,
                             alternative="less")
    assert not r.passed and 0.0 < r.p_value < 1e-16, r.p_value


def test_convergence_of_a_float32_exact_estimator_says_it_is_exact():
    """A float32 estimator that is exact to float32's rounding (p ∝ f, or a constant
    np.float32(0.1) against 0.1) has an RMSE of float32 ulps at every N: until
    7 December its flat RMSE was fitted, "slope 0.000 (99% CI [-0.000, 0.000]),
    expected -0.5", p = 4e-168, where float64's got "RMSE is 0 (to rounding)". A
    float32 estimator of real noise is still fitted."""
    f32 = np.float32

    def perfect(n, s):
        x = np.sqrt(np.random.default_rng(s).random(n).astype(f32))
        return np.mean((f32(0.2) * x) / (f32(2.0) * x), dtype=f32)

    for est, expected in ((perfect, 0.1), (lambda n, s: f32(0.1), 0.1),
                          (lambda n, s: 0.1, f32(0.1))):
        r = mv.check_convergence(est, expected, ns=[64, 256, 1024, 4096], n_seeds=16)
        assert not r.passed and r.statistic is None
        assert r.failures[0].startswith("RMSE is 0 (to rounding) at N=[64, 256, 1024, "
                                        "4096]"), r.failures

    def noisy(n, s):
        return np.mean(np.random.default_rng(s).random(n).astype(f32), dtype=f32)

    r = mv.check_convergence(noisy, 0.5, ns=[256, 1024, 4096, 16384], n_seeds=32)
    assert r.passed and r.statistic is not None, r.summary()


@pytest.mark.parametrize("scale", [1e-155, 1e-170, 1e-300, 1e160, 1e300])
def test_convergence_at_extreme_scales_fits_the_unit_scale_slope(scale):
    """Errors near the ends of float64's range: their squares underflowed or overflowed,
    so a correct estimator of an integral of 1e-155 failed, "slope 0.000 (99% CI
    [-0.000, 0.000])", p = 4e-168; at 1e-160 it was called exact ("RMSE is 0"), and at
    1e160 its finite estimates "overflow when squared" (until 7 December). The errors
    are squared scaled; the slope, p-value and RMSE are the unit scale's."""
    def est(n, s, scale=1.0):
        return scale * np.mean(np.random.default_rng(s).random(n))

    kw = dict(ns=[64, 256, 1024, 4096], n_seeds=16)
    ref = mv.check_convergence(est, 0.5, **kw)
    r = mv.check_convergence(lambda n, s: est(n, s, scale), 0.5 * scale, **kw)
    assert r.passed and ref.passed and not r.failures, r.summary()
    assert r.statistic == pytest.approx(ref.statistic, rel=1e-9)
    assert r.p_value == pytest.approx(ref.p_value, rel=1e-6)
    assert np.allclose(np.divide(r.details["rmse"], scale), ref.details["rmse"], rtol=1e-9)


def test_convergence_of_an_estimator_that_ignores_its_seed_says_so():
    """An unrandomised "QMC" estimator (the same point set for every seed) has one error
    at each N, no spread: the jackknife's standard error was 0, so the slope's interval
    had no width and the verdict was the sign of the error's slope against the claim.
    A midpoint rule (N^-2) passed the RQMC claim ``expected_slope=-1.0,
    alternative="less"``, "slope -2.000 (99% CI [-2.000, -2.000])", p = 1, and
    unscrambled Sobol on exp(xy) failed it at p = 0 saying only "slope -0.977" (until
    7 December). Both now fail saying the estimator ignores its seed."""
    from scipy.stats import qmc

    def midpoint(n, seed):       # a fixed shift, the same for every seed
        return float(np.mean(np.exp((np.arange(n) + 0.5) / n)))

    def sobol(n, seed):          # unscrambled: seed unused
        p = qmc.Sobol(2, scramble=False).random(n)
        return float(np.mean(np.exp(p[:, 0] * p[:, 1])))

    def shuffled(n, seed):       # the midpoints in a seed's order: the last bits differ
        x = np.random.default_rng(seed).permutation((np.arange(n) + 0.5) / n)
        return float(np.mean(np.exp(x)))

    for est, expected in ((midpoint, np.e - 1.0), (sobol, 1.3179021514544038),
                          (shuffled, np.e - 1.0)):
        r = mv.check_convergence(est, expected, ns=[64, 256, 1024, 4096], n_seeds=8,
                                 expected_slope=-1.0, alternative="less")
        assert not r.passed and r.p_value is None, r.summary()
        assert "the same value (to rounding) for all 8 seeds at every N" in r.failures[0], \
            r.failures
        assert "ignores its seed" in r.failures[0], r.failures


def test_a_discrepancy_names_the_extent_of_its_cell():
    """A wide cell's centre alone misled: a cone 10 % wider than its pdf about the pole
    (cos θ_max = 1 - 1.1e-6 against 1 - 1e-6) was reported at z ≈ 0.9677, the centre of
    the cell beyond the rim, far from any of its points (until 7 December). The message
    now gives the cell's extent, which reaches to the rim."""
    ct = 1.0 - 1e-6

    def cone(u, width=1.1):
        z = 1.0 - u[:, 0] * (1.0 - ct) * width
        r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
        return np.stack([r * np.cos(2 * np.pi * u[:, 1]), r * np.sin(2 * np.pi * u[:, 1]),
                         z], 1)

    pdf = lambda x: np.where(x[:, 2] >= ct, 1 / (2 * np.pi * (1 - ct)), 0.0)  # noqa: E731
    r = mv.check_sampler(cone, pdf, "sphere", n_samples=200_000, seed=0)
    assert not r.passed
    m = next(m for m in r.messages if m.startswith("largest discrepancy at"))
    lo = float(m.split("(the cell (1 - z) / 2 in [")[1].split(",")[0])
    assert lo < 1e-6, m
    r = mv.check_same_distribution(cone, lambda u: cone(u, 1.0), "sphere",
                                   n_samples=200_000, seed=0)
    m = next(m for m in r.messages if m.startswith("largest discrepancy at"))
    assert float(m.split("(the cell (1 - z) / 2 in [")[1].split(",")[0]) < 1e-6, m


# ----------------------------------------------------------------- streaming judge
def test_stream_is_independent_of_chunk_size_and_thread_count():
    """The uniforms come in seeded blocks of STREAM_BLOCK rows, so cutting the stream into
    other chunks, or binning on one thread instead of two, changes nothing."""
    import numba

    from mcverify.checks.sampler import STREAM_BLOCK

    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        a = mv.check_sampler(cosine, W.cosine_hemisphere_pdf, "hemisphere",
                             n_samples=5 * STREAM_BLOCK + 123, seed=8, chunk=STREAM_BLOCK)
        numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
        b = mv.check_sampler(cosine, W.cosine_hemisphere_pdf, "hemisphere",
                             n_samples=5 * STREAM_BLOCK + 123, seed=8, chunk=4 * STREAM_BLOCK)
    finally:
        numba.set_num_threads(before)
    assert np.array_equal(a.artifacts["histogram"]["observed"],
                          b.artifacts["histogram"]["observed"])
    assert a.p_value == b.p_value and a.statistic == b.statistic


@pytest.mark.parametrize("n", [1, STREAM_BLOCK_FOR_TESTS - 1, STREAM_BLOCK_FOR_TESTS,
                               3 * STREAM_BLOCK_FOR_TESTS + 7])
def test_pilot_uniforms_are_the_streams_rows(n):
    """The pilot's all-at-once draw (``_uniforms``) is row for row the chunked stream
    (``_uniform_chunks``), whatever the chunk size: the same blocks, the same generators."""
    from mcverify.checks.sampler import _uniform_chunks, _uniforms

    seq = np.random.SeedSequence(42).spawn(2)[1]
    whole = _uniforms(seq, n, 3)
    for chunk in (STREAM_BLOCK_FOR_TESTS, 2 * STREAM_BLOCK_FOR_TESTS):
        parts = np.concatenate([u for _, u in _uniform_chunks(seq, n, 3, chunk)])
        assert whole.shape == (n, 3) and np.array_equal(whole, parts)
    assert not np.array_equal(whole, _uniforms(np.random.SeedSequence(43), n, 3))


def _mixture_quantiles_by_numpy(ps, r):
    """The cell edges' definition in numpy (the judge's code before 3 December): the
    merged candidates by ``np.insert``, inverted by ``np.interp``."""
    lin = np.linspace(0.0, 1.0, 4 * r + 1)
    at = np.searchsorted(ps, lin, side="right")
    cand = np.insert(ps, at, lin)
    g = np.insert(0.5 * np.arange(1, ps.size + 1) / ps.size + 0.5 * ps, at,
                  0.5 * at / ps.size + 0.5 * lin)
    return np.interp(np.linspace(0.0, 1.0, r + 1), g, cand)


@pytest.mark.parametrize("pilot", ["uniform", "peaked", "ties", "zeros", "both ends"])
def test_cell_edges_equal_numpys_interp_of_the_merged_mixture(pilot):
    """The pilot's cell edges come from one numba merge walk (``_mixture_quantiles``):
    bit for bit numpy's insert + interp of the same mixture CDF, also with pilot values
    tied to the uniform points, all equal, or piled at both ends of [0, 1)."""
    from mcverify.checks.sampler import _mixture_quantiles

    rng = np.random.default_rng(11)
    for _ in range(200):
        n, r = int(rng.integers(1, 3000)), int(rng.integers(1, 200))
        ps = {"uniform": lambda: rng.random(n), "peaked": lambda: rng.random(n) ** 8,
              "ties": lambda: np.round(rng.random(n) * 8) / 8,
              "zeros": lambda: np.zeros(n),
              "both ends": lambda: np.minimum(1 - 2.0 ** -52, rng.random(n) * 1e-9
                                              + rng.integers(0, 2, n))}[pilot]()
        ps = np.sort(ps)
        e = np.empty(r + 1)
        _mixture_quantiles(ps, np.linspace(0.0, 1.0, 4 * r + 1), np.linspace(0.0, 1.0, r + 1), e)
        assert np.array_equal(e, _mixture_quantiles_by_numpy(ps, r)), (n, r)


def test_bad_chunk_is_rejected_before_any_work():
    with pytest.raises(mv.InvalidArgument, match="chunk=1000"):
        mv.check_sampler(cosine, W.cosine_hemisphere_pdf, "hemisphere", chunk=1000)


def test_float32_points_are_binned_as_they_are():
    a = mv.check_sampler(lambda u: W.sample_cosine_hemisphere(u.astype(np.float32)),
                         W.cosine_hemisphere_pdf, "hemisphere", n_samples=200_000, seed=2)
    assert a.passed, a.summary()


def test_binned_ks_in_one_dimension_catches_a_small_shift():
    # A 0.3 % shift of a tent: the χ² cells barely see it, the fine-grid KS does.
    r = mv.check_sampler(lambda u: W.sample_tent(u, 1.0) + 0.003, lambda x: W.tent_pdf(x, 1.0),
                         mv.Interval(-1.5, 1.5), n_samples=1_000_000, seed=3)
    assert not r.passed and r.details["tests"]["ks"]["p_value"] < 1e-4


# ------------------------------------------------------------------ rejected draws
def _rejecting(u):
    """Cosine-weighted candidates accepted with probability cos θ: the accepted points
    have the sub-density cos²θ / π, which integrates to P = 2/3."""
    x = W.sample_cosine_hemisphere(u[:, :2])
    x[u[:, 2] >= x[:, 2]] = np.nan
    return x


def _sub_density(scale=1.0, power=2.0):
    # ∫ c z^power dω over the hemisphere = 2π c / (power + 1); c keeps P = 2/3 · scale.
    c = scale * (2.0 / 3.0) * (power + 1.0) / (2.0 * np.pi)
    return lambda x: c * np.maximum(x[:, 2], 0.0) ** power


def test_rejection_sampler_passes_and_reports_its_acceptance():
    r = mv.check_sampler(_rejecting, _sub_density(), "hemisphere", sample_dim=3,
                         rejection=True, seed=5)
    assert r.passed, (r.summary(), r.failures, r.messages)
    rej = r.details["rejection"]
    assert abs(rej["acceptance_rate"] - 2 / 3) < 3e-3
    assert abs(rej["pdf_integral"] - 2 / 3) < 1e-6
    assert r.details["tests"]["acceptance"]["p_value"] > 0.01


def test_a_row_nan_in_some_coordinates_is_named_as_no_rejected_draw():
    """A plastic's delta lobe written as NaN in x and y with z = 1 kept, judged with
    rejection=True: until 7 December check_sampler and check_pdf_consistency failed it
    as NaN/Inf points without a word on why those rows were not rejected draws (the
    acceptance line said every draw was accepted). Both now say that a rejected draw is
    NaN in every coordinate."""
    def sample(u):
        x = W.sample_cosine_hemisphere(u[:, 1:])
        x[u[:, 0] < 0.3, :2] = np.nan
        return x

    def pdf(x):
        return 0.7 * W.cosine_hemisphere_pdf(x)

    r = mv.check_sampler(sample, pdf, "hemisphere", sample_dim=3, rejection=True,
                         n_samples=20_000)
    assert not r.passed
    assert "a rejected draw is a row of NaN in every coordinate" in r.failures[0], r.failures
    r = mv.check_pdf_consistency(lambda u: (sample(u), pdf(sample(u))), pdf, sample_dim=3,
                                 rejection=True, n_samples=2000)
    assert not r.passed
    assert "a rejected draw is a row of NaN in every coordinate" in r.failures[0], r.failures

    # an infinite point, no NaN in it, is no half-written rejection: no such hint (a
    # read-only review of the change above)
    def infinite(u):
        x = W.sample_cosine_hemisphere(u[:, 1:])
        x[u[:, 0] < 0.3, 2] = np.inf
        return x

    r = mv.check_sampler(infinite, pdf, "hemisphere", sample_dim=3, rejection=True,
                         n_samples=20_000)
    assert not r.passed and "NaN/Inf" in r.failures[0], r.failures
    assert "rejected draw" not in r.failures[0], r.failures
    r = mv.check_pdf_consistency(lambda u: (infinite(u), pdf(infinite(u))), pdf,
                                 sample_dim=3, rejection=True, n_samples=2000)
    assert not r.passed and "rejected draw" not in r.failures[0], r.failures


def _accepting(t):
    """Cosine-weighted points, each kept with probability ``t`` (a mask's opacity)."""
    def sample(u):
        x = W.sample_cosine_hemisphere(u[:, 1:])
        x[u[:, 0] >= t] = np.nan
        return x
    return sample, lambda x: t * W.cosine_hemisphere_pdf(x)


@pytest.mark.parametrize("t", [0.3, 0.05])
def test_a_low_acceptance_costs_the_cubature_no_more_than_none(t):
    """With rejection a cell expects n_valid · mass / ∫pdf. Scored against n_valid ·
    mass, every cell of a sampler accepting 30 % of its draws looked 3x over-full and was
    re-integrated (8.7 million pdf evaluations at 1e6 draws instead of 0.47 million), and
    the first integral's tolerance was 1/√t times τ of a cell's noise."""
    runs = {a: mv.check_sampler(*_accepting(a), "hemisphere", sample_dim=3, rejection=True,
                                seed=5, n_samples=200_000) for a in (1.0, t)}
    assert all(r.passed for r in runs.values()), [r.summary() for r in runs.values()]
    assert runs[t].details["pdf_evaluations"] <= 1.5 * runs[1.0].details["pdf_evaluations"]


@pytest.mark.parametrize("t", [0.0, 1e-16])
def test_a_sampler_rejecting_every_draw_where_none_was_expected_passes(t):
    """Every draw rejected where the pdf integrates to 0 or to so little that none of n
    draws was expected (the tracer's plastic at θ_i = 90°: its diffuse lobe keeps 1e-16
    of the mass, the rest a delta lobe's NaN rows). At 1e-16 the check failed with "no
    valid samples to test" until 6 December, though the binomial test had p = 1."""
    r = mv.check_sampler(*_accepting(t), "hemisphere", sample_dim=3, rejection=True,
                         seed=5, n_samples=100_000)
    assert r.passed, (r.summary(), r.failures, r.messages)
    assert r.details["rejection"]["accepted"] == 0
    assert any("nothing else to test" in m for m in r.messages), r.messages


def test_every_draw_rejected_with_a_pdf_of_nan_is_not_called_consistent():
    """Every draw rejected, and a pdf returning NaN (a Mitsuba plugin of a NaN
    parameter): the check failed on the NaN values, while its message said "consistent,
    nothing else to test" (an outside review)."""
    r = mv.check_sampler(lambda u: np.full((len(u), 3), np.nan),
                         lambda x: np.full(len(x), np.nan), "hemisphere", rejection=True,
                         seed=5, n_samples=10_000)
    assert not r.passed and any("NaN/Inf" in f for f in r.failures), r.failures
    assert not any("consistent" in m for m in r.messages), r.messages


def test_a_sampler_rejecting_every_draw_where_some_were_expected_fails():
    """A sampler rejecting every draw where its pdf says 1 draw in 1000 is accepted (100
    expected of 1e5): the acceptance test fails it."""
    r = mv.check_sampler(lambda u: np.full((len(u), 3), np.nan), _accepting(1e-3)[1],
                         "hemisphere", sample_dim=3, rejection=True, seed=5,
                         n_samples=100_000)
    assert not r.passed and r.p_value < 1e-30, (r.summary(), r.messages)
    assert any(m.startswith("acceptance: 0 of") for m in r.messages), r.messages


def test_rejected_draws_are_failures_without_rejection():
    r = mv.check_sampler(_rejecting, _sub_density(), "hemisphere", sample_dim=3,
                         n_samples=50_000)
    assert not r.passed and any("NaN/Inf" in f for f in r.failures)


def test_wrong_acceptance_rate_fails_and_says_so():
    r = mv.check_sampler(_rejecting, _sub_density(scale=1.01), "hemisphere", sample_dim=3,
                         rejection=True, seed=5)
    assert not r.passed
    assert r.details["tests"]["acceptance"]["p_value"] < 1e-6
    assert r.details["tests"]["chi2"]["p_value"] > 1e-3   # the shape is right
    assert any(m.startswith("acceptance:") for m in r.messages), r.messages


def test_wrong_shape_of_accepted_samples_fails():
    r = mv.check_sampler(_rejecting, _sub_density(power=1.9), "hemisphere", sample_dim=3,
                         rejection=True, seed=5)
    assert not r.passed
    assert r.details["tests"]["acceptance"]["p_value"] > 1e-3   # the rate is right
    assert min(r.details["tests"][k]["p_value"] for k in ("chi2", "chi2_axis0")) < 1e-6


def test_pdf_above_one_cannot_be_an_acceptance_probability():
    r = mv.check_sampler(cosine, lambda x: 1.2 * W.cosine_hemisphere_pdf(x), "hemisphere",
                         rejection=True, n_samples=100_000)
    assert not r.passed and any("above 1" in f for f in r.failures)


def test_same_distribution_with_rejected_draws():
    def other_rejecting(u):     # same law, drawn by a different map: u2 compared to z
        x = W.sample_cosine_hemisphere(u[:, 1:])
        x[u[:, 0] >= x[:, 2]] = np.nan
        return x

    def fewer(u):               # accepts with probability 0.99·cos θ
        x = W.sample_cosine_hemisphere(u[:, :2])
        x[u[:, 2] >= 0.99 * x[:, 2]] = np.nan
        return x

    same = mv.check_same_distribution(_rejecting, other_rejecting, "hemisphere",
                                      sample_dim=3, rejection=True, seed=2)
    assert same.passed, same.details["tests"]
    diff = mv.check_same_distribution(_rejecting, fewer, "hemisphere", sample_dim=3,
                                      rejection=True, seed=2)
    assert not diff.passed and diff.details["tests"]["acceptance"]["p_value"] < 1e-6
    plain = mv.check_same_distribution(_rejecting, other_rejecting, "hemisphere",
                                       sample_dim=3, n_samples=20_000)
    assert not plain.passed and any("NaN/Inf" in f for f in plain.failures)


def test_same_distribution_names_no_cell_where_only_the_acceptance_rates_differ():
    """Two samplers drawing the same law, rejecting 10 % and 12 % of draws: only the
    acceptance test rejects, yet the grid's most extreme noise cell was named "largest
    discrepancy" (16 against 43 points). Seeded; α = 0.01."""
    def rejecting(p):
        def sample(u):
            x = W.sample_cosine_hemisphere(u[:, :2])
            x[u[:, 2] < p] = np.nan
            return x
        return sample

    r = mv.check_same_distribution(rejecting(0.1), rejecting(0.12), "hemisphere",
                                   sample_dim=3, n_samples=200_000, rejection=True, seed=1)
    level = r.alpha / len(r.details["tests"])
    assert not r.passed and r.details["tests"]["acceptance"]["p_value"] < 1e-50
    assert all(t["p_value"] > level for k, t in r.details["tests"].items()
               if k.startswith("chi2")), r.details["tests"]
    assert any(m.startswith("acceptance differs") for m in r.messages), r.messages
    assert not any("largest discrepancy" in m for m in r.messages), r.messages


def test_same_distribution_names_the_cdf_gap_where_only_the_ks_test_rejects():
    """A smooth shift of 0.4 % (x + 0.004 sin πx): the χ² test does not see it (p =
    0.26), the KS test does (p = 6e-9), and until 7 December the failure said nothing
    of where. It now names the largest gap of the two CDFs, near x = 0.5 where the shift
    peaks, with both sides' shares below it. Seeded; α = 0.01."""
    a = lambda u: u[:, :1]
    b = lambda u: np.clip(u[:, :1] + 0.004 * np.sin(np.pi * u[:, :1]), 0.0, 1.0)
    r = mv.check_same_distribution(a, b, "interval", n_samples=1_000_000, seed=1)
    level = r.alpha / len(r.details["tests"])
    assert not r.passed and r.details["tests"]["chi2"]["p_value"] > level
    gap = next(m for m in r.messages if m.startswith("largest CDF gap at x≈"))
    x = float(gap.split("≈")[1].split(":")[0])
    assert 0.4 < x < 0.6, gap
    assert "of sample_a and" in gap and "KS p = " in gap, gap


def test_cubature_is_cached_by_pdf_identity_and_grid():
    """A repeated check integrates once and decides the same; another seed (other cell
    edges) or a pdf whose values changed since (hidden state) integrates afresh; the
    pdf's bad values met by the cached integration are still reported."""
    from mcverify.checks.sampler import _CUBATURE

    _CUBATURE.clear()
    run = lambda pdf, seed=6: mv.check_sampler(cosine, pdf, "hemisphere", n_samples=100_000,
                                               seed=seed)
    a, b = run(W.cosine_hemisphere_pdf), run(W.cosine_hemisphere_pdf)
    assert not a.details["cubature_cached"] and b.details["cubature_cached"]
    assert (a.p_value, a.statistic, a.details["pdf_integral"]) == \
        (b.p_value, b.statistic, b.details["pdf_integral"])
    assert np.array_equal(a.artifacts["histogram"]["expected"],
                          b.artifacts["histogram"]["expected"])
    assert not run(W.cosine_hemisphere_pdf, seed=7).details["cubature_cached"]

    scale = [1.0]

    def stateful(x):
        return scale[0] * W.cosine_hemisphere_pdf(x)
    assert run(stateful).passed
    scale[0] = 1.03
    r = run(stateful)
    assert not r.details["cubature_cached"] and not r.passed
    assert any("integrates to 1.03" in f for f in r.failures)

    def negative(x):
        return W.cosine_hemisphere_pdf(x) - 0.01
    first, again = run(negative), run(negative)
    assert again.details["cubature_cached"]
    assert [f for f in first.failures if "negative" in f] == \
        [f for f in again.failures if "negative" in f] != []


def _arcsine_sample(u):
    return np.sin(np.pi * u[:, 0] / 2) ** 2


def _arcsine_pdf(x, scale=1.0):
    x = x[:, 0]
    with np.errstate(divide="ignore"):
        return scale / (np.pi * np.sqrt(x * (1 - x)))


def _theta_uniform_sample(u, power=1.0):
    th = u[:, 0] ** power * np.pi / 2
    phi = 2 * np.pi * u[:, 1]
    return np.stack([np.sin(th) * np.cos(phi), np.sin(th) * np.sin(phi), np.cos(th)], -1)


def _theta_uniform_pdf(x):
    with np.errstate(divide="ignore"):
        return 1 / (np.pi ** 2 * np.hypot(x[:, 0], x[:, 1]))


def _r_uniform_sample(u):
    r, phi = u[:, 0], 2 * np.pi * u[:, 1]
    return np.stack([r * np.cos(phi), r * np.sin(phi)], -1)


def _r_uniform_pdf(x, scale=1.0):
    with np.errstate(divide="ignore"):
        return scale / (2 * np.pi * np.hypot(x[:, 0], x[:, 1]))


@pytest.mark.parametrize("sample, pdf, domain", [
    (_arcsine_sample, _arcsine_pdf, "interval"),
    (_theta_uniform_sample, _theta_uniform_pdf, "hemisphere"),
    (_r_uniform_sample, _r_uniform_pdf, "disk"),
], ids=["arcsine", "hemisphere-uniform-in-theta", "disk-uniform-in-r"])
def test_pdfs_with_integrable_singularities_pass_and_their_bugs_fail(sample, pdf, domain):
    """Correct samplers whose density is infinite on the domain's edge or at a point
    (the arcsine at 0 and 1, 1/sin θ at the pole, 1/r at the disk's centre): they pass
    (they failed with "pdf returned ... NaN/Inf" at the singular point, which the
    cubature evaluated exactly), and the same pdf 2 % too large, or the hemisphere's
    sampler drawing θ ∝ u^1.05, fails."""
    r = mv.check_sampler(sample, pdf, domain, n_samples=200_000, seed=4)
    assert r.passed, (r.failures, r.messages, r.p_value)
    assert abs(r.details["pdf_integral"] - 1.0) < 1e-4
    if domain == "hemisphere":
        bad = mv.check_sampler(lambda u: _theta_uniform_sample(u, 1.05), pdf, domain,
                               n_samples=200_000, seed=4)
    else:
        bad = mv.check_sampler(sample, lambda x: pdf(x, 1.02), domain, n_samples=200_000,
                               seed=4)
    assert not bad.passed


def test_the_largest_discrepancy_is_a_cell_the_chi2_test_weighs():
    """A cell expecting 0.01 counts that got 1 (a correct sampler's tail, pooled by the
    χ² test) used to top the "largest discrepancy" list ahead of the cell that drove the
    failure; a count where the pdf integrates to 0 still comes first."""
    from mcverify.checks.sampler import _worst_cells
    from mcverify.domains import Square

    edges = [np.linspace(0, 1, 4), np.linspace(0, 1, 4)]
    expected = np.full((3, 3), 100.0)
    expected[0, 0] = 0.01
    counts = expected.copy()
    counts[0, 0] = 1.0
    counts[2, 1] = 140.0
    worst = _worst_cells(Square(), edges, counts, expected)
    assert worst[0]["cell"] == [2, 1]
    expected[1, 1], counts[1, 1] = 0.0, 1.0
    assert _worst_cells(Square(), edges, counts, expected)[0]["cell"] == [1, 1]


def test_a_cell_is_printed_with_the_digits_that_tell_its_ends_apart():
    """A sampler clamped at 1 (2.4 % of its draws exactly 1) fails in the last cell, one
    ulp wide below 1, and until 7 December it was named "the cell [1, 1)", an empty
    interval; its ends are now printed to the digits that differ, and a last cell, which
    holds its end, closes with "]". Other cells keep six digits."""
    r = mv.check_sampler(lambda u: np.clip(1.05 * u[:, 0] - 0.025, 0.0, 1.0),
                         lambda x: np.ones(len(x)), "interval", n_samples=100_000, seed=1)
    assert not r.passed
    (m,) = [m for m in r.messages if m.startswith("largest discrepancy")]
    assert "(the cell [0.9999999999999998, 1]):" in m, m
    from mcverify.checks.sampler import _span
    assert _span(0.25, 0.2512345678, 6) == "[0.25, 0.251235)"


def test_a_point_at_the_scale_of_metres_is_printed_with_its_digits():
    """A wavelength sampler in metres on Interval(3.6e-7, 8.3e-7), missing its last
    fifth, was reported at "x≈[0.0] (the cell [...e-07, ...e-07))" and, with a pdf of 0
    there, "first x = [0.0]": the centre was rounded to 4 decimals (an outside review).
    Coordinates keep 4 (6) significant digits where the decimals would lose them."""
    a, b = 3.6e-7, 8.3e-7
    r = mv.check_sampler(lambda u: a + 0.8 * (b - a) * u[:, 0],
                         lambda x: np.full(len(x), 1 / (b - a)), mv.Interval(a, b),
                         n_samples=20_000, seed=1)
    (m,) = [m for m in r.messages if m.startswith("largest discrepancy")]
    centre = float(m.split("x≈[")[1].split("]")[0])
    assert a + 0.8 * (b - a) < centre < b, m
    r = mv.check_sampler(lambda u: a + (b - a) * u[:, 0],
                         lambda x: np.where(np.ravel(x) < 6e-7, 1 / (6e-7 - a), 0.0),
                         mv.Interval(a, b), n_samples=20_000, seed=1)
    (f,) = [f for f in r.failures if "where the pdf is 0" in f]
    first = float(f.split("first x = [")[1].split("]")[0])
    assert 6e-7 <= first <= b, f
    from mcverify.checks.sampler import _rounded
    assert _rounded([0.1555049, 368.20594, 0.0], 4) == [0.1555, 368.2059, 0.0]
    assert _rounded([5.8225556e-07, -0.0123456], 4) == [5.823e-07, -0.01235]


def test_a_failure_names_where_the_rejecting_test_saw_it():
    """The "largest discrepancy" was the full grid's worst cell whatever sub-test had
    rejected: a sampler whose x follows 1.015·x^0.015 (too few points near x = 0), caught
    by the x marginal alone, was reported at x≈[0.105, 0.558], "observed 144, expected
    101.8", a noise cell with too many; a 1-D sampler caught by the KS test alone, and a
    rejection sampler whose acceptance rate alone is wrong, likewise (an outside review).
    Seeded: the grid's χ² test does not reject at these seeds."""
    for seed in (0, 2):
        r = mv.check_sampler(lambda u: np.stack([u[:, 0] ** (1 / 1.015), u[:, 1]], 1),
                             lambda x: np.ones(len(x)), "square", n_samples=200_000,
                             seed=seed)
        assert not r.passed and r.details["tests"]["chi2"]["p_value"] > 0.01
        (m,) = [m for m in r.messages if m.startswith("largest discrepancy")]
        assert m.startswith("largest discrepancy in the first axis' marginal, x in [0, "), m
        obs, exp = (float(v) for v in m.split("observed ")[1].split(", expected "))
        assert obs < exp, m
    r = mv.check_sampler(lambda u: 2 + 3 * u ** (1 / 1.01), lambda x: np.full(len(x), 1 / 3),
                         mv.Interval(2, 5), n_samples=200_000, seed=0)
    assert not r.passed and r.details["tests"]["chi2"]["p_value"] > 0.01
    (m,) = r.messages
    # F(x) = t^1.01 below the pdf's t = (x - 2) / 3, farthest at t = 1.01^-100 ≈ 0.37
    assert m.startswith("largest CDF gap at x≈3.0") and "KS p = " in m, m

    def disk(u):
        x = 2 * u - 1
        x[(x ** 2).sum(1) > 1] = np.nan
        return x

    r = mv.check_sampler(disk, lambda x: np.full(len(x), 0.98 / 4), "disk",
                         n_samples=200_000, rejection=True)
    assert not r.passed
    assert [m.split(":")[0] for m in r.messages] == ["acceptance"], r.messages


def test_worst_cells_rank_overflowed_expectations_first():
    """Expected counts that overflowed to inf give NaN contributions: the worst cells
    still list them (first), and otherwise the largest contributions, ties in cell order."""
    from mcverify.checks.sampler import _worst_cells

    edges = [np.linspace(0, 1, 5)] * 2
    counts = np.full((4, 4), 10.0)
    expected = np.full((4, 4), 10.0)
    expected[1, 2] = np.inf
    expected[3, 0] = 2.0            # contribution 64 / 5
    expected[0, 1] = expected[2, 2] = 6.0   # a tie at 16 / 6
    with np.errstate(invalid="ignore"):
        w = _worst_cells(mv.Square(), edges, counts, expected, k=3)
    assert [c["cell"] for c in w] == [[1, 2], [3, 0], [0, 1]]
    assert np.allclose(w[2]["point"], [0.125, 0.375])


@pytest.mark.parametrize("case", ["uniform", "empty", "one", "signs", "wide", "ties", "equal",
                                  "column"])
def test_the_pilots_radix_sort_sorts_as_numpy_does(case):
    """``radix_sorted`` (the pilot's sort) gives ``np.sort``'s values: negative values,
    ±0, subnormals, ±inf, ties, digits all equal (skipped passes), 0 and 1 values, a
    strided column (as the pilot's axes are); its input is left as it was."""
    from mcverify.checks.sampler import radix_sorted

    rng = np.random.default_rng(5)
    x = {"uniform": rng.random(100_003), "empty": np.zeros(0), "one": np.array([0.3]),
         "signs": np.array([-0.0, 0.0, -1e-310, 1e-310, -np.inf, np.inf, 5.0, -5.0, 5.0,
                            -2.5, 1e-300, -1e300]),
         "wide": rng.standard_normal(20_001) * 10.0 ** rng.integers(-300, 300, 20_001),
         "ties": rng.integers(-3, 4, 5_000).astype(float),
         "equal": np.full(1000, 0.25), "column": rng.standard_normal((3001, 2))[:, 1]}[case]
    before = x.copy()
    assert np.array_equal(radix_sorted(x), np.sort(x))
    assert np.array_equal(x, before)


def _cone(c):
    return (lambda u: W.sample_uniform_cone(u, c)), (lambda x: W.uniform_cone_pdf(x, c))


@pytest.mark.parametrize("case", ["cone 1e-8", "cone 1e-12", "beckmann 1e-6"])
@pytest.mark.parametrize("seed", [0, 1])
def test_supports_far_narrower_than_a_cell_are_integrated(case, seed):
    """A cone of cos θ_max = 1 - 1e-8 puts its support in 2e-9 of its cell's width: no
    node of the cubature met it, the cell's mass was 0 and a correct sampler failed
    ("samples fell in cells where the pdf integrates to 0", ∫pdf = 0.97). The pilot's
    points in such a cell now guide its re-integration. A planted bug in the same narrow
    lobe still fails: a pdf 3 % high, a sampler's cone 10 % wider than its pdf's."""
    kind, size = case.split()
    if kind == "cone":
        c = 1 - float(size)
        sample, pdf = _cone(c)
        wide, _ = _cone(1 - 1.1 * float(size))
        domain = "sphere"
    else:
        a = float(size)
        sample, pdf = (lambda u: W.sample_beckmann(u, a)), (lambda x: W.beckmann_pdf(x, a))
        wide = lambda u: W.sample_beckmann(u, 1.1 * a)    # noqa: E731
        domain = "hemisphere"
    kw = dict(n_samples=200_000, seed=seed)
    r = mv.check_sampler(sample, pdf, domain, **kw)
    assert r.passed, r.failures
    assert abs(r.details["pdf_integral"] - 1) < 1e-3
    assert not mv.check_sampler(sample, lambda x: 1.03 * pdf(x), domain, **kw).passed
    assert not mv.check_sampler(wide, pdf, domain, **kw).passed


@pytest.mark.parametrize("domain", ["sphere", "hemisphere"])
def test_a_pdf_singular_at_the_pole_is_not_read_at_the_pole(domain):
    """Uniform in θ, p = 1 / (span · 2π sin θ): integrable, infinite only at the pole. Within
    2^-54 of the pole the judge's own map from parameters to points rounded z to 1, read
    the pdf there and failed the correct sampler, "pdf returned 0 negative and 356
    NaN/Inf values" (found by an outside review). Those points now stay a double below
    the pole. The same sampler against the uniform density still fails."""
    span = np.pi if domain == "sphere" else np.pi / 2

    def sample(u):
        z, phi = np.cos(span * u[:, 0]), 2 * np.pi * u[:, 1]
        r = np.sqrt(np.maximum(0.0, 1 - z * z))
        return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)

    def pdf(x):
        with np.errstate(divide="ignore"):
            return 1 / (span * 2 * np.pi * np.sqrt(np.maximum(0.0, 1 - x[:, 2] ** 2)))

    r = mv.check_sampler(sample, pdf, domain, n_samples=200_000, seed=0)
    assert r.passed, r.failures
    area = 4 * np.pi if domain == "sphere" else 2 * np.pi
    assert not mv.check_sampler(sample, lambda x: np.full(len(x), 1 / area), domain,
                                n_samples=200_000, seed=0).passed


@pytest.mark.parametrize("c,w,seed", [(0.5, 1e-7, 0), (0.0, 1e-9, 1), (0.123456, 1e-12, 0)])
def test_a_sliver_of_the_interval_narrower_than_a_cell_is_integrated(c, w, seed):
    """Uniform on [c, c + w]: an edge falls on the pilot's last point and the last
    1.2e-5 of the support lies in a cell 3.9e-3 wide, below the cubature's deepest leaf.
    Its mass was 0 and the correct sampler failed ("2 samples fell in cells where the pdf
    integrates to 0"), every case here (found by an outside review); 2-D cells had the
    pilot-guided re-integration, 1-D ones not. A sampler 10 % wider or a pdf 3 % high
    still fails."""
    def pdf(x):
        return np.where((x[:, 0] >= c) & (x[:, 0] <= c + w), 1.0 / w, 0.0)

    kw = dict(n_samples=200_000, seed=seed)
    r = mv.check_sampler(lambda u: c + w * u, pdf, "interval", **kw)
    assert r.passed, r.failures
    assert abs(r.details["pdf_integral"] - 1) < 1e-4
    assert not mv.check_sampler(lambda u: c + 1.1 * w * u, pdf, "interval", **kw).passed
    assert not mv.check_sampler(lambda u: c + w * u, lambda x: 1.03 * pdf(x), "interval",
                                **kw).passed


@pytest.mark.parametrize("omc,seed", [(1e-4, 1), (1e-4, 3), (1e-8, 0), (1.0822e-5, 1)])
def test_a_narrow_cone_passes_with_an_even_number_of_rows(omc, seed):
    """At 1e6 samples the grid has 64 rows: an edge falls on the pilot's last point and
    the cone's rim lies in a sliver of the next row (1.4e-9 of 0.03), whose 36 counts
    were expected as 7, 128 cells of a fraction of a count each, none of them suspicious
    alone: a correct cone failed on the row marginal (p = 8e-17), 9 seeds in 10 at 1 -
    1e-8, and a sun-sized cone (1 - cos θ = 1.08e-5) on 5 of 5 at 1e7 (found by a probe).
    A row or column whose marginal is suspicious now has its cells re-integrated around
    the pilot points beside them. A 1 % wider or narrower sampler, and a pdf 0.1 % high,
    still fail."""
    sample, pdf = _cone(1 - omc)
    kw = dict(n_samples=1_000_000, seed=seed)
    r = mv.check_sampler(sample, pdf, "sphere", **kw)
    assert r.passed and r.details["resolution"] == [64, 128], (r.p_value, r.failures)
    # within the normalisation test's own tolerance (1e-4); the sliver's 2.8e-5 was out
    assert abs(r.details["pdf_integral"] - 1) < 1e-4
    for wrong in (1.01, 0.99):
        assert not mv.check_sampler(_cone(1 - wrong * omc)[0], pdf, "sphere", **kw).passed
    assert not mv.check_sampler(sample, lambda x: 1.001 * pdf(x), "sphere", **kw).passed


@pytest.mark.parametrize("omc,domain", [(1.0822e-5, "sphere"), (5e-7, "hemisphere")])
def test_a_narrow_cones_rim_row_is_integrated_at_a_few_samples(omc, domain):
    """At 3e4 samples the rim of a sun-sized cone (1 - cos θ = 1.08e-5 on the sphere; a
    cone of 1e-3 rad on the hemisphere) lies a hair beyond the pilot's last point, in a
    row of 22 to 44 cells holding 1e-4 to 3e-4 of the mass, a fraction of a count each:
    the cells with counts were re-integrated, the others of the row kept no mass, and the
    correct sampler failed "pdf integrates to 0.9997" on 7 of these 10 seeds (an outside
    review). The massless cells of such a row are now integrated around the pilot points.
    α = 0.01 per check: more than 2 failures in 10 has probability 1.1e-4. A sampler
    10 % wider than its pdf and a pdf 3 % high still fail."""
    c = 1 - omc
    sample, pdf = _cone(c)
    kw = dict(n_samples=30_000)
    results = [mv.check_sampler(sample, pdf, domain, seed=s, **kw) for s in range(10)]
    assert not [r.failures for r in results if any("integrates" in f for f in r.failures)]
    assert sum(not r.passed for r in results) <= 2, [r.p_value for r in results]
    assert not mv.check_sampler(_cone(1 - 1.1 * omc)[0], pdf, domain, seed=0, **kw).passed
    assert not mv.check_sampler(sample, lambda x: 1.03 * pdf(x), domain, seed=0, **kw).passed


def _tilted_cone(theta_max, tilt, theta_drawn=None):
    """A uniform cone of half-angle ``theta_max`` about an axis ``tilt`` radians from the
    pole, sampled in its own frame and rotated (its sampler's cone ``theta_drawn`` wide)."""
    axis = np.array([np.sin(tilt), 0.0, np.cos(tilt)])
    t = np.array([np.cos(tilt), 0.0, -np.sin(tilt)])
    b = np.cross(axis, t)
    omc, omc_drawn = 2 * np.sin(theta_max / 2) ** 2, 2 * np.sin((theta_drawn or theta_max) / 2) ** 2

    def sample(u):
        c = 1 - u[:, 0] * omc_drawn
        s, phi = np.sqrt(np.maximum(0.0, 1 - c * c)), 2 * np.pi * u[:, 1]
        return (s * np.cos(phi))[:, None] * t + (s * np.sin(phi))[:, None] * b + c[:, None] * axis

    def pdf(x):
        return np.where(x @ axis >= 1 - omc, 1 / (2 * np.pi * omc), 0.0)

    return sample, pdf


@pytest.mark.parametrize("theta,tilt", [(0.0023562, 60), (1e-3, 30)])
def test_a_tilted_narrow_cones_rim_is_integrated_to_its_budget(theta, tilt):
    """A cone off the axes has a rim that crosses cells as a curve: in a cell it cuts, the
    3-point rule on the cell and on its four children could err alike, |fine - coarse|
    then 20-40 times below the true error (a cell of the sun 60° from the pole, 0.0039 of
    the mass, integrated as 0.0037 with an error estimate of 9.5e-6), and a correct cone
    failed 'pdf integrates to 0.999679, not 1' on 6 of 30 seeds of 1e5 samples, the sun
    (half-angle 0.135°) 60° from the pole and a 1e-3 rad cone 30° from it, on the
    hemisphere (an outside review). Such a leaf is now accepted only where its parent met
    its budget too. α = 0.01 per check: more than 2 failures in 20 has probability 1e-3. A
    sampler's cone 2 % wider (in solid angle) than its pdf's and a pdf 3 % high still
    fail."""
    theta_max, tilt = theta, np.radians(tilt)
    sample, pdf = _tilted_cone(theta_max, tilt)
    kw = dict(n_samples=100_000)
    results = [mv.check_sampler(sample, pdf, "hemisphere", seed=s, **kw) for s in range(20)]
    assert not [r.failures for r in results if any("integrates" in f for f in r.failures)]
    assert sum(not r.passed for r in results) <= 2, [r.p_value for r in results]
    wide, _ = _tilted_cone(theta_max, tilt, theta_max * np.sqrt(1.02))
    assert not mv.check_sampler(wide, pdf, "hemisphere", seed=0, **kw).passed
    assert not mv.check_sampler(sample, lambda x: 1.03 * pdf(x), "hemisphere", seed=0,
                                **kw).passed


def _sun_frame(theta, tilt, theta_drawn=None):
    """A sun's axis ``tilt`` radians from the pole at φ = 0, two unit vectors across it,
    and 1 - cos of its half-angle ``theta`` and of the half-angle it is drawn with."""
    axis = np.array([np.sin(tilt), 0.0, np.cos(tilt)])
    t = np.array([np.cos(tilt), 0.0, -np.sin(tilt)])
    return (axis, t, np.cross(axis, t), 2 * np.sin(theta / 2) ** 2,
            2 * np.sin((theta_drawn or theta) / 2) ** 2)


def _sun_on_sky(theta, tilt, ratio, theta_drawn=None):
    """A uniform sky on the sphere and a sun of half-angle ``theta`` whose density is
    ``ratio`` times the sky's, ``tilt`` radians from the pole at φ = 0 (on the seam),
    sampled exactly: the sun with its probability (drawn ``theta_drawn`` wide), else the
    sky."""
    axis, t, b, omc, omc_drawn = _sun_frame(theta, tilt, theta_drawn)
    total = 4 * np.pi + (ratio - 1) * 2 * np.pi * omc
    p_sun = (ratio - 1) * 2 * np.pi * omc / total

    def sample(u):
        z, phi = 1 - 2 * u[:, 0], 2 * np.pi * u[:, 1]
        r = np.sqrt(np.maximum(0.0, 1 - z * z))
        x = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)
        sun = u[:, 2] < p_sun
        c = 1 - u[sun, 0] * omc_drawn
        s = np.sqrt(np.maximum(0.0, 1 - c * c))
        x[sun] = ((s * np.cos(phi[sun]))[:, None] * t + (s * np.sin(phi[sun]))[:, None] * b
                  + c[:, None] * axis)
        return x

    def pdf(x):
        return np.where(x @ axis >= 1 - omc, ratio, 1.0) / total

    return sample, pdf


def test_a_suns_rim_bulging_into_a_leaf_of_sky_is_integrated():
    """A step between two positive densities: a sun 1e4 times the sky, half-angle
    0.00465 rad, 40° from the pole. Where its rim bulges through a leaf's edge between
    the leaf's corners, less deep than the leaf's children's outermost nodes, the leaf
    reads the sky at every node and corner and was accepted with an error of 0, 2e-4 of
    the mass unseen at any depth: a correct sampler failed 'pdf integrates to 0.999794,
    not 1' on 17 of 200 seeds of 1e5 samples (an outside review). A leaf whose nodes all
    read one value, split from a parent that missed its budget, is now split once more.
    α = 0.01 per check: more than 4 failures in 60 has probability 3.5e-4. A sun drawn
    50 % wider (in solid angle) than its pdf's and a pdf 3 % high still fail."""
    sample, pdf = _sun_on_sky(0.00465, np.radians(40), 1e4)
    kw = dict(n_samples=100_000, sample_dim=3)
    results = [mv.check_sampler(sample, pdf, "sphere", seed=s, **kw) for s in range(60)]
    assert not [r.failures for r in results if any("integrates" in f for f in r.failures)]
    assert sum(not r.passed for r in results) <= 4, [r.p_value for r in results]
    wide, _ = _sun_on_sky(0.00465, np.radians(40), 1e4, 0.00465 * np.sqrt(1.5))
    assert not mv.check_sampler(wide, pdf, "sphere", seed=0, **kw).passed
    assert not mv.check_sampler(sample, lambda x: 1.03 * pdf(x), "sphere", seed=0, **kw).passed


def _sun_on_hemisphere_sky(theta, tilt, ratio, theta_drawn=None):
    """``_sun_on_sky`` on the hemisphere, its sky uniform there, the sun or the sky
    chosen by the first uniform (rescaled), as a sky model's sampler does."""
    axis, t, b, omc, omc_drawn = _sun_frame(theta, tilt, theta_drawn)
    total = 2 * np.pi + (ratio - 1) * 2 * np.pi * omc
    p_sun = (ratio - 1) * 2 * np.pi * omc / total

    def sample(u):
        sun = u[:, 0] < p_sun
        v = np.where(sun, u[:, 0] / p_sun, (u[:, 0] - p_sun) / (1 - p_sun))
        phi = 2 * np.pi * u[:, 1]
        z = np.where(sun, 1 - v * omc_drawn, 1 - v)
        r = np.sqrt(np.maximum(0.0, 1 - z * z))
        local = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)
        x = local.copy()
        x[sun] = local[sun, :1] * t + local[sun, 1:2] * b + local[sun, 2:] * axis
        return x

    def pdf(x):
        return np.where(x @ axis >= 1 - omc, ratio, 1.0) / total * (x[:, 2] >= 0)

    return sample, pdf


def test_a_sun_on_the_hemispheres_sky_is_integrated():
    """The sun of the test above on a sky over the hemisphere. Where a leaf's nodes lay
    on both sides of the sun's rim, a step between two positive densities, the 3-point
    rule on the leaf and on its four children could err alike and the leaf was accepted
    on |fine - coarse| alone, which a support's edge (density 0 outside) had not been
    since 7 December: a correct sampler failed 'pdf integrates to 0.999895, not 1' on
    6 of 100 seeds of 1e5 samples (8 and 18 among the first 40; left by a review of
    7 December). A leaf whose nodes differ more than 1.5-fold is now accepted only where
    its parent met its budget too, as at a support's edge. α = 0.01 per check: more
    than 3 failures in 40 has probability 7e-4. A sun drawn 50 % wider (in solid angle)
    than its pdf's and a pdf 3 % high still fail."""
    sample, pdf = _sun_on_hemisphere_sky(np.radians(0.27), np.radians(40), 1e4)
    kw = dict(n_samples=100_000)
    results = [mv.check_sampler(sample, pdf, "hemisphere", seed=s, **kw) for s in range(40)]
    assert not [r.failures for r in results if any("integrates" in f for f in r.failures)]
    assert sum(not r.passed for r in results) <= 3, [r.p_value for r in results]
    wide, _ = _sun_on_hemisphere_sky(np.radians(0.27), np.radians(40), 1e4,
                                     np.radians(0.27) * np.sqrt(1.5))
    assert not mv.check_sampler(wide, pdf, "hemisphere", seed=0, **kw).passed
    assert not mv.check_sampler(sample, lambda x: 1.03 * pdf(x), "hemisphere", seed=0,
                                **kw).passed


def test_a_moderate_step_on_the_hemisphere_is_integrated():
    """A cap of half-angle 0.3 rad, 40° from the pole, 3.9 times the sky over the
    hemisphere: at 1e4 samples a correct sampler failed 'pdf integrates to 1.00074, not
    1 (quadrature error bound 0.00027)' on 14 of 40 seeds, under a rule that asked a
    leaf's parent to meet its budget only where the leaf's nodes differed more than
    4-fold (a read-only review); 1.5-fold now. α = 0.01 per check: more than 3 failures
    in 40 has probability 7e-4. The cap drawn 10 % wider (in solid angle) than its pdf's
    and a pdf 3 % high still fail."""
    sample, pdf = _sun_on_hemisphere_sky(0.3, np.radians(40), 3.9)
    kw = dict(n_samples=10_000)
    results = [mv.check_sampler(sample, pdf, "hemisphere", seed=s, **kw) for s in range(40)]
    assert not [r.failures for r in results if any("integrates" in f for f in r.failures)]
    assert sum(not r.passed for r in results) <= 3, [r.p_value for r in results]
    wide, _ = _sun_on_hemisphere_sky(0.3, np.radians(40), 3.9, 2 * np.arcsin(
        np.sqrt(1.1) * np.sin(0.15)))
    assert not mv.check_sampler(wide, pdf, "hemisphere", seed=0, n_samples=100_000).passed
    assert not mv.check_sampler(sample, lambda x: 1.03 * pdf(x), "hemisphere", seed=0,
                                **kw).passed


def test_a_sun_between_every_node_of_its_cells_is_integrated():
    """A sun 1e3 times the sky, half-angle 0.1°, 5° from the pole on the φ = 0 seam, lies
    between every node and corner of its cell: the cubature read sky throughout and left
    its 7.6e-4 of the mass out with an error bound of 0, and its samples, split between
    the seam's two cells, moved neither cell's χ² enough to have it integrated again: a
    correct sampler failed 'pdf integrates to 0.99924, not 1' on 98 of 100 seeds of 1e5
    samples (an outside review). A cell where a pilot point's pdf lies more than 4-fold
    outside every value the cubature read there, and the cells beside it that read no
    such value either, are now integrated around those points. α = 0.01 per check: more
    than 4 failures in 60 has probability 3.5e-4. A pdf 3 % high still fails."""
    sample, pdf = _sun_on_sky(np.radians(0.1), np.radians(5), 1e3)
    kw = dict(n_samples=100_000, sample_dim=3)
    results = [mv.check_sampler(sample, pdf, "sphere", seed=s, **kw) for s in range(60)]
    assert sum(not r.passed for r in results) <= 4, [r.failures for r in results]
    assert not mv.check_sampler(sample, lambda x: 1.03 * pdf(x), "sphere", seed=0, **kw).passed


def test_a_sun_the_sampler_never_draws_is_named_as_a_possible_cause():
    """A sampler that leaves out the pdf's sun (1e3 times the sky, half-angle 0.1°),
    whose pilot has no point in it and whose cells' nodes all miss it, fails the
    normalisation test: the cubature cannot see mass nobody reaches. The failure said
    only 'pdf integrates to 0.99924, not 1', blaming a pdf that integrates to 1 (an
    outside review's found-not-fixed); it now names the other cause. A pdf off by more
    (1 %) or with a telling factor does not get the hint."""
    sample, pdf = _sun_on_sky(np.radians(0.1), np.radians(5), 1e3)
    sky_only = lambda u: sample(np.column_stack([u[:, :2], np.ones(len(u))]))  # noqa: E731
    r = mv.check_sampler(sky_only, pdf, "sphere", seed=0, n_samples=100_000)
    assert not r.passed
    (f,) = [f for f in r.failures if "integrates to" in f]
    assert "0.99924" in f and "a narrow feature (a small light, a sun) the sampler never" in f
    for scale in (0.98, 0.5):
        r = mv.check_sampler(sky_only, lambda x, k=scale: k * pdf(x), "sphere", seed=0,
                             n_samples=100_000)
        assert not r.passed and not any("narrow feature" in f for f in r.failures)


def test_the_unseen_screen_keeps_every_point_outside_its_cells_range():
    """``_unseen_kernel`` compares each point with the ranges of every cell its bin of a
    uniform table meets, and those outside with their own cell's: it must keep exactly
    the points whose density lies more than 4-fold outside their own cell's range, as
    ``np.searchsorted`` bins them (points on cell edges and on the table's bin
    boundaries, cells 1e-6 wide, 1-D and 2-D, ranges with inf)."""
    from mcverify.checks.sampler import _unseen_kernel
    rng = np.random.default_rng(1)
    for trial in range(60):
        m = 1 + trial % 2
        edges = [np.unique(np.r_[0.0, (0.5 + 1e-6 * rng.random(r - 1)) if trial % 3 == 0
                                 else rng.random(r - 1), 1.0])
                 for r in rng.integers(1, 40, m)]
        shape = tuple(e.size - 1 for e in edges)
        lo = rng.random(shape) * (rng.random(shape) < 0.5)
        hi = np.where(rng.random(shape) < 0.1, np.inf, lo + 3 * rng.random(shape))
        s = rng.random((1500, m))
        for j, ed in enumerate(edges):
            s[:300, j] = rng.choice(ed, 300)
            s[300:600, j] = rng.integers(0, shape[j] + 1, 300) / shape[j]
            s[600:700, j] = np.nextafter(s[300:400, j], 0.0)
        d = 5 * rng.random(1500)
        idx = [np.clip(np.searchsorted(ed, s[:, j], side="right") - 1, 0, ed.size - 2)
               for j, ed in enumerate(edges)]
        flat = np.ravel_multi_index(idx, shape)
        odd = np.flatnonzero((2 * d > 4 * hi.ravel()[flat]) | (2 * d < 0.25 * lo.ravel()[flat]))
        out = np.empty(1500, dtype=np.int64)
        c = _unseen_kernel(s[:, 0], s[:, -1], d, 2.0, edges[0],
                               edges[1] if m > 1 else np.array([0.0, 1.0]),
                               lo.reshape(shape[0], -1), hi.reshape(shape[0], -1), out)
        assert np.array_equal(np.sort(out[:c]), odd), trial


@pytest.mark.parametrize("sample,pdf", [
    (W.sample_cosine_hemisphere, W.cosine_hemisphere_pdf),
    (lambda u: W.sample_beckmann(u, 0.05), lambda x: W.beckmann_pdf(x, 0.05))])
def test_a_smooth_pdfs_pilot_is_not_binned_for_the_unseen_screen(monkeypatch, sample, pdf):
    """The screen for features between the cubature's nodes kept all 1e5 pilot points of
    the cosine lobe at 1e6 samples (a bound from the narrowest cell's range; the edge
    cells read 0 to a little), and binning them with ``np.searchsorted`` cost 9-10 ms a
    repeated check, about 60 % more (a read-only review): it keeps none now. Nor of a
    peaked lobe (Beckmann α = 0.05), whose narrow cells fall many to a bin of the
    screen's table: every point was binned so, 7.8 ms a check (a read-only review)."""
    import mcverify.checks.sampler as S
    kept = []
    screen = S._unseen_kernel
    monkeypatch.setattr(S, "_unseen_kernel", lambda *a: kept.append(screen(*a)) or kept[-1])
    r = mv.check_sampler(sample, pdf, "hemisphere", n_samples=1_000_000, seed=0)
    assert r.passed and kept and max(kept) <= 10, kept


def test_a_cell_the_pilot_guided_integral_read_is_not_integrated_again(monkeypatch):
    """A cone of cos θ_max = 1 - 1e-8 lies between every node of its cells; the pilot
    guided integral finds it. The screen for features between the cubature's nodes then
    read those cells' ranges from before that integral and integrated them once more, to
    the same mass: 2.21M -> 2.87M pdf evaluations at 1e6, 36 ms more a check (a read-only
    review). The guided integral's range is now the cell's: nothing is spent again."""
    import mcverify.checks.sampler as S
    spent = []
    unseen = S._pilot_unseen

    def spy(*a, **k):
        got = unseen(*a, **k)
        spent.append(got[0])
        return got

    monkeypatch.setattr(S, "_pilot_unseen", spy)
    c = 1 - 1e-8
    r = mv.check_sampler(lambda u: W.sample_uniform_cone(u, c),
                         lambda x: W.uniform_cone_pdf(x, c), "sphere", n_samples=1_000_000,
                         seed=0)
    assert r.passed and spent == [0], spent


def test_guided_cuts_end_on_a_subnormal_cell_and_a_wrong_sampler_there_fails():
    """A cell 1e-315 wide holding one pilot value made the cuts' width 0 and the loop
    never ended (MemoryError; found by review). Through the check: samples where the pdf
    is 0 fail, as before the guided step."""
    from mcverify.checks.sampler import _guided_edges

    cuts = _guided_edges(0.0, 1e-315, np.array([0.0]))
    assert cuts[0] == 0.0 and cuts[-1] == 1e-315 and np.all(np.diff(cuts) > 0)

    def sample(u):
        x0 = np.where(u[:, 0] < 0.3, 0.0, np.where(u[:, 0] < 0.6, 1e-315, u[:, 0]))
        return np.stack([x0, u[:, 1]], 1)

    r = mv.check_sampler(sample, lambda x: np.where(x[:, 0] > 1e-300, 1.0, 0.0), "square",
                         n_samples=100_000, seed=0)
    assert not r.passed


def test_guided_reintegration_keeps_to_its_budget(monkeypatch):
    """It charged 9 evaluations a box where the rule spends 49 and never counted what
    refinement spent: 9.7e6 evaluations against a budget of 4e6 (found by review)."""
    import mcverify.checks.sampler as S

    def flipped(u):
        x = W.sample_cosine_hemisphere(u)
        x[: u.shape[0] // 1000, 2] *= -1.0
        return x

    base = mv.check_sampler(flipped, W.cosine_hemisphere_pdf, "sphere", n_samples=200_000,
                            seed=0, pilot=True)
    monkeypatch.setattr(S, "_pilot_guided", lambda *a: (0, a[-1]))
    without = mv.check_sampler(flipped, W.cosine_hemisphere_pdf, "sphere", n_samples=200_000,
                               seed=0, pilot=True)
    assert not base.passed and not without.passed
    extra = base.details["pdf_evaluations"] - without.details["pdf_evaluations"]
    assert 0 < extra <= S._REFINE_BUDGET * 1.5, extra


def test_an_unnormalised_verdict_says_when_the_cubature_hit_its_depth_limit():
    """x^-0.95 on [0, 1], sampled exactly: 7e-4 of its mass lies below the cubature's
    deepest leaf, and the check said the pdf integrates to 0.99928, blaming the pdf
    (found by a probe). Since 8 December the pilot's points there, reading the pdf far
    above anything the cubature read in their cell, have it integrated around them, and
    x^-0.95 passes; x^-0.98 (6e-4 short) still fails (the quadrature cannot decide), but
    says the shortfall may be the quadrature's; a pdf 1 % high without a singularity
    does not."""
    a = 0.98
    with np.errstate(divide="ignore"):
        r = mv.check_sampler(lambda u: u ** (1 / (1 - a)), lambda x: (1 - a) * x[:, 0] ** -a,
                             mv.Interval(0, 1), n_samples=100_000, seed=0)
    assert not r.passed and "stopped at its depth limit" in r.failures[0], r.failures
    r = mv.check_sampler(lambda u: u, lambda x: 1.01 * np.ones(len(x)), mv.Interval(0, 1),
                         n_samples=100_000, seed=0)
    assert not r.passed and "not 1" in r.failures[0]
    assert "depth limit" not in r.failures[0], r.failures


def test_a_2d_shortfall_at_an_edge_singularity_says_so_too():
    """0.2·x^-0.8 on the square, sampled exactly: the leaves along x = 0 go to nested
    1-D integrals, which stop at their depth limit 3.3e-4 short, and the check said
    "pdf integrates to 0.999672 ..., not 1 (quadrature error bound 5.6e-05)" without
    the hint the same shortfall on the interval gives: the nested integrals' stopped
    leaves were not counted (an outside review)."""
    with np.errstate(divide="ignore"):
        r = mv.check_sampler(lambda u: np.stack([u[:, 0] ** 5, u[:, 1]], 1),
                             lambda x: 0.2 * x[:, 0] ** -0.8, "square", n_samples=200_000,
                             seed=0)
    assert not r.passed and "stopped at its depth limit" in r.failures[0], r.failures
    r = mv.check_sampler(lambda u: u, lambda x: 1.01 * np.ones(len(x)), "square",
                         n_samples=200_000, seed=0)
    assert not r.passed and "depth limit" not in r.failures[0], r.failures


def test_a_float32_expected_value_widens_only_its_own_comparison():
    """A float32 expected value stands for any value within half its ulp, no more: it
    had raised the samples' allowance to float32's 64 eps, so float64 estimates 3e-6
    above 0.5 (spread 1e-7) passed against np.float32(0.5) as "constant to rounding",
    and a float64 estimator of noise 1e-4 was called exact against np.float32(1.0) by
    check_convergence."""
    x = 0.5 + 3e-6 + np.random.default_rng(0).normal(0.0, 1e-7, 100_000)
    assert not mv.check_unbiased(x, 0.5).passed
    assert not mv.check_unbiased(x, np.float32(0.5)).passed
    # a correct float64 estimator of tiny noise against the float32 rounding of its value
    y = 0.1 + np.random.default_rng(1).normal(0.0, 1e-12, 100_000)
    assert not mv.check_unbiased(y, float(np.float32(0.1))).passed
    assert mv.check_unbiased(y, np.float32(0.1)).passed

    def est(n, seed):
        return float(np.random.default_rng(seed).normal(1.0, 1e-4, n).mean())

    for expected in (1.0, np.float32(1.0)):
        r = mv.check_convergence(est, expected, n_seeds=16)
        assert r.statistic is not None and r.passed, r.summary()


@pytest.mark.parametrize("pdf,domain,guess", [
    (lambda x: np.full(len(x), 1.0 / np.pi), "hemisphere",
     "a density per projected solid angle (divided by cos θ) where one per solid angle is "
     "meant, or the hemisphere's 1/(2π) where the sphere's 1/(4π) is?"),
    # the check integrates per solid angle: 1/2 is the sphere's constant on the hemisphere
    # (a read-only review: it was called a density per solid angle, which is never wrong)
    (lambda x: np.full(len(x), 0.25 / np.pi), "hemisphere",
     "the sphere's 1/(4π) where the hemisphere's 1/(2π) is meant, or a lobe's weight of 1/2 "
     "applied twice?"),
    (lambda x: np.full(len(x), 1.0), "sphere", "a factor 4π too many (1/(4π) left out)?"),
    (lambda x: x[:, 2], "hemisphere", "a factor π too many (1/π left out)?"),
    # a density per dθ dφ given per solid angle (an outside review)
    (lambda x: np.full(len(x), 0.5 / np.pi ** 2), "sphere",
     "a density per dθ dφ (uniform in θ and φ) where one per solid angle is meant: divide "
     "it by sin θ?"),
    (lambda x: np.sqrt(np.maximum(1 - x[:, 2] ** 2, 0)) / (4 * np.pi), "sphere",
     "a density per dθ dφ (a uniform one's, sin θ / (4π) or sin θ / (2π)) where one per "
     "solid angle is meant: divide it by sin θ?"),
    (lambda x: x[:, 2] * np.sqrt(np.maximum(1 - x[:, 2] ** 2, 0)) / np.pi, "hemisphere",
     "a density per dθ dφ (the cosine lobe's, cos θ sin θ / π) where one per solid angle "
     "is meant: divide it by sin θ?"),
])
def test_a_pdf_integrating_to_a_telling_factor_gets_a_guess(pdf, domain, guess):
    """An outside review: a cosine sampler's pdf given per projected solid angle (1/π)
    integrates to 2 over the hemisphere, and the failure said 'integrates to 2, not 1' and
    no more; factors that name a classic mistake (2 or 1/2 on the sphere, π, 2π, 4π and
    their inverses anywhere) now add the guess. Any other integral gets none."""
    sample = W.sample_uniform_sphere if domain == "sphere" else W.sample_cosine_hemisphere
    r = mv.check_sampler(sample, pdf, domain, n_samples=20_000, seed=1, sample_dim=2)
    note = next(m for m in r.failures if "integrates to" in m)
    assert not r.passed and note.endswith("; " + guess), note
    r = mv.check_sampler(sample, lambda x: 1.3 * pdf(x), domain, n_samples=20_000, seed=1,
                         sample_dim=2)
    assert not next(m for m in r.failures if "integrates to" in m).endswith("?")


@pytest.mark.parametrize("scale, guess", [
    (470.0, "a density not divided by the interval's width, b - a = 470?"),
    (1.0 / 470.0, "a density divided by the interval's width, b - a = 470, twice?"),
    (1000.0, "a density per a unit 1000 times smaller than x's (per μm where x is in nm, "
             "per nm where it is in μm)?"),
    (1e-3, "a density per a unit 1000 times larger than x's (per nm where x is in μm, per "
           "metre where it is in mm)?"),
])
def test_an_interval_pdf_off_by_its_width_or_a_unit_gets_a_guess(scale, guess):
    """A wavelength sampler on Interval(360, 830) whose pdf is given per μm (1000 times
    the density per nm) failed as 'integrates to 1000, not 1', and one not divided by the
    width as 'integrates to 470' and no more (outside reviews); now with the guess. A
    factor that names nothing (1.3) gets none; nor does the width on an interval of width
    about 1."""
    sample = lambda u: 360.0 + 470.0 * u[:, 0]                   # noqa: E731
    pdf = lambda x: np.full(len(x), 1.0 / 470.0)                # noqa: E731
    for factor, said in ((scale, guess), (1.3, None)):
        r = mv.check_sampler(sample, lambda x, f=factor: f * pdf(x), mv.Interval(360, 830),
                             n_samples=20_000, seed=1)
        note = next(m for m in r.failures if "integrates to" in m)
        assert not r.passed and (note.endswith("; " + said) if said else
                                 not note.endswith("?")), note
    r = mv.check_sampler(lambda u: u[:, 0] * 1.001, lambda x: np.ones(len(x)),
                         mv.Interval(0, 1.001), n_samples=20_000, seed=1)
    note = next(m for m in r.failures if "integrates to" in m)
    assert "width" not in note and not note.endswith("?"), note


def test_a_bsdf_pdf_divided_by_cos_gets_the_guess_with_rejection():
    """A BSDF is checked with rejection=True (its draws below the horizon are rejected),
    where a pdf integrating above 1 failed as 'above 1, so it is no acceptance
    probability' and no more: a user's Mitsuba BSDF whose pdf was divided by cos θ
    (1/π on the hemisphere, 2 over the sphere) got no guess (an outside review)."""
    def sample(u):
        x = W.sample_cosine_hemisphere(u)
        x[u[:, 0] > 0.9] = np.nan                       # rejected draws
        return x

    per_projected = lambda x: np.where(x[:, 2] > 0.0, 1.0 / np.pi, 0.0)  # noqa: E731
    r = mv.check_sampler(sample, per_projected, "sphere", n_samples=20_000, seed=1,
                         rejection=True)
    note = next(m for m in r.failures if "integrates to" in m)
    assert not r.passed and "no acceptance probability" in note, note
    assert note.endswith("; a density per projected solid angle (divided by cos θ) where "
                         "one per solid angle is meant, or the hemisphere's 1/(2π) where "
                         "the sphere's 1/(4π) is?"), note
