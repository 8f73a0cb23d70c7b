"""Configuration: YAML validated into dataclasses, with ``key.sub=value`` overrides.

Every key is declared once, below, with :func:`key`: its default, the values it accepts
and a one-line description. ``Config()`` is glsynth's default configuration; validation
reads the accepted values from the declarations, and ``configs/default.yaml`` and the
key table of ``docs/config.md`` are generated from them (``glsynth.configdoc``). Every
error names the offending key and value (and the file). Ranges are [lo, hi] lists.
"""
from __future__ import annotations

import copy
import dataclasses
import math
import os
from dataclasses import dataclass, field
from typing import Any, Callable, NamedTuple

import yaml

from .errors import GlsynthError


class ConfigError(GlsynthError, ValueError):
    """A configuration file or override is invalid; the message names the key."""


OUTPUTS = ("rgb", "semantic", "instances", "anatomy", "depth", "nevi", "normals", "uv", "face_id")
# written unless ``outputs`` says otherwise; the extra 3D outputs are opt-in
DEFAULT_OUTPUTS = ("rgb", "semantic", "instances", "anatomy", "depth")
BLEND_METHODS = ("deep", "poisson", "paste")
SHADINGS = ("phong", "skin")
FRAMINGS = ("wild", "closeup", "regional")
FEATURES = ("auto", "vgg16", "filters")
OVERLAPS = ("lesion", "dilated")
LIGHT_POSITIONS = ("room", "near_camera", "paper")


# ---- how a key is declared --------------------------------------------------------------
def _num(x) -> str:
    return f"{x:g}"


@dataclass(frozen=True)
class Interval:
    """The numbers a key accepts: ``lo`` .. ``hi`` (None: unbounded), each end included
    unless marked open."""
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False

    def __contains__(self, x) -> bool:
        return ((self.lo is None or (x > self.lo if self.lo_open else x >= self.lo)) and
                (self.hi is None or (x < self.hi if self.hi_open else x <= self.hi)))

    def __str__(self):
        if self.hi is None:
            return f"{'>' if self.lo_open else '>='} {_num(self.lo)}"
        return (f"in {'(' if self.lo_open else '['}{_num(self.lo)}, {_num(self.hi)}"
                f"{')' if self.hi_open else ']'}")


def at_least(lo) -> Interval:
    return Interval(lo)


def above(lo) -> Interval:
    return Interval(lo, lo_open=True)


def between(lo, hi) -> Interval:
    return Interval(lo, hi)


class Rule(NamedTuple):
    """A check no interval or list of choices expresses: ``test(value)`` is true for a
    good value; ``allowed`` says what is accepted (after "must be" in errors, and in the
    docs' table), or is a function that says it (to import what it names only then)."""
    test: Callable[[Any], bool]
    allowed: str | Callable[[], str]

    def describe(self) -> str:
        return self.allowed() if callable(self.allowed) else self.allowed


@dataclass(frozen=True)
class Accepts:
    """What a key accepts: a number ``within`` an interval, a [low, high] ``pair``
    within one, one of ``choices``, or whatever ``rule`` allows (any that are given)."""
    within: Interval | None = None
    pair: Interval | None = None
    choices: tuple | None = None
    rule: Rule | None = None

    def describe(self) -> str:
        parts = []
        if self.within is not None:
            parts.append(str(self.within))
        if self.pair is not None:
            parts.append(f"[low, high] {self.pair}")
        if self.choices is not None:
            parts.append("one of " + ", ".join(map(str, self.choices)))
        if self.rule is not None:
            parts.append(self.rule.describe())
        return "; ".join(parts)


def key(default, doc: str, *, within=None, pair=None, choices=None, rule=None):
    """A config field: ``default`` (lists and dicts are copied for each instance), its
    one-line ``doc`` and what it accepts (see :class:`Accepts`)."""
    meta = {"doc": doc, "accepts": Accepts(within, pair, tuple(choices) if choices else None, rule)}
    if isinstance(default, (list, dict)):
        return field(default_factory=lambda: copy.deepcopy(default), metadata=meta)
    return field(default=default, metadata=meta)


