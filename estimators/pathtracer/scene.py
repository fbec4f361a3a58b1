"""Mitsuba 3 XML scenes, the subset the path tracer supports, parsed into plain records.

The same file loads in Mitsuba (``mitsuba.load_file``) unchanged. Anything outside the
subset is rejected with a ``SceneError`` naming the element, its line in the file and
what is supported: never silently ignored or approximated.

Supported: ``scene``, ``default`` and ``$param`` substitution, ``ref``/``id``,
``transform`` (``lookat``, ``translate``, ``rotate``, ``scale``, ``matrix``),
integrators ``path`` and ``direct``, sensors ``perspective`` and ``orthographic`` with
film ``hdrfilm``, ``rfilter`` ``box``, ``gaussian`` (the default) and ``tent``, samplers
``independent``, ``stratified``, ``multijitter``, ``orthogonal``; shapes ``rectangle``,
``cube``, ``disk``, ``sphere``, ``obj``, ``ply``, ``serialized``; BSDFs ``diffuse``, ``conductor``,
``roughconductor``, ``dielectric``, ``roughdielectric``, ``thindielectric``, ``plastic``,
``roughplastic``, ``twosided``, ``blendbsdf``, ``mask``; emitters ``area``, ``point``,
``spot``, ``directional``, ``constant``, ``envmap``; ``rgb`` values, ``spectrum`` values
(turned into RGB as Mitsuba's RGB variants turn them: ``spectra.py``), ``bitmap`` and
``checkerboard`` textures.
"""

from __future__ import annotations

import os
import re
import stat
from dataclasses import dataclass, field
from xml.parsers import expat

import numpy as np

from .text_numbers import (INT32, INT32_PROPERTIES, INT64, SPACE, ascii_lower,
                           finite_in_float32, parse_float, parse_int, split_numbers)
from .spectra import (INDEX_PROPERTIES, lone_cr_note, number_pair, read_spd,
                      spectrum_features, spectrum_list_rgb, uniform_emission_rgb)
from .transform import look_at, matrix, rotate, scale, translate

__all__ = ["SceneError", "SceneDescription", "Plugin", "load_scene", "parse_scene"]


class SceneError(ValueError):
    """A scene the path tracer cannot render as written; the message names the file,
    line, element and what is supported."""


#: Largest files read: a scene's XML, and a mesh or image it names (reading /dev/zero
#: or a runaway file would otherwise run until memory is gone).
MAX_SCENE_BYTES = 16 << 20
MAX_ASSET_BYTES = 1 << 30


def resolved_candidates(name: str, folders) -> list[str]:
    """The paths Mitsuba's file resolver tries for ``name``: itself where absolute, else
    ``folder/name`` for each of ``folders`` in turn, each path once."""
    if os.path.isabs(name):
        return [name]
    return list(dict.fromkeys(os.path.join(d, name) for d in folders))


def first_found(name: str, folders, there=os.path.exists) -> str | None:
    """The first of ``resolved_candidates`` for which ``there(path)`` holds, None where
    none does: the loader's ``<path>`` and ``<include>``, the files a scene names
    (``prepare``) and the reference's hashing (``mcverify.gate.reference``) look up
    names so, one rule for all four."""
    return next((p for p in resolved_candidates(name, folders) if there(p)), None)


def file_problem(path: str, limit: int) -> str | None:
    """Why ``path`` cannot be read as a scene file or asset (missing, not a regular file,
    larger than ``limit`` bytes), or None."""
    try:
        st = os.stat(path)
    except OSError as e:
        return f"cannot read {path} ({e.strerror})"
    if not stat.S_ISREG(st.st_mode):
        return f"{path} is not a regular file"
    if st.st_size > limit:
        return f"{path} has {st.st_size} bytes, more than the {limit >> 20} MiB limit"
    return None


@dataclass
class _Node:
    tag: str
    attrib: dict
    line: int
    children: list = field(default_factory=list)
    origin: str | None = None     # the <include>d file it came from (None: the scene's)
    #: a <spectrum>'s: the folders its ``filename`` is looked for in (``_spliced``)
    folders: list | None = None


def _parse_xml(text: str | bytes, origin: str) -> _Node:
    """A small element tree that remembers each element's line (ElementTree does not)."""
    parser = expat.ParserCreate()
    root = _Node("#document", {}, 0)
    stack = [root]

    def no_dtd(*_):  # Mitsuba scenes have no DTD; entities could expand without bound
        raise SceneError(f"{origin}:{parser.CurrentLineNumber}: a DOCTYPE or entity "
                         "declaration; scene files must not have one")

    def start(tag, attrib):
        node = _Node(tag, dict(attrib), parser.CurrentLineNumber)
        stack[-1].children.append(node)
        stack.append(node)

    def end(tag):
        stack.pop()

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.StartDoctypeDeclHandler = no_dtd
    parser.EntityDeclHandler = no_dtd
    try:
        parser.Parse(text, True)
    except expat.ExpatError as e:
        raise SceneError(f"{origin}:{e.lineno}: not well-formed XML ({expat.ErrorString(e.code)})"
                         ) from None
    if len(root.children) != 1 or root.children[0].tag != "scene":
        raise SceneError(f"{origin}:1: the root element must be <scene>")
    return root.children[0]


@dataclass
class Plugin:
    """One plugin instance: kind (``bsdf``, ``shape``...), type, properties, children."""

    kind: str
    type: str
    props: dict
    line: int
    id: str | None = None
    children: list = field(default_factory=list)
    origin: str | None = None     # the <include>d file it is declared in (None: the scene)
    #: property -> how a <spectrum> gave it (``spectrum_features``), for the coverage matrix
    spectra: dict = field(default_factory=dict)

    def get(self, name, default=None):
        return self.props.get(name, default)

    def at(self, scene_path: str) -> str:
        """``FILE:LINE`` of its element: the included file's where it was declared in one
        (a missing mesh named there was blamed on the scene file, at the included file's
        line; a read-only review)."""
        return f"{self.origin or scene_path}:{self.line}"

    def line_text(self) -> str:
        """``line N`` of its element, with its included file where it has one."""
        return f"line {self.line}" + (f" of {self.origin}" if self.origin else "")


@dataclass
class SceneDescription:
    integrator: Plugin
    sensor: Plugin
    film: Plugin
    sampler: Plugin
    shapes: list
    emitters: list
    path: str
    features: set = field(default_factory=set)
    #: the folders of the scene's ``<path value="DIR"/>`` elements, the last one first:
    #: a relative file name is looked for in each, then beside the scene (Mitsuba's file
    #: resolver)
    search: list = field(default_factory=list)


