"""``check_pdf_consistency``: the pdf and weight a sampler returns with each draw, held
to ``pdf(x)`` and ``f(x) / pdf(x)``. Not statistical (no significance level): every row
is compared within a relative tolerance; seeds are fixed."""

import numpy as np
import pytest

import mcverify as mv
from estimators import warps
from estimators.warps import WARPS
from test_tracer_checks import _MESH_LIGHT, STACKED_QUADS


def _cosine(u):
    r, phi = np.sqrt(u[:, 0]), 2.0 * np.pi * u[:, 1]
    z = np.sqrt(1.0 - u[:, 0])
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _cos_pdf(x):
    return x[:, 2] / np.pi


def _good(u):
    x = _cosine(u)
    return x, _cos_pdf(x)


ALBEDO = np.array([0.8, 0.5, 0.2])


def _f(x):                                  # a diffuse BSDF's f · cos
    return ALBEDO[None, :] / np.pi * x[:, 2:3]


def _weighted(u):
    x, p = _good(u)
    return x, p, np.broadcast_to(ALBEDO, (len(x), 3))


@pytest.mark.parametrize("name", sorted(WARPS))
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_every_warps_with_pdf_agrees_with_its_pdf(name, dtype):
    w = WARPS[name]
    r = mv.check_pdf_consistency(
        lambda u: w.sample.with_pdf(np.asarray(u, dtype=dtype), *w.defaults),
        lambda x: w.pdf(x, *w.defaults), sample_dim=w.sample_dim, n_samples=20_000, seed=1)
    assert r.passed, r.failures
    assert r.details["rtol"] == (1e-3 if dtype == np.float32 else 1e-6)
    assert r.details["n_compared"] + r.details["no_sample"] == 20_000


def test_a_returned_density_of_theta_fails_naming_the_ratio():
    def theta(u):
        x = _cosine(u)
        return x, 2.0 * x[:, 2] * np.sqrt(1.0 - x[:, 2] ** 2)

    r = mv.check_pdf_consistency(theta, _cos_pdf, sample_dim=2, n_samples=5000, seed=2)
    assert not r.passed and r.p_value is None
    assert r.failures[0].startswith("5000 of 5000 returned pdfs differ from pdf(x)")
    assert "ratio" in r.failures[0] and "u=[" in r.failures[0]
    worst = r.details["worst_pdf"]
    assert worst["returned"][0] != pytest.approx(worst["expected"][0], rel=0.1)


def test_a_weight_off_by_pi_in_every_channel_names_each_channel_ratio():
    """A BSDF's returned weight f·cos/pdf off by π in each of its three channels: the
    failure gives the ratio of each channel (until 7 December a multi-channel value had
    none), 1 where a channel is 0 on both sides."""
    albedo = np.array([0.5, 0.25, 0.0])

    def sample(u):
        x, p = _good(u)
        return x, p, np.tile(albedo * np.pi, (len(x), 1))

    def f(x):
        return np.tile(albedo, (len(x), 1)) * x[:, 2:3] / np.pi

    r = mv.check_pdf_consistency(sample, _cos_pdf, sample_dim=2, f=f, n_samples=2000,
                                 seed=3)
    assert not r.passed
    msg = next(m for m in r.failures if "weights" in m)
    assert "(ratios [3.14159, 3.14159, 1])" in msg, msg


def test_a_delta_lobes_huge_stand_in_pdf_is_named_with_what_to_do():
    """A plastic's mirror draw returned as the normal with a pdf of 1e30 (as some
    renderers do) failed at ratio 4.5e30 without saying what to do (an outside review);
    the failure now points to NaN rows and rejection=True. A narrow but real lobe's
    difference gets no such hint."""
    def sample(u):
        x, p = _good(u[:, 1:])
        mirror = u[:, 0] < 0.3
        x[mirror], p[mirror] = [0.0, 0.0, 1.0], 1e30
        return x, np.where(mirror, p, 0.7 * p)

    r = mv.check_pdf_consistency(sample, lambda x: 0.7 * _cos_pdf(x), sample_dim=3,
                                 n_samples=2000, seed=4)
    assert not r.passed
    assert "delta lobe's stand-in: return such draws as rows of NaN and check with " \
           "rejection=True" in r.failures[0], r.failures
    r = mv.check_pdf_consistency(lambda u: (_cosine(u), 2.0 * _cos_pdf(_cosine(u))),
                                 _cos_pdf, sample_dim=2, n_samples=2000, seed=4)
    assert not r.passed and "stand-in" not in r.failures[0], r.failures


def test_a_jacobian_missed_near_the_horizon_only_fails_with_its_count():
    def grazing(u):
        x, p = _good(u)
        return x, np.where(x[:, 2] < 0.1, 2.0 * p, p)

    r = mv.check_pdf_consistency(grazing, _cos_pdf, sample_dim=2, n_samples=100_000, seed=3)
    bad = int(r.failures[0].split(" of ")[0])
    assert not r.passed and 700 < bad < 1300        # P(z < 0.1) = 0.01 for cosine draws


