"""Numbers in scene text as Mitsuba's parsers read them, not as Python's ``float`` and
``int`` do: those also take ``1_5``, digits of other scripts (``١.٥``, ``１.５``) and
Unicode spaces, which Mitsuba refuses; and Python's integers have no range, where
Mitsuba parses 64-bit ones and holds some properties to 32 bits (a ``max_depth`` of
10^20 reached numba as "Int value is too large").
ASCII only: a sign, digits with at most one point, an exponent; ``inf`` and ``nan`` are
read (the loader then refuses them as not finite, naming them)."""

from __future__ import annotations

import re

#: What separates the numbers of an ``<rgb>`` or a ``value="x, y, z"``, and what may pad
#: a value: commas and ASCII whitespace (Mitsuba's tokenizer; not a no-break space).
SPACE = " \t\n\r"
_SEPARATORS = re.compile(r"[, \t\n\r]+")
_SPACES = re.compile(r"[ \t\n\r]+")
_FLOAT = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?"
                    r"|[+-]?(?:infinity|inf|nan)", re.ASCII | re.IGNORECASE)
#: the longest number at the start of a text, as Mitsuba's reader takes it (ASCII
#: decimal only: no hexadecimal, no leading white space)
FLOAT_PREFIX = _FLOAT
_INT = re.compile(r"[+-]?[0-9]+", re.ASCII)
INT64 = (-2 ** 63, 2 ** 63 - 1)
#: The least magnitude that float32 rounds to inf (FLT_MAX + half its ulp): Mitsuba's RGB
#: variants hold every scene value (and a mesh, a to_uv) in single precision, so a double
#: at or beyond it is infinite there.
FLOAT32_OVERFLOW = 2.0 ** 128 - 2.0 ** 103
INT32 = (-2 ** 31, 2 ** 31 - 1)
#: integer properties Mitsuba 3.9.1 holds to 32 bits (it refuses max_depth 2^31 when it
#: builds the integrator); a sampler's seed has its own range, [0, 2^32 - 1]
INT32_PROPERTIES = ("max_depth", "rr_depth", "sample_count", "width", "height",
                    "emitter_samples", "bsdf_samples", "shading_samples", "samples_per_pass",
                    "shape_index")


def finite_in_float32(values) -> bool:
    """Whether ``values`` (a few floats: a scene number, an OBJ line, a to_uv) stay finite
    rounded to float32, as Mitsuba stores them: one comparison a value (a numpy array a
    line cost an OBJ of 1e6 vertices about a second)."""
    return all(abs(x) < FLOAT32_OVERFLOW for x in values)


def parse_float(token: str) -> float:
    """``token`` as a float64; ``ValueError`` unless it is a plain decimal number."""
    if not _FLOAT.fullmatch(token):
        raise ValueError(f"not a number: {token!r}")
    return float(token)


def parse_int(token: str, sign: str = "-") -> int:
    """``token`` as an int; ``ValueError`` unless it is ASCII digits after an optional
    sign (``sign``: the signs allowed; Mitsuba's XML integers take ``-`` only)."""
    if not _INT.fullmatch(token) or (token[0] in "+-" and token[0] not in sign):
        raise ValueError(f"not an integer: {token!r}")
    return int(token)


def split_numbers(text: str) -> list[str]:
    """The number tokens of ``text``: split at commas and ASCII whitespace."""
    return [t for t in _SEPARATORS.split(text.strip(SPACE)) if t]


def split_words(text: str) -> list[str]:
    """The words of ``text``: split at ASCII whitespace (an OBJ line's tokens; Python's
    ``str.split`` also splits at Unicode spaces)."""
    return [t for t in _SPACES.split(text.strip(SPACE)) if t]


_ASCII_LOWER = str.maketrans("ABCDEFGHIJKLMNOPQRSTUVWXYZ", "abcdefghijklmnopqrstuvwxyz")


def ascii_lower(text: str) -> str:
    """``text`` with its ASCII letters lowered, as Mitsuba compares names case-blind
    (``std::tolower`` in the C locale): ``str.lower`` also folds other scripts, so a
    Kelvin sign (U+212A) read as ``k`` and ``"B\u212a7"`` as the index of BK7, which
    Mitsuba refuses (an outside review)."""
    return text.translate(_ASCII_LOWER)
