"""Reconstruction filters as Mitsuba splats them: the 1-D filter values and the weights one
sample puts into each pixel, pointwise against Mitsuba's own ``rfilter`` and
``ImageBlock``; the ratio Σ w L / Σ w; planted wrong filter widths fail the render gate
on the filter scenes (their passing gate runs in test_pathtracer_coverage.py)."""

import numpy as np
import pytest

from estimators.pathtracer.camera import SPLAT_CHANNELS, Camera, filter_weights, splat

FILTERS = [("gaussian", {}), ("gaussian", {"stddev": 0.3}), ("gaussian", {"stddev": 1.0}),
           ("tent", {}), ("tent", {"radius": 1.5})]
IDS = ["gaussian", "gaussian-0.3", "gaussian-1", "tent", "tent-1.5"]
# Mitsuba's gaussian evaluates a degree-9 Remez fit of exp(-x²/2σ²) shifted to 0 at the
# radius (measured: within 4.2e-4 of the exact function, and up to 1.6e-5 beyond the
# radius where the fit is not clamped); its tent is exact to float32.
ATOL = {"gaussian": 5e-4, "tent": 1e-6}


def _camera(rfilter, w=12, h=9, **kw):
    return Camera(np.eye(4), 1.0, 1.0, 0.01, 100.0, w, h).with_filter(rfilter, **kw)


@pytest.fixture(scope="module")
def mi():
    from mcverify.gate import mitsuba as mvm

    return mvm.mi()


@pytest.mark.mitsuba
@pytest.mark.parametrize("name,kw", FILTERS, ids=IDS)
def test_filter_values_match_mitsubas_rfilter(mi, name, kw):
    cam = _camera(name, **kw)
    theirs_filter = mi.load_dict({"type": name, **kw})
    assert cam.filter_radius == pytest.approx(theirs_filter.radius())
    x = np.linspace(-cam.filter_radius - 0.5, cam.filter_radius + 0.5, 2001)
    ours = filter_weights(cam, x)
    theirs = np.array(theirs_filter.eval(mi.Float(x)))
    np.testing.assert_allclose(ours, theirs, atol=ATOL[name])
    assert np.all(ours[np.abs(x) >= cam.filter_radius] == 0) and np.all(ours >= 0)


@pytest.mark.mitsuba
@pytest.mark.parametrize("coalesce", [True, False], ids=["coalesced", "per-pixel"])
@pytest.mark.parametrize("name,kw", FILTERS, ids=IDS)
def test_one_samples_pixel_weights_match_mitsubas_imageblock(mi, name, kw, coalesce):
    """A sample at film position p (pixels) splats into every pixel of a 12 × 9 image the
    weight Mitsuba's ImageBlock gives it (both of its accumulation paths), at random
    positions, on pixel edges and centres, and at the image's borders (where weight
    falling outside the image is dropped, not folded back)."""
    w, h = 12, 9
    cam = _camera(name, w, h, **kw)
    rfilter = mi.load_dict({"type": name, **kw})
    rng = np.random.default_rng(7)
    points = np.concatenate([rng.uniform((0, 0), (w, h), (24, 2)),
                             [(0.01, 0.02), (w - 0.01, h - 0.5), (3.0, 4.0), (3.5, 4.5),
                              (0.5, h - 0.001), (w / 2, 0.0)]])
    for p in points:
        block = mi.ImageBlock(mi.ScalarVector2u(w, h), mi.ScalarPoint2i(0, 0), 1, rfilter,
                              coalesce=coalesce)
        block.put(mi.Point2f(float(p[0]), float(p[1])), [mi.Float(1.0)])
        theirs = np.array(block.tensor())[:, :, 0]
        ours = splat(cam, [[p[0], p[1], 1.0, 1.0, 1.0]])[:, :, 0]
        np.testing.assert_allclose(ours, theirs, atol=2 * ATOL[name],
                                   err_msg=f"{name} {kw} at p={tuple(p)}")
        assert ours.sum() > 0          # every radius here reaches the nearest centre


def test_the_film_sums_give_the_weighted_mean_and_its_delta_method_variance():
    """Every channel of the splat sums, for a few samples of known radiance reaching one
    pixel: Σw, Σw·L, Σw², Σw²·L, Σw²·L², from the filter weights computed apart."""
    cam = _camera("tent", 6, 5, radius=1.5)
    pts = np.array([[2.3, 2.6, 1.0, 2.0, 0.0], [2.9, 1.7, 4.0, 0.5, 1.0],
                    [1.2, 2.4, 0.0, 3.0, 2.0]])
    acc = splat(cam, pts)
    assert acc.shape == (5, 6, SPLAT_CHANNELS)
    i, j = 2, 2                                              # pixel centre (2.5, 2.5)
    wts = filter_weights(cam, 2.5 - pts[:, 0]) * filter_weights(cam, 2.5 - pts[:, 1])
    L = pts[:, 2:]
    expect = np.concatenate([[wts.sum()], wts @ L, [(wts ** 2).sum()], wts ** 2 @ L,
                             wts ** 2 @ L ** 2])
    np.testing.assert_allclose(acc[j, i], expect, rtol=1e-12)


@pytest.mark.mitsuba
@pytest.mark.parametrize("scene,plant", [
    ("filters", {"filter_scale": 1.2}),          # Mitsuba's default σ = 0.5 rendered as 0.6
    ("filters", {"filter_scale": 0.8}),          # ... as 0.4
    ("filters-tent", {"filter_scale": 1.2}),     # tent radius 1.5 rendered as 1.8
], ids=["gaussian-0.5-as-0.6", "gaussian-0.5-as-0.4", "tent-1.5-as-1.8"])
def test_a_wrong_filter_width_fails_the_render_gate(scene, plant):
    """Teeth: the filter's width off by 20 % blurs the scene's edges differently, which
    the block and pixel tests (not the image mean: a filter keeps it) must see."""
    import mcverify as mv

    r = mv.render_check(scene, seed=23, plant=plant)
    assert not r.passed, r.summary()
    assert {"blocks", "pixels"} & set(r.details["found_by"]), r.details["found_by"]
    assert r.details["pixels_correlated"]
