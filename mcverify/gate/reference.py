"""Reference renders: Mitsuba's image of a scene as K independent passes, with per-pixel
variance across passes and a manifest, so a stale or corrupt reference is never used.

Layout: ``reference/scenes/<name>/scene.xml`` and, built from it,
``reference/scenes/<name>/ref/{mean.exr, var.exr, passes.exr, manifest.json}``; a scene
file of another name, ``<folder>/<file>.xml``, has its reference in
``<folder>/ref-<file>.xml/`` (``ref_folder``), so scenes sharing a folder keep one each.
The manifest records Mitsuba's version and variant, spp, passes, the seed and the pass
seeds derived from it, UTC time, the
film's filter radius (``rfilter_radius``: above 1/2 the filter splats, and pixels of one
pass correlate) and the SHA-256 of the scene, of every file it names (meshes, textures,
environment maps: ``scene_assets``) and of each image: a changed scene, a changed mesh or
texture, or a swapped image is refused as stale. ``passes.exr`` holds the K pass
images stacked vertically ((K·H, W, C)): the render gate needs them where pixels
correlate. References built before it was written have none and stay valid for
box-filtered scenes.
Images are read only as float OpenEXR (``read_float_exr``): an 8-bit PNG renamed ``.exr``
would otherwise be read as radiance.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import shlex
import shutil
import stat
import struct
import tempfile
from dataclasses import dataclass
from xml.parsers import expat

import numpy as np

from .. import _validate as validate
from ..errors import (EnvironmentProblem, InvalidArgument, MissingReference, first_cause,
                      interrupted)
from ..provenance import provenance
from ..result import shared_mode
from .executors import Pool, Unit, same_source, source_fingerprint

try:
    import fcntl
except ImportError:         # not on POSIX: no lock, as before
    fcntl = None


def _reference_root() -> str:
    """Where the reference scenes are: ``$MCVERIFY_REFS`` if set; else the scenes that
    come with mcverify (``_bundled_root``)."""
    forced = os.environ.get("MCVERIFY_REFS")
    if forced:
        return os.path.abspath(forced)
    return _bundled_root()


#: The folder that holds the ``mcverify`` package, and a checkout's scenes beside it.
_PACKAGES = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
_CHECKOUT = os.path.join(_PACKAGES, "reference", "scenes")


def _bundled_root() -> str:
    """The scenes that come with mcverify: this checkout's ``reference/scenes``; else, for
    an installed (non-editable) mcverify, the copy installed with it (``_installed_root``)."""
    if os.path.isdir(_CHECKOUT):
        return _CHECKOUT
    return _installed_root(_PACKAGES) or _CHECKOUT


def _installed_root(packages: str) -> str | None:
    """Where installing the wheel put its ``share/mcverify/scenes`` (pyproject's
    data-files), ``packages`` being the folder that holds the ``mcverify`` package: beside
    the packages (``pip install --target DIR``); where the wheel's RECORD, beside the
    packages, places them (any scheme: a venv, ``--user``, ``--prefix DIR``, Debian's
    system Python, which installs under /usr/local while ``sys.prefix`` is /usr); else
    under ``sys.prefix`` or the user base. None if none of them is a folder."""
    import site
    import sys

    tail = ("share", "mcverify", "scenes")
    candidates = [os.path.join(packages, *tail)]
    candidates += _recorded_roots(packages, tail)
    candidates += [os.path.join(base, *tail) for base in (sys.prefix, site.USER_BASE) if base]
    return next((c for c in candidates if os.path.isdir(c)), None)


def _recorded_roots(packages: str, tail: tuple[str, ...]) -> list[str]:
    """The folders ending in ``tail`` that the RECORD of the mcverify installed in
    ``packages`` names, resolved against ``packages`` as pip wrote them."""
    from importlib.metadata import distributions

    roots = []
    for dist in distributions(name="mcverify", path=[packages]):
        for file in dist.files or ():
            parts = file.parts
            at = next((i for i in range(len(parts) - len(tail) + 1)
                       if parts[i:i + len(tail)] == tail), None)
            if at is not None:
                roots.append(os.path.normpath(os.path.join(packages,
                                                           *parts[:at + len(tail)])))
                break
    return roots


REFERENCE_ROOT = _reference_root()
#: The scenes that come with mcverify, whatever ``--refs``/``$MCVERIFY_REFS`` say: the
#: fixed workloads of ``mcverify bench`` (the Cornell box's gate, the white furnace's
#: kernels) are these.
BUNDLED_ROOT = _bundled_root()


def installed_copy(path: str) -> str | None:
    """The folder of scenes installed with mcverify (not a checkout's) if it holds
    ``path``, else None. Their references are what this install's ``check`` and
    ``render-check`` compare against, so ``reference build`` leaves them alone."""
    if BUNDLED_ROOT == _CHECKOUT or not os.path.isdir(BUNDLED_ROOT):
        return None
    root, real = os.path.realpath(BUNDLED_ROOT), os.path.realpath(path)
    return BUNDLED_ROOT if os.path.commonpath([root, real]) == root else None


def set_reference_root(path: str, option: str = "--refs") -> str:
    """Make scene names resolve in ``path`` (``--refs DIR``): a folder of
    ``NAME/scene.xml`` (+ ``NAME/ref/``). Also exported as ``$MCVERIFY_REFS``, so worker
    processes started from here resolve names the same way. ``option`` names where
    ``path`` came from in the error (``--refs`` or ``$MCVERIFY_REFS``)."""
    global REFERENCE_ROOT
    if not os.path.isdir(path):
        what = "does not exist" if not os.path.exists(path) else "is not a directory"
        sep = "=" if option.startswith("$") else " "
        raise InvalidArgument(f"{option}{sep}{path}: {what} (a folder of NAME/scene.xml)")
    REFERENCE_ROOT = os.path.abspath(path)
    os.environ["MCVERIFY_REFS"] = REFERENCE_ROOT
    return REFERENCE_ROOT


@dataclass(frozen=True)
class Reference:
    name: str
    mean: np.ndarray
    var: np.ndarray
    n: int
    manifest: dict
    passes: np.ndarray | None = None    # (K, H, W, C), K = n; None in older references

    @property
    def pixels_correlated(self) -> bool:
        """True if the film's filter splats samples into neighbouring pixels (radius
        above 1/2), so that pixels of one pass are correlated."""
        return float(self.manifest.get("rfilter_radius", 0.5)) != 0.5

    def rmse(self, image) -> float:
        """RMSE of ``image`` against this reference's mean, with the reference's own noise
        (its per-pixel variance of the mean, var / n) subtracted from the MSE."""
        return self.rmse_of_mean_mse(self.mse(image))

    def mse(self, image) -> float:
        """Raw MSE of ``image`` against this reference's mean (its noise included)."""
        return float(np.mean((np.asarray(image, np.float64) - self.mean) ** 2))

    def rmse_of_mean_mse(self, mse: float) -> float:
        """The RMSE that a (mean) raw MSE gives once the reference's own noise is
        subtracted."""
        return float(np.sqrt(max(mse - np.mean(self.var / self.n), 0.0)))


