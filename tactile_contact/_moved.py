"""Old module paths of the flat layout (before the stage packages), kept importable.

Until version 0.2 every module sat directly in ``tactile_contact`` (``tactile_contact.codec``,
``tactile_contact.reconstruction``, ``tactile_contact.nodes.skin_driver``, ...). Code and
command lines that still name them (``import``, ``from … import``, ``python -m``) get the module
at its new place, the same module object, with a :class:`DeprecationWarning` naming that place.
A name that never existed still fails as usual.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import sys
import types
import warnings
from collections.abc import Sequence
from typing import Any

#: Old dotted name (under ``tactile_contact.``) → new one. A package maps its submodules too
#: (``elastic.love`` → ``model.elastic.love``).
MOVED: dict[str, str] = {
    "codec": "canbus.codec",
    "assembler": "canbus.assembler",
    "stream": "canbus.stream",
    "baseline": "canbus.baseline",
    "bus_health": "canbus.bus_health",
    "can_fuzz": "canbus.fuzz",
    "modules": "model.modules",
    "layout": "model.layout",
    "grids": "model.grids",
    "sensor": "model.sensor",
    "indenters": "model.indenters",
    "forward": "model.forward",
    "elastic": "model.elastic",
    "detection": "inverse.detection",
    "contacts": "inverse.contacts",
    "summary": "inverse.summary",
    "_round_kernels": "inverse._round_kernels",
    "round_contact": "inverse.round_contact",
    "reconstruction": "inverse.reconstruction",
    "solvers": "inverse.solvers",
    "bundle": "offline.bundle",
    "build": "offline.build",
    "calibrate": "offline.calibrate",
    "simulator": "sim.simulator",
    "nodes": "ros",
    "bag": "ros.bag",
    "cli": "ros.cli",
    "demo": "ros.demo",
}

_PREFIX = "tactile_contact."


def new_name(old: str) -> str | None:
    """The current dotted name of the old module ``old`` (full name), or None if not moved."""
    if not old.startswith(_PREFIX):
        return None
    rest = old[len(_PREFIX) :]
    head, dot, tail = rest.partition(".")
    if head not in MOVED:
        return None
    return _PREFIX + MOVED[head] + dot + tail


class _AliasLoader(importlib.abc.Loader):
    """Loads an old name as the module at its new place (the same object)."""

    def __init__(self, old: str, new: str) -> None:
        self.old, self.new = old, new
        self._spec: importlib.machinery.ModuleSpec | None = None

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> types.ModuleType:
        warnings.warn(
            f"{self.old} moved to {self.new}; import it from there",
            DeprecationWarning,
            stacklevel=3,
        )
        module = importlib.import_module(self.new)
        self._spec = module.__spec__
        return module

    def exec_module(self, module: types.ModuleType) -> None:
        # The module at the new place is already executed; the import system files it under
        # the old name as well, so both names give the same object. It set the module's
        # __spec__ to the alias's: the module keeps its own.
        module.__spec__ = self._spec

    def get_code(self, fullname: str) -> Any:
        # `python -m tactile_contact.build` (runpy) runs the new module's code as __main__.
        spec = importlib.util.find_spec(self.new)
        if spec is None or spec.loader is None:
            raise ImportError(f"{self.old} moved to {self.new}, which cannot be found")
        return spec.loader.get_code(self.new)  # type: ignore[attr-defined]

    def is_package(self, fullname: str) -> bool:
        spec = importlib.util.find_spec(self.new)
        return bool(spec is not None and spec.submodule_search_locations is not None)


class MovedFinder(importlib.abc.MetaPathFinder):
    """Finds old module names (see :data:`MOVED`); first on ``sys.meta_path``, so that a
    submodule of a moved package (``tactile_contact.elastic.love``) is the new one too and not
    loaded a second time from the package's path."""

    def find_spec(
        self, fullname: str, path: Sequence[str] | None, target: types.ModuleType | None = None
    ) -> importlib.machinery.ModuleSpec | None:
        new = new_name(fullname)
        if new is None or importlib.util.find_spec(new) is None:
            return None
        loader = _AliasLoader(fullname, new)
        return importlib.util.spec_from_loader(
            fullname, loader, is_package=loader.is_package(fullname)
        )


def install() -> None:
    """Put one :class:`MovedFinder` on ``sys.meta_path`` (idempotent)."""
    if not any(isinstance(f, MovedFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, MovedFinder())
