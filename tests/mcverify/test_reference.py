"""Reference renders and the compare gate, end to end through the CLI (real Mitsuba)."""

import os
import shutil
import json
import subprocess
import sys

import numpy as np
import pytest

from mcverify.gate import mitsuba as mvm
from mcverify.gate import reference
from mcverify.errors import EnvironmentProblem

pytestmark = pytest.mark.mitsuba
SCENES = reference.REFERENCE_ROOT
CMD = [sys.executable, "-m", "mcverify"]


@pytest.fixture
def scene_copy(tmp_path):
    dst = tmp_path / "cornell-box"
    shutil.copytree(os.path.join(SCENES, "cornell-box"), dst,
                    ignore=shutil.ignore_patterns("ref"))
    return dst


def _render_pair(path, seed0, scale=1.0, passes=16, spp=64):
    imgs = mvm.render_passes(str(path), spp=spp, seeds=range(seed0, seed0 + passes)) * scale
    return imgs.mean(0), imgs.var(0, ddof=1)


def test_build_load_stale_and_corrupt(scene_copy):
    out = reference.build_reference(str(scene_copy), spp=16, passes=4)
    ref = reference.load_reference(str(scene_copy))
    assert ref.n == 4 and ref.mean.shape == (64, 64, 3)
    assert ref.manifest["scene_sha256"] == reference.scene_hash(str(scene_copy / "scene.xml"))
    assert not [p for p in os.listdir(scene_copy) if p.startswith(".ref-")]
    (scene_copy / "scene.xml").write_text((scene_copy / "scene.xml").read_text()
                                          .replace('value="17, 12, 4"', 'value="18, 12, 4"'))
    with pytest.raises(EnvironmentProblem, match="stale"):
        reference.load_reference(str(scene_copy))
    reference.build_reference(str(scene_copy), spp=16, passes=4)
    with open(os.path.join(out, "mean.exr"), "r+b") as f:
        f.truncate(100)
    with pytest.raises(EnvironmentProblem, match="mean.exr"):
        reference.load_reference(str(scene_copy))


def test_compare_cli_passes_a_to_a_and_fails_a_brighter_render(scene_copy, tmp_path):
    reference.build_reference(str(scene_copy), spp=64, passes=16, seed=3)
    flips = {}
    for label, scale, expected in (("same", 1.0, 0), ("brighter", 1.05, 1)):
        mean, var = _render_pair(scene_copy / "scene.xml", 500, scale)
        mvm.write_exr(str(tmp_path / f"{label}.exr"), mean)
        mvm.write_exr(str(tmp_path / f"{label}_var.exr"), var)
        r = subprocess.run(CMD + ["compare", str(tmp_path / f"{label}.exr"), str(scene_copy),
                                  "--test-var", str(tmp_path / f"{label}_var.exr"),
                                  "--test-n", "16", "--json", str(tmp_path / f"{label}.json")],
                           capture_output=True, text=True, timeout=300)
        assert r.returncode == expected, (label, r.stdout, r.stderr)
        d = json.loads((tmp_path / f"{label}.json").read_text())["details"]
        assert "how visible: mean ΔE2000" in r.stdout and "HDR-FLIP" in r.stdout
        flips[label] = d["flip_mean"]
    assert 0 <= flips["same"] < flips["brighter"] <= 1, flips


@pytest.mark.parametrize("args,needle", [
    (["compare", "a.exr", "no-such-reference", "--test-var", "v.exr", "--test-n", "4"],
     "a.exr: cannot read"),
    (["reference", "build", "no-such-scene"], "scene 'no-such-scene'"),
], ids=["missing-exr", "unknown-scene"])
def test_bad_input_exit_2(args, needle, tmp_path):
    r = subprocess.run(CMD + args, capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert r.returncode == 2 and needle in r.stderr and "Traceback" not in r.stderr


def test_refs_dir_names_where_scene_names_resolve(tmp_path):
    """``--refs DIR``: scene names resolve in DIR (here a copy of white-furnace under
    another name, with its reference), from any working directory; the checkout's names
    are then unknown, and a missing DIR is bad input."""
    refs = tmp_path / "my-refs"
    shutil.copytree(os.path.join(SCENES, "white-furnace"), refs / "furnace")
    env = {k: v for k, v in os.environ.items() if k != "MCVERIFY_REFS"}
    env["PYTHONPATH"] = os.path.dirname(os.path.dirname(os.path.dirname(
        os.path.abspath(__file__))))
    run = lambda *a: subprocess.run(CMD + list(a), capture_output=True, text=True,  # noqa: E731
                                    timeout=600, cwd=tmp_path, env=env)
    r = run("render-check", "furnace", "--refs", str(refs), "--spp", "256", "--passes", "4",
            "--json", str(tmp_path / "rc.json"))
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / "rc.json").read_text())["details"]["scene"] == \
        str(refs / "furnace" / "scene.xml")
    r = run("render-check", "cornell-box", "--refs", str(refs))
    assert r.returncode == 2 and "scene 'cornell-box'" in r.stderr and "known: furnace" in r.stderr
    r = run("compare", "a.exr", "furnace", "--refs", str(tmp_path / "nowhere"),
            "--test-var", "v.exr", "--test-n", "4")
    assert r.returncode == 2 and "--refs" in r.stderr and "does not exist" in r.stderr
    assert not (tmp_path / "nowhere").exists()
