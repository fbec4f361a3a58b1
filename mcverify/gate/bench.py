"""Run time, ours against Mitsuba, as ratios measured in one run.

``pairs()`` gives the workloads as (group, ours, theirs) callables; ``mcverify bench``
times them (best of at least ``repeats`` runs and ``MIN_SECONDS`` of runs, after a
warm-up, so JIT compilation is excluded on both sides) and reports ``ours / theirs``;
``benchmarks/`` feeds the same callables to pytest-benchmark for saved baselines.
"""

from __future__ import annotations

import re
import time

import numpy as np

N = 1_000_000
#: Memory a point of ``n`` takes, about: the uniform numbers in float64 and float32 (24
#: bytes), our points and pdf (32), Mitsuba's float32 copies of both and their numpy
#: arrays (40); ``mcverify bench --n`` is refused where they exceed half the memory.
BYTES_PER_POINT = 96


def pairs(n: int = N, *, spp: int = 64, renders: bool = True):
    """Workloads: [(group, description, ours, theirs or None, against)]; ``against``
    names the other side (Mitsuba, or our general kernel for the specialisation row)."""
    from estimators import warps

    from .. import checks
    from . import mitsuba as mvm

    vectorised = mvm._vectorised()
    mi = mvm._mi() if vectorised else None
    u = np.random.default_rng(0).random((n, 2))
    out = []

    def mi_warp(sample, pdf, *params, u=u):
        # Both outputs are evaluated and brought back to numpy, as ours returns both:
        # where the pdf is a constant (uniform sphere, cone), asking for the pdf alone
        # would let Dr.Jit skip computing the points at all.
        def run():
            d = sample(mi.Point2f(u[:, 0], u[:, 1]), *params)
            return mvm.to_numpy(d, pdf(d, *params))
        return run

    warp_pairs = [
        ("cosine_hemisphere", warps.sample_cosine_hemisphere, warps.cosine_hemisphere_pdf, (),
         "square_to_cosine_hemisphere"),
        ("uniform_sphere", warps.sample_uniform_sphere, warps.uniform_sphere_pdf, (),
         "square_to_uniform_sphere"),
        ("uniform_cone", warps.sample_uniform_cone, warps.uniform_cone_pdf, (0.8,),
         "square_to_uniform_cone"),
        ("beckmann", warps.sample_beckmann, warps.beckmann_pdf, (0.3,), "square_to_beckmann"),
    ]
    # Ours: the sampler's ``with_pdf`` (both in one pass over the points), as Dr.Jit runs
    # Mitsuba's two calls as one kernel; the two separate calls get a row of their own.
    for label, sample, pdf, params, mi_name in warp_pairs:
        theirs = (mi_warp(getattr(mi.warp, mi_name), getattr(mi.warp, mi_name + "_pdf"), *params)
                  if vectorised else None)
        out.append((f"warp:{label}", f"sample + pdf of {n:,} points (with_pdf)",
                    lambda s=sample, a=params: s.with_pdf(u, *a), theirs, "mitsuba"))
        if label == "cosine_hemisphere":
            out.append((f"warp:{label}(two calls)", f"pdf(sample(u)) of {n:,} points",
                        lambda s=sample, p=pdf: p(s(u)), theirs, "mitsuba"))
    # float32 in, as Mitsuba computes: our front ends read and write float32 directly.
    u32 = u.astype(np.float32)
    out.append(("warp:cosine_hemisphere(float32)",
                f"sample + pdf of {n:,} float32 points (with_pdf)",
                lambda: warps.sample_cosine_hemisphere.with_pdf(u32),
                mi_warp(mi.warp.square_to_cosine_hemisphere,
                        mi.warp.square_to_cosine_hemisphere_pdf, u=u32) if vectorised else None,
                "mitsuba"))

    def ours_chi2():
        return checks.check_sampler(warps.sample_cosine_hemisphere, warps.cosine_hemisphere_pdf,
                                    "hemisphere", n_samples=n, seed=0)

    theirs_chi2 = mvm.chi2_cosine_hemisphere(n) if vectorised else None
    out.append(("chi2:cosine_hemisphere", f"sampler vs pdf test, {n:,} samples", ours_chi2,
                theirs_chi2, "mitsuba"))
    if renders:
        out += _render_pairs(mi if vectorised else mvm._mi(), spp)
    return out


