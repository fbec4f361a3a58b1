"""Bitmap textures and environment maps: image files in, bilinear lookups out.

Conventions (Mitsuba's, measured against it in the tests): a ``bitmap`` texture maps
the surface's (u, v) through its ``to_uv`` affine transform, then either filters texels
bilinearly with texel centres at ((i + ½)/w, (j + ½)/h) (``filter_type`` bilinear) or takes
texel (⌊u·w⌋, ⌊v·h⌋) (nearest), row 0 at v = 0; texel indices outside the image repeat,
mirror or clamp (``wrap_mode``). An ``envmap`` maps the local direction d to
u = atan2(d.x, -d.z) / 2π, v = acos(d.y) / π and filters with x = u·w - ½ (periodic) and
y = v·(h - 1) (clamped).

Images are stored back to back in one float64 array; each texture is one float64 row of
``tex_info`` with the columns named in ``layout`` (``TEX_OFFSET``, ``TEX_WIDTH``...;
integers are stored exactly). Files are decoded with Mitsuba's image reader (file I/O
only; 8-bit sRGB images, PNG and JPEG, are linearised unless ``raw``; a grey image
is repeated into R, G and B; a bitmap's 16-bit image rounded to half, as Mitsuba stores
it), imported lazily.
"""

from __future__ import annotations

import math
import os
import threading

import numpy as np

from .._compile_options import fused
from .._fastmath import coarse_acos, coarse_atan2, fast_sincos_2pi
from .layout import (BILINEAR, CLAMP, NEAREST, REPEAT, TEX_COLUMNS, TEX_FILTER,
                     TEX_HEIGHT, TEX_OFFSET, TEX_UV, TEX_WIDTH, TEX_WRAP)

_jit = fused()
_fast = fused(_nrt=False)    # array arguments, no allocation: see emitters.py


_IDENTITY_UV = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0)


#: Held while Mitsuba is imported and its variant set. Mitsuba's import puts another
#: module in ``sys.modules["mitsuba"]`` part-way (``mitsuba_alias``), and a thread
#: importing it meanwhile got the first one, which has no ``variant``: scenes with an
#: image prepared from several threads at once failed, "cannot read image (module
#: 'mitsuba' has no attribute 'variant')" (an outside review).
MITSUBA_IMPORT = threading.RLock()


def _new_import_lock() -> None:
    """A fresh lock in a forked child: one held by another thread of the parent at the
    fork (importing Mitsuba) would stay held in the child, whose next image read waited
    forever (a read-only review)."""
    global MITSUBA_IMPORT
    MITSUBA_IMPORT = threading.RLock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_new_import_lock)


def import_mitsuba(variant: str | None = None):
    """The ``mitsuba`` module, its variant set (``variant``, or ``scalar_rgb`` if none is
    set yet), with at least two Dr.Jit worker threads: with one (a process confined to
    one CPU, e.g. ``taskset -c 0``), Mitsuba 3.9's OpenEXR reader waits forever on its
    thread pool, in ``Bitmap`` and in loading any scene with an EXR texture. One thread
    at a time (``MITSUBA_IMPORT``)."""
    with MITSUBA_IMPORT:
        import drjit as dr
        import mitsuba as mi

        if dr.thread_count() < 2:
            dr.set_thread_count(2)
        if variant is not None:
            mi.set_variant(variant)
        elif mi.variant() is None:
            mi.set_variant("scalar_rgb")
        return mi


