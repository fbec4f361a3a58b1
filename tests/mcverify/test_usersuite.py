"""User suites in the gate: ``--suite MODULE:ATTR`` and ``[tool.mcverify]``."""

import json
import os
import subprocess
import sys
import textwrap

import pytest

import mcverify as mv
from mcverify.gate.suites import Check, resolve_suite
from mcverify.gate.usersuite import find_config, load_user_suite

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
EXAMPLE = os.path.join(ROOT, "examples", "user-suite")

CHECKS = textwrap.dedent('''
    import numpy as np
    import mcverify as mv
    from mcverify.gate.suites import Check

    def _check(name, scale):
        def run(seed):
            return mv.check_sampler(lambda u: np.sqrt(u), lambda x: scale * 2 * x[:, 0],
                                    "interval", n_samples=20_000, seed=seed, name=name)
        return Check(name, run)

    good = [_check("sqrt", 1.0), _check("sqrt-again", 1.0)]
    bad = [_check("sqrt*1.1", 1.1)]

    def factory():
        return good[:1]

    not_checks = [1, 2]
    number_named = [Check(3, good[0].run)]
    surrogate_named = [Check("scene_\\udcff.xml", good[0].run)]
    not_runnable = [Check("x", None)]
    canary_tagged = [Check("mine-planted", lambda seed: None, ("canary",))]
    duplicates = [good[0], good[0]]
    empty_named = [Check("", good[0].run)]
    as_set = {good[0]}                       # no order: results would change places
    by_name = {"sqrt": good[0]}
    number = 3

    class grouped:                           # MODULE:OBJ.ATTR
        suite = good

    def raising_builder():
        return 1 / 0

    def _exits(seed):
        import sys
        sys.exit(0)

    def _unnamed(scale):
        def run(seed):       # check_sampler names its result "sampler:<lambda>"
            return mv.check_sampler(lambda u: np.sqrt(u), lambda x: scale * 2 * x[:, 0],
                                    "interval", n_samples=20_000, seed=seed)
        return run

    # a failure, then a check that calls sys.exit(0), one that returns None, and two
    # checks whose results carry the same default name
    odd = [bad[0], Check("exits", _exits), Check("returns-none", lambda seed: None),
           Check("unnamed-good", _unnamed(1.0)), Check("unnamed-bad", _unnamed(1.1))]
    empty = []
''')


@pytest.fixture
def project(tmp_path, monkeypatch):
    """A user's project: mine/checks.py and a pyproject.toml; cwd in a subfolder."""
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "__init__.py").write_text("")
    (tmp_path / "mine" / "checks.py").write_text(CHECKS)
    (tmp_path / "mine" / "broken.py").write_text('raise ValueError("at import")\n')
    (tmp_path / "mine" / "syntax.py").write_text("suite = [\n")
    (tmp_path / "sub" / "deeper").mkdir(parents=True)
    monkeypatch.chdir(tmp_path / "sub" / "deeper")
    for name in list(sys.modules):
        if name == "mine" or name.startswith("mine."):
            monkeypatch.delitem(sys.modules, name)
    monkeypatch.setattr(sys, "path", list(sys.path))
    return tmp_path


def _pyproject(root, body):
    (root / "pyproject.toml").write_text(body)


def test_a_list_and_a_factory_load(project):
    checks = load_user_suite("mine.checks:good", roots=[str(project)])
    assert [c.name for c in checks] == ["sqrt", "sqrt-again"]
    assert [c.name for c in load_user_suite("mine.checks:factory", roots=[str(project)])] \
        == ["sqrt"]
    assert checks[0].run(0).passed
    assert [c.name for c in load_user_suite("mine.checks:grouped.suite",
                                            roots=[str(project)])] == ["sqrt", "sqrt-again"]


def test_the_first_import_root_wins(project, monkeypatch):
    """Roots go on the import path in their order, as pytest's do: a module in two of
    them is imported from the first."""
    for root, name in (("one", "first"), ("two", "second")):
        (project / root).mkdir()
        (project / root / "rootorder_mod.py").write_text(
            f"from mcverify.gate.suites import Check\nsuite = [Check({name!r}, print)]\n")
    monkeypatch.delitem(sys.modules, "rootorder_mod", raising=False)
    checks = load_user_suite("rootorder_mod:suite",
                             roots=[str(project / "one"), str(project / "two")])
    assert [c.name for c in checks] == ["first"]
    monkeypatch.delitem(sys.modules, "rootorder_mod")


