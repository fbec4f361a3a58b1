"""Executors: the same results in-process, on local worker processes and on a Dask
cluster; dead workers are retried or named; progress counts units across workers."""

import os
import pickle

import numpy as np
import pytest

from mcverify.errors import EnvironmentProblem, InvalidArgument
from mcverify.gate import suites
from mcverify.gate.executors import Pool, Unit, WorkerLost, same_source

distributed = pytest.importorskip("distributed")


def _timeless(d):
    """A result's JSON without what may differ between runs: timings (``seconds``,
    ``*_seconds``, ``*_per_second``), the UTC time and the executor's name."""
    if isinstance(d, dict):
        return {k: _timeless(v) for k, v in d.items()
                if not k.endswith(("seconds", "per_second")) and k not in ("utc_time", "executor")}
    if isinstance(d, list):
        return [_timeless(x) for x in d]
    return d


def _small_suite():
    return [c for c in suites.build_suite("default")
            if c.name.startswith("unbiased:") or "uniform_disk_polar" in c.name]


def test_suite_json_is_identical_in_process_on_2_processes_and_on_a_dask_cluster():
    checks = _small_suite()
    assert len(checks) == 14         # 10 estimators; the polar disk's sampler, inverse, stability,
    #                                  pdf consistency
    serial = suites.run_suite(checks, seed=3, canary=False).to_dict()
    with Pool(jobs=2) as pool:
        calls = []
        local = suites.run_suite(checks, seed=3, canary=False, pool=pool,
                                 progress=lambda i, n, r, c: calls.append((i, n, c.name)))
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        with Pool(dask=cluster.scheduler_address) as pool:
            assert pool.width == 2
            dask = suites.run_suite(checks, seed=3, canary=False, pool=pool)
    assert _timeless(serial) == _timeless(local.to_dict()) == _timeless(dask.to_dict())
    assert serial["provenance"]["executor"] == "in-process"
    assert local.provenance["executor"] == "2 local processes"
    # progress: every unit once, counted 1..N whatever order the workers finish in
    assert sorted(i for i, _, _ in calls) == list(range(1, len(checks) + 1))
    assert {n for _, n, _ in calls} == {len(checks)}
    assert sorted(name for _, _, name in calls) == sorted(c.name for c in checks)


def _threads_then_compile() -> tuple[int, int]:
    """What a check's unit does in a worker: a warp's front end asks numba's thread count
    (which starts its threads), then a function compiles."""
    import numba

    numba.get_num_threads()
    return numba.njit(lambda x: x + 1)(1), numba.get_num_threads()


