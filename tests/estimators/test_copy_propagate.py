"""``estimators._copy_propagate``: numba's copy propagation analysis without deep copies
gives numba's own copies into and out of every block, on every numba function of the
package (before and after SSA, every name of one type and names of a few types), on
every call the parfor passes make while compiling parallel loops (that numba is left
as it was outside ``fast_copy_propagation``: ``test_numba_patches``). The warps' loops and the tracer's kernels are
compiled inside it (``compile_lock``), so every warp and render test also checks its
output."""

import collections

import numpy as np
from numba import njit, prange, types
from numba.core import compiler, ir_utils, ssa
from numba.parfors import parfor

from estimators import _copy_propagate
from estimators._copy_propagate import fast_copy_propagation
from test_ssa_blocks import _package_functions

_MODULES = (ir_utils, parfor)
_TYPES = (types.float64, types.int64, types.float64, types.Array(types.float64, 1, "C"))


def _typemaps(blocks):
    """Every name one type (every variable-to-variable assignment is then a copy), and
    the names spread over a few types, arrays among them (some assignments are then not
    copies, and an in-place operation on an array kills its copies)."""
    one = collections.defaultdict(lambda: types.float64)
    names = sorted({v.name for block in blocks.values() for stmt in block.body
                    for v in stmt.list_vars()})
    few = {name: _TYPES[i % len(_TYPES)] for i, name in enumerate(names)}
    return one, few


def test_every_package_function_gets_numbas_copies():
    functions = _package_functions()
    assert len(functions) > 100
    copies = 0
    for name, fn in sorted(functions.items()):
        blocks = compiler.run_frontend(fn).blocks
        for stage in (blocks, ssa._run_ssa(blocks)):
            for typemap in _typemaps(stage):
                theirs = _copy_propagate._NUMBAS(stage, typemap)
                ours = _copy_propagate.copy_propagate(stage, typemap)
                assert ours == theirs, name
                copies += sum(map(len, ours[0].values()))
    # the comparison covers functions with copies flowing between blocks
    assert copies > 1000, copies


def _loops(a, out, n):
    for i in prange(a.shape[0]):
        acc = 0.0
        x = a[i]
        for k in range(n):
            if x > k:
                acc += x * k
            elif k % 3 == 0:
                continue
            else:
                acc -= 1.0
                y = acc
                if y < -50.0:
                    break
            x = 0.5 * x + 1.0
        b = acc
        out[i] = b
    return out


def test_every_call_of_a_parallel_compilation_gets_numbas_copies(monkeypatch):
    """The parfor passes call the analysis on whole functions and on each parfor's
    blocks: each call's inputs through both, the same answer, and the function compiled
    with ours computes what the one compiled with numba's does."""
    calls = []

    def both(blocks, typemap):
        theirs = _copy_propagate._NUMBAS(blocks, typemap)
        ours = _copy_propagate.copy_propagate(blocks, typemap)
        assert ours == theirs
        calls.append(sum(map(len, ours[1].values())))
        return theirs

    for module in _MODULES:
        monkeypatch.setattr(module, "copy_propagate", both)
    njit(parallel=True)(_loops).compile("float64[:](float64[:], float64[:], int64)")
    monkeypatch.undo()
    assert len(calls) >= 3 and sum(calls) > 0, calls

    a = np.linspace(-10, 60, 57)
    plain = njit(parallel=True)(_loops)
    with fast_copy_propagation():
        fast = njit(parallel=True)(_loops)
        fast.compile("float64[:](float64[:], float64[:], int64)")
    for n in (0, 1, 5, 40):
        np.testing.assert_array_equal(plain(a, np.empty_like(a), n),
                                      fast(a, np.empty_like(a), n))
