"""``estimators._ssa_blocks``: numba's SSA reconstruction rewriting only the blocks that
name each variable gives numba's own IR, statement for statement and name for name, on
every numba function of the package and on an inlined caller, in fewer block passes;
numba is left as it was outside ``fast_ssa``. The tracer's kernels are compiled inside
it (``compile_lock``), so every render test also checks its output."""

import copy
import importlib
import inspect
import pkgutil

import numpy as np
import pytest
from numba import njit
from numba.core import compiler, ssa
from numba.core.dispatcher import Dispatcher

import estimators
from estimators import _ssa_blocks
from estimators._ssa_blocks import fast_ssa


def _dump(blocks) -> list:
    """Each block's label and its statements as numba prints them, in order."""
    return [(label, [str(stmt) for stmt in blk.body]) for label, blk in blocks.items()]


def _both(blocks):
    """numba's result and ours on two copies of ``blocks`` (each with its own scope)."""
    theirs = _ssa_blocks._NUMBAS(copy.deepcopy(blocks))
    ours = _ssa_blocks._run_ssa(copy.deepcopy(blocks))
    return _dump(theirs), _dump(ours)


def _package_functions():
    """The Python functions behind every numba dispatcher of the ``estimators`` package."""
    found = {}
    for info in pkgutil.walk_packages(estimators.__path__, "estimators."):
        module = importlib.import_module(info.name)
        for name, obj in vars(module).items():
            if isinstance(obj, Dispatcher) and obj.py_func.__module__ == info.name:
                found[f"{info.name}.{name}"] = obj.py_func
    return found


def test_the_package_has_many_functions_to_compare():
    assert len(_package_functions()) > 100


def test_every_package_function_gets_numbas_ssa():
    violating = 0
    for name, fn in sorted(_package_functions().items()):
        blocks = compiler.run_frontend(fn).blocks
        theirs, ours = _both(blocks)
        assert theirs == ours, name
        violating += bool(ssa._find_defs_violators(blocks, ssa.compute_cfg_from_blocks(blocks)))
    # the comparison covers functions SSA has work in, not only trivial ones
    assert violating > 50, violating


def _branchy(x, n):
    acc = 0.0
    k = 0
    while k < n:
        if x > k:
            t = x * k
            acc += t
        elif x < -k:
            t = -x
            acc -= t
            if acc < -100.0:
                break
        else:
            t = 1.0
        x = x * 0.5 + t
        k += 1
    for j in range(3):
        acc = acc + j * x if j % 2 else acc - x
    return acc, k


def test_an_inlined_caller_gets_numbas_ssa_in_fewer_block_passes(monkeypatch):
    callee = njit(inline="always")(_branchy)

    def caller(x, n):
        a, i = callee(x, n)
        b, j = callee(x + 1.0, n + i)
        c, _ = callee(a - b, j)
        return a + b * c

    seen = []

    def recording(blocks):
        seen.append(copy.deepcopy(blocks))
        return _ssa_blocks._run_ssa(blocks)

    plain = njit(caller)
    plain.compile("float64(float64, int64)")
    with fast_ssa():
        assert ssa._run_ssa is _ssa_blocks._run_ssa
        ssa._run_ssa = recording            # fast_ssa puts numba's back on leaving
        fast = njit(caller)
        fast.compile("float64(float64, int64)")
    assert ssa._run_ssa is _ssa_blocks._NUMBAS
    # the caller's reconstruction, with the callee's three copies in it
    assert max(len(b) for b in seen) > 2 * len(compiler.run_frontend(_branchy).blocks)
    passes = [0]
    real_pass = ssa._run_ssa_block_pass

    def counting(states, blk, handler):
        passes[0] += 1
        return real_pass(states, blk, handler)

    monkeypatch.setattr(ssa, "_run_ssa_block_pass", counting)
    counts = []
    for blocks in seen:
        passes[0] = 0
        theirs = _dump(_ssa_blocks._NUMBAS(copy.deepcopy(blocks)))
        numbas = passes[0]
        passes[0] = 0
        ours = _dump(_ssa_blocks._run_ssa(copy.deepcopy(blocks)))
        assert theirs == ours
        counts.append((numbas, passes[0]))
    # on the inlined caller numba's visits every block once per violator and twice over
    numbas, ours = max(counts)
    assert numbas > 3 * ours > 0, counts
    rng = np.random.default_rng(5)
    for x in rng.uniform(-20, 20, 100):
        for n in (0, 1, 7, 30):
            a, b = plain(x, n), fast(x, n)
            assert a == b or (np.isnan(a) and np.isnan(b)), (x, n)


def test_numba_is_restored_outside_and_contexts_nest():
    assert ssa._run_ssa is _ssa_blocks._NUMBAS
    with fast_ssa():
        with fast_ssa():
            assert ssa._run_ssa is _ssa_blocks._run_ssa
        assert ssa._run_ssa is _ssa_blocks._run_ssa
    assert ssa._run_ssa is _ssa_blocks._NUMBAS


def test_an_error_inside_restores_numba():
    with pytest.raises(RuntimeError):
        with fast_ssa():
            raise RuntimeError("compile failed")
    assert ssa._run_ssa is _ssa_blocks._NUMBAS


def test_the_module_says_what_it_measured():
    doc = inspect.getdoc(_ssa_blocks)
    assert "numba's own" in doc
