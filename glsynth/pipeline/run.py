"""``generate``: the whole pipeline into one run folder, on the local or the Ray
executor, and the run's manifest."""
from __future__ import annotations

import json
import os
import time

from .. import __version__
from ..config import Config
from ..errors import InputError
from ..io.images import remove_temporaries
from .bodies import body_ids
from .inputs import open_inputs
from .runlock import open_run
from .writer import finalize

EXECUTORS = ("local", "ray")


def generate(cfg: Config, out, resume=False, workers=1, executor="local", address=None):
    """The whole pipeline into ``out``; returns the manifest.

    ``workers`` > 1 runs that many processes, each with its own GL context, started
    once: bodies are pasted and blended in parallel, then views are rendered in chunks.
    Every random choice is keyed by the task, so the files are the same for any
    number of workers. ``executor="ray"`` spreads the same tasks over Ray actors
    (``address``: an existing cluster; None starts a local one).

    ``out`` holds one run (``runlock``): a folder with a run in it needs ``resume``,
    which continues it only with the same config, seed and glsynth version, and no
    other process may write there meanwhile.
    """
    out = os.fspath(out)
    if workers < 1:
        raise InputError(f"workers must be >= 1, got {workers}")
    if executor not in EXECUTORS:
        raise InputError(f"executor must be one of {EXECUTORS}, got {executor!r}")
    # one run per folder: locked, and its fingerprint written first or checked
    with open_run(out, cfg, resume):
        return _generate(cfg, out, resume, workers, executor, address)


def _generate(cfg, out, resume, workers, executor, address):
    if resume:
        remove_temporaries(out)  # of writes a killed run never renamed into place
    inputs = open_inputs(cfg)  # every input file checked before any stage works
    t_start = time.perf_counter()
    ids = body_ids(cfg)
    tasks = [(b, j) for b in ids for j in range(cfg.views.per_body)]
    chunk = max(1, min(8, len(tasks) // (4 * workers) or 1))
    chunks = [tasks[i:i + chunk] for i in range(0, len(tasks), chunk)]
    if executor == "ray":
        from .ray_executor import run_ray
        reports = run_ray(cfg, out, ids, chunks, workers, address)
    else:
        from .local_executor import run_local
        reports = run_local(cfg, out, ids, tasks, chunks, workers, inputs)
    timings, rejected = {}, {}
    for r in reports:
        for k, t in r["timings"].items():
            timings[k] = timings.get(k, 0.0) + t
        for k, n in r.get("rejected", {}).items():
            rejected[k] = rejected.get(k, 0) + n
    timings["total"] = time.perf_counter() - t_start
    features = _blend_features(out, ids)
    gl = reports[-1]["gl"] if reports else {}
    manifest = {"glsynth_version": __version__, "seed": cfg.seed, "config": cfg.to_dict(),
                "workers": workers, "executor": executor, "gl_renderer": gl.get("GL_RENDERER"),
                "gl_version": gl.get("GL_VERSION"), "versions": _versions(),
                "blend_features": ", ".join(features),
                "timings_seconds": {k: round(t, 3) for k, t in timings.items()},
                "rejected_views": rejected}
    finalize(out, manifest)
    return manifest


def _blend_features(out, ids) -> list:
    """The feature extractors the bodies' deep blends used, from their blend.json: the
    same for a resumed run, which blends nothing itself."""
    found = set()
    for body_id in ids:
        path = os.path.join(out, "bodies", body_id, "blend.json")
        if os.path.isfile(path):
            with open(path) as fh:
                found.add(json.load(fh).get("features", "none"))
    return sorted(found - {"none"}) or ["none"]


def _versions():
    import importlib.metadata as md
    out = {}
    for pkg in ("numpy", "torch", "moderngl", "anny", "opencv-contrib-python-headless"):
        try:
            out[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            pass
    return out