def test_local_workers_compile_on_their_share_of_the_cores():
    """Each of ``-j N``'s workers was given its share of the cores as NUMBA_NUM_THREADS,
    which numba reads again at each compilation and refuses to change once its threads
    have started: every check of ``mcverify check -j 2`` that compiled a function
    failed, "raised RuntimeError: Cannot set NUMBA_NUM_THREADS to a different value once
    the threads have been launched" (an outside review, on 2 cores). The share is the
    worker's thread count now."""
    import numba

    share = max(1, min((os.cpu_count() or 1) // 2, numba.config.NUMBA_NUM_THREADS))
    with Pool(jobs=2) as pool:
        results = pool.map([Unit("compile", _threads_then_compile, ())])
    assert results == [(2, share)]


def _die_once(marker: str) -> int:
    if not os.path.exists(marker):
        open(marker, "w").close()
        os._exit(3)                   # the worker process dies mid-unit
    return 42


def _die_always() -> int:
    os._exit(3)


def _square(x: int) -> int:
    return x * x


def _slow_mark(started: str, done: str) -> int:
    import time

    open(started, "w").close()
    time.sleep(3.0)
    open(done, "w").close()
    return 1


def test_an_interrupted_pool_ends_its_running_units(tmp_path):
    """A SIGTERM reaches the parent alone (its workers are spawned), which raises
    KeyboardInterrupt there; leaving the pool then waited for every unit the workers
    were running (``shutdown(wait=True)``): minutes for a long check, and CI's SIGKILL
    after its grace period orphaned them (a review of the change). The workers are now
    ended at once: the running unit never finishes."""
    import time

    started, done = str(tmp_path / "started"), str(tmp_path / "done")
    with pytest.raises(KeyboardInterrupt):
        with Pool(jobs=2) as pool:
            pool._executor.submit(_slow_mark, started, done)
            for _ in range(600):        # the unit is running (spawn takes a few seconds)
                if os.path.exists(started):
                    break
                time.sleep(0.1)
            raise KeyboardInterrupt
    assert os.path.exists(started)
    time.sleep(5.0)             # past the unit's end, had its worker lived
    assert not os.path.exists(done)


def test_a_unit_whose_worker_dies_once_is_rerun(tmp_path):
    units = [Unit(f"sq{i}", _square, (i,)) for i in range(4)]
    units.insert(2, Unit("flaky", _die_once, (str(tmp_path / "died"),)))
    with Pool(jobs=2) as pool:
        assert pool.map(units) == [0, 1, 42, 4, 9]


def test_a_unit_that_kills_every_worker_is_named_and_nothing_partial_returned():
    units = [Unit("sq", _square, (3,)), Unit("killer", _die_always)]
    with Pool(jobs=2) as pool:
        with pytest.raises(WorkerLost, match="killer.*tried 2 times"):
            pool.map(units)
    assert issubclass(WorkerLost, EnvironmentProblem)      # the CLI exits 2


def test_a_unit_that_kills_every_dask_worker_is_named():
    import dask

    with dask.config.set({"distributed.scheduler.allowed-failures": 1}):
        with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                      dashboard_address=None) as cluster:
            with Pool(dask=cluster.scheduler_address) as pool:
                with pytest.raises(WorkerLost, match="unit .*killer.*: its Dask worker died"):
                    pool.map([Unit("sq", _square, (2,)), Unit("killer", _die_always)])


def test_unit_errors_are_raised_as_they_are():
    with Pool(jobs=2) as pool:
        with pytest.raises(ZeroDivisionError):
            pool.map([Unit("div", divmod, (1, 0))])


def _meet(mine: str, other: str) -> bool:
    """Mark this unit as running, then wait (at most 60 s) for the other one to run."""
    import time

    open(mine, "w").close()
    for _ in range(600):
        if os.path.exists(other):
            return True
        time.sleep(0.1)
    return False


def test_local_workers_run_units_at_the_same_time(tmp_path):
    """``-j 2`` keeps both workers busy: each of two units waits for the other to start
    (a pool that submitted one unit at a time gave the same results, on one worker)."""
    a, b = str(tmp_path / "a"), str(tmp_path / "b")
    with Pool(jobs=2) as pool:
        assert pool.map([Unit("a", _meet, (a, b)), Unit("b", _meet, (b, a))]) == [True, True]


def _mark(folder: str, i: int) -> int:
    import time

    time.sleep(0.3)
    open(os.path.join(folder, str(i)), "w").close()
    return i


def test_closing_the_iterator_cancels_the_units_not_yet_started(tmp_path):
    """A consumer that stops early (a sequential test that has decided) leaves the units
    submitted ahead of it unrun, while the pool stays open."""
    import time

    with Pool(jobs=2) as pool:
        it = pool.imap([Unit(str(i), _mark, (str(tmp_path), i)) for i in range(20)],
                       lookahead=20)
        assert next(it) == 0
        it.close()
        time.sleep(8.0)         # the 20 units take 3 s on 2 workers
        ran = len(os.listdir(tmp_path))
    assert ran < 20, ran


def test_a_unit_cancelled_by_the_cluster_is_named_not_waited_on(monkeypatch):
    """A future the executor cancelled itself (a Dask scheduler gone) is no result: the
    run stops naming the unit, where it could wait on it for ever."""
    import concurrent.futures as cf
    import threading

    def cancelled(unit):
        f = cf.Future()
        f.cancel()
        f.set_running_or_notify_cancel()    # as Dask's executor does, waking cf.wait
        return f

    outcome = []

    def consume(pool):
        try:
            pool.map([Unit("dropped", _square, (2,))])
        except WorkerLost as e:
            outcome.append(str(e))

    with Pool() as pool:
        monkeypatch.setattr(pool, "_submit", cancelled)
        thread = threading.Thread(target=consume, args=(pool,), daemon=True)
        thread.start()
        thread.join(30)
    assert outcome and outcome[0].startswith("unit dropped: cancelled by in-process"), outcome


def test_a_dask_pools_width_counts_its_workers_threads():
    """``width`` (how many units ``render-check`` keeps submitted) is the cluster's threads,
    not its workers."""
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=True,
                                  dashboard_address=None) as cluster:
        with Pool(dask=cluster.scheduler_address) as pool:
            assert pool.width == 2


