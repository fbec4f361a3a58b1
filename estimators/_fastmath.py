"""Branch-free float64 ``exp``, ``expm1``, ``log``, ``log1p``, ``atan``, ``atan2``,
``acos`` and sin/cos of 2πu as numba scalar functions.

numba's LLVM has no vector math library (no SVML), so ``math.exp`` and its kin stay
scalar libm calls and a loop over points that calls one is not vectorised. These
versions use only arithmetic, integer bit operations and selects, so LLVM vectorises a
loop over them (``<4 x double>`` with AVX2, ``<8 x double>`` with 512-bit vectors;
tested). Every special case is a select, not a branch: ±0, subnormals, ±inf, NaN,
overflow and underflow (subnormal results included), log of a negative number (NaN).

The algorithms are fdlibm's (Sun, 1993; as in FreeBSD's and musl's libm), rewritten
without branches:

- ``exp``: x = k ln2 + r with k = round(x / ln2), ln2 in two parts (the high part has
  trailing zeros, so k·ln2_hi is exact) and |r| <= ln2/2; a degree-5 minimax polynomial
  R(r²) ≈ r (e^r + 1)/(e^r - 1) gives e^r = 1 + 2r/(R - r); the result is scaled by
  2^k as 2^⌊k/2⌋ · 2^(k-⌊k/2⌋), two normal powers of two, so results near overflow need
  no special case and a subnormal result is y rounded once more to its fewer bits.
- ``expm1``: the same reduction with the rounding error of r kept (c); a degree-5
  polynomial in r²/2 for e^r - 1 - r - r²/2; the cases k = 0, -1, 1, 2..56 and the rest
  each compose the result their own way to avoid cancellation (fdlibm's), all computed
  and the right one selected.
- ``log`` and ``log1p``: x = 2^k (1 + f) with √½ <= 1 + f < √2 (exponent and mantissa by
  bit operations, subnormals scaled by 2^54 first), then log(1 + f) = f - f²/2 + s(f²/2
  + R(s²)) with s = f / (2 + f) and R a degree-14 minimax polynomial (7 terms); log1p
  forms u = 1 + x and adds the rounding error of u as c = (x - (u - 1)) / u (or
  (1 - (u - x)) / u), so log1p(x) is accurate for tiny x; where 1 + x lies in [√½, √2)
  it takes f = x directly.

- ``atan`` and ``atan2``: fdlibm's ``s_atan.c`` reduction (around 0, ½, 1, 3/2, ∞) and
  polynomial, with the reduced argument formed from |y| and |x| themselves (numerator
  exact) and the division's rounding error added back (an exact two-product, one fused
  multiply-add), and
  π - atan for x < 0 rounded once from double-double constants: measured 0.75 ulp,
  where fdlibm's atan of the rounded y/x, then π - z, gives 1.4 ulp. atan2's special
  values (signed zeros, infinities, NaN) are C99's.
- ``acos``: fdlibm's ``e_acos.c`` (and musl's form for x < -½), not 2·atan2(√(1-x),
  √(1+x)): it needs one square root and a rational R(z) for asin √z where 2 atan2 needs
  two roots and the atan reduction, and it is accurate near ±1 by construction
  (z = (1 - |x|)/2 is exact there and acos = 2 asin √z has no cancellation).
- ``fast_sincos_2pi(u)``: sin and cos of 2πu, an angle given as a fraction of a turn
  (what every caller has: φ = 2πu of a sample, θ = πv of a texture coordinate); the
  quadrant reduction is exact, the remaining angle 2πd is a double-double, and fdlibm's
  ``k_sin.c`` / FreeBSD's ``k_cos.c`` kernels take its tail. No radian-argument sin/cos
  is provided: nothing calls one, and reducing a radian argument needs π/2 in three
  parts (fdlibm's ``__rem_pio2``) for what the turn form gets exactly.

fdlibm states an error below 1 ulp for each; ``tests/estimators/test_fastmath.py``
measures it against an extended-precision (80-bit ``np.longdouble``) reference over
dense log-uniform samples of the whole domain and its edges, and asserts <= 1 ulp.

Integers are float64 bits reinterpreted as int64 (``_bits``/``_from_bits``, an LLVM
``bitcast``); int64 <-> float64 conversions are done with the 2^52 trick (or the
exponent field into a float whose mantissa holds it) because AVX2 has no vector
int64 <-> double conversion and LLVM would not vectorise one.

numba caches a compiled function by its own file only: after editing this module alone,
the cached functions elsewhere that inline it are stale (``warps.py``'s, and the path
tracer's ``geometry.py``, ``textures.py`` and ``emitters.py``; the tracer's generated
kernels and the warps' front-end loops do hash this file): clear ``$MCVERIFY_CACHE``
and the numba index files in ``__pycache__``, or edit those files with it.

References: Sun Microsystems, fdlibm 5.3, ``e_exp.c``, ``s_expm1.c``, ``e_log.c``,
``s_log1p.c``, ``s_atan.c``, ``e_atan2.c``, ``e_acos.c``, ``k_sin.c`` (1993); FreeBSD
``k_cos.c`` (Bruce Evans' coefficients); T. J. Dekker, "A floating-point technique for
extending the available precision", Numer. Math. 18 (1971) (two-product); W. J. Cody, W. Waite, *Software Manual for the Elementary
Functions* (1980), ch. 5–6 (the two-part ln 2 reduction).
"""

