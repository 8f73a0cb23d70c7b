"""How real photographs and glsynth views frame a lesion: its share of the frame, and how
often it runs off the frame's edge.

    .venv/bin/python tools/framing_stats.py --real ../shared/realdev/fitz17k DATASET [DATASET ...]

For the real folder (fitz17k layout, read as ``glsynth evaluate`` reads it) and for each
glsynth dataset, all views and by framing (``camera.framing`` in the per-view JSON):
quantiles of the lesion's share of the frame, the share of images where the lesion covers
more than 30% of it, and the share where the lesion touches the frame's border (a large
eruption photographed in part).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from dataset_views import views_by_framing
from glsynth.dataformat import SEMANTIC_LESION
from glsynth.train.evaluate import CLASSES, read_real

QUANTILES = (0.1, 0.25, 0.5, 0.75, 0.9)


def _row(lesion: np.ndarray):
    """(lesion share of the frame, whether it touches the frame's border)."""
    edge = lesion[0].any() or lesion[-1].any() or lesion[:, 0].any() or lesion[:, -1].any()
    return float(lesion.mean()), bool(edge)


def real_rows(folder: Path):
    return [_row(truth == CLASSES.index("lesion")) for _, _, truth in read_real(folder, "fitz17k")]


def dataset_rows(folder: Path):
    by_kind = {}
    for kind, run, sid in views_by_framing(folder):
        row = _row(run.layer(sid, "semantic") == SEMANTIC_LESION)
        by_kind.setdefault(kind, []).append(row)
        by_kind.setdefault("all", []).append(row)
    return by_kind


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--real", type=Path, required=True)
    ap.add_argument("datasets", type=Path, nargs="+")
    args = ap.parse_args()
    print("| images | n | lesion share " + " / ".join(f"p{round(q * 100)}" for q in QUANTILES)
          + " | share > 0.3 | touches the edge |\n|---|---:|---|---:|---:|")
    groups = [(f"real ({args.real})", real_rows(args.real))]
    for d in args.datasets:
        groups += [(f"{d} {kind}", rows) for kind, rows in sorted(dataset_rows(d).items())]
    for name, rows in groups:
        share, edge = np.array(rows, float).T
        qs = " / ".join(f"{x:.3f}" for x in np.quantile(share, QUANTILES))
        print(f"| {name} | {len(rows)} | {qs} | {np.mean(share > 0.3):.2f} | {np.mean(edge):.2f} |")


if __name__ == "__main__":
    main()
