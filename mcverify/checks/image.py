"""Pixelwise statistical comparison of two renders (ours or anyone's against a reference).

Three tests of the same null hypothesis ("both images have the same expected value in
every pixel"), each at α/3 (Bonferroni):

1. **global**: the image mean of each channel, z-tests of the differences (Bonferroni
   across channels, whose values are correlated: one path gives all three). It sees a
   light 2 % too bright long before any single pixel does.
2. **blocks**: means of ``block × block`` pixel blocks per channel, and of blocks half
   and twice that side, z-tests under one Holm correction (Jung, Hanika, Dachsbacher,
   JCGT 2020, at three scales). They see a local bias, one wall's albedo off by 10 %, a
   small object's by 50 %, and say where.
3. **pixels**: per-pixel Welch t-tests under Benjamini–Hochberg. Under the global null
   BH's FDR control is family-wise control, and the adjusted p-values form the p-map.

Tests 1 and 2 sum per-pixel variances, which is right only if pixels are independent. A
splatting reconstruction filter (Mitsuba's default gaussian, tent) makes neighbouring
pixels of one render share samples, and their sum's variance is then larger than the
sum of theirs. Given the pass images behind each mean (``test_passes``/``ref_passes``),
the image and block means are compared by Welch t-tests on the K pass-level means
instead: those are i.i.d. across independent passes however the pixels of a pass
correlate. A pixel's K pass values are i.i.d. too, so test 3 is unchanged.

A pixel with zero variance on both sides (e.g. black background) is equal (p = 1) or
different (p = 0) by its values alone, to float32 resolution at the image's scale.
"""

from __future__ import annotations

import dataclasses
import math
import re
import time

import numpy as np

from .. import _validate as validate
from .. import stats
from ..errors import InvalidArgument
from ..result import CheckResult

__all__ = ["compare_images", "perceptual_metrics"]

#: Per-sample variances of the two sides further apart than this (in the median pixel)
#: are noted as a likely wrong ``test_spp``/``ref_spp``.
SPP_RATIO_LIMIT = 8.0
#: The three tests of ``compare_images``.
TESTS = ("global", "blocks", "pixels")


def _as_image(name, a, shape=None):
    raw = validate.as_array(name, a)
    if not validate.real_dtype(raw.dtype):
        raise InvalidArgument(f"{name}: must be an array of real numbers, got dtype "
                              f"{raw.dtype}")
    a = raw.astype(np.float64)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3:
        raise InvalidArgument(f"{name}: expected shape (H, W) or (H, W, C), got {a.shape}")
    if a.size == 0:
        raise InvalidArgument(f"{name}: empty image (shape {a.shape}); nothing to compare")
    if shape is not None and a.shape != shape:
        raise InvalidArgument(f"{name}: shape {a.shape} differs from test_mean's {shape}"
                              + (shape_hint(shape, a.shape) if name == "ref_mean" else ""))
    if not np.all(np.isfinite(a)):
        raise InvalidArgument(f"{name}: contains NaN/Inf at "
                              f"{np.argwhere(~np.isfinite(a))[0].tolist()}")
    return a


def shape_hint(test_shape, ref_shape) -> str:
    """What a test image's shape (H, W, C) suggests where it is not the reference's: a
    transposed (column-major) grid, another resolution, an alpha channel. Without it
    an RGBA image was refused as "ref_mean: shape (16, 24, 3) differs from test_mean's
    (16, 24, 4)", blaming the reference and naming no cause (an outside review)."""
    (th, tw, tc), (rh, rw, rc) = test_shape, ref_shape
    if (th, tw) == (rw, rh) and th != tw and tc == rc:
        return ("; the test image's rows and columns are the reference's swapped: a "
                "column-major (transposed) image? transpose it")
    if tc == rc and th * rw == tw * rh and th != rh:
        return (f"; the test image has {th / rh:.3g} times the reference's resolution: "
                f"render it at the reference's {rw} x {rh} pixels")
    if (th, tw) == (rh, rw) and tc == rc + 1:
        return (f"; one channel more than the reference: an alpha? compare the colour "
                f"channels, test_mean[..., :{rc}] (its variance's too)")
    return ""


#: Relative differences that are rounding, not evidence, between inputs of float32 or finer
#: (a renderer summing hundreds of float32 samples drifts that much on a constant pixel).
ROUNDING = 2.0 ** -16


def _rounding(*arrays) -> tuple[float, float]:
    """(relative, absolute) rounding of the coarsest float type among the inputs: a half
    image (OpenEXR's half, Mitsuba's default film format) rounds each value by up to
    2^-11 of it and anything below 2^-25 to 0, far beyond ``ROUNDING``; a correct
    renderer's half image of a directly seen emitter of radiance 0.7 (zero variance on
    both sides) failed against a float reference with p = 0 (an outside review)."""
    rel, tiny = ROUNDING, 0.0
    for a in arrays:        # arrays, or a numpy dtype (``compare_images``' ``precision``)
        dtype = validate.numpy_dtype(a)
        if dtype is not None and np.issubdtype(dtype, np.floating):
            info = np.finfo(dtype)
            rel, tiny = max(rel, float(info.eps)), max(tiny, float(info.smallest_subnormal))
    return rel, tiny


def _floating_type(name: str, v) -> np.dtype:
    """``v`` as a numpy floating dtype, or InvalidArgument naming ``name``."""
    try:
        dtype = np.dtype(v)
    except TypeError:
        dtype = None
    if dtype is None or not np.issubdtype(dtype, np.floating):
        raise InvalidArgument(f"{name}={v!r}: must be a numpy floating type (np.float16, "
                              "np.float32, np.float64)")
    return dtype


def _display_scale(ref) -> float:
    """The reference's 99th-percentile luminance: the exposure both ΔE maps use."""
    lum = ref @ np.array([0.2126, 0.7152, 0.0722])
    return max(float(np.percentile(lum, 99)), 1e-12)


