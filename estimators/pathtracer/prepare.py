"""Scene description → the named arrays the kernel reads (``PreparedScene``, whose
``arrays`` is a ``layout.SceneArrays``). Nothing is compiled here: numba compiles the
kernel in ``render``.

Shapes become primitives (rectangles and cubes two triangles a face, OBJ, PLY and
serialized meshes their triangles; spheres and disks stay analytic), BSDFs and emitters
become rows of parameter tables, images become one texture store, and the whole is
indexed by the SAH hierarchy.
Mitsuba's defaults apply wherever the XML is silent (a shape without a BSDF is diffuse
0.5, or black if it emits; roughconductor and roughplastic default to Beckmann α = 0.1;
dielectric to BK7 in air; plastic to polypropylene in air; conductor to a perfect mirror).
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import os
from dataclasses import dataclass, field

import numpy as np

from ..distributions import DiscreteDistribution, PiecewiseConstant2D
from . import layout
from .bsdfs import fresnel_diffuse_reflectance, rough_coat_tables
from .camera import Camera, camera_from_scene
from .geometry import build_bvh, pack_bvh
from .layout import DISK, FEATURE_BITS, INFINITE_DEPTH, PRIM_WIDTH, SPHERE, TRIANGLE
from .meshes import read_ply, read_serialized
from .scene import (MAX_ASSET_BYTES, TRANSMISSIVE, Plugin, SceneDescription, SceneError,
                    file_problem, first_found, load_scene, scene_path)
from .text_numbers import (FLOAT32_OVERFLOW, SPACE, ascii_lower, finite_in_float32,
                           parse_float, parse_int, split_words)
from .textures import (TextureStore, envmap_sampling_weights, luminance,
                       non_finite_texels, read_image)

_MATERIALS = None


def _materials() -> dict:
    global _MATERIALS
    if _MATERIALS is None:
        with open(os.path.join(os.path.dirname(__file__), "materials.json"),
                  encoding="utf-8") as f:
            _MATERIALS = json.load(f)
    return _MATERIALS


@dataclass
class PreparedScene:
    """Everything the kernel needs, as named arrays, plus what a person needs to know.
    ``features`` is the mask of ``layout.FEATURE_BITS`` the scene uses."""

    desc: SceneDescription
    camera: Camera
    arrays: layout.SceneArrays
    features: int
    spp: int
    n_triangles: int
    n_lights: int
    bsdf_names: list = field(default_factory=list)
    #: ``FILE:LINE`` of each BSDF row's element ("": Mitsuba's default diffuse) and of
    #: each light's <emitter>, in the scene or the file it includes, for messages that
    #: point into the file
    bsdf_lines: list = field(default_factory=list)
    light_lines: list = field(default_factory=list)

    @property
    def width(self) -> int:
        return self.camera.width

    def planted(self, *, light_scale: float = 1.0, albedo_scale: float = 1.0,
                bsdf: int | None = None, texture_filter: str | None = None,
                texture_raw: bool = False, camera_extent: float = 1.0,
                filter_scale: float = 1.0, bsdf_scale: tuple | None = None,
                swap_alpha_uv: bool = False, frame_ignored: bool = False,
                normalmap_ignored: bool = False,
                checkerboard_swapped: bool = False,
                tex_coords_unflipped: bool = False) -> "PreparedScene":
        """A copy with a planted bug, for testing the render gate: every emitter's
        radiance/intensity scaled by ``light_scale``; BSDF ``bsdf``'s (default: the
        first textureless diffuse-like one) base colour scaled by ``albedo_scale``;
        every bitmap looked up with ``texture_filter`` (``"bilinear"`` or ``"nearest"``)
        whatever the scene says (the bug issue 12 found: ``filter_type`` ignored);
        ``texture_raw``: every bitmap read as ``raw`` (an 8-bit sRGB image's gamma
        ignored); the camera's extent (orthographic) or tangent of the half field of
        view (perspective) scaled by ``camera_extent``; the film's reconstruction filter
        widened by ``filter_scale`` (a gaussian's stddev, a tent's radius: 1.2 turns
        Mitsuba's default σ = 0.5 into 0.6); ``bsdf_scale=(type, parameter, factor)``:
        that parameter (``"alpha"`` (both roughnesses), ``"alpha_u"``, ``"alpha_v"``,
        ``"eta"``, or ``"mix"``: a blend's weight or a mask's opacity, when a float) of
        every BSDF of that type (``"roughdielectric"``...) multiplied by ``factor``;
        ``swap_alpha_uv``: every BSDF's alpha_u and alpha_v exchanged (anisotropy along
        the wrong tangent); ``frame_ignored``: every BSDF shaded in ``coordinate_system``'s
        frame around the normal instead of Mitsuba's (s along dp/du);
        ``normalmap_ignored``: every ``normalmap`` replaced by the BSDF it holds;
        ``checkerboard_swapped``: every ``checkerboard``'s two colours exchanged (as
        Mitsuba's float look-up has them); ``tex_coords_unflipped``: every mesh's texture
        coordinates read as stored, ``flip_tex_coords`` ignored (an OBJ's v not turned
        into 1 - v, Mitsuba's default)."""
        if texture_raw or checkerboard_swapped or tex_coords_unflipped:
            desc = copy.deepcopy(self.desc)
            for shape in desc.shapes:
                if tex_coords_unflipped and shape.type in ("obj", "ply"):
                    shape.props["flip_tex_coords"] = False
                for tex in _textures(shape):
                    if tex.type == "checkerboard" and checkerboard_swapped:
                        p = tex.props
                        p["color0"], p["color1"] = p.get("color1", 0.2), p.get("color0", 0.4)
                    elif texture_raw:
                        tex.props["raw"] = True
            return _Builder(desc).build().planted(
                light_scale=light_scale, albedo_scale=albedo_scale, bsdf=bsdf,
                texture_filter=texture_filter, camera_extent=camera_extent,
                filter_scale=filter_scale, bsdf_scale=bsdf_scale,
                swap_alpha_uv=swap_alpha_uv, frame_ignored=frame_ignored,
                normalmap_ignored=normalmap_ignored)
        camera = dataclasses.replace(self.camera, tan_x=self.camera.tan_x * camera_extent,
                                     tan_y=self.camera.tan_y * camera_extent)
        a = self.arrays
        if filter_scale != 1.0:
            if not camera.splats:
                raise ValueError("filter_scale: the film's filter is box; nothing to widen")
            camera = camera.with_filter(camera.rfilter,
                                        radius=camera.filter_radius * filter_scale,
                                        stddev=camera.filter_stddev * filter_scale)
        if bsdf_scale is not None:
            a = a._replace(bsdf_f=self._bsdf_scaled(*bsdf_scale))
        if normalmap_ignored:
            # each shape shades with the held BSDF (two-sided if the normalmap was)
            bsdf_i = a.bsdf_i.copy()
            rows = np.flatnonzero(bsdf_i[:, layout.BSDF_KIND] == layout.NORMALMAP)
            held = bsdf_i[rows, layout.BSDF_CHILD0]
            bsdf_i[held, layout.BSDF_TWOSIDED] |= bsdf_i[rows, layout.BSDF_TWOSIDED]
            lookup = np.arange(len(bsdf_i))
            lookup[rows] = held
            a = a._replace(bsdf_i=bsdf_i, shape_bsdf=lookup[a.shape_bsdf])
        if frame_ignored:
            bsdf_i = a.bsdf_i.copy()
            bsdf_i[:, layout.BSDF_FRAME] = 0
            a = a._replace(bsdf_i=bsdf_i)
        if texture_filter is not None:
            if texture_filter not in layout.FILTERS:
                raise ValueError(f"texture_filter={texture_filter!r}; one of "
                                 f"{', '.join(layout.FILTERS)}")
            tex_info = a.tex_info.copy()
            tex_info[:, layout.TEX_FILTER] = layout.FILTERS.index(texture_filter)
            a = a._replace(tex_info=tex_info)
        rgb = slice(layout.LIGHT_RADIANCE, layout.LIGHT_RADIANCE + 3)
        light_f = a.light_f.copy()
        light_f[:, rgb] *= light_scale
        bf = a.bsdf_f.copy()
        if swap_alpha_uv:
            bf[:, [layout.ALPHA, layout.ALPHA_V]] = bf[:, [layout.ALPHA_V, layout.ALPHA]]
        if albedo_scale != 1.0:
            base = slice(layout.COLOR0, layout.COLOR0 + 3)
            if bsdf is None:
                bsdf = next((i for i, row in enumerate(a.bsdf_i)
                             if row[layout.BSDF_KIND] in _DIFFUSE_LIKE
                             and a.bsdf_tex[i, 0] < 0 and bf[i, base].any()), None)
                if bsdf is None:
                    raise ValueError("the scene has no untextured diffuse-like BSDF to plant in")
            bf[bsdf, base] *= albedo_scale
        return dataclasses.replace(self, camera=camera,
                                   arrays=a._replace(light_f=light_f, bsdf_f=bf))

    def _bsdf_scaled(self, kind: str, param: str, factor: float) -> np.ndarray:
        columns = {"alpha": [layout.ALPHA, layout.ALPHA_V], "alpha_u": [layout.ALPHA],
                   "alpha_v": [layout.ALPHA_V], "eta": [layout.ETA], "mix": [layout.MIX]}
        if kind not in layout.BSDF_NAMES or param not in columns:
            raise ValueError(f"bsdf_scale=({kind!r}, {param!r}, ...): a BSDF type "
                             f"({', '.join(layout.BSDF_NAMES)}) and one of "
                             f"{', '.join(columns)}")
        rows = np.flatnonzero(self.arrays.bsdf_i[:, layout.BSDF_KIND]
                              == layout.BSDF_NAMES.index(kind))
        rows = rows[self.arrays.bsdf_f[rows, columns[param][0]] != 0]
        if len(rows) == 0:
            raise ValueError(f"the scene has no {kind} with a {param} to plant in")
        bf = self.arrays.bsdf_f.copy()
        for col in columns[param]:
            bf[rows, col] *= factor
        return bf

    @property
    def height(self) -> int:
        return self.camera.height


class _Builder:
    def __init__(self, desc: SceneDescription):
        self.desc = desc
        self.dir = os.path.dirname(os.path.abspath(desc.path)) if desc.path else "."
        self.prims: list[np.ndarray] = []
        self.info: list[tuple[int, int]] = []
        self.bsdf_rows: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self.bsdf_ids: dict[int, int] = {}
        self.bsdf_names: list[str] = []
        self.bsdf_lines: list[str] = []
        self.lights: list[tuple[np.ndarray, np.ndarray]] = []
        self.light_lines: list[str] = []
        self.light_cdf: list[float] = [0.0]
        self.textures = TextureStore()
        self.texture_ids: dict[int, int] = {}
        self.env = -1
        self.env_marg = np.array([0.0, 1.0, 0.0])      # one piece (a table of _guided),
        self.env_cond = np.array([[0.0, 1.0, 0.0]])    # unread while there is no envmap
        self.features = 0

    def _where(self, plugin: Plugin) -> str:
        """``FILE:LINE`` of the plugin's element, "" for one the scene does not declare."""
        return plugin.at(self.desc.path) if plugin.line else ""

    def fail(self, plugin: Plugin, message: str):
        raise SceneError(f"{plugin.at(self.desc.path)}: <{plugin.kind} "
                         f"type=\"{plugin.type}\">: {message}")

    # ---------------------------------------------------------------- textures
    def _asset_path(self, plugin: Plugin, what: str = "") -> str:
        """The file the plugin's ``filename`` names (relative: in the scene's ``<path>``
        folders, the last one first, else in the scene's folder, as Mitsuba's file
        resolver looks), checked to be a regular file within the cap; refused naming the
        plugin."""
        name = plugin.get("filename")
        if not name:
            self.fail(plugin, f"set <string name=\"filename\" .../>{what}")
        path = first_found(name, self.desc.search) or os.path.join(self.dir, name)
        problem = file_problem(path, MAX_ASSET_BYTES)
        if problem:
            self.fail(plugin, problem)
        return path

    def _image(self, plugin: Plugin, raw: bool = False, half: bool = False) -> np.ndarray:
        path = self._asset_path(plugin, " (the image file)")
        try:
            img = read_image(path, raw=raw, texture=plugin.kind == "texture", half=half)
        except OSError as e:
            self.fail(plugin, str(e))
        bad = non_finite_texels(img)
        if bad:
            # as a non-finite number in the XML: Mitsuba renders NaN pixels from it, and
            # an envmap's sampling table cannot be built from it
            count, y, x, c, value = bad
            self.fail(plugin, f"{path}: texel (row {y}, column {x}) channel {c} is {value}; "
                              f"{count} texels are not finite")
        return img

    def _bitmap(self, tex: Plugin) -> int:
        """Store a ``bitmap`` texture with its filter, wrap mode and ``to_uv``, its texels
        in half precision where its ``format`` is "float16" (``accel``, GPU texture
        hardware in Mitsuba's CUDA variants, changes nothing here)."""
        fmt = tex.get("format", "variant")
        if fmt in ("auto", "uint8"):
            # Mitsuba 3.9.1 takes these (texels held in the file's own type, or in 8 bits)
            self.fail(tex, f"format {fmt!r} is not supported by the tracer; supported: "
                           "variant, float16 (or fp16)")
        if fmt not in ("variant", "float16", "fp16"):
            self.fail(tex, f"format {fmt!r}; Mitsuba takes auto, variant, float16 (or fp16) "
                           "and uint8, and refuses others; the tracer supports variant and "
                           "float16")
        img = self._image(tex, raw=bool(tex.get("raw", False)),
                          half=fmt in ("float16", "fp16"))
        options = {}
        for name, names, default in (("filter_type", layout.FILTERS, "bilinear"),
                                     ("wrap_mode", layout.WRAPS, "repeat")):
            value = tex.get(name, default)
            if value not in names:
                self.fail(tex, f"{name} {value!r}; supported: {', '.join(names)}")
            options[name] = names.index(value)
        tex._mean = float(img.mean())
        return self.textures.add(img, filter_type=options["filter_type"],
                                 wrap=options["wrap_mode"], to_uv=self._to_uv(tex))

    def _checkerboard(self, tex: Plugin) -> int:
        """Store a ``checkerboard`` texture as the 2 × 2 image a nearest, repeating
        look-up reads it from: Mitsuba's colour0 where the uv's fractional parts are both
        above 1/2 or both not, else colour1 (the cells meet at 1/2, where a look-up's
        floor(2·frac) and Mitsuba's frac > 1/2 differ: a set of measure zero). Its mean
        is Mitsuba's, the two colours' average."""
        c0, c1 = (np.broadcast_to(np.asarray(tex.get(name, default), dtype=np.float64), 3)
                  for name, default in (("color0", 0.4), ("color1", 0.2)))
        img = np.array([[c0, c1], [c1, c0]])
        tex._mean = float(img.mean())
        return self.textures.add(img, filter_type=layout.FILTERS.index("nearest"),
                                 wrap=layout.WRAPS.index("repeat"), to_uv=self._to_uv(tex))

    def _to_uv(self, tex: Plugin) -> tuple:
        """A texture's ``to_uv`` as the six entries ``TextureStore.add`` takes."""
        m = np.asarray(tex.get("to_uv", np.eye(4)), dtype=np.float64)
        off = [(r, c) for r, c in ((0, 2), (1, 2), (2, 0), (2, 1), (2, 3)) if m[r, c] != 0]
        if off:
            # Mitsuba keeps rows and columns 0, 1 and 3 and drops the rest: a 9-number
            # <matrix> written as a homogeneous uv transform lost its offset there
            entries = ", ".join(f"[{r}][{c}] = {m[r, c]:g}" for r, c in off)
            self.fail(tex, f"to_uv must map the uv plane to itself (x and y only), but its "
                           f"4x4 matrix has {entries}, which Mitsuba drops (it renders the "
                           "texture without them); a 9-number <matrix> is the 3x3 linear "
                           "part of (x, y, z), not a homogeneous uv transform: give a uv "
                           "offset with <translate x=\"...\" y=\"...\"/>")
        if tex.type == "bitmap" and not finite_in_float32(m[[0, 0, 0, 1, 1, 1],
                                                             [0, 1, 3, 0, 1, 3]]):
            # Mitsuba stores it in float32 as inf: its bilinear look-up is NaN, its nearest
            # one a texel that depends on the wrap mode; we read texel 0 (render-check then
            # refused Mitsuba's NaN image blaming an emitter's value). A checkerboard's
            # infinite uv has a NaN fraction, the cell Mitsuba's and our look-up both give.
            self.fail(tex, f"to_uv {m[:2, [0, 1, 3]].tolist()}: beyond float32's range "
                           "(±3.4e38), where Mitsuba stores it as infinity and its look-up "
                           "is NaN (bilinear) or one texel (nearest)")
        return m[0, 0], m[0, 1], m[0, 3], m[1, 0], m[1, 1], m[1, 3]

    def _colour(self, plugin: Plugin, name: str, default: float):
        """(rgb, texture id or -1, mean) of a colour property."""
        v = plugin.get(name, default)
        if isinstance(v, Plugin):
            key = id(v)
            if key not in self.texture_ids:
                store = self._checkerboard if v.type == "checkerboard" else self._bitmap
                self.texture_ids[key] = store(v)
                self.features |= FEATURE_BITS["texture:bitmap"]
            img = self.textures.images[self.texture_ids[key]]
            if name in _ALBEDOS and img.min() < 0:
                # as a <float> below 0 (scene.py): the tracer ends a path whose BSDF
                # value is negative in every channel, Mitsuba carries it on
                y, x, c = np.argwhere(img < 0)[0]
                self.fail(v, f"{v.get('filename')}: texel (row {y}, column {x}) channel {c} "
                             f"is {img[y, x, c]:g}: as {name}, a texture must be >= 0 "
                             "(Mitsuba renders a negative one as a negative albedo, which "
                             "this tracer does not)")
            return np.zeros(3), self.texture_ids[key], v._mean
        rgb = np.broadcast_to(np.asarray(v, dtype=np.float64), 3).astype(np.float64)
        return rgb, -1, float(rgb.mean())

    # ------------------------------------------------------------------- BSDFs
    def _ior(self, plugin: Plugin, name: str, default: str) -> float:
        v = plugin.get(name, default)
        if isinstance(v, str):
            table = _materials()["dielectrics"]
            if ascii_lower(v) not in table:
                self.fail(plugin, f"unknown {name} {v!r}; named indices: "
                                  f"{', '.join(sorted(table))}")
            return float(table[ascii_lower(v)])
        if not v > 0:       # Mitsuba refuses a negative index; 0 would divide by zero
            self.fail(plugin, f"{name} must be > 0, got {v}")
        if v < 2.0 ** -126:
            # (the scene parser refuses one beyond float32's range: Mitsuba's inf there
            # rendered int_ior 1e39 black where ours rendered glass)
            self.fail(plugin, f"{name} = {v:g} is below float32's least normal number "
                              "(1.2e-38), in which Mitsuba holds it")
        return float(v)

    def _relative_ior(self, plugin: Plugin, default: str, rough: bool) -> float:
        """int_ior / ext_ior; a rough interface of ratio 1 is refused, as Mitsuba
        refuses it: equal in float32, where Mitsuba holds them (int_ior 1.00000001
        and ext_ior 1 are both 1 there)."""
        int_ior = self._ior(plugin, "int_ior", default)
        ext_ior = self._ior(plugin, "ext_ior", "air")
        eta = int_ior / ext_ior
        if rough and np.float32(int_ior) == np.float32(ext_ior):
            self.fail(plugin, f"int_ior and ext_ior must differ (int_ior {int_ior!r} and "
                              f"ext_ior {ext_ior!r} are equal in float32, in which Mitsuba "
                              "holds them)")
        if not 2.0 ** -60 <= eta <= 2.0 ** 60:
            # Mitsuba squares the ratio and its inverse in float32, with factors: a rough
            # plastic of ratio 1e-19 rendered NaN (2e-19 did not), a thin dielectric of
            # 1.2e-38 grey
            self.fail(plugin, f"int_ior / ext_ior = {eta:g} must lie in [2^-60, 2^60] "
                              "(8.7e-19 to 1.2e18): Mitsuba squares it in float32, which "
                              "overflows beyond")
        return eta

    def _distribution(self, plugin: Plugin) -> int:
        given = str(plugin.get("distribution", "beckmann"))
        d = ascii_lower(given)      # as Mitsuba reads it
        if d not in ("ggx", "beckmann"):
            self.fail(plugin, f"distribution {given!r}; supported: ggx, beckmann")
        for name in ("alpha", "alpha_u", "alpha_v"):
            alpha = float(plugin.get(name, 0.1))
            if not alpha >= 0:      # 0 (an exporter's smooth surface) is raised to 1e-4
                self.fail(plugin, f"{name} must be >= 0, got {alpha}")
        return layout.GGX if d == "ggx" else layout.BECKMANN

    def _alpha(self, plugin: Plugin) -> tuple[float, float]:
        """The roughness (alpha_u, alpha_v): ``alpha`` for both, or ``alpha_u`` and
        ``alpha_v`` (both, and no ``alpha``: Mitsuba refuses the rest). Mitsuba orients
        alpha_u along the shading frame's tangent s, which follows dp/du; a BSDF whose
        two differ asks the kernel for that frame (``BSDF_FRAME``)."""
        def raised(name):       # to Mitsuba's least roughness
            return max(float(plugin.get(name, 0.1)), _ALPHA_MIN)

        given = {n for n in ("alpha_u", "alpha_v") if n in plugin.props}
        if not given:
            return raised("alpha"), raised("alpha")
        if len(given) == 1 or "alpha" in plugin.props:
            self.fail(plugin, "give alpha, or both alpha_u and alpha_v")
        return raised("alpha_u"), raised("alpha_v")

    def _roughness(self, plugin: Plugin, f: np.ndarray, i: np.ndarray):
        """Store the distribution and (alpha_u, alpha_v) of a microfacet BSDF; an
        anisotropic one needs Mitsuba's shading frame."""
        i[layout.BSDF_DISTRIBUTION] = self._distribution(plugin)
        f[layout.ALPHA], f[layout.ALPHA_V] = self._alpha(plugin)
        if f[layout.ALPHA] != f[layout.ALPHA_V]:
            i[layout.BSDF_FRAME] = 1
            self.features |= FEATURE_BITS["shading:frame"]

    def bsdf(self, plugin: Plugin | None, emitter: bool = False) -> int:
        if plugin is None:
            # Mitsuba's default: diffuse 0.5, or black on an emitting shape
            plugin = Plugin("bsdf", "diffuse", {"reflectance": 0.0} if emitter else {}, 0)
            key = -2 if emitter else -1
        else:
            key = id(plugin)
        if key not in self.bsdf_ids:
            self.bsdf_ids[key] = self._bsdf_row(plugin, 0, None)
        return self.bsdf_ids[key]

    def _blend_mitsuba_samples_right(self, plugin: Plugin, nested) -> None:
        """Refuse a blend whose reference Mitsuba 3.9.1 renders biased: a diffuse or
        roughconductor beside a roughdielectric. Where light arrives from below the
        surface, its llvm variants' blendbsdf sample weights (the scalar variant's do
        not) average above its own eval's integral
        (α 0.44, η 1.69, weight 0.5: 0.88 against 0.70 at cos θ_i = -0.8 beside a
        diffuse, 0.94 against 0.41 at -0.3 beside a roughconductor), so an emitting
        panel of such a blend, lit from behind by its own light, rendered 8 % brighter
        in Mitsuba than here; ours agrees with the eval (an outside review)."""
        pair = _one_sided_beside_glass(nested)
        if pair:
            self.fail(plugin, f"a {pair[0]} beside a {pair[1]} in a blendbsdf is not "
                              "supported: Mitsuba 3.9.1's llvm variants, which build the "
                              "references, weigh its samples from below the surface wrongly "
                              "(their mean is not its eval's integral, as in its scalar "
                              "variant), so its image is not the one to match; a twosided "
                              "diffuse or a roughplastic beside the roughdielectric is "
                              "sampled right")

    def _nested(self, plugin: Plugin) -> list[Plugin]:
        return [c for c in plugin.children if c.kind == "bsdf"]

    def _bsdf_row(self, plugin: Plugin, twosided: int, parent: str | None) -> int:
        """Append the row(s) of ``plugin`` (children first) and return its row. ``parent``:
        the composite it is nested in, which limits what it may be."""
        if plugin.type == "twosided":
            nested = self._nested(plugin)
            if len(nested) != 1:
                self.fail(plugin, "exactly one nested <bsdf> is supported (the same on "
                                  "both sides)")
            inner = nested[0]
            grand = self._nested(inner) if inner.type in ("blendbsdf", "normalmap") else []
            if inner.type in TRANSMISSIVE or any(g.type in TRANSMISSIVE for g in grand):
                self.fail(plugin, f"a twosided {inner.type} is not supported (Mitsuba "
                                  "accepts only reflective BSDFs inside twosided)")
            if twosided:
                self.fail(plugin, "a twosided inside a twosided")
            self.features |= FEATURE_BITS["bsdf:twosided"]
            return self._bsdf_row(inner, 1, parent)
        if parent == "blendbsdf" and plugin.type not in _BLENDABLE:
            # a blendbsdf inside one was told "BSDFs with a density", which a blend of
            # two of them has: the limit is the table's depth (an outside review)
            why = ("BSDFs with a density: Mitsuba mixes a delta lobe's probability "
                   "with the other BSDF's density"
                   if plugin.type in ("conductor", "dielectric", "thindielectric",
                                      "plastic") else
                   "the tracer's BSDF table nests one level: a blend of basic BSDFs, "
                   "not of a blend, mask or normalmap")
            self.fail(plugin, f"a {plugin.type} inside a blendbsdf is not supported: "
                              f"supported: {', '.join(_BLENDABLE)} ({why})")
        if parent == "mask" and plugin.type == "mask":
            self.fail(plugin, "a mask inside a mask")
        if plugin.type == "normalmap" and parent is not None:
            self.fail(plugin, f"a normalmap inside a {parent} is not supported: make it the "
                              "shape's BSDF (a twosided around it is fine)")
        f = np.zeros(layout.BSDF_WIDTH)
        i = np.zeros(layout.BSDF_INTS, dtype=np.int64)
        tex = np.full(2, -1, dtype=np.int64)
        kind = layout.BSDF_NAMES.index(plugin.type)
        i[layout.BSDF_KIND], i[layout.BSDF_TWOSIDED] = kind, twosided
        self.features |= layout.BSDF_BITS[kind]
        c0, c1 = slice(layout.COLOR0, layout.COLOR0 + 3), slice(layout.COLOR1, layout.COLOR1 + 3)
        if kind == layout.NORMALMAP:
            self._normalmap(plugin, f, i, tex)
        elif kind in layout.COMPOSITE:
            nested = self._nested(plugin)
            want = 2 if kind == layout.BLEND else 1
            if len(nested) != want:
                self.fail(plugin, f"needs exactly {want} nested <bsdf>, has {len(nested)}")
            name = "weight" if kind == layout.BLEND else "opacity"
            if kind == layout.BLEND and name not in plugin.props:
                self.fail(plugin, "set its weight (Mitsuba has no default)")
            if kind == layout.BLEND:
                self._blend_mitsuba_samples_right(plugin, nested)
            if getattr(plugin.get(name), "type", None) == "checkerboard":
                # Mitsuba 3.9.1 reads a checkerboard as a float (eval_1) with its two
                # colours the other way round from its colour (eval)
                self.fail(plugin, f"a checkerboard as its {name} is not supported "
                                  "(Mitsuba's float look-up swaps the two colours); "
                                  "use a bitmap")
            rgb, tex[0], _ = self._colour(plugin, name, 0.5)
            f[layout.MIX] = rgb[0]
            for col, child in zip((layout.BSDF_CHILD0, layout.BSDF_CHILD1), nested):
                i[col] = self._bsdf_row(child, twosided, plugin.type)
                i[layout.BSDF_FRAME] |= self.bsdf_rows[i[col]][1][layout.BSDF_FRAME]
        elif kind == layout.DIFFUSE:
            f[c0], tex[0], _ = self._colour(plugin, "reflectance", 0.5)
        elif kind in (layout.CONDUCTOR, layout.ROUGHCONDUCTOR):
            f[c0], tex[0], _ = self._colour(plugin, "specular_reflectance", 1.0)
            eta = slice(layout.COND_ETA, layout.COND_ETA + 3)
            k = slice(layout.COND_K, layout.COND_K + 3)
            name = plugin.get("material", "none")
            given = [q for q in ("eta", "k") if q in plugin.props]
            if given and name != "none":
                # Mitsuba refuses both (eta with a material; k alone is left unread)
                self.fail(plugin, f"material={name!r} and {'/'.join(given)} given: "
                                  "specify either (eta, k) or a material, not both")
            if given:
                f[eta] = np.broadcast_to(plugin.get("eta", 0.0), 3)
                f[k] = np.broadcast_to(plugin.get("k", 1.0), 3)
                over = f[eta] ** 2 + f[k] ** 2 >= 2.0 ** 64
                if over.any():
                    c = int(np.argmax(over))
                    # (η² + k²)² is the Fresnel term's largest product: beyond float32
                    # there, Mitsuba's term is NaN and the surface renders black
                    self.fail(plugin, f"eta = {f[eta][c]:g}, k = {f[k][c]:g}: eta² + k² "
                                      "must be below 2^64 (1.8e19), beyond which Mitsuba's "
                                      "float32 Fresnel term is NaN and renders the surface "
                                      "black; a perfect mirror is material=\"none\"")
            else:
                table = _materials()["conductors"]
                if name not in table:
                    self.fail(plugin, f"unknown material {name!r}; supported: "
                                      f"{', '.join(sorted(table))}")
                f[eta], f[k] = table[name]["eta"], table[name]["k"]
            if kind == layout.ROUGHCONDUCTOR:
                self._roughness(plugin, f, i)
        elif kind in (layout.DIELECTRIC, layout.ROUGHDIELECTRIC, layout.THINDIELECTRIC):
            f[c0], tex[0], _ = self._colour(plugin, "specular_reflectance", 1.0)
            f[c1], tex[1], _ = self._colour(plugin, "specular_transmittance", 1.0)
            f[layout.ETA] = self._relative_ior(plugin, "bk7", kind == layout.ROUGHDIELECTRIC)
            if kind == layout.ROUGHDIELECTRIC:
                self._roughness(plugin, f, i)
        else:  # plastic, roughplastic
            f[c0], tex[0], d_mean = self._colour(plugin, "diffuse_reflectance", 0.5)
            f[c1], tex[1], s_mean = self._colour(plugin, "specular_reflectance", 1.0)
            eta = f[layout.ETA] = self._relative_ior(plugin, "polypropylene",
                                                     kind == layout.ROUGHPLASTIC)
            # a black plastic (both reflectances 0) scatters nothing: Mitsuba's weight is
            # 0 / 0, NaN, which samples the diffuse lobe only, as 0 does (it was a
            # ZeroDivisionError, "unexpected" in the CLI)
            total = d_mean + s_mean
            f[layout.SPECULAR_WEIGHT] = s_mean / total if total > 0 else 0.0
            i[layout.BSDF_NONLINEAR] = int(bool(plugin.get("nonlinear", False)))
            if kind == layout.PLASTIC:
                f[layout.COAT_INTERNAL] = fresnel_diffuse_reflectance(1.0 / eta)
            else:
                i[layout.BSDF_DISTRIBUTION] = self._distribution(plugin)
                alpha = self._alpha(plugin)[0]      # isotropic: the loader takes no
                f[layout.ALPHA] = f[layout.ALPHA_V] = alpha     # alpha_u on a plastic
                if alpha >= 2.0 ** 64:
                    # Mitsuba's coat squares it in float32: alpha 2e19 evaluated to NaN
                    # (Beckmann; GGX from about 1e35) and the reference build blamed an
                    # emitter's value beyond float32's range, which the scene had none of
                    self.fail(plugin, f"alpha = {alpha:g}: a rough plastic's roughness "
                                      "must be below 2^64 (1.8e19), beyond which Mitsuba's "
                                      "float32 alpha² overflows and its coat evaluates to "
                                      "NaN (Beckmann; GGX from about 1e35)")
                table, internal = rough_coat_tables(alpha, int(i[layout.BSDF_DISTRIBUTION]), eta)
                f[layout.COAT_TABLE:layout.COAT_TABLE + layout.COAT_TABLE_RES] = table
                f[layout.COAT_INTERNAL] = internal
            # the base under the coat, r / (1 - F_int) or (nonlinear) r / (1 - r F_int),
            # must stay finite and >= 0: Mitsuba's fit of a smooth coat's internal
            # reflectance F_int exceeds 1 above int_ior / ext_ior ~ 3.85 (a plastic of
            # int_ior 5 rendered 3 % off Mitsuba), and a nonlinear base r >= 1 / F_int
            # divides by 0 or less
            f_int = f[layout.COAT_INTERNAL]
            d_max = self.textures.images[tex[0]].max() if tex[0] >= 0 else f[c0].max()
            nonlinear = bool(i[layout.BSDF_NONLINEAR])
            if (d_max * f_int if nonlinear else f_int) >= 1.0:
                r = (f"r / (1 - r F_int) with r up to {d_max:g} (diffuse_reflectance)"
                     if nonlinear else "r / (1 - F_int)")
                self.fail(plugin, f"the coat's internal reflectance F_int = {f_int:.4g} (for "
                                  f"int_ior / ext_ior = {eta:.4g}) makes the base {r} "
                                  "infinite or negative (Mitsuba renders a negative albedo, "
                                  "which this tracer does not)")
        self.bsdf_rows.append((f, i, tex))
        self.bsdf_names.append(plugin.type if not twosided else f"twosided({plugin.type})")
        self.bsdf_lines.append(self._where(plugin))
        return len(self.bsdf_rows) - 1

    def _normalmap(self, plugin: Plugin, f: np.ndarray, i: np.ndarray, tex: np.ndarray):
        """A ``normalmap`` row: its image (slot 0; Mitsuba maps a texel v to the normal
        2 v - 1 in the shading frame, so the image is usually ``raw``), Mitsuba's two
        switches, and its one BSDF (basic, or a twosided basic one), which it shades in
        the perturbed frame. It needs Mitsuba's shading frame."""
        nested = self._nested(plugin)
        if len(nested) != 1:
            self.fail(plugin, f"needs exactly 1 nested <bsdf>, has {len(nested)}")
        core = nested[0]
        if core.type == "twosided" and len(self._nested(core)) == 1:
            core = self._nested(core)[0]
        if core.type in ("blendbsdf", "mask", "normalmap"):
            self.fail(plugin, f"a {core.type} inside a normalmap is not supported: it holds "
                              "one basic BSDF (twosided or not)")
        if getattr(plugin.get("normalmap"), "type", None) != "bitmap":
            self.fail(plugin, "normalmap must be a bitmap texture")
        _, tex[0], _ = self._colour(plugin, "normalmap", 0.5)
        self._normals_fit(plugin, self.textures.images[tex[0]])
        i[layout.NORMALMAP_FLIP_INVALID] = int(bool(plugin.get("flip_invalid_normals", True)))
        i[layout.NORMALMAP_SHADOWING] = int(bool(plugin.get("use_shadowing_function", True)))
        i[layout.BSDF_CHILD0] = self._bsdf_row(nested[0], 0, "normalmap")
        i[layout.BSDF_FRAME] = 1
        self.features |= FEATURE_BITS["shading:frame"]

    def _normals_fit(self, plugin: Plugin, img: np.ndarray) -> None:
        """Refuse a normal map texel whose normal 2 v - 1 has a squared length beyond
        float32's range: Mitsuba's LLVM variant normalises it as n / sqrt(n · n) in
        float32, where n · n overflows and the normal comes out 0 (texels of 1e19 and 1e30
        rendered black there, and up to 94 % brighter in ours, which normalises in
        float64)."""
        square = np.sum((2.0 * img - 1.0) ** 2, axis=2)
        over = ~(square < np.finfo(np.float32).max)
        if over.any():
            y, x = np.argwhere(over)[0]
            tex = plugin.get("normalmap")
            self.fail(tex, f"{tex.get('filename')}: texel (row {y}, column {x}) is "
                           f"{', '.join(f'{c:g}' for c in img[y, x])}, a normal 2 v - 1 "
                           "whose squared length is beyond float32's range (3.4e38), in "
                           "which Mitsuba normalises it (the normal comes out 0 and the "
                           f"surface black); {int(over.sum())} texel(s) are so: keep the "
                           "squared length of 2 v - 1 below 3.4e38 (each channel below "
                           "about 5e18)")

    # ------------------------------------------------------------------ shapes
    def _triangles(self, verts, faces, normals=None, uvs=None):
        """Append triangles; returns (first, count)."""
        first = len(self.prims)
        for k, (a, b, c) in enumerate(faces):
            row = np.zeros(PRIM_WIDTH)
            for corner, col in zip((a, b, c), (layout.TRI_P0, layout.TRI_P1, layout.TRI_P2)):
                row[col:col + 3] = verts[corner]
            if normals is not None:
                for corner, col in zip((a, b, c), (layout.TRI_N0, layout.TRI_N1, layout.TRI_N2)):
                    row[col:col + 3] = normals[corner]
            if uvs is not None:
                for corner, col in zip((a, b, c), (layout.TRI_UV0, layout.TRI_UV1, layout.TRI_UV2)):
                    row[col:col + 2] = uvs[corner]
            self.prims.append(row)
        return first, len(self.prims) - first

    def shape(self, s: Plugin, index: int):
        m = np.asarray(s.get("to_world", np.eye(4)), dtype=np.float64)
        lin, off = m[:3, :3], m[:3, 3]
        n_before = len(self.prims)
        if s.type in ("rectangle", "cube"):
            verts, faces, uvs = (_rectangle() if s.type == "rectangle" else _cube())
            if np.linalg.det(lin) < 0:          # keep the normal Mitsuba's transform gives
                faces = [(a, c, b) for a, b, c in faces]
            self._triangles(verts @ lin.T + off, faces, None, uvs)
        elif s.type in ("obj", "ply", "serialized"):
            verts, faces, normals, uvs, pidx = (self._obj(s) if s.type == "obj"
                                                else self._indexed_mesh(s))
            wverts = verts @ lin.T + off
            if s.get("face_normals", False):
                normals = None
            elif normals is None:   # smooth normals, computed in world space as Mitsuba does
                faces = np.asarray(faces).reshape(-1, 3)
                normals, cancelled = _vertex_normals(wverts, faces, pidx, int(pidx.max()) + 1)
                if cancelled.any():
                    self._cancelled_normals(s, verts[np.argmax(cancelled)],
                                            len(np.unique(pidx[cancelled])))
            else:
                # world-space unit normals, as Mitsuba stores them (a non-unit normal in
                # the file would otherwise weigh more in the interpolation)
                with np.errstate(over="ignore", under="ignore", invalid="ignore"):
                    normals = normals @ np.linalg.inv(lin)
                    length = np.linalg.norm(normals, axis=1, keepdims=True)
                if not np.all(np.isfinite(length) & (length > 0)):
                    # Mitsuba refuses these ("invalid vertex normal data"): a zero normal
                    # shaded with a zero frame (a 2 % darker image, pixels at 0.44), and
                    # one of 1e300 (its length overflows) or one the transform shrinks
                    # below the smallest double became a zero or NaN normal again
                    self.fail(s, f"{self._asset_path(s)}: a vertex normal is zero or not "
                                 "finite, or cannot be normalised in world space (too large "
                                 "or too small)")
                normals = normals / length
            self._triangles(wverts, faces, normals, uvs)
        elif s.type == "sphere":
            c = m @ np.append(np.asarray(s.get("center", np.zeros(3)), float), 1.0)
            # within 1e-3: an exporter's rotation written to 4 or 6 decimals is one (at
            # 1e-6, 1.4 % of random rotations written to 6 decimals were refused as a
            # non-uniform scale and 2.7 % as a shear); the radius is the x column's
            # length, as Mitsuba takes it, and the frame a rotation to that tolerance
            scales = np.linalg.norm(lin, axis=0)
            if not np.allclose(scales, scales[0], rtol=_SIMILARITY_TOL):
                self.fail(s, "a sphere's to_world must scale uniformly")
            frame = lin / scales[0]
            if not np.allclose(frame.T @ frame, np.eye(3), atol=_SIMILARITY_TOL):
                # equal column lengths, but not orthogonal: a shear, which the sphere's
                # frame (its uv and shading frame) cannot hold (Mitsuba warns of it)
                self.fail(s, "a sphere's to_world must not shear (a rotation, a uniform "
                             "scale and a translation)")
            r = float(s.get("radius", 1.0)) * scales[0]
            if not r > 0:
                self.fail(s, f"radius must be > 0, got {r}")
            row = np.zeros(PRIM_WIDTH)
            row[layout.SPHERE_CENTER:layout.SPHERE_CENTER + 3], row[layout.SPHERE_RADIUS] = c[:3], r
            row[layout.SPHERE_ROTATION:layout.SPHERE_ROTATION + 9] = (lin / scales[0]).T.ravel()
            self.prims.append(row)
        elif s.type == "disk":
            if abs(np.linalg.det(lin)) == 0:
                self.fail(s, "to_world is singular")
            inv = np.linalg.inv(m)
            row = np.zeros(PRIM_WIDTH)
            row[layout.DISK_TO_WORLD:layout.DISK_TO_WORLD + 12] = m[:3, :4].ravel()
            row[layout.DISK_TO_LOCAL:layout.DISK_TO_LOCAL + 12] = inv[:3, :4].ravel()
            self.prims.append(row)
        rows = np.asarray(self.prims[n_before:])
        if rows.size and not np.all(np.abs(rows) < FLOAT32_OVERFLOW):
            # Mitsuba stores the shape in single precision, as infinity, and renders none
            # of it; float64 rendered it here (a rectangle scaled by 1e39: the image mean
            # 0.75 against Mitsuba's 1, an outside review)
            self.fail(s, f"its geometry in world space (to_world applied) reaches "
                         f"{np.abs(rows).max():.3g}, not finite in single precision "
                         "(beyond ±3.4028235e38), as Mitsuba stores it (it renders no "
                         "such shape)")
        kind = {"sphere": SPHERE, "disk": DISK}.get(s.type, TRIANGLE)
        self.info += [(kind, index)] * (len(self.prims) - n_before)
        return n_before, len(self.prims) - n_before, kind

    def _indexed_mesh(self, s: Plugin):
        """A PLY or serialized mesh as (vertices, faces, the file's normals or None, uvs,
        the position index of each vertex): per vertex when the file has uv, else one
        vertex per face corner with Mitsuba's barycentric uv."""
        path = self._asset_path(s)      # refuses a missing file naming the shape itself
        normals = not s.get("face_normals", False)
        try:
            mesh = (read_ply(path, normals=normals) if s.type == "ply" else
                    read_serialized(path, s.get("shape_index", 0), normals=normals,
                                    cap=MAX_ASSET_BYTES))
        except SceneError as e:
            self.fail(s, str(e))
        verts, faces, normals, uvs = mesh.vertices, mesh.faces, mesh.normals, mesh.uvs
        pidx = np.arange(len(verts))
        if uvs is not None and s.get("flip_tex_coords", False):   # Mitsuba's PLY default
            uvs = np.column_stack([uvs[:, 0], 1.0 - uvs[:, 1]])  # v -> 1 - v, as for an OBJ
        if uvs is None:
            pidx = faces.ravel()
            verts = verts[pidx]
            normals = None if normals is None else normals[pidx]
            uvs = np.tile(np.array(_BARYCENTRIC_UV), (len(faces), 1))
            faces = np.arange(len(pidx)).reshape(-1, 3)
        return verts, faces, normals, uvs, pidx

    def _obj(self, s: Plugin):
        """An OBJ mesh as (vertices, faces, the file's normals or None, uvs, the vertex
        each corner is: one vertex per distinct (position, vt, vn) triple, as Mitsuba's
        loader makes them, so that smooth normals are summed per such vertex), one
        vertex per face corner. What Mitsuba refuses is refused, naming the line."""
        path = self._asset_path(s)
        try:
            with open(path, "rb") as fh:
                # lines end at LF only, as Mitsuba splits them (a lone CR is a space to it)
                lines = fh.read().split(b"\n")
        except OSError as e:
            self.fail(s, f"cannot read {path} ({getattr(e, 'strerror', None) or e})")
        for ln, line in enumerate(lines, 1):
            if len(line) >= _OBJ_LINE_BYTES:
                # Mitsuba refuses the file ("excessively long line"): an exporter's n-gon
                # of 200 'v/vt/vn' corners (a cylinder's cap) rendered here
                self.fail(s, f"{path}:{ln}: a line of {len(line)} bytes; Mitsuba refuses "
                             f"lines of {_OBJ_LINE_BYTES} or more (triangulate long "
                             f"polygons on export){_lone_cr(lines)}")
        # numbers and keywords are ASCII; a comment or a name in another encoding
        # (an exporter's Latin-1 "# Café") is read past, as Mitsuba reads bytes
        lines = [line.decode("utf-8", errors="replace") for line in lines]
        if lines and lines[0].startswith("\ufeff"):
            self.fail(s, f"{path}: starts with a byte-order mark, which Mitsuba's OBJ "
                         "loader reads as part of the first line (it refuses the file): "
                         "save it as UTF-8 without one")
        v, vt, vn = [], [], []
        corners = []
        width = {"v": 3, "vt": 2, "vn": 3}
        # with face_normals Mitsuba reads neither vn lines nor their indices (it rendered
        # a 'vn 0 0 0' an exporter wrote for a degenerate face, which we refused)
        face_normals = bool(s.get("face_normals", False))
        for ln, line in enumerate(lines, 1):
            hash_at = line.find("#")                    # a comment may end any line
            t = split_words(line if hash_at < 0 else line[:hash_at])
            if not t:
                continue
            where = f"{path}:{ln}: {line.strip()!r}"
            if t[0] == "vn" and face_normals:
                continue
            if t[0] in width:
                vals = _numbers(t[1:width[t[0]] + 1], parse_float)
                if vals is None or len(vals) < width[t[0]]:
                    self.fail(s, f"{where}: needs {width[t[0]]} numbers")
                if not all(math.isfinite(x) for x in vals):
                    # Mitsuba: "invalid vertex position data"; the triangle vanished
                    self.fail(s, f"{where}: not finite")
                if t[0] != "vt" and not finite_in_float32(vals):
                    # Mitsuba stores single precision and refuses the file ("invalid
                    # vertex position data"); float64 rendered it here
                    self.fail(s, f"{where}: not finite in single precision (beyond "
                                 "±3.4028235e38), as Mitsuba stores it (it refuses it too)")
                if t[0] == "vn" and not any(vals):
                    # Mitsuba refuses the file for any such line, used or not
                    self.fail(s, f"{where}: a zero normal")
                {"v": v, "vt": vt, "vn": vn}[t[0]].append(vals)
            elif t[0] == "f":
                if hash_at > 0 and line[hash_at - 1] not in SPACE:
                    # Mitsuba misreads such a face (it dropped 'f 1 2 3#c', kept one
                    # triangle of 'f 1 2 4 3#c', and garbled the next face's vertices)
                    self.fail(s, f"{where}: a comment glued to an index "
                                 f"({t[-1]}#...), which Mitsuba "
                                 "misreads: put a space before '#'")
                extra = next((tok for tok in t[1:] if any(tok.split("/")[3:])), None)
                if extra is not None:
                    # Mitsuba refuses the file ("could not parse line"); the fourth
                    # index was dropped here and the face rendered
                    self.fail(s, f"{where}: the corner {extra!r} has more than three "
                                 "indices (v, v/vt, v//vn or v/vt/vn), which Mitsuba "
                                 "refuses")
                idx = [_numbers([p or "0" for p in (tok.split("/") + ["", ""])[:3]],
                                lambda p: parse_int(p, sign="+-"))
                       for tok in t[1:]]
                if any(c is None for c in idx):
                    self.fail(s, f"{where}: cannot parse it")
                if any(i < 0 for c in idx for i in c):
                    # Mitsuba reads them as huge unsigned indices and refuses the file
                    self.fail(s, f"{where}: negative (relative) indices are not supported "
                                 "(Mitsuba refuses them too)")
                bare = next((tok for tok in t[1:] if tok.startswith("/")), None)
                if bare is not None:
                    # Mitsuba drops such a face without a word; it was refused here as
                    # one that 'refers to vertex 0', which the file does not say
                    self.fail(s, f"{where}: the corner {bare!r} has no vertex index "
                                 "(Mitsuba drops such a face): begin each corner with "
                                 "its 'v' index")
                if any(c[0] == 0 for c in idx):
                    self.fail(s, f"{where}: a face refers to vertex 0 (indices start at 1)")
                for j, (name, seen) in enumerate((("v", v), ("vt", vt), ("vn", vn))):
                    if any(c[j] > len(seen) for c in idx) and not (j == 2 and face_normals):
                        # Mitsuba resolves an index as the face is read
                        self.fail(s, f"{where}: refers to a '{name}' that is not defined "
                                     f"before it ({len(seen)} so far)")
                if any(c[1] and not finite_in_float32(vt[c[1] - 1]) for c in idx):
                    # Mitsuba holds it as inf (an unused one is harmless); it was refused
                    # only as the triangles' "geometry ... reaches 1e+39", naming no line
                    self.fail(s, f"{where}: uses a 'vt' that is not finite in single "
                                 "precision (beyond ±3.4028235e38), as Mitsuba stores it")
                for k in range(1, len(idx) - 1):
                    corners.append((idx[0], idx[k], idx[k + 1]))
        if not corners:
            self.fail(s, f"{path}: no faces{_lone_cr(lines)}")
        v, vt, vn = np.array(v, float), np.array(vt, float), np.array(vn, float)
        for j, word, key, seen in ((1, "texture coordinates", "vt", vt),
                                   (2, "normals", "vn", vn))[:2 - face_normals]:
            given = {bool(c[j]) for tri in corners for c in tri}
            if len(given) > 1:
                self.fail(s, f"{path}: some faces have {word} and some do not (Mitsuba's "
                             f"{word} on those are undefined); give them to every face or "
                             "to none")
            if given == {False} and len(seen):
                # Mitsuba allocates them for the file's lines and fills none: its
                # vertices' normals were left uninitialised (zeros in one run, 9e-24 in
                # the next), where ours took the last 'vn' for every corner (vn[0 - 1])
                self._unused_lines(s, path, key, len(seen), word)
        use_vn = len(vn) > 0 and not face_normals
        flip = bool(s.get("flip_tex_coords", True))     # Mitsuba's default: v -> 1 - v
        verts, uvs, normals, faces, key = [], [], [], [], {}
        for tri in corners:
            f = []
            for k, (pi, ti, ni) in enumerate(tri):
                verts.append(v[pi - 1])
                key.setdefault((pi, ti, ni), len(key))
                # without texture coordinates Mitsuba's uv is the barycentric (b1, b2)
                if ti:
                    t_u, t_v = vt[ti - 1]
                    uvs.append([t_u, 1.0 - t_v if flip else t_v])
                else:
                    uvs.append(_BARYCENTRIC_UV[k])
                if use_vn:
                    normals.append(vn[ni - 1])
                f.append(len(verts) - 1)
            faces.append(tuple(f))
        vertex = np.array([key[c] for tri in corners for c in tri])
        normals = np.array(normals, float) if use_vn else None
        return np.array(verts), faces, normals, np.array(uvs), vertex

    def _cancelled_normals(self, s: Plugin, where, count: int):
        """Refuse a mesh whose smooth normal at a vertex (``where``, as in the file)
        cancels out: Mitsuba's there is rounding noise, or (1, 0, 0) where its sum is
        exactly 0 (a quad whose two triangles are wound opposite ways rendered a block of
        0.12 here against Mitsuba's 0.004)."""
        self.fail(s, f"{self._asset_path(s)}: the smooth normal at the vertex at "
                     f"({', '.join(f'{x:g}' for x in where)}) cancels out, faces wound "
                     f"opposite ways sharing it ({count} vertex(es) so), and Mitsuba's "
                     "normal there is left to rounding or set to (1, 0, 0): wind the "
                     "faces consistently (a double-sided card: one set of faces and a "
                     "twosided BSDF), give the mesh normals, or set face_normals")

    def _unused_lines(self, s: Plugin, path: str, key: str, count: int, word: str):
        """Refuse an OBJ with ``key`` lines ('vt' or 'vn') that no face refers to."""
        fix = "v/vt" if key == "vt" else "v//vn, or set face_normals"
        self.fail(s, f"{path}: {count} '{key}' line(s) but no face refers to one "
                     f"(Mitsuba gives every vertex {word} from memory it never fills, "
                     f"undefined): refer to them ({fix}) or delete the '{key}' lines")

    # ---------------------------------------------------------------- emitters
    def area_light(self, emitter: Plugin, first: int, count: int, kind: int):
        f = np.zeros(layout.LIGHT_WIDTH)
        i = np.zeros(layout.LIGHT_INTS, dtype=np.int64)
        f[_RGB] = np.broadcast_to(emitter.get("radiance", 1.0), 3)
        i[layout.LIGHT_KIND], i[layout.LIGHT_PRIM] = layout.AREA, first
        if kind == TRIANGLE:
            p = np.array(self.prims[first:first + count])
            p0, p1, p2 = (p[:, c:c + 3] for c in (layout.TRI_P0, layout.TRI_P1, layout.TRI_P2))
            areas = 0.5 * np.linalg.norm(np.cross(p1 - p0, p2 - p0), axis=1)
            if not areas.sum() > 0.0:
                # Mitsuba refuses it too ("DiscreteDistribution: no probability mass
                # found!"); a uniform choice of triangle would draw points of no area
                self.fail(emitter, "the mesh it sits on has zero area (every triangle is "
                                   "degenerate): nothing to emit from (Mitsuba refuses it "
                                   "too)")
            dist = DiscreteDistribution(areas)
            i[layout.LIGHT_CDF], i[layout.LIGHT_PRIM_COUNT] = len(self.light_cdf), count
            self.light_cdf += list(dist.cdf)
            f[layout.LIGHT_AREA] = areas.sum()
        elif kind == DISK:
            to_world = self.prims[first][layout.DISK_TO_WORLD:layout.DISK_TO_WORLD + 12]
            m = to_world.reshape(3, 4)[:, :3]
            f[layout.LIGHT_AREA] = math.pi * np.linalg.norm(np.cross(m[:, 0], m[:, 1]))
        else:
            f[layout.LIGHT_AREA] = 4 * math.pi * self.prims[first][layout.SPHERE_RADIUS] ** 2
        self.lights.append((f, i))
        self.light_lines.append(self._where(emitter))
        self.features |= FEATURE_BITS["light:area"]
        return len(self.lights) - 1

    def emitter(self, e: Plugin):
        f = np.zeros(layout.LIGHT_WIDTH)
        i = np.zeros(layout.LIGHT_INTS, dtype=np.int64)
        m = np.asarray(e.get("to_world", np.eye(4)), dtype=np.float64)
        i[layout.LIGHT_KIND] = layout.LIGHT_NAMES.index(e.type)
        placed = {"point": "position", "directional": "direction"}.get(e.type)
        if placed in e.props and "to_world" in e.props:
            self.fail(e, f"give either {placed} or to_world, not both (Mitsuba refuses both)")
        if e.type in ("point", "spot"):
            f[_RGB] = np.broadcast_to(e.get("intensity", 1.0), 3)
            f[layout.LIGHT_POSITION:layout.LIGHT_POSITION + 3] = (e.get("position", m[:3, 3])
                                                        if e.type == "point" else m[:3, 3])
            if e.type == "spot":
                m3 = m[:3, :3]
                g = m3 @ m3.T
                if np.max(np.abs(g / (np.trace(g) / 3.0) - np.eye(3))) > 1e-3:
                    # Mitsuba measures the cone in the light's own frame, M⁻¹(−d) normalised:
                    # a non-uniform scale or a shear stretches it (-60 % measured)
                    self.fail(e, "to_world must be a rotation and translation (a uniform scale "
                                 "is allowed): Mitsuba measures the cone in the scaled frame, "
                                 "which is not matched")
                cutoff = math.radians(float(e.get("cutoff_angle", 20.0)))
                beam = math.radians(float(e.get("beam_width", math.degrees(cutoff) * 0.75)))
                if not (cutoff > 0.0 and beam >= 0.0):
                    # Mitsuba's falloff (cutoff - θ)/(cutoff - beam) turns a negative cutoff
                    # into a bright ring; we lit nothing (-86 %, found by a probe)
                    self.fail(e, f"cutoff_angle={math.degrees(cutoff):g} and beam_width="
                                 f"{math.degrees(beam):g}: need cutoff_angle > 0 and "
                                 "beam_width >= 0 (degrees)")
                axis = m[:3, 2] / np.linalg.norm(m[:3, 2])
                f[layout.SPOT_AXIS:layout.SPOT_AXIS + 3] = axis
                f[layout.SPOT_COS_CUTOFF] = math.cos(cutoff)
                f[layout.SPOT_COS_BEAM] = math.cos(beam)
                f[layout.SPOT_CUTOFF] = cutoff
                f[layout.SPOT_INV_FALLOFF] = 1.0 / (cutoff - beam) if cutoff > beam else 0.0
        elif e.type == "directional":
            f[_RGB] = np.broadcast_to(e.get("irradiance", 1.0), 3)
            d = np.asarray(e.get("direction", m[:3, :3] @ np.array([0.0, 0.0, 1.0])), float)
            if "direction" not in e.props and abs(np.linalg.norm(d) - 1.0) > 1e-3:
                # Mitsuba shades with M·(0, 0, 1) as it is: a scale of 2 doubled the light
                self.fail(e, f"to_world maps (0, 0, 1) to a vector of length "
                             f"{np.linalg.norm(d):.4g}, not 1: Mitsuba uses it unnormalised "
                             "(the light scales with it), which is not matched; remove the "
                             "scale (or give a unit <rotate> axis)")
            if not np.linalg.norm(d) > 0:
                self.fail(e, "direction must be non-zero")
            f[layout.LIGHT_DIRECTION:layout.LIGHT_DIRECTION + 3] = d / np.linalg.norm(d)
        else:  # constant, envmap
            if self.env >= 0:
                self.fail(e, "only one environment emitter (constant or envmap) per scene")
            if e.type == "constant":
                f[_RGB] = np.broadcast_to(e.get("radiance", 1.0), 3)
            else:
                m3 = m[:3, :3]
                if np.max(np.abs(m3 @ m3.T - np.eye(3))) > 1e-3:
                    # Mitsuba looks up M⁻¹d unnormalised and samples M·d, unnormalised too
                    self.fail(e, "to_world must be a rotation (no scale or shear; Mitsuba does "
                                 "not normalise a <rotate> axis, so give a unit one): Mitsuba's "
                                 "envmap then looks up and samples directions that are not "
                                 "unit vectors, which cannot be matched")
                img = self._image(e)
                if img.shape[0] < 3 or img.shape[1] < 2:
                    # Mitsuba 3.9.1 renders a 2-row map with a lookup not matched (newer
                    # Mitsuba refuses maps under 2 x 3 pixels)
                    self.fail(e, f"{e.get('filename')}: {img.shape[1]} x {img.shape[0]} "
                                 "pixels; an envmap needs at least 2 columns and 3 rows")
                rgb = np.asarray(img, dtype=np.float64)[..., :3]
                lum = luminance.py_func(rgb[..., 0], rgb[..., 1], rgb[..., 2])
                if not np.any(lum > 0) and np.any(rgb != 0):
                    # Mitsuba samples the map by its luminance: with no positive mass its
                    # table is degenerate (max_depth 2: red 0.40 there, 0.57 here)
                    self.fail(e, f"{e.get('filename')}: its luminance is nowhere positive; "
                                 "Mitsuba cannot importance-sample it (its sampling table "
                                 "has no mass), so its image is not matched")
                if not np.any(lum[1:] > 0) and np.any(lum > 0):
                    # Mitsuba weights row y of its sampling table by sin(y π / (h - 1)):
                    # row 0 sits on the pole, weight 0, and a map lit there alone renders
                    # black in Mitsuba 3.9.1 (0.055 mean here, p = 5e-161)
                    self.fail(e, f"{e.get('filename')}: its luminance is positive in its top "
                                 "row only, which Mitsuba's sampling table weights by "
                                 "sin θ = 0 (the pole): its table has no mass and it renders "
                                 "the map black, so its image is not matched")
                i[layout.LIGHT_TEXTURE] = self.textures.add(img)
                f[layout.ENV_SCALE] = float(e.get("scale", 1.0))
                f[layout.ENV_TO_LOCAL:layout.ENV_TO_LOCAL + 9] = np.linalg.inv(
                    _nearest_rotation(m3)).ravel()
                pc = PiecewiseConstant2D(envmap_sampling_weights(img))
                self.env_marg, self.env_cond = pc.marginal_table, pc.conditional_table
            self.env = len(self.lights)
            self.features |= FEATURE_BITS["light:environment"]
            self.features |= FEATURE_BITS["light:nondelta"]
        self.lights.append((f, i))
        self.light_lines.append(self._where(e))

    # -------------------------------------------------------------------- all
    def build(self) -> PreparedScene:
        d = self.desc
        if ascii_lower(str(d.film.get("pixel_format", "rgb"))) != "rgb":    # any case, as Mitsuba
            self.fail(d.film, f"pixel_format {d.film.get('pixel_format')!r}: only rgb is "
                              "supported (the tracer writes 3 channels)")
        for name, allowed in _FILM_FORMATS.items():
            # how Mitsuba writes and stores the image, not what it renders; it refuses
            # other values (case aside)
            if ascii_lower(str(d.film.get(name, allowed[0]))) not in allowed:
                self.fail(d.film, f"{name} {d.film.get(name)!r}: Mitsuba takes "
                                  + ", ".join(allowed) + " (any case)")
        shape_bsdf, shape_light, shape_flip = [], [], []
        for index, s in enumerate(d.shapes):
            bsdf = next((c for c in s.children if c.kind == "bsdf"), None)
            em = next((c for c in s.children if c.kind == "emitter"), None)
            shape_bsdf.append(self.bsdf(bsdf, emitter=em is not None))
            first, count, kind = self.shape(s, index)
            flip = bool(s.get("flip_normals", False))
            if s.type == "sphere" and np.linalg.det(np.asarray(s.get("to_world", np.eye(4)),
                                                               float)[:3, :3]) < 0:
                flip = not flip     # Mitsuba's sphere turns its normals in under a mirror
            shape_flip.append(flip)
            shape_light.append(self.area_light(em, first, count, kind) if em else -1)
        for e in d.emitters:
            self.emitter(e)
        if any(i[layout.LIGHT_KIND] == layout.AREA for _, i in self.lights):
            self.features |= FEATURE_BITS["light:nondelta"]
        if len(self.lights) > 1:
            self.features |= FEATURE_BITS["light:many"]
        prims = np.array(self.prims, dtype=np.float64).reshape(-1, PRIM_WIDTH)
        info = np.array(self.info, dtype=np.int64).reshape(-1, 2)
        if len(prims) == 0:
            # no shapes: one degenerate triangle (no ray hits it) gives the hierarchy a
            # leaf (a root of zero primitives read as an interior node and crashed)
            prims = np.zeros((1, PRIM_WIDTH))
            info = np.array([[TRIANGLE, -1]], dtype=np.int64)
        nb, ni, order = build_bvh(prims, info)
        bvh_nodes, leaf_prims, leaf_info = pack_bvh(prims, info, nb, ni, order)
        integ = d.integrator
        # BSDFs with a null component (hide_emitters cannot be matched with them below)
        null = sorted({"bsdf:mask", "bsdf:thindielectric"} & d.features)
        if int(integ.get("samples_per_pass", 1)) < 1:
            # Mitsuba 3.9.1 refuses a negative value and crashes on 0 (a division by it)
            self.fail(integ, f"samples_per_pass={integ.get('samples_per_pass')}: must be "
                             ">= 1 (Mitsuba refuses a negative value and stops on 0)")
        if integ.type == "direct":
            max_depth, rr_depth = 2, INFINITE_DEPTH
            shading = integ.get("shading_samples")
            if shading is not None:
                # Mitsuba's default for both counts; it refuses it beside either of them,
                # and below 1 ("Must have at least 1 BSDF or emitter sample!")
                given = [n for n in ("emitter_samples", "bsdf_samples") if n in integ.props]
                if given:
                    self.fail(integ, f"shading_samples with {given[0]}: give one or the "
                                     "other (Mitsuba refuses both)")
                if int(shading) < 1:
                    self.fail(integ, f"shading_samples={shading}: must be >= 1 (Mitsuba "
                                     "refuses it)")
            samples = {n: int(integ.get(n, 1 if shading is None else shading))
                       for n in ("emitter_samples", "bsdf_samples")}
            for name in ("emitter_samples", "bsdf_samples"):
                if samples[name] < 1:
                    # Mitsuba then drops a technique (and with it delta lights or delta
                    # BSDFs); the tracer always uses both, weighted by MIS
                    self.fail(integ, f"{name}={integ.get(name)}: must be >= 1 (with 0 "
                                     "Mitsuba drops that technique and the light only it "
                                     "finds; not matched)")
            if integ.get("hide_emitters", False) and null:
                # Mitsuba's direct integrator keeps what is seen through a null component
                # (its valid_ray is the camera hit); the tracer's depth-2 path drops it
                self.fail(integ, f"hide_emitters with a {null[0][5:]} BSDF: Mitsuba's direct "
                                 "integrator shows the hidden environment through its null "
                                 "component, the tracer (a path of depth 2) does not; not "
                                 "matched")
            delta = [e for e in d.emitters if e.type in ("point", "spot", "directional")]
            if delta and samples["emitter_samples"] != 1:
                source = "emitter_samples" if shading is None else "shading_samples"
                self.fail(integ, f"{source}={samples['emitter_samples']} with a "
                                 f"{delta[0].type} light ({delta[0].line_text()}): Mitsuba "
                                 "3.9.1's direct integrator adds each sample of a delta light "
                                 "without dividing by emitter_samples (mitsuba3 issue 1861), "
                                 "so its image is too bright; not matched: use 1")
        else:
            max_depth = int(integ.get("max_depth", -1))
            rr_depth = int(integ.get("rr_depth", 5))
            if max_depth < -1:
                self.fail(integ, f"max_depth must be -1 (infinite) or >= 0, got {max_depth}")
            if max_depth < 0:
                max_depth = INFINITE_DEPTH
            if rr_depth < 1:
                self.fail(integ, f"rr_depth must be >= 1, got {rr_depth}")
            if integ.get("hide_emitters", False) and null and 2 <= max_depth < INFINITE_DEPTH:
                # at the last vertex, Mitsuba's llvm variant counts a path that only passed
                # through null components as valid, its scalar variant does not (a mask
                # sphere under an envmap, max_depth 2: the two differ at p = 1e-173, the
                # tracer matches scalar); neither can be matched for both
                self.fail(integ, f"hide_emitters with a {null[0][5:]} BSDF and max_depth "
                                 f"{max_depth}: Mitsuba's llvm and scalar variants render "
                                 "what is seen through its null component at the last bounce "
                                 "differently; not matched (use max_depth -1, or "
                                 "hide_emitters false)")
        tex_data, tex_info = self.textures.arrays()
        arrays = layout.SceneArrays(
            bvh_nodes=bvh_nodes, leaf_prims=leaf_prims, leaf_info=leaf_info, prims=prims,
            prim_info=info,
            shape_bsdf=np.array(shape_bsdf, dtype=np.int64),
            shape_light=np.array(shape_light, dtype=np.int64),
            shape_flip=np.array(shape_flip, dtype=np.bool_),
            bsdf_f=np.array([r[0] for r in self.bsdf_rows]).reshape(-1, layout.BSDF_WIDTH),
            bsdf_i=np.array([r[1] for r in self.bsdf_rows],
                            dtype=np.int64).reshape(-1, layout.BSDF_INTS),
            bsdf_tex=np.array([r[2] for r in self.bsdf_rows], dtype=np.int64).reshape(-1, 2),
            tex_data=tex_data, tex_info=tex_info,
            light_f=np.array([x[0] for x in self.lights]).reshape(-1, layout.LIGHT_WIDTH),
            light_i=np.array([x[1] for x in self.lights],
                             dtype=np.int64).reshape(-1, layout.LIGHT_INTS),
            light_cdf=np.array(self.light_cdf, dtype=np.float64),
            env_marginal=self.env_marg, env_conditional=self.env_cond,
            max_depth=int(max_depth), rr_depth=int(rr_depth),
            hide_emitters=bool(integ.get("hide_emitters", False)), env=int(self.env),
            keep_null_paths=integ.type == "direct")
        spp = int(d.sampler.get("sample_count", 4))
        if spp < 1:
            self.fail(d.sampler, f"sample_count {spp}: must be at least 1")
        if d.sampler.type != "independent":      # all the others render stratified
            if d.sampler.get("jitter", True) is False:
                self.fail(d.sampler, "jitter=\"false\" (samples at the strata's centres) is "
                          "not supported: its image is not the independent sampler's "
                          "expectation; leave jitter on")
            strength = int(d.sampler.get("strength", 2))
            if d.sampler.type == "orthogonal" and strength < 2:
                # Mitsuba's Bush construction of strength s draws from p^s rows: below
                # 2 it never returns (3.9.1 hangs at 0, at 1 above 4 samples)
                self.fail(d.sampler, f"strength {strength}: must be at least 2 (Mitsuba "
                          "3.9.1's orthogonal sampler never finishes a render below "
                          "that, so no reference could be built)")
            self.features |= layout.F_STRATIFIED
        n_tri = int(np.sum((info[:, layout.PRIM_KIND] == TRIANGLE)
                           & (info[:, layout.PRIM_SHAPE] >= 0)))
        return PreparedScene(d, camera_from_scene(d), arrays, self.features, spp, n_tri,
                             len(self.lights), self.bsdf_names, self.bsdf_lines,
                             self.light_lines)


_RGB = slice(layout.LIGHT_RADIANCE, layout.LIGHT_RADIANCE + 3)
#: the film's output settings Mitsuba 3.9.1 accepts (its default first)
_FILM_FORMATS = {"file_format": ("openexr", "exr", "pfm", "rgbe"),
                 "component_format": ("float16", "float32", "uint32")}
#: the least microfacet roughness: Mitsuba 3.9.1's ``MicrofacetDistribution`` raises
#: alpha_u and alpha_v to 1e-4, so a rough BSDF of alpha 1e-6 is one of 1e-4 there (an
#: outside review: a rough mirror of alpha 1e-5 under a directional light rendered 96 %
#: darker than Mitsuba, a rough dielectric of alpha 1e-200, whose alpha² underflows, NaN)
_ALPHA_MIN = 1e-4
#: BSDF colour properties that are albedos: a texture's texels must be >= 0
_ALBEDOS = ("reflectance", "diffuse_reflectance", "specular_reflectance",
            "specular_transmittance")
#: what a blendbsdf may hold: BSDFs with a density and no delta lobe
_BLENDABLE = ("diffuse", "roughconductor", "roughplastic", "roughdielectric", "twosided")
#: one-sided BSDFs whose samples from below the surface Mitsuba 3.9.1's blendbsdf weighs
#: wrongly beside a roughdielectric (a roughplastic, a twosided one and a second
#: roughdielectric are weighed right): its mean sample weight is not its eval's integral
_MISWEIGHED_BESIDE_GLASS = ("diffuse", "roughconductor")


def _one_sided_beside_glass(nested) -> tuple[str, str] | None:
    """(the one-sided BSDF, the rough dielectric) of a blend's two that Mitsuba 3.9.1
    samples with the wrong weight, or None."""
    types = [b.type for b in nested]
    if "roughdielectric" in types:
        other = types[1 - types.index("roughdielectric")]
        if other in _MISWEIGHED_BESIDE_GLASS:
            return other, "roughdielectric"
    return None


def _textures(p: Plugin):
    """The texture plugins under a plugin (its properties and nested plugins)."""
    for v in p.props.values():
        if isinstance(v, Plugin):
            yield v
    for child in p.children:
        yield from _textures(child)
_DIFFUSE_LIKE = (layout.DIFFUSE, layout.PLASTIC, layout.ROUGHPLASTIC)


_BARYCENTRIC_UV = ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0))