# What each plugin type accepts: property name -> allowed value kinds. Nested plugins are
# listed by kind under "children".
_TEX = ("rgb", "float", "texture")
SUPPORTED = {
    "integrator": {
        "path": {"max_depth": ("integer",), "rr_depth": ("integer",),
                 "hide_emitters": ("boolean",), "samples_per_pass": ("integer",)},
        "direct": {"hide_emitters": ("boolean",), "emitter_samples": ("integer",),
                   "bsdf_samples": ("integer",), "shading_samples": ("integer",),
                   "samples_per_pass": ("integer",)},
    },
    "sensor": {"perspective": {"fov": ("float",), "fov_axis": ("string",),
                               "focal_length": ("string",),
                               "near_clip": ("float",), "far_clip": ("float",),
                               "focus_distance": ("float",), "shutter_open": ("float",),
                               "shutter_close": ("float",),
                               "principal_point_offset_x": ("float",),
                               "principal_point_offset_y": ("float",),
                               "to_world": ("transform",), "children": ("film", "sampler")},
               "orthographic": {"near_clip": ("float",), "far_clip": ("float",),
                                "focus_distance": ("float",), "shutter_open": ("float",),
                                "shutter_close": ("float",),
                                "to_world": ("transform",), "children": ("film", "sampler")}},
    "film": {"hdrfilm": {"width": ("integer",), "height": ("integer",),
                         "pixel_format": ("string",), "file_format": ("string",),
                         "component_format": ("string",), "compensate": ("boolean",),
                         "children": ("rfilter",)}},
    "rfilter": {"box": {}, "gaussian": {"stddev": ("float",)}, "tent": {"radius": ("float",)}},
    # stratified, multijitter and orthogonal: each pixel's samples stratified per
    # dimension (the same expectation as independent ones, less variance);
    # jitter="false" is refused
    "sampler": {t: {"sample_count": ("integer",), "seed": ("integer",), **extra}
                for t, extra in {"independent": {}, "stratified": {"jitter": ("boolean",)},
                                 "multijitter": {"jitter": ("boolean",)},
                                 "orthogonal": {"jitter": ("boolean",),
                                                "strength": ("integer",)}}.items()},
    "shape": {t: {"to_world": ("transform",), "flip_normals": ("boolean",),
                  "children": ("bsdf", "emitter"), **extra}
              for t, extra in {"rectangle": {}, "cube": {}, "disk": {},
                               "sphere": {"radius": ("float",), "center": ("point",)},
                               **{mesh: {"filename": ("string",),
                                         "face_normals": ("boolean",),
                                         "flip_tex_coords": ("boolean",)}
                                  for mesh in ("obj", "ply")},
                               # Mitsuba's serialized takes no flip_tex_coords (it
                               # refuses it as unreferenced): its uv are read as stored
                               "serialized": {"filename": ("string",),
                                              "shape_index": ("integer",),
                                              "face_normals": ("boolean",)}}.items()},
    "bsdf": {
        "diffuse": {"reflectance": _TEX},
        "conductor": {"material": ("string",), "eta": ("rgb", "float"), "k": ("rgb", "float"),
                      "specular_reflectance": _TEX},
        "roughconductor": {"material": ("string",), "eta": ("rgb", "float"),
                           "k": ("rgb", "float"), "distribution": ("string",),
                           "alpha": ("float",), "alpha_u": ("float",), "alpha_v": ("float",),
                           "specular_reflectance": _TEX, "sample_visible": ("boolean",)},
        "dielectric": {"int_ior": ("float", "string"), "ext_ior": ("float", "string"),
                       "specular_reflectance": _TEX, "specular_transmittance": _TEX},
        "plastic": {"int_ior": ("float", "string"), "ext_ior": ("float", "string"),
                    "diffuse_reflectance": _TEX, "specular_reflectance": _TEX,
                    "nonlinear": ("boolean",)},
        "roughplastic": {"int_ior": ("float", "string"), "ext_ior": ("float", "string"),
                         "diffuse_reflectance": _TEX, "specular_reflectance": _TEX,
                         "distribution": ("string",), "alpha": ("float",),
                         "nonlinear": ("boolean",), "sample_visible": ("boolean",)},
        "roughdielectric": {"int_ior": ("float", "string"), "ext_ior": ("float", "string"),
                            "specular_reflectance": _TEX, "specular_transmittance": _TEX,
                            "distribution": ("string",), "alpha": ("float",),
                            "alpha_u": ("float",), "alpha_v": ("float",),
                            "sample_visible": ("boolean",)},
        "thindielectric": {"int_ior": ("float", "string"), "ext_ior": ("float", "string"),
                           "specular_reflectance": _TEX, "specular_transmittance": _TEX},
        "twosided": {"children": ("bsdf",)},
        "blendbsdf": {"weight": ("float", "texture"), "children": ("bsdf",)},
        "mask": {"opacity": ("float", "texture"), "children": ("bsdf",)},
        "normalmap": {"normalmap": ("texture",), "flip_invalid_normals": ("boolean",),
                      "use_shadowing_function": ("boolean",), "children": ("bsdf",)},
    },
    "emitter": {
        "area": {"radiance": ("rgb", "float")},
        "point": {"intensity": ("rgb", "float"), "position": ("point",),
                  "to_world": ("transform",)},
        "spot": {"intensity": ("rgb", "float"), "cutoff_angle": ("float",),
                 "beam_width": ("float",), "to_world": ("transform",)},
        "directional": {"irradiance": ("rgb", "float"), "direction": ("vector",),
                        "to_world": ("transform",)},
        "constant": {"radiance": ("rgb", "float")},
        # mis_compensation changes Mitsuba's sampling of the map, not its image: ours
        # samples it our own way
        "envmap": {"filename": ("string",), "scale": ("float",), "to_world": ("transform",),
                   "mis_compensation": ("boolean",)},
    },
    "texture": {"bitmap": {"filename": ("string",), "filter_type": ("string",),
                           "wrap_mode": ("string",), "raw": ("boolean",),
                           "to_uv": ("transform",), "format": ("string",),
                           "accel": ("boolean",)},
                # constant colours only: Mitsuba's may hold textures
                "checkerboard": {"color0": ("rgb", "float"), "color1": ("rgb", "float"),
                                 "to_uv": ("transform",)}},
}
#: Mitsuba plugins refused because Mitsuba's own image is not the one to match:
#: (kind, type) -> why, added to the refusal
UNMATCHED = {
    ("sampler", "ldsampler"): "Mitsuba 3.9.1's low-discrepancy sampler renders a biased "
                              "image: on the delta-lights scene 0.1 % brighter than its "
                              "independent, stratified, multijitter and orthogonal samplers, "
                              "at 6-10 standard errors (README)",
}
#: BSDFs with a transmission (or null) component: Mitsuba refuses them inside twosided
TRANSMISSIVE = ("dielectric", "roughdielectric", "thindielectric", "mask")
#: the attributes of each transform operation (Mitsuba's parser allows these only)
_TRANSFORM_ATTRIBUTES = {"translate": ("value", "x", "y", "z"),
                         "scale": ("value", "x", "y", "z"),
                         "rotate": ("value", "x", "y", "z", "angle"),
                         "lookat": ("origin", "target", "up"), "matrix": ("value",)}
