"""Tileable skin micro-detail: the relief of the skin surface and body hair, at the scale of
a tenth of a millimetre, independent of any body texture's resolution.

The shader (``shaders/skin.glsl``) samples two periodic tiles with mipmaps, so that far
views see their average and close-ups their structure:

* the **relief tile** (``RELIEF_PERIOD`` metres square) holds the skin's microrelief:
  the rhombic net of primary skin lines (crossing families of long furrows ~0.5 mm
  apart), a finer criss-cross of secondary lines, long wavy tension lines, pores and a
  fine roughness.
  The shader also reads it at ``MACRO_SCALE`` times the size, for the coarser furrows
  that cross several plateaus (and so that the tile's period does not show). Half
  floats: R, G the height slope along the tile's x and y, B the relative albedo change
  (darker furrows, melanin speckle; mean 0 over the tile), A the pore opening (0..1).
  Floats keep the tile's means exact (8 bits would tilt a far view's normal by the
  rounding of the mean slope). The shader projects it from 3D positions along the two
  world axes nearest the surface normal (shaders/skin.frag), so it needs no UVs and has
  no seams. With it, on the same texels, the **flakes** of dry skin (xerosis): the
  opacity of keratin plates lifting along its furrows, which the shader lays over skin
  whose parameter map codes it as dry (``lipid_codes``).
* the **hair tile** (``HAIR_PERIOD`` metres square) holds hair strands lying along the
  tile's +x (the hair-flow direction, see :func:`hair_coordinates`), as coverage in four
  groups: R, G terminal hair (long, thick), B, A vellus hair (short, fine). A body's hair
  density map selects how many groups show, so density changes without aliasing
  (mipmaps average coverage, which is exactly what a far view should see).
* the **crease tile** (``CREASE_PERIOD`` metres square) holds wrinkles: wavy grooves
  that run along the tile's x, which the shader lays across the hair flow (around a
  limb, across the forehead and the neck, as flexion creases and the wrinkles of aged
  skin run), with fainter oblique families for the criss-cross of aged skin. The shader
  reads it as it is (fine wrinkles ~1.3 mm apart) and ``COARSE_CREASE_SCALE`` times
  larger (deep creases a few millimetres apart). Half floats: R, G the height slope
  along x and y, B the relative albedo change (mean 0), A unused.
* the **mesoscale tile** (``MESO_PERIOD`` metres square) holds what lies between the
  relief tile and the body texture's texels: the soft undulation of the skin over fat,
  muscle, tendons and veins (features ~6-30 mm, a few degrees of slope) and mottling of
  pigment and of the superficial vascular plexus at 1-6 mm. Without it a close-up of a
  hand's width of skin is evenly lit and evenly coloured between the furrows. The
  mottling is faint (RMS 3% melanin and 2% blood absorbance): at 8% and 5%, until
  2026-12-01, it speckled regional views of healthy skin like a rash. Half floats: R, G
  the height slope, B the melanin mottle and A the blood mottle (relative absorbance
  changes, mean 0), projected like the relief tile.

All four are made from a seed with numpy/OpenCV in a few seconds and kept per process.
Heights and sizes are in micrometres, from the dermatology literature's orders of
magnitude: primary furrows 20-100 um deep and 0.2-1 mm apart, follicular openings
50-150 um, terminal hairs 50-100 um thick and vellus hairs under 30 um.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np
from scipy.spatial import cKDTree

RELIEF_PERIOD = 0.008     # metres covered by one relief tile
RELIEF_SIZE = 1024        # texels (7.8 um each)
HAIR_PERIOD = 0.024       # metres covered by one hair tile (room for 2 cm hairs)
HAIR_SIZE = 2048          # texels (11.7 um each: over twice as fine as a close-up's
                          # finest pixel, 29 um at 1:1 macro in 512 px)
MACRO_SCALE = 4.37        # the relief tile's second, coarser reading (incommensurate)
MACRO_WEIGHT = 0.2        # its share at relief level 0.5 (the shader: times (level / 0.5)^2)
CREASE_PERIOD = 0.024     # metres covered by one crease tile
CREASE_SIZE = 1024        # texels (23 um each)
COARSE_CREASE_SCALE = 3.3  # the crease tile's second reading: deep creases
MESO_PERIOD = 0.096       # metres covered by one mesoscale tile
MESO_SIZE = 512           # texels (0.19 mm each)
# The skin parameter map's A channel is one axis of the skin's surface lipids: codes
# from XEROSIS_CODES up are sebum (oiliness 0 to 1 over XEROSIS_CODES..255), codes below
# it xerosis, dry and flaking skin (dryness 1 at code 0), so that where filtering mixes
# an oily texel with a dry one the two meet at neither (see ``lipid_codes``)
XEROSIS_CODES = 32
FLAKE_PATCH_SCALE = 7.3   # the flake tile's patch channel is read this much larger (incommensurate)


def lipid_codes(oil, dry):
    """The parameter map's A channel (uint8) for oiliness and dryness (0..1 each): sebum
    makes up for dryness, so the code follows their difference (``XEROSIS_CODES``)."""
    s = np.clip(oil, 0.0, 1.0) - np.clip(dry, 0.0, 1.0)
    code = np.where(s >= 0, XEROSIS_CODES + (255 - XEROSIS_CODES) * s, XEROSIS_CODES * (1 + s))
    return np.clip(np.rint(code), 0, 255).astype(np.uint8)


# skin parameters of a mesh without a SkinSurface: some relief and pores, vellus hair
# only, moderate sebum (RGBA: relief, pores, hair density, lipids)
DEFAULT_PARAMS = (140, 80, 64, int(lipid_codes(100 / 255, 0.0)))


@dataclass(frozen=True)
class DetailTiles:
    """The four tiles (relief, crease and mesoscale float16 RGBA, hair uint8 RGBA; row 0 =
    tile y 0), the relief tile's xerosis flakes (uint8) and their physical periods."""
    relief: np.ndarray
    hair: np.ndarray
    crease: np.ndarray
    meso: np.ndarray
    flakes: np.ndarray
    relief_period: float = RELIEF_PERIOD
    hair_period: float = HAIR_PERIOD
    crease_period: float = CREASE_PERIOD
    meso_period: float = MESO_PERIOD


