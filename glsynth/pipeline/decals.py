"""Lesion decals: every pasted lesion kept at its own resolution, independent of the body
texture's.

A lesion's decal is an image of it as its placement camera saw it, ``size`` pixels
square (at the look-at distance a pixel is a few hundredths of a millimetre for small
lesions): its colour and coverage, the slope of its relief, its gloss and how much of
the skin's micro-relief shows, and its instance ids. The shaders (``shaders/decal.glsl``)
project each surface point the body's region map assigns to a decal into that decal and
blend it over the body texture by the coverage, which falls to 0 before the region ends;
the label passes take the lesion ids from the decal there, so a lesion's outline in the
labels is as sharp as in the image. Colours are final:

* a procedural condition (placement kind "fields") is applied to the body's original
  skin under each decal pixel, as pasting applied it to the texels;
* a lesion image keeps the blended body texture's colour and adds back the detail the
  texture lost: decal = blended + (source - pasted) where the lesion is, the source
  sampled at the decal's own resolution.

Geometry never changes, so the decal's projection is exact on the placement's surface;
decals are rebuilt from the placements and the lesion sources, and saved per body
(``bodies/<id>/decals.npz``).
"""
from __future__ import annotations

import io
import math
import os
from dataclasses import dataclass

import cv2
import numpy as np

from ..camera import Camera
from ..rows import by_rows
from ..sampling import sample_bilinear

SLOPE_RANGE = 2.0   # relief slope (dh/dx) stored in the aux channels: 0..255 <-> -2..2
DETAIL_RANGE = 2.0  # micro-relief visibility stored in aux alpha: 0..255 <-> 0..2
FILE = "decals.npz"


def encode_aux(slope_x, slope_y, gloss, detail) -> np.ndarray:
    """The aux channels (uint8, last axis 4) of relief slopes (world per world), gloss
    (0..1) and micro-relief visibility (0..DETAIL_RANGE), rounded to the nearest code:
    truncation tilted every small negative slope one step further."""
    def code(x, lo, hi, offset, scale):
        return np.rint(offset + scale * np.clip(np.asarray(x), lo, hi) / hi)
    return np.stack([code(slope_x, -SLOPE_RANGE, SLOPE_RANGE, 128, 127),
                     code(slope_y, -SLOPE_RANGE, SLOPE_RANGE, 128, 127),
                     code(gloss, 0, 1, 0, 255),
                     code(detail, 0, DETAIL_RANGE, 0, 255)], -1).astype(np.uint8)


@dataclass
class Decals:
    """The decals of one body. region: (H, W) uint16 at the texture's size, decal layer
    + 1 over the texels it covers (0: none); projection: (N, 3, 4) float64 world ->
    (column, row, 1) decal pixels (homogeneous, divided by the third row; pixel centres
    at +0.5); axes: (N, 2, 3) float64 world directions of the decal's +x (right) and +y
    (down); texel: (N,) world size of a decal pixel at the look-at point; colour:
    (N, S, S, 4) uint8 sRGB + coverage; aux: (N, S, S, 4) uint8 relief slope along +x and
    +y, gloss, micro-relief visibility; instances: (N, S, S) uint16 lesion ids."""
    region: np.ndarray
    projection: np.ndarray
    axes: np.ndarray
    texel: np.ndarray
    colour: np.ndarray
    aux: np.ndarray
    instances: np.ndarray

    @property
    def size(self) -> int:
        return self.colour.shape[1]

    def __len__(self):
        return len(self.colour)

    def save(self, folder):
        from ..io.images import write_bytes
        buf = io.BytesIO()
        np.savez_compressed(buf, **{k: getattr(self, k) for k in self.__dataclass_fields__})
        write_bytes(os.path.join(folder, FILE), buf.getvalue())

    @classmethod
    def load(cls, folder):
        path = os.path.join(folder, FILE)
        if not os.path.isfile(path):
            return None
        with np.load(path, allow_pickle=False) as z:
            return cls(**{k: z[k] for k in cls.__dataclass_fields__})


