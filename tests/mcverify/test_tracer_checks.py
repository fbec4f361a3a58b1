"""The path tracer's own BSDF and emitter instances, χ²-checked as the reference scenes
use them (``mcverify.gate.tracer_checks`` over ``estimators.pathtracer.sampling``).

Significance: every instance check of a test is one family; the family-wise level is
α = 0.01, Holm-corrected over the checks of the test. Seeds are fixed.
"""

import dataclasses
import glob
import os
import subprocess
import sys

import numpy as np
import pytest

import mcverify
from estimators.pathtracer import layout, prepare_scene
from estimators.pathtracer.sampling import (bsdf_sampler, bsdf_sampler_with_weight,
                                            emitter_sampler)
from mcverify.gate.reference import REFERENCE_ROOT
from mcverify.gate.tracer_checks import reference_points, tracer_checks
from mcverify.stats import holm

ALPHA = 0.01
SCENES = sorted(glob.glob(os.path.join(REFERENCE_ROOT, "*", "scene.xml")))
ROUGH = os.path.join(REFERENCE_ROOT, "rough-conductors", "scene.xml")


def _family_passes(checks, seed, pick=lambda c: True):
    chosen = [c for c in checks if pick(c)]
    results = [c.run(seed) for c in chosen]
    adjusted = holm([r.p_value for r in results])
    bad = [(r.name, p) for r, p in zip(results, adjusted) if p <= ALPHA]
    return len(chosen), bad


def _one_per_instance(checks):
    """The 45° BSDF check and the camera's emitter check of each instance."""
    seen, out = set(), []
    for c in checks:
        (kind, label), = c.verifies
        if (kind, label) in seen or (kind == "bsdf" and "@wi=45°" not in c.name):
            continue
        seen.add((kind, label))
        out.append(c)
    return out


def test_the_reference_scenes_plan_bsdf_and_emitter_instances():
    checks = []
    for path in SCENES:
        checks += _one_per_instance(tracer_checks(path, 2 ** 18)[0])
    assert {next(iter(c.verifies))[0] for c in checks} == {"bsdf", "emitter"}
    assert len(checks) >= 15


@pytest.mark.parametrize("path", SCENES, ids=lambda p: os.path.basename(os.path.dirname(p)))
def test_every_reference_instance_passes_at_2_18(path):
    """One family per scene (Holm over that scene's instances), so the test run's
    workers share the scenes."""
    n, bad = _family_passes(_one_per_instance(tracer_checks(path, 2 ** 18)[0]), seed=13)
    assert not bad, bad


@pytest.mark.slow
def test_every_planned_instance_passes_at_2_20():
    checks = []
    for path in SCENES:
        checks += tracer_checks(path, 2 ** 20)[0]
    n, bad = _family_passes(checks, seed=29)
    assert not bad, bad


def _alpha_changed(scene, b, factor):
    bf = scene.arrays.bsdf_f.copy()
    bf[b, [layout.ALPHA, layout.ALPHA_V]] *= factor
    return dataclasses.replace(scene, arrays=scene.arrays._replace(bsdf_f=bf))


@pytest.mark.parametrize("b, factor", [(2, 1.3), (5, 0.9)])
def test_alpha_changed_only_in_the_pdf_fails(b, factor):
    """A planted bug: the sampler draws with the scene's α, the pdf reads another."""
    scene = prepare_scene(ROUGH)
    wi = (np.sin(np.radians(45.0)), 0.0, np.cos(np.radians(45.0)))
    sample, _ = bsdf_sampler(scene, b, wi)
    _, wrong_pdf = bsdf_sampler(_alpha_changed(scene, b, factor), b, wi)
    r = mcverify.check_sampler(sample, wrong_pdf, "sphere", rejection=True, sample_dim=3,
                               n_samples=2 ** 18, seed=3, alpha=ALPHA)
    assert not r.passed


def test_emitter_pdf_of_another_reference_point_fails():
    """A planted bug: an area light sampled from one point, its pdf taken at another."""
    scene = prepare_scene(ROUGH)
    sample, _ = emitter_sampler(scene, 0, (0.0, 1.0, 0.0))
    _, wrong_pdf = emitter_sampler(scene, 0, (0.0, 0.8, 0.0))
    r = mcverify.check_sampler(sample, wrong_pdf, "sphere", rejection=True, sample_dim=3,
                               n_samples=2 ** 18, seed=3, alpha=ALPHA)
    assert not r.passed


def test_delta_instances_are_skipped_with_a_reason():
    checks, skipped = tracer_checks(os.path.join(REFERENCE_ROOT, "delta-lights", "scene.xml"))
    reasons = dict(skipped)
    assert any("point" in k and "delta emitter" in why for k, why in reasons.items())
    assert not any("point" in c.name for c in checks)
    _, skipped = tracer_checks(os.path.join(REFERENCE_ROOT, "cornell-box", "scene.xml"))
    assert any("dielectric" in k and "delta BSDF" in why for k, why in skipped)


