"""mcverify command line: the CI gate and its tools.

Exit codes: 0 all checks passed (images equal); 1 a check failed, a canary survived or
images differ; 2 bad input or environment, with one line on stderr naming what and where;
130 interrupted (Ctrl-C), with nothing written (or, during the writes, all); 141 the reader
of stdout left; 143 terminated (SIGTERM), as on Ctrl-C.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import difflib
import glob
import json
import os
import signal
import stat
import sys
import threading
import textwrap
import time

from .._validate import decimal_int
from ..errors import EnvironmentProblem, InvalidArgument, MissingReference, interrupted
from ..result import escape_controls, staged_writes

EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130
EXIT_BROKEN_PIPE = 141         # 128 + SIGPIPE, as a shell reports a command whose reader left
EXIT_TERMINATED = 143          # 128 + SIGTERM, as a shell reports a command it terminated
#: Seeds must fit the path tracer's counter-based RNG (and numpy's SeedSequence).
MAX_SEED = 2 ** 63 - 1

EPILOG = """exit codes:
  0    all checks passed (compare, render-check: the images agree)
  1    a check failed or a canary survived (compare, render-check: the images differ)
  2    bad input or environment: one line on stderr names what and where; no output is
       written or replaced
  130  interrupted (Ctrl-C); output files are left as they were (one while they are
       written, at the end, waits until all are)
  141  the reader of stdout left (mcverify list | head): no message
  143  terminated (SIGTERM: a cancelled CI job); stops as on Ctrl-C

output files (--json, --junit) are written when the run ends: a regular file is replaced
atomically, a symlink is followed to its target, a FIFO or device (/dev/stdout) is
written into, missing folders are made; paths are checked before any work; an option
given twice exits 2"""


def _command_epilog(ok: str, failed: str | None = None) -> str:
    """A command's exit codes: what its own 0 (and 1, where it judges) mean, then those
    every command shares. Only check, compare and render-check showed any: ``report
    --help`` did not say that a failed check exits 1, nor ``bench --help`` that no
    ratio does."""
    lines = EPILOG.splitlines()
    own = [f"  0    {ok}"] + ([f"  1    {failed}"] if failed else [])
    return "\n".join(lines[:1] + own + lines[3:])


class _Formatter(argparse.RawDescriptionHelpFormatter):
    """Help with each option's default (when it has one worth showing)."""

    def _get_help_string(self, action):
        text = action.help or ""
        # not ``in (None, False)``: 0 == False, so --seed's default of 0 went unsaid
        if ("%(default)" not in text and action.default is not None
                and action.default is not False
                and action.default is not argparse.SUPPRESS and action.option_strings):
            text += " (default: %(default)s)"
        return text


class _Once(argparse.Action):
    """An option that takes one value and may be given once: argparse keeps the last of
    repeated ones, so ``--suite A --suite B`` ran B alone without a word."""

    def __call__(self, parser, namespace, values, option_string=None):
        given = namespace.__dict__.setdefault("_given_once", {})
        if self.dest in given:
            parser.error(f"{option_string} given twice ({given[self.dest]!r} and {values!r}); "
                         "give it once")
        given[self.dest] = values
        setattr(namespace, self.dest, values)


class _Parser(argparse.ArgumentParser):
    def __init__(self, *a, **kw):
        kw.setdefault("formatter_class", _Formatter)
        # no prefixes of options: `reference build --sp 4` (a typo of --seed, or of
        # --spp) rebuilt every reference at 4 spp as --spp 4, and `check --sui default`
        # ran as --suite (until 7 December; a read-only review's accident); a prefix is
        # now an unknown option, with "did you mean" (_unknown_option_hint)
        kw.setdefault("allow_abbrev", False)
        if kw.get("description"):   # the raw formatter keeps the epilog's layout, not this
            kw["description"] = textwrap.fill(kw["description"], 88)
        super().__init__(*a, **kw)

    def add_argument(self, *args, **kw):
        # every option with one value (not --param, which collects; not flags)
        if args and args[0].startswith("-") and kw.get("action", "store") == "store" \
                and kw.get("nargs") is None:
            kw["action"] = _Once
        return super().add_argument(*args, **kw)

    def _check_value(self, action, value):
        # a misspelt command or choice: "did you mean", as argparse says it from 3.14 on
        if action.choices is not None and value not in action.choices:
            close = difflib.get_close_matches(value, list(action.choices), n=1)
            if close:
                raise argparse.ArgumentError(action, f"invalid choice: {value!r}; did you "
                                                     f"mean {close[0]!r}?")
        super()._check_value(action, value)

    def error(self, message):  # one line, exit 2 (argparse's own convention too)
        # this parser's own help: a command's options are in `mcverify check --help`,
        # not in `mcverify --help`, which every error named (an outside review)
        self.exit(EXIT_BAD_INPUT, f"mcverify: error: {message} (see `{self.prog} --help`)\n")


def _same_file(a: str, b: str) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _writable(option: str, path: str | None, inputs=()) -> None:
    """Fail before any work if ``path`` cannot be written as an output: an empty path, a
    directory, a socket, a folder that cannot be made or written, or one of ``inputs``
    (writing it would replace the data being read)."""
    from ..result import output_target

    if path is None:
        return
    if not path.strip():
        raise InvalidArgument(f"{option} {path!r}: empty path; give a file path")
    if path == "-":     # was written as a file named '-', where a pipe read nothing
        raise InvalidArgument(f"{option} -: is not stdout here (it would be a file named "
                              "'-'); give a file path, or /dev/stdout, where the file "
                              "follows the printed lines")
    try:
        target, how = output_target(path)
    except InvalidArgument as e:
        raise InvalidArgument(f"{option} {e}") from None
    for other in inputs:
        # by path too: an input the run makes (the reference a render check builds, its
        # folder missing until then) does not exist yet, and the output would replace it
        if other and (_same_file(target, other)
                      or target == os.path.realpath(other)):
            raise InvalidArgument(f"{option} {path}: is also an input ({other}); writing "
                                  "it would replace the data being read; give another path")
    if how == "stream":
        if not os.access(target, os.W_OK):
            raise InvalidArgument(f"{option} {path}: {target} is not writable")
        return
    folder = os.path.dirname(target)
    # The writer makes missing folders; here nothing is created (a run refused later
    # must leave nothing behind): the nearest existing folder must be one we can write.
    existing = os.path.abspath(folder or ".")
    while not os.path.exists(existing):
        existing = os.path.dirname(existing)
    if not os.path.isdir(existing):
        raise InvalidArgument(f"{option} {path}: cannot create folder {folder} "
                              f"({existing} is not a folder)")
    import tempfile

    try:  # the very operation the writer will do: a temporary file in that folder
        fd, probe = tempfile.mkstemp(dir=existing, prefix=".tmp-probe-")
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise InvalidArgument(f"{option} {path}: cannot create a file in folder {existing} "
                              f"({e.strerror})") from None
    if _others_in_sticky_folder(target):
        raise InvalidArgument(f"{option} {path}: cannot replace it: it is another user's "
                              f"file in folder {os.path.dirname(target)}, whose sticky bit "
                              "(as /tmp's) lets only its owner replace it; give another path")


def _others_in_sticky_folder(target: str) -> bool:
    """Whether ``target`` is a file that this user cannot replace by renaming onto it: in
    a sticky folder (``/tmp``, a shared drop folder), another user's file in a folder not
    this user's either. It was found at the run's end: ``--json /tmp/results.json`` left
    by a colleague exited 2, "cannot write it (Operation not permitted)", after all the
    run's work (an outside review)."""
    if not hasattr(os, "geteuid"):
        return False
    try:
        st, folder = os.stat(target), os.stat(os.path.dirname(target))
    except OSError:     # a new file: the probe above tried its folder
        return False
    return bool(folder.st_mode & stat.S_ISVTX) and os.geteuid() not in (0, st.st_uid,
                                                                         folder.st_uid)


def _distinct_outputs(*pairs) -> None:
    """Two output options naming the same file would overwrite each other; one naming a
    folder the other is written into (``--junit out --report out``) would fail the
    second write at the run's end, after the first (each path alone is writable)."""
    given = [(o, p, os.path.realpath(p)) for o, p in pairs if p]
    for i, (o1, p1, r1) in enumerate(given):
        for o2, p2, r2 in given[i + 1:]:
            if r1 == r2:
                raise InvalidArgument(f"{o1} {p1} and {o2} {p2}: the same file; give "
                                      "two paths")
            for (oa, pa, ra), (ob, pb, rb) in (((o1, p1, r1), (o2, p2, r2)),
                                               ((o2, p2, r2), (o1, p1, r1))):
                if rb.startswith(ra.rstrip(os.sep) + os.sep):
                    raise InvalidArgument(
                        f"{o1} {p1} and {o2} {p2}: {oa} names a file to write and {ob} "
                        f"a file inside it, as a folder; give paths apart")


def _shown(text) -> str:
    """``text`` as a line of the terminal or CI log shows it: the characters a terminal
    acts on (an ANSI escape, BEL, NUL or carriage return in an exception's text that a
    check's message quotes) written as their escapes (``\\x1b``), as the error line and
    the JUnit file write them: they reached stdout raw, where they coloured, rang or hid
    the verdict's text."""
    return escape_controls(text).replace("\r", "\\r")


def _verdict(r, check, alpha: float | None) -> str:
    """What the final verdict on ``r`` will be, as far as it is known now.

    Canaries are judged alone at their own level: "bitten" (rejected, as they must be)
    or "NOT bitten". A check with a deterministic failure is "FAIL"; one without a
    p-value, or whose raw p exceeds the family-wise ``alpha``, is "ok" (Holm only raises
    p-values). Otherwise the verdict waits for Holm across all checks: "pending"."""
    if check is not None and "canary" in check.tags:
        return "bitten" if not r.passed else "NOT bitten"
    if r.failures:
        return "FAIL"
    if alpha is None:
        return "ok" if r.passed else "FAIL"
    if r.p_value is None or r.p_value > alpha:
        return "ok"
    return f"pending (p={r.p_value:.2g}; Holm across all checks decides)"


#: The terminal stream whose progress line was written without its newline, to be
#: overwritten by the next one; empty where none is.
_OPEN_LINE: list = []


def _overwrites(stream) -> bool:
    """Whether ``stream`` is a terminal that can overwrite a line ("\\r\\033[K"): not
    where ``TERM=dumb`` says it cannot (Emacs' compilation and shell buffers, which are
    terminals and showed each progress line as '^[[K[3/8] …', all on one line)."""
    return stream.isatty() and os.environ.get("TERM") != "dumb"


