"""The time-budgeted gate: allocation of a budget (exact, no timing) and the CLI's
``--budget`` end to end (structure only: the chosen n depend on this machine)."""

import json
import subprocess
import sys

import numpy as np
import pytest

import mcverify as mv
from mcverify import stats
from estimators import warps as W
from mcverify.gate import budget as B
from mcverify.gate.budget import allocate, measure_cost


def test_allocate_gives_equal_time_shares():
    fixed = {"a": 1.0, "b": 3.0}
    per = {"a": 1e-8, "b": 1e-7}
    n, predicted, notes = allocate(20.0, 4.0, 2.0, fixed, per, n_min=1000, n_max=10**12)
    # 14 s left, 7 s each: a gets (7 - 1) / 1e-8, b gets (7 - 3) / 1e-7.
    assert n == {"a": 600_000_000, "b": 40_000_000}
    assert predicted == pytest.approx(20.0) and notes == ()


def test_allocate_shares_out_the_time_a_check_at_the_minimum_cannot_use():
    """A check whose fixed cost alone exceeds its equal share runs at n_min; the others
    share what is left. With equal shares b (6 s of cubature, share 4 s) overran its share
    by 2 s while a took its full 4 s: a 20 s budget was planned at 22 s, and no note."""
    fixed, per = {"a": 0.01, "b": 6.0}, {"a": 1e-7, "b": 1e-7}
    n, predicted, notes = allocate(20.0, 10.0, 2.0, fixed, per, n_min=1 << 17, n_max=10**9)
    assert n["b"] == 1 << 17 and n["a"] > 1 << 17
    assert predicted == pytest.approx(20.0, abs=1e-6) and notes == ()
    # too small for every check's minimum: all at n_min, and said
    n, predicted, notes = allocate(20.0, 10.0, 2.0, {"a": 0.01, "b": 8.5}, per,
                                   n_min=1 << 17, n_max=10**9)
    assert n == {"a": 1 << 17, "b": 1 << 17} and predicted > 20.0 and "too small" in notes[0]


def test_allocate_clamps_and_says_when_the_budget_is_too_small():
    n, predicted, notes = allocate(5.0, 4.0, 2.0, {"a": 1.0}, {"a": 1e-8}, n_min=1000,
                                   n_max=10**9)
    assert n == {"a": 1000} and predicted > 5.0 and "too small" in notes[0]
    # no sampler check to scale: the overrun was not said (a review's noticed-left-alone)
    n, predicted, notes = allocate(5.0, 4.0, 2.0, {}, {}, n_min=1000, n_max=10**9)
    assert n == {} and predicted == 6.0 and "too small" in notes[0] and "6.0s" in notes[0]
    assert allocate(7.0, 4.0, 2.0, {}, {}, n_min=1000, n_max=10**9)[2] == ()
    # sampler checks left untimed (calibration stopped at once) do scale with n: the note
    # said "no selected check scales with n" of 28 of them (check --budget 1)
    notes = allocate(5.0, 4.0, 2.0, {}, {}, n_min=1000, n_max=10**9, untimed=28)[2]
    assert len(notes) == 1 and "every sampler check runs at the minimum n = 1,000" in notes[0]
    assert "no selected check scales" not in notes[0]
    n, _, _ = allocate(1e6, 0.0, 0.0, {"a": 0.0}, {"a": 1e-9}, n_min=1000, n_max=10**9)
    assert n == {"a": 10**9}
    # a huge budget or a free check: capped, no infinite n (OverflowError until 4 December)
    n, _, _ = allocate(1e308, 1.0, 0.0, {"a": 0.1, "b": 0.1}, {"a": 1e-8, "b": 0.0},
                       n_min=1000, n_max=10**9)
    assert n == {"a": 10**9, "b": 10**9}


class _FakeCheck:
    """A check whose run at n samples advances a fake clock by fixed + per·n seconds,
    plus the load spike ``spikes[i]`` on its i-th run."""

    def __init__(self, fixed, per, spikes=()):
        self.fixed, self.per, self.spikes, self.now, self.ns = fixed, per, spikes, 0.0, []

    def clock(self):
        return self.now

    def run_at(self, n):
        i = len(self.ns)
        self.ns.append(n)
        self.now += self.fixed + self.per * n + (self.spikes[i] if i < len(self.spikes) else 0)


