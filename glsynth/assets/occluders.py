"""What covers part of a clinical photograph at its edge: an examiner's gloved fingers
stretching the skin, the edge of the patient's clothing, or a surgical drape.

An ``Occluder`` is drawn in the image plane over the composited view, at the scale of
the skin it lies on (``mm_per_px`` at the camera's focus), lit from the view's light
direction, and casts a soft shadow on what lies beneath. It comes with its own exact
coverage: the pipeline takes ``mask`` (coverage >= 1/2, or for hair the lock's outline)
out of every body label, as it would for a foreground mesh.

Gloved fingers are flattened capsules narrowing to a round tip (Lambert plus a glossy
highlight), with the stipple and knuckle wrinkles of nitrile or latex; cloth is a
clinical backdrop (``backgrounds.backdrop_image``) cut along a wavy edge, with a rolled
rim and, on clothing, a hem's stitches. A lock of the patient's scalp hair (views of the
head: the body's scalp hair is painted on its texture and has no volume of its own) is a
mass of strands drawn one by one, straight, wavy or curled, shaded as fibres, with
strays past its outline; its label is the outline, as an annotator draws a mass of hair,
and the strays over the skin stay skin, as single hairs do. Each is computed only in the
box it covers or shades (a fifth to a half of the frame).
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
    outline: np.ndarray | None = None   # box-sized bool: the label, when not alpha >= 1/2

    @property
    def mask(self) -> np.ndarray:
        """Frame-sized: its label, the pixels it covers (coverage >= 1/2) or its outline."""
        y0, y1, x0, x1 = self.box
        m = np.zeros(self.shape, bool)
        m[y0:y1, x0:x1] = self.alpha >= 0.5 if self.outline is None else self.outline
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


def _near_edge(shape, origin, inward, deepest):
    """The frame's pixels less than ``deepest`` px in from an edge through ``origin``
    facing ``inward``: their box, their depth and place along the edge (px), and that
    place as an index into a noise row of 4 x the frame's long side centred on
    ``origin``. None when no pixel is that near."""
    h, w = shape
    n = max(h, w)
    depth, _ = _coords((0, h, 0, w), origin, inward)
    near = depth < deepest
    rows, cols = np.flatnonzero(near.any(1)), np.flatnonzero(near.any(0))
    if not len(rows):
        return None
    box = (int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1)
    depth, along = _coords(box, origin, inward)
    return box, depth, along, np.clip((along + 2 * n).astype(np.int32), 0, 4 * n - 1)


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
    box, depth, along, idx = _near_edge(shape, origin, inward, deepest)   # never None: the origin is on the frame
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


# hair of the head (strand width 70 um: below a pixel in every clinical frame, so a
# strand is drawn as a one-pixel line at twice the resolution, its coverage its width)
HAIR_SUPERSAMPLE = 2


def _hair_paths(rng, n_clumps, per_clump, start, inward, length_px, curl_px, clump_px, wave_px):
    """Strands as image points (n x steps x 2) and their heights towards the camera (n x
    steps), ``per_clump`` to each of ``n_clumps`` locks starting at ``start``
    (n_clumps x 2) and heading ``inward`` give or take 25 degrees. The strands of a lock
    run together, ``clump_px`` across at its root and narrowing to its tip: straight
    with a slow wave of ``wave_px`` period, or, where ``curl_px`` > 0, a ringlet coiled
    in loops of that radius about the lock's axis, each strand in step with the lock."""
    turns_max = length_px / (1.5 * curl_px) if curl_px > 0 else 0.0
    steps = int(np.clip(max(length_px / 6, 16 * turns_max), 16, 96))  # 16 points to a loop
    t = np.linspace(0.0, 1.0, steps, dtype=np.float32)[None, :]
    heading = np.arctan2(inward[1], inward[0]) + rng.normal(0, np.radians(25), (n_clumps, 1))
    ang = heading + rng.normal(0, np.radians(20), (n_clumps, 1)) * t   # a lock turns as it falls
    length = length_px * rng.uniform(0.5, 1.0, (n_clumps, 1))
    along = np.stack([np.cos(ang), np.sin(ang)], -1)
    across = np.stack([-np.sin(ang), np.cos(ang)], -1)
    axis = start[:, None, :] + (length * t)[..., None] * along
    z = rng.normal(0, 0.4, (n_clumps, 1)) * length * t                  # lifting off or lying down
    k = np.repeat(np.arange(n_clumps), per_clump)
    m = len(k)
    if curl_px > 0:
        # a ringlet: its strands coil together, each a little out of step and wider or
        # narrower, so that they part and cross
        turns = length / (curl_px * rng.uniform(1.5, 3.0, (n_clumps, 1)))
        phase = (2 * np.pi * turns * t + rng.uniform(0, 2 * np.pi, (n_clumps, 1)))[k] \
            + rng.normal(0, 0.35, (m, 1))
        r = (curl_px * rng.uniform(0.6, 1.4, (n_clumps, 1)))[k] * rng.uniform(0.8, 1.2, (m, 1))
        tilt = rng.uniform(0.3, 1.0, (n_clumps, 1))[k]                  # the coil's axis to the view
        coil = (r * np.sin(phase))[..., None] * across[k] + (tilt * r * np.cos(phase))[..., None] * along[k]
        axis, z = axis[k] + coil, z[k] + r * np.sqrt(1 - tilt ** 2) * np.cos(phase)
    else:
        phase = 2 * np.pi * length * t / wave_px + rng.uniform(0, 2 * np.pi, (n_clumps, 1))
        axis, z = (axis + (0.08 * wave_px * np.sin(phase))[..., None] * across)[k], z[k]
    # each strand: its lock's axis, offset across it (narrowing towards the tip), with a
    # wander of its own and its own length
    offset = rng.normal(0, 0.5 * clump_px, (m, 1)) * (1 - 0.6 * t)
    wander = 0.15 * clump_px * np.cumsum(rng.normal(0, 1, (m, steps)), 1) / np.sqrt(steps)
    pts = axis + ((offset + wander)[..., None]) * across[k]
    heights = z + rng.normal(0, 0.2 * clump_px, (m, 1))
    ends = rng.uniform(0.6, 1.0, m)                                     # where each strand ends
    return pts, heights, ends


