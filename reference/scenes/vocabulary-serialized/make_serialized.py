"""Write the meshes of the vocabulary-serialized scene, Mitsuba's ``serialized`` format in
each version, precision and attribute set:

- ``meshes.serialized``, version 4: mesh 0, the bump of vocabulary-geometry (a height
  field) in double precision with normals and uv; mesh 1, its pebble (an icosphere) in
  single precision, bare (smooth normals and barycentric uv computed by both
  renderers); mesh 2, a quad facing +z with uv and vertex colours (read past), which the
  scene turns to face down and lights out of ``flip_normals``' side.
- ``gem.serialized``, version 3 (uint32 offsets, no mesh names): mesh 0 a stray
  triangle, mesh 1 the octahedron with normals and uv, rendered with ``face_normals``.

Run: python reference/scenes/vocabulary-serialized/make_serialized.py. The files are
committed; rerunning rewrites them bit for bit.
"""

import os
import struct
import sys
import zlib

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "vocabulary-geometry"))
from make_geometry import bump, icosphere, octahedron  # noqa: E402


def mesh_stream(v, f, *, normals=None, uvs=None, colours=None, double=False, version=4,
                name="mesh"):
    """One mesh: the identifier and version, then the zlib stream of its flags, name
    (version 4), counts and arrays."""
    flags = (0x2000 if double else 0x1000) | (normals is not None) * 0x1 \
        | (uvs is not None) * 0x2 | (colours is not None) * 0x8
    ftype = "<f8" if double else "<f4"
    body = struct.pack("<I", flags) + (name.encode() + b"\0" if version == 4 else b"")
    body += struct.pack("<QQ", len(v), len(f))
    body += b"".join(np.asarray(a, ftype).tobytes() for a in (v, normals, uvs, colours)
                     if a is not None)
    body += np.asarray(f, "<u4").tobytes()
    return struct.pack("<HH", 0x041C, version) + zlib.compress(body, 9)


def write_serialized(path, streams, version=4):
    offsets = np.cumsum([0] + [len(s) for s in streams[:-1]])
    with open(path, "wb") as out:
        out.write(b"".join(streams))
        out.write(np.asarray(offsets, "<u8" if version == 4 else "<u4").tobytes())
        out.write(struct.pack("<I", len(streams)))


if __name__ == "__main__":
    v, f, n, uv = bump()
    sphere_v, sphere_f = icosphere()
    quad = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
    write_serialized(os.path.join(HERE, "meshes.serialized"), [
        mesh_stream(v, f, normals=n, uvs=uv, double=True, name="bump"),
        mesh_stream(sphere_v * [1.0, 0.6, 1.0], sphere_f, name="pebble"),
        mesh_stream(quad, [[0, 1, 2], [0, 2, 3]], uvs=(quad[:, :2] + 1) / 2,
                    colours=np.abs(quad), name="lamp")])
    gem_v, gem_f, gem_uv = octahedron()
    write_serialized(os.path.join(HERE, "gem.serialized"), [
        mesh_stream(quad[:3], [[0, 1, 2]], version=3),
        mesh_stream(gem_v, gem_f, normals=gem_v, uvs=gem_uv, double=True, version=3)],
        version=3)
