"""Skin conditions composed from dermatology's vocabulary, as changes to the skin they
sit on (glsynth.assets.chromophores), not as pictures.

A condition is a :class:`LesionFields`: on a square grid covering ``extent_mm``, maps of
what the condition does to the skin: epidermal melanin (a factor and an amount
added: a naevus's melanocytes make melanin whatever the skin around), blood (a factor
and an amount added, its oxygen saturation), dermal melanin, bilirubin, the dermis's
scattering (lower in vascular, collagen-poor tissue, whose red is deeper), how much epidermis
is left (0 in an erosion or ulcer), coverage by scale and crust of a given colour,
height (mm: plaques, nodules, ulcers), gloss (moist or tense surfaces), how much of the
skin's micro-relief shows (0 smooth, 1 normal, 2 lichenified), and the mask a
dermatologist would draw, with one instance id per discrete lesion.

:func:`apply_to_skin` turns the fields into colours on any skin: each colour is mapped
to its nearest melanin and blood in the skin model, changed, mapped back, and keeps its
own deviation from the model; so erythema is pink on light skin and violaceous or dark
brown on dark skin, and the body's own mottling continues under the condition.

Presets named after common conditions (``PRESETS``) sample the vocabulary:

* primary morphology: macule/patch (colour only), papule/plaque (raised), nodule,
  vesicle/bulla (tense, translucent), pustule, wheal, telangiectasia;
* secondary changes: scale (white, silvery, greasy yellow), crust (honey,
  haemorrhagic), erosion, ulcer with granulation and slough, lichenification, atrophy,
  excoriation, hyperpigmentation;
* borders (sharp, ill-defined, raised, rolled), shapes (round, oval, annular, arcuate,
  serpiginous, targetoid, linear, reticular) and arrangements (solitary, grouped,
  confluent, satellite, dermatomal, widespread), from millimetres to a whole region.

Everything is drawn from a seeded generator: the same seed gives the same condition.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy import ndimage

from ..sampling import sample_bilinear
from .chromophores import skin_inverse, skin_rgb_fast
from .colour import lab_to_srgb, srgb_to_lab

FIELDS = ("melanin", "melanin_add", "blood", "blood_add", "oxygen", "dermal_melanin", "bilirubin",
          "scatter", "epidermis", "scale", "crust", "crust_dark", "height", "gloss", "detail")
NEUTRAL = {"melanin": 1.0, "melanin_add": 0.0, "blood": 1.0, "blood_add": 0.0, "oxygen": 0.75,
           "dermal_melanin": 0.0, "scatter": 1.0,
           "bilirubin": 0.0, "epidermis": 1.0, "scale": 0.0, "crust": 0.0, "crust_dark": 0.0, "height": 0.0,
           "gloss": 0.0, "detail": 1.0}
SCALE_COLOURS = {"white": (236, 232, 226), "silvery": (214, 218, 222), "greasy": (205, 178, 120),
                 "pus": (232, 216, 168), "fibrin": (236, 226, 204)}
CRUST_COLOURS = {"honey": (196, 140, 58), "haemorrhagic": (88, 28, 24), "serous": (170, 120, 70),
                 "slough": (214, 196, 138)}
OLD_CRUST = np.array([72, 36, 26]) / 255.0
FIBRIN_GREY = (206, 204, 194)      # wet fibrinous slough: grey-white, no yellow
# blood volume fraction added where the epidermis is gone (Builder.erode): about that of
# a florid erythema (Builder.erythema amount 2.5)
ERODED_BLOOD = 0.25


@dataclass
class LesionFields:
    """A condition on a size x size grid covering extent_mm x extent_mm (row 0 at the top).
    ``f`` holds the float32 maps named in FIELDS; ``mask`` bool; ``instances`` uint16
    (1..n, one per discrete lesion, 0 outside the mask)."""
    f: dict
    mask: np.ndarray
    instances: np.ndarray
    extent_mm: float
    scale_rgb: tuple = SCALE_COLOURS["white"]
    crust_rgb: tuple = CRUST_COLOURS["honey"]
    preset: str = ""
    params: dict = field(default_factory=dict)

    @property
    def size(self) -> int:
        return self.mask.shape[0]

    @property
    def influence(self) -> np.ndarray:
        """0..1: how much the condition changes the skin at each grid cell (1 on the
        mask; 0 where it leaves the skin as it is), widened by a cell and smoothed, so
        that it can serve as the blend weight of a decal."""
        if getattr(self, "_influence", None) is None:
            f = self.f
            dev = np.maximum.reduce([
                np.abs(np.log(np.maximum(f["melanin"], 1e-3))) / 0.3, f["melanin_add"] / 0.01,
                np.abs(f["blood"] - 1) / 0.3,
                f["blood_add"] / 0.02, f["dermal_melanin"] / 0.005, f["bilirubin"] / 0.05,
                np.abs(f["scatter"] - 1) / 0.1,
                np.abs(f["epidermis"] - 1) / 0.3, f["scale"] / 0.05, f["crust"] / 0.05,
                np.abs(f["height"]) / 0.05, f["gloss"] / 0.1, np.abs(f["detail"] - 1) / 0.2])
            w = np.maximum(np.clip(dev, 0, 1), self.mask).astype(np.float32)
            w = cv2.dilate(w, np.ones((3, 3), np.uint8))
            self._influence = cv2.GaussianBlur(w, (0, 0), 1.0)
        return self._influence

    @property
    def mm_per_px(self) -> float:
        return self.extent_mm / self.size


# ---- primitives ---------------------------------------------------------------------------
def noise(rng, size, feature_px, octaves=3, persistence=0.5):
    """Zero-mean unit-std value noise with features about ``feature_px`` wide."""
    out = np.zeros((size, size), np.float32)
    amp = 1.0
    for _ in range(octaves):
        step = max(feature_px, 1.0)
        g = rng.standard_normal((int(size / step) + 3, int(size / step) + 3)).astype(np.float32)
        out += amp * cv2.resize(g, (size, size), interpolation=cv2.INTER_CUBIC)
        feature_px /= 2
        amp *= persistence
    return (out - out.mean()) / (out.std() + 1e-6)


def smoothstep(e0, e1, x):
    t = np.clip((np.asarray(x, np.float32) - e0) / (e1 - e0), 0, 1)
    return t * t * (3 - 2 * t)


def dome(inside, smooth=0.2):
    """0..1 height of a smooth dome over the region ``inside`` (bool grid): the distance to
    its edge, blurred over ``smooth`` of its greatest depth so that the distance's crease
    along the middle does not show as a fold, and rounded at the top. The blur lets it
    slope a little past the edge: a shoulder, not a step."""
    d = cv2.distanceTransform(inside.astype(np.uint8), cv2.DIST_L2, 5)
    if d.max() <= 0:
        return d
    d = cv2.GaussianBlur(d, (0, 0), max(1.0, smooth * float(d.max())))
    s = d / float(d.max())
    return 1 - (1 - s) ** 2


class Canvas:
    """Coordinates (mm, centred) of a size x size grid and a seeded generator."""

    def __init__(self, rng, size, extent_mm):
        self.rng, self.size, self.extent = rng, size, float(extent_mm)
        c = (np.arange(size, dtype=np.float32) + 0.5) / size - 0.5
        self.y, self.x = np.meshgrid(c * self.extent, c * self.extent, indexing="ij")
        self.px = self.extent / size

    def noise(self, feature_mm, octaves=3):
        return noise(self.rng, self.size, feature_mm / self.px, octaves)

    def shape(self, kind, radius, centre=(0.0, 0.0), aspect=1.0, angle=None, irregular=0.1,
              warp=0.08, width=None):
        """Signed distance (mm, > 0 inside) of a shape: round/oval (``aspect``), annular
        or arcuate (a ring of ``width``; arcuate keeps part of it), targetoid (rings),
        serpiginous (a winding band), linear (a band), reticular (a net)."""
        rng = self.rng
        angle = rng.uniform(0, np.pi) if angle is None else angle
        dx, dy = self.x - centre[0], self.y - centre[1]
        u = dx * np.cos(angle) + dy * np.sin(angle)
        v = (dy * np.cos(angle) - dx * np.sin(angle)) / aspect
        theta, r = np.arctan2(v, u), np.hypot(u, v)
        radial = np.ones_like(r)
        for k in range(2, 8):
            radial += irregular * rng.normal() / k ** 0.9 * np.cos(k * theta + rng.uniform(0, 2 * np.pi))
        r = r / np.clip(radial, 0.5, 1.7) + warp * radius * self.noise(radius / 2, 2)
        width = width or 0.25 * radius
        if kind in ("round", "oval"):
            return radius - r
        if kind in ("annular", "arcuate"):
            sd = width / 2 - np.abs(r - radius)
            if kind == "arcuate":
                gap = rng.uniform(0.6, 1.6)
                keep = np.cos(theta - rng.uniform(-np.pi, np.pi)) > np.cos(np.pi - gap / 2)
                sd = np.where(keep, sd, np.minimum(sd, -width))
            return sd
        if kind == "targetoid":
            rings = [radius * 0.25, radius * 0.65, radius]
            sd = rings[0] - r
            for ri in rings[1:]:
                sd = np.maximum(sd, width / 2 - np.abs(r - ri))
            return sd
        if kind == "linear":
            return width / 2 - np.abs(v * aspect) - 0.0 * u + np.minimum(0, radius * 2 - np.abs(u))
        if kind == "serpiginous":
            path = 0.35 * radius * np.sin(u / radius * rng.uniform(2.0, 3.5) + rng.uniform(0, 6))
            return np.minimum(width / 2 - np.abs(v * aspect - path), radius * 1.6 - np.abs(u))
        if kind == "reticular":
            n = self.noise(radius * 0.35, 2)
            net = 1 - smoothstep(0.0, 0.35, np.abs(n))
            return np.where(r < radius, net * width - width / 2, -r + radius - width / 2)
        raise ValueError(f"unknown shape {kind!r}")


def spots(canvas, centres, radii, irregular=0.15, reach=3.0):
    """Signed distance (mm, > 0 inside) to the nearest of many small round spots, and the
    index of the spot each cell belongs to (-1: none within ``reach`` radii). Each spot is
    worked out on its own window of the grid, so hundreds of pinpoint spots cost what one
    shape does; their outlines wobble by ``irregular`` of their radius."""
    c = canvas
    wobble = 1 + irregular * noise(c.rng, c.size, max(1.5, float(np.median(radii)) / c.px), 2)
    sd = np.full((c.size, c.size), -np.inf, np.float32)
    index = np.full((c.size, c.size), -1, np.int32)
    for i, ((x, y), r) in enumerate(zip(centres, radii)):
        span = reach * r / c.px
        col, row = (x / c.extent + 0.5) * c.size, (y / c.extent + 0.5) * c.size
        r0, r1 = max(int(row - span), 0), min(int(row + span) + 2, c.size)
        c0, c1 = max(int(col - span), 0), min(int(col + span) + 2, c.size)
        if r0 >= r1 or c0 >= c1:
            continue
        d = r * wobble[r0:r1, c0:c1] - np.hypot(c.x[r0:r1, c0:c1] - x, c.y[r0:r1, c0:c1] - y)
        win = d > sd[r0:r1, c0:c1]
        sd[r0:r1, c0:c1][win] = d[win]
        index[r0:r1, c0:c1][win] = i
    return np.maximum(sd, -reach * float(np.max(radii))), index


def polygon(canvas, centre, radius, sides):
    """Signed distance (mm, > 0 inside) of an angular papule: a convex polygon of
    ``sides`` sides about ``radius`` from its centre, each turned and set a little apart
    from the regular one's, its corners rounded off towards a circle and its edges
    wavering (a regular polygon with sharp corners read as a crystal)."""
    c, rng = canvas, canvas.rng
    dx, dy = c.x - centre[0], c.y - centre[1]
    base = rng.uniform(0, 2 * np.pi)
    sd = np.full(dx.shape, np.inf, np.float32)
    for i in range(sides):
        phi = base + 2 * np.pi * (i + rng.uniform(-0.3, 0.3)) / sides
        np.minimum(sd, radius * rng.uniform(0.75, 1.05) - (dx * np.cos(phi) + dy * np.sin(phi)), out=sd)
    return 0.6 * sd + 0.4 * (0.95 * radius - np.hypot(dx, dy)) + 0.03 * radius * c.noise(radius / 2, 1)


def vessel_tree(canvas, starts, headings, width_mm, length_mm, depth=3):
    """Coverage (0..1) of branching vessels: from each start (mm) along its heading
    (radians) a vessel ``width_mm`` wide runs ``length_mm`` in three bent steps, then
    forks in two at 25-50 degrees, each branch 0.65 as wide and 0.75 as long, ``depth``
    times: thick trunks tapering to capillaries, as the arborising vessels on a basal
    cell carcinoma are. Each step is drawn on its own window of the grid; a vessel
    narrower than a cell is drawn a cell wide and fainter in proportion."""
    c = canvas
    out = np.zeros((c.size, c.size), np.float32)
    todo = [(np.asarray(p, np.float64), float(h), float(width_mm), float(length_mm), 0)
            for p, h in zip(starts, headings)]
    while todo:
        p, h, w, length, k = todo.pop()
        for _ in range(3):
            h += c.rng.normal(0.0, 0.35)
            q = p + length / 3 * np.array([np.cos(h), np.sin(h)])
            _draw_segment(c, out, p, q, w)
            p = q
        if k < depth:
            for side in (-1.0, 1.0):
                todo.append((p, h + side * c.rng.uniform(0.45, 0.9), 0.65 * w, 0.75 * length, k + 1))
    return out


def _draw_segment(c, out, p, q, width):
    """Draw the segment p-q (mm) ``width`` wide into ``out`` (max), anti-aliased."""
    half = max(width, c.px) / 2
    strength = min(1.0, width / c.px)
    lo, hi = np.minimum(p, q) - half - 2 * c.px, np.maximum(p, q) + half + 2 * c.px
    c0, c1 = (np.array([lo[0], hi[0]]) / c.extent + 0.5) * c.size
    r0, r1 = (np.array([lo[1], hi[1]]) / c.extent + 0.5) * c.size
    c0, r0 = max(int(c0), 0), max(int(r0), 0)
    c1, r1 = min(int(c1) + 2, c.size), min(int(r1) + 2, c.size)
    if c0 >= c1 or r0 >= r1:
        return
    x, y = c.x[r0:r1, c0:c1] - p[0], c.y[r0:r1, c0:c1] - p[1]
    d = q - p
    t = np.clip((x * d[0] + y * d[1]) / max(float(d @ d), 1e-12), 0.0, 1.0)
    dist = np.hypot(x - t * d[0], y - t * d[1])
    cov = strength * smoothstep(half + 0.5 * c.px, half - 0.5 * c.px, dist)
    np.maximum(out[r0:r1, c0:c1], cov, out=out[r0:r1, c0:c1])


def headings_around(rng, n, jitter):
    """``n`` headings (radians) spread evenly round the circle from a random start, each
    off by a normal draw of ``jitter``: vessels leaving a point or crossing a dome."""
    return rng.uniform(0, 2 * np.pi) + np.arange(n) * 2 * np.pi / n + rng.normal(0, jitter, n)


def largest_piece(inside):
    """The largest connected piece of a bool grid with its holes filled (all False when
    there is none): one lesion's outline, without the specks and islets at its edge."""
    lab, count = ndimage.label(inside)
    if not count:
        return np.zeros_like(inside, dtype=bool)
    return ndimage.binary_fill_holes(lab == 1 + int(np.argmax(np.bincount(lab.ravel())[1:])))


