"""Mitsuba's ``serialized`` meshes (the geometry of its material-preview scenes, refused
as an unsupported plugin until 7 December): files written here after the format (a
writer of a few lines, independent of the reader) read as Mitsuba 3.9.1 reads them, in
each version, precision and attribute set and at each index of a file of several
meshes; bad files are refused naming the file and the problem; the same mesh as PLY
and as serialized prepares bit for bit the same; and a scene of serialized meshes
passes the render gate against Mitsuba's reference."""

import struct
import zlib

import numpy as np
import pytest

from estimators.pathtracer import prepare_scene
from estimators.pathtracer.meshes import (read_serialized, serialized_mesh, write_ply,
                                          write_serialized)
from estimators.pathtracer.scene import SceneError

# the PLY tests' bent 3 × 3 grid: distinct positions, normals (not unit: Mitsuba
# normalises them) and uv, all exact in float32
from test_pathtracer_meshes import (_FACES as FACES, _NORMALS as NORMALS,  # noqa: E402
                                    _SCENE, _UVS as UVS, _VERTS as VERTS)


# name: (keyword arguments of serialized_mesh)
KINDS = {
    "bare-single": {},
    "normals-uv-single": {"normals": NORMALS, "uvs": UVS},
    "normals-uv-double": {"normals": NORMALS, "uvs": UVS, "double": True},
    "uv-colours-double": {"uvs": UVS, "colours": np.abs(VERTS), "double": True},
    "normals-colours-v3": {"normals": NORMALS, "colours": np.abs(VERTS), "version": 3},
    "uv-v3-double": {"uvs": UVS, "version": 3, "double": True},
}


def _two_meshes(tmp_path, kind):
    """A file of two meshes: a bare triangle, then the grid as ``kind`` says."""
    extra = dict(KINDS[kind])
    version = extra.get("version", 4)
    first = serialized_mesh(VERTS[:3] * 2, [[0, 1, 2]], version=version)
    return write_serialized(tmp_path / f"{kind}.serialized",
                            [first, serialized_mesh(VERTS, FACES, **extra)], version)


@pytest.mark.mitsuba
@pytest.mark.parametrize("face_normals", [False, True])
@pytest.mark.parametrize("kind", sorted(KINDS))
def test_each_mesh_of_a_file_reads_as_mitsuba_reads_it(mi, tmp_path, kind, face_normals):
    path = _two_meshes(tmp_path, kind)
    for index in (0, 1):
        ours = read_serialized(path, index, normals=not face_normals)
        theirs = mi.traverse(mi.load_dict({"type": "serialized", "filename": path,
                                           "shape_index": index,
                                           "face_normals": face_normals}))
        np.testing.assert_array_equal(ours.vertices.astype(np.float32).ravel(),
                                      np.array(theirs["vertex_positions"]))
        np.testing.assert_array_equal(ours.faces.ravel(), np.array(theirs["faces"]))
        uvs = np.array(theirs["vertex_texcoords"])
        assert (ours.uvs is None) == (uvs.size == 0)
        if ours.uvs is not None:
            np.testing.assert_array_equal(ours.uvs.astype(np.float32).ravel(), uvs)
        if ours.normals is not None:     # Mitsuba's hold the file's, normalised
            unit = ours.normals / np.linalg.norm(ours.normals, axis=1, keepdims=True)
            np.testing.assert_allclose(unit.ravel(), np.array(theirs["vertex_normals"]),
                                       atol=1e-6)
        else:                            # none in the file (computed later) or face normals
            assert face_normals or "normals" not in KINDS[kind] or index == 0


@pytest.mark.mitsuba
def test_mesh_0_of_a_file_without_a_dictionary_reads_as_mitsuba_reads_it(mi, tmp_path):
    """Mitsuba seeks the end-of-file dictionary for shape_index > 0 only: a lone mesh
    stream (a writer that leaves the dictionary out) loads as mesh 0, and anything after
    the zlib stream is not read."""
    path = tmp_path / "lone.serialized"
    path.write_bytes(serialized_mesh(VERTS, FACES, uvs=UVS) + b"not read")
    theirs = mi.load_dict({"type": "serialized", "filename": str(path)})
    ours = read_serialized(str(path))
    np.testing.assert_array_equal(ours.faces.ravel(), np.array(theirs.faces_buffer()))


def _bytes(tmp_path, name, data):
    (tmp_path / name).write_bytes(data)
    return str(tmp_path / name)


def _good(tmp_path):
    return open(_two_meshes(tmp_path, "normals-uv-single"), "rb").read()


