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
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "vocabulary-geometry"))
from make_geometry import bump, icosphere, octahedron  # noqa: E402

from estimators.pathtracer.meshes import serialized_mesh, write_serialized  # noqa: E402


if __name__ == "__main__":
    v, f, n, uv = bump()
    sphere_v, sphere_f = icosphere()
    quad = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
    write_serialized(os.path.join(HERE, "meshes.serialized"), [
        serialized_mesh(v, f, normals=n, uvs=uv, double=True, name="bump"),
        serialized_mesh(sphere_v * [1.0, 0.6, 1.0], sphere_f, name="pebble"),
        serialized_mesh(quad, [[0, 1, 2], [0, 2, 3]], uvs=(quad[:, :2] + 1) / 2,
                        colours=np.abs(quad), name="lamp")])
    gem_v, gem_f, gem_uv = octahedron()
    write_serialized(os.path.join(HERE, "gem.serialized"), [
        serialized_mesh(quad[:3], [[0, 1, 2]], version=3),
        serialized_mesh(gem_v, gem_f, normals=gem_v, uvs=gem_uv, double=True, version=3)],
        version=3)
