"""The tracer's own BSDF and emitter sampling as array functions, for a judge to check.

Each front end wraps the scalar kernels the path tracer calls (``bsdfs.bsdf_sample`` /
``bsdf_eval``, ``emitters.sample_emitter`` / ``area_pdf`` / ``environment_pdf``) in a
numba ``prange`` loop over rows: no second implementation.

- :func:`bsdf_sampler` (BSDF row ``b`` of a prepared scene, incident ``wi`` in the local
  shading frame, normal +z): ``sample(u (n, 3)) -> wo (n, 3)``, the first number choosing
  the lobe as the kernel does; a row of NaN where the kernel's draw has zero pdf (its
  "end the path" answer: below the horizon, outside the support) or went to a delta lobe
  (no density: its probability is the mass the continuous part lacks).
  ``pdf(wo (n, 3)) -> (n,)``: the density of the non-delta part per unit solid angle,
  as the kernel's MIS weights read it.
- :func:`emitter_sampler` (light row ``k``, reference point ``ref`` in world space):
  ``sample(u (n, 3)) -> direction (n, 3)`` (NaN where the kernel's pdf is zero: the
  light's back side), ``pdf(direction)`` in solid angle without the choice of light: for
  an area light, the ray ``ref + t·d`` is intersected with the light's own primitives
  (nothing else occludes) and ``area_pdf`` is evaluated at the hit, as the kernel does
  when a BSDF-sampled ray hits the light. Delta lights have no density and are refused.

Textured BSDFs are evaluated at texture coordinates (0.5, 0.5) (textures change weights,
never directions).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .bsdfs import bsdf_eval, bsdf_is_smooth, bsdf_sample
from .emitters import area_pdf, environment_pdf, is_delta, sample_emitter
from .geometry import _hit_prim, surface
from .layout import (AREA, LEAF_KIND, LEAF_PRIM, LIGHT_KIND, LIGHT_PRIM, LIGHT_PRIM_COUNT,
                     PRIM_KIND, PRIM_SHAPE, TRIANGLE)

__all__ = ["bsdf_sampler", "emitter_sampler", "bsdf_has_density", "emitter_has_density"]

_UV = 0.5


@njit(parallel=True, cache=True)
def _bsdf_sample_rows(mask, bf, bi, btex, tex_data, tex_info, b, wx, wy, wz, u, out):
    wi = (wx, wy, wz)
    for i in prange(u.shape[0]):
        r = bsdf_sample(mask, bf, bi, btex, tex_data, tex_info, b, wi, u[i, 0], u[i, 1],
                        u[i, 2], _UV, _UV, 1.0)
        if r[6] > 0.0 and not r[7]:
            out[i, 0], out[i, 1], out[i, 2] = r[0], r[1], r[2]
        else:
            out[i, 0], out[i, 1], out[i, 2] = np.nan, np.nan, np.nan


@njit(parallel=True, cache=True)
def _bsdf_pdf_rows(mask, bf, bi, btex, tex_data, tex_info, b, wx, wy, wz, wo, out):
    wi = (wx, wy, wz)
    for i in prange(wo.shape[0]):
        out[i] = bsdf_eval(mask, bf, bi, btex, tex_data, tex_info, b, wi,
                           (wo[i, 0], wo[i, 1], wo[i, 2]), _UV, _UV)[3]


@njit(parallel=True, cache=True)
def _emitter_sample_rows(light_f, light_i, light_cdf, prims, info, shape_flip, tex_data,
                         tex_info, env_marg, env_cond, k, x, y, z, u, out):
    for i in prange(u.shape[0]):
        r = sample_emitter(light_f, light_i, light_cdf, prims, info, shape_flip, tex_data,
                           tex_info, env_marg, env_cond, k, x, y, z, u[i, 0], u[i, 1], u[i, 2])
        if r[7] > 0.0:
            out[i, 0], out[i, 1], out[i, 2] = r[0], r[1], r[2]
        else:
            out[i, 0], out[i, 1], out[i, 2] = np.nan, np.nan, np.nan


@njit(parallel=True, cache=True)
def _emitter_pdf_rows(light_f, light_i, prims, info, shape_flip, leaf, leaf_info, rows,
                      env_marg, env_cond, k, x, y, z, d, out):
    area = light_i[k, LIGHT_KIND] == AREA
    for i in prange(d.shape[0]):
        dx, dy, dz = d[i, 0], d[i, 1], d[i, 2]
        if not area:
            out[i] = environment_pdf(light_f, light_i, env_marg, env_cond, k, dx, dy, dz)
            continue
        best, hit, b1, b2 = np.inf, -1, 0.0, 0.0
        for r in rows:
            t, c1, c2 = _hit_prim(leaf[r], leaf_info[r, LEAF_KIND], x, y, z, dx, dy, dz)
            if t < best:
                best, hit, b1, b2 = t, r, c1, c2
        if hit < 0:
            out[i] = 0.0
            continue
        j = leaf_info[hit, LEAF_PRIM]
        s = surface(prims, info, j, x, y, z, dx, dy, dz, best, b1, b2)
        cos_y = -(s[6] * dx + s[7] * dy + s[8] * dz)
        if shape_flip[info[j, PRIM_SHAPE]]:
            cos_y = -cos_y
        out[i] = area_pdf(light_f, light_i, prims, info, k, x, y, z, best, cos_y) \
            if cos_y > 0.0 else 0.0


def _rows(name: str, x) -> np.ndarray:
    a = np.ascontiguousarray(np.asarray(x, dtype=np.float64))
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"{name}: expected an array of shape (n, 3), got {a.shape}")
    return a


def _vector(name: str, v) -> tuple[float, float, float]:
    a = np.asarray(v, dtype=np.float64)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name}={v!r}: expected 3 finite numbers")
    return float(a[0]), float(a[1]), float(a[2])


def _index(name: str, i, count: int) -> int:
    if not isinstance(i, (int, np.integer)) or isinstance(i, bool) or not 0 <= i < count:
        raise ValueError(f"{name}={i!r}: expected an index in [0, {count})")
    return int(i)


def bsdf_has_density(scene, b: int) -> bool:
    """Whether BSDF row ``b`` has a non-delta component (something to check)."""
    return bool(bsdf_is_smooth(scene.arrays.bsdf_i, _index("b", b, len(scene.arrays.bsdf_i))))


def emitter_has_density(scene, k: int) -> bool:
    """Whether light row ``k`` has a density (not a point, spot or directional light)."""
    li = scene.arrays.light_i
    return not is_delta(int(li[_index("k", k, len(li)), LIGHT_KIND]))


def bsdf_sampler(scene, b: int, wi):
    """``(sample, pdf)`` of BSDF row ``b`` of the prepared ``scene`` at incident ``wi``
    (a unit vector in the local frame; see the module docstring)."""
    a = scene.arrays
    b = _index("b", b, len(a.bsdf_i))
    w = _vector("wi", wi)
    if abs(math.sqrt(sum(c * c for c in w)) - 1.0) > 1e-9:
        raise ValueError(f"wi={wi!r}: expected a unit vector")
    mask = int(scene.features)
    tables = (mask, a.bsdf_f, a.bsdf_i, a.bsdf_tex, a.tex_data, a.tex_info, b) + w

    def sample(u):
        u = _rows("u", u)
        out = np.empty_like(u)
        _bsdf_sample_rows(*tables, u, out)
        return out

    def pdf(wo):
        wo = _rows("wo", wo)
        out = np.empty(wo.shape[0])
        _bsdf_pdf_rows(*tables, wo, out)
        return out

    return sample, pdf


def _light_leaf_rows(a, k: int) -> np.ndarray:
    """Rows of ``leaf_prims`` holding the primitives of area light ``k``."""
    first = int(a.light_i[k, LIGHT_PRIM])
    mesh = a.prim_info[first, PRIM_KIND] == TRIANGLE
    count = int(a.light_i[k, LIGHT_PRIM_COUNT]) if mesh else 1
    prim = a.leaf_info[:, LEAF_PRIM]
    return np.flatnonzero((prim >= first) & (prim < first + count)).astype(np.int64)


def emitter_sampler(scene, k: int, ref):
    """``(sample, pdf)`` of light row ``k`` of the prepared ``scene`` seen from the world
    point ``ref`` (see the module docstring). Delta lights raise ``ValueError``."""
    a = scene.arrays
    k = _index("k", k, len(a.light_i))
    x, y, z = _vector("ref", ref)
    if not emitter_has_density(scene, k):
        raise ValueError(f"k={k}: a delta light (point, spot, directional) has no density")
    rows = _light_leaf_rows(a, k) if a.light_i[k, LIGHT_KIND] == AREA else np.zeros(0, np.int64)

    def sample(u):
        u = _rows("u", u)
        out = np.empty_like(u)
        _emitter_sample_rows(a.light_f, a.light_i, a.light_cdf, a.prims, a.prim_info,
                             a.shape_flip, a.tex_data, a.tex_info, a.env_marginal,
                             a.env_conditional, k, x, y, z, u, out)
        return out

    def pdf(d):
        d = _rows("direction", d)
        out = np.empty(d.shape[0])
        _emitter_pdf_rows(a.light_f, a.light_i, a.prims, a.prim_info, a.shape_flip,
                          a.leaf_prims, a.leaf_info, rows, a.env_marginal,
                          a.env_conditional, k, x, y, z, d, out)
        return out

    return sample, pdf
