"""The kernel cache's compile lock: processes that start together compile a kernel once."""

import importlib
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from estimators import _generated

render_module = importlib.import_module("estimators.pathtracer.render")

_HOLDER = textwrap.dedent("""
    import os, sys, time
    from estimators._generated import compile_lock
    log, name = sys.argv[1], sys.argv[2]
    with compile_lock(name):
        with open(log, "a") as f:
            f.write(f"{os.getpid()} in\\n")
        open(log + ".held", "w").close()
        time.sleep(1.0)
        with open(log, "a") as f:
            f.write(f"{os.getpid()} out\\n")
""")


def test_compile_lock_excludes_a_second_process(tmp_path, monkeypatch):
    """The second process enters only after the first has left: the log reads
    in, out, in, out, never in, in."""
    monkeypatch.setenv("MCVERIFY_CACHE", str(tmp_path / "cache"))
    log = str(tmp_path / "log")
    env = dict(os.environ, PYTHONPATH=os.getcwd())
    first = subprocess.Popen([sys.executable, "-c", _HOLDER, log, "k"], env=env)
    while not os.path.exists(log + ".held"):
        assert first.poll() is None, "the first process ended without taking the lock"
    second = subprocess.Popen([sys.executable, "-c", _HOLDER, log, "k"], env=env)
    assert first.wait(60) == 0 and second.wait(60) == 0
    lines = [line.split() for line in open(log).read().splitlines()]
    assert [w for _, w in lines] == ["in", "out", "in", "out"]
    assert lines[0][0] == lines[1][0] == str(first.pid)
    assert lines[2][0] == lines[3][0] == str(second.pid)


class _Terminal:
    def __init__(self, tty):
        self.tty, self.text = tty, ""

    def isatty(self):
        return self.tty

    def write(self, s):
        self.text += s

    def flush(self):
        pass


def test_a_long_wait_for_the_lock_is_said_on_a_terminal_only(tmp_path, monkeypatch):
    """A probe's script waited minutes in silence behind a test run's compilation: past
    ``LOCK_NOTICE_SECONDS`` the waiting process says so, on a terminal; a pipe (CI logs,
    the tests' subprocesses) gets nothing. A short wait says nothing either."""
    import fcntl
    import threading

    monkeypatch.setenv("MCVERIFY_CACHE", str(tmp_path))
    monkeypatch.setattr(_generated, "LOCK_NOTICE_SECONDS", 0.3)
    for tty, hold, said in [(True, 1.0, True), (False, 1.0, False), (True, 0.0, False)]:
        term = _Terminal(tty)
        monkeypatch.setattr(sys, "stderr", term)
        holder = open(tmp_path / "k.lock", "a")
        fcntl.flock(holder, fcntl.LOCK_EX)
        release = threading.Timer(hold, lambda: (fcntl.flock(holder, fcntl.LOCK_UN),
                                                 holder.close()))
        release.start()
        with _generated.compile_lock("k"):
            pass
        release.join()
        assert ("waiting for another process compiling" in term.text) == said, term.text


def test_other_names_do_not_wait(tmp_path, monkeypatch):
    """A lock of another name is free while one is held (kernels compile in parallel)."""
    monkeypatch.setenv("MCVERIFY_CACHE", str(tmp_path))
    import fcntl
    with _generated.compile_lock("a"):
        with open(tmp_path / "b.lock", "a") as f:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)    # raises if it were held
            fcntl.flock(f, fcntl.LOCK_UN)
        with open(tmp_path / "a.lock", "a") as f:
            try:
                fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
                held = False
            except BlockingIOError:
                held = True
        assert held


def _spy_on_the_lock(monkeypatch) -> list:
    """Record the names the kernels' first calls lock (``_generated.first_call``), with
    the process's record of first calls emptied."""
    taken = []
    real = _generated.compile_lock

    def spy(name):
        taken.append(name)
        return real(name)

    monkeypatch.setattr(_generated, "compile_lock", spy)
    monkeypatch.setattr(_generated, "_CALLED", set())
    return taken


def test_render_takes_the_lock_on_a_kernels_first_call_only(monkeypatch):
    taken = _spy_on_the_lock(monkeypatch)
    scene = "reference/scenes/white-furnace/scene.xml"
    a = render_module.render(scene, spp=2, seed=1, general=True, params={"res": 8})
    b = render_module.render(scene, spp=2, seed=1, general=True, params={"res": 8})
    assert taken == [render_module.specialised_kernel(-1).__name__]
    np.testing.assert_array_equal(a.mean, b.mean)