def _periodic_noise(rng, size, feature_px):
    """Zero-mean, unit-std periodic noise with features about ``feature_px`` texels wide
    (white noise low-passed with a Gaussian in the Fourier domain, so it tiles exactly)."""
    white = rng.standard_normal((size, size))
    f = np.fft.fftfreq(size)
    k2 = f[:, None] ** 2 + f[None, :] ** 2
    sigma = 1.0 / (np.pi * max(feature_px, 1e-3))
    out = np.real(np.fft.ifft2(np.fft.fft2(white) * np.exp(-k2 / (2 * sigma ** 2))))
    return ((out - out.mean()) / (out.std() + 1e-12)).astype(np.float32)


def _wrap_blur(img, sigma):
    """Gaussian blur of a periodic image (OpenCV has no wrapping border for it)."""
    pad = int(np.ceil(4 * sigma))
    big = np.pad(img, pad, mode="wrap")
    return cv2.GaussianBlur(big, (0, 0), sigma)[pad:-pad, pad:-pad]


def _line_family(rng, size, spacing_px, direction, warp, fade):
    """Distance (texels) to the nearest line of a family of wavy, parallel lines that tile
    the square, and a strength in [0, 1] that fades lines in and out (``fade``: about
    the fraction of their length missing). ``direction``: the lines' normal as two
    integers (a, b); the lines are a x + b y = k size / m, so that they tile (m lines per
    tile along the normal, the one that puts them ``spacing_px`` apart most nearly),
    their phase bent by periodic noise of ``warp`` line spacings."""
    a, b = direction
    if a != int(a) or b != int(b) or (a, b) == (0, 0):
        raise ValueError(f"a line family's normal must be two integers, not both 0, got {direction}")
    norm = np.hypot(a, b)
    m = max(1, int(round(size / (spacing_px * norm))))   # lines per tile along the normal
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32) + 0.5
    phase = m * (a * xx + b * yy) / size + warp * _periodic_noise(rng, size, 2.5 * spacing_px)
    dist = np.abs(phase - np.round(phase)) * size / (m * norm)
    strength = np.clip(1.5 * _periodic_noise(rng, size, 3 * spacing_px) + 2.0 * (0.5 - fade) + 0.5, 0, 1)
    return dist, strength


