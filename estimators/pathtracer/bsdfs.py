"""BSDFs as numba scalar kernels, in the local shading frame (normal +z), with Mitsuba's
models and conventions so that both renderers estimate the same image:

``diffuse``, ``conductor`` (smooth, complex Fresnel), ``roughconductor`` (GGX or Beckmann,
Smith G1; Beckmann's G1 is Walter's rational fit, as Mitsuba's), ``dielectric`` (smooth,
with radiance scaled by η² on refraction), ``plastic`` and ``roughplastic`` (a diffuse base
under a dielectric coat, with Mitsuba's internal-scattering normalisation), and the
``twosided`` wrapper (a flag: the back side mirrors the front).

Each BSDF is one row of ``bsdf_f`` and ``bsdf_i``, with the columns named in ``layout``
(``COLOR0``, ``ETA``, ``ALPHA``, ``BSDF_KIND``...). Colours live in two slots, ``COLOR0``
and ``COLOR1``, which a bitmap texture may replace (``bsdf_tex[b, slot]`` >= 0). Values:
``eval`` returns f · cos θ_o; ``sample`` returns the weight f · cos θ_o / pdf.

Sampling is our own where it does not change the expectation of a consistent estimator:
GGX samples visible normals with the estimators' VNDF warp; Beckmann samples D · cos θ_m
with the estimators' warp, where Mitsuba samples visible normals. Mitsuba's own image
depends on that choice where light leaks across a mesh's smooth normals (its light pdf
reads the interpolated normal, not the density of its draws): there a Beckmann surface
renders about 0.90 of Mitsuba's (the README says more).
"""

from __future__ import annotations

import math

import numpy as np

from .._compile_options import fused
from ..warps import (beckmann_pdf_kernel, cosine_hemisphere_pdf_kernel, ggx_d,
                     sample_beckmann_kernel, sample_cosine_hemisphere_kernel,
                     sample_ggx_vndf_kernel)
from .layout import (ALPHA, ALPHA_V, BLEND, BSDF_CHILD0, BSDF_CHILD1, BSDF_DISTRIBUTION,
                     BSDF_KIND, BSDF_NONLINEAR, BSDF_TWOSIDED, COAT_INTERNAL, COAT_TABLE,
                     COAT_TABLE_RES, COLOR0, COLOR1, COND_ETA, COND_K, CONDUCTOR, DIELECTRIC,
                     DIFFUSE, ETA, F_BLEND, F_CONDUCTOR, F_DIELECTRIC, F_DIFFUSE, F_MASK,
                     F_NORMALMAP, F_PLASTIC, F_ROUGHCONDUCTOR, F_ROUGHDIELECTRIC, F_ROUGHPLASTIC,
                     F_TEXTURES, F_THINDIELECTRIC, F_TWOSIDED, GGX, MASK, MIX,
                     NORMALMAP, NORMALMAP_FLIP_INVALID, NORMALMAP_SHADOWING, PLASTIC,
                     ROUGHCONDUCTOR, ROUGHDIELECTRIC, ROUGHPLASTIC, SPECULAR_WEIGHT,
                     THINDIELECTRIC)
from .textures import eval_texture, luminance

__all__ = ["bsdf_eval", "bsdf_sample", "bsdf_is_smooth", "rough_coat_tables",
           "fresnel_dielectric", "fresnel_conductor", "fresnel_diffuse_reflectance"]

_jit = fused()
_fast = fused(_nrt=False)    # array arguments, no allocation: see emitters.py
_INV_PI = 1.0 / math.pi


# --------------------------------------------------------------------------- Fresnel
@_jit
def fresnel_dielectric(cos_i, eta):
    """Mitsuba's ``fresnel``: (R, cos θ_t signed opposite to cos θ_i, η_it, η_ti)."""
    if cos_i >= 0.0:
        eta_it, eta_ti = eta, 1.0 / eta
    else:
        eta_it, eta_ti = 1.0 / eta, eta
    cos_t2 = 1.0 - eta_ti * eta_ti * (1.0 - cos_i * cos_i)
    ci = abs(cos_i)
    ct = math.sqrt(max(cos_t2, 0.0))
    if eta == 1.0:
        r = 0.0
    elif ci == 0.0:
        r = 1.0
    else:
        a_s = (ci - eta_it * ct) / (ci + eta_it * ct)
        a_p = (ct - eta_it * ci) / (ct + eta_it * ci)
        r = 0.5 * (a_s * a_s + a_p * a_p)
    cos_t = -ct if cos_i >= 0.0 else ct
    return r, cos_t, eta_it, eta_ti


@_jit
def fresnel_conductor(cos_i, eta, k):
    """Unpolarised reflectance of a conductor of complex index η + ik."""
    c2 = cos_i * cos_i
    s2 = 1.0 - c2
    s4 = s2 * s2
    t1 = eta * eta - k * k - s2
    a2b2 = math.sqrt(max(t1 * t1 + 4.0 * k * k * eta * eta, 0.0))
    a = math.sqrt(max(0.5 * (a2b2 + t1), 0.0))
    term1 = a2b2 + c2
    term2 = 2.0 * cos_i * a
    rs = (term1 - term2) / (term1 + term2)
    term3 = a2b2 * c2 + s4
    term4 = term2 * s2
    rp = rs * (term3 - term4) / (term3 + term4)
    return 0.5 * (rs + rp)


