"""Skin-condition sources: real images with masks (Fitzpatrick17k annotations, ISIC/HAM10000,
PH2, images/ + masks/ folders) and seeded procedural lesions rendered on a skin patch.

Every source yields :class:`Lesion` objects: an RGB crop around the lesion (the mask's
bounding box plus ~25% of its size as surrounding skin context) and the boolean mask of
the same size.
"""
from __future__ import annotations

import csv
import logging
import os
import re
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy import ndimage

from ..errors import InputError
from ..io.images import ImageError, read_mask, read_rgb
from .colour import ita_range, lab_to_uint8, shades_of_gray

log = logging.getLogger(__name__)

IMAGE_EXTS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")
CROP_MARGIN = 0.25
_FITZ_MASKS = ("selected_lesion.png", "lesions.png", "nonskin.png")
# Stem suffixes that mark a file as a mask in the "pairs" layout (ISIC, PH2, generic).
_MASK_SUFFIX = re.compile(r"(_segmentation|_seg|_mask|_lesion|_gt|_label|-mask)$", re.I)
_MASK_DIRS = {"masks", "mask", "labels", "segmentations", "groundtruth", "ground_truth", "gt"}
# Files in those datasets that are neither images nor lesion masks (ISIC superpixels, PH2 ROIs).
_IGNORE = re.compile(r"(_superpixels|_R\d+_Label\d+)$", re.I)
_CSV_KEYS = ("name", "image_id", "image", "isic_id", "md5hash", "id")
MIN_SIZE = 16              # px, shorter side of a lesion image (config lesions.min_size)
MAX_MASK_FRACTION = 0.95   # of its image a mask may cover (config lesions.max_mask_fraction)


class LesionError(InputError):
    """A lesion image or mask is unusable; the message names the file and the problem."""


class RejectedLesionError(LesionError):
    """A readable lesion that cannot be pasted; a lesion set skips it, counted by ``reason``."""
    reason = "rejected"


class EmptyMaskError(RejectedLesionError):
    """The lesion mask has no set pixel."""
    reason = "with empty lesion masks"


class LesionTooSmallError(RejectedLesionError):
    """The lesion image is smaller than the minimum size."""
    reason = "with images below the minimum size"


class MaskTooLargeError(RejectedLesionError):
    """The mask covers (nearly) the whole image: no skin around the lesion."""
    reason = "with masks covering nearly the whole image"


@dataclass
class Lesion:
    """A skin condition on its surrounding skin.

    image: HxWx3 uint8 RGB crop. mask: HxW bool, True on the lesion.
    meta: source information. For file sources: ``image_path``, ``mask_path``, ``crop``
    (x0, y0, x1, y1 in the full image), ``layout``, and for Fitzpatrick17k folders
    ``lesions_mask_path`` / ``nonskin_mask_path`` plus the CSV row (``label``,
    ``fitzpatrick``, ...). For procedural lesions: ``kind``, ``seed``, ``params``,
    ``fitzpatrick``.
    """
    image: np.ndarray
    mask: np.ndarray
    id: str
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        img, m = self.image, self.mask
        if not isinstance(img, np.ndarray) or img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
            raise LesionError(f"lesion {self.id}: image must be HxWx3 uint8 RGB, got "
                              f"{getattr(img, 'dtype', type(img))} {getattr(img, 'shape', '')}")
        if not isinstance(m, np.ndarray) or m.dtype != bool or m.shape != img.shape[:2]:
            raise LesionError(f"lesion {self.id}: mask must be bool {img.shape[:2]}, got "
                              f"{getattr(m, 'dtype', type(m))} {getattr(m, 'shape', '')}")
        if not m.any():
            raise EmptyMaskError(f"lesion {self.id}: mask is empty")

    # Full-image ground truth (Fitzpatrick17k layout), read on demand for evaluation.
    @property
    def lesions_mask(self) -> np.ndarray | None:
        """Full-image bool mask of all lesions (lesions.png), or None when not available."""
        return _optional_mask(self.meta.get("lesions_mask_path"))

    @property
    def nonskin_mask(self) -> np.ndarray | None:
        """Full-image bool mask of non-skin pixels (nonskin.png), or None when not available."""
        return _optional_mask(self.meta.get("nonskin_mask_path"))

    def full_image(self) -> np.ndarray | None:
        """The whole source image (uncropped, no colour constancy), or None for procedural ones."""
        path = self.meta.get("image_path")
        return read_rgb(path) if path else None


def _optional_mask(path):
    return read_mask(path) if path and os.path.isfile(path) else None


# ---------------------------------------------------------------------------------------
# Reading one image + mask


def crop_box(mask: np.ndarray, margin: float = CROP_MARGIN) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1), exclusive end: the mask's bounding box grown by `margin` of its size."""
    ys, xs = np.nonzero(mask)
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    my = max(2, int(round(margin * (y1 - y0))))
    mx = max(2, int(round(margin * (x1 - x0))))
    h, w = mask.shape
    return max(0, x0 - mx), max(0, y0 - my), min(w, x1 + mx), min(h, y1 + my)


