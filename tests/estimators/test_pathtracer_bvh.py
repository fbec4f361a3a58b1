"""The tracer's BVH: the packed layout (``geometry.pack_bvh``, the binary SAH tree
collapsed 4-wide) is a valid hierarchy over every primitive, traversal finds what a
brute-force test of every primitive finds, and the four box tests of a node compile to
AVX2 instructions."""

import re

import llvmlite.binding as llvm
import numpy as np
import pytest
from hypothesis import event, example, given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from numba import njit

from estimators.pathtracer import geometry, layout
from estimators.pathtracer.layout import (LEAF_KIND, LEAF_PRIM, NODE_ARITY, NODE_HI,
                                          NODE_LO, PRIM_WIDTH, SPHERE, TRIANGLE)

# direct calls of the tracer's per-ray functions compile as inside the kernels
pytestmark = pytest.mark.usefixtures("kernel_compile_context")


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


def _child_box(nodes, i, k):
    """(lo, hi) of child slot k of 4-wide node i."""
    axes = NODE_ARITY * np.arange(3) + k
    return nodes[i, NODE_LO + axes], nodes[i, NODE_HI + axes]


def test_packed_hierarchy_is_valid(packed):
    """Every primitive sits in exactly one leaf; leaves hold their primitives' boxes,
    4-wide nodes their children's boxes; every node but the root is one child of one
    node, stored after it; a node with an unused slot has only leaves (the collapse
    opened every interior child it could); unused slots are empty boxes (+inf corners)
    of no primitives; leaf rows are the primitives' own data; the rows are 32-byte
    aligned."""
    _check_hierarchy(*packed)


def _check_hierarchy(prims, info, packed):
    nodes, leaf, leaf_info = packed
    lo, hi = geometry._prim_bounds(prims, info)
    assert nodes.flags.c_contiguous and nodes.ctypes.data % 32 == 0
    # the traversal reads the three tables flat, row · the layout's width + column
    assert nodes.shape[1] == layout.NODE_WIDTH and leaf.shape[1] == layout.LEAF_WIDTH
    assert leaf_info.shape[1] == layout.LEAF_INFO_WIDTH
    assert leaf.flags.c_contiguous and leaf_info.flags.c_contiguous
    assert sorted(leaf_info[:, LEAF_PRIM]) == list(range(len(prims)))
    np.testing.assert_array_equal(leaf_info[:, LEAF_KIND],
                                  info[leaf_info[:, LEAF_PRIM], layout.PRIM_KIND])
    seen = np.zeros(len(prims), dtype=int)
    parents = np.zeros(len(nodes), dtype=int)
    # (node, the box its parent gives it); the root's: everything
    stack = [(0, np.full(3, -np.inf), np.full(3, np.inf))]
    while stack:
        i, box_lo, box_hi = stack.pop()
        counts = geometry.child_links(nodes)[1][i]
        unused = nodes[i, NODE_LO:NODE_LO + NODE_ARITY] == np.inf
        assert not unused.any() or np.all(counts >= 0), (i, counts)
        for k in range(NODE_ARITY):
            c_lo, c_hi = _child_box(nodes, i, k)
            link, count = (int(a[i, k]) for a in geometry.child_links(nodes))
            if np.all(c_lo == np.inf):
                assert np.all(c_hi == np.inf) and count == 0, (i, k)
                continue
            assert np.all(box_lo <= c_lo) and np.all(c_hi <= box_hi), (i, k)
            if count >= 0:
                assert count > 0, (i, k)
                for j in leaf_info[link:link + count, LEAF_PRIM]:
                    assert np.all(c_lo <= lo[j]) and np.all(hi[j] <= c_hi)
                seen[link:link + count] += 1
            else:
                assert count == -1 and i < link < len(nodes), (i, k, link)
                parents[link] += 1
                stack.append((link, c_lo, c_hi))
    assert np.all(seen == 1)
    assert parents[0] == 0 and np.all(parents[1:] == 1)
    assert leaf.flags.c_contiguous and leaf.ctypes.data % 32 == 0
    n = len(leaf_info)
    tri = leaf_info[:, LEAF_KIND] == TRIANGLE
    j = leaf_info[tri, LEAF_PRIM]
    np.testing.assert_array_equal(leaf[:n][tri, layout.LEAF_E2:layout.LEAF_E2 + 3],
                                  prims[j, layout.TRI_P2:layout.TRI_P2 + 3]
                                  - prims[j, layout.TRI_P0:layout.TRI_P0 + 3])
    _check_triangle_groups(nodes, leaf, leaf_info)


