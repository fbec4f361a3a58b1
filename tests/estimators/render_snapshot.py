"""Bit-identity of our renders across a refactor: save renders of the reference scenes
now, compare after the change.

    python tests/estimators/render_snapshot.py save DIR      # before
    python tests/estimators/render_snapshot.py compare DIR   # after: exit 1 on any bit

Each scene is rendered at its own resolution with 16 spp and seed 7 (the specialised
kernel), plus the Cornell box at 64 spp, whose kernel time (compilation excluded, the
best of three) is printed so a speed change shows beside the bits.
"""

import os
import sys

import numpy as np

from estimators.pathtracer import render

ROOT = os.path.join(os.path.dirname(__file__), "..", "..", "reference", "scenes")
SCENES = ("cornell-box", "envmap", "veach-mis", "rough-conductors", "glass-sphere",
          "delta-lights", "white-furnace", "textures", "bunny")


def snapshot() -> tuple[dict, float]:
    images = {}
    for name in SCENES:
        r = render(os.path.join(ROOT, name, "scene.xml"), spp=16, seed=7)
        images[name] = np.concatenate([r.mean, r.variance], axis=-1)
    cornell = os.path.join(ROOT, "cornell-box", "scene.xml")
    times = []
    for _ in range(3):
        r = render(cornell, spp=64, seed=3)
        times.append(r.seconds)
    images["cornell-box@64"] = np.concatenate([r.mean, r.variance], axis=-1)
    return images, min(times)


def main(argv) -> int:
    if len(argv) != 2 or argv[0] not in ("save", "compare"):
        print(__doc__, file=sys.stderr)
        return 2
    mode, folder = argv
    images, seconds = snapshot()
    print(f"cornell-box 64 spp: {seconds:.3f} s (best of 3, compilation excluded)")
    if mode == "save":
        os.makedirs(folder, exist_ok=True)
        np.savez(os.path.join(folder, "snapshot.npz"), **images)
        return 0
    before = np.load(os.path.join(folder, "snapshot.npz"))
    bad = [name for name in images if not np.array_equal(before[name], images[name])]
    for name in images:
        print(f"{name}: {'DIFFERENT' if name in bad else 'bit-identical'}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
