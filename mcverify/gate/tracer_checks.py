"""χ² checks of the path tracer's own BSDF and emitter instances, as a scene uses them.

For a scene, every BSDF row of the prepared scene that has a density (not a smooth
conductor or dielectric, nor a thin dielectric) is checked at incident angles ``ANGLES``
(and from below for two-sided BSDFs, whose back side mirrors the front, and for rough
dielectrics and the blends and masks that hold them); a ``blendbsdf`` or ``mask`` is
checked as a whole (the mixture; the mask's null part is a rejected draw) and each BSDF
nested in it as its own row; and every emitter with a density
(area lights, constant and envmap environments; not point, spot or directional lights)
from ``reference_points``: the camera's position, the centre of the scene's bounds and
the point half way between (a mesh light whose vertex normals lean off its faces with
its face normals: ``_face_normals``; a point on the light's own surface is skipped for
it: ``_on_light``), and, where none of those sees the light's emitting side, a point in
front of it (``_front_point``). The subject is ``estimators.pathtracer.sampling`` (the
tracer's own kernels, with the parameters the scene gives: α (or α_u, α_v), η,
distribution, weights, coat tables, blend weights and opacities). Draws can be rejected (zero pdf, a delta lobe, a light's back side), so the
judge runs with ``rejection=True``: the pdf integrates to the acceptance probability.

Each check ``verifies`` ``("bsdf", label)`` or ``("emitter", label)``, the label naming
the instance (``rough-conductors/bsdf2:roughconductor(ggx,alpha=0.01)``).

``consistency_checks`` adds, per instance, ``mcverify.check_pdf_consistency`` of what the
kernel's draw returns (its pdf, and weight or radiance) against what the other strategy
reads at the drawn direction (``bsdf_eval``; the light's density and radiance where a ray
along it meets the light): ``pdf_consistency:tracer.bsdf:…`` and ``…emitter:…``.
"""

from __future__ import annotations

import numpy as np

from .. import checks
from .reference import scene_name
from .suites import Check

__all__ = ["ANGLES", "TRACER_SAMPLES", "CONSISTENCY_SAMPLES", "tracer_checks",
           "consistency_checks", "scene_instances"]

#: Incident polar angles (degrees) of every BSDF instance; two-sided ones also at 180° - θ.
ANGLES = (0.0, 45.0, 80.0)
#: Samples per check in a scene's plan: 1e6, a few seconds per instance.
TRACER_SAMPLES = 1_000_000
#: Draws per consistency check (exact row by row, not statistical): 1e5, milliseconds.
CONSISTENCY_SAMPLES = 100_000


#: Azimuth (degrees) of the incident direction for anisotropic BSDFs, off both axes of
#: the roughness so that neither alpha_u nor alpha_v alone decides the lobe.
ANISOTROPIC_PHI = 30.0


def _direction(theta_deg: float, phi_deg: float = 0.0) -> tuple[float, float, float]:
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return (float(np.sin(t) * np.cos(p)), float(np.sin(t) * np.sin(p)), float(np.cos(t)))


def _bsdf_label(scene, tag: str, b: int) -> str:
    from estimators.pathtracer import layout

    a = scene.arrays
    f, i = a.bsdf_f[b], a.bsdf_i[b]
    parts = []
    if int(i[layout.BSDF_KIND]) == layout.NORMALMAP:
        parts.append(f"bsdf{i[layout.BSDF_CHILD0]}")
    elif int(i[layout.BSDF_KIND]) in layout.COMPOSITE:
        name = "weight" if i[layout.BSDF_KIND] == layout.BLEND else "opacity"
        parts.append(f"{name}=texture" if a.bsdf_tex[b, 0] >= 0 else
                     f"{name}={f[layout.MIX]:g}")
        children = (layout.BSDF_CHILD0, layout.BSDF_CHILD1)[:2 if name == "weight" else 1]
        parts.append("+".join(f"bsdf{i[c]}" for c in children))
    elif f[layout.ALPHA] > 0:
        parts.append(("ggx", "beckmann")[int(i[layout.BSDF_DISTRIBUTION])])
        if f[layout.ALPHA_V] != f[layout.ALPHA]:
            parts.append(f"alpha_u={f[layout.ALPHA]:g},alpha_v={f[layout.ALPHA_V]:g}")
        else:
            parts.append(f"alpha={f[layout.ALPHA]:g}")
    if f[layout.ETA] > 0:
        parts.append(f"eta={_eta(float(f[layout.ETA]))}")
    params = f"({','.join(parts)})" if parts else ""
    return f"{tag}/bsdf{b}:{scene.bsdf_names[b]}{params}"


