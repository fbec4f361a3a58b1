"""The χ² sampler test at the issue's size, ours against Mitsuba's, in one run:
``check_sampler`` of the cosine warp against ``mitsuba.chi2.ChiSquareTest`` of Mitsuba's
cosine warp at the same n (best of ``--repeats`` after a warm-up, so JIT compilation is
excluded on both sides). Ours is timed twice: repeated (its expected counts cached, as
``mcverify bench`` times it) and cold (integrated afresh, as Mitsuba's test always does).

    python benchmarks/chi2_speed.py [--n 16e6] [--repeats 3]
"""

from __future__ import annotations

import argparse
import time

from estimators import warps as W
from mcverify.checks import sampler as S
from mcverify.gate import mitsuba as mvm

import _args  # benchmarks/_args.py, beside this script


def best(fn, repeats):
    fn()
    t = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        t = min(t, time.perf_counter() - t0)
    return t


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=_args.count, default=16e6)
    ap.add_argument("--repeats", type=_args.count, default=3)
    a = ap.parse_args()
    n = int(a.n)
    if mvm.choose_variant().variant.startswith("scalar"):
        raise SystemExit("chi2_speed: Mitsuba's vectorised llvm variant is unavailable here "
                         "(libLLVM >= 16, DRJIT_LIBLLVM_PATH)")

    def ours():
        return S.check_sampler(W.sample_cosine_hemisphere, W.cosine_hemisphere_pdf,
                               "hemisphere", n_samples=n, seed=0)

    def ours_cold():
        S._CUBATURE.clear()
        return ours()

    t_rep, t_cold = best(ours, a.repeats), best(ours_cold, a.repeats)
    t_mi = best(mvm.chi2_cosine_hemisphere(n), a.repeats)
    print(f"n = {n:,}: ours {t_rep:.3f} s repeated, {t_cold:.3f} s cold; Mitsuba "
          f"{t_mi:.3f} s; ours / Mitsuba {t_rep / t_mi:.2f} (repeated), "
          f"{t_cold / t_mi:.2f} (cold)")


if __name__ == "__main__":
    _args.run(main)
