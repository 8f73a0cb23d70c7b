"""Load a glsynth dataset folder for training (torch ``Dataset``)."""
from __future__ import annotations

import os

import numpy as np

from . import dataformat as fmt
from .errors import InputError

TARGETS = ("semantic", "three_class", "instances", "anatomy", "anatomy_groups", "depth", "boxes",
           "nevi")


class SynthDataset:
    """Samples of a ``glsynth generate`` folder.

    ``targets``: any of semantic (uint8 0 bg, 1 skin, 2 lesion, 3 non-skin),
    three_class (0 lesion, 1 skin, 2 non-skin), instances (int64), anatomy (16 parts),
    anatomy_groups (7 groups + background), depth (float32, -1 off the body; a
    frame-edge occluder's pixels hold the focus distance), boxes (float32 N x 4,
    [x0, y0, x1, y1) ), nevi (int64 nevus ids, 0 none: the scan's
    annotated nevus boxes as rendered; written when ``outputs`` has nevi). Codes and
    names: ``glsynth.dataformat``. Items are dicts of torch tensors with ``image``
    float32 3 x H x W in [0, 1], plus ``meta`` (the per-image JSON). ``transform``
    (optional) gets and returns the dict.
    """

    def __init__(self, root, targets=("three_class", "anatomy_groups"), transform=None):
        self.run = fmt.RunFolder(root)
        self.root = self.run.root
        bad = [t for t in targets if t not in TARGETS]
        if bad:
            raise InputError(f"unknown targets {bad}; choose from {TARGETS}")
        if not os.path.isdir(os.path.join(self.root, "targets")):
            raise FileNotFoundError(f"{self.root}: not a glsynth dataset (no targets/ folder)")
        self.ids = self.run.sample_ids()
        self.targets, self.transform = tuple(targets), transform

    def __len__(self):
        return len(self.ids)

    def __getitem__(self, i):
        import torch
        sid, run = self.ids[i], self.run
        meta = run.record(sid)
        item = {"id": sid, "meta": meta,
                "image": torch.from_numpy(run.image(sid).transpose(2, 0, 1).astype(np.float32) / 255)}
        semantic = run.layer(sid, "semantic") if {"semantic", "three_class"} & set(self.targets) else None
        for t in self.targets:
            if t == "semantic":
                a = semantic
            elif t == "three_class":
                a = fmt.three_class(semantic)
            elif t in ("anatomy", "anatomy_groups"):
                a = run.layer(sid, "anatomy")
                a = fmt.group_labels(a) if t == "anatomy_groups" else a
            elif t == "depth":
                item[t] = torch.from_numpy(run.layer(sid, "depth"))
                continue
            elif t == "boxes":
                item[t] = torch.from_numpy(fmt.boxes(meta))
                continue
            else:  # instances, nevi
                a = run.layer(sid, t)
            item[t] = torch.from_numpy(a.astype(np.int64))
        return self.transform(item) if self.transform else item
