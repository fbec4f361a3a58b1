"""The branch-free exp, expm1, log, log1p, atan, acos, atan2 and sin/cos of 2πu of
``estimators._fastmath``: error in ulps against an extended-precision reference over
the whole domain, the special values exactly, and that a loop over them vectorises (the
reason they exist)."""

import functools
import math
import os
import re
import subprocess
import sys

import numpy as np
import pytest
from numba import njit

from estimators import _fastmath as F

L = np.longdouble
#: The ulp-error tests measure against long double; the special-value, scalar-vs-loop
#: and vectorisation tests need no reference and run everywhere.
needs_long_double = pytest.mark.skipif(np.finfo(L).nmant < 63,
                                       reason="needs an 80-bit long double reference")

TINY = 5e-324                      # smallest subnormal
MIN_NORMAL = 2.2250738585072014e-308
MAX = 1.7976931348623157e308
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(F.__file__)))
ULP_BOUND = 1.0                    # fdlibm's bound for each (< 1 ulp); measured: exp, log
#                                    and the rest below 1, atan2 0.75, acos 0.89, sin/cos 2πu 0.85


def up(x):
    return float(np.nextafter(x, np.inf))


def down(x):
    return float(np.nextafter(x, -np.inf))


@functools.lru_cache(maxsize=None)
def array_loop(f):
    """``out[i] = f(x[i])`` compiled as callers of these functions should be (one loop
    per function in a test process: each compiles for seconds, and is not cached)."""
    @njit(error_model="numpy")
    def loop(x, out):
        for i in range(x.size):
            out[i] = f(x[i])
    return loop


def evaluate(f, x):
    x = np.ascontiguousarray(x, dtype=np.float64)
    out = np.empty_like(x)
    array_loop(f)(x, out)
    return out


def ulp_errors(got, ref):
    """|got - ref| in units of the float64 ulp at the exact value ``ref`` (long double):
    2^(e - 53) for |ref| in [2^(e-1), 2^e), 2^-1074 in the subnormal range. Where the
    reference overflows float64 (beyond MAX + half an ulp) the result must be an inf of
    its sign, where it is NaN a NaN; anything else not finite is an infinite error."""
    ref = np.asarray(ref, dtype=L)
    with np.errstate(all="ignore"):
        _, e = np.frexp(np.abs(ref))
        ulp = np.maximum(np.ldexp(L(1), e - 53), np.ldexp(L(1), -1074))
        err = (np.abs(got.astype(L) - ref) / ulp).astype(np.float64)
        overflow = np.abs(ref) >= L(MAX) + np.ldexp(L(1), 970)
    same_inf = overflow & np.isinf(got) & (np.sign(got) == np.sign(ref))
    same_nan = np.isnan(ref) & np.isnan(got)
    err = np.where(np.isnan(err), np.inf, err)
    return np.where(same_inf | same_nan, 0.0, err)


def log_uniform(rng, lo_exp, hi_exp, n):
    return 10.0 ** rng.uniform(lo_exp, hi_exp, n)


def samples(name):
    """Dense samples of each function's domain (1.2e6 to 1.6e6 points), seeded."""
    rng = np.random.default_rng({"exp": 1, "expm1": 2, "log": 3, "log1p": 4, "atan": 6,
                                 "acos": 7}[name])
    n = 1_000_000
    small = np.concatenate([log_uniform(rng, -320, 0, 100_000), -log_uniform(rng, -320, 0, 100_000)])
    if name == "exp":
        return np.concatenate([rng.uniform(-745.2, 709.8, n), small,
                               rng.uniform(-745.2, -708.3, 200_000)])   # subnormal results
    if name == "expm1":
        return np.concatenate([rng.uniform(-40.0, 709.8, n), small,
                               rng.uniform(-0.5, 0.5, 200_000)])        # k = 0, ±1
    if name == "atan":
        return np.concatenate([log_uniform(rng, -323.6, 308.25, n) * rng.choice([-1.0, 1.0], n),
                               rng.uniform(-3.0, 3.0, 200_000)])        # every reduction
    if name == "acos":
        return np.concatenate([rng.uniform(-1.0, 1.0, n), small,
                               1.0 - log_uniform(rng, -16, 0, 200_000),   # near 1 and -1
                               -1.0 + log_uniform(rng, -16, 0, 200_000)])
    if name == "log":
        return np.concatenate([log_uniform(rng, -323.6, 308.25, n),    # subnormals included
                               rng.uniform(0.5, 2.0, 200_000)])         # near 1
    return np.concatenate([log_uniform(rng, -323.6, 308.25, n),        # log1p
                           -log_uniform(rng, -323.6, 0.0, 200_000),       # (-1, 0)
                           -1.0 + log_uniform(rng, -16, 0, 200_000),      # near -1
                           rng.uniform(-0.3, 0.42, 200_000)])             # f = x directly


