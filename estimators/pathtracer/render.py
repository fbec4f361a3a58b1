"""``render(scene, spp=, seed=)``: our path tracer's front end.

The kernel is specialised to the features a scene uses: ``specialised_kernel`` writes a
copy of ``_kernel.py`` with its feature constants set into a cache folder
(``$MCVERIFY_CACHE`` or ``~/.cache/mcverify/kernels``), and numba compiles and caches
that copy on disk, so a second process starts warm. ``general=True`` runs the kernel with
every feature on, for comparison.
"""

from __future__ import annotations

import ast
import functools
import hashlib
import math
import numbers
import os
import time
from dataclasses import dataclass, field

import numpy as np

from mcnumba.threads import get_num_threads, run_split

from .. import _memory
from . import _kernel
from .camera import SPLAT_CHANNELS, SPLAT_VALUE_CHANNELS
from .layout import F_STRATIFIED
from .._generated import first_call, load
from .prepare import PreparedScene, prepare_scene

TILE = 8
_MODULES: dict[str, object] = {}
#: A render's samples a pixel with a stratified sampler stay below this (31-bit strata:
#: ``_kernel.strata_field``).
STRATIFIED_SPP_LIMIT = 2 ** 31


@dataclass(frozen=True)
class RenderResult:
    """Per-pixel mean and sample variance of ``n`` samples, (H, W, 3) float32 (variance
    None when ``render(variance=False)``); with passes, ``passes`` holds the ``n`` pass
    images (n, H, W, 3) float32 (the render gate needs them where a splatting filter
    correlates neighbouring pixels)."""

    mean: np.ndarray
    variance: np.ndarray | None
    n: int
    seconds: float
    stats: dict = field(default_factory=dict)
    passes: np.ndarray | None = None


@functools.lru_cache(maxsize=None)
def _imported_files(path: str, top: str | None = None) -> tuple[str, ...]:
    """The files of the ``estimators`` package that ``path`` imports, directly or through
    them (every ``import``/``from`` statement, at module level or inside a function;
    relative ones resolved), ``path`` excluded. A package's ``__init__`` is not followed:
    numba compiles a function together with the globals of its own module only, and a
    module's names reach another module only through an import statement. Parsing them
    takes ~140 ms, so once per process (the digest itself, a hash of their bytes, is
    computed where asked: ~1 ms)."""
    # ``top``: the folder holding ``estimators/`` (a test gives another)
    top = top or os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    seen, todo = set(), [os.path.abspath(path)]
    while todo:
        current = todo.pop()
        with open(current, encoding="utf-8") as f:
            tree = ast.parse(f.read(), current)
        package = os.path.relpath(os.path.dirname(current), top).split(os.sep)
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                base = (package[:len(package) - node.level + 1] if node.level else [])
                base += node.module.split(".") if node.module else []
                targets = [base + [a.name] for a in node.names] + [base]
            elif isinstance(node, ast.Import):
                targets = [a.name.split(".") for a in node.names]
            else:
                continue
            for parts in targets:
                if parts[:1] != ["estimators"]:
                    continue
                f = os.path.join(top, *parts) + ".py"
                if os.path.isfile(f) and f not in seen and f != os.path.abspath(path):
                    seen.add(f)
                    todo.append(f)
    return tuple(sorted(seen))


def _dependency_digest(template: str | None = None) -> str:
    """Hash of every source the kernel (or another template, ``_sampling_loops.py``)
    compiles in: the files it imports, transitively (``_imported_files``). numba's cache
    checks only the file of the cached function itself, not its callees, so the
    generated file's name carries this digest: an edit to a BSDF or a warp makes a new
    kernel, never a stale one, and an edit to the Python that drives it (``render.py``,
    ``prepare.py``) does not cost a recompilation of every scene's kernel."""
    h = hashlib.sha256()
    for path in _imported_files(template or _kernel.__file__):
        h.update(os.path.basename(path).encode())
        with open(path, "rb") as f:
            h.update(f.read())
    return h.hexdigest()


