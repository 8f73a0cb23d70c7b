"""Background sources: indoor photographs from a folder, or seeded procedural rooms.

Both give a Sequence of HxWx3 uint8 RGB images with ``ids``/``meta`` and
``get(i, width, height)``, which resizes an image to cover the view (aspect kept) and
crops the centre.
"""
from __future__ import annotations

import logging
import os
from collections.abc import Sequence

import cv2
import numpy as np

from ..errors import InputError
from ..io.images import ImageError, read_rgb
from .colour import lab_to_srgb
from .lesions import fractal_noise

log = logging.getLogger(__name__)

BACKGROUND_EXTS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")


class BackgroundError(InputError):
    """A background folder holds no usable image, or a view size is invalid."""


def fit_cover(img: np.ndarray, width: int, height: int) -> np.ndarray:
    """Resize `img` (aspect kept) so it covers width x height, then crop the centre."""
    if int(width) < 1 or int(height) < 1:
        raise BackgroundError(f"background view size must be positive, got {width}x{height}")
    h, w = img.shape[:2]
    s = max(width / w, height / h)
    nw, nh = max(width, int(round(w * s))), max(height, int(round(h * s)))
    interp = cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR
    img = cv2.resize(img, (nw, nh), interpolation=interp) if (nw, nh) != (w, h) else img
    y0, x0 = (nh - height) // 2, (nw - width) // 2
    return np.ascontiguousarray(img[y0:y0 + height, x0:x0 + width])


