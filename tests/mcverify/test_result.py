import json
from dataclasses import replace
import xml.etree.ElementTree as ET

import numpy as np

import mcverify as mv
from mcverify.result import CheckResult, SuiteResult


def _r(name, p, failures=()):
    return CheckResult(name, CheckResult.decide(p, 0.01, failures), p, 1.0, 0.01, 10, 0.1,
                       {"seed": 1}, (), tuple(failures),
                       artifacts={"histogram": {"observed": np.zeros(3)}})


def test_holm_judging_across_checks():
    # p = 0.004 fails alone at 0.01, but is no alarm after Holm over three checks (0.012).
    assert not _r("a", 0.004).passed
    suite = SuiteResult.judge("s", [_r("a", 0.004), _r("b", 0.5), _r("c", 0.9)], alpha=0.01,
                              seconds=1.0)
    assert suite.results[0].passed and suite.results[0].details["p_adjusted"] == 0.012
    suite = SuiteResult.judge("s", [_r("a", 0.002), _r("b", 0.5)], alpha=0.01, seconds=1.0)
    assert not suite.passed      # 0.004 after Holm: still an alarm
    assert not SuiteResult.judge("s", [_r("a", 0.9, ["NaN"])], alpha=0.01, seconds=1).passed


def test_a_p_value_at_alpha_is_a_rejection():
    """p <= α rejects (the level is the largest p-value that fails), for one check and for
    a suite's Holm-adjusted p-values: 0.005 of two checks adjusts to 0.01 exactly."""
    assert not CheckResult.decide(0.01, 0.01, ()) and CheckResult.decide(0.0100001, 0.01, ())
    suite = SuiteResult.judge("s", [_r("a", 0.005), _r("b", 0.5)], alpha=0.01, seconds=1.0)
    assert suite.results[0].details["p_adjusted"] == 0.01 and not suite.passed


def test_holm_counts_every_check_with_a_p_value_even_of_1():
    """A check with p = 1 is one of the m hypotheses all the same: 0.006 beside it adjusts
    to 0.012 and passes at 0.01 (left out of the count, 0.006 would fail)."""
    suite = SuiteResult.judge("s", [_r("a", 0.006), _r("b", 1.0)], alpha=0.01, seconds=1.0)
    assert suite.results[0].details["p_adjusted"] == 0.012 and suite.passed


def test_one_canary_not_bitten_fails_the_suite_among_bitten_ones():
    bitten, missed = _r("planted1", 1e-9), _r("planted2", 0.5)
    suite = SuiteResult.judge("s", [_r("a", 0.5)], alpha=0.01, seconds=1.0,
                              canary=(bitten, missed))
    assert not suite.canary_bitten and not suite.passed
    assert len(suite.toothless()) == 1 and "planted2" in suite.toothless()[0]


def test_json_and_junit_writers(tmp_path):
    suite = SuiteResult.judge("s", [_r("a", 0.5), _r("b", 1e-9)], alpha=0.01, seconds=1.0,
                              provenance={"seed": 0})
    mv.write_json(suite, str(tmp_path / "r.json"))
    d = json.loads((tmp_path / "r.json").read_text())
    assert d["n_failed"] == 1 and "artifacts" not in d["results"][0]
    assert d["results"][0]["details"]["seed"] == 1
    assert suite.results[0].to_dict(arrays=True)["artifacts"]["histogram"]["observed"] == [0, 0, 0]
    mv.write_junit(suite, str(tmp_path / "r.xml"))
    root = ET.parse(tmp_path / "r.xml").getroot()
    assert root.get("tests") == "2" and root.get("failures") == "1"
    assert not list(tmp_path.glob(".tmp-*"))


def test_junit_parses_whatever_characters_a_check_reports(tmp_path):
    """A check's name or message may hold characters XML 1.0 cannot (an ANSI colour code
    in an exception's message, a non-UTF-8 file name decoded to a lone surrogate): the
    writer put control characters in as they were (a file CI's parsers reject, "not
    well-formed (invalid token)") and raised UnicodeEncodeError on a surrogate (exit 2,
    no JUnit). They are written as escapes now."""
    bad = _r("red\x1b[31m", 1e-9, ["raised OSError: \x00 in 'x\udcffy'"])
    suite = SuiteResult.judge("s\x07", [bad, _r("ok", 0.5)], alpha=0.01, seconds=1.0,
                              provenance={"seed": 0, "k\x01": "v"})
    mv.write_junit(suite, str(tmp_path / "r.xml"))
    root = ET.parse(tmp_path / "r.xml").getroot()
    assert root.get("name") == "mcverify.s\\x07" and root.get("failures") == "1"
    case = root.find("testcase")
    assert case.get("name") == "red\\x1b[31m"
    assert case.find("failure").text == "raised OSError: \\x00 in 'x\\udcffy'"
    assert [p.get("name") for p in root.iter("property")] == ["seed", "k\\x01"]


