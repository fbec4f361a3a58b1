"""Every feature the loader accepts is exercised by a reference scene whose render check
runs against Mitsuba in the default test run, and the README's matrix is the generated
one (so neither can drift from the loader)."""

import os
import re

import pytest

from estimators.pathtracer import coverage, layout
from estimators.pathtracer.scene import SUPPORTED

ROOT = os.path.join(os.path.dirname(__file__), "..", "..")
SCENES = os.path.join(ROOT, "reference", "scenes")
# the scenes whose render gate runs in the default test run: these, one gate run each
# below, cornell-box, rough-conductors and glass-sphere at two depths in
# tests/estimators/test_pathtracer_render.py, and bunny in tests/estimators/test_real_mesh.py
GATE_SCENES = ["delta-lights", "veach-mis", "textures", "vocabulary-materials",
               "vocabulary-lights", "vocabulary-geometry", "vocabulary-glass",
               "vocabulary-frame", "vocabulary-serialized", "vocabulary-spectra", "filters",
               "filters-tent", "filters-gaussian"]
GATED = set(GATE_SCENES) | {"cornell-box", "rough-conductors", "glass-sphere", "bunny"}


@pytest.mark.mitsuba
@pytest.mark.parametrize("name", GATE_SCENES)
def test_scene_passes_the_render_gate(name):
    """Our tracer against the committed Mitsuba reference at the gate's defaults
    (1024 spp in 16 passes, α = 0.01)."""
    import mcverify as mv

    r = mv.render_check(name, seed=21)
    assert r.passed, (r.summary(), r.details["found_by"])


def test_every_accepted_feature_is_in_a_gated_reference_scene():
    table, _ = coverage.reference_matrix(SCENES)
    missing = sorted(f for f, scenes in table.items() if not scenes & GATED)
    assert not missing, f"accepted but proven by no gated reference scene: {missing}"


def test_readme_matrix_is_the_generated_one():
    with open(os.path.join(ROOT, "README.md"), encoding="utf-8") as f:
        readme = f.read()
    m = re.search(r"<!-- coverage:begin -->\n(.*?)<!-- coverage:end -->", readme, re.S)
    assert m, "README.md has no <!-- coverage:begin --> ... <!-- coverage:end --> block"
    table, names = coverage.reference_matrix(SCENES)
    assert m.group(1) == coverage.markdown(table, names), \
        "regenerate: python -m estimators.pathtracer.coverage reference/scenes"


def test_no_image_effect_entries_name_real_properties():
    for kind, ptype, prop in coverage.NO_IMAGE_EFFECT:
        assert prop in SUPPORTED[kind][ptype]


def test_the_kernel_bits_and_the_planner_speak_the_loaders_vocabulary():
    """One vocabulary: the feature bits (apart from the lights-as-a-whole bits and the
    shading frame, which the preparation sets from what the BSDFs need) and every
    feature the scene planner maps to checks are features the loader accepts."""
    from mcverify.gate import plan

    accepted = coverage.accepted_features()
    bits = {n for n in layout.FEATURE_BITS if not n.startswith(("light:", "shading:"))}
    assert bits <= accepted
    assert set(plan.NEEDS) | set(plan.NOTHING_TO_SAMPLE) <= accepted
    # and the converse: every feature a scene's description can carry (`_features`: its
    # integrator, shapes, BSDFs, lights, textures) is planned or skipped with a reason
    # (a PLY area light planned no triangle sampling until 4 December)
    described = {f for f in accepted if f.split(":")[0] in ("integrator", "shape", "bsdf",
                                                            "emitter", "texture")
                 and not any(c in f for c in ".(=")}
    unplanned = {f for f in described if f not in plan.NEEDS and f not in
                 plan.NOTHING_TO_SAMPLE and f not in plan.UNLISTED_NAMES
                 and not f.startswith(plan.UNLISTED_PREFIXES)}
    assert not unplanned, unplanned


@pytest.mark.parametrize("xml,feature", [
    ('<bsdf type="diffuse"><texture type="bitmap" name="reflectance"><string name="filename" '
     'value="x.exr"/><string name="wrap_mode" value="mirror"/></texture></bsdf>',
     "texture:bitmap.wrap_mode=mirror"),
    ('<bsdf type="twosided"><bsdf type="plastic"/></bsdf>', "bsdf:twosided(plastic)"),
])
def test_exercised_names_what_a_scene_sets(xml, feature):
    from estimators.pathtracer import parse_scene

    desc = parse_scene('<scene version="3.0.0"><sensor type="perspective"/>'
                       f'<shape type="rectangle">{xml}</shape></scene>')
    assert feature in coverage.exercised(desc)


