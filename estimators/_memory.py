"""The machine's physical memory, for refusing requests that could never fit (a film or
a sample count named in the message, instead of numpy's allocation error)."""

from __future__ import annotations

import os


def physical_bytes() -> int | None:
    """Bytes of physical memory, or None where the platform does not say (then numpy's
    own allocation decides)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None