def _presets():  # imported when needed: the procedural lesion code is slow to import
    from .assets.morphology import PRESETS
    return PRESETS


def _known_presets(kinds) -> bool:
    return all(k in _presets() for k in kinds)


def _framing_weights(framing) -> bool:
    return (all(k in FRAMINGS for k in framing) and
            all(isinstance(x, (int, float)) and not isinstance(x, bool) and x >= 0
                for x in framing.values()) and sum(framing.values()) > 0)


def _jpeg_quality(q) -> bool:
    return all(float(x).is_integer() for x in q) and (q == [0, 0] or q[0] >= 1)


# ---- the keys -----------------------------------------------------------------------------
# Config() is glsynth's default run: built-in bodies, procedural lesions and rooms, small
# counts (a couple of minutes on 2 CPU cores once the body cache is warm), and the
# realism additions switched on. configs/paper.yaml sets the DermSynth3D paper's values.
@dataclass
class BodiesConfig:
    """The bodies that lesions are pasted on and views are rendered of."""
    source: str = key("builtin", "'builtin' (parametric bodies made by glsynth) or a folder of "
                      "3DBodyTex scans / meshes, one folder per body")
    count: int = key(2, "bodies in the run (from a folder: that many, spread over skin tone)",
                     within=at_least(1))
    first: int = key(0, "index of the run's first body: a shard of a larger run holds bodies "
                     "first..first+count-1 of it (built-in ones with the procedural lesions dealt "
                     "to them there; scans in an order spread over skin tone) and backgrounds of "
                     "its own (sim2real's parts are shards)", within=at_least(0))
    texture_size: int = key(2048, "texels per side of a built-in body's texture",
                            within=between(64, 8192))
    fitzpatrick: list = key([1, 6], "Fitzpatrick skin types of built-in bodies (drawn per body)",
                            pair=between(1, 6))
    poses: list = key(["a-pose", "arms-down", "slight-turn", "arms-raised"],
                      "poses of built-in bodies (drawn per body)",
                      rule=Rule(bool, "a list of at least one pose"))


@dataclass
class LesionsConfig:
    """The lesions pasted on each body: procedural conditions or real images with masks."""
    source: str = key("procedural", "'procedural' or a folder of lesion images with masks (see layout)")
    layout: str = key("fitz17k", "a lesion folder's layout: the Fitzpatrick17k annotations, or "
                      "image + mask pairs", choices=("fitz17k", "pairs"))
    per_body: int = key(3, "lesions placed per body (0: none, no paste or blend)", within=at_least(0))
    colour_constancy: bool = key(True, "Shades of Gray colour constancy on real lesion images (paper)")
    size: list = key([0.15, 0.4], "lesion extent / placement view width", pair=between(0.01, 1.5))
    min_size: int = key(16, "lesion images with a shorter side (px) are rejected",
                        within=between(1, 4096))
    max_mask_fraction: float = key(0.95, "masks covering more of their image are rejected",
                                   within=Interval(0, 1, lo_open=True))
    kinds: list = key([], "procedural presets to use ([]: all)",
                      rule=Rule(_known_presets, lambda: f"names from {sorted(_presets())}"))
    resolution: int = key(512, "grid cells per side of a procedural condition",
                          within=between(64, 4096))
    halo: float = key(0.35, "procedural lesions: each outline takes in the visible change round "
                      "its lesion (an inflamed halo, a macerated rim, a faint fringe) out to this "
                      "share of its radius, as annotators draw (0: the preset's own outline)",
                      within=between(0, 2))
    decal_size: int = key(1024, "pixels per side of each lesion's decal, drawn over the body "
                          "texture at the lesion's own resolution (0: no decals)",
                          rule=Rule(lambda n: n == 0 or 64 <= n <= 4096, "0 or in [64, 4096]"))
    eruption: float = key(0.0, "procedural lesions: probability that a body's first lesion of an "
                          "eruptive preset (assets/morphology.ERUPTIVE: psoriasis, eczema, "
                          "urticaria...) spreads as a generalised eruption, further draws of its "
                          "preset placed round it; close-up and regional views treat the eruption "
                          "as one lesion (0: every lesion alone, as the paper's; at 0.5 generation "
                          "takes ~1.2x as long, docs/realism.md)", within=between(0, 1))
    eruption_lesions: list = key([2, 6], "further lesions of an eruption (drawn uniformly, both "
                                 "ends included)", pair=between(1, 50),
                                 rule=Rule(lambda q: all(float(x).is_integer() for x in q), "integers"))
    eruption_radius: list = key([0.1, 0.3], "an eruption's lesions lie within this distance (m) "
                                "of its first", pair=between(0.01, 2.0))


