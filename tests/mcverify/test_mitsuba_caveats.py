"""``mitsuba_caveats``: where Mitsuba 3.9.1's reference is known to be wrong, a failing
render gate says so. With ``hide_emitters`` Mitsuba computes the hit behind a skipped
area emitter from the camera ray (path.cpp after ``skip_area_emitters``), which a sphere
or disk turns into a wrong point (``ray(pi.t)``) and a mesh does not (its (u, v))."""

import numpy as np
import pytest

import mcverify as mv
from estimators.pathtracer.scene import load_scene
from mcverify.gate.render_check import _caveats, mitsuba_caveats

# A mirror behind a hidden disk light, under a white sky: a camera ray passing through the
# disk meets the mirror 0.1 behind it and is reflected onto the disk's dark back side.
SCENE = """<scene version="3.0.0">
  <default name="hide" value="true"/>
  <integrator type="path"><integer name="max_depth" value="2"/>
    <boolean name="hide_emitters" value="$hide"/></integrator>
  <sensor type="perspective"><float name="fov" value="40"/>
    <transform name="to_world"><lookat origin="0,0,4" target="0,0,0"/></transform>
    <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/>
      <rfilter type="box"/></film>
  </sensor>
  <emitter type="constant"/>
  {mirror}
  <shape type="disk"><transform name="to_world"><scale value="0.5"/><translate z="0.3"/></transform>
    <emitter type="area"><rgb name="radiance" value="0.3"/></emitter></shape>
</scene>
"""
SPHERE = ('<shape type="sphere"><float name="radius" value="0.8"/>'
          '<point name="center" x="0" y="0" z="-0.6"/><bsdf type="conductor"/></shape>')
# the same mirror's front as a mesh: a rectangle facing the camera 0.1 behind the disk
RECTANGLE = ('<shape type="rectangle"><transform name="to_world"><scale value="0.8"/>'
             '<translate z="0.2"/></transform><bsdf type="conductor"/></shape>')


def _scene(tmp_path, mirror, name="scene.xml"):
    folder = tmp_path / name.replace(".xml", "")
    folder.mkdir()
    path = folder / "scene.xml"
    path.write_text(SCENE.format(mirror=mirror))
    return str(path)


@pytest.mark.parametrize("mirror,params,said", [
    (SPHERE, None, "sphere"),
    (SPHERE.replace('type="sphere"', 'type="disk"').replace(
        '<float name="radius" value="0.8"/><point name="center" x="0" y="0" z="-0.6"/>',
        '<transform name="to_world"><translate z="0.2"/></transform>'), None, "disk"),
    (RECTANGLE, None, None),                    # a mesh: Mitsuba is right
    (SPHERE, {"hide": "false"}, None),          # nothing skipped
], ids=["sphere", "disk", "mesh", "not-hidden"])
def test_the_caveat_names_the_shapes_mitsuba_places_wrongly(tmp_path, mirror, params, said):
    notes = mitsuba_caveats(load_scene(_scene(tmp_path, mirror), params=params))
    if said is None:
        assert notes == []
    else:
        assert len(notes) == 1 and f"onto a {said}" in notes[0] and "hide_emitters" in notes[0]


def test_a_light_that_is_itself_a_sphere_is_no_caveat(tmp_path):
    # the emitter is skipped, not placed: only a sphere or disk that does not emit counts
    path = _scene(tmp_path, "")
    text = open(path).read().replace('<shape type="disk">', '<shape type="sphere">')
    open(path, "w").write(text)
    assert mitsuba_caveats(load_scene(path)) == []


@pytest.mark.mitsuba
def test_the_gate_fails_on_mitsubas_sphere_and_says_why_and_passes_the_mesh(tmp_path):
    """The centre of the mirror's image (rays through the disk's middle, reflected onto
    its back) is 0, as ours and Mitsuba's image of the mesh mirror show; Mitsuba's
    sphere shows the white sky there (an outside review: likewise at 32 × 32, and
    against a mesh sphere)."""
    wrong = mv.render_check(_scene(tmp_path, SPHERE, "sphere.xml"), spp=512, seed=1)
    assert not wrong.passed
    assert any(m.startswith("note: Mitsuba 3.9.1 may be wrong here") for m in wrong.messages)
    assert wrong.artifacts["ours"][7:9, 7:9].max() < 0.05 < 0.5 < wrong.artifacts[
        "mitsuba"][7:9, 7:9].min()
    right = mv.render_check(_scene(tmp_path, RECTANGLE, "rectangle.xml"), spp=512, seed=1)
    assert right.passed and not any(m.startswith("note:") for m in right.messages)
    assert np.abs(right.artifacts["mitsuba"][7:9, 7:9]).max() < 0.05


