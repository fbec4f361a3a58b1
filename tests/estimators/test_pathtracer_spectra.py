"""``<spectrum>`` values (refused by line until 7 December, though Mitsuba's own Cornell
box and documentation scenes give their colours so): read into RGB as Mitsuba's RGB
variants read them, compared with the values Mitsuba 3.9.1 loads (random spectra in
every role, every emitter type, a spectrum file); what Mitsuba refuses is refused by
line; and the vocabulary-spectra reference scene's render gate sees a wrong reading."""

import os
import shutil

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimators.pathtracer import SceneError, load_scene, parse_scene
from estimators.pathtracer import scene as scene_module
from estimators.pathtracer import spectra
from estimators.pathtracer.spectra import spectrum_list_rgb, uniform_emission_rgb

ROOT = os.path.join(os.path.dirname(__file__), "..", "..")
SPECTRA_SCENE = os.path.join(ROOT, "reference", "scenes", "vocabulary-spectra")
SENSOR = '<sensor type="perspective"><float name="fov" value="45"/></sensor>'


def _mitsuba_values(mi, text):
    """Mitsuba's loaded colour and number parameters of a scene: the last key component
    before ``.value`` (``radiance``, ``eta``, ``color0``, ...) -> its value(s)."""
    params = mi.traverse(mi.load_string(text))
    return {k.split(".")[-2]: np.ravel(np.array(params[k], dtype=float))
            for k in params.keys() if k.endswith(".value")}


@st.composite
def _spectra(draw):
    """Wavelength:value pairs as users write them: 2 to 12 wavelengths, increasing, from
    300 to 900 nm (some outside the 360–830 nm the CIE tables cover), values to 6
    digits."""
    n = draw(st.integers(2, 12))
    wavelengths = sorted(draw(st.sets(st.integers(300, 900), min_size=n, max_size=n)))
    values = [float(f"{draw(st.floats(0.0, 5.0)):.6g}") for _ in wavelengths]
    return np.array(wavelengths, float), np.array(values)


def _text(spectrum):
    return ", ".join(f"{w:g}:{v:.6g}" for w, v in zip(*spectrum))


@pytest.mark.mitsuba
@settings(max_examples=40, deadline=None, derandomize=True, database=None)
@given(spectrum=_spectra())
def test_pairs_read_as_mitsubas_rgb_variants_read_them_in_every_role(mi, spectrum):
    """An emitter's radiance (not weighted by D65, clipped at 0), a conductor's eta and
    k (weighted, clipped at 0) and a diffuse reflectance (weighted, clipped to [0, 1]):
    within 1e-5 of Mitsuba's largest channel (its tables are float32, and its D65 the
    tabulated one)."""
    pairs = _text(spectrum)
    ours = {"radiance": spectrum_list_rgb(*spectrum, emitter=True, unbounded=False),
            "eta": spectrum_list_rgb(*spectrum, emitter=False, unbounded=True),
            "reflectance": spectrum_list_rgb(*spectrum, emitter=False, unbounded=False)}
    theirs = _mitsuba_values(mi, (
        f'<scene version="3.0.0"><shape type="sphere"><bsdf type="roughconductor">'
        f'<spectrum name="eta" value="{pairs}"/></bsdf><emitter type="area">'
        f'<spectrum name="radiance" value="{pairs}"/></emitter></shape>'
        f'<shape type="sphere"><bsdf type="diffuse"><spectrum name="reflectance" '
        f'value="{pairs}"/></bsdf></shape></scene>'))
    for name, rgb in ours.items():
        # to 1e-5 of the colour's largest channel: a small channel is a difference of
        # large XYZ terms, as exact as the largest
        scale = 1e-5 * np.abs(theirs[name]).max() + 1e-6
        assert np.all(np.abs(rgb - theirs[name]) <= scale), (name, rgb, theirs[name])
    assert np.all(ours["reflectance"] <= 1.0)