@fused(inline="always")
def _conductor_fresnel(bf, b, cos_i):
    """BSDF b's conductor reflectance per colour channel: one Fresnel term where the
    three channels' (η, k) agree (a grey conductor), none for (0, 1), Mitsuba's material
    "none", a perfect mirror (each term costs two square roots and two divisions)."""
    e0, e1, e2 = bf[b, COND_ETA], bf[b, COND_ETA + 1], bf[b, COND_ETA + 2]
    k0, k1, k2 = bf[b, COND_K], bf[b, COND_K + 1], bf[b, COND_K + 2]
    if e0 == e1 and e0 == e2 and k0 == k1 and k0 == k2:
        if e0 == 0.0 and k0 == 1.0:
            return 1.0, 1.0, 1.0
        f = fresnel_conductor(cos_i, e0, k0)
        return f, f, f
    return (fresnel_conductor(cos_i, e0, k0), fresnel_conductor(cos_i, e1, k1),
            fresnel_conductor(cos_i, e2, k2))


def fresnel_diffuse_reflectance(eta: float) -> float:
    """Fdr: the fraction of diffuse light a dielectric boundary reflects (the fits of
    Egan–Hilgeman for η < 1 and d'Eon–Irving for η >= 1, as Mitsuba uses)."""
    if eta < 1.0:
        return -1.4399 * eta * eta + 0.7099 * eta + 0.6681 + 0.0636 / eta
    x = 1.0 / eta
    return 0.919317 + x * (-3.4793 + x * (6.75335 + x * (-7.80989 + x * (4.98554
                                                                       - 1.36881 * x))))


# ------------------------------------------------------------------------ microfacets
# Roughness is (alpha_u, alpha_v) along the local x (the shading frame's s) and y. The
# isotropic case (equal) runs the warps' code as it always did; the anisotropic one is
# the isotropic α = 1 distribution stretched by (alpha_u, alpha_v) in slope space, which
# is exact for GGX and Beckmann (their slope densities scale, Heitz 2014, sec. 5.4).
@_jit
def _d_isotropic(m, alpha, dist):
    if dist == GGX:
        return ggx_d(m, alpha)
    if m[2] <= 0.0:
        return 0.0
    return beckmann_pdf_kernel(m, (alpha,)) / m[2]


@_jit
def microfacet_d(m, au, av, dist):
    """D(m) of roughness (alpha_u, alpha_v). Anisotropic: D(m) = D₁(m̃) / (αu αv L⁴)
    with m̃ = (mx/αu, my/αv, mz) / L, D₁ the distribution at α = 1."""
    if au == av:
        return _d_isotropic(m, au, dist)
    if m[2] <= 0.0:
        return 0.0
    sx, sy = m[0] / au, m[1] / av
    l2 = sx * sx + sy * sy + m[2] * m[2]
    inv = 1.0 / math.sqrt(l2)
    return _d_isotropic((sx * inv, sy * inv, m[2] * inv), 1.0, dist) / (au * av * l2 * l2)


@_jit
def smith_g1(v, m, au, av, dist):
    if au == av:
        xy2 = au * au * (v[0] * v[0] + v[1] * v[1])
    else:
        xy2 = au * au * v[0] * v[0] + av * av * v[1] * v[1]
    if (v[0] * m[0] + v[1] * m[1] + v[2] * m[2]) * v[2] <= 0.0:
        return 0.0
    if xy2 == 0.0:
        return 1.0
    tan2 = xy2 / (v[2] * v[2])
    if dist == GGX:
        return 2.0 / (1.0 + math.sqrt(1.0 + tan2))
    a = 1.0 / math.sqrt(tan2)
    if a >= 1.6:
        return 1.0
    return (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a)


@_jit
def _normalize(x, y, z):
    inv = 1.0 / math.sqrt(x * x + y * y + z * z)
    return (x * inv, y * inv, z * inv)


@_jit
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@_jit
def _reflect(w, m):
    c = 2.0 * _dot(w, m)
    return (c * m[0] - w[0], c * m[1] - w[1], c * m[2] - w[2])


@_jit
def _sample_isotropic(wi, alpha, dist, u0, u1):
    if dist == GGX:
        return sample_ggx_vndf_kernel((u0, u1), (alpha, wi[0], wi[1], wi[2]))
    return sample_beckmann_kernel((u0, u1), (alpha,))


@_jit
def sample_microfacet(wi, au, av, dist, u0, u1):
    """A microfacet normal for ``wi`` (z > 0): visible normals for GGX, D cos θ_m for
    Beckmann; its density is ``_pdf_given_d``. Anisotropic: ``wi`` stretched by
    (αu, αv), a normal of the α = 1 distribution drawn, and unstretched."""
    if au == av:
        return _sample_isotropic(wi, au, dist, u0, u1)
    ws = _normalize(au * wi[0], av * wi[1], wi[2])
    m = _sample_isotropic(ws, 1.0, dist, u0, u1)
    return _normalize(au * m[0], av * m[1], m[2])


