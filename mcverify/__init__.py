"""mcverify: statistical verification of Monte Carlo rendering code.

Public API
==========

==============================  ======================================================
``check_sampler``               χ² (+ marginals / KS) of a sampler against its pdf
``check_inverse``               CDF-inversion round trip ``inverse(sample(u)) ≈ u``
``check_stability``             property-based search (hypothesis) for a u at which a
                                sampler, its pdf or inverse breaks (edges, subnormals)
``check_pdf_consistency``       the pdf (and weight) a sampler returns with each draw
                                against ``pdf(x)`` (and ``f(x) / pdf(x)``): MIS's contract
``check_same_distribution``     two-sample test of two samplers (regression checks)
``detectable_contamination``    the power a ``check_sampler`` result had: the mixture
                                weight of uniform it would catch at 95 %
``check_unbiased``              t-test of per-sample estimates, heavy-tail aware;
                                group-sequential over batches (``batches=``)
``check_variance``              zero variance when p ∝ f, or a known variance
``check_convergence``           log-log slope of RMSE against N over seeds
``compare_images``              two renders, pixelwise: global, block and pixel tests
``render_check``                a renderer (ours by default) against a scene's Mitsuba
                                reference (gate layer: ``mcverify.gate.render_check``)
``CheckResult``, ``SuiteResult``  results as frozen data; ``to_dict()``
``write_json``, ``write_junit``   sinks (atomic writes)
``Interval``, ``Square``, ``Disk``, ``Sphere``, ``Hemisphere``  domains
``Domain``                      their base class (a subclass may change only the
                                repr, ``default_resolution`` and ``sample_dim``)
``InvalidArgument``             the one exception for bad input (a ValueError)
``EnvironmentProblem``          what the environment cannot do (a RuntimeError: a
                                missing package, an unusable Mitsuba variant)
``__version__``                 this package's version
==============================  ======================================================

Every randomised function takes ``seed``; the same seed gives the same result.

Layers: this package's core (``stats``, ``quadrature``, ``domains``, ``checks``,
``sequential`` (group-sequential looks), ``result``, ``errors``) imports neither the subject (``estimators``)
nor Mitsuba; ``mcverify.gate`` composes them (suites, scene plans, the render check,
references, the Mitsuba adapters, bench, report, CLI). ``render_check`` is re-exported
from the gate lazily, so ``import mcverify`` loads neither.
"""

import os as _os
import sys as _sys


def _numba_refused(e: ValueError):
    """numba raises ValueError as it is imported where ``NUMBA_NUM_THREADS`` is 0 or
    negative: ``mcverify check`` printed numba's traceback and exited 1, "a check failed".
    Run as the command line (``python -m mcverify``, whose package import is this one,
    or the ``mcverify`` script): one line naming the variable, exit 2; imported:
    ``EnvironmentProblem`` saying the same."""
    from .errors import EnvironmentProblem

    given = _os.environ.get("NUMBA_NUM_THREADS")
    text = (f"numba cannot start ({e})" + (f": NUMBA_NUM_THREADS={given!r}; set it to a "
            "whole number >= 1, or unset it" if given is not None else ""))
    script = _os.path.splitext(_os.path.basename(_sys.argv[0]))[0]   # mcverify.exe too
    if _sys.argv[:1] == ["-m"] or script == "mcverify":
        print(f"mcverify: error: {text}", file=_sys.stderr)
        raise SystemExit(2)
    raise EnvironmentProblem(text) from None


try:
    import numba  # noqa: F401 - numba refuses some settings as it is imported
except ValueError as _e:
    _numba_refused(_e)

from mcnumba.disk_cache import cache_in_temporary_folder, tolerate_damaged_cache
from mcnumba.vector_width import prefer_wide_vectors

prefer_wide_vectors()       # before any numba function is defined: see mcnumba.vector_width
tolerate_damaged_cache()    # a cache file cut short is a miss: see mcnumba.disk_cache
cache_in_temporary_folder()  # where numba has nowhere else to cache: see mcnumba.disk_cache

from ._version import __version__
from .checks import (check_convergence, check_inverse, check_pdf_consistency,
                     check_same_distribution,
                     check_sampler, check_stability, check_unbiased, check_variance,
                     compare_images, detectable_contamination)
from .domains import Disk, Domain, Hemisphere, Interval, Sphere, Square
from .errors import EnvironmentProblem, InvalidArgument
from .result import CheckResult, SuiteResult, write_json, write_junit

__all__ = [
    "check_sampler", "check_inverse", "check_same_distribution", "detectable_contamination",
    "check_unbiased", "check_variance", "check_convergence", "compare_images",
    "check_stability", "check_pdf_consistency", "render_check", "CheckResult", "SuiteResult", "write_json", "write_junit",
    "Domain", "Interval", "Square", "Disk", "Sphere", "Hemisphere",
    "InvalidArgument", "EnvironmentProblem", "__version__",
]


def __getattr__(name):
    # The gate layer's render check, imported on first use only (PEP 562): the core
    # stays free of the subject and of Mitsuba.
    if name == "render_check":
        from .gate.render_check import render_check

        return render_check
    raise AttributeError(f"module 'mcverify' has no attribute {name!r}")
