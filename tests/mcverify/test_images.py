"""compare_images: calibrated under A/A (synthetic skewed pixels and real Mitsuba renders),
and it catches a global ±2 % bias and a local +10 % one, saying which test found what."""

import os
import re

import numpy as np
import pytest

import mcverify as mv
from mcverify import stats

ALPHA = 0.01
RUNS = 200
BOUND = stats.binomial_upper_bound(RUNS, ALPHA, 0.999)


def _pair(rng, shape_k, n, size=(32, 32, 3), scale_b=1.0, local=None):
    a = rng.gamma(shape_k, 1.0, size + (n,))
    b = rng.gamma(shape_k, 1.0, size + (n,)) * scale_b
    if local is not None:
        b[local] *= 1.10
    return dict(test_mean=a.mean(-1), ref_mean=b.mean(-1), test_var=a.var(-1, ddof=1),
                ref_var=b.var(-1, ddof=1), test_n=n, ref_n=n)


@pytest.mark.parametrize("shape_k,n", [(0.5, 8), (0.1, 64)], ids=["skewed-n8", "heavy-n64"])
def test_false_alarms_within_binomial_bound(shape_k, n):
    alarms = sum(not mv.compare_images(**_pair(np.random.default_rng(s), shape_k, n),
                                       alpha=ALPHA).passed for s in range(RUNS))
    assert alarms <= BOUND, (alarms, BOUND)


def test_four_passes_against_sixteen_stay_calibrated():
    """Four pass means a pixel (gamma shape 6.4: a 64-spp mean of samples with skewness
    6) against a 16-pass reference of the same expectation, all three tests: false alarms
    within the binomial bound over 200 seeds. With Welch–Satterthwaite degrees of freedom
    the pixel t-tests alone raised 107 (``stats.welch_dof``)."""
    def pair(rng):
        a = rng.gamma(6.4, 1.0, (16, 16, 3, 4))
        b = rng.gamma(25.6, 0.25, (16, 16, 3, 16))
        return dict(test_mean=a.mean(-1), ref_mean=b.mean(-1), test_var=a.var(-1, ddof=1),
                    ref_var=b.var(-1, ddof=1), test_n=4, ref_n=16, perceptual=False)

    alarms = sum(not mv.compare_images(**pair(np.random.default_rng(s))).passed
                 for s in range(RUNS))
    assert alarms <= BOUND, (alarms, BOUND)


@pytest.mark.parametrize("n_ref,n_test", [(2, 16), (2, 4), (3, 64)])
def test_a_reference_of_two_or_three_passes_stays_calibrated(n_ref, n_test):
    """A reference of 2 passes gives each pixel's variance 1 degree of freedom. The image
    and block tests treated their summed variances as known (a z-test): where a few
    pixels of a block carry most of its variance (bright and dark pixels side by side:
    pixel scales lognormal(0, 1.5)), that sum has few degrees of freedom too, and the
    z-test raised 147 false alarms in 200 seeds (2 passes against 16), 104 (2 against 4)
    and 125 (3 against 64); an outside review met one on a real scene (``reference build
    --passes 2``). They now take Student's t with the sum's Satterthwaite degrees of
    freedom (the smaller side's count of pixels): 0, 1 and 1, within the binomial bound
    (near-normal pass values: gamma shape 30, a 64-spp mean of samples with skewness
    1.4)."""
    def pair(rng):
        scale = rng.lognormal(0.0, 1.5, (32, 32, 1, 1))
        a = rng.gamma(30.0, 1.0, (32, 32, 3, n_test)) * scale
        b = rng.gamma(30.0, 1.0, (32, 32, 3, n_ref)) * scale
        return dict(test_mean=a.mean(-1), ref_mean=b.mean(-1), test_var=a.var(-1, ddof=1),
                    ref_var=b.var(-1, ddof=1), test_n=n_test, ref_n=n_ref, perceptual=False)

    results = [mv.compare_images(**pair(np.random.default_rng(s))) for s in range(RUNS)]
    alarms = sum(not r.passed for r in results)
    assert alarms <= BOUND, (alarms, BOUND, [r.details["found_by"] for r in results
                                             if not r.passed])


@pytest.mark.parametrize("n_test,n_ref", [(16, 2), (2, 16)])
def test_a_bright_pixel_caught_low_by_few_passes_is_no_evidence(n_test, n_ref):
    """One pixel in each 4 × 4 block carries its block's variance (30 times the noise
    of its neighbours: a highlight, a caustic). From 2 or 4 passes that pixel's
    variance is often caught far low, and then its block looked like 16 equal pixels,
    many degrees of freedom, just when its variance came out low: 12 and 13 false alarms
    in 200 seeds at α = 0.01 (binomial 99.9 % bound 8). The side with more passes sees
    the bright pixel; both sides now count the pixels that carry a block's variance by
    the smaller of their two counts (``_block_variances``): none."""
    scale = np.ones((16, 16, 1, 1))
    scale[::5, ::7] = 30.0

    def pair(rng):
        a = 1.0 + scale * rng.normal(0.0, 1.0, (16, 16, 3, n_test))
        b = 1.0 + scale * rng.normal(0.0, 1.0, (16, 16, 3, n_ref))
        return dict(test_mean=a.mean(-1), ref_mean=b.mean(-1), test_var=a.var(-1, ddof=1),
                    ref_var=b.var(-1, ddof=1), test_n=n_test, ref_n=n_ref,
                    perceptual=False)

    alarms = sum(not mv.compare_images(**pair(np.random.default_rng(s))).passed
                 for s in range(RUNS))
    assert alarms <= BOUND, (alarms, BOUND)


