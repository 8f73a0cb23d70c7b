"""The failures glsynth expects: bad input, unusable files, a full disk, a busy folder.

Every one derives from :class:`GlsynthError`, and also from the built-in class it was
raised as before (``ValueError``, ``RuntimeError``, ``OSError``...), so that code
catching those still catches it. The command line prints a ``GlsynthError`` (or an
``OSError``) as one line naming the file and the problem; any other exception is a bug
and keeps its traceback. The domain errors live beside their code (``ConfigError`` in
``glsynth.config``, ``LesionError`` in ``glsynth.assets.lesions``...); this module holds
the base and the errors that belong to no one module.
"""
from __future__ import annotations

import errno as _errno


class GlsynthError(Exception):
    """An expected failure; the message names the file, key or argument and the problem."""


class InputError(GlsynthError, ValueError):
    """An argument or a file's content that glsynth cannot use."""


class MeshError(InputError):
    """A mesh (or a mesh file) is unusable; the message names the file and the problem.
    Here, not in ``glsynth.mesh``, because the mesh file readers (``glsynth.io.meshfile``)
    raise it too, and ``Mesh.load`` calls them."""


class ModelFileError(InputError):
    """A model or checkpoint file is unreadable, not glsynth's, or holds more than plain
    tensors and Python values (glsynth never runs code from a model file)."""


class UnavailableError(GlsynthError, RuntimeError):
    """Something the machine lacks for this request (CUDA, a display, a GL backend)."""


class MissingDependencyError(GlsynthError, ImportError):
    """An optional dependency is not installed; the message names the extra to install."""


class WriteError(GlsynthError, OSError):
    """A file could not be written completely; built like ``OSError(errno, strerror,
    path)``. Nothing is left under the final name."""

    def __str__(self):
        why = self.strerror or "write failed"
        if self.errno in (_errno.ENOSPC, _errno.EDQUOT):
            why += " (the disk or your quota is full: free space, or write elsewhere)"
        return f"{self.filename}: could not write the file: {why}"


def describe(exc: BaseException) -> str:
    """One line for the user: the message, or ``path: reason`` for a plain OSError."""
    if isinstance(exc, OSError) and not isinstance(exc, GlsynthError) and exc.filename:
        text = f"{exc.filename}: {exc.strerror or exc}"
        if exc.filename2:
            text += f" ({exc.filename2})"
    else:
        text = str(exc) or type(exc).__name__
    return " ".join(text.split())
