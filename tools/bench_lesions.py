"""Time to make each procedural condition's fields (glsynth.assets.morphology).

    .venv/bin/python tools/bench_lesions.py [--seeds 5] [--size 512] [--presets a,b] [--halo R]

For every preset: the median, over ``--seeds`` seeds, of the seconds ``make_condition``
takes on a ``--size`` grid (the default config's ``lesions.resolution``), and the median
number of lesion instances it outlines, each outline taking in the halo round its lesion
out to ``--halo`` of its radius (the config's ``lesions.halo``; 0 times the presets' own
outlines, the peer for what the halo costs). One untimed warm-up call first (imports and
first-use set-up are not what a run pays per lesion). Prints a Markdown table.
"""
from __future__ import annotations

import argparse
import statistics
import time

from glsynth.assets.morphology import HALO_REACH, PRESETS, make_condition


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--presets", default="", help="comma-separated preset names (default: all)")
    ap.add_argument("--halo", type=float, default=HALO_REACH,
                    help="share of a lesion's radius its outline may reach into its halo")
    args = ap.parse_args()
    names = [p for p in args.presets.split(",") if p] or list(PRESETS)
    make_condition(names[0], [10_000], size=args.size)
    print(f"| preset | median s ({args.seeds} seeds, {args.size}-cell grid, halo {args.halo:g}) "
          "| slowest s | instances (median) |")
    print("|---|---|---|---|")
    total = []
    for name in names:
        times, counts = [], []
        for seed in range(args.seeds):
            t = time.perf_counter()
            f = make_condition(name, [seed, 1], size=args.size, halo_reach=args.halo)
            times.append(time.perf_counter() - t)
            counts.append(int(f.instances.max()))
        total.append(statistics.median(times))
        print(f"| {name} | {statistics.median(times):.3f} | {max(times):.3f} | {statistics.median(counts):g} |")
    print(f"\nmean of the medians over {len(names)} presets: {statistics.mean(total):.3f} s")


if __name__ == "__main__":
    main()
