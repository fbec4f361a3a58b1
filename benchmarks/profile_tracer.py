"""Where the path tracer's time goes, per scene at 128²:

    python benchmarks/profile_tracer.py [SCENE ...] [--spp 16]

- ``rays``: camera rays alone through ``geometry.intersect`` (one per pixel, 20 times,
  all threads), in millions of rays per second;
- ``depth 1`` / ``depth 2`` / ``full``: the render with ``max_depth`` cut to 1 (camera
  rays and what they see), 2 (plus one bounce: next-event estimation, one BSDF sample,
  one more ray) and the scene's own, best of 3, compilation excluded.

With ``--cpu`` the times are CPU seconds of the process (``time.process_time``, best of
5) instead of wall seconds: run it as ``NUMBA_NUM_THREADS=1 python
benchmarks/profile_tracer.py --cpu`` to compare two versions on a loaded machine, where
wall times move with the other processes and one thread's CPU time moves much less.

With ``--variance`` it answers instead whether a scene's equal-time error is a speed or a
variance matter: our per-sample variance against Mitsuba's (the reference's), per pixel
block, at the reference's resolution and number of passes (``--spp`` per pass):

    python benchmarks/profile_tracer.py veach-mis --variance

``--variance --renders N`` measures the same against Mitsuba itself at equal samples:
N renders of each side at ``--spp`` (and ``--max-depth``, to isolate direct lighting
with 2), the variance across them per pixel, summed over the image (and over all but
the 1 % of pixels with the largest variance on either side, where a firefly dominates):

    python benchmarks/profile_tracer.py vocabulary-materials --variance --renders 64 \
        --max-depth 2
"""

import argparse
import dataclasses
import time

import numpy as np
from numba import njit, prange

from estimators.pathtracer import geometry, prepare_scene, render
from estimators.pathtracer.camera import _generate_ray_kernel
from mcverify.gate.reference import load_reference, resolve_scene

import _args  # benchmarks/_args.py, beside this script

SCENES = ("cornell-box", "bunny", "glass-sphere", "envmap")


@njit(parallel=True, cache=True)
def _cast_kernel(nodes, leaf, leaf_info, cam, width, height, repeats):
    hits = np.zeros(width * height, dtype=np.int64)
    for pixel in prange(width * height):
        stack = geometry.new_stack()
        x, y = pixel % width, pixel // width
        ox, oy, oz, dx, dy, dz, t_max = _generate_ray_kernel(cam, (x + 0.5) / width,
                                                             (y + 0.5) / height)
        for _ in range(repeats):
            t, j, b1, b2 = geometry.intersect(nodes, leaf, leaf_info, stack, ox, oy, oz,
                                              dx, dy, dz, 0.0, t_max)
            hits[pixel] += j >= 0
    return hits