@pytest.mark.mitsuba
def test_an_ignored_filter_type_fails_the_gate_on_the_textures_scene():
    """The bug issue 12 found, planted again: every bitmap filtered bilinearly whatever
    its ``filter_type`` says. The nearest-filtered checker's edges differ pixel by pixel,
    so the block and pixel tests must see it (not only the image mean)."""
    import mcverify as mv

    r = mv.render_check("textures", seed=22, plant={"texture_filter": "bilinear"})
    assert not r.passed
    assert {"blocks", "pixels"} & set(r.details["found_by"]), r.details["found_by"]


@pytest.mark.mitsuba
def test_a_checkerboard_with_its_colours_swapped_fails_the_gate_on_the_textures_scene():
    """The sphere's checkerboard with colour0 and colour1 exchanged (as Mitsuba's float
    look-up has them): the texture's mean stays the same, only the cells tell it apart,
    and the default gate must fail it."""
    import mcverify as mv

    r = mv.render_check("textures", seed=22, plant={"checkerboard_swapped": True})
    assert not r.passed, r.summary()


@pytest.mark.mitsuba
@pytest.mark.parametrize("plant,what", [
    ({"camera_extent": 1.005}, "the orthographic view 0.5 % too wide"),
    ({"camera_extent": 0.995}, "the orthographic view 0.5 % too narrow"),
    ({"texture_raw": True}, "the JPEG's sRGB gamma ignored"),
])
def test_a_planted_geometry_bug_fails_the_gate(plant, what):
    """On the vocabulary-geometry scene (orthographic camera, PLY meshes, a JPEG texture):
    the view's extent off by 0.5 % (at most a sixth of a pixel at the film's edge) and
    the JPEG read without its sRGB decoding must both fail the default gate."""
    import mcverify as mv

    r = mv.render_check("vocabulary-geometry", seed=24, plant=plant)
    assert not r.passed, (what, r.summary())


@pytest.mark.mitsuba
@pytest.mark.parametrize("plant", [("roughdielectric", "alpha", 1.5),
                                   ("thindielectric", "eta", 1.15),
                                   ("mask", "mix", 0.75)],
                         ids=["rough-glass-alpha", "thin-window-eta", "mask-opacity"])
def test_a_wrong_glass_parameter_fails_the_gate_on_the_glass_scene(plant):
    """Planted bugs in the new BSDFs: every rough dielectric's α × 1.5, the thin window's
    η × 1.15, the float mask's opacity × 0.75; each must fail the default gate."""
    import mcverify as mv

    r = mv.render_check("vocabulary-glass", seed=23, plant={"bsdf_scale": plant})
    assert not r.passed, r.summary()


@pytest.mark.mitsuba
@pytest.mark.parametrize("plant", [{"swap_alpha_uv": True}, {"frame_ignored": True},
                                   {"bsdf_scale": ("roughconductor", "alpha_v", 0.7)},
                                   {"normalmap_ignored": True}],
                         ids=["alpha-uv-swapped", "frame-ignored", "roughconductor-alpha_v",
                              "normalmap-ignored"])
def test_wrong_frame_or_anisotropy_fails_the_gate_on_the_frame_scene(plant):
    """Planted bugs: every BSDF's alpha_u and alpha_v exchanged (the streaks turn by
    90°), the BSDFs shaded in a tangent frame of our own instead of Mitsuba's (the
    tracer before this scene: the streaks and the bumps turn), every rough conductor's
    alpha_v × 0.7, and the normal maps ignored; each must fail the default gate."""
    import mcverify as mv

    r = mv.render_check("vocabulary-frame", seed=25, plant=plant)
    assert not r.passed, r.summary()


@pytest.mark.mitsuba
def test_an_objs_default_v_flip_ignored_fails_the_gate(tmp_path):
    """A textured OBJ at Mitsuba's default ``flip_tex_coords`` (v read as 1 - v): the
    textures scene's card without its ``flip_tex_coords`` false. No reference scene has
    one (the textures scene's card sets false, panel.obj is an untextured light), so the
    bug of an OBJ loader that forgets the flip passed every gate until 7 December (an
    outside review: planted in the loader, the textures scene passed at p = 1). Ours
    against Mitsuba's reference made on the fly passes; the flip ignored fails."""
    import shutil

    import mcverify as mv

    src = os.path.join(SCENES, "textures")
    for name in ("card.obj", "checker.exr", "tiles.png"):
        shutil.copy(os.path.join(src, name), tmp_path / name)
    with open(os.path.join(src, "scene.xml")) as f:
        xml = f.read()
    unflip = '<boolean name="flip_tex_coords" value="false"/>'
    assert xml.count(unflip) == 1
    (tmp_path / "scene.xml").write_text(xml.replace(unflip, ""))
    r = mv.render_check(str(tmp_path / "scene.xml"), seed=26)
    assert r.passed, (r.summary(), r.details["found_by"])
    r = mv.render_check(str(tmp_path / "scene.xml"), seed=26,
                        plant={"tex_coords_unflipped": True})
    assert not r.passed, r.summary()