def test_weights_are_checked_against_f_over_pdf():
    r = mv.check_pdf_consistency(_weighted, _cos_pdf, f=_f, sample_dim=2, n_samples=5000)
    assert r.passed and r.details["max_weight_rel_error"] < 1e-12, r.failures

    def cos_missed(u):                     # the weight keeps a cosine the pdf cancelled
        x, p, w = _weighted(u)
        return x, p, w * x[:, 2:3]

    r = mv.check_pdf_consistency(cos_missed, _cos_pdf, f=_f, sample_dim=2, n_samples=5000)
    assert not r.passed and "returned weights differ from f(x) / pdf(x)" in r.failures[0]
    assert "worst_weight" in r.details and "worst_pdf" not in r.details


def test_one_channel_weights_and_values():
    def mono(u):
        x, p = _good(u)
        return x, p, np.full(len(x), 0.5)

    ok = mv.check_pdf_consistency(mono, _cos_pdf, f=lambda x: 0.5 * _cos_pdf(x),
                                  sample_dim=2, n_samples=1000)
    bad = mv.check_pdf_consistency(mono, _cos_pdf, f=lambda x: 0.6 * _cos_pdf(x),
                                   sample_dim=2, n_samples=1000)
    assert ok.passed and not bad.passed


def test_a_constant_weight_or_value_is_that_number_for_every_row():
    """One number as a weight or as f's value means that value everywhere, as one number
    from pdf does (it was refused; an outside review)."""
    def half(u):
        x, p = _good(u)
        return x, p, 0.5

    ok = mv.check_pdf_consistency(half, _cos_pdf, f=lambda x: 0.5 * _cos_pdf(x),
                                  sample_dim=2, n_samples=1000)
    assert ok.passed, ok.failures
    bad = mv.check_pdf_consistency(half, _cos_pdf, f=lambda x: 0.25, sample_dim=2,
                                   n_samples=1000)
    assert not bad.passed and "returned weights differ" in bad.failures[0]


def test_weights_or_values_returned_per_channel_are_told_to_transpose():
    """An RGB weight or f(x) given as (3, n), channels first (a Dr.Jit mi.Color3f as
    numpy reads it), was refused as "shape (3, 1000), expected (1000,) or (1000,
    channels)", no word of the transposition that the points' refusal names (an outside
    review)."""
    rgb = np.array([0.5, 0.4, 0.3])

    def rgb_rows(u):
        x, p = _good(u)
        return x, p, np.repeat(rgb[:, None], len(u), axis=1)       # (3, n)

    with pytest.raises(mv.InvalidArgument, match=r"sample's weight: shape \(3, 1000\), "
                       r"expected .*; transposed\? return values\.T"):
        mv.check_pdf_consistency(rgb_rows, _cos_pdf, f=lambda x: 0.0, sample_dim=2,
                                 n_samples=1000)
    with pytest.raises(mv.InvalidArgument, match=r"f: shape \(3, 1000\), "
                       r"expected .*; transposed\? return values\.T"):
        mv.check_pdf_consistency(lambda u: (*_good(u), rgb_rows(u)[2].T), _cos_pdf,
                                 sample_dim=2, f=lambda x: rgb[:, None] * _cos_pdf(x),
                                 n_samples=1000)
    ok = mv.check_pdf_consistency(lambda u: (*_good(u), rgb_rows(u)[2].T), _cos_pdf,
                                  sample_dim=2,
                                  f=lambda x: (rgb[:, None] * _cos_pdf(x)).T,
                                  n_samples=1000)
    assert ok.passed, ok.failures


def test_weights_without_f_are_not_compared_and_say_so():
    r = mv.check_pdf_consistency(_weighted, _cos_pdf, sample_dim=2, n_samples=1000)
    assert r.passed and "max_weight_rel_error" not in r.details
    assert any("pass f" in m for m in r.messages)


def test_the_tolerance_follows_rtol_and_float32():
    def off(u):                                    # 1e-4 relative: rounding for float32
        x, p = _good(u)
        return x, p * (1.0 + 1e-4)

    assert not mv.check_pdf_consistency(off, _cos_pdf, sample_dim=2, n_samples=1000).passed
    assert mv.check_pdf_consistency(off, _cos_pdf, sample_dim=2, n_samples=1000,
                                    rtol=1e-3).passed

    def off32(u):
        x, p = off(u)
        return x.astype(np.float32), p.astype(np.float32)

    r = mv.check_pdf_consistency(off32, _cos_pdf, sample_dim=2, n_samples=1000)
    assert r.passed and r.details["rtol"] == 1e-3
    r = mv.check_pdf_consistency(off32, _cos_pdf, sample_dim=2, n_samples=1000, rtol=1e-5)
    assert not r.passed


def test_a_float32_pdf_of_x_takes_float32_s_tolerance():
    """pdf(x) computed in float32 against float64 draws: float32's rounding (here about
    5e-6 at cos θ = 0.1, where 1 - x² - y² cancels), not a disagreement."""
    def cos_pdf32(x):
        x = x.astype(np.float32)
        z2 = np.maximum(np.float32(0.0), 1 - x[:, 0] ** 2 - x[:, 1] ** 2)
        return np.sqrt(z2) / np.float32(np.pi)

    def near_pole(u):                   # cos θ >= 0.1: float32 rounding below 1e-4
        return _good(np.stack([0.99 * u[:, 0], u[:, 1]], axis=1))

    r = mv.check_pdf_consistency(near_pole, cos_pdf32, sample_dim=2, n_samples=20_000,
                                 seed=5)
    assert r.passed and r.details["rtol"] == 1e-3, r.failures
    assert r.details["max_pdf_rel_error"] > 1e-6    # would have failed float64's rtol

    def doubled(u):
        x, p = near_pole(u)
        return x, np.where(x[:, 2] < 0.6, 2.0 * p, p)

    r = mv.check_pdf_consistency(doubled, cos_pdf32, sample_dim=2, n_samples=20_000, seed=5)
    assert not r.passed