@pytest.mark.parametrize("lo,hi,noted", [
    ((-4e-3, -4e-3, -4e-3), (4e-3, 4e-3, 4e-3), True),     # a scene scaled by 1e-3
    ((-4.0, -4.0, -4.0), (4.0, 4.0, 4.0), False),          # the same at scale 1
    ((-4e3, -4e3, -4e3), (4e3, 4e3, 4e3), False),          # and at 1e3
    ((1e4, 0.0, 0.0), (1e4 + 1.0, 1.0, 1.0), True),        # unit size far from the origin
])
def test_a_scene_small_against_mitsubas_ray_offset_is_noted(lo, hi, noted):
    """Mitsuba starts each ray from a surface (1 + max|p|) · 1500 · 2^-24 off it (its
    interaction.h ``offset_p``), at least 8.9e-5 however small the scene: an outside
    review's scene scaled by 1e-3 failed the gate on three seeds while Mitsuba's own
    image of it differed from its image at scale 1 by 15 standard errors in the failing
    block (ours matched both)."""
    notes = mitsuba_caveats(None, (np.array(lo), np.array(hi)))
    assert (len(notes) == 1 and "ray from a surface" in notes[0]) == noted
    assert len(notes) == noted


def test_the_gate_measures_the_scene_it_renders(tmp_path):
    # the hide_emitters scene above, scaled by 1e-3 (camera, mirror and light): both notes
    path = _scene(tmp_path, SPHERE)
    text = open(path).read()
    small = text.replace('origin="0,0,4"', 'origin="0,0,0.004"').replace(
        '<float name="radius" value="0.8"/><point name="center" x="0" y="0" z="-0.6"/>',
        '<float name="radius" value="0.0008"/><point name="center" x="0" y="0" '
        'z="-0.0006"/>').replace('<scale value="0.5"/><translate z="0.3"/>',
                                 '<scale value="0.0005"/><translate z="0.0003"/>')
    open(path, "w").write(small)
    notes = _caveats(path, None, None)
    assert len(notes) == 2 and "ray from a surface" in notes[0] and "onto a sphere" in notes[1]
    open(path, "w").write(text)
    assert len(_caveats(path, None, None)) == 1


# A floor seen from above, 16² at 64 spp: the scenes of the notes below add to it
FLOOR = """<scene version="3.0.0">
  {defaults}
  <integrator type="path">{integrator}</integrator>
  <sensor type="perspective"><float name="fov" value="45"/>
    <transform name="to_world"><lookat origin="0,1.5,4" target="0,0.3,0"/></transform>
    <sampler type="independent"><integer name="sample_count" value="64"/></sampler>
    <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/>
      <rfilter type="box"/></film>
  </sensor>
  <shape type="rectangle"><transform name="to_world"><scale value="3"/>
    <rotate x="1" angle="-90"/><translate y="-0.5"/></transform></shape>
  {body}
</scene>
"""
# ... under a small light of fixed power (radiance 1 / r²), 1.5 above it
SMALL_LIGHT = FLOOR.format(
    defaults='<default name="r" value="0.001"/>\n  <default name="L" value="1e6"/>',
    integrator='<integer name="max_depth" value="2"/>\n    <boolean name="hide_emitters" '
               'value="true"/>', body="{light}")
SMALL_SPHERE = ('<shape type="sphere"><float name="radius" value="$r"/><point name="center" '
                'x="-0.5" y="1" z="0.5"/><emitter type="area"><rgb name="radiance" '
                'value="$L"/></emitter></shape>')
SMALL_DISK = ('<shape type="disk"><transform name="to_world"><scale value="$r"/><rotate x="1" '
              'angle="90"/><translate x="-0.5" y="1" z="0.5"/></transform><emitter '
              'type="area"><rgb name="radiance" value="$L"/></emitter></shape>')


