"""The numba functions our kernels' compilation replaces in every module that imports them
(``_numba_patch.FunctionPatch``: ``_live_bits``' liveness, ``_copy_propagate``'s copy
propagation): replaced inside their context and in ``compile_lock``, numba's own put
back outside, after an error and when contexts nest, and a module holding some other
function left alone."""

import pytest
from numba.core import analysis, ir_utils
from numba.parfors import parfor

from estimators import _copy_propagate, _generated, _live_bits

#: (the patch's module, its context, the function's name, the modules holding it)
CASES = [
    pytest.param(_live_bits, _live_bits.fast_liveness, "compute_live_map",
                 (analysis, ir_utils, parfor), id="liveness"),
    pytest.param(_copy_propagate, _copy_propagate.fast_copy_propagation, "copy_propagate",
                 (ir_utils, parfor), id="copy-propagation"),
]


def _all(modules, name, fn) -> bool:
    return all(getattr(m, name) is fn for m in modules)


@pytest.mark.parametrize("ours, context, name, modules", CASES)
def test_numba_is_restored_outside_and_contexts_nest(ours, context, name, modules):
    assert _all(modules, name, ours._NUMBAS)
    with context():
        with context():
            assert _all(modules, name, getattr(ours, name))
        assert _all(modules, name, getattr(ours, name))
    assert _all(modules, name, ours._NUMBAS)


@pytest.mark.parametrize("ours, context, name, modules", CASES)
def test_an_error_inside_restores_numba(ours, context, name, modules):
    with pytest.raises(RuntimeError):
        with context():
            raise RuntimeError("compile failed")
    assert _all(modules, name, ours._NUMBAS)


@pytest.mark.parametrize("ours, context, name, modules", CASES)
def test_a_module_holding_another_function_is_left_alone(ours, context, name, modules,
                                                         monkeypatch):
    def other(*args):
        raise AssertionError("not ours to replace")

    held, *rest = modules[::-1]
    monkeypatch.setattr(held, name, other)
    with context():
        assert _all(rest, name, getattr(ours, name))
        assert getattr(held, name) is other
    assert getattr(held, name) is other


@pytest.mark.parametrize("ours, context, name, modules", CASES)
def test_the_kernels_compile_inside_it(ours, context, name, modules):
    with _generated.compile_lock(f"test-{name}"):
        assert _all(modules, name, getattr(ours, name))
    with _generated.compile_context():
        assert _all(modules, name, getattr(ours, name))
    assert _all(modules, name, ours._NUMBAS)
