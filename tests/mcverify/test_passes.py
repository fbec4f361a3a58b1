"""Any renderer's images: K pass EXRs -> mean, variance, n (``mcverify compare
--test-passes/--ref-passes``), RGBA compared on colour."""

import os
import subprocess
import sys

import numpy as np
import pytest

import mcverify as mv
from mcverify.gate import mitsuba as mvm
from mcverify.gate import reference
from mcverify.gate.passes import pass_stats, read_radiance

pytestmark = pytest.mark.mitsuba
CMD = [sys.executable, "-m", "mcverify"]


def _write(folder, images, stem="pass"):
    os.makedirs(folder, exist_ok=True)
    for i, img in enumerate(images):
        mvm.write_exr(os.path.join(folder, f"{stem}_{i:02d}.exr"), img)
    return os.path.join(folder, f"{stem}_*.exr")


def test_mean_variance_and_n_of_the_passes(tmp_path):
    rng = np.random.default_rng(0)
    imgs = rng.random((6, 5, 7, 3)).astype(np.float32) * 4
    s = pass_stats(_write(tmp_path, imgs))
    assert s.n == 6 and len(s.files) == 6 and s.notes == ()
    np.testing.assert_allclose(s.mean, imgs.astype(np.float64).mean(0), rtol=1e-12)
    np.testing.assert_allclose(s.var, imgs.astype(np.float64).var(0, ddof=1), rtol=1e-9)


def test_rgba_is_compared_on_colour_and_says_so(tmp_path):
    rgba = np.random.default_rng(1).random((4, 4, 4)).astype(np.float32)
    path = str(tmp_path / "a.exr")
    mvm.write_exr(path, rgba)
    assert set(reference.exr_channel_types(path)) == {"R", "G", "B", "A"}
    img, note = read_radiance(path)
    np.testing.assert_array_equal(img, rgba[:, :, :3].astype(np.float64))
    assert "alpha channel ignored" in note
    s = pass_stats(_write(tmp_path / "p", [rgba, rgba * 2]))
    assert s.mean.shape == (4, 4, 3) and s.notes == ("alpha channels ignored",)


@pytest.mark.parametrize("make, match", [
    (lambda d: _write(d, [np.ones((3, 3, 3))]), "matches 1 file"),
    (lambda d: os.path.join(d, "nothing_*.exr"), "matches 0 file"),
    (lambda d: _write(d, [np.ones((3, 3, 3)), np.ones((3, 3, 3))]), "identical to"),
    (lambda d: _write(d, [np.ones((3, 3, 3)), np.zeros((3, 4, 3))]), "all passes must have"),
], ids=["one-pass", "no-pass", "same-seed", "sizes"])
def test_bad_passes_are_refused(tmp_path, make, match):
    with pytest.raises(mv.InvalidArgument, match=match):
        pass_stats(make(str(tmp_path)))


def _scene():
    return os.path.join(reference.REFERENCE_ROOT, "cornell-box", "scene.xml")


def _mitsuba_passes(seed0, k=16, scale=1.0):
    return mvm.render_passes(_scene(), spp=64, seeds=range(seed0, seed0 + k),
                             params={"res": "16"}) * scale