from __future__ import annotations

import math

from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from ._compile_options import exact

#: IEEE division (no ZeroDivisionError check, whose branch would stop vectorisation; no
#: divisor here can be 0), and every rounding as written whoever calls first
#: (``_compile_options``). Helpers are small and LLVM inlines them.
_jit = exact()
#: The four functions are inlined into their callers by numba (LLVM's inliner keeps
#: ``fast_expm1``, the largest, as a call, and a call in a loop stops vectorisation); the
#: caller's error model then applies: compile callers with ``error_model="numpy"``.
_inline = exact(inline="always")


def _bitcast(src, dst, doc):
    """An intrinsic reinterpreting a ``src`` value's bits as ``dst`` (an LLVM bitcast)."""
    @intrinsic
    def cast(typingctx, x):
        if x != src:
            return None

        def codegen(context, builder, signature, args):
            return builder.bitcast(args[0], context.get_value_type(dst))

        return dst(src), codegen

    cast.__doc__ = doc
    return cast


@intrinsic
def _fma(typingctx, a, b, c):
    """a·b + c rounded once (LLVM's ``llvm.fma.f64``: one instruction on x86-64 with
    FMA; elsewhere LLVM calls the C library's ``fma``, as exact and slower)."""
    if not (a == b == c == types.float64):
        return None

    def codegen(context, builder, signature, args):
        d = ir.DoubleType()
        fn = builder.module.declare_intrinsic("llvm.fma", [d], ir.FunctionType(d, [d, d, d]))
        return builder.call(fn, args)

    return types.float64(types.float64, types.float64, types.float64), codegen


_bits = _bitcast(types.float64, types.int64, "The IEEE-754 bits of a float64 as int64.")
_from_bits = _bitcast(types.int64, types.float64, "The float64 whose bits are the int64.")


_INF = float("inf")
_NAN = float("nan")
_LN2_HI = 6.93147180369123816490e-01    # 0x3fe62e42fee00000: trailing zeros, k·_LN2_HI exact
_LN2_LO = 1.90821492927058770002e-10    # ln 2 - _LN2_HI
_INV_LN2 = 1.44269504088896338700e+00
_TWO52 = 4503599627370496.0             # 2^52
_TWO54 = 18014398509481984.0            # 2^54
_TWO_M53 = 1.1102230246251565e-16       # 2^-53
_TWO_M54 = 5.551115123125783e-17        # 2^-54
_EXP_OVERFLOW = 7.09782712893383973096e+02      # above: exp(x) = inf
_EXP_UNDERFLOW = -7.45133219101941108420e+02    # below: exp(x) = 0
_MIN_NORMAL = 2.2250738585072014e-308

# exp: R(t) ≈ r·(e^r + 1)/(e^r − 1) − 2 on |r| <= ln2/2, t = r², error < 2^-59 (fdlibm)
_P1 = 1.66666666666666019037e-01
_P2 = -2.77777777770155933842e-03
_P3 = 6.61375632143793436117e-05
_P4 = -1.65339022054652515390e-06
_P5 = 4.13813679705723846039e-08

# expm1: the rational correction on |r| <= ln2/2 in r²/2, error < 2^-61 (fdlibm)
_Q1 = -3.33333333333331316428e-02
_Q2 = 1.58730158725481460165e-03
_Q3 = -7.93650757867487942473e-05
_Q4 = 4.00821782732936239552e-06
_Q5 = -2.01099218183624371326e-07

