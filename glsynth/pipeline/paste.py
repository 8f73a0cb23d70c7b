"""Select & paste (paper section 3.1, appendix A): find suitable places on the skin and
pull the lesion into the body's texture.

For a lesion, a surface point and a camera distance w are sampled; the scaled, flipped
and rotated lesion is composed at the centre of the view from that camera; the place
is accepted when the dilated lesion mask lies on the body, on skin, off earlier lesions,
and its depth change c = max(|z_skin - w| * a_xd) is at most the threshold. The lesion
then enters texture space by the inverse mapping: every texel near the surface point
is projected into the view and takes the lesion pixel it lands on (no holes, correct
across UV seams), giving T_p (pasted colours), T_m (instance ids) and T_d (the dilated
lesion with its surrounding skin).
"""
from __future__ import annotations

import json
import logging
import math
import os
from dataclasses import asdict, dataclass, field

import cv2
import numpy as np

from ..camera import Camera
from ..config import Config, LesionsConfig, PasteConfig
from ..assets.morphology import SITES
from ..dataformat import BODY_INSTANCES, GROUP_NAMES, PASTED, PLACEMENTS, group_labels
from ..errors import GlsynthError
from ..sampling import sample_bilinear
from .seeding import rng_for

log = logging.getLogger(__name__)


class PasteError(GlsynthError, RuntimeError):
    """A body cannot take lesions (no skin, every place rejected...)."""


@dataclass
class Placement:
    instance: int            # id in T_m, 1..k
    lesion_id: str
    lesion_meta: dict
    camera: dict             # Camera.to_dict() of the placement view
    flip_h: bool
    flip_v: bool
    angle_deg: float
    scale: float             # lesion pixels -> view pixels
    depth_change: float      # c of appendix A
    attempts: int
    view_box: list           # [x0, y0, x1, y1) of the lesion in the placement view
    texel_box: list          # [x0, y0, x1, y1) of its texels
    texels: int
    # "image": a picture pasted, then blended; "fields": a procedural condition applied to
    # the body's own skin (no blending needed)
    kind: str = "image"
    instance_ids: list | None = None   # every id this placement holds (several lesions)
    affine: list | None = None         # 2x3: lesion (image or grid) pixels -> view pixels

    @property
    def ids(self) -> list:
        return list(self.instance_ids or [self.instance])


@dataclass
class PastedTextures:
    """T (original), T_p, T_m (uint16 instance ids), T_d, and where each lesion went."""

    original: np.ndarray
    pasted: np.ndarray
    instances: np.ndarray
    dilated: np.ndarray
    placements: list = field(default_factory=list)

    def save(self, folder):
        from ..io.images import write_bytes, write_png
        os.makedirs(folder, exist_ok=True)
        write_png(os.path.join(folder, PASTED), self.pasted)
        write_png(os.path.join(folder, "dilated.png"), self.dilated)
        write_png(os.path.join(folder, BODY_INSTANCES), self.instances)
        write_bytes(os.path.join(folder, PLACEMENTS),
                    json.dumps([asdict(p) for p in self.placements], indent=1,
                               sort_keys=True).encode())

    @classmethod
    def load(cls, folder, original):
        from ..io.images import read_rgb
        instances, placements = cls.load_instances(folder)
        return cls(original, read_rgb(os.path.join(folder, PASTED)), instances,
                   read_rgb(os.path.join(folder, "dilated.png")), placements)

    @staticmethod
    def load_instances(folder):
        """T_m and the placements: all that view generation needs besides the texture."""
        from ..io.images import read_image
        with open(os.path.join(folder, PLACEMENTS)) as fh:
            placements = [Placement(**p) for p in json.load(fh)]
        return read_image(os.path.join(folder, BODY_INSTANCES)).astype(np.uint16), placements

    @staticmethod
    def exists(folder):
        return os.path.isfile(os.path.join(folder, PLACEMENTS))


_PASTE, _LESIONS = PasteConfig(), LesionsConfig()  # the keys' defaults (glsynth/config.py)