def test_in_process_imap_runs_units_only_as_they_are_consumed():
    ran = []
    units = [Unit(str(i), ran.append, (i,)) for i in range(5)]
    with Pool() as pool:
        it = pool.imap(units)
        next(it)
        next(it)
        it.close()
    assert ran == [0, 1]


def test_a_check_without_a_recipe_must_pickle_to_leave_the_process():
    check = suites.Check("lambda-check", lambda seed: None)
    with pytest.raises((pickle.PicklingError, AttributeError)):
        pickle.dumps(check)
    with Pool(jobs=2) as pool:
        with pytest.raises(InvalidArgument, match="check 'lambda-check': cannot be sent to "
                                                  "2 local processes"):
            suites.run_suite([check], canary=False, pool=pool)


def test_a_worker_with_other_sources_refuses():
    same_source(None)
    with pytest.raises(EnvironmentProblem, match="different mcverify/estimators/mcnumba "
                                                 "sources"):
        same_source("0" * 64)


def test_the_source_fingerprint_reads_every_package_the_distribution_installs(monkeypatch):
    """Every package ``pyproject.toml`` installs (``mcnumba``'s threads too) is in the
    fingerprint a worker must match."""
    import tomllib

    from mcverify.gate import executors

    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    with open(os.path.join(root, "pyproject.toml"), "rb") as f:
        include = tomllib.load(f)["tool"]["setuptools"]["packages"]["find"]["include"]
    walked, walk = [], os.walk
    monkeypatch.setattr(executors.os, "walk", lambda p: walked.append(os.path.basename(p))
                        or walk(p))
    executors.source_fingerprint.cache_clear()
    try:
        executors.source_fingerprint()
    finally:
        executors.source_fingerprint.cache_clear()
    assert sorted(walked) == sorted(p.rstrip("*") for p in include)


def test_a_check_missing_from_its_rebuilt_suite_is_named():
    """A worker rebuilds a check's suite from its recipe and looks the name up: a user
    suite whose names depend on the process (a pid in the name) failed there with
    "unexpected KeyError: 'my.cos.7031'"."""
    with pytest.raises(InvalidArgument, match="check 'sampler:nosuch': not among the 95 "
                                              "checks that rebuilding its suite"):
        suites._run_unit((suites.build_suite, ("default",)), "sampler:nosuch", 0, None, None)


@pytest.mark.parametrize("kwargs,needle", [
    (dict(jobs=0), "-j 0"),
    # more than the pool's semaphore counts: an "unexpected OverflowError" at start
    (dict(jobs=99999999999), "-j 99999999999: more local worker processes"),
    (dict(jobs=2, dask="tcp://localhost:1"), "-j 2 with a Dask cluster"),
    (dict(dask="tcp://a:1", dask_scheduler_file="f"), "give one of them"),
    (dict(dask_scheduler_file="/no/such/file.json"), "--dask-scheduler-file /no/such.*: no such"),
    # a folder was "no such file", which it is, under its name, not
    (dict(dask_scheduler_file="/tmp"), "--dask-scheduler-file /tmp: a folder, not a file"),
    # given but empty (an unset variable): ran in this process without a word
    (dict(dask=""), "--dask '': empty"),
    (dict(dask_scheduler_file=" "), "--dask-scheduler-file ' ': empty"),
    (dict(retries=-1), "retries=-1: must be >= 0"),
], ids=["jobs", "jobs-huge", "jobs-and-dask", "both-dask", "scheduler-file",
        "scheduler-file-folder", "dask-empty", "scheduler-file-empty", "retries-negative"])
