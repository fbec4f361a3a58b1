"""Planning from a scene: only what the scene uses is checked, the rest is skipped with a
reason, and an unsupported scene is refused by line."""

import os
import subprocess
import sys

import pytest

from mcverify.gate.plan import plan
from mcverify.gate.reference import REFERENCE_ROOT

CORNELL = os.path.join(REFERENCE_ROOT, "cornell-box", "scene.xml")
CMD = [sys.executable, "-m", "mcverify"]

DIFFUSE_POINT = """<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="45"/><film type="hdrfilm"><rfilter type="box"/></film></sensor>
  <emitter type="point"><point name="position" x="0" y="2" z="0"/></emitter>
  <shape type="sphere"><bsdf type="diffuse"/></shape>
</scene>"""


def _names(checks):
    return {c.name for c in checks}


def test_cornell_box_plan():
    checks, skipped, features = plan(CORNELL)
    names = _names(checks)
    assert {"sampler:cosine_hemisphere", "sampler:uniform_triangle", "sampler:ggx(alpha=0.3)",
            "sampler:beckmann(alpha=0.3)", "unbiased:russian_roulette(q=0.3)"} <= names
    assert not any(n.startswith(("scipy:", "sampler:mitsuba", "sampler:exponential",
                                 "sampler:uniform_cone")) for n in names)
    reasons = dict(skipped)
    assert "delta BSDF" in reasons["bsdf:dielectric"]
    assert "render:cornell-box" in names           # the scene's own render gate


def test_rough_conductors_instance_checks_are_as_many_as_the_readme_says():
    # The README's cost line: `-k tracer.` runs 21 chi-square and 21 consistency checks.
    checks, _, _ = plan(os.path.join(REFERENCE_ROOT, "rough-conductors", "scene.xml"))
    names = [n for n in _names(checks) if "tracer." in n]
    assert len(names) == 42
    assert sum(n.startswith("sampler:tracer.") for n in names) == 21
    assert sum(n.startswith("pdf_consistency:tracer.") for n in names) == 21


def test_a_check_that_names_nothing_it_verifies_runs_with_any_scene():
    """A user suite's checks leave ``verifies`` empty (Check's default): with --scene they
    were all skipped as "not needed by this scene" (printed nowhere), and a project's
    `mcverify check --scene` passed without running any of its own checks."""
    from mcverify.gate.suites import Check, build_suite

    mine = Check("mine", lambda seed: None)
    checks, skipped, _ = plan(CORNELL, checks=build_suite("default") + [mine])
    assert "mine" in _names(checks)
    assert "mine" not in {name for name, _ in skipped}
    # the built-in checks are still planned by what they verify
    assert "sampler:uniform_interval(a=-1,b=3)" in {name for name, _ in skipped}


def test_diffuse_scene_with_a_point_light(tmp_path):
    path = tmp_path / "scene.xml"
    path.write_text(DIFFUSE_POINT)
    checks, skipped, _ = plan(str(path))
    tracer = {n for n in _names(checks) if ":tracer." in n}
    assert tracer == {f"{kind}:tracer.bsdf:{tmp_path.name}/bsdf0:diffuse@wi={t}°"
                      for t in (0, 45, 80) for kind in ("sampler", "pdf_consistency")}
    assert _names(checks) - tracer == {
        "sampler:cosine_hemisphere", "inverse:cosine_hemisphere",
        "unbiased:russian_roulette(q=0.3)", "unbiased:mis(balance)", "unbiased:mis(power)",
        f"render:{tmp_path.name}"}
    assert "delta emitter" in dict(skipped)["emitter:point"]
    assert "delta emitter" in dict(skipped)[f"emitter {tmp_path.name}/light0:point"]


@pytest.mark.parametrize("bsdf", ["plastic", "roughplastic"])
def test_a_plastic_alone_plans_the_cosine_warp_of_its_diffuse_lobe(tmp_path, bsdf):
    """A scene whose only BSDF is a plastic samples its diffuse lobe by the cosine warp:
    a mutation review found plastic's entry of NEEDS emptied passing every test (the
    plans tested had a diffuse BSDF beside it), and then the warp was skipped as "not
    needed by this scene"."""
    path = tmp_path / "scene.xml"
    path.write_text(DIFFUSE_POINT.replace('"diffuse"', f'"{bsdf}"'))
    checks, skipped, features = plan(str(path))
    assert f"bsdf:{bsdf}" in features and "bsdf:diffuse" not in features
    assert "sampler:cosine_hemisphere" in _names(checks)
    assert "sampler:cosine_hemisphere" not in dict(skipped)