def load_lesion(image_path, mask_path, lesion_id=None, meta=None, colour_constancy=False,
                min_size=MIN_SIZE, max_mask_fraction=MAX_MASK_FRACTION) -> Lesion:
    """Read one image and its lesion mask, check them, and crop around the lesion.
    Images with a side below ``min_size`` pixels and masks covering more than
    ``max_mask_fraction`` of the image raise a RejectedLesionError saying why."""
    image_path, mask_path = os.fspath(image_path), os.fspath(mask_path)
    try:
        img = read_rgb(image_path)
    except ImageError as e:
        raise LesionError(f"lesion image {e}") from None
    try:
        mask = read_mask(mask_path)
    except ImageError as e:
        raise LesionError(f"lesion mask {e}") from None
    if min(img.shape[:2]) < min_size:
        raise LesionTooSmallError(f"{image_path}: image is {img.shape[1]}x{img.shape[0]} pixels, "
                                  f"below the minimum lesion size ({min_size} px, lesions.min_size)")
    if mask.shape != img.shape[:2]:
        raise LesionError(f"{mask_path}: mask size {mask.shape[1]}x{mask.shape[0]} differs from "
                          f"image {image_path} size {img.shape[1]}x{img.shape[0]}")
    if not mask.any():
        raise EmptyMaskError(f"{mask_path}: mask is empty (no lesion pixels)")
    if mask.mean() > max_mask_fraction:
        raise MaskTooLargeError(f"{mask_path}: mask covers {mask.mean():.0%} of the image (more than "
                                f"lesions.max_mask_fraction {max_mask_fraction:g}), leaving no skin "
                                "around the lesion; is it inverted?")
    if mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any():
        log.warning("%s: lesion mask touches the image border; the lesion may be cut off", mask_path)
    if colour_constancy:
        img = shades_of_gray(img)  # estimated on the whole image, before cropping
    x0, y0, x1, y1 = crop_box(mask)
    meta = dict(meta or {}, image_path=image_path, mask_path=mask_path,
                crop=(int(x0), int(y0), int(x1), int(y1)), colour_constancy=bool(colour_constancy))
    lesion_id = lesion_id or os.path.splitext(os.path.basename(image_path))[0]
    return Lesion(np.ascontiguousarray(img[y0:y1, x0:x1]),
                  np.ascontiguousarray(mask[y0:y1, x0:x1]), lesion_id, meta)


# ---------------------------------------------------------------------------------------
# Sources


@dataclass
class _Entry:
    id: str
    image_path: str
    mask_paths: list  # candidates in order of preference; the first non-empty one is used
    meta: dict


class LesionSet(Sequence):
    """A sequence of lesions from files. Eager sets hold the loaded crops; lazy sets read
    (and check) each lesion when it is indexed. ``skipped`` counts skipped folders/images
    by reason."""

    def __init__(self, path, entries, colour_constancy=False, lazy=False, skipped=None,
                 min_size=MIN_SIZE, max_mask_fraction=MAX_MASK_FRACTION):
        self.path, self.colour_constancy, self.lazy = os.fspath(path), colour_constancy, lazy
        self.limits = {"min_size": min_size, "max_mask_fraction": max_mask_fraction}
        self.skipped = Counter(skipped or {})
        self._loaded = None
        if not lazy:
            kept, self._loaded = [], []
            for e in entries:
                try:
                    self._loaded.append(self._load(e))
                    kept.append(e)
                except RejectedLesionError as err:
                    log.warning("%s; skipped", err)
                    self.skipped[err.reason] += 1
            entries = kept
        self.entries = entries

    def __len__(self):
        return len(self.entries)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        return self._loaded[i] if self._loaded is not None else self._load(self.entries[i])

    @property
    def ids(self) -> list[str]:
        return [e.id for e in self.entries]

    def _load(self, e: _Entry) -> Lesion:
        # selected_lesion.png may be present but empty: fall back to the next candidate.
        for mask_path in e.mask_paths[:-1]:
            try:
                if read_mask(mask_path).any():
                    return load_lesion(e.image_path, mask_path, e.id, e.meta, self.colour_constancy,
                                       **self.limits)
            except ImageError as err:
                raise LesionError(f"lesion mask {err}") from None
            log.info("%s: empty, trying the next mask", mask_path)
        return load_lesion(e.image_path, e.mask_paths[-1], e.id, e.meta, self.colour_constancy,
                           **self.limits)