_EVERY_ROLE = f"""<scene version="3.0.0">{SENSOR}
<shape type="sphere"><bsdf type="roughconductor"><spectrum name="eta" value="{{L}}"/>
  <spectrum name="k" value="3"/><spectrum name="specular_reflectance" value="{{L}}"/></bsdf>
  <emitter type="area"><spectrum name="radiance" value="{{L}}"/></emitter></shape>
<shape type="rectangle"><bsdf type="plastic"><texture type="checkerboard"
  name="diffuse_reflectance"><spectrum name="color0" filename="paint.spd"/>
  <spectrum name="color1" value="0.25"/></texture>
  <spectrum name="specular_reflectance" value="0.5"/></bsdf></shape>
<emitter type="point"><spectrum name="intensity" value="2"/></emitter>
<emitter type="spot"><spectrum name="intensity" value="{{L}}"/></emitter>
<emitter type="directional"><spectrum name="irradiance" value="0.75"/></emitter>
<emitter type="constant"><spectrum name="radiance" value="{{L}}"/></emitter>
</scene>"""


def _our_values(desc):
    """Our loaded colour and number properties, by name, as ``_mitsuba_values``."""
    out = {}

    def walk(p):
        for name, value in p.props.items():
            if hasattr(value, "props"):
                walk(value)
            elif name not in ("to_world", "to_uv"):
                out.setdefault(name, []).append(np.ravel(np.array(value, dtype=float)))
        for child in p.children:
            walk(child)
    for p in (*desc.shapes, *desc.emitters):
        walk(p)
    return out


@pytest.mark.mitsuba
def test_a_scene_of_spectra_in_every_role_loads_mitsubas_values(mi, tmp_path):
    """Each emitter type (pairs and uniform: an equal-energy spectrum, pinkish in sRGB),
    indices, reflectances (pairs, a uniform number) and a spectrum file, in one scene:
    our loader's values are Mitsuba's."""
    (tmp_path / "paint.spd").write_text("# wavelength value\n400 0.1\n\n550 0.8\n700 0.3\n")
    text = _EVERY_ROLE.replace("{L}", "400:0.1, 450:0.7, 500:2.5, 620:0.3, 700:1.1")
    (tmp_path / "s.xml").write_text(text)
    ours = _our_values(load_scene(str(tmp_path / "s.xml")))
    params = mi.traverse(mi.load_file(str(tmp_path / "s.xml")))
    theirs = {}
    for k in params.keys():
        if k.endswith(".value"):
            theirs.setdefault(k.split(".")[-2], []).append(
                np.ravel(np.array(params[k], dtype=float)))
    for name in ("eta", "k", "specular_reflectance", "radiance", "color0", "color1",
                 "intensity", "irradiance"):
        mine = sorted(ours[name], key=lambda v: tuple(np.broadcast_to(v, 3)))
        other = sorted(theirs[name], key=lambda v: tuple(np.broadcast_to(v, 3)))
        assert len(mine) == len(other), name
        for a, b in zip(mine, other):
            assert np.allclose(np.broadcast_to(a, 3), np.broadcast_to(b, 3), rtol=1e-5,
                               atol=1e-6), (name, a, b)
    # the uniform emissions are not grey: an equal-energy spectrum in sRGB
    assert np.allclose(uniform_emission_rgb(1.0), [1.204794, 0.948292, 0.908916], atol=1e-6)


@pytest.mark.parametrize("element,needle,mitsuba_refuses", [
    ('<spectrum name="reflectance" value="0.5" filename="a.spd"/>',
     "takes value=\"...\" or filename=\"...\", one of the two", True),
    ('<spectrum name="reflectance"/>',
     "takes value=\"...\" or filename=\"...\", one of the two", True),
    ('<spectrum name="reflectance" value="500:0.5"/>',
     "1 wavelength:value pair(s); a spectrum needs at least two", True),
    ('<spectrum name="reflectance" value="500:0.5, 400:0.2"/>',
     "the wavelengths must increase", True),
    ('<spectrum name="reflectance" value="400:0.5, 400:0.2"/>',
     "the wavelengths must increase", True),
    ('<spectrum name="reflectance" value="400-0.5, 500:0.2"/>',
     "expected wavelength:value pairs", True),
    ('<spectrum name="reflectance" value="0.5 0.2"/>',
     "expected wavelength:value pairs", True),
    ('<spectrum name="reflectance" value="400:nan, 500:0.2"/>',
     "expected finite numbers", False),
    ('<spectrum name="reflectance" filename="missing.spd"/>', "missing.spd", True),
    ('<spectrum name="reflectance" type="blackbody"/>', "spectrum plugins", False),
    ('<spectrum name="reflectance" value="0.5" wavelengths="400"/>',
     "unexpected attribute 'wavelengths'", True),
], ids=["both", "neither", "one-pair", "decreasing", "repeated", "not-a-pair",
        "two-numbers", "nan", "missing-file", "plugin", "attribute"])
