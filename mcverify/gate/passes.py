"""Any renderer's images as inputs of the compare gate.

``compare_images`` needs, per pixel, a mean, the sample variance of the values averaged
into it and their number n. A renderer that writes one EXR per run gives them through K
independently seeded passes: the mean of the passes, their variance (ddof = 1) and
n = K (Jung et al. 2020 compare pass means for the same reason: they are far less skewed
than single paths). Alpha is ignored: an RGBA or YA image is compared on its colour
channels, and a note says so.
"""

from __future__ import annotations

import glob
import hashlib
import os
from dataclasses import dataclass

import numpy as np

from ..errors import InvalidArgument
from . import reference
from .reference import is_alpha as _is_alpha

__all__ = ["ImageStats", "read_radiance", "pass_files", "pass_stats"]


@dataclass(frozen=True)
class ImageStats:
    """One side of a comparison: per-pixel mean, variance of the n values behind it."""

    mean: np.ndarray
    var: np.ndarray
    n: int
    files: tuple[str, ...]
    notes: tuple[str, ...] = ()
    passes: np.ndarray | None = None    # (K, H, W, C) if kept (``pass_stats(keep=True)``)
    #: the type every input file stored its pixels in, where coarser than float32 (half)
    precision: type | None = None


def colour_types(path: str) -> list[str]:
    """The pixel types ("half", "float") of an OpenEXR image's colour channels: its
    alpha left out, as ``read_radiance`` leaves it out. A half alpha beside float
    colours gave a float pass half's rounding allowance, 2^-10 instead of 2^-16 (a
    review of the change)."""
    return [t for c, t in reference.exr_channel_types(path).items() if not _is_alpha(c)]


#: The colour channels an image may hold (by the name after a layer's ``.``), beside
#: an alpha: what a reference holds, RGB or luminance.
COLOURS = ({"R", "G", "B"}, {"Y"})


def colour_channels(path: str) -> list[str]:
    """The channels of an OpenEXR image (its header read), which must be one layer's
    colour, R, G, B or Y, and an alpha at most; InvalidArgument naming the file and the
    channels otherwise. A depth channel or a second layer beside the colour was compared
    as colour: RGB and Z was refused as "shape (64, 64, 4)", blaming the right variance
    image, and X, Y, Z was compared as R, G, B (an outside review)."""
    names = list(reference.exr_channel_types(path))
    colour = [c for c in names if not _is_alpha(c)]
    layers = {c.rpartition(".")[0] for c in colour}
    # two alphas (R G B A diffuse.A) passed here and ended in the shape error this
    # check is for (a read-only review)
    kinds = {reference.channel_name(c).upper() for c in colour}
    if len(layers) != 1 or kinds not in COLOURS or len(names) - len(colour) > 1:
        raise InvalidArgument(f"{path}: channels {', '.join(names)}: give one layer's "
                              "colour, R, G, B or Y (an alpha beside it is ignored); other "
                              "channels (depth, a second layer, XYZ) are not compared: "
                              "write the colour to an image of its own")
    return names


def read_radiance(path: str) -> tuple[np.ndarray, str | None]:
    """An OpenEXR image's colour channels as (H, W, C) float64, and a note if an alpha
    channel was dropped (RGBA -> RGB, YA -> Y). Other checks as ``colour_channels`` and
    ``read_float_exr``."""
    names = colour_channels(path)
    img = reference.read_float_exr(path)
    colour = reference.without_alpha(names, img)
    return colour, (f"{path}: alpha channel ignored" if colour is not img else None)


def pass_files(pattern: str, *, option: str = "--test-passes") -> list[str]:
    """The pass images matching ``pattern``, sorted, each an OpenEXR file (its header
    read); fewer than two raise ``InvalidArgument`` naming ``option``."""
    files = sorted(glob.glob(os.path.expanduser(pattern)))
    if len(files) < 2:
        raise InvalidArgument(f"{option} {pattern!r}: matches {len(files)} file(s); give a "
                              "glob (quoted) matching at least 2 independently seeded passes")
    for f in files:
        colour_channels(f)
    return files


def pass_stats(pattern: str, *, option: str = "--test-passes", keep: bool = False) -> ImageStats:
    """Mean, variance (ddof = 1) and n = K of the K pass images matching ``pattern``.

    The passes must be independent renders (different seeds): two identical files mean
    the renderer reused its seed, and are refused, as are fewer than two passes and
    passes of different sizes. Pixels are accumulated one pass at a time (Welford), so
    K large images need the memory of three; ``keep=True`` keeps the K images too
    (``passes``: what ``compare_images`` needs where a splatting filter correlates
    pixels).
    """
    files = pass_files(pattern, option=option)     # every input readable before any work
    mean = m2 = None
    seen: dict[str, str] = {}
    notes = set()
    kept = []
    for k, f in enumerate(files, start=1):
        img, note = read_radiance(f)
        if note:
            notes.add("alpha channels ignored")
        digest = hashlib.sha256(np.ascontiguousarray(img).tobytes()).hexdigest()
        if digest in seen:
            raise InvalidArgument(f"{option}: {f} is identical to {seen[digest]}: the passes "
                                  "must be rendered with different seeds")
        seen[digest] = f
        if mean is None:
            mean, m2 = np.zeros_like(img), np.zeros_like(img)
        elif img.shape != mean.shape:
            raise InvalidArgument(f"{option}: {f} has shape {img.shape}, {files[0]} has "
                                  f"{mean.shape}; all passes must have one size")
        if keep:
            kept.append(img)
        delta = img - mean
        mean += delta / k
        m2 += delta * (img - mean)
    # half passes (Mitsuba's default film format): their rounding, 2^-11 of a value, is
    # no evidence, though their mean and variance are computed in float64 (a correct
    # renderer's half passes failed against float ones with p = 0: an outside review);
    # one half pass is enough (4 half passes among 12 float ones of a correct render
    # failed with p = 4e-42 until 7 December: the mean holds their rounding)
    half = any("half" in colour_types(f) for f in files)
    return ImageStats(mean=mean, var=m2 / (len(files) - 1), n=len(files), files=tuple(files),
                      notes=tuple(sorted(notes)), passes=np.stack(kept) if keep else None,
                      precision=np.float16 if half else None)