def test_bad_pool_arguments(kwargs, needle):
    with pytest.raises(InvalidArgument, match=needle):
        Pool(**kwargs)


def test_an_unreachable_scheduler_is_an_environment_problem(monkeypatch):
    from mcverify.gate import executors

    monkeypatch.setattr(executors, "DASK_CONNECT_TIMEOUT", "2s")    # Dask retries till then
    with pytest.raises(EnvironmentProblem, match="cannot connect"):
        with Pool(dask="tcp://127.0.0.1:9"):
            pass


@pytest.mark.mitsuba
def test_reference_and_render_passes_are_bit_identical_on_worker_processes():
    from mcverify.gate import reference
    from mcverify.gate.render_check import render_check

    a, imgs_a = reference.render_reference("cornell-box", spp=4, passes=4, seed=1)
    with Pool(jobs=2) as pool:
        b, imgs_b = reference.render_reference("cornell-box", spp=4, passes=4, seed=1,
                                               pool=pool)
        ours_b = render_check("cornell-box", spp=256, passes=4, seed=2, pool=pool,
                              params={"res": 32})
    ours_a = render_check("cornell-box", spp=256, passes=4, seed=2, params={"res": 32})
    assert np.array_equal(imgs_a, imgs_b) and np.array_equal(a.var, b.var)
    assert np.array_equal(ours_a.artifacts["ours"], ours_b.artifacts["ours"])
    assert _timeless(ours_a.to_dict()) == _timeless(ours_b.to_dict())


def test_a_scheduler_without_workers_is_refused_not_waited_on(monkeypatch, tmp_path):
    """A live scheduler with no worker took the units and never ran them: the run hung
    silently (found by review). A scheduler file without an address said only
    'unexpected AssertionError'."""
    from mcverify.gate import executors

    monkeypatch.setattr(executors, "DASK_WORKER_WAIT", 1)
    with distributed.LocalCluster(n_workers=0, dashboard_address=None,
                                  processes=False) as cluster:
        with pytest.raises(EnvironmentProblem, match="the scheduler has no workers"):
            with Pool(dask=cluster.scheduler_address) as pool:
                pool.width
    bad = tmp_path / "scheduler.json"
    bad.write_text("{}")
    monkeypatch.setattr(executors, "DASK_CONNECT_TIMEOUT", "2s")
    with pytest.raises(EnvironmentProblem, match="cannot connect to the scheduler") as info:
        with Pool(dask_scheduler_file=str(bad)) as pool:
            pool.width
    # the option given, and why: it said "--dask FILE: ... (AssertionError: )"
    assert str(info.value).startswith(f"--dask-scheduler-file {bad}: "), str(info.value)
    assert str(info.value).endswith("(the file holds no scheduler address)"), str(info.value)
    bad.write_text("{not json")
    with pytest.raises(EnvironmentProblem) as info:
        with Pool(dask_scheduler_file=str(bad)) as pool:
            pool.width
    assert str(info.value).startswith(f"--dask-scheduler-file {bad}: cannot connect to the "
                                      "scheduler ("), str(info.value)
    assert not str(info.value).endswith(": )"), str(info.value)


@pytest.mark.parametrize("text", ['{"address": 5}', '{"address": ""}', "[]",
                                  '"tcp://127.0.0.1:1"'],
                         ids=["address-not-a-string", "address-empty", "a-list", "a-string"])
def test_a_scheduler_file_without_an_address_string_is_named(tmp_path, text):
    """A scheduler file whose JSON is no object with a string address ended the run with
    "unexpected TypeError: expected str, got 'int'", naming no option or file."""
    bad = tmp_path / "scheduler.json"
    bad.write_text(text)
    with pytest.raises(EnvironmentProblem) as info:
        with Pool(dask_scheduler_file=str(bad)):
            pass
    assert str(info.value) == (f"--dask-scheduler-file {bad}: cannot connect to the "
                               "scheduler (the file holds no scheduler address)")