@pytest.mark.parametrize("spec, match", [
    ("mine.checks", "expected MODULE:ATTR"),
    ("mine.nothere:x", "cannot import 'mine.nothere'"),
    ("mine.checks:missing", "has no attribute 'missing'"),
    ("mine.checks:number", "expected a list of mcverify.gate.suites.Check, got int"),
    ("mine.checks:not_checks", "item 0 is a int"),
    ("mine.checks:as_set", "expected a list of mcverify.gate.suites.Check, got set"),
    ("mine.checks:by_name", "expected a list of mcverify.gate.suites.Check, got dict"),
    ("mine.checks:empty_named", "item 0 is named '': a check's name must be a non-empty "),
    ("mine.checks:duplicates", "two checks are named 'sqrt'"),
    ("mine.checks:number_named", "item 0 is named 3: a check's name must be a non-empty "
                                 "string"),
    ("mine.checks:not_runnable", "check 'x': run=None is not callable"),
    # the progress line read it as a canary ("NOT bitten") where the verdict was FAIL
    ("mine.checks:canary_tagged", "check 'mine-planted' is tagged 'canary'"),
    # a name from a non-UTF-8 file name (surrogateescape): the seed's derivation raised
    # "unexpected UnicodeEncodeError" without naming the check, and nothing was written
    ("mine.checks:surrogate_named", r"item 0 is named 'scene_\\udcff.xml': not "
                                    "encodable as UTF-8"),
    # the user's own code failing: named, not "unexpected ValueError"
    ("mine.broken:suite", "importing 'mine.broken' raised ValueError: at import"),
    ("mine.syntax:suite", "importing 'mine.syntax' raised SyntaxError at "),
    ("mine.checks:raising_builder", r"raising_builder\(\) raised ZeroDivisionError"),
])
def test_bad_user_suites_are_refused_by_name(project, spec, match):
    with pytest.raises(mv.InvalidArgument, match=match):
        load_user_suite(spec, roots=[str(project)])


def test_the_config_is_found_from_a_subfolder(project):
    _pyproject(project, '[tool.mcverify]\nsuite = ["mine.checks:good", "default"]\n'
                        'alpha = 0.05\nseed = 7\npath = ["."]\n')
    config = find_config()
    assert config.file == str(project / "pyproject.toml")
    assert config.suites == ("mine.checks:good", "default")
    assert (config.alpha, config.seed, config.path) == (0.05, 7, (".",))
    # import roots are relative to the pyproject.toml, not to the current directory
    _pyproject(project, '[tool.mcverify]\npath = ["mine"]\n')
    assert find_config().path == ("mine",)


def test_the_first_pyproject_decides_even_without_a_table(project):
    _pyproject(project, '[tool.mcverify]\nsuite = "mine.checks:good"\n')
    (project / "sub" / "pyproject.toml").write_text('[project]\nname = "x"\n')
    assert find_config() is None


@pytest.mark.parametrize("body, match", [
    ('[tool.mcverify]\nsuites = "a:b"\n', "'suites': unknown key"),
    ('[tool.mcverify]\nalpha = 2.0\n', "alpha = 2.0: must be strictly between 0 and 1"),
    ('[tool.mcverify]\nalpha = "x"\n', "alpha = 'x': expected float or int"),
    ('[tool.mcverify]\nalpha = 1\n', "alpha = 1: must be strictly between 0 and 1"),
    ('[tool.mcverify]\nalpha = 0.0\n', "alpha = 0.0: must be strictly between 0 and 1"),
    ('[tool.mcverify]\nseed = -1\n', r"seed = -1: must be in \[0, 2\*\*63 - 1\]"),
    # as --seed refuses it (was accepted)
    ('[tool.mcverify]\nseed = 99999999999999999999\n', "seed = 99999999999999999999: must be"),
    ('[tool.mcverify]\nseed = 9223372036854775808\n', "seed = 9223372036854775808: must be"),
    # an empty list fell back to the default suite; a repeated entry ran every check twice
    ('[tool.mcverify]\nsuite = []\n', "suite: an empty list"),
    ('[tool.mcverify]\nsuite = ["default", "default"]\n', "'default' is listed twice"),
    ('[tool.mcverify]\nseed = true\n', "seed = True: expected int"),
    ('[tool.mcverify]\nsuite = "nightly"\n', "suite 'nightly': expected MODULE:ATTR"),
    ('[tool.mcverify]\nsuite = [1]\n', "suite: 1 is not a string"),
    ('[tool.mcverify\n', "not valid TOML"),
    # these raised AttributeError and UnicodeDecodeError, naming no file
    ('tool = 3\n', "tool = 3: must be a table"),
    ('[tool]\nmcverify = 3\n', r"\[tool.mcverify\] must be a table"),
    (b'[tool.mcverify]\nseed = 1 # \xff\n', "not valid TOML"),
    # a misspelt import root was accepted without a word (the module may still import
    # from the current directory, another copy of it)
    ('[tool.mcverify]\npath = ["scr"]\n', "path 'scr': no such folder"),
    ('[tool.mcverify]\npath = "pyproject.toml"\n', "path 'pyproject.toml': no such folder"),
    # a Windows editor's byte-order mark was "Invalid statement (at line 1, column 1)"
    (b'\xef\xbb\xbf[tool.mcverify]\nseed = 1\n', "starts with a UTF-8 byte-order mark"),
], ids=["unknown-key", "alpha-range", "alpha-type", "alpha-1", "alpha-0", "seed-negative",
        "seed-beyond-2^63", "seed-2^63", "empty-suite-list", "suite-twice", "seed-bool",
        "suite-name", "suite-type", "toml", "tool-not-a-table", "mcverify-not-a-table", "not-utf8", "path-missing", "path-a-file", "bom"])
