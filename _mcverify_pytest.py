"""mcverify's pytest plugin, for renderer projects' own test suites (entry point
``pytest11``, name ``mcverify``: ``-p no:mcverify`` turns it off).

A top-level module, apart from the ``mcverify`` package: pytest loads every installed
plugin in every run, also of test suites that never use mcverify, and importing the
package imports numba and scipy (0.34 s) and, on an AVX-512 host, sets
``NUMBA_CPU_FEATURES`` (``mcnumba.vector_width``), under which a user's own numba
kernels compile and cache anew. As ``mcverify.pytest_plugin`` it did all that in every
pytest run of an environment where mcverify was installed (until 7 December; an
outside review). This module imports only pytest and the standard library; mcverify,
and numba, are imported where a test uses them.

Fixtures:

- ``mcverify_seed``: the seed for this run (``--mcverify-seed``, default 0), so a CI
  job can pin or vary it.
- ``assert_check``: call it on a ``CheckResult``; it fails the test with the check's
  failures and messages (p-value, worst cell, ``u -> x -> u'`` chain), the line of the
  call (``failed at tests/test_x.py:12``) and the seeds (the check's, where it records
  one, and ``--mcverify-seed``) when it did not pass.

Both are session-scoped, so fixtures of any scope (a session fixture that renders a
reference once with the seed) can use them.

The run's ``--mcverify-seed`` is in pytest's header.

Under pytest-xdist (``-n N``), each worker's numba parallel loops get an equal share of
the cores, ``NUMBA_NUM_THREADS // N`` threads (at least 1), as mcverify's own worker
processes do: N workers each running every core's worth of OpenMP threads wait for
descheduled threads and spin (measured on 2 cores, ``-n 2``, three of mcverify's judge
test files: 115-124 s wall and 181-196 s of CPU with two threads a worker, 75 s and
96-100 s with one). The mcverify runs a test starts get the same share (the worker sets
``MCVERIFY_NUM_THREADS``, which the CLI reads, unless the user set it): a CLI run of 2
threads beside a busy worker paid about 7 ms for every parallel loop it started, waiting
for its descheduled second thread. The share applies once numba is imported (from the
first test after a test's own ``import numba``). Results do not depend on the thread
count. ``--mcverify-all-threads`` keeps numba's default in every
worker.

Example::

    def test_my_cosine_sampler(assert_check, mcverify_seed):
        assert_check(mcverify.check_sampler(my_sample, my_pdf, "hemisphere",
                                            seed=mcverify_seed))
"""

from __future__ import annotations

import os
import sys

import pytest


def _decimal_int(text):
    """``--mcverify-seed``'s type: decimal digits only (``mcverify._validate.decimal_int``;
    imported when the option is given, so that loading the plugin stays light)."""
    from mcverify._validate import decimal_int

    return decimal_int(text)


def pytest_addoption(parser):
    group = parser.getgroup("mcverify")
    group.addoption("--mcverify-seed", type=_decimal_int, default=0,
                    help="seed passed to mcverify checks through the mcverify_seed fixture")
    group.addoption("--mcverify-all-threads", action="store_true",
                    help="under pytest-xdist, let every worker's numba loops use all the "
                         "cores (default: an equal share each)")