def test_a_spectrum_mitsuba_cannot_read_is_refused_by_line(mi, tmp_path, element, needle,
                                                          mitsuba_refuses):
    text = (f'<scene version="3.0.0">\n{SENSOR}\n<shape type="sphere"><bsdf '
            f'type="diffuse">{element}</bsdf></shape>\n</scene>')
    (tmp_path / "s.xml").write_text(text)
    with pytest.raises(SceneError) as e:
        load_scene(str(tmp_path / "s.xml"))
    assert "s.xml:3" in str(e.value) and needle in str(e.value), str(e.value)
    if mitsuba_refuses:     # the refusal is Mitsuba's too, not a gap of ours
        with pytest.raises(RuntimeError):
            mi.load_file(str(tmp_path / "s.xml"))


def test_a_bad_spectrum_file_is_refused_naming_it_and_its_line(tmp_path):
    # the XML's wavelength:value form in a file (Mitsuba: "Could not extract value"); a
    # third number after the pair Mitsuba ignores (refused here until 7 December)
    (tmp_path / "bad.spd").write_text("# a comment\n400 0.1\n500:0.2\n")
    (tmp_path / "s.xml").write_text(
        f'<scene version="3.0.0">\n{SENSOR}\n<emitter type="constant"><spectrum '
        'name="radiance" filename="bad.spd"/></emitter>\n</scene>')
    with pytest.raises(SceneError, match=r"s\.xml:3.*bad\.spd: line 3: expected a "
                                         r"wavelength and a value, got '500:0.2'"):
        load_scene(str(tmp_path / "s.xml"))


@pytest.mark.mitsuba
@pytest.mark.parametrize("content,needle", [
    ("400 0.1\n   \n500 0.7\n", "line 2: a line of spaces or tabs"),
    ("400 0.1\n500 0.7\n\t\n", "line 3: a line of spaces or tabs"),
    ("400 0.1\n \r\n500 0.7\n", "line 2: a line of spaces or tabs"),
    # one line to Mitsuba, whose first two numbers it reads: one pair, said why (the
    # count alone told a 50-line classic Mac file it had one pair; a read-only review)
    ("400 0.1\r500 0.7\r", "1 wavelength:value pair(s); a spectrum needs at least two "
                             "(Mitsuba refuses it too); its lines end at a lone \\r"),
], ids=["spaces", "trailing-tab", "space-crlf", "lone-cr"])
def test_a_spectrum_file_line_mitsuba_refuses_is_refused_by_line(mi, tmp_path, content,
                                                                needle):
    """Mitsuba 3.9.1 skips an empty line, or one starting with '#' or a carriage return,
    and ends lines at \\n only: a line of spaces or tabs it refuses ("Could not extract
    wavelength"), and a file of lone \\r line ends is one line to it. Until 7 December
    Python's reading of lines skipped the first and split the second, and the scene was
    read; ``render-check`` then failed in Mitsuba's reference build."""
    (tmp_path / "a.spd").write_bytes(content.encode())
    (tmp_path / "s.xml").write_text(
        f'<scene version="3.0.0">\n{SENSOR}\n<shape type="sphere"><bsdf type="diffuse">'
        '<spectrum name="reflectance" filename="a.spd"/></bsdf></shape>\n</scene>')
    with pytest.raises(SceneError) as e:
        load_scene(str(tmp_path / "s.xml"))
    assert "s.xml:3" in str(e.value) and needle in str(e.value), str(e.value)
    with pytest.raises(RuntimeError):
        mi.load_file(str(tmp_path / "s.xml"))


def test_a_spectrum_file_of_crlf_lines_is_read_as_mitsuba_reads_it(tmp_path):
    """CRLF line ends, an empty CRLF line and one starting with \\r (skipped by Mitsuba
    too) read as the same file with \\n ends."""
    (tmp_path / "crlf.spd").write_bytes(b"# c\r\n400 0.1\r\n\r\n\r# d\r\n500\t0.7\r\n")
    (tmp_path / "lf.spd").write_bytes(b"400 0.1\n500 0.7\n")
    assert spectra.read_spd(str(tmp_path / "crlf.spd")) == \
        spectra.read_spd(str(tmp_path / "lf.spd")) == ([400.0, 500.0], [0.1, 0.7])


