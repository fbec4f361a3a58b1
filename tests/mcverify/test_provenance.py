"""Provenance names the processor: the bench's ratios against Mitsuba depend on it."""

import os
import sys

import pytest

from mcverify import provenance as prov

_AMD = """processor\t: 0
vendor_id\t: AuthenticAMD
cpu family\t: 23
model\t\t: 1
model name\t: AMD EPYC
stepping\t: 2

processor\t: 1
vendor_id\t: AuthenticAMD
cpu family\t: 25
model\t\t: 17
model name\t: another one
"""

_INTEL = """processor : 0
cpu family : 6
model : 106
model name : Intel(R) Xeon(R) Platinum 8375C CPU @ 2.90GHz
flags : fpu avx512f model
"""


def test_cpuinfo_fields_reads_the_first_processors_block():
    assert prov.cpuinfo_fields(_AMD.splitlines()) == {
        "family": "23", "model_number": "1", "model": "AMD EPYC"}
    assert prov.cpuinfo_fields(_INTEL.splitlines()) == {
        "family": "6", "model_number": "106",
        "model": "Intel(R) Xeon(R) Platinum 8375C CPU @ 2.90GHz"}
    assert prov.cpuinfo_fields([]) == {}


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/cpuinfo")
def test_provenance_names_this_machines_cpu_and_llvm_target():
    import llvmlite.binding as llvm

    with open("/proc/cpuinfo", encoding="utf-8") as f:
        first = f.read().split("\n\n")[0]
    names = [line.partition(":")[2].strip() for line in first.splitlines()
             if line.partition(":")[0].strip() == "model name"]
    cpu = prov.provenance()["machine"]["cpu"]
    if names:                       # x86 and most others; some ARM kernels have none
        assert cpu["model"] == names[0]
    expected = os.environ.get("NUMBA_CPU_NAME") or llvm.get_host_cpu_name()
    assert cpu["llvm_cpu"] == expected and expected
    cpu["model"] = "changed"        # a caller's copy: the cached one stays as it was
    assert prov.provenance()["machine"]["cpu"]["model"] != "changed"


def test_describe_cpu_names_model_family_and_target(monkeypatch):
    fake = {"model": "AMD EPYC", "family": "23", "model_number": "1", "llvm_cpu": "znver1"}
    monkeypatch.setattr(prov, "cpu", lambda: fake)
    monkeypatch.setattr(prov.os, "cpu_count", lambda: 2)
    assert prov.describe_cpu() == "AMD EPYC (family 23, model 1; LLVM target znver1), 2 cores"
    monkeypatch.setattr(prov, "cpu", lambda: {"model": None, "family": None,
                                              "model_number": None, "llvm_cpu": None})
    assert prov.describe_cpu() == f"{prov.platform.machine() or 'unknown CPU'}, 2 cores"


def test_the_commit_is_the_tree_that_tracks_mcverify(tmp_path):
    """Installed into an ignored virtual environment inside the user's repository,
    mcverify recorded the user's HEAD as its own commit; a file the tree does not track
    has no commit, one it tracks has the tree's HEAD."""
    import subprocess

    # the user's own git configuration (commit signing, hooks) kept out
    env = {**os.environ, "GIT_CONFIG_GLOBAL": os.devnull, "GIT_CONFIG_NOSYSTEM": "1"}

    def git(*args):
        subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", "-c",
                        "commit.gpgsign=false", *args], cwd=tmp_path, check=True,
                       capture_output=True, env=env)

    git("init", "-q")
    (tmp_path / ".gitignore").write_text(".venv/\n")
    (tmp_path / "tracked.py").write_text("")
    git("add", ".")
    git("commit", "-qm", "user's work")
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=tmp_path, capture_output=True,
                          text=True, check=True).stdout.strip()
    installed = tmp_path / ".venv" / "lib" / "mcverify"
    installed.mkdir(parents=True)
    (installed / "provenance.py").write_text("")
    assert prov.commit_of(str(installed / "provenance.py")) is None
    assert prov.commit_of(str(tmp_path / "tracked.py")) == head