def _overwrite(stream, text: str, done: bool) -> None:
    """``text`` over a terminal's progress line, left open for the next unless ``done``."""
    stream.write("\r\033[K" + text + ("\n" if done and text else ""))
    stream.flush()
    _OPEN_LINE[:] = [] if done else [stream]


def _end_progress_line() -> None:
    """End a terminal's open progress line, so that the line that ends a run (an error,
    an interrupt) starts a line of its own: it was written on the same line, "[1/6] ok ok
    (0.0s)mcverify: error: check 'gpu': no GPU here"."""
    for stream in _OPEN_LINE:
        stream.write("\n")
        stream.flush()
    _OPEN_LINE.clear()


def _progress(stream, verdicts: bool = True, alpha: float | None = None):
    """Progress lines ``[i/total] name verdict (seconds)``. ``alpha``: the family-wise
    level the results are judged at later (None: each result's verdict is final)."""
    tty = _overwrites(stream)

    def show(i, total, r, check=None):
        verdict = _verdict(r, check, alpha) if verdicts else "done"
        line = f"[{i}/{total}] {_shown(r.name)} {verdict} ({r.seconds:.1f}s)"
        if tty:
            _overwrite(stream, line, i == total)
        else:
            stream.write(line + "\n")
            stream.flush()

    return show


def _pool(args):
    """The executor of ``-j`` / ``--dask`` / ``--dask-scheduler-file`` (``executors``)."""
    from .executors import Pool

    return Pool(jobs=args.jobs, dask=args.dask, dask_scheduler_file=args.dask_scheduler_file)


def _pool_inputs(args) -> list[str]:
    """The executor's input file, ``--dask-scheduler-file``: an output naming it replaced
    it with the run's results, and every later run (and client) refused it."""
    return [args.dask_scheduler_file] if args.dask_scheduler_file else []


def _add_pool_options(parser) -> None:
    parser.add_argument("-j", "--jobs", type=decimal_int, default=1, metavar="N",
                        help="run independent units (checks, passes) on N local worker "
                             "processes; 1: in this process. Results are identical")
    parser.add_argument("--dask", metavar="tcp://HOST:PORT",
                        help="run the units on this Dask scheduler's workers")
    parser.add_argument("--dask-scheduler-file", metavar="FILE",
                        help="run the units on the Dask cluster this scheduler file names")


def _add_refs_option(parser) -> None:
    parser.add_argument("--refs", metavar="DIR",
                        help="folder of reference scenes (NAME/scene.xml, NAME/ref/) that "
                             "scene names resolve in; default: $MCVERIFY_REFS, else this "
                             "checkout's reference/scenes, else the copy installed with "
                             "mcverify (<prefix>/share/mcverify/scenes)")


def _mitsuba_provenance(selected) -> dict:
    """Mitsuba's version and variant for the provenance of a run that checks Mitsuba's
    warps, printing the fallback notice once; {} when no selected check uses Mitsuba."""
    if not any("mitsuba" in c.tags for c in selected):
        return {}
    return _variant_provenance()


def _variant_notice():
    """Mitsuba's variant choice, its fallback notice printed to stderr."""
    from . import mitsuba as mv_mitsuba

    choice = mv_mitsuba.choose_variant()
    if choice.notice:
        print(f"notice: {choice.notice}", file=sys.stderr)
    return choice


def _variant_provenance() -> dict:
    """Mitsuba's version and variant, printing the variant choice's fallback notice."""
    from . import mitsuba as mv_mitsuba

    return {"mitsuba_version": mv_mitsuba.mitsuba_version(),
            "mitsuba_variant": _variant_notice().variant}


def _suite_checks(args):
    """The suite(s) to run: ``--suite``, else ``[tool.mcverify]`` of the project's
    pyproject.toml, else "default". Fills in ``args.alpha``/``args.seed`` from the table
    where the command line left them (commands without those options, ``list`` and
    ``plan``, have none to fill); user suites import from the table's ``path`` and the
    current directory. Returns (suite name, checks, skipped, provenance)."""
    from . import suites
    from .usersuite import find_config

    if args.suite is not None and not args.suite.strip():   # '' read as "not given"
        raise InvalidArgument(f"--suite {args.suite!r}: empty; give one of "
                              f"{', '.join(suites.SUITE_NAMES)} or MODULE:ATTR")
    config = find_config()
    names = (args.suite,) if args.suite else (config.suites if config and config.suites
                                              else ("default",))
    for key, default in (("alpha", 0.01), ("seed", 0)):
        if getattr(args, key, default) is None:
            table = getattr(config, key) if config else None
            setattr(args, key, table if table is not None else default)
    roots = [os.path.join(config.root, p) for p in config.path] if config else []
    roots.append(".")
    checks, skipped, origin = [], [], {}
    # a suite the table names is reported by the file and key, not as --suite
    option = ("--suite" if args.suite or not (config and config.suites) else
              f"{config.file}: [tool.mcverify] suite")
    for n in names:
        c, s = suites.resolve_suite(n, roots=roots, option=option)
        for check in c:     # each check's seed derives from its name: two would share one
            if check.name in origin:
                raise InvalidArgument(f"{option}: check {check.name!r} is in suite "
                                      f"{origin[check.name]!r} and in suite {n!r}; names "
                                      "must be unique across the suites of one run (seeds "
                                      "derive from names): rename one")
            origin[check.name] = n
        checks += c
        skipped += s
    return "+".join(names), checks, skipped, ({"config": config.file} if config else {})


def _no_check(args) -> str:
    """Why nothing is selected: ``-k`` matches no check, or the suite has none."""
    if args.k is None:
        return f"suite {args.suite!r} has no checks"
    # the suite given on the command line, which a bare `mcverify list` does not list (it
    # lists the table's or the default suite: sampler:uniform_disk_polar, where `check
    # --suite mitsuba -k uniform_disk_polar` had matched nothing)
    given = getattr(args, "_given_once", {}).get("suite")
    if args.command == "report":    # a built-in suite always, never the table's
        given = args.suite
    listing = "mcverify list" + (f" --suite {given}" if given else "")
    return (f"-k {args.k!r}: matches no check of suite {args.suite!r}; `{listing}` "
            "shows the names")


def _suite_sources(suite: str, extra: dict) -> list[str]:
    """The files a run of ``suite`` reads its checks from: each user suite's module
    (``MODULE:ATTR``, imported by now) and the project's pyproject.toml."""
    files = [extra["config"]] if extra.get("config") else []
    for name in suite.split("+"):
        if ":" in name:
            module = sys.modules.get(name.split(":", 1)[0])
            if getattr(module, "__file__", None):
                files.append(module.__file__)
    return files


def _seconds_since_start() -> float:
    """Wall seconds since this process started (Linux's /proc; elsewhere since mcverify's
    CLI was imported), so that ``--budget`` counts the interpreter's start and imports."""
    try:
        with open("/proc/self/stat") as f:
            start_ticks = int(f.read().rsplit(")", 1)[1].split()[19])
        with open("/proc/uptime") as f:
            uptime = float(f.read().split()[0])
        return max(uptime - start_ticks / os.sysconf("SC_CLK_TCK"), 0.0)
    except (OSError, ValueError, IndexError):
        return time.perf_counter() - _IMPORTED


_IMPORTED = time.perf_counter()


