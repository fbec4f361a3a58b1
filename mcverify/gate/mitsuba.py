"""The one module of mcverify that imports mitsuba: variant choice and adapters.

Variant choice: ``llvm_ad_rgb`` (vectorised, about 3× faster here) needs libLLVM >= 16;
with LLVM 15 Dr.Jit aborts the *whole process* ("Cannot select fminimum"), so the variant
is probed in a subprocess first. Without a working LLVM we fall back to ``scalar_rgb``
with a one-line notice. ``MCVERIFY_MITSUBA_VARIANT`` forces a variant.
"""

from __future__ import annotations

import glob
import os
import subprocess
import sys
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ..errors import EnvironmentProblem

__all__ = ["VariantChoice", "choose_variant", "mitsuba_warps", "mitsuba_version"]

_LLVM_VARIANT = "llvm_ad_rgb"
_SCALAR_VARIANT = "scalar_rgb"
_PROBE = (
    "import mitsuba as mi, drjit as dr, numpy as np\n"
    f"mi.set_variant('{_LLVM_VARIANT}')\n"
    "x = mi.Float([0.25, 2.0])\n"
    "print(float(np.asarray(dr.sum(dr.minimum(x, 1.0))).ravel()[0]))\n"
)


@dataclass(frozen=True)
class VariantChoice:
    """The Mitsuba variant this process uses, and the notice to print if it fell back."""

    variant: str
    notice: str | None


def _find_libllvm() -> str | None:
    """A libLLVM >= 16 on this machine (Debian's libllvm19 by default), or None."""
    candidates = []
    for pattern in ("/lib/x86_64-linux-gnu/libLLVM.so.*", "/usr/lib/x86_64-linux-gnu/libLLVM.so.*",
                    "/lib/x86_64-linux-gnu/libLLVM-*.so", "/usr/lib/llvm-*/lib/libLLVM*.so*"):
        candidates += glob.glob(pattern)

    def major(path):
        for part in os.path.basename(path).replace("-", ".").split("."):
            if part.isdigit():
                return int(part)
        return 0

    good = sorted({p for p in candidates if major(p) >= 16}, key=major, reverse=True)
    return good[0] if good else None


@lru_cache(maxsize=1)
def choose_variant() -> VariantChoice:
    """Pick the Mitsuba variant for this process (probed once, in a subprocess)."""
    forced = os.environ.get("MCVERIFY_MITSUBA_VARIANT")
    try:
        import mitsuba  # noqa: F401
    except ImportError as e:  # pragma: no cover - mitsuba is a dependency
        raise EnvironmentProblem(f"mitsuba is not importable ({e}); run `make setup`") from e
    if forced:
        return VariantChoice(forced, None)
    lib = os.environ.get("DRJIT_LIBLLVM_PATH") or _find_libllvm()
    if lib is None:
        return VariantChoice(_SCALAR_VARIANT, "mitsuba: no libLLVM >= 16 found (apt-get install "
                             "libllvm19 for the 3x faster llvm_ad_rgb); using scalar_rgb")
    env = dict(os.environ, DRJIT_LIBLLVM_PATH=lib)
    try:
        r = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True,
                           text=True, timeout=120, check=False)
        ok = r.returncode == 0 and r.stdout.strip() == "1.25"
    except (OSError, subprocess.SubprocessError):
        ok = False
    if not ok:
        return VariantChoice(_SCALAR_VARIANT, f"mitsuba: {_LLVM_VARIANT} does not work with "
                             f"{lib}; using scalar_rgb")
    os.environ["DRJIT_LIBLLVM_PATH"] = lib
    return VariantChoice(_LLVM_VARIANT, None)


@lru_cache(maxsize=1)
def _mi():
    import mitsuba as mi

    mi.set_variant(choose_variant().variant)
    return mi


def mitsuba_version() -> str:
    import mitsuba as mi

    return mi.__version__


def _vectorised() -> bool:
    return not choose_variant().variant.startswith("scalar")


def chi2_cosine_hemisphere(n: int):
    """Mitsuba's own χ² test (``mitsuba.chi2.ChiSquareTest``) of its cosine-hemisphere
    warp at ``n`` samples, as a callable for the benchmark (its pdf clamped at the
    horizon, as its own tests do); its log is silenced."""
    import contextlib
    import io

    import drjit as dr
    from mitsuba.chi2 import ChiSquareTest, SphericalDomain

    mi = _mi()

    def run():
        with contextlib.redirect_stdout(io.StringIO()):   # its log goes to stdout
            return ChiSquareTest(
                domain=SphericalDomain(),
                sample_func=lambda s: mi.warp.square_to_cosine_hemisphere(s),
                pdf_func=lambda v: dr.maximum(mi.warp.square_to_cosine_hemisphere_pdf(v), 0.0),
                sample_dim=2, sample_count=n).run()

    return run




def _from_mitsuba(v, n):
    a = np.asarray(v, dtype=np.float64)
    if a.size == 1 and n != 1:  # a constant (e.g. the uniform sphere's pdf)
        return np.full(n, float(a.ravel()[0]))
    if a.ndim == 1:
        return a.reshape(n, -1) if a.size != n else a
    return a.T if a.shape[0] != n else a


