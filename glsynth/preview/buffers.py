"""The buffers the previewer can show, and the false colours it shows them in."""
from __future__ import annotations

import numpy as np

from .. import dataformat as fmt
from ..errors import InputError

# Displayable buffers, in key order (keys 1..8).
BUFFERS = ("rgb", "semantic", "instances", "anatomy", "anatomy_groups", "depth", "face_id", "uv")


def layer_for(name: str) -> str:
    """The ``render_view`` layer a label buffer is coloured from."""
    return "anatomy" if name == "anatomy_groups" else name


def colourise(name: str, layers: dict) -> np.ndarray:
    """The H x W x 3 uint8 image the window shows for buffer ``name`` of ``layers`` (the
    dict ``glsynth.pipeline.views.render_view`` returns; palettes: ``glsynth.dataformat``)."""
    if name == "rgb":
        return np.ascontiguousarray(layers["rgba"][..., :3])  # premultiplied: over black
    if name == "semantic":
        return fmt.SEMANTIC_PALETTE[np.minimum(layers["semantic"], 3)]
    if name == "instances":
        return fmt.id_colours(layers["instances"])
    if name in ("anatomy", "anatomy_groups"):
        if "anatomy" not in layers:
            raise KeyError(f"{name}: this body has no anatomy labels")
        anat = np.minimum(layers["anatomy"], fmt.N_PARTS)
        if name == "anatomy":
            return fmt.ANATOMY_PALETTE[anat]
        return fmt.GROUP_PALETTE[fmt.group_labels(anat)]
    if name == "depth":
        d = layers["depth"]
        fg = d > 0
        out = np.zeros(d.shape + (3,), np.uint8)
        if fg.any():
            lo, hi = float(d[fg].min()), float(d[fg].max())
            t = (d - lo) / max(hi - lo, 1e-12)
            grey = np.round((1.0 - 0.85 * t) * 255).astype(np.uint8)  # near bright, far dark
            out[fg] = grey[fg][:, None]
        return out
    if name == "face_id":
        return fmt.id_colours(layers["face_id"].astype(np.int64) + 1)
    if name == "uv":
        uv = layers["uv"]
        fg = uv[..., 0] >= 0
        out = np.zeros(uv.shape[:2] + (3,), np.uint8)
        out[..., 0] = np.where(fg, np.round(np.clip(uv[..., 0], 0, 1) * 255), 0)
        out[..., 1] = np.where(fg, np.round(np.clip(uv[..., 1], 0, 1) * 255), 0)
        out[..., 2] = np.where(fg, 64, 0)
        return out
    raise InputError(f"unknown buffer {name!r}; choose from {', '.join(BUFFERS)}")
