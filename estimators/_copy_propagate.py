"""numba's copy propagation analysis without deep copies: the same copies into and out of
each block, computed without copying every set of copies in every sweep.

``numba.core.ir_utils.copy_propagate`` (run by ``ir_utils.simplify`` and, for every
parfor, by the parfor passes) iterates the data-flow equations in_b = ∩ out_p over the
predecessors p, out_b = gen_b ∪ (in_b − kill_b) to a fix point, and tests for it by a
``copy.deepcopy`` of every block's set of (lhs, rhs) name pairs after each sweep. Its
initial kill sets test every copy of the function against every block, rebuilding the
block's set of assigned names for each copy. Under cProfile, compiling one warp's
float32 front-end loop (``invert_uniform_cone``) took 28 s, of which copy propagation
15 s and ``deepcopy`` 15 s (a 2-core AMD Zen 1).

Here a sweep notes whether any block's out set changed (a block is updated once a sweep,
so that is whether the state after the sweep differs from the state before: numba's
test), and a block's kill set is the union, over the names it kills or assigns, of an
index of the copies naming each name (a copy in the block's own gen set is kept out of
the assigned part, as numba's condition says). The equations, the sweep order
(``blocks``' keys, the entry left out) and the initial state are numba's, so each sweep
gives numba's sets and the result is numba's, block for block:
``tests/estimators/test_copy_propagate.py`` holds it to numba's on every function of the
package and on every call the parfor passes make while compiling a parallel loop.

Active only inside :func:`fast_copy_propagation` (``_generated.compile_lock`` holds it
around our kernels' compilation); numba's function is put back after. ``parfors.parfor``
imports the function by name, so both names are replaced.
"""

from __future__ import annotations

from ._numba_patch import FunctionPatch

try:
    from numba.core import ir_utils as _ir_utils
    from numba.parfors import parfor as _parfor
except ImportError:             # another numba layout: leave numba alone
    _ir_utils = _parfor = None

_MODULES = (_ir_utils, _parfor)
_NUMBAS = getattr(_ir_utils, "copy_propagate", None)
_NONE: frozenset = frozenset()


def kill_sets(gen_copies, extra_kill) -> dict:
    """numba's initial kill set of each block (``init_copy_propagate_data``): a copy
    (lhs, rhs) of the function is killed in a block that kills lhs or rhs outright
    (``extra_kill``), or that assigns lhs or rhs and does not itself make that copy."""
    by_name: dict = {}
    for gen in gen_copies.values():
        for pair in gen:
            for name in pair:
                by_name.setdefault(name, set()).add(pair)
    kill = {}
    for label, gen in gen_copies.items():
        killed = set()
        for name in extra_kill[label]:
            killed |= by_name.get(name, _NONE)
        moved = set()
        for lhs, _ in gen:
            moved |= by_name.get(lhs, _NONE)
        kill[label] = killed | (moved - gen)
    return kill


def copy_propagate(blocks, typemap):
    """``numba.core.ir_utils.copy_propagate``'s result: (in_copies, out_copies), for
    each label of ``blocks`` the set of (lhs, rhs) copies valid at its entry and exit."""
    cfg = _ir_utils.compute_cfg_from_blocks(blocks)
    entry = cfg.entry_point()
    gen_copies, extra_kill = _ir_utils.get_block_copies(blocks, typemap)
    all_copies = set()
    for gen in gen_copies.values():
        all_copies |= gen
    kill_copies = kill_sets(gen_copies, extra_kill)
    in_copies = {label: all_copies.copy() for label in blocks.keys()}
    in_copies[entry] = set()
    out_copies = {label: gen_copies[label] | (in_copies[label] - kill_copies[label])
                  for label in blocks.keys()}
    out_copies[entry] = gen_copies[entry]
    changed = True
    while changed:
        changed = False
        for label in blocks.keys():
            if label == entry:
                continue
            predecs = [p for p, _ in cfg.predecessors(label)]
            here = out_copies[predecs[0]].copy()
            for p in predecs:
                here &= out_copies[p]
            in_copies[label] = here
            out = gen_copies[label] | (here - kill_copies[label])
            if out != out_copies[label]:
                changed = True
            out_copies[label] = out
    return in_copies, out_copies


_PATCH = FunctionPatch(_MODULES, "copy_propagate", copy_propagate, _NUMBAS)


def fast_copy_propagation():
    """numba's copy propagation analysis runs without deep copies
    (:func:`copy_propagate`) while inside; nests; a no-op where numba is not laid out as
    expected."""
    return _PATCH.held()
