"""The dataset format of ``glsynth generate`` (DESIGN.md sections 3 and 5): label codes
and names, their false-colour palettes, the per-image record (``targets/<id>.json``) and
the run folder.

Whatever writes or reads a run folder takes its names from here: the pipeline, the torch
dataset, ``glsynth preview``, ``glsynth show`` and the training code.
"""
from __future__ import annotations

import dataclasses
import functools
import json
import os

import numpy as np

# ---- semantic labels (uint8) -------------------------------------------------------------
SEMANTIC_BACKGROUND, SEMANTIC_SKIN, SEMANTIC_LESION, SEMANTIC_NONSKIN = 0, 1, 2, 3
SEMANTIC_NAMES = {0: "background", 1: "skin", 2: "lesion", 3: "non-skin"}

# The paper's 3-class target: 0 lesion, 1 skin, 2 non-skin (background and non-skin body).
THREE_CLASS_NAMES = {0: "lesion", 1: "skin", 2: "non-skin"}


def three_class(semantic: np.ndarray) -> np.ndarray:
    """uint8 3-class target (``THREE_CLASS_NAMES``) from semantic labels."""
    out = np.full(semantic.shape, 2, np.uint8)
    out[semantic == SEMANTIC_LESION] = 0
    out[semantic == SEMANTIC_SKIN] = 1
    return out


# ---- anatomy labels (uint8) -----------------------------------------------------------------
N_PARTS = 16
PART_NAMES = {
    1: "head", 2: "upper torso", 3: "lower torso", 4: "hips",
    5: "upper leg left", 6: "upper leg right", 7: "lower leg left", 8: "lower leg right",
    9: "foot left", 10: "foot right", 11: "upper arm left", 12: "upper arm right",
    13: "lower arm left", 14: "lower arm right", 15: "hand left", 16: "hand right",
}
ANATOMY_NAMES = {0: "background", **PART_NAMES}
# PASCAL-part style groups (7 + background)
GROUP_NAMES = {0: "background", 1: "head", 2: "torso", 3: "hips", 4: "legs", 5: "feet",
               6: "arms", 7: "hands"}
# part label -> group label (index 0, background, stays 0)
PART_GROUPS = np.array([0, 1, 2, 2, 3, 4, 4, 4, 4, 5, 5, 6, 6, 6, 6, 7, 7], np.uint8)


def group_labels(labels) -> np.ndarray:
    """Map 16-part anatomy labels (0 = background) to the 7 groups (0 = background)."""
    labels = np.asarray(labels)
    return PART_GROUPS[labels if labels.dtype == np.uint8 else labels.astype(np.int64)]


# ---- false colours (uint8 RGB, index = label; background black) -------------------------------
SEMANTIC_PALETTE = np.array([[0, 0, 0], [225, 185, 150], [220, 30, 40], [40, 90, 210]], np.uint8)
ANATOMY_PALETTE = np.array([
    [0, 0, 0], [230, 25, 75], [60, 180, 75], [255, 225, 25], [0, 130, 200], [245, 130, 48],
    [145, 30, 180], [70, 240, 240], [240, 50, 230], [210, 245, 60], [250, 190, 212],
    [0, 128, 128], [220, 190, 255], [170, 110, 40], [255, 250, 200], [128, 0, 0],
    [170, 255, 195]], np.uint8)
GROUP_PALETTE = ANATOMY_PALETTE[:8].copy()  # the groups take the first 8 part colours
# 3-class target, plus index 3 for pixels a prediction leaves unknown
THREE_CLASS_PALETTE = np.array([[220, 40, 40], [70, 180, 80], [40, 40, 120], [150, 150, 150]],
                               np.uint8)


def id_colours(ids: np.ndarray) -> np.ndarray:
    """Distinct, deterministic colours for integer ids (lesion instances, faces):
    golden-ratio hues; 0 and negative ids are black. Returns uint8 (..., 3)."""
    ids = np.asarray(ids).astype(np.int64)
    if ids.size and ids.max() < (1 << 20):
        lut = _id_lut(max(1 << 16, 1 << int(ids.max()).bit_length()))
        return lut[np.maximum(ids, 0)]
    return _id_colours(ids)


