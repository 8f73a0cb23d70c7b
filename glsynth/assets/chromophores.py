"""A spectral model of skin colour from its chromophores, shared by healthy skin and
skin conditions, so that a condition looks as it does on each skin type (more blood
under a melanin-rich epidermis reads violaceous or dark brown, not pink).

Two layers, 400-700 nm in 10 nm steps:

* the **epidermis** (``EPIDERMIS_CM`` thick, scaled by ``epidermis``; 0 is an erosion)
  absorbs by melanin (volume fraction ``melanin``; a melanosome's absorption at 500 nm
  as Jacques gives it, 680 /cm, falling as lambda^-MELANIN_EXPONENT: see there) over a
  bloodless baseline;
* the **papillary dermis** (``PAPILLARY_CM``) scatters (reduced scattering
  46 * (lambda / 500)^-1.42 /cm) and absorbs by blood (volume fraction ``blood``, 150 g/l
  haemoglobin at oxygen saturation ``oxygen``), bilirubin (``bilirubin``, mmol/l) and
  dermal melanin (``dermal_melanin``, the blue-grey of melanin deep in the skin);
* the **reticular dermis** below scatters the same, with a little blood.

Blood is not spread evenly through the dermis but packed in vessels (``VESSEL_CM``
radius), so where it absorbs strongly the light that reaches a vessel's core is already
spent: its absorption is scaled by (1 - exp(-2 mu R)) / (2 mu R) (the vessel packaging
correction of Svaasand et al. and Verkruysse et al.). This flattens haemoglobin's
Soret band near 420 nm far more than its 540-580 nm bands, so blood-rich skin keeps
some blue and reads crimson rather than orange.

Layers combine by Kubelka-Munk's formulas (thin layers over the semi-infinite
reticular dermis), the epidermis also back-scattering a little; reflectance spectra are weighted by the CIE 1931 colour matching
functions (Wyman, Sloan and Shirley's multi-lobe fit) under a 6500 K blackbody, white
balanced to a perfect reflector, and encoded as sRGB. Haemoglobin's extinction follows
Prahl's tabulation at a few anchor wavelengths, interpolated in log space.

Forward: :func:`skin_rgb` (any array shape of parameters, vectorised). Inverse:
:class:`SkinInverse` finds the melanin and blood of the model colour nearest an sRGB
colour (in CIELAB), so a condition can be applied to any texture's skin, keeping the
texel's own deviation from the model as a residual.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from .colour import WHITE_D65, XYZ_TO_LINEAR_RGB, linear_to_srgb, srgb_to_lab

LAMBDA = np.arange(400.0, 701.0, 10.0)          # nm
EPIDERMIS_CM = 0.006                            # 60 um
EPI_SCATTER = 0.12      # the epidermis scatters 0.12 times as much as the dermis per length
SURFACE = 0.005         # diffuse share of the surface reflection
PAPILLARY_CM = 0.02     # 200 um of papillary dermis
RETICULAR_BLOOD = 0.005 # blood volume fraction of the reticular dermis
HB_G_PER_L = 150.0
VESSEL_CM = 0.0015      # radius of the dermal vessels holding the blood (15 um)
HB_MOLAR_MASS = 64500.0
# Melanin's absorption falls with wavelength as lambda^-MELANIN_EXPONENT. Jacques's fit
# to melanosomes in vitro has 3.33; with it, adding melanin to light skin raised b* about
# as much as it lowered L* (db*/dL* -1.0 at ITA 45), where skin measured across types
# rises only ~0.2 in b* per unit of L* (skin.skin_lab's locus), so pigmented lesions came
# out orange and no (melanin, blood) reached mid and dark skin colours (3.9-15 CIEDE76
# off the locus at ITA 45 to -20: the inverse made up with 10-20% blood). Fitted to the
# locus at ITA 65 to -40, exponents 1.8-2.0 are best (mean 1.8-1.9 off, against 7.6;
# `tests/test_lesions.py` checks both).
MELANIN_EXPONENT = 2.0

# molar extinction (cm^-1 / M) of oxy- and deoxyhaemoglobin at anchor wavelengths (Prahl)
_HB_ANCHORS = {
    "lambda": [400, 414, 420, 430, 440, 450, 460, 480, 500, 520, 542, 550, 556, 560, 570, 576,
               580, 590, 600, 620, 640, 660, 680, 700],
    "oxy": [266232, 524280, 480360, 214120, 103292, 62816, 44480, 33209, 20932, 24202, 53236,
            43016, 36030, 32613, 44496, 55540, 50104, 14400, 3200, 942, 442, 320, 272, 290],
    "deoxy": [223296, 332392, 407920, 528600, 413280, 103292, 23388, 14550, 20862, 31590, 46592,
              53412, 54628, 53788, 45072, 37020, 37020, 28324, 14677, 6509, 4243, 3227, 2278, 1794],
}
# bilirubin in plasma (cm^-1 / M): a broad band peaking near 460 nm
_BILI_PEAK, _BILI_WIDTH, _BILI_MAX = 460.0, 32.0, 55000.0


def _interp_log(x, xs, ys):
    return np.exp(np.interp(x, xs, np.log(ys)))


def _packed(mu_blood):
    """Whole blood's absorption (/cm) as it acts when packed in vessels of radius
    VESSEL_CM: unchanged where blood is nearly transparent, divided by up to ~8 in the
    Soret band (by ~1.3 in the 540-580 nm bands)."""
    x = 2.0 * mu_blood * VESSEL_CM
    return mu_blood * -np.expm1(-x) / x


@lru_cache(maxsize=1)
def _spectra():
    lam = LAMBDA
    mel = 6.6e11 * 500.0 ** -3.33 * (lam / 500.0) ** -MELANIN_EXPONENT
    base = 0.244 + 85.3 * np.exp(-(lam - 154.0) / 66.2)
    molar_hb = HB_G_PER_L / HB_MOLAR_MASS
    hbo2 = 2.303 * molar_hb * _interp_log(lam, _HB_ANCHORS["lambda"], _HB_ANCHORS["oxy"])
    hb = 2.303 * molar_hb * _interp_log(lam, _HB_ANCHORS["lambda"], _HB_ANCHORS["deoxy"])
    hbo2, hb = _packed(hbo2), _packed(hb)
    bili = 2.303 * 1e-3 * _BILI_MAX * np.exp(-0.5 * ((lam - _BILI_PEAK) / _BILI_WIDTH) ** 2)
    scat = 46.0 * (lam / 500.0) ** -1.42
    # CIE 1931 2-degree colour matching functions, Wyman-Sloan-Shirley multi-lobe fit
    def g(mu, s1, s2):
        return np.exp(-0.5 * ((lam - mu) / np.where(lam < mu, s1, s2)) ** 2)
    cmf = np.stack([1.056 * g(599.8, 37.9, 31.0) + 0.362 * g(442.0, 16.0, 26.7) - 0.065 * g(501.1, 20.4, 26.2),
                    0.821 * g(568.8, 46.9, 40.5) + 0.286 * g(530.9, 16.3, 31.1),
                    1.217 * g(437.0, 11.8, 36.0) + 0.681 * g(459.0, 26.0, 13.8)], 1)
    h, c, k, t = 6.62607e-34, 2.99792e8, 1.380649e-23, 6500.0
    m = lam * 1e-9
    illum = 1.0 / (m ** 5 * (np.exp(h * c / (m * k * t)) - 1.0))
    weights = cmf * illum[:, None]
    white = weights.sum(0)
    return {"mel": mel, "base": base, "hbo2": hbo2, "hb": hb, "bili": bili, "scat": scat,
            "weights": weights / white[1], "white": white / white[1]}


@lru_cache(maxsize=1)
def _spectra32():
    # the spectral model runs in float32: twice as fast as float64, and its rounding
    # (~1e-7) is far below a colour's 1/255 step
    return {k: v.astype(np.float32) for k, v in _spectra().items()}


def reflectance(melanin, blood, oxygen=0.75, bilirubin=0.0, dermal_melanin=0.0, epidermis=1.0,
                scatter=1.0):
    """Diffuse reflectance spectra (..., 31, float32) of skin with these chromophores
    (arrays broadcast together; volume fractions are clipped to [0, 1])."""
    sp = _spectra32()
    melanin, blood, oxygen, bilirubin, dermal_melanin, epidermis, scatter = (
        np.clip(np.asarray(x, np.float32), lo, hi)[..., None] for x, lo, hi in
        ((melanin, 0, 1), (blood, 0, 1), (oxygen, 0, 1), (bilirubin, 0, 10),
         (dermal_melanin, 0, 1), (epidermis, 0, 4), (scatter, 0.05, 4)))
    mu_epi = melanin * sp["mel"] + (1 - melanin) * sp["base"]
    mu_blood = oxygen * sp["hbo2"] + (1 - oxygen) * sp["hb"]
    # papillary dermis: the thin, vascular layer under the epidermis that inflammation
    # fills with blood; reticular dermis below: scattering, with a little blood
    mu_pap = (blood * mu_blood + (1 - blood) * sp["base"] + bilirubin * sp["bili"]
              + dermal_melanin * sp["mel"])
    mu_ret = RETICULAR_BLOOD * mu_blood + sp["base"] + bilirubin * sp["bili"]
    # ``scatter`` scales the dermis's scattering: tissue with less collagen and more
    # vessels (granulation tissue, vascular tumours) scatters less, so its blood shows a
    # deeper red than the same blood in normal dermis
    scat = sp["scat"] * scatter
    ks = mu_ret / scat
    r_ret = 1 + ks - np.sqrt(ks * ks + 2 * ks)
    r_pap, t_pap = _km_layer(2 * mu_pap, 2 * scat, PAPILLARY_CM)
    r_derm = r_pap + t_pap * t_pap * r_ret / (1 - r_pap * r_ret)
    # the epidermis: it back-scatters a little (the whitish sheen that keeps skin from
    # looking like dye) and filters what reaches the dermis, twice
    r_epi, t_epi = _km_layer(2 * mu_epi, 2 * EPI_SCATTER * sp["scat"], EPIDERMIS_CM * epidermis)
    return SURFACE + r_epi + t_epi * t_epi * r_derm / (1 - r_epi * r_derm)


def _km_layer(K, S, thickness):
    """Kubelka-Munk reflectance and transmittance of a layer (absorption K, scattering S
    per cm) of the given thickness over a black background.

    With a = 1 + K/S, b = sqrt(a^2 - 1) and x = b S d, R = sinh x / (a sinh x + b cosh x)
    and T = b / (the same); multiplied through by 2 exp(-x) they need one exponential and
    stay finite for any thickness (sinh and cosh overflow in thick, dark layers)."""
    k = K / S
    a = 1 + k
    b = np.sqrt(k * (k + 2))                      # = sqrt(a^2 - 1), exact for small k
    e = np.exp(-b * (S * thickness))
    one_minus_e2 = 1 - e * e
    den = a * one_minus_e2 + b * (2 - one_minus_e2)
    return one_minus_e2 / den, 2 * b * e / den


def _flattened(*params):
    """The parameters broadcast together: their common shape and each as a flat float64
    array."""
    params = np.broadcast_arrays(*(np.asarray(x, np.float64) for x in params))
    return params[0].shape, [p.reshape(-1) for p in params]


# pixels per block of the spectral model: its (pixels x 31) temporaries stay in cache
_BLOCK = 8192


def linear_rgb(melanin, blood, oxygen=0.75, bilirubin=0.0, dermal_melanin=0.0, epidermis=1.0,
               scatter=1.0):
    """Linear sRGB (..., 3) of skin with these chromophores, not clipped: a value outside
    [0, 1] is a colour outside sRGB's gamut."""
    sp = _spectra()
    shape, flat = _flattened(melanin, blood, oxygen, bilirubin, dermal_melanin, epidermis, scatter)
    to_linear = (sp["weights"] * (WHITE_D65 / sp["white"])) @ XYZ_TO_LINEAR_RGB.T   # (31, 3)
    out = np.empty((flat[0].size, 3))
    for s in range(0, flat[0].size, _BLOCK):
        out[s:s + _BLOCK] = reflectance(*(p[s:s + _BLOCK] for p in flat)) @ to_linear
    return out.reshape(shape + (3,))


