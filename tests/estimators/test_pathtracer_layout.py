"""The tracer's data layout has one owner (``layout``): the promises of its docstring,
kept by tests, so that a column or a feature bit cannot be defined twice or read by a
bare number again."""

import ast
import os

import numpy as np
import pytest

import estimators.pathtracer as pt
from estimators.pathtracer import geometry, layout, prepare_scene

# direct calls of the tracer's per-ray functions compile as inside the kernels
pytestmark = pytest.mark.usefixtures("kernel_compile_context")

HERE = os.path.dirname(pt.__file__)
MODULES = sorted(f for f in os.listdir(HERE) if f.endswith(".py"))


def _tree(name):
    with open(os.path.join(HERE, name), encoding="utf-8") as f:
        return ast.parse(f.read())


def test_feature_bits_are_defined_only_in_layout():
    """No other module of the tracer shifts a bit (``1 << k``, k a name or below 16) to
    make a feature; ``1 << 30`` as a size cap is not one."""
    offenders = []
    for name in MODULES:
        if name == "layout.py":
            continue
        for node in ast.walk(_tree(name)):
            if isinstance(node, ast.BinOp) and isinstance(node.op, ast.LShift) \
                    and isinstance(node.left, ast.Constant) and node.left.value == 1 \
                    and not (isinstance(node.right, ast.Constant) and node.right.value >= 16):
                offenders.append(f"{name}:{node.lineno}")
    assert not offenders, offenders


def test_feature_bits_are_distinct_single_bits_and_the_masks_hold_them_all():
    bits = list(layout.FEATURE_BITS.values())
    assert all(b > 0 and b & (b - 1) == 0 for b in bits)
    assert len(set(bits)) == len(bits)
    assert layout.ALL_FEATURES == sum(bits)
    assert layout.ALL_BSDF_FEATURES == sum(layout.BSDF_BITS) | layout.F_TEXTURES | \
        layout.F_TWOSIDED
    # every BSDF the layout knows has its own bit; every feature the loader can name
    # from a BSDF is a key of the table
    assert [layout.FEATURE_BITS[f"bsdf:{n}"] for n in layout.BSDF_NAMES] == \
        list(layout.BSDF_BITS)


def test_nothing_unpacks_the_scene_arrays_by_position():
    """The kernel reads ``sc.<field>``: a tuple target unpacking ``sc`` (or ``arrays``)
    would read the wrong array silently after a reordering."""
    offenders = []
    for name in MODULES:
        for node in ast.walk(_tree(name)):
            if isinstance(node, ast.Assign) and isinstance(node.targets[0], ast.Tuple) \
                    and isinstance(node.value, ast.Name) and node.value.id in ("sc", "arrays"):
                offenders.append(f"{name}:{node.lineno}")
            if isinstance(node, ast.Subscript) and isinstance(node.value, ast.Name) \
                    and node.value.id in ("sc", "arrays") \
                    and isinstance(node.slice, ast.Constant):
                offenders.append(f"{name}:{node.lineno}")
    assert not offenders, offenders


def test_geometry_reads_primitives_where_the_layout_puts_them(tmp_path):
    """Geometry's element offsets are the layout's columns: a triangle, a sphere and a
    disk written by ``prepare`` through the named columns are intersected where they are."""
    assert (layout.TRI_P0, layout.TRI_P1, layout.TRI_P2) == (0, 3, 6)
    assert (layout.TRI_N0, layout.TRI_UV0) == (9, 18)
    assert (layout.SPHERE_CENTER, layout.SPHERE_RADIUS, layout.SPHERE_ROTATION) == (0, 3, 4)
    assert (layout.DISK_TO_WORLD, layout.DISK_TO_LOCAL) == (0, 12)
    path = tmp_path / "s.xml"
    path.write_text("""<scene version="3.0.0"><sensor type="perspective">
      <float name="fov" value="40"/><film type="hdrfilm"><rfilter type="box"/></film></sensor>
      <shape type="rectangle"><transform name="to_world"><translate x="6" z="-5"/>
        </transform></shape>
      <shape type="sphere"><point name="center" x="3" y="0" z="-3"/>
        <float name="radius" value="0.5"/></shape>
      <shape type="disk"><transform name="to_world"><translate z="-2"/></transform></shape>
    </scene>""")
    a = prepare_scene(str(path)).arrays
    stack = geometry.new_stack()
    # rays along -z from z = 0: the disk (radius 1) at 2, the sphere's front at 2.5, the
    # rectangle at 5, and nothing at x = 9
    for ox, expect in ((0.0, 2.0), (3.0, 2.5), (6.5, 5.0), (9.0, None)):
        t, j, _, _ = geometry.intersect(a.bvh_nodes, a.leaf_prims, a.leaf_info, stack,
                                        ox, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, np.inf)
        if expect is None:
            assert j < 0
        else:
            assert j >= 0 and abs(t - expect) < 1e-9, (ox, t)
