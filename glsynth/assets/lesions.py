"""Skin-condition sources: real images with masks (Fitzpatrick17k annotations, ISIC/HAM10000,
PH2, images/ + masks/ folders) and seeded procedural lesions rendered on a skin patch.

Every source yields :class:`Lesion` objects: an RGB crop around the lesion (the mask's
bounding box plus ~25% of its size as surrounding skin context) and the boolean mask of
the same size.
"""
from __future__ import annotations

import csv
import functools
import logging
import os
import re
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..errors import InputError
from ..io.images import ImageError, read_mask, read_rgb
from .colour import ita_range, shades_of_gray
from .morphology import HALO_REACH, PRESETS, apply_to_skin, make_condition

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
# Procedural lesions: conditions composed from dermatology's vocabulary
# (glsynth.assets.morphology), carried as the changes they make to the skin. Pasting
# applies those changes to the body's own skin, at any resolution; ``image`` shows the
# condition on a reference skin of the lesion's Fitzpatrick type (contact sheets,
# held-out sets, and whatever wants a picture).

KINDS = tuple(PRESETS)
# melanin volume fraction of a reference skin per Fitzpatrick type (chromophore model)
# (mid-band ITA 65, 48, 35, 20, -8, -51 degrees at 2% blood)
_REFERENCE_MELANIN = {1: 0.025, 2: 0.048, 3: 0.065, 4: 0.084, 5: 0.126, 6: 0.225}


class FieldLesion(Lesion):
    """A procedural condition: ``fields`` (a morphology.LesionFields) holds what it does
    to the skin; ``image``/``mask`` show it on a reference skin, one pixel per grid
    cell, the mask being the outline a dermatologist would draw. The pipeline paints
    the body's own skin from ``fields``, so ``image`` is painted only when first read
    (~2 s for a 512-cell grid)."""

    def __init__(self, fields, id: str, meta: dict, fitzpatrick: int):
        self.fields, self.id, self.meta = fields, id, meta
        self.mask = fields.mask.copy()
        self._fitzpatrick, self._image = int(fitzpatrick), None
        if not self.mask.any():
            raise EmptyMaskError(f"lesion {id}: mask is empty")

    @property
    def image(self) -> np.ndarray:
        if self._image is None:
            seed = [int(self.meta["seed"]), int(self.meta["index"]), 1]
            skin = reference_skin(self._fitzpatrick, self.fields.size, np.random.default_rng(seed))
            self._image = apply_to_skin(self.fields, skin)
        return self._image

    def __repr__(self):
        return f"FieldLesion({self.id!r})"


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


def reference_skin(fitzpatrick: int, size: int, rng) -> np.ndarray:
    """A size x size uint8 patch of healthy skin of a Fitzpatrick type from the
    chromophore model, with gentle mottling (from the model's table: within 1/255)."""
    from .chromophores import skin_rgb_fast
    mel = _REFERENCE_MELANIN[int(fitzpatrick)] * np.exp(0.08 * fractal_noise(rng, (size, size), size / 3))
    blood = 0.02 * np.exp(0.25 * fractal_noise(rng, (size, size), size / 4))
    return np.clip(np.rint(skin_rgb_fast(mel, blood) * 255), 0, 255).astype(np.uint8)


