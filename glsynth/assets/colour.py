"""Colour helpers: Shades of Gray colour constancy, sRGB <-> CIELAB, ITA and Fitzpatrick bands.

CIELAB conversion (numpy, no colour-management library):

1. sRGB in [0, 1] is linearised with the IEC 61966-2-1 transfer curve
   (``c / 12.92`` below 0.04045, ``((c + 0.055) / 1.055) ** 2.4`` above).
2. Linear RGB -> CIE XYZ with the sRGB primaries and the D65 white point.
3. XYZ -> L*a*b* relative to the D65 reference white (Xn, Yn, Zn) = (0.95047, 1, 1.08883),
   with the CIE 1976 cube-root function and its linear segment below (6/29)^3.

The Individual Typology Angle is ``ITA = atan2(L* - 50, b*)`` in degrees; for skin
(b* > 0) this equals the usual ``arctan((L* - 50) / b*)``.
"""
from __future__ import annotations

import numpy as np

# linear sRGB <-> CIE XYZ (sRGB primaries, D65 white); the middle row is luminance Y
LINEAR_RGB_TO_XYZ = np.array([[0.4124564, 0.3575761, 0.1804375],
                              [0.2126729, 0.7151522, 0.0721750],
                              [0.0193339, 0.1191920, 0.9503041]])
XYZ_TO_LINEAR_RGB = np.linalg.inv(LINEAR_RGB_TO_XYZ)
WHITE_D65 = np.array([0.95047, 1.0, 1.08883])
_DELTA = 6.0 / 29.0

# Fitzpatrick type -> (lo, hi] ITA band in degrees (Del Bino et al. / Groh et al.).
_ITA_BANDS = {1: (55.0, 90.0), 2: (41.0, 55.0), 3: (28.0, 41.0),
              4: (10.0, 28.0), 5: (-30.0, 10.0), 6: (-90.0, -30.0)}


def shades_of_gray_table(img: np.ndarray, p: float = 6) -> np.ndarray:
    """Finlayson & Trezzi's Shades of Gray colour constancy as a lookup table: 256 x 3
    uint8, entry [v, c] the corrected value of level v in channel c.

    The illuminant is estimated per channel as the Minkowski p-mean
    ``e_c = mean(I_c ** p) ** (1/p)`` and each channel is scaled so that all three
    estimates become equal (to their RMS, which keeps the overall brightness), rounded
    and clipped to [0, 255]. p=1 is Gray World, p=inf would be max-RGB. The identity
    when a channel is all zero (no illuminant estimate is possible).

    img: HxWx3 uint8 RGB. The means come from each channel's 256-bin histogram, exactly
    as from the pixels and ~20x faster (training normalises every sample with this).
    """
    img = np.asarray(img)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"shades_of_gray expects HxWx3 uint8 RGB, got {img.dtype} {img.shape}")
    if p <= 0:
        raise ValueError(f"shades_of_gray: Minkowski norm p must be > 0, got {p}")
    levels = np.arange(256, dtype=np.float64)
    identity = np.repeat(levels[:, None], 3, 1).astype(np.uint8)
    if img.size == 0:
        return identity
    hist = np.stack([np.bincount(img[..., c].ravel(), minlength=256) for c in range(3)])
    e = np.power(hist @ np.power(levels, p) / (img.size // 3), 1.0 / p)
    if np.any(e <= 0):
        return identity
    gain = np.sqrt(np.mean(e ** 2)) / e
    return np.clip(np.rint(levels[:, None] * gain), 0, 255).astype(np.uint8)


def shades_of_gray(img: np.ndarray, p: float = 6) -> np.ndarray:
    """Shades of Gray colour constancy (``shades_of_gray_table``) applied.

    img: HxWx3 uint8 RGB. Returns HxWx3 uint8 RGB, a new array.
    """
    lut = shades_of_gray_table(img, p)
    return np.ascontiguousarray(np.stack([lut[img[..., c], c] for c in range(3)], -1))


def srgb_to_linear(c) -> np.ndarray:
    """sRGB values in [0, 1] -> linear light (float64)."""
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(lin) -> np.ndarray:
    """Linear light in [0, 1] -> sRGB values in [0, 1] (float64)."""
    lin = np.asarray(lin, dtype=np.float64)
    return np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055)


# the same for 8-bit values, as a table (float32; index it with uint8 sRGB)
SRGB8_TO_LINEAR = srgb_to_linear(np.arange(256) / 255).astype(np.float32)


def srgb_to_lab(rgb) -> np.ndarray:
    """sRGB (uint8 0..255, or float 0..1) ...x3 -> CIELAB (D65) float64 ...x3."""
    rgb = np.asarray(rgb)
    lin = srgb_to_linear(rgb / 255.0 if rgb.dtype == np.uint8 else rgb)
    xyz = lin @ LINEAR_RGB_TO_XYZ.T / WHITE_D65
    f = np.where(xyz > _DELTA ** 3, np.cbrt(xyz), xyz / (3 * _DELTA ** 2) + 4.0 / 29.0)
    L = 116.0 * f[..., 1] - 16.0
    a = 500.0 * (f[..., 0] - f[..., 1])
    b = 200.0 * (f[..., 1] - f[..., 2])
    return np.stack([L, a, b], axis=-1)


def lab_to_srgb(lab) -> np.ndarray:
    """CIELAB (D65) ...x3 -> sRGB float in [0, 1] (out-of-gamut values clipped)."""
    lab = np.asarray(lab, dtype=np.float64)
    fy = (lab[..., 0] + 16.0) / 116.0
    f = np.stack([fy + lab[..., 1] / 500.0, fy, fy - lab[..., 2] / 200.0], axis=-1)
    xyz = np.where(f > _DELTA, f ** 3, 3 * _DELTA ** 2 * (f - 4.0 / 29.0)) * WHITE_D65
    return linear_to_srgb(np.clip(xyz @ XYZ_TO_LINEAR_RGB.T, 0.0, 1.0))


def lab_to_uint8(lab) -> np.ndarray:
    return np.clip(np.rint(lab_to_srgb(lab) * 255.0), 0, 255).astype(np.uint8)


def ita_degrees(rgb) -> np.ndarray:
    """ITA angle in degrees for uint8 sRGB colours (Nx3 or HxWx3); shape drops the last axis."""
    lab = srgb_to_lab(rgb)
    return np.degrees(np.arctan2(lab[..., 0] - 50.0, lab[..., 2]))


def fitzpatrick_from_ita(ita):
    """Fitzpatrick type 1..6 from ITA: I > 55 >= II > 41 >= III > 28 >= IV > 10 >= V > -30 >= VI.

    Scalar in -> int out; array in -> int array out.
    """
    ita = np.asarray(ita, dtype=np.float64)
    types = 6 - np.searchsorted(np.array([-30.0, 10.0, 28.0, 41.0, 55.0]), ita, side="left")
    return int(types) if types.ndim == 0 else types.astype(np.int64)


def ita_range(fitzpatrick: int) -> tuple[float, float]:
    """(lo, hi) ITA band of a Fitzpatrick type (1..6); types I and VI are capped at +-90."""
    try:
        return _ITA_BANDS[int(fitzpatrick)]
    except (KeyError, TypeError, ValueError):
        raise ValueError(f"Fitzpatrick type must be 1..6, got {fitzpatrick!r}") from None