#: BSDF properties whose <rgb> is no reflectance (complex index of refraction): Mitsuba
#: lets them leave [0, 1]
_UNBOUNDED_RGB = INDEX_PROPERTIES
#: (plugin type, property) of the numbers Mitsuba reads as textures, which take a uniform
#: <spectrum> as that number (refused by line until 7 December, an outside review);
#: others (roughplastic's alpha, an int_ior) it refuses, "has the wrong type"
_TEXTURE_NUMBERS = {(t, a) for t in ("roughconductor", "roughdielectric")
                    for a in ("alpha", "alpha_u", "alpha_v")} | {("blendbsdf", "weight"),
                                                                ("mask", "opacity")}
#: properties Mitsuba reads as a <float> or a named <string> only: its index look-up
#: refuses an <integer> ("has the wrong type (expected string, got integer)")
_NO_INTEGER = ("int_ior", "ext_ior")
_VALUE_TAGS = ("float", "integer", "boolean", "string", "rgb", "spectrum", "point", "vector",
               "transform")
#: the attributes Mitsuba's parser allows on each element (it refuses any other: a typo
#: such as ``vaule=`` would otherwise leave a default in place without a word)
_ATTRIBUTES = {"scene": ("version",), "default": ("name", "value"), "ref": ("id", "name"),
               "include": ("filename",), "path": ("value",),
               "transform": ("name",), "point": ("name", "value", "x", "y", "z"),
               "vector": ("name", "value", "x", "y", "z"),
               "spectrum": ("name", "value", "filename"),
               **{t: ("name", "value") for t in ("float", "integer", "boolean", "string", "rgb")}}
_PLUGIN_ATTRIBUTES = ("type", "id", "name")
#: children a plugin may hold one of at most (Mitsuba refuses a second: "A film can only
#: have one reconstruction filter", "Only one sampler can be specified per sensor")
_ONE_EACH = {"shape": ("bsdf", "emitter"), "sensor": ("film", "sampler"), "film": ("rfilter",)}
#: plugins a scene may declare at its top level with an id, for ``<ref>`` elsewhere; the
#: sensor's parts must then be referenced (the loader's checks run on the sensor's)
_SENSOR_PARTS = ("film", "sampler", "rfilter")
_REFERENCED = ("bsdf", "texture") + _SENSOR_PARTS
_PLUGIN_TAGS = ("integrator", "sensor", "film", "rfilter", "sampler", "shape", "bsdf",
                "emitter", "texture")


#: ``_Loader.attr``'s default: the attribute must be there
_REQUIRED = object()