def _cmd_check(args) -> int:
    from . import suites
    from ..result import write_json, write_junit

    # the arguments alone can be refused before the suite is built (seconds of imports)
    if args.budget is not None and not 0 < args.budget < float("inf"):
        raise InvalidArgument(f"--budget {args.budget:g}: must be a positive, finite number "
                              "of seconds")
    if args.budget is not None and args.scene:
        raise InvalidArgument("--budget with --scene: not supported; a scene's render check "
                              "has its own spp and passes (use --budget without --scene)")
    if args.scene:
        args.scene = _scene_file(args.scene)
    given_suite = args.suite
    args.suite, checks, skipped, extra = _suite_checks(args)
    # the scene, its reference (the render check reads it), the project's pyproject.toml
    # and a user suite's module are inputs: an output path naming one would replace it
    inputs = _suite_sources(args.suite, extra) + _pool_inputs(args)
    if args.scene:
        from .reference import reference_files

        inputs += reference_files(args.scene)
    _writable("--json", args.json, inputs)
    _writable("--junit", args.junit, inputs)
    report_files = _report_files("--report", args.report, inputs)
    _distinct_outputs(("--json", args.json), ("--junit", args.junit),
                      *(("--report", f) for f in report_files))
    plan = None
    if args.budget is not None and args.suite not in suites.SUITES:
        where = (f"--suite {args.suite}" if given_suite else   # else the table's
                 f"{extra['config']}: [tool.mcverify] suite {args.suite!r}")
        raise InvalidArgument(f"--budget with {where}: only the built-in suites "
                              f"{', '.join(suites.SUITES)} can be sized to a time budget")
    if args.scene:
        # from the suites already resolved: a table's list ran as 'a:b+default', a name
        # that does not resolve, and its import roots were not passed on
        planned, skipped, _ = _plan(args.scene, args.suite, checks)
        selected, family = suites.select(planned, args.k), len(planned)
        if any(c.name == planned[-1].name for c in selected):
            _precheck_render(args.scene)
        if planned and not selected:      # -k left nothing: no gate may pass on no check
            suite_option = f" --suite {given_suite}" if given_suite else ""
            raise InvalidArgument(f"-k {args.k!r}: matches none of the {len(planned)} "
                                  f"checks the scene needs; `mcverify plan {args.scene}"
                                  f"{suite_option}` lists them")
        extra["scene"] = os.path.abspath(args.scene)
    elif args.budget is not None:
        from .budget import plan_budget

        if not suites.select(suites.build_suite(args.suite), args.k):
            raise InvalidArgument(_no_check(args))
        if not args.quiet:
            print(f"mcverify check --budget {args.budget:g}: calibrating this machine ...",
                  file=sys.stderr)
        plan = plan_budget(args.suite, args.k, args.budget, seed=args.seed,
                           startup=_seconds_since_start())
        sized = suites.build_suite(args.suite, plan.n_overrides)
        selected, family = suites.select(sized, args.k), len(sized)
    else:
        selected, family = suites.select(checks, args.k), len(checks)
    if not selected and args.scene:
        print(f"mcverify check --scene {args.scene}: the scene needs no sampler or estimator "
              "checks", file=sys.stderr)
    elif not selected:
        raise InvalidArgument(_no_check(args))
    extra.update(_mitsuba_provenance(selected))
    with _pool(args) as pool:
        result = suites.run_suite(selected, name=args.suite, seed=args.seed, alpha=args.alpha,
                                  progress=None if args.quiet else
                                  _progress(sys.stderr, alpha=args.alpha),
                                  extra_provenance=extra, skipped=skipped, pool=pool,
                                  family=family)   # -k changes no check's stop level
    bought = None
    if plan is not None:
        from .budget import power_bought

        bought = power_bought([r for r in result.results if r.name in plan.n_samples],
                              args.alpha, n_checks=len(result.results))
        result = dataclasses.replace(result, provenance={
            **result.provenance,
            "budget": {**plan.to_dict(), "detectable_contamination": bought}})
    failed = [r for r in result.results if not r.passed]
    if not args.quiet:  # the checks whose progress line said "pending", now judged
        for r in result.results:
            if not r.failures and r.p_value is not None and r.p_value <= args.alpha and r.passed:
                print(f"PASS {_shown(r.name)}: p={r.p_value:.3g} is no alarm after Holm "
                      f"(p_adj={r.details.get('p_adjusted'):.3g})")
    for line in [*map(str, failed), *result.toothless()]:
        print(_shown(line))
    if skipped and not args.scene:
        reasons = {}
        for _, why in skipped:
            reasons[why] = reasons.get(why, 0) + 1
        for why, count in reasons.items():
            print(f"skipped {count}: {why}")
    if plan is not None:
        for note in plan.notes:
            print(f"note: {note}")
        ns = sorted(plan.n_samples.values())
        seen = {k: e for k, e in (bought or {}).items() if e is not None}
        head = (f"budget {args.budget:g}s (took {_seconds_since_start():.1f}s, predicted "
                f"{plan.predicted_seconds:.1f}s; start-up {plan.startup_seconds:.1f}s, "
                f"calibration {plan.calibration_seconds:.1f}s with the fixed-size checks "
                f"and canaries it also timed)")
        # Mitsuba's own warps keep the suite's n (not scalable): said, not left out of a
        # line about "sampler checks" (a read-only review)
        kept = [r for r in result.results
                if r.name.startswith("sampler:") and r.name not in plan.n_samples]
        tail = (f"; {len(kept)} kept the suite's n, Mitsuba's own warps, which a budget "
                f"does not scale ({', '.join(f'{r.name} at {r.n_samples:,}' for r in kept)})"
                if kept else "")
        if ns and seen:
            worst = max(seen, key=seen.get)
            print(f"{head}: sampler checks at n = {ns[0]:,} to {ns[-1]:,}; each catches "
                  f"uniform contamination of {100 * seen[worst]:.2g} % or less at 95 % "
                  f"power (worst: {worst}){tail}")
        elif ns:
            # said, not left out: a uniform pdf is what uniform contamination leaves alone
            print(f"{head}: sampler checks at n = {ns[0]:,} to {ns[-1]:,}; their pdfs are "
                  f"uniform, which uniform contamination does not change: no power "
                  f"figure{tail}")
        else:
            # said, not left out: a -k without sampler checks has nothing to scale
            print(f"{head}: no sampler check of ours selected, nothing to scale; every "
                  f"check ran at its fixed size{tail}")
    # a scene's run says so: its checks are the plan's, not the suite's (it read
    # "mcverify check --suite default" after `check --scene X`; an outside review)
    what = (f"--scene {args.scene}" + (f" --suite {given_suite}" if given_suite else "")
            if args.scene else f"--suite {args.suite}")
    print(f"mcverify check {what}: {result.counts()}")
    # written after the verdict is printed: a write that fails (exit 2) loses no result;
    # flushed first, so that a --json /dev/stdout follows the text instead of cutting it
    sys.stdout.flush()
    report = None
    if args.report is not None:     # made (seconds of plots) before any file is written
        from .report import files_touched, prepare_report

        doc, report = prepare_report(args.report, suite=result, study=None,
                                     extra_provenance=dict(extra, seed=args.seed))
        # the histograms' names are known only now: --json/--junit named as one of them
        # (or as an old report's image, which the report removes) would be replaced by it
        _distinct_outputs(("--json", args.json), ("--junit", args.junit),
                          *(("--report", f) for f in files_touched(args.report, doc)))
    with _outputs_together():
        if args.json:
            write_json(result, args.json)
        if args.junit:
            write_junit(result, args.junit)
        if report is not None:
            report()
    if report is not None:      # once renamed into place, at the block's end
        print(f"mcverify check: wrote {report_files[1]} and report.json")
    return EXIT_OK if result.passed else EXIT_FAILED


@contextlib.contextmanager
def _outputs_together():
    """Hold a Ctrl-C that comes while a run's output files are written (``--json``,
    ``--junit``, ``--report``'s files, one after another) until the last is, then stop
    (KeyboardInterrupt, exit 130): one there left this run's JSON beside the last run's
    JUnit file and report. A SIGTERM that ``_sigterm_unwinds`` raises is held too. Where
    SIGINT is not Python's (ignored, or the caller's own handler) or off the main thread,
    it is left alone. The files are renamed into place together once all are written
    (``staged_writes``): a write that fails leaves every output as it was."""
    ours = {signal.SIGINT: signal.default_int_handler, signal.SIGTERM: _on_sigterm}
    if threading.current_thread() is not threading.main_thread():
        ours = {}
    ours = {sig: h for sig, h in ours.items() if signal.getsignal(sig) is h}
    held = []
    for sig in ours:
        signal.signal(sig, lambda signum, frame: held.append(signum))
    try:
        # renamed in together once all are written: a write that fails (a full disk on
        # --junit) left this run's --json beside the last run's JUnit file, exit 2
        with staged_writes():
            yield
    finally:
        for sig, handler in ours.items():
            signal.signal(sig, handler)
    if held:
        if signal.SIGTERM in held:
            _TERMINATED.append(signal.SIGTERM)
        raise KeyboardInterrupt


def _report_files(option: str, out: str | None, inputs=()) -> list[str]:
    """``report.json`` and ``report.html`` in the folder ``out`` (``check --report``,
    ``report --out``), checked writable before any work; none for None."""
    if out is None:
        return []
    if not out.strip():
        raise InvalidArgument(f"{option} {out!r}: empty path; give a folder")
    files = [os.path.join(out, name) for name in ("report.json", "report.html")]
    for f in files:
        _writable(option, f, inputs)
    return files


def _scene_file(spec: str) -> str:
    """The scene file ``check --scene`` and ``plan`` read: a file as given, else (as
    ``render-check`` takes them) a folder holding scene.xml or a reference name, resolved
    in ``--refs``/``$MCVERIFY_REFS``/the checkout's or installed reference scenes."""
    if os.path.exists(spec) and not os.path.isdir(spec):
        return spec
    from .reference import resolve_scene

    return resolve_scene(spec)[1]


def _plan(scene, suite, checks=None):
    from estimators.pathtracer import SceneError

    from .plan import plan

    try:
        return plan(scene, suite, checks)
    except SceneError as e:
        raise InvalidArgument(str(e)) from None


def _precheck_render(scene) -> None:
    """The plan's render check (its last) has Mitsuba render the scene: one Mitsuba
    refuses (no <integrator>, which our tracer defaults to path) was planned, every other
    check ran, and its render check then failed, exit 1."""
    from .reference import precheck_scene

    precheck_scene(scene)


def _cmd_plan(args) -> int:
    if (args.scene is None) == (args.scene_option is None):
        raise InvalidArgument("plan: name one scene, as SCENE.xml or --scene SCENE.xml")
    args.scene = _scene_file(args.scene if args.scene is not None else args.scene_option)
    # the suites `check --scene` plans from: --suite, else [tool.mcverify]'s, else default
    # (plan read the built-in default whatever the table said, and listed other checks)
    args.suite, suite_checks, _, _ = _suite_checks(args)
    checks, skipped, features = _plan(args.scene, args.suite, suite_checks)
    _precheck_render(args.scene)
    print(f"scene {args.scene} uses: {', '.join(sorted(features))}")
    print(f"checks ({len(checks)}):")
    for c in checks:
        print(f"  {c.name}")
    print(f"skipped ({len(skipped)}):")
    for name, why in skipped:
        if why != "not needed by this scene" or args.verbose:
            print(f"  {name}: {why}")
    hidden = sum(why == "not needed by this scene" for _, why in skipped)
    if hidden and not args.verbose:
        print(f"  ... and {hidden} checks this scene does not need (-v lists them)")
    return EXIT_OK


def _cmd_list(args) -> int:
    from . import suites

    args.suite, checks, _, _ = _suite_checks(args)
    selected = suites.select(checks, args.k)
    if not selected:
        raise InvalidArgument(_no_check(args))
    for c in selected:
        print(c.name)
    return EXIT_OK