class ProceduralLesions(Sequence):
    """``n`` seeded procedural conditions (FieldLesion), made when indexed: presets
    from ``kinds`` (default: all of KINDS), each shown on a reference skin of a
    Fitzpatrick type drawn from ``fitzpatrick`` (a type, a list, or None for any) on a
    ``size``-cell grid, each outline taking in the visible halo round its lesion out to
    ``halo`` of its radius (morphology.make_condition). Lesion i depends only on (seed,
    i), so a longer set starts with the shorter one.

    The presets come in rounds: each run of ``len(kinds)`` lesions holds every preset
    once, in an order shuffled by (seed, round). A set smaller than a round (a run of
    2 bodies x 3 lesions holds 6) thus draws different presets for different seeds,
    rather than always the first ones listed."""

    def __init__(self, n: int, seed: int = 0, size: int = 256, kinds=None, fitzpatrick=None,
                 halo=HALO_REACH):
        kinds = list(KINDS if not kinds else ([kinds] if isinstance(kinds, str) else kinds))
        bad = [k for k in kinds if k not in KINDS]
        if bad:
            raise ValueError(f"unknown procedural lesion kinds {bad}; choose from {KINDS}")
        if size < 32:
            raise ValueError(f"procedural lesion size must be >= 32 px, got {size}")
        self.types = list(range(1, 7)) if fitzpatrick is None else np.atleast_1d(fitzpatrick).tolist()
        for t in self.types:
            ita_range(t)  # validates 1..6
        self.n, self.seed, self.size, self.kinds = int(n), int(seed), int(size), kinds
        self.halo = float(halo)

    def __len__(self):
        return self.n

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(self.n))]
        if not -self.n <= i < self.n:
            raise IndexError(i)
        return self._make(i % self.n)   # (its fields come from _condition's cache)

    def kind(self, i: int) -> str:
        """The preset of lesion ``i``: position i % len(kinds) in round i // len(kinds)."""
        k = len(self.kinds)
        order = np.random.default_rng([self.seed, i // k, 0x6B696E64]).permutation(k)
        return self.kinds[int(order[i % k])]

    def _make(self, i):
        rng = np.random.default_rng([self.seed, i])
        kind = self.kind(i)
        fitz = int(self.types[rng.integers(len(self.types))])
        return _field_lesion(kind, self.seed, i, self.size, fitz, self.halo)

    def spread(self, lesion, copy: int):
        """Another lesion of the same condition as ``lesion`` (one of this set), for a
        generalised eruption: the same preset and reference skin, its own draw (``copy``
        >= 1; copy 0 is ``lesion`` itself)."""
        m = lesion.meta
        return _field_lesion(m["preset"], int(m["seed"]), int(m["index"]), int(m["grid"]),
                             int(m["fitzpatrick"]), float(m["halo"]), copy)


def _field_lesion(kind, seed, index, grid, fitz, halo, copy=0):
    fields = _condition(kind, seed, index, grid, halo, copy)
    meta = {"kind": kind, "preset": kind, "seed": seed, "index": index, "fitzpatrick": fitz,
            "grid": grid, "halo": halo, "extent_mm": round(fields.extent_mm, 2),
            "instances": int(fields.instances.max()), "params": fields.params}
    name = f"procedural-{kind}-{seed}-{index}"
    if copy:
        meta["copy"] = copy
        name += f"-{copy}"
    return FieldLesion(fields, name, meta, fitz)


@functools.lru_cache(maxsize=16)
def _condition(preset: str, seed: int, index: int, grid: int, halo: float, copy: int = 0):
    """Procedural lesion ``index`` of a run's ``seed`` (``copy`` >= 1: another draw of its
    preset, a lesion of the same eruption). Cached: a worker pastes a body's lesions and
    builds their decals moments apart (~0.1-2 s each to make; ~16 MB at 512)."""
    key = [seed, index] if copy == 0 else [seed, index, 0x65727570, copy]
    return make_condition(preset, key, size=grid, halo_reach=halo)


def procedural_lesions(n: int, seed: int = 0, size: int = 256, kinds=None,
                       fitzpatrick=None, halo=HALO_REACH) -> list[Lesion]:
    """A list of ``ProceduralLesions(n, seed, size, kinds, fitzpatrick, halo)``."""
    return list(ProceduralLesions(n, seed, size, kinds, fitzpatrick, halo))


def lesion_from_meta(meta: dict) -> Lesion:
    """The lesion a placement recorded (its ``lesion_meta``): a procedural condition made
    again from its preset, seed and index, or a lesion image read again from its files."""
    if meta.get("preset"):
        copy = int(meta.get("copy", 0))
        fields = _condition(meta["preset"], int(meta["seed"]), int(meta["index"]),
                            int(meta.get("grid", 256)), float(meta.get("halo", 0.0)), copy)
        name = f"procedural-{meta['preset']}-{meta['seed']}-{meta['index']}" + (f"-{copy}" if copy else "")
        return FieldLesion(fields, name, meta, meta.get("fitzpatrick", 3))
    return load_lesion(meta["image_path"], meta["mask_path"], meta.get("id"), meta,
                       colour_constancy=bool(meta.get("colour_constancy")))