FUNCTIONS = {  # name: (ours, the long double reference, the float64 reference)
    "exp": (F.fast_exp, np.exp, math.exp),
    "expm1": (F.fast_expm1, np.expm1, math.expm1),
    "log": (F.fast_log, np.log, math.log),
    "log1p": (F.fast_log1p, np.log1p, math.log1p),
    "atan": (F.fast_atan, np.arctan, math.atan),
    "acos": (F.fast_acos, np.arccos, math.acos),
}


@needs_long_double
@pytest.mark.parametrize("name", sorted(FUNCTIONS))
def test_error_at_most_one_ulp_over_the_domain(name):
    f, ref, _ = FUNCTIONS[name]
    x = samples(name)
    with np.errstate(all="ignore"):
        want = ref(x.astype(L))
    err = ulp_errors(evaluate(f, x), want)
    worst = int(np.argmax(err))
    assert err[worst] <= ULP_BOUND, (name, x[worst], err[worst])


EDGES = {
    "exp": [0.0, -0.0, TINY, -TINY, MIN_NORMAL, -MIN_NORMAL, 1.0, up(1.0), down(1.0), -1.0,
            0.5 * math.log(2), -0.5 * math.log(2), 1e-300, -1e-300,
            709.782712893383973096, down(709.782712893383973096), up(709.782712893383973096),
            710.0, 1e308, MAX, -708.3964185322641, -708.4, -720.0, -744.4400719213812,
            -745.1332191019411, -745.1332191019412, -745.14, -746.0, -1e308, -MAX],
    "expm1": [0.0, -0.0, TINY, -TINY, MIN_NORMAL, -MIN_NORMAL, 1e-300, -1e-300,
              2.0 ** -54, -2.0 ** -54, up(2.0 ** -54), 2.0 ** -53, -2.0 ** -53,
              0.5 * math.log(2), -0.5 * math.log(2), up(0.5 * math.log(2)), math.log(2),
              -math.log(2), -0.25, -0.26, 1.0, -1.0, 20 * math.log(2), 19.5 * math.log(2),
              56 * math.log(2), 57 * math.log(2), -56 * math.log(2), -38.8, -38.9, -40.0, -1e300,
              709.782712893383973096, up(709.782712893383973096), 1e308, MAX, -MAX],
    "log": [TINY, 2 * TINY, down(MIN_NORMAL), MIN_NORMAL, up(MIN_NORMAL), 1.0, up(1.0),
            down(1.0), math.sqrt(2), down(math.sqrt(2)), math.sqrt(0.5), up(math.sqrt(0.5)),
            2.0, 0.5, math.e, 10.0, 1e-300, 1e300, MAX],
    "log1p": [0.0, -0.0, TINY, -TINY, MIN_NORMAL, -MIN_NORMAL, 2.0 ** -53, -2.0 ** -53,
              down(2.0 ** -53), up(2.0 ** -53), 1e-16, -1e-16, 1e-10, -1e-10,
              math.sqrt(2) - 1, down(math.sqrt(2) - 1), up(math.sqrt(2) - 1),
              math.sqrt(0.5) - 1, down(math.sqrt(0.5) - 1), up(math.sqrt(0.5) - 1),
              up(-1.0), -0.999999, -0.5, 0.5, 1.0, 2.0 ** 53, 2.0 ** 54, 1e300, MAX],
    # the reductions' class boundaries 7/16, 11/16, 19/16, 39/16 and their neighbours
    "atan": [v * sign for sign in (1.0, -1.0) for b in (0.4375, 0.6875, 1.1875, 2.4375)
             for v in (b, up(b), down(b))]
            + [0.0, TINY, -TINY, MIN_NORMAL, 1e-300, 2.0 ** -27, 0.5, 1.0, 1.5, 1e17, 1e300, MAX,
               -MAX],
    "acos": [0.0, -0.0, TINY, -TINY, 0.5, down(0.5), up(0.5), -0.5, up(-0.5), down(-0.5),
             1.0, down(1.0), down(down(1.0)), -1.0, up(-1.0), up(up(-1.0)), 2.0 ** -57,
             -2.0 ** -57, math.sqrt(0.5), -math.sqrt(0.5), 0.9999999999, -0.9999999999],
}
SPECIAL = {  # inputs whose result is known exactly (infinities, NaN, zeros, π/2, π), and it
    "exp": [(math.inf, math.inf), (-math.inf, 0.0), (math.nan, math.nan),
            (710.0, math.inf), (-746.0, 0.0)],
    "expm1": [(math.inf, math.inf), (-math.inf, -1.0), (math.nan, math.nan), (0.0, 0.0),
              (-0.0, -0.0), (-40.0, -1.0), (710.0, math.inf)],
    "log": [(0.0, -math.inf), (-0.0, -math.inf), (1.0, 0.0), (math.inf, math.inf),
            (-math.inf, math.nan), (-1.0, math.nan), (-TINY, math.nan), (math.nan, math.nan)],
    "log1p": [(0.0, 0.0), (-0.0, -0.0), (-1.0, -math.inf), (down(-1.0), math.nan),
              (-2.0, math.nan), (math.inf, math.inf), (-math.inf, math.nan),
              (math.nan, math.nan)],
    "atan": [(0.0, 0.0), (-0.0, -0.0), (math.inf, math.pi / 2), (-math.inf, -math.pi / 2),
             (math.nan, math.nan)],
    "acos": [(1.0, 0.0), (-1.0, math.pi), (0.0, math.pi / 2), (-0.0, math.pi / 2),
             (up(1.0), math.nan), (down(-1.0), math.nan), (2.0, math.nan),
             (math.inf, math.nan), (-math.inf, math.nan), (math.nan, math.nan)],
}


