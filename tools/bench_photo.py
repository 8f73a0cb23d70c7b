"""Cost and look of the post-render camera model (glsynth/pipeline/photo.py).

    .venv/bin/python tools/bench_photo.py [--views 4] [--repeats 7] [--sheet docs/photo_sheet.png]

1. Renders a few 512x512 views of a built-in body (default config, camera model off)
   and keeps their composites and depth maps.
2. Cost per sample (median over ``--repeats`` runs and the views) of each effect alone
   at the top of its default range, of all of them together, and of parameters drawn
   from the default ranges as ``glsynth generate`` does.
3. A contact sheet: the centre 256x256 of one view, one row per effect (and one with
   all of them), columns at 0, 0.5, 1, 2 and 4 times the top of the default range.
"""
from __future__ import annotations

import argparse
import copy
import os
import statistics
import tempfile
import time

import cv2
import numpy as np

from glsynth.config import load_config
from glsynth.io.images import read_rgb
from glsynth.pipeline import photo
from glsynth.pipeline.seeding import rng_for
from glsynth.pipeline import generate

# effect -> (config key, sampled params key) for the "one effect at strength t" rows
KEYS = {"defocus": "aperture", "motion_blur": "motion_blur", "chromatic_aberration": "chromatic_aberration",
        "vignetting": "vignetting", "exposure": "exposure", "noise": ("shot_noise", "read_noise"),
        "white_balance": ("white_balance", "tint"), "tone": ("contrast", "saturation"),
        "watermark": "watermark", "jpeg": "jpeg_quality"}


def _scaled(pc, effects, t):
    """A PhotoConfig with only ``effects`` on, each at t x the top of its default range
    (JPEG: quality 100 - t * (100 - lowest default quality); the watermark: on every
    image)."""
    out = copy.deepcopy(pc)
    for name, keys in KEYS.items():
        for key in (keys if isinstance(keys, tuple) else (keys,)):
            if key == "watermark":                        # a share of images, not a strength
                out.watermark = 1.0 if name in effects and t > 0 else 0.0
                continue
            lo, hi = getattr(pc, key)
            if name not in effects or t == 0:
                setattr(out, key, [0, 0])
            elif key == "jpeg_quality":
                q = int(round(max(1, 100 - t * (100 - lo))))
                setattr(out, key, [q, q])
            else:
                top = hi if abs(hi) >= abs(lo) else lo
                v = min(top * t, 1.0) if key in ("contrast", "saturation") else top * t  # S curve: c <= 1
                setattr(out, key, [v, v])
    out.focus_jitter = 0.0
    out.enabled = True
    return out


def _params(pc, view, seed=0):
    return photo.sample_params(pc, rng_for(seed, "bench", view["id"]), view["focus"], view["focal"])


def _time(fn, repeats):
    fn()
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return ts


def _label(tile, text):
    cv2.putText(tile, text, (6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(tile, text, (6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return tile


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--sheet", default="docs/photo_sheet.png")
    ap.add_argument("--sheet-view", type=int, default=None, help="index of the view on the sheet")
    ap.add_argument("--out", default=None, help="reuse/keep the rendered views here")
    args = ap.parse_args(argv)

    out = args.out or tempfile.mkdtemp(prefix="glsynth-photo-")
    cfg = load_config(None, ["bodies.count=1", f"views.per_body={args.views}", "lesions.per_body=2",
                             "blend.method=poisson", "photo.enabled=false", "views.min_lesion=0.01",
                             "views.lesion_bias=1.0", "outputs=[rgb, depth]"])
    if not os.path.isdir(os.path.join(out, "images")):
        generate(cfg, out)
    import json
    import tifffile
    views = []
    for f in sorted(os.listdir(os.path.join(out, "images"))):
        sid = f[:-4]
        meta = json.load(open(os.path.join(out, "targets", f"{sid}.json")))
        views.append({"id": sid, "image": read_rgb(os.path.join(out, "images", f)),
                      "depth": tifffile.imread(os.path.join(out, "targets", f"{sid}_depth.tiff")),
                      "focus": float(np.linalg.norm(np.subtract(meta["camera"]["target"],
                                                                meta["camera"]["eye"]))),
                      "focal": float(np.array(meta["camera"]["intrinsics"])[1, 1])})
    h, w = views[0]["image"].shape[:2]
    pc = load_config().photo
    print(f"## Camera model cost per {w}x{h} sample (median of {args.repeats} runs x {len(views)} views)\n")
    print("| effect | ms / sample |")
    print("|---|---:|")
    rows = [(name, [name]) for name in KEYS] + [("all together (top of each range)", list(KEYS))]
    for name, effects in rows:
        spc = _scaled(pc, effects, 1.0)
        ts = []
        for v in views:
            p = _params(spc, v)
            ts += _time(lambda: photo.apply(v["image"], p, v["depth"]), args.repeats)
        print(f"| {name} | {statistics.median(ts) * 1e3:.1f} |")
    ts = []
    for v in views:
        for k in range(args.repeats):
            p = _params(pc, v, seed=k)
            t0 = time.perf_counter()
            photo.apply(v["image"], p, v["depth"])
            ts.append(time.perf_counter() - t0)
    print(f"| all, drawn from configs/default.yaml | {statistics.median(ts) * 1e3:.1f} |")

    # contact sheet
    vi = args.sheet_view if args.sheet_view is not None else int(
        np.argmax([(v["depth"] > 0).mean() * (v["depth"] <= 0).mean() for v in views]))
    v = views[vi]
    # the crop: midway between the centre (the lesion) and the nearest silhouette pixel,
    # so that skin, the body's edge and the background (defocus) are all in it
    body = (v["depth"] > 0).astype(np.uint8)
    edge = np.argwhere(body != cv2.erode(body, np.ones((3, 3), np.uint8)))
    cy, cx = h // 2, w // 2
    if len(edge):
        ey, ex = edge[np.argmin(((edge - [h // 2, w // 2]) ** 2).sum(1))]
        cy, cx = (cy + ey) // 2, (cx + ex) // 2
    c0, c1 = int(np.clip(cy - 128, 0, h - 256)), int(np.clip(cx - 128, 0, w - 256))
    strengths = (0.0, 0.5, 1.0, 2.0, 4.0)
    sheet_rows = []
    for name, effects in rows[:-1] + [("all", list(KEYS))]:
        tiles = []
        for t in strengths:
            img = photo.apply(v["image"], _params(_scaled(pc, effects, t), v), v["depth"])
            tiles.append(_label(np.ascontiguousarray(img[c0:c0 + 256, c1:c1 + 256]).copy(), f"{name} x{t:g}"))
        sheet_rows.append(np.concatenate(tiles, 1))
    sheet = np.concatenate(sheet_rows, 0)
    os.makedirs(os.path.dirname(os.path.abspath(args.sheet)), exist_ok=True)
    cv2.imwrite(args.sheet, sheet[..., ::-1])
    # the same view, full frame: clean and three draws from the default ranges
    full = [v["image"]] + [photo.apply(v["image"], _params(pc, v, seed=s), v["depth"]) for s in range(3)]
    full = [_label(f.copy(), t) for f, t in zip(full, ("clean", "default draw 1", "default draw 2",
                                                        "default draw 3"))]
    base, ext = os.path.splitext(args.sheet)
    cv2.imwrite(f"{base}_defaults{ext}", np.concatenate(full, 1)[..., ::-1])
    print(f"\ncontact sheet: {args.sheet} (view {v['id']}), defaults: {base}_defaults{ext}")


if __name__ == "__main__":
    main()