def _render_pairs(mi, spp: int):
    """The path tracer: the render gate's decision time on the Cornell box (no
    counterpart); every reference scene at ``res`` 128 (128 × 128 unless its film fixes
    a side; its own integrator settings), ours
    against Mitsuba at the same spp; and the specialised kernel against the general one
    on a diffuse-only scene (the white furnace)."""
    from estimators.pathtracer import prepare_scene, render

    from . import mitsuba as mvm
    from .reference import BUNDLED_ROOT, list_scenes, resolve_scene

    # the fixed workloads are the scenes that come with mcverify: `bench --refs MYDIR`
    # refused MYDIR without a white-furnace (and would without a cornell-box)
    cornell = resolve_scene("cornell-box", BUNDLED_ROOT)[1]

    def gate():
        from .render_check import render_check
        return render_check(cornell)

    out = [("render-check:cornell-box", "the render gate at its defaults, 64 x 64, reference "
            "cached (budget: 30 s)", gate, None, "-")]
    # One Mitsuba scene alive at a time, loaded at its row's first call (the warm-up): with
    # all 17 reference scenes loaded, Mitsuba rendered the Cornell box in 0.35 s instead
    # of 0.235 s (64 spp, 128²), which flattered our ratios by about 1.5×.
    loaded: dict = {}

    def theirs_render(path, params):
        def run():
            if loaded.get("path") != path:
                loaded.clear()                  # drop the previous scene before loading
                loaded["scene"] = mi.load_file(path, **params)
                loaded["path"] = path
            return np.asarray(mi.render(loaded["scene"], spp=spp))
        return run

    for name in list_scenes():
        path = resolve_scene(name)[1]
        params = _res_128(path)
        ours = prepare_scene(path, params=params)
        depth = ours.arrays.max_depth
        # ours renders the samples Mitsuba's sampler rounds spp to (orthogonal: 64 -> 121)
        n = mvm.sampler_rounds(ours.desc.sampler, spp)
        # the film's own size: a scene whose width is fixed (vocabulary-geometry's 64)
        # renders 64 x 128 on both sides, which this label had called 128 x 128
        what = (f"{ours.width} x {ours.height}, {ours.n_triangles:,} triangles, max_depth "
                f"{depth if depth < 1 << 30 else 'unlimited'}, {n} spp, the image alone")
        # the image alone on both sides (ours variance=False, as the render gate's passes)
        out.append((f"render:{name}", what,
                    lambda ours=ours, n=n: render(ours, spp=n, variance=False),
                    theirs_render(path, params), "mitsuba"))
    furnace = prepare_scene(resolve_scene("white-furnace", BUNDLED_ROOT)[1],
                            params={"res": 128})
    out.append(("kernel:specialised/general", f"white furnace (diffuse only), {spp} spp",
                lambda: render(furnace, spp=spp, general=False),
                lambda: render(furnace, spp=spp, general=True), "general kernel"))
    return out


def _res_128(path: str) -> dict:
    """``{"res": 128}`` for a scene that takes a ``res`` parameter (every scene that comes
    with mcverify), else ``{}``: the scene at its own film size. A ``--refs`` scene of the
    user's with a literal film size was refused by both renderers ("params ['res']: the
    scene has no such parameter"; Mitsuba: "Found unused parameters")."""
    with open(path, encoding="utf-8", errors="replace") as f:  # the loader names a bad
        text = f.read()                                         # encoding, not this read
    uses = re.search(r"""<default\s+name\s*=\s*["']res["']|\$res\b""", text)
    return {"res": 128} if uses else {}


def equal_time_rmse(scene: str = "cornell-box", spp: int = 16, seed: int = 1,
                    repeats: int = 16, mi=None, clock=time.perf_counter) -> dict:
    """RMSE of ours and of Mitsuba against the scene's reference when both get the time
    Mitsuba needs for ``spp`` samples per pixel. Both sides' times are whole render calls
    (the scene loaded and prepared before; JIT excluded: each side renders once first),
    the best of 3. Each side's MSE is the mean over ``repeats`` independent renders: one
    image's MSE is a noisy estimate where a few bright samples dominate (a tiny light seen
    in a glossy plate): single pairs of images put the Veach scene's ratio at 0.23, 0.33
    and 1.18 for three seeds, and 4 renders a side (until 3 December) vocabulary-lights'
    at 1.27 where 16 renders a side at equal spp gave 0.97 (its renders take ~10 ms).
    The reference's own noise, var / passes, is subtracted from both mean MSEs."""
    from estimators.pathtracer import prepare_scene, render

    from . import mitsuba as mvm
    from .reference import load_reference, resolve_scene

    mi = mvm._mi() if mi is None else mi             # (a stand-in and a clock for tests)
    path = resolve_scene(scene)[1]
    ref = load_reference(path)
    their_scene = mi.load_file(path)
    ours_scene = prepare_scene(path)
    spp = mvm.sampler_rounds(ours_scene.desc.sampler, spp)   # Mitsuba's (orthogonal: 16 -> 25)

    def theirs(s: int, n: int = spp):
        return np.asarray(mi.render(their_scene, spp=n, seed=s), dtype=np.float64)

    def ours(s: int, n: int = spp):
        return render(ours_scene, spp=n, seed=s, variance=False).mean

    def best_time(fn) -> float:
        seeds = iter(range(seed, seed + 4))           # the warm-up's, then each timed run's
        return _best(lambda: fn(next(seeds)), 3, clock)

    t_theirs, t_ours = best_time(theirs), best_time(ours)
    ours_spp = max(2, int(round(spp * t_theirs / t_ours)))
    mse_theirs = np.mean([ref.mse(theirs(seed + 100 + r)) for r in range(repeats)])
    mse_ours = np.mean([ref.mse(ours(seed + 200 + r, ours_spp)) for r in range(repeats)])
    r_ours, r_theirs = ref.rmse_of_mean_mse(mse_ours), ref.rmse_of_mean_mse(mse_theirs)
    return {"group": f"equal-time-rmse:{scene}", "workload":
            f"Mitsuba {spp} spp in {t_theirs:.3f}s; ours {ours_spp} spp "
            f"(ours {spp} spp in {t_ours:.3f}s); mean MSE of {repeats} renders each",
            "ours_rmse": r_ours, "mitsuba_rmse": r_theirs,
            "ratio": r_ours / r_theirs if r_theirs > 0 else float("nan"), "against": "mitsuba"}