@pytest.mark.parametrize("fixed, per, spikes, low", [
    (0.01, 5e-9, (), 1.0),
    # load spikes on the two small runs (the faster counts), and the first larger one
    (0.01, 5e-9, (0.02, 0.02), 0.5),
    (0.01, 5e-9, (0.02, 0.02, 0.01), 0.5),
    # the old fit (2^16, 2^18, 2^16 again) measured 0.1 ns a sample with these spikes
    (0.01, 5e-9, (0.02, 0.0, 0.02), 1.0),
    (0.0, 2e-8, (0.5,), 1.0),                           # JIT on the first run only
    (0.01, 5e-9, (0.0, 0.0, 0.0, 0.3), 1.0),            # a spike on a larger run
])
def test_measure_cost_finds_the_cost_per_sample_despite_load_spikes(fixed, per, spikes, low):
    c = _FakeCheck(fixed, per, spikes)
    f, p = measure_cost(c.run_at, c.clock)
    # never under half the true cost per sample (a run sized by it takes at most about
    # twice its share); exact but for rounding without spikes
    assert low * per * (1 - 1e-9) <= p
    if not spikes:
        assert p == pytest.approx(per) and f == pytest.approx(fixed)
        # the larger run grew until the per-sample cost showed, and no further
        big = max(c.ns)
        assert big == B._N_CAP or (big * per >= 2 * fixed and fixed + big * per >= B._MIN_LARGE_S)
        assert fixed + big // 4 * per < max(3 * (fixed + per * B._N_SMALL), B._MIN_LARGE_S)


def test_measure_cost_errs_towards_fewer_samples_when_the_fixed_cost_dominates():
    c = _FakeCheck(2.0, 1e-10)                  # cubature-like fixed cost, cheap samples
    f, p = measure_cost(c.run_at, c.clock)
    assert max(c.ns) == B._N_CAP                # grew to the cap, no further
    assert p >= 1e-10 and f + p * 10**9 >= 2.0 + 1e-10 * 10**9  # never under-predicts


def test_detectable_contamination_falls_as_one_over_root_n():
    r1 = mv.check_sampler(W.sample_cosine_hemisphere, W.cosine_hemisphere_pdf, "hemisphere",
                          n_samples=250_000, seed=1, pilot=False, resolution=(16, 32))
    r4 = mv.check_sampler(W.sample_cosine_hemisphere, W.cosine_hemisphere_pdf, "hemisphere",
                          n_samples=1_000_000, seed=1, pilot=False, resolution=(16, 32))
    e1, e4 = mv.detectable_contamination(r1), mv.detectable_contamination(r4)
    # Same cells, 4× the samples: the noncentrality is linear in n·ε², so ε halves; not
    # exactly since the counts' variance under the admixture is counted too (its terms
    # in n·ε and n·ε² scale apart: 0.4971 here, exactly ½ under the noncentral χ² used
    # until 7 December, which ignored it and overstated the power of peaked pdfs)
    assert e4 == pytest.approx(e1 / 2, rel=1e-2)
    assert e4 < e1 / 2
    assert 0.001 < e4 < 0.02
    assert mv.detectable_contamination(r4, alpha=1e-4) > e4
    # a power at or below the test's own level is no power (scipy's root finder raised)
    with pytest.raises(mv.InvalidArgument, match="power=0.001: must exceed the test's level"):
        mv.detectable_contamination(r4, power=0.001)
    assert 0 < mv.detectable_contamination(r4, power=0.01) < e4


def test_power_bought_is_at_the_level_holm_gives_the_most_significant_of_the_family():
    """``check --budget``'s ``detectable_contamination``: each sampler check's ε at α over
    the family's size (Holm's smallest level), the uniform pdf's None. A mutation review
    found the level taken as α itself passing every test: with 5 checks it reported an ε
    7 % smaller than the family-wise gate catches with 95 % power (0.0109 for 0.0117).
    Deterministic: no sampling beyond the two seeded checks."""
    cos = mv.check_sampler(W.sample_cosine_hemisphere, W.cosine_hemisphere_pdf, "hemisphere",
                           n_samples=250_000, seed=1, pilot=False, resolution=(16, 32))
    flat = mv.check_sampler(lambda u: u, lambda x: np.ones(len(x)), "square",
                            n_samples=100_000, seed=2, pilot=False)
    bought = B.power_bought([cos, flat], 0.01, n_checks=5)
    assert bought == {cos.name: mv.detectable_contamination(cos, alpha=0.002),
                      flat.name: None}
    assert B.power_bought([cos], 0.01)[cos.name] == mv.detectable_contamination(cos, alpha=0.01)
    assert bought[cos.name] > mv.detectable_contamination(cos, alpha=0.01)


