"""Emitters as numba kernels: area lights on shapes, point, spot, directional, constant
and envmap, with Mitsuba's radiometric conventions (area lights emit on the front side of
the shape's normal; a spot's falloff is 1 inside ``beam_width`` and falls linearly in
angle to 0 at ``cutoff_angle``; a point's ``intensity`` is radiant intensity; a
directional's ``irradiance`` is measured perpendicular to its direction).

Each emitter is a row of ``light_f`` and ``light_i``, with the columns named in
``layout`` (``LIGHT_KIND``, ``LIGHT_RADIANCE``, ``SPOT_AXIS``...). Light sampling picks an emitter
uniformly (as Mitsuba does), then a point on it: triangles by area (the estimators'
discrete distribution and triangle warp), disks uniformly, spheres by the cone they
subtend (the estimators' cone warp), envmaps by the estimators' piecewise-constant 2-D
distribution over (u, v).
"""

from __future__ import annotations

import math

import numpy as np

from .._compile_options import fused
from .._fastmath import fast_acos
from ..distributions import pc2d_pdf_kernel, sample_discrete_kernel, sample_pc2d_kernel
from ..warps import (sample_uniform_cone_kernel, sample_uniform_disk_concentric_kernel,
                     sample_uniform_sphere_kernel, sample_uniform_triangle_kernel)
from .geometry import coordinate_system, to_world, triangle_point, triangle_shading_normal
from .layout import (AREA, CONSTANT, DIRECTIONAL, DISK_TO_LOCAL, DISK_TO_WORLD, ENV_SCALE,
                     ENV_TO_LOCAL, LIGHT_AREA, LIGHT_CDF, LIGHT_DIRECTION, LIGHT_KIND,
                     LIGHT_POSITION, LIGHT_PRIM, LIGHT_PRIM_COUNT, LIGHT_RADIANCE,
                     LIGHT_TEXTURE, POINT, PRIM_KIND, PRIM_SHAPE, SPHERE, SPHERE_CENTER,
                     SPHERE_RADIUS, SPOT, SPOT_AXIS, SPOT_COS_BEAM, SPOT_COS_CUTOFF,
                     SPOT_CUTOFF, SPOT_INV_FALLOFF, TRIANGLE)
from .textures import envmap_direction, envmap_uv, eval_envmap
_jit = fused()
# Per-ray functions skip reference counting (_nrt=False): they allocate nothing, and the
# atomic count updates on shared arrays cost more than the work when all threads call.
# They are inlined into the kernel (numba IR inlining), as is the camera ray: a call
# passes every array argument as a struct of ~9 words on the stack, and inlining these
# made renders 3-11 % faster (one thread: Cornell box 0.131 -> 0.117 s, veach-mis 0.107
# -> 0.097, vocabulary-glass 1.00 -> 0.90), images bit-identical, for ~12 s more
# compilation of the general kernel (48 -> 60 s). The texture lookups stay calls:
# inlining them too cost 230 s more.
_fast = fused(_nrt=False, inline="always")
_INV_FOUR_PI = 1.0 / (4.0 * math.pi)


@fused(inline="always")
def _xyz(row, col):
    """The three entries of a row from column ``col`` (a colour, point or direction)."""
    return row[col], row[col + 1], row[col + 2]


@_jit
def is_delta(kind):
    return kind == POINT or kind == SPOT or kind == DIRECTIONAL


@_fast
def _sphere_cone(prims, j, x, y, z):
    """(cos θ_max, distance to centre) of the cone a sphere subtends from outside, or
    (-2, d) when the point is inside."""
    p = prims[j]
    dx, dy, dz = p[SPHERE_CENTER] - x, p[SPHERE_CENTER + 1] - y, p[SPHERE_CENTER + 2] - z
    d2 = dx * dx + dy * dy + dz * dz
    r2 = p[SPHERE_RADIUS] * p[SPHERE_RADIUS]
    if d2 <= r2 * (1.0 + 1e-9):
        return -2.0, math.sqrt(d2)
    sin2 = r2 / d2
    return math.sqrt(max(0.0, 1.0 - sin2)), math.sqrt(d2)