def test_a_server_that_is_no_scheduler_is_refused_not_waited_on(monkeypatch):
    """``--dask`` at a server that accepts the connection and never answers (an HTTP
    server waiting for a request) hung for ever: Dask's handshake has no time limit. One
    that answers something else ended the run with "unexpected MemoryError: Unable to
    allocate 3.07 EiB" (its reply read as a frame length)."""
    import socket
    import threading

    from mcverify.gate import executors

    monkeypatch.setattr(executors, "DASK_CONNECT_TIMEOUT", "2s")
    silent = socket.create_server(("127.0.0.1", 0))        # accepts (backlog), says nothing
    talker = socket.create_server(("127.0.0.1", 0))

    def answer():
        conn, _ = talker.accept()
        conn.recv(4096)
        conn.sendall(b"HTTP/1.0 400 Bad Request\r\nContent-Type: text/html\r\n\r\n" * 8)
        conn.close()

    threading.Thread(target=answer, daemon=True).start()
    with silent, talker:
        for server, why in ((silent, "no Dask handshake"), (talker, "does not answer as a "
                                                             "Dask scheduler")):
            address = "tcp://127.0.0.1:%d" % server.getsockname()[1]
            with pytest.raises(EnvironmentProblem) as info:
                with Pool(dask=address):
                    pass
            assert str(info.value).startswith(f"--dask {address}: cannot connect to the "
                                              "scheduler ("), str(info.value)
            assert why in str(info.value), str(info.value)


_EDITED_SUITE = """
from mcverify.gate.suites import Check
from mcverify.result import CheckResult

def _run(seed):
    return CheckResult(name="edited", passed={passed}, p_value={p}, statistic=None,
                       alpha=0.01, n_samples=1, seconds=0.0)

suite = [Check("edited.check", _run)]
"""


def test_a_dask_worker_holding_an_earlier_version_of_a_user_suite_refuses(tmp_path):
    """Dask workers live across runs and keep a user suite's module imported: after the
    user fixed (or broke) a check, ``--dask`` ran the version the worker had imported
    first, and reported its verdict as the current one."""
    import sys

    from mcverify.gate import usersuite

    module = tmp_path / "edited_suite_mod.py"
    module.write_text(_EDITED_SUITE.format(passed=False, p=0.0))

    def fresh_client_load():        # a new `mcverify check` process reads the file anew
        sys.modules.pop("edited_suite_mod", None)
        usersuite._DIGESTS.pop("edited_suite_mod", None)
        return usersuite.load_user_suite("edited_suite_mod:suite", roots=[str(tmp_path)])

    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        with Pool(dask=cluster.scheduler_address) as pool:
            first = suites.run_suite(fresh_client_load(), canary=False, pool=pool)
            assert not first.passed
            module.write_text(_EDITED_SUITE.format(passed=True, p=0.5))   # the fix
            with pytest.raises(EnvironmentProblem, match="runs another version of .*"
                               "edited_suite_mod.py than this run"):
                suites.run_suite(fresh_client_load(), canary=False, pool=pool)
    sys.modules.pop("edited_suite_mod", None)


def test_an_interrupt_inside_set_result_stays_an_interrupt(monkeypatch):
    """A Ctrl-C that lands inside ``Future.set_result`` after the future is finished went
    to the in-process executor's ``except`` and its ``set_exception``, which raised
    InvalidStateError ("FINISHED"): ``reference build`` exited 2, "unexpected
    InvalidStateError", instead of 130 (seen once in a fresh clone's test run). The
    interrupt now goes on as itself; one raised by the unit still reaches its future."""
    import concurrent.futures as cf

    from mcverify.gate.executors import InProcessExecutor

    real = cf.Future.set_result

    def interrupted(self, result):
        real(self, result)
        raise KeyboardInterrupt

    monkeypatch.setattr(cf.Future, "set_result", interrupted)
    with pytest.raises(KeyboardInterrupt):
        InProcessExecutor().submit(_square, 3)
    monkeypatch.setattr(cf.Future, "set_result", real)

    def ctrl_c():
        raise KeyboardInterrupt

    f = InProcessExecutor().submit(ctrl_c)
    with pytest.raises(KeyboardInterrupt):
        f.result()