# log: R(z) ≈ (log(1+s) - log(1-s) - 2s)/s on s² = z <= 0.0294, error < 2^-58.45 (fdlibm)
_LG1 = 6.666666666666735130e-01
_LG2 = 3.999999999940941908e-01
_LG3 = 2.857142874366239149e-01
_LG4 = 2.222219843214978396e-01
_LG5 = 1.818357216161805012e-01
_LG6 = 1.531383769920937332e-01
_LG7 = 1.479819860511658591e-01

# The high word of √½ (0x3fe6a09e667f3bcd): adding 0x3ff00000 - this to the high word
# carries into the exponent exactly when the mantissa is >= √2's.
_SQRT_HALF_HI = 0x3FE6A09E
_HI_SHIFT = (0x3FF00000 - _SQRT_HALF_HI) << 32
_MANT_HI_MASK = 0x000FFFFF00000000
_LOW_WORD = 0xFFFFFFFF
_EXP_MASK = 0x7FF


@_jit
def _pow2(k):
    """2^k for an integer-valued float64 k in [-1022, 1023], built from its bits: k +
    2^52 + 1023 holds k + 1023 in its low mantissa bits, shifted into the exponent."""
    return _from_bits(_bits(k + (_TWO52 + 1023.0)) << 52)


@_jit
def _exponent(field):
    """The int64 ``field`` (0..2047) as float64, without an int -> float conversion."""
    return _from_bits(_bits(_TWO52) | (field & _EXP_MASK)) - _TWO52


@_jit
def _round(x):
    """x rounded to the nearest integer (ties to even) for |x| < 2^51."""
    magic = 1.5 * _TWO52
    return (x + magic) - magic


@_jit
def _scale(y, k):
    """y · 2^k for integer-valued k in [-2044, 2046], rounded once: as two factors
    2^(k//2) and 2^(k - k//2), each a normal number."""
    half = _round(0.5 * k - 0.25)      # ⌊k/2⌋ for integer k
    return y * _pow2(half) * _pow2(k - half)


@_inline
def fast_exp(x):
    """e^x, branch-free; error < 1 ulp (fdlibm's ``e_exp.c``)."""
    xc = min(max(x, -746.0), 710.0)          # keeps k in range; the selects below decide
    k = _round(xc * _INV_LN2)
    hi = xc - k * _LN2_HI
    lo = k * _LN2_LO
    r = hi - lo
    t = r * r
    c = r - t * (_P1 + t * (_P2 + t * (_P3 + t * (_P4 + t * _P5))))
    y = 1.0 - ((lo - (r * c) / (2.0 - c)) - hi)
    y = _scale(y, k)
    y = 0.0 if x < _EXP_UNDERFLOW else y
    y = _INF if x > _EXP_OVERFLOW else y
    return x if x != x else y


@_inline
def fast_expm1(x):
    """e^x - 1, accurate near 0, branch-free; error < 1 ulp (fdlibm's ``s_expm1.c``)."""
    xc = min(max(x, -50.0), 710.0)
    k = _round(xc * _INV_LN2)
    hi = xc - k * _LN2_HI
    lo = k * _LN2_LO
    r = hi - lo
    c = (hi - r) - lo                         # the rounding error of r
    hfx = 0.5 * r
    hxs = r * hfx
    r1 = 1.0 + hxs * (_Q1 + hxs * (_Q2 + hxs * (_Q3 + hxs * (_Q4 + hxs * _Q5))))
    t = 3.0 - r1 * hfx
    e = hxs * ((r1 - t) / (6.0 - r * t))
    y0 = r - (r * e - hxs)                   # k = 0: c = 0 there
    e = r * (e - c) - c
    e -= hxs
    ym1 = 0.5 * (r - e) - 0.5                # k = -1
    y1_neg = -2.0 * (e - (r + 0.5))         # k = 1, r < -1/4
    y1_pos = 1.0 + 2.0 * (r - e)             # k = 1, r >= -1/4
    y1 = y1_neg if r < -0.25 else y1_pos
    ybig = _scale(1.0 - (e - r), k) - 1.0      # k <= -2 or k > 56
    uf = _pow2(-min(max(k, 0.0), 60.0))      # 2^-k for 2 <= k <= 56
    two_k = _pow2(min(max(k, -60.0), 60.0))
    ylow = ((1.0 - uf) - (e - r)) * two_k      # 2 <= k < 20
    ymid = (r - (e + uf) + 1.0) * two_k      # 20 <= k <= 56
    y = ymid if k >= 20.0 else ylow
    y = ybig if (k <= -2.0) | (k > 56.0) else y
    y = y1 if k == 1.0 else y
    y = ym1 if k == -1.0 else y
    y = y0 if k == 0.0 else y
    y = -1.0 if x < -38.816242111356935 else y       # x < -56 ln2: e^x - 1 rounds to -1
    y = _INF if x > _EXP_OVERFLOW else y
    return x if (x != x) | (abs(x) < _TWO_M54) else y   # NaN, ±0, tiny x: x itself


