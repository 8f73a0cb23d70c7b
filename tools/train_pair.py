"""Training alone, paired: one dataset, the same fixed steps, one training option changed.

    .venv/bin/python tools/train_pair.py --real ../shared/realdev/fitz17k --out /tmp/pair \
        [--config configs/default.yaml] [--set seed=100 ...] [--data RUN/data/part000 ...] [--steps 4000] \
        [--skin-loss paper,exclusive] [--seed 0] [--tta d4]

Without ``--data`` it first generates the yardstick's share of a 30-minute
``glsynth sim2real`` run (30% of 29 minutes, in parts of 2 bodies x 80 views, into
``--out/data``). Each arm then trains from the same seed for ``--steps`` optimiser steps
(fixed, so the arms see the same batches in the same order and a busy host changes only
their time) and is scored on ``--real`` as ``glsynth evaluate`` scores it. Arms whose
``summary.json`` exists are skipped, so a stopped run continues. Prints one line per
arm and writes ``results.json`` in --out.
"""
from __future__ import annotations

import argparse
import json
import os
import time


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--real", required=True)
    ap.add_argument("--layout", default="fitz17k", choices=("fitz17k", "pairs"))
    ap.add_argument("--out", required=True)
    ap.add_argument("--config", default=None, help="YAML config (default: the embedded default)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                    help="config override for the generated data (repeatable)")
    ap.add_argument("--data", action="append", default=None, help="glsynth datasets to train on")
    ap.add_argument("--steps", type=int, default=4000)
    ap.add_argument("--skin-loss", default="paper,exclusive", help="comma-separated arms")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--tta", default="d4", choices=("none", "flip", "d4"))
    a = ap.parse_args()

    from glsynth.config import load_config
    from glsynth.train.evaluate import evaluate
    from glsynth.train.sim2real import generate_parts
    from glsynth.train.trainer import train

    os.makedirs(a.out, exist_ok=True)
    folders = a.data
    if not folders:
        done = os.path.join(a.out, "parts.json")
        if os.path.exists(done):
            with open(done) as f:
                folders = json.load(f)
        else:
            folders = generate_parts(load_config(a.config, a.overrides), a.out, (30 - 1) * 60 * 0.3, state={})
            with open(done, "w") as f:
                json.dump(folders, f)
    results = {}
    for arm in a.skin_loss.split(","):
        d = os.path.join(a.out, f"skin_loss-{arm}")
        ckpt = os.path.join(d, "model.pt")
        if not os.path.exists(os.path.join(d, "summary.json")):
            os.makedirs(d, exist_ok=True)
            t0 = time.perf_counter()
            ck = train(folders, ckpt, seed=a.seed, steps=a.steps, save_every=2.0, skin_loss=arm,
                       progress=False, resume=os.path.exists(ckpt))
            evaluate(ckpt, a.real, a.layout, d, progress=False, tta=a.tta,
                     extra={"train_seconds": round(time.perf_counter() - t0, 1), "steps": ck["step"]})
        with open(os.path.join(d, "summary.json")) as f:
            s = json.load(f)
        results[arm] = {"jaccard": {c: v["jaccard_mean"] for c, v in s["classes"].items()},
                        "jaccard_nonempty": {c: v["jaccard_nonempty_mean"] for c, v in s["classes"].items()},
                        "ap_centroid": s["detection"]["ap_centroid"], "box_iou": s["detection"]["box_iou"],
                        "steps": s["steps"], "train_seconds": s["train_seconds"]}
        r = results[arm]
        print(f"skin loss {arm}: lesion {r['jaccard']['lesion']:.3f} skin {r['jaccard']['skin']:.3f} "
              f"non-skin {r['jaccard']['nonskin']:.3f} ({r['jaccard_nonempty']['nonskin']:.3f}) "
              f"AP_c {r['ap_centroid']:.3f} box IoU {r['box_iou']:.3f}; {r['steps']} steps in "
              f"{r['train_seconds']:.0f} s", flush=True)
    with open(os.path.join(a.out, "results.json"), "w") as f:
        json.dump(results, f, indent=1)


if __name__ == "__main__":
    main()
