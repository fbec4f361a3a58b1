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
from .executors import Pool, Unit, same_source, source_fingerprint

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


def _pass_seeds(seed: int, passes: int) -> list[int]:
    return [int(s) for s in np.random.SeedSequence([seed, 7]).generate_state(passes)]


def _render_pass_unit(fingerprint, path, spp, seed, params, variant) -> np.ndarray:
    """One Mitsuba pass as a unit of work (in this process or a worker)."""
    from . import mitsuba as mvm

    same_source(fingerprint)
    return mvm.render_pass(path, spp=spp, seed=seed, params=params, variant=variant)


@dataclass(frozen=True)
class _Job:
    """The passes of one scene's reference: what to render and how to label it."""

    name: str
    path: str
    spp: int
    seeds: list
    params: dict | None

    def units(self, pool: Pool, variant: str) -> list[Unit]:
        fingerprint = None if pool.in_process else source_fingerprint()
        k = len(self.seeds)
        return [Unit(f"{self.name} pass {i + 1}/{k}", _render_pass_unit,
                     (fingerprint, self.path, self.spp, s, self.params, variant))
                for i, s in enumerate(self.seeds)]

    def assemble(self, imgs: np.ndarray, variant: str) -> Reference:
        from . import mitsuba as mvm

        manifest = provenance(scene=self.name, scene_sha256=scene_hash(self.path),
                              spp=self.spp, passes=len(self.seeds), seeds=self.seeds,
                              mitsuba_version=mvm.mitsuba_version(), mitsuba_variant=variant,
                              shape=list(imgs.shape[1:]),
                              params={k: str(v) for k, v in (self.params or {}).items()})
        return Reference(self.name, imgs.mean(axis=0), imgs.var(axis=0, ddof=1),
                         len(self.seeds), manifest)


def _job(spec: str, spp: int, passes: int, seed: int, params: dict | None) -> _Job:
    if spp < 1 or passes < 2:
        raise InvalidArgument(f"spp={spp}, passes={passes}: need spp >= 1 and passes >= 2 "
                              "(the variance needs two passes)")
    name, path = resolve_scene(spec)
    return _Job(name, path, spp, _pass_seeds(seed, passes), params)


def _render_jobs(jobs: list[_Job], pool: Pool | None, progress) -> list[tuple[Reference,
                                                                             np.ndarray]]:
    """Every pass of every job as one batch of units (passes of different scenes run side
    by side); (Reference, passes) per job, in order."""
    from . import mitsuba as mvm

    variant = mvm.choose_variant().variant
    show = None if progress is None else (lambda d, t, unit, _: progress(d, t, unit.key))
    own = pool is None
    pool = Pool() if own else pool
    try:
        units = [u for job in jobs for u in job.units(pool, variant)]
        imgs = pool.map(units, progress=show)
    finally:
        if own:
            pool.close()
    out, at = [], 0
    for job in jobs:
        stack = np.stack(imgs[at:at + len(job.seeds)])
        at += len(job.seeds)
        out.append((job.assemble(stack, variant), stack))
    return out


def render_reference(spec: str, *, spp: int = 64, passes: int = 16, seed: int = 0,
                     params: dict | None = None, progress=None,
                     pool: Pool | None = None) -> tuple[Reference, np.ndarray]:
    """Render a scene with Mitsuba as ``passes`` independent passes (in memory, not
    cached): (Reference with per-pixel mean and variance across passes, the passes).
    Passes are units of work on ``pool`` (default: this process);
    ``progress(done, total, label)`` is called as passes finish."""
    return _render_jobs([_job(spec, spp, passes, seed, params)], pool, progress)[0]


def build_references(specs, *, spp: int = 256, passes: int = 16, seed: int = 0,
                     progress=None, pool: Pool | None = None) -> list[str]:
    """Render the references of several scenes (all their passes as units on ``pool``,
    default this process) and write each atomically; returns their folders. Every scene
    is resolved before any rendering."""
    jobs = [_job(s, spp, passes, seed, None) for s in specs]
    return [_write(job.path, ref) for job, (ref, _) in
            zip(jobs, _render_jobs(jobs, pool, progress))]


def build_reference(spec: str, *, spp: int = 256, passes: int = 16, seed: int = 0,
                    progress=None, pool: Pool | None = None) -> str:
    """Render the reference of a scene and write it atomically; returns its folder."""
    return build_references([spec], spp=spp, passes=passes, seed=seed, progress=progress,
                            pool=pool)[0]


def _write(path: str, ref: Reference) -> str:
    from . import mitsuba as mvm

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
