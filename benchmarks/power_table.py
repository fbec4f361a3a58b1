"""The power of the default gate: for every sampler check of a suite, the smallest
uniform contamination ε it catches with 95 % power, at the Holm level of the most
significant check (α / number of checks: an upper bound on ε). Prints the Markdown
table the README quotes.

    python benchmarks/power_table.py [--suite default] [--n N] [-k PATTERN]

``--n`` replaces every sampler check's sample count (to compare with another default).
"""

from __future__ import annotations

import argparse

from mcverify.gate import suites
from mcverify.gate.budget import power_bought

import _args  # benchmarks/_args.py, beside this script


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--suite", default="default")
    ap.add_argument("--n", type=_args.count, default=None)
    ap.add_argument("-k", default=None)
    ap.add_argument("--alpha", type=float, default=0.01)
    a = ap.parse_args()
    every = suites.build_suite(a.suite)
    names = [c.name for c in every if suites.SCALABLE in c.tags]
    overrides = tuple((x, int(a.n)) for x in names) if a.n else ()
    chosen = suites.select(suites.build_suite(a.suite, overrides), a.k)
    result = suites.run_suite(chosen, name=a.suite, canary=False, alpha=a.alpha)
    # The Holm level of the whole suite, whatever -k selected.
    eps = power_bought([r for r in result.results if r.name in names], a.alpha,
                       n_checks=len(every))
    level = a.alpha / len(every)
    print(f"suite {a.suite!r}: ε caught with 95 % power at α / {len(every)} = {level:.2g} "
          f"(uniform contamination; '-' where the pdf is uniform)\n")
    print("| check | n | seconds | ε (95 % power) |\n|---|---|---|---|")
    for r in result.results:
        if r.name in eps:
            e = eps[r.name]
            print(f"| {r.name} | {r.n_samples:,} | {r.seconds:.2f} | "
                  f"{'-' if e is None else f'{100 * e:.2f} %'} |")


if __name__ == "__main__":
    _args.run(main)