def _colour():
    """colour-science, imported keeping numpy's print options: its import sets
    ``np.set_printoptions(legacy="1.13")`` for the whole process, so a caller's arrays
    printed otherwise (``[ 0.5  1. ]`` for ``[0.5 1. ]``) after a ``compare_images``."""
    with np.printoptions():
        import colour

    return colour


def delta_e2000(test, ref) -> np.ndarray:
    """Per-pixel CIEDE2000 colour difference of two linear-sRGB HDR images (H, W, 3),
    both divided by the reference's 99th-percentile luminance and clipped to [0, 1] (ΔE is
    defined for display colours; 1 is about the smallest difference a person notices)."""
    colour = _colour()

    scale = _display_scale(ref)
    space = colour.RGB_COLOURSPACES["sRGB"]
    labs = [colour.XYZ_to_Lab(colour.RGB_to_XYZ(np.clip(img / scale, 0.0, 1.0), space,
                                                 apply_cctf_decoding=False))
            for img in (test, ref)]
    return np.asarray(colour.delta_E(labs[0], labs[1], method="CIE 2000"))


def delta_e_itp(test, ref) -> np.ndarray:
    """Per-pixel ΔE ITP (ITU-R BT.2124) of two linear-sRGB HDR images: the reference's
    99th-percentile luminance is shown at 100 cd/m², brighter pixels keep their HDR
    values (ICtCp's PQ encoding covers them); 1 is about a just-noticeable difference."""
    colour = _colour()

    scale = _display_scale(ref)
    # colour's ICtCp takes absolute luminance in cd/m² (1.0 is 1 cd/m²)
    ictcp = [colour.RGB_to_ICtCp(colour.RGB_to_RGB(np.maximum(img, 0.0) * (100.0 / scale),
                                                    "sRGB", "ITU-R BT.2020"))
             for img in (test, ref)]
    return np.asarray(colour.difference.delta_E_ITP(ictcp[0], ictcp[1]))


def _as_passes(name, a, n, shape):
    """Pass images (K, H, W[, C]) as float64 (K, H, W, C) with K == n, or None."""
    if a is None:
        return None
    raw = validate.as_array(name, a)
    if raw.ndim == len(shape):             # (K, H, W) for single-channel means
        raw = raw[..., None]
    if raw.ndim != 4 or raw.shape[1:] != shape or raw.shape[0] != n:
        raise InvalidArgument(f"{name}: expected {n} pass images of shape {shape} "
                              f"(an array ({n}, H, W[, C])), got shape {raw.shape}")
    return _as_image(name, raw.reshape(n * shape[0], *shape[1:])).reshape(n, *shape)