@needs_long_double
@pytest.mark.parametrize("name", sorted(FUNCTIONS))
def test_edges_within_one_ulp(name):
    f, ref, _ = FUNCTIONS[name]
    x = np.array(EDGES[name])
    got = evaluate(f, x)
    with np.errstate(all="ignore"):
        want = ref(x.astype(L))
    err = ulp_errors(got, want)
    bad = err > ULP_BOUND
    assert not bad.any(), [(xi, gi, e) for xi, gi, e in zip(x[bad], got[bad], err[bad])]


@pytest.mark.parametrize("name", sorted(FUNCTIONS))
def test_special_values_exact(name):
    f, _, libm = FUNCTIONS[name]
    x = np.array([v for v, _ in SPECIAL[name]])
    want = np.array([w for _, w in SPECIAL[name]])
    got = evaluate(f, x)
    same = (got == want) & (np.signbit(got) == np.signbit(want)) | np.isnan(got) & np.isnan(want)
    assert same.all(), list(zip(x[~same], got[~same], want[~same]))
    for v, w in SPECIAL[name]:          # the table agrees with libm where libm answers
        try:
            m = libm(v)
        except (ValueError, OverflowError):
            continue
        if math.isnan(w):
            assert math.isnan(m), (v, m)
        else:
            assert m == w and math.copysign(1, m) == math.copysign(1, w), (v, m, w)