#: Reference files whose SHA-256 the manifest records (besides the scene).
IMAGES = ("mean.exr", "var.exr")
#: The pass images, stacked vertically; recorded as ``passes_sha256`` where present.
PASSES = "passes.exr"
#: OpenEXR pixel types (the ``chlist`` attribute of the header).
_EXR_TYPES = {0: "uint", 1: "half", 2: "float"}
#: OpenEXR compressions that change the pixels, and the pixel types they change: PXR24
#: rounds float channels to 24 bits, B44(A) quantises half ones, DWAA and DWAB colour
#: channels of either type (``_DWA_LOSSY``; others they keep). A correct render's mean
#: written with DWAB at its recommended level 45 failed against its reference with p = 0.
_EXR_LOSSY = {5: ("PXR24", ("float",)), 6: ("B44", ("half",)), 7: ("B44A", ("half",)),
              8: ("DWAA", ("half", "float")), 9: ("DWAB", ("half", "float"))}
#: The channels DWAA/DWAB compress in a DCT (by the name after a layer's ``.``).
_DWA_LOSSY = ("R", "G", "B", "Y", "RY", "BY")
_EXR_MAGIC = b"\x76\x2f\x31\x01"
#: Largest image or scene file read (a reference image of 4096² RGB float32 is 200 MB).
MAX_FILE_BYTES = 1 << 30


