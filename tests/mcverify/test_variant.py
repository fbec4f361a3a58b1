"""The Mitsuba variant choice (``mcverify.gate.mitsuba.choose_variant``): a libLLVM that
Dr.Jit cannot use falls back to ``scalar_rgb`` with a notice naming it; the verdict on a
library is passed to child processes in ``MCVERIFY_LLVM_PROBED``, which then do not probe
that library again, and probe any other."""

import os
import subprocess
import sys

import pytest

from mcverify.gate import mitsuba as mvm


@pytest.fixture
def fresh(monkeypatch):
    """choose_variant as in a new process: nothing forced, nothing inherited; the
    environment it writes is put back after the test."""
    for name in ("MCVERIFY_MITSUBA_VARIANT", mvm._PROBED, "DRJIT_LIBLLVM_PATH"):
        monkeypatch.delenv(name, raising=False)
    mvm.choose_variant.cache_clear()
    yield monkeypatch
    mvm.choose_variant.cache_clear()


def test_a_library_drjit_cannot_use_falls_back_to_scalar_naming_it(fresh, tmp_path):
    fake = tmp_path / "libLLVM.so.19"
    fake.write_bytes(b"not a shared library")
    fresh.setenv("DRJIT_LIBLLVM_PATH", str(fake))
    choice = mvm.choose_variant()
    assert choice.variant == "scalar_rgb"
    assert str(fake) in choice.notice and "llvm_ad_rgb does not work" in choice.notice
    assert os.environ[mvm._PROBED] == f"bad:{fake}"


def test_an_inherited_verdict_on_the_same_library_is_not_probed_again(fresh, tmp_path):
    lib = str(tmp_path / "libLLVM.so.19")
    fresh.setenv("DRJIT_LIBLLVM_PATH", lib)
    probed = []
    fresh.setattr(mvm, "_probe", lambda path: probed.append(path) or True)
    fresh.setenv(mvm._PROBED, f"bad:{lib}")
    assert mvm.choose_variant().variant == "scalar_rgb" and probed == []
    mvm.choose_variant.cache_clear()
    fresh.setenv(mvm._PROBED, f"ok:{lib}")
    assert mvm.choose_variant() == mvm.VariantChoice("llvm_ad_rgb", None) and probed == []
    assert os.environ["DRJIT_LIBLLVM_PATH"] == lib
    # a verdict on another library is no verdict on this one
    mvm.choose_variant.cache_clear()
    fresh.setenv(mvm._PROBED, f"ok:{lib}.other")
    assert mvm.choose_variant().variant == "llvm_ad_rgb" and probed == [lib]
    assert os.environ[mvm._PROBED] == f"ok:{lib}"


def test_a_forced_variant_is_not_probed(fresh):
    fresh.setenv("MCVERIFY_MITSUBA_VARIANT", "scalar_rgb")
    fresh.setattr(mvm, "_probe", lambda path: pytest.fail("probed"))
    assert mvm.choose_variant() == mvm.VariantChoice("scalar_rgb", None)


@pytest.mark.parametrize("variant, match", [
    ("llvm_ad_mono", "the Mitsuba adapters read RGB"),
    ("scalar_spectral", "the Mitsuba adapters read RGB"),
    ("llvm_rgb", "not a variant of this Mitsuba")])
def test_a_forced_variant_the_adapters_cannot_use_is_refused_naming_it(fresh, variant, match):
    """A mono or spectral variant failed every Mitsuba check with numpy's "cannot
    reshape" (the adapters read RGB), a misspelt one with Mitsuba's ImportError."""
    fresh.setenv("MCVERIFY_MITSUBA_VARIANT", variant)
    with pytest.raises(mvm.EnvironmentProblem, match=f"MCVERIFY_MITSUBA_VARIANT='{variant}': "
                       f"{match}.*scalar_rgb"):
        mvm.choose_variant()