#: ``run_bench`` repeats a workload at least this long (and at least ``repeats`` times):
#: a best of 5 runs of 3 ms, on a shared 2-core machine, moved by 30 % between runs.
MIN_SECONDS = 0.25


def _best(fn, repeats: int, clock=time.perf_counter, min_seconds: float = 0.0) -> float:
    """Best time of ``fn`` over at least ``repeats`` runs and ``min_seconds`` of runs
    (at most 1000), after a warm-up."""
    if isinstance(repeats, bool) or not isinstance(repeats, int) or repeats < 1:
        # benchmarks/tracer_speed.py --repeats 0 printed "ours infs" (no run timed)
        raise ValueError(f"repeats={repeats!r}: must be an integer >= 1")
    fn()  # warm-up: JIT compilation on both sides is excluded
    best, spent, runs = np.inf, 0.0, 0
    while runs < repeats or (spent < min_seconds and runs < 1000):
        t0 = clock()
        fn()
        t = clock() - t0
        best, spent, runs = min(best, t), spent + t, runs + 1
    return float(best)


def _not_vectorised() -> str:
    """Why a row has no Mitsuba time: the variant in use and why it is that one. It said
    "no libLLVM >= 16" also where a libLLVM was found but failed Dr.Jit's probe, or where
    $MCVERIFY_MITSUBA_VARIANT chose scalar_rgb."""
    from . import mitsuba as mvm

    choice = mvm.choose_variant()
    why = (choice.notice.removeprefix("mitsuba: ") if choice.notice
           else "chosen by $MCVERIFY_MITSUBA_VARIANT")
    return f"Mitsuba's variant here, {choice.variant}, is not vectorised ({why})"


def equal_time_spp(spp: int) -> int:
    """The spp the equal-time rows ask of Mitsuba for a bench at ``spp`` (a quarter;
    its sampler may round it up, as each row's workload says)."""
    return max(2, spp // 4)


def run_bench(*, repeats: int = 5, n: int = N, spp: int = 64, renders: bool = True,
              progress=None) -> list[dict]:
    """Time every pair (best of at least ``repeats`` runs and ``MIN_SECONDS`` of runs,
    after a warm-up) and, with ``renders``, the equal-time RMSE of the path tracer on
    every reference scene. ``ratio`` is ours / theirs: time for timings, RMSE for the
    equal-time rows."""
    from .reference import list_scenes, load_reference, resolve_scene

    rows = []
    scenes = list_scenes() if renders else []
    for scene in scenes:    # the equal-time rows need references: refused before any timing
        load_reference(resolve_scene(scene)[1])
    work = pairs(n, spp=spp, renders=renders)
    total = len(work) + len(scenes)
    for i, (group, what, ours, theirs, against) in enumerate(work):
        t_ours = _best(ours, repeats, min_seconds=MIN_SECONDS)
        t_theirs = (_best(theirs, repeats, min_seconds=MIN_SECONDS) if theirs is not None
                    else None)
        rows.append({"group": group, "workload": what, "ours_s": t_ours,
                     "mitsuba_s": t_theirs, "against": against,
                     "ratio": None if t_theirs is None else t_ours / t_theirs,
                     "note": None if theirs is not None else
                     "no counterpart" if against == "-" else _not_vectorised()})
        if progress:
            progress(i + 1, total, rows[-1])
    for i, scene in enumerate(scenes):
        rows.append(equal_time_rmse(scene, spp=equal_time_spp(spp)))
        if progress:
            progress(len(work) + i + 1, total, rows[-1])
    return rows
