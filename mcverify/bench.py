"""Run time, ours against Mitsuba, as ratios measured in one run.

``pairs()`` gives the workloads as (group, ours, theirs) callables; ``mcverify bench``
times them (best of ``repeats`` after a warm-up, so JIT compilation is excluded on both
sides) and reports ``ours / theirs``; ``benchmarks/`` feeds the same callables to
pytest-benchmark for saved baselines.
"""

from __future__ import annotations

import contextlib
import io
import time

import numpy as np

N = 1_000_000


def pairs(n: int = N):
    """Workloads: [(group, description, ours, theirs or None)]."""
    from estimators import warps as W

    from . import checks
    from . import mitsuba as mvm

    vectorised = not mvm.choose_variant().variant.startswith("scalar")
    mi = mvm._mi() if vectorised else None
    u = np.random.default_rng(0).random((n, 2))
    out = []

    def mi_warp(sample, pdf, *params):
        def run():
            d = sample(mi.Point2f(u[:, 0], u[:, 1]), *params)
            return np.asarray(pdf(d, *params))
        return run

    warp_pairs = [
        ("cosine_hemisphere", W.sample_cosine_hemisphere, W.cosine_hemisphere_pdf, (),
         "square_to_cosine_hemisphere"),
        ("uniform_sphere", W.sample_uniform_sphere, W.uniform_sphere_pdf, (),
         "square_to_uniform_sphere"),
        ("uniform_cone", W.sample_uniform_cone, W.uniform_cone_pdf, (0.8,),
         "square_to_uniform_cone"),
        ("beckmann", W.sample_beckmann, W.beckmann_pdf, (0.3,), "square_to_beckmann"),
    ]
    for label, sample, pdf, params, mi_name in warp_pairs:
        theirs = (mi_warp(getattr(mi.warp, mi_name), getattr(mi.warp, mi_name + "_pdf"), *params)
                  if vectorised else None)
        out.append((f"warp:{label}", f"sample + pdf of {n:,} points",
                    lambda s=sample, p=pdf, a=params: p(s(u, *a), *a), theirs))

    def ours_chi2():
        return checks.check_sampler(W.sample_cosine_hemisphere, W.cosine_hemisphere_pdf,
                                    "hemisphere", n_samples=n, seed=0)

    theirs_chi2 = None
    if vectorised:
        import drjit as dr
        from mitsuba.chi2 import ChiSquareTest, SphericalDomain

        def theirs_chi2():
            with contextlib.redirect_stdout(io.StringIO()):   # its log goes to stdout
                return ChiSquareTest(
                    domain=SphericalDomain(),
                    sample_func=lambda s: mi.warp.square_to_cosine_hemisphere(s),
                    pdf_func=lambda v: dr.maximum(mi.warp.square_to_cosine_hemisphere_pdf(v),
                                                  0.0),
                    sample_dim=2, sample_count=n).run()

    out.append(("chi2:cosine_hemisphere", f"sampler vs pdf test, {n:,} samples", ours_chi2,
                theirs_chi2))
    return out


def _best(fn, repeats: int) -> float:
    fn()  # warm-up: JIT compilation on both sides is excluded
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return float(best)


def run_bench(*, repeats: int = 5, n: int = N, progress=None) -> list[dict]:
    rows = []
    work = pairs(n)
    for i, (group, what, ours, theirs) in enumerate(work):
        t_ours = _best(ours, repeats)
        t_theirs = _best(theirs, repeats) if theirs is not None else None
        rows.append({"group": group, "workload": what, "ours_s": t_ours,
                     "mitsuba_s": t_theirs,
                     "ratio": None if t_theirs is None else t_ours / t_theirs,
                     "note": None if theirs is not None else
                     "Mitsuba's vectorised llvm variant unavailable (no libLLVM >= 16)"})
        if progress:
            progress(i + 1, len(work), rows[-1])
    return rows