def test_a_two_pass_reference_still_finds_a_local_bias():
    """Power with a 2-pass reference: an 8 × 8 patch 30 % brighter on 16 test passes is
    found by the block test on at least 18 of 20 seeds."""
    found = 0
    for s in range(20):
        rng = np.random.default_rng(100 + s)
        a = rng.gamma(30.0, 1.0, (32, 32, 3, 16))
        a[8:16, 8:16] *= 1.3
        b = rng.gamma(30.0, 1.0, (32, 32, 3, 2))
        r = mv.compare_images(a.mean(-1), b.mean(-1), test_var=a.var(-1, ddof=1),
                              ref_var=b.var(-1, ddof=1), test_n=16, ref_n=2,
                              perceptual=False)
        found += "blocks" in r.details["found_by"]
    assert found >= 18, found


def test_the_variance_floor_scales_the_references_variance():
    """``test_spp``/``ref_spp``: the test variance is raised to ref_var · ref_spp /
    test_spp where below it. A 4 × 4 block whose 4 passes missed a rare bright path (10 %
    low, almost no spread) is rejected by the block test without the floor and passes
    with it; both or neither must be given."""
    ref = np.ones((8, 8))
    ref_var = np.full((8, 8), 0.04)             # 16 passes of 256 spp
    test = ref.copy()
    test_var = np.full((8, 8), 0.16)            # 4 passes of 64 spp, the same σ² a sample
    test[:4, :4], test_var[:4, :4] = 0.9, 1e-4
    kw = dict(test_var=test_var, ref_var=ref_var, test_n=4, ref_n=16, block=4,
              perceptual=False)
    bare = mv.compare_images(test, ref, **kw)
    assert not bare.passed and bare.details["found_by"] == ["blocks"]
    assert bare.details["variance_floor"] is None
    r = mv.compare_images(test, ref, **kw, test_spp=64, ref_spp=256)
    assert r.passed and r.details["variance_floor"] == {"test_spp": 64, "ref_spp": 256,
                                                        "raised_fraction": 0.25,
                                                        "ref_raised_fraction": 0.0,
                                                        "per_sample_variance_ratio": 1.0}
    assert not any(m.startswith("note:") for m in r.messages)
    with pytest.raises(mv.InvalidArgument, match="test_spp/ref_spp: give both"):
        mv.compare_images(test, ref, **kw, test_spp=64)
    with pytest.raises(mv.InvalidArgument, match="ref_spp"):
        mv.compare_images(test, ref, **kw, test_spp=64, ref_spp=0)


def test_a_sample_count_far_off_the_variances_is_noted():
    """A test_spp 256 times too large (the total of 16 passes of 16 times the spp)
    floors the reference's variance at 256 times the test's: a 10 % bias found at p =
    1e-53 with the right counts is found at p = 1.6e-4 only, and a smaller one not at
    all. The note names the counts, from the per-sample variances' ratio in the median
    pixel (1 for two renderers of the same scene)."""
    rng = np.random.default_rng(3)
    ref = rng.uniform(0.5, 1.5, (16, 16))
    var = np.full(ref.shape, 0.01)
    kw = dict(test_var=var, ref_var=var, test_n=16, ref_n=16, perceptual=False)
    right = mv.compare_images(ref * 1.1, ref, **kw, test_spp=64, ref_spp=64)
    assert not right.passed and not any(m.startswith("note: per sample")
                                        for m in right.messages)
    wrong = mv.compare_images(ref * 1.1, ref, **kw, test_spp=64 * 16 * 16, ref_spp=64)
    assert wrong.details["variance_floor"]["per_sample_variance_ratio"] == 256.0
    assert any("note: per sample, the test side's variance is 256 times" in m
               and "test_spp=16384 and ref_spp=64" in m for m in wrong.messages)


def test_variances_at_the_values_rounding_note_no_sample_count():
    """Pixels of no sampling noise (a textured plane under a directional light, each pixel
    seeing one texel): ours 0, Mitsuba's ~1e-15 from its float32 sums. Their ratio is no
    per-sample variance ratio: until 6 December it was 1e-38 and every such render-check
    noted 'check test_spp=32 and ref_spp=256' with both counts right. Where some pixels
    are noisy, those give the ratio."""
    rng = np.random.default_rng(4)
    ref = rng.uniform(0.2, 0.9, (16, 16, 3)).astype(np.float32)     # as EXRs hold them
    ref_var = (ref * 3e-8) ** 2             # float32 rounding of 256-sample sums
    kw = dict(test_var=np.zeros_like(ref), ref_var=ref_var, test_n=16, ref_n=16,
              perceptual=False, test_spp=32, ref_spp=256)
    r = mv.compare_images(ref.copy(), ref, **kw)
    assert r.passed and not any(m.startswith("note:") for m in r.messages)
    assert r.details["variance_floor"]["per_sample_variance_ratio"] is None
    noisy_test, noisy_ref = np.zeros_like(ref), ref_var.copy()
    noisy_test[:4], noisy_ref[:4] = 0.01 * 256 / 32, 0.01     # the same σ² a sample
    # (float32: 1.0 within its rounding)
    r = mv.compare_images(ref.copy(), ref, **{**kw, "test_var": noisy_test,
                                               "ref_var": noisy_ref})
    assert r.details["variance_floor"]["per_sample_variance_ratio"] == pytest.approx(1.0)


def test_the_variance_floor_also_raises_a_reference_whose_few_passes_missed_a_path():
    """A reference of 2 passes whose pixel saw a rare path in neither (both 0, variance
    0) against 16 test passes that saw it (mean 0.006): the pixel t-test took the
    reference as exact and rejected (Mitsuba against itself on the Cornell box, 16
    passes of 64 spp against 2: 10 false alarms in 200 seeds). With ``test_spp`` and
    ``ref_spp`` the reference's variance is floored at the test side's scaled as well."""
    rng = np.random.default_rng(0)
    a = rng.gamma(4.0, 0.0015, (16, 8, 8))
    b = rng.gamma(4.0, 0.0015, (2, 8, 8))
    b[:, 3, 3] = 0.0
    kw = dict(test_var=a.var(0, ddof=1), ref_var=b.var(0, ddof=1), test_n=16, ref_n=2,
              perceptual=False)
    assert not mv.compare_images(a.mean(0), b.mean(0), **kw).passed
    r = mv.compare_images(a.mean(0), b.mean(0), **kw, test_spp=64, ref_spp=64)
    assert r.passed and r.details["variance_floor"]["ref_raised_fraction"] > 0