def worker_threads(total: int) -> int | None:
    """numba threads for this process when it is one of N >= 2 pytest-xdist workers
    (``total // N``, at least 1); None when it is not such a worker."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1") or 1)
    if workers < 2 or not os.environ.get("PYTEST_XDIST_WORKER"):
        return None
    return max(1, total // workers)


def _numba_threads() -> int | None:
    """numba's thread pool size for this process, as numba computes it
    (``NUMBA_NUM_THREADS``, else the CPUs this process may run on), without importing
    numba where it is not imported yet; None where the variable is not a whole number
    (numba refuses it as it is imported, and says so then)."""
    numba = sys.modules.get("numba")
    if numba is not None:
        return numba.config.NUMBA_NUM_THREADS
    given = os.environ.get("NUMBA_NUM_THREADS", "").strip()
    if given:
        return int(given) if given.isdigit() and given.isascii() else None
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


#: the attribute of pytest's config holding the worker's share until numba is imported
#: (an attribute, not ``config.stash``: the plugin loads in every pytest run, and
#: ``pytest.StashKey`` needs pytest 7, which mcverify does not require)
_SHARE = "_mcverify_thread_share"


def _apply_share(config) -> None:
    """Give this thread's numba loops the worker's share once numba is imported: at the
    start, or before the first test after it (the tests' modules import it as they are
    collected, or a test does). The plugin imports no numba of its own: a test suite may
    never use it."""
    share = getattr(config, _SHARE, None)
    if share is not None and "numba" in sys.modules:
        setattr(config, _SHARE, None)
        sys.modules["numba"].set_num_threads(share)


def pytest_configure(config):
    seed = config.getoption("mcverify_seed")
    if not 0 <= seed <= 2 ** 63 - 1:        # as mcverify check --seed
        raise pytest.UsageError(f"--mcverify-seed={seed}: must be in [0, 2**63 - 1]")
    if config.getoption("mcverify_all_threads"):
        return
    total = _numba_threads()
    threads = None if total is None else worker_threads(total)
    if threads is None:
        return
    # The mcverify runs the tests start read the share from the environment (not
    # NUMBA_NUM_THREADS: numba re-reads that in this process too, and refuses a change
    # once its threads run). A value the user set is theirs: it was overwritten, so
    # MCVERIFY_NUM_THREADS=1 pytest -n 2 ran those runs on half the cores each.
    if not os.environ.get("MCVERIFY_NUM_THREADS", "").strip():
        os.environ["MCVERIFY_NUM_THREADS"] = str(threads)
    # numba's thread count is per thread: this sets the worker's main thread, which
    # runs the tests.
    setattr(config, _SHARE, threads)
    _apply_share(config)


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    _apply_share(item.config)


def pytest_report_header(config):
    # the seed a failure reproduces with (a CI job that varies it printed it nowhere)
    return f"mcverify: --mcverify-seed={config.getoption('mcverify_seed')}"


def _caller(rootpath) -> str:
    """``file:line`` of the call of ``assert_check`` (the failure has no traceback, and two
    checks of one sampler in a test read alike), past the frames that hide themselves
    from tracebacks (``__tracebackhide__``, a user's helper), as pytest reads them."""
    frame = sys._getframe(2)
    while frame.f_back is not None and frame.f_locals.get("__tracebackhide__"):
        frame = frame.f_back
    path = os.path.abspath(frame.f_code.co_filename)
    rel = os.path.relpath(path, rootpath)
    return f"{path if rel.startswith(os.pardir) else rel}:{frame.f_lineno}"


class _CheckFailed(pytest.fail.Exception):
    """``pytest.fail(msg, pytrace=False)`` whose report keeps the notes added to it on its
    way out: pytest reports such a failure by its message alone, so in the caller's
    ``@given`` test the note hypothesis adds, ``Failing test case: test_x(a=3)``, was
    dropped, and which example failed went unsaid (until 7 December; an outside review)."""

    def __str__(self) -> str:
        return "\n".join([self.msg, *map(str, getattr(self, "__notes__", ()))])

    __repr__ = __str__


# reported as pytest.fail's are, "Failed: FAIL ..." (pytest's outcomes live in builtins
# for this), not "_mcverify_pytest._CheckFailed: ..."
_CheckFailed.__module__ = "builtins"
_CheckFailed.__name__ = _CheckFailed.__qualname__ = "Failed"


# Session-scoped, as the run's seed and checker are: a session fixture that renders a
# reference once with the seed could not request them (pytest's ScopeMismatch).
@pytest.fixture(scope="session")
def mcverify_seed(request) -> int:
    """The seed of this run for mcverify checks (``--mcverify-seed``, default 0; in
    pytest's header): pass it as the checks' ``seed``."""
    return request.config.getoption("--mcverify-seed")


@pytest.fixture(scope="session")
def assert_check(request):
    """Call it on a mcverify ``CheckResult``: returns it if it passed, else fails the test
    with its summary and messages, the line of the call and the seeds to rerun it."""
    run_seed = request.config.getoption("mcverify_seed")

    def check(result):
        __tracebackhide__ = True
        from mcverify.result import CheckResult

        if not isinstance(result, CheckResult):
            pytest.fail(f"assert_check expects the CheckResult of a mcverify check, got "
                        f"{type(result).__name__} {result!r:.80}", pytrace=False)
        if not result.passed:
            # the summary line carries the failures already; messages not repeated
            lines = [result.summary(), *dict.fromkeys(m for m in result.messages
                                                      if m not in result.failures)]
            lines.append(f"failed at {_caller(request.config.rootpath)}")
            seed = result.details.get("seed")
            lines.append(("" if seed is None else f"check seed={seed}; ")
                         + f"run with --mcverify-seed={run_seed}")
            raise _CheckFailed("\n".join(lines), pytrace=False)
        return result

    return check
