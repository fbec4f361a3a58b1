"""The tracer's own BSDF and emitter sampling as array functions, for a judge to check.

Each front end wraps the scalar kernels the path tracer calls (``bsdfs.bsdf_sample`` /
``bsdf_eval``, ``emitters.sample_emitter`` / ``area_pdf`` / ``environment_pdf``) in a
loop over rows (``_sampling_loops``), run on numba's threads: no second implementation.

- :func:`bsdf_sampler` (BSDF row ``b`` of a prepared scene, incident ``wi`` in the local
  shading frame, normal +z): ``sample(u (n, 3)) -> wo (n, 3)``, the first number choosing
  the lobe as the kernel does; a row of NaN where the kernel's draw has zero pdf (its
  "end the path" answer: below the horizon, outside the support) or went to a delta lobe
  (no density: its probability is the mass the continuous part lacks).
  ``pdf(wo (n, 3)) -> (n,)``: the density of the non-delta part per unit solid angle,
  as the kernel's MIS weights read it. :func:`bsdf_sampler_with_weight` adds what the
  kernel's draw returns with each direction (its pdf and weight) and ``bsdf_eval``'s
  value, for ``mcverify.check_pdf_consistency``.
- :func:`emitter_sampler` (light row ``k``, reference point ``ref`` in world space):
  ``sample(u (n, 3)) -> direction (n, 3)`` (NaN where the kernel's pdf is zero: the
  light's back side), ``pdf(direction)`` in solid angle without the choice of light: for
  an area light, the ray ``ref + t·d`` is intersected with the light's own primitives
  (nothing else occludes) and ``area_pdf`` is evaluated at each front-facing hit, as the
  kernel does when a BSDF-sampled ray hits the light, and summed: the sampler draws
  points by area without a visibility test, so where one part of a light hides another
  (a folded mesh) both add to the direction's density (the kernel's MIS takes the
  nearest hit, where the hidden draws are shadowed and add nothing). Delta lights have
  no density and are refused. :func:`emitter_sampler_with_weight` adds what the
  kernel's draw returns (its pdf and radiance) and what a BSDF-sampled ray meeting the
  light reads (the density and radiance at its nearest point), for
  ``mcverify.check_pdf_consistency``.

A row of u with a coordinate outside [0, 1] (or NaN) draws a NaN row, as in the warps'
front ends (until 6 December u = 1.5 gave a direction, the kernels reading any number);
a direction with a NaN coordinate has a NaN density and value, as a warp's pdf gives
(until 6 December a diffuse BSDF's pdf of (NaN, 0, 1) was 1/π and an area light's 0).

``scene``: a ``PreparedScene``, or what ``prepare_scene`` takes (a path, a
``SceneDescription``), as ``render`` does (a path raised AttributeError until 6 December).

Textured BSDFs are evaluated at texture coordinates (0.5, 0.5) (textures change weights,
never directions).
"""

from __future__ import annotations

import functools
import hashlib
import math
import os

import numpy as np

from mcnumba.threads import run_ranges

from .._generated import first_call
from .bsdfs import bsdf_is_smooth
from .emitters import is_delta
from .layout import (AREA, ENVMAP, LEAF_PRIM, LIGHT_KIND, LIGHT_PRIM, LIGHT_PRIM_COUNT,
                     PRIM_KIND, TRIANGLE)
from .prepare import prepare_scene
from .render import _dependency_digest, load_cached

__all__ = ["bsdf_sampler", "bsdf_sampler_with_weight", "emitter_sampler",
           "emitter_sampler_with_weight", "bsdf_has_density", "emitter_has_density"]


@functools.lru_cache(maxsize=1)
def _loops():
    """The compiled loops (see ``_sampling_loops``)."""
    template = os.path.join(os.path.dirname(__file__), "_sampling_loops.py")
    with open(template, encoding="utf-8") as f:
        source = f.read()
    key = hashlib.sha256((source + _dependency_digest(template)).encode()).hexdigest()[:16]
    return load_cached(f"mcverify_sampling_{key}", source)


#: the fewest rows worth a thread of their own (a BSDF sample costs 0.1-1 µs)
_GRAIN = 1024


def _run(name: str, *args) -> None:
    """Run the loop ``name`` over every row of its last argument, on numba's threads
    (``mcnumba.threads.run_ranges``); its first call in this process holds the kernel
    cache's lock (``_generated.first_call``): processes starting together compile it
    once."""
    fn = getattr(_loops(), name)
    key = f"{fn.py_func.__module__}.{name}"
    with first_call(key, key):
        run_ranges(fn, args[-1].shape[0], *args, grain=_GRAIN)


