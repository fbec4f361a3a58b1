"""PLY meshes: every format reads the same mesh, a PLY that Mitsuba wrote reads as Mitsuba
holds it, bad files are refused naming the file and the problem (and Mitsuba refuses
them too), and the same mesh as OBJ and as PLY renders bit-identically in our tracer.
The (u, v) and shading normals at hits are compared with Mitsuba in
``test_pathtracer_textures.py::test_uv_at_a_hit_matches_mitsuba``."""

import numpy as np
import pytest

from estimators.pathtracer import prepare_scene, render
from estimators.pathtracer.meshes import read_ply, write_ply
from estimators.pathtracer.layout import TRI_UV0, TRI_UV1, TRI_UV2
from estimators.pathtracer.scene import SceneError

FORMATS = ("ascii", "binary_little_endian", "binary_big_endian")

# a bent 3 × 3 grid: distinct dyadic positions, normals and uv (exact in float32 and in
# decimal, so OBJ, whose v is flipped on reading, and PLY hold the very same numbers)
_G = np.array([-1.0, 0.0, 1.0])
_VERTS = np.array([[x, y, 0.25 * x * y + 0.125 * y] for y in _G for x in _G])
_NORMALS = np.array([[-0.25 * y, -0.25 * x - 0.125, 1.0] for y in _G for x in _G])
_UVS = (_VERTS[:, :2] + 1) / 2
_FACES = np.array([[r * 3 + c, r * 3 + c + 1, r * 3 + c + 4] for r in range(2) for c in range(2)]
                  + [[r * 3 + c, r * 3 + c + 4, r * 3 + c + 3] for r in range(2) for c in range(2)])


@pytest.mark.parametrize("vertex_type", ["float", "double"])
def test_every_format_reads_the_mesh_written(tmp_path, vertex_type):
    rng = np.random.default_rng(1)
    v, n, uv = rng.normal(size=(7, 3)), rng.normal(size=(7, 3)), rng.random((7, 2))
    f = rng.integers(0, 7, (5, 3))
    cast = np.float32 if vertex_type == "float" else np.float64
    for fmt in FORMATS:
        for names in (("u", "v"), ("s", "t"), ("texture_u", "texture_v")):
            path = tmp_path / f"{fmt}-{names[0]}.ply"
            write_ply(str(path), v, f, normals=n, uvs=uv, uv_names=names, fmt=fmt,
                      vertex_type=vertex_type)
            m = read_ply(str(path))
            np.testing.assert_array_equal(m.vertices, v.astype(cast))
            np.testing.assert_array_equal(m.normals, n.astype(cast))
            np.testing.assert_array_equal(m.uvs, uv.astype(cast))
            np.testing.assert_array_equal(m.faces, f)
    bare = read_ply(str(_written(tmp_path, "bare.ply", "ascii", normals=False, uvs=False)))
    assert bare.normals is None and bare.uvs is None


@pytest.mark.parametrize("newline", [b"\n", b"\r\n"])
def test_header_comments_empty_elements_and_line_ends(tmp_path, newline):
    """A comment that mentions end_header, an element without properties and one with
    properties the tracer ignores (read past), CRLF line ends."""
    text = (b"ply\nformat ascii 1.0\ncomment end_header is the last line\n"
            b"element vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
            b"property uchar red\nelement empty 2\nelement face 1\n"
            b"property list uchar int vertex_indices\nproperty float quality\n"
            b"element edge 1\nproperty int a\nproperty int b\nend_header\n"
            b"0 0 0 255\n1 0 0 0\n0 1 0.5 7\n3 0 1 2 0.25\n0 1\n")
    path = tmp_path / "m.ply"
    path.write_bytes(text.replace(b"\n", newline))
    m = read_ply(str(path))
    np.testing.assert_array_equal(m.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0.5]])
    np.testing.assert_array_equal(m.faces, [[0, 1, 2]])


@pytest.mark.mitsuba
def test_a_ply_that_mitsuba_wrote_reads_as_mitsuba_holds_it(mi, tmp_path):
    """An independent writer: Mitsuba's ``Mesh.write_ply`` (binary, with its own header
    layout) of a mesh with normals and uv."""
    path = tmp_path / "grid.obj"
    path.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in _VERTS)
                    + "".join(f"vn {x} {y} {z}\n" for x, y, z in _NORMALS)
                    + "".join(f"vt {u} {v}\n" for u, v in _UVS)
                    + "".join("f " + " ".join(f"{i + 1}/{i + 1}/{i + 1}" for i in face) + "\n"
                              for face in _FACES))
    mesh = mi.load_dict({"type": "obj", "filename": str(path)})
    mesh.write_ply(str(tmp_path / "mitsuba.ply"))
    ours = read_ply(str(tmp_path / "mitsuba.ply"))
    np.testing.assert_array_equal(ours.vertices.ravel(), np.array(mesh.vertex_positions_buffer()))
    np.testing.assert_array_equal(ours.normals.ravel(), np.array(mesh.vertex_normals_buffer()))
    np.testing.assert_array_equal(ours.uvs.ravel(), np.array(mesh.vertex_texcoords_buffer()))
    np.testing.assert_array_equal(ours.faces.ravel(), np.array(mesh.faces_buffer()))


