"""numba's liveness analysis on bit sets: the same live variables per block, without
copying whole sets of names along every edge.

``numba.core.analysis.compute_live_map`` first finds, per block, every variable defined
or used in a block that reaches it (``def_reach``), then pushes uses backwards. Both are
fix points over Python sets of names, and in a large function the reaching set of a
block is nearly every variable of the function, so each edge costs a set union of that
size, in every pass, in every call. numba runs the analysis again after each of its
rewrites (``PostProcessor.run``, dead-code removal, parfor parameters): compiling the
path tracer's general kernel called it about 2200 times, and under cProfile spent 61 s
of 493 in ``def_reach`` alone (a 2-core AMD Zen 1).

Here each set is a Python ``int`` with one bit per variable, and only variables that are
used in some block before that block defines them get a bit: ``def_reach`` matters only
where it is intersected with live variables, and every live variable is such a use. A
union is then an ``or`` of a few machine words. The equations, their node order and
their edges are numba's (``cfg.topo_order``, ``cfg.successors``, ``cfg.predecessors``),
and both are least fix points, so the result is numba's, block for block:
``tests/estimators/test_live_bits.py`` holds it to numba's on random control-flow graphs
and on every function of the package.

Active only inside :func:`fast_liveness` (``_generated.compile_lock`` holds it around our
kernels' compilation); numba's function is put back after. numba imports the function by
name into ``ir_utils`` and ``parfors.parfor`` as well, so all three names are replaced.
"""

from __future__ import annotations

from ._numba_patch import FunctionPatch

try:
    from numba.core import analysis as _analysis
    from numba.core import ir_utils as _ir_utils
    from numba.parfors import parfor as _parfor
except ImportError:             # another numba layout: leave numba alone
    _analysis = _ir_utils = _parfor = None

_MODULES = (_analysis, _ir_utils, _parfor)
_NUMBAS = getattr(_analysis, "compute_live_map", None)


def compute_live_map(cfg, blocks, var_use_map, var_def_map):
    """``numba.core.analysis.compute_live_map``'s result (the variables live at the
    entry of each block, keyed like ``blocks``), computed on bit sets."""
    topo_order = cfg.topo_order()
    index, names = {}, []

    def bits(of, new_bits: bool) -> int:
        """The set ``of`` as bits; with ``new_bits`` its names not yet numbered get the
        next bits, else they are left out (they cannot be live)."""
        out = 0
        for name in of:
            i = index.get(name)
            if i is None:
                if not new_bits:
                    continue
                i = index[name] = len(names)
                names.append(name)
            out |= 1 << i
        return out

    use = {label: bits(var_use_map[label], True) for label in blocks.keys()}
    defs = {label: bits(var_def_map[label], False) for label in blocks.keys()}

    # numba's def_reach: what is defined or used in any block reaching this one
    reach = {}
    changed = True
    while changed:
        changed = False
        for label in topo_order:
            here = reach.get(label, 0) | defs[label] | use[label]
            reach[label] = here
            for out, _ in cfg.successors(label):
                before = reach.get(out, 0)
                after = before | here
                if after != before:
                    reach[out] = after
                    changed = True

    # numba's liveness: uses pushed back to predecessors that a definition reaches
    live = dict(use)
    changed = True
    while changed:
        changed = False
        for label in reversed(topo_order):
            here = live[label]
            for pred, _ in cfg.predecessors(label):
                before = live[pred]
                after = before | (here & reach.get(pred, 0) & ~defs[pred])
                if after != before:
                    live[pred] = after
                    changed = True

    live_map = {}
    for label in blocks.keys():
        found = set(var_use_map[label])
        extra = live[label] & ~use[label]
        while extra:
            top = extra.bit_length() - 1
            found.add(names[top])
            extra ^= 1 << top
        live_map[label] = found
    return live_map


_PATCH = FunctionPatch(_MODULES, "compute_live_map", compute_live_map, _NUMBAS)


def fast_liveness():
    """numba's liveness analysis runs on bit sets (:func:`compute_live_map`) while
    inside; nests; a no-op where numba is not laid out as expected."""
    return _PATCH.held()