@_jit
def _log1p_f(f, k, c):
    """k ln2 + log(1 + f) + c for √½ <= 1 + f < √2 (k, a float64 integer; c, a small
    correction): fdlibm's polynomial in s = f / (2 + f)."""
    hfsq = 0.5 * f * f
    s = f / (2.0 + f)
    z = s * s
    w = z * z
    t1 = w * (_LG2 + w * (_LG4 + w * _LG6))
    t2 = z * (_LG1 + w * (_LG3 + w * (_LG5 + w * _LG7)))
    return s * (hfsq + (t2 + t1)) + (k * _LN2_LO + c) - hfsq + f + k * _LN2_HI


@_jit
def _reduce(u):
    """(f, k) with u = 2^k (1 + f), √½ <= 1 + f < √2, for a positive normal u."""
    ix = _bits(u) + _HI_SHIFT
    k = _exponent(ix >> 52) - 1023.0
    ix = ((ix & _MANT_HI_MASK) + (_SQRT_HALF_HI << 32)) | (_bits(u) & _LOW_WORD)
    return _from_bits(ix) - 1.0, k


@_inline
def fast_log(x):
    """Natural logarithm, branch-free; error < 1 ulp (fdlibm's ``e_log.c``)."""
    sub = x < _MIN_NORMAL
    xs = x * _TWO54 if sub else x             # subnormals (and the rest, discarded) scaled
    f, k = _reduce(xs)
    k = k - 54.0 if sub else k
    y = _log1p_f(f, k, 0.0)
    y = _NAN if x < 0.0 else y
    y = -_INF if x == 0.0 else y
    y = x if (x != x) | (x == _INF) else y
    return y


@_inline
def fast_log1p(x):
    """log(1 + x), accurate near 0, branch-free; error < 1 ulp (fdlibm's ``s_log1p.c``)."""
    u = 1.0 + x
    uc = min(max(u, _MIN_NORMAL), 1.7976931348623157e308)   # inf, NaN, <= 0: selected below
    f, k = _reduce(uc)
    # c: the rounding error of u = 1 + x over u; log(1 + x) = log u + c to first order
    c = (1.0 - (uc - x) if k >= 2.0 else x - (uc - 1.0)) / uc
    c = 0.0 if k >= 54.0 else c
    direct = k == 0.0                          # √½ <= 1 + x < √2: f = x exactly
    f = x if direct else f
    c = 0.0 if direct else c
    y = _log1p_f(f, k, c)
    y = _NAN if x < -1.0 else y
    y = -_INF if x == -1.0 else y
    return x if (x != x) | (x == _INF) | (abs(x) < _TWO_M53) else y



