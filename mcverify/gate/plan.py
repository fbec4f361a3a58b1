"""Plan the checks a scene needs: "skip what a scene doesn't need".

The scene's features (its BSDFs, emitters by the shape they sit on, textures and
integrator, as the path tracer's loader reports them) are looked up in ``NEEDS``, one
table of what each feature relies on, as ``(kind, subject)`` pairs that checks declare
in ``Check.verifies``. Delta features have nothing to sample and are listed in
``NOTHING_TO_SAMPLE`` with the reason. On top of these, the scene's own BSDF and emitter
instances, with their parameters, are χ²-checked (``tracer_checks``), and each BSDF
instance's returned pdf and weight are held to its evaluation (``consistency_checks``).
A path tracer of ``max_depth`` 0 or 1, or one of depth 2 under delta lights only, samples
nothing (``nothing_sampled``): all of these are then skipped with that reason, and the
scene's render check (and a user's own checks that name nothing they verify) run. A
path tracer whose ``max_depth`` is at most its ``rr_depth`` never plays Russian roulette
(``roulette_unused``): the roulette's estimator check is skipped with that reason.
"""

from __future__ import annotations

import dataclasses

from ..errors import EnvironmentProblem, InvalidArgument
from .suites import Check, resolve_suite
from .tracer_checks import consistency_checks, tracer_checks

__all__ = ["NEEDS", "NOTHING_TO_SAMPLE", "nothing_sampled", "plan", "roulette_unused"]


def _pairs(kind: str, *subjects: str) -> set[tuple[str, str]]:
    return {(kind, s) for s in subjects}


_MESH_LIGHT = (_pairs("sampler", "uniform_triangle") | _pairs("inverse", "uniform_triangle"),
               "mesh lights are sampled by area, triangle by triangle")

#: What each scene feature needs verified: feature -> ({(kind, subject)}, why).
NEEDS: dict[str, tuple[set[tuple[str, str]], str]] = {
    "bsdf:diffuse": (_pairs("sampler", "cosine_hemisphere") | _pairs("inverse", "cosine_hemisphere"),
                     "diffuse BSDF sampling draws cosine-weighted directions"),
    "bsdf:plastic": (_pairs("sampler", "cosine_hemisphere"), "plastic's diffuse lobe"),
    "bsdf:roughplastic": (_pairs("sampler", "cosine_hemisphere", "beckmann", "ggx", "ggx_vndf"),
                          "rough plastic: diffuse + microfacet lobes"),
    "bsdf:roughconductor": (_pairs("sampler", "beckmann", "ggx", "ggx_vndf")
                            | _pairs("inverse", "beckmann", "ggx", "ggx_vndf"),
                            "rough conductor: microfacet normal sampling"),
    "bsdf:roughdielectric": (_pairs("sampler", "beckmann", "ggx", "ggx_vndf")
                             | _pairs("inverse", "beckmann", "ggx", "ggx_vndf"),
                             "rough dielectric: microfacet normal sampling, then reflection "
                             "or refraction"),
    "emitter:area:rectangle": _MESH_LIGHT,
    "emitter:area:cube": _MESH_LIGHT,
    "emitter:area:obj": _MESH_LIGHT,
    "emitter:area:ply": _MESH_LIGHT,
    "emitter:area:serialized": _MESH_LIGHT,
    "emitter:area:disk": (_pairs("sampler", "uniform_disk_concentric")
                          | _pairs("inverse", "uniform_disk_concentric"),
                          "disk lights are sampled by area"),
    "emitter:area:sphere": (_pairs("sampler", "uniform_cone", "uniform_sphere")
                            | _pairs("inverse", "uniform_cone", "uniform_sphere"),
                            "sphere lights: the cone they subtend, or area from inside"),
    "emitter:envmap": (_pairs("sampler", "piecewise_constant_2d")
                       | _pairs("inverse", "piecewise_constant_2d"),
                       "environment maps are sampled by a 2-D piecewise-constant pdf"),
    "emitter:constant": (_pairs("sampler", "uniform_sphere"),
                         "a constant environment is sampled uniformly over the sphere"),
    "integrator:path": (_pairs("unbiased", "russian_roulette", "mis"),
                        "path tracing uses Russian roulette and MIS"),
    "integrator:direct": (_pairs("unbiased", "mis"),
                          "direct illumination combines strategies by MIS"),
}

