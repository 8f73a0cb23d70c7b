"""Ray executor against the local executor, measured in one run on this machine.

    .venv/bin/python tools/bench_ray.py [--views 8] [--repeats 1] [--chunk 4] [--calls 200]

1. Samples per second of the views stage (default config, 512x512, 2 bodies pasted and
   blended beforehand and reused, writing included) with 1 and 2 workers, for the local
   executor (worker processes) and for Ray (actors on a local cluster started once, so
   ``ray.init`` is not counted; starting the actors is, as the process pool's start is
   for the local executor). Median of ``--repeats``.
2. Ray's per-task overhead: the round trip of a no-op actor call, and the wall time of
   one render chunk of ``--chunk`` views called directly on a ``Worker`` in this
   process against the same chunk on a Ray actor (body already loaded in both).

Prints Markdown tables.
"""
from __future__ import annotations

import argparse
import glob
import logging
import os
import shutil
import statistics
import tempfile
import time

from glsynth.config import load_config
from glsynth.pipeline import generate
from glsynth.pipeline.worker import Worker


def _views_rate(overrides, prepared, workers, executor, repeats):
    rates, man = [], None
    for _ in range(repeats):
        out = tempfile.mkdtemp(prefix="glsynth-bench-ray-")
        shutil.copytree(f"{prepared}/bodies", f"{out}/bodies")
        t0 = time.perf_counter()
        man = generate(load_config(None, overrides), out, resume=True, workers=workers, executor=executor)
        rates.append(man["counts"]["images"] / (time.perf_counter() - t0))
        shutil.rmtree(out)
    return statistics.median(rates), man


def _clear_samples(out):
    for d in ("images", "targets"):
        shutil.rmtree(os.path.join(out, d), ignore_errors=True)
    for f in glob.glob(os.path.join(out, ".tmp-*")):
        os.unlink(f)


def _chunk_times(call, out, repeats):
    call()  # warm-up: loads the body and the backgrounds
    times = []
    for _ in range(repeats):
        _clear_samples(out)
        t0 = time.perf_counter()
        call()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, default=8, help="views per body (2 bodies)")
    ap.add_argument("--repeats", type=int, default=1, help="runs per throughput setting")
    ap.add_argument("--chunk", type=int, default=4, help="views in the per-chunk comparison")
    ap.add_argument("--chunk-repeats", type=int, default=5)
    ap.add_argument("--calls", type=int, default=200, help="no-op round trips timed")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    import ray
    from glsynth.pipeline.ray_executor import GlsynthWorker

    base = [f"views.per_body={args.views}"]
    prepared = tempfile.mkdtemp(prefix="glsynth-prep-")
    generate(load_config(None, base + ["views.per_body=0"]), prepared)  # bodies, paste, blend

    t0 = time.perf_counter()
    ray.init(num_cpus=2, include_dashboard=False, logging_level=logging.WARNING)
    t_init = time.perf_counter() - t0
    try:
        print(f"## Samples per second (512x512, default config, {2 * args.views} views, "
              "views stage incl. writing)\n")
        print("| executor | workers | samples/s | vs local, same workers |")
        print("|---|---:|---:|---:|")
        local = {}
        for workers in (1, 2):
            for executor in ("local", "ray"):
                rate, man = _views_rate(base, prepared, workers, executor, args.repeats)
                if executor == "local":
                    local[workers] = rate
                print(f"| {executor} | {workers} | {rate:.2f} | {rate / local[workers]:.2f} |")
        print(f"\nGL_RENDERER: {man['gl_renderer']}; ray.init of the local cluster "
              f"(not counted above): {t_init:.1f} s\n")

        # per-task overhead
        cfg = load_config(None, base)
        out = tempfile.mkdtemp(prefix="glsynth-bench-chunk-")
        shutil.copytree(f"{prepared}/bodies", f"{out}/bodies")
        chunk = [("body000", j) for j in range(args.chunk)]
        t0 = time.perf_counter()
        actor = GlsynthWorker.options(num_cpus=1, runtime_env={"env_vars": {"TQDM_DISABLE": "1"}}).remote(
            cfg.to_dict(), out)
        ray.get(actor.ready.remote())
        t_actor = time.perf_counter() - t0
        ray.get(actor.ping.remote())
        trips = []
        for _ in range(args.calls):
            t0 = time.perf_counter()
            ray.get(actor.ping.remote())
            trips.append(time.perf_counter() - t0)
        t_ray = _chunk_times(lambda: ray.get(actor.render.remote(chunk)), out, args.chunk_repeats)
        ray.kill(actor)
        _clear_samples(out)
        worker = Worker(cfg, out)
        t_local = _chunk_times(lambda: worker.render(chunk), out, args.chunk_repeats)
        # Ray runs a 1-CPU actor with OMP_NUM_THREADS=1: the same chunk with torch on one thread
        import torch
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        t_local1 = _chunk_times(lambda: worker.render(chunk), out, args.chunk_repeats)
        torch.set_num_threads(threads)
        shutil.rmtree(out)

        print("## Ray per-task overhead\n")
        print("| measure | value |\n|---|---:|")
        print(f"| no-op actor call round trip, median of {args.calls} | "
              f"{statistics.median(trips) * 1e3:.2f} ms |")
        print(f"| no-op actor call round trip, 90th percentile | "
              f"{statistics.quantiles(trips, n=10)[-1] * 1e3:.2f} ms |")
        print(f"| start one actor (process, imports, GL context) until ready | {t_actor:.2f} s |")
        print(f"| chunk of {args.chunk} views, local `Worker.render` | {t_local * 1e3:.0f} ms |")
        print(f"| same, torch on 1 thread (as in a 1-CPU Ray actor) | {t_local1 * 1e3:.0f} ms |")
        print(f"| same chunk on a Ray actor | {t_ray * 1e3:.0f} ms |")
        print(f"| Ray actor vs local (torch 1 thread) per chunk | {(t_ray - t_local1) * 1e3:+.0f} ms "
              f"({(t_ray / t_local1 - 1) * 100:+.1f} %) |")
    finally:
        ray.shutdown()
        shutil.rmtree(prepared, ignore_errors=True)


if __name__ == "__main__":
    main()