@dataclass
class PasteSettings:
    """What placing lesions reads: the ``paste`` keys and ``lesions.size`` (documented
    in glsynth/config.py), ranges as tuples; the defaults are the config's."""
    view_size: int = _PASTE.view_size
    fov_deg: float = _PASTE.fov_deg
    w: tuple = tuple(_PASTE.w)
    max_depth_change: float = _PASTE.max_depth_change
    dilation: int = _PASTE.dilation
    attempts: int = _PASTE.attempts
    size: tuple = tuple(_LESIONS.size)
    enlarge: bool = _PASTE.enlarge
    overlap: str = _PASTE.overlap
    body_sites: bool = _PASTE.body_sites

    @classmethod
    def from_config(cls, cfg: Config) -> PasteSettings:
        p = cfg.paste
        return cls(p.view_size, p.fov_deg, tuple(p.w), p.max_depth_change, p.dilation, p.attempts,
                   tuple(cfg.lesions.size), p.enlarge, p.overlap, p.body_sites)


def compose_lesion(lesion, view_size, extent_px, flip_h, flip_v, angle_deg, max_scale=None):
    """Affine (2x3) from lesion pixels to view pixels placing the mask's box centre at
    the view centre with its longer side ``extent_px`` long (at most ``max_scale`` view
    pixels per lesion pixel when given), and that scale."""
    ys, xs = np.nonzero(lesion.mask)
    cy, cx = (ys.min() + ys.max()) / 2, (xs.min() + xs.max()) / 2
    extent = max(ys.max() - ys.min() + 1, xs.max() - xs.min() + 1)
    scale = extent_px / extent if max_scale is None else min(extent_px / extent, max_scale)
    a = cv2.getRotationMatrix2D((float(cx), float(cy)), float(angle_deg), float(scale))
    flip = np.diag([-1.0 if flip_h else 1.0, -1.0 if flip_v else 1.0])
    a[:, :2] = flip @ a[:, :2]
    a[:, 2] = (view_size - 1) / 2 - a[:, :2] @ np.array([cx, cy])
    return a, scale


FIELD_FILL = 0.8   # share of its placement view that a procedural condition's grid spans


def compose_grid(grid_size, view_size, extent_px, flip_h, flip_v, angle_deg):
    """Affine (2x3) from a condition's grid pixels to view pixels: the grid's centre at
    the view centre, its side ``extent_px`` long; and the scale."""
    c = (grid_size - 1) / 2
    scale = extent_px / grid_size
    a = cv2.getRotationMatrix2D((float(c), float(c)), float(angle_deg), float(scale))
    flip = np.diag([-1.0 if flip_h else 1.0, -1.0 if flip_v else 1.0])
    a[:, :2] = flip @ a[:, :2]
    a[:, 2] = (view_size - 1) / 2 - a[:, :2] @ np.array([c, c])
    return a, scale