@dataclass
class PasteConfig:
    """Where lesions go (paper appendix A): a view of each candidate place, kept when the
    surface under the lesion is flat enough and free."""
    view_size: int = key(512, "pixels per side of the placement view", within=between(32, 4096))
    fov_deg: float = key(30.0, "vertical field of view of the placement view (degrees)",
                         within=Interval(0, 170, lo_open=True, hi_open=True))
    w: list = key([0.4, 0.6], "placement camera distance from the surface (m)",
                  pair=between(1e-4, 1e4))
    max_depth_change: float = key(0.02, "largest depth change under the lesion (appendix A's c, m)",
                                  within=above(0))
    dilation: int = key(9, "pixels added around the lesion mask (a_xd)", within=at_least(0))
    attempts: int = key(60, "places tried per lesion before giving up", within=at_least(1))
    enlarge: bool = key(True, "false: a lesion never gets more view pixels than source pixels")
    overlap: str = key("lesion", "what a new dilated lesion must not touch: earlier lesions "
                       "(lesion) or their dilated regions (dilated, the original)", choices=OVERLAPS)
    body_sites: bool = key(True, "procedural conditions go where they are usually seen (a region "
                           "drawn by the preset's sites, assets/morphology.SITES, for the first "
                           "half of the attempts); false: anywhere on the skin by area, the "
                           "paper's")


_WEIGHT = Interval(0, 1e12, hi_open=True)


@dataclass
class BlendConfig:
    """How pasted lesions are blended into the texture (paper section 3.2)."""
    method: str = key("poisson", "poisson (log-albedo, exact, ~0.2 s per lesion), deep (the paper's "
                      "loss; needs VGG16 weights to look right) or paste (keep the pasted texture)",
                      choices=BLEND_METHODS)
    steps: int = key(400, "deep: optimisation steps", within=at_least(0))
    lr: float = key(0.005, "deep: learning rate", within=above(0))
    optimizer: str = key("adam", "deep: optimiser", choices=("adam", "lbfgs"))
    content: float = key(2.0, "deep: content loss weight", within=_WEIGHT)
    style: float = key(1e6, "deep: style loss weight", within=_WEIGHT)
    gradient: float = key(1e5, "deep: Laplacian gradient loss weight", within=_WEIGHT)
    tv: float = key(1e-4, "deep: total variation weight", within=_WEIGHT)
    features: str = key("auto", "deep: CNN features; auto is VGG16 when its weights are found "
                        "locally, else the filter bank", choices=FEATURES)
    vgg_weights: str | None = key(None, "deep: VGG16 weights file (null: look in the usual places)")
    pad: int = key(16, "pixels around the lesion box where the loss is computed", within=at_least(0))
    perturb_deg: float = key(4.0, "deep: camera jitter per step (degrees around the surface point)")
    perturb_w: float = key(0.1, "deep: relative jitter of the camera distance per step")
    threads: int = key(1, "torch threads of the deep blend (its float sums depend on the count: "
                       "a fixed count gives the same bytes for any workers)", within=between(1, 1024))