def _eta(eta: float) -> str:
    """η to 4 significant digits, or as many more as it takes not to print an η other than
    1 as 1: a rough dielectric at η = 1.0001 (int_ior 1.0001, ext_ior 1), a known limit of
    the χ² binning, was labelled ``eta=1``, a value Mitsuba refuses."""
    for digits in range(4, 18):
        text = f"{eta:.{digits}g}"
        if text != "1" or eta == 1.0:
            return text
    return repr(eta)


def _emitter_label(scene, tag: str, k: int) -> str:
    from estimators.pathtracer import layout

    a = scene.arrays
    kind = int(a.light_i[k, layout.LIGHT_KIND])
    name = layout.LIGHT_NAMES[kind]
    if kind == layout.AREA:
        prim = int(a.prim_info[a.light_i[k, layout.LIGHT_PRIM], layout.PRIM_KIND])
        name += ":" + ("triangles", "sphere", "disk")[prim]
    return f"{tag}/light{k}:{name}"


def reference_points(scene) -> list[tuple[float, float, float]]:
    """The camera's position, the centre of the scene's bounds, and half way between."""
    from estimators.pathtracer.geometry import bvh_bounds

    cam = np.asarray(scene.camera.to_world, dtype=np.float64)[:3, 3]
    lo, hi = bvh_bounds(scene.arrays.bvh_nodes)
    centre = 0.5 * (lo + hi)
    return [tuple(float(c) for c in p) for p in (cam, centre, 0.5 * (cam + centre))]


def _both_sides(bi, b: int) -> bool:
    """Whether BSDF row ``b`` scatters light arriving from below: two-sided, a rough
    dielectric, or a blend or mask holding one of those."""
    from estimators.pathtracer import layout

    kind = int(bi[b, layout.BSDF_KIND])
    if kind == layout.NORMALMAP:
        return bool(bi[b, layout.BSDF_TWOSIDED]) or _both_sides(bi, int(bi[b, layout.BSDF_CHILD0]))
    if kind in layout.COMPOSITE:
        children = (layout.BSDF_CHILD0, layout.BSDF_CHILD1)[:2 if kind == layout.BLEND else 1]
        return any(_both_sides(bi, int(bi[b, c])) for c in children)
    return bool(bi[b, layout.BSDF_TWOSIDED]) or kind == layout.ROUGHDIELECTRIC


def _light_triangles(a, k: int):
    """(rows, vertices (t, 3, 3), cross products (t, 3), their lengths) of the triangles
    of area light ``k`` in the prepared arrays ``a``: twice its triangles' areas and
    their unnormalised face normals, which ``_face_normals``, ``_on_light`` and
    ``_light_parts`` all read."""
    from estimators.pathtracer import layout

    first = int(a.light_i[k, layout.LIGHT_PRIM])
    rows = np.arange(first, first + int(a.light_i[k, layout.LIGHT_PRIM_COUNT]))
    v = a.prims[rows, :9].reshape(-1, 3, 3)
    g = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    return rows, v, g, np.linalg.norm(g, axis=1)


def _face_normals(scene, k: int):
    """``scene``, or a copy whose area light ``k`` has its triangles' vertex normals
    dropped where they are not all along the face normals. A mesh light's samples carry
    the interpolated normal, and its pdf takes the cosine there, as Mitsuba's
    ``Mesh::sample_position`` does: where that normal leans off the face's, the pdf is not
    the density of the sampled directions (which is the face's cosine over the squared
    distance), and the χ² check would fail a tracer that renders as Mitsuba. With face
    normals the check still covers the choice of triangle, the triangle warp and the
    change to solid angle. Each face normal faces the side its vertex normals give (their
    sum's): a mesh wound against its normals (mirrored in ``to_world``, or exported so)
    emits along them, and with the winding's normal instead a point lit by the light saw
    its back, every draw rejected, a check that could not fail (an outside review)."""
    import dataclasses

    from estimators.pathtracer import layout

    a = scene.arrays
    first = int(a.light_i[k, layout.LIGHT_PRIM])
    if a.prim_info[first, layout.PRIM_KIND] != layout.TRIANGLE:
        return scene
    rows, _, g, length = _light_triangles(a, k)
    g /= np.maximum(length, 1e-300)[:, None]
    n = a.prims[rows, 9:18].reshape(-1, 3, 3)
    along = np.abs(np.einsum("tvc,tc->tv", n, g)) >= (1.0 - 1e-9) * np.linalg.norm(n, axis=2)
    if np.all(along | ~np.any(n != 0.0, axis=2)):
        return scene
    side = np.where(np.einsum("tc,tc->t", n.sum(axis=1), g) < 0.0, -1.0, 1.0)
    prims = a.prims.copy()
    prims[rows, 9:18] = np.tile(side[:, None] * g, 3)
    return dataclasses.replace(scene, arrays=a._replace(prims=prims))


