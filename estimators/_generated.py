"""Generated numba modules, written once into the kernel cache and imported from there.

numba's on-disk cache keys a compiled function by its own file, not by the callees it
inlines, so code that is generated per specialisation (the path tracer's kernel per
feature set, the warps' parallel block loops per kernel) is written to a file whose name
carries a hash of every source it compiles in, then imported as a module: an edit makes a
new file, never a stale kernel, and a second process starts warm.
"""

from __future__ import annotations

import contextlib
import importlib.util
import os
import sys
import time
import uuid

from mcnumba.disk_cache import NotPrivate, private_folder, temporary_cache

from ._copy_propagate import fast_copy_propagation
from ._inline_copy import shared_scope_copies
from ._live_bits import fast_liveness
from ._ssa_blocks import fast_ssa

try:
    import fcntl
except ImportError:         # not on POSIX: no lock, each process compiles for itself
    fcntl = None


def user_cache() -> str:
    """``~/.cache``; where no home folder is known (``HOME`` unset and the user not in the
    password database: a container run as ``-u 1234``), ``mcverify-UID-cache`` in the
    temporary folder: ``~`` was left as it was, and the kernel cache (and hypothesis's)
    went into a folder named ``~`` in the current directory, the user's project. The
    same where the home folder is missing (``nobody``'s ``/nonexistent``) or its
    ``.cache`` cannot be made or written (a read-only home): numba caches there then too
    (``mcnumba.disk_cache``), and ``check`` exited 2 on the kernel cache alone (a
    read-only review)."""
    home = os.path.expanduser("~")
    if os.path.isabs(home) and os.path.isdir(home):
        cache = os.path.join(home, ".cache")
        try:
            os.makedirs(cache, exist_ok=True)
        except OSError:
            pass
        else:
            if os.access(cache, os.W_OK | os.X_OK):
                return cache
    return _private_folder(temporary_cache())


def _private_folder(path: str) -> str:
    """``path``, a folder of this user's alone (``mcnumba.disk_cache.private_folder``),
    refused with a PermissionError naming it and ``MCVERIFY_CACHE``: its modules are
    imported and numba's cache files beside them unpickled, so a folder another user made
    first under the predictable name would run their code in this user's checks (the
    final review)."""
    try:
        return private_folder(path)
    except NotPrivate:
        raise PermissionError(f"{path}: the kernel cache's folder in the temporary folder "
                              "(no home folder is known or writable) is not this user's "
                              "private folder (a link, another user's, or writable by "
                              "others); set MCVERIFY_CACHE to a folder of your own") from None
    except OSError as e:
        raise PermissionError(f"{path}: cannot make the kernel cache there ({e.strerror}); "
                              "set MCVERIFY_CACHE to a folder of your own") from None


def cache_path() -> str:
    """``$MCVERIFY_CACHE``, else ``~/.cache/mcverify/kernels`` (see ``user_cache``)."""
    return os.environ.get("MCVERIFY_CACHE") or os.path.join(user_cache(), "mcverify",
                                                            "kernels")


def cache_dir() -> str:
    """``cache_path()``, made if missing."""
    d = cache_path()
    os.makedirs(d, exist_ok=True)
    return d


class CacheWriteError(OSError):
    """The kernel cache cannot take a generated module (a full disk, a quota): the
    machine's problem, not the warp's. ``filename`` is the module's path."""