def _written(folder, name, fmt, *, normals=True, uvs=True, **kw):
    path = folder / name
    write_ply(str(path), _VERTS, _FACES, normals=_NORMALS if normals else None,
              uvs=_UVS if uvs else None, fmt=fmt, **kw)
    return path


def _quad_face(text: bytes) -> bytes:
    """The last face made a quad (ASCII)."""
    head, last = text.rstrip(b"\n").rsplit(b"\n", 1)
    return head + b"\n" + last.replace(b"3 ", b"4 ", 1) + b" 0\n"


def _bad(fmt, edit):
    def make(folder):
        path = _written(folder, f"bad-{fmt}.ply", fmt)
        path.write_bytes(edit(path.read_bytes()))
        return path
    return make


def _beyond_float32(folder):
    """The mesh with double positions, its first coordinate 1e39."""
    path = _written(folder, "big.ply", "ascii", vertex_type="double")
    path.write_bytes(path.read_bytes().replace(b"end_header\n-1.0", b"end_header\n1e39", 1))
    return path


def _normal_beyond_float32(folder):
    """Double normals, one of them 1e39 long: Mitsuba loads it as inf and renders the
    triangle black (a NaN normal); ours normalised it and lit it (a final review)."""
    path = folder / "bign.ply"
    write_ply(str(path), np.eye(3), [[0, 1, 2]], fmt="ascii", vertex_type="double",
              normals=[[0, 0, 1], [0, 0, 1e39], [0, 0, 1]])
    return path