def read_image(path: str, *, raw: bool = False, texture: bool = False,
               half: bool = False) -> np.ndarray:
    """(H, W, 3) float64 RGB of an image file, 8-bit sRGB decoded to linear unless
    ``raw`` (as Mitsuba's ``bitmap`` does); raises OSError naming the file. ``texture``:
    the values a ``bitmap`` texture holds, which Mitsuba 3.9.1 stores in half precision
    where the file has 2 bytes a channel (a 16-bit PNG: decoded, then rounded to half,
    up to 2^-11 of a texel; an envmap keeps float32). A texture whose image is already
    linear Y or RGB in the type it is held in is taken as it is, as Mitsuba's ``bitmap``
    takes it: an EXR whose channels carry a layer's name (``albedo.R``, ``albedo.G``,
    ``albedo.B``), which Mitsuba's conversion to RGB, and an envmap's, cannot match; where
    that conversion is needed (an alpha channel, an envmap) the refusal names the
    channels, not the conversion's structures. ``half``: a texture held in half
    precision whatever the file (a ``bitmap`` of ``format`` "float16")."""
    mi = bmp = None
    try:
        mi = import_mitsuba()
        bmp = mi.Bitmap(path)
        if raw:
            bmp.set_srgb_gamma(False)
        half = texture and (half or bmp.bytes_per_pixel() == 2 * bmp.channel_count())
        stored = mi.Struct.Type.Float16 if half else mi.Struct.Type.Float32
        if not (texture and _held_as_it_is(mi, bmp, stored)):
            bmp = bmp.convert(mi.Bitmap.PixelFormat.RGB, stored, False)
        a = np.array(bmp, dtype=np.float64)
    except Exception as e:  # noqa: BLE001 - any decoder failure is a bad file
        raise OSError(f"{path}: {_unreadable(mi, bmp, e, texture)}") from None
    if a.ndim == 2:
        a = a[:, :, None]
    if a.shape[2] == 1:
        a = np.repeat(a, 3, axis=2)
    return a[:, :, :3]


def _unreadable(mi, bmp, error: Exception, texture: bool) -> str:
    """Why an image cannot be read: Mitsuba's words, or, for Y, RGB or XYZ channels (with
    alpha or not) named by a layer (its conversion then dumps both structures and says
    'don't know how to obtain channel "R"'), those channels and what Mitsuba does."""
    if bmp is None or bmp.pixel_format() == mi.Bitmap.PixelFormat.MultiChannel:
        return f"cannot read image ({error})"
    names = [bmp.struct_()[i].name for i in range(bmp.channel_count())]
    if "." not in "".join(names):
        return f"cannot read image ({error})"
    use = ("as a texture Mitsuba takes such channels only without alpha, as Y or R, G, B"
           if texture else "as an environment map Mitsuba cannot read such channels")
    # a channel without a layer among them keeps its name (albedo.R, G, B and a bare A:
    # "[1]" raised IndexError, a crash where Mitsuba refuses the file; a read-only review)
    plain = ", ".join(n.rsplit(".", 1)[-1] for n in names)
    return (f"cannot read image: its channels are {', '.join(names)}, named by a layer; "
            f"{use}, and refuses it too: save them as {plain}")


def _held_as_it_is(mi, bmp, stored) -> bool:
    """Whether Mitsuba 3.9.1's ``bitmap`` texture keeps ``bmp`` without converting it:
    linear Y or RGB already in the type it stores (a converted layered EXR is refused,
    'don't know how to obtain channel "R"', where Mitsuba renders it)."""
    pf = mi.Bitmap.PixelFormat
    return (bmp.pixel_format() in (pf.Y, pf.RGB) and bmp.component_format() == stored
            and not bmp.srgb_gamma())


def non_finite_texels(image: np.ndarray) -> tuple | None:
    """Where ``image`` (H, W, 3) holds NaN or infinite values: (the number of such texels,
    the first one's row, column and channel, its value), or None if it holds none (for
    the loader's refusal and the reference build's diagnosis)."""
    bad = ~np.isfinite(image)
    if not bad.any():
        return None
    y, x, c = np.argwhere(bad)[0]
    return int(bad.any(axis=2).sum()), y, x, c, image[y, x, c]