@_jit
def _pdf_given_d(d, g1, wi, m, dist):
    """Density (solid angle of m) of ``sample_microfacet(wi, ...)``, from D(m) = d and,
    for GGX, G1(wi, m) = g1: both computed by the caller for the BSDF's value."""
    if dist == GGX:
        return d * g1 * max(_dot(wi, m), 0.0) / wi[2]
    return d * m[2]


@_jit
def _microfacet_value_pdf(wi, wo, au, av, dist):
    """(D G / (4 cos θ_i), wi · h, pdf) for the half vector h of wi and wo: the value and
    the density of wo = reflect(wi, m), m from ``sample_microfacet``, sharing h, D(h) and
    G1(wi, h) (each was computed twice, once for the value and once for the pdf)."""
    m = _normalize(wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2])
    d = microfacet_d(m, au, av, dist)
    g1 = smith_g1(wi, m, au, av, dist)
    wim, wom = _dot(wi, m), _dot(wo, m)
    pdf = 0.0 if wim <= 0.0 or wom <= 0.0 else _pdf_given_d(d, g1, wi, m, dist) / (4.0 * wom)
    if d == 0.0:
        return 0.0, 0.0, pdf
    return d * (g1 * smith_g1(wo, m, au, av, dist)) / (4.0 * wi[2]), wim, pdf


# ------------------------------------------------------------------------- colours
@fused(inline="always")
def color(mask, bf, btex, tex_data, tex_info, b, slot, u, v):
    t = btex[b, slot] if mask & F_TEXTURES else -1
    if t < 0:
        o = COLOR1 if slot else COLOR0
        return bf[b, o], bf[b, o + 1], bf[b, o + 2]
    return eval_texture(tex_data, tex_info, t, u, v)


@_fast
def _lerp_table(bf, b, x):
    x = x * (COAT_TABLE_RES - 1)
    i = min(int(x), COAT_TABLE_RES - 2)
    w = x - i
    return (1.0 - w) * bf[b, COAT_TABLE + i] + w * bf[b, COAT_TABLE + i + 1]


@_fast
def _rough_plastic_probs(bf, b, cos_i):
    t_i = _lerp_table(bf, b, cos_i)
    w = bf[b, SPECULAR_WEIGHT]
    ps = (1.0 - t_i) * w
    pd = t_i * (1.0 - w)
    ps = ps / (ps + pd)
    return ps, t_i


@_fast
def _plastic_probs(bf, b, f_i):
    w = bf[b, SPECULAR_WEIGHT]
    ps = f_i * w
    pd = (1.0 - f_i) * (1.0 - w)
    return ps / (ps + pd)


@_jit
def _coat_base(r, g, b, internal, nonlinear):
    """The base colour under a coat that reflects ``internal`` of diffuse light back
    down: divided by 1 - internal (Mitsuba's default), or by 1 - colour · internal
    (``nonlinear``, the colour shift of real coated materials)."""
    if nonlinear:
        return r / (1.0 - r * internal), g / (1.0 - g * internal), b / (1.0 - b * internal)
    k = 1.0 / (1.0 - internal)
    return r * k, g * k, b * k


# ------------------------------------------------------------------ eval and sample
@fused(inline="always")
def _rough_dielectric_eval(mask, bf, bi, btex, tex_data, tex_info, b, wi, wo, u, v):
    """Mitsuba's ``roughdielectric`` (Walter et al. 2007), either side: (f · |cos θ_o| as
    r, g, b, pdf). In radiance mode the η² of the transmission term and the 1/η² of the
    solid-angle compression cancel."""
    ci, co = wi[2], wo[2]
    if ci == 0.0 or co == 0.0:
        return 0.0, 0.0, 0.0, 0.0
    reflect = ci * co > 0.0
    eta = bf[b, ETA] if ci > 0.0 else 1.0 / bf[b, ETA]
    s = 1.0 if reflect else eta
    m = _normalize(wi[0] + wo[0] * s, wi[1] + wo[1] * s, wi[2] + wo[2] * s)
    if m[2] < 0.0:
        m = (-m[0], -m[1], -m[2])
    wim, wom = _dot(wi, m), _dot(wo, m)
    if wim * ci <= 0.0 or wom * co <= 0.0:
        return 0.0, 0.0, 0.0, 0.0
    au, av, dist = bf[b, ALPHA], bf[b, ALPHA_V], bi[b, BSDF_DISTRIBUTION]
    d = microfacet_d(m, au, av, dist)
    f = fresnel_dielectric(wim, bf[b, ETA])[0]
    # G1(wi, m) is G1(-wi, m) too (wi's sign enters only through (wi · m) wi_z), so the
    # pdf of the flipped wp takes it
    g1 = smith_g1(wi, m, au, av, dist)
    g = g1 * smith_g1(wo, m, au, av, dist)
    wp = wi if ci > 0.0 else (-wi[0], -wi[1], -wi[2])
    pdf = _pdf_given_d(d, g1, wp, m, dist)
    if reflect:
        val = f * d * g / (4.0 * abs(ci))
        pdf *= f / (4.0 * abs(wom))
        c0, c1, c2 = color(mask, bf, btex, tex_data, tex_info, b, 0, u, v)
    else:
        den = wim + eta * wom
        if den == 0.0:
            return 0.0, 0.0, 0.0, 0.0
        den *= den
        val = abs((1.0 - f) * d * g * wim * wom / (ci * den))
        pdf *= (1.0 - f) * abs(eta * eta * wom / den)
        c0, c1, c2 = color(mask, bf, btex, tex_data, tex_info, b, 1, u, v)
    return c0 * val, c1 * val, c2 * val, pdf


