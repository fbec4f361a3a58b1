"""Branch-free float64 ``exp``, ``expm1``, ``log``, ``log1p`` as numba scalar functions.

numba's LLVM has no vector math library (no SVML), so ``math.exp`` and its kin stay
scalar libm calls and a loop over points that calls one is not vectorised. These
versions use only arithmetic, integer bit operations and selects, so LLVM vectorises a
loop over them (``<4 x double>`` with AVX2; tested). Every special case is a select, not
a branch: ±0, subnormals, ±inf, NaN, overflow and underflow (subnormal results
included), log of a negative number (NaN).

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

fdlibm states an error below 1 ulp for each; ``tests/estimators/test_fastmath.py``
measures it against an extended-precision (80-bit ``np.longdouble``) reference over
dense log-uniform samples of the whole domain and its edges, and asserts <= 1 ulp.

Integers are float64 bits reinterpreted as int64 (``_bits``/``_from_bits``, an LLVM
``bitcast``); int64 <-> float64 conversions are done with the 2^52 trick (or the
exponent field into a float whose mantissa holds it) because AVX2 has no vector
int64 <-> double conversion and LLVM would not vectorise one.

numba caches a compiled function by its own file only: after editing this module alone,
the cached kernels that inline it are stale (``warps.py``'s, and the path tracer's,
whose generated kernels hash ``warps.py`` but not this file; the warps' front-end loops
do hash it): clear ``$MCVERIFY_CACHE`` and the numba index files in ``__pycache__``, or
edit ``warps.py`` with it.

References: Sun Microsystems, fdlibm 5.3, ``e_exp.c``, ``s_expm1.c``, ``e_log.c``,
``s_log1p.c`` (1993); W. J. Cody, W. Waite, *Software Manual for the Elementary
Functions* (1980), ch. 5–6 (the two-part ln 2 reduction).
"""

from __future__ import annotations

from numba import njit, types
from numba.extending import intrinsic

#: IEEE division (no ZeroDivisionError check, whose branch would stop vectorisation; no
#: divisor here can be 0). Helpers are small and LLVM inlines them.
_jit = njit(cache=True, error_model="numpy")
#: The four functions are inlined into their callers by numba (LLVM's inliner keeps
#: ``fast_expm1``, the largest, as a call, and a call in a loop stops vectorisation); the
#: caller's error model then applies: compile callers with ``error_model="numpy"``.
_inline = njit(cache=True, error_model="numpy", inline="always")


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

