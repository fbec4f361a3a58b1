"""The independent path tracer (in progress): Mitsuba XML scenes in, mean + variance out.

Landed so far: the scene loader (``scene``: the supported subset, with clear errors),
transforms and the perspective camera, proven against Mitsuba's own rays.
"""

from .camera import Camera, camera_from_scene, generate_rays
from .scene import SceneDescription, SceneError, load_scene, parse_scene

__all__ = ["Camera", "camera_from_scene", "generate_rays", "SceneDescription", "SceneError",
           "load_scene", "parse_scene"]