@fused(inline="always")
def _eval_basic(mask, bf, bi, btex, tex_data, tex_info, b, wi, wo, u, v):
    """``bsdf_eval`` of a row that is not composite."""
    kind = bi[b, BSDF_KIND]
    if mask & F_ROUGHDIELECTRIC and kind == ROUGHDIELECTRIC:
        return _rough_dielectric_eval(mask, bf, bi, btex, tex_data, tex_info, b, wi, wo, u, v)
    if mask & F_TWOSIDED and bi[b, BSDF_TWOSIDED] and wi[2] < 0.0:
        wi = (wi[0], wi[1], -wi[2])
        wo = (wo[0], wo[1], -wo[2])
    ci, co = wi[2], wo[2]
    if (ci <= 0.0 or co <= 0.0 or kind == CONDUCTOR or kind == DIELECTRIC
            or kind == THINDIELECTRIC):
        return 0.0, 0.0, 0.0, 0.0
    if mask & F_DIFFUSE and kind == DIFFUSE:
        r, g, bl = color(mask, bf, btex, tex_data, tex_info, b, 0, u, v)
        s = co * _INV_PI
        return r * s, g * s, bl * s, s
    if mask & F_ROUGHCONDUCTOR and kind == ROUGHCONDUCTOR:
        au, av, dist = bf[b, ALPHA], bf[b, ALPHA_V], bi[b, BSDF_DISTRIBUTION]
        val, cos_h, pdf = _microfacet_value_pdf(wi, wo, au, av, dist)
        if val == 0.0:
            return 0.0, 0.0, 0.0, 0.0
        r, g, bl = color(mask, bf, btex, tex_data, tex_info, b, 0, u, v)
        f0, f1, f2 = _conductor_fresnel(bf, b, cos_h)
        return r * val * f0, g * val * f1, bl * val * f2, pdf
    eta = bf[b, ETA]
    dr, dg, db = color(mask, bf, btex, tex_data, tex_info, b, 0, u, v)
    if mask & F_PLASTIC and kind == PLASTIC:
        f_i = fresnel_dielectric(ci, eta)[0]
        f_o = fresnel_dielectric(co, eta)[0]
        dr, dg, db = _coat_base(dr, dg, db, bf[b, COAT_INTERNAL], bi[b, BSDF_NONLINEAR])
        s = co * _INV_PI / (eta * eta) * (1.0 - f_i) * (1.0 - f_o)
        pdf = co * _INV_PI * (1.0 - _plastic_probs(bf, b, f_i))
        return dr * s, dg * s, db * s, pdf
    if not (mask & F_ROUGHPLASTIC) or kind != ROUGHPLASTIC:
        return 0.0, 0.0, 0.0, 0.0
    alpha, dist = bf[b, ALPHA], bi[b, BSDF_DISTRIBUTION]
    ps, t_i = _rough_plastic_probs(bf, b, ci)
    t_o = _lerp_table(bf, b, co)
    dr, dg, db = _coat_base(dr, dg, db, bf[b, COAT_INTERNAL], bi[b, BSDF_NONLINEAR])
    s = _INV_PI / (eta * eta) * co * t_i * t_o
    r, g, bl = dr * s, dg * s, db * s
    val, cos_h, spec_pdf = _microfacet_value_pdf(wi, wo, alpha, alpha, dist)
    if val != 0.0:
        sr, sg, sb = color(mask, bf, btex, tex_data, tex_info, b, 1, u, v)
        val *= fresnel_dielectric(cos_h, eta)[0]
        r, g, bl = r + sr * val, g + sg * val, bl + sb * val
    pdf = (ps * spec_pdf
           + (1.0 - ps) * cosine_hemisphere_pdf_kernel(wo, (0.0,)))
    return r, g, bl, pdf


@fused(inline="always")
def _mix_value(mask, bf, btex, tex_data, tex_info, b, u, v):
    """A composite row's scalar (blend weight, mask opacity), clipped to [0, 1]; a texture
    gives its luminance, as Mitsuba's ``eval_1`` of an RGB bitmap."""
    t = btex[b, 0] if mask & F_TEXTURES else -1
    if t < 0:
        x = bf[b, MIX]
    else:
        r, g, bl = eval_texture(tex_data, tex_info, t, u, v)
        x = luminance(r, g, bl)
    return min(max(x, 0.0), 1.0)