@pytest.mark.mitsuba
def test_what_follows_a_spectrum_file_lines_two_numbers_is_ignored_as_mitsuba_does(mi,
                                                                                  tmp_path):
    """A trailing comment and a third column (a measured file's n and k, or its error):
    Mitsuba 3.9.1 reads the first two numbers of a line and ignores the rest; until 7
    December we refused the line, though Mitsuba renders the scene."""
    (tmp_path / "a.spd").write_text("# wavelength eta k\n400 0.9 # blue\n500 2.5 3.1\n"
                                    "600 0.4\t7 8\n")
    (tmp_path / "s.xml").write_text(
        f'<scene version="3.0.0">\n{SENSOR}\n<shape type="sphere"><bsdf type="diffuse">'
        '<spectrum name="reflectance" filename="a.spd"/></bsdf></shape>\n</scene>')
    ours = load_scene(str(tmp_path / "s.xml")).shapes[0].children[0].props["reflectance"]
    theirs = _mitsuba_values(mi, (tmp_path / "s.xml").read_text().replace(
        'filename="a.spd"', 'value="400:0.9, 500:2.5, 600:0.4"'))["reflectance"]
    assert np.allclose(ours, theirs, rtol=1e-5, atol=1e-6), (ours, theirs)
    assert np.allclose(_mitsuba_values(mi, (tmp_path / "s.xml").read_text().replace(
        'filename="a.spd"', f'filename="{tmp_path / "a.spd"}"'))["reflectance"], theirs,
        rtol=1e-6)


@pytest.mark.mitsuba
@pytest.mark.parametrize("line,pair", [
    ("400 0.9# blue", (400, 0.9)), ("400 0.9,", (400, 0.9)), ("400\t0.9;", (400, 0.9)),
    ("400 0.9e", (400, 0.9)), ("400 0.2e1x", (400, 2.0)), ("400 0x10", (400, 0.0)),
    ("400.5.3 0.1", (400.5, 0.3)), ("400 0.9\v", (400, 0.9)),
], ids=["hash", "comma", "semicolon", "bare-e", "exponent-then-text", "hex", "two-points",
        "vtab"])
def test_a_spectrum_file_lines_numbers_end_where_mitsubas_reader_ends_them(mi, tmp_path,
                                                                          line, pair):
    """Mitsuba 3.9.1 reads a line's wavelength and value each as the longest decimal
    number after spaces or tabs, and ignores what follows: ``400 0.9# blue`` and
    ``400 0.9,`` are 0.9 to it. Until 7 December such a line was refused here as
    'expected a wavelength and a value', though Mitsuba renders the scene."""
    (tmp_path / "a.spd").write_bytes(f"{line}\n700 0.4\n".encode())
    (tmp_path / "s.xml").write_text(
        f'<scene version="3.0.0">\n{SENSOR}\n<shape type="sphere"><bsdf type="diffuse">'
        '<spectrum name="reflectance" filename="a.spd"/></bsdf></shape>\n</scene>')
    assert spectra.read_spd(str(tmp_path / "a.spd")) == ([pair[0], 700.0], [pair[1], 0.4])
    ours = load_scene(str(tmp_path / "s.xml")).shapes[0].children[0].props["reflectance"]
    theirs = _mitsuba_values(mi, (tmp_path / "s.xml").read_text().replace(
        'filename="a.spd"', f'filename="{tmp_path / "a.spd"}"'))["reflectance"]
    assert np.allclose(ours, theirs, rtol=1e-5, atol=1e-6), (ours, theirs)


@pytest.mark.mitsuba
@pytest.mark.parametrize("line", ["400x 0.1", "400\v0.1", "400\r0.1", "400, 0.1", "x 0.1"])
def test_a_spectrum_file_line_without_two_leading_numbers_is_refused(mi, tmp_path, line):
    """Where no number follows the wavelength (after spaces or tabs only), Mitsuba
    refuses the line ("Could not extract value"), and so do we, by file and line."""
    (tmp_path / "a.spd").write_bytes(f"{line}\n700 0.4\n".encode())
    assert spectra.read_spd(str(tmp_path / "a.spd")).startswith(
        "line 1: expected a wavelength and a value")
    (tmp_path / "s.xml").write_text(
        f'<scene version="3.0.0">\n{SENSOR}\n<shape type="sphere"><bsdf type="diffuse">'
        '<spectrum name="reflectance" filename="a.spd"/></bsdf></shape>\n</scene>')
    with pytest.raises(RuntimeError):
        mi.load_file(str(tmp_path / "s.xml"))


