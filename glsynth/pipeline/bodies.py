"""Which bodies a run uses: built-in anny bodies or a folder of scans, plus the
texel geometry (which surface point each texel shows) that pasting needs."""
from __future__ import annotations

import hashlib
import json
import logging
import math
import os
from dataclasses import dataclass

import numpy as np

from ..config import Config
from .seeding import rng_for

log = logging.getLogger(__name__)


def body_ids(cfg: Config) -> list[str]:
    """The run's bodies, from the ``bodies.first``-th on: built-in body names, or scan
    folders in an order that spreads over skin tone (:func:`skin_tone_order`), so that
    any run or shard of ``bodies.count`` scans spans the range; a shard's scans are
    those of the whole run. Scan ids come sorted by name."""
    first, count = cfg.bodies.first, cfg.bodies.count
    if cfg.bodies.source == "builtin":
        return [f"body{i:03d}" for i in range(first, first + count)]
    folders = scan_folders(cfg.bodies.source)
    if first >= len(folders):
        raise FileNotFoundError(f"bodies.source {cfg.bodies.source!r}: bodies.first is {first}, "
                                f"but it holds {len(folders)} scan folders")
    if first + count >= len(folders) and first == 0:
        return [os.path.basename(f) for f in folders]   # all: no skin tones to measure
    return sorted(skin_tone_order(folders)[first:first + count])


def skin_tone_order(folders) -> list[str]:
    """Scan ids ordered so that every prefix spreads over skin tone: the lightest, the
    darkest, then each time the scan whose skin tone rank lies farthest from those
    taken (the paper chose its 50 of 3DBodyTex's scans "to cover a wider range of skin
    tones", measured as ITA over the skin, ``scan_ita``). Scans without skin texels rank
    after the others."""
    tone = {os.path.basename(f): scan_ita(f) for f in folders}
    ranked = sorted(tone, key=lambda name: (math.inf if tone[name] is None else tone[name], name))
    n = len(ranked)
    taken = [0] + ([n - 1] if n > 1 else [])
    gap = np.abs(np.arange(n)[:, None] - np.array(taken)[None]).min(1)
    while len(taken) < n:
        k = int(np.argmax(gap))                            # ties: the lighter
        taken.append(k)
        gap = np.minimum(gap, np.abs(np.arange(n) - k))
    log.info("bodies: scans in skin tone order (ITA): %s",
             ", ".join(f"{ranked[k]} {tone[ranked[k]]}" for k in taken[:8]))
    return [ranked[k] for k in taken]


def scan_ita(folder) -> float | None:
    """Median skin ITA of a scan folder (``meta["ita"]`` of its body), cached on disk
    (``glsynth.assets.bodies.cache_root``) by the files' names, sizes and times."""
    from ..assets.bodies import cache_root
    from ..assets.bodytex import load_bodytex
    from ..io.images import write_text
    files = [os.path.join(folder, n) for n in sorted(os.listdir(folder))]
    stat = [(os.path.basename(f), os.stat(f).st_size, os.stat(f).st_mtime_ns) for f in files
            if os.path.isfile(f)]
    key = hashlib.sha256(json.dumps(["median skin ITA 1", os.path.abspath(folder), stat]).encode())
    key = key.hexdigest()[:24]
    path = cache_root() / "scan-ita" / f"{key}.json"
    if path.is_file():
        with open(path) as fh:
            return json.load(fh)["ita"]
    ita = load_bodytex(folder).meta["ita"]
    try:
        os.makedirs(path.parent, exist_ok=True)
        write_text(str(path), json.dumps({"folder": os.path.abspath(folder), "ita": ita}))
    except OSError as exc:
        log.warning("could not cache the skin tone of %s at %s: %s", folder, path, exc)
    return ita


def scan_folders(root) -> list[str]:
    if not os.path.isdir(root):
        raise FileNotFoundError(f"bodies.source {root!r}: folder not found")
    found = sorted(os.path.join(root, d) for d in os.listdir(root)
                   if os.path.isdir(os.path.join(root, d)))
    if not found:
        raise FileNotFoundError(f"bodies.source {root!r}: no scan folders inside")
    return found