def voronoi_walls(sites, points):
    """For each of ``points`` (N x 2): its distance to the nearest wall of the Voronoi
    tessellation of ``sites`` (M x 2) and the index of its cell's site. The distance to
    the bisector of the two nearest sites is exactly the distance to the wall."""
    d, i = cKDTree(sites).query(points, k=2)
    wall = (d[:, 1] ** 2 - d[:, 0] ** 2) / (2 * np.linalg.norm(sites[i[:, 1]] - sites[i[:, 0]], axis=1))
    return wall, i[:, 0]


def _relief_tile(seed=0, size=RELIEF_SIZE, period=RELIEF_PERIOD):
    rng = np.random.default_rng([seed, 1])
    um = period * 1e6 / size                                        # micrometres per texel
    # primary furrows: the rhombic net of skin lines. Two families of long lines about
    # 0.5 mm apart cross at a shallow angle (+-27 degrees to the tile's x, the skin's
    # tension lines), and a sparser, broken third family crosses them steeply, so the
    # plateaus are rhombi and triangles. Lines cross at X junctions and run on through
    # several (the Voronoi net of cells used until 2026-12-06 met at Y junctions and
    # read as cracked mud or crocodile leather up close). V grooves ~30 um deep and
    # ~25 um wide, their depth varying along each line, fading out in places; a wide
    # shallow shoulder rounds the plateaus between them
    furrows = np.zeros((size, size), np.float32)
    for spacing, normal, warp, fade, depth in ((500, (-1, 2), 0.25, 0.25, 30.0),
                                               (560, (1, 2), 0.25, 0.3, 30.0),
                                               (700, (3, -1), 0.3, 0.6, 22.0)):
        dist, strength = _line_family(rng, size, spacing / um, normal, warp, fade)
        depth = depth * strength * np.clip(0.8 + 0.5 * _periodic_noise(rng, size, 250 / um), 0.2, 1.5)
        furrows -= depth * np.exp(-dist / (25 / um)) + 0.25 * depth * np.exp(-dist / (90 / um))
    # secondary lines: a finer, shallower criss-cross (~0.17 mm, 6 um) in patches,
    # dividing the plateaus
    patches = np.clip(0.5 + 0.5 * _periodic_noise(rng, size, 300 / um), 0, 1)
    for spacing, normal in ((170, (1, 1)), (190, (-1, 1)), (210, (0, 1))):
        dist, strength = _line_family(rng, size, spacing / um, normal, 0.35, 0.5)
        furrows -= 6.0 * strength * patches * np.exp(-dist / (8 / um))
    # tension lines: long wavy furrows ~1.5 mm apart along x, fading
    dist, strength = _line_family(rng, size, 1500 / um, (0, 1), 0.3, 0.5)
    furrows -= 30.0 * strength * np.exp(-dist / (30 / um))
    # pores (follicular openings, 40-60 um across) on a jittered ~0.9 mm grid, half kept
    pores = np.zeros((size, size), np.float32)
    g = int(round(period / 0.0009))
    for i in range(g):
        for j in range(g):
            if rng.random() < 0.5:
                continue
            cy, cx = (np.array([i, j]) + 0.5 + rng.uniform(-0.4, 0.4, 2)) * size / g
            r = rng.uniform(20.0, 30.0) / um
            for oy in (-size, 0, size):
                for ox in (-size, 0, size):
                    cv2.circle(pores, (int(round((cx + ox) * 16)), int(round((cy + oy) * 16))),
                               int(round(r * 16)), 1.0, -1, cv2.LINE_AA, shift=4)
    pores = _wrap_blur(pores, 6.0 / um)
    # fine roughness: 2 um bumps ~25 um wide
    rough = 2.0 * _periodic_noise(rng, size, 25.0 / um)
    height = furrows + rough - 25.0 * pores                          # micrometres
    gx, gy = _slopes(height, um)
    # albedo: furrows a little darker (shadowed, thinner stratum corneum over them; the
    # relief's shading does most of it) and melanin speckle (+-5% in patches ~0.1-0.3
    # mm); mean 0 over the tile
    cavity = np.clip(-(furrows - np.median(furrows)) / 40.0, 0, 1)
    speckle = 0.6 * _periodic_noise(rng, size, 60.0 / um) + 0.4 * _periodic_noise(rng, size, 180.0 / um)
    shade = -0.12 * cavity + 0.06 * speckle
    shade -= shade.mean()
    tile = np.stack([gx, gy, shade, np.clip(pores, 0, 1)], -1).astype(np.float16)
    return tile, _flakes(np.random.default_rng([seed, 5]), cavity, um)


