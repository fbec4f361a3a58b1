"""Where the gate's independent units of work run: in this process, in local worker
processes (``-j N``) or on a Dask cluster (``--dask``), behind one ``concurrent.futures``
interface.

A *unit* is a module-level function and picklable arguments (a check named within its
suite's recipe and its seed; one reference pass; one render pass). Seeds derive from
names and pass indices, never from which worker runs a unit or when, and results are
handed back in the order the units were given; so every result (timings aside) is
bit-identical whatever the executor.

A worker that dies mid-run (killed, out of memory, a crash in native code) never
leaves a silent gap: with local processes the pool is restarted and the units that were
in flight are run again (``retries`` times, 1 by default); Dask's scheduler reruns them
itself (``distributed.scheduler.allowed-failures``). A unit that still cannot finish
raises ``WorkerLost`` naming it (the CLI exits 2).
"""

from __future__ import annotations

import asyncio
import concurrent.futures as cf
import hashlib
import json
import multiprocessing
import multiprocessing.synchronize
import os
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any, Callable, Iterable, Iterator

from ..errors import EnvironmentProblem, InvalidArgument

__all__ = ["Unit", "Pool", "WorkerLost", "InProcessExecutor", "source_fingerprint",
           "same_source"]

#: How long ``--dask`` keeps trying to reach the scheduler (Dask retries a refused
#: connection until then) before the run stops with an environment problem.
DASK_CONNECT_TIMEOUT = "20s"
#: Seconds to wait for a first worker of a Dask scheduler before refusing it.
DASK_WORKER_WAIT = 30
#: The most local workers: the process pool's call queue holds one more call than it has
#: workers, in a semaphore that counts to ``SEM_VALUE_MAX`` (-j 99999999999 was an
#: "unexpected OverflowError" naming no option).
MAX_JOBS = multiprocessing.synchronize.SEM_VALUE_MAX - cf.process.EXTRA_QUEUED_CALLS


class WorkerLost(EnvironmentProblem):
    """A unit's worker died and the unit could not be finished elsewhere."""


@dataclass(frozen=True)
class Unit:
    """One independent piece of work: ``fn(*args)`` with ``fn`` defined at module level
    (workers import it by name) and picklable ``args``. ``key`` names it in progress
    lines and errors."""

    key: str
    fn: Callable
    args: tuple = ()


class InProcessExecutor(cf.Executor):
    """A ``concurrent.futures.Executor`` that runs each call in the calling thread, at
    submission: the default executor (no pickling, no workers, exceptions as raised)."""

    def submit(self, fn, /, *args, **kwargs):
        f = cf.Future()
        f.set_running_or_notify_cancel()
        try:
            result = fn(*args, **kwargs)
        except BaseException as e:  # noqa: BLE001 - delivered through the future
            f.set_exception(e)
        else:
            # outside the try: a Ctrl-C landing inside set_result, once the future was
            # finished, went to set_exception, whose InvalidStateError ("FINISHED")
            # ended `reference build` with exit 2 instead of 130 (seen once in a test run)
            f.set_result(result)
        return f


@lru_cache(maxsize=1)
def source_fingerprint() -> str:
    """SHA-256 of the sources of ``mcverify``, ``estimators`` and ``mcnumba`` as this
    process sees them: a worker that would rebuild checks from different code refuses
    to run."""
    here = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    h = hashlib.sha256()
    for pkg in ("mcverify", "estimators", "mcnumba"):
        for folder, dirs, files in sorted(os.walk(os.path.join(here, pkg))):
            dirs.sort()
            for name in sorted(files):
                if name.endswith((".py", ".json")):
                    path = os.path.join(folder, name)
                    h.update(os.path.relpath(path, here).encode())
                    with open(path, "rb") as f:
                        h.update(f.read())
    return h.hexdigest()


def same_source(expected: str | None) -> None:
    """Called by units in workers: refuse to run code that differs from the client's."""
    if expected is not None and expected != source_fingerprint():
        raise EnvironmentProblem(
            f"worker {os.uname().nodename} (pid {os.getpid()}) runs different mcverify/"
            f"estimators/mcnumba sources (fingerprint {source_fingerprint()[:12]}, client "
            f"{expected[:12]}); install the same version on every worker")


