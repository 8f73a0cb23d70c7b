"""``glsynth assets --out DIR``: contact sheets of the built-in assets for a person to
check: bodies across the six Fitzpatrick types in several shapes and poses (front and
back), procedural skin conditions, procedural rooms."""
from __future__ import annotations

import os

import cv2
import numpy as np
from tqdm import tqdm

from ..io.images import write_png


def _label(img, text):
    out = img.copy()
    cv2.putText(out, text, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 2, cv2.LINE_AA)
    cv2.putText(out, text, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (20, 20, 20), 1, cv2.LINE_AA)
    return out


def body_sheet(path, seed=0, texture_size=1024, tile=(256, 384)):
    """Six bodies (Fitzpatrick I..VI, shapes and poses from the seed), front and back."""
    import glsynth as gs
    from .bodies import POSES, make_body
    poses = list(POSES)
    r = gs.Renderer(*tile)
    rows = []
    for fitz in tqdm(range(1, 7), desc="bodies", unit="body"):
        body = make_body(seed=seed + fitz, fitzpatrick=fitz, pose=poses[fitz % len(poses)],
                         texture_size=texture_size)
        lo, hi = body.mesh.bounds
        centre = (lo + hi) / 2
        tiles = []
        for side in (1.0, -1.0):
            eye = centre + np.array([0.0, 0.1, side * 4.2])
            cam = gs.Camera.look_at(eye, centre, width=tile[0], height=tile[1], fov_deg=30)
            light = gs.PointLight(eye + (0.8, 1.0, 0.0), ambient=0.45, diffuse=0.6, specular=0.03)
            out = r.render(body.mesh, cam, passes=("rgb",), lights=[light], supersample=2)
            bg = np.full(out["rgb"].shape, 0.93, np.float32)
            img = out["rgb"] * out["alpha"][..., None] + bg * (1 - out["alpha"][..., None])
            tiles.append((img * 255).astype(np.uint8))
        meta = body.meta
        text = f"type {fitz}, ITA {meta['ita']:.0f}, {meta.get('sex', '')}, {meta['pose']}"
        rows.append(_label(np.hstack(tiles), text))
    sheet = np.vstack([np.hstack(rows[i:i + 3]) for i in range(0, 6, 3)])
    write_png(path, sheet)
    return path


def lesion_sheet(path, seed=0, per_kind=6, tile=160):
    from .lesions import KINDS, procedural_lesions
    lesions = procedural_lesions(per_kind * len(KINDS), seed=seed)
    by_kind = {}
    for les in lesions:
        by_kind.setdefault(les.meta["kind"], []).append(les)
    rows = []
    for kind, items in by_kind.items():
        tiles = []
        for les in items[:per_kind]:
            img = cv2.resize(les.image, (tile, tile), interpolation=cv2.INTER_AREA)
            tiles.append(_label(img, f"{kind} F{les.meta.get('fitzpatrick')}"))
        rows.append(np.hstack(tiles))
    write_png(path, np.vstack(rows))
    return path


def background_sheet(path, seed=0, n=12, tile=192):
    from .backgrounds import procedural_backgrounds
    bgs = procedural_backgrounds(n, seed=seed, size=tile)
    tiles = [bgs.get(i, tile, tile) for i in range(n)]
    write_png(path, np.vstack([np.hstack(tiles[i:i + 6]) for i in range(0, n, 6)]))
    return path


def write_sheets(out, seed=0, texture_size=1024):
    os.makedirs(out, exist_ok=True)
    return [body_sheet(os.path.join(out, "bodies.png"), seed, texture_size),
            lesion_sheet(os.path.join(out, "lesions.png"), seed),
            background_sheet(os.path.join(out, "backgrounds.png"), seed)]


def register(sub):
    p = sub.add_parser("assets", help="contact sheets of the built-in bodies, lesions and rooms")
    p.add_argument("--out", required=True, help="folder for bodies.png, lesions.png, backgrounds.png")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--texture-size", type=int, default=1024)

    def run(args):
        for path in write_sheets(args.out, args.seed, args.texture_size):
            print(f"wrote {path}")
    p.set_defaults(fn=run)
