"""Per-image Jaccard and Dice on binary masks, with the empty-mask cases defined.

For a predicted mask P and a true mask G (same shape, bool):

* J = |P & G| / |P | G| and D = 2 |P & G| / (|P| + |G|) when G or P is non-empty;
* both empty: J = D = 1 (the model correctly finds none of that class). Such images are
  *included* in the mean (``report.md`` also gives the mean over images whose truth is
  non-empty, and how many images had an empty truth);
* G empty, P non-empty: J = D = 0 (any false positive on an image without the class
  scores zero), included;
* G non-empty, P empty: J = D = 0.
"""
from __future__ import annotations

import numpy as np


def jaccard(pred, truth) -> float:
    p, g = np.asarray(pred, bool), np.asarray(truth, bool)
    if p.shape != g.shape:
        raise ValueError(f"jaccard: shapes differ {p.shape} vs {g.shape}")
    union = np.count_nonzero(p | g)
    return 1.0 if union == 0 else np.count_nonzero(p & g) / union


def dice(pred, truth) -> float:
    p, g = np.asarray(pred, bool), np.asarray(truth, bool)
    if p.shape != g.shape:
        raise ValueError(f"dice: shapes differ {p.shape} vs {g.shape}")
    total = np.count_nonzero(p) + np.count_nonzero(g)
    return 1.0 if total == 0 else 2.0 * np.count_nonzero(p & g) / total
