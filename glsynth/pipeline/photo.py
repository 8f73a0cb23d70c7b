"""A post-render camera model: what a phone camera does to the rendered scene.

The renderer gives a clean, display-referred composite (body over background). Clinical
photos taken "in the wild" add optics and sensor artefacts; this module adds them to the
RGB image only. **Labels stay exact**: masks, instances, anatomy, depth, normals, UV and
face ids are the sharp geometric truth of the scene; a blurred lesion edge in the image
still has its label on the pixels the lesion covers geometrically.

Order (the order light takes through a camera), each step optional:

1. sRGB -> linear (only when one of the linear-space effects below is on)
2. defocus: thin-lens circle of confusion from the depth buffer,
   ``CoC(d) = kappa * |d - s| / (d * s)`` pixels (diameter) for a point at depth ``d``
   when focused at ``s`` (background pixels: ``d = inf``, so ``CoC = kappa / s``);
   ``kappa = A * f_px`` (aperture diameter ``A`` in scene units times the focal length
   in pixels, K[1, 1]; for s >> f this is the thin lens'
   ``A * f / (s - f) * |d - s| / d`` over the pixel pitch). Rendered as layered blur: the image is blurred with disc kernels of
   integer radii 0, 1, 2, ... and each pixel interpolates between the two layers around
   its own radius (radius 0 is the untouched pixel).
3. motion blur: camera shake, a short anti-aliased line kernel of random direction
4. chromatic aberration: red and blue scaled radially about the centre (lateral CA)
5. vignetting: gain ``1 - v * rho^2`` (rho = 1 at the image corners)
6. exposure: gain ``2^EV``
7. sensor noise: shot noise (variance ``a * x``, Gaussian approximation of Poisson)
   plus read noise (std ``b``), ``x`` in linear units, then clipped to [0, 1]
8. white balance / colour temperature: channel gains ``R 2^(t/2)``, ``B 2^(-t/2)``,
   ``G 2^g`` (``t`` warm/cool, ``g`` green/magenta tint); a share of images
   (``cast_share``) draws ``t`` and ``g`` from the wider cast ranges instead. Before
   them the camera's own grey-world balance (``auto_white_balance``, strength ``k``):
   gains ``(Y / m_c)^k`` from the frame's mean linear colour ``m`` (unclipped pixels)
   and its luminance ``Y``, which keep ``Y``; a frame filled with skin comes out less
   warm, one filled with a red plaque casts its skin green
9. linear -> sRGB, rounded to 8 bits
10. tone: the phone's rendering of its sRGB image, an S curve
    ``(1 - c) x + c x^2 (3 - 2 x)`` (mid-tones steeper by ``c / 2``, black, mid-grey and
    white fixed) and chroma scaled by ``1 + s`` about each pixel's luma (Rec. 601
    weights: grey stays grey)
11. watermark: in a share of images (``watermark``) the publisher's stamp, as online
    atlases put on their photographs (initials, a site's address, a copyright line) in a
    corner or across the middle, anti-aliased, opaque or translucent. It is a property
    of where clinical photo collections come from, not of the camera, and it changes no
    label (the dev set's annotators labelled such text as what lies under it)
12. JPEG at the sampled quality (OpenCV encode + decode)

An effect whose strength is zero is skipped entirely, so with every strength at zero the
image is returned unchanged (bit-exact). Parameters are drawn by ``sample_params`` from
the ``photo`` config section with the view's own generator
(``rng_for(seed, "photo", body_id, j)``) and recorded in the per-image JSON; ``apply``
is a pure function of the image, depth and those parameters (the noise realisation comes
from the recorded ``seed``), so a recorded sample can be reproduced exactly.
"""
from __future__ import annotations

import functools
import math

import cv2
import numpy as np

from ..assets.colour import LINEAR_RGB_TO_XYZ, SRGB8_TO_LINEAR

LINEAR_EFFECTS = ("defocus", "motion_blur", "chromatic_aberration", "vignetting", "exposure",
                  "noise", "auto_white_balance", "white_balance")