#: How far a sphere's to_world may be from a rotation times a uniform scale (relative).
_SIMILARITY_TOL = 1e-3


#: Mitsuba 3.9.1's OBJ loader reads a line into 1025 bytes and refuses one of this many
#: bytes or more (the LF not counted, a CR before it counted)
_OBJ_LINE_BYTES = 1024

#: A smooth vertex normal whose faces' sum is below this fraction of their weight (faces
#: wound opposite ways share the vertex) is left to rounding in Mitsuba's float32 sum, up
#: to 0.6 % of a radian at 1e-5, any direction near 0, and (1, 0, 0) at exactly 0
_CANCELLED = 1e-5


def _lone_cr(lines) -> str:
    """A refusal's hint where an OBJ's ``lines`` (split at LF, as bytes or text) hold a CR
    before their end: classic Mac OS line ends, one line to Mitsuba. Scanned only when a
    refusal is written, not on every load."""
    cr = "\r" if lines and isinstance(lines[0], str) else b"\r"
    return ("; its lines end in CR alone, classic Mac OS line ends, which Mitsuba reads as "
            "one line: convert them to LF"
            if any(cr in line.rstrip(cr) for line in lines) else "")


def _numbers(tokens, kind):
    """``tokens`` as a tuple of numbers read by ``kind`` (``text_numbers.parse_float`` or
    ``parse_int``: ASCII digits only, as Mitsuba reads them), or None if one is not."""
    try:
        return tuple(kind(x) for x in tokens)
    except ValueError:
        return None


