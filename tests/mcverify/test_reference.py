"""Reference renders and the compare gate, end to end through the CLI (real Mitsuba)."""

import os
import re
import shutil
import json
import subprocess
import sys

import numpy as np
import pytest

from mcverify.gate import mitsuba as mvm
from mcverify.gate import reference
from mcverify.errors import EnvironmentProblem, InvalidArgument, MissingReference

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
    # the pass images are stored (hashed like the mean and variance), and the filter
    assert ref.passes.shape == (4, 64, 64, 3)
    np.testing.assert_allclose(ref.passes.mean(0), ref.mean, rtol=1e-5, atol=1e-6)
    assert ref.manifest["rfilter_radius"] == 0.5 and not ref.pixels_correlated
    (scene_copy / "scene.xml").write_text((scene_copy / "scene.xml").read_text()
                                          .replace('value="17, 12, 4"', 'value="18, 12, 4"'))
    with pytest.raises(EnvironmentProblem, match="stale"):
        reference.load_reference(str(scene_copy))
    reference.build_reference(str(scene_copy), spp=16, passes=4)
    with open(os.path.join(out, "mean.exr"), "r+b") as f:
        f.truncate(100)
    with pytest.raises(EnvironmentProblem, match="mean.exr"):
        reference.load_reference(str(scene_copy))
    reference.build_reference(str(scene_copy), spp=16, passes=4)
    with open(os.path.join(out, "passes.exr"), "r+b") as f:
        f.truncate(1000)
    with pytest.raises(EnvironmentProblem, match="passes.exr: stale"):
        reference.load_reference(str(scene_copy))


def test_the_stored_variance_and_pass_count_read_back_as_the_passes_give_them(scene_copy):
    """What ``compare_images`` takes of a reference: its mean, the variance (ddof = 1, a
    variance, not a standard deviation) of its n passes, and n. A mutation review found a
    var.exr written as the passes' standard deviation, or with ddof = 0, passing every
    test: they checked the mean against the passes, not the variance."""
    reference.build_reference(str(scene_copy), spp=16, passes=4, seed=3)
    ref = reference.load_reference(str(scene_copy))
    assert ref.n == ref.manifest["passes"] == len(ref.passes) == 4
    assert len(set(ref.manifest["seeds"])) == 4
    np.testing.assert_allclose(ref.var, ref.passes.var(axis=0, ddof=1), rtol=1e-4, atol=1e-7)
    assert ref.var.max() > 1e-3      # a noisy scene: a std instead would differ


def test_a_scene_edited_while_its_reference_renders_leaves_it_stale(scene_copy,
                                                                    monkeypatch):
    """The scene's SHA-256 is taken before any pass renders, as its files' are: it was
    taken after the last pass, so a scene saved during a long build was recorded as the
    one rendered, and the reference of the old scene loaded as current."""
    scene = scene_copy / "scene.xml"
    scene.write_text(scene.read_text().replace('name="res" value="64"', 'name="res" value="8"'))
    render_pass = mvm.render_pass

    def edit_after_rendering(*args, **kwargs):
        img = render_pass(*args, **kwargs)
        scene.write_text(scene.read_text().replace('value="17, 12, 4"', 'value="34, 24, 8"'))
        return img

    monkeypatch.setattr(mvm, "render_pass", edit_after_rendering)
    reference.build_reference(str(scene_copy), spp=4, passes=2)
    assert "34, 24, 8" in scene.read_text()
    with pytest.raises(EnvironmentProblem, match="stale: .*scene.xml changed"):
        reference.load_reference(str(scene_copy))


def test_a_reference_without_pass_images_still_loads(scene_copy):
    """References built before passes.exr was stored (no ``passes_sha256``) stay valid
    for box-filtered scenes: they load, without passes."""
    import json

    out = reference.build_reference(str(scene_copy), spp=16, passes=4)
    mpath = os.path.join(out, "manifest.json")
    with open(mpath) as f:
        manifest = json.load(f)
    for key in ("passes_sha256", "rfilter_radius"):
        del manifest[key]
    with open(mpath, "w") as f:
        json.dump(manifest, f)
    os.remove(os.path.join(out, "passes.exr"))
    ref = reference.load_reference(str(scene_copy))
    assert ref.passes is None and not ref.pixels_correlated and ref.n == 4


def test_compare_cli_passes_a_to_a_and_fails_a_brighter_render(scene_copy, tmp_path):
    reference.build_reference(str(scene_copy), spp=64, passes=16, seed=3)
    flips = {}
    for label, scale, expected in (("same", 1.0, 0), ("brighter", 1.05, 1)):
        mean, var = _render_pair(scene_copy / "scene.xml", 500, scale)
        mvm.write_exr(str(tmp_path / f"{label}.exr"), mean)
        mvm.write_exr(str(tmp_path / f"{label}_var.exr"), var)
        # the reference by its folder, and by its scene file (read as an image until 4
        # December: "an image needs --ref-var")
        ref_arg = scene_copy if label == "same" else scene_copy / "scene.xml"
        r = subprocess.run(CMD + ["compare", str(tmp_path / f"{label}.exr"), str(ref_arg),
                                  "--test-var", str(tmp_path / f"{label}_var.exr"),
                                  "--test-n", "16", "--json", str(tmp_path / f"{label}.json")],
                           capture_output=True, text=True, timeout=300)
        assert r.returncode == expected, (label, r.stdout, r.stderr)
        doc = json.loads((tmp_path / f"{label}.json").read_text())
        d = doc["details"]
        assert doc["provenance"]["command"] == "compare" and "git_commit" in doc["provenance"]
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
    doc = json.loads((tmp_path / "rc.json").read_text())
    assert doc["details"]["scene"] == str(refs / "furnace" / "scene.xml")
    # who ran it, where and when: a suite's JSON says so, and so does a render check's
    assert doc["provenance"]["command"] == "render-check" and doc["provenance"]["seed"] == 0
    assert {"mcverify_version", "git_commit", "machine", "utc_time"} <= set(doc["provenance"])
    r = run("render-check", "cornell-box", "--refs", str(refs))
    assert r.returncode == 2 and "scene 'cornell-box'" in r.stderr and "known: furnace" in r.stderr
    r = run("compare", "a.exr", "furnace", "--refs", str(tmp_path / "nowhere"),
            "--test-var", "v.exr", "--test-n", "4")
    assert r.returncode == 2 and "--refs" in r.stderr and "does not exist" in r.stderr
    assert not (tmp_path / "nowhere").exists()


def test_scenes_sharing_a_folder_keep_a_reference_each(tmp_path):
    """Two scene files in one folder: each has its own reference (``ref-<file>``), its
    own name (the file's), and a missing one is missing, not the other's gone stale; the
    rebuild command names the file."""
    src = open(os.path.join(SCENES, "white-furnace", "scene.xml")).read()
    a, b = tmp_path / "a.xml", tmp_path / "b.xml"
    a.write_text(src)
    b.write_text(src.replace('value="0.8"', 'value="0.6"'))
    assert reference.resolve_scene(str(a))[0] == "a"
    out_a = reference.build_reference(str(a), spp=16, passes=2)
    assert out_a == str(tmp_path / "ref-a.xml")
    assert reference.load_reference(str(a)).n == 2
    with pytest.raises(MissingReference, match=f"mcverify reference build {b}"):
        reference.load_reference(str(b))
    reference.build_reference(str(b), spp=16, passes=2)
    ra, rb = reference.load_reference(str(a)), reference.load_reference(str(b))
    assert ra.manifest["scene_sha256"] != rb.manifest["scene_sha256"]
    assert sorted(os.listdir(tmp_path)) == ["a.xml", "b.xml", "ref-a.xml", "ref-b.xml"]


def test_rebuild_command_is_quoted_for_the_shell(tmp_path):
    """A scene whose path holds a space (or another shell metacharacter): the rebuild
    command the message names, pasted into a shell, builds that scene's reference (it
    was printed unquoted, so the shell split the path into several arguments)."""
    import shlex
    folder = tmp_path / "my scenes"
    folder.mkdir()
    scene = folder / "furnace (v2).xml"
    shutil.copy(os.path.join(SCENES, "white-furnace", "scene.xml"), scene)
    with pytest.raises(MissingReference) as e:
        reference.load_reference(str(scene))
    command = str(e.value).split("run `", 1)[1].split("`", 1)[0]
    assert shlex.split(command) == ["mcverify", "reference", "build", str(scene)]


