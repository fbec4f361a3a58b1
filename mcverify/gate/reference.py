"""Reference renders: Mitsuba's image of a scene as K independent passes, with per-pixel
variance across passes and a manifest, so a stale or corrupt reference is never used.

Layout: ``reference/scenes/<name>/scene.xml`` and, built from it,
``reference/scenes/<name>/ref/{mean.exr, var.exr, manifest.json}``. The manifest records
Mitsuba's version and variant, spp, passes, seeds, the scene's SHA-256 and UTC time.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from dataclasses import dataclass

import numpy as np

from ..errors import EnvironmentProblem, InvalidArgument, MissingReference
from ..provenance import provenance
from ..result import shared_mode

REFERENCE_ROOT = os.path.join(
    os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))),
    "reference", "scenes")


@dataclass(frozen=True)
class Reference:
    name: str
    mean: np.ndarray
    var: np.ndarray
    n: int
    manifest: dict

    def rmse(self, image) -> float:
        """RMSE of ``image`` against this reference's mean, with the reference's own noise
        (its per-pixel variance of the mean, var / n) subtracted from the MSE."""
        mse = np.mean((np.asarray(image, np.float64) - self.mean) ** 2)
        return float(np.sqrt(max(mse - np.mean(self.var / self.n), 0.0)))


def scene_hash(scene_path: str) -> str:
    with open(scene_path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


def resolve_scene(spec: str, root: str = REFERENCE_ROOT) -> tuple[str, str]:
    """(name, scene.xml path) from a reference name or a path to a scene file/folder."""
    if os.path.isfile(spec):
        path = os.path.abspath(spec)
    elif os.path.isdir(spec) and os.path.isfile(os.path.join(spec, "scene.xml")):
        path = os.path.abspath(os.path.join(spec, "scene.xml"))
    elif os.path.isfile(os.path.join(root, spec, "scene.xml")):
        path = os.path.join(root, spec, "scene.xml")
    else:
        known = ", ".join(list_scenes(root)) or "none"
        raise InvalidArgument(f"scene {spec!r}: no such file, folder with scene.xml, or "
                              f"reference name (known: {known})")
    return os.path.basename(os.path.dirname(path)), path


def list_scenes(root: str = REFERENCE_ROOT) -> list[str]:
    if not os.path.isdir(root):
        return []
    return sorted(d for d in os.listdir(root) if os.path.isfile(os.path.join(root, d, "scene.xml")))


def render_reference(spec: str, *, spp: int = 64, passes: int = 16, seed: int = 0,
                     params: dict | None = None, progress=None) -> tuple[Reference, np.ndarray]:
    """Render a scene with Mitsuba as ``passes`` independent passes (in memory, not
    cached): (Reference with per-pixel mean and variance across passes, the passes)."""
    from . import mitsuba as mvm

    if spp < 1 or passes < 2:
        raise InvalidArgument(f"spp={spp}, passes={passes}: need spp >= 1 and passes >= 2 "
                              "(the variance needs two passes)")
    name, path = resolve_scene(spec)
    seeds = [int(s) for s in np.random.SeedSequence([seed, 7]).generate_state(passes)]
    imgs = mvm.render_passes(path, spp=spp, seeds=seeds, params=params, progress=progress)
    choice = mvm.choose_variant()
    manifest = provenance(scene=name, scene_sha256=scene_hash(path), spp=spp,
                          passes=passes, seeds=seeds, mitsuba_version=mvm.mitsuba_version(),
                          mitsuba_variant=choice.variant, shape=list(imgs.shape[1:]),
                          params={k: str(v) for k, v in (params or {}).items()})
    return Reference(name, imgs.mean(axis=0), imgs.var(axis=0, ddof=1), passes, manifest), imgs


def build_reference(spec: str, *, spp: int = 256, passes: int = 16, seed: int = 0,
                    progress=None) -> str:
    """Render the reference of a scene and write it atomically; returns its folder."""
    from . import mitsuba as mvm

    name, path = resolve_scene(spec)
    ref, imgs = render_reference(path, spp=spp, passes=passes, seed=seed, progress=progress)
    out = os.path.join(os.path.dirname(path), "ref")
    tmp = tempfile.mkdtemp(prefix=".ref-", dir=os.path.dirname(path))
    try:
        mvm.write_exr(os.path.join(tmp, "mean.exr"), ref.mean)
        mvm.write_exr(os.path.join(tmp, "var.exr"), ref.var)
        manifest = {k: v for k, v in ref.manifest.items() if k != "params"}
        with open(os.path.join(tmp, "manifest.json"), "w", encoding="utf-8") as f:
            json.dump(manifest, f, indent=2)
        os.chmod(tmp, shared_mode(0o777))  # mkdtemp makes 0700; references are shared
        if os.path.isdir(out):
            shutil.rmtree(out)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


def load_reference(spec: str) -> Reference:
    """Load a built reference; a missing, stale (scene changed) or corrupt one raises
    ``EnvironmentProblem`` naming the file and saying how to rebuild it."""
    from . import mitsuba as mvm

    name, path = resolve_scene(spec)
    folder = os.path.join(os.path.dirname(path), "ref")
    mpath = os.path.join(folder, "manifest.json")
    rebuild = f"run `mcverify reference build {name}`"
    if not os.path.isfile(mpath):
        raise MissingReference(f"{mpath}: no reference built for {name!r}; {rebuild}")
    try:
        with open(mpath, encoding="utf-8") as f:
            manifest = json.load(f)
        n = int(manifest["passes"])
        digest = manifest["scene_sha256"]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise EnvironmentProblem(f"{mpath}: corrupt manifest ({e}); {rebuild}") from None
    if digest != scene_hash(path):
        raise EnvironmentProblem(f"{mpath}: stale: {path} changed since the reference was "
                                 f"built; {rebuild}")
    mean = mvm.read_exr(os.path.join(folder, "mean.exr"))
    var = mvm.read_exr(os.path.join(folder, "var.exr"))
    shape = tuple(manifest.get("shape", mean.shape))
    for label, img in (("mean.exr", mean), ("var.exr", var)):
        if img.shape != shape or not np.all(np.isfinite(img)):
            raise EnvironmentProblem(f"{os.path.join(folder, label)}: corrupt (shape "
                                     f"{img.shape}, expected {shape}, or NaN/Inf); {rebuild}")
    return Reference(name, mean, var, n, manifest)
