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
"""

from __future__ import annotations

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