@functools.lru_cache(maxsize=4)
def _id_lut(n):
    return _id_colours(np.arange(n))


def _id_colours(ids):
    hue = (ids * 0.618033988749895) % 1.0
    sat = 0.55 + 0.45 * ((ids * 7919) % 3) / 2.0
    val = 0.75 + 0.25 * ((ids * 104729) % 2)
    h6 = hue * 6.0
    i = np.floor(h6).astype(np.int64) % 6
    f = h6 - np.floor(h6)
    p, q, t = val * (1 - sat), val * (1 - sat * f), val * (1 - sat * (1 - f))
    table = [(val, t, p), (q, val, p), (p, val, t), (p, q, val), (t, p, val), (val, p, q)]
    rgb = np.zeros(ids.shape + (3,), np.float64)
    for k, (r, g, b) in enumerate(table):
        sel = i == k
        rgb[sel] = np.stack([r[sel], g[sel], b[sel]], -1)
    rgb[ids <= 0] = 0
    return np.round(rgb * 255).astype(np.uint8)


# ---- the per-image record (targets/<id>.json) ----------------------------------------------
BOX_CONVENTION = "[x0, y0, x1, y1] pixels, x1/y1 exclusive"
CAMERA_CONVENTIONS = ("intrinsics K: pixels, row 0 at the top, pixel centres at +0.5; "
                      "world_to_camera (= view_matrix): OpenGL view space (x right, y up, camera "
                      "looks down -z); world_to_camera_cv: OpenCV camera (x right, y down, z "
                      "forward), the frame K projects: [u v 1] ~ K @ (world_to_camera_cv @ X)[:3]")


def camera_record(cam, **extra) -> dict:
    """The record's ``camera``: ``Camera.to_dict()``, ``extra`` keys, intrinsics and the
    world-to-camera matrices in OpenGL's and OpenCV's frames."""
    view = cam.view_matrix()
    return {**cam.to_dict(), **extra, "intrinsics": cam.intrinsics().tolist(),
            "view_matrix": view.tolist(), "world_to_camera": view.tolist(),
            "world_to_camera_cv": (np.diag([1.0, -1.0, -1.0, 1.0]) @ view).tolist(),
            "conventions": CAMERA_CONVENTIONS}


def lights_record(lights, kinds=("room", "flash")) -> list:
    """The record's ``lights``: each ``PointLight.to_dict()`` with its kind."""
    return [{**light.to_dict(), "kind": kind} for light, kind in zip(lights, kinds)]


def view_record(sample_id, size, scene, *, attempts, ambient_tint, photo, body, lesions, nevi,
                background, fractions) -> dict:
    """The record of a rendered view: ``scene`` (a pipeline.views.ViewScene) gives the
    camera, lights and material; ``ambient_tint`` is the RGB tint or None; the rest are
    stored as given (plain JSON values)."""
    return {"id": sample_id, "width": size, "height": size, "attempts": attempts,
            "camera": camera_record(scene.camera, centre=scene.centre, framing=scene.framing),
            "light": scene.light.to_dict(), "material": scene.material.to_dict(),
            "lights": lights_record(scene.lights),
            "ambient_tint": list(ambient_tint) if ambient_tint is not None else None,
            **({"light_kelvin": scene.kelvin, "white_balance_gains": list(scene.white_balance)}
               if scene.kelvin is not None else {}),
            "photo": photo, "body": body, "lesions": lesions, "nevi": nevi,
            "background": background, "fractions": fractions, "box_convention": BOX_CONVENTION}


def camera_from_record(record: dict):
    """The Camera of a record (or of a bare ``Camera.to_dict()`` dict)."""
    from .camera import Camera
    return Camera.from_dict(record.get("camera", record))


def lights_from_record(record: dict) -> list:
    """The PointLights of a record: ``lights`` (room light first), else ``light``."""
    from .lighting import PointLight
    dicts = record.get("lights") or [record["light"]]
    keys = [f.name for f in dataclasses.fields(PointLight)]
    return [PointLight(**{k: d[k] for k in keys if k in d}) for d in dicts]


def material_from_record(record: dict):
    """The Material of a record (``Material.to_dict()`` under ``material``)."""
    from .lighting import Material
    return Material(**record.get("material", {}))