def _scene_head(origin: str, target: str) -> str:
    """A test scene's opening: the path integrator and a 4 × 4 camera at ``origin``
    looking at ``target`` (which the plan's reference points derive from)."""
    return ('<scene version="3.0.0">\n  <integrator type="path"/>\n'
            '  <sensor type="perspective"><float name="fov" value="40"/>\n'
            f'    <transform name="to_world"><lookat origin="{origin}" target="{target}" '
            'up="0, 1, 0"/></transform>\n'
            '    <sampler type="independent"><integer name="sample_count" value="4"/>'
            '</sampler>\n'
            '    <film type="hdrfilm"><integer name="width" value="4"/><integer name="height" '
            'value="4"/></film>\n  </sensor>\n')


_BACKLIT = _scene_head("{cam}", "0, 0, -2") + """\
  <shape type="rectangle"><transform name="to_world"><scale value="4"/><translate z="-2"/></transform>
    <bsdf type="diffuse"/></shape>
  <shape type="rectangle"><transform name="to_world"><scale value="0.5"/><rotate y="1" angle="180"/>
    <translate y="0.5" z="-1"/></transform>
    <emitter type="area"><rgb name="radiance" value="10, 10, 10"/></emitter></shape>
  <shape type="sphere"><float name="radius" value="9"/>
    <emitter type="area"><rgb name="radiance" value="1, 1, 1"/></emitter></shape>
</scene>"""


def test_emitters_seen_from_behind_or_from_one_point_plan_and_pass(tmp_path):
    """An outside review: a one-sided light facing away from a reference point rejects
    every draw, where its pdf has no mass, and the check failed with "no valid samples to
    test" on a correct tracer; a camera at the centre of the bounds (inside a sphere
    light centred there) planned three checks under one name. Now such a check passes,
    saying it tested nothing else, and coinciding points are checked once."""
    scene = tmp_path / "backlit.xml"
    scene.write_text(_BACKLIT.format(cam="0, 0, 0"))
    checks, _ = tracer_checks(str(scene), 2 ** 14)
    names = [c.name for c in checks if ".emitter:" in c.name]
    assert len(names) == len(set(names)), names
    sphere = [n for n in names if "sphere" in n]
    # all three coincide, inside the sphere (its back side), and a point outside it, which
    # sees its front (9 + half the bounds' diagonal above its centre), is added
    assert [n.split("@")[1] for n in sphere] == ["ref=(0,0,0)", "ref=(0,0,24.6)"], names
    n, bad = _family_passes(checks, seed=3, pick=lambda c: ".emitter:" in c.name)
    assert n == len(names) and not bad, bad
    back = [c.run(3) for c in checks if ".emitter:" in c.name and "triangles" in c.name]
    assert any(r.passed and any("draws was rejected" in m for m in r.messages)
               for r in back), [r.summary() for r in back]


_AIMED_AWAY = _scene_head("0, 0, 5", "0, 0, 0") + """\
  <shape type="rectangle"><transform name="to_world"><rotate x="1" angle="90"/><scale value="3"/>
    <translate y="2"/></transform><bsdf type="diffuse"/></shape>
  <shape type="rectangle"><transform name="to_world"><rotate x="1" angle="-90"/><scale value="3"/>
    <translate y="-1"/></transform><bsdf type="diffuse"/></shape>
  <shape type="LIGHT">FLIP<transform name="to_world"><rotate x="1" angle="ANGLE"/>
    <translate y="1.5"/></transform><emitter type="area"><rgb name="radiance" value="5"/></emitter></shape>
</scene>"""


@pytest.mark.parametrize("light,angle,flip", [("rectangle", -90, False), ("disk", -90, False),
                                              ("rectangle", 90, True)])
def test_a_light_aimed_away_from_every_reference_point_is_checked_from_its_front(
        tmp_path, light, angle, flip):
    """A light aimed at the ceiling (a bounce light), away from the camera, the centre of
    the bounds and the point between, rejects every draw from all three, where its pdf
    integrates to 0: its checks passed testing nothing, as would a sampler that never
    draws a point. A fourth reference point now stands in front of it, on the side the
    light's pdf says emits (flip_normals turns it), and its check tests the draws."""
    scene = tmp_path / "aimed.xml"
    scene.write_text(_AIMED_AWAY.replace("LIGHT", light).replace("ANGLE", str(angle)).replace(
        "FLIP", '<boolean name="flip_normals" value="true"/>' if flip else ""))
    checks, _ = tracer_checks(str(scene), 2 ** 16)
    emitter = [c for c in checks if ".emitter:" in c.name]
    assert len(emitter) == 4, [c.name for c in emitter]
    # 1.5 above the origin + half the bounds' diagonal (6 x 3 x 6: 4.5)
    front = [c for c in emitter if "@ref=(0,6,0)" in c.name]
    assert len(front) == 1, [c.name for c in emitter]
    results = {c.name: c.run(5) for c in emitter}
    tested = {n for n, r in results.items() if r.details.get("n_valid")}
    assert tested == {front[0].name}, {n: r.details.get("n_valid") for n, r in results.items()}
    assert all(r.passed for r in results.values()), [r.summary() for r in results.values()]
    # the light turned towards the camera: two of the points see it, no fourth is added
    scene.write_text(_AIMED_AWAY.replace("LIGHT", light).replace("ANGLE", "-20").replace(
        "FLIP", ""))
    assert len([c for c in tracer_checks(str(scene), 2 ** 16)[0]
                if ".emitter:" in c.name]) == 3


