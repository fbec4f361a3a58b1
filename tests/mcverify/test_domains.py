import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from numba import njit

import mcverify as mv
from mcverify import _domain_kernels as K
from mcverify.domains import as_domain

DOMAINS = [mv.Interval(-2.0, 3.0), mv.Square(), mv.Disk(), mv.Sphere(), mv.Hemisphere()]


@pytest.mark.parametrize("dom", DOMAINS, ids=repr)
@given(s=arrays(np.float64, (16, 2), elements=st.floats(0.0, 1.0)))
def test_param_round_trip(dom, s):
    s = s[:, :dom.param_dim]
    x = dom.to_point(s)
    assert np.all(dom.inside(x))
    back = dom.to_param(x)
    # Azimuth wraps at 1 -> 0 and is undefined at the poles / centre.
    err = np.abs(back - s)
    if dom.param_dim == 2 and dom.name != "square":
        err[:, 1] = np.minimum(err[:, 1], 1.0 - err[:, 1])
        # At the poles / the centre the azimuth is ill-conditioned: skip it there.
        radius = np.hypot(x[:, 0], x[:, 1])
        err[radius < 1e-6, 1] = 0.0
    assert np.all(err < 1e-7)


@pytest.mark.parametrize("dom", DOMAINS, ids=repr)
def test_jacobian_is_total_measure(dom):
    # A uniform density over the domain has parameter-space density 1.
    expected = {"interval": 5.0, "square": 1.0, "disk": np.pi, "sphere": 4 * np.pi,
                "hemisphere": 2 * np.pi}[dom.name]
    assert dom.measure == pytest.approx(expected)


def test_as_domain_names_and_errors():
    assert as_domain("disk") == mv.Disk()
    with pytest.raises(mv.InvalidArgument, match="domain='torus'"):
        as_domain("torus")
    with pytest.raises(mv.InvalidArgument, match="Interval"):
        mv.Interval(1.0, 1.0)


def test_azimuth_matches_atan2_to_an_ulp():
    """The binning kernel's azimuth (Cephes' atan, no libm call) against math.atan2, on
    random directions and on the axes and diagonals."""
    import math

    from mcverify import _domain_kernels as K

    rng = np.random.default_rng(0)
    pts = [tuple(p) for p in rng.normal(size=(20_000, 2))]
    pts += [(1, 0), (0, 1), (-1, 0), (0, -1), (1, 1), (-1, -1), (1, -1e-300), (-1, -0.0),
            (-1, 1e-300), (1e-300, 1), (3, 4), (-4, 3)]
    for x, y in pts:
        ref = math.atan2(y, x)
        ref = (ref + 2 * math.pi if ref < 0 else ref) / (2 * math.pi)
        assert abs(K._azimuth(x, y) - ref) <= 4e-16, (x, y)


@pytest.mark.parametrize("dom", [mv.Disk(), mv.Sphere(), mv.Hemisphere()], ids=repr)
def test_binning_without_arc_tangent_matches_the_exact_parameters(dom):
    """The histogram kernel bins the azimuth by a monotone stand-in (the diamond angle)
    against converted edges: every point lands in the cell its exact parameters
    (φ / 2π by atan2) give, also on the axes and on the cells' own edges."""
    from mcverify.checks.sampler import _Histogram, _edges

    rng = np.random.default_rng(1)
    s = rng.random((200_000, 2))
    edges = _edges(s[:20_000] ** 2, (16, 32))            # non-uniform cells
    # Points at the edges themselves (within rounding), and on the axes.
    grid = np.stack(np.meshgrid(edges[0][:-1], edges[1][:-1], indexing="ij"), -1)
    axes = np.array([[0.3, 0.0], [0.3, 0.25], [0.3, 0.5], [0.3, 0.75]])
    x = dom.to_point(np.concatenate([s, grid.reshape(-1, 2), axes]))
    h = _Histogram(dom, edges)
    h.add(x)
    exact = dom.to_param(x)
    idx = [np.searchsorted(e, exact[:, j], side="right") - 1 for j, e in enumerate(edges)]
    ref = np.zeros(h.shape, dtype=np.int64)
    np.add.at(ref, tuple(idx), 1)
    # A point within rounding of an edge may fall either side of it: allow those only.
    on_edge = np.zeros(len(x), bool)
    for j, e in enumerate(edges):
        k = idx[j]
        on_edge |= np.minimum(np.abs(exact[:, j] - e[k]), np.abs(e[k + 1] - exact[:, j])) < 1e-12
    moved = np.abs(ref - h.flat.reshape(h.shape)).sum()
    assert moved <= 2 * np.count_nonzero(on_edge)
    assert h.flat.sum() == len(x)
    # Off the edges, the same cell for every random point.
    ref_r = np.zeros(h.shape, dtype=np.int64)
    np.add.at(ref_r, tuple(i[:len(s)] for i in idx), 1)
    h_r = _Histogram(dom, edges)
    h_r.add(x[:len(s)])
    assert np.array_equal(ref_r, h_r.flat.reshape(h.shape))


