"""CPU cost of every warp's numpy front ends: nanoseconds of CPU time per point for
``sample``, ``pdf`` and ``invert`` at the warp's default parameters, one numba thread,
float64 in, best of ``--repeats`` (JIT warm-up excluded). On a shared machine CPU time
(``time.process_time``) is the steadier figure; one thread makes it a cost, not a wait
for a descheduled partner. Prints the Markdown table the README quotes.

    python benchmarks/warp_speed.py [--n 1000000] [--repeats 5] [--fastmath] [WARP ...]

``--fastmath`` times ``estimators._fastmath``'s functions against libm's (numba's
``math.*``) instead, each in a plain loop over n points of (0.01, 5) (a second argument
or acos's on (-1, 1)), which LLVM vectorises where it can, and in a loop summing the
results, which stays scalar (the path tracer's case).
"""

from __future__ import annotations

import argparse
import time

import math

import numba
import numpy as np
from numba import njit

from estimators import _fastmath as F
from estimators import warps as W

import _args  # benchmarks/_args.py, beside this script

_TWO_PI = 2.0 * math.pi


@njit
def _sum2(pair):
    return pair[0] + pair[1]


def cpu_ns_per_point(fn, arg, params, n, repeats):
    fn(arg, *params)
    best = np.inf
    for _ in range(repeats):
        c0 = time.process_time()
        fn(arg, *params)
        best = min(best, time.process_time() - c0)
    return best / n * 1e9


def _plain_loop(f):
    @njit(error_model="numpy")
    def loop(y, x, out):
        for i in range(x.size):
            out[i] = f(y[i], x[i])
    return loop


def _sum_loop(f):
    """The same calls summed in order: a float sum LLVM may not reorder, so the loop
    stays scalar, as the path tracer's calls are; default error model, as the tracer's."""
    @njit
    def loop(y, x, out):
        acc = 0.0
        for i in range(x.size):
            acc += f(y[i], x[i])
        out[0] = acc
    return loop


# name, ours, libm, each as f(y, x); y is uniform on (-1, 1), x on (0.01, 5)
_FUNCTIONS = [
    ("exp", lambda y, x: F.fast_exp(x), lambda y, x: math.exp(x)),
    ("expm1", lambda y, x: F.fast_expm1(x), lambda y, x: math.expm1(x)),
    ("log", lambda y, x: F.fast_log(x), lambda y, x: math.log(x)),
    ("log1p", lambda y, x: F.fast_log1p(x), lambda y, x: math.log1p(x)),
    ("atan", lambda y, x: F.fast_atan(x), lambda y, x: math.atan(x)),
    ("atan2", lambda y, x: F.fast_atan2(y, x), lambda y, x: math.atan2(y, x)),
    ("acos", lambda y, x: F.fast_acos(y), lambda y, x: math.acos(y)),
    ("sin + cos of 2πu", lambda y, x: _sum2(F.fast_sincos_2pi(0.2 * x)),
     lambda y, x: math.sin(_TWO_PI * (0.2 * x)) + math.cos(_TWO_PI * (0.2 * x))),
]


def fastmath_table(n, repeats):
    rng = np.random.default_rng(0)
    x = rng.uniform(0.01, 5.0, n)
    y = rng.uniform(-1.0, 1.0, n)
    out = np.empty_like(x)
    print("| function (1 thread, ns CPU a point) | `_fastmath` | libm "
          "| `_fastmath`, scalar loop | libm, scalar loop |")
    print("|---|---|---|---|---|")
    for name, ours, libm in _FUNCTIONS:
        cells = []
        # each inlined into its loop (a call would stop vectorisation) and compiled with
        # the loop's error model (numba's default adds a branch to every division)
        for make, model in ((_plain_loop, "numpy"), (_sum_loop, "python")):
            for f in (ours, libm):
                loop = make(njit(error_model=model, inline="always")(f))
                cells.append(cpu_ns_per_point(lambda a, g=loop: g(y, a, out), x, (), n, repeats))
        print(f"| {name} | " + " | ".join(f"{c:.1f}" for c in cells) + " |", flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("warps", nargs="*", help="warp names (default: all of WARPS)")
    ap.add_argument("--n", type=_args.count, default=1e6)
    ap.add_argument("--repeats", type=_args.count, default=5)
    ap.add_argument("--fastmath", action="store_true",
                    help="time _fastmath's functions against libm's instead")
    args = ap.parse_args()
    unknown = [w for w in args.warps if w not in W.WARPS]
    if unknown:
        ap.error(f"unknown warp {unknown[0]!r}; known: {', '.join(sorted(W.WARPS))}")
    numba.set_num_threads(1)
    n = int(args.n)
    if args.fastmath:
        fastmath_table(n, args.repeats)
        return
    rng = np.random.default_rng(0)
    print("| warp (1 thread, ns CPU a point) | sample | pdf | invert |")
    print("|---|---|---|---|")
    for name in args.warps or sorted(W.WARPS):
        w = W.WARPS[name]
        u = rng.random((n, w.sample_dim))
        x = w.sample(u, *w.defaults)
        cells = [cpu_ns_per_point(w.sample, u, w.defaults, n, args.repeats),
                 cpu_ns_per_point(w.pdf, x, w.defaults, n, args.repeats)]
        if w.invert is not None:
            cells.append(cpu_ns_per_point(w.invert, x, w.defaults, n, args.repeats))
        print(f"| {name} | " + " | ".join(f"{c:.1f}" for c in cells)
              + (" |" if w.invert is not None else " | – |"), flush=True)


if __name__ == "__main__":
    _args.run(main)