def file_hash(path: str) -> str:
    """SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def scene_hash(scene_path: str) -> str:
    """SHA-256 of a scene file (the manifest's ``scene_sha256``)."""
    return file_hash(scene_path)


def scene_assets(scene_path: str, params=None) -> dict[str, str | None]:
    """SHA-256 of every file the scene names (the manifest's ``assets_sha256``): each
    ``<string name="filename" value=...>``, ``<spectrum filename=...>`` and
    ``<include filename=...>``, keyed by the
    name as written, ``$name`` replaced by the scene's ``<default>`` (Mitsuba's
    substitution), resolved against the scene's folder as Mitsuba resolves it; None for
    a name that is no regular file (Mitsuba then refuses the scene). Parsed as
    ``precheck_scene`` parses it (``_parse_scene``)."""
    return {name: file_hash(full) if os.path.isfile(full) else None
            for name, full in scene_asset_files(scene_path, params).items()}


def scene_asset_files(scene_path: str, params=None) -> dict[str, str]:
    """The file each name of ``scene_assets`` resolves to (its key: the name as written).

    The files an ``<include>``d file names count too (a texture named only there changed
    without the reference going stale): included files are read in turn, each once, and
    their names resolved, as Mitsuba resolves them, against the scene's own folder; the
    files an ``<include>`` names are found beside the file that includes it first (Mitsuba
    3.9 renders ``sub/more.xml`` for an include of ``more.xml`` in ``sub/parts.xml``,
    where the manifest hashed ``more.xml`` beside the scene), keyed then by its path from
    the scene's folder (``sub/more.xml``), so that the same name included beside the
    scene too is hashed as well.
    A ``<path value="DIR"/>`` is read as Mitsuba's file resolver reads it, as our
    loader does (``estimators.pathtracer.scene._Loader._spliced``): DIR against the folder
    of the file it is in, else against the resolver's folders; it puts DIR first for the
    ``<include>``s after it in its file, and a ``<path>`` of the scene's (not an included
    file's, which Mitsuba reads with a copy of its resolver) for every file an element
    names, the last such element first, wherever it stands (a texture found there was
    rendered while the manifest hashed the file of that name beside the scene, or
    recorded it as missing; until a read-only review an included file's ``<path>`` was
    ignored, and the file its include named went unhashed). An include found elsewhere
    than beside the scene is keyed by its path from the scene's folder. ``params`` (a
    dict, or its sorted items): the ``$name`` values the scene is loaded with, over its
    ``<default>``s, as Mitsuba takes them (the file a ``--param mesh=b.obj`` names was
    not the one stamped or hashed). A ``<spectrum filename=...>`` is looked for as Mitsuba
    reads it, while parsing: in the resolver's folders as they stand at the element (the
    ``<path>``s before it in its file, then the folders its file was included with), keyed
    as an include is."""
    return _asset_files_and_namers(scene_path, params)[0]


def scene_asset_namers(scene_path: str, params=None) -> dict[str, str]:
    """The file that names each of ``scene_asset_files``'s names (the scene, or the
    included file the name is written in), by the same key: a staleness message said
    "textures/museum.exr (named by bsdf_diffuse.xml)" of a scene that names it only
    through ``<include filename="include/matpreview.xml"/>``, Mitsuba's own
    material-preview scenes."""
    return _asset_files_and_namers(scene_path, params)[1]


def _asset_files_and_namers(scene_path: str, params=None):
    from estimators.pathtracer.scene import first_found, parse_time_folders

    defaults = {k: str(v).lower() if isinstance(v, bool) else str(v)
                for k, v in dict(params or {}).items()}
    folder = os.path.dirname(os.path.abspath(scene_path))
    # (name, None) for a file an element names, found at the end through the scene's own
    # resolver; (name, folders) for an <include> or a <spectrum filename>, looked for in
    # the resolver's folders as they stood at it in the file being read
    names, includes, namers = [], set(), []
    # the file being read; "own": where its folder stands in the resolver, which serves
    # its includes only (None: the scene's, which is Mitsuba's resolver's too)
    reading = {"here": folder, "resolver": [folder], "own": None,
               "file": os.path.abspath(scene_path)}

    def substitute(text):
        for key in sorted(defaults, key=len, reverse=True):    # as Mitsuba: longest first
            text = text.replace("$" + key, defaults[key])
        return text

    def start(tag, attrib):
        if tag == "default" and "name" in attrib:
            # a default's value may use the ones before it (value="$base.obj")
            defaults.setdefault(attrib["name"], substitute(attrib.get("value", "")))
        elif tag == "string" and attrib.get("name") == "filename" and "value" in attrib:
            names.append((attrib["value"], None))
            namers.append(reading["file"])
        elif tag == "spectrum" and "filename" in attrib:
            # <spectrum name="reflectance" filename="x.spd"/>: Mitsuba reads the file
            # (into RGB in RGB variants), so a changed one changes the image; it reads
            # it as it parses, in the resolver's folders as they stand there (the
            # loader's _mark_spectra): a <path> after it does not count, and an included
            # file's own folder serves its includes only
            names.append((attrib["filename"], tuple(
                parse_time_folders(reading["resolver"], reading["own"]))))
            namers.append(reading["file"])
        elif tag == "include" and "filename" in attrib:
            names.append((attrib["filename"], tuple(reading["resolver"])))
            namers.append(reading["file"])
            includes.add(names[-1])
        elif tag == "path" and "value" in attrib:
            d = substitute(attrib["value"])
            found = first_found(d, [reading["here"]] + reading["resolver"], os.path.isdir)
            if found is not None:       # else Mitsuba refuses the scene
                reading["resolver"].insert(0, os.path.abspath(found))
                if reading["own"] is not None:
                    reading["own"] += 1

    _parse_scene(scene_path, start)
    scene_resolver = list(reading["resolver"])      # the files elements name are found in
    out: dict[str, str] = {}
    named_by: dict[str, str] = {}
    read = {os.path.realpath(scene_path)}
    i = 0
    while i < len(names):           # grows as included files are read
        name, at = names[i]
        i += 1
        real = substitute(name)
        full = first_found(real, scene_resolver if at is None else at, os.path.exists) \
            or os.path.join(folder, real)
        # an include found elsewhere than beside the scene keyed by its path from there:
        # the same name included beside the scene too is another file (a read-only
        # review found one of them left out)
        key = name if at is None or full == os.path.join(folder, real) \
            or os.path.isabs(real) else os.path.relpath(full, folder)
        if key in out:
            continue
        out[key] = full
        named_by[key] = namers[i - 1]
        if (name, at) in includes and os.path.isfile(full) and \
                os.path.realpath(full) not in read:
            read.add(os.path.realpath(full))
            reading["here"] = os.path.dirname(full)
            reading["resolver"] = [reading["here"]] + list(at)
            reading["own"] = 0
            reading["file"] = full
            _parse_scene(full, start)
    return out, named_by


def _named_by(scene_path: str, asset: str) -> str:
    """The file that names ``asset``, and the scene whose includes reach it where that is
    another file (``include/m.xml, through the includes of scene.xml``), both as the
    scene's path was given (a nested include was said to be "included by" the scene,
    and an absolute path stood beside a relative one; a read-only review)."""
    namer = scene_asset_namers(scene_path).get(asset)
    if namer is None or os.path.realpath(namer) == os.path.realpath(scene_path):
        return scene_path
    folder = os.path.dirname(scene_path)
    shown = os.path.join(folder, os.path.relpath(namer, os.path.dirname(
        os.path.abspath(scene_path))))
    return f"{shown}, through the includes of {scene_path}"


def scene_stamp(scene_path: str, params=None) -> tuple:
    """What a scene loaded once per process (Mitsuba's, our tracer's) is kept by: the
    modification time, size and inode of the scene file and of every file it names
    (``scene_asset_files``). Keyed by the scene file's time alone, a texture changed
    beside an unchanged scene was rendered as it was: a reference rebuilt in the same
    process showed the old texture under a manifest hashing the new one."""
    def stamp(file):
        try:
            st = os.stat(file)
        except OSError:
            return None
        return st.st_mtime_ns, st.st_size, st.st_ino

    try:
        files = sorted(set(scene_asset_files(scene_path, params).values()))
    except InvalidArgument:     # the loader names what is wrong with the scene itself
        files = []
    return (stamp(scene_path),) + tuple((f, stamp(f)) for f in files)


def ref_folder(scene_path: str) -> str:
    """Where the reference of a scene file lives: ``ref`` beside a ``scene.xml``,
    ``ref-<file name>`` beside a scene file of any other name."""
    folder, base = os.path.split(os.path.abspath(scene_path))
    return os.path.join(folder, "ref" if base == "scene.xml" else f"ref-{base}")


#: ``reference build``'s (and ``build_reference``'s) samples per pass and passes.
DEFAULT_SPP, DEFAULT_PASSES = 256, 16


def rebuild_command(name: str, scene_path: str, manifest: dict | None = None) -> str:
    """The command that builds the reference of a scene: by its reference name when the
    name resolves to it, else by its path, quoted for the shell (a path with a space was
    split into several arguments when the command was pasted); with the ``--spp`` and
    ``--passes`` of the reference it replaces (``manifest``) where they are not the
    defaults: a splatting-filter scene's reference of 64 passes × 64 spp, rebuilt by the
    bare command at 16 × 256, was then refused by ``render-check`` at its defaults; and
    with its ``--seed`` where that is not 0, so that the command builds the same bits
    (a reference built with ``--seed 5`` was to be rebuilt at seed 0). A name that
    resolves in a folder other than the bundled scenes (``--refs DIR``,
    ``$MCVERIFY_REFS``) comes with ``--refs DIR``: without it the pasted command rebuilt
    the checkout's scene of that name, and DIR's stayed stale."""
    named = os.path.join(REFERENCE_ROOT, name, "scene.xml")
    if os.path.abspath(named) != os.path.abspath(scene_path):
        return f"mcverify reference build {shlex.quote(scene_path)}{_build_options(manifest)}"
    refs = ("" if os.path.abspath(REFERENCE_ROOT) == os.path.abspath(BUNDLED_ROOT)
            else f" --refs {shlex.quote(REFERENCE_ROOT)}")
    return f"mcverify reference build {shlex.quote(name)}{_build_options(manifest)}{refs}"


def _build_options(manifest: dict | None) -> str:
    """``--spp``, ``--passes`` and ``--seed`` of the reference a manifest describes, where
    they are not the defaults ("" without a manifest)."""
    counts = ""
    if isinstance(manifest, dict):
        spp = manifest.get("spp_requested", manifest.get("spp"))
        passes = manifest.get("passes")
        if all(isinstance(v, int) and not isinstance(v, bool) and v > 0
               for v in (spp, passes)) and (spp, passes) != (DEFAULT_SPP, DEFAULT_PASSES):
            counts = f" --spp {spp} --passes {passes}"
        seed = manifest.get("seed")
        if isinstance(seed, int) and not isinstance(seed, bool) and 0 < seed < 2 ** 63:
            counts += f" --seed {seed}"
    return counts


def rebuild_advice(name: str, scene_path: str, manifest: dict | None = None) -> str:
    """What to do to (re)build a scene's reference: ``run `rebuild_command```; for a
    scene installed with mcverify, which ``reference build`` leaves alone, to copy its
    folder into a folder of one's own and build it there (the command it named was
    refused; a read-only review)."""
    if not installed_copy(scene_path):
        return f"run `{rebuild_command(name, scene_path, manifest)}`"
    folder = os.path.dirname(os.path.abspath(scene_path))
    base = os.path.basename(folder)
    return (f"copy {shlex.quote(folder)} into a folder of your own, DIR, and run "
            f"`mcverify reference build {shlex.quote(base)} --refs DIR"
            f"{_build_options(manifest)}` (the references installed with mcverify are "
            "left as they are)")


def _regular_file(path: str, what: str) -> None:
    """A readable regular file of sane size, or InvalidArgument naming it (a FIFO or
    /dev/zero would block or never end)."""
    try:
        st = os.stat(path)
    except OSError as e:
        raise InvalidArgument(f"{path}: cannot read {what} ({e.strerror})") from None
    if not stat.S_ISREG(st.st_mode):
        raise InvalidArgument(f"{path}: not a regular file; give the {what} file itself")
    if st.st_size > MAX_FILE_BYTES:
        raise InvalidArgument(f"{path}: {st.st_size} bytes, more than the "
                              f"{MAX_FILE_BYTES >> 20} MiB any {what} may have")


def exr_channel_types(path: str) -> dict[str, str]:
    """The channels of an OpenEXR file and their pixel types ("half", "float", "uint"),
    from its header; InvalidArgument naming the file if it is not OpenEXR, if its
    compression is lossy for its channels (``_EXR_LOSSY``) or if it stores another
    window than its image's (``_whole``)."""
    _regular_file(path, "OpenEXR image")
    with open(path, "rb") as f:
        head = f.read(1 << 16)
    if head[:4] != _EXR_MAGIC:
        raise InvalidArgument(f"{path}: not an OpenEXR file (it starts with "
                              f"{head[:4]!r}); give a float OpenEXR image")
    pos, channels, compression, windows = 8, None, 0, {}
    try:
        while head[pos] != 0:
            end = head.index(b"\0", pos)
            name = head[pos:end].decode("latin-1")
            tend = head.index(b"\0", end + 1)
            kind = head[end + 1:tend]
            size = struct.unpack_from("<i", head, tend + 1)[0]
            value = head[tend + 5:tend + 5 + size]
            if size < 0 or len(value) != size:
                raise ValueError("attribute runs past the header")
            if name == "channels" and kind == b"chlist":
                channels, q = {}, 0
                while value[q] != 0:
                    cend = value.index(b"\0", q)
                    ptype = struct.unpack_from("<i", value, cend + 1)[0]
                    channels[value[q:cend].decode("latin-1")] = _EXR_TYPES.get(ptype, "?")
                    q = cend + 1 + 16
            if name == "compression" and kind == b"compression":
                compression = value[0]
            if name in ("dataWindow", "displayWindow") and kind == b"box2i":
                windows[name] = struct.unpack_from("<4i", value)
            pos = tend + 5 + size
    except (IndexError, ValueError, struct.error) as e:
        raise InvalidArgument(f"{path}: corrupt OpenEXR header ({e})") from None
    if not channels:
        raise InvalidArgument(f"{path}: OpenEXR header without channels")
    _lossless(path, compression, channels)
    _whole(path, windows)
    return channels


def _whole(path: str, windows: dict) -> None:
    """InvalidArgument naming the file where its pixels (the data window) are not its
    image (the display window): a crop to the pixels that are not black, or an
    overscan, read as an image of another size ("shape (62, 62, 3) differs from the
    reference's (64, 64, 3)" of a 64 × 64 image, an outside review)."""
    data, display = windows.get("dataWindow"), windows.get("displayWindow")
    if data and display and data != display:
        raise InvalidArgument(f"{path}: its data window {list(data)} is not its display "
                              f"window {list(display)} (x min, y min, x max, y max): "
                              "only the data window's pixels are stored; write the whole "
                              "image, not cropped (autocrop) or with an overscan")


def channel_name(channel: str) -> str:
    """An OpenEXR channel's name without its layer (``beauty.R`` -> ``R``)."""
    return channel.rpartition(".")[2]


def is_alpha(channel: str) -> bool:
    """An OpenEXR alpha channel (``A``, or a layer's ``beauty.A``; either case, as the
    colour channels are read): not compared."""
    return channel_name(channel) in ("A", "a")


def _lossless(path: str, compression: int, channels: dict[str, str]) -> None:
    """InvalidArgument naming the file where its compression changed the pixels of the
    channels compared (all but alpha): the compression's error would read as the
    renderer's."""
    codec, changed = _EXR_LOSSY.get(compression, (None, ()))
    lossy = sorted(c for c, t in channels.items() if t in changed and not is_alpha(c) and (
        not codec.startswith("DWA") or channel_name(c).upper() in _DWA_LOSSY))
    if lossy:
        raise InvalidArgument(f"{path}: {codec} compression is lossy for its channels "
                              f"{', '.join(lossy)}; its error would be taken for the "
                              "renderer's: write the image with a lossless compression "
                              "(none, RLE, ZIPS, ZIP or PIZ)")


def read_float_exr(path: str) -> np.ndarray:
    """An OpenEXR image with half or float channels as (H, W, C) float64. Anything else
    (another format, integer channels, a truncated file, NaN/Inf) raises InvalidArgument
    or EnvironmentProblem naming the file: code values are not radiance."""
    from . import mitsuba as mvm

    types = exr_channel_types(path)
    if any(t not in ("half", "float") for t in types.values()):
        raise InvalidArgument(f"{path}: channels {types}: only half or float channels hold "
                              "radiance; give a float OpenEXR image")
    img = mvm.read_exr(path)
    if not np.all(np.isfinite(img)):
        raise InvalidArgument(f"{path}: contains NaN/Inf at "
                              f"{np.argwhere(~np.isfinite(img))[0].tolist()}")
    return img


def _parse_scene(path: str, start, end=None) -> None:
    """Parse a scene file (a readable regular file of sane size) with expat, calling
    ``start(tag, attrib)`` and ``end(tag)`` per element; a DOCTYPE or entity
    declaration (entity expansion) or malformed XML is InvalidArgument naming the file
    and line. The one parser of scene files here, so every reading is hardened alike."""
    _regular_file(path, "scene")
    with open(path, "rb") as f:
        text = f.read()
    parser = expat.ParserCreate()

    def refuse(*_):
        raise InvalidArgument(f"{path}: has a DOCTYPE/entity declaration; Mitsuba scenes "
                              "need none (refused: entity expansion)")

    parser.StartDoctypeDeclHandler = refuse
    parser.EntityDeclHandler = refuse
    parser.StartElementHandler = start
    if end is not None:
        parser.EndElementHandler = end
    try:
        parser.Parse(text, True)
    except expat.ExpatError as e:
        raise InvalidArgument(f"{path}:{e.lineno}: not well-formed XML "
                              f"({expat.ErrorString(e.code)})") from None


def precheck_scene(path: str) -> None:
    """What Mitsuba needs before rendering anything: a readable, well-formed XML file
    whose root is <scene> with an <integrator> (Mitsuba has no default one) and a
    <sensor> (or an <include> that may hold them). InvalidArgument names the file."""
    tags, depth = [], [0]

    def start(tag, attrib):
        if depth[0] == 1:
            tags.append(tag)
        elif depth[0] == 0:
            tags.append("<root>" + tag)
        depth[0] += 1

    def end(tag):
        depth[0] -= 1

    _parse_scene(path, start, end)
    if not tags or tags[0] != "<root>scene":
        raise InvalidArgument(f"{path}: the root element must be <scene>")
    if "include" not in tags:
        for need in ("integrator", "sensor"):
            if need not in tags:
                raise InvalidArgument(f"{path}: no <{need}>; Mitsuba cannot render a "
                                      f"scene without one (add e.g. <{need} type="
                                      f"\"{'path' if need == 'integrator' else 'perspective'}"
                                      "\">)")


def resolve_scene(spec: str, root: str | None = None) -> tuple[str, str]:
    """(name, scene file path) from a reference name (in ``root``, default
    ``REFERENCE_ROOT``) or a path to a scene file/folder. The name is the folder's for a
    ``scene.xml``, else the file's own without its extension."""
    root = REFERENCE_ROOT if root is None else root
    if (os.sep not in spec and spec not in (".", "..")
            and os.path.isfile(os.path.join(root, spec, "scene.xml"))):
        # a bare name of a scene under the root is that scene, whatever folder of that
        # name the working directory has (`reference build --refs DIR` rebuilt ./NAME
        # instead of DIR/NAME); ./NAME is the folder here
        path = os.path.join(root, spec, "scene.xml")
    elif os.path.isfile(spec):
        path = os.path.abspath(spec)
    elif os.path.isdir(spec) and os.path.isfile(os.path.join(spec, "scene.xml")):
        path = os.path.abspath(os.path.join(spec, "scene.xml"))
    elif os.path.isfile(os.path.join(root, spec, "scene.xml")):
        path = os.path.join(root, spec, "scene.xml")
    elif os.path.isdir(spec):
        raise InvalidArgument(f"scene {spec!r} is a folder without a scene.xml (and no "
                              "reference of that name): give the scene file's path, or "
                              "the folder that holds scene.xml")
    else:
        known = ", ".join(list_scenes(root)) or "none"
        raise InvalidArgument(f"scene {spec!r}: no such file, folder with scene.xml, or "
                              f"reference name (known: {known})")
    return scene_name(path), path


def scene_name(path: str) -> str:
    """A scene file's name in check names and references: its folder's for a
    ``scene.xml``, else the file's own without its extension."""
    path = os.path.abspath(path)
    base = os.path.basename(path)
    return (os.path.basename(os.path.dirname(path)) if base == "scene.xml"
            else os.path.splitext(base)[0])


def list_scenes(root: str | None = None) -> list[str]:
    root = REFERENCE_ROOT if root is None else root
    if not os.path.isdir(root):
        return []
    return sorted(d for d in os.listdir(root) if os.path.isfile(os.path.join(root, d, "scene.xml")))


def _pass_seeds(seed: int, passes: int) -> list[int]:
    return [int(s) for s in np.random.SeedSequence([seed, 7]).generate_state(passes)]


def _film_unit(fingerprint, path, spp, params, variant) -> tuple[float, int]:
    """(the film's filter radius, the samples per pixel Mitsuba's sampler renders for
    ``spp``) as Mitsuba loads the scene (a unit of work)."""
    from . import mitsuba as mvm

    same_source(fingerprint)
    return mvm.filter_radius(path, params), mvm.sampler_spp(path, spp, params)


def _render_pass_unit(fingerprint, path, spp, seed, params, variant) -> np.ndarray:
    """One Mitsuba pass as a unit of work (in this process or a worker)."""
    from . import mitsuba as mvm

    same_source(fingerprint)
    try:
        return mvm.render_pass(path, spp=spp, seed=seed, params=params, variant=variant)
    except (InvalidArgument, EnvironmentProblem):
        raise
    except Exception as e:  # noqa: BLE001 - Mitsuba raises plain Exception/RuntimeError
        if interrupted(e):    # Ctrl-C inside a render arrives wrapped in a drjit error
            raise KeyboardInterrupt from None
        raise EnvironmentProblem(f"{path}: Mitsuba cannot render it ("
                                 f"{' '.join(str(first_cause(e)).split())})") from None


def _non_finite_image(scene_path: str) -> str | None:
    """Which image the scene names (a texture, an envmap, a normal map) holds a NaN or
    infinite texel, said in words, or None: Mitsuba renders such a texel as NaN pixels,
    and the build blamed an emitter's value beyond float32's range (an outside review;
    ``render-check``'s loader names the file, ``reference build`` loads no scene of its
    own). Files that are no image (meshes, includes) are passed over. Images are read as
    a texture holds them, which takes an EXR whose channels carry a layer's name (an
    envmap's conversion refuses it, and its NaN texel was passed over)."""
    from estimators.pathtracer.textures import non_finite_texels, read_image

    for name, full in scene_asset_files(scene_path).items():
        if not os.path.isfile(full):
            continue
        try:
            bad = non_finite_texels(read_image(full, texture=True))
        except OSError:
            continue
        if bad:
            count, y, x, c, value = bad
            return (f"the image {name} has {count} texel(s) that are not finite, the first "
                    f"at row {y}, column {x} (channel {c}: {value}), which Mitsuba renders "
                    "as NaN")
    return None


@dataclass(frozen=True)
class _Job:
    """The passes of one scene's reference: what to render and how to label it."""

    name: str
    path: str
    spp: int
    seeds: list
    params: dict | None
    assets: dict        # scene_assets() when the job was made, before any pass renders
    scene_sha256: str   # likewise: a scene edited during the build is stale, not current
    seed: int = 0       # the build's seed, from which ``seeds`` derive (the rebuild needs it)
    pass_bytes: int = 0  # what one pass holds at the build's peak (``_pass_bytes``)

    def units(self, pool: Pool, variant: str) -> list[Unit]:
        fingerprint = None if pool.in_process else source_fingerprint()
        k = len(self.seeds)
        return [Unit(f"{self.name} pass {i + 1}/{k}", _render_pass_unit,
                     (fingerprint, self.path, self.spp, s, self.params, variant))
                for i, s in enumerate(self.seeds)] + \
            [Unit(f"{self.name} filter", _film_unit,
                  (fingerprint, self.path, self.spp, self.params, variant))]

    def assemble(self, imgs: np.ndarray, film: tuple[float, int], variant: str) -> Reference:
        from . import mitsuba as mvm

        radius, spp = film
        bad = ~np.isfinite(imgs)
        if bad.any():
            # a reference of inf pixels was written, then refused on loading with a
            # rebuild command that built the same (and numpy warned on its variance)
            k, y, x = np.argwhere(bad)[0][:3]
            cause = _non_finite_image(self.path) or (
                "a radiance, intensity, irradiance or scale beyond float32's range "
                "(3.4e38), which Mitsuba stores as infinity, or near it, where the float32 "
                "sum of a pixel's samples overflows, renders so")
            raise InvalidArgument(
                f"{self.path}: Mitsuba's image is not finite (NaN or inf) in "
                f"{int(bad.any(axis=(0, 3)).sum())} pixel(s), the first in pass {k + 1} at "
                f"x={x}, y={y}: {cause}; no reference written")
        var = imgs.var(axis=0, ddof=1)
        _check_variance_fits(self.path, var, imgs)
        # What Mitsuba rendered: a stratified sampler rounds 33 spp up to 36, and the
        # render gate pairs passes of equal spp where the filter splats (a probe found
        # the manifest saying 33)
        asked = {} if spp == self.spp else {"spp_requested": self.spp}
        manifest = provenance(scene=self.name, scene_sha256=self.scene_sha256,
                              assets_sha256=self.assets, spp=spp, **asked,
                              passes=len(self.seeds), seed=self.seed, seeds=self.seeds,
                              mitsuba_version=mvm.mitsuba_version(), mitsuba_variant=variant,
                              shape=list(imgs.shape[1:]), rfilter_radius=radius,
                              params={k: str(v) for k, v in (self.params or {}).items()})
        return Reference(self.name, imgs.mean(axis=0), var, len(self.seeds), manifest, imgs)


def _check_variance_fits(path: str, var: np.ndarray, imgs: np.ndarray) -> None:
    """Refuse a reference whose per-pixel variance across passes is beyond float32's
    range, in which ``var.exr`` stores it: finite pass values above about 1.8e19 (an area
    light of radiance 1e30) have a variance of 1e60, which was written as infinity (numpy
    warning of an overflow in the cast), reported built, and then refused by
    ``render-check`` as containing NaN/Inf with a rebuild command that built the same."""
    over = ~(var <= np.finfo(np.float32).max)
    if not over.any():
        return
    y, x, c = np.argwhere(over)[0]
    raise InvalidArgument(
        f"{path}: the variance across Mitsuba's passes is beyond float32's range "
        f"(3.4e38), in which a reference stores it (var.exr), in "
        f"{int(over.any(axis=2).sum())} pixel(s), "
        f"the first at x={x}, y={y} (channel {c}: {var[y, x, c]:.3g}; pass values up to "
        f"{np.abs(imgs).max():.3g}): scale the scene's emitters down so that its pixels "
        "stay below about 1e19; nothing written")


#: Most samples per pixel of one Mitsuba pass: ``mi.render`` takes a 32-bit unsigned spp
#: (2^32 reached it as a binding error blamed on the scene).
MAX_SPP_PER_PASS = 2 ** 32 - 1


def _pass_bytes(path: str, params: dict | None) -> int:
    """Bytes one pass of a reference takes at the build's peak, at the film size our
    loader reads (Mitsuba's default 768 × 576 where the film says nothing, and where our
    loader refuses the scene): its float64 RGB image (``render_pass`` returns float64)
    three times over, as Pool.map's list, their ``np.stack`` and ``var``'s deviations,
    with the stack's non-finite mask, 75 bytes a pixel, rounded up to 80 for each pass's
    small objects. Until 7 December it counted one float32 image, 12 bytes a pixel: a
    4096 × 4096 film under ``ulimit -v 5000000`` was allowed "at most 10" passes, and the
    10th failed after nine had rendered (an outside review)."""
    from estimators.pathtracer import SceneError
    from estimators.pathtracer.scene import load_scene

    try:
        film = load_scene(path, params=params).film
        width, height = int(film.get("width", 768)), int(film.get("height", 576))
    except SceneError:
        width, height = 768, 576
    return 80 * width * height


def _job(spec: str, spp: int, passes: int, seed: int, params: dict | None) -> _Job:
    # checked by type first: spp="8" raised a bare TypeError, spp=8.0 a Mitsuba binding
    # error blamed on the scene, seed=-1 numpy's ValueError
    for label, v in (("spp", spp), ("passes", passes), ("seed", seed)):
        validate.integer(label, v)
    if spp < 1 or passes < 2:
        raise InvalidArgument(f"spp={spp}, passes={passes}: need spp >= 1 and passes >= 2 "
                              "(the variance needs two passes)")
    if spp > MAX_SPP_PER_PASS:
        raise InvalidArgument(f"spp={spp}: at most {MAX_SPP_PER_PASS} (2^32 - 1) samples per "
                              "pass, Mitsuba's limit; use more passes")
    validate.seed("seed", seed)
    name, path = resolve_scene(spec)
    precheck_scene(path)
    # the passes stay in memory until the reference is written: --passes 10^17 was an
    # "unexpected MemoryError" naming no option (an outside review)
    each = _pass_bytes(path, params)
    validate.memory("passes", passes, each,
                    "its pass images, held until the reference is written", least=2)
    return _Job(name, path, spp, _pass_seeds(seed, passes), params,
                scene_assets(path, params), scene_hash(path), seed, each)


def _passes_fit_together(jobs: list[_Job], passes: int) -> None:
    """The passes of every scene a build renders are held together until the last has
    rendered (``_render_jobs``), and each scene's were counted alone: each 256 x 256
    scene added to a build of 6 passes added 22 MB to its peak (56 bytes a pixel a
    pass) that no guard counted, so scenes that each fit in half the memory ran out of
    it together after every pass had rendered (an outside review). InvalidArgument
    naming the scenes' count and the most passes that fit."""
    if len(jobs) < 2:
        return
    each = sum(job.pass_bytes for job in jobs)      # a pass of every scene

    def hint(avail):
        most = avail // 2 // each
        return (f"use at most {most}, or build fewer scenes at once" if most >= 2 else
                "build fewer scenes at once (each alone fits)")

    validate.fits(passes * each, f"passes={passes} of {len(jobs)} scenes: needs",
                  " (their pass images, all held until the last scene's have rendered)",
                  hint)


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
        film = imgs[at + len(job.seeds)]
        at += len(job.seeds) + 1
        out.append((job.assemble(stack, film, variant), stack))
    return out


def render_reference(spec: str, *, spp: int = 64, passes: int = 16, seed: int = 0,
                     params: dict | None = None, progress=None,
                     pool: Pool | None = None) -> tuple[Reference, np.ndarray]:
    """Render a scene with Mitsuba as ``passes`` independent passes (in memory, not
    cached): (Reference with per-pixel mean and variance across passes, the passes).
    Passes are units of work on ``pool`` (default: this process);
    ``progress(done, total, label)`` is called as passes finish."""
    return _render_jobs([_job(spec, spp, passes, seed, params)], pool, progress)[0]


def build_references(specs, *, spp: int = DEFAULT_SPP, passes: int = DEFAULT_PASSES,
                     seed: int = 0, progress=None, pool: Pool | None = None) -> list[str]:
    """Render the references of several scenes (all their passes as units on ``pool``,
    default this process) and write each (see ``build_reference``); returns their
    folders, one per distinct scene (a scene named twice is built once). Every scene is
    resolved and prechecked before any rendering."""
    jobs = []
    for s in specs:
        job = _job(s, spp, passes, seed, None)
        if all(os.path.realpath(j.path) != os.path.realpath(job.path) for j in jobs):
            _replaceable(ref_folder(job.path))       # a scene named twice is built once
            _assets_beside(job)
            jobs.append(job)
    _passes_fit_together(jobs, passes)
    return [_write(job.path, ref) for job, (ref, _) in
            zip(jobs, _render_jobs(jobs, pool, progress))]


#: Most bytes of a file name on common file systems (NAME_MAX), where ``pathconf`` says
#: nothing.
_NAME_MAX = 255


def _name_max(folder: str) -> int:
    try:
        return os.pathconf(folder, "PC_NAME_MAX")
    except (OSError, ValueError):
        return _NAME_MAX


def _aside(base: str, what: str) -> str:
    """The prefix of the temporary folders beside a reference folder ``base`` while it is
    replaced (``what``: "new" or "old"): ``.BASE-new-``, or, for a name too long to take
    that and mkdtemp's 8 characters within NAME_MAX, its SHA-256's first 16 digits
    (``.ref-<name of 240 bytes>.xml-new-…`` failed with 'File name too long' after
    every pass had rendered)."""
    if len(os.fsencode(base)) > 200:
        base = "ref-" + hashlib.sha256(os.fsencode(base)).hexdigest()[:16]
    return f".{base}-{what}-"


def _assets_beside(job: _Job) -> None:
    """Every file the scene names must be a file where the manifest hashes it (against the
    scene's folder): Mitsuba also looks in the current directory, so a mesh found only
    there was rendered into a reference that recorded it as missing (null) and never went
    stale when that file changed, and our tracer, which looks beside the scene, refused
    the scene the reference was built from."""
    for name, digest in job.assets.items():
        if digest is None:
            full = scene_asset_files(job.path, job.params)[name]
            raise InvalidArgument(f"{job.path}: names {name!r}, which is no file at {full}; "
                                  "give its path from the scene's folder or an absolute "
                                  "path (Mitsuba would also look in the current directory, "
                                  "and the reference would depend on where it is built)")


def _replaceable(out: str) -> None:
    """A reference folder may be replaced only if it is one: a file, a link or a folder
    holding anything but a reference's files is refused before any rendering (a file
    named ``ref`` beside the scene was deleted without a word); so is a scene whose
    reference folder's name, ``ref-<file name>``, is longer than the file system takes,
    and (EnvironmentProblem) a folder where no reference can be written."""
    folder, base = os.path.split(out)
    if len(os.fsencode(base)) > _name_max(folder):
        raise InvalidArgument(f"{out}: the reference folder of "
                              f"{os.path.join(folder, base[len('ref-'):])} would have a name "
                              f"of {len(os.fsencode(base))} bytes, more than the file system "
                              f"takes ({_name_max(folder)}); give the scene file a shorter name")
    try:    # the build's first write: a read-only folder failed only after every pass
        os.rmdir(tempfile.mkdtemp(prefix=_aside(base, "new"), dir=folder))   # rendered
    except OSError as e:
        raise EnvironmentProblem(f"{out}: cannot write the reference in {folder} "
                                 f"({e.strerror or e}); make the folder writable, or copy "
                                 "the scene somewhere writable and build it there") from None
    if not os.path.lexists(out):
        return
    if os.path.islink(out) or not os.path.isdir(out):
        raise InvalidArgument(f"{out}: exists and is not a reference folder (a "
                              f"{'link' if os.path.islink(out) else 'file'}); building "
                              "the reference would replace it: move it away first")
    extra = sorted(set(os.listdir(out)) - {"manifest.json", *IMAGES, PASSES})
    if extra:
        raise InvalidArgument(f"{out}: holds {os.path.join(out, extra[0])}, which is not "
                              "part of a reference; building the reference would delete "
                              "it: move it away first")


def build_reference(spec: str, *, spp: int = DEFAULT_SPP, passes: int = DEFAULT_PASSES,
                    seed: int = 0, progress=None, pool: Pool | None = None) -> str:
    """Render the reference of a scene and write it; returns its folder.

    Nothing is lost at any instant: the new reference is written into a temporary folder,
    the old one renamed aside, the new one renamed in, and only then the old one deleted.
    An interruption restores the old reference (or, if even that is cut short, leaves it
    as ``.ref-old-*`` beside the scene, which ``load_reference`` points to)."""
    return build_references([spec], spp=spp, passes=passes, seed=seed, progress=progress,
                            pool=pool)[0]


@contextlib.contextmanager
def _swap_lock(folder: str, exclusive: bool):
    """Hold an advisory ``flock`` on ``folder`` (the one a reference folder is in; no file
    is added there): exclusive while a build swaps a reference in, shared while one is
    read. Two builds of one reference at once failed where their swaps met ("Directory
    not empty", or an error naming the other's ``.ref-old-*`` folder, exit 2), and a
    render check reading it at that moment found none. A folder that cannot be opened
    or locked (a file system without ``flock``) is used unlocked."""
    try:
        fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY) if fcntl is not None else None
    except OSError:
        fd = None
    try:
        if fd is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH)
            except OSError:
                pass
        yield
    finally:
        if fd is not None:
            os.close(fd)