def test_a_warp_loop_takes_the_lock_once_per_dtype(monkeypatch):
    from estimators import warps
    taken = _spy_on_the_lock(monkeypatch)
    u = np.random.default_rng(3).random((100, 2))
    a = warps.sample_cosine_hemisphere(u)
    b = warps.sample_cosine_hemisphere(u)
    c = warps.sample_cosine_hemisphere(u.astype(np.float32))
    np.testing.assert_array_equal(a, b)
    assert c.dtype == np.float32
    assert len(taken) == 2 and taken[0].endswith(".float64") and taken[1].endswith(".float32")


def test_a_sampling_loop_takes_the_lock_on_its_first_call_only(monkeypatch):
    from estimators.pathtracer import prepare_scene
    from estimators.pathtracer.sampling import bsdf_sampler
    taken = _spy_on_the_lock(monkeypatch)
    scene = prepare_scene("reference/scenes/cornell-box/scene.xml", params={"res": 8})
    sample, pdf = bsdf_sampler(scene, 0, (0.0, 0.6, 0.8))
    u = np.random.default_rng(4).random((64, 3))
    a, b = sample(u), sample(u)
    np.testing.assert_array_equal(a, b)
    pdf(a)
    assert len(taken) == 2 and taken[0].endswith("._bsdf_sample_rows") \
        and taken[1].endswith("._bsdf_eval_rows"), taken