@fused(inline="always")
def _eval_mix(mask, bf, bi, btex, tex_data, tex_info, b, wi, wo, u, v):
    """``_eval_basic`` of row b, or of a ``blendbsdf``'s two rows mixed by its weight
    (one call site in a loop: the kernel is compiled with one copy of the BSDFs)."""
    c0 = c1 = b
    w, n = 0.0, 1
    if mask & F_BLEND and bi[b, BSDF_KIND] == BLEND:
        w, n = _mix_value(mask, bf, btex, tex_data, tex_info, b, u, v), 2
        c0, c1 = bi[b, BSDF_CHILD0], bi[b, BSDF_CHILD1]
    r = g = bl = pdf = 0.0
    for k in range(n):
        row, wk = (c0, 1.0 - w) if k == 0 else (c1, w)
        x = _eval_basic(mask, bf, bi, btex, tex_data, tex_info, row, wi, wo, u, v)
        r, g, bl, pdf = r + wk * x[0], g + wk * x[1], bl + wk * x[2], pdf + wk * x[3]
    return r, g, bl, pdf


# ------------------------------------------------------------------- normal maps
@fused(inline="always")
def _normalmap_frame(bi, btex, tex_data, tex_info, b, wi, u, v):
    """Mitsuba's ``normalmap`` frame (s, t, n), in the local shading frame: n is the
    texel v mapped to 2 v - 1, turned by π about the local z where it faces away from
    ``wi`` (``flip_invalid_normals``), normalised; s is (1, 0, 0) made orthogonal to n;
    t = n × s."""
    r, g, bl = eval_texture(tex_data, tex_info, btex[b, 0], u, v)
    nx, ny, nz = 2.0 * r - 1.0, 2.0 * g - 1.0, 2.0 * bl - 1.0
    if bi[b, NORMALMAP_FLIP_INVALID] and wi[2] * (wi[0] * nx + wi[1] * ny + wi[2] * nz) <= 0.0:
        nx, ny = -nx, -ny
    n = _normalize(nx, ny, nz)
    s = _normalize(1.0 - n[0] * n[0], -n[0] * n[1], -n[0] * n[2])
    return s, (n[1] * s[2] - n[2] * s[1], n[2] * s[0] - n[0] * s[2],
               n[0] * s[1] - n[1] * s[0]), n


@_jit
def _tan2(w):
    return max(0.0, 1.0 - w[2] * w[2]) / (w[2] * w[2])


@_jit
def shadow_terminator(n, wo):
    """Mitsuba's ``eval_shadow_terminator`` (Estévez et al., Ray Tracing Gems 2019): the
    GGX-like masking of ``wo`` (local frame) with α² = min(tan² θ_n / 8, 1) set by how far
    the mapped normal n leans."""
    a2 = min(0.125 * _tan2(n), 1.0)
    return 2.0 / (1.0 + math.sqrt(1.0 + a2 * _tan2(wo)))


@fused(inline="always")
def bsdf_eval(mask, bf, bi, btex, tex_data, tex_info, b, wi, wo, u, v):
    """(f · |cos θ_o| as r, g, b, pdf) of the non-delta components. A ``mask`` scales its
    BSDF's value and pdf by the opacity; a ``blendbsdf`` mixes its two by the weight; a
    ``normalmap`` evaluates its BSDF in the perturbed frame (nothing where wo lies on
    opposite sides of the two frames) and scales the value by ``shadow_terminator``."""
    shadow = 1.0
    if mask & F_NORMALMAP and bi[b, BSDF_KIND] == NORMALMAP:
        if bi[b, BSDF_TWOSIDED] and wi[2] < 0.0:
            wi, wo = (wi[0], wi[1], -wi[2]), (wo[0], wo[1], -wo[2])
        fs, ft, fn = _normalmap_frame(bi, btex, tex_data, tex_info, b, wi, u, v)
        po = (_dot(fs, wo), _dot(ft, wo), _dot(fn, wo))
        if wo[2] * po[2] <= 0.0:
            return 0.0, 0.0, 0.0, 0.0
        if bi[b, NORMALMAP_SHADOWING]:
            shadow = shadow_terminator(fn, wo)
        wi, wo = (_dot(fs, wi), _dot(ft, wi), _dot(fn, wi)), po
        b = bi[b, BSDF_CHILD0]
    scale = 1.0
    if mask & F_MASK and bi[b, BSDF_KIND] == MASK:
        scale = _mix_value(mask, bf, btex, tex_data, tex_info, b, u, v)
        b = bi[b, BSDF_CHILD0]
    r, g, bl, pdf = _eval_mix(mask, bf, bi, btex, tex_data, tex_info, b, wi, wo, u, v)
    if mask & F_NORMALMAP:
        return r * scale * shadow, g * scale * shadow, bl * scale * shadow, pdf * scale
    return r * scale, g * scale, bl * scale, pdf * scale