# ------------------------------------------------------------------ atan, atan2, acos
# atan: the odd polynomial on |t| <= 7/16, atan(t) = t - t·(s1 + s2) with s1, s2 its even
# and odd parts in t²; error < 2^-57 relative (fdlibm's s_atan.c)
_AT0 = 3.33333333333329318027e-01
_AT1 = -1.99999999998764832476e-01
_AT2 = 1.42857142725034663711e-01
_AT3 = -1.11111104054623557880e-01
_AT4 = 9.09088713343650656196e-02
_AT5 = -7.69187620504482999495e-02
_AT6 = 6.66107313738753120669e-02
_AT7 = -5.83357013379057348645e-02
_AT8 = 4.97687799461593236017e-02
_AT9 = -3.65315727442169155270e-02
_AT10 = 1.62858201153657823623e-02
# atan(1/2), atan(1), atan(3/2), atan(inf) = π/2, each as hi + lo (fdlibm's atanhi/atanlo)
_ATAN_HALF_HI = 4.63647609000806093515e-01
_ATAN_HALF_LO = 2.26987774529616870924e-17
_ATAN_ONE_HI = 7.85398163397448278999e-01
_ATAN_ONE_LO = 3.06161699786838301793e-17
_ATAN_THREE_HALVES_HI = 9.82793723247329054082e-01
_ATAN_THREE_HALVES_LO = 1.39033110312309984516e-17
_PI_2_HI = 1.57079632679489655800e+00
_PI_2_LO = 6.12323399573676603587e-17
_PI_HI = 3.14159265358979311600e+00
_PI_LO = 1.22464679914735317720e-16      # π - _PI_HI
# π - atan(1/2), π - π/4, π - atan(3/2) as hi + lo: (_PI_HI + _PI_LO) - (hi + lo) above
_PI_MINUS_HALF_HI = 2.677945044588987
_PI_MINUS_HALF_LO = 1.5527705369303147e-16
_PI_MINUS_ONE_HI = 2.356194490192345
_PI_MINUS_ONE_LO = 9.184850993605148e-17
_PI_MINUS_THREE_HALVES_HI = 2.158798930342464
_PI_MINUS_THREE_HALVES_LO = 2.1958367134601997e-16
_TWO_960 = 2.0 ** 960
_TWO_M400 = 2.0 ** -400
_TWO_M500 = 2.0 ** -500
@_jit
def _residual(n, x, d):
    """n - x·d with x = fl(n / d): the product x·d as hi + lo exactly (lo by one fused
    multiply-add), n - hi exact (Sterbenz: hi is within an ulp or two
    of n), one rounding in all."""
    hi = x * d
    return (n - hi) - _fma(x, d, -hi)


@_inline
def _atan_ratio(a, b, reflect):
    """atan(a / b) in [0, π/2], or π - atan(a / b) if ``reflect``, for a, b >= 0
    (finite, scaled so that 3·max(a, b) does not overflow and a normal max(a, b) is far
    above the subnormals): fdlibm's
    reduction of t = a/b to |x| <= 7/16 around 0, 1/2, 1, 3/2 or ∞, but with x formed
    from a and b, not from the rounded t, so that its numerator is exact (Sterbenz;
    3b as the two-sum 2b + b):

        t < 7/16:          x = a/b                      atan t = atan x
        7/16 <= t < 11/16: x = (2a - b)/(2b + a)        atan t = atan ½ + atan x
        11/16 <= t < 19/16: x = (a - b)/(a + b)         atan t = π/4 + atan x
        19/16 <= t < 39/16: x = (2a - 3b)/(2b + 3a)     atan t = atan 3/2 + atan x
        t >= 39/16:         x = -b/a                    atan t = π/2 + atan x

    Each case's numerator and denominator are selected, then one division, whose
    rounding error e = (num - x·den)/den (x·den exact as a two-product) is added back,
    and one polynomial: atan(x + e) = atan x + e to the precision kept. Inlined by
    numba (LLVM's inliner would keep it as a call, which stops vectorisation), so no
    divisor may be 0: a caller compiled with numba's default error model would raise
    ZeroDivisionError. The class boundaries are compared as a against b·c (b·11/16 and
    b·19/16 may round: a boundary moved by an ulp leaves |x| within the polynomial's
    range). The sum c + atan x is formed as fdlibm's hi - ((x·R - lo) - x), with
    c = hi + lo; reflected, π - c (exactly rounded pairs) and -x: one rounding of a
    small tail onto the head."""
    id0 = a >= 0.4375 * b
    id1 = a >= 0.6875 * b
    id2 = a >= 1.1875 * b
    id3 = a >= 2.4375 * b
    three_b = 2.0 * b + b
    three_b_lo = (2.0 * b - three_b) + b          # 3b = three_b + three_b_lo exactly
    num = a
    den = b
    num = 2.0 * a - b if id0 else num
    den = 2.0 * b + a if id0 else den
    num = a - b if id1 else num
    den = a + b if id1 else den
    num = (2.0 * a - three_b) - three_b_lo if id2 else num
    den = 2.0 * b + 3.0 * a if id2 else den
    num = -b if id3 else num
    den = a if id3 else den
    den = max(den, _MIN_NORMAL)                   # a = b = 0 (selected away by atan2)
    x = num / den
    e = _residual(num, x, den) / den              # the division's rounding error
    e = e if abs(x) > _TWO_M500 else 0.0          # (its low parts would be subnormal)
    z = x * x
    w = z * z
    s1 = z * (_AT0 + w * (_AT2 + w * (_AT4 + w * (_AT6 + w * (_AT8 + w * _AT10)))))
    s2 = w * (_AT1 + w * (_AT3 + w * (_AT5 + w * (_AT7 + w * _AT9))))
    p = x * (s1 + s2) - e
    # π - atan t = (π - c) - atan x: the same sum with x, p negated and c's pair replaced
    hi = _ATAN_HALF_HI if id0 else 0.0
    lo = _ATAN_HALF_LO if id0 else 0.0
    hi = _ATAN_ONE_HI if id1 else hi
    lo = _ATAN_ONE_LO if id1 else lo
    hi = _ATAN_THREE_HALVES_HI if id2 else hi
    lo = _ATAN_THREE_HALVES_LO if id2 else lo
    hi = _PI_2_HI if id3 else hi
    lo = _PI_2_LO if id3 else lo
    nhi = _PI_MINUS_HALF_HI if id0 else _PI_HI
    nlo = _PI_MINUS_HALF_LO if id0 else _PI_LO
    nhi = _PI_MINUS_ONE_HI if id1 else nhi
    nlo = _PI_MINUS_ONE_LO if id1 else nlo
    nhi = _PI_MINUS_THREE_HALVES_HI if id2 else nhi
    nlo = _PI_MINUS_THREE_HALVES_LO if id2 else nlo
    nhi = _PI_2_HI if id3 else nhi
    nlo = _PI_2_LO if id3 else nlo
    hi = nhi if reflect else hi
    lo = nlo if reflect else lo
    x = -x if reflect else x
    p = -p if reflect else p
    return hi - ((p - lo) - x)


