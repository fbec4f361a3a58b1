"""The independent path tracer: Mitsuba XML scenes in, per-pixel mean + variance out.

``scene`` parses the supported subset (clear errors for the rest), ``prepare`` turns it
into named arrays whose layout ``layout`` owns (primitives, SAH hierarchy, BSDF and
emitter tables, textures, feature bits),
``_kernel`` is the numba path tracer (NEE + MIS, Russian roulette), specialised per scene
by ``render``.
"""

from .camera import Camera, camera_from_scene, generate_rays
from .prepare import PreparedScene, prepare_scene
from .render import RenderResult, render
from .scene import SceneDescription, SceneError, load_scene, parse_scene

__all__ = ["Camera", "camera_from_scene", "generate_rays", "PreparedScene", "prepare_scene",
           "RenderResult", "render", "SceneDescription", "SceneError", "load_scene",
           "parse_scene"]