def test_compare_two_renderers_pass_folders_end_to_end(tmp_path):
    """Mitsuba against itself as "any renderer" (16 passes each, RGBA on the test side):
    the same scene passes, 5 % brighter fails."""
    ref = _write(tmp_path / "ref", _mitsuba_passes(0))
    test = _mitsuba_passes(1000)
    alpha = np.ones(test.shape[:3] + (1,))
    same = _write(tmp_path / "same", np.concatenate([test, alpha], axis=3))
    bright = _write(tmp_path / "bright", _mitsuba_passes(2000, scale=1.05))
    r = subprocess.run(CMD + ["compare", "--test-passes", same, "--ref-passes", ref],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "notice: alpha channels ignored" in r.stderr
    r = subprocess.run(CMD + ["compare", "--test-passes", bright, "--ref-passes", ref],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 1, r.stdout + r.stderr
    # the same pass images on both sides would always agree: refused, naming a file
    r = subprocess.run(CMD + ["compare", "--test-passes", same, "--ref-passes", same],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "is on both sides of the comparison" in r.stderr, r.stderr


def test_compare_notes_the_sample_counts_by_its_options_and_a_variance_of_the_mean(tmp_path):
    """An image whose --test-var is the variance of its mean, not of the --test-n passes
    averaged into it (a renderer's "variance of the estimate", n times too small), with
    the right counts: the note said "check test_spp=64 and ref_spp=64", names of
    ``compare_images``' parameters the user never gave, and counts that were right. It
    names the options and says what else to check."""
    ref = _write(tmp_path / "ref", _mitsuba_passes(0))
    passes = _mitsuba_passes(1000).astype(np.float64)
    mean, var = str(tmp_path / "mean.exr"), str(tmp_path / "var.exr")
    mvm.write_exr(mean, passes.mean(0).astype(np.float32))
    mvm.write_exr(var, (passes.var(0, ddof=1) / 16).astype(np.float32))
    r = subprocess.run(CMD + ["compare", mean, "--ref-passes", ref, "--test-var", var,
                              "--test-n", "16", "--test-spp", "64", "--ref-spp", "64"],
                       capture_output=True, text=True, timeout=300)
    note = [line for line in r.stdout.splitlines() if "note: per sample" in line]
    assert r.returncode in (0, 1) and len(note) == 1, r.stdout + r.stderr
    assert "test_spp=" not in note[0] and "check --test-spp 64 and --ref-spp 64" in note[0]
    assert f"that --test-var ({var}) is the variance of the 16 values averaged into " \
           "each pixel, not of their mean" in note[0], note[0]


def test_compare_with_few_passes_and_no_spp_says_so(tmp_path):
    """A reference of 2 passes compared without --test-spp: the variance floor is off,
    and passes that all missed a rare path read as confident evidence; ``compare`` says
    so (a notice; the verdict is the test's). With --test-spp and --ref-spp it does
    not."""
    ref = _write(tmp_path / "ref", _mitsuba_passes(0, k=2))
    test = _write(tmp_path / "test", _mitsuba_passes(1000, k=4))
    r = subprocess.run(CMD + ["compare", "--test-passes", test, "--ref-passes", ref],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode in (0, 1) and "notice: 2 passes on one side and no --test-spp" \
        in r.stderr, r.stdout + r.stderr
    r = subprocess.run(CMD + ["compare", "--test-passes", test, "--ref-passes", ref,
                              "--test-spp", "64", "--ref-spp", "64"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode in (0, 1) and "no --test-spp" not in r.stderr, r.stderr


@pytest.mark.parametrize("args, needle", [
    (["compare", "--test-passes", "p_*.exr"], "expected 1: REF"),
    (["compare", "a.exr", "b.exr", "--test-passes", "p_*.exr"], "expected 1: REF"),
    # the shell expanded an unquoted glob: the option got the first pass, the rest came
    # as image arguments (until 7 December not said, an outside review)
    (["compare", "--test-passes", "p_00.exr", "p_01.exr", "p_02.exr", "cornell-box"],
     "the shell seems to have expanded the glob of --test-passes (it got p_00.exr, the "
     "other files came as image arguments): quote it"),
    (["compare", "--ref-passes", "r_0.exr", "r_1.exr", "t.exr", "--test-var", "v.exr",
      "--test-n", "4"], "expanded the glob of --ref-passes (it got r_0.exr"),
    (["compare", "cornell-box", "--test-passes", "p_00.exr", "p_01.exr", "p_02.exr"],
     "unrecognized arguments: p_01.exr p_02.exr; the shell seems to have expanded the glob "
     "of --test-passes (it got p_00.exr"),
    # both unquoted: both named (until 7 December only --test-passes, while the files
    # listed as unrecognized were the reference side's; an outside review)
    (["compare", "--test-passes", "p_0.exr", "p_1.exr", "--ref-passes", "r_0.exr",
      "r_1.exr"], "unrecognized arguments: r_1.exr; the shell seems to have expanded the "
     "globs of --test-passes and --ref-passes (they got p_0.exr and r_0.exr, the other "
     "files came as image arguments): quote them"),
    (["compare", "cornell-box", "--test-passes", "p_00.exr", "--bogus"],
     "unrecognized arguments: --bogus (see"),
    (["compare", "r", "--test-passes", "p_*.exr", "--test-n", "4"],
     "--test-n: not with --test-passes"),
    (["compare", "a.exr", "r"], "a.exr: an image needs --test-var and --test-n"),
    (["compare", "r", "--test-passes", "none_*.exr"], "matches 0 file"),
    (["compare", "cornell-box", "--test-passes", "p_*.exr", "--test-spp", "0"],
     "--test-spp 0: samples per pixel"),
    (["compare", "cornell-box", "--test-passes", "p_*.exr", "--ref-spp", "64"],
     "--ref-spp 64: give --test-spp too"),
], ids=["no-ref", "two-positionals", "unquoted-test-glob", "unquoted-ref-glob",
        "unquoted-glob-after-ref", "unquoted-globs-both-sides", "unknown-option-no-glob-hint",
        "n-with-passes", "no-var", "empty-glob", "spp-0",
        "ref-spp-alone"])
def test_compare_bad_input_exit_2(tmp_path, args, needle):
    (tmp_path / "a.exr").write_bytes(b"")    # there: a missing image is said so first
    r = subprocess.run(CMD + args, capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert r.returncode == 2 and needle in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_compare_against_a_splatting_reference_uses_the_pass_images(tmp_path):
    """The ``filters`` reference (Mitsuba's default gaussian) says its pixels correlate:
    Mitsuba's own passes compare on pass images and pass; one image with a variance is
    refused (its block and image tests would assume independent pixels), and so is
    --correlated without the reference side's passes."""
    _, path = reference.resolve_scene("filters")
    imgs = mvm.render_passes(path, spp=64, seeds=range(500, 508))   # the reference's spp
    passes = _write(tmp_path / "mine", imgs)
    out = tmp_path / "r.json"
    r = subprocess.run(CMD + ["compare", "--test-passes", passes, "filters", "--json",
                              str(out)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    import json

    assert json.loads(out.read_text())["details"]["pixels_correlated"] is True
    mvm.write_exr(str(tmp_path / "m.exr"), imgs.mean(0))
    mvm.write_exr(str(tmp_path / "v.exr"), imgs.var(0, ddof=1))
    r = subprocess.run(CMD + ["compare", str(tmp_path / "m.exr"), "filters", "--test-var",
                              str(tmp_path / "v.exr"), "--test-n", "8"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "pixels of a pass correlate" in r.stderr, r.stderr
    r = subprocess.run(CMD + ["compare", "--test-passes", passes, str(tmp_path / "m.exr"),
                              "--ref-var", str(tmp_path / "v.exr"), "--ref-n", "8",
                              "--correlated"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "--ref-passes" in r.stderr, r.stderr


def test_compare_floors_the_test_variance_at_the_references(tmp_path):
    """``--test-spp``: the test side's variance is at least the committed reference's
    scaled to the test's samples per pass (its manifest knows its own 256); the JSON
    says how much was raised. Passes of unknown spp against images: --ref-spp needed."""
    import json

    imgs = mvm.render_passes(_scene(), spp=64, seeds=range(3000, 3008))
    passes = _write(tmp_path / "mine", imgs)
    out = tmp_path / "r.json"
    r = subprocess.run(CMD + ["compare", "--test-passes", passes, "cornell-box", "--test-spp",
                              "64", "--json", str(out)], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    floor = json.loads(out.read_text())["details"]["variance_floor"]
    assert floor["test_spp"] == 64 and floor["ref_spp"] == 256
    assert 0.0 < floor["raised_fraction"] < 1.0
    theirs = _write(tmp_path / "theirs", imgs)      # the same images apart: not itself
    r = subprocess.run(CMD + ["compare", "--test-passes", passes, "--ref-passes", theirs,
                              "--test-spp", "64"], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 2 and "give --ref-spp" in r.stderr, r.stderr


def test_half_mean_and_variance_images_of_a_correct_render_agree(tmp_path):
    """``compare TEST.exr REF.exr --test-var VAR.exr`` with half images (a renderer's
    default output) of a correct render exited 1, p = 0: a zero-variance pixel of value
    0.7 is 0.69971 in half (see test_images' test_half_images_round_within_half_s_
    precision). The half files now reach compare_images as half."""
    mi = mvm._mi()
    rng = np.random.default_rng(3)
    a, b = rng.gamma(2.0, 0.5, (2, 16, 16, 3, 32))
    a[:4, :4] = b[:4, :4] = 0.7
    paths = {}
    for name, img, half in (("m", a.mean(-1), True), ("v", a.var(-1, ddof=1), True),
                            ("rm", b.mean(-1), False), ("rv", b.var(-1, ddof=1), False)):
        paths[name] = str(tmp_path / f"{name}.exr")
        mi.Bitmap(img.astype(np.float16 if half else np.float32)).write(paths[name])
    assert set(reference.exr_channel_types(paths["m"]).values()) == {"half"}
    r = subprocess.run(CMD + ["compare", paths["m"], paths["rm"], "--test-var", paths["v"],
                              "--test-n", "32", "--ref-var", paths["rv"], "--ref-n", "32"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr


def test_half_pass_images_of_a_correct_render_agree(tmp_path):
    """``compare --test-passes 'T_*.exr' --ref-passes 'R_*.exr'`` with half passes (a
    renderer's default output) of a correct render exited 1, p = 0: the passes' mean and
    variance are computed in float64, so compare_images saw no half input, and a
    zero-variance pixel of value 0.7 (0.69971 in half) was a certain difference (an
    outside review). The passes' storage type now reaches it (``precision``); a 5 % bias
    of the same half passes still fails."""
    mi = mvm._mi()
    rng = np.random.default_rng(4)
    a, b = rng.gamma(2.0, 0.5, (2, 16, 16, 16, 3))
    a[:, :4, :4] = b[:, :4, :4] = 0.7                   # an emitter seen directly

    def write(stem, imgs, dtype):
        for i, img in enumerate(imgs):
            mi.Bitmap(img.astype(dtype)).write(str(tmp_path / f"{stem}_{i:02d}.exr"))
        return str(tmp_path / f"{stem}_*.exr")

    ref = write("r", b, np.float32)
    for stem, scale, code in (("t", 1.0, 0), ("bright", 1.05, 1)):
        test = write(stem, a * scale, np.float16)
        assert pass_stats(test).precision == np.float16
        r = subprocess.run(CMD + ["compare", "--test-passes", test, "--ref-passes", ref],
                           capture_output=True, text=True, timeout=300)
        assert r.returncode == code, r.stdout + r.stderr
    assert pass_stats(ref).precision is None


def test_passes_some_of_them_half_of_a_correct_render_agree(tmp_path):
    """Passes of which only some are half (a renderer's output format changed part-way,
    or passes gathered from two machines) were compared at float precision: the sky at
    0.18 is 0.17993 in half, so 4 half passes among 12 moved a zero-variance pixel's mean
    by 1e-4 of its value, and a correct render failed with p = 4e-42 (an outside review).
    Half rounding of any pass is now no evidence."""
    mi = mvm._mi()
    rng = np.random.default_rng(5)
    a, b = rng.gamma(2.0, 0.5, (2, 12, 16, 16, 3))
    a[:, :4, :4] = b[:, :4, :4] = 0.18                  # a constant sky seen directly
    for i, img in enumerate(a):
        mi.Bitmap(img.astype(np.float16 if i >= 8 else np.float32)).write(
            str(tmp_path / f"t_{i:02d}.exr"))
        mi.Bitmap(b[i].astype(np.float32)).write(str(tmp_path / f"r_{i:02d}.exr"))
    assert pass_stats(str(tmp_path / "t_*.exr")).precision == np.float16
    r = subprocess.run(CMD + ["compare", "--test-passes", str(tmp_path / "t_*.exr"),
                              "--ref-passes", str(tmp_path / "r_*.exr")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr


def test_compare_refuses_correlated_passes_of_other_spp_than_the_references(tmp_path):
    """Where pixels correlate (a splatting filter) the passes compare only at the
    reference's samples per pass (render-check refuses another split); ``compare
    --test-spp 16`` against the ``filters`` reference (64 a pass) was compared without a
    word. It exits 2 naming the count to use; at the reference's own count it goes on."""
    rng = np.random.default_rng(6)
    passes = _write(tmp_path / "p", rng.gamma(2.0, 0.5, (4, 64, 64, 3)))
    r = subprocess.run(CMD + ["compare", "--test-passes", passes, "filters", "--test-spp",
                              "16"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "--test-spp 16" in r.stderr and \
        "64 samples per pass" in r.stderr and "Traceback" not in r.stderr, r.stderr
    r = subprocess.run(CMD + ["compare", "--test-passes", passes, "filters", "--test-spp",
                              "64"], capture_output=True, text=True, timeout=300)
    assert r.returncode in (0, 1) and "samples per pass" not in r.stderr, r.stderr
    theirs = _write(tmp_path / "r", rng.gamma(2.0, 0.5, (4, 64, 64, 3)))
    r = subprocess.run(CMD + ["compare", "--test-passes", passes, "--ref-passes", theirs,
                              "--correlated", "--test-spp", "16", "--ref-spp", "64"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "64 samples per pass" in r.stderr, r.stderr


def _exr_header_only(path, channels):
    """An OpenEXR file holding a header alone: ``channels`` {name: 1 (half) or 2 (float)}.
    Enough for the header readers (exr_channel_types, colour_types), not for pixels."""
    import struct

    chlist = b"".join(name.encode() + b"\0" + struct.pack("<iB3xii", kind, 0, 1, 1)
                      for name, kind in channels.items()) + b"\0"
    path.write_bytes(b"\x76\x2f\x31\x01" + struct.pack("<i", 2) + b"channels\0chlist\0"
                     + struct.pack("<i", len(chlist)) + chlist + b"\0")
    return str(path)


def test_a_half_alpha_beside_float_colours_is_no_half_image(tmp_path):
    """A pass of float colours and a half alpha (a common film setting) made the whole
    comparison take half's rounding, 2^-10 instead of 2^-16, as if the colours were half
    (a review of the change): the alpha, which ``read_radiance`` drops, no longer
    counts; half colours still do, whatever the alpha's type."""
    from mcverify.gate.passes import colour_types

    mixed = _exr_header_only(tmp_path / "a.exr", {"A": 1, "B": 2, "G": 2, "R": 2})
    assert "half" in reference.exr_channel_types(mixed).values()
    assert colour_types(mixed) == ["float"] * 3
    half = _exr_header_only(tmp_path / "b.exr", {"A": 2, "B": 1, "G": 1, "R": 1})
    assert colour_types(half) == ["half"] * 3
    layered = _exr_header_only(tmp_path / "c.exr", {"rgb.A": 1, "rgb.R": 2})
    assert colour_types(layered) == ["float"]


def test_compare_refuses_an_image_given_as_its_own_variance(tmp_path):
    """``compare M.exr REF --test-var M.exr`` (the image named twice) or a variance file
    holding the image's own pixels (a mean written twice) was compared as if it were the
    variance, and passed; now each exits 2 naming the file. A black image's variance is
    its pixels, 0, and is taken."""
    rng = np.random.default_rng(4)
    m, v = rng.gamma(2.0, 0.5, (2, 8, 8, 3))
    for name, img in (("m", m), ("m_again", m), ("rm", m * 1.01), ("rv", v),
                      ("black", np.zeros_like(m)), ("black_var", np.zeros_like(m))):
        mvm.write_exr(str(tmp_path / f"{name}.exr"), img)
    ref = ["rm.exr", "--ref-var", "rv.exr", "--ref-n", "16"]
    for var, needle in (("m.exr", "m.exr (--test-var): is the image itself (m.exr)"),
                        ("m_again.exr", "m_again.exr (--test-var): holds the pixels of m.exr")):
        r = subprocess.run(CMD + ["compare", "m.exr", *ref, "--test-var", var, "--test-n",
                                  "16"], capture_output=True, text=True, cwd=tmp_path,
                           timeout=120)
        assert r.returncode == 2 and needle in r.stderr, r.stdout + r.stderr
    r = subprocess.run(CMD + ["compare", "rm.exr", "m.exr", "--test-var", "rv.exr",
                              "--test-n", "16", "--ref-var", "m.exr", "--ref-n", "16"],
                       capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert r.returncode == 2 and "m.exr (--ref-var): is the image itself" in r.stderr, \
        r.stdout + r.stderr
    r = subprocess.run(CMD + ["compare", "black.exr", "rm.exr", "--test-var", "black_var.exr",
                              "--test-n", "16", "--ref-var", "rv.exr", "--ref-n", "16"],
                       capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert r.returncode == 1 and "FAIL" in r.stdout, r.stdout + r.stderr


def test_compare_refuses_a_lossy_compressed_image(tmp_path):
    """A correct render's mean written with DWAB (Mitsuba's ``Bitmap.write(quality=45)``,
    OpenEXR's recommended lossy level) failed against its reference with p = 0, the
    compression's error taken for the renderer's: here "10 blocks and 37.11% of pixels
    rejected", black pixels (no variance) stored as ~1e-5 (an outside review). Now it
    exits 2 naming the file and its compression, as does a lossy pass, before any work.
    The same mean written losslessly (PIZ, Mitsuba's default) passes."""
    rng = np.random.default_rng(11)
    truth = 0.2 + np.linspace(0, 1, 16 * 16 * 3).reshape(16, 16, 3)
    truth[:, :6] = 0                                  # a black background
    mine, theirs = (truth * rng.gamma(4.0, 0.25, (16, 16, 16, 3)) for _ in range(2))
    mi = mvm._mi()
    for name, img in (("m", mine.mean(0)), ("v", mine.var(0, ddof=1)),
                      ("rm", theirs.mean(0)), ("rv", theirs.var(0, ddof=1))):
        mi.Bitmap(img.astype(np.float32)).write(str(tmp_path / f"{name}.exr"))
    mi.Bitmap(mine.mean(0).astype(np.float32)).write(str(tmp_path / "dwab.exr"), quality=45)
    ref = ["rm.exr", "--ref-var", "rv.exr", "--ref-n", "16", "--test-var", "v.exr",
           "--test-n", "16"]
    for image, code in (("m.exr", 0), ("dwab.exr", 2)):
        r = subprocess.run(CMD + ["compare", image, *ref], capture_output=True, text=True,
                           cwd=tmp_path, timeout=120)
        assert r.returncode == code, r.stdout + r.stderr
    assert "dwab.exr: DWAB compression is lossy for its channels B, G, R" in r.stderr, r.stderr
    assert r.stdout == "", r.stdout
    _write(tmp_path / "p", mine[:2])
    os.replace(tmp_path / "dwab.exr", tmp_path / "p" / "pass_01.exr")
    r = subprocess.run(CMD + ["compare", "--test-passes", "p/pass_*.exr", "rm.exr",
                              "--ref-var", "rv.exr", "--ref-n", "16"],
                       capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert r.returncode == 2 and "pass_01.exr: DWAB compression" in r.stderr, r.stderr


@pytest.mark.parametrize("compression,channels,lossy", [
    (5, {"B": 2, "G": 2, "R": 2}, "PXR24 compression is lossy for its channels B, G, R"),
    (5, {"A": 2, "B": 1, "G": 1, "R": 1}, None),      # PXR24 keeps half; alpha ignored
    (6, {"A": 2, "Y": 1}, "B44 compression is lossy for its channels Y"),
    (7, {"B": 2, "G": 2, "R": 2}, None),              # B44(A) stores float as it is
    (8, {"beauty.R": 2, "depth.Z": 2}, "DWAA compression is lossy for its channels beauty.R"),
    (9, {"A": 1, "Z": 2}, None),                      # DWA keeps what is not colour
    (4, {"B": 2, "G": 2, "R": 2}, None)], ids=["pxr24-float", "pxr24-half", "b44-half",
                                               "b44a-float", "dwaa-layer", "dwab-alpha",
                                               "piz"])
def test_lossy_compression_is_refused_by_the_header(tmp_path, compression, channels, lossy):
    import struct

    path = tmp_path / "a.exr"
    _exr_header_only(path, channels)
    data = path.read_bytes()
    path.write_bytes(data[:-1] + b"compression\0compression\0" + struct.pack("<i", 1)
                     + bytes([compression]) + b"\0")
    if lossy is None:
        assert set(reference.exr_channel_types(str(path))) == set(channels)
        return
    with pytest.raises(mv.InvalidArgument, match=lossy) as info:
        reference.exr_channel_types(str(path))
    assert str(path) in str(info.value) and "lossless compression" in str(info.value)


def _exr_channels(path, planes, display=None):
    """An uncompressed scanline OpenEXR file of float channels ``planes`` {name: (H, W)},
    as any renderer's image library writes one (channels sorted by name); ``display``
    (x0, y0, x1, y1) its display window where not the data window (0, 0, W-1, H-1)."""
    import struct

    names = sorted(planes)
    h, w = planes[names[0]].shape

    def attr(name, kind, value):
        return name.encode() + b"\0" + kind + b"\0" + struct.pack("<i", len(value)) + value

    chlist = b"".join(n.encode() + b"\0" + struct.pack("<iB3xii", 2, 0, 1, 1)
                      for n in names) + b"\0"
    box = struct.pack("<4i", 0, 0, w - 1, h - 1)
    header = (b"\x76\x2f\x31\x01" + struct.pack("<i", 2) + attr("channels", b"chlist", chlist)
              + attr("compression", b"compression", b"\0")
              + attr("dataWindow", b"box2i", box)
              + attr("displayWindow", b"box2i", struct.pack("<4i", *display) if display else box)
              + attr("lineOrder", b"lineOrder", b"\0")
              + attr("pixelAspectRatio", b"float", struct.pack("<f", 1))
              + attr("screenWindowCenter", b"v2f", struct.pack("<2f", 0, 0))
              + attr("screenWindowWidth", b"float", struct.pack("<f", 1)) + b"\0")
    lines = [b"".join(planes[n][y].astype("<f4").tobytes() for n in names) for y in range(h)]
    start = len(header) + 8 * h
    offsets = [start + y * (8 + len(lines[0])) for y in range(h)]
    path.write_bytes(header + struct.pack(f"<{h}Q", *offsets) + b"".join(
        struct.pack("<ii", y, len(line)) + line for y, line in enumerate(lines)))
    return str(path)


@pytest.mark.parametrize("channels", ["R G B Z", "beauty.R beauty.G beauty.B diffuse.R "
                                      "diffuse.G diffuse.B", "X Y Z", "R G B Y",
                                      "R G B A diffuse.A"],
                         ids=["depth", "two-layers", "xyz", "rgb-and-y", "two-alphas"])
def test_channels_beside_the_colour_are_refused_naming_the_image(tmp_path, channels):
    """An image with a depth channel or a second layer beside its colour (what a
    renderer's AOV output writes) was refused as "my_var.exr (--test-var): shape
    (64, 64, 3) differs from rgbz.exr's (64, 64, 4); give the variance image of it",
    blaming the right variance image, and X, Y, Z was compared as R, G, B (an outside
    review); now the image exits 2 naming itself and its channels, as a pass does.
    One layer's colour, with an alpha or not, is read."""
    rng = np.random.default_rng(12)
    plane = lambda: rng.gamma(2.0, 0.5, (8, 8))  # noqa: E731
    names = channels.split()
    _exr_channels(tmp_path / "bad.exr", {n: plane() for n in names})
    for name, img in (("v", rng.gamma(2.0, 0.5, (8, 8, 3)) / 16),
                      ("rm", rng.gamma(2.0, 0.5, (8, 8, 3))),
                      ("rv", rng.gamma(2.0, 0.5, (8, 8, 3)) / 16)):
        mvm.write_exr(str(tmp_path / f"{name}.exr"), img)
    r = subprocess.run(CMD + ["compare", "bad.exr", "rm.exr", "--test-var", "v.exr",
                              "--test-n", "16", "--ref-var", "rv.exr", "--ref-n", "16"],
                       capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert r.returncode == 2, r.stdout + r.stderr
    assert f"bad.exr: channels {', '.join(sorted(names))}: give one layer's colour" \
        in r.stderr and "v.exr" not in r.stderr, r.stderr
    _write(tmp_path / "p", rng.gamma(2.0, 0.5, (2, 8, 8, 3)))
    os.replace(tmp_path / "bad.exr", tmp_path / "p" / "pass_01.exr")
    with pytest.raises(mv.InvalidArgument, match="pass_01.exr: channels"):
        pass_stats(str(tmp_path / "p" / "pass_*.exr"))


def test_one_layer_of_colour_is_read_with_its_alpha_left_out(tmp_path):
    rng = np.random.default_rng(13)
    rgb = rng.gamma(2.0, 0.5, (3, 8, 8))
    # "r g b a": an alpha in lower case, as the colours may be (refused until a read-only
    # review: "a" counted as a colour channel)
    for names in ("R G B", "beauty.R beauty.G beauty.B beauty.A", "Y A", "r g b", "r g b a"):
        planes = dict(zip(names.split(), list(rgb) + [np.ones((8, 8))]))
        img, note = read_radiance(_exr_channels(tmp_path / "a.exr", planes))
        colour = [p for n, p in planes.items() if n[-1] not in "Aa"]
        np.testing.assert_array_equal(img, np.stack(colour, -1).astype(np.float32))
        assert (note is None) == (names[-1] not in "Aa"), names


@pytest.mark.parametrize("display", [(0, 0, 9, 9), (-1, -1, 6, 6), (1, 0, 8, 7)],
                         ids=["cropped", "overscan", "shifted"])
def test_an_image_storing_part_of_its_window_is_refused_naming_it(tmp_path, display):
    """A 10 × 10 image whose file stores its 8 × 8 pixels that are not black (an
    autocrop) was read as an 8 × 8 image, and refused as "shape (8, 8, 3) differs from
    the reference's (10, 10, 3)" (an outside review); one whose pixels sit elsewhere in
    its display window was compared shifted. Now each exits 2 naming the file and both
    windows; an image whose data window is its display window is read."""
    rng = np.random.default_rng(14)
    planes = {c: rng.gamma(2.0, 0.5, (8, 8)) for c in "RGB"}
    bad = _exr_channels(tmp_path / "crop.exr", planes, display=display)
    with pytest.raises(mv.InvalidArgument, match=r"crop.exr: its data window \[0, 0, 7, 7\] "
                       r"is not its display window \[" + ", ".join(map(str, display))):
        read_radiance(bad)
    _write(tmp_path / "p", rng.gamma(2.0, 0.5, (4, 10, 10, 3)))
    mvm.write_exr(str(tmp_path / "v.exr"), np.full((8, 8, 3), 0.1))
    r = subprocess.run(CMD + ["compare", "--test-passes", "p/pass_*.exr", "crop.exr",
                              "--ref-var", "v.exr", "--ref-n", "4"], capture_output=True,
                       text=True, cwd=tmp_path, timeout=120)
    assert r.returncode == 2 and "crop.exr: its data window" in r.stderr, r.stderr
    whole = _exr_channels(tmp_path / "whole.exr", planes, display=(0, 0, 7, 7))
    assert read_radiance(whole)[0].shape == (8, 8, 3)


def test_luminance_passes_against_an_rgb_reference_are_refused_naming_pixel_format(tmp_path):
    """Passes of a film with pixel_format luminance (one channel) against an RGB reference
    were refused as a bare "shape (8, 8, 1) differs from the reference's (8, 8, 3)" (an
    outside review); the refusal now says what differs and what to render. Other shape
    mismatches keep the bare message."""
    rng = np.random.default_rng(21)
    _write(tmp_path / "p", rng.gamma(2.0, 0.5, (4, 8, 8, 1)))
    _write(tmp_path / "q", rng.gamma(2.0, 0.5, (4, 6, 8, 3)))
    for name, img in (("rm", rng.gamma(2.0, 0.5, (8, 8, 3))), ("rv", np.full((8, 8, 3), 0.1))):
        mvm.write_exr(str(tmp_path / f"{name}.exr"), img)
    ref = ["rm.exr", "--ref-var", "rv.exr", "--ref-n", "16"]
    r = subprocess.run(CMD + ["compare", "--test-passes", "p/pass_*.exr", *ref],
                       capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert r.returncode == 2 and "one channel against three" in r.stderr and \
        "pixel_format" in r.stderr, r.stdout + r.stderr
    r = subprocess.run(CMD + ["compare", "--test-passes", "q/pass_*.exr", *ref],
                       capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert r.returncode == 2 and "differs from the reference's (8, 8, 3)" in r.stderr and \
        "channel" not in r.stderr, r.stdout + r.stderr
    # another resolution of the same aspect is named, as compare_images names it (until
    # 7 December the CLI's refusal did not say)
    _write(tmp_path / "d", rng.gamma(2.0, 0.5, (4, 16, 16, 3)))
    r = subprocess.run(CMD + ["compare", "--test-passes", "d/pass_*.exr", *ref],
                       capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert r.returncode == 2 and "2 times the reference's resolution" in r.stderr, \
        r.stdout + r.stderr


def test_compare_json_names_what_was_compared(tmp_path):
    """`compare --json`'s file named the test side alone ("compare:out/pass_*.exr"), and
    its provenance only the command: a CI artifact of a failed compare did not say which
    reference (or which version of it) the render was held to, nor the counts (an
    outside review). It now records both sides' files and n, and a reference's manifest."""
    import json

    from mcverify.gate import cli

    rng = np.random.default_rng(5)
    passes = _write(tmp_path / "mine", rng.random((4, 64, 64, 3)).astype(np.float32))
    out = tmp_path / "r.json"
    assert cli.main(["compare", "--test-passes", passes, "white-furnace", "--json",
                     str(out)]) in (0, 1)
    p = json.loads(out.read_text())["provenance"]
    _, scene = reference.resolve_scene("white-furnace")
    assert p["reference"] == os.path.abspath(scene) and p["ref_n"] == 16
    assert p["reference_manifest"] == reference.load_reference("white-furnace").manifest
    assert p["test"] == passes and p["test_n"] == 4 and len(p["test_files"]) == 4
    m, v = str(tmp_path / "m.exr"), str(tmp_path / "v.exr")
    mvm.write_exr(m, rng.random((8, 8, 3)).astype(np.float32))
    mvm.write_exr(v, rng.random((8, 8, 3)).astype(np.float32))
    ref = str(tmp_path / "ref.exr")
    mvm.write_exr(ref, rng.random((8, 8, 3)).astype(np.float32))
    assert cli.main(["compare", m, ref, "--test-var", v, "--test-n", "5", "--ref-var", v,
                     "--ref-n", "7", "--json", str(out)]) in (0, 1)
    p = json.loads(out.read_text())["provenance"]
    assert p["reference"] == ref and p["reference_files"] == [ref, v]
    assert (p["test_n"], p["ref_n"], p["reference_manifest"]) == (5, 7, None)