_LIGHT = between(0, 10)


@dataclass
class ViewsConfig:
    """The annotated views rendered of each body: framing, camera, lights and shading."""
    per_body: int = key(10, "views rendered per body", within=at_least(0))
    size: int = key(512, "pixels per side of a view", within=between(32, 4096))
    fov_deg: float = key(30.0, "vertical field of view (degrees)",
                         within=Interval(0, 170, lo_open=True, hi_open=True))
    supersample: int = key(1, "k x k shading samples per pixel (box filter; also smooths texture "
                           "minification, at k^2 times the shading)", within=between(1, 8))
    multisample: int = key(4, "MSAA samples per pixel: anti-aliased silhouettes, shaded once (0: off; "
                           "the GL may support fewer: llvmpipe 4)", choices=(0, 1, 2, 4, 8, 16))
    w: list = key([0.1, 1.3], "wild views: camera distance from the surface point (m)",
                  pair=between(1e-4, 1e4))
    lesion_bias: float = key(0.7, "probability that a wild view is centred on a lesion",
                             within=between(0, 1))
    min_skin: float = key(0.1, "views showing a smaller share of skin are rejected",
                          within=between(0, 1))
    min_lesion: float = key(0.0, "views showing a smaller share of lesion are rejected",
                            within=between(0, 1))
    ambient: list = key([0.02, 0.12], "room light: ambient intensity (light from the room's walls and "
                        "ceiling; low enough that skin turning away from the lamp falls into "
                        "deep shade, as in clinical photographs)", pair=_LIGHT)
    ambient_ground: list = key([0.25, 0.7], "room light: ambient reaching a surface facing the floor, "
                               "relative to one facing the ceiling (1: even, the paper's)",
                               pair=between(0, 1))
    diffuse: list = key([0.4, 1.0], "room light: diffuse intensity", pair=_LIGHT)
    specular: list = key([0.0, 0.1], "room light: specular intensity", pair=_LIGHT)
    material_specular: list = key([0.0, 0.05], "phong: material specular", pair=_LIGHT)
    shininess: list = key([30.0, 60.0], "phong: material shininess", pair=between(1e-3, 1e4))
    light_position: str = key("room", "room: light_distance from the viewed point, light_angle "
                              "away from the camera's direction, more often above than below; "
                              "near_camera: light_offset from the camera in a random direction (both "
                              "reject views whose light is blocked); paper: DermSynth3D's, "
                              "light_offset per axis away from the point, at the camera when blocked",
                              choices=LIGHT_POSITIONS)
    light_angle: list = key([0.0, 70.0], "room: angle between the light and the camera as seen from "
                            "the viewed point (degrees)", pair=between(0, 90))
    light_distance: list = key([0.4, 2.5], "room: light distance from the viewed point (m)",
                               pair=between(1e-3, 1e3))
    light_offset: list = key([0.0, 0.5], "near_camera, paper: light distance from the camera (m)",
                             pair=between(0, 1e3))
    attempts: int = key(50, "scenes tried per view before it is skipped", within=at_least(1))
    wrap: list = key([0.0, 0.1], "wrap diffuse lighting (skin-like light bleeding past the terminator; "
                     "millimetres of scattering soften a nose's, hardly a limb's; 0: Lambert)",
                     pair=between(0, 1))
    flash: float = key(0.3, "probability of a phone flash at the camera in a wild or regional view",
                       within=between(0, 1))
    shadows: bool = key(True, "soft shadows from the room light (shadow map); the paper has none")
    falloff: bool = key(True, "room light and flash fall off with the inverse square of the "
                        "distance, as sampled at the viewed point; the paper's do not")
    flash_diffuse: list = key([0.3, 1.0], "flash: diffuse intensity", pair=_LIGHT)
    flash_specular: list = key([0.0, 0.1], "flash: specular intensity", pair=_LIGHT)
    flash_corner: list = key([0.25, 1.0], "flash: its beam's intensity toward the frame's corners "
                             "relative to the middle (a phone's LED flash about 0.3-0.6, a "
                             "diffused or ring flash 1: even)", pair=between(0.01, 1))
    flash_kelvin: list = key([5000.0, 6000.0], "flash: its colour temperature (K; a phone's LED "
                             "flash 5,000-6,000), with views.light_kelvin", pair=between(1667, 25000))
    flash_room: list = key([0.05, 1.0], "flash: the room light's intensity when the flash fires, "
                           "relative to its own draw (the camera exposes for the flash: a phone "
                           "in a lit room 1-2 stops under, a clinical macro flash at f/8-16 "
                           "4 or more); a room background is dimmed as much",
                           pair=between(0, 1))
    ambient_tint: float = key(0.5, "tint the ambient light by the background's mean colour (0: none)",
                              within=between(0, 1))
    light_kelvin: list = key([2700.0, 7500.0], "colour temperature of the room light (K, uniform in "
                             "mired: warm lamps to daylight); the camera white-balances for the mix "
                             "of lights at the viewed point, so only mixed light shows colour "
                             "([0, 0]: white lights, the paper's)", pair=between(0, 25000),
                             rule=Rule(lambda p: p == [0, 0] or p[0] >= 1667, "[0, 0] or from 1667"))
    light_mixed: float = key(0.4, "probability that the room's ambient light has a colour temperature "
                             "of its own (a window beside lamps), else the room light's",
                             within=between(0, 1))
    shading: str = key("skin", "skin: linear-light skin reflectance with micro-relief and hair "
                       "(shaders/skin.frag); phong: the paper's", choices=SHADINGS)
    roughness: list = key([0.45, 0.6], "skin: GGX roughness of dry skin", pair=between(0.02, 1))
    oil: list = key([0.1, 0.7], "skin: scales the body's oiliness map", pair=between(0, 1))
    relief: list = key([0.7, 1.3], "skin: scales the micro-relief", pair=between(0, 10))
    detail: bool = key(True, "skin: micro-relief and hair")
    occlusion: bool = key(True, "skin: ambient occlusion baked per body (folds, the armpit, ears "
                          "and between the fingers get less of the room's ambient light; cached "
                          "on disk, ~0.8 s per body the first time)")
    framing: dict = key({"closeup": 0.7, "regional": 0.25, "wild": 0.05},
                        "weights of the view kinds (pipeline/views.py): closeup (a lesion filling "
                        "closeup_fraction of the frame), regional (a body part fills the frame), "
                        "wild (the paper's: a surface point or lesion at distance w)",
                        rule=Rule(_framing_weights, f"a mapping of some of {', '.join(FRAMINGS)} "
                                  "to weights >= 0, not all 0"))
    closeup_fraction: list = key([0.08, 2.0], "close-ups: the lesion's share of the frame, as "
                                 "the frame shows it (a spread group framed until its lesions "
                                 "fill that share); above 1, lesion area / frame area (a large "
                                 "lesion or eruption seen in part, running off the frame)",
                                 pair=between(1e-4, 10))
    closeup_tilt: float = key(25.0, "close-ups: the camera within this angle of the normal (degrees)",
                              within=Interval(0, 90, hi_open=True))
    closeup_w: list = key([0.04, 0.6], "close-ups: camera distance limits (m)",
                          pair=between(1e-4, 1e4))
    closeup_min_width: list = key([0.015, 0.03], "close-ups: the narrowest frame on the skin (m), "
                                  "log-uniform per view: from a clinical camera at its closest "
                                  "(about 1:1 macro, 1.5 cm) to a small lesion shown in context; a "
                                  "lesion too small to fill its share of the frame fills less",
                                  pair=between(1e-5, 10))
    closeup_flash: float = key(0.6, "close-ups: probability of a flash", within=between(0, 1))
    regional_fill: list = key([0.9, 1.8], "regional views: body part width (its extent across its "
                              "main axis) / frame width",
                              pair=between(0.05, 10))
    regional_lesion: float = key(0.8, "regional views: probability of framing the part that holds a "
                                 "lesion, centred near it", within=between(0, 1))


