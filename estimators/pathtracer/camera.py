"""The perspective and orthographic cameras, with Mitsuba's conventions exactly (so that
images compare pixel for pixel): film position (u, v) in [0, 1]², u to the right, v down;
camera space looks along +z with +x to the left (``look_at``); rays start on the near
plane and end at the far plane.

Perspective: ``fov`` spans the axis ``fov_axis``. Orthographic (Mitsuba's
``orthographic_projection``): the film covers x in [-1, 1] and y in [-1/aspect,
1/aspect] of the plane z = near_clip in camera space, which ``to_world`` maps to the
world (its scale sets the view's extent); every ray has the direction of ``to_world``'s
z axis, normalised, and length far_clip - near_clip in world units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from .scene import SceneDescription, SceneError


PERSPECTIVE, ORTHOGRAPHIC = 0, 1


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

    @property
    def params(self) -> np.ndarray:
        """Flat parameters for ``_generate_ray_kernel``."""
        m = self.to_world
        return np.concatenate([m[:3, :3].ravel(), m[:3, 3],
                               [self.tan_x, self.tan_y, self.near, self.far, self.kind]])


def camera_from_scene(desc: SceneDescription) -> Camera:
    s, f = desc.sensor, desc.film
    if s.type == "perspective" and "fov" not in s.props:
        raise SceneError(f"{desc.path}:{s.line}: <sensor type=\"perspective\">: set "
                         "<float name=\"fov\" .../>; focal_length is not supported")
    if not any(c.kind == "rfilter" for c in f.children):
        # Mitsuba's default reconstruction filter is gaussian (radius 2 pixels), which
        # this tracer does not implement: a scene silent about it would render blurred
        # there and sharp here, so it is refused rather than rendered differently.
        raise SceneError(f"{desc.path}:{f.line}: <film>: no <rfilter>: Mitsuba's default is "
                         "gaussian, which this path tracer does not implement; add "
                         "<rfilter type=\"box\"/> to the film (both renderers then agree)")
    w, h = int(f.get("width", 768)), int(f.get("height", 576))
    if w < 1 or h < 1:
        raise SceneError(f"{desc.path}:{f.line}: <film>: width and height must be >= 1")
    aspect = w / h
    to_world = np.asarray(s.get("to_world", np.eye(4)), dtype=np.float64)
    near, far = float(s.get("near_clip", 1e-2)), float(s.get("far_clip", 1e4))
    if s.type == "orthographic":
        if not np.linalg.norm(to_world[:3, 2]) > 0:
            raise SceneError(f"{desc.path}:{s.line}: <sensor type=\"orthographic\">: "
                             "to_world maps the view direction (0, 0, 1) to zero")
        return Camera(to_world, 1.0, 1.0 / aspect, near, far, w, h, ORTHOGRAPHIC)
    fov = math.radians(s.props["fov"])
    axis = s.get("fov_axis", "x")
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
        raise SceneError(f"{desc.path}:{s.line}: fov_axis={axis!r}; supported: x, y, "
                         "diagonal, smaller, larger")
    return Camera(to_world, tan_x, tan_y, near, far, w, h, PERSPECTIVE)


@njit(cache=True)
def _generate_ray_kernel(c, u, v):
    """Ray through film position (u, v): (ox, oy, oz, dx, dy, dz, t_max), unit d."""
    x = (1.0 - 2.0 * u) * c[12]
    y = (1.0 - 2.0 * v) * c[13]
    if c[16] == ORTHOGRAPHIC:
        # the film point (x, y, near) in camera space, the camera's z axis as direction
        z = c[14]
        dx, dy, dz = c[2], c[5], c[8]
        inv = 1.0 / math.sqrt(dx * dx + dy * dy + dz * dz)
        return (c[0] * x + c[1] * y + c[2] * z + c[9], c[3] * x + c[4] * y + c[5] * z + c[10],
                c[6] * x + c[7] * y + c[8] * z + c[11], dx * inv, dy * inv, dz * inv,
                c[15] - c[14])
    inv = 1.0 / math.sqrt(x * x + y * y + 1.0)
    lx, ly, lz = x * inv, y * inv, inv               # camera-space unit direction
    dx = c[0] * lx + c[1] * ly + c[2] * lz
    dy = c[3] * lx + c[4] * ly + c[5] * lz
    dz = c[6] * lx + c[7] * ly + c[8] * lz
    t_near = c[14] / lz                              # near plane z = near
    return (c[9] + dx * t_near, c[10] + dy * t_near, c[11] + dz * t_near, dx, dy, dz,
            (c[15] - c[14]) / lz)


def generate_rays(camera: Camera, film_uv) -> tuple[np.ndarray, np.ndarray]:
    """Origins and unit directions (n, 3) for film positions (n, 2)."""
    uv = np.asarray(film_uv, dtype=np.float64).reshape(-1, 2)
    c = camera.params
    out = np.array([_generate_ray_kernel(c, a, b)[:6] for a, b in uv])
    return out[:, :3], out[:, 3:]