def arrange(canvas, kind, n, spread_mm, min_gap_mm):
    """Centres (mm) of ``n`` lesions: grouped (a cluster), satellite (one big, small ones
    around), dermatomal (a band), widespread (over the whole grid)."""
    rng = canvas.rng
    pts = []
    for _ in range(50 * n):
        if len(pts) == n:
            break
        if kind == "grouped":
            p = rng.normal(0, spread_mm / 3, 2)
        elif kind == "satellite":
            a = rng.uniform(0, 2 * np.pi)
            p = (spread_mm * rng.uniform(0.5, 1.0)) * np.array([np.cos(a), np.sin(a)]) if pts else np.zeros(2)
        elif kind == "dermatomal":
            t = rng.uniform(-1, 1)
            p = np.array([t * spread_mm, 0.15 * spread_mm * np.sin(2 * t) + rng.normal(0, spread_mm * 0.08)])
        else:  # widespread
            p = rng.uniform(-spread_mm, spread_mm, 2)
        if all(np.hypot(*(p - q)) >= min_gap_mm for q in pts) and np.abs(p).max() < canvas.extent / 2:
            pts.append(p)
    return pts


# ---- composing a condition -------------------------------------------------------------------
# inflammatory erythema's texture (Builder.stippling): blotches and puncta, mm across
STIPPLE_BLOTCH_MM = 3.0
STIPPLE_DOT_MM = 0.35
INFLAMED = 0.8          # its strength in the dermatoses' erythema


def puncta_mm(mm_per_cell) -> float:
    """How far apart the stippling's puncta are drawn on a grid: STIPPLE_DOT_MM, or 1.5
    cells where the grid is too coarse to hold them."""
    return max(STIPPLE_DOT_MM, 1.5 * mm_per_cell)


class Builder:
    """Accumulates a condition's fields on a Canvas."""

    def __init__(self, canvas: Canvas):
        self.c = canvas
        n = canvas.size
        self.f = {k: np.full((n, n), v, np.float32) for k, v in NEUTRAL.items()}
        self.mask = np.zeros((n, n), bool)
        self.instances = np.zeros((n, n), np.uint16)
        self.spared = np.zeros((n, n), bool)    # skin inside a lesion that its outline leaves out
        self._cell_cache = {}
        self._stippling = None

    def weight(self, sd, border, kind="sharp"):
        """Coverage 0..1 from a signed distance: sharp (a pixel or two), ill-defined
        (fading over ``border`` mm), raised/rolled (sharp, handled by the caller)."""
        if kind == "ill-defined":
            return smoothstep(-border, border * 0.3, sd)
        return smoothstep(-max(self.c.px, 0.02 * border), max(self.c.px, 0.02 * border) + 0.05 * border, sd)

    def mix(self, name, w, value):
        self.f[name] = self.f[name] * (1 - w) + value * w

    def outline(self, w, threshold=0.35, instance=None):
        """Add where ``w`` > threshold to the mask, as a new instance (or ``instance``)."""
        m = w > threshold
        if not m.any():
            return 0
        k = instance or int(self.instances.max()) + 1
        self.instances[m & (self.instances == 0)] = k
        self.mask |= m
        return k

    def fields(self, extent, **kw) -> LesionFields:
        return LesionFields(self.f, self.mask, self.instances, extent, **kw)

    # secondary changes
    def erythema(self, w, amount, oxygen=0.8, stipple=0.0):
        """Dilated papillary vessels: ``amount`` x 10% blood volume added (negative:
        blanching, a factor on the skin's own blood). ``stipple`` (0..1) lays the added
        blood out as inflamed skin shows it up close (``stippling``), its mean kept."""
        if amount >= 0:
            if stipple > 0:
                w = w * (1 + stipple * (self.stippling() - 1))
            self.f["blood_add"] += w * amount * 0.1
        else:
            self.mix("blood", w, 1 + amount)
        self.mix("oxygen", w, oxygen)

    def stippling(self):
        """Mean-1 factor on an inflammatory erythema: seen up close, the redness of a
        dermatitis is not an even wash but blotches a few millimetres across (dermal
        vessel clusters) dotted with puncta a few tenths of a millimetre apart (the
        capillary loops of the dermal papillae and the vessels round follicles). One
        pattern per condition, so overlapping patches share it."""
        if self._stippling is None:
            c = self.c
            blotch = c.noise(STIPPLE_BLOTCH_MM, 2)
            dots = c.noise(puncta_mm(c.px), 1)
            factor = np.exp(0.35 * blotch) * (0.55 + 0.9 * smoothstep(0.0, 1.2, dots))
            self._stippling = (factor / factor.mean()).astype(np.float32)
        return self._stippling

    def scale(self, w, coverage, flake_mm, colour="white"):
        """Keratin flakes over ``w``: plates about ``flake_mm`` wide (a Voronoi
        tessellation), split by fine fissures through which the plaque shows. A plate is
        there or has shed; heavier ``coverage`` keeps more of them (a psoriatic plaque's
        scale is nearly continuous, light scale lies in scattered flakes), thicker plates
        are whiter, and their edges lift (height)."""
        c = self.c
        wall, thickness, plate = self.cells(flake_mm)     # plates, each its thickness
        # not every edge has split: fissures come and go along the plate edges
        split = smoothstep(-0.6, 0.4, c.noise(flake_mm * 0.8, 2))
        fissure = 1 - split * (1 - smoothstep(0.015, 0.07, wall))
        # whole areas of the plaque hold more or less scale, over several flakes
        keep = coverage * (0.75 + 0.5 * smoothstep(-1.2, 1.2, c.noise(flake_mm * 4, 2)))
        grain = 0.85 + 0.15 * c.noise(flake_mm * 0.25, 2)
        # scale sheds in patches a few plates wide, and thickens and thins smoothly across
        # the plaque; plate to plate it differs only a little (each plate its own
        # brightness, and single plates missing at random, read as confetti)
        area = smoothstep(-1.0, 1.0, c.noise(flake_mm * 2.5, 2))
        # which plates stay: ranked by their thickness and (mostly) the area they lie in,
        # so whole plates shed in patches; the ranks are uniform, as thickness alone is,
        # so that ``keep`` holds the same share of plates as before
        texels = np.maximum(np.bincount(plate.ravel()), 1)
        per_plate = (0.35 * np.bincount(plate.ravel(), thickness.ravel())
                     + 0.65 * np.bincount(plate.ravel(), area.ravel())) / texels
        held = (np.argsort(np.argsort(per_plate)) / max(len(per_plate) - 1, 1))[plate]
        # light scale is thin as well as sparse: its flakes are more translucent
        opacity = (0.55 + 0.2 * thickness + 0.2 * area) * (0.5 + 0.5 * coverage) * grain
        plates = smoothstep(0.0, 0.2, keep - (1 - held)) * opacity
        flakes = plates * fissure
        # between the plates, a thin powdery film: light scale whitens a plaque as a
        # haze with a few flakes on it, not as loose bright dots on bare red skin
        haze = (0.12 + 0.3 * coverage) * smoothstep(-1.5, 1.0, c.noise(flake_mm * 2, 2)) * grain
        self.f["scale"] = np.maximum(self.f["scale"], np.clip(w * np.maximum(flakes, haze), 0, 0.92))
        self.f["height"] += 0.12 * w * flakes * (0.6 + 0.4 * smoothstep(0.3, 0.05, wall))
        self.f["detail"] *= 1 - 0.6 * w * coverage
        return SCALE_COLOURS[colour]

    def cells(self, width_mm):
        """A tessellation of the grid into ragged cells ``width_mm`` wide (scale's
        plates, an ulcer's granules, a granuloma's lobules): each texel's distance to
        its cell's edge over the cell width, its cell's random value in [0, 1] and its
        cell's index. Made once per width for this condition."""
        key = round(float(width_mm), 4)
        if key not in self._cell_cache:
            from .detail import voronoi_walls
            c, n = self.c, self.c.size
            cell = max(width_mm / c.px, 1.5)                          # grid pixels per cell
            m = int(min(max((n / cell) ** 2, 4), 40000))
            sites = c.rng.uniform(0, n, (m, 2))
            # cell edges are ragged, not straight: the grid is warped by a sixth of a cell
            yy, xx = np.mgrid[0:n, 0:n] + 0.5
            warp = 0.15 * cell
            xx = xx + warp * noise(c.rng, n, cell, 2)
            yy = yy + warp * noise(c.rng, n, cell, 2)
            edge, i = voronoi_walls(sites, np.stack([xx.ravel(), yy.ravel()], 1))
            value = c.rng.random(m)[i]
            self._cell_cache[key] = ((edge / cell).reshape(n, n).astype(np.float32),
                                     value.reshape(n, n).astype(np.float32), i.reshape(n, n))
        return self._cell_cache[key]

    def crust(self, w, coverage, colour="honey", darken=1.0, lump_mm=None, thickness_mm=0.4):
        """Dried exudate over ``w``: lumps (``lump_mm`` across, default a twentieth of
        the grid) up to ``thickness_mm`` thick, whose colour darkens where they are thick
        or old (``crust_dark``, scaled by ``darken``), granular and rough rather than a
        flat coat of paint."""
        c = self.c
        lumps = smoothstep(-0.3, 0.8, c.noise(lump_mm or c.extent * 0.05, 3))
        grain = c.noise(max(0.12, c.extent * 0.008), 2)
        a = np.clip(w * coverage * lumps * (0.8 + 0.2 * smoothstep(-1, 1, grain)), 0, 1)
        self.f["crust"] = np.maximum(self.f["crust"], a)
        dark = np.clip(0.55 * lumps + 0.35 * c.noise(c.extent * 0.03, 2) + 0.15 * grain, 0, 1)
        self.f["crust_dark"] = np.maximum(self.f["crust_dark"], a * dark * darken)
        self.f["height"] += thickness_mm * a * (0.8 + 0.2 * grain)
        self.f["gloss"] = np.maximum(self.f["gloss"], 0.3 * a * smoothstep(0.2, 0.9, 1 - dark))
        return CRUST_COLOURS[colour]

    def erode(self, w, depth_mm=0.1):
        """Loss of the epidermis: the papillary dermis shows, its capillary loops close
        under the surface, so an erosion is raw red and moist, not the pale colour of
        a dermis without blood."""
        self.mix("epidermis", w, 0.0)
        self.f["blood_add"] += ERODED_BLOOD * w
        self.mix("oxygen", w, 0.85)
        self.f["melanin"] *= 1 - 0.8 * w
        self.f["height"] -= depth_mm * w
        self.f["gloss"] = np.maximum(self.f["gloss"], 0.5 * w)
        self.f["detail"] *= 1 - w


# ---- presets ------------------------------------------------------------------------------------
def _log_uniform(rng, lo, hi):
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


# a common naevus's nests of melanocytes: at the dermo-epidermal junction (flat), there
# and in the dermis (raised middle), or in the dermis alone (a dome that has lost most
# of its pigment: older adults' skin-coloured to light brown papules, on the face and
# trunk), with their shares and melanin added (log-uniform range)
NEVUS_TYPES = {"junctional": (0.4, (0.03, 0.25)), "compound": (0.35, (0.04, 0.3)),
               "intradermal": (0.25, (0.004, 0.04))}


def _nevus(b, rng, R):
    """A common acquired naevus: round, even, sharply bordered; tan to dark brown when
    junctional or compound, a skin-coloured to light brown dome when intradermal. Until
    2026-12-07 every naevus was mid to dark brown (L* 28-49 below type II skin)."""
    names = list(NEVUS_TYPES)
    kind = names[rng.choice(len(names), p=[NEVUS_TYPES[n][0] for n in names])]
    sd = b.c.shape("round", R, aspect=rng.uniform(0.8, 1.0), irregular=0.05, warp=0.03)
    w = b.weight(sd, R * 0.15)
    b.f["melanin_add"] += w * (0.85 + 0.15 * b.c.noise(R / 3, 2)) * _log_uniform(rng, *NEVUS_TYPES[kind][1])
    if kind == "compound":       # raised in the middle, a little dermal pigment
        b.f["height"] += rng.uniform(0.3, 1.0) * smoothstep(-R * 0.1, R * 0.8, sd)
        b.f["dermal_melanin"] += 0.01 * w
    elif kind == "intradermal":  # a soft dome, smoother than the skin round it
        b.f["height"] += min(rng.uniform(0.5, 1.5), 0.5 * R) * smoothstep(-R * 0.2, R * 0.9, sd)
        b.f["dermal_melanin"] += 0.005 * w
        b.f["detail"] *= 1 - 0.4 * w
    b.outline(w, 0.4)
    return {"type": kind}


def _melanoma(b, rng, R):
    """Superficial spreading or nodular melanoma: asymmetric, tan to black, variegated in
    zones (an eccentric darker area, paler ones, mottling of a few millimetres), with a
    coarse atypical network, dots, a blue-grey veil, erythema and regression; often
    raised. Its outline is a compact oval grown out unevenly into one or two eccentric
    lobes, notched at a finer scale; the border is abrupt in places and fades out in
    others. (Until 2026-12-01 it was one warped disc with strong radial harmonics, which
    drew petals, fingers and holes: an ink blot, in leopard spots. The flat, ill-defined
    lentigo maligna on sun-damaged skin is its own preset.)"""
    c = b.c
    sd = c.shape("round", R * 0.8, aspect=rng.uniform(0.65, 0.95), irregular=rng.uniform(0.05, 0.12),
                 warp=0.05)
    lobes = int(rng.integers(1, 3))
    for _ in range(lobes):
        t = rng.uniform(0, 2 * np.pi)
        off = R * rng.uniform(0.3, 0.5) * np.array([np.cos(t), np.sin(t)])
        lobe = c.shape("round", R * rng.uniform(0.4, 0.65), centre=off, aspect=rng.uniform(0.6, 1.0),
                       irregular=0.08, warp=0.05)
        sd = np.maximum(sd, lobe)
    n = c.noise(R / 6, 2)
    sd = sd + R * (0.02 * n + 0.06 * np.minimum(n, 0))       # notches more than bumps: no islands
    fade = smoothstep(-0.5, 1.2, c.noise(R / 1.5, 1)) * (rng.random() < 0.7)
    border = R * (0.03 + 0.25 * fade)                         # abrupt here, fading out there
    w = smoothstep(-border, 0.3 * border + c.px, sd)
    d = c.noise(R / 1.2, 2) + 1.0 * (c.x * rng.normal() + c.y * rng.normal()) / R   # zones, asymmetric
    fine = c.noise(max(0.6, R / 6), 2)
    net = 1 - smoothstep(0.0, 0.35, np.abs(c.noise(max(0.35, R / 25), 1)))
    dots = smoothstep(1.6, 2.3, c.noise(max(0.25, R / 40), 1)) * smoothstep(-0.5, 0.8, d)
    b.f["melanin_add"] += w * (0.08 + 0.4 * smoothstep(-1.2, 1.8, d + 0.35 * fine)
                               + 0.04 * net + 0.3 * dots)                            # tan/brown to black
    b.f["dermal_melanin"] += w * 0.015 * smoothstep(0.6, 1.8, c.noise(R / 2.5, 2))     # blue-grey veil
    b.erythema(w * smoothstep(0.5, 2.0, c.noise(R / 2.5, 2)), 1.5)
    regress = w * 0.7 * smoothstep(1.2, 2.4, c.noise(R / 2.5, 2))                      # regression
    b.mix("melanin_add", regress, 0.0)
    b.mix("melanin", regress, 0.6)
    b.f["height"] += rng.uniform(0.0, 0.8) * smoothstep(0, R, sd)
    # one lesion: the outline takes in its regressed (pale) areas, not specks at its edge
    main = largest_piece(w > 0.35)
    if main.any():
        b.outline(main.astype(np.float32), 0.5)
    return {"irregularity": "high", "lobes": lobes, "border_fades": bool(fade.max() > 0)}