def test_rejected_and_no_sample_rows_are_skipped_and_counted():
    def rejecting(u):
        x, p, w = _weighted(u)
        x, p, w = x.copy(), p.copy(), w.copy()
        x[u[:, 0] < 0.25] = np.nan                 # rejected draws
        p[(u[:, 0] >= 0.25) & (u[:, 1] < 0.1)] = 0.0     # "no sample": pdf 0 ...
        w[(u[:, 0] >= 0.25) & (u[:, 1] < 0.1)] = 0.0     # ... and its weight 0
        w[(u[:, 0] >= 0.25) & (u[:, 1] > 0.9)] = 0.0     # "no sample": weight 0
        p[(u[:, 0] >= 0.25) & (u[:, 1] > 0.9)] = 123.0   # ... whatever pdf it keeps
        return x, p, w

    r = mv.check_pdf_consistency(rejecting, _cos_pdf, f=_f, sample_dim=2, n_samples=20_000,
                                 rejection=True, seed=4)
    d = r.details
    assert r.passed, r.failures
    assert d["rejected"] + d["no_sample"] + d["n_compared"] == 20_000
    assert 4500 < d["rejected"] < 5500 and 2500 < d["no_sample"] < 3500
    r = mv.check_pdf_consistency(lambda u: rejecting(u)[:2], _cos_pdf, sample_dim=2,
                                 n_samples=20_000, rejection=True, seed=4)
    assert not r.passed and r.details["no_sample"] < 2000   # without a weight: pdf 0 only
    assert "123" in r.failures[0]
    r = mv.check_pdf_consistency(rejecting, _cos_pdf, f=_f, sample_dim=2, n_samples=20_000,
                                 seed=4)
    assert not r.passed and "rejection=True" in r.failures[0]


def test_a_sampler_that_never_samples_fails_but_all_rejected_draws_pass():
    """A sampler returning (points, pdf) whose pdf array is never filled (every draw
    returns pdf 0) compared no row and passed ("no row to compare"): a vacuous pass.
    Draws that are all rejected (a delta lobe's NaN rows), or weights all 0 (a black
    BSDF), still pass: there is nothing to agree on."""
    def unfilled(u):
        x = _cosine(u)
        return x, np.zeros(len(u))

    r = mv.check_pdf_consistency(unfilled, _cos_pdf, sample_dim=2, n_samples=1000, seed=1)
    assert not r.passed and r.details["n_compared"] == 0
    assert r.failures[0].startswith("no row to compare: 1000 of 1000 draws returned a pdf "
                                    "of 0"), r.failures

    def black(u):
        x, p, w = _weighted(u)
        return x, p, np.zeros_like(w)

    r = mv.check_pdf_consistency(black, _cos_pdf, f=lambda x: 0.0 * _f(x), sample_dim=2,
                                 n_samples=1000, seed=1)
    assert r.passed and r.details["no_sample"] == 1000, r.failures
    # it said "every draw was rejected", though none was (an outside review)
    assert r.messages[0] == ("no row to compare: 1000 of 1000 draws returned a weight of 0 "
                             "(no-sample answers) and 0 were rejected"), r.messages

    def delta(u):
        return np.full((len(u), 3), np.nan), np.zeros(len(u))

    r = mv.check_pdf_consistency(delta, _cos_pdf, sample_dim=2, n_samples=1000,
                                 rejection=True, seed=1)
    assert r.passed and r.details["rejected"] == 1000, r.failures
    assert r.messages[0].endswith("and 1000 were rejected"), r.messages


def test_a_zero_pdf_returned_with_a_weight_is_compared_not_skipped():
    """A lobe that sets the weight but leaves the pdf 0: the path goes on with the
    weight while MIS reads no density. Only a weight of 0 is a "no sample" answer."""
    def pdf_forgotten(u):
        x, p, w = _weighted(u)
        return x, np.where(x[:, 2] < 0.1, 0.0, p), w

    r = mv.check_pdf_consistency(pdf_forgotten, _cos_pdf, f=_f, sample_dim=2,
                                 n_samples=100_000, seed=6)
    assert not r.passed and r.details["no_sample"] == 0
    bad = int(r.failures[0].split(" of ")[0])
    assert 700 < bad < 1300                         # P(z < 0.1) = 0.01 for cosine draws
    assert r.details["worst_pdf"]["returned"] == [0.0]

    def outside(u):                     # a weight for a point neither pdf gives density
        x, p, w = _weighted(u)
        x = np.where(u[:, :1] < 0.01, -x, x)
        return x, np.where(x[:, 2] < 0.0, 0.0, p), w

    r = mv.check_pdf_consistency(outside, lambda x: np.maximum(_cos_pdf(x), 0.0),
                                 f=lambda x: np.maximum(_f(x), 0.0), sample_dim=2,
                                 n_samples=10_000, seed=6)
    assert not r.passed and "returned weights differ" in r.failures[0]


