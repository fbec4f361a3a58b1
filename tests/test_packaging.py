"""An installed mcverify works without the checkout: a non-editable ``pip install .`` in
a fresh venv, run from another directory, runs ``check``, ``render-check cornell-box``
and ``report`` (the reference scenes are installed as data)."""

import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _pyproject():
    import tomllib

    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
        return tomllib.load(f)


def test_every_reference_folder_is_installed_as_data():
    data = _pyproject()["tool"]["setuptools"]["data-files"]
    scenes = os.path.join(ROOT, "reference", "scenes")
    # Python's byte code (a scene folder's script, imported by its test) is no data
    folders = {os.path.relpath(r, scenes) for r, _, files in os.walk(scenes)
               if files and os.path.basename(r) != "__pycache__"}
    listed = {k.removeprefix("share/mcverify/scenes/"): v for k, v in data.items()}
    assert set(listed) == folders
    for rel, globs in listed.items():
        assert globs == [f"reference/scenes/{rel}/*.*"]
        names = [f for f in os.listdir(os.path.join(scenes, rel))
                 if os.path.isfile(os.path.join(scenes, rel, f))]
        assert all("." in f for f in names), (rel, names)   # the glob needs an extension


def test_package_data_holds_what_the_code_opens():
    assert _pyproject()["tool"]["setuptools"]["package-data"]["estimators.pathtracer"] == [
        "*.json"]
    assert os.path.isfile(os.path.join(ROOT, "estimators", "pathtracer", "materials.json"))


@pytest.mark.slow
def test_a_non_editable_install_runs_check_render_check_and_report(tmp_path):
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    pip = subprocess.run([str(venv / "bin" / "pip"), "install", "-q", ROOT],
                         capture_output=True, text=True, timeout=1800)
    assert pip.returncode == 0, pip.stdout[-2000:] + pip.stderr[-2000:]
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "MCVERIFY_REFS")}
    exe = str(venv / "bin" / "mcverify")

    def run(*args):
        return subprocess.run([exe, *args], cwd=elsewhere, env=env, capture_output=True,
                              text=True, timeout=1200)

    where = subprocess.run([str(venv / "bin" / "python"), "-c",
                            "import mcverify, mcverify.gate.reference as r; "
                            "print(mcverify.__file__); print(r.REFERENCE_ROOT)"],
                           cwd=elsewhere, env=env, capture_output=True, text=True, timeout=300)
    module, root = where.stdout.split()
    assert module.startswith(str(venv)) and root == str(venv / "share" / "mcverify" / "scenes")
    r = run("check", "-q", "-k", "uniform_disk_polar")
    assert r.returncode == 0 and "4 passed, 0 failed" in r.stdout, r.stdout + r.stderr
    r = run("render-check", "cornell-box", "-q")
    assert r.returncode == 0 and "PASS" in r.stdout, r.stdout + r.stderr
    r = run("report", "-q", "--out", "rep", "-k", "uniform_disk_polar", "--renders",
            "white-furnace")
    assert r.returncode == 0, r.stdout + r.stderr
    assert (elsewhere / "rep" / "report.html").is_file()


def test_the_public_api_table_lists_every_public_name():
    """``mcverify.__init__``'s docstring is the API table (STYLE.md: keep it current);
    ``Domain``, ``EnvironmentProblem`` and ``__version__`` were exported unlisted."""
    import re

    import mcverify

    listed = set(re.findall(r"``(\w+)``", mcverify.__doc__))
    assert set(mcverify.__all__) <= listed, sorted(set(mcverify.__all__) - listed)


def _fake_install(packages, record_prefix, share):
    """An install of this checkout's packages into ``packages`` as pip lays one out:
    the package folders (links to the sources), a dist-info whose RECORD names the scenes
    as ``record_prefix/share/mcverify/scenes/...`` and the scenes themselves under
    ``share/mcverify/scenes``."""
    packages.mkdir(parents=True)
    for pkg in ("mcverify", "estimators", "mcnumba"):
        (packages / pkg).symlink_to(os.path.join(ROOT, pkg), target_is_directory=True)
    info = packages / "mcverify-0.1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: mcverify\nVersion: 0.1.0\n")
    (info / "RECORD").write_text(
        "mcverify/__init__.py,,\n"
        f"{record_prefix}/share/mcverify/scenes/cornell-box/scene.xml,,\n")
    scenes = share / "mcverify" / "scenes"
    (scenes / "cornell-box").mkdir(parents=True)
    (scenes / "cornell-box" / "scene.xml").write_text("<scene/>")
    return scenes


def _installed_roots(packages):
    env = {k: v for k, v in os.environ.items() if k != "MCVERIFY_REFS"}
    env["PYTHONPATH"] = str(packages)
    r = subprocess.run([sys.executable, "-c",
                        "import mcverify.gate.reference as r, mcverify.gate as g; "
                        "print(g.__file__); print(r.BUNDLED_ROOT); print(r.REFERENCE_ROOT)"],
                       cwd=str(packages), env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return r.stdout.split()


@pytest.mark.parametrize("layout", ["prefix", "target"])
def test_the_installed_scenes_are_found_where_the_install_put_them(tmp_path, layout):
    # pip install --prefix DIR (and Debian's system Python, whose pip installs under
    # /usr/local while sys.prefix is /usr): the scenes are under DIR/share, not under
    # sys.prefix; pip install --target DIR puts them in DIR/share beside the packages,
    # while its RECORD still names them as from DIR/lib/python. Until 7 December both
    # found no scenes ('known: none').
    if layout == "prefix":
        packages = tmp_path / "pfx" / "lib" / "python3" / "site-packages"
        scenes = _fake_install(packages, "../../..", tmp_path / "pfx" / "share")
    else:
        packages = tmp_path / "tgt"
        scenes = _fake_install(packages, "../..", packages / "share")
    module, bundled, root = _installed_roots(packages)
    assert module == str(packages / "mcverify" / "gate" / "__init__.py")
    assert bundled == root == str(scenes)


def test_python_3_10_gets_a_toml_reader():
    # usersuite reads [tool.mcverify] with tomllib, or tomli on Python 3.10 (which
    # requires-python admits): until 7 December tomli was no dependency, and on 3.10
    # `mcverify check` or `list` in any folder below a pyproject.toml exited 2,
    # "unexpected ModuleNotFoundError: No module named 'tomli'" (an outside review)
    from packaging.requirements import Requirement
    from packaging.specifiers import SpecifierSet

    project = _pyproject()["project"]
    assert SpecifierSet(project["requires-python"]).contains("3.10")
    on_310 = [r for r in map(Requirement, project["dependencies"])
              if r.marker is None or r.marker.evaluate({"python_version": "3.10"})]
    assert "tomli" in {r.name for r in on_310}
    on_311 = [r for r in map(Requirement, project["dependencies"])
              if r.marker is None or r.marker.evaluate({"python_version": "3.11"})]
    assert "tomli" not in {r.name for r in on_311}