#: A reference point within this fraction of the scene's size of an area light's surface
#: (a sphere's, or the plane of a disk or of any of a mesh's triangles) is not used for
#: that light: it sees the light, or that part of it, edge-on, where the cosine at the
#: light is rounding noise (draws accepted or rejected by its sign) and the pdf's rays
#: run along the surface without meeting it.
ON_LIGHT_TOLERANCE = 1e-10


def _on_light(scene, k: int, p) -> bool:
    """Whether the world point ``p`` lies on area light ``k``'s surface (a sphere) or in
    the plane of one of its planar primitives (a disk, a triangle), within
    ``ON_LIGHT_TOLERANCE`` of the scene's size."""
    from estimators.pathtracer import layout
    from estimators.pathtracer.geometry import bvh_bounds

    a = scene.arrays
    lo, hi = bvh_bounds(a.bvh_nodes)
    tol = ON_LIGHT_TOLERANCE * max(float(np.linalg.norm(hi - lo)), 1e-300)
    p = np.asarray(p, dtype=np.float64)
    first = int(a.light_i[k, layout.LIGHT_PRIM])
    kind = int(a.prim_info[first, layout.PRIM_KIND])
    if kind == layout.SPHERE:
        row = a.prims[first]
        c = row[layout.SPHERE_CENTER:layout.SPHERE_CENTER + 3]
        return abs(float(np.linalg.norm(p - c)) - float(row[layout.SPHERE_RADIUS])) <= tol
    if kind == layout.DISK:
        m = a.prims[first, layout.DISK_TO_LOCAL:layout.DISK_TO_LOCAL + 12].reshape(3, 4)
        # local z is the plane's signed distance over the length of the matrix's z row
        return abs(float(m[2, :3] @ p + m[2, 3])) <= tol * float(np.linalg.norm(m[2, :3]))
    _, v, g, length = _light_triangles(a, k)
    g, v = g[length > 0.0] / length[length > 0.0, None], v[length > 0.0]
    return bool(np.any(np.abs(np.einsum("tc,tc->t", p - v[:, 0], g)) <= tol))


def _light_parts(scene, k: int):
    """(candidates, centres) of area light ``k``: ``centres`` of its primitives in world
    space (a triangle's centroid, a disk's or sphere's centre), and ``candidates``, two
    points by its largest primitive at a distance of half the scene's size, one on each
    side (along a triangle's or disk's normal; for a sphere, outside it and its centre,
    where a flipped sphere emits; for a sphere ``centres`` holds the top of its surface
    too, so that its centre is tried along a direction that has a length: until 7
    December it was tried towards itself alone, and a sphere light shining on its inside
    away from the three reference points got no fourth, its checks testing nothing)."""
    from estimators.pathtracer import layout
    from estimators.pathtracer.geometry import bvh_bounds

    a = scene.arrays
    lo, hi = bvh_bounds(a.bvh_nodes)
    step = 0.5 * float(np.linalg.norm(hi - lo))
    first = int(a.light_i[k, layout.LIGHT_PRIM])
    kind = int(a.prim_info[first, layout.PRIM_KIND])
    if kind == layout.SPHERE:
        row = a.prims[first]
        c = row[layout.SPHERE_CENTER:layout.SPHERE_CENTER + 3]
        r = float(row[layout.SPHERE_RADIUS])
        out = c + np.array([0.0, 0.0, r + step])
        return [out, c], np.array([c, c + np.array([0.0, 0.0, r])])
    if kind == layout.DISK:
        c = a.prims[first, layout.DISK_TO_WORLD:layout.DISK_TO_WORLD + 12].reshape(3, 4)[:, 3]
        m = a.prims[first, layout.DISK_TO_LOCAL:layout.DISK_TO_LOCAL + 12].reshape(3, 4)
        n = m[2, :3] / np.linalg.norm(m[2, :3])
        return [c + step * n, c - step * n], c[None]
    _, v, g, length = _light_triangles(a, k)
    if not np.any(length > 0.0):
        return [], v.mean(axis=1)
    i = int(np.argmax(length))
    centres, n = v.mean(axis=1), g[i] / length[i]
    # the face the largest triangle lies in (a rectangle's two halves): its centre
    face = (g @ n >= (1.0 - 1e-9) * length) & (np.abs((centres - centres[i]) @ n) <= 1e-9 * step)
    c = (length[face, None] * centres[face]).sum(axis=0) / length[face].sum()
    return [c + step * n, c - step * n], centres