class _Loader:
    def __init__(self, path: str, params: dict):
        self.path = path
        if not isinstance(params, dict):
            raise SceneError(f"{path}: params={params!r}: must be a dict of scene "
                             "parameters, {name: value}")
        for k in params:
            if not isinstance(k, str):
                # a non-string name reached the sorting of unknown names as a TypeError
                raise SceneError(f"{path}: params: the name {k!r} is not a string "
                                 f"({type(k).__name__}); a scene parameter is named as its "
                                 "<default name=...> is")
        self.params = {k: str(v) for k, v in params.items()}
        self.given = set(self.params)
        self.declared: set[str] = set()
        self.ids: dict[str, Plugin] = {}
        self.referenced: set[str] = set()      # ids some <ref> names
        # a <ref> may name a plugin declared after it, as in Mitsuba: the elements with
        # an id, each with the top-level <default>s before it (load fills them in)
        self.later: list[tuple[_Node, list]] = []
        self.search: list[str] = []            # <path> folders, the last one first
        self.done: dict[int, Plugin] = {}      # id(node) -> its plugin, once parsed
        self.by_id: dict | None = None         # later_ids(), built at the first <ref> ahead
        self.parsing: list[str] = []           # the ids being parsed, outermost first
        # area emitters declared at the top level with an id, for the one shape whose
        # <ref> attaches them (Mitsuba's own Cornell box, cbox-rgb.xml, is so written)
        self.top_nodes: set[int] = set()       # id() of the top-level elements
        self.free_area: set[int] = set()       # id() of such emitters' plugins
        self.attached: dict[str, tuple] = {}   # such an emitter's id -> (its <ref>, shape)

    def fail(self, node, message):
        raise SceneError(f"{node.origin or self.path}:{node.line}: <{node.tag}"
                         + "".join(f" {a}=\"{node.attrib[a]}\"" for a in ("type", "name")
                                   if a in node.attrib)
                         + f">: {message}")

    def check_attributes(self, node):
        """Refuse an attribute Mitsuba's parser does not allow on ``node``'s element."""
        allowed = _PLUGIN_ATTRIBUTES if node.tag in _PLUGIN_TAGS else \
            _ATTRIBUTES.get(node.tag, _TRANSFORM_ATTRIBUTES.get(node.tag))
        for a in node.attrib:
            if allowed is not None and a not in allowed:
                self.fail(node, f"unexpected attribute {a!r}; <{node.tag}> takes "
                                f"{', '.join(allowed)} (Mitsuba refuses it too)")

    def attr(self, node, name, missing=_REQUIRED):
        """Attribute ``name`` of ``node`` with $params substituted, as Mitsuba substitutes
        them in every attribute; ``missing`` where it is absent, if given (else a
        refusal naming the attribute)."""
        if name not in node.attrib:
            if missing is not _REQUIRED:
                return missing
            self.fail(node, f"missing attribute {name!r}")
        value = node.attrib[name]
        if "$" not in value:
            return value
        # Mitsuba's substitution: each parameter's "$name" replaced, the longest names
        # first ($r2 is r2's value, not r's and a 2), whatever characters the name has
        # ($max-depth, $2x; an identifier pattern took "$r-x" for "$r" and left "$2x")
        for key in sorted(self.params, key=len, reverse=True):
            if "$" + key in value:
                self.declared.add(key)
                value = value.replace("$" + key, self.params[key])
        if "$" in value:
            key = re.search(r"\$([A-Za-z0-9_-]*)", value).group(1)
            self.fail(node, f"${key} has no value: add <default name=\"{key}\" .../> or "
                            "pass it as a parameter" if key else
                      f"{node.attrib[name]!r}: a '$' that names no parameter")
        return value

    def numbers(self, node, text, count, broadcast=True):
        """``count`` numbers of ``text`` as Mitsuba reads them; with ``broadcast``, one
        number stands for all three of a triple (an <rgb>, a point, a translate), which a
        <lookat>'s origin, target and up do not take (Mitsuba: "expected 3 values in
        vector"; a read-only review found origin="5" taken as (5, 5, 5))."""
        broadcast = broadcast and count == 3
        want = ("a number" if count == 1 else "3 numbers, or one for all three"
                if broadcast else f"{count} numbers")
        # one number is the value alone (padded by ASCII spaces): Mitsuba refuses
        # "0.5," and ",0.5" for a <float>, though a list's tokenizer skips empty items
        tokens = [text.strip(SPACE)] if count == 1 else split_numbers(text)
        try:
            vals = [parse_float(t) for t in tokens]
        except ValueError:
            self.fail(node, f"expected {want}, got {text!r}")
        if len(vals) == 1 and broadcast:
            vals = vals * 3
        if len(vals) != count:
            self.fail(node, f"expected {want}, got {text!r}")
        if not all(np.isfinite(vals)):
            self.fail(node, f"expected {'a finite number' if count == 1 else 'finite numbers'}"
                            f", got {text!r}")
        if not finite_in_float32(vals):
            # Mitsuba loads it as inf (a sphere of radius 1e39 had an invalid bounding box)
            self.fail(node, f"{text!r} is beyond float32's range (|x| < 3.4e38), in which "
                            "Mitsuba holds scene values: it would be infinite there")
        return np.array(vals)

    def value(self, node):
        tag = node.tag
        if tag == "float":
            return "float", float(self.numbers(node, self.attr(node, "value"), 1)[0])
        if tag == "integer":
            text = self.attr(node, "value")
            try:
                n = parse_int(text.strip(SPACE))
            except ValueError:
                self.fail(node, f"expected an integer, got {text!r}")
            if not INT64[0] <= n <= INT64[1]:
                self.fail(node, f"{text!r} is outside the 64-bit integers Mitsuba reads")
            name = self.attr(node, "name", None)
            if name in INT32_PROPERTIES and not INT32[0] <= n <= INT32[1]:
                self.fail(node, f"{text!r} is outside the 32-bit integers Mitsuba takes for "
                                f"{name} [{INT32[0]}, {INT32[1]}]")
            return "integer", n
        if tag == "boolean":
            # any case, no padding: Mitsuba refuses " true" (its numbers may be padded)
            text = self.attr(node, "value")
            if ascii_lower(text) not in ("true", "false"):
                self.fail(node, f"expected true or false, got {text!r}")
            return "boolean", ascii_lower(text) == "true"
        if tag == "string":
            return "string", self.attr(node, "value")
        if tag == "rgb":
            return "rgb", self.numbers(node, self.attr(node, "value"), 3)
        if tag == "spectrum":
            return "spectrum", self.spectrum(node)
        if tag in ("point", "vector"):
            # value, or all three coordinates, as Mitsuba requires (translate/scale/rotate
            # default the ones left out; a point or vector does not)
            return tag, self._xyz(node, None)
        if tag == "transform":
            return "transform", self.transform(node)
        self.fail(node, "unsupported value type")

    def spectrum(self, node):
        """A ``<spectrum>``'s uniform value (a float), or its wavelengths and values (two
        arrays), from ``value`` or from the file ``filename`` names, as Mitsuba's parser
        takes them: one of the two; a single number, or ``wavelength:value`` pairs
        separated by commas or spaces, at least two, the wavelengths increasing."""
        text, name = self.attr(node, "value", ""), self.attr(node, "filename", "")
        if (text == "") == (name == ""):
            self.fail(node, "a <spectrum> takes value=\"...\" or filename=\"...\", one of "
                            "the two (Mitsuba refuses both, or neither, too)")
        if name:
            folders = node.folders or [os.path.dirname(self.path)]
            path = first_found(name, folders) or os.path.join(folders[-1], name)
            problem = file_problem(path, MAX_SCENE_BYTES)
            read = problem or read_spd(path)
            if isinstance(read, str):
                self.fail(node, read if problem else f"spectrum file {path}: {read}")
            wavelengths, values = read
        else:
            tokens = split_numbers(text)
            if len(tokens) == 1 and ":" not in tokens[0]:
                return float(self.numbers(node, text, 1)[0])
            wavelengths, values = [], []
            for token in tokens:
                pair = number_pair([t for t in token.split(":") if t])
                if pair is None:
                    self.fail(node, f"expected wavelength:value pairs (e.g. \"400:0.1, "
                                    f"700:0.9\") or one number, got {token!r}")
                wavelengths.append(pair[0])
                values.append(pair[1])
        where = f"spectrum file {name!r}" if name else "spectrum"
        if len(wavelengths) < 2:
            self.fail(node, f"{where}: {len(wavelengths)} wavelength:value pair(s); a "
                            "spectrum needs at least two (Mitsuba refuses it too)"
                            + (lone_cr_note(path) if name else ""))
        if not (np.all(np.isfinite(wavelengths)) and np.all(np.isfinite(values))):
            self.fail(node, f"{where}: expected finite numbers")
        if not np.all(np.diff(wavelengths) > 0):
            self.fail(node, f"{where}: the wavelengths must increase (Mitsuba refuses it "
                            "too)")
        return np.array(wavelengths), np.array(values)

    def spectrum_value(self, node, plugin, name, allowed, spectrum):
        """A ``<spectrum>`` as the ``<rgb>`` or ``<float>`` Mitsuba's RGB variants make of
        it for property ``name`` of a ``plugin`` (kind, type; ``spectra.py``): an
        emitter's radiance, irradiance or intensity is an emission, ``eta`` and ``k``
        unbounded indices, the rest reflectances; a uniform one is a number where
        Mitsuba reads a number as a texture (``_TEXTURE_NUMBERS``)."""
        emitter = plugin[0] == "emitter"
        if "rgb" not in allowed:
            if isinstance(spectrum, float) and (plugin[1], name) in _TEXTURE_NUMBERS:
                return "float", spectrum
            self.fail(node, f"property {name!r} takes {' or '.join(allowed)}, not a spectrum"
                            + (" of wavelength:value pairs" if (plugin[1], name) in
                               _TEXTURE_NUMBERS else ""))
        if isinstance(spectrum, float) and not emitter:
            return "float", spectrum        # every property that takes an rgb takes one
        rgb = uniform_emission_rgb(spectrum) if isinstance(spectrum, float) else \
            spectrum_list_rgb(*spectrum, emitter=emitter, unbounded=name in _UNBOUNDED_RGB)
        if not finite_in_float32(rgb):
            # as an <rgb> beyond it: Mitsuba holds the colour in float32, as inf
            self.fail(node, f"the spectrum's RGB, {', '.join(f'{v:g}' for v in rgb)}, is "
                            "beyond float32's range (|x| < 3.4e38), in which Mitsuba holds "
                            "scene values: it would be infinite there")
        return "rgb", rgb

    def transform(self, node):
        m = np.eye(4)
        for op in node.children:
            self.check_attributes(op)     # Mitsuba refuses others (a typo, not a default)
            try:
                if op.tag == "lookat":
                    def triple(k):
                        return self.numbers(op, self.attr(op, k), 3, broadcast=False)
                    t = look_at(triple("origin"), triple("target"),
                                triple("up") if "up" in op.attrib else None)
                elif op.tag == "translate":
                    t = translate(self._xyz(op, 0.0))
                elif op.tag == "scale":
                    t = scale(self._xyz(op, 1.0))
                elif op.tag == "rotate":
                    axis = self._xyz(op, 0.0)
                    t = rotate(axis, self.numbers(op, self.attr(op, "angle"), 1)[0])
                elif op.tag == "matrix":
                    # 16 values, or 9: a linear part (Mitsuba's parser takes both)
                    text = self.attr(op, "value")
                    count = len(split_numbers(text))
                    if count not in (9, 16):
                        self.fail(op, f"expected 16 numbers (a 4x4 matrix) or 9 (its linear "
                                      f"part, 3x3), got {count}: {text!r}")
                    t = matrix(self.numbers(op, text, count))
                else:
                    self.fail(op, "unsupported transform operation; supported: lookat, "
                                  "translate, rotate, scale, matrix")
            except SceneError:
                raise
            except ValueError as e:     # a degenerate transform (zero axis, up ∥ view)
                self.fail(op, str(e))
            m = t @ m
        return m

    def _check_invertible(self, node, m):
        """Refuse a shape's or emitter's singular ``to_world`` (it flattens the object to a
        plane, a line or a point: its normals, the inverse transpose, are undefined; a
        camera's is the camera's to judge: ``camera.py``)."""
        sv = np.linalg.svd(m[:3, :3], compute_uv=False)
        if not sv[-1] > 1e-12 * sv[0]:
            self.fail(node, f"to_world is singular (its linear part's singular values "
                            f"{', '.join(f'{v:.3g}' for v in sv)}): it flattens the object "
                            "and leaves its normals undefined; give it a nonzero scale on "
                            "every axis")

    def _xyz(self, op, default):
        """``value`` or x, y, z; a coordinate left out is ``default`` (None: required)."""
        if "value" in op.attrib and any(k in op.attrib for k in "xyz"):
            # Mitsuba: 'Cannot mix "value" and "x"/"y"/"z" attributes' (a <point> or
            # <vector> took the value and ignored x, y, z)
            self.fail(op, "give either value or x/y/z, not both (Mitsuba refuses both too)")
        if "value" in op.attrib:
            return self.numbers(op, self.attr(op, "value"), 3)
        return np.array([self.numbers(op, self.attr(op, k), 1)[0]
                         if k in op.attrib or default is None else default for k in "xyz"])

    def plugin(self, node, kind=None):
        if id(node) in self.done:       # parsed already, for a <ref> before it
            return self.done[id(node)]
        kind = kind or node.tag
        if kind not in SUPPORTED:
            self.fail(node, f"unsupported element; supported: {', '.join(_PLUGIN_TAGS)}")
        self.check_attributes(node)
        ptype = self.attr(node, "type")
        spec = SUPPORTED[kind].get(ptype)
        if spec is None:
            why = UNMATCHED.get((kind, ptype))
            self.fail(node, f"unsupported {kind} type {ptype!r}{f' ({why})' if why else ''}; "
                            f"supported: {', '.join(sorted(SUPPORTED[kind]))}")
        # $params are substituted in every attribute, the id too, as Mitsuba does
        p = Plugin(kind, ptype, {}, node.line, self.attr(node, "id", None),
                   origin=node.origin)
        if (kind, ptype) == ("emitter", "area") and id(node) in self.top_nodes:
            self.free_area.add(id(p))
        self.parsing.append(p.id)
        try:
            self._fill(node, kind, ptype, spec, p)
        finally:
            self.parsing.pop()
        if p.id:
            if p.id in self.ids:
                self.fail(node, f"id {p.id!r} is already used by the <{self.ids[p.id].kind}> "
                                f"on {self.ids[p.id].line_text()} (Mitsuba refuses a "
                                "duplicate id too)")
            self.ids[p.id] = p
            self.done[id(node)] = p
        return p

    def _fill(self, node, kind, ptype, spec, p):
        """``p``'s properties and children from ``node``'s, checked against ``spec``."""
        allowed_children = spec.get("children", ())

        def set_prop(child, name, val):
            if name in p.props:     # Mitsuba: 'specified multiple times'
                self.fail(child, f"property {name!r} is given twice in this {kind}; give "
                                 "it once (Mitsuba refuses it too)")
            p.props[name] = val

        for child in node.children:
            if child.tag == "spectrum" and "type" in child.attrib:
                self.fail(child, "spectrum plugins (<spectrum type=...>: blackbody, d65, "
                                 "...) are not supported; give wavelength:value pairs, a "
                                 "file of them, or an <rgb>")
            if child.tag in _VALUE_TAGS or child.tag == "ref":
                self.check_attributes(child)
            if child.tag in _VALUE_TAGS:
                name = self.attr(child, "name")
                vkind, val = self.value(child)
                if name not in spec or name == "children":
                    # unsupported, not absent: Mitsuba's hdrfilm has crop_offset_x, and
                    # "has no property" read as a typo in a scene Mitsuba renders
                    known = ", ".join(k for k in sorted(spec) if k != "children")
                    self.fail(child, f"{kind} {ptype!r}: unsupported property {name!r}; "
                                     f"supported: {known or 'none'}")
                if vkind == "spectrum":
                    p.spectra[name] = spectrum_features(kind, name, val,
                                                        "filename" in child.attrib)
                    vkind, val = self.spectrum_value(child, (kind, ptype), name, spec[name],
                                                     val)
                if vkind == "integer" and "integer" not in spec[name] and \
                        "float" in spec[name] and name not in _NO_INTEGER:
                    vkind, val = "float", float(val)    # Mitsuba reads an integer as a float
                if vkind not in spec[name]:
                    hint = (f" (Mitsuba refuses it too: write <float name=\"{name}\" "
                            f"value=\"{val}\"/>)" if name in _NO_INTEGER else "")
                    self.fail(child, f"property {name!r} takes {' or '.join(spec[name])}, "
                                     f"not {vkind}{hint}")
                # a BSDF's colours and a checkerboard's (only a BSDF's colour properties
                # take one) are reflectances
                reflectance = kind == "bsdf" or (kind, ptype) == ("texture", "checkerboard")
                if reflectance and vkind == "rgb" and name not in _UNBOUNDED_RGB and \
                        not np.all((val >= 0.0) & (val <= 1.0)):
                    # Mitsuba reads a BSDF's <rgb> as an sRGB reflectance
                    self.fail(child, f"an RGB reflectance must lie in [0, 1], got "
                                     f"{', '.join(f'{v:g}' for v in val)} (Mitsuba refuses "
                                     "it too; a <float> may exceed 1)")
                if reflectance and vkind == "float" and "rgb" in spec[name] and \
                        name not in _UNBOUNDED_RGB and val < 0.0:
                    # Mitsuba carries a negative albedo through the path (a sphere's
                    # block came out -0.15); the tracer ends such a path
                    self.fail(child, f"{name} = {val:g}: a reflectance or transmittance "
                                     "must be >= 0 (Mitsuba renders a negative one as a "
                                     "negative albedo, which this tracer does not)")
                if vkind == "transform" and name == "to_world" and kind in ("shape", "emitter"):
                    self._check_invertible(child, val)
                set_prop(child, name, val)
            elif child.tag == "ref":
                target = self.attr(child, "id")
                if target not in self.ids:
                    self.declared_later(child, target)
                ref = self.ids[target]
                self.referenced.add(target)
                if ref.kind == "texture":
                    # a texture is a property value: <ref id="..." name="reflectance"/>
                    name = self.attr(child, "name", None)
                    if name is None or name not in spec or "texture" not in spec[name]:
                        self.fail(child, f"texture {target!r} needs name=\"...\" naming a "
                                         f"property of {kind} {ptype!r} that takes a texture")
                    set_prop(child, name, ref)
                    continue
                if ref.kind not in allowed_children:
                    self.fail(child, f"a {ref.kind} cannot go inside {kind} {ptype!r}")
                if ref.kind == "emitter" and ref.type == "area":
                    self.attach(child, target, ref, p)
                p.children.append(ref)
            elif child.tag == "texture":
                name = self.attr(child, "name")
                if name not in spec or "texture" not in spec[name]:
                    self.fail(child, _no_texture(kind, ptype, name, spec))
                set_prop(child, name, self.plugin(child))
            elif child.tag in _PLUGIN_TAGS:
                if child.tag not in allowed_children:
                    self.fail(child, f"a <{child.tag}> cannot go inside {kind} {ptype!r}")
                p.children.append(self.plugin(child))
            else:
                self.fail(child, f"unsupported element inside {kind} {ptype!r}; supported: "
                                 f"{', '.join(_VALUE_TAGS)}, ref, texture and nested "
                                 "plugins")
        for what in _ONE_EACH.get(kind, ()):
            if sum(c.kind == what for c in p.children) > 1:
                self.fail(node, f"more than one {what} in one {kind} (Mitsuba refuses it "
                                f"too){'; give each its own shape' if kind == 'shape' else ''}")
        if kind == "sampler" and "seed" in p.props and \
                not 0 <= p.props["seed"] <= 2 ** 32 - 1:
            self.fail(node, f"seed {p.props['seed']}: must lie in [0, 4294967295] (Mitsuba "
                            "refuses it too)")
        if kind == "shape":
            for c in p.children:
                if c.kind == "emitter" and c.type != "area":
                    # Mitsuba keeps such a light as it is (a point light at its own
                    # position, not the shape's surface); rendering the shape as an
                    # area light instead would be silently wrong
                    self.fail(node, f"a {c.type!r} emitter inside a shape ({c.line_text()}): "
                                    "only an area emitter makes a shape emit; put a "
                                    f"{c.type} light at the top level of the scene")

    def attach(self, ref, target, emitter, shape):
        """Attach the area emitter ``emitter`` (id ``target``) to ``shape``, whose ``<ref>``
        is ``ref``: one declared at the top level, to one shape, as Mitsuba does (it was
        refused as "must be inside a <shape>", and Mitsuba's cbox-rgb.xml with it).
        Mitsuba refuses a second shape ("An endpoint can be only be attached to a single
        shape"); the loader made both shapes emit until 6 December."""
        if id(emitter) not in self.free_area:
            self.fail(ref, f"area emitter {target!r} ({emitter.line_text()}) already "
                           "belongs to the shape it is declared in; an emitter is attached "
                           "to one shape only (Mitsuba refuses it too): give this shape its "
                           "own <emitter type=\"area\">")
        if target in self.attached:
            first, holder = self.attached[target]
            if holder is shape:     # "already attached to the shape of the <ref> on line N"
                # named this very shape (two reviews)
                self.fail(ref, f"a second <ref> to area emitter {target!r} in this shape "
                               f"(the first on line {first.line}); a shape holds one "
                               "emitter (Mitsuba refuses a second too)")
            self.fail(ref, f"area emitter {target!r} ({emitter.line_text()}) is already "
                           f"attached to the shape of the <ref> on line {first.line}"
                           f"{f' of {first.origin}' if first.origin else ''}; an emitter is "
                           "attached to one shape only (Mitsuba refuses it too): give this "
                           "shape its own <emitter type=\"area\">")
        self.attached[target] = (ref, shape)

    def declared_later(self, ref, target):
        """Parse the plugin of id ``target`` that the document declares after ``ref``
        (Mitsuba resolves references once the whole file is read), with the parameters
        of the <default>s before it; refuse a cycle or an id nowhere declared."""
        if target in self.parsing:
            cycle = [i for i in self.parsing[self.parsing.index(target):] if i] + [target]
            self.fail(ref, f"circular reference {' -> '.join(cycle)}: a plugin cannot "
                           "contain itself (Mitsuba refuses it too)")
        if target not in self.later_ids():
            self.fail(ref, f"no object with id {target!r}: no element of the scene has "
                           f"id=\"{target}\" (Mitsuba refuses it too)")
        node, defaults = self.later_ids()[target]
        self.with_defaults(defaults, lambda: self.plugin(node))

    def later_ids(self) -> dict:
        """id -> (element, the <default>s before it), for every plugin element with an
        id (the first of each id), its $params substituted as at its place."""
        if self.by_id is None:
            self.by_id = {}
            for node, defaults in self.later:
                key = node.attrib["id"]
                if "$" in key:
                    key = self.with_defaults(defaults, lambda: self.attr(node, "id"))
                self.by_id.setdefault(key, (node, defaults))
        return self.by_id

    def with_defaults(self, defaults, f):
        """``f()`` with the parameters as they are after ``defaults`` (the <default>s
        before an element declared further on), then as they were."""
        saved = self.params
        self.params = dict(saved)
        try:
            for d in defaults:
                self.default(d)
            return f()
        finally:
            self.params = saved

    def default(self, node):
        """A top-level ``<default>``: its parameter, unless the caller gave it."""
        self.check_attributes(node)
        name = self.attr(node, "name")
        self.declared.add(name)
        # its value may use the parameters before it, as in Mitsuba
        # (<default name="height" value="$res"/>; it was taken as "$res"); Mitsuba
        # requires the value, given by the caller or not (one without was taken as "")
        value = self.attr(node, "value")
        self.params.setdefault(name, value)

    def index_ids(self, root):
        """Every plugin element with an id, in document order, with the top-level
        <default>s before it, for a <ref> that names a plugin declared after it."""
        defaults = []
        for top in root.children:
            if top.tag == "default":
                defaults.append(top)
                continue
            stack = [top]
            while stack:
                node = stack.pop()
                if node.tag in _PLUGIN_TAGS and "id" in node.attrib:
                    self.later.append((node, list(defaults)))
                stack += reversed(node.children)

    def include_all(self, root):
        """Each top-level ``<include filename=...>`` replaced by the top-level elements of
        the scene file it names, in place, as Mitsuba reads it (until 7 December refused
        by line): a file's includes are found beside it first, then beside the scene;
        the included file is a whole ``<scene>`` with its version; a ``$param`` in the
        name takes the ``<default>``s before it. Files its elements name (meshes,
        textures) are found against the scene's own folder, as Mitsuba finds them.

        Mitsuba's file resolver is modelled by ``resolver``, the folders a name is looked
        for in, in order: the scene's folder; a ``<path value="DIR"/>`` (``search_folder``)
        puts DIR first, and is taken out of the elements; an included file is read with a
        copy that has its own folder first, dropped after it, so that its ``<path>``s
        serve its own includes only. The scene's own ``<path>`` folders are where the
        files its elements name are looked for first (``SceneDescription.search``)."""
        scene = os.path.realpath(self.path) if os.path.isfile(self.path) else self.path
        resolver = [os.path.dirname(self.path)]
        root.children = self._spliced(root.children, resolver, [scene], [])
        self.search = resolver[:-1]

    def _spliced(self, children, resolver, chain, defaults, own=None):
        """``children`` with their includes read in place. ``resolver``: the folders
        names are looked for in; ``own``: where in it the folder of an included file
        stands (None: the scene's), which serves that file's includes only."""
        out = []
        for node in children:
            if node.tag == "default":
                defaults.append(node)
            if node.tag == "path":
                resolver.insert(0, self.search_folder(node, resolver, defaults))
                own = None if own is None else own + 1
                continue
            if node.tag != "include":
                # a <spectrum filename> is read as Mitsuba parses it, with the resolver as
                # it stands there: the <path>s before it in its file, then the folders
                # its file was included with (where the file is found, not beside it)
                _mark_spectra(node, parse_time_folders(resolver, own))
                out.append(node)
                continue
            self.check_attributes(node)
            name = self.with_defaults(defaults, lambda: self.attr(node, "filename"))
            full = self.included_file(node, name, resolver)
            real = os.path.realpath(full)
            if real in chain:
                self.fail(node, f"{name!r} includes itself ({' -> '.join(chain + [real])}; "
                                "Mitsuba stops there too)")
            sub = _read_scene(full)
            stack = [sub]
            while stack:                # its elements' messages name its file
                n = stack.pop()
                n.origin = full
                stack += n.children
            self.check_root(sub)
            out += self._spliced(sub.children, [os.path.dirname(full)] + resolver,
                                 chain + [real], defaults, own=0)
        return out

    def search_folder(self, node, resolver, defaults):
        """The folder a top-level ``<path value="DIR"/>`` adds to the places file names are
        looked for (Mitsuba's own documentation scenes start with ``<path
        value="../../common"/>``; refused by line until 7 December): DIR as given where
        absolute, else against the folder of the file it is in, else against each of
        ``resolver`` (Mitsuba's order); a folder that is not there is refused, as Mitsuba
        refuses it. (Until a read-only review the folder "of the file" was the previous
        ``<path>``'s once there was one: ``<path value="a"/><path value="b"/>`` took
        ``a/b`` where both it and ``b`` were there, and Mitsuba ``b``.)"""
        self.check_attributes(node)
        value = self.with_defaults(defaults, lambda: self.attr(node, "value"))
        folders = [os.path.dirname(node.origin or self.path)] + resolver
        found = first_found(value, folders, os.path.isdir)
        if found is not None:
            return os.path.abspath(found)
        self.fail(node, f"folder {value!r} not found (looked for "
                        f"{' and '.join(resolved_candidates(value, folders))}; Mitsuba "
                        "refuses it too)")

    def included_file(self, node, name, resolver):
        """The file an ``<include>`` names: as given where absolute, else in each folder of
        ``resolver`` in turn (``_spliced``): the ``<path>`` folders read before it in the
        same file, the last one first, then beside the file that includes it, then as the
        file that included that one looked (Mitsuba 3.9's order: a nested include of
        ``more.xml`` in ``sub/parts.xml`` is ``sub/more.xml`` where that exists)."""
        found = first_found(name, resolver, os.path.isfile)
        if found is not None:
            return found
        self.fail(node, f"included file {name!r} not found (looked for "
                        f"{' and '.join(resolved_candidates(name, resolver))})")

    def check_root(self, root):
        """A ``<scene>`` element's attributes and version, the scene's or an included
        file's."""
        self.check_attributes(root)
        version = self.attr(root, "version")    # Mitsuba requires it too
        if not re.fullmatch(r"[0-9]+\.[0-9]+\.[0-9]+", version.strip(SPACE)):
            self.fail(root, f"version {version!r}: expected major.minor.patch, e.g. 3.0.0")
        if int(version.split(".")[0]) < 2:
            self.fail(root, f"version {version!r}: Mitsuba rewrites scenes older than 2.0.0 "
                            "(camelCase names, diffuse_reflectance, uoffset/uscale); not "
                            "supported here: write it for Mitsuba 3 (version=\"3.0.0\")")

    def load(self, root) -> SceneDescription:
        self.check_root(root)
        self.include_all(root)
        integrator = sensor = None
        shapes, emitters, declared, free = [], [], [], []
        self.index_ids(root)
        self.top_nodes = {id(node) for node in root.children}
        for node in root.children:
            if node.tag == "default":
                self.default(node)
            elif node.tag == "integrator":
                if integrator is not None:
                    self.fail(node, "a second <integrator>; a scene has one (Mitsuba refuses "
                                    "a second too)")
                integrator = self.plugin(node)
            elif node.tag == "sensor":
                # Mitsuba renders the first sensor unless told otherwise
                first = self.plugin(node)
                sensor = sensor or first
            elif node.tag == "shape":
                shapes.append(self.plugin(node))
            elif node.tag == "emitter":
                if self.attr(node, "type", None) == "area":
                    if self.attr(node, "id", None) is None:
                        self.fail(node, "an area emitter must be inside a <shape>, or have "
                                        "an id that one shape's <ref> names")
                    free.append((node, self.plugin(node)))     # its shape's <ref> takes it
                    continue
                emitters.append(self.plugin(node))
            elif node.tag in _REFERENCED:
                # declared once, used by <ref id=.../> (a sensor's film and sampler, a
                # film's rfilter, as Mitsuba's own test scenes write them)
                # one without an id is never used, as Mitsuba builds and ignores it (a
                # BSDF or texture; it was refused, "needs an id to be referenced")
                p = self.plugin(node)
                if p.kind in _SENSOR_PARTS:
                    declared.append((node, p))
            else:
                self.fail(node, "unsupported top-level element; supported: default, "
                                "integrator, sensor, shape, emitter, " + ", ".join(_REFERENCED))
        if sensor is None:
            self.fail(root, "the scene has no <sensor>")
        for node, p in free:
            if p.id not in self.attached:
                # Mitsuba drops it without a word: no light where the scene meant one
                self.fail(node, f"area emitter {p.id!r} is attached to no shape: no <shape> "
                                f"holds <ref id=\"{p.id}\"/> (Mitsuba drops it and renders "
                                "no light); reference it from the shape that emits")
        for node, p in declared:
            if p.id is None:
                self.fail(node, f"a top-level {p.kind} without an id is never used (a "
                                "sensor's parts are checked here as the sensor uses them); "
                                "remove it, or give it an id and reference it")
            if p.id not in self.referenced:
                # Mitsuba builds it anyway (and refuses it where it is invalid); the
                # checks here run on the sensor's film and sampler only
                self.fail(node, f"{p.kind} {p.id!r} is never used: no <ref id=\"{p.id}\"/> "
                                "names it; remove it or reference it")
        unknown = sorted(self.given - self.declared)
        if unknown:
            raise SceneError(f"{self.path}: params {unknown}: the scene has no such "
                             f"parameter (it has: {', '.join(sorted(self.declared)) or 'none'})")
        integrator = integrator or Plugin("integrator", "path", {}, root.line)
        film = next((c for c in sensor.children if c.kind == "film"), None) or \
            Plugin("film", "hdrfilm", {}, sensor.line)
        if not any(c.kind == "rfilter" for c in film.children):
            # Mitsuba's default reconstruction filter
            film.children.append(Plugin("rfilter", "gaussian", {}, film.line))
        sampler = next((c for c in sensor.children if c.kind == "sampler"), None) or \
            Plugin("sampler", "independent", {}, sensor.line)
        desc = SceneDescription(integrator, sensor, film, sampler, shapes, emitters, self.path,
                                search=list(self.search))
        desc.features = _features(desc)
        return desc