def _vertex_normals(verts, faces, pidx, n_positions):
    """Smooth normals for a mesh without them, as Mitsuba computes: each face's normal
    weighted by its angle at the vertex (Thürmer and Wüthrich), summed per position; and
    per corner whether that sum cancels out (below ``_CANCELLED`` of its weight), where
    Mitsuba's float32 normal is left to rounding."""
    acc, weight = np.zeros((n_positions, 3)), np.zeros(n_positions)
    p = verts[faces]                                        # (F, 3 corners, 3)
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    area = np.linalg.norm(n, axis=1)
    n /= np.maximum(area, 1e-300)[:, None]
    for c in range(3):
        e1 = p[:, (c + 1) % 3] - p[:, c]
        e2 = p[:, (c + 2) % 3] - p[:, c]
        cos = np.sum(e1 * e2, axis=1) / np.maximum(
            np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1), 1e-300)
        angle = np.arccos(np.clip(cos, -1, 1))
        np.add.at(acc, pidx[faces[:, c]], n * angle[:, None])
        np.add.at(weight, pidx[faces[:, c]], np.where(area > 0, angle, 0.0))
    length = np.linalg.norm(acc, axis=1)
    cancelled = (weight > 0) & (length < _CANCELLED * weight)
    acc /= np.maximum(length, 1e-300)[:, None]
    return acc[pidx], cancelled[pidx]