def test_the_rebuild_command_of_a_stale_reference_keeps_its_counts(scene_copy):
    """A stale reference's rebuild command builds it as it was built: the splatting-filter
    scenes' references are 64 passes × 64 spp, and the bare command rebuilt them at the
    default 16 × 256, which ``render-check`` at its defaults (64 a pass) then refused
    (exit 2). The defaults are not spelled out."""
    scene = scene_copy / "scene.xml"
    scene.write_text(scene.read_text().replace('name="res" value="64"', 'name="res" value="8"'))
    reference.build_reference(str(scene_copy), spp=4, passes=3)
    scene.write_text(scene.read_text().replace('value="17, 12, 4"', 'value="18, 12, 4"'))
    with pytest.raises(EnvironmentProblem, match=r"stale: .*; run `mcverify reference build "
                                                 r"\S*scene.xml --spp 4 --passes 3`$"):
        reference.load_reference(str(scene_copy))
    m = scene_copy / "ref" / "manifest.json"
    doc = json.loads(m.read_text())
    m.write_text(json.dumps(dict(doc, spp=256, passes=16)))
    with pytest.raises(EnvironmentProblem, match=r"stale: .*; run `mcverify reference build "
                                                 r"\S*scene.xml`$"):
        reference.load_reference(str(scene_copy))
    m.write_text(json.dumps(dict(doc, spp=9, spp_requested=8)))     # what was asked
    with pytest.raises(EnvironmentProblem, match=r"build \S*scene.xml --spp 8 --passes 3`$"):
        reference.load_reference(str(scene_copy))



def test_the_rebuild_command_of_a_scene_under_refs_names_that_folder(scene_copy, tmp_path):
    """A stale reference of a scene found by name in ``--refs DIR`` named the command
    `mcverify reference build cornell-box`, without ``--refs``: pasted into a shell, the
    name resolved in the checkout's (or ``$MCVERIFY_REFS``') scenes, which it rebuilt,
    and DIR's stayed stale. The command names DIR, and run as printed it rebuilds DIR's
    (here with ``$MCVERIFY_REFS`` an empty folder, so the bare name would find nothing)."""
    import shlex
    scene = scene_copy / "scene.xml"
    scene.write_text(scene.read_text().replace('name="res" value="64"', 'name="res" value="8"'))
    reference.build_reference(str(scene_copy), spp=4, passes=2)
    scene.write_text(scene.read_text().replace('value="17, 12, 4"', 'value="18, 12, 4"'))
    refs = str(scene_copy.parent)
    out = subprocess.run(CMD + ["render-check", "cornell-box", "--refs", refs, "-q"],
                         capture_output=True, text=True, cwd=tmp_path)
    assert out.returncode == 2 and "stale" in out.stderr, out.stderr
    command = shlex.split(out.stderr.split("run `", 1)[1].split("`", 1)[0])
    assert command[:4] == ["mcverify", "reference", "build", "cornell-box"]
    assert command[command.index("--refs") + 1] == refs
    empty = tmp_path / "elsewhere"
    empty.mkdir()
    env = dict(os.environ, MCVERIFY_REFS=str(empty))
    rebuilt = subprocess.run(CMD + command[1:] + ["-q"], capture_output=True, text=True,
                             cwd=empty, env=env)
    assert rebuilt.returncode == 0, rebuilt.stderr
    assert reference.load_reference(str(scene_copy)).n == 2


def test_the_rebuild_command_keeps_the_seed_so_it_builds_the_same_bits(scene_copy):
    """A reference built with ``--seed 5`` was to be rebuilt by a command without it, at
    seed 0: other pass seeds, other bits (the manifest kept the pass seeds only, not the
    seed they derive from). The manifest records the seed, the command passes it on where
    it is not 0, and running it again gives the reference it replaces, bit for bit."""
    scene = scene_copy / "scene.xml"
    scene.write_text(scene.read_text().replace('name="res" value="64"', 'name="res" value="8"'))
    reference.build_reference(str(scene_copy), spp=4, passes=2, seed=5)
    assert reference.load_reference(str(scene_copy)).manifest["seed"] == 5
    images = {f: (scene_copy / "ref" / f).read_bytes() for f in ("mean.exr", "var.exr")}
    text = scene.read_text()
    scene.write_text(text.replace('value="17, 12, 4"', 'value="18, 12, 4"'))
    with pytest.raises(EnvironmentProblem, match=r"stale: .*; run `mcverify reference build "
                                                 r"\S*scene.xml --spp 4 --passes 2 --seed 5`$"):
        reference.load_reference(str(scene_copy))
    scene.write_text(text)          # the edit undone: the command rebuilds the same bits
    reference.build_reference(str(scene_copy), spp=4, passes=2, seed=5)
    assert {f: (scene_copy / "ref" / f).read_bytes() for f in images} == images
    reference.build_reference(str(scene_copy), spp=4, passes=2)
    assert reference.load_reference(str(scene_copy)).manifest["seed"] == 0

def test_a_changed_texture_or_mesh_makes_the_reference_stale(tmp_path):
    """The manifest records the SHA-256 of every file the scene names: a texture changed
    or removed after the build is refused as stale, naming it, instead of comparing a
    render of the new texture with Mitsuba's image of the old one. A manifest that
    records no such hashes, for a scene that names files, is stale too."""
    scene = tmp_path / "textures"
    shutil.copytree(os.path.join(SCENES, "textures"), scene,
                    ignore=shutil.ignore_patterns("ref"))
    reference.build_reference(str(scene), spp=4, passes=2)
    ref = reference.load_reference(str(scene))
    assert set(ref.manifest["assets_sha256"]) == {"checker.exr", "tiles.png", "card.obj"}
    png = (scene / "tiles.png").read_bytes()
    (scene / "tiles.png").write_bytes(png + b"\0")
    with pytest.raises(EnvironmentProblem, match="stale: tiles.png .* changed"):
        reference.load_reference(str(scene))
    (scene / "tiles.png").unlink()
    with pytest.raises(EnvironmentProblem, match="stale: tiles.png .* is missing"):
        reference.load_reference(str(scene))
    (scene / "tiles.png").write_bytes(png)
    reference.load_reference(str(scene))
    mpath = scene / "ref" / "manifest.json"
    manifest = json.loads(mpath.read_text())
    del manifest["assets_sha256"]
    mpath.write_text(json.dumps(manifest))
    with pytest.raises(EnvironmentProblem, match="records no SHA-256 of the files"):
        reference.load_reference(str(scene))


def test_a_file_found_only_in_the_working_directory_is_refused(tmp_path, monkeypatch):
    """Mitsuba resolves a relative file name against the scene's folder, then the current
    directory: a mesh that lay only in the directory the build ran from was rendered into
    the reference, recorded as missing (null), and a later change to it never made the
    reference stale (our tracer, which looks beside the scene, refused the scene). The
    build now refuses such a scene before rendering, naming the file."""
    scene = tmp_path / "textures"
    shutil.copytree(os.path.join(SCENES, "textures"), scene,
                    ignore=shutil.ignore_patterns("ref"))
    here = tmp_path / "here"
    here.mkdir()
    shutil.move(scene / "card.obj", here / "card.obj")
    monkeypatch.chdir(here)
    with pytest.raises(InvalidArgument, match=r"names 'card.obj', which is no file at "
                                              + str(scene / "card.obj")):
        reference.build_reference(str(scene), spp=4, passes=2)
    assert not (scene / "ref").exists()
    r = subprocess.run(CMD + ["reference", "build", str(scene), "--spp", "4", "--passes",
                              "2"], capture_output=True, text=True, cwd=here)
    assert r.returncode == 2 and "card.obj" in r.stderr and "Traceback" not in r.stderr
    assert not (scene / "ref").exists()


