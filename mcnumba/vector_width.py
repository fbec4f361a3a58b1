"""512-bit vectors on AVX-512 machines: numba's code for the subject's and the judge's loops.

LLVM tunes its code for most AVX-512 CPUs with ``prefer-256-bit``: its loop vectoriser
then uses 256-bit registers (4 float64 lanes), a choice made for old server CPUs whose
clock dropped under 512-bit code. Our vectorised loops (the warps' array front ends,
the judge's histogram) are compute-bound, and measured on one thread of this project's
machines (AVX-512, 1M points; ``mcverify bench`` and its notes) they run 1.3-1.5× as
fast with 512-bit vectors: cosine hemisphere 6.4 -> 5.1 ms, uniform sphere 7.6 -> 5.0,
Beckmann 12.5 -> 9.2, the χ² check 39 -> 29 ms, renders unchanged (±4 %). The results
are bit-identical (no reassociation: numba compiles without fast-math).

``prefer_wide_vectors()`` runs when ``estimators`` or ``mcverify`` is imported (either
may come first), before any of their numba functions is defined. Numba reads
``NUMBA_CPU_FEATURES`` when its code generator starts (at the process's first ``@njit``),
so it sets that variable, unless the user has set it or ``NUMBA_CPU_NAME``, to the host's
features with ``-prefer-256-bit``; child processes (workers) inherit it. Only numba's
``config.CPU_FEATURES`` follows it in this process: settings the caller made in code
before the import (``numba.config.THREADING_LAYER = "workqueue"``, ``BOUNDSCHECK``,
``CACHE_DIR``) stay as they were (a ``config.reload_config()`` here read every setting
from the environment again and put those back to their defaults). A process that
defined numba functions before importing either package keeps its code generator as it
is. Numba's cache is keyed by the features, so code compiled either way is never
confused. Set ``NUMBA_CPU_FEATURES`` yourself (for example to
``numba.core.codegen.get_host_cpu_features()``) to keep LLVM's choice.
"""

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
    value = f"{features},{FEATURE}"
    os.environ["NUMBA_CPU_FEATURES"] = value
    _adopt(config, "NUMBA_CPU_FEATURES", value)
    config.CPU_FEATURES = value
    return True


def _adopt(config, name: str, value: str) -> None:
    """Tell numba's config that the environment variable ``name`` it last read is
    ``value`` now: its compiler reloads every setting from the environment at each
    compilation where a ``NUMBA_`` variable differs from what it last read, which would
    put the caller's settings made in code back to their defaults. Where numba keeps no
    such record (another version), its config is reloaded as before."""
    seen = getattr(getattr(config, "_env_reloader", None), "old_environ", None)
    if isinstance(seen, dict):
        seen[name] = value
    else:
        config.reload_config()