def _cmd_report(args) -> int:
    from . import suites
    from .report import prepare_report
    from .report.study import run_study

    out = args.out
    _report_files("--out", out, _pool_inputs(args))     # before the suite's minutes of work
    scenes = []
    if args.renders != "none":
        from . import reference
        from .reference import list_scenes, load_reference, resolve_scene

        scenes = list_scenes() if args.renders == "all" else \
            list(dict.fromkeys(args.renders.split(",")))        # each scene once
        if not scenes:      # was a report without renders, exit 0 (a --refs one level off)
            raise InvalidArgument(f"--renders all (the default): no reference scenes "
                                  f"(NAME/scene.xml) under {reference.REFERENCE_ROOT}; "
                                  "give --refs DIR, or --renders none")
        if "" in [s.strip() for s in scenes]:   # was refused as "scene ''", not naming it
            raise InvalidArgument(f"--renders {args.renders!r}: an empty scene name; give "
                                  "comma-separated reference scenes, 'all' or 'none'")
        by_file = {}                    # a scene spelt two ways (its name, its folder)
        for s in scenes:                # was rendered twice, two rows of the report
            # before any work (it was checked after the suite)
            by_file.setdefault(os.path.realpath(resolve_scene(s)[1]), s)
        scenes = list(by_file.values())
        for s in scenes:
            try:                        # a stale or corrupt reference too, before any work
                load_reference(s)
            except MissingReference:
                pass                    # built by the render check, with a notice
    if args.no_suite and args.k:
        raise InvalidArgument(f"-k {args.k!r}: selects checks of the suite, which "
                              "--no-suite leaves out")
    if args.no_suite:
        _suite_options_unused(args)
    show = None if args.quiet else _progress(sys.stderr, alpha=0.01)
    suite = None
    extra = {}
    if not args.no_suite:
        whole = suites.build_suite(args.suite)
        selected = suites.select(whole, args.k)
        if not selected:
            raise InvalidArgument(_no_check(args))
        extra = _mitsuba_provenance(selected)
        with _pool(args) as pool:
            suite = suites.run_suite(selected, name=args.suite, seed=args.seed, progress=show,
                                     extra_provenance=extra, pool=pool, family=len(whole))
    # Study rows are judged together (Holm) at the end: no per-row verdict while running.
    study = run_study(seed=args.seed,
                      progress=None if args.quiet else _progress(sys.stderr, verdicts=False))
    renders = None
    if scenes:
        from .report.renders import run_renders

        if "mitsuba_variant" not in extra:    # Mitsuba renders beside ours: its variant's
            # fallback notice and provenance, which a suite without Mitsuba checks (or
            # --no-suite) left out
            extra = dict(extra, **_variant_provenance())

        renders = run_renders(scenes, seed=args.seed,
                              progress=None if args.quiet else _progress(sys.stderr),
                              notice=None if args.quiet else
                              (lambda m: print(f"notice: {m}", file=sys.stderr)))
    _, write = prepare_report(out, suite=suite, study=study, renders=renders,
                              extra_provenance=dict(extra, seed=args.seed))
    with _outputs_together():
        write()
    print(f"mcverify report: wrote {os.path.join(out, 'report.html')} and report.json")
    # the report is written either way; its verdicts decide the exit code, as check's do
    failed = ([r.name for r in suite.results if not r.passed] if suite is not None else [])
    if suite is not None and not suite.canary_bitten:
        failed += [f"canary {c.name} (not bitten)" for c in suite.canary if c.passed]
    failed += [f"convergence:{row['estimator']}:{row['integrand']}" for row in study
               if not row.get("passed", True)]
    failed += [f"render:{row['scene']}" for row in (renders[0] if renders else ())
               if not row.get("passed", True)]
    for name in failed:
        print(f"FAIL {_shown(name)}")
    return EXIT_FAILED if failed else EXIT_OK


def _suite_options_unused(args) -> None:
    """``report --no-suite`` with an option that acts on the suite alone (``--suite``,
    ``-j``, ``--dask``, ``--dask-scheduler-file``): the study and renders ran in this
    process, and the report was written, as if the option had been used."""
    given = getattr(args, "_given_once", {})
    if "suite" in given:
        raise InvalidArgument(f"--suite {args.suite}: the suite's checks, which --no-suite "
                              "leaves out; drop one of them")
    where = ("-j", args.jobs if args.jobs != 1 else None), ("--dask", args.dask), \
        ("--dask-scheduler-file", args.dask_scheduler_file)
    for option, value in where:
        if value is not None:
            raise InvalidArgument(f"{option} {value}: runs the suite's checks on worker "
                                  "processes, which --no-suite leaves out (the convergence "
                                  "study and renders run in this process); drop one of them")


def _cmd_bench(args) -> int:
    from .bench import equal_time_spp, run_bench
    from ..provenance import describe_cpu, provenance
    from ..result import atomic_write, json_text

    inputs = []
    if not args.no_render:  # the scenes and references the render rows read
        from .reference import BUNDLED_ROOT, list_scenes, reference_files

        scenes = list_scenes() + [os.path.join(BUNDLED_ROOT, s, "scene.xml")
                                  for s in ("cornell-box", "white-furnace")]
        inputs = [f for s in scenes for f in reference_files(s)]
    _writable("--json", args.json, inputs)
    if args.repeats < 1:
        raise InvalidArgument(f"--repeats {args.repeats}: must be >= 1")
    if args.spp < 4:
        raise InvalidArgument(f"--spp {args.spp}: must be >= 4")
    if args.n < 1000:
        raise InvalidArgument(f"--n {args.n}: must be >= 1000 (timings of fewer points "
                              "measure call overhead, not work)")
    from .._validate import memory
    from .bench import BYTES_PER_POINT

    # --n 10000000000 ended in "unexpected MemoryError: Unable to allocate 149. GiB for an
    # array with shape (10000000000, 2)", naming no option, after Mitsuba's probe
    memory("--n", args.n, BYTES_PER_POINT, "the warps' points and results, both sides")
    from . import mitsuba as mv_mitsuba

    choice = _variant_notice()

    def show(i, total, row):
        if not args.quiet:
            print(f"[{i}/{total}] {row['group']} done", file=sys.stderr)

    from estimators.pathtracer import SceneError

    try:    # every scene is prepared before anything is timed
        rows = run_bench(repeats=args.repeats, n=args.n, spp=args.spp,
                         renders=not args.no_render, progress=show)
    except SceneError as e:     # a --refs scene our tracer refuses: bad input, as in check
        raise InvalidArgument(str(e)) from None
    w = max([30] + [len(r["group"]) for r in rows])     # long names kept the columns apart
    # the ratios depend on the processor (up to 1.8x apart on this project's machines)
    # and on each side's threads: MCVERIFY_NUM_THREADS=1 timed ours on one thread against
    # Mitsuba's every core, and neither the table nor the JSON said so
    import numba

    threads = {"ours": numba.get_num_threads(), "mitsuba": mv_mitsuba.thread_count()}
    print(f"on {describe_cpu()}, Mitsuba {mv_mitsuba.mitsuba_version()} {choice.variant}; "
          f"threads: ours {threads['ours']}, Mitsuba {threads['mitsuba']}")
    print(f"{'workload':{w}s} {'ours':>10s} {'theirs':>10s} {'ours/theirs':>12s}  against")
    for r in rows:
        if "ours_rmse" in r:
            print(f"{r['group']:{w}s} {r['ours_rmse']:10.4g} {r['mitsuba_rmse']:10.4g} "
                  f"{r['ratio']:12.2f}  mitsuba (RMSE at equal time)")
            continue
        # 4 significant digits: a warp of --n 1000 points takes microseconds (0.0000)
        m = "n/a" if r["mitsuba_s"] is None else f"{r['mitsuba_s']:.4g}"
        ratio = "n/a" if r["ratio"] is None else f"{r['ratio']:.2f}"
        print(f"{r['group']:{w}s} {r['ours_s']:10.4g} {m:>10s} {ratio:>12s}  {r['against']} "
              "(seconds)")
    if args.json:
        from .reference import REFERENCE_ROOT

        # the sizes chosen, as the table's rows were timed with them: a run at --n 1000
        # --spp 4 had the provenance of one at the defaults (only --repeats recorded)
        doc = {"provenance": provenance(mitsuba_version=mv_mitsuba.mitsuba_version(),
                                        mitsuba_variant=choice.variant, repeats=args.repeats,
                                        n=args.n, spp=args.spp, renders=not args.no_render,
                                        threads=threads,
                                        equal_time_spp=equal_time_spp(args.spp),
                                        refs=None if args.no_render else REFERENCE_ROOT),
               "results": rows}
        atomic_write(args.json, json_text(doc))     # a ratio 0/0 was a bare NaN token
    return EXIT_OK


def _cmd_reference_build(args) -> int:
    from . import reference

    names = args.scenes or reference.list_scenes()
    if not names:
        raise InvalidArgument(f"no scenes given and none under {reference.REFERENCE_ROOT}")
    if args.spp < 1 or args.passes < 2:
        raise InvalidArgument(f"--spp {args.spp} --passes {args.passes}: need --spp >= 1 "
                              "(per pass) and --passes >= 2 (the variance needs two passes)")
    if args.spp > reference.MAX_SPP_PER_PASS:   # reached Mitsuba, blamed on the scene
        raise InvalidArgument(f"--spp {args.spp}: at most {reference.MAX_SPP_PER_PASS} "
                              "(2^32 - 1) samples per pass, Mitsuba's limit; use more "
                              "--passes")
    resolved = [reference.resolve_scene(s) for s in names]    # fail before any rendering
    for name, path in resolved:
        installed = reference.installed_copy(path)
        if installed:
            # an installed mcverify's own references were rebuilt in place without a word
            # (an 8-spp cornell-box then gated every check of this install; an outside
            # review, 7 December)
            raise InvalidArgument(
                f"{name}: {path} is a scene installed with mcverify ({installed}), whose "
                "reference this install's check and render-check compare against; copy "
                "its folder into a folder of your own and build there (--refs DIR)")
        reference.precheck_scene(path)
    choice = _variant_notice()
    def show(done, total, label):
        if not args.quiet:
            print(f"[{done}/{total}] {label}", file=sys.stderr)

    with _pool(args) as pool:   # every pass of every scene is a unit
        outs = reference.build_references([p for _, p in resolved], spp=args.spp,
                                          passes=args.passes, seed=args.seed, progress=show,
                                          pool=pool)
    for out in outs:
        with open(os.path.join(out, "manifest.json"), encoding="utf-8") as f:
            spp = json.load(f)["spp"]
        rounded = (f"; Mitsuba's sampler rounds --spp {args.spp} to {spp}"
                   if spp != args.spp else "")
        print(f"built {out} ({args.passes} passes × {spp} spp per pass = "
              f"{args.passes * spp} spp, {choice.variant}{rounded})")
    return EXIT_OK


