"""4×4 affine transforms with Mitsuba's conventions (column vectors, ``T @ p``)."""

from __future__ import annotations

import numpy as np


def translate(v) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = v
    return m


def scale(v) -> np.ndarray:
    return np.diag([*np.broadcast_to(np.asarray(v, float), 3), 1.0])


def rotate(axis, angle_deg: float) -> np.ndarray:
    """Rotation by ``angle_deg`` degrees about ``axis`` (right-handed, Rodrigues), with
    the axis taken as given, as Mitsuba does: it does not normalise it, so an axis such
    as (1, 1, 0) gives Mitsuba's (non-rigid) matrix, and both renderers see one scene."""
    x, y, z = np.asarray(axis, dtype=np.float64)
    if x == y == z == 0:
        raise ValueError("rotate: the axis must be non-zero")
    t = np.radians(angle_deg)
    c, s = np.cos(t), np.sin(t)
    k = 1.0 - c
    m = np.eye(4)
    m[:3, :3] = [[x * x + (1.0 - x * x) * c, x * y * k - z * s, x * z * k + y * s],
                 [y * x * k + z * s, y * y + (1.0 - y * y) * c, y * z * k - x * s],
                 [z * x * k - y * s, z * y * k + x * s, z * z + (1.0 - z * z) * c]]
    return m


def coordinate_system(n) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing the unit vector ``n`` to an orthonormal basis, by
    Mitsuba's ``coordinate_system`` (Duff et al., "Building an Orthonormal Basis,
    Revisited", JCGT 6(1), 2017), so that the basis is Mitsuba's, not merely a basis."""
    x, y, z = (float(c) for c in n)
    sign = 1.0 if z >= 0 else -1.0
    a = -1.0 / (sign + z)
    b = x * y * a
    return (np.array([sign * x * x * a + 1.0, sign * b, -sign * x]),
            np.array([b, y * y * a + sign, -y]))


def look_at(origin, target, up=None) -> np.ndarray:
    """Camera-to-world of a camera at ``origin`` looking at ``target``: columns are
    (left, up, forward, origin), so camera space looks along +z, +x is to the left.
    Without ``up`` (or with a zero one) Mitsuba 3 takes the first vector of
    :func:`coordinate_system` of the viewing direction, not (0, 1, 0)."""
    origin, target = (np.asarray(v, dtype=np.float64) for v in (origin, target))
    d = target - origin
    if np.linalg.norm(d) == 0:
        raise ValueError("origin and target coincide")
    d = d / np.linalg.norm(d)
    up = np.zeros(3) if up is None else np.asarray(up, dtype=np.float64)
    if not up.any():
        up = coordinate_system(d)[0]
    left = np.cross(up, d)
    if np.linalg.norm(left) == 0:
        raise ValueError("'up' is parallel to the viewing direction")
    left = left / np.linalg.norm(left)
    new_up = np.cross(d, left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, new_up, d, origin
    return m


def matrix(values) -> np.ndarray:
    """A 4×4 matrix from 16 row-major values, or from 9, its linear part (Mitsuba's
    ``<matrix value="...">`` takes either)."""
    values = np.asarray(values, dtype=np.float64)
    if values.size == 9:
        m = np.eye(4)
        m[:3, :3] = values.reshape(3, 3)
        return m
    return values.reshape(4, 4)


def apply_point(m, p) -> np.ndarray:
    p = np.asarray(p, dtype=np.float64)
    return p @ m[:3, :3].T + m[:3, 3]


def apply_vector(m, v) -> np.ndarray:
    return np.asarray(v, dtype=np.float64) @ m[:3, :3].T
