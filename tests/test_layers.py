"""The import rules of the house (docs/ARCHITECTURE.md), kept by a test:

- ``mcnumba`` (numba plumbing both packages use: threads, vector width) imports
  neither of them;
- ``estimators`` (the subject) never imports ``mcverify`` (its judge);
- ``mcverify``'s core (everything outside ``mcverify/gate/``) imports neither
  ``estimators`` nor Mitsuba nor the gate, at module level or inside functions; the one
  exception is the lazy re-export of ``render_check`` in ``mcverify.__getattr__``;
- within ``mcverify``, Mitsuba and Dr.Jit are imported by ``mcverify/gate/mitsuba.py``
  only; within ``estimators``, only by the image reader and the materials generator
  (Mitsuba's bitmap codec and spectral tables as data sources, never its rendering);
- the pytest plugin (``_mcverify_pytest``, loaded by every pytest run where mcverify is
  installed) imports only pytest and the standard library until a test uses mcverify.
"""

import ast
import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MITSUBA = ("mitsuba", "drjit")

#: (file, enclosing function, imported module): imports that are allowed by design.
ALLOWED = {
    ("mcverify/__init__.py", "__getattr__", "mcverify.gate.render_check"),
    ("estimators/pathtracer/textures.py", "import_mitsuba", "mitsuba"),
    ("estimators/pathtracer/textures.py", "import_mitsuba", "drjit"),
}


def _package(rel: str) -> str:
    parts = rel[:-3].split("/")
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts[:-1])


def imports(rel: str):
    """(module imported, enclosing function or None) for every import in a file,
    relative imports resolved against the file's package."""
    tree = ast.parse(open(os.path.join(ROOT, rel), encoding="utf-8").read(), rel)
    out = []

    def visit(node, func):
        for child in ast.iter_child_nodes(node):
            f = child.name if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)) \
                else func
            if isinstance(child, ast.Import):
                out.extend((a.name, func) for a in child.names)
            elif isinstance(child, ast.ImportFrom):
                if child.level:
                    base = _package(rel).split(".")
                    base = base[:len(base) - child.level + 1]
                    mod = ".".join(base + ([child.module] if child.module else []))
                else:
                    mod = child.module
                out.append((mod, func))
                out.extend((f"{mod}.{a.name}", func) for a in child.names)
            visit(child, f)

    visit(tree, None)
    return out


def files(package: str):
    for folder, _, names in os.walk(os.path.join(ROOT, package)):
        for n in sorted(names):
            if n.endswith(".py"):
                yield os.path.relpath(os.path.join(folder, n), ROOT).replace(os.sep, "/")


def _under(mod, prefix):
    return mod == prefix or mod.startswith(prefix + ".")


def _hits(rel, bad):
    return [(mod, func) for mod, func in imports(rel)
            if any(_under(mod, b) for b in bad)
            and not any(rel == r and func == f and _under(mod, m) for r, f, m in ALLOWED)]


def test_the_rule_finds_what_it_looks_for():
    # the checker itself: a relative import of the gate from the core is resolved and seen
    mods = dict(imports("mcverify/__init__.py"))
    assert "mcverify.gate.render_check" in mods and "mcverify._version" in mods
    assert any(m == "mitsuba" for m, _ in imports("mcverify/gate/mitsuba.py"))
    assert _hits("mcverify/gate/bench.py", ("estimators",))     # the gate may, and is seen


def test_the_subject_never_imports_its_judge():
    bad = {rel: _hits(rel, ("mcverify",)) for rel in files("estimators")}
    assert not {k: v for k, v in bad.items() if v}


def test_the_core_imports_neither_subject_nor_mitsuba_nor_gate():
    core = [rel for rel in files("mcverify")
            if not rel.startswith("mcverify/gate/") and rel != "mcverify/__main__.py"]
    assert "mcverify/checks/sampler.py" in core and "mcverify/result.py" in core
    bad = {rel: _hits(rel, ("estimators", "mcverify.gate") + MITSUBA) for rel in core}
    assert not {k: v for k, v in bad.items() if v}


def test_mitsuba_is_imported_in_one_module_of_mcverify():
    bad = {rel: _hits(rel, MITSUBA) for rel in files("mcverify")
           if rel != "mcverify/gate/mitsuba.py"}
    assert not {k: v for k, v in bad.items() if v}
    assert not {rel: _hits(rel, MITSUBA) for rel in files("estimators")
                if _hits(rel, MITSUBA)}


def test_the_pytest_plugin_imports_only_pytest_until_a_test_uses_mcverify():
    """pytest loads the plugin (``_mcverify_pytest``, a top-level module) in every run of
    an environment where mcverify is installed: at module level it imports the standard
    library and pytest, and inside functions the judge's core only (as
    ``mcverify.pytest_plugin`` it imported the package, numba and scipy in every run)."""
    found = imports("_mcverify_pytest.py")
    top = {mod for mod, func in found if func is None}
    assert top <= {"__future__", "__future__.annotations", "os", "sys", "pytest"}, top
    lazy = {mod for mod, func in found if func is not None}
    assert lazy and all(_under(m, "mcverify") for m in lazy), lazy
    assert not [m for m in lazy if _under(m, "mcverify.gate")], lazy


@pytest.mark.parametrize("code", [
    "import mcverify",
    "import mcverify as mv, numpy as np; mv.check_sampler(lambda u: u, lambda x: "
    "np.ones(len(x)), 'square', n_samples=20000)",
])
def test_importing_the_core_loads_neither(code):
    assert _loaded_after(code, "m.split('.')[0] in ('estimators', 'mitsuba', 'drjit') or "
                               "m.startswith('mcverify.gate')") == "[]"