def _sees_front(scene, k: int, p, centres) -> bool:
    """Whether the light's pdf is positive from ``p`` along the direction to one of its
    primitives' ``centres``: ``p`` sees some of its emitting side."""
    from estimators.pathtracer.sampling import emitter_sampler

    d = centres - np.asarray(p, dtype=np.float64)
    length = np.linalg.norm(d, axis=1)
    d, length = d[length > 0.0], length[length > 0.0]
    if not len(d):
        return False
    with np.errstate(invalid="ignore"):
        return bool(np.any(emitter_sampler(scene, k, p)[1](d / length[:, None]) > 0.0))


def _front_point(scene, k: int, refs):
    """A point in front of area light ``k`` where none of ``refs`` sees its emitting side
    (a light aimed at a wall or ceiling, away from the camera and the scene's centre),
    else None: the first of ``_light_parts``' candidates from which the light's pdf is
    positive. Without it such a light's checks tested nothing: from behind every draw is
    rejected and the pdf integrates to 0, which a sampler that never draws passes too."""
    candidates, centres = _light_parts(scene, k)
    if any(_sees_front(scene, k, p, centres) for p in refs):
        return None
    for p in candidates:
        if _sees_front(scene, k, p, centres):
            # rounding noise of the transforms (a disk's centre at z = 2.8e-16) is 0
            scale = float(np.abs(p).max())
            return tuple(float(c) if abs(c) > 1e-12 * scale else 0.0 for c in p)
    return None


def _declared(scene, kind: str, index: int) -> str:
    """Where the scene file declares BSDF row or light ``index``: a message for its
    checks, so that a failure points at the element (``FILE:LINE: <bsdf type="...">``)."""
    lines = scene.bsdf_lines if kind == "bsdf" else scene.light_lines
    line = lines[index] if index < len(lines) else ""
    if not line:
        return ("declared nowhere: Mitsuba's default diffuse of a shape without a <bsdf>"
                if kind == "bsdf" else "declared nowhere in the scene file")
    what = (scene.bsdf_names[index] if kind == "bsdf" else
            _emitter_label(scene, "", index).split(":", 1)[1].split(":")[0])
    what = what.removeprefix("twosided(").removesuffix(")")
    tag = kind if kind == "bsdf" else "emitter"
    return f"declared at {line}: <{tag} type=\"{what}\">"


def _fmt(p) -> str:
    return "(" + ",".join(f"{c:.3g}" for c in p) + ")"


