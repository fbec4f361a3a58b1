"""Mitsuba plugin adapters (``mcverify.gate.mitsuba``): the judge's sampler contract for
Mitsuba's BSDFs, emitters, microfacet distributions and phase functions.

Statistical tests are seeded and each runs at α = 0.01 (check_sampler's default); the
few binomial checks of acceptance use |z| < 4.5 (two-sided p ≈ 7e-6 each).
"""

import contextlib
import math

import numpy as np
import pytest

import mcverify as mv
from mcverify.gate import mitsuba as mvm
from mcverify.gate.mitsuba_suite import direction

pytestmark = pytest.mark.mitsuba

N = 200_000


def _check(subject, n=N, seed=1, **kw):
    s, p, d, opts = subject
    return mv.check_sampler(s, p, d, n_samples=n, seed=seed, **dict(opts, **kw))


@pytest.mark.parametrize("subject", [
    lambda: mvm.microfacet("ggx", 0.01, wi=direction(80.0)),
    lambda: mvm.microfacet("beckmann", (0.05, 0.5), sample_visible=False),
    lambda: mvm.phase({"type": "hg", "g": 0.7}, wi=direction(30.0, 40.0)),
    lambda: mvm.emitter({"type": "rectangle", "emitter": {"type": "area"}}, ref=(0.3, 0.2, 2.0)),
    lambda: mvm.emitter('<shape version="3.0.0" type="sphere"><point name="center" x="0" '
                        'y="0" z="3"/><emitter type="area"/></shape>'),
    lambda: mvm.bsdf({"type": "diffuse"}, wi=direction(60.0)),
], ids=["ggx-visible-0.01-80deg", "beckmann-aniso", "hg", "rectangle-light",
        "sphere-light-xml", "diffuse"])
def test_subjects_that_never_reject_pass_the_judge(subject):
    r = _check(subject())
    assert r.passed, (r.name, r.p_value, r.failures)
    assert r.name.startswith("mitsuba.")


def test_a_loaded_plugin_and_its_dict_give_the_same_draws():
    mi = mvm.mi()
    plugin = {"type": "roughconductor", "alpha": 0.3}
    u = np.random.default_rng(3).random((1000, 3))
    a = mvm.bsdf(plugin, wi=direction(40.0))
    b = mvm.bsdf(mi.load_dict(plugin), wi=direction(40.0))
    np.testing.assert_array_equal(a.sample(u), b.sample(u))
    x = a.sample(u)
    ok = ~np.isnan(x).any(axis=1)
    np.testing.assert_array_equal(a.pdf(x[ok]), b.pdf(x[ok]))


def test_lobe_selection_is_part_of_the_sample():
    """Rough plastic picks its lobe with u[:, 0]: the same u[:, 1:] with a different
    first number lands elsewhere."""
    s = mvm.bsdf({"type": "roughplastic", "alpha": 0.1}, wi=direction(20.0)).sample
    u = np.random.default_rng(0).random((2000, 3))
    lo, hi = u.copy(), u.copy()
    lo[:, 0], hi[:, 0] = 0.001, 0.999
    assert np.nanmean(np.abs(s(lo) - s(hi))) > 0.1


def test_rejected_draws_are_nan_rows_and_the_pdf_integrates_to_the_acceptance():
    """Rough conductor without visible normals at 80° loses draws below the horizon:
    they are NaN rows, and the pdf integrates to the accepted fraction (binomial z)."""
    subject = mvm.bsdf({"type": "roughconductor", "alpha": 0.5, "sample_visible": False},
                       wi=direction(80.0))
    x = subject.sample(np.random.default_rng(5).random((N, 3)))
    rejected = np.isnan(x).any(axis=1)
    assert np.isnan(x[rejected]).all() and 0.05 < rejected.mean() < 0.5
    accepted = 1.0 - rejected.mean()
    r = _check(subject)                      # fails (NaN rows), but integrates the pdf
    assert any("NaN" in f for f in r.failures)
    integral = r.details["pdf_integral"]
    z = (accepted - integral) / math.sqrt(integral * (1 - integral) / N)
    assert abs(z) < 4.5, (accepted, integral)


@pytest.mark.parametrize("plugin, theta", [
    ({"type": "roughconductor", "alpha": 0.1, "distribution": "ggx"}, 80.0),
    ({"type": "roughdielectric", "alpha": 0.3}, 150.0),            # from inside
    ({"type": "plastic"}, 30.0),                                   # a delta lobe
], ids=["roughconductor-80deg", "roughdielectric-inside", "plastic-delta"])
def test_rejecting_bsdfs_pass_the_judge_with_rejection(plugin, theta):
    r = _check(mvm.bsdf(plugin, wi=direction(theta)), rejection=True)
    assert r.passed, (r.p_value, r.failures)
    assert 0 < r.details["rejection"]["rejected"] < N


def test_roughplastic_pdf_is_positive_below_the_horizon_where_sample_never_goes():
    """The README's finding on Mitsuba's rough plastic (GGX, α = 0.3, normal incidence):
    its pdf integrates to about 1.075 over the sphere while sample() accepts 99.2 %;
    restricted to the upper hemisphere the pdf integrates to the acceptance."""
    subject = mvm.bsdf({"type": "roughplastic", "alpha": 0.3, "distribution": "ggx"},
                       wi=direction(0.0))
    x = subject.sample(np.random.default_rng(6).random((N, 3)))
    ok = ~np.isnan(x).any(axis=1)
    assert (x[ok, 2] > 0).all()
    accepted = ok.mean()
    whole = _check(subject).details["pdf_integral"]
    upper = mv.check_sampler(subject.sample, lambda v: subject.pdf(v) * (v[:, 2] > 0),
                             "sphere", n_samples=N, seed=1, sample_dim=3
                             ).details["pdf_integral"]
    sigma = math.sqrt(accepted * (1 - accepted) / N)
    assert whole - accepted > 0.05
    assert abs(upper - accepted) < 4.5 * sigma, (upper, accepted)
    judged = _check(subject, rejection=True)
    assert not judged.passed and "above 1" in judged.failures[0]