@pytest.mark.parametrize("light,r,noted", [
    (SMALL_SPHERE, "0.001", True),      # Mitsuba 11 % bright (image mean)
    (SMALL_SPHERE, "1e-4", True),       # Mitsuba black
    (SMALL_SPHERE, "0.01", False),      # Mitsuba within 0.2 %
    (SMALL_SPHERE.replace('value="$r"', 'value="0.1"').replace(
        "<emitter", '<transform name="to_world"><scale value="$r"/></transform><emitter')
     .replace('x="-0.5" y="1" z="0.5"', 'x="-5000" y="10000" z="5000"'), "1e-4", True),
    (SMALL_DISK, "1e-4", False),        # a disk is sampled by area: right in both
], ids=["sphere-1e-3", "sphere-1e-4", "sphere-1e-2", "sphere-scaled-by-to_world", "disk"])
def test_a_small_sphere_light_is_noted(tmp_path, light, r, noted):
    """Mitsuba 3.9.1 divides a sphere emitter's cone samples by 2π(1 - cos θ_max) with
    cos θ_max = sqrt(1 - (r/d)²) in float32, which keeps (r/d)²/2 to about 2^-24: a sphere
    light of radius 1e-3 about 1.5 from the floor (radiance 1e6) came out 11 % brighter
    than ours and than Mitsuba's own at radius 1e-2 (radiance 1e4), and at 1e-4 black (an
    outside review). A failing gate says so; a disk of the same power renders alike."""
    path = tmp_path / "scene.xml"
    path.write_text(SMALL_LIGHT.format(light=light))
    notes = _caveats(str(path), {"r": r, "L": repr(1.0 / float(r) ** 2)}, None)
    assert any("sphere emitter" in n for n in notes) == noted, notes


def test_mitsubas_small_sphere_light_is_what_the_note_says():
    """The note's premise, in Mitsuba 3.9.1 itself: the floor's mean under a sphere light of
    fixed power, radius 1e-2 and 1e-3 (seeded, 8 × 64 spp at 16², the means' standard
    error about 0.3 %): 8 % or more apart, where its disk of the same power is within 2 %
    at both sizes."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("llvm_ad_rgb")

    def mean(light, r):
        scene = mi.load_string(SMALL_LIGHT.format(light=light), r=r, L=repr(1.0 / float(r) ** 2))
        return np.mean([np.array(mi.render(scene, spp=64, seed=k)).mean() for k in range(8)])

    assert mean(SMALL_SPHERE, "0.001") / mean(SMALL_SPHERE, "0.01") > 1.08
    assert mean(SMALL_DISK, "0.001") / mean(SMALL_DISK, "0.01") == pytest.approx(1.0, abs=0.02)


# ... seen through a glass slab 2 t thick under a white sky, with a red sphere
SLAB = FLOOR.format(defaults='<default name="t" value="5e-6"/>',
                    integrator='<integer name="max_depth" value="8"/>', body="""\
<shape type="sphere"><float name="radius" value="0.3"/>
    <point name="center" x="0.3" y="-0.2" z="0"/>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.2, 0.2"/></bsdf></shape>
  <shape type="cube"><transform name="to_world"><scale x="0.6" y="$t" z="0.6"/>
    <rotate x="1" angle="20"/><translate y="0.3" z="0.5"/></transform>
    <bsdf type="dielectric"/></shape>
  <emitter type="constant"/>""")


@pytest.mark.parametrize("shape,t,noted", [
    ("cube", "5e-6", True),             # Mitsuba 19 % dark through the slab
    ("cube", "5e-3", False),            # Mitsuba agrees with ours
    ("sphere", "5e-6", True),           # a glass bead of radius 5e-6
    ("sphere", "5e-3", False),
], ids=["slab-1e-5", "slab-1e-2", "bead-1e-5", "bead-1e-2"])
def test_a_shape_thinner_than_mitsubas_ray_offset_is_noted(tmp_path, shape, t, noted):
    """Mitsuba starts a ray (1 + max|p|) · 1500 · 2^-24 off the surface it leaves: a ray
    refracted into a glass slab 1e-5 thick at scale 1 starts beyond its far side (an
    outside review: 19 % dark through the slab, where ours matched the same slab 1e-2
    thick). A failing gate says so."""
    text = SLAB
    if shape == "sphere":
        text = text.replace('<shape type="cube"><transform name="to_world"><scale x="0.6" '
                            'y="$t" z="0.6"/>', '<shape type="sphere"><float name="radius" '
                            'value="$t"/><transform name="to_world">')
    path = tmp_path / "scene.xml"
    path.write_text(text)
    notes = _caveats(str(path), {"t": t}, None)
    assert any(f"the {shape} at" in n and "thick" in n for n in notes) == noted, notes


def test_mitsubas_thin_glass_slab_is_what_the_note_says():
    """The note's premise, in Mitsuba 3.9.1 itself: the pixels through the slab (8 × 64 spp
    at 16²) 10 % or more darker at 1e-5 thick than at 1e-2; a plate that thin differs
    from the thicker one by a lateral shift of the image through it."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("llvm_ad_rgb")

    def plate(t):
        scene = mi.load_string(SLAB, t=t)
        img = np.mean([np.array(mi.render(scene, spp=64, seed=k)) for k in range(8)], axis=0)
        return img[4:10, 4:12].mean()

    assert plate("5e-6") / plate("5e-3") < 0.9