def test_a_weight_with_no_density_on_either_side_fails_saying_so():
    """A delta lobe returning its weight with a pdf of 0, where pdf(x) is 0 too: the
    weight was compared with f(x) / 0 and failed as "expected [nan] (ratio nan)"."""
    def mirror(u):
        n = len(u)
        return np.tile([0.0, 0.0, 1.0], (n, 1)), np.zeros(n), np.full((n, 3), 0.9)

    r = mv.check_pdf_consistency(mirror, lambda x: np.zeros(len(x)), sample_dim=2,
                                 f=lambda x: np.zeros((len(x), 3)), n_samples=1000, seed=1)
    assert not r.passed and r.details["weight_without_density"] == 1000
    assert len(r.failures) == 1 and "nan" not in r.failures[0], r.failures
    assert r.failures[0].startswith("1000 of 1000 returned weights differ from f(x) / pdf(x) "
                                    "= f(x) / 0: the draw returned a pdf of 0 and pdf(x) "
                                    "is 0 too"), r.failures
    assert "rejection=True" in r.failures[0] and "weight [0.9, 0.9, 0.9]" in r.failures[0]


def test_nan_or_inf_returned_pdfs_fail():
    def nan_pdf(u):
        x, p = _good(u)
        p = p.copy()
        p[::100] = np.nan
        return x, p

    r = mv.check_pdf_consistency(nan_pdf, _cos_pdf, sample_dim=2, n_samples=1000)
    assert not r.passed and r.failures[0].startswith("10 of 1000")
    r = mv.check_pdf_consistency(_good, lambda x: np.full(len(x), np.inf), sample_dim=2,
                                 n_samples=100)
    assert not r.passed


def test_negative_pdfs_fail_even_where_both_sides_agree():
    """A negative density is no density: the same negative value returned and given by
    pdf(x) (a sign lost in both, say) passed, and pdf(x) < 0 turned the weight check off."""
    def signed(x):
        return np.where(x[:, 2] < 0.1, -1.0, 1.0) * _cos_pdf(x)

    def sample(u):
        x, _, w = _weighted(u)
        return x, signed(x), w

    r = mv.check_pdf_consistency(sample, signed, f=_f, sample_dim=2, n_samples=100_000,
                                 seed=8)
    assert not r.passed and 700 < r.details["negative_pdf"] < 1300
    assert "negative pdf" in r.failures[0]
    assert mv.check_pdf_consistency(lambda u: sample(u)[:2], lambda x: -_cos_pdf(x),
                                    sample_dim=2, n_samples=100).failures[0].startswith(
        "100 of 100 draws have a negative pdf")


def test_the_same_seed_gives_the_same_finding():
    def theta(u):
        x = _cosine(u)
        return x, x[:, 2] * 0.9 + 0.01 * u[:, 1]

    a, b, c = (mv.check_pdf_consistency(theta, _cos_pdf, sample_dim=2, n_samples=2000,
                                        seed=s) for s in (7, 7, 8))
    assert a.details["worst_pdf"] == b.details["worst_pdf"] != c.details["worst_pdf"]


@pytest.mark.parametrize("kwargs, match", [
    (dict(sample=lambda u: _cosine(u)), "check_sampler's subject"),
    (dict(sample=lambda u: (_cosine(u),)), r"\(points, pdf\)"),
    (dict(sample=_good, f=_f), "f given, but sample returns no weight"),
    (dict(sample=_weighted, f=lambda x: np.ones((len(x), 2))), "2 channels, the weight has 3"),
    (dict(sample=_good, pdf=lambda x: np.ones((len(x), 2))), "pdf returned shape"),
    (dict(sample=lambda u: (_cosine(u), np.ones(3))), "sample's pdf returned shape"),
    (dict(sample=lambda u: (_cosine(u)[:5], np.ones(5))),
     r"sample's points: shape \(5, 3\), expected \(100, d\)"),
    (dict(sample=lambda u: (_cosine(u).T, _cos_pdf(_cosine(u)))),
     r"shape \(3, 100\), expected \(100, d\).*transposed"),
    (dict(sample=lambda u: (_cosine(u)[:, :, None], _cos_pdf(_cosine(u)))),
     r"shape \(100, 3, 1\), expected \(100, d\)"),
    (dict(sample=lambda u: (np.zeros((len(u), 0)), _cos_pdf(_cosine(u)))),
     r"shape \(100, 0\), expected \(100, d\), a row of d >= 1"),
    (dict(sample=lambda u: (1.0, _cos_pdf(_cosine(u)))), r"shape \(\), expected"),
    (dict(sample=lambda u: (_cosine(u), ["a"] * len(u))), "dtype"),
    (dict(sample=lambda u: (_cosine(u), _cos_pdf(_cosine(u)).astype(np.float16))),
     "sample's pdf: float16"),
    (dict(pdf=lambda x: _cos_pdf(x).astype(np.float16)), "pdf: float16"),
    (dict(sample=lambda u: (*_weighted(u)[:2], _weighted(u)[2].astype(np.float16)), f=_f),
     "sample's weight: float16"),
    (dict(sample=_weighted, f=lambda x: _f(x).astype(np.float16)), "f: float16"),
    (dict(rtol=-1.0), "rtol=-1.0"),
    (dict(rtol=np.nan), "rtol=nan"),
    (dict(n_samples=0), "n_samples=0"),
    (dict(sample_dim=0), "sample_dim=0"),
    (dict(rejection="yes"), "rejection="),
    (dict(pdf="x"), "pdf="),
])
def test_bad_input_is_refused_naming_it(kwargs, match):
    args = dict(sample=_good, pdf=_cos_pdf, sample_dim=2, n_samples=100)
    args.update(kwargs)
    with pytest.raises(mv.InvalidArgument, match=match):
        mv.check_pdf_consistency(args.pop("sample"), args.pop("pdf"), **args)


