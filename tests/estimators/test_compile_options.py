"""Every numba function of ``estimators`` states its own ``fastmath`` and ``error_model``
(``estimators._compile_options``): numba otherwise compiles a callee with its first
caller's options and keeps that compilation for every later caller, so the warps' bits
depended on whether the path tracer (``fastmath={"contract"}``) was compiled first."""

import importlib
import os
import pkgutil
import subprocess
import sys

from numba.core.registry import CPUDispatcher

import estimators
from estimators._compile_options import EXACT, FUSED

# the tracer's templates, loaded by ``render``/``sampling`` from the kernel cache folder
_TEMPLATES = ("estimators.pathtracer._kernel", "estimators.pathtracer._sampling_loops")


def _modules():
    names = [m.name for m in pkgutil.walk_packages(estimators.__path__, "estimators.")
             if m.name != "estimators.pathtracer.make_materials"]   # imports Mitsuba
    return [importlib.import_module(n) for n in sorted(set(names) | set(_TEMPLATES))]


def test_every_numba_function_states_its_compile_options():
    """Each dispatcher defined in the package carries ``fastmath`` and ``error_model`` of
    its own, ``EXACT``'s in the sampling code and ``FUSED``'s in the path tracer."""
    seen = 0
    for module in _modules():
        tracer = module.__name__.startswith("estimators.pathtracer")
        for name, f in vars(module).items():
            if not isinstance(f, CPUDispatcher) or f.py_func.__module__ != module.__name__:
                continue
            seen += 1
            options = {k: f.targetoptions.get(k) for k in ("fastmath", "error_model")}
            assert options == (FUSED if tracer else EXACT), (module.__name__, name, options)
    assert seen > 150, seen     # every module was found


_PROBE = """
import numpy as np
from numba import njit
from estimators import warps
from estimators._fastmath import sincos_reduced
from estimators.distributions import sample_pc2d_kernel
from estimators.pathtracer.geometry import coordinate_system

@njit(fastmath={"contract"})
def contracting_caller(u):
    # compiled first: the callees would inherit its contract flag
    marg = np.array([0.0, 0.5, 1.0, 0.0, 1.0])
    return (warps._sample_ggx_kernel((u, 0.25), (0.3,))[0] + sincos_reduced(u, 0.0)[0]
            + sample_pc2d_kernel(marg, marg.reshape(1, -1), u, u)[2])

@njit
def plain_caller(u):
    return coordinate_system(u, 0.0, 1.0)[0][0]

contracting_caller(0.3)
plain_caller(0.3)
for f in (warps._sample_ggx_kernel, sincos_reduced, sample_pc2d_kernel, coordinate_system):
    ir = "".join(f.inspect_llvm(s) for s in f.signatures)
    print(f.__name__, " contract " in ir)
u = np.random.default_rng(7).random((4099, 2))
w = warps.WARPS["ggx"]
x = w.sample(u, 0.3)
xs, ps = w.sample.with_pdf(u, 0.3)
print("with_pdf", np.array_equal(x, xs) and np.array_equal(ps, w.pdf(x, 0.3)))
"""


def test_callers_options_do_not_leak_into_kernels(tmp_path):
    """In fresh caches, a ``contract`` caller compiled first leaves the warps', the
    ``_fastmath`` helpers' and the distributions' kernels without the flag, and a plain
    caller leaves the tracer's ``coordinate_system`` with it (the IR check is what tells
    the old code from the new on any CPU: it printed True, True, True, False); GGX's
    ``with_pdf`` equals ``sample`` and ``pdf`` bit for bit (it was 2 ulps off on 45 of
    4099 rows when the flag had leaked, in another order of compilation)."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"),
               MCVERIFY_CACHE=str(tmp_path / "kernels"))
    r = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True,
                       env=env, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    assert r.stdout.split() == ["_sample_ggx_kernel", "False", "sincos_reduced", "False",
                                "sample_pc2d_kernel", "False", "coordinate_system", "True",
                                "with_pdf", "True"], r.stdout

