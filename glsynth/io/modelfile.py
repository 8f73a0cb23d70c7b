"""Reading model files (checkpoints, state dicts) without running code from them.

``torch.load`` unpickles: a crafted file can make it call any importable function. With
``weights_only=True`` torch only rebuilds tensors, containers and plain Python values,
and refuses everything else; glsynth's checkpoints hold nothing more.
"""
from __future__ import annotations

import os
import pickle
import re

from ..errors import ModelFileError


def load_torch_file(path, what="model file"):
    """The object in the torch file ``path`` (on the CPU), read with ``weights_only``;
    :class:`ModelFileError` naming the file when it is unreadable or asks for more."""
    import torch
    from torch.torch_version import TorchVersion  # a str; older checkpoints hold one

    path = os.fspath(path)
    if os.path.isdir(path):
        raise ModelFileError(f"{path}: is a folder, not a {what}")
    try:
        with torch.serialization.safe_globals([TorchVersion]):
            return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        refused = re.search(r"GLOBAL (\S+) was not an allowed global", str(exc))
        if refused:
            raise ModelFileError(
                f"{path}: refused: the {what} holds a Python object ({refused.group(1)}) beyond "
                "tensors and plain values, and glsynth never runs code from a model file") from None
        raise ModelFileError(f"{path}: not a torch {what} (unreadable pickle data)") from None
    except (EOFError, RuntimeError, ValueError, TypeError, AttributeError) as exc:
        why = str(exc).splitlines()[0] if str(exc) else "the file is empty or cut short"
        raise ModelFileError(f"{path}: not a readable torch {what} ({why})") from None


def check_torch_file(path, what="model file"):
    """Open ``path`` and check that it starts as a torch file does (a zip archive, or a
    pickle for the legacy format), without loading it."""
    path = os.fspath(path)
    if os.path.isdir(path):
        raise ModelFileError(f"{path}: is a folder, not a {what}")
    with open(path, "rb") as fh:
        head = fh.read(4)
    if not (head.startswith(b"PK\x03\x04") or head[:1] == b"\x80"):
        raise ModelFileError(f"{path}: not a torch {what} ("
                             + ("the file is empty)" if not head else "neither a zip archive nor a pickle)"))