def warp_lesion(lesion, affine, view_size):
    img = cv2.warpAffine(lesion.image.astype(np.float32) / 255, affine, (view_size, view_size),
                         flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    mask = cv2.warpAffine(lesion.mask.astype(np.float32), affine, (view_size, view_size),
                          flags=cv2.INTER_LINEAR, borderValue=0)
    return img, mask


def depth_change(out, nonskin_view, instances_view, region, w):
    """c of appendix A over ``region`` (bool): off-body, non-skin and already-used pixels
    count as depth -1, so they reject the place as the paper's z_skin does."""
    depth = out["depth"]
    usable = (out["face_id"] >= 0) & (nonskin_view == 0) & (instances_view == 0)
    z_skin = np.where(usable, depth, -1.0)
    return float(np.abs(z_skin[region] - w).max()) if region.any() else math.inf


class Paster:
    """Places lesions on one body. ``renderer`` must be ``view_size`` square."""

    def __init__(self, renderer, body, texels, settings: PasteSettings):
        self.r, self.body, self.tx, self.s = renderer, body, texels, settings
        mesh = body.mesh
        # sample only faces that are (mostly) skin at their centre texel
        h, w = body.nonskin.shape
        uv = mesh.uvs[mesh.face_uvs].mean(1)
        col = np.clip((uv[:, 0] * w).astype(int), 0, w - 1)
        row = np.clip(((1 - uv[:, 1]) * h).astype(int), 0, h - 1)
        skin_face = (body.nonskin[row, col] == 0) & ~mesh.degenerate_faces
        area = mesh.face_areas * skin_face
        if area.sum() <= 0:
            raise PasteError(f"{mesh.name}: no skin on this body (the non-skin mask covers "
                             "every face), so no lesion can be placed")
        self.face_area, self.face_p = area, area / area.sum()
        labels = mesh.vertex_labels
        self.face_group = None if labels is None else group_labels(labels[mesh.faces[:, 0]])
        self._site_p = {}
        self.nonskin = body.nonskin.astype(np.uint16)
        self.T = mesh.texture
        self.result = PastedTextures(self.T, self.T.copy(), np.zeros(self.T.shape[:2], np.uint16),
                                     self.T.copy())
        if settings.overlap not in ("lesion", "dilated"):
            raise ValueError(f"overlap must be 'lesion' or 'dilated', got {settings.overlap!r}")
        # with overlap "dilated" (DermSynth3D's code): the lesion ids over each lesion's
        # dilated region (T_d's mask), which a new dilated region must not touch
        self.dilated_ids = np.zeros_like(self.result.instances) if settings.overlap == "dilated" else None

    def site_p(self, preset) -> np.ndarray:
        """Each face's probability of holding a lesion of ``preset``: a region by the
        preset's share (morphology.SITES), then by skin area within it; by skin area alone
        when the preset has no sites, the body no part labels or body_sites is off."""
        shares = SITES.get(preset) if self.s.body_sites else None
        if shares is None or self.face_group is None:
            return self.face_p
        if preset not in self._site_p:
            p = np.zeros_like(self.face_p)
            for group, name in GROUP_NAMES.items():
                in_group = self.face_group == group
                total = self.face_area[in_group].sum()
                if name in shares and total > 0:
                    p[in_group] = shares[name] * self.face_area[in_group] / total
            self._site_p[preset] = p / p.sum() if p.sum() > 0 else self.face_p
        return self._site_p[preset]

    def near_p(self, point, radius) -> np.ndarray | None:
        """Skin faces by area, only those whose centre lies within ``radius`` (scene
        units) of ``point``; None when there are none."""
        if not hasattr(self, "_centres"):
            mesh = self.body.mesh
            self._centres = mesh.vertices[mesh.faces].mean(1)
        near = np.sum((self._centres - np.asarray(point)) ** 2, axis=1) < radius ** 2
        p = self.face_p * near
        return p / p.sum() if p.sum() > 0 else None

    def place(self, lesion, rng, near=None) -> Placement | None:
        """Try up to ``attempts`` places, the first half where the lesion's condition is
        usually seen (``site_p``) and the rest anywhere on the skin, so that a condition
        too large for its usual region still finds a place; with ``near`` (face
        probabilities, ``near_p``) every attempt there. Paste and return the placement,
        or None."""
        s, mesh = self.s, self.body.mesh
        site_p = self.site_p((lesion.meta or {}).get("preset")) if near is None else near
        k = max((max(p.ids) for p in self.result.placements), default=0) + 1
        fields = getattr(lesion, "fields", None)
        unit = mesh.skin.unit if mesh.skin is not None else 1.0
        half_tan = math.tan(math.radians(s.fov_deg) / 2)
        reasons = {}
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * s.dilation + 1,) * 2)
        for attempt in range(1, s.attempts + 1):
            anywhere = near is None and attempt > (s.attempts + 1) // 2
            f = rng.choice(len(self.face_p), p=self.face_p if anywhere else site_p)
            bary = rng.dirichlet((1.0, 1.0, 1.0))
            corners = mesh.faces[f]
            point = bary @ mesh.vertices[corners]
            normal = bary @ mesh.vertex_normals[corners]
            if np.linalg.norm(normal) < 1e-9:
                normal = mesh.face_normals[f]
            if fields is not None:
                # a condition has a physical size: the camera distance follows from it
                grid = fields.extent_mm / 1000.0 * unit
                w = grid / FIELD_FILL / (2 * half_tan)
                threshold = s.max_depth_change * float(np.clip(grid / 0.1, 0.25, 4.0))
            else:
                w = rng.uniform(*s.w)
                threshold = s.max_depth_change
            cam = Camera.from_surface(point, normal, w, fov_deg=s.fov_deg,
                                      width=s.view_size, height=s.view_size)
            flip_h, flip_v = bool(rng.random() < 0.5), bool(rng.random() < 0.5)
            angle = float(rng.uniform(0, 360))
            if fields is not None:
                affine, scale = compose_grid(fields.size, s.view_size, FIELD_FILL * s.view_size,
                                             flip_h, flip_v, angle)
                mask = cv2.warpAffine(fields.mask.astype(np.float32), affine, (s.view_size,) * 2,
                                      flags=cv2.INTER_LINEAR, borderValue=0) > 0.5
            else:
                extent = rng.uniform(*s.size) * s.view_size
                # enlarge False: as the original, which shrinks lesions to fit but never
                # enlarges them, a lesion keeps at least its source's resolution
                affine, scale = compose_lesion(lesion, s.view_size, extent, flip_h, flip_v, angle,
                                               max_scale=None if s.enlarge else 1.0)
                mask = warp_lesion(lesion, affine, s.view_size)[1] > 0.5
            if mask.sum() < 3:
                reasons["lesion too small"] = reasons.get("lesion too small", 0) + 1
                continue
            dilated = cv2.dilate(mask.astype(np.uint8), kernel) > 0
            used = self.result.instances if self.dilated_ids is None else self.dilated_ids
            out = self.r.render(mesh, cam, passes=("gbuffer", "labels"),
                                label_textures={"nonskin": self.nonskin, "instances": used})
            c = depth_change(out, out["nonskin"], out["instances"], dilated, w)
            if dilated[0].any() or dilated[-1].any() or dilated[:, 0].any() or dilated[:, -1].any():
                c = math.inf  # lesion does not fit in the view: its edge would be unchecked
            if c > threshold:
                key = "off body / non-skin / overlap / depth change"
                reasons[key] = reasons.get(key, 0) + 1
                continue
            if fields is not None:
                n, ids = self._paste_fields(cam, out, affine, fields, k)
            else:
                n, ids = self._paste(cam, out, affine, lesion, mask, dilated, k), [k]
            if n is None:
                reasons["dilated overlap"] = reasons.get("dilated overlap", 0) + 1
                continue
            if n == 0:
                reasons["no texel visible"] = reasons.get("no texel visible", 0) + 1
                continue
            rows, cols = np.nonzero(mask)
            t_rows, t_cols = np.nonzero(np.isin(self.result.instances, ids))
            meta = _jsonable(lesion.meta)
            if self.face_group is not None:
                meta["body_region"] = GROUP_NAMES[int(self.face_group[f])]
            if fields is not None and "fitzpatrick" in meta:
                # the condition is drawn on this body's skin, not on the swatch it was
                # previewed on: the record's skin type is the body's
                meta["reference_fitzpatrick"] = meta["fitzpatrick"]
                meta["fitzpatrick"] = (getattr(self.body, "meta", None) or {}).get("fitzpatrick")
            p = Placement(k, lesion.id, meta, cam.to_dict(), flip_h, flip_v, angle,
                          float(scale), float(c), attempt,
                          [int(cols.min()), int(rows.min()), int(cols.max()) + 1, int(rows.max()) + 1],
                          [int(t_cols.min()), int(t_rows.min()), int(t_cols.max()) + 1, int(t_rows.max()) + 1],
                          int(n), kind="image" if fields is None else "fields",
                          instance_ids=[int(i) for i in ids], affine=affine.tolist())
            self.result.placements.append(p)
            return p
        log.warning("%s: lesion %s not placed after %d attempts (%s)", mesh.name, lesion.id,
                    s.attempts, ", ".join(f"{v}x {k_}" for k_, v in reasons.items()))
        return None

    def _visible_texels(self, cam, out):
        """Texels near the look-at point that the placement view sees: their indices into
        the texel geometry, view pixel positions and visibility."""
        tx = self.tx
        eye = np.asarray(cam.eye)
        target = np.asarray(cam.target)
        w = float(np.linalg.norm(target - eye))
        radius = (w + self.s.max_depth_change) * math.tan(math.radians(cam.fov_deg) / 2) * 1.5 + 1e-3
        near = np.nonzero(np.sum((tx.points - target) ** 2, axis=1) < radius ** 2)[0]
        pts = tx.points[near]
        px = cam.project(pts) if len(near) else np.zeros((0, 2))
        size = cam.width
        inside = (px[:, 0] >= 0) & (px[:, 0] < size) & (px[:, 1] >= 0) & (px[:, 1] < size)
        ix = np.clip(px[:, 0].astype(int), 0, size - 1)
        iy = np.clip(px[:, 1].astype(int), 0, size - 1)
        forward = (target - eye) / w
        z = (pts - eye) @ forward
        rendered = out["depth"][iy, ix]
        facing = ((eye - pts) * tx.normals[near]).sum(1) > 0
        return near, px, inside & facing & (np.abs(z - rendered) <= 0.01 * w + 1e-4)

    def _paste_fields(self, cam, out, affine, fields, k):
        """Apply a procedural condition to the skin of the texels the view sees, through
        the inverse of ``affine`` into its grid; returns (lesion texels, instance ids)."""
        tx, res = self.tx, self.result
        near, px, visible = self._visible_texels(cam, out)
        inv = cv2.invertAffineTransform(affine)
        grid = np.c_[px - 0.5, np.ones(len(px))] @ inv.T          # (col, row), pixel centres at 0
        at = np.stack([grid[:, 1] + 0.5, grid[:, 0] + 0.5], 1)      # (row, col), centres at +0.5
        from ..assets.morphology import apply_to_skin
        infl = sample_bilinear(fields.influence, grid[:, 0], grid[:, 1], cv2.BORDER_REPLICATE)
        touched = visible & (infl > 1e-3)
        if not touched.any():
            return 0, []
        r, c = tx.rows[near], tx.cols[near]
        rt, ct = r[touched], c[touched]
        colours = apply_to_skin(fields, res.pasted[rt, ct], at=at[touched])
        res.pasted[rt, ct] = colours
        res.dilated[rt, ct] = colours
        gi = np.clip(np.floor(at[:, 0]).astype(np.int64), 0, fields.size - 1)
        gj = np.clip(np.floor(at[:, 1]).astype(np.int64), 0, fields.size - 1)
        local = np.where(visible, fields.instances[gi, gj], 0).astype(np.int64)
        # every lesion of the condition keeps an id, also one too small for a texel
        # (the decal still shows and labels it)
        ids = list(range(k, k + int(fields.instances.max())))
        res.instances[r[local > 0], c[local > 0]] = (local[local > 0] + k - 1).astype(np.uint16)
        for i in np.unique(local[local > 0]) + k - 1:
            _spill_into_gutters(res, tx.covered, int(i))
        self.r.invalidate(res.instances)
        if self.dilated_ids is not None:
            self.dilated_ids[rt, ct] = k
            self.r.invalidate(self.dilated_ids)
        return int((local > 0).sum()), ids

    def _paste(self, cam, out, affine, lesion, mask, dilated, k) -> int | None:
        """Pull lesion pixels into texels seen by this view; returns texels written, or
        None when (overlap "dilated") the dilated texels touch an earlier lesion's."""
        tx, res = self.tx, self.result
        near, px, visible = self._visible_texels(cam, out)
        if len(near) == 0:
            return 0
        # bilinear mask values at the projected points (pixel centres at +0.5)
        m_val = sample_bilinear(mask.astype(np.float32), px[:, 0] - 0.5, px[:, 1] - 0.5)
        d_val = sample_bilinear(dilated.astype(np.float32), px[:, 0] - 0.5, px[:, 1] - 0.5)
        in_lesion = visible & (m_val > 0.5)
        in_dilated = visible & (d_val > 0.5)
        if not in_lesion.any():
            return 0
        r, c = tx.rows[near], tx.cols[near]
        if self.dilated_ids is not None and self.dilated_ids[r[in_dilated], c[in_dilated]].any():
            return None  # tested texel by texel, as the original (the view misses some)
        # lesion colours straight from the source image through the inverse affine
        inv = cv2.invertAffineTransform(affine)
        src = np.c_[px - 0.5, np.ones(len(px))] @ inv.T
        colours = sample_bilinear(lesion.image, src[:, 0], src[:, 1], cv2.BORDER_REPLICATE)
        res.pasted[r[in_lesion], c[in_lesion]] = colours[in_lesion]
        res.instances[r[in_lesion], c[in_lesion]] = k
        res.dilated[r[in_dilated], c[in_dilated]] = colours[in_dilated]
        box = _spill_into_gutters(res, tx.covered, k)
        self.r.invalidate(res.instances)  # changed in place: re-upload before the next check
        if self.dilated_ids is not None:
            self.dilated_ids[r[in_dilated], c[in_dilated]] = k
            self.dilated_ids[box][res.instances[box] == k] = k  # and the gutters spilled into
            self.r.invalidate(self.dilated_ids)
        return int(in_lesion.sum())


