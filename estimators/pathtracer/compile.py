"""Scene description → the flat arrays the kernel reads (``CompiledScene``).

Shapes become primitives (rectangles and cubes two triangles a face, OBJ meshes their
triangles; spheres and disks stay analytic), BSDFs and emitters become rows of parameter
tables, images become one texture store, and the whole is indexed by the SAH hierarchy.
Mitsuba's defaults apply wherever the XML is silent (a shape without a BSDF is diffuse
0.5, or black if it emits; roughconductor and roughplastic default to Beckmann α = 0.1; dielectric to BK7 in
air; plastic to polypropylene in air; conductor to a perfect mirror).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from dataclasses import dataclass, field

import numpy as np

from ..distributions import DiscreteDistribution, PiecewiseConstant2D
from . import bsdfs as B
from . import emitters as E
from .camera import Camera, camera_from_scene
from .geometry import DISK, PRIM_WIDTH, SPHERE, TRIANGLE, build_bvh
from .scene import (MAX_ASSET_BYTES, Plugin, SceneDescription, SceneError, file_problem,
                    load_scene)
from .textures import (FILTERS, WRAPS, TextureStore, envmap_sampling_weights, read_image)

_MATERIALS = None
INFINITE_DEPTH = 1 << 40


def _materials() -> dict:
    global _MATERIALS
    if _MATERIALS is None:
        with open(os.path.join(os.path.dirname(__file__), "materials.json"),
                  encoding="utf-8") as f:
            _MATERIALS = json.load(f)
    return _MATERIALS


@dataclass
class CompiledScene:
    """Everything the kernel needs, as arrays, plus what a person needs to know."""

    desc: SceneDescription
    camera: Camera
    arrays: tuple
    features: int
    spp: int
    n_triangles: int
    n_lights: int
    bsdf_names: list = field(default_factory=list)

    @property
    def width(self) -> int:
        return self.camera.width

    def planted(self, *, light_scale: float = 1.0, albedo_scale: float = 1.0,
                bsdf: int | None = None) -> "CompiledScene":
        """A copy with a planted bug, for testing the render gate: every emitter's
        radiance/intensity scaled by ``light_scale``; BSDF ``bsdf``'s (default: the
        first textureless diffuse-like one) base colour scaled by ``albedo_scale``."""
        a = list(self.arrays)
        light_f = a[13].copy()
        light_f[:, 0:3] *= light_scale
        bf = a[8].copy()
        if albedo_scale != 1.0:
            if bsdf is None:
                bsdf = next((i for i, row in enumerate(a[9])
                             if row[0] in (B.DIFFUSE, B.PLASTIC, B.ROUGHPLASTIC)
                             and a[10][i, 0] < 0 and bf[i, 0:3].any()), None)
                if bsdf is None:
                    raise ValueError("the scene has no untextured diffuse-like BSDF to plant in")
            bf[bsdf, 0:3] *= albedo_scale
        a[13], a[8] = light_f, bf
        return dataclasses.replace(self, arrays=tuple(a))

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
        self.lights: list[tuple[np.ndarray, np.ndarray]] = []
        self.light_cdf: list[float] = [0.0]
        self.textures = TextureStore()
        self.texture_ids: dict[int, int] = {}
        self.env = -1
        self.env_marg = np.zeros(2)
        self.env_cond = np.zeros((1, 2))
        self.features = 0

    def fail(self, plugin: Plugin, message: str):
        raise SceneError(f"{self.desc.path}:{plugin.line}: <{plugin.kind} "
                         f"type=\"{plugin.type}\">: {message}")

    # ---------------------------------------------------------------- textures
    def _image(self, plugin: Plugin, filename: str, raw: bool = False) -> np.ndarray:
        path = filename if os.path.isabs(filename) else os.path.join(self.dir, filename)
        problem = file_problem(path, MAX_ASSET_BYTES)
        if problem:
            self.fail(plugin, problem)
        try:
            return read_image(path, raw=raw)
        except OSError as e:
            self.fail(plugin, str(e))

    def _bitmap(self, tex: Plugin) -> int:
        """Store a ``bitmap`` texture with its filter, wrap mode and ``to_uv``."""
        img = self._image(tex, tex.get("filename", ""), raw=bool(tex.get("raw", False)))
        options = {}
        for name, names, default in (("filter_type", FILTERS, "bilinear"),
                                     ("wrap_mode", WRAPS, "repeat")):
            value = tex.get(name, default)
            if value not in names:
                self.fail(tex, f"{name} {value!r}; supported: {', '.join(names)}")
            options[name] = names.index(value)
        m = np.asarray(tex.get("to_uv", np.eye(4)), dtype=np.float64)
        if np.any(m[2, [0, 1, 3]] != 0) or np.any(m[[0, 1], 2] != 0):
            self.fail(tex, "to_uv must map the uv plane to itself (x and y only)")
        to_uv = (m[0, 0], m[0, 1], m[0, 3], m[1, 0], m[1, 1], m[1, 3])
        tex._mean = float(img.mean())
        return self.textures.add(img, filter_type=options["filter_type"],
                                 wrap=options["wrap_mode"], to_uv=to_uv)

    def _colour(self, plugin: Plugin, name: str, default: float):
        """(rgb, texture id or -1, mean) of a colour property."""
        v = plugin.get(name, default)
        if isinstance(v, Plugin):
            key = id(v)
            if key not in self.texture_ids:
                self.texture_ids[key] = self._bitmap(v)
                self.features |= B.F_TEXTURES
            return np.zeros(3), self.texture_ids[key], v._mean
        rgb = np.broadcast_to(np.asarray(v, dtype=np.float64), 3).astype(np.float64)
        return rgb, -1, float(rgb.mean())

    # ------------------------------------------------------------------- BSDFs
    def _ior(self, plugin: Plugin, name: str, default: str) -> float:
        v = plugin.get(name, default)
        if isinstance(v, str):
            table = _materials()["dielectrics"]
            if v.lower() not in table:
                self.fail(plugin, f"unknown {name} {v!r}; named indices: "
                                  f"{', '.join(sorted(table))}")
            return float(table[v.lower()])
        return float(v)

    def _distribution(self, plugin: Plugin) -> int:
        d = plugin.get("distribution", "beckmann")
        if d not in ("ggx", "beckmann"):
            self.fail(plugin, f"distribution {d!r}; supported: ggx, beckmann")
        alpha = float(plugin.get("alpha", 0.1))
        if not alpha > 0:
            self.fail(plugin, f"alpha must be > 0, got {alpha}")
        return B.GGX if d == "ggx" else B.BECKMANN

    def bsdf(self, plugin: Plugin | None, emitter: bool = False) -> int:
        if plugin is None:
            # Mitsuba's default: diffuse 0.5, or black on an emitting shape
            plugin = Plugin("bsdf", "diffuse", {"reflectance": 0.0} if emitter else {}, 0)
            key = -2 if emitter else -1
        else:
            key = id(plugin)
        if key in self.bsdf_ids:
            return self.bsdf_ids[key]
        twosided = 0
        inner = plugin
        if plugin.type == "twosided":
            nested = [c for c in plugin.children if c.kind == "bsdf"]
            if len(nested) != 1:
                self.fail(plugin, "exactly one nested <bsdf> is supported (the same on "
                                  "both sides)")
            inner = nested[0]
            if inner.type == "dielectric":
                self.fail(plugin, "a twosided dielectric is not supported (Mitsuba "
                                  "accepts only reflective BSDFs inside twosided)")
            twosided = 1
            self.features |= B.F_TWOSIDED
        f = np.zeros(B.BSDF_WIDTH)
        i = np.zeros(4, dtype=np.int64)
        tex = np.full(2, -1, dtype=np.int64)
        kind = B.NAMES.index(inner.type)
        i[0], i[1] = kind, twosided
        self.features |= 1 << kind
        if kind == B.DIFFUSE:
            f[0:3], tex[0], _ = self._colour(inner, "reflectance", 0.5)
        elif kind in (B.CONDUCTOR, B.ROUGHCONDUCTOR):
            f[0:3], tex[0], _ = self._colour(inner, "specular_reflectance", 1.0)
            if "eta" in inner.props or "k" in inner.props:
                f[3:6] = np.broadcast_to(inner.get("eta", 0.0), 3)
                f[6:9] = np.broadcast_to(inner.get("k", 1.0), 3)
            else:
                name = inner.get("material", "none")
                table = _materials()["conductors"]
                if name not in table:
                    self.fail(inner, f"unknown material {name!r}; supported: "
                                     f"{', '.join(sorted(table))}")
                f[3:6], f[6:9] = table[name]["eta"], table[name]["k"]
            if kind == B.ROUGHCONDUCTOR:
                i[2] = self._distribution(inner)
                f[B.ALPHA] = float(inner.get("alpha", 0.1))
        elif kind == B.DIELECTRIC:
            f[0:3], tex[0], _ = self._colour(inner, "specular_reflectance", 1.0)
            f[3:6], tex[1], _ = self._colour(inner, "specular_transmittance", 1.0)
            f[B.ETA] = self._ior(inner, "int_ior", "bk7") / self._ior(inner, "ext_ior", "air")
        else:  # plastic, roughplastic
            f[0:3], tex[0], d_mean = self._colour(inner, "diffuse_reflectance", 0.5)
            f[3:6], tex[1], s_mean = self._colour(inner, "specular_reflectance", 1.0)
            eta = self._ior(inner, "int_ior", "polypropylene") / self._ior(inner, "ext_ior",
                                                                            "air")
            if eta == 1.0:
                self.fail(inner, "int_ior and ext_ior must differ")
            f[B.ETA] = eta
            f[B.EXTRA2] = s_mean / (d_mean + s_mean)
            i[3] = int(bool(inner.get("nonlinear", False)))
            if kind == B.PLASTIC:
                f[B.EXTRA1] = B.fresnel_diffuse_reflectance(1.0 / eta)
            else:
                i[2] = self._distribution(inner)
                alpha = float(inner.get("alpha", 0.1))
                f[B.ALPHA] = alpha
                table, internal = B.rough_coat_tables(alpha, int(i[2]), eta)
                f[B.TABLE:B.TABLE + B.TABLE_RES] = table
                f[B.EXTRA1] = internal
        self.bsdf_rows.append((f, i, tex))
        self.bsdf_names.append(plugin.type if not twosided else f"twosided({inner.type})")
        self.bsdf_ids[key] = len(self.bsdf_rows) - 1
        return self.bsdf_ids[key]

    # ------------------------------------------------------------------ shapes
    def _triangles(self, verts, faces, normals=None, uvs=None):
        """Append triangles; returns (first, count)."""
        first = len(self.prims)
        for k, (a, b, c) in enumerate(faces):
            row = np.zeros(PRIM_WIDTH)
            row[0:3], row[3:6], row[6:9] = verts[a], verts[b], verts[c]
            if normals is not None:
                row[9:12], row[12:15], row[15:18] = normals[a], normals[b], normals[c]
            if uvs is not None:
                row[18:20], row[20:22], row[22:24] = uvs[a], uvs[b], uvs[c]
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
        elif s.type == "obj":
            verts, faces, normals, uvs = self._obj(s)
            wverts = verts @ lin.T + off
            if normals is not None:
                normals = normals @ np.linalg.inv(lin)
            self._triangles(wverts, faces, normals, uvs)
        elif s.type == "sphere":
            c = m @ np.append(np.asarray(s.get("center", np.zeros(3)), float), 1.0)
            scales = np.linalg.norm(lin, axis=0)
            if not np.allclose(scales, scales[0], rtol=1e-6):
                self.fail(s, "a sphere's to_world must scale uniformly")
            r = float(s.get("radius", 1.0)) * scales[0]
            if not r > 0:
                self.fail(s, f"radius must be > 0, got {r}")
            row = np.zeros(PRIM_WIDTH)
            row[0:3], row[3] = c[:3], r
            row[4:13] = (lin / scales[0]).T.ravel()     # world-to-local rotation
            self.prims.append(row)
        elif s.type == "disk":
            if abs(np.linalg.det(lin)) == 0:
                self.fail(s, "to_world is singular")
            inv = np.linalg.inv(m)
            row = np.zeros(PRIM_WIDTH)
            row[0:12] = m[:3, :4].ravel()
            row[12:24] = inv[:3, :4].ravel()
            self.prims.append(row)
        kind = {"sphere": SPHERE, "disk": DISK}.get(s.type, TRIANGLE)
        self.info += [(kind, index)] * (len(self.prims) - n_before)
        return n_before, len(self.prims) - n_before, kind

    def _obj(self, s: Plugin):
        name = s.get("filename")
        if not name:
            self.fail(s, "set <string name=\"filename\" .../>")
        path = name if os.path.isabs(name) else os.path.join(self.dir, name)
        problem = file_problem(path, MAX_ASSET_BYTES)
        if problem:
            self.fail(s, problem)
        try:
            with open(path, encoding="utf-8") as fh:
                lines = fh.readlines()
        except (OSError, UnicodeDecodeError) as e:
            self.fail(s, f"cannot read {path} ({getattr(e, 'strerror', None) or e})")
        v, vt, vn = [], [], []
        corners = []
        for ln, line in enumerate(lines, 1):
            t = line.split()
            if not t or t[0].startswith("#"):
                continue
            try:
                if t[0] == "v":
                    v.append([float(x) for x in t[1:4]])
                elif t[0] == "vt":
                    vt.append([float(x) for x in t[1:3]])
                elif t[0] == "vn":
                    vn.append([float(x) for x in t[1:4]])
                elif t[0] == "f":
                    idx = []
                    for tok in t[1:]:
                        parts = (tok.split("/") + ["", ""])[:3]
                        idx.append(tuple(int(p) if p else 0 for p in parts))
                    for k in range(1, len(idx) - 1):
                        corners.append((idx[0], idx[k], idx[k + 1]))
            except ValueError:
                self.fail(s, f"{path}:{ln}: cannot parse {line.strip()!r}")
        if not corners:
            self.fail(s, f"{path}: no faces")
        v, vt, vn = np.array(v, float), np.array(vt, float), np.array(vn, float)

        def fix(i, n):
            return i - 1 if i > 0 else n + i

        verts, uvs, normals, faces, pidx = [], [], [], [], []
        use_vn = len(vn) > 0 and not s.get("face_normals", False)
        with_uv = {bool(ti) for tri in corners for (_, ti, _) in tri}
        if len(with_uv) > 1:
            self.fail(s, f"{path}: some faces have texture coordinates and some do not "
                         "(Mitsuba's uv on those is undefined); give every face vt indices "
                         "or none")
        try:
            for tri in corners:
                f = []
                for k, (pi, ti, ni) in enumerate(tri):
                    verts.append(v[fix(pi, len(v))])
                    pidx.append(fix(pi, len(v)))
                    # without texture coordinates Mitsuba's uv is the barycentric (b1, b2)
                    uvs.append([vt[fix(ti, len(vt))][0], 1.0 - vt[fix(ti, len(vt))][1]]
                               if ti else _BARYCENTRIC_UV[k])
                    normals.append(vn[fix(ni, len(vn))] if (ni and use_vn) else [0, 0, 0])
                    f.append(len(verts) - 1)
                faces.append(tuple(f))
        except IndexError:
            self.fail(s, f"{path}: a face refers to a vertex that does not exist")
        verts = np.array(verts)
        normals = np.array(normals, float)
        if s.get("face_normals", False):
            normals = None
        elif not use_vn:
            normals = _vertex_normals(verts, np.array(faces), np.array(pidx), len(v))
        return verts, faces, normals, np.array(uvs)

    # ---------------------------------------------------------------- emitters
    def area_light(self, emitter: Plugin, first: int, count: int, kind: int):
        f = np.zeros(E.LIGHT_WIDTH)
        i = np.zeros(4, dtype=np.int64)
        f[0:3] = np.broadcast_to(emitter.get("radiance", 1.0), 3)
        i[0], i[1] = E.AREA, first
        if kind == TRIANGLE:
            p = np.array(self.prims[first:first + count])
            areas = 0.5 * np.linalg.norm(np.cross(p[:, 3:6] - p[:, 0:3], p[:, 6:9] - p[:, 0:3]),
                                         axis=1)
            dist = DiscreteDistribution(areas)
            i[2], i[3] = len(self.light_cdf), count
            self.light_cdf += list(dist.cdf)
            f[3] = areas.sum()
        elif kind == DISK:
            m = self.prims[first][0:12].reshape(3, 4)[:, :3]
            f[3] = math.pi * np.linalg.norm(np.cross(m[:, 0], m[:, 1]))
        else:
            f[3] = 4 * math.pi * self.prims[first][3] ** 2
        self.lights.append((f, i))
        self.features |= E_FEATURES["area"]
        return len(self.lights) - 1

    def emitter(self, e: Plugin):
        f = np.zeros(E.LIGHT_WIDTH)
        i = np.zeros(4, dtype=np.int64)
        m = np.asarray(e.get("to_world", np.eye(4)), dtype=np.float64)
        if e.type in ("point", "spot"):
            f[0:3] = np.broadcast_to(e.get("intensity", 1.0), 3)
            f[3:6] = e.get("position", m[:3, 3]) if e.type == "point" else m[:3, 3]
            if e.type == "spot":
                i[0] = E.SPOT
                cutoff = math.radians(float(e.get("cutoff_angle", 20.0)))
                beam = math.radians(float(e.get("beam_width", math.degrees(cutoff) * 0.75)))
                axis = m[:3, 2] / np.linalg.norm(m[:3, 2])
                f[12:15] = axis
                f[15], f[16], f[17] = math.cos(cutoff), math.cos(beam), cutoff
                f[18] = 1.0 / (cutoff - beam) if cutoff > beam else 0.0
            else:
                i[0] = E.POINT
        elif e.type == "directional":
            i[0] = E.DIRECTIONAL
            f[0:3] = np.broadcast_to(e.get("irradiance", 1.0), 3)
            d = np.asarray(e.get("direction", m[:3, :3] @ np.array([0.0, 0.0, 1.0])), float)
            if not np.linalg.norm(d) > 0:
                self.fail(e, "direction must be non-zero")
            f[3:6] = d / np.linalg.norm(d)
        else:  # constant, envmap
            if self.env >= 0:
                self.fail(e, "only one environment emitter (constant or envmap) per scene")
            if e.type == "constant":
                i[0] = E.CONSTANT
                f[0:3] = np.broadcast_to(e.get("radiance", 1.0), 3)
            else:
                i[0] = E.ENVMAP
                img = self._image(e, e.get("filename", ""))
                i[1] = self.textures.add(img)
                f[0] = float(e.get("scale", 1.0))
                f[1:10] = np.linalg.inv(m[:3, :3]).ravel()
                pc = PiecewiseConstant2D(envmap_sampling_weights(img))
                self.env_marg, self.env_cond = pc.marginal_cdf, pc.conditional_cdf
            self.env = len(self.lights)
            self.features |= E_FEATURES["env"]
        if e.type in ("constant", "envmap"):
            self.features |= E_FEATURES["nondelta"]
        self.lights.append((f, i))

    # -------------------------------------------------------------------- all
    def build(self) -> CompiledScene:
        d = self.desc
        shape_bsdf, shape_light, shape_flip = [], [], []
        for index, s in enumerate(d.shapes):
            bsdf = next((c for c in s.children if c.kind == "bsdf"), None)
            em = next((c for c in s.children if c.kind == "emitter"), None)
            shape_bsdf.append(self.bsdf(bsdf, emitter=em is not None))
            first, count, kind = self.shape(s, index)
            shape_flip.append(bool(s.get("flip_normals", False)))
            shape_light.append(self.area_light(em, first, count, kind) if em else -1)
        for e in d.emitters:
            self.emitter(e)
        if any(i[0] == E.AREA for _, i in self.lights):
            self.features |= E_FEATURES["nondelta"]
        if len(self.lights) > 1:
            self.features |= E_FEATURES["many"]
        prims = np.array(self.prims, dtype=np.float64).reshape(-1, PRIM_WIDTH)
        info = np.array(self.info, dtype=np.int64).reshape(-1, 2)
        if len(prims) == 0:
            nb, ni, order = np.array([[1.0, 1, 1, -1, -1, -1]]), \
                np.array([[0, 0, 0]], dtype=np.int64), np.zeros(0, dtype=np.int64)
            ni[0, 1] = 0
        else:
            nb, ni, order = build_bvh(prims, info)
        integ = d.integrator
        if integ.type == "direct":
            max_depth, rr_depth = 2, INFINITE_DEPTH
        else:
            max_depth = int(integ.get("max_depth", -1))
            rr_depth = int(integ.get("rr_depth", 5))
            if max_depth < 0:
                max_depth = INFINITE_DEPTH
            if rr_depth < 1:
                self.fail(integ, f"rr_depth must be >= 1, got {rr_depth}")
        ints = np.array([max_depth, rr_depth, int(bool(integ.get("hide_emitters", False))),
                         self.env], dtype=np.int64)
        tex_data, tex_info = self.textures.arrays()
        bf = np.array([r[0] for r in self.bsdf_rows]).reshape(-1, B.BSDF_WIDTH)
        bi = np.array([r[1] for r in self.bsdf_rows], dtype=np.int64).reshape(-1, 4)
        btex = np.array([r[2] for r in self.bsdf_rows], dtype=np.int64).reshape(-1, 2)
        light_f = np.array([x[0] for x in self.lights]).reshape(-1, E.LIGHT_WIDTH)
        light_i = np.array([x[1] for x in self.lights], dtype=np.int64).reshape(-1, 4)
        arrays = (nb, ni, order, prims, info, np.array(shape_bsdf, dtype=np.int64),
                  np.array(shape_light, dtype=np.int64), np.array(shape_flip, dtype=np.bool_),
                  bf, bi, btex, tex_data, tex_info, light_f, light_i,
                  np.array(self.light_cdf, dtype=np.float64), self.env_marg, self.env_cond,
                  ints)
        spp = int(d.sampler.get("sample_count", 4))
        n_tri = int(np.sum(info[:, 0] == TRIANGLE)) if len(info) else 0
        return CompiledScene(d, camera_from_scene(d), arrays, self.features, spp, n_tri,
                             len(self.lights), self.bsdf_names)


# feature bits of the lights (the kernel's numbering; see _kernel.py)
E_FEATURES = {"env": 1 << 8, "area": 1 << 9, "nondelta": 1 << 10, "many": 1 << 11}


_BARYCENTRIC_UV = ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0))


def _vertex_normals(verts, faces, pidx, n_positions):
    """Smooth normals for a mesh without them, as Mitsuba computes: each face's normal
    weighted by its angle at the vertex (Thürmer and Wüthrich), summed per position."""
    acc = np.zeros((n_positions, 3))
    p = verts[faces]                                        # (F, 3 corners, 3)
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    for c in range(3):
        e1 = p[:, (c + 1) % 3] - p[:, c]
        e2 = p[:, (c + 2) % 3] - p[:, c]
        cos = np.sum(e1 * e2, axis=1) / np.maximum(
            np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1), 1e-300)
        np.add.at(acc, pidx[faces[:, c]], n * np.arccos(np.clip(cos, -1, 1))[:, None])
    acc /= np.maximum(np.linalg.norm(acc, axis=1, keepdims=True), 1e-300)
    return acc[pidx]


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


def compile_scene(scene, *, params: dict | None = None) -> CompiledScene:
    """A path, a ``SceneDescription`` or an already compiled scene → ``CompiledScene``."""
    if isinstance(scene, CompiledScene):
        return scene
    desc = scene if isinstance(scene, SceneDescription) else load_scene(str(scene),
                                                                        params=params)
    return _Builder(desc).build()
