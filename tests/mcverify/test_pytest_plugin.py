"""The pytest plugin (loaded through the installed pytest11 entry point)."""

import subprocess
import sys

import pytest

import mcverify as mv
from estimators import warps as W


def _pytest_on(path, *options, env=None):
    """pytest run quietly on one generated test file, in its folder, with ``options``."""
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                           *options, str(path)], cwd=path.parent, env=env,
                          capture_output=True, text=True, timeout=300)


def test_seed_fixture_defaults_to_zero(mcverify_seed):
    assert mcverify_seed == 0


def test_assert_check_passes_through_and_fails_with_the_reason(assert_check):
    good = mv.check_sampler(W.sample_cosine_hemisphere, W.cosine_hemisphere_pdf, "hemisphere",
                            n_samples=50_000)
    assert assert_check(good) is good
    bad = mv.check_sampler(W.sample_cosine_hemisphere,
                           lambda x: 1.05 * W.cosine_hemisphere_pdf(x), "hemisphere",
                           n_samples=50_000)
    with pytest.raises(pytest.fail.Exception, match="integrates to 1.05") as failed:
        assert_check(bad)
    # each failure once: the summary line carries them (they were printed twice)
    text = str(failed.value)
    assert all(text.count(f) == 1 for f in bad.failures), text
    inverse = mv.check_inverse(lambda u: u, lambda x: x * 1.1, 1, n_samples=100)
    with pytest.raises(pytest.fail.Exception) as failed:
        assert_check(inverse)
    assert str(failed.value).count(inverse.failures[0]) == 1, str(failed.value)
    with pytest.raises(pytest.fail.Exception, match="expects the CheckResult of a mcverify "
                                                   "check, got bool True"):
        assert_check(True)


def test_a_negative_seed_is_refused_before_any_test_runs(tmp_path):
    """--mcverify-seed -1 used to reach every check, each failing on its own."""
    (tmp_path / "test_x.py").write_text("def test_x(mcverify_seed):\n    pass\n")
    r = _pytest_on(tmp_path / "test_x.py", "--mcverify-seed", "-1")
    assert r.returncode == pytest.ExitCode.USAGE_ERROR, (r.stdout, r.stderr)
    assert "--mcverify-seed=-1: must be in [0, 2**63 - 1]" in r.stderr, r.stderr


def test_a_seed_that_is_not_decimal_digits_is_refused(tmp_path):
    """``--mcverify-seed=1_0`` was read as 10 (Python's int() takes underscores and other
    scripts' digits; an outside review)."""
    (tmp_path / "test_x.py").write_text("def test_x(mcverify_seed):\n    pass\n")
    r = _pytest_on(tmp_path / "test_x.py", "--mcverify-seed=1_0")
    assert r.returncode == pytest.ExitCode.USAGE_ERROR, (r.stdout, r.stderr)
    assert "invalid int value: '1_0'" in r.stderr, r.stderr


@pytest.mark.parametrize("env, total, want", [
    ({}, 2, None),                                                        # no xdist
    ({"PYTEST_XDIST_WORKER_COUNT": "2"}, 2, None),                        # the controller
    ({"PYTEST_XDIST_WORKER_COUNT": "2", "PYTEST_XDIST_WORKER": "gw1"}, 2, 1),
    ({"PYTEST_XDIST_WORKER_COUNT": "2", "PYTEST_XDIST_WORKER": "gw0"}, 16, 8),
    ({"PYTEST_XDIST_WORKER_COUNT": "3", "PYTEST_XDIST_WORKER": "gw2"}, 16, 5),
    ({"PYTEST_XDIST_WORKER_COUNT": "4", "PYTEST_XDIST_WORKER": "gw3"}, 2, 1),
    ({"PYTEST_XDIST_WORKER_COUNT": "1", "PYTEST_XDIST_WORKER": "gw0"}, 4, None),
])
def test_xdist_workers_get_an_equal_share_of_numbas_threads(monkeypatch, env, total, want):
    from _mcverify_pytest import worker_threads

    for k in ("PYTEST_XDIST_WORKER_COUNT", "PYTEST_XDIST_WORKER"):
        monkeypatch.delenv(k, raising=False)
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    assert worker_threads(total) == want