def test_a_reference_that_recorded_a_file_as_missing_is_stale(tmp_path):
    """References built before the build refused a file found only in the working
    directory recorded it as null, and loaded as valid while it was missing beside the
    scene (null == null): a change to the file Mitsuba had rendered went unnoticed. A
    file missing now is stale, whatever the manifest recorded."""
    scene = tmp_path / "textures"
    shutil.copytree(os.path.join(SCENES, "textures"), scene,
                    ignore=shutil.ignore_patterns("ref"))
    reference.build_reference(str(scene), spp=4, passes=2)
    mpath = scene / "ref" / "manifest.json"
    manifest = json.loads(mpath.read_text())
    manifest["assets_sha256"]["card.obj"] = None
    mpath.write_text(json.dumps(manifest))
    (scene / "card.obj").unlink()
    with pytest.raises(EnvironmentProblem, match="stale: card.obj .* is missing"):
        reference.load_reference(str(scene))


def _textured_furnace(res, filename, extra=""):
    """The white furnace at ``res`` pixels high, its sphere's reflectance the bitmap
    ``filename`` (``$tex`` with ``extra='<default name="tex" value=.../>'``), ``extra``
    after the resolution's default."""
    src = open(os.path.join(SCENES, "white-furnace", "scene.xml")).read()
    src = src.replace('<default name="res" value="64"/>',
                      f'<default name="res" value="{res}"/>{extra}')
    src = src.replace('<rgb name="reflectance" value="1, 1, 1"/>',
                      '<texture type="bitmap" name="reflectance">'
                      f'<string name="filename" value="{filename}"/></texture>')
    assert filename in src and f'value="{res}"' in src
    return src


def test_a_stale_file_named_by_a_parameter_is_named_as_it_resolves(tmp_path):
    """A texture named ``$tex``: the staleness message names the file it resolves to
    (it said only "$tex", an outside review), and the manifest keeps the name as
    written."""
    shutil.copy(os.path.join(SCENES, "textures", "checker.exr"), tmp_path / "t.exr")
    src = _textured_furnace(4, "$tex", '<default name="tex" value="t.exr"/>')
    scene = tmp_path / "scene.xml"
    scene.write_text(src)
    reference.build_reference(str(scene), spp=4, passes=2)
    assert set(reference.load_reference(str(scene)).manifest["assets_sha256"]) == {"$tex"}
    (tmp_path / "t.exr").write_bytes((tmp_path / "t.exr").read_bytes() + b"\0")
    with pytest.raises(EnvironmentProblem, match=r"stale: \$tex = t.exr \(named by .*\) "
                                                 "changed"):
        reference.load_reference(str(scene))


def test_scene_assets_resolve_defaults_and_relative_paths(tmp_path):
    """``scene_assets``: names as written, ``$name`` replaced by the scene's default,
    relative to the scene's folder, None for a name that is no file."""
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "m.obj").write_text("v 0 0 0\n")
    (tmp_path / "t.png").write_bytes(b"png")
    (tmp_path / "s.xml").write_text(
        '<scene version="3.0.0"><default name="mesh" value="m"/>'
        '<shape type="obj"><string name="filename" value="sub/$mesh.obj"/></shape>'
        '<texture type="bitmap"><string name="filename" value="t.png"/></texture>'
        '<texture type="bitmap"><string name="filename" value="gone.png"/></texture>'
        '</scene>')
    assets = reference.scene_assets(str(tmp_path / "s.xml"))
    assert assets == {"sub/$mesh.obj": reference.file_hash(str(tmp_path / "sub" / "m.obj")),
                      "t.png": reference.file_hash(str(tmp_path / "t.png")),
                      "gone.png": None}


def test_a_changed_spectrum_file_makes_the_reference_stale(tmp_path):
    """``<spectrum name="reflectance" filename="x.spd"/>``: Mitsuba reads the file (into
    RGB in an RGB variant), so it is hashed like a texture. It was not recorded, and a
    reference of the old reflectance (its red wall 0.34 off) loaded as current after the
    file changed."""
    src = open(os.path.join(SCENES, "cornell-box", "scene.xml")).read()
    src = src.replace('<default name="res" value="64"/>', '<default name="res" value="8"/>')
    src = src.replace('<rgb name="reflectance" value="0.63 0.065 0.05"/>',
                      '<spectrum name="reflectance" filename="red.spd"/>')
    assert "red.spd" in src
    (tmp_path / "scene.xml").write_text(src)
    (tmp_path / "red.spd").write_text("400 0.2\n500 0.5\n600 0.8\n700 0.9\n")
    assert set(reference.scene_assets(str(tmp_path / "scene.xml"))) == {"red.spd"}
    reference.build_reference(str(tmp_path), spp=4, passes=2)
    reference.load_reference(str(tmp_path))
    (tmp_path / "red.spd").write_text("400 0.02\n500 0.05\n600 0.08\n700 0.09\n")
    with pytest.raises(EnvironmentProblem, match="stale: red.spd .* changed"):
        reference.load_reference(str(tmp_path))


def test_a_file_found_through_a_path_element_is_the_one_hashed(tmp_path):
    """``<path value="tex"/>`` puts ``tex/`` before the scene's folder in Mitsuba's file
    resolver (the last such element first, wherever it stands): the manifest hashed
    ``t.exr`` beside the scene while Mitsuba rendered ``tex/t.exr``, so a change to the
    texture rendered left the reference in use."""
    src = _textured_furnace(4, "t.exr", '<path value="other"/><path value="tex"/>')
    (tmp_path / "scene.xml").write_text(src)
    for d, v in (("tex", 0.5), ("other", 0.25), (".", 0.75)):
        (tmp_path / d).mkdir(exist_ok=True)
        mvm.write_exr(str(tmp_path / d / "t.exr"), np.full((2, 2, 3), v, np.float32))
    assert reference.scene_asset_files(str(tmp_path / "scene.xml")) == {
        "t.exr": os.path.join(str(tmp_path), "tex", "t.exr")}
    reference.build_reference(str(tmp_path), spp=4, passes=2)
    reference.load_reference(str(tmp_path))
    mvm.write_exr(str(tmp_path / "tex" / "t.exr"), np.full((2, 2, 3), 0.9, np.float32))
    with pytest.raises(EnvironmentProblem, match="stale: t.exr .* changed"):
        reference.load_reference(str(tmp_path))


def test_an_included_file_s_path_element_does_not_move_the_scene_s_files(tmp_path):
    """An included file's ``<path>`` serves that file's own includes only: Mitsuba reads
    it with a copy of its file resolver, dropped after it, so the scene's texture is the
    one beside the scene, which is the one hashed (the manifest hashed ``tex/t.exr``)."""
    src = _textured_furnace(4, "t.exr", '<include filename="parts.xml"/>')
    (tmp_path / "scene.xml").write_text(src)
    (tmp_path / "parts.xml").write_text('<scene version="3.0.0"><path value="tex"/></scene>')
    (tmp_path / "tex").mkdir()
    for d, v in (("tex", 0.5), (".", 0.75)):
        mvm.write_exr(str(tmp_path / d / "t.exr"), np.full((2, 2, 3), v, np.float32))
    assert reference.scene_asset_files(str(tmp_path / "scene.xml"))["t.exr"] == \
        os.path.join(str(tmp_path), "t.exr")
    mi = mvm._mi()
    texture = mi.traverse(mi.load_file(str(tmp_path / "scene.xml")))
    values = [np.asarray(texture[k]) for k in texture.keys() if k.endswith(".data")]
    assert len(values) == 1 and np.allclose(values[0], 0.75), values


