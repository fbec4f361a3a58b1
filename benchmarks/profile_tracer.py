"""Where the path tracer's time goes, per scene at 128²:

    python benchmarks/profile_tracer.py [SCENE ...] [--spp 16]

- ``rays``: camera rays alone through ``geometry.intersect`` (one per pixel, 20 times,
  all threads), in millions of rays per second;
- ``depth 1`` / ``depth 2`` / ``full``: the render with ``max_depth`` cut to 1 (camera
  rays and what they see), 2 (plus one bounce: next-event estimation, one BSDF sample,
  one more ray) and the scene's own, best of 3, compilation excluded.
"""

import argparse
import dataclasses
import time

import numpy as np
from numba import njit, prange

from estimators.pathtracer import geometry, prepare_scene, render
from estimators.pathtracer.camera import _generate_ray_kernel
from mcverify.gate.reference import resolve_scene

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


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("scenes", nargs="*", default=list(SCENES))
    ap.add_argument("--spp", type=int, default=16)
    a = ap.parse_args()
    for name in a.scenes:
        cs = prepare_scene(resolve_scene(name)[1], params={"res": 128})
        sa, cam = cs.arrays, cs.camera.params
        _cast_kernel(sa.bvh_nodes, sa.leaf_prims, sa.leaf_info, cam, 128, 128, 1)
        best = np.inf
        for _ in range(3):
            t0 = time.perf_counter()
            _cast_kernel(sa.bvh_nodes, sa.leaf_prims, sa.leaf_info, cam, 128, 128, 20)
            best = min(best, time.perf_counter() - t0)
        parts = [f"rays {128 * 128 * 20 / best / 1e6:.2f} M/s"]
        render(cs, spp=2)
        for depth in (1, 2, sa.max_depth):
            c = dataclasses.replace(cs, arrays=sa._replace(max_depth=depth))
            t = min(render(c, spp=a.spp, seed=k).seconds for k in range(3))
            parts.append(f"{'full' if depth == sa.max_depth else f'depth {depth}'} {t:.3f}s")
        print(f"{name} ({cs.n_triangles:,} triangles, {len(sa.bvh_nodes):,} nodes): "
              + ", ".join(parts), flush=True)


if __name__ == "__main__":
    main()
