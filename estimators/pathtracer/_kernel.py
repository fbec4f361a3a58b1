"""The path-tracing kernel: unidirectional path tracing with next-event estimation and
multiple importance sampling (power heuristic) against BSDF sampling, Russian roulette
after ``rr_depth`` (Mitsuba's rule: continue with probability min(max throughput · η², 0.95)),
delta BSDFs and delta lights, over tiles (ranges of them on numba's threads).

This file is the template of the kernels: ``render.specialised_kernel`` copies it with
the feature block below rewritten (``FEATURES``, a bit mask of what a scene uses; -1 for
the general kernel), and numba compiles the copy with that value as a constant, so LLVM
removes the code a scene does not need. The per-ray functions are inlined (numba IR
inlining): a call that passes arrays costs reference-count updates that all threads
share, which halved the speed before. ``trace`` is inlined too, into ``_trace_samples``,
which the tile loops call once per ``CHUNK`` samples of a pixel (at a few samples a
pixel, once per group of pixels: ``pixel_group``): numba zeroes every
return slot of a function's calls on entry (about 1.3 KB for ``trace``), and with a call
per sample that set-up cost more than the camera ray and the pixel's bookkeeping together
(measured on the Cornell box, one thread, max_depth 0: 38 ms -> 10.5 ms at 128², 16 spp;
the whole render 151-159 -> 117-126 ms; images bit-identical).

Random numbers are counter-based (splitmix64 of seed, pixel and sample index, then a
Weyl sequence), so an image is bit-identical whatever the number of threads. A
stratified sampler's strata (Kensler's permutations) are computed for a chunk's samples
at once as its paths reach each dimension (``_strata_slot``): the same values, in loops
LLVM vectorises.
"""

import math

import numpy as np

from estimators._compile_options import THREADED, fused
from estimators.pathtracer.bsdfs import bsdf_eval, bsdf_is_smooth, bsdf_sample
from estimators.pathtracer.camera import (CAMERA_KIND, ORTHOGRAPHIC, SPLAT_CHANNELS,
                                          _orthographic_ray, _perspective_ray, splat_kernel,
                                          splat_scratch)
from estimators.pathtracer.emitters import area_pdf, eval_environment, is_delta, sample_emitter
from estimators.pathtracer.geometry import (coordinate_system, intersect, new_stack, occluded,
                                            shading_frame, surface, to_local, to_world)
from estimators.pathtracer.layout import (ALL_BSDF_FEATURES, ALL_FEATURES, BSDF_FRAME,
                                          F_AREA_LIGHTS, F_ENV, F_FRAME, F_MANY_LIGHTS,
                                          F_NONDELTA_LIGHTS, F_NULL_BSDFS, F_STRATIFIED,
                                          LIGHT_KIND,
                                          LIGHT_RADIANCE, PRIM_SHAPE)
from estimators.warps import ONE_MINUS_EPSILON

# --- features (rewritten by render.specialised_kernel) ---
FEATURES = -1
# --- end features ---

MASK = FEATURES & ALL_FEATURES if FEATURES >= 0 else ALL_FEATURES
BSDF_MASK = MASK & ALL_BSDF_FEATURES

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)
_TO_UNIT = 2.0 ** -53
_EPS = 1e-7


@fused(inline="always")
def _mix(z):
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


_U32 = np.uint64(0xFFFFFFFF)


@fused(inline="always")
def _walk_step(i, w, p):
    """One step of Kensler's walk (``permute``): a hash that is a bijection on 0..w, w + 1
    a power of two. Only the low 32 bits of ``i`` and of the products matter (the paper's
    32-bit arithmetic): no bit above them reaches the result, which ``& w`` keeps."""
    i ^= p
    i *= np.uint64(0xe170893d)
    i ^= p >> np.uint64(16)
    i ^= (i & w) >> np.uint64(4)
    i ^= p >> np.uint64(8)
    i *= np.uint64(0x0929eb3f)
    i ^= p >> np.uint64(23)
    i ^= (i & w) >> np.uint64(1)
    i *= np.uint64(1) | (p >> np.uint64(27))
    i *= np.uint64(0x6935fa69)
    i ^= (i & w) >> np.uint64(11)
    i *= np.uint64(0x74dcb303)
    i ^= (i & w) >> np.uint64(2)
    i *= np.uint64(0x9e501cc3)
    i ^= (i & w) >> np.uint64(2)
    i *= np.uint64(0xc860a3df)
    i &= w
    return i ^ (i >> np.uint64(5))


@fused(inline="always")
def _walk_mask(n):
    """w: the next power of two at or above n, minus one."""
    w = n - np.uint64(1)
    w |= w >> np.uint64(1)
    w |= w >> np.uint64(2)
    w |= w >> np.uint64(4)
    w |= w >> np.uint64(8)
    return w | (w >> np.uint64(16))


@fused(_nrt=False)
def permute(i, n, p):
    """Element ``i`` of a pseudo-random permutation of 0..n-1 chosen by ``p`` (Kensler,
    "Correlated multi-jittered sampling", 2013: a hash that is a bijection on the next
    power of two, walked until it lands below n); 32-bit arithmetic in uint64 lanes."""
    i, n, p = np.uint64(i), np.uint64(n), np.uint64(p) & _U32
    w = _walk_mask(n)
    while True:
        i = _walk_step(i, w, p)
        if i < n:
            # n a power of two (w = n - 1): the walk ends here and % n is a mask
            return (i + p) & w if n & w == np.uint64(0) else (i + p) % n


@fused(inline="always")
def _permute_rows(v, c, n, p):
    """``v[:c] = permute(v[:c], n, p)`` in place, the same values: for n a power of two
    one step of the walk, in a loop LLVM vectorises; otherwise two steps there, and the
    rows whose walk is longer finish in a scalar pass."""
    w = _walk_mask(n)
    p = p & _U32
    if n & w == np.uint64(0):
        for j in range(c):
            v[j] = (_walk_step(np.uint64(v[j]), w, p) + p) & w
        return
    for j in range(c):
        i = _walk_step(np.uint64(v[j]), w, p)
        v[j] = i if i < n else _walk_step(i, w, p)
    off = p % n                     # (i + p) % n, as i + p % n less n when it passes n
    for j in range(c):
        i = np.uint64(v[j])
        while i >= n:
            i = _walk_step(i, w, p)
        i += off
        v[j] = i - n if i >= n else i


