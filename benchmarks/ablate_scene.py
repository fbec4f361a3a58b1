"""Which part of a scene costs ours more than Mitsuba: each emitter and shape taken out
in turn, ours and Mitsuba's render times in one process at 128², 64 spp:

    python benchmarks/ablate_scene.py vocabulary-lights [--repeats 7]

A row per variant (the full scene first): our time, Mitsuba's (``llvm_ad_rgb`` where its
LLVM is found, else what ``mcverify.gate.mitsuba`` falls back to), and the ratio. An
element whose removal drops our time far more than Mitsuba's is where the gap lives
(6 December: the floor of vocabulary-lights, 40.3 → 11.1 ms of ours, 17.9 → 10.5 of
Mitsuba's). The variants are written beside the scene (so that its relative paths
resolve) as ``_ablate.xml`` and removed after each row.
"""

from __future__ import annotations

import argparse
import os
import xml.etree.ElementTree as ET

import numpy as np

import _args  # benchmarks/_args.py, beside this script


def variants(text: str):
    """(label, scene text): the scene, then the scene without each top-level emitter or
    shape."""
    yield "full", text
    root = ET.fromstring(text)
    for i, child in enumerate(list(root)):
        if child.tag in ("emitter", "shape"):
            copy = ET.fromstring(text)
            copy.remove(list(copy)[i])
            yield f"-{child.tag} {i} ({child.get('type')})", ET.tostring(copy, encoding="unicode")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", help="a reference scene's name or a scene file")
    ap.add_argument("--repeats", type=_args.count, default=7)
    ap.add_argument("--spp", type=_args.count, default=64)
    args = ap.parse_args()
    from estimators.pathtracer import prepare_scene, render
    from mcverify.gate import mitsuba as mvm
    from mcverify.gate.bench import _best      # best of the repeats after a warm-up
    from mcverify.gate.reference import resolve_scene

    mi = mvm.mi()
    path = resolve_scene(args.scene)[1]
    text = open(path, encoding="utf-8").read()
    scratch = os.path.join(os.path.dirname(path), "_ablate.xml")
    for label, variant in variants(text):
        with open(scratch, "w", encoding="utf-8") as f:
            f.write(variant)
        try:
            ours = prepare_scene(scratch, params={"res": 128})
            theirs = mi.load_file(scratch, res=128)
            # the samples Mitsuba's sampler rounds --spp to (orthogonal: 32 -> 49), on both
            n = mvm.sampler_rounds(ours.desc.sampler, args.spp)
            t_ours = _best(lambda: render(ours, spp=n, variance=False), args.repeats)
            t_theirs = _best(lambda: np.asarray(mi.render(theirs, spp=args.spp)),
                             args.repeats)
        finally:
            os.remove(scratch)
        print(f"{label:32s} ours {1e3 * t_ours:8.1f} ms  Mitsuba {1e3 * t_theirs:8.1f} ms  "
              f"ratio {t_ours / t_theirs:5.2f}", flush=True)


if __name__ == "__main__":
    _args.run(main)