@dataclass
class PhotoConfig:
    """Post-render camera model of a phone camera (glsynth/pipeline/photo.py; docs/photo.md
    explains each range). It changes the RGB image only: labels stay the sharp truth. A
    range [0, 0] switches that effect off; enabled: false switches them all off."""
    enabled: bool = key(True, "apply the camera model")
    aperture: list = key([0.0, 0.0025], "lens aperture diameter (m): phone main cameras ~1.5-2.5 mm",
                         pair=between(0, 1))
    focus_jitter: float = key(0.05, "relative error of the focus distance around the look-at point",
                              within=Interval(0, 1, hi_open=True))
    max_coc: float = key(12.0, "cap on the circle of confusion (px, diameter)",
                         within=Interval(0, 64, lo_open=True))
    motion_blur: list = key([0.0, 1.5], "hand-shake streak length (px)", pair=between(0, 64))
    shot_noise: list = key([0.0001, 0.0015], "variance per unit linear signal (after the phone's "
                           "denoiser)", pair=between(0, 1))
    read_noise: list = key([0.0005, 0.003], "std dev, linear units", pair=between(0, 1))
    white_balance: list = key([-0.15, 0.15], "log2(R gain / B gain) shift (+ warm): about +-600 K "
                              "around 5500 K", pair=between(-2, 2))
    tint: list = key([-0.03, 0.03], "log2 G gain shift", pair=between(-2, 2))
    cast_share: float = key(0.25, "share of images with a strong colour cast (slides and prints "
                            "scanned into clinical collections, tungsten or fluorescent light "
                            "the camera did not correct): their white balance and tint come "
                            "from cast_white_balance and cast_tint", within=between(0, 1))
    cast_white_balance: list = key([-0.6, 0.6], "a cast's log2(R gain / B gain): about +-2,000 K",
                                   pair=between(-2, 2))
    cast_tint: list = key([-0.4, 0.4], "a cast's log2 G gain (green / magenta)", pair=between(-2, 2))
    auto_white_balance: list = key([0.0, 0.3], "the camera's grey-world white balance: how far (in "
                                   "log) it takes the frame's mean colour towards grey (1: all "
                                   "the way; a frame of skin comes out cooler, one of a red "
                                   "plaque casts the skin round it green)", pair=between(0, 1))
    exposure: list = key([-0.3, 0.3], "exposure error (EV, stops)", pair=between(-4, 4))
    vignetting: list = key([0.0, 0.25], "relative light fall-off at the corners", pair=between(0, 1))
    chromatic_aberration: list = key([0.0, 0.6], "R/B shift at the corners (px)", pair=between(0, 16))
    contrast: list = key([0.0, 0.4], "the phone's S tone curve on the sRGB image: (1 - c) x + c "
                         "smoothstep(x), mid-tone slope 1 + c/2", pair=between(0, 1))
    saturation: list = key([0.0, 0.2], "the phone's chroma boost: chroma times 1 + s about each "
                           "pixel's luma", pair=between(0, 1))
    watermark: float = key(0.3, "share of images stamped with a publisher's watermark (initials, a web "
                           "address or a copyright line, as the online atlases that clinical "
                           "collections come from put on their photographs); labels unchanged",
                           within=between(0, 1))
    jpeg_quality: list = key([70, 95], "JPEG quality ([0, 0]: no JPEG)", pair=between(0, 100),
                             rule=Rule(_jpeg_quality, "[0, 0] or integers in [1, 100]"))