# name: (make the file's bytes from a good two-mesh file's, shape_index, what the
# message says, Mitsuba refuses it too)
BAD = {
    "empty": (lambda good: b"", 0, "shorter than its 4-byte header", True),
    "wrong-identifier": (lambda good: b"\x1d\x04" + good[2:], 0,
                         "starts with 0x041D, not the format identifier 0x041C", True),
    "version-5": (lambda good: good[:2] + b"\x05\x00" + good[4:], 0,
                  "format version 5; Mitsuba reads versions 3 and 4", True),
    "truncated": (lambda good: good[:40], 0, "truncated: its compressed data ends", True),
    "zlib-error": (lambda good: good[:4] + b"\x00\x00" + good[6:], 0,
                   "compressed data is corrupt (zlib", True),
    "negative-index": (lambda good: good, -1, "shape_index=-1; it must be >= 0", True),
    # Mitsuba reads one dictionary entry too far here ("read 4 out of 8 bytes")
    "index-is-the-count": (lambda good: good, 2, "shape_index=2, but the file holds 2 "
                                                 "meshes (indices 0 to 1)", True),
    "index-beyond": (lambda good: good, 7, "shape_index=7, but the file holds 2 meshes",
                     True),
    "no-dictionary": (lambda good: serialized_mesh(VERTS, FACES), 1,
                      "end-of-file dictionary claims", False),
    "vertex-out-of-range": (lambda good: serialized_mesh(VERTS, [[0, 1, 9]]), 0,
                            "triangle 0 refers to vertex 9; the mesh has 9 vertices",
                            False),
    "nan-position": (lambda good: serialized_mesh(np.where(VERTS == 1, np.nan, VERTS), FACES), 0,
                     "a non-finite position", False),
    "no-triangles": (lambda good: serialized_mesh(VERTS, np.zeros((0, 3))), 0,
                     "the mesh has no triangles", False),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_files_are_refused_naming_the_file_and_the_problem(tmp_path, case):
    make, index, needle, _ = BAD[case]
    path = _bytes(tmp_path, "bad.serialized", make(_good(tmp_path)))
    with pytest.raises(SceneError) as e:
        read_serialized(path, index)
    assert str(e.value).startswith(path) and needle in str(e.value), str(e.value)


@pytest.mark.mitsuba
@pytest.mark.parametrize("case", sorted(c for c in BAD if BAD[c][3]))
def test_mitsuba_refuses_them_too(mi, tmp_path, case):
    make, index, _, _ = BAD[case]
    path = _bytes(tmp_path, "bad.serialized", make(_good(tmp_path)))
    with pytest.raises(Exception):
        mi.load_dict({"type": "serialized", "filename": path, "shape_index": index})




@pytest.mark.parametrize("kind", sorted(KINDS))
@pytest.mark.parametrize("face_normals", ["false", "true"])
def test_the_same_mesh_as_ply_and_as_serialized_prepares_identically(tmp_path, kind,
                                                                     face_normals):
    """Mesh 1 of each file, transformed, against the same grid as a PLY: the same
    triangles, normals (the file's, or smooth ones computed) and uv, bit for bit."""
    extra = KINDS[kind]
    write_ply(str(tmp_path / "grid.ply"), VERTS, FACES, normals=extra.get("normals"),
              uvs=extra.get("uvs"), vertex_type="double" if extra.get("double") else "float")
    serialized = _two_meshes(tmp_path, kind)
    common = (f'<boolean name="face_normals" value="{face_normals}"/>'
              '<transform name="to_world"><scale x="1.3" y="0.8"/><rotate z="1" angle="20"/>'
              '</transform>')
    prims = []
    for mesh in ('<shape type="ply"><string name="filename" value="grid.ply"/>',
                 f'<shape type="serialized"><string name="filename" value="{serialized}"/>'
                 '<integer name="shape_index" value="1"/>'):
        scene = tmp_path / "s.xml"
        scene.write_text(_SCENE.format(mesh=mesh + common + "</shape>"))
        prims.append(prepare_scene(str(scene)).arrays.prims)
    np.testing.assert_array_equal(prims[1], prims[0])


@pytest.mark.parametrize("prop,needle", [
    ('<boolean name="flip_tex_coords" value="true"/>', "flip_tex_coords"),
    ('<float name="max_smooth_angle" value="30"/>', "max_smooth_angle"),
    ('<integer name="shape_index" value="5"/>', "shape_index=5, but the file holds 2 meshes"),
    ('<integer name="shape_index" value="2147483648"/>', "32-bit integers"),
])
def test_what_mitsuba_refuses_on_a_serialized_shape_is_refused_naming_the_line(
        tmp_path, prop, needle):
    path = _two_meshes(tmp_path, "bare-single")
    scene = tmp_path / "s.xml"
    scene.write_text(_SCENE.format(mesh=f'<shape type="serialized"><string name="filename" '
                                        f'value="{path}"/>{prop}</shape>'))
    with pytest.raises(SceneError) as e:
        prepare_scene(str(scene))
    assert f"{scene}:8" in str(e.value) and needle in str(e.value), str(e.value)


def test_a_long_mesh_name_is_read_past(tmp_path):
    """A version 4 mesh's name is read past a chunk at a time (it was a byte a call: a
    3 MB name took 1.2 s; a read-only review): a name of 2 MB, spanning many inflated
    chunks, and the mesh after it read whole."""
    path = tmp_path / "long.serialized"
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float32)
    body = (struct.pack("<I", 0x1000) + b"x" * 2_000_000 + b"\0" + struct.pack("<QQ", 3, 1)
            + verts.tobytes() + np.array([0, 1, 2], "<u4").tobytes())
    path.write_bytes(struct.pack("<HH", 0x041C, 4) + zlib.compress(body))
    mesh = read_serialized(str(path))
    assert np.array_equal(mesh.vertices, verts) and mesh.faces.tolist() == [[0, 1, 2]]
