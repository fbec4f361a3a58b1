"""Our BSDF and emitter kernels against Mitsuba's, pointwise: the same XML must mean the
same function, or the two renderers estimate different images."""

import math
import os

import numpy as np
import pytest

from estimators.pathtracer import prepare_scene, parse_scene
from estimators.pathtracer import bsdfs as B

# direct calls of the tracer's per-ray functions compile as inside the kernels
pytestmark = [pytest.mark.mitsuba, pytest.mark.usefixtures("kernel_compile_context")]

_SCENE = """<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="40"/>
    <film type="hdrfilm"><integer name="width" value="4"/><integer name="height" value="4"/>
    <rfilter type="box"/></film></sensor>
  <shape type="rectangle">{bsdf}</shape>
</scene>"""

BSDFS = {
    "diffuse": '<bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.5, 0.8"/></bsdf>',
    "twosided-diffuse": '<bsdf type="twosided"><bsdf type="diffuse"/></bsdf>',
    "roughconductor-ggx-Au": '<bsdf type="roughconductor"><string name="material" value="Au"/>'
                             '<float name="alpha" value="0.2"/>'
                             '<string name="distribution" value="ggx"/></bsdf>',
    "roughconductor-beckmann-Cu": '<bsdf type="roughconductor"><string name="material" '
                                  'value="Cu"/><float name="alpha" value="0.35"/></bsdf>',
    "roughconductor-eta-k": '<bsdf type="roughconductor"><rgb name="eta" value="0.2, 0.9, 1.1"/>'
                            '<rgb name="k" value="3, 2.5, 2"/><float name="alpha" value="0.05"/>'
                            '<string name="distribution" value="ggx"/></bsdf>',
    # one Fresnel term for all channels: grey (η, k), and Mitsuba's default material
    # "none", (0, 1), a perfect mirror
    # with a specular_reflectance: no case had one, and a rough conductor's value, or a
    # conductor's sampled weight, without it passed (mutants of an outside review)
    "roughconductor-grey": '<bsdf type="roughconductor"><float name="eta" value="0.4"/>'
                           '<float name="k" value="2.5"/><float name="alpha" value="0.3"/>'
                           '<rgb name="specular_reflectance" value="0.6, 0.8, 0.95"/>'
                           '</bsdf>',
    "roughconductor-none": '<bsdf type="roughconductor"><float name="alpha" value="0.08"/>'
                           '<string name="distribution" value="ggx"/></bsdf>',
    "plastic": '<bsdf type="plastic"><rgb name="diffuse_reflectance" value="0.6, 0.1, 0.1"/>'
               '</bsdf>',
    "plastic-nonlinear": '<bsdf type="plastic"><rgb name="diffuse_reflectance" '
                         'value="0.6, 0.3, 0.9"/><boolean name="nonlinear" value="true"/>'
                         '<float name="int_ior" value="1.7"/></bsdf>',
    # equal indices: no coat at all, a Lambertian base (Mitsuba's plastic allows them; its
    # rough plastic refuses them, as ours does)
    "plastic-equal-indices": '<bsdf type="plastic"><rgb name="diffuse_reflectance" '
                             'value="0.3, 0.6, 0.2"/><float name="int_ior" value="1.333"/>'
                             '<string name="ext_ior" value="water"/></bsdf>',
    "roughplastic-ggx": '<bsdf type="roughplastic"><rgb name="diffuse_reflectance" '
                        'value="0.1, 0.3, 0.6"/><float name="alpha" value="0.15"/>'
                        '<string name="distribution" value="ggx"/></bsdf>',
    "roughplastic-beckmann": '<bsdf type="roughplastic"><rgb name="diffuse_reflectance" '
                             'value="0.8, 0.5, 0.2"/><float name="alpha" value="0.4"/>'
                             '<string name="int_ior" value="bk7"/></bsdf>',
}


def _ours(xml):
    a = prepare_scene(parse_scene(_SCENE.format(bsdf=xml))).arrays
    return a.bsdf_f, a.bsdf_i, a.bsdf_tex, a.tex_data, a.tex_info


def _directions(rng, n, lower=False):
    z = rng.uniform(0.05, 1.0, n)
    phi = rng.uniform(0, 2 * math.pi, n)
    s = np.sqrt(1 - z * z)
    d = np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)
    if lower:
        d[:, 2] *= np.where(rng.random(n) < 0.5, -1, 1)
    return d


def _si(mi, wi):
    si = mi.SurfaceInteraction3f()
    si.p = mi.Point3f(0, 0, 0)
    si.n = mi.Normal3f(0, 0, 1)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.wi = mi.Vector3f(*wi)
    si.uv = mi.Point2f(0.3, 0.6)
    return si


@pytest.mark.parametrize("name", sorted(BSDFS))
def test_eval_matches_mitsuba(mi, name):
    """f · cos θ_o agrees with Mitsuba's ``eval`` to float32 precision, except the rough
    plastic, whose coat tables both renderers integrate numerically (ours: 64² Gauss–
    Legendre nodes; Mitsuba's: 32² or 128² in float32): they agree to 2e-3."""
    arrays = _ours(BSDFS[name])
    bsdf = mi.load_string(BSDFS[name].replace("<bsdf ", '<bsdf version="3.0.0" ', 1))
    ctx = mi.BSDFContext()
    rng = np.random.default_rng(1)
    two = name.startswith("twosided")
    wis, wos = _directions(rng, 200, lower=two), _directions(rng, 200)
    worst = 0.0
    for wi, wo in zip(wis, wos):
        if two and wi[2] < 0:
            wo = wo * np.array([1, 1, -1])
        ours = np.array(B.bsdf_eval(-1, *arrays, 0, tuple(wi), tuple(wo), 0.3, 0.6)[:3])
        theirs = np.array(bsdf.eval(ctx, _si(mi, wi), mi.Vector3f(*wo)))
        scale = max(np.abs(theirs).max(), 1e-3)
        worst = max(worst, np.abs(ours - theirs).max() / scale)
    tol = 2e-3 if "roughplastic" in name else 2e-5
    assert worst < tol, f"{name}: worst relative difference {worst:.3g}"


@pytest.mark.parametrize("xml", [
    '<bsdf type="roughconductor"><float name="alpha" value="1e-6"/>'
    '<string name="distribution" value="ggx"/></bsdf>',
    '<bsdf type="roughconductor"><float name="alpha_u" value="1e-7"/>'
    '<float name="alpha_v" value="2e-5"/><string name="distribution" value="ggx"/></bsdf>',
    '<bsdf type="roughdielectric"><float name="alpha" value="1e-200"/>'
    '<string name="distribution" value="ggx"/></bsdf>',
    '<bsdf type="roughplastic"><float name="alpha" value="1e-6"/>'
    '<string name="distribution" value="ggx"/></bsdf>',
    # 0, as exporters write a smooth surface: refused until 6 December, where Mitsuba
    # raises it to 1e-4 as any alpha below (an outside review)
    '<bsdf type="roughconductor"><float name="alpha" value="0"/>'
    '<string name="distribution" value="ggx"/></bsdf>',
    '<bsdf type="roughdielectric"><float name="alpha_u" value="0"/>'
    '<float name="alpha_v" value="0"/><string name="distribution" value="ggx"/></bsdf>',
])
def test_a_roughness_below_mitsubas_floor_is_raised_to_it(mi, xml):
    """Mitsuba raises every microfacet alpha below 1e-4 to 1e-4: near the mirror
    direction (θ_h ≈ 1e-3, where D at 1e-4 and at 1e-6 differ 1e4-fold) our value is
    Mitsuba's (it was 1e-4 of it at alpha 1e-6, and NaN at 1e-200, whose alpha²
    underflows). The directions are float32, as Mitsuba holds them."""
    arrays = _ours(xml)
    bsdf = mi.load_string(xml.replace("<bsdf ", '<bsdf version="3.0.0" ', 1))
    ctx = mi.BSDFContext()
    wi = np.array([0.3, 0.0, 1.0], np.float32)
    wo = np.array([-0.3, 0.002, 1.0], np.float32)
    wi, wo = wi / np.linalg.norm(wi), wo / np.linalg.norm(wo)
    ours = np.array(B.bsdf_eval(-1, *arrays, 0, tuple(map(float, wi)), tuple(map(float, wo)),
                                0.3, 0.6)[:3])
    theirs = np.array(bsdf.eval(ctx, _si(mi, tuple(map(float, wi))),
                                mi.Vector3f(*map(float, wo))))
    assert theirs.max() > 1.0
    np.testing.assert_allclose(ours, theirs, rtol=2e-3)