def skin_rgb(melanin, blood, oxygen=0.75, bilirubin=0.0, dermal_melanin=0.0, epidermis=1.0,
             scatter=1.0):
    """sRGB in [0, 1] (..., 3) of skin with these chromophores."""
    return linear_to_srgb(np.clip(linear_rgb(melanin, blood, oxygen, bilirubin, dermal_melanin, epidermis,
                                             scatter), 0, 1))


# The look-up table of skin_rgb_fast: linear sRGB over (melanin, blood, oxygen) of skin
# with its whole epidermis, melanin and blood log-spaced (0 in front), oxygen linear.
_LUT_AXES = (np.r_[0.0, np.geomspace(1e-4, 1.0, 64)], np.r_[0.0, np.geomspace(1e-4, 0.7, 64)],
             np.linspace(0.0, 1.0, 11))
_LOG_EPS = 5e-5


@lru_cache(maxsize=1)
def _lut():
    grids = np.meshgrid(*_LUT_AXES, indexing="ij")
    rgb = skin_rgb(grids[0], grids[1], grids[2])
    lin = np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4)
    coords = [np.log(_LUT_AXES[0] + _LOG_EPS), np.log(_LUT_AXES[1] + _LOG_EPS), _LUT_AXES[2]]
    return lin.astype(np.float32), coords


