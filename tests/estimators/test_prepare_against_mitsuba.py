"""What ``prepare.py`` hands the kernel, read against what Mitsuba loads from the same
XML: each shape's world-space extent, its normals, an area light's surface area and
radiance, a directional light's direction. No render: Mitsuba's shapes and emitters are
asked directly, so a loader mistake fails here, not only in a slow render or a reference
scene that happens to use the feature (mutants of a mutation review lived through the
loader's tests: a sphere's center not transformed, a mirrored rectangle's winding not
flipped, a disk's or a sphere's area off by π or r, normals transformed by the matrix
and not its inverse transpose, a directional light's default direction negated)."""
import numpy as np
import pytest

from estimators.pathtracer import layout, parse_scene
from estimators.pathtracer.prepare import prepare_scene

_SENSOR = ('<sensor type="perspective"><film type="hdrfilm"><integer name="width" '
           'value="4"/><integer name="height" value="4"/></film></sensor>')


def _scene(body: str) -> str:
    return f'<scene version="3.0.0">{_SENSOR}{body}</scene>'


def _to_world(ops: str) -> str:
    return f'<transform name="to_world">{ops}</transform>'


def _triangles(prepared) -> np.ndarray:
    """(triangles, 3 corners, 3) of shape 0."""
    a = prepared.arrays
    rows = a.prims[a.prim_info[:, 1] == 0]
    return np.stack([rows[:, c:c + 3] for c in (layout.TRI_P0, layout.TRI_P1,
                                                layout.TRI_P2)], axis=1)


def _winding(tri) -> np.ndarray:
    """The unit normal of a triangle's winding."""
    n = np.cross(tri[1] - tri[0], tri[2] - tri[0])
    return n / np.linalg.norm(n)


def _shading_normal(mi, scene, tri) -> np.ndarray:
    """Mitsuba's shading normal at the triangle's centroid, hit along its winding."""
    g, c = _winding(tri), tri.mean(axis=0)
    si = scene.ray_intersect(mi.Ray3f(mi.Point3f(*(c + 0.01 * g)), mi.Vector3f(*-g)))
    assert si.is_valid()
    return np.array(si.sh_frame.n)


#: unit rotation axes only: Mitsuba inverts a rotation by transposing it (see
#: test_pathtracer_textures' _NON_UNIT_AXIS), so a non-unit axis leans its normals
_TRANSFORMS = {
    "plain": "",
    "mirror-x": '<scale x="-1"/>',
    "mirror-z-rotated": '<scale x="0.5" z="-2"/><rotate x="0.6" z="0.8" angle="37"/>'
                        '<translate value="1 2 3"/>',
    "stretched-rotated": '<scale x="2" y="0.5" z="3"/><rotate y="1" angle="-50"/>',
    "two-mirrors": '<scale value="-1 -1.5 1"/><rotate x="1" angle="20"/>',
    "shear": '<matrix value="1 0.5 0 1  0 2 0 0  0.3 0 1 -1  0 0 0 1"/>',
}


@pytest.mark.parametrize("shape", ["rectangle", "cube"])
@pytest.mark.parametrize("ops", list(_TRANSFORMS.values()), ids=list(_TRANSFORMS))
def test_a_rectangles_and_a_cubes_triangles_face_as_mitsubas_normals(mi, shape, ops):
    """Every triangle spans Mitsuba's shape (the same bounding box) and its winding's
    normal is Mitsuba's shading normal at its centroid, mirrored transforms included,
    where the loader flips the winding to keep the normal the transform gives."""
    text = _scene(f'<shape type="{shape}">{_to_world(ops)}</shape>')
    tris = _triangles(prepare_scene(parse_scene(text)))
    scene = mi.load_string(text)
    box = scene.shapes()[0].bbox()
    flat = tris.reshape(-1, 3)
    np.testing.assert_allclose(flat.min(axis=0), np.array(box.min), atol=1e-5)
    np.testing.assert_allclose(flat.max(axis=0), np.array(box.max), atol=1e-5)
    for tri in tris:
        np.testing.assert_allclose(_shading_normal(mi, scene, tri), _winding(tri), atol=1e-5)


@pytest.mark.parametrize("ops", [
    "", '<scale value="0.5"/>', '<rotate x="0.6" y="0.8" angle="70"/><scale value="1.7"/>'
    '<translate value="-1 0.5 2"/>', '<scale value="-2"/><translate x="3"/>'],
    ids=["plain", "scaled", "rotated-scaled-moved", "mirrored"])