def _lentigo_maligna(b, rng, R):
    """Lentigo maligna (melanoma in situ on chronically sun-damaged skin, and the solar
    lentigines it is mistaken for): a large flat macule, several centimetres, its outline
    a ragged coast that fades out in places; a tan stain mottled in shades up to mid
    brown, in blotches of a few millimetres to a centimetre that overlap unevenly,
    with skip areas of paler skin inside, faint flecks and rings round follicle openings
    (which stay pale), and grey where pigment has dropped into the dermis. Flat: the
    skin's markings run through it unchanged."""
    c = b.c
    sd = c.shape("round", R, aspect=rng.uniform(0.5, 0.9), irregular=rng.uniform(0.1, 0.25),
                 warp=rng.uniform(0.08, 0.2))
    fade = smoothstep(-1.0, 1.0, c.noise(R / 1.5, 2))            # where the border fades out
    w = b.weight(sd, R * (0.12 + 0.35 * fade), "ill-defined")
    blotch = smoothstep(-1.5, 2.2, c.noise(R / 3, 2) + 0.5 * c.noise(max(0.8, R / 8), 2))
    skip = 0.55 + 0.45 * smoothstep(-2.2, -0.6, c.noise(R / 4, 2))  # paler skin left inside
    # from a faint stain (the way it is most often missed) to mid brown; skip areas
    # keep at least 0.55 of the pigment (emptied, they read as round pale holes)
    base = rng.uniform(0.015, 0.06)
    dark = rng.uniform(0.04, 0.16)
    follicle = c.noise(max(0.3, R / 40), 1)                        # rings round follicles
    flecks = smoothstep(0.4, 1.0, follicle) * (1 - smoothstep(1.3, 1.7, follicle)) * blotch
    b.f["melanin_add"] += w * skip * (base + dark * blotch + 0.03 * flecks)
    grey = smoothstep(1.0, 2.0, c.noise(R / 4, 2)) * w
    b.f["dermal_melanin"] += 0.012 * grey
    b.outline(w * np.maximum(skip, 0.6), 0.35)
    return {"border": "ill-defined, fading in places"}


def _plaque(b, rng, R, shape, scale_colour, erythema, scale_cov, border="sharp", flake=1.5):
    c = b.c
    sd = c.shape(shape, R, aspect=rng.uniform(0.55, 1.0), irregular=0.15, warp=0.12,
                 width=R * rng.uniform(0.3, 0.5))
    w = b.weight(sd, R * 0.25, border)
    b.erythema(w * (0.8 + 0.2 * c.noise(R / 3, 2)), erythema, stipple=INFLAMED)
    b.f["height"] += rng.uniform(0.2, 0.6) * smoothstep(-R * 0.05, R * 0.2, sd)
    col = b.scale(w * smoothstep(0, R * 0.3, sd + R * 0.1), scale_cov, flake, scale_colour)
    b.f["melanin"] *= 1 + 0.5 * w      # post-inflammatory darkening shows on darker skin
    b.outline(w, 0.3)
    return col


def _psoriasis(b, rng, R):
    arrangement = rng.choice(["solitary", "grouped", "confluent"], p=[0.5, 0.3, 0.2])
    # from the thick silvery plates of untreated plaques on elbows and knees to the thin
    # scale of a treated or moisturised plaque, whose salmon-red shows through
    cover = rng.uniform(0.25, 1.0)
    if arrangement == "solitary":
        col = _plaque(b, rng, R, "oval", "silvery", rng.uniform(2.5, 4.5), scale_cov=cover)
    else:
        for p in arrange(b.c, "grouped", int(rng.integers(3, 9)), R * 1.2, R * 0.3):
            col = _plaque_at(b, rng, R * rng.uniform(0.25, 0.5), p, "silvery", rng.uniform(2.5, 4.5),
                             merge=arrangement == "confluent", scale_cov=cover)
    return {"scale": "silvery", "arrangement": str(arrangement), "scale_cover": round(float(cover), 3),
            "scale_rgb": col}


def _plaque_at(b, rng, r, centre, scale_colour, erythema, scale_cov, merge=False, border="sharp",
               flake=1.2):
    c = b.c
    sd = c.shape("oval", r, centre=centre, aspect=rng.uniform(0.6, 1.0), irregular=0.15, warp=0.1)
    w = b.weight(sd, r * 0.3, border)
    b.erythema(w, erythema, stipple=INFLAMED)
    # merging plaques make one plateau (their scale, added next, still piles up)
    b.f["height"] = np.maximum(b.f["height"], rng.uniform(0.2, 0.5) * smoothstep(-r * 0.05, r * 0.2, sd))
    col = b.scale(w * smoothstep(0, r * 0.3, sd + r * 0.1), scale_cov, flake, scale_colour)
    b.outline(w, 0.3, instance=1 if merge else None)
    return col


def _eczema(b, rng, R):
    c = b.c
    sd = c.shape("round", R, aspect=rng.uniform(0.5, 1.0), irregular=0.3, warp=0.25)
    w = b.weight(sd, R * 0.35, "ill-defined")
    w = w * (0.7 + 0.3 * c.noise(R / 4, 2))
    b.erythema(w, rng.uniform(1.5, 3.0), stipple=INFLAMED)
    # papulovesicles, excoriations, crust, fine scale, lichenified skin lines
    pap = smoothstep(0.5, 1.9, c.noise(max(0.4, R / 40), 1)) ** 2 * w   # domed, closely set
    b.f["height"] += 0.2 * pap
    b.erythema(pap, 2.0)
    b.scale(w, 0.12, 0.6, "white")
    # excoriations: short scratches, broken along their length, mostly under dark dried
    # blood (raw, orange-red erosions of even width read as sticks laid on the skin)
    broken = smoothstep(-0.3, 0.5, c.noise(max(0.5, R / 30), 1))
    for _ in range(int(rng.integers(0, 7))):
        centre = rng.uniform(-R, R, 2) * 0.6
        line = c.shape("linear", R * rng.uniform(0.04, 0.14), centre=centre,
                       width=max(0.25, R * rng.uniform(0.006, 0.012)), aspect=1.0)
        e = b.weight(line, 0.2) * w * broken
        b.erode(e, 0.03)
        b.crust(e, 1.0, "haemorrhagic")
        # a scratch is crusted along its length, not in the lumps of a weeping plaque
        b.f["crust"] = np.maximum(b.f["crust"], 0.9 * np.minimum(1.5 * e, 1.0))
        b.f["crust_dark"] = np.maximum(b.f["crust_dark"], 0.6 * e)
    if rng.random() < 0.5:
        b.f["detail"] *= 1 + 1.0 * w          # lichenification
        b.f["melanin"] *= 1 + 0.6 * w
    b.outline(w, 0.3)
    return {"crust_rgb": CRUST_COLOURS["haemorrhagic"], "scale_rgb": SCALE_COLOURS["white"]}


def _tinea(b, rng, R):
    c = b.c
    kind = "annular" if rng.random() < 0.7 else "arcuate"
    width = R * rng.uniform(0.12, 0.25)
    ring = c.shape(kind, R, aspect=rng.uniform(0.75, 1.0), irregular=0.12, warp=0.06, width=width)
    disc = c.shape("round", R + width / 2, irregular=0.0, warp=0.0, angle=0.0)
    w_ring = b.weight(ring, width * 0.8, "ill-defined")
    w_disc = b.weight(disc, width * 0.5)
    b.erythema(w_ring, rng.uniform(2.5, 4.0), stipple=INFLAMED)
    b.erythema(w_disc * 0.3, 0.6)                          # a clearer, faintly pink centre
    b.f["height"] += 0.15 * w_ring
    b.scale(w_ring, 0.6, 0.5, "white")
    b.f["melanin"] *= 1 + 0.4 * w_ring
    b.outline(np.maximum(w_ring, w_disc * 0.9), 0.5)      # the whole ring, centre included
    return {"shape": kind}


def _bcc(b, rng, R):
    """Basal cell carcinoma. Nodular (two thirds): a pearly, translucent dome whose skin
    is stretched smooth (its markings gone), with a rolled border, a slight central dell
    and fine arborising vessels on top, sometimes a crusted central ulcer. Superficial: a
    thin pink plaque with a thread-like raised edge and a little fine scale. Pearly is a
    soft sheen on a smooth surface, not a wet gloss."""
    c = b.c
    superficial = rng.random() < 0.35
    sd = c.shape("round", R, aspect=rng.uniform(0.6 if superficial else 0.75, 1.0),
                 irregular=0.2 if superficial else 0.08, warp=0.1 if superficial else 0.04)
    w = b.weight(sd, R * 0.1)
    # arborising vessels: a few trunks from near the edge across the top, forking and
    # tapering (until 2026-11-28 the zero lines of a noise: even-width meanders, a map's
    # rivers, that read as cracks)
    n = int(rng.integers(2, 6))
    around = headings_around(rng, n, 0.3)
    starts = R * rng.uniform(0.55, 0.85, (n, 1)) * np.stack([np.cos(around), np.sin(around)], 1)
    vessels = vessel_tree(c, starts, around + np.pi + rng.normal(0, 0.5, n),
                          rng.uniform(0.06, 0.12) if superficial else rng.uniform(0.1, 0.2),
                          R * rng.uniform(0.3, 0.5)) * w
    if superficial:
        b.erythema(w * (0.75 + 0.25 * c.noise(R / 3, 2)), rng.uniform(1.0, 2.0))
        thread = smoothstep(max(0.3, 1.5 * c.px), 0.0, np.abs(sd - R * 0.04)) * w
        b.f["height"] += 0.05 * w + 0.15 * thread
        b.scale(w, 0.15, 0.5, "white")
        b.erythema(vessels * 0.5, 3.0, 0.85)
        b.f["melanin"] *= 1 + 0.15 * w
        b.outline(w, 0.4)
        return {"subtype": "superficial"}
    height = rng.uniform(0.8, 2.0)
    dell = rng.uniform(0.15, 0.35)
    dome = smoothstep(-R * 0.05, R * 0.35, sd) * (1 - dell * smoothstep(R * 0.3, R * 0.9, sd))
    rim = smoothstep(R * 0.3, 0.0, np.abs(sd - R * 0.2)) * w                 # rolled border
    lobes = 1 + 0.08 * c.noise(R / 2.5, 2)             # not a turned dome: a light breaks up on it
    b.f["height"] += (height * dome + 0.3 * height * rim) * lobes
    b.f["gloss"] = np.maximum(b.f["gloss"], rng.uniform(0.2, 0.4) * w)
    b.f["detail"] *= 1 - 0.6 * w                                            # stretched smooth
    b.mix("melanin", w, rng.uniform(0.5, 0.9))                              # translucent, pale
    b.mix("scatter", w, rng.uniform(1.15, 1.4))                             # pearly
    b.erythema(w, rng.uniform(0.4, 1.0))
    b.erythema(vessels * smoothstep(0.0, R * 0.2, sd), 5.0, 0.85)           # telangiectasia
    ulcer = rng.random() < 0.4                                              # central ulcer
    if ulcer:
        core = b.weight(c.shape("round", R * rng.uniform(0.2, 0.45), irregular=0.2), R * 0.1)
        b.erode(core, 0.5)
        b.crust(core, 0.7, "haemorrhagic")
    b.outline(w, 0.4)
    return {"subtype": "nodular", "ulcer": ulcer, "crust_rgb": CRUST_COLOURS["haemorrhagic"]}


def _scc(b, rng, R):
    c = b.c
    sd = c.shape("round", R, aspect=rng.uniform(0.6, 1.0), irregular=0.25, warp=0.15)
    w = b.weight(sd, R * 0.3, "ill-defined" if rng.random() < 0.5 else "sharp")
    b.erythema(w, rng.uniform(2.0, 4.0))
    b.f["height"] += rng.uniform(0.5, 2.5) * smoothstep(-R * 0.1, R * 0.6, sd)
    b.scale(w * smoothstep(0, R * 0.5, sd), 0.9, 1.0, "white")          # keratotic
    core = b.weight(c.shape("round", R * rng.uniform(0.3, 0.6), irregular=0.3), R * 0.2)
    if rng.random() < 0.6:
        b.erode(core, 0.3)
        b.crust(core, 0.9, rng.choice(["haemorrhagic", "serous"]))
    b.outline(w, 0.35)
    return {}


def _seb_keratosis(b, rng, R):
    c = b.c
    sd = c.shape("oval", R, aspect=rng.uniform(0.6, 0.95), irregular=0.12, warp=0.06)
    w = b.weight(sd, R * 0.05)                                          # stuck-on: sharp
    mottle = 0.8 + 0.2 * c.noise(R / 4, 2)
    # light tan to dark brown, most of them mid brown (log-uniform: until 2026-12-07
    # 0.08-0.4, which made most of them black-brown, L* 17-30 on type II skin)
    level = _log_uniform(rng, 0.03, 0.3)
    b.f["melanin_add"] += w * mottle * level
    # a dull, papillomatous surface: winding ridges (~1 mm, "cerebriform") with darker
    # keratin packed in the fissures between them, keratin plugs, and a few small
    # milia-like cysts
    folds = np.abs(c.noise(max(0.5, R / 8), 2))
    # the fissures come and go and vary in width (until 2026-12-07 every zero line of
    # the noise was drawn dark, joined into a continuous black net, like cracked tar)
    open_ = smoothstep(-0.8, 0.6, c.noise(max(0.5, R / 5), 2))
    fissure = (1 - smoothstep(0.0, 0.15 + 0.2 * open_, folds)) * (0.3 + 0.7 * open_)
    b.f["height"] += w * (0.3 + 0.25 * smoothstep(0.0, 0.8, folds)) * rng.uniform(0.6, 1.2)
    # (the keratin there is as pigmented as the lesion, so a darker SK's fissures are
    # darker: a fixed amount was lost in a dark one's mottling)
    b.f["melanin_add"] += w * fissure * (rng.uniform(0.02, 0.05) + rng.uniform(0.4, 0.8) * level)
    plugs = smoothstep(1.9, 2.4, c.noise(max(0.3, R / 20), 1)) * w     # comedo-like openings
    b.f["melanin_add"] += (0.1 + level) * plugs
    b.f["detail"] *= 1 + 0.3 * w
    cysts = smoothstep(1.8, 2.4, c.noise(max(0.25, R / 25), 1)) * w     # milia-like cysts
    b.scale(cysts, 0.6, 0.3, "white")
    b.outline(w, 0.4)
    return {}


def _acne(b, rng, R):
    """Acne vulgaris: inflamed papules and pustules, now and then a nodule, scattered
    among comedones and the flat marks that healed lesions leave: pink on light skin
    (post-inflammatory erythema), brown and lasting on darker skin (post-inflammatory
    hyperpigmentation). A dermatologist outlines the inflamed lesions, each its own
    instance; comedones and marks stay skin. Until 2026-11-29 every lesion was the same
    red dome, two in five with a tan plate of scale for a head, on otherwise clear skin."""
    c = b.c
    kinds = []
    for p in arrange(c, "widespread", int(rng.integers(6, 25)), R, R * 0.1):
        kind = str(rng.choice(["papule", "pustule", "nodule"], p=[0.55, 0.35, 0.1]))
        r = rng.uniform(2.5, 4.5) if kind == "nodule" else rng.uniform(0.8, 2.2)
        sd = c.shape("round", r, centre=p, irregular=0.08, warp=0.02)
        w = b.weight(sd, r * 0.6, "ill-defined")
        if kind == "nodule":          # deep in the dermis: broad, dusky red, taut and smooth
            b.erythema(w, rng.uniform(3.0, 5.0), oxygen=rng.uniform(0.55, 0.7))
            b.f["height"] = np.maximum(b.f["height"], rng.uniform(0.8, 1.5) * smoothstep(-r * 0.3, r * 0.8, sd))
            b.f["detail"] *= 1 - 0.5 * w
            b.f["gloss"] = np.maximum(b.f["gloss"], 0.15 * w)
        else:
            b.erythema(w, rng.uniform(2.0, 4.5))
            b.f["height"] = np.maximum(b.f["height"], rng.uniform(0.3, 0.9) * smoothstep(-r * 0.3, r * 0.6, sd))
        if kind == "pustule":         # a yellow-white head of pus under a thin, tense roof
            head = b.weight(c.shape("round", r * rng.uniform(0.3, 0.5), centre=p, irregular=0.05, warp=0.0),
                            r * 0.35, "ill-defined")
            b.f["blood_add"] *= 1 - 0.6 * head
            b.f["scale"] = np.maximum(b.f["scale"], rng.uniform(0.45, 0.75) * head)
            b.f["gloss"] = np.maximum(b.f["gloss"], 0.4 * head)
        b.outline(w, 0.45)
        kinds.append(kind)
    # comedones, unlabelled: open ones a dark keratin plug in a pore, closed ones a small
    # whitish bump
    pts = arrange(c, "widespread", int(rng.integers(5, 40)), R, 0.6)
    comedones = len(pts)
    if pts:
        open_ = rng.random(len(pts)) < 0.5
        radii = np.where(open_, rng.uniform(0.12, 0.3, len(pts)), rng.uniform(0.3, 0.6, len(pts)))
        sd, index = spots(c, pts, radii, irregular=0.1)
        # (index -1, no comedo near: sd there is far below the fade, so dot is 0)
        dot = smoothstep(-0.3, 0.3, sd / radii[index].astype(np.float32))
        is_open = open_[index]
        b.f["melanin_add"] += np.where(is_open, rng.uniform(0.25, 0.45) * dot, 0)
        closed = np.where(is_open, 0, dot)
        b.mix("scatter", closed, 1.25)
        b.f["height"] = np.maximum(b.f["height"], 0.15 * closed)
    # healed lesions' flat marks, unlabelled: redness (shows on light skin) and melanin
    # (in proportion to the skin's own, so it shows most on darker skin)
    pts = arrange(c, "widespread", int(rng.integers(2, 12)), R, 2.0)
    if pts:
        radii = rng.uniform(0.8, 2.0, len(pts))
        sd, index = spots(c, pts, radii, irregular=0.2)
        mark = smoothstep(-0.4, 0.4, sd / radii[index].astype(np.float32))
        b.erythema(mark, rng.uniform(0.5, 1.5))
        b.f["melanin"] *= 1 + rng.uniform(0.15, 0.5) * mark
    return {"scale_rgb": SCALE_COLOURS["pus"], "arrangement": "widespread",
            "papules": kinds.count("papule"), "pustules": kinds.count("pustule"),
            "nodules": kinds.count("nodule"), "comedones": comedones}


