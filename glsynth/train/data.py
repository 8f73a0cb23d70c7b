"""Preprocessing and augmentation shared by training and evaluation.

Preprocessing follows the paper (section 3.2.3 of the experimental details):
Shades of Gray colour constancy (p = 6) on the whole image, then per-channel
normalisation with the ImageNet mean and standard deviation (the statistics the
paper's pretrained backbone expects; kept here so that ImageNet-initialised backbones
can be dropped in), and a resize that keeps the aspect ratio so that the shorter side
equals the training size.

Training augmentation (``augment``): random horizontal and vertical flips, rotation
(a multiple of 90 degrees plus up to +-30), zoom (0.75-3x: close-ups from mid-range
views) and translation, applied as one affine warp to the image (bilinear) and to every
label map (nearest); brightness, contrast, saturation and hue shifts and a per-channel
gain (a colour cast, which Shades of Gray partly undoes, as it would on a real
photograph); light that falls off across the frame (half the crops); then blur, sensor
noise and JPEG compression, all before the colour constancy step. Pixels that the warp
brings in from outside the image are marked 255 (ignored) in the labels.
"""
from __future__ import annotations

import cv2
import numpy as np

from ..assets.colour import shades_of_gray_table

MEAN = np.array([0.485, 0.456, 0.406], np.float32)
STD = np.array([0.229, 0.224, 0.225], np.float32)
IGNORE = 255


def normalise(rgb_uint8: np.ndarray) -> np.ndarray:
    """HxWx3 uint8 RGB -> 3xHxW float32, Shades of Gray then ImageNet normalisation,
    through one 256-entry table per channel (the same values as ``shades_of_gray``
    followed by the arithmetic, at a fraction of the cost)."""
    corrected = shades_of_gray_table(rgb_uint8).astype(np.float32)
    table = ((corrected / 255.0 - MEAN) / STD).astype(np.float32)  # 256 x 3
    return np.stack([table[rgb_uint8[..., c], c] for c in range(3)])


def resize_shorter(img: np.ndarray, size: int, interp=cv2.INTER_AREA) -> np.ndarray:
    """Resize keeping the aspect ratio so that the shorter side is `size`."""
    h, w = img.shape[:2]
    s = size / min(h, w)
    nh, nw = max(1, int(round(h * s))), max(1, int(round(w * s)))
    if (nh, nw) == (h, w):
        return img
    if s > 1 and interp == cv2.INTER_AREA:
        interp = cv2.INTER_LINEAR
    return cv2.resize(img, (nw, nh), interpolation=interp)


def preprocess(rgb_uint8: np.ndarray, size: int) -> np.ndarray:
    """Evaluation preprocessing: resize (shorter side = size), Shades of Gray, normalise."""
    return normalise(resize_shorter(rgb_uint8, size))


def _colour_jitter(rng, img):
    x = img.astype(np.float32) / 255.0
    hsv = cv2.cvtColor(x, cv2.COLOR_RGB2HSV)
    hsv[..., 0] = (hsv[..., 0] + rng.uniform(-8, 8)) % 360.0           # hue, degrees
    hsv[..., 1] = np.clip(hsv[..., 1] * rng.uniform(0.75, 1.25), 0, 1)  # saturation
    x = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)
    x = x * rng.uniform(0.75, 1.25)                                     # brightness
    m = x.mean()
    x = (x - m) * rng.uniform(0.75, 1.25) + m                           # contrast
    x = x * rng.uniform(0.9, 1.1, size=3).astype(np.float32)            # colour cast
    return np.clip(np.rint(x * 255.0), 0, 255).astype(np.uint8)


# Zoom relative to "shorter side = size": log-uniform, up to 3x so that mid-range views
# also yield close-ups (a lesion and a hand's width of skin), as clinical photos are.
SCALE_RANGE = (0.75, 3.0)