BAD = {
    "truncated-binary": (_bad("binary_little_endian", lambda b: b[:-7]), "truncated", True),
    "truncated-ascii": (_bad("ascii", lambda b: b.rsplit(b" ", 2)[0]), "truncated", True),
    "quad-ascii": (_bad("ascii", _quad_face), "has 4 vertices", True),
    "quad-binary": (_bad("binary_big_endian",
                         lambda b: b[:-13] + b"\x04" + b[-12:] + b"\x00\x00\x00\x00"),
                    "has 4 vertices", True),
    "trailing-content": (_bad("binary_little_endian", lambda b: b + b"\x00" * 8),
                         "trailing content", True),
    "integer-positions": (lambda folder: _written(folder, "int.ply", "ascii", normals=False,
                                                  uvs=False, vertex_type="int"),
                          "'x' is int32 (integer)", False),
    "unknown-type": (_bad("ascii", lambda b: b.replace(b"property float x",
                                                       b"property float128 x")),
                     "unknown type 'float128'", True),
    "index-out-of-range": (_bad("ascii", lambda b: b.rstrip(b"\n")[:-1] + b"9\n"),
                           "refers to vertex 9", False),
    "no-end-header": (_bad("ascii", lambda b: b.replace(b"end_header", b"end")),
                      "no end_header", True),
    "extra-list": (_bad("ascii", lambda b: b.replace(
        b"property float x", b"property list uchar int x")), "list property 'x'", False),
    "two-uv-names": (_bad("ascii", lambda b: b.replace(b"property float nx",
                                                       b"property float s").replace(
        b"property float ny", b"property float t")), "texture coordinates named", False),
    "non-finite": (_bad("ascii", lambda b: b.replace(b"end_header\n-1.0", b"end_header\nnan")),
                   "non-finite position", True),
    # a double Mitsuba rounds to float32's infinity ("invalid vertex position data");
    # it was rendered in float64 here
    "beyond-float32": (_beyond_float32, "in single precision", True),
    "normal-beyond-float32": (_normal_beyond_float32, "normal that is not finite in single",
                              False),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_files_are_refused_naming_the_file(tmp_path, case):
    make, needle, _ = BAD[case]
    path = make(tmp_path)
    with pytest.raises(SceneError) as e:
        read_ply(str(path))
    assert str(path) in str(e.value) and needle in str(e.value), str(e.value)


@pytest.mark.mitsuba
@pytest.mark.parametrize("case", sorted(c for c in BAD if BAD[c][2]))
def test_mitsuba_refuses_them_too(mi, tmp_path, case):
    """What we refuse as Mitsuba's rule (triangles only, no trailing content...), Mitsuba
    refuses as well; the others are files Mitsuba reads differently or not reliably."""
    path = BAD[case][0](tmp_path)
    with pytest.raises(Exception):
        mi.load_dict({"type": "ply", "filename": str(path)})


def test_a_ply_shape_names_the_scene_line_and_the_file(tmp_path):
    path = BAD["quad-ascii"][0](tmp_path)
    scene = tmp_path / "s.xml"
    scene.write_text(_SCENE.format(mesh=f'<shape type="ply"><string name="filename" '
                                        f'value="{path.name}"/></shape>'))
    with pytest.raises(SceneError) as e:
        prepare_scene(str(scene))
    assert f"{scene}:8" in str(e.value) and '<shape type="ply">' in str(e.value)


@pytest.mark.parametrize("mesh", ["ply", "obj"])
def test_a_missing_mesh_file_is_named_once(tmp_path, mesh):
    # a missing PLY said "s.xml:8: <shape type="ply">: s.xml:8: <shape type="ply">:
    # cannot read ...": the path check's own SceneError was caught and prefixed again
    scene = tmp_path / "s.xml"
    scene.write_text(_SCENE.format(mesh=f'<shape type="{mesh}"><string name="filename" '
                                        f'value="gone.{mesh}"/></shape>'))
    with pytest.raises(SceneError) as e:
        prepare_scene(str(scene))
    message = str(e.value)
    assert message.startswith(f'{scene}:8: <shape type="{mesh}">: ')
    assert message.count(str(scene)) == 1 and "gone." + mesh in message


_SCENE = """<scene version="3.0.0">
  <integrator type="path"><integer name="max_depth" value="3"/></integrator>
  <sensor type="perspective"><float name="fov" value="50"/>
    <transform name="to_world">
      <lookat origin="0.5, -2, 2.5" target="0, 0, 0" up="0, 0, 1"/></transform>
    <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="12"/>
    <rfilter type="box"/></film></sensor>
  {mesh}
  <emitter type="point"><point name="position" x="1" y="-1" z="3"/>
    <rgb name="intensity" value="8, 6, 4"/></emitter>
</scene>"""


def _obj_text(normals, uvs):
    """The grid as OBJ: v flipped (Mitsuba reads an OBJ's v as 1 - v, a PLY's as is)."""
    lines = ["v %r %r %r" % tuple(map(float, p)) for p in _VERTS]
    lines += ["vn %r %r %r" % tuple(map(float, n)) for n in _NORMALS] if normals else []
    lines += ["vt %r %r" % (float(u), float(1 - v)) for u, v in _UVS] if uvs else []
    ref = "{0}/{0}/{0}" if normals and uvs else "{0}"
    lines += ["f " + " ".join(ref.format(i + 1) for i in face) for face in _FACES]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("with_attributes", [True, False], ids=["normals-uv", "bare"])
def test_the_same_mesh_as_obj_and_as_ply_renders_identically(tmp_path, with_attributes):
    """The grid, transformed, with given normals and uv or with neither (smooth normals
    and barycentric uv computed): OBJ and each PLY format give the same triangles, bit
    for bit, and so the same image."""
    (tmp_path / "grid.obj").write_text(_obj_text(with_attributes, with_attributes))
    transform = ('<transform name="to_world"><scale x="1.3" y="0.8"/>'
                 '<rotate z="1" angle="20"/></transform>')
    bsdf = ('<bsdf type="roughplastic"><float name="alpha" value="0.3"/>'
               '<rgb name="diffuse_reflectance" value="0.6, 0.4, 0.2"/></bsdf>')
    images, prims = {}, {}
    for name in ("grid.obj", *(_written(tmp_path, f"grid-{fmt}.ply", fmt,
                                        normals=with_attributes, uvs=with_attributes).name
                               for fmt in FORMATS)):
        kind = name.rsplit(".", 1)[1]
        scene = tmp_path / f"{name}.xml"
        scene.write_text(_SCENE.format(mesh=f'<shape type="{kind}"><string name="filename" '
                                            f'value="{name}"/>{transform}{bsdf}</shape>'))
        cs = prepare_scene(str(scene))
        prims[name] = cs.arrays.prims
        images[name] = render(cs, spp=4, seed=3).mean
    assert images["grid.obj"].max() > 0
    for name in prims:
        np.testing.assert_array_equal(prims[name], prims["grid.obj"], err_msg=name)
        np.testing.assert_array_equal(images[name], images["grid.obj"], err_msg=name)


def _uv_scene(folder, name, flip):
    """A scene of the grid file ``name``, ``flip_tex_coords`` set to ``flip`` (None: not
    given), prepared by ours."""
    extra = "" if flip is None else f'<boolean name="flip_tex_coords" value="{flip}"/>'
    kind = name.rsplit(".", 1)[1]
    scene = folder / f"{name}-{flip}.xml"
    scene.write_text(_SCENE.format(mesh=f'<shape type="{kind}"><string name="filename" '
                                        f'value="{name}"/>{extra}</shape>'))
    return prepare_scene(str(scene))


def test_flip_tex_coords_on_a_ply_flips_v_as_on_an_obj(tmp_path):
    """Mitsuba's PLY takes ``flip_tex_coords`` too, default false (an OBJ's default is
    true): a PLY with it true holds the uv of the OBJ with the same ``vt``, one with it
    false or absent the uv as stored. Until 7 December a PLY with it was refused."""
    ply = _written(tmp_path, "grid.ply", "binary_little_endian").name
    (tmp_path / "grid.obj").write_text(_obj_text(True, True).replace(
        "".join("vt %r %r\n" % (float(u), float(1 - v)) for u, v in _UVS),
        "".join("vt %r %r\n" % (float(u), float(v)) for u, v in _UVS)))
    uv = slice(TRI_UV0, TRI_UV2 + 2)
    flipped = _uv_scene(tmp_path, "grid.obj", None).arrays.prims
    as_stored = _uv_scene(tmp_path, ply, None).arrays.prims
    assert not np.array_equal(flipped[:, uv], as_stored[:, uv])
    np.testing.assert_array_equal(_uv_scene(tmp_path, ply, "true").arrays.prims, flipped)
    np.testing.assert_array_equal(_uv_scene(tmp_path, ply, "false").arrays.prims, as_stored)


@pytest.mark.mitsuba
@pytest.mark.parametrize("flip", [None, "true", "false"])
def test_a_plys_uv_with_flip_tex_coords_are_mitsubas(mi, tmp_path, flip):
    ply = _written(tmp_path, "grid.ply", "ascii").name
    extra = {} if flip is None else {"flip_tex_coords": flip == "true"}
    mesh = mi.load_dict({"type": "ply", "filename": str(tmp_path / ply), **extra})
    theirs = np.array(mesh.vertex_texcoords_buffer()).reshape(-1, 2)
    prims = _uv_scene(tmp_path, ply, flip).arrays.prims
    faces = np.array(mesh.faces_buffer()).reshape(-1, 3)
    for k, col in enumerate((TRI_UV0, TRI_UV1, TRI_UV2)):
        np.testing.assert_array_equal(np.sort(prims[:, col:col + 2], axis=0),
                                      np.sort(theirs[faces[:, k]], axis=0))


# ------------------------------------------------------------------ OBJ, as Mitsuba reads it
_TRI = "v 0 0 0\nv 1 0 0\nv 0 1 0\n"
OBJ_BAD = {   # name: (file text, what the message says, Mitsuba refuses it too)
    "nan-position": ("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", ":1: 'v nan 0 0': not finite",
                     True),
    "inf-position": (_TRI + "v inf 0 0\nf 1 2 4\n", ":4: 'v inf 0 0': not finite", True),
    # finite in float64, infinite in the float32 Mitsuba stores (it refuses both; they
    # were rendered here)
    "float32-overflow-position": (_TRI + "v 0 0 3.4028236e38\nf 1 2 4\n",
                                  ":4: 'v 0 0 3.4028236e38': not finite in single", True),
    "float32-overflow-normal": (_TRI + "vn 0 0 1e39\nf 1//1 2//1 3//1\n",
                                ":4: 'vn 0 0 1e39': not finite in single", True),
    "negative-index": (_TRI + "f -3 -2 -1\n", "negative (relative) indices", True),
    "negative-vt": (_TRI + "vt 0 0\nvt 1 1\nf 1/-1 2/-2 3/-1\n", "negative (relative)", True),
    "zero-normal": (_TRI + "vn 0 0 0\nf 1//1 2//1 3//1\n", "'vn 0 0 0': a zero normal", True),
    "normal-without-vn": (_TRI + "f 1//1 2//1 3//1\n", "a 'vn' that is not defined before "
                          "it (0 so far)", True),
    "vertex-after-face": ("v 0 0 0\nv 1 0 0\nf 1 2 3\nv 0 1 0\n",
                          ":3: 'f 1 2 3': refers to a 'v' that is not defined", True),
    "unused-zero-normal": (_TRI + "vn 0 0 0\nf 1 2 3\n", ":4: 'vn 0 0 0': a zero normal",
                           True),
    # beyond float32 (Mitsuba's precision) as well as too large to normalise in float64
    "huge-normal": (_TRI + "vn 0 1e300 1e300\nf 1//1 2//1 3//1\n",
                    ":4: 'vn 0 1e300 1e300': not finite in single", True),
    "two-coordinates": ("v 0 0\n" + _TRI + "f 2 3 4\n", ":1: 'v 0 0': needs 3 numbers", True),
    "one-uv": (_TRI + "vt 0.1\nf 1/1 2/1 3/1\n", "'vt 0.1': needs 2 numbers", True),
    # the fourth index was dropped and the face rendered
    "four-indices": (_TRI + "vt 0 0\nvn 0 0 1\nf 1/1/1 2/1/1/1 3/1/1\n",
                     ":6: 'f 1/1/1 2/1/1/1 3/1/1': the corner '2/1/1/1' has more than three "
                     "indices", True),
    "two-normal-values": (_TRI + "vn 0 1\nf 1//1 2//1 3//1\n", "'vn 0 1': needs 3", True),
    "byte-order-mark": ("\ufeff" + _TRI + "f 1 2 3\n", "starts with a byte-order mark", True),
    "underscore-number": ("v 1_0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", ":1: 'v 1_0 0 0': needs 3",
                          True),
    # Mitsuba makes no face of it (and warns of invalid vertices)
    "full-width-index": (_TRI + "f 1 2 \uff13\n", ":4: 'f 1 2 \uff13': cannot parse it",
                         False),
    "some-faces-without-normals": (_TRI + "v 1 1 0\nvn 0 0 1\nf 1//1 2//1 3//1\nf 2 4 3\n",
                                   "some faces have normals and some do not", False),
    # Mitsuba's normals or uv are then uninitialised memory (zeros in one run, 9e-24 in
    # the next); ours took the last 'vn' for every corner, vn[0 - 1]
    "normals-no-face-uses": (_TRI + "vn 1 0 0\nf 1 2 3\n", ": 1 'vn' line(s) but no face "
                             "refers to one", False),
    "uv-no-face-uses": (_TRI + "vt 0.3 0.3\nvn 0 0 1\nf 1//1 2//1 3//1\n",
                        ": 1 'vt' line(s) but no face refers to one", False),
    "uv-index-zero": (_TRI + "vt 0.3 0.3\nf 1/0 2/0 3/0\n", "'vt' line(s) but no face", False),
    # Mitsuba drops the face; it was refused as one that 'refers to vertex 0'
    "corner-without-vertex": (_TRI + "vt 0 0\nf 1/1 /1 3/1\n", ":5: 'f 1/1 /1 3/1': the "
                              "corner '/1' has no vertex index", False),
    "corner-of-a-slash": (_TRI + "f 1 / 2 3\n", "the corner '/' has no vertex index", False),
    # Mitsuba misreads these (no face of 'f 1 2 3#c'; one triangle of the quad)
    "comment-glued-to-face": (_TRI + "f 1 2 3#c\n", ":4: 'f 1 2 3#c': a comment glued to an "
                              "index (3#...)", False),
    "comment-glued-to-quad": (_TRI + "v 1 1 0\nf 1 2 4 3#c\n", "glued to an index (3#...)",
                              False),
    "comment-glued-mid-face": (_TRI + "f 1 2#c 3\n", "glued to an index (2#...)", False),
}


def _obj_scene(folder, text, name="m.obj"):
    (folder / name).write_text(text, encoding="utf-8")
    scene = folder / "s.xml"
    scene.write_text(_SCENE.format(mesh=f'<shape type="obj"><string name="filename" '
                                        f'value="{name}"/></shape>'))
    return scene


@pytest.mark.parametrize("case", sorted(OBJ_BAD))
def test_bad_obj_files_are_refused_naming_the_file(tmp_path, case):
    """Each was accepted (a NaN triangle vanished, a zero normal shaded with a zero frame,
    negative indices resolved against the wrong count) or crashed with a bare ValueError
    (found by a probe)."""
    text, needle, _ = OBJ_BAD[case]
    with pytest.raises(SceneError) as e:
        prepare_scene(str(_obj_scene(tmp_path, text)))
    assert str(tmp_path / "m.obj") in str(e.value) and needle in str(e.value), str(e.value)


@pytest.mark.mitsuba
@pytest.mark.parametrize("case", sorted(c for c in OBJ_BAD if OBJ_BAD[c][2]))
def test_mitsuba_refuses_those_obj_files_too(mi, tmp_path, case):
    (tmp_path / "m.obj").write_text(OBJ_BAD[case][0], encoding="utf-8")
    with pytest.raises(Exception):
        mi.load_dict({"type": "obj", "filename": str(tmp_path / "m.obj")})


def test_an_obj_with_non_utf8_comments_and_names_loads_as_in_mitsuba(mi, tmp_path):
    """An outside review: an OBJ whose comment or object name is Latin-1 (an exporter's
    "# Caf\xe9") was refused, "cannot read ... 'utf-8' codec can't decode byte 0xe9",
    where Mitsuba, which reads bytes, renders it. Its numbers are ASCII: it loads, with
    Mitsuba's triangle."""
    (tmp_path / "m.obj").write_bytes(b"# Caf\xe9\no d\xe9cor\n" + _TRI.encode() + b"f 1 2 3\n")
    scene = tmp_path / "s.xml"
    scene.write_text(_SCENE.format(mesh='<shape type="obj"><string name="filename" '
                                        'value="m.obj"/></shape>'))
    cs = prepare_scene(str(scene))
    assert len(cs.arrays.prims) == 1
    shape = mi.load_dict({"type": "obj", "filename": str(tmp_path / "m.obj")})
    assert shape.face_count() == 1


_COLLINEAR = "v 0 0 0\nv 1 0 0\nv 2 0 0\nv 3 0 0\nf 1 2 3\nf 2 3 4\n"


def test_an_emitting_mesh_of_zero_area_is_refused(tmp_path):
    """An outside review: an OBJ light whose every triangle is degenerate was accepted
    (``plan`` exit 0, its checks passing on draws that were all rejected, a black light
    rendered) where Mitsuba refuses it ("no probability mass found"). It is now refused
    naming the file and the emitter's line; the same mesh without an emitter is fine."""
    (tmp_path / "m.obj").write_text(_COLLINEAR)
    lit = tmp_path / "lit.xml"
    lit.write_text(_SCENE.format(mesh='<shape type="obj"><string name="filename" '
                                      'value="m.obj"/>\n<emitter type="area"/></shape>'))
    with pytest.raises(SceneError) as e:
        prepare_scene(str(lit))
    assert f"{lit}:9: <emitter type=\"area\">" in str(e.value), str(e.value)
    assert "zero area" in str(e.value), str(e.value)
    prepare_scene(str(_obj_scene(tmp_path, _COLLINEAR)))


@pytest.mark.mitsuba
def test_mitsuba_refuses_an_emitting_mesh_of_zero_area_too(mi, tmp_path):
    (tmp_path / "m.obj").write_text(_COLLINEAR)
    with pytest.raises(Exception, match="no probability mass"):
        mi.load_dict({"type": "obj", "filename": str(tmp_path / "m.obj"),
                      "emitter": {"type": "area"}})


_CUBE_UV = ("".join(f"v {x} {y} {z}\n" for x in (-1, 1) for y in (-1, 1) for z in (-1, 1))
            + "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvt 0.5 0.5\n"
            + "f 2/1 4/2 3/3 1/4\nf 5/1 7/2 8/3 6/4 # a comment after a face\n"
            + "f 2/1 6/2 5/3 1/4\nf 3/1 7/2 8/3 4/4\nf 3/1 7/5 5/3 1/4\nf 2/1 6/2 8/3 4/4\n")


def _corner_normals(cs):
    from estimators.pathtracer import layout as L

    p = cs.arrays.prims
    return np.stack([p[:, k:k + 3] for k in (L.TRI_N0, L.TRI_N1, L.TRI_N2)], 1)


@pytest.mark.mitsuba
@pytest.mark.parametrize("text", [_CUBE_UV, _TRI + "v 0 0 1\nvt 0 0\nvt 1 0\nvt 0 1\n"
                                  "vt 0.5 0.5\nf 1/1 2/2 3/3\nf 1/4 4/3 2/2\n"],
                         ids=["cube-uv-seams", "roof-seam"])
def test_smooth_normals_of_an_obj_with_uv_are_mitsubas(mi, tmp_path, text):
    """Mitsuba makes one vertex per distinct (position, vt, vn) of an OBJ and sums smooth
    normals per such vertex; we summed them per position, across uv seams (a cube with
    per-face uv rendered 30 % brighter than Mitsuba, z = 420; found by a probe)."""
    cs = prepare_scene(str(_obj_scene(tmp_path, text)))
    m = mi.load_dict({"type": "obj", "filename": str(tmp_path / "m.obj")})
    faces = np.array(m.faces_buffer()).reshape(-1, 3)
    theirs = np.array(m.vertex_normals_buffer()).reshape(-1, 3)[faces]
    ours = _corner_normals(cs)
    assert ours.shape == theirs.shape
    np.testing.assert_allclose(ours, theirs, atol=1e-6)


def test_a_ply_with_a_zero_normal_is_refused(tmp_path):
    """Mitsuba stores NaN normals for it; we shaded with a zero frame."""
    normals = _NORMALS.copy()
    normals[4] = 0.0
    write_ply(str(tmp_path / "z.ply"), _VERTS, _FACES, normals=normals, fmt="ascii")
    scene = tmp_path / "s.xml"
    scene.write_text(_SCENE.format(mesh='<shape type="ply"><string name="filename" '
                                        'value="z.ply"/></shape>'))
    with pytest.raises(SceneError, match="a vertex normal is zero or not finite"):
        prepare_scene(str(scene))


def _ply_with_uv(folder, fmt, bad):
    path = folder / f"uv-{fmt}.ply"
    uvs = _UVS.copy()
    uvs[4, 0] = bad
    write_ply(str(path), _VERTS, _FACES, uvs=uvs, fmt=fmt, vertex_type="double")
    return path


@pytest.mark.parametrize("fmt,bad", [("ascii", 1e39), ("binary_little_endian", 1e39),
                                     ("binary_big_endian", np.nan)])
def test_a_uv_beyond_float32_is_refused_naming_the_file_and_vertex(tmp_path, fmt, bad):
    """An outside review: a PLY whose uv is 1e39 (a double; float32's inf in Mitsuba) or
    NaN was refused only by the check on the prepared triangles, "its geometry in world
    space (to_world applied) reaches 1e+39", naming neither the file nor the uv."""
    path = _ply_with_uv(tmp_path, fmt, bad)
    with pytest.raises(SceneError) as e:
        read_ply(str(path))
    assert str(path) in str(e.value) and "vertex 4" in str(e.value), str(e.value)
    assert "texture coordinates" in str(e.value), str(e.value)


def test_an_obj_face_using_a_vt_beyond_float32_is_refused_naming_the_line(tmp_path):
    """The same for an OBJ: a used 'vt 1e39 0' was refused as "its geometry in world
    space reaches 1e+39"; it now names the face's line (an unused one stays accepted,
    as in Mitsuba)."""
    text = _TRI + "vt 0 0\nvt 1e39 0\nvt 0 1\n"
    prepare_scene(str(_obj_scene(tmp_path, text + "f 1/1 2/1 3/3\n")))
    with pytest.raises(SceneError) as e:
        prepare_scene(str(_obj_scene(tmp_path, text + "f 1/1 2/2 3/3\n")))
    message = str(e.value)
    assert f"{tmp_path / 'm.obj'}:7: 'f 1/1 2/2 3/3'" in message, message
    assert "'vt'" in message and "single precision" in message, message


_ASCII_TRIANGLE = (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n"
                   b"property float y\nproperty float z\nelement face 1\n"
                   b"property list uchar int vertex_indices\nproperty int flags\n"
                   b"end_header\n0 0 0\n1 0 0\n0 1 0\n")
# np.savetxt's default format writes every integer so; Mitsuba's ascii reader takes an
# integer field as digits only ("2.0" leaves ".0", which it refuses)
_INTEGERS_WRITTEN_AS_FLOATS = {
    "index": (b"3 0 1.0 2 7\n", "vertex_indices.1 = b'1.0'"),
    "count": (b"3.0 0 1 2 7\n", "vertex_indices.count = b'3.0'"),
    "savetxt": (b"3.000000000000000000e+00 0 1 2 7\n", "vertex_indices.count"),
    "other-property": (b"3 0 1 2 7.0\n", "flags = b'7.0'"),
}


@pytest.mark.parametrize("case", sorted(_INTEGERS_WRITTEN_AS_FLOATS))
def test_an_ascii_integer_written_as_a_float_is_refused(tmp_path, case):
    """An outside review: an ASCII PLY whose face counts or indices were written as
    floats ("1.0", "3.000e+00", as numpy's savetxt writes them) was read as the integer
    where Mitsuba refuses the file ("could not parse ..."): render-check could then build
    no reference for a scene we render."""
    face, needle = _INTEGERS_WRITTEN_AS_FLOATS[case]
    path = tmp_path / "m.ply"
    path.write_bytes(_ASCII_TRIANGLE + face)
    with pytest.raises(SceneError) as e:
        read_ply(str(path))
    assert str(path) in str(e.value) and needle in str(e.value), str(e.value)
    assert "not an integer" in str(e.value), str(e.value)
    path.write_bytes(_ASCII_TRIANGLE + b"+3 0 +1 2 -7\n")     # signs are integers
    np.testing.assert_array_equal(read_ply(str(path)).faces, [[0, 1, 2]])


@pytest.mark.mitsuba
@pytest.mark.parametrize("case", sorted(_INTEGERS_WRITTEN_AS_FLOATS))
def test_mitsuba_refuses_an_ascii_integer_written_as_a_float_too(mi, tmp_path, case):
    path = tmp_path / "m.ply"
    path.write_bytes(_ASCII_TRIANGLE + _INTEGERS_WRITTEN_AS_FLOATS[case][0])
    with pytest.raises(Exception):
        mi.load_dict({"type": "ply", "filename": str(path)})
    path.write_bytes(_ASCII_TRIANGLE + b"+3 0 +1 2 -7\n")
    assert mi.load_dict({"type": "ply", "filename": str(path)}).face_count() == 1


def test_obj_lines_end_at_lf_only_as_mitsuba_splits_them(tmp_path):
    """An outside review: the OBJ was read with Python's universal newlines, which also
    end a line at a lone CR. Mitsuba splits at LF only (a CR is a space to it), so an OBJ
    with classic Mac OS line ends (CR alone), which Mitsuba refuses, rendered here, and a
    face with a stray CR in it ('f 1 2\\r3', one triangle in Mitsuba) was refused here."""
    with pytest.raises(SceneError) as e:
        prepare_scene(str(_obj_scene(tmp_path, (_TRI + "f 1 2 3\n").replace("\n", "\r"))))
    message = str(e.value)
    assert str(tmp_path / "m.obj") in message and "no faces" in message, message
    assert "; its lines end in CR alone" in message, message
    cs = prepare_scene(str(_obj_scene(tmp_path, _TRI + "f 1 2\r3\r\n")))
    assert len(cs.arrays.prims) == 1


@pytest.mark.mitsuba
def test_mitsuba_splits_obj_lines_at_lf_only_too(mi, tmp_path):
    path = tmp_path / "m.obj"
    path.write_bytes((_TRI + "f 1 2 3\n").replace("\n", "\r").encode())
    with pytest.raises(Exception):
        mi.load_dict({"type": "obj", "filename": str(path)})
    path.write_bytes((_TRI + "f 1 2\r3\r\n").encode())
    assert mi.load_dict({"type": "obj", "filename": str(path)}).face_count() == 1


def _ngon(n):
    """An exporter's n-gon with v/vt/vn corners on one face line (a cylinder's cap)."""
    ring = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return ("".join(f"v {np.cos(a):.6f} {np.sin(a):.6f} 0.000000\n" for a in ring)
            + "vn 0 0 1\nvt 0 0\nf " + " ".join(f"{k + 1}/1/1" for k in range(n)) + "\n")


_LONG_LINES = {   # name: (text, its long line's number and bytes, or None)
    "ngon-200": (_ngon(200), (203, 1493)),
    "ngon-100": (_ngon(100), None),                    # 690 bytes: read
    "face-1023": (_TRI + "f 1 2 3" + " " * 1016 + "\n", None),
    "face-1024-crlf": (_TRI + "f 1 2 3" + " " * 1016 + "\r\n", (4, 1024)),
    "comment-1024": (_TRI + "#" * 1024 + "\nf 1 2 3\n", (4, 1024)),
    "latin-1-comment": ((_TRI + "# " + "\xe9" * 1022 + "\nf 1 2 3\n"), (4, 1024)),
}


@pytest.mark.parametrize("case", sorted(_LONG_LINES))
def test_an_obj_line_of_1024_bytes_or_more_is_refused(tmp_path, case):
    """An outside review: Mitsuba refuses an OBJ with a line of 1024 bytes or more
    ("file contains an excessively long line"), as an exporter writes an n-gon of 200
    corners; it rendered here (198 triangles)."""
    text, long_line = _LONG_LINES[case]
    scene = _obj_scene(tmp_path, "")
    (tmp_path / "m.obj").write_bytes(text.encode("latin-1"))
    if long_line is None:
        assert len(prepare_scene(str(scene)).arrays.prims) > 0
        return
    with pytest.raises(SceneError) as e:
        prepare_scene(str(scene))
    line, size = long_line
    assert f"{tmp_path / 'm.obj'}:{line}: a line of {size} bytes" in str(e.value), str(e.value)


@pytest.mark.mitsuba
@pytest.mark.parametrize("case", sorted(_LONG_LINES))
def test_mitsuba_refuses_an_obj_line_of_1024_bytes_or_more_too(mi, tmp_path, case):
    text, long_line = _LONG_LINES[case]
    (tmp_path / "m.obj").write_bytes(text.encode("latin-1"))
    if long_line is None:
        assert mi.load_dict({"type": "obj", "filename": str(tmp_path / "m.obj")}).face_count()
        return
    with pytest.raises(Exception, match="excessively long line"):
        mi.load_dict({"type": "obj", "filename": str(tmp_path / "m.obj")})


_FACE_NORMALS = '<boolean name="face_normals" value="true"/>'
# normals Mitsuba refuses, which it reads past with face_normals (an exporter writes
# 'vn 0 0 0' for a degenerate face): name -> (mesh file text, kind)
_UNREAD_NORMALS = {
    "obj-zero-vn": (_TRI + "vn 0 0 0\nf 1//1 2//1 3//1\n", "obj"),
    "obj-nan-vn": (_TRI + "vn nan 0 1\nf 1//1 2//1 3//1\n", "obj"),
    "obj-short-vn": (_TRI + "vn 0 1\nf 1//1 2//1 3//1\n", "obj"),
    "obj-undefined-vn": (_TRI + "f 1//5 2//5 3//5\n", "obj"),
    "obj-some-faces-vn": (_TRI + "v 1 1 0\nvn 0 0 1\nf 1//1 2//1 3//1\nf 2 4 3\n", "obj"),
    "ply-normal-1e39": ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n"
                        "property float y\nproperty float z\nproperty double nx\n"
                        "property double ny\nproperty double nz\nelement face 1\n"
                        "property list uchar int vertex_indices\nend_header\n"
                        "0 0 0 0 0 1e39\n1 0 0 0 0 1\n0 1 0 0 0 1\n3 0 1 2\n", "ply"),
}


