"""numba's SSA reconstruction, visiting only the blocks that name each variable: the same
IR, without the pass over the whole function per variable.

numba's ``ssa._run_ssa`` fixes one SSA-violating variable (assigned more than once, or
used where its one assignment does not dominate) at a time, and for each it rewrites
every block of the function twice (``_fresh_vars`` renames the variable's assignments,
``_fix_ssa_vars`` points each use at the reaching definition and inserts phi nodes):
O(violators × statements). The path tracer's ``_trace_samples``, with the whole path
inlined, has thousands of each; under cProfile its general kernel's compilation spent
131 s of 493 there (13.8 million block passes, on a 2-core AMD Zen 1; the function
then compiled twice, see ``_kernel._group_end``).

A block in which no statement names the variable comes out of both rewrites with the
same statements (the handlers return each statement unchanged when the variable is not
among its variables), so :func:`_run_ssa` rewrites only the blocks that name it (one
scan of the function beforehand lists them), in the function's block order, with the
same handlers, states, scope and phi insertion: the renamed variables, the phi nodes and
their order are numba's own. ``tests/estimators/test_ssa_blocks.py`` holds the result to
numba's IR, dump for dump, on every numba function of the package and on an inlined
caller; the general kernel's renders were bit-identical with it and without.

Active only inside :func:`fast_ssa` (``_generated.compile_lock`` holds it around our
kernels' compilation); it restores numba's function after, and is left out where numba's
``ssa`` module does not have the pieces it uses.
"""

from __future__ import annotations

from collections import defaultdict

from ._numba_patch import NestedPatch

try:
    from numba.core import ir as _ir
    from numba.core import ssa as _ssa
except ImportError:             # another numba layout: leave numba alone
    _ir = _ssa = None


_NEEDED = ("_run_ssa", "_iterated_domfronts", "_find_defs_violators", "_CacheListVars",
           "_run_block_rewrite", "_FreshVarHandler", "_FixSSAVars", "_compute_phi_locations",
           "_get_scope", "compute_cfg_from_blocks")
_NUMBAS = getattr(_ssa, "_run_ssa", None)


def _run_ssa(blocks):
    """``numba.core.ssa._run_ssa``'s result, rewriting per variable only the blocks that
    name it."""
    if not blocks:
        return {}
    cfg = _ssa.compute_cfg_from_blocks(blocks)
    df_plus = _ssa._iterated_domfronts(cfg)
    violators = _ssa._find_defs_violators(blocks, cfg)
    cache_list_vars = _ssa._CacheListVars()
    scope = _ssa._get_scope(blocks)
    naming = defaultdict(list)          # variable -> labels of blocks naming it, in order
    for label, blk in blocks.items():
        names = set()
        for stmt in blk.body:
            names.update(v.name for v in stmt.list_vars())
        for name in names:
            naming[name].append(label)
    for varname in violators:
        labels = naming.get(varname, ())
        part = {label: blocks[label] for label in labels}
        # numba's _fresh_vars on the blocks that name the variable
        defmap = defaultdict(list)
        part = _ssa._run_block_rewrite(part, dict(scope=scope, varname=varname,
                                                  defmap=defmap), _ssa._FreshVarHandler())
        # numba's _fix_ssa_vars on the same blocks
        phimap = defaultdict(list)
        states = dict(scope=scope, varname=varname, defmap=defmap, phimap=phimap, cfg=cfg,
                      phi_locations=_ssa._compute_phi_locations(df_plus, defmap))
        part = _ssa._run_block_rewrite(part, states, _ssa._FixSSAVars(cache_list_vars))
        blocks = {label: part.get(label, blk) for label, blk in blocks.items()}
        for label, philist in phimap.items():
            blk = blocks[label]
            if label not in part:       # a block numba's rewrite would have copied
                blk = _ir.Block(scope=blk.scope, loc=blk.loc)
                blk.body = list(blocks[label].body)
                blocks[label] = blk
            blk.body = philist + blk.body
    if _ssa.compute_cfg_from_blocks(blocks) != cfg:
        raise _ssa.errors.CompilerError("CFG mutated in SSA pass")
    return blocks


def _applicable() -> bool:
    return _ssa is not None and all(hasattr(_ssa, n) for n in _NEEDED) \
        and hasattr(_ssa, "errors") and hasattr(_ir, "Block")


_PATCH = NestedPatch(_ssa, "_run_ssa", lambda: _run_ssa, _applicable)


def fast_ssa():
    """numba's SSA reconstruction rewrites only the blocks naming each variable while
    inside; nests; a no-op where numba is not laid out as expected."""
    return _PATCH.held()
