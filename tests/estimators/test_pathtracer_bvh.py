"""The tracer's BVH: the packed layout (``geometry.pack_bvh``) is a valid hierarchy over
every primitive, and traversal finds what a brute-force test of every primitive finds."""

import numpy as np
import pytest

from estimators.pathtracer import geometry, layout
from estimators.pathtracer.layout import (LEAF_KIND, LEAF_PRIM, NODE_COUNT, NODE_FIRST,
                                          NODE_HI, NODE_LO, PRIM_WIDTH, SPHERE, TRIANGLE)


def _soup(n_tri, n_sphere, seed):
    """Random triangles (some long and thin, some tiny) and spheres in [-1, 1]³."""
    rng = np.random.default_rng(seed)
    prims = np.zeros((n_tri + n_sphere, PRIM_WIDTH))
    info = np.zeros((n_tri + n_sphere, 2), dtype=np.int64)
    centre = rng.uniform(-1, 1, (n_tri, 1, 3))
    size = 10.0 ** rng.uniform(-3, -0.5, (n_tri, 1, 1))
    v = centre + size * rng.normal(size=(n_tri, 3, 3))
    prims[:n_tri, layout.TRI_P0:layout.TRI_P0 + 3] = v[:, 0]
    prims[:n_tri, layout.TRI_P1:layout.TRI_P1 + 3] = v[:, 1]
    prims[:n_tri, layout.TRI_P2:layout.TRI_P2 + 3] = v[:, 2]
    info[:n_tri, layout.PRIM_KIND] = TRIANGLE
    s = slice(n_tri, None)
    prims[s, layout.SPHERE_CENTER:layout.SPHERE_CENTER + 3] = rng.uniform(-1, 1, (n_sphere, 3))
    prims[s, layout.SPHERE_RADIUS] = rng.uniform(0.01, 0.2, n_sphere)
    info[s, layout.PRIM_KIND] = SPHERE
    info[:, layout.PRIM_SHAPE] = np.arange(len(prims))
    return prims, info


def _brute(prims, info, o, d):
    """Nearest hit over all primitives, by numpy (Möller–Trumbore; the sphere's roots):
    (t of every primitive, inf where missed)."""
    t = np.full(len(prims), np.inf)
    tri = info[:, layout.PRIM_KIND] == TRIANGLE
    p0 = prims[tri, layout.TRI_P0:layout.TRI_P0 + 3]
    e1 = prims[tri, layout.TRI_P1:layout.TRI_P1 + 3] - p0
    e2 = prims[tri, layout.TRI_P2:layout.TRI_P2 + 3] - p0
    pv = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, pv)
    with np.errstate(divide="ignore", invalid="ignore"):
        sv = o - p0
        b1 = np.einsum("ij,ij->i", sv, pv) / det
        qv = np.cross(sv, e1)
        b2 = qv @ d / det
        th = np.einsum("ij,ij->i", e2, qv) / det
    ok = (b1 >= 0) & (b2 >= 0) & (b1 + b2 <= 1) & (th > 0)
    t[tri] = np.where(ok, th, np.inf)
    sph = ~tri
    c = prims[sph, layout.SPHERE_CENTER:layout.SPHERE_CENTER + 3]
    r = prims[sph, layout.SPHERE_RADIUS]
    f = o - c
    b = f @ d
    disc = b * b - (np.einsum("ij,ij->i", f, f) - r * r)
    s = np.sqrt(np.maximum(disc, 0.0))
    near, far = -b - s, -b + s
    ts = np.where(near > 0, near, np.where(far > 0, far, np.inf))
    t[sph] = np.where(disc >= 0, ts, np.inf)
    return t


@pytest.fixture(scope="module", params=[(1, 0), (7, 2), (3000, 40)],
                ids=lambda p: f"{p[0]}tri+{p[1]}sph")
def packed(request):
    prims, info = _soup(*request.param, seed=sum(request.param))
    nb, ni, order = geometry.build_bvh(prims, info)
    return prims, info, geometry.pack_bvh(prims, info, nb, ni, order)