def _trilinear(table, coords, points):
    """Multilinear interpolation of ``table`` (n0 x n1 x n2 x C) on the rectilinear grid
    ``coords`` at ``points`` (N x 3), clamped to the grid."""
    idx, frac = [], []
    for d, ax in enumerate(coords):
        x = np.clip(points[:, d], ax[0], ax[-1])
        i = np.clip(np.searchsorted(ax, x) - 1, 0, len(ax) - 2)
        idx.append(i)
        frac.append(((x - ax[i]) / (ax[i + 1] - ax[i]))[:, None].astype(np.float32))
    out = 0.0
    for c0 in (0, 1):
        for c1 in (0, 1):
            for c2 in (0, 1):
                w = ((frac[0] if c0 else 1 - frac[0]) * (frac[1] if c1 else 1 - frac[1])
                     * (frac[2] if c2 else 1 - frac[2]))
                out = out + w * table[idx[0] + c0, idx[1] + c1, idx[2] + c2]
    return out


def skin_rgb_fast(melanin, blood, oxygen=0.75, bilirubin=0.0, dermal_melanin=0.0, epidermis=1.0,
                  scatter=1.0):
    """``skin_rgb`` from a look-up table (within ~1/255 of it) where the epidermis is
    whole, the dermis scatters as usual and bilirubin and dermal melanin are 0, computed
    exactly elsewhere."""
    shape, (mel, blood, oxy, bili, dmel, epi, scat) = _flattened(
        melanin, blood, oxygen, bilirubin, dermal_melanin, epidermis, scatter)
    table, coords = _lut()
    pts = np.stack([np.log(np.clip(mel, 0, 1) + _LOG_EPS), np.log(np.clip(blood, 0, 0.7) + _LOG_EPS),
                    np.clip(oxy, 0, 1)], 1)
    lin = np.clip(_trilinear(table, coords, pts), 0, 1)
    out = linear_to_srgb(lin)
    exact = (bili > 0) | (dmel > 0) | (blood > 0.7) | (epi != 1) | (scat != 1)
    if exact.any():
        out[exact] = skin_rgb(mel[exact], blood[exact], oxy[exact], bili[exact], dmel[exact], epi[exact],
                              scat[exact])
    return out.reshape(shape + (3,))


