"""The one module of mcverify that imports mitsuba: variant choice and adapters.

Variant choice: ``llvm_ad_rgb`` (vectorised, about 3× faster here) needs libLLVM >= 16;
with LLVM 15 Dr.Jit aborts the *whole process* ("Cannot select fminimum"), so the variant
is probed in a subprocess first. Without a working LLVM we fall back to ``scalar_rgb``
with a one-line notice. ``MCVERIFY_MITSUBA_VARIANT`` forces a variant. The probe's verdict
on a library goes into ``MCVERIFY_LLVM_PROBED`` (``ok:PATH`` or ``bad:PATH``), so the
processes this one starts (``mcverify check -j N``'s workers, a test run's CLI calls)
inherit it instead of probing the same library again (about a second each).
"""

from __future__ import annotations

import glob
import numbers
import os
import re
import subprocess
import sys
from dataclasses import dataclass
from functools import lru_cache
from typing import Callable, NamedTuple

import numpy as np

from .. import _validate
from ..errors import EnvironmentProblem, InvalidArgument

__all__ = ["VariantChoice", "choose_variant", "mitsuba_warps", "mitsuba_version", "mi",
           "Subject", "WeightedSubject", "bsdf", "bsdf_weighted", "emitter", "microfacet", "phase"]

_LLVM_VARIANT = "llvm_ad_rgb"
_SCALAR_VARIANT = "scalar_rgb"
_PROBE = (
    "import mitsuba as mi, drjit as dr, numpy as np\n"
    "mi.set_variant({variant!r})\n"
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


_PROBED = "MCVERIFY_LLVM_PROBED"


def _probe_variant(variant: str, lib: str | None) -> str | None:
    """None where ``variant`` computes (with libLLVM ``lib``, if given), else why not:
    tried in a subprocess (an LLVM that Dr.Jit cannot use aborts the process that
    loads it)."""
    env = dict(os.environ, **({"DRJIT_LIBLLVM_PATH": lib} if lib else {}))
    try:
        r = subprocess.run([sys.executable, "-c", _PROBE.format(variant=variant)], env=env,
                           capture_output=True, text=True, timeout=120, check=False)
    except (OSError, subprocess.SubprocessError) as e:
        return str(e)
    if r.returncode == 0 and r.stdout.strip() == "1.25":
        return None
    # Dr.Jit's reason: the last line that names an error (an ImportError's, LLVM's
    # "LLVM ERROR: Cannot select: ... fminimum" with LLVM 15), not the last line, which
    # after LLVM's abort is its DAG dump's "In function: drjit_<hash>"
    lines = [ln.strip() for ln in r.stderr.splitlines() if ln.strip()]
    errors = [ln for ln in lines if "error" in ln.lower()]
    return (errors or lines or [f"exit status {r.returncode}"])[-1]


def _probe(lib: str) -> bool:
    """Whether ``llvm_ad_rgb`` computes with ``lib`` (see :func:`_probe_variant`)."""
    return _probe_variant(_LLVM_VARIANT, lib) is None


@lru_cache(maxsize=1)
def choose_variant() -> VariantChoice:
    """Pick the Mitsuba variant for this process (probed once, in a subprocess)."""
    from estimators.pathtracer.textures import MITSUBA_IMPORT

    forced = os.environ.get("MCVERIFY_MITSUBA_VARIANT")
    try:
        with MITSUBA_IMPORT:        # one thread at a time: see there
            import mitsuba
    except ImportError as e:  # pragma: no cover - mitsuba is a dependency
        # `make setup` alone meant nothing where mcverify was installed with pip
        raise EnvironmentProblem(f"mitsuba is not importable ({e}); install it (`pip install "
                                 "mitsuba`, or `make setup` in a checkout of mcverify)") from e
    if forced:
        # the adapters read weights and values as RGB (3 channels): a mono or spectral
        # variant failed every check with numpy's "cannot reshape", a misspelt one with
        # Mitsuba's ImportError, both raised inside each check
        usable = [v for v in mitsuba.variants() if v.endswith("_rgb")]
        if forced not in usable:
            raise EnvironmentProblem(
                f"MCVERIFY_MITSUBA_VARIANT={forced!r}: "
                + ("not a variant of this Mitsuba" if forced not in mitsuba.variants()
                   else "the Mitsuba adapters read RGB weights and values")
                + f"; use one of {', '.join(usable)}, or unset it to choose automatically")
        if not forced.startswith("scalar"):
            # a JIT variant without its backend (cuda_ad_rgb without a GPU, llvm_ad_rgb
            # without a libLLVM) failed every Mitsuba check with Dr.Jit's ImportError
            # ("the CUDA backend hasn't been initialized"): exit 1, as if Mitsuba's
            # plugins were wrong. Probed in a subprocess, the verdict passed on as above.
            lib = os.environ.get("DRJIT_LIBLLVM_PATH", "")
            key = f"{forced}@{lib}"
            known = os.environ.get(_PROBED, "")
            if known == "ok:" + key:
                return VariantChoice(forced, None)
            why = "it did not compute before" if known == "bad:" + key else \
                _probe_variant(forced, lib or None)
            os.environ[_PROBED] = ("ok:" if why is None else "bad:") + key
            if why is not None:
                raise EnvironmentProblem(
                    f"MCVERIFY_MITSUBA_VARIANT={forced!r}: Mitsuba cannot compute in it here "
                    f"({why}); use scalar_rgb, or unset it to choose automatically"
                    + (f", or point DRJIT_LIBLLVM_PATH (now {lib or 'unset'}) at a libLLVM "
                       ">= 16" if forced.startswith("llvm") else ""))
        return VariantChoice(forced, None)
    lib = os.environ.get("DRJIT_LIBLLVM_PATH") or _find_libllvm()
    if lib is None:
        return VariantChoice(_SCALAR_VARIANT, "mitsuba: no libLLVM >= 16 found (apt-get install "
                             "libllvm19 for the 3x faster llvm_ad_rgb); using scalar_rgb")
    known = os.environ.get(_PROBED, "")
    if known in ("ok:" + lib, "bad:" + lib):       # a parent process probed this library
        ok = known.startswith("ok:")
    else:
        ok = _probe(lib)
        os.environ[_PROBED] = ("ok:" if ok else "bad:") + lib
    if not ok:
        # the library may be the user's DRJIT_LIBLLVM_PATH: say how to get llvm_ad_rgb back
        return VariantChoice(_SCALAR_VARIANT, f"mitsuba: {_LLVM_VARIANT} does not work with "
                             f"{lib}; using scalar_rgb (for the 3x faster {_LLVM_VARIANT}, "
                             "point DRJIT_LIBLLVM_PATH at a working libLLVM >= 16, such as "
                             "Debian's libllvm19)")
    os.environ["DRJIT_LIBLLVM_PATH"] = lib
    return VariantChoice(_LLVM_VARIANT, None)


@lru_cache(maxsize=1)
def _mitsuba():
    """Mitsuba in the chosen variant, its log at errors only: its warnings repeat at every
    load of a scene (a stratified sampler's rounded sample count: 64 lines in one
    render-check, coloured, whatever ``-q`` says); what they say that matters is
    reported by mcverify itself (the rounded spp) or raised (a refused scene)."""
    from estimators.pathtracer.textures import import_mitsuba

    mi = import_mitsuba(choose_variant().variant)
    mi.set_log_level(mi.LogLevel.Error)
    return mi


def _mi():
    """:func:`_mitsuba`, its variant set again where code since set another: Mitsuba's
    variant is one per process, and the adapters' ``mi.Vector3f`` and the like follow it,
    so an ``mi.set_variant("scalar_rgb")`` after the adapters chose ``llvm_ad_rgb`` made
    their next call fail with a bare TypeError ("only 0-dimensional arrays can be
    converted to Python scalars")."""
    from estimators.pathtracer.textures import MITSUBA_IMPORT

    mi = _mitsuba()
    variant = choose_variant().variant
    with MITSUBA_IMPORT:        # as import_mitsuba sets it: one thread at a time
        if mi.variant() != variant:
            mi.set_variant(variant)
    return mi


def mitsuba_version() -> str:
    from estimators.pathtracer.textures import MITSUBA_IMPORT

    with MITSUBA_IMPORT:
        import mitsuba as mi
    return mi.__version__


def thread_count() -> int:
    """The threads Mitsuba renders on (Dr.Jit's pool: every core unless told)."""
    import drjit as dr

    return int(dr.thread_count())


def _vectorised() -> bool:
    return not choose_variant().variant.startswith("scalar")


def chi2_cosine_hemisphere(n: int):
    """Mitsuba's own χ² test (``mitsuba.chi2.ChiSquareTest``) of its cosine-hemisphere
    warp at ``n`` samples, as a callable for the benchmark (its pdf clamped at the
    horizon, as its own tests do); its log is silenced."""
    import contextlib
    import io

    mi = _mi()      # first: Mitsuba imported one thread at a time (see _mitsuba)
    import drjit as dr
    from mitsuba.chi2 import ChiSquareTest, SphericalDomain

    def run():
        with contextlib.redirect_stdout(io.StringIO()):   # its log goes to stdout
            return ChiSquareTest(
                domain=SphericalDomain(),
                sample_func=lambda s: mi.warp.square_to_cosine_hemisphere(s),
                pdf_func=lambda v: dr.maximum(mi.warp.square_to_cosine_hemisphere_pdf(v), 0.0),
                sample_dim=2, sample_count=n).run()

    return run




def to_numpy(*values):
    """Mitsuba/Dr.Jit values evaluated together (one kernel launch for all of them) and
    returned as numpy arrays."""
    import drjit as dr

    dr.eval(*values)
    return tuple(np.asarray(v) for v in values)


def _from_mitsuba(v, n):
    a = np.asarray(v, dtype=np.float64)
    if a.size == 1 and n != 1:  # a constant (e.g. the uniform sphere's pdf)
        return np.full(n, float(a.ravel()[0]))
    if a.ndim == 1:
        return a.reshape(n, -1) if a.size != n else a
    return a.T if a.shape[0] != n else a


#: The largest float32 below 1. Mitsuba computes in float32, and a uniform u in
#: (1 - 2^-25, 1) rounds to 1.0f, outside the warps' domain [0, 1): Beckmann then returns
#: a horizon direction where its pdf is 0 (seen once in 4e6 draws).
_BELOW_ONE_F32 = float(np.nextafter(np.float32(1.0), np.float32(0.0)))


def _wrap(fn, n_in, *params, uniforms=False):
    """numpy front end for a Mitsuba warp function (vectorised or a per-row loop);
    ``uniforms``: the input is uniform numbers, clamped below float32's 1 (pbrt's habit)."""
    mi = _mi()

    def call(x):
        _mi()          # in the adapters' variant, whatever was set since
        x = np.asarray(x, dtype=np.float64)
        if uniforms:
            x = np.minimum(x, _BELOW_ONE_F32)
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
        MitsubaWarp("mitsuba.cosine_hemisphere",
                    _wrap(w.square_to_cosine_hemisphere, 2, uniforms=True),
                    hemi(_wrap(w.square_to_cosine_hemisphere_pdf, 3)),
                    _wrap(w.cosine_hemisphere_to_square, 3), "hemisphere", 2),
        MitsubaWarp("mitsuba.uniform_sphere",
                    _wrap(w.square_to_uniform_sphere, 2, uniforms=True),
                    _wrap(w.square_to_uniform_sphere_pdf, 3),
                    _wrap(w.uniform_sphere_to_square, 3), "sphere", 2),
        MitsubaWarp("mitsuba.uniform_disk_concentric",
                    _wrap(w.square_to_uniform_disk_concentric, 2, uniforms=True),
                    lambda x: np.where(np.sum(np.asarray(x) ** 2, 1) <= 1, 1 / np.pi, 0.0),
                    _wrap(w.uniform_disk_to_square_concentric, 2), "disk", 2),
        MitsubaWarp("mitsuba.uniform_cone",
                    _wrap(w.square_to_uniform_cone, 2, cos_cut, uniforms=True),
                    cone(_wrap(w.square_to_uniform_cone_pdf, 3, cos_cut)),
                    _wrap(w.uniform_cone_to_square, 3, cos_cut), "sphere", 2),
        MitsubaWarp("mitsuba.beckmann",
                    _wrap(w.square_to_beckmann, 2, alpha, uniforms=True),
                    hemi(_wrap(w.square_to_beckmann_pdf, 3, alpha)),
                    _wrap(w.beckmann_to_square, 3, alpha), "hemisphere", 2),
    ]