def test_delta_lobe_draws_are_rejected_rows():
    """Smooth plastic: the specular (delta) lobe's draws are NaN; the continuous
    (diffuse) part's pdf integrates to its selection probability."""
    subject = mvm.bsdf({"type": "plastic"}, wi=direction(30.0))
    x = subject.sample(np.random.default_rng(7).random((N, 3)))
    ok = ~np.isnan(x).any(axis=1)
    integral = _check(subject).details["pdf_integral"]
    assert 0.5 < ok.mean() < 1.0
    assert abs(ok.mean() - integral) < 4.5 * math.sqrt(integral * (1 - integral) / N)


def test_a_component_restricts_sampling_and_pdf():
    """Rough plastic's diffuse component alone never rejects. Its pdf is negative below
    the horizon (the README's Mitsuba finding: the cosine is not clamped); clamped there,
    the component passes."""
    mi = mvm.mi()
    b = mi.load_dict({"type": "roughplastic"})
    assert b.component_count() == 2 and mi.has_flag(b.flags(1), mi.BSDFFlags.DiffuseReflection)
    s, p, d, kw = mvm.bsdf(b, wi=direction(30.0), component=1)
    r = mv.check_sampler(s, p, d, n_samples=N, seed=1, **kw)
    assert not r.passed and "negative" in r.failures[0]
    below = p(np.array([[0.6, 0.0, -0.8]]))
    assert below[0] < 0
    clamped = mv.check_sampler(s, lambda x: np.where(x[:, 2] > 0, p(x), 0.0), d,
                               n_samples=N, seed=1, **kw)
    assert clamped.passed, (clamped.p_value, clamped.failures)


def test_a_python_registered_bsdf_with_a_planted_bug_is_caught():
    mi = mvm.mi()
    import drjit as dr

    class Lambert(mi.BSDF):
        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self.bug = props.get("bug", False)
            self.m_flags = mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide
            self.m_components = [self.m_flags]

        def sample(self, ctx, si, s1, s2, active=True):
            bs = dr.zeros(mi.BSDFSample3f)
            # the bug: the uniform hemisphere warp where the pdf says cosine
            bs.wo = (mi.warp.square_to_uniform_hemisphere(s2) if self.bug
                     else mi.warp.square_to_cosine_hemisphere(s2))
            bs.pdf = self.pdf(ctx, si, bs.wo)
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.DiffuseReflection)
            return bs, dr.select(bs.pdf > 0, mi.Color3f(1.0), 0.0)

        def eval(self, ctx, si, wo, active=True):
            return mi.Color3f(self.pdf(ctx, si, wo))

        def pdf(self, ctx, si, wo, active=True):
            return dr.maximum(mi.Frame3f.cos_theta(wo), 0.0) * dr.inv_pi

        def eval_pdf(self, ctx, si, wo, active=True):
            return self.eval(ctx, si, wo), self.pdf(ctx, si, wo)

        def to_string(self):
            return "TestLambert[]"

    mi.register_bsdf("test_lambert", lambda props: Lambert(props))
    good = _check(mvm.bsdf({"type": "test_lambert"}, wi=direction(10.0)))
    bad = _check(mvm.bsdf({"type": "test_lambert", "bug": True}, wi=direction(10.0)))
    assert good.passed, (good.p_value, good.failures)
    assert not bad.passed and bad.p_value < 1e-10


def test_float32_directions_near_the_pole_keep_their_angle():
    """z recomputed from x, y: a normal 1e-4 rad from the pole is not snapped onto it,
    while a vector of the wrong length passes through for the judge to flag."""
    t = 1e-4
    v32 = np.array([[math.sin(t), 0.0, math.cos(t)], [0.0, 0.0, 1.2]], dtype=np.float32)
    assert v32[0, 2] == 1.0                               # float32 lost the angle in z
    out = mvm._nan_rejected(v32, np.array([True, True]))
    assert out[0, 2] < 1.0 and abs(np.arctan2(out[0, 0], out[0, 2]) - t) < 1e-10
    assert out[1, 2] == np.float32(1.2)


