"""A serial numba loop over a range of items (blocks of rows, rows), run on several
threads: contiguous ranges, one a thread, the caller's own thread taking the first.

The loops that ran as numba ``prange`` loops (``parallel=True``) are plain ``nogil``
loops over ``range(b0, b1)`` instead, compiled with IEEE division as numba compiles a
parallel loop's body. They compute the same values as fast on one thread, and compile
in about half the time: numba's parfor passes analyse the whole loop again to split it
into a gufunc, and compile that body a second time (measured on an empty cache, AMD
Zen 1: the Beckmann sampler's loop 5.2 -> 3.0 s, the power-cosine inverse 8.2 -> 3.5 s,
at 28.1 -> 27.8 and 60.1 -> 57.2 ns a point on one thread).

The thread count is numba's (``numba.get_num_threads()``, which ``NUMBA_NUM_THREADS``
and ``numba.set_num_threads`` set), so that whoever limited numba's threads limits
these too; it is read without starting numba's threading layer (``get_num_threads``).
Each thread gets at least ``grain`` items, and fewer than two threads' worth run on the
caller's thread alone: handing work to another thread costs about 50 µs
(``ThreadPoolExecutor`` round trip, AMD Zen 1), so a thread's share should take longer.
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor

import numba

#: the fewest of the warps' 512-row blocks worth a thread of their own (about 80 µs)
MIN_BLOCKS = 16
#: ``njit`` options of a loop that these functions run, where nothing more is needed: a
#: serial loop over a range that releases the GIL, compiled with IEEE division (x/0 is
#: ±inf or NaN, no ZeroDivisionError branch) as numba compiles a ``prange`` body, and
#: cached on disk.
LOOP = {"cache": True, "nogil": True, "error_model": "numpy"}

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


def get_num_threads() -> int:
    """``numba.get_num_threads()`` (the calling thread's count), without starting numba's
    threading layer where nothing has started it yet: numba's own starts it, and these
    loops never use it. Started, a GNU OpenMP layer (numba's default where TBB is
    missing) kills a ``fork``ed child at its first ``parallel=True`` loop, "Terminating:
    fork() called from a process already using GNU OpenMP": a renderer that checked a
    sampler with mcverify, then rendered in a ``multiprocessing`` pool, hung on workers
    that had died (an outside review). Until the layer starts, no thread can have set a
    count (``numba.set_num_threads`` starts it), so the count is numba's
    ``NUMBA_NUM_THREADS``."""
    parallel = getattr(getattr(numba, "np", None), "ufunc", None)
    parallel = getattr(parallel, "parallel", None)
    if getattr(parallel, "_is_initialized", True):      # started, or laid out otherwise
        return numba.get_num_threads()
    return max(1, int(numba.config.NUMBA_NUM_THREADS))


def threads_for(count: int, grain: int = MIN_BLOCKS) -> int:
    """How many threads ``run_ranges`` uses for ``count`` items."""
    return max(1, min(get_num_threads(), count // grain))


def run_ranges(loop, count: int, *args, grain: int = MIN_BLOCKS) -> None:
    """``loop(*args, i0, i1)`` over ``[0, count)``: one contiguous range a thread, at
    least ``grain`` items each, the ranges as equal as whole items make them
    (``run_split``)."""
    t = threads_for(count, grain)
    run_split(loop, [count * i // t for i in range(t + 1)], *args)


def run_split(loop, cuts, *args) -> None:
    """``loop(*args, cuts[k], cuts[k + 1])`` for every k, each range on a thread of its
    own, the first on the caller's thread (an empty range is skipped, but one call is
    always made: a first call compiles). Returns once every range has run; the first
    error raised by one is raised here, after the others have finished (none writes
    into the caller's arrays after this returns)."""
    ranges = [(a, b) for a, b in zip(cuts[:-1], cuts[1:]) if b > a] or [(cuts[0], cuts[0])]
    if len(ranges) == 1:
        loop(*args, *ranges[0])
        return
    pool = _pool()
    others = [pool.submit(loop, *args, a, b) for a, b in ranges[1:]]
    try:
        loop(*args, *ranges[0])
    finally:
        errors = [f.exception() for f in others]       # waits for each
    for e in errors:
        if e is not None:
            raise e