def _floats(name: str, v) -> np.ndarray:
    """``v`` as float64, or ValueError naming ``name`` (numpy's "could not convert string
    to float: 'abc'" named nothing). Only real numbers, as the warps' front ends take:
    until 7 December a complex u lost its imaginary part (numpy's ComplexWarning) and a
    None in a list of u became NaN, each drawn from without a word."""
    try:
        a = np.asarray(v)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name}={v!r}: not numbers ({e})") from None
    if a.dtype.kind not in "biuf":
        shown = f"{name}={v!r}" if a.size <= 3 else name    # one vector or row, not n
        raise ValueError(f"{shown}: not numbers (an array of {a.dtype}; expected real "
                         "numbers)")
    return a.astype(np.float64)


def _rows(name: str, x) -> np.ndarray:
    a = np.ascontiguousarray(_floats(name, x))
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"{name}: expected an array of shape (n, 3), got {a.shape}")
    return a


def _outside_unit(u: np.ndarray) -> np.ndarray:
    """Rows of ``u`` with a coordinate outside [0, 1] (or NaN): their draws are NaN rows,
    as the warps' front ends give for such a u (the kernels read any number)."""
    return ~np.all((u >= 0.0) & (u <= 1.0), axis=1)


def _vector(name: str, v) -> tuple[float, float, float]:
    a = _floats(name, v)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name}={v!r}: expected 3 finite numbers")
    return float(a[0]), float(a[1]), float(a[2])


def _unit_vector(name: str, v) -> tuple[float, float, float]:
    """A unit vector: its length within 1e-9 of 1, or, given in float32, within float32's
    rounding (4 ulps, 2.4e-7) of 1 and then normalised in float64 (a normalised float32
    direction is off by up to ~1e-7 and was refused)."""
    w = _vector(name, v)
    norm = math.sqrt(sum(c * c for c in w))
    single = getattr(v, "dtype", None) == np.float32 or (
        isinstance(v, (list, tuple)) and any(isinstance(c, np.float32) for c in v))
    tol = 2.0 ** -22 if single else 1e-9
    if abs(norm - 1.0) <= tol:
        return w if not single else (w[0] / norm, w[1] / norm, w[2] / norm)
    raise ValueError(f"{name}={v!r}: expected a unit vector, its length is {norm!r} "
                     f"(allowed: 1 ± {tol:.2g})")


def _index(name: str, i, count: int) -> int:
    if not isinstance(i, (int, np.integer)) or isinstance(i, bool) or not 0 <= i < count:
        raise ValueError(f"{name}={i!r}: expected an index in [0, {count})")
    return int(i)


def bsdf_has_density(scene, b: int) -> bool:
    """Whether BSDF row ``b`` has a non-delta component (something to check)."""
    scene = prepare_scene(scene)
    return bool(bsdf_is_smooth(scene.arrays.bsdf_i, _index("b", b, len(scene.arrays.bsdf_i))))


def emitter_has_density(scene, k: int) -> bool:
    """Whether light row ``k`` has a density (not a point, spot or directional light)."""
    scene = prepare_scene(scene)
    li = scene.arrays.light_i
    return not is_delta(int(li[_index("k", k, len(li)), LIGHT_KIND]))


def bsdf_sampler(scene, b: int, wi):
    """``(sample, pdf)`` of BSDF row ``b`` of the prepared ``scene`` at incident ``wi``
    (a unit vector in the local frame; see the module docstring)."""
    draw, evaluate = _bsdf_rows(scene, b, wi)
    return (lambda u: draw(u)[:, :3]), (lambda wo: evaluate(wo)[:, 3])


def bsdf_sampler_with_weight(scene, b: int, wi):
    """``(sample, pdf, f)`` of BSDF row ``b`` at incident ``wi``, for
    ``mcverify.check_pdf_consistency``: ``sample(u) -> (wo, pdf, weight)`` as the kernel's
    ``bsdf_sample`` returns them (weight: ``f · cos / pdf``, rgb; rows as
    :func:`bsdf_sampler`'s, NaN where it draws nothing), ``pdf(wo)`` and
    ``f(wo) -> (n, 3)`` (``f · cos``) as ``bsdf_eval`` returns them."""
    draw, evaluate = _bsdf_rows(scene, b, wi)

    def sample(u):
        out = draw(u)
        return out[:, :3], out[:, 6], out[:, 3:6]

    return sample, (lambda wo: evaluate(wo)[:, 3]), (lambda wo: evaluate(wo)[:, :3])