def _wrap(fn, n_in, *params):
    """numpy front end for a Mitsuba warp function (vectorised or a per-row loop)."""
    mi = _mi()

    def call(x):
        x = np.asarray(x, dtype=np.float64)
        if x.ndim == 1:
            x = x.reshape(-1, 1)
        n = x.shape[0]
        if _vectorised():
            if n_in == 3:
                arg = mi.Vector3f(x[:, 0], x[:, 1], x[:, 2])
            elif n_in == 2:
                arg = mi.Point2f(x[:, 0], x[:, 1])
            else:
                arg = mi.Float(x[:, 0])
            return _from_mitsuba(fn(arg, *params), n)
        rows = []
        for row in x:
            arg = (mi.Vector3f(*row) if n_in == 3 else
                   mi.Point2f(*row) if n_in == 2 else float(row[0]))
            rows.append(np.asarray(fn(arg, *params), dtype=np.float64).reshape(-1))
        out = np.asarray(rows)
        return out[:, 0] if out.shape[1] == 1 else out

    return call


@dataclass(frozen=True)
class MitsubaWarp:
    name: str
    sample: object
    pdf: object
    invert: object | None
    domain: str
    sample_dim: int


def mitsuba_warps() -> list[MitsubaWarp]:
    """Mitsuba's own warps (``mi.warp``) as numpy samplers, pdfs and inverses.

    Mitsuba's pdfs are defined on their natural support only (e.g. the cosine pdf is
    negative below the horizon), so they are clamped at 0 outside it.
    """
    mi = _mi()
    w = mi.warp
    cos_cut, alpha = 0.8, 0.3

    def hemi(pdf):
        return lambda x: np.where(np.asarray(x)[:, 2] >= 0, np.maximum(pdf(x), 0.0), 0.0)

    def cone(pdf):
        return lambda x: np.where(np.asarray(x)[:, 2] >= cos_cut, pdf(x), 0.0)

    return [
        MitsubaWarp("mitsuba.cosine_hemisphere", _wrap(w.square_to_cosine_hemisphere, 2),
                    hemi(_wrap(w.square_to_cosine_hemisphere_pdf, 3)),
                    _wrap(w.cosine_hemisphere_to_square, 3), "hemisphere", 2),
        MitsubaWarp("mitsuba.uniform_sphere", _wrap(w.square_to_uniform_sphere, 2),
                    _wrap(w.square_to_uniform_sphere_pdf, 3),
                    _wrap(w.uniform_sphere_to_square, 3), "sphere", 2),
        MitsubaWarp("mitsuba.uniform_disk_concentric",
                    _wrap(w.square_to_uniform_disk_concentric, 2),
                    lambda x: np.where(np.sum(np.asarray(x) ** 2, 1) <= 1, 1 / np.pi, 0.0),
                    _wrap(w.uniform_disk_to_square_concentric, 2), "disk", 2),
        MitsubaWarp("mitsuba.uniform_cone", _wrap(w.square_to_uniform_cone, 2, cos_cut),
                    cone(_wrap(w.square_to_uniform_cone_pdf, 3, cos_cut)),
                    _wrap(w.uniform_cone_to_square, 3, cos_cut), "sphere", 2),
        MitsubaWarp("mitsuba.beckmann", _wrap(w.square_to_beckmann, 2, alpha),
                    hemi(_wrap(w.square_to_beckmann_pdf, 3, alpha)),
                    _wrap(w.beckmann_to_square, 3, alpha), "hemisphere", 2),
    ]


@lru_cache(maxsize=4)
def _loaded(scene_path: str, params: tuple, mtime: int):
    mi = _mi()
    try:
        return mi.load_file(scene_path, **dict(params))
    except Exception as e:  # Mitsuba raises RuntimeError with its parser's message
        raise EnvironmentProblem(f"{scene_path}: Mitsuba cannot load it ({e})") from None


def render_pass(scene_path: str, *, spp: int, seed: int, params: dict | None = None,
                variant: str | None = None) -> np.ndarray:
    """One independent pass of ``scene_path``: (H, W, C) float64. The loaded scene is
    kept per process (keyed by path, ``$`` parameters and modification time), so a
    worker rendering many passes parses the scene once. ``variant``: the variant the
    caller uses; a process that would render with another one refuses (its images would
    differ)."""
    if variant is not None and choose_variant().variant != variant:
        raise EnvironmentProblem(f"{scene_path}: this process renders with Mitsuba "
                                 f"{choose_variant().variant}, the client with {variant}; "
                                 "set MCVERIFY_MITSUBA_VARIANT alike on every worker")
    try:
        mtime = os.stat(scene_path).st_mtime_ns
    except OSError as e:
        raise EnvironmentProblem(f"{scene_path}: cannot read it here ({e.strerror}); workers "
                                 "need the scenes at the same path") from None
    scene = _loaded(scene_path, tuple(sorted((params or {}).items())), mtime)
    return np.asarray(_mi().render(scene, spp=spp, seed=int(seed)), dtype=np.float64)


def render_passes(scene_path: str, *, spp: int, seeds, params: dict | None = None,
                  progress=None) -> np.ndarray:
    """Render ``scene_path`` once per seed (independent passes): (K, H, W, C) float64."""
    seeds = list(seeds)
    out = []
    for i, seed in enumerate(seeds):
        out.append(render_pass(scene_path, spp=spp, seed=seed, params=params))
        if progress:
            progress(i + 1, len(seeds))
    return np.stack(out)


def write_exr(path: str, image: np.ndarray) -> None:
    """Write an (H, W, C) image as a float32 OpenEXR file."""
    mi = _mi()
    mi.Bitmap(np.ascontiguousarray(image, dtype=np.float32)).write(path)


def read_exr(path: str) -> np.ndarray:
    """Read an OpenEXR (or any Mitsuba-readable) image as (H, W, C) float64; a missing
    or corrupt file raises ``EnvironmentProblem`` naming it."""
    mi = _mi()
    try:
        a = np.array(mi.Bitmap(path), dtype=np.float64)
    except Exception as e:
        raise EnvironmentProblem(f"{path}: cannot read image ({e})") from None
    return a[:, :, None] if a.ndim == 2 else a
