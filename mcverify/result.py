"""Results are data: frozen dataclasses, JSON and JUnit XML writers.

A statistical rejection is a result (``passed=False`` with readable ``messages``), never
an exception. Writers go through a temporary file and a rename, so a crash never leaves a
half-written report behind; symlinks are followed and FIFOs/devices written into, never
replaced (``atomic_write``).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import stat
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field, fields, is_dataclass, replace

import numpy as np

from . import stats
from .errors import InvalidArgument

__all__ = ["CheckResult", "SuiteResult", "write_json", "write_junit", "atomic_write",
           "staged_writes", "output_target", "json_text", "escape_controls"]


def _jsonable(v, _inside=frozenset()):
    record = is_dataclass(v) and not isinstance(v, type)
    if record or isinstance(v, (dict, list, tuple, set, frozenset)):
        # a container holding itself (a user's details with d["self"] = d) is written as
        # Python's repr writes it: it ended the run with "unexpected RecursionError" after
        # every check had run, naming none, and no --json was written
        if id(v) in _inside:
            return "{...}" if isinstance(v, dict) else "[...]"
        _inside = _inside | {id(v)}
    if record:                                          # as dataclasses.asdict wrote it
        return _jsonable({f.name: getattr(v, f.name) for f in fields(v)}, _inside)
    if isinstance(v, dict):
        return {str(k): _jsonable(x, _inside) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x, _inside) for x in v]
    if isinstance(v, np.ndarray):
        return _jsonable(v.tolist())
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (np.floating, float)):
        f = float(v)
        return f if math.isfinite(f) else str(f)
    if isinstance(v, np.bool_):
        return bool(v)
    if isinstance(v, (set, frozenset)):
        return [_jsonable(x, _inside) for x in sorted(v, key=repr)]
    if v is None or isinstance(v, (str, int)):
        return v
    # anything else a user's check put in its details (a Path, a complex): its text, not
    # a TypeError at the end of the run that writes no JSON and names no check
    return str(v)


def json_text(doc) -> str:
    """``doc`` as indented JSON text, as every output file writes it: numpy values as
    numbers, infinite and NaN floats as the strings "inf" and "nan" (the bare tokens NaN
    and Infinity are no JSON: strict parsers such as jq's or JavaScript's refuse them)."""
    return json.dumps(_jsonable(doc), indent=2, allow_nan=False) + "\n"


def _same(a, b) -> bool:
    """``a == b`` for a result's fields: arrays compared as arrays (their ``==`` is an
    array, which a dict's or a tuple's comparison cannot read as true or false) and NaN
    equal to NaN, so a result equals its copy, pickled or deep-copied."""
    if a is b:
        return True
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        nan = a.dtype.kind in "fc" and b.dtype.kind in "fc"
        return a.shape == b.shape and bool(np.array_equal(a, b, equal_nan=nan))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)) and type(a) is type(b):
        return len(a) == len(b) and all(map(_same, a, b))
    if isinstance(a, (float, np.floating)) and isinstance(b, (float, np.floating)):
        return a == b or (math.isnan(a) and math.isnan(b))
    return bool(a == b)


@dataclass(frozen=True)
class CheckResult:
    """One check's verdict.

    ``passed`` is true iff no deterministic failure was found (``failures`` empty: NaN
    samples, points outside the domain, a pdf that does not integrate to 1, ...) and the
    p-value, if the check has one, exceeds ``alpha``. ``p_value`` is None for checks
    that are deterministic (e.g. an inverse round trip).
    ``bool(result)`` is ``passed``, so ``assert result`` fails a test where the check
    failed.
    ``str(result)`` (``print``) is its ``summary()`` and ``messages``, a line each;
    ``repr`` gives every field.

    ``details`` holds small JSON-able facts (sub-test p-values, worst cells, seeds);
    ``artifacts`` holds the large arrays a report draws (a histogram with its expected
    counts, p-value and colour-difference maps, the compared images). JSON summaries
    leave ``artifacts`` out.
    """

    name: str
    passed: bool
    p_value: float | None
    statistic: float | None
    alpha: float
    n_samples: int
    seconds: float
    details: dict = field(default_factory=dict)
    messages: tuple[str, ...] = ()
    failures: tuple[str, ...] = ()
    artifacts: dict = field(default_factory=dict, repr=False)

    def __eq__(self, other) -> bool:
        # the dataclass's own compared the fields as tuples: a result holding arrays (a
        # histogram, a p-value map) raised "The truth value of an array ... is ambiguous"
        # against its own pickled copy, and one with a NaN was unequal to it
        if type(other) is not type(self):
            return NotImplemented
        return all(_same(getattr(self, f.name), getattr(other, f.name)) for f in fields(self))

    def __bool__(self) -> bool:
        # ``assert mv.check_sampler(...)`` held for every result, a failed one too: a
        # dataclass is always true. It is the verdict now, as ``passed`` says.
        return bool(self.passed)

    @staticmethod
    def decide(p_value, alpha, failures) -> bool:
        return not failures and (p_value is None or p_value > alpha)

    def with_alpha(self, alpha: float, p_adjusted: float | None) -> "CheckResult":
        """The same result judged at a family-wise level: ``p_adjusted`` (Holm/Šidák)
        compared with ``alpha``."""
        details = dict(self.details, p_adjusted=p_adjusted, alpha_check=self.alpha)
        return replace(self, alpha=alpha, details=details,
                       passed=self.decide(p_adjusted, alpha, self.failures))

    def summary(self) -> str:
        verdict = "PASS" if self.passed else "FAIL"
        p = "" if self.p_value is None else f" p={self.p_value:.3g}"
        padj = self.details.get("p_adjusted")
        if padj is not None:
            p += f" p_adj={padj:.3g}"
        why = ("  " + "; ".join(self.failures)) if self.failures else ""
        return f"{verdict} {self.name}{p} ({self.seconds:.2f}s){why}"

    def __str__(self) -> str:
        # print(result) was the dataclass's repr: a failed compare_images' 50 rejected
        # blocks, some 7,000 characters of details, before the messages saying where
        # (the lines mcverify check prints for a failed check, which also escapes the
        # control characters a terminal would act on)
        return "\n".join([self.summary(), *("    " + m for m in self.messages)])

    def _repr_pretty_(self, printer, cycle) -> None:
        # IPython and Jupyter show a bare result with this, not repr (some 7,000
        # characters of details for a failed image)
        printer.text(str(self))

    def to_dict(self, *, arrays: bool = False) -> dict:
        """JSON-able dict. ``artifacts`` (bulky arrays) are left out unless
        ``arrays=True`` (reports ask for them on failed checks)."""
        # the fields as they are (dataclasses.asdict recursed into a details dict that
        # holds itself); _jsonable makes the copy
        d = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "artifacts"}
        if arrays:
            d["artifacts"] = self.artifacts
        return _jsonable(d)


@dataclass(frozen=True)
class SuiteResult:
    """Results of a suite judged with one family-wise ``alpha``."""

    name: str
    results: tuple[CheckResult, ...]
    alpha: float
    correction: str
    seconds: float
    provenance: dict = field(default_factory=dict)
    skipped: tuple[tuple[str, str], ...] = ()
    canary: tuple[CheckResult, ...] = ()

    @property
    def canary_bitten(self) -> bool:
        """True iff every planted bug was rejected (the judge has teeth)."""
        return all(not c.passed for c in self.canary)

    @property
    def passed(self) -> bool:
        return all(r.passed for r in self.results) and self.canary_bitten

    def __bool__(self) -> bool:
        return self.passed             # as CheckResult's: ``assert suite`` is the verdict

    def toothless(self) -> list[str]:
        """A line for each canary (planted bug) the judge did not reject."""
        return [f"FAIL judge has no teeth: planted bug {c.name!r} was not rejected"
                + ("" if c.p_value is None else f" (p={c.p_value:.3g})")
                for c in self.canary if c.passed]

    def counts(self) -> str:
        """``N passed, M failed (family-wise alpha=A by holm; canaries bitten; Ts)``."""
        failed = sum(not r.passed for r in self.results)
        canaries = canary_words(len(self.canary), self.canary_bitten)
        return (f"{len(self.results) - failed} passed, {failed} failed (family-wise "
                f"alpha={self.alpha:g} by {self.correction}; {canaries}; {self.seconds:.1f}s)")

    def __str__(self) -> str:
        """What ``mcverify check`` prints of it (which also escapes control characters):
        each failed check (its summary and messages), each canary not bitten, and a last
        line with the counts (``print``
        gave the dataclass's repr: every check's details, thousands of characters each
        for a failed image)."""
        return "\n".join([*(str(r) for r in self.results if not r.passed),
                          *self.toothless(), f"suite {self.name}: {self.counts()}"])

    _repr_pretty_ = CheckResult._repr_pretty_

    @classmethod
    def judge(cls, name, results, *, alpha, correction="holm", **kw) -> "SuiteResult":
        """Re-judge ``results`` at family-wise level ``alpha``: adjusted p-values by
        Holm (default) or Šidák across the checks that have a p-value."""
        results = list(results)
        idx = [i for i, r in enumerate(results) if r.p_value is not None]
        raw = [results[i].p_value for i in idx]
        if correction == "holm":
            adj = stats.holm(raw)
        elif correction == "sidak":
            adj = stats.sidak(raw)
        elif correction == "none":
            adj = np.asarray(raw, dtype=float)
        else:
            raise ValueError(f"correction={correction!r}: expected 'holm', 'sidak' or 'none'")
        padj = dict(zip(idx, adj))
        judged = tuple(r.with_alpha(alpha, None if i not in padj else float(padj[i]))
                       for i, r in enumerate(results))
        return cls(name, judged, alpha, correction, **kw)

    def to_dict(self) -> dict:
        return _jsonable({
            "suite": self.name, "passed": self.passed, "alpha": self.alpha,
            "correction": self.correction, "seconds": self.seconds,
            "n_checks": len(self.results),
            "n_failed": sum(not r.passed for r in self.results),
            "canary_bitten": self.canary_bitten,
            "provenance": self.provenance,
            "results": [r.to_dict() for r in self.results],
            "canary": [c.to_dict() for c in self.canary],
            "skipped": [{"check": c, "reason": why} for c, why in self.skipped],
        })


def canary_words(count: int, bitten: bool, strong=str) -> str:
    """What a suite's line (and the report's page) says of its ``count`` canaries:
    "no canaries" where none ran (a suite run with ``canary=False`` said "canaries
    bitten" of none: a mutation review), else bitten or ``strong("NOT bitten")``."""
    if not count:
        return "no canaries"
    return "canaries " + ("bitten" if bitten else strong("NOT bitten"))


def shared_mode(base: int = 0o666) -> int:
    """``base`` under the process umask: the mode an ordinary ``open`` would give, for
    files and folders made by ``mkstemp``/``mkdtemp`` (which make them private)."""
    umask = os.umask(0)
    os.umask(umask)
    return base & ~umask


def output_target(path) -> tuple[str, str]:
    """Where a write to ``path`` lands and how: ``(target, "replace" | "stream")``.

    A symlink is followed to its target (the link stays a link). An existing FIFO or
    character device (``/dev/stdout``, ``/dev/null``, a pipe) is written into as it is
    ("stream"): replacing it with a plain file would destroy it. A regular file, or a path
    that does not exist yet, is written through a temporary file and a rename
    ("replace"). Anything else (a directory, a socket, a block device) is refused with
    ``InvalidArgument`` naming the path."""
    if not isinstance(path, (str, os.PathLike)) or not os.fspath(path):
        raise InvalidArgument(f"path={path!r}: give a file path (an empty path writes nothing)")
    path = os.fspath(path)
    if os.path.basename(path) in ("", ".", ".."):
        # "out/" names a folder: realpath dropped the slash, and a file named "out" was
        # written (or "f.json/" replaced the file f.json, which open() would refuse)
        raise InvalidArgument(f"{path}: ends in {os.path.basename(path) or os.sep!r}, "
                              "which names a folder; give a file path")
    target = os.path.realpath(path)
    try:    # the path itself, followed: /dev/stdout -> /proc/self/fd/1 -> "pipe:[N]", a
        mode = os.stat(path).st_mode    # link whose text realpath cannot resolve
    except (FileNotFoundError, NotADirectoryError):   # new (its folder may not exist yet)
        return target, "replace"
    if stat.S_ISREG(mode):
        return target, "replace"
    if stat.S_ISFIFO(mode) or stat.S_ISCHR(mode):
        return (target if os.path.exists(target) else os.path.abspath(path)), "stream"
    what = "a directory" if stat.S_ISDIR(mode) else "not a regular file, FIFO or character device"
    shown = path if target == os.path.abspath(path) else f"{path} (-> {target})"
    raise InvalidArgument(f"{shown}: is {what}; give a file path")


def atomic_write(path, data: str | bytes) -> None:
    """Write ``data`` (text as UTF-8, or bytes) to ``path`` without losing anything.

    A regular file (or a new one) is replaced through a temporary file in the same folder
    and a rename: readers see the old or the new content, never half of it, and on any
    failure the temporary file is removed and the old file is untouched. An existing
    file keeps its permission bits. A symlink is followed and its target written; a FIFO
    or character device is written into directly (see ``output_target``). Inside
    ``staged_writes`` the rename waits for the block's end."""
    target, how = output_target(path)
    # a lone surrogate (a non-UTF-8 file name in a check's message) has no UTF-8 bytes:
    # it is written as its escape, \udcff, rather than fail the write after the others
    payload = data.encode("utf-8", "backslashreplace") if isinstance(data, str) else data
    try:
        _write(target, how, payload, path)
    except OSError as e:    # named by the path asked for, not a temporary file's name
        raise OSError(e.errno, f"cannot write it ({e.strerror or e})", path) from None


#: The renames (temporary file, target, path as given) that the open ``staged_writes``
#: block makes at its end, and the files it removes then; None outside a block.
_STAGED: dict | None = None


@contextlib.contextmanager
def staged_writes():
    """Several outputs written as one: inside the block, ``atomic_write`` writes each
    regular file's temporary file and ``discard`` notes the files to remove, and the
    renames and removals are made together at its end, once every file is written; an
    error (a full disk on the last output) or Ctrl-C before then removes the temporary
    files, and every output is left as it was. ``check --json A --junit B`` whose JUnit
    write failed (ENOSPC) exited 2 with A replaced by this run's results beside B's
    last ones. A rename that fails (an immutable file, ``chattr +i``) undoes the ones
    before it: each replaced file is kept aside under a temporary name until all are
    renamed (a read-only review found A replaced beside an immutable B). A removal that
    fails leaves that old file behind (a report's image that is now a folder). A FIFO or
    device (``/dev/stdout``) is written into at once, as outside. Nested blocks join the
    outermost."""
    global _STAGED
    if _STAGED is not None:
        yield
        return
    _STAGED = {"renames": [], "removals": []}
    try:
        yield
        staged = _STAGED
        _STAGED = None
        _rename_all(staged["renames"])
        for path in staged["removals"]:
            with contextlib.suppress(OSError):
                os.remove(path)
    finally:
        if _STAGED is not None:
            staged, _STAGED = _STAGED, None
        for tmp, _, _ in staged["renames"]:
            if os.path.exists(tmp):
                os.unlink(tmp)


def _rename_all(renames) -> None:
    """Each (temporary file, target, path as given) renamed onto its target, all or none:
    a target that exists is kept aside (a hard link beside it) until every rename is
    made, and put back, with the new targets removed, where one fails."""
    done = []           # (target, its old content's link, or None where it was new)
    try:
        for tmp, target, path in renames:
            again = any(t == target for t, _ in done)     # one file named twice
            kept = None if again else _kept_aside(target)
            try:
                os.replace(tmp, target)
            except OSError as e:
                if kept:
                    os.unlink(kept)
                raise OSError(e.errno, f"cannot write it ({e.strerror or e})", path) from None
            if not again:
                done.append((target, kept))
    except BaseException:
        for target, kept in reversed(done):
            with contextlib.suppress(OSError):
                if kept:
                    os.replace(kept, target)
                else:
                    os.unlink(target)
        raise
    for _, kept in done:
        if kept:
            with contextlib.suppress(OSError):
                os.unlink(kept)


def _kept_aside(target: str) -> str | None:
    """A hard link to ``target`` beside it under a temporary name (None where there is
    no such file, or the file system takes no link: that one is then not put back)."""
    if not os.path.isfile(target):
        return None
    kept = os.path.join(os.path.dirname(target), f".old-{os.getpid()}-{_name_part(target)}")
    try:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(kept)
        os.link(target, kept)
    except OSError:
        return None
    return kept


def discard(path) -> None:
    """Remove the file ``path`` if it exists; inside ``staged_writes``, at the block's end
    with its renames (a report's images that the new report no longer names)."""
    if _STAGED is not None:
        _STAGED["removals"].append(os.fspath(path))
        return
    with contextlib.suppress(FileNotFoundError):
        os.remove(path)


#: Most bytes of a target's name that its temporary file's name repeats: with ".tmp-" and
#: mkstemp's 8 characters it stays within NAME_MAX (255 bytes) of common file systems.
_TMP_NAME_BYTES = 200


def _name_part(target: str) -> str:
    """``target``'s file name, for a temporary file's name beside it, where that fits the
    folder's limit on a name (".tmp-XXXXXXXX" + a 250-byte name failed with "File name
    too long", after the run, though the target itself could be written); else ''."""
    base = os.path.basename(target)
    return base if len(os.fsencode(base)) <= _TMP_NAME_BYTES else ""


def _write(target: str, how: str, payload: bytes, path) -> None:
    if how == "stream":
        with open(target, "wb") as f:
            f.write(payload)
        return
    try:
        mode = stat.S_IMODE(os.stat(target).st_mode)
    except FileNotFoundError:
        mode = shared_mode()    # mkstemp makes 0600; results are for reading
    folder = os.path.dirname(target)
    os.makedirs(folder, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=".tmp-", suffix=_name_part(target))
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(payload)
        os.chmod(tmp, mode)
        if _STAGED is not None:     # renamed at the end of the block, with the others
            _STAGED["renames"].append((tmp, target, os.fspath(path)))
        else:
            os.replace(tmp, target)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_json(result, path: str, *, provenance: dict | None = None) -> None:
    """Write a ``CheckResult`` or ``SuiteResult`` as indented JSON, atomically; a
    ``CheckResult`` written on its own (``compare``, ``render-check``) carries the run's
    ``provenance`` as a suite's does."""
    if not isinstance(result, (CheckResult, SuiteResult)):
        # was "AttributeError: 'dict' object has no attribute 'to_dict'", as write_junit
        # names what it expects
        raise InvalidArgument(f"write_json: expected a CheckResult or SuiteResult, got "
                              f"{type(result).__name__}")
    d = result.to_dict()
    if provenance is not None:
        d["provenance"] = _jsonable(provenance)
    atomic_write(path, json_text(d))


#: Characters XML 1.0 cannot hold, not even as references: C0 controls but tab, LF and CR
#: (an ANSI colour code in an exception's message), lone surrogates (a file name that is
#: not UTF-8, decoded by Python), U+FFFE and U+FFFF; and DEL and the C1 controls, which
#: XML discourages and a terminal may act on (U+009B is a one-character CSI).
_NOT_XML = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x9f\ud800-\udfff\ufffe\uffff]")


