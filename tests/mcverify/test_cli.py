"""The CLI runs as a real subprocess: output, exit codes, files."""

import json
import subprocess
import sys

import pytest

CMD = [sys.executable, "-m", "mcverify"]


def run(*args, timeout=600):
    return subprocess.run(CMD + list(args), capture_output=True, text=True, timeout=timeout)


def test_check_writes_the_html_report_of_its_results(tmp_path):
    """``check --report DIR`` (DESIGN.md's CLI contract; it did not exist): the same
    results as ``--json``, in report.json and report.html; a path that cannot be a
    report folder is refused before any work, naming --report."""
    out, js = tmp_path / "rep", tmp_path / "r.json"
    r = run("check", "-k", "uniform_disk_polar", "--json", str(js), "--report", str(out),
            "-q")
    assert r.returncode == 0, r.stdout + r.stderr
    assert f"wrote {out / 'report.html'}" in r.stdout
    doc = json.loads((out / "report.json").read_text())
    plain = json.loads(js.read_text())
    assert [x["name"] for x in doc["verification"]["results"]] == \
        [x["name"] for x in plain["results"]]
    assert [x["p_value"] for x in doc["verification"]["results"]] == \
        [x["p_value"] for x in plain["results"]]
    assert "uniform_disk_polar" in (out / "report.html").read_text()
    (tmp_path / "file").write_text("x")
    for bad, needle in (("", "--report '': empty path"),
                        (str(tmp_path / "file"), "--report")):
        r = run("check", "-k", "uniform_disk_polar", "--report", bad, "-q")
        assert r.returncode == 2 and needle in r.stderr and "Traceback" not in r.stderr, \
            r.stderr


def test_check_subset_passes_writes_json_and_is_deterministic(tmp_path):
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    r = run("check", "-k", "uniform_disk_polar", "--json", str(a), "--junit",
            str(tmp_path / "r.xml"), "-q")
    assert r.returncode == 0, r.stdout + r.stderr
    # sampler, inverse, stability and pdf-consistency checks
    assert "4 passed, 0 failed" in r.stdout and "canaries bitten" in r.stdout
    run("check", "-k", "uniform_disk_polar", "--json", str(b), "-q")
    ra, rb = (json.loads(p.read_text()) for p in (a, b))
    assert [x["p_value"] for x in ra["results"]] == [x["p_value"] for x in rb["results"]]
    assert ra["provenance"]["seed"] == 0 and "utc_time" in ra["provenance"]
    assert (tmp_path / "r.xml").exists()


@pytest.mark.parametrize("args,needle", [
    (["check", "--suite", "nightly"], "--suite"),
    (["check", "-k", "no-such-check"], "-k 'no-such-check': matches no check of suite "
                                        "'default'"),
    (["list", "-k", "no-such-check"], "-k 'no-such-check': matches no check of suite "
                                       "'default'"),
    (["check", "--alpha", "2"], "--alpha 2.0"),
    (["check", "--seed", "-3"], "--seed -3"),
    # Python's int() reads these; a seed on a command line is decimal digits only
    (["check", "--seed", "1_0"], "invalid int value: '1_0'"),
    (["check", "--seed", "\uff11"], "invalid int value"),
    (["check", "--json", "/proc/forbidden/x.json"], "--json /proc/forbidden/x.json"),
    (["frobnicate"], "invalid choice"),
    (["report", "--out", "/proc/forbidden/rep"], "--out /proc/forbidden/rep"),
    (["bench", "--repeats", "0"], "--repeats 0"),
    (["bench", "--n", "10"], "--n 10"),
    # more points than memory: numpy's "unexpected MemoryError", naming no option
    (["bench", "--no-render", "--n", "10000000000000"], "--n=10000000000000: needs about"),
], ids=["suite", "pattern", "list-pattern", "alpha", "seed", "seed-underscore",
        "seed-fullwidth", "json-path", "command", "report-out", "bench-repeats", "bench-n",
        "bench-n-memory"])
def test_bad_input_is_one_line_exit_2(args, needle):
    r = run(*args)
    assert r.returncode == 2
    assert needle in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_list_names_checks():
    r = run("list", "-k", "inverse:")
    assert r.returncode == 0 and "inverse:cosine_hemisphere" in r.stdout