def _scheduler_address(scheduler_file: str, where: str) -> str:
    """The address a Dask scheduler file names (Dask's own reading said "unexpected
    TypeError" for a file whose address is no string, or that holds no JSON object)."""
    try:
        with open(scheduler_file, encoding="utf-8") as f:
            address = json.load(f).get("address")
    except (OSError, ValueError, AttributeError):
        address = None
    if not isinstance(address, str) or not address:
        raise EnvironmentProblem(f"{where}: cannot connect to the scheduler (the file holds "
                                 "no scheduler address)")
    return address


def _handshake(address: str, timeout: str) -> None:
    """Connect to ``address`` and exchange Dask's handshake within ``timeout``, or raise.
    ``Client()`` waits for that handshake without a limit: a server that accepts the
    connection and never answers (an HTTP server, a port forwarder) hung the run."""
    from dask.utils import parse_timedelta
    from distributed.comm import connect

    seconds = parse_timedelta(timeout)

    async def probe():
        try:
            comm = await asyncio.wait_for(connect(address, timeout=seconds), seconds + 5)
        except asyncio.TimeoutError:
            raise TimeoutError(f"no Dask handshake from {address} within {timeout}") from None
        await comm.close()

    # in a thread of its own: its event loop is not the caller's (nor Dask's)
    with cf.ThreadPoolExecutor(1) as thread:
        thread.submit(asyncio.run, probe()).result()


def _worker_init(threads: int) -> None:
    """Local worker processes share the machine: numba's parallel loops get an equal
    share of the cores each (results do not depend on the thread count), set as the
    thread count of the worker's main thread, which runs the units. It was set as
    ``NUMBA_NUM_THREADS``, which numba had read when the worker imported it, and reads
    again at each compilation: once a warp's front end had started numba's threads
    (``numba.get_num_threads``), the next compilation refused the change, and every
    check of ``check -j 2`` that compiled a function failed, "raised RuntimeError:
    Cannot set NUMBA_NUM_THREADS to a different value once the threads have been
    launched" (an outside review)."""
    import numba

    numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))


def _lost_errors() -> tuple[type[BaseException], ...]:
    errors: list[type[BaseException]] = [BrokenProcessPool]
    try:
        from distributed.scheduler import KilledWorker

        errors.append(KilledWorker)
    except ImportError:
        pass
    return tuple(errors)


