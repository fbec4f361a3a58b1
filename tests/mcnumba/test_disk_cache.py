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
