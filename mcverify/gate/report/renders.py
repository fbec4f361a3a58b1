"""The render part of a report: per reference scene, the render gate's verdict with its
images (ours, Mitsuba, difference, p-map, ΔE2000, ΔE ITP, FLIP), and error against spp and against
seconds for both renderers (RMSE against the reference, the reference's own noise
subtracted).
"""

from __future__ import annotations

import time

import numpy as np

SPPS = (4, 16, 64, 256)


def _shifted(seed: int, by: int) -> int:
    """Seed ``seed + by`` kept within the seeds our renders take (0 to 2^63 - 1)."""
    return (seed + by) % (1 << 63)


def run_renders(scenes, *, seed: int = 0, spps=SPPS, progress=None,
                notice=None) -> tuple[list, dict]:
    """(JSON-able rows, {scene: image arrays for the panels}). ``notice(message)``: the
    render check's notices (a reference built for a scene that has none, Mitsuba's
    fallback variant), which ``report --renders`` made silently until 7 December."""
    from estimators.pathtracer import prepare_scene, render

    from .. import mitsuba as mvm
    from ..render_check import render_check
    from ..reference import load_reference, resolve_scene

    mi = mvm._mi()
    rows, arrays = [], {}
    for i, name in enumerate(scenes):
        _, path = resolve_scene(name)
        check = render_check(path, seed=seed, notice=notice)
        ref = load_reference(path)
        ours_scene, their_scene = prepare_scene(path), mi.load_file(path)
        render(ours_scene, spp=2, seed=seed)                     # warm-ups: JIT excluded
        np.asarray(mi.render(their_scene, spp=spps[0], seed=mvm.mitsuba_seed(seed)))
        # both sides at the samples Mitsuba's sampler renders (orthogonal: 16 -> 25, 64 ->
        # 121): Mitsuba's curve was plotted at the spp asked, beside ours at that count
        counts = [mvm.sampler_rounds(ours_scene.desc.sampler, max(s, 2)) for s in spps]
        curve = {"spp": counts, "ours_rmse": [], "ours_seconds": [], "mitsuba_rmse": [],
                 "mitsuba_seconds": []}
        for k, spp in enumerate(counts):
            r = render(ours_scene, spp=spp, seed=_shifted(seed, 10 + k))
            curve["ours_rmse"].append(ref.rmse(r.mean))
            curve["ours_seconds"].append(r.seconds)
            # a render per spp first: Mitsuba compiles its kernels per spp
            warm = mvm.mitsuba_seed(_shifted(seed, 20 + k))
            np.asarray(mi.render(their_scene, spp=spp, seed=warm))
            t0 = time.perf_counter()
            img = np.asarray(mi.render(their_scene, spp=spp,
                                       seed=mvm.mitsuba_seed(_shifted(seed, 30 + k))))
            curve["mitsuba_seconds"].append(time.perf_counter() - t0)
            curve["mitsuba_rmse"].append(ref.rmse(img))
        d = check.details
        rows.append({"scene": name, "passed": check.passed, "p_value": check.p_value,
                     "found_by": d["found_by"], "relmse": d["relmse"],
                     "delta_e2000_mean": d.get("delta_e2000_mean"),
                     "delta_e_itp_mean": d.get("delta_e_itp_mean"),
                     "flip_mean": d.get("flip_mean"),
                     "ours_spp": d["ours_spp"], "ours_passes": d["ours_passes"],
                     "ours_seconds": d["ours_seconds"], "kernel": d["ours_kernel"],
                     "reference": {k: d["reference"].get(k) for k in
                                   ("spp", "passes", "mitsuba_version", "mitsuba_variant")},
                     "curve": curve})
        a = check.artifacts
        arrays[name] = {"ours": a["ours"], "mitsuba": a["mitsuba"], "p_map": a["p_map"],
                        "delta_e": a.get("delta_e2000"), "delta_itp": a.get("delta_e_itp"),
                        "flip": a.get("flip")}
        if progress:
            progress(i + 1, len(scenes), check)
    return rows, arrays
