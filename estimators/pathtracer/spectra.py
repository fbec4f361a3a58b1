"""A ``<spectrum>`` read as Mitsuba's RGB variants read it, into the RGB the tracer renders.

Mitsuba's RGB variants (``scalar_rgb``, ``llvm_ad_rgb``, the ones the references are
rendered with) turn a spectrum into an sRGB colour once, when the scene loads:

- a uniform spectrum, ``value="0.5"``, is the number 0.5 for a reflectance or an index
  (as a ``<float>``), but for an emitter's radiance, irradiance or intensity the colour
  of an equal-energy spectrum in sRGB: 0.5 · (1.2048, 0.9483, 0.9089), pinkish, since
  sRGB's white is D65's;
- wavelength:value pairs (``value="400:0.1, 500:0.5"``, or a ``.spd`` file of
  ``wavelength value`` lines) are interpolated linearly between their wavelengths, zero
  outside them, and integrated against the CIE 1931 colour-matching functions over
  360–830 nm at 1000 points (a reflectance or an index weighted by D65, so that a flat
  spectrum of 1 is white; an emitter not); the XYZ is converted to linear sRGB and a
  reflectance clipped to [0, 1], an emitter or an index (``eta``, ``k``) to ≥ 0.

This module reproduces that rule (tested against Mitsuba's loaded values); the CIE
tables come from colour-science: the 1931 2° observer at 5 nm, and D65 from its CIE
D-series definition (within 1e-5 of the tabulated values Mitsuba carries).
"""

from __future__ import annotations

import functools
import re

import numpy as np

#: linear sRGB from CIE XYZ, the matrix Mitsuba's ``xyz_to_srgb`` applies
XYZ_TO_SRGB = np.array([[3.240479, -1.537150, -0.498535],
                        [-0.969256, 1.875991, 0.041556],
                        [0.055648, -0.204043, 1.057311]])
_CIE_MIN, _CIE_MAX, _CIE_SAMPLES = 360.0, 830.0, 95
#: a unit spectrum's luminance (∫ ȳ over 360–830 nm), and D65's relative to 560 nm
_Y_NORMALIZATION = 1.0 / 106.7502593994140625
_D65_NORMALIZATION = 1.0 / 98.99741751876255
_STEPS = 1000
#: the longest line Mitsuba reads whole (``fgets`` into 1024 bytes)
_SPD_LINE_BYTES = 1023


#: the properties that are indices of refraction (a conductor's), unbounded above
INDEX_PROPERTIES = ("eta", "k")
#: how a property may be given as a spectrum, each its own rule (the coverage matrix's
#: ``spectrum:...`` features): pairs as an emission, an index or a reflectance, a uniform
#: emission, a uniform number (a reflectance's or an index's), pairs from a file
FEATURES = ("emission", "index", "reflectance", "emission(uniform)", "uniform", "file")


def spectrum_features(kind: str, name: str, spectrum, from_file: bool) -> tuple[str, ...]:
    """Which of ``FEATURES`` a ``<spectrum>`` given to property ``name`` of a ``kind``
    plugin is (``spectrum``: a float where uniform, else its pairs): its rule, and
    ``file`` where its pairs were read from a file."""
    emitter = kind == "emitter"
    if isinstance(spectrum, float):
        return ("emission(uniform)" if emitter else "uniform",)
    role = "emission" if emitter else "index" if name in INDEX_PROPERTIES else "reflectance"
    return (role, "file") if from_file else (role,)


def uniform_emission_rgb(value: float) -> np.ndarray:
    """The RGB of an emitter's uniform spectrum of ``value``."""
    return value * XYZ_TO_SRGB.sum(axis=1)


@functools.lru_cache(maxsize=1)
def _cie_tables() -> tuple[np.ndarray, np.ndarray]:
    """The CIE 1931 2° colour-matching functions (3, 95) and D65 (95,), 360–830 nm at
    5 nm, from colour-science (imported here: it takes a second or two)."""
    with np.printoptions():     # colour-science sets numpy's legacy printing on import
        import colour
        from colour.temperature import CCT_to_xy_CIE_D

    grid = np.linspace(_CIE_MIN, _CIE_MAX, _CIE_SAMPLES)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    # D65 as CIE 015:2004 defines it (the D series at 6504 K, M1 and M2 rounded)
    d65 = colour.sd_CIE_illuminant_D_series(CCT_to_xy_CIE_D(6500 * 1.4388 / 1.4380))
    return np.asarray(cmfs[grid]).T.copy(), np.asarray(d65[grid])