@fused(inline="always")
def _jitter1(o, u, n):
    """Stratum o of n jittered by u: (o + u) / n, clamped below 1 ((n - 1 + u) / n rounds
    to 1 for u within an ulp of 1)."""
    return min((float(o) + u) / float(n), ONE_MINUS_EPSILON)


@fused(_nrt=False)
def _stratum(u, s, n, seed):
    """Sample s of n in one dimension: stratum permute(s) of n, jittered by u."""
    return _jitter1(permute(s, n, _mix(seed) >> np.uint64(32)), u, n)


@fused(_nrt=False)
def grid_columns(n):
    """Columns m of the m × k grid a 2-D dimension of n stratified samples uses
    (``_stratum2``): n / k, k the largest divisor of n up to √n; 0 where that grid would be
    more than 4 times wider than tall (n prime, or nearly): the 2-D dimension is then a
    rank-1 lattice (``lattice_generator``)."""
    n = np.uint64(n)
    k = np.uint64(math.sqrt(float(n)))
    while n % k != np.uint64(0):
        k -= np.uint64(1)
    m = n // k
    return np.uint64(0) if m > np.uint64(4) * k else m


@fused(_nrt=False)
def lattice_generator(n):
    """The generator a of the n-point rank-1 lattice {(i, a·i mod n) / n} a 2-D dimension
    uses where n has no squarish grid: of the a within 8 of n / φ (the Fibonacci lattice's
    choice) and coprime with n, the one whose shortest lattice vector on the torus is the
    longest (0: none coprime)."""
    n = np.uint64(n)
    centre = np.uint64(float(n) * 0.6180339887498949 + 0.5)
    lo = max(np.uint64(1), centre - np.uint64(min(centre, np.uint64(8))))
    hi = min(n - np.uint64(1), centre + np.uint64(8))
    best, best_d = np.uint64(0), np.uint64(0)
    for ai in range(np.int64(lo), np.int64(hi) + 1):
        a = np.uint64(ai)
        x, y = n, a
        while y != np.uint64(0):
            x, y = y, x % y
        if x != np.uint64(1):
            continue
        # the shortest vector (i, a·i mod n), i ≤ n / 2 by symmetry, and no i with i² at
        # or above the shortest found so far can beat it: O(√n) steps, not O(n)
        d = n * n
        y = np.uint64(0)
        i = np.uint64(1)
        while i * i < d and i + i <= n:
            y += a
            if y >= n:
                y -= n
            dy = min(y, n - y)
            d = min(d, i * i + dy * dy)
            i += np.uint64(1)
        if d > best_d:
            best, best_d = a, d
    return best


#: The strata field's flag of a lattice 2-D dimension (its generator in bits 32-62).
_LATTICE = np.uint64(1) << np.uint64(63)
_U31 = np.uint64(0x7FFFFFFF)


@fused(_nrt=False)
def strata_field(n):
    """The state's strata field, computed once a kernel call: n (0: the independent sampler)
    in the low 32 bits; above them the 2-D grid's columns (``grid_columns``), or the
    lattice's generator (``lattice_generator``) and the ``_LATTICE`` flag. n < 2^31."""
    n = np.uint64(n)
    if n == np.uint64(0):
        return n
    m = grid_columns(n)
    if m != np.uint64(0):
        return n | (m << np.uint64(32))
    return n | (lattice_generator(n) << np.uint64(32)) | _LATTICE


@fused(inline="always")
def _lattice_row(x, g, h, n):
    """Row (a·x + b) mod n of column x of an n-point rank-1 lattice: a = g or n - g (its
    mirror image) and the shift b uniform on 0..n-1, both chosen by the hash h, so every
    cell is equally likely and the estimate unbiased. The remainder by a float division
    and one correction (a loop LLVM vectorises)."""
    a = g if h & np.uint64(1 << 40) else n - g
    t = np.int64(a * x + (((h & _U32) * n) >> np.uint64(32)))
    nn = np.int64(n)
    r = t - np.int64(float(t) / float(nn)) * nn
    if r < 0:
        r += nn
    return np.uint64(r - nn if r >= nn else r)


@fused(_nrt=False)
def _stratum2(u, v, s, field, seed):
    """Sample s of n in two dimensions (``field``: ``strata_field(n)``).

    Where n has a squarish grid (``grid_columns``: m × k = n, k the largest divisor of n
    up to √n, m ≤ 4k): correlated multi-jittered (Kensler 2013) on it. Within its cell
    each sample takes the sub-column a permutation of its row gives and the sub-row a
    permutation of its column gives, so each coordinate's projection has one sample in
    each of n strata. A light chosen from the first coordinate is then stratified over n
    strata, not √n (vocabulary-materials at max_depth 2, multijitter, 16 spp: per-sample
    variance 2.0× Mitsuba's with jittered grids, 0.95× now).

    Otherwise (n prime, or nearly: 5, 7, 11, 13, 17, 22...): a rank-1 lattice, column
    x = the sample's 1-D stratum (a permutation of n) and row ``_lattice_row``: again one
    sample in each of n strata on each axis, and the points spread over the square as a
    Fibonacci lattice's. Until this evening those n took ⌈√n⌉ columns with n of the
    cells filled (each coordinate over up to n + ⌈√n⌉ strata): per-sample MSE on
    vocabulary-lights (× spp, 24 renders) 11 spp 0.071, 13 0.105, 17 0.082 against 0.045
    at 16; with the lattice, see docs/PERFORMANCE.md."""
    n = field & _U32
    h = _mix(seed)
    if field & _LATTICE:
        x = permute(s, n, h >> np.uint64(32))
        return (_jitter1(x, u, n),
                _jitter1(_lattice_row(x, (field >> np.uint64(32)) & _U31, h, n), v, n))
    m = field >> np.uint64(32)
    k = n // m
    x, y = _cell(permute(s, n, h >> np.uint64(32)), m)
    # the sub-strata's permutations: h's low 32 bits and a second hash, independent of
    # the cell's permutation (h's high 32 bits)
    return (_jitter1(_sub_stratum(x, permute(y, k, _mix(h ^ _M2)), k), u, n),
            _jitter1(_sub_stratum(y, permute(x, m, h), m), v, n))


