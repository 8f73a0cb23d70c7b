"""A compact encoder-decoder for lesion / skin / non-skin and anatomy segmentation.

``SegNet`` is a small U-Net built from depthwise-separable convolutions (MobileNet
style), with an LR-ASPP-like global-context gate at the bottleneck. It stands in for
the paper's DeepLabV3-ResNet50 (about 40M parameters) so that training on a CPU is
feasible: ~0.17M parameters at the default width; the heads predict at 1/4 resolution,
upsampled bilinearly (as LR-ASPP does at 1/8). Two heads share the decoder:

* ``seg``: 3 channels (0 lesion, 1 skin, 2 non-skin), softmax over the three;
* ``anatomy``: 8 channels (0 background + the 7 PASCAL-part groups), softmax.

Input: B x 3 x H x W normalised images; any H, W (padded internally to a multiple of 32).
"""
from __future__ import annotations

import torch
import torch.nn as nn
import torch.nn.functional as F


def _bn_act(c):
    return nn.Sequential(nn.BatchNorm2d(c), nn.ReLU(inplace=True))


class DSConv(nn.Module):
    """Depthwise 3x3 (stride, dilation) -> BN-ReLU -> pointwise 1x1 -> BN-ReLU, residual if shapes match."""

    def __init__(self, cin, cout, stride=1, dilation=1):
        super().__init__()
        self.dw = nn.Conv2d(cin, cin, 3, stride, padding=dilation, dilation=dilation, groups=cin, bias=False)
        self.a1 = _bn_act(cin)
        self.pw = nn.Conv2d(cin, cout, 1, bias=False)
        self.bn = nn.BatchNorm2d(cout)
        self.res = stride == 1 and cin == cout

    def forward(self, x):
        y = self.bn(self.pw(self.a1(self.dw(x))))
        return F.relu(y + x if self.res else y, inplace=True)


class SegNet(nn.Module):
    def __init__(self, n_seg=3, n_anatomy=8, width=1.0, depth=0):
        """width: channel multiplier; depth: extra residual blocks in each encoder stage
        from 1/4 down (0 is the original network)."""
        super().__init__()
        if width <= 0 or depth < 0:
            raise ValueError(f"SegNet width must be > 0 and depth >= 0, got {width}, {depth}")
        c = [max(8, int(round(v * width))) for v in (16, 32, 48, 96, 160)]
        self.arch = {"name": "SegNet", "n_seg": n_seg, "n_anatomy": n_anatomy, "width": width,
                     "depth": int(depth)}
        extra = [[DSConv(ch, ch) for _ in range(int(depth))] for ch in c[1:4]]
        self.stem = nn.Sequential(nn.Conv2d(3, c[0], 3, 2, 1, bias=False), _bn_act(c[0]))  # /2
        self.enc1 = nn.Sequential(DSConv(c[0], c[1], 2), DSConv(c[1], c[1]), *extra[0])    # /4
        self.enc2 = nn.Sequential(DSConv(c[1], c[2], 2), DSConv(c[2], c[2]), *extra[1])    # /8
        self.enc3 = nn.Sequential(DSConv(c[2], c[3], 2), DSConv(c[3], c[3]), DSConv(c[3], c[3]),
                                  *extra[2])                                                # /16
        self.enc4 = nn.Sequential(DSConv(c[3], c[4], 2), DSConv(c[4], c[4], dilation=2),
                                  DSConv(c[4], c[4], dilation=4))                           # /32
        # LR-ASPP-style global context: a sigmoid gate from globally pooled features.
        self.gate = nn.Sequential(nn.AdaptiveAvgPool2d(1), nn.Conv2d(c[4], c[4], 1), nn.Sigmoid())
        self.dec3 = DSConv(c[4] + c[3], c[3])
        self.dec2 = DSConv(c[3] + c[2], c[2])
        self.dec1 = DSConv(c[2] + c[1], c[1])
        self.seg_head = nn.Conv2d(c[1], n_seg, 1)
        self.anatomy_head = nn.Conv2d(c[1], n_anatomy, 1)
        # channels-last (NHWC) weights and activations: the depthwise and 1x1 convolutions
        # run ~20% faster on a CPU this way (oneDNN); ``.to(device)`` and
        # ``load_state_dict`` keep the layout
        self.to(memory_format=torch.channels_last)

    @staticmethod
    def _up_cat(x, skip):
        x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
        return torch.cat([x, skip], 1)

    def forward(self, x):
        h, w = x.shape[-2:]
        ph, pw = (-h) % 32, (-w) % 32
        if ph or pw:
            x = F.pad(x, (0, pw, 0, ph), mode="reflect" if min(h, w) > max(ph, pw) else "replicate")
        x = x.contiguous(memory_format=torch.channels_last)
        s0 = self.stem(x)
        s1 = self.enc1(s0)
        s2 = self.enc2(s1)
        s3 = self.enc3(s2)
        s4 = self.enc4(s3)
        s4 = s4 * self.gate(s4)
        d = self.dec3(self._up_cat(s4, s3))
        d = self.dec2(self._up_cat(d, s2))
        d = self.dec1(self._up_cat(d, s1))
        full = x.shape[-2:]
        seg = F.interpolate(self.seg_head(d), size=full, mode="bilinear", align_corners=False)
        anat = F.interpolate(self.anatomy_head(d), size=full, mode="bilinear", align_corners=False)
        return {"seg": seg[..., :h, :w], "anatomy": anat[..., :h, :w]}


def count_parameters(model) -> int:
    return sum(p.numel() for p in model.parameters())