def _urticaria(b, rng, R):
    c = b.c
    for p in arrange(c, "widespread", int(rng.integers(2, 7)), R * 0.9, R * 0.35):
        r = R * rng.uniform(0.2, 0.45)
        kind = rng.choice(["round", "annular", "serpiginous"], p=[0.5, 0.3, 0.2])
        sd = c.shape(str(kind), r, centre=p, irregular=0.3, warp=0.2, width=r * 0.5)
        flare = b.weight(sd, r * 0.4, "ill-defined")
        # the wheal lies inside the flare; a ring or band (half as wide as the shape) has
        # less room for the margin than a round one
        inset = r * (0.15 if kind == "round" else 0.05)
        wheal = b.weight(sd - inset, r * 0.1)
        b.erythema(flare, 2.5)
        b.erythema(wheal, -0.3)                                          # pale, oedematous centre
        # oedema swells the wheal as a smooth dome, taut and a little shiny (a plateau
        # with a step at its edge showed only its outline, where the flare is hidden by
        # melanin)
        dome = smoothstep(-0.1 * r, 0.5 * r, sd - inset)
        b.f["height"] = np.maximum(b.f["height"], 0.5 * dome)           # merging wheals: one swelling
        b.f["detail"] *= 1 - 0.5 * wheal
        b.f["gloss"] = np.maximum(b.f["gloss"], 0.15 * dome)
        b.outline(flare, 0.4)
    return {"arrangement": "widespread"}


def _vitiligo(b, rng, R):
    """Depigmented patches, milky white with the pink of the blood beneath (stark on
    dark skin), their borders sharp and scalloped; some with a tan middle zone at the
    edge (trichrome), some repigmenting from the follicles in dots. The outline is the
    whole patch, islands included, as a dermatologist draws it."""
    c = b.c
    sd = c.shape("round", R, aspect=rng.uniform(0.5, 1.0), irregular=0.2, warp=0.15)
    w = b.weight(sd, R * 0.05)
    lost = w
    trichrome = rng.random() < 0.25
    if trichrome:                                                       # a tan band inside the edge
        band = R * rng.uniform(0.05, 0.12)
        lost = w * (0.45 + 0.55 * smoothstep(0.0, band, sd - band))
    repigmenting = rng.random() < 0.35
    if repigmenting:                                                    # perifollicular islands
        lo = rng.uniform(1.2, 1.7)
        lost = lost * (1 - smoothstep(lo, lo + 0.5, c.noise(max(0.5, R / 20), 1)))
    b.mix("melanin", lost, rng.uniform(0.0, 0.04))   # amelanotic: up to 0.12 left type VI skin tan
    b.erythema(lost, rng.uniform(0.1, 0.3))         # the dermis' blood shows without melanin
    # a warped outline can pinch off islands of normal skin; they lie inside the patch
    # a dermatologist draws, so they are part of its mask
    b.outline(ndimage.binary_fill_holes(w > 0.5).astype(np.float32), 0.5)
    return {"trichrome": trichrome, "repigmenting": repigmenting}


def _pityriasis_rosea(b, rng, R):
    """A herald patch (an oval a quarter to two fifths of the extent across, at the
    centre) and, days later, smaller daughter ovals along the skin's tension lines.
    Each is salmon at its edge, its centre paler and finely wrinkled, a thin collarette
    of scale just inside the edge facing inwards; on pigmented skin they read
    grey-brown (a little more melanin)."""
    c = b.c
    axis = rng.uniform(0, np.pi)
    r_herald = R * rng.uniform(0.25, 0.4)
    # (radius, signed distance) of each oval: the herald, then daughters spread over the
    # region clear of it
    ovals = [(r_herald, c.shape("oval", r_herald, aspect=rng.uniform(0.55, 0.8),
                                irregular=0.05, warp=0.03))]
    for p in arrange(c, "widespread", int(rng.integers(6, 16)), R, R * 0.18):
        if np.hypot(*p) > 1.6 * r_herald:
            r = R * rng.uniform(0.06, 0.14)
            ovals.append((r, c.shape("oval", r, centre=p, aspect=0.55, angle=axis,
                                     irregular=0.05, warp=0.03)))
    salmon = rng.uniform(1.2, 2.2)
    for r, sd in ovals:
        w = b.weight(sd, r * 0.2, "ill-defined")
        # the edge is the reddest; the centre clears towards the skin's own colour
        ring = 1 - 0.75 * smoothstep(r * 0.1, r * 0.55, sd)
        b.erythema(w * ring, salmon, 0.95, stipple=INFLAMED)
        b.f["melanin"] *= 1 + 0.2 * w
        # a fine collarette just inside the edge, free towards the centre: a thin
        # translucent rim, not flakes (at this size they were a speckle of dots)
        # (a millimetre or two wide on a herald patch, broken in places)
        collar = smoothstep(r * 0.06, 0.0, np.abs(sd - r * 0.1)) * w
        b.f["scale"] = np.maximum(b.f["scale"], 0.2 * collar * smoothstep(-1.0, 0.5, c.noise(r / 3, 1)))
        b.f["detail"] *= 1 - 0.3 * collar
        b.outline(w, 0.4)
    return {"arrangement": "widespread", "herald_mm": round(float(2 * r_herald), 1),
            "daughters": len(ovals) - 1}


def _ulcer(b, rng, R):
    """An ulcer: epidermis and upper dermis lost down to a bed below the skin, reached by
    a wall, its floor granulation tissue under patches of slough. Three kinds, as
    photographed: venous (shallow, a sloping wall, round it haemosiderin staining in
    patches), pressure or traumatic (deeper, its rim often macerated white) and
    pyoderma gangrenosum (punched out, with a violaceous, undermined border).
    Granulation is a cobblestone of moist domed granules a fraction of a millimetre to
    a millimetre across (each a tuft of capillary loops: bright red on top, darker and
    bluer in the clefts), in zones from beefy red to dusky maroon; slough is yellow-white
    fibrin laid over the floor in patches, sometimes over most of it; some ulcers carry
    black eschar."""
    c = b.c
    kind = ("venous", "pressure", "pyoderma")[int(rng.choice(3, p=[0.45, 0.3, 0.25]))]
    sd = c.shape("round", R, aspect=rng.uniform(0.6, 1.0), irregular=0.12, warp=0.06)
    w_peri = b.weight(sd + R * 0.25, R * 0.2, "ill-defined")
    bed = b.weight(sd, R * 0.05)
    depth, slope = {"venous": (rng.uniform(0.3, 1.0), rng.uniform(0.15, 0.35)),
                    "pressure": (rng.uniform(0.8, 2.5), rng.uniform(0.06, 0.2)),
                    "pyoderma": (rng.uniform(1.0, 3.0), rng.uniform(0.02, 0.06))}[kind]
    b.erythema(w_peri, rng.uniform(0.4, 1.5), stipple=INFLAMED)  # from a faint pink rim to cellulitis red
    # periwound darkening, in patches: a uniform 1.8x band left type VI skin a slate ring
    # (L* 14, chroma 10 round skin at 27 and 27), where dark skin round a real ulcer is a
    # few L* darker and keeps its colour
    patches = smoothstep(-1.0, 1.0, c.noise(R / 3, 2))
    b.f["melanin"] *= 1 + 0.5 * w_peri * (1 - bed) * (0.3 + 0.7 * patches)
    if kind == "venous":      # haemosiderin from leaking venules: brown, blotchy, wider
        stain = b.weight(sd + R * 0.6, R * 0.4, "ill-defined") * (1 - bed)
        b.f["dermal_melanin"] += stain * smoothstep(-0.5, 1.0, c.noise(R / 2, 2)) * rng.uniform(0.002, 0.008)
    if kind == "pyoderma":    # a raised dusky violet border over the undermined edge
        border = smoothstep(R * rng.uniform(0.1, 0.25), 0.0, np.abs(sd + R * 0.05)) * (1 - bed)
        b.erythema(border, rng.uniform(2.0, 3.5), oxygen=rng.uniform(0.4, 0.55))
        b.f["height"] += 0.3 * border
    b.erode(bed, 0.0)
    floor = smoothstep(0.0, slope * R, sd)           # the wall down to the floor
    b.f["height"] -= depth * floor
    # granulation on the floor
    cell = max(float(np.clip(R / 25, 0.3, 1.0)), 3 * c.px)
    wall, tuft, _ = b.cells(cell)
    granule = np.sqrt(smoothstep(0.0, 0.45, wall)) * (0.7 + 0.3 * tuft)
    dusky = smoothstep(-0.2, 1.2, c.noise(R / 2.5, 2)) * rng.uniform(0.3, 1.0)
    on_floor = bed * floor
    b.f["blood_add"] += bed * (0.4 - ERODED_BLOOD + 0.2 * dusky) + on_floor * 0.3 * (granule - 0.5)
    b.mix("oxygen", bed, 0.8 - 0.25 * (1 - granule * floor) - 0.4 * dusky)
    b.mix("scatter", bed, rng.uniform(0.15, 0.4))                        # new vessels, little collagen
    b.f["height"] += on_floor * min(0.3 * cell, 0.25 * depth) * granule   # the floor stays below the skin
    # zones of pale, poorly granulating tissue (fewer new vessels, more collagen): pink,
    # not beefy red
    pale = smoothstep(-0.3, 1.2, c.noise(R / 3, 2)) * rng.uniform(0.0, 0.8) * (1 - dusky)
    b.f["blood_add"] -= on_floor * 0.2 * pale
    b.mix("scatter", on_floor * pale, 0.7)
    # a thin film of fibrin and exudate over much of the bed, through which only the
    # granules' red tops show: a granulating bed photographs as red dots on a pale pink
    # to cream ground, not as a coat of red paint
    filmy = rng.uniform(-0.8, 0.6)                                      # how much of the bed
    film = smoothstep(filmy - 0.8, filmy + 0.8, 0.7 * c.noise(R / 5, 2) + 0.6 * c.noise(R / 15, 1))
    film *= on_floor * rng.uniform(0.3, 0.6) * (1 - 0.85 * smoothstep(0.75, 1.0, granule))
    b.f["scale"] = np.maximum(b.f["scale"], film)      # (cream-white: SCALE_COLOURS["fibrin"])
    # new epithelium creeping in from the edge: a pink, shiny band where the epidermis
    # is thin again and the granulation beneath shows through it
    margin = bed * (1 - smoothstep(0.0, rng.uniform(0.06, 0.2) * R, sd)) * rng.uniform(0.0, 1.0)
    b.mix("epidermis", margin, 0.35)
    b.f["blood_add"] -= margin * 0.3
    if kind != "pyoderma" and rng.random() < 0.6:  # macerated: soggy white skin round the edge
        rim = smoothstep(-R * rng.uniform(0.08, 0.2), -R * 0.01, sd) * (1 - bed)
        soggy = rim * smoothstep(-0.8, 0.6, c.noise(R / 4, 2))
        b.f["scale"] = np.maximum(b.f["scale"], rng.uniform(0.4, 0.75) * soggy)
        b.f["detail"] *= 1 - 0.5 * soggy
        b.f["gloss"] = np.maximum(b.f["gloss"], 0.3 * soggy)
    sloughy = rng.uniform(-0.6, 0.8)                                    # how much of the floor
    # (its edge ragged at two scales: slough tears and lifts in strands, it does not lie
    # in smooth-edged pools)
    slough = smoothstep(sloughy, sloughy + 0.6, c.noise(R / 2.5, 2) + 0.45 * c.noise(R / 10, 2)) * on_floor
    b.crust(slough, rng.uniform(0.6, 1.0), "slough", darken=0.3, lump_mm=R * 0.2,
            thickness_mm=0.2 * depth)
    b.f["gloss"] = np.maximum(b.f["gloss"], 0.6 * bed)                  # wet
    if rng.random() < 0.3:
        eschar = smoothstep(0.8, 1.8, c.noise(R / 2, 2)) * on_floor
        b.crust(eschar, 1.0, "haemorrhagic")
    b.outline(np.maximum(bed, 0.45 * w_peri), 0.4)
    # slough from yellow to the grey-white of wet fibrin, which covers a bed in sheets
    fibrinous = rng.uniform(0.0, 1.0)
    slough_rgb = np.rint(np.array(CRUST_COLOURS["slough"]) + fibrinous * (np.array(FIBRIN_GREY)
                                                                          - CRUST_COLOURS["slough"]))
    return {"kind": kind, "crust_rgb": tuple(int(v) for v in slough_rgb), "scale_rgb": SCALE_COLOURS["fibrin"],
            "fibrinous": round(float(fibrinous), 3)}


