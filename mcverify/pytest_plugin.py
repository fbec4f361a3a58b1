"""pytest plugin for renderer projects' own test suites (entry point ``pytest11``).

Fixtures:

- ``mcverify_seed``: the seed for this run (``--mcverify-seed``, default 0), so a CI
  job can pin or vary it.
- ``assert_check``: call it on a ``CheckResult``; it fails the test with the check's
  failures and messages (p-value, worst cell, ``u -> x -> u'`` chain) when it did not pass.

Example::

    def test_my_cosine_sampler(assert_check, mcverify_seed):
        assert_check(mcverify.check_sampler(my_sample, my_pdf, "hemisphere",
                                            seed=mcverify_seed))
"""

from __future__ import annotations

import pytest


def pytest_addoption(parser):
    group = parser.getgroup("mcverify")
    group.addoption("--mcverify-seed", type=int, default=0,
                    help="seed passed to mcverify checks through the mcverify_seed fixture")


@pytest.fixture
def mcverify_seed(request) -> int:
    return request.config.getoption("--mcverify-seed")


@pytest.fixture
def assert_check():
    def check(result):
        __tracebackhide__ = True
        if not result.passed:
            lines = [result.summary(), *result.failures, *result.messages]
            pytest.fail("\n".join(lines), pytrace=False)
        return result

    return check
