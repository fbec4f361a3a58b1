"""The render gate: our path tracer's image of a scene against Mitsuba's reference,
pixel by pixel (``compare_images``).

Both sides are independent passes (ours: ``passes`` passes of spp / passes samples), so
each pixel's value is a pass mean, far less skewed than a single path sample; that keeps
the pixelwise t-test calibrated on heavy-tailed pixels (caustics, a small sun).
"""

from __future__ import annotations

import dataclasses
import time
from typing import Callable

from ..errors import InvalidArgument, MissingReference
from ..result import CheckResult
from ..checks.image import compare_images

# Pass means of 32 samples on the Cornell box's caustic pixels are skewed enough that the
# pixel t-test against a low-noise reference raised false alarms on 4 seeds of 4; at 64
# samples per pass the gate is calibrated (slow test: ours at the defaults against fresh
# references).
MIN_SPP_PER_PASS = 64


#: A renderer under test: ``render(scene_path, spp, seed)`` returning ``(mean, var, n)``:
#: the per-pixel mean (H, W) or (H, W, C), the per-pixel variance of the ``n`` i.i.d.
#: values averaged into it (samples or independent passes), and ``n``. An object with
#: ``mean``, ``variance`` and ``n`` attributes (our ``RenderResult``) is accepted too.
Renderer = Callable[[str, int, int], object]


def path_tracer(*, passes: int = 16, params: dict | None = None, pdf_scale: float = 1.0,
                plant: dict | None = None, progress=None) -> Renderer:
    """Our path tracer (``estimators.pathtracer``) as a ``Renderer``: ``passes``
    independent passes of ``spp / passes`` samples, so ``n = passes`` pass means.
    ``params`` are XML ``$`` overrides, ``pdf_scale`` the wrong-pdf hook (1: correct),
    ``plant`` plants a bug (``CompiledScene.planted`` keywords)."""
    def render_ours(scene_path: str, spp: int, seed: int):
        from estimators.pathtracer import SceneError, compile_scene, render

        try:
            subject = compile_scene(scene_path, params=params)
        except SceneError as e:
            raise InvalidArgument(str(e)) from None
        if plant:
            subject = subject.planted(**plant)
        return render(subject, spp=spp, passes=passes, seed=seed, pdf_scale=pdf_scale,
                      progress=progress)

    return render_ours


def _rendered(out, who: str):
    """(mean, var, n, seconds, stats) of a renderer's output: a RenderResult-like object
    or a ``(mean, var, n)`` tuple."""
    if hasattr(out, "mean") and hasattr(out, "variance") and hasattr(out, "n"):
        return (out.mean, out.variance, out.n, getattr(out, "seconds", None),
                getattr(out, "stats", {}) or {})
    try:
        mean, var, n = out
    except (TypeError, ValueError):
        raise InvalidArgument(f"renderer={who}: returned {type(out).__name__}; expected "
                              "(mean, var, n) or an object with mean, variance, n") from None
    return mean, var, n, None, {}