def test_a_malformed_table_names_the_file_and_key(project, body, match):
    if isinstance(body, bytes):
        (project / "pyproject.toml").write_bytes(body)
    else:
        _pyproject(project, body)
    with pytest.raises(mv.InvalidArgument, match=match) as e:
        find_config()
    assert str(project / "pyproject.toml") in str(e.value)


def test_resolve_suite_knows_the_built_in_names_and_user_specs(project):
    checks, skipped = resolve_suite("mine.checks:bad", roots=[str(project)])
    assert [c.name for c in checks] == ["sqrt*1.1"] and skipped == []
    assert resolve_suite("default")[0]
    with pytest.raises(mv.InvalidArgument, match="--suite 'nightly'"):
        resolve_suite("nightly")


def _cli(args, cwd):
    env = dict(os.environ, PYTHONPATH=ROOT)
    return subprocess.run([sys.executable, "-m", "mcverify", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=600)


def test_mcverify_check_runs_the_projects_suite_with_its_alpha_and_seed(project, tmp_path):
    _pyproject(project, '[tool.mcverify]\nsuite = "mine.checks:good"\nalpha = 0.02\n'
                        'seed = 3\n')
    out = tmp_path / "r.json"
    r = _cli(["check", "-q", "--json", str(out), "--junit", str(tmp_path / "r.xml")],
             cwd=project / "sub" / "deeper")
    assert r.returncode == 0, r.stderr
    doc = json.loads(out.read_text())
    assert doc["suite"] == "mine.checks:good" and doc["alpha"] == 0.02
    assert doc["provenance"]["seed"] == 3
    assert doc["provenance"]["config"] == str(project / "pyproject.toml")
    assert [x["name"] for x in doc["results"]] == ["sqrt", "sqrt-again"]
    assert doc["canary_bitten"]
    assert 'tests="6"' in (tmp_path / "r.xml").read_text()      # 2 checks + 4 canaries
    # the command line wins over the table
    r2 = _cli(["check", "-q", "--suite", "mine.checks:bad", "--alpha", "0.01", "--json",
               str(out)], cwd=project / "sub" / "deeper")
    assert r2.returncode == 1 and "FAIL sqrt*1.1" in r2.stdout
    assert json.loads(out.read_text())["alpha"] == 0.01


def test_list_shows_a_user_suite_and_a_bad_table_exits_2(project):
    _pyproject(project, '[tool.mcverify]\nsuite = "mine.checks:good"\n')
    r = _cli(["list"], cwd=project)
    assert r.returncode == 0 and r.stdout.split() == ["sqrt", "sqrt-again"]
    # a pattern that selects nothing names the table's suite (it said "suite None")
    r = _cli(["list", "-k", "nosuch"], cwd=project)
    assert r.returncode == 2 and "of suite 'mine.checks:good'" in r.stderr, r.stderr
    _pyproject(project, '[tool.mcverify]\nsute = "mine.checks:good"\n')
    r = _cli(["check"], cwd=project)
    assert r.returncode == 2 and "'sute': unknown key" in r.stderr
    assert "Traceback" not in r.stderr


@pytest.mark.mitsuba
def test_the_readme_example_passes_and_its_planted_bug_fails():
    """examples/user-suite: a Python-registered Mitsuba BSDF gated from its own
    pyproject.toml; the same checks on the planted off-by-one exponent fail."""
    ok = _cli(["check", "-q"], cwd=EXAMPLE)
    assert ok.returncode == 0, ok.stdout + ok.stderr
    assert "mychecks:suite: 4 passed, 0 failed" in ok.stdout
    bad = _cli(["check", "-q", "--suite", "mychecks:planted"], cwd=EXAMPLE)
    assert bad.returncode == 1, bad.stdout + bad.stderr
    assert bad.stdout.count("FAIL powercosine(exponent=4,bug)") == 2
    assert "FAIL pdf_consistency" not in bad.stdout     # its returned pdfs are pdf(x)
    # the other planted bug: draws right, returned pdf without its Jacobian 1/(2π)
    bad = _cli(["check", "-q", "--suite", "mychecks:planted_pdf"], cwd=EXAMPLE)
    assert bad.returncode == 1, bad.stdout + bad.stderr
    assert bad.stdout.count("FAIL pdf_consistency:powercosine(exponent=4,pdf_bug)") == 2
    assert "(ratio 6.28319)" in bad.stdout
    assert "FAIL powercosine" not in bad.stdout         # χ² cannot see it


def test_a_user_suite_runs_in_worker_processes_with_the_same_results(project):
    """Workers rebuild the suite from its recipe (the same import, the same roots)."""
    from mcverify.gate.executors import Pool
    from mcverify.gate.suites import run_suite

    checks = load_user_suite("mine.checks:good", roots=[str(project)])
    here = run_suite(checks, seed=5, canary=False)
    with Pool(jobs=2) as pool:
        there = run_suite(checks, seed=5, canary=False, pool=pool)
    assert [r.p_value for r in here.results] == [r.p_value for r in there.results]


def _seed_seen(seed):
    from mcverify.result import CheckResult

    return CheckResult(name="seed", passed=True, p_value=0.5, statistic=None, alpha=0.01,
                       n_samples=1, seconds=0.0, details={"seed": seed})


def test_a_checks_seed_derives_from_its_name_not_its_place():
    """Selecting or reordering checks (``-k``, a suite grown by one) changes no check's
    seed, hence no check's result."""
    from mcverify.gate.suites import check_seed, run_suite

    a, b = Check("a", _seed_seen), Check("b", _seed_seen)
    both = run_suite([a, b], seed=4, canary=False).results
    alone = run_suite([b], seed=4, canary=False).results
    assert both[1].details["seed"] == alone[0].details["seed"] == check_seed(4, "b")
    assert both[0].details["seed"] == check_seed(4, "a") != check_seed(4, "b")


def test_what_a_check_does_wrong_is_its_own_failure_not_the_gates(project, tmp_path):
    """A check that calls sys.exit(0) (the gate used to exit 0 after a failure, writing
    nothing), one that returns None (the run stopped with an AttributeError naming no
    check): each is a named FAIL and the others still run; results are reported under
    the suite's names for them, not the names their CheckResults carry."""
    out = tmp_path / "r.json"
    r = _cli(["check", "-q", "--suite", "mine.checks:odd", "--json", str(out)], cwd=project)
    assert r.returncode == 1, r.stdout + r.stderr
    doc = json.loads(out.read_text())
    got = {x["name"]: x for x in doc["results"]}
    assert list(got) == ["sqrt*1.1", "exits", "returns-none", "unnamed-good", "unnamed-bad"]
    assert got["exits"]["failures"] == ["raised SystemExit: 0"]
    assert got["returns-none"]["failures"] == ["returned NoneType, not a CheckResult"]
    assert got["unnamed-good"]["passed"] and not got["unnamed-bad"]["passed"]
    assert got["unnamed-bad"]["details"]["result_name"] == "sampler:<lambda>"
    assert "FAIL unnamed-bad" in r.stdout


def test_ctrl_c_inside_compiled_code_interrupts_instead_of_failing_the_check():
    """Ctrl-C inside a numba kernel reaches Python as ``SystemError: ... returned a
    result with an exception set`` caused by the KeyboardInterrupt: the gate stops
    (exit 130), it does not record a failed check and go on."""
    from mcverify.gate.suites import _run_guarded

    def run(seed):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as e:
            raise SystemError("CPUDispatcher(<function histogram_kernel>) returned a "
                              "result with an exception set") from e

    def plain(seed):
        raise SystemError("x")

    with pytest.raises(KeyboardInterrupt):
        _run_guarded(Check("interrupted", run), 0)
    r = _run_guarded(Check("plain", plain), 0)
    assert not r.passed and r.failures == ("raised SystemError: x",)


@pytest.mark.parametrize("option", ["--json", "--junit"])
@pytest.mark.parametrize("target", ["mine/checks.py", "pyproject.toml"])
def test_an_output_path_naming_the_suite_module_or_the_config_exits_2(project, option,
                                                                      target):
    """The user suite's module and the project's pyproject.toml are inputs of `check`:
    an output path naming one exits 2 before any check runs, and leaves it intact (the
    module used to be replaced by the JSON, with exit 0)."""
    _pyproject(project, '[tool.mcverify]\nsuite = "mine.checks:good"\n')
    before = (project / target).read_text()
    r = _cli(["check", "-q", option, target], cwd=project)
    assert r.returncode == 2 and "is also an input" in r.stderr, r.stdout + r.stderr
    assert (project / target).read_text() == before


@pytest.mark.parametrize("args, needle", [
    (["--suite", "mine.checks:empty"], "suite 'mine.checks:empty' has no checks"),
    (["--suite", "mine.checks:good", "-k", "nosuch"], "-k 'nosuch': matches no check"),
    (["--budget", "inf"], "--budget inf: must be a positive, finite number"),
    # an empty --suite ran the default suite, passing over the project's table
    (["--suite", ""], "--suite '': empty"),
], ids=["empty-suite", "k-matches-nothing", "budget-inf", "suite-empty-string"])
def test_nothing_to_run_and_an_infinite_budget_exit_2_saying_why(project, args, needle):
    r = _cli(["check", "-q", *args], cwd=project)
    assert r.returncode == 2 and needle in r.stderr, r.stdout + r.stderr
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1



def test_a_check_name_in_two_suites_of_the_table_exits_2(project):
    """Each check's seed derives from its name: the same name in two suites of one run
    gave both the same seed, and both counted in Holm (refused within one suite only,
    until 4 December)."""
    _pyproject(project, '[tool.mcverify]\nsuite = ["mine.checks:good", "mine.checks:factory"]\n')
    r = _cli(["check", "-q"], cwd=project)
    assert r.returncode == 2, r.stdout + r.stderr
    assert ("check 'sqrt' is in suite 'mine.checks:good' and in suite 'mine.checks:factory'"
            in r.stderr), r.stderr
    # named by the file and key that listed the suites (it named neither)
    assert f"{project / 'pyproject.toml'}: [tool.mcverify] suite: " in r.stderr, r.stderr
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1


def test_a_write_that_fails_at_the_end_still_prints_every_verdict(project):
    """The outputs were written before the verdicts were printed: a --json write that
    failed at the end (exit 2) left the run's failures and its summary line unprinted,
    though the README promises that the results printed are complete."""
    (project / "mine" / "sabotage.py").write_text(textwrap.dedent('''
        from mcverify.gate.suites import Check
        from mine.checks import bad

        def _run(seed):
            open("out", "w").close()     # the folder --json writes into is now a file
            return bad[0].run(seed)

        suite = [Check("sqrt*1.1", _run)]
    '''))
    r = _cli(["check", "-q", "--suite", "mine.sabotage:suite", "--json", "out/r.json",
              "--junit", "r.xml"], cwd=project)
    assert r.returncode == 2, r.stdout + r.stderr
    assert "FAIL sqrt*1.1" in r.stdout and "0 passed, 1 failed" in r.stdout, r.stdout
    assert "out/r.json: cannot write it" in r.stderr and "Traceback" not in r.stderr
    assert (project / "out").is_file() and not (project / "r.xml").exists()


@pytest.mark.parametrize("suite, needle", [
    ("mine.nothere:x", "suite 'mine.nothere:x': cannot import 'mine.nothere'"),
    ("mine.checks:missing", "suite 'mine.checks:missing': mine.checks has no attribute"),
])
def test_a_bad_suite_in_the_table_is_named_by_the_file_not_as_suite(project, suite, needle):
    """The table's suite that cannot be loaded was reported as "--suite '...'", an option
    the user never gave, and the file it came from was not named."""
    _pyproject(project, f'[tool.mcverify]\nsuite = "{suite}"\n')
    r = _cli(["list"], cwd=project / "sub")
    assert r.returncode == 2, r.stdout + r.stderr
    assert f"{project / 'pyproject.toml'}: [tool.mcverify] {needle}" in r.stderr, r.stderr
    assert "--suite" not in r.stderr and len(r.stderr.strip().splitlines()) == 1


def test_a_check_named_like_a_canary_is_reported_as_itself():
    """Progress looked checks up by name, so a user's check that shares a canary's name
    ("cosine-pdf*1.03") was shown as that canary: "NOT bitten" when it passed."""
    from mcverify.gate.cli import _verdict
    from mcverify.gate.suites import canaries, run_suite

    name = canaries()[2].name

    def ok(seed):
        return mv.CheckResult(name, True, 0.5, 1.0, 0.01, 10, 0.0)

    seen = []
    result = run_suite([Check(name, ok)], progress=lambda i, n, r, c: seen.append(
        (r.name, c.tags, _verdict(r, c, 0.01))))
    assert result.passed and seen[0] == (name, (), "ok"), seen
    assert [v for _, tags, v in seen if "canary" in tags] == ["bitten"] * len(canaries())


def test_a_p_value_that_is_no_probability_fails_its_check_and_stays_out_of_holm():
    """A user check's CheckResult with p_value 7, -0.5 or NaN was judged as given: p = 7
    passed and counted in Holm's m (p = 0.004 among three checks then passed at 0.012),
    p = -0.5 printed "p_adj=-1.5", NaN failed without a word why."""
    from mcverify.gate.suites import run_suite

    def check(name, p):
        return Check(name, lambda seed: mv.CheckResult(name, True, p, 1.0, 0.01, 10, 0.0))

    bad = [7.0, -0.5, float("nan"), "0.5", True]
    result = run_suite([check(f"bad{i}", p) for i, p in enumerate(bad)]
                       + [check("small", 0.004), check("mid", 0.5)], canary=False)
    got = {r.name: r for r in result.results}
    for i, p in enumerate(bad):
        assert got[f"bad{i}"].failures == (f"returned p_value={p!r}, not a probability in "
                                           "[0, 1]",)
        assert got[f"bad{i}"].p_value is None
    assert got["small"].details["p_adjusted"] == 0.008 and not got["small"].passed
    assert got["mid"].passed


def test_a_result_with_fields_of_the_wrong_type_is_reported_not_a_crash(tmp_path, capsys):
    """A user check's CheckResult with seconds=None, details=None or its messages and
    failures as a list or one string ended `mcverify check` with "unexpected TypeError"
    (exit 2, no check named) in its progress line, JUnit file or report page, the last
    after report.json was written. Now seconds that is no number is the call's measured
    time, messages and failures become tuples of strings, and details that is no dict
    fails its check, saying so."""
    from mcverify.gate import cli
    from mcverify.gate.suites import run_suite

    def check(name, **kw):
        fields = dict(dict(name=name, passed=True, p_value=0.5, statistic=1.0, alpha=0.01,
                           n_samples=10, seconds=0.0), **kw)
        return Check(name, lambda seed: mv.CheckResult(**fields))

    checks = [check("no-seconds", seconds=None), check("nan-seconds", seconds=float("nan")),
              check("no-details", details=None),
              check("listed", messages=["m"], failures=["bad"], passed=False, p_value=None),
              check("one-string", failures="bad", passed=False, p_value=0.5)]
    got = {r.name: r for r in run_suite(checks, canary=False).results}
    for name in ("no-seconds", "nan-seconds"):
        assert got[name].passed and got[name].seconds >= 0.0
    assert not got["no-details"].passed and got["no-details"].details.get("p_adjusted") == 1.0
    assert got["no-details"].failures == ("returned details=None, not a dict",)
    assert got["listed"].failures == ("bad",) and got["listed"].messages == ("m",)
    assert got["one-string"].failures == ("bad",) and not got["one-string"].passed

    import types
    mod = types.ModuleType("odd_results_suite")
    mod.suite = checks
    sys.modules[mod.__name__] = mod
    try:
        rc = cli.main(["check", "-q", "--suite", "odd_results_suite:suite", "--junit",
                       str(tmp_path / "j.xml"), "--report", str(tmp_path / "rep")])
    finally:
        del sys.modules[mod.__name__]
    out, err = capsys.readouterr()
    assert rc == 1, out + err
    assert "FAIL no-details" in out and "unexpected" not in err, out + err
    assert (tmp_path / "rep" / "report.html").is_file() and (tmp_path / "j.xml").is_file()


def test_check_scene_plans_from_the_tables_list_of_suites(project):
    """With a [tool.mcverify] list of suites, `check --scene` planned from the joined name
    'mine.checks:good+default' and exited 2 ("has no attribute 'good+default'")."""
    scene = os.path.join(ROOT, "reference", "scenes", "white-furnace", "scene.xml")
    _pyproject(project, '[tool.mcverify]\nsuite = ["mine.checks:good", "default"]\n')
    r = _cli(["check", "-q", "--scene", scene, "-k", "inverse:cosine_hemisphere"],
             cwd=project / "sub")
    assert r.returncode == 0, r.stdout + r.stderr
    assert "1 passed, 0 failed" in r.stdout


def test_budget_with_the_tables_user_suite_names_the_table(project):
    """--budget sizes built-in suites only: with the suite from [tool.mcverify] the
    refusal said "--budget with --suite mine.checks:good", an option never given."""
    _pyproject(project, '[tool.mcverify]\nsuite = "mine.checks:good"\n')
    r = _cli(["check", "--budget", "5"], cwd=project)
    assert r.returncode == 2, r.stdout + r.stderr
    assert (f"--budget with {project / 'pyproject.toml'}: [tool.mcverify] suite "
            "'mine.checks:good': only the built-in suites" in r.stderr), r.stderr
    r = _cli(["check", "--budget", "5", "--suite", "mine.checks:good"], cwd=project)
    assert r.returncode == 2 and "--budget with --suite mine.checks:good" in r.stderr


def test_a_failed_result_without_p_value_or_failures_stays_failed():
    """A user check returning CheckResult(passed=False, p_value=None) with only messages
    (its own deterministic test, e.g. a round trip) was re-judged by Holm from its
    (empty) failures and passed: the gate exited 0 on a check that said it failed."""
    from mcverify.gate.suites import run_suite

    def check(name, passed, p=None):
        return Check(name, lambda seed: mv.CheckResult(name, passed, p, None, 0.01, 10, 0.0,
                                                       messages=("round trip off",)))

    result = run_suite([check("det-bad", False), check("det-ok", True),
                        check("stat", False, 0.5)], canary=False)
    got = {r.name: r for r in result.results}
    assert not result.passed
    assert not got["det-bad"].passed
    assert got["det-bad"].failures == ("returned passed=False without a failure or a "
                                       "p-value",)
    assert got["det-ok"].passed and got["stat"].passed     # a p-value is re-judged by Holm


def test_a_stability_check_leaves_no_hypothesis_folder_in_the_project(project, tmp_path):
    """check_stability runs hypothesis, which cached the constants of the user's module in
    ./.hypothesis/constants: `mcverify check` left that folder in the user's project.
    Since 7 December the search reads no module's constants (nothing is cached); whatever
    else hypothesis stores goes under ~/.cache/mcverify/hypothesis."""
    (project / "mine" / "stab.py").write_text(textwrap.dedent('''
        import os
        import numpy as np
        import mcverify as mv
        from mcverify.gate.suites import Check

        def run(seed):
            assert os.environ["HYPOTHESIS_STORAGE_DIRECTORY"] == os.path.join(
                os.environ["HOME"], ".cache", "mcverify", "hypothesis")
            return mv.check_stability(lambda u: np.sqrt(u), "interval", sample_dim=1,
                                      max_examples=20, seed=seed, name="stab")

        suite = [Check("stab", run)]
    '''))
    env = {k: v for k, v in os.environ.items() if k != "HYPOTHESIS_STORAGE_DIRECTORY"}
    from estimators._generated import cache_dir

    env.setdefault("MCVERIFY_CACHE", cache_dir())       # the kernels, not in the new HOME
    (tmp_path / "home").mkdir()
    env.update(PYTHONPATH=ROOT, HOME=str(tmp_path / "home"))
    r = subprocess.run([sys.executable, "-m", "mcverify", "check", "-q", "--suite",
                        "mine.stab:suite"], cwd=project, env=env, capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    assert not (project / ".hypothesis").exists()
    assert not (tmp_path / "home" / ".cache" / "mcverify" / "hypothesis" / "constants").exists()


def _ok(seed):
    """A user's check that passes."""
    return mv.CheckResult("ok", True, 0.5, 1.0, 0.01, 10, 0.0)


def _no_gpu(seed):
    """A user's check that meets its environment."""
    from mcverify.errors import EnvironmentProblem

    raise EnvironmentProblem("no GPU")


def test_an_environment_problem_in_a_check_names_the_check(tmp_path, capsys):
    """A user's check that meets its environment (raises EnvironmentProblem: "no GPU")
    stops the run, exit 2, as the README says; the line said "mcverify: error: no GPU",
    naming no check among the suite's, and no output file is written."""
    from mcverify.gate import cli

    import types
    mod = types.ModuleType("env_problem_suite")
    mod.suite = [Check("ok", _ok), Check("my.gpu[kernel]", _no_gpu)]
    sys.modules[mod.__name__] = mod
    try:
        rc = cli.main(["check", "-q", "--suite", "env_problem_suite:suite", "--json",
                       str(tmp_path / "r.json")])
    finally:
        del sys.modules[mod.__name__]
    err = capsys.readouterr().err
    assert rc == 2 and err == "mcverify: error: check 'my.gpu[kernel]': no GPU\n", err
    assert not (tmp_path / "r.json").exists()


def test_plan_lists_the_checks_check_scene_runs_under_the_tables_suite(project, capsys):
    """`mcverify plan` planned from the built-in default suite whatever the project's
    [tool.mcverify] table said, and its --suite took default or full only: it listed
    sampler:uniform_sphere for a scene whose `check --scene` ran the table's checks, and
    `check --scene S -k sampler:uniform_sphere` exited 2, "matches none of the checks the
    scene needs; `mcverify plan S` lists them", pointing at a list holding it."""
    from mcverify.gate import cli

    scene = os.path.join(ROOT, "reference", "scenes", "white-furnace", "scene.xml")
    _pyproject(project, '[tool.mcverify]\nsuite = "mine.checks:good"\n')
    assert cli.main(["plan", scene]) == 0
    listed = capsys.readouterr().out.split("skipped")[0].split()
    assert "sqrt" in listed and "sqrt-again" in listed
    assert "sampler:uniform_sphere" not in listed
    # the command line wins over the table, and takes what check's --suite takes
    assert cli.main(["plan", scene, "--suite", "default"]) == 0
    assert "sampler:uniform_sphere" in capsys.readouterr().out.split("skipped")[0]
    assert cli.main(["plan", scene, "--suite", "mine.checks:bad"]) == 0
    assert "sqrt*1.1" in capsys.readouterr().out.split("skipped")[0]
    # check --scene's hint names the suite it planned from, so the plan it names is its own
    assert cli.main(["check", "--scene", scene, "--suite", "full", "-k", "nosuch"]) == 2
    assert f"`mcverify plan {scene} --suite full` lists them" in capsys.readouterr().err


def test_the_line_that_ends_a_run_is_not_written_onto_a_terminals_progress_line(
        monkeypatch, tmp_path):
    """On a terminal each progress line is overwritten by the next ("\\r\\033[K", no
    newline until the last check): a run that an error ended wrote its error on the same
    line, "[1/6] ok ok (0.0s)mcverify: error: check 'my.gpu': no GPU" (an outside
    review). The open line is ended first."""
    import io

    from mcverify.gate import cli

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    import types
    mod = types.ModuleType("tty_progress_suite")
    mod.suite = [Check("ok", _ok), Check("my.gpu", _no_gpu)]
    monkeypatch.setitem(sys.modules, mod.__name__, mod)
    monkeypatch.setenv("TERM", "xterm")     # one that overwrites its lines
    term = Terminal()
    monkeypatch.setattr(sys, "stderr", term)
    assert cli.main(["check", "--suite", "tty_progress_suite:suite"]) == 2
    lines = term.getvalue().split("\n")
    assert lines[0].endswith("[1/6] ok ok (0.0s)"), lines
    assert lines[1] == "mcverify: error: check 'my.gpu': no GPU", lines


def test_a_failed_checks_verdict_lines_escape_what_a_terminal_would_act_on(monkeypatch,
                                                                           capsys):
    """A check whose subject raised an error with an ANSI colour code (quoting a tool's
    coloured output) or a carriage return printed it raw in its FAIL line and messages on stdout:
    the terminal or CI log coloured the rest of the log, or showed only the text after
    the '\\r'. They are written as escapes, as the error line and the JUnit file write
    them (an outside review)."""
    from mcverify.gate import cli

    def raises(seed):
        raise RuntimeError("\x1b[1;31mTypingError\x1b[0m: bad")

    def fails(seed):
        return mv.CheckResult("my.msg\x07", False, 0.0, 1.0, 0.01, 10, 0.0,
                              messages=("50%\rall draws NaN\x00",))

    import types
    mod = types.ModuleType("control_chars_suite")
    mod.suite = [Check("my.raises", raises), Check("my.msg\x07", fails)]
    monkeypatch.setitem(sys.modules, mod.__name__, mod)
    assert cli.main(["check", "--suite", "control_chars_suite:suite"]) == 1
    out, err = capsys.readouterr()
    assert "raised RuntimeError: \\x1b[1;31mTypingError\\x1b[0m: bad" in out, out
    assert "FAIL my.msg\\x07 p=0" in out and "    50%\\rall draws NaN\\x00" in out, out
    assert "[2/6] my.msg\\x07 pending" in err, err
    assert not any(c in out + err for c in "\x1b\x07\x00\r"), out + err


@pytest.mark.parametrize("option", ["--json", "--junit"])
def test_an_output_path_of_a_dash_is_refused_not_written_as_a_file_named_dash(
        monkeypatch, tmp_path, capsys, option):
    """`mcverify check --json - | jq .passed`, as many tools read '-', got the printed
    verdict on the pipe and a file named '-' in the current folder, exit 0 (an outside
    review). It exits 2 before any work, saying what to give instead."""
    from mcverify.gate import cli

    import types
    mod = types.ModuleType("dash_output_suite")
    mod.suite = [Check("ok", lambda seed: mv.CheckResult("ok", True, 0.5, 1.0, 0.01, 10,
                                                         0.0))]
    monkeypatch.setitem(sys.modules, mod.__name__, mod)
    monkeypatch.chdir(tmp_path)
    assert cli.main(["check", "-q", "--suite", "dash_output_suite:suite", option, "-"]) == 2
    out, err = capsys.readouterr()
    assert err.startswith(f"mcverify: error: {option} -: is not stdout here") and \
        "/dev/stdout" in err and out == "", err
    assert not (tmp_path / "-").exists()


def test_a_dumb_terminal_gets_one_progress_line_a_check(monkeypatch):
    """A terminal whose TERM is dumb (Emacs' compilation and shell buffers) cannot move
    back over a line: each progress line was written over the last with "\\r\\033[K",
    shown as '^[[K[1/5] ok ok (0.0s)^[[K[2/5] …' on one line (an outside review). It
    gets the lines a log file gets."""
    import io

    from mcverify.gate import cli

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    import types
    mod = types.ModuleType("dumb_terminal_suite")
    mod.suite = [Check("ok", lambda seed: mv.CheckResult("ok", True, 0.5, 1.0, 0.01, 10,
                                                         0.0))]
    monkeypatch.setitem(sys.modules, mod.__name__, mod)
    monkeypatch.setenv("TERM", "dumb")
    term = Terminal()
    monkeypatch.setattr(sys, "stderr", term)
    assert cli.main(["check", "--suite", "dumb_terminal_suite:suite"]) == 0
    lines = term.getvalue().splitlines()
    assert lines[0] == "[1/5] ok ok (0.0s)" and len(lines) == 5, lines
    assert "\x1b" not in term.getvalue() and "\r" not in term.getvalue()