def decal_camera(placement, size) -> Camera:
    """The placement view at the decal's size."""
    view = Camera.from_dict(placement.camera)
    return Camera(view.eye, view.target, view.up, view.fov_deg, size, size, None, None, view.surface)


def projection_rows(cam: Camera) -> np.ndarray:
    """3 x 4 matrix: world -> homogeneous pixel coordinates (column, row, 1) of ``cam``
    (pixel centres at +0.5), as ``Camera.project`` computes them."""
    k = cam.intrinsics()
    kk = np.array([[k[0, 0], 0, -k[0, 2]], [0, -k[1, 1], -k[1, 2]], [0, 0, -1.0]])
    return kk @ cam.view_matrix()[:3]


def _texture_at(texture, uv):
    """Bilinear samples (float32 0..255) of ``texture`` at UVs (N x 2), as GL samples it."""
    h, w = texture.shape[:2]
    return sample_bilinear(texture.astype(np.float32), uv[:, 0] * w - 0.5, (1 - uv[:, 1]) * h - 0.5,
                           cv2.BORDER_REPLICATE)


def build_decals(renderer, mesh, texels, original, pasted, final, placements, lesion_for, size=1024,
                 margin=1):
    """The decals of ``placements`` (list of paste.Placement) on ``mesh``; ``original``,
    ``pasted`` and ``final`` are the body texture before pasting, after pasting and after
    blending (uint8); ``lesion_for(placement)`` returns the placement's lesion (a
    FieldLesion or an image Lesion); ``texels`` the body's texel geometry
    (bodies.TexelGeometry). Returns Decals, or None without placements."""
    if not placements:
        return None
    n = len(placements)
    colour = np.zeros((n, size, size, 4), np.uint8)
    aux = np.zeros((n, size, size, 4), np.uint8)
    instances = np.zeros((n, size, size), np.uint16)
    projection = np.zeros((n, 3, 4))
    axes = np.zeros((n, 2, 3))
    texel = np.zeros(n)
    region = np.zeros(original.shape[:2], np.uint16)
    owner_cover = np.zeros(original.shape[:2], np.uint8)   # the coverage of the texel's decal
    unit = mesh.skin.unit if mesh.skin is not None else 1.0
    for i, p in enumerate(placements):
        cam = decal_camera(p, size)
        out = renderer.render(mesh, cam, passes=("gbuffer",), buffers=("face_id", "depth", "uv"))
        fg = out["face_id"] >= 0
        uv = out["uv"][fg]
        rows, cols = np.nonzero(fg)
        # decal pixel -> placement view pixel -> lesion (grid or image) pixel
        scale = cam.width / Camera.from_dict(p.camera).width
        view = np.stack([(cols + 0.5) / scale, (rows + 0.5) / scale], 1)
        inv = cv2.invertAffineTransform(np.asarray(p.affine, np.float64))
        src = np.c_[view - 0.5, np.ones(len(view))] @ inv.T          # lesion pixel, centres at 0
        lesion = lesion_for(p)
        c = np.zeros((len(uv), 4), np.float32)
        a = np.zeros((len(uv), 4), np.float32)
        a[:, :2] = 128
        pixel_world = 2 * float(np.linalg.norm(np.subtract(cam.target, cam.eye))) \
            * math.tan(math.radians(cam.fov_deg) / 2) / size
        seen = _seen_texels(texels, cam, out)
        if p.kind == "fields":
            # d(grid pixel)/d(decal pixel), and world units per mm of height
            jac = inv[:, :2] / scale
            _fields_decal(lesion.fields, src, uv, original, p, c, a, instances[i], rows, cols,
                          jac, unit / 1000.0 / pixel_world)
            _cover_texture_bleed(c, instances[i], rows, cols, seen, fg)
        else:
            _image_decal(lesion, src, uv, pasted, final, p, c, a, instances[i], rows, cols)
        colour[i][fg] = np.clip(np.rint(c), 0, 255).astype(np.uint8)
        aux[i][fg] = np.clip(np.rint(a), 0, 255).astype(np.uint8)
        projection[i] = projection_rows(cam)
        view_m = cam.view_matrix()
        axes[i] = [view_m[0, :3], -view_m[1, :3]]
        texel[i] = pixel_world
        _mark_region(region, owner_cover, i + 1, seen, colour[i][..., 3], margin)
    return Decals(region, projection, axes, texel, colour, aux, instances)