@pytest.mark.parametrize("dom", [mv.Sphere(), mv.Hemisphere()], ids=repr)
def test_float32_points_near_the_pole_keep_their_polar_parameter(dom):
    """1 - z of a float32 point within 1e-4 of the pole is 0 or a multiple of 6e-8; the
    domain takes it from the tangential components instead, to float32 precision."""
    s0 = np.geomspace(1e-12, 1e-4, 50) / (2.0 if dom.name == "sphere" else 1.0)
    s = np.stack([s0, np.full_like(s0, 0.3)], -1)
    x32 = dom.to_point(s).astype(np.float32)
    back = dom.to_param(x32)[:, 0]
    assert np.all(np.abs(back - s0) <= 1e-6 * s0)


@njit
def _cells_of(e, lut, cut, s, out):
    for i in range(s.shape[0]):
        out[i] = K._find_cell(e, lut, cut, s[i])


def _edge_sets():
    """Cell edges as the checks make them, and adversarial ones: on the look-up table's
    slot boundaries (and an ulp off them), several edges in one slot, a single cell."""
    rng = np.random.default_rng(4)
    for r in (1, 2, 3, 16, 64, 129):
        yield np.linspace(0.0, 1.0, r + 1)
        yield np.unique(np.concatenate([[0.0, 1.0], rng.random(r - 1)]))
        slots = 8 * r
        on = (np.arange(1, r) * 8 + rng.integers(-3, 4, r - 1)).clip(1, slots - 1) / slots
        yield np.unique(np.concatenate([[0.0, 1.0], on]))
        yield np.unique(np.concatenate([[0.0, 1.0], np.nextafter(on, 0.0)]))
        yield np.unique(np.concatenate([[0.0, 1.0], 0.5 + np.arange(r - 1) * 1e-9]))


@pytest.mark.parametrize("e", list(_edge_sets()), ids=lambda e: f"{e.size - 1}cells")
def test_cell_lookup_finds_the_cell_a_binary_search_finds(e):
    """The histogram kernel's table look-up (a slot's cell, plus one if past the slot's
    one inner edge; a scan where a slot holds several) gives searchsorted's cell for
    random values, the edges themselves and an ulp either side, and the slot bounds."""
    lut, cut = K.cell_lookup(e)
    slots = np.arange(lut.size) / lut.size
    s = np.concatenate([np.random.default_rng(5).random(20_000), e[:-1],
                        np.nextafter(e[1:], 0.0), np.nextafter(e[:-1], 1.0), slots,
                        np.nextafter(slots[1:], 0.0), np.nextafter(slots, 1.0)])
    s = np.clip(s, 0.0, K._S_MAX)
    out = np.empty(s.size, dtype=np.int64)
    _cells_of(e, lut, cut, s, out)
    assert np.array_equal(out, np.searchsorted(e, s, side="right") - 1)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("dom", DOMAINS, ids=repr)
def test_every_status_is_counted_with_its_first_example(dom, dtype):
    """NaN and ±Inf in any coordinate are NONFINITE, a row of NaN is REJECTED when draws
    may be rejected, points outside are OUTSIDE; the valid points are binned."""
    from mcverify.checks.sampler import _Histogram

    good = dom.to_point(np.random.default_rng(6).random((50, dom.param_dim)))
    bad = []
    for j in range(dom.dim):
        for v in (np.nan, np.inf, -np.inf):
            row = good[0].copy()
            row[j] = v
            bad.append(row)
    far = good[0] * 3.0 + 2.0
    x = np.concatenate([good, np.array(bad), far[None], np.full((2, dom.dim), np.nan)])
    x = x.astype(dtype)
    one_nan = 1 if dom.dim == 1 else 0         # a 1-D NaN point is a row of NaN
    for rejection, want in ((False, [50, 3 * dom.dim + 2, 1, 0]),
                            (True, [50, 3 * dom.dim - one_nan, 1, 2 + one_nan])):
        h = _Histogram(dom, [np.linspace(0, 1, 5)] * dom.param_dim, rejection=rejection)
        h.add(x)
        assert h.n_status.tolist() == want
        assert h.flat.sum() == 50
        first = 50 + (one_nan if rejection else 0)
        assert np.array_equal(h.examples[K.NONFINITE][1], x[first], equal_nan=True)
        assert np.array_equal(h.examples[K.OUTSIDE][1], x[50 + 3 * dom.dim])


def test_density_values_are_screened_in_one_pass():
    """The cubature's pdf screen: NaN/±Inf and negative values count once each and
    integrate as 0; the rest are scaled by the jacobian; the first bad index is kept."""
    p = np.array([1.0, 0.5, -2.0, np.nan, np.inf, -np.inf, 0.0, -0.0, 3.0])
    out = np.empty_like(p)
    assert K.screen_density(p, 2.0, out) == (3, 1, 2)
    assert np.array_equal(out, [2.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 6.0])
    assert K.screen_density(np.array([1.0, 2.0]), 0.5, np.empty(2)) == (0, 0, -1)