def test_a_shape_without_a_bsdf_plans_mitsubas_default_diffuse(tmp_path):
    """An outside review: a shape with no <bsdf> is diffuse in Mitsuba and in the tracer
    (its instance was checked as bsdf0:diffuse), but the scene's features did not name
    bsdf:diffuse, so the cosine warp it samples by was skipped as "not needed by this
    scene". It plans the same checks as an explicit <bsdf type="diffuse"/> now."""
    explicit = tmp_path / "explicit.xml"
    explicit.write_text(DIFFUSE_POINT)
    default = tmp_path / "default.xml"
    default.write_text(DIFFUSE_POINT.replace('<bsdf type="diffuse"/>', ""))
    (want, _, want_features), (got, _, features) = plan(str(explicit)), plan(str(default))
    assert "bsdf:diffuse" in features and features == want_features
    assert {"sampler:cosine_hemisphere", "inverse:cosine_hemisphere"} <= _names(got)
    assert {n.replace("explicit", "default") for n in _names(want)} == _names(got)


def test_two_scene_files_in_one_folder_get_their_own_check_names(tmp_path):
    """A scene file other than scene.xml is named by its stem, as its reference is
    (``ref-FILE.xml/``) and as render-check names it; plan named both files of a folder
    after the folder, so their checks collided."""
    for stem in ("lamp", "desk"):
        (tmp_path / f"{stem}.xml").write_text(DIFFUSE_POINT)
    a, b = (_names(plan(str(tmp_path / f"{s}.xml"))[0]) for s in ("lamp", "desk"))
    own = {n for n in a if n.startswith(("render:", "sampler:tracer."))}
    assert "render:lamp" in own and "render:desk" in b and own.isdisjoint(b)
    assert "sampler:tracer.bsdf:lamp/bsdf0:diffuse@wi=0°" in a