def test_the_default_suite_checks_every_warp_and_bites_its_canary():
    from mcverify.gate.suites import build_suite, canaries

    names = {c.name.split("(")[0] for c in build_suite("default")
             if c.name.startswith("pdf_consistency:")}
    assert names == {f"pdf_consistency:{w}" for w in WARPS}
    canary = next(c for c in canaries() if c.name == "cosine-returns-pdf-of-theta")
    assert not canary.run(0).passed


@pytest.mark.parametrize("scene,least", [("vocabulary-glass", 30), ("vocabulary-frame", 40)])
def test_the_tracer_s_bsdf_draws_agree_with_its_evaluation(scene, least):
    """Every BSDF instance of a reference scene: bsdf_sample's pdf and weight against
    bsdf_eval (the scene plan's ``pdf_consistency:tracer.bsdf`` checks). vocabulary-frame's
    normal maps and anisotropic lobes too: a normal map's sampled weight without its
    shadowing term passed every test but the render gate's (an outside review)."""
    import os

    from mcverify.gate.reference import REFERENCE_ROOT
    from mcverify.gate.tracer_checks import consistency_checks

    checks = consistency_checks(os.path.join(REFERENCE_ROOT, scene, "scene.xml"), 20_000)
    assert len(checks) >= least
    results = [c.run(3) for c in checks]
    assert all(r.passed for r in results), [r.failures for r in results if not r.passed]
    assert sum(r.details["n_compared"] for r in results) > 20_000 * len(checks) // 2


def test_a_tracer_weight_planted_off_its_evaluation_fails():
    """A planted bug: the tracer's draws with their weight scaled (a lost Fresnel factor,
    say) against its evaluation."""
    import os

    from estimators.pathtracer import prepare_scene
    from estimators.pathtracer.sampling import bsdf_sampler_with_weight
    from mcverify.gate.reference import REFERENCE_ROOT

    scene = prepare_scene(os.path.join(REFERENCE_ROOT, "rough-conductors", "scene.xml"))
    sample, pdf, f = bsdf_sampler_with_weight(scene, 2, (0.6, 0.0, 0.8))
    assert mv.check_pdf_consistency(sample, pdf, f=f, sample_dim=3, rejection=True).passed

    def scaled(u):
        x, p, w = sample(u)
        return x, p, w * 0.98

    r = mv.check_pdf_consistency(scaled, pdf, f=f, sample_dim=3, rejection=True)
    assert not r.passed and "returned weights" in r.failures[0]


@pytest.mark.parametrize("scene", ["veach-mis", "vocabulary-materials", "vocabulary-lights",
                                   "white-furnace"])
def test_the_tracer_s_emitter_draws_agree_with_what_a_bsdf_ray_meets(scene):
    """Sphere, disk, mesh, one-sided (seen from behind: every draw rejected), envmap and
    constant lights: sample_emitter's pdf and radiance against the density and radiance
    where a ray along the drawn direction meets the light."""
    import os

    from mcverify.gate.reference import REFERENCE_ROOT
    from mcverify.gate.tracer_checks import consistency_checks

    checks = [c for c in consistency_checks(os.path.join(REFERENCE_ROOT, scene, "scene.xml"),
                                            20_000) if ".emitter:" in c.name]
    assert checks
    results = [c.run(5) for c in checks]
    assert all(r.passed for r in results), [r.failures for r in results if not r.passed]
    assert any(r.details["n_compared"] > 5_000 for r in results)


def test_an_environment_maps_drawn_radiance_is_its_radiance_along_the_draw():
    """The emitter checks compare an environment map's density alone: its radiance is
    looked up again from the direction's arc tangents, ~1e-10 off in (u, v), so beside a
    sharp texel edge the two look-ups differ by up to ~4e-5. A light sample returning the
    radiance of the texel mirrored in u (``1 - u``) passed every test but the
    vocabulary-lights render gate (an outside review). Here the radiance each draw
    returns is held to the map's own along its direction, within 1e-3."""
    import os

    from estimators.pathtracer import prepare_scene
    from estimators.pathtracer.layout import ENVMAP, LIGHT_KIND
    from estimators.pathtracer.sampling import _emitter_rows
    from mcverify.gate.reference import REFERENCE_ROOT

    scene = prepare_scene(os.path.join(REFERENCE_ROOT, "vocabulary-lights", "scene.xml"))
    k = int(np.flatnonzero(scene.arrays.light_i[:, LIGHT_KIND] == ENVMAP)[0])
    draw, evaluate = _emitter_rows(scene, k, (0.2, 0.1, 0.0))
    out = draw(np.random.default_rng(4).random((20_000, 3)))
    drawn = ~np.isnan(out[:, 0]) & (out[:, 7] > 0)
    assert drawn.sum() > 19_000
    back = evaluate(out[drawn, :3])[:, 3:6]
    assert np.ptp(back) > 0.1 * np.max(back)         # a map, not a constant
    np.testing.assert_allclose(out[drawn, 4:7], back, rtol=1e-3)