def _lupus(b, rng, R):
    """Discoid lupus: an active rim, raised, violaceous red and darkened by melanin (near
    black on brown skin), carrying adherent scale, around a scarred centre: atrophic,
    depigmented, faintly shiny, with islands of pigment left in it, fine vessels and
    follicular plugs (keratin in dilated follicle openings: white dots a few tenths of a
    millimetre across, a millimetre or two apart) in the active border; the scar has
    lost most of its follicles (scarring alopecia), so few plugs sit there."""
    c = b.c
    sd = c.shape("round", R, aspect=rng.uniform(0.6, 1.0), irregular=0.25, warp=0.15)
    w = b.weight(sd, R * 0.2, "ill-defined")
    centre = smoothstep(0, R * rng.uniform(0.4, 0.7), sd)
    rim = w * (1 - centre)
    # how burnt out the centre is: in an active lesion it stays red; an old one's scar is
    # fibrosed (dense collagen scatters: ivory to porcelain white) with little blood left
    scarred = rng.uniform(0.0, 1.0)
    b.erythema(w * (1 - centre * (0.4 + 0.45 * scarred)), rng.uniform(2.0, 3.5), oxygen=rng.uniform(0.55, 0.7),
               stipple=INFLAMED)
    b.mix("scatter", w * centre, 1 + 0.35 * scarred)
    b.mix("melanin", rim, rng.uniform(1.5, 2.2))                         # hyperpigmented rim
    # pigment left in the scar: islands, never most of it (a plain noise threshold could
    # cover a small centre whole), so the threshold is the noise's 60th centile there
    n_res = c.noise(R * 0.35, 2)
    lo = np.percentile(n_res[centre > 0.5], 60) if (centre > 0.5).any() else 0.4
    residual = smoothstep(lo, lo + 0.6, n_res)
    b.mix("melanin", centre * (1 - 0.8 * residual), rng.uniform(0.02, 0.15))  # depigmented scar
    vessels = (1 - smoothstep(0.0, 0.06, np.abs(c.noise(max(0.6, R / 12), 2)))) * centre
    b.f["blood_add"] += 0.12 * vessels
    b.f["detail"] *= 1 - 0.7 * centre                                    # atrophy: smooth, shiny
    b.f["gloss"] = np.maximum(b.f["gloss"], 0.25 * centre)
    b.f["height"] += 0.12 * rim - 0.1 * centre
    b.scale(rim, 0.28, 0.5, "white")                                     # adherent, on the rim
    gap = rng.uniform(1.0, 2.0)
    n = int(np.clip((2 * R / gap) ** 2, 8, 400))
    plugs = arrange(c, "widespread", n, R, gap * 0.45)                 # irregularly spaced
    if plugs:
        radii = np.full(len(plugs), max(0.15, 0.8 * c.px)) * rng.uniform(0.8, 1.3, len(plugs))
        plug_sd, owner = spots(c, plugs, radii)
        # the scar keeps about a seventh of its follicles, chosen at random
        kept = np.append(rng.random(len(plugs)) < 0.15, False)[owner]     # (owner -1: none)
        dots = smoothstep(-c.px, c.px, plug_sd) * w * np.where(kept, 1.0, 1 - centre)
        b.f["scale"] = np.maximum(b.f["scale"], 0.6 * dots)
        b.f["height"] += 0.05 * dots
    b.outline(w, 0.35)
    return {"follicular_plugs": len(plugs), "scarred": round(float(scarred), 3)}


def _pyogenic_granuloma(b, rng, R):
    """Pyogenic granuloma (lobular capillary haemangioma): a domed, friable papule,
    crimson to raspberry (much blood, little collagen to scatter), moist and glistening:
    its epidermis is stretched thin, so the skin's markings are gone from it, and it is
    eroded in places, sometimes under dark dried blood. Its surface is granular, as
    granulation tissue is: capillary lobules a few tenths of a millimetre across bulge
    under it, each its own red, so a flash glints on many of them instead of leaving one
    highlight on a smooth dome. Three in five are lobulated into two to four lobes
    parted by pale fibrous septa; half have a collarette of scale round part of the
    base."""
    c = b.c
    sd = c.shape("round", R, aspect=rng.uniform(0.8, 1.0), irregular=0.08, warp=0.0)
    w = b.weight(sd, R * 0.08)
    s = np.clip(sd / R, 0.0, 1.0)
    # lobes: each its own shade from crimson to dark raspberry (its vessels more or less
    # full and oxygenated), parted by shallow clefts along pale septa of collagen (deep
    # folds between smooth lobes, until 2026-12-08, read as a rubber balloon; narrow
    # clefts with the skin's markings on them, until 2026-11-29, as a wax seal).
    # Unlobulated ones vary in shade smoothly
    lobulated = rng.random() < 0.6
    if lobulated:
        wall, shade, _ = b.cells(R * rng.uniform(0.9, 1.4))
        dimple = (1 - smoothstep(0.0, 0.3, wall)) * rng.uniform(0.3, 0.6)
        septa = (1 - smoothstep(0.0, 0.04, wall)) * rng.uniform(0.15, 0.35)
    else:
        dimple, shade = np.zeros_like(s), smoothstep(-1.0, 1.0, c.noise(R * 0.7, 1))
        septa = np.zeros_like(s)
    # granules: capillary lobules 0.3-0.8 mm across bulging as low rounded lumps, the
    # fuller ones redder
    gran_mm = float(np.clip(R * rng.uniform(0.06, 0.12), 0.3, 0.8))
    granule = smoothstep(-0.5, 1.2, c.noise(gran_mm, 1))
    gran_fill = smoothstep(-1.0, 1.0, 0.6 * c.noise(gran_mm, 1) + 0.8 * granule - 0.4)
    granular_blood = (0.8 + 0.4 * gran_fill) * (0.85 + 0.15 * granule)
    raw = smoothstep(-0.4, 0.6, c.noise(R * 0.4, 2)) * rng.uniform(0.5, 1.0)   # eroded surface
    b.mix("epidermis", w, rng.uniform(0.3, 0.6))               # stretched thin over the dome
    b.erode(w * raw, 0.0)
    b.f["blood_add"] += w * ((rng.uniform(0.45, 0.75) - ERODED_BLOOD * raw) * (0.75 + 0.5 * shade)
                             * (1 + 0.2 * dimple) * (1 - 0.6 * septa) * granular_blood)
    b.mix("oxygen", w, rng.uniform(0.8, 0.92) - 0.35 * shade * rng.uniform(0.4, 1.0) - 0.1 * dimple
          + 0.1 * (gran_fill - 0.5))
    b.mix("scatter", w, rng.uniform(0.08, 0.2) + 0.6 * septa)   # vessels, little collagen
    b.f["melanin"] *= 1 - 0.8 * w                              # the epidermis over it is thin
    b.f["detail"] *= 1 - 0.85 * w                              # stretched smooth
    dome = np.sqrt(s * (2 - s)) - 0.15 * dimple * s
    bumps = rng.uniform(0.03, 0.07) * granule                               # mm
    b.f["height"] += w * (rng.uniform(0.5, 0.9) * R * dome + bumps * smoothstep(0.05, 0.3, s))
    b.f["gloss"] = np.maximum(b.f["gloss"], w * (0.35 + 0.4 * raw))
    if rng.random() < 0.4:                                     # friable: it has bled
        spot = smoothstep(0.6, 1.2, c.noise(R * 0.8, 1)) * w     # a dark clot or two
        b.crust(spot, 1.0, "haemorrhagic")
    collarette = rng.random() < 0.5
    if collarette:   # scale lifted round the base, missing over part of it
        rim = smoothstep(R * 0.1, 0, np.abs(sd + R * 0.04)) * smoothstep(-0.6, 0.4, c.noise(R * 0.5, 1))
        b.scale(rim, 0.5, 0.25, "white")
    b.outline(w, 0.4)
    return {"crust_rgb": CRUST_COLOURS["haemorrhagic"], "collarette": collarette,
            "lobulated": lobulated}


def _purpura(b, rng, R):
    """Blood outside the vessels, so it does not blanch: petechiae (pinpoint red-purple
    dots, in crops), palpable purpura (small raised papules of small-vessel vasculitis,
    grouped, some merging, a few with a dusky or crusted centre) or an ecchymosis (a
    bruise: blue-purple where fresh, fading through brown to bilirubin yellow from its
    edge inwards as it ages). The blood lies deeper and is spent of oxygen, so it reads
    purple, not the pink of erythema."""
    c = b.c
    kind = str(rng.choice(["petechiae", "palpable", "ecchymosis"], p=[0.3, 0.35, 0.35]))
    if kind == "ecchymosis":
        sd = c.shape("round", R, aspect=rng.uniform(0.5, 1.0), irregular=0.35, warp=0.3)
        w = b.weight(sd, R * 0.45, "ill-defined")
        age = rng.uniform(0, 1)                                          # fresh -> fading
        # the bruise clears from its edge: old blood (and its breakdown) is left at the rim
        core = smoothstep(-0.2, 1.0, sd / R + 0.4 * c.noise(R / 2, 2) - 0.45 * age)
        blood = w * (0.15 + 0.35 * core) * (1 - 0.5 * age)
        b.f["blood_add"] += blood
        b.mix("oxygen", w, 0.2)
        b.mix("scatter", w * core, rng.uniform(0.35, 0.6))
        # macrophages break the blood down where it lies thin, so bilirubin yellow and
        # haemosiderin brown gather at the rim while the thick core stays blue-purple
        rim = w * (1 - core) ** 2
        b.f["bilirubin"] += rim * 0.35 * age
        b.f["dermal_melanin"] += rim * 0.006 * age
        b.outline(w, 0.4)
        return {"kind": kind, "age": round(float(age), 2)}
    # spots a few radii apart, denser in some crops than others
    r_lo, r_hi = (0.25, 1.0) if kind == "petechiae" else (0.6, 2.5)
    confluent = kind == "palpable" and rng.random() < 0.4               # papules run together
    fill = rng.uniform(0.3, 0.6) if confluent else rng.uniform(0.08, 0.3)
    n = int(np.clip(fill * (R / (0.5 * (r_lo + r_hi))) ** 2, 4, 200))
    centres = arrange(c, "grouped", n, R * 1.1, r_lo * 1.5)
    radii = rng.uniform(r_lo, r_hi, len(centres))
    if kind == "petechiae" and len(centres) > 1:                        # pinpoints stay apart
        pts = np.array(centres)
        gap = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
        np.fill_diagonal(gap, np.inf)
        radii = np.minimum(radii, 0.4 * gap.min(1))            # at most 0.4 of the nearest gap
    sd, index = spots(c, centres, radii)
    r = radii[index].astype(np.float32)            # each cell's own spot (index -1 is harmless:
    w = b.weight(sd, r * 0.4, "ill-defined")       # sd there is far below the fade)
    per_spot = lambda lo, hi: rng.uniform(lo, hi, len(centres)).astype(np.float32)[index]
    b.f["blood_add"] += w * per_spot(0.35, 0.7)
    b.mix("oxygen", w, per_spot(0.3, 0.55))
    b.mix("scatter", w, per_spot(0.3, 0.6))
    if kind == "palpable":
        b.f["height"] += per_spot(0.1, 0.3) * smoothstep(-0.2, 0.6, sd / r)
        necrotic = per_spot(0, 1) < 0.15                                # a dusky, crusted centre
        b.crust(smoothstep(0.5, 0.65, sd / r) * necrotic, 0.9, "haemorrhagic")
    b.outline(w, 0.4)
    return {"kind": kind, "arrangement": "confluent" if confluent else "grouped",
            "crust_rgb": CRUST_COLOURS["haemorrhagic"]}


def _morphea(b, rng, R):
    """Localized scleroderma. Active: an oval indurated plaque, ivory and shiny where
    collagen has replaced the dermis (little blood, skin markings lost), pale or darker on
    pigmented skin, often inside a lilac (poorly oxygenated) inflammatory ring. Burnt out
    (atrophoderma): a brown patch, a little depressed, its edge dropping like a cliff,
    the skin's markings kept: the pigment the inflammation left behind."""
    c = b.c
    sd = c.shape("round", R, aspect=rng.uniform(0.45, 0.9), irregular=0.2, warp=0.15)
    if rng.random() < 0.35:
        w = b.weight(sd, R * 0.15, "ill-defined")
        b.f["melanin_add"] += w * rng.uniform(0.05, 0.12) * (0.85 + 0.15 * c.noise(R / 3, 2))
        b.f["dermal_melanin"] += w * rng.uniform(0.0, 0.006)                # grey-brown
        b.f["height"] -= rng.uniform(0.05, 0.15) * smoothstep(0.0, R * 0.1, sd)
        b.f["gloss"] = np.maximum(b.f["gloss"], 0.1 * w)
        b.outline(w, 0.4)
        return {"stage": "burnt-out"}
    w = b.weight(sd, R * 0.12, "ill-defined")
    core = smoothstep(0.0, R * 0.35, sd)
    b.erythema(core, -rng.uniform(0.5, 0.75))                            # blanched
    b.f["bilirubin"] += 0.06 * core                                      # ivory, faintly yellow
    b.mix("melanin", core, rng.uniform(0.55, 0.85) if rng.random() < 0.7 else rng.uniform(1.3, 1.8))
    b.f["detail"] *= 1 - 0.75 * core                                     # bound-down, smooth
    b.f["gloss"] = np.maximum(b.f["gloss"], 0.2 * core)
    b.f["height"] += rng.uniform(-0.1, 0.15) * core
    if rng.random() < 0.7:                                               # active lilac border
        ring = smoothstep(R * 0.45, 0.0, np.abs(sd - R * 0.05)) ** 2 * w
        b.erythema(ring, rng.uniform(0.8, 1.8), oxygen=0.5)
    b.outline(w, 0.4)
    return {"stage": "active"}


def _porokeratosis(b, rng, R):
    """Disseminated superficial actinic porokeratosis: many small rings, each a thin
    raised keratotic ridge (the cornoid lamella, brownish) round a slightly atrophic,
    pale or pink-brown centre, on sun-damaged skin."""
    c = b.c
    # mostly apart, some touching (with the old gap of 0.08 R, close-ups showed crowds of
    # overlapping rings, a stained-glass window)
    for p in arrange(c, "widespread", int(rng.integers(10, 35)), R, max(R * 0.08, 7.0)):
        r = rng.uniform(1.5, 4.5)
        sd = c.shape("round", r, centre=p, aspect=rng.uniform(0.7, 1.0), irregular=0.15, warp=0.1)
        disc = b.weight(sd, r * 0.1)
        # the cornoid lamella: a thread ~0.3 mm wide, brown (0.7 mm and 2.6x the melanin
        # drew a bold dark outline round each ring up close)
        ridge = smoothstep(max(0.15, 1.5 * c.px), 0.0, np.abs(sd))
        inner = smoothstep(0.0, r * 0.3, sd)
        b.f["detail"] *= 1 - 0.5 * inner
        if rng.random() < 0.5:
            b.f["melanin"] *= 1 + 0.25 * inner                           # pink-brown centre
            b.erythema(inner, 0.8)
        else:
            b.mix("melanin", inner, 0.7)                                 # pale centre
        b.f["melanin"] *= 1 + 1.0 * ridge
        b.f["height"] += 0.15 * ridge
        b.f["scale"] = np.maximum(b.f["scale"], 0.55 * ridge)
        b.outline(disc, 0.4)
    return {"scale_rgb": (150, 118, 90), "arrangement": "widespread"}


def _pigmented_patch(b, rng, R):
    """A flat brown patch (cafe-au-lait macule, Becker naevus, post-inflammatory
    hyperpigmentation): evenly light to mid brown with faint mottling, sharply bordered,
    its outline smooth (the 'coast of California') or jagged (the 'coast of Maine'), the
    skin's markings and texture unchanged. Large and flat, the kind of lesion a model
    that only knows small dark ones takes for skin."""
    c = b.c
    jagged = rng.random() < 0.4
    sd = c.shape("round", R, aspect=rng.uniform(0.5, 0.95), irregular=0.35 if jagged else 0.08,
                 warp=0.2 if jagged else 0.06)
    w = b.weight(sd, R * 0.06)
    # light brown as a rule: melanin added (what shows on fair skin) and multiplied (an
    # added amount hardly shows on dark skin), L* 5-20 below the skin round it on types
    # II and V (median ~10 and ~13). Real cafe-au-lait macules and the dev set's flat brown
    # patches sit ~10 below; 0.03-0.14 added made them 14-38 below on types I-III
    add = _log_uniform(rng, 0.008, 0.05)
    b.f["melanin_add"] += w * add * (1 + 0.12 * c.noise(max(0.8, R / 6), 2))
    b.f["melanin"] *= 1 + w * rng.uniform(0.15, 0.8)
    b.outline(w, 0.35)
    return {"border": "jagged" if jagged else "smooth", "melanin_add": round(add, 4)}


