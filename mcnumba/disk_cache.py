"""numba's on-disk cache read as a miss where a file of it is damaged.

numba writes its cache files atomically, but a crash, a full disk or a copied cache can
leave an index (``.nbi``) or data file (``.nbc``) cut short. numba then raises from the
unpickling at the function's first call: a check whose kernel's cache was cut short
failed with "raised UnpicklingError: pickle data was truncated" (exit 1, a correct
subject failing; an outside review). ``tolerate_damaged_cache()`` runs when
``estimators`` or ``mcverify`` is imported: an index that cannot be unpickled reads as
empty and a data file as missing (as numba already reads a data file removed under its
index), so the function is compiled again and its cache rewritten. An error opening the
files (a permission) goes on as numba raises it. A cache file that cannot be written (a
full disk) is not written, with one warning a process: numba raised from the save after
compiling, and the check whose kernel compiled first failed, "raised OSError: [Errno 28]
No space left on device", exit 1.

``cache_in_temporary_folder()``, run then too, gives numba a last place to cache in where
it has none: a read-only install (sources whose ``__pycache__`` cannot be written) run by
a user whose home is read-only, missing or unset (``nobody``, a container run as ``-u
1234``) and with no ``NUMBA_CACHE_DIR`` it can write. numba then raised "cannot cache
function '_atan01': no locator available" as ``mcverify`` was imported, a traceback and
exit 1 from every command (``mcverify --version`` too; an outside review). It caches in
``mcverify-UID-cache/numba`` in the temporary folder, beside the kernel cache's fallback
(``estimators._generated.user_cache``): a folder of this user's alone (``private_folder``).
"""

from __future__ import annotations

import os
import stat
import tempfile
import warnings


def tolerate_damaged_cache() -> bool:
    """Make numba's ``IndexDataCacheFile`` read a damaged index as empty and a damaged
    data file as missing; True if it did (once a process; False where numba is not laid
    out as expected, which leaves it as it is)."""
    from numba.core import caching

    cls = getattr(caching, "IndexDataCacheFile", None)
    if cls is None or not all(callable(getattr(cls, a, None))
                              for a in ("_load_index", "_load_data", "save")):
        return False
    if getattr(cls, "_mcnumba_tolerant", False):
        return True
    load_index, load_data, save = cls._load_index, cls._load_data, cls.save

    def _load_index(self):
        try:
            return load_index(self)
        except OSError:
            raise
        except Exception:       # noqa: BLE001 - cut short or garbage: unpickling's errors
            return {}

    def _load_data(self, name):
        try:
            return load_data(self, name)
        except OSError:
            raise
        except Exception as e:  # noqa: BLE001 - numba's load() reads OSError as missing
            raise OSError(f"damaged numba cache file {name}: {e}") from e

    def _save(self, key, data):
        try:
            save(self, key, data)
        except OSError as e:    # the function is compiled; only its cache is not kept
            if not _warned:
                _warned.append(e)
                warnings.warn(f"numba's cache cannot be written ({e}); kernels compile "
                              "again in each process: free space there or set "
                              "NUMBA_CACHE_DIR to a folder you can write", RuntimeWarning,
                              stacklevel=2)

    _warned = []
    cls._load_index, cls._load_data, cls.save = _load_index, _load_data, _save
    cls._mcnumba_tolerant = True
    return True


class NotPrivate(PermissionError):
    """A folder that ``private_folder`` refuses: a link, another user's, or writable by
    others."""


def private_folder(path: str) -> str:
    """``path``, a folder of this user's alone in a shared temporary folder: made 0700,
    ``NotPrivate`` where it is a link, another user's or writable by others (``OSError``
    where it cannot be made). Modules are imported and numba's cache files unpickled from
    it, so a folder another user made first under the predictable name would run their
    code in this user's checks."""
    os.makedirs(path, mode=0o700, exist_ok=True)
    st = os.lstat(path)
    own = not hasattr(os, "getuid") or st.st_uid == os.getuid()
    if not stat.S_ISDIR(st.st_mode) or not own or st.st_mode & 0o022:
        raise NotPrivate(f"{path}: not this user's private folder")
    return path


def temporary_cache() -> str:
    """``mcverify-UID-cache`` in the temporary folder (not made here)."""
    uid = os.getuid() if hasattr(os, "getuid") else "user"
    return os.path.join(tempfile.gettempdir(), f"mcverify-{uid}-cache")


def cache_in_temporary_folder() -> bool:
    """Append to numba's cache locators one in ``temporary_cache()/numba``, tried where
    ``NUMBA_CACHE_DIR``, the sources' ``__pycache__`` and numba's user cache (``~/.cache/
    numba``) cannot be written; True if it is there (once a process; False where numba is
    not laid out as expected, which leaves it as it is)."""
    from numba.core import caching

    impl = getattr(caching, "CacheImpl", None)
    user_wide = getattr(caching, "UserWideCacheLocator", None)
    locators = getattr(impl, "_locator_classes", None)
    if user_wide is None or not isinstance(locators, list):
        return False
    if any(getattr(c, "_mcnumba_temporary", False) for c in locators):
        return True

    class TemporaryFolderCacheLocator(user_wide):
        """numba's user-wide locator, rooted in this user's private temporary folder."""

        _mcnumba_temporary = True

        def __init__(self, py_func, py_file):
            self._py_file = py_file
            self._lineno = py_func.__code__.co_firstlineno
            self._root = temporary_cache()
            self._cache_path = os.path.join(self._root, "numba",
                                            self.get_suitable_cache_subpath(py_file))

        def ensure_cache_path(self):
            private_folder(self._root)
            os.makedirs(self._cache_path, exist_ok=True)
            tempfile.TemporaryFile(dir=self._cache_path).close()

        @classmethod
        def from_function(cls, py_func, py_file):
            if not os.path.exists(py_file):     # "<ipython-...>": not a file
                return None
            self = cls(py_func, py_file)
            try:
                self.ensure_cache_path()
            except OSError:                     # numba: "no locator available"
                return None
            return self

    locators.append(TemporaryFolderCacheLocator)
    return True