def _spill_into_gutters(res: PastedTextures, covered, k, rings=2):
    """Copy lesion texels a few texels into uncovered gutter texels next to them, so
    bilinear sampling at UV island borders does not mix in the old skin colour.
    Returns the texel window (slices) that holds lesion k."""
    region = res.instances == k
    rows, cols = np.nonzero(region)
    y0, y1 = max(rows.min() - rings - 1, 0), rows.max() + rings + 2
    x0, x1 = max(cols.min() - rings - 1, 0), cols.max() + rings + 2
    reg = region[y0:y1, x0:x1].copy()
    cov = covered[y0:y1, x0:x1]
    box = np.ones((3, 3), np.float32)
    for _ in range(rings):
        ring = (cv2.dilate(reg.astype(np.uint8), box.astype(np.uint8)) > 0) & ~reg & ~cov
        if not ring.any():
            break
        weight = cv2.filter2D(reg.astype(np.float32), -1, box, borderType=cv2.BORDER_CONSTANT)
        for tex in (res.pasted, res.dilated):
            sub = tex[y0:y1, x0:x1]
            acc = cv2.filter2D(sub.astype(np.float32) * reg[..., None], -1, box,
                               borderType=cv2.BORDER_CONSTANT)
            fill = acc[ring] / weight[ring][:, None]
            sub[ring] = np.clip(np.round(fill), 0, 255).astype(np.uint8)
        res.instances[y0:y1, x0:x1][ring] = k
        reg |= ring
    return np.s_[y0:y1, x0:x1]