def _table_at(table: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``table`` (its last axis the 95 wavelengths) interpolated linearly at ``w``."""
    t = (w - _CIE_MIN) * ((_CIE_SAMPLES - 1) / (_CIE_MAX - _CIE_MIN))
    i0 = np.clip(np.floor(t).astype(int), 0, _CIE_SAMPLES - 2)
    f = t - i0
    return (1.0 - f) * table[..., i0] + f * table[..., i0 + 1]


def spectrum_list_rgb(wavelengths, values, emitter: bool, unbounded: bool) -> np.ndarray:
    """The RGB of a spectrum given at ``wavelengths`` (increasing, at least two) with
    ``values``: an emitter's (``emitter``), an index's (``unbounded``: ``eta``, ``k``) or
    a reflectance's (neither), as the module's docstring says."""
    wl = np.asarray(wavelengths, dtype=float)
    vals = np.asarray(values, dtype=float)
    w = _CIE_MIN + np.arange(_STEPS) / (_STEPS - 1) * (_CIE_MAX - _CIE_MIN)
    w = w[(w >= wl[0]) & (w <= wl[-1])]
    i = np.clip(np.searchsorted(wl, w, side="right") - 1, 0, len(wl) - 2)
    w0, w1, v0, v1 = wl[i], wl[i + 1], vals[i], vals[i + 1]
    v = ((w - w1) * v0 + (w0 - w) * v1) / (w0 - w1)
    cmfs, d65 = _cie_tables()
    weight = v if emitter else v * _table_at(d65, w) * _D65_NORMALIZATION
    xyz = _table_at(cmfs, w) @ weight
    xyz *= (_CIE_MAX - _CIE_MIN) * _Y_NORMALIZATION / _STEPS
    rgb = XYZ_TO_SRGB @ xyz
    return np.maximum(rgb, 0.0) if emitter or unbounded else np.clip(rgb, 0.0, 1.0)


def number_pair(words) -> tuple[float, float] | None:
    """Two numbers read as Mitsuba reads them from two words, or None where ``words`` are
    not two numbers."""
    from .text_numbers import parse_float

    try:
        return tuple(parse_float(w) for w in words) if len(words) == 2 else None
    except ValueError:
        return None


def _leading_number(line: str, start: int) -> tuple[float, int] | None:
    """The number at the start of ``line[start:]`` after spaces and tabs, and where it
    ends, as Mitsuba's reader takes it: the longest decimal number there (``0.1`` of
    ``0.1#peak`` or ``0.1,``, ``0`` of ``0x10``); None where none starts there."""
    from .text_numbers import FLOAT_PREFIX

    pos = start + len(line[start:]) - len(line[start:].lstrip(" \t"))
    match = FLOAT_PREFIX.match(line, pos)
    return (float(match.group()), match.end()) if match else None


def lone_cr_note(path: str) -> str:
    """Why a spectrum file whose lines end at a lone ``\\r`` (a classic Mac file) reads
    as one pair, for the refusal of too few pairs; '' where it has none."""
    with open(path, "rb") as f:
        if re.search(rb"\r(?!\n)", f.read()) is None:
            return ""
    return ("; its lines end at a lone \\r, which Mitsuba takes for no line end, so the "
            "file is one line to it, read as one pair: save it with \\n line ends")


def read_spd(path: str) -> tuple[list[float], list[float]] | str:
    """The wavelengths and values of a spectrum file (a ``wavelength value`` pair a
    line), read as Mitsuba 3.9.1 reads it, or why it cannot be read: lines end at ``\n``
    only (a lone ``\r`` ends none); an empty line, or one starting with ``#`` or ``\r``
    (a CRLF file's empty line), is skipped; any other starts with two numbers, each the
    longest decimal number after spaces or tabs, and what follows them is ignored
    (``400 0.1 # peak``, a third column: until 7 December refused, though Mitsuba
    renders it; and ``400 0.1# peak``, ``400 0.1,``: refused as 'expected a wavelength
    and a value' until 7 December, though Mitsuba reads 0.1 there). A line of spaces or
    tabs Mitsuba refuses ("Could not extract wavelength"): it is refused by line; a
    file whose lines end at a lone ``\r`` is one line to Mitsuba, of one pair, refused
    by the loader as too few pairs, saying why (until 7
    December both were read, Python's reading of lines skipping the one and splitting
    the other, and ``render-check`` failed in Mitsuba's reference build)."""
    wavelengths, values = [], []
    with open(path, encoding="utf-8", errors="replace", newline="\n") as f:
        for number, line in enumerate(f, 1):
            line = line.removesuffix("\n")
            if len(line.encode("utf-8")) > _SPD_LINE_BYTES:
                # Mitsuba reads a line in pieces of 1023 bytes and refuses the second
                # (a long comment too): it was read here, and failed in Mitsuba's build
                return (f"line {number}: longer than {_SPD_LINE_BYTES} bytes, which "
                        "Mitsuba reads as two lines and refuses; shorten it")
            if not line or line[0] in "#\r":
                continue
            if not line.rstrip("\r").strip(" \t"):
                return (f"line {number}: a line of spaces or tabs, {line!r}: Mitsuba "
                        "skips only an empty line or one starting with '#', and refuses "
                        "this one; make it empty")
            # Mitsuba reads the first two numbers and ignores the rest of the line (a
            # comment, a third column, a comma): refused here until 7 December
            wavelength = _leading_number(line, 0)
            value = wavelength and _leading_number(line, wavelength[1])
            if not value:
                shown = line.rstrip("\r").strip(" \t")
                return f"line {number}: expected a wavelength and a value, got {shown!r}"
            wavelengths.append(wavelength[0])
            values.append(value[0])
    return wavelengths, values