@_fast
def _sample_area(light_f, light_i, light_cdf, prims, info, k, x, y, z, u0, u1, u2,
                 flip):
    """A point on area light k as (wx, wy, wz, dist, pdf in solid angle)."""
    first, off, count = light_i[k, LIGHT_PRIM], light_i[k, LIGHT_CDF], light_i[k, LIGHT_PRIM_COUNT]
    kind = info[first, PRIM_KIND]
    if kind == SPHERE:
        cos_max, dc = _sphere_cone(prims, first, x, y, z)
        p = prims[first]
        if cos_max > -2.0:
            c0, c1, c2 = _xyz(p, SPHERE_CENTER)
            cx, cy, cz = (c0 - x) / dc, (c1 - y) / dc, (c2 - z) / dc
            s, t = coordinate_system(cx, cy, cz)
            lw = sample_uniform_cone_kernel((u1, u2), (cos_max,))
            wx, wy, wz = to_world(s, t, (cx, cy, cz), lw[0], lw[1], lw[2])
            # near intersection with the sphere along w
            b = dc * lw[2]
            disc = p[SPHERE_RADIUS] * p[SPHERE_RADIUS] - dc * dc * (1.0 - lw[2] * lw[2])
            dist = b - math.sqrt(max(disc, 0.0))
            # outward normal at the hit; emission needs it to face the point
            nx = (x + dist * wx - p[SPHERE_CENTER]) / p[SPHERE_RADIUS]
            ny = (y + dist * wy - p[SPHERE_CENTER + 1]) / p[SPHERE_RADIUS]
            nz = (z + dist * wz - p[SPHERE_CENTER + 2]) / p[SPHERE_RADIUS]
            cos_y = -(nx * wx + ny * wy + nz * wz)
            if flip:
                cos_y = -cos_y
            if cos_y <= 0.0:
                return 0.0, 0.0, 1.0, 0.0, 0.0
            one_minus = (1.0 - cos_max * cos_max) / (1.0 + cos_max)
            return wx, wy, wz, dist, 1.0 / (2.0 * math.pi * one_minus)
        # inside the sphere: uniform over its area
        sw = sample_uniform_sphere_kernel((u1, u2), (0.0,))
        c0, c1, c2 = _xyz(p, SPHERE_CENTER)
        r = p[SPHERE_RADIUS]
        px, py, pz = c0 + r * sw[0], c1 + r * sw[1], c2 + r * sw[2]
        nx, ny, nz = sw[0], sw[1], sw[2]
        area = 4.0 * math.pi * p[SPHERE_RADIUS] * p[SPHERE_RADIUS]
    elif kind == TRIANGLE:
        i, _, _ = sample_discrete_kernel(light_cdf[off:off + count + 1], u0)
        p = prims[first + i]
        bary = sample_uniform_triangle_kernel((u1, u2), (0.0,))
        px, py, pz, gx, gy, gz = triangle_point(p, bary[0], bary[1])
        # Mitsuba's mesh position samples carry the interpolated vertex normal, which
        # decides the emitting side and the pdf's cosine (as the hit's shading normal does)
        nx, ny, nz = triangle_shading_normal(p, bary[0], bary[1], gx, gy, gz)
        area = light_f[k, LIGHT_AREA]
    else:  # disk
        p = prims[first]
        dpt = sample_uniform_disk_concentric_kernel((u1, u2), (0.0,))
        px = p[DISK_TO_WORLD + 0] * dpt[0] + p[DISK_TO_WORLD + 1] * dpt[1] + p[DISK_TO_WORLD + 3]
        py = p[DISK_TO_WORLD + 4] * dpt[0] + p[DISK_TO_WORLD + 5] * dpt[1] + p[DISK_TO_WORLD + 7]
        pz = p[DISK_TO_WORLD + 8] * dpt[0] + p[DISK_TO_WORLD + 9] * dpt[1] + p[DISK_TO_WORLD + 11]
        nx, ny, nz = p[DISK_TO_LOCAL + 8], p[DISK_TO_LOCAL + 9], p[DISK_TO_LOCAL + 10]
        ln = math.sqrt(nx * nx + ny * ny + nz * nz)
        nx, ny, nz = nx / ln, ny / ln, nz / ln
        area = light_f[k, LIGHT_AREA]
    if flip:
        nx, ny, nz = -nx, -ny, -nz
    dx, dy, dz = px - x, py - y, pz - z
    d2 = dx * dx + dy * dy + dz * dz
    dist = math.sqrt(d2)
    if dist == 0.0:
        return 0.0, 0.0, 1.0, 0.0, 0.0
    wx, wy, wz = dx / dist, dy / dist, dz / dist
    cos_y = -(nx * wx + ny * wy + nz * wz)
    if cos_y <= 0.0:
        return 0.0, 0.0, 1.0, 0.0, 0.0
    return wx, wy, wz, dist, d2 / (cos_y * area)