@dataclass
class BackgroundsConfig:
    """What surrounds the body in the views: behind it, and at the frame's edge."""
    source: str = key("procedural", "'procedural' or a folder of background images")
    count: int = key(24, "procedural backgrounds to make", within=at_least(1))
    blur: list = key([0.0, 3.0], "Gaussian blur of the background (px)", pair=between(0, 50))
    clinical: float = key(0.6, "share of procedural backgrounds that are clinical backdrops (drapes, "
                          "sheets, couch paper, plain walls, clothing, black cloth; else rooms)", within=between(0, 1))
    edges: float = key(0.25, "share of close-up and regional views with gloved fingers, the patient's "
                       "clothing or a drape reaching in from the frame's edge (assets/occluders.py)",
                       within=between(0, 1))
    hair: float = key(0.0, "share of close-up and regional views of the head (a quarter of the body in "
                      "view, or any of it for long hair) with a lock of the patient's scalp hair over the "
                      "frame's edge, where no other edge is drawn (assets/occluders.py; off by default: "
                      "docs/realism.md)", within=between(0, 1))


@dataclass
class Config:
    """A whole run: its seed, the sections below and the layers it writes."""
    seed: int = key(0, "seed of every random choice (the same seed and config give the same bytes)",
                    within=at_least(0))
    bodies: BodiesConfig = field(default_factory=BodiesConfig)
    lesions: LesionsConfig = field(default_factory=LesionsConfig)
    paste: PasteConfig = field(default_factory=PasteConfig)
    blend: BlendConfig = field(default_factory=BlendConfig)
    views: ViewsConfig = field(default_factory=ViewsConfig)
    backgrounds: BackgroundsConfig = field(default_factory=BackgroundsConfig)
    photo: PhotoConfig = field(default_factory=PhotoConfig)
    outputs: list = key(list(DEFAULT_OUTPUTS), "layers written per view (normals, uv and face_id: "
                        "extra 3D outputs, on request)",
                        rule=Rule(lambda o: bool(o) and all(x in OUTPUTS for x in o),
                                  f"a non-empty subset of {list(OUTPUTS)}"))

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def section_type(f: dataclasses.Field):
    """The dataclass of a section field (``Config.bodies``...), else None."""
    factory = f.default_factory
    return factory if isinstance(factory, type) and dataclasses.is_dataclass(factory) else None