def test_details_json_cannot_hold_are_written_as_text(tmp_path):
    """A user check's details holding a set or a Path stopped the run at the very end with
    "unexpected TypeError: Object of type set is not JSON serializable" (exit 2, no JSON,
    no check named). Sets are written as lists, other objects as their text."""
    import pathlib

    r = CheckResult("d", True, 0.5, 1.0, 0.01, 10, 0.0,
                    details={"cells": {3, 1}, "file": pathlib.Path("/x/y"), "z": 1 + 2j,
                             "ok": [None, True, "s", 2]})
    suite = SuiteResult.judge("s", [r], alpha=0.01, seconds=1.0)
    mv.write_json(suite, str(tmp_path / "r.json"))
    d = json.loads((tmp_path / "r.json").read_text())["results"][0]["details"]
    assert d["cells"] == [1, 3] and d["file"] == "/x/y" and d["z"] == "(1+2j)"
    assert d["ok"] == [None, True, "s", 2]


def test_junit_lists_the_skipped_checks_as_the_json_does(tmp_path):
    """`check --scene` skips what the scene does not need, with the reason ("smooth
    dielectric: a delta BSDF, nothing to sample"): the JSON listed them under
    "skipped", the JUnit file not at all, so a CI's test view (GitLab, Jenkins) showed
    every test passed and nothing skipped. Each is now a testcase with <skipped>."""
    suite = SuiteResult.judge("s", [_r("a", 0.5)], alpha=0.01, seconds=1.0,
                              skipped=(("sampler:x", "not needed by this scene"),
                                       ("bsdf:dielectric\x1b", "a delta BSDF, <nothing> & co")))
    mv.write_junit(suite, str(tmp_path / "r.xml"))
    mv.write_json(suite, str(tmp_path / "r.json"))
    root = ET.parse(tmp_path / "r.xml").getroot()
    assert (root.get("tests"), root.get("failures"), root.get("skipped")) == ("3", "0", "2")
    skipped = {c.get("name"): c.find("skipped").get("message")
               for c in root.iter("testcase") if c.find("skipped") is not None}
    listed = json.loads((tmp_path / "r.json").read_text())["skipped"]
    assert skipped == {"sampler:x": "not needed by this scene",
                       "bsdf:dielectric\\x1b": "a delta BSDF, <nothing> & co"}
    assert [s["check"] for s in listed] == ["sampler:x", "bsdf:dielectric\x1b"]


def test_junit_failures_say_why_and_canaries_are_their_own_class(tmp_path):
    """A check that fails on its p-value alone (no failures, no messages) and a canary
    not bitten had an empty <failure> text, which CI views show as the whole story; the
    canaries shared the checks' classname though the writer said "their own class"."""
    not_bitten = _r("cosine+2%", 0.5)               # a canary the checks did not catch
    suite = SuiteResult.judge("s", [_r("a", 1e-9), _r("b", 0.5)], alpha=0.01, seconds=1.0,
                              canary=(not_bitten,))
    mv.write_junit(suite, str(tmp_path / "r.xml"))
    cases = {c.get("name"): c for c in ET.parse(tmp_path / "r.xml").getroot().iter("testcase")}
    text = cases["a"].find("failure").text
    assert "rejected at family-wise alpha=0.01 (holm)" in text and "p=1e-09" in text
    assert cases["b"].find("failure") is None
    canary = cases["canary.cosine+2%"]
    assert canary.get("classname") == "mcverify.s.canary"
    assert cases["a"].get("classname") == "mcverify.s"
    assert "planted bug passed" in canary.find("failure").text


def test_details_that_hold_themselves_are_written_as_their_repr(tmp_path):
    """A user's details holding itself (d["self"] = d) ended `mcverify check --json` with
    "unexpected RecursionError" after the run, naming no check and writing no JSON. The
    cycle is written as Python's repr writes it; a value shared, not a cycle, in full."""
    d, shared = {"a": 1}, [1.0, 2.0]
    d["self"], d["l"] = d, [shared, shared]
    d["l"].append(d["l"])
    suite = SuiteResult.judge("s", [CheckResult("c", True, 0.5, None, 0.01, 1, 0.1, d)],
                              alpha=0.01, seconds=1.0)
    mv.write_json(suite, str(tmp_path / "r.json"))
    mv.write_junit(suite, str(tmp_path / "r.xml"))
    got = json.loads((tmp_path / "r.json").read_text())["results"][0]["details"]
    # (the judged result's details are a copy with p_adjusted: its "self" is the original)
    assert got["self"]["self"] == "{...}" and got["l"] == [[1.0, 2.0], [1.0, 2.0], "[...]"]