@pytest.mark.parametrize("name,xml", [
    ("dielectric", '<bsdf type="dielectric"><float name="int_ior" value="1.5"/></bsdf>'),
    ("dielectric-water", '<bsdf type="dielectric"><string name="int_ior" value="water"/>'
                         '<rgb name="specular_transmittance" value="0.9, 0.8, 0.7"/></bsdf>'),
    ("conductor-Ag", '<bsdf type="conductor"><string name="material" value="Ag"/></bsdf>'),
    ("conductor-mirror", '<bsdf type="conductor"/>'),
    ("conductor-grey", '<bsdf type="conductor"><float name="eta" value="1.3"/>'
                       '<float name="k" value="0.7"/></bsdf>'),
    ("plastic", BSDFS["plastic"]),
    ("plastic-equal-indices", BSDFS["plastic-equal-indices"]),
    # from below, a twosided BSDF's mirror direction is below too: the z of a conductor's
    # reflection left unflipped (a mutant) passed every test (an outside mutation review)
    ("twosided-conductor", '<bsdf type="twosided"><bsdf type="conductor"><string '
                           'name="material" value="Au"/><rgb name="specular_reflectance" '
                           'value="0.9, 0.8, 0.7"/></bsdf></bsdf>'),
    ("twosided-plastic", f'<bsdf type="twosided">{BSDFS["plastic"]}</bsdf>'),
])
def test_delta_sampling_matches_mitsuba(mi, name, xml):
    """Delta components: with the same random numbers, the same direction and weight
    (for plastic the choice between coat and base uses the same probabilities); glass
    and twosided BSDFs from both sides."""
    arrays = _ours(xml)
    bsdf = mi.load_string(xml.replace("<bsdf ", '<bsdf version="3.0.0" ', 1))
    ctx = mi.BSDFContext()
    rng = np.random.default_rng(2)
    wis = _directions(rng, 100, lower=name.startswith(("dielectric", "twosided")))
    for wi, u0 in zip(wis, rng.random(100)):
        bs, w = bsdf.sample(ctx, _si(mi, wi), float(u0), mi.Point2f(0.3, 0.7))
        ours = B.bsdf_sample(-1, *arrays, 0, tuple(wi), float(u0), 0.3, 0.7, 0.3, 0.6, 1.0)
        if not ours[7]:
            assert not (int(bs.sampled_type) & int(mi.BSDFFlags.Delta))
            continue
        np.testing.assert_allclose(ours[:3], np.array(bs.wo), atol=2e-6)
        np.testing.assert_allclose(ours[3:6], np.array(w), rtol=2e-5, atol=1e-6)


@pytest.mark.parametrize("xml", [
    '<bsdf type="plastic"><rgb name="diffuse_reflectance" value="0, 0, 0"/>'
    '<rgb name="specular_reflectance" value="0, 0, 0"/></bsdf>',
    '<bsdf type="roughplastic"><float name="diffuse_reflectance" value="0"/>'
    '<float name="specular_reflectance" value="0"/><float name="alpha" value="0.2"/></bsdf>',
])
def test_a_black_plastic_scatters_nothing(mi, xml):
    """A plastic whose two reflectances are both 0 is one Mitsuba loads and renders black
    (its sampling weight s / (d + s) is 0 / 0, NaN): ours samples the base only (weight
    0) and scatters nothing, its weights 0, not NaN. It was a ZeroDivisionError in
    ``prepare_scene``, which the CLI reported as "unexpected" (an outside review)."""
    arrays = _ours(xml)
    bsdf = mi.load_string(xml.replace("<bsdf ", '<bsdf version="3.0.0" ', 1))
    ctx = mi.BSDFContext()
    rng = np.random.default_rng(5)
    for wi, wo, u0 in zip(_directions(rng, 50), _directions(rng, 50), rng.random(50)):
        ours = B.bsdf_eval(-1, *arrays, 0, tuple(wi), tuple(wo), 0.3, 0.6)
        assert ours[:3] == (0.0, 0.0, 0.0)
        np.testing.assert_array_equal(np.array(bsdf.eval(ctx, _si(mi, wi),
                                                         mi.Vector3f(*wo))), 0.0)
        drawn = B.bsdf_sample(-1, *arrays, 0, tuple(wi), float(u0), 0.3, 0.7, 0.3, 0.6, 1.0)
        assert drawn[3:6] == (0.0, 0.0, 0.0)


def test_fresnel_diffuse_reflectance_matches_mitsuba(mi):
    # Mitsuba evaluates the polynomial fits in float32
    for eta in (1 / 1.49, 1.49, 1.0 / 1.33, 2.4):
        assert B.fresnel_diffuse_reflectance(eta) == pytest.approx(
            float(mi.fresnel_diffuse_reflectance(eta)), rel=1e-5)


def test_a_wrong_pdf_scale_changes_weights_only_by_that_factor():
    arrays = _ours(BSDFS["diffuse"])
    a = B.bsdf_sample(-1, *arrays, 0, (0.0, 0.6, 0.8), 0.5, 0.3, 0.7, 0.3, 0.6, 1.0)
    b = B.bsdf_sample(-1, *arrays, 0, (0.0, 0.6, 0.8), 0.5, 0.3, 0.7, 0.3, 0.6, 1.1)
    assert a[:3] == b[:3]
    np.testing.assert_allclose(np.array(a[3:6]) / np.array(b[3:6]), 1.1)


def test_bitmap_and_envmap_lookups_match_mitsuba(mi, tmp_path):
    from estimators.pathtracer import textures as T

    img = np.random.default_rng(3).random((6, 10, 3)) * 4
    path = str(tmp_path / "t.exr")
    mi.Bitmap(img.astype(np.float32)).write(path)
    store = T.TextureStore()
    store.add(T.read_image(path))
    data, info = store.arrays()
    tex = mi.load_dict({"type": "bitmap", "filename": path})
    env = mi.load_dict({"type": "envmap", "filename": path})
    si = mi.SurfaceInteraction3f()
    rng = np.random.default_rng(4)
    for u, v in rng.random((200, 2)):
        si.uv = mi.Point2f(u, v)
        np.testing.assert_allclose(T.eval_texture(data, info, 0, u, v), np.array(tex.eval(si)),
                                   rtol=1e-5)
        d = T.envmap_direction(u, v)
        assert np.allclose(T.envmap_uv(*d), (u, v), atol=1e-9)
        si.wi = mi.Vector3f(*(-np.array(d)))
        np.testing.assert_allclose(T.eval_envmap(data, info, 0, u, v), np.array(env.eval(si)),
                                   rtol=2e-5)