@pytest.mark.parametrize("name", sorted(FUNCTIONS))
def test_scalar_call_equals_loop(name):
    """The function called on its own (compiled alone) gives the loop's bits."""
    f = FUNCTIONS[name][0]
    x = samples(name)[::1000]
    scalar = np.array([f(float(v)) for v in x])
    assert np.array_equal(scalar, evaluate(f, x), equal_nan=True)


# --------------------------------------------------------------------- vectorisation
def vectorised(ir: str) -> bool:
    """The loop in ``ir`` was vectorised and calls no libm function: LLVM's vectoriser
    made a ``vector.body`` of double lanes and no libm call (``exp``, ``atan2``...: scalar, or an
    ``llvm.exp.v4f64`` that becomes one libm call per lane) is left."""
    has_vector_body = "vector.body" in ir and re.search(r"<\d+ x double>", ir) is not None
    libm = re.search(r"call [^\n]*@(llvm\.)?(exp|expm1|log|log1p|pow|atan|atan2|acos|sin|cos)"
                     r"(\.[a-z0-9]+)?\(", ir)
    return has_vector_body and libm is None


@pytest.mark.parametrize("name", sorted(FUNCTIONS))
def test_a_loop_over_it_vectorises(name):
    loop = array_loop(FUNCTIONS[name][0])
    x = np.linspace(0.1, 2.0, 64)
    loop(x, np.empty_like(x))
    ir = loop.inspect_llvm(loop.signatures[0])
    assert vectorised(ir), name
    lanes = expected_lanes()
    if lanes:
        assert re.search(rf"fmul <{lanes} x double>", ir), (name, lanes)


def expected_lanes():
    """float64 lanes of the code numba generates here: 8 with 512-bit vectors (an
    AVX-512 host, ``mcnumba.vector_width``), 4 with AVX2, None elsewhere."""
    from numba.core import registry

    features = registry.cpu_target.target_context.codegen()._tm_features.split(",")
    if "+avx512f" in features and "-prefer-256-bit" in features:
        return 8
    return 4 if "+avx2" in features else None


@pytest.mark.parametrize("name", sorted(FUNCTIONS))
def test_the_same_loop_over_libm_does_not(name):
    """The check above has teeth: libm's versions fail it (a scalar call per point)."""
    libm = FUNCTIONS[name][2]
    loop = array_loop(njit(lambda v: libm(v)))
    x = np.linspace(0.1, 2.0, 64)
    loop(x, np.empty_like(x))
    assert not vectorised(loop.inspect_llvm(loop.signatures[0])), name


_WARP_LOOPS = r'''
import re
import numpy as np
from estimators import warps as W
for name in ("beckmann", "exponential", "power_cosine"):
    w = W.WARPS[name]
    u = np.full((8, w.sample_dim), 0.25)
    x = w.sample(u, *w.defaults)
    for label, f, x in [("sample", w.sample, u), ("pdf", w.pdf, x), ("invert", w.invert, x)]:
        f(x, *w.defaults)
        loop = f.loop()
        ir = loop.inspect_llvm(loop.signatures[0])
        # the fast functions' integer bit operations in vector lanes exist only if the
        # kernel's loop was vectorised
        print(name + "_" + label, bool(re.search(r"= (ashr|shl|and|or) <\d+ x i64>", ir)),
              bool(re.search(r"call [^\n]*@(llvm\.)?(exp|expm1|log|log1p|pow)(\.[a-z0-9]+)?\(", ir)))
'''


def loop_rows(script, tmp_path):
    """Run ``script`` in a subprocess with empty caches (numba does not show the IR of
    cached code) and return its rows, ``name: [fields]``."""
    env = dict(os.environ, MCVERIFY_CACHE=str(tmp_path / "k"), NUMBA_CACHE_DIR=str(tmp_path / "n"),
               PYTHONPATH=os.pathsep.join([ROOT, os.environ.get("PYTHONPATH", "")]))
    run = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True,
                         text=True, timeout=900)
    assert run.returncode == 0, run.stderr
    return {r.split()[0]: r.split()[1:] for r in run.stdout.splitlines() if r.strip()}


