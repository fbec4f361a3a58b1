"""Bitmap textures and environment maps: image files in, bilinear lookups out.

Conventions (Mitsuba's, measured against it in the tests): a ``bitmap`` texture at
(u, v) filters texels bilinearly with texel centres at ((i + ½)/w, (j + ½)/h), row 0 at
v = 0, repeating in both directions. An ``envmap`` maps the local direction d to
u = atan2(d.x, -d.z) / 2π, v = acos(d.y) / π and filters with x = u·w - ½ (periodic) and
y = v·(h - 1) (clamped).

Images are stored back to back in one float64 array; ``tex_info[t] = (offset, width,
height)``. Files are decoded with Mitsuba's image reader (file I/O only; 8-bit sRGB
images are linearised), imported lazily.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_jit = njit(cache=True)
_fast = njit(cache=True, _nrt=False)    # array arguments, no allocation: see emitters.py


def read_image(path: str) -> np.ndarray:
    """(H, W, 3) float64 linear RGB of an image file; raises OSError naming the file."""
    try:
        import mitsuba as mi
        if mi.variant() is None:
            mi.set_variant("scalar_rgb")
        bmp = mi.Bitmap(path)
        bmp = bmp.convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float32, False)
        a = np.array(bmp, dtype=np.float64)
    except Exception as e:  # noqa: BLE001 - any decoder failure is a bad file
        raise OSError(f"{path}: cannot read image ({e})") from None
    if a.ndim == 2:
        a = np.repeat(a[:, :, None], 3, axis=2)
    return a[:, :, :3]


class TextureStore:
    """Collects images into the flat arrays the kernels read."""

    def __init__(self):
        self.images: list[np.ndarray] = []

    def add(self, image: np.ndarray) -> int:
        self.images.append(np.ascontiguousarray(image, dtype=np.float64))
        return len(self.images) - 1

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        if not self.images:
            return np.zeros(3), np.zeros((1, 3), dtype=np.int64)
        info = np.zeros((len(self.images), 3), dtype=np.int64)
        off = 0
        for i, im in enumerate(self.images):
            info[i] = off, im.shape[1], im.shape[0]
            off += im.size
        return np.concatenate([im.ravel() for im in self.images]), info


@_fast
def _texel(tex_data, off, w, x, y):
    k = off + 3 * (y * w + x)
    return tex_data[k], tex_data[k + 1], tex_data[k + 2]


@_fast
def _bilinear(tex_data, tex_info, t, x, y, wrap_y):
    off, w, h = tex_info[t, 0], tex_info[t, 1], tex_info[t, 2]
    x0 = math.floor(x)
    y0 = math.floor(y)
    fx, fy = x - x0, y - y0
    xa = int(x0) % w
    xb = (xa + 1) % w
    if wrap_y:
        ya = int(y0) % h
        yb = (ya + 1) % h
    else:
        ya = min(max(int(y0), 0), h - 1)
        yb = min(ya + 1, h - 1)
    a = _texel(tex_data, off, w, xa, ya)
    b = _texel(tex_data, off, w, xb, ya)
    c = _texel(tex_data, off, w, xa, yb)
    d = _texel(tex_data, off, w, xb, yb)
    w00, w10, w01, w11 = (1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy
    return (w00 * a[0] + w10 * b[0] + w01 * c[0] + w11 * d[0],
            w00 * a[1] + w10 * b[1] + w01 * c[1] + w11 * d[1],
            w00 * a[2] + w10 * b[2] + w01 * c[2] + w11 * d[2])


@_fast
def eval_texture(tex_data, tex_info, t, u, v):
    """A bitmap texture's bilinear value at (u, v), repeating."""
    return _bilinear(tex_data, tex_info, t, u * tex_info[t, 1] - 0.5,
                     v * tex_info[t, 2] - 0.5, True)


@_jit
def envmap_uv(lx, ly, lz):
    """(u, v) of a local unit direction."""
    u = math.atan2(lx, -lz) * (0.5 / math.pi)
    u -= math.floor(u)
    v = math.acos(min(max(ly, -1.0), 1.0)) / math.pi
    return u, v


@_jit
def envmap_direction(u, v):
    """The local unit direction of (u, v); inverse of ``envmap_uv``."""
    theta = v * math.pi
    phi = u * 2.0 * math.pi
    s = math.sin(theta)
    return s * math.sin(phi), math.cos(theta), -s * math.cos(phi)


@_fast
def eval_envmap(tex_data, tex_info, t, u, v):
    h = tex_info[t, 2]
    return _bilinear(tex_data, tex_info, t, u * tex_info[t, 1] - 0.5,
                     v * (h - 1) if h > 1 else 0.0, False)


def envmap_sampling_weights(image: np.ndarray) -> np.ndarray:
    """Per-texel weights (H, W) for sampling an envmap's (u, v) piecewise constantly: the
    largest value the bilinear lookup can take over each cell (its 3 × 3 neighbourhood
    of texels, max over RGB) times sin θ at the cell centre, floored so that every cell
    has a non-zero density (the estimator stays unbiased wherever the map is non-zero)."""
    lum = image.max(axis=2)
    pad = np.pad(lum, ((1, 1), (0, 0)), mode="edge")
    pad = np.concatenate([pad[:, -1:], pad, pad[:, :1]], axis=1)
    h, w = lum.shape
    neigh = np.max([pad[1 + dy:1 + dy + h, 1 + dx:1 + dx + w]
                    for dy in (-1, 0, 1) for dx in (-1, 0, 1)], axis=0)
    sin_t = np.sin(np.pi * (np.arange(h) + 0.5) / h)[:, None]
    weights = np.maximum(neigh, 0.0) * sin_t
    floor = 1e-3 * weights.mean() if weights.mean() > 0 else 1.0
    return weights + floor * sin_t