def _write(path: str, ref: Reference) -> str:
    """Write a rendered reference beside its scene (``build_reference``'s swap)."""
    from . import mitsuba as mvm

    out = ref_folder(path)
    folder, base = os.path.split(out)
    tmp = tempfile.mkdtemp(prefix=_aside(base, "new"), dir=folder)
    old = None
    try:
        manifest = {k: v for k, v in ref.manifest.items() if k != "params"}
        images = [(IMAGES[0], ref.mean), (IMAGES[1], ref.var)]
        if ref.passes is not None:
            images.append((PASSES, ref.passes.reshape(-1, *ref.passes.shape[2:])))
        for label, img in images:
            mvm.write_exr(os.path.join(tmp, label), img)
            manifest[label.replace(".exr", "_sha256")] = file_hash(os.path.join(tmp, label))
        with open(os.path.join(tmp, "manifest.json"), "w", encoding="utf-8") as f:
            json.dump(manifest, f, indent=2)
        os.chmod(tmp, shared_mode(0o777))  # mkdtemp makes 0700; references are shared
        with _swap_lock(folder, exclusive=True):
            try:
                if os.path.lexists(out):
                    old = tempfile.mkdtemp(prefix=_aside(base, "old"), dir=folder)
                    os.rename(out, os.path.join(old, base))
                os.rename(tmp, out)
            except BaseException:
                if old is not None and not os.path.lexists(out):
                    os.rename(os.path.join(old, base), out)
                    os.rmdir(old)
                raise
    except BaseException as e:
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(e, OSError) or type(e) is RuntimeError:
            # a full disk: Mitsuba's writer raises RuntimeError naming the temporary file,
            # which was "unexpected RuntimeError" (its subclasses, a RecursionError or
            # NotImplementedError, are not the disk's and go on as they are)
            why = e.strerror if isinstance(e, OSError) and e.strerror else str(e)
            raise EnvironmentProblem(f"{out}: cannot write the reference ({why}); "
                                     "the previous one, if any, is kept") from None
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
    return out