def test_this_run_shares_the_cores_unless_told_not_to(pytestconfig):
    """In this very run: a pytest-xdist worker of N has NUMBA_NUM_THREADS // N threads
    (this test runs in the worker's main thread), a lone process all of them."""
    import numba

    from _mcverify_pytest import worker_threads

    total = numba.config.NUMBA_NUM_THREADS
    share = worker_threads(total)
    if share is None or pytestconfig.getoption("mcverify_all_threads"):
        assert numba.get_num_threads() == total
    else:
        assert numba.get_num_threads() == share
        # ... and the processes its tests start inherit the share
        import subprocess
        import sys
        script = ("import numba, mcverify.gate.cli as c; c._thread_limit(); "
                  "print(numba.get_num_threads())")
        r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                           timeout=120, check=True)
        assert int(r.stdout) == share


def test_the_seed_is_in_the_header_and_in_a_failure(tmp_path):
    """A failing check said nothing of the seed it ran with, nor did pytest's header: a CI
    job that varies --mcverify-seed could not say which one to rerun."""
    (tmp_path / "test_x.py").write_text(
        "import mcverify as mv\n"
        "from estimators import warps as W\n"
        "def test_x(assert_check, mcverify_seed):\n"
        "    assert_check(mv.check_sampler(W.sample_cosine_hemisphere,\n"
        "        lambda x: 1.05 * W.cosine_hemisphere_pdf(x), 'hemisphere',\n"
        "        n_samples=20_000, seed=mcverify_seed + 1))\n")
    r = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider",
                        "--mcverify-seed", "41", str(tmp_path / "test_x.py")],
                       cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert r.returncode == pytest.ExitCode.TESTS_FAILED, (r.stdout, r.stderr)
    assert "mcverify: --mcverify-seed=41" in r.stdout, r.stdout
    assert "check seed=42; run with --mcverify-seed=41" in r.stdout, r.stdout


def test_the_fixtures_serve_a_session_scoped_fixture(tmp_path):
    """Both fixtures were function-scoped, so a session fixture that renders a reference
    once with the run's seed (or a module fixture that checks it) stopped every test with
    pytest's ScopeMismatch; the seed and the checker are the run's, not a test's."""
    (tmp_path / "test_x.py").write_text(
        "import pytest\n"
        "import mcverify as mv\n"
        "@pytest.fixture(scope='session')\n"
        "def ref(mcverify_seed, assert_check):\n"
        "    return mcverify_seed, assert_check(mv.check_unbiased([1.0, 1.0], 1.0))\n"
        "def test_x(ref, mcverify_seed):\n"
        "    assert ref[0] == mcverify_seed == 5 and ref[1].passed\n")
    r = _pytest_on(tmp_path / "test_x.py", "--mcverify-seed", "5")
    assert r.returncode == pytest.ExitCode.OK, (r.stdout, r.stderr)