def _loaded_after(code: str, which: str) -> str:
    """The sorted names of the modules ``m`` in ``sys.modules`` for which ``which``
    holds, after running ``code`` in a fresh interpreter."""
    probe = code + f"\nimport sys; print(sorted(m for m in sys.modules if {which}))"
    r = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                       cwd=ROOT, timeout=300)
    assert r.returncode == 0, r.stderr
    return r.stdout.strip().splitlines()[-1]


@pytest.mark.parametrize("code, loaded", [
    ("import mcverify", "[]"),
    ("import sys; sys.argv = ['mcverify', '--help']\n"
     "from mcverify.gate.cli import main\ntry: main()\nexcept SystemExit: pass", "[]"),
    ("import mcverify; mcverify.stats.ks_uniform([0.1, 0.5, 0.9])",
     "['scipy.optimize', 'scipy.stats']"),
    ("import estimators.mc, estimators.warps, estimators.distributions", "[]"),
    ("import estimators.mc; estimators.mc.rqmc(lambda x: x, 0.0, 1.0, 8, replicates=2)",
     "['scipy.optimize', 'scipy.stats']"),
    ("from mcverify.gate.suites import build_suite; build_suite('default')", "[]"),
    ("from mcverify.gate.suites import build_suite\n"
     "[c for c in build_suite('default') if c.name == 'scipy:norm'][0].run(0)",
     "['scipy.optimize', 'scipy.stats']"),
])
def test_scipy_stats_and_optimize_load_on_first_use(code, loaded):
    """``import mcverify``, ``mcverify --help``, the subjects' modules and building the
    default suite (what ``mcverify list`` and ``plan`` do) do not import scipy.stats or
    scipy.optimize (about 2.5 s here, mcverify._lazy); a statistic, Sobol points or a
    scipy subject's check does."""
    got = _loaded_after(code, "m in ('scipy.stats', 'scipy.optimize')")
    assert got == loaded, got


def test_render_check_is_re_exported_lazily():
    import mcverify
    from mcverify.gate.render_check import render_check

    assert mcverify.render_check is render_check
    with pytest.raises(AttributeError):
        mcverify.no_such_thing   # noqa: B018


def test_the_shared_numba_plumbing_imports_neither_subject_nor_judge():
    """``mcnumba`` (threads, vector width) serves both packages: it may import neither,
    nor Mitsuba, and both packages take their vector width from it."""
    shared = list(files("mcnumba"))
    assert "mcnumba/threads.py" in shared and "mcnumba/vector_width.py" in shared
    bad = {rel: _hits(rel, ("estimators", "mcverify") + MITSUBA) for rel in shared}
    assert not {k: v for k, v in bad.items() if v}
    for package in ("estimators", "mcverify"):
        assert ("mcnumba.vector_width.prefer_wide_vectors", None) in imports(
            f"{package}/__init__.py")


@pytest.mark.parametrize("first", ["mcverify", "estimators"])
@pytest.mark.parametrize("user_set", [False, True])
def test_whichever_package_comes_first_sets_the_vector_width(first, user_set):
    """Imported first in a fresh process, either package gives numba's code generator
    the host's features with 512-bit vectors preferred (on an AVX-512 host; elsewhere
    LLVM's own choice); a ``NUMBA_CPU_FEATURES`` the user set is kept."""
    from numba.core.codegen import get_host_cpu_features

    host = get_host_cpu_features()
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CPU_FEATURES",
                                                             "NUMBA_CPU_NAME")}
    if user_set:
        env["NUMBA_CPU_FEATURES"] = host
    probe = (f"import {first}, numba\n"
             "from numba.core import registry\n"
             "print(registry.cpu_target.target_context.codegen()._tm_features)\n")
    r = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                       cwd=ROOT, env=env, timeout=300)
    assert r.returncode == 0, r.stderr
    wide = "+avx512f" in host.split(",") and not user_set
    assert r.stdout.strip() == (host + ",-prefer-256-bit" if wide else host)


@pytest.mark.parametrize("first", ["mcverify", "estimators"])
def test_the_vector_width_keeps_numba_settings_made_in_code(first):
    """numba's settings made in code before the import (its documented
    ``numba.config.THREADING_LAYER = ...``) are kept, through the import and the next
    compilation: the import reloaded numba's whole config from the environment, so they
    went back to their defaults ('default', None, numba's cache folder)."""
    probe = ("import numba\n"
             "numba.config.THREADING_LAYER = 'workqueue'\n"
             "numba.config.BOUNDSCHECK = 1\n"
             f"import {first}\n"
             "numba.njit(lambda x: x + 1)(1)\n"
             "from numba.core import registry\n"
             "print(numba.config.THREADING_LAYER, numba.config.BOUNDSCHECK)\n"
             "print(registry.cpu_target.target_context.codegen()._tm_features)\n")
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CPU_FEATURES",
                                                             "NUMBA_CPU_NAME")}
    r = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                       cwd=ROOT, env=env, timeout=300)
    assert r.returncode == 0, r.stderr
    settings, features = r.stdout.splitlines()
    assert settings == "workqueue 1"
    from numba.core.codegen import get_host_cpu_features

    host = get_host_cpu_features()
    wide = "+avx512f" in host.split(",")
    assert features == (host + ",-prefer-256-bit" if wide else host)
