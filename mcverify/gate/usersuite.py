"""The user's own checks in the gate: ``--suite MODULE:ATTR`` and ``[tool.mcverify]``.

A user suite is a Python object named ``package.module:attribute``: a list (or tuple)
of :class:`mcverify.gate.suites.Check`, or a callable returning one. The gate runs it
like a built-in suite: one family-wise α, the canaries, seeds derived from the check
names, JSON and JUnit.

``mcverify check`` without ``--suite`` looks for ``pyproject.toml`` from the current
directory upward; the first one found is the project's. If it has a ``[tool.mcverify]``
table, its settings apply (command-line options win)::

    [tool.mcverify]
    suite = "mychecks:suite"      # or a list of MODULE:ATTR
    alpha = 0.01                  # family-wise significance level
    seed = 0
    path = ["."]                  # import roots, relative to pyproject.toml
"""

from __future__ import annotations

import dataclasses
import importlib
import os
import sys
from dataclasses import dataclass

from ..errors import EnvironmentProblem, InvalidArgument
from .suites import Check

__all__ = ["ProjectConfig", "find_config", "load_user_suite", "is_user_suite"]

#: Keys of ``[tool.mcverify]`` and their types.
_KEYS = {"suite": (str, list), "alpha": (float, int), "seed": (int,), "path": (str, list)}


@dataclass(frozen=True)
class ProjectConfig:
    """``[tool.mcverify]`` of a project's ``pyproject.toml``."""

    file: str
    suites: tuple[str, ...] = ()
    alpha: float | None = None
    seed: int | None = None
    path: tuple[str, ...] = (".",)

    @property
    def root(self) -> str:
        return os.path.dirname(self.file)


def is_user_suite(name: str) -> bool:
    """Whether a ``--suite`` value names a user suite (``MODULE:ATTR``)."""
    return ":" in name


def find_config(start: str | None = None) -> ProjectConfig | None:
    """``[tool.mcverify]`` of the first ``pyproject.toml`` from ``start`` (default: the
    current directory) upward; None if that file has no such table or there is none.
    A malformed table raises ``InvalidArgument`` naming the file and the key."""
    folder = os.path.abspath(start or os.getcwd())
    while True:
        candidate = os.path.join(folder, "pyproject.toml")
        if os.path.isfile(candidate):
            return _read_config(candidate)
        parent = os.path.dirname(folder)
        if parent == folder:
            return None
        folder = parent