def test_an_emitter_pdf_taken_from_another_point_fails():
    """A planted bug: a light sampled from one point, its pdf and radiance read from
    another (an MIS weight evaluated at the wrong vertex)."""
    import os

    from estimators.pathtracer import prepare_scene
    from estimators.pathtracer.sampling import emitter_sampler_with_weight
    from mcverify.gate.reference import REFERENCE_ROOT

    scene = prepare_scene(os.path.join(REFERENCE_ROOT, "rough-conductors", "scene.xml"))
    sample, pdf, f = emitter_sampler_with_weight(scene, 0, (0.0, 1.0, 0.0))
    assert mv.check_pdf_consistency(sample, pdf, f=f, sample_dim=3, rejection=True).passed
    _, wrong_pdf, wrong_f = emitter_sampler_with_weight(scene, 0, (0.0, 0.9, 0.0))
    r = mv.check_pdf_consistency(sample, wrong_pdf, f=wrong_f, sample_dim=3, rejection=True)
    assert not r.passed and "returned pdfs differ" in r.failures[0]


def test_a_light_hiding_part_of_itself_compares_only_the_visible_draws(tmp_path):
    """Two stacked quads of one OBJ light, both facing down: from below, draws on the
    upper quad behind the lower one meet the lower one first along their direction, so
    the two strategies see different points there: those draws are rejected, the rest
    compared (a pdf summed over both quads would differ from the drawn point's)."""
    (tmp_path / "lamp.obj").write_text(STACKED_QUADS)
    (tmp_path / "lamp.xml").write_text(_MESH_LIGHT.format(extra=""))
    from estimators.pathtracer import prepare_scene
    from estimators.pathtracer.sampling import emitter_sampler_with_weight

    scene = prepare_scene(str(tmp_path / "lamp.xml"))
    sample, pdf, f = emitter_sampler_with_weight(scene, 0, (0.0, 0.0, 0.0))
    r = mv.check_pdf_consistency(sample, pdf, f=f, sample_dim=3, rejection=True,
                                 n_samples=20_000)
    assert r.passed, r.failures
    assert 1_000 < r.details["rejected"] < 19_000 and r.details["n_compared"] > 1_000


def test_an_environment_map_is_compared_by_its_density_alone(tmp_path):
    """A noisy 512 × 256 map: the radiance looked up at the direction's (u, v), which
    the arc tangents give back within ~1e-10 of the drawn (u, v), differs from the
    drawn one by rounding times the map's gradient (3.7e-5 relative on lognormal(0, 2.5)
    noise at 2048 × 1024), so only the density, piecewise constant, is compared."""
    from estimators.pathtracer import prepare_scene
    from estimators.pathtracer.sampling import emitter_sampler_with_weight
    from mcverify.gate import mitsuba as mvm

    img = np.random.default_rng(0).lognormal(0, 2.5, (256, 512, 3)).astype(np.float32)
    mvm.write_exr(str(tmp_path / "noise.exr"), img)
    lamp = _MESH_LIGHT.index('  <shape type="obj">')
    (tmp_path / "env.xml").write_text(
        _MESH_LIGHT[:lamp] + '  <emitter type="envmap"><string name="filename" '
        'value="noise.exr"/></emitter>\n</scene>')
    scene = prepare_scene(str(tmp_path / "env.xml"))
    sample, pdf, f = emitter_sampler_with_weight(scene, 0, (0.0, 0.0, 0.0))
    assert f is None and len(sample(np.full((4, 3), 0.5))) == 2
    r = mv.check_pdf_consistency(sample, pdf, sample_dim=3, n_samples=20_000)
    assert r.passed and r.details["max_pdf_rel_error"] == 0.0, r.failures
    wrong = mv.check_pdf_consistency(sample, lambda d: pdf(d[:, [0, 2, 1]]), sample_dim=3,
                                     n_samples=20_000)
    assert not wrong.passed         # the density of another direction: found


def test_an_environment_map_bright_at_its_pole_agrees_with_its_density(tmp_path):
    """An outside review: an 8 × 16 map lit in its top row (and faintly in a middle
    one), turned by its to_world.
    Draws near the pole carried a pdf whose sin θ was sqrt(1 - y²), which cancels there
    (a relative error ~1e-16 / θ²), and the density of the same direction took it from
    the direction turned back: 3 of 1e5 draws differed by more than 1e-6 (p = 0, check
    --scene failing on a correct map). Both now take sin θ from the other two
    coordinates, as Mitsuba's pdf_direction does."""
    from estimators.pathtracer import prepare_scene
    from estimators.pathtracer.sampling import emitter_sampler_with_weight
    from mcverify.gate import mitsuba as mvm

    img = np.zeros((8, 16, 3), np.float32)
    img[0] = 5.0
    img[4] = 0.01       # lit in its top row only, Mitsuba's table would have no mass
    mvm.write_exr(str(tmp_path / "pole.exr"), img)
    lamp = _MESH_LIGHT.index('  <shape type="obj">')
    (tmp_path / "env.xml").write_text(
        _MESH_LIGHT[:lamp] + '  <emitter type="envmap"><string name="filename" '
        'value="pole.exr"/><transform name="to_world"><rotate x="1" angle="30"/>'
        '<rotate y="1" angle="45"/></transform></emitter>\n</scene>')
    scene = prepare_scene(str(tmp_path / "env.xml"))
    sample, pdf, _ = emitter_sampler_with_weight(scene, 0, (0.0, 1.2, 5.0))
    r = mv.check_pdf_consistency(sample, pdf, sample_dim=3, n_samples=200_000, seed=0)
    assert r.passed, r.failures