def _check_triangle_groups(nodes, leaf, leaf_info):
    """Every triangle row is in exactly one group; a group is up to 4 consecutive
    triangle rows of one leaf, and a run of triangles in a leaf is cut into groups of 4
    (only its last is smaller); a group's lanes are its rows' p0, e1, e2, lane by lane,
    and 0 past its size; the lane rows follow the primitives' rows, 3 per group."""
    n = len(leaf_info)
    kind, group, size = (leaf_info[:, c] for c in (LEAF_KIND, layout.LEAF_GROUP,
                                                   layout.LEAF_GROUP_SIZE))
    assert np.all((group >= 0) == (size > 0))
    assert len(leaf) == n + layout.LEAF_GROUP_ROWS * np.count_nonzero(size)
    covered = np.zeros(n, dtype=int)
    leaf_of = np.full(n, -1)
    firsts, counts = (a.ravel() for a in geometry.child_links(nodes))
    for i, (first, count) in enumerate(zip(firsts[counts > 0], counts[counts > 0])):
        leaf_of[first:first + count] = i
    for k in np.flatnonzero(size):
        g, m = group[k], size[k]
        assert 1 <= m <= NODE_ARITY and np.all(kind[k:k + m] == TRIANGLE)
        assert len(set(leaf_of[k:k + m])) == 1
        if m < NODE_ARITY and k + m < n and leaf_of[k + m] == leaf_of[k]:
            assert kind[k + m] != TRIANGLE, k      # a run is cut short only at its end
        covered[k:k + m] += 1
        lanes = leaf[g:g + layout.LEAF_GROUP_ROWS].reshape(9, NODE_ARITY)
        np.testing.assert_array_equal(lanes[:, :m],
                                      leaf[k:k + m, layout.LEAF_P0:layout.LEAF_E2 + 3].T)
        assert np.all(lanes[:, m:] == 0.0)
    assert np.array_equal(covered, (kind == TRIANGLE).astype(int))


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


# ------------------------------------------------------------------ property test
# Coordinates from a coarse grid or anywhere in [-1, 1]: grid values make flat boxes
# (axis-aligned triangles), shared vertices and edges, and ray origins exactly on slab
# planes, where a ray parallel to the plane (d component 0: 1/d = inf) gives 0 · inf.
_coord = st.one_of(st.sampled_from([-1.0, -0.5, 0.0, 0.25, 0.5, 1.0]),
                   st.floats(-1.0, 1.0, allow_subnormal=False))
_dir = st.one_of(st.sampled_from([-1.0, -0.0, 0.0, 0.5, 1.0]),
                 st.floats(-1.0, 1.0, allow_subnormal=False))


def _brute_hits(leaf, leaf_info, o, d):
    """t of every leaf row by the tracer's own primitive test (no hierarchy), and its
    (b1, b2)."""
    out = [geometry._hit_prim(leaf[k], leaf_info[k, LEAF_KIND], *o, *d)
           for k in range(len(leaf_info))]
    return np.array([h[0] for h in out]), [h[1:] for h in out]


def _leaf_paths(nodes, n_rows):
    """For each leaf row, the boxes (lo, hi) of the children a ray passes to reach it,
    from the root's child down to its leaf."""
    paths = [None] * n_rows
    stack = [(0, [])]
    while stack:
        i, path = stack.pop()
        for k in range(NODE_ARITY):
            link, count = (int(a[i, k]) for a in geometry.child_links(nodes))
            here = path + [_child_box(nodes, i, k)]
            if count < 0:
                stack.append((link, here))
            for row in range(link, link + max(count, 0)):
                paths[row] = here
    return paths


def _admits(lo, hi, o, inv, t):
    """The box test written out on Python floats: the ray's span in the box within
    [0, t] by slabs (each axis's near plane by the sign of 1/d; a product 0 · inf = NaN,
    a ray in a slab's plane and parallel to it, leaves the span as it is), accepted with
    the traversal's relative slack 4e-16. True where a hit at t lies in the box."""
    t0, t1 = 0.0, float(t)
    for a in range(3):
        near, far = (lo[a], hi[a]) if inv[a] >= 0.0 else (hi[a], lo[a])
        tn, tf = (float(near) - o[a]) * inv[a], (float(far) - o[a]) * inv[a]
        if tn > t0:
            t0 = tn
        if tf < t1:
            t1 = tf
    return t0 <= t1 * (1.0 + 4e-16)


@given(tris=st.integers(1, 48).flatmap(
           lambda n: arrays(np.float64, (n, 9), elements=_coord)),
       origins=arrays(np.float64, (12, 3), elements=_coord),
       dirs=arrays(np.float64, (12, 3), elements=_dir),
       t_min=st.sampled_from([0.0, 1e-4]))
