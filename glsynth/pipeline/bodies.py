"""Which bodies a run uses: built-in anny bodies or a folder of scans, plus the
texel geometry (which surface point each texel shows) that pasting needs."""
from __future__ import annotations

import logging
import os
from dataclasses import dataclass

import numpy as np

from ..config import Config
from .seeding import rng_for

log = logging.getLogger(__name__)


def body_ids(cfg: Config) -> list[str]:
    if cfg.bodies.source == "builtin":
        return [f"body{i:03d}" for i in range(cfg.bodies.count)]
    folders = scan_folders(cfg.bodies.source)
    return [os.path.basename(f) for f in folders][: cfg.bodies.count]


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