def test_the_files_hashed_through_path_elements_are_those_mitsuba_reads(tmp_path):
    """An included file's ``<path>`` serves its own includes: sub/parts.xml's ``<path
    value="x"/><include filename="inc.xml"/>`` reads sub/x/inc.xml, which the manifest
    left out (it looked for inc.xml beside the scene); a second ``<path>`` is taken
    against the file's folder, then the first's (only a/b there: a/b/m.obj, which the
    manifest recorded as m.obj beside the scene). A read-only review; Mitsuba reads the
    same files (told apart by their triangles)."""
    tri = "v 0 0 {z}\nv 1 0 {z}\nv 0 1 {z}\nf 1 2 3\n"
    for d in ("sub/x", "a/b"):
        (tmp_path / d).mkdir(parents=True)
    (tmp_path / "a" / "b" / "m.obj").write_text(tri.format(z=0) + tri.format(z=1)
                                                .replace("f 1 2 3", "f 4 5 6"))
    (tmp_path / "m.obj").write_text(tri.format(z=0))
    (tmp_path / "sub" / "x" / "inc.xml").write_text(
        '<scene version="3.0.0"><shape type="obj"><string name="filename" value="m.obj"/>'
        '</shape></scene>')
    (tmp_path / "sub" / "parts.xml").write_text(
        '<scene version="3.0.0"><path value="x"/><include filename="inc.xml"/></scene>')
    src = _textured_furnace(4, "t.exr", '<path value="a"/><path value="b"/>'
                                        '<include filename="sub/parts.xml"/>')
    (tmp_path / "scene.xml").write_text(src)
    files = reference.scene_asset_files(str(tmp_path / "scene.xml"))
    assert files[os.path.join("sub", "x", "inc.xml")] == str(tmp_path / "sub/x/inc.xml")
    assert files["m.obj"] == str(tmp_path / "a" / "b" / "m.obj")
    mvm.write_exr(str(tmp_path / "t.exr"), np.full((2, 2, 3), 0.5, np.float32))
    mi = mvm._mi()
    faces = [s.face_count() for s in mi.load_file(str(tmp_path / "scene.xml")).shapes()
             if s.is_mesh()]
    assert faces == [2], faces      # a/b/m.obj, through sub/x/inc.xml
    from estimators.pathtracer import prepare_scene

    assert prepare_scene(str(tmp_path / "scene.xml")).n_triangles == 2      # and ours


def test_a_top_level_area_emitter_attached_by_ref_renders_as_mitsubas(tmp_path):
    """An area emitter declared at the top level with an id and attached by one shape's
    ``<ref>`` (Mitsuba's own cbox-rgb.xml writes its light so; refused by our loader until
    7 December): ours renders the light where Mitsuba does, through the render gate."""
    from mcverify.gate.render_check import render_check

    (tmp_path / "scene.xml").write_text(
        '<scene version="3.0.0"><integrator type="path"><integer name="max_depth" '
        'value="3"/></integrator>'
        '<sensor type="perspective"><float name="fov" value="60"/><transform '
        'name="to_world"><lookat origin="0, 0, 3" target="0, 0, 0" up="0, 1, 0"/>'
        '</transform><sampler type="independent"><integer name="sample_count" value="64"/>'
        '</sampler><film type="hdrfilm"><integer name="width" value="12"/><integer '
        'name="height" value="8"/><rfilter type="box"/></film></sensor>'
        '<emitter type="area" id="lamp"><rgb name="radiance" value="4, 3, 2"/></emitter>'
        '<shape type="rectangle"><transform name="to_world"><scale value="0.4"/>'
        '<rotate x="1" angle="90"/><translate y="0.9"/></transform><ref id="lamp"/></shape>'
        '<shape type="rectangle"><transform name="to_world"><rotate x="1" angle="-90"/>'
        '<translate y="-0.5"/></transform><bsdf type="diffuse"/></shape></scene>')
    reference.build_reference(str(tmp_path), spp=64, passes=4)
    assert reference.load_reference(str(tmp_path)).mean.max() > 0    # a lit floor
    r = render_check(str(tmp_path), spp=128, passes=4, seed=1)
    assert r.passed, r.summary()
    # the gate sees that light: half as bright again fails
    assert not render_check(str(tmp_path), spp=128, passes=4, seed=1,
                            plant={"light_scale": 1.5}).passed


def test_ours_renders_the_file_found_through_a_path_element_as_mitsuba_does(tmp_path):
    """A scene whose texture is found through ``<path value="tex"/>`` (refused by our
    loader until 7 December): ours reads ``tex/t.exr`` as Mitsuba does, not the file of
    that name beside the scene, and the render gate passes against Mitsuba's reference
    (reflectance 0.5 against 0.75 beside the scene: a furnace four times as dark at
    its second bounce, which the gate cannot miss)."""
    from mcverify.gate.render_check import render_check

    (tmp_path / "scene.xml").write_text(_textured_furnace(4, "t.exr", '<path value="tex"/>'))
    (tmp_path / "tex").mkdir()
    mvm.write_exr(str(tmp_path / "tex" / "t.exr"), np.full((2, 2, 3), 0.5, np.float32))
    mvm.write_exr(str(tmp_path / "t.exr"), np.full((2, 2, 3), 0.75, np.float32))
    reference.build_reference(str(tmp_path), spp=64, passes=4)
    r = render_check(str(tmp_path), spp=128, passes=4, seed=1)
    assert r.passed, r.summary()


def test_a_rebuild_in_the_same_process_renders_the_changed_texture(tmp_path):
    """Mitsuba's loaded scene is kept per process, keyed by the scene file's modification
    time only: a texture changed and the reference rebuilt by ``build_reference`` in the
    same process rendered the old texture, under a manifest hashing the new one, and the
    stale image loaded as current. The files the scene names are part of the key."""
    (tmp_path / "scene.xml").write_text(_textured_furnace(4, "t.exr"))
    mvm.write_exr(str(tmp_path / "t.exr"), np.full((2, 2, 3), 0.25, np.float32))
    reference.build_reference(str(tmp_path), spp=4, passes=2)
    dark = reference.load_reference(str(tmp_path)).mean
    mvm.write_exr(str(tmp_path / "t.exr"), np.full((2, 2, 3), 1.0, np.float32))
    reference.build_reference(str(tmp_path), spp=4, passes=2)
    bright = reference.load_reference(str(tmp_path)).mean
    # albedo 1 under radiance 1 is 1 everywhere; albedo 0.25 darkens the sphere's pixels
    assert bright.mean() > 0.99 and dark.mean() < 0.9, (bright.mean(), dark.mean())


def test_scene_assets_resolve_a_default_that_uses_another(tmp_path):
    """``<default name="mesh" value="$base.obj"/>``, as Mitsuba (and the loader) read it:
    the file was resolved as ``$base.obj``, hashed as missing, so that a change to the
    mesh left the reference in use."""
    (tmp_path / "tri.obj").write_text("v 0 0 0\n")
    (tmp_path / "s.xml").write_text(
        '<scene version="3.0.0"><default name="base" value="tri"/>'
        '<default name="mesh" value="$base.obj"/>'
        '<shape type="obj"><string name="filename" value="$mesh"/></shape></scene>')
    assert reference.scene_assets(str(tmp_path / "s.xml")) == {
        "$mesh": reference.file_hash(str(tmp_path / "tri.obj"))}


def test_files_named_by_an_included_file_count_too(tmp_path):
    """A texture named only inside an ``<include>``d file (resolved, as Mitsuba does,
    against the scene's folder; includes of includes too, each read once) is hashed:
    the manifest recorded the included file alone, and a changed texture left the
    reference in use, a render of the new texture compared with Mitsuba's of the old."""
    (tmp_path / "t.png").write_bytes(b"png")
    (tmp_path / "m.obj").write_text("v 0 0 0\n")
    (tmp_path / "inc").mkdir()
    (tmp_path / "inc" / "mat.xml").write_text(
        '<scene version="3.0.0"><include filename="inc/mesh.xml"/>'
        '<include filename="s.xml"/>'                                   # a cycle
        '<texture type="bitmap" id="t"><string name="filename" value="t.png"/></texture>'
        '</scene>')
    (tmp_path / "inc" / "mesh.xml").write_text(
        '<scene version="3.0.0"><shape type="obj"><string name="filename" '
        'value="$mesh"/></shape><include filename="inc/mat.xml"/></scene>')
    (tmp_path / "s.xml").write_text(
        '<scene version="3.0.0"><default name="mesh" value="m.obj"/>'
        '<include filename="inc/mat.xml"/></scene>')
    assets = reference.scene_assets(str(tmp_path / "s.xml"))
    h = reference.file_hash
    assert assets == {"inc/mat.xml": h(str(tmp_path / "inc" / "mat.xml")),
                      "inc/mesh.xml": h(str(tmp_path / "inc" / "mesh.xml")),
                      "s.xml": h(str(tmp_path / "s.xml")),
                      "t.png": h(str(tmp_path / "t.png")),
                      "$mesh": h(str(tmp_path / "m.obj"))}