# a triangle in the plane y = -0.5 with a vertex at x = -0.5, its box's hi x face, and
# rays parallel to that face, in it (x = -0.5, where (hi - o) / 0 = 0 · inf) and in its
# lo face (x = -1): each hits the triangle on its boundary
@example(tris=np.array([[-0.5, -0.5, -1.0, -1.0, -0.5, -0.5, -0.5, -0.5, -0.5]]),
         origins=np.repeat([[-0.5, -1.0, -0.5], [-1.0, -1.0, -0.5]], 6, axis=0),
         dirs=np.repeat([[-0.0, 0.5, -0.0], [0.0, 1.0, 0.0]], 6, axis=0), t_min=0.0)
def test_four_wide_traversal_is_brute_force(tris, origins, dirs, t_min):
    """Over random triangle soups (axis-aligned, shared vertices, degenerate ones among
    them) and rays from inside and outside the boxes, axis-parallel rays included, the
    4-wide hierarchy is valid and ``intersect`` agrees with testing every primitive:
    its hit is a primitive's own (t, b1, b2) to the bit, no primitive is hit nearer, and
    no primitive whose hit lies in every box on its way down (``_admits``) is hit
    farther (so the two agree unless rounding puts the nearest hit outside its own box,
    which no hierarchy can find; counted as an event). ``occluded`` is true if such a
    primitive lies before the limit (below, at and above the nearest hit), false if no
    primitive does."""
    prims = np.zeros((len(tris), PRIM_WIDTH))
    prims[:, layout.TRI_P0:layout.TRI_P0 + 9] = tris
    info = np.zeros((len(tris), 2), dtype=np.int64)
    info[:, layout.PRIM_KIND] = TRIANGLE
    nb, ni, order = geometry.build_bvh(prims, info)
    nodes, leaf, leaf_info = packed = geometry.pack_bvh(prims, info, nb, ni, order)
    _check_hierarchy(prims, info, packed)
    paths = _leaf_paths(nodes, len(leaf_info))
    stack = geometry.new_stack()
    for o, d in zip(origins, dirs):
        if not np.any(d):
            continue
        ts, bs = _brute_hits(leaf, leaf_info, o, d)
        ts = np.where(ts > t_min, ts, np.inf)
        of = [float(x) for x in o]
        inv = [1.0 / float(x) if x != 0.0 else np.inf for x in d]
        inside = np.array([ts[k] < np.inf and all(_admits(lo, hi, of, inv, ts[k])
                                                  for lo, hi in paths[k])
                           for k in range(len(leaf_info))], dtype=bool)
        reach = ts[inside].min() if inside.any() else np.inf
        t, j, b1, b2 = geometry.intersect(nodes, leaf, leaf_info, stack, *o, *d, t_min,
                                          np.inf)
        if j < 0:
            assert t == np.inf and reach == np.inf, (o, d, t, reach)
        else:
            rows = np.flatnonzero((leaf_info[:, LEAF_PRIM] == j) & (ts == t))
            assert len(rows) == 1 and bs[rows[0]] == (b1, b2), (o, d, t, j)
            assert ts.min() <= t <= reach, (o, d, t, ts.min(), reach)
        if ts.min() < reach:
            event("nearest hit outside its own box by rounding")
        best = ts.min()
        for limit in (0.5 * best, best, np.nextafter(best, np.inf), 2.0 * best, np.inf):
            if not limit > t_min:
                continue
            blocked = geometry.occluded(nodes, leaf, leaf_info, stack, *o, *d, t_min, limit)
            if np.any(ts[inside] < limit):
                assert blocked, (o, d, limit, best)
            if not np.any(ts < limit):
                assert not blocked, (o, d, limit, best)


@njit
def _group_lanes(leaf, row, o, d, t_min, t_max):
    return geometry._tri4_entry(leaf, row, o[0], o[1], o[2], d[0], d[1], d[2], t_min, t_max)


@given(tris=st.integers(1, NODE_ARITY).flatmap(
           lambda n: arrays(np.float64, (n, 9), elements=_coord)),
       o=arrays(np.float64, 3, elements=_coord), d=arrays(np.float64, 3, elements=_dir),
       t_min=st.sampled_from([0.0, 1e-4, 0.5]),
       t_max=st.sampled_from([np.inf, 1.0, 0.25]))