@fused(inline="always")
def _cell(p, m):
    """Column and row (p % m, p // m) of cell p of a grid m wide."""
    # p // m by a float division: exact, since p < 2^32 and m < 2^16 keep the quotient's
    # distance from the next integer (>= 1/m) far above its rounding
    y = np.uint64(float(p) / float(m))
    return p - y * m, y


@fused(inline="always")
def _sub_stratum(x, sy, k):
    """Stratum x·k + sy of a coordinate's m·k: column x of the grid, sub-column sy of its
    k (the point is (x + (sy + u) / k) / m = (x·k + sy + u) / (m·k))."""
    return x * k + sy


#: Samples of one pixel per call of ``_trace_samples`` (a power of two).
CHUNK = 64
#: Rows of a call's scratch (samples of several pixels at a few samples a pixel,
#: ``pixel_group``; a multiple of CHUNK).
ROWS = 128
#: Dimensions of a chunk's strata table (``_strata_fill``); a path's later dimensions
#: are stratified one sample at a time (``_stratum``, ``_stratum2``).
STRATA_DIMS = 16
#: Rows of a strata table's dimension: the 1-D stratum, then the 2-D point's strata of
#: its two coordinates (``_sub_stratum``).
STRATA_ROWS = 3


@fused(_nrt=False)
def _strata_fill(tab, d, seed, s0, j0, c, field):
    """Dimension d of the strata table of a pixel's samples s0 + j0 <= s < s0 + c: the
    integers ``_stratum`` and ``_stratum2`` compute for one sample (the same values,
    tested), here for the c samples at once in loops LLVM vectorises. A 2-D dimension's
    three permutations one sample at a time took 24 ns (n = 16, 64) to 46 ns (n = 10, 15);
    filled here, both kinds of dimension: 5.6 ns a sample (16), 3.6 (64), 22 (10)."""
    h = _mix(seed)
    n = field & _U32
    one, su, sv = tab[d, 0, j0:c], tab[d, 1, j0:c], tab[d, 2, j0:c]
    c -= j0
    s0 += np.uint64(j0)
    for j in range(c):
        one[j] = s0 + np.uint64(j)
    _permute_rows(one, c, n, h >> np.uint64(32))
    if field & _LATTICE:
        g = (field >> np.uint64(32)) & _U31
        for j in range(c):
            x = np.uint64(one[j])
            su[j], sv[j] = x, _lattice_row(x, g, h, n)
        return
    m = field >> np.uint64(32)
    k = n // m
    for j in range(c):
        x, y = _cell(np.uint64(one[j]), m)
        su[j], sv[j] = y, x
    _permute_rows(su, c, k, _mix(h ^ _M2))
    _permute_rows(sv, c, m, h)
    for j in range(c):
        x, y = _cell(np.uint64(one[j]), m)
        su[j] = _sub_stratum(x, np.uint64(su[j]), k)
        sv[j] = _sub_stratum(y, np.uint64(sv[j]), m)


@fused(inline="always")
def _strata_table(stratified):
    """A tile's strata table and its control words (``_strata_slot``); none for the
    independent sampler."""
    return (np.empty((STRATA_DIMS if stratified else 0, STRATA_ROWS, CHUNK), np.uint32),
            np.zeros(1, np.int64))


@fused(inline="always")
def _strata_slot(tab, ctl, d, s, n, scramble):
    """Column of sample s in dimension d of its chunk's strata table (-1: d is past the
    table), the table's dimensions up to d filled first. ``ctl``: [dimensions filled];
    a chunk is CHUNK samples of a pixel from a multiple of CHUNK, traced
    in order: a dimension is filled for sample s and the chunk's later samples (the
    earlier ones never reach it)."""
    di = np.int64(d)
    if di >= tab.shape[0]:
        return -1
    j = s & np.uint64(CHUNK - 1)
    if ctl[0] <= di:
        s0 = s - j
        n32 = n & _U32
        c = min(np.uint64(CHUNK), n32 - s0)
        for r in range(ctl[0], di + 1):
            _strata_fill(tab, r, scramble + np.uint64(r) * _GOLDEN, s0, j, c, n)
        ctl[0] = di + 1
    return np.int64(j)


@fused(inline="always")
def _unit(rng):
    """The uniform in [0, 1) of one step of the Weyl sequence."""
    return float(_mix(rng) >> _S11) * _TO_UNIT


@fused(inline="always")
def _next(state):
    """One uniform and the next state (rng, scramble, sample, n, dimension), n the strata
    field (``strata_field``: the sample count and the 2-D grid's columns). With n = 0
    (the independent sampler) a splitmix64 Weyl sequence; with n > 0 (stratified) sample
    s of the pixel's n falls in the stratum a per-pixel, per-dimension permutation gives
    it, jittered by that same uniform."""
    rng, scramble, s, n, d, tab, ctl = state
    rng = rng + _GOLDEN
    u = _unit(rng)
    if MASK & F_STRATIFIED and n != np.uint64(0):
        j = _strata_slot(tab, ctl, d, s, n, scramble)
        if j >= 0:
            u = _jitter1(tab[d, 0, j], u, n & _U32)
        else:
            u = _stratum(u, s, n & _U32, scramble + d * _GOLDEN)
    return u, (rng, scramble, s, n, d + np.uint64(1), tab, ctl)


@fused(inline="always")
def _weyl2(rng):
    """Two uniforms of the Weyl sequence after ``rng``, and the state after them."""
    rng = rng + _GOLDEN
    u = _unit(rng)
    rng = rng + _GOLDEN
    return u, _unit(rng), rng