@pytest.mark.parametrize("call, match", [
    (lambda: mvm.bsdf({"type": "diffuse"}, wi=(0, 0, 2)), "wi=.*unit vector"),
    (lambda: mvm.bsdf({"type": "diffuse"}, wi=(0, 1)), "wi=.*3-vector"),
    (lambda: mvm.bsdf({"type": "diffuse"}, wi=(0, np.nan, 1)), "wi=.*finite"),
    (lambda: mvm.bsdf({"type": "no_such_bsdf"}, wi=(0, 0, 1)), "plugin: Mitsuba cannot load"),
    (lambda: mvm.bsdf("diffuse", wi=(0, 0, 1)), "plugin=.*must be Mitsuba XML"),
    (lambda: mvm.bsdf({"type": "constant"}, wi=(0, 0, 1)), "expected a mitsuba.BSDF"),
    (lambda: mvm.bsdf({"type": "roughplastic"}, wi=(0, 0, 1), component=2), "component=2"),
    (lambda: mvm.bsdf({"type": "plastic"}, wi=(0, 0, 1), component=True), "component=True"),
    (lambda: mvm.bsdf({"type": "diffuse"}, wi=(0, 0, 1), uv=(0.5,)), "uv=.*2-vector"),
    (lambda: mvm.bsdf({"type": "diffuse"}, wi=(0, 0, 1), uv=0.5), "uv=.*2-vector"),
    (lambda: mvm.bsdf({"type": "diffuse"}, wi=(0, 0, 1), uv=("a", 0)), "uv=.*2-vector"),
    (lambda: mvm.bsdf({"type": "diffuse"}, wi=(0, 0, 1), uv=(np.nan, 0.5)), "uv=.*finite"),
    (lambda: mvm.emitter({"type": "point"}), "delta emitter"),
    (lambda: mvm.emitter({"type": "rectangle"}), "shape without an emitter"),
    (lambda: mvm.emitter({"type": "constant"}, ref=(0, 0)), "ref=.*3-vector"),
    (lambda: mvm.microfacet("phong", 0.1), "distribution='phong'"),
    (lambda: mvm.microfacet("ggx", 0.0), "alpha=0.0: alpha_u must be a positive"),
    (lambda: mvm.microfacet("ggx", (0.1, -1.0)), "alpha_v must be a positive"),
    (lambda: mvm.microfacet("ggx", 0.1, wi=(0, 0, -1)), "above the horizon"),
    (lambda: mvm.microfacet("ggx", (0.1, 0.2, 0.3)), "alpha=.*one roughness or a pair"),
    (lambda: mvm.microfacet("ggx", [0.1]), "alpha=.*one roughness or a pair"),
    (lambda: mvm.microfacet("ggx", True), "alpha=True: alpha_u must be a positive"),
    (lambda: mvm.microfacet("ggx", "0.1"), "alpha='0.1': alpha_u must be a positive"),
    (lambda: mvm.microfacet("ggx", 0.1, sample_visible="False"),
     "sample_visible='False': must be True or False"),
    (lambda: mvm.phase({"type": "diffuse"}), "expected a mitsuba.PhaseFunction"),
    # Mitsuba loads NaN and infinite parameters; every draw was rejected and the check
    # passed as 'consistent, nothing else to test'
    (lambda: mvm.bsdf({"type": "roughconductor", "alpha": math.nan}, wi=(0, 0, 1)),
     r"plugin\['alpha'\]=nan: not a finite number"),
    (lambda: mvm.bsdf({"type": "twosided", "bsdf": {"type": "roughconductor",
                                                     "alpha": np.float32("inf")}},
                      wi=(0, 0, 1)), r"plugin\['bsdf'\]\['alpha'\]=inf: not a finite"),
    (lambda: mvm.bsdf({"type": "diffuse", "reflectance": {"type": "rgb",
                                                          "value": [0.5, math.nan, 0.5]}},
                      wi=(0, 0, 1)), r"plugin\['reflectance'\]\['value'\]\[1\]=nan"),
    (lambda: mvm.emitter({"type": "sphere", "radius": math.nan,
                          "emitter": {"type": "area"}}, ref=(0, 0, 5)),
     r"plugin\['radius'\]=nan: not a finite"),
    (lambda: mvm.emitter({"type": "envmap", "bitmap": np.full((4, 8, 3), np.nan)}),
     r"plugin\['bitmap'\]=an array with 96 NaN or infinite values"),
    (lambda: mvm.phase({"type": "hg", "g": math.nan}), r"plugin\['g'\]=nan"),
    # Mitsuba took these for a scene, or raised std::bad_cast
    (lambda: mvm.bsdf({"alpha": 0.2}, wi=(0, 0, 1)),
     r"plugin: a dict with no 'type' \(keys \['alpha'\]\); name the plugin"),
    (lambda: mvm.emitter({}), r"plugin: a dict with no 'type' \(keys \[\]\)"),
    (lambda: mvm.phase({"type": 3}), "plugin: a dict with 'type': 3, not a string"),
    # read as if out of range: "this BSDF has 2 components (0...1)"
    (lambda: mvm.bsdf({"type": "plastic"}, wi=(0, 0, 1), component=1.0),
     r"component=1.0: an integer index, or None for all; this BSDF has 2"),
    (lambda: mvm.bsdf_weighted({"type": "plastic"}, wi=(0, 0, 1), component="0"),
     r"component='0': an integer index"),
], ids=["wi-length", "wi-size", "wi-nan", "unknown-plugin", "not-xml", "wrong-class",
        "component", "component-bool", "uv-size", "uv-scalar", "uv-str", "uv-nan",
        "delta-emitter", "no-emitter", "ref-size", "distribution", "alpha-zero",
        "alpha-v", "visible-below", "alpha-3", "alpha-1", "alpha-bool", "alpha-str",
        "visible-str", "phase-class", "alpha-nan", "nested-inf", "rgb-nan", "radius-nan",
        "envmap-nan", "g-nan", "no-type", "empty-dict", "type-int",
        "component-float", "component-str"])
def test_bad_arguments_raise_invalid_argument(call, match):
    with pytest.raises(mv.InvalidArgument, match=match):
        call()


def _other_variant(ours: str) -> str:
    """An RGB variant of this Mitsuba beside ``ours``; the test skips where the build has
    none (the PyPI wheel has both scalar_rgb and llvm_ad_rgb, so it runs here and in CI)."""
    import mitsuba

    other = "scalar_rgb" if ours != "scalar_rgb" else "llvm_ad_rgb"
    if other not in mitsuba.variants():
        pytest.skip(f"needs a second RGB variant beside {ours}; {other} not built")
    return other


def test_a_plugin_of_another_variant_is_refused_naming_the_variants():
    """A BSDF loaded under another variant was refused as "got BSDF, expected a
    mitsuba.BSDF", naming no difference."""
    import mitsuba

    mi = mvm.mi()
    other = _other_variant(mi.variant())
    with mitsuba.variant_context(other):
        plugin = mitsuba.load_dict({"type": "diffuse"})
    for adapter in (mvm.bsdf, mvm.bsdf_weighted):
        # both variants named, as the README says (the plugin's own was not, until 6
        # December)
        with pytest.raises(mv.InvalidArgument, match=f"plugin: a mitsuba.BSDF of another "
                           f"variant \\({other}\\) than the adapters' {mi.variant()}.*"
                           "load it after"):
            adapter(plugin, (0.0, 0.0, 1.0))
    assert mi.variant() != other