def test_an_include_in_an_included_file_is_hashed_where_mitsuba_finds_it(tmp_path):
    """Mitsuba 3.9 finds an include named in an included file beside that file first:
    sub/parts.xml's include of more.xml renders sub/more.xml where it exists. The
    manifest hashed more.xml beside the scene, so a change to the one rendered left the
    reference in use."""
    (tmp_path / "sub").mkdir()
    for f in ("more.xml", "sub/more.xml"):
        (tmp_path / f).write_text('<scene version="3.0.0"/>')
    (tmp_path / "sub" / "parts.xml").write_text(
        '<scene version="3.0.0"><include filename="more.xml"/></scene>')
    (tmp_path / "s.xml").write_text(
        '<scene version="3.0.0"><include filename="sub/parts.xml"/></scene>')
    files = reference.scene_asset_files(str(tmp_path / "s.xml"))
    assert files == {"sub/parts.xml": str(tmp_path / "sub" / "parts.xml"),
                     os.path.join("sub", "more.xml"): str(tmp_path / "sub" / "more.xml")}
    # the same name included beside the scene too is the other file, hashed as well
    (tmp_path / "s.xml").write_text('<scene version="3.0.0"><include filename="more.xml"/>'
                                    '<include filename="sub/parts.xml"/></scene>')
    files = reference.scene_asset_files(str(tmp_path / "s.xml"))
    assert files["more.xml"] == str(tmp_path / "more.xml")
    assert files[os.path.join("sub", "more.xml")] == str(tmp_path / "sub" / "more.xml")
    os.remove(tmp_path / "sub" / "more.xml")        # then beside the scene, as Mitsuba
    files = reference.scene_asset_files(str(tmp_path / "s.xml"))
    assert files["more.xml"] == os.path.join(str(tmp_path), "more.xml")


def test_a_texture_changed_in_an_included_file_makes_the_reference_stale(tmp_path):
    """The message names the included file that names the texture, and the scene that
    includes it: it said "t.exr (named by scene.xml)", a file without that name (Mitsuba's
    material-preview scenes name museum.exr in include/matpreview.xml; an outside
    review)."""
    shutil.copy(os.path.join(SCENES, "textures", "checker.exr"), tmp_path / "t.exr")
    src = open(os.path.join(SCENES, "white-furnace", "scene.xml")).read()
    src = src.replace('<default name="res" value="64"/>', '<default name="res" value="4"/>')
    src = src.replace('<bsdf type="diffuse"><rgb name="reflectance" value="1, 1, 1"/></bsdf>',
                      '<ref id="mat"/>')
    src = src.replace("<integrator", '<include filename="mat.xml"/><integrator', 1)
    assert '<ref id="mat"/>' in src
    (tmp_path / "mat.xml").write_text(
        '<scene version="3.0.0"><bsdf type="diffuse" id="mat"><texture type="bitmap" '
        'name="reflectance"><string name="filename" value="t.exr"/></texture></bsdf></scene>')
    (tmp_path / "scene.xml").write_text(src)
    reference.build_reference(str(tmp_path), spp=4, passes=2)
    assert set(reference.load_reference(str(tmp_path)).manifest["assets_sha256"]) == {
        "mat.xml", "t.exr"}
    (tmp_path / "t.exr").write_bytes((tmp_path / "t.exr").read_bytes() + b"\0")
    mat, scene = re.escape(str(tmp_path / "mat.xml")), re.escape(str(tmp_path / "scene.xml"))
    with pytest.raises(EnvironmentProblem, match=rf"stale: t.exr \(named by {mat}, through "
                                                 rf"the includes of {scene}\) changed"):
        reference.load_reference(str(tmp_path))


def test_a_scene_name_resolves_under_the_root_not_in_the_working_directory(
        tmp_path, monkeypatch):
    """`mcverify reference build --refs DIR` (every scene of DIR, by name) run in a folder
    that holds a folder of the same name as one of DIR's scenes rebuilt that folder's
    reference, not DIR's. A bare name under the root is the root's scene; ./NAME (or a
    name the root lacks) the folder here."""
    from mcverify.gate import cli

    root, here = tmp_path / "refs", tmp_path / "here"
    for base in (root, here):
        shutil.copytree(os.path.join(SCENES, "white-furnace"), base / "mine",
                        ignore=shutil.ignore_patterns("ref"))
    (here / "other").mkdir()
    shutil.copy(here / "mine" / "scene.xml", here / "other" / "scene.xml")
    monkeypatch.chdir(here)
    monkeypatch.setattr(reference, "REFERENCE_ROOT", str(root))
    assert reference.resolve_scene("mine")[1] == str(root / "mine" / "scene.xml")
    assert reference.resolve_scene("./mine")[1] == str(here / "mine" / "scene.xml")
    assert reference.resolve_scene("other")[1] == str(here / "other" / "scene.xml")
    monkeypatch.setenv("MCVERIFY_REFS", str(root))        # --refs sets it: restored after
    assert cli.main(["reference", "build", "--refs", str(root), "--spp", "4",
                     "--passes", "2", "-q"]) == 0
    assert (root / "mine" / "ref" / "manifest.json").exists()
    assert not (here / "mine" / "ref").exists()


def test_build_leaves_the_references_installed_with_mcverify_alone(tmp_path, monkeypatch,
                                                                  capsys):
    """An installed (non-editable) mcverify's own references were rebuilt in place by
    `mcverify reference build cornell-box --spp 4 --passes 2` from a user's project, and a
    bare `reference build` would have re-rendered every one: the install's check and
    render-check then compared against them. Refused, by name and by path, exit 2, the
    old reference kept; a copy in a folder of one's own builds (an outside review)."""
    from mcverify.gate import cli

    installed, mine = tmp_path / "share" / "mcverify" / "scenes", tmp_path / "mine"
    for base in (installed, mine):
        shutil.copytree(os.path.join(SCENES, "white-furnace"), base / "white-furnace")
    before = (installed / "white-furnace" / "ref" / "manifest.json").read_bytes()
    monkeypatch.setattr(reference, "BUNDLED_ROOT", str(installed))
    monkeypatch.setattr(reference, "_CHECKOUT", str(tmp_path / "no-checkout"))
    monkeypatch.setenv("MCVERIFY_REFS", str(installed))        # --refs sets it: restored
    monkeypatch.setattr(reference, "REFERENCE_ROOT", reference.REFERENCE_ROOT)   # and this
    for args in (["--refs", str(installed), "white-furnace"], ["--refs", str(installed)],
                 [str(installed / "white-furnace" / "scene.xml")]):
        assert cli.main(["reference", "build", "--spp", "4", "--passes", "2", "-q",
                         *args]) == 2
        err = capsys.readouterr().err
        assert "is a scene installed with mcverify" in err and "--refs DIR" in err, err
    assert (installed / "white-furnace" / "ref" / "manifest.json").read_bytes() == before
    # a stale installed reference's advice is no command that is refused (a read-only
    # review: it said `mcverify reference build white-furnace`)
    scene = installed / "white-furnace" / "scene.xml"
    scene.write_text(scene.read_text() + "<!-- edited -->\n")
    with pytest.raises(EnvironmentProblem, match="stale") as e:
        reference.load_reference(str(scene))
    assert "into a folder of your own, DIR, and run `mcverify reference build " \
           "white-furnace --refs DIR" in str(e.value), str(e.value)
    assert reference.installed_copy(str(mine / "white-furnace" / "scene.xml")) is None
    assert cli.main(["reference", "build", "--refs", str(mine), "--spp", "4", "--passes",
                     "2", "-q", "white-furnace"]) == 0
    # in a checkout the scenes that come with mcverify are the developer's to rebuild
    monkeypatch.setattr(reference, "_CHECKOUT", str(installed))
    assert reference.installed_copy(str(installed / "white-furnace")) is None


def test_build_refuses_to_replace_what_is_not_a_reference(scene_copy, monkeypatch):
    """A file named ``ref`` beside the scene was deleted by the build (exit 0), as was a
    user's folder of that name; both are refused before anything renders, and kept."""
    from mcverify.errors import InvalidArgument

    monkeypatch.setattr(reference, "_render_jobs", lambda *a, **k: pytest.fail("rendered"))
    ref = scene_copy / "ref"
    ref.write_text("my notes")
    with pytest.raises(InvalidArgument, match=r"ref: exists and is not a reference folder"):
        reference.build_reference(str(scene_copy), spp=4, passes=2)
    r = subprocess.run(CMD + ["reference", "build", str(scene_copy), "--spp", "4",
                              "--passes", "2"], capture_output=True, text=True)
    assert r.returncode == 2 and "not a reference folder" in r.stderr
    assert ref.read_text() == "my notes"
    ref.unlink()
    ref.mkdir()
    (ref / "mean.exr").write_bytes(b"x")
    (ref / "thesis.tex").write_text("keep me")
    with pytest.raises(InvalidArgument, match=r"thesis.tex, which is not part of a reference"):
        reference.build_reference(str(scene_copy), spp=4, passes=2)
    assert (ref / "thesis.tex").read_text() == "keep me"