def test_a_reader_that_leaves_early_ends_the_run_quietly():
    """``mcverify list | head -3``: the reader closes the pipe; the CLI stops with 141
    (128 + SIGPIPE, as a shell reports it) and no message. It printed "mcverify: error:
    Broken pipe" and exited 2, which reads as bad input (an outside review)."""
    import os

    read, write = os.pipe()
    os.close(read)                  # the reader is gone before the first line
    try:
        r = subprocess.run(CMD + ["list"], stdout=write, stderr=subprocess.PIPE, text=True,
                           timeout=120)
    finally:
        os.close(write)
    assert r.returncode == 141, r.stderr
    assert r.stderr == ""


def test_k_selects_a_name_that_contains_glob_characters():
    """-k's help says "checks whose name contains PATTERN (or matches it as a glob)", but a
    pattern with [ ] was read as a glob alone: a user's check named 'bsdf[ggx]' could not
    be selected by its own name (the glob's [ggx] is one character), exit 2."""
    from mcverify.gate.suites import Check, select

    checks = [Check(n, lambda seed: None) for n in ("bsdf[ggx]", "bsdf[beckmann]",
                                                    "bsdfy", "light*2", "light-2")]
    names = lambda k: [c.name for c in select(checks, k)]     # noqa: E731
    assert names("bsdf[ggx]") == ["bsdf[ggx]"]
    assert names("[ggx]") == ["bsdf[ggx]"]
    assert names("bsdf[y]") == ["bsdfy"]                # still a glob too
    assert names("light*2") == ["light*2", "light-2"]
    assert names("light?2") == ["light*2", "light-2"]


def test_the_error_line_escapes_control_characters(monkeypatch, capsys):
    """A message holding a user's ANSI escape or BEL (an exception's text) reached the
    terminal raw, where it acted instead of showing; it is written as its escape, as in
    the JUnit file."""
    from mcverify.errors import InvalidArgument
    from mcverify.gate import cli

    def bad(args):
        raise InvalidArgument("no \x1b[31mGPU\x07 here\x9b")

    monkeypatch.setattr(cli, "_validate_common", bad)
    assert cli.main(["list"]) == 2
    err = capsys.readouterr().err
    assert "no \\x1b[31mGPU\\x07 here\\x9b" in err
    assert not any(c in err for c in "\x1b\x07\x9b")