def test_a_sphere_with_a_center_is_where_mitsubas_is(mi, ops):
    """A sphere's center and radius go through to_world (Mitsuba's bounding box), and
    as an area light its surface area is Mitsuba's."""
    text = _scene('<shape type="sphere"><point name="center" x="0.3" y="-0.4" z="1.1"/>'
                  f'<float name="radius" value="0.7"/>{_to_world(ops)}'
                  '<emitter type="area"/></shape>')
    prepared = prepare_scene(parse_scene(text))
    row = prepared.arrays.prims[0]
    c = row[layout.SPHERE_CENTER:layout.SPHERE_CENTER + 3]
    r = row[layout.SPHERE_RADIUS]
    sphere = mi.load_string(text).shapes()[0]
    box = sphere.bbox()
    np.testing.assert_allclose(c - r, np.array(box.min), atol=1e-5)
    np.testing.assert_allclose(c + r, np.array(box.max), atol=1e-5)
    np.testing.assert_allclose(prepared.arrays.light_f[0, layout.LIGHT_AREA],
                               sphere.surface_area(), rtol=1e-6)


@pytest.mark.parametrize("shape,ops", [
    ("disk", ""), ("disk", '<scale x="2" y="0.5"/><rotate x="1" angle="30"/>'),
    ("disk", '<scale value="-1.5"/>'), ("rectangle", '<scale x="3" y="0.25"/>'),
    ("cube", '<scale value="0.5 2 1"/>')])
def test_an_area_lights_surface_area_and_radiance_are_mitsubas(mi, shape, ops):
    """The light's area (its sampling pdf's 1/A) and radiance are Mitsuba's."""
    text = _scene(f'<shape type="{shape}">{_to_world(ops)}<emitter type="area">'
                  '<rgb name="radiance" value="2, 0.5, 7"/></emitter></shape>')
    lights = prepare_scene(parse_scene(text)).arrays.light_f
    loaded = mi.load_string(text)
    np.testing.assert_allclose(lights[0, layout.LIGHT_AREA],
                               loaded.shapes()[0].surface_area(), rtol=1e-6)
    radiance = mi.traverse(loaded.emitters()[0])["radiance.value"]
    np.testing.assert_allclose(lights[0, layout.LIGHT_RADIANCE:layout.LIGHT_RADIANCE + 3],
                               np.array(radiance), rtol=1e-6)


@pytest.mark.parametrize("ops", ["", '<rotate x="1" angle="30"/>',
                                 '<rotate x="0.6" y="0.8" angle="-110"/>'])
def test_a_directional_lights_direction_from_to_world_is_mitsubas(mi, ops):
    """Without ``direction``, the light travels along to_world's +z, as in Mitsuba:
    its sample towards a point is the opposite of the direction of travel."""
    text = _scene(f'<emitter type="directional">{_to_world(ops)}</emitter>')
    lights = prepare_scene(parse_scene(text)).arrays.light_f
    ours = lights[0, layout.LIGHT_DIRECTION:layout.LIGHT_DIRECTION + 3]
    emitter = mi.load_string(text).emitters()[0]
    it = mi.Interaction3f()
    it.p = mi.Point3f(0.0, 0.0, 0.0)
    ds, _ = emitter.sample_direction(it, mi.Point2f(0.5, 0.5))
    np.testing.assert_allclose(-np.array(ds.d), ours, atol=1e-6)


_TILTED_QUAD = """v -1 -1 0
v 1 -1 0.2
v 1 1 0
v -1 1 -0.3
vn 0.3 0 1
vn 0 -0.4 1
vn 0.5 0.5 1
vn -0.2 0.1 1
f 1//1 2//2 3//3
f 1//1 3//3 4//4
"""


@pytest.mark.parametrize("ops", ['<scale x="3" y="0.5" z="2"/><rotate x="0.6" y="0.8" '
                                 'angle="40"/>', '<scale x="-1" z="4"/>'],
                         ids=["stretched-rotated", "mirrored-stretched"])
def test_a_meshs_own_normals_go_to_world_space_as_mitsubas(mi, tmp_path, ops):
    """A file's vertex normals are taken by to_world's inverse transpose (a stretch tilts
    them the other way from the surface): the shading normal at each triangle's centroid
    is Mitsuba's ``si.sh_frame.n`` there."""
    (tmp_path / "quad.obj").write_text(_TILTED_QUAD)
    text = _scene(f'<shape type="obj"><string name="filename" value="quad.obj"/>'
                  f'{_to_world(ops)}</shape>')
    path = tmp_path / "scene.xml"
    path.write_text(text)
    prepared = prepare_scene(str(path))
    rows = prepared.arrays.prims[prepared.arrays.prim_info[:, 1] == 0]
    scene = mi.load_file(str(path))
    for tri, row in zip(_triangles(prepared), rows):
        n = sum(row[c:c + 3] for c in (layout.TRI_N0, layout.TRI_N1, layout.TRI_N2))
        np.testing.assert_allclose(_shading_normal(mi, scene, tri), n / np.linalg.norm(n),
                                   atol=1e-5)