_FLIPPED_LAMP = _scene_head("0, 0, 5", "0, 0, 0") + """\
  <shape type="rectangle"><transform name="to_world"><rotate x="1" angle="-90"/><scale value="3"/>
    <translate y="-1"/></transform><bsdf type="diffuse"/></shape>
  <shape type="sphere"><float name="radius" value="0.2"/><point name="center" x="2" y="1.5" z="0"/>
    TRANSFORM<boolean name="flip_normals" value="FLIP"/>
    <emitter type="area"><rgb name="radiance" value="5"/></emitter></shape>
</scene>"""


@pytest.mark.parametrize("transform,flip", [("", "true"),
                                            ('<transform name="to_world"><scale x="-1"/>'
                                             '</transform>', "false")],
                         ids=["flip_normals", "mirrored"])
def test_a_sphere_light_shining_inwards_is_checked_from_its_centre(tmp_path, transform, flip):
    """An outside review: a small sphere light that shines on its inside (flip_normals, or
    a to_world that mirrors it, as Mitsuba renders it too) is seen from behind by every
    reference point outside it, and the fourth point its centre, where it emits, was never
    added: the direction from the centre to the centre was the one tried, which has no
    length, so all its checks passed testing nothing. The centre is now tried along a
    direction to the sphere's surface, and its check tests the draws. α = 0.01, Holm over
    the light's checks, seed 5."""
    scene = tmp_path / "lamp.xml"
    scene.write_text(_FLIPPED_LAMP.replace("TRANSFORM", transform).replace("FLIP", flip)
                     .replace('x="2" y="1.5"', 'x="-2" y="1.5"' if transform else 'x="2" y="1.5"'))
    emitter = [c for c in tracer_checks(str(scene), 2 ** 16)[0] if ".emitter:" in c.name]
    centre = [c for c in emitter if "@ref=(2,1.5,0)" in c.name]
    assert len(centre) == 1, [c.name for c in emitter]
    results = [c.run(5) for c in emitter]
    tested = [r.name for r in results if r.details.get("n_valid")]
    assert tested == [centre[0].name], [(r.name, r.details.get("n_valid")) for r in results]
    adjusted = holm([r.p_value for r in results])
    assert all(p > ALPHA for p in adjusted), list(zip([r.name for r in results], adjusted))


def test_a_plastic_at_grazing_incidence_passes_though_every_draw_is_its_delta_lobe():
    """At θ_i = 90° (wi_z = 6e-17) the plastic's Fresnel reflectance is 1: every draw
    goes to its specular lobe (NaN rows) and its diffuse part keeps 1e-16 of the mass.
    The check failed this correct BSDF with "no valid samples to test" until 6 December;
    α = 0.01."""
    scene = prepare_scene(os.path.join(REFERENCE_ROOT, "vocabulary-materials", "scene.xml"),
                          params={"res": 8})
    b = list(scene.bsdf_names).index("twosided(plastic)")
    wi = (np.sin(np.pi / 2), 0.0, np.cos(np.pi / 2))
    r = mcverify.check_sampler(*bsdf_sampler(scene, b, wi), "sphere", n_samples=2 ** 16,
                               seed=1, rejection=True, sample_dim=3, alpha=ALPHA)
    assert r.passed, (r.summary(), r.failures, r.messages)
    assert r.details["rejection"]["accepted"] == 0


