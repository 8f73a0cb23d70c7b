"""The paper's modified fuzzy Jaccard loss (DermSynth3D appendix C).

Fuzzy Jaccard index (Crum et al. 2006) of a soft prediction p in [0, 1] against a binary
truth g: J = sum(min(p, g)) / sum(max(p, g)); for binary g this is
sum(p g) / sum(p + g - p g), which is what is computed here. The loss is 1 - J.

Modifications, as appendix C describes them:

* channels whose ground truth is empty (inside the pixels that count) are ignored;
* lesion / skin / non-skin: J is computed for each image and each channel separately;
* anatomy: J is computed for each channel over the whole batch;
* the skin channel ignores pixels that are lesion in the ground truth (``skin_loss``
  "paper"; "exclusive" counts them, as the evaluation does: skin there is neither
  lesion nor non-skin, so skin predicted on a lesion is wrong);
* the lesion and skin channels ignore pixels inside nevus boxes (existing moles on the
  body texture, which may be skin or lesion) when the sample lists any.

The two terms (mean over the counted (image, channel) pairs, and mean over the counted
anatomy channels) are added; each lies in [0, 1], so the total lies in [0, 2], and a
perfect prediction gives exactly 0.
"""
from __future__ import annotations

import numpy as np
import torch

LESION, SKIN, NONSKIN = 0, 1, 2
EPS = 1e-6


def _jaccard_terms(p, g, w, dims):
    """(intersection, union, truth mass) of soft p against binary g with pixel weights w.
    union = sum(p w) + sum(g w) - sum(p g w): two full-size products instead of four
    (at full resolution these sums cost more than the network on a CPU)."""
    pw = p * w
    inter = (pw * g).sum(dims)
    mass = (g * w).sum(dims)
    return inter, pw.sum(dims) + mass - inter, mass


SKIN_LOSSES = ("paper", "exclusive")


def seg_jaccard_loss(probs, target, ignore=None, return_parts=False, skin_loss="paper"):
    """Per-image, per-channel fuzzy Jaccard loss for the 3-class head.

    probs: B x 3 x H x W softmax probabilities (lesion, skin, non-skin).
    target: B x H x W int64 in {0 lesion, 1 skin, 2 non-skin}; any other value
    (e.g. 255) is ignored in every channel.
    ignore: optional B x H x W bool, True inside nevus boxes (ignored for the lesion and
    skin channels only).
    skin_loss: "paper" ignores lesion pixels in the skin channel; "exclusive" counts them.
    Returns the mean of 1 - J over the (image, channel) pairs whose truth is not empty
    (0 with a zero gradient when there are none).
    """
    g = torch.stack([target == c for c in range(3)], 1).to(probs.dtype)
    valid = ((target >= 0) & (target < 3)).to(probs.dtype)
    w = valid.unsqueeze(1).repeat(1, 3, 1, 1)
    if ignore is not None:
        keep = (~ignore.bool()).to(probs.dtype)
        w[:, LESION] = w[:, LESION] * keep
        w[:, SKIN] = w[:, SKIN] * keep
    if skin_loss == "paper":
        w[:, SKIN] = w[:, SKIN] * (1 - g[:, LESION])   # lesion pixels do not count for skin
    elif skin_loss != "exclusive":
        raise ValueError(f"skin_loss must be one of {SKIN_LOSSES}, got {skin_loss!r}")
    inter, union, mass = _jaccard_terms(probs, g, w, (2, 3))   # B x 3
    counted = mass > 0
    j = inter / union.clamp_min(EPS)
    loss = torch.where(counted, 1 - j, torch.zeros_like(j))
    n = counted.sum()
    total = loss.sum() / n.clamp_min(1) + 0 * probs.sum()
    return (total, counted) if return_parts else total


def anatomy_jaccard_loss(probs, target, return_parts=False):
    """Per-channel fuzzy Jaccard loss over the whole batch for the anatomy head.

    probs: B x C x H x W softmax probabilities; target: B x H x W int64 in [0, C), other
    values ignored. Channels absent from the whole batch are ignored.
    """
    C = probs.shape[1]
    g = torch.stack([target == c for c in range(C)], 1).to(probs.dtype)
    w = ((target >= 0) & (target < C)).to(probs.dtype).unsqueeze(1)
    inter, union, mass = _jaccard_terms(probs, g, w, (0, 2, 3))   # C
    counted = mass > 0
    j = inter / union.clamp_min(EPS)
    loss = torch.where(counted, 1 - j, torch.zeros_like(j))
    total = loss.sum() / counted.sum().clamp_min(1) + 0 * probs.sum()
    return (total, counted) if return_parts else total


def fuzzy_jaccard_loss(seg_logits, seg_target, anat_logits=None, anat_target=None,
                       ignore=None, anatomy_weight=1.0, skin_loss="paper"):
    """Total loss: seg term + anatomy_weight * anatomy term (logits in, softmax inside).

    Returns (total, {"seg": float, "anatomy": float}).
    """
    seg = seg_jaccard_loss(torch.softmax(seg_logits, 1), seg_target, ignore, skin_loss=skin_loss)
    parts = {"seg": float(seg.detach())}
    total = seg
    if anat_logits is not None and anat_target is not None and anatomy_weight:
        anat = anatomy_jaccard_loss(torch.softmax(anat_logits, 1), anat_target)
        parts["anatomy"] = float(anat.detach())
        total = total + anatomy_weight * anat
    return total, parts


def nevi_ignore_mask(meta: dict, shape) -> np.ndarray:
    """H x W bool mask of the nevus boxes listed in a sample's JSON (``"nevi"``).

    Each entry is ``{"id": ..., "box": [x0, y0, x1, y1]}`` in pixels, x1/y1 exclusive
    (a bare [x0, y0, x1, y1] list is accepted too). No ``"nevi"`` key: all False.
    """
    h, w = shape[:2]
    m = np.zeros((h, w), bool)
    for nv in (meta or {}).get("nevi") or ():
        box = nv.get("box") if isinstance(nv, dict) else nv
        if box is None or len(box) != 4:
            continue
        x0, y0, x1, y1 = (int(round(float(v))) for v in box)
        x0, y0, x1, y1 = max(0, x0), max(0, y0), min(w, x1), min(h, y1)
        if x1 > x0 and y1 > y0:
            m[y0:y1, x0:x1] = True
    return m
