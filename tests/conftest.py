import os
import subprocess
import sys

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


# Kernels each test worker would compile for itself (a minute or more each on a new
# machine): with two or more pytest-xdist workers, the big ones are dealt at the start,
# worker k taking the k-th (the tracer's general kernel; the tracer's sampling loops)
# and every n-th warp's front-end loops, while the others compile theirs. A kernel's
# first call holds a lock in the kernel cache (estimators._generated.compile_lock), so a
# worker that needs a kernel another is still compiling waits for it and then loads it
# from numba's cache instead of compiling it again. Each only when the run collected the
# tests that use it.
_SCENES = os.path.join(os.path.dirname(__file__), os.pardir, "reference", "scenes")


def _xdist_worker(request, *collected: str):
    """(k, n): this process is pytest-xdist worker k of n >= 2, in a run that collected a
    test whose id contains one of ``collected``; else None."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    n = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if n < 2 or not worker.startswith("gw") or not any(
            c in item.nodeid for item in request.session.items for c in collected):
        return None
    return int(worker[2:]), n


def _general_kernel():
    """render_tiles and the trace it calls (the splatting film's kernel shares trace)."""
    from estimators.pathtracer import render
    render(os.path.join(_SCENES, "white-furnace", "scene.xml"), spp=2, seed=0,
           params={"res": 8, "spp": 2})


def _sampling_loops():
    """The four loops of estimators.pathtracer.sampling (the tracer-instance checks)."""
    import numpy as np

    from estimators.pathtracer import prepare_scene
    from estimators.pathtracer.sampling import bsdf_sampler, emitter_sampler
    scene = prepare_scene(os.path.join(_SCENES, "cornell-box", "scene.xml"),
                          params={"res": 8, "spp": 2})
    u = np.full((4, 3), 0.3)
    for sample, pdf in (bsdf_sampler(scene, 0, (0.0, 0.6, 0.8)),
                        emitter_sampler(scene, 0, (0.0, 1.0, 0.0))):
        pdf(sample(u))


@pytest.fixture(scope="session", autouse=True)
def _compile_shared_kernels_once(request):
    jobs = []
    if os.environ.get("MCVERIFY_GENERAL_KERNEL") == "1":
        jobs.append((_general_kernel, ("pathtracer", "reference")))
    jobs.append((_sampling_loops, ("test_tracer_checks.py",)))
    for i, (job, collected) in enumerate(jobs):
        me = _xdist_worker(request, *collected)
        if me is not None and i % me[1] == me[0]:
            job()


@pytest.fixture(scope="session", autouse=True)
def _compile_warp_loops_once(request):
    """The warps' front-end loops (about two minutes for all of them, cold): with n >= 2
    workers, worker k compiles every n-th warp's sample/pdf/invert loops at the start
    (estimators._vectorize takes the same lock), when the run collected the tests that
    call every warp."""
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


@pytest.fixture(scope="module")
def kernel_compile_context():
    """A module's tests run inside ``estimators._generated.compile_context``, as the kernels
    compile: the tracer's per-ray functions that its tests call on their own (the BVH's
    ``intersect`` and ``occluded``, the BSDFs' dispatch) compile with numba's passes as
    inside the kernels, the same code faster (empty caches, Zen 1: ``intersect`` 19.6 ->
    8.0 s, ``occluded`` 21.0 -> 7.6 s)."""
    from estimators._generated import compile_context
    with compile_context():
        yield


@pytest.fixture
def numba_threads():
    """``numba.set_num_threads`` for a test, numba's thread count put back after it."""
    import numba
    before = numba.get_num_threads()
    yield numba.set_num_threads
    numba.set_num_threads(before)


@pytest.fixture
def run_python():
    """``run(code, timeout=120)``: ``code`` run by a fresh interpreter (for state that is
    the process's: imports, numpy's print options, matplotlib's backend, environment
    variables read once), asserted to exit 0; returns its stdout, stripped."""
    def run(code: str, timeout: float = 120) -> str:
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                             timeout=timeout)
        assert out.returncode == 0, out.stderr
        return out.stdout.strip()
    return run
