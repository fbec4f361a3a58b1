"""Warps: maps from the unit square (or interval) to domains, with pdf and inverse.

pbrt's triple for every warp: ``sample_X(u, *params)``, ``X_pdf(x, *params)``,
``invert_X(x, *params)``, ``u`` first. Each is a numpy front end over one numba scalar
kernel (``_sample_X_kernel`` etc.). The kernels that compiled code elsewhere calls
directly on tuples (the path tracer's BSDFs and emitters) are public, without the
underscore (``sample_cosine_hemisphere_kernel``, ``ggx_d``...): the one implementation
both the array front ends and the tracer use.

Numerical habits (pbrt-v4): the inverses return ``u`` clamped to ``[0, 1 - 2^-53]``,
and a sampler given u = 1 (a float32 u near 1 rounds to it) returns a point of its
domain, never NaN (tested for every warp); square roots take
``max(0, ·)``; densities are 0 outside the support; quantities that cancel near a pole
(``1 - cos θ``) are computed from the tangential components instead.

``WARPS`` lists every warp with its domain, parameter ranges and default parameters;
tests and ``mcverify check`` iterate over it.

References: M. Pharr, W. Jakob, G. Humphreys, *Physically Based Rendering*, 4th ed.,
§A.5 (sampling functions); P. Shirley, K. Chiu, "A low distortion map between disk and
square" (1997); E. Heitz, "Sampling the GGX distribution of visible normals", JCGT 7(4)
(2018); E. Heitz, "A low-distortion map between triangle and square" (2019).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from ._compile_options import exact
from ._fastmath import (fast_atan, fast_atan2, fast_exp, fast_expm1, fast_log, fast_log1p,
                        fast_sincos_2pi, sincos_reduced)
from ._vectorize import fused_front_end, point_front_end, value_front_end

ONE_MINUS_EPSILON = 1.0 - 2.0 ** -53
_PI = math.pi
_TWO_PI = 2.0 * math.pi
_INV_PI = 1.0 / math.pi
_INV_TWO_PI = 1.0 / (2.0 * math.pi)
_INV_FOUR_PI = 1.0 / (4.0 * math.pi)
_PI_OVER_4 = math.pi / 4.0
_PI_OVER_2 = math.pi / 2.0

#: IEEE division (x/0 is ±inf or NaN, as in numpy): numba's default ZeroDivisionError
#: check is a branch to an exception in every kernel that divides, and stops LLVM from
#: vectorising the front ends' loops over it. No fast-math flag, whoever calls the kernel
#: first (``_compile_options``: the path tracer's ``contract`` would otherwise reach it).
_jit = exact()
#: For helpers that call ``_fastmath``'s sin/cos or atan2 (an azimuth and its inverse):
#: LLVM's inliner would keep them as calls, and a call stops a caller's loop from
#: vectorising; numba inlines them into every caller.
_inline = exact(inline="always")


# ----------------------------------------------------------------------- helpers
_DISK_RIM = 1.0 + 8.0 * 2.0 ** -52
#: The least z of a visible normal: float32's least subnormal, 2^-149, which a float32
#: point keeps (``sample_ggx_vndf_kernel``).
_HORIZON_Z = 2.0 ** -149


@_jit
def _clamp_u(u):
    return min(max(u, 0.0), ONE_MINUS_EPSILON)


@_jit
def _safe_sqrt(v):
    """√v of v rounded below 0; NaN stays NaN (``max`` returns its first argument when
    the comparison fails: max(0.0, NaN) was 0, and GGX sampled a NaN u to a zero vector
    of density 0)."""
    return math.sqrt(max(v, 0.0))


@_inline
def _azimuth_u(x, y):
    """φ / 2π in [0, 1) of the direction (x, y)."""
    phi = fast_atan2(y, x)
    phi = phi + _TWO_PI if phi < 0.0 else phi
    return min(phi * _INV_TWO_PI, ONE_MINUS_EPSILON)


#: (sin 2πu, cos 2πu) without libm (``_fastmath.fast_sincos_2pi``, within 1 ulp).
_sincos_two_pi = fast_sincos_2pi


@_inline
def _direction(sin_theta, cos_theta, u1):
    """The unit vector at polar angle θ and azimuth φ = 2π·u1."""
    s, c = _sincos_two_pi(u1)
    return (sin_theta * c, sin_theta * s, cos_theta)


# ----------------------------------------------------------------- interval & square
@_jit
def _sample_uniform_interval_kernel(u, p):
    # at most b: a + (b - a)·1 rounds above b for 1 in 6 random (a, b) (a = -0.3,
    # b = 0.1: 0.10000000000000003, of density 0); NaN stays NaN (min returns it first)
    return (min(p[0] + (p[1] - p[0]) * u[0], p[1]),)


@_jit
def _uniform_interval_pdf_kernel(x, p):
    return 1.0 / (p[1] - p[0]) if p[0] <= x[0] <= p[1] else 0.0


@_jit
def _invert_uniform_interval_kernel(x, p):
    return (_clamp_u((x[0] - p[0]) / (p[1] - p[0])),)


@_jit
def _sample_uniform_square_kernel(u, p):
    return (u[0], u[1])


@_jit
def _uniform_square_pdf_kernel(x, p):
    return 1.0 if (0.0 <= x[0] <= 1.0 and 0.0 <= x[1] <= 1.0) else 0.0


# --------------------------------------------------------------------------- disk
@_jit
def _sample_uniform_disk_polar_kernel(u, p):
    r = math.sqrt(u[0])
    s, c = _sincos_two_pi(u[1])
    return (r * c, r * s)


@_jit
def _uniform_disk_pdf_kernel(x, p):
    # the rim with its rounding: the concentric map's points at r = 1 (u on the square's
    # edge, common in QMC) have x² + y² up to 2 ulps above 1
    return _INV_PI if x[0] * x[0] + x[1] * x[1] <= _DISK_RIM else 0.0


@_jit
def _invert_uniform_disk_polar_kernel(x, p):
    return (min(x[0] * x[0] + x[1] * x[1], ONE_MINUS_EPSILON), _azimuth_u(x[0], x[1]))


@_jit
def sample_uniform_disk_concentric_kernel(u, p):
    # Shirley–Chiu in pbrt's form: the wedge |a| > |b| maps to r·(cos φ, sin φ), the
    # other to r·(sin φ, cos φ) (= r·(cos, sin)(π/2 - φ)), with φ = (π/4)·q/r in
    # [-π/4, π/4] either way; (a, b) = (0, 0) gives r = 0, the centre.
    a = 2.0 * u[0] - 1.0
    b = 2.0 * u[1] - 1.0
    wide = abs(a) > abs(b)
    r = a if wide else b
    q = b if wide else a
    phi = _PI_OVER_4 * (q / r) if r != 0.0 else 0.0
    s, c = sincos_reduced(phi, 0.0)
    return (r * c, r * s) if wide else (r * s, r * c)


@_inline
def _invert_uniform_disk_concentric_kernel(x, p):
    # Derived from the forward map: in the wedge |x| >= |y| the point is a·(cos θ, sin θ)
    # with |θ| <= π/4, so a = sign(x)·ρ and θ = atan(y/x) = (π/4)(b/a); in the other
    # wedge the point is b·(cos θ, sin θ) with π/2 - θ = atan(x/y) = (π/4)(a/b). Both
    # computed, one selected (no branch); at the centre the divisor 0 is replaced by 1,
    # so θ = 0 and (a, b) = (±0, ±0) -> (½, ½).
    rho = math.sqrt(x[0] * x[0] + x[1] * x[1])
    wide = abs(x[0]) >= abs(x[1])
    num = x[1] if wide else x[0]
    den = x[0] if wide else x[1]
    t = fast_atan(num / (den if den != 0.0 else 1.0)) / _PI_OVER_4
    r = math.copysign(rho, den)
    a = r if wide else r * t
    b = r * t if wide else r
    return (_clamp_u(0.5 * (a + 1.0)), _clamp_u(0.5 * (b + 1.0)))


# ----------------------------------------------------------------------- triangle
@_jit
def sample_uniform_triangle_kernel(u, p):
    """Barycentrics (b0, b1) of the triangle (0,0), (1,0), (0,1): Heitz's
    low-distortion map, which keeps strata compact."""
    if u[0] < u[1]:
        b0 = 0.5 * u[0]
        b1 = u[1] - b0
    else:
        b1 = 0.5 * u[1]
        b0 = u[0] - b1
    return (b0, b1)


@_jit
def _uniform_triangle_pdf_kernel(x, p):
    return 2.0 if (x[0] >= 0.0 and x[1] >= 0.0 and x[0] + x[1] <= 1.0) else 0.0


@_jit
def _invert_uniform_triangle_kernel(x, p):
    if x[0] > x[1]:
        return (_clamp_u(x[0] + x[1]), _clamp_u(2.0 * x[1]))
    return (_clamp_u(2.0 * x[0]), _clamp_u(x[1] + x[0]))


# ------------------------------------------------------------ sphere & hemisphere
@_jit
def sample_uniform_sphere_kernel(u, p):
    # 1 - z² = 4 u0 (1 - u0): no cancellation at the poles
    return _direction(2.0 * _safe_sqrt(u[0] * (1.0 - u[0])), 1.0 - 2.0 * u[0], u[1])


@_jit
def _uniform_sphere_pdf_kernel(x, p):
    return _INV_FOUR_PI


@_inline
def _one_minus_z(x):
    """1 - z of a unit x: sin²θ / (1 + z) above the equator, where 1 - z itself cancels
    near the pole; 1 - z below it (the south pole's 0 / 0 would be NaN)."""
    return (x[0] * x[0] + x[1] * x[1]) / (1.0 + x[2]) if x[2] > 0.0 else 1.0 - x[2]


@_jit
def _invert_uniform_sphere_kernel(x, p):
    # u0 = (1 - z) / 2 from the tangential components: (1 - z) itself gave u0 = 0 for
    # u0 = 1e-20 and lost 8e-8 of u0 = 1e-10 (every float32 u0 below 3e-8, as z rounds
    # to 1), where the cone of cos θ_max = -1, the same sphere, kept them
    return (_clamp_u(0.5 * _one_minus_z(x)), _azimuth_u(x[0], x[1]))


@_jit
def _sample_uniform_hemisphere_kernel(u, p):
    z = u[0]
    return _direction(_safe_sqrt((1.0 - z) * (1.0 + z)), z, u[1])


@_jit
def _uniform_hemisphere_pdf_kernel(x, p):
    return _INV_TWO_PI if x[2] >= 0.0 else 0.0


@_jit
def _invert_uniform_hemisphere_kernel(x, p):
    return (_clamp_u(x[2]), _azimuth_u(x[0], x[1]))


@_jit
def sample_cosine_hemisphere_kernel(u, p):
    d = sample_uniform_disk_concentric_kernel(u, p)
    return (d[0], d[1], _safe_sqrt(1.0 - d[0] * d[0] - d[1] * d[1]))


@_jit
def cosine_hemisphere_pdf_kernel(x, p):
    return x[2] * _INV_PI if x[2] >= 0.0 else 0.0


@_jit
def _invert_cosine_hemisphere_kernel(x, p):
    return _invert_uniform_disk_concentric_kernel(x, p)


# ---------------------------------------------------------------------------- cone
@_jit
def sample_uniform_cone_kernel(u, p):
    """Uniform directions within θ_max of +z; ``p[0] = cos θ_max``."""
    one_minus_cos = u[0] * (1.0 - p[0])
    # at least cos θ_max: at u0 = 1, 1 - (1 - c) rounds below c for 1 in 10 random c
    # (c = -0.3: -0.30000000000000004, of density 0); NaN stays NaN (max returns it first)
    cos_t = max(1.0 - one_minus_cos, p[0])
    sin_t = _safe_sqrt(one_minus_cos * (2.0 - one_minus_cos))
    return _direction(sin_t, cos_t, u[1])


@_jit
def _uniform_cone_pdf_kernel(x, p):
    return 1.0 / (_TWO_PI * (1.0 - p[0])) if x[2] >= p[0] else 0.0


@_jit
def _invert_uniform_cone_kernel(x, p):
    # 1 - cos θ = sin²θ / (1 + cos θ): no cancellation near the pole; 1 - cos θ itself
    # below the equator (the south pole's 0 / 0 was a NaN where cos θ_max = -1)
    return (_clamp_u(_one_minus_z(x) / (1.0 - p[0])), _azimuth_u(x[0], x[1]))


# --------------------------------------------------------------- power-cosine lobe
@_jit
def _sample_power_cosine_kernel(u, p):
    """Phong lobe around +z: pdf (n + 1)/(2π) cos^n θ; ``p[0] = n >= 0``. cos θ =
    (1 - u)^(1/(n+1)) = e^y with y = log1p(-u)/(n+1), and 1 - cos θ = -expm1(y): at a
    large n the lobe is narrow, and 1 - cos θ taken from a rounded cos θ would keep only
    the last bits of cos θ (n = 1e8: round trip off by 5.5e-9; n = 1e12: 5.5e-5).
    u[0] = 1 is taken as 1 - 2^-53, as Beckmann's: it gave the horizon, of density 0."""
    y = fast_log1p(-min(u[0], ONE_MINUS_EPSILON)) / (p[0] + 1.0)
    one_minus_cos = -fast_expm1(y)
    cos_t = fast_exp(y)
    return _direction(_safe_sqrt(one_minus_cos * (1.0 + cos_t)), cos_t, u[1])


@_inline
def _log_cos(x):
    """ln cos θ of a unit x: from 1 - cos θ = (x² + y²)/(1 + z) near the pole, where z
    alone has lost its last digits, and from z itself below z = 1/2 (the sum there
    cancels instead); -inf at or below the horizon, NaN for NaN."""
    z = max(x[2], 0.0)
    near = fast_log1p(-(x[0] * x[0] + x[1] * x[1]) / (1.0 + z))
    return near if z > 0.5 else fast_log(z)


@_jit
def _power_cosine_pdf_kernel(x, p):
    # cos^n θ = e^(n ln cos θ), and cos^0 θ = 1 even at the horizon (0 · -inf would be NaN)
    t = p[0] * _log_cos(x) if p[0] > 0.0 else 0.0 * x[2]
    pdf = (p[0] + 1.0) * _INV_TWO_PI * fast_exp(t)
    return 0.0 if x[2] < 0.0 else pdf


@_jit
def _invert_power_cosine_kernel(x, p):
    # u = 1 - cos^(n+1) θ = -expm1((n + 1) ln cos θ): no cancellation near the pole
    return (_clamp_u(-fast_expm1((p[0] + 1.0) * _log_cos(x))), _azimuth_u(x[0], x[1]))


# ------------------------------------------------------------- microfacet normals
@_jit
def ggx_d(x, alpha):
    """GGX / Trowbridge–Reitz D(h) for a unit h; the denominator uses x² + y² instead
    of 1 - z² so that it keeps its precision for tiny α."""
    if x[2] <= 0.0:
        return 0.0
    a2 = alpha * alpha
    t = x[0] * x[0] + x[1] * x[1] + a2 * x[2] * x[2]
    return a2 / (_PI * t * t)


@_jit
def _sample_ggx_kernel(u, p):
    """Normals h distributed as D(h) cos θ_h for GGX of roughness ``p[0] = α``. u[0] = 1
    is taken as 1 - 2^-53, as Beckmann's: it gave the horizon, of density D cos θ = 0."""
    a2 = p[0] * p[0]
    v = min(u[0], ONE_MINUS_EPSILON)     # NaN stays NaN (min returns its first argument)
    den = 1.0 - v + a2 * v
    cos2 = (1.0 - v) / den
    sin2 = a2 * v / den
    return _direction(_safe_sqrt(sin2), _safe_sqrt(cos2), u[1])


@_jit
def _ggx_pdf_kernel(x, p):
    return ggx_d(x, p[0]) * max(x[2], 0.0)


@_jit
def _invert_ggx_kernel(x, p):
    s2 = x[0] * x[0] + x[1] * x[1]
    return (_clamp_u(s2 / (s2 + p[0] * p[0] * x[2] * x[2])), _azimuth_u(x[0], x[1]))


@_jit
def sample_beckmann_kernel(u, p):
    """Normals h distributed as D(h) cos θ_h for Beckmann of roughness ``p[0] = α``.
    u[0] = 1 (a float32 u rounds to it once in 2^25 draws) is taken as 1 - 2^-53: its
    log1p(-1) = -inf made the point NaN (an outside review)."""
    tan2 = -p[0] * p[0] * fast_log1p(-min(u[0], ONE_MINUS_EPSILON))
    cos_t = 1.0 / math.sqrt(1.0 + tan2)
    return _direction(_safe_sqrt(tan2) * cos_t, cos_t, u[1])


@_jit
def beckmann_pdf_kernel(x, p):
    # Computed everywhere, then selected: a branch around the exponential stays a
    # branch (too costly for LLVM to speculate) and stops a loop over points vectorising.
    a2 = p[0] * p[0]
    c2 = x[2] * x[2]
    tan2 = (x[0] * x[0] + x[1] * x[1]) / c2
    d = fast_exp(-tan2 / a2) / (_PI * a2 * c2 * x[2])
    return 0.0 if x[2] <= 0.0 else d


@_jit
def _invert_beckmann_kernel(x, p):
    tan2 = (x[0] * x[0] + x[1] * x[1]) / (x[2] * x[2])
    return (_clamp_u(-fast_expm1(-tan2 / (p[0] * p[0]))), _azimuth_u(x[0], x[1]))


@_jit
def _ggx_g1_over_cos(w, alpha):
    """G1(w) / w_z = 1 / (w_z (1 + Λ(w))) = 2 / (w_z + √(w_z² + α² (w_x² + w_y²))) for
    w_z > 0: Λ itself takes tan²θ = (w_x² + w_y²) / w_z², which overflowed below w_z ≈
    1e-154 (grazing), so G1 was 0 and every density 0 beside samples of a finite one."""
    s2 = w[0] * w[0] + w[1] * w[1]
    return 2.0 / (w[2] + math.sqrt(w[2] * w[2] + alpha * alpha * s2))


@_jit
def sample_ggx_vndf_kernel(u, p):
    """Visible normals of GGX (Heitz 2018) for the outgoing direction
    ``w = (p[1], p[2], p[3])`` (unit, z > 0) and roughness ``p[0] = α``. u[0] = 1 is
    taken as 1 - 2^-53, as Beckmann's: r = 1 put h on the visible hemisphere's edge,
    where w · h = 0, of density 0 (the front end takes a float32 u0 = 1 as 1 - 2^-24)."""
    alpha = p[0]
    vx, vy, vz = alpha * p[1], alpha * p[2], p[3]
    inv = 1.0 / math.sqrt(vx * vx + vy * vy + vz * vz)
    vx, vy, vz = vx * inv, vy * inv, vz * inv
    lensq = vx * vx + vy * vy
    if lensq > 0.0:
        il = 1.0 / math.sqrt(lensq)
        t1x, t1y, t1z = -vy * il, vx * il, 0.0
    else:
        t1x, t1y, t1z = 1.0, 0.0, 0.0
    t2x, t2y, t2z = vy * t1z - vz * t1y, vz * t1x - vx * t1z, vx * t1y - vy * t1x
    v = min(u[0], ONE_MINUS_EPSILON)
    r = math.sqrt(v)
    sin_phi, cos_phi = _sincos_two_pi(u[1])
    a = r * cos_phi
    b0 = r * sin_phi
    s = 0.5 * (1.0 + vz)
    # c = √(1 - a² - b²) without cancelling at the disk's rim, where 1 - a² - b² of the
    # rounded a, b came out 0 for 0.5-20 % of u1 once u0 was within 2^-51 of 1 (u0 = 1
    # included): h had w · h = 0 or lay on the horizon, of density 0. With e = 1 - r² =
    # 1 - u0 (exact there) and t = √(1 - a²) = √(sin²φ + e cos²φ): (t - b0)(t + b0) = e,
    # the factor that cancels taken as e over the other; t - b = s (t - b0) and t + b =
    # 2 (1 - s) t + s (t + b0), both without a difference of like terms.
    e = 1.0 - v
    t = math.sqrt(sin_phi * sin_phi + e * cos_phi * cos_phi)
    upper = b0 > 0.0
    t_minus = e / (t + b0) if upper else t - b0
    t_plus = t + b0 if upper else e / (t - b0)
    b = (1.0 - s) * t + s * b0
    c = _safe_sqrt(s * t_minus * (2.0 * (1.0 - s) * t + s * t_plus))
    nx = a * t1x + b * t2x + c * vx
    ny = a * t1y + b * t2y + c * vy
    nz = a * t1z + b * t2z + c * vz
    hx, hy, hz = alpha * nx, alpha * ny, max(0.0, nz)
    inv = 1.0 / math.sqrt(hx * hx + hy * hy + hz * hz)
    # at least float32's least subnormal: the disk's lower rim maps to the horizon, and
    # nz there, within 1e-16 of 0, is a difference of terms near 1 that rounds to <= 0
    # (for up to 20 % of u1 at u0 = 1 - 2^-53): h on the horizon, of density D = 0.
    # The true h lies above it, where D is positive. NaN stays NaN (max returns it first).
    return (hx * inv, hy * inv, max(hz * inv, _HORIZON_Z))


@_jit
def _ggx_vndf_pdf_kernel(x, p):
    w = (p[1], p[2], p[3])
    cos_wh = w[0] * x[0] + w[1] * x[1] + w[2] * x[2]
    if cos_wh <= 0.0:
        return 0.0
    return _ggx_g1_over_cos(w, p[0]) * cos_wh * ggx_d(x, p[0])


# ------------------------------------------------------------------- 1-D densities
@_jit
def _sample_exponential_kernel(u, p):
    """Distance sampling: pdf σ e^{-σx} / (1 - e^{-σ t}) on [0, t]; ``p = (σ, t)``,
    t may be inf."""
    c = -fast_expm1(-p[0] * p[1])
    # u = 1 (a float32 u within 2^-25 of 1) as 1 - 2^-53: with t = inf, -log1p(-1) made
    # the point inf; NaN stays NaN (min returns its first argument when it cannot compare)
    v = min(u[0], ONE_MINUS_EPSILON)
    return (min(-fast_log1p(-v * c) / p[0], p[1]),)


@_jit
def _exponential_pdf_kernel(x, p):
    if x[0] < 0.0 or x[0] > p[1]:
        return 0.0
    return p[0] * fast_exp(-p[0] * x[0]) / -fast_expm1(-p[0] * p[1])


@_jit
def _invert_exponential_kernel(x, p):
    return (_clamp_u(fast_expm1(-p[0] * x[0]) / fast_expm1(-p[0] * p[1])),)


@_jit
def _sample_tent_kernel(u, p):
    """Tent of radius ``p[0] = r`` on [-r, r]: pdf (r - |x|) / r²."""
    r = p[0]
    if u[0] < 0.5:
        return (-r + r * math.sqrt(2.0 * u[0]),)
    return (r - r * math.sqrt(2.0 - 2.0 * u[0]),)


@_jit
def _tent_pdf_kernel(x, p):
    # (1 - |x|/r)/r: (r - |x|)/r² overflowed to 0 at r = 1e155 and to inf at 1e-170
    r = p[0]
    return max(0.0, 1.0 - abs(x[0]) / r) / r


@_jit
def _invert_tent_kernel(x, p):
    r = p[0]
    # a point beyond an end as that end, as the interval's inverse: t² of t < 0 folded
    # the tails back (x = 5 with r = 1 gave u = 0, x = -5 gave 1 - 2^-53)
    v = min(max(x[0], -r), r)
    if v < 0.0:
        t = (v + r) / r
        return (_clamp_u(0.5 * t * t),)
    t = (r - v) / r
    return (_clamp_u(1.0 - 0.5 * t * t),)


@_jit
def _unit_scale(a, b, c=0.0, d=0.0):
    """The weights a, b (c, d) divided by the largest where that is below 1e-150 or
    above 1e150, else as they are: a linear or bilinear density depends on their ratios
    alone, and squares or sums of extreme weights under- or overflow (a = b = 1e-300
    sampled 2u, not u; a, b near 1e300 sampled 0; a pdf with a + b or 2·a past 1.8e308
    was 0, inf or NaN)."""
    s = max(a, b, c, d)
    if s < 1e-150 or s > 1e150:
        return a / s, b / s, c / s, d / s
    return a, b, c, d


@_jit
def _sample_linear_1d(u, a, b):
    if u == 0.0:     # x = 0; a weight that the scaling below rounds to 0 made it 0/0
        return 0.0   # (a = 1e-170, b = 1e170: NaN), as a = 0 had before
    # the weights over the larger, always: with a = 0, u·b² underflowed for tiny u
    # (a = 0, b = 1e-60, u = 1e-250 sampled 1 - 2⁻⁵³, not 1e-125; smaller, 0/0 = NaN)
    s = max(a, b)
    a, b = (a / s, b / s) if s > 0.0 else (a, b)
    x = u * (a + b) / (a + math.sqrt((1.0 - u) * a * a + u * b * b))
    # a = b = 0 (the bilinear warp's row y = 0 when w00 = w10 = 0, or y = 1 when w01 =
    # w11 = 0: a line of zero density, met only at u = 0 or 1): any x, so u (0/0 before)
    return min(x, ONE_MINUS_EPSILON) if a + b > 0.0 else u


@_jit
def _linear_pdf_1d(x, a, b):
    if x < 0.0 or x > 1.0:
        return 0.0
    a, b, _, _ = _unit_scale(a, b)
    return 2.0 * ((1.0 - x) * a + x * b) / (a + b)


@_jit
def _invert_linear_1d(x, a, b):
    # a point beyond [0, 1] as its nearest end, as the interval's inverse: the CDF's
    # quadratic turns back outside (a = 2, b = 0.01: x = 3 gave u = 0; a = 0.01, b = 2:
    # x = -2 gave 1 - 2^-53)
    x = min(max(x, 0.0), 1.0)
    a, b, _, _ = _unit_scale(a, b)
    return _clamp_u(x * (a * (2.0 - x) + b * x) / (a + b) if a + b > 0.0 else x)


@_jit
def _sample_linear_kernel(u, p):
    """Linear density on [0, 1] from ``p[0] = a`` at 0 to ``p[1] = b`` at 1 (a, b >= 0)."""
    return (_sample_linear_1d(u[0], p[0], p[1]),)


@_jit
def _linear_pdf_kernel(x, p):
    return _linear_pdf_1d(x[0], p[0], p[1])


@_jit
def _invert_linear_kernel(x, p):
    return (_invert_linear_1d(x[0], p[0], p[1]),)


@_jit
def _sample_bilinear_kernel(u, p):
    """Bilinear density on [0, 1]² with corner weights ``p = (w00, w10, w01, w11)``."""
    w00, w10, w01, w11 = _unit_scale(p[0], p[1], p[2], p[3])
    y = _sample_linear_1d(u[1], w00 + w10, w01 + w11)
    x = _sample_linear_1d(u[0], (1.0 - y) * w00 + y * w01, (1.0 - y) * w10 + y * w11)
    return (x, y)


@_jit
def _bilinear_pdf_kernel(x, p):
    if x[0] < 0.0 or x[0] > 1.0 or x[1] < 0.0 or x[1] > 1.0:
        return 0.0
    w00, w10, w01, w11 = _unit_scale(p[0], p[1], p[2], p[3])
    s, t = x[0], x[1]
    v = ((1 - s) * (1 - t) * w00 + s * (1 - t) * w10 + (1 - s) * t * w01 + s * t * w11)
    return 4.0 * v / (w00 + w10 + w01 + w11)


@_jit
def _invert_bilinear_kernel(x, p):
    w00, w10, w01, w11 = _unit_scale(p[0], p[1], p[2], p[3])
    y = min(max(x[1], 0.0), 1.0)     # the row's weights are negative beyond [0, 1]
    return (_invert_linear_1d(x[0], (1.0 - y) * w00 + y * w01, (1.0 - y) * w10 + y * w11),
            _invert_linear_1d(y, w00 + w10, w01 + w11))


# ------------------------------------------------------------------ the registry
@dataclass(frozen=True)
class Warp:
    """A warp's triple and what a test needs to know about it.

    ``domain``: a domain name, or ``("interval", a, b)`` where a, b may name
    parameters (e.g. ``("interval", "-radius", "radius")``). ``params``: parameter
    names; ``defaults``: a typical value each; ``ranges``: (low, high) each, for
    property-based tests; ``log_scale``: parameters to draw log-uniformly.
    """

    name: str
    sample: object
    pdf: object
    invert: object | None
    domain: object
    sample_dim: int
    dim: int
    params: tuple[str, ...] = ()
    defaults: tuple[float, ...] = ()
    ranges: tuple[tuple[float, float], ...] = ()
    log_scale: tuple[str, ...] = ()

    def domain_spec(self, *params):
        """``(name, args)`` of the domain for these parameter values."""
        if isinstance(self.domain, str):
            return self.domain, ()
        name, *bounds = self.domain
        values = dict(zip(self.params, params))
        args = []
        for b in bounds:
            if isinstance(b, str):
                sign = -1.0 if b.startswith("-") else 1.0
                args.append(sign * values[b.lstrip("-")])
            else:
                args.append(float(b))
        return name, tuple(args)


def _triple(name, n_in, n_out, sample_k, pdf_k, invert_k, doc, inline=()):
    """The three front ends, and the sampler's ``with_pdf`` (sample and density in one
    pass: ``_vectorize.fused_front_end``). ``inline`` names those ("sample", "pdf",
    "invert") whose loops numba inlines the kernel into (``_vectorize._loop``), for
    kernels LLVM finds too large to inline and so does not vectorise: those calling
    ``_fastmath`` (an azimuth's sin/cos or atan2 is enough), and GGX's visible normals
    (measured, one thread: 55 -> 19 ns a point to sample)."""
    s = point_front_end(sample_k, n_in, n_out, f"sample_{name}", doc,
                        inline="sample" in inline, unit=True)
    p = value_front_end(pdf_k, n_out, f"{name}_pdf", f"Density of ``sample_{name}``.",
                        inline="pdf" in inline)
    i = None if invert_k is None else _below_one(point_front_end(
        invert_k, n_out, n_in, f"invert_{name}", f"Inverse of ``sample_{name}``: x -> u.",
        inline="invert" in inline))
    s.with_pdf = fused_front_end(
        sample_k, pdf_k, n_in, n_out, f"sample_{name}.with_pdf",
        f"``(x, pdf)``: ``x = sample_{name}(u, *params)`` and ``{name}_pdf(x, *params)`` "
        "in one pass over the points, bit for bit as the two calls.",
        inline="sample" in inline, inline_density="pdf" in inline)
    return s, p, i


def _kept_within(sample, pdf, lift):
    """The sampler with float32 points kept inside their support: a point computed
    inside can round to a float32 just outside (the cone's z below cos θ_max = 0.9999:
    310 of 2M float32 u; the interval's a = -0.3 at u = 0, as Sobol's first point gives;
    the disk's rim and the triangle's diagonal at u on the square's edge), a point of
    density 0 as stored, whose f / pdf is inf. ``lift(x, params)`` moves such float32
    rows of ``x`` in place by an ulp or two and says which it moved (None for float64
    points, left as they are); ``with_pdf`` gives the density of the point as stored."""
    def front(u, *params):
        x = sample(u, *params)
        lift(x, params)
        return x

    def with_pdf(u, *params):
        x, density = sample.with_pdf(u, *params)
        moved = lift(x, params)
        if moved is not None and moved.any():
            density[moved] = pdf(x[moved], *params)
        return x, density

    return _like(sample, front, with_pdf)


def _like(sample, front, with_pdf):
    """``front`` and its ``with_pdf``, wrappers of the sampler ``sample``, given its names,
    docstrings, kernel and loops, as the other front ends have them."""
    functools.update_wrapper(front, sample)
    functools.update_wrapper(with_pdf, sample.with_pdf)
    front.kernel, front.loop = sample.kernel, sample.loop
    with_pdf.loop = sample.with_pdf.loop
    front.with_pdf = with_pdf
    return front


def _coordinate_lift(coord, bounds):
    """``lift`` for a support [lo, hi] = ``bounds(*params)`` on coordinate ``coord``: a
    coordinate outside becomes the float32 nearest it inside (one ulp from where it was,
    within one float32 ulp of the float64 point, not half), where [lo, hi] holds one."""
    def lift(x, params):
        if x.dtype != np.float32 or x.ndim != 2:
            return None
        lo, hi = (float(np.asarray(v)) for v in bounds(*params))
        first, last = np.float32(lo), np.float32(hi)
        if float(first) < lo:                               # the least float32 >= lo
            first = np.nextafter(first, np.float32(np.inf))
        if float(last) > hi:                                # the largest float32 <= hi
            last = np.nextafter(last, np.float32(-np.inf))
        if not float(first) <= float(last):    # no float32 inside: as rounded
            return None
        v = x[:, coord]
        wide = v.astype(np.float64)     # (numpy compares float32 with a float in float32)
        low, high = wide < lo, wide > hi        # NaN: neither
        v[low], v[high] = first, last
        return low | high

    return lift


def _stepwise_lift(outside, step):
    """``lift`` for a support that no one coordinate bounds: float32 rows where
    ``outside(x in float64)`` holds are moved by ``step(x, rows)`` (an ulp towards the
    inside), at most four times (one or two steps have always sufficed)."""
    def lift(x, params):
        if x.dtype != np.float32 or x.ndim != 2:
            return None
        moved = np.zeros(len(x), dtype=bool)
        for _ in range(4):
            rows = np.flatnonzero(outside(x.astype(np.float64)))      # NaN: never
            if not rows.size:
                break
            step(x, rows)
            moved[rows] = True
        return moved

    return lift


def _disk_step(x, rows):
    x[rows] = np.nextafter(x[rows], np.float32(0.0))         # both towards the centre


def _triangle_step(x, rows):
    col = np.argmax(x[rows], axis=1)                        # the larger barycentric
    x[rows, col] = np.nextafter(x[rows, col], np.float32(0.0))


_DISK_LIFT = _stepwise_lift(lambda w: w[:, 0] * w[:, 0] + w[:, 1] * w[:, 1] > _DISK_RIM,
                            _disk_step)
_TRIANGLE_LIFT = _stepwise_lift(lambda w: w[:, 0] + w[:, 1] > 1.0, _triangle_step)


_BELOW_ONE_F32 = np.float32(1.0 - 2.0 ** -24)


def _float32_one_below(sample):
    """The sampler with a float32 u0 of 1 taken as the largest float32 below 1, not as
    the kernel's 1 - 2^-53: the visible normals' h at u0 = 1 - 2^-53 lies within 1e-8
    of the edge where w · h = 0, which a float32 point cannot resolve (w · h of the
    stored point came out <= 0, density 0, for 2 % of u1 at the default parameters)."""
    def clamped(u):
        try:
            u = np.asarray(u)
        except ValueError:      # ragged: the front end refuses it, naming the sampler
            return u
        if u.dtype != np.float32 or u.ndim != 2 or not u.shape[1] or \
                not (u[:, 0] == 1.0).any():
            return u
        u = u.copy()
        u[u[:, 0] == 1.0, 0] = _BELOW_ONE_F32
        return u

    def front(u, *params):
        return sample(clamped(u), *params)

    def with_pdf(u, *params):
        return sample.with_pdf(clamped(u), *params)

    return _like(sample, front, with_pdf)


def _below_one(invert):
    """An inverse whose float32 output stays in [0, 1): the kernels clamp u to the
    float64 ``ONE_MINUS_EPSILON``, which rounds to 1.0 in float32, so float32 results are
    clamped again to the largest float32 below 1."""
    def front(x, *params):
        u = invert(x, *params)
        if u.dtype == np.float32:
            np.minimum(u, _BELOW_ONE_F32, out=u)
        return u

    functools.update_wrapper(front, invert)
    front.kernel, front.loop = invert.kernel, invert.loop
    return front


_ALL = ("sample", "pdf", "invert")


sample_uniform_interval, uniform_interval_pdf, invert_uniform_interval = _triple(
    "uniform_interval", 1, 1, _sample_uniform_interval_kernel, _uniform_interval_pdf_kernel,
    _invert_uniform_interval_kernel, "Uniform on [a, b]: ``sample_uniform_interval(u, a, b)``.")
sample_uniform_interval = _kept_within(sample_uniform_interval, uniform_interval_pdf,
                                       _coordinate_lift(0, lambda a, b: (a, b)))
sample_uniform_square, uniform_square_pdf, _ = _triple(
    "uniform_square", 2, 2, _sample_uniform_square_kernel, _uniform_square_pdf_kernel, None,
    "Identity map of the unit square.")
sample_uniform_disk_polar, uniform_disk_pdf, invert_uniform_disk_polar = _triple(
    "uniform_disk_polar", 2, 2, _sample_uniform_disk_polar_kernel, _uniform_disk_pdf_kernel,
    _invert_uniform_disk_polar_kernel, "Uniform on the unit disk, polar map r = √u₀.",
    inline=("invert",))
sample_uniform_disk_concentric, _, invert_uniform_disk_concentric = _triple(
    "uniform_disk_concentric", 2, 2, sample_uniform_disk_concentric_kernel,
    _uniform_disk_pdf_kernel, _invert_uniform_disk_concentric_kernel,
    "Uniform on the unit disk, Shirley–Chiu concentric map (low distortion).")
sample_uniform_disk_polar = _kept_within(sample_uniform_disk_polar, uniform_disk_pdf,
                                         _DISK_LIFT)
sample_uniform_disk_concentric = _kept_within(sample_uniform_disk_concentric,
                                              uniform_disk_pdf, _DISK_LIFT)
sample_uniform_triangle, uniform_triangle_pdf, invert_uniform_triangle = _triple(
    "uniform_triangle", 2, 2, sample_uniform_triangle_kernel, _uniform_triangle_pdf_kernel,
    _invert_uniform_triangle_kernel,
    "Uniform barycentrics (b0, b1) on the triangle (0,0), (1,0), (0,1) (Heitz 2019).")
sample_uniform_triangle = _kept_within(sample_uniform_triangle, uniform_triangle_pdf,
                                       _TRIANGLE_LIFT)
sample_uniform_sphere, uniform_sphere_pdf, invert_uniform_sphere = _triple(
    "uniform_sphere", 2, 3, sample_uniform_sphere_kernel, _uniform_sphere_pdf_kernel,
    _invert_uniform_sphere_kernel, "Uniform directions on the unit sphere.",
    inline=("sample", "invert"))
sample_uniform_hemisphere, uniform_hemisphere_pdf, invert_uniform_hemisphere = _triple(
    "uniform_hemisphere", 2, 3, _sample_uniform_hemisphere_kernel,
    _uniform_hemisphere_pdf_kernel, _invert_uniform_hemisphere_kernel,
    "Uniform directions on the hemisphere z >= 0.", inline=("sample", "invert"))
sample_cosine_hemisphere, cosine_hemisphere_pdf, invert_cosine_hemisphere = _triple(
    "cosine_hemisphere", 2, 3, sample_cosine_hemisphere_kernel, cosine_hemisphere_pdf_kernel,
    _invert_cosine_hemisphere_kernel,
    "Cosine-weighted hemisphere (Malley's method on the concentric disk): pdf cos θ / π.",
    inline=("invert",))
sample_uniform_cone, uniform_cone_pdf, invert_uniform_cone = _triple(
    "uniform_cone", 2, 3, sample_uniform_cone_kernel, _uniform_cone_pdf_kernel,
    _invert_uniform_cone_kernel,
    "Uniform on the spherical cap θ <= θ_max: ``sample_uniform_cone(u, cos_theta_max)``.",
    inline=("sample", "invert"))
sample_uniform_cone = _kept_within(sample_uniform_cone, uniform_cone_pdf,
                                   _coordinate_lift(2, lambda cos_theta_max: (cos_theta_max,
                                                                              1.0)))
sample_power_cosine, power_cosine_pdf, invert_power_cosine = _triple(
    "power_cosine", 2, 3, _sample_power_cosine_kernel, _power_cosine_pdf_kernel,
    _invert_power_cosine_kernel,
    "Phong / power-cosine lobe: pdf (n+1)/(2π) cos^n θ: ``sample_power_cosine(u, n)``.",
    inline=("sample", "pdf", "invert"))
sample_ggx, ggx_pdf, invert_ggx = _triple(
    "ggx", 2, 3, _sample_ggx_kernel, _ggx_pdf_kernel, _invert_ggx_kernel,
    "GGX (Trowbridge–Reitz) normals, pdf D(h) cos θ_h: ``sample_ggx(u, alpha)``.",
    inline=("sample", "invert"))
sample_beckmann, beckmann_pdf, invert_beckmann = _triple(
    "beckmann", 2, 3, sample_beckmann_kernel, beckmann_pdf_kernel, _invert_beckmann_kernel,
    "Beckmann normals, pdf D(h) cos θ_h: ``sample_beckmann(u, alpha)``.", inline=_ALL)
sample_ggx_vndf, ggx_vndf_pdf, _ = _triple(
    "ggx_vndf", 2, 3, sample_ggx_vndf_kernel, _ggx_vndf_pdf_kernel, None,
    "GGX visible normals (Heitz 2018): ``sample_ggx_vndf(u, alpha, wx, wy, wz)``, "
    "pdf G1(w) max(0, w·h) D(h) / w_z.", inline=_ALL)
sample_ggx_vndf = _float32_one_below(sample_ggx_vndf)
sample_exponential, exponential_pdf, invert_exponential = _triple(
    "exponential", 1, 1, _sample_exponential_kernel, _exponential_pdf_kernel,
    _invert_exponential_kernel,
    "Truncated exponential (distance sampling): ``sample_exponential(u, sigma, t_max)``.",
    inline=_ALL)
sample_exponential = _kept_within(sample_exponential, exponential_pdf,
                                  _coordinate_lift(0, lambda sigma, t_max: (0.0, t_max)))
sample_tent, tent_pdf, invert_tent = _triple(
    "tent", 1, 1, _sample_tent_kernel, _tent_pdf_kernel, _invert_tent_kernel,
    "Tent on [-r, r]: ``sample_tent(u, r)``.")
sample_linear, linear_pdf, invert_linear = _triple(
    "linear", 1, 1, _sample_linear_kernel, _linear_pdf_kernel, _invert_linear_kernel,
    "Linear density on [0, 1] from a to b: ``sample_linear(u, a, b)``.")
sample_bilinear, bilinear_pdf, invert_bilinear = _triple(
    "bilinear", 2, 2, _sample_bilinear_kernel, _bilinear_pdf_kernel, _invert_bilinear_kernel,
    "Bilinear density on [0, 1]²: ``sample_bilinear(u, w00, w10, w01, w11)``.")


WARPS: dict[str, Warp] = {w.name: w for w in [
    Warp("uniform_interval", sample_uniform_interval, uniform_interval_pdf,
         invert_uniform_interval, ("interval", "a", "b"), 1, 1, ("a", "b"), (-1.0, 3.0),
         ((-10.0, -0.5), (0.5, 10.0))),
    Warp("uniform_disk_polar", sample_uniform_disk_polar, uniform_disk_pdf,
         invert_uniform_disk_polar, "disk", 2, 2),
    Warp("uniform_disk_concentric", sample_uniform_disk_concentric, uniform_disk_pdf,
         invert_uniform_disk_concentric, "disk", 2, 2),
    # pdf 2 on the lower-left triangle of the unit square: an edge inside cells
    Warp("uniform_triangle", sample_uniform_triangle, uniform_triangle_pdf,
         invert_uniform_triangle, "square", 2, 2),
    Warp("uniform_sphere", sample_uniform_sphere, uniform_sphere_pdf, invert_uniform_sphere,
         "sphere", 2, 3),
    Warp("uniform_hemisphere", sample_uniform_hemisphere, uniform_hemisphere_pdf,
         invert_uniform_hemisphere, "hemisphere", 2, 3),
    Warp("cosine_hemisphere", sample_cosine_hemisphere, cosine_hemisphere_pdf,
         invert_cosine_hemisphere, "hemisphere", 2, 3),
    Warp("uniform_cone", sample_uniform_cone, uniform_cone_pdf, invert_uniform_cone,
         "sphere", 2, 3, ("cos_theta_max",), (0.8,), ((-0.99, 0.999),)),
    Warp("power_cosine", sample_power_cosine, power_cosine_pdf, invert_power_cosine,
         "hemisphere", 2, 3, ("n",), (20.0,), ((0.0, 1000.0),)),
    Warp("ggx", sample_ggx, ggx_pdf, invert_ggx, "hemisphere", 2, 3, ("alpha",), (0.3,),
         ((1e-3, 1.0),), ("alpha",)),
    Warp("beckmann", sample_beckmann, beckmann_pdf, invert_beckmann, "hemisphere", 2, 3,
         ("alpha",), (0.3,), ((1e-3, 1.0),), ("alpha",)),
    # (wx, wy, wz) is normalised by the property tests; no closed-form inverse
    Warp("ggx_vndf", sample_ggx_vndf, ggx_vndf_pdf, None, "hemisphere", 2, 3,
         ("alpha", "wx", "wy", "wz"), (0.3, 0.6, 0.0, 0.8),
         ((1e-2, 1.0), (-1.0, 1.0), (-1.0, 1.0), (0.05, 1.0)), ("alpha",)),
    Warp("exponential", sample_exponential, exponential_pdf, invert_exponential,
         ("interval", 0.0, "t_max"), 1, 1, ("sigma", "t_max"), (2.0, 3.0),
         ((1e-2, 1e2), (1e-2, 1e2)), ("sigma", "t_max")),
    Warp("tent", sample_tent, tent_pdf, invert_tent, ("interval", "-radius", "radius"), 1, 1,
         ("radius",), (1.5,), ((1e-3, 1e3),), ("radius",)),
    Warp("linear", sample_linear, linear_pdf, invert_linear, ("interval", 0.0, 1.0), 1, 1,
         ("a", "b"), (0.5, 2.0), ((0.0, 10.0), (0.01, 10.0))),
    Warp("bilinear", sample_bilinear, bilinear_pdf, invert_bilinear, "square", 2, 2,
         ("w00", "w10", "w01", "w11"), (1.0, 3.0, 0.5, 2.0),
         ((0.01, 10.0),) * 4),
]}