# A tilted floor rectangle of half-width $S under a directional light, a sphere on it
HUGE_FLOOR = """<scene version="3.0.0">
  <default name="S" value="1e5"/>
  <integrator type="path"><integer name="max_depth" value="3"/></integrator>
  <sensor type="perspective"><float name="fov" value="45"/>
    <transform name="to_world"><lookat origin="0,1.5,4" target="0,0.3,0" up="0,1,0"/></transform>
    <sampler type="independent"><integer name="sample_count" value="64"/></sampler>
    <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/>
      <rfilter type="box"/></film>
  </sensor>
  <shape type="rectangle"><transform name="to_world"><scale value="$S"/><rotate x="1" angle="-90"/>
    <rotate z="1" angle="17"/><rotate x="1" angle="9"/><translate y="-0.5"/></transform></shape>
  <shape type="sphere"><float name="radius" value="0.3"/>
    <point name="center" x="0" y="0.3" z="0"/></shape>
  <emitter type="directional"><vector name="direction" x="0.3" y="-1" z="-0.4"/>
    <rgb name="irradiance" value="2"/></emitter>
</scene>
"""


@pytest.mark.parametrize("size,noted", [("1e5", True), ("3", False), ("100", False)])
def test_a_huge_triangle_near_the_origin_is_noted(tmp_path, size, noted):
    """Mitsuba 3.9.1 computes a triangle's hit point from its vertices in float32, about
    2^-24 of their magnitude off the plane, more than its ray offset where the hit is
    near the origin: the floor above, scaled by 1e5, is 84 % dark at the camera's feet in
    Mitsuba (an outside review; right in Mitsuba at scale 100, and in ours at both)."""
    path = tmp_path / "scene.xml"
    path.write_text(HUGE_FLOOR)
    notes = _caveats(str(path), {"S": size}, None)
    assert any("a triangle" in n and "across" in n for n in notes) == noted, notes
    # the same triangle far from the origin (a scene at that scale) is not noted
    far = np.array([[1e5, 1e5, 1e5, 3e5, 1e5, 1e5, 1e5, 3e5, 1e5]])
    assert mitsuba_caveats(None, None, far) == []
    assert len(mitsuba_caveats(None, None, far - 1e5)) == 1


def test_mitsubas_huge_floor_is_what_the_note_says():
    """The note's premise, in Mitsuba 3.9.1 itself (8 × 64 spp at 16²): at scale 1e5 more
    than a quarter of the image is black (below 0.05; the lit floor is 0.31), at scale 100,
    the same plane seen over the same small area, 2 % (the sphere's shadow)."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("llvm_ad_rgb")

    def black(size):
        scene = mi.load_string(HUGE_FLOOR, S=size)
        img = np.mean([np.array(mi.render(scene, spp=64, seed=k)) for k in range(8)], axis=0)
        return np.mean(img[..., 0] < 0.05)

    assert black("1e5") > black("100") + 0.15


# A closed furnace: the camera inside a sphere of albedo $rho emitting radiance 1 inward;
# at max_depth $d every pixel is exactly 1 + rho + ... + rho^(d-1) (a flipped cube too)
FURNACE = """<scene version="3.0.0">
  <default name="rho" value="1"/>
  <default name="d" value="3"/>
  <default name="flip" value="true"/>
  <integrator type="path"><integer name="max_depth" value="$d"/></integrator>
  <sensor type="perspective"><float name="fov" value="60"/>
    <transform name="to_world"><lookat origin="0,0,0" target="0,0,-1" up="0,1,0"/></transform>
    <sampler type="independent"><integer name="sample_count" value="64"/></sampler>
    <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/>
      <rfilter type="box"/></film>
  </sensor>
  <shape type="{shape}">{size}<boolean name="flip_normals" value="$flip"/>
    <bsdf type="diffuse"><rgb name="reflectance" value="$rho"/></bsdf>
    <emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>