def _jsonable(meta):
    return json.loads(json.dumps(meta, default=str))


def paste_lesions(renderer, body, texels, lesions, settings: PasteSettings, seed_keys, seed,
                  spares=(), eruption=None):
    """Place ``lesions`` (a list) on ``body``; returns PastedTextures. When none of them
    finds a place (conditions larger than the body's flat skin), ``spares`` (an iterable
    of other lesions) are tried in turn until one does. ``eruption`` (spread, radius in
    m): the first placed lesion for which ``spread(lesion)`` gives further lesions
    spreads; they go within the radius of it, and all of them record ``eruption`` (its
    instance id) in their lesion_meta, so that views treat them as one lesion."""
    paster = Paster(renderer, body, texels, settings)
    placed = [paster.place(lesion, rng_for(seed, "paste", *seed_keys, i))
              for i, lesion in enumerate(lesions)]
    if eruption is not None:
        spread, radius = eruption
        for lesion, p in zip(lesions, placed):
            further = spread(lesion) if p is not None else []
            if further:
                _spread(paster, p, further, radius, rng_keys=(seed, "paste", *seed_keys))
                break
    tried = len(lesions)
    if lesions and not paster.result.placements:
        for lesion in spares:
            paster.place(lesion, rng_for(seed, "paste", *seed_keys, tried))
            tried += 1
            if paster.result.placements:
                log.warning("%s: none of the %d lesions drawn found a place; placed %s instead",
                            body.mesh.name, len(lesions), lesion.id)
                break
        else:
            raise PasteError(f"{body.mesh.name}: none of {tried} lesions found a valid place "
                             f"in {settings.attempts} attempts each (too little flat skin for "
                             f"lesions of {settings.size} of the view; lower lesions.size or raise "
                             "paste.max_depth_change)")
    return paster.result


def _spread(paster, first: Placement, further, radius_m, rng_keys):
    """Place the ``further`` lesions of an eruption round ``first`` (within ``radius_m``
    of its centre, on skin, clear of other lesions) and mark them all as one eruption."""
    mesh = paster.body.mesh
    unit = mesh.skin.unit if mesh.skin is not None else 1.0
    near = paster.near_p(first.camera["target"], radius_m * unit)
    if near is None:
        return
    first.lesion_meta["eruption"] = first.instance
    for j, lesion in enumerate(further):
        p = paster.place(lesion, rng_for(*rng_keys, "eruption", j), near=near)
        if p is not None:
            p.lesion_meta["eruption"] = first.instance
