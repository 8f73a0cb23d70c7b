"""Network width, depth and input size against the real-image score, at a fixed budget.

    .venv/bin/python tools/train_sweep.py --real ../shared/realdev/fitz17k \
        --data RUN/data/part000 --data RUN/data/part001 ... --minutes 10 --out /tmp/sweep \
        [--grid 1,0,256 0.5,0,256 2,0,256 1,1,256 1,0,192 1,0,320] [--threads 1]

Each grid point (width, depth, size) is one ``glsynth sim2real`` run on the same
synthetic data (``--data``: nothing is generated) with the same minutes of training, so
the points differ only in the network and its input size: a bigger network or input
takes fewer steps in the same time. Writes ``sweep.md`` (the curve: parameters, steps,
seconds per step, Jaccard per class, AP_centroid) and ``sweep.json`` in --out; a point
already run there is read back, not trained again (the sweep resumes).
"""
from __future__ import annotations

import argparse
import json
import os

DEFAULT_GRID = ("1,0,256", "0.5,0,256", "2,0,256", "1,1,256", "1,0,192", "1,0,320")


def point_name(width, depth, size) -> str:
    return f"w{width:g}_d{depth}_s{size}"


def run_point(args, width, depth, size) -> dict:
    from glsynth.config import load_config
    from glsynth.train.sim2real import sim2real
    out = os.path.join(args.out, point_name(width, depth, size))
    done = os.path.join(out, "summary.json")
    if os.path.exists(done):
        with open(done) as f:
            return json.load(f)
    return sim2real(load_config(None, ()), args.real, args.layout, args.minutes, out,
                    resume=os.path.exists(out), data=args.data, seed=args.seed, size=size,
                    width=width, depth=depth, progress=not args.quiet)


def row(s) -> dict:
    r = s["sim2real"]
    return {"width": r["width"], "depth": r["depth"], "size": r["size"],
            "parameters": r["n_parameters"], "steps": r["training_steps"],
            "seconds_per_step": r["seconds_per_step"], "jaccard": s["jaccard"],
            "jaccard_nonempty": s["jaccard_nonempty"],
            "ap_centroid": s.get("detection", {}).get("ap_centroid")}


def sweep_md(rows, args) -> str:
    lines = [f"# Network and input size against the real-image score ({args.minutes:g} min "
             f"of training each, same data)", "",
             "| width | depth | size | parameters | steps | s/step | lesion | skin | "
             "non-skin (non-empty) | AP_centroid |", "|---|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        j, jn = r["jaccard"], r["jaccard_nonempty"]
        ap = "—" if r["ap_centroid"] is None else f"{r['ap_centroid']:.3f}"
        lines.append(f"| {r['width']:g} | {r['depth']} | {r['size']} | {r['parameters']:,} | "
                     f"{r['steps']} | {r['seconds_per_step']:.3f} | {j['lesion']:.3f} | "
                     f"{j['skin']:.3f} | {j['nonskin']:.3f} ({jn['nonskin']:.3f}) | {ap} |")
    return "\n".join(lines) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--real", required=True)
    ap.add_argument("--layout", default="fitz17k", choices=("fitz17k", "pairs"))
    ap.add_argument("--data", action="append", required=True, help="glsynth datasets to train on")
    ap.add_argument("--out", required=True)
    ap.add_argument("--minutes", type=float, default=10.0, help="budget of each point")
    ap.add_argument("--grid", nargs="+", default=list(DEFAULT_GRID), metavar="W,D,S")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=None, help="CPU threads for torch")
    ap.add_argument("-q", "--quiet", action="store_true")
    args = ap.parse_args()
    import torch
    if args.threads:
        torch.set_num_threads(args.threads)
    os.makedirs(args.out, exist_ok=True)
    rows = []
    for point in args.grid:
        try:
            w, d, s = point.split(",")
            width, depth, size = float(w), int(d), int(s)
        except ValueError:
            ap.error(f"--grid point {point!r} is not WIDTH,DEPTH,SIZE")
        rows.append(row(run_point(args, width, depth, size)))
        with open(os.path.join(args.out, "sweep.json"), "w") as f:
            json.dump(rows, f, indent=1)
        with open(os.path.join(args.out, "sweep.md"), "w") as f:
            f.write(sweep_md(rows, args))
    print(sweep_md(rows, args))


if __name__ == "__main__":
    main()