def test_a_result_is_true_only_where_it_passed():
    """``assert mv.check_sampler(...)`` held for a failed check as for a passed one: a
    dataclass without ``__bool__`` is always true, so a user's test that asserted the
    result itself (not ``.passed``) could never fail. A result's truth is its verdict."""
    failed, ok = _r("a", 1e-9), _r("b", 0.5)
    assert not failed and ok
    assert [bool(r) for r in (failed, ok)] == [False, True]
    assert not SuiteResult.judge("s", [failed, ok], alpha=0.01, seconds=1.0)
    assert SuiteResult.judge("s", [ok], alpha=0.01, seconds=1.0)
    assert not SuiteResult.judge("s", [ok], alpha=0.01, seconds=1.0, canary=(ok,))


def test_a_result_equals_its_copies():
    """Results come back from worker processes pickled: a result holding arrays in its
    artifacts (check_sampler's histogram, compare_images' p-value map) raised "The truth
    value of an array with more than one element is ambiguous" on ``==`` against its own
    copy (and so on ``in`` and ``index`` over a list of results), and one with a NaN in its
    details was unequal to its pickled copy. A result equals its copies, not another."""
    import copy
    import pickle

    r = _r("a", 0.5)
    nan = replace(r, details={"worst": {"u": [float("nan"), 0.5]}}, statistic=float("nan"))
    for x in (r, nan):
        assert pickle.loads(pickle.dumps(x)) == x and copy.deepcopy(x) == x
        assert x in [pickle.loads(pickle.dumps(x))]
    other = replace(r, artifacts={"histogram": {"observed": np.ones(3)}})
    assert other != r and replace(r, details={"seed": 2}) != r and r != r.to_dict()
    assert replace(r, artifacts={"histogram": {"observed": np.zeros(4)}}) != r


def test_print_shows_the_verdict_and_its_messages_not_the_details():
    """``print(result)`` was the dataclass's repr: for a failed 32 x 32 compare_images,
    some 7,000 characters of rejected blocks before the messages that say where. It is
    the summary line and the messages now; ``repr`` keeps every field."""
    rng = np.random.default_rng(0)
    a, v = rng.random((32, 32)) + 0.5, np.full((32, 32), 1e-4)
    r = mv.compare_images(a * 1.2, a, test_var=v, ref_var=v, test_n=100, ref_n=100)
    lines = str(r).splitlines()
    assert lines[0] == r.summary() and lines[0].startswith("FAIL image p=0")
    assert lines[1:] == ["    " + m for m in r.messages] and "clearest block" in lines[2]
    assert len(str(r)) < 600 and "rejected_fraction" in repr(r)
    failed = _r("s", 0.5, ["pdf integrates to 1.1"])
    assert str(failed) == failed.summary() and "pdf integrates to 1.1" in str(failed)


def test_print_of_a_suite_names_its_failures_and_counts():
    """``print(suite)`` gave every check's full repr, details and all; it is what
    ``mcverify check`` prints: the failed checks, a canary not bitten, the counts."""
    big = {"blocks": [{"pixels": [i, i], "p_adjusted": 0.0} for i in range(50)]}
    fail = replace(_r("b", 1e-9), details=big, messages=("clearest block: y 0-3",))
    suite = SuiteResult.judge("s", [_r("a", 0.5), fail], alpha=0.01, seconds=1.0,
                              canary=(_r("planted", 0.5),))
    lines = str(suite).splitlines()
    assert lines[0].startswith("FAIL b p=1e-09 p_adj=2e-09")
    assert lines[1:] == ["    clearest block: y 0-3",
                         "FAIL judge has no teeth: planted bug 'planted' was not rejected "
                         "(p=0.5)",
                         "suite s: 1 passed, 1 failed (family-wise alpha=0.01 by holm; "
                         "canaries NOT bitten; 1.0s)"]


def test_a_suite_run_without_canaries_says_none_ran():
    """``run_suite(..., canary=False)`` (the API; the CLI always plants them) said
    "canaries bitten" of none, in its counts and on the report's page (``all([])`` is
    true; a mutation review's found-not-fixed). It says "no canaries" now."""
    from mcverify.gate.report import render_html

    bare = SuiteResult.judge("s", [_r("a", 0.5)], alpha=0.01, seconds=1.0)
    assert bare.counts() == ("1 passed, 0 failed (family-wise alpha=0.01 by holm; "
                             "no canaries; 1.0s)")
    page = render_html(dict(provenance={}, verification=bare.to_dict(), convergence=[],
                            renders=[]), {})
    assert "no canaries;" in page and "bitten" not in page
    bitten = SuiteResult.judge("s", [_r("a", 0.5)], alpha=0.01, seconds=1.0,
                               canary=(_r("planted", 1e-9),))
    assert "; canaries bitten; " in bitten.counts()