@functools.lru_cache(maxsize=None)
def _kernel_source(features: int) -> tuple[str, str]:
    """(module name, source) of the kernel for ``features``: read and hashed once per
    process, not once per render pass."""
    with open(_kernel.__file__, encoding="utf-8") as f:
        template = f.read()
    start = template.index("# --- features (rewritten by render.specialised_kernel) ---")
    end = template.index("# --- end features ---")
    source = (template[:start] + f"# --- features (generated) ---\nFEATURES = {int(features)}\n"
              + template[end:])
    key = hashlib.sha256((source + _dependency_digest()).encode()).hexdigest()[:16]
    return f"mcverify_kernel_{key}", source


def specialised_kernel(features: int):
    """The kernel module compiled for ``features`` (a bit mask; -1: all)."""
    return load_cached(*_kernel_source(int(features)))


def load_cached(name: str, source: str):
    """The module ``name`` with ``source``, written once into the kernel cache folder (so
    that numba's ``cache=True`` works for it) and imported once per process. ``name``
    must carry a hash of ``source`` and of ``_dependency_digest()``."""
    if name in _MODULES:
        return _MODULES[name]
    module = load(name, source)
    _MODULES[name] = module
    return module


def _tiles(width: int, height: int, threads: int) -> np.ndarray:
    """Rows (x0, y0, x1, y1) of the image's tiles, dealt to ``threads`` like cards: each
    thread renders one contiguous block of them (``_dealt``), and the block of thread i
    holds tiles i, i + threads, i + 2 threads... spread over the whole image, so a
    costly region (a glass sphere, the mesh) is shared by all threads instead of falling
    to one."""
    y, x = np.meshgrid(np.arange(0, height, TILE, dtype=np.int64),
                       np.arange(0, width, TILE, dtype=np.int64), indexing="ij")
    x, y = x.ravel(), y.ravel()         # row-major tiles: x fastest
    rows = np.stack([x, y, np.minimum(x + TILE, width), np.minimum(y + TILE, height)], axis=1)
    return np.concatenate([rows[i::threads] for i in range(threads)])


def _dealt(n: int, threads: int) -> list[int]:
    """Where each thread's block of ``_tiles(..., threads)`` starts, and the end: thread
    i was dealt ``ceil((n - i) / threads)`` of the ``n`` tiles."""
    return [sum(len(range(i, n, threads)) for i in range(k)) for k in range(threads + 1)]


def _integer(name: str, v, minimum: int, maximum: int | None = None) -> None:
    if isinstance(v, bool) or not isinstance(v, numbers.Integral):
        raise ValueError(f"{name}={v!r}: must be an integer (got {type(v).__name__})")
    if v < minimum or (maximum is not None and v > maximum):
        raise ValueError(f"{name}={v}: must be in [{minimum}, "
                         f"{'∞' if maximum is None else maximum}]")


def _render_iv(spp, seed, passes, pdf_scale, params, variance, general=None,
               progress=None) -> None:
    """render()'s arguments, checked before the scene is compiled: a ValueError names the
    parameter (no silent coercion of '64' or 2.5)."""
    if spp is not None:     # the kernel counts samples in int64 (10**30 was an
        _integer("spp", spp, 1, 2 ** 63 - 1)        # OverflowError naming nothing)
    _integer("seed", seed, 0, 2 ** 63 - 1)
    _integer("passes", passes, 1)
    if isinstance(pdf_scale, bool) or not isinstance(pdf_scale, numbers.Real) \
            or not (math.isfinite(pdf_scale) and pdf_scale > 0):
        raise ValueError(f"pdf_scale={pdf_scale!r}: must be a finite number > 0")
    if params is not None and not isinstance(params, dict):
        raise ValueError(f"params={params!r}: must be a dict of scene parameters")
    if not isinstance(variance, (bool, np.bool_)):
        raise ValueError(f"variance={variance!r}: must be True or False")
    if general is not None and not isinstance(general, (bool, np.bool_)):
        raise ValueError(f"general={general!r}: must be True, False or None (None: "
                         "$MCVERIFY_GENERAL_KERNEL decides)")
    if progress is not None and not callable(progress):
        raise ValueError(f"progress={progress!r}: must be callable as progress(done, total)")


#: Bytes a pixel of the film takes in the render's buffers, at least (mean, second
#: moment, count and the non-finite count: 3 + 3 + 1 + 1 float64 or int64).
_FILM_BYTES_PER_PIXEL = 64


