"""numba's compile options, stated by each of this package's functions for itself.

numba compiles a function that another numba function calls with the caller's
``fastmath`` and ``error_model`` wherever the callee does not state its own
(``CPUTargetOptions.finalize``: ``flags.inherit_if_not_set``), and it keeps that first
compilation, in memory and in its cache, for every later caller. The path tracer's
``_trace_samples`` is compiled with ``fastmath={"contract"}`` (a multiply feeding an add
may become one fused multiply-add); the warps, ``_fastmath``'s helpers and the
distributions' kernels, which it calls, then came out with fused multiply-adds or
without them depending on which was compiled first, the tracer or an array front end.
Their bits then changed with the order of the tests, and LLVM fuses flagged pairs where
the code's shape allows, so the same kernel inlined into two loops rounded differently:
a GGX sample 2 ulps off between ``sample_ggx`` and ``sample_ggx.with_pdf``, and the
512-bit and 256-bit builds of the warps no longer equal (CI, 5 December).

So every function states both, through these two decorators:

- ``exact``: every rounding as written (no fast-math flag), for the sampling code whose
  error bounds are analysed and tested bit for bit: ``warps``, ``_fastmath``,
  ``distributions``.
- ``fused``: LLVM's ``contract`` flag alone, for the path tracer's own code (its BSDFs,
  emitters, geometry, textures, camera and kernel), as ``_trace_samples`` has it; its
  array front ends (``sampling``) call the same compiled functions.

Both use IEEE division (``error_model="numpy"``: x/0 is ±inf or NaN, no
ZeroDivisionError branch, which would also stop LLVM from vectorising a loop). A function
inlined by numba (``inline="always"``) is lowered with its caller's options, whatever it
states: the tracer's inlined per-ray code is ``fused``, the warps' inlined helpers
``exact`` inside an exact kernel. ``tests/estimators/test_compile_options.py`` checks
that every numba function of the package states both options.
"""

from __future__ import annotations

from numba import njit
from numba.core import ir_utils
from numba.core.compiler import Compiler, DefaultPassBuilder
from numba.core.compiler_machinery import FunctionPass, PassManager, register_pass
from numba.core.typed_passes import NopythonRewrites

#: The sampling code's options: IEEE arithmetic, nothing relaxed.
EXACT = {"fastmath": False, "error_model": "numpy"}
#: The path tracer's options: multiply-adds may fuse, nothing else relaxed.
FUSED = {"fastmath": {"contract"}, "error_model": "numpy"}


@register_pass(mutates_CFG=True, analysis_only=False)
class SimplifyCopies(FunctionPass):
    """numba's copy propagation and dead code removal on the typed IR
    (``ir_utils.simplify``), as its parallel pipeline runs them on every function: the
    copies that inlining leaves (an inlined function's array parameter bound to the
    caller's array) are gone before lowering, and with them a reference count update
    each."""

    _name = "estimators_simplify_copies"

    def __init__(self):
        FunctionPass.__init__(self)

    def run_pass(self, state):
        ir_utils.simplify(state.func_ir, state.typemap, state.calltypes, {})
        return True


class ThreadedLoopCompiler(Compiler):
    """numba's pipeline as it compiles the body of a parallel loop, without the parallel
    loop: copies simplified after typing (``SimplifyCopies``) and the ``noalias`` flag
    set (the pointers of the function's array arguments marked ``noalias`` for LLVM: no
    two arguments overlap where one is written). The loops that ``mcnumba.threads`` runs
    were such bodies; compiled as plain functions they ran 2-13 times slower (measured,
    one thread: the Cornell box at 128² and 64 spp 0.37 -> 0.85 s, a BSDF's sampling
    loop 62 -> 316 ns a row), from reference count updates in the per-sample code."""

    def define_pipelines(self):
        self.state.flags.noalias = True
        build = DefaultPassBuilder
        pm = PassManager("threaded_loop")
        pm.passes.extend(build.define_untyped_pipeline(self.state).passes)
        typed = build.define_typed_pipeline(self.state).passes
        at = next(i for i, (cls, _) in enumerate(typed) if cls is NopythonRewrites) + 1
        pm.passes.extend(typed[:at] + [(SimplifyCopies, "simplify copies")] + typed[at:])
        pm.passes.extend(build.define_nopython_lowering_pipeline(self.state).passes)
        pm.finalize()
        return [pm]


#: A loop over a range of items that ``mcnumba.threads`` runs on several threads
#: (``@fused(**THREADED)``): it releases the GIL, and its callers pass arrays that do not
#: overlap where one is written (``ThreadedLoopCompiler``).
THREADED = {"nogil": True, "pipeline_class": ThreadedLoopCompiler}


def exact(**options):
    """``njit(cache=True, **EXACT, **options)``."""
    return njit(cache=True, **EXACT, **options)


def fused(**options):
    """``njit(cache=True, **FUSED, **options)``."""
    return njit(cache=True, **FUSED, **options)