@pytest.mark.slow   # compiles the loops afresh in a subprocess: about a minute
def test_the_warp_front_end_loops_vectorise(tmp_path):
    """The Beckmann, exponential and power-cosine front ends' loops (compiled afresh in a
    subprocess, since numba does not show the IR of cached code) run the kernel in
    vector lanes and call no libm exp, expm1, log, log1p (or pow)."""
    rows = loop_rows(_WARP_LOOPS, tmp_path)
    assert rows == {f"{w}_{f}": ["True", "False"]
                    for w in ("beckmann", "exponential", "power_cosine")
                    for f in ("sample", "pdf", "invert")}, rows
_AZIMUTH_LOOPS = r'''
import re
import numpy as np
from estimators import warps as W
for name, labels in [("uniform_sphere", ("sample", "invert")), ("uniform_cone", ("sample", "invert")),
                     ("ggx", ("sample", "invert")), ("uniform_disk_polar", ("invert",)),
                     ("uniform_disk_concentric", ("sample", "invert")),
                     ("cosine_hemisphere", ("invert",))]:
    w = W.WARPS[name]
    u = np.full((8, w.sample_dim), 0.25)
    x = w.sample(u, *w.defaults)
    for label in labels:
        f, arg = (w.sample, u) if label == "sample" else (w.invert, x)
        f(arg, *w.defaults)
        loop = f.loop()
        ir = loop.inspect_llvm(loop.signatures[0])
        print(name + "_" + label, bool(re.search(r"fmul <\d+ x double>", ir)),
              bool(re.search(r"call [^\n]*@_ZN10estimators", ir)),
              bool(re.search(r"call [^\n]*@(llvm\.)?(atan|atan2|sin|cos)(\.[a-z0-9]+)?\(", ir)))
'''


@pytest.mark.slow   # compiles the loops afresh in a subprocess: about a minute
def test_the_azimuth_front_end_loops_vectorise(tmp_path):
    """The loops of the warps whose sample or inverse takes an azimuth (sin/cos of 2πu,
    atan2, the concentric inverse's atan) multiply in vector lanes, call no warp kernel
    (inlined, so LLVM could vectorise) and no libm function; compiled afresh in a
    subprocess, as above."""
    rows = loop_rows(_AZIMUTH_LOOPS, tmp_path)
    assert len(rows) == 10 and all(v == ["True", "False", "False"] for v in rows.values()), rows


# --------------------------------------------------------------------------- atan2
@njit(error_model="numpy")
def _atan2_loop(y, x, out):
    for i in range(x.size):
        out[i] = F.fast_atan2(y[i], x[i])


def evaluate_atan2(y, x):
    y, x = np.broadcast_arrays(np.asarray(y, dtype=np.float64), np.asarray(x, dtype=np.float64))
    out = np.empty(x.shape)
    _atan2_loop(np.ascontiguousarray(y), np.ascontiguousarray(x), out)
    return out


def atan2_samples():
    """1.8e6 seeded pairs: every quadrant and magnitude (subnormals to MAX, so y/x
    overflows and underflows), the unit square, ratios near each reduction boundary of
    |y/x| (7/16, 11/16, 19/16, 39/16) and near the diagonals and axes."""
    rng = np.random.default_rng(9)
    n = 300_000

    def signed(lo, hi):
        return log_uniform(rng, lo, hi, n) * rng.choice([-1.0, 1.0], n)

    sign = rng.choice([-1.0, 1.0], (2, n))
    x_unit = signed(-3, 3)
    ratio = np.repeat([0.4375, 0.6875, 1.1875, 2.4375, 1.0], n // 5) * (1 + rng.uniform(-1e-3, 1e-3, n))
    pairs = [(signed(-323.6, 308.25), signed(-323.6, 308.25)),
             (rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)),
             (sign[0] * ratio * np.abs(x_unit), x_unit),
             (signed(-30, 0), sign[1]),                       # near the x axis
             (sign[1], signed(-30, 0)),                       # near the y axis
             (signed(-310, -300), signed(-310, -300))]        # both tiny (scaled up)
    return np.concatenate([p[0] for p in pairs]), np.concatenate([p[1] for p in pairs])


