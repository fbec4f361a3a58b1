"""The sequential render gate: planted bugs are decided on a quarter of the passes, a
correct render runs all of them and ends with the pixel tests."""

import pytest

import mcverify as mv

pytestmark = pytest.mark.mitsuba


@pytest.mark.parametrize("plant,pdf_scale,decided_by", [
    ({"albedo_scale": 1.1}, 1.0, 1), (None, 1.1, 1), ({"light_scale": 0.98}, 1.0, 1),
    # +2 % light: z ≈ 8.7 on all 16 passes; O'Brien–Fleming spending stops at 1/4 only
    # from z ≈ 4 · 2.58 = 10.3, so this one is decided at half the passes.
    ({"light_scale": 1.02}, 1.0, 2),
], ids=["albedo+10%", "wrong-pdf", "light-2%", "light+2%"])
def test_planted_bugs_are_decided_early(plant, pdf_scale, decided_by):
    r = mv.render_check("cornell-box", seed=12, plant=plant, pdf_scale=pdf_scale)
    seq = r.details["sequential"]
    assert not r.passed and seq["batches"] == 4 and seq["batch"] <= decided_by, seq
    assert r.details["ours_passes"] == 4 * seq["batch"]
    assert r.n_samples == 1024 * seq["batch"] // 4 * 64 * 64
    assert r.details["tests"] == ["global", "blocks"]          # early looks: pooled tests
    assert f"decided at batch {seq['batch']} of 4 (stopped early)" in r.messages


def test_a_correct_render_runs_every_pass_and_ends_with_the_pixel_tests():
    r = mv.render_check("cornell-box", seed=11)
    seq = r.details["sequential"]
    assert r.passed and seq["batch"] == 4 and seq["looks"] == [1, 2, 4]
    assert r.details["tests"] == ["global", "blocks", "pixels"]
    assert r.details["ours_passes"] == 16 and not seq["stopped_early"]
    assert r.p_value >= min(seq["p_looks"])     # the sequential p-value is conservative