def _compare_side(label: str, image: str | None, var: str | None, n: int | None,
                  passes: str | None, *, reference_ok: bool):
    """One side of ``mcverify compare`` -> (ImageStats or a reference name, input files).

    Pass images (``--X-passes``), or an image with ``--X-var``/``--X-n``, or (reference
    side only) a reference name or folder. Every input is checked before any work."""
    from . import reference
    from .passes import colour_channels, pass_files, pass_stats

    opt = f"--{label}"
    if passes is not None:
        for o, v in ((f"{opt}-var", var), (f"{opt}-n", n)):
            if v is not None:
                raise InvalidArgument(f"{o}: not with {opt}-passes (the passes give the "
                                      "variance and n)")
        files = pass_files(passes, option=f"{opt}-passes")
        return (lambda keep=False: pass_stats(passes, option=f"{opt}-passes", keep=keep)), files
    if reference_ok and (not os.path.isfile(image) or image.lower().endswith(".xml")):
        # a reference name, its folder or its scene file (never an image)
        for o, v in ((f"{opt}-var", var), (f"{opt}-n", n)):
            if v is not None:   # silently ignored until 6 December
                raise InvalidArgument(f"{o}: not with a reference ({image}), which gives "
                                      "its own variance and passes; give REF.exr with it")
        return None, reference.reference_files(image)
    if not os.path.isfile(image):
        # said "an image needs --test-var and --test-n" of a file that is not there (an
        # outside review): the missing file is the first thing to mend
        raise InvalidArgument(f"{image}: cannot read it (no such file; the {label} image)")
    if var is None or n is None:
        raise InvalidArgument(f"{image}: an image needs {opt}-var and {opt}-n (or give "
                              f"{opt}-passes)")
    if not 2 <= n <= 2 ** 53:    # compare_images' bounds, named as the option
        raise InvalidArgument(f"{opt}-n {n}: must be from 2 to 2^53 (values per pixel "
                              "behind the variance)")
    for path in (image, var):
        colour_channels(path)
    if os.path.realpath(var) == os.path.realpath(image):
        # the image read as its own variance: compared without a word until 7 December
        raise InvalidArgument(f"{var} ({opt}-var): is the image itself ({image}); give the "
                              "variance image of it (the variance of the values averaged "
                              "into each pixel)")

    def load(keep=False):
        import numpy as np

        from .._validate import negatives
        from .passes import ImageStats, colour_types, read_radiance

        (m, a), (v, b) = read_radiance(image), read_radiance(var)
        # a half image handed on as half (exactly: its values are half's), so that
        # compare_images takes half's rounding as no evidence (a correct renderer's half
        # mean.exr and var.exr failed with p = 0 against a float reference); its colour
        # channels decide, not a float alpha beside them (an outside review)
        m, v = (x.astype(np.float16) if all(t == "half" for t in colour_types(f)) else x
                for x, f in ((m, image), (v, var)))
        if v.shape != m.shape:  # named here by file (compare_images would say "test_var")
            raise InvalidArgument(f"{var} ({opt}-var): shape {v.shape} differs from "
                                  f"{image}'s {m.shape}; give the variance image of it")
        if np.array_equal(m, v) and np.any(m != 0):   # a mean written twice
            raise InvalidArgument(f"{var} ({opt}-var): holds the pixels of {image} itself; "
                                  "give the variance image of it")
        bad = negatives(v)
        if bad:       # named here by file (compare_images would name the side only)
            count, first, value = bad
            raise InvalidArgument(f"{var} ({opt}-var): {count} negative variance value(s), "
                                  f"first at pixel (y, x, channel) = {first}: {value:.6g}")
        return ImageStats(m, v, n, (image, var), tuple(x for x in (a, b) if x))

    return load, [image, var]


#: Fewer passes a side than this, compared without --test-spp: ``compare`` says that a
#: few passes which all missed a rare path read as confident evidence (Mitsuba against
#: itself, 16 passes against 2, Cornell box: 10 false alarms in 200 seeds without the
#: floor, none with it; an outside review).
FEW_PASSES = 4


def _expanded_glob(args, excess: bool) -> str:
    """A hint where the shell expanded an unquoted --test-passes/--ref-passes glob: the
    option took the first file and the others came as image arguments (``excess``), and
    the refusal listed them as images given in excess, or (after REF) as unrecognized
    arguments, never saying why (an outside review: ``--test-passes p_*.exr REF`` over
    16 passes, 'got 16 image argument(s)'). Both options are named where neither holds a
    glob (it named --test-passes alone, while the files it listed were the reference
    side's)."""
    if not excess:
        return ""
    given = [(opt, v) for opt, v in (("--test-passes", getattr(args, "test_passes", None)),
                                     ("--ref-passes", getattr(args, "ref_passes", None)))
             if v is not None and not glob.has_magic(v)]
    if not given:
        return ""
    if len(given) == 2:
        return ("; the shell seems to have expanded the globs of --test-passes and "
                f"--ref-passes (they got {given[0][1]} and {given[1][1]}, the other files "
                "came as image arguments): quote them, as in --test-passes "
                "'out/pass_*.exr', so that compare expands them")
    opt, first = given[0]
    return (f"; the shell seems to have expanded the glob of {opt} (it got {first}, "
            f"the other files came as image arguments): quote it, as in {opt} "
            "'out/pass_*.exr', so that compare expands it")


def _counts_note(message: str, args, ref_named: bool) -> str:
    """``compare_images``' note on the two sides' per-sample variances in ``compare``'s
    words: it said "check test_spp=64 and ref_spp=64", names of parameters the user never
    gave, and an image whose --test-var was the variance of its mean, not of the
    --test-n values averaged into it, was noted so with both counts right (an outside
    review). It names the options, and each variance image given, as what else to
    check."""
    from ..checks.image import SPP_NOTE

    def say(m):
        ref = (f"the reference's {m.group(2)} samples per pass (its manifest)" if ref_named
               else f"--ref-spp {m.group(2)}")
        text = (f"check --test-spp {m.group(1)} and {ref}, the samples in each value "
                "averaged into a pixel (e.g. a pass)")
        for opt, var, n in (("--test-var", args.test_var, args.test_n),
                            ("--ref-var", args.ref_var, args.ref_n)):
            if var is not None:
                text += (f", and that {opt} ({var}) is the variance of the {n} values "
                         "averaged into each pixel, not of their mean")
        return text
    return SPP_NOTE.sub(say, message)


def _channels_hint(test_shape, ref_shape) -> str:
    """Where only the channels differ, one or three: a luminance film's image against an
    RGB reference (or the other way round) was refused as a bare shape mismatch (an
    outside review)."""
    if test_shape[:2] != ref_shape[:2] or {test_shape[2:], ref_shape[2:]} != {(1,), (3,)}:
        return ""
    return ("; one channel against three: render both with the film's pixel_format "
            "(rgb, as the reference scene's film), not one as luminance")


def _shape_hint(test_shape, ref_shape) -> str:
    """``_channels_hint``, else what ``compare_images`` says of such shapes (a transposed
    image, another resolution, an alpha channel; until 7 December the CLI gave none of
    it, an outside review's found-not-fixed)."""
    from ..checks.image import shape_hint

    hint = _channels_hint(test_shape, ref_shape)
    if hint or len(test_shape) != 3 or len(ref_shape) != 3:
        return hint
    return shape_hint(test_shape, ref_shape)


def _cmd_compare(args) -> int:
    from . import reference
    from ..checks import compare_images
    from ..provenance import provenance
    from ..result import write_json

    for opt, value in (("--test-spp", args.test_spp), ("--ref-spp", args.ref_spp)):
        if value is not None and value < 1:
            raise InvalidArgument(f"{opt} {value}: samples per pixel behind each value "
                                  "(per pass) must be >= 1")
    if args.test_spp is None and args.ref_spp is not None:
        raise InvalidArgument(f"--ref-spp {args.ref_spp}: give --test-spp too (the variance "
                              "floor scales the reference's variance by their ratio)")
    want = (args.test_passes is None) + (args.ref_passes is None)
    if len(args.images) != want:
        shape = " ".join(x for x, given in (("TEST.exr", args.test_passes is None),
                                            ("REF", args.ref_passes is None)) if given)
        raise InvalidArgument(f"compare: got {len(args.images)} image argument(s) "
                              f"{args.images}, expected {want}: {shape or 'none'} (with "
                              "--test-passes there is no TEST.exr, with --ref-passes no REF)"
                              + _expanded_glob(args, len(args.images) > want))
    images = list(args.images)
    test_image = images.pop(0) if args.test_passes is None else None
    ref_image = images.pop(0) if args.ref_passes is None else None
    test_load, test_files = _compare_side("test", test_image, args.test_var, args.test_n,
                                          args.test_passes, reference_ok=False)
    ref_load, ref_files = _compare_side("ref", ref_image, args.ref_var, args.ref_n,
                                        args.ref_passes, reference_ok=True)
    _writable("--json", args.json, test_files + ref_files)
    # the images under test (not their variance file) among the reference side's files:
    # an image compared with itself always agrees, whatever the renderer did
    shown = test_files if test_image is None else [test_image]
    ref_real = {os.path.realpath(f): f for f in ref_files}
    for f in shown:
        real = os.path.realpath(f)
        if real in ref_real:
            raise InvalidArgument(f"{f}: is on both sides of the comparison (the reference "
                                  f"side reads {ref_real[real]}); an image "
                                  "compared with itself always agrees: give the render "
                                  "under test and a reference made apart from it")
    correlated = args.correlated
    ref_spp = args.ref_spp
    if ref_load is None:
        r = reference.load_reference(ref_image)
        ref_mean, ref_var, ref_n, ref_passes = r.mean, r.var, r.n, r.passes
        correlated |= r.pixels_correlated
        if r.manifest.get("spp"):
            if ref_spp is not None and ref_spp != int(r.manifest["spp"]):
                # it replaced what the manifest records, and the floor scaled the
                # reference's variance by the wrong ratio without a word
                raise InvalidArgument(f"--ref-spp {ref_spp}: the reference {ref_image} "
                                      f"records {int(r.manifest['spp'])} samples per pass "
                                      "(its manifest's spp); drop --ref-spp")
            ref_spp = int(r.manifest["spp"])
        if correlated and ref_passes is None:
            raise EnvironmentProblem(f"{ref_image}: the reference has no pass images (built "
                                     "before passes.exr was stored), which correlated pixels "
                                     "need; " + reference.rebuild_advice(
                                         *reference.resolve_scene(ref_image), r.manifest))
    elif correlated and args.ref_passes is None:
        raise InvalidArgument("--correlated: give the reference side's pass images "
                              "(--ref-passes GLOB) or a reference name")
    if correlated and args.test_passes is None:
        raise InvalidArgument(f"{test_image}: pixels of a pass correlate (--correlated, or "
                              "the reference's filter splats); give the test side's pass "
                              "images (--test-passes GLOB) instead of one image")
    if args.test_spp is not None and ref_spp is None:
        raise InvalidArgument(f"--test-spp {args.test_spp}: the reference side's samples per "
                              "value are unknown; give --ref-spp (a committed reference "
                              "knows its own)")
    if correlated and args.test_spp is not None and args.test_spp != ref_spp:
        # a pixel's Σ w L / Σ w has a bias of order 1/(samples per pass), as render-check
        # refuses (until 7 December compare took 16-spp passes against 64 without a word)
        raise InvalidArgument(f"--test-spp {args.test_spp}: pixels of a pass correlate (a "
                              "splatting filter), and a pixel's weighted mean Σ w L / Σ w "
                              "has a bias of order 1/(samples per pass), so the test passes "
                              f"need the reference side's {ref_spp} samples per pass")
    test = test_load(keep=correlated)
    if ref_load is not None:
        ref = ref_load(keep=correlated)
        ref_mean, ref_var, ref_n, ref_passes = ref.mean, ref.var, ref.n, ref.passes
    label = test_image or args.test_passes
    if test.mean.shape != ref_mean.shape:
        raise InvalidArgument(f"{label}: shape {test.mean.shape} differs from the "
                              f"reference's {ref_mean.shape}" + _shape_hint(
                                  test.mean.shape, ref_mean.shape))
    # half pass images (``pass_stats``): their rounding is no evidence
    stored = [s.precision for s in (test, ref if ref_load is not None else None)
              if s is not None and s.precision is not None]
    result = compare_images(test.mean, ref_mean, test_var=test.var, ref_var=ref_var,
                            test_n=test.n, ref_n=ref_n, alpha=args.alpha,
                            name=f"compare:{label}",
                            **(dict(test_passes=test.passes, ref_passes=ref_passes)
                               if correlated else {}),
                            **(dict(test_spp=args.test_spp, ref_spp=ref_spp)
                               if args.test_spp is not None else {}),
                            precision=stored[0] if stored else None)
    result = dataclasses.replace(result, messages=tuple(
        _counts_note(m, args, ref_load is None) for m in result.messages))
    for note in test.notes + (() if ref_load is None else ref.notes):
        print(f"notice: {note}", file=sys.stderr)
    if args.test_spp is None and min(test.n, ref_n) < FEW_PASSES:
        print(f"notice: {min(test.n, ref_n)} passes on one side and no --test-spp: passes "
              "that all missed a rare bright path have a low mean and a low variance, "
              "which reads as confident evidence; give --test-spp (and --ref-spp) to floor "
              "each side's variance at the other's", file=sys.stderr)
    print(_shown(result))    # its summary line and messages
    _print_visibility(result.details)
    sys.stdout.flush()
    if args.json:   # after the verdict is printed (and flushed), as in `check`
        # what was compared: the JSON named only the test side (compare:LABEL), not the
        # reference it was held to, its counts or a reference's manifest
        write_json(result, args.json, provenance=provenance(
            command="compare", test=os.path.abspath(label),
            test_files=[os.path.abspath(f) for f in test_files], test_n=test.n,
            test_spp=args.test_spp,     # a reference by name or folder: its scene file
            reference=os.path.abspath(ref_image or args.ref_passes) if ref_load is not None
            else os.path.abspath(reference.resolve_scene(ref_image)[1]),
            reference_files=[os.path.abspath(f) for f in ref_files]
            if ref_load is not None else None,
            ref_n=ref_n, ref_spp=ref_spp, correlated=correlated,
            reference_manifest=None if ref_load is not None else r.manifest))
    return EXIT_OK if result.passed else EXIT_FAILED