@dataclass
class Pool:
    """Runs units on an executor: ``Pool()`` in this process, ``Pool(jobs=N)`` on N local
    worker processes, ``Pool(dask="tcp://HOST:PORT")`` or
    ``Pool(dask_scheduler_file=PATH)`` on a Dask cluster (``Client.get_executor()``).

    Use as a context manager (workers and the Dask client are closed on exit)."""

    jobs: int = 1
    dask: str | None = None
    dask_scheduler_file: str | None = None
    retries: int = 1
    _executor: Any = field(default=None, init=False, repr=False)
    _client: Any = field(default=None, init=False, repr=False)

    def __post_init__(self):
        if isinstance(self.jobs, bool) or not isinstance(self.jobs, int) or self.jobs < 1:
            raise InvalidArgument(f"-j {self.jobs!r}: the number of local worker processes "
                                  "must be an integer >= 1")
        if self.jobs > MAX_JOBS:
            raise InvalidArgument(f"-j {self.jobs}: more local worker processes than a "
                                  f"process pool can have (at most {MAX_JOBS})")
        # given but empty (`--dask "$SCHEDULER"` with the variable unset): it ran in this
        # process without a word
        for option, value in (("--dask", self.dask),
                              ("--dask-scheduler-file", self.dask_scheduler_file)):
            if value is not None and not value.strip():
                raise InvalidArgument(f"{option} {value!r}: empty; give the scheduler's "
                                      "address (tcp://HOST:PORT) or its scheduler file, or "
                                      "leave the option out to run in this process")
        if self.dask and self.dask_scheduler_file:
            raise InvalidArgument("--dask and --dask-scheduler-file: give one of them")
        if (self.dask or self.dask_scheduler_file) and self.jobs != 1:
            raise InvalidArgument(f"-j {self.jobs} with a Dask cluster: the cluster's "
                                  "workers set the parallelism; drop -j")
        if self.dask_scheduler_file and not os.path.isfile(self.dask_scheduler_file):
            what = ("a folder, not a file" if os.path.isdir(self.dask_scheduler_file)
                    else "no such file")
            raise InvalidArgument(f"--dask-scheduler-file {self.dask_scheduler_file}: {what} "
                                  "(dask-scheduler --scheduler-file writes it)")
        if self.retries < 0:
            raise InvalidArgument(f"retries={self.retries}: must be >= 0")

    # ------------------------------------------------------------------ set-up
    @property
    def kind(self) -> str:
        if self.dask or self.dask_scheduler_file:
            return "dask"
        return "processes" if self.jobs > 1 else "in-process"

    @property
    def in_process(self) -> bool:
        return self.kind == "in-process"

    def describe(self) -> str:
        if self.kind == "dask":
            return f"dask {self.dask or self.dask_scheduler_file}"
        return f"{self.jobs} local processes" if self.jobs > 1 else "in-process"

    def __enter__(self) -> "Pool":
        self._start()
        return self

    def __exit__(self, kind, *exc) -> None:
        if kind is not None and issubclass(kind, KeyboardInterrupt):
            self._stop_workers()
        self.close()

    def _stop_workers(self) -> None:
        """End the local workers now, on an interrupt: a SIGTERM (a cancelled CI job)
        reaches this process alone, not the spawned workers, and ``close`` waited for
        every unit they were running (minutes for a long check) before the run could
        exit; a CI runner's SIGKILL after its grace period then orphaned them (a review
        of the change). On Ctrl-C the workers got the SIGINT themselves."""
        if self.kind == "processes" and self._executor is not None:
            procs = list((getattr(self._executor, "_processes", None) or {}).values())
            for proc in procs:
                if proc.is_alive():
                    proc.terminate()
            self._executor.shutdown(wait=False, cancel_futures=True)
            self._executor = None
            for proc in procs:      # reaped, not left as zombies
                proc.join(5)

    def _start(self) -> None:
        if self._executor is not None:
            return
        if self.kind == "in-process":
            self._executor = InProcessExecutor()
        elif self.kind == "processes":
            threads = max(1, (os.cpu_count() or 1) // self.jobs)
            self._executor = cf.ProcessPoolExecutor(
                self.jobs, mp_context=multiprocessing.get_context("spawn"),
                initializer=_worker_init, initargs=(threads,))
        else:
            try:
                from distributed import Client
            except ImportError:
                raise EnvironmentProblem("--dask needs dask.distributed: pip install "
                                         "'dask[distributed]'") from None
            where = (f"--dask {self.dask}" if self.dask else
                     f"--dask-scheduler-file {self.dask_scheduler_file}")
            address = self.dask or _scheduler_address(self.dask_scheduler_file, where)
            try:
                _handshake(address, DASK_CONNECT_TIMEOUT)
                self._client = Client(address, timeout=DASK_CONNECT_TIMEOUT)
            except (OSError, TimeoutError, ValueError) as e:
                why = f"{type(e).__name__}: {e}" if str(e) else type(e).__name__
                raise EnvironmentProblem(f"{where}: cannot connect to the scheduler ({why})") \
                    from None
            except Exception as e:  # noqa: BLE001 - whatever answered, it is no scheduler
                # a server that answers something else: Dask read its reply as a frame
                # length ("unexpected MemoryError: Unable to allocate 3.07 EiB")
                raise EnvironmentProblem(
                    f"{where}: cannot connect to the scheduler ({address} does not answer "
                    f"as a Dask scheduler: {type(e).__name__}: {e})") from None
            try:
                # a scheduler without workers would take the units and never run them
                self._client.wait_for_workers(1, timeout=DASK_WORKER_WAIT)
            except (TimeoutError, OSError) as e:
                self._client.close()
                self._client = None
                raise EnvironmentProblem(f"{where}: the scheduler has no workers "
                                         f"(none joined within {DASK_WORKER_WAIT} s: {e}); "
                                         "start some with `dask worker ADDRESS`") from None
            # pure=False: a unit rerun after a lost worker is a new task, never a cached
            # failure
            self._executor = self._client.get_executor(pure=False)

    def close(self) -> None:
        if self._executor is not None:
            if self.kind == "processes":
                self._executor.shutdown(wait=True, cancel_futures=True)
            else:                   # Dask's executor takes no cancel_futures
                self._executor.shutdown(wait=False)
            self._executor = None
        if self._client is not None:
            self._client.close()
            self._client = None

    @property
    def width(self) -> int:
        """Units that can run at once."""
        self._start()
        if self.kind == "dask":
            return max(1, sum(self._client.nthreads().values()))
        return self.jobs

    def _restart(self) -> None:
        """A local worker died: the process pool is broken; start a fresh one."""
        self._executor.shutdown(wait=False, cancel_futures=True)
        self._executor = None
        self._start()

    # ------------------------------------------------------------------ running
    def map(self, units: Iterable[Unit], *, progress=None) -> list:
        """Run all units; their results in the units' order."""
        return list(self.imap(units, progress=progress))

    def imap(self, units: Iterable[Unit], *, progress=None,
             lookahead: int | None = None) -> Iterator:
        """Results of ``units`` in order, as they become available. At most
        ``lookahead`` units are submitted ahead of the one being waited for (default: one
        per local worker, so a dead worker takes only the units it was running with it;
        on Dask all of them, its scheduler queues; in-process: one at a time, so a
        consumer that stops early, such as a sequential test that has decided, never pays
        for the rest). Closing the iterator
        cancels what has not started. ``progress(done, total, unit, result)`` is called as
        units finish, in whatever order workers finish them."""
        self._start()
        units = list(units)
        total = len(units)
        limit = 1 if self.in_process else (lookahead or (
            total if self.kind == "dask" else self.jobs))
        lost = _lost_errors()
        attempts = [0] * total
        inflight: dict[int, cf.Future] = {}
        results: dict[int, Any] = {}
        submitted = given = done = 0
        try:
            while given < total:
                while submitted < total and submitted - given < limit:
                    inflight[submitted] = self._submit(units[submitted])
                    submitted += 1
                if given in results:
                    yield results.pop(given)
                    given += 1
                    continue
                cf.wait(list(inflight.values()), return_when=cf.FIRST_COMPLETED)
                broken = []
                for i in sorted(inflight):
                    f = inflight[i]
                    if not f.done():
                        continue
                    if f.cancelled():       # not by us: the cluster dropped it
                        raise WorkerLost(f"unit {units[i].key}: cancelled by "
                                         f"{self.describe()} (scheduler gone?); no partial "
                                         "result is reported")
                    e = f.exception()
                    if e is None:
                        del inflight[i]
                        results[i] = f.result()
                        done += 1
                        if progress:
                            progress(done, total, units[i], results[i])
                    elif isinstance(e, lost):
                        broken.append((i, e))
                    else:
                        raise e
                if broken:
                    self._recover(units, inflight, broken, attempts)
        finally:
            for f in inflight.values():
                f.cancel()

    def _submit(self, unit: Unit) -> cf.Future:
        return self._executor.submit(unit.fn, *unit.args)

    def _recover(self, units, inflight, broken, attempts) -> None:
        """Units whose worker died: run them again, or raise ``WorkerLost``."""
        if self.kind == "processes":
            # The whole pool is broken: every unit still in flight is lost with it.
            cf.wait(list(inflight.values()))
            broken = [(i, f.exception()) for i, f in inflight.items()
                      if isinstance(f.exception(), BrokenProcessPool)]
            names = ", ".join(units[i].key for i, _ in broken)
            for i, _ in broken:
                attempts[i] += 1
            over = [i for i, _ in broken if attempts[i] > self.retries]
            if over:
                raise WorkerLost(f"a worker process died while running {names} (one of "
                                 f"them killed it, or the system did); tried {attempts[over[0]]} times, giving up on "
                                 f"{', '.join(units[i].key for i in over)} (no partial "
                                 "result is reported)")
            self._restart()
            for i, _ in broken:
                inflight[i] = self._submit(units[i])
            return
        # Dask has rerun the tasks on other workers already (allowed-failures times); a
        # unit queued on a dying worker counts as running there, so name every one.
        names = ", ".join(units[i].key for i, _ in broken)
        raise WorkerLost(f"unit {names}: its Dask worker died on every attempt "
                         f"({type(broken[0][1]).__name__}: {broken[0][1]}); no partial result "
                         "is reported")
