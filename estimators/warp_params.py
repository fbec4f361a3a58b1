"""What each warp's parameters may be: how many, their names, and the values the warp is
defined for. The array front ends (``_vectorize``) check them on every call, before any
point is computed: a kernel reads its parameters by position, so a missing one was read
past the end of its array (``sample_ggx(u)`` sampled α = 0), and a value outside the
warp's definition gave plausible numbers (a negative α, a cone of cos θ_max = 1.5).

These are the warps' definitions, not the ranges the property tests draw from (those are
``warps.WARPS[name].ranges``, inside these).
"""

from __future__ import annotations

import math
import numbers

import numpy as np

#: The microfacet warps' roughness range. Their kernels square α (GGX's density, α⁴):
#: beyond about 1e77 or below 1e-77 that over- or underflows, and the warps gave a zero
#: vector of density 0 (α = 1e160) or an infinite density (GGX at α = 1e-100) without a
#: word. Inside the range every sample is a unit vector of finite positive density and
#: inverts to its u within 4e-16 (measured at the ends, 1e5 points each).
_ALPHA_MIN, _ALPHA_MAX = 1e-30, 1e30

#: name -> (parameter names, condition on their values, the condition in words).
RULES = {
    # b - a >= 2^-1022 (normal): a = 0, b = 5e-324 put every point at a, of density inf
    "uniform_interval": (("a", "b"), lambda a, b: a < b and math.isfinite(b - a)
                         and b - a >= 2.0 ** -1022,
                         "a < b with b - a finite and at least 2^-1022"),
    "uniform_cone": (("cos_theta_max",), lambda c: -1.0 <= c < 1.0,
                     "-1 <= cos_theta_max < 1"),
    "power_cosine": (("n",), lambda n: n >= 0.0, "n >= 0"),
    "ggx": (("alpha",), lambda a: _ALPHA_MIN <= a <= _ALPHA_MAX, "1e-30 <= alpha <= 1e30"),
    "beckmann": (("alpha",), lambda a: _ALPHA_MIN <= a <= _ALPHA_MAX,
                 "1e-30 <= alpha <= 1e30"),
    "ggx_vndf": (("alpha", "wx", "wy", "wz"),
                 lambda a, x, y, z: _ALPHA_MIN <= a <= _ALPHA_MAX and z > 0.0
                 and abs(x * x + y * y + z * z - 1.0) <= 1e-6,
                 "1e-30 <= alpha <= 1e30 and (wx, wy, wz) a unit vector with wz > 0"),
    # σ·t below 1e-150 is uniform on [0, t] to 1e-150 (and -expm1(-σt) underflowed:
    # every sample 0, its density inf); σ below 1e-150 sends far samples past float64
    "exponential": (("sigma", "t_max"),
                    lambda s, t: s >= 1e-150 and t > 0.0 and s * t >= 1e-150,
                    "sigma >= 1e-150, t_max > 0 and sigma·t_max >= 1e-150"),
    # r >= 2^-1022 (normal), as the interval's width: r = 1e-310 gave every point a
    # density of 1 / r = inf
    "tent": (("radius",), lambda r: r >= 2.0 ** -1022, "radius >= 2^-1022"),
    "linear": (("a", "b"), lambda a, b: a >= 0.0 and b >= 0.0 and a + b > 0.0,
               "a >= 0 and b >= 0, not both 0"),
    "bilinear": (("w00", "w10", "w01", "w11"),
                 lambda *w: min(w) >= 0.0 and sum(w) > 0.0, "every w >= 0, not all 0"),
}
#: Parameters that may be +inf (an exponential without a far end).
_MAY_BE_INFINITE = {"t_max"}


def warp_of(front_name: str) -> str:
    """The warp a front end belongs to: ``sample_X``, ``sample_X.with_pdf``, ``X_pdf``
    and ``invert_X`` -> X."""
    front_name = front_name.removesuffix(".with_pdf")
    for prefix in ("sample_", "invert_"):
        if front_name.startswith(prefix):
            return front_name[len(prefix):]
    return front_name[:-len("_pdf")] if front_name.endswith("_pdf") else front_name


def param_count(front_name: str) -> int:
    """How many parameters the front end ``front_name`` takes."""
    return len(RULES.get(warp_of(front_name), ((),))[0])


def check_params(front_name: str, params: tuple) -> np.ndarray:
    """``params`` of the front end ``front_name`` as the float64 array its kernel reads,
    or ValueError naming the parameter and what it must be."""
    warp = warp_of(front_name)
    names, condition, words = RULES.get(warp, ((), None, ""))
    if len(params) != len(names):
        want = (f"{len(names)} parameter(s) ({', '.join(names)})" if names
                else "no parameters")
        raise ValueError(f"{front_name}: takes {want} after the points, got "
                         f"{len(params)}")
    values = []
    for name, v in zip(names, params):
        if isinstance(v, np.ndarray) and v.ndim == 0:
            v = v[()]
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Real):
            raise ValueError(f"{front_name}: {name}={v!r}: must be a real number")
        try:
            v = float(v)
        except OverflowError:                      # an int beyond float64 (10**400)
            raise ValueError(f"{front_name}: {name}={v!r:.40}: must be finite") from None
        if not (math.isfinite(v) or (v == math.inf and name in _MAY_BE_INFINITE)):
            raise ValueError(f"{front_name}: {name}={v!r}: must be finite")
        values.append(v)
    if condition is not None and not condition(*values):
        shown = ", ".join(f"{n}={v!r}" for n, v in zip(names, values))
        raise ValueError(f"{front_name}: {shown}: the warp needs {words}")
    return np.asarray(values, dtype=np.float64) if values else np.zeros(1)
