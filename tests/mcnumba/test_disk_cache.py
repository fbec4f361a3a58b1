"""numba's on-disk cache: a damaged file is a miss (``mcnumba.disk_cache``)."""

import os
import subprocess
import sys
import textwrap

import pytest

#: a cached numba function in a module of its own; ``import mcverify`` first, as a run does
_MODULE = "from numba import njit\n\n\n@njit(cache=True)\ndef f(x):\n    return 2 * x + 1\n"
_CALL = textwrap.dedent("""
    import sys
    sys.path.insert(0, sys.argv[1])
    import mcverify
    import cached_f
    print(cached_f.f(20))
""")


def _call(folder, cache):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    return subprocess.run([sys.executable, "-c", _CALL, str(folder)], env=env,
                          capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("suffix", [".nbc", ".nbi"])
def test_a_cache_file_cut_short_is_compiled_again(tmp_path, suffix):
    """A numba cache file cut short (a crash, a full disk) raised from numba's unpickling
    at the function's first call: a correct warp failed its check with "raised
    UnpicklingError: pickle data was truncated" (an outside review). It is now a miss:
    the function compiles again, gives its result, and its cache is rewritten."""
    src, cache = tmp_path / "src", tmp_path / "cache"
    src.mkdir()
    (src / "cached_f.py").write_text(_MODULE)
    first = _call(src, cache)
    assert first.returncode == 0 and first.stdout == "41\n", first.stderr
    files = [os.path.join(d, n) for d, _, names in os.walk(cache) for n in names
             if n.endswith(suffix)]
    assert len(files) == 1, files
    with open(files[0], "rb") as f:
        data = f.read()
    with open(files[0], "wb") as f:
        f.write(data[:len(data) // 2])
    again = _call(src, cache)
    assert again.returncode == 0 and again.stdout == "41\n", again.stderr
    with open(files[0], "rb") as f:
        assert len(f.read()) == len(data)            # rewritten whole


def test_a_cache_that_cannot_be_written_compiles_and_warns(tmp_path):
    """numba's cache on a full disk (NUMBA_CACHE_DIR): numba raised from its save after
    compiling, and the check whose kernel compiled first failed, "raised OSError: [Errno
    28] No space left on device", exit 1. The function now runs uncached, with one
    warning naming NUMBA_CACHE_DIR."""
    src, cache = tmp_path / "src", tmp_path / "cache"
    src.mkdir()
    (src / "cached_f.py").write_text(_MODULE + "\n\n@njit(cache=True)\ndef g(x):\n"
                                     "    return 3 * x\n")
    full = textwrap.dedent("""
        import contextlib, errno, sys
        sys.path.insert(0, sys.argv[1])
        import mcverify
        from numba.core import caching

        @contextlib.contextmanager
        def full(self, path):
            raise OSError(errno.ENOSPC, "No space left on device")
            yield

        caching.IndexDataCacheFile._open_for_write = full
        import cached_f
        print(cached_f.f(20), cached_f.g(2))
    """)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    r = subprocess.run([sys.executable, "-c", full, str(src)], env=env, capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0 and r.stdout == "41 6\n", r.stderr
    assert r.stderr.count("numba's cache cannot be written") == 1, r.stderr
    assert "No space left on device" in r.stderr and "NUMBA_CACHE_DIR" in r.stderr


#: numba's own places to cache all refused, as for a read-only install run by a user
#: whose home is read-only, missing or unset (``nobody``): root, as CI runs, writes anywhere
_NOWHERE = textwrap.dedent("""
    import os, sys, tempfile
    sys.path.insert(0, sys.argv[1])
    tempfile.tempdir = sys.argv[2]
    os.environ.pop("NUMBA_CACHE_DIR", None)
    from numba.core import caching
    for cls in (caching.InTreeCacheLocator, caching.UserWideCacheLocator):
        cls.from_function = classmethod(lambda cls, py_func, py_file: None)
    import mcverify
    import cached_f
    print(cached_f.f(20))
""")


def test_numba_with_nowhere_to_cache_caches_in_the_temporary_folder(tmp_path):
    """A read-only install run by a user whose home is read-only or unset (``nobody``,
    ``NUMBA_CACHE_DIR`` unset): numba raised "cannot cache function '_atan01': no
    locator available" as mcverify was imported, a traceback and exit 1 from every
    command (an outside review). numba now caches in the user's private folder in the
    temporary folder, ``mcverify-UID-cache/numba``, made 0700."""
    src, tmp = tmp_path / "src", tmp_path / "tmp"
    src.mkdir()
    tmp.mkdir()
    (src / "cached_f.py").write_text(_MODULE)
    r = subprocess.run([sys.executable, "-c", _NOWHERE, str(src), str(tmp)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and r.stdout == "41\n", r.stderr
    folder = tmp / f"mcverify-{os.getuid()}-cache"
    assert folder.stat().st_mode & 0o777 == 0o700
    cached = [n for _, _, names in os.walk(folder / "numba") for n in names
              if n.startswith("cached_f.f-")]
    assert sorted(n.rsplit(".", 1)[1] for n in cached) == ["nbc", "nbi"], cached


def test_numba_does_not_cache_in_a_temporary_folder_of_another_user(tmp_path):
    """The temporary folder's name is predictable: one writable by others (or another
    user's, or a link) is not cached in, since numba unpickles what it finds there."""
    src, tmp = tmp_path / "src", tmp_path / "tmp"
    src.mkdir()
    folder = tmp / f"mcverify-{os.getuid()}-cache"
    folder.mkdir(parents=True)
    folder.chmod(0o777)
    (src / "cached_f.py").write_text(_MODULE)
    r = subprocess.run([sys.executable, "-c", _NOWHERE, str(src), str(tmp)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode != 0 and "no locator available" in r.stderr, r.stderr
    assert os.listdir(folder) == []