def keys(cls=Config, prefix=""):
    """(dotted name, field) of every key of ``cls``, sections expanded, in declaration
    order; ``field.metadata`` holds its ``doc`` and ``accepts``."""
    for f in dataclasses.fields(cls):
        section = section_type(f)
        if section is not None:
            yield from keys(section, f"{prefix}{f.name}.")
        else:
            yield f"{prefix}{f.name}", f


# ---- loading and validation ------------------------------------------------------------------
def load_config(path=None, overrides=()) -> Config:
    """Read a YAML config (default: none, glsynth's defaults, which configs/default.yaml
    lists), apply ``key.sub=value`` overrides (values parsed as YAML), validate. Keys a
    file leaves out keep their defaults."""
    if path is None:
        path, raw = "default config", {}
    else:
        path, raw = os.fspath(path), _read_yaml(os.fspath(path))
    for item in overrides:
        _apply_override(raw, item)
    return from_dict(raw, source=path)


def _read_yaml(path) -> dict:
    try:
        with open(path, encoding="utf-8") as fh:
            raw = yaml.safe_load(fh) or {}
    except FileNotFoundError:
        raise ConfigError(f"{path}: config file not found") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a folder, not a config file") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the config file ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not UTF-8 text (byte {exc.start}: {exc.reason}); "
                          "save the config as UTF-8") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML ({exc})") from None
    if not isinstance(raw, dict):
        raise ConfigError(f"{path}: top level must be a mapping, got {type(raw).__name__}")
    return raw


def _apply_override(raw: dict, item: str):
    if "=" not in item:
        raise ConfigError(f"override {item!r} must look like key.sub=value")
    key, value = item.split("=", 1)
    node = raw
    parts = key.strip().split(".")
    for p in parts[:-1]:
        node = node.setdefault(p, {})
        if not isinstance(node, dict):
            raise ConfigError(f"override {item!r}: {p!r} is not a section")
    try:
        node[parts[-1]] = yaml.safe_load(value)
    except yaml.YAMLError as exc:
        raise ConfigError(f"override {item!r}: value is not valid YAML ({exc})") from None