def _params(items) -> dict:
    out = {}
    for item in items or ():
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise InvalidArgument(f"--param {item!r}: expected NAME=VALUE")
        if key in out:      # the last one silently won
            raise InvalidArgument(f"--param {item!r}: {key!r} is already set to "
                                  f"{out[key]!r}; give each name once")
        out[key] = value
    return out


def _cmd_render_check(args) -> int:
    from .render_check import render_check
    from ..provenance import provenance
    from ..result import write_json

    from . import reference

    _, scene_path = reference.resolve_scene(args.scene)
    _writable("--json", args.json, [scene_path] + reference.reference_files(scene_path)
              + _pool_inputs(args))
    params = _params(args.param)
    if args.passes < 2 or args.spp < 1:
        raise InvalidArgument(f"--spp {args.spp} --passes {args.passes}: need --passes >= 2 "
                              "and --spp (in all) >= 32 per pass")
    from estimators.pathtracer import SceneError, load_scene

    try:  # our parser must accept the scene and its --param names before anything renders
        load_scene(scene_path, params=params)
    except SceneError as e:
        raise InvalidArgument(str(e)) from None
    reference.precheck_scene(scene_path)      # and Mitsuba's needs, before the notice
    tty = _overwrites(sys.stderr) and not args.quiet

    def show_as(what):
        def show(done, total):   # the last one clears the line
            _overwrite(sys.stderr, "" if done == total else f"[{what}] {100 * done // total}%",
                       done == total)
        return show if tty else None

    try:
        with _pool(args) as pool:
            result = render_check(args.scene, spp=args.spp, passes=args.passes,
                                  seed=args.seed, alpha=args.alpha, params=params,
                                  notice=None if args.quiet else
                                  (lambda m: print(f"notice: {m}", file=sys.stderr)),
                                  progress=show_as("render"), pool=pool,
                                  # a missing reference is built first: a minute or
                                  # more of Mitsuba with no progress until 7 December
                                  reference_progress=show_as("reference"))
    finally:
        if _OPEN_LINE:  # a render decided early stops short of 100 %: its verdict was
            _overwrite(sys.stderr, "", True)  # written on, "[render] 25%FAIL render:…"
    d = result.details
    print(_shown(result))    # its summary line and messages
    print(f"    ours: {d['ours_spp']} spp in {d['ours_passes']} passes, {d['ours_seconds']:.2f}s "
          f"({d['ours_samples_per_second'] / 1e6:.2f} M samples/s, {d['ours_kernel']}); "
          f"relMSE {d['relmse']:.3g}; found by: {', '.join(d['found_by']) or 'nothing'}")
    _print_visibility(d)
    sys.stdout.flush()
    if args.json:   # after the verdict is printed (and flushed), as in `check`
        write_json(result, args.json, provenance=provenance(
            command="render-check", seed=args.seed, params=params))
    return EXIT_OK if result.passed else EXIT_FAILED