@fused(inline="always")
def _table_jitter2(tab, d, j, u, v, n):
    """(u, v) jittering column j of 2-D dimension d of the strata table (``n``: the
    strata field)."""
    return _jitter1(tab[d, 1, j], u, n & _U32), _jitter1(tab[d, 2, j], v, n & _U32)


@fused(inline="always")
def _next2(state):
    """Two uniforms (one 2-D dimension, as Mitsuba's samplers count them) and the next
    state; independent: the same as two ``_next``."""
    rng, scramble, s, n, d, tab, ctl = state
    u, v, rng = _weyl2(rng)
    if MASK & F_STRATIFIED and n != np.uint64(0):
        j = _strata_slot(tab, ctl, d, s, n, scramble)
        if j >= 0:
            u, v = _table_jitter2(tab, d, j, u, v, n)
        else:
            u, v = _stratum2(u, v, s, n, scramble + d * _GOLDEN)
    return u, v, (rng, scramble, s, n, d + np.uint64(1), tab, ctl)


@fused(inline="always")
def _reuse(u, n):
    """Choose one of n items from the uniform u and return (index, u rescaled to a fresh
    uniform): the light choice takes the first of the light sample's 2-D dimension, as
    Mitsuba's does, so with a stratified sampler the choice is stratified jointly with
    the point on the light (vocabulary-lights: per-sample variance against Mitsuba's
    2.13 -> 1.01)."""
    x = u * n
    k = min(int(x), n - 1)
    return k, min(x - k, ONE_MINUS_EPSILON)


@fused(inline="always")
def _mis(a, b):
    a2, b2 = a * a, b * b
    s = a2 + b2
    return a2 / s if s > 0.0 and math.isfinite(s) else (1.0 if math.isinf(a) else 0.0)


@fused(inline="always")
def _offset(px, py, pz, gx, gy, gz, dx, dy, dz):
    """Origin lifted off the surface to the side the direction leaves on."""
    e = _EPS * (1.0 + max(abs(px), abs(py), abs(pz)))
    if gx * dx + gy * dy + gz * dz < 0.0:
        e = -e
    return px + e * gx, py + e * gy, pz + e * gz


@fused(inline="always")
def _local_frame(bi, prims, info, b, j, px, py, pz, sx, sy, sz, b1, b2, dx, dy, dz):
    """The shading frame (s, t, n) at a hit on primitive j with BSDF b (Mitsuba's, from
    the mesh's tangents, where the BSDF needs it) and the incoming direction -d in it."""
    if MASK & F_FRAME and bi[b, BSDF_FRAME]:
        fs, ft = shading_frame(prims, info, j, px, py, pz, sx, sy, sz, b1, b2)
    else:
        fs, ft = coordinate_system(sx, sy, sz)
    fn = (sx, sy, sz)
    return fs, ft, fn, to_local(fs, ft, fn, -dx, -dy, -dz)