EFFECTS = LINEAR_EFFECTS + ("tone", "watermark", "jpeg")
LUMA = np.array([0.299, 0.587, 0.114], np.float32)   # Rec. 601, as JPEG's YCbCr
LUMA_LINEAR = LINEAR_RGB_TO_XYZ[1]                     # luminance Y of linear sRGB

# sRGB <-> linear look-up tables (the sRGB transfer function, IEC 61966-2-1)
SRGB_TO_LINEAR = SRGB8_TO_LINEAR
_LIN_STEPS = 65535
_L = np.arange(_LIN_STEPS + 1, dtype=np.float64) / _LIN_STEPS
LINEAR_TO_SRGB8 = np.clip(np.round(255 * np.where(_L <= 0.0031308, 12.92 * _L,
                                                    1.055 * _L ** (1 / 2.4) - 0.055)), 0, 255).astype(np.uint8)
del _L


def srgb_to_linear(img_u8: np.ndarray) -> np.ndarray:
    """float32 linear values of an 8-bit sRGB image (OpenCV's table look-up: a third of
    numpy indexing's time)."""
    img = np.ascontiguousarray(img_u8)
    return cv2.LUT(img, SRGB_TO_LINEAR.reshape(256, 1)).reshape(img.shape)


def linear_to_srgb8(lin: np.ndarray, gains=None) -> np.ndarray:
    """8-bit sRGB of linear values (clipped to [0, 1]; ``gains``: per-channel factors
    applied first, e.g. white balance)."""
    scale = np.float32(_LIN_STEPS) * (np.float32(1) if gains is None else np.asarray(gains, np.float32))
    idx = np.array(lin, np.float32, ndmin=1) * scale
    np.clip(idx, 0, _LIN_STEPS, out=idx)
    idx += np.float32(0.5)
    return LINEAR_TO_SRGB8[idx.astype(np.uint16)].reshape(np.shape(lin))


# ---- sampling ------------------------------------------------------------------------

def _u(rng, pair):
    lo, hi = float(pair[0]), float(pair[1])
    return lo + (hi - lo) * float(rng.random())


def sample_params(pc, rng, focus_distance: float, focal_px: float = 1.0) -> dict:
    """Draw the camera-model parameters for one image from config section ``pc``
    (``PhotoConfig``) for a view focused near ``focus_distance`` (the look-at point)
    with focal length ``focal_px`` (pixels). The same number of values is drawn whatever is switched on, so
    turning one effect on or off does not change the others. Returns
    ``{"enabled": bool, "effects": {name: params}}`` with only the active effects."""
    if not pc.enabled:
        return {"enabled": False, "effects": {}}
    aperture = _u(rng, pc.aperture)
    focus = float(focus_distance) * (1 + float(pc.focus_jitter) * (2 * float(rng.random()) - 1))
    length = _u(rng, pc.motion_blur)
    angle = 180.0 * float(rng.random())
    shot, read = _u(rng, pc.shot_noise), _u(rng, pc.read_noise)
    noise_seed = int(rng.integers(0, 2**31 - 1))
    cast = float(rng.random()) < pc.cast_share
    wb = _u(rng, pc.cast_white_balance if cast else pc.white_balance)
    tint = _u(rng, pc.cast_tint if cast else pc.tint)
    ev = _u(rng, pc.exposure)
    vig = _u(rng, pc.vignetting)
    ca = _u(rng, pc.chromatic_aberration)
    q_lo, q_hi = int(pc.jpeg_quality[0]), int(pc.jpeg_quality[1])
    quality = int(rng.integers(q_lo, q_hi + 1)) if q_hi > 0 else 0
    contrast, saturation = _u(rng, pc.contrast), _u(rng, pc.saturation)
    awb = _u(rng, pc.auto_white_balance)
    fx = {}
    if aperture > 0:
        fx["defocus"] = {"aperture": aperture, "focal_px": float(focal_px),
                         "kappa_px_m": aperture * float(focal_px), "focus_distance": focus,
                         "max_coc_px": float(pc.max_coc)}
    if length > 0:
        fx["motion_blur"] = {"length_px": length, "angle_deg": angle}
    if ca > 0:
        fx["chromatic_aberration"] = {"shift_px": ca}
    if vig > 0:
        fx["vignetting"] = {"strength": vig}
    if ev != 0:
        fx["exposure"] = {"ev": ev}
    if shot > 0 or read > 0:
        fx["noise"] = {"shot": shot, "read": read, "seed": noise_seed}
    if awb > 0:
        fx["auto_white_balance"] = {"strength": awb}
    if wb != 0 or tint != 0:
        fx["white_balance"] = {"temperature": wb, "tint": tint, "cast": cast,
                               "gains": [2 ** (wb / 2), 2 ** tint, 2 ** (-wb / 2)]}
    if contrast > 0 or saturation > 0:
        fx["tone"] = {"contrast": contrast, "saturation": saturation}
    if quality > 0:
        fx["jpeg"] = {"quality": quality}
    # (drawn last: its text has a variable length, and nothing is drawn after it)
    stamp = sample_watermark(rng)
    if stamp["share_draw"] < pc.watermark:
        fx["watermark"] = {k: v for k, v in stamp.items() if k != "share_draw"}
    return {"enabled": True, "effects": fx, "order": [e for e in EFFECTS if e in fx]}