def variance_ratio(name: str, spp: int, block: int = 8) -> str:
    """Per-sample variance ours / reference (Mitsuba's): a pass mean of n samples has the
    per-sample variance / n, so each side's variance across passes times its samples per
    pass. Reported per block of pixels (blocks where the reference has no variance are
    left out, as is any pixel row or column beyond the last whole block): the median and quartiles of the block ratios (heavy-tailed pixels, a
    firefly, move one block, not the summary), and the ratio of whole-image sums."""
    path = resolve_scene(name)[1]
    ref = load_reference(path)
    ref_spp = int(ref.manifest["spp"])
    ours = render(path, spp=spp * ref.n, passes=ref.n, seed=11)
    v_ours = ours.variance.astype(np.float64).mean(axis=-1) * spp
    v_ref = np.asarray(ref.var, dtype=np.float64).mean(axis=-1) * ref_spp
    h, w = (s - s % block for s in v_ref.shape)
    blocks = [v[:h, :w].reshape(h // block, block, w // block, block).sum(axis=(1, 3))
              for v in (v_ours, v_ref)]
    keep = blocks[1] > 0.0
    r = blocks[0][keep] / blocks[1][keep]
    q1, med, q3 = np.percentile(r, [25, 50, 75])
    mean_ratio = ours.mean.astype(np.float64).sum() / np.asarray(ref.mean, np.float64).sum()
    return (f"{name}: per-sample variance ours / Mitsuba, {keep.sum()} blocks of {block}x"
            f"{block} px: median {med:.2f} (quartiles {q1:.2f}-{q3:.2f}), whole image "
            f"{v_ours.sum() / v_ref.sum():.2f}; mean ours / reference {mean_ratio:.4f} "
            f"({ref.n} passes: ours {spp} spp each, Mitsuba {ref_spp})")


def mitsuba_variance_ratio(name: str, spp: int, renders: int,
                           max_depth: int | None = None) -> str:
    """Our per-pixel variance across ``renders`` renders at ``spp`` against Mitsuba's,
    the scene as it is or with ``max_depth`` set (both sides the same)."""
    from mcverify.gate import mitsuba as mvm

    mi = mvm._mi()
    path = resolve_scene(name)[1]
    params = {} if max_depth is None else {"max_depth": str(max_depth)}
    theirs = mi.load_file(path, **params)
    ours = prepare_scene(path, params=params)
    # the samples Mitsuba's sampler rounds spp to, on both sides (orthogonal: 16 -> 25;
    # ours had rendered 16, its variance set against that of Mitsuba's 25)
    spp = mvm.sampler_rounds(ours.desc.sampler, spp)
    imgs = [np.array([np.asarray(mi.render(theirs, spp=spp, seed=1000 + r), np.float64)
                      for r in range(renders)]),
            np.array([render(ours, spp=spp, seed=2000 + r, variance=False).mean
                      for r in range(renders)])]
    v_theirs, v_ours = (i.var(axis=0, ddof=1).sum(axis=-1) for i in imgs)
    calm = np.maximum(v_ours, v_theirs) < np.quantile(np.maximum(v_ours, v_theirs), 0.99)
    return (f"{name}{'' if max_depth is None else f' (max_depth {max_depth})'}: variance "
            f"ours / Mitsuba at {spp} spp, {renders} renders each: whole image "
            f"{v_ours.sum() / v_theirs.sum():.3f}, without the top 1 % of pixels "
            f"{v_ours[calm].sum() / v_theirs[calm].sum():.3f}; mean ours / Mitsuba "
            f"{imgs[1].mean() / imgs[0].mean():.4f}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("scenes", nargs="*", default=list(SCENES))
    ap.add_argument("--spp", type=_args.count, default=16)
    ap.add_argument("--variance", action="store_true")
    ap.add_argument("--renders", type=int, default=0,
                    help="with --variance: against Mitsuba at equal spp, N renders a side")
    ap.add_argument("--max-depth", type=int, default=None)
    ap.add_argument("--cpu", action="store_true",
                    help="CPU seconds (time.process_time, best of 5), not wall seconds")
    a = ap.parse_args()
    if a.variance:
        for name in a.scenes:
            print(mitsuba_variance_ratio(name, a.spp, a.renders, a.max_depth) if a.renders
                  else variance_ratio(name, a.spp), flush=True)
        return
    clock, repeats = (time.process_time, 5) if a.cpu else (time.perf_counter, 3)

    def timed(fn):
        best = np.inf
        for k in range(repeats):
            t0 = clock()
            fn(k)
            best = min(best, clock() - t0)
        return best

    for name in a.scenes:
        cs = prepare_scene(resolve_scene(name)[1], params={"res": 128})
        sa, cam = cs.arrays, cs.camera.params
        _cast_kernel(sa.bvh_nodes, sa.leaf_prims, sa.leaf_info, cam, 128, 128, 1)
        best = timed(lambda k: _cast_kernel(sa.bvh_nodes, sa.leaf_prims, sa.leaf_info, cam,
                                            128, 128, 20))
        parts = [f"rays {128 * 128 * 20 / best / 1e6:.2f} M/s"]
        render(cs, spp=2)
        for depth in (1, 2, sa.max_depth):
            c = dataclasses.replace(cs, arrays=sa._replace(max_depth=depth))
            # wall: the render's own kernel time (its set-up excluded); CPU: the call's
            t = (timed(lambda k: render(c, spp=a.spp, seed=k)) if a.cpu
                 else min(render(c, spp=a.spp, seed=k).seconds for k in range(repeats)))
            parts.append(f"{'full' if depth == sa.max_depth else f'depth {depth}'} {t:.3f}s")
        print(f"{name} ({cs.n_triangles:,} triangles, {len(sa.bvh_nodes):,} nodes): "
              + ", ".join(parts) + (" (CPU seconds)" if a.cpu else ""), flush=True)


if __name__ == "__main__":
    _args.run(main)
