"""What the benchmark scripts share on their command lines: counts that must be whole and
positive, and a ``run(main)`` that turns a refused value (a scene name that is no scene,
a scene the tracer refuses) into one ``error:`` line and exit 2, as ``mcverify`` does.
Until 7 December such inputs ended in a raw traceback, or ran: ``--n -5`` in numpy's
"negative dimensions", ``warp_speed.py --repeats 0`` printed ``inf`` for every warp."""

from __future__ import annotations

import argparse
import os
import sys


def count(text: str) -> int:
    """A positive whole number, also written as a float (``--n 1e6``)."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (v >= 1 and v.is_integer()):     # inf and NaN too (int(inf) raised)
        raise argparse.ArgumentTypeError(f"{text!r}: must be a whole number >= 1")
    return int(v)


def seconds(text: str) -> float:
    """A positive, finite duration in seconds."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 0 < v < float("inf"):
        raise argparse.ArgumentTypeError(f"{text!r}: must be a number of seconds > 0")
    return v


def run(main) -> None:
    """``main()``, with the project's refusals (``InvalidArgument``, ``EnvironmentProblem``,
    ``SceneError``) said in one line on stderr and exit 2 instead of a traceback."""
    from estimators.pathtracer import SceneError
    from mcverify.errors import EnvironmentProblem, InvalidArgument

    try:
        main()
    except (InvalidArgument, EnvironmentProblem, SceneError) as e:
        print(f"{os.path.basename(sys.argv[0])}: error: {e}", file=sys.stderr)
        sys.exit(2)
