import os

import pytest
from hypothesis import HealthCheck, settings

# The path tracer renders with its general kernel in the tests (render(general=None)
# reads this; subprocesses inherit it): one numba compilation serves every scene, where
# each scene's specialised kernel costs about a minute on a new machine. The slow test
# test_every_scenes_specialised_kernel_matches_the_general_one holds every reference
# scene's specialised kernel to the general one bit for bit.
os.environ.setdefault("MCVERIFY_GENERAL_KERNEL", "1")

# Hypothesis profiles, as the project's configuration habit: "ci" is derandomised so
# CI is deterministic; "thorough" explores more for nightly runs.
settings.register_profile("ci", derandomize=True, max_examples=40, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("thorough", max_examples=300, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


# Kernels each test worker would compile for itself (about a minute each on a new
# machine): with two or more pytest-xdist workers, worker k compiles the k-th at the
# start, while the others compile theirs; render() takes a lock around a kernel's first
# call (estimators._generated.compile_lock), so a worker that needs a kernel another is
# still compiling waits for it and then loads it from numba's cache instead of
# compiling it again. Only when the run collected tests of the path tracer.
_SHARED_KERNELS = ("white-furnace", "filters-gaussian")   # render_tiles, splat_tiles


def _xdist_worker(request, *collected: str):
    """(k, n): this process is pytest-xdist worker k of n >= 2, in a run that collected a
    test whose id contains one of ``collected``; else None."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    n = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if n < 2 or not worker.startswith("gw") or not any(
            c in item.nodeid for item in request.session.items for c in collected):
        return None
    return int(worker[2:]), n


@pytest.fixture(scope="session", autouse=True)
def _compile_shared_kernels_once(request):
    me = _xdist_worker(request, "pathtracer", "reference")
    if me is None or me[0] >= len(_SHARED_KERNELS) or \
            os.environ.get("MCVERIFY_GENERAL_KERNEL") != "1":
        return
    k = me[0]
    from estimators.pathtracer import render
    scenes = os.path.join(os.path.dirname(__file__), os.pardir, "reference", "scenes")
    render(os.path.join(scenes, _SHARED_KERNELS[k], "scene.xml"), spp=2, seed=0,
           params={"res": 8, "spp": 2})


@pytest.fixture(scope="session", autouse=True)
def _compile_warp_loops_once(request):
    """The same for the warps' front-end loops (about two minutes for all of them, cold):
    with n >= 2 workers, worker k compiles every n-th warp's sample/pdf/invert loops at the
    start (estimators._vectorize takes the same lock), when the run collected the tests
    that call every warp."""
    me = _xdist_worker(request, "test_warps.py")
    if me is None:
        return
    import numpy as np

    from estimators import warps
    k, n = me
    u = np.full((4, 3), 0.25)
    for w in list(warps.WARPS.values())[k::n]:
        x = w.sample(u[:, :w.sample_dim], *w.defaults)
        w.pdf(x, *w.defaults)
        if w.invert is not None:
            w.invert(x, *w.defaults)
