"""The committed reference scenes: every reference is current (scene hash) and readable,
the white furnace matches its analytic answer, and Mitsuba against itself passes the
pixelwise gate at the stated false-alarm rate (slow)."""

import numpy as np
import pytest

import mcverify as mv
from mcverify import mitsuba as mvm
from mcverify import reference, stats

pytestmark = pytest.mark.mitsuba
SCENES = reference.list_scenes()


def test_at_least_six_scenes_covering_the_features():
    from estimators.pathtracer import load_scene

    assert len(SCENES) >= 6
    features = set().union(*(load_scene(f"{reference.REFERENCE_ROOT}/{n}/scene.xml").features
                             for n in SCENES))
    assert {"emitter:envmap", "emitter:constant", "emitter:point", "emitter:spot",
            "emitter:directional", "emitter:area:sphere", "bsdf:dielectric",
            "bsdf:roughconductor", "bsdf:roughplastic", "bsdf:plastic"} <= features


@pytest.mark.parametrize("name", SCENES)
def test_reference_is_current_and_readable(name):
    r = reference.load_reference(name)
    assert r.n >= 2 and r.mean.shape == tuple(r.manifest["shape"])
    assert np.all(r.var >= 0)


def test_white_furnace_is_one_everywhere():
    r = reference.load_reference("white-furnace")
    ones = np.ones_like(r.mean)
    res = mv.compare_images(r.mean, ones, test_var=r.var, ref_var=np.zeros_like(ones),
                            test_n=r.n, ref_n=2)
    assert res.passed, res.details["found_by"]


@pytest.mark.slow
def test_mitsuba_against_itself_is_calibrated_on_every_scene():
    pairs = 20
    alarms = {}
    for name in SCENES:
        _, path = reference.resolve_scene(name)
        for k in range(pairs):
            a = mvm.render_passes(path, spp=16, seeds=range(100_000 * k, 100_000 * k + 8))
            b = mvm.render_passes(path, spp=16, seeds=range(100_000 * k + 50, 100_000 * k + 58))
            r = mv.compare_images(a.mean(0), b.mean(0), test_var=a.var(0, ddof=1),
                                  ref_var=b.var(0, ddof=1), test_n=8, ref_n=8)
            alarms[name] = alarms.get(name, 0) + (not r.passed)
    total = sum(alarms.values())
    bound = stats.binomial_upper_bound(pairs * len(SCENES), 0.01, 0.999)
    print(f"A/A false alarms: {total}/{pairs * len(SCENES)} (bound {bound}) {alarms}")
    assert total <= bound, alarms