@lru_cache(maxsize=4)
def _loaded(scene_path: str, params: tuple, stamp: tuple):
    mi = _mi()
    try:
        return mi.load_file(scene_path, **dict(params))
    except Exception as e:  # Mitsuba raises RuntimeError with its parser's message
        raise EnvironmentProblem(f"{scene_path}: Mitsuba cannot load it ({e})") from None


def _current(scene_path: str, params: dict | None):
    """The scene as ``_loaded`` keeps it, as its files are now (``scene_stamp``)."""
    from .reference import scene_stamp

    os.stat(scene_path)         # a missing scene raises here (its stamp would be None)
    return _loaded(scene_path, tuple(sorted((params or {}).items())),
                   scene_stamp(scene_path, params))


def mitsuba_seed(seed: int) -> int:
    """A seed as Mitsuba's ``render`` takes it: 32 bits (a larger one raised a
    TypeError from its bindings); ``seed mod 2^32``, so seeds below 2^32 are kept."""
    return int(seed) % (1 << 32)


def render_pass(scene_path: str, *, spp: int, seed: int, params: dict | None = None,
                variant: str | None = None) -> np.ndarray:
    """One independent pass of ``scene_path``: (H, W, C) float64. The loaded scene is
    kept per process (keyed by path, ``$`` parameters and the modification times of the
    scene and the files it names), so a
    worker rendering many passes parses the scene once. ``variant``: the variant the
    caller uses; a process that would render with another one refuses (its images would
    differ)."""
    if variant is not None and choose_variant().variant != variant:
        raise EnvironmentProblem(f"{scene_path}: this process renders with Mitsuba "
                                 f"{choose_variant().variant}, the client with {variant}; "
                                 "set MCVERIFY_MITSUBA_VARIANT alike on every worker")
    try:
        scene = _current(scene_path, params)
    except OSError as e:
        raise EnvironmentProblem(f"{scene_path}: cannot read it here ({e.strerror}); workers "
                                 "need the scenes at the same path") from None
    image = np.asarray(_mi().render(scene, spp=spp, seed=mitsuba_seed(seed)),
                       dtype=np.float64)
    if scene.integrator().should_stop():
        # While it renders, Mitsuba holds Ctrl-C itself: it cancels the render and returns
        # the partial image without raising, so Python never sees the signal (a reference
        # build went on to the next pass). An integrator's own ``timeout`` stops it alike;
        # either way the pass is not the one asked for.
        raise KeyboardInterrupt
    return image