def render_check(scene: str, *, renderer: Renderer | None = None, spp: int = 1024,
                 passes: int = 16, seed: int = 0, alpha: float = 0.01,
                 params: dict | None = None, pdf_scale: float = 1.0,
                 plant: dict | None = None, build_missing: bool = True, notice=None,
                 progress=None) -> CheckResult:
    """Render ``scene`` (a reference name or a scene.xml path) and compare the image with
    Mitsuba's reference by ``compare_images``.

    ``renderer`` is any ``Renderer`` (``render(scene_path, spp, seed) -> (mean, var,
    n)``); by default our path tracer in ``passes`` passes (``path_tracer``), whose
    ``pdf_scale`` and ``plant`` hooks plant bugs for the gate's own tests.

    The cached reference (``<scene folder>/ref``) is used when ``params`` is empty; a
    missing one is built first (``notice(message)`` says so); a stale or corrupt one is an
    error. With ``params`` (XML ``$`` overrides, e.g. ``{"max_depth": 2}``) the reference
    is rendered on the fly with the same overrides (16 passes × 64 spp)."""
    from . import reference

    if renderer is None:
        if passes < 2 or spp < MIN_SPP_PER_PASS * passes:
            raise InvalidArgument(f"spp={spp}, passes={passes}: need passes >= 2 and at least "
                                  f"{MIN_SPP_PER_PASS} samples per pass (pass means of fewer "
                                  "samples are too skewed on caustic pixels for the t-test)")
        renderer = path_tracer(passes=passes, params=params, pdf_scale=pdf_scale, plant=plant,
                               progress=progress)
    elif pdf_scale != 1.0 or plant:
        raise InvalidArgument("pdf_scale/plant: planted bugs are hooks of our path tracer; "
                              "they cannot be applied to a renderer= of your own")
    name, path = reference.resolve_scene(scene)
    t0 = time.perf_counter()
    if params:
        ref, _ = reference.render_reference(path, params=params, seed=seed + 1)
    else:
        try:
            ref = reference.load_reference(path)
        except MissingReference:
            if not build_missing:
                raise
            if notice:
                notice(f"{name}: no reference yet; building it with Mitsuba (once)")
            reference.build_reference(path)
            ref = reference.load_reference(path)
    ref_seconds = time.perf_counter() - t0
    t1 = time.perf_counter()
    mean, var, n, seconds, stats = _rendered(renderer(path, spp, seed),
                                             getattr(renderer, "__name__", "renderer"))
    seconds = time.perf_counter() - t1 if seconds is None else seconds
    if getattr(mean, "shape", None) != ref.mean.shape:
        raise InvalidArgument(f"{path}: the rendered image is {getattr(mean, 'shape', None)}, "
                              f"the reference {ref.mean.shape}; rebuild the reference")
    label = name + "".join(f",{k}={v}" for k, v in sorted({**(params or {}), **(plant or {}),
                                                           **({"pdf_scale": pdf_scale}
                                                              if pdf_scale != 1 else {})
                                                           }.items()))
    result = compare_images(mean, ref.mean, test_var=var, ref_var=ref.var,
                            test_n=n, ref_n=ref.n, alpha=alpha, name=f"render:{label}")
    details = dict(result.details, scene=path, ours_spp=spp, ours_passes=n,
                   ours_seconds=seconds, ours_kernel=stats.get("kernel"),
                   ours_samples_per_second=stats.get("samples_per_second"),
                   compile_seconds=stats.get("compile_seconds"),
                   reference=ref.manifest, reference_seconds=ref_seconds)
    artifacts = dict(result.artifacts, ours=mean, mitsuba=ref.mean)
    return dataclasses.replace(result, details=details, artifacts=artifacts,
                               seconds=result.seconds + seconds + ref_seconds,
                               n_samples=spp * mean.shape[0] * mean.shape[1])


def global_sensitivity(scene: str, *, epsilons=(0.0025, 0.005, 0.01, 0.02, 0.05),
                       seeds=(0, 1), spp: int = 1024, passes: int = 16) -> dict:
    """The smallest global bias the render gate catches on a scene at a budget: every
    emitter scaled by 1 ± ε, for growing ε, until both signs are rejected on every seed.
    Returns {"scene", "caught_at" (ε or None), "trials": [(ε, sign, seed, p, found_by)]}."""
    trials = []
    for eps in epsilons:
        caught = True
        for sign in (1, -1):
            for seed in seeds:
                r = render_check(scene, spp=spp, passes=passes, seed=seed,
                                 plant={"light_scale": 1 + sign * eps})
                trials.append((eps, sign, seed, r.p_value, r.details["found_by"]))
                caught &= not r.passed
        if caught:
            return {"scene": scene, "caught_at": eps, "trials": trials}
    return {"scene": scene, "caught_at": None, "trials": trials}