def reference_files(spec: str) -> list[str]:
    """The files a reference is made of (scene, the files it names, its folder, manifest,
    images), for refusing to write an output over one of them (the folder too: a render
    check built it where none was, then failed to write its JSON there, exit 2 after all
    its work)."""
    _, path = resolve_scene(spec)
    folder = ref_folder(path)
    return ([path] + list(scene_asset_files(path).values()) + [folder]
            + [os.path.join(folder, f) for f in ("manifest.json",) + IMAGES + (PASSES,)])


def _count(manifest: dict, key: str, minimum: int) -> int:
    """A manifest's count (``passes``, ``spp``): an integer of at least ``minimum``
    (ValueError naming the field otherwise; -1 passes blamed passes.exr, "x" spp raised
    a bare ValueError from the comparison)."""
    value = manifest[key]
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ValueError(f"{key}: {value!r}, expected an integer >= {minimum}")
    return value


def _radius(manifest: dict) -> float:
    """A manifest's ``rfilter_radius``: a positive finite number (ValueError naming the
    field otherwise; "x" raised a bare ValueError from ``pixels_correlated``)."""
    value = manifest["rfilter_radius"]
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value) or value <= 0:
        raise ValueError(f"rfilter_radius: {value!r}, expected a positive number")
    return float(value)