</scene>
"""
SPHERE_FURNACE = FURNACE.format(shape="sphere", size='<float name="radius" value="2"/>')
CUBE_FURNACE = FURNACE.format(shape="cube", size='<transform name="to_world">'
                              '<scale value="2"/></transform>')


@pytest.mark.parametrize("text,flip,noted", [
    (SPHERE_FURNACE, "true", True),
    (SPHERE_FURNACE, "false", False),   # its light faces out: nothing lights its inside
    (CUBE_FURNACE, "true", False),      # a mesh: sampled and weighted alike in Mitsuba
    (SPHERE_FURNACE.replace('<bsdf type="diffuse"><rgb name="reflectance" value="$rho"/>'
                            '</bsdf>', ''), "true", False),     # an emitter's default: black
], ids=["flipped-sphere", "sphere", "flipped-cube", "flipped-sphere-without-bsdf"])
def test_a_sphere_light_facing_inward_is_noted(tmp_path, text, flip, noted):
    """Mitsuba 3.9.1 samples a flipped sphere light from a point of its own surface as from
    inside it but weighs a direction that hits it by the cone pdf wherever float32 puts
    the point just outside the radius: its closed furnace above comes out 0.17 % bright,
    where ours is exactly 3 and the gate failed ours naming only the image mean (an
    outside review). A failing gate says so."""
    path = tmp_path / "scene.xml"
    path.write_text(text)
    notes = _caveats(str(path), {"flip": flip}, None)
    assert any("flip_normals" in n and "MIS weights" in n for n in notes) == noted, notes


@pytest.mark.parametrize("text,params", [
    (SPHERE_FURNACE, {"d": "1"}),       # max_depth 1: nothing sampled, no MIS
    (SPHERE_FURNACE.replace('<bsdf type="diffuse"><rgb name="reflectance" value="$rho"/>'
                            '</bsdf>', '<bsdf type="dielectric"/>'), {}),   # delta: weight 1
], ids=["max-depth-1", "delta-bsdf"])
def test_an_inward_sphere_light_without_mis_there_is_not_noted(tmp_path, text, params):
    """The note names MIS weights at the sphere's surface: a read-only review found it
    given at max_depth 1, where nothing is sampled, and on a sphere whose BSDF is a delta
    lobe alone, never light-sampled, where Mitsuba's error cannot arise."""
    path = tmp_path / "scene.xml"
    path.write_text(text)
    notes = _caveats(str(path), {"flip": "true", **params}, None)
    assert not any("flip_normals" in n for n in notes), notes


def test_mitsubas_inward_sphere_light_is_what_the_note_says(tmp_path):
    """The note's premise, in Mitsuba 3.9.1 itself: the furnace above at max_depth 2 is 2
    exactly; Mitsuba's sphere gives 2.0027 (8 × 1024 spp at 8², standard error 5e-5), its
    flipped cube 2 within its error (4e-4); ours is 2 to rounding in every pixel."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("llvm_ad_rgb")

    def mean(text):
        scene = mi.load_string(text, d="2")
        return np.mean([np.array(mi.render(scene, spp=1024, seed=k)).mean() for k in range(8)])

    assert mean(SPHERE_FURNACE) > 2.0015
    assert mean(CUBE_FURNACE) == pytest.approx(2.0, abs=0.002)
    from estimators.pathtracer import render

    path = tmp_path / "scene.xml"
    path.write_text(SPHERE_FURNACE)
    ours = render(str(path), spp=64, seed=0, params={"d": "2"}, variance=False)
    assert np.asarray(ours.mean) == pytest.approx(2.0, abs=1e-9)
