"""numba's inliner without its quadratic copy: the path tracer's kernel compiles in about a
minute and a half instead of ten.

numba inlines an ``inline="always"`` function by copying the callee's IR (twice per call
site, ``InlineWorker.inline_ir``) block by block, each block with a ``copy.deepcopy`` of
its own; every variable holds the function's ``Scope``, which holds every variable, so
each block's copy copies the whole scope again: O(blocks × variables) per call site. The
tracer's ``trace`` inlines BSDFs, emitters and the BVH traversal whose own inlined callees
make them large: numba 0.68 compiled it in 604 s (fresh caches, one process), and under
cProfile 481 s of its 636 went to the inlining pass, 455 s of them to these copies
(27.6 million ``deepcopy`` calls).

:func:`shared_scope_copies` makes the blocks of one copy share one memo, so the scope
and its variables are copied once per copy, as a ``deepcopy`` of the whole IR would: the
copied blocks share one scope, like the blocks they copy (numba's own copy gives each
block a scope of its own and then asserts they are equal). A copy starts when a block of
another scope comes, or a block already copied comes again (the same IR copied a second
time gets new objects, never the first copy's). The IR that results is the same, so
is the machine code: the renders of the ten ``tests/estimators/render_snapshot.py``
entries (every kind of reference scene) were bit-identical with it and without, and
the general ``trace`` compiled in 78 s instead of 604 s (fresh caches, one process).

It is active only inside the context (``_generated.compile_lock`` holds it around our
kernels' compilation), restores numba's module as it was, and is left out (numba's own
copy runs) where numba's module does not look as expected.
"""

from __future__ import annotations

import copy as _copy

from ._numba_patch import NestedPatch

try:
    from numba.core import inline_closurecall as _icc
    from numba.core import ir as _ir
except ImportError:             # another numba layout: leave numba alone
    _icc = _ir = None


class _SharedScopeCopy:
    """Stands in for the ``copy`` module inside ``numba.core.inline_closurecall``."""

    copy = staticmethod(_copy.copy)

    def __init__(self):
        self._scope = None
        self._memo: dict = {}

    def deepcopy(self, x, memo=None):
        if memo is not None or not isinstance(x, _ir.Block):
            return _copy.deepcopy(x, memo)
        if x.scope is not self._scope or id(x) in self._memo:
            self._scope, self._memo = x.scope, {}
        return _copy.deepcopy(x, self._memo)


def _applicable() -> bool:
    return (_icc is not None and getattr(_icc, "copy", None) is _copy
            and hasattr(_icc, "InlineWorker") and hasattr(_ir, "Block"))


_PATCH = NestedPatch(_icc, "copy", _SharedScopeCopy, _applicable)


def shared_scope_copies():
    """numba's inliner copies each callee's scope once per copy (not once per block)
    while inside; nests; a no-op where numba is not laid out as expected."""
    return _PATCH.held()
