"""Optional dependencies: imported when present, otherwise a stand-in that fails on use.

``glfw = optional_import("glfw", extra="preview", needed_by="glsynth preview")`` gives the
module, or a :class:`MissingModule` whose first attribute access raises
:class:`~glsynth.errors.MissingDependencyError` naming the ``pip install`` that fixes it
(the original ImportError chained), so importing glsynth's modules never fails for want
of an extra; only the command that needs it does.
"""
from __future__ import annotations

import importlib

from .errors import MissingDependencyError


class MissingModule:
    """Stands in for a module that could not be imported."""

    def __init__(self, name: str, extra: str, needed_by: str, error: ImportError):
        self._name, self._extra, self._needed_by, self._error = name, extra, needed_by, error

    def __getattr__(self, attr):
        if attr.startswith("__"):  # copy, pickle and introspection probe these
            raise AttributeError(attr)
        raise self._missing()

    def _missing(self) -> MissingDependencyError:
        err = MissingDependencyError(
            f"{self._needed_by} needs {self._name}, which is not installed: "
            f"pip install 'glsynth[{self._extra}]' (import failed: {self._error})")
        err.__cause__ = self._error
        return err


def require(module):
    """Raise the MissingDependencyError of a :class:`MissingModule`; a module passes."""
    if isinstance(module, MissingModule):
        raise module._missing()


def optional_import(name: str, extra: str, needed_by: str):
    """The module ``name``, or a :class:`MissingModule` when it cannot be imported."""
    try:
        return importlib.import_module(name)
    except ImportError as exc:
        return MissingModule(name, extra, needed_by, exc)
