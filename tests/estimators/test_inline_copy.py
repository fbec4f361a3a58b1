"""``estimators._inline_copy``: numba's inliner copies a callee's scope once per copy
inside ``shared_scope_copies`` (same compiled functions, far fewer copies), and numba is
left as it was outside. The tracer's kernels are compiled inside it (``compile_lock``),
so every render test checks its output; their bit-identity with and without it was
checked with ``tests/estimators/render_snapshot.py`` (every reference scene)."""

import copy

import numpy as np
from numba import njit
from numba.core import inline_closurecall, ir

from estimators import _inline_copy
from estimators._inline_copy import shared_scope_copies


def _branchy_source(name: str) -> str:
    """A callee of many blocks and variables (what makes numba's block-by-block copy
    quadratic), inlined at three call sites."""
    body = "\n".join(f"    if x > {k}.5:\n        a{k} = x * {k + 1}.0 + y\n    else:\n"
                     f"        a{k} = y - {k}.0\n    acc = acc + a{k}" for k in range(25))
    return (f"def callee(x, y):\n    acc = 0.0\n{body}\n    return acc\n\n"
            f"def {name}(x, y):\n    return callee(x, y) + callee(y, x) + callee(x + 1.0, y)\n")


def _compile(name: str):
    space = {}
    exec(_branchy_source(name), space)
    callee = njit(inline="always")(space["callee"])
    space["callee"] = callee
    caller = njit(space[name])
    caller.compile("float64(float64, float64)")
    return caller, space[name]


def _var_copies(monkeypatch, inside: bool, name: str) -> tuple[int, object]:
    count = [0]
    real = ir.Var.__deepcopy__

    def counting(self, memo):
        count[0] += 1
        return real(self, memo)

    monkeypatch.setattr(ir.Var, "__deepcopy__", counting)
    if inside:
        with shared_scope_copies():
            fn, py = _compile(name)
    else:
        fn, py = _compile(name)
    monkeypatch.setattr(ir.Var, "__deepcopy__", real)
    return count[0], (fn, py)


def test_inlining_copies_far_fewer_variables_and_compiles_the_same_function(monkeypatch):
    plain, (f_plain, py) = _var_copies(monkeypatch, False, "caller_plain")
    shared, (f_shared, _) = _var_copies(monkeypatch, True, "caller_shared")
    # numba copies each of the callee's ~75 blocks with the whole scope: at least 10x
    assert plain > 10 * shared > 0, (plain, shared)
    rng = np.random.default_rng(3)
    for x, y in rng.uniform(-5, 30, (200, 2)):
        assert f_shared(x, y) == f_plain(x, y) == py(x, y)


def test_numba_is_left_as_it_was_outside_and_the_context_nests():
    assert inline_closurecall.copy is copy
    with shared_scope_copies():
        inside = inline_closurecall.copy
        assert inside is not copy
        with shared_scope_copies():
            assert inline_closurecall.copy is inside
        assert inline_closurecall.copy is inside
    assert inline_closurecall.copy is copy
    try:
        with shared_scope_copies():
            raise RuntimeError("a failed compile")
    except RuntimeError:
        pass
    assert inline_closurecall.copy is copy


def test_the_same_block_copied_twice_gives_new_objects_and_blocks_share_one_scope():
    scope = ir.Scope(None, ir.Loc("f", 1))
    blocks = []
    for k in range(3):
        b = ir.Block(scope, ir.Loc("f", k))
        v = scope.redefine(f"v{k}", ir.Loc("f", k))
        b.append(ir.Assign(ir.Const(k, ir.Loc("f", k)), v, ir.Loc("f", k)))
        blocks.append(b)
    shim = _inline_copy._SharedScopeCopy()
    first = [shim.deepcopy(b) for b in blocks]
    second = [shim.deepcopy(b) for b in blocks]
    assert len({id(c.scope) for c in first}) == 1          # one scope copy per copy
    assert first[0].scope is not scope
    assert all(a is not b for a, b in zip(first, second))   # a second copy: new objects
    assert first[0].scope is not second[0].scope
    assert first[2].body[0].target.name == "v2"
    assert first[2].body[0].target is not blocks[2].body[0].target


def test_a_layout_numba_does_not_have_is_left_alone(monkeypatch):
    monkeypatch.setattr(inline_closurecall, "copy", object())
    sentinel = inline_closurecall.copy
    with shared_scope_copies():
        assert inline_closurecall.copy is sentinel
    assert inline_closurecall.copy is sentinel