@pytest.mark.parametrize("element,needle", [
    # a plain number to Mitsuba too ("has the wrong type")
    ('<bsdf type="roughplastic"><spectrum name="alpha" value="0.2"/></bsdf>',
     "property 'alpha' takes float, not a spectrum"),
    ('<bsdf type="dielectric"><spectrum name="int_ior" value="1.5"/></bsdf>',
     "property 'int_ior' takes float or string, not a spectrum"),
])
def test_a_spectrum_where_a_number_is_read_is_refused(element, needle):
    with pytest.raises(SceneError, match=needle):
        parse_scene(f'<scene version="3.0.0">{SENSOR}<shape type="sphere">{element}'
                    '</shape></scene>', path="s.xml")


def test_a_uniform_reflectance_is_a_number_and_a_negative_one_is_refused():
    desc = parse_scene(f'<scene version="3.0.0">{SENSOR}<shape type="sphere"><bsdf '
                       'type="diffuse"><spectrum name="reflectance" value="0.4"/></bsdf>'
                       '</shape></scene>', path="s.xml")
    assert desc.shapes[0].children[0].props["reflectance"] == 0.4
    with pytest.raises(SceneError, match="reflectance = -0.4: a reflectance"):
        parse_scene(f'<scene version="3.0.0">{SENSOR}<shape type="sphere"><bsdf '
                    'type="diffuse"><spectrum name="reflectance" value="-0.4"/></bsdf>'
                    '</shape></scene>', path="s.xml")


@pytest.mark.mitsuba
@pytest.mark.parametrize("mutant", ["grey-uniform-emission", "emission-weighted-by-d65",
                                    "reflectance-not-weighted"])
def test_the_render_gate_sees_a_spectrum_read_wrongly(tmp_path, monkeypatch, mutant):
    """vocabulary-spectra passes its render gate (``test_pathtracer_coverage``); with a
    spectrum read otherwise than Mitsuba reads it, it fails: a uniform emission taken as
    grey, pairs of an emission weighted by D65 as a reflectance's are, or a
    reflectance's not weighted. A copy of the scene (its committed reference with it):
    a compiled scene is kept per path."""
    from mcverify.gate.render_check import render_check

    shutil.copytree(SPECTRA_SCENE, tmp_path / "vs")
    if mutant == "grey-uniform-emission":
        monkeypatch.setattr(scene_module, "uniform_emission_rgb", lambda v: np.full(3, v))
    else:
        def wrong(wavelengths, values, emitter, unbounded):
            if mutant == "emission-weighted-by-d65" and emitter:
                return spectrum_list_rgb(wavelengths, values, emitter=False, unbounded=True)
            if mutant == "reflectance-not-weighted" and not emitter:
                return np.clip(spectrum_list_rgb(wavelengths, values, emitter=True,
                                                 unbounded=False), 0.0, 1.0)
            return spectrum_list_rgb(wavelengths, values, emitter=emitter,
                                     unbounded=unbounded)
        monkeypatch.setattr(scene_module, "spectrum_list_rgb", wrong)
    r = render_check(str(tmp_path / "vs" / "scene.xml"), spp=512, passes=8, seed=3)
    assert not r.passed, r.summary()


def _colour_of(desc):
    return np.ravel(desc.shapes[0].children[0].props["reflectance"])


@pytest.mark.mitsuba
@pytest.mark.parametrize("layout", ["path-after", "path-in-include", "nested-include",
                                    "include-beside"])
