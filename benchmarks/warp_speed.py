"""CPU cost of every warp's numpy front ends: nanoseconds of CPU time per point for
``sample``, ``pdf`` and ``invert`` at the warp's default parameters, one numba thread,
float64 in, best of ``--repeats`` (JIT warm-up excluded). On a shared machine CPU time
(``time.process_time``) is the steadier figure; one thread makes it a cost, not a wait
for a descheduled partner. Prints the Markdown table the README quotes.

    python benchmarks/warp_speed.py [--n 1000000] [--repeats 5] [WARP ...]
"""

from __future__ import annotations

import argparse
import time

import numba
import numpy as np

from estimators import warps as W


def cpu_ns_per_point(fn, arg, params, n, repeats):
    fn(arg, *params)
    best = np.inf
    for _ in range(repeats):
        c0 = time.process_time()
        fn(arg, *params)
        best = min(best, time.process_time() - c0)
    return best / n * 1e9


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("warps", nargs="*", help="warp names (default: all of WARPS)")
    ap.add_argument("--n", type=float, default=1e6)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    numba.set_num_threads(1)
    n = int(args.n)
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
