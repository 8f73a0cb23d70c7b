"""Feature extractors for the blending loss: VGG16 (ImageNet weights from a local
torchvision-layout state dict) or, without weights, a fixed multi-scale filter bank.

No torchvision dependency and no download: the VGG16 layers are defined here with
torchvision's parameter names (``features.N.weight``), so its state dict loads as is.
"""
from __future__ import annotations

import glob
import logging
import os

import torch
import torch.nn as nn
import torch.nn.functional as F

from ..errors import ModelFileError
from ..io.modelfile import load_torch_file

log = logging.getLogger(__name__)

# VGG16 "D" configuration; numbers are conv widths, "M" max-pooling.
_VGG16 = [64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512, "M"]
# Zhang et al. (2020) style layers relu1_2, relu2_2, relu3_3, relu4_3; content relu2_2.
_STYLE_RELUS = (3, 8, 15, 22)
_CONTENT_RELU = 8
_MEAN = (0.485, 0.456, 0.406)
_STD = (0.229, 0.224, 0.225)


class VGG16Features(nn.Module):
    """The convolutional part of VGG16, returning (content, [style layers])."""

    name = "vgg16"

    def __init__(self):
        super().__init__()
        layers, c = [], 3
        for v in _VGG16:
            if v == "M":
                layers.append(nn.MaxPool2d(2, 2))
            else:
                layers += [nn.Conv2d(c, v, 3, padding=1), nn.ReLU(inplace=False)]
                c = v
        self.features = nn.Sequential(*layers[: _STYLE_RELUS[-1] + 1])
        self.register_buffer("mean", torch.tensor(_MEAN).view(1, 3, 1, 1))
        self.register_buffer("std", torch.tensor(_STD).view(1, 3, 1, 1))

    def forward(self, x):
        x = (x - self.mean) / self.std
        style, content = [], None
        for i, layer in enumerate(self.features):
            x = layer(x)
            if i in _STYLE_RELUS:
                style.append(x)
            if i == _CONTENT_RELU:
                content = x
        return content, style


class FilterBankFeatures(nn.Module):
    """Weight-free features: oriented first and second Gaussian-derivative filters on
    luminance, rectified, plus the colour-opponent channels, at three scales. Fixed,
    not learned; the Gram matrices of these responses describe texture the way
    Portilla-Simoncelli-style statistics do. 19 channels keep a blend step cheap."""

    name = "filters"

    def __init__(self):
        super().__init__()
        self.register_buffer("bank", _derivative_bank(7, 1.2))
        self.register_buffer("opponent", torch.tensor([[1 / 3, 1 / 3, 1 / 3], [1, -1, 0],
                                                       [0.5, 0.5, -1]]).view(3, 3, 1, 1))

    def forward(self, x):
        x = F.conv2d(x, self.opponent)
        style, content = [], None
        for level in range(3):
            resp = F.conv2d(x[:, :1], self.bank, padding=3)
            feat = torch.cat([F.relu(resp), F.relu(-resp), x], 1)
            style.append(feat)
            if level == 0:
                content = feat
            if min(x.shape[-2:]) < 8:
                break
            x = F.avg_pool2d(x, 2)
        return content, style


def _derivative_bank(size, sigma):
    r = torch.arange(size, dtype=torch.float32) - size // 2
    y, x = torch.meshgrid(r, r, indexing="ij")
    g = torch.exp(-(x ** 2 + y ** 2) / (2 * sigma ** 2))
    filters = []
    for angle in (0.0, 0.785398, 1.570796, 2.356194):
        u = x * torch.cos(torch.tensor(angle)) + y * torch.sin(torch.tensor(angle))
        d1 = -u * g
        d2 = (u ** 2 / sigma ** 2 - 1) * g
        filters += [d1 / d1.abs().sum(), d2 / d2.abs().sum()]
    return torch.stack(filters)[:, None]


def find_vgg_weights(path=None):
    """A VGG16 state dict file: ``path`` if given, else torch's hub cache."""
    if path:
        if not os.path.isfile(path):
            raise FileNotFoundError(f"blend.vgg_weights {path!r}: file not found")
        return path
    hub = os.path.join(torch.hub.get_dir(), "checkpoints")
    found = sorted(glob.glob(os.path.join(hub, "vgg16*.pth")))
    return found[0] if found else None


def load_vgg16(path) -> VGG16Features:
    net = VGG16Features()
    state = load_torch_file(path, "VGG16 state dict")
    if not isinstance(state, dict):
        raise ModelFileError(f"{path}: not a VGG16 state dict (holds a {type(state).__name__})")
    wanted = {k for k in net.state_dict() if k.startswith("features.")}
    state = {k: v for k, v in state.items() if k in wanted}
    missing = wanted - set(state)
    if missing:
        raise ModelFileError(f"{path}: not a VGG16 state dict (missing {sorted(missing)[:3]}...)")
    net.load_state_dict(state, strict=False)
    return net.eval().requires_grad_(False)


def vgg_weights_for(kind, weights=None):
    """The VGG16 weights file blend.features ``kind`` will read (None: the filter bank)."""
    if kind == "filters":
        return None
    path = find_vgg_weights(weights)
    if path is None and kind == "vgg16":
        raise FileNotFoundError("blend.features=vgg16 but no VGG16 weights: set blend.vgg_weights "
                                f"or put vgg16-*.pth in {torch.hub.get_dir()}/checkpoints")
    return path


def make_extractor(kind="auto", weights=None):
    """(module, description). kind: 'auto' (VGG16 when weights are found, else the
    filter bank with a warning), 'vgg16' (weights required) or 'filters'."""
    if kind == "filters":
        return FilterBankFeatures().eval(), "filters"
    path = vgg_weights_for(kind, weights)
    if path is None:
        log.warning("no VGG16 ImageNet weights found (blend.vgg_weights or torch hub cache); "
                    "blending uses the weight-free filter-bank features")
        return FilterBankFeatures().eval(), "filters (no VGG16 weights found)"
    return load_vgg16(path), f"vgg16 ({path})"