@pytest.mark.parametrize("scale_b", [1.02, 0.98])
def test_global_two_percent_bias_is_found_by_the_global_test(scale_b):
    r = mv.compare_images(**_pair(np.random.default_rng(1), 2.0, 64, scale_b=scale_b))
    assert not r.passed and "global" in r.details["found_by"]
    assert np.sign(r.details["global"]["relative"]) == -np.sign(scale_b - 1)


def test_colour_differences_are_zero_for_identical_images_and_grow_with_a_shift():
    rng = np.random.default_rng(3)
    img = rng.random((16, 16, 3))
    same = mv.compare_images(img, img, test_var=np.full_like(img, 0.01),
                             ref_var=np.full_like(img, 0.01), test_n=4, ref_n=4)
    assert same.details["delta_e2000_mean"] == 0.0 and same.details["delta_e_itp_mean"] == 0.0
    assert same.details["flip_mean"] == 0.0 and same.artifacts["flip"].shape == (16, 16)
    shifted = img * np.array([1.0, 1.0, 1.3])
    r = mv.compare_images(shifted, img, test_var=np.full_like(img, 0.01),
                          ref_var=np.full_like(img, 0.01), test_n=4, ref_n=4)
    assert r.details["delta_e2000_mean"] > 1.0 and r.details["delta_e_itp_mean"] > 1.0
    assert 0.0 < r.details["flip_mean"] <= r.details["flip_p99"] <= 1.0
    assert r.artifacts["delta_e2000"].shape == r.artifacts["delta_e_itp"].shape \
        == (16, 16)
    # a 1 % grey change is below a just-noticeable ΔE ITP; a 30 % blue shift far above
    grey = mv.compare_images(img * 1.01, img, test_var=np.full_like(img, 0.01),
                             ref_var=np.full_like(img, 0.01), test_n=4, ref_n=4)
    assert grey.details["delta_e_itp_mean"] < 1.0 < r.details["delta_e_itp_mean"]
    assert 0.0 < grey.details["flip_mean"] < r.details["flip_mean"]      # FLIP ranks them too
    # one channel, or perceptual=False: measured not at all (None), maps absent
    for one in (mv.compare_images(img[..., 0], img[..., 0], test_var=np.full((16, 16), .01),
                                  ref_var=np.full((16, 16), .01), test_n=4, ref_n=4),
                mv.compare_images(shifted, img, test_var=np.full_like(img, 0.01),
                                  ref_var=np.full_like(img, 0.01), test_n=4, ref_n=4,
                                  perceptual=False)):
        assert one.details["flip_mean"] is None and one.details["delta_e2000_mean"] is None
        assert "flip" not in one.artifacts and "delta_e_itp" not in one.artifacts
    assert "artifacts" not in r.to_dict() and "delta_e2000" not in r.to_dict()["details"]


@pytest.mark.parametrize("level", [0.0, 1e-8], ids=["black", "near-black"])
def test_a_black_reference_is_compared_without_hdr_flip(level, run_python):
    """flip-evaluator exits the whole process on a reference whose maximum luminance is
    below about 1.2e-7 (its exposure range is reversed): render-check died (exit 134) on
    a scene not in the repository whose only light was hidden at max_depth 1. Run in a
    subprocess so that a regression fails this test instead of killing pytest."""
    code = (f"import numpy as np, mcverify as mv\n"
            f"ref = np.full((8, 8, 3), {level}); test = ref + 0.01\n"
            f"v = np.full_like(ref, 1e-4)\n"
            f"r = mv.compare_images(test, ref, test_var=v, ref_var=v, test_n=4, ref_n=4)\n"
            f"assert r.details['flip_mean'] is None and r.details['flip_p99'] is None\n"
            f"assert 'flip' not in r.artifacts and r.details['delta_e2000_mean'] is not None\n"
            f"assert r.artifacts['delta_e_itp'].shape == (8, 8)\n"
            f"print('ok')\n")
    assert run_python(code) == "ok"


def test_the_perceptual_metrics_keep_the_caller_s_print_options(run_python):
    """An outside review: colour-science's import sets numpy's print options to
    ``legacy="1.13"`` for the whole process, so a caller's arrays printed otherwise after
    their first ``compare_images`` (``[ 0.5  1. ]``). Run in a fresh process, where
    colour is not imported yet."""
    code = ("import numpy as np, mcverify as mv\n"
            "np.set_printoptions(precision=3)\n"
            "before = np.get_printoptions()\n"
            "ref = np.full((8, 8, 3), 0.5); v = np.full_like(ref, 1e-4)\n"
            "r = mv.compare_images(ref + 0.01, ref, test_var=v, ref_var=v, test_n=4, ref_n=4)\n"
            "assert r.details['delta_e2000_mean'] is not None\n"
            "print(np.get_printoptions() == before, np.array([0.5, 1.0]))\n")
    assert run_python(code) == "True [0.5 1. ]"


def test_a_black_reference_s_message_gives_no_percentage():
    """An outside review: a scene whose Mitsuba reference rendered black (an envmap lit
    in its top row only) failed with "image mean differs by +0.05494
    (+5494475381993146...00%)", the difference over a 1e-300 floor printed in full. The
    message now says the reference's mean is 0; a reference with light keeps its
    percentage."""
    ref = np.zeros((8, 8, 3))
    v = np.full_like(ref, 1e-4)
    r = mv.compare_images(ref + 0.05, ref, test_var=v, ref_var=v, test_n=4, ref_n=4,
                          perceptual=False)
    assert not r.passed
    first = r.messages[0]
    assert "image mean differs by +0.05 (the reference's mean is 0; the test image minus " \
        "the reference)" in first, first
    assert len(first) < 200, first
    lit = mv.compare_images(ref + 0.55, ref + 0.5, test_var=v, ref_var=v, test_n=4,
                            ref_n=4, perceptual=False)
    assert "(+10.00%; the test image minus the reference)" in lit.messages[0], lit.messages


