"""The views of glsynth datasets, for the tools that compare them with real photographs."""
from __future__ import annotations

from pathlib import Path

from glsynth.dataformat import RunFolder


def views_by_framing(folder):
    """(framing, RunFolder, sample id) for every view of the run folders at or below
    ``folder`` (a sim2real ``data`` folder holds one per part); framing is the record's
    ``camera.framing`` ("wild" in runs from before framings)."""
    for targets in sorted(Path(folder).rglob("targets")):
        run = RunFolder(targets.parent)
        for sid in run.sample_ids():
            yield run.record(sid)["camera"].get("framing", "wild"), run, sid