def _scalar_subjects():
    """Subjects compared between scalar_rgb and the vectorised variant."""
    return [
        ("bsdf", mvm.bsdf({"type": "roughconductor", "alpha": 0.5, "sample_visible": False},
                          direction(80.0))),
        ("microfacet", mvm.microfacet("ggx", 0.3, wi=direction(40.0))),
        ("phase", mvm.phase({"type": "hg", "g": 0.5})),
        ("area", mvm.emitter({"type": "rectangle", "emitter": {"type": "area"}},
                             ref=(0.2, 0.1, 1.0))),
        ("constant", mvm.emitter({"type": "constant"})),
        ("weighted", mvm.bsdf_weighted({"type": "roughplastic", "alpha": 0.3},
                                       direction(40.0))),
    ]


def _draws(subjects):
    u = np.random.default_rng(0).random((200, 3))
    out = {}
    for key, sub in subjects:
        if isinstance(sub, mvm.WeightedSubject):    # (wo, pdf, weight), then pdf and f
            x, p, w = sub.sample(u)
            ok = ~np.isnan(x).any(axis=1)
            out[key] = [x[ok].tolist(), np.concatenate([p[ok], w[ok].ravel(),
                                                        sub.pdf(x[ok]),
                                                        sub.f(x[ok]).ravel()]).tolist()]
            continue
        x = sub.sample(u[:, :sub.kwargs["sample_dim"]])
        ok = ~np.isnan(x).any(axis=1)
        out[key] = [np.nan_to_num(x, nan=9.0).tolist(), sub.pdf(x[ok]).tolist()]
    return out


def test_the_scalar_variant_gives_the_same_draws_and_densities():
    """Per-sample calls on scalar_rgb (no LLVM) against one vectorised call: the same
    points and pdf values, to float32 rounding.

    The rough conductor's directions carry one float32 error that grows where the sampled
    normal m is near the pole: Mitsuba takes sin θ_m = sqrt(1 - cos² θ_m), so a rounding
    δ ≤ 2 ε (ε = 2^-23) in cos θ_m becomes δ / sin θ_m in sin θ_m, and the reflection
    wo = 2 (wi·m) m - wi passes at most 4× that on (measured on an AVX-512 machine: 3.7e-6
    at sin θ_m = 0.059, with the float64 value between the two variants). Its points get
    that bound on top of 2e-6; a wrong mapping of u moves points by O(1)."""
    import json
    import os
    import subprocess
    import sys

    here = os.path.dirname(os.path.abspath(__file__))
    script = ("import json, sys; sys.path.insert(0, sys.argv[1]); "
              "from mcverify.gate import mitsuba as mvm; "
              "assert mvm.choose_variant().variant == 'scalar_rgb'; "
              "from test_mitsuba_adapters import _draws, _scalar_subjects; "
              "json.dump(_draws(_scalar_subjects()), sys.stdout)")
    r = subprocess.run([sys.executable, "-c", script, here], capture_output=True, text=True,
                       timeout=600, env=dict(os.environ, MCVERIFY_MITSUBA_VARIANT="scalar_rgb",
                                             PYTHONPATH=os.path.dirname(os.path.dirname(here))))
    assert r.returncode == 0, r.stderr
    scalar, vector = json.loads(r.stdout), _draws(_scalar_subjects())
    for key in vector:
        atol = 2e-6
        if key == "bsdf":
            wi, wo = np.asarray(direction(80.0)), np.asarray(vector[key][0])
            m = wi + wo
            sin_m = np.hypot(m[:, 0], m[:, 1]) / np.linalg.norm(m, axis=1)
            atol = atol + 8 * 2.0 ** -23 / sin_m[:, None]
        diff = np.abs(np.asarray(vector[key][0]) - np.asarray(scalar[key][0]))
        assert (diff <= atol).all(), (key, np.argwhere(diff > atol), diff.max())
        np.testing.assert_allclose(vector[key][1], scalar[key][1], rtol=2e-5, err_msg=key)


def test_seeds_above_32_bits_reach_mitsuba_reduced():
    """Mitsuba's render takes 32-bit seeds: ``mcverify report --seed 4294967263`` raised a
    TypeError from its bindings (an outside review; the CLI accepts seeds to 2^63 - 1).
    Seeds go to it mod 2^32 (those below are kept), and the report's derived seeds stay
    within the range our renders take."""
    from mcverify.gate.reference import resolve_scene
    from mcverify.gate.report.renders import _shifted

    path = resolve_scene("white-furnace")[1]
    big = (1 << 40) + 7
    a = mvm.render_pass(path, spp=1, seed=big, params={"res": 4})
    b = mvm.render_pass(path, spp=1, seed=7, params={"res": 4})
    assert np.array_equal(a, b)
    assert mvm.mitsuba_seed(2 ** 32 - 1) == 2 ** 32 - 1 and mvm.mitsuba_seed(2 ** 32) == 0
    assert _shifted(2 ** 63 - 1, 10) == 9 and _shifted(5, 10) == 15


def test_a_numpy_integer_component_is_a_component():
    """component=np.int64(1) was refused as out of range ("this BSDF has 2 components")."""
    s, p, d, kw = mvm.bsdf({"type": "plastic"}, wi=(0, 0, 1), component=np.int64(1))
    x = s(np.random.default_rng(0).random((1000, 3)))
    assert np.all(np.isfinite(x)) and np.all(x[:, 2] > 0)    # the diffuse lobe only


def test_numpy_roughnesses_are_roughnesses():
    """np.float32(0.1) was refused ("alpha_u must be a positive number")."""
    a = mvm.microfacet("ggx", np.float32(0.1))
    b = mvm.microfacet("ggx", np.array([0.1, 0.1]))
    c = mvm.microfacet("ggx", np.array(0.1))
    u = np.random.default_rng(0).random((1000, 2))
    assert np.allclose(a.sample(u), b.sample(u), atol=1e-6)
    assert np.allclose(c.sample(u), b.sample(u), atol=1e-6)