def _print_visibility(d: dict) -> None:
    """How visible the difference is (decides nothing): ΔE2000, ΔE ITP, HDR-FLIP."""
    from ..checks.image import FLIP_MIN_LUMINANCE

    if d.get("flip_mean") is not None:
        print(f"    how visible: mean ΔE2000 {d['delta_e2000_mean']:.3g}, mean ΔE ITP "
              f"{d['delta_e_itp_mean']:.3g}, mean HDR-FLIP {d['flip_mean']:.3g} "
              f"(99th percentiles {d['delta_e2000_p99']:.3g}, {d['delta_e_itp_p99']:.3g}, "
              f"{d['flip_p99']:.3g})")
    elif d.get("delta_e2000_mean") is not None:
        # "the reference is black" was said of a negative image too (an outside review)
        print(f"    how visible: mean ΔE2000 {d['delta_e2000_mean']:.3g}, mean ΔE ITP "
              f"{d['delta_e_itp_mean']:.3g} (99th percentiles {d['delta_e2000_p99']:.3g}, "
              f"{d['delta_e_itp_p99']:.3g}); HDR-FLIP not measured: no reference pixel "
              f"reaches luminance {FLIP_MIN_LUMINANCE:g} (negative values count as 0)")


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="mcverify", description=__doc__.splitlines()[0], epilog=EPILOG)
    from .._version import __version__
    from .render_check import GATE_PASSES, GATE_SPP, MIN_SPP_PER_PASS

    p.add_argument("--version", action="version", version=f"mcverify {__version__}")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser,
                           metavar="COMMAND")
    suite_help = ("suite: 'default' (the CI gate, 1e7 samples) or 'full' (parameter sweeps, "
                  "2e7 samples)")
    any_suite_help = ("suite: 'default' (the CI gate, 1e7 samples), 'full' (parameter sweeps, "
                      "2e7 samples), 'mitsuba' (Mitsuba's own plugins over sweeps) or "
                      "MODULE:ATTR (your list of mcverify.gate.suites.Check, or a callable "
                      "returning one); default: the [tool.mcverify] suite of the nearest "
                      "pyproject.toml, else 'default'")
    seed_help = f"master seed, 0 to {MAX_SEED}; each check's seed derives from it"
    quiet_help = "no progress lines on stderr"

    c = sub.add_parser("check", help="run a verification suite (the CI gate)",
                       description="Run a verification suite (the CI gate): each check draws "
                       "seeded samples and all are judged at one family-wise alpha; a line "
                       "per check on stderr, the verdict on stdout.",
                       epilog=_command_epilog("all checks passed (and every canary was "
                                              "bitten)", "a check failed or a canary "
                                              "survived"))
    c.add_argument("--suite", metavar="SUITE", help=any_suite_help)
    c.add_argument("--scene", metavar="SCENE.xml",
                   help="plan the checks from a scene (and run its render check): a scene "
                        "file, its folder or a reference name; default: the whole suite")
    c.add_argument("-k", metavar="PATTERN", help="only checks whose name contains PATTERN "
                   "(or matches it as a glob); default: all; no match exits 2")
    c.add_argument("--seed", type=decimal_int, help=seed_help + "; default: [tool.mcverify] seed, "
                   "else 0")
    c.add_argument("--alpha", type=float,
                   help="family-wise significance level (Holm across checks); default: "
                        "[tool.mcverify] alpha, else 0.01")
    c.add_argument("--json", metavar="PATH", help="write the results as JSON; default: none")
    c.add_argument("--junit", metavar="PATH",
                   help="write the results as JUnit XML; default: none")
    c.add_argument("--report", metavar="DIR",
                   help="also write the HTML report of these results into DIR "
                        "(report.html, report.json and the histograms of failed checks; "
                        "`mcverify report` adds the convergence study and renders); "
                        "default: none")
    c.add_argument("--budget", type=float, metavar="SECONDS",
                   help="choose each sampler check's n so the run (with a short "
                        "calibration of this machine) takes about SECONDS, and say what "
                        "power that buys; the chosen n go into the JSON; the built-in "
                        "suites only, not with --scene or a suite of your own; default: the "
                        "suite's fixed n")
    c.add_argument("-q", "--quiet", action="store_true", help=quiet_help)
    _add_pool_options(c)
    _add_refs_option(c)
    c.set_defaults(func=_cmd_check)

    ls = sub.add_parser("list", help="list the checks of a suite",
                        description="List the checks of a suite, one name a line: the "
                        "names -k selects from. Runs nothing.",
                        epilog=_command_epilog("the checks were listed"))
    ls.add_argument("--suite", metavar="SUITE", help=any_suite_help)
    ls.add_argument("-k", metavar="PATTERN", help="only checks whose name contains PATTERN "
                    "(or matches it as a glob); default: all; no match exits 2")
    ls.set_defaults(func=_cmd_list)

    pl = sub.add_parser("plan", help="the checks a scene needs, and what is skipped",
                        description="The checks a scene needs (its BSDFs, emitters, "
                        "textures and integrator), and what is skipped and why: what "
                        "`mcverify check --scene` runs. Runs nothing.",
                        epilog=_command_epilog("the plan was printed"))
    pl.add_argument("scene", metavar="SCENE.xml", nargs="?",
                    help="a Mitsuba XML scene, its folder or a reference name")
    pl.add_argument("--scene", dest="scene_option", metavar="SCENE.xml",
                    help="the same, spelt as for mcverify check --scene")
    pl.add_argument("--suite", metavar="SUITE", help=any_suite_help)
    pl.add_argument("-v", "--verbose", action="store_true",
                    help="also list the checks the scene does not need")
    _add_refs_option(pl)
    pl.set_defaults(func=_cmd_plan)

    rp = sub.add_parser("report", help="convergence, efficiency and verification report",
                        description="Convergence, efficiency and verification report: "
                        "runs the suite, a convergence study and the reference renders, "
                        "and writes report.json, report.html and its PNGs into --out.",
                        epilog=_command_epilog(
                            "the report was written and found nothing wrong",
                            "a check failed, a canary survived, or a convergence row or a "
                            "render was\n       judged wrong (the report is written all "
                            "the same)"))
    rp.add_argument("--out", default=os.path.join("reports", "report"), metavar="DIR",
                    help="folder for report.json, report.html and the PNGs")
    rp.add_argument("--suite", choices=("default", "full"), default="default", help=suite_help)
    rp.add_argument("-k", metavar="PATTERN",
                    help="only these checks in the verification part; default: all")
    rp.add_argument("--no-suite", action="store_true",
                    help="skip the verification part (convergence study and renders only)")
    rp.add_argument("--renders", default="all", metavar="SCENES",
                    help="reference scenes to render and compare (comma-separated), "
                         "'all' or 'none'")
    rp.add_argument("--seed", type=decimal_int, default=0, help=seed_help)
    rp.add_argument("-q", "--quiet", action="store_true", help=quiet_help)
    _add_pool_options(rp)
    _add_refs_option(rp)
    rp.set_defaults(func=_cmd_report)

    b = sub.add_parser("bench", help="run time, ours vs Mitsuba, as ratios",
                       description="Run time, ours vs Mitsuba, as ratios: a measurement, "
                       "not a verdict.",
                       epilog=_command_epilog("the timings were printed (whatever the "
                                              "ratios: bench judges nothing)"))
    b.add_argument("--json", metavar="PATH", help="write the timings as JSON; default: none")
    b.add_argument("--repeats", type=decimal_int, default=5,
                   help="timed repetitions per workload, at least (a workload is also "
                        "repeated for at least 0.25 s; the minimum is reported)")
    b.add_argument("--n", type=decimal_int, default=1_000_000, help="points per workload (>= 1000)")
    b.add_argument("--spp", type=decimal_int, default=64,
                   help="samples per pixel of the renders (>= 4; in all, one pass; rounded "
                        "up to what a scene's sampler takes, on both sides); the "
                        "equal-time RMSE rows ask Mitsuba for a quarter of it (at least 2)")
    b.add_argument("--no-render", action="store_true", help="skip the path-tracer rows")
    b.add_argument("-q", "--quiet", action="store_true", help=quiet_help)
    _add_refs_option(b)
    b.set_defaults(func=_cmd_bench)

    ref = sub.add_parser("reference", help="Mitsuba reference renders",
                         description="Mitsuba reference renders, which render-check, "
                         "compare and check --scene compare against.")
    rsub = ref.add_subparsers(dest="action", required=True, parser_class=_Parser,
                              metavar="ACTION")
    rb = rsub.add_parser("build", help="(re)render references with per-pixel variance",
                         description="(Re)render references with Mitsuba, with per-pixel "
                         "variance from independent passes, into a folder beside each "
                         "scene file (ref/ beside a scene.xml, ref-NAME beside any other: "
                         "mean.exr, var.exr, manifest.json), replacing the one there.",
                         epilog=_command_epilog("the references were written"))
    rb.add_argument("scenes", nargs="*", metavar="SCENE",
                    help="reference names or scene.xml paths (default: all)")
    rb.add_argument("--spp", type=decimal_int, default=256,
                    help="samples per pixel of EACH pass (a reference has passes × spp "
                         "samples per pixel; its own noise sets a floor under the gate's "
                         "sensitivity)")
    rb.add_argument("--passes", type=decimal_int, default=16,
                    help="independent passes (>= 2), whose spread is the variance")
    rb.add_argument("--seed", type=decimal_int, default=0,
                    help=f"master seed, 0 to {MAX_SEED}; each pass's seed derives from it")
    rb.add_argument("-q", "--quiet", action="store_true", help=quiet_help)
    _add_pool_options(rb)
    _add_refs_option(rb)
    rb.set_defaults(func=_cmd_reference_build)

    cp = sub.add_parser("compare", help="compare any renderer's EXR with a reference",
                        description="Compare any renderer's EXR with a reference, pixel by "
                        "pixel (per-pixel Welch t-tests at one family-wise alpha).",
                        epilog=_command_epilog("the images agree", "the images differ"))
    cp.add_argument("images", nargs="*", metavar="IMAGE",
                    help="TEST.exr REF; only REF with --test-passes, only TEST.exr with "
                         "--ref-passes, none with both. TEST.exr: the image under test "
                         "(float OpenEXR; RGBA and YA are compared on colour, alpha "
                         "ignored); REF: REF.exr, or a reference name or folder")
    cp.add_argument("--test-var", metavar="VAR.exr",
                    help="per-pixel variance of the --test-n values averaged into TEST.exr "
                         "(float OpenEXR); required with TEST.exr")
    cp.add_argument("--test-n", type=decimal_int, metavar="N",
                    help="values per pixel behind TEST.exr (samples or passes, >= 2); "
                         "required with TEST.exr")
    cp.add_argument("--test-passes", metavar="GLOB",
                    help="instead of TEST.exr: K >= 2 independently seeded pass images "
                         "(quote the glob, e.g. 'out/pass_*.exr'); mean, variance and "
                         "n = K come from them")
    cp.add_argument("--ref-var", metavar="VAR.exr",
                    help="variance image of REF.exr; required with an image REF, read from "
                         "the reference otherwise")
    cp.add_argument("--ref-n", type=decimal_int, metavar="M",
                    help="values per pixel behind REF.exr; required with an image REF, the "
                         "reference's passes otherwise")
    cp.add_argument("--ref-passes", metavar="GLOB",
                    help="instead of REF: K >= 2 independently seeded pass images of the "
                         "reference renderer")
    cp.add_argument("--correlated", action="store_true",
                    help="pixels of one pass correlate (a splatting reconstruction filter "
                         "such as Mitsuba's default gaussian): the image and block tests "
                         "use the pass images of both sides (--test-passes, and "
                         "--ref-passes or a reference); implied by a reference whose "
                         "filter splats")
    cp.add_argument("--test-spp", type=decimal_int, metavar="N",
                    help="samples per pixel behind each test value (per pass): floors the "
                         "test side's variance at the reference's scaled to N, so that "
                         "passes which missed a rare bright path (a caustic) cannot look "
                         "overconfident; default: no floor")
    cp.add_argument("--ref-spp", type=decimal_int, metavar="M",
                    help="samples per pixel behind each reference value, with --test-spp; "
                         "default: a committed reference's own")
    cp.add_argument("--alpha", type=float, default=0.01,
                    help="family-wise significance level of the whole comparison")
    cp.add_argument("--json", metavar="PATH",
                    help="write the result as JSON (not one of the inputs); default: none")
    _add_refs_option(cp)
    cp.set_defaults(func=_cmd_compare)

    rc = sub.add_parser("render-check", help="our path tracer against the scene's Mitsuba "
                        "reference, pixel by pixel",
                        description="Render the scene with our path tracer and compare it "
                        "with its Mitsuba reference, pixel by pixel (a missing reference "
                        "is built first).",
                        epilog=_command_epilog("the images agree", "the images differ"))
    rc.add_argument("scene", metavar="SCENE", help="scene.xml path or reference name")
    rc.add_argument("--spp", type=decimal_int, default=GATE_SPP,
                    help="samples per pixel IN ALL, split over --passes (at least "
                         f"{MIN_SPP_PER_PASS} per pass); unlike `reference build --spp`, "
                         "which is per pass")
    rc.add_argument("--passes", type=decimal_int, default=GATE_PASSES,
                    help="independent passes (>= 2)")
    rc.add_argument("--seed", type=decimal_int, default=0, help=f"seed of our renders, 0 to {MAX_SEED}")
    rc.add_argument("--alpha", type=float, default=0.01,
                    help="significance level of the image comparison")
    rc.add_argument("--param", action="append", metavar="NAME=VALUE",
                    help="override a scene <default> (both renderers); the reference is "
                         "then rendered on the fly; repeatable")
    rc.add_argument("--json", metavar="PATH", help="write the result as JSON; default: none")
    rc.add_argument("-q", "--quiet", action="store_true", help=quiet_help)
    _add_pool_options(rc)
    _add_refs_option(rc)
    rc.set_defaults(func=_cmd_render_check)
    return p


def _validate_common(args) -> None:
    """Checks every command shares, before any work."""
    seed = getattr(args, "seed", None)   # None: check takes [tool.mcverify]'s or 0
    if seed is not None and not 0 <= seed <= MAX_SEED:
        raise InvalidArgument(f"--seed {seed}: must be in [0, 2^63 - 1]")
    if getattr(args, "alpha", None) is not None and not 0.0 < args.alpha < 1.0:
        raise InvalidArgument(f"--alpha {args.alpha}: must be strictly between 0 and 1")
    if hasattr(args, "jobs"):
        # -j 0, --dask with -j, a missing scheduler file: refused before the suite's
        # imports, a scene's plan or --budget's calibration (it was refused after them)
        _pool(args)
    if getattr(args, "refs", None) is not None:
        from . import reference

        reference.set_reference_root(args.refs)
    elif hasattr(args, "refs") and os.environ.get("MCVERIFY_REFS"):
        # checked as --refs is: a misspelt $MCVERIFY_REFS left every scene name unknown,
        # "no such file ... (known: none)", without naming the variable
        from . import reference

        reference.set_reference_root(os.environ["MCVERIFY_REFS"], "$MCVERIFY_REFS")


