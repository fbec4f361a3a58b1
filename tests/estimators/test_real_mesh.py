"""A real scanned mesh: the Stanford bunny at 58,784 triangles (reference/scenes/bunny),
so the BVH, the mesh loader and the speed figures are exercised at a realistic size."""

import os

import numpy as np
import pytest

import mcverify as mv
from estimators.pathtracer import prepare_scene
from mcverify.gate import reference

BUNNY = os.path.join(reference.REFERENCE_ROOT, "bunny")


def test_the_committed_mesh_is_what_the_script_makes():
    # make_bunny.py is the recipe; the committed OBJ must be its output (two levels of Loop
    # subdivision of the npm package's 3,674 triangles: 4**2 * 3674 triangles)
    scene = prepare_scene(os.path.join(BUNNY, "scene.xml"), params={"res": 16})
    assert scene.n_triangles == 16 * 3674 + 2 * 2          # bunny + floor + light rectangles
    with open(os.path.join(BUNNY, "bunny.obj"), encoding="ascii") as f:
        assert "2 levels of Loop subdivision" in f.readline()


def test_loop_subdivision_keeps_a_closed_surface_closed_and_smooth():
    import importlib.util

    spec = importlib.util.spec_from_file_location("make_bunny", os.path.join(BUNNY, "make_bunny.py"))
    mb = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mb)
    # an octahedron: closed, every vertex of valence 4; Loop's limit surface shrinks
    # towards the centre but stays a closed, consistently oriented surface
    v = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    f = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4],
                  [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    v2, f2 = mb.loop_subdivide(v, f)
    assert len(f2) == 4 * len(f) and len(v2) == 6 + 12
    edges = np.sort(np.concatenate([f2[:, [0, 1]], f2[:, [1, 2]], f2[:, [2, 0]]]), axis=1)
    _, count = np.unique(edges, axis=0, return_counts=True)
    assert np.all(count == 2)                                # closed, manifold
    def volume(v, f):
        return np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6
    assert 0 < volume(v2, f2) < volume(v, f)                 # same orientation, smoothed
    # a corner of valence n = 4 (β = 3/(8n) = 3/32) whose 4 neighbours sum to 0 moves to
    # (1 - nβ) v = 0.625 v; an edge point is 3/8 (a + b) + 1/8 (c + d), at radius
    # |3/8 (e_x + e_y) + 1/8 (e_z - e_z)| = 3/8 √2
    r = np.linalg.norm(v2, axis=1)
    np.testing.assert_allclose(r[:6], 0.625)
    np.testing.assert_allclose(r[6:], 0.375 * np.sqrt(2))


@pytest.mark.mitsuba
def test_the_bunny_passes_the_render_gate_and_a_planted_bug_fails_it():
    ok = mv.render_check("bunny", seed=21)
    assert ok.passed, (ok.summary(), ok.details["found_by"])
    bad = mv.render_check("bunny", seed=21, plant={"light_scale": 1.02})
    assert not bad.passed and "global" in bad.details["found_by"], bad.details["found_by"]