def _lichen_planus(b, rng, R):
    """Lichen planus: flat-topped, polygonal, shiny papules 1-5 mm across, violaceous
    (poorly oxygenated blood) and dusky with melanin dropped into the dermis (grey-brown,
    near black on dark skin), crossed by a fine white lace (Wickham's striae), grouped
    and often merging into plaques. Papules differ: fresher ones are more violet, older
    ones browner, and none is one even colour."""
    c = b.c
    confluent = rng.random() < 0.4
    n = int(rng.integers(8, 40))
    mottle = c.noise(max(0.4, R / 20), 2)                   # uneven colour within papules
    skin_blood = b.f["blood_add"].copy()
    for p in arrange(c, "grouped", n, R * 1.1, R * 0.06):
        r = rng.uniform(0.6, 2.5) * (1.6 if confluent else 1.0)
        sd = polygon(c, p, r, int(rng.integers(5, 8)))
        w = b.weight(sd, r * 0.15)
        age = rng.uniform(0, 1)                                   # violet -> brown
        b.erythema(w, rng.uniform(2.0, 3.5) * (1 - 0.5 * age), oxygen=0.45, stipple=INFLAMED)
        b.f["melanin"] *= 1 + rng.uniform(0.1, 0.4) * w
        # (the most of it where papules merge, not their sum: that turned plaques blue-black)
        b.f["dermal_melanin"] = np.maximum(b.f["dermal_melanin"], w * rng.uniform(0.005, 0.02) * (0.7 + 0.5 * age))
        # flat-topped; merging papules make one plateau, not stacked ones
        b.f["height"] = np.maximum(b.f["height"], 0.12 * smoothstep(-r * 0.05, r * 0.25, sd))
        # shiny, not a mirror: a flat plaque facing a flash at 0.25 turned silver-white
        b.f["gloss"] = np.maximum(b.f["gloss"], 0.15 * w)
        b.f["detail"] *= 1 - 0.35 * w
        b.outline(w, 0.35, instance=1 if confluent else None)
    # the mottle scales the blood the papules added (on the erythema's weight it also
    # left their oxygen short of 0.45)
    b.f["blood_add"] = skin_blood + (b.f["blood_add"] - skin_blood) * np.clip(1 + 0.2 * mottle, 0.5, 1.5)
    cover = smoothstep(0.02, 0.08, b.f["height"])
    # Wickham's striae: a lace of thin grey-white lines 0.5-1.5 mm apart over parts of
    # the papules (until 2026-12-08 the zero crossings of a noise: white scratches)
    wall, _, _ = b.cells(float(np.clip(R / 25, 0.5, 1.5)))
    lace = (1 - smoothstep(0.0, 0.07, wall)) * smoothstep(-0.6, 0.8, c.noise(max(1.0, R / 8), 2))
    b.f["scale"] = np.maximum(b.f["scale"], rng.uniform(0.3, 0.5) * lace * cover)
    return {"arrangement": "confluent" if confluent else "grouped", "scale_rgb": SCALE_COLOURS["white"]}


def _inflammatory_patch(b, rng, R):
    """A large erythematous patch or thin plaque, the commonest look in clinical
    photographs (nummular and contact dermatitis, patch-stage mycosis fungoides, fixed
    drug eruption, cellulitis): pink to red on light skin, violaceous to dark brown on
    dark skin, its border ill-defined or geographic, with uneven redness inside, and
    sometimes fine scale, atrophic fine wrinkling or post-inflammatory darkening.
    One to four patches, overlapping ones merging."""
    c = b.c
    n = int(rng.choice([1, 1, 2, 3, 4]))
    border = str(rng.choice(["ill-defined", "sharp"], p=[0.6, 0.4]))
    oxygen = rng.uniform(0.55, 0.85)
    stipple = rng.uniform(0.5, 1.0)
    islands = int(rng.integers(1, 5)) if rng.random() < 0.3 else 0
    spared = 0.0
    for i, p in enumerate(arrange(c, "grouped", n, R * 0.6, R * 0.3)):
        r = R * (rng.uniform(0.55, 0.9) if i == 0 else rng.uniform(0.25, 0.5))
        sd = c.shape("round", r, centre=p, aspect=rng.uniform(0.5, 1.0), irregular=0.4, warp=0.25)
        w = b.weight(sd, r * 0.3, border)
        if i == 0 and islands:       # islands sit in the main patch and are spared by all of them
            spared = _spared_islands(b, rng, sd, r, islands)
        w *= 1 - spared
        inside = 0.65 + 0.35 * smoothstep(-1.0, 1.0, c.noise(r / 3, 3))    # uneven redness
        b.erythema(w * inside, rng.uniform(1.2, 3.0), oxygen=oxygen, stipple=stipple)
        b.f["melanin"] *= 1 + rng.uniform(0.0, 0.6) * w
        b.f["height"] += rng.uniform(0.0, 0.12) * w
        b.outline(w, 0.35, instance=1)
    w = np.clip(b.mask.astype(np.float32), 0, 1)
    look = rng.choice(["plain", "scale", "atrophy"], p=[0.45, 0.35, 0.2])
    if look == "scale":
        b.scale(w, rng.uniform(0.15, 0.4), rng.uniform(0.4, 1.0), "white")
    elif look == "atrophy":                                             # cigarette-paper wrinkling
        b.f["detail"] *= 1 + 0.8 * w
    return {"border": border, "surface": str(look), "patches": n, "islands": islands}


def _spared_islands(b, rng, sd, r, count):
    """Coverage of ``count`` islands of spared skin inside a patch (signed distance
    ``sd``, radius ``r``), each 5-15% of its radius, as patch-stage mycosis fungoides,
    pityriasis rubra pilaris and drug eruptions leave them; the outline leaves them out,
    as the dev set's annotators did round the mycosis fungoides photograph's islands."""
    c = b.c
    cells = np.argwhere(sd > 0.4 * r)
    spare = np.zeros_like(sd)
    for row, col in cells[rng.choice(len(cells), min(count, len(cells)), replace=False)]:
        ri = r * rng.uniform(0.05, 0.15)
        isd = c.shape("round", ri, centre=(c.x[row, col], c.y[row, col]), aspect=rng.uniform(0.5, 1.0),
                      irregular=0.3, warp=0.2)
        np.maximum(spare, b.weight(isd, ri * 0.3), out=spare)
    b.spared |= spare > 0.5
    return spare


def _wart(b, rng, R):
    """Common wart (verruca vulgaris): a rough papule of skin colour to grey, its surface
    a crowd of keratotic fronds (papillomatous: small conical projections under dry,
    yellowish-grey keratin) that interrupt the skin's lines, flecked with black dots where
    capillary loops have clotted. Solitary, a mother wart with satellites, or small warts
    merged into a mosaic plaque (one lesion), on the hands and feet."""
    c = b.c
    kind = str(rng.choice(["solitary", "satellite", "mosaic"], p=[0.45, 0.35, 0.2]))
    if kind == "solitary":
        centres, radii = [np.zeros(2)], [R * rng.uniform(0.6, 0.85)]
    elif kind == "satellite":
        centres = arrange(c, "satellite", int(rng.integers(3, 8)), R * 0.75, R * 0.25)
        radii = [R * 0.4] + list(R * rng.uniform(0.1, 0.2, len(centres) - 1))
    else:
        centres = arrange(c, "grouped", int(rng.integers(6, 20)), R * 0.9, R * 0.1)
        radii = list(R * rng.uniform(0.12, 0.25, len(centres)))
    frond = float(np.clip(R / 10, 0.25, 0.6))               # mm across one frond
    wall, tip, _ = b.cells(frond)
    # papillae packed base to base: steep cones, each its own height, the clefts between
    # them narrow (smooth cones a millimetre across, until 2026-12-07, read as a scoop
    # of clay), with the keratin's own fine roughness on them
    cone = smoothstep(0.02, 0.5, wall)
    fronds = cone ** 1.5 * (0.6 + 0.4 * tip)
    rough = c.noise(max(0.08, frond * 0.25), 1)
    keratin = (188, 174, 150)
    # thrombosed capillaries: black dots a quarter to half a millimetre, in the valleys
    speckle = c.noise(max(0.25, frond * 0.6), 1)
    cover = np.zeros((c.size, c.size), np.float32)
    for p, r in zip(centres, radii):
        sd = c.shape("round", r, centre=p, aspect=rng.uniform(0.75, 1.0), irregular=0.2, warp=0.1)
        w = b.weight(sd, r * 0.1)
        dome = smoothstep(-r * 0.05, r * 0.5, sd)
        h = min(rng.uniform(0.25, 0.45) * r, 2.0)
        b.f["height"] = np.maximum(b.f["height"], w * (h * dome + 0.35 * fronds + 0.03 * rough))
        # keratin thick and grey-white on the tips, thin in the clefts, where the
        # capillary loops of the papillae show: darker and a little red-brown there
        b.f["scale"] = np.maximum(b.f["scale"], w * (0.12 + 0.55 * fronds) * rng.uniform(0.7, 1.0))
        b.f["detail"] *= 1 - 0.8 * w
        b.f["melanin"] *= 1 + 0.4 * w * (1 - cone)
        b.f["blood_add"] += 0.04 * w * (1 - cone)
        cover = np.maximum(cover, w * dome)
        b.outline(w, 0.4, instance=1 if kind == "mosaic" else None)
    # the noise's peaks, but at least the top 3% of the warts' tops: a few small warts
    # had none above a fixed level and showed no dots at all
    top = cover > 0.5
    lo = min(1.6, float(np.quantile(speckle[top], 0.97))) if top.any() else 1.6
    dots = smoothstep(lo, lo + 0.6, speckle) * cover
    # one crust pass for all the warts' dots (each pass makes three full-grid noises)
    b.crust(dots, 1.0, "haemorrhagic", lump_mm=frond, thickness_mm=0.02)
    b.f["crust_dark"] = np.maximum(b.f["crust_dark"], dots)
    return {"arrangement": kind, "scale_rgb": keratin, "crust_rgb": CRUST_COLOURS["haemorrhagic"]}


def _keloid(b, rng, R):
    """Keloid: scar tissue grown past the wound it closed: a firm, raised plaque with
    rounded edges and a smooth, taut, shiny surface (the skin's lines gone), often
    sending claw-like extensions out along the skin's tension lines; pink to red while
    it grows, then the colour of the skin or darker (dark brown on dark skin), fine
    vessels across its top. On the chest, shoulders, earlobes and jaw."""
    c = b.c
    axis = rng.uniform(0, np.pi)
    aspect = rng.uniform(0.25, 0.7)
    # a band with rounded ends (a stadium), its edge wavy: a long ellipse's dome rose to a
    # ridge that ran out to two points, a glossy lozenge
    u = c.x * np.cos(axis) + c.y * np.sin(axis)
    v = c.y * np.cos(axis) - c.x * np.sin(axis)
    half = band = R * 0.8 * aspect                     # half its width
    straight = R * 0.8 - half                          # half its straight middle's length
    sd = half * (1 + 0.1 * c.noise(max(R / 3, 2 * c.px), 2)) \
        - np.hypot(np.maximum(np.abs(u) - straight, 0.0), v)
    claws = int(rng.choice([0, 0, 1, 2, 3]))
    for _ in range(claws):           # tapering, gently curving bands out near the long axis
        a = axis + rng.choice([0.0, np.pi]) + rng.normal(0, 0.5)
        start = R * rng.uniform(0.3, 0.6) * aspect * np.array([np.cos(a), np.sin(a)])
        length, half = R * rng.uniform(0.5, 1.0), R * aspect * rng.uniform(0.2, 0.4)
        u = (c.x - start[0]) * np.cos(a) + (c.y - start[1]) * np.sin(a)
        v = (c.y - start[1]) * np.cos(a) - (c.x - start[0]) * np.sin(a)
        v = v - rng.uniform(-0.4, 0.4) * u ** 2 / length
        t = np.clip(u / length, 0.0, 1.0)         # narrowing to a blunt, rounded tip
        claw = half * (1 - 0.6 * t) - np.hypot(v, u - length * t)
        k = 0.3 * half                      # a smooth union: a fillet where a claw leaves
        sd = k * np.logaddexp(sd / k, claw / k)
    w = b.weight(sd, R * 0.05)
    # a plateau: steep rounded shoulders and a flat top with low, broad swellings (a dome
    # over the whole band rose to a tube with a fold along its middle), each claw lower
    # as it narrows. It stands at most 0.6 of its half-width high: a 4 mm band raised
    # 1-4 mm, as all were, was a pill or a chocolate bar standing on the skin
    top = max(float(sd.max()), 1e-6)
    lumps = 1 + 0.05 * c.noise(max(R / 1.5, 2 * c.px), 2)
    rise = min(rng.uniform(1.0, 4.0), 0.6 * band)
    b.f["height"] += rise * lumps * smoothstep(0.0, 0.9, dome(sd > 0)) \
        * smoothstep(-0.08 * top, 0.1 * top, sd)
    # taut and shiny (0.12-0.25 until 2026-12-08: matte putty; 0.3-0.5 mirrored a flash
    # over the whole flat top)
    b.f["gloss"] = np.maximum(b.f["gloss"], rng.uniform(0.2, 0.35) * w)
    b.f["detail"] *= 1 - 0.85 * w
    b.mix("scatter", w, rng.uniform(1.05, 1.25))            # dense collagen
    active = rng.random() < 0.45
    margin = w * (1 - smoothstep(0.0, 0.35 * top, sd))      # the margin grows, so it is redder
    mottle = 0.8 + 0.2 * c.noise(R / 3, 2)
    if active:
        b.erythema(np.clip(w * mottle + 0.3 * margin, 0, 1.3), rng.uniform(1.5, 3.0))
    else:
        b.erythema(w * mottle + 0.5 * margin, rng.uniform(0.2, 0.8))
        b.f["melanin"] *= 1 + rng.uniform(0.1, 0.5) * w * mottle
    n = int(rng.integers(1, 5))
    around = rng.uniform(0, 2 * np.pi, n)
    starts = R * 0.5 * aspect * np.stack([np.cos(around), np.sin(around)], 1)
    vessels = vessel_tree(c, starts, around + np.pi, rng.uniform(0.06, 0.12), R * 0.5, depth=2) * w
    b.erythema(vessels * smoothstep(0.0, R * 0.1, sd), 3.0, 0.85)
    b.outline(w, 0.4)
    return {"stage": "active" if active else "mature", "claws": claws, "aspect": round(aspect, 3),
            "height_mm": round(rise, 2)}


def _herpes(b, rng, R):
    """Herpes simplex and zoster: clusters of small tense vesicles (1-3 mm, clear to
    milky, domed and glistening, some with a central dell) on a red base; older clusters
    turned to pustules or to honey and dark crust. Simplex is one cluster (lips, face);
    zoster several along a dermatome, a band across one side of the trunk. Each cluster
    is outlined with its red base."""
    c = b.c
    zoster = R > 20 and rng.random() < 0.6          # a dermatome's band is centimetres long
    if zoster:
        centres = arrange(c, "dermatomal", int(rng.integers(3, 8)), R * 0.85, R * 0.3)
        sizes = R * rng.uniform(0.12, 0.25, len(centres))
    else:
        centres, sizes = [np.zeros(2)], [min(R * rng.uniform(0.35, 0.6), rng.uniform(5.0, 15.0))]
    stages, bases = [], np.zeros((c.size, c.size), np.float32)
    crust = str(rng.choice(["honey", "haemorrhagic"]))       # of the crusted clusters
    for q, rc in zip(centres, sizes):
        base = c.shape("round", rc, centre=q, aspect=rng.uniform(0.6, 1.0), irregular=0.2, warp=0.06)
        w = b.weight(base, rc * 0.3, "ill-defined")
        b.erythema(w, rng.uniform(2.0, 3.5), stipple=INFLAMED)
        stage = str(rng.choice(["vesicles", "pustules", "crusted"], p=[0.5, 0.2, 0.3]))
        stages.append(stage)
        r_lo, r_hi = 0.4, float(np.clip(rc * 0.15, 0.6, 1.5))
        n = int(np.clip(0.8 * (rc / r_hi) ** 2 * rng.uniform(0.6, 1.2), 5, 60))   # closely set
        pts = [np.asarray(q) + p for p in arrange(c, "grouped", n, rc * 1.2, r_lo * 1.6)]
        pts = [p for p in pts if np.abs(p).max() < c.extent / 2]
        if pts:
            radii = rng.uniform(r_lo, r_hi, len(pts))
            sd, index = spots(c, pts, radii)
            r = radii[index].astype(np.float32)
            v = smoothstep(-0.1, 0.25, sd / r) * w
            dome = np.sqrt(np.clip(sd / r, 0, 1))
            dell = (rng.random(len(pts)) < 0.3)[index] * smoothstep(0.6, 0.95, sd / r)
            b.f["height"] = np.maximum(b.f["height"], 0.5 * r * v * (dome - 0.4 * dell))
            if stage == "crusted":
                b.crust(v, 0.9, crust, lump_mm=r_hi)
            else:
                # fluid lifts the epidermis off the red base: paler, milky, glistening
                b.f["blood_add"] *= 1 - 0.6 * v
                b.mix("scatter", v, rng.uniform(1.2, 1.5))
                cloudy = 0.2 if stage == "vesicles" else 0.6
                b.f["scale"] = np.maximum(b.f["scale"], cloudy * v)
                b.f["gloss"] = np.maximum(b.f["gloss"], 0.7 * v)
        bases = np.maximum(bases, w)
    b.outline(bases, 0.35)          # one lesion per connected cluster (make_condition splits)
    colour = SCALE_COLOURS["white"] if "vesicles" in stages else SCALE_COLOURS["pus"]
    return {"kind": "zoster" if zoster else "simplex", "clusters": len(centres), "stages": stages,
            "scale_rgb": colour, "crust_rgb": CRUST_COLOURS[crust]}


