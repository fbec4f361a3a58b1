"""Provenance stamped on every saved result (pytest-benchmark's saved-run habit)."""

from __future__ import annotations

import datetime as _dt
import os
import platform
import subprocess
from functools import lru_cache

from ._version import __version__


@lru_cache(maxsize=1)
def git_commit() -> str | None:
    """The commit of the checkout mcverify runs from, or None outside a git tree."""
    here = os.path.dirname(os.path.abspath(__file__))
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=here, capture_output=True,
                             text=True, timeout=5, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None


def provenance(**extra) -> dict:
    """Package version, git commit, machine, Python/numpy/scipy versions, UTC time,
    plus whatever the caller adds (seeds, mitsuba variant, suite)."""
    import numpy
    import scipy

    info = {
        "mcverify_version": __version__,
        "git_commit": git_commit(),
        "machine": {"node": platform.node(), "system": platform.system(),
                    "machine": platform.machine(), "cpu_count": os.cpu_count(),
                    "python": platform.python_version()},
        "numpy": numpy.__version__,
        "scipy": scipy.__version__,
        "utc_time": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
    }
    info.update(extra)
    return info