@example(tris=np.zeros((1, 9)), o=np.zeros(3), d=np.array([0.0, 0.0, 1.0]), t_min=0.0,
         t_max=np.inf)              # a degenerate triangle: det = 0 (0/0 = NaN after it)
# a ray through a vertex, two edges (b1 = 0, b1 + b2 = 1) and a triangle it lies in the
# plane of, all at once
@example(tris=np.array([[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0],
                        [0.5, 0.5, 1.0, 0.5, -0.5, 1.0, -0.5, 0.5, 1.0],
                        [0.5, 0.5, 0.5, 0.5, 1.0, 0.5, -1.0, 0.0, 0.5],
                        [0.5, 0.5, -0.5, 0.5, 0.5, 1.0, 0.5, 1.0, 0.0]]),
         o=np.array([0.5, 0.5, -1.0]), d=np.array([0.0, 0.0, 1.0]), t_min=0.0,
         t_max=np.inf)
def test_triangle_group_lanes_are_the_scalar_test(tris, o, d, t_min, t_max):
    """Each lane of a triangle group (``_tri4_entry``) is the scalar triangle test of its
    row (``_hit_prim``) to the bit, t, b1 and b2 (the traversal takes a hit's b1, b2
    from its lane), kept only inside (t_min, t_max): triangles on a
    coarse grid (shared edges and vertices, axis-aligned and degenerate ones, rays along
    their planes and through their edges), NaN and the det = 0 rejection included;
    lanes past the group's size are never hit."""
    prims = np.zeros((len(tris), PRIM_WIDTH))
    prims[:, layout.TRI_P0:layout.TRI_P0 + 9] = tris
    info = np.zeros((len(tris), 2), dtype=np.int64)
    info[:, layout.PRIM_KIND] = TRIANGLE
    nb, ni, order = geometry.build_bvh(prims, info)
    nodes, leaf, leaf_info = geometry.pack_bvh(prims, info, nb, ni, order)
    for k in np.flatnonzero(leaf_info[:, layout.LEAF_GROUP_SIZE]):
        m = leaf_info[k, layout.LEAF_GROUP_SIZE]
        lanes = _group_lanes(leaf, leaf_info[k, layout.LEAF_GROUP], o, d, t_min, t_max)
        for lane in range(NODE_ARITY):
            if lane >= m:
                assert lanes[lane] == np.inf
                continue
            t, b1, b2 = geometry._hit_prim(leaf[k + lane], TRIANGLE, *o, *d)
            want = t if t_min < t < t_max else np.inf
            assert lanes[lane] == want, (k, lane, lanes[lane], t)
            if want < np.inf:
                b = (lanes[NODE_ARITY + lane], lanes[2 * NODE_ARITY + lane])
                assert b == (b1, b2), (k, lane, b, b1, b2)


# ----------------------------------------------------------------- the SIMD box test
@pytest.mark.skipif("+avx2" not in llvm.get_host_cpu_features().flatten(),
                    reason="the 4-wide box test compiles to ymm registers on AVX2 CPUs")
def test_the_four_box_tests_compile_to_avx2():
    """``intersect`` as the kernel inlines it tests the four child boxes of a node with
    256-bit packed float64 instructions (subtract, multiply, min, max on ymm registers),
    not four scalar slab tests."""
    @njit
    def cast(nodes, leaf, leaf_info, stack, o, d):
        return geometry.intersect(nodes, leaf, leaf_info, stack, o[0], o[1], o[2],
                                  d[0], d[1], d[2], 0.0, np.inf)

    prims, info = _soup(5, 0, seed=1)
    nb, ni, order = geometry.build_bvh(prims, info)
    nodes, leaf, leaf_info = geometry.pack_bvh(prims, info, nb, ni, order)
    cast(nodes, leaf, leaf_info, geometry.new_stack(), np.zeros(3), np.ones(3))
    asm = cast.inspect_asm(cast.signatures[0])
    packed = {op for op in re.findall(r"\b(v(?:sub|mul|min|max)pd)\s+[^\n]*ymm", asm)}
    assert packed == {"vsubpd", "vmulpd", "vminpd", "vmaxpd"}, packed


def test_bvh_bounds_is_the_box_of_every_primitive(packed):
    """``bvh_bounds`` (the scene's box, which the tracer checks' reference points are
    placed in) is the union of the primitives' boxes, to the bit."""
    prims, info, (nodes, _, _) = packed
    lo, hi = geometry._prim_bounds(prims, info)
    b_lo, b_hi = geometry.bvh_bounds(nodes)
    np.testing.assert_array_equal(b_lo, lo.min(axis=0))
    np.testing.assert_array_equal(b_hi, hi.max(axis=0))
