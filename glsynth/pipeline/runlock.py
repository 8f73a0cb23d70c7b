"""One run per output folder: the run's fingerprint and a lock.

``OUT/fingerprint.json`` (the resolved config with its seed, and glsynth's version) is
written before anything else. Whatever continues in the folder later (``--resume``, a
stage command) must have the same fingerprint, so that a dataset never mixes two
configurations under the same sample ids.

``OUT/.glsynth.lock`` is locked (``flock``) while a process writes the folder: a second
process is refused, naming the first. The kernel drops the lock when its holder dies, so
the lock of a killed run is simply taken over.
"""
from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import logging
import os
import socket
import time

from .. import __version__
from ..config import Config
from ..errors import GlsynthError
from ..io.images import write_text

log = logging.getLogger(__name__)

FINGERPRINT = "fingerprint.json"
LOCK = ".glsynth.lock"
# what a run writes; a folder holding any of these has a run in it
RUN_ENTRIES = (FINGERPRINT, "manifest.json", "images", "targets", "bodies")


class RunFolderError(GlsynthError):
    """The output folder cannot take this run (another run's data, or busy)."""


class RunFolderExistsError(RunFolderError, FileExistsError):
    """The folder holds a run and this call does not continue it."""


class RunLockedError(RunFolderError):
    """Another process is writing the folder."""


def fingerprint(cfg: Config) -> dict:
    return {"glsynth_version": __version__, "seed": cfg.seed, "config": cfg.to_dict()}


@contextlib.contextmanager
def open_run(out, cfg: Config, resume: bool):
    """Hold ``out`` for this run: create it, lock it, and check (or write, for a new
    run) its fingerprint. ``resume=False`` refuses a folder that holds a run."""
    out = os.fspath(out)
    if os.path.exists(out) and not os.path.isdir(out):
        raise RunFolderExistsError(f"{out}: exists and is not a folder; choose another --out")
    os.makedirs(out, exist_ok=True)
    with _locked(out):
        has_run = any(os.path.exists(os.path.join(out, e)) for e in RUN_ENTRIES)
        if has_run and not resume:
            raise RunFolderExistsError(f"{out}: output folder is not empty; pass --resume to "
                                       "continue the run there, or choose another folder")
        mine = fingerprint(cfg)
        if has_run:
            _check(out, _recorded(out), mine)
        if not os.path.isfile(os.path.join(out, FINGERPRINT)):
            write_text(os.path.join(out, FINGERPRINT), json.dumps(mine, indent=1, sort_keys=True),
                       durable=True)
        yield out


def _recorded(out) -> dict:
    """The folder's fingerprint; a run made before fingerprints has it in its manifest."""
    for name in (FINGERPRINT, "manifest.json"):
        path = os.path.join(out, name)
        if os.path.isfile(path):
            try:
                with open(path, encoding="utf-8") as fh:
                    data = json.load(fh)
                return {k: data[k] for k in ("glsynth_version", "seed", "config")}
            except (ValueError, KeyError, TypeError) as exc:
                raise RunFolderError(f"{path}: unreadable run fingerprint ({exc}); this folder "
                                     "cannot be continued safely: choose another --out") from None
    raise RunFolderError(f"{out}: holds part of a run but no {FINGERPRINT} (it was not made by "
                         "this glsynth version), so it cannot be continued safely: choose "
                         "another --out")


def _check(out, recorded: dict, mine: dict):
    old, new = _flatten(recorded), _flatten(mine)
    diffs = [(k, old.get(k, "<absent>"), new.get(k, "<absent>"))
             for k in list(old) + [k for k in new if k not in old] if old.get(k) != new.get(k)]
    if diffs:
        shown = ", ".join(f"{k} {a!r} -> {b!r}" for k, a, b in diffs[:3])
        more = f" and {len(diffs) - 3} more" if len(diffs) > 3 else ""
        raise RunFolderError(f"{out}: holds a run with another config: {shown}{more}; continue it "
                             f"with its own config ({FINGERPRINT}) or choose another --out")


def _flatten(fp: dict) -> dict:
    """{dotted key: value} of the version and the config (which holds the seed)."""
    flat = {"glsynth_version": fp.get("glsynth_version")}

    def walk(node, prefix):
        for k, v in node.items():
            if isinstance(v, dict):
                walk(v, f"{prefix}{k}.")
            else:
                flat[f"{prefix}{k}"] = v
    walk(fp.get("config") or {}, "")
    return flat


@contextlib.contextmanager
def _locked(out):
    path = os.path.join(out, LOCK)
    fd = None
    while fd is None:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            holder = os.pread(fd, 200, 0).decode("utf-8", "replace").strip() or "unknown"
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN):
                raise RunLockedError(f"{out}: another glsynth run is writing this folder ({holder}); "
                                     "wait for it to end, or choose another --out") from None
            log.warning("%s: cannot lock the folder (%s); make sure no other run writes there",
                        out, exc.strerror)
            yield
            return
        # the holder before us may have removed the file between our open and flock
        try:
            current = os.stat(path).st_ino
        except FileNotFoundError:
            current = None
        if current != os.fstat(fd).st_ino:
            os.close(fd)
            fd = None
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()} on {socket.gethostname()} since "
                      f"{time.strftime('%Y-%m-%d %H:%M:%S')}\n".encode(), 0)
        yield
    finally:
        with contextlib.suppress(OSError):
            os.unlink(path)  # while still locked: a process that opened it re-checks above
        os.close(fd)
