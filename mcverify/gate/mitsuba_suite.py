"""``mcverify check --suite mitsuba``: Mitsuba's own plugins over parameter sweeps.

Each entry of :func:`sweep` names a plugin configuration and how to build its adapter
(:mod:`mcverify.gate.mitsuba`); the checks run at the gate's family-wise α like any
other suite. Microfacet distributions sweep α from 0.01 to 1, isotropic and
anisotropic, with and without visible normals, at incident angles 0°, 45° and 80°;
phase functions and emitters cover Mitsuba's samplable ones; BSDFs at several incident
angles, from both sides of a dielectric. Rough BSDFs reject draws (zero weight below the
horizon; smooth plastic's delta lobe comes back as a rejected row too): they are judged
with ``check_sampler(rejection=True)``, their pdf integrating to the acceptance.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from .. import checks
from .suites import Check

__all__ = ["Entry", "direction", "mitsuba_suite", "sweep"]

def direction(theta_deg: float, phi_deg: float = 0.0) -> tuple[float, float, float]:
    """The unit vector at polar angle ``theta_deg`` and azimuth ``phi_deg`` (degrees)."""
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return (float(np.sin(t) * np.cos(p)), float(np.sin(t) * np.sin(p)), float(np.cos(t)))


@dataclass(frozen=True)
class Entry:
    """One plugin configuration: ``make()`` builds its adapter (Mitsuba loads then)."""

    kind: str            # "microfacet", "phase", "emitter", "bsdf"
    label: str           # plugin and parameters, as the check's name shows them
    make: Callable
    rejects: bool = False   # draws may be rejected: check_sampler(rejection=True)


_ANGLES = (0.0, 45.0, 80.0)
_ALPHAS = (0.01, 0.1, 0.5, 1.0)


def _microfacets(mvm) -> list[Entry]:
    out = []
    for dist in ("ggx", "beckmann"):
        for alpha in _ALPHAS + ((0.05, 0.5),):
            a = f"{alpha:g}" if np.ndim(alpha) == 0 else f"{alpha[0]:g},{alpha[1]:g}"
            out.append(Entry("microfacet", f"{dist}(alpha={a})",
                             lambda d=dist, al=alpha: mvm.microfacet(d, al,
                                                                     sample_visible=False)))
            angles = _ANGLES if np.ndim(alpha) == 0 else ((60.0, 30.0),)
            for ang in angles:
                wi = direction(*np.atleast_1d(ang))
                deg = "°,".join(f"{v:g}" for v in np.atleast_1d(ang)) + "°"
                out.append(Entry("microfacet", f"{dist}(alpha={a},visible)@wi={deg}",
                                 lambda d=dist, al=alpha, w=wi: mvm.microfacet(d, al, wi=w)))
    return out


def _phases(mvm) -> list[Entry]:
    wi = direction(45.0, 20.0)
    out = [Entry("phase", "isotropic", lambda: mvm.phase({"type": "isotropic"}, wi)),
           Entry("phase", "rayleigh@wi=45°", lambda: mvm.phase({"type": "rayleigh"}, wi))]
    for g in (-0.7, 0.3, 0.9):
        out.append(Entry("phase", f"hg(g={g:g})@wi=45°",
                         lambda g=g: mvm.phase({"type": "hg", "g": g}, wi)))
    return out


def _envmap_image() -> np.ndarray:
    """A fixed, steep 16 × 32 RGB environment (seeded): bright spots and dark pixels."""
    img = np.random.default_rng(2024).random((16, 32, 3)) ** 4 * 10.0 + 0.01
    img[3:5, 7:9] = 0.0
    return img


def _emitters(mvm) -> list[Entry]:
    disk = ('<shape version="3.0.0" type="disk"><transform name="to_world">'
            '<rotate x="1" angle="30"/><translate z="1"/></transform>'
            '<emitter type="area"/></shape>')
    return [
        Entry("emitter", "constant", lambda: mvm.emitter({"type": "constant"})),
        Entry("emitter", "envmap(16x32)",
              lambda: mvm.emitter({"type": "envmap", "bitmap": _envmap_image()})),
        Entry("emitter", "area:rectangle@ref=(0.3,-0.2,1.5)",
              lambda: mvm.emitter({"type": "rectangle", "emitter": {"type": "area"}},
                                  ref=(0.3, -0.2, 1.5))),
        Entry("emitter", "area:disk(tilted)@ref=(0.4,0.1,3)",
              lambda: mvm.emitter(disk, ref=(0.4, 0.1, 3.0))),
        Entry("emitter", "area:sphere(r=1,c=(0,0.5,3))@ref=(0,0,0)",
              lambda: mvm.emitter({"type": "sphere", "center": [0.0, 0.5, 3.0], "radius": 1.0,
                                   "emitter": {"type": "area"}})),
    ]


def _bsdfs(mvm) -> list[Entry]:
    out = [Entry("bsdf", f"diffuse@wi={t:g}°",
                 lambda t=t: mvm.bsdf({"type": "diffuse"}, direction(t)))
           for t in (0.0, 70.0)]
    for name in ("plastic", "roughplastic"):   # component 1: the diffuse lobe alone
        out.append(Entry("bsdf", f"{name}(diffuse component)@wi=30°",
                         lambda n=name: mvm.bsdf({"type": n}, direction(30.0), component=1)))
    rough = []   # (label, plugin, incident angles): these reject draws
    for dist in ("ggx", "beckmann"):
        for alpha in _ALPHAS:
            rough.append((f"roughconductor({dist},alpha={alpha:g})",
                          {"type": "roughconductor", "distribution": dist, "alpha": alpha},
                          (45.0, 80.0)))
        rough.append((f"roughconductor({dist},alpha=0.05,0.5)",
                      {"type": "roughconductor", "distribution": dist, "alpha_u": 0.05,
                       "alpha_v": 0.5}, (45.0,)))
        for alpha in (0.1, 0.5):
            rough.append((f"roughdielectric({dist},alpha={alpha:g},eta=1.5)",
                          {"type": "roughdielectric", "distribution": dist, "alpha": alpha},
                          (45.0, 135.0)))                 # from outside and from inside
        for alpha in (0.1, 0.3):
            rough.append((f"roughplastic({dist},alpha={alpha:g})",
                          {"type": "roughplastic", "distribution": dist, "alpha": alpha},
                          (33.0,)))
    rough += [("roughconductor(beckmann,alpha=0.5,not visible)",
               {"type": "roughconductor", "alpha": 0.5, "sample_visible": False}, (45.0,)),
              ("principled", {"type": "principled"}, (45.0,)),
              ("plastic(delta lobe rejected)", {"type": "plastic"}, (30.0,))]
    for label, plugin, angles in rough:
        for t in angles:
            out.append(Entry("bsdf", f"{label}@wi={t:g}°",
                             lambda p=plugin, t=t: mvm.bsdf(p, direction(t)), rejects=True))
    return out


def sweep() -> list[Entry]:
    """Every configuration of the suite, in order (builds no plugin)."""
    from . import mitsuba as mvm

    return _microfacets(mvm) + _phases(mvm) + _emitters(mvm) + _bsdfs(mvm)


def mitsuba_suite(n_samples: int) -> list[Check]:
    """The suite's checks, each carrying the recipe that rebuilds it in a worker process.

    ``n_samples`` per check (a tenth on a scalar Mitsuba variant, one Python call per
    sample, as for the default suite's warps)."""
    from . import mitsuba as mvm

    scalar = mvm.choose_variant().variant.startswith("scalar")
    n = n_samples // 10 if scalar else n_samples
    out = []
    for e in sweep():
        name = f"sampler:mitsuba.{e.kind}:{e.label}"

        def run(seed, e=e, name=name):
            s, p, d, kw = e.make()
            return checks.check_sampler(s, p, d, n_samples=n, seed=seed,
                                        rejection=e.rejects, **dict(kw, name=name))

        plugin = e.label.split("(")[0].split("@")[0]
        out.append(Check(name, run, ("mitsuba", "mitsuba-plugin", e.kind),
                         frozenset({("sampler", f"mitsuba.{e.kind}:{plugin}")}),
                         source=(mitsuba_suite, (n_samples,))))
    return out
