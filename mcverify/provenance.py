"""Provenance stamped on every saved result (pytest-benchmark's saved-run habit)."""

from __future__ import annotations

import datetime as _dt
import os
import platform
import subprocess
from functools import lru_cache

from ._version import __version__


@lru_cache(maxsize=1)
def git_commit() -> str | None:
    """The commit of the checkout mcverify runs from, or None outside a git tree."""
    return commit_of(os.path.abspath(__file__))


def commit_of(path: str) -> str | None:
    """HEAD of the git tree that tracks the file ``path``, else None. An untracked file
    in a tree is not its commit's: mcverify installed into a virtual environment inside
    the user's repository (``.venv/lib/...``, ignored) recorded the user's commit as
    mcverify's until 7 December (an outside review)."""
    def git(*args):
        return subprocess.run(["git", *args], cwd=os.path.dirname(path), capture_output=True,
                              text=True, timeout=5, check=False)
    try:
        if git("ls-files", "--error-unmatch", "--", os.path.basename(path)).returncode:
            return None
        out = git("rev-parse", "HEAD")
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None


_CPUINFO_KEYS = {"model name": "model", "cpu family": "family", "model": "model_number"}


def cpuinfo_fields(lines) -> dict:
    """The first processor's model name, family and model from ``/proc/cpuinfo``'s
    lines (its block ends at the first blank line), under ``cpu()``'s keys."""
    out = {}
    for line in lines:
        if not line.strip():
            break
        key, _, value = (part.strip() for part in line.partition(":"))
        if key in _CPUINFO_KEYS:
            out[_CPUINFO_KEYS[key]] = value
    return out


@lru_cache(maxsize=1)
def cpu() -> dict:
    """The processor the numbers were measured on: its model name and, on Linux, its
    family and model numbers (``/proc/cpuinfo``), and the CPU that numba's LLVM compiles
    the kernels for (``NUMBA_CPU_NAME``, else the host's: ``znver1``, ``icelake-server``;
    it decides the vector width). The bench's ratios against Mitsuba depend on it: this
    project's 2-core machines, an Intel with AVX-512, an AMD Zen 4 and an AMD Zen 1 (both
    named "AMD EPYC", told apart by family 25 and 23), gave ratios up to 1.8x apart for
    the same code (``docs/PERFORMANCE.md``)."""
    info = {"model": platform.processor() or None, "family": None, "model_number": None}
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            info.update(cpuinfo_fields(f))
    except OSError:
        pass
    try:
        import llvmlite.binding as llvm
        info["llvm_cpu"] = os.environ.get("NUMBA_CPU_NAME") or llvm.get_host_cpu_name()
    except Exception:                                    # noqa: BLE001 (a label only)
        info["llvm_cpu"] = None
    return info


def describe_cpu() -> str:
    """``cpu()`` in a line: 'AMD EPYC (family 23, model 1; LLVM target znver1), 2 cores'."""
    c = cpu()
    fm = ", ".join(f"{k} {c[key]}" for k, key in (("family", "family"),
                                                  ("model", "model_number")) if c.get(key))
    detail = "; ".join(x for x in (fm, c.get("llvm_cpu") and f"LLVM target {c['llvm_cpu']}")
                       if x)
    return (f"{c.get('model') or platform.machine() or 'unknown CPU'}"
            + (f" ({detail})" if detail else "") + f", {os.cpu_count()} cores")


def provenance(**extra) -> dict:
    """Package version, git commit, machine (with its ``cpu()``), Python/numpy/scipy
    versions, UTC time, plus whatever the caller adds (seeds, mitsuba variant, suite)."""
    import numpy
    import scipy

    info = {
        "mcverify_version": __version__,
        "git_commit": git_commit(),
        "machine": {"node": platform.node(), "system": platform.system(),
                    "machine": platform.machine(), "cpu_count": os.cpu_count(),
                    "cpu": dict(cpu()), "python": platform.python_version()},
        "numpy": numpy.__version__,
        "scipy": scipy.__version__,
        "utc_time": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
    }
    info.update(extra)
    return info
