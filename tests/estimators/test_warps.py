"""Every warp, the same ways: χ² against its pdf, inverse round trip, numerical stability
under hypothesis, float32 agreement, and a wrong parameter rejected (mutation test)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import mcverify as mv
from mcnumba.threads import MIN_BLOCKS, threads_for
from estimators.warps import ONE_MINUS_EPSILON, WARPS

NAMES = sorted(WARPS)
EDGE_U = [0.0, 0.5, ONE_MINUS_EPSILON, 1.0 - 2.0 ** -24, 2.0 ** -53, 1e-300]


def domain_of(w, params):
    name, args = w.domain_spec(*params)
    return mv.Interval(*args) if name == "interval" else mv.domains.as_domain(name)


def normalise(w, params):
    params = list(params)
    if w.name == "ggx_vndf":
        d = np.array(params[1:4])
        d[2] = max(d[2], 0.05)
        params[1:4] = d / np.linalg.norm(d)
    return tuple(float(p) for p in params)


def param_strategy(w):
    parts = []
    for name, (lo, hi) in zip(w.params, w.ranges):
        if name in w.log_scale:
            parts.append(st.floats(np.log(lo), np.log(hi)).map(np.exp))
        else:
            parts.append(st.floats(lo, hi))
    return st.tuples(*parts)


@pytest.mark.parametrize("name", NAMES)
def test_sampler_matches_pdf_at_defaults(name):
    w = WARPS[name]
    p = normalise(w, w.defaults)
    r = mv.check_sampler(lambda u: w.sample(u, *p), lambda x: w.pdf(x, *p), domain_of(w, p),
                         n_samples=300_000, seed=11, sample_dim=w.sample_dim)
    assert r.passed, (r.summary(), r.messages)


@pytest.mark.parametrize("name", [n for n in NAMES if WARPS[n].invert is not None])
def test_inverse_round_trip(name):
    w = WARPS[name]
    r = mv.check_inverse(lambda u: w.sample(u, *w.defaults), lambda x: w.invert(x, *w.defaults),
                         w.sample_dim, atol=1e-9)
    assert r.passed, r.failures


@pytest.mark.parametrize("name", [n for n in NAMES if WARPS[n].params])
def test_wrong_parameter_is_rejected(name):
    w = WARPS[name]
    p = normalise(w, w.defaults)
    wrong = list(p)
    wrong[0] = wrong[0] * 1.1 if wrong[0] != 0 else 0.1
    wrong = normalise(w, wrong)
    r = mv.check_sampler(lambda u: w.sample(u, *p), lambda x: w.pdf(x, *wrong),
                         domain_of(w, p), n_samples=300_000, seed=12, sample_dim=w.sample_dim)
    assert not r.passed, r.summary()


@pytest.mark.parametrize("name", [n for n in NAMES if WARPS[n].params])
@settings(max_examples=4)
@given(data=st.data())
def test_sampler_matches_pdf_across_parameters(name, data):
    w = WARPS[name]
    p = normalise(w, data.draw(param_strategy(w)))
    r = mv.check_sampler(lambda u: w.sample(u, *p), lambda x: w.pdf(x, *p), domain_of(w, p),
                         n_samples=100_000, seed=13, sample_dim=w.sample_dim,
                         alpha=0.001)  # α per example; 4 examples × 15 warps, Šidák ≈ 0.06
    assert r.passed, (p, r.summary(), r.messages)


@pytest.mark.parametrize("name", NAMES)
@given(data=st.data())
def test_stability_at_extreme_inputs(name, data):
    w = WARPS[name]
    p = normalise(w, data.draw(param_strategy(w)) if w.params else ())
    u = np.array([[data.draw(st.sampled_from(EDGE_U) | st.floats(0, ONE_MINUS_EPSILON))
                   for _ in range(w.sample_dim)] for _ in range(8)])
    x = w.sample(u, *p)
    dom = domain_of(w, p)
    assert np.all(np.isfinite(x)), (u, x)
    assert np.all(dom.inside(x)), (u, x)
    pdf = w.pdf(x, *p)
    assert np.all(np.isfinite(pdf)) and np.all(pdf >= 0), (u, x, pdf)
    if w.invert is not None:
        back = w.invert(x, *p)
        assert np.all(np.isfinite(back)) and np.all((back >= 0) & (back < 1)), (u, x, back)


#: Warps whose float32 pdf and inverse loops the default run compiles (a few seconds of
#: numba each on a new machine): between them every shape of the loop template, rows of
#: 1, 2 and 3 coordinates in and out, a density of 1, 2 and 3, the kernel inlined into the
#: loop (the polar disk's and the sphere's inverses, the visible normals' pdf) or called.
#: ``-m slow`` runs the same test on every other warp.
FLOAT32_SHAPES = ("uniform_interval", "uniform_triangle", "uniform_disk_polar",
                  "cosine_hemisphere", "uniform_sphere", "ggx_vndf")


@pytest.mark.parametrize("name", NAMES)
def test_float32_agrees_with_float64(name):
    w = WARPS[name]
    u = np.random.default_rng(3).random((10_000, w.sample_dim))
    u32 = u.astype(np.float32)
    x64 = w.sample(u32.astype(np.float64), *w.defaults)
    x32 = w.sample(u32, *w.defaults)
    assert x32.dtype == np.float32
    # Same input values: the float32 path computes in float64 and rounds once, so it is
    # within half a float32 ulp of the float64 result.
    assert np.all(np.abs(x32 - x64) <= 0.5 * np.spacing(np.abs(x64).astype(np.float32)))


@pytest.mark.parametrize("name, dtype", [
    pytest.param(name, dtype, marks=() if dtype == np.float64 or name in FLOAT32_SHAPES
                 else pytest.mark.slow, id=f"{name}-{dtype.__name__}")
    for dtype in (np.float64, np.float32) for name in NAMES])
def test_a_nan_point_has_a_nan_density(name, dtype):
    """A NaN in any coordinate gives a NaN density, not the 0 (or the sphere's 1/4π)
    the kernel's tests make of it, and leaves the other rows' densities as they were;
    a NaN u gives a NaN point and density through ``with_pdf`` too. float32: the warps
    of ``FLOAT32_SHAPES`` (their float32 pdf and ``with_pdf`` loops), every warp in the
    slow run."""
    w = WARPS[name]
    p = normalise(w, w.defaults)
    u = np.random.default_rng(7).random((40, w.sample_dim)).astype(dtype)
    x = w.sample(u, *p)
    clean = w.pdf(x, *p)
    for j in range(x.shape[1]):
        y = x.copy()
        y[3 + j, j] = np.nan
        v = w.pdf(y, *p)
        assert np.isnan(v[3 + j]) and np.array_equal(np.delete(v, 3 + j), np.delete(clean, 3 + j))
    u[5, 0] = np.nan
    xs, ps = w.sample.with_pdf(u, *p)
    assert np.isnan(xs[5]).any() and np.isnan(ps[5]), (xs[5], ps[5])
    assert np.array_equal(np.delete(ps, 5), np.delete(clean, 5))


@pytest.mark.parametrize("n", [0.0, 20.0, 1e3, 1e8, 1e12])
def test_power_cosine_keeps_its_precision_in_a_narrow_lobe(n):
    """A narrow lobe's directions lie within 1e-6 of the pole at n = 1e12: 1 - cos θ
    taken from a rounded cos θ kept only its last bits (round trip off by 5.5e-9 at
    n = 1e8, pdf by 5.5e-11 at n = 1e6). The inverse returns u to 8 ulps and the pdf
    at each sample is its density in u, (n+1)/2π (1 - u)^(n/(n+1)), to 128 ulps (a
    long-double reference; the worst cases are at the horizon, cos θ < 1e-10)."""
    rng = np.random.default_rng(5)
    u0 = np.concatenate([rng.random(20_000), 10.0 ** -rng.uniform(0, 12, 20_000),
                         1 - 10.0 ** -rng.uniform(0, 9, 20_000)])
    u = np.stack([u0, rng.random(u0.size)], 1)
    x = WARPS["power_cosine"].sample(u, n)
    assert np.allclose(np.linalg.norm(x, axis=1), 1.0, rtol=0, atol=4e-16)
    back = WARPS["power_cosine"].invert(x, n)
    assert np.all(np.abs(back[:, 0] - u0) <= 8 * np.spacing(u0)), \
        np.max(np.abs(back[:, 0] - u0) / np.spacing(u0))
    ld = np.longdouble
    ref = (ld(n) + 1) / (2 * ld(np.pi)) * np.exp(ld(n) / (ld(n) + 1) * np.log1p(-u0.astype(ld)))
    ulps = np.abs(WARPS["power_cosine"].pdf(x, n) - ref) / np.spacing(ref.astype(np.float64))
    assert ulps.max() <= 128, ulps.max()


@pytest.mark.parametrize("name,params", [
    # Found by hypothesis: the Beckmann tail beyond the last pilot edge hid in a
    # boundary layer no Gauss node saw (fixed by the cubature's corner test).
    ("beckmann", (float(np.exp(-4.5)),)),
    ("ggx", (1e-3,)),
    ("power_cosine", (1000.0,)),
    ("uniform_cone", (0.999,)),
], ids=lambda v: str(v))
def test_regression_examples(name, params):
    w = WARPS[name]
    r = mv.check_sampler(lambda u: w.sample(u, *params), lambda x: w.pdf(x, *params),
                         domain_of(w, params), n_samples=100_000, seed=13,
                         sample_dim=w.sample_dim, alpha=0.001)
    assert r.passed, (r.summary(), r.messages)


@pytest.mark.parametrize("name", NAMES)
def test_pdf_is_the_inverse_jacobian_of_the_sample_map(name):
    """pdf(sample(u)) · |∂x/∂u| = 1: the density a map produces is the reciprocal of
    how much it stretches measure (|dx/du| in 1-D, |det J| for square -> plane, the
    area of the parallelogram |∂x/∂u₀ × ∂x/∂u₁| for maps onto the sphere). Central
    differences, h = 1e-6, at interior u away from the maps' seams."""
    w = WARPS[name]
    p = normalise(w, w.defaults)
    rng = np.random.default_rng(17)
    u = 0.02 + 0.96 * rng.random((400, w.sample_dim))
    h = 1e-6
    cols = []
    for j in range(w.sample_dim):
        du = np.zeros(w.sample_dim)
        du[j] = h
        cols.append((w.sample(u + du, *p) - w.sample(u - du, *p)) / (2 * h))
    if w.sample_dim == 1:
        stretch = np.abs(cols[0][:, 0])
    elif w.dim == 2:
        stretch = np.abs(cols[0][:, 0] * cols[1][:, 1] - cols[0][:, 1] * cols[1][:, 0])
    else:
        stretch = np.linalg.norm(np.cross(cols[0], cols[1]), axis=1)
    pdf = w.pdf(w.sample(u, *p), *p)
    # Skip points where the map folds (the triangle's diagonal u0 = u1, the concentric
    # map's diagonals), where a central difference straddles two branches.
    if name == "uniform_triangle":
        keep = np.abs(u[:, 0] - u[:, 1]) > 1e-4
    elif name in ("uniform_disk_concentric", "cosine_hemisphere"):
        keep = np.abs(np.abs(2 * u[:, 0] - 1) - np.abs(2 * u[:, 1] - 1)) > 1e-4
    else:
        keep = np.ones(len(u), bool)
    rel = np.abs(pdf * stretch - 1.0)[keep]
    assert np.max(rel) < 1e-4, (name, float(np.max(rel)))


def _front_end_runs(w, u, dtype, pdf_and_invert):
    """The sample (and its pdf and inverse) on one thread and on two."""
    import numba

    before = numba.get_num_threads()
    runs = []
    try:
        for threads in (1, 2):
            numba.set_num_threads(threads)
            assert threads_for(-(-u.shape[0] // 512)) == threads    # the threads it runs on
            x = w.sample(u.astype(dtype), *w.defaults)
            out = [x]
            if pdf_and_invert:
                out.append(w.pdf(x, *w.defaults))
                if w.invert is not None:
                    out.append(w.invert(x, *w.defaults))
            runs.append(out)
    finally:
        numba.set_num_threads(before)
    for a, b in zip(*runs):
        assert a.dtype == dtype and b.dtype == dtype and np.array_equal(a, b, equal_nan=True)
    return runs[0]


def _same_bits_and_float32_within_half_an_ulp(name, float32_pdf_and_invert):
    """The array front ends run in parallel blocks; every row is computed on its own, so
    one thread and two give the same bits. The float32 path widens each input to float64,
    computes in float64 and rounds once: its pdf and inverse are within half a float32 ulp
    of the float64 ones at the same (float32) points."""
    import numba

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("numba has a single thread here")
    w = WARPS[name]
    # enough blocks of 512 rows for two threads (``mcnumba.threads.MIN_BLOCKS`` each), and a
    # partial last block
    u = np.random.default_rng(5).random(((2 * MIN_BLOCKS + 3) * 512 + 7, w.sample_dim))
    _front_end_runs(w, u, np.float64, True)
    got = _front_end_runs(w, u, np.float32, float32_pdf_and_invert)
    if not float32_pdf_and_invert:
        return
    x32 = got[0]
    want = [w.pdf(x32.astype(np.float64), *w.defaults)]
    if w.invert is not None:
        want.append(w.invert(x32.astype(np.float64), *w.defaults))
    for g, f in zip(got[1:], want):
        ok = np.isfinite(f)
        assert np.array_equal(np.isfinite(g), ok)
        assert np.all(np.abs(g[ok] - f[ok])
                      <= 0.5 * np.spacing(np.abs(f[ok]).astype(np.float32))), name


@pytest.mark.parametrize("name", NAMES)
def test_front_ends_are_bit_identical_whatever_the_thread_count(name):
    """float64 every front end; float32 the sample, and the pdf and the inverse of the
    warps in ``FLOAT32_SHAPES``."""
    _same_bits_and_float32_within_half_an_ulp(name, name in FLOAT32_SHAPES)


@pytest.mark.slow
@pytest.mark.parametrize("name", [n for n in NAMES if n not in FLOAT32_SHAPES])
def test_every_float32_pdf_and_inverse_same_bits_and_within_half_an_ulp(name):
    _same_bits_and_float32_within_half_an_ulp(name, True)


def test_sincos_two_pi_matches_libm():
    """The warps' libm-free sin/cos of 2πu (quadrant reduction onto the concentric map's
    polynomial) against numpy's: within 1e-15 absolute (libm's own argument 2πu is
    rounded, an error of up to 4.4e-16 · 2π), at random u and at every quadrant
    boundary and its neighbours."""
    from estimators.warps import _sincos_two_pi

    u = np.random.default_rng(8).random(20_000).tolist()
    for b in (0.0, 0.125, 0.25, 0.375, 0.5, 0.625, 0.75, 0.875, 1.0):
        u += [b, float(np.nextafter(b, 0.0)), float(np.nextafter(b, 1.0))]
    u = np.clip(u, 0.0, 1.0)
    sc = np.array([_sincos_two_pi(v) for v in u])
    assert np.max(np.abs(sc[:, 0] - np.sin(2 * np.pi * u))) < 1e-15
    assert np.max(np.abs(sc[:, 1] - np.cos(2 * np.pi * u))) < 1e-15
    assert np.all(np.abs(np.hypot(sc[:, 0], sc[:, 1]) - 1.0) < 4e-16)


_WIDTH_PROBE = """
import hashlib, sys, numpy as np
from estimators.warps import WARPS
from numba.core import registry
u = np.random.default_rng(5).random((4099, 2))
u[:6, 0] = [0.0, 0.5, 1 - 2**-53, 1 - 2**-24, 2**-53, 1e-300]
for name in sys.argv[1:]:
    w = WARPS[name]
    x = w.sample(u[:, :w.sample_dim], *w.defaults)
    outs = [x, w.pdf(x, *w.defaults)]
    if w.invert is not None:
        outs.append(w.invert(x, *w.defaults))
    print(name, hashlib.sha256(b"".join(np.ascontiguousarray(o).tobytes()
                                         for o in outs)).hexdigest())
print("-prefer-256-bit" in registry.cpu_target.target_context.codegen()._tm_features)
"""


def _width_digests(names, features):
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CPU_FEATURES",
                                                             "NUMBA_CPU_NAME")}
    if features is not None:
        env["NUMBA_CPU_FEATURES"] = features
    r = subprocess.run([sys.executable, "-c", _WIDTH_PROBE, *names], capture_output=True,
                       text=True, env=env, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    lines = r.stdout.split("\n")
    return lines[:len(names)], lines[len(names)]


def _check_width_bit_identical(names):
    from numba.core.codegen import get_host_cpu_features

    host = get_host_cpu_features()
    wide, wide_flag = _width_digests(names, None)
    narrow, narrow_flag = _width_digests(names, host)
    assert narrow_flag == "False"
    assert wide_flag == str("+avx512f" in host.split(","))
    assert wide == narrow


def test_wide_vectors_give_bit_identical_warps():
    """``mcnumba.vector_width``: the warps' loops compiled for 512-bit vectors (the
    default on an AVX-512 host) and for LLVM's own 256-bit choice give the same bits
    (samples, pdfs, inverses; edge u included). Three warps here, every warp in the slow
    run. On a host without AVX-512 both runs compile the same code."""
    _check_width_bit_identical(["cosine_hemisphere", "uniform_sphere", "beckmann"])


@pytest.mark.slow
def test_wide_vectors_give_bit_identical_warps_for_every_warp():
    _check_width_bit_identical(NAMES)


def test_float32_inverses_stay_below_one_and_the_interval_inverse_clamps():
    """The kernels clamp u to float64's 1 - 2^-53, which rounds to 1.0 in float32: five
    inverses returned u = 1.0 for float32 points; invert_uniform_interval did not clamp
    at all (found by review)."""
    from estimators import warps as W

    u = np.array([[1 - 2 ** -24, 0.3]], np.float32)
    outs = [W.invert_uniform_cone(W.sample_uniform_cone(u, 0.999), 0.999),
            W.invert_exponential(W.sample_exponential(u[:, :1], 0.27, 0.01), 0.27, 0.01),
            W.invert_linear(np.float32([[1.0]]), 0.0, 9.5),
            W.invert_uniform_sphere(np.float32([[0, 0, -1]])),
            W.invert_uniform_triangle(np.float32([[0, 1]]))]
    for out in outs:
        assert out.dtype == np.float32 and np.all((out >= 0) & (out < 1)), out
    v = W.invert_uniform_interval(np.array([[20.0], [-20.0]]), -1.0, 3.0).ravel()
    assert v.tolist() == [1 - 2 ** -53, 0.0]


@pytest.mark.parametrize("name,params,beyond,end", [
    ("tent", (1.0,), [[5.0], [-5.0], [1.5], [-2.5]], [[1], [0], [1], [0]]),
    ("linear", (2.0, 0.01), [[3.0], [-2.0]], [[1], [0]]),
    ("linear", (0.01, 2.0), [[3.0], [-2.0]], [[1], [0]]),
    ("bilinear", (1.0, 3.0, 0.5, 2.0), [[0.5, 2.0], [0.5, -1.0], [3.0, 0.5], [-2.0, 0.5]],
     [[None, 1], [None, 0], [1, None], [0, None]]),
])
def test_points_beyond_the_support_invert_to_its_nearest_end(name, params, beyond, end):
    """As invert_uniform_interval clamps: the tent's and the linear warps' CDFs are
    quadratics that turn back outside the support, and a point beyond one end inverted
    to the other (tent r = 1: x = 5 gave u = 0, x = -5 gave 1 - 2^-53; linear a = 2,
    b = 0.01: x = 3 gave 0; the bilinear row weights went negative for y > 1)."""
    from estimators.warps import WARPS

    w = WARPS[name]
    x = np.array(beyond, dtype=np.float64)
    u = w.invert(x, *params)
    for row, want, point in zip(u, end, x):
        for ui, e in zip(row, want):
            if e is not None:
                assert ui == (1 - 2 ** -53 if e else 0.0), (name, point, row)
    # the other coordinate of a bilinear point is inverted as at the nearest edge
    if name == "bilinear":
        edge = np.clip(x, 0.0, 1.0)
        assert np.array_equal(u, w.invert(edge, *params)), (u, w.invert(edge, *params))


def test_uniform_interval_at_u_one_stays_in_the_interval():
    """a + (b - a)·u at u = 1 rounded above b for about 1 in 6 random (a, b) in float64
    (a = -0.3, b = 0.1: 0.10000000000000003, density 0; found by review), where the
    README promises a point of the domain at u = 1. Seeded draws of (a, b)."""
    from estimators import warps as W

    rng = np.random.default_rng(0)
    u = np.array([[1.0], [1 - 2 ** -53], [0.0], [np.nan]])
    for _ in range(2000):
        a, b = np.sort(rng.normal(size=2) * rng.choice([1.0, 10.0, 100.0]))
        x, pdf = W.sample_uniform_interval.with_pdf(u, a, b)
        assert np.all((x[:3] >= a) & (x[:3] <= b)) and np.all(pdf[:3] > 0), (a, b, x)
        assert x[2, 0] == a and np.isnan(x[3, 0])


def test_uniform_cone_at_u_one_stays_in_the_cap():
    """z = 1 - u0 (1 - cos θ_max) at u0 = 1 rounded below cos θ_max for about 1 in 10
    random cos θ_max in float64 (-0.3: z = -0.30000000000000004, density 0), where the
    README promises a point of the domain at u = 1, as for the interval above. Seeded
    draws of cos θ_max."""
    from estimators import warps as W

    rng = np.random.default_rng(0)
    u = np.array([[1.0, 0.3], [1 - 2 ** -53, 0.7], [0.0, 0.1], [np.nan, 0.5]])
    for c in np.concatenate([[-0.3, 0.1, -1.0], rng.uniform(-1.0, 0.999, 2000)]):
        x, pdf = W.sample_uniform_cone.with_pdf(u, c)
        assert np.all(x[:3, 2] >= c) and np.all(pdf[:3] > 0), (c, x)
        assert np.allclose(np.linalg.norm(x[:3], axis=1), 1.0, atol=1e-15)
        assert np.isnan(x[3]).all()


def test_float32_cone_samples_stay_inside_the_cap():
    """A float32 point of a narrow cone (cos θ_max = 0.9999) whose z rounded below
    cos θ_max had density 0 as stored: 310 of 2M float32 u (u from [0, 1)), so f / pdf
    was inf (found by review). Every such point is now inside the cap, with the cap's
    density, within one float32 ulp of the float64 point; with_pdf agrees bit for bit."""
    from estimators import warps as W

    u = np.random.default_rng(5).random((2_000_000, 2), dtype=np.float32)
    for c in (0.9999, 0.99999):
        x = W.sample_uniform_cone(u, c)
        assert x.dtype == np.float32 and np.all(x[:, 2].astype(np.float64) >= c)
        pdf = W.uniform_cone_pdf(x, c)
        assert np.all(pdf == np.float32(1.0 / (2.0 * np.pi * (1.0 - c))))
        xf, pf = W.sample_uniform_cone.with_pdf(u, c)
        assert np.array_equal(xf, x) and np.array_equal(pf, pdf)
        x64 = W.sample_uniform_cone(u.astype(np.float64), c)
        assert np.all(np.abs(x - x64) <= np.spacing(np.abs(x64).astype(np.float32)))
    # u = 1 (a float32 u that rounded to it): the cap's edge, inside
    assert W.sample_uniform_cone(np.float32([[1.0, 0.0]]), 0.9999)[0, 2] >= 0.9999


def test_float32_interval_samples_stay_inside_the_interval():
    """u = 0 (Sobol's first point; a float32 u from [0, 1) once in 2^24) on [-0.3, 0.1]
    stored float32(-0.3) = -0.30000001, outside the interval, of density 0, and u = 1
    float32(0.1) > 0.1 (found by review): each is now the float32 nearest inside, of
    the interval's density, and with_pdf agrees bit for bit."""
    from estimators import warps as W

    u = np.concatenate([np.float32([[0.0], [1.0], [np.nan]]),
                        np.random.default_rng(1).random((100_000, 1), dtype=np.float32)])
    for a, b in ((-0.3, 0.1), (0.1, 0.7), (-1e-30, 1e-30), (-7.3, -1.1)):
        x = W.sample_uniform_interval(u, a, b)
        inside = x[:2, 0].astype(np.float64)
        assert x.dtype == np.float32 and np.all((inside >= a) & (inside <= b)), (a, b, x[:2])
        assert np.all(np.abs(inside - [a, b]) <= np.abs(np.spacing(np.float32([a, b])))), (a, b)
        assert np.isnan(x[2, 0])
        pdf = W.uniform_interval_pdf(x, a, b)
        assert np.all(pdf[3:] > 0) and np.all(pdf[:2] == np.float32(1.0 / (b - a)))
        xf, pf = W.sample_uniform_interval.with_pdf(u, a, b)
        assert np.array_equal(xf, x, equal_nan=True) and np.array_equal(pf, pdf, equal_nan=True)


def test_float32_exponential_at_u_one_stays_within_t_max():
    """u = 1 (a float32 u that rounded to it) gave t_max = 0.1 itself, stored as float32
    0.10000000149 > t_max, density 0 (found by review; the README promises a point of
    the domain at u = 1 in float32): now the largest float32 <= t_max."""
    from estimators import warps as W

    u = np.float32([[1.0], [0.0], [0.5]])
    for sigma, t_max in ((1.0, 0.1), (5.0, 0.3), (0.27, 0.01), (2.0, np.inf)):
        x, pdf = W.sample_exponential.with_pdf(u, sigma, t_max)
        assert np.all((x.astype(np.float64) >= 0) & (x.astype(np.float64) <= t_max))
        assert np.all(pdf > 0) and np.array_equal(W.sample_exponential(u, sigma, t_max), x)
        assert np.array_equal(W.exponential_pdf(x, sigma, t_max), pdf)


def test_float32_disk_rims_and_triangle_diagonals_stay_inside():
    """u on the square's edge (QMC's points; u = 1 a float32 u that rounded to it) put
    float32 disk points just outside the rim (concentric at u = (0, 0.00434059): x² + y²
    = 1 + 7.5e-9; polar at u = (1, 5.96e-8)) and triangle points past the diagonal
    (u = (5.96e-8, 1): b0 + b1 = 1 + 3e-8), of density 0 as stored (found by review).
    Such a point now moves an ulp towards the inside, with the support's density;
    with_pdf agrees bit for bit, and float64 points are left as they are."""
    from estimators import warps as W

    edges = np.float32([[0.0, 0.00434059], [1.0, 5.96e-8], [5.96e-8, 1.0], [0.0, 0.0],
                        [1.0, 1.0], [0.5, 1.0], [1.0, 0.5], [np.nan, 0.5]])
    u = np.concatenate([edges, np.random.default_rng(2).random((100_000, 2),
                                                               dtype=np.float32)])
    for sample, pdf, density in ((W.sample_uniform_disk_concentric, W.uniform_disk_pdf, 1 / np.pi),
                                 (W.sample_uniform_disk_polar, W.uniform_disk_pdf, 1 / np.pi),
                                 (W.sample_uniform_triangle, W.uniform_triangle_pdf, 2.0)):
        x = sample(u)
        p = pdf(x)
        assert x.dtype == np.float32 and np.isnan(x[7]).all()
        assert np.all(p[:7] == np.float32(density)) and np.all(p[8:] == np.float32(density))
        xf, pf = sample.with_pdf(u)
        assert np.array_equal(xf, x, equal_nan=True) and np.array_equal(pf, p, equal_nan=True)
        x64 = sample(u.astype(np.float64))
        assert np.all(np.abs(x[8:] - x64[8:]) <= 2 * np.spacing(np.abs(x64[8:]).astype(np.float32)))
        assert np.array_equal(sample(u[:7].astype(np.float64)), x64[:7])


def test_the_concentric_disks_rim_points_have_the_disks_density():
    """u on the square's edge (u0 or u1 exactly 0, common in QMC) maps to r = 1, where
    x² + y² rounds up to 2 ulps above 1: uniform_disk_pdf gave 0 there (4 % of that edge)."""
    from estimators import warps as W

    g = np.linspace(0, 1, 100_001)[:-1]
    for u in (np.stack([g, 0 * g], 1), np.stack([0 * g, g], 1)):
        assert np.all(W.uniform_disk_pdf(W.sample_uniform_disk_concentric(u)) == 1 / np.pi)
    assert W.uniform_disk_pdf(np.array([[1.0, 1e-7]]))[0] == 0.0    # beyond the rounding


@pytest.mark.parametrize("call,needle", [
    (lambda W, u: W.sample_ggx(u), "sample_ggx: takes 1 parameter(s) (alpha) after the "
                                   "points, got 0"),
    (lambda W, u: W.bilinear_pdf(u, 1, 2, 3), "takes 4 parameter(s) (w00, w10, w01, w11)"),
    (lambda W, u: W.sample_cosine_hemisphere(u, 0.3), "takes no parameters after the points"),
    (lambda W, u: W.sample_ggx(u, -0.3), "alpha=-0.3: the warp needs 1e-30 <= alpha <= 1e30"),
    (lambda W, u: W.sample_ggx(u, 1e160), "alpha=1e+160: the warp needs 1e-30 <= alpha"),
    (lambda W, u: W.ggx_pdf(np.ones((2, 3)), 1e-100), "alpha=1e-100: the warp needs"),
    (lambda W, u: W.invert_beckmann(np.ones((2, 3)), 1e31), "alpha=1e+31: the warp needs"),
    (lambda W, u: W.sample_ggx_vndf(u, 1e-40, 0.6, 0.0, 0.8), "alpha=1e-40, wx=0.6"),
    (lambda W, u: W.ggx_pdf(np.ones((2, 3)), float("nan")), "alpha=nan: must be finite"),
    (lambda W, u: W.sample_beckmann(u, "0.3"), "alpha='0.3': must be a real number"),
    (lambda W, u: W.sample_uniform_cone(u, 1.5), "cos_theta_max=1.5: the warp needs"),
    (lambda W, u: W.power_cosine_pdf(np.ones((2, 3)), -3), "n=-3.0: the warp needs n >= 0"),
    (lambda W, u: W.sample_ggx_vndf(u, 0.3, 0.6, 0.0, 0.9), "a unit vector with wz > 0"),
    (lambda W, u: W.sample_exponential(u[:, :1], 0.0, 1.0), "sigma >= 1e-150, t_max > 0"),
    (lambda W, u: W.sample_tent(u[:, :1], -1.0), "radius=-1.0: the warp needs radius >= "
                                                 "2^-1022"),
    # found by review: every point of density 1 / 1e-310 = inf
    (lambda W, u: W.tent_pdf(u[:, :1], 1e-310), "radius=1e-310: the warp needs radius"),
    (lambda W, u: W.sample_tent(u[:, :1], 2.0 ** -1022), None),
    (lambda W, u: W.sample_uniform_interval(u[:, :1], 3.0, 1.0), "a=3.0, b=1.0"),
    (lambda W, u: W.sample_linear(u[:, :1], 0.0, 0.0), "a >= 0 and b >= 0, not both 0"),
    (lambda W, u: W.sample_exponential(u[:, :1], 1e-200, 1e-200), "sigma·t_max >= 1e-150"),
    (lambda W, u: W.exponential_pdf(u[:, :1], 1e-310, np.inf), "sigma >= 1e-150"),
    (lambda W, u: W.sample_uniform_interval(u[:, :1], -1e308, 1e308), "b - a finite"),
    # found by review: every point a, of density 1 / 5e-324 = inf
    (lambda W, u: W.uniform_interval_pdf(u[:, :1], 0.0, 5e-324), "at least 2^-1022"),
    (lambda W, u: W.sample_uniform_interval(u[:, :1], 1.0, 1.0 + 2.0 ** -52), None),
    (lambda W, u: W.sample_ggx(u, 10 ** 400), "sample_ggx: alpha=1000"),
    (lambda W, u: W.sample_cosine_hemisphere(u + 0.1j), "sample_cosine_hemisphere: expected "
                                                        "real numbers"),
    (lambda W, u: W.sample_uniform_sphere(np.array([[0.1, None]])), "dtype object"),
    (lambda W, u: W.cosine_hemisphere_pdf(np.array([["a", "b", "c"]])), "cosine_hemisphere_pdf"),
    # found by review: numpy's "setting an array element with a sequence", naming nothing
    (lambda W, u: W.sample_ggx([[0.1], [0.1, 0.2]], 0.5), "sample_ggx: not an array of "
                                                          "numbers"),
    (lambda W, u: W.sample_ggx.with_pdf([[0.1], [0.1, 0.2]], 0.5), "sample_ggx.with_pdf: "
                                                                   "not an array"),
    # the visible normals' float32 wrapper read u first: numpy's bare error (a review)
    (lambda W, u: W.sample_ggx_vndf([[0.1], [0.1, 0.2]], 0.3, 0.6, 0.0, 0.8),
     "sample_ggx_vndf: not an array of numbers"),
    (lambda W, u: W.sample_ggx_vndf.with_pdf([[0.1], [0.1, 0.2]], 0.3, 0.6, 0.0, 0.8),
     "sample_ggx_vndf.with_pdf: not an array"),
], ids=["missing", "too-few", "extra", "negative-alpha", "huge-alpha", "tiny-alpha-pdf",
        "beckmann-huge-alpha", "vndf-tiny-alpha", "nan", "string", "cone-1.5",
        "power-negative", "vndf-not-unit", "sigma-0", "tent-negative", "tent-subnormal",
        "tent-smallest-normal-is-fine", "interval-reversed",
        "linear-zero", "exponential-sigma-t-underflows", "exponential-tiny-sigma",
        "interval-span-overflows", "interval-span-subnormal", "interval-one-ulp-is-fine",
        "int-beyond-float", "complex-points", "object-points",
        "string-points", "ragged-points", "ragged-points-with-pdf", "ragged-vndf",
        "ragged-vndf-with-pdf"])
def test_warp_parameters_are_checked_by_name(call, needle):
    """The kernels read their parameters by position: a missing one was read past its
    array's end (sample_ggx(u) sampled α = 0), and values outside a warp's definition gave
    plausible numbers silently (found by review)."""
    from estimators import warps as W

    u = np.random.default_rng(0).random((8, 2))
    if needle is None:               # a value at the edge of the rule, accepted
        assert np.isfinite(call(W, u)).all()
        return
    with pytest.raises(ValueError) as e:
        call(W, u)
    assert needle in str(e.value), str(e.value)


def test_every_warps_parameters_have_a_rule_and_its_test_ranges_satisfy_it():
    from estimators.warp_params import RULES
    from estimators.warps import WARPS

    for name, w in WARPS.items():
        names, ok, _ = RULES.get(name, ((), None, ""))
        assert names == w.params, name
        corners = [w.defaults, tuple(lo for lo, _ in w.ranges), tuple(hi for _, hi in w.ranges)]
        for values in corners if w.params else []:
            if name == "ggx_vndf":          # the direction is normalised by the tests
                a, x, y, z = values
                n = (x * x + y * y + z * z) ** 0.5
                values = (a, x / n, y / n, z / n)
            assert ok(*values), (name, values)


@pytest.mark.parametrize("scale", [1e-300, 1e-160, 1e160, 1e300, 3e307])
def test_the_linear_warp_depends_on_a_to_b_alone(scale):
    """The linear density depends on a : b only, so scaling both must not move a sample,
    a pdf value or an inverse: a² and b² underflowed (a = b = 1e-300 sampled 2u instead
    of u) or overflowed (every sample 0), and the pdf's 2·a or a + b overflowed (a pdf of
    inf, 0 or NaN at 3e307). Also the bilinear warp, whose rows are linear densities and
    whose pdf sums its four weights."""
    from estimators import warps as W

    u = np.random.default_rng(5).random((1000, 2))
    for a, b in ((1.0, 1.0), (0.2, 3.0), (0.0, 1.0), (5.0, 0.0)):
        for fn, x in ((W.sample_linear, u[:, :1]), (W.linear_pdf, u[:, :1]),
                      (W.invert_linear, u[:, :1])):
            want = fn(x, a, b)
            got = fn(x, a * scale, b * scale)
            assert np.all(np.isfinite(got)), (fn.__name__, a, b)
            np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-300,
                                       err_msg=(fn.__name__, a, b))
    w = (0.5, 2.0, 1.0, 3.0)
    for fn in (W.sample_bilinear, W.bilinear_pdf, W.invert_bilinear):
        got = fn(u, *(scale * c for c in w))
        assert np.all(np.isfinite(got)), fn.__name__
        np.testing.assert_allclose(got, fn(u, *w), rtol=1e-12, err_msg=fn.__name__)


@pytest.mark.parametrize("w", [(0.0, 0.0, 0.0, 1.0), (0.0, 0.0, 2.0, 3.0), (1.0, 2.0, 0.0, 0.0)])
def test_the_bilinear_warp_on_a_row_of_zero_density_stays_finite(w):
    """With w00 = w10 = 0 the row y = 0 has zero density (and y = 1 with w01 = w11 = 0):
    a u on it (u1 = 0 or 1 exactly) sampled NaN (0/0) and the inverse at y = 0 was NaN.
    Any x is right there; the warp gives u (and the inverse x). Elsewhere: unchanged."""
    from estimators import warps as W

    edge = np.array([[0.7, 0.0], [0.2, 0.0], [0.7, 1.0 - 2.0 ** -53], [0.3, 0.5]])
    x = W.sample_bilinear(edge, *w)
    assert np.all(np.isfinite(x)) and np.all((x >= 0.0) & (x < 1.0)), x
    u = W.invert_bilinear(x, *w)
    assert np.all(np.isfinite(u)), u
    np.testing.assert_allclose(u[3], edge[3], rtol=1e-12)
    rows = np.array([[0.7, 0.0], [0.25, 1.0]])
    assert np.all(np.isfinite(W.invert_bilinear(rows, *w)))


@pytest.mark.parametrize("alpha", [1e-30, 1e30])
@pytest.mark.parametrize("name", ["ggx", "beckmann", "ggx_vndf"])
def test_microfacet_warps_hold_at_the_ends_of_their_alpha_range(name, alpha):
    """At the range's ends every sample is a unit vector of finite positive density and
    (where the warp has an inverse) inverts to its u. Past them α² or α⁴ over- or
    underflowed: a zero vector of density 0 at α = 1e160, GGX's density inf at 1e-100."""
    from estimators.warps import WARPS

    w = WARPS[name]
    params = (alpha,) + tuple(w.defaults[1:])
    u = np.random.default_rng(3).random((20_000, 2))
    x = w.sample(u, *params)
    pdf = w.pdf(x, *params)
    assert np.all(np.abs(np.linalg.norm(x, axis=1) - 1) < 1e-15)
    assert np.all(np.isfinite(pdf) & (pdf > 0))
    if w.invert is not None:
        assert np.max(np.abs(w.invert(x, *params) - u)) < 1e-15


@pytest.mark.parametrize("alpha", [1e-30, 0.05, 2.0, 1e30])
@pytest.mark.parametrize("wz", [1e-160, 1e-200, 1e-300])
def test_ggx_visible_normals_density_holds_at_grazing_incidence(alpha, wz):
    """Below w_z ≈ 1e-154, Smith's Λ took tan²θ = (w_x² + w_y²)/w_z², which overflowed:
    G1 = 0 and every sample, a unit vector, had density 0 (found by review). The density
    converges as w_z -> 0, so at these w_z it is the one at w_z = 1e-100 (wx = 1 in
    float64 for all of them)."""
    from estimators import warps as W

    u = np.random.default_rng(11).random((20_000, 2))
    x = W.sample_ggx_vndf(u, alpha, 1.0, 0.0, wz)
    pdf = W.ggx_vndf_pdf(x, alpha, 1.0, 0.0, wz)
    assert np.all(np.isfinite(pdf) & (pdf > 0)), pdf[~(pdf > 0)][:5]
    np.testing.assert_allclose(pdf, W.ggx_vndf_pdf(x, alpha, 1.0, 0.0, 1e-100), rtol=1e-12)


def test_a_nan_u_gives_a_nan_point_from_every_warp():
    """sqrt(max(0, NaN)) was 0: GGX turned a NaN u into the zero vector, density 0."""
    from estimators.warps import WARPS

    for name, w in WARPS.items():
        u = np.full((3, w.sample_dim), 0.4)
        u[1, 0] = np.nan
        x = w.sample(u, *w.defaults)
        assert np.isnan(x[1]).any() and np.isfinite(x[[0, 2]]).all(), name


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_u_of_one_gives_a_point_of_the_domain_from_every_warp(dtype):
    """u = 1 is outside [0, 1), but float32(u) rounds to it for u within 2^-25 of 1: the
    Beckmann sampler's log1p(-1) = -inf made its point NaN (an outside review). Every
    warp returns a finite point of its domain with a finite, non-negative density."""
    from estimators.warps import WARPS

    for name, w in WARPS.items():
        corners = [(1.0,), (0.0,)] if w.sample_dim == 1 else \
            [(1.0, 1.0), (1.0, 0.0), (0.0, 1.0), (1.0, 0.5), (0.5, 1.0)]
        u = np.array(corners, dtype=dtype)
        x = w.sample(u, *w.defaults)
        pdf = w.pdf(x, *w.defaults)
        assert x.dtype == dtype and np.isfinite(x).all(), (name, x)
        assert np.all(np.isfinite(pdf) & (pdf >= 0)), (name, pdf)
        if x.shape[1] == 3:
            assert np.allclose(np.linalg.norm(x.astype(np.float64), axis=1), 1.0,
                               atol=1e-6), (name, x)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("name,params", [
    ("power_cosine", (0.0,)), ("power_cosine", (20.0,)), ("power_cosine", (1e4,)),
    ("ggx", (1e-4,)), ("ggx", (0.3,)), ("ggx", (1e3,)),
    ("ggx_vndf", (0.3, 0.6, 0.0, 0.8)), ("ggx_vndf", (1e-4, 0.6, 0.0, 0.8)),
    ("ggx_vndf", (1e3, 0.6, 0.0, 0.8)), ("beckmann", (0.3,))])
def test_u0_of_one_gives_a_point_of_positive_density(name, params, dtype):
    """u0 = 1 (a float32 u within 2^-25 of 1 rounds to it) put the power-cosine lobe's
    and GGX's point on the horizon and the visible normals' on the edge where w · h = 0,
    all of density 0, so f / pdf was inf once in 2^25 float32 draws (found by review).
    u0 = 1 is taken as 1 - 2^-53, as Beckmann's sampler takes it."""
    from estimators.warps import ONE_MINUS_EPSILON, WARPS

    w = WARPS[name]
    u = np.array([[1.0, 0.0], [1.0, 0.3], [1.0, 1.0]], dtype=dtype)
    x = w.sample(u, *params)
    pdf = w.pdf(x, *params)
    assert np.all(np.isfinite(pdf) & (pdf > 0)), (x, pdf)
    if dtype == np.float64:
        below = u.copy()
        below[:, 0] = ONE_MINUS_EPSILON
        np.testing.assert_array_equal(x, w.sample(below, *params))


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("params", [
    (0.3, 0.6, 0.0, 0.8), (1e-4, 0.6, 0.0, 0.8), (1e3, 0.6, 0.0, 0.8), (0.3, 0.0, 0.0, 1.0),
    (1.0, -0.6, 0.48, 0.64), (0.3, float(np.sqrt(1 - 1e-16)), 0.0, 1e-8)])
def test_visible_normals_near_u0_of_one_have_positive_density(params, dtype):
    """c = √(1 - a² - b²) cancelled at the disk's rim: for u0 within 2^-51 of 1 (u0 = 1,
    taken as 1 - 2^-53, among them) it came out 0 for 0.5-20 % of u1, putting h where
    w · h = 0 (or, through it, below the horizon), of density 0, so f / pdf was inf
    (an outside review; the test above tries three u1 only). It is now taken from
    1 - u0, exact there."""
    from estimators.warps import ONE_MINUS_EPSILON, sample_ggx_vndf

    u1 = np.linspace(0.0, 1.0, 4001)
    for u0 in (1.0, ONE_MINUS_EPSILON, 1.0 - 2.0 ** -52, 1.0 - 2.0 ** -51):
        u = np.stack([np.full_like(u1, u0), u1], axis=-1).astype(dtype)
        x, pdf = sample_ggx_vndf.with_pdf(u, *params)
        bad = ~(np.isfinite(pdf) & (pdf > 0))
        assert not bad.any(), (u0, bad.sum(), u[bad][:3], x[bad][:3])


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_the_sphere_inverse_keeps_u0_near_the_north_pole(dtype):
    """u0 = (1 - z) / 2 cancelled near the pole, where the module computes 1 - cos θ from
    the tangential components (the cone's inverse did, so the cone of cos θ_max = -1,
    the same sphere, kept u0): u0 = 1e-20 came back 0, 1e-10 with a relative error of
    8e-8, and in float32, where z rounds to 1, every u0 below 3e-8 came back 0 (an
    outside review)."""
    from estimators import warps as W

    u = np.array([[1e-20, 0.3], [1e-10, 0.7], [3e-6, 0.1], [0.2, 0.4], [0.9, 0.6]],
                 dtype=dtype)
    back = W.invert_uniform_sphere(W.sample_uniform_sphere(u))
    rtol = 1e-6 if dtype == np.float32 else 1e-14
    np.testing.assert_allclose(back, u, rtol=rtol)


def test_the_cone_inverse_at_the_south_pole_of_the_whole_sphere():
    """cos θ_max = -1: the cone is the sphere, and its inverse at (0, 0, -1) divided 0 by
    0 (an outside review); the uniform sphere's inverse gives u0 = 1 - 2^-53 there."""
    from estimators import warps as W

    south = np.array([[0.0, 0.0, -1.0], [1e-9, 0.0, -1.0 + 5e-19]])
    u = W.invert_uniform_cone(south, -1.0)
    assert np.isfinite(u).all() and u[0, 0] == ONE_MINUS_EPSILON, u
    assert np.allclose(W.invert_uniform_cone(south, -1.0), W.invert_uniform_sphere(south))


@pytest.mark.parametrize("radius", [1e-170, 1e-3, 1e155])
def test_tent_density_at_extreme_radii(radius):
    """(r - |x|)/r² overflowed to 0 at r = 1e155 and to inf at r = 1e-170."""
    from estimators import warps as W

    x = np.array([[0.0], [0.5 * radius], [-0.75 * radius], [radius], [2 * radius]])
    assert W.tent_pdf(x, radius).tolist() == pytest.approx(
        [1 / radius, 0.5 / radius, 0.25 / radius, 0.0, 0.0], rel=1e-15)
    u = np.random.default_rng(0).random((1000, 1))
    assert np.allclose(W.invert_tent(W.sample_tent(u, radius), radius), u, atol=1e-14)


def test_linear_warps_with_a_zero_weight_at_tiny_u():
    """u·b² underflowed: a = 0, b = 1e-60, u = 1e-250 sampled 1 - 2⁻⁵³ (√u = 1e-125 is
    right), smaller u gave NaN, and the bilinear warp's x NaN."""
    from estimators import warps as W

    assert W.sample_linear(np.array([[1e-250]]), 0.0, 1e-60)[0, 0] == pytest.approx(1e-125)
    assert W.sample_linear(np.array([[1e-300]]), 0.0, 1e-149)[0, 0] == pytest.approx(1e-150)
    xy = W.sample_bilinear(np.array([[1e-300, 1e-300]]), 0.0, 0.0, 0.0, 1.0)[0]
    assert xy.tolist() == pytest.approx([1e-150, 1e-150])    # x, y = √u on this row


def test_linear_warps_at_u_0_with_a_weight_ratio_below_float64s_range():
    """a = 1e-170, b = 1e170: a / max(a, b) rounds to 0, and u = 0 gave 0 / 0 = NaN (the
    shortcut for u = 0 looked at the unscaled a; found by review). x = 0 there, of a
    finite density, and the bilinear warp's rows likewise."""
    from estimators import warps as W

    u = np.array([[0.0], [0.25], [1.0 - 2.0 ** -53]])
    for a, b in ((1e-170, 1e170), (5e-324, 1.0), (1e-300, 1e10)):
        x = W.sample_linear(u, a, b)
        assert x[0, 0] == 0.0 and np.isfinite(x).all(), (a, b, x)
        assert np.isfinite(W.linear_pdf(x, a, b)).all()
    xy = W.sample_bilinear(np.array([[0.0, 0.0], [0.0, 0.5]]), 1e-170, 1e170, 1e-170, 1e170)
    assert np.isfinite(xy).all() and xy[:, 0].tolist() == [0.0, 0.0], xy


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_exponential_without_a_far_end_samples_u_of_one_to_a_finite_distance(dtype):
    """t_max = inf: u = 1 (float32's rounding of every u within 2^-25 of 1) gave the
    point inf, of density 0, though u = 1 gives a finite point of the domain from every
    warp (found by review: the test of that used t_max = 3). It is now the distance of
    1 - 2^-53, -log(2^-53) / σ; NaN stays NaN."""
    from estimators import warps as W

    u = np.array([[1.0], [1.0 - 2.0 ** -53], [np.nan], [0.5]], dtype=dtype)
    # (float32 holds 1e-38 to 3.4e38: σ = 1e-150 puts every point past that, σ = 1e150
    # every density)
    for sigma in (2.0, 1e-150, 1e150) if dtype == np.float64 else (2.0, 1e-20, 1e20):
        x = W.sample_exponential(u, sigma, np.inf)
        assert x.dtype == dtype and np.isfinite(x[[0, 1, 3]]).all() and np.isnan(x[2, 0])
        assert x[0, 0] == x[1, 0] if dtype == np.float64 else x[0, 0] >= x[1, 0]
        pdf = W.exponential_pdf(x, sigma, np.inf)
        assert np.all(pdf[[0, 1, 3]] > 0) and np.isfinite(pdf[[0, 1, 3]]).all(), pdf
    xs, ps = W.sample_exponential.with_pdf(u, 2.0, np.inf)
    assert np.isfinite(xs[0, 0]) and ps[0] > 0


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_a_nan_in_one_coordinate_makes_the_whole_point_or_u_nan(dtype):
    """u = (0.3, NaN) gave the sphere (NaN, NaN, 0.4) and the triangle (NaN, y): half a
    point, looking like a coordinate the NaN had not touched; the cosine hemisphere's
    inverse of (x, y, NaN) was a finite u, the NaN gone (found by review). Every
    coordinate of such a row is NaN now, from sample, with_pdf and invert; the other
    rows keep their bits."""
    from estimators.warps import WARPS

    for name, w in WARPS.items():
        good = np.full((1, w.sample_dim), 0.3, dtype)
        u = np.repeat(good, w.sample_dim + 1, 0)
        for i in range(w.sample_dim):
            u[i, i] = np.nan
        x = w.sample(u, *w.defaults)
        assert np.isnan(x[:-1]).all() and np.isfinite(x[-1]).all(), (name, x)
        assert np.array_equal(x[-1], w.sample(good, *w.defaults)[0]), name
        xs, ps = w.sample.with_pdf(u, *w.defaults)
        assert np.array_equal(xs, x, equal_nan=True) and np.isnan(ps[:-1]).all(), name
        if w.invert is None:
            continue
        pts = np.repeat(x[-1:], w.dim + 1, 0)
        for i in range(w.dim):
            pts[i, i] = np.nan
        back = w.invert(pts, *w.defaults)
        assert np.isnan(back[:-1]).all() and np.isfinite(back[-1]).all(), (name, back)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_a_u_outside_the_unit_interval_gives_a_nan_point(dtype):
    """The warps extrapolated a u outside [0, 1] to points off their domain, silently:
    u = -0.5 gave the uniform sphere (0, 0, 2), the cone z = 1.1, the interval a - (b -
    a)/2 and a negative exponential distance (found by review). Such a row is NaN now
    (sample and with_pdf), as a NaN u is; u = 0 and u = 1 stay points of the domain."""
    from estimators.warps import WARPS

    for name, w in WARPS.items():
        k = w.sample_dim
        rows = [np.full(k, v) for v in (-0.5, 1.5, -1e-30, 1.0 + 2.0 ** -23, np.inf)]
        for v in (-0.5, 1.5):          # one coordinate out
            r = np.full(k, 0.3)
            r[-1] = v
            rows.append(r)
        rows += [np.zeros(k), np.ones(k), np.full(k, 0.3)]
        u = np.array(rows, dtype=dtype)
        bad = len(rows) - 3
        x = w.sample(u, *w.defaults)
        assert np.isnan(x[:bad]).all(), (name, x[:bad])
        assert np.isfinite(x[bad:]).all(), (name, x[bad:])
        xs, ps = w.sample.with_pdf(u, *w.defaults)
        assert np.array_equal(xs, x, equal_nan=True) and np.isnan(ps[:bad]).all(), name
        assert np.all(ps[bad:] >= 0), name
