"""Fuzz of the scene loader: random mutations of the reference scenes' XML either raise
``SceneError`` (naming the file) or compile and render; never anything else (no
IndexError from a short list, no hang on /dev/zero, no NaN radius slipping through)."""

import os
import re

import numpy as np
from hypothesis import event, given
from hypothesis import strategies as st

from estimators.pathtracer import SceneError, prepare_scene, parse_scene, render

ROOT = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(
    __file__)))), "reference", "scenes")
SCENES = sorted(d for d in os.listdir(ROOT) if os.path.isfile(os.path.join(ROOT, d, "scene.xml")))
TEXTS = {d: open(os.path.join(ROOT, d, "scene.xml"), encoding="utf-8").read() for d in SCENES}

VALUES = ["", "0", "-1", "nan", "inf", "-inf", "1e400", "1e-320", "abc", "$nosuch", "1, 2",
          "1 2 3 4", "-0.0", "99999999", "0.5", "3", "/dev/zero", "../../../etc/passwd",
          "nosuch.exr", "Au", "beckmann", "true"]
TYPES = ["diffuse", "conductor", "roughconductor", "dielectric", "plastic", "roughplastic",
         "twosided", "area", "point", "spot", "directional", "constant", "envmap", "sphere",
         "rectangle", "cube", "disk", "obj", "path", "direct", "perspective", "hdrfilm", "box",
         "independent", "bitmap", "rgb", "hair", "", "ply", "volpath", "orthographic"]
TAGS = ["float", "integer", "rgb", "string", "boolean", "point", "vector", "transform",
        "bsdf", "emitter", "shape", "texture", "ref", "lookat", "scale", "rotate", "matrix",
        "default", "sensor", "film", "sampler", "rfilter", "spectrum", "nosuch"]
SNIPPETS = ['<float name="radius" value="-2"/>', '<ref id="nosuch"/>', '<!DOCTYPE scene>',
            '<shape type="obj"><string name="filename" value="/dev/zero"/></shape>',
            '<shape type="ply"><string name="filename" value="/dev/zero"/></shape>',
            '<rgb name="reflectance" value="nan, 0, 1"/>', '<integer name="width" value="0"/>',
            '<transform name="to_world"><scale value="0"/></transform>',
            '<emitter type="area"><rgb name="radiance" value="1"/></emitter>',
            '<bsdf type="twosided"><bsdf type="twosided"/></bsdf>', '</shape>', '<shape>',
            '<default name="max_depth" value="-5"/>', '&amp;', '<float name="fov" value="0"/>']

FACTORS = [0.0, -1.0, 1e-6, 0.5, 2.0, 1e6]

mutation = st.one_of(
    st.tuples(st.just("scale"), st.floats(0, 1), st.sampled_from(FACTORS)),
    st.tuples(st.just("scale"), st.floats(0, 1), st.sampled_from(FACTORS)),
    st.tuples(st.just("delete"), st.floats(0, 1), st.integers(1, 40)),
    st.tuples(st.just("duplicate"), st.floats(0, 1), st.integers(1, 80)),
    st.tuples(st.just("value"), st.floats(0, 1), st.sampled_from(VALUES)),
    st.tuples(st.just("type"), st.floats(0, 1), st.sampled_from(TYPES)),
    st.tuples(st.just("tag"), st.floats(0, 1), st.sampled_from(TAGS)),
    st.tuples(st.just("insert"), st.floats(0, 1), st.sampled_from(SNIPPETS)),
)


def mutate(text: str, op) -> str:
    kind, where, arg = op
    if kind in ("delete", "duplicate", "insert"):
        i = int(where * len(text))
        if kind == "delete":
            return text[:i] + text[i + arg:]
        if kind == "duplicate":
            return text[:i] + text[i:i + arg] + text[i:]
        return text[:i] + arg + text[i:]
    pattern = {"value": r'value="([^"]*)"', "type": r'type="([^"]*)"',
               "tag": r"<(\w+)", "scale": r"[-+]?\d+\.?\d*(?:[eE][-+]?\d+)?"}[kind]
    if kind == "scale":   # one number in the file times a factor: odd but valid scenes
        spans = [m.span() for m in re.finditer(pattern, text)]
        a, b = spans[min(int(where * len(spans)), len(spans) - 1)]
        return text[:a] + repr(float(text[a:b]) * arg) + text[b:]
    spans = [m.span(1) for m in re.finditer(pattern, text)]
    if not spans:
        return text
    a, b = spans[min(int(where * len(spans)), len(spans) - 1)]
    return text[:a] + arg + text[b:]


@given(st.sampled_from(SCENES), st.lists(mutation, min_size=1, max_size=3))
def test_mutated_scene_raises_scene_error_or_renders(name, ops):
    text = TEXTS[name]
    for op in ops:
        text = mutate(text, op)
    path = os.path.join(ROOT, name, "fuzz.xml")      # never written: assets resolve here
    try:
        desc = parse_scene(text, path=path, params={"res": "8", "max_depth": "3"})
        scene = prepare_scene(desc)
    except SceneError as e:
        assert "fuzz.xml" in str(e), str(e)
        event("SceneError")
        return
    event("compiled")
    if scene.width * scene.height <= 32 * 32:
        event("rendered")
        r = render(scene, spp=2, seed=1, general=True)   # one kernel for every mutation
        assert r.mean.shape == (scene.height, scene.width, 3)
        assert r.variance.shape == r.mean.shape and np.all(r.variance >= 0)