def test_front_ends_refuse_bad_input():
    scene = prepare_scene(ROUGH)
    with pytest.raises(ValueError, match="b=99"):
        bsdf_sampler(scene, 99, (0.0, 0.0, 1.0))
    with pytest.raises(ValueError, match="wi="):
        bsdf_sampler(scene, 2, (0.0, 0.0, 2.0))
    with pytest.raises(ValueError, match="ref="):
        emitter_sampler(scene, 0, (0.0, np.nan, 0.0))
    sample, _ = bsdf_sampler(scene, 2, (0.0, 0.0, 1.0))
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        sample(np.zeros((4, 2)))
    # numpy's own "could not convert string to float" named no parameter
    with pytest.raises(ValueError, match="wi='abc': not numbers"):
        bsdf_sampler_with_weight(scene, 2, "abc")
    with pytest.raises(ValueError, match="ref=.*: not numbers"):
        emitter_sampler(scene, 0, ("a", 0, 0))
    with pytest.raises(ValueError, match="u=.*: not numbers"):
        sample([["a", "b", "c"]])
    # a complex u lost its imaginary part (a ComplexWarning), a None became a NaN row,
    # and a complex wi was read as its real part, each without an error, until 7 December
    with pytest.raises(ValueError, match="u: not numbers.*complex128"):
        sample(np.full((2, 3), 0.5 + 0.5j))
    with pytest.raises(ValueError, match=r"u=\[\[0.1, 0.2, None\]\]: not numbers.*object"):
        sample([[0.1, 0.2, None]])
    with pytest.raises(ValueError, match="wi=.*: not numbers.*complex128"):
        bsdf_sampler(scene, 2, (0.0, 0.0, 1.0 + 0j))
    _, pdf = emitter_sampler(scene, 0, (0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="direction=.*: not numbers.*complex128"):
        pdf(np.array([[0.0, 1.0, 1j]]))


def test_a_float32_unit_wi_is_taken_as_its_float64_normalisation():
    """A normalised float32 direction is off unit length by up to ~1e-7; with the float64
    tolerance (1e-9) it was refused ("expected a unit vector", its length not said). It
    is now normalised in float64; a float64 one off by the same is still refused, and the
    message gives the length."""
    scene = prepare_scene(ROUGH)
    v = np.array([0.3, 0.5, 0.8])
    w32 = (v / np.linalg.norm(v)).astype(np.float32)
    w32 = w32 * np.float32(1 + 1.2e-7)            # float32's rounding at most
    assert abs(np.linalg.norm(w32.astype(np.float64)) - 1.0) > 1e-9
    _, pdf = bsdf_sampler(scene, 2, w32)
    w64 = tuple(w32.astype(np.float64) / np.linalg.norm(w32.astype(np.float64)))
    _, pdf64 = bsdf_sampler(scene, 2, w64)
    wo = np.array([[0.0, 0.6, 0.8], [0.5, -0.5, np.sqrt(0.5)]])
    assert np.array_equal(pdf(wo), pdf64(wo))
    _, pdf_list = bsdf_sampler(scene, 2, list(w32))          # float32 scalars in a list
    assert np.array_equal(pdf_list(wo), pdf64(wo))
    with pytest.raises(ValueError, match=r"wi=.*its length is 1\.0000001"):
        bsdf_sampler(scene, 2, tuple(w32.astype(np.float64)))
    with pytest.raises(ValueError, match=r"its length is 1\.001"):
        bsdf_sampler(scene, 2, np.array([0.0, 0.0, 1.001], dtype=np.float32))


def test_a_direction_with_a_nan_coordinate_has_a_nan_density_as_in_the_warps():
    """The warps' rule (a NaN point, a NaN density: a broken sampler's NaN stays
    visible): the tracer's diffuse pdf of (NaN, 0, 1) was 1/π, an area light's 0, until
    6 December. A finite direction in the same call keeps its value."""
    scene = prepare_scene(os.path.join(REFERENCE_ROOT, "cornell-box", "scene.xml"),
                          params={"res": 8})
    d = np.array([[np.nan, 0.0, 1.0], [0.0, 0.6, 0.8]])
    _, pdf, f = bsdf_sampler_with_weight(scene, 1, (0.0, 0.0, 1.0))
    assert np.isnan(pdf(d)[0]) and np.all(np.isnan(f(d)[0]))
    assert pdf(d)[1] == pytest.approx(0.8 / np.pi)
    _, pdf = emitter_sampler(scene, 0, (0.0, 0.0, 0.0))
    up = np.array([[0.0, 1.0, np.nan], [0.0, 1.0, 0.0]])
    assert np.isnan(pdf(up)[0]) and pdf(up)[1] > 0.0


def test_front_ends_take_a_scene_path_as_render_does():
    """An outside review: ``bsdf_sampler(path, ...)`` raised a bare AttributeError ('str'
    object has no attribute 'arrays'); the front ends now prepare what they are given, as
    ``render`` does, with the same results as from the prepared scene, and a missing file
    is a SceneError naming it."""
    from estimators.pathtracer import SceneError
    from estimators.pathtracer.sampling import emitter_sampler_with_weight

    scene = prepare_scene(ROUGH)
    u = np.random.default_rng(1).random((64, 3))
    for make in (lambda s: bsdf_sampler(s, 2, (0.0, 0.6, 0.8))[0],
                 lambda s: emitter_sampler_with_weight(s, 0, (0.0, 1.2, 5.0))[0]):
        want, got = make(scene)(u), make(ROUGH)(u)
        for w, g in zip(want if isinstance(want, tuple) else (want,),
                        got if isinstance(got, tuple) else (got,)):
            np.testing.assert_array_equal(g, w)
    with pytest.raises(SceneError, match="nope.xml"):
        emitter_sampler("nope.xml", 0, (0.0, 0.0, 0.0))


def test_front_ends_draw_nan_rows_for_a_u_outside_the_unit_cube():
    """An outside review: ``bsdf_sampler``'s sample(u) gave a direction for u = 1.5 or
    -0.5 (the kernel reads any number), where the warps' front ends give NaN; now a row
    with a coordinate outside [0, 1] is a NaN row (NaN already was), the others as
    before, in the weighted front ends too."""
    scene = prepare_scene(ROUGH)
    u = np.array([[0.3, 0.4, 0.5], [1.5, 0.4, 0.5], [0.3, -0.5, 0.5], [0.3, 0.4, 1.0 + 1e-12],
                  [0.6, 0.2, 0.7]])
    ok = np.array([True, False, False, False, True])
    for sample in (bsdf_sampler(scene, 2, (0.0, 0.6, 0.8))[0],
                   bsdf_sampler_with_weight(scene, 2, (0.0, 0.6, 0.8))[0],
                   emitter_sampler(scene, 0, (0.0, 1.2, 5.0))[0]):
        out = sample(u)
        wo = out[0] if isinstance(out, tuple) else out
        assert np.all(np.isnan(wo[~ok])), wo
        assert np.all(np.isfinite(wo[ok])), wo
        again = sample(u[ok])
        np.testing.assert_array_equal(again[0] if isinstance(again, tuple) else again,
                                      wo[ok])


def test_cli_plan_lists_the_four_rough_conductors():
    r = subprocess.run([sys.executable, "-m", "mcverify", "plan", ROUGH], capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    labels = {line.strip().split("@")[0] for line in r.stdout.splitlines()
              if line.strip().startswith("sampler:tracer.bsdf:") and "roughconductor" in line}
    assert labels == {
        "sampler:tracer.bsdf:rough-conductors/bsdf2:roughconductor(ggx,alpha=0.01)",
        "sampler:tracer.bsdf:rough-conductors/bsdf3:roughconductor(ggx,alpha=0.1)",
        "sampler:tracer.bsdf:rough-conductors/bsdf4:roughconductor(beckmann,alpha=0.3)",
        "sampler:tracer.bsdf:rough-conductors/bsdf5:roughconductor(beckmann,alpha=0.5)"}


GLASS = os.path.join(REFERENCE_ROOT, "vocabulary-glass", "scene.xml")


def _rows_of(scene, kind):
    return [b for b, name in enumerate(scene.bsdf_names) if name == kind]


def test_glass_instances_are_planned_from_both_sides():
    """Rough dielectrics, and the blend and mask that hold BSDFs, are checked as a whole
    and from below where light arrives from below; the thin window has no density."""
    checks, skipped = tracer_checks(GLASS)
    names = [c.name for c in checks]
    assert any("roughdielectric(ggx,alpha=0.15,eta=1.505)@wi=100°" in n for n in names)
    assert any("blendbsdf(weight=0.4," in n and "@wi=135°" in n for n in names)
    assert any(":mask(opacity=texture,bsdf" in n and "@wi=180°" in n for n in names)
    assert any(":mask(opacity=0.35," in n for n in names)
    assert not any(":mask(opacity=0.35," in n and "@wi=180°" in n for n in names)
    assert any("thindielectric" in k and "delta BSDF" in why for k, why in skipped)


def test_every_glass_instance_passes_at_2_16():
    checks = tracer_checks(GLASS, 2 ** 16)[0]
    n, bad = _family_passes(checks, seed=17)
    assert n >= 30 and not bad, bad


@pytest.mark.parametrize("kind, column, factor, wi_deg", [
    ("roughdielectric", layout.ALPHA, 1.3, 45.0),     # the rough glass sphere
    ("roughdielectric", layout.ETA, 1.05, 135.0),     # ... seen from inside
    ("blendbsdf", layout.MIX, 1.25, 45.0),            # the plastic/glass blend's weight
    ("mask", layout.MIX, 0.8, 45.0),                  # the copper disk's opacity
])
def test_a_parameter_changed_only_in_the_pdf_fails(kind, column, factor, wi_deg):
    """Planted bugs in the new BSDFs: the sampler draws with the scene's parameter, the
    pdf reads another."""
    scene = prepare_scene(GLASS)
    b = next(r for r in _rows_of(scene, kind) if scene.arrays.bsdf_f[r, column] != 0)
    bf = scene.arrays.bsdf_f.copy()
    bf[b, [column, layout.ALPHA_V] if column == layout.ALPHA else column] *= factor
    wrong = dataclasses.replace(scene, arrays=scene.arrays._replace(bsdf_f=bf))
    t = np.radians(wi_deg)
    wi = (np.sin(t), 0.0, np.cos(t))
    sample, _ = bsdf_sampler(scene, b, wi)
    _, wrong_pdf = bsdf_sampler(wrong, b, wi)
    r = mcverify.check_sampler(sample, wrong_pdf, "sphere", rejection=True, sample_dim=3,
                               n_samples=2 ** 18, seed=3, alpha=ALPHA)
    assert not r.passed


FRAME = os.path.join(REFERENCE_ROOT, "vocabulary-frame", "scene.xml")


def test_anisotropic_instances_pass_and_are_checked_off_axis():
    """Every anisotropic BSDF of the frame scene, χ²-checked with wi at φ = 30° (off both
    roughness axes) from above, and from below for the glass."""
    checks = tracer_checks(FRAME, 2 ** 16)[0]
    aniso = [c for c in checks if "alpha_u=" in c.name]
    assert len(aniso) == 3 * 3 + 2 * 6
    assert all("phi=30°" in c.name for c in aniso)
    n, bad = _family_passes(aniso, seed=19)
    assert not bad, bad


def _wrong_pdf_is_rejected(scene, b, wrong_scene, wrong_b):
    """χ² of BSDF ``b``'s sampler against row ``wrong_b``'s pdf in ``wrong_scene``, with
    wi at 45° and φ = 30° (off both roughness axes): whether the check rejects it."""
    t, p = np.radians(45.0), np.radians(30.0)
    wi = (np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t))
    sample, _ = bsdf_sampler(scene, b, wi)
    _, wrong_pdf = bsdf_sampler(wrong_scene, wrong_b, wi)
    r = mcverify.check_sampler(sample, wrong_pdf, "sphere", rejection=True, sample_dim=3,
                               n_samples=2 ** 18, seed=3, alpha=ALPHA)
    return not r.passed


@pytest.mark.parametrize("kind", ["roughconductor", "roughdielectric"])
def test_alpha_u_and_v_swapped_only_in_the_pdf_fails(kind):
    """A planted bug: the sampler draws with (alpha_u, alpha_v), the pdf reads them
    exchanged."""
    scene = prepare_scene(FRAME)
    b = next(r for r in _rows_of(scene, kind)
             if scene.arrays.bsdf_f[r, layout.ALPHA] != scene.arrays.bsdf_f[r, layout.ALPHA_V])
    assert _wrong_pdf_is_rejected(scene, b, scene.planted(swap_alpha_uv=True), b)


def test_a_normal_map_ignored_only_in_the_pdf_fails():
    """A planted bug: the sampler draws in the normal map's perturbed frame, the pdf is
    the held BSDF's in the unperturbed one."""
    scene = prepare_scene(FRAME)
    b = _rows_of(scene, "normalmap")[0]
    held = int(scene.arrays.bsdf_i[b, layout.BSDF_CHILD0])
    assert _wrong_pdf_is_rejected(scene, b, scene, held)


_MESH_LIGHT = _scene_head("0, 1.2, 5", "0, 0.3, 0") + """\
  <shape type="rectangle"><transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/>
    <translate y="-0.5"/></transform><bsdf type="diffuse"/></shape>
  <shape type="obj"><string name="filename" value="lamp.obj"/>{extra}
    <emitter type="area"><rgb name="radiance" value="5, 5, 5"/></emitter></shape>
</scene>"""


#: Two quads of one OBJ light, both facing down, the lower one smaller.
STACKED_QUADS = ("v -0.5 2.5 -0.5\nv 0.5 2.5 -0.5\nv 0.5 2.5 0.5\nv -0.5 2.5 0.5\n"
                 "v -0.3 2.2 -0.3\nv 0.3 2.2 -0.3\nv 0.3 2.2 0.3\nv -0.3 2.2 0.3\n"
                 "f 1 2 3 4\nf 5 6 7 8\n")


def _mesh_light_checks(tmp_path, obj, extra=""):
    (tmp_path / "lamp.obj").write_text(obj)
    scene = tmp_path / "lamp.xml"
    scene.write_text(_MESH_LIGHT.format(extra=extra))
    checks, _ = tracer_checks(str(scene), 2 ** 18)
    return [c for c in checks if ".emitter:" in c.name]


def test_a_bent_mesh_light_with_smooth_normals_passes(tmp_path):
    """An outside review: an OBJ light without normals gets smooth vertex normals (as in
    Mitsuba), and its samples' pdf takes the cosine at the interpolated normal (Mitsuba's
    ``Mesh::sample_position``), which is not the density of the sampled directions where
    the mesh bends: the check failed (p = 0) on a tracer that renders as Mitsuba. Such a
    light is now checked with its face normals, and says so in its name."""
    bent = "v -0.5 2.5 -0.5\nv 0.5 2.5 -0.5\nv 0 2.5 0.5\nv 0 2.2 0\nf 1 3 2\nf 1 2 4\n"
    checks = _mesh_light_checks(tmp_path, bent)
    assert len(checks) == 3 and all("triangles(face normals)@" in c.name for c in checks)
    n, bad = _family_passes(checks, seed=5)
    assert not bad, bad
    flat = _mesh_light_checks(tmp_path, bent, '<boolean name="face_normals" value="true"/>')
    assert not any("face normals" in c.name for c in flat)


#: A small dome of six faces around -y (the apex below, the ring above), its file's
#: smooth normals facing down and out; its faces are wound the other way, as a mesh
#: mirrored in to_world (or exported so) is: the winding gives face normals facing up.
DOME_AGAINST_ITS_NORMALS = "v 0 2.2 0\n" + "".join(
    f"v {0.5 * np.cos(a):.6f} 2.5 {0.5 * np.sin(a):.6f}\n"
    for a in np.linspace(0.0, 2 * np.pi, 7)[:-1]) + "vn 0 -1 0\n" + "".join(
    f"vn {0.6 * np.cos(a):.6f} -0.8 {0.6 * np.sin(a):.6f}\n"
    for a in np.linspace(0.0, 2 * np.pi, 7)[:-1]) + "".join(
    f"f 1//1 {(j + 1) % 6 + 2}//{(j + 1) % 6 + 2} {j + 2}//{j + 2}\n" for j in range(6))


def test_a_mesh_light_wound_against_its_normals_is_checked_from_its_emitting_side(tmp_path):
    """An outside review: a mesh light whose vertex normals lean off its faces is checked
    with face normals, and those were the winding's, facing up, where the file's normals
    (which the renderer emits along, as Mitsuba does) face down: from the scene's centre,
    below the dome and lit by all of it, every draw was rejected ("the pdf integrates to
    0: consistent, nothing else to test"), a check that could not fail. The face normals
    now face the side the vertex normals give, and every point that sees the light's
    emitting side tests draws. α = 0.01, Holm over the light's checks, seed 5."""
    checks = _mesh_light_checks(tmp_path, DOME_AGAINST_ITS_NORMALS)
    scene = prepare_scene(str(tmp_path / "lamp.xml"))
    centre = reference_points(scene)[1]
    assert 0.0 < centre[1] < 2.2    # below the apex, which emits towards it
    assert emitter_sampler(scene, 0, centre)[1](np.array([[0.0, 1.0, 0.0]]))[0] > 0.0
    assert checks and all("triangles(face normals)@" in c.name for c in checks)
    results = [c.run(5) for c in checks]
    empty = [r.name for r in results if r.details.get("n_valid", 1) == 0]
    assert not empty, empty
    adjusted = holm([r.p_value for r in results])
    assert all(p > ALPHA for p in adjusted), list(zip([r.name for r in results], adjusted))


def test_a_mesh_light_hiding_part_of_itself_passes(tmp_path):
    """An outside review: two stacked quads of one OBJ light, both facing down; from
    below the lower one hides part of the upper one. The sampler draws points by area
    without a visibility test, so both add to a direction's density, but the check's pdf
    took the nearest hit only: the check failed (p = 0) on a correct tracer. The pdf now
    sums every front-facing hit along the ray."""
    checks = _mesh_light_checks(tmp_path, STACKED_QUADS)
    assert len(checks) == 3
    n, bad = _family_passes(checks, seed=5)
    assert not bad, bad


_EDGE_ON = _scene_head("0.3, 0.2, 6", "0, 0, 0") + """\
  <shape type="rectangle"><transform name="to_world"><rotate x="1" angle="90"/></transform>
    <emitter type="area"><rgb name="radiance" value="1, 1, 1"/></emitter></shape>
  <shape type="disk"><transform name="to_world"><rotate x="1" angle="90"/><translate y="-2"/>
    </transform><emitter type="area"><rgb name="radiance" value="1, 1, 1"/></emitter></shape>
  <shape type="rectangle"><transform name="to_world"><rotate x="1" angle="90"/><translate y="2"/>
    </transform></shape>
  <shape type="sphere"><float name="radius" value="1"/><point name="center" x="0" y="-1" z="0"/>
    <emitter type="area"><rgb name="radiance" value="1, 1, 1"/></emitter></shape>
</scene>"""


def test_a_reference_point_on_a_light_is_skipped_for_that_light(tmp_path):
    """An outside review: the centre of the scene's bounds, (0, 0, 0), lies in the plane
    of a rectangle light (and on a sphere light's surface). From there the rectangle is
    seen edge-on: the cosine at its sampled points is rounding noise (half the draws
    accepted, by its sign), and the pdf's rays along the plane meet nothing: the check
    failed (p = 0, "samples fell in cells where the pdf integrates to 0") on a correct
    tracer. Such a point is now skipped for that light, with the reason; the light is
    checked from the other points."""
    scene = tmp_path / "edge.xml"
    scene.write_text(_EDGE_ON)
    checks, skipped = tracer_checks(str(scene), 2 ** 16)
    on = [k for k, why in skipped if "on the light's own surface" in why]
    assert sorted(on) == ["emitter edge/light0:area:triangles@ref=(0,0,0)",
                          "emitter edge/light2:area:sphere@ref=(0,0,0)"], skipped
    emitters = [c for c in checks if ".emitter:" in c.name]
    assert [c.name for c in emitters if "@ref=(0,0,0)" in c.name] == \
        ["sampler:tracer.emitter:edge/light1:area:disk@ref=(0,0,0)"]
    assert any("light0" in c.name for c in emitters)
    # both planar lights face down, away from every other point: each is also checked
    # from a point below it (until 7 December those checks tested nothing)
    assert {c.name.split("/")[1] for c in emitters if "-" in c.name.split("@")[1]} == \
        {"light0:area:triangles@ref=(0,-2.45,0)", "light1:area:disk@ref=(0,-4.45,0)"}
    n, bad = _family_passes(emitters, seed=4)
    assert n == 9 and not bad, bad


_ROUGH_GLASS = _scene_head("0, 1, 5", "0, 0, 0") + """\
  <shape type="sphere"><float name="radius" value="0.5"/>
    <bsdf type="roughdielectric"><float name="int_ior" value="1.5"/>
      <float name="alpha" value="{alpha}"/>
      <string name="distribution" value="beckmann"/>{visible}</bsdf></shape>
  <shape type="sphere"><float name="radius" value="9"/>
    <emitter type="area"><rgb name="radiance" value="1, 1, 1"/></emitter></shape>
</scene>"""


@pytest.mark.parametrize("alpha,visible", [
    (2.0, ""), (5.0, '<boolean name="sample_visible" value="false"/>')])
def test_a_very_rough_beckmann_glass_passes_at_grazing_incidence(tmp_path, alpha, visible):
    """An outside review: a Beckmann normal is drawn from D cos θ_m, which can face away
    from wi; the sampler refracted wi through such a normal and kept the direction, which
    eval (from the half vector, another normal) gives a positive pdf, so a rough glass of
    α = 2 failed at θ_i = 80° (accepted 0.62 of the draws, pdf integrating to 0.47):
    extra transmitted light in renders. Now such a draw is rejected (G1 = 0, as Mitsuba's
    weight is); α = 0.01 over the instance's six checks (Holm)."""
    scene = tmp_path / "glass.xml"
    scene.write_text(_ROUGH_GLASS.format(alpha=alpha, visible=visible))
    checks, _ = tracer_checks(str(scene), 2 ** 18)
    n, bad = _family_passes(checks, seed=5, pick=lambda c: "roughdielectric" in c.name)
    assert n == 6 and not bad, bad


def test_each_instance_check_names_where_the_scene_file_declares_it(tmp_path):
    """An outside review: a failing instance check named its BSDF by row (``bsdf1``), which
    the user had to count out of the file (rows include Mitsuba's default diffuse and the
    children of composites). Now every result's first message says where: the file, the
    line and the element."""
    from mcverify.gate.tracer_checks import consistency_checks

    scene = tmp_path / "glass.xml"
    scene.write_text(_ROUGH_GLASS.format(alpha=0.3, visible=""))
    lines = scene.read_text().splitlines()
    bsdf = 1 + next(i for i, t in enumerate(lines) if '<bsdf type="roughdielectric">' in t)
    light = 1 + next(i for i, t in enumerate(lines) if '<emitter type="area">' in t)
    checks, _ = tracer_checks(str(scene), 2 ** 12)
    by_name = {c.name: c for c in checks + consistency_checks(str(scene), 2 ** 10)}
    for prefix in ("sampler", "pdf_consistency"):
        glass = next(c for n, c in by_name.items()
                     if n.startswith(prefix) and "roughdielectric" in n)
        assert glass.run(1).messages[0] == (
            f'declared at {scene}:{bsdf}: <bsdf type="roughdielectric">')
        lamp = next(c for n, c in by_name.items() if n.startswith(prefix) and ".emitter:" in n)
        assert lamp.run(1).messages[0] == f'declared at {scene}:{light}: <emitter type="area">'
    default = next(c for n, c in by_name.items() if ":diffuse@" in n)
    assert "Mitsuba's default diffuse" in default.run(1).messages[0]


def test_an_eta_near_1_is_labelled_with_the_digits_that_tell_it_from_1(tmp_path):
    """An outside review: a rough dielectric at int_ior 1.0001 over ext_ior 1 (a known
    limit of the chi-square binning, README) failed as ``roughdielectric(beckmann,
    alpha=0.001,eta=1)``, eta printed to 4 significant digits: a value Mitsuba refuses,
    and not the scene's. It reads eta=1.0001 now (0.9999 below 1); eta=1.505 is as
    before."""
    glass = ('  <shape type="sphere"><bsdf type="roughdielectric"><float name="alpha" '
             'value="0.001"/><float name="int_ior" value="{eta}"/><float name="ext_ior" '
             'value="1"/></bsdf></shape>\n</scene>\n')
    for eta, want in (("1.0001", "eta=1.0001)"), ("0.9999", "eta=0.9999)"),
                      ("1.505", "eta=1.505)"), ("1.0000002", "eta=1.0000002)")):
        path = tmp_path / f"g{len(want)}{eta[-1]}.xml"
        path.write_text(_scene_head("0, 0, 4", "0, 0, 0") + glass.format(eta=eta))
        names = [c.name for c in tracer_checks(str(path))[0]]
        assert names and all(want in n for n in names), (eta, names[0])


def test_an_anisotropic_bsdf_before_an_isotropic_one_is_checked_at_its_own_azimuth(tmp_path):
    """An outside review: the instance checks' samplers read φ when they ran, not when
    they were made, so every BSDF took the azimuth of the scene's last BSDF row: an
    anisotropic rough conductor followed by a diffuse was checked (χ² and pdf
    consistency) with wi at φ = 0°, along its alpha_u axis, under the name
    ``@wi=45°,phi=30°``. A near-mirror's draws leave opposite wi, so their mean azimuth
    is the check's φ + 180°."""
    from mcverify.gate.tracer_checks import scene_instances

    scene = tmp_path / "aniso.xml"
    scene.write_text(_scene_head("0, 0, 4", "0, 0, 0") + """\
  <shape type="sphere"><bsdf type="roughconductor"><float name="alpha_u" value="0.01"/>
    <float name="alpha_v" value="0.02"/></bsdf></shape>
  <shape type="rectangle"><transform name="to_world"><translate z="-2"/></transform>
    <bsdf type="diffuse"/></shape>
</scene>
""")
    u = np.random.default_rng(4).random((2000, 3))
    found = 0
    for kind, label, where, make, make_weighted, _ in scene_instances(str(scene))[0]:
        if "roughconductor" not in label or where != "wi=45°,phi=30°":
            continue
        for wo in (make()[0](u), make_weighted()[0](u)[0]):
            wo = wo[~np.isnan(wo).any(axis=1)].mean(axis=0)
            assert np.degrees(np.arctan2(-wo[1], -wo[0])) == pytest.approx(30.0, abs=1.0)
        found += 1
    assert found == 1


def test_an_instance_check_draws_from_the_seed_and_the_count_it_is_given():
    """A mutation review: the instance checks' ``run(seed)`` with the seed not passed on
    to the judge (or ``n_samples`` not) passed every test, the gate's ``--seed`` then
    changing none of them. The same seed gives the same finding, another seed other
    draws, and each check draws the samples asked for."""
    from mcverify.gate.tracer_checks import consistency_checks

    sampler = tracer_checks(ROUGH, 4096)[0][1]
    consistent = consistency_checks(ROUGH, 1024)[1]
    for check, n in ((sampler, 4096), (consistent, 1024)):
        a, b, c = check.run(1), check.run(1), check.run(2)
        assert a.n_samples == n, (check.name, a.n_samples)
        assert a.p_value == b.p_value and a.details == b.details
        assert (a.p_value, a.statistic, a.details) != (c.p_value, c.statistic, c.details)