def _features(desc: SceneDescription) -> set[str]:
    """What the scene uses, for specialising the kernel and planning checks."""
    feats = {f"integrator:{desc.integrator.type}"}
    for s in desc.shapes:
        feats.add(f"shape:{s.type}")
        if not any(c.kind == "bsdf" for c in s.children):
            # Mitsuba's default BSDF (diffuse 0.5, black on an emitting shape), which the
            # tracer samples as any diffuse
            feats.add("bsdf:diffuse")
        for c in s.children:
            if c.kind == "bsdf":
                stack = [c]
                while stack:
                    b = stack.pop()
                    feats.add(f"bsdf:{b.type}")
                    stack += [x for x in b.children if x.kind == "bsdf"]
                    feats |= {f"texture:{v.type}" for v in b.props.values()
                              if isinstance(v, Plugin)}
            elif c.kind == "emitter":
                feats |= {"emitter:area", f"emitter:area:{s.type}"}
    feats |= {f"emitter:{e.type}" for e in desc.emitters}
    return feats


def parse_scene(text: str | bytes, *, path: str = "<string>", params: dict | None = None
                ) -> SceneDescription:
    """Parse scene XML text, or a file's bytes in the encoding its BOM or XML declaration
    names (``params`` override ``<default>`` values)."""
    if not isinstance(text, (str, bytes)):
        raise TypeError(f"text: expected the scene's XML as str or bytes (load_scene reads "
                        f"a file), got {type(text).__name__}")
    return _Loader(path, params or {}).load(_parse_xml(text, path))


