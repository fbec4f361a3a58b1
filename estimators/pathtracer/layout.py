"""The path tracer's data layout, in one place: the arrays a prepared scene hands to
the kernel (``SceneArrays``, a ``NamedTuple`` that numba takes as one argument), the
named columns of every table, the type codes, and the feature bits that the scene
preparation sets, the kernel specialises on and the planner reads.

Every other module reads and writes rows through these names; nothing indexes a column
by a bare number. Reordering a column here moves it everywhere.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class SceneArrays(NamedTuple):
    """Everything the kernel reads, by name. Tables are one row per item. The BVH tables
    (``bvh_nodes, leaf_prims, leaf_info``) are C-contiguous with exactly the widths
    below: the traversal reads them flat, row · width + column (``flat.flat_get``)."""

    bvh_nodes: np.ndarray       # (nodes, NODE_WIDTH) float: 4-wide, see the NODE_ columns
    leaf_prims: np.ndarray      # (prims + 3 groups, LEAF_WIDTH) float: intersection data
                                # in leaf order, then the triangle groups' lanes
    leaf_info: np.ndarray       # (prims, LEAF_INFO_WIDTH) int: LEAF_KIND, LEAF_PRIM (row of prims),
                                # LEAF_GROUP, LEAF_GROUP_SIZE
    prims: np.ndarray           # (prims, PRIM_WIDTH) float: see the PRIM_ columns
    prim_info: np.ndarray       # (prims, 2) int: PRIM_KIND, PRIM_SHAPE
    shape_bsdf: np.ndarray      # (shapes,) int: row of the BSDF tables
    shape_light: np.ndarray     # (shapes,) int: row of the light tables, -1 if none
    shape_flip: np.ndarray      # (shapes,) bool: flip_normals
    bsdf_f: np.ndarray          # (bsdfs, BSDF_WIDTH) float: see the BSDF_ columns
    bsdf_i: np.ndarray          # (bsdfs, BSDF_INTS) int: see the BSDF_ columns
    bsdf_tex: np.ndarray        # (bsdfs, 2) int: texture of colour slot 0 / 1, -1 if none
    tex_data: np.ndarray        # (texels * 3,) float: every image back to back
    tex_info: np.ndarray        # (textures, TEX_COLUMNS) float: see the TEX_ columns
    light_f: np.ndarray         # (lights, LIGHT_WIDTH) float: see the LIGHT_ columns
    light_i: np.ndarray         # (lights, LIGHT_INTS) int: see the LIGHT_ columns
    light_cdf: np.ndarray       # (n,) float: triangle-area CDFs of mesh lights, back to back
    env_marginal: np.ndarray    # envmap sampling: marginal CDF over rows
    env_conditional: np.ndarray  # envmap sampling: conditional CDFs per row
    max_depth: int              # path length limit (INFINITE_DEPTH: none)
    rr_depth: int               # Russian roulette from this depth on
    hide_emitters: bool         # camera rays do not see emitters
    env: int                    # light row of the environment, -1 if none
    keep_null_paths: bool       # the direct integrator: no valid_ray (Mitsuba's has none)


INFINITE_DEPTH = 1 << 40

# ------------------------------------------------------------------ feature bits
#: The one table of feature bits: scene feature name -> bit. The scene loader names
#: features this way (``SceneDescription.features``), the preparation sets the bits of
#: the ones a scene uses, the kernel is specialised on the mask (code of an unset bit is
#: removed), and the planner reads the names. The ``light:`` bits describe the lights
#: as a whole (set by the preparation, not by one element).
FEATURE_BITS = {
    "bsdf:diffuse": 1 << 0, "bsdf:conductor": 1 << 1, "bsdf:roughconductor": 1 << 2,
    "bsdf:dielectric": 1 << 3, "bsdf:plastic": 1 << 4, "bsdf:roughplastic": 1 << 5,
    "texture:bitmap": 1 << 6,
    "bsdf:twosided": 1 << 7,
    "light:environment": 1 << 8,    # a constant or envmap emitter exists
    "light:area": 1 << 9,           # emitting shapes exist (hits add emission with MIS)
    "light:nondelta": 1 << 10,      # some light can be hit or has a density (MIS)
    "light:many": 1 << 11,          # more than one light (light selection)
    "bsdf:roughdielectric": 1 << 12, "bsdf:thindielectric": 1 << 13,
    "bsdf:blendbsdf": 1 << 14, "bsdf:mask": 1 << 15,
    # a BSDF reads Mitsuba's shading frame (tangent s along dp/du: anisotropic roughness);
    # without it the kernel keeps any frame around the normal (isotropic BSDFs)
    "shading:frame": 1 << 16,
    "bsdf:normalmap": 1 << 17,
    # the stratified or multijitter sampler: each pixel's samples stratified per dimension
    "sampler:stratified": 1 << 18,
}
ALL_FEATURES = sum(FEATURE_BITS.values())
F_DIFFUSE, F_CONDUCTOR, F_ROUGHCONDUCTOR, F_DIELECTRIC, F_PLASTIC, F_ROUGHPLASTIC = (
    FEATURE_BITS[f"bsdf:{name}"] for name in ("diffuse", "conductor", "roughconductor",
                                              "dielectric", "plastic", "roughplastic"))
F_ROUGHDIELECTRIC, F_THINDIELECTRIC, F_BLEND, F_MASK = (
    FEATURE_BITS[f"bsdf:{name}"] for name in ("roughdielectric", "thindielectric",
                                              "blendbsdf", "mask"))
#: BSDFs with a null component (the ray goes on unchanged: Mitsuba's ``Null`` flag); a
#: path that only passed through them keeps Mitsuba's ``valid_ray`` false
F_NULL_BSDFS = F_THINDIELECTRIC | F_MASK
F_TEXTURES = FEATURE_BITS["texture:bitmap"]
F_TWOSIDED = FEATURE_BITS["bsdf:twosided"]
F_ENV = FEATURE_BITS["light:environment"]
F_AREA_LIGHTS = FEATURE_BITS["light:area"]
F_NONDELTA_LIGHTS = FEATURE_BITS["light:nondelta"]
F_MANY_LIGHTS = FEATURE_BITS["light:many"]
F_FRAME = FEATURE_BITS["shading:frame"]
F_NORMALMAP = FEATURE_BITS["bsdf:normalmap"]
F_STRATIFIED = FEATURE_BITS["sampler:stratified"]
#: the bits the BSDF code reads (BSDF types, textures, two-sided)
ALL_BSDF_FEATURES = sum(bit for name, bit in FEATURE_BITS.items()
                        if name.startswith(("bsdf:", "texture:")))

# ------------------------------------------------------------------- primitives
TRIANGLE, SPHERE, DISK = 0, 1, 2
PRIM_KIND, PRIM_SHAPE = 0, 1                # prim_info columns
PRIM_WIDTH = 24
# triangle: vertices, vertex normals (all zero: face normal only), texture coordinates
TRI_P0, TRI_P1, TRI_P2 = 0, 3, 6
TRI_N0, TRI_N1, TRI_N2 = 9, 12, 15
TRI_UV0, TRI_UV1, TRI_UV2 = 18, 20, 22
# sphere: centre, radius, world-to-local rotation (row major, for uv)
SPHERE_CENTER, SPHERE_RADIUS, SPHERE_ROTATION = 0, 3, 4
# disk (the unit disk at z = 0): local-to-world and world-to-local, 3 × 4 row major
DISK_TO_WORLD, DISK_TO_LOCAL = 0, 12

# -------------------------------------------------------------------------- BVH
# bvh_nodes: a 4-wide hierarchy, one 256-byte row (32 float64) per node, 32-byte aligned,
# holding its (up to) four children: their boxes coordinate by coordinate (lo x of
# children 0-3, lo y, lo z, hi x, hi y, hi z: one 4-lane SIMD load each, so a ray is
# tested against all four boxes at once), then their links and counts. The root is row 0
# (its own box is the union of its children's). The links and counts are int64 values
# stored bit for bit in the float64 rows (``geometry.child_links`` views them).
NODE_ARITY = 4                  # children per node
NODE_LO, NODE_HI = 0, 12        # box corners: lo of axis a of child i at NODE_LO + 4 a + i
NODE_LINK = 24                  # child i at NODE_LINK + i: an interior child's row of
                                # bvh_nodes; a leaf's first slot in leaf_prims
NODE_COUNT = 28                 # child i at NODE_COUNT + i: a leaf's number of primitives
                                # (>= 0); -1: interior child; an unused slot is a leaf of 0
                                # primitives with an empty box (every corner +inf: no ray
                                # enters it)
NODE_WIDTH = 32
# leaf_prims: what the ray test reads, copied in leaf order (no indirection): a triangle's
# first vertex and its two edges (p1 - p0, p2 - p0, as the test would compute them), a
# sphere's centre and radius, a disk's world-to-local 3 × 4
LEAF_P0, LEAF_E1, LEAF_E2 = 0, 3, 6
LEAF_CENTER, LEAF_RADIUS = 0, 3
LEAF_TO_LOCAL = 0
LEAF_WIDTH = 12
# After the rows of every primitive come the triangle groups: up to 4 consecutive
# triangles of a leaf, tested in one pass (``geometry._tri4_entry``), as 3 rows (36
# values: the 4 lanes of p0 x, p0 y, p0 z, e1 x ... e2 z, 4 values each; lanes past the
# group's size are 0, a degenerate triangle no ray hits).
LEAF_GROUP_ROWS = 3
# leaf_info columns: primitive kind, row of prims, and on the first row of a triangle
# group the row of leaf_prims where its lanes start (-1 elsewhere) and its size (0
# elsewhere)
LEAF_KIND, LEAF_PRIM, LEAF_GROUP, LEAF_GROUP_SIZE = 0, 1, 2, 3
LEAF_INFO_WIDTH = 4

# ------------------------------------------------------------------------ BSDFs
BSDF_NAMES = ("diffuse", "conductor", "roughconductor", "dielectric", "plastic",
              "roughplastic", "roughdielectric", "thindielectric", "blendbsdf",
              "mask", "normalmap")      # type codes are indices into this
(DIFFUSE, CONDUCTOR, ROUGHCONDUCTOR, DIELECTRIC, PLASTIC, ROUGHPLASTIC, ROUGHDIELECTRIC,
 THINDIELECTRIC, BLEND, MASK, NORMALMAP) = range(11)
#: the composite BSDFs: rows that point at other rows (``BSDF_CHILD0/1``) and have no
#: lobe of their own. A ``mask`` holds a basic BSDF or a ``blendbsdf``; a ``blendbsdf``
#: holds two basic BSDFs with a density (no delta lobe), so that nothing nests deeper.
COMPOSITE = (BLEND, MASK)
#: feature bit of each BSDF type code
BSDF_BITS = tuple(FEATURE_BITS[f"bsdf:{name}"] for name in BSDF_NAMES)
GGX, BECKMANN = 0, 1
# bsdf_i columns
BSDF_KIND, BSDF_TWOSIDED, BSDF_DISTRIBUTION, BSDF_NONLINEAR = range(4)
BSDF_CHILD0, BSDF_CHILD1 = 4, 5     # blendbsdf: its two rows; mask, normalmap: its one row
# normalmap (a wrapper at the top of a shape's BSDF, holding one basic BSDF; its image in
# bsdf_tex slot 0): Mitsuba's two switches, in columns no other use of the row has
NORMALMAP_FLIP_INVALID, NORMALMAP_SHADOWING = BSDF_DISTRIBUTION, BSDF_NONLINEAR
BSDF_FRAME = 6                  # 1: the row or one it holds needs Mitsuba's shading frame
BSDF_INTS = 7
# bsdf_f columns. Colour slots 0 and 1 (a texture in bsdf_tex may replace either):
COLOR0, COLOR1 = 0, 3           # diffuse/specular reflectance, specular transmittance
COND_ETA, COND_K = 3, 6         # conductors: complex index per channel
ETA = 9                         # dielectrics, plastics: interior / exterior index
COAT_INTERNAL = 10              # plastics: diffuse light the coat reflects back down
SPECULAR_WEIGHT = 11            # plastics: probability weight of the specular lobe
ALPHA = 12                      # microfacet roughness (alpha_u: along the tangent s)
ALPHA_V = 13                    # roughness along t = n × s (alpha_v; = ALPHA if isotropic)
MIX = 14                        # blendbsdf: weight of the second BSDF; mask: opacity.
                                # A texture in bsdf_tex slot 0 replaces it (luminance)
COAT_TABLE = 16                 # roughplastic: coat transmittance at cos θ = linspace(0, 1)
COAT_TABLE_RES = 64
BSDF_WIDTH = COAT_TABLE + COAT_TABLE_RES

# ---------------------------------------------------------------------- lights
LIGHT_NAMES = ("area", "point", "spot", "directional", "constant", "envmap")
AREA, POINT, SPOT, DIRECTIONAL, CONSTANT, ENVMAP = range(6)
# light_i columns
LIGHT_KIND = 0
LIGHT_PRIM = 1                  # area: first primitive of the shape
LIGHT_TEXTURE = 1               # envmap: its image
LIGHT_CDF = 2                   # mesh area light: offset of its triangle CDF in light_cdf
LIGHT_PRIM_COUNT = 3            # mesh area light: its number of triangles
LIGHT_INTS = 4
# light_f columns
LIGHT_RADIANCE = 0              # radiance, intensity or irradiance (rgb)
LIGHT_AREA = 3                  # area light: the shape's surface area
LIGHT_POSITION = 3              # point, spot
LIGHT_DIRECTION = 3             # directional: unit direction of travel
ENV_SCALE = 0                   # envmap: radiance scale
ENV_TO_LOCAL = 1                # envmap: world-to-local rotation (3 × 3 row major)
SPOT_AXIS = 12                  # spot: unit axis
SPOT_COS_CUTOFF, SPOT_COS_BEAM, SPOT_CUTOFF, SPOT_INV_FALLOFF = 15, 16, 17, 18
LIGHT_WIDTH = 24

# --------------------------------------------------------------------- textures
TEX_OFFSET, TEX_WIDTH, TEX_HEIGHT, TEX_FILTER, TEX_WRAP = range(5)
TEX_UV = 5                      # 6 entries: the to_uv affine map, rows (a, b, c), (d, e, f)
TEX_COLUMNS = TEX_UV + 6
FILTERS = ("bilinear", "nearest")
BILINEAR, NEAREST = 0, 1
WRAPS = ("repeat", "clamp", "mirror")
REPEAT, CLAMP, MIRROR = 0, 1, 2