def _fields_decal(fields, src, uv, original, p, c, a, inst, rows, cols, jac, slope_per_mm):
    """A procedural condition's decal pixels (``src``: grid pixels, centres at 0)."""
    from ..assets.morphology import apply_to_skin
    at = np.stack([src[:, 1] + 0.5, src[:, 0] + 0.5], 1)
    base = np.clip(np.rint(_texture_at(original, uv)), 0, 255).astype(np.uint8)
    c[:, :3] = by_rows(lambda skin, where: apply_to_skin(fields, skin, at=where), base, at)
    g = lambda img: sample_bilinear(np.asarray(img, np.float32), src[:, 0], src[:, 1],  # noqa: E731
                                    cv2.BORDER_REPLICATE)
    infl = sample_bilinear(fields.influence, src[:, 0], src[:, 1], cv2.BORDER_CONSTANT)
    # relief: the height gradient per grid pixel, through the affine into decal pixels,
    # as a slope (world per world)
    gy, gx = np.gradient(fields.f["height"])
    hx, hy = g(gx), g(gy)
    a[:] = encode_aux((hx * jac[0, 0] + hy * jac[1, 0]) * slope_per_mm,
                      (hx * jac[0, 1] + hy * jac[1, 1]) * slope_per_mm,
                      g(fields.f["gloss"]), g(fields.f["detail"]))
    n = fields.size
    gi = np.clip(np.floor(src[:, 1] + 0.5).astype(np.int64), 0, n - 1)
    gj = np.clip(np.floor(src[:, 0] + 0.5).astype(np.int64), 0, n - 1)
    inside = (src[:, 0] >= -0.5) & (src[:, 0] < n - 0.5) & (src[:, 1] >= -0.5) & (src[:, 1] < n - 0.5)
    local = np.where(inside, fields.instances[gi, gj], 0).astype(np.int64)
    inst[rows, cols] = np.where(local > 0, local + p.instance - 1, 0).astype(np.uint16)
    # coverage: 1 where the condition changes the skin, fading out with its influence
    c[:, 3] = np.where(local > 0, 255, 255 * np.clip(infl / 0.05, 0, 1))


def _image_decal(lesion, src, uv, pasted, final, p, c, a, inst, rows, cols):
    """A lesion image's decal pixels (``src``: lesion image pixels, centres at 0)."""
    m = sample_bilinear(lesion.mask.astype(np.float32), src[:, 0], src[:, 1], cv2.BORDER_CONSTANT)
    # coverage: the lesion and a rim of a few view pixels around it, feathered
    rim = max(2.0, 4.0 / max(p.scale, 1e-6))                    # lesion pixels
    soft = cv2.GaussianBlur(lesion.mask.astype(np.float32), (0, 0), rim)
    cover = np.clip(2 * sample_bilinear(soft, src[:, 0], src[:, 1], cv2.BORDER_CONSTANT), 0, 1)
    hr = sample_bilinear(lesion.image.astype(np.float32), src[:, 0], src[:, 1], cv2.BORDER_REPLICATE)
    lo_final, lo_pasted = _texture_at(final, uv), _texture_at(pasted, uv)
    c[:, :3] = lo_final + (hr - lo_pasted) * np.clip(cover, 0, 1)[:, None]
    c[:, 3] = 255 * cover
    a[:, 3] = 255 * 0.6 / DETAIL_RANGE                         # a photo has its own texture
    inst[rows, cols] = np.where(m > 0.5, p.instance, 0).astype(np.uint16)


