"""``render_check(scene, renderer=...)``: a renderer of one's own through the render gate,
held to what ours is held to (found by a probe with renderers not in the repository)."""

import shutil

import numpy as np
import pytest

import mcverify as mv
from estimators.pathtracer import render
from mcverify.gate.render_check import render_check


def _ours(scale=1.0):
    def renderer(path, spp, seed):
        r = render(path, spp=spp, seed=seed, passes=16)
        if scale == 1.0:
            return r
        return (r.mean * scale, r.variance * scale ** 2, r.n)
    renderer.__name__ = f"ours_x{scale}"
    return renderer


def test_a_renderer_of_ones_own_passes_when_right_and_fails_when_brighter():
    assert render_check("white-furnace", renderer=_ours(), spp=512, seed=2).passed
    brighter = render_check("white-furnace", renderer=_ours(1.02), spp=512, seed=2)
    assert not brighter.passed


@pytest.mark.parametrize("out,needle", [
    (lambda r: (r.mean[:32], r.variance[:32], r.n), "return the mean as a numpy array"),
    (lambda r: (r.mean.tolist(), r.variance, r.n), "the rendered image is list"),
], ids=["shape", "list"])
def test_a_wrong_image_is_named_without_blaming_the_reference(out, needle):
    """It said 'rebuild the reference' for a renderer's own wrong shape."""
    def renderer(path, spp, seed):
        return out(render(path, spp=spp, seed=seed, passes=16))
    with pytest.raises(mv.InvalidArgument) as e:
        render_check("white-furnace", renderer=renderer, spp=512, seed=2)
    assert needle in str(e.value) and "rebuild" not in str(e.value), str(e.value)


def test_params_cannot_reach_a_renderer_of_ones_own():
    """The reference was rendered with the params, the renderer's image without them (a
    shape mismatch, or a silently different scene)."""
    with pytest.raises(mv.InvalidArgument, match="params=.*renderer\\(scene_path, spp, seed\\)"):
        render_check("white-furnace", renderer=_ours(), spp=512, params={"res": 16})


@pytest.mark.parametrize("kw", [{"passes": 4}, {"pdf_scale": 1.1}, {"plant": {"x": 1}}],
                         ids=["passes", "pdf_scale", "plant"])
def test_our_tracers_settings_are_refused_for_a_renderer_of_ones_own(kw):
    """``passes`` (and the bug-planting hooks) were accepted with a renderer of one's
    own and silently ignored: it is called once (an outside review)."""
    with pytest.raises(mv.InvalidArgument, match=f"{next(iter(kw))}=.*our path tracer only"):
        render_check("white-furnace", renderer=_ours(), spp=512, **kw)


def test_a_splatting_scene_holds_a_renderer_of_ones_own_to_the_references_passes():
    """filters-tent's reference has 64 samples a pass: 16 passes of 16 are refused, as
    for our tracer, and a mean that is not its passes' mean is refused."""
    with pytest.raises(mv.InvalidArgument, match="64 samples each: spp=1024 for 16 passes"):
        render_check("filters-tent", renderer=_ours(), spp=256, seed=1)

    def inconsistent(path, spp, seed):
        r = render(path, spp=spp, seed=seed, passes=16)
        return type("R", (), dict(mean=r.mean * 1.02, variance=r.variance, n=r.n,
                                  passes=r.passes))()
    with pytest.raises(mv.InvalidArgument, match="not the mean of its passes"):
        render_check("filters-tent", renderer=inconsistent, spp=1024, seed=1)


def test_a_correct_renderer_of_ones_own_has_the_variance_floor_ours_has():
    """A renderer of one's own had no variance floor: our own tracer's 16 passes, handed in
    as a renderer, failed the Cornell box on seeds 5 and 11 of 0-11 (pixels whose passes
    missed the caustic, blocks dark) at α = 0.01 while the very same image passed as ours.
    Its n values of spp / n samples each are now floored at the reference's variance."""
    r = render_check("cornell-box", renderer=_ours(), spp=512, seed=5)
    assert r.passed, r.messages
    assert r.details["variance_floor"]["test_spp"] == 32
    # a (mean, var, n) of single samples: one sample behind each value
    def per_sample(path, spp, seed):
        p = render(path, spp=spp, seed=seed, passes=16)
        return p.mean, p.variance * 32, 512
    r = render_check("white-furnace", renderer=per_sample, spp=512, seed=2)
    assert r.passed and r.details["variance_floor"]["test_spp"] == 1