def _read_config(file: str) -> ProjectConfig | None:
    try:
        import tomllib
    except ImportError:  # Python 3.10
        import tomli as tomllib
    with open(file, "rb") as f:
        data = f.read()
    if data.startswith(b"\xef\xbb\xbf"):   # was "Invalid statement (at line 1, column 1)"
        raise InvalidArgument(f"{file}: starts with a UTF-8 byte-order mark, which TOML "
                              "does not allow (pip cannot read it either); save it as "
                              "UTF-8 without one")
    try:
        doc = tomllib.loads(data.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:   # TOML is UTF-8
        raise InvalidArgument(f"{file}: not valid TOML ({e})") from None
    tool = doc.get("tool", {})
    if not isinstance(tool, dict):
        raise InvalidArgument(f"{file}: tool = {tool!r}: must be a table ([tool.mcverify] "
                              "is read from it)")
    table = tool.get("mcverify")
    if table is None:
        return None
    if not isinstance(table, dict):
        raise InvalidArgument(f"{file}: [tool.mcverify] must be a table")
    for key, value in table.items():
        if key not in _KEYS:
            raise InvalidArgument(f"{file}: [tool.mcverify] {key!r}: unknown key; "
                                  f"valid keys: {', '.join(sorted(_KEYS))}")
        if not isinstance(value, _KEYS[key]) or isinstance(value, bool):
            raise InvalidArgument(f"{file}: [tool.mcverify] {key} = {value!r}: expected "
                                  f"{' or '.join(t.__name__ for t in _KEYS[key])}")

    def strings(key):
        v = table.get(key)
        items = [v] if isinstance(v, str) else list(v or [])
        bad = [x for x in items if not isinstance(x, str)]
        if bad:
            raise InvalidArgument(f"{file}: [tool.mcverify] {key}: {bad[0]!r} is not a string")
        return tuple(items)

    suites = strings("suite")
    for s in suites:
        if not is_user_suite(s):
            from .suites import SUITES

            if s not in SUITES and s != "mitsuba":
                raise InvalidArgument(f"{file}: [tool.mcverify] suite {s!r}: expected "
                                      "MODULE:ATTR or a built-in suite name")
    alpha = table.get("alpha")
    if alpha is not None and not 0.0 < alpha < 1.0:
        raise InvalidArgument(f"{file}: [tool.mcverify] alpha = {alpha}: must be strictly "
                              "between 0 and 1")
    seed = table.get("seed")
    if seed is not None and not 0 <= seed <= 2 ** 63 - 1:    # as --seed
        raise InvalidArgument(f"{file}: [tool.mcverify] seed = {seed}: must be in "
                              "[0, 2**63 - 1]")
    if "suite" in table and not suites:
        raise InvalidArgument(f"{file}: [tool.mcverify] suite: an empty list; name at least "
                              "one suite, or leave the key out for the default suite")
    if len(set(suites)) != len(suites):
        raise InvalidArgument(f"{file}: [tool.mcverify] suite: "
                              f"{next(s for s in suites if suites.count(s) > 1)!r} is listed "
                              "twice")
    path = strings("path") or (".",)
    for p in path:      # a misspelt root was accepted without a word
        if not os.path.isdir(os.path.join(os.path.dirname(file), p)):
            raise InvalidArgument(f"{file}: [tool.mcverify] path {p!r}: no such folder "
                                  "(import roots are relative to pyproject.toml)")
    return ProjectConfig(file=file, suites=suites, alpha=None if alpha is None else
                         float(alpha), seed=seed, path=path)


def _import_roots(roots) -> None:
    for r in reversed([os.path.abspath(r) for r in roots]):
        if r not in sys.path:
            sys.path.insert(0, r)


def load_user_suite(spec: str, *, roots=(".",), option: str = "--suite") -> list[Check]:
    """The checks named by ``spec`` (``package.module:attribute``).

    ``roots`` are put on ``sys.path`` first (the current directory by default), as
    pytest does with a project's root. The attribute is a list or tuple of ``Check``,
    or a callable returning one. Names must be unique (each seed derives from its name).
    ``option`` names where ``spec`` was given, in errors (``--suite``, or the file and
    key of a ``[tool.mcverify]`` table).
    """
    module_name, _, attr = spec.partition(":")
    if not module_name or not attr:
        raise InvalidArgument(f"{option} {spec!r}: expected MODULE:ATTR, e.g. "
                              "mypkg.checks:suite")
    _import_roots(roots)
    try:
        module = importlib.import_module(module_name)
    except ImportError as e:
        raise InvalidArgument(f"{option} {spec!r}: cannot import {module_name!r} ({e}); "
                              f"import roots: {', '.join(roots)}") from None
    except (Exception, SystemExit) as e:   # noqa: BLE001 - the user's module failed
        where = ""
        if isinstance(e, SyntaxError) and e.filename:
            where = f" at {e.filename}:{e.lineno}"
        raise InvalidArgument(f"{option} {spec!r}: importing {module_name!r} raised "
                              f"{type(e).__name__}{where}: {e}") from None
    obj = module
    for part in attr.split("."):
        if not hasattr(obj, part):
            raise InvalidArgument(f"{option} {spec!r}: {module_name} has no attribute "
                                  f"{attr!r}")
        obj = getattr(obj, part)
    if callable(obj) and not isinstance(obj, (list, tuple)):
        try:
            obj = obj()
        except (Exception, SystemExit) as e:   # noqa: BLE001 - the user's builder failed
            raise InvalidArgument(f"{option} {spec!r}: {attr}() raised {type(e).__name__}: "
                                  f"{e}") from None
    if not isinstance(obj, (list, tuple)):
        raise InvalidArgument(f"{option} {spec!r}: expected a list of "
                              f"mcverify.gate.suites.Check, got {type(obj).__name__}")
    seen = set()
    for i, c in enumerate(obj):
        if not isinstance(c, Check):
            raise InvalidArgument(f"{option} {spec!r}: item {i} is a {type(c).__name__}, "
                                  "not a mcverify.gate.suites.Check(name, run, tags, "
                                  "verifies)")
        if not isinstance(c.name, str) or not c.name:
            raise InvalidArgument(f"{option} {spec!r}: item {i} is named {c.name!r}: a "
                                  "check's name must be a non-empty string (its seed "
                                  "derives from it)")
        try:
            c.name.encode()     # the seed derives from its UTF-8 bytes; JSON holds them
        except UnicodeEncodeError:
            raise InvalidArgument(f"{option} {spec!r}: item {i} is named {c.name!r}: not "
                                  "encodable as UTF-8 (a lone surrogate, as a non-UTF-8 "
                                  "file name decodes to); name it in text") from None
        if not callable(c.run):
            raise InvalidArgument(f"{option} {spec!r}: check {c.name!r}: run={c.run!r} is "
                                  "not callable")
        if "canary" in (c.tags or ()):
            # reserved for mcverify's planted bugs: the progress line read such a check
            # as one ("NOT bitten") where its verdict was a plain FAIL
            raise InvalidArgument(f"{option} {spec!r}: check {c.name!r} is tagged "
                                  "'canary', which marks mcverify's own planted bugs "
                                  "(judged as 'bitten'); use another tag")
        if c.name in seen:
            raise InvalidArgument(f"{option} {spec!r}: two checks are named {c.name!r} "
                                  "(seeds derive from names; make them unique)")
        seen.add(c.name)
    recipe = (_rebuild, (spec, tuple(os.path.abspath(r) for r in roots),
                         _imported_digest(module)))
    return [c if c.source is not None else dataclasses.replace(c, source=recipe) for c in obj]


#: SHA-256 of each user-suite module's file as this process first imported it: Python
#: keeps a module once imported, so a long-lived (Dask) worker runs that version.
_DIGESTS: dict[str, str | None] = {}


def _imported_digest(module) -> str | None:
    from .reference import file_hash

    if module.__name__ not in _DIGESTS:
        try:
            _DIGESTS[module.__name__] = file_hash(getattr(module, "__file__", None))
        except (OSError, TypeError):    # no file (a namespace package, a built-in)
            _DIGESTS[module.__name__] = None
    return _DIGESTS[module.__name__]


def _rebuild(spec: str, roots: tuple, digest: str | None = None) -> list[Check]:
    """How a worker process rebuilds a user suite: the same import, the same roots, and
    the module as the client imported it (a Dask worker that imported an earlier version
    of it ran those checks, as if they were the current ones)."""
    checks = load_user_suite(spec, roots=roots)
    module = sys.modules[spec.partition(":")[0]]
    if digest is not None and _imported_digest(module) != digest:
        raise EnvironmentProblem(
            f"suite {spec!r}: worker {os.uname().nodename} (pid {os.getpid()}) runs another "
            f"version of {getattr(module, '__file__', module.__name__)} than this run "
            "(imported before it was edited, or a different file); restart the workers (a "
            "worker keeps a module it has imported)")
    return checks