@fused(inline="always")
def trace(sc, stack, ox, oy, oz, dx, dy, dz, t_max, state, pdf_scale):
    """Radiance along one camera ray: (r, g, b, rng state). ``sc`` is the scene's
    ``layout.SceneArrays``; ``pdf_scale`` is the wrong-pdf test hook (1: correct)."""
    nodes, leaf, leaf_info = sc.bvh_nodes, sc.leaf_prims, sc.leaf_info
    prims, info = sc.prims, sc.prim_info
    bf, bi, btex, tex_data, tex_info = sc.bsdf_f, sc.bsdf_i, sc.bsdf_tex, sc.tex_data, \
        sc.tex_info
    light_f, light_i, light_cdf = sc.light_f, sc.light_i, sc.light_cdf
    env_marg, env_cond = sc.env_marginal, sc.env_conditional
    shape_bsdf, shape_light, shape_flip = sc.shape_bsdf, sc.shape_light, sc.shape_flip
    max_depth, rr_depth, hide, env = sc.max_depth, sc.rr_depth, sc.hide_emitters, sc.env
    n_lights = light_f.shape[0]
    sel_pdf = 1.0 / n_lights if n_lights > 0 else 0.0
    rr, rg, rb = 0.0, 0.0, 0.0
    tr, tg, tb = 1.0, 1.0, 1.0
    eta = 1.0
    prev_pdf, prev_delta = 1.0, True
    ppx, ppy, ppz = ox, oy, oz
    depth = 0
    t_min = 0.0
    # Mitsuba's valid_ray: a path that only passed through null BSDF components (a mask's
    # transparent part, a thin dielectric's transmission) counts only if the environment
    # is visible to camera rays, or the BSDF sample at its last vertex (max_depth) is not
    # null (Mitsuba's llvm variant); Mitsuba's direct integrator has no valid_ray and
    # keeps every path
    valid = not (MASK & F_NULL_BSDFS) or (env >= 0 and not hide) or sc.keep_null_paths
    if max_depth == 0:      # Mitsuba returns black, not even emitters seen directly
        return 0.0, 0.0, 0.0, state
    while True:
        t, j, b1, b2 = intersect(nodes, leaf, leaf_info, stack, ox, oy, oz, dx, dy, dz,
                                 t_min, t_max)
        if j < 0:
            if MASK & F_ENV and env >= 0 and not (depth == 0 and hide):
                lr, lg, lb, env_pdf = eval_environment(light_f, light_i, tex_data, tex_info,
                                                       env_marg, env_cond, env, dx, dy, dz,
                                                       not prev_delta)
                w = 1.0 if prev_delta else _mis(prev_pdf, sel_pdf * env_pdf)
                rr += tr * lr * w
                rg += tg * lg * w
                rb += tb * lb * w
            break
        (px, py, pz, gx, gy, gz, sx, sy, sz, u, v) = surface(prims, info, j, ox, oy, oz,
                                                            dx, dy, dz, t, b1, b2)
        shape = info[j, PRIM_SHAPE]
        if shape_flip[shape]:
            gx, gy, gz, sx, sy, sz = -gx, -gy, -gz, -sx, -sy, -sz
        if MASK & F_AREA_LIGHTS:
            k = shape_light[shape]
            if k >= 0 and depth == 0 and hide:
                # hidden emitters are transparent to camera rays (Mitsuba skips every
                # area emitter along them, and the continued ray has no far clip)
                ox, oy, oz = _offset(px, py, pz, gx, gy, gz, dx, dy, dz)
                t_max = np.inf
                continue
            if k >= 0:
                cos_y = -(sx * dx + sy * dy + sz * dz)
                if cos_y > 0.0:
                    w = 1.0
                    if not prev_delta:
                        dist = math.sqrt((px - ppx) ** 2 + (py - ppy) ** 2 + (pz - ppz) ** 2)
                        w = _mis(prev_pdf, sel_pdf * area_pdf(light_f, light_i, prims, info,
                                                              k, ppx, ppy, ppz, dist, cos_y))
                    rr += tr * light_f[k, LIGHT_RADIANCE] * w
                    rg += tg * light_f[k, LIGHT_RADIANCE + 1] * w
                    rb += tb * light_f[k, LIGHT_RADIANCE + 2] * w
        if depth + 1 >= max_depth:
            if MASK & F_NULL_BSDFS and not valid:
                # Mitsuba's JIT variants (llvm_ad_rgb: the references) still sample the
                # BSDF at the last vertex and count the path as valid unless that sample
                # is null: without it, a path whose only sample so far was a null event
                # lost its emitter samples (a mask sphere without an environment,
                # max_depth 2: 8 % dark where Mitsuba's llvm variant was the reference).
                # An emitter's own BSDF decides too: a light seen through, or as, a mask
                # at max_depth 1 shows as much of its radiance as the mask is opaque
                b = shape_bsdf[shape]
                fs, ft, fn, wi = _local_frame(bi, prims, info, b, j, px, py, pz, sx, sy, sz,
                                              b1, b2, dx, dy, dz)
                u0, state = _next(state)
                u1, u2, state = _next2(state)
                null = bsdf_sample(BSDF_MASK, bf, bi, btex, tex_data, tex_info, b, wi, u0,
                                   u1, u2, u, v, pdf_scale)[9]
                if not null:
                    valid = True
            break
        b = shape_bsdf[shape]
        fs, ft, fn, wi = _local_frame(bi, prims, info, b, j, px, py, pz, sx, sy, sz, b1, b2,
                                      dx, dy, dz)
        # ---- emitter sampling
        if n_lights > 0 and bsdf_is_smooth(bi, b):
            u0, state = _next(state)
            u1, u2, state = _next2(state)
            k = 0
            if MASK & F_MANY_LIGHTS:
                k, u1 = _reuse(u1, n_lights)
            wx, wy, wz, dist, lr, lg, lb, lpdf = sample_emitter(
                light_f, light_i, light_cdf, prims, info, shape_flip, tex_data, tex_info,
                env_marg, env_cond, k, px, py, pz, u0, u1, u2)
            # != 0: an emitter may be negative (Mitsuba adds it linearly)
            if lpdf > 0.0 and (lr != 0.0 or lg != 0.0 or lb != 0.0):
                wo = to_local(fs, ft, fn, wx, wy, wz)
                fr, fg, fb, bpdf = bsdf_eval(BSDF_MASK, bf, bi, btex, tex_data, tex_info, b,
                                             wi, wo, u, v)
                if fr > 0.0 or fg > 0.0 or fb > 0.0:
                    sox, soy, soz = _offset(px, py, pz, gx, gy, gz, wx, wy, wz)
                    sdx, sdy, sdz, smax = wx, wy, wz, np.inf
                    if dist < np.inf:
                        # aim the shadow ray from the lifted origin at the light point itself
                        # and stop 1e-6 short of it: a fixed margin along the sampled
                        # direction fails on grazing hits (a sphere light 0.06 from a
                        # plate lost a third of its light that way)
                        sdx = px + dist * wx - sox
                        sdy = py + dist * wy - soy
                        sdz = pz + dist * wz - soz
                        ln = math.sqrt(sdx * sdx + sdy * sdy + sdz * sdz)
                        sdx, sdy, sdz, smax = sdx / ln, sdy / ln, sdz / ln, ln * (1.0 - 1e-6)
                    if not occluded(nodes, leaf, leaf_info, stack, sox, soy, soz,
                                    sdx, sdy, sdz, 0.0, smax):
                        delta = (MASK & F_NONDELTA_LIGHTS) == 0 or is_delta(light_i[k, LIGHT_KIND])
                        w = 1.0 if delta else _mis(lpdf * sel_pdf, bpdf)
                        w /= lpdf * sel_pdf
                        rr += tr * fr * lr * w
                        rg += tg * fg * lg * w
                        rb += tb * fb * lb * w
        if depth + 2 >= max_depth and not (MASK & F_AREA_LIGHTS) and not (MASK & F_NULL_BSDFS) \
                and not (MASK & F_ENV and env >= 0):
            # the BSDF's ray would end the path where it lands, and nothing there emits:
            # no area light, no environment (the same image; a direct integrator under
            # point, spot and directional lights traced it for nothing)
            break
        # ---- BSDF sampling
        u0, state = _next(state)
        u1, u2, state = _next2(state)
        (wx, wy, wz, wr, wg, wb, pdf, delta, eta_k, null) = bsdf_sample(
            BSDF_MASK, bf, bi, btex, tex_data, tex_info, b, wi, u0, u1, u2, u, v, pdf_scale)
        if not null:
            valid = True
        if pdf <= 0.0 or (wr <= 0.0 and wg <= 0.0 and wb <= 0.0):
            break
        tr, tg, tb = tr * wr, tg * wg, tb * wb
        eta *= eta_k
        prev_pdf, prev_delta = pdf, delta
        ppx, ppy, ppz = px, py, pz
        dx, dy, dz = to_world(fs, ft, fn, wx, wy, wz)
        ox, oy, oz = _offset(px, py, pz, gx, gy, gz, dx, dy, dz)
        t_max = np.inf
        depth += 1
        if depth >= rr_depth:
            q = min(max(tr, tg, tb) * eta * eta, 0.95)
            ur, state = _next(state)
            if ur >= q:
                break
            tr, tg, tb = tr / q, tg / q, tb / q
        if max(tr, tg, tb) < 2.0 ** -126:
            # Mitsuba's stopping rule (throughput_max != 0), in its float32 arithmetic,
            # which flushes a value below float32's smallest normal number to 0. Without
            # it a closed room below rr_depth never ended: a float64 throughput stalls at
            # the least subnormal, which an albedo above 1/2 rounds back to itself
            break
    if not valid:
        return 0.0, 0.0, 0.0, state
    return rr, rg, rb, state