def test_a_huge_relative_difference_is_printed_in_a_few_digits():
    """An outside review: a test image with a firefly block of 1e30 against a reference
    of 0.5 (a float32 EXR holds it) printed the image mean's and the block's difference
    as percentages of 30-odd digits ("+200000000000000005366162204393472.0%"). From
    10^6 % on they are now printed in three significant digits."""
    ref = np.full((16, 16, 3), 0.5)
    v = np.full_like(ref, 1e-4)
    test = ref.copy()
    test[:8, :8] = 1e30
    r = mv.compare_images(test, ref, test_var=v, ref_var=v, test_n=4, ref_n=4,
                          perceptual=False)
    assert not r.passed
    text = " ".join(r.messages)
    assert "(+5e+31%;" in text and "channel 0, +2e+32%" in text, text
    assert not re.search(r"\d{12}", text), text


def test_local_ten_percent_bias_is_found_by_blocks_at_the_right_place():
    local = (slice(16, 24), slice(8, 16), slice(None))
    r = mv.compare_images(**_pair(np.random.default_rng(2), 2.0, 64, local=local))
    assert not r.passed and "blocks" in r.details["found_by"]
    rejected = r.details["blocks"]["rejected"]
    assert {tuple(b["block"]) for b in rejected if b["side"] == 8} == {(2, 1)}
    # the half-side blocks inside it and the double-side block holding it, nothing else
    assert {(b["side"], *b["pixels"]) for b in rejected} <= \
        {(8, 16, 8), (16, 16, 0)} | {(4, y, x) for y in (16, 20) for x in (8, 12)}
    assert r.details["blocks"]["sides"] == [4, 8, 16]
    # and the printed verdict says where (it said how many blocks, only the JSON where)
    where = [m for m in r.messages if m.startswith("clearest block: ")]
    assert len(where) == 1 and any(f"pixels y {y}-{y + s - 1}, x {x}-{x + s - 1}," in where[0]
                                   for s, y, x in ((8, 16, 8), (16, 16, 0), (4, 16, 8),
                                                   (4, 16, 12), (4, 20, 8), (4, 20, 12))), \
        r.messages


def test_the_clearest_block_says_how_far_off_a_small_difference_is():
    """A rejected block 0.02 % off (a precise block: the sky beside a silhouette) printed
    '+0.0%', as if nothing differed; it now keeps two significant digits."""
    rng = np.random.default_rng(0)
    ref = np.full((16, 16, 3), 0.25)
    test = ref.copy()
    test[4:8, 8:12] *= 1.0002
    v = np.full_like(ref, 1e-12)
    r = mv.compare_images(test + rng.normal(0, 1e-6, ref.shape), ref, test_var=v,
                          ref_var=v, test_n=16, ref_n=16, perceptual=False)
    where = [m for m in r.messages if m.startswith("clearest block: ")]
    assert not r.passed and len(where) == 1 and where[0].endswith("+0.02%"), r.messages
    pixel = [m for m in r.messages if m.startswith("clearest pixel: ")]
    assert re.search(r"test \[(0\.2500[45]\d? ){2}0\.2500[45]\d?\] against reference "
                     r"\[0\.25 0\.25 0\.25\]", pixel[0]), pixel


def test_a_small_patch_is_found_by_blocks_of_its_size():
    """A 4 × 4 patch 50 % off (a small object's albedo) in 8 × 8 blocks alone was found in
    12 of 200 seeded trials; with blocks of 4, 8 and 16 under one Holm correction in 108
    (gamma noise, 32 values a pixel). Here 40 seeds: at least 12 found, all by the
    4-pixel blocks, at the patch."""
    found = 0
    for seed in range(40):
        rng = np.random.default_rng(500 + seed)
        a, b = rng.gamma(1.0, 1.0, (2, 32, 64, 64, 3))
        a[:, 30:34, 20:24] *= 1.5
        r = mv.compare_images(a.mean(0), b.mean(0), test_var=a.var(0, ddof=1),
                              ref_var=b.var(0, ddof=1), test_n=32, ref_n=32, perceptual=False)
        if not r.passed:
            found += 1
            best = r.details["blocks"]["rejected"][0]
            assert best["side"] == 4 and best["pixels"] in ([28, 20], [32, 20]), best
    assert found >= 12, found


def _splatted_passes(rng, passes, size=32, sigma=1.2, offset=0.0):
    """Pass images whose pixels correlate as a splatting filter makes them: i.i.d.
    skewed noise per pass, blurred by a gaussian of ``sigma`` pixels (wrapping)."""
    from scipy.ndimage import gaussian_filter

    noise = rng.gamma(0.5, 2.0, (passes, size, size, 3)) + offset
    return gaussian_filter(noise, sigma=(0, sigma, sigma, 0), mode="wrap")


def _passes_pair(a, b, with_passes):
    kw = dict(test_mean=a.mean(0), ref_mean=b.mean(0), test_var=a.var(0, ddof=1),
              ref_var=b.var(0, ddof=1), test_n=len(a), ref_n=len(b))
    return dict(kw, test_passes=a, ref_passes=b) if with_passes else kw


@pytest.mark.slow   # 400 seeded comparisons: 20-40 s
def test_correlated_pixels_need_the_pass_images():
    """A/A on pass images whose pixels correlate (blurred noise, as a gaussian filter
    splats it): given the passes, the image and block tests are calibrated (false alarms
    within the binomial 99.9 % bound of α = 0.01 over 200 seeded runs); summing per-pixel
    variances as if pixels were independent raises alarms far more often (what the render
    gate did before it compared pass images)."""
    def alarms(with_passes):
        out = 0
        for s in range(RUNS):
            rng = np.random.default_rng(1000 + s)
            r = mv.compare_images(**_passes_pair(_splatted_passes(rng, 16),
                                                 _splatted_passes(rng, 16), with_passes),
                                  alpha=ALPHA)
            out += not r.passed
            assert r.details["pixels_correlated"] == with_passes
        return out

    assert alarms(True) <= BOUND
    assert alarms(False) > 4 * BOUND