@fused(inline="always")
def _sample_basic(mask, bf, bi, btex, tex_data, tex_info, b, wi, u0, u1, u2, u, v, pdf_scale):
    """A direction from a row that is not composite: (wo x, y, z, ok, delta, weight r, g,
    b and pdf of a delta lobe, η, null). The weight of a non-delta direction is the
    caller's: f / pdf of the whole BSDF (a blend's mixture)."""
    kind = bi[b, BSDF_KIND]
    flip = bool(mask & F_TWOSIDED) and bool(bi[b, BSDF_TWOSIDED]) and wi[2] < 0.0
    if flip:
        wi = (wi[0], wi[1], -wi[2])
    fail = (0.0, 0.0, 1.0, False, False, 0.0, 0.0, 0.0, 0.0, 1.0, False)
    ci = wi[2]
    if mask & F_DIELECTRIC and kind == DIELECTRIC:
        eta = bf[b, ETA]
        r, cos_t, eta_it, eta_ti = fresnel_dielectric(ci, eta)
        if u0 <= r:
            c0, c1, c2 = color(mask, bf, btex, tex_data, tex_info, b, 0, u, v)
            w = 1.0 / pdf_scale
            return (-wi[0], -wi[1], wi[2], True, True, c0 * w, c1 * w, c2 * w, r * pdf_scale,
                    1.0, False)
        c0, c1, c2 = color(mask, bf, btex, tex_data, tex_info, b, 1, u, v)
        w = eta_ti * eta_ti / pdf_scale
        return (-eta_ti * wi[0], -eta_ti * wi[1], cos_t, True, True, c0 * w, c1 * w, c2 * w,
                (1.0 - r) * pdf_scale, eta_it, False)
    if mask & F_THINDIELECTRIC and kind == THINDIELECTRIC:
        # a thin slab: reflections between its two faces summed (R' = 2R / (1 + R)), the
        # rest goes straight through, unrefracted (Mitsuba's null component)
        r = fresnel_dielectric(abs(ci), bf[b, ETA])[0]
        r *= 2.0 / (1.0 + r)
        w = 1.0 / pdf_scale
        if u0 <= r:
            c0, c1, c2 = color(mask, bf, btex, tex_data, tex_info, b, 0, u, v)
            return (-wi[0], -wi[1], wi[2], True, True, c0 * w, c1 * w, c2 * w, r * pdf_scale,
                    1.0, False)
        c0, c1, c2 = color(mask, bf, btex, tex_data, tex_info, b, 1, u, v)
        return (-wi[0], -wi[1], -wi[2], True, True, c0 * w, c1 * w, c2 * w,
                (1.0 - r) * pdf_scale, 1.0, True)
    if mask & F_ROUGHDIELECTRIC and kind == ROUGHDIELECTRIC:
        if ci == 0.0:
            return fail
        wp = wi if ci > 0.0 else (-wi[0], -wi[1], -wi[2])
        m = sample_microfacet(wp, bf[b, ALPHA], bf[b, ALPHA_V], bi[b, BSDF_DISTRIBUTION],
                              u1, u2)
        wim = _dot(wi, m)
        if wim * ci <= 0.0:             # a back-facing normal (Beckmann's D cos θ_m): G1 = 0
            return fail
        f, cos_t, eta_it, eta_ti = fresnel_dielectric(wim, bf[b, ETA])
        if u0 <= f:
            wo = _reflect(wi, m)
            if wo[2] * ci <= 0.0:       # reflected through the surface: G1 = 0
                return fail
            return wo[0], wo[1], wo[2], True, False, 0.0, 0.0, 0.0, 0.0, 1.0, False
        c = wim * eta_ti + cos_t
        wo = (c * m[0] - eta_ti * wi[0], c * m[1] - eta_ti * wi[1], c * m[2] - eta_ti * wi[2])
        if wo[2] * ci >= 0.0:           # refracted back to the side it came from: G1 = 0
            return fail
        return wo[0], wo[1], wo[2], True, False, 0.0, 0.0, 0.0, 0.0, eta_it, False
    if ci <= 0.0:
        return fail
    if mask & F_CONDUCTOR and kind == CONDUCTOR:
        c0, c1, c2 = color(mask, bf, btex, tex_data, tex_info, b, 0, u, v)
        w = 1.0 / pdf_scale
        f0, f1, f2 = _conductor_fresnel(bf, b, ci)
        return (-wi[0], -wi[1], -ci if flip else ci, True, True, c0 * f0 * w, c1 * f1 * w,
                c2 * f2 * w, pdf_scale, 1.0, False)
    if mask & F_PLASTIC and kind == PLASTIC:
        f_i = fresnel_dielectric(ci, bf[b, ETA])[0]
        ps = _plastic_probs(bf, b, f_i)
        if u0 < ps:
            c0, c1, c2 = color(mask, bf, btex, tex_data, tex_info, b, 1, u, v)
            w = f_i / (ps * pdf_scale)
            return (-wi[0], -wi[1], -ci if flip else ci, True, True, c0 * w, c1 * w, c2 * w,
                    ps * pdf_scale, 1.0, False)
        wo = sample_cosine_hemisphere_kernel((u1, u2), (0.0,))
    elif mask & F_DIFFUSE and kind == DIFFUSE:
        wo = sample_cosine_hemisphere_kernel((u1, u2), (0.0,))
    elif mask & F_ROUGHCONDUCTOR and kind == ROUGHCONDUCTOR:
        m = sample_microfacet(wi, bf[b, ALPHA], bf[b, ALPHA_V], bi[b, BSDF_DISTRIBUTION],
                              u1, u2)
        wo = _reflect(wi, m)
    elif mask & F_ROUGHPLASTIC and kind == ROUGHPLASTIC:
        ps = _rough_plastic_probs(bf, b, ci)[0]
        if u0 < ps:
            alpha = bf[b, ALPHA]
            m = sample_microfacet(wi, alpha, alpha, bi[b, BSDF_DISTRIBUTION], u1, u2)
            wo = _reflect(wi, m)
        else:
            wo = sample_cosine_hemisphere_kernel((u1, u2), (0.0,))
    else:
        return fail
    if wo[2] <= 0.0:
        return fail
    return wo[0], wo[1], -wo[2] if flip else wo[2], True, False, 0.0, 0.0, 0.0, 0.0, 1.0, False


