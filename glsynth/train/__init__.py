"""Segmentation training on glsynth datasets and evaluation on real images (issue 8).

The paper's experiment (DermSynth3D section 4.2, appendix C): one network with two
softmax heads, lesion / skin / non-skin and the 7 anatomy groups plus background,
trained with a modified fuzzy Jaccard loss on synthetic images, tested per image on
real clinical photographs. See ``docs/training.md``.
"""
from .loss import fuzzy_jaccard_loss, nevi_ignore_mask
from .model import SegNet
from .metrics import jaccard, dice

__all__ = ["SegNet", "fuzzy_jaccard_loss", "nevi_ignore_mask", "jaccard", "dice"]