@needs_long_double
def test_atan2_error_at_most_one_ulp():
    y, x = atan2_samples()
    err = ulp_errors(evaluate_atan2(y, x), np.arctan2(y.astype(L), x.astype(L)))
    worst = int(np.argmax(err))
    assert err[worst] <= ULP_BOUND, (y[worst], x[worst], err[worst])


ATAN2_VALUES = [0.0, -0.0, TINY, -TINY, MIN_NORMAL, 1.0, -1.0, 0.5, 3.0, 1e-300, 1e300,
                MAX, -MAX, math.inf, -math.inf, math.nan]


@needs_long_double
def test_atan2_special_values_as_libm():
    """Every pair of zeros, subnormals, huge values, infinities and NaN: numpy's (C99
    Annex F) result exactly where it is exact (a zero, ±π/2, ±π/4, ±3π/4, ±π or NaN,
    sign included), within one ulp elsewhere."""
    y = np.repeat(ATAN2_VALUES, len(ATAN2_VALUES))
    x = np.tile(ATAN2_VALUES, len(ATAN2_VALUES))
    got = evaluate_atan2(y, x)
    want = np.arctan2(y, x)
    exact = (np.abs(y) == np.abs(x)) | np.isin(np.abs(y), [0.0, math.inf]) | np.isin(
        np.abs(x), [0.0, math.inf]) | np.isnan(y) | np.isnan(x)
    same = (got == want) & (np.signbit(got) == np.signbit(want)) | np.isnan(got) & np.isnan(want)
    assert same[exact].all(), list(zip(y[exact & ~same], x[exact & ~same], got[exact & ~same]))
    err = ulp_errors(got, np.arctan2(y.astype(L), x.astype(L)))
    assert (err <= ULP_BOUND).all(), list(zip(y[err > ULP_BOUND], x[err > ULP_BOUND]))


def test_atan2_scalar_call_equals_loop():
    y, x = atan2_samples()
    y, x = y[::2000], x[::2000]
    scalar = np.array([F.fast_atan2(float(a), float(b)) for a, b in zip(y, x)])
    assert np.array_equal(scalar, evaluate_atan2(y, x), equal_nan=True)


def test_atan2_loop_vectorises_and_libms_does_not():
    x = np.linspace(-2.0, 2.0, 64)
    _atan2_loop(x[::-1].copy(), x, np.empty_like(x))
    assert vectorised(_atan2_loop.inspect_llvm(_atan2_loop.signatures[0]))

    @njit(error_model="numpy")
    def libm(y, x, out):
        for i in range(x.size):
            out[i] = math.atan2(y[i], x[i])
    libm(x[::-1].copy(), x, np.empty_like(x))
    assert not vectorised(libm.inspect_llvm(libm.signatures[0]))


# ------------------------------------------------------------------ sin, cos of 2πu
_TWO_PI_L = L("6.283185307179586476925286766559005768")


@njit(error_model="numpy")
def _sincos_loop(u, s, c):
    for i in range(u.size):
        s[i], c[i] = F.fast_sincos_2pi(u[i])


def evaluate_sincos(u):
    u = np.ascontiguousarray(u, dtype=np.float64)
    s, c = np.empty_like(u), np.empty_like(u)
    _sincos_loop(u, s, c)
    return s, c


def sincos_reference(u):
    """sin 2πu, cos 2πu in long double: u's quadrant q and remainder r = u - q/4 are
    exact in float64, so only the small angle 2πr is rounded (to 64 bits), then rotated."""
    q = np.floor(4 * u + 0.5)
    t = _TWO_PI_L * (u - 0.25 * q).astype(L)
    s, c = np.sin(t), np.cos(t)
    k = (q % 4).astype(int)
    return np.choose(k, [s, c, -s, -c]), np.choose(k, [c, -s, -c, s])


