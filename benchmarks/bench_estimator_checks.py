"""pytest-benchmark of the estimator checks at 10^7 estimates (`make bench`): they run on
numpy alone, with no Mitsuba counterpart, so the rows are ours only; compare them with a
saved baseline (`--benchmark-compare`). Skewed estimates (an exponential, shifted to take
both signs) are the case the skewness and tail terms work on."""

import numpy as np
import pytest

import mcverify as mv

N = 10 ** 7


@pytest.fixture(scope="module")
def estimates():
    return np.random.default_rng(1).exponential(size=N) - 0.3


@pytest.mark.parametrize("check", ["check_unbiased", "check_variance"])
def test_estimator_check(benchmark, estimates, check):
    fn = {"check_unbiased": lambda: mv.check_unbiased(estimates, 0.7),
          "check_variance": lambda: mv.check_variance(estimates, 1.0)}[check]
    benchmark.group = f"{check}, 1e7 estimates"
    r = benchmark.pedantic(fn, rounds=3, warmup_rounds=1)
    assert r.passed, r.summary()