def from_dict(raw: dict, source="config") -> Config:
    cfg = _build(Config, copy.deepcopy(raw), "", source)
    validate(cfg, source)
    return cfg


def _build(cls, raw, prefix, source):
    if not isinstance(raw, dict):
        raise ConfigError(f"{source}: {prefix or 'top level'} must be a mapping, got {raw!r}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    kwargs = {}
    for name, value in raw.items():
        dotted = f"{prefix}{name}"
        if name not in fields:
            raise ConfigError(f"{source}: unknown key {dotted!r} (known: {', '.join(sorted(fields))})")
        f = fields[name]
        section = section_type(f)
        if section is not None:
            kwargs[name] = _build(section, value, f"{dotted}.", source)
        else:
            default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
            kwargs[name] = _coerce(value, default, dotted, source)
    return cls(**kwargs)


def _coerce(value, default, name, source) -> Any:
    """``value`` as the type of the key's default (an int is a float where one is due)."""
    def bad(expected):
        return ConfigError(f"{source}: {name} must be {expected}, got {value!r}")
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise bad("true or false")
        return value
    if isinstance(default, int) and not isinstance(default, bool):
        if isinstance(value, bool) or not isinstance(value, int):
            raise bad("an integer")
        return value
    if isinstance(default, float) or (default is None and isinstance(value, float)):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise bad("a number")
        return float(value)
    if isinstance(default, list):
        if not isinstance(value, list):
            raise bad("a list")
        return value
    if isinstance(default, dict):
        if not isinstance(value, dict):
            raise bad("a mapping")
        return dict(value)
    if isinstance(default, str) or default is None:
        if value is not None and not isinstance(value, str):
            raise bad("a string")
        return value
    return value


def _check_finite(value, name, source):
    """NaN or infinity anywhere (a number, or inside a list) is an error naming the key."""
    if isinstance(value, dict):
        for k, v in value.items():
            _check_finite(v, f"{name}.{k}" if name else k, source)
    elif isinstance(value, (list, tuple)):
        if any(isinstance(x, float) and not math.isfinite(x) for x in value):
            raise ConfigError(f"{source}: {name} must hold finite numbers, got {list(value)!r}")
        for i, x in enumerate(value):
            if isinstance(x, (dict, list, tuple)):
                _check_finite(x, f"{name}[{i}]", source)
    elif isinstance(value, float) and not math.isfinite(value):
        raise ConfigError(f"{source}: {name} must be a finite number, got {value!r}")


def _problem(accepts: Accepts, value) -> str | None:
    """What is wrong with ``value`` for a key that ``accepts`` it, or None."""
    if accepts.pair is not None:
        if len(value) != 2 or not all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                      for x in value):
            return "must be a [low, high] pair of numbers"
        if value[0] > value[1]:
            return "must have low <= high"
        if value[0] not in accepts.pair or value[1] not in accepts.pair:
            return f"must lie {accepts.pair}"
    if accepts.within is not None and value not in accepts.within:
        return f"must be {accepts.within}"
    if accepts.choices is not None and value not in accepts.choices:
        return "must be one of " + ", ".join(map(repr, accepts.choices))
    if accepts.rule is not None and not accepts.rule.test(value):
        return f"must be {accepts.rule.describe()}"
    return None


def validate(cfg: Config, source="config"):
    """Raise ConfigError naming the first key whose value its declaration does not accept."""
    _check_finite(cfg.to_dict(), "", source)
    for name, f in keys():
        value = cfg
        for part in name.split("."):
            value = getattr(value, part)
        problem = _problem(f.metadata["accepts"], value)
        if problem is not None:
            raise ConfigError(f"{source}: {name} {problem}, got {value!r}")