def test_a_terminal_that_is_not_utf8_gets_the_verdict_and_the_json(tmp_path):
    """On a terminal whose encoding has no '≈' (PYTHONIOENCODING=ascii stands for a
    Latin-1 locale or a Windows console) a failing check's message "largest discrepancy
    at x≈[...]" raised UnicodeEncodeError while it was printed: exit 2, "unexpected
    UnicodeEncodeError", instead of 1, and no --json. The character is now escaped."""
    import os

    (tmp_path / "latin1_suite.py").write_text(
        "import numpy as np, mcverify\n"
        "from mcverify.gate.suites import Check\n"
        "def bad(seed, stop_alpha=None):\n"
        "    return mcverify.check_sampler(lambda u: np.sqrt(u[:, :1]),\n"
        "        lambda x: np.ones(len(x)), mcverify.Interval(0, 1), sample_dim=1,\n"
        "        n_samples=20_000, seed=seed, name='bad')\n"
        "suite = [Check('my.bad', bad)]\n", encoding="utf-8")
    env = dict(os.environ, PYTHONIOENCODING="ascii",
               PYTHONPATH=os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")]))
    out = tmp_path / "run.json"
    r = subprocess.run(CMD + ["check", "--suite", "latin1_suite:suite", "--json", str(out)],
                       capture_output=True, text=True, timeout=600, env=env, cwd=tmp_path)
    assert r.returncode == 1, r.stderr
    assert "UnicodeEncodeError" not in r.stderr + r.stdout
    assert "x\\u2248" in r.stderr + r.stdout
    doc = json.loads(out.read_text(encoding="utf-8"))
    assert doc["passed"] is False and doc["n_failed"] == 1


@pytest.mark.parametrize("value", ["0", "-2"])
def test_a_numba_thread_count_numba_refuses_exits_2_naming_it(value):
    """numba raises ValueError as it is imported where NUMBA_NUM_THREADS is 0 or negative:
    the command printed numba's traceback and exited 1, which CI reads as a failed check.
    It now exits 2 with one line naming the variable; an import names it too."""
    import os

    env = dict(os.environ, NUMBA_NUM_THREADS=value)
    r = subprocess.run(CMD + ["list"], capture_output=True, text=True, timeout=600, env=env)
    assert r.returncode == 2 and r.stdout == ""
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert f"NUMBA_NUM_THREADS='{value}'" in r.stderr and "whole number >= 1" in r.stderr
    r = subprocess.run([sys.executable, "-c", "import mcverify"], capture_output=True,
                       text=True, timeout=600, env=env)
    assert r.returncode == 1
    assert "EnvironmentProblem: numba cannot start" in r.stderr.strip().splitlines()[-1]


@pytest.mark.parametrize("layer, needle", [("bogus", "unknown to Numba"),
                                           ("tbb", "No threading layer could be loaded")])
def test_a_threading_layer_numba_cannot_load_exits_2_naming_it(layer, needle):
    """NUMBA_THREADING_LAYER misspelt, or tbb without TBB installed: numba raised inside
    the first check that ran a parallel loop, which failed ("raised ValueError: ...",
    exit 1) as if the warp were wrong. The run now stops before any work, exit 2."""
    import os

    env = dict(os.environ, NUMBA_THREADING_LAYER=layer)
    if layer == "tbb":      # loadable where a system libtbb is (no Python package needed)
        probe = subprocess.run([sys.executable, "-c", "from numba.np.ufunc import parallel; "
                                "parallel._launch_threads()"], capture_output=True, env=env)
        if probe.returncode == 0:
            pytest.skip("numba loads the TBB threading layer here")
    r = subprocess.run(CMD + ["check", "-k", "sampler:cosine_hemisphere", "-q"],
                       capture_output=True, text=True, timeout=600, env=env)
    assert r.returncode == 2 and r.stdout == "", r.stdout + r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and needle in r.stderr
    assert f"NUMBA_THREADING_LAYER='{layer}'" in r.stderr


@pytest.mark.parametrize("argv,hint", [
    (["check", "--suite", "mitsuba", "-k", "uniform_disk_polar"],
     "`mcverify list --suite mitsuba` shows the names"),
    (["list", "--suite", "full", "-k", "no-such-check"],
     "`mcverify list --suite full` shows the names"),
    (["check", "-k", "no-such-check"], "`mcverify list` shows the names"),
    # report runs a built-in suite whatever a [tool.mcverify] table names, which a bare
    # `mcverify list` would list
    (["report", "--renders", "none", "-k", "no-such-check", "--out", "rep"],
     "`mcverify list --suite default` shows the names"),
], ids=["check-suite", "list-suite", "default", "report"])
def test_a_k_matching_nothing_points_at_the_list_of_the_suite_given(argv, hint, tmp_path,
                                                                    monkeypatch, capsys):
    """`check --suite mitsuba -k uniform_disk_polar` said "matches no check of suite
    'mitsuba'; `mcverify list` shows the names", and `mcverify list` (the default suite)
    showed sampler:uniform_disk_polar: the hint listed another suite than the one given."""
    from mcverify.gate import cli

    monkeypatch.chdir(tmp_path)         # no [tool.mcverify] table above
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert hint in err, err


@pytest.mark.parametrize("outputs,needle", [
    (["--junit", "out", "--report", "out"], "--junit out and --report out/report.json"),
    (["--json", "out/x.json", "--junit", "out"], "--json out/x.json and --junit out"),
    (["--junit", "a/b", "--json", "a/b/c/d.json"], "--json a/b/c/d.json and --junit a/b: --junit names a file "
                                            "to write and --json a file inside it"),
], ids=["junit-is-report-folder", "junit-is-json-folder", "deeper"])
def test_an_output_that_is_another_outputs_folder_exits_2_before_any_work(
        outputs, needle, tmp_path, monkeypatch, capsys):
    """`check --junit out --report out` (or `--json out/x.json --junit out`) passed the
    checks before any work, ran every check, wrote the first file and then failed on the
    second, 'out: File exists' or 'out: is a directory', exit 2 with one output written:
    one path named a file to write and a folder another output is written into."""
    from mcverify.gate import cli

    monkeypatch.chdir(tmp_path)
    assert cli.main(["check", "-q", "-k", "uniform_disk_polar", *outputs]) == 2
    out, err = capsys.readouterr()
    assert needle in err and "passed" not in out, out + err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv", [
    ["check", "-q", "-k", "uniform_disk_polar", "--json", "sched.json"],
    ["render-check", "white-furnace", "-q", "--json", "sched.json"],
    ["report", "-q", "--renders", "none", "--out", "."],
], ids=["check", "render-check", "report"])
def test_an_output_naming_the_dask_scheduler_file_exits_2_before_any_work(
        argv, tmp_path, monkeypatch, capsys):
    """`--dask-scheduler-file sched.json --json sched.json` was no input to the output
    checks: the run connected, ran every check on the cluster and replaced the scheduler
    file with its results, which every later run (and client) then refused, 'not a JSON
    object with a string address'."""
    from mcverify.gate import cli

    monkeypatch.chdir(tmp_path)
    sched = tmp_path / ("report.json" if argv[0] == "report" else "sched.json")
    sched.write_text('{"address": "tcp://127.0.0.1:1"}')
    assert cli.main([*argv, "--dask-scheduler-file", str(sched)]) == 2
    err = capsys.readouterr().err
    assert "is also an input" in err and str(sched) in err, err
    assert sched.read_text() == '{"address": "tcp://127.0.0.1:1"}'