def test_packed_hierarchy_is_valid(packed):
    """Every primitive sits in exactly one leaf; leaves hold their primitives' boxes,
    interior nodes their children's boxes; leaf rows are the primitives' own data."""
    prims, info, (nodes, leaf, leaf_info) = packed
    lo, hi = geometry._prim_bounds(prims, info)
    assert sorted(leaf_info[:, LEAF_PRIM]) == list(range(len(prims)))
    np.testing.assert_array_equal(leaf_info[:, LEAF_KIND],
                                  info[leaf_info[:, LEAF_PRIM], layout.PRIM_KIND])
    seen = np.zeros(len(prims), dtype=int)
    stack = [0]
    while stack:
        i = stack.pop()
        box_lo, box_hi = nodes[i, NODE_LO:NODE_LO + 3], nodes[i, NODE_HI:NODE_HI + 3]
        first, count = int(nodes[i, NODE_FIRST]), int(nodes[i, NODE_COUNT])
        if count >= 0:
            for k in range(first, first + count):
                seen[k] += 1
                j = leaf_info[k, LEAF_PRIM]
                assert np.all(box_lo <= lo[j]) and np.all(hi[j] <= box_hi)
        else:
            assert -count - 1 in (0, 1, 2)
            for child in (first, first + 1):
                assert i < child < len(nodes)
                assert np.all(box_lo <= nodes[child, NODE_LO:NODE_LO + 3])
                assert np.all(nodes[child, NODE_HI:NODE_HI + 3] <= box_hi)
                stack.append(child)
    assert np.all(seen == 1)
    tri = leaf_info[:, LEAF_KIND] == TRIANGLE
    j = leaf_info[tri, LEAF_PRIM]
    np.testing.assert_array_equal(leaf[tri, layout.LEAF_E2:layout.LEAF_E2 + 3],
                                  prims[j, layout.TRI_P2:layout.TRI_P2 + 3]
                                  - prims[j, layout.TRI_P0:layout.TRI_P0 + 3])


def test_traversal_finds_the_brute_force_nearest_hit(packed):
    """Rays from outside and inside the soup, in every direction: the nearest hit, its
    primitive and whether anything lies before a limit agree with testing every
    primitive (rays whose two nearest hits are within 1e-9 are ties, not compared)."""
    prims, info, (nodes, leaf, leaf_info) = packed
    rng = np.random.default_rng(5)
    stack = geometry.new_stack()
    hits = 0
    for k in range(600):
        o = rng.uniform(-1.2, 1.2, 3) if k % 2 else 3.0 * rng.normal(size=3)
        # aim at a point of a random primitive (a triangle's or a sphere's centre)
        j = rng.integers(len(prims))
        if info[j, layout.PRIM_KIND] == TRIANGLE:
            w = rng.dirichlet(np.ones(3))
            target = w @ prims[j, layout.TRI_P0:layout.TRI_P2 + 3].reshape(3, 3)
        else:
            target = prims[j, layout.SPHERE_CENTER:layout.SPHERE_CENTER + 3]
        d = target - o if k % 3 else rng.normal(size=3)
        if k % 5 == 0:
            d[rng.integers(3)] = 0.0         # some rays parallel to a coordinate plane
        if not np.any(d):
            continue
        d /= np.linalg.norm(d)
        ts = _brute(prims, info, o, d)
        order = np.argsort(ts)
        t, j, _, _ = geometry.intersect(nodes, leaf, leaf_info, stack, *o, *d, 0.0, np.inf)
        if not np.isfinite(ts[order[0]]):
            assert j < 0, (o, d)
            continue
        hits += 1
        if len(ts) > 1 and ts[order[1]] - ts[order[0]] < 1e-9 * (1 + ts[order[0]]):
            continue
        assert j == order[0], (o, d, t, ts[order[0]])
        assert abs(t - ts[j]) <= 1e-9 * (1 + t)
        limit = ts[j] * rng.choice([0.5, 2.0])
        blocked = geometry.occluded(nodes, leaf, leaf_info, stack, *o, *d, 0.0, limit)
        assert blocked == (limit > ts[j])
    assert hits > 50
