"""``estimators._live_bits``: numba's liveness analysis on bit sets gives numba's own live
variables, block for block, on random control-flow graphs (loops, self-loops, dead
blocks, blocks without successors) and on every numba function of the package before
and after SSA (that numba is left as it was outside ``fast_liveness``, in all three
modules that hold the function: ``test_numba_patches``). The tracer's kernels are compiled inside it (``compile_lock``),
so every render test also checks its output."""

import numpy as np
from numba import njit
from numba.core import analysis, compiler, ir_utils, ssa
from numba.core.controlflow import CFGraph
from numba.parfors import parfor

from estimators import _live_bits
from estimators._live_bits import fast_liveness
from test_ssa_blocks import _package_functions

_MODULES = (analysis, ir_utils, parfor)


def _random_case(rng):
    """A random graph (entry 0) over 1-40 blocks, at times with dead blocks, and
    random uses and definitions drawn from a pool of names."""
    n = int(rng.integers(1, 41))
    cfg = CFGraph()
    for label in range(n):
        cfg.add_node(label)
    for label in range(n - 1):
        if rng.random() < 0.9:              # a spine keeps most blocks reachable
            cfg.add_edge(label, label + 1)
    for label in range(n):
        for _ in range(int(rng.integers(0, 3))):
            if rng.random() < 0.7:          # mostly forward, some back edges and self-loops
                target = int(rng.integers(label, n))
            else:
                target = int(rng.integers(0, label + 1))
            cfg.add_edge(label, target)
    cfg.set_entry_point(0)
    cfg.process()
    pool = [f"v{i}" for i in range(int(rng.integers(1, n + 3)))]

    def some():
        k = int(rng.integers(0, min(len(pool), 6) + 1))
        return set(rng.choice(pool, size=k, replace=False).tolist())

    blocks = {label: None for label in range(n)}
    uses = {label: some() for label in blocks}
    defs = {label: some() - uses[label] for label in blocks}
    return cfg, blocks, uses, defs


def test_random_graphs_get_numbas_live_variables():
    rng = np.random.default_rng(20261205)
    spread, dead = 0, 0
    for _ in range(600):
        cfg, blocks, uses, defs = _random_case(rng)
        theirs = _live_bits._NUMBAS(cfg, blocks, uses, defs)
        ours = _live_bits.compute_live_map(cfg, blocks, uses, defs)
        assert list(ours) == list(theirs)
        assert ours == theirs
        spread += any(ours[b] != uses[b] for b in blocks)
        dead += bool(cfg.dead_nodes())
    # the cases propagate liveness across blocks and include unreachable blocks
    assert spread > 300 and dead > 100, (spread, dead)


def _both(blocks):
    cfg = analysis.compute_cfg_from_blocks(blocks)
    usedefs = analysis.compute_use_defs(blocks)
    args = cfg, blocks, usedefs.usemap, usedefs.defmap
    return _live_bits._NUMBAS(*args), _live_bits.compute_live_map(*args)


def test_every_package_function_gets_numbas_live_variables():
    functions = _package_functions()
    assert len(functions) > 100
    spread = 0
    for name, fn in sorted(functions.items()):
        blocks = compiler.run_frontend(fn).blocks
        for stage in (blocks, ssa._run_ssa(blocks)):
            theirs, ours = _both(stage)
            assert theirs == ours, name
            spread += any(ours[b] != set(analysis.compute_use_defs(stage).usemap[b])
                          for b in stage)
    assert spread > 50, spread


def _loops(x, n):
    acc = 0.0
    for k in range(n):
        if x > k:
            acc += x * k
        elif k % 3 == 0:
            continue
        else:
            acc -= 1.0
            if acc < -50.0:
                break
        x = 0.5 * x + 1.0
    return acc


def test_a_function_compiled_inside_uses_it_and_gives_the_same_results(monkeypatch):
    calls = []
    real = _live_bits.compute_live_map

    def recording(*args):
        calls.append(1)
        return real(*args)

    plain = njit(_loops)
    with fast_liveness():
        for module in _MODULES:
            assert module.compute_live_map is _live_bits.compute_live_map
        monkeypatch.setattr(analysis, "compute_live_map", recording)
        fast = njit(_loops)
        fast.compile("float64(float64, int64)")
        monkeypatch.undo()
    assert calls                        # numba's post-processing ran ours
    for x in np.linspace(-10, 60, 57):
        for n in (0, 1, 5, 40):
            assert plain(x, n) == fast(x, n)