@fused(inline="always")
def bsdf_sample(mask, bf, bi, btex, tex_data, tex_info, b, wi, u0, u1, u2, u, v, pdf_scale):
    """(wo x, y, z, weight r, g, b, pdf, delta, η, null) with weight = f cos θ_o / pdf.
    A ``normalmap`` samples its BSDF in the perturbed frame; a direction on opposite
    sides of the two frames is dropped; the weight is scaled by ``shadow_terminator``
    (see ``_sample_unmapped`` for the rest)."""
    # the frame as nine floats: numba's parfor analysis rejects a tuple of tuples
    # that is rebound in a branch
    sx, sy, sz, tx, ty, tz, nx, ny, nz = 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0
    mapped, flip, shadowing = False, False, False
    if mask & F_NORMALMAP and bi[b, BSDF_KIND] == NORMALMAP:
        mapped = True
        flip = bool(bi[b, BSDF_TWOSIDED]) and wi[2] < 0.0
        if flip:
            wi = (wi[0], wi[1], -wi[2])
        (sx, sy, sz), (tx, ty, tz), (nx, ny, nz) = _normalmap_frame(
            bi, btex, tex_data, tex_info, b, wi, u, v)
        wi = (sx * wi[0] + sy * wi[1] + sz * wi[2], tx * wi[0] + ty * wi[1] + tz * wi[2],
              nx * wi[0] + ny * wi[1] + nz * wi[2])
        shadowing = bool(bi[b, NORMALMAP_SHADOWING])
        b = bi[b, BSDF_CHILD0]
    res = _sample_unmapped(mask, bf, bi, btex, tex_data, tex_info, b, wi, u0, u1, u2, u, v,
                           pdf_scale)
    if not mapped:
        return res
    (px, py, pz, wr, wg, wb, pdf, delta, eta, null) = res
    wx = sx * px + tx * py + nx * pz
    wy = sy * px + ty * py + ny * pz
    wz = sz * px + tz * py + nz * pz
    if pdf <= 0.0 or pz * wz <= 0.0:
        return 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, False, 1.0, False
    g = shadow_terminator((nx, ny, nz), (wx, wy, wz)) if shadowing else 1.0
    return wx, wy, -wz if flip else wz, wr * g, wg * g, wb * g, pdf, delta, eta, null


@fused(inline="always")
def _sample_unmapped(mask, bf, bi, btex, tex_data, tex_info, b, wi, u0, u1, u2, u, v,
                     pdf_scale):
    """``bsdf_sample`` of a row that is not a ``normalmap``. A zero weight ends the path;
    ``null``: the ray goes on unchanged (a ``mask``'s transparent part, a
    ``thindielectric``'s transmission), a delta event that Mitsuba counts as a bounce. ``pdf_scale`` is a test hook: a wrong pdf (not 1) must make the
    renderer biased, and the render gate must notice.

    A ``mask`` passes the ray through with probability 1 - opacity and otherwise samples
    its BSDF (pdf × opacity, weight unchanged); a ``blendbsdf`` picks one of its two by
    the weight and weighs the direction by the mixture (f / pdf of the blend)."""
    zero = (0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, False, 1.0, False)
    opacity = 1.0
    if mask & F_MASK and bi[b, BSDF_KIND] == MASK:
        opacity = _mix_value(mask, bf, btex, tex_data, tex_info, b, u, v)
        if not u0 < opacity:
            w = 1.0 / pdf_scale
            return (-wi[0], -wi[1], -wi[2], w, w, w, (1.0 - opacity) * pdf_scale, True, 1.0,
                    True)
        u0 = u0 / opacity
        b = bi[b, BSDF_CHILD0]
    row = b
    if mask & F_BLEND and bi[b, BSDF_KIND] == BLEND:
        w = _mix_value(mask, bf, btex, tex_data, tex_info, b, u, v)
        if u0 > w:
            row, u0 = bi[b, BSDF_CHILD0], (u0 - w) / (1.0 - w)
        else:
            row, u0 = bi[b, BSDF_CHILD1], u0 / w
    (wx, wy, wz, ok, delta, dr, dg, db, dpdf, eta, null) = _sample_basic(
        mask, bf, bi, btex, tex_data, tex_info, row, wi, u0, u1, u2, u, v, pdf_scale)
    if not ok:
        return zero
    if delta:
        return wx, wy, wz, dr, dg, db, dpdf * opacity, True, eta, null
    r, g, bl, pdf = _eval_mix(mask, bf, bi, btex, tex_data, tex_info, b, wi, (wx, wy, wz), u, v)
    if pdf <= 0.0:
        return zero
    pdf *= pdf_scale
    return wx, wy, wz, r / pdf, g / pdf, bl / pdf, pdf * opacity, False, eta, False