@_inline
def fast_atan2(y, x):
    """The angle of the point (x, y) in [-π, π], branch-free; as C99's ``atan2`` on
    every special value (the signs of zeros, infinities, NaN). atan(|y| / |x|) by
    ``_atan_ratio`` on |x|, |y| scaled by a power of two (exact) when the larger is
    above 2^960 or below 2^-400, placed in its quadrant: π - atan(|y| / |x|) where
    x < 0 (-0 included), formed inside ``_atan_ratio`` so that it is rounded once,
    negated where y < 0."""
    ay = abs(y)
    ax = abs(x)
    m = max(ax, ay)
    s = 2.0 ** -64 if m > _TWO_960 else 1.0
    s = 2.0 ** 600 if m < _TWO_M400 else s
    x_neg = _bits(x) < 0                          # the sign bit: -0 counts as negative
    y_neg = _bits(y) < 0
    r = _atan_ratio(ay * s, ax * s, x_neg)
    both_zero = (ay == 0.0) & (ax == 0.0)
    r = (_PI_HI if x_neg else 0.0) if both_zero else r
    both_inf = (ay == _INF) & (ax == _INF)
    r = (3.0 * 0.7853981633974483 if x_neg else 0.7853981633974483) if both_inf else r
    r = -r if y_neg else r
    return x + y if (x != x) | (y != y) else r


@_inline
def fast_atan(t):
    """atan(t) in [-π/2, π/2], branch-free: ``_atan_ratio(|t|, 1)`` with t's sign
    (fdlibm's ``s_atan.c``, whose reduction it is)."""
    at = abs(t)
    z = _atan_ratio(min(at, 1e300), 1.0, False)
    z = _PI_2_HI if at == _INF else z
    z = -z if _bits(t) < 0 else z
    return t if t != t else z


# acos: R(z) = p(z)/q(z) ≈ (asin(√z) - √z)/√z on z <= 1/4, error < 2^-58.75 (fdlibm)
_PS0 = 1.66666666666666657415e-01
_PS1 = -3.25565818622400915405e-01
_PS2 = 2.01212532134862925881e-01
_PS3 = -4.00555345006794114027e-02
_PS4 = 7.91534994289814532176e-04
_PS5 = 3.47933107596021167570e-05
_QS1 = -2.40339491173441421878e+00
_QS2 = 2.02094576023350569471e+00
_QS3 = -6.88283971605453293030e-01
_QS4 = 7.70381505559019352791e-02
_HIGH_WORD = -4294967296                        # 0xFFFFFFFF00000000 as int64


