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


def condition_patch(fields, fitzpatrick, rng, texture_size=256):
    """A flat square of skin (a Mesh, metres, facing +Z) of a Fitzpatrick type, with the
    condition ``fields`` (morphology.LesionFields) over it as a decal at the grid's own
    resolution, and skin micro-detail (relief, pores, vellus hair)."""
    import glsynth as gs
    from ..mesh import SkinSurface, grid_faces
    from ..pipeline.decals import Decals, encode_aux, projection_rows
    from .detail import lipid_codes
    from .lesions import reference_skin
    from .morphology import apply_to_skin
    half = fields.extent_mm / 2000.0
    n = 16
    xs = np.linspace(-half, half, n)
    xx, yy = np.meshgrid(xs, xs)
    v = np.stack([xx.ravel(), yy.ravel(), np.zeros(n * n)], 1)
    f = grid_faces(n)
    uv = (v[:, :2] + half) / (2 * half)
    size = fields.size
    skin = reference_skin(fitzpatrick, size, rng)
    texture = cv2.resize(skin, (texture_size, texture_size), interpolation=cv2.INTER_AREA)
    colour = np.empty((size, size, 4), np.uint8)
    colour[..., :3] = apply_to_skin(fields, skin)
    colour[..., 3] = 255
    gy, gx = np.gradient(fields.f["height"] / fields.mm_per_px)          # slope, mm per mm
    aux = encode_aux(gx, gy, fields.f["gloss"], fields.f["detail"])
    fov = 30.0
    cam = gs.Camera.look_at((0, 0, half / np.tan(np.radians(fov) / 2)), (0, 0, 0), up=(0, 1, 0),
                            fov_deg=fov, width=size, height=size)
    view = cam.view_matrix()
    decals = Decals(np.ones((8, 8), np.uint16), projection_rows(cam)[None],
                    np.stack([view[0, :3], -view[1, :3]])[None], np.array([2 * half / size]),
                    colour[None], aux[None], fields.instances[None])
    params = np.zeros((8, 8, 4), np.uint8)
    params[:] = (150, 90, 64, lipid_codes(110 / 255, 0.0))
    hair = v[f][..., :2].astype(np.float32)
    return gs.Mesh(v, f, uvs=uv, texture=texture, name="condition-patch",
                   skin=SkinSurface(params, None, hair, (60, 45, 35)), decals=decals)


def lesion_atlas(folder, seed=0, tile=224, resolution=384):
    """One sheet per preset: the condition on the six Fitzpatrick types (columns) under
    a phone flash and under an oblique room light (rows), rendered as the views are
    (skin shading, relief, micro-detail, decals), the outline drawn on the first."""
    import glsynth as gs
    from ..config import ViewsConfig
    from .morphology import PRESETS, make_condition
    os.makedirs(folder, exist_ok=True)
    r = gs.Renderer(tile, tile)
    # the skin's gloss in the middle of what views draw (a glossier atlas showed flat
    # lesions washed white by the flash, which views seldom do)
    views = ViewsConfig()
    material = gs.Material(model="skin", roughness=float(np.mean(views.roughness)), oil=float(np.mean(views.oil)))
    paths = []
    for preset in tqdm(PRESETS, desc="lesion atlas", unit="preset"):
        fields = make_condition(preset, [seed, 1], size=resolution)
        rows = [[], []]
        for fitz in range(1, 7):
            mesh = condition_patch(fields, fitz, np.random.default_rng([seed, fitz]))
            half = fields.extent_mm / 2000.0
            cam = gs.Camera.look_at((0.05 * half, -0.1 * half, 1.1 * half / np.tan(np.radians(15))),
                                    (0, 0, 0), up=(0, 1, 0), fov_deg=30, width=tile, height=tile)
            eye = np.asarray(cam.eye)
            for row, lights in enumerate((
                    [gs.PointLight(eye, ambient=0.15, diffuse=0.9)],
                    [gs.PointLight(eye + np.array([2.0, 1.5, -0.5]) * np.linalg.norm(eye), ambient=0.3,
                                   diffuse=1.0)])):
                out = r.render(mesh, cam, passes=("rgb", "labels"), label_textures={"instances":
                               np.zeros((8, 8), np.uint16)}, decal_labels="instances", lights=lights,
                               material=material,
                               multisample=4)
                img = (np.clip(out["rgb"], 0, 1) * 255).astype(np.uint8)
                if row == 0 and fitz == 1:
                    edge = cv2.morphologyEx((out["instances"] > 0).astype(np.uint8), cv2.MORPH_GRADIENT,
                                            np.ones((3, 3), np.uint8)) > 0
                    img[edge] = (40, 255, 40)
                rows[row].append(_label(img, f"F{fitz}" + (" flash" if row == 0 else " room")))
        sheet = _label(np.vstack([np.hstack(rw) for rw in rows]),
                       f"{preset}: {fields.params.get('extent_mm')} mm")
        path = os.path.join(folder, f"{preset}.png")
        write_png(path, sheet)
        paths.append(path)
    return paths