def test_a_renderer_returning_its_samples_variance_is_told_what_to_check():
    """Mitsuba's own 16 passes, 2 % brighter, returned with their samples' variance (32
    times the pass means') and n = 16: the tests lose power (p = 7e-4 on seed 100, 4e-7
    with the right variance; on the 32 × 32 box of the review a light 1 % brighter passed,
    p = 0.15), and the note that says so named compare_images' test_spp=32 and
    ref_spp=256, counts the user never gave, where what to check is the renderer's n and
    variance (an outside review)."""
    from mcverify.gate import mitsuba as mvm

    def samples_variance(path, spp, seed):
        m = mvm.render_passes(path, spp=spp // 16, seeds=range(seed, seed + 16)) * 1.02
        return m.mean(axis=0), m.var(axis=0, ddof=1) * (spp // 16), 16
    r = render_check("cornell-box", renderer=samples_variance, spp=512, seed=100)
    note = [m for m in r.messages if m.startswith("note: per sample")]
    assert note and "test_spp" not in note[0] and "check what renderer=samples_variance " \
        "returned: n=16 values of 32 samples each (spp / n), and the variance of those " \
        "values, not of single samples (the reference's values are of 256" in note[0], note


def _returning(name, mean=None, var=None, n=16, passes=None):
    """A renderer of one's own returning the given image of white-furnace (64 × 64 × 3,
    1 in every pixel), no rendering needed."""
    def renderer(path, spp, seed):
        m = np.ones((64, 64, 3)) if mean is None else mean
        v = np.full((64, 64, 3), 1e-3) if var is None else var
        if passes is None:
            return m, v, n
        return type("R", (), dict(mean=m, variance=v, n=n, passes=passes))()
    renderer.__name__ = name
    return renderer


_nan = np.ones((64, 64, 3))
_nan[3, 4, 1] = np.nan


@pytest.mark.parametrize("renderer,needle", [
    (_returning("nan_pixel", mean=_nan), "renderer=nan_pixel: its mean: contains NaN/Inf at "
                                         "[3, 4, 1]"),
    (_returning("negative_var", var=-np.ones((64, 64, 3))),
     "renderer=negative_var: its variance: 12288 negative"),
    (_returning("grey_var", var=np.ones((64, 64))),
     "renderer=grey_var: its variance: shape (64, 64, 1) differs from its mean's"),
    (_returning("one_value", n=1), "renderer=one_value: its n=1: must be >= 2"),
    (_returning("float_n", n=16.0), "renderer=float_n: its n=16.0: must be an integer"),
    (_returning("rgba", mean=np.ones((64, 64, 4))), "renderer=rgba: "),
], ids=["nan", "negative-var", "var-shape", "n1", "n-float", "rgba"])
def test_what_a_renderer_returned_wrong_is_named_with_the_renderer(renderer, needle):
    """compare_images' refusals reached the user as "test_mean: contains NaN/Inf at
    [3, 4, 1]" or "test_n=1: must be >= 2": names of compare_images' parameters, which the
    user never gave, and not the renderer."""
    with pytest.raises(mv.InvalidArgument) as e:
        render_check("white-furnace", renderer=renderer, spp=512, seed=2)
    assert needle in str(e.value) and "test_" not in str(e.value), str(e.value)


def test_a_nan_in_a_renderers_passes_is_named_as_such():
    """On a splatting scene a NaN in one pass image was reported as "its mean is not the
    mean of its passes (largest difference nan)"."""
    passes = np.ones((16, 64, 64, 3)) + 0.01 * np.arange(16)[:, None, None, None]
    passes[5, 10, 11, 2] = np.nan
    renderer = _returning("nan_pass", mean=np.nanmean(passes, axis=0), passes=passes)
    with pytest.raises(mv.InvalidArgument) as e:
        render_check("filters-tent", renderer=renderer, spp=1024, seed=1)
    assert "renderer=nan_pass: its passes: contains NaN/Inf" in str(e.value), str(e.value)


@pytest.mark.parametrize("scene,spp", [("white-furnace", 512), ("filters-tent", 1024)])
def test_a_renderer_reusing_its_seed_is_refused_for_it(scene, spp):
    """A renderer that ignores its seed returns identical passes. They failed the gate as
    blocks of another brightness (filters-tent) or were not looked at (a box filter), the
    cause unsaid; compare --test-passes refuses them. Now both say so."""
    rng = np.random.default_rng(5)
    one = 1.0 + 0.1 * rng.standard_normal((64, 64, 3))
    passes = np.stack([one + 0.01 * k for k in range(16)])
    passes[9] = passes[3]
    renderer = _returning("same_seed", mean=passes.mean(axis=0),
                          var=passes.var(axis=0, ddof=1), passes=passes)
    with pytest.raises(mv.InvalidArgument,
                       match="renderer=same_seed: its pass 9 is identical to its pass 3"):
        render_check(scene, renderer=renderer, spp=spp, seed=1)


def test_identical_passes_of_a_scene_without_noise_are_no_reused_seed(tmp_path):
    """Where the reference's own passes are identical (no noise: a pixel sees one
    constant emitter), any renderer's are: they are compared, not refused."""
    scene = tmp_path / "scene.xml"
    scene.write_text("""<scene version="3.0.0">
  <integrator type="path"><integer name="max_depth" value="2"/></integrator>
  <sensor type="perspective"><float name="fov" value="30"/>
    <sampler type="independent"><integer name="sample_count" value="4"/></sampler>
    <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/>
      <rfilter type="box"/></film></sensor>
  <emitter type="constant"><rgb name="radiance" value="0.5, 0.25, 1"/></emitter>
</scene>""")
    passes = np.tile(np.array([0.5, 0.25, 1.0]), (16, 8, 8, 1))
    renderer = _returning("constant", mean=passes[0], var=np.zeros((8, 8, 3)),
                          passes=passes)
    r = render_check(str(scene), renderer=renderer, spp=512, seed=1)
    assert r.passed, r.messages


@pytest.mark.parametrize("renderer,needle", [
    ("mymodule:render", "renderer='mymodule:render': must be a callable"),
    (42, "renderer=42: must be a callable"),
    (lambda path, spp: None, "renderer=<lambda>: cannot be called as renderer(scene_path, "
                             "spp, seed)"),
], ids=["module-string", "int", "two-parameters"])
def test_a_renderer_that_cannot_be_called_so_is_named(renderer, needle):
    """A "module:function" string (as check --suite takes) or a function of two
    parameters ended in Python's TypeError ("'str' object is not callable")."""
    with pytest.raises(mv.InvalidArgument) as e:
        render_check("white-furnace", renderer=renderer, spp=512)
    assert needle in str(e.value), str(e.value)


def test_a_renderer_with_extra_defaults_or_a_callable_object_is_taken():
    class Renderer:
        def __call__(self, path, spp, seed, *, quality="high"):
            return np.ones((64, 64, 3)), np.full((64, 64, 3), 1e-3), 16
    assert render_check("white-furnace", renderer=Renderer(), spp=512).passed
@pytest.mark.parametrize("params", [None, {"res": 16}], ids=["missing-reference", "params"])
def test_a_reference_mitsuba_renders_under_the_fallback_variant_says_so(tmp_path, monkeypatch,
                                                                         params):
    """With llvm_ad_rgb unusable (DRJIT_LIBLLVM_PATH at LLVM 15) render-check built a new
    scene's reference, or rendered one for --param, with scalar_rgb without a word: the
    notice said "building it with Mitsuba", the fallback's notice was printed by `check`
    and `bench` only. It now comes through ``notice`` before Mitsuba renders."""
    from mcverify.gate import mitsuba as mvm
    from mcverify.gate import reference

    scene = tmp_path / "scene.xml"
    shutil.copy(reference.resolve_scene("white-furnace")[1], scene)
    fallback = "mitsuba: llvm_ad_rgb does not work with /x/libLLVM-15.so; using scalar_rgb"
    monkeypatch.setattr(mvm, "choose_variant", lambda: mvm.VariantChoice("scalar_rgb", fallback))

    class Rendered(Exception):
        pass

    def render_with_mitsuba(*a, **k):
        raise Rendered

    monkeypatch.setattr(reference, "build_reference", render_with_mitsuba)
    monkeypatch.setattr(reference, "render_reference", render_with_mitsuba)
    said = []
    with pytest.raises(Rendered):
        render_check(str(scene), spp=512, seed=2, params=params, notice=said.append)
    assert fallback in said, said


def test_identical_passes_are_refused_only_where_the_scene_is_noisy_enough():
    """Correct passes of a scene noisy at a few pixel values only (1 spp a pass, an edge
    pixel of two values) can coincide by chance: refused only where the reference is
    noisy at 64 values or more (two seeds then agree with probability 2^-64 or less)."""
    from types import SimpleNamespace

    from mcverify.gate.render_check import _NOISY_VALUES, _distinct_passes

    passes = 1.0 + 0.01 * np.arange(4)[:, None, None, None] * np.ones((4, 8, 8, 3))
    passes[2] = passes[1]
    for noisy, refused in ((_NOISY_VALUES - 1, False), (_NOISY_VALUES, True)):
        var = np.zeros((8, 8, 3))
        var.flat[:noisy] = 0.1
        ref = SimpleNamespace(mean=np.ones((8, 8, 3)), var=var)
        if refused:
            with pytest.raises(mv.InvalidArgument, match="its pass 2 is identical to its "
                                                         "pass 1"):
                _distinct_passes(passes, ref, "mine")
        else:
            _distinct_passes(passes, ref, "mine")


def _constant_scene(tmp_path, res):
    from mcverify.gate import reference

    scene = tmp_path / "scene.xml"
    scene.write_text(f"""<scene version="3.0.0">
  <integrator type="path"><integer name="max_depth" value="2"/></integrator>
  <sensor type="perspective"><float name="fov" value="30"/>
    <sampler type="independent"><integer name="sample_count" value="4"/></sampler>
    <film type="hdrfilm"><integer name="width" value="{res}"/>
      <integer name="height" value="{res}"/><rfilter type="box"/></film></sensor>
  <emitter type="constant"><rgb name="radiance" value="0.5, 0.25, 1"/></emitter>
</scene>""")
    reference.build_reference(str(scene), spp=1, passes=2)
    return str(scene)


def test_a_film_too_large_for_the_memory_is_refused_before_our_passes(tmp_path, monkeypatch):
    """render-check had no memory guard of its own: a 4096 × 4096 film under
    `ulimit -v 4000000` rendered and ended in "unexpected MemoryError: Unable to allocate
    192. MiB", naming nothing (an outside review). Now refused before our passes render,
    naming the film and the memory it needs."""
    from mcverify import _validate
    from mcverify.gate import render_check as rc

    scene = _constant_scene(tmp_path, 256)
    monkeypatch.setattr(_validate, "_available_memory", lambda: 2 ** 26)    # 64 MiB
    monkeypatch.setattr(rc, "_OurPasses", None)     # never reached
    with pytest.raises(mv.InvalidArgument, match=r"film 256 x 256 and --passes=2: the "
                       r"render check needs about .* MiB of memory .*more than half of "
                       r"the 64 MiB available"):
        render_check(scene, spp=64, passes=2)


@pytest.mark.parametrize("passes", [2, 8])
def test_the_render_check_memory_guard_counts_what_it_takes(tmp_path, passes):
    """The guard's bytes a pixel bound what a check takes at its peak (tracemalloc)."""
    import tracemalloc

    from mcverify.gate import render_check as rc

    scene = _constant_scene(tmp_path, 256)
    render_check(scene, spp=64, passes=2)     # what stays loaded after a first check
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        render_check(scene, spp=32 * passes, passes=passes)
        peak = tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()
    assert peak <= 256 * 256 * (rc._CHECK_BYTES_PER_PIXEL + rc._PASS_BYTES_PER_PIXEL * passes)


def test_a_black_reference_is_refused_as_testing_nothing(tmp_path):
    """A camera outside a closed room (a cube with flip_normals, one-sided diffuse walls)
    sees only the walls' backs: Mitsuba's reference is 0 everywhere, and render-check
    passed, p = 1, comparing 0 with 0 (found with a scene not in the repository). It is
    refused now; an image with light against that reference still fails."""
    from mcverify.gate import reference

    scene = tmp_path / "scene.xml"
    scene.write_text("""<scene version="3.0.0">
  <integrator type="path"><integer name="max_depth" value="3"/></integrator>
  <sensor type="perspective"><float name="fov" value="40"/>
    <transform name="to_world"><lookat origin="0, 0, 3" target="0, 0, 0" up="0, 1, 0"/></transform>
    <sampler type="independent"><integer name="sample_count" value="4"/></sampler>
    <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/>
      <rfilter type="box"/></film></sensor>
  <shape type="cube"><transform name="to_world"><scale value="2"/></transform>
    <boolean name="flip_normals" value="true"/><bsdf type="diffuse"/></shape>
  <shape type="sphere"><float name="radius" value="0.3"/>
    <emitter type="area"><rgb name="radiance" value="5"/></emitter></shape>
</scene>""")
    reference.build_reference(str(scene), spp=4, passes=2)

    def black(path, spp, seed):
        return np.zeros((8, 8, 3)), np.zeros((8, 8, 3)), 16
    black.__name__ = "black"
    with pytest.raises(mv.InvalidArgument, match="reference and renderer=black's image are "
                                                 "black in every pixel") as e:
        render_check(str(scene), renderer=black, spp=64, seed=1)
    # the causes it lists include hide_emitters and delta lights behind glass, which an
    # outside review met and the message did not name
    assert "hide_emitters" in str(e.value) and "behind glass" in str(e.value), str(e.value)
    # and a sphere light mirrored by its to_world, which shines inwards (an outside review)
    assert "negative scale in to_world shines inwards" in str(e.value), str(e.value)

    def lit(path, spp, seed):       # light where Mitsuba has none: compared, and fails
        return np.full((8, 8, 3), 0.5), np.full((8, 8, 3), 0.01), 16
    assert not render_check(str(scene), renderer=lit, spp=64, seed=1).passed


def test_the_gate_hands_compare_images_each_sides_own_variance_n_and_the_alpha(monkeypatch):
    """The wiring, not the statistics: each side's mean, variance and n (the renderer's 8
    values, the reference's 16 passes), the samples behind each value (512 / 8 and the
    reference's per pass) and the α asked for reach ``compare_images``. A mutation review
    found ``ref_n=n`` (the renderer's n for the reference's) passing every test, where the
    renderers returned 16 values as the reference holds 16 passes."""
    from mcverify.gate import reference, render_check as rc

    ref = reference.load_reference("white-furnace")
    mean, var = ref.mean * 1.0, np.full_like(ref.var, 0.25)
    seen = []
    real = rc.compare_images

    def spy(test_mean, ref_mean, **kw):
        seen.append(dict(kw, test_mean=test_mean, ref_mean=ref_mean))
        return real(test_mean, ref_mean, **kw)

    monkeypatch.setattr(rc, "compare_images", spy)
    render_check("white-furnace", renderer=lambda path, spp, seed: (mean, var, 8), spp=512,
                 seed=2, alpha=0.2)
    (kw,) = seen
    assert kw["test_mean"] is mean and kw["test_var"] is var and kw["test_n"] == 8
    assert np.array_equal(kw["ref_mean"], ref.mean)
    assert np.array_equal(kw["ref_var"], ref.var) and kw["ref_n"] == ref.n == 16
    assert (kw["alpha"], kw["test_spp"], kw["ref_spp"]) == (0.2, 64, ref.manifest["spp"])


@pytest.mark.mitsuba
def test_our_passes_reach_compare_images_as_a_one_shot_render_of_them(monkeypatch):
    """``_OurPasses`` promises the final look sees the image ``render(passes=...)`` makes:
    the mean and variance (ddof = 1) of ``passes`` passes of spp / passes samples, each
    with its own seed (``pass_seed``). A mutation review found two passes sharing a seed
    (``pass_seed(seed, k // 2)``) passing every test: a render gate whose test variance
    came from 8 distinct passes of 16 and n = 16."""
    from mcverify.gate import render_check as rc

    seen = []
    real = rc.compare_images

    def spy(test_mean, ref_mean, **kw):
        seen.append((test_mean, kw["test_var"], kw["test_n"], kw["test_spp"]))
        return real(test_mean, ref_mean, **kw)

    monkeypatch.setattr(rc, "compare_images", spy)
    from mcverify.gate.reference import resolve_scene

    r = render_check("cornell-box", spp=512, passes=8, seed=7, params={"res": 8})
    want = render(resolve_scene("cornell-box")[1], spp=512, seed=7, passes=8,
                  params={"res": 8})
    mean, var, n, per = seen[-1]
    assert r.details["ours_passes"] == n == want.n == 8 and per == 64
    assert np.array_equal(mean, want.mean) and np.array_equal(var, want.variance)
    assert var.max() > 0        # a noisy image: passes sharing a seed would show
