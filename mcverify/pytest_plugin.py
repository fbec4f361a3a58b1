"""pytest plugin for renderer projects' own test suites (entry point ``pytest11``).

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
for its descheduled second thread. Results do
not depend on the thread count. ``--mcverify-all-threads`` keeps numba's default in every
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
    """``--mcverify-seed``'s type: decimal digits only (``_validate.decimal_int``; imported
    when the option is given, so that loading the plugin stays light)."""
    from ._validate import decimal_int

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


def pytest_configure(config):
    seed = config.getoption("mcverify_seed")
    if not 0 <= seed <= 2 ** 63 - 1:        # as mcverify check --seed
        raise pytest.UsageError(f"--mcverify-seed={seed}: must be in [0, 2**63 - 1]")
    # numba's thread count is per thread: this sets the worker's main thread, which
    # runs the tests.
    if config.getoption("mcverify_all_threads"):
        return
    import numba

    threads = worker_threads(numba.config.NUMBA_NUM_THREADS)
    if threads is not None:
        numba.set_num_threads(threads)
        # The mcverify runs the tests start read the share from the environment (not
        # NUMBA_NUM_THREADS: numba re-reads that in this process too, and refuses a change
        # once its threads run). A value the user set is theirs: it was overwritten, so
        # MCVERIFY_NUM_THREADS=1 pytest -n 2 ran those runs on half the cores each.
        if not os.environ.get("MCVERIFY_NUM_THREADS", "").strip():
            os.environ["MCVERIFY_NUM_THREADS"] = str(threads)


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
            pytest.fail("\n".join(lines), pytrace=False)
        return result

    return check