def _thread_limit() -> None:
    """``MCVERIFY_NUM_THREADS``: numba threads for this run's parallel loops, at most
    numba's own count (the pytest plugin sets it to an xdist worker's share, for the
    runs its tests start)."""
    value = os.environ.get("MCVERIFY_NUM_THREADS", "").strip()
    if not value:
        return
    if not value.isdigit() or int(value) < 1:
        raise InvalidArgument(f"MCVERIFY_NUM_THREADS={value!r}: must be a whole number >= 1")
    import numba

    numba.set_num_threads(min(int(value), numba.config.NUMBA_NUM_THREADS))


#: The commands that compile or load numba kernels through the kernel cache.
_KERNEL_COMMANDS = ("check", "render-check", "report", "bench")


def _kernel_cache(command: str) -> None:
    """The kernel cache (``$MCVERIFY_CACHE``, else ``~/.cache/mcverify/kernels``) must be a
    folder this run can write, for the commands that compile kernels: a file there, or a
    read-only folder, failed every check that compiles one ("raised FileExistsError",
    exit 1) as if the sampler were wrong. EnvironmentProblem naming it otherwise."""
    if command not in _KERNEL_COMMANDS:
        return
    import tempfile

    from estimators._generated import cache_dir, cache_path

    given = os.environ.get("MCVERIFY_CACHE")
    where = f"MCVERIFY_CACHE={given}" if given else f"the kernel cache {cache_path()}"
    try:
        folder = cache_dir()
        fd, probe = tempfile.mkstemp(dir=folder, prefix=".tmp-probe-")
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise EnvironmentProblem(f"{where}: cannot write kernels there ("
                                 f"{e.strerror or e}{': ' + e.filename if e.filename else ''}"
                                 "); set MCVERIFY_CACHE to a folder you can write") from None


def _hypothesis_home() -> None:
    """``check_stability`` runs hypothesis, which caches the constants of the user's modules
    in ``./.hypothesis``: a gate run left that folder in the project it was started in
    (an untracked folder in a CI checkout). Its storage goes to
    ``~/.cache/mcverify/hypothesis`` unless ``HYPOTHESIS_STORAGE_DIRECTORY`` says where;
    worker processes inherit the setting."""
    from estimators._generated import user_cache

    os.environ.setdefault("HYPOTHESIS_STORAGE_DIRECTORY", os.path.join(
        user_cache(), "mcverify", "hypothesis"))


#: SIGTERMs ``main``'s handler has turned into KeyboardInterrupt in this process
_TERMINATED: list = []


def _on_sigterm(signum, frame):
    _TERMINATED.append(signum)
    raise KeyboardInterrupt


@contextlib.contextmanager
def _sigterm_unwinds():
    """SIGTERM (a CI job cancelled, ``timeout``, ``kill``) raised as KeyboardInterrupt,
    so that a run stops as on Ctrl-C: its worker processes shut down, its temporary
    files removed. Python's default ended the process at once: ``-j N``'s workers
    stayed behind, idle, for good (they hold their own queue open). Not where SIGTERM is
    ignored or handled already, nor off the main thread; the handler that was there is
    put back on return."""
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL):
        yield
        return
    _TERMINATED.clear()
    signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _printable_streams() -> None:
    """stdout and stderr write what their encoding cannot hold as escapes (``\\u2248``):
    on a terminal that is not UTF-8 (``LANG=en_US.ISO-8859-1``, a Windows console,
    ``PYTHONIOENCODING=ascii``) a failing check's message, "largest discrepancy at x≈…",
    raised UnicodeEncodeError while its verdict was printed: exit 2 for a failed check,
    and no ``--json`` written."""
    for stream in (sys.stdout, sys.stderr):
        if hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="backslashreplace")


def main(argv=None) -> int:
    _printable_streams()
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:       # as parse_args says it, with the unquoted glob's hint where it applies
        # the hint only where every extra is a file argument: an unknown option with it
        # read as a glob's fault (a read-only review)
        command = _command_parser(parser, args)
        command.error(f"unrecognized arguments: {' '.join(extra)}"
                      + _unknown_option_hint(parser, command, extra)
                      + _expanded_glob(args, not any(e.startswith("-") for e in extra)))
    with _sigterm_unwinds():
        return _main(args)


def _subcommands(parser) -> dict:
    """The parsers of ``parser``'s commands (or of ``reference``'s actions), by name."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return action.choices
    return {}


def _command_parser(parser, args):
    """The parser of the command ``args`` ran: ``mcverify reference build``'s for it."""
    for name, sub in _subcommands(parser).items():
        if name in (args.command, getattr(args, "action", None)):
            return _command_parser(sub, args)
    return parser


def _options(parser) -> dict:
    """Every option string of every command, to the commands that take it."""
    found = {}
    for sub in _subcommands(parser).values():
        for option in sub._option_string_actions:
            found.setdefault(option, []).append(sub.prog.removeprefix("mcverify "))
        for option, commands in _options(sub).items():
            found.setdefault(option, []).extend(commands)
    return found


def _spoken(items: list, conjunction: str) -> str:
    """``a``, ``a and b``, ``a, b and c`` (or ``or``)."""
    return ", ".join(items[:-1]) + f" {conjunction} " * (len(items) > 1) + items[-1]


def _unknown_option_hint(parser, command, extra) -> str:
    """Where the first unknown option of ``extra`` is: another command's (``check --spp``:
    render-check's), or one of this command's misspelt (``--sed``: ``--seed``). argparse
    said "unrecognized arguments: --sed 3" alone, as Python before 3.14 does."""
    option = next((e.split("=", 1)[0] for e in extra if e.startswith("-") and len(e) > 1),
                  None)
    if option is None:
        return ""
    own = command.prog.removeprefix("mcverify ")
    if option in parser._option_string_actions:
        return f"; {option} goes before the command: mcverify {option}"
    elsewhere = [c for c in _options(parser).get(option, []) if c != own]
    if elsewhere:
        return f"; {option} is an option of {_spoken(elsewhere, 'and')}, not of {own}"
    # an option it begins first (`--pa`: --passes, where difflib's nearest was --spp;
    # a read-only review), else the nearest by spelling
    begun = sorted(o for o in command._option_string_actions if o.startswith(option))
    if begun:
        return f"; did you mean {_spoken(begun, 'or')}?"
    close = difflib.get_close_matches(option, list(command._option_string_actions), n=1)
    return f"; did you mean {close[0]}?" if close else ""


def _threading_layer(command: str) -> None:
    """numba's threading layer, started before any work by the commands that run its
    parallel loops: one it cannot load (``NUMBA_THREADING_LAYER=tbb`` without TBB, a
    misspelt name) raised ValueError inside the first check that ran a parallel loop,
    which failed ("raised ValueError: The threading layer requested 'bogus' is unknown
    to Numba", exit 1) as if its subject were wrong. EnvironmentProblem naming it."""
    if command not in _KERNEL_COMMANDS:
        return
    from numba.np.ufunc import parallel

    try:
        parallel._launch_threads()
    except ValueError as e:
        layer = os.environ.get("NUMBA_THREADING_LAYER")
        raise EnvironmentProblem(
            f"numba cannot start its threads ({' '.join(str(e).split())})"
            + (f": NUMBA_THREADING_LAYER={layer!r}; unset it, or install that layer"
               if layer else "")) from None


def _main(args) -> int:
    try:
        _validate_common(args)
        _threading_layer(args.command)     # before _thread_limit starts the threads
        _thread_limit()
        _kernel_cache(args.command)
        _hypothesis_home()
        return args.func(args)
    except KeyboardInterrupt:
        return _stopped()
    except Exception as e:  # noqa: BLE001 - a crash must not read as "a check failed" (1)
        if interrupted(e):
            # Ctrl-C (or SIGTERM) inside a library's import arrives wrapped: Dr.Jit's
            # extension, interrupted while it initialises, raises ImportError, its
            # __init__ then NameError, and the run said "unexpected NameError: name
            # '_drjit_ext' is not defined", exit 2
            return _stopped()
        return _failure(e)


def _stopped() -> int:
    """The one line and exit code of a run stopped by Ctrl-C (130) or SIGTERM (143)."""
    _end_progress_line()
    if _TERMINATED:
        print("mcverify: terminated (SIGTERM; outputs are written whole or not at all)",
              file=sys.stderr)
        return EXIT_TERMINATED
    print("mcverify: interrupted (outputs are written whole or not at all)",
          file=sys.stderr)
    return EXIT_INTERRUPTED


def _cwd_gone() -> str:
    """Where the current directory was deleted under the process (``os.getcwd()``
    fails), the words that say so, added to any error that ends the run: every command
    but a ``compare`` of absolute paths ended in "mcverify: error: No such file or
    directory", naming nothing (an outside review), and a relative scene or image path
    in "no such file" (a read-only review)."""
    try:
        os.getcwd()
    except FileNotFoundError:
        return (" (the current directory no longer exists: it was deleted or moved under "
                "this run; cd into a folder that exists and run again)")
    return ""


def _failure(e: Exception) -> int:
    """The one stderr line and exit code of an error that ended a run (called while it
    is handled: ``MCVERIFY_TRACEBACK`` re-raises it)."""
    _end_progress_line()
    if isinstance(e, (InvalidArgument, EnvironmentProblem)):
        print(f"mcverify: error: {escape_controls(' '.join(str(e).split()))}{_cwd_gone()}",
              file=sys.stderr)
        return EXIT_BAD_INPUT
    if isinstance(e, BrokenPipeError):
        # the reader closed the pipe (mcverify list | head -3): stop without a message,
        # as command-line tools do, and keep Python's exit-time flush from raising again
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_BROKEN_PIPE
    if isinstance(e, OSError):
        where = f"{e.filename}: " if e.filename else ""
        print(f"mcverify: error: {where}{e.strerror or e}{_cwd_gone()}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if os.environ.get("MCVERIFY_TRACEBACK"):
        raise e
    text = escape_controls(" ".join(str(e).split()))
    print(f"mcverify: error: unexpected {type(e).__name__}: {text} (set "
          "MCVERIFY_TRACEBACK=1 to see where)", file=sys.stderr)
    return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