def load_scene(path: str, *, params: dict | None = None) -> SceneDescription:
    """Parse a Mitsuba XML scene file (``path``: a str, bytes or ``os.PathLike``)."""
    path = scene_path(path, "path")
    desc = _Loader(path, params or {}).load(_read_scene(path))
    desc.path = os.path.abspath(path)
    return desc


def scene_path(value, name: str, also: str = "") -> str:
    """``value`` as a scene file's path: a str, an ``os.PathLike`` or bytes (decoded as
    the file system does); else TypeError naming ``name`` (``also``: what else it may
    be). None raised os.stat's TypeError, naming nothing, and an int was taken as a file
    descriptor, read and closed (an outside review); bytes reached ``str()`` as
    "b'scene.xml'" in ``prepare_scene`` and ``render``."""
    if isinstance(value, (str, bytes, os.PathLike)):
        return os.fsdecode(value)
    raise TypeError(f"{name}: expected a scene file's path (str or os.PathLike{also}), "
                    f"got {type(value).__name__}")


def parse_time_folders(resolver: list, own: int | None) -> list:
    """The folders Mitsuba's resolver holds while it parses an element (a ``<spectrum
    filename>`` is read then): ``resolver``, the folders an ``<include>`` there is looked
    for in, without the folder of the included file being read, at ``own``, which serves
    that file's includes only (None: the scene, whose folder is in Mitsuba's resolver
    too). The
    loader (``_spliced``) and the reference's hashing (``mcverify.gate.reference``)
    both read spectrum files so."""
    return list(resolver) if own is None else resolver[:own] + resolver[own + 1:]