def _nearest_rotation(m3: np.ndarray) -> np.ndarray:
    """``m3``, or where it is a rotation (or a mirror) only to the loader's tolerance (a
    matrix written to 4 decimals) the orthogonal matrix nearest it (its polar factor):
    an envmap's sampler turns its draws to world space by the inverse's transpose, which
    is the matrix only where it is orthogonal, and a 4-decimal rotation drew directions
    5e-5 off unit length, 5e-5 off the pdf of their lookup (an outside review)."""
    if np.max(np.abs(m3 @ m3.T - np.eye(3))) <= 1e-12:
        return m3
    u, _, vt = np.linalg.svd(m3)
    return u @ vt


def _rectangle():
    verts = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=np.float64)
    uvs = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64)
    return verts, [(0, 1, 2), (0, 2, 3)], uvs


# Mitsuba's cube, face by face: the four corners of each face (bit k of a corner index is
# the sign of axis k: set means +1) and the uv every face repeats; the face's triangles are
# (0, 1, 2) and (3, 0, 2) of its corners. The texture layout depends on this order.
_CUBE_FACES = ((1, 5, 4, 0), (3, 2, 6, 7), (1, 3, 7, 5), (5, 7, 6, 4), (4, 6, 2, 0),
               (3, 1, 0, 2))
