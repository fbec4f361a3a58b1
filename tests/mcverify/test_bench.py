"""``mcverify bench``'s render rows: Mitsuba's scenes are loaded one at a time."""

import json
import os

import numpy as np
import pytest

from mcverify.gate import bench


class _FakeMitsuba:
    """Stands in for the ``mitsuba`` module: counts the scenes alive and the loads."""

    def __init__(self):
        self.alive, self.most_alive, self.loads = 0, 0, []
        fake = self

        class Scene:
            def __init__(self, path):
                fake.alive += 1
                fake.most_alive = max(fake.most_alive, fake.alive)
                fake.loads.append(path)
                self.path = path

            def __del__(self):
                fake.alive -= 1

        self.Scene = Scene

    def load_file(self, path, **params):
        assert params in ({"res": 128}, {})     # {}: a scene without a res parameter
        self.params = params
        return self.Scene(path)

    def render(self, scene, spp):
        return np.full((2, 2, 3), float(spp))


def test_render_rows_load_one_mitsuba_scene_at_a_time():
    mi = _FakeMitsuba()
    rows = [r for r in bench._render_pairs(mi, spp=4) if r[0].startswith("render:")]
    assert len(rows) >= 2 and mi.loads == []           # nothing loaded up front
    first, second = rows[0][3], rows[1][3]
    assert first().shape == (2, 2, 3)
    first()
    assert len(mi.loads) == 1 and mi.alive == 1          # loaded once, reused
    second()
    second()
    assert len(mi.loads) == 2 and mi.alive == 1 and mi.most_alive == 1
    assert mi.loads[0] != mi.loads[1]
    first()                                              # back to the first: reloaded
    assert len(mi.loads) == 3 and mi.alive == 1


def test_render_rows_give_ours_the_samples_mitsubas_sampler_renders():
    """vocabulary-geometry's orthogonal sampler renders 121 spp when asked for 64 (a
    prime's square): our side of its row renders 121 too; an independent scene's 64.
    Finding that out loads no Mitsuba scene (a first version loaded each through the
    gate's scene cache, which kept four alive and made Mitsuba's renders up to 7 times
    slower in the bench)."""
    from mcverify.gate import mitsuba as mvm

    loads = mvm._loaded.cache_info().misses
    rows = {r[0]: r for r in bench._render_pairs(_FakeMitsuba(), spp=64)}
    assert "121 spp" in rows["render:vocabulary-geometry"][1]
    assert "64 spp" in rows["render:cornell-box"][1]
    assert mvm._loaded.cache_info().misses == loads


def test_render_rows_name_the_film_size_both_sides_render():
    """`res` 128 sets the height; a film whose width is fixed keeps it (vocabulary-geometry
    64, vocabulary-lights 48): their rows said "128 x 128" for the 64 x 128 and 48 x 128
    images both sides render."""
    rows = {r[0]: r[1] for r in bench._render_pairs(_FakeMitsuba(), spp=16)}
    assert rows["render:vocabulary-geometry"].startswith("64 x 128,"), rows
    assert rows["render:vocabulary-lights"].startswith("48 x 128,"), rows
    assert rows["render:cornell-box"].startswith("128 x 128,"), rows


_BENCHMARKS = os.path.join(os.path.dirname(__file__), "..", "..", "benchmarks")