def test_detectable_contamination_of_a_peaked_pdf_is_caught_at_the_power_named():
    """21x^20 on [0, 1] at 1e5 samples: a uniform admixture lands in the pdf's empty low
    end, a pooled bin whose count then scatters far more than the noncentral χ² assumed
    (variance E_b). At the ε it named, 84 of these 100 seeded checks rejected, below the
    binomial 99.9 % lower bound of 95 % power (87; an outside review). The count's own
    variance under the admixture gives a larger ε, which is caught as claimed."""
    sample = lambda u: u[:, :1] ** (1 / 21)           # noqa: E731
    pdf = lambda x: 21 * x[:, 0] ** 20                # noqa: E731
    eps = mv.detectable_contamination(mv.check_sampler(sample, pdf, "interval",
                                                       n_samples=100_000, seed=12345))

    def mixed(u):           # (1 - eps)·pdf + eps·uniform, from a third uniform number
        return np.where(u[:, 1:2] < eps, u[:, 2:3], sample(u))

    rejected = sum(not mv.check_sampler(mixed, pdf, "interval", n_samples=100_000, seed=s,
                                        sample_dim=3).passed for s in range(100))
    assert rejected >= 87, (eps, rejected)


def test_uniform_contamination_of_a_uniform_pdf_is_invisible():
    r = mv.check_sampler(W.sample_uniform_disk_polar, W.uniform_disk_pdf, "disk",
                         n_samples=100_000, seed=1)
    assert mv.detectable_contamination(r) == float("inf")


def test_detectable_contamination_needs_a_sampler_result():
    r = mv.check_unbiased([1.0, 2.0, 3.0] * 10, 2.0)
    with pytest.raises(mv.InvalidArgument, match="histogram"):
        mv.detectable_contamination(r)


