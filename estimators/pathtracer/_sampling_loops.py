"""The row loops of ``sampling``: a template, never imported as it is. ``sampling``
loads a copy from the kernel cache folder whose name carries a hash of every tracer
source (``render.load_cached``): numba's cache checks only this file, not the kernels it
calls, so an edited BSDF or emitter gets new loops, never stale ones. Each computes
rows ``i0`` to ``i1``; ``sampling`` runs them on numba's threads (``mcnumba.threads``)."""

import numpy as np

from estimators._compile_options import THREADED, fused
from estimators.pathtracer.bsdfs import bsdf_eval, bsdf_sample
from estimators.pathtracer.emitters import area_pdf, eval_environment, sample_emitter
from estimators.pathtracer.geometry import _hit_prim, surface
from estimators.pathtracer.layout import (AREA, LEAF_KIND, LEAF_PRIM, LIGHT_KIND,
                                          LIGHT_RADIANCE, PRIM_SHAPE)

_UV = 0.5    # texture coordinates of textured BSDFs (textures change weights, not directions)


@fused(**THREADED)
def _bsdf_sample_rows(mask, bf, bi, btex, tex_data, tex_info, b, wx, wy, wz, u, out, i0, i1):
    wi = (wx, wy, wz)
    for i in range(i0, i1):
        r = bsdf_sample(mask, bf, bi, btex, tex_data, tex_info, b, wi, u[i, 0], u[i, 1],
                        u[i, 2], _UV, _UV, 1.0)
        if r[6] > 0.0 and not r[7]:     # direction, weight (rgb), pdf
            out[i, 0], out[i, 1], out[i, 2] = r[0], r[1], r[2]
            out[i, 3], out[i, 4], out[i, 5], out[i, 6] = r[3], r[4], r[5], r[6]
        else:
            out[i, :] = np.nan


@fused(**THREADED)
def _bsdf_eval_rows(mask, bf, bi, btex, tex_data, tex_info, b, wx, wy, wz, wo, out, i0, i1):
    wi = (wx, wy, wz)
    for i in range(i0, i1):     # value (f · cos, rgb), pdf
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = bsdf_eval(
            mask, bf, bi, btex, tex_data, tex_info, b, wi, (wo[i, 0], wo[i, 1], wo[i, 2]),
            _UV, _UV)


@fused(**THREADED)
def _emitter_sample_rows(light_f, light_i, light_cdf, prims, info, shape_flip, tex_data,
                         tex_info, env_marg, env_cond, k, x, y, z, u, out, i0, i1):
    for i in range(i0, i1):
        r = sample_emitter(light_f, light_i, light_cdf, prims, info, shape_flip, tex_data,
                           tex_info, env_marg, env_cond, k, x, y, z, u[i, 0], u[i, 1], u[i, 2])
        if r[7] > 0.0:          # direction, distance, Le (rgb), pdf
            for c in range(8):
                out[i, c] = r[c]
        else:
            out[i, :] = np.nan


@fused(**THREADED)
def _emitter_eval_rows(light_f, light_i, prims, info, shape_flip, leaf, leaf_info, rows,
                       tex_data, tex_info, env_marg, env_cond, k, x, y, z, d, out, i0, i1):
    """Per direction: the density summed over every front-facing point of the light
    along the ray; the distance to the nearest point of the light (front or back); the
    density and radiance (rgb) there, as the kernel's MIS and emission read them when a
    BSDF-sampled ray meets the light (0 where that point faces away)."""
    area = light_i[k, LIGHT_KIND] == AREA
    for i in range(i0, i1):
        dx, dy, dz = d[i, 0], d[i, 1], d[i, 2]
        if not area:
            r = eval_environment(light_f, light_i, tex_data, tex_info, env_marg, env_cond, k,
                                 dx, dy, dz, True)
            out[i, 0], out[i, 1], out[i, 2] = r[3], np.inf, r[3]
            out[i, 3], out[i, 4], out[i, 5] = r[0], r[1], r[2]
            continue
        # every point of the light along the ray, not only the nearest: the sampler
        # draws points by area without testing visibility, so a part of the light
        # behind another (a folded mesh) adds its density to the same direction
        total, t_near, pdf_near, front_near = 0.0, np.inf, 0.0, False
        for r in rows:
            t, b1, b2 = _hit_prim(leaf[r], leaf_info[r, LEAF_KIND], x, y, z, dx, dy, dz)
            if t == np.inf:
                continue
            j = leaf_info[r, LEAF_PRIM]
            s = surface(prims, info, j, x, y, z, dx, dy, dz, t, b1, b2)
            cos_y = -(s[6] * dx + s[7] * dy + s[8] * dz)
            if shape_flip[info[j, PRIM_SHAPE]]:
                cos_y = -cos_y
            pdf = area_pdf(light_f, light_i, prims, info, k, x, y, z, t, cos_y) \
                if cos_y > 0.0 else 0.0
            total += pdf
            if t < t_near:
                t_near, pdf_near, front_near = t, pdf, cos_y > 0.0
        out[i, 0], out[i, 1], out[i, 2] = total, t_near, pdf_near
        for c in range(3):
            out[i, 3 + c] = light_f[k, LIGHT_RADIANCE + c] if front_near else 0.0