def _seen_texels(texels, cam, out):
    """The body texels the decal camera sees: (texture rows, texture columns, decal
    column, decal row) of each texel near the look-at point whose surface point is
    visible in the decal."""
    target = np.asarray(cam.target)
    eye = np.asarray(cam.eye)
    w = float(np.linalg.norm(target - eye))
    radius = w * math.tan(math.radians(cam.fov_deg) / 2) * 1.5
    near = np.nonzero(np.sum((texels.points - target) ** 2, axis=1) < radius ** 2)[0]
    px = cam.project(texels.points[near]) if len(near) else np.zeros((0, 2))
    size = cam.width
    ix = np.clip(np.floor(px[:, 0]).astype(int), 0, size - 1)
    iy = np.clip(np.floor(px[:, 1]).astype(int), 0, size - 1)
    inside = (px[:, 0] >= 0) & (px[:, 0] < size) & (px[:, 1] >= 0) & (px[:, 1] < size)
    z = (texels.points[near] - eye) @ ((target - eye) / w)
    facing = ((eye - texels.points[near]) * texels.normals[near]).sum(1) > 0
    seen = inside & facing & (np.abs(z - out["depth"][iy, ix]) <= 0.01 * w + 1e-4)
    return texels.rows[near][seen], texels.cols[near][seen], ix[seen], iy[seen]


def _cover_texture_bleed(c, inst, rows, cols, seen, fg):
    """Widen a procedural condition's coverage over the band where the body texture's
    own copy of the lesion bleeds out.

    Pasting also painted the condition into the body texture, at texel resolution, and
    the renderer samples that texture bilinearly: its dark (or red) lesion texels shade
    up to a texel beyond the outline. Where the decal's coverage ended at the outline,
    that low-resolution bleed showed outside the sharp decal edge as a dark halo, with
    the decal's own clean skin just inside it reading as a pale rim. The decal already
    holds the clean skin there (the condition applied to the original texture), so it
    now covers two texels beyond the outline, fading out over the last half."""
    n_px = int(fg.sum())
    if not len(seen[0]) or not n_px:
        return
    texel_px = math.sqrt(n_px / len(seen[0]))             # decal pixels per body texel
    outside = np.ascontiguousarray((inst == 0).astype(np.uint8))
    dist = cv2.distanceTransform(outside, cv2.DIST_L2, 5)[rows, cols]
    rim = np.clip((2.0 * texel_px - dist) / (0.5 * texel_px), 0, 1)
    c[:, 3] = np.maximum(c[:, 3], 255 * rim)


def _mark_region(region, owner_cover, layer, seen, alpha, margin):
    """Give ``layer`` to the texels whose surface point the decal sees with coverage > 0
    (``seen``: from _seen_texels) where no decal covers them more (``owner_cover``: the
    coverage of each texel's decal so far, updated), and to ``margin`` rings of seen
    texels around them that no decal has. A texel shows one decal, and each decal holds
    only its own lesion: when the first decal to claim a texel kept it, a small lesion
    lying in the fading edge of a large one's coverage was cut off along body texels,
    a staircase across its image and labels."""
    r, c, ix, iy = seen
    if not len(r):
        return
    cover = alpha[iy, ix]
    covered = cover > 0
    r1, c1, cover = r[covered], c[covered], cover[covered]
    wins = (region[r1, c1] == 0) | (cover > owner_cover[r1, c1])
    region[r1[wins], c1[wins]] = layer
    owner_cover[r1[wins], c1[wins]] = cover[wins]
    if margin:
        mark = np.zeros(region.shape, bool)
        mark[r1, c1] = True
        ok = np.zeros(region.shape, bool)
        ok[r, c] = True
        k = np.ones((2 * margin + 1,) * 2, np.uint8)
        ring = (cv2.dilate(mark.view(np.uint8), k) > 0) & ok & (region == 0)
        region[ring] = layer