@_fast
def area_pdf(light_f, light_i, prims, info, k, x, y, z, dist, cos_y):
    """Solid-angle pdf (excluding the choice of light) with which ``_sample_area`` picks
    the point at ``dist`` along a ray from (x, y, z) meeting the light at cosine cos_y."""
    first = light_i[k, LIGHT_PRIM]
    if info[first, PRIM_KIND] == SPHERE:
        cos_max, _ = _sphere_cone(prims, first, x, y, z)
        if cos_max > -2.0:
            one_minus = (1.0 - cos_max * cos_max) / (1.0 + cos_max)
            return 1.0 / (2.0 * math.pi * one_minus)
        area = 4.0 * math.pi * prims[first, SPHERE_RADIUS] ** 2
    else:
        area = light_f[k, LIGHT_AREA]
    return dist * dist / (abs(cos_y) * area)


@_fast
def _env_uv(f, dx, dy, dz):
    """(u, v, sin θ) of the world direction d in the map of the environment whose row
    of ``light_f`` is ``f``."""
    lx = f[ENV_TO_LOCAL + 0] * dx + f[ENV_TO_LOCAL + 1] * dy + f[ENV_TO_LOCAL + 2] * dz
    ly = f[ENV_TO_LOCAL + 3] * dx + f[ENV_TO_LOCAL + 4] * dy + f[ENV_TO_LOCAL + 5] * dz
    lz = f[ENV_TO_LOCAL + 6] * dx + f[ENV_TO_LOCAL + 7] * dy + f[ENV_TO_LOCAL + 8] * dz
    u, v = envmap_uv(lx, ly, lz)
    # sin θ from the other two coordinates, as Mitsuba's pdf_direction: 1 - ly² cancels
    # near a pole (a relative error of ~1e-16 / θ², 1e-5 at θ = 3e-6)
    return u, v, math.sqrt(lx * lx + lz * lz)


@_fast
def _env_radiance(light_f, light_i, tex_data, tex_info, k, u, v):
    r, g, b = eval_envmap(tex_data, tex_info, light_i[k, LIGHT_TEXTURE], u, v)
    s = light_f[k, ENV_SCALE]
    return r * s, g * s, b * s


@_fast
def _uv_to_solid_angle(pdf_uv, sin_theta):
    """A density over the map's (u, v) as one over solid angle: divided by the Jacobian
    2π² sin θ (0 at the poles, where sin θ = 0)."""
    if sin_theta == 0.0:
        return 0.0
    return pdf_uv / (2.0 * math.pi * math.pi * sin_theta)


@_fast
def _env_pdf(env_marg, env_cond, u, v, sin_theta):
    """Solid-angle density of sampling (u, v)."""
    return _uv_to_solid_angle(pc2d_pdf_kernel(env_marg, env_cond, u, v), sin_theta)


@_fast
def eval_environment(light_f, light_i, tex_data, tex_info, env_marg, env_cond, k,
                     dx, dy, dz, with_pdf):
    """Radiance (r, g, b) of environment k seen along the escaping ray direction d, and,
    if ``with_pdf``, the solid-angle density of sampling d (else 0): one (u, v) lookup
    serves both (two arc tangents per escaping ray were 10 % of a render of
    vocabulary-lights)."""
    if light_i[k, LIGHT_KIND] == CONSTANT:
        lr, lg, lb = _xyz(light_f[k], LIGHT_RADIANCE)
        return lr, lg, lb, _INV_FOUR_PI
    u, v, s = _env_uv(light_f[k], dx, dy, dz)
    r, g, b = _env_radiance(light_f, light_i, tex_data, tex_info, k, u, v)
    return r, g, b, _env_pdf(env_marg, env_cond, u, v, s) if with_pdf else 0.0