@pytest.mark.parametrize("argv, needle", [
    (["check", "--sed", "3"], "unrecognized arguments: --sed 3; did you mean --seed? "
                              "(see `mcverify check --help`)"),
    (["check", "--spp", "16"], "--spp is an option of bench, reference build and "
                               "render-check, not of check (see `mcverify check --help`)"),
    (["list", "--json=x.json"], "--json is an option of check, bench, compare and "
                                "render-check, not of list (see `mcverify list --help`)"),
    (["check", "--version"], "--version goes before the command: mcverify --version"),
    (["render-check", "cornell-box", "--seed"], "argument --seed: expected one argument "
                                                "(see `mcverify render-check --help`)"),
    (["reference", "build", "--pases", "4"], "did you mean --passes? (see `mcverify "
                                             "reference build --help`)"),
    (["chek"], "invalid choice: 'chek'; did you mean 'check'? (see `mcverify --help`)"),
    (["report", "--suite", "ful"], "invalid choice: 'ful'; did you mean 'full'?"),
    (["check", "foo"], "unrecognized arguments: foo (see `mcverify check --help`)"),
    # a prefix of an option is no option: `reference build --sp 4` rebuilt every
    # reference at 4 spp as --spp 4 until 7 December (a read-only review's accident)
    (["reference", "build", "--sp", "4"], "unrecognized arguments: --sp; did you mean "
                                          "--spp?"),
    (["check", "--sui", "default"], "unrecognized arguments: --sui default; did you mean "
                                    "--suite?"),
    # the option a prefix begins before the nearest by spelling (--pa was "--spp?")
    (["reference", "build", "--pa", "4"], "did you mean --passes?"),
    (["compare", "x.exr", "--ref-s", "4"], "did you mean --ref-spp?"),
    (["bench", "--re", "1"], "did you mean --refs or --repeats?"),
], ids=["misspelt", "another-commands", "another-commands-with-value", "top-level",
        "missing-value", "nested-command", "command", "choice", "no-hint", "prefix-build",
        "prefix-check", "prefix-begun", "prefix-begun-2", "prefix-several"])
def test_a_usage_error_points_at_the_commands_help_and_the_option_meant(argv, needle,
                                                                       capsys):
    """Every usage error ended "(see `mcverify --help`)", a page that lists the commands
    but none of their options, and a misspelt or misplaced option was "unrecognized
    arguments: --sed 3" alone (argparse before Python 3.14 suggests nothing): the error
    now names the command's own help, the option meant where one is close, and the
    commands that take an option given to another (an outside review)."""
    from mcverify.gate import cli

    with pytest.raises(SystemExit) as e:
        cli.main(argv)
    err = capsys.readouterr().err
    assert e.value.code == 2 and needle in err, err
    assert len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("argv, says", [
    (["check"], ["Run a verification suite", "  1    a check failed or a canary survived"]),
    (["list"], ["List the checks of a suite", "  0    the checks were listed", "  2    "]),
    (["plan"], ["The checks a scene needs", "  0    the plan was printed", "  2    "]),
    (["report"], ["writes report.json, report.html", "  1    a check failed, a canary "
                  "survived, or a convergence row"]),
    (["bench"], ["not a verdict", "bench judges nothing", "  2    "]),
    (["reference", "build"], ["replacing the one there", "  0    the references were "
                              "written", "  2    "]),
    (["compare"], ["Compare any renderer's EXR", "  1    the images differ"]),
    (["render-check"], ["Render the scene with our path tracer", "  1    the images differ"]),
], ids=["check", "list", "plan", "report", "bench", "reference-build", "compare",
        "render-check"])
