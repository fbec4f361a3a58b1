"""The perspective and orthographic cameras, with Mitsuba's conventions exactly (so that
images compare pixel for pixel): film position (u, v) in [0, 1]², u to the right, v down;
camera space looks along +z with +x to the left (``look_at``); rays start on the near
plane and end at the far plane.

Perspective: ``fov`` spans the axis ``fov_axis``. Orthographic (Mitsuba's
``orthographic_projection``): the film covers x in [-1, 1] and y in [-1/aspect,
1/aspect] of the plane z = near_clip in camera space, which ``to_world`` maps to the
world (its scale sets the view's extent); every ray has the direction of ``to_world``'s
z axis, normalised, and length far_clip - near_clip in world units.

The film's reconstruction filter is Mitsuba's too (``hdrfilm``, ``ImageBlock::put``): a
sample at film position ``pos`` (pixel ``(x, y)`` plus a uniform jitter, samples only
inside the image) adds ``w·L`` and ``w`` to every pixel whose centre lies within the
filter's radius, ``w = f(x + 0.5 - pos_x)·f(y + 0.5 - pos_y)``, and a pixel's value is
``Σ w L / Σ w`` over the samples of one render (0 where ``Σ w`` is 0). ``gaussian``:
``f(d) = max(0, exp(-d²/2σ²) - exp(-r²/2σ²))``, radius ``r = 4σ`` (Mitsuba evaluates a
Remez fit of this, within 4.2e-4; its default, σ = 0.5, is used where the film names no
filter); ``tent``: ``f(d) = max(0, 1 - |d|/r)``. A filter of radius exactly 1/2 is a box
filter (Mitsuba's test): each sample counts in its own pixel only.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from .._compile_options import fused
from .flat import flat_add, flat_add4, flat_get
from .scene import SceneDescription, SceneError
from .text_numbers import SPACE, ascii_lower, parse_float


PERSPECTIVE, ORTHOGRAPHIC = 0, 1
#: where ``Camera.params`` holds the camera's kind (PERSPECTIVE or ORTHOGRAPHIC)
CAMERA_KIND = 16
#: Reconstruction filters, in the order of their codes in ``Camera.params``.
RFILTERS = ("box", "gaussian", "tent")
#: Mitsuba's defaults: gaussian stddev 0.5 (radius 4σ), tent radius 1.
GAUSSIAN_STDDEV = 0.5
TENT_RADIUS = 1.0
#: Widest filter accepted (pixels): each tile splats into a buffer reaching this far
#: around it, so memory grows with the radius squared.
MAX_FILTER_RADIUS = 32.0


@dataclass(frozen=True)
class Camera:
    to_world: np.ndarray        # 4×4 camera-to-world
    tan_x: float                # perspective: tan of half the horizontal field of view;
    tan_y: float                # orthographic: half the film's extent on the near plane
    near: float
    far: float
    width: int
    height: int
    kind: int = PERSPECTIVE     # PERSPECTIVE or ORTHOGRAPHIC
    rfilter: str = "box"        # one of RFILTERS
    filter_radius: float = 0.5  # pixels
    filter_stddev: float = 0.0  # gaussian only
    offset_x: float = 0.0       # perspective: principal point offset, in film widths
    offset_y: float = 0.0       # and heights (Mitsuba's principal_point_offset_x/y)

    @property
    def splats(self) -> bool:
        """True if a sample counts in pixels other than its own (any filter but box)."""
        return self.rfilter != "box"

    @property
    def params(self) -> np.ndarray:
        """Flat parameters for ``_generate_ray_kernel`` (0-16, 24-25: the principal point
        offset) and ``filter_weight_kernel`` (17-23: filter code, radius, stddev; a
        gaussian's exponent factor k = -1/(2σ²), its value at the radius e^(k r²) and
        e^(2k); 1/radius: computed here once, not once a splat)."""
        m = self.to_world
        gaussian = self.rfilter == "gaussian"
        k = -0.5 / (self.filter_stddev * self.filter_stddev) if gaussian else 0.0
        shift = math.exp(k * self.filter_radius * self.filter_radius) if gaussian else 0.0
        step = math.exp(2.0 * k) if gaussian else 0.0
        return np.concatenate([m[:3, :3].ravel(), m[:3, 3],
                               [self.tan_x, self.tan_y, self.near, self.far, self.kind,
                                RFILTERS.index(self.rfilter), self.filter_radius,
                                self.filter_stddev, k, shift, 1.0 / self.filter_radius,
                                step, self.offset_x, self.offset_y]])

    def with_filter(self, rfilter: str, *, radius: float | None = None,
                    stddev: float | None = None) -> "Camera":
        """This camera with another reconstruction filter (Mitsuba's semantics and
        defaults: a gaussian's radius is 4σ; a radius of exactly 1/2 is a box)."""
        if rfilter not in RFILTERS:
            raise ValueError(f"rfilter={rfilter!r}; one of {', '.join(RFILTERS)}")
        if rfilter == "gaussian":
            stddev = GAUSSIAN_STDDEV if stddev is None else float(stddev)
            radius = 4.0 * stddev
        elif rfilter == "tent":
            stddev, radius = 0.0, TENT_RADIUS if radius is None else float(radius)
        else:
            stddev, radius = 0.0, 0.5
        if not (math.isfinite(radius) and 0 < radius <= MAX_FILTER_RADIUS):
            given = f"stddev {stddev} (radius 4σ = {radius})" if rfilter == "gaussian" \
                else f"radius {radius}"
            raise ValueError(f"{rfilter} filter: {given}: the radius must be finite and > 0 "
                             f"(and at most {MAX_FILTER_RADIUS:g} pixels: wider filters are "
                             "not supported)")
        if np.float32(radius) == np.float32(0.5):
            rfilter, stddev = "box", 0.0      # Mitsuba's ImageBlock treats it as a box
        return dataclasses.replace(self, rfilter=rfilter, filter_radius=radius,
                                   filter_stddev=stddev)


def camera_from_scene(desc: SceneDescription) -> Camera:
    s, f = desc.sensor, desc.film
    w, h = int(f.get("width", 768)), int(f.get("height", 576))
    for name, n in (("width", w), ("height", h)):
        if n < 1:       # named with its value: a size given by $parameters was a guess
            raise SceneError(f"{f.at(desc.path)}: <film type=\"{f.type}\">: {name}={n}: "
                             "must be >= 1")
    aspect = w / h
    to_world = np.asarray(s.get("to_world", np.eye(4)), dtype=np.float64)
    near, far = float(s.get("near_clip", 1e-2)), float(s.get("far_clip", 1e4))
    if not 0.0 < near < far:        # Mitsuba's ProjectiveCamera refuses both
        what = "must be > 0" if not near > 0.0 else f"must be below far_clip={far!r}"
        raise SceneError(f"{s.at(desc.path)}: <sensor type=\"{s.type}\">: "
                         f"near_clip={near!r}: {what} (as Mitsuba requires)")
    shutter = float(s.get("shutter_open", 0.0)), float(s.get("shutter_close", 0.0))
    if not shutter[0] <= shutter[1]:    # the time of motion blur: nothing here moves
        raise SceneError(f"{s.at(desc.path)}: <sensor type=\"{s.type}\">: "
                         f"shutter_open={shutter[0]!r} is after shutter_close="
                         f"{shutter[1]!r} (Mitsuba refuses it)")
    if s.type == "orthographic":
        if not np.linalg.norm(to_world[:3, 2]) > 0:
            raise SceneError(f"{s.at(desc.path)}: <sensor type=\"orthographic\">: "
                             "to_world maps the view direction (0, 0, 1) to zero")
        return _with_film_filter(desc, Camera(to_world, 1.0, 1.0 / aspect, near, far, w, h,
                                              ORTHOGRAPHIC))
    m3 = to_world[:3, :3]
    if np.max(np.abs(m3 @ m3.T - np.eye(3))) > 1e-3:
        # Mitsuba's has_scale (M Mᵀ ≠ I within 1e-3): a mirror passes, a scale does not
        raise SceneError(f"{s.at(desc.path)}: <sensor type=\"perspective\">: to_world "
                         "scales (Mitsuba refuses scale factors in a perspective camera's "
                         "to_world; a mirror such as <scale x=\"-1\"/> is allowed)")
    fov_deg, axis = _field_of_view(desc)
    if not 0.0 < fov_deg < 180.0:
        raise SceneError(f"{s.at(desc.path)}: <sensor type=\"perspective\">: fov="
                         f"{fov_deg!r}: must be in (0, 180) degrees, as in Mitsuba")
    fov = math.radians(fov_deg)
    if axis == "smaller":
        axis = "x" if aspect <= 1 else "y"
    elif axis == "larger":
        axis = "x" if aspect >= 1 else "y"
    if axis == "x":
        tan_x = math.tan(fov / 2)
        tan_y = tan_x / aspect
    elif axis == "y":
        tan_y = math.tan(fov / 2)
        tan_x = tan_y * aspect
    elif axis == "diagonal":
        diag = math.tan(fov / 2)
        tan_x = diag * aspect / math.hypot(aspect, 1.0)
        tan_y = diag / math.hypot(aspect, 1.0)
    else:
        raise SceneError(f"{s.at(desc.path)}: <sensor type=\"{s.type}\">: fov_axis="
                         f"{axis!r}; supported: x, y, diagonal, smaller, larger")
    offset = (float(s.get("principal_point_offset_x", 0.0)),
              float(s.get("principal_point_offset_y", 0.0)))
    return _with_film_filter(desc, Camera(to_world, tan_x, tan_y, near, far, w, h,
                                          PERSPECTIVE, offset_x=offset[0],
                                          offset_y=offset[1]))


def _field_of_view(desc: SceneDescription) -> tuple[float, str]:
    """(fov in degrees, fov_axis) of a perspective sensor, as Mitsuba's ``parse_fov``
    reads them: ``fov`` along ``fov_axis`` (default x), or else ``focal_length``
    ("<x>mm" or a number, default "50mm") on a 35 mm film, which spans the diagonal:
    fov = 2 atan(√(36² + 24²) / (2 f))."""
    s = desc.sensor
    if "fov" in s.props:
        if "focal_length" in s.props:
            raise SceneError(f"{s.at(desc.path)}: <sensor type=\"perspective\">: give "
                             "either fov or focal_length, not both (Mitsuba refuses both)")
        return float(s.props["fov"]), ascii_lower(str(s.get("fov_axis", "x")))   # as Mitsuba
    if "fov_axis" in s.props:
        # Mitsuba reads fov_axis only with fov, and refuses it unread ("unreferenced
        # property"); ignoring it would render another view than the file asks for
        raise SceneError(f"{s.at(desc.path)}: <sensor type=\"perspective\">: fov_axis "
                         "without fov (Mitsuba refuses it as unused; a focal_length spans "
                         "the diagonal)")
    # Mitsuba's rule: a trailing "mm" cut off, then a number with ASCII spaces around it
    # ("50 mm" and "50 " pass, "50mm " and "5_0mm" do not)
    text = str(s.get("focal_length", "50mm"))
    number = text[:-2] if text.endswith("mm") else text
    try:
        focal = parse_float(number.strip(SPACE))
    except ValueError:
        focal = float("nan")
    if not (math.isfinite(focal) and focal > 0):
        raise SceneError(f"{s.at(desc.path)}: <sensor type=\"perspective\">: "
                         f"focal_length {text!r}: expected a positive length in mm, e.g. "
                         "\"35mm\"")
    return math.degrees(2.0 * math.atan(math.hypot(36.0, 24.0) / (2.0 * focal))), "diagonal"


def _with_film_filter(desc: SceneDescription, cam: Camera) -> Camera:
    """``cam`` with the film's reconstruction filter (the loader gives a film without
    <rfilter> Mitsuba's default, a gaussian)."""
    rf = next((c for c in desc.film.children if c.kind == "rfilter"), None)
    if rf is None:
        return cam.with_filter("gaussian")
    try:
        return cam.with_filter(rf.type, radius=rf.get("radius"), stddev=rf.get("stddev"))
    except ValueError as e:
        raise SceneError(f"{rf.at(desc.path)}: <rfilter type=\"{rf.type}\">: {e}") from None


@fused(inline="always")
def _filter_constants(c):
    """(kind, radius, gaussian exponent factor, gaussian value at the radius, 1/radius)."""
    return c[17], c[18], c[20], c[21], c[22]


@fused(inline="always")
def _filter_weight(kind, r, k, shift, inv_r, d):
    a = abs(d)
    if a > r:
        return 0.0
    if kind == 1.0:                                   # gaussian, shifted to 0 at r
        return max(0.0, math.exp(k * d * d) - shift)
    if kind == 2.0:                                   # tent: Mitsuba's 1 - |x · (1/r)|
        return max(0.0, 1.0 - abs(d * inv_r))
    return 1.0                                        # box


@fused(inline="always")
def _filter_run(c, i0, n, centre, out, at):
    """The filter's weights at the n pixel centres i0 + m + 1/2 (m < n) around the
    sample position ``centre`` + 1/2 into ``out[at + m]``. A gaussian's by the recurrence
    e^(k d²)·e^(k(2d + 1)) = e^(k(d + 1)²), the second factor times e^(2k) from one
    pixel to the next: two exponentials a run instead of one a pixel (each weight within
    ~2n ulp of ``filter_weight_kernel``'s; profiled: the exponentials were a sixth of the
    filters scene's time)."""
    kind, r, k, shift, inv_r = _filter_constants(c)
    if kind != 1.0:
        for m in range(n):
            out[at + m] = _filter_weight(kind, r, k, shift, inv_r, (i0 + m) - centre)
        return
    step = c[23]                                        # e^(2k)
    d = i0 - centre
    e = math.exp(k * d * d)
    f = math.exp(k * (2.0 * d + 1.0))
    for m in range(n):
        d = (i0 + m) - centre
        out[at + m] = 0.0 if abs(d) > r else max(0.0, e - shift)
        e *= f
        f *= step


@fused()
def filter_weight_kernel(c, d):
    """The 1-D reconstruction filter at offset ``d`` (pixels) from a pixel centre, for
    camera parameters ``c`` (``Camera.params``); 0 outside the radius."""
    kind, r, k, shift, inv_r = _filter_constants(c)
    return _filter_weight(kind, r, k, shift, inv_r, d)


#: Per-pixel sums a splatting film accumulates: Σw, Σw·L (r, g, b), Σw², Σw²·L (3),
#: Σw²·L² (3): the pixel's value Σ w L / Σ w and its delta-method variance; the value
#: alone needs the first ``SPLAT_VALUE_CHANNELS``.
SPLAT_CHANNELS = 11
SPLAT_VALUE_CHANNELS = 4


@fused(inline="always")
def splat_kernel(c, buf, bx, by, width, height, px, py, r, g, b, wx, variance):
    """Add a sample of radiance (r, g, b) at film position (px, py) (pixels) to ``buf``
    (rows from image row ``by``, columns from ``bx``, ``SPLAT_CHANNELS`` deep): every
    image pixel (i, j) whose centre is within the filter's radius of it gets the weight
    ``w = f(i + 1/2 - px)·f(j + 1/2 - py)`` (Mitsuba's ``ImageBlock::put``, the film
    without a border: pixels outside the image get nothing). ``wx``: scratch for the
    column and row weights, at least ``splat_scratch(c)`` long (each weight is evaluated
    once a sample, not once a pixel: a gaussian of radius 2 cost 305 ns a sample that
    way).
    Without ``variance`` only the first 4 sums (Σw, Σw·L): the 7 others took a third of
    the time (a gaussian of radius 2, one thread: 140 -> 96 ns a sample)."""
    radius = c[18]
    cx, cy = px - 0.5, py - 0.5
    i0 = max(int(math.ceil(cx - radius)), 0)
    i1 = min(int(math.floor(cx + radius)), width - 1)
    j0 = max(int(math.ceil(cy - radius)), 0)
    j1 = min(int(math.floor(cy + radius)), height - 1)
    nx, ny = i1 - i0 + 1, j1 - j0 + 1
    _filter_run(c, i0, nx, cx, wx, 0)
    _filter_run(c, j0, ny, cy, wx, max(nx, 0))
    # buf read flat: (j - by, i - bx, channel) at (j - by)·pitch + (i - bx)·ch + channel
    # (a pixel's address was a multiply by the run-time stride and a negative-index
    # wrap-around each time)
    ch = buf.shape[2]
    pitch = buf.shape[1] * ch
    for j in range(j0, j1 + 1):
        wy = flat_get(wx, nx + j - j0)
        if wy == 0.0:
            continue
        o = (j - by) * pitch + (i0 - bx) * ch
        for m in range(nx):
            w = wy * flat_get(wx, m)
            flat_add4(buf, o, w, 1.0, r, g, b)
            if variance:
                w2 = w * w
                flat_add4(buf, o + 4, w2, 1.0, r, g, b)
                flat_add(buf, o + 8, w2 * r * r)
                flat_add(buf, o + 9, w2 * g * g)
                flat_add(buf, o + 10, w2 * b * b)
            o += ch


@fused()
def splat_scratch(c) -> int:
    """The length of ``splat_kernel``'s scratch: the weights of the columns and of the
    rows a splat reaches, each at most floor(x + r) - ceil(x - r) + 1 <= 2r + 1."""
    return 2 * (int(2.0 * c[18]) + 2)


@fused()
def _splat_points_kernel(c, buf, width, height, points):
    wx = np.empty(splat_scratch(c))
    for k in range(points.shape[0]):
        splat_kernel(c, buf, 0, 0, width, height, points[k, 0], points[k, 1], points[k, 2],
                     points[k, 3], points[k, 4], wx, buf.shape[2] == SPLAT_CHANNELS)


def splat(camera: Camera, points, variance: bool = True) -> np.ndarray:
    """The film's sums (H, W, SPLAT_CHANNELS, or SPLAT_VALUE_CHANNELS without
    ``variance``) after splatting ``points``, rows of (px, py, r, g, b): film position in
    pixels and radiance (for tests against Mitsuba's ``ImageBlock``)."""
    pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 5))
    buf = np.zeros((camera.height, camera.width,
                    SPLAT_CHANNELS if variance else SPLAT_VALUE_CHANNELS))
    _splat_points_kernel(camera.params, buf, camera.width, camera.height, pts)
    return buf