def test_with_pass_images_a_local_bias_is_still_found_by_the_blocks():
    rng = np.random.default_rng(3)
    a, b = _splatted_passes(rng, 16, offset=5.0), _splatted_passes(rng, 16, offset=5.0)
    b[:, 8:16, 16:24] *= 1.10
    r = mv.compare_images(**_passes_pair(a, b, True))
    assert not r.passed and "blocks" in r.details["found_by"]
    assert [1, 2] in [blk["block"] for blk in r.details["blocks"]["rejected"]
                      if blk["side"] == 8]


def test_zero_variance_pixels_compare_exactly():
    z = np.zeros((8, 8))
    ok = mv.compare_images(z, z, test_var=z, ref_var=z, test_n=4, ref_n=4)
    assert ok.passed
    t = z.copy()
    t[3, 3] = 1e-3
    t[5, 5] = 1e-30       # below float32 resolution of the image's scale: equal
    bad = mv.compare_images(t, z, test_var=z, ref_var=z, test_n=4, ref_n=4)
    assert not bad.passed and "pixels" in bad.details["found_by"]
    assert bad.artifacts["p_map"][3, 3] == 0.0 and bad.artifacts["p_map"][5, 5] == 1.0


def test_half_images_round_within_half_s_precision():
    """A correct renderer's half image (OpenEXR half, Mitsuba's default film format)
    failed against a float reference with p = 0: a directly seen emitter of radiance 0.7
    (zero variance on both sides) rounds to 0.69971 in half, beyond the 2^-16 rounding
    allowance, and a faint pixel's variance underflowed to 0 against a black reference
    pixel. Half's own rounding is no evidence now; a 0.3 % bias still is."""
    rng = np.random.default_rng(0)
    a, b = rng.gamma(2.0, 0.5, (2, 32, 32, 3, 64))
    a[:8, :8] = b[:8, :8] = 0.7                     # an emitter seen directly
    b[20, 20] = 0.0                                 # a path the reference never found
    a[20, 20] = 0.0
    a[20, 20, :, 0] = 1e-3                          # variance 6e-8 / 64: 0 in half
    ref = dict(ref_mean=b.mean(-1), ref_var=b.var(-1, ddof=1), test_n=64, ref_n=64)
    mean, var = a.mean(-1).astype(np.float16), a.var(-1, ddof=1).astype(np.float16)
    assert var[20, 20, 0] == 0
    ok = mv.compare_images(mean, test_var=var, **ref)
    assert ok.passed, ok.messages
    bright = mv.compare_images(mean * np.float16(1.003), test_var=var, **ref)
    assert not bright.passed
    # float32 keeps its own, finer allowance: 0.7 in half is a difference there
    assert not mv.compare_images(np.float32(mean), test_var=np.float32(var), **ref).passed
    # unless the caller says the images were stored as half before (``precision``)
    assert mv.compare_images(np.float64(mean), test_var=np.float64(var), **ref,
                             precision=np.float16).passed
    for bad in ("half-ish", np.int32, 3):
        with pytest.raises(mv.InvalidArgument, match="precision=.*numpy floating type"):
            mv.compare_images(mean, test_var=var, **ref, precision=bad)


def test_one_test_named_as_a_string_is_that_test_alone():
    # tests="global" was read as the six "tests" g, l, o, b, a, l and refused
    pair = _pair(np.random.default_rng(1), 2.0, 64, scale_b=1.02)
    r = mv.compare_images(**pair, tests="global")
    assert r.details["tests"] == ["global"] and r.details["found_by"] == ["global"]
    assert mv.compare_images(**pair, tests="pixels").details["tests"] == ["pixels"]


def test_one_bright_pixel_does_not_hide_a_bias_everywhere_else():
    """The rounding floor was 2^-24 of the image's largest value: one pixel at 1e6 (a
    visible sun, a firefly on both sides) made every difference under 0.06 no evidence,
    and a 3 % bias across the whole image passed. The floor's scale is now the median
    magnitude, which no single pixel moves."""
    rng = np.random.default_rng(0)
    ref = rng.uniform(0.5, 1.5, (32, 32, 3))
    var = np.full(ref.shape, 1e-4)
    test = ref * 1.03 + rng.normal(0.0, 1e-3, ref.shape)
    for bright in (None, 1e6):
        t, r = test.copy(), ref.copy()
        if bright is not None:
            t[4, 4], r[4, 4] = bright, bright
        res = mv.compare_images(t, r, test_var=var, ref_var=var, test_n=16, ref_n=16,
                                alpha=ALPHA)
        assert not res.passed, bright
        assert {"global", "blocks", "pixels"} <= set(res.details["found_by"]), bright


@pytest.mark.parametrize("kwargs,match", [
    (dict(ref_mean=np.zeros((4, 5))), "shape"),
    (dict(test_var=-np.ones((4, 4))), ">= 0"),
    (dict(test_mean=np.full((4, 4), np.nan)), "NaN"),
    (dict(test_n=1), "test_n=1"),
    (dict(block=0), "block=0"),
    (dict(tests="blocs"), "tests=\\('blocs',\\)"),
    (dict(test_passes=np.zeros((4, 4, 4))), "test_passes/ref_passes: give both"),
    (dict(test_passes=np.zeros((3, 4, 4)), ref_passes=np.zeros((4, 4, 4))),
     r"test_passes: expected 4 pass images"),
    (dict(test_passes=np.zeros((4, 4, 4)), ref_passes=np.full((4, 4, 4), np.inf)),
     "ref_passes: contains NaN/Inf"),
    # the block and image tests read the passes, the pixel tests the mean: a mean 1.5
    # times its passes' was compared without a word (an outside review)
    (dict(test_passes=np.full((4, 4, 4), 1.5), ref_passes=np.zeros((4, 4, 4)),
          test_mean=np.ones((4, 4))), "test_mean: not the mean of test_passes"),
    (dict(test_passes=np.zeros((4, 4, 4)), ref_passes=np.ones((4, 4, 4))),
     "ref_mean: not the mean of ref_passes"),
], ids=["shape", "negative-var", "nan", "n", "block", "misspelt-test", "one-side-passes",
        "passes-count", "passes-inf", "mean-not-of-test-passes", "mean-not-of-ref-passes"])
