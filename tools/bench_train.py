"""Seconds per training step of ``glsynth train`` in steady state, optionally paired
against another checkout of glsynth measured in the same run.

    .venv/bin/python tools/bench_train.py --data RUN/data/part000 [--epochs 4] \
        [--repeats 3] [--peer /path/to/other/checkout] [--size 256] [--batch 8]

Each measurement is one ``train`` call in a fresh process (the current checkout's
``glsynth``, or ``--peer``'s): ``--epochs`` passes over ``--data``, timed from the
epoch history, leaving out the first epoch (imports, first decoding of every sample,
allocator warm-up), so the figure is what a long run pays per step: data loading,
augmentation, forward, loss, backward, optimiser and weight average. Checkout and peer
alternate, ``--repeats`` times each; prints the medians and their ratio.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

_MEASURE = """
import json, sys, tempfile, os
from glsynth.train.trainer import train
data, epochs, size, batch = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
with tempfile.TemporaryDirectory() as d:
    ck = train(data, os.path.join(d, "m.pt"), size=size, batch_size=batch, epochs=epochs,
               progress=False, save_every=0)
h = ck["history"]
print(json.dumps((h[-1]["seconds"] - h[0]["seconds"]) / (h[-1]["step"] - h[0]["step"])))
"""


def measure(src, data, epochs, size, batch) -> float:
    env = dict(os.environ, PYTHONPATH=os.path.abspath(src))
    with tempfile.TemporaryDirectory() as cwd:  # no stray imports from the caller's folder
        out = subprocess.run([sys.executable, "-c", _MEASURE, os.path.abspath(data), str(epochs),
                              str(size), str(batch)], env=env, cwd=cwd, check=True,
                             capture_output=True, text=True).stdout
    return float(json.loads(out.strip().splitlines()[-1]))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, help="a glsynth generate folder")
    ap.add_argument("--epochs", type=int, default=4, help="passes over --data (at least 2)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--peer", help="another glsynth checkout to time in the same run")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--batch", type=int, default=8)
    args = ap.parse_args()
    if args.epochs < 2:
        ap.error("--epochs must be at least 2 (the first is left out)")
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    sources = {"this checkout": here, **({"peer": args.peer} if args.peer else {})}
    times = {k: [] for k in sources}
    for r in range(args.repeats):
        for name, src in sources.items():
            times[name].append(measure(src, args.data, args.epochs, args.size, args.batch))
            print(f"repeat {r + 1}: {name}: {times[name][-1]:.3f} s per step", file=sys.stderr,
                  flush=True)
    print(f"| code | median s per step ({args.repeats} runs, batch {args.batch}, {args.size} px) | runs |")
    print("|---|---|---|")
    for name, ts in times.items():
        print(f"| {name} | {statistics.median(ts):.3f} | {', '.join(f'{t:.3f}' for t in ts)} |")
    if args.peer:
        ratio = statistics.median(times["peer"]) / statistics.median(times["this checkout"])
        print(f"\nthis checkout is {ratio:.2f}x as fast as the peer")


if __name__ == "__main__":
    main()
