"""Reports: JSON first, PNGs and one self-contained HTML page that a browser renders with
every image loaded and no console error (headless Chromium)."""

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from mcverify.gate import suites
from mcverify.gate.report import build_report
from mcverify.gate.report.renders import run_renders
from mcverify.gate.report.study import run_study

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("report")
    checks = suites.select(suites.build_suite("default"), "sampler:uniform_disk")
    planted = suites.canaries(200_000)[:1]   # a failing check, so its histogram is drawn
    result = suites.run_suite(checks + planted, seed=0, canary=False)
    study = run_study(ns=(64, 256, 1024), n_seeds=8)
    renders = run_renders(["cornell-box"], spps=(4, 16))
    doc = build_report(str(out), suite=result, study=study, renders=renders)
    return out, doc


def test_json_first_with_provenance_and_all_parts(report):
    out, doc = report
    on_disk = json.loads((out / "report.json").read_text())
    assert on_disk["provenance"]["git_commit"] == doc["provenance"]["git_commit"]
    assert on_disk["verification"]["n_failed"] == 1
    assert {r["estimator"] for r in on_disk["convergence"]} >= {"uniform", "rqmc"}
    names = set(on_disk["images"])
    assert {"convergence.png", "efficiency.png", "render_cornell_box.png",
            "render_error.png"} <= names
    (row,) = on_disk["renders"]
    assert row["scene"] == "cornell-box" and row["passed"]
    assert len(row["curve"]["ours_rmse"]) == 2 and row["curve"]["mitsuba_seconds"][0] > 0
    assert any(n.startswith("failed_") for n in names)
    for n in names:
        assert (out / n).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not list(out.glob("*.tmp")) and not list(out.glob(".tmp-*"))


def test_a_report_over_an_old_one_removes_the_old_ones_images_only(tmp_path):
    """A report written into the folder of an earlier one removes the images that report
    listed and this one does not write (its render_*.png stayed before), and leaves
    the user's own files alone."""
    build_report(str(tmp_path), suite=None, study=None, extra_provenance={})
    (tmp_path / "render_a.png").write_bytes(b"old")      # as if the old report drew it
    doc = json.loads((tmp_path / "report.json").read_text())
    doc["images"]["render_a.png"] = "render_a.png"
    (tmp_path / "report.json").write_text(json.dumps(doc))
    (tmp_path / "mine.png").write_bytes(b"user")
    build_report(str(tmp_path), suite=None, study=None, extra_provenance={})
    assert not (tmp_path / "render_a.png").exists()
    assert (tmp_path / "mine.png").read_bytes() == b"user"
    assert (tmp_path / "report.html").exists()


def test_a_report_whose_page_cannot_be_written_leaves_the_old_report_whole(tmp_path):
    """The report writes its images, report.json and report.html one after another: where
    the page could not be written (a full disk: report.html a link to /dev/full), the
    new report.json replaced the old one beside the old page, and the old report's
    images it no longer names were deleted. Now nothing is replaced or removed until
    every file is written."""
    build_report(str(tmp_path), suite=None, study=None, extra_provenance={})
    (tmp_path / "render_a.png").write_bytes(b"old")      # as if the old report drew it
    doc = json.loads((tmp_path / "report.json").read_text())
    doc["images"]["render_a.png"] = "render_a.png"
    old = json.dumps(doc)
    (tmp_path / "report.json").write_text(old)
    (tmp_path / "report.html").unlink()
    (tmp_path / "report.html").symlink_to("/dev/full")
    with pytest.raises(OSError, match="No space left"):
        build_report(str(tmp_path), suite=None, study=None, extra_provenance={})
    assert (tmp_path / "report.json").read_text() == old
    assert (tmp_path / "render_a.png").read_bytes() == b"old"
    assert sorted(os.listdir(tmp_path)) == ["render_a.png", "report.html", "report.json"]


def test_report_json_has_no_bare_nan_token(tmp_path):
    """report.json is written as every other output file (``result.json_text``): a
    non-finite number is the string "nan"/"inf", where a plain json.dumps wrote the bare
    token NaN, which strict parsers (jq, JavaScript) refuse."""
    build_report(str(tmp_path), suite=None, study=None,
                 extra_provenance={"odd": float("nan"), "big": float("inf")})
    text = (tmp_path / "report.json").read_text()
    doc = json.loads(text, parse_constant=lambda c: pytest.fail(f"bare token {c}"))
    assert doc["provenance"]["odd"] == "nan" and doc["provenance"]["big"] == "inf"


@pytest.mark.parametrize("blocked", ["report.html", "convergence.png"])
def test_a_folder_in_the_way_is_refused_before_any_file_is_written(tmp_path, blocked):
    """A folder where a report file goes (report.html, a PNG) is refused, naming it,
    before anything is written: report.json and the PNGs were written first, then the
    page failed, leaving a new report.json beside no report.html."""
    from mcverify.errors import InvalidArgument

    out = tmp_path / "rep"
    (out / blocked).mkdir(parents=True)
    study = run_study(ns=(64, 128, 256), n_seeds=4)
    with pytest.raises(InvalidArgument, match=f"{blocked}: is a directory"):
        build_report(str(out), suite=None, study=study, extra_provenance={})
    assert sorted(p.name for p in out.iterdir()) == [blocked]