@pytest.mark.parametrize("plugin, theta", [
    ({"type": "roughconductor", "alpha": 0.01}, 80.0),
    ({"type": "roughconductor", "alpha": 0.3, "distribution": "beckmann"}, 45.0),
    ({"type": "roughdielectric", "alpha": 0.3}, 135.0),
    ({"type": "roughplastic", "alpha": 0.3}, 45.0),
    ({"type": "plastic"}, 80.0),
    ({"type": "principled", "roughness": 0.4, "metallic": 0.3}, 45.0),
    ({"type": "blendbsdf", "weight": 0.3, "a": {"type": "diffuse"},
      "b": {"type": "roughconductor", "alpha": 0.1}}, 45.0),
    ({"type": "thindielectric"}, 45.0),
], ids=["ggx-0.01-80deg", "beckmann", "roughdielectric-inside", "roughplastic", "plastic",
        "principled", "blend", "thindielectric"])
def test_mitsuba_bsdfs_return_the_pdf_and_weight_they_evaluate(plugin, theta):
    """``bsdf_weighted``: what Mitsuba's ``BSDF.sample`` returns with each direction
    against its ``pdf`` and ``eval`` at that direction, in float32 (rtol 1e-3; the
    largest error seen is 3.5e-4, rough glass from inside)."""
    s, p, f, kw = mvm.bsdf_weighted(plugin, wi=direction(theta))
    assert kw["rtol"] == 1e-3 and kw["rejection"] and kw["sample_dim"] == 3
    r = mv.check_pdf_consistency(s, p, f=f, n_samples=50_000, seed=2, **kw)
    assert r.passed, r.failures
    assert r.name.startswith("mitsuba.bsdf_weighted:" + plugin["type"])
    d = r.details
    assert d["n_compared"] + d["rejected"] + d["no_sample"] == 50_000
    if plugin["type"] == "thindielectric":          # delta lobes only: every draw rejected
        assert d["rejected"] == 50_000
    else:
        assert d["n_compared"] > 20_000 and d["max_pdf_rel_error"] < 1e-3


def test_bsdf_weighted_keeps_mitsubas_zero_weight_draws_as_no_sample_answers():
    """Mitsuba's rough conductor below the horizon keeps its pdf and returns weight 0
    (``eval`` and ``pdf`` give 0 there): no estimator reads such a pdf, so the check skips
    these rows, counting them."""
    s, p, f, kw = mvm.bsdf_weighted({"type": "roughconductor", "alpha": 0.2},
                                    wi=direction(80.0))
    x, pdf, weight = s(np.random.default_rng(0).random((20_000, 3)))
    zero = np.all(weight == 0, axis=1)
    assert zero.sum() > 100 and np.all(pdf[zero] > 0) and np.all(p(x[zero]) == 0)
    r = mv.check_pdf_consistency(s, p, f=f, n_samples=20_000, seed=0, **kw)
    assert r.passed and r.details["no_sample"] == zero.sum()


def test_bsdf_weighted_refuses_bad_arguments_like_bsdf():
    with pytest.raises(mv.InvalidArgument, match="wi="):
        mvm.bsdf_weighted({"type": "diffuse"}, wi=(0.0, 0.0, 2.0))
    with pytest.raises(mv.InvalidArgument, match="component=3"):
        mvm.bsdf_weighted({"type": "diffuse"}, wi=(0.0, 0.0, 1.0), component=3)
    with pytest.raises(mv.InvalidArgument, match="uv="):
        mvm.bsdf_weighted({"type": "diffuse"}, wi=(0.0, 0.0, 1.0), uv=(0.5,))


@pytest.mark.parametrize("make, dim", [
    (lambda: mvm.bsdf({"type": "diffuse"}, wi=(0, 0, 1))[:3], 3),
    (lambda: mvm.bsdf_weighted({"type": "diffuse"}, wi=(0, 0, 1))[:2], 3),
    (lambda: mvm.emitter({"type": "constant"})[:3], 2),
    (lambda: mvm.microfacet("ggx", 0.3)[:3], 2),
    (lambda: mvm.phase({"type": "hg", "g": 0.3})[:3], 3),
], ids=["bsdf", "bsdf_weighted", "emitter", "microfacet", "phase"])
def test_a_check_with_another_sample_dim_is_refused_naming_it(make, dim):
    """A check run with another sample_dim than the adapter's kwargs raised a bare
    IndexError inside it (too few columns) or silently dropped columns (too many)."""
    subject = make()
    sample, pdf = subject[:2]
    for wrong in (dim - 1, dim + 1):
        with pytest.raises(mv.InvalidArgument,
                           match=rf"sample_dim={wrong}\): this Mitsuba sampler takes {dim} "
                                 rf"uniform numbers a draw.*\(sample_dim={dim}\)"):
            if len(subject) == 3:       # (sample, pdf, domain): a chi-square subject
                mv.check_sampler(sample, pdf, subject[2], n_samples=1000, sample_dim=wrong)
            else:
                mv.check_pdf_consistency(sample, pdf, n_samples=100, sample_dim=wrong)


def test_the_adapters_keep_their_variant_when_user_code_sets_another():
    """Mitsuba's variant is one per process: an ``mi.set_variant`` of the user's own code
    after the adapters chose theirs made their next draw fail with a bare TypeError ("only
    0-dimensional arrays can be converted to Python scalars"). The adapters now set
    their variant again when they are made and when they are called."""
    import mitsuba

    ours = mvm.choose_variant().variant
    other = _other_variant(ours)
    u = np.random.default_rng(0).random((500, 3))
    s, p, d, kw = mvm.bsdf({"type": "roughconductor", "alpha": 0.3}, wi=direction(40.0))
    x0, p0 = s(u), p(np.array([[0.0, 0.6, 0.8]]))
    try:
        mitsuba.set_variant(other)                  # between making and calling
        assert np.array_equal(s(u), x0, equal_nan=True)
        mitsuba.set_variant(other)
        assert np.array_equal(p(np.array([[0.0, 0.6, 0.8]])), p0)
        mitsuba.set_variant(other)                  # before making
        s2, p2, f2, kw2 = mvm.bsdf_weighted({"type": "diffuse"}, wi=direction(40.0))
        mitsuba.set_variant(other)
        assert mv.check_pdf_consistency(s2, p2, f=f2, n_samples=2000, seed=0, **kw2).passed
        mitsuba.set_variant(other)
        assert mvm.mi().variant() == ours
    finally:
        mitsuba.set_variant(ours)