def _shape(manifest: dict) -> tuple[int, ...]:
    """A manifest's ``shape``: a list of 2 or 3 positive integers (ValueError naming the
    field otherwise; 5 or null raised "unexpected TypeError" naming no file)."""
    value = manifest["shape"]
    if not isinstance(value, list) or len(value) not in (2, 3) or any(
            isinstance(v, bool) or not isinstance(v, int) or v < 1 for v in value):
        raise ValueError(f"shape: {value!r}, expected [height, width(, channels)]")
    return tuple(value)


def load_reference(spec: str) -> Reference:
    """Load a built reference; a missing, stale (scene changed) or corrupt one raises
    ``EnvironmentProblem`` naming the file and saying how to rebuild it. A build
    swapping it in meanwhile waits until it is read (``_swap_lock``)."""
    name, path = resolve_scene(spec)
    with _swap_lock(os.path.dirname(ref_folder(path)), exclusive=False):
        return _load(name, path)


def _load(name: str, path: str) -> Reference:
    folder = ref_folder(path)
    parent, base = os.path.split(folder)
    mpath = os.path.join(folder, "manifest.json")
    rebuild = rebuild_advice(name, path)
    if not os.path.isfile(mpath):
        aside = sorted(d for d in os.listdir(parent) if d.startswith(_aside(base, "old")))
        where = (f" (an interrupted build left the previous one in "
                 f"{os.path.join(parent, aside[-1], base)})" if aside else "")
        raise MissingReference(f"{mpath}: no reference built for {name!r}{where}; {rebuild}")
    try:
        with open(mpath, encoding="utf-8") as f:
            manifest = json.load(f)
        n = _count(manifest, "passes", 2)
        if "spp" in manifest:
            _count(manifest, "spp", 1)
        if "rfilter_radius" in manifest:
            _radius(manifest)
        if "shape" in manifest:
            _shape(manifest)
        digest = manifest["scene_sha256"]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise EnvironmentProblem(f"{mpath}: corrupt manifest ({e}); {rebuild}") from None
    rebuild = rebuild_advice(name, path, manifest)    # as it was built
    if digest != scene_hash(path):
        raise EnvironmentProblem(f"{mpath}: stale: {path} changed since the reference was "
                                 f"built; {rebuild}")
    assets = scene_assets(path)
    recorded = manifest.get("assets_sha256")
    if recorded is None and assets:
        raise EnvironmentProblem(f"{mpath}: stale: records no SHA-256 of the files the scene "
                                 f"names (built before they were recorded); {rebuild}")
    for asset, now in sorted(assets.items()):
        # a file missing now is stale whatever was recorded: a reference built before the
        # build refused it (Mitsuba found it in the working directory) recorded null
        if not isinstance(recorded, dict) or recorded.get(asset, "") != now or now is None:
            what = "is missing" if now is None else "changed"
            # a name with a $parameter: the file it names now, too
            named = asset
            if "$" in asset:
                now_file = scene_asset_files(path)[asset]
                named += f" = {os.path.relpath(now_file, os.path.dirname(path) or '.')}"
            raise EnvironmentProblem(f"{mpath}: stale: {named} (named by "
                                     f"{_named_by(path, asset)}) {what} since the "
                                     f"reference was built; {rebuild}")
    labels = IMAGES + ((PASSES,) if "passes_sha256" in manifest else ())
    for label in labels:
        key = label.replace(".exr", "_sha256")
        file = os.path.join(folder, label)
        if key not in manifest:
            raise EnvironmentProblem(f"{mpath}: stale: records no {key} (built before "
                                     f"references were hashed); {rebuild}")
        if not os.path.isfile(file):
            raise EnvironmentProblem(f"{file}: missing; {rebuild}")
        if file_hash(file) != manifest[key]:
            raise EnvironmentProblem(f"{file}: stale: its SHA-256 differs from the "
                                     f"manifest's (the file was replaced); {rebuild}")
    try:
        mean, var = (read_float_exr(os.path.join(folder, label)) for label in IMAGES)
    except InvalidArgument as e:
        raise EnvironmentProblem(f"{e}; {rebuild}") from None
    shape = _shape(manifest) if "shape" in manifest else mean.shape
    for label, img in (("mean.exr", mean), ("var.exr", var)):
        if img.shape != shape or not np.all(np.isfinite(img)):
            raise EnvironmentProblem(f"{os.path.join(folder, label)}: corrupt (shape "
                                     f"{img.shape}, expected {shape}, or NaN/Inf); {rebuild}")
    passes = None
    if PASSES in labels:
        file = os.path.join(folder, PASSES)
        try:
            stacked = read_float_exr(file)
        except InvalidArgument as e:
            raise EnvironmentProblem(f"{e}; {rebuild}") from None
        if stacked.shape != (n * shape[0],) + shape[1:]:
            raise EnvironmentProblem(f"{file}: corrupt (shape {stacked.shape}, expected "
                                     f"{n} passes of {shape} stacked); {rebuild}")
        passes = _colour(file, stacked)
        passes = passes.reshape((n, shape[0]) + passes.shape[1:])
    mean, var = (_colour(os.path.join(folder, label), img)
                 for label, img in zip(IMAGES, (mean, var)))
    return Reference(name, mean, var, n, manifest, passes)


def _colour(path: str, img: np.ndarray) -> np.ndarray:
    """``img``, read from the reference image ``path``, without its alpha channel, as
    ``compare`` reads the images under test: a film of ``pixel_format`` rgba renders R, G,
    B and A, and until 7 December its reference kept A, and Mitsuba's own RGBA passes
    were refused against it, "shape (16, 24, 3) differs from the reference's (16, 24, 4)"
    (an outside review)."""
    return without_alpha(list(exr_channel_types(path)), img)


def without_alpha(names: list[str], img: np.ndarray) -> np.ndarray:
    """``img`` (H, W, C) of the OpenEXR channels ``names`` without its alpha, the last
    channel as read (RGBA -> RGB, YA -> Y), where one of them is an alpha; else ``img``
    itself. The one rule for the images under test (``passes.read_radiance``) and the
    reference's."""
    if img.ndim == 3 and img.shape[2] in (2, 4) and len(names) == img.shape[2] \
            and any(is_alpha(c) for c in names):
        return img[:, :, :-1]
    return img