def test_the_report_page_lists_the_checks_a_run_skipped():
    """The checks a run skips (``--scene``: what the scene does not need) were in the
    JSON, the JUnit file and the text output, not on the report's page (a mutation
    review's found-not-fixed): it lists each with its reason, escaped."""
    from mcverify.gate.report import render_html

    suite = SuiteResult.judge("s", [_r("a", 0.5)], alpha=0.01, seconds=1.0,
                              skipped=(("sampler:<cone>", "not needed by this scene"),))
    page = render_html(dict(provenance={}, verification=suite.to_dict(), convergence=[],
                            renders=[]), {})
    assert "<p>1 skipped:</p><ul><li>sampler:&lt;cone&gt;: not needed by this scene</li>" \
        in page
    bare = SuiteResult.judge("s", [_r("a", 0.5)], alpha=0.01, seconds=1.0)
    assert "skipped" not in render_html(dict(provenance={}, verification=bare.to_dict(),
                                             convergence=[], renders=[]), {})


def test_a_notebook_shows_a_result_as_print_does():
    """Jupyter and IPython display a bare result through ``_repr_pretty_`` where it has
    one, else ``repr``: some 7,000 characters of details for a failed image."""
    shown = []

    class Printer:                          # IPython's pretty printer, as far as used
        def text(self, t):
            shown.append(t)

    fail = replace(_r("b", 1e-9), messages=("clearest block: y 0-3",))
    suite = SuiteResult.judge("s", [_r("a", 0.5), fail], alpha=0.01, seconds=1.0)
    for r in (fail, suite):
        r._repr_pretty_(Printer(), False)
        assert shown.pop() == str(r)


def test_outputs_written_together_are_all_put_back_where_a_rename_fails(tmp_path,
                                                                        monkeypatch):
    """``staged_writes`` renames its files at the block's end: where one rename fails (an
    immutable file, ``chattr +i``), the ones made before it are undone, and no temporary
    or kept-aside file is left (a read-only review found ``--json A`` replaced beside an
    immutable ``--junit B``, exit 2). A new file made before the failure is removed."""
    import os

    import pytest

    from mcverify import result

    (tmp_path / "a.json").write_text("old a\n")
    (tmp_path / "b.xml").write_text("old b\n")
    real = os.replace

    def replace(src, dst):
        if str(dst).endswith("b.xml") and ".tmp-" in str(src):
            raise PermissionError(1, "Operation not permitted")
        return real(src, dst)

    monkeypatch.setattr(result.os, "replace", replace)
    with pytest.raises(OSError, match=r"cannot write it \(Operation not permitted\)"):
        with result.staged_writes():
            result.atomic_write(tmp_path / "a.json", "new a\n")
            result.atomic_write(tmp_path / "new.txt", "new\n")
            result.atomic_write(tmp_path / "b.xml", "new b\n")
    assert (tmp_path / "a.json").read_text() == "old a\n"
    assert (tmp_path / "b.xml").read_text() == "old b\n"
    assert sorted(os.listdir(tmp_path)) == ["a.json", "b.xml"]


def test_outputs_written_together_keep_no_aside_copy_and_skip_a_removal_that_fails(tmp_path):
    """On success the kept-aside links are removed; a file to discard that cannot be
    removed (an old report's image that is now a folder) is left, not an error after
    the renames."""
    import os

    from mcverify import result

    (tmp_path / "a.json").write_text("old a\n")
    (tmp_path / "x.png").mkdir()
    with result.staged_writes():
        result.atomic_write(tmp_path / "a.json", "new a\n")
        result.discard(tmp_path / "x.png")
    assert (tmp_path / "a.json").read_text() == "new a\n"
    assert sorted(os.listdir(tmp_path)) == ["a.json", "x.png"]


def test_each_json_result_says_the_level_it_was_judged_at_and_its_own(tmp_path):
    """A mutation review: a result's ``details.alpha_check`` (the α the check ran at)
    written as the suite's family-wise α, or the result's ``alpha`` left at the check's
    own, passed every test. A check run at α = 0.05 in a suite judged at 0.01 (Holm over
    two): its JSON says alpha 0.01, alpha_check 0.05, its raw p and its adjusted p."""
    own = replace(_r("a", 0.03), alpha=0.05, passed=True)
    suite = SuiteResult.judge("s", [own, _r("b", 0.5)], alpha=0.01, seconds=1.0)
    mv.write_json(suite, str(tmp_path / "r.json"))
    a = json.loads((tmp_path / "r.json").read_text())["results"][0]
    assert (a["name"], a["alpha"], a["p_value"], a["passed"]) == ("a", 0.01, 0.03, True)
    assert a["details"]["alpha_check"] == 0.05 and a["details"]["p_adjusted"] == 0.06
