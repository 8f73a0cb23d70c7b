"""The paper's real-vs-synthetic training comparison on a small real set, two-fold.

    .venv/bin/python tools/twofold.py --real ../shared/realdev/fitz17k --synthetic RUN/model.pt \
        --data RUN/data/part000 --data RUN/data/part001 ... --out /tmp/twofold [--steps 600]

The real images (Fitzpatrick17k layout) are split in two halves by their sorted ids (the
even ones and the odd ones; the split is made with symbolic links under --out, the
images are not copied). For each half, models learn from the other half and are scored
on this one; the report pools the 2 x 7 per-image scores:

* real only: the network trained from scratch on the other half's images;
* synthetic only: ``--synthetic`` (e.g. a sim2real checkpoint), no real image;
* synthetic, then real: ``--synthetic`` fine-tuned on the other half (staged);
* mixed: trained from scratch on the synthetic ``--data`` with a quarter of every batch
  from the other half's real images.

Writes ``report.md`` and ``results.json`` in --out.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil

import numpy as np


def split(real, out):
    """Two folders of symbolic links to the real image folders: even and odd ids."""
    ids = sorted(d for d in os.listdir(real) if os.path.isdir(os.path.join(real, d)))
    folds = {}
    for k, name in enumerate(("even", "odd")):
        folder = os.path.join(out, "folds", name)
        os.makedirs(folder, exist_ok=True)
        for sid in ids[k::2]:   # a folder per image of links to its files (the readers
            src = os.path.abspath(os.path.join(real, sid))   # walk no linked folder)
            os.makedirs(os.path.join(folder, sid), exist_ok=True)
            for f in os.listdir(src):
                link = os.path.join(folder, sid, f)
                if not os.path.lexists(link):
                    os.symlink(os.path.join(src, f), link)
        for f in os.listdir(real):                      # the metadata CSV, if any
            if f.endswith(".csv") and not os.path.lexists(os.path.join(folder, f)):
                os.symlink(os.path.abspath(os.path.join(real, f)), os.path.join(folder, f))
        folds[name] = folder
    return folds


def main():
    from glsynth.train.evaluate import evaluate
    from glsynth.train.trainer import train
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--real", required=True)
    ap.add_argument("--synthetic", required=True, help="a checkpoint trained on synthetic data")
    ap.add_argument("--data", action="append", required=True, help="synthetic datasets (mixed)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--steps", type=int, default=600, help="steps for real-only and fine-tuning")
    ap.add_argument("--mixed-steps", type=int, default=2000)
    ap.add_argument("--size", type=int, default=256)
    a = ap.parse_args()
    folds = split(a.real, a.out)
    scores = {k: [] for k in ("real only", "synthetic only", "synthetic, then real", "mixed")}
    for test, trainset in (("even", "odd"), ("odd", "even")):
        work = os.path.join(a.out, test)
        if os.path.isdir(work):
            shutil.rmtree(work)
        os.makedirs(work)
        train([], os.path.join(work, "real.pt"), size=a.size, steps=a.steps, lr=2e-3,
              real_train=folds[trainset], progress=False, save_every=0)
        train([], os.path.join(work, "staged.pt"), size=a.size, steps=a.steps, lr=5e-4,
              init=a.synthetic, real_train=folds[trainset], progress=False, save_every=0)
        train(a.data, os.path.join(work, "mixed.pt"), size=a.size, steps=a.mixed_steps,
              real_train=folds[trainset], real_ratio=0.25, progress=False, save_every=0)
        models = {"real only": os.path.join(work, "real.pt"), "synthetic only": a.synthetic,
                  "synthetic, then real": os.path.join(work, "staged.pt"),
                  "mixed": os.path.join(work, "mixed.pt")}
        for name, model in models.items():
            report_dir = os.path.join(work, name.replace(", ", "_").replace(" ", "_"))
            evaluate(model, folds[test], "fitz17k", report_dir, progress=False)
            scores[name] += list(csv_rows(os.path.join(report_dir, "per_image.csv")))
    report = {name: {c: float(np.mean([float(r[f"{c}_jaccard"]) for r in rows]))
                     for c in ("lesion", "skin", "nonskin")} | {
                         "nonskin_nonempty": float(np.mean([float(r["nonskin_jaccard"]) for r in rows
                                                            if int(r["nonskin_truth_px"]) > 0])),
                         "n": len(rows)}
              for name, rows in scores.items()}
    with open(os.path.join(a.out, "results.json"), "w") as fh:
        json.dump(report, fh, indent=1)
    lines = ["| training | lesion | skin | non-skin | non-skin (non-empty truth) | images |",
             "|---|---|---|---|---|---|"]
    for name, r in report.items():
        lines.append(f"| {name} | {r['lesion']:.3f} | {r['skin']:.3f} | {r['nonskin']:.3f} | "
                     f"{r['nonskin_nonempty']:.3f} | {r['n']} |")
    with open(os.path.join(a.out, "report.md"), "w") as fh:
        fh.write("\n".join(lines) + "\n")
    print("\n".join(lines))


def csv_rows(path):
    import csv
    with open(path, newline="") as fh:
        yield from csv.DictReader(fh)


if __name__ == "__main__":
    main()
