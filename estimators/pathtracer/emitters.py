"""Emitters as numba kernels: area lights on shapes, point, spot, directional, constant
and envmap, with Mitsuba's radiometric conventions (area lights emit on the front side of
the shape's normal; a spot's falloff is 1 inside ``beam_width`` and falls linearly in
angle to 0 at ``cutoff_angle``; a point's ``intensity`` is radiant intensity; a
directional's ``irradiance`` is measured perpendicular to its direction).

Each emitter is a row of ``light_f`` (float64, ``LIGHT_WIDTH``) and ``light_i`` (int64:
type, first primitive, cdf offset, primitive count). Light sampling picks an emitter
uniformly (as Mitsuba does), then a point on it: triangles by area (the estimators'
discrete distribution and triangle warp), disks uniformly, spheres by the cone they
subtend (the estimators' cone warp), envmaps by the estimators' piecewise-constant 2-D
distribution over (u, v).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..distributions import _pc2d_pdf_kernel, _sample_discrete_kernel, _sample_pc2d_kernel
from ..warps import (_sample_uniform_cone_kernel, _sample_uniform_disk_concentric_kernel,
                     _sample_uniform_sphere_kernel, _sample_uniform_triangle_kernel)
from .geometry import SPHERE, TRIANGLE, coordinate_system, to_world, triangle_point
from .textures import envmap_direction, envmap_uv, eval_envmap

AREA, POINT, SPOT, DIRECTIONAL, CONSTANT, ENVMAP = range(6)
NAMES = ("area", "point", "spot", "directional", "constant", "envmap")
LIGHT_WIDTH = 24
_jit = njit(cache=True)
# Per-ray functions skip reference counting (_nrt=False): they allocate nothing, and the
# atomic count updates on shared arrays cost more than the work when all threads call.
_fast = njit(cache=True, _nrt=False)
_INV_FOUR_PI = 1.0 / (4.0 * math.pi)


@_jit
def is_delta(kind):
    return kind == POINT or kind == SPOT or kind == DIRECTIONAL


@_fast
def _sphere_cone(prims, j, x, y, z):
    """(cos θ_max, distance to centre) of the cone a sphere subtends from outside, or
    (-2, d) when the point is inside."""
    p = prims[j]
    dx, dy, dz = p[0] - x, p[1] - y, p[2] - z
    d2 = dx * dx + dy * dy + dz * dz
    r2 = p[3] * p[3]
    if d2 <= r2 * (1.0 + 1e-9):
        return -2.0, math.sqrt(d2)
    sin2 = r2 / d2
    return math.sqrt(max(0.0, 1.0 - sin2)), math.sqrt(d2)


@_fast
def _sample_area(light_f, light_i, light_cdf, prims, info, k, x, y, z, u0, u1, u2,
                 flip):
    """A point on area light k as (wx, wy, wz, dist, pdf in solid angle)."""
    first, off, count = light_i[k, 1], light_i[k, 2], light_i[k, 3]
    kind = info[first, 0]
    if kind == SPHERE:
        cos_max, dc = _sphere_cone(prims, first, x, y, z)
        p = prims[first]
        if cos_max > -2.0:
            cx, cy, cz = (p[0] - x) / dc, (p[1] - y) / dc, (p[2] - z) / dc
            s, t = coordinate_system(cx, cy, cz)
            lw = _sample_uniform_cone_kernel((u1, u2), (cos_max,))
            wx, wy, wz = to_world(s, t, (cx, cy, cz), lw[0], lw[1], lw[2])
            # near intersection with the sphere along w
            b = dc * lw[2]
            disc = p[3] * p[3] - dc * dc * (1.0 - lw[2] * lw[2])
            dist = b - math.sqrt(max(disc, 0.0))
            # outward normal at the hit; emission needs it to face the point
            nx = (x + dist * wx - p[0]) / p[3]
            ny = (y + dist * wy - p[1]) / p[3]
            nz = (z + dist * wz - p[2]) / p[3]
            cos_y = -(nx * wx + ny * wy + nz * wz)
            if flip:
                cos_y = -cos_y
            if cos_y <= 0.0:
                return 0.0, 0.0, 1.0, 0.0, 0.0
            one_minus = (1.0 - cos_max * cos_max) / (1.0 + cos_max)
            return wx, wy, wz, dist, 1.0 / (2.0 * math.pi * one_minus)
        # inside the sphere: uniform over its area
        sw = _sample_uniform_sphere_kernel((u1, u2), (0.0,))
        px, py, pz = p[0] + p[3] * sw[0], p[1] + p[3] * sw[1], p[2] + p[3] * sw[2]
        nx, ny, nz = sw[0], sw[1], sw[2]
        area = 4.0 * math.pi * p[3] * p[3]
    elif kind == TRIANGLE:
        i, _, _ = _sample_discrete_kernel(light_cdf[off:off + count + 1], u0)
        p = prims[first + i]
        bary = _sample_uniform_triangle_kernel((u1, u2), (0.0,))
        px, py, pz, nx, ny, nz = triangle_point(p, bary[0], bary[1])
        area = light_f[k, 3]
    else:  # disk
        p = prims[first]
        dpt = _sample_uniform_disk_concentric_kernel((u1, u2), (0.0,))
        px = p[0] * dpt[0] + p[1] * dpt[1] + p[3]
        py = p[4] * dpt[0] + p[5] * dpt[1] + p[7]
        pz = p[8] * dpt[0] + p[9] * dpt[1] + p[11]
        nx, ny, nz = p[20], p[21], p[22]
        ln = math.sqrt(nx * nx + ny * ny + nz * nz)
        nx, ny, nz = nx / ln, ny / ln, nz / ln
        area = light_f[k, 3]
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
    first = light_i[k, 1]
    if info[first, 0] == SPHERE:
        cos_max, _ = _sphere_cone(prims, first, x, y, z)
        if cos_max > -2.0:
            one_minus = (1.0 - cos_max * cos_max) / (1.0 + cos_max)
            return 1.0 / (2.0 * math.pi * one_minus)
        area = 4.0 * math.pi * prims[first, 3] ** 2
    else:
        area = light_f[k, 3]
    return dist * dist / (abs(cos_y) * area)


@_fast
def eval_environment(light_f, light_i, tex_data, tex_info, k, dx, dy, dz):
    """Radiance of environment k seen along the escaping ray direction d."""
    if light_i[k, 0] == CONSTANT:
        return light_f[k, 0], light_f[k, 1], light_f[k, 2]
    f = light_f[k]
    lx = f[1] * dx + f[2] * dy + f[3] * dz
    ly = f[4] * dx + f[5] * dy + f[6] * dz
    lz = f[7] * dx + f[8] * dy + f[9] * dz
    u, v = envmap_uv(lx, ly, lz)
    r, g, b = eval_envmap(tex_data, tex_info, light_i[k, 1], u, v)
    return r * f[0], g * f[0], b * f[0]


@_fast
def environment_pdf(light_f, light_i, env_marg, env_cond, k, dx, dy, dz):
    if light_i[k, 0] == CONSTANT:
        return _INV_FOUR_PI
    f = light_f[k]
    lx = f[1] * dx + f[2] * dy + f[3] * dz
    ly = f[4] * dx + f[5] * dy + f[6] * dz
    lz = f[7] * dx + f[8] * dy + f[9] * dz
    u, v = envmap_uv(lx, ly, lz)
    s = math.sqrt(max(0.0, 1.0 - ly * ly))
    if s == 0.0:
        return 0.0
    return _pc2d_pdf_kernel(env_marg, env_cond, u, v) / (2.0 * math.pi * math.pi * s)


@_fast
def sample_emitter(light_f, light_i, light_cdf, prims, info, shape_flip, tex_data, tex_info,
                   env_marg, env_cond, k, x, y, z, u0, u1, u2):
    """Sample light k from (x, y, z): (wx, wy, wz, dist, Le r, g, b, pdf) with Le the
    incident radiance (or intensity / dist², or irradiance, for delta lights) and pdf the
    solid-angle density (1 for delta lights). dist is inf for lights at infinity."""
    kind = light_i[k, 0]
    f = light_f[k]
    if kind == AREA:
        wx, wy, wz, dist, pdf = _sample_area(light_f, light_i, light_cdf, prims, info, k,
                                             x, y, z, u0, u1, u2,
                                             shape_flip[info[light_i[k, 1], 1]])
        return wx, wy, wz, dist, f[0], f[1], f[2], pdf
    if kind == POINT or kind == SPOT:
        dx, dy, dz = f[3] - x, f[4] - y, f[5] - z
        d2 = dx * dx + dy * dy + dz * dz
        dist = math.sqrt(d2)
        wx, wy, wz = dx / dist, dy / dist, dz / dist
        s = 1.0 / d2
        if kind == SPOT:
            # direction from the light to the point, in the light's frame
            cz = -(f[12] * wx + f[13] * wy + f[14] * wz)
            if cz <= f[15]:
                s = 0.0
            elif cz < f[16]:
                s *= (f[17] - math.acos(min(cz, 1.0))) * f[18]
        return wx, wy, wz, dist, f[0] * s, f[1] * s, f[2] * s, 1.0
    if kind == DIRECTIONAL:
        return -f[3], -f[4], -f[5], np.inf, f[0], f[1], f[2], 1.0
    if kind == CONSTANT:
        w = _sample_uniform_sphere_kernel((u1, u2), (0.0,))
        return w[0], w[1], w[2], np.inf, f[0], f[1], f[2], _INV_FOUR_PI
    # ENVMAP
    u, v, pdf_uv = _sample_pc2d_kernel(env_marg, env_cond, u1, u2)
    lx, ly, lz = envmap_direction(u, v)
    s = math.sqrt(max(0.0, 1.0 - ly * ly))
    if s == 0.0 or pdf_uv == 0.0:
        return 0.0, 0.0, 1.0, np.inf, 0.0, 0.0, 0.0, 0.0
    # world = R^T local (f[1:10] is the world-to-local rotation, row major)
    wx = f[1] * lx + f[4] * ly + f[7] * lz
    wy = f[2] * lx + f[5] * ly + f[8] * lz
    wz = f[3] * lx + f[6] * ly + f[9] * lz
    r, g, b = eval_envmap(tex_data, tex_info, light_i[k, 1], u, v)
    return (wx, wy, wz, np.inf, r * f[0], g * f[0], b * f[0],
            pdf_uv / (2.0 * math.pi * math.pi * s))
