"""Poisson blending of pasted lesions (``blend.method: poisson``): gradient-domain
blending of each lesion's placement view, solved exactly with a sparse direct solver in
unlit log albedo (so that lighting is not baked into the texture), then pulled back
into the lesion's texels. NumPy and SciPy only: a run that blends this way never
imports torch (~1.3 s of start-up)."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..camera import Camera
from ..sampling import sample_bilinear
from .paste import PastedTextures


def crop_box(placement, size, pad):
    """The placement view's lesion box grown by ``pad`` pixels, inside the view."""
    x0, y0, x1, y1 = placement.view_box
    return max(x0 - pad, 0), max(y0 - pad, 0), min(x1 + pad, size), min(y1 + pad, size)


def poisson_blend(renderer, mesh, pasted: PastedTextures, texels, pad: int = 16) -> np.ndarray:
    """Exact gradient-domain blending of every lesion in its placement view, cropped
    to the lesion's box plus ``pad`` pixels."""
    out_tex = pasted.pasted.copy()
    T = pasted.original.astype(np.float32) / 255
    # The guidance field comes from the dilated lesion T_d: its pixels just outside the
    # mask are the photo's own skin, so gradients across the boundary are the photo's
    # and not the jump from lesion to body skin.
    Td = pasted.dilated.astype(np.float32) / 255
    for p in pasted.placements:
        if p.kind == "fields":  # a procedural condition was made on the body's own skin
            continue
        view = Camera.from_dict(p.camera)
        x0, y0, x1, y1 = crop_box(p, view.width, pad)
        cam = view.crop(x0, y0, x1 - x0, y1 - y0)
        out = renderer.render(mesh, cam, passes=("gbuffer", "labels"), label_texture=pasted.instances)
        inside = out["labels"] == p.instance
        inside[[0, -1], :] = False
        inside[:, [0, -1]] = False
        if not inside.any():
            continue
        fg = out["face_id"] >= 0
        uv = out["uv"]
        # unlit albedo views: texture values under each pixel (bilinear, as GL samples)
        tx = uv[..., 0] * T.shape[1] - 0.5
        ty = (1 - uv[..., 1]) * T.shape[0] - 0.5
        src = sample_bilinear(Td, tx.ravel(), ty.ravel()).reshape(uv.shape[:2] + (3,))
        dst = sample_bilinear(T, tx.ravel(), ty.ravel()).reshape(uv.shape[:2] + (3,))
        # Solved on log albedo: pigment scales reflectance, so a lesion keeps its
        # contrast *ratio* to the skin around it when the body's skin is lighter or
        # darker than the photo's (in linear values a dark nevus on dark skin would
        # turn pale grey on light skin).
        eps = 1.0 / 255
        log_f = solve_poisson(np.log(src + eps), np.log(dst + eps), inside, clip=False)
        f = np.clip(np.exp(log_f) - eps, 0, 1) * fg[..., None]
        _pull_back(out_tex, texels, pasted.instances == p.instance, cam, out, f)
    return out_tex


def solve_poisson(src, dst, inside, clip=True):
    """f = dst outside ``inside``; inside, Laplacian(f) = Laplacian(src) (Perez et al.
    2003), solved exactly by sparse LU. src, dst: (H, W, C) float; inside: bool."""
    h, w = inside.shape
    idx = -np.ones((h, w), np.int64)
    ys, xs = np.nonzero(inside)
    n = len(ys)
    idx[ys, xs] = np.arange(n)
    rows, cols, vals = [np.arange(n)], [np.arange(n)], [np.full(n, 4.0)]
    rhs = 4 * src[ys, xs] - sum(src[np.clip(ys + dy, 0, h - 1), np.clip(xs + dx, 0, w - 1)]
                                for dy, dx in ((1, 0), (-1, 0), (0, 1), (0, -1)))
    for dy, dx in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        ny, nx = ys + dy, xs + dx
        j = idx[ny, nx]
        unknown = j >= 0
        rows.append(np.arange(n)[unknown])
        cols.append(j[unknown])
        vals.append(-np.ones(unknown.sum()))
        rhs[~unknown] += dst[ny[~unknown], nx[~unknown]]
    a = sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))
    solution = spla.splu(a).solve(rhs)
    f = dst.copy()
    f[ys, xs] = solution
    return np.clip(f, 0, 1) if clip else f


def _pull_back(texture, texels, lesion_texels, cam, out, view_img):
    """Write view pixels into the lesion texels that see them (inverse mapping)."""
    sel = lesion_texels[texels.rows, texels.cols]
    pts = texels.points[sel]
    px = cam.project(pts)
    eye = np.asarray(cam.eye)
    forward = np.asarray(cam.target) - eye
    forward /= np.linalg.norm(forward)
    h, w = out["depth"].shape
    ix = np.clip(px[:, 0].astype(int), 0, w - 1)
    iy = np.clip(px[:, 1].astype(int), 0, h - 1)
    inside = (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
    z = (pts - eye) @ forward
    visible = inside & (np.abs(z - out["depth"][iy, ix]) <= 0.01 * z + 1e-4)
    vals = sample_bilinear(view_img.astype(np.float32), px[:, 0] - 0.5, px[:, 1] - 0.5, 1)
    r, c = texels.rows[sel][visible], texels.cols[sel][visible]
    texture[r, c] = np.clip(np.round(vals[visible] * 255), 0, 255).astype(np.uint8)