def test_the_names_of_bsdf_checks_tell_components_and_texels_apart():
    """``component`` and a non-default ``uv`` were left out of the name: two components of
    one plastic were two checks of one name in a report (an outside review)."""
    plastic = {"type": "plastic"}
    names = [mvm.bsdf(plastic, wi=(0, 0, 1), component=c)[3]["name"] for c in (None, 0, 1)]
    names += [mvm.bsdf_weighted(plastic, wi=(0, 0, 1), component=c).kwargs["name"]
              for c in (None, 0, 1)]
    names.append(mvm.bsdf(plastic, wi=(0, 0, 1), uv=(0.25, 0.5))[3]["name"])
    assert len(set(names)) == len(names), names
    assert names[0] == "mitsuba.bsdf:plastic@wi=(0,0,1)"     # the defaults' name as before
    assert names[2].endswith("@wi=(0,0,1),component=1")
    assert names[-1].endswith("@wi=(0,0,1),uv=(0.25,0.5)")


def test_a_bump_mapped_bsdf_is_sampled_in_its_perturbed_frame():
    """``bumpmap`` builds its normal from the surface's tangents ``dp_du`` and ``dp_dv``,
    which the adapters left at zero: every draw was NaN with zero weight, so all were
    rejected and the check passed with nothing tested (an outside review). With the
    tangents set, most draws are accepted and they follow the pdf (α = 0.01)."""
    height = np.random.default_rng(5).random((8, 8, 1)).astype(np.float32)
    plugin = {"type": "bumpmap", "scale": 0.5, "bsdf": {"type": "diffuse"},
              "texture": {"type": "bitmap", "bitmap": mvm.mi().Bitmap(height), "raw": True}}
    subject = mvm.bsdf(plugin, wi=direction(30.0), uv=(0.3, 0.6))
    r = _check(subject, rejection=True)
    assert r.passed, (r.p_value, r.failures)
    assert r.details["rejection"]["acceptance_rate"] > 0.5
    s, p, f, kw = mvm.bsdf_weighted(plugin, wi=direction(30.0), uv=(0.3, 0.6))
    wo, pdf, weight = s(np.random.default_rng(2).random((1000, 3)))
    assert np.isfinite(wo).all() and (weight > 0).any()


def test_the_names_of_checks_show_nested_plugins_and_number_lists():
    """Only a plugin's number and string parameters were in its check's name: two-sided
    diffuse and two-sided rough conductor were both 'twosided', and sphere lights at two
    centres both 'sphere' (a user suite refuses two checks of one name)."""
    names = [mvm.bsdf({"type": "twosided", "bsdf": b}, wi=(0, 0, 1))[3]["name"]
             for b in ({"type": "diffuse"}, {"type": "roughconductor", "alpha": 0.2})]
    names += [mvm.emitter({"type": "sphere", "center": c, "emitter": {"type": "area"}},
                          ref=(0, 0, 0))[3]["name"] for c in ([0, 0, 3], (0, 0.5, 3))]
    assert names == ["mitsuba.bsdf:twosided(bsdf=diffuse)@wi=(0,0,1)",
                     "mitsuba.bsdf:twosided(bsdf=roughconductor(alpha=0.2))@wi=(0,0,1)",
                     "mitsuba.emitter:sphere(center=(0,0,3),emitter=area)@ref=(0,0,0)",
                     "mitsuba.emitter:sphere(center=(0,0.5,3),emitter=area)@ref=(0,0,0)"]
    # what has no short form (an inline image) is left out, as before
    env = mvm.emitter({"type": "envmap", "bitmap": np.ones((4, 8, 3)), "scale": 2.0})
    assert env[3]["name"] == "mitsuba.emitter:envmap(scale=2.0)@ref=(0,0,0)"


@contextlib.contextmanager
def _llvm():
    """Mitsuba in its llvm_ad_rgb variant for the block (``_llvm_variant``), the process's
    variant put back after it."""
    import mitsuba

    ours = mitsuba.variant()
    mitsuba.set_variant(_llvm_variant())
    try:
        yield mitsuba
    finally:
        if ours is not None:
            mitsuba.set_variant(ours)


def _llvm_variant() -> str:
    """llvm_ad_rgb, where a Dr.Jit array holds n points; the test skips where Mitsuba
    cannot compute in it here (no LLVM: the gate then runs scalar_rgb, whose Dr.Jit types
    hold one point, so the case cannot arise), as ``_other_variant`` does."""
    if mvm.choose_variant().variant != "llvm_ad_rgb":
        pytest.skip("needs Mitsuba's llvm_ad_rgb variant (LLVM) for Dr.Jit arrays of n points")
    return "llvm_ad_rgb"