def filter_weights(camera: Camera, offsets) -> np.ndarray:
    """``filter_weight_kernel`` over an array of offsets (pixels)."""
    c = camera.params
    d = np.asarray(offsets, dtype=np.float64)
    return np.array([filter_weight_kernel(c, x) for x in d.ravel()]).reshape(d.shape)


@fused(inline="always")
def _orthographic_ray(c, u, v):
    """``_generate_ray_kernel`` of an orthographic camera: the film point (x, y, near) in
    camera space, the camera's z axis as direction."""
    x = (1.0 - 2.0 * (u + c[24])) * c[12]
    y = (1.0 - 2.0 * (v + c[25])) * c[13]
    z = c[14]
    dx, dy, dz = c[2], c[5], c[8]
    inv = 1.0 / math.sqrt(dx * dx + dy * dy + dz * dz)
    return (c[0] * x + c[1] * y + c[2] * z + c[9], c[3] * x + c[4] * y + c[5] * z + c[10],
            c[6] * x + c[7] * y + c[8] * z + c[11], dx * inv, dy * inv, dz * inv,
            c[15] - c[14])


@fused(inline="always")
def _perspective_ray(c, u, v):
    """``_generate_ray_kernel`` of a perspective camera."""
    x = (1.0 - 2.0 * (u + c[24])) * c[12]
    y = (1.0 - 2.0 * (v + c[25])) * c[13]
    norm = math.sqrt(x * x + y * y + 1.0)
    inv = 1.0 / norm
    lx, ly, lz = x * inv, y * inv, inv               # camera-space unit direction
    dx = c[0] * lx + c[1] * ly + c[2] * lz
    dy = c[3] * lx + c[4] * ly + c[5] * lz
    dz = c[6] * lx + c[7] * ly + c[8] * lz
    t_near = c[14] * norm                            # near plane z = near: near / lz
    return (c[9] + dx * t_near, c[10] + dy * t_near, c[11] + dz * t_near, dx, dy, dz,
            (c[15] - c[14]) * norm)


@fused(inline="always")
def _generate_ray_kernel(c, u, v):
    """Ray through film position (u, v): (ox, oy, oz, dx, dy, dz, t_max), unit d. A
    perspective camera's principal point offset shifts (u, v) as Mitsuba's does (0 for
    an orthographic one, which has none)."""
    if c[CAMERA_KIND] == ORTHOGRAPHIC:
        return _orthographic_ray(c, u, v)
    return _perspective_ray(c, u, v)


def generate_rays(camera: Camera, film_uv) -> tuple[np.ndarray, np.ndarray]:
    """Origins and unit directions (n, 3) for film positions (n, 2)."""
    uv = np.asarray(film_uv, dtype=np.float64).reshape(-1, 2)
    c = camera.params
    out = np.array([_generate_ray_kernel(c, a, b)[:6] for a, b in uv])
    return out[:, :3], out[:, 3:]
