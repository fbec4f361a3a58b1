"""512-bit vectors on AVX-512 machines for the judge's numba loops (the histogram): a
copy of ``estimators/_vector_width.py``, whose docstring has the measurements and the
mechanism. A copy, because the core may not import the subject (``tests/test_layers.py``)
and either package may be imported first; ``tests/test_layers.py`` holds the two to the
same source."""

from __future__ import annotations

import os

#: the tuning flag removed from the host's features (a no-op where LLVM does not set it)
FEATURE = "-prefer-256-bit"


def prefer_wide_vectors() -> bool:
    """Set ``NUMBA_CPU_FEATURES`` for 512-bit vectors on an AVX-512 host; True if it
    did (the variable and ``NUMBA_CPU_NAME`` unset, the host has AVX-512F)."""
    if "NUMBA_CPU_FEATURES" in os.environ or "NUMBA_CPU_NAME" in os.environ:
        return False
    from numba.core import config
    from numba.core.codegen import get_host_cpu_features

    features = get_host_cpu_features()      # numba's default ('' if LLVM cannot tell)
    if "+avx512f" not in features.split(","):
        return False
    os.environ["NUMBA_CPU_FEATURES"] = f"{features},{FEATURE}"
    config.reload_config()
    return True