def _flakes(rng, cavity, um):
    """Xerosis on the relief tile (uint8, same size and period): R the opacity of the
    thin, translucent plates the dry horny layer comes away in, bounded by the skin's
    lines: a faint veil on the plateau (opacity 0.1) and a band some 20-60 um wide
    along its furrows, where the plate's edge lifts off and catches the light; G which of them lift, as
    noise with features a quarter of a millimetre, that the shader reads FLAKE_PATCH_SCALE
    times larger (patches of lifting plates a millimetre or two across, without the
    tile's period showing). Mipmaps average both, so far views see dry skin's even,
    ashy whitening."""
    size = cavity.shape[0]
    edge = np.clip(_wrap_blur(cavity, 20 / um) / 0.35, 0, 1)
    lifted = np.clip(0.5 + 0.3 * _periodic_noise(rng, size, 250 / um), 0, 1)
    return np.rint(255 * np.stack([0.1 + 0.9 * edge, lifted], -1)).astype(np.uint8)


def _slopes(height, um):
    """Central-difference slopes (um / um) along x and y of a periodic height map (um)."""
    gy = (np.roll(height, -1, 0) - np.roll(height, 1, 0)) / (2 * um)
    gx = (np.roll(height, -1, 1) - np.roll(height, 1, 1)) / (2 * um)
    return gx, gy


def _crease_tile(seed=0, size=CREASE_SIZE, period=CREASE_PERIOD):
    rng = np.random.default_rng([seed, 3])
    um = period * 1e6 / size
    height = np.zeros((size, size), np.float32)
    # (spacing um, direction of the lines' normal, waviness, share missing, depth um,
    # groove width um): wrinkles along x ~1.3 mm apart, ~90 um deep (the skin between
    # them bunched into a low ridge), and two fainter oblique families, mostly broken
    families = ((1300, (0, 1), 0.35, 0.35, 90.0, 60.0),
                (2100, (1, 2), 0.45, 0.7, 45.0, 45.0),
                (2300, (-1, 2), 0.45, 0.7, 45.0, 45.0))
    for spacing, normal, warp, fade, depth, width in families:
        dist, strength = _line_family(rng, size, spacing / um, normal, warp, fade)
        depth = depth * strength * np.clip(1 + 0.4 * _periodic_noise(rng, size, 1500 / um), 0.3, 1.6)
        height -= depth * (np.exp(-dist / (width / um)) + 0.3 * np.exp(-dist / (0.3 * spacing / um)))
    gx, gy = _slopes(height, um)
    # grooves a little darker (shadowed, and light caught in them); mean 0
    shade = -0.2 * np.clip(-(height - np.median(height)) / 90.0, 0, 1)
    shade -= shade.mean()
    return np.stack([gx, gy, shade, np.zeros_like(shade)], -1).astype(np.float16)


def _meso_tile(seed=0, size=MESO_SIZE, period=MESO_PERIOD, slope=0.04, pigment=0.032, blood=0.02):
    """Soft undulation (RMS slope ``slope``) and mottling of melanin and blood (RMS
    relative absorbance ``pigment``, ``blood``), each the sum of a coarse and a fine
    octave so that no single size shows."""
    rng = np.random.default_rng([seed, 4])
    mm = period * 1e3 / size                                          # mm per texel
    height = _periodic_noise(rng, size, 22 / mm) + 0.3 * _periodic_noise(rng, size, 7 / mm)
    gx, gy = _slopes(height, mm)
    rms = np.sqrt(np.mean(gx ** 2 + gy ** 2))
    gx, gy = gx * slope / rms, gy * slope / rms
    mel = _periodic_noise(rng, size, 4 / mm) + 0.7 * _periodic_noise(rng, size, 1.5 / mm)
    vessels = _periodic_noise(rng, size, 6 / mm) + 0.6 * _periodic_noise(rng, size, 2 / mm)
    mel = (mel - mel.mean()) * pigment / mel.std()
    # blood only adds: skin with less blood than its base colour would turn green (the
    # body texture's redness follows the same rule); mean 0 over the tile again
    vessels = np.maximum(vessels - vessels.mean(), 0.0) * blood / vessels.std()
    vessels -= vessels.mean()
    return np.stack([gx, gy, mel, vessels], -1).astype(np.float16)