def load_lesions(path, layout: str = "fitz17k", colour_constancy: bool = False,
                 lazy: bool = False, image_dir=None, min_size=MIN_SIZE,
                 max_mask_fraction=MAX_MASK_FRACTION) -> LesionSet:
    """Load skin conditions with masks from `path`.

    layout "fitz17k": one folder per image id (folders may be nested one level, e.g. per
    annotator) holding the image (``image.jpg``/``.png`` or ``<id>.jpg``/``.png``, or
    ``<id>.*`` in `image_dir`) and 0/255 masks ``lesions.png``, ``nonskin.png``,
    ``selected_lesion.png``. The pasted mask is ``selected_lesion.png`` if present and
    non-empty, else ``lesions.png``. Folders without an image or a lesion mask are skipped.
    layout "pairs": images paired with masks anywhere below `path`: ISIC/HAM10000
    (``X.jpg`` + ``X_segmentation.png``), PH2 (``X.bmp`` + ``X_lesion.bmp``), or
    ``images/`` + ``masks/`` folders with matching stems (mask suffix optional).
    Any ``*.csv`` directly in `path` with a ``name`` (or ``image_id``/``md5hash``) column
    adds its row to each lesion's meta.

    lazy=False reads and checks every lesion now: lesions whose masks are all empty, whose
    image has a side below ``min_size`` px or whose mask covers more than
    ``max_mask_fraction`` of the image are skipped (counted in ``.skipped`` by reason), any
    other bad file raises LesionError. lazy=True only
    indexes the files (use it for large sets such as ISIC); errors come when indexing.
    Raises LesionError naming `path` and the skip reasons if no usable lesion remains.
    """
    path = os.fspath(path)
    if not os.path.isdir(path):
        raise LesionError(f"{path}: lesion folder not found")
    if layout == "fitz17k":
        entries, skipped = _index_fitz17k(path, image_dir)
    elif layout == "pairs":
        entries, skipped = _index_pairs(path)
    else:
        raise LesionError(f"unknown lesion layout {layout!r} (expected 'fitz17k' or 'pairs')")
    rows = _read_csv_rows(path)
    for e in entries:
        row = rows.get(e.meta.get("image_id", e.id)) or rows.get(os.path.basename(e.image_path))
        if row:
            e.meta.update(row)
    lesions = LesionSet(path, entries, colour_constancy, lazy, skipped, min_size, max_mask_fraction)
    for reason, n in lesions.skipped.items():
        log.warning("%s: skipped %d %s", path, n, reason)
    if not len(lesions):
        why = ", ".join(f"{n} {r}" for r, n in lesions.skipped.items()) or "no image/mask files found"
        raise LesionError(f"{path}: no usable lesions in layout {layout!r} (skipped: {why})")
    log.info("%s: %d lesions (%s layout)", path, len(lesions), layout)
    return lesions


def _find_image(folder, names):
    for name in names:
        for ext in IMAGE_EXTS:
            p = os.path.join(folder, name + ext)
            if os.path.isfile(p):
                return p
    return None


def _index_fitz17k(path, image_dir):
    folders = []
    for root, dirs, files in os.walk(path):
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        if root == path:
            continue
        depth = os.path.relpath(root, path).count(os.sep)
        # Direct children are id folders unless they only hold sub-folders (annotators).
        if any(f in files for f in _FITZ_MASKS) or (depth == 0 and (files or not dirs)):
            folders.append(root)
    entries, skipped = [], Counter()
    for folder in folders:
        fid = os.path.basename(folder)
        img = _find_image(folder, ("image", fid))
        if img is None:  # otherwise accept a single non-mask image of any name
            others = [f for f in sorted(os.listdir(folder)) if f.lower().endswith(IMAGE_EXTS)
                      and f not in _FITZ_MASKS and os.path.isfile(os.path.join(folder, f))]
            img = os.path.join(folder, others[0]) if len(others) == 1 else None
        if img is None and image_dir is not None:
            img = _find_image(image_dir, (fid,))
        if img is None:
            skipped["folders without an image"] += 1
            continue
        masks = [os.path.join(folder, n) for n in ("selected_lesion.png", "lesions.png")]
        masks = [m for m in masks if os.path.isfile(m)]
        if not masks:
            skipped["folders without selected_lesion.png or lesions.png"] += 1
            continue
        meta = {"layout": "fitz17k", "folder": folder, "image_id": fid,
                "lesions_mask_path": os.path.join(folder, "lesions.png"),
                "nonskin_mask_path": os.path.join(folder, "nonskin.png")}
        entries.append(_Entry(fid, img, masks, meta))
    # The same image annotated in several (annotator) folders: keep ids unique.
    counts = Counter(e.id for e in entries)
    for e in entries:
        if counts[e.id] > 1:
            e.id = os.path.relpath(e.meta["folder"], path).replace(os.sep, "/")
    return entries, skipped