def test_cli_report_refuses_a_folder_named_report_html_before_any_work(tmp_path, capsys):
    from mcverify.gate.cli import main

    (tmp_path / "report.html").mkdir()
    rc = main(["report", "--no-suite", "--renders", "none", "-q", "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert rc == 2 and "report.html: is a directory" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.html"]


def _render_row(scene, level):
    rng = np.random.default_rng(int(level * 100))
    ours = np.full((4, 4, 3), level) + 0.01 * rng.random((4, 4, 3))
    arrays = {"ours": ours, "mitsuba": np.full((4, 4, 3), level), "p_map": np.ones((4, 4)),
              "delta_e": None, "delta_itp": None, "flip": None}
    row = {"scene": scene, "passed": True, "p_value": 1.0, "found_by": [], "relmse": 0.0,
           "delta_e2000_mean": None, "delta_e_itp_mean": None, "flip_mean": None,
           "ours_spp": 64, "ours_passes": 16, "ours_seconds": 0.1, "kernel": "general",
           "reference": {"spp": 16, "passes": 4, "mitsuba_version": "3",
                         "mitsuba_variant": "v"},
           "curve": {"spp": [4, 16], "ours_rmse": [0.2, 0.1], "ours_seconds": [0.1, 0.2],
                     "mitsuba_rmse": [0.2, 0.1], "mitsuba_seconds": [0.1, 0.2]}}
    return row, arrays


def test_each_render_has_its_own_image(tmp_path):
    """Scenes whose names agree in their first 80 characters (two scene files in one
    long folder), or differ only in punctuation, or a scene named ``error``, each get
    their own panel image, named in their row: the second overwrote the first, and the
    page showed it for both (the scene ``error`` replaced the error plot)."""
    import base64
    import re

    folder = "/home/me/renderer/tests/regression-scenes/for-the-continuous-integration-gate"
    scenes = [f"{folder}/sphere_a.xml", f"{folder}/sphere_b.xml", "my-scene", "my_scene",
              "error"]
    made = [_render_row(s, 0.1 * (i + 1)) for i, s in enumerate(scenes)]
    renders = ([r for r, _ in made], {r["scene"]: a for r, a in made})
    doc = build_report(str(tmp_path), suite=None, study=None, renders=renders,
                       extra_provenance={})
    names = [r["image"] for r in doc["renders"]]
    assert len(set(names)) == len(scenes) and "render_error.png" not in names, names
    on_disk = json.loads((tmp_path / "report.json").read_text())
    assert [r["image"] for r in on_disk["renders"]] == names
    assert set(on_disk["images"]) == {*names, "render_error.png"}
    panels = {(tmp_path / n).read_bytes() for n in names}
    assert len(panels) == len(scenes)
    page = (tmp_path / "report.html").read_text()
    shown = re.findall(r'<img alt="([^"]*)" src="data:image/png;base64,([^"]*)"', page)
    by_alt = {alt: base64.b64decode(data) for alt, data in shown}
    for scene, name in zip(scenes, names):
        assert by_alt[scene] == (tmp_path / name).read_bytes(), scene


def test_cli_report_refuses_a_stale_reference_before_any_work(tmp_path, capsys,
                                                              monkeypatch):
    """A scene of --renders whose reference is stale is refused before the suite and the
    study run (it failed after them, minutes into a run); a missing one is still built
    by the render check."""
    from mcverify.gate import cli
    from mcverify.gate.report import study

    scene = tmp_path / "furnace"
    shutil.copytree(os.path.join(os.path.dirname(__file__), "..", "..", "reference",
                                 "scenes", "white-furnace"), scene)
    (scene / "scene.xml").write_text((scene / "scene.xml").read_text().replace('"0.8"',
                                                                               '"0.9"'))
    monkeypatch.setattr(study, "run_study", lambda **k: pytest.fail("the study ran"))
    rc = cli.main(["report", "--no-suite", "--renders", str(scene), "-q", "--out",
                   str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == 2 and "stale" in err and "manifest.json" in err, err
    assert not (tmp_path / "out").exists()


def test_cli_report_refuses_renders_all_of_a_folder_without_scenes(tmp_path, capsys,
                                                                    monkeypatch):
    """`--renders all` (the default) with --refs naming a folder that holds no
    NAME/scene.xml (one level off: the checkout's reference/ instead of
    reference/scenes) wrote a report without a render and exited 0. It is refused,
    naming the folder, before any work, as `reference build` refuses it."""
    from mcverify.gate import cli, reference
    from mcverify.gate.report import study

    monkeypatch.setattr(reference, "REFERENCE_ROOT", reference.REFERENCE_ROOT)
    monkeypatch.setenv("MCVERIFY_REFS", reference.REFERENCE_ROOT)
    monkeypatch.setattr(study, "run_study", lambda **k: pytest.fail("the study ran"))
    (tmp_path / "refs").mkdir()
    rc = cli.main(["report", "--no-suite", "--refs", str(tmp_path / "refs"), "-q",
                   "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == 2 and "--renders all (the default): no reference scenes" in err, err
    assert str(tmp_path / "refs") in err
    assert not (tmp_path / "out").exists()


def test_a_message_with_a_lone_surrogate_is_written_into_the_page(tmp_path):
    """A user check that raised on a non-UTF-8 file name ('scene_\\udcff.xml', as
    surrogateescape decodes it) failed `check --report`: report.json was written, then
    encoding report.html raised UnicodeEncodeError, the run exited 2 ("unexpected")
    instead of 1 and left the folder without its page. The character is written as
    the escape \\udcff, as the JUnit file writes what XML cannot hold."""
    from mcverify.result import CheckResult, SuiteResult

    failed = CheckResult("mine", False, None, None, 0.01, 1, 0.0,
                         failures=("raised OSError: cannot open scene_\udcff.xml",))
    build_report(str(tmp_path), suite=SuiteResult.judge("mine:suite", [failed], alpha=0.01,
                                                         seconds=0.0),
                 study=None)
    assert "scene_\\udcff.xml" in (tmp_path / "report.html").read_text()
    assert json.loads((tmp_path / "report.json").read_text())["verification"]["results"][0][
        "failures"] == ["raised OSError: cannot open scene_\udcff.xml"]


def test_a_page_that_cannot_be_rendered_leaves_the_old_report_whole(tmp_path, monkeypatch):
    """The page was rendered after the new report.json had replaced the old one: a
    result it could not show (a user's check returning seconds=None, "unexpected
    TypeError") left the new report.json beside the old report.html, or beside none.
    Both documents are now made before any file is written."""
    from mcverify.gate import report as report_mod
    from mcverify.result import CheckResult, SuiteResult

    def suite(name):
        r = CheckResult(name, True, 0.5, None, 0.01, 1, 0.0)
        return SuiteResult.judge("mine:suite", [r], alpha=0.01, seconds=0.0)

    build_report(str(tmp_path), suite=suite("old"), study=None)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}

    def broken(doc, images, captions=None):
        raise RuntimeError("page")

    monkeypatch.setattr(report_mod, "render_html", broken)
    study = run_study(ns=(64, 128, 256), n_seeds=4)
    with pytest.raises(RuntimeError, match="page"):
        build_report(str(tmp_path), suite=suite("new"), study=study)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


def test_every_study_estimator_evaluates_f_n_times_at_n():
    """The convergence study plots RMSE against N; its RQMC estimate at N was two
    replicates of N Sobol points each, 2N evaluations of f, plotted beside estimators
    that make N (a sqrt(2) head start in the RMSE panel and in the table's N)."""
    from mcverify.gate.report import study as study_mod

    calls = {}

    def counted(name):
        def f(x):
            calls[name] = calls.get(name, 0) + len(x)
            return np.sin(x)
        return f

    for name, (est, _, _) in study_mod._estimators().items():
        g = study_mod.Integrand("sin", counted(name), 0.0, np.pi, 2.0, "",
                                study_mod._proposals()["sin"])
        calls[name] = 0
        est(g, 256, 0)
    assert calls == {name: 256 for name in calls}, calls


def test_failed_checks_come_first(report):
    out, _ = report
    page = (out / "report.html").read_text()
    assert page.index("cosine+2%uniform") < page.index("sampler:uniform_disk_polar")


def test_page_names_the_cpu_its_times_were_measured_on(report):
    import html

    out, doc = report
    cpu = doc["provenance"]["machine"]["cpu"]
    page = (out / "report.html").read_text()
    if cpu["model"]:
        assert html.escape(f"cpu: {cpu['model']} ({cpu['llvm_cpu']})") in page
    else:
        assert "cpu: " not in page


@pytest.mark.skipif(CHROMIUM is None, reason="chromium not installed: `make setup` installs "
                    "it as root (apt-get install chromium); CI always has it")
def test_html_renders_every_image_in_headless_chromium(report, tmp_path):
    out, doc = report
    url = "file://" + os.path.abspath(out / "report.html")
    flags = ["--headless", "--no-sandbox", "--disable-gpu", "--enable-logging=stderr", "--v=0"]
    dom = subprocess.run([CHROMIUM, *flags, "--virtual-time-budget=5000", "--dump-dom", url],
                         capture_output=True, text=True, timeout=120)
    n = len(doc["images"])
    assert f'data-images="{n}/{n}"' in dom.stdout, dom.stdout[-500:]
    console_errors = [line for line in dom.stderr.splitlines()
                      if "CONSOLE" in line and ("Error" in line or "Uncaught" in line)]
    assert not console_errors, console_errors
    shot = tmp_path / "shot.png"
    subprocess.run([CHROMIUM, *flags, "--window-size=1400,2000", f"--screenshot={shot}", url],
                   capture_output=True, timeout=120)
    assert shot.exists() and shot.stat().st_size > 10_000


def _bench(tmp_path, *extra):
    out = tmp_path / "bench.json"
    r = subprocess.run([sys.executable, "-m", "mcverify", "bench", "--n", "20000",
                        "--spp", "4", "--repeats", "1", "--json", str(out), "-q", *extra],
                       capture_output=True, text=True, timeout=1800)
    assert r.returncode == 0, r.stderr
    doc = json.loads(out.read_text())
    assert "ours/theirs" in r.stdout and doc["provenance"]["mitsuba_variant"]
    machine, header, *lines = r.stdout.splitlines()
    # the first line names the processor and Mitsuba's variant the ratios were measured on
    assert machine.startswith("on ") and " cores, Mitsuba " in machine, machine
    # ... and each side's threads (ours on one thread against Mitsuba's every core was
    # not said)
    t = doc["provenance"]["threads"]
    assert machine.endswith(f"{doc['provenance']['mitsuba_variant']}; threads: ours "
                            f"{t['ours']}, Mitsuba {t['mitsuba']}"), machine
    end = header.index("ours/theirs") + len("ours/theirs")
    for line in lines:          # the ratio column ends under its header on every row
        assert line[end - 1] != " " and line[end:end + 2] == "  ", (header, line)
    rows = {row["group"]: row for row in doc["results"]}
    assert all(row["ratio"] > 0 for row in rows.values() if row["ratio"] is not None)
    return rows


def test_cli_bench_reports_ratios_of_the_judge_workloads(tmp_path):
    rows = _bench(tmp_path, "--no-render")
    assert {"warp:cosine_hemisphere", "warp:cosine_hemisphere(float32)",
            "chi2:cosine_hemisphere"} <= set(rows)
    assert not any(g.startswith(("render", "equal-time")) for g in rows)


@pytest.mark.slow
def test_cli_bench_reports_ratios(tmp_path):
    # every reference scene rendered by both renderers, and its equal-time RMSE: minutes
    rows = _bench(tmp_path)
    assert {"warp:cosine_hemisphere", "chi2:cosine_hemisphere", "render:cornell-box",
            "render:bunny", "render-check:cornell-box",
            "kernel:specialised/general", "equal-time-rmse:cornell-box"} <= set(rows)
    assert rows["kernel:specialised/general"]["against"] == "general kernel"


def test_cli_report_exits_1_when_a_check_in_it_failed(tmp_path, capsys, monkeypatch):
    """`mcverify report` exited 0 whatever its verification part found (a failed check, a
    canary not bitten), against the exit codes `mcverify --help` states: a CI job that
    publishes the report saw it pass. The report is still written; the exit is 1."""
    from mcverify.gate import cli
    from mcverify.gate.report import study as study_mod

    planted = suites.canaries(200_000)[:1]     # a cosine sampler + 2 % uniform: fails
    monkeypatch.setattr(suites, "build_suite", lambda name, *a, **kw: planted)
    monkeypatch.setattr(study_mod, "run_study", lambda **kw: run_study(
        ns=(64, 128, 256), n_seeds=4, seed=kw.get("seed", 0)))
    rc = cli.main(["report", "--renders", "none", "-q", "--out", str(tmp_path)])
    out = capsys.readouterr().out
    assert rc == 1, out
    assert f"FAIL {planted[0].name}" in out
    doc = json.loads((tmp_path / "report.json").read_text())
    assert doc["verification"]["n_failed"] == 1 and (tmp_path / "report.html").is_file()


@pytest.mark.parametrize("failing,line", [
    (None, None), ("canary", "FAIL canary toothless (not bitten)"),
    ("study", "FAIL convergence:mc:planted"), ("render", "FAIL render:cornell-box")])
def test_cli_report_exits_1_for_each_part_that_failed(tmp_path, capsys, monkeypatch,
                                                      failing, line):
    """Each part of the report that can fail decides the exit code as a failed check
    does: a canary the judge did not reject, a convergence row whose slope is off, a
    render whose check failed (each alone, with every other part passing), and 0 where
    all pass. Until an outside mutation review, only a failed check was tested: the
    lines adding the other three to the failures could go and every test passed."""
    from mcverify.gate import cli
    from mcverify.gate import report as report_pkg
    from mcverify.gate.report import renders as renders_mod
    from mcverify.gate.report import study as study_mod
    from mcverify.result import CheckResult

    def check(name, passed, tags=()):
        result = CheckResult(name, passed, 0.5 if passed else 1e-9, 0.0, 0.01, 10, 0.0)
        return suites.Check(name, lambda seed, stop_alpha=None: result, tags,
                            sequential=True)

    monkeypatch.setattr(suites, "build_suite", lambda name, *a, **kw: [check("ok", True)])
    monkeypatch.setattr(suites, "canaries", lambda *a, **kw: [
        check("toothless", failing == "canary", ("canary",))])
    monkeypatch.setattr(study_mod, "run_study", lambda **kw: [
        {"estimator": "mc", "integrand": "planted", "passed": failing != "study"}])
    monkeypatch.setattr(renders_mod, "run_renders", lambda scenes, **kw: (
        [{"scene": s, "passed": failing != "render"} for s in scenes], {}))
    monkeypatch.setattr(report_pkg, "prepare_report", lambda out, **kw: (None, lambda: None))
    monkeypatch.setattr(cli, "_variant_provenance", lambda: {})
    rc = cli.main(["report", "--renders", "cornell-box", "-q", "--out", str(tmp_path)])
    out = capsys.readouterr().out
    fails = [l for l in out.splitlines() if l.startswith("FAIL")]
    assert (rc, fails) == ((0, []) if failing is None else (1, [line])), out


@pytest.mark.parametrize("panel", ["convergence", "efficiency"])
def test_an_estimator_has_one_colour_in_every_panel(monkeypatch, panel):
    """Each panel coloured its own rows in turn: where an integrand lacked an estimator,
    one colour meant different estimators in different panels (an outside review)."""
    from mcverify.gate.report import plots

    figs = []
    monkeypatch.setattr(plots, "_png", lambda fig: figs.append(fig) or b"")
    row = dict(ns=[64, 256], rmse=[0.1, 0.05], slope=-0.5, ci=[-0.6, -0.4],
               seconds=[1e-3, 4e-3], efficiency=[1.0, 1.0])
    rows = [dict(row, integrand=g, estimator=e) for g, es in
            (("smooth", ("uniform", "rqmc", "stratified")), ("step", ("rqmc", "stratified")))
            for e in es]
    getattr(plots, panel)(rows)
    colour = {}
    for ax in figs[0].axes:
        for line in ax.get_lines():
            name = line.get_label().split(":")[0]
            if name in ("uniform", "rqmc", "stratified"):
                assert colour.setdefault(name, line.get_color()) == line.get_color(), name
    assert len(colour) == 3 and len(set(colour.values())) == 3


@pytest.mark.parametrize("name", ["cost $\\frac$ 5", "$x^2$ sampler"])
def test_a_check_name_with_dollar_signs_is_drawn_as_text(tmp_path, monkeypatch, name):
    """matplotlib read a failed check's name as mathtext in its histogram's title: a name
    such as 'cost $\\frac$ 5' ended `check --report` with "unexpected ValueError" after
    the run, with no report, JSON or JUnit file; '$x^2$' was drawn as x²."""
    import mcverify as mv
    from mcverify.gate.report import plots
    from mcverify.result import SuiteResult

    r = mv.check_sampler(lambda u: np.sqrt(u[:, :1]), lambda x: np.ones(len(x)), "interval",
                         n_samples=20_000, seed=0, name=name)
    assert not r.passed and "histogram" in r.artifacts
    titles, png = [], plots._png
    monkeypatch.setattr(plots, "_png", lambda fig: titles.append(fig._suptitle) or png(fig))
    build_report(str(tmp_path), study=None, extra_provenance={},
                 suite=SuiteResult.judge("mine:suite", [r], alpha=0.01, seconds=0.0))
    (title,) = titles
    assert title.get_text() == name and not title.get_parse_math()
    doc = json.loads((tmp_path / "report.json").read_text())
    (image,) = [n for n in doc["images"] if n.startswith("failed_")]
    assert (tmp_path / image).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_render_curves_plot_both_renderers_at_the_samples_mitsuba_renders(monkeypatch):
    """vocabulary-geometry's orthogonal sampler renders 25 samples where 16 are asked:
    the report's error-against-spp panel plotted Mitsuba's RMSE of 25 samples at 16,
    beside ours of 16 (a head start of 1.56x the samples). Both sides now render, and the
    curve records, the count Mitsuba's sampler renders."""
    import estimators.pathtracer as pt
    from types import SimpleNamespace

    from mcverify.gate import render_check as rc_mod

    asked = []

    def ours(scene, spp, seed, **kw):
        asked.append(spp)
        return SimpleNamespace(mean=np.full((scene.height, scene.width, 3), 7.0), seconds=0.1)

    told = []

    def check(path, seed, notice=None):
        told.append(notice)
        return SimpleNamespace(passed=True, p_value=1.0, artifacts={
            "ours": None, "mitsuba": None, "p_map": None}, details={
            "found_by": [], "relmse": 0.0, "ours_spp": 1, "ours_passes": 1,
            "ours_seconds": 0.1, "ours_kernel": "general", "reference": {}})

    monkeypatch.setattr(pt, "render", ours)
    monkeypatch.setattr(rc_mod, "render_check", check)
    # each curve's "RMSE" the mean of the image it was given: ours is 7 everywhere
    from mcverify.gate import reference as reference_mod

    monkeypatch.setattr(reference_mod, "load_reference",
                        lambda path: SimpleNamespace(rmse=lambda img: float(np.mean(img))))
    rows, _ = run_renders(["vocabulary-geometry"], spps=(4, 16), notice=print)
    assert rows[0]["curve"]["spp"] == [4, 25]
    # Mitsuba's curve is of Mitsuba's renders (a mutation review: our RMSE recorded as
    # Mitsuba's lived through every test)
    curve = rows[0]["curve"]
    assert curve["ours_rmse"] == [7.0, 7.0]
    assert 0 < min(curve["mitsuba_rmse"]) and 7.0 not in curve["mitsuba_rmse"]
    assert asked == [2, 4, 25]        # the warm-up, then the curve's two renders
    # the render check's notices (a reference built, Mitsuba's fallback) reach the
    # caller: `report --renders` built a missing reference silently until 7 December
    assert told == [print]


@pytest.mark.parametrize("old", [False, True])
def test_check_refuses_an_output_named_as_a_report_image(tmp_path, capsys, old):
    """A failed check's histogram is named only once the run has judged it: `check
    --report rep --junit rep/failed_x.png` wrote the JUnit file, then the histogram over
    it, exit 1 without a word; and a --junit named as the last report's image was
    written, then removed with that report's images. Both now exit 2, the same file,
    with nothing written."""
    import types

    import mcverify as mv
    from mcverify.gate import cli
    from mcverify.gate.suites import Check

    def run(seed):
        return mv.check_sampler(lambda u: np.sqrt(u[:, :1]), lambda x: np.ones(len(x)),
                                "interval", n_samples=20_000, seed=seed, name="x")

    rep = tmp_path / "rep"
    name = "failed_old.png" if old else "failed_x.png"
    if old:
        build_report(str(rep), suite=None, study=None, extra_provenance={})
        doc = json.loads((rep / "report.json").read_text())
        doc["images"][name] = name
        (rep / "report.json").write_text(json.dumps(doc))
        (rep / name).write_bytes(b"old")
    before = {p.name: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    mod = types.ModuleType("image_named_suite")
    mod.suite = [Check("x", run)]
    sys.modules[mod.__name__] = mod
    try:
        rc = cli.main(["check", "-q", "--suite", "image_named_suite:suite", "--report",
                       str(rep), "--junit", str(rep / name)])
    finally:
        del sys.modules[mod.__name__]
    err = capsys.readouterr().err
    assert rc == 2 and "the same file" in err and name in err, err
    assert {p.name: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before


def test_a_long_name_of_wide_letters_gets_an_image_file_name_that_fits(tmp_path):
    """The histogram's file name kept 80 letters of a failed check's name: 80 letters of
    4 bytes ('𝐀', mathematical bold) made a name of 331 bytes, past the file system's
    255, and `check --report --json` failed after the run with "File name too long",
    its --json written and no report. Names are now cut at 160 bytes too."""
    import mcverify as mv
    from mcverify.result import SuiteResult

    results = [mv.check_sampler(lambda u: np.sqrt(u[:, :1]), lambda x: np.ones(len(x)),
                                "interval", n_samples=20_000, seed=0, name="\U0001D400" * k)
               for k in (90, 91)]
    build_report(str(tmp_path), study=None, extra_provenance={},
                 suite=SuiteResult.judge("mine:suite", results, alpha=0.01, seconds=0.0))
    images = [n for n in json.loads((tmp_path / "report.json").read_text())["images"]]
    assert len(images) == 2 and all(len(n.encode()) <= 255 for n in images), images
    for n in images:
        assert (tmp_path / n).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_fifo_named_report_json_is_written_into_not_read(tmp_path):
    """A FIFO named report.json (the JSON piped to another program) is written into, as
    every output FIFO is; the report first opened it for reading, to find the last
    report's images, and the run hung there (a reader waiting for a writer)."""
    fifo = tmp_path / "out" / "report.json"
    fifo.parent.mkdir()
    os.mkfifo(fifo)
    script = (
        "import sys, threading\n"
        "from mcverify.gate.report import build_report\n"
        "got = []\n"
        "def read():\n"
        f"    with open({str(fifo)!r}, 'rb') as f: got.append(f.read())\n"
        "t = threading.Thread(target=read); t.start()\n"
        f"build_report({str(fifo.parent)!r}, suite=None, study=None, extra_provenance={{}})\n"
        "t.join(); sys.stdout.write(got[0].decode())\n")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["verification"] is None
    assert (tmp_path / "out" / "report.html").is_file()


def test_the_page_names_each_failed_check_under_its_histogram_and_says_why(tmp_path):
    """Under a failed check's histogram the page wrote its file name (failed__a_b_.png),
    the same for checks whose names differ only in punctuation; a check failing on its
    p-value alone had an empty "why" cell, and one without a sample count read "None"."""
    import mcverify as mv
    from mcverify.result import CheckResult, SuiteResult

    def bad(name):
        return mv.check_sampler(lambda u: np.sqrt(u[:, :1]), lambda x: np.ones(len(x)),
                                "interval", n_samples=20_000, seed=0, name=name)

    plain = CheckResult("mine<&>", False, 1e-9, 1.0, 0.01, None, 0.0)
    checks = [bad("<a&b>"), bad("(a b)"), plain]
    build_report(str(tmp_path), study=None, extra_provenance={},
                 suite=SuiteResult.judge("mine:suite", checks, alpha=0.01, seconds=0.0))
    page = (tmp_path / "report.html").read_text()
    for name in ("&lt;a&amp;b&gt;", "(a b)"):
        assert f"<figcaption>{name}: histogram" in page
    row = page[page.index("<td>mine&lt;&amp;&gt;</td>"):].split("</tr>")[0]
    assert "None" not in row and "≤ family-wise α 0.01" in row


def test_the_convergence_table_states_its_intervals_confidence(report):
    out, doc = report
    page = (out / "report.html").read_text()
    assert "CI (confidence)" in page
    assert all(r["ci_confidence"] == pytest.approx(0.99) for r in doc["convergence"])
    assert " (99 %)</td>" in page


def test_a_report_keeps_the_caller_s_matplotlib_backend_and_figures(tmp_path, run_python):
    """A program or notebook with its own backend and figures makes a report: the plots
    called ``matplotlib.use("Agg")``, which switched the caller's backend for the rest
    of the process (an interactive one's ``plt.show()`` then showed nothing; an outside
    review). Run in a fresh process, as the backend is the process's."""
    script = (
        "import matplotlib\n"
        "matplotlib.use('svg')\n"
        "import matplotlib.pyplot as plt\n"
        "plt.plot([1, 2])\n"
        "import numpy as np, mcverify as mv\n"
        "from mcverify.gate.report import build_report\n"
        "from mcverify.result import SuiteResult\n"
        "r = mv.check_sampler(lambda u: np.sqrt(u), lambda x: np.ones(len(x)), 'interval',\n"
        "                     n_samples=20_000, seed=0, name='sqrt')\n"
        "suite = SuiteResult.judge('mine', [r], alpha=0.01, seconds=0.0)\n"
        f"doc = build_report({str(tmp_path)!r}, suite=suite, study=None, extra_provenance={{}})\n"
        "assert 'failed_sqrt.png' in doc['images'], doc['images']\n"
        "print(matplotlib.get_backend(), plt.get_fignums())\n")
    assert run_python(script) == "svg [1]"
    assert (tmp_path / "failed_sqrt.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_report_is_drawn_alike_whatever_the_caller_s_rcparams(tmp_path):
    """A caller's own matplotlib style (a notebook's font size, ``text.usetex``) reached
    the report's plots: with ``text.usetex = True`` every plot was a LaTeX run, and
    without LaTeX installed ``build_report`` raised "latex could not be found" (an
    outside review). The plots are drawn in matplotlib's default style, the caller's
    rcParams left as they were."""
    import matplotlib

    import mcverify as mv
    from mcverify.result import SuiteResult

    r = mv.check_sampler(lambda u: np.sqrt(u), lambda x: np.ones(len(x)), "interval",
                         n_samples=20_000, seed=0, name="sqrt_x $5")
    suite = SuiteResult.judge("mine", [r], alpha=0.01, seconds=0.0)
    plain = build_report(str(tmp_path / "plain"), suite=suite, study=None,
                         extra_provenance={})
    (image,) = plain["images"]
    theirs = {"text.usetex": True, "font.size": 23.0, "axes.facecolor": "black"}
    with matplotlib.rc_context(theirs):
        build_report(str(tmp_path / "styled"), suite=suite, study=None, extra_provenance={})
        assert {k: matplotlib.rcParams[k] for k in theirs} == theirs
    assert (tmp_path / "styled" / image).read_bytes() == (tmp_path / "plain" / image).read_bytes()


@pytest.mark.parametrize("extra,needle", [
    (["-j", "2"], "-j 2: runs the suite's checks on worker processes"),
    (["--dask", "tcp://127.0.0.1:1"], "--dask tcp://127.0.0.1:1: runs the suite's checks"),
    (["--suite", "full"], "--suite full: the suite's checks"),
], ids=["jobs", "dask", "suite"])
def test_cli_report_refuses_suite_options_with_no_suite(tmp_path, capsys, extra, needle):
    """`report --no-suite` ran its convergence study and renders in this process whatever
    -j, --dask or --suite said (they apply to the suite's checks alone), and wrote the
    report, exit 0, as if they had been used; -k was refused there already."""
    from mcverify.gate.cli import main

    rc = main(["report", "--no-suite", "--renders", "none", "-q", "--out",
               str(tmp_path / "rep"), *extra])
    err = capsys.readouterr().err
    assert rc == 2 and needle in err and "--no-suite" in err, err
    assert not (tmp_path / "rep").exists()


def test_cli_report_renders_a_scene_named_twice_once(tmp_path, capsys, monkeypatch):
    """`--renders white-furnace,reference/scenes/white-furnace/` rendered the scene twice
    and listed it as two rows of the report (each scene was kept once by its spelling
    alone), where `reference build` builds such a scene once."""
    from mcverify.errors import InvalidArgument
    from mcverify.gate import cli, reference
    from mcverify.gate.report import renders, study

    monkeypatch.setattr(study, "run_study", lambda **k: [])
    rendered = []

    def run_renders(scenes, **kw):
        rendered.extend(scenes)
        raise InvalidArgument("stop here")

    monkeypatch.setattr(renders, "run_renders", run_renders)
    monkeypatch.setattr(cli, "_variant_provenance", lambda: {})
    folder = os.path.join(reference.REFERENCE_ROOT, "white-furnace")
    rc = cli.main(["report", "--no-suite", "--renders",
                   f"white-furnace,{folder}{os.sep},{folder}/scene.xml", "-q",
                   "--out", str(tmp_path / "out")])
    assert rc == 2 and "stop here" in capsys.readouterr().err
    assert rendered == ["white-furnace"]


def test_control_characters_in_a_message_are_escaped_in_the_page(tmp_path):
    """A check that raised with an ANSI colour code (quoting a tool's coloured output),
    a BEL or a NUL put them into report.html raw: NUL shown as U+FFFD, the escape
    invisible, and an HTML validator refused the page (an outside review). They are
    written as escapes, as the JUnit file writes them; the JSON keeps the text."""
    from mcverify.result import CheckResult, SuiteResult

    failed = CheckResult("mine\x07", False, None, None, 0.01, 1, 0.0,
                         failures=("raised RuntimeError: \x1b[31mno\x1b[0m GPU\x00",))
    build_report(str(tmp_path), suite=SuiteResult.judge("mine:suite", [failed], alpha=0.01,
                                                         seconds=0.0),
                 study=None)
    page = (tmp_path / "report.html").read_text()
    assert "\\x1b[31mno\\x1b[0m GPU\\x00" in page and "mine\\x07" in page
    assert not any(c in page for c in "\x1b\x07\x00")
    assert json.loads((tmp_path / "report.json").read_text())["verification"]["results"][0][
        "failures"] == ["raised RuntimeError: \x1b[31mno\x1b[0m GPU\x00"]


def test_the_study_takes_its_ns_in_increasing_order():
    """``run_study(ns=(1024, 64, 256))`` kept that order: the page's "efficiency at the
    largest N" read N = 256's, and the plots zigzagged (a mutation review's
    found-not-fixed). Each row's ``ns`` is increasing, its numbers in that order."""
    from mcverify.gate.report import study as study_mod

    rows = study_mod.run_study(ns=(1024, 64, 256), n_seeds=4, seed=3)
    assert all(r["ns"] == [64, 256, 1024] for r in rows)
    again = study_mod.run_study(ns=(64, 256, 1024), n_seeds=4, seed=3)
    assert [r["rmse"] for r in rows] == [r["rmse"] for r in again]


def test_the_study_s_numbers_are_its_checks_judged_together(monkeypatch):
    """Each study row as its docstring and the page state it (a mutation review: every
    one of these could be wrong with no test failing): the interval of the row's own
    check_convergence at its level (99 %), stated as ci_confidence whatever the table's
    alpha (0.2 here); p adjusted by Holm across the whole table, the verdict p adjusted >
    alpha; seconds the median time per estimate; efficiency 1 / (MSE * seconds)."""
    from types import SimpleNamespace

    import mcverify as mv
    from mcverify.gate.report import study as study_mod
    from mcverify.stats import holm

    clock = SimpleNamespace(t=0.0, calls=0)

    def perf_counter():     # each N's 4 estimates take 1, 1, 1 and 100 s: median 1
        clock.calls += 1
        if clock.calls % 2 == 0:
            clock.t += 100.0 if clock.calls % 8 == 0 else 1.0
        return clock.t

    monkeypatch.setattr(study_mod, "time", SimpleNamespace(perf_counter=perf_counter))
    ns = (64, 256, 1024)
    rows = study_mod.run_study(ns=ns, n_seeds=4, seed=3, alpha=0.2)
    uniform = study_mod._estimators()["uniform"][0]
    (g,) = [g for g in study_mod.integrands() if g.name == "sin on [0, pi]"]
    own = mv.check_convergence(lambda n, s: uniform(g, n, s), g.truth, ns=ns, n_seeds=4,
                               seed=3)
    (row,) = [r for r in rows if r["integrand"] == g.name and r["estimator"] == "uniform"]
    assert row["ci"] == pytest.approx(own.details["ci"], rel=1e-12)
    assert row["slope"] == pytest.approx(own.details["slope"], rel=1e-12)
    assert [r["ci_confidence"] for r in rows] == pytest.approx([0.99] * len(rows))
    adjusted = holm([r["p_value"] for r in rows])
    assert [r["p_adjusted"] for r in rows] == pytest.approx(list(adjusted), rel=1e-12)
    assert [r["passed"] for r in rows] == [bool(p > 0.2) for p in adjusted]
    for r in rows:
        assert r["seconds"] == [1.0] * len(ns)
        rmse = np.asarray(r["rmse"])
        assert r["efficiency"] == pytest.approx(list(1.0 / rmse ** 2), rel=1e-12)


def _page_rows(page: str, head: str) -> list[str]:
    """The rows (``<tr …>…</tr>``) of the table whose header row starts with ``head``."""
    table = page[page.index(f"<table><tr><th>{head}</th>"):].split("</table>")[0]
    return table.split("<tr")[2:]


def test_the_page_shows_each_row_s_own_numbers_and_verdict():
    """Each table row of the page is its own result's: slope, verdict and efficiency at
    the largest N of that study row; each check's verdict and the suite's counts; the
    canaries' state; a render's passes and spp; a scene's name escaped in its row and in
    its image's alt text (a mutation review: another row's slope or verdict, the
    efficiency at the smallest N, a failed check counted as passed, canaries read the
    other way and raw scene names all lived through every test)."""
    from mcverify.gate.report import render_html
    from mcverify.result import CheckResult, SuiteResult

    checks = [CheckResult("good", True, 0.5, 1.0, 0.01, 100, 0.0),
              CheckResult("bad", False, 1e-9, 1.0, 0.01, 100, 0.0)]
    conv = dict(ns=[64, 256, 1024], ci_confidence=0.99, expected_slope=-0.5,
                alternative="two-sided", integrand="sin")
    study = [dict(conv, estimator="uniform", slope=-0.512, ci=[-0.6, -0.4], passed=True,
                  p_adjusted=0.8, efficiency=[1.0, 2.0, 3.5]),
             dict(conv, estimator="broken", slope=-0.25, ci=[-0.3, -0.2], passed=False,
                  p_adjusted=1e-6, efficiency=[4.0, 5.0, 6.5])]
    scene = "<b>box</b>"
    render = dict(scene=scene, passed=True, p_value=0.4, found_by=[], relmse=0.01,
                  delta_e2000_mean=None, delta_e_itp_mean=None, flip_mean=None,
                  ours_passes=3, ours_spp=64, ours_seconds=1.0, kernel="general",
                  image="render_x.png", reference=dict(mitsuba_version="3", spp=1024,
                                                       passes=8, mitsuba_variant="v"))
    images = dict.fromkeys(["convergence.png", "efficiency.png", "render_error.png",
                            "render_x.png"], b"png")
    for bitten in (True, False):
        suite = SuiteResult.judge("mine", checks, alpha=0.01, seconds=0.0, canary=(
            CheckResult("canary", not bitten, 0.5, 1.0, 0.01, 100, 0.0),))
        doc = dict(provenance={}, verification=suite.to_dict(), convergence=study,
                   renders=[render])
        page = render_html(doc, images)
        assert ("canaries bitten;" in page) == bitten
        assert ("canaries <b>NOT bitten</b>;" in page) == (not bitten)
    assert "<b>mine</b>: 1 passed, 1 failed," in page
    bad, good = _page_rows(page, "check")
    assert "<td>bad</td><td>FAIL</td>" in bad and "<td>good</td><td>pass</td>" in good
    uniform, broken = _page_rows(page, "integrand")
    assert "<td>-0.512</td>" in uniform and "<td>as expected</td><td>3.5</td>" in uniform
    assert "<td>-0.250</td>" in broken and "<td>NOT</td><td>6.5</td>" in broken
    (row,) = _page_rows(page, "scene")
    assert "<td>&lt;b&gt;box&lt;/b&gt;</td>" in row and "<td>3 passes, 64 spp" in row
    assert "8 × 1024 spp" in row
    assert scene not in page and 'alt="&lt;b&gt;box&lt;/b&gt;"' in page


def _drawn(monkeypatch):
    """The figures the report's plots draw, in order (their PNGs still made)."""
    from mcverify.gate.report import plots

    figs, png = [], plots._png
    monkeypatch.setattr(plots, "_png", lambda fig: figs.append(fig) or png(fig))
    return figs


def test_a_histogram_draws_its_own_check_s_counts(monkeypatch):
    """Observed, expected and (O - E)/sqrt(E) panels of a histogram, 1-D and 2-D, hold the
    check's own counts (a mutation review: observed and expected swapped, (O - E)/E,
    lived through every test)."""
    from mcverify.gate.report import plots

    figs = _drawn(monkeypatch)
    obs, exp = np.array([10.0, 30.0, 20.0, 41.0]), np.full(4, 25.0)
    plots.histogram({"name": "one", "artifacts": {"histogram": {
        "observed": obs, "expected": exp, "edges": [np.linspace(0, 1, 5)]}}})
    ax = figs[0].axes
    assert np.array_equal(ax[0].lines[0].get_ydata(), obs)
    assert np.array_equal(ax[1].lines[0].get_ydata(), exp)
    assert np.allclose(ax[2].lines[0].get_ydata(), (obs - exp) / 5.0)
    obs2, exp2 = np.array([[1.0, 9.0, 4.0], [16.0, 0.0, 4.0]]), np.full((2, 3), 4.0)
    plots.histogram({"name": "two", "artifacts": {"histogram": {
        "observed": obs2, "expected": exp2, "edges": [[0, 1, 2], [0, 1, 2, 3]]}}})
    ax = figs[1].axes
    assert np.array_equal(ax[0].images[0].get_array(), obs2)
    assert np.array_equal(ax[1].images[0].get_array(), exp2)
    assert np.allclose(ax[2].images[0].get_array(), np.clip((obs2 - exp2) / 2.0, -6, 6))


def test_each_failed_check_s_histogram_is_drawn_from_that_check(tmp_path, monkeypatch):
    """Two failed checks, two histograms, each of its own check (a mutation review: every
    histogram drawn from the suite's first check lived through every test)."""
    import mcverify as mv
    from mcverify.result import SuiteResult

    def bad(name, power):
        return mv.check_sampler(lambda u: u[:, :1] ** power, lambda x: np.ones(len(x)),
                                "interval", n_samples=20_000, seed=0, name=name)

    checks = [bad("sqrt", 0.5), bad("square", 2.0)]
    figs = _drawn(monkeypatch)
    build_report(str(tmp_path), study=None, extra_provenance={},
                 suite=SuiteResult.judge("mine:suite", checks, alpha=0.01, seconds=0.0))
    assert [f._suptitle.get_text() for f in figs] == ["sqrt", "square"]
    for fig, check in zip(figs, checks):
        observed = np.asarray(check.artifacts["histogram"]["observed"], float)
        assert np.array_equal(fig.axes[0].lines[0].get_ydata(), observed)


def test_the_study_and_render_plots_draw_each_row_s_numbers(monkeypatch):
    """The convergence panel's legend gives the slope and both ends of its interval, its
    N^-1/2 guide falls from uniform's first RMSE; the render panel plots each renderer's
    RMSE against its own seconds (a mutation review: the interval's upper end drawn as its
    lower, a guide of N^-1, Mitsuba's RMSE at our seconds lived through every test)."""
    from mcverify.gate.report import plots

    figs = _drawn(monkeypatch)
    plots.convergence([dict(integrand="sin", estimator="uniform", ns=[64, 256, 1024],
                            rmse=[0.2, 0.1, 0.05], slope=-0.5, ci=[-0.61, -0.42])])
    ax = figs[0].axes[0]
    assert [line.get_label() for line in ax.lines] == ["uniform: -0.50 [-0.61, -0.42]",
                                                       "N^-1/2"]
    assert np.allclose(ax.lines[1].get_ydata(), [0.2, 0.1, 0.05])
    curve = dict(spp=[4, 16], ours_rmse=[0.2, 0.1], mitsuba_rmse=[0.3, 0.15],
                 ours_seconds=[1.0, 2.0], mitsuba_seconds=[5.0, 7.0])
    plots.render_error([dict(scene="box", curve=curve)])
    for ax, x in zip(figs[1].axes, ("spp", "seconds")):
        for line, who in zip(ax.lines, ("ours", "mitsuba")):
            xs = curve["spp"] if x == "spp" else curve[f"{who}_seconds"]
            assert line.get_label() == who
            assert np.array_equal(line.get_xdata(), xs)
            assert np.array_equal(line.get_ydata(), curve[f"{who}_rmse"])