def test_subnormal_pdfs_are_compared_within_their_rounding():
    """An outside review: two correct computations of a pdf near 1e-318 (subnormal, a few
    significant digits) differ by 5e-6 relative and failed at rtol 1e-6. Differences
    within 16 smallest subnormals are rounding; a factor of 2 among subnormals, and any
    error of normal values, is still found."""
    scale = 1e-318

    def tiny(u):
        x = _cosine(u)
        return x, (x[:, 2] / np.pi) * scale

    r = mv.check_pdf_consistency(tiny, lambda x: x[:, 2] * (scale / np.pi), sample_dim=2,
                                 n_samples=5000)
    assert r.passed, r.failures
    r = mv.check_pdf_consistency(tiny, lambda x: 2 * x[:, 2] * (scale / np.pi),
                                 sample_dim=2, n_samples=5000)
    assert not r.passed


def test_an_infinite_pdf_fails_as_not_finite_not_as_a_difference():
    """A pdf infinite on both sides (x^-1/2 at 0 from u = 0, a returned 1/0) failed as
    "returned pdfs differ from pdf(x)", returned inf, expected inf, ratio nan, with
    numpy's RuntimeWarnings, until 6 December; it is now named for what it is."""
    import warnings

    def pdf(x):
        with np.errstate(divide="ignore"):
            return np.where(x[:, 0] < 0.1, np.inf, 1.0)

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = mv.check_pdf_consistency(lambda u: (u, pdf(u)), pdf, sample_dim=2,
                                     n_samples=1000, seed=3)
    assert not r.passed and len(r.failures) == 1
    assert r.failures[0].startswith(f"{r.details['nonfinite_pdf']} of 1000 draws have a "
                                    "pdf that is not finite")
    assert 50 < r.details["nonfinite_pdf"] < 150 and "worst_pdf" not in r.details


@pytest.mark.parametrize("factor, ok", [(1.8, True), (1 / 1.8, True), (2.2, False),
                                        (1 / 2.2, False)])
def test_the_tolerance_is_relative_to_the_larger_value_either_way(factor, ok):
    """|a - b| <= rtol · max(|a|, |b|), as documented: a returned pdf 1.8 times pdf(x), or
    1/1.8 of it, is within rtol = 0.5 (0.8 / 1.8 = 0.44) either way; 2.2 times is not
    (1.2 / 2.2 = 0.55). Measured against either side alone, one of the first two read
    as 0.8 (a mutation review: no test held the tolerance's denominator)."""
    def sample(u):
        x = _cosine(u)
        return x, factor * _cos_pdf(x)

    r = mv.check_pdf_consistency(sample, _cos_pdf, sample_dim=2, n_samples=200, rtol=0.5)
    assert r.passed == ok, r.failures


def test_rtol_zero_asks_for_equal_values():
    """rtol=0 is allowed and means bit-equal: the same computation on both sides passes,
    one ulp off fails (a comparison of rel >= rtol failed every row at rtol=0)."""
    assert mv.check_pdf_consistency(_good, _cos_pdf, sample_dim=2, n_samples=500,
                                    rtol=0.0).passed
    r = mv.check_pdf_consistency(lambda u: (_good(u)[0], np.nextafter(_good(u)[1], 1.0)),
                                 _cos_pdf, sample_dim=2, n_samples=500, rtol=0.0)
    assert not r.passed and r.failures[0].startswith("500 of 500"), r.failures


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("extra, ok", [(16, True), (17, False)])
def test_a_difference_of_sixteen_subnormals_of_the_type_is_rounding(dtype, extra, ok):
    """"Within 16 of the type's smallest subnormals" is rounding, 16 included, and the
    type is float32's where a pdf is float32 (its smallest subnormal 1.4e-45, not
    float64's 4.9e-324: float32 pdfs 16 of theirs apart, 1.6 % relative, failed under
    float64's floor). Seventeen apart is a difference (a mutation review)."""
    s = np.finfo(dtype).smallest_subnormal

    def sample(u):
        return u, np.full(len(u), dtype(1000) * s, dtype=dtype)

    r = mv.check_pdf_consistency(sample, lambda x: np.full(len(x), dtype(1000 + extra) * s,
                                                           dtype=dtype),
                                 sample_dim=2, n_samples=100)
    assert r.passed == ok, r.failures


def test_a_float32_f_takes_float32_s_tolerance():
    """f(x) computed in float32 (z from 1 - x² - y², which cancels near the horizon) is
    float32's rounding, as a float32 pdf(x) is: rtol 1e-3 (a mutation review: the
    weight's and f's dtypes were not held to it by any test)."""
    def f32(x):
        x = x.astype(np.float32)
        z = np.sqrt(np.maximum(np.float32(0.0), 1 - x[:, 0] ** 2 - x[:, 1] ** 2))
        return ALBEDO.astype(np.float32)[None, :] / np.float32(np.pi) * z[:, None]

    def near_pole(u):                   # cos θ >= 0.1: float32 rounding below 1e-4
        return _weighted(np.stack([0.99 * u[:, 0], u[:, 1]], axis=1))

    r = mv.check_pdf_consistency(near_pole, _cos_pdf, f=f32, sample_dim=2,
                                 n_samples=20_000, seed=5)
    assert r.passed and r.details["rtol"] == 1e-3, r.failures
    assert r.details["max_weight_rel_error"] > 1e-6     # would have failed float64's rtol