@_fast
def environment_pdf(light_f, light_i, env_marg, env_cond, k, dx, dy, dz):
    if light_i[k, LIGHT_KIND] == CONSTANT:
        return _INV_FOUR_PI
    u, v, s = _env_uv(light_f[k], dx, dy, dz)
    return _env_pdf(env_marg, env_cond, u, v, s)


@_fast
def sample_emitter(light_f, light_i, light_cdf, prims, info, shape_flip, tex_data, tex_info,
                   env_marg, env_cond, k, x, y, z, u0, u1, u2):
    """Sample light k from (x, y, z): (wx, wy, wz, dist, Le r, g, b, pdf) with Le the
    incident radiance (or intensity / dist², or irradiance, for delta lights) and pdf the
    solid-angle density (1 for delta lights). dist is inf for lights at infinity."""
    kind = light_i[k, LIGHT_KIND]
    f = light_f[k]
    if kind == AREA:
        wx, wy, wz, dist, pdf = _sample_area(light_f, light_i, light_cdf, prims, info, k,
                                             x, y, z, u0, u1, u2,
                                             shape_flip[info[light_i[k, LIGHT_PRIM], PRIM_SHAPE]])
        lr, lg, lb = _xyz(f, LIGHT_RADIANCE)
        return wx, wy, wz, dist, lr, lg, lb, pdf
    if kind == POINT or kind == SPOT:
        dx, dy, dz = f[LIGHT_POSITION] - x, f[LIGHT_POSITION + 1] - y, f[LIGHT_POSITION + 2] - z
        d2 = dx * dx + dy * dy + dz * dz
        dist = math.sqrt(d2)
        wx, wy, wz = dx / dist, dy / dist, dz / dist
        s = 1.0 / d2
        if kind == SPOT:
            # direction from the light to the point, in the light's frame
            cz = -(f[SPOT_AXIS] * wx + f[SPOT_AXIS + 1] * wy + f[SPOT_AXIS + 2] * wz)
            if cz <= f[SPOT_COS_CUTOFF]:
                s = 0.0
            elif cz < f[SPOT_COS_BEAM]:
                s *= (f[SPOT_CUTOFF] - fast_acos(min(cz, 1.0))) * f[SPOT_INV_FALLOFF]
        lr, lg, lb = _xyz(f, LIGHT_RADIANCE)
        return wx, wy, wz, dist, lr * s, lg * s, lb * s, 1.0
    if kind == DIRECTIONAL:
        dx, dy, dz = _xyz(f, LIGHT_DIRECTION)
        lr, lg, lb = _xyz(f, LIGHT_RADIANCE)
        return -dx, -dy, -dz, np.inf, lr, lg, lb, 1.0
    if kind == CONSTANT:
        w = sample_uniform_sphere_kernel((u1, u2), (0.0,))
        lr, lg, lb = _xyz(f, LIGHT_RADIANCE)
        return w[0], w[1], w[2], np.inf, lr, lg, lb, _INV_FOUR_PI
    # ENVMAP
    u, v, pdf_uv = sample_pc2d_kernel(env_marg, env_cond, u1, u2)
    lx, ly, lz = envmap_direction(u, v)
    s = math.sqrt(lx * lx + lz * lz)     # sin θ, as _env_uv takes it
    if s == 0.0 or pdf_uv == 0.0:
        return 0.0, 0.0, 1.0, np.inf, 0.0, 0.0, 0.0, 0.0
    # world = R^T local (ENV_TO_LOCAL: the world-to-local rotation, row major)
    wx = f[ENV_TO_LOCAL + 0] * lx + f[ENV_TO_LOCAL + 3] * ly + f[ENV_TO_LOCAL + 6] * lz
    wy = f[ENV_TO_LOCAL + 1] * lx + f[ENV_TO_LOCAL + 4] * ly + f[ENV_TO_LOCAL + 7] * lz
    wz = f[ENV_TO_LOCAL + 2] * lx + f[ENV_TO_LOCAL + 5] * ly + f[ENV_TO_LOCAL + 8] * lz
    r, g, b = _env_radiance(light_f, light_i, tex_data, tex_info, k, u, v)
    return wx, wy, wz, np.inf, r, g, b, _uv_to_solid_angle(pdf_uv, s)
