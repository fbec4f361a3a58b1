"""CPU cost of every warp's numpy front ends: nanoseconds of CPU time per point for
``sample``, ``pdf`` and ``invert`` at the warp's default parameters, one numba thread,
float64 in, best of ``--repeats`` (JIT warm-up excluded). On a shared machine CPU time
(``time.process_time``) is the steadier figure; one thread makes it a cost, not a wait
for a descheduled partner. Prints the Markdown table the README quotes.

    python benchmarks/warp_speed.py [--n 1000000] [--repeats 5] [--fastmath] [WARP ...]

``--fastmath`` times ``estimators._fastmath``'s functions against libm's (numba's
``math.*``) instead, each in a plain loop over n points of (0.01, 5).
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
    def loop(x, out):
        for i in range(x.size):
            out[i] = f(x[i])
    return loop


def fastmath_table(n, repeats):
    x = np.random.default_rng(0).uniform(0.01, 5.0, n)
    out = np.empty_like(x)
    print("| function (1 thread, ns CPU a point) | `_fastmath` | libm |")
    print("|---|---|---|")
    for name, ours, libm in [("exp", F.fast_exp, math.exp), ("expm1", F.fast_expm1, math.expm1),
                             ("log", F.fast_log, math.log), ("log1p", F.fast_log1p, math.log1p)]:
        cells = []
        for f in (ours, njit(lambda v, g=libm: g(v))):
            loop = _plain_loop(f)
            cells.append(cpu_ns_per_point(lambda a, g=loop: g(a, out), x, (), n, repeats))
        print(f"| {name} | {cells[0]:.1f} | {cells[1]:.1f} |", flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("warps", nargs="*", help="warp names (default: all of WARPS)")
    ap.add_argument("--n", type=float, default=1e6)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--fastmath", action="store_true",
                    help="time _fastmath's exp, expm1, log, log1p against libm's instead")
    args = ap.parse_args()
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
    main()