def test_a_thread_count_the_user_set_is_kept_for_the_runs_tests_start(tmp_path):
    """Each pytest-xdist worker set MCVERIFY_NUM_THREADS to its share whatever it held:
    ``MCVERIFY_NUM_THREADS=1 pytest -n 2`` on 4 threads ran the tests' mcverify commands
    on 2 threads each."""
    import os

    (tmp_path / "test_x.py").write_text(
        "import os\n"
        "def test_x():\n"
        "    assert os.environ['PYTEST_XDIST_WORKER'] and "
        "os.environ['MCVERIFY_NUM_THREADS'] == '1'\n")
    env = {**os.environ, "MCVERIFY_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "4"}
    r = _pytest_on(tmp_path / "test_x.py", "-n", "2", env=env)
    assert r.returncode == pytest.ExitCode.OK, (r.stdout, r.stderr)


def test_a_failure_says_which_call_failed(tmp_path):
    """A failed check showed its summary and nothing of where: in a test that checks the
    same sampler twice (two resolutions) the two failures read alike. The line of the
    assert_check call is given, or of the call of a helper that hides itself from
    tracebacks (``__tracebackhide__``), as pytest's own frames are read."""
    (tmp_path / "test_x.py").write_text(
        "import mcverify as mv\n"
        "def helper(assert_check, r):\n"
        "    __tracebackhide__ = True\n"
        "    assert_check(r)\n"
        "def test_x(assert_check):\n"
        "    assert_check(mv.check_unbiased([1.0, 1.0], 1.0))\n"
        "    assert_check(mv.check_unbiased([0.0, 1.0] * 50, 2.0))\n"
        "def test_y(assert_check):\n"
        "    helper(assert_check, mv.check_unbiased([0.0, 1.0] * 50, 2.0))\n")
    r = _pytest_on(tmp_path / "test_x.py")
    assert r.returncode == pytest.ExitCode.TESTS_FAILED, (r.stdout, r.stderr)
    assert "failed at test_x.py:7\n" in r.stdout, r.stdout
    assert "failed at test_x.py:9\n" in r.stdout, r.stdout


def test_a_failure_in_a_given_test_says_which_example_failed(tmp_path):
    """assert_check fails the test with pytest.fail(pytrace=False), whose report is the
    message alone: in the caller's ``@given`` test ("stable for every roughness") the
    note hypothesis adds with the failing example, ``Failing test case: test_x(a=3)``,
    was dropped, and the user learnt that some parameter failed, not which."""
    (tmp_path / "test_x.py").write_text(
        "import mcverify as mv\n"
        "from hypothesis import given, settings, strategies as st\n"
        "@settings(max_examples=20, deadline=None, database=None, derandomize=True)\n"
        "@given(a=st.integers(0, 5))\n"
        "def test_x(a, assert_check):\n"
        "    assert_check(mv.check_unbiased([0.0, 1.0] * 50, 0.5 if a < 3 else 2.0))\n")
    r = _pytest_on(tmp_path / "test_x.py")
    assert r.returncode == pytest.ExitCode.TESTS_FAILED, (r.stdout, r.stderr)
    assert "failed at test_x.py:6\n" in r.stdout, r.stdout
    assert "a=3," in r.stdout, r.stdout
    assert "test_x.py::test_x - Failed: FAIL unbiased" in r.stdout, r.stdout


def test_pytest_fixtures_describes_both_fixtures(tmp_path):
    """``pytest --fixtures``, where a team finds what a plugin offers, said "no docstring
    available" for both."""
    (tmp_path / "test_x.py").write_text("def test_x():\n    pass\n")
    r = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider",
                        "--fixtures", str(tmp_path / "test_x.py")],
                       cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert r.returncode == pytest.ExitCode.OK, (r.stdout, r.stderr)
    ours = r.stdout.split("fixtures defined from _mcverify_pytest")[1]
    ours = ours.split("fixtures defined from")[0].split("=====")[0]
    assert "no docstring" not in ours and "--mcverify-seed" in ours, ours
    assert "CheckResult" in ours, ours


@pytest.mark.parametrize("xdist", [[], ["-n", "2"]], ids=["serial", "xdist"])
def test_a_suite_that_never_uses_mcverify_is_left_alone(tmp_path, xdist):
    """The plugin was ``mcverify.pytest_plugin``: loading it imported the package, so every
    pytest run of an environment with mcverify installed imported numba and scipy and set
    ``NUMBA_CPU_FEATURES`` on AVX-512 hosts (the user's own numba kernels then compiled
    and cached anew), also in test suites that never use mcverify (an outside review)."""
    import os

    (tmp_path / "test_x.py").write_text(
        "import os, sys\n"
        "def test_x():\n"
        "    heavy = [m for m in ('mcverify', 'numba', 'scipy') if m in sys.modules]\n"
        "    assert not heavy and 'NUMBA_CPU_FEATURES' not in os.environ, heavy\n")
    env = {k: v for k, v in os.environ.items()
           if k not in ("NUMBA_CPU_FEATURES", "MCVERIFY_NUM_THREADS")}
    r = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider",
                        *xdist, str(tmp_path / "test_x.py")],
                       cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == pytest.ExitCode.OK, (r.stdout, r.stderr)
    assert "mcverify: --mcverify-seed=0" in r.stdout, r.stdout     # the plugin was loaded


def test_an_xdist_worker_shares_the_cores_with_numba_imported_by_a_test(tmp_path):
    """The plugin no longer imports numba itself: a worker whose tests import it late (in
    a test's body, after collection) runs its numba loops on its share from the next test
    on (``--dist loadfile``: one worker runs the file, in order)."""
    import os

    (tmp_path / "test_x.py").write_text(
        "def test_imports_numba():\n"
        "    import numba  # noqa: F401\n"
        "def test_after_it():\n"
        "    import numba\n"
        "    assert numba.get_num_threads() == 2, numba.get_num_threads()\n")
    env = {**os.environ, "NUMBA_NUM_THREADS": "4"}
    env.pop("MCVERIFY_NUM_THREADS", None)
    r = _pytest_on(tmp_path / "test_x.py", "-n", "2", "--dist", "loadfile", env=env)
    assert r.returncode == pytest.ExitCode.OK, (r.stdout, r.stderr)
