"""The pytest plugin (loaded through the installed pytest11 entry point)."""

import pytest

import mcverify as mv
from estimators import warps as W


def test_seed_fixture_defaults_to_zero(mcverify_seed):
    assert mcverify_seed == 0


def test_assert_check_passes_through_and_fails_with_the_reason(assert_check):
    good = mv.check_sampler(W.sample_cosine_hemisphere, W.cosine_hemisphere_pdf, "hemisphere",
                            n_samples=50_000)
    assert assert_check(good) is good
    bad = mv.check_sampler(W.sample_cosine_hemisphere,
                           lambda x: 1.05 * W.cosine_hemisphere_pdf(x), "hemisphere",
                           n_samples=50_000)
    with pytest.raises(pytest.fail.Exception, match="integrates to 1.05"):
        assert_check(bad)