_CUBE_FACE_UV = ((0.0, 1.0), (1.0, 1.0), (1.0, 0.0), (0.0, 0.0))


def _cube():
    verts, uvs, faces = [], [], []
    for corners in _CUBE_FACES:
        k = len(verts)
        verts += [[1.0 if c >> axis & 1 else -1.0 for axis in range(3)] for c in corners]
        uvs += _CUBE_FACE_UV
        faces += [(k, k + 1, k + 2), (k + 3, k, k + 2)]
    return np.array(verts), faces, np.array(uvs, dtype=np.float64)


def prepare_scene(scene, *, params: dict | None = None) -> PreparedScene:
    """A path, a ``SceneDescription`` or an already prepared scene → ``PreparedScene``.
    ``params`` override the scene's ``<default>`` values, so they need a path: a
    description or a prepared scene has its values already (they were ignored until 4
    December, an unknown name too)."""
    if params and not isinstance(scene, (str, bytes, os.PathLike)):
        raise ValueError(f"params={params!r}: scene parameters apply when the scene is read "
                         f"from its file; this {type(scene).__name__} was read already: give "
                         "its path, or load_scene(path, params=...) / "
                         "prepare_scene(path, params=...)")
    if isinstance(scene, PreparedScene):
        return scene
    desc = scene if isinstance(scene, SceneDescription) else load_scene(
        scene_path(scene, "scene", ", a SceneDescription or a PreparedScene"), params=params)
    return _Builder(desc).build()