def test_the_worst_row_is_reported_with_its_own_u_and_x():
    """The reported row is the worst, not the first out of tolerance, and its u is the
    one that drew its x, rejected draws before it notwithstanding (a mutation review:
    the worst's index into the compared rows, taken as an index into all draws, or the
    first row out of tolerance, passed every test)."""
    def sample(u):
        x = _cosine(u)
        x[u[:, 1] < 0.5] = np.nan                       # rejected draws
        return x, _cos_pdf(x) * (1.0 + u[:, 0])         # worse as u[0] grows

    r = mv.check_pdf_consistency(sample, _cos_pdf, sample_dim=2, n_samples=1000,
                                 rejection=True, seed=9)
    worst = r.details["worst_pdf"]
    x, p = sample(np.array([worst["u"]]))
    assert x[0].tolist() == pytest.approx(worst["x"], rel=1e-12)
    assert p[0] == pytest.approx(worst["returned"][0], rel=1e-12)
    got, want = worst["returned"][0], worst["expected"][0]
    assert abs(got - want) / max(got, want) == r.details["max_pdf_rel_error"]


def test_a_negative_pdf_is_reported_at_the_u_that_drew_it():
    """The first draw with a negative pdf is named with its own u, rejected draws before
    it notwithstanding, and as a negative pdf where pdf(x) is positive (a mutation
    review: both were held by no test)."""
    def sample(u):
        x = _cosine(u)
        x[u[:, 1] < 0.5] = np.nan                       # rejected draws
        return x, np.where(u[:, 0] < 0.05, -1.0, 1.0) * _cos_pdf(x)

    r = mv.check_pdf_consistency(sample, _cos_pdf, sample_dim=2, n_samples=2000,
                                 rejection=True, seed=10)
    n_bad = r.details["negative_pdf"]
    assert 20 < n_bad < 80, r.details
    msg = r.failures[0]
    assert msg.startswith(f"{n_bad} of {r.details['n_compared']} draws have a negative pdf")
    u = [float(v) for v in msg.split("first at u=[")[1].split("]")[0].split(", ")]
    assert u[0] < 0.05 and u[1] >= 0.5, msg


def test_a_weight_off_in_one_channel_only_fails():
    """A weight wrong in its blue channel alone (a colour's channel dropped or swapped)
    fails, with each channel's ratio (a mutation review: only the first channel's error
    was held by any test)."""
    def sample(u):
        x, p, w = _weighted(u)
        w = w.copy()
        w[:, 2] *= 1.5
        return x, p, w

    r = mv.check_pdf_consistency(sample, _cos_pdf, f=_f, sample_dim=2, n_samples=1000)
    assert not r.passed and "(ratios [1, 1, 1.5])" in r.failures[0], r.failures


def test_a_weight_matching_a_wrong_returned_pdf_fails_as_a_weight_too():
    """A weight f / p built on a returned p that is not pdf(x) is no f(x) / pdf(x): both
    the pdf and the weight are reported (a mutation review: a weight held to f over the
    returned pdf passed every test)."""
    def sample(u):
        x = _cosine(u)
        p = 2.0 * _cos_pdf(x)
        return x, p, _f(x) / p[:, None]

    r = mv.check_pdf_consistency(sample, _cos_pdf, f=_f, sample_dim=2, n_samples=500)
    assert not r.passed and len(r.failures) == 2, r.failures
    assert "worst_pdf" in r.details and "worst_weight" in r.details


def test_a_pdf_of_x_of_zero_beside_a_returned_pdf_is_no_weight_without_density():
    """pdf(x) = 0 where the draw returned a positive pdf is a pdf failure, not "a weight
    with no density on either side" (that is for a returned pdf of 0 too; a mutation
    review: no test told the two apart)."""
    def pdf(x):
        return np.where(x[:, 2] < 0.3, 0.0, _cos_pdf(x))

    r = mv.check_pdf_consistency(_weighted, pdf, f=_f, sample_dim=2, n_samples=1000,
                                 seed=2)
    assert not r.passed and "weight_without_density" not in r.details, r.failures
    assert len(r.failures) == 1 and "returned pdfs differ" in r.failures[0], r.failures


def test_a_sampler_changing_u_in_place_is_reported_at_the_u_it_was_given():
    """A sampler writing its warp into u (``np.sqrt(u, out=u)``, numba code reusing the
    buffer) was reported at the u as it had changed it: the worst row's u, given to the
    sampler again, drew another point (a mutation review)."""
    def sample(u):                      # density 2x on [0, 1), its pdf wrong above 0.9
        np.sqrt(u, out=u)
        return u, np.where(u[:, 0] > 0.9, 4.0, 2.0) * u[:, 0]

    r = mv.check_pdf_consistency(sample, lambda x: 2.0 * x[:, 0], sample_dim=1,
                                 n_samples=1000, seed=3)
    worst = r.details["worst_pdf"]
    assert not r.passed
    x, _ = sample(np.array([worst["u"]]))
    assert x[0].tolist() == pytest.approx(worst["x"], rel=1e-12), worst