def test_cli_plan_and_check_scene(tmp_path):
    r = subprocess.run(CMD + ["plan", CORNELL], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "sampler:cosine_hemisphere" in r.stdout
    assert "delta BSDF" in r.stdout
    # spelt as for check, --scene works too
    r2 = subprocess.run(CMD + ["plan", "--scene", CORNELL], capture_output=True, text=True,
                        timeout=120)
    assert r2.returncode == 0 and r2.stdout == r.stdout
    out = tmp_path / "r.json"
    r = subprocess.run(CMD + ["check", "--scene", CORNELL, "-k", "inverse:", "--json", str(out),
                              "-q"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    import json
    doc = json.loads(out.read_text())
    assert doc["n_checks"] >= 3
    r = subprocess.run(CMD + ["check", "--scene", CORNELL, "-k", "render:", "--json", str(out),
                              "-q"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    doc = json.loads(out.read_text())
    assert [x["name"] for x in doc["results"]] == ["render:cornell-box"]


def test_unsupported_scene_is_exit_2_naming_the_line(tmp_path):
    path = tmp_path / "bad.xml"
    path.write_text(DIFFUSE_POINT.replace('<bsdf type="diffuse"/>', '<bsdf type="hair"/>'))
    r = subprocess.run(CMD + ["plan", str(path)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "bad.xml:4" in r.stderr and "hair" in r.stderr


def test_a_ply_area_light_plans_triangle_sampling(tmp_path):
    """A PLY mesh light is sampled triangle by triangle, as an OBJ one is (its feature
    emitter:area:ply had no entry: uniform_triangle was 'not needed' until 4 December)."""
    from mcverify.gate.plan import NEEDS

    assert NEEDS["emitter:area:ply"] == NEEDS["emitter:area:obj"]
    path = tmp_path / "scene.xml"
    path.write_text(DIFFUSE_POINT.replace(
        '<shape type="sphere"><bsdf type="diffuse"/></shape>',
        '<shape type="ply"><string name="filename" value="lamp.ply"/><emitter type="area">'
        '<rgb name="radiance" value="1"/></emitter></shape>'))
    import shutil
    shutil.copy(os.path.join(REFERENCE_ROOT, "vocabulary-geometry", "lamp.ply"), tmp_path)
    checks, skipped, features = plan(str(path))
    assert "emitter:area:ply" in features
    assert {"sampler:uniform_triangle", "inverse:uniform_triangle"} <= _names(checks)


def test_plan_and_check_scene_take_a_folder_or_a_reference_name(tmp_path):
    """As render-check does (and as --refs on check says): `plan cornell-box` and `check
    --scene <folder>` failed with "cannot read cornell-box" / "is not a regular file"."""
    r = subprocess.run(CMD + ["plan", CORNELL], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    for spec in ("cornell-box", os.path.dirname(CORNELL)):
        by = subprocess.run(CMD + ["plan", spec], capture_output=True, text=True,
                            timeout=120)
        assert by.returncode == 0, by.stderr
        assert by.stdout.splitlines()[1:] == r.stdout.splitlines()[1:]
    # a reference of one's own, by name in --refs
    (tmp_path / "lamp").mkdir()
    (tmp_path / "lamp" / "scene.xml").write_text(DIFFUSE_POINT)
    r = subprocess.run(CMD + ["check", "--refs", str(tmp_path), "--scene", "lamp", "-k",
                              "inverse:", "-q"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    r = subprocess.run(CMD + ["plan", "nosuch-scene"], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2 and "scene 'nosuch-scene'" in r.stderr


CONDUCTOR_SKY = """<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="45"/><film type="hdrfilm"><rfilter type="box"/></film></sensor>
  <emitter type="constant"/>
  <shape type="sphere"><bsdf type="roughconductor"><float name="alpha" value="0.2"/></bsdf></shape>
</scene>"""


def test_a_constant_environment_plans_uniform_sphere_sampling_only(tmp_path):
    """An outside review: a constant environment planned the cosine-hemisphere warp too
    ("sampled uniformly / by cosine"), but the tracer samples it uniformly over the
    sphere only: a rough conductor under a constant sky ran a warp the scene never uses."""
    path = tmp_path / "scene.xml"
    path.write_text(CONDUCTOR_SKY)
    names = _names(plan(str(path))[0])
    assert "sampler:uniform_sphere" in names
    assert not any("cosine_hemisphere" in n for n in names), sorted(names)


GLASS_SEEN_DIRECTLY = """<scene version="3.0.0">
  <integrator type="path"><integer name="max_depth" value="DEPTH"/></integrator>
  <sensor type="perspective"><float name="fov" value="45"/><film type="hdrfilm"><rfilter type="box"/></film></sensor>
  <shape type="sphere"><bsdf type="roughdielectric"><float name="alpha" value="0.001"/><float name="int_ior" value="1.0001"/><float name="ext_ior" value="1"/></bsdf></shape>
  <shape type="rectangle"><emitter type="area"/></shape>
</scene>"""


def test_a_path_tracer_of_max_depth_0_or_1_plans_its_render_check_only(tmp_path):
    """An outside review: at max_depth 1 camera rays end where they first hit (0: a black
    image), so no BSDF or light is sampled, but the plan kept every sampler, estimator and
    instance check of the scene's materials and lights: this rough dielectric at alpha
    0.001, eta 1.0001 (a known limit of the chi-square binning, README) failed the gate of
    a scene whose image never samples it. They are skipped with that reason now; at
    max_depth 2 they run."""
    for depth in (0, 1):
        path = tmp_path / f"d{depth}.xml"
        path.write_text(GLASS_SEEN_DIRECTLY.replace("DEPTH", str(depth)))
        checks, skipped, _ = plan(str(path))
        assert _names(checks) == {f"render:d{depth}"}
        reasons = dict(skipped)
        label = (f"sampler:tracer.bsdf:d{depth}/bsdf0:"
                 "roughdielectric(beckmann,alpha=0.001,eta=1.0001)@wi=0°")
        assert f"max_depth {depth}" in reasons[label]
        assert f"max_depth {depth}" in reasons["sampler:uniform_triangle"]
        assert f"max_depth {depth}" in reasons["unbiased:mis(balance)"]
        assert reasons["scipy:norm"] == "not needed by this scene"
    path = tmp_path / "d2.xml"
    path.write_text(GLASS_SEEN_DIRECTLY.replace("DEPTH", "2"))
    names = _names(plan(str(path))[0])
    assert {"sampler:uniform_triangle", "unbiased:mis(balance)",
            label.replace("d1/", "d2/")} <= names


def test_a_masked_emitter_keeps_its_mask_checks_at_max_depth_1(tmp_path):
    """A read-only review: with a mask in the scene the last vertex's BSDF is sampled
    still (Mitsuba's valid_ray), so a masked emitter at max_depth 1 shows its radiance ×
    opacity, the mask's null probability, which its instance check tests; the plan
    skipped it as "no BSDF or light is sampled"."""
    path = tmp_path / "mask1.xml"
    path.write_text(GLASS_SEEN_DIRECTLY.replace("DEPTH", "1").replace(
        '<shape type="rectangle"><emitter type="area"/></shape>',
        '<shape type="rectangle"><emitter type="area"/><bsdf type="mask"><float '
        'name="opacity" value="0.3"/><bsdf type="diffuse"/></bsdf></shape>'))
    checks, skipped, _ = plan(str(path))
    names = _names(checks)
    assert any(n.startswith("sampler:tracer.bsdf:mask1/") and "mask(opacity=0.3" in n
               for n in names), sorted(names)
    assert not any("first hit" in why for _, why in skipped), skipped


def test_a_user_check_still_runs_at_max_depth_1(tmp_path):
    from mcverify.gate.suites import Check, resolve_suite

    path = tmp_path / "scene.xml"
    path.write_text(GLASS_SEEN_DIRECTLY.replace("DEPTH", "1"))
    mine = Check("mine", lambda seed, stop_alpha=None: None, ("user",))
    checks, _, _ = plan(str(path), checks=resolve_suite("default")[0] + [mine])
    assert _names(checks) == {"mine", f"render:{tmp_path.name}"}


def test_depth_2_under_delta_lights_only_plans_its_render_check_only(tmp_path):
    """An outside review: a direct integrator (or path at max_depth 2) under a point light
    reaches the light by its delta sample, and a BSDF-sampled ray finds nothing that
    emits, so no BSDF is sampled in the image; the plan ran every BSDF sampler and
    instance check. Skipped with that reason now; an area light, a deeper path or a mask
    (whose null component carries the ray on) keeps them."""
    def planned(name, integrator, extra=""):
        path = tmp_path / f"{name}.xml"
        path.write_text(DIFFUSE_POINT.replace(
            "<sensor", integrator + "\n  <sensor").replace("</scene>", extra + "</scene>"))
        return plan(str(path))

    for name, integrator in (("direct", '<integrator type="direct"/>'),
                             ("path2", '<integrator type="path"><integer name="max_depth" '
                                       'value="2"/></integrator>')):
        checks, skipped, _ = planned(name, integrator)
        assert _names(checks) == {f"render:{name}"}
        reasons = dict(skipped)
        assert "delta sample" in reasons[f"sampler:tracer.bsdf:{name}/bsdf0:diffuse@wi=45°"]
        assert "delta sample" in reasons["sampler:cosine_hemisphere"]
    deeper = '<integrator type="path"><integer name="max_depth" value="3"/></integrator>'
    area = '<shape type="disk"><emitter type="area"/></shape>'
    mask = '<shape type="disk"><bsdf type="mask"><bsdf type="diffuse"/></bsdf></shape>'
    for name, integrator, extra in (("deeper", deeper, ""),
                                    ("area", '<integrator type="direct"/>', area),
                                    ("mask", '<integrator type="direct"/>', mask)):
        names = _names(planned(name, integrator, extra)[0])
        assert {"sampler:cosine_hemisphere",
                f"sampler:tracer.bsdf:{name}/bsdf0:diffuse@wi=45°"} <= names, name


def test_russian_roulette_is_planned_only_where_a_path_reaches_rr_depth(tmp_path):
    """A path of max_depth vertices makes max_depth - 1 bounces and plays Russian roulette
    from rr_depth bounces on (Mitsuba's default 5), so at max_depth <= rr_depth no path
    reaches it: its estimator check was planned all the same (veach-mis, max_depth 4)."""
    def reasons(name, depth, rr=None):
        rr_line = "" if rr is None else f'<integer name="rr_depth" value="{rr}"/>'
        path = tmp_path / f"{name}.xml"
        path.write_text(DIFFUSE_POINT.replace("<sensor", (
            f'<integrator type="path"><integer name="max_depth" value="{depth}"/>'
            f'{rr_line}</integrator>\n  <sensor')))
        checks, skipped, _ = plan(str(path))
        return _names(checks), dict(skipped)

    rr = "unbiased:russian_roulette(q=0.3)"
    for name, depth, rr_depth in (("d5", 5, None), ("d3", 3, 3), ("d4", 4, None)):
        names, why = reasons(name, depth, rr_depth)
        assert rr not in names
        assert why[rr] == (f"path with max_depth {depth} <= rr_depth {rr_depth or 5}: "
                           "no path reaches Russian roulette")
        assert "unbiased:mis(balance)" in names     # the rest of the path's needs stay
    for name, depth, rr_depth in (("d6", 6, None), ("d4rr3", 4, 3), ("inf", -1, None)):
        assert rr in reasons(name, depth, rr_depth)[0], name


def test_a_suite_check_named_as_a_check_the_plan_adds_is_refused():
    """A project's own check named like the scene's render check ('render:white-furnace',
    a render check of its own) ran beside it under `check --scene`: two results of one
    name, one seed (seeds derive from names), two JUnit testcases alike. The names of a
    run's checks are unique across its suites; so they are against the plan's own."""
    import pytest

    from mcverify.errors import InvalidArgument
    from mcverify.gate.suites import Check

    scene = os.path.join(REFERENCE_ROOT, "white-furnace", "scene.xml")
    for name in ("render:white-furnace",
                 "sampler:tracer.bsdf:white-furnace/bsdf0:diffuse@wi=45°"):
        with pytest.raises(InvalidArgument, match=f"check {name!r}.*the scene's own"):
            plan(scene, checks=[Check(name, lambda seed: None)])


def test_check_scene_gates_a_splatting_film_at_its_references_samples_per_pass(tmp_path):
    """A gaussian-filtered scene (Mitsuba's default filter, that of its documentation
    scenes) whose reference the user built with other samples per pass than the render
    check's 64 (``reference build``'s default 256, or ``render-check --spp 128 --passes
    4``'s 32): ``check --scene`` failed its render check, exit 1, "raised
    InvalidArgument: ... our passes need the reference's 32 samples per pass: spp=512
    with passes=16", an option ``check`` does not have. The check now renders the
    reference's count a pass; a reference of fewer than 32 a pass exits 2 saying how to
    rebuild it."""
    from mcverify.errors import EnvironmentProblem
    from mcverify.gate import reference
    from mcverify.gate.suites import _run_guarded

    import pytest

    path = tmp_path / "scene.xml"
    path.write_text(DIFFUSE_POINT.replace('<rfilter type="box"/>', '<integer name="width" '
                                          'value="6"/><integer name="height" value="4"/>'
                                          '<rfilter type="gaussian"/>').replace(
        "<sensor", '<integrator type="path"/><sensor', 1).replace(
        "<film", '<transform name="to_world"><lookat origin="0, 1, -4" target="0, 0, 0" '
                 'up="0, 1, 0"/></transform><film', 1))
    reference.build_reference(str(path), spp=40, passes=2)
    render = [c for c in plan(str(path))[0] if c.name.startswith("render:")]
    r = _run_guarded(render[0], 0)
    assert r.passed, r.failures
    assert (r.details["ours_spp"], r.details["ours_passes"]) == (640, 16)
    reference.build_reference(str(path), spp=8, passes=2)
    with pytest.raises(EnvironmentProblem, match=r"its reference has 8 samples per pass; "
                                                 r".*at least 32; run `mcverify reference "
                                                 r"build .*scene.xml --spp 64 --passes 64`"):
        _run_guarded(render[0], 0)


def test_check_scene_exits_2_where_its_render_check_compares_nothing(tmp_path):
    """A scene whose reference and render are black in every pixel (here a camera inside
    a sphere) is refused by ``render-check``, exit 2: the comparison tested nothing.
    ``check --scene`` failed its render check instead, exit 1 ("FAIL render:... raised
    InvalidArgument"), as if our tracer were wrong; now exit 2 naming the scene."""
    path = tmp_path / "scene.xml"
    path.write_text(DIFFUSE_POINT.replace("<sensor", '<integrator type="path"/><sensor', 1)
                    .replace('<rfilter', '<integer name="width" value="6"/><integer '
                             'name="height" value="4"/><rfilter', 1))
    r = subprocess.run(CMD + ["check", "--scene", str(path), "-k", "render:", "-q"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 2, r.stdout + r.stderr
    assert "black in every pixel" in r.stderr and str(path) in r.stderr
    assert "Traceback" not in r.stderr


def test_check_scene_says_it_ran_the_scenes_plan(capsys):
    """`check --scene X` ended "mcverify check --suite default: 1 passed", the suite's
    name for a run whose checks the scene's plan chose (an outside review); it names the
    scene, and the suite only where one was given."""
    from mcverify.gate import cli

    scene = os.path.join(REFERENCE_ROOT, "white-furnace", "scene.xml")
    assert cli.main(["check", "--scene", scene, "-k", "inverse:cosine", "-q"]) == 0
    out = capsys.readouterr().out
    assert f"mcverify check --scene {scene}: 1 passed" in out, out
