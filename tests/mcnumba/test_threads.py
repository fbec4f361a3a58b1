"""``mcnumba.threads``: a serial block loop run on numba's threads."""

import multiprocessing
import re
import threading
import time

import numba
import numpy as np
import pytest
from numba import njit

from mcnumba import threads as _threads
from estimators._compile_options import FUSED, THREADED
from mcnumba.threads import MIN_BLOCKS, run_ranges, run_split, threads_for


@njit(nogil=True)
def _mark(seen, b0, b1):
    for b in range(b0, b1):
        seen[b] += 1


def _recorder():
    calls = []
    lock = threading.Lock()

    def loop(tag, b0, b1):
        with lock:
            calls.append((tag, b0, b1, threading.get_ident()))
    return loop, calls


@pytest.mark.parametrize("blocks", [0, 1, MIN_BLOCKS - 1, 2 * MIN_BLOCKS - 1, 2 * MIN_BLOCKS,
                                    5 * MIN_BLOCKS + 3, 1000])
def test_every_block_runs_once_in_one_contiguous_range_a_thread(blocks, numba_threads):
    numba_threads(numba.config.NUMBA_NUM_THREADS)
    loop, calls = _recorder()
    run_ranges(loop, blocks, "x")
    ranges = sorted((b0, b1) for _, b0, b1, _ in calls)
    covered = [b for b0, b1 in ranges for b in range(b0, b1)]
    assert covered == list(range(blocks))
    want = max(1, min(numba.config.NUMBA_NUM_THREADS, blocks // MIN_BLOCKS))
    assert len(calls) == want == threads_for(blocks)
    assert len({ident for *_, ident in calls}) == want           # each on its own thread
    sizes = [b1 - b0 for b0, b1 in ranges]
    assert max(sizes) - min(sizes) <= 1
    assert all(tag == "x" for tag, *_ in calls)


def test_a_numba_loop_marks_each_block_once(numba_threads):
    numba_threads(numba.config.NUMBA_NUM_THREADS)
    seen = np.zeros(777, np.int64)
    run_ranges(_mark, seen.shape[0], seen)
    assert np.all(seen == 1)


def test_numbas_thread_count_limits_the_threads(numba_threads):
    numba_threads(1)
    loop, calls = _recorder()
    run_ranges(loop, 100 * MIN_BLOCKS, None)
    assert [(b0, b1) for _, b0, b1, _ in calls] == [(0, 100 * MIN_BLOCKS)]
    assert calls[0][3] == threading.get_ident()                   # on the caller's thread


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs two of numba's threads")
@pytest.mark.parametrize("failing", ["caller", "helper"])
def test_an_error_is_raised_once_every_range_has_finished(failing, numba_threads):
    numba_threads(2)
    finished = []

    def loop(b0, b1):
        mine = "caller" if b0 == 0 else "helper"
        if mine == failing:
            raise ValueError(f"{mine} failed")
        time.sleep(0.2)
        finished.append(mine)

    with pytest.raises(ValueError, match=f"{failing} failed"):
        run_ranges(loop, 4 * MIN_BLOCKS)
    assert finished == ["helper" if failing == "caller" else "caller"]


def _child(q):
    loop, calls = _recorder()
    run_ranges(loop, 4 * MIN_BLOCKS, None)
    q.put(sorted((b0, b1) for _, b0, b1, _ in calls))


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs two of numba's threads")
@pytest.mark.skipif("fork" not in multiprocessing.get_all_start_methods(), reason="no fork")
def test_a_forked_child_gets_threads_of_its_own(numba_threads):
    """The parent's pool is made, then a forked child (which inherits the executor but
    not its threads) runs blocks on two threads without hanging."""
    numba_threads(2)
    run_ranges(_recorder()[0], 4 * MIN_BLOCKS, None)
    assert _threads._POOL[0] is not None
    ctx = multiprocessing.get_context("fork")
    q = ctx.Queue()
    p = ctx.Process(target=_child, args=(q,))
    p.start()
    try:
        got = q.get(timeout=60)
    finally:
        p.join(timeout=60)
    assert got == [(0, 2 * MIN_BLOCKS), (2 * MIN_BLOCKS, 4 * MIN_BLOCKS)]


@pytest.mark.skipif(not hasattr(__import__("os"), "fork"), reason="no fork")
def test_a_check_leaves_numbas_threading_layer_unstarted_for_a_forked_child(run_python):
    """The loops read numba's thread count without starting its threading layer, which
    they never use: started (``numba.get_num_threads()`` starts it), a GNU OpenMP layer
    killed a forked child at its first ``parallel=True`` loop, "Terminating: fork()
    called from a process already using GNU OpenMP", and a renderer's
    ``multiprocessing`` pool, forked after a ``check_sampler``, hung on its dead workers
    (an outside review). A fresh process checks a sampler, then forks a child that runs
    a ``prange`` loop."""
    out = run_python(
        "import os\n"
        "import numpy as np\n"
        "from numba import njit, prange\n"
        "from numba.np.ufunc import parallel\n"
        "import mcverify as mv\n"
        "r = mv.check_sampler(lambda u: np.sqrt(u), lambda x: 2 * x[:, 0], 'interval',\n"
        "                     n_samples=100_000, seed=1)\n"
        "print(r.passed, parallel._is_initialized)\n"
        "@njit(parallel=True)\n"
        "def total(a):\n"
        "    s = 0.0\n"
        "    for i in prange(a.size):\n"
        "        s += a[i]\n"
        "    return s\n"
        "pid = os.fork()\n"
        "if pid == 0:\n"
        "    os._exit(0 if total(np.ones(1000)) == 1000.0 else 3)\n"
        "print(os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1]))\n", timeout=300)
    assert out.splitlines()[-2:] == ["True False", "0"], out


def test_run_split_runs_the_given_ranges_skipping_empty_ones(numba_threads):
    numba_threads(numba.config.NUMBA_NUM_THREADS)
    loop, calls = _recorder()
    run_split(loop, [0, 3, 3, 10], "y")
    assert sorted((b0, b1) for _, b0, b1, _ in calls) == [(0, 3), (3, 10)]
    loop, calls = _recorder()
    run_split(loop, [5, 5, 5], "z")                 # nothing to do: one call, to compile
    assert [(b0, b1) for _, b0, b1, _ in calls] == [(5, 5)]


@pytest.mark.parametrize("n, threads", [(0, 1), (1, 2), (10, 3), (10, 4), (256, 2), (7, 16)])
def test_dealt_tiles_start_where_each_threads_cards_start(n, threads):
    """``render._dealt`` cuts ``render._tiles``'s dealt list where each thread's cards
    start: the block of thread i holds tiles i, i + threads, ..."""
    from estimators.pathtracer.render import _dealt
    order = list(range(n))
    dealt = [k for i in range(threads) for k in order[i::threads]]
    cuts = _dealt(n, threads)
    assert cuts[0] == 0 and cuts[-1] == n and len(cuts) == threads + 1
    for i in range(threads):
        assert dealt[cuts[i]:cuts[i + 1]] == order[i::threads]


@njit(inline="always", error_model="numpy")
def _density(x, p):
    return 1.0 / (p[1] - p[0]) if p[0] <= x <= p[1] else 0.0


def _body(a, w, out, i0, i1):
    for i in range(i0, i1):
        out[i] = _density(a[i], w)


def test_threaded_loops_compile_as_a_parallel_body_with_the_same_values():
    """``_compile_options.THREADED``: the loop's array arguments are ``noalias`` for LLVM
    and the copies of ``w`` that inlining makes are gone (no reference count update in
    the loop, where the plain compilation has them), with the same values."""
    plain = njit(nogil=True, **FUSED)(_body)
    threaded = njit(**THREADED, **FUSED)(_body)
    a, w = np.linspace(0.0, 5.0, 1000), np.array([2.0, 3.0])
    out = [np.zeros(1000), np.zeros(1000)]
    plain(a, w, out[0], 0, 1000)
    run_ranges(threaded, 1000, a, w, out[1], grain=100)
    assert np.array_equal(out[0], out[1])
    assert np.array_equal(out[1], np.where((a >= 2.0) & (a <= 3.0), 1.0, 0.0))

    def body(f):
        ir = f.inspect_llvm(f.signatures[0])
        start = ir.index("define")
        return ir[start:ir.index("\n}\n", start)]

    def data_pointers(text):      # the attributes of each array's data pointer
        return re.findall(r"ptr ([^,%]*)%arg\.\w+\.4\b", text.split("\n")[0])

    assert all("noalias" in p for p in data_pointers(body(threaded)))
    assert not any("noalias" in p for p in data_pointers(body(plain)))
    assert len(data_pointers(body(threaded))) == 3
    assert "NRT_incref" in body(plain) and "NRT_incref" not in body(threaded)