def _index_pairs(path):
    images, masks = [], {}
    for root, dirs, files in os.walk(path):
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        in_mask_dir = any(part.lower() in _MASK_DIRS
                          for part in os.path.relpath(root, path).split(os.sep))
        for f in sorted(files):
            stem, ext = os.path.splitext(f)
            if ext.lower() not in IMAGE_EXTS or _IGNORE.search(stem):
                continue
            p = os.path.join(root, f)
            key = _MASK_SUFFIX.sub("", stem).lower()
            if _MASK_SUFFIX.search(stem) or in_mask_dir:
                masks.setdefault(key, []).append(p)
            else:
                images.append((stem, p))
    entries, skipped = [], Counter()
    for stem, img in images:
        cands = masks.get(stem.lower())
        if not cands:
            skipped["images without a mask"] += 1
            continue
        # Several masks with the same stem: take the one closest to the image in the tree.
        mask = max(cands, key=lambda m: len(os.path.commonpath([m, img])))
        entries.append(_Entry(stem, img, [mask], {"layout": "pairs"}))
    return entries, skipped


def _read_csv_rows(path) -> dict:
    rows = {}
    for f in sorted(os.listdir(path)):
        if not f.lower().endswith(".csv"):
            continue
        p = os.path.join(path, f)
        try:
            with open(p, newline="", encoding="utf-8-sig") as fh:
                reader = csv.DictReader(fh)
                key = next((k for k in _CSV_KEYS if k in (reader.fieldnames or [])), None)
                if key is None:
                    log.warning("%s: no name/image_id column, ignored", p)
                    continue
                for row in reader:
                    name = (row.get(key) or "").strip()
                    if not name:
                        continue
                    row = {k: _csv_value(k, v) for k, v in row.items() if k is not None}
                    rows[name] = row
                    rows.setdefault(os.path.splitext(name)[0], row)
        except (OSError, UnicodeDecodeError, csv.Error) as e:
            log.warning("%s: unreadable metadata CSV (%s), ignored", p, e)
    return rows


def _csv_value(key, value):
    if key == "fitzpatrick":  # Fitzpatrick17k uses -1 for "unknown"
        try:
            v = int(float(value))
            return v if 1 <= v <= 6 else None
        except (TypeError, ValueError):
            return None
    return value


# ---------------------------------------------------------------------------------------
# Procedural lesions. Colours are built in CIELAB: a textured skin patch, then each kind
# adds a Lab offset weighted by a soft-edged alpha, so skin texture shows through where
# the condition would not hide it. A height map adds relief through simple shading.

KINDS = ("nevus", "melanoma", "psoriasis", "ulcer", "vitiligo", "eczema")


def fractal_noise(rng: np.random.Generator, shape, scale: float, octaves: int = 4,
                  persistence: float = 0.5) -> np.ndarray:
    """Zero-mean, unit-std float32 value noise with features about `scale` pixels wide."""
    h, w = shape
    out = np.zeros((h, w), np.float32)
    amp = 1.0
    for o in range(octaves):
        step = max(scale / 2 ** o, 1.0)
        g = rng.standard_normal((int(h / step) + 2, int(w / step) + 2)).astype(np.float32)
        out += amp * cv2.resize(g, (w, h), interpolation=cv2.INTER_CUBIC)
        amp *= persistence
    return (out - out.mean()) / (out.std() + 1e-6)


def _smoothstep(e0, e1, x):
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _dots(rng, shape, count, radius, where=None):
    """Soft round dots (0..1) at random places, optionally only where `where` is True."""
    h, w = shape
    img = np.zeros(shape, np.float32)
    ys, xs = rng.integers(0, h, count), rng.integers(0, w, count)
    for y, x, r in zip(ys, xs, rng.uniform(0.6, 1.4, count) * radius):
        if where is None or where[y, x]:
            cv2.circle(img, (int(x), int(y)), max(1, int(round(r))), 1.0, -1, cv2.LINE_AA)
    return cv2.GaussianBlur(img, (0, 0), max(0.5, radius * 0.4))


def skin_colour(rng, fitzpatrick: int) -> np.ndarray:
    """A Lab skin colour whose ITA lies in the band of `fitzpatrick`."""
    lo, hi = ita_range(fitzpatrick)
    ita = np.radians(rng.uniform(max(lo, -62.0), min(hi, 66.0)))
    rho = rng.uniform(21.0, 27.0)  # distance from (b*=0, L*=50): fairly constant for skin
    if ita < 0:
        rho += 4.0 * np.sin(-ita)  # deep skin stays warm (b* ~ 15) rather than grey
    return np.array([50 + rho * np.sin(ita), rng.uniform(9.0, 15.0), rho * np.cos(ita)])