def _kaposi_sarcoma(b, rng, R):
    """Kaposi sarcoma, a tumour of small vessels: patches, plaques and nodules, oval along
    the skin's lines, violaceous to red-purple on light skin and purple-brown to near black
    on dark skin (poorly oxygenated blood in slit-like vessels, haemosiderin round them),
    some with a yellow-green bruise-like halo; several, on the legs and feet."""
    c = b.c
    axis = rng.uniform(0, np.pi)
    halo = rng.random() < 0.4
    for i, p in enumerate(arrange(c, "grouped", int(rng.integers(1, 7)), R * 0.8, R * 0.3)):
        r = R * (rng.uniform(0.4, 0.7) if i == 0 else rng.uniform(0.12, 0.35))
        stage = str(rng.choice(["patch", "plaque", "nodule"], p=[0.35, 0.4, 0.25]))
        sd = c.shape("oval", r, centre=p, aspect=rng.uniform(0.4, 0.85), angle=axis + rng.normal(0, 0.3),
                     irregular=0.15, warp=0.1)
        w = b.weight(sd, r * 0.3, "ill-defined" if stage == "patch" else "sharp")
        inside = 0.8 + 0.2 * smoothstep(-1.0, 1.0, c.noise(r / 3, 2))
        b.f["blood_add"] += w * inside * rng.uniform(0.35, 0.7)
        b.mix("oxygen", w, rng.uniform(0.3, 0.5))
        b.mix("scatter", w, rng.uniform(0.3, 0.55))
        b.f["dermal_melanin"] += w * rng.uniform(0.005, 0.015)
        b.f["melanin"] *= 1 + rng.uniform(0.2, 0.6) * w
        if halo:
            ring = b.weight(sd + r * 0.35, r * 0.3, "ill-defined") * (1 - w)
            # with the skin's flush laid over (apply_to_skin), 0.15 made the yellow ring
            # visible past what an outline takes in (up to 0.7 of the cells two out from
            # it visibly changed over 15 draws; 0.25 at most with 0.08)
            b.f["bilirubin"] += 0.08 * ring
            b.f["dermal_melanin"] += 0.003 * ring
        if stage != "patch":
            h = rng.uniform(0.2, 0.5) if stage == "plaque" else min(0.35 * r, 3.0)
            # a dome, not a mesa (a flat top caught the whole flash as one white disc)
            b.f["height"] = np.maximum(b.f["height"], h * dome(sd > -0.05 * r))
            b.f["gloss"] = np.maximum(b.f["gloss"], 0.12 * w)
            b.f["detail"] *= 1 - (0.3 if stage == "plaque" else 0.7) * w
        b.outline(w, 0.4)
    return {"halo": halo}


def _granuloma_annulare(b, rng, R):
    """Granuloma annulare: a ring of small, smooth, firm papules (beaded), skin-coloured
    to pink or violet-brown, round a centre of normal or faintly dusky skin, with no
    scale (what tells it from tinea); on the backs of the hands and feet, the fingers,
    the elbows and the shins. The ring is outlined with its centre."""
    c = b.c
    width = R * rng.uniform(0.15, 0.3)
    # papules side by side round a wobbly ring, overlapping enough to coalesce, each a low
    # dome (round top, soft edge): a beaded ring with a scalloped edge, not a tube
    mid, aspect, turn = R - width / 2, rng.uniform(0.7, 1.0), rng.uniform(0, np.pi)
    n = max(8, int(2 * np.pi * mid / (width * 0.7)))
    t = (np.arange(n) + rng.uniform(-0.25, 0.25, n)) * 2 * np.pi / n
    radius = mid * (1 + sum(0.12 * rng.normal() / k * np.cos(k * t + rng.uniform(0, 2 * np.pi))
                            for k in (2, 3, 4)))
    u, v = radius * np.cos(t), aspect * radius * np.sin(t)
    centres = np.stack([u * np.cos(turn) - v * np.sin(turn), u * np.sin(turn) + v * np.cos(turn)], 1)
    radii = width / 2 * rng.uniform(0.55, 1.2, n)
    # a papule missing here and there: gaps in the ring, never two side by side (a gap
    # wider than the centre's closing bridges left an open arc, its centre unoutlined)
    keep = rng.random(n) > 0.12
    keep[0] = True
    keep |= ~np.roll(keep, 1)
    centres, radii = centres[keep], radii[keep]
    sd, which = spots(c, centres, radii, irregular=0.1)
    s = np.clip(sd / radii[np.maximum(which, 0)], 0.0, 1.0)
    papule = cv2.GaussianBlur(1 - (1 - s) ** 2, (0, 0), max(0.5, 0.1 * width / c.px))
    # the papules merge into one raised, rounded band (the ring's blurred papules) whose
    # top the papules bead; until 2026-12-01 each stood as its own dome between deep
    # notches, a string of pearls laid on the skin
    band = cv2.GaussianBlur(papule, (0, 0), max(1.0, 0.3 * width / c.px))
    band /= max(float(band.max()), 1e-6)
    relief = 0.6 * band + 0.4 * papule
    b.f["height"] += min(rng.uniform(0.3, 0.6), 0.3 * width) * relief   # low: at most r x 0.6
    w_ring = b.weight(sd, width * 0.3, "ill-defined")
    b.erythema(w_ring * (0.7 + 0.3 * papule), rng.uniform(1.0, 2.5), oxygen=rng.uniform(0.55, 0.75))
    b.f["melanin"] *= 1 + rng.uniform(0.1, 0.5) * w_ring
    b.mix("scatter", w_ring, 1.1)
    b.f["detail"] *= 1 - 0.5 * w_ring
    b.f["gloss"] = np.maximum(b.f["gloss"], 0.1 * papule)
    # the centre: what the ring closes round (bridging a missing papule), faintly dusky
    bridge = 2 * int(1.5 * width / c.px) + 1
    ring_px = cv2.morphologyEx((w_ring > 0.35).astype(np.uint8), cv2.MORPH_CLOSE,
                               cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (bridge, bridge)))
    closed = ndimage.binary_fill_holes(ring_px)
    w_centre = cv2.GaussianBlur((closed & (w_ring <= 0.35)).astype(np.float32), (0, 0),
                                max(1.0, width * 0.2 / c.px))
    b.erythema(w_centre * rng.uniform(0.0, 0.3), 0.5, oxygen=0.6)
    b.outline(np.maximum(w_ring, closed), 0.35)
    return {"ring_mm": round(float(width), 2)}


def _actinic_keratosis(b, rng, R):
    """Actinic keratoses on sun-damaged skin: rough, ill-defined pink to red-brown macules
    and thin plaques a few millimetres to a centimetre or two across, under adherent
    white to yellowish scale that is felt more than seen; several, on the face, scalp,
    ears and the backs of the hands."""
    c = b.c
    scaly = np.zeros((c.size, c.size), np.float32)
    for i, p in enumerate(arrange(c, "widespread", int(rng.integers(2, 8)), R * 0.8, R * 0.25)):
        r = R * (rng.uniform(0.3, 0.5) if i == 0 else rng.uniform(0.12, 0.3))
        sd = c.shape("round", r, centre=p, aspect=rng.uniform(0.5, 1.0), irregular=0.3, warp=0.2)
        w = b.weight(sd, r * 0.4, "ill-defined")
        b.erythema(w * (0.7 + 0.3 * c.noise(r / 2, 2)), rng.uniform(1.0, 2.5), stipple=INFLAMED)
        b.f["melanin"] *= 1 + rng.uniform(0.0, 0.5) * w
        scaly = np.maximum(scaly, w * smoothstep(-r * 0.1, r * 0.3, sd))
        b.f["height"] += rng.uniform(0.0, 0.15) * w
        b.outline(w, 0.35)
    # one scale over them all (each scale() call costs a plate tessellation and four noises)
    colour = str(rng.choice(["white", "greasy"], p=[0.7, 0.3]))
    b.scale(scaly, rng.uniform(0.1, 0.35), rng.uniform(0.3, 0.8), colour)
    return {"scale": colour, "scale_rgb": SCALE_COLOURS[colour]}


def _telangiectasia(b, rng, R):
    """Telangiectasia, small vessels dilated for good and seen through the skin as lines
    0.05-0.4 mm wide. Under 18 mm a spider angioma: a red central arteriole, a little
    raised, with 5-10 fine legs radiating from it and a faint flush round them (face,
    neck, upper trunk, hands). Larger, a patch of leg telangiectases (fine red to violet
    branching lines, some in sunburst clusters, over one to three bluer reticular veins
    1-2.5 mm wide that lie deeper) or, under 60 mm, facial telangiectasia (straight and
    gently curved red lines over a diffuse flush, as on rosacea or sun-damaged cheeks).
    The outline is the area the vessels occupy, as annotators draw it, not each line."""
    c = b.c
    if 2 * R < 18.0:
        kind = "spider"
        n = int(rng.integers(5, 11))
        heads = headings_around(rng, n, 0.25)
        # (a leg runs its length, then forks once into branches 0.75 as long: ~0.8 R)
        legs = vessel_tree(c, np.zeros((n, 2)), heads, rng.uniform(0.05, 0.1), R * rng.uniform(0.35, 0.5),
                           depth=1)
        punctum = b.weight(c.shape("round", rng.uniform(0.25, 0.5), irregular=0.15), 0.2, "ill-defined")
        region, inside, area = _one_area(b, c.shape("round", R * 0.85, irregular=0.2, warp=0.1), R * 0.2)
        b.erythema(area * 0.5, rng.uniform(0.5, 1.2), oxygen=0.85)       # the flush round it
        b.erythema(legs * inside, rng.uniform(3.0, 5.0), oxygen=0.85)    # arterial: bright red
        b.erythema(punctum, 6.0, oxygen=0.9)
        b.f["height"] += 0.2 * punctum
        b.outline((region | (punctum > 0.4)).astype(np.float32), 0.5)
        return {"kind": kind, "legs": n}
    # (a cheek or a nose holds at most ~6 cm of facial telangiectasia)
    kind = str(rng.choice(["leg", "facial"], p=[0.55, 0.45])) if 2 * R < 60.0 else "leg"
    sd = c.shape("round", R, aspect=rng.uniform(0.45, 1.0), irregular=0.25, warp=0.12)
    region, inside, area = _one_area(b, sd, R * 0.2)
    lines = np.zeros((c.size, c.size), np.float32)
    if kind == "leg":
        # sunburst clusters: fine vessels radiating from a feeding point, forking twice
        clusters = int(np.clip((R / 12.0) ** 2, 2, 10))
        for p in arrange(c, "widespread", clusters, R * 0.7, R * 0.25):
            n = int(rng.integers(3, 7))
            heads = headings_around(rng, n, 0.4)
            starts = np.tile(np.asarray(p, np.float64), (n, 1))
            np.maximum(lines, vessel_tree(c, starts, heads, rng.uniform(0.15, 0.4), R * rng.uniform(0.2, 0.45),
                                          depth=2), out=lines)
        # reticular veins: long, bent, 1-2.5 mm wide, deeper (less red, bluer)
        veins = np.zeros_like(lines)
        for _ in range(int(rng.integers(1, 4))):
            a = rng.uniform(0, np.pi)
            start = -R * np.array([np.cos(a), np.sin(a)]) + rng.normal(0, R * 0.2, 2)
            np.maximum(veins, vessel_tree(c, [start], [a], rng.uniform(1.0, 2.5), R * 1.6, depth=1), out=veins)
        veins = cv2.GaussianBlur(veins, (0, 0), max(0.6, 0.4 / c.px)) * inside
        b.f["blood_add"] += 0.2 * veins
        b.mix("oxygen", veins, 0.35)
        b.mix("scatter", veins, 0.6)
        oxygen = rng.uniform(0.45, 0.8)                  # red to violet
        b.erythema(area * 0.4, rng.uniform(0.5, 1.5), oxygen=oxygen)
    else:
        # many short, nearly straight vessels in every direction, a few forked
        n = int(np.clip(rng.uniform(0.8, 2.0) * (R / 3.0) ** 2, 10, 200))
        starts = np.array(arrange(c, "widespread", n, R * 0.95, R * 0.04))
        lengths = R * rng.uniform(0.1, 0.3)
        for p in starts:
            np.maximum(lines, vessel_tree(c, [p], [rng.uniform(0, 2 * np.pi)], rng.uniform(0.08, 0.2),
                                          lengths, depth=int(rng.integers(0, 2))), out=lines)
        oxygen = rng.uniform(0.7, 0.9)
        b.erythema(area * (0.7 + 0.3 * c.noise(R / 3, 2)), rng.uniform(0.6, 1.6), oxygen=0.8)
    b.erythema(lines * inside, rng.uniform(4.0, 6.0), oxygen=oxygen)
    b.outline(region.astype(np.float32), 0.5)
    return {"kind": kind}


def _one_area(b, sd, border):
    """An ill-defined area (signed distance ``sd``, fading over ``border`` mm) as one
    region: the largest piece of its outline, holes filled (a warp may pinch off an
    islet). Returns the region (bool), a weight that fades to 0 just inside its edge (for
    what must stay within the outline), and the area's weight cut to the region."""
    w = b.weight(sd, border, "ill-defined")
    region = largest_piece(w > 0.4)
    inside = smoothstep(0.5, 0.9, cv2.GaussianBlur(region.astype(np.float32), (0, 0), max(1.0, 0.25 * border / b.c.px)))
    return region, inside, w * np.maximum(inside, region)


# preset -> (builder, size range in mm (the condition's extent))
PRESETS = {
    "nevus": (_nevus, (2.5, 9.0)),
    "melanoma": (_melanoma, (6.0, 35.0)),
    "lentigo_maligna": (_lentigo_maligna, (15.0, 70.0)),
    "psoriasis": (_psoriasis, (15.0, 120.0)),
    "eczema": (_eczema, (20.0, 120.0)),
    "tinea": (_tinea, (15.0, 80.0)),
    "bcc": (_bcc, (4.0, 25.0)),
    "scc": (_scc, (8.0, 40.0)),
    "seborrhoeic_keratosis": (_seb_keratosis, (5.0, 30.0)),
    "acne": (_acne, (30.0, 120.0)),
    "urticaria": (_urticaria, (40.0, 200.0)),
    "vitiligo": (_vitiligo, (15.0, 150.0)),
    "pityriasis_rosea": (_pityriasis_rosea, (60.0, 220.0)),
    "ulcer": (_ulcer, (10.0, 90.0)),
    "lupus": (_lupus, (10.0, 60.0)),
    "pyogenic_granuloma": (_pyogenic_granuloma, (4.0, 18.0)),
    "purpura": (_purpura, (10.0, 90.0)),
    "morphea": (_morphea, (20.0, 120.0)),
    "porokeratosis": (_porokeratosis, (30.0, 120.0)),
    "pigmented_patch": (_pigmented_patch, (15.0, 150.0)),
    "lichen_planus": (_lichen_planus, (15.0, 80.0)),
    "inflammatory_patch": (_inflammatory_patch, (30.0, 200.0)),
    "wart": (_wart, (5.0, 30.0)),
    "keloid": (_keloid, (10.0, 80.0)),
    "herpes": (_herpes, (12.0, 150.0)),
    "kaposi_sarcoma": (_kaposi_sarcoma, (8.0, 80.0)),
    "granuloma_annulare": (_granuloma_annulare, (15.0, 60.0)),
    "actinic_keratosis": (_actinic_keratosis, (15.0, 60.0)),
    "telangiectasia": (_telangiectasia, (5.0, 100.0)),
}