def test_a_dr_jit_sampler_returning_vector3f_is_told_how_to_transpose_it():
    """A user's Dr.Jit sampler returns mi.Vector3f, which numpy reads as (3, n): the
    checks' hint, "transposed? return points.T", sent its author to a TypeError ("not a
    matrix or tensor type": Dr.Jit arrays have no .T); it now says np.array(points).T
    (an outside review). The sampler so fixed passes (seeded, α = 0.01)."""
    import re

    with _llvm() as mitsuba:                        # a Dr.Jit array of n points
        def cosine(u):
            return mitsuba.warp.square_to_cosine_hemisphere(
                mitsuba.Point2f(u[:, 0], u[:, 1]))

        def pdf(x):
            return np.maximum(x[:, 2], 0.0) / np.pi

        hint = "; transposed? return np.array(points).T (a Dr.Jit array has no .T)"
        for check in (lambda: mv.check_sampler(cosine, pdf, "hemisphere", n_samples=10_000),
                      lambda: mv.check_inverse(cosine, lambda x: x[:, :2], 2, n_samples=1000),
                      lambda: mv.check_pdf_consistency(lambda u: (cosine(u), 1.0), pdf,
                                                       sample_dim=2, n_samples=1000)):
            with pytest.raises(mv.InvalidArgument, match=re.escape(hint)):
                check()
        r = mv.check_stability(cosine, "hemisphere", max_examples=5)
        assert not r.passed and hint in r.details["problem"]
        u = np.random.default_rng(0).random((2, 5000, 2))
        with pytest.raises(mv.InvalidArgument, match=re.escape(hint.replace("return", "pass"))):
            mv.check_same_distribution(cosine(u[0]), cosine(u[1]), "hemisphere")
        # an RGB weight as Dr.Jit gives it, mi.Color3f: numpy's (3, n)
        rgb = lambda x: mitsuba.Color3f(0.5, 0.4, 0.3) * mitsuba.Float(x[:, 2])  # noqa: E731
        with pytest.raises(mv.InvalidArgument, match=re.escape(
                hint.replace("points", "values"))):
            mv.check_pdf_consistency(lambda u: (np.array(cosine(u)).T, 1.0,
                                                rgb(np.array(cosine(u)).T)),
                                     pdf, f=lambda x: 0.0, sample_dim=2, n_samples=1000)
        r = mv.check_sampler(lambda u: np.array(cosine(u)).T, pdf, "hemisphere",
                             n_samples=10_000)
        assert r.passed, r.failures


def test_a_constant_dr_jit_weight_or_value_is_one_for_every_row():
    """A diffuse BSDF of a literal albedo returns its weight as mi.Color3f(0.5, 0.4, 0.3),
    numpy's (3, 1), or a grey one as an mi.Float of width 1: check_pdf_consistency took a
    width-1 Dr.Jit pdf as one number but refused such a weight or f(x), "shape (3, 1),
    expected (1000,) or (1000, channels)" (a read-only review)."""
    with _llvm() as mitsuba:
        def sample(u):
            return np.array(mitsuba.warp.square_to_cosine_hemisphere(
                mitsuba.Point2f(u[:, 0], u[:, 1]))).T

        def pdf(x):
            return x[:, 2] / np.pi

        albedo = (0.5, 0.4, 0.3)
        for weight, f in ((mitsuba.Color3f(*albedo),
                           lambda x: np.outer(x[:, 2] / np.pi, albedo)),
                          (mitsuba.Float(0.5), lambda x: 0.5 * x[:, 2] / np.pi)):
            def draw(u, weight=weight):
                x = sample(u)
                return x, pdf(x), weight

            r = mv.check_pdf_consistency(draw, pdf, sample_dim=2, f=f, n_samples=1000)
            assert r.passed, r.failures
        # and a wrong constant still fails, channel by channel
        r = mv.check_pdf_consistency(lambda u: (sample(u), pdf(sample(u)),
                                                mitsuba.Color3f(0.5, 0.4, 0.6)),
                                     pdf, sample_dim=2, n_samples=1000,
                                     f=lambda x: np.outer(x[:, 2] / np.pi, albedo))
        assert not r.passed, r.failures


def test_mitsubas_own_constant_warp_pdf_is_one_number_for_every_point():
    """mi.warp.square_to_uniform_sphere_pdf returns a Dr.Jit Float of width 1, the
    constant as Dr.Jit broadcasts it: check_sampler and check_pdf_consistency refused it,
    "pdf returned shape (1,): expected (2000,) or one number for all points", where
    check_stability took it (an outside review). Seeded, α = 0.01."""
    with _llvm() as mitsuba:
        def sample(u):
            return np.array(mitsuba.warp.square_to_uniform_sphere(
                mitsuba.Point2f(u[:, 0], u[:, 1]))).T

        def pdf(x):
            return mitsuba.warp.square_to_uniform_sphere_pdf(
                mitsuba.Vector3f(x[:, 0], x[:, 1], x[:, 2]))

        r = mv.check_sampler(sample, pdf, "sphere", n_samples=20_000)
        assert r.passed, r.failures
        r = mv.check_pdf_consistency(lambda u: (sample(u), pdf(sample(u))), pdf,
                                     sample_dim=2, n_samples=2000)
        assert r.passed, r.failures
        # the planted bug, the hemisphere's constant on the sphere, still fails
        half = lambda x: mitsuba.warp.square_to_uniform_hemisphere_pdf(    # noqa: E731
            mitsuba.Vector3f(x[:, 0], x[:, 1], x[:, 2]))
        r = mv.check_sampler(sample, half, "sphere", n_samples=20_000)
        assert not r.passed and "integrates to 2" in " ".join(r.failures), r.failures


def test_mitsubas_own_warps_pass_the_judge_and_invert():
    """``mitsuba_warps`` (the default suite's Mitsuba checks) against the judge: each
    sampler with its clamped pdf (Mitsuba's cone pdf is its constant outside the cone,
    its cosine pdf negative below the horizon) and its inverse. Nothing in the adapters'
    tests ran them: the cone's clamp dropped, or the cone's pdf given another cut-off
    than its sampler, passed them all (a mutation review). Seeded, α = 0.01."""
    for w in mvm.mitsuba_warps():
        r = mv.check_sampler(w.sample, w.pdf, w.domain, n_samples=N, seed=1,
                             sample_dim=w.sample_dim, name=w.name)
        assert r.passed, (w.name, r.p_value, r.failures)
        inv = mv.check_inverse(w.sample, w.invert, w.sample_dim, n_samples=10_000, seed=1,
                               atol=1e-3)
        assert inv.passed, (w.name, inv.failures)