def sincos_samples():
    """1.6e6 seeded u: uniform on [0, 1], log-uniform down to the subnormals, each
    quadrant boundary k/8 and its neighbourhood, the envmap's θ/2π = v/2 on [0, ½], and
    beyond [0, 1] (negative, and up to 2^40)."""
    rng = np.random.default_rng(10)
    n = 200_000
    near = np.repeat(np.arange(9) / 8.0, n // 9 + 1)[:n] + rng.uniform(-1e-6, 1e-6, n)
    return np.concatenate([rng.uniform(0.0, 1.0, 4 * n), log_uniform(rng, -323.6, 0, n),
                           np.abs(near), 0.5 * rng.uniform(0.0, 1.0, n),
                           rng.uniform(-1.0, 0.0, n // 2), log_uniform(rng, 0, 12, n // 2)])


@needs_long_double
def test_sincos_2pi_error_at_most_one_ulp():
    u = sincos_samples()
    s, c = evaluate_sincos(u)
    ref_s, ref_c = sincos_reference(u)
    for name, got, ref in (("sin", s, ref_s), ("cos", c, ref_c)):
        err = ulp_errors(got, ref)
        worst = int(np.argmax(err))
        assert err[worst] <= ULP_BOUND, (name, u[worst], err[worst])


def test_sincos_2pi_special_values():
    """Quarter turns exactly (0, ±1), ±0 gives (±0, 1), and ±inf and NaN give NaN."""
    u = np.array([0.0, -0.0, 0.25, 0.5, 0.75, 1.0, -0.25, 2.5, math.inf, -math.inf, math.nan])
    s, c = evaluate_sincos(u)
    assert list(s[:8]) == [0.0, 0.0, 1.0, 0.0, -1.0, 0.0, -1.0, 0.0]
    assert list(c[:8]) == [1.0, 1.0, 0.0, -1.0, 0.0, 1.0, 0.0, -1.0]
    assert np.signbit(s[1]) and not np.signbit(s[0])
    assert np.isnan(s[8:]).all() and np.isnan(c[8:]).all()


@needs_long_double
def test_sincos_reduced_at_most_one_ulp():
    """The kernel on its own, as the concentric disk map calls it (tail y = 0) on
    [-π/4, π/4], and with a tail."""
    rng = np.random.default_rng(11)
    x = np.concatenate([rng.uniform(-math.pi / 4, math.pi / 4, 1_000_000),
                        log_uniform(rng, -300, 0, 200_000) * (math.pi / 4)])

    @njit(error_model="numpy")
    def loop(x, y, s, c):
        for i in range(x.size):
            s[i], c[i] = F.sincos_reduced(x[i], y[i])
    for y in (np.zeros_like(x), x * rng.uniform(-2.0 ** -54, 2.0 ** -54, x.size)):
        s, c = np.empty_like(x), np.empty_like(x)
        loop(x, y, s, c)
        t = x.astype(L) + y.astype(L)
        for name, got, ref in (("sin", s, np.sin(t)), ("cos", c, np.cos(t))):
            err = ulp_errors(got, ref)
            assert err.max() <= ULP_BOUND, (name, x[np.argmax(err)], err.max())


def test_sincos_2pi_scalar_call_equals_loop():
    u = sincos_samples()[::1000]
    scalar = np.array([F.fast_sincos_2pi(float(v)) for v in u])
    assert np.array_equal(scalar, np.stack(evaluate_sincos(u), axis=1), equal_nan=True)


def test_sincos_2pi_loop_vectorises_and_libms_does_not():
    u = np.linspace(0.0, 1.0, 64)
    evaluate_sincos(u)
    assert vectorised(_sincos_loop.inspect_llvm(_sincos_loop.signatures[0]))

    @njit(error_model="numpy")
    def libm(u, s, c):
        for i in range(u.size):
            s[i], c[i] = math.sin(2 * math.pi * u[i]), math.cos(2 * math.pi * u[i])
    libm(u, np.empty_like(u), np.empty_like(u))
    assert not vectorised(libm.inspect_llvm(libm.signatures[0]))


# --------------------------------------------- coarse angles for texture coordinates
@njit(error_model="numpy")
def _coarse_atan2_loop(y, x, out):
    for i in range(x.size):
        out[i] = F.coarse_atan2(y[i], x[i])


@njit(error_model="numpy")
def _coarse_acos_loop(x, out):
    for i in range(x.size):
        out[i] = F.coarse_acos(x[i])


def test_coarse_atan2_within_1e_10_and_as_libm_on_special_values():
    """Within 1e-10 of the exact angle on random points, near the axes and the
    diagonals, at tiny and huge scales; every pair of zeros, subnormals, huge values,
    infinities and NaN has numpy's sign, and its value within 1e-10."""
    rng = np.random.default_rng(11)
    n = 400_000
    t = np.concatenate([rng.uniform(0, 1, n), 10.0 ** rng.uniform(-30, 0, n),
                        1.0 - 10.0 ** rng.uniform(-16, 0, n)])
    sx, sy = rng.choice([-1.0, 1.0], (2, t.size))
    swap = rng.random(t.size) < 0.5
    y = np.where(swap, t, 1.0) * sy
    x = np.where(swap, 1.0, t) * sx
    scale = 10.0 ** rng.uniform(-300, 300, t.size)
    for yy, xx in ((y, x), (y * scale, x * scale)):
        got = np.empty_like(xx)
        _coarse_atan2_loop(yy, xx, got)
        want = np.arctan2(yy.astype(np.longdouble), xx.astype(np.longdouble))
        assert np.abs(got - want).max() <= 1e-10
    values = [0.0, -0.0, 5e-324, -5e-324, 2.2250738585072014e-308, 1.0, -1.0, 1e300,
              -1e300, 1.7976931348623157e308, math.inf, -math.inf, math.nan]
    y = np.repeat(values, len(values))
    x = np.tile(values, len(values))
    got = np.empty_like(x)
    _coarse_atan2_loop(y, x, got)
    want = np.arctan2(y, x)
    nan = np.isnan(want)
    assert np.array_equal(np.isnan(got), nan)
    assert (np.abs(got - want)[~nan] <= 1e-10).all()
    assert np.array_equal(np.signbit(got[~nan]), np.signbit(want[~nan]))


def test_coarse_acos_within_1e_10_absolute_and_relative():
    rng = np.random.default_rng(12)
    x = np.concatenate([np.linspace(-1.0, 1.0, 400_001), rng.uniform(-1, 1, 400_000),
                        1.0 - 10.0 ** rng.uniform(-16, 0, 200_000),
                        -1.0 + 10.0 ** rng.uniform(-16, 0, 200_000)])
    got = np.empty_like(x)
    _coarse_acos_loop(x, got)
    want = np.arccos(x.astype(np.longdouble))
    assert np.abs(got - want).max() <= 1e-10
    near_one = (x > 0.5) & (x < 1.0)      # acos small: relative precision kept
    assert (np.abs(got - want)[near_one] / want[near_one]).max() <= 1e-10
    special = np.array([1.0, -1.0, 0.0, -0.0, 1.0 + 2.0 ** -52, -1.5, math.inf, math.nan])
    got = np.empty_like(special)
    _coarse_acos_loop(special, got)
    assert got[0] == 0.0 and got[1] == math.pi
    assert abs(got[2] - math.pi / 2) <= 1e-10 and abs(got[3] - math.pi / 2) <= 1e-10
    assert np.isnan(got[4:]).all()


def test_coarse_angle_loops_vectorise():
    x = np.linspace(-1.0, 1.0, 64)
    _coarse_atan2_loop(x[::-1].copy(), x, np.empty_like(x))
    _coarse_acos_loop(x, np.empty_like(x))
    assert vectorised(_coarse_atan2_loop.inspect_llvm(_coarse_atan2_loop.signatures[0]))
    assert vectorised(_coarse_acos_loop.inspect_llvm(_coarse_acos_loop.signatures[0]))