def _script(name):
    """A script of benchmarks/ as a module (they are run as files, not imported; each
    imports ``_args`` from its own folder, which running it puts on the path)."""
    import importlib.util
    import sys

    if _BENCHMARKS not in sys.path:
        sys.path.append(_BENCHMARKS)
    path = os.path.join(_BENCHMARKS, name + ".py")
    spec = importlib.util.spec_from_file_location(f"_bench_script_{name}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("argv, needle", [
    (["tracer_speed.py", "nosuchscene", "--ours-only"],
     "tracer_speed.py: error: scene 'nosuchscene': no such file"),
    (["profile_judge.py", "--n", "-5"], "argument --n: '-5': must be a whole number >= 1"),
    (["chi2_speed.py", "--n", "inf"], "argument --n: 'inf': must be a whole number >= 1"),
    (["warp_speed.py", "--repeats", "0"], "argument --repeats: '0': must be a whole number"),
    (["warp_speed.py", "nosuchwarp"], "unknown warp 'nosuchwarp'; known: beckmann"),
    (["perf_tracer.py", "x", "--seconds", "nan"], "'nan': must be a number of seconds > 0"),
])
def test_a_benchmark_script_refuses_a_bad_input_in_one_line(argv, needle):
    """The scripts of benchmarks/ ended in a raw traceback on a scene that is none
    (tracer_speed, profile_tracer, ablate_scene) or on --n -5 (numpy's "negative
    dimensions"), and warp_speed --repeats 0 printed inf for every warp: each is now
    one error line and exit 2, before any work."""
    import subprocess
    import sys

    r = subprocess.run([sys.executable, os.path.join(_BENCHMARKS, argv[0]), *argv[1:]],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, (r.returncode, r.stderr[-2000:])
    assert needle in r.stderr and "Traceback" not in r.stderr, r.stderr[-2000:]


def test_tracer_speed_renders_ours_at_mitsubas_sample_count(monkeypatch, capsys):
    """benchmarks/tracer_speed.py at --spp 32 on vocabulary-geometry (an orthogonal
    sampler: Mitsuba renders 49) timed ours at 32 samples against Mitsuba's 49, a ratio
    flattering ours by 1.5x; now both render 49, as `mcverify bench` has them."""
    import sys
    import types

    from mcverify.gate import mitsuba as mvm

    script = _script("tracer_speed")
    spps = {"ours": set(), "theirs": set()}

    class Theirs:
        @staticmethod
        def load_file(path, **params):
            return path

        @staticmethod
        def render(scene, spp, seed):
            spps["theirs"].add(mvm.sampler_rounds(
                script.prepare_scene(scene).desc.sampler, spp))   # what Mitsuba renders
            return np.zeros((2, 2, 3))

    monkeypatch.setattr(script, "mvm", types.SimpleNamespace(
        _mi=lambda: Theirs, sampler_rounds=mvm.sampler_rounds))
    monkeypatch.setattr(script, "render", lambda scene, spp, **kw: spps["ours"].add(spp))
    monkeypatch.setattr(sys, "argv", ["tracer_speed.py", "vocabulary-geometry", "--spp", "32",
                                      "--repeats", "1"])
    script.main()
    assert spps == {"ours": {49}, "theirs": {49}}, spps
    assert "(49 spp" in capsys.readouterr().out


def test_equal_time_rmse_of_our_tracer_against_itself_is_one():
    """A stand-in Mitsuba that renders with our own tracer, and a clock under which every
    render takes the same time: the same estimator at the same spp, so the equal-time
    RMSE ratio is 1 to within the spread of a mean of 4 MSEs (seeded: no timing in the
    test); every render of both sides has its own seed."""
    import itertools

    from estimators.pathtracer import prepare_scene, render

    seeds = []

    class Itself:
        @staticmethod
        def load_file(path):
            return prepare_scene(path)

        @staticmethod
        def render(scene, spp, seed):
            seeds.append(seed)
            return render(scene, spp=spp, seed=10_000 + seed).mean

    row = bench.equal_time_rmse("cornell-box", spp=8, repeats=4, mi=Itself,
                                clock=itertools.count(0.0, 0.5).__next__)
    assert "ours 8 spp" in row["workload"]                 # equal time: equal spp
    assert 0.8 < row["ratio"] < 1.25, row
    assert row["ours_rmse"] > 0 and "mean MSE of 4 renders" in row["workload"]
    assert len(seeds) == 8 and len(set(seeds[4:])) == 4     # warm-up, 3 timed, 4 measured


@pytest.mark.parametrize("repeats", [0, -2])
def test_best_of_no_runs_is_refused(repeats):
    """``_best`` with no timed run returned inf: benchmarks/tracer_speed.py --repeats 0
    (and ablate_scene.py, which share it) printed "ours infs" as a time."""
    calls = []
    with pytest.raises(ValueError, match=f"repeats={repeats}: must be an integer >= 1"):
        bench._best(lambda: calls.append(1), repeats)
    assert calls == []
    assert bench._best(lambda: calls.append(1), 1, clock=iter([0.0, 0.5]).__next__) == 0.5


def test_cli_prints_microsecond_timings_as_numbers(monkeypatch, capsys):
    """A workload of microseconds (``--n 1000``) printed as 0.0000 on both sides, beside
    a ratio of 0.33 that its printed times could not give; now 4 significant digits."""
    from mcverify.gate import cli

    rows = [{"group": "warp:cosine_hemisphere", "workload": "w", "ours_s": 1.394e-05,
             "mitsuba_s": 4.2774e-05, "against": "mitsuba", "ratio": 1.394 / 4.2774,
             "note": None},
            {"group": "chi2:cosine_hemisphere", "workload": "w", "ours_s": 2.5,
             "mitsuba_s": None, "against": "mitsuba", "ratio": None, "note": None}]
    monkeypatch.setattr(bench, "run_bench", lambda **kw: rows)
    assert cli.main(["bench", "--no-render", "--n", "1000", "-q"]) == 0
    machine, header, *lines = capsys.readouterr().out.splitlines()
    assert lines[0].split()[1:4] == ["1.394e-05", "4.277e-05", "0.33"], lines[0]
    assert lines[1].split()[1:4] == ["2.5", "n/a", "n/a"], lines[1]
    end = header.index("ours/theirs") + len("ours/theirs")
    for line in lines:          # the ratio column still ends under its header
        assert line[end - 1] != " " and line[end:end + 2] == "  ", (header, line)


def test_cli_json_records_the_sizes_it_timed(tmp_path, monkeypatch, capsys):
    """`bench --json` records --n, --spp (and the equal-time rows' quarter of it), whether
    the renders ran and their scenes' folder: only --repeats was recorded, so a run at
    --n 1000 --spp 8 had the provenance of one at the defaults."""
    import json

    from mcverify.gate import cli, reference

    _own_scenes(tmp_path, monkeypatch)
    monkeypatch.setattr(bench, "run_bench", lambda **kw: [])
    out = tmp_path / "bench.json"
    assert cli.main(["bench", "--n", "2000", "--spp", "8", "--repeats", "2", "-q",
                     "--json", str(out)]) == 0
    prov = json.loads(out.read_text())["provenance"]
    assert (prov["n"], prov["spp"], prov["equal_time_spp"], prov["repeats"]) == (2000, 8, 2, 2)
    assert prov["renders"] is True and prov["refs"] == reference.REFERENCE_ROOT
    assert cli.main(["bench", "--no-render", "--n", "1000", "-q", "--json", str(out)]) == 0
    prov = json.loads(out.read_text())["provenance"]
    assert (prov["n"], prov["spp"], prov["renders"], prov["refs"]) == (1000, 64, False, None)


def test_cli_says_how_many_threads_each_side_ran(tmp_path, monkeypatch, capsys):
    """MCVERIFY_NUM_THREADS=1 timed ours on one thread against Mitsuba's every core, and
    neither the table nor --json said so; both now give each side's threads."""
    import numba

    from mcverify.gate import cli
    from mcverify.gate import mitsuba as mvm

    before = numba.get_num_threads()
    monkeypatch.setenv("MCVERIFY_NUM_THREADS", "1")
    monkeypatch.setattr(bench, "run_bench", lambda **kw: [])
    out = tmp_path / "bench.json"
    try:
        assert cli.main(["bench", "--no-render", "-q", "--json", str(out)]) == 0
    finally:
        numba.set_num_threads(before)
    threads = json.loads(out.read_text())["provenance"]["threads"]
    assert threads == {"ours": 1, "mitsuba": mvm.thread_count()}
    assert f"threads: ours 1, Mitsuba {mvm.thread_count()}" in capsys.readouterr().out


@pytest.mark.parametrize("notice,why", [
    ("mitsuba: llvm_ad_rgb does not work with /x/libLLVM.so; using scalar_rgb",
     "(llvm_ad_rgb does not work with /x/libLLVM.so; using scalar_rgb)"),
    (None, "(chosen by $MCVERIFY_MITSUBA_VARIANT)")])
def test_a_row_without_mitsuba_says_which_variant_and_why(monkeypatch, notice, why):
    """A warp row with no Mitsuba time said "no libLLVM >= 16" whatever the reason: also
    where a libLLVM was found but failed the probe, or the variable chose scalar_rgb."""
    from mcverify.gate import mitsuba as mvm

    monkeypatch.setattr(mvm, "choose_variant", lambda: mvm.VariantChoice("scalar_rgb", notice))
    monkeypatch.setattr(bench, "pairs", lambda *a, **k: [
        ("warp:w", "w", lambda: None, None, "mitsuba"), ("gate", "g", lambda: None, None, "-")])
    monkeypatch.setattr(bench, "MIN_SECONDS", 0.0)
    warp, gate = bench.run_bench(repeats=1, n=1000, renders=False)
    assert warp["note"] == f"Mitsuba's variant here, scalar_rgb, is not vectorised {why}"
    assert gate["note"] == "no counterpart"


def _own_scenes(tmp_path, monkeypatch, *, with_reference=True):
    """A --refs folder of the user's own: one scene (a copy of the white furnace under
    another name), with or without its reference."""
    import shutil

    from mcverify.gate import reference

    src = os.path.join(os.path.dirname(__file__), "..", "..", "reference", "scenes",
                       "white-furnace")
    shutil.copytree(src, tmp_path / "mine",
                    ignore=None if with_reference else shutil.ignore_patterns("ref"))
    monkeypatch.setattr(reference, "REFERENCE_ROOT", str(tmp_path))


def test_own_scenes_folder_keeps_the_fixed_workloads(tmp_path, monkeypatch):
    """`mcverify bench --refs MYDIR` with the user's own scenes: the rows of every scene
    are theirs, and the fixed workloads (the Cornell box's gate, the white furnace's
    kernels) still come with mcverify; it exited 2 with "scene 'white-furnace': no such
    file ... (known: mine)"."""
    _own_scenes(tmp_path, monkeypatch)
    rows = {r[0]: r for r in bench._render_pairs(_FakeMitsuba(), spp=4)}
    assert {"render:mine", "render-check:cornell-box",
            "kernel:specialised/general"} <= set(rows), sorted(rows)
    assert not any(name in rows for name in ("render:cornell-box", "render:white-furnace"))


def test_own_scene_without_a_res_parameter_renders_at_its_own_size(tmp_path, monkeypatch):
    """`bench --refs MYDIR` with a scene whose film size is literal (no $res, as a user's
    own scene often is) was refused by both renderers: "params ['res']: the scene has no
    such parameter" (ours), "Found unused parameters" (Mitsuba). It now renders at its
    own size on both sides, the row saying which."""
    _own_scenes(tmp_path, monkeypatch)
    scene = tmp_path / "mine" / "scene.xml"
    text = scene.read_text()
    assert '<default name="res" value="64"/>' in text
    scene.write_text(text.replace('<default name="res" value="64"/>', "")
                     .replace("$res", "40"))
    mi = _FakeMitsuba()
    rows = {r[0]: r for r in bench._render_pairs(mi, spp=4)}
    assert rows["render:mine"][1].startswith("40 x 40,"), rows["render:mine"][1]
    rows["render:mine"][3]()
    assert mi.params == {}
    assert bench._res_128(str(scene)) == {}


def test_a_scene_without_reference_is_refused_before_any_timing(tmp_path, monkeypatch):
    """The equal-time rows need each scene's reference: a missing one is refused, naming
    it, before anything is timed (it failed after all the timings)."""
    from mcverify.errors import MissingReference

    _own_scenes(tmp_path, monkeypatch, with_reference=False)
    monkeypatch.setattr(bench, "_best", lambda *a, **k: pytest.fail("timed"))
    with pytest.raises(MissingReference, match="no reference built for 'mine'"):
        bench.run_bench(repeats=1, n=1000, spp=4)


def test_cli_a_scene_our_tracer_refuses_is_bad_input(tmp_path, monkeypatch, capsys):
    """A --refs scene our tracer refuses (an unsupported integrator, its reference
    present) ended as "unexpected SceneError ... (set MCVERIFY_TRACEBACK=1 to see where)",
    the wording of a crash; now the scene's own message, as `check` gives it, exit 2,
    before anything is timed and with no --json written."""
    from mcverify.gate import cli
    from mcverify.gate.reference import scene_hash

    _own_scenes(tmp_path, monkeypatch)
    scene = tmp_path / "mine" / "scene.xml"
    scene.write_text(scene.read_text().replace('<integrator type="path"',
                                               '<integrator type="volpath"'))
    manifest = tmp_path / "mine" / "ref" / "manifest.json"
    doc = json.loads(manifest.read_text())
    doc["scene_sha256"] = scene_hash(str(scene))        # the reference stays current
    manifest.write_text(json.dumps(doc))
    monkeypatch.setattr(bench, "_best", lambda *a, **k: pytest.fail("timed"))
    out = tmp_path / "bench.json"
    assert cli.main(["bench", "--n", "1000", "-q", "--json", str(out)]) == 2
    err = capsys.readouterr().err
    assert "unsupported integrator type 'volpath'" in err and "unexpected" not in err, err
    assert not out.exists()


def test_cli_json_over_a_reference_it_reads_is_refused(tmp_path, monkeypatch, capsys):
    """`bench --json` naming a file the render rows read (a scene's reference manifest)
    is refused before anything runs, as every other command refuses its inputs; it was
    replaced after the run, leaving a corrupt reference."""
    from mcverify.gate import cli

    _own_scenes(tmp_path, monkeypatch)
    manifest = tmp_path / "mine" / "ref" / "manifest.json"
    before = manifest.read_bytes()
    monkeypatch.setattr(bench, "run_bench", lambda **kw: pytest.fail("ran"))
    assert cli.main(["bench", "--json", str(manifest), "-q"]) == 2
    assert "is also an input" in capsys.readouterr().err
    assert manifest.read_bytes() == before


def test_cli_json_has_no_nan_token_where_a_ratio_is_undefined(tmp_path, monkeypatch, capsys):
    """An equal-time row whose Mitsuba RMSE is 0 (a noise-free scene of the user's
    --refs, a constant environment) has ratio NaN: `bench --json` wrote the bare token
    NaN, which strict JSON parsers (jq, JavaScript, Go, Rust) refuse. Written as the
    results' other writers do: "nan"."""
    from mcverify.gate import cli

    row = {"group": "equal-time-rmse:empty", "workload": "w", "ours_rmse": 0.0,
           "mitsuba_rmse": 0.0, "ratio": float("nan"), "against": "mitsuba"}
    monkeypatch.setattr(bench, "run_bench", lambda **kw: [row])
    out = tmp_path / "bench.json"
    assert cli.main(["bench", "--no-render", "-q", "--json", str(out)]) == 0

    def strict(token):
        raise AssertionError(f"{token} in bench.json: not JSON")

    doc = json.loads(out.read_text(), parse_constant=strict)
    assert doc["results"][0]["ratio"] == "nan"


def test_a_scenes_res_parameter_is_found_whatever_its_encoding(tmp_path):
    """``bench --refs``: a scene in Latin-1 (an XML encoding declaration, a comment with
    0xe9) was read as strict UTF-8 to find its ``$res`` and ended in "unexpected
    UnicodeDecodeError" before the loader could name the encoding (a final review)."""
    from mcverify.gate.bench import _res_128

    path = tmp_path / "scene.xml"
    path.write_bytes(b'<?xml version="1.0" encoding="ISO-8859-1"?>\n<!-- caf\xe9 -->\n'
                     b'<scene version="3.0.0"><default name="res" value="64"/></scene>')
    assert _res_128(str(path)) == {"res": 128}
    path.write_bytes(b'<!-- caf\xe9 --><scene version="3.0.0"/>')
    assert _res_128(str(path)) == {}