#: Rows of a chunk's camera rays (``_chunk_scratch``: one row per quantity, a column per
#: sample, so that ``_camera_rays`` stores each to a contiguous row).
RAY_FX, RAY_FY, RAY_OX, RAY_OY, RAY_OZ, RAY_DX, RAY_DY, RAY_DZ, RAY_TMAX = range(9)


@fused(**THREADED)
def _camera_rays(cam, seed, s0, s1, n, tab, x0, x1, y, width, height, fx, fy, ox, oy, oz, dx,
                 dy, dz, tm, rng):
    """The camera rays of samples s0 <= s < s1 of the pixels (x, y), x0 <= x < x1, into
    columns ``(x - x0)·(s1 - s0) + s - s0`` of the rows ``fx`` ... ``tm`` (the jitter in
    the pixel, the ray, its far end) and ``rng`` (the random state after the camera's
    2-D dimension): the values ``_next2`` and ``_generate_ray_kernel`` give one sample at
    a time. ``n``: the strata field (0: the independent sampler); a stratified sampler's
    samples are one pixel's, of one chunk (s0 a multiple of CHUNK), and dimension 0 of
    the strata table ``tab`` is filled.

    A function of its own, whose arguments LLVM knows do not overlap (``THREADED``),
    each quantity in a row of its own, and a loop for each kind of camera and sampler,
    without a branch in its body: LLVM vectorises them. Written to the rows of one
    array inside ``_trace_samples``, the loop stayed scalar; with the camera's branch
    inside, its loads became gathers. Zen 4, one thread, 512-bit vectors: 8.7 -> 2.4 ns
    a sample on its own; the white furnace at max_depth 0 and 16 spp 4.2 -> 3.6 ms."""
    if MASK & F_STRATIFIED and n != np.uint64(0):
        if cam[CAMERA_KIND] == ORTHOGRAPHIC:
            _camera_ray_loop(cam, seed, s0, s1, n, tab, x0, x1, y, width, height, fx, fy, ox,
                             oy, oz, dx, dy, dz, tm, rng, True, True)
        else:
            _camera_ray_loop(cam, seed, s0, s1, n, tab, x0, x1, y, width, height, fx, fy, ox,
                             oy, oz, dx, dy, dz, tm, rng, False, True)
    elif cam[CAMERA_KIND] == ORTHOGRAPHIC:
        _camera_ray_loop(cam, seed, s0, s1, n, tab, x0, x1, y, width, height, fx, fy, ox, oy,
                         oz, dx, dy, dz, tm, rng, True, False)
    else:
        _camera_ray_loop(cam, seed, s0, s1, n, tab, x0, x1, y, width, height, fx, fy, ox, oy,
                         oz, dx, dy, dz, tm, rng, False, False)


@fused(inline="always")
def _camera_ray_loop(cam, seed, s0, s1, n, tab, x0, x1, y, width, height, fx, fy, ox, oy, oz,
                     dx, dy, dz, tm, rng, ortho, stratified):
    """``_camera_rays``'s loop for one kind of camera and sampler (``ortho`` and
    ``stratified`` constants)."""
    m = s1 - s0
    for x in range(x0, x1):
        base = pixel_base(seed, y * width + x)
        k0 = (x - x0) * m
        for j in range(m):
            s = np.uint64(s0 + j)
            u, v, r = _weyl2(_mix(base ^ (s * _M2)))
            if stratified:      # dimension 0, column s % CHUNK (``_strata_slot``)
                u, v = _table_jitter2(tab, 0, s & np.uint64(CHUNK - 1), u, v, n)
            fu, fv = (x + u) / width, (y + v) / height
            if ortho:
                o0, o1, o2, d0, d1, d2, t = _orthographic_ray(cam, fu, fv)
            else:
                o0, o1, o2, d0, d1, d2, t = _perspective_ray(cam, fu, fv)
            # unsigned: no negative-index fix-up, whose select made the stores scatters
            k = np.uint64(k0 + j)
            fx[k], fy[k], ox[k], oy[k], oz[k] = u, v, o0, o1, o2
            dx[k], dy[k], dz[k], tm[k], rng[k] = d0, d1, d2, t, r