def _draw_strands(canvas, rng, n, length_mm, width_um, spread_deg, curl, um, period_px):
    """Tapered, curved strands lying along +x, wrapped around the tile; each strand's
    coverage between 0.6 and 1 (thin and light hairs let some skin through)."""
    size = canvas.shape[0]
    # roots on a jittered grid (follicles keep apart; uniform roots clump, and a tile of
    # long hairs then varies in cover over its quarters, which a far view's coarse mip
    # levels show as speckle)
    m = int(np.ceil(np.sqrt(n)))
    cells = rng.permutation(m * m)[:n]
    roots = (np.stack([cells % m, cells // m], 1) + rng.uniform(0, 1, (n, 2))) * (size / m)
    for x0, y0 in roots:
        length = float(np.exp(rng.uniform(np.log(length_mm[0]), np.log(length_mm[1])))) * 1000 / um
        angle = np.radians(rng.normal(0, spread_deg))
        bend = rng.normal(0, curl)
        value = int(rng.uniform(150, 255))
        width = rng.uniform(*width_um) / um
        k = max(4, int(length / (3 * max(width, 1))))
        t = np.linspace(0, 1, k + 1)
        a = angle + bend * t
        xs = x0 + np.cumsum(np.r_[0, np.cos(a[:-1])]) * length / k
        ys = y0 + np.cumsum(np.r_[0, np.sin(a[:-1])]) * length / k
        taper = np.clip(1.2 - t, 0.35, 1.0)                          # thinner towards the tip
        for ox in (-size, 0, size):
            for oy in (-size, 0, size):
                for i in range(k):
                    p = (int(round((xs[i] + ox) * 16)), int(round((ys[i] + oy) * 16)))
                    q = (int(round((xs[i + 1] + ox) * 16)), int(round((ys[i + 1] + oy) * 16)))
                    th = max(1, int(round(width * taper[i])))
                    cv2.line(canvas, p, q, value, th, cv2.LINE_AA, shift=4)


def _hair_tile(seed=0, size=HAIR_SIZE, period=HAIR_PERIOD):
    rng = np.random.default_rng([seed, 2])
    um = period * 1e6 / size
    area_cm2 = (period * 100) ** 2
    groups = []
    for g in range(2):   # terminal: ~14 hairs / cm2 per group, 6-22 mm long (a shin's
        c = np.zeros((size, size), np.uint8)   # and a forearm's, under the tile's period),
        # 50-90 um thick, leaving the flow by ~30 degrees and bent by up to ~80 along
        # their length, so they cross
        _draw_strands(c, rng, int(14 * area_cm2), (6.0, 22.0), (50, 90), 30, 0.7, um, size)
        groups.append(c)
    for g in range(2):   # vellus: ~40 hairs / cm2 per group, 0.6-2.5 mm, 15-30 um
        c = np.zeros((size, size), np.uint8)
        _draw_strands(c, rng, int(40 * area_cm2), (0.6, 2.5), (15, 30), 30, 0.25, um, size)
        groups.append(c)
    return np.stack(groups, -1)


@lru_cache(maxsize=2)
def detail_tiles(seed: int = 0) -> DetailTiles:
    """The relief, hair, crease and mesoscale tiles for ``seed``, made once per process
    (~5 s on 2 cores, ~2.7 s of it the relief, ~1.5 s the creases)."""
    relief, flakes = _relief_tile(seed)
    return DetailTiles(relief, _hair_tile(seed), _crease_tile(seed), _meso_tile(seed), flakes)