def test_a_failed_write_leaves_no_temporary_file_in_the_cache(tmp_path, monkeypatch):
    """A generated module whose write fails (a full disk, Ctrl-C) left its ``.tmp`` file
    in the kernel cache (an outside review); it is removed, and the error goes on."""
    monkeypatch.setenv("MCVERIFY_CACHE", str(tmp_path))

    def full(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(_generated.os, "replace", full)
    with pytest.raises(OSError, match="No space left"):
        _generated.load("mcverify_test_failed_write", "x = 1\n")
    assert os.listdir(tmp_path) == []


def test_a_damaged_generated_module_is_written_again(tmp_path, monkeypatch):
    """A generated module cut short in the cache (at a line's end, as a crash or a full
    disk may leave it) was imported as it was: the uniform disk's loop, cut after its
    first lines, returned ``np.empty``'s garbage and the correct warp failed its check
    with p = 0 (an outside review). Its name hashes its source, so a file that differs
    is rewritten before the import; one that matches is left alone."""
    monkeypatch.setenv("MCVERIFY_CACHE", str(tmp_path))
    source = "def f():\n    x = 1\n    return x + 1\n"
    path = tmp_path / "mcverify_test_damaged.py"
    path.write_text(source[:len("def f():\n    x = 1\n")])
    assert _generated.load("mcverify_test_damaged", source).f() == 2
    assert path.read_text() == source
    path.write_bytes(b"\xff\xfe")        # not UTF-8 at all
    assert _generated.load("mcverify_test_damaged", source).f() == 2
    stamp = path.stat().st_mtime_ns
    os.utime(path, ns=(stamp - 10**9, stamp - 10**9))
    _generated.load("mcverify_test_damaged", source)
    assert path.stat().st_mtime_ns == stamp - 10**9        # intact: not rewritten



@pytest.mark.parametrize("umask", [0o022, 0o077])
def test_a_generated_module_is_readable_as_the_umask_allows(tmp_path, monkeypatch, umask):
    """Generated modules were written through ``mkstemp``, private (0600) whatever the
    umask: a kernel cache shared by a team's accounts (``MCVERIFY_CACHE`` on a shared
    disk) could not be read by the others (an outside review). They are created as
    ``open`` creates a file, 0666 under the umask."""
    monkeypatch.setenv("MCVERIFY_CACHE", str(tmp_path))
    old = os.umask(umask)
    try:
        _generated.load(f"mcverify_test_mode_{umask:o}", "x = 1\n")
    finally:
        os.umask(old)
    mode = (tmp_path / f"mcverify_test_mode_{umask:o}.py").stat().st_mode & 0o777
    assert mode == 0o666 & ~umask, oct(mode)
    assert [p for p in os.listdir(tmp_path) if p.endswith(".tmp")] == []


def test_a_full_kernel_cache_stops_the_gate_naming_it(tmp_path, monkeypatch):
    """A kernel cache on a full disk failed the check whose warp compiled first, "raised
    OSError: [Errno 28] No space left on device", exit 1 as if the warp were wrong,
    naming neither the cache nor what to do. The write now raises CacheWriteError (an
    OSError) naming the module's path and MCVERIFY_CACHE, and the gate stops on it as an
    environment problem (exit 2)."""
    from mcverify.errors import EnvironmentProblem
    from mcverify.gate.suites import Check, _run_guarded

    monkeypatch.setenv("MCVERIFY_CACHE", str(tmp_path))

    def full(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(_generated.os, "replace", full)
    with pytest.raises(_generated.CacheWriteError, match="No space left.*MCVERIFY_CACHE") as e:
        _generated.load("mcverify_test_full_cache", "x = 1\n")
    assert e.value.filename == str(tmp_path / "mcverify_test_full_cache.py")
    check = Check("my.warp", lambda seed: _generated.load("mcverify_test_full_cache2", "x = 2\n"))
    with pytest.raises(EnvironmentProblem, match="check 'my.warp': .*mcverify_test_full_cache2"
                       ".py: cannot write a kernel .*No space left"):
        _run_guarded(check, 0)


def test_without_a_home_folder_the_cache_is_not_put_in_the_current_directory(monkeypatch,
                                                                            tmp_path):
    """HOME unset and the user not in the password database (a container run as
    ``-u 1234``): ``~`` stayed unexpanded, and the kernel cache and hypothesis's storage
    went into a folder named ``~`` in the current directory, the user's project. They go
    into the temporary folder instead."""
    import pwd
    import tempfile

    from mcverify.gate import cli

    def unknown(uid):
        raise KeyError(f"getpwuid(): uid not found: {uid}")

    for name in ("HOME", "MCVERIFY_CACHE", "HYPOTHESIS_STORAGE_DIRECTORY"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(pwd, "getpwuid", unknown)
    monkeypatch.chdir(tmp_path)
    assert os.path.expanduser("~") == "~"           # the situation
    path = _generated.cache_path()
    assert os.path.isabs(path) and path.startswith(tempfile.gettempdir()), path
    cli._hypothesis_home()
    storage = os.environ["HYPOTHESIS_STORAGE_DIRECTORY"]
    assert os.path.isabs(storage) and storage.startswith(tempfile.gettempdir()), storage
    assert os.listdir(tmp_path) == []


def test_the_temporary_cache_folder_must_be_this_users_private_one(monkeypatch, tmp_path):
    """Without a home folder the cache goes to a predictable name in the shared temporary
    folder, whose modules are imported and whose numba files are unpickled: one made
    first by another user (or writable by others, or a link) would run their code in
    this user's checks. It is made 0700 and refused otherwise, naming MCVERIFY_CACHE."""
    import pwd
    import tempfile

    def unknown(uid):
        raise KeyError(f"getpwuid(): uid not found: {uid}")

    for name in ("HOME", "MCVERIFY_CACHE"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(pwd, "getpwuid", unknown)
    monkeypatch.setattr(tempfile, "gettempdir", lambda: str(tmp_path))
    folder = tmp_path / f"mcverify-{os.getuid()}-cache"
    assert _generated.user_cache() == str(folder)
    assert folder.stat().st_mode & 0o777 == 0o700
    folder.chmod(0o777)                                 # writable by others
    with pytest.raises(PermissionError, match="set MCVERIFY_CACHE"):
        _generated.cache_path()
    folder.rmdir()
    (tmp_path / "elsewhere").mkdir(mode=0o700)
    folder.symlink_to(tmp_path / "elsewhere")           # a link planted under the name
    with pytest.raises(PermissionError, match="not this user's private folder"):
        _generated.user_cache()


@pytest.mark.parametrize("home", ["missing", "cache-is-a-file"])
def test_a_home_without_a_usable_cache_folder_falls_back_to_the_private_temporary_one(
        tmp_path, monkeypatch, home):
    """``nobody``'s home is ``/nonexistent``, and a read-only home has no ``.cache`` to
    make: numba then caches in the temporary folder (``mcnumba.disk_cache``), and the
    kernel cache did not, so ``check`` exited 2 there on it alone (a read-only review).
    Both now use ``mcverify-UID-cache`` in the temporary folder (a ``.cache`` that is a
    file stands in for one that cannot be made: the tests run as root, where a
    read-only folder is written anyway)."""
    import tempfile

    if home == "missing":
        monkeypatch.setenv("HOME", str(tmp_path / "nonexistent"))
    else:
        (tmp_path / "home").mkdir()
        (tmp_path / "home" / ".cache").write_text("not a folder\n")
        monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.delenv("MCVERIFY_CACHE", raising=False)
    monkeypatch.setattr(tempfile, "gettempdir", lambda: str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    assert _generated.user_cache() == str(tmp_path / "tmp" / f"mcverify-{os.getuid()}-cache")
    assert not (tmp_path / "nonexistent").exists()
