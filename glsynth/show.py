"""``glsynth show``: a contact sheet like the paper's annotation overview (rows: image,
boxes, semantic, anatomy groups, depth) for a person to look at."""
from __future__ import annotations

import os

import cv2
import numpy as np

from .dataformat import GROUP_PALETTE, SEMANTIC_PALETTE, group_labels
from .dataset import SynthDataset
from .io.images import write_png


def contact_sheet(root, out_png, n=6, tile=256):
    ds = SynthDataset(root, targets=("semantic", "anatomy", "depth"))
    if len(ds) == 0:
        raise FileNotFoundError(f"{root}: no samples")
    idx = np.linspace(0, len(ds) - 1, min(n, len(ds))).round().astype(int)
    cols = []
    for i in idx:
        item = ds[int(i)]
        img = (item["image"].numpy().transpose(1, 2, 0) * 255).astype(np.uint8)
        boxed = img.copy()
        for l in item["meta"]["lesions"]:
            x0, y0, x1, y1 = l["box"]
            cv2.rectangle(boxed, (x0, y0), (x1 - 1, y1 - 1), (255, 255, 0), 2)
        for nv in item["meta"].get("nevi", []):
            x0, y0, x1, y1 = nv["box"]
            cv2.rectangle(boxed, (x0, y0), (x1 - 1, y1 - 1), (0, 255, 255), 1)
        sem = SEMANTIC_PALETTE[item["semantic"].numpy()]
        ana = GROUP_PALETTE[group_labels(item["anatomy"].numpy())]
        d = item["depth"].numpy()
        body = d > 0
        dep = np.zeros(d.shape + (3,), np.uint8)
        if body.any():
            lo, hi = d[body].min(), d[body].max()
            norm = 1 - (d - lo) / max(hi - lo, 1e-6)
            dep = cv2.applyColorMap((norm * 255).astype(np.uint8), cv2.COLORMAP_VIRIDIS)[..., ::-1]
            dep[~body] = 0
        col = [cv2.resize(x, (tile, tile), interpolation=cv2.INTER_NEAREST if x is not img else cv2.INTER_AREA)
               for x in (img, boxed, sem, ana, dep)]
        cols.append(np.vstack(col))
    sheet = np.hstack(cols)
    write_png(out_png, sheet)
    return os.fspath(out_png)