class TextureStore:
    """Collects images into the flat arrays the kernels read."""

    def __init__(self):
        self.images: list[np.ndarray] = []
        self.modes: list[tuple] = []

    def add(self, image: np.ndarray, *, filter_type: int = BILINEAR, wrap: int = REPEAT,
            to_uv=_IDENTITY_UV) -> int:
        """Store an image with its lookup settings; returns its index. ``to_uv``: the six
        entries (a, b, c, d, e, f) of u' = a u + b v + c, v' = d u + e v + f."""
        self.images.append(np.ascontiguousarray(image, dtype=np.float64))
        self.modes.append((filter_type, wrap, *to_uv))
        return len(self.images) - 1

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(texel data, texture table (n, TEX_COLUMNS) float64)."""
        if not self.images:
            return np.zeros(3), np.zeros((1, TEX_COLUMNS))
        info = np.zeros((len(self.images), TEX_COLUMNS))
        off = 0
        for i, (im, modes) in enumerate(zip(self.images, self.modes)):
            info[i, :TEX_FILTER] = off, im.shape[1], im.shape[0]
            info[i, TEX_FILTER:] = modes
            off += im.size
        return np.concatenate([im.ravel() for im in self.images]), info


@_fast
def _texel(tex_data, off, w, x, y):
    # unsigned: x and y are wrapped into the image, and numba's negative-index fix-up
    # (a compare and a select per load) is not paid
    k = np.uint64(off + 3 * (y * w + x))
    return tex_data[k], tex_data[k + np.uint64(1)], tex_data[k + np.uint64(2)]


@_fast
def _wrap(i, n, mode):
    """Texel index i of a row of n, clamped or (any other mode) mirrored into [0, n)."""
    if mode == CLAMP:
        return min(max(i, 0), n - 1)
    i = i % (2 * n)
    return i if i < n else 2 * n - 1 - i


@fused(inline="always")
def _wrap_pair(x0, n, mode):
    """Texel indices of ⌊x⌋ and ⌊x⌋ + 1 (x0 = ⌊x⌋, a float) in a row of n, repeated,
    clamped or mirrored. Both inside the row, the common case, costs one compare; a
    repeat reduces x0 in floating point (exact: the integers are below 2^53) instead of
    by an integer division (~26 cycles on the path to the texel's load). x0 not finite
    (a NaN uv) reads texel 0."""
    if 0.0 <= x0 and x0 + 1.0 < n:
        i = int(x0)
        return i, i + 1
    if not abs(x0) < 4503599627370496.0:    # 2^52: beyond it no fraction is left
        x0 = 0.0
    ni = int(n)
    if mode == REPEAT:
        r = x0 - n * math.floor(x0 / n)
        if r < 0.0:         # the rounded quotient one off
            r += n
        elif r >= n:
            r -= n
        i = int(r)
        return i, (i + 1 if i + 1 < ni else 0)
    i = int(x0)
    return _wrap(i, ni, mode), _wrap(i + 1, ni, mode)


@_fast
def _size(tex_info, t):
    return int(tex_info[t, TEX_OFFSET]), int(tex_info[t, TEX_WIDTH]), int(tex_info[t, TEX_HEIGHT])


@_fast
def _bilinear(tex_data, tex_info, t, x, y, wrap_x, wrap_y):
    off, w, h = _size(tex_info, t)
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx, fy = x - x0, y - y0
    xa, xb = _wrap_pair(x0, float(w), wrap_x)
    ya, yb = _wrap_pair(y0, float(h), wrap_y)
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
    """A bitmap texture's value at surface coordinates (u, v): mapped by its ``to_uv``,
    then filtered (bilinear or nearest) with its wrap mode."""
    row = tex_info[t]
    uu = row[TEX_UV] * u + row[TEX_UV + 1] * v + row[TEX_UV + 2]
    vv = row[TEX_UV + 3] * u + row[TEX_UV + 4] * v + row[TEX_UV + 5]
    w, h = row[TEX_WIDTH], row[TEX_HEIGHT]
    wrap = int(row[TEX_WRAP])
    if row[TEX_FILTER] == NEAREST:
        off = int(row[TEX_OFFSET])
        iw, ih = int(w), int(h)
        return _texel(tex_data, off, iw, _wrap_pair(np.floor(uu * w), w, wrap)[0],
                      _wrap_pair(np.floor(vv * h), h, wrap)[0])
    return _bilinear(tex_data, tex_info, t, uu * w - 0.5, vv * h - 0.5, wrap, wrap)


@_jit
def envmap_uv(lx, ly, lz):
    """(u, v) of a local unit direction, within 3e-11 (the angles by ``coarse_atan2``
    and ``coarse_acos``; the full-precision pair took 7 % of a render of the envmap
    scene). A texel of a 16384-wide map is 6e-5 of it. The price: a direction within
    ~3e-11 of a sampling cell's edge may come back in the cell beside the one it was
    sampled in (the 1-ulp pair never did), so there its two MIS weights use the two
    cells' densities: ~1e-8 of the samples on a 2048 × 1024 grid, fewer on a coarser."""
    u = coarse_atan2(lx, -lz) * (0.5 / math.pi)
    u -= math.floor(u)
    v = coarse_acos(min(max(ly, -1.0), 1.0)) / math.pi
    return u, v


@_jit
def envmap_direction(u, v):
    """The local unit direction of (u, v); inverse of ``envmap_uv``: θ = πv, φ = 2πu,
    their sines and cosines from the fractions of a turn v/2 and u (exact, no libm)."""
    s, cos_theta = fast_sincos_2pi(0.5 * v)
    sin_phi, cos_phi = fast_sincos_2pi(u)
    return s * sin_phi, cos_theta, -s * cos_phi


@fused(inline="always")
def luminance(r, g, b):
    """The luminance of linear sRGB (Rec. 709) r, g, b: Mitsuba's ``luminance``."""
    return 0.212671 * r + 0.715160 * g + 0.072169 * b


@_fast
def eval_envmap(tex_data, tex_info, t, u, v):
    h = tex_info[t, TEX_HEIGHT]
    return _bilinear(tex_data, tex_info, t, u * tex_info[t, TEX_WIDTH] - 0.5,
                     v * (h - 1) if h > 1 else 0.0, REPEAT, CLAMP)


@_jit
def _cell_means(tex_data, tex_info, h, w, k):
    """The mean over each (u, v) cell of the luminance of ``eval_envmap`` (texture 0; at
    least 0) at k × k points of the cell."""
    out = np.zeros((h, w))
    for j in range(h):
        for i in range(w):
            acc = 0.0
            for a in range(k):
                for b in range(k):
                    r, g, bl = eval_envmap(tex_data, tex_info, 0, (i + (a + 0.5) / k) / w,
                                           (j + (b + 0.5) / k) / h)
                    acc += max(luminance(r, g, bl), 0.0)
            out[j, i] = acc / (k * k)
    return out


#: The envmap's sampling grid: each texel split into s × s cells, s the smallest factor
#: that gives at least ``ENV_MIN_COLUMNS`` columns, at most 8 and at most
#: ``ENV_MAX_CELLS`` cells in all (a large map keeps one cell a texel).
ENV_MIN_COLUMNS = 256
ENV_MAX_CELLS = 1 << 20


def envmap_refinement(h: int, w: int) -> int:
    """Cells per texel side of the envmap's sampling grid (``envmap_sampling_weights``)."""
    s = min(8, max(1, -(-ENV_MIN_COLUMNS // w)))
    while s > 1 and s * s * h * w > ENV_MAX_CELLS:
        s -= 1
    return s


def envmap_sampling_weights(image: np.ndarray, k: int = 4) -> np.ndarray:
    """Per-cell weights (s·H, s·W) for sampling an envmap's (u, v) piecewise constantly,
    each texel split into s × s cells (``envmap_refinement``: a bilinear lookup varies
    across a texel, most where a small bright sun sits, and a constant density per texel
    cannot follow it): the mean over the cell of what ``eval_envmap`` returns there (its
    bilinear lookup's luminance, as Mitsuba weights its envmap's texels, at k × k points
    of the cell), times sin θ at the cell centre, plus a floor so that every cell has a
    non-zero density (the estimator stays unbiased wherever the map is non-zero). On the
    envmap scene's sky (32 × 64, s = 4) the relative variance of one sample of the
    environment's integral (luminance over the sphere) is 0.0082; with the largest of R,
    G, B (until 3 December; mean of R, G, B integrated) 0.023, with one cell a texel
    0.155, and with each texel's weight the largest texel of its 3 × 3 neighbourhood
    (until 2 December) 0.55. The luminance against the largest channel: per-sample
    variance of the envmap scene at max_depth 2 against Mitsuba's 1.18 -> 1.05 (the sun,
    white, weighs more against the blue sky)."""
    store = TextureStore()
    store.add(np.asarray(image, dtype=np.float64)[..., :3])
    h, w = image.shape[:2]
    s = envmap_refinement(h, w)
    h, w = s * h, s * w
    sin_t = np.sin(np.pi * (np.arange(h) + 0.5) / h)[:, None]
    weights = _cell_means(*store.arrays(), h, w, k) * sin_t
    floor = 1e-3 * weights.mean() if weights.mean() > 0 else 1.0
    return weights + floor * sin_t