@_inline
def fast_acos(x):
    """arccos x in [0, π], branch-free; error < 1 ulp (fdlibm's ``e_acos.c``): for
    |x| < ½, π/2 - (x + x·R(x²)); for |x| >= ½, z = (1 - |x|)/2 (exact: Sterbenz) and
    s = √z, so acos|x| = 2 asin √z = 2(s + s·R(z)) with no cancellation near ±1;
    for x > ½ s is split into a 32-bit head and a correction (z - head²)/(s + head),
    for x < -½ the result is 2(π/2 - (s + s·R(z))) (musl's form). All three are computed, one selected.
    ±1 give 0 and π exactly, |x| > 1 and NaN give NaN."""
    ax = abs(x)
    small = ax < 0.5
    z = x * x if small else (1.0 - ax) * 0.5
    p = z * (_PS0 + z * (_PS1 + z * (_PS2 + z * (_PS3 + z * (_PS4 + z * _PS5)))))
    q = 1.0 + z * (_QS1 + z * (_QS2 + z * (_QS3 + z * _QS4)))
    r = p / q
    s = math.sqrt(z)
    y_small = _PI_2_HI - (x - (_PI_2_LO - x * r))
    y_neg = 2.0 * (_PI_2_HI - (s + (r * s - _PI_2_LO)))
    df = _from_bits(_bits(s) & _HIGH_WORD)
    c = (z - df * df) / max(s + df, _MIN_NORMAL)  # 0 at x = 1, not 0/0: callers compiled
    #                                                   with numba's default error model
    #                                                   would raise ZeroDivisionError
    y_pos = 2.0 * (df + (r * s + c))
    y = y_neg if x < 0.0 else y_pos
    y = y_small if small else y
    y = 0.0 if x == 1.0 else y
    y = _PI_HI if x == -1.0 else y
    return _NAN if (ax > 1.0) | (x != x) else y


# ------------------------------------------------------------------------ sin, cos
# sin x ≈ x + x³·(S1 + x²·R(x²)) and cos x ≈ 1 - x²/2 + x⁴·C(x²) on |x| <= π/4, error
# < 2^-58 relative (fdlibm's k_sin.c; FreeBSD's k_cos.c, whose C is more accurate)
_S1 = -1.66666666666666324348e-01
_S2 = 8.33333333332248946124e-03
_S3 = -1.98412698298579493134e-04
_S4 = 2.75573137070700676789e-06
_S5 = -2.50507602534068634195e-08
_S6 = 1.58969099521155010221e-10
_C1 = 4.16666666666666019037e-02
_C2 = -1.38888888888741095749e-03
_C3 = 2.48015872894767294178e-05
_C4 = -2.75573143513906633035e-07
_C5 = 2.08757232129817482790e-09
_C6 = -1.13596475577881948265e-11
_TWO_PI_HI = 6.283185307179586                  # fl(2π)
_TWO_PI_LO = 2.4492935982947064e-16             # 2π - fl(2π)
_TWO_M900 = 2.0 ** -900


@_jit
def sincos_reduced(x, y):
    """(sin, cos) of x + y for |x + y| <= π/4, y a tail below half an ulp of x (0 when
    x is exact): fdlibm's kernels ``__kernel_sin(x, y, 1)`` and ``__kernel_cos(x, y)``,
    each < 1 ulp; cos as w + ((1 - w) - x²/2 + ...) with w = 1 - x²/2, so that its
    rounding is kept."""
    z = x * x
    w = z * z
    r = _S2 + z * (_S3 + z * _S4) + z * w * (_S5 + z * _S6)
    v = z * x
    sin = x - ((z * (0.5 * y - v * r) - y) - v * _S1)
    rc = z * (_C1 + z * (_C2 + z * _C3)) + w * w * (_C4 + z * (_C5 + z * _C6))
    hz = 0.5 * z
    wc = 1.0 - hz
    cos = wc + (((1.0 - wc) - hz) + (z * rc - x * y))
    return sin, cos