def block_sides(block: int, h: int, w: int) -> tuple[int, ...]:
    """The block sides the block test uses: ``block`` and, where they are blocks of more
    than one pixel and less than the whole image, half and twice it (8: 4, 8 and 16
    pixels). A difference is found best by blocks of its own size: a 4 × 4 patch 50 %
    off in 8 × 8 blocks was found in 12 of 200 seeded trials, with the three sides under
    one Holm correction in 108 (gamma noise, 32 values a pixel, α = 0.01)."""
    return tuple(s for s in (block // 2, block, 2 * block)
                 if s == block or (s >= 2 and s < max(h, w)))


def _block_means(img, block):
    """Means of ``block × block`` pixel blocks (edge blocks may be smaller) over the two
    axes before the last of ``img`` (..., H, W, C): (..., by, bx, C). Sums by
    ``np.add.reduceat``: a Python loop over blocks took 0.8 s of a 1280 × 720
    comparison at side 4 (found by review)."""
    h, w = img.shape[-3:-1]
    sums = np.add.reduceat(np.add.reduceat(np.asarray(img, dtype=np.float64),
                                           np.arange(0, h, block), axis=-3),
                           np.arange(0, w, block), axis=-2)
    return sums / _block_sizes(h, w, block)


def _block_variance(v, side):
    """(variance of each ``side``-block's mean, its effective number of pixels) from
    per-pixel variances of the mean ``v`` (H, W, C): the block mean's variance is
    Σ v / k², and (Σ v)² / Σ v² counts the pixels that carry it, from 1 (one pixel
    dominates) to k (equal pixels); inf for a block of zero variance."""
    h, w = v.shape[:2]
    k = _block_sizes(h, w, side)
    mean_v, mean_v2 = _block_means(v, side), _block_means(v * v, side)
    with np.errstate(divide="ignore", invalid="ignore"):
        pixels = k * mean_v * mean_v / mean_v2
    return mean_v / k, np.where(mean_v2 > 0, pixels, np.inf)


def _block_variances(v_a, n_a, v_b, n_b, side):
    """``[(se², dof)]`` of each side's ``side``-block means (``_block_variance``): a sum of
    per-pixel estimates of n - 1 degrees of freedom has Satterthwaite's (n - 1) times the
    pixels that carry it. Both sides count those pixels, and the smaller count serves
    both: from few values a pixel's variance is often caught far low (2 passes: below
    1/1000 of its value in 2.5 % of pixels), and where that pixel carries its block's
    variance the block looks like many equal pixels, many degrees of freedom, just as
    its variance comes out low. The side with more values sees the dominant pixel. One
    bright pixel in each 4 × 4 block (30 times the noise) raised 12 false alarms in 200
    seeds at α = 0.01 with each side's own count, 16 passes against a reference of 2 (13
    the other way round); none with the smaller. A block of zero variance on both sides
    gets n - 1."""
    (se_a, px_a), (se_b, px_b) = _block_variance(v_a, side), _block_variance(v_b, side)
    pixels = np.minimum(px_a, px_b)
    return [(se, np.where(np.isfinite(pixels), (n - 1) * pixels, float(n - 1)))
            for se, n in ((se_a, n_a), (se_b, n_b))]


def _block_sizes(h, w, block):
    """Pixels in each ``block × block`` block of an H × W image: (by, bx, 1)."""
    return np.minimum(block, h - np.arange(0, h, block))[:, None, None] * \
        np.minimum(block, w - np.arange(0, w, block))[None, :, None]


#: Below this maximum luminance of the reference, HDR-FLIP is not measured: its automatic
#: exposure range runs from log2(k / Y_max) to log2(k / max(Y_median, ~1.2e-7)), reversed
#: when Y_max < ~1.2e-7, and flip-evaluator then exits the whole process (an all-black
#: reference, e.g. a scene whose only light is hidden at max_depth 1, killed render-check).
FLIP_MIN_LUMINANCE = 1e-6


def flip_error(test, ref) -> np.ndarray | None:
    """Per-pixel HDR-FLIP error (Andersson et al. 2021, NVIDIA's ``flip-evaluator``) of two
    linear-sRGB HDR images (H, W, 3): 0 identical, 1 the largest difference. FLIP models
    what a viewer sees when alternating the two images at 67 pixels per degree, over the
    exposures of the reference's range (ACES tone mapping); negative values count as 0.
    None (not measured) for a reference darker than :data:`FLIP_MIN_LUMINANCE` everywhere,
    where FLIP's exposure range is undefined."""
    import flip_evaluator

    luminance = np.maximum(ref, 0.0) @ np.array([0.2126, 0.7152, 0.0722])
    if not luminance.max() >= FLIP_MIN_LUMINANCE:
        return None

    def prepared(img):
        return np.ascontiguousarray(np.maximum(img, 0.0), dtype=np.float32)

    err, _, _ = flip_evaluator.evaluate(prepared(ref), prepared(test), "HDR",
                                        applyMagma=False, computeMeanError=False)
    return np.asarray(err, dtype=np.float64).reshape(ref.shape[:2])


#: The detail keys :func:`perceptual_metrics` fills (None where not measured).
PERCEPTUAL_KEYS = tuple(f"{k}_{s}" for k in ("delta_e2000", "delta_e_itp", "flip")
                        for s in ("mean", "p99"))


def perceptual_metrics(test, ref) -> tuple[dict, dict]:
    """What a viewer would see of the difference between two 3-channel linear-sRGB
    images: ``(details, maps)``, details the means and 99th percentiles of ΔE2000, ΔE ITP
    and HDR-FLIP, maps the per-pixel ``delta_e2000``, ``delta_e_itp`` and ``flip``. Not
    evidence of a bias (that is the tests' job); a size for it."""
    test = _as_image("test", test)
    ref = _as_image("ref", ref, test.shape)
    if test.shape[2] != 3:
        return dict.fromkeys(PERCEPTUAL_KEYS), {}
    maps = {"delta_e2000": delta_e2000(test, ref), "delta_e_itp": delta_e_itp(test, ref),
            "flip": flip_error(test, ref)}
    details = dict.fromkeys(PERCEPTUAL_KEYS)
    for k, m in maps.items():
        if m is not None:
            details[f"{k}_mean"] = float(m.mean())
            details[f"{k}_p99"] = float(np.percentile(m, 99))
    return details, {k: m for k, m in maps.items() if m is not None}


def _percent(r: float, spec: str) -> str:
    """``r`` as a percentage in ``spec``, or in three significant digits from 10^6 % on:
    a test image holding a 1e30 firefly against a reference of 0.5 printed its block as
    "+200000000000000005366162204393472.0%" (an outside review)."""
    return format(r, spec) if abs(r) < 1e4 else f"{100 * r:+.3g}%"


def _values(v) -> str:
    """A pixel's channels to 6 significant digits (4 decimals printed a pixel 0.02 % off as
    equal to its reference)."""
    return np.array2string(np.asarray(v, dtype=np.float64),
                           formatter={"float_kind": lambda x: f"{x:.6g}"})


#: Below this many values a side (passes), pixels of zero variance on both sides that
#: differ get ``_EXACT_NOTE``: two correct renders of 3 and 2 passes of 4 samples of a
#: path found with probability 0.02 failed 42 of 60 seeds at α = 0.01 so, a pass value
#: being 0, or its one hit, again and again (none with 16 passes a side; an outside
#: review measured 69-100 % at 2-3 passes).
FEW_VALUES = 16
_EXACT_NOTE = ("note: {k} rejected pixel(s) have zero variance on both sides ({nt} and {nr} "
               "values), so they were compared exactly; where a pass's value is discrete "
               "(few samples of a rare path: 0, or its one hit) passes coincide by chance "
               "and such a difference is no evidence: give more passes, or more samples a "
               "pass")

#: The counts in the note on the sides' per-sample variances (``check test_spp=64 and
#: ref_spp=64 (samples per value, e.g. per pass)``), which ``compare`` and ``render_check``
#: re-word in their own terms: one pattern for the note's one wording.
SPP_NOTE = re.compile(r"check test_spp=(\d+) and ref_spp=(\d+) \(samples per value, "
                      r"e\.g\. per pass\)")

#: Bytes a pixel takes at compare_images' peak, above its inputs (tracemalloc, at 512²
#: and 1024²: 434 without the perceptual metrics, 710 with them), and for each pass
#: image given (24 a pass on both sides: 900 and 1092 with 4 and 8 passes a side).
_BYTES_PER_PIXEL, _PERCEPTUAL_BYTES_PER_PIXEL, _PASS_BYTES_PER_PIXEL = 440, 280, 24


def _fits(shape, perceptual, test_passes, ref_passes) -> None:
    """Refuse, before any work, images whose comparison would need more than half the
    memory available: two 4096 × 4096 EXRs under ``ulimit -v 4000000`` ended in
    "unexpected MemoryError: Unable to allocate 384. MiB", naming nothing (an outside
    review)."""
    pixels = int(np.prod(shape[:2], dtype=np.int64))
    k = sum(int(np.shape(p)[0]) if np.ndim(p) >= 1 else 0
            for p in (test_passes, ref_passes) if p is not None)
    each = _BYTES_PER_PIXEL + (_PERCEPTUAL_BYTES_PER_PIXEL if perceptual is True else 0) \
        + _PASS_BYTES_PER_PIXEL * k
    validate.fits(pixels * each, f"test_mean: {shape[1]} x {shape[0]} pixels"
                  + (f" and {k} pass images" if k else "") + " need",
                  f" to compare ({each} bytes a pixel)",
                  "perceptual=False saves 280 a pixel" if perceptual is True else None)


#: Ways a renderer may store a correct image other than the reference does, each undone
#: on the test side by a function of an image array and the axis of its rows (0 for a
#: mean or variance (H, W[, C]), 1 for pass images (K, H, W[, C])): flips and a
#: transpose of the pixel grid, and channels in reverse order (OpenCV's BGR).
_LAYOUTS = (
    ("flipped vertically (row 0 at the bottom, as OpenGL stores an image): flip its rows",
     lambda x, o: np.flip(x, o)),
    ("flipped horizontally: flip its columns", lambda x, o: np.flip(x, o + 1)),
    ("rotated by 180°: flip its rows and its columns", lambda x, o: np.flip(x, (o, o + 1))),
    ("transposed (column-major, rows and columns swapped): transpose it",
     lambda x, o: np.swapaxes(x, o, o + 1)),
    ("in BGR order (OpenCV's): reverse its channels", lambda x, o: x[..., ::-1]),
)

#: Constant factors with a likely cause, named where the test image is within 1 % of one
#: of them times the reference.
_FACTORS = ((2.0, "2 (an exposure of +1 stop)"), (0.5, "1/2 (an exposure of -1 stop)"),
            (math.pi, "π (irradiance against radiance, or a BSDF's 1/π left out)"),
            (1 / math.pi, "1/π (radiance against irradiance, or a BSDF's 1/π twice)"),
            (4 * math.pi, "4π (a point light's power against its intensity)"),
            (1 / (4 * math.pi), "1/(4π) (a point light's intensity against its power)"))


def _srgb_decoded(x):
    """sRGB's decoding (IEC 61966-2-1) of display values in [0, 1] to linear ones, and its
    derivative (the delta method carries a variance through it)."""
    x = np.clip(x, 0.0, 1.0)
    low = x <= 0.04045
    base = (x + 0.055) / 1.055
    return (np.where(low, x / 12.92, base ** 2.4),
            np.where(low, 1 / 12.92, 2.4 / 1.055 * base ** 1.4))


def _factor_named(k: float) -> str:
    for value, text in _FACTORS:
        if abs(k / value - 1) <= 0.01:
            return f"{k:.4g} times the reference, about {text}: divide it by that"
    return (f"{k:.4g} times the reference everywhere (a constant factor: an emitter's "
            "strength, the exposure, a unit): find where the factor comes from")


def _undone(tm, tv, test_passes, rm):
    """(description, (mean, var, passes) undone) of each convention the test image (its
    mean and variance arrays ``tm``, ``tv``) may have been stored in: ``_LAYOUTS`` where
    the undone grid has the reference's (``rm``) shape, a constant factor (the ratio of
    the image means), and sRGB encoding where every value lies in [0, 1]."""
    tp = None if test_passes is None else validate.as_array("test_passes", test_passes)
    for text, undo in _LAYOUTS:
        if "BGR" in text and (tm.ndim != 3 or tm.shape[2] != 3):
            continue
        if undo(tm, 0).shape == rm.shape:
            yield text, (undo(tm, 0), undo(tv, 0), None if tp is None else undo(tp, 1))
    tm, tv = tm.astype(np.float64), tv.astype(np.float64)
    tp = None if tp is None else tp.astype(np.float64)
    k = float(tm.sum() / rm.sum()) if rm.sum() > 0 and tm.sum() > 0 else math.nan
    if math.isfinite(k) and k != 1.0:
        yield _factor_named(k), (tm / k, tv / k ** 2, None if tp is None else tp / k)
    if tm.min() >= 0.0 and tm.max() <= 1.0 and (tp is None or (tp.min() >= 0.0 and
                                                                tp.max() <= 1.0)):
        linear, slope = _srgb_decoded(tm)
        passes = None if tp is None else _srgb_decoded(tp)[0]      # decoded once
        yield ("sRGB-encoded (gamma, a display image): compare the linear values the "
               "renderer computed, before its output transform",
               (linear if passes is None else passes.mean(axis=0), tv * slope ** 2, passes))


def _misfit(tm, tv, rm, rv, nt, nr) -> float:
    """How far a test image is from the reference: the mean over pixels of the squared
    Welch statistic, each clipped at 100 (a black pixel of zero variance against a lit
    one counts as 100, not as infinity). A screen for ``_convention``, never a verdict."""
    tm, tv, rm, rv = (np.asarray(a, dtype=np.float64) for a in (tm, tv, rm, rv))
    se2 = np.maximum(tv / nt + rv / nr, 1e-300)
    with np.errstate(over="ignore"):
        return float(np.mean(np.minimum((tm - rm) ** 2 / se2, 100.0)))


#: The level at which the undone image must differ from the image as given (``_moves``)
_MOVES_ALPHA = 1e-3


def _moves(undone, raw, kw) -> bool:
    """Whether undoing a convention moves the test image beyond its noise: the comparison
    itself, at ``_MOVES_ALPHA``, of the undone image against the image as given, fails (a
    grid of another shape moved by definition). On a false alarm of a flat or symmetric
    image a flip, BGR or a factor near 1 is fresh noise that then passes the rerun, and
    4 of 5 false alarms in 800 seeds of two correct flat renders carried such a guess,
    "looks flipped horizontally"; a mean squared statistic over all pixels, tried first,
    missed a small bright object flipped on a large background and, for a factor,
    overflowed at 1e152 (read-only reviews)."""
    m, v, _ = undone
    if m.shape != raw[0].shape:
        return True
    nt = kw["test_n"]
    return not _compare_images(m, raw[0], test_var=v, ref_var=raw[1], test_n=nt, ref_n=nt,
                               alpha=_MOVES_ALPHA, block=kw["block"],
                               perceptual=False).passed


def _convention(test_mean, ref_mean, kw):
    """Where a comparison failed: the convention of ``_undone`` which, undone, brings the
    test image closest to the reference, if the same comparison then passes (a note
    saying so and ``{"guess", "p_value"}``), else None. A guess never changes the
    verdict; it tells a user whose correct renderer wrote its image another way
    (upside down, gamma-encoded, a factor π off) where to look. Only a convention whose
    undoing moves the test image beyond its noise (``_moves``) is offered."""
    nt, nr = int(kw["test_n"]), int(kw["ref_n"])
    # read once, as the comparison read them (a torch tensor that requires grad raised
    # from np.asarray here, where the comparison had read it; a read-only review)
    raw = [validate.as_array(k, a) for k, a in (
        ("test_mean", test_mean), ("test_var", kw["test_var"]), ("ref_mean", ref_mean),
        ("ref_var", kw["ref_var"]))]
    tm, tv, rm, rv = (np.asarray(a, dtype=np.float64) for a in raw)
    candidates = list(_undone(raw[0], raw[1], kw["test_passes"], raw[2]))
    if not candidates:
        return None
    misfits = [_misfit(m, v, rm, rv, nt, nr) for _, (m, v, _) in candidates]
    best = int(np.argmin(misfits))
    if not misfits[best] < _misfit(tm, tv, rm, rv, nt, nr) \
            or not _moves(candidates[best][1], raw, kw):
        return None
    text, (m, v, p) = candidates[best]
    # the undone image in the type the test side was stored in: its rounding no evidence
    stored = [a.dtype for a in raw[:2] if np.issubdtype(a.dtype, np.floating)]
    if kw["precision"] is not None:
        stored.append(_floating_type("precision", kw["precision"]))
    precision = max(stored, key=lambda d: np.finfo(d).eps) if stored else None
    undone = _compare_images(m, raw[2], **{**kw, "test_var": v, "ref_var": raw[3],
                                           "test_passes": p, "precision": precision},
                             perceptual=False)
    if not undone.passed:
        return None
    return {"message": f"note: the test image looks {text}; so undone it agrees with the "
                       f"reference (p = {undone.p_value:.3g})",
            "details": {"guess": text, "p_value": float(undone.p_value)}}


def _compare_images(test_mean, ref_mean, *, test_var, ref_var, test_n, ref_n,
                   alpha: float = 0.01, block: int = 8, name: str = "image",
                   tests=TESTS, test_passes=None, ref_passes=None,
                   perceptual: bool = True, test_spp=None, ref_spp=None,
                   precision=None) -> CheckResult:
    """``compare_images`` without its guess of the test image's convention."""
    t0 = time.perf_counter()
    stored = () if precision is None else (_floating_type("precision", precision),)
    rel_rounding, tiny = _rounding(test_mean, ref_mean, test_var, ref_var, test_passes,
                                   ref_passes, *stored)
    tm = _as_image("test_mean", test_mean)
    _fits(tm.shape, perceptual, test_passes, ref_passes)
    rm = _as_image("ref_mean", ref_mean, tm.shape)
    tv = _as_image("test_var", test_var, tm.shape)
    rv = _as_image("ref_var", ref_var, tm.shape)
    for label, v in (("test_var", tv), ("ref_var", rv)):
        bad = validate.negatives(v)
        if bad:
            count, first, value = bad
            raise InvalidArgument(f"{label}: {count} negative variance(s) (first at {first}: "
                                  f"{value:.6g}); variances must be >= 0")
    # a variance stored as 0 in a coarse float type is only below half its smallest
    # subnormal (half: 2^-25); as exactly 0 it made a faint pixel of a half image, whose
    # variance underflowed, differ from a black reference pixel with certainty (the
    # type it was stored in: its own, or ``precision`` where that is coarser)
    tv_zero, rv_zero = _rounding(test_var, *stored)[1] / 2, _rounding(ref_var, *stored)[1] / 2
    tv, rv = np.maximum(tv, tv_zero), np.maximum(rv, rv_zero)
    # counts beyond 2^53 are not exact in float64 (10^30 reached scipy as an object)
    nt = validate.integer("test_n", test_n, minimum=2, maximum=2 ** 53)
    nr = validate.integer("ref_n", ref_n, minimum=2, maximum=2 ** 53)
    alpha = validate.probability("alpha", alpha)
    block = validate.integer("block", block, minimum=1)
    perceptual = validate.boolean("perceptual", perceptual)
    name = validate.label(name, "image")
    tests = (tests,) if isinstance(tests, str) else tuple(tests)
    if not tests or len(set(tests)) != len(tests) or not set(tests) <= set(TESTS):
        raise InvalidArgument(f"tests={tests}: a non-empty selection of {TESTS}")
    if (test_passes is None) != (ref_passes is None):
        raise InvalidArgument("test_passes/ref_passes: give both sides' pass images or "
                              "neither (a correlated-pixel variance needs both)")
    if (test_spp is None) != (ref_spp is None):
        raise InvalidArgument("test_spp/ref_spp: give both sides' samples per value or "
                              "neither (the variance floor scales one by their ratio)")
    floor_info = None
    if test_spp is not None:
        ts = validate.integer("test_spp", test_spp, minimum=1)
        rs = validate.integer("ref_spp", ref_spp, minimum=1)
        # both ways: a reference of few passes misses rare paths as well (16 passes of
        # 64 spp against 2 of Mitsuba's own: 10 false alarms in 200 seeds on the Cornell
        # box, pixels whose 2 reference passes were both 0; none with the floor)
        floor, ref_floor = rv * (rs / ts), tv * (ts / rs)
        # per-sample variances, test over reference, in the median pixel where both have
        # one: near 1 for two renderers of the same scene, whatever their passes (ours
        # against Mitsuba: 0.5-1.3 on the reference scenes)
        # (a variance at the values' rounding is none: a pixel that sees one texel under
        # a directional light has 0 here, floored at half the smallest subnormal above,
        # and ~1e-15 in Mitsuba's float32 sums; their ratio, 1e-38, noted a wrong sample
        # count on every such render-check, the counts right)
        both = ((tv > (rel_rounding * np.abs(tm)) ** 2 + tiny)
                & (rv > (rel_rounding * np.abs(rm)) ** 2 + tiny))
        ratio = float(np.median(tv[both] * ts / (rv[both] * rs))) if both.any() else None
        floor_info = {"test_spp": ts, "ref_spp": rs,
                      "raised_fraction": float(np.mean(tv < floor)),
                      "ref_raised_fraction": float(np.mean(rv < ref_floor)),
                      "per_sample_variance_ratio": ratio}
        tv, rv = np.maximum(tv, floor), np.maximum(rv, ref_floor)
    tp = _as_passes("test_passes", test_passes, nt, tm.shape)
    rp = _as_passes("ref_passes", ref_passes, nr, tm.shape)
    for label, passes, mean in (("test", tp, tm), ("ref", rp, rm)):
        # the image and block tests read the passes, the pixel tests the mean: a mean
        # that is not its passes' mean (1.5 times it) was compared without a word
        of_passes = None if passes is None else passes.mean(axis=0)
        if of_passes is not None and not np.allclose(
                of_passes, mean, rtol=max(1e-4, rel_rounding),
                atol=1e-6 * max(float(np.abs(mean).max()), 1e-300)):
            worst = float(np.max(np.abs(of_passes - mean)))
            raise InvalidArgument(f"{label}_mean: not the mean of {label}_passes (largest "
                                  f"difference {worst:.3g}); give the mean of the passes")
    correlated = tp is not None
    h, w, c = tm.shape
    diff = tm - rm
    # Rounding is no evidence. A renderer that sums hundreds of samples in float32 drifts
    # on a constant pixel (Mitsuba at 512 spp: 0.899996 for 0.9, variance 0), and a
    # variance can underflow (one 1e-22 contribution among zeros). So differences within
    # 2^-16 of the compared values (half images: half's epsilon, 2^-10, and its smallest
    # subnormal; ``_rounding``) (plus 2^-24 of the image's scale, for values near 0)
    # pass; zero-variance values compare exactly beyond that. The scale is the median
    # non-zero magnitude: the largest one let a single pixel at 1e6 (a visible sun, a
    # firefly) make every difference under 0.06 no evidence, and a 3 % bias passed.
    magnitudes = np.abs(np.concatenate([tm.ravel(), rm.ravel()]))
    magnitudes = magnitudes[magnitudes > 0]
    floor = 2.0 ** -24 * max(float(np.median(magnitudes)) if magnitudes.size else 0.0,
                             1e-300) + tiny

    def tol(a, b):
        return rel_rounding * np.maximum(np.abs(a), np.abs(b)) + floor

    # 1. global, per channel: the colour channels of one path are strongly correlated
    #    (identical on grey scenes), so they cannot be pooled as independent values;
    #    pixels within a channel are independent. Bonferroni across channels.
    gtol = tol(tm.mean(axis=(0, 1)), rm.mean(axis=(0, 1)))
    if correlated:
        gt, gr = tp.mean(axis=(1, 2)), rp.mean(axis=(1, 2))          # (K, C) pass means
        p_channels = stats.welch_t_beyond(gt.mean(0) - gr.mean(0), gt.var(0, ddof=1), nt,
                                          gr.var(0, ddof=1), nr, gtol)
    else:   # the whole image as one block
        (va, da), (vb, db) = _block_variances(tv / nt, nt, rv / nr, nr, max(h, w))
        p_channels = stats.welch_t_pooled_beyond(diff.mean(axis=(0, 1)), va[0, 0], da[0, 0],
                                                 vb[0, 0], db[0, 0], gtol)
    p_global = stats.bonferroni_min(p_channels)

    # 2. blocks (edge blocks may be smaller), at each side in ``sides``, all under one Holm
    sides = block_sides(block, h, w)
    scales = []                                 # (difference, reference, p) per side
    for side in sides:
        bref = _block_means(rm, side)
        if correlated:
            bt, br = _block_means(tp, side), _block_means(rp, side)   # (K, by, bx, C)
            bdiff = bt.mean(0) - br.mean(0)
            p = stats.welch_t_beyond(bdiff, bt.var(0, ddof=1), nt, br.var(0, ddof=1), nr,
                                     tol(bref + bdiff, bref))
        else:
            bdiff = _block_means(diff, side)
            # Var(mean of k independent pixels) = Σ se² / k², each side's estimate with
            # its own degrees of freedom: a reference of 2 passes gives each pixel's
            # variance 1, and a z-test treating the block's as known raised 9 false
            # alarms in 100 (normal pass values; 75 with skewed ones)
            (va, da), (vb, db) = _block_variances(tv / nt, nt, rv / nr, nr, side)
            p = stats.welch_t_pooled_beyond(bdiff, va, da, vb, db, tol(bref + bdiff, bref))
        scales.append((bdiff, bref, p))
    adjusted = stats.holm(np.concatenate([p.ravel() for *_, p in scales]))
    p_blocks_adj, at = [], 0
    for *_, p in scales:
        p_blocks_adj.append(adjusted[at:at + p.size].reshape(p.shape))
        at += p.size

    # 3. pixels: Welch t (dof from stats.welch_dof)
    p_pix = stats.welch_t_beyond(diff, tv, nt, rv, nr, tol(tm, rm))
    p_pix_adj = stats.benjamini_hochberg(p_pix.ravel()).reshape(p_pix.shape)
    p_map = p_pix_adj.min(axis=2)

    level = alpha / len(tests)
    found = []
    if "global" in tests and p_global <= level:
        found.append("global")
    # (side index, i, j, channel) of every rejected block, the clearest first
    rejected_blocks, p_rejected = [np.zeros((0, 4), dtype=int)], [np.zeros(0)]
    for k, adj in enumerate(p_blocks_adj if "blocks" in tests else ()):
        hit = adj <= level              # argwhere and the mask both walk in C order
        rejected_blocks.append(np.column_stack([np.full(hit.sum(), k), np.argwhere(hit)]))
        p_rejected.append(adj[hit])
    rejected_blocks = np.concatenate(rejected_blocks)[
        np.argsort(np.concatenate(p_rejected), kind="stable")]
    if len(rejected_blocks):
        found.append("blocks")
    rejected_px = (p_pix_adj <= level) if "pixels" in tests else np.zeros(p_pix_adj.shape, bool)
    if rejected_px.any():
        found.append("pixels")
    min_blocks = float(adjusted.min())
    minima = {"global": p_global, "blocks": min_blocks, "pixels": p_pix_adj.min()}
    p_value = stats.bonferroni_min([minima[t] for t in tests])

    def relative(k, i, j, c):
        bdiff, bref, _ = scales[k]
        return float(bdiff[i, j, c] / abs(bref[i, j, c])) if bref[i, j, c] != 0 else math.nan

    blocks_info = [{"side": sides[k], "block": [int(i), int(j)], "channel": int(c),
                    "pixels": [int(i * sides[k]), int(j * sides[k])],
                    "relative_difference": relative(k, i, j, c),
                    "p_adjusted": float(p_blocks_adj[k][i, j, c])}
                   for k, i, j, c in rejected_blocks[:50]]
    denom = rm ** 2 + 1e-2
    messages = []
    if found:
        # relative to the reference's mean, unless that is 0 (a black reference: the
        # ratio to 1e-300 printed a 300-digit percentage)
        rel = (_percent(diff.mean() / abs(rm.mean()), "+.2%") if rm.mean() != 0
               else "the reference's mean is 0")
        # the sign said nothing of its side: test minus reference (an outside review)
        messages.append(f"found by {', '.join(found)}: image mean differs by "
                        f"{diff.mean():+.4g} ({rel}; the test image minus the reference)"
                        f"; {len(rejected_blocks)} blocks and "
                        f"{rejected_px.any(axis=2).mean():.2%} of pixels rejected")
        # where: the printed verdict said how many blocks, never which (only the JSON did)
        if blocks_info:
            b = blocks_info[0]
            y, x = b["pixels"]
            # two significant digits below 0.1 %: a precise block 0.02 % off printed +0.0%
            d = b["relative_difference"]
            off = ("against a reference of 0" if not math.isfinite(d) else
                   _percent(d, "+.1%") if abs(d) >= 0.00095 else f"{100 * d:+.2g}%")
            messages.append(f"clearest block: pixels y {y}-{min(y + b['side'], h) - 1}, "
                            f"x {x}-{min(x + b['side'], w) - 1}, channel {b['channel']}, "
                            f"{off}")
        if rejected_px.any():
            y, x = np.unravel_index(int(np.argmin(np.where(rejected_px.any(axis=2), p_map,
                                                           np.inf))), p_map.shape)
            messages.append(f"clearest pixel: (y, x) = ({y}, {x}), test "
                            f"{_values(tm[y, x])} against reference {_values(rm[y, x])}")
            exact = int(np.count_nonzero((rejected_px & (tv <= tv_zero)
                                          & (rv <= rv_zero)).any(axis=2)))
            if exact and min(nt, nr) < FEW_VALUES:
                messages.append(_EXACT_NOTE.format(k=exact, nt=nt, nr=nr))
    ratio = floor_info and floor_info["per_sample_variance_ratio"]
    if ratio and not 1 / SPP_RATIO_LIMIT <= ratio <= SPP_RATIO_LIMIT:
        # a wrong sample count (total spp given for spp per pass) scales one side's floor:
        # raised by the factor, the other side's variance swamps the test (no power), a
        # loss the verdict does not show
        spps = f"test_spp={floor_info['test_spp']} and ref_spp={floor_info['ref_spp']}"
        messages.append(f"note: per sample, the test side's variance is {ratio:.3g} times "
                        f"the reference's in the median pixel: check {spps} (samples per "
                        "value, e.g. per pass); the variance floor scales each side's "
                        "variance by their ratio, and a wrong one takes the tests' power")
    seen, seen_maps = perceptual_metrics(tm, rm) if perceptual else \
        (dict.fromkeys(PERCEPTUAL_KEYS), {})
    maps = {"p_map": p_map, **seen_maps}
    details = {
        "found_by": found, "tests": list(tests), "alpha_per_test": level, "block": block,
        "pixels_correlated": correlated, "variance_floor": floor_info,
        "global": {"difference": float(diff.mean()),
                   "relative": float(diff.mean() / max(abs(rm.mean()), 1e-300)),
                   "p_value": p_global, "p_channels": [float(x) for x in p_channels]},
        "blocks": {"n": int(adjusted.size), "sides": list(sides),
                   "n_rejected": len(rejected_blocks), "rejected": blocks_info,
                   "min_p_adjusted": min_blocks},
        "rejected_fraction": float(rejected_px.any(axis=2).mean()),
        "min_pixel_p_adjusted": float(p_pix_adj.min()),
        "relmse": float(np.mean(diff ** 2 / denom)),
        "smape": float(np.mean(np.where(np.abs(tm) + np.abs(rm) > 0,
                                        2 * np.abs(diff) / (np.abs(tm) + np.abs(rm) + 1e-300),
                                        0.0))),
        **seen,
    }
    return CheckResult(name=name, passed=CheckResult.decide(p_value, alpha, ()),
                       p_value=p_value, statistic=float(diff.mean()), alpha=alpha,
                       n_samples=int(min(nt, nr)), seconds=time.perf_counter() - t0,
                       details=details, messages=tuple(messages), artifacts=maps)


def compare_images(test_mean, ref_mean, *, test_var, ref_var, test_n, ref_n,
                   alpha: float = 0.01, block: int = 8, name: str = "image",
                   tests=TESTS, test_passes=None, ref_passes=None,
                   perceptual: bool = True, test_spp=None, ref_spp=None,
                   precision=None) -> CheckResult:
    """Test that two renders have the same expected value in every pixel.

    Parameters
    ----------
    test_mean, ref_mean : arrays (H, W) or (H, W, C)
        Per-pixel means.
    test_var, ref_var : arrays of the same shape
        Per-pixel sample variance of the ``test_n`` / ``ref_n`` i.i.d. values (samples,
        or independent passes) averaged into each mean.
    test_n, ref_n : int
        Values per pixel (>= 2).
    alpha : float
        Family-wise level of the whole comparison.
    block : int
        Block side in pixels for the block tests (8: 64 blocks on a 64 × 64 image); blocks
        of half and twice the side are tested too (``block_sides``), all under one Holm
        correction.
    tests : sequence of {"global", "blocks", "pixels"}, or one of them as a string
        The tests to run, each at α / len(tests) (all three by default). The render
        gate's early looks, on a few passes, leave out the pixel t-tests: a pixel's
        variance from 4 passes is too uncertain on caustic pixels, while image and block
        means pool many pixels.
    test_passes, ref_passes : arrays (K, H, W[, C]), optional
        The i.i.d. pass images averaged into ``test_mean``/``ref_mean`` (K = ``test_n`` /
        ``ref_n``). Given both, the global and block tests estimate the variance of
        image and block means from the pass-level means (Welch t, K - 1 degrees of
        freedom a side): valid when pixels within a pass are correlated, as a splatting
        reconstruction filter makes them. ``details["pixels_correlated"]`` says which.
    test_spp, ref_spp : int, optional
        Samples per pixel behind each of a side's values (samples per pass). Given both,
        the test side's per-pixel variance is taken as at least the reference's scaled
        to the test side's samples, ``ref_var * ref_spp / test_spp``, and the
        reference's at least the test side's likewise: a few passes can
        miss rare bright paths altogether (a caustic), and then their mean and their
        variance both come out low, while the reference, with many more samples, has
        seen them. Where the tested renderer has the lower variance this costs power,
        never calibration. ``details["variance_floor"]`` says what was raised. Measured
        on the Cornell box (ours, 16 passes of 64 spp, against fresh 16 × 256-spp
        references): 2 false alarms in 20 without it, 0 with it.
    perceptual : bool
        Also measure how visible the difference is (:func:`perceptual_metrics`: ΔE2000,
        ΔE ITP, HDR-FLIP; 3-channel images). They decide nothing; the render gate computes
        them once, on its last look's image.
    precision : numpy floating type, optional
        The coarsest type the images were stored in before they were converted (half
        EXR passes that ``mcverify compare`` averages in float64): its rounding is no
        evidence, as for arrays of that type. Default: the arrays' own types.

    Returns
    -------
    CheckResult
        ``details``: ``found_by`` (which tests rejected), ``global``, ``blocks``
        (rejected blocks with their position and relative difference),
        ``rejected_fraction`` of pixels, ``relmse``, ``smape``, ``delta_e2000_mean`` and
        ``_p99``, ``delta_e_itp_mean`` and ``_p99``, ``flip_mean`` and ``_p99`` (CIEDE2000,
        ITU-R BT.2124 ΔE ITP and HDR-FLIP; 3-channel images with ``perceptual``, else
        None). ``artifacts``: ``p_map`` (per-pixel BH-adjusted p-values, the minimum over
        channels), ``delta_e2000``, ``delta_e_itp`` and ``flip`` maps; left out of JSON by
        default.

    Notes
    -----
    Pixel means of independent renders are independent across pixels (not across the
    channels of a pixel), so a channel's image mean has variance
    :math:`\\sum_p (s_{t,p}^2/n_t + s_{r,p}^2/n_r) / P^2`, and a block mean likewise;
    each side's sum is an estimate with Satterthwaite's degrees of freedom
    :math:`(n - 1)(\\sum_p v_p)^2 / \\sum_p v_p^2` (:math:`v_p = s_p^2/n`; the ratio
    taken as the smaller of the two sides', ``_block_variances``), and the
    difference is tested with Student's t (``stats.welch_t_pooled_beyond``), not as a
    z-score: with a reference of 2 or 3 passes, where a few pixels carry a block's
    variance, the sum has few degrees of freedom and a z-test raised false alarms in
    half of all seeds (``tests/mcverify/test_images.py``).
    Welch's t per pixel takes its degrees of freedom from ``stats.welch_dof`` (the
    Welch–Satterthwaite value at a conservative end of the variances' uncertainty). With
    pass images, the image (block) mean of pass k, :math:`g_k`, is i.i.d. over k on each
    side, and the difference of the two sides' averages of :math:`g_k` is Welch-t
    tested with the sample variances of the :math:`g_k`.

    Examples
    --------
    >>> import numpy as np, mcverify as mv
    >>> rng = np.random.default_rng(0)
    >>> a = rng.gamma(2.0, 0.5, (32, 32, 3, 64)); b = rng.gamma(2.0, 0.5, (32, 32, 3, 64))
    >>> mv.compare_images(a.mean(-1), b.mean(-1), test_var=a.var(-1, ddof=1),
    ...                   ref_var=b.var(-1, ddof=1), test_n=64, ref_n=64).passed
    True
    """
    kw = dict(test_var=test_var, ref_var=ref_var, test_n=test_n, ref_n=ref_n, alpha=alpha,
              block=block, name=name, tests=tests, test_passes=test_passes,
              ref_passes=ref_passes, test_spp=test_spp, ref_spp=ref_spp, precision=precision)
    result = _compare_images(test_mean, ref_mean, perceptual=perceptual, **kw)
    guess = None if result.passed else _convention(test_mean, ref_mean, kw)
    if guess is None:
        return dataclasses.replace(result, details={**result.details, "convention": None})
    return dataclasses.replace(result, messages=result.messages + (guess["message"],),
                               details={**result.details, "convention": guess["details"]})