class SkinInverse:
    """Nearest (melanin, blood) of the model for sRGB skin colours, by a look-up over a
    grid (melanin 0.002-0.6, blood 0.002-0.2, both log-spaced; oxygen 0.75) matched in
    CIELAB. ``__call__`` returns (melanin, blood, residual Lab = colour - model). The
    nearest grid point is looked up once per colour at 6 bits a channel, in a 64^3
    table filled as colours first occur: skin textures use a few thousand of its cells,
    and the whole cube, mostly colours far from any skin, took ~4 s of nearest-neighbour
    search per process; the residual is the colour's own, exactly."""

    def __init__(self, n_mel=96, n_blood=64):
        self.mel = np.geomspace(0.002, 0.6, n_mel)
        self.blood = np.geomspace(0.002, 0.2, n_blood)
        mm, bb = np.meshgrid(self.mel, self.blood, indexing="ij")
        self.grid_mel, self.grid_blood = mm.ravel(), bb.ravel()
        self.grid_lab = srgb_to_lab(skin_rgb(self.grid_mel, self.grid_blood))
        self._table = np.full(64 ** 3, -1, np.int32)     # -1: not looked up yet
        self._tree = None

    def _nearest(self, codes):
        """Grid indices for 6-bit colour codes (r << 12 | g << 6 | b), filling the table."""
        missing = np.unique(codes[self._table[codes] < 0])
        if missing.size:
            if self._tree is None:
                from scipy.spatial import cKDTree
                self._tree = cKDTree(self.grid_lab)
            centres = np.stack([missing >> 12, (missing >> 6) & 63, missing & 63], 1) * 4 + 2
            self._table[missing] = self._tree.query(srgb_to_lab(centres.astype(np.uint8)))[1]
        return self._table[codes]

    def __call__(self, rgb_uint8):
        rgb = np.asarray(rgb_uint8, np.uint8)
        flat = rgb.reshape(-1, 3).astype(np.int32) >> 2
        idx = self._nearest((flat[:, 0] << 12) | (flat[:, 1] << 6) | flat[:, 2])
        lab = srgb_to_lab(rgb.reshape(-1, 3))
        shape = rgb.shape[:-1]
        return (self.grid_mel[idx].reshape(shape), self.grid_blood[idx].reshape(shape),
                (lab - self.grid_lab[idx]).reshape(rgb.shape))


@lru_cache(maxsize=1)
def skin_inverse() -> SkinInverse:
    return SkinInverse()


def melanin_slope(lab) -> np.ndarray:
    """How a* and b* change per unit of L* where a skin colour (CIELAB) holds a little more
    or less epidermal melanin, as (da*/dL*, db*/dL*) in the spectral model at the colour's
    nearest (melanin, blood). Light skin with more melanin is darker and a little
    yellower (db*/dL* about -0.45 at ITA 45); very dark skin darker and less chromatic
    (about +0.4 at ITA -40)."""
    inv = skin_inverse()
    i = int(np.argmin(((inv.grid_lab - np.asarray(lab, np.float64)) ** 2).sum(-1)))
    m, blood = inv.grid_mel[i], inv.grid_blood[i]
    d = srgb_to_lab(skin_rgb(m * 1.1, blood)) - srgb_to_lab(skin_rgb(m / 1.1, blood))
    d = np.asarray(d, np.float64).ravel()
    return np.array([d[1] / d[0], d[2] / d[0]])