def test_bad_input(kwargs, match):
    base = dict(test_mean=np.zeros((4, 4)), ref_mean=np.zeros((4, 4)),
                test_var=np.ones((4, 4)), ref_var=np.ones((4, 4)), test_n=4, ref_n=4)
    base.update(kwargs)
    with pytest.raises(mv.InvalidArgument, match=match):
        mv.compare_images(**base)


SCENE = os.path.join(os.path.dirname(__file__), "..", "..", "reference", "scenes",
                     "cornell-box", "scene.xml")


def _mitsuba_passes(mi, scene, seed0, passes=16, spp=64):
    imgs = np.stack([np.asarray(mi.render(scene, spp=spp, seed=seed0 + k), dtype=np.float64)
                     for k in range(passes)])
    return imgs.mean(0), imgs.var(0, ddof=1), passes


@pytest.mark.mitsuba
def test_mitsuba_against_itself_passes_and_a_brighter_light_fails():
    from mcverify.gate import mitsuba as mvm

    if mvm.choose_variant().variant.startswith("scalar"):
        pytest.skip("rendering the A/A pair needs the llvm variant (libLLVM >= 16) to be fast")
    mi = mvm._mi()
    scene = mi.load_file(SCENE)
    ta, va, n = _mitsuba_passes(mi, scene, 0)
    tb, vb, _ = _mitsuba_passes(mi, scene, 1000)
    same = mv.compare_images(ta, tb, test_var=va, ref_var=vb, test_n=n, ref_n=n)
    assert same.passed, same.details["found_by"]
    params = mi.traverse(scene)
    key = next(k for k in params.keys() if k.endswith("emitter.radiance.value"))
    params[key] = params[key] * 1.02
    params.update()
    tc, vc, _ = _mitsuba_passes(mi, scene, 2000)
    brighter = mv.compare_images(tc, tb, test_var=vc, ref_var=vb, test_n=n, ref_n=n)
    assert not brighter.passed and "global" in brighter.details["found_by"]


def test_images_too_large_for_the_memory_are_refused_before_any_work(monkeypatch):
    """Two 4096 × 4096 EXRs under `ulimit -v 4000000` ended in "unexpected MemoryError:
    Unable to allocate 384. MiB", naming nothing (an outside review)."""
    from mcverify import _validate

    rng = np.random.default_rng(0)
    a, b, va, vb = (rng.gamma(2, .5, (256, 256, 3)) for _ in range(4))
    monkeypatch.setattr(_validate, "_available_memory", lambda: 2 ** 26)    # 64 MiB
    with pytest.raises(mv.InvalidArgument, match=r"test_mean: 256 x 256 pixels need about "
                       r".* MiB of memory to compare .*more than half of the 64 MiB"):
        mv.compare_images(a, b, test_var=va, ref_var=vb, test_n=16, ref_n=16)


@pytest.mark.parametrize("perceptual, k", [(True, 0), (False, 0), (True, 4)])
def test_the_image_memory_guard_counts_what_a_comparison_takes(perceptual, k):
    """The guard's bytes a pixel bound compare_images' peak above its inputs (tracemalloc)."""
    import tracemalloc

    from mcverify.checks import image

    rng = np.random.default_rng(1)
    p = rng.gamma(2, .5, (2, max(k, 2), 256, 256, 3))
    means, var = p.mean(1), p.var(1, ddof=1)
    kw = dict(test_passes=p[0], ref_passes=p[1]) if k else {}
    n = max(k, 2)
    mv.compare_images(means[0][:8, :8], means[1][:8, :8], test_var=var[0][:8, :8],
                      ref_var=var[1][:8, :8], test_n=n, ref_n=n)    # first-call imports
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        mv.compare_images(means[0], means[1], test_var=var[0], ref_var=var[1], test_n=n,
                          ref_n=n, perceptual=perceptual, **kw)
        peak = tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()
    each = image._BYTES_PER_PIXEL + image._PERCEPTUAL_BYTES_PER_PIXEL * perceptual \
        + image._PASS_BYTES_PER_PIXEL * 2 * k
    assert peak <= 256 * 256 * each, (peak / 256 ** 2, each)


def test_a_negative_reference_is_not_called_black(capsys):
    """A scene of negative radiance (both renderers agree) printed "HDR-FLIP not measured:
    the reference is black" (an outside review): FLIP reads negative values as 0, and the
    line now says that no pixel reaches its luminance threshold."""
    from mcverify.checks.image import perceptual_metrics
    from mcverify.gate.cli import _print_visibility

    ref = -np.full((8, 8, 3), 0.5)
    details, _ = perceptual_metrics(ref * 1.01, ref)
    assert details["flip_mean"] is None and details["delta_e2000_mean"] is not None
    _print_visibility(details)
    out = capsys.readouterr().out
    assert "black" not in out and "no reference pixel reaches luminance 1e-06 " \
        "(negative values count as 0)" in out, out