_FONTS = (cv2.FONT_HERSHEY_SIMPLEX, cv2.FONT_HERSHEY_DUPLEX, cv2.FONT_HERSHEY_COMPLEX,
          cv2.FONT_HERSHEY_TRIPLEX, cv2.FONT_HERSHEY_PLAIN, cv2.FONT_HERSHEY_COMPLEX_SMALL)
_PLACES = ("bottom-left", "bottom-right", "top-left", "top-right", "bottom-centre", "centre")
_INKS = {"white": (255, 255, 255), "grey": (200, 200, 200), "black": (20, 20, 20), "yellow": (250, 225, 60)}


def _word(rng, lo, hi, letters="abcdefghijklmnopqrstuvwxyz"):
    return "".join(rng.choice(list(letters), int(rng.integers(lo, hi + 1))))


def sample_watermark(rng) -> dict:
    """The parameters of one publisher's stamp (``share_draw`` is compared with the
    config's share): its text (initials, a web address or a copyright line, as on
    the online atlases clinical collections were gathered from), font, cap height as a
    share of the image height, place and margin, ink, opacity, stroke weight and
    whether it has a dark drop shadow."""
    share_draw = float(rng.random())
    kind = str(rng.choice(["initials", "site", "copyright"], p=[0.45, 0.4, 0.15]))
    if kind == "initials":
        text = _word(rng, 2, 4, "ABCDEFGHIJKLMNOPQRSTUVWXYZ")
        height = float(rng.uniform(0.035, 0.09))
    elif kind == "site":
        tld = str(rng.choice([".com", ".org", ".net", ".com.br", ".info", ".de"]))
        text = str(rng.choice(["www.", "", "http://"], p=[0.6, 0.3, 0.1])) + _word(rng, 5, 12) + tld
        height = float(rng.uniform(0.018, 0.04))
    else:
        text = f"(c) {int(rng.integers(1995, 2024))} " + _word(rng, 4, 10).capitalize()
        height = float(rng.uniform(0.018, 0.035))
    ink = str(rng.choice(list(_INKS), p=[0.7, 0.1, 0.1, 0.1]))
    return {"share_draw": share_draw, "text": text, "kind": kind,
            "font": int(rng.integers(len(_FONTS))), "height": height,
            "place": str(rng.choice(_PLACES, p=[0.3, 0.3, 0.1, 0.1, 0.1, 0.1])),
            "margin": float(rng.uniform(0.01, 0.05)), "rgb": list(_INKS[ink]),
            "opacity": float(rng.uniform(0.5, 1.0)), "weight": float(rng.uniform(0.08, 0.2)),
            "shadow": bool(rng.random() < 0.4)}


# ---- the effects (float32 linear RGB, H x W x 3) ---------------------------------------

def coc_map(depth, kappa, focus, max_coc):
    """Circle-of-confusion diameter (pixels) per pixel; depth <= 0 (background) is at
    infinity."""
    d = np.asarray(depth, np.float32)
    body = d > 0
    d_safe = np.where(body, d, np.float32(1))
    coc = np.abs(d_safe - np.float32(focus))
    coc *= np.float32(kappa / focus)
    coc /= d_safe
    coc[~body] = kappa / focus
    return np.minimum(coc, np.float32(max_coc), out=coc)


