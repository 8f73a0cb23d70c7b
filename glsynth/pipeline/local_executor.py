"""``glsynth generate --executor local``: the run's tasks in this process (one worker)
or in a pool of worker processes, each with its own GL context, started once."""
from __future__ import annotations

import logging
import os

from tqdm import tqdm

from ..config import Config, from_dict
from .inputs import Inputs
from .worker import Worker, share_cores


def run_local(cfg: Config, out, ids, tasks, chunks, workers, inputs: Inputs):
    """Prepare (paste and blend) every body of ``ids``, then render the views: all
    ``tasks`` in one call with one worker (the views stage then loads each next body
    while rendering), else ``chunks`` of them spread over ``workers`` processes.
    Returns the workers' reports, prepare reports first."""
    if workers == 1:
        worker = Worker(cfg, out, inputs=inputs)
        try:
            reports = [worker.prepare(b) for b in tqdm(ids, desc="paste + blend", unit="body")]
            reports.append(worker.render(tasks, progress=True))
            return reports
        finally:  # a process that calls generate again must not keep this run's GL memory
            worker.close()
    import multiprocessing as mp
    ctx = mp.get_context("spawn")  # GL contexts do not survive fork
    threads = max(1, (os.cpu_count() or 1) // workers)
    with ctx.Pool(workers, initializer=_init, initargs=(cfg.to_dict(), out, threads)) as pool:
        reports = list(tqdm(pool.imap_unordered(_prepare, ids), total=len(ids),
                            desc="paste + blend", unit="body"))
        bar = tqdm(total=len(tasks), desc="views", unit="img")
        for r in pool.imap_unordered(_render, chunks):
            reports.append(r)
            bar.update(r["done"])
        bar.close()
    return reports


# In each pool process: its Worker, made once by the pool's initializer.
_PROCESS_WORKER = None


def _init(cfg_dict, out, threads):
    global _PROCESS_WORKER
    import signal
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the driver's to handle
    logging.basicConfig(level=logging.WARNING)
    share_cores(threads)
    _PROCESS_WORKER = Worker(from_dict(cfg_dict), out, writer_threads=threads)


def _prepare(body_id):
    return _PROCESS_WORKER.prepare(body_id)


def _render(tasks):
    return _PROCESS_WORKER.render(tasks)