def _hair_lock(rng, shape, mm_per_px, light, up, reach, hair_rgb, coily, long_hair):
    """A lock of scalp hair reaching ``reach`` (of the short side) into the frame from
    the side ``up`` (unit image vector towards the top of the head) points to."""
    h, w = shape
    n_side = max(h, w)
    # where the hair comes from: the frame's edge in the direction of the crown, turned
    # up to 50 degrees (hair falls at the temples and the nape as well)
    towards = _turn(np.asarray(up, np.float64), rng.uniform(-50, 50))
    centre = np.array([w / 2, h / 2])
    hit = min((w / 2) / max(abs(towards[0]), 1e-6), (h / 2) / max(abs(towards[1]), 1e-6))
    origin, inward = centre + hit * towards, -towards
    curl_mm = rng.uniform(0.8, 2.0) if coily else (rng.uniform(2.5, 6.0) if rng.random() < 0.3 else 0.0)
    curl_px = curl_mm / mm_per_px
    length_px = (rng.uniform(15, 40) if long_hair else rng.uniform(6, 15)) / mm_per_px
    # the lock's outline: a wavy line (locks 1-3 cm wide), short hair reaching no
    # further than its length
    wave = fractal_noise(rng, (1, 4 * n_side), max(rng.uniform(8, 25) / mm_per_px, 6), octaves=3)[0]
    deep = reach * min(h, w) if long_hair else min(reach * min(h, w), length_px)
    stray_px = rng.uniform(1, 4) / mm_per_px           # how far strays reach past it
    near = _near_edge(shape, origin, inward, 1.35 * deep + stray_px + 2)
    if near is None:
        return None
    box, depth, _, idx = near
    edge = deep * (1 + 0.3 * np.clip(wave[idx], -2.5, 2.5) / 2.5)
    inside = (edge - depth).astype(np.float32)                    # px inside the outline
    bh, bw = inside.shape
    s = HAIR_SUPERSAMPLE
    if curl_px:
        length_px = max(length_px / 2, 4 * curl_px)
    clump_px = (rng.uniform(1.0, 2.5) if curl_px else rng.uniform(1.5, 4.0)) / mm_per_px
    # locks start anywhere inside the outline (a little way back along the flow, so that
    # they run across it), with enough strands to cover it about four times over: a
    # strand L px long, one pixel wide at s times the resolution, covers L / s px
    area = float((inside > 0).sum())
    per_clump = int(np.clip(clump_px * s * 2, 6, 120))
    strands = 4 * area * s / max(length_px, 1.0)
    n_clumps = int(np.clip(strands / per_clump, 8, 12000 // per_clump))
    ys, xs = np.nonzero(inside > 0)
    if not len(ys):
        return None
    pick = rng.integers(len(ys), size=n_clumps)
    start = np.stack([xs[pick], ys[pick]], 1).astype(np.float32) - 0.4 * length_px * np.asarray(inward, np.float32)
    paths, heights, ends = _hair_paths(rng, n_clumps, per_clump, start, np.asarray(inward), length_px,
                                       curl_px, clump_px, rng.uniform(15, 40) / mm_per_px)
    n, steps = heights.shape
    # strands end at their own length; past the outline only strays go on (two to a
    # millimetre of the outline),
    # up to stray_px beyond it
    px = np.clip(paths[..., 0].round().astype(int), 0, bw - 1)
    py = np.clip(paths[..., 1].round().astype(int), 0, bh - 1)
    inside_at = inside[py, px]
    rim = inside >= 0
    rim_mm = float((rim & ~(cv2.erode(rim.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0)).sum()) * mm_per_px
    strays = rng.random(n) < min(2.0 * rim_mm / n, 0.3)          # two to a millimetre of outline
    stop = np.where(strays[:, None], inside_at < -stray_px, inside_at < 0)
    stop |= np.linspace(0, 1, steps)[None, :] > ends[:, None]
    cut = np.argmax(np.concatenate([stop, np.ones((n, 1), bool)], 1), 1)
    # fibre shading (Kajiya-Kay, as the shader's) per segment, from its 3D direction in
    # the camera's frame (image y runs down, the camera's y up)
    seg = np.concatenate([paths[:, 1:] - paths[:, :-1], (heights[:, 1:] - heights[:, :-1])[..., None]], -1)
    fibre = seg * np.array([1.0, -1.0, 1.0])
    fibre /= np.maximum(np.linalg.norm(fibre, axis=-1, keepdims=True), 1e-9)
    light = np.asarray(light, np.float64)
    half = light + np.array([0.0, 0.0, 1.0])
    half /= np.linalg.norm(half)
    tl, th = fibre @ light, fibre @ half
    diffuse = 0.3 + 0.7 * np.sqrt(np.clip(1 - tl * tl, 0, 1))
    glint = np.clip(1 - th * th, 0, 1) ** 20
    # each lock a shade of its own, and each strand a little: the locks on top are lit,
    # those beneath in the shade of the ones above (a lock's depth in the mass: random)
    depth_shade = np.repeat(rng.uniform(0.3, 1.0, n // per_clump), per_clump)[:, None] * rng.uniform(0.75, 1.0, (n, 1))
    level = diffuse * depth_shade, glint * depth_shade
    bins = (np.minimum((level[0] / 1.0 * 6).astype(int), 5) * 4 + np.minimum((level[1] * 4).astype(int), 3))
    shift = 4                                                   # cv2 fixed point: 1/16 px
    fp = np.rint((paths * s + 0.5 * (s - 1)) * (1 << shift)).astype(np.int32)
    segs = np.stack([fp[:, :-1], fp[:, 1:]], 2)                 # n x steps-1 x 2 points x 2
    drawn = np.arange(steps - 1)[None, :] < (cut[:, None] - 1)
    strand = np.zeros((bh, bw), np.float32)
    lit = np.zeros((bh, bw), np.float32)
    shine = np.zeros((bh, bw), np.float32)
    canvas = np.zeros((bh * s, bw * s), np.uint8)
    for b in np.unique(bins[drawn]):
        canvas[:] = 0
        cv2.polylines(canvas, list(segs[drawn & (bins == b)]), False, 255, 1, cv2.LINE_AA, shift)
        cover = cv2.resize(canvas, (bw, bh), interpolation=cv2.INTER_AREA).astype(np.float32) / 255
        strand += cover
        lit += cover * ((b // 4) + 0.5) / 6
        shine += cover * ((b % 4) + 0.5) / 4
    coverage = 1 - np.exp(-1.5 * strand)                        # overlapping strands
    lit /= np.maximum(strand, 1e-6)
    shine /= np.maximum(strand, 1e-6)
    albedo = srgb_to_linear(np.clip(np.asarray(hair_rgb, np.float32) + rng.normal(0, 5, 3), 0, 255) / 255)
    albedo = albedo.astype(np.float32)
    # the mass beneath the strands drawn: hair deeper in the lock, in its shade, dark;
    # it fades in over 1-2 mm from the outline (at most a third of the lock's depth), so
    # that strands, not a line, end the lock
    under = np.clip(inside / min(rng.uniform(1.0, 2.0) / mm_per_px, deep / 3), 0, 1)
    mass = albedo * (0.3 + 0.3 * float(max(light[2], 0.0)))
    top = albedo * (0.2 + 1.0 * lit)[..., None] + (0.06 * shine)[..., None]
    rgb = mass * under[..., None]
    rgb = rgb + (top - rgb) * coverage[..., None]
    alpha = (1 - (1 - under) * (1 - coverage)).astype(np.float32)
    rgb = np.where(alpha[..., None] > 0, rgb / np.maximum(alpha, 1e-6)[..., None], 0)
    standoff = rng.uniform(1, 4) / mm_per_px
    shadow = _cast_shadow(np.maximum(under, 0.5 * coverage).astype(np.float32), light, standoff,
                          0.6 * standoff, 0.45)
    outline = inside >= 0
    meta = {"colour": [int(c) for c in hair_rgb], "strands": int(n), "curl_mm": float(curl_mm),
            "length_mm": float(length_px * mm_per_px), "lock_mm": float(clump_px * mm_per_px),
            # the root line the lock's depth is counted from: through root_px (on the
            # frame's edge), across inward (image x right, y down)
            "root_px": [round(float(v), 2) for v in origin], "inward": [round(float(v), 4) for v in inward]}
    return box, np.clip(rgb, 0, 1).astype(np.float32), alpha, shadow, outline, meta


def sample_hair(rng, shape, mm_per_px: float, light, up, hair_rgb, coily=False, long_hair=False,
                reach=(0.1, 0.4)) -> Occluder | None:
    """A lock of the patient's scalp hair (sRGB ``hair_rgb``; ``coily``: tight curls,
    else straight, wavy or loosely curled; ``long_hair``: longer strands) reaching
    ``reach`` (fractions of the short side; short hair no further than its strands'
    length) into a ``shape`` frame from the side that
    ``up`` (image x right, y down) points to; ``light`` as in ``sample_occluder``. None
    when the outline misses the frame."""
    r = float(rng.uniform(*reach))
    made = _hair_lock(rng, tuple(shape), mm_per_px, light, up, r, hair_rgb, coily, long_hair)
    if made is None:
        return None
    box, rgb, alpha, shadow, outline, meta = made
    return Occluder("hair", tuple(shape), box, rgb, alpha, shadow,
                    {"kind": "hair", "reach": r, **meta}, outline=outline)


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