def lesion_sheet(path, seed=0, per_kind=6, tile=160):
    from .lesions import KINDS, procedural_lesions
    lesions = procedural_lesions(per_kind * len(KINDS), seed=seed, size=192)
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


def closeup_sheet(path, data, real=None, n=12, tile=224):
    """Close-ups of a glsynth dataset (``data``: a ``glsynth generate`` folder) beside
    real clinical photographs (``real``: a folder in the Fitzpatrick17k or pairs layout,
    the user's own; read, never copied), alternating, for a person to compare."""
    from ..dataformat import RunFolder, image_path
    from ..io.images import read_rgb
    run = RunFolder(data)
    synth = [image_path(run.root, sid) for sid in run.sample_ids()
             if run.record(sid)["camera"].get("framing") == "closeup"][:n]
    photos = []
    if real is not None:
        from .lesions import load_lesions
        for layout in ("fitz17k", "pairs"):
            try:
                photos = [e.image_path for e in load_lesions(real, layout=layout, lazy=True).entries][:n]
                break
            except Exception:  # noqa: BLE001 - try the other layout
                continue
    def square(img):
        h, w = img.shape[:2]
        c = min(h, w)
        y0, x0 = (h - c) // 2, (w - c) // 2
        return cv2.resize(img[y0:y0 + c, x0:x0 + c], (tile, tile), interpolation=cv2.INTER_AREA)
    tiles = []
    for i in range(max(len(synth), len(photos))):
        if i < len(synth):
            tiles.append(_label(square(read_rgb(synth[i])), "glsynth"))
        if i < len(photos):
            tiles.append(_label(square(read_rgb(photos[i])), "real"))
    if not tiles:
        raise FileNotFoundError(f"{data}: no close-up views (views.framing has no closeup?)")
    cols = 6
    tiles += [np.full_like(tiles[0], 255)] * (-len(tiles) % cols)
    write_png(path, np.vstack([np.hstack(tiles[i:i + cols]) for i in range(0, len(tiles), cols)]))
    return path


def write_sheets(out, seed=0, texture_size=1024):
    os.makedirs(out, exist_ok=True)
    return [body_sheet(os.path.join(out, "bodies.png"), seed, texture_size),
            lesion_sheet(os.path.join(out, "lesions.png"), seed),
            background_sheet(os.path.join(out, "backgrounds.png"), seed),
            *lesion_atlas(os.path.join(out, "lesion_atlas"), seed)]


def register(sub):
    p = sub.add_parser("assets", help="contact sheets of the built-in bodies, lesions, lesion "
                                      "atlas and backgrounds, and close-ups beside real photographs")
    p.add_argument("--out", required=True, help="folder for bodies.png, lesions.png, backgrounds.png, "
                                               "lesion_atlas/, closeups.png")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--texture-size", type=int, default=1024)
    p.add_argument("--data", default=None, help="a glsynth dataset whose close-ups closeups.png shows "
                                                "(default: a small one made with the embedded config)")
    p.add_argument("--real", default=None, help="real photographs (fitz17k or pairs layout) to show "
                                                "beside the close-ups")

    def run(args):
        for path in write_sheets(args.out, args.seed, args.texture_size):
            print(f"wrote {path}")
        data = args.data
        if data is None:
            from ..config import load_config
            from ..pipeline import generate
            data = os.path.join(args.out, "closeup_data")
            if not os.path.isdir(os.path.join(data, "images")):
                generate(load_config(None, [f"seed={args.seed}", "views.per_body=16",
                                            "views.framing={closeup: 1}"]), data)
        print(f"wrote {closeup_sheet(os.path.join(args.out, 'closeups.png'), data, args.real)}")
    p.set_defaults(fn=run)
