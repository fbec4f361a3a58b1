"""Write the images of the textures scene: ``checker.exr`` (16 × 16 float, a two-colour
checker of 2 × 2 texel squares with one yellow marker texel at row 0, column 0, so a
flipped or shifted layout shows) and ``tiles.png`` (8 × 8, 8-bit sRGB, random colours
with dark grout lines: decoded from sRGB unless the scene says ``raw``).
Run: python reference/scenes/textures/make_textures.py (needs mcverify's Mitsuba adapter)."""

import os

import numpy as np

from mcverify.gate.mitsuba import write_exr


def checker(n: int = 16) -> np.ndarray:
    y, x = np.mgrid[0:n, 0:n]
    odd = ((x // 2 + y // 2) % 2)[..., None]
    img = np.where(odd, [0.9, 0.2, 0.1], [0.1, 0.3, 0.8])
    img[0, 0] = [1.0, 1.0, 0.0]
    return img


def tiles(n: int = 8) -> np.ndarray:
    rng = np.random.default_rng(12)
    img = rng.integers(60, 256, (n, n, 3))
    img[::4, :] = 20
    img[:, ::4] = 20
    return img.astype(np.uint8)


if __name__ == "__main__":
    import mitsuba as mi

    here = os.path.dirname(os.path.abspath(__file__))
    write_exr(os.path.join(here, "checker.exr"), checker())
    mi.Bitmap(tiles()).write(os.path.join(here, "tiles.png"))
