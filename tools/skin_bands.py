"""How much healthy skin varies in lightness and colour at two scales, real against ours.

    .venv/bin/python tools/skin_bands.py --real ../shared/realdev/fitz17k DATASET [DATASET ...]

Each image is scaled to 512 px on its longer side; over its healthy skin (skin label,
eroded by 6 px, so lesion borders and silhouettes stay out), L*, a* and b* are smoothed
with mask-normalised Gaussians of sigma 3, 12 and 48 px, and the standard deviation of the
differences 3-12 px ("fine": 0.3-1.2 mm in a 5 cm close-up) and 12-48 px ("coarse":
1.2-5 mm) is taken. Prints the median over images of each, for the real folder (fitz17k
layout, read as ``glsynth evaluate`` reads it) and for each glsynth dataset by
framing (``camera.framing`` in the per-view JSON).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from dataset_views import views_by_framing
from glsynth.dataformat import SEMANTIC_SKIN
from glsynth.train.evaluate import CLASSES, read_real


def _blur(x, m, sigma):
    return cv2.GaussianBlur(x * m, (0, 0), sigma) / np.maximum(cv2.GaussianBlur(m, (0, 0), sigma), 1e-6)


def band_stats(rgb, skin):
    """(L fine, L coarse, a fine, a coarse, b fine, b coarse), or None with too little skin."""
    h, w = skin.shape
    k = 512 / max(h, w)
    size = (round(w * k), round(h * k))
    img = cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)
    skin = cv2.resize(skin.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST)
    m = cv2.erode(skin, np.ones((13, 13), np.uint8)).astype(np.float32)
    if m.sum() < 2000:
        return None
    lab = cv2.cvtColor(img.astype(np.float32) / 255, cv2.COLOR_RGB2LAB)
    sel = m > 0
    out = []
    for c in range(3):
        b3, b12, b48 = (_blur(lab[..., c], m, s) for s in (3, 12, 48))
        out += [float(np.std((b3 - b12)[sel])), float(np.std((b12 - b48)[sel]))]
    return out


def real_rows(folder: Path):
    rows = []
    for _, rgb, truth in read_real(folder, "fitz17k"):
        r = band_stats(rgb, truth == CLASSES.index("skin"))
        if r:
            rows.append(r)
    return rows


def dataset_rows(folder: Path):
    by_kind = {}
    for kind, run, sid in views_by_framing(folder):
        r = band_stats(run.image(sid), run.layer(sid, "semantic") == SEMANTIC_SKIN)
        if r:
            by_kind.setdefault(kind, []).append(r)
    return by_kind


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--real", type=Path, required=True)
    ap.add_argument("datasets", type=Path, nargs="+")
    args = ap.parse_args()
    print("| images | n | L* fine | L* coarse | a* fine | a* coarse | b* fine | b* coarse |\n|---|---:|"
          + "---:|" * 6)
    groups = [(f"real ({args.real})", real_rows(args.real))]
    for d in args.datasets:
        groups += [(f"{d} {kind}", rows) for kind, rows in sorted(dataset_rows(d).items())]
    for name, rows in groups:
        if rows:
            med = np.median(np.array(rows), 0)
            print(f"| {name} | {len(rows)} | " + " | ".join(f"{x:.2f}" for x in med) + " |")


if __name__ == "__main__":
    main()
