"""Held-out evaluation folders in the Fitzpatrick17k layout, for machines without real
clinical images.

* ``procedural_clinical(out, n, seed)``: clinical-style close-ups. A procedural skin
  condition on its skin patch (``glsynth.assets.lesions.procedural_lesions``) fills an
  irregular body-part-shaped region of the frame (or the whole frame for a third of
  the images, as in many Fitzpatrick17k photographs); the rest is non-skin: a procedural
  indoor room or a clothing-like fabric. A smooth illumination gradient, a colour cast,
  sensor noise and JPEG compression are applied. ``lesions.png`` is the lesion mask,
  ``nonskin.png`` the region outside the skin.
* ``from_synthetic(dataset, out)``: a ``glsynth generate`` folder (made with another seed
  and other bodies than the training set) rewritten in the same layout: lesion =
  semantic 2, non-skin = semantic 0 or 3.

Neither is a substitute for real photographs: both come from glsynth's own generators,
so they measure fit to this domain, not transfer to real images.

``python -m glsynth.train.heldout procedural OUT -n 60 --seed 1000``
``python -m glsynth.train.heldout synthetic DATASET OUT``
"""
from __future__ import annotations

import argparse
import os

import cv2
import numpy as np

from ..assets.backgrounds import procedural_backgrounds
from ..assets.lesions import fractal_noise, procedural_lesions
from ..dataformat import SEMANTIC_BACKGROUND, SEMANTIC_LESION, SEMANTIC_NONSKIN, RunFolder
from ..io.images import write_bytes, write_png


def _write(folder, img, lesion, nonskin, quality=90):
    os.makedirs(folder, exist_ok=True)
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(img[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise RuntimeError(f"{folder}: JPEG encoding failed")
    write_bytes(os.path.join(folder, "image.jpg"), buf.tobytes())
    write_png(os.path.join(folder, "lesions.png"), lesion.astype(np.uint8) * 255)
    write_png(os.path.join(folder, "nonskin.png"), nonskin.astype(np.uint8) * 255)


def _skin_region(rng, h, w):
    """An irregular limb/torso-like region: a rotated ellipse with a noisy border."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    cx, cy = w * rng.uniform(0.4, 0.6), h * rng.uniform(0.4, 0.6)
    a, b = w * rng.uniform(0.45, 0.8), h * rng.uniform(0.3, 0.55)
    t = rng.uniform(0, np.pi)
    u = ((xx - cx) * np.cos(t) + (yy - cy) * np.sin(t)) / a
    v = (-(xx - cx) * np.sin(t) + (yy - cy) * np.cos(t)) / b
    r = u * u + v * v + 0.25 * fractal_noise(rng, (h, w), scale=h / 3, octaves=3)
    return r < 1.0


def _fabric(rng, h, w):
    base = rng.uniform(20, 230, 3)
    folds = fractal_noise(rng, (h, w), scale=h / 4, octaves=3)[..., None]
    weave = rng.normal(0, 4, (h, w, 1))
    return np.clip(base * (1 + 0.35 * folds) + weave, 0, 255).astype(np.uint8)


def procedural_clinical(out, n=60, seed=1000, size=384):
    """Write `n` clinical-style images (size x size) in the fitz17k layout under `out`."""
    lesions = procedural_lesions(n, seed=seed, size=256)
    rooms = procedural_backgrounds(max(1, n), seed=seed + 1, size=size)
    ids = []
    for i, les in enumerate(lesions):
        rng = np.random.default_rng([seed, i, 7])
        # the lesion patch covers the skin region; keep its mask aligned
        s = size / 256 * rng.uniform(1.0, 1.4)
        k = int(round(256 * s))
        patch = cv2.resize(les.image, (k, k), interpolation=cv2.INTER_LINEAR)
        pmask = cv2.resize(les.mask.astype(np.uint8), (k, k), interpolation=cv2.INTER_NEAREST) > 0
        ox, oy = (k - size) // 2, (k - size) // 2
        skin_img = patch[oy:oy + size, ox:ox + size]
        lesion = pmask[oy:oy + size, ox:ox + size].copy()
        if i % 3 == 0:
            region = np.ones((size, size), bool)
        else:
            region = _skin_region(rng, size, size) | lesion  # never cut the lesion
        bg = rooms[i % len(rooms)] if rng.random() < 0.5 else _fabric(rng, size, size)
        img = np.where(region[..., None], skin_img, bg).astype(np.float32)
        # soft edge at the skin border (a real photo's edge is not a hard cut)
        edge = cv2.GaussianBlur(img, (0, 0), 1.0)
        border = cv2.morphologyEx(region.astype(np.uint8), cv2.MORPH_GRADIENT, np.ones((3, 3))) > 0
        img[border] = edge[border]
        # light: a smooth gradient, a colour cast, noise
        yy, xx = np.mgrid[0:size, 0:size] / size
        ang = rng.uniform(0, 2 * np.pi)
        grad = 1 + rng.uniform(0.05, 0.3) * ((xx - 0.5) * np.cos(ang) + (yy - 0.5) * np.sin(ang))
        img = img * grad[..., None] * rng.uniform(0.85, 1.15, 3) * rng.uniform(0.8, 1.15)
        img = img + rng.normal(0, 2.0, img.shape)
        img = np.clip(np.rint(img), 0, 255).astype(np.uint8)
        sid = f"proc{i:04d}"
        _write(os.path.join(out, sid), img, lesion, ~region, quality=int(rng.integers(75, 95)))
        ids.append(sid)
    return ids


def from_synthetic(dataset, out):
    """Rewrite a glsynth dataset in the fitz17k layout (image.jpg, lesions.png, nonskin.png)."""
    run = RunFolder(dataset)
    ids = run.sample_ids()
    for sid in ids:
        sem = run.layer(sid, "semantic")
        nonskin = (sem == SEMANTIC_BACKGROUND) | (sem == SEMANTIC_NONSKIN)
        _write(os.path.join(out, sid), run.image(sid), sem == SEMANTIC_LESION, nonskin, quality=95)
    return ids


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m glsynth.train.heldout", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="kind", required=True)
    p = sub.add_parser("procedural")
    p.add_argument("out")
    p.add_argument("-n", type=int, default=60)
    p.add_argument("--seed", type=int, default=1000)
    p.add_argument("--size", type=int, default=384)
    p = sub.add_parser("synthetic")
    p.add_argument("dataset")
    p.add_argument("out")
    a = ap.parse_args(argv)
    ids = (procedural_clinical(a.out, a.n, a.seed, a.size) if a.kind == "procedural"
           else from_synthetic(a.dataset, a.out))
    print(f"wrote {len(ids)} folders to {a.out}")


if __name__ == "__main__":
    main()