def load(name: str, source: str):
    """The module ``name`` with ``source``: written atomically into the cache (once, and
    again where the file there is not ``source``: see ``_cached_source``), imported, and
    registered in ``sys.modules`` (numba's cache finds it there)."""
    folder = cache_dir()
    path = os.path.join(folder, name + ".py")
    if _cached_source(path) != source:
        # created as open() creates a file (0666 under the umask), not as mkstemp's
        # private 0600: a kernel cache shared by a team's accounts was unreadable to all
        # but the first to write each module
        tmp = f"{path}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp"
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
            try:
                with os.fdopen(fd, "w", encoding="utf-8") as f:
                    f.write(source)
                os.replace(tmp, path)
            except BaseException:   # a full disk, Ctrl-C: no .tmp file left in the cache
                if os.path.exists(tmp):
                    os.unlink(tmp)
                raise
        except OSError as e:
            # a full disk failed the check whose warp compiled first, "raised OSError:
            # [Errno 28] No space left on device" (exit 1), naming neither the cache nor
            # what to do, as if the warp were wrong
            raise CacheWriteError(e.errno, f"cannot write a kernel into the kernel cache "
                                  f"({e.strerror}); free space there or set MCVERIFY_CACHE "
                                  "to a folder you can write", path) from None
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def _cached_source(path: str) -> str | None:
    """The text of the generated module at ``path``, None if it is missing or unreadable
    as UTF-8. ``name`` hashes the source, so a file that differs is damaged: one cut
    short at a line's end still imported, its loop left the output array as
    ``np.empty`` made it, and a correct warp failed its check with p = 0."""
    try:
        with open(path, encoding="utf-8") as f:
            return f.read()
    except (FileNotFoundError, UnicodeDecodeError):
        return None


@contextlib.contextmanager
def compile_context():
    """numba as our kernels compile (``compile_lock`` holds it, without the lock's file):
    its inliner copies scopes once per copy (``_inline_copy``), its SSA reconstruction
    rewrites only the blocks naming each variable (``_ssa_blocks``), its liveness analysis
    runs on bit sets (``_live_bits``) and its copy propagation analysis makes no deep
    copies (``_copy_propagate``). Each gives numba's own result; nests."""
    with shared_scope_copies(), fast_ssa(), fast_liveness(), fast_copy_propagation():
        yield


@contextlib.contextmanager
def compile_lock(name: str):
    """Hold the kernel cache's lock ``name`` (an advisory ``flock`` on ``name.lock`` in
    the cache folder). Around a kernel's first call it makes processes that start
    together (``mcverify check -j N``, the test run's workers) compile a kernel once:
    the first compiles and writes numba's cache, the others wait and load it. Inside,
    numba compiles as in ``compile_context``."""
    with compile_context():
        if fcntl is None:
            yield
            return
        path = os.path.join(cache_dir(), name + ".lock")
        with open(path, "a") as f:
            _wait_for(f, path)
            try:
                yield
            finally:
                fcntl.flock(f, fcntl.LOCK_UN)


#: seconds a process waits on another's compilation before saying so on a terminal
LOCK_NOTICE_SECONDS = 5.0


def _try_lock(f) -> bool:
    try:
        fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return True
    except BlockingIOError:
        return False


def _wait_for(f, path: str) -> None:
    """``flock`` the open ``f`` exclusively. Where another process holds it (compiling
    the kernel) for over ``LOCK_NOTICE_SECONDS``, say so once on stderr if stderr is a
    terminal: a probe's script waited minutes in silence behind a test run's compile.
    Pipes (CI logs, the tests' subprocesses) get nothing, so that their output is
    unchanged."""
    deadline = time.monotonic() + LOCK_NOTICE_SECONDS
    while not _try_lock(f):
        if time.monotonic() >= deadline:
            if sys.stderr is not None and sys.stderr.isatty():
                print(f"mcverify: waiting for another process compiling the kernel {path} "
                      "guards (this one then loads it from the cache)", file=sys.stderr,
                      flush=True)
            fcntl.flock(f, fcntl.LOCK_EX)
            return
        time.sleep(0.1)


#: keys of ``first_call`` already made in this process
_CALLED: set = set()


def first_call(key, lock: str):
    """Context for a kernel's call: ``compile_lock(lock)`` the first time ``key`` comes in
    this process (the call compiles, or loads numba's cache), nothing after. ``key`` is
    marked only once the call has returned, so a failed first call is locked again."""
    if key in _CALLED:
        return contextlib.nullcontext()
    return _first(key, lock)


@contextlib.contextmanager
def _first(key, lock: str):
    with compile_lock(lock):
        yield
    _CALLED.add(key)