_UNIT = "x=\"0.8638684255813601\" y=\"0.43193421279068006\" z=\"0.25916052767440806\""


@pytest.mark.parametrize("to_world", [f'<rotate {_UNIT} angle="50"/>',
                                      '<rotate y="1" angle="70"/><scale x="-1"/>'],
                         ids=["unit-axis", "mirrored"])
def test_a_rotated_envmap_is_mitsubas(mi, tmp_path, to_world):
    """Radiance of an envmap whose to_world is a rotation about a general unit axis (the
    reference scenes rotate about y only), or a mirror, through the loader. (The pdfs
    differ by design: Mitsuba's warp interpolates the luminance, ours is piecewise
    constant; each renderer is consistent with its own.)"""
    from estimators.pathtracer.emitters import eval_environment

    img = np.random.default_rng(5).random((8, 16, 3)) * 3
    mi.Bitmap(img.astype(np.float32)).write(str(tmp_path / "env.exr"))
    path = tmp_path / "s.xml"
    path.write_text(_SCENE.format(bsdf="").replace(
        "</scene>", f'<emitter type="envmap"><string name="filename" value="env.exr"/>'
                    f'<float name="scale" value="1.7"/><transform name="to_world">{to_world}'
                    f'</transform></emitter></scene>'))
    a = prepare_scene(str(path)).arrays
    env = mi.load_file(str(path)).environment()
    rng = np.random.default_rng(6)
    d = rng.normal(size=(300, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    si = mi.SurfaceInteraction3f()
    for v in d:
        si.wi = mi.Vector3f(*(-v))
        np.testing.assert_allclose(
            eval_environment(a.light_f, a.light_i, a.tex_data, a.tex_info, a.env_marginal,
                             a.env_conditional, a.env, *v, False)[:3],
            np.array(env.eval(si)), rtol=2e-4, atol=1e-6)


def test_an_envmaps_mis_compensation_is_taken_and_changes_nothing_here(mi, tmp_path):
    """``mis_compensation`` changes how Mitsuba samples its map (the luminance less its
    mean), not the image; the loader refused it. Ours samples the map its own way, so the
    prepared scene is the one without it, and the radiance is Mitsuba's with it."""
    from estimators.pathtracer.emitters import eval_environment

    img = np.random.default_rng(8).random((8, 16, 3)) * 3
    mi.Bitmap(img.astype(np.float32)).write(str(tmp_path / "env.exr"))
    arrays = []
    for flag in ("", '<boolean name="mis_compensation" value="true"/>'):
        path = tmp_path / f"s{len(arrays)}.xml"
        path.write_text(_SCENE.format(bsdf="").replace(
            "</scene>", f'<emitter type="envmap"><string name="filename" value="env.exr"/>'
                        f'{flag}</emitter></scene>'))
        arrays.append(prepare_scene(str(path)).arrays)
    for name in ("light_f", "light_i", "tex_data", "env_marginal", "env_conditional"):
        np.testing.assert_array_equal(getattr(arrays[0], name), getattr(arrays[1], name))
    a, env = arrays[1], mi.load_file(str(path)).environment()
    si = mi.SurfaceInteraction3f()
    d = np.random.default_rng(9).normal(size=(100, 3))
    for v in d / np.linalg.norm(d, axis=1, keepdims=True):
        si.wi = mi.Vector3f(*(-v))
        np.testing.assert_allclose(
            eval_environment(a.light_f, a.light_i, a.tex_data, a.tex_info, a.env_marginal,
                             a.env_conditional, a.env, *v, False)[:3],
            np.array(env.eval(si)), rtol=2e-4, atol=1e-6)


@pytest.mark.parametrize("to_world", ['<rotate x="1" y="0.5" z="0.3" angle="50"/>',
                                      '<scale value="2"/>', '<scale x="1" y="2"/>'],
                         ids=["non-unit-axis", "uniform-scale", "stretch"])
def test_an_envmap_that_is_not_rotated_rigidly_is_refused(tmp_path, to_world):
    """Mitsuba looks such a map up along M⁻¹d and samples M·d, neither normalised: found on
    a scene not in the repository (a rotation about the axis (1, 0.5, 0.3), which Mitsuba
    does not normalise, made the image mean 5 % off), and it cannot be matched."""
    from estimators.pathtracer.scene import SceneError

    path = tmp_path / "s.xml"
    path.write_text(_SCENE.format(bsdf="").replace(
        "</scene>", f'<emitter type="envmap"><string name="filename" value="none.exr"/>'
                    f'<transform name="to_world">{to_world}</transform></emitter></scene>'))
    with pytest.raises(SceneError, match=r's\.xml:\d+: <emitter type="envmap">: to_world must '
                                         r"be a rotation .*cannot be matched"):
        prepare_scene(str(path))


def test_an_envmap_rotated_by_a_matrix_written_to_4_decimals_samples_unit_directions(mi,
                                                                                      tmp_path):
    """An outside review: a rotation about y by 40 degrees written to 4 decimals (as
    exporters write a matrix) is accepted as a rotation (within 1e-3), but the sampler
    turned its draws to world space by the transpose of the inverse, which is not the
    matrix: its directions were 5e-5 off unit length and their lookup 5e-5 off the pdf
    drawn with them, so the plan's checks of such an envmap failed on the tracer
    (chi-square p = 0, 93 % of the draws off the unit sphere; the pdf consistency at
    rtol 1e-6). The map is now rotated by the rotation nearest the matrix, both ways."""
    from estimators.pathtracer.sampling import emitter_sampler_with_weight

    img = np.random.default_rng(5).random((8, 16, 3)) * 3 + 0.1
    mi.Bitmap(img.astype(np.float32)).write(str(tmp_path / "env.exr"))
    path = tmp_path / "s.xml"
    path.write_text(_SCENE.format(bsdf="").replace(
        "</scene>", '<emitter type="envmap"><string name="filename" value="env.exr"/>'
                    '<transform name="to_world"><matrix value="0.7660 0 0.6428 0  0 1 0 0  '
                    '-0.6428 0 0.7660 0  0 0 0 1"/></transform></emitter></scene>'))
    scene = prepare_scene(str(path))
    sample, pdf, _ = emitter_sampler_with_weight(scene, scene.arrays.env, (0.0, 0.0, 0.0))
    d, p = sample(np.random.default_rng(7).random((2000, 3)))[:2]
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, rtol=1e-12)
    np.testing.assert_allclose(pdf(d), p, rtol=1e-9)


def _envmap_scene(mi, tmp_path, img):
    # written by the fixture's Mitsuba (mcverify.gate.mitsuba.write_exr would switch the
    # module's scalar variant to its own)
    mi.Bitmap(np.ascontiguousarray(img, dtype=np.float32)).write(str(tmp_path / "e.exr"))
    path = tmp_path / "s.xml"
    path.write_text(_SCENE.format(bsdf="").replace(
        "</scene>", '<emitter type="envmap"><string name="filename" value="e.exr"/>'
                    '</emitter></scene>'))
    return str(path)


@pytest.mark.parametrize("shape, fill, match", [
    ((2, 3), 1.0, r"3 x 2 pixels; an envmap needs at least 2 columns and 3 rows"),
    ((5, 1), 1.0, r"1 x 5 pixels; an envmap needs at least 2 columns and 3 rows"),
    ((4, 6), (1.0, -0.4, 0.0), r"its luminance is nowhere positive.*not matched")],
    ids=["two-rows", "one-column", "negative-luminance"])
def test_envmaps_mitsuba_cannot_render_consistently_are_refused(mi, tmp_path, shape, fill,
                                                                 match):
    """Found on maps not in the repository: Mitsuba 3.9.1 rendered a 3 x 2 map's directly
    seen radiance differently (mean red 0.84 against our 0.76; newer Mitsuba refuses maps
    under 2 x 3), and a map whose luminance is nowhere positive leaves Mitsuba's sampling
    table without mass (max_depth 2: red 0.40 there, 0.57 here). An all-black map and a
    map negative over half its area stay accepted."""
    from estimators.pathtracer.scene import SceneError

    def scene(img):
        return _envmap_scene(mi, tmp_path, img)

    with pytest.raises(SceneError, match=r'<emitter type="envmap">: e\.exr: ' + match):
        prepare_scene(scene(np.broadcast_to(fill, (*shape, 3))))
    prepare_scene(scene(np.zeros((4, 6, 3))))
    half = np.ones((4, 6, 3))
    half[:, :3] = -1.0
    prepare_scene(scene(half))


def test_an_envmap_lit_in_its_top_row_only_is_refused(mi, tmp_path):
    """An outside review: an 8 x 16 map lit in its top row only rendered 0.055 (mean)
    here and black in Mitsuba (check --scene failed, p = 5e-161): Mitsuba weights row y
    of its sampling table by sin(y π / (h - 1)), 0 on the top row, so the table has no
    mass. It is refused now, naming the file; the map lit in its top two rows, or in its
    bottom row, renders as in Mitsuba (their render checks pass) and stays accepted."""
    from estimators.pathtracer.scene import SceneError

    img = np.zeros((8, 16, 3))
    img[0] = 5.0
    with pytest.raises(SceneError, match=r'<emitter type="envmap">: e\.exr: its luminance '
                                         r'is positive in its top row only'):
        prepare_scene(_envmap_scene(mi, tmp_path, img))
    for rows in (slice(0, 2), slice(7, 8)):
        img = np.zeros((8, 16, 3))
        img[rows] = 5.0
        prepare_scene(_envmap_scene(mi, tmp_path, img))


@pytest.mark.mitsuba
def test_mitsuba_renders_an_envmap_lit_in_its_top_row_only_black(mi, tmp_path):
    img = np.zeros((8, 16, 3), np.float32)
    means = []
    for row in (0, 1):
        img[:] = 0.0
        img[row] = 5.0
        mi.Bitmap(img).write(str(tmp_path / "e.exr"))
        scene = mi.load_dict({
            "type": "scene", "i": {"type": "path", "max_depth": 3},
            "e": {"type": "envmap", "filename": str(tmp_path / "e.exr")},
            "s": {"type": "sphere", "bsdf": {"type": "diffuse"}},
            "c": {"type": "perspective", "fov": 60, "to_world": mi.ScalarTransform4f()
                  .look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0]),
                  "film": {"type": "hdrfilm", "width": 8, "height": 8,
                           "rfilter": {"type": "box"}}}})
        means.append(float(np.mean(np.array(mi.render(scene, spp=16)))))
    assert means[0] == 0.0 and means[1] > 0.0, means


