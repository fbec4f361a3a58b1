"""The branch-free exp, expm1, log, log1p of ``estimators._fastmath``: error in ulps
against an extended-precision reference over the whole domain, the special values
exactly, and that a loop over them vectorises (the reason they exist)."""

import math
import os
import re
import subprocess
import sys

import numpy as np
import pytest
from llvmlite import binding as llvm
from numba import njit

from estimators import _fastmath as F

L = np.longdouble
pytestmark = pytest.mark.skipif(np.finfo(L).nmant < 63,
                                reason="needs an 80-bit long double reference")

TINY = 5e-324                      # smallest subnormal
MIN_NORMAL = 2.2250738585072014e-308
MAX = 1.7976931348623157e308
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(F.__file__)))
ULP_BOUND = 1.0                    # fdlibm's bound for each of the four (< 1 ulp)


def up(x):
    return float(np.nextafter(x, np.inf))


def down(x):
    return float(np.nextafter(x, -np.inf))


def array_loop(f):
    """``out[i] = f(x[i])`` compiled as callers of these functions should be."""
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
    rng = np.random.default_rng({"exp": 1, "expm1": 2, "log": 3, "log1p": 4}[name])
    n = 1_000_000
    small = np.concatenate([log_uniform(rng, -320, 0, 100_000), -log_uniform(rng, -320, 0, 100_000)])
    if name == "exp":
        return np.concatenate([rng.uniform(-745.2, 709.8, n), small,
                               rng.uniform(-745.2, -708.3, 200_000)])   # subnormal results
    if name == "expm1":
        return np.concatenate([rng.uniform(-40.0, 709.8, n), small,
                               rng.uniform(-0.5, 0.5, 200_000)])        # k = 0, ±1
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
}


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
}
SPECIAL = {  # inputs whose results are not finite-and-nonzero, and the exact result
    "exp": [(math.inf, math.inf), (-math.inf, 0.0), (math.nan, math.nan),
            (710.0, math.inf), (-746.0, 0.0)],
    "expm1": [(math.inf, math.inf), (-math.inf, -1.0), (math.nan, math.nan), (0.0, 0.0),
              (-0.0, -0.0), (-40.0, -1.0), (710.0, math.inf)],
    "log": [(0.0, -math.inf), (-0.0, -math.inf), (1.0, 0.0), (math.inf, math.inf),
            (-math.inf, math.nan), (-1.0, math.nan), (-TINY, math.nan), (math.nan, math.nan)],
    "log1p": [(0.0, 0.0), (-0.0, -0.0), (-1.0, -math.inf), (down(-1.0), math.nan),
              (-2.0, math.nan), (math.inf, math.inf), (-math.inf, math.nan),
              (math.nan, math.nan)],
}


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
    made a ``vector.body`` of double lanes and no ``exp``/``log`` call (scalar, or an
    ``llvm.exp.v4f64`` that becomes one libm call per lane) is left."""
    has_vector_body = "vector.body" in ir and re.search(r"<\d+ x double>", ir) is not None
    libm = re.search(r"call [^\n]*@(llvm\.)?(exp|expm1|log|log1p|pow)(\.[a-z0-9]+)?\(", ir)
    return has_vector_body and libm is None


@pytest.mark.parametrize("name", sorted(FUNCTIONS))
def test_a_loop_over_it_vectorises(name):
    loop = array_loop(FUNCTIONS[name][0])
    x = np.linspace(0.1, 2.0, 64)
    loop(x, np.empty_like(x))
    ir = loop.inspect_llvm(loop.signatures[0])
    assert vectorised(ir), name
    if "+avx2" in llvm.get_host_cpu_features().flatten():   # AVX2: four lanes
        assert re.search(r"fmul <4 x double>", ir), name


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
for name in ("beckmann", "exponential"):
    w = W.WARPS[name]
    u = np.full((8, w.sample_dim), 0.25)
    for label, f, x in [("sample", w.sample, u), ("pdf", w.pdf, w.sample(u, *w.defaults))]:
        f(x, *w.defaults)
        loop = f.loop()
        ir = loop.inspect_llvm(loop.signatures[0])
        # the fast functions' integer bit operations in vector lanes exist only if the
        # kernel's loop was vectorised
        print(name + "_" + label, bool(re.search(r"= (ashr|shl|and|or) <\d+ x i64>", ir)),
              bool(re.search(r"call [^\n]*@(llvm\.)?(exp|expm1|log|log1p)(\.[a-z0-9]+)?\(", ir)))
'''


def test_the_warp_front_end_loops_vectorise(tmp_path):
    """The Beckmann and exponential front ends' loops (compiled afresh in a subprocess,
    since numba does not show the IR of cached code) run the kernel in vector lanes."""
    env = dict(os.environ, MCVERIFY_CACHE=str(tmp_path / "k"), NUMBA_CACHE_DIR=str(tmp_path / "n"),
               PYTHONPATH=os.pathsep.join([ROOT, os.environ.get("PYTHONPATH", "")]))
    run = subprocess.run([sys.executable, "-c", _WARP_LOOPS], env=env, capture_output=True,
                         text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    rows = {r.split()[0]: r.split()[1:] for r in run.stdout.splitlines() if r.strip()}
    assert rows == {k: ["True", "False"] for k in ("beckmann_sample", "beckmann_pdf",
                                                   "exponential_sample", "exponential_pdf")}, rows