def filter_radius(scene_path: str, params: dict | None = None) -> float:
    """The radius (pixels) of the reconstruction filter of the scene's first sensor's
    film, as Mitsuba loads it; 0.5 is a box filter (each sample in its own pixel), a
    larger one splats samples into neighbouring pixels."""
    return float(_current(scene_path, params).sensors()[0].film().rfilter().radius())


def sampler_rounds(sampler, spp: int) -> int:
    """The samples per pixel Mitsuba's sampler of this type renders when asked for
    ``spp`` (``sampler``: the scene loader's ``Plugin``), from a sampler alone: no scene
    is loaded and kept (the bench times Mitsuba with one scene alive; with others
    loaded too its renders took up to 7 times as long)."""
    props = {k: v for k, v in sampler.props.items() if k == "strength"}
    s = _mi().load_dict({"type": sampler.type, **props})
    s.set_sample_count(int(spp))
    return int(s.sample_count())


def sampler_spp(scene_path: str, spp: int, params: dict | None = None) -> int:
    """The samples per pixel Mitsuba renders when asked for ``spp``: its stratified
    sampler rounds up to a square (33 -> 36), multijitter to a product of near-equal
    factors (7 -> 8)."""
    sampler = _current(scene_path, params).sensors()[0].sampler().clone()
    sampler.set_sample_count(int(spp))
    return int(sampler.sample_count())


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
        # one line, and short: a partly written file's error carried Mitsuba's whole
        # FileStream[...] dump (an outside review)
        why = " ".join(str(e).split())
        why = why if len(why) <= 300 else why[:300] + " ..."
        raise EnvironmentProblem(f"{path}: cannot read image ({why})") from None
    return a[:, :, None] if a.ndim == 2 else a


