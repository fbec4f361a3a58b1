"""Regenerate ``materials.json``: the RGB complex indices of refraction of Mitsuba's named
conductors, as Mitsuba's RGB variants use them (its spectral tables reduced to linear
sRGB), so that ``<string name="material" value="Au"/>`` means the same in both renderers.

This is data, not code shared with Mitsuba: the path tracer reads the JSON and never
imports Mitsuba. Run ``python -m estimators.pathtracer.make_materials`` after a Mitsuba
upgrade; the committed file records the version it came from.
"""

from __future__ import annotations

import json
import os

def conductor_names(mi) -> list[str]:
    """Every conductor Mitsuba ships (a ``NAME.eta.spd`` and ``NAME.k.spd`` pair in its
    ``data/ior`` folder; 71 in 3.9.1, the ``_palik`` variants included), and ``none``."""
    folder = os.path.join(os.path.dirname(mi.__file__), "data", "ior")
    names = {f[:-len(".eta.spd")] for f in os.listdir(folder) if f.endswith(".eta.spd")}
    return sorted(n for n in names if os.path.isfile(os.path.join(folder, f"{n}.k.spd"))) \
        + ["none"]

# Named dielectric indices (Mitsuba's table, the values of its documentation).
DIELECTRICS = {
    "vacuum": 1.0, "helium": 1.000036, "hydrogen": 1.000132, "air": 1.000277,
    "carbon dioxide": 1.00045, "water": 1.3330, "acetone": 1.36, "ethanol": 1.361,
    "carbon tetrachloride": 1.461, "glycerol": 1.4729, "benzene": 1.501,
    "silicone oil": 1.52045, "bromine": 1.661, "water ice": 1.31, "fused quartz": 1.458,
    "pyrex": 1.470, "acrylic glass": 1.49, "polypropylene": 1.49, "bk7": 1.5046,
    "sodium chloride": 1.544, "amber": 1.55, "pet": 1.5750, "diamond": 2.419,
}


def _rgb(value) -> list[float]:
    try:
        return [float(value[i]) for i in range(3)]
    except TypeError:                     # a single float for all three channels
        return [float(value)] * 3


def main() -> None:
    from .textures import import_mitsuba
    mi = import_mitsuba("scalar_rgb")
    mi.set_log_level(mi.LogLevel.Error)
    conductors = {}
    for name in conductor_names(mi):
        params = mi.traverse(mi.load_dict({"type": "conductor", "material": name}))
        conductors[name] = {k: _rgb(params[f"{k}.value"]) for k in ("eta", "k")}
    out = {"source": f"mitsuba {mi.__version__} scalar_rgb", "conductors": conductors,
           "dielectrics": DIELECTRICS}
    path = os.path.join(os.path.dirname(__file__), "materials.json")
    with open(path, "w", encoding="utf-8") as f:
        json.dump(out, f, indent=1)
    print(f"wrote {path} ({len(conductors)} conductors)")


if __name__ == "__main__":
    main()