def _mark_spectra(node: _Node, folders: list) -> None:
    """Give each ``<spectrum>`` in ``node``'s tree the folders its file is looked for in."""
    stack = [node]
    while stack:
        n = stack.pop()
        if n.tag == "spectrum":
            n.folders = list(folders)
        stack += n.children


def _read_scene(path: str) -> _Node:
    """The ``<scene>`` element of the XML file ``path`` (a scene, or a file it includes),
    or SceneError naming the file."""
    problem = file_problem(path, MAX_SCENE_BYTES)
    if problem:
        raise SceneError(problem)
    try:
        # bytes: expat reads the encoding from the BOM or the XML declaration, as
        # Mitsuba's parser does (a UTF-16 or ISO-8859-1 scene was "cannot read")
        with open(path, "rb") as f:
            text = f.read(MAX_SCENE_BYTES + 1)
    except OSError as e:
        raise SceneError(f"{path}: cannot read ({e.strerror or e})") from None
    return _parse_xml(text, path)


def _no_texture(kind: str, ptype: str, name: str, spec: dict) -> str:
    """The refusal of a texture where the tracer takes none (Mitsuba may: a conductor's
    ``eta``; 'takes no texture' read as if Mitsuba refused it too, an outside review)."""
    takes = sorted(p for p, kinds in spec.items() if p != "children" and "texture" in kinds)
    where = (f"; give a constant value (textures are supported on {', '.join(takes)})"
             if takes else "; give a constant value")
    return f"property {name!r} of {kind} {ptype!r}: a texture is not supported there{where}"