#: Features with nothing of their own to sample: feature -> why it is skipped.
NOTHING_TO_SAMPLE = {
    "bsdf:conductor": "smooth conductor: a delta BSDF, nothing to sample",
    "bsdf:dielectric": "smooth dielectric: a delta BSDF, nothing to sample",
    "emitter:point": "point light: a delta emitter, nothing to sample",
    "emitter:directional": "directional light: a delta emitter, nothing to sample",
    "emitter:spot": "spot light: a delta emitter, nothing to sample",
    "bsdf:twosided": "two-sided adapter: nothing of its own to sample",
    "bsdf:thindielectric": "thin dielectric: delta reflection and a null transmission, "
                           "nothing to sample",
    "bsdf:blendbsdf": "blend: a mixture of its two BSDFs, nothing of its own (its "
                      "instances are χ²-checked)",
    "bsdf:mask": "mask: a null component and its BSDF, nothing of its own (its instances "
                 "are χ²-checked)",
    "bsdf:normalmap": "normal map: turns its BSDF's shading frame, nothing of its own to "
                      "sample (its instances are χ²-checked)",
    "texture:bitmap": "bitmap texture: a look-up, nothing to sample",
    "texture:checkerboard": "checkerboard texture: a look-up, nothing to sample",
}
#: Features that need nothing verified and are not listed: the shapes themselves (their
#: lights are, as emitter:area:SHAPE), and "emitter:area" itself (its shape's entry
#: decides). Exact names and prefixes, kept apart: a prefix "emitter:area" would also
#: cover the emitter:area:SHAPE entries the planner must have.
UNLISTED_PREFIXES = ("shape:",)
UNLISTED_NAMES = ("emitter:area",)


def plan(scene_path: str, suite: str = "default", checks: list[Check] | None = None
         ) -> tuple[list[Check], list[tuple[str, str]], set[str]]:
    """The checks a scene needs, and the skipped ones with the reason.

    Reads the scene with the path tracer's loader (an unsupported element raises
    ``SceneError`` naming it), keeps the suite's checks whose ``verifies`` meets what the
    scene's features need (``NEEDS``), and adds the scene's render check. ``checks``:
    the suite's checks already resolved (``mcverify check``: those of a project's table,
    possibly several suites), instead of resolving ``suite``. Returns
    (checks, skipped, features).
    """
    from estimators.pathtracer import load_scene

    desc = load_scene(scene_path)
    all_checks = resolve_suite(suite)[0] if checks is None else checks
    unsampled = nothing_sampled(desc)
    no_roulette = roulette_unused(desc)
    wanted: dict[str, str] = {}
    unused: dict[str, str] = {}
    for feature in sorted(desc.features):
        needs, why = NEEDS.get(feature, (set(), ""))
        for c in all_checks:
            hit = c.verifies & needs
            if hit and no_roulette and hit <= ROULETTE:
                unused.setdefault(c.name, no_roulette)
            elif hit:
                wanted.setdefault(c.name, f"{feature}: {why}")
    # a check that names nothing it verifies (the user's own, Check's default) runs with
    # any scene: it was skipped as "not needed", and a project's gate ran none of its own
    keep = [c for c in all_checks if (c.name in wanted and not unsampled) or not c.verifies]
    skipped = [(c.name, unsampled if c.name in wanted else
                unused.get(c.name, "not needed by this scene"))
               for c in all_checks if c.verifies and (unsampled or c.name not in wanted)]
    skipped += [(f, why) for f, why in NOTHING_TO_SAMPLE.items() if f in desc.features]
    # prepared whatever the depth: a scene the tracer cannot render is refused here
    instances, delta = tracer_checks(scene_path)
    instances += consistency_checks(scene_path)
    render = _render_check(scene_path)
    _names_apart(all_checks, instances + [render])
    if unsampled:
        skipped += [(c.name, unsampled) for c in instances]
    else:
        keep += instances
    skipped += delta
    keep.append(render)
    return keep, skipped, desc.features


def _names_apart(suite_checks: list[Check], own: list[Check]) -> None:
    """A suite's check named as one the plan adds (a project's own render check named
    ``render:SCENE``) ran beside it: two results of one name and one seed (seeds derive
    from names), two JUnit testcases alike."""
    ours = {c.name for c in own}
    for c in suite_checks:
        if c.name in ours:
            raise InvalidArgument(f"check {c.name!r}: a check of the suite has the name of "
                                  "one of the scene's own checks (its render check, or an "
                                  "instance check the plan adds); rename it (seeds derive "
                                  "from names)")