@_inline
def fast_sincos_2pi(u):
    """(sin 2πu, cos 2πu) for |u| <= 2^50, branch-free, each within 1 ulp of the exact
    value (tested): the quadrant q = round(4u), the remainder d = u - q/4 in [-1/8, 1/8]
    (exact, Sterbenz), the angle 2πd as hi + lo (2π in two parts, the product's error
    by a fused multiply-add; not renormalised, |lo| stays near half
    an ulp of hi, as fdlibm's kernels allow), ``sincos_reduced`` at it, rotated by
    q·π/2 with selects. The argument is a fraction of a turn, not an
    angle: π·v is ``fast_sincos_2pi(0.5 * v)`` (exact halving), with no rounding of
    the angle, so sin π = 0 exactly and sin 2πu near its zeros keeps its relative
    precision, which libm's sin of a rounded 2πu does not."""
    q = math.floor(4.0 * u + 0.5)
    d = u - 0.25 * q
    q = q - 4.0 * math.floor(0.25 * q)            # the quadrant mod 4 (u outside [0, 1))
    hi = _TWO_PI_HI * d
    lo = _fma(_TWO_PI_HI, d, -hi) + d * _TWO_PI_LO   # the product's error, 2π's own
    lo = lo if abs(d) > _TWO_M900 else 0.0        # else its parts would be subnormal
    s, c = sincos_reduced(hi, lo)
    odd = (q == 1.0) | (q == 3.0)
    sin = c if odd else s
    cos = s if odd else c
    flip_sin = (q == 2.0) | (q == 3.0)            # sin < 0 in quadrants 2 and 3
    flip_cos = (q == 1.0) | (q == 2.0)            # cos < 0 in quadrants 1 and 2
    return (-sin if flip_sin else sin), (-cos if flip_cos else cos)


# ------------------------------------------- angles for texture coordinates (1e-10)
# Least-squares fits on 40,001 Chebyshev nodes of [0, 1] (numpy ``lstsq``): atan t / t
# as a polynomial in t² (degree 11) and acos x / √(1 - x) in x (degree 10). Their
# errors, measured on 4·10⁶ points of [0, 1], are at most 5.2e-11 and 8.0e-11
# absolute, and 5.1e-11 relative for acos (tested).
_ATAN_POLY = (0.9999999999775722, -0.3333333207917994, 0.19999928193125643,
              -0.14284198620626296, 0.1109481233774139, -0.08987010437234337,
              0.07264204803564145, -0.05460689553772921, 0.034586083791286394,
              -0.016381885369403704, 0.004961077257035968, -0.0007042587470986315)
_ACOS_POLY = (1.5707963267151788, -0.21460181664222042, 0.08904779002026471,
              -0.05077912361181552, 0.03356400905713734, -0.023774524053216194,
              0.01668944339214201, -0.010418516134319574, 0.005045564778472674,
              -0.001593420415132375, 0.0002378293253944716)


@_inline
def _horner(c, x):
    r = c[len(c) - 1]
    for k in range(len(c) - 2, -1, -1):
        r = r * x + c[k]
    return r


@_inline
def coarse_atan2(y, x):
    """atan2(y, x) in [-π, π] within 1e-10 absolute (5.2e-11 measured), for the angles
    of texture coordinates, where the fdlibm-grade ``fast_atan2`` costs more than the
    lookup needs: t = min(|x|, |y|) / max(|x|, |y|), atan t = t·P(t²), placed in its
    octant. One division and a polynomial (an envmap's (u, v) of a direction went from
    32 to 13 ns a call, one thread). Zeros, infinities and NaN as C99's ``atan2``."""
    ay = abs(y)
    ax = abs(x)
    mx = max(ax, ay)
    mn = min(ax, ay)
    s = 2.0 ** -64 if mx > _TWO_960 else 1.0
    s = 2.0 ** 600 if mx < _TWO_M400 else s
    t = (mn * s) / max(mx * s, _MIN_NORMAL)
    t = 1.0 if mn == mx else t                    # both infinite (inf / inf)
    t = 0.0 if mx == 0.0 else t
    a = t * _horner(_ATAN_POLY, t * t)
    a = _PI_2_HI - a if ay > ax else a
    a = _PI_HI - a if _bits(x) < 0 else a         # x < 0, -0 included
    a = -a if _bits(y) < 0 else a
    return x + y if (x != x) | (y != y) else a


@_inline
def coarse_acos(x):
    """arccos x in [0, π] within 1e-10 absolute and relative (8.0e-11, 5.1e-11
    measured): √(1 - |x|)·P(|x|), reflected for x < 0; the texture-coordinate
    counterpart of ``fast_acos``. ±1 give 0 and π exactly, |x| > 1 and NaN give NaN."""
    ax = abs(x)
    r = math.sqrt(max(1.0 - ax, 0.0)) * _horner(_ACOS_POLY, ax)
    r = _PI_HI - r if x < 0.0 else r
    return _NAN if (ax > 1.0) | (x != x) else r