@pytest.mark.parametrize("case", sorted(_UNREAD_NORMALS))
def test_face_normals_reads_past_the_files_normals_as_mitsuba_does(tmp_path, case):
    """An outside review: with face_normals Mitsuba does not read an OBJ's vn lines or
    indices, nor a PLY's nx, ny, nz, and renders these meshes with the faces' normals;
    we refused them for normals the render does not use. Without face_normals they are
    still refused (Mitsuba refuses them too, or its normals there are undefined)."""
    text, kind = _UNREAD_NORMALS[case]
    (tmp_path / f"m.{kind}").write_text(text)
    scene = tmp_path / "s.xml"
    for extra in ("", _FACE_NORMALS):
        scene.write_text(_SCENE.format(mesh=f'<shape type="{kind}"><string name="filename" '
                                            f'value="m.{kind}"/>{extra}</shape>'))
        if not extra:
            with pytest.raises(SceneError, match=str(tmp_path / f"m.{kind}")):
                prepare_scene(str(scene))
            continue
        prims = prepare_scene(str(scene)).arrays.prims
        normals = _corner_normals(prepare_scene(str(scene)))
        assert len(prims) == text.count("\nf ") + ("3 0 1 2" in text)
        assert np.all(normals == 0)         # no vertex normals: the face's is used