def test_cli_budget_puts_the_chosen_n_and_the_power_into_the_json(tmp_path):
    out = tmp_path / "b.json"
    r = subprocess.run([sys.executable, "-m", "mcverify", "check", "--budget", "3", "-k",
                        "sampler:cosine_hemisphere", "--json", str(out), "-q"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "budget 3s" in r.stdout and "95 % power" in r.stdout
    d = json.loads(out.read_text())
    budget = d["provenance"]["budget"]
    chosen = budget["n_samples"]["sampler:cosine_hemisphere"]
    assert [x["n_samples"] for x in d["results"]] == [chosen]
    assert 0 < budget["detectable_contamination"]["sampler:cosine_hemisphere"] < 1


def test_cli_budget_without_a_sampler_check_says_so():
    """A ``-k`` that selects no sampler check has nothing to scale: the budget line says
    that instead of being left out (an outside review)."""
    r = subprocess.run([sys.executable, "-m", "mcverify", "check", "--budget", "2", "-k",
                        "inverse:cosine_hemisphere", "-q"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "budget 2s" in r.stdout and "no sampler check of ours selected" in r.stdout, \
        r.stdout


def test_cli_budget_says_mitsubas_warps_kept_their_n():
    """Mitsuba's own warps are not scaled by a budget (its Beckmann warp's horizon bug):
    the budget line said "no sampler check selected" of a run that ran one (a read-only
    review); it names them and their n."""
    r = subprocess.run([sys.executable, "-m", "mcverify", "check", "--budget", "2", "-k",
                        "sampler:mitsuba.uniform_sphere", "-q"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    assert ("1 kept the suite's n, Mitsuba's own warps, which a budget does not scale "
            "(sampler:mitsuba.uniform_sphere at 1,000,000)") in r.stdout, r.stdout


def test_cli_budget_of_uniform_pdfs_says_what_it_took():
    """Sampler checks whose pdf is uniform have no power figure (a uniform admixture is
    invisible): the budget line (took, predicted, the chosen n) was left out altogether."""
    r = subprocess.run([sys.executable, "-m", "mcverify", "check", "--budget", "2", "-k",
                        "sampler:uniform_sphere", "-q"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "budget 2s (took" in r.stdout and "sampler checks at n = " in r.stdout, r.stdout
    assert "no power figure" in r.stdout, r.stdout


def test_cli_budget_refuses_bad_values():
    for args, needle in ((["--budget", "0"], "positive"), (["--budget", "nan"], "positive"),
                         (["--budget", "5", "--scene", "x.xml"], "--scene"),
                         # was refused after the calibration
                         (["--budget", "5", "-j", "0", "-k", "sampler:cosine_hemisphere"],
                          "-j 0")):
        r = subprocess.run([sys.executable, "-m", "mcverify", "check", *args], text=True,
                           capture_output=True, timeout=600)
        assert r.returncode == 2 and needle in r.stderr, r.stderr
        assert "calibrating" not in r.stderr, r.stderr     # refused before any work


def test_calibration_stops_at_two_thirds_of_the_budget():
    """Calibration may use at most two thirds of the budget, start-up included (on busy
    cores timing every check took 167 s of a 20 s budget): past it, the checks left
    untimed run at the minimum n and a note says so. Here the start-up alone is past."""
    plan = B.plan_budget("default", "sampler:cosine_hemisphere", 10.0, startup=7.0,
                         canary=False, n_min=1 << 17)
    assert plan.n_samples == {"sampler:cosine_hemisphere": 1 << 17}
    # the note gives the time at the stop and the share it passed (it called the time at
    # the end of calibration "two thirds of the budget": 14.1 s of 15 s)
    assert any(n.startswith("calibration stopped timing sampler checks when start-up and "
                            "calibration had taken "
                            ) and "s, past two thirds of the 10s budget (6.7s" in n
               and "1 of 1 sampler checks" in n for n in plan.notes), plan.notes
    # no check was timed: the note does not speak of "the last timed check"
    assert any("no check was timed" in n for n in plan.notes), plan.notes
    assert not any("last timed check" in n for n in plan.notes), plan.notes
    # past the whole budget before any timing: the sampler check is untimed, not absent
    # (the note said "no selected check scales with n", check --budget 1)
    over = B.plan_budget("default", "sampler:cosine_hemisphere", 10.0, startup=12.0,
                         canary=False)
    assert any("every sampler check runs at the minimum n" in n for n in over.notes), over.notes
    assert not any("no selected check scales" in n for n in over.notes), over.notes
    timed = B.plan_budget("default", "sampler:cosine_hemisphere", 60.0, canary=False)
    assert not any("calibration stopped" in n for n in timed.notes)
    assert "sampler:cosine_hemisphere" in timed.per_sample_ns


def _linear_sphere(u):
    """Density (1 + 0.9 z) / 4π on the sphere, draws below the equator rejected."""
    a = 0.9
    z = (-1.0 + np.sqrt(1.0 - 2.0 * a * (1.0 - a / 2.0 - 2.0 * u[:, 0]))) / a
    z = np.clip(z, -1.0, 1.0)
    r, phi = np.sqrt(np.maximum(0.0, 1.0 - z * z)), 2.0 * np.pi * u[:, 1]
    x = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    x[z < 0.0] = np.nan
    return x


@pytest.mark.parametrize("dom, sample, pdf", [
    ("sphere", _linear_sphere,
     lambda x: np.where(x[:, 2] >= 0.0, (1.0 + 0.9 * x[:, 2]) / (4.0 * np.pi), 0.0)),
    ("interval", lambda u: np.where(u[:, :1] < 0.8, np.sqrt(u[:, :1] / 0.8), np.nan),
     lambda x: 1.6 * x[:, 0]),
], ids=["sphere", "interval"])
def test_detectable_contamination_counts_the_acceptance_test(dom, sample, pdf):
    """With rejection=True the check Bonferroni-combines the acceptance test too (α/4 in
    2-D, α/3 in 1-D); the power was computed at α/3 and α/2, as without rejection, which
    overstated it (an outside review)."""
    r = mv.check_sampler(sample, pdf, dom, n_samples=200_000, seed=1, rejection=True)
    assert r.passed, r.summary()
    h = r.artifacts["histogram"]
    e = np.asarray(h["expected"])
    widths = [np.diff(np.asarray(x)) for x in h["edges"]]
    u = (widths[0] if len(widths) == 1 else np.outer(*widths)) * e.sum()
    pairs = [(e, u)] + ([(e.sum(1), u.sum(1)), (e.sum(0), u.sum(0))] if e.ndim == 2 else [])
    level = r.alpha / len(r.details["tests"])
    assert len(r.details["tests"]) == (4 if e.ndim == 2 else 3)
    want = min(stats.chi2_detectable_mixture(a, b, alpha=level) for a, b in pairs)
    assert mv.detectable_contamination(r) == pytest.approx(want, rel=1e-9)


@pytest.mark.parametrize("overrides, needle", [
    # the full suite's name, a typo, a check that does not scale: each ran at the suite's
    # own n without a word, so a rerun "at the chosen n" silently was not one
    ((("sampler:ggx(alpha=0.5)", 1 << 17),), "not a sampler check of suite 'default'"),
    ((("sampler:cosine_hemisphere ", 1 << 17),), "not a sampler check of suite 'default'"),
    ((("inverse:cosine_hemisphere", 1 << 17),), "not a sampler check of suite 'default'"),
    # Mitsuba's Beckmann warp fails at the n a budget gave it (its own horizon bug, on 4
    # of 4 seeds at 5.4e7): Mitsuba's warps keep the suite's n (an outside review)
    ((("sampler:mitsuba.beckmann", 1 << 17),), "'sampler:mitsuba.beckmann' keeps its n"),
    ((("sampler:cosine_hemisphere", 0),), "must be >= 1"),
    ((("sampler:cosine_hemisphere", 1.5e6),), "must be an integer"),
    ((("sampler:cosine_hemisphere", "131072"),), "must be an integer"),
    ((("sampler:cosine_hemisphere",),), "(check name, n_samples) pairs"),
], ids=["other-suite", "typo", "not-scalable", "mitsuba-warp", "zero", "float", "string",
        "not-a-pair"])
def test_build_suite_refuses_n_overrides_it_cannot_apply(overrides, needle):
    """The README's rerun recipe gives a budget run's chosen n to ``build_suite``: an
    override it could not apply was silently dropped (a rerun at other n than the JSON
    says, a 'reproduction' that reproduces nothing)."""
    from mcverify.gate.suites import build_suite

    with pytest.raises(mv.InvalidArgument) as e:
        build_suite("default", overrides)
    assert needle in str(e.value), str(e.value)


def test_build_suite_takes_a_budget_runs_n_and_names_an_unknown_suite():
    from mcverify.gate.suites import build_suite

    chosen = {"sampler:cosine_hemisphere": np.int64(1 << 17),
              "sampler:power_cosine(n=20)": 200_000}
    checks = {c.name: c for c in build_suite("default", tuple(chosen.items()))}
    assert checks["sampler:cosine_hemisphere"].run(0).n_samples == 1 << 17
    with pytest.raises(mv.InvalidArgument,
                       match=r"build_suite\(.mitsuba.\): expected one of default, full"):
        build_suite("mitsuba")


def test_the_plan_records_the_calibration_it_allocated_from(monkeypatch):
    """The JSON's ``budget`` block: each timed check's cost per sample in ns and fixed
    seconds as calibration measured them, and the n ``allocate`` chose from them (a
    mutation review found a field of to_dict taken from another passing every test).
    The timing is replaced by a fixed cost, so the n is exact."""
    monkeypatch.setattr(B, "measure_cost", lambda run_at, timer=None: (0.5, 1e-7))
    name = "sampler:cosine_hemisphere"
    plan = B.plan_budget("default", name, 60.0, canary=False)
    share = 60.0 - plan.calibration_seconds - plan.other_seconds
    assert plan.per_sample_ns == {name: pytest.approx(100.0)} and plan.fixed_seconds == {name: 0.5}
    assert plan.n_samples == {name: int((share - 0.5) / 1e-7)}
    assert plan.n_overrides == ((name, plan.n_samples[name]),)
    d = plan.to_dict()
    assert (d["budget_seconds"], d["n_samples"], d["per_sample_ns"], d["fixed_seconds"]) == (
        60.0, plan.n_samples, plan.per_sample_ns, plan.fixed_seconds)
    assert (d["other_seconds"], d["startup_seconds"], d["calibration_seconds"],
            d["predicted_seconds"], d["notes"]) == (
        plan.other_seconds, 0.0, plan.calibration_seconds, plan.predicted_seconds, [])
    assert plan.predicted_seconds == pytest.approx(60.0)