def test_each_commands_help_says_what_it_does_and_what_it_exits_with(argv, says, capsys):
    """`mcverify COMMAND --help` began with the options: no line said what the command
    does, and list, plan, report, bench and reference build stated no exit code, so
    `report --help` did not say that a failed check exits 1 (a CI gate's question), nor
    `bench --help` that no ratio does (an outside review). Each says both now."""
    from mcverify.gate import cli

    with pytest.raises(SystemExit) as e:
        cli.main(argv + ["--help"])
    out = capsys.readouterr().out
    assert e.value.code == 0
    for text in says:
        assert text in out, (text, out)
    if argv[0] in ("list", "plan", "bench", "reference"):   # they judge nothing
        assert "\n  1    " not in out, out


def test_a_failed_output_write_leaves_the_other_outputs_as_they_were(tmp_path):
    """`check --json A --junit B` writes A, then B, at the run's end: where B could not be
    written (a full disk: /dev/full), the run exited 2, "no output is written or
    replaced", with A replaced by this run's results beside B's last ones, which CI then
    read together. The outputs are now renamed into place together once all are
    written; a failed write leaves every one as it was, and no temporary file."""
    import os

    (tmp_path / "tiny_suite.py").write_text(
        "import numpy as np, mcverify\n"
        "from mcverify.gate.suites import Check\n"
        "def ok(seed, stop_alpha=None):\n"
        "    x = np.random.default_rng(seed).normal(size=1000)\n"
        "    return mcverify.check_unbiased(x, 0.0)\n"
        "suite = [Check('my.ok', ok)]\n", encoding="utf-8")
    env = dict(os.environ,
               PYTHONPATH=os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")]))
    out = tmp_path / "out"
    out.mkdir()
    (out / "run.json").write_text("last run\n")
    r = subprocess.run(CMD + ["check", "--suite", "tiny_suite:suite", "-q", "--json",
                              str(out / "run.json"), "--junit", "/dev/full"],
                       capture_output=True, text=True, timeout=600, env=env, cwd=tmp_path)
    assert r.returncode == 2, r.stdout + r.stderr
    assert "/dev/full" in r.stderr and "No space left" in r.stderr, r.stderr
    assert (out / "run.json").read_text() == "last run\n"
    assert os.listdir(out) == ["run.json"]


@pytest.mark.parametrize("args", [["list"], ["plan", "scene.xml"]])
def test_a_deleted_working_directory_is_named_as_the_cause(tmp_path, args):
    """A CI step run in a folder another step deleted (`mcverify list` there) ended in
    "mcverify: error: No such file or directory", naming nothing: the current directory
    is read to find [tool.mcverify]. It now says that the current directory no longer
    exists, exit 2; so does an error about a relative path there (`plan scene.xml`: "no
    such file", a read-only review)."""
    gone = tmp_path / "gone"
    gone.mkdir()
    code = ("import os, sys; os.chdir(sys.argv[1]); os.rmdir(sys.argv[1]); "
            "from mcverify.gate.cli import main; sys.exit(main(sys.argv[2:]))")
    r = subprocess.run([sys.executable, "-c", code, str(gone), *args], capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 2, r.stdout + r.stderr
    assert "current directory no longer exists" in r.stderr, r.stderr


def test_a_fallback_to_scalar_rgb_is_noticed_where_mitsuba_runs(monkeypatch, capsys):
    """Where Mitsuba's fast variant is unavailable, every command that runs Mitsuba
    (`check` of its plugins, `bench`, `reference build`) prints the fallback's notice to
    stderr and records the variant it ran; no test read the notice (a mutation review's
    found-not-fixed: it could be dropped unseen). No notice where llvm_ad_rgb runs, and
    none where no selected check uses Mitsuba."""
    from types import SimpleNamespace

    from mcverify.gate import cli
    from mcverify.gate import mitsuba as mvm

    why = "mitsuba: llvm_ad_rgb needs LLVM >= 16 (found 15); using scalar_rgb"
    monkeypatch.setattr(mvm, "choose_variant", lambda: mvm.VariantChoice("scalar_rgb", why))
    uses = [SimpleNamespace(tags=("sampler", "mitsuba"))]
    assert cli._mitsuba_provenance(uses)["mitsuba_variant"] == "scalar_rgb"
    assert capsys.readouterr().err == f"notice: {why}\n"
    assert cli._mitsuba_provenance([SimpleNamespace(tags=("sampler",))]) == {}
    assert capsys.readouterr().err == ""
    monkeypatch.setattr(mvm, "choose_variant", lambda: mvm.VariantChoice("llvm_ad_rgb", None))
    assert cli._variant_notice().variant == "llvm_ad_rgb"
    assert capsys.readouterr().err == ""