@pytest.mark.parametrize("bsdf", ['<bsdf type="mask"><float name="opacity" value="0.3"/>'
                                  '<bsdf type="diffuse"/></bsdf>',
                                  '<bsdf type="thindielectric"/>'], ids=["mask", "thin"])
def test_hidden_emitters_seen_through_a_null_component_at_a_depth_limit_are_refused(
        tmp_path, bsdf):
    """Found on a scene not in the repository (a mask sphere under an envmap, path,
    hide_emitters, max_depth 2): Mitsuba's llvm variant counts a path that only passed
    through null components as valid at the last vertex, its scalar variant does not (the
    two differ at p = 1e-173); unlimited depth, or emitters shown, stay accepted."""
    from estimators.pathtracer.scene import SceneError

    def scene(max_depth, hide):
        path = tmp_path / "s.xml"
        path.write_text(_SCENE.format(bsdf=bsdf).replace(
            "<sensor", f'<integrator type="path"><integer name="max_depth" value="{max_depth}"/>'
                       f'<boolean name="hide_emitters" value="{hide}"/></integrator><sensor')
            .replace("</scene>", '<emitter type="constant"/></scene>'))
        return str(path)

    for depth in (2, 3, 8):
        with pytest.raises(SceneError, match=r"hide_emitters with a (mask|thindielectric) "
                                             rf"BSDF and max_depth {depth}: .*not matched"):
            prepare_scene(scene(depth, "true"))
    for depth, hide in ((-1, "true"), (1, "true"), (2, "false")):
        prepare_scene(scene(depth, hide))


