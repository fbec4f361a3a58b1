"""Slow, high-power statistics of the judge itself (``pytest -m slow``).

Calibration: over 300 seeded runs of correct samplers (continuous and discontinuous
pdfs), the number of false alarms at α = 0.01 must not exceed the binomial 99.9 % upper
bound (7 of 300). Power: contamination by ε = 1 % uniform must be rejected in >= 95 %
of seeds at 1e6 samples.
"""

import numpy as np
import pytest

import mcverify as mv
from estimators import warps as W
from mcverify import stats

pytestmark = pytest.mark.slow

STEP = 0.37


def step_sample(u):   # piecewise-constant pdf with a step inside a cell
    a = 0.25 / STEP   # density on [0, STEP); mass 0.25
    b = 0.75 / (1 - STEP)
    x = np.where(u[:, 0] < 0.25, u[:, 0] / a, STEP + (u[:, 0] - 0.25) / b)
    return x


def step_pdf(x):
    return np.where(x[:, 0] < STEP, 0.25 / STEP, 0.75 / (1 - STEP))


SUBJECTS = [
    ("cosine", W.sample_cosine_hemisphere, W.cosine_hemisphere_pdf, "hemisphere"),
    ("cone", lambda u: W.sample_uniform_cone(u, 0.8), lambda x: W.uniform_cone_pdf(x, 0.8),
     "sphere"),
    ("triangle", W.sample_uniform_triangle, W.uniform_triangle_pdf, "square"),
    ("step", step_sample, step_pdf, "interval"),
    ("ggx", lambda u: W.sample_ggx(u, 0.05), lambda x: W.ggx_pdf(x, 0.05), "hemisphere"),
    ("tent", lambda u: W.sample_tent(u, 1.0), lambda x: W.tent_pdf(x, 1.0), mv.Interval(-1, 1)),
]
RUNS = 300


def test_false_alarm_rate_is_calibrated():
    rejections = {}
    for i in range(RUNS):
        label, s, p, d = SUBJECTS[i % len(SUBJECTS)]
        r = mv.check_sampler(s, p, d, seed=1000 + i, alpha=0.01)
        rejections[label] = rejections.get(label, 0) + (not r.passed)
    total = sum(rejections.values())
    bound = stats.binomial_upper_bound(RUNS, 0.01, 0.999)
    print(f"false alarms: {total}/{RUNS} (bound {bound}) by subject {rejections}")
    assert total <= bound, rejections


def _mixture(eps):
    def sample(u):
        x = W.sample_cosine_hemisphere(u)
        flip = np.random.default_rng(int(u[0, 0] * 2**31)).random(u.shape[0]) < eps
        x[flip] = W.sample_uniform_hemisphere(u[flip])
        return x
    return sample


# 1 % contamination: rejected in 40 of 40 seeds (1e6 samples), the README's claim of at
# least 95 % power; 0.5 %: in 27 of 40, floored at 14 of 40, the binomial 99.9 % lower
# bound of 60 % power: a judge that lost power fails here.
@pytest.mark.parametrize("eps,min_rate", [(0.01, 0.95), (0.005, 0.35)])
def test_power_against_contamination(eps, min_rate):
    seeds = 40
    rejected = sum(not mv.check_sampler(_mixture(eps), W.cosine_hemisphere_pdf, "hemisphere",
                                        seed=s).passed for s in range(seeds))
    print(f"eps={eps}: rejected {rejected}/{seeds}")
    assert rejected / seeds >= min_rate


def test_detectable_contamination_is_what_the_check_catches():
    """The power figure is honest: at the ε that ``detectable_contamination`` says a
    check catches with 95 % power, 40 seeded runs reject at least the binomial 99.9 %
    lower bound of 95 % (33 of 40)."""
    ok = mv.check_sampler(W.sample_cosine_hemisphere, W.cosine_hemisphere_pdf, "hemisphere",
                          seed=0)
    eps = mv.detectable_contamination(ok)
    seeds = 40
    rejected = sum(not mv.check_sampler(_mixture(eps), W.cosine_hemisphere_pdf, "hemisphere",
                                        seed=s).passed for s in range(seeds))
    print(f"eps95={eps:.4g}: rejected {rejected}/{seeds}")
    assert rejected >= 33
