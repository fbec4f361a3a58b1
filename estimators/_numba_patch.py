"""One attribute of a numba module replaced while a context is held: how
``_inline_copy``, ``_ssa_blocks``, ``_live_bits`` and ``_copy_propagate`` change numba only
around our kernels' compilation.
"""

from __future__ import annotations

import contextlib
import threading


class NestedPatch:
    """``module.attr`` set to ``make()`` while any thread is inside :meth:`held`: the
    first entry sets it, the last exit puts back what was there before. Where
    ``applicable()`` is false at the first entry (numba not laid out as expected),
    entering changes nothing."""

    def __init__(self, module, attr: str, make, applicable):
        self._module, self._attr = module, attr
        self._make, self._applicable = make, applicable
        self._lock = threading.RLock()
        self._depth = 0
        self._before = None

    @contextlib.contextmanager
    def held(self):
        with self._lock:
            active = self._depth > 0 or self._applicable()
            if active:
                if self._depth == 0:
                    self._before = getattr(self._module, self._attr)
                    setattr(self._module, self._attr, self._make())
                self._depth += 1
        try:
            yield
        finally:
            if active:
                with self._lock:
                    self._depth -= 1
                    if self._depth == 0:
                        setattr(self._module, self._attr, self._before)


class FunctionPatch:
    """numba's function ``numbas``, imported by name ``attr`` into several ``modules``,
    replaced by ``ours`` in each of them that holds numba's own while any thread is
    inside :meth:`held` (one :class:`NestedPatch` a module). With ``numbas`` None (numba
    not laid out as expected) entering changes nothing."""

    def __init__(self, modules, attr: str, ours, numbas):
        def patch(module):
            return NestedPatch(module, attr, lambda: ours,
                               lambda: getattr(module, attr, None) is numbas)

        self._patches = [patch(m) for m in modules] if numbas is not None else []

    @contextlib.contextmanager
    def held(self):
        with contextlib.ExitStack() as stack:
            for patch in self._patches:
                stack.enter_context(patch.held())
            yield