def test_a_spectrum_file_is_the_one_mitsuba_reads_and_the_reference_hashes(mi, tmp_path,
                                                                          layout):
    """Mitsuba reads a ``<spectrum filename>`` as it parses: in the folders of its
    resolver as they stand there. A ``<path>`` after the element does not count; one in an
    included file does, for that file; a nested include's element looks beside the file
    that included its file; an included file's own folder does not count (a read-only
    review: the loader and the reference's hashing read the scene's folders, wherever its
    ``<path>``s stood, and the first three read and hashed another file than Mitsuba's).
    Red where Mitsuba reads, blue elsewhere."""
    from mcverify.gate.reference import scene_asset_files

    red, blue = "400 0.9\n700 0.9\n", "400 0.05\n700 0.05\n"
    element = ('<shape type="sphere"><bsdf type="diffuse"><spectrum name="reflectance" '
               'filename="c.spd"/></bsdf></shape>')
    for d in ("sub", "sub/lib", "dir"):
        (tmp_path / d).mkdir(exist_ok=True)

    def scene(body):
        return f'<scene version="3.0.0">{SENSOR}{body}</scene>'

    if layout == "path-after":
        (tmp_path / "s.xml").write_text(scene(element + '<path value="dir"/>'))
        where, other = "c.spd", "dir/c.spd"
    elif layout == "path-in-include":
        (tmp_path / "s.xml").write_text(scene('<include filename="sub/parts.xml"/>'))
        (tmp_path / "sub/parts.xml").write_text(
            '<scene version="3.0.0"><path value="lib"/>' + element + '</scene>')
        where, other = "sub/lib/c.spd", "c.spd"
    elif layout == "nested-include":
        (tmp_path / "s.xml").write_text(scene('<include filename="sub/a.xml"/>'))
        (tmp_path / "sub/a.xml").write_text(
            '<scene version="3.0.0"><include filename="b.xml"/></scene>')
        (tmp_path / "sub/b.xml").write_text(f'<scene version="3.0.0">{element}</scene>')
        where, other = "sub/c.spd", "c.spd"
    else:
        (tmp_path / "s.xml").write_text(scene('<include filename="sub/parts.xml"/>'))
        (tmp_path / "sub/parts.xml").write_text(f'<scene version="3.0.0">{element}</scene>')
        where, other = "c.spd", "sub/c.spd"
    (tmp_path / where).write_text(red)
    (tmp_path / other).write_text(blue)
    params = mi.traverse(mi.load_file(str(tmp_path / "s.xml")))
    theirs = next(np.ravel(np.array(params[k], dtype=float)) for k in params.keys()
                  if k.endswith("reflectance.value"))
    ours = _colour_of(load_scene(str(tmp_path / "s.xml")))
    assert np.allclose(ours, theirs, rtol=1e-5, atol=1e-6) and theirs.min() > 0.5, \
        (ours, theirs)
    hashed = scene_asset_files(str(tmp_path / "s.xml"))
    assert os.path.realpath(tmp_path / where) in {os.path.realpath(f) for f in
                                                  hashed.values()}, hashed