#: Bytes a pixel of each pass takes while a render in passes holds them, at most: its
#: mean in float64 (24) and the stack of them (24); then the stack and numpy's variance
#: temporary (24 + 24), then the stack and ``RenderResult.passes`` in float32 (24 + 12).
#: The means are let go once stacked (held through the variance, the peak was 72; a
#: read-only review); 60 keeps a margin.
_PASS_BYTES_PER_PIXEL = 60


def _film_fits(cs, passes: int) -> None:
    """Refuse, naming the film, a render whose image buffers exceed this machine's
    physical memory (a 100000 × 100000 film failed in numpy's allocation, naming an
    array shape; an outside review), and, naming ``passes``, one whose pass images,
    all held until the last pass, do (passes=10**6 of a 64 x 64 film, 229 GiB, would
    render every pass and then fail in numpy's allocation; an outside review)."""
    pixels = cs.width * cs.height
    need = pixels * _FILM_BYTES_PER_PIXEL
    have = _memory.physical_bytes()
    if have is not None and need > have:
        raise ValueError(f"film {cs.width} x {cs.height}: its image buffers need "
                         f"{need / 2**30:.3g} GiB, more than this machine's "
                         f"{have / 2**30:.3g} GiB of memory")
    if passes > 1 and have is not None and need + passes * pixels * _PASS_BYTES_PER_PIXEL > have:
        most = (have - need) // (pixels * _PASS_BYTES_PER_PIXEL)
        raise ValueError(f"passes={passes}: the pass images of the {cs.width} x {cs.height} "
                         f"film, all held until the last pass, need "
                         f"{passes * pixels * _PASS_BYTES_PER_PIXEL / 2**30:.3g} GiB, more "
                         f"than this machine's {have / 2**30:.3g} GiB of memory: "
                         + (f"use at most {most} passes" if most >= 2 else
                            "render in one pass (passes=1)"))


