"""Make ``bunny.obj``: the Stanford bunny at a realistic size, for the BVH and the speed
figures (``mcverify bench``) to be measured on a real scanned mesh.

Source: the npm package ``bunny`` (1.0.1, public domain; the Stanford 3D Scanning
Repository's bunny reduced to 1,839 vertices and 3,674 triangles). Two levels of Loop
subdivision (Loop 1987) bring it to 58,784 triangles, the size of the usual 70k-triangle
scan, with a smooth surface; the scan's holes (at its base) stay boundaries, subdivided
with Loop's boundary rules. No normals are written: Mitsuba and our tracer both compute
smooth vertex normals for an OBJ without them.

    python reference/scenes/bunny/make_bunny.py            # runs `npm pack bunny`
    python reference/scenes/bunny/make_bunny.py index.js   # or from the package's index.js
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tarfile
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))


def read_package(index_js: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(positions (n, 3), triangles (m, 3)) of the npm package ``bunny``."""
    if index_js is None:
        with tempfile.TemporaryDirectory() as tmp:
            subprocess.run(["npm", "pack", "bunny@1.0.1"], cwd=tmp, check=True,
                           capture_output=True)
            with tarfile.open(os.path.join(tmp, "bunny-1.0.1.tgz")) as tar:
                text = tar.extractfile("package/index.js").read().decode()
    else:
        with open(index_js, encoding="utf-8") as f:
            text = f.read()
    grab = lambda key: json.loads(re.search(rf"exports\.{key}=(\[.*?\]\])", text, re.S)[1])  # noqa: E731
    return np.array(grab("positions"), float), np.array(grab("cells"), np.int64)


def loop_subdivide(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One level of Loop subdivision, with the boundary rules (creases at holes)."""
    n = len(v)
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    opposite = np.concatenate([f[:, 2], f[:, 0], f[:, 1]])
    uniq, inv, count = np.unique(edges, axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    boundary = count == 1
    # edge points: 3/8 (a + b) + 1/8 (c + d) inside, the midpoint on a boundary
    opp_sum = np.zeros((len(uniq), 3))
    np.add.at(opp_sum, inv, v[opposite])
    a, b = v[uniq[:, 0]], v[uniq[:, 1]]
    edge_pts = np.where(boundary[:, None], 0.5 * (a + b), 0.375 * (a + b) + 0.125 * opp_sum)
    # vertex points: Loop's β over the neighbours inside; 3/4 v + 1/8 (two boundary
    # neighbours) on a boundary
    nb_sum = np.zeros((n, 3))
    valence = np.zeros(n)
    np.add.at(nb_sum, uniq[:, 0], v[uniq[:, 1]])
    np.add.at(nb_sum, uniq[:, 1], v[uniq[:, 0]])
    np.add.at(valence, uniq.ravel(), 1)
    bd_sum = np.zeros((n, 3))
    bd_count = np.zeros(n)
    be = uniq[boundary]
    np.add.at(bd_sum, be[:, 0], v[be[:, 1]])
    np.add.at(bd_sum, be[:, 1], v[be[:, 0]])
    np.add.at(bd_count, be.ravel(), 1)
    beta = np.where(valence > 3, 3.0 / (8.0 * np.maximum(valence, 1)), 3.0 / 16.0)
    inner = (1 - valence * beta)[:, None] * v + beta[:, None] * nb_sum
    on_bd = bd_count == 2
    new_v = np.where(on_bd[:, None], 0.75 * v + 0.125 * bd_sum, inner)
    # four triangles per triangle, consistently oriented
    e = inv.reshape(3, -1).T + n          # edge-point index of (01, 12, 20) per face
    f0, f1, f2 = f[:, 0], f[:, 1], f[:, 2]
    e01, e12, e20 = e[:, 0], e[:, 1], e[:, 2]
    faces = np.concatenate([np.stack([f0, e01, e20], 1), np.stack([f1, e12, e01], 1),
                            np.stack([f2, e20, e12], 1), np.stack([e01, e12, e20], 1)])
    return np.concatenate([new_v, edge_pts]), faces


def write_obj(path: str, v: np.ndarray, f: np.ndarray) -> None:
    with open(path, "w", encoding="ascii") as out:
        out.write(f"# Stanford bunny (npm 'bunny' 1.0.1), 2 levels of Loop subdivision: "
                  f"{len(v)} vertices, {len(f)} triangles; made by make_bunny.py\n")
        out.write("".join(f"v {x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in v))
        out.write("".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in f))


def main(argv=None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    v, f = read_package(argv[0] if argv else None)
    for _ in range(2):
        v, f = loop_subdivide(v, f)
    # the package's bunny is ~10 units tall, y up; scale to 1 unit, base on y = 0
    v = (v - [0.5 * (v[:, 0].min() + v[:, 0].max()), v[:, 1].min(),
              0.5 * (v[:, 2].min() + v[:, 2].max())]) / (v[:, 1].max() - v[:, 1].min())
    write_obj(os.path.join(HERE, "bunny.obj"), v, f)
    print(f"bunny.obj: {len(v)} vertices, {len(f)} triangles")


if __name__ == "__main__":
    main()
