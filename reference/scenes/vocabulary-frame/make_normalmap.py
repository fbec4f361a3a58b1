"""Write the normal map of the vocabulary-frame scene: ``bumps.png`` (16 × 16, 8-bit RGB,
read ``raw``), a tangent-space normal map of four hemispherical bumps per side with a
flat border, encoded as Mitsuba reads it: texel = (n + 1) / 2. The bumps lean up to
60°, so the flipped-normal rule and the shadowing term both matter.
Run: python reference/scenes/vocabulary-frame/make_normalmap.py (needs Mitsuba)."""

import os

import numpy as np


def bumps(n: int = 16, per_side: int = 4) -> np.ndarray:
    c = (np.arange(n) + 0.5) / n * per_side
    x, y = np.meshgrid(c % 1.0 - 0.5, c % 1.0 - 0.5)
    r2 = (x / 0.42) ** 2 + (y / 0.42) ** 2
    inside = r2 < 1.0
    lean = np.where(inside, np.sqrt(np.minimum(r2, 1.0)), 0.0) * np.sin(np.radians(60.0))
    phi = np.arctan2(y, x)
    normal = np.stack([lean * np.cos(phi), lean * np.sin(phi),
                       np.sqrt(1.0 - lean ** 2)], axis=-1)
    return np.clip(np.round((normal + 1.0) * 0.5 * 255.0), 0, 255).astype(np.uint8)


if __name__ == "__main__":
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    here = os.path.dirname(os.path.abspath(__file__))
    mi.Bitmap(bumps(), mi.Bitmap.PixelFormat.RGB).write(os.path.join(here, "bumps.png"))
