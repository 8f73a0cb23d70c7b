"""Load a glsynth dataset folder for training (torch ``Dataset``)."""
from __future__ import annotations

import json
import os

import numpy as np

from .io.images import read_image, read_rgb

# DESIGN.md section 3: 16 parts -> 7 groups (+ background 0)
ANATOMY_GROUPS = np.array([0, 1, 2, 2, 3, 4, 4, 4, 4, 5, 5, 6, 6, 6, 6, 7, 7], np.uint8)
TARGETS = ("semantic", "three_class", "instances", "anatomy", "anatomy_groups", "depth", "boxes",
           "nevi")


def three_class(semantic: np.ndarray) -> np.ndarray:
    """The paper's target: 0 lesion, 1 skin, 2 non-skin (background and non-skin body)."""
    out = np.full(semantic.shape, 2, np.uint8)
    out[semantic == 2] = 0
    out[semantic == 1] = 1
    return out


class SynthDataset:
    """Samples of a ``glsynth generate`` folder.

    ``targets``: any of semantic (uint8 0 bg, 1 skin, 2 lesion, 3 non-skin),
    three_class (0 lesion, 1 skin, 2 non-skin), instances (int64), anatomy (16 parts),
    anatomy_groups (7 groups + background), depth (float32, -1 off the body), boxes
    (float32 N x 4, [x0, y0, x1, y1) ), nevi (int64 nevus ids, 0 none: the scan's
    annotated nevus boxes as rendered; written when ``outputs`` has nevi). Items are dicts of torch tensors with
    ``image`` float32 3 x H x W in [0, 1], plus ``meta`` (the per-image JSON).
    ``transform`` (optional) gets and returns the dict.
    """

    def __init__(self, root, targets=("three_class", "anatomy_groups"), transform=None):
        self.root = os.fspath(root)
        bad = [t for t in targets if t not in TARGETS]
        if bad:
            raise ValueError(f"unknown targets {bad}; choose from {TARGETS}")
        tgt = os.path.join(self.root, "targets")
        if not os.path.isdir(tgt):
            raise FileNotFoundError(f"{self.root}: not a glsynth dataset (no targets/ folder)")
        self.ids = sorted(f[:-5] for f in os.listdir(tgt) if f.endswith(".json"))
        self.targets, self.transform = tuple(targets), transform

    def __len__(self):
        return len(self.ids)

    def _path(self, sid, suffix):
        return os.path.join(self.root, "targets", f"{sid}{suffix}")

    def __getitem__(self, i):
        import torch
        sid = self.ids[i]
        with open(self._path(sid, ".json")) as fh:
            meta = json.load(fh)
        item = {"id": sid, "meta": meta,
                "image": torch.from_numpy(read_rgb(os.path.join(self.root, "images", f"{sid}.png"))
                                          .transpose(2, 0, 1).astype(np.float32) / 255)}
        semantic = None
        if {"semantic", "three_class"} & set(self.targets):
            semantic = read_image(self._path(sid, "_semantic.png"))
        for t in self.targets:
            if t == "semantic":
                item[t] = torch.from_numpy(semantic.astype(np.int64))
            elif t == "three_class":
                item[t] = torch.from_numpy(three_class(semantic).astype(np.int64))
            elif t in ("instances", "nevi"):
                item[t] = torch.from_numpy(read_image(self._path(sid, f"_{t}.png")).astype(np.int64))
            elif t in ("anatomy", "anatomy_groups"):
                a = read_image(self._path(sid, "_anatomy.png"))
                a = ANATOMY_GROUPS[a] if t == "anatomy_groups" else a
                item[t] = torch.from_numpy(a.astype(np.int64))
            elif t == "depth":
                import tifffile
                item[t] = torch.from_numpy(tifffile.imread(self._path(sid, "_depth.tiff")))
            elif t == "boxes":
                boxes = [l["box"] for l in meta["lesions"]]
                item[t] = torch.tensor(boxes, dtype=torch.float32).reshape(-1, 4)
        return self.transform(item) if self.transform else item
