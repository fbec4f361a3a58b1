"""Write sky.exr for the envmap scene: a 64 × 32 latitude-longitude sky, blue at the
zenith, pale at the horizon, dark below it, with a small sun 30° above the horizon.
Run: python reference/scenes/envmap/make_sky.py (needs mcverify's Mitsuba adapter)."""

import os

import numpy as np

from mcverify.gate.mitsuba import write_exr


def sky(width: int = 64, height: int = 32) -> np.ndarray:
    theta = (np.arange(height) + 0.5) / height * np.pi          # from +y (zenith) down
    phi = (np.arange(width) + 0.5) / width * 2 * np.pi
    t, p = np.meshgrid(theta, phi, indexing="ij")
    up = np.cos(t)
    zenith, horizon, ground = np.array([0.25, 0.45, 1.0]), np.array([1.0, 0.95, 0.9]), 0.05
    w = np.clip(up, 0, 1)[..., None]
    img = np.where(up[..., None] > 0, w * zenith + (1 - w) * horizon, ground)
    sun = (np.abs(t - np.radians(60)) < 0.12) & (np.abs(p - 1.0) < 0.2)
    img[sun] = [60.0, 55.0, 45.0]
    return img


if __name__ == "__main__":
    write_exr(os.path.join(os.path.dirname(os.path.abspath(__file__)), "sky.exr"), sky())
