"""Write the images of the vocabulary-glass scene: ``leaf.exr`` (32 × 32 float, an
opacity mask: a leaf-shaped blade (1) with a thin midrib cut out (0.25) on a clear
background (0)) and ``stripes.exr`` (8 × 8 float, a blend weight in stripes of 0.15 and
0.85 with a ramp inside each, so a mirrored or averaged weight shows).
Run: python reference/scenes/vocabulary-glass/make_textures.py (needs mcverify's Mitsuba
adapter)."""

import os

import numpy as np

from mcverify.gate.mitsuba import write_exr


def leaf(n: int = 32) -> np.ndarray:
    y, x = (np.mgrid[0:n, 0:n] + 0.5) / n * 2.0 - 1.0
    blade = (x / 0.55) ** 2 + (y / 0.95) ** 2 * (1.0 + 0.6 * y) < 1.0
    opacity = np.where(blade, 1.0, 0.0)
    opacity[blade & (np.abs(x) < 0.06)] = 0.25
    return np.repeat(opacity[..., None], 3, axis=2)


def stripes(n: int = 8) -> np.ndarray:
    x = np.arange(n)
    w = np.where((x // 2) % 2, 0.85, 0.15) + 0.02 * (x % 2)
    img = np.broadcast_to(w[None, :, None], (n, n, 3)).copy()
    img[0, 0] = [1.0, 0.0, 0.0]          # a luminance of 0.21 at one corner
    return img


if __name__ == "__main__":
    here = os.path.dirname(os.path.abspath(__file__))
    write_exr(os.path.join(here, "leaf.exr"), leaf())
    write_exr(os.path.join(here, "stripes.exr"), stripes())
