"""A module imported on its first use: ``scipy.stats`` and ``scipy.optimize`` cost about
2.5 s to import on a 2-core Zen 1, which every ``mcverify`` process paid at
``import mcverify`` even when it only plans, lists, prints its help or refuses a bad
argument (``mcverify --help`` took 2.7 s)."""

from __future__ import annotations

import importlib


class LazyModule:
    """Stands for the module ``name``: the first attribute read imports it."""

    def __init__(self, name: str):
        self._name = name
        self._module = None

    def __getattr__(self, attr: str):
        if self._module is None:
            self._module = importlib.import_module(self._name)
        return getattr(self._module, attr)

    def __repr__(self) -> str:
        return f"LazyModule({self._name!r})"
