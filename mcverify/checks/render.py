"""The render gate: our path tracer's image of a scene against Mitsuba's reference,
pixel by pixel (``compare_images``).

Both sides are independent passes (ours: ``passes`` passes of spp / passes samples), so
each pixel's value is a pass mean, far less skewed than a single path sample; that keeps
the pixelwise t-test calibrated on heavy-tailed pixels (caustics, a small sun).
"""

from __future__ import annotations

import dataclasses
import time

from ..errors import InvalidArgument, MissingReference
from ..result import CheckResult
from .image import compare_images

# Pass means of 32 samples on the Cornell box's caustic pixels are skewed enough that the
# pixel t-test against a low-noise reference raised false alarms on 4 seeds of 4; at 64
# samples per pass the gate is calibrated (slow test: ours at the defaults against fresh
# references).
MIN_SPP_PER_PASS = 64


def render_check(scene: str, *, spp: int = 1024, passes: int = 16, seed: int = 0,
                 alpha: float = 0.01, params: dict | None = None, pdf_scale: float = 1.0,
                 plant: dict | None = None, build_missing: bool = True, notice=None,
                 progress=None) -> CheckResult:
    """Render ``scene`` (a reference name or a scene.xml path) with our path tracer and
    compare it with Mitsuba's reference.

    The cached reference (``<scene folder>/ref``) is used when ``params`` is empty; a
    missing one is built first (``notice(message)`` says so); a stale or corrupt one is an
    error. With ``params`` (XML ``$`` overrides, e.g. ``{"max_depth": 2}``) the reference
    is rendered on the fly with the same overrides (16 passes × 64 spp). ``pdf_scale`` is
    the tracer's wrong-pdf hook (1: correct); ``plant`` plants a bug in our scene
    (``PreparedScene.planted`` keywords, e.g. ``{"light_scale": 1.02}``)."""
    from estimators.pathtracer import SceneError, prepare_scene, render

    from .. import reference as R

    if passes < 2 or spp < MIN_SPP_PER_PASS * passes:
        raise InvalidArgument(f"spp={spp}, passes={passes}: need passes >= 2 and at least "
                              f"{MIN_SPP_PER_PASS} samples per pass (pass means of fewer "
                              "samples are too skewed on caustic pixels for the t-test)")
    name, path = R.resolve_scene(scene)
    t0 = time.perf_counter()
    if params:
        ref, _ = R.render_reference(path, params=params, seed=seed + 1)
    else:
        try:
            ref = R.load_reference(path)
        except MissingReference:
            if not build_missing:
                raise
            if notice:
                notice(f"{name}: no reference yet; building it with Mitsuba (once)")
            R.build_reference(path)
            ref = R.load_reference(path)
    ref_seconds = time.perf_counter() - t0
    try:
        subject = prepare_scene(path, params=params)
    except SceneError as e:
        raise InvalidArgument(str(e)) from None
    if plant:
        subject = subject.planted(**plant)
    ours = render(subject, spp=spp, passes=passes, seed=seed, pdf_scale=pdf_scale,
                  progress=progress)
    if ours.mean.shape != ref.mean.shape:
        raise InvalidArgument(f"{path}: our image is {ours.mean.shape}, the reference "
                              f"{ref.mean.shape}; rebuild the reference")
    label = name + "".join(f",{k}={v}" for k, v in sorted({**(params or {}), **(plant or {}),
                                                           **({"pdf_scale": pdf_scale}
                                                              if pdf_scale != 1 else {})
                                                           }.items()))
    result = compare_images(ours.mean, ref.mean, test_var=ours.variance, ref_var=ref.var,
                            test_n=ours.n, ref_n=ref.n, alpha=alpha, name=f"render:{label}")
    details = dict(result.details, scene=path, ours_spp=spp, ours_passes=passes,
                   ours_seconds=ours.seconds, ours_kernel=ours.stats.get("kernel"),
                   ours_samples_per_second=ours.stats.get("samples_per_second"),
                   compile_seconds=ours.stats.get("compile_seconds"),
                   reference=ref.manifest, reference_seconds=ref_seconds,
                   images={"ours": ours.mean, "mitsuba": ref.mean})
    return dataclasses.replace(result, details=details,
                               seconds=result.seconds + ours.seconds + ref_seconds,
                               n_samples=spp * ours.mean.shape[0] * ours.mean.shape[1])


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
