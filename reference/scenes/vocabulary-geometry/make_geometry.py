"""Write the meshes and the image of the vocabulary-geometry scene, one PLY per format and
per attribute set Mitsuba reads, and an 8-bit sRGB JPEG:

- ``bump.ply``: binary little endian, float: a 20 × 20 height field (a smooth bump),
  with analytic vertex normals and uv named ``u, v``.
- ``pebble.ply``: ASCII: a squashed icosphere (two subdivisions), no normals and no uv
  (smooth normals and barycentric uv computed by both renderers).
- ``gem.ply``: binary big endian, double: an octahedron with uv named ``texture_u,
  texture_v``, rendered with ``face_normals``.
- ``lamp.ply``: binary big endian: a quad facing +z (uv named ``s, t``); the scene turns
  it to face down and its light out of ``flip_normals``' side.
- ``tiles.jpg``: 16 × 16, random colours with dark grout lines (decoded from sRGB unless
  the scene says ``raw``), written at quality 95.

Run: python reference/scenes/vocabulary-geometry/make_geometry.py (needs Mitsuba for the
JPEG). The files are committed; rerunning rewrites them bit for bit.
"""

import os

import numpy as np

from estimators.pathtracer.meshes import write_ply

HERE = os.path.dirname(os.path.abspath(__file__))


def bump(n: int = 20):
    """Height field z = 0.35 exp(-4 r²) over [-1, 1]², its unit normals and uv."""
    g = np.linspace(-1.0, 1.0, n)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    h = 0.35 * np.exp(-4 * (x * x + y * y))
    grad = -8 * h                                   # d h / d x = grad · x
    normals = np.stack([-grad * x, -grad * y, np.ones_like(x)], 1)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    faces = []
    for r in range(n - 1):
        for c in range(n - 1):
            k = r * n + c
            faces += [[k, k + 1, k + n + 1], [k, k + n + 1, k + n]]
    return np.stack([x, y, h], 1), np.array(faces), normals, (np.stack([x, y], 1) + 1) / 2


def icosphere(subdivisions: int = 2):
    """Unit icosphere: (vertices, faces), every edge split at its midpoint per level."""
    t = (1 + 5 ** 0.5) / 2
    v = [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
         [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]]
    verts = [np.array(p, float) / np.linalg.norm(p) for p in v]
    faces = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9],
             [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2],
             [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10],
             [8, 6, 7], [9, 8, 1]]
    for _ in range(subdivisions):
        cache, out = {}, []

        def mid(a, b):
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = verts[a] + verts[b]
                verts.append(m / np.linalg.norm(m))
                cache[key] = len(verts) - 1
            return cache[key]

        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            out += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
        faces = out
    return np.array(verts), np.array(faces)


def octahedron():
    verts = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]],
                     float)
    faces = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4],
                      [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    uvs = np.stack([np.arctan2(verts[:, 1], verts[:, 0]) / (2 * np.pi) + 0.5,
                    (verts[:, 2] + 1) / 2], 1)
    return verts, faces, uvs


def tiles(n: int = 16) -> np.ndarray:
    rng = np.random.default_rng(31)
    img = rng.integers(40, 256, (n, n, 3))
    img[::4, :] = 15
    img[:, ::4] = 15
    return img.astype(np.uint8)


if __name__ == "__main__":
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    v, f, n, uv = bump()
    write_ply(os.path.join(HERE, "bump.ply"), v, f, normals=n, uvs=uv,
              fmt="binary_little_endian")
    v, f = icosphere()
    write_ply(os.path.join(HERE, "pebble.ply"), v * [1.0, 0.6, 1.0], f, fmt="ascii")
    v, f, uv = octahedron()
    write_ply(os.path.join(HERE, "gem.ply"), v, f, uvs=uv,
              uv_names=("texture_u", "texture_v"), fmt="binary_big_endian",
              vertex_type="double")
    write_ply(os.path.join(HERE, "lamp.ply"), [[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]],
              [[0, 1, 2], [0, 2, 3]], uvs=[[0, 0], [1, 0], [1, 1], [0, 1]],
              uv_names=("s", "t"), fmt="binary_big_endian")
    mi.Bitmap(tiles()).write(os.path.join(HERE, "tiles.jpg"), quality=95)