def test_loading_pairs_leaves_numpys_print_options_as_they_were():
    """colour-science's import sets numpy's legacy printing for the whole process; a
    scene of wavelength:value pairs imported it bare (a read-only review)."""
    import subprocess
    import sys

    code = ("import numpy as np\n"
            "from estimators.pathtracer import parse_scene\n"
            "parse_scene('<scene version=\"3.0.0\"><sensor type=\"perspective\"/><shape "
            "type=\"sphere\"><bsdf type=\"diffuse\"><spectrum name=\"reflectance\" "
            "value=\"400:0.2, 700:0.6\"/></bsdf></shape></scene>', path='s.xml')\n"
            "import sys; sys.modules['colour']\n"
            "print(repr(np.get_printoptions()['legacy']), np.array([0.5, 1.0]))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=ROOT, check=True).stdout
    assert out.strip() == "False [0.5 1. ]", out


@pytest.mark.parametrize("element", [
    '<emitter type="constant"><spectrum name="radiance" value="3e38"/></emitter>',
    '<emitter type="constant"><spectrum name="radiance" value="400:3e38, 700:3e38"/>'
    '</emitter>'])
def test_a_spectrum_whose_rgb_is_beyond_float32_is_refused(element):
    """As an ``<rgb>`` beyond float32's range: Mitsuba holds the colour as inf (a uniform
    emission of 3e38 is 3.6e38 red; a read-only review)."""
    with pytest.raises(SceneError, match=r"s\.xml:1.*beyond float32's range"):
        parse_scene(f'<scene version="3.0.0">{SENSOR}{element}</scene>', path="s.xml")


@pytest.mark.mitsuba
def test_a_spectrum_file_line_over_1023_bytes_is_refused_as_mitsuba_refuses_it(mi, tmp_path):
    """Mitsuba reads a spectrum file's line in pieces of 1023 bytes and refuses the second
    piece, a long comment's too; 1023 bytes are read whole by both (a read-only review)."""
    for name, comment in (("ok", "#" + "x" * 1022), ("long", "#" + "x" * 1023)):
        (tmp_path / f"{name}.spd").write_text(f"{comment}\n400 0.1\n700 0.5\n")
        (tmp_path / f"{name}.xml").write_text(
            f'<scene version="3.0.0">\n{SENSOR}\n<shape type="sphere"><bsdf type="diffuse">'
            f'<spectrum name="reflectance" filename="{name}.spd"/></bsdf></shape>\n</scene>')
    load_scene(str(tmp_path / "ok.xml"))
    mi.load_file(str(tmp_path / "ok.xml"))
    with pytest.raises(SceneError, match=r"long\.spd: line 1: longer than 1023 bytes"):
        load_scene(str(tmp_path / "long.xml"))
    with pytest.raises(RuntimeError):
        mi.load_file(str(tmp_path / "long.xml"))


def test_a_spectrum_files_features_are_its_rule_and_the_file():
    from estimators.pathtracer.spectra import spectrum_features

    pairs = (np.array([400.0, 700.0]), np.array([1.0, 2.0]))
    assert spectrum_features("emitter", "radiance", pairs, True) == ("emission", "file")
    assert spectrum_features("bsdf", "k", pairs, False) == ("index",)
    assert spectrum_features("bsdf", "reflectance", 0.5, False) == ("uniform",)
    assert spectrum_features("emitter", "radiance", 0.5, False) == ("emission(uniform)",)


@pytest.mark.mitsuba
@pytest.mark.parametrize("bsdf, name", [
    ('<bsdf type="roughconductor">{s}</bsdf>', "alpha"),
    ('<bsdf type="roughconductor">{s}<float name="alpha_v" value="0.2"/></bsdf>', "alpha_u"),
    ('<bsdf type="roughdielectric">{s}</bsdf>', "alpha"),
    ('<bsdf type="roughdielectric">{s}<float name="alpha_u" value="0.2"/></bsdf>', "alpha_v"),
    ('<bsdf type="blendbsdf">{s}<bsdf type="diffuse"/><bsdf type="conductor"/></bsdf>',
     "weight"),
    ('<bsdf type="mask">{s}<bsdf type="diffuse"/></bsdf>', "opacity"),
])
def test_a_uniform_spectrum_is_the_number_mitsuba_reads_as_a_texture(mi, bsdf, name):
    """Mitsuba reads a rough BSDF's roughness, a blend's weight and a mask's opacity as
    textures, which take a uniform spectrum as its number; ours refused it by line (an
    outside review): it is that number now, as a <float> of it would be."""
    def scene(value):
        return (f'<scene version="3.0.0">{SENSOR}<shape type="sphere">'
                + bsdf.format(s=value) + '</shape></scene>')
    spectral = scene(f'<spectrum name="{name}" value="0.3"/>')
    plain = scene(f'<float name="{name}" value="0.3"/>')
    mi.load_string(spectral)                                  # Mitsuba takes it
    assert parse_scene(spectral, path="s.xml").shapes[0].children[0].props == \
        parse_scene(plain, path="s.xml").shapes[0].children[0].props


@pytest.mark.mitsuba
@pytest.mark.parametrize("bsdf, name, mitsuba_refuses", [
    ('<bsdf type="roughplastic"><spectrum name="alpha" value="0.3"/></bsdf>', "alpha", True),
    ('<bsdf type="roughconductor"><spectrum name="alpha" value="400:0.1, 700:0.3"/></bsdf>',
     "alpha", False),
])
def test_a_spectrum_mitsuba_or_the_tracer_cannot_take_as_a_number_is_refused(
        mi, bsdf, name, mitsuba_refuses):
    """roughplastic's alpha is no texture in Mitsuba ("has the wrong type"); pairs on a
    roughness are an RGB texture there, which the tracer's roughness is not."""
    text = f'<scene version="3.0.0">{SENSOR}<shape type="sphere">{bsdf}</shape></scene>'
    with pytest.raises(SceneError, match=f"property '{name}' takes float, not a spectrum"):
        parse_scene(text, path="s.xml")
    if mitsuba_refuses:
        with pytest.raises(RuntimeError):
            mi.load_string(text)