# Where each condition is usually seen: the share of its lesions on each body region
# (dataformat.GROUP_NAMES), after textbook predilection sites: basal cell carcinoma and
# lentigo maligna on sun-damaged faces, acne on the face and upper trunk, pityriasis rosea
# on the trunk, venous ulcers and purpura on the lower legs, psoriasis on elbows, knees,
# scalp line and lower back. Placement (``paste.body_sites``) draws a region by these
# shares, then a place in it by skin area; a preset not listed goes anywhere by area.
SITES = {
    "nevus": {"head": 0.1, "torso": 0.45, "hips": 0.05, "legs": 0.15, "arms": 0.2, "hands": 0.05},
    "melanoma": {"head": 0.15, "torso": 0.4, "hips": 0.03, "legs": 0.25, "feet": 0.02, "arms": 0.15},
    "lentigo_maligna": {"head": 0.9, "arms": 0.05, "hands": 0.05},
    "psoriasis": {"head": 0.1, "torso": 0.25, "legs": 0.3, "feet": 0.05, "arms": 0.25, "hands": 0.05},
    "eczema": {"head": 0.15, "torso": 0.15, "legs": 0.2, "arms": 0.3, "hands": 0.2},
    "tinea": {"head": 0.05, "torso": 0.3, "hips": 0.2, "legs": 0.15, "feet": 0.2, "arms": 0.1},
    "bcc": {"head": 0.8, "torso": 0.15, "arms": 0.05},
    "scc": {"head": 0.55, "torso": 0.05, "legs": 0.1, "arms": 0.15, "hands": 0.15},
    "seborrhoeic_keratosis": {"head": 0.2, "torso": 0.6, "legs": 0.1, "arms": 0.1},
    "acne": {"head": 0.6, "torso": 0.4},
    "urticaria": {"head": 0.1, "torso": 0.35, "hips": 0.1, "legs": 0.25, "arms": 0.2},
    "vitiligo": {"head": 0.3, "torso": 0.1, "legs": 0.1, "feet": 0.1, "arms": 0.15, "hands": 0.25},
    "pityriasis_rosea": {"torso": 0.75, "legs": 0.1, "arms": 0.15},
    "ulcer": {"hips": 0.05, "legs": 0.75, "feet": 0.2},
    "lupus": {"head": 0.85, "torso": 0.05, "arms": 0.1},
    "pyogenic_granuloma": {"head": 0.35, "torso": 0.1, "arms": 0.1, "hands": 0.45},
    "purpura": {"torso": 0.05, "legs": 0.7, "arms": 0.25},
    "morphea": {"head": 0.1, "torso": 0.6, "legs": 0.2, "arms": 0.1},
    "porokeratosis": {"torso": 0.05, "legs": 0.5, "arms": 0.45},
    "pigmented_patch": {"head": 0.4, "torso": 0.3, "legs": 0.15, "arms": 0.15},
    "lichen_planus": {"head": 0.1, "torso": 0.1, "legs": 0.35, "arms": 0.45},
    "wart": {"head": 0.05, "legs": 0.05, "feet": 0.25, "arms": 0.05, "hands": 0.6},
    "keloid": {"head": 0.2, "torso": 0.55, "legs": 0.05, "arms": 0.2},
    "herpes": {"head": 0.35, "torso": 0.45, "hips": 0.05, "legs": 0.05, "arms": 0.1},
    "kaposi_sarcoma": {"head": 0.05, "torso": 0.05, "legs": 0.55, "feet": 0.25, "arms": 0.1},
    "granuloma_annulare": {"torso": 0.05, "legs": 0.2, "feet": 0.1, "arms": 0.3, "hands": 0.35},
    "actinic_keratosis": {"head": 0.7, "arms": 0.1, "hands": 0.2},
    "telangiectasia": {"head": 0.4, "torso": 0.15, "legs": 0.35, "hands": 0.05, "arms": 0.05},
}

# conditions that often spread over a region as many separate lesions (a generalised
# eruption: psoriasis, eczema, urticaria, pityriasis rosea, lichen planus, vitiligo, acne,
# purpura of the legs, and the plaques of a drug eruption or mycosis fungoides, which the
# inflammatory patch draws); `lesions.eruption` spreads one of a body's such lesions over
# the skin around it
ERUPTIVE = ("psoriasis", "eczema", "urticaria", "pityriasis_rosea", "inflammatory_patch",
            "lichen_planus", "vitiligo", "acne", "purpura")


# grid side / condition extent, tried in turn until the outline stays off the grid's edge
GRID_MARGINS = (1.4, 1.9, 2.6, 3.6)

# The change round a lesion that its outline takes in: colour visibly changed (CIEDE76
# above HALO_VISIBLE on an even type III skin, scale and crust included), connected to
# the lesion and within HALO_REACH of its equivalent radius. The dev set's annotators
# drew round an ulcer's inflamed halo and macerated rim; outlines that left them out
# taught models to call the faint edge of real lesions skin.
HALO_VISIBLE = 5.0
HALO_REACH = 0.35
HALO_SKIN = (196, 150, 124)


def make_condition(preset: str, seed, size=512, extent_mm=None, halo_reach=HALO_REACH) -> LesionFields:
    """One seeded condition of ``preset`` on a size x size grid; its extent is drawn from
    the preset's range unless given (mm; the grid has a margin around it). Each lesion's
    mask takes in the visible change round it up to ``halo_reach`` of its radius
    (``_take_in_halo``; 0: only what the preset outlined)."""
    if preset not in PRESETS:
        raise ValueError(f"unknown lesion preset {preset!r}; choose from {sorted(PRESETS)}")
    build, (lo, hi) = PRESETS[preset]
    # the condition fades out before the grid's edge; an outline that reaches that band
    # would be cut along a straight line there, so the same draw is made again on a grid
    # with a wider margin (coarser cells) until its outline stays inside
    edge = np.minimum.reduce([np.arange(size), np.arange(size)[::-1]]).astype(np.float32)
    taper = smoothstep(0.0, 0.06 * size, edge)
    taper = np.minimum.outer(taper, taper)
    for margin in GRID_MARGINS:
        rng = np.random.default_rng(np.atleast_1d(seed).tolist() + [17])
        extent = float(extent_mm) if extent_mm is not None else _log_uniform(rng, lo, hi)
        canvas = Canvas(rng, int(size), extent * margin)
        b = Builder(canvas)
        extra = build(b, rng, extent / 2) or {}
        if not (b.mask & (taper < 1)).any():
            break
    b.f["height"] = cv2.GaussianBlur(b.f["height"], (0, 0), max(0.6, 0.05 / canvas.px))
    for k in FIELDS:
        b.f[k] = (NEUTRAL[k] + (b.f[k] - NEUTRAL[k]) * taper).astype(np.float32)
    b.mask &= taper > 0.5
    b.instances[~b.mask] = 0
    if not b.mask.any():      # a draw that left nothing outlined: the strongest change
        strength = np.abs(b.f["blood"] - 1) + np.abs(b.f["melanin"] - 1) + b.f["scale"] + b.f["crust"]
        b.outline(strength / max(strength.max(), 1e-6), 0.5)
    fields = LesionFields(b.f, b.mask, b.instances, canvas.extent, preset=preset,
                          scale_rgb=tuple(extra.pop("scale_rgb", SCALE_COLOURS["white"])),
                          crust_rgb=tuple(extra.pop("crust_rgb", CRUST_COLOURS["honey"])),
                          params={"extent_mm": round(extent, 2), **extra})
    if halo_reach > 0:       # (not into the band where the grid fades the fields out)
        _take_in_halo(b, fields, halo_reach, taper >= 1)
    _relabel(b)
    fields.mask, fields.instances = b.mask, b.instances
    return fields


def visible_change(fields: LesionFields) -> np.ndarray:
    """CIEDE76 by which ``fields`` change the even skin a halo is judged on
    (``HALO_SKIN``), per grid cell."""
    skin = np.empty(fields.mask.shape + (3,), np.uint8)
    skin[:] = HALO_SKIN
    lab = srgb_to_lab(apply_to_skin(fields, skin).reshape(-1, 3) / 255.0)
    return np.linalg.norm(lab - srgb_to_lab(np.asarray(HALO_SKIN, np.float64)[None] / 255.0),
                          axis=1).reshape(fields.mask.shape)


def _take_in_halo(b, fields, reach, allowed, step=4):
    """Add to each lesion's mask the visible change that touches it (``HALO_VISIBLE``)
    within ``reach`` of its equivalent radius: an inflamed halo, a macerated rim, the
    faint fringe of a patch. Spared islands stay out, nothing leaves ``allowed``. The
    colour is judged on a grid ``step`` times coarser (a halo is smooth)."""
    coarse = LesionFields({k: v[step // 2::step, step // 2::step] for k, v in fields.f.items()},
                          b.mask[step // 2::step, step // 2::step], b.instances[step // 2::step, step // 2::step],
                          fields.extent_mm, fields.scale_rgb, fields.crust_rgb)
    visible = (visible_change(coarse) > HALO_VISIBLE).astype(np.float32)
    n = b.mask.shape[0]
    visible = cv2.resize(visible, (n, n), interpolation=cv2.INTER_LINEAR) > 0.5
    candidate = (visible | b.mask) & allowed & ~b.spared
    lab, _ = ndimage.label(candidate)
    touching = np.unique(lab[b.mask])
    candidate &= np.isin(lab, touching[touching > 0]) & ~b.mask
    if not candidate.any():
        return
    dist, (iy, ix) = ndimage.distance_transform_edt(~b.mask, return_indices=True)
    nearest = b.instances[iy, ix]
    radius = np.sqrt(np.bincount(b.instances.ravel())[nearest] / np.pi)
    add = candidate & (dist <= reach * radius)
    # skin a halo closes round (between a lesion and its rim) is drawn over too; the
    # lesion's own holes (an annulus's clear centre) stay holes, and so do spared
    # islands, also those that were notches in the outline until the halo closed them
    grown = b.mask | add
    add |= ndimage.binary_fill_holes(grown) & ~grown & ~ndimage.binary_fill_holes(b.mask) & allowed & ~b.spared
    b.instances[add] = nearest[add]
    b.mask |= add


def _relabel(b, min_mm2=0.05):
    """Instance ids 1..n in order of first appearance, one per connected region of each
    outlined lesion (lesions that merged keep the first id). A region under ``min_mm2``
    (0.25 mm across; the smallest petechiae are twice that) is a speck where an outline's
    threshold nicked a stray peak: it joins the lesion it touches, or leaves the mask."""
    min_area = min_mm2 / b.c.px ** 2
    h, w = b.instances.shape
    specks = []                     # (lesion id, a box one cell wider, the speck in it)
    for k in np.unique(b.instances[b.instances > 0]):
        lab, _ = ndimage.label(b.instances == k)
        boxes = ndimage.find_objects(lab)
        for j in np.flatnonzero(np.bincount(lab.ravel())[1:] < min_area) + 1:
            ys, xs = boxes[j - 1]
            box = (slice(max(ys.start - 1, 0), min(ys.stop + 1, h)),
                   slice(max(xs.start - 1, 0), min(xs.stop + 1, w)))
            specks.append((k, box, lab[box] == j))
    for k, box, region in specks:
        inst = b.instances[box]
        rim = inst[ndimage.binary_dilation(region) & ~region]
        rim = rim[(rim > 0) & (rim != k)]
        if rim.size:                                # a nick off a neighbour's edge
            inst[region] = np.bincount(rim).argmax()
        else:
            inst[region] = 0
            b.mask[box][region] = False
    out = np.zeros_like(b.instances)
    n = 0
    for k in np.unique(b.instances[b.instances > 0]):
        lab, count = ndimage.label(b.instances == k)
        for j in range(1, count + 1):
            n += 1
            out[lab == j] = n
    b.instances = out


HEALTHY_BLOOD = 0.04   # blood volume fraction of a healthy papillary dermis (2-4%)


def apply_to_skin(fields: LesionFields, skin_rgb_uint8: np.ndarray, at=None) -> np.ndarray:
    """The condition on a skin: ``skin_rgb_uint8`` (N x 3 or H x W x 3 uint8) holds the
    skin's colour at each sample, ``at`` the samples' grid positions (N x 2 float
    (row, col), bilinear; default: the skin image is the grid). Returns uint8 colours of
    the same shape. Melanin and blood come from the skin model's inverse; the residual
    of each colour is kept, so the skin's own texture stays, and so is its flush (blood
    beyond ``HEALTHY_BLOOD``), over the condition rather than under it."""
    rgb = np.asarray(skin_rgb_uint8)
    shape = rgb.shape
    flat = rgb.reshape(-1, 3)
    if at is None:
        vals = {k: v.reshape(-1) for k, v in fields.f.items()}
    else:
        rows, cols = np.asarray(at, np.float32).T
        vals = {k: sample_bilinear(v, cols - 0.5, rows - 0.5, cv2.BORDER_REPLICATE)
                for k, v in fields.f.items()}
    mel, blood, residual = skin_inverse()(flat)
    mel = np.clip(mel * vals["melanin"] + vals["melanin_add"], 0, 1)
    # Redness beyond a healthy papillary dermis' blood is the skin's own flush, laid over
    # the condition rather than under it: the model's redness saturates (a* 5 -> 14 from
    # 2% to 10% blood, only 14 -> 20 from 10% to 25%), so a plaque's vessels added to the
    # 8-10% that the inverse reads in textures' healthy skin (a* 12-14) reddened it half
    # as much as on skin at 2% (rendered plaques: a* 2.4 above their skin against 7.4 in
    # the dev photographs). The flush still blanches with the skin's blood and fades
    # under added melanin.
    base = np.minimum(blood, HEALTHY_BLOOD) * vals["blood"]
    model = skin_rgb_fast(mel, np.clip(base + vals["blood_add"], 0, 0.7),
                          vals["oxygen"], vals["bilirubin"], vals["dermal_melanin"], vals["epidermis"],
                          vals["scatter"])
    lab = srgb_to_lab(model) + residual * np.clip(vals["epidermis"], 0.3, 1.0)[:, None]
    flushed = np.flatnonzero(blood > HEALTHY_BLOOD)
    if flushed.size:
        m, o, own = mel[flushed], vals["oxygen"][flushed], blood[flushed] * vals["blood"][flushed]
        lab[flushed] += srgb_to_lab(skin_rgb_fast(m, np.clip(own, 0, 0.7), o)) \
            - srgb_to_lab(skin_rgb_fast(m, base[flushed], o))
    out = lab_to_srgb(lab)
    # thick, old crust darkens towards the brown-red of dried blood and serum
    old = 0.75 * np.clip(vals["crust_dark"], 0, 1)[:, None]
    crust = np.asarray(fields.crust_rgb, np.float64) / 255.0 * (1 - old) + OLD_CRUST * old
    for name, tone in (("scale", np.asarray(fields.scale_rgb, np.float64) / 255.0), ("crust", crust)):
        a = np.clip(vals[name], 0, 1)[:, None]
        out = out * (1 - a) + tone * a
    return np.clip(np.rint(out * 255), 0, 255).astype(np.uint8).reshape(shape)