@_fast
def bsdf_is_smooth(bi, b):
    """Whether the BSDF has a non-delta component (so light sampling can help)."""
    k = bi[b, BSDF_KIND]
    if k == NORMALMAP:
        b = bi[b, BSDF_CHILD0]
        k = bi[b, BSDF_KIND]
    if k == MASK:
        k = bi[bi[b, BSDF_CHILD0], BSDF_KIND]
    return k != CONDUCTOR and k != DIELECTRIC and k != THINDIELECTRIC


# ------------------------------------------------------- rough plastic precomputation
def rough_coat_tables(alpha: float, dist: int, eta: float) -> tuple[np.ndarray, float]:
    """(external transmittance at cos θ_i = linspace(0, 1, 64), internal diffuse
    reflectance) of a rough dielectric coat, as Mitsuba's ``roughplastic`` defines them:
    transmittance is the visible-normal average of (1 - F) G1(refracted); the internal
    reflectance is 2 · mean over the same grid of R(μ; 1/η) μ (Mitsuba's Riemann sum, kept
    so that both renderers scale the base identically). Our own quadrature: Gauss–Legendre
    over the microfacet warp, 64 × 64 nodes."""
    mus = np.maximum(1e-6, np.linspace(0.0, 1.0, COAT_TABLE_RES))
    nodes, weights = np.polynomial.legendre.leggauss(64)
    x = 0.5 * (nodes + 1.0)
    w2 = np.outer(weights, weights).ravel() * 0.25
    ua, ub = (a.ravel() for a in np.meshgrid(x, x, indexing="ij"))
    trans = np.array([_coat_average(mu, alpha, dist, eta, ua, ub, w2, True) for mu in mus])
    refl = np.array([_coat_average(mu, alpha, dist, 1.0 / eta, ua, ub, w2, False)
                     for mu in mus])
    return trans, float(2.0 * np.mean(refl * mus))


@_jit
def _beckmann_g1_exact(v, alpha):
    s2 = v[0] * v[0] + v[1] * v[1]
    if s2 == 0.0:
        return 1.0
    a = v[2] / (alpha * math.sqrt(s2))
    lam = 0.5 * (math.erf(a) - 1.0) + math.exp(-a * a) / (2.0 * a * math.sqrt(math.pi))
    return 1.0 / (1.0 + lam)


@_jit
def _coat_average(mu, alpha, dist, eta, ua, ub, w2, transmit):
    """∫ over visible normals m (pdf D_wi(m)) of (1-F) G1(refracted) or F G1(reflected),
    by quadrature of the microfacet warp's unit square with the density ratio."""
    wi = (math.sqrt(max(0.0, 1.0 - mu * mu)), 0.0, mu)
    acc = 0.0
    for j in range(ua.shape[0]):
        m = sample_microfacet(wi, alpha, alpha, dist, ua[j], ub[j])
        wim = _dot(wi, m)
        if wim <= 0.0:
            continue
        d = microfacet_d(m, alpha, alpha, dist)
        if dist == GGX:
            ratio = 1.0          # the warp samples visible normals already
        else:
            # visible-normal density / warp density = G1 (wi·m) D / cos θ_i / (D cos θ_m),
            # normalised with the exact Beckmann G1 (the one Mitsuba's sampler draws from)
            ratio = _beckmann_g1_exact(wi, alpha) * wim / (mu * m[2]) if d > 0 else 0.0
        f, cos_t, eta_it, eta_ti = fresnel_dielectric(wim, eta)
        if transmit:
            c = wim * eta_ti + cos_t
            wo = (c * m[0] - wi[0] * eta_ti, c * m[1] - wi[1] * eta_ti,
                  c * m[2] - wi[2] * eta_ti)
            if wo[2] * wi[2] >= 0.0:
                continue
            acc += w2[j] * ratio * smith_g1(wo, m, alpha, alpha, dist) * (1.0 - f)
        else:
            wo = _reflect(wi, m)
            if wo[2] <= 0.0:
                continue
            acc += w2[j] * ratio * smith_g1(wo, m, alpha, alpha, dist) * f
    return acc