def augment(rng: np.random.Generator, image: np.ndarray, labels: dict, size: int,
            scale_range=SCALE_RANGE, degrade=True):
    """Random geometric, colour and camera augmentation to a size x size crop.

    Geometry, one affine warp for the image (bilinear) and every label map (nearest):
    flips, a rotation by a multiple of 90 degrees plus up to +-30, a zoom in
    ``scale_range`` and a shift of the crop (within the image when zoomed in). Then the
    colour jitter, and (``degrade``) the degradations of real photographs: Gaussian
    blur, sensor noise and JPEG compression, each with its own probability.
    image: HxWx3 uint8; labels: name -> HxW uint8 maps (IGNORE-valued pixels stay ignored).
    Returns (image, labels) at size x size.
    """
    h, w = image.shape[:2]
    base = size / min(h, w)
    zoom = np.exp(rng.uniform(np.log(scale_range[0]), np.log(scale_range[1])))
    s = base * zoom
    ang = rng.uniform(-30, 30) + 90 * int(rng.integers(4))
    fx = -1.0 if rng.random() < 0.5 else 1.0
    fy = -1.0 if rng.random() < 0.5 else 1.0
    a = np.deg2rad(ang)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]) @ np.diag([fx, fy]) * s
    # crop centre: up to 15% of the image off its centre, or anywhere that keeps a
    # zoomed-in crop inside the image
    reach = np.maximum(0.15, 0.5 - 0.5 * size / (s * np.array([w, h])))
    c_src = np.array([w / 2, h / 2]) + rng.uniform(-1, 1, 2) * reach * np.array([w, h])
    t = np.array([size / 2, size / 2]) - R @ c_src
    M = np.hstack([R, t[:, None]]).astype(np.float64)
    img = cv2.warpAffine(image, M, (size, size), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT_101)
    out = {}
    for k, lab in labels.items():
        out[k] = cv2.warpAffine(lab, M, (size, size), flags=cv2.INTER_NEAREST,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=IGNORE)
    img = _colour_jitter(rng, img)
    img = _uneven_light(rng, img)
    return (_degrade(rng, img) if degrade else img), out


# Share of training crops lit unevenly, and the most light the field takes away (stops).
UNEVEN_LIGHT = 0.5
UNEVEN_STOPS = 1.5


def _uneven_light(rng, img):
    """Light that falls off across the frame, as on a real photograph of a curved body
    part under one lamp or a near flash: a gain, in linear light, from a ramp in a random
    direction plus a smooth blob a third of the frame wide, spanning up to UNEVEN_STOPS
    (p UNEVEN_LIGHT). Over healthy skin the dev photographs' luminance (L*, smoothed over
    8 of 512 px) spans a median 28 between its 10th and 90th percentiles, our rendered
    views' 13 (close-ups 11, regional views 16): our views are lit too evenly."""
    apply, stops = rng.random() < UNEVEN_LIGHT, rng.uniform(0.3, UNEVEN_STOPS)
    angle, blob_at, blob_w = rng.uniform(0, 2 * np.pi), rng.uniform(-0.5, 0.5, 2), rng.uniform(0, 1)
    if not apply:
        return img
    from ..pipeline.photo import linear_to_srgb8, srgb_to_linear
    h, w = img.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    x, y = 2 * xx / w - 1, 2 * yy / h - 1
    ramp = np.cos(angle) * x + np.sin(angle) * y
    blob = np.exp(-((x - blob_at[0]) ** 2 + (y - blob_at[1]) ** 2) / (2 * 0.33 ** 2))
    field = (1 - blob_w) * ramp / max(np.ptp(ramp), 1e-6) + blob_w * blob   # each spans <= 1
    gain = np.exp2(stops * (field - field.max()))[..., None]       # full light at its brightest
    return linear_to_srgb8(srgb_to_linear(img) * gain)


def _degrade(rng, img):
    """Blur (p 0.3, sigma 0.3-1.5 px), Gaussian noise (p 0.5, std 1-8 levels) and JPEG
    (p 0.5, quality 30-95), in the order a camera applies them. Each draws its random
    numbers whether or not it applies, so one change leaves the others' draws alone."""
    blur, sigma = rng.random() < 0.3, rng.uniform(0.3, 1.5)
    noisy, std = rng.random() < 0.5, rng.uniform(1.0, 8.0)
    jpeg, quality = rng.random() < 0.5, int(rng.integers(30, 96))
    noise_seed = int(rng.integers(2**31))
    if blur:
        img = cv2.GaussianBlur(img, (0, 0), sigma)
    if noisy:
        noise = np.random.default_rng(noise_seed).normal(0, std, img.shape).astype(np.float32)
        img = np.clip(img.astype(np.float32) + noise, 0, 255).round().astype(np.uint8)
    if jpeg:
        ok, buf = cv2.imencode(".jpg", img[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, quality])
        img = np.ascontiguousarray(cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1])
    return img


def plain(image: np.ndarray, labels: dict, size: int):
    """No augmentation: resize to size x size (image area-interpolated, labels nearest)."""
    img = cv2.resize(image, (size, size), interpolation=cv2.INTER_AREA if min(image.shape[:2]) > size
                     else cv2.INTER_LINEAR)
    return img, {k: cv2.resize(v, (size, size), interpolation=cv2.INTER_NEAREST) for k, v in labels.items()}
