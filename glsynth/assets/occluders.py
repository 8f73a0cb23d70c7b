"""What covers part of a clinical photograph at its edge: an examiner's gloved fingers
stretching the skin, the edge of the patient's clothing, or a surgical drape.

An ``Occluder`` is drawn in the image plane over the composited view, at the scale of
the skin it lies on (``mm_per_px`` at the camera's focus), lit from the view's light
direction, and casts a soft shadow on what lies beneath. It comes with its own exact
coverage: the pipeline takes ``mask`` (coverage >= 1/2) out of every body label, as it
would for a foreground mesh.

Gloved fingers are flattened capsules narrowing to a round tip (Lambert plus a glossy
highlight), with the stipple and knuckle wrinkles of nitrile or latex; cloth is a
clinical backdrop (``backgrounds.backdrop_image``) cut along a wavy edge, with a rolled
rim and, on clothing, a hem's stitches. Each is computed only in the box it covers or
shades (a fifth to a half of the frame).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from .backgrounds import backdrop_image, backdrop_layout, wide_blur
from .colour import SRGB8_TO_LINEAR, srgb_to_linear
from .lesions import fractal_noise

# examination gloves (sRGB): nitrile blue, violet, black, white; latex cream; a
# surgeon's brown latex
GLOVES = [(70, 115, 195), (95, 140, 215), (110, 95, 180), (40, 40, 46), (232, 234, 236),
          (226, 208, 170), (196, 160, 118)]
EDGE_KINDS = {"glove": 0.45, "clothing": 0.35, "drape": 0.2}
FINGER_WIDTH_MM = (15.0, 20.0)   # a gloved adult finger's width


@dataclass
class Occluder:
    """What the occluder draws inside ``box`` (y0, y1, x0, x1) of a ``shape`` frame:
    ``rgb`` (float32 linear light, 0..1) over ``alpha`` (coverage 0..1), and ``shadow``,
    the share of light left to what lies beneath; all three box-sized. ``meta`` goes in the per-image
    JSON."""
    kind: str
    shape: tuple
    box: tuple
    rgb: np.ndarray
    alpha: np.ndarray
    shadow: np.ndarray
    meta: dict = field(default_factory=dict)

    @property
    def mask(self) -> np.ndarray:
        """Frame-sized: the pixels it covers (coverage >= 1/2), its label."""
        y0, y1, x0, x1 = self.box
        m = np.zeros(self.shape, bool)
        m[y0:y1, x0:x1] = self.alpha >= 0.5
        return m


def _side_frame(shape, side: int, angle_deg: float = 0.0):
    """The middle of a frame side (0 top, 1 right, 2 bottom, 3 left) and the unit
    direction into the frame from it, turned by ``angle_deg`` (image x right, y down)."""
    h, w = shape
    inward = np.array({0: (0.0, 1.0), 1: (-1.0, 0.0), 2: (0.0, -1.0), 3: (1.0, 0.0)}[side])
    origin = np.array({0: (w / 2, 0.0), 1: (w, h / 2), 2: (w / 2, h), 3: (0.0, h / 2)}[side])
    return origin, _turn(inward, angle_deg)


def _turn(v, deg):
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])


def _coords(box, origin, axis):
    """Per pixel of ``box``: distance along ``axis`` from ``origin`` and across it (px)."""
    y0, y1, x0, x1 = box
    xx = np.arange(x0, x1, dtype=np.float32)[None, :] - np.float32(origin[0])
    yy = np.arange(y0, y1, dtype=np.float32)[:, None] - np.float32(origin[1])
    ax, ay = np.float32(axis[0]), np.float32(axis[1])
    return xx * ax + yy * ay, -xx * ay + yy * ax


def _box_around(points, margin, shape):
    """(y0, y1, x0, x1): the frame's pixels within ``margin`` of the points' bounds."""
    pts = np.asarray(points, np.float64)
    x0, y0 = np.floor(pts.min(0) - margin).astype(int)
    x1, y1 = np.ceil(pts.max(0) + margin).astype(int) + 1
    h, w = shape
    return max(y0, 0), min(max(y1, 1), h), max(x0, 0), min(max(x1, 1), w)


def _cast_shadow(alpha, light_xy, offset_px, softness_px, strength):
    """Light kept beneath an object ``offset_px`` above the surface: its coverage moved
    away from the light and blurred, plus a little contact occlusion at its rim."""
    shift = np.float32([[1, 0, -light_xy[0] * offset_px], [0, 1, light_xy[1] * offset_px]])
    moved = cv2.warpAffine(alpha, shift, alpha.shape[::-1], borderMode=cv2.BORDER_REPLICATE)
    cast = wide_blur(moved, max(softness_px, 0.5))
    contact = wide_blur(alpha, max(softness_px / 3, 0.5))
    return np.clip(1 - strength * np.maximum(cast, 0.6 * contact), 0, 1).astype(np.float32)


def _gloved_fingers(rng, shape, mm_per_px, light, side, reach):
    h, w = shape
    radius = rng.uniform(*FINGER_WIDTH_MM) / 2 / mm_per_px
    # the hand comes in from a point on the side, its fingers pointing at the middle
    # of the frame (give or take a sixth of it)
    middle, side_inward = _side_frame(shape, side)
    origin = middle + rng.uniform(-0.3, 0.3) * min(h, w) * np.array([-side_inward[1], side_inward[0]])
    aim = np.array([w / 2, h / 2]) + rng.uniform(-1, 1, 2) * min(h, w) / 6
    inward = (aim - origin) / np.linalg.norm(aim - origin)
    across = np.array([-inward[1], inward[0]])
    n = int(rng.choice([1, 2, 3, 4], p=[0.4, 0.3, 0.2, 0.1]))
    colour = np.clip(np.array(GLOVES[rng.integers(len(GLOVES))], np.float32) + rng.normal(0, 6, 3), 0, 255)
    albedo = srgb_to_linear(colour / 255).astype(np.float32)
    gloss, sheen = rng.uniform(8, 30), rng.uniform(0.08, 0.25)   # nitrile satin to latex shine
    fingers = []
    for k in range(n):
        # fingers side by side from outside the frame, fanned a little, the middle
        # ones reaching further
        start = origin + (k - (n - 1) / 2) * 2.0 * radius * across - 2 * radius * inward
        axis = _turn(inward, rng.uniform(-6, 6))
        tip = max(reach * min(h, w), 5 * radius) * (1 - 0.12 * abs(k - (n - 1) / 2)) + radius
        fingers.append((start, axis, tip, rng.uniform(0.9, 1.05)))
    offset, softness = 0.6 * radius, 0.5 * radius
    ends = [p for s, a, t, _ in fingers for p in (s, s + (t + radius) * a)]
    box = _box_around(ends, radius + offset + 3 * softness, shape)
    bh, bw = box[1] - box[0], box[3] - box[2]
    rgb = np.zeros((bh, bw, 3), np.float32)
    alpha = np.zeros((bh, bw), np.float32)
    stipple = 0.04 * fractal_noise(rng, (bh, bw), max(0.4 / mm_per_px, 1.0), octaves=2)
    wrinkles = 0.25 * fractal_noise(rng, (bh, bw), 0.5 * radius, octaves=2)
    light = np.asarray(light, np.float32)
    half = (light + [0, 0, 1]) / np.linalg.norm(light + [0, 0, 1])
    for start, axis, tip, girth in fingers:   # drawn in order, each over the last
        u, v = _coords(box, start, axis)
        # a finger narrows a little towards its tip and is flatter than it is wide
        rad = radius * girth * (1 - 0.1 * np.clip(u / tip, 0, 1))
        beyond = np.maximum(u - tip, 0)                # past the tip's centre: its round end
        r = np.sqrt(beyond ** 2 + v ** 2) / rad
        cover = np.clip((1 - r) * rad + 0.5, 0, 1)
        # the normal of a flattened cylinder with a rounded end, in the camera's frame
        # (image y runs down, the camera's up); the glove wrinkles over the knuckle
        wrinkle = wrinkles * np.exp(-((u - tip + 2.5 * radius) / (1.5 * radius)) ** 2)
        nx = (beyond * axis[0] - v * axis[1]) / rad + wrinkle * axis[0]
        ny = -(beyond * axis[1] + v * axis[0]) / rad - wrinkle * axis[1]
        nz = 1.6 * np.sqrt(np.clip(1 - r ** 2, 0, 1))
        norm = np.sqrt(nx ** 2 + ny ** 2 + nz ** 2) + 1e-6
        nx, ny, nz = nx / norm, ny / norm, nz / norm
        lambert = np.clip(nx * light[0] + ny * light[1] + nz * light[2], 0, 1)
        spec = np.clip(nx * half[0] + ny * half[1] + nz * half[2], 0, 1) ** gloss
        occlusion = 0.55 + 0.45 * np.sqrt(np.clip(1 - r ** 2, 0, 1))    # where fingers meet
        shade = albedo * ((0.3 + 0.75 * lambert) * occlusion * (1 + stipple))[..., None] \
            + sheen * spec[..., None]
        rgb += (shade - rgb) * cover[..., None]
        alpha = np.maximum(alpha, cover)
    shadow = _cast_shadow(alpha, light, offset, softness, 0.55)
    meta = {"colour": [int(c) for c in colour], "fingers": n, "width_mm": float(2 * radius * mm_per_px)}
    return box, np.clip(rgb, 0, 1), alpha, shadow, meta


def _cloth_edge(rng, shape, mm_per_px, light, side, reach, kind):
    h, w = shape
    n = max(h, w)
    origin, inward = _side_frame(shape, side, rng.uniform(-20, 20))
    # the edge: a wavy line at `reach`, bent by folds a few centimetres long, frayed by
    # threads a millimetre or so long
    wave = fractal_noise(rng, (1, 4 * n), max(25 / mm_per_px, 8), octaves=3)[0]
    fray = fractal_noise(rng, (1, 4 * n), max(1.5 / mm_per_px, 1), octaves=2)[0]
    fray_px = min(0.3 / mm_per_px, 0.25 * reach * min(h, w))
    standoff = rng.uniform(2, 10) / mm_per_px                         # above the skin
    softness = 0.6 * standoff
    deepest = 1.2 * reach * min(h, w) + fray_px + standoff + 3 * softness + 2
    depth, _ = _coords((0, h, 0, w), origin, inward)
    near = depth < deepest
    rows, cols = np.flatnonzero(near.any(1)), np.flatnonzero(near.any(0))
    box = (int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1)
    depth, along = _coords(box, origin, inward)
    idx = np.clip((along + 2 * n).astype(np.int32), 0, 4 * n - 1)
    edge = reach * min(h, w) * (1 + 0.2 * np.clip(wave[idx], -2.5, 2.5) / 2.5) \
        + fray_px * np.clip(fray[idx], -2, 2) / 2
    inside = edge - depth                                              # px inside the cloth
    alpha = np.clip(inside + 0.5, 0, 1).astype(np.float32)
    # the cloth: a clinical backdrop made at half the resolution (a quarter of the time)
    bh, bw = alpha.shape
    layout = backdrop_layout("drape" if kind == "drape" else "fabric", rng)
    cloth = backdrop_image(layout, (max(bh, bw) + 1) // 2, rng)
    cloth = cv2.resize(cloth, (2 * cloth.shape[1], 2 * cloth.shape[0]), interpolation=cv2.INTER_LINEAR)[:bh, :bw]
    # the rolled rim turns from the light: darker over its last 2-4 mm
    rim = np.clip(inside * mm_per_px / rng.uniform(2, 4), 0, 1)
    shade = 0.7 + 0.3 * np.sqrt(rim)
    if kind == "clothing":   # a hem: a row of stitches 6-15 mm in from the edge
        hem = rng.uniform(6, 15) / mm_per_px
        stitch = max(2.5 / mm_per_px, 2.0)
        on_line = np.exp(-((inside - hem) / max(0.3 / mm_per_px, 0.7)) ** 2)
        dashes = (np.mod(along, stitch) < 0.6 * stitch).astype(np.float32)
        shade = shade * (1 - 0.3 * on_line * dashes)
    rgb = SRGB8_TO_LINEAR[cloth] * shade[..., None]
    shadow = _cast_shadow(alpha, np.asarray(light, np.float32), standoff, softness, 0.5)
    meta = {"colour": list(layout["colour"]), "pattern": layout.get("pattern")}
    return box, rgb, alpha, shadow, meta


def sample_occluder(rng, shape, mm_per_px: float, light, reach=(0.1, 0.35), kinds=None) -> Occluder:
    """Gloved fingers, clothing or a drape reaching ``reach`` (fractions of the short
    side) into an ``shape`` (H, W) frame from one of its sides. ``light``: unit
    direction towards the key light in the camera's frame (+x right, +y up, +z towards
    the camera). Fingers only where a finger is a tenth to a third of the frame's
    short side (else clothing): a wider frame would show the whole hand. A finger
    reaches at least two and a half finger widths in, so that it reads as one.
    ``kinds``: weights of glove, clothing and drape (default EDGE_KINDS)."""
    kinds = EDGE_KINDS if kinds is None else kinds
    kind = str(rng.choice(list(kinds), p=np.divide(list(kinds.values()), sum(kinds.values()))))
    side, r = int(rng.integers(4)), float(rng.uniform(*reach))
    finger_px = np.mean(FINGER_WIDTH_MM) / mm_per_px
    if kind == "glove" and not min(shape) / 10 <= finger_px <= min(shape) / 3:
        kind = "clothing"   # a frame much wider than a few fingers would show the hand
    shape = tuple(shape)
    if kind == "glove":
        box, rgb, alpha, shadow, meta = _gloved_fingers(rng, shape, mm_per_px, light, side, r)
    else:
        box, rgb, alpha, shadow, meta = _cloth_edge(rng, shape, mm_per_px, light, side, r, kind)
    meta = {"kind": kind, "side": ["top", "right", "bottom", "left"][side], "reach": r, **meta}
    return Occluder(kind, shape, box, rgb, alpha, shadow, meta)
