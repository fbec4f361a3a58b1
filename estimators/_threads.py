"""A serial numba loop over a range of blocks, run on several threads: contiguous ranges,
one a thread, the caller's own thread taking the first.

The loops that ran as numba ``prange`` loops (``parallel=True``) are plain ``nogil``
loops over ``range(b0, b1)`` instead, compiled with IEEE division as numba compiles a
parallel loop's body. They compute the same values as fast on one thread, and compile
in about half the time: numba's parfor passes analyse the whole loop again to split it
into a gufunc, and compile that body a second time (measured on an empty cache, AMD
Zen 1: the Beckmann sampler's loop 5.2 -> 3.0 s, the power-cosine inverse 8.2 -> 3.5 s,
at 28.1 -> 27.8 and 60.1 -> 57.2 ns a point on one thread).

The thread count is numba's (``numba.get_num_threads()``, which ``NUMBA_NUM_THREADS``
and ``numba.set_num_threads`` set), so that whoever limited numba's threads limits
these too. A range of fewer than ``MIN_BLOCKS`` blocks a thread runs on the caller's
thread alone: handing work to another thread costs tens of microseconds.
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor

import numba

#: the fewest blocks worth a thread of their own
MIN_BLOCKS = 16

_POOL: list = [None, None]          # (executor, the pid that made it)
_POOL_LOCK = threading.Lock()


def _pool() -> ThreadPoolExecutor:
    """The process's helper threads (made on first use; made again in a forked child,
    which inherits the executor but not its threads)."""
    with _POOL_LOCK:
        if _POOL[0] is None or _POOL[1] != os.getpid():
            _POOL[0] = ThreadPoolExecutor(max(1, numba.config.NUMBA_NUM_THREADS - 1),
                                          thread_name_prefix="estimators")
            _POOL[1] = os.getpid()
        return _POOL[0]


def threads_for(blocks: int) -> int:
    """How many threads ``run_blocks`` uses for ``blocks`` blocks."""
    return max(1, min(numba.get_num_threads(), blocks // MIN_BLOCKS))


def run_blocks(loop, blocks: int, *args) -> None:
    """``loop(*args, b0, b1)`` over ``[0, blocks)``: one contiguous range a thread, the
    ranges as equal as whole blocks make them. Returns once every range has run; the
    first error raised by one is raised here, after the others have finished (none
    writes into the caller's arrays after this returns)."""
    t = threads_for(blocks)
    if t == 1:
        loop(*args, 0, blocks)
        return
    cut = [blocks * i // t for i in range(t + 1)]
    pool = _pool()
    others = [pool.submit(loop, *args, cut[i], cut[i + 1]) for i in range(1, t)]
    try:
        loop(*args, cut[0], cut[1])
    finally:
        errors = [f.exception() for f in others]       # waits for each
    for e in errors:
        if e is not None:
            raise e