def escape_controls(text) -> str:
    """``text`` with each character XML cannot hold written as its escape (``\\x1b``):
    for the JUnit file, and for the error line on a terminal, where a user's message's
    ANSI escape or BEL would act instead of showing."""
    return _NOT_XML.sub(lambda m: m.group().encode("unicode_escape").decode("ascii"),
                        str(text))


_xml = escape_controls       # the JUnit writer's name for it


def write_junit(suite: SuiteResult, path: str) -> None:
    """Write a suite as JUnit XML (one testcase per check, canaries as their own class,
    each skipped check with ``<skipped message=REASON>``, as the JSON lists them).
    Characters XML cannot hold are written as escapes (``_xml``): the file always parses."""
    if not isinstance(suite, SuiteResult):
        raise InvalidArgument(f"write_junit: expected a SuiteResult (what run_suite and "
                              f"`mcverify check` make), got {type(suite).__name__}; a single "
                              "CheckResult goes to write_json")
    cases = list(suite.results) + [replace(c, name="canary." + c.name, passed=not c.passed)
                                   for c in suite.canary]
    root = ET.Element("testsuite", name=_xml(f"mcverify.{suite.name}"),
                      tests=str(len(cases) + len(suite.skipped)),
                      failures=str(sum(not c.passed for c in cases)),
                      skipped=str(len(suite.skipped)), time=f"{suite.seconds:.3f}")
    props = ET.SubElement(root, "properties")
    for k, v in suite.provenance.items():
        ET.SubElement(props, "property", name=_xml(k), value=_xml(json.dumps(_jsonable(v))))
    n_checks = len(suite.results)
    for i, c in enumerate(cases):
        canary = i >= n_checks      # their own class, as this docstring has always said
        tc = ET.SubElement(root, "testcase", name=_xml(c.name), time=f"{c.seconds:.3f}",
                           classname=_xml(f"mcverify.{suite.name}"
                                          + (".canary" if canary else "")))
        if not c.passed:
            f = ET.SubElement(tc, "failure", message=_xml(c.summary()))
            # a check failed on its p-value alone, or a canary not bitten, had an empty
            # text, which CI views show as the failure's whole story
            f.text = _xml("\n".join(c.failures + c.messages) or (
                "the planted bug passed: the checks cannot see it" if canary else
                f"rejected at family-wise alpha={suite.alpha:g} ({suite.correction}): "
                + c.summary()))
        elif c.messages:
            ET.SubElement(tc, "system-out").text = _xml("\n".join(c.messages))
    for name, why in suite.skipped:     # were in the JSON only: CI showed nothing skipped
        tc = ET.SubElement(root, "testcase", classname=_xml(f"mcverify.{suite.name}"),
                           name=_xml(name), time="0.000")
        ET.SubElement(tc, "skipped", message=_xml(why))
    ET.indent(root)
    atomic_write(path, ET.tostring(root, encoding="unicode", xml_declaration=True) + "\n")