# --------------------------------------------------------------------------------------
# Plugin adapters: a Mitsuba plugin's sampling routine as the judge's sampler contract.
# --------------------------------------------------------------------------------------

class Subject(NamedTuple):
    """A Mitsuba sampling routine in the shape ``mcverify.check_sampler`` takes.

    ``sample(u)`` maps (n, k) uniform numbers to (n, 3) directions; a row of NaN is a
    draw the plugin rejected (zero weight or zero pdf: below the horizon, behind a
    light) or one that went to a delta lobe (no density to test; its probability is the
    mass the continuous part is missing). ``pdf(x)`` is the plugin's own density of the
    continuous part, per unit solid angle. ``kwargs`` holds ``sample_dim`` and a
    ``name``. Use it as ``s, p, d, kw = mvm.bsdf(...); mv.check_sampler(s, p, d, **kw)``.
    """

    sample: Callable
    pdf: Callable
    domain: str
    kwargs: dict


def mi():
    """The ``mitsuba`` module with the gate's variant set (see :func:`choose_variant`).

    Register your own plugins through it (``mvm.mi().register_bsdf(...)``) so that they
    exist in the variant the adapters use.
    """
    return _mi()


_ONE_MINUS_EPS32 = 1.0 - 2.0 ** -24   # float32 uniform numbers stay below 1