def test_pixels_of_zero_variance_from_few_discrete_passes_are_noted_as_no_evidence():
    """Two correct renders of 3 and 2 passes, each pass 4 samples of a path found with
    probability 0.02: a pixel's passes are all 0, or coincide at its one hit, and a
    pixel of zero variance on both sides is compared exactly, so the pair fails (42 of 60
    seeds at α = 0.01; an outside review measured 69-100 %). The failure now says that
    such a difference is no evidence and what to give instead; with 16 passes a side
    there is no such pixel to note."""
    rng0 = np.random.default_rng(123)
    mu = np.exp(rng0.normal(0, 1, (13, 21)))

    def render(rng, k):
        passes = (rng.random((k, 13, 21, 4)) < 0.02).mean(-1) / 0.02 * mu
        return passes.mean(0), passes.var(0, ddof=1), k

    rng = np.random.default_rng(0)
    (tm, tv, nt), (rm, rv, nr) = render(rng, 3), render(rng, 2)
    r = mv.compare_images(tm, rm, test_var=tv, ref_var=rv, test_n=nt, ref_n=nr,
                          perceptual=False)
    assert not r.passed and "pixels" in r.details["found_by"], r.messages
    note = [m for m in r.messages if m.startswith("note: ")]
    assert note and "have zero variance on both sides (3 and 2 values)" in note[0], r.messages
    for seed in range(20):
        rng = np.random.default_rng(seed)
        (tm, tv, nt), (rm, rv, nr) = render(rng, 16), render(rng, 16)
        r = mv.compare_images(tm, rm, test_var=tv, ref_var=rv, test_n=nt, ref_n=nr,
                              perceptual=False)
        assert not any("zero variance on both sides" in m for m in r.messages), r.messages


def _scene_pair(seed=0, shape=(24, 24, 3), n=16, wrong=None):
    """A correct render and its reference of one scene whose expected image is no
    symmetric pattern (a ramp down, a ramp across, a bright square off the centre, each
    channel its own level): gamma pass values, ``n`` a side. ``wrong`` brightens a block
    of the test side by 50 % (a real bug, which no convention undoes)."""
    h, w, c = shape
    y, x = np.mgrid[0:h, 0:w] / max(h, w)
    mu = (0.2 + 2 * y + 0.5 * x)[..., None] * np.array([1.0, 0.6, 0.3])[:c]
    mu[2:7, 3:9] *= 8.0
    rng = np.random.default_rng(seed)
    a = rng.gamma(30.0, mu[..., None] / 30.0, shape + (n,))
    b = rng.gamma(30.0, mu[..., None] / 30.0, shape + (n,))
    if wrong is not None:
        a[wrong] *= 1.5
    return dict(test_mean=a.mean(-1), ref_mean=b.mean(-1), test_var=a.var(-1, ddof=1),
                ref_var=b.var(-1, ddof=1), test_n=n, ref_n=n, perceptual=False)


#: A correct image stored in another renderer's convention (its grid, and a factor), and
#: a word of the guess.
CONVENTIONS = [("flipud", lambda x: x[::-1], 1.0, "flipped vertically"),
               ("fliplr", lambda x: x[:, ::-1], 1.0, "flipped horizontally"),
               ("rot180", lambda x: x[::-1, ::-1], 1.0, "rotated by 180"),
               ("transposed", lambda x: x.transpose(1, 0, 2), 1.0, "transposed"),
               ("bgr", lambda x: x[..., ::-1], 1.0, "BGR"),
               ("times-pi", lambda x: x, np.pi, "about π"),
               ("times-2", lambda x: x, 2.0, "about 2"),
               ("times-1.03", lambda x: x, 1.03, "a constant factor")]


@pytest.mark.parametrize("convention", CONVENTIONS, ids=[c[0] for c in CONVENTIONS])
def test_a_correct_image_in_another_convention_fails_naming_the_convention(convention):
    """A correct render stored upside down (OpenGL's rows), mirrored, transposed, in
    OpenCV's BGR order or a constant factor off failed with blocks and pixels rejected
    and nothing saying why; it still fails (the verdict, p and messages unchanged), and a
    note names the convention which, undone, passes the same comparison."""
    _, stored, factor, word = convention
    kw = _scene_pair()
    kw["test_mean"] = stored(kw["test_mean"]) * factor
    kw["test_var"] = stored(kw["test_var"]) * factor ** 2
    r = mv.compare_images(**kw)
    plain = mv.checks.image._compare_images(**kw)
    assert not r.passed and r.p_value == plain.p_value
    assert r.messages[:-1] == plain.messages
    assert r.messages[-1].startswith("note: the test image looks") and word in r.messages[-1]
    assert word in r.details["convention"]["guess"]
    assert r.details["convention"]["p_value"] > ALPHA


@pytest.mark.parametrize("seed", range(3))
def test_no_convention_is_guessed_where_none_holds(seed):
    """A correct image passes with no guess; a wrong one (a block 50 % bright), stored as
    is or upside down, fails with none: no flip or factor makes it agree."""
    assert mv.compare_images(**_scene_pair(seed)).details["convention"] is None
    for stored in (lambda x: x, lambda x: x[::-1]):
        kw = _scene_pair(seed, wrong=np.s_[14:20, 12:18])
        kw["test_mean"], kw["test_var"] = stored(kw["test_mean"]), stored(kw["test_var"])
        r = mv.compare_images(**kw)
        assert not r.passed and r.details["convention"] is None
        assert not any("looks" in m for m in r.messages)


def test_a_gamma_encoded_image_is_named():
    """A correct render whose mean was sRGB-encoded for display (its variance carried
    through the encoding) fails, and the note names the encoding; the same image linear
    passes with no note."""
    kw = _scene_pair()
    scale = 1.2 * max(kw["test_mean"].max(), kw["ref_mean"].max())   # values in [0, 1]
    for k in ("test_mean", "ref_mean"):
        kw[k] = kw[k] / scale
    for k in ("test_var", "ref_var"):
        kw[k] = kw[k] / scale ** 2
    assert mv.compare_images(**kw).details["convention"] is None
    m = kw["test_mean"]
    slope = np.where(m <= 0.0031308, 12.92, 1.055 / 2.4 * np.maximum(m, 1e-12) ** (1 / 2.4 - 1))
    kw["test_mean"] = np.where(m <= 0.0031308, 12.92 * m, 1.055 * m ** (1 / 2.4) - 0.055)
    kw["test_var"] = kw["test_var"] * slope ** 2
    r = mv.compare_images(**kw)
    assert not r.passed and "sRGB-encoded" in r.messages[-1]
    assert r.details["convention"]["guess"].startswith("sRGB-encoded")


