"""``mcverify`` command line: the CI gate.

Exit codes: 0 all checks passed; 1 a check failed (or the judge has no teeth); 2 bad
input or environment, with one line on stderr naming what and where.
"""

from __future__ import annotations

import argparse
import os
import sys

from ..errors import EnvironmentProblem, InvalidArgument

EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT = 0, 1, 2


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit 2 (argparse's own convention too)
        self.exit(EXIT_BAD_INPUT, f"mcverify: error: {message} (see `mcverify --help`)\n")


def _writable(option: str, path: str | None) -> None:
    """Fail before any work if an output path cannot be written."""
    if path is None:
        return
    folder = os.path.dirname(os.path.abspath(path)) or "."
    if os.path.isdir(path):
        raise InvalidArgument(f"{option} {path}: is a directory; give a file path")
    try:
        os.makedirs(folder, exist_ok=True)
    except OSError as e:
        raise InvalidArgument(f"{option} {path}: cannot create folder {folder} "
                              f"({e.strerror})") from None
    if not os.access(folder, os.W_OK):
        raise InvalidArgument(f"{option} {path}: folder {folder} is not writable")


def _progress(stream, verdicts: bool = True):
    tty = stream.isatty()

    def show(i, total, r):
        verdict = "ok" if r.passed else ("bitten" if "canary" in str(r.name) else "FAIL")
        verdict = verdict if verdicts else "done"
        line = f"[{i}/{total}] {r.name} {verdict} ({r.seconds:.1f}s)"
        if tty:
            stream.write("\r\033[K" + line + ("\n" if i == total else ""))
        else:
            stream.write(line + "\n")
        stream.flush()

    return show


def _mitsuba_provenance(selected) -> dict:
    """Mitsuba's version and variant for the provenance of a run that checks Mitsuba's
    warps, printing the fallback notice once; {} when no selected check uses Mitsuba."""
    if not any("mitsuba" in c.tags for c in selected):
        return {}
    from . import mitsuba as mv_mitsuba

    choice = mv_mitsuba.choose_variant()
    if choice.notice:
        print(f"notice: {choice.notice}", file=sys.stderr)
    return {"mitsuba_version": mv_mitsuba.mitsuba_version(), "mitsuba_variant": choice.variant}


def _suite_checks(args):
    """The suite(s) to run: ``--suite``, else ``[tool.mcverify]`` of the project's
    pyproject.toml, else "default". Fills in ``args.alpha``/``args.seed`` from the table
    where the command line left them; user suites import from the table's ``path`` and
    the current directory. Returns (suite name, checks, skipped, provenance)."""
    from . import suites
    from .usersuite import find_config

    config = find_config()
    names = (args.suite,) if args.suite else (config.suites if config and config.suites
                                              else ("default",))
    if args.alpha is None:
        args.alpha = config.alpha if config and config.alpha is not None else 0.01
    if args.seed is None:
        args.seed = config.seed if config and config.seed is not None else 0
    roots = [os.path.join(config.root, p) for p in config.path] if config else []
    roots.append(".")
    checks, skipped = [], []
    for n in names:
        c, s = suites.resolve_suite(n, roots=roots)
        checks += c
        skipped += s
    return "+".join(names), checks, skipped, ({"config": config.file} if config else {})


def _cmd_check(args) -> int:
    from . import suites
    from ..result import write_json, write_junit

    _writable("--json", args.json)
    _writable("--junit", args.junit)
    args.suite, checks, skipped, extra = _suite_checks(args)
    if args.scene:
        planned, skipped, _ = _plan(args.scene, args.suite)
        selected = suites.select(planned, args.k)
        extra["scene"] = os.path.abspath(args.scene)
    else:
        selected = suites.select(checks, args.k)
    if not selected and args.scene:
        print(f"mcverify check --scene {args.scene}: the scene needs no sampler or estimator "
              "checks", file=sys.stderr)
    elif not selected:
        raise InvalidArgument(f"-k {args.k!r}: matches no check of suite {args.suite!r}; "
                              "`mcverify list` shows the names")
    extra.update(_mitsuba_provenance(selected))
    result = suites.run_suite(selected, name=args.suite, seed=args.seed, alpha=args.alpha,
                              progress=None if args.quiet else _progress(sys.stderr),
                              extra_provenance=extra, skipped=skipped)
    if args.json:
        write_json(result, args.json)
    if args.junit:
        write_junit(result, args.junit)
    failed = [r for r in result.results if not r.passed]
    for r in failed:
        print(r.summary())
        for m in r.messages:
            print(f"    {m}")
    if not result.canary_bitten:
        for c in result.canary:
            if c.passed:
                print(f"FAIL judge has no teeth: planted bug {c.name!r} was not rejected "
                      f"(p={c.p_value:.3g})")
    if skipped and not args.scene:
        reasons = {}
        for _, why in skipped:
            reasons[why] = reasons.get(why, 0) + 1
        for why, count in reasons.items():
            print(f"skipped {count}: {why}")
    n = len(result.results)
    print(f"mcverify check --suite {args.suite}: {n - len(failed)} passed, {len(failed)} failed"
          f" (family-wise alpha={args.alpha} by {result.correction}; canaries "
          f"{'bitten' if result.canary_bitten else 'NOT bitten'}; {result.seconds:.1f}s)")
    return EXIT_OK if result.passed else EXIT_FAILED


def _plan(scene, suite):
    from estimators.pathtracer import SceneError

    from .plan import plan

    try:
        return plan(scene, suite)
    except SceneError as e:
        raise InvalidArgument(str(e)) from None


def _cmd_plan(args) -> int:
    checks, skipped, features = _plan(args.scene, args.suite)
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

    args.alpha = args.seed = 0   # not used by list
    _, checks, _, _ = _suite_checks(args)
    for c in suites.select(checks, args.k):
        print(c.name)
    return EXIT_OK


def _cmd_report(args) -> int:
    from . import suites
    from .report import build_report
    from .report.study import run_study

    out = args.out
    _writable("--out", os.path.join(out, "report.json"))
    show = None if args.quiet else _progress(sys.stderr)
    suite = None
    extra = {}
    if not args.no_suite:
        selected = suites.select(suites.build_suite(args.suite), args.k)
        if not selected:
            raise InvalidArgument(f"-k {args.k!r}: matches no check of suite {args.suite!r}")
        extra = _mitsuba_provenance(selected)
        suite = suites.run_suite(selected, name=args.suite, seed=args.seed, progress=show,
                                 extra_provenance=extra)
    # Study rows are judged together (Holm) at the end: no per-row verdict while running.
    study = run_study(seed=args.seed,
                      progress=None if args.quiet else _progress(sys.stderr, verdicts=False))
    renders = None
    if args.renders != "none":
        from .reference import list_scenes, resolve_scene
        from .report.renders import run_renders

        scenes = list_scenes() if args.renders == "all" else args.renders.split(",")
        for s in scenes:
            resolve_scene(s)                                     # fail before any work
        renders = run_renders(scenes, seed=args.seed, progress=show)
    build_report(out, suite=suite, study=study, renders=renders,
                 extra_provenance=dict(extra, seed=args.seed))
    print(f"mcverify report: wrote {os.path.join(out, 'report.html')} and report.json")
    return EXIT_OK


def _cmd_bench(args) -> int:
    import json

    from .bench import run_bench
    from ..provenance import provenance
    from ..result import atomic_write

    _writable("--json", args.json)
    if args.repeats < 1:
        raise InvalidArgument(f"--repeats {args.repeats}: must be >= 1")
    if args.spp < 4:
        raise InvalidArgument(f"--spp {args.spp}: must be >= 4")
    if args.n < 1000:
        raise InvalidArgument(f"--n {args.n}: must be >= 1000 (timings of fewer points "
                              "measure call overhead, not work)")
    from . import mitsuba as mv_mitsuba

    choice = mv_mitsuba.choose_variant()
    if choice.notice:
        print(f"notice: {choice.notice}", file=sys.stderr)

    def show(i, total, row):
        if not args.quiet:
            print(f"[{i}/{total}] {row['group']} done", file=sys.stderr)

    rows = run_bench(repeats=args.repeats, n=args.n, spp=args.spp,
                     renders=not args.no_render, progress=show)
    print(f"{'workload':30s} {'ours':>10s} {'theirs':>10s} {'ours/theirs':>12s}  against")
    for r in rows:
        if "ours_rmse" in r:
            print(f"{r['group']:30s} {r['ours_rmse']:10.4g} {r['mitsuba_rmse']:10.4g} "
                  f"{r['ratio']:12.2f}  mitsuba (RMSE at equal time)")
            continue
        m = "n/a" if r["mitsuba_s"] is None else f"{r['mitsuba_s']:.4f}"
        ratio = "n/a" if r["ratio"] is None else f"{r['ratio']:.2f}"
        print(f"{r['group']:30s} {r['ours_s']:10.4f} {m:>10s} {ratio:>12s}  {r['against']} "
              "(seconds)")
    if args.json:
        doc = {"provenance": provenance(mitsuba_version=mv_mitsuba.mitsuba_version(),
                                        mitsuba_variant=choice.variant, repeats=args.repeats),
               "results": rows}
        atomic_write(args.json, json.dumps(doc, indent=2) + "\n")
    return EXIT_OK


def _cmd_reference_build(args) -> int:
    from . import reference

    names = args.scenes or reference.list_scenes()
    if not names:
        raise InvalidArgument(f"no scenes given and none under {reference.REFERENCE_ROOT}")
    resolved = [reference.resolve_scene(s) for s in names]    # fail before any rendering
    from . import mitsuba as mv_mitsuba

    choice = mv_mitsuba.choose_variant()
    if choice.notice:
        print(f"notice: {choice.notice}", file=sys.stderr)
    for name, path in resolved:
        def show(i, total, name=name):
            if not args.quiet:
                print(f"[{name}] pass {i}/{total}", file=sys.stderr)

        out = reference.build_reference(path, spp=args.spp, passes=args.passes, seed=args.seed,
                                        progress=show)
        print(f"built {out} ({args.passes} passes × {args.spp} spp, {choice.variant})")
    return EXIT_OK


def _cmd_compare(args) -> int:
    from . import mitsuba as mv_mitsuba
    from . import reference
    from ..checks import compare_images
    from ..result import write_json

    _writable("--json", args.json)
    test = mv_mitsuba.read_exr(args.test)
    test_var = mv_mitsuba.read_exr(args.test_var)
    if os.path.isfile(args.ref):
        if args.ref_var is None or args.ref_n is None:
            raise InvalidArgument(f"{args.ref}: an image reference needs --ref-var and --ref-n")
        ref, ref_var, ref_n = mv_mitsuba.read_exr(args.ref), mv_mitsuba.read_exr(args.ref_var), \
            args.ref_n
    else:
        r = reference.load_reference(args.ref)
        ref, ref_var, ref_n = r.mean, r.var, r.n
    if test.shape != ref.shape:
        raise InvalidArgument(f"{args.test}: shape {test.shape} differs from the reference's "
                              f"{ref.shape}")
    result = compare_images(test, ref, test_var=test_var, ref_var=ref_var, test_n=args.test_n,
                            ref_n=ref_n, alpha=args.alpha, name=f"compare:{args.test}")
    if args.json:
        write_json(result, args.json)
    print(result.summary())
    for m in result.messages:
        print(f"    {m}")
    return EXIT_OK if result.passed else EXIT_FAILED


def _params(items) -> dict:
    out = {}
    for item in items or ():
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise InvalidArgument(f"--param {item!r}: expected NAME=VALUE")
        out[key] = value
    return out


def _cmd_render_check(args) -> int:
    from .render_check import render_check
    from ..result import write_json

    _writable("--json", args.json)
    tty = sys.stderr.isatty() and not args.quiet

    def show(done, total):
        if tty:
            sys.stderr.write(f"\r\033[K[render] {100 * done // total}%")
            if done == total:
                sys.stderr.write("\r\033[K")
            sys.stderr.flush()

    result = render_check(args.scene, spp=args.spp, passes=args.passes, seed=args.seed,
                          alpha=args.alpha, params=_params(args.param),
                          notice=None if args.quiet else
                          (lambda m: print(f"notice: {m}", file=sys.stderr)),
                          progress=show if tty else None)
    if args.json:
        write_json(result, args.json)
    d = result.details
    print(result.summary())
    for m in result.messages:
        print(f"    {m}")
    print(f"    ours: {d['ours_passes']} passes, {d['ours_spp']} spp, {d['ours_seconds']:.2f}s "
          f"({d['ours_samples_per_second'] / 1e6:.2f} M samples/s, {d['ours_kernel']}); "
          f"relMSE {d['relmse']:.3g}; found by: {', '.join(d['found_by']) or 'nothing'}")
    return EXIT_OK if result.passed else EXIT_FAILED


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="mcverify", description=__doc__.splitlines()[0])
    from .._version import __version__

    p.add_argument("--version", action="version", version=f"mcverify {__version__}")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)
    suite_help = ("default, full, mitsuba (Mitsuba's own plugins), or MODULE:ATTR (your "
                  "list of mcverify.gate.suites.Check, or a callable returning one); "
                  "default: [tool.mcverify] suite of pyproject.toml, else default")
    c = sub.add_parser("check", help="run a verification suite (the CI gate)")
    c.add_argument("--suite", metavar="SUITE", help=suite_help)
    c.add_argument("--scene", metavar="SCENE.xml", help="plan checks from a scene")
    c.add_argument("-k", metavar="PATTERN", help="only checks whose name contains PATTERN "
                   "(or matches it as a glob)")
    c.add_argument("--seed", type=int, help="suite seed (default: [tool.mcverify] seed, "
                   "else 0)")
    c.add_argument("--alpha", type=float,
                   help="family-wise significance level (Holm across checks; default: "
                        "[tool.mcverify] alpha, else 0.01)")
    c.add_argument("--json", metavar="PATH", help="write the results as JSON")
    c.add_argument("--junit", metavar="PATH", help="write the results as JUnit XML")
    c.add_argument("-q", "--quiet", action="store_true", help="no progress lines")
    c.set_defaults(func=_cmd_check)
    ls = sub.add_parser("list", help="list the checks of a suite")
    ls.add_argument("--suite", metavar="SUITE", help=suite_help)
    ls.add_argument("-k", metavar="PATTERN")
    ls.set_defaults(func=_cmd_list)
    pl = sub.add_parser("plan", help="the checks a scene needs, and what is skipped")
    pl.add_argument("scene", metavar="SCENE.xml")
    pl.add_argument("--suite", choices=("default", "full"), default="default")
    pl.add_argument("-v", "--verbose", action="store_true")
    pl.set_defaults(func=_cmd_plan)
    rp = sub.add_parser("report", help="convergence, efficiency and verification report")
    rp.add_argument("--out", default=os.path.join("reports", "report"), metavar="DIR")
    rp.add_argument("--suite", choices=("default", "full"), default="default")
    rp.add_argument("-k", metavar="PATTERN", help="only these checks in the verification part")
    rp.add_argument("--no-suite", action="store_true", help="convergence study only")
    rp.add_argument("--renders", default="all", metavar="SCENES",
                    help="reference scenes to render and compare (comma-separated), "
                         "'all' (default) or 'none'")
    rp.add_argument("--seed", type=int, default=0)
    rp.add_argument("-q", "--quiet", action="store_true")
    rp.set_defaults(func=_cmd_report)
    b = sub.add_parser("bench", help="run time, ours vs Mitsuba, as ratios")
    b.add_argument("--json", metavar="PATH")
    b.add_argument("--repeats", type=int, default=5)
    b.add_argument("--n", type=int, default=1_000_000, help="points per workload")
    b.add_argument("--spp", type=int, default=64, help="samples per pixel of the renders")
    b.add_argument("--no-render", action="store_true", help="skip the path-tracer rows")
    b.add_argument("-q", "--quiet", action="store_true")
    b.set_defaults(func=_cmd_bench)
    ref = sub.add_parser("reference", help="Mitsuba reference renders")
    rsub = ref.add_subparsers(dest="action", required=True, parser_class=_Parser)
    rb = rsub.add_parser("build", help="(re)render references with per-pixel variance")
    rb.add_argument("scenes", nargs="*", metavar="SCENE",
                    help="reference names or scene.xml paths (default: all)")
    rb.add_argument("--spp", type=int, default=256,
                    help="samples per pixel of each pass (the reference's own noise sets a "
                         "floor under the gate's sensitivity)")
    rb.add_argument("--passes", type=int, default=16)
    rb.add_argument("--seed", type=int, default=0)
    rb.add_argument("-q", "--quiet", action="store_true")
    rb.set_defaults(func=_cmd_reference_build)
    cp = sub.add_parser("compare", help="compare any renderer's EXR with a reference")
    cp.add_argument("test", metavar="TEST.exr")
    cp.add_argument("ref", metavar="REF", help="REF.exr or a reference name")
    cp.add_argument("--test-var", required=True, metavar="VAR.exr")
    cp.add_argument("--test-n", required=True, type=int)
    cp.add_argument("--ref-var", metavar="VAR.exr")
    cp.add_argument("--ref-n", type=int)
    cp.add_argument("--alpha", type=float, default=0.01)
    cp.add_argument("--json", metavar="PATH")
    cp.set_defaults(func=_cmd_compare)
    rc = sub.add_parser("render-check", help="our path tracer against the scene's Mitsuba "
                        "reference, pixel by pixel")
    rc.add_argument("scene", metavar="SCENE", help="scene.xml path or reference name")
    rc.add_argument("--spp", type=int, default=1024, help="samples per pixel in all")
    rc.add_argument("--passes", type=int, default=16, help="independent passes (>= 2)")
    rc.add_argument("--seed", type=int, default=0)
    rc.add_argument("--alpha", type=float, default=0.01)
    rc.add_argument("--param", action="append", metavar="NAME=VALUE",
                    help="override a scene <default> (both renderers); the reference is "
                         "then rendered on the fly")
    rc.add_argument("--json", metavar="PATH")
    rc.add_argument("-q", "--quiet", action="store_true")
    rc.set_defaults(func=_cmd_render_check)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if (getattr(args, "seed", 0) or 0) < 0:
        print(f"mcverify: error: --seed {args.seed}: must be >= 0", file=sys.stderr)
        return EXIT_BAD_INPUT
    if getattr(args, "alpha", None) is not None and not 0.0 < args.alpha < 1.0:
        print(f"mcverify: error: --alpha {args.alpha}: must be strictly between 0 and 1",
              file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        return args.func(args)
    except (InvalidArgument, EnvironmentProblem) as e:
        print(f"mcverify: error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as e:
        print(f"mcverify: error: {e.filename or ''}: {e.strerror or e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("mcverify: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