def disc_kernel(radius: float, samples: int = 4) -> np.ndarray:
    """Anti-aliased disc of the given radius (pixels), normalised to sum 1."""
    n = int(math.ceil(radius))
    offs = (np.arange(samples) + 0.5) / samples - 0.5
    ax = np.arange(-n, n + 1, dtype=np.float64)
    yy = (ax[:, None, None, None] + offs[None, None, :, None])
    xx = (ax[None, :, None, None] + offs[None, None, None, :])
    k = ((xx ** 2 + yy ** 2) <= radius ** 2).mean(axis=(2, 3))
    return (k / k.sum()).astype(np.float32)


def defocus(lin, depth, kappa, focus, max_coc):
    r = coc_map(depth, kappa, focus, max_coc)
    r *= np.float32(0.5)                                   # radius in pixels
    out = np.zeros_like(lin)
    wgt = np.empty_like(r)
    for k in range(int(math.ceil(float(r.max()))) + 1):
        # weight of layer k: 1 - |r - k| clipped to [0, 1], only in the rows it touches
        rows = np.flatnonzero(((r > k - 1) & (r < k + 1)).any(1))
        if not len(rows):
            continue
        y0, y1 = int(rows[0]), int(rows[-1]) + 1
        w = np.subtract(r[y0:y1], np.float32(k), out=wgt[y0:y1])
        np.abs(w, out=w)
        np.subtract(np.float32(1), w, out=w)
        np.maximum(w, 0, out=w)
        if k == 0:
            layer = lin[y0:y1]
        else:  # blur a band k rows taller each side, so the kept rows see true neighbours
            b0, b1 = max(y0 - k, 0), min(y1 + k, lin.shape[0])
            layer = cv2.filter2D(lin[b0:b1], -1, disc_kernel(k), borderType=cv2.BORDER_REFLECT)
            layer = layer[y0 - b0:y1 - b0]
        cv2.accumulateProduct(layer, cv2.merge([w, w, w]), out[y0:y1])
    return out


def line_kernel(length: float, angle_deg: float, samples_per_px: int = 8) -> np.ndarray:
    """Normalised anti-aliased line segment of ``length`` pixels through the centre."""
    half = length / 2
    n = int(math.ceil(half)) + 1
    size = 2 * n + 1
    k = np.zeros((size, size), np.float64)
    t = np.linspace(-half, half, max(2, int(math.ceil(length * samples_per_px)) + 1))
    a = math.radians(angle_deg)
    xs, ys = n + t * math.cos(a), n - t * math.sin(a)
    x0, y0 = np.floor(xs).astype(int), np.floor(ys).astype(int)
    fx, fy = xs - x0, ys - y0
    for dx, dy, w in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy),
                      (1, 1, fx * fy)):
        np.add.at(k, (y0 + dy, x0 + dx), w)
    return (k / k.sum()).astype(np.float32)


def motion_blur(lin, length, angle_deg):
    return cv2.filter2D(lin, -1, line_kernel(length, angle_deg), borderType=cv2.BORDER_REFLECT)