def boxes(record: dict, key="lesions") -> np.ndarray:
    """float32 N x 4 boxes ([x0, y0, x1, y1), pixels) of the record's ``lesions`` (or
    ``nevi``)."""
    return np.array([item["box"] for item in record.get(key, [])], np.float32).reshape(-1, 4)


# ---- the run folder ----------------------------------------------------------------------------
# targets/<id><suffix> of each layer (``outputs`` in the config; rgb is images/<id>.png)
LAYER_SUFFIXES = {"semantic": "_semantic.png", "instances": "_instances.png",
                  "anatomy": "_anatomy.png", "depth": "_depth.tiff", "nevi": "_nevi.png",
                  "normals": "_normals.npy", "uv": "_uv.npy", "face_id": "_face_id.npy"}
MANIFEST = "manifest.json"
# bodies/<id>/: the pasted texture, the blended one, texture-space lesion ids, placements
PASTED, BLENDED, BODY_INSTANCES, PLACEMENTS = "pasted.png", "blended.png", "instances.png", "placements.json"


def image_path(root, sample_id) -> str:
    return os.path.join(root, "images", f"{sample_id}.png")


def record_path(root, sample_id) -> str:
    """The per-image JSON, written last: a sample is complete exactly when it exists."""
    return os.path.join(root, "targets", f"{sample_id}.json")


def layer_path(root, sample_id, layer) -> str:
    if layer not in LAYER_SUFFIXES:
        from .errors import InputError
        raise InputError(f"unknown layer {layer!r}; choose from {', '.join(LAYER_SUFFIXES)}")
    return os.path.join(root, "targets", f"{sample_id}{LAYER_SUFFIXES[layer]}")


def sample_ids(root) -> list[str]:
    """Ids of the complete samples under ``root`` (those with a record), sorted."""
    tgt = os.path.join(root, "targets")
    return sorted(f[:-5] for f in os.listdir(tgt) if f.endswith(".json")) if os.path.isdir(tgt) else []


class RunFolder:
    """Reads a ``glsynth generate`` output folder: samples (image, layers, record), the
    manifest with the resolved config, and the per-body textures under ``bodies/``."""

    def __init__(self, root):
        self.root = os.fspath(root)

    def sample_ids(self) -> list[str]:
        return sample_ids(self.root)

    def record(self, sample_id) -> dict:
        with open(record_path(self.root, sample_id)) as fh:
            return json.load(fh)

    def image(self, sample_id) -> np.ndarray:
        """H x W x 3 uint8 RGB."""
        from .io.images import read_rgb
        return read_rgb(image_path(self.root, sample_id))

    def layer(self, sample_id, name) -> np.ndarray:
        """A target layer as written: uint8/uint16 labels, float32 depth, .npy arrays."""
        path = layer_path(self.root, sample_id, name)
        if path.endswith(".npy"):
            return np.load(path, allow_pickle=False)
        if path.endswith(".tiff"):
            import tifffile
            return tifffile.imread(path)
        from .io.images import read_image
        return read_image(path)

    def manifest(self) -> dict:
        path = os.path.join(self.root, MANIFEST)
        if not os.path.isfile(path):
            raise FileNotFoundError(f"{self.root}: no {MANIFEST} (not a finished `glsynth generate` "
                                    "output folder)")
        with open(path) as fh:
            return json.load(fh)

    def config(self):
        """The run's resolved Config, from its manifest."""
        from .config import from_dict
        from .errors import InputError
        raw = self.manifest()
        if "config" not in raw:
            raise InputError(f"{os.path.join(self.root, MANIFEST)}: has no 'config' (the resolved "
                             "run config)")
        return from_dict(raw["config"], source=os.path.join(self.root, MANIFEST))

    def body_ids(self) -> list[str]:
        """The bodies with a folder under ``bodies/`` (those that had lesions pasted)."""
        bodies = os.path.join(self.root, "bodies")
        if not os.path.isdir(bodies):
            return []
        return sorted(d for d in os.listdir(bodies) if os.path.isdir(os.path.join(bodies, d)))

    def body_path(self, body_id, name="") -> str:
        return os.path.join(self.root, "bodies", body_id, name)
