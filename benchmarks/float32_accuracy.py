"""What float32 speed costs in accuracy: the cosine-hemisphere warp and its pdf on float32
inputs, ours (computed in float64, rounded once) and Mitsuba's ``mi.warp`` (``llvm_ad_rgb``:
float32 arithmetic, 8 lanes), each against the float64 result of the same float32 inputs,
in float32 ulps (of the float64 reference rounded to float32).

    python benchmarks/float32_accuracy.py [--n 1000000] [--seed 1]
"""

import argparse

import numpy as np

from estimators import warps
from mcverify.gate import mitsuba as mvm

import _args  # benchmarks/_args.py, beside this script


def ulps(a: np.ndarray, ref: np.ndarray) -> np.ndarray:
    spacing = np.spacing(np.abs(ref.astype(np.float32))).astype(np.float64)
    return np.abs(a.astype(np.float64) - ref) / spacing


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=_args.count, default=1_000_000)
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    mi = mvm._mi()
    u = np.random.default_rng(a.seed).random((a.n, 2)).astype(np.float32)
    ref = warps.sample_cosine_hemisphere(u.astype(np.float64))
    pdf_ref = warps.cosine_hemisphere_pdf(ref)
    ours = warps.sample_cosine_hemisphere(u)
    d = mi.warp.square_to_cosine_hemisphere(mi.Point2f(u[:, 0], u[:, 1]))
    theirs = np.stack([np.asarray(d[i]) for i in range(3)], axis=1)
    rows = [("ours", ours, warps.cosine_hemisphere_pdf(ours)),
            (f"Mitsuba ({mi.variant()})", theirs,
             np.asarray(mi.warp.square_to_cosine_hemisphere_pdf(d)))]
    print(f"cosine hemisphere, {a.n:,} float32 inputs; error in float32 ulps")
    print("| | points: max | points: 99.9 % | pdf: max | pdf: 99.9 % |")
    print("|---|---|---|---|---|")
    for name, pts, pdf in rows:
        e, f = ulps(pts, ref), ulps(pdf, pdf_ref)
        print(f"| {name} | {e.max():.3g} | {np.quantile(e, 0.999):.3g} | {f.max():.3g} "
              f"| {np.quantile(f, 0.999):.3g} |")


if __name__ == "__main__":
    _args.run(main)