def render(scene, *, spp: int | None = None, seed: int = 0, passes: int = 1,
           general: bool | None = None, pdf_scale: float = 1.0, params: dict | None = None,
           progress=None, variance: bool = True) -> RenderResult:
    """Render a Mitsuba XML scene (path, ``SceneDescription`` or ``PreparedScene``) with
    ``spp`` samples per pixel (default: the scene's sampler). The same seed gives the same
    image bit for bit, whatever the number of threads. ``progress(done, total)`` is called
    as tiles finish.

    With ``passes`` = K > 1 the spp are split into K independent passes and ``variance``
    and ``n`` describe the K pass means (as Mitsuba references do): pass means are far
    less skewed than single path samples, which keeps a pixelwise t-test calibrated.

    ``variance=False``: the image alone (``RenderResult.variance`` None, any spp >= 1), as
    Mitsuba's ``render`` and the render gate's passes need it; a splatting filter then
    adds 4 sums a pixel instead of 11 (one thread, 128², 64 spp, CPU s: filters 0.352 ->
    0.293, filters-tent 0.251 -> 0.226, filters-gaussian 0.273 -> 0.255).
    Passes compute their variance from the pass means either way.

    ``pdf_scale`` != 1 is a test hook: every BSDF sample's pdf is scaled by it, a planted
    bug the render gate must catch.

    ``general``: run the kernel compiled for every feature instead of the scene's
    specialised one (bit-identical images, ~10 % slower, one compilation for all scenes).
    Default: ``$MCVERIFY_GENERAL_KERNEL`` = 1 means general (the default test run sets it:
    a new machine compiles one kernel instead of one per scene), else specialised."""
    if general is None:
        general = os.environ.get("MCVERIFY_GENERAL_KERNEL", "") == "1"
    _render_iv(spp, seed, passes, pdf_scale, params, variance, general, progress)
    cs: PreparedScene = prepare_scene(scene, params=params)
    spp = cs.spp if spp is None else int(spp)
    # a stratified or multijitter sampler: each pixel's samples stratified per dimension
    stratified = bool(cs.features & F_STRATIFIED)
    if stratified and spp // passes >= STRATIFIED_SPP_LIMIT:
        raise ValueError(f"spp={spp}" + (f", passes={passes}: {spp // passes} a pass"
                                         if passes > 1 else "")
                         + ": a stratified or multijitter sampler takes fewer than 2^31 "
                         "samples a pixel (its strata are 31-bit)")
    _film_fits(cs, passes)
    if passes > 1:
        return _render_passes(cs, spp, seed, int(passes), general, pdf_scale, progress)
    if spp < 2 and variance:
        raise ValueError(f"spp must be >= 2 for a per-pixel variance, got {spp} (or "
                         "render(variance=False): the image alone)")
    features = -1 if general else cs.features
    module = specialised_kernel(features)
    w, h = cs.width, cs.height
    cam = cs.camera.params
    threads = get_num_threads()
    pdf_scale = float(pdf_scale)
    bad = np.zeros((h, w), dtype=np.int64)
    if cs.camera.splats:
        film = _SplatFilm(cs.camera, module, h, w, bool(variance))
    else:
        film = _BoxFilm(module, h, w)
    t0 = time.perf_counter()
    # the kernel's first call in this process (no tiles: compile, or load from numba's
    # cache) holds the module's lock, so processes starting together compile it once: the
    # box and the splatting film's kernels share ``trace``, so one lock for both (a
    # process that needs the other waits for ``trace`` and loads it from numba's cache)
    with first_call(f"{module.__name__}.{type(film).__name__}", module.__name__):
        film.render(cs.arrays, cam, _tiles(1, 1, 1)[:0], spp, seed, stratified, pdf_scale,
                    bad, 1)
    compile_seconds = time.perf_counter() - t0
    # one parallel call, or with a progress callback up to 20 (each call ends on its
    # slowest thread, so chunks cost time); a splatting film also bounds its tile buffers
    n_chunks = max(1, min(20, (w * h) // (4 * threads * TILE * TILE))) if progress else 1
    n_chunks = max(n_chunks, film.min_chunks(w, h))
    bounds = np.linspace(0, h, n_chunks + 1).astype(int)
    bounds = np.unique(bounds - bounds % TILE)      # whole tile rows
    bounds = np.append(bounds, h) if bounds[-1] != h else bounds
    n_tiles = len(_tiles(w, h, 1))
    t0 = time.perf_counter()
    for a, b in zip(bounds[:-1], bounds[1:]):
        band = _tiles(w, b - a, threads)
        band[:, 1] += a
        band[:, 3] += a
        film.render(cs.arrays, cam, band, spp, seed, stratified, pdf_scale, bad, threads)
        if progress:
            progress(n_tiles * int(b) // h, n_tiles)
    seconds = time.perf_counter() - t0
    mean, var = film.develop(spp)
    stats = {"compile_seconds": compile_seconds, "threads": threads,
             "samples_per_second": w * h * spp / seconds if seconds > 0 else float("inf"),
             "kernel": "general" if features == -1 else f"specialised({cs.features:#x})",
             "nonfinite_samples": int(bad.sum()), "triangles": cs.n_triangles,
             "lights": cs.n_lights, "bsdfs": list(cs.bsdf_names),
             "rfilter": cs.camera.rfilter}
    with np.errstate(over="ignore"):    # beyond float32's range is inf, and counted
        return RenderResult(mean.astype(np.float32),
                            var.astype(np.float32) if variance else None, spp, seconds,
                            stats)


class _BoxFilm:
    """Box filter: each sample counts in its own pixel; per pixel the mean and the sum of
    squared deviations of its samples (``render_tiles``)."""

    def __init__(self, module, h, w):
        self.module, self.width, self.height = module, w, h
        self.mean = np.zeros((h, w, 3))
        self.m2 = np.zeros((h, w, 3))

    def min_chunks(self, w, h) -> int:
        return 1

    def render(self, arrays, cam, tiles, spp, seed, stratified, pdf_scale, bad, threads):
        """Render ``tiles``, dealt to ``threads`` by ``_tiles``, on that many threads."""
        run_split(self.module.render_tiles, _dealt(len(tiles), threads), arrays, cam, tiles,
                  self.width, self.height, spp, seed, stratified, pdf_scale, self.mean,
                  self.m2, bad)

    def develop(self, spp):
        return self.mean, (self.m2 / (spp - 1) if spp > 1 else None)


class _SplatFilm:
    """A splatting reconstruction filter (``camera`` says which; ``splat_tiles``): per
    pixel Σw, Σw·L, Σw², Σw²·L, Σw²·L². The value is the ratio Σ w L / Σ w (0 where no
    sample reached the pixel, as in Mitsuba); its variance is the delta method's
    Σ w² (L - value)² / (Σ w)², reported times spp (``RenderResult``: variance / n is
    the variance of the pixel's value). Neighbouring pixels share samples, so their
    values correlate; the render gate compares pass images for that reason."""

    #: Bytes of tile buffers one ``splat_tiles`` call may allocate.
    BUFFER_BYTES = 1 << 26

    def __init__(self, camera, module, h, w, variance=True):
        self.module, self.width, self.height = module, w, h
        self.reach = int(math.ceil(camera.filter_radius + 0.5))
        self.channels = SPLAT_CHANNELS if variance else SPLAT_VALUE_CHANNELS
        self.acc = np.zeros((h, w, self.channels))

    def min_chunks(self, w, h) -> int:
        side = TILE + 2 * self.reach
        per_tile = side * side * self.channels * 8
        n_tiles = -(-w // TILE) * -(-h // TILE)
        return max(1, min(-(-h // TILE), -(-n_tiles * per_tile // self.BUFFER_BYTES)))

    def render(self, arrays, cam, tiles, spp, seed, stratified, pdf_scale, bad, threads):
        """Render ``tiles``, dealt to ``threads`` by ``_tiles``, on that many threads: each
        tile into a buffer of its own, added up in row-major tile order after."""
        r = self.reach
        extent = np.maximum(tiles[:, 2] - tiles[:, 0], tiles[:, 3] - tiles[:, 1])
        side = int(extent.max(initial=0)) + 2 * r
        buf = np.zeros((len(tiles), side, side, self.channels))
        run_split(self.module.splat_tiles, _dealt(len(tiles), threads), arrays, cam, tiles,
                  r, self.width, self.height, spp, seed, stratified, pdf_scale, buf, bad)
        # added row by row (``tiles`` is dealt to the threads: its order depends on how
        # many; until 6 December the sums, and so the variance, did too)
        order = np.lexsort((tiles[:, 0], tiles[:, 1]))
        self.module.add_splats(tiles, order, r, buf, self.acc)

    def develop(self, spp):
        a = self.acc
        wsum = a[:, :, 0:1]
        safe = np.where(wsum > 0, wsum, 1.0)
        mean = np.where(wsum > 0, a[:, :, 1:4] / safe, 0.0)
        if self.channels != SPLAT_CHANNELS:
            return mean, None
        var = (a[:, :, 8:11] - 2 * mean * a[:, :, 5:8] + mean ** 2 * a[:, :, 4:5]) / safe ** 2
        return mean, np.maximum(var, 0.0) * spp


def pass_seed(seed: int, k: int) -> int:
    """Seed of pass ``k`` of a render with ``passes`` > 1 (render one pass alone with it
    and ``spp // passes`` samples, and it is bit-identical to that pass of the whole)."""
    return (seed + k * 0x9E3779B97F4A7C15) % 2 ** 63


def _render_passes(cs, spp, seed, passes, general, pdf_scale, progress) -> RenderResult:
    per = spp // passes
    if per < 1 or spp % passes:
        raise ValueError(f"spp={spp} cannot be split into {passes} equal passes (spp must "
                         "be a multiple of passes)")
    means = []
    seconds = compile_seconds = 0.0
    stats = {}
    nonfinite = 0
    for k in range(passes):
        r = render(cs, spp=per, seed=pass_seed(seed, k),
                   general=general, pdf_scale=pdf_scale, variance=False,
                   progress=(lambda d, t, k=k: progress(k * t + d, passes * t))
                   if progress else None)
        means.append(r.mean.astype(np.float64))
        seconds += r.seconds
        stats = r.stats
        # the whole render's counts (until 6 December the last pass's alone)
        nonfinite += stats["nonfinite_samples"]
        compile_seconds += stats["compile_seconds"]
    m = np.stack(means)
    del means       # the stack holds them now: _PASS_BYTES_PER_PIXEL counts them once
    stats = dict(stats, passes=passes, spp_per_pass=per, nonfinite_samples=nonfinite,
                 compile_seconds=compile_seconds,
                 samples_per_second=cs.width * cs.height * per * passes / seconds)
    with np.errstate(over="ignore", invalid="ignore"):     # inf passes: inf, NaN spread
        return RenderResult(m.mean(axis=0).astype(np.float32),
                            m.var(axis=0, ddof=1).astype(np.float32), passes, seconds,
                            stats, m.astype(np.float32))
