"""A run's input sources, opened and checked before any stage works.

A missing background folder, an unreadable lesion or a scan folder without a mesh then
fails in the first seconds of a run, not after every body was pasted and blended.
Procedural sources are made from the seed and need no check.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

from ..config import Config
from .bodies import body_ids

STAGES = ("paste", "blend", "views")


def lesion_source(cfg: Config):
    from .. import assets
    le = cfg.lesions
    if le.source == "procedural":
        from ..assets.lesions import ProceduralLesions
        n = max(le.per_body * (cfg.bodies.first + cfg.bodies.count), 1)  # dealt by body index
        return ProceduralLesions(n, seed=cfg.seed, size=le.resolution, kinds=le.kinds, halo=le.halo)
    return assets.load_lesions(le.source, layout=le.layout, colour_constancy=le.colour_constancy,
                               min_size=le.min_size, max_mask_fraction=le.max_mask_fraction)


def background_source(cfg: Config):
    from .. import assets
    b = cfg.backgrounds
    if b.source == "procedural":
        # a shard's own: indices from bodies.first x count, so shards do not share them
        return assets.procedural_backgrounds(b.count, seed=cfg.seed, size=cfg.views.size,
                                             first=cfg.bodies.first * b.count,
                                             clinical=b.clinical)
    return assets.load_backgrounds(b.source)


@dataclass
class Inputs:
    """The file sources read by :func:`open_inputs` (None: procedural or not needed)."""
    lesions: object = None
    backgrounds: object = None


def open_inputs(cfg: Config, stages=STAGES) -> Inputs:
    """Open and check every file input that ``stages`` will read: lesion images and
    masks (each one read), background images (each one decoded), the body scan
    folders' meshes and the VGG16 weights of a deep blend."""
    from .paste import PasteError
    inputs = Inputs()
    lesions_used = cfg.lesions.per_body > 0
    if cfg.bodies.source != "builtin":
        from ..assets.bodytex import scan_mesh_path
        for body_id in body_ids(cfg):
            _readable(scan_mesh_path(os.path.join(cfg.bodies.source, body_id)))
    if "paste" in stages and lesions_used and cfg.lesions.source != "procedural":
        inputs.lesions = lesion_source(cfg)
        if len(inputs.lesions) == 0:
            raise PasteError(f"lesions.source {cfg.lesions.source!r}: no usable lesions")
    if "blend" in stages and lesions_used and cfg.blend.method == "deep":
        from ..io.modelfile import check_torch_file
        from .features import vgg_weights_for
        weights = vgg_weights_for(cfg.blend.features, cfg.blend.vgg_weights)
        if weights is not None:
            check_torch_file(weights, "VGG16 weights file")
    if "views" in stages and cfg.backgrounds.source != "procedural":
        inputs.backgrounds = background_source(cfg)
    return inputs


def _readable(path):
    with open(path, "rb") as fh:
        fh.read(1)