@fused(_nrt=False)
def _trace_samples(sc, stack, cam, seed, s0, s1, n, x0, x1, y, width, height, pdf_scale,
                   out, tab, ctl, rays, states):
    """Samples s0 <= s < s1 of each pixel (x, y), x0 <= x < x1 (the render's ``seed``),
    into rows ``(x - x0)·(s1 - s0) + s - s0`` of ``out``: the jitter (ξ, ξ') in the
    pixel, the radiance along the camera ray through (x + ξ, y + ξ') (a non-finite one as
    0) and 1.0 if it was finite, else 0.0. One call serves many samples: a call of this
    large function costs ~150 ns of set-up (its stack slots are zeroed on entry), which a
    call per sample paid every time, and a call per pixel at a few samples a pixel
    (``pixel_group``). ``out`` has at least ``(x1 - x0)·(s1 - s0)`` rows of 6. ``n``:
    ``strata_field`` of the pixel's sample count for a stratified sampler (then one
    pixel a call: x1 = x0 + 1), 0 for the independent one; ``tab`` and ``ctl`` the
    chunk's strata table (``_strata_slot``: STRATA_DIMS × STRATA_ROWS × CHUNK uint32, one
    int64), filled as the samples reach its dimensions. ``rays`` (a row per ``RAY_*``
    quantity, a column per sample) and ``states`` (uint64) are scratch for the chunk's
    camera rays.

    The camera rays come first, in a loop of their own: each is a chain of divisions and
    a square root, and the ray's traversal begins with three more, which one sample at a
    time left the core waiting (profiled on the white furnace at max_depth 1: a quarter
    of the samples on that chain); the loop's independent iterations overlap, and LLVM
    vectorises it (``_camera_rays``). The strata table fills dimension 0 at the chunk's
    first sample either way, so the numbers are the same.

    Compiled with IEEE division, as the warps are: the inlined per-ray code then has no
    zero-divisor branch at each division (a division by zero that would have raised
    gives ±inf or NaN, counted as a non-finite sample). One thread, 16 spp, alternating
    runs: 1-3 % less time on five scenes, images bit-identical.

    And with LLVM's ``contract`` flag alone of fast-math's: a multiply feeding an add
    may become one fused multiply-add (one rounding instead of two; Mitsuba's Dr.Jit
    fuses them too). Nothing else is relaxed: no reassociation, NaN and inf kept, the
    image the same whatever the thread count, and the specialised kernel the general
    one's bit for bit (tested on five scenes). One thread, 16 spp, CPU seconds, two
    rounds A/B/A/B: Cornell box 0.043-0.044 -> 0.041, veach-mis 0.043 -> 0.041-0.042,
    vocabulary-glass 0.323-0.328 -> 0.306-0.307, vocabulary-lights 0.022-0.024 ->
    0.021-0.022; bunny, envmap, white furnace within noise. These options are
    ``_compile_options.fused``, which every function of the tracer's modules states for
    itself; the warps' and distributions' kernels it calls state ``exact`` and keep
    every rounding (a callee without options of its own would take this one's)."""
    n = np.uint64(n)
    ctl[0] = 0
    m = s1 - s0
    if MASK & F_STRATIFIED and n != np.uint64(0):
        # the camera's dimension 0 of the chunk's strata table (one pixel a call)
        _strata_slot(tab, ctl, np.uint64(0), np.uint64(s0), n,
                     pixel_base(seed, y * width + x0))
    _camera_rays(cam, seed, s0, s1, n, tab, x0, x1, y, width, height, rays[RAY_FX],
                 rays[RAY_FY], rays[RAY_OX], rays[RAY_OY], rays[RAY_OZ], rays[RAY_DX],
                 rays[RAY_DY], rays[RAY_DZ], rays[RAY_TMAX], states)
    for x in range(x0, x1):
        base = pixel_base(seed, y * width + x)
        for s in range(s0, s1):
            k = np.uint64((x - x0) * m + s - s0)      # unsigned: no negative-index fix-up
            # every sample's state after the camera's 2-D dimension: dimension 1
            state = (states[k], base, np.uint64(s), n, np.uint64(1), tab, ctl)
            r, g, b, state = trace(sc, stack, rays[RAY_OX, k], rays[RAY_OY, k],
                                   rays[RAY_OZ, k], rays[RAY_DX, k], rays[RAY_DY, k],
                                   rays[RAY_DZ, k], rays[RAY_TMAX, k], state, pdf_scale)
            out[k, 0], out[k, 1] = rays[RAY_FX, k], rays[RAY_FY, k]
            if math.isfinite(r) and math.isfinite(g) and math.isfinite(b):
                out[k, 2], out[k, 3], out[k, 4], out[k, 5] = r, g, b, 1.0
            else:
                out[k, 2], out[k, 3], out[k, 4], out[k, 5] = 0.0, 0.0, 0.0, 0.0


@fused(inline="always")
def pixel_base(seed, pixel):
    """The hashed seed of a pixel (flat index ``y · width + x``) of a render: its samples'
    random numbers are splitmix64 steps from it."""
    return _mix(_mix(np.uint64(seed) + _GOLDEN) ^ np.uint64(pixel))


@fused(inline="always")
def pixel_group(spp, stratified):
    """Pixels of a tile's row that share one ``_trace_samples`` call: as many as fill
    its ROWS rows with all their samples (the independent sampler; a stratified
    sampler's strata table holds one pixel's samples, so one pixel a call there), at
    most the tile's width. A call per pixel cost ~45 ns a pixel of set-up (one thread).
    Both kernels in one process, alternating, best of 40, 128², two threads: at 16 spp
    (a tile row of 8 pixels a call) white furnace 7.68 -> 7.25 ms, Cornell box 23.1 ->
    22.6, veach-mis no change; one thread at 4 spp, white furnace 4.77 -> 3.92 ms. At 64
    spp two pixels a call (no change measured); above it one call per pixel's CHUNK of
    samples, as before."""
    return 1 if stratified or 2 * spp > ROWS else ROWS // spp


@fused(inline="always")
def _group_end(sc, stack, cam, seed, spp, n, xg, x1, y, width, height, pdf_scale, out, tab,
               ctl, rays, states, group):
    """The end of the group of ``group`` pixels from ``xg`` in a tile's row that ends at
    ``x1``; with several pixels a call, their samples traced into ``out`` now."""
    xe = min(x1, xg + group)
    if group > 1:
        # np.int64(0), not 0: a literal 0 made numba compile _trace_samples a second time
        # (its signature with Literal[int](0)), doubling the kernel's compilation
        _trace_samples(sc, stack, cam, seed, np.int64(0), spp, n, xg, xe, y, width, height,
                       pdf_scale, out, tab, ctl, rays, states)
    return xe


@fused(inline="always")
def _sample_row(sc, stack, cam, seed, s, spp, n, x, xg, y, width, height, pdf_scale, out,
                tab, ctl, rays, states, group):
    """The row of ``out`` that holds sample s of pixel (x, y): with one pixel a call
    (``group`` 1) its chunk's row, ``_trace_samples`` called at each chunk's first
    sample; else row ``(x - xg)·spp + s`` of the call the group starting at ``xg`` made."""
    if group > 1:
        return (x - xg) * spp + s
    k = s % CHUNK
    if k == 0:
        _trace_samples(sc, stack, cam, seed, s, min(s + CHUNK, spp), n, x, x + 1, y, width,
                       height, pdf_scale, out, tab, ctl, rays, states)
    return k