@pytest.mark.mitsuba
@pytest.mark.parametrize("case", sorted(_UNREAD_NORMALS))
def test_mitsuba_renders_those_with_face_normals(mi, tmp_path, case):
    text, kind = _UNREAD_NORMALS[case]
    (tmp_path / f"m.{kind}").write_text(text)
    shape = mi.load_dict({"type": kind, "filename": str(tmp_path / f"m.{kind}"),
                          "face_normals": True})
    assert shape.face_count() >= 1 and not shape.has_vertex_normals()



_CARD = "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\n"
_OPPOSITE = _CARD + "f 1 2 3\nf 1 4 3\n"     # a quad's two triangles wound opposite ways


@pytest.mark.parametrize("text", [_OPPOSITE, _CARD + "f 1 2 3 4\nf 4 3 2 1\n"],
                         ids=["opposite-windings", "double-sided-card"])
def test_a_smooth_normal_that_cancels_out_is_refused(tmp_path, text):
    """An outside review: where faces wound opposite ways share a vertex, its smooth
    normal sums to 0, which Mitsuba's float32 sum leaves to rounding or sets to (1, 0, 0);
    ours took another, and a quad whose triangles are wound opposite ways rendered a
    block of 0.12 against Mitsuba's 0.004 (32 x 32 under a constant light)."""
    with pytest.raises(SceneError, match="cancels out") as e:
        prepare_scene(str(_obj_scene(tmp_path, text)))
    assert str(tmp_path / "m.obj") in str(e.value)
    assert "(-1, -1, 0)" in str(e.value) and "face_normals" in str(e.value)


@pytest.mark.parametrize("fix", ["consistent-winding", "face-normals"])
def test_a_mesh_wound_opposite_ways_loads_as_the_refusal_says(tmp_path, fix):
    text = _CARD + "f 1 2 3\nf 1 3 4\n" if fix == "consistent-winding" else _OPPOSITE
    scene = _obj_scene(tmp_path, text)
    if fix == "face-normals":
        scene.write_text(scene.read_text().replace(
            '<string name="filename" value="m.obj"/>',
            '<string name="filename" value="m.obj"/><boolean name="face_normals" '
            'value="true"/>'))
    assert prepare_scene(str(scene)).n_triangles == 2