def load_body(cfg: Config, body_id: str):
    """The Body for ``body_id`` (built-in bodies are cached on disk by glsynth.assets)."""
    from .. import assets
    if cfg.bodies.source == "builtin":
        index = int(body_id[4:])
        rng = rng_for(cfg.seed, "body", index)
        lo, hi = cfg.bodies.fitzpatrick
        return assets.make_body(seed=int(rng.integers(0, 2**31 - 1)),
                                fitzpatrick=int(rng.integers(lo, hi + 1)),
                                pose=str(rng.choice(cfg.bodies.poses)),
                                texture_size=cfg.bodies.texture_size)
    folder = os.path.join(cfg.bodies.source, body_id)
    body = assets.load_bodytex(folder)
    check_scale(body.mesh.vertices, folder)
    return body


# A person, in metres (the unit of paste.w, views.w and depth): from a small child to
# well above the tallest adult, with room for a scan's props.
PERSON_SIZE_M = (0.2, 4.0)
_UNITS = {"millimetres": 1e-3, "centimetres": 1e-2, "inches": 0.0254, "feet": 0.3048,
          "kilometres": 1e3}


def check_scale(vertices, name):
    """BodyError unless the mesh's largest extent is a person's size in metres; the
    message guesses the unit the mesh is in."""
    from ..assets.bodytex import BodyError
    extent = float(np.ptp(np.asarray(vertices), axis=0).max())
    lo, hi = PERSON_SIZE_M
    if lo <= extent <= hi:
        return
    guess = ""
    if extent > 0:
        unit = min(_UNITS, key=lambda u: abs(np.log(extent * _UNITS[u] / 1.7)))
        guess = f"; it looks like {unit}: scale its vertices by {_UNITS[unit]:g}"
    raise BodyError(f"{name}: the body is {extent:.4g} units across, but glsynth works in metres "
                    f"(a person is {lo}-{hi} m; paste.w and views.w are metres too){guess}")


@dataclass
class TexelGeometry:
    """For every texel covered by a face: its face, 3D position and unit normal."""

    rows: np.ndarray      # (N,) texel rows (row 0 = v 1)
    cols: np.ndarray
    faces: np.ndarray     # (N,) face index
    points: np.ndarray    # (N, 3) float64
    normals: np.ndarray   # (N, 3) float64
    covered: np.ndarray   # (H, W) bool

    @classmethod
    def of(cls, renderer, mesh, only=None, box=None):
        """Geometry of every covered texel, or only of those where ``only`` (bool HxW);
        ``box`` (x0, y0, x1, y1) limits the work to a window of texels (``covered``
        is then False outside it)."""
        h, w = mesh.texture.shape[:2]
        raster = renderer.render_uv_space(mesh, w, h, box=box)
        x0, y0 = (0, 0) if box is None else (max(int(box[0]), 0), max(int(box[1]), 0))
        wh, ww = raster["face_id"].shape
        covered = np.zeros((h, w), bool)
        window = covered[y0:y0 + wh, x0:x0 + ww]
        window[...] = raster["face_id"] >= 0
        r, c = np.nonzero(window if only is None else window & only[y0:y0 + wh, x0:x0 + ww])
        faces = raster["face_id"][r, c]
        bary = raster["bary"][r, c].astype(np.float64)
        rows, cols = r + y0, c + x0
        corners = mesh.faces[faces]
        points = np.einsum("nk,nkj->nj", bary, mesh.vertices[corners])
        normals = np.einsum("nk,nkj->nj", bary, mesh.vertex_normals[corners])
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
        return cls(rows, cols, faces, points, normals, covered)

    @classmethod
    def of_body(cls, renderer, mesh):
        """``of(renderer, mesh)`` for all texels, kept for the last body seen (by its
        geometry, UVs and texture size): a worker pastes a body, then blends it and
        builds its decals, and each needs the same ~2 s of texel geometry."""
        h = hashlib.sha1()
        for a in (mesh.vertices, mesh.faces, mesh.uvs, mesh.face_uvs):
            h.update(np.ascontiguousarray(a).tobytes())
        key = (mesh.texture.shape[:2], h.hexdigest())
        if _LAST_BODY_TEXELS.get("key") != key:
            _LAST_BODY_TEXELS.clear()      # one body's (~0.2 GB) at a time
            _LAST_BODY_TEXELS.update(key=key, texels=cls.of(renderer, mesh))
        return _LAST_BODY_TEXELS["texels"]

    @staticmethod
    def forget():
        """Drop the body kept by ``of_body`` (once its blend and decals are done)."""
        _LAST_BODY_TEXELS.clear()


_LAST_BODY_TEXELS = {}