@fused(inline="always")
def _chunk_scratch(stratified):
    """A tile's scratch for ``_trace_samples``: its output rows, the strata table and its
    control words, the camera rays and their states."""
    tab, ctl = _strata_table(stratified)
    return (np.empty((ROWS, 6)), tab, ctl, np.empty((RAY_TMAX + 1, ROWS)),
            np.empty(ROWS, np.uint64))


@fused(**THREADED)
def render_tiles(sc, cam, tiles, width, height, spp, seed, stratified, pdf_scale, mean, m2,
                 bad, t0, t1):
    """Render tiles ``t0`` to ``t1`` of the list (rows of x0, y0, x1, y1): per pixel, the
    mean and the sum of squared deviations (Welford) of ``spp`` samples (stratified per
    dimension when ``stratified``); ``bad`` counts non-finite samples (set to zero).
    ``render`` runs ranges of tiles on numba's threads (``mcnumba.threads``)."""
    n_strat = strata_field(spp) if stratified else np.uint64(0)
    group = pixel_group(spp, stratified)
    for ti in range(t0, t1):
        stack = new_stack()
        out, tab, ctl, rays, states = _chunk_scratch(stratified)
        x0, y0, x1, y1 = tiles[ti, 0], tiles[ti, 1], tiles[ti, 2], tiles[ti, 3]
        for y in range(y0, y1):
            for xg in range(x0, x1, group):
                xe = _group_end(sc, stack, cam, seed, spp, n_strat, xg, x1, y, width, height,
                                pdf_scale, out, tab, ctl, rays, states, group)
                for x in range(xg, xe):
                    mr, mg, mb = 0.0, 0.0, 0.0
                    sr, sg, sb = 0.0, 0.0, 0.0
                    nbad = 0
                    for s in range(spp):
                        k = _sample_row(sc, stack, cam, seed, s, spp, n_strat, x, xg, y,
                                        width, height, pdf_scale, out, tab, ctl, rays,
                                        states, group)
                        r, g, b = out[k, 2], out[k, 3], out[k, 4]
                        if out[k, 5] == 0.0:
                            nbad += 1
                        # 1/n off the running means' chain: a division in it (three, one a
                        # channel) made each sample wait for the last one's
                        inv_n = 1.0 / (s + 1.0)
                        d0, d1, d2 = r - mr, g - mg, b - mb
                        mr += d0 * inv_n
                        mg += d1 * inv_n
                        mb += d2 * inv_n
                        sr += d0 * (r - mr)
                        sg += d1 * (g - mg)
                        sb += d2 * (b - mb)
                    mean[y, x, 0], mean[y, x, 1], mean[y, x, 2] = mr, mg, mb
                    m2[y, x, 0], m2[y, x, 1], m2[y, x, 2] = sr, sg, sb
                    bad[y, x] = nbad


@fused(**THREADED)
def splat_tiles(sc, cam, tiles, reach, width, height, spp, seed, stratified, pdf_scale, buf,
                bad, t0, t1):
    """Render tiles ``t0`` to ``t1`` of the list with a splatting reconstruction filter
    (Mitsuba's ``ImageBlock::put``): sample s of pixel (x, y) sits at (x + ξ, y + ξ') and
    ``camera.splat_kernel`` adds it to the pixels within the filter's radius. The random
    numbers are those of ``render_tiles``. Tile ``ti`` splats into its own zeroed buffer
    ``buf[ti]`` (the tile and ``reach`` pixels around it; ``add_splats`` adds them up);
    ``buf``'s last axis has ``SPLAT_CHANNELS``, or ``SPLAT_VALUE_CHANNELS`` for the sums
    of the value alone. ``bad`` counts non-finite samples (set to zero) per pixel."""
    n_strat = strata_field(spp) if stratified else np.uint64(0)
    group = pixel_group(spp, stratified)
    variance = buf.shape[3] == SPLAT_CHANNELS
    for ti in range(t0, t1):
        stack = new_stack()
        out, tab, ctl, rays, states = _chunk_scratch(stratified)
        wx = np.empty(splat_scratch(cam))
        x0, y0, x1, y1 = tiles[ti, 0], tiles[ti, 1], tiles[ti, 2], tiles[ti, 3]
        bx, by = x0 - reach, y0 - reach
        tile_buf = buf[ti]
        for y in range(y0, y1):
            for xg in range(x0, x1, group):
                xe = _group_end(sc, stack, cam, seed, spp, n_strat, xg, x1, y, width, height,
                                pdf_scale, out, tab, ctl, rays, states, group)
                for x in range(xg, xe):
                    nbad = 0
                    for s in range(spp):
                        k = _sample_row(sc, stack, cam, seed, s, spp, n_strat, x, xg, y,
                                        width, height, pdf_scale, out, tab, ctl, rays,
                                        states, group)
                        fx, fy = out[k, 0], out[k, 1]
                        r, g, b = out[k, 2], out[k, 3], out[k, 4]
                        if out[k, 5] == 0.0:
                            nbad += 1
                        splat_kernel(cam, tile_buf, bx, by, width, height, x + fx, y + fy,
                                     r, g, b, wx, variance)
                    bad[y, x] = nbad


@fused()
def add_splats(tiles, order, reach, buf, acc):
    """Add the tile buffers of ``splat_tiles`` into ``acc`` (H, W, channels) in
    ``order`` (row-major tiles, not the order they were dealt to the threads in), so
    that the image is the same whatever the number of threads."""
    height, width, channels = acc.shape
    side = buf.shape[1]
    for ti in order:
        bx, by = tiles[ti, 0] - reach, tiles[ti, 1] - reach
        for j in range(max(0, -by), min(side, height - by)):
            for i in range(max(0, -bx), min(side, width - bx)):
                for k in range(channels):
                    acc[by + j, bx + i, k] += buf[ti, j, i, k]