def _point3(name: str, v, size: int = 3) -> tuple[float, ...]:
    try:
        a = np.asarray(v, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        a = np.empty(0)
    if a.size != size or not np.all(np.isfinite(a)):
        raise InvalidArgument(f"{name}={v!r}: expected a finite {size}-vector")
    return tuple(float(c) for c in a)


def _unit3(name: str, v) -> tuple[float, float, float]:
    a = _point3(name, v)
    length = float(np.linalg.norm(a))
    if abs(length - 1.0) > 1e-6:
        raise InvalidArgument(f"{name}={v!r}: length {length:.6g}, expected a unit vector "
                              "(normalise it)")
    return a


def _load(plugin, what: str, classes: tuple):
    """A dict (``mi.load_dict``), an XML string (``mi.load_string``) or a loaded plugin."""
    m = _mi()
    if isinstance(plugin, dict):
        if not isinstance(plugin.get("type"), str):
            # Mitsuba takes a dict without one for a scene ("unreferenced property in
            # scene plugin", or "got Scene"), and a type of 3 for std::bad_cast
            got = (f"'type': {plugin['type']!r}, not a string" if "type" in plugin
                   else f"no 'type' (keys {sorted(map(str, plugin))})")
            raise InvalidArgument(f"{what}: a dict with {got}; name the plugin, e.g. "
                                  "{'type': 'roughconductor', 'alpha': 0.2}")
        _finite_values(plugin, what)
        loader, arg = m.load_dict, _bitmaps(plugin)
    elif isinstance(plugin, str):
        if not plugin.lstrip().startswith("<"):
            raise InvalidArgument(f"{what}={plugin[:40]!r}: a string must be Mitsuba XML "
                                  f"such as '<bsdf type=\"diffuse\"/>'; give a dict for "
                                  "load_dict")
        loader, arg = m.load_string, plugin
    else:
        loader, arg = None, None
    if loader is not None:
        try:
            plugin = loader(arg)
        except Exception as e:  # Mitsuba raises RuntimeError with its parser's message
            raise InvalidArgument(f"{what}: Mitsuba cannot load it ({e})") from None
    if not isinstance(plugin, tuple(getattr(m, c) for c in classes)):
        if type(plugin).__module__ == "mitsuba" and any(
                t.__name__ in classes for t in type(plugin).__mro__):
            # a plugin loaded under another variant: "got BSDF, expected a mitsuba.BSDF";
            # its variant is the loaded variant module whose class it is an instance of
            theirs = [v for v in m.variants()
                      if (mod := sys.modules.get("mitsuba." + v)) is not None
                      and isinstance(plugin, getattr(mod, type(plugin).__name__, ()))]
            raise InvalidArgument(
                f"{what}: a mitsuba.{type(plugin).__name__} of another variant"
                f"{' (' + theirs[0] + ')' if theirs else ''} than the adapters' "
                f"{m.variant()} (loaded before mvm.mi() set it, or under "
                "mi.set_variant); load it after mvm.mi(), or pass a dict or XML string")
        raise InvalidArgument(f"{what}: got {type(plugin).__name__}, expected a "
                              f"{' or '.join('mitsuba.' + c for c in classes)} (a dict, an "
                              "XML string or a loaded plugin)")
    return plugin


def _finite_values(v, where: str) -> None:
    """Refuse a NaN or infinite number anywhere in a plugin dict (a parameter, an RGB
    value, a pixel of an inline image). Mitsuba loads them: a rough conductor of
    α = NaN or a sphere light of radius NaN rejected every draw, and the check passed
    as 'consistent, nothing else to test'."""
    if isinstance(v, dict):
        for k, x in v.items():
            _finite_values(x, f"{where}[{k!r}]")
    elif isinstance(v, (list, tuple)):
        for i, x in enumerate(v):
            _finite_values(x, f"{where}[{i}]")
    elif isinstance(v, (numbers.Real, np.ndarray)) and not isinstance(v, bool):
        a = np.asarray(v)
        if a.dtype.kind in "fc" and not np.all(np.isfinite(a)):
            shown = v if a.ndim == 0 else f"an array with {int(np.sum(~np.isfinite(a)))} " \
                                          "NaN or infinite values"
            raise InvalidArgument(f"{where}={shown}: not a finite number; Mitsuba loads it, "
                                  "but its draws and pdf are NaN or rejected, so the check "
                                  "would test nothing")


def _bitmaps(d: dict) -> dict:
    """A plugin dict with (H, W, C) numpy arrays turned into ``mi.Bitmap`` (an envmap's
    or a bitmap texture's image given inline)."""
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            v = _bitmaps(v)
        elif isinstance(v, np.ndarray) and v.ndim == 3:
            v = _mi().Bitmap(np.ascontiguousarray(v, dtype=np.float32))
        out[k] = v
    return out


def _label(plugin, obj) -> str:
    if isinstance(plugin, dict):
        shown = ((k, _param(v)) for k, v in plugin.items() if k != "type")
        inner = ",".join(f"{k}={v}" for k, v in shown if v is not None)
        return f"{plugin.get('type', '?')}({inner})" if inner else str(plugin.get("type"))
    if isinstance(plugin, str):
        found = re.search(r'type\s*=\s*"([^"]+)"', plugin)
        if found:
            return found.group(1)
    return str(obj).split("[", 1)[0].strip() or type(obj).__name__


def _param(v) -> str | None:
    """A plugin parameter as a check's name shows it: a number or string, a list of
    numbers, a nested plugin by its own label; None for what has no short form (an
    image, a transform). Nested plugins and lists were left out: two-sided diffuse and
    two-sided rough conductor were both 'twosided', and sphere lights at two centres
    'sphere', checks of one name (a user suite refuses two)."""
    if isinstance(v, dict):
        return _label(v, None)
    if isinstance(v, (str, numbers.Number)):
        return f"{v}"
    if (isinstance(v, (list, tuple)) and v
            and all(isinstance(c, numbers.Real) for c in v)):
        return "(" + ",".join(f"{c:g}" for c in v) + ")"
    return None


def _rows(fn, x: np.ndarray, d_out: int):
    """Run ``fn(columns, n)`` on (n, k) float64 rows: one vectorised call, or one call
    per row on a scalar variant. ``fn`` returns (points (d_out, n) or (n,), ok (n,))."""
    _mi()              # in the adapters' variant, whatever was set since
    x = np.asarray(x, dtype=np.float64)
    n = x.shape[0]
    if _vectorised():
        out, ok = fn([x[:, j] for j in range(x.shape[1])], n)
        return _np_out(out, n, d_out), np.broadcast_to(np.asarray(ok, bool).reshape(-1), (n,))
    outs, oks = [], []
    for row in x:
        out, ok = fn([float(c) for c in row], 1)
        outs.append(_np_out(out, 1, d_out)[0])
        oks.append(bool(np.asarray(ok).reshape(-1)[0]))
    return np.asarray(outs).reshape(n, *(() if d_out == 1 else (d_out,))), np.asarray(oks)


def _np_out(v, n, d):
    a = np.asarray(v, dtype=np.float64)
    if d == 1:
        return np.broadcast_to(a.reshape(-1), (n,)).copy() if a.size in (1, n) else a
    return np.broadcast_to(a.reshape(d, -1), (d, n)).T.copy()


def _zeros(T, n):
    if _vectorised():
        return _dr().zeros(T, n)
    try:
        return _dr().zeros(T)
    except RuntimeError:     # scalar DirectionSample3f has no zeros(); emitters without
        # a shape read only its direction, which the caller sets
        return T()


def _dr():
    import drjit

    return drjit


def _float(col):
    return _mi().Float(col) if _vectorised() else float(col)


def _uniform(u, dim: int):
    """Uniform numbers as float32-safe values (below 1 after rounding), ``dim`` a row:
    a check run with another ``sample_dim`` than the adapter's ``kwargs`` raised a bare
    IndexError (too few) or dropped columns (too many)."""
    u = np.asarray(u, dtype=np.float64)
    if u.ndim != 2 or u.shape[1] != dim:
        got = f" (sample_dim={u.shape[1]})" if u.ndim == 2 else ""
        raise InvalidArgument(f"u of shape {u.shape}{got}: this Mitsuba sampler takes {dim} "
                              f"uniform numbers a draw; pass the adapter's kwargs "
                              f"(sample_dim={dim})")
    return np.minimum(u, _ONE_MINUS_EPS32)


def _vec3(cols):
    return _mi().Vector3f(_float(cols[0]), _float(cols[1]), _float(cols[2]))


def _nan_rejected(x, ok):
    """Mitsuba's float32 directions as float64 points, rejected rows NaN.

    Near a pole, float32 rounds z to ±1 within 2.4e-4 rad (GGX at α = 0.01 puts 0.06 %
    of its normals there), while x and y keep theirs where the plugin computed them
    directly (not from a rounded cos θ: see the README's findings). The judge parameterises
    by z, so such points would pile into the first cell: z is recomputed from x and y in
    float64 where |z| > 0.5, for unit vectors only (a vector whose length is off by more
    than float32 rounding is passed on as it is, for the judge to flag).
    """
    x = np.array(x, dtype=np.float64)
    x[~ok] = np.nan
    with np.errstate(invalid="ignore"):
        r2 = x[:, 0] ** 2 + x[:, 1] ** 2
        unit = np.abs(np.sqrt(r2 + x[:, 2] ** 2) - 1.0) <= 4e-7
        polar = unit & (np.abs(x[:, 2]) > 0.5)
    x[polar, 2] = np.copysign(np.sqrt(np.maximum(0.0, 1.0 - r2[polar])), x[polar, 2])
    return x


def _bsdf_setup(plugin, wi, uv, component):
    """(plugin, wi, context, interaction(n), draw(columns, n)) of the BSDF adapters,
    arguments checked."""
    m = _mi()
    obj = _load(plugin, "plugin", ("BSDF",))
    w = _unit3("wi", wi)
    # uv reaches Mitsuba at the first draw, inside the check: a bad one raised a bare
    # IndexError or ValueError there, and NaN was taken
    uv = _point3("uv", uv, 2)
    if component is not None and (isinstance(component, bool)
                                  or not isinstance(component, numbers.Integral)
                                  or not 0 <= component < obj.component_count()):
        # 1.0 and "1" read "this BSDF has 2 components (0...1)", as if out of range
        kind = ("" if isinstance(component, numbers.Integral) and not isinstance(component, bool)
                else "an integer index, or None for all; ")
        raise InvalidArgument(f"component={component!r}: {kind}this BSDF has "
                              f"{obj.component_count()} components (0..."
                              f"{obj.component_count() - 1})")
    ctx = m.BSDFContext()
    if component is not None:
        ctx.component = int(component)

    def interaction(n):
        si = _zeros(m.SurfaceInteraction3f, n)
        si.wi = m.Vector3f(*w)
        si.n = m.Normal3f(0.0, 0.0, 1.0)
        si.sh_frame = m.Frame3f(m.Vector3f(0.0, 0.0, 1.0))
        # the surface's tangents along u and v, the shading frame's s and t: bumpmap
        # builds its perturbed normal from them (cross(dp_du, dp_dv)); left at zero,
        # every draw of a bump-mapped BSDF was NaN with zero weight, all rejected, and
        # the check passed with nothing tested
        si.dp_du = m.Vector3f(1.0, 0.0, 0.0)
        si.dp_dv = m.Vector3f(0.0, 1.0, 0.0)
        si.uv = m.Point2f(*uv)
        return si

    delta = int(m.BSDFFlags.Delta)

    def draw(cols, n):
        """``BSDF.sample`` of uniform columns: (BSDFSample, weight, not into a delta lobe)."""
        bs, weight = obj.sample(ctx, interaction(n), _float(cols[0]),
                                m.Point2f(_float(cols[1]), _float(cols[2])))
        return bs, weight, (np.asarray(bs.sampled_type).reshape(-1) & delta) == 0

    return obj, w, ctx, interaction, draw


def bsdf(plugin, wi, *, uv=(0.5, 0.5), component: int | None = None) -> Subject:
    """A BSDF's ``sample``/``pdf`` pair at incident direction ``wi`` (local frame).

    ``plugin``: a ``load_dict`` dict, an XML string or a loaded ``mi.BSDF`` (one
    registered from Python with ``mi.register_bsdf`` included). The sample is 3-D: the
    first number selects the lobe, as in Mitsuba's own χ² tests, so lobe selection is
    part of what is checked. Draws with zero weight (Mitsuba's way of rejecting: below
    the horizon, total internal reflection lost) or into a delta lobe come back as NaN
    rows (see :class:`Subject`). ``component`` restricts sampling and pdf to one
    component through ``BSDFContext.component``.

    The domain is the sphere: reflection and transmission together.
    """
    obj, w, ctx, interaction, bsdf_draw = _bsdf_setup(plugin, wi, uv, component)

    def draw(cols, n):
        bs, weight, smooth = bsdf_draw(cols, n)
        wt = np.asarray(weight, dtype=np.float64).reshape(3, -1)
        ok = np.any(wt != 0, axis=0) & (np.asarray(bs.pdf).reshape(-1) > 0) & smooth
        return bs.wo, ok

    def sample(u):
        x, ok = _rows(draw, _uniform(u, 3), 3)
        return _nan_rejected(x, ok)

    def pdf(x):
        return _rows(lambda c, n: (obj.pdf(ctx, interaction(n), _vec3(c)), True), x, 1)[0]

    return Subject(sample, pdf, "sphere",
                   {"sample_dim": 3, "name": f"mitsuba.bsdf:{_label(plugin, obj)}"
                                             f"{_at(w, uv, component)}"})


class WeightedSubject(NamedTuple):
    """A Mitsuba BSDF in the shape ``mcverify.check_pdf_consistency`` takes:
    ``sample(u) -> (wo, pdf, weight)`` as ``BSDF.sample`` returns them (a row of NaN
    where the draw went to a delta lobe), ``pdf(wo)`` and ``f(wo)`` (``BSDF.eval``:
    f · cos, rgb). ``kwargs``: ``sample_dim``, ``rejection``, ``rtol`` (float32's, 1e-3)
    and a ``name``. Use it as ``s, p, f, kw = mvm.bsdf_weighted(...);
    mv.check_pdf_consistency(s, p, f=f, **kw)``."""

    sample: Callable
    pdf: Callable
    f: Callable
    kwargs: dict


def bsdf_weighted(plugin, wi, *, uv=(0.5, 0.5), component: int | None = None
                  ) -> WeightedSubject:
    """What ``BSDF.sample`` returns with each direction (its pdf and weight) and what
    ``BSDF.pdf`` and ``BSDF.eval`` say of that direction, at incident ``wi`` (arguments
    as :func:`bsdf`). The directions are Mitsuba's own float32 values, not recomputed,
    so that ``pdf`` and ``eval`` see exactly what ``sample`` produced."""
    obj, w, ctx, interaction, bsdf_draw = _bsdf_setup(plugin, wi, uv, component)

    def draw(cols, n):
        bs, weight, smooth = bsdf_draw(cols, n)
        # a constant (thindielectric's weight) comes back as one value: broadcast
        parts = [(bs.wo, 3), (bs.pdf, 1), (weight, 3)]
        rows = np.concatenate([np.broadcast_to(np.asarray(v, dtype=np.float64).reshape(k, -1),
                                               (k, n)) for v, k in parts])
        return rows, smooth

    def sample(u):
        out, ok = _rows(draw, _uniform(u, 3), 7)
        out[~ok] = np.nan
        return out[:, :3], out[:, 3], out[:, 4:]

    def pdf(x):
        return _rows(lambda c, n: (obj.pdf(ctx, interaction(n), _vec3(c)), True), x, 1)[0]

    def f(x):
        return _rows(lambda c, n: (obj.eval(ctx, interaction(n), _vec3(c)), True), x, 3)[0]

    return WeightedSubject(sample, pdf, f, {
        "sample_dim": 3, "rejection": True, "rtol": 1e-3,
        "name": f"mitsuba.bsdf_weighted:{_label(plugin, obj)}{_at(w, uv, component)}"})


def _fmt(v) -> str:
    return "(" + ",".join(f"{c:.3g}" for c in v) + ")"


def _at(w, uv, component) -> str:
    """Where a BSDF adapter samples, for its check's name: ``@wi=(…)``, and the uv and
    component where not the defaults (two components of one plastic, or two texels of
    one textured BSDF, were checks of one name; an outside review)."""
    return (f"@wi={_fmt(w)}"
            + (f",uv={_fmt(uv)}" if tuple(float(c) for c in uv) != (0.5, 0.5) else "")
            + (f",component={component}" if component is not None else ""))


def emitter(plugin, ref=(0.0, 0.0, 0.0)) -> Subject:
    """An emitter's ``sample_direction``/``pdf_direction`` pair seen from point ``ref``.

    ``plugin``: an emitter (``{"type": "envmap", ...}``, ``"constant"``, ...) or a shape
    carrying an ``area`` emitter (``{"type": "sphere", "emitter": {"type": "area"}}``),
    as a dict, an XML string or a loaded plugin. ``pdf(d)`` traces the ray ``ref + t·d``
    against the shape, builds the ``DirectionSample3f`` from the hit (as Mitsuba's
    integrators do for MIS) and returns 0 where it misses. Draws with zero weight (the
    light's back side) come back as NaN rows. Delta emitters (point, spot, directional)
    have no density and are refused.
    """
    m = _mi()
    obj = _load(plugin, "plugin", ("Emitter", "Shape"))
    p = _point3("ref", ref)
    scene = None
    if isinstance(obj, m.Shape):
        light = obj.emitter()
        if light is None:
            raise InvalidArgument("plugin: a shape without an emitter; add "
                                  "'emitter': {'type': 'area'}")
        scene = m.load_dict({"type": "scene", "shape": obj})
        obj = light
    if int(obj.flags()) & int(m.EmitterFlags.Delta):
        raise InvalidArgument(f"plugin: {_label(plugin, obj)} is a delta emitter (point, spot,"
                              " directional): no density to test")
    if scene is None and int(obj.flags()) & int(m.EmitterFlags.Surface):
        raise InvalidArgument("plugin: an area emitter must be given with its shape, e.g. "
                              "{'type': 'rectangle', 'emitter': {'type': 'area'}}")

    def origin(n):
        it = _zeros(m.Interaction3f, n)
        it.p = m.Point3f(*p)
        return it

    def draw(cols, n):
        ds, weight = obj.sample_direction(origin(n), m.Point2f(_float(cols[0]),
                                                              _float(cols[1])))
        wt = np.asarray(weight, dtype=np.float64).reshape(3, -1)
        ok = np.any(wt != 0, axis=0) & (np.asarray(ds.pdf).reshape(-1) > 0)
        return ds.d, ok

    def sample(u):
        x, ok = _rows(draw, _uniform(u, 2), 3)
        return _nan_rejected(x, ok)

    def density(cols, n):
        it, d = origin(n), _vec3(cols)
        if scene is None:
            ds = _zeros(m.DirectionSample3f, n)
            ds.d = d
            return obj.pdf_direction(it, ds), True
        si = scene.ray_intersect(it.spawn_ray(d))
        ds = m.DirectionSample3f(scene, si, it)
        return obj.pdf_direction(it, ds, si.is_valid()), si.is_valid()

    def pdf(x):
        v, hit = _rows(density, x, 1)
        return np.where(hit, v, 0.0)

    return Subject(sample, pdf, "sphere",
                   {"sample_dim": 2, "name": f"mitsuba.emitter:{_label(plugin, obj)}"
                                             f"@ref={_fmt(p)}"})


def microfacet(distribution: str, alpha, *, wi=(0.0, 0.0, 1.0),
               sample_visible: bool = True) -> Subject:
    """``mi.MicrofacetDistribution``'s normal sampling: ``sample(wi, u)`` against
    ``pdf(wi, m)``, over the hemisphere of microfacet normals.

    ``distribution``: ``"ggx"`` or ``"beckmann"``; ``alpha``: one roughness or
    ``(alpha_u, alpha_v)`` (anisotropic); ``sample_visible``: the distribution of
    visible normals from ``wi`` (Heitz 2018) instead of ``D(m) cos θ_m``.
    """
    m = _mi()
    types = {"ggx": m.MicrofacetType.GGX, "beckmann": m.MicrofacetType.Beckmann}
    if distribution not in types:
        raise InvalidArgument(f"distribution={distribution!r}: expected 'ggx' or 'beckmann'")
    if isinstance(alpha, np.ndarray) and alpha.ndim == 0:
        alpha = alpha.item()
    if isinstance(alpha, (list, tuple, np.ndarray)):
        if len(alpha) != 2:     # was a bare "too many values to unpack"
            raise InvalidArgument(f"alpha={alpha!r}: one roughness or a pair "
                                  "(alpha_u, alpha_v)")
        au, av = alpha
    else:
        au = av = alpha
    for name, a in (("alpha_u", au), ("alpha_v", av)):
        # numpy's floats are numbers too (np.float32(0.1) was refused); a bool is not
        # (alpha=True was α = 1)
        if (isinstance(a, bool) or not isinstance(a, numbers.Real) or not np.isfinite(a)
                or not a > 0):
            raise InvalidArgument(f"alpha={alpha!r}: {name} must be a positive number")
    # sample_visible="False" was true
    sample_visible = _validate.boolean("sample_visible", sample_visible)
    w = _unit3("wi", wi)
    if sample_visible and w[2] <= 0:
        raise InvalidArgument(f"wi={wi!r}: visible normals need wi above the horizon (z > 0)")
    dist = m.MicrofacetDistribution(types[distribution], float(au), float(av),
                                    bool(sample_visible))

    def draw(cols, n):
        mm, pdf_ = dist.sample(m.Vector3f(*w), m.Point2f(_float(cols[0]), _float(cols[1])))
        return mm, np.asarray(pdf_).reshape(-1) > 0

    def sample(u):
        x, ok = _rows(draw, _uniform(u, 2), 3)
        return _nan_rejected(x, ok)

    def pdf(x):
        return _rows(lambda c, n: (dist.pdf(m.Vector3f(*w), _vec3(c)), True), x, 1)[0]

    a = f"{au:g}" if au == av else f"{au:g},{av:g}"
    label = f"mitsuba.microfacet:{distribution}(alpha={a}{',visible' if sample_visible else ''})"
    return Subject(sample, pdf, "hemisphere",
                   {"sample_dim": 2, "name": label + (f"@wi={_fmt(w)}" if sample_visible
                                                      else "")})


def phase(plugin, wi=(0.0, 0.0, 1.0)) -> Subject:
    """A phase function's ``sample``/``eval_pdf`` pair for incident direction ``wi``.

    ``plugin``: a dict (``{"type": "hg", "g": 0.5}``), an XML string or a loaded
    ``mi.PhaseFunction``. The sample is 3-D (Mitsuba passes a lobe-selection number
    first); the domain is the sphere.
    """
    m = _mi()
    obj = _load(plugin, "plugin", ("PhaseFunction",))
    w = _unit3("wi", wi)
    ctx = m.PhaseFunctionContext()

    def interaction(n):
        mei = _zeros(m.MediumInteraction3f, n)
        mei.wi = m.Vector3f(*w)
        mei.sh_frame = m.Frame3f(m.Vector3f(*w))
        return mei

    def draw(cols, n):
        wo, weight, pdf_ = obj.sample(ctx, interaction(n), _float(cols[0]),
                                      m.Point2f(_float(cols[1]), _float(cols[2])))
        wt = np.asarray(weight, dtype=np.float64).reshape(3, -1)
        return wo, np.any(wt != 0, axis=0) & (np.asarray(pdf_).reshape(-1) > 0)

    def sample(u):
        x, ok = _rows(draw, _uniform(u, 3), 3)
        return _nan_rejected(x, ok)

    def pdf(x):
        return _rows(lambda c, n: (obj.eval_pdf(ctx, interaction(n), _vec3(c))[1], True),
                     x, 1)[0]

    return Subject(sample, pdf, "sphere",
                   {"sample_dim": 3, "name": f"mitsuba.phase:{_label(plugin, obj)}"
                                             f"@wi={_fmt(w)}"})