def test_a_scene_file_with_a_long_name_gets_its_reference(scene_copy, monkeypatch):
    """A scene file of 240 bytes has a reference folder of 244 (``ref-`` + the name), a
    valid name, but the build's temporary folders beside it, ``.ref-<name>-new-XXXXXXXX``,
    were not: every pass rendered, then 'File name too long' (exit 2), for each rebuild
    too. A name whose reference folder cannot exist (252 bytes + ``ref-``) is refused
    before anything renders, naming the scene."""
    scene = scene_copy / ("b" * 236 + ".xml")
    shutil.copy(scene_copy / "scene.xml", scene)
    for _ in range(2):                  # built, then rebuilt over the first one
        out = reference.build_reference(str(scene), spp=2, passes=2)
        assert os.path.basename(out) == "ref-" + scene.name
        assert reference.load_reference(str(scene)).n == 2
    assert sorted(p.name for p in scene_copy.iterdir() if p.name.startswith(".")) == []
    monkeypatch.setattr(reference, "_render_jobs", lambda *a, **k: pytest.fail("rendered"))
    longer = scene_copy / ("c" * 248 + ".xml")
    shutil.copy(scene_copy / "scene.xml", longer)
    with pytest.raises(InvalidArgument, match=r"name of 256 bytes.*shorter name") as e:
        reference.build_reference(str(longer), spp=2, passes=2)
    assert str(longer) in str(e.value)


def test_a_folder_where_no_reference_can_be_written_is_refused_before_rendering(
        scene_copy, monkeypatch):
    """A read-only scene folder rendered every pass, then failed naming a temporary
    folder ('.ref-new-XXXXXXXX: Read-only file system'); now EnvironmentProblem naming
    the reference folder, before anything renders. And ``check --scene`` whose render
    check cannot build its reference (a file named ``ref`` in the way) failed that check,
    exit 1, as if our tracer were wrong; now exit 2 naming the file."""
    monkeypatch.setattr(reference, "_render_jobs", lambda *a, **k: pytest.fail("rendered"))

    def read_only(*a, **k):
        raise OSError(30, "Read-only file system", str(scene_copy / ".ref-new-x"))

    monkeypatch.setattr(reference.tempfile, "mkdtemp", read_only)
    with pytest.raises(EnvironmentProblem, match=r"ref: cannot write the reference in "
                                                 r".*\(Read-only file system\)") as e:
        reference.build_reference(str(scene_copy), spp=4, passes=2)
    assert ".ref-new" not in str(e.value)
    monkeypatch.undo()
    xml = scene_copy / "scene.xml"
    xml.write_text(xml.read_text().replace('name="res" value="64"', 'name="res" value="8"'))
    (scene_copy / "ref").write_text("my notes")
    r = subprocess.run(CMD + ["check", "--scene", str(scene_copy), "-k", "render", "-q"],
                       capture_output=True, text=True)
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert "not a reference folder" in r.stderr and "Traceback" not in r.stderr
    assert (scene_copy / "ref").read_text() == "my notes"


def test_a_reference_that_cannot_be_written_names_it_and_keeps_the_old_one(
        scene_copy, monkeypatch):
    """A full disk while the images were written: Mitsuba's writer raised RuntimeError,
    reported as 'unexpected RuntimeError: [FileStream] ".../.ref-new-…/var.exr": I/O
    error … No space left on device'. Now EnvironmentProblem naming the reference folder;
    the previous reference stays, and nothing is left beside it."""
    xml = scene_copy / "scene.xml"
    xml.write_text(xml.read_text().replace('name="res" value="64"', 'name="res" value="8"'))
    reference.build_reference(str(scene_copy), spp=2, passes=2)
    before = sorted(os.listdir(scene_copy))
    calls = []

    def full_disk(path, image):
        calls.append(path)
        raise RuntimeError(f'[FileStream] "{path}": I/O error while attempting to write '
                           "12402 bytes: No space left on device")

    monkeypatch.setattr(mvm, "write_exr", full_disk)
    with pytest.raises(EnvironmentProblem, match=r"ref: cannot write the reference \(.*No "
                                                 r"space left on device\); the previous") as e:
        reference.build_reference(str(scene_copy), spp=2, passes=3)
    assert str(e.value).startswith(str(scene_copy / "ref")) and calls
    assert sorted(os.listdir(scene_copy)) == before
    assert reference.load_reference(str(scene_copy)).n == 2
    # a RuntimeError subclass is no disk's: it goes on as it is (it was reworded as
    # "cannot write the reference"; a final review), the old reference kept all the same
    monkeypatch.setattr(mvm, "write_exr", lambda path, image: (_ for _ in ()).throw(
        NotImplementedError("a writer bug")))
    with pytest.raises(NotImplementedError, match="a writer bug"):
        reference.build_reference(str(scene_copy), spp=2, passes=3)
    assert sorted(os.listdir(scene_copy)) == before


def test_a_scene_named_twice_is_built_once(scene_copy, monkeypatch):
    seen = []
    real = reference._render_jobs

    def spy(jobs, pool, progress):
        seen.append(len(jobs))
        return real(jobs, pool, progress)

    monkeypatch.setattr(reference, "_render_jobs", spy)
    out = reference.build_references([str(scene_copy), str(scene_copy / "scene.xml")],
                                     spp=2, passes=2)
    assert seen == [1] and len(out) == 1 and reference.load_reference(str(scene_copy)).n == 2


@pytest.mark.parametrize("sampler,asked,rendered", [("stratified", 5, 9),
                                                    ("multijitter", 7, 8),
                                                    ("orthogonal", 10, 25),
                                                    ("independent", 5, 5)])