def nothing_sampled(desc) -> str:
    """Why the scene's integrator samples no BSDF and no light, or "" where it does: a
    path tracer with ``max_depth`` 1 ends each camera ray where it first hits (it adds
    the emitter it sees there), and one with ``max_depth`` 0 renders black, as Mitsuba's
    ``path`` does (not where a mask or thin dielectric is in the scene: Mitsuba samples
    the last vertex's BSDF for its null component, and a masked emitter shows its
    radiance × opacity). At depth 2 (``direct``, or ``path`` with ``max_depth`` 2) under point,
    spot and directional lights only, each light is reached by its delta sample, and a
    BSDF-sampled ray finds nothing that emits (no area light, no environment; a null
    component, a mask's or a thin dielectric's, would carry it on). Its samplers,
    estimators and instances then decide nothing in the image (the render check still
    compares it); a failure of one failed such a scene's gate (until 7 December)."""
    integ = desc.integrator
    depth = 2 if integ.type == "direct" else int(integ.get("max_depth", -1))
    emitting = {"emitter:area", "emitter:constant", "emitter:envmap"}
    null = {"bsdf:mask", "bsdf:thindielectric"}
    if integ.type == "path" and depth == 0:
        return "path with max_depth 0: the image is black, nothing is sampled"
    if integ.type == "path" and depth == 1 and not desc.features & null:
        # with a null component the last vertex's BSDF is sampled still (Mitsuba's
        # valid_ray): a masked emitter shows radiance × opacity, which the mask's
        # instance check tests (skipped until a read-only review)
        return ("path with max_depth 1: camera rays end at their first hit (the emitters "
                "they see), no BSDF or light is sampled")
    if depth == 2 and not (desc.features & (emitting | null)):
        which = "direct" if integ.type == "direct" else "path with max_depth 2"
        return (f"{which} under point, spot and directional lights only: each light is "
                "reached by its delta sample, a BSDF-sampled ray finds nothing that emits, "
                "nothing is sampled")
    return ""


#: What only Russian roulette needs verified (``roulette_unused`` drops it).
ROULETTE = _pairs("unbiased", "russian_roulette")


def roulette_unused(desc) -> str:
    """Why the scene's path tracer never plays Russian roulette, or "" where it may: it
    plays from ``rr_depth`` bounces on (Mitsuba's default 5), and a path of ``max_depth``
    vertices ends after ``max_depth`` - 1 bounces, so with 0 <= max_depth <= rr_depth no
    path reaches it (the roulette's estimator check was planned for such a scene until
    7 December, an image it decides nothing in)."""
    integ = desc.integrator
    if integ.type != "path":
        return ""
    depth, rr_depth = int(integ.get("max_depth", -1)), int(integ.get("rr_depth", 5))
    if 0 <= depth <= rr_depth:
        return (f"path with max_depth {depth} <= rr_depth {rr_depth}: no path reaches "
                "Russian roulette")
    return ""


def _render_check(scene_path: str) -> Check:
    """The scene's render gate: our path tracer against its Mitsuba reference (built on
    first use); sequential, so the suite tells it where it may stop early."""
    from .reference import scene_name
    from .render_check import render_check

    name = f"render:{scene_name(scene_path)}"

    def run(seed, stop_alpha=None):
        try:
            r = render_check(scene_path, spp=_gate_spp(scene_path), seed=seed,
                             stop_alpha=stop_alpha)
        except InvalidArgument as e:
            # given nothing but the scene, render_check refuses the scene or its reference
            # (a reference and a render both black: nothing compared), which render-check
            # exits 2 for; this check failed, exit 1, as if our tracer were wrong, until 7
            # December (an outside review)
            raise EnvironmentProblem(str(e)) from None
        return dataclasses.replace(r, name=name)

    return Check(name, run, ("render", "mitsuba"), frozenset({("render", name)}),
                 source=(_render_check, (scene_path,)), sequential=True)


def _gate_spp(scene_path: str) -> int:
    """The samples in all of a scene's render check in ``check --scene``: the gate's
    ``GATE_SPP`` in ``GATE_PASSES`` passes (1024 in 16), except where the film's filter
    splats and the scene's reference has another count per pass (``reference build``'s
    default is 256, a reference built by ``render-check --spp 128 --passes 4`` has 32):
    such passes compare only at the reference's count, so that count times 16. Until 7
    December the check failed, exit 1, "raised InvalidArgument: ... our passes need the
    reference's 256 samples per pass: spp=4096 with passes=16", an option ``check`` does
    not have (an outside review). A reference of fewer than ``MIN_SPP_PER_PASS`` a pass
    cannot be gated so: ``EnvironmentProblem`` (exit 2) saying how to rebuild it."""
    from ..errors import MissingReference
    from . import reference
    from .render_check import GATE_PASSES, GATE_SPP, MIN_SPP_PER_PASS

    name, path = reference.resolve_scene(scene_path)
    try:
        ref = reference.load_reference(path)
    except MissingReference:        # render_check builds it at GATE_SPP // GATE_PASSES
        return GATE_SPP
    per_pass = ref.manifest.get("spp")     # absent from references of before spp
    if not ref.pixels_correlated or not isinstance(per_pass, int) \
            or per_pass * GATE_PASSES == GATE_SPP:
        return GATE_SPP
    if per_pass < MIN_SPP_PER_PASS:
        advice = reference.rebuild_advice(name, path, {
            **ref.manifest, "spp": 64, "passes": 64, "spp_requested": 64})
        raise EnvironmentProblem(f"{path}: its reference has {per_pass} samples per pass; "
                                 "the film's filter splats, so the render check's passes "
                                 "must have as many, and a pass needs at least "
                                 f"{MIN_SPP_PER_PASS}; {advice}")
    return per_pass * GATE_PASSES