def _skin_patch(rng, size, base):
    """HxWx3 Lab skin: blotchy tone, pores, fine crease lines and a soft light gradient."""
    lab = np.empty((size, size, 3), np.float32)
    lab[:] = base
    lab[..., 0] += 1.6 * fractal_noise(rng, (size, size), size / 3)
    lab[..., 1] += 1.4 * fractal_noise(rng, (size, size), size / 5)
    lab[..., 2] += 0.8 * fractal_noise(rng, (size, size), size / 4)
    lab[..., 0] += 0.7 * fractal_noise(rng, (size, size), 2.0, octaves=2)
    pores = _dots(rng, (size, size), size * size // 150, 0.8)
    lab[..., 0] -= 2.5 * pores
    # Micro-relief: fine bumps plus crease lines (valleys of stretched noise, two directions).
    height = 0.6 * fractal_noise(rng, (size, size), 4.0, octaves=2) - 1.5 * pores
    for angle in rng.uniform(0, 180, 2):
        n = fractal_noise(rng, (size, size * 4), 6.0, octaves=2)
        n = cv2.resize(n, (size, size), interpolation=cv2.INTER_AREA)
        m = cv2.getRotationMatrix2D((size / 2, size / 2), angle, 1.3)
        n = cv2.warpAffine(n, m, (size, size), borderMode=cv2.BORDER_REFLECT)
        height -= 1.2 * _smoothstep(0.3, 0.0, np.abs(n))
    _shade(lab, height, rng.uniform(2.0, 4.0), rng)
    yy, xx = np.mgrid[0:size, 0:size] / size - 0.5
    d = rng.normal(size=2)
    lab[..., 0] += 3.0 * (xx * d[0] + yy * d[1]) / np.hypot(*d)
    return lab


def _blob(rng, size, radius, irregularity, warp, aspect):
    """Signed distance (px, > 0 inside) of one connected, hole-free blob clear of the border."""
    n = size
    yy, xx = np.mgrid[0:n, 0:n].astype(np.float32)
    cy, cx = n / 2 + rng.uniform(-0.03, 0.03, 2) * n
    ang = rng.uniform(0, np.pi)
    u = (xx - cx) * np.cos(ang) + (yy - cy) * np.sin(ang)
    v = ((yy - cy) * np.cos(ang) - (xx - cx) * np.sin(ang)) / aspect
    theta, r = np.arctan2(v, u), np.hypot(u, v)
    radial = np.ones_like(r)
    for k in range(2, 9):
        radial += irregularity * rng.normal() / k ** 0.9 * np.cos(k * theta + rng.uniform(0, 2 * np.pi))
    r = r + warp * radius * fractal_noise(rng, (n, n), radius / 2.5, octaves=2)
    inside = r < radius * np.clip(radial, 0.5, 1.6)
    margin = max(4, n // 24)
    inside[:margin] = inside[-margin:] = False
    inside[:, :margin] = inside[:, -margin:] = False
    labels, count = ndimage.label(inside)
    if count == 0:  # degenerate draw: fall back to a plain disc
        inside = (xx - n / 2) ** 2 + (yy - n / 2) ** 2 < (0.25 * n) ** 2
    else:
        sizes = ndimage.sum(inside, labels, range(1, count + 1))
        inside = ndimage.binary_fill_holes(labels == 1 + int(np.argmax(sizes)))
    m8 = inside.astype(np.uint8)
    return (cv2.distanceTransform(m8, cv2.DIST_L2, 5)
            - cv2.distanceTransform(1 - m8, cv2.DIST_L2, 5)).astype(np.float32)


def _shade(lab, height, strength, rng):
    """Lambert-like relief: brighten slopes facing a random light, darken the others."""
    gy, gx = np.gradient(height)
    a = rng.uniform(0, 2 * np.pi)
    lab[..., 0] += strength * (gx * np.cos(a) + gy * np.sin(a))


def procedural_lesions(n: int, seed: int = 0, size: int = 256, kinds=None,
                       fitzpatrick=None) -> list[Lesion]:
    """`n` seeded procedural skin conditions on skin patches (size x size RGB + mask).

    kinds: names from KINDS (default: all), used in turn. fitzpatrick: skin type 1..6 for
    every patch, a list to draw from, or None for any. Lesion i depends only on (seed, i),
    so a longer list starts with the shorter one.
    """
    kinds = list(KINDS if kinds is None else ([kinds] if isinstance(kinds, str) else kinds))
    bad = [k for k in kinds if k not in KINDS]
    if bad or not kinds:
        raise ValueError(f"unknown procedural lesion kinds {bad or kinds}; choose from {KINDS}")
    if size < 32:
        raise ValueError(f"procedural lesion size must be >= 32 px, got {size}")
    types = list(range(1, 7)) if fitzpatrick is None else np.atleast_1d(fitzpatrick).tolist()
    for t in types:
        ita_range(t)  # validates 1..6
    out = []
    for i in range(int(n)):
        rng = np.random.default_rng([int(seed), i])
        kind = kinds[i % len(kinds)]
        fitz = int(types[rng.integers(len(types))])
        base = skin_colour(rng, fitz)
        skin = _skin_patch(rng, size, base)
        lab, sd, params = _RENDER[kind](rng, skin.copy(), base, size)
        rgb = lab_to_uint8(lab).astype(np.float32)
        rgb = cv2.GaussianBlur(rgb, (0, 0), 0.55) + rng.normal(0, 1.2, rgb.shape)
        image = np.clip(np.rint(rgb), 0, 255).astype(np.uint8)
        params = {k: (round(float(v), 4) if np.isscalar(v) and not isinstance(v, str) else v)
                  for k, v in params.items()}
        meta = {"kind": kind, "seed": int(seed), "index": i, "fitzpatrick": fitz,
                "skin_lab": [round(float(c), 2) for c in base], "params": params}
        out.append(Lesion(image, sd > 0, f"procedural-{kind}-{seed}-{i}", meta))
    return out


def _apply(lab, alpha, target):
    """Move `lab` towards the per-pixel Lab `target` by `alpha` (HxW, 0..1)."""
    lab += alpha[..., None] * (target - lab)


def _nevus(rng, lab, base, n):
    radius = rng.uniform(0.17, 0.27) * n
    sd = _blob(rng, n, radius, rng.uniform(0.04, 0.09), rng.uniform(0.02, 0.05), rng.uniform(0.75, 1.0))
    dark = rng.uniform(0.5, 0.72)
    col = np.array([max(14.0, base[0] * dark), rng.uniform(7, 12),
                    rng.uniform(17, 27) * min(1, base[0] / 50)])
    t = np.empty_like(lab)
    t[:] = col
    core = _smoothstep(0, radius * 0.8, sd)
    t[..., 0] += rng.uniform(-5, 4) * core + 2.5 * fractal_noise(rng, (n, n), radius / 4)
    t[..., 2] += 2.0 * fractal_noise(rng, (n, n), radius / 3)
    t[..., 0] -= 5 * _dots(rng, (n, n), 25, 1.2, where=sd > radius * 0.2)
    edge = rng.uniform(0.015, 0.03) * n
    alpha = _smoothstep(-1.5, edge, sd) * rng.uniform(0.9, 1.0)
    _apply(lab, alpha, t)
    height = rng.uniform(0, 6) * _smoothstep(-2, radius, sd)
    _shade(lab, height, 4.0, rng)
    return lab, sd, {"radius": radius, "darkness": dark, "edge_px": edge}


def _melanoma(rng, lab, base, n):
    radius = rng.uniform(0.22, 0.3) * n
    irr = rng.uniform(0.14, 0.24)
    sd = _blob(rng, n, radius, irr, rng.uniform(0.08, 0.16), rng.uniform(0.65, 0.95))
    shape = (n, n)
    yy, xx = np.mgrid[0:n, 0:n] / n - 0.5
    d = rng.normal(size=2)
    asym = (xx * d[0] + yy * d[1]) / np.hypot(*d) * 3.0  # one side darker: asymmetry

    def field(scale):  # smooth blotches: colours in melanoma merge rather than tile
        return fractal_noise(rng, shape, scale, octaves=2, persistence=0.4)

    darkness = field(radius / 2) + asym
    t = np.empty_like(lab)
    t[:] = (max(20.0, base[0] * 0.72), 13, 24 * min(1, base[0] / 55))
    palette = [((max(12, base[0] * 0.42), 11, 14), _smoothstep(-0.6, 0.8, darkness)),  # dark brown
               ((12, 3, 3), 0.9 * _smoothstep(0.8, 1.8, darkness)),                     # black
               ((42, 0, -5), 0.6 * _smoothstep(0.5, 1.8, field(radius / 2.5))),         # blue-grey veil
               ((50, 22, 14), 0.45 * _smoothstep(0.8, 2.0, field(radius / 2.5))),       # erythema
               ((70, 7, 11), 0.55 * _smoothstep(1.4, 2.4, field(radius / 3)))]          # regression
    for col, w in palette:
        _apply(t, w.astype(np.float32), np.array(col, np.float32))
    t[..., 0] += 2.0 * fractal_noise(rng, shape, 3.0, octaves=2)
    t[..., 0] -= 10 * _dots(rng, shape, 40, 1.6, where=(sd > 0) & (sd < radius * 0.35))
    edge = np.maximum(1.0, 0.02 * n * (1 + 0.9 * field(radius / 2)))
    alpha = np.clip((sd + 1.5) / (edge + 1.5), 0, 1)
    _apply(lab, (alpha * alpha * (3 - 2 * alpha)).astype(np.float32), t)
    inside = _smoothstep(-2, radius * 0.6, sd)
    _shade(lab, inside * (3.0 + fractal_noise(rng, shape, 6.0)), 3.0, rng)
    return lab, sd, {"radius": radius, "irregularity": irr}


def _psoriasis(rng, lab, base, n):
    radius = rng.uniform(0.24, 0.32) * n
    sd = _blob(rng, n, radius, rng.uniform(0.08, 0.14), rng.uniform(0.06, 0.12), rng.uniform(0.6, 0.95))
    shape = (n, n)
    fair = np.clip((base[0] - 25) / 45, 0, 1)  # dark skin: violaceous/brown, not bright red
    t = lab.copy()
    t[..., 0] = base[0] - rng.uniform(6, 12) + 2 * fractal_noise(rng, shape, radius / 4)
    t[..., 1] = min(28.0, base[1] + 6 + rng.uniform(8, 16) * fair) + 3 * fractal_noise(rng, shape, radius / 3)
    t[..., 2] = max(base[2], 13) + 2 * fair  # salmon-red, not magenta
    alpha = _smoothstep(-1.5, rng.uniform(2, 4), sd)
    _apply(lab, alpha, t)
    # Silvery scale: thick plates inside the plaque split by fine fissures, thin at the rim.
    cover = fractal_noise(rng, shape, radius / 2.5, octaves=2) + 2.0 * _smoothstep(0, radius * 0.6, sd)
    fissures = _smoothstep(0.03, 0.12, np.abs(fractal_noise(rng, shape, 9.0, octaves=2)))
    thick = 0.6 + 0.4 * _smoothstep(-1, 1, fractal_noise(rng, shape, 5.0, octaves=2))
    flakes = _smoothstep(0.4, 1.3, cover) * (0.35 + 0.65 * fissures) * thick * _smoothstep(2, 10, sd)
    scale_col = np.empty_like(lab)
    scale_col[:] = (min(88, max(base[0] + 16, 70)), 1.5, 5)
    scale_col[..., 0] += 2.5 * fractal_noise(rng, shape, 2.5, octaves=2)
    amount = rng.uniform(0.65, 0.9)
    _apply(lab, (amount * flakes).astype(np.float32), scale_col)
    _shade(lab, 3 * _smoothstep(-2, 6, sd) + 3.0 * flakes, 4.0, rng)
    return lab, sd, {"radius": radius, "scale_amount": amount}


def _ulcer(rng, lab, base, n):
    radius = rng.uniform(0.2, 0.3) * n
    sd = _blob(rng, n, radius, rng.uniform(0.06, 0.12), rng.uniform(0.04, 0.08), rng.uniform(0.7, 1.0))
    shape = (n, n)
    rim = rng.uniform(0.1, 0.22) * radius
    bed = _smoothstep(rim * 0.5, rim * 1.3, sd)
    # Periwound: macerated pale-pink rim on fair skin, hyperpigmented rim on dark skin.
    t = lab.copy()
    if base[0] > 50 and rng.random() < 0.7:
        t[..., 0] += rng.uniform(2, 6); t[..., 1] += rng.uniform(6, 12); t[..., 2] -= 3
    else:
        t[..., 0] -= rng.uniform(8, 15); t[..., 1] += 3
    _apply(lab, _smoothstep(-0.25 * rim, rim * 0.4, sd) * (1 - bed), t)
    lab[..., 1] += 4 * _smoothstep(-0.35 * radius, 0, sd) * (sd <= 0)  # faint erythema halo
    # Bed: granulation (beefy red, granular) with yellow slough and maybe dark eschar.
    # Granulation is cobbled: packed round buds a few pixels wide.
    grain = _dots(rng, shape, n * n // 12, rng.uniform(1.6, 2.4), where=sd > 0)
    grain = (grain - grain.mean()) / (grain.std() + 1e-6) + 0.3 * fractal_noise(rng, shape, 1.5, octaves=1)
    gran = np.empty_like(lab)
    gran[:] = (rng.uniform(34, 44), rng.uniform(40, 50), rng.uniform(22, 30))
    gran[..., 0] += 2.0 * grain + 3 * fractal_noise(rng, shape, radius / 3)
    yy, xx = np.mgrid[0:n, 0:n]
    off = rng.uniform(-0.25, 0.25, 2) * radius
    centre = 1 - np.hypot(yy - n / 2 - off[0], xx - n / 2 - off[1]) / radius
    patchy = fractal_noise(rng, shape, radius / 2.5, octaves=2, persistence=0.4)
    slough_w = _smoothstep(-0.1, 0.9, centre + 0.4 * patchy + rng.uniform(-0.4, 0.2))
    slough = np.empty_like(lab)
    slough[:] = (rng.uniform(68, 78), rng.uniform(5, 10), rng.uniform(24, 36))
    slough[..., 0] += 3 * fractal_noise(rng, shape, 4.0, octaves=2)
    _apply(gran, (0.85 * slough_w).astype(np.float32), slough)
    if rng.random() < 0.3:  # a patch of dark necrotic tissue
        eschar = _smoothstep(0.8, 2.0, fractal_noise(rng, shape, radius / 2, octaves=1)) * bed
        _apply(gran, (0.8 * eschar).astype(np.float32), np.array((28, 12, 14), np.float32))
    _apply(lab, bed.astype(np.float32), gran)
    height = -6 * bed + 1.2 * grain * bed + 2 * _smoothstep(-rim, 0, sd) * (1 - bed)
    _shade(lab, height, 4.0, rng)
    gy, gx = np.gradient(cv2.GaussianBlur(grain, (0, 0), 0.8))
    glint = _smoothstep(0.4, 0.8, gx - gy) * bed * (1 - 0.7 * slough_w)  # moist wound bed
    lab[..., 0] += 9 * glint
    lab[..., 1] -= 4 * glint
    return lab, sd, {"radius": radius, "rim_px": rim}


def _vitiligo(rng, lab, base, n):
    radius = rng.uniform(0.22, 0.32) * n
    sd = _blob(rng, n, radius, rng.uniform(0.15, 0.25), rng.uniform(0.1, 0.18), rng.uniform(0.6, 1.0))
    shape = (n, n)
    # Melanin removed: what is left is the pinkish ivory of dermis and blood.
    white = np.array((min(92, max(rng.uniform(76, 84), base[0] + 9)), rng.uniform(6, 10),
                      min(rng.uniform(9, 14), base[2] - 3)), np.float32)
    t = lab - base + white  # keep the skin's own texture, change its pigment
    alpha = _smoothstep(-1.0, rng.uniform(1.5, 3.0), sd)
    # Perifollicular repigmentation: skin-coloured freckles inside the patch.
    repig = _dots(rng, shape, int(rng.uniform(0, 40)), rng.uniform(1.2, 2.5), where=sd > 4)
    alpha = alpha * (1 - 0.8 * np.clip(repig * 2, 0, 1)) * rng.uniform(0.85, 1.0)
    alpha *= 1 - 0.25 * _smoothstep(0, 1.5, fractal_noise(rng, shape, radius / 3, octaves=3))
    if rng.random() < 0.4:  # trichrome vitiligo: a partly depigmented band inside the border
        alpha *= 1 - 0.4 * _smoothstep(0.15 * radius, 0.02 * radius, sd)
    t[..., 0] += 0.6 * (lab[..., 0] - base[0])  # texture reads weaker on white: boost it
    _apply(lab, alpha.astype(np.float32), t)
    if base[0] < 55:  # slightly hyperpigmented border on darker skin
        lab[..., 0] -= 4 * _smoothstep(-6, -1, sd) * _smoothstep(0, -6, sd) * (sd < 0)
    return lab, sd, {"radius": radius}


def _eczema(rng, lab, base, n):
    radius = rng.uniform(0.22, 0.3) * n
    sd = _blob(rng, n, radius, rng.uniform(0.1, 0.2), rng.uniform(0.1, 0.2), rng.uniform(0.6, 1.0))
    shape = (n, n)
    fair = np.clip((base[0] - 25) / 45, 0, 1)
    inside = _smoothstep(-3, rng.uniform(0.05, 0.1) * n, sd)  # ill-defined border
    intensity = inside * (0.75 + 0.25 * fractal_noise(rng, shape, radius / 3))
    lab[..., 0] -= intensity * (4 + 6 * (1 - fair))
    lab[..., 1] += intensity * (7 + 12 * fair)
    lab[..., 2] += intensity * (1.5 + 3 * fair)
    papules = _dots(rng, shape, 150, rng.uniform(1.2, 2.2), where=sd > 2)
    lab[..., 1] += 12 * fair * papules
    lab[..., 0] -= 4 * papules
    # Excoriations: short scratch marks with crusts.
    scratches = np.zeros(shape, np.float32)
    for _ in range(int(rng.integers(3, 9))):
        y, x = rng.uniform(-0.6, 0.6, 2) * radius + n / 2
        a, ln = rng.uniform(0, np.pi), rng.uniform(0.04, 0.14) * radius
        for k in range(int(ln)):  # an excoriation: a broken row of small erosions
            if rng.random() < 0.6:
                px, py = x + (k - ln / 2) * np.cos(a), y + (k - ln / 2) * np.sin(a)
                cv2.circle(scratches, (int(px), int(py)), 1, float(rng.uniform(0.5, 1)), -1, cv2.LINE_AA)
    scratches = cv2.GaussianBlur(scratches, (0, 0), 0.7) * (sd > 3)
    crust = np.array((max(22, base[0] * 0.7), 28, 26), np.float32)  # dried blood / serum
    _apply(lab, np.clip(scratches, 0, 0.7).astype(np.float32), crust)
    flakes = _smoothstep(1.2, 2.0, fractal_noise(rng, shape, 2.0, octaves=2)) * inside
    lab[..., 0] += 10 * flakes * rng.uniform(0.3, 1.0)
    _shade(lab, 2.0 * papules + inside * 2 + fractal_noise(rng, shape, 3.0, octaves=2) * inside, 3.0, rng)
    return lab, sd, {"radius": radius, "redness": 5 + 12 * float(fair)}


_RENDER = {"nevus": _nevus, "melanoma": _melanoma, "psoriasis": _psoriasis,
           "ulcer": _ulcer, "vitiligo": _vitiligo, "eczema": _eczema}