def test_a_forced_jit_variant_that_cannot_compute_is_refused_naming_it(fresh, tmp_path):
    """Forcing llvm_ad_rgb without a usable libLLVM (or cuda_ad_rgb without a GPU) failed
    every Mitsuba check with Dr.Jit's ImportError, exit 1 as if the plugins were wrong;
    now the variant is probed in a subprocess and refused (exit 2), the verdict passed
    on to child processes."""
    fake = tmp_path / "libLLVM.so.19"
    fake.write_bytes(b"not a shared library")
    fresh.setenv("DRJIT_LIBLLVM_PATH", str(fake))
    fresh.setenv("MCVERIFY_MITSUBA_VARIANT", "llvm_ad_rgb")
    with pytest.raises(mvm.EnvironmentProblem, match="MCVERIFY_MITSUBA_VARIANT='llvm_ad_rgb': "
                       "Mitsuba cannot compute in it here .*LLVM.*use scalar_rgb"):
        mvm.choose_variant()
    assert os.environ[mvm._PROBED] == f"bad:llvm_ad_rgb@{fake}"
    mvm.choose_variant.cache_clear()
    fresh.setattr(mvm, "_probe_variant", lambda *a: pytest.fail("probed again"))
    with pytest.raises(mvm.EnvironmentProblem, match="llvm_ad_rgb"):
        mvm.choose_variant()
    mvm.choose_variant.cache_clear()
    fresh.setenv(mvm._PROBED, f"ok:llvm_ad_rgb@{fake}")
    assert mvm.choose_variant() == mvm.VariantChoice("llvm_ad_rgb", None)


@pytest.mark.skipif(mvm._find_libllvm() is None, reason="needs a libLLVM >= 16 (libllvm19)")
def test_a_child_process_inherits_the_verdict(fresh):
    """The parent probes once; a child started after it finds the verdict and does not
    start a probe of its own (its subprocess.run would say so)."""
    assert mvm.choose_variant().variant == "llvm_ad_rgb"
    script = ("import subprocess\n"
              "def refuse(*a, **k): raise AssertionError('probed again')\n"
              "subprocess.run = refuse\n"
              "from mcverify.gate import mitsuba as mvm\n"
              "print(mvm.choose_variant().variant)\n")
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == "llvm_ad_rgb", r.stderr


def test_a_forced_llvm_variant_is_refused_with_llvms_own_reason(fresh, tmp_path):
    """With LLVM 15 Dr.Jit aborts after LLVM's "Cannot select ... fminimum" and a dump of
    the DAG whose last line is "In function: drjit_<hash>": the refusal quoted that line,
    which says nothing about what is wrong; it now quotes LLVM's error, and says how to
    get the variant back (DRJIT_LIBLLVM_PATH)."""
    lib = str(tmp_path / "libLLVM-15.so")
    stderr = ("LLVM ERROR: Cannot select: 0x55f3: f32 = fminimum 0x55f4, 0x55f5\n"
              "  0x55f4: f32,ch = load<(load (s32))> 0x55f6, undef:i64\n"
              "In function: drjit_fa746af9fa891f13ca9aa6575a4f1972\n")
    fresh.setattr(mvm.subprocess, "run", lambda *a, **k: subprocess.CompletedProcess(
        a[0], -6, stdout="", stderr=stderr))
    fresh.setenv("DRJIT_LIBLLVM_PATH", lib)
    fresh.setenv("MCVERIFY_MITSUBA_VARIANT", "llvm_ad_rgb")
    with pytest.raises(mvm.EnvironmentProblem) as e:
        mvm.choose_variant()
    assert "Cannot select" in str(e.value) and "fminimum" in str(e.value)
    assert "In function" not in str(e.value)
    assert f"DRJIT_LIBLLVM_PATH (now {lib})" in str(e.value)
    # an ImportError's traceback: its last line, the error
    assert mvm._probe_variant("llvm_ad_rgb", lib) == "LLVM ERROR: Cannot select: 0x55f3: " \
        "f32 = fminimum 0x55f4, 0x55f5"


def test_the_fallback_notice_says_how_to_get_llvm_back(fresh, tmp_path):
    """A DRJIT_LIBLLVM_PATH that Dr.Jit cannot use (LLVM 15, a missing file) fell back to
    scalar_rgb with a notice naming the library only, not what to do about it."""
    fresh.setenv("DRJIT_LIBLLVM_PATH", str(tmp_path / "missing" / "libLLVM.so.19"))
    fresh.setattr(mvm, "_probe", lambda path: False)
    choice = mvm.choose_variant()
    assert choice.variant == "scalar_rgb"
    assert "point DRJIT_LIBLLVM_PATH at a working libLLVM >= 16" in choice.notice


def test_mitsuba_missing_says_how_to_install_it(fresh):
    """Mitsuba not importable said only "run `make setup`", a target of this repository's
    Makefile, which a user who installed mcverify with pip does not have."""
    fresh.setitem(sys.modules, "mitsuba", None)
    with pytest.raises(mvm.EnvironmentProblem, match="mitsuba is not importable .*"
                       "pip install mitsuba"):
        mvm.choose_variant()