def scene_instances(scene_path: str):
    """(entries, skipped): entries are (kind, label, where, make, make_weighted,
    declared) with
    ``make()`` returning the (sample, pdf) pair and ``make_weighted()`` the (sample, pdf,
    f) of ``sampling.bsdf_sampler_with_weight`` or ``emitter_sampler_with_weight`` (an
    emitter's with the scene's own normals: the consistency check compares a drawn
    point's density with the density at that same point) and ``declared`` the element's
    place in the scene file (``_declared``); skipped are (label, why) for
    delta instances and for reference points on a light's own surface (``_on_light``)."""
    from estimators.pathtracer import layout, prepare_scene
    from estimators.pathtracer.sampling import (bsdf_has_density, bsdf_sampler,
                                                bsdf_sampler_with_weight, emitter_has_density,
                                                emitter_sampler, emitter_sampler_with_weight)

    scene = prepare_scene(scene_path)
    tag = scene_name(scene_path)
    entries, skipped = [], []
    for b in range(len(scene.arrays.bsdf_i)):
        label = _bsdf_label(scene, tag, b)
        if not bsdf_has_density(scene, b):
            skipped.append((f"bsdf {label}", "a delta BSDF (smooth), nothing to sample"))
            continue
        angles = list(ANGLES)
        if _both_sides(scene.arrays.bsdf_i, b):
            angles += [180.0 - t for t in ANGLES]
        phi = ANISOTROPIC_PHI if scene.arrays.bsdf_i[b, layout.BSDF_FRAME] else 0.0
        where = "" if phi == 0.0 else f",phi={phi:g}°"
        # phi bound with b and t: read when the check ran, it was the last row's, and an
        # anisotropic BSDF before an isotropic one was checked at φ = 0 (an outside review)
        for t in angles:
            entries.append(("bsdf", label, f"wi={t:g}°{where}",
                            lambda b=b, t=t, phi=phi: bsdf_sampler(scene, b,
                                                                   _direction(t, phi)),
                            lambda b=b, t=t, phi=phi: bsdf_sampler_with_weight(
                                scene, b, _direction(t, phi)),
                            _declared(scene, "bsdf", b)))
    for k in range(len(scene.arrays.light_i)):
        label = _emitter_label(scene, tag, k)
        if not emitter_has_density(scene, k):
            skipped.append((f"emitter {label}", "a delta emitter, nothing to sample"))
            continue
        area = scene.arrays.light_i[k, layout.LIGHT_KIND] == layout.AREA
        refs = reference_points(scene) if area else reference_points(scene)[:1]
        light_scene = _face_normals(scene, k) if area else scene
        if light_scene is not scene:
            label += "(face normals)"
        # points that coincide (the camera at the bounds' centre) or print alike: one
        # check each, under a name of its own
        front = _front_point(scene, k, refs) if area else None
        unique: dict[str, tuple] = {}
        for p in refs + ([front] if front is not None else []):
            unique.setdefault(_fmt(p), p)
        for where, p in unique.items():
            if area and _on_light(scene, k, p):
                skipped.append((f"emitter {label}@ref={where}",
                                "the reference point lies on the light's own surface (or "
                                "in the plane of one of its faces), which it sees edge-on: "
                                "the cosine there is rounding noise"))
                continue
            entries.append(("emitter", label, f"ref={where}",
                            lambda k=k, p=p, s=light_scene: emitter_sampler(s, k, p),
                            lambda k=k, p=p: emitter_sampler_with_weight(scene, k, p),
                            _declared(scene, "emitter", k)))
    return entries, skipped


def tracer_checks(scene_path: str, n_samples: int = TRACER_SAMPLES
                  ) -> tuple[list[Check], list[tuple[str, str]]]:
    """The χ² checks of the scene's BSDF and emitter instances, and the skipped ones
    (delta instances) with the reason. Each check rebuilds in a worker from its source."""
    entries, skipped = scene_instances(scene_path)
    out = []
    for kind, label, where, make, _, declared in entries:
        name = f"sampler:tracer.{kind}:{label}@{where}"

        def run(seed, make=make, name=name, declared=declared):
            sample, pdf = make()
            return _with_declared(checks.check_sampler(
                sample, pdf, "sphere", n_samples=n_samples, seed=seed, rejection=True,
                sample_dim=3, name=name), declared)

        out.append(Check(name, run, ("tracer", kind), frozenset({(kind, label)}),
                         source=(_rebuild, (scene_path, n_samples))))
    return out, skipped


def _with_declared(result, declared: str):
    """``result`` with where the scene file declares its instance as its first message."""
    import dataclasses

    return dataclasses.replace(result, messages=(declared,) + tuple(result.messages))


def _rebuild(scene_path: str, n_samples: int) -> list[Check]:
    return tracer_checks(scene_path, n_samples)[0]


def consistency_checks(scene_path: str, n_samples: int = CONSISTENCY_SAMPLES) -> list[Check]:
    """Each BSDF and emitter instance's draws, at the χ² checks' incident directions and
    reference points, held to what the other strategy reads
    (``mcverify.check_pdf_consistency``; row by row, float64, rtol 1e-6): the pdf
    ``bsdf_sample`` returns with a direction (the path's throughput and its MIS weight
    divide by it) must be the pdf ``bsdf_eval`` gives that direction (what light
    sampling's MIS weight reads), and its weight ``f · cos / pdf``; the pdf
    ``sample_emitter`` returns must be the light's density where a BSDF-sampled ray
    meets the same point, and its radiance the radiance there."""
    out = []
    for kind, label, where, _, make_weighted, declared in scene_instances(scene_path)[0]:
        label = label.removesuffix("(face normals)")
        name = f"pdf_consistency:tracer.{kind}:{label}@{where}"

        def run(seed, make=make_weighted, name=name, declared=declared):
            sample, pdf, f = make()
            return _with_declared(checks.check_pdf_consistency(
                sample, pdf, f=f, sample_dim=3, n_samples=n_samples, rejection=True,
                seed=seed, name=name), declared)

        out.append(Check(name, run, ("tracer", "pdf_consistency"),
                         frozenset({("pdf_consistency", label)}),
                         source=(consistency_checks, (scene_path, n_samples))))
    return out