def _bsdf_rows(scene, b: int, wi):
    """(draw, evaluate): u (n, 3) -> (n, 7) rows of (wo, weight, pdf) from
    ``bsdf_sample``; wo (n, 3) -> (n, 4) rows of (f · cos, pdf) from ``bsdf_eval``."""
    scene = prepare_scene(scene)
    a = scene.arrays
    b = _index("b", b, len(a.bsdf_i))
    w = _unit_vector("wi", wi)
    mask = int(scene.features)
    tables = (mask, a.bsdf_f, a.bsdf_i, a.bsdf_tex, a.tex_data, a.tex_info, b) + w

    def draw(u):
        u = _rows("u", u)
        out = np.empty((u.shape[0], 7))
        _run("_bsdf_sample_rows", *tables, u, out)
        out[_outside_unit(u)] = np.nan
        return out

    def evaluate(wo):
        wo = _rows("wo", wo)
        out = np.empty((wo.shape[0], 4))
        _run("_bsdf_eval_rows", *tables, wo, out)
        out[np.isnan(wo).any(axis=1)] = np.nan
        return out

    return draw, evaluate


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
    draw, evaluate = _emitter_rows(scene, k, ref)
    return (lambda u: draw(u)[:, :3]), (lambda d: evaluate(d)[:, 0])


def emitter_sampler_with_weight(scene, k: int, ref):
    """``(sample, pdf, f)`` of light row ``k`` seen from ``ref``, for
    ``mcverify.check_pdf_consistency``: ``sample(u) -> (d, pdf, weight)`` as the kernel's
    ``sample_emitter`` returns them (weight: the radiance it returns over its pdf), and
    ``pdf(d)``, ``f(d)`` (radiance, rgb) at the light's nearest point along d, as the
    kernel reads them when a BSDF-sampled ray meets the light. A draw whose point is not
    the light's nearest along its direction (hidden by another part of the light, which
    the kernel's shadow ray would meet) is a NaN row: the two strategies then see
    different points, and no estimator combines them. For an environment map, ``f`` is
    None and ``sample`` returns (d, pdf): its radiance is not compared (see below)."""
    scene = prepare_scene(scene)
    draw, evaluate = _emitter_rows(scene, k, ref)

    def sample(u):
        out = draw(u)
        drawn = ~np.isnan(out[:, 0])
        near = np.full(len(out), np.nan)
        near[drawn] = evaluate(out[drawn, :3])[:, 1]
        dist = out[:, 3]
        with np.errstate(invalid="ignore"):
            hidden = ~((near == dist) | (np.abs(near - dist) <= 1e-9 * dist))
        out[hidden] = np.nan
        with np.errstate(divide="ignore", invalid="ignore"):
            return out[:, :3], out[:, 7], out[:, 4:7] / out[:, 7:8]

    if scene.arrays.light_i[k, LIGHT_KIND] == ENVMAP:
        # its radiance is looked up bilinearly at the (u, v) of the direction, which the
        # arc tangents give back within ~1e-10 of the drawn (u, v): beside a sharp texel
        # edge the two lookups differ by that much times the map's gradient (3.7e-5 on
        # lognormal(0, 2.5) noise at 2048 × 1024). Rounding, not a bug: the density
        # (piecewise constant) is compared alone
        return (lambda u: sample(u)[:2]), (lambda d: evaluate(d)[:, 2]), None
    return sample, (lambda d: evaluate(d)[:, 2]), (lambda d: evaluate(d)[:, 3:6])


def _emitter_rows(scene, k: int, ref):
    """(draw, evaluate): u (n, 3) -> (n, 8) rows of (direction, distance, Le, pdf) from
    ``sample_emitter``; d (n, 3) -> (n, 6) rows of ``_emitter_eval_rows`` (summed
    density, nearest distance, density and radiance there)."""
    scene = prepare_scene(scene)
    a = scene.arrays
    k = _index("k", k, len(a.light_i))
    x, y, z = _vector("ref", ref)
    if not emitter_has_density(scene, k):
        raise ValueError(f"k={k}: a delta light (point, spot, directional) has no density")
    rows = _light_leaf_rows(a, k) if a.light_i[k, LIGHT_KIND] == AREA else np.zeros(0, np.int64)

    def draw(u):
        u = _rows("u", u)
        out = np.empty((u.shape[0], 8))
        _run("_emitter_sample_rows", a.light_f, a.light_i, a.light_cdf, a.prims, a.prim_info,
             a.shape_flip, a.tex_data, a.tex_info, a.env_marginal, a.env_conditional, k, x,
             y, z, u, out)
        out[_outside_unit(u)] = np.nan
        return out

    def evaluate(d):
        d = _rows("direction", d)
        out = np.empty((d.shape[0], 6))
        _run("_emitter_eval_rows", a.light_f, a.light_i, a.prims, a.prim_info, a.shape_flip,
             a.leaf_prims, a.leaf_info, rows, a.tex_data, a.tex_info, a.env_marginal,
             a.env_conditional, k, x, y, z, d, out)
        out[np.isnan(d).any(axis=1)] = np.nan
        return out

    return draw, evaluate