def wide_blur(field: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian blur of a float32 field by a wide ``sigma`` (px), mirrored at the image
    edge, done at 1/f of the resolution (f = sigma // 8) and resized back: within 0.002
    of the full-resolution blur of a 0/1 mask, at 1/16 of its time for sigma = 43 px (a
    window's glow on a 512^2 room)."""
    h, w = field.shape[:2]
    f = max(1, int(sigma // 8))
    if f == 1:
        return cv2.GaussianBlur(field, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    sw, sh = max(round(w / f), 1), max(round(h / f), 1)  # sigma scales with each axis
    small = cv2.resize(field, (sw, sh), interpolation=cv2.INTER_AREA)
    blurred = cv2.GaussianBlur(small, (0, 0), sigmaX=sigma * sw / w, sigmaY=sigma * sh / h,
                               borderType=cv2.BORDER_REFLECT)  # mirrored at the edge, at any scale
    return cv2.resize(blurred, (w, h), interpolation=cv2.INTER_LINEAR)


class _Backgrounds(Sequence):
    ids: list
    meta: list

    def __len__(self):
        return len(self.ids)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        return self._image(range(len(self))[i])

    def get(self, i: int, width: int, height: int) -> np.ndarray:
        """Image i resized to cover width x height and centre-cropped (uint8 RGB).
        The last 32 results are kept: views reuse a few backgrounds many times, and
        making a procedural room or decoding a photo costs more than a render."""
        cache = self.__dict__.setdefault("_fitted", {})
        key = (int(i), int(width), int(height))
        if key not in cache:
            if len(cache) >= 32:
                cache.pop(next(iter(cache)))
            cache[key] = fit_cover(self[i], width, height)
        return cache[key]


class FolderBackgrounds(_Backgrounds):
    """Images below a folder, read on access. Files that fail to read are skipped with a
    warning when indexed; ``skipped`` lists them."""

    def __init__(self, path):
        self.path = os.fspath(path)
        if not os.path.isdir(self.path):
            raise BackgroundError(f"{self.path}: background folder not found")
        files = []
        for root, dirs, names in os.walk(self.path):
            dirs[:] = sorted(d for d in dirs if not d.startswith("."))
            files += [os.path.join(root, n) for n in sorted(names)
                      if n.lower().endswith(BACKGROUND_EXTS) and not n.startswith(".")]
        # Check every file once, so that a bad file fails here rather than mid-run.
        self.paths, self.skipped = [], []
        for p in files:
            if _readable(p):
                self.paths.append(p)
            else:
                self.skipped.append(p)
                log.warning("%s: unreadable background image, skipped", p)
        if not self.paths:
            raise BackgroundError(
                f"{self.path}: no readable background images ({len(files)} image files found, "
                f"{len(self.skipped)} unreadable; extensions {', '.join(BACKGROUND_EXTS)})")
        self.ids = [os.path.splitext(os.path.relpath(p, self.path))[0].replace(os.sep, "/")
                    for p in self.paths]
        self.meta = [{"path": p, "source": "folder"} for p in self.paths]

    def _image(self, i):
        return read_rgb(self.paths[i])


def _readable(path) -> bool:
    # Decoding only the header would miss truncated files; backgrounds are few, decode fully.
    try:
        read_rgb(path)
        return True
    except ImageError:
        return False


def load_backgrounds(path) -> FolderBackgrounds:
    """Backgrounds from every jpg/png/bmp/tif/webp below `path` (recursive).

    Unreadable files are skipped with a warning; BackgroundError names `path` if none is
    readable.
    """
    return FolderBackgrounds(path)


# ---------------------------------------------------------------------------------------
# Procedural rooms: a wall with a light gradient, a floor in perspective (planks or tiles),
# and some of: a bright window, a door frame, a picture, furniture boxes, a skirting board.

_WALLS = [(226, 220, 205), (200, 210, 215), (235, 232, 225), (210, 195, 170), (180, 195, 180),
          (215, 200, 200), (190, 190, 195), (228, 196, 168), (232, 218, 172)]
_WOODS = [(150, 105, 65), (120, 80, 50), (175, 140, 100), (95, 65, 45), (185, 160, 125)]
_TILES = [(200, 200, 195), (150, 150, 150), (215, 205, 185), (120, 110, 100), (230, 230, 230)]
_FURN = [(90, 60, 40), (60, 60, 65), (140, 110, 80), (200, 200, 195), (70, 90, 110), (110, 40, 40)]


# Clinical backdrops: what surrounds skin in clinical photographs (sRGB); "fabric"
# (clothing, curtains, towels) takes any dye, from fabric_colour
BACKDROPS = {
    "drape": [(40, 110, 160), (30, 120, 130), (60, 140, 120), (45, 85, 150), (90, 150, 170)],
    "sheet": [(232, 232, 228), (215, 222, 230), (200, 212, 220), (236, 230, 220)],
    "paper": [(238, 238, 233), (228, 230, 226)],
    "wall": [(200, 200, 195), (215, 210, 200), (170, 180, 185), (120, 130, 140), (60, 62, 66),
             (225, 192, 160), (196, 120, 80)],
    # black velvet or a dark room: medical photography's standard backdrop, and what a
    # room becomes behind a flash-lit patient (4 of the 9 dev photographs with non-skin)
    "dark": [(14, 14, 16), (22, 20, 20), (10, 12, 18), (26, 24, 22)],
}
BACKDROP_SHARES = {"drape": 0.25, "sheet": 0.18, "paper": 0.1, "wall": 0.12, "fabric": 0.22, "dark": 0.13}


# backdrops of cloth: lit across their folds, with a weave
CLOTH_BACKDROPS = ("drape", "sheet", "fabric", "dark")
# backdrops that lie against the patient, lit by a flash as the skin is (a room or a wall
# is far behind and gets only the room's light)
NEAR_BACKDROPS = ("drape", "sheet", "paper", "fabric")


def fabric_colour(rng) -> np.ndarray:
    """The sRGB colour (0..255) of a garment, curtain or towel: any hue, at lightness
    L* 15-85, mostly muted (chroma a Beta(1.3, 2.5) draw of 0-75: greys, earth tones,
    denim) and now and then a strong dye. Skin-like tans, browns and rusts among them,
    as in clinical photographs, so that hue alone does not tell skin from cloth."""
    light, chroma, hue = rng.uniform(15, 85), 75 * rng.beta(1.3, 2.5), rng.uniform(0, 2 * np.pi)
    lab = np.array([light, chroma * np.cos(hue), chroma * np.sin(hue)])
    return np.clip(np.rint(lab_to_srgb(lab) * 255), 0, 255)


def backdrop_layout(kind: str, rng) -> dict:
    """A clinical backdrop of ``kind`` (a BACKDROP_SHARES key): its colour, folds, fold
    direction and light, and for some fabrics a stripe or check print."""
    if kind == "fabric":
        colour = fabric_colour(rng)
    else:
        table = BACKDROPS[kind]
        colour = np.clip(np.array(table[rng.integers(len(table))]) + rng.normal(0, 8, 3), 0, 255)
    out = {"kind": kind, "colour": tuple(int(c) for c in colour),
           "folds": float(rng.uniform(0.3, 1.0)), "angle": float(rng.uniform(0, 180)),
           "light": float(rng.uniform(0, 360))}
    if kind == "fabric" and rng.random() < 0.4:   # a striped or checked cloth
        out.update(pattern=str(rng.choice(["stripes", "check"])),
                   colour2=tuple(int(c) for c in fabric_colour(rng)),
                   period=float(np.exp(rng.uniform(np.log(0.01), np.log(0.12)))),
                   duty=float(rng.uniform(0.15, 0.6)))
    return out


def backdrop_image(m: dict, n: int, rng) -> np.ndarray:
    """An n x n uint8 image of backdrop ``m`` (see backdrop_layout): a colour lit across
    by folds (a height field's slope towards the light), with the weave or grain of the
    material and sensor noise."""
    yy, xx = np.mgrid[0:n, 0:n].astype(np.float32) / n
    a = np.radians(m["angle"])
    u = xx * np.cos(a) + yy * np.sin(a)
    height = np.zeros((n, n), np.float32)
    if m["kind"] in CLOTH_BACKDROPS:
        # folds: ridges along one direction, bent by noise
        bend = 0.15 * fractal_noise(rng, (n, n), n / 2, octaves=2)
        height += m["folds"] * (np.sin(2 * np.pi * (u + bend) * rng.uniform(2, 5))
                                + 0.5 * fractal_noise(rng, (n, n), n / 5, octaves=3))
    elif m["kind"] == "paper":
        crinkle = np.abs(fractal_noise(rng, (n, n), n / 8, octaves=4))
        height += 0.15 * (1 - np.clip(crinkle * 2, 0, 1))
    gy, gx = np.gradient(height * n / 40.0)
    la = np.radians(m["light"])
    shade = 1 + 0.35 * np.clip(gx * np.cos(la) + gy * np.sin(la), -2, 2)
    shade *= 1 - 0.25 * np.hypot(xx - 0.5, yy - 0.5)                  # light falls off
    img = np.array(m["colour"], np.float32)[None, None] * shade[..., None]
    if "pattern" in m:   # the print follows the cloth (the fold direction)
        mark = ((u / m["period"]) % 1.0 < m["duty"]).astype(np.float32)
        if m["pattern"] == "check":
            across = -xx * np.sin(a) + yy * np.cos(a)
            mark = np.maximum(mark, ((across / m["period"]) % 1.0 < m["duty"]).astype(np.float32))
        mark = cv2.GaussianBlur(mark, (0, 0), 0.7)[..., None]
        img = img * (1 - mark) + np.array(m["colour2"], np.float32) * shade[..., None] * mark
    if m["kind"] in CLOTH_BACKDROPS:                                  # the weave
        period = rng.uniform(2.5, 5.0)
        weave = np.sin(2 * np.pi * xx * n / period) * np.sin(2 * np.pi * yy * n / period)
        img *= (1 + 0.04 * weave)[..., None]
    else:
        img += 3.0 * fractal_noise(rng, (n, n), 2.0, octaves=2)[..., None]
    img = cv2.GaussianBlur(img, (0, 0), 0.6) + 1.5 * rng.standard_normal(img.shape, np.float32)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


class ProceduralBackgrounds(_Backgrounds):
    """`n` seeded backgrounds, size x size, rendered on access (image i depends only on
    (seed, first + i)): indoor rooms and, with probability ``clinical``, the backdrops of
    clinical photographs (surgical drapes, sheets, couch paper, plain walls, clothing
    fabric, black cloth)."""

    def __init__(self, n: int, seed: int = 0, size: int = 512, clinical: float = 0.0, first: int = 0):
        if int(size) < 64:
            raise BackgroundError(f"procedural background size must be >= 64 px, got {size}")
        self.seed, self.size, self.clinical = int(seed), int(size), float(clinical)
        self.ids, self.meta = [], []
        for k in range(int(first), int(first) + int(n)):
            backdrop = self._backdrop(k)
            self.ids.append(f"{'room' if backdrop is None else backdrop['kind']}-{self.seed}-{k}")
            self.meta.append(dict(self._layout(k) if backdrop is None else backdrop,
                                  source="procedural", seed=self.seed, index=k))

    def _backdrop(self, i):
        """A clinical backdrop's layout, or None for a room (drawn from a stream of its
        own, so rooms stay as they were when ``clinical`` is 0)."""
        if self.clinical <= 0:
            return None
        rng = np.random.default_rng([self.seed, i, 7])
        if rng.random() >= self.clinical:
            return None
        kind = str(rng.choice(list(BACKDROP_SHARES), p=list(BACKDROP_SHARES.values())))
        return backdrop_layout(kind, rng)

    def _layout(self, i):
        rng = np.random.default_rng([self.seed, i, 0])
        pick = lambda table: tuple(int(c) for c in np.clip(
            np.array(table[rng.integers(len(table))]) + rng.normal(0, 8, 3), 0, 255))
        return {"horizon": float(rng.uniform(0.55, 0.75)), "wall": pick(_WALLS),
                "floor": str(rng.choice(["planks", "tiles"])), "floor_colour": pick(_WOODS + _TILES),
                "light_x": float(rng.uniform(0, 1)), "window": bool(rng.random() < 0.6),
                "door": bool(rng.random() < 0.5), "picture": bool(rng.random() < 0.5),
                "furniture": int(rng.integers(0, 3)), "vanish_x": float(rng.uniform(0.3, 0.7)),
                "corner": float(rng.choice([0.12, 0.88]) + rng.uniform(-0.06, 0.06))
                if rng.random() < 0.4 else None}

    def _image(self, i):
        m, n = self.meta[i], self.size
        rng = np.random.default_rng([self.seed, m["index"], 1])
        if "kind" in m:
            return backdrop_image(m, self.size, rng)
        img = np.empty((n, n, 3), np.float32)
        yy, xx = np.mgrid[0:n, 0:n].astype(np.float32) / n
        hz = int(m["horizon"] * n)
        # Wall: soft fall-off from a light source, plus faint plaster texture.
        light = 1.0 - 0.45 * np.clip(np.hypot(xx - m["light_x"], yy * 0.7), 0, 1.2)
        img[:] = np.array(m["wall"], np.float32) * light[..., None]
        img += 3.0 * fractal_noise(rng, (n, n), n / 6, octaves=5)[..., None]
        if m["window"]:
            self._window(img, rng, hz, m)
        if m["door"]:
            self._door(img, rng, hz)
        if m["picture"]:
            self._picture(img, rng, hz)
        if m["corner"] is not None:  # a room corner: the side wall gets less light
            x = int(m["corner"] * n)
            side = slice(0, x) if m["corner"] < 0.5 else slice(x, n)
            img[:hz, side] *= 0.8
            cv2.line(img, (x, 0), (x, hz), tuple(float(c) * 0.7 for c in m["wall"]), 1, cv2.LINE_AA)
        self._floor(img, rng, hz, m)
        cv2.rectangle(img, (0, hz - max(2, n // 60)), (n, hz), (245, 245, 240), -1)  # skirting
        for _ in range(m["furniture"]):
            self._furniture(img, rng, hz)
        img = cv2.GaussianBlur(img, (0, 0), 0.8) + 1.5 * rng.standard_normal(img.shape, np.float32)
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)

    def _window(self, img, rng, hz, m):
        n = self.size
        w, h = int(rng.uniform(0.18, 0.3) * n), int(rng.uniform(0.3, 0.45) * hz)
        x0 = int(np.clip(m["light_x"] * n - w / 2, 2, n - w - 2))
        y0 = int(rng.uniform(0.12, 0.25) * hz)
        sky = np.array([235, 242, 250], np.float32)
        gy = np.linspace(0, 1, h)[:, None, None]
        img[y0:y0 + h, x0:x0 + w] = sky * (1 - 0.1 * gy) + np.array([0, 5, 10]) * gy
        # Glow on the wall around the window.
        glow = np.zeros(img.shape[:2], np.float32)
        glow[y0:y0 + h, x0:x0 + w] = 1
        img += 25 * wide_blur(glow, n / 12)[..., None]
        frame = (250, 250, 248)
        t = max(2, n // 90)
        cv2.rectangle(img, (x0, y0), (x0 + w, y0 + h), frame, t)
        cv2.line(img, (x0 + w // 2, y0), (x0 + w // 2, y0 + h), frame, t)
        cv2.line(img, (x0, y0 + h // 2), (x0 + w, y0 + h // 2), frame, t)
        cv2.rectangle(img, (x0 - 2 * t, y0 + h), (x0 + w + 2 * t, y0 + h + 2 * t), (235, 235, 230), -1)

    def _door(self, img, rng, hz):
        n = self.size
        w = int(rng.uniform(0.14, 0.2) * n)
        x0 = int(rng.uniform(0.02, 0.98) * (n - w))
        y0 = int(hz * rng.uniform(0.15, 0.25))
        painted = rng.random() < 0.5
        col = np.array((236, 234, 228) if painted else _WOODS[rng.integers(len(_WOODS))], np.float32)
        img[y0:hz, x0:x0 + w] = col * np.linspace(1.0, 0.85, w)[None, :, None]
        t = max(2, n // 100)
        cv2.rectangle(img, (x0 - t, y0 - t), (x0 + w + t, hz), tuple(float(c) for c in col * 0.75), t)
        for yy in (y0 + (hz - y0) // 8, y0 + (hz - y0) // 2):  # panels
            cv2.rectangle(img, (x0 + w // 6, yy), (x0 + 5 * w // 6, yy + (hz - y0) // 3),
                          tuple(float(c) for c in col * 0.9), 1, cv2.LINE_AA)
        cv2.circle(img, (x0 + int(0.85 * w), y0 + (hz - y0) // 2), max(2, n // 120), (200, 180, 90), -1)

    def _picture(self, img, rng, hz):
        n = self.size
        w, h = int(rng.uniform(0.12, 0.22) * n), int(rng.uniform(0.1, 0.18) * n)
        x0, y0 = int(rng.uniform(0.05, 0.95) * (n - w)), int(rng.uniform(0.1, 0.4) * hz)
        art = np.empty((h, w, 3), np.float32)
        top, bottom = rng.uniform(60, 230, 3), rng.uniform(40, 200, 3)
        art[:] = top + (bottom - top) * np.linspace(0, 1, h)[:, None, None]
        art += 20 * fractal_noise(rng, (h, w), max(4, w / 4))[..., None]
        img[y0:y0 + h, x0:x0 + w] = art
        cv2.rectangle(img, (x0, y0), (x0 + w, y0 + h), (40, 35, 30), max(2, n // 120))

    def _floor(self, img, rng, hz, m):
        n, ss = self.size, 2  # 2x supersampling: joints near the horizon would alias
        col = np.array(m["floor_colour"], np.float32)
        ys = (np.arange(hz * ss, n * ss, dtype=np.float32) + 0.5) / ss
        depth = (ys - hz + 1) / (n - hz)  # 0 at the horizon, 1 at the bottom (near)
        vx = m["vanish_x"] * n
        # Floor coordinates: u across (converging to the vanishing point), v into the room.
        xs = (np.arange(n * ss, dtype=np.float32) + 0.5) / ss
        u = (xs[None, :] - vx) / (depth[:, None] + 0.05) / n
        v = 1.0 / (depth[:, None] + 0.05)
        u, v = np.broadcast_arrays(u, v)
        if m["floor"] == "planks":
            plank = np.floor(u * 6)
            shade = 1 + 0.08 * np.sin(plank * 12.9898) + 0.05 * np.sin(plank * 78.233 + v * 0.3)
            grain = 0.05 * np.sin(u * 6 * 40 + 3 * np.sin(v * 2 + plank))
            joint = (np.abs(u * 6 - np.round(u * 6)) < 0.02 * (v / 2 + 0.5))
            tex = shade + grain - 0.25 * joint
        else:
            tu, tv = u * 4, v * 0.8
            joint = (np.abs(tu - np.round(tu)) < 0.03 * (v / 3 + 0.5)) | (np.abs(tv - np.round(tv)) < 0.03)
            tex = 1 + 0.04 * np.sin(np.floor(tu) * 7.1 + np.floor(tv) * 3.3) - 0.2 * joint
        near = 0.75 + 0.3 * depth[:, None]  # the far floor is darker
        floor = cv2.resize((tex * near).astype(np.float32), (n, n - hz), interpolation=cv2.INTER_AREA)
        floor = col * floor[..., None] + 4 * fractal_noise(rng, (n - hz, n), n / 10)[..., None]
        img[hz:] = floor
        # A soft reflection of the window on a glossy floor.
        if m["window"]:
            x = int(m["light_x"] * n)
            refl = np.zeros(img.shape[:2], np.float32)
            cv2.ellipse(refl, (x, hz + (n - hz) // 3), (n // 10, (n - hz) // 4), 0, 0, 360, 1.0, -1)
            img += 20 * wide_blur(refl, n / 30)[..., None]

    def _furniture(self, img, rng, hz):
        n = self.size
        col = np.array(_FURN[rng.integers(len(_FURN))], np.float32)
        w, h = int(rng.uniform(0.15, 0.4) * n), int(rng.uniform(0.15, 0.35) * n)
        x0 = int(rng.uniform(0, 1) * (n - w))
        y1 = int(hz + rng.uniform(0.05, 0.4) * (n - hz))
        y0, d = max(0, y1 - h), int(0.25 * h)
        shadow = np.zeros(img.shape[:2], np.float32)
        cv2.rectangle(shadow, (x0 - 4, y1 - 4), (x0 + w + 8, y1 + 6), 1.0, -1)
        img *= 1 - 0.35 * cv2.GaussianBlur(shadow, (0, 0), n / 80)[..., None]
        # Front face, top face (lighter) and legs: a cabinet, table or sofa-like box.
        img[y0:y1, x0:x0 + w] = col * np.linspace(0.95, 0.8, y1 - y0)[:, None, None]
        top = np.array([[x0, y0], [x0 + w, y0], [x0 + w - d // 2, y0 - d // 2], [x0 + d // 2, y0 - d // 2]])
        cv2.fillConvexPoly(img, top.astype(np.int32), tuple(float(c) for c in np.minimum(col * 1.2, 255)))
        if rng.random() < 0.5:  # drawers / cushions
            k = int(rng.integers(2, 4))
            for j in range(1, k):
                x = x0 + j * w // k
                cv2.line(img, (x, y0 + 3), (x, y1 - 3), tuple(float(c) for c in col * 0.6), 1, cv2.LINE_AA)


def procedural_backgrounds(n: int, seed: int = 0, size: int = 512, clinical: float = 0.0,
                           first: int = 0) -> ProceduralBackgrounds:
    """`n` seeded procedural backgrounds (size x size); see ProceduralBackgrounds."""
    return ProceduralBackgrounds(n, seed, size, clinical, first)