def test_a_bump_map_tilts_the_normal_along_the_tangent_of_its_gradient():
    """The adapters' tangents are the shading frame's s and t: ``dp_du`` = x, ``dp_dv``
    = y. A height ramp along u tilts bumpmap's normal in the x-z plane. With the two
    swapped, the check still passed (sample and pdf agree) while the normal tilted along
    y (a mutation review). Diffuse's draw at the warp's centre, u = (·, 0.5, 0.5), is the
    perturbed normal itself."""
    ramp = np.tile(np.linspace(0.0, 1.0, 16, dtype=np.float32), (16, 1))[:, :, None]
    plugin = {"type": "bumpmap", "scale": 0.2, "bsdf": {"type": "diffuse"},
              "texture": {"type": "bitmap", "bitmap": mvm.mi().Bitmap(ramp), "raw": True}}
    n = mvm.bsdf(plugin, wi=(0.0, 0.0, 1.0)).sample(np.array([[0.5, 0.5, 0.5]]))[0]
    assert abs(n[1]) < 1e-6 and n[0] < -0.1, n


def test_the_uv_reaches_the_plugins_textures():
    """A rough conductor whose roughness is a two-texel texture (α = 0.05 left, 0.5
    right, given inline as a numpy image) draws at ``uv`` as the conductor of that
    texel's α. Left at Mitsuba's default uv, every texel's check was the left one's (a
    mutation review)."""
    texels = np.array([[[0.05], [0.5]]])        # an inline (H, W, C) image
    alpha = {"type": "bitmap", "bitmap": texels, "raw": True,
             "filter_type": "nearest"}
    u = np.random.default_rng(0).random((2000, 3))
    wi = direction(40.0)
    for uv, a in (((0.25, 0.5), 0.05), ((0.75, 0.5), 0.5)):
        textured = mvm.bsdf({"type": "roughconductor", "alpha": alpha}, wi, uv=uv).sample(u)
        plain = mvm.bsdf({"type": "roughconductor", "alpha": a}, wi).sample(u)
        np.testing.assert_allclose(textured, plain, atol=1e-6, err_msg=str(uv))


def test_the_weights_are_radiance_transports():
    """The adapters' ``BSDFContext`` is Mitsuba's default, ``TransportMode.Radiance``, as
    its path tracer uses: a dielectric's refracted weight carries the 1/η² of radiance
    (η = 1.5 entering: 0.444 at normal incidence for a near-smooth surface; importance
    transport has none, about 1). Either mode passed the consistency checks, which
    compare a mode with itself (a mutation review)."""
    s, p, f, kw = mvm.bsdf_weighted({"type": "roughdielectric", "alpha": 0.01},
                                    wi=(0.0, 0.0, 1.0))
    wo, pdf, weight = s(np.random.default_rng(0).random((2000, 3)))
    refracted = wo[:, 2] < 0
    assert refracted.sum() > 1000
    np.testing.assert_allclose(weight[refracted], 1 / 1.5 ** 2, rtol=0.02)


def test_bsdf_weighteds_eval_keeps_to_the_component():
    """``bsdf_weighted(component=1)``: rough plastic's diffuse lobe alone, in ``sample``,
    ``pdf`` and ``f`` alike; an ``f`` of every component disagreed with the weight
    (nothing ran bsdf_weighted with a component; a mutation review)."""
    s, p, f, kw = mvm.bsdf_weighted({"type": "roughplastic", "alpha": 0.3},
                                    wi=direction(37.0), component=1)
    r = mv.check_pdf_consistency(s, p, f=f, n_samples=20_000, seed=0, **kw)
    assert r.passed and r.details["n_compared"] == 20_000, r.failures


def test_the_phase_functions_wi_points_back_along_the_ray():
    """Mitsuba's ``wi`` points away from the scattering point: forward scattering
    (Henyey-Greenstein, g = 0.9) sends ``wo`` near ``-wi``, E[wo · wi] = -g. With wi
    negated, sample and pdf still agreed and the check passed (a mutation review).
    Seeded: the standard error of the mean at n = 20,000 is below 0.002."""
    wi = np.asarray(direction(30.0, 40.0))
    x = mvm.phase({"type": "hg", "g": 0.9}, wi).sample(
        np.random.default_rng(0).random((20_000, 3)))
    assert abs(np.mean(x @ wi) + 0.9) < 0.01


def test_visible_normals_lean_towards_wi():
    """Visible normals from ``wi`` in the x-z plane lean towards it: E[m_x] > 0, E[m_y]
    = 0 (a wi with its x and y swapped passed the check, sample and pdf agreeing; a
    mutation review). Seeded; the standard errors are below 0.005 at n = 20,000."""
    m = mvm.microfacet("ggx", 0.5, wi=direction(60.0)).sample(
        np.random.default_rng(0).random((20_000, 2)))
    assert m[:, 0].mean() > 0.1 and abs(m[:, 1].mean()) < 0.02


def test_a_uniform_number_that_rounds_to_one_in_float32_stays_below_it():
    """u = 1 - 1e-9 rounds to 1.0f, outside the warps' [0, 1): diffuse's cosine warp
    then returns a horizon direction of pdf 0, a rejected draw. The adapters clamp u
    below float32's 1, so it is a valid direction just above the horizon."""
    x = mvm.bsdf({"type": "diffuse"}, wi=(0.0, 0.0, 1.0)).sample(
        np.array([[0.5, 1 - 1e-9, 1 - 1e-9]]))
    assert np.isfinite(x).all() and x[0, 2] > 0


def test_every_number_of_the_plugin_dict_is_in_the_name():
    """Two rough conductors that differ only in their ``eta`` are two checks, of two
    names (a user suite refuses two checks of one name); a label that left a parameter
    out passed every other test (a mutation review)."""
    names = [mvm.bsdf({"type": "roughconductor", "alpha": 0.2, "eta": eta, "k": 0.0},
                      wi=(0, 0, 1))[3]["name"] for eta in (1.5, 2.0)]
    assert names == [f"mitsuba.bsdf:roughconductor(alpha=0.2,eta={eta},k=0.0)@wi=(0,0,1)"
                     for eta in (1.5, 2.0)]
