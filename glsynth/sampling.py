"""Sampling images at arbitrary points."""
from __future__ import annotations

import cv2
import numpy as np


def sample_bilinear(img, x, y, border=cv2.BORDER_CONSTANT):
    """img sampled at float pixel indices (x = column); one value per point.
    cv2.remap needs maps under 32767 wide, hence the reshape into rows of 1024."""
    n = len(x)
    cols = 1024
    pad = (-n) % cols
    mx = np.pad(np.asarray(x, np.float32), (0, pad)).reshape(-1, cols)
    my = np.pad(np.asarray(y, np.float32), (0, pad)).reshape(-1, cols)
    out = cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=border, borderValue=0)
    return out.reshape((-1,) + img.shape[2:])[:n]