@pytest.mark.parametrize("stored,hint", [
    (lambda x: x.transpose(1, 0, 2), "column-major (transposed)"),
    (lambda x: x[::2, ::2], "0.5 times the reference's resolution"),
    (lambda x: np.concatenate([x, np.ones(x.shape[:2] + (1,))], -1), "an alpha?")],
    ids=["transposed", "half-resolution", "rgba"])
def test_a_test_image_of_another_shape_is_refused_saying_what_it_looks_like(stored, hint):
    """A non-square render stored transposed, at half the resolution or with an alpha
    channel was refused as a bare shape mismatch; the refusal now says which."""
    kw = _scene_pair(shape=(16, 24, 3))
    kw["test_mean"], kw["test_var"] = stored(kw["test_mean"]), stored(kw["test_var"])
    with pytest.raises(mv.InvalidArgument, match=r"ref_mean: shape .*" + re.escape(hint)):
        mv.compare_images(**kw)
    kw["test_mean"] = kw["test_mean"][:-1]
    with pytest.raises(mv.InvalidArgument, match=r"differs from test_mean's \(\d+, \d+, \d\)$"):
        mv.compare_images(**kw)


def test_a_false_alarm_of_a_flat_image_gets_no_convention_guess():
    """On a false alarm of two correct renders of a flat image, a flip, BGR or a factor
    near 1 is fresh noise that then passes: 4 of 5 false alarms in 800 seeds carried
    "the test image looks flipped horizontally" (a read-only review). A convention is
    offered only where undoing it moves the image by well over its noise. At α = 0.3,
    40 seeds, the failures (some there must be) carry no guess."""
    failed = 0
    for seed in range(40):
        rng = np.random.default_rng(seed)
        a, b = rng.gamma(2.0, 0.5, (2, 16, 16, 3, 16))
        r = mv.compare_images(a.mean(-1), b.mean(-1), test_var=a.var(-1, ddof=1),
                              ref_var=b.var(-1, ddof=1), test_n=16, ref_n=16, alpha=0.3,
                              perceptual=False)
        failed += not r.passed
        assert r.details["convention"] is None, (seed, r.messages)
    assert failed >= 3, failed


def test_a_small_object_flipped_on_a_flat_background_is_named():
    """A 4 × 4 bright object off the centre of a flat 64 × 64 background, stored upside
    down: a criterion of the mean squared statistic over all pixels diluted the object's
    few pixels and gave no guess (a read-only review); whether the undoing moves the
    image is the comparison's own verdict, which sees a few pixels."""
    mu = np.full((64, 64, 3), 0.3)
    mu[10:14, 40:44] = 1.5
    rng = np.random.default_rng(5)
    a = rng.gamma(30.0, mu[..., None] / 30.0, mu.shape + (16,))
    b = rng.gamma(30.0, mu[..., None] / 30.0, mu.shape + (16,))
    r = mv.compare_images(a.mean(-1)[::-1], b.mean(-1), test_var=a.var(-1, ddof=1)[::-1],
                          ref_var=b.var(-1, ddof=1), test_n=16, ref_n=16, perceptual=False)
    assert not r.passed and "flipped vertically" in r.details["convention"]["guess"]


def test_what_is_reported_found_is_what_failed_the_image():
    """The verdict is the smallest of the three tests' p-values times 3 (Bonferroni) against
    α, so each test's findings are those at α / 3: a pixel reported rejected (found_by,
    rejected_fraction, the clearest pixel) at α while the image passed told the user of
    a difference the verdict did not count. A single pixel off by more and more, from
    nothing to clear: found iff failed, at every step."""
    for shift in np.linspace(0.0, 1.2, 49):
        tm = np.ones((8, 8, 1))
        tm[3, 4, 0] += shift
        v = np.ones((8, 8, 1))
        r = mv.compare_images(tm, np.ones((8, 8, 1)), test_var=v, ref_var=v, test_n=100,
                              ref_n=100, perceptual=False)
        found = bool(r.details["found_by"])
        assert r.passed != found, (shift, r.p_value, r.details["found_by"])
        assert (r.details["rejected_fraction"] > 0) <= found
        assert (r.details["blocks"]["n_rejected"] > 0) <= found


def test_the_image_test_counts_n_minus_1_degrees_of_freedom_a_pixel():
    """Without pass images the image's variance is a sum of per-pixel variances, each of
    n - 1 degrees of freedom: 64 equal pixels of 2 values a side carry 64, not 128 (n a
    pixel, a mutant of an outside review that no test saw: with 2 passes it doubles the
    degrees of freedom where they are fewest). The global p-value is Welch's t on them."""
    v = np.ones((8, 8, 1))
    r = mv.compare_images(np.full((8, 8, 1), 1.5), np.ones((8, 8, 1)), test_var=v,
                          ref_var=v, test_n=2, ref_n=2, perceptual=False)
    se2 = 0.5 / 64                      # (variance 1 / 2 values) / 64 pixels, a side
    p = stats.welch_t_pooled_beyond(0.5, se2, 64.0, se2, 64.0, 0.0)
    assert r.details["global"]["p_channels"][0] == pytest.approx(float(p), rel=1e-2)


def test_with_pass_images_the_image_test_is_welchs_t_on_the_pass_means():
    """Given pass images, the global test is Welch's t of the passes' image means, their
    sample variances (ddof = 1) over 4 and 16 passes: ddof = 0, or the test's count for
    the reference's, passed every other test (mutants of an outside review)."""
    rng = np.random.default_rng(8)
    a = 1.05 + 0.2 * rng.standard_normal((4, 8, 8, 1))
    b = 1.0 + 0.2 * rng.standard_normal((16, 8, 8, 1))
    r = mv.compare_images(**_passes_pair(a, b, True), perceptual=False)
    ga, gb = a.mean(axis=(1, 2, 3)), b.mean(axis=(1, 2, 3))
    p = stats.welch_t_beyond(ga.mean() - gb.mean(), ga.var(ddof=1), 4, gb.var(ddof=1), 16,
                             0.0)
    assert r.details["pixels_correlated"] and 1e-4 < float(p) < 0.5
    assert r.details["global"]["p_channels"][0] == pytest.approx(float(p), rel=1e-2)