def test_the_manifest_records_the_samples_mitsuba_renders(tmp_path, sampler, asked, rendered):
    """Mitsuba's stratified sampler rounds 5 spp up to 9, multijitter 7 to 8: the manifest
    said 5 (found by a probe), and the render gate pairs passes of equal spp where the
    filter splats. It records what was rendered, and what was asked where they differ;
    the CLI says so, once, and Mitsuba's own warning about it (one a load, coloured, on
    stdout where that is not a terminal: among a --json /dev/stdout) stays silent."""
    src = open(os.path.join(SCENES, "white-furnace", "scene.xml")).read()
    scene = tmp_path / "s.xml"
    scene.write_text(src.replace('type="independent"', f'type="{sampler}"'))
    assert f'type="{sampler}"' in scene.read_text()
    out = subprocess.run(CMD + ["reference", "build", str(scene), "--spp", str(asked),
                                "--passes", "2", "-q"], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    manifest = reference.load_reference(str(scene)).manifest
    assert manifest["spp"] == rendered
    assert manifest.get("spp_requested") == (asked if asked != rendered else None)
    assert f"2 passes × {rendered} spp per pass" in out.stdout
    assert ("rounds --spp" in out.stdout) == (asked != rendered)
    assert "WARN" not in out.stdout + out.stderr, out.stdout   # (its log: stdout)


@pytest.mark.parametrize("sampler,per,rounded", [("stratified", 32, 36),
                                                ("orthogonal", 64, 121)])
def test_render_check_refuses_before_building_a_reference_it_would_refuse(
        tmp_path, sampler, per, rounded):
    """A splatting filter compares passes of equal samples, and a reference's passes
    have the count Mitsuba's sampler rounds to: the gate built a reference at the
    rounded count, then refused it against ours, and left it on disk, so that every
    later default run was refused too (an outside review). Now it refuses first, saying
    which spp to use, and writes nothing; with that spp it builds and compares."""
    from mcverify.errors import InvalidArgument
    from mcverify.gate.render_check import render_check

    src = open(os.path.join(SCENES, "white-furnace", "scene.xml")).read()
    src = src.replace('type="independent"', f'type="{sampler}"')
    src = src.replace('<rfilter type="box"/>', '<rfilter type="gaussian"/>')
    src = src.replace('<default name="res" value="64"/>', '<default name="res" value="4"/>')
    scene = tmp_path / "s.xml"
    scene.write_text(src)
    assert 'type="gaussian"' in src and f'type="{sampler}"' in src and 'value="4"' in src
    with pytest.raises(InvalidArgument, match=f"renders {rounded} where {per} are asked; "
                                              f"use spp={rounded * 2} with passes=2"):
        render_check(str(scene), spp=per * 2, passes=2, seed=1)
    assert sorted(os.listdir(tmp_path)) == ["s.xml"]
    r = render_check(str(scene), spp=rounded * 2, passes=2, seed=1)
    assert r.passed, r.summary()
    assert reference.load_reference(str(scene)).manifest["spp"] == rounded


def test_a_folder_without_a_scene_file_is_named_as_such(tmp_path, monkeypatch):
    """A folder given as the scene, holding no scene.xml, is refused as a folder (not
    'no such file'); a reference name still wins over a local folder of that name."""
    from mcverify.errors import InvalidArgument

    empty = tmp_path / "scenes.xml"
    empty.mkdir()
    with pytest.raises(InvalidArgument, match="is a folder without a scene.xml"):
        reference.resolve_scene(str(empty))
    monkeypatch.chdir(tmp_path)
    (tmp_path / "cornell-box").mkdir()
    assert reference.resolve_scene("cornell-box")[1].endswith(
        os.path.join("cornell-box", "scene.xml"))


@pytest.mark.parametrize("kwargs, match", [
    (dict(spp="8"), "spp='8': must be an integer"),
    (dict(spp=8.0), "spp=8.0: must be an integer"),
    (dict(spp=2 ** 32), "spp=4294967296: at most 4294967295"),
    (dict(passes=2.5), "passes=2.5: must be an integer"),
    (dict(seed=-1), "seed=-1: must be >= 0"),
    (dict(seed=1.5), "seed=1.5: must be an integer"),
    # the passes are held in memory until the reference is written: 10^17 of them was an
    # "unexpected MemoryError" naming no option (an outside review)
    (dict(passes=10 ** 17), "passes=100000000000000000: needs about .* of memory .*pass "
                            "images.*; use at most"),
])
def test_build_reference_names_a_bad_count_before_rendering(scene_copy, kwargs, match):
    """spp="8" and passes=2.5 raised bare TypeErrors, seed=-1 numpy's ValueError, and
    spp=8.0 or 2^32 reached Mitsuba's render() as a binding error blamed on the scene."""
    from mcverify.errors import InvalidArgument

    with pytest.raises(InvalidArgument, match=match):
        reference.build_reference(str(scene_copy), **{"spp": 8, **kwargs})
    assert not os.path.exists(scene_copy / "ref")


def test_reference_build_cli_refuses_more_spp_than_mitsuba_takes(scene_copy):
    r = subprocess.run(CMD + ["reference", "build", str(scene_copy), "--spp", str(2 ** 32)],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "--spp 4294967296: at most 4294967295" in r.stderr, r.stderr
    assert "Mitsuba cannot render" not in r.stderr
    assert not os.path.exists(scene_copy / "ref")


def test_a_missing_mcverify_refs_is_named(tmp_path):
    """``$MCVERIFY_REFS`` is checked as ``--refs`` is: a folder that does not exist (a
    misspelt path in CI) exits 2 naming the variable; until 6 December every scene name
    was "no such file ... (known: none)", the variable named nowhere."""
    env = dict(os.environ, MCVERIFY_REFS=str(tmp_path / "nowhere"))
    env["PYTHONPATH"] = os.path.dirname(os.path.dirname(os.path.dirname(
        os.path.abspath(__file__))))
    r = subprocess.run(CMD + ["plan", "cornell-box"], capture_output=True, text=True,
                       timeout=120, cwd=tmp_path, env=env)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "$MCVERIFY_REFS=" in r.stderr and "does not exist" in r.stderr
    # --refs wins over the variable, as the README says
    r = subprocess.run(CMD + ["plan", "cornell-box", "--refs", SCENES], capture_output=True,
                       text=True, timeout=120, cwd=tmp_path, env=env)
    assert r.returncode == 0, r.stderr


def _refused_then_built(scene, text, bad, good, match):
    """``text`` with the radiance ``bad`` is refused by the build (``match``), nothing
    written beside the scene; with ``good`` it builds a finite reference of 2 passes."""
    from mcverify.errors import InvalidArgument

    scene.write_text(text.format(bad))
    with pytest.raises(InvalidArgument, match=match):
        reference.build_reference(str(scene), spp=4, passes=2)
    assert sorted(os.listdir(scene.parent)) == [scene.name]
    scene.write_text(text.format(good))
    reference.build_reference(str(scene), spp=4, passes=2)
    built = reference.load_reference(str(scene))
    assert built.n == 2 and np.isfinite(built.mean).all() and np.isfinite(built.var).all()


@pytest.mark.filterwarnings("error::RuntimeWarning")
def test_a_scene_mitsuba_renders_infinite_is_refused_before_writing(tmp_path):
    """An outside review: a constant sky of radiance 1e39, beyond float32's range, is
    infinite in Mitsuba's image. The reference was written (numpy warning on its
    variance) and render-check then refused it as containing NaN/Inf with a rebuild
    command that built the same. Now the build says what Mitsuba rendered and writes
    nothing; a sky of 1e37, whose samples' sum stays within the range, builds."""
    scene = tmp_path / "sky.xml"
    text = """<scene version="3.0.0"><integrator type="path"/>
  <sensor type="perspective"><film type="hdrfilm"><integer name="width" value="4"/>
    <integer name="height" value="4"/><rfilter type="box"/></film></sensor>
  <emitter type="constant"><rgb name="radiance" value="{}"/></emitter></scene>"""
    _refused_then_built(scene, text, "1e39", "1e37",
                        r"sky\.xml: Mitsuba's image is not finite \(NaN or inf\) in 16 "
                        r"pixel\(s\), the first in pass 1 at x=0, y=0: .*beyond float32's "
                        r"range .*no reference written")


@pytest.mark.filterwarnings("error::RuntimeWarning")
def test_a_variance_beyond_float32_is_refused_before_writing(tmp_path):
    """An outside review: an area light of radiance 1e30 renders finite pixels (about
    1e29), but their variance across passes, about 1e58, is beyond float32's range: var.exr
    was written as infinity (numpy warning of an overflow in the cast), the build said
    'built', and render-check then refused the reference as containing NaN/Inf with a
    rebuild command that built the same. Now the build names the pixel and writes
    nothing; a light of 1e15 (a variance near 1e28) builds."""
    scene = tmp_path / "scene.xml"
    text = """<scene version="3.0.0"><integrator type="path"/>
  <sensor type="perspective"><transform name="to_world"><lookat origin="0, 0, 4"
    target="0, 0, 0" up="0, 1, 0"/></transform><film type="hdrfilm">
    <integer name="width" value="4"/><integer name="height" value="4"/>
    <rfilter type="box"/></film></sensor>
  <shape type="rectangle"><transform name="to_world"><scale value="3"/></transform>
    <bsdf type="diffuse"/></shape>
  <shape type="sphere"><point name="center" x="0" y="0" z="3"/><float name="radius"
    value="0.3"/><emitter type="area"><rgb name="radiance" value="{}"/></emitter></shape>
</scene>"""
    _refused_then_built(scene, text, "1e30", "1e15",
                        r"scene\.xml: the variance across Mitsuba's passes is beyond "
                        r"float32's range .* the first at x=\d+, y=\d+ .*nothing written")


def _write_plain_exr(path, texels):
    mvm.write_exr(path, texels)


def _write_layered_exr(path, texels):
    mi = mvm._mi()
    mi.Bitmap(texels, mi.Bitmap.PixelFormat.MultiChannel,
              ["albedo.R", "albedo.G", "albedo.B"]).write(path)


@pytest.mark.parametrize("write, image", [(_write_plain_exr, "bad.exr"),
                                          (_write_layered_exr, "layer.exr")],
                         ids=["rgb", "layer-named"])
def test_a_texture_with_a_nan_texel_is_named_when_mitsubas_image_is_not_finite(
        tmp_path, write, image):
    """An outside review: ``reference build`` of a scene whose bitmap holds a NaN texel
    (Mitsuba renders NaN pixels from it) blamed 'a radiance, intensity, irradiance or scale
    beyond float32's range', which the scene had none of. The message now names the image
    and its first non-finite texel; nothing is written. A mesh beside it (no image) is
    passed over. So for an EXR whose channels carry a layer's name (albedo.R, albedo.G,
    albedo.B), which Mitsuba renders as a texture: the build read it as an envmap, whose
    conversion refuses such channels, and passed it over (another outside review)."""
    from mcverify.errors import InvalidArgument

    texels = np.full((4, 5, 3), 0.5, dtype=np.float32)
    texels[2, 3, 1] = np.nan
    write(str(tmp_path / image), texels)
    (tmp_path / "card.obj").write_text("v -1 -1 0\nv 1 -1 0\nv 1 1 0\nf 1 2 3\n")
    scene = tmp_path / "scene.xml"
    scene.write_text(f"""<scene version="3.0.0"><integrator type="path"/>
  <sensor type="orthographic"><transform name="to_world"><lookat origin="0, 0, 5"
    target="0, 0, 0" up="0, 1, 0"/></transform><film type="hdrfilm">
    <integer name="width" value="8"/><integer name="height" value="8"/>
    <rfilter type="box"/></film></sensor>
  <shape type="obj"><string name="filename" value="card.obj"/></shape>
  <shape type="rectangle"><bsdf type="diffuse"><texture type="bitmap" name="reflectance">
    <string name="filename" value="{image}"/><string name="filter_type" value="nearest"/>
  </texture></bsdf></shape>
  <emitter type="constant"/></scene>""")
    with pytest.raises(InvalidArgument, match=r"scene\.xml: Mitsuba's image is not finite "
                                              rf".*: the image {image.replace('.', '[.]')} "
                                              r"has 1 texel\(s\) that are not finite, the "
                                              r"first at row 2, column 3 \(channel 1: nan\)"
                                              r".*no reference written"):
        reference.build_reference(str(scene), spp=4, passes=2)
    assert sorted(os.listdir(tmp_path)) == sorted([image, "card.obj", "scene.xml"])


def test_the_stamp_and_assets_follow_the_params_the_scene_is_loaded_with(tmp_path):
    """A ``$name`` given as a parameter (``--param tex=b.exr``) replaces the scene's
    ``<default>``: the stamp that keys a loaded scene and the hashes of a job's files
    described the default's file (a.exr), so b.exr edited in the same process rendered
    the scene as it was loaded."""
    (tmp_path / "scene.xml").write_text(
        _textured_furnace(64, "$tex", '<default name="tex" value="a.exr"/>'))
    for name in ("a.exr", "b.exr"):
        mvm.write_exr(str(tmp_path / name), np.full((2, 2, 3), 0.5, np.float32))
    scene = str(tmp_path / "scene.xml")
    files = [f for f, _ in reference.scene_stamp(scene, {"tex": "b.exr"})[1:]]
    assert files == [str(tmp_path / "b.exr")]
    assert set(reference.scene_assets(scene, (("tex", "b.exr"),))) == {"$tex"}
    assert reference.scene_asset_files(scene, {"tex": "b.exr"})["$tex"] == \
        str(tmp_path / "b.exr")
    assert reference.scene_asset_files(scene)["$tex"] == str(tmp_path / "a.exr")


def test_the_passes_memory_guard_counts_what_a_pass_takes(scene_copy):
    """The --passes guard counted a float32 image a pass (12 bytes a pixel) while the
    build holds float64 passes three times over (75): a 4096 × 4096 film under
    `ulimit -v 5000000` was allowed "at most 10" passes and the 10th failed in Mitsuba
    after nine had rendered (an outside review). The peak grows by at most what the guard
    counts for each added pass."""
    import tracemalloc

    xml = scene_copy / "scene.xml"
    xml.write_text(xml.read_text().replace('name="res" value="64"', 'name="res" value="256"'))
    peaks = {}
    tracemalloc.start()
    try:
        for k in (2, 6):
            tracemalloc.reset_peak()
            reference.build_reference(str(scene_copy), spp=1, passes=k)
            peaks[k] = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    per_pass = (peaks[6] - peaks[2]) / 4
    assert per_pass > 256 * 256 * 24, peaks          # at least one float64 image a pass
    assert per_pass <= reference._pass_bytes(str(xml), None), (per_pass, peaks)


def test_passes_that_do_not_fit_at_all_are_not_told_to_use_one(scene_copy, monkeypatch):
    """Where not even the least 2 passes fit, the refusal said "use at most 1", a count
    that is itself refused (an outside review)."""
    from mcverify import _validate
    from mcverify.errors import InvalidArgument

    one = reference._pass_bytes(reference.resolve_scene(str(scene_copy))[1], None)
    monkeypatch.setattr(_validate, "_available_memory", lambda: 3 * one)   # 1.5 in half
    with pytest.raises(InvalidArgument, match=r"passes=2: .*; not even 2 fit") as e:
        reference.build_reference(str(scene_copy), spp=4, passes=2)
    assert "use at most" not in str(e.value)


def test_the_passes_memory_guard_counts_every_scene_of_a_build(scene_copy, monkeypatch):
    """``reference build A B`` holds the passes of both scenes until the last has
    rendered, and each scene's passes were checked against half the memory alone: two
    that each fit were rendered, then ran out of memory together (an outside review).
    They are refused before any rendering, naming the scenes' count and the most passes
    that fit; one of them alone is not."""
    from mcverify import _validate
    from mcverify.errors import InvalidArgument
    from mcverify.gate import mitsuba as mvm

    other = scene_copy / "other.xml"
    shutil.copy(scene_copy / "scene.xml", other)
    one = reference._pass_bytes(reference.resolve_scene(str(scene_copy))[1], None)
    monkeypatch.setattr(_validate, "_available_memory", lambda: 2 * 6 * one)  # 6 in half
    monkeypatch.setattr(mvm, "choose_variant", lambda: pytest.fail("rendered"))
    with pytest.raises(InvalidArgument, match=r"passes=4 of 2 scenes: needs .*; use at "
                                               r"most 3, or build fewer scenes at once"):
        reference.build_references([str(scene_copy), str(other)], spp=1, passes=4)
    reference._job(str(other), 1, 4, 0, None)      # one of them alone fits
    assert sorted(os.listdir(scene_copy)) == ["other.xml", "scene.xml"]


def test_a_reference_of_an_rgba_film_is_compared_on_its_colour(tmp_path):
    """A scene whose film has pixel_format rgba: Mitsuba renders R, G, B and A, and the
    reference kept A (until 7 December), so Mitsuba's own RGBA passes, read on their
    colour as ``compare`` reads an image under test, were refused against it: "shape
    (6, 8, 3) differs from the reference's (6, 8, 4)", exit 2. The reference is read on
    its colour too, and Mitsuba against itself passes (α = 0.01)."""
    scene = tmp_path / "scene.xml"
    scene.write_text("""<scene version="3.0.0">
  <integrator type="path"><integer name="max_depth" value="2"/></integrator>
  <sensor type="perspective"><float name="fov" value="45"/>
    <transform name="to_world"><lookat origin="0, 0, 3" target="0, 0, 0" up="0, 1, 0"/>
    </transform>
    <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="6"/>
      <string name="pixel_format" value="rgba"/><rfilter type="box"/></film>
  </sensor>
  <shape type="sphere"><float name="radius" value="0.6"/><bsdf type="diffuse"/></shape>
  <emitter type="constant"><rgb name="radiance" value="0.8, 0.5, 0.3"/></emitter>
</scene>""")
    reference.build_reference(str(scene), spp=16, passes=4, seed=1)
    ref = reference.load_reference(str(scene))
    assert ref.mean.shape == ref.var.shape == (6, 8, 3) and ref.passes.shape == (4, 6, 8, 3)
    passes = mvm.render_passes(str(scene), spp=16, seeds=range(100, 104))
    assert passes.shape == (4, 6, 8, 4)          # Mitsuba's RGBA, alpha last
    for k, img in enumerate(passes):
        mvm.write_exr(str(tmp_path / f"pass_{k}.exr"), img)
    r = subprocess.run(CMD + ["compare", "--test-passes", str(tmp_path / "pass_*.exr"),
                              str(scene), "--test-spp", "16"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, (r.stdout, r.stderr)