def test_envmap_sampling_weights_cover_every_cell():
    from estimators.pathtracer.textures import envmap_refinement, envmap_sampling_weights

    img = np.zeros((8, 16, 3))
    img[3, 5] = 100.0
    w = envmap_sampling_weights(img)
    r = envmap_refinement(8, 16)
    assert r == 8 and w.shape == (64, 128)
    assert np.all(w > 0)
    # the bright texel's bilinear support (its 3 × 3 texels) carries most of the weight,
    # the cells of its own texel the most
    assert w[2 * r:5 * r, 4 * r:7 * r].sum() > 0.9 * w.sum()
    row, col = np.unravel_index(w.argmax(), w.shape)
    assert (row // r, col // r) == (3, 5)


@pytest.mark.parametrize("h, w, want", [(32, 64, 4), (1, 7, 8), (8, 3, 8), (256, 512, 1),
                                        (100, 200, 2), (1, 300, 1), (600, 200, 2), (2000, 200, 1),
                                        (200, 100, 3)])
def test_envmap_refinement_reaches_256_columns_within_its_caps(h, w, want):
    """Each texel is split into s × s sampling cells: the least s giving 256 columns, at
    most 8, and at most 2^20 cells in all."""
    from estimators.pathtracer.textures import envmap_refinement

    s = envmap_refinement(h, w)
    assert s == want
    assert 1 <= s <= 8 and (s == 1 or s * s * h * w <= 1 << 20)


_LUMINANCE = np.array([0.212671, 0.715160, 0.072169])   # Rec. 709 (Mitsuba's luminance)


def _envmap_lookup(img, uu, vv):
    """The envmap's bilinear lookup at (u, v) arrays, in numpy: x = u W - 1/2 repeating,
    y = v (H - 1) clamped (Mitsuba's convention, as ``eval_envmap``)."""
    h, w = img.shape[:2]
    x, y = uu * w - 0.5, vv * (h - 1)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    xa, xb = x0 % w, (x0 + 1) % w
    ya, yb = np.clip(y0, 0, h - 1), np.clip(y0 + 1, 0, h - 1)
    return ((1 - fx) * (1 - fy) * img[ya, xa] + fx * (1 - fy) * img[ya, xb]
            + (1 - fx) * fy * img[yb, xa] + fx * fy * img[yb, xb])


@pytest.mark.parametrize("shape", [(5, 7), (1, 7), (8, 3), (3, 300)])
def test_envmap_weights_are_cell_means_of_the_lookup_times_sin_theta(shape):
    from estimators.pathtracer.textures import envmap_refinement, envmap_sampling_weights

    img = np.random.default_rng(1).random((*shape, 3)) ** 4
    s = envmap_refinement(*shape)
    h, w = s * shape[0], s * shape[1]
    k = 4
    off = (np.arange(k) + 0.5) / k
    means = np.zeros((h, w))
    for a in off:
        for b in off:
            jj, ii = np.mgrid[0:h, 0:w]
            means += np.maximum(_envmap_lookup(img, (ii + a) / w, (jj + b) / h) @ _LUMINANCE,
                                0.0)
    sin_t = np.sin(np.pi * (np.arange(h) + 0.5) / h)[:, None]
    want = means / k ** 2 * sin_t
    want += 1e-3 * want.mean() * sin_t
    np.testing.assert_allclose(envmap_sampling_weights(img), want, rtol=1e-12)


def test_envmap_sampling_follows_the_lookup_closely():
    """The envmap scene's sky (32 × 64 texels, sampled on a 4× finer grid): sampling
    (u, v) from the weights, the relative variance of one sample of the environment's
    integral (its lookup's luminance times sin θ, on an 8× finer grid) is 0.0082 (0.023
    for the mean of R, G, B with the largest channel's weights before 3 December, 0.155
    with one cell a texel, 0.55 with the 3 × 3 maximum the weights were before that)."""
    from estimators.pathtracer.textures import envmap_sampling_weights, read_image

    scenes = os.path.join(os.path.dirname(__file__), "..", "..", "reference", "scenes")
    img = np.asarray(read_image(os.path.join(scenes, "envmap", "sky.exr")))[..., :3]
    h, w = img.shape[:2]
    p = envmap_sampling_weights(img)
    ph, pw = p.shape
    assert (ph, pw) == (4 * h, 4 * w)
    p = p / p.sum() * (ph * pw)
    vv, uu = np.meshgrid((np.arange(8 * h) + 0.5) / (8 * h), (np.arange(8 * w) + 0.5) / (8 * w),
                         indexing="ij")
    f = _envmap_lookup(img, uu, vv) @ _LUMINANCE * np.sin(np.pi * vv)
    pdf = p[(vv * ph).astype(int), (uu * pw).astype(int)]
    rel_var = (f ** 2 / pdf).mean() / f.mean() ** 2 - 1
    assert rel_var < 0.01, rel_var


# ----------------------------------------------- transmissive and composite BSDFs
_EXR = "weight.exr"
COMPOSITE = {
    "roughdielectric-ggx": '<bsdf type="roughdielectric"><float name="alpha" value="0.2"/>'
                           '<string name="distribution" value="ggx"/>'
                           '<float name="int_ior" value="1.5"/></bsdf>',
    "roughdielectric-beckmann-colours": '<bsdf type="roughdielectric"><float name="alpha" '
                                        'value="0.35"/><string name="int_ior" value="water"/>'
                                        '<rgb name="specular_reflectance" value="0.9, 0.7, 0.5"/>'
                                        '<rgb name="specular_transmittance" value="0.3, 0.6, 0.9"/>'
                                        '</bsdf>',
    "roughdielectric-alpha-uv-ggx": '<bsdf type="roughdielectric"><float name="alpha_u" '
                                    'value="0.25"/><float name="alpha_v" value="0.25"/>'
                                    '<string name="distribution" value="ggx"/>'
                                    '<float name="int_ior" value="1.33"/>'
                                    '<float name="ext_ior" value="1.6"/></bsdf>',
    "roughconductor-anisotropic-ggx": '<bsdf type="roughconductor"><string name="material" '
                                      'value="Cu"/><float name="alpha_u" value="0.05"/>'
                                      '<float name="alpha_v" value="0.4"/>'
                                      '<string name="distribution" value="ggx"/></bsdf>',
    "roughconductor-anisotropic-beckmann": '<bsdf type="roughconductor"><float name="alpha_u" '
                                           'value="0.3"/><float name="alpha_v" value="0.08"/>'
                                           '<boolean name="sample_visible" value="false"/>'
                                           '</bsdf>',
    "roughdielectric-anisotropic-ggx": '<bsdf type="roughdielectric"><float name="alpha_u" '
                                       'value="0.1"/><float name="alpha_v" value="0.35"/>'
                                       '<string name="distribution" value="ggx"/>'
                                       '<float name="int_ior" value="1.5"/></bsdf>',
    "roughdielectric-anisotropic-beckmann": '<bsdf type="roughdielectric"><float name="alpha_u" '
                                            'value="0.4"/><float name="alpha_v" value="0.15"/>'
                                            '</bsdf>',
    "normalmap-diffuse": '<bsdf type="normalmap"><texture type="bitmap" name="normalmap">'
                         f'<string name="filename" value="{_EXR}"/><boolean name="raw" '
                         'value="true"/></texture><bsdf type="diffuse"><rgb name="reflectance" '
                         'value="0.7, 0.5, 0.3"/></bsdf></bsdf>',
    "normalmap-roughconductor-no-flip": '<bsdf type="normalmap"><texture type="bitmap" '
                                        f'name="normalmap"><string name="filename" value="{_EXR}"/>'
                                        '<string name="filter_type" value="nearest"/></texture>'
                                        '<boolean name="flip_invalid_normals" value="false"/>'
                                        '<bsdf type="roughconductor"><float name="alpha_u" '
                                        'value="0.1"/><float name="alpha_v" value="0.3"/>'
                                        '<string name="distribution" value="ggx"/></bsdf></bsdf>',
    "normalmap-roughdielectric-no-shadowing": '<bsdf type="normalmap"><texture type="bitmap" '
                                              f'name="normalmap"><string name="filename" '
                                              f'value="{_EXR}"/></texture><boolean '
                                              'name="use_shadowing_function" value="false"/>'
                                              '<bsdf type="roughdielectric"><string '
                                              'name="distribution" value="ggx"/><float '
                                              'name="alpha" value="0.3"/></bsdf></bsdf>',
    "twosided-normalmap-plastic": '<bsdf type="twosided"><bsdf type="normalmap"><texture '
                                  f'type="bitmap" name="normalmap"><string name="filename" '
                                  f'value="{_EXR}"/></texture><bsdf type="roughplastic"/>'
                                  '</bsdf></bsdf>',
    "normalmap-twosided-diffuse": '<bsdf type="normalmap"><texture type="bitmap" '
                                  f'name="normalmap"><string name="filename" value="{_EXR}"/>'
                                  '</texture><bsdf type="twosided"><bsdf type="diffuse"/></bsdf>'
                                  '</bsdf>',
    "mask-twosided-diffuse": '<bsdf type="mask"><float name="opacity" value="0.3"/>'
                             '<bsdf type="twosided"><bsdf type="diffuse"><rgb name="reflectance" '
                             'value="0.2, 0.7, 0.4"/></bsdf></bsdf></bsdf>',
    "mask-roughdielectric": '<bsdf type="mask"><float name="opacity" value="0.6"/>'
                            '<bsdf type="roughdielectric"><float name="alpha" value="0.3"/>'
                            '<string name="distribution" value="ggx"/></bsdf></bsdf>',
    "blend-diffuse-roughconductor": '<bsdf type="blendbsdf"><float name="weight" value="0.3"/>'
                                    '<bsdf type="diffuse"/><bsdf type="roughconductor">'
                                    '<string name="distribution" value="ggx"/>'
                                    '<float name="alpha" value="0.2"/></bsdf></bsdf>',
    "blend-texture-weight": '<bsdf type="blendbsdf"><texture type="bitmap" name="weight">'
                            f'<string name="filename" value="{_EXR}"/></texture>'
                            '<bsdf type="roughplastic"/><bsdf type="roughdielectric">'
                            '<string name="distribution" value="ggx"/></bsdf></bsdf>',
    "twosided-blend": '<bsdf type="twosided"><bsdf type="blendbsdf"><float name="weight" '
                      'value="0.7"/><bsdf type="diffuse"/><bsdf type="roughconductor">'
                      '<string name="material" value="Cu"/></bsdf></bsdf></bsdf>',
    "mask-blend": '<bsdf type="mask"><texture type="bitmap" name="opacity">'
                  f'<string name="filename" value="{_EXR}"/></texture>'
                  '<bsdf type="blendbsdf"><float name="weight" value="0.5"/><bsdf type="diffuse"/>'
                  '<bsdf type="roughconductor"><string name="distribution" value="ggx"/></bsdf>'
                  '</bsdf></bsdf>',
}
#: where our pdf must equal Mitsuba's: the same sampling strategy (GGX visible normals,
#: cosine-weighted diffuse); Beckmann we sample by D cos θ_m, Mitsuba by visible normals
#: (a rough conductor's ``sample_visible`` false: D cos θ_m too)
SAME_PDF = ("roughdielectric-ggx", "roughdielectric-alpha-uv-ggx", "mask-twosided-diffuse",
            "mask-roughdielectric", "blend-diffuse-roughconductor",
            "roughconductor-anisotropic-ggx", "roughconductor-anisotropic-beckmann",
            "roughdielectric-anisotropic-ggx", "normalmap-diffuse",
            "normalmap-roughconductor-no-flip", "normalmap-roughdielectric-no-shadowing",
            "normalmap-twosided-diffuse")


@pytest.fixture(scope="module")
def exr_dir(mi, tmp_path_factory):
    d = tmp_path_factory.mktemp("composite")
    img = np.random.default_rng(5).random((4, 6, 3)).astype(np.float32)
    mi.Bitmap(img).write(str(d / _EXR))
    return d


def _ours_in(xml, folder):
    path = folder / "scene.xml"
    path.write_text(_SCENE.format(bsdf=xml))
    a = prepare_scene(str(path)).arrays
    top = int(a.shape_bsdf[0])
    return (a.bsdf_f, a.bsdf_i, a.bsdf_tex, a.tex_data, a.tex_info), top


def _theirs(mi, xml, folder):
    return mi.load_string(xml.replace("<bsdf ", '<bsdf version="3.0.0" ', 1)
                          .replace(f'value="{_EXR}"', f'value="{folder / _EXR}"'))


def _sphere_directions(rng, n):
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d[np.abs(d[:, 2]) > 0.05]


@pytest.mark.parametrize("name", sorted(COMPOSITE))
def test_transmissive_and_composite_eval_and_pdf_match_mitsuba(mi, exr_dir, name):
    """Over the whole sphere of wi and wo (reflection and transmission, both sides):
    f · |cos θ_o| agrees with Mitsuba's ``eval`` to float32 precision (2e-3 where a rough
    plastic's coat tables are inside), and so does the pdf where both sample alike."""
    arrays, top = _ours_in(COMPOSITE[name], exr_dir)
    bsdf = _theirs(mi, COMPOSITE[name], exr_dir)
    ctx = mi.BSDFContext()
    rng = np.random.default_rng(6)
    # a rough conductor reflects only: a quarter of the pairs lie both above, so twice
    # the pairs give it as many nonzero values as the others
    n = 600 if name.startswith("roughconductor") else 300
    wis, wos = _sphere_directions(rng, n), _sphere_directions(rng, n)
    worst_f = worst_p = 0.0
    nonzero = 0
    for wi, wo in zip(wis, wos):
        r = B.bsdf_eval(-1, *arrays, top, tuple(wi), tuple(wo), 0.3, 0.6)
        si = _si(mi, wi)
        theirs = np.array(bsdf.eval(ctx, si, mi.Vector3f(*wo)))
        scale = max(np.abs(theirs).max(), 1e-3)
        worst_f = max(worst_f, np.abs(np.array(r[:3]) - theirs).max() / scale)
        nonzero += theirs.max() > 0
        if name in SAME_PDF:
            p = float(bsdf.pdf(ctx, si, mi.Vector3f(*wo)))
            worst_p = max(worst_p, abs(r[3] - p) / max(p, 1e-3))
    tol = 2e-3 if "texture-weight" in name or "plastic" in name else 5e-5
    assert nonzero > 50
    assert worst_f < tol, f"{name}: worst relative difference of f {worst_f:.3g}"
    assert worst_p < 5e-5, f"{name}: worst relative difference of the pdf {worst_p:.3g}"


_NORMALMAP = ('<bsdf type="normalmap"><texture type="bitmap" name="normalmap"><string '
              f'name="filename" value="{_EXR}"/><boolean name="raw" value="true"/></texture>'
              '<bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.5, 0.3"/></bsdf></bsdf>')


@pytest.mark.parametrize("name,xml", [
    ("normalmap-diffuse", _NORMALMAP),
    ("normalmap-diffuse-no-shadowing",
     _NORMALMAP.replace("</texture>", '</texture><boolean name="use_shadowing_function" '
                                      'value="false"/>')),
    ("twosided-normalmap-diffuse", f'<bsdf type="twosided">{_NORMALMAP}</bsdf>'),
])
def test_normal_mapped_sampling_matches_mitsuba(mi, exr_dir, name, xml):
    """A normal-mapped diffuse BSDF sampled from either side with the same random numbers
    (both renderers draw the cosine lobe by the concentric map, in the mapped frame):
    the same direction and weight, the shadowing term in it, a direction on opposite
    sides of the two frames dropped by both. The eval-only tests let live a sampled
    weight without the shadowing term and a twosided normal map's direction left above
    the surface from below (two mutants of an outside review)."""
    arrays, top = _ours_in(xml, exr_dir)
    bsdf = _theirs(mi, xml, exr_dir)
    ctx = mi.BSDFContext()
    rng = np.random.default_rng(8)
    wis = _sphere_directions(rng, 300)
    if not name.startswith("twosided"):
        wis[:, 2] = np.abs(wis[:, 2])
    kept = 0
    for wi, (u1, u2) in zip(wis, rng.random((len(wis), 2))):
        bs, w = bsdf.sample(ctx, _si(mi, wi), 0.5, mi.Point2f(float(u1), float(u2)))
        ours = B.bsdf_sample(-1, *arrays, top, tuple(wi), 0.5, float(u1), float(u2), 0.3, 0.6,
                             1.0)
        theirs = np.array(w)
        np.testing.assert_allclose(ours[3:6], theirs, rtol=5e-5, atol=1e-6)
        if theirs.max() > 0:
            kept += 1
            np.testing.assert_allclose(ours[:3], np.array(bs.wo), atol=2e-6)
    assert kept > 150


@pytest.mark.parametrize("name,xml", [
    ("thindielectric", '<bsdf type="thindielectric"><float name="int_ior" value="1.7"/>'
                       '<rgb name="specular_reflectance" value="0.9, 0.8, 0.7"/>'
                       '<rgb name="specular_transmittance" value="0.5, 0.6, 0.7"/></bsdf>'),
    ("thindielectric-named", '<bsdf type="thindielectric"><string name="int_ior" '
                             'value="water"/><string name="ext_ior" value="bk7"/></bsdf>'),
    ("mask-dielectric", '<bsdf type="mask"><float name="opacity" value="0.4"/>'
                        '<bsdf type="dielectric"/></bsdf>'),
    ("mask-conductor", '<bsdf type="mask"><float name="opacity" value="0.75"/>'
                       '<bsdf type="conductor"><string name="material" value="Au"/></bsdf></bsdf>'),
])
def test_null_and_delta_sampling_matches_mitsuba(mi, tmp_path, name, xml):
    """A null component (the ray goes on unchanged: Mitsuba's ``Null`` flag) and the delta
    lobes beside it: with the same random numbers, the same direction, weight, pdf and
    kind of event, from either side."""
    arrays, top = _ours_in(xml, tmp_path)
    bsdf = _theirs(mi, xml, tmp_path)
    ctx = mi.BSDFContext()
    rng = np.random.default_rng(7)
    kinds = set()
    for wi, u0 in zip(_sphere_directions(rng, 200), rng.random(200)):
        bs, w = bsdf.sample(ctx, _si(mi, wi), float(u0), mi.Point2f(0.3, 0.7))
        ours = B.bsdf_sample(-1, *arrays, top, tuple(wi), float(u0), 0.3, 0.7, 0.3, 0.6, 1.0)
        if not np.any(np.array(w)):             # a conductor seen from below: nothing
            assert not any(ours[3:6])
            continue
        null = bool(int(bs.sampled_type) & int(mi.BSDFFlags.Null))
        assert ours[9] == null and ours[7]
        kinds.add(null)
        np.testing.assert_allclose(ours[:3], np.array(bs.wo), atol=2e-6)
        np.testing.assert_allclose(ours[3:6], np.array(w), rtol=2e-5, atol=1e-6)
        assert ours[6] == pytest.approx(float(bs.pdf), rel=2e-5)
        assert ours[8] == pytest.approx(float(bs.eta), rel=1e-6)
    assert kinds == {True, False}


@pytest.mark.parametrize("xml,message", [
    ('<bsdf type="twosided"><bsdf type="roughdielectric"/></bsdf>', "twosided roughdielectric"),
    ('<bsdf type="twosided"><bsdf type="mask"><bsdf type="diffuse"/></bsdf></bsdf>',
     "twosided mask"),
    ('<bsdf type="twosided"><bsdf type="blendbsdf"><float name="weight" value="0.5"/>'
     '<bsdf type="diffuse"/><bsdf type="roughdielectric"/></bsdf></bsdf>', "twosided blendbsdf"),
    ('<bsdf type="blendbsdf"><float name="weight" value="0.5"/><bsdf type="diffuse"/>'
     '<bsdf type="plastic"/></bsdf>', "plastic inside a blendbsdf.*delta lobe"),
    # Mitsuba 3.9.1 weighs these blends' samples from below the surface wrongly (evidence:
    # test_mitsubas_blend_of_glass_and_a_one_sided_bsdf_is_misweighed_from_below)
    ('<bsdf type="blendbsdf"><float name="weight" value="0.5"/><bsdf type="diffuse"/>'
     '<bsdf type="roughdielectric"/></bsdf>', "a diffuse beside a roughdielectric"),
    ('<bsdf type="blendbsdf"><float name="weight" value="0.3"/><bsdf type="roughdielectric"/>'
     '<bsdf type="roughconductor"/></bsdf>', "a roughconductor beside a roughdielectric"),
    # a blend in a blend was told "BSDFs with a density", which it has (an outside review)
    ('<bsdf type="blendbsdf"><float name="weight" value="0.5"/><bsdf type="diffuse"/>'
     '<bsdf type="blendbsdf"><float name="weight" value="0.5"/><bsdf type="diffuse"/>'
     '<bsdf type="diffuse"/></bsdf></bsdf>', "blendbsdf inside a blendbsdf.*nests one level"),
    ('<bsdf type="blendbsdf"><bsdf type="diffuse"/><bsdf type="diffuse"/></bsdf>', "weight"),
    ('<bsdf type="blendbsdf"><float name="weight" value="0.5"/><bsdf type="diffuse"/></bsdf>',
     "exactly 2 nested"),
    ('<bsdf type="mask"><bsdf type="mask"><bsdf type="diffuse"/></bsdf></bsdf>',
     "mask inside a mask"),
    ('<bsdf type="roughdielectric"><float name="alpha_u" value="0.1"/></bsdf>',
     "both alpha_u and alpha_v"),
    ('<bsdf type="roughdielectric"><float name="alpha" value="0.1"/>'
     '<float name="alpha_u" value="0.1"/><float name="alpha_v" value="0.2"/></bsdf>',
     "both alpha_u and alpha_v"),
    ('<bsdf type="roughdielectric"><float name="alpha_v" value="-1"/>'
     '<float name="alpha_u" value="0.1"/></bsdf>', "alpha_v must be >= 0"),
    ('<bsdf type="roughconductor"><float name="alpha_u" value="0.1"/></bsdf>',
     "both alpha_u and alpha_v"),
    ('<bsdf type="mask"><bsdf type="normalmap"><texture type="bitmap" name="normalmap">'
     '<string name="filename" value="n.exr"/></texture><bsdf type="diffuse"/></bsdf></bsdf>',
     "a normalmap inside a mask"),
    ('<bsdf type="normalmap"><texture type="bitmap" name="normalmap"><string name="filename" '
     'value="n.exr"/></texture><bsdf type="mask"><bsdf type="diffuse"/></bsdf></bsdf>',
     "a mask inside a normalmap"),
    ('<bsdf type="normalmap"><texture type="bitmap" name="normalmap"><string name="filename" '
     'value="n.exr"/></texture></bsdf>', "exactly 1 nested"),
    ('<bsdf type="twosided"><bsdf type="normalmap"><texture type="bitmap" name="normalmap">'
     '<string name="filename" value="n.exr"/></texture><bsdf type="dielectric"/></bsdf></bsdf>',
     "twosided normalmap"),
    # Mitsuba's roughplastic refuses anisotropy; ours has no alpha_u/alpha_v at all
    ('<bsdf type="roughplastic"><float name="alpha_u" value="0.1"/>'
     '<float name="alpha_v" value="0.3"/></bsdf>', "alpha_u"),
    ('<bsdf type="roughdielectric"><float name="int_ior" value="1.2"/>'
     '<float name="ext_ior" value="1.2"/></bsdf>', "must differ"),
    ('<bsdf type="roughplastic"><float name="int_ior" value="1.2"/>'
     '<float name="ext_ior" value="1.2"/></bsdf>', "must differ"),
    # equal in float32, where Mitsuba holds them (it refuses them too: an outside review,
    # until 7 December accepted, a near-delta lobe that failed `check --scene`)
    ('<bsdf type="roughdielectric"><float name="int_ior" value="1.00000001"/>'
     '<float name="ext_ior" value="1"/></bsdf>', "equal in float32"),
    ('<bsdf type="roughplastic"><float name="int_ior" value="1.33"/>'
     '<float name="ext_ior" value="1.33000001"/></bsdf>', "equal in float32"),
    # a coat whose base is negative: Mitsuba's fit of F_int exceeds 1 above eta ~ 3.85
    # (int_ior 5 rendered 3 % off Mitsuba), and nonlinear r / (1 - r F_int) turns
    # negative for r >= 1 / F_int (diffuse 3: +695 %); the tracer ends such a path
    ('<bsdf type="plastic"><float name="int_ior" value="5"/></bsdf>',
     r"F_int = 1.07 .* r / \(1 - F_int\) infinite or negative"),
    ('<bsdf type="plastic"><boolean name="nonlinear" value="true"/>'
     '<float name="diffuse_reflectance" value="3"/></bsdf>', r"with r up to 3 \("),
    ('<bsdf type="roughplastic"><boolean name="nonlinear" value="true"/>'
     '<float name="diffuse_reflectance" value="1.6"/><float name="int_ior" value="2.5"/>'
     '</bsdf>', r"F_int = 0.859.* with r up to 1.6"),
])
def test_what_mitsuba_would_render_differently_is_refused(xml, message):
    from estimators.pathtracer import SceneError

    with pytest.raises(SceneError, match=message):
        _ours(xml)


_GLASS = ('<bsdf type="roughdielectric"><float name="int_ior" value="1.69"/>'
          '<float name="alpha" value="0.439"/><string name="distribution" value="ggx"/></bsdf>')


def _mean_sample_weight(mitsuba, variant, xml, wi, n, seed):
    """Mitsuba's mean sample weight (red) of ``xml`` at ``wi`` over n seeded samples in
    ``variant`` (drawn as one wavefront in a JIT variant), and its standard error."""
    import drjit as dr

    u = np.random.default_rng(seed).random((3, n))
    with mitsuba.variant_context(variant):
        bsdf = mitsuba.load_string(xml.replace("<bsdf ", '<bsdf version="3.0.0" ', 1))
        ctx = mitsuba.BSDFContext()
        if variant == "scalar_rgb":
            si = _si(mitsuba, wi)
            w = np.array([bsdf.sample(ctx, si, float(a), mitsuba.Point2f(float(b),
                                                                         float(c)))[1][0]
                          for a, b, c in u.T])
        else:
            si = dr.zeros(mitsuba.SurfaceInteraction3f, n)
            si.n = mitsuba.Normal3f(0, 0, 1)
            si.sh_frame = mitsuba.Frame3f(mitsuba.Vector3f(0, 0, 1))
            si.wi = mitsuba.Vector3f(*(float(x) for x in wi))
            si.uv = mitsuba.Point2f(0.3, 0.6)
            _, weight = bsdf.sample(ctx, si, mitsuba.Float(u[0]), mitsuba.Point2f(u[1], u[2]))
            w = np.array(weight)
            w = w[0] if w.shape[0] == 3 else w[:, 0]
    return w.mean(), w.std(ddof=1) / math.sqrt(n)


@pytest.mark.parametrize("other,wi", [('<bsdf type="diffuse"/>', (0.6, 0.0, -0.8)),
                                      ('<bsdf type="roughconductor"><float name="alpha" '
                                       'value="0.3"/></bsdf>', (0.954, 0.0, -0.3))])
def test_mitsubas_blend_of_glass_and_a_one_sided_bsdf_is_misweighed_from_below(mi, other,
                                                                                wi):
    """Evidence for the refusal above: from below the surface the one-sided BSDF scatters
    nothing (Mitsuba's blend evaluates to half the glass there), so a blend of weight 1/2
    has half the rough glass's albedo. Mitsuba 3.9.1's scalar variant samples average at
    it; its llvm variant's, which build the references, far above (0.88 against 0.70,
    0.94 against 0.41). Seeded (20000 llvm samples, 4000 scalar); the scalar mean within
    4 standard errors (α = 6e-5), the llvm one beyond 12 (chance 2e-33)."""
    import mitsuba

    from mcverify.gate import mitsuba as mvm

    if mvm.choose_variant().variant.startswith("scalar"):
        pytest.skip("Mitsuba's llvm variant, whose sampling is measured here, needs "
                    "libLLVM >= 16 (install libllvm19); without it the references are "
                    "built with scalar_rgb")
    wi = tuple(np.array(wi) / np.linalg.norm(wi))
    blend = f'<bsdf type="blendbsdf"><float name="weight" value="0.5"/>{_GLASS}{other}</bsdf>'
    ctx, si = mi.BSDFContext(), _si(mi, wi)
    one = {x: mi.load_string(x.replace("<bsdf ", '<bsdf version="3.0.0" ', 1))
           for x in (_GLASS, blend)}
    for wo in _sphere_directions(np.random.default_rng(0), 50):
        f_glass, f_blend = (np.array(one[x].eval(ctx, si, mi.Vector3f(*wo)))
                            for x in (_GLASS, blend))
        np.testing.assert_allclose(f_blend, f_glass / 2, rtol=1e-5, atol=1e-7)
    glass, se_glass = _mean_sample_weight(mitsuba, "llvm_ad_rgb", _GLASS, wi, 20000, 1)
    half, se_half = glass / 2, se_glass / 2
    scalar, se_scalar = _mean_sample_weight(mitsuba, "scalar_rgb", blend, wi, 4000, 2)
    assert abs(scalar - half) < 4 * math.hypot(se_scalar, se_half)
    llvm, se_llvm = _mean_sample_weight(mitsuba, "llvm_ad_rgb", blend, wi, 20000, 3)
    assert llvm - half > 12 * math.hypot(se_llvm, se_half)


def test_indices_equal_in_float32_are_refused_by_mitsuba_and_different_ones_not(mi):
    """Evidence for the float32 refusal above: Mitsuba refuses int_ior 1.00000001 against
    ext_ior 1, and takes 1.0000002 (the next float32 above 1 is 1 + 2^-23)."""
    with pytest.raises(RuntimeError, match="must be positive and differ"):
        mi.load_dict({"type": "roughdielectric", "int_ior": 1.00000001, "ext_ior": 1.0})
    mi.load_dict({"type": "roughdielectric", "int_ior": 1.0000002, "ext_ior": 1.0})
    _ours('<bsdf type="roughdielectric"><float name="int_ior" value="1.0000002"/>'
          '<float name="ext_ior" value="1"/></bsdf>')


def test_the_coat_bases_refused_are_negative_in_mitsuba(mi):
    """Evidence for the refusals above: Mitsuba's plastic of int_ior 5, and its nonlinear
    one of diffuse 3, evaluate to a negative value."""
    ctx, si = mi.BSDFContext(), _si(mi, (0.0, 0.0, 1.0))
    for props in ({"int_ior": 5.0}, {"nonlinear": True, "diffuse_reflectance": 3.0}):
        bsdf = mi.load_dict({"type": "plastic", **props})
        assert np.array(bsdf.eval(ctx, si, mi.Vector3f(0.6, 0.0, 0.8))).max() < 0


@pytest.mark.parametrize("prop", ["reflectance", "specular_transmittance"])
def test_a_texture_albedo_with_a_negative_texel_is_refused(mi, tmp_path, prop):
    """As a <float> below 0: an EXR texel below 0 as a BSDF's colour is refused, naming the
    file and texel (a texel negative in every channel rendered 0 here, where Mitsuba
    carries the negative albedo on); a blend weight's may be negative (it is clipped)."""
    from estimators.pathtracer import SceneError

    img = np.full((3, 4, 3), 0.5, np.float32)
    img[1, 2] = -0.25
    mi.Bitmap(img).write(str(tmp_path / "neg.exr"))
    tex = f'<texture type="bitmap" name="{prop}"><string name="filename" value="neg.exr"/>' \
          '</texture>'
    bsdf = {"reflectance": f'<bsdf type="diffuse">{tex}</bsdf>',
            "specular_transmittance": f'<bsdf type="dielectric">{tex}</bsdf>'}[prop]
    path = tmp_path / "scene.xml"
    path.write_text(_SCENE.format(bsdf=bsdf))
    with pytest.raises(SceneError, match=r"neg\.exr: texel \(row 1, column 2\) channel 0 is "
                                         rf"-0.25: as {prop}, a texture must be >= 0"):
        prepare_scene(str(path))
    path.write_text(_SCENE.format(bsdf=f'<bsdf type="blendbsdf">{tex.replace(prop, "weight")}'
                                       '<bsdf type="diffuse"/><bsdf type="roughplastic"/></bsdf>'))
    prepare_scene(str(path))