@functools.lru_cache(maxsize=4)
def _radius_grid(h, w):
    """Pixel offsets from the image centre (x, y), their squared radius over the corner
    radius squared, and the corner radius; cached (read-only) since every view of a run
    has the same size."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    cy, cx = (h - 1) / 2, (w - 1) / 2
    dx, dy, rc = xx - cx, yy - cy, math.hypot(cx, cy)
    rho2 = (dx ** 2 + dy ** 2) / np.float32(rc ** 2)
    for a in (dx, dy, rho2):
        a.setflags(write=False)
    return dx, dy, rho2, rc


def chromatic_aberration(lin, shift_px):
    """Lateral CA: red magnified, blue shrunk about the centre, by ``shift_px`` pixels at
    the corners (green is the reference)."""
    h, w = lin.shape[:2]
    dx, dy, _, rc = _radius_grid(h, w)
    cx, cy = (w - 1) / 2, (h - 1) / 2
    channels = list(cv2.split(lin))
    for c, sign in ((0, 1.0), (2, -1.0)):
        s = 1 + sign * shift_px / rc           # channel magnified by s: sample at p / s
        mx, my = cx + dx / s, cy + dy / s
        channels[c] = cv2.remap(channels[c], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    return cv2.merge(channels)


def vignetting_gain(shape, strength):
    """Per-pixel gain ``1 - strength * rho^2`` (H x W float32)."""
    rho2 = _radius_grid(*shape[:2])[2]
    return 1 - np.float32(strength) * rho2


def add_noise(lin, shot, read, seed):
    """Shot + read noise in linear units: ``x + sqrt(shot * x + read^2) * N(0, 1)``,
    clipped to [0, 1]. The normals come from OpenCV's generator seeded with ``seed``
    (3.4x faster than numpy's for a 512^2 image; the generator is per thread, so the
    same seed gives the same noise in any thread)."""
    normal = np.empty(lin.shape, np.float32)
    cv2.setRNGSeed(int(seed))
    cv2.randn(normal.reshape(-1, 1), 0.0, 1.0)  # one channel: scalar std for every value
    std = np.maximum(lin, 0)
    std *= np.float32(shot)
    std += np.float32(read * read)
    np.sqrt(std, out=std)
    normal *= std
    normal += lin
    return np.clip(normal, 0, 1, out=normal)


def grey_world_gains(lin, strength):
    """RGB gains that take the frame's mean linear colour ``strength`` of the way (in
    log) to a grey of the same luminance, as a camera's grey-world white balance does:
    the mean of the pixels no channel of which clips (every pixel when fewer than 1%
    are left), sampled every 4th row and column. Bounded to [1/4, 4] so that a frame of
    nearly one primary (black cloth, a saturated drape) does not blow up a channel."""
    px = np.asarray(lin[::4, ::4], np.float64).reshape(-1, 3)
    ok = px.max(axis=1) < 0.98
    mean = np.maximum((px[ok] if ok.mean() >= 0.01 else px).mean(axis=0), 1e-6)
    y = float(LUMA_LINEAR @ mean)
    gains = np.clip((y / mean) ** float(strength), 0.25, 4.0)
    return gains * (y / float(LUMA_LINEAR @ (mean * gains)))


def tone_curve(contrast):
    """The S curve of strength ``contrast`` as a 256-entry table of 8-bit values."""
    x = np.arange(256, dtype=np.float64) / 255
    return np.rint(255 * ((1 - contrast) * x + contrast * x * x * (3 - 2 * x))).astype(np.uint8)


def tone(img_u8, contrast, saturation):
    """The phone's tone curve and chroma boost on an 8-bit sRGB image (a new array): a
    table look-up, then one 3x3 colour matrix, ``(1 + s) I - s 1 LUMA`` (rounded and
    clipped by OpenCV)."""
    img = np.ascontiguousarray(img_u8)
    out = cv2.LUT(img, tone_curve(contrast).reshape(256, 1)).reshape(img.shape) if contrast > 0 else img
    if saturation > 0:
        m = (1 + saturation) * np.eye(3) - saturation * np.outer(np.ones(3), LUMA)
        out = cv2.transform(out.reshape(-1, 1, 3), m.astype(np.float32)).reshape(img.shape)
    return out


def watermark(img_u8, p):
    """A publisher's stamp of parameters ``p`` (``sample_watermark``) over an 8-bit
    sRGB image (a new array), sized from the image's height so that one record gives
    the same stamp at any resolution; kept inside the frame."""
    h, w = img_u8.shape[:2]
    font, text = _FONTS[int(p["font"]) % len(_FONTS)], str(p["text"])
    cap = max(p["height"] * h, 4.0)
    (_, th), _ = cv2.getTextSize(text, font, 1.0, 1)
    scale = cap / max(th, 1)
    thick = max(1, int(round(p["weight"] * cap)))
    (tw, th), base = cv2.getTextSize(text, font, scale, thick)
    if tw > 0.9 * w:                                      # too long for the frame: smaller
        scale, thick = scale * 0.9 * w / tw, max(1, int(round(thick * 0.9 * w / tw)))
        (tw, th), base = cv2.getTextSize(text, font, scale, thick)
    m = p["margin"] * min(h, w)
    x = {"left": m, "right": w - m - tw}.get(p["place"].split("-")[-1], 0.5 * (w - tw))
    y = {"top": m + th, "bottom": h - m - base}.get(p["place"].split("-")[0], 0.5 * (h + th))
    off = max(1, thick // 2 + 1) if p["shadow"] else 0
    # only the text's box (and its shadow's) is touched: a stamp covers ~1% of the image
    x0, y0 = max(int(x) - thick - 2, 0), max(int(y) - th - thick - 2, 0)
    x1, y1 = min(int(x + tw) + thick + off + 3, w), min(int(y) + base + thick + off + 3, h)
    org = (int(round(x)) - x0, int(round(y)) - y0)
    out = img_u8.copy()
    roi = out[y0:y1, x0:x1].astype(np.float32)
    if off:
        cover = np.zeros(roi.shape[:2], np.uint8)
        cv2.putText(cover, text, (org[0] + off, org[1] + off), font, scale, 255, thick, cv2.LINE_AA)
        roi *= 1 - cover[..., None].astype(np.float32) * (0.6 * p["opacity"] / 255)
    cover = np.zeros(roi.shape[:2], np.uint8)
    cv2.putText(cover, text, org, font, scale, 255, thick, cv2.LINE_AA)
    roi += cover[..., None].astype(np.float32) * (p["opacity"] / 255) * (np.asarray(p["rgb"], np.float32) - roi)
    out[y0:y1, x0:x1] = np.clip(np.rint(roi), 0, 255).astype(np.uint8)
    return out


def jpeg(img_u8, quality):
    ok, buf = cv2.imencode(".jpg", img_u8[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return np.ascontiguousarray(cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1])


def apply(image: np.ndarray, params: dict, depth: np.ndarray | None = None) -> np.ndarray:
    """The camera model on an 8-bit sRGB image (H x W x 3) with the parameters of
    ``sample_params``; ``depth`` (view-space, <= 0 off the body) drives defocus.
    Returns a new uint8 image (the input itself when no effect is active)."""
    fx = params.get("effects", {}) if params.get("enabled", True) else {}
    img = image
    if any(e in fx for e in LINEAR_EFFECTS):
        lin = srgb_to_linear(img)
        if "defocus" in fx:
            p = fx["defocus"]
            if depth is None:
                raise ValueError("defocus needs the depth buffer")
            lin = defocus(lin, depth, p["kappa_px_m"], p["focus_distance"], p["max_coc_px"])
        if "motion_blur" in fx:
            lin = motion_blur(lin, fx["motion_blur"]["length_px"], fx["motion_blur"]["angle_deg"])
        if "chromatic_aberration" in fx:
            lin = chromatic_aberration(lin, fx["chromatic_aberration"]["shift_px"])
        # vignetting and exposure are both gains before the sensor: one multiply
        exposure = np.float32(2 ** fx["exposure"]["ev"]) if "exposure" in fx else None
        if "vignetting" in fx:
            gain = vignetting_gain(lin.shape, fx["vignetting"]["strength"])
            if exposure is not None:
                gain *= exposure
            lin = lin * gain[..., None]
        elif exposure is not None:
            lin = lin * exposure
        if "noise" in fx:
            p = fx["noise"]
            lin = add_noise(lin, p["shot"], p["read"], p["seed"])
        # white balance: gains after the sensor, applied by the sRGB encoding; the
        # camera's own balance first, from the frame it sees, then its error or a cast
        gains = np.ones(3)
        if "auto_white_balance" in fx:
            gains *= grey_world_gains(lin, fx["auto_white_balance"]["strength"])
        if "white_balance" in fx:
            gains *= fx["white_balance"]["gains"]
        img = linear_to_srgb8(lin, gains)
    if "tone" in fx:
        img = tone(img, fx["tone"]["contrast"], fx["tone"]["saturation"])
    if "watermark" in fx:
        img = watermark(img, fx["watermark"])
    if "jpeg" in fx:
        img = jpeg(img, fx["jpeg"]["quality"])
    return img
