"""Ends what a local Ray instance started by glsynth leaves behind when the driver dies.

Ray's GCS server and raylet die with the process that started them, but the agents the
raylet starts (dashboard agent, runtime-env agent) outlived a killed driver by a minute
or more. :class:`Reaper` starts a small watcher process in a session of its own (so
that Ctrl-C and a closed terminal leave it running) and sends it, through a pipe, the
processes the driver's Ray instance runs. When the pipe closes (the driver finished, or
died however it died) the watcher terminates those of them that still run: SIGTERM,
then SIGKILL. Linux only (``/proc``); elsewhere it does nothing.

    python glsynth/pipeline/ray_reaper.py      # the watcher; reads JSON lines on stdin
"""
from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time

GRACE_S = 3.0  # between SIGTERM and SIGKILL


def _stat(pid):
    """(ppid, start time, state) of a process, or None when it is gone."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            stat = fh.read().decode("ascii", "replace")
    except OSError:
        return None
    fields = stat[stat.rindex(")") + 2:].split()  # the name may hold spaces and parentheses
    return int(fields[1]), int(fields[19]), fields[0]


def descendants(root: int) -> dict:
    """{pid: start time} of every process below ``root``."""
    if not os.path.isdir("/proc"):
        return {}
    table = {}
    for name in os.listdir("/proc"):
        if name.isdigit():
            st = _stat(int(name))
            if st is not None:
                table[int(name)] = st
    children = {}
    for pid, (ppid, _, _) in table.items():
        children.setdefault(ppid, []).append(pid)
    found, todo = {}, [root]
    while todo:
        for child in children.get(todo.pop(), ()):
            found[child] = table[child][1]
            todo.append(child)
    return found


class Reaper:
    """Driver side: start it before ``ray.init``, call :meth:`watch` after, and
    :meth:`close` after ``ray.shutdown`` (if the driver dies, the kernel closes it)."""

    def __init__(self):
        self._before = set(descendants(os.getpid()))
        # run by path: importing the glsynth package would load numpy, OpenCV... for nothing
        self._proc = subprocess.Popen([sys.executable, os.path.abspath(__file__)],
                                      stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                                      start_new_session=True)
        self._before.add(self._proc.pid)

    def watch(self):
        """Hand every process started below this one since the reaper to the watcher."""
        new = {pid: t for pid, t in descendants(os.getpid()).items() if pid not in self._before}
        with contextlib.suppress(OSError):
            self._proc.stdin.write((json.dumps(new) + "\n").encode())
            self._proc.stdin.flush()

    def close(self, timeout=10.0):
        with contextlib.suppress(OSError):
            self._proc.stdin.close()
        with contextlib.suppress(subprocess.TimeoutExpired):
            self._proc.wait(timeout)


def _running(watched: dict) -> list:
    """The watched processes still running (same start time: not a reused pid; zombies
    are dead already)."""
    out = []
    for pid, start in watched.items():
        st = _stat(pid)
        if st is not None and st[1] == start and st[2] != "Z":
            out.append(pid)
    return out


def terminate(watched: dict):
    for sig, wait in ((signal.SIGTERM, GRACE_S), (signal.SIGKILL, 1.0)):
        for pid in _running(watched):
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.kill(pid, sig)
        deadline = time.monotonic() + wait
        while _running(watched) and time.monotonic() < deadline:
            time.sleep(0.05)


def main():
    for sig in (signal.SIGINT, signal.SIGHUP):  # the driver's terminal is not ours
        signal.signal(sig, signal.SIG_IGN)
    watched = {}
    for line in sys.stdin.buffer:  # until the driver closes the pipe or dies
        with contextlib.suppress(ValueError):
            watched.update({int(pid): int(start) for pid, start in json.loads(line).items()})
    terminate(watched)


if __name__ == "__main__":
    main()
