"""Configuration: YAML validated into dataclasses, with ``key.sub=value`` overrides.

Every error names the offending key and value (and the file). Ranges are [lo, hi] lists.
"""
from __future__ import annotations

import copy
import dataclasses
import math
import os
from dataclasses import dataclass, field
from typing import Any

import yaml

from .errors import GlsynthError
from .resources import config_dir


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
LIGHT_POSITIONS = ("near_camera", "paper")


@dataclass
class BodiesConfig:
    source: str = "builtin"           # 'builtin' or a folder of 3DBodyTex scans / meshes
    count: int = 2
    texture_size: int = 2048
    fitzpatrick: list = field(default_factory=lambda: [1, 6])
    poses: list = field(default_factory=lambda: ["a-pose", "arms-down", "slight-turn"])


@dataclass
class LesionsConfig:
    source: str = "procedural"        # 'procedural' or a folder
    layout: str = "fitz17k"           # 'fitz17k' or 'pairs'
    per_body: int = 2
    colour_constancy: bool = True     # Shades of Gray on real lesion images (paper)
    size: list = field(default_factory=lambda: [0.15, 0.4])  # lesion extent / view width
    min_size: int = 16                # lesion images with a shorter side (px) are rejected
    max_mask_fraction: float = 0.95   # masks covering more of their image are rejected
    kinds: list = field(default_factory=list)  # procedural presets to use ([]: all)
    resolution: int = 512             # grid cells per side of a procedural condition
    decal_size: int = 1024            # pixels per side of each lesion's decal (0: none)


@dataclass
class PasteConfig:
    view_size: int = 512
    fov_deg: float = 30.0
    w: list = field(default_factory=lambda: [0.4, 0.6])
    max_depth_change: float = 0.02   # appendix A threshold c
    dilation: int = 9                 # pixels added around the lesion mask (a_xd)
    attempts: int = 60                # locations tried per lesion before giving up
    enlarge: bool = True              # false: a lesion never gets more view pixels than source pixels
    overlap: str = "lesion"           # a new dilated lesion must not touch earlier lesions
                                      # ('lesion') or their dilated regions ('dilated', the original)


@dataclass
class BlendConfig:
    method: str = "deep"              # deep | poisson | paste
    steps: int = 400
    lr: float = 0.005
    optimizer: str = "adam"           # adam | lbfgs
    content: float = 2.0
    style: float = 1e6
    gradient: float = 1e5
    tv: float = 1e-4
    features: str = "auto"            # auto (VGG16 if weights found, else filters) | vgg16 | filters
    vgg_weights: str | None = None
    pad: int = 16                     # pixels around the lesion box where the loss is computed
    perturb_deg: float = 4.0          # camera jitter per step (degrees around the surface point)
    perturb_w: float = 0.1            # relative jitter of w per step
    threads: int = 1                  # torch threads of the deep blend (its float sums depend on
                                      # the count: a fixed count gives the same bytes for any workers)


@dataclass
class ViewsConfig:
    per_body: int = 8
    size: int = 512
    fov_deg: float = 30.0
    supersample: int = 1              # k x k shading samples per pixel (box filter)
    multisample: int = 4              # MSAA samples per pixel: anti-aliased silhouettes, shaded once
    w: list = field(default_factory=lambda: [0.1, 1.3])
    lesion_bias: float = 0.7          # probability that a view is centred on a lesion
    min_skin: float = 0.1
    min_lesion: float = 0.0
    ambient: list = field(default_factory=lambda: [0.2, 0.99])
    diffuse: list = field(default_factory=lambda: [0.2, 0.99])
    specular: list = field(default_factory=lambda: [0.0, 0.1])
    material_specular: list = field(default_factory=lambda: [0.0, 0.05])
    shininess: list = field(default_factory=lambda: [30.0, 60.0])
    light_offset: list = field(default_factory=lambda: [0.0, 0.5])  # light distance from camera (m)
    # near_camera: light_offset away in a random direction, views with a blocked light
    # rejected; paper: DermSynth3D's, light_offset per axis away from the point, at the
    # camera when blocked
    light_position: str = "near_camera"
    attempts: int = 50
    # Richer lighting (defaults off: the paper's single light, Lambert diffuse).
    wrap: list = field(default_factory=lambda: [0.0, 0.0])       # material wrap lighting
    flash: float = 0.0                # probability of a flash light at the camera
    shadows: bool = False             # soft shadows from the main (room) light
    flash_diffuse: list = field(default_factory=lambda: [0.2, 0.6])
    flash_specular: list = field(default_factory=lambda: [0.0, 0.1])
    ambient_tint: float = 0.0         # 0..1: tint the ambient light by the background's mean colour
    # Shading: "phong" (the paper's) or "skin" (linear-light skin reflectance with
    # micro-relief and hair, shaders/skin.frag); skin material ranges:
    shading: str = "phong"
    roughness: list = field(default_factory=lambda: [0.3, 0.5])   # GGX roughness of dry skin
    oil: list = field(default_factory=lambda: [0.2, 1.0])         # scales the body's oiliness map
    relief: list = field(default_factory=lambda: [0.7, 1.3])      # scales the micro-relief
    detail: bool = True               # micro-relief and hair (skin shading only)
    # Framing: weights of the view kinds (views.py): "wild" (the paper's: a surface point
    # or lesion at w), "closeup" (lesion-centred, near-perpendicular, the lesion filling
    # closeup_fraction of the frame), "regional" (a body part fills the frame).
    framing: dict = field(default_factory=lambda: {"wild": 1.0})
    closeup_fraction: list = field(default_factory=lambda: [0.05, 0.7])  # lesion area / frame area
    closeup_tilt: float = 25.0        # degrees: the camera within this angle of the normal
    closeup_w: list = field(default_factory=lambda: [0.04, 0.6])   # close-up distance limits
    closeup_flash: float = 0.6        # probability of a flash in a close-up
    regional_fill: list = field(default_factory=lambda: [0.6, 1.2])  # part extent / frame width


@dataclass
class PhotoConfig:
    """Post-render camera model (glsynth/pipeline/photo.py). Every range [0, 0] (the
    default) switches that effect off; ``enabled: false`` switches them all off."""
    enabled: bool = False
    aperture: list = field(default_factory=lambda: [0.0, 0.0])    # lens aperture diameter (scene units)
    focus_jitter: float = 0.05        # relative error of the focus distance around the look-at point
    max_coc: float = 12.0             # cap on the circle of confusion (px, diameter)
    motion_blur: list = field(default_factory=lambda: [0.0, 0.0])  # shake kernel length (px)
    shot_noise: list = field(default_factory=lambda: [0.0, 0.0])   # variance per unit linear signal
    read_noise: list = field(default_factory=lambda: [0.0, 0.0])   # std dev, linear units
    white_balance: list = field(default_factory=lambda: [0.0, 0.0])  # log2 red/blue gain shift (+ warm)
    tint: list = field(default_factory=lambda: [0.0, 0.0])         # log2 green gain shift
    exposure: list = field(default_factory=lambda: [0.0, 0.0])     # EV (stops)
    vignetting: list = field(default_factory=lambda: [0.0, 0.0])   # light fall-off at the corners
    chromatic_aberration: list = field(default_factory=lambda: [0.0, 0.0])  # R/B shift at the corner (px)
    jpeg_quality: list = field(default_factory=lambda: [0, 0])     # [0, 0] = no JPEG; else 1..100


@dataclass
class BackgroundsConfig:
    source: str = "procedural"
    count: int = 16                   # procedural backgrounds to make
    blur: list = field(default_factory=lambda: [0.0, 3.0])
    clinical: float = 0.0             # share of procedural backgrounds that are clinical backdrops


@dataclass
class Config:
    seed: int = 0
    bodies: BodiesConfig = field(default_factory=BodiesConfig)
    lesions: LesionsConfig = field(default_factory=LesionsConfig)
    paste: PasteConfig = field(default_factory=PasteConfig)
    blend: BlendConfig = field(default_factory=BlendConfig)
    views: ViewsConfig = field(default_factory=ViewsConfig)
    backgrounds: BackgroundsConfig = field(default_factory=BackgroundsConfig)
    photo: PhotoConfig = field(default_factory=PhotoConfig)
    outputs: list = field(default_factory=lambda: list(DEFAULT_OUTPUTS))

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def load_config(path=None, overrides=()) -> Config:
    """Read a YAML config (default: the embedded configs/default.yaml), apply
    ``key.sub=value`` overrides (values parsed as YAML), validate."""
    path = os.fspath(path) if path is not None else str(config_dir() / "default.yaml")
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
    for item in overrides:
        _apply_override(raw, item)
    return from_dict(raw, source=path)


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
    for key, value in raw.items():
        name = f"{prefix}{key}"
        if key not in fields:
            raise ConfigError(f"{source}: unknown key {name!r} (known: {', '.join(sorted(fields))})")
        default = fields[key].default_factory() if fields[key].default_factory is not dataclasses.MISSING \
            else fields[key].default
        if dataclasses.is_dataclass(default):
            kwargs[key] = _build(type(default), value, f"{name}.", source)
        else:
            kwargs[key] = _coerce(value, default, name, source)
    return cls(**kwargs)


def _coerce(value, default, name, source) -> Any:
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


def _range(cfg_value, name, source, lo=None, hi=None, integer=False):
    v = cfg_value
    if len(v) != 2 or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
        raise ConfigError(f"{source}: {name} must be a [low, high] pair of numbers, got {v!r}")
    if v[0] > v[1]:
        raise ConfigError(f"{source}: {name} low > high in {v!r}")
    if (lo is not None and v[0] < lo) or (hi is not None and v[1] > hi):
        raise ConfigError(f"{source}: {name} must lie in [{lo}, {hi}], got {v!r}")


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


def validate(cfg: Config, source="config"):
    def need(cond, name, value, what):
        if not cond:
            raise ConfigError(f"{source}: {name} {what}, got {value!r}")
    _check_finite(cfg.to_dict(), "", source)
    need(cfg.seed >= 0, "seed", cfg.seed, "must be >= 0")
    b = cfg.bodies
    need(b.count >= 1, "bodies.count", b.count, "must be >= 1")
    need(64 <= b.texture_size <= 8192, "bodies.texture_size", b.texture_size, "must be in [64, 8192]")
    _range(b.fitzpatrick, "bodies.fitzpatrick", source, 1, 6)
    need(bool(b.poses), "bodies.poses", b.poses, "must list at least one pose")
    le = cfg.lesions
    need(le.layout in ("fitz17k", "pairs"), "lesions.layout", le.layout, "must be 'fitz17k' or 'pairs'")
    need(le.per_body >= 0, "lesions.per_body", le.per_body, "must be >= 0")
    from .assets.morphology import PRESETS
    bad_kinds = [k for k in le.kinds if k not in PRESETS]
    need(not bad_kinds, "lesions.kinds", le.kinds, f"must name presets from {sorted(PRESETS)}")
    need(64 <= le.resolution <= 4096, "lesions.resolution", le.resolution, "must be in [64, 4096]")
    need(le.decal_size == 0 or 64 <= le.decal_size <= 4096, "lesions.decal_size", le.decal_size,
         "must be 0 (no decals) or in [64, 4096]")
    _range(le.size, "lesions.size", source, 0.01, 1.5)
    need(1 <= le.min_size <= 4096, "lesions.min_size", le.min_size, "must be in [1, 4096] pixels")
    need(0 < le.max_mask_fraction <= 1, "lesions.max_mask_fraction", le.max_mask_fraction,
         "must be in (0, 1]")
    p = cfg.paste
    need(32 <= p.view_size <= 4096, "paste.view_size", p.view_size, "must be in [32, 4096]")
    need(0 < p.fov_deg < 170, "paste.fov_deg", p.fov_deg, "must be in (0, 170)")
    _range(p.w, "paste.w", source, 1e-4, 1e4)
    need(p.max_depth_change > 0, "paste.max_depth_change", p.max_depth_change, "must be > 0")
    need(p.dilation >= 0, "paste.dilation", p.dilation, "must be >= 0")
    need(p.attempts >= 1, "paste.attempts", p.attempts, "must be >= 1")
    need(p.overlap in OVERLAPS, "paste.overlap", p.overlap, f"must be one of {OVERLAPS}")
    bl = cfg.blend
    need(bl.method in BLEND_METHODS, "blend.method", bl.method, f"must be one of {BLEND_METHODS}")
    need(bl.steps >= 0, "blend.steps", bl.steps, "must be >= 0")
    need(bl.lr > 0, "blend.lr", bl.lr, "must be > 0")
    need(bl.optimizer in ("adam", "lbfgs"), "blend.optimizer", bl.optimizer, "must be 'adam' or 'lbfgs'")
    for k in ("content", "style", "gradient", "tv"):
        v = getattr(bl, k)
        need(0 <= v < 1e12, f"blend.{k}", v, "must be in [0, 1e12)")
    need(bl.features in FEATURES, "blend.features", bl.features, f"must be one of {FEATURES}")
    need(bl.pad >= 0, "blend.pad", bl.pad, "must be >= 0")
    need(1 <= bl.threads <= 1024, "blend.threads", bl.threads, "must be in [1, 1024]")
    v = cfg.views
    need(v.per_body >= 0, "views.per_body", v.per_body, "must be >= 0")
    need(32 <= v.size <= 4096, "views.size", v.size, "must be in [32, 4096]")
    need(1 <= v.supersample <= 8, "views.supersample", v.supersample, "must be in [1, 8]")
    need(v.multisample in (0, 1, 2, 4, 8, 16), "views.multisample", v.multisample,
         "must be 0 (off), 1, 2, 4, 8 or 16 (the GL may support fewer: llvmpipe 4)")
    need(0 < v.fov_deg < 170, "views.fov_deg", v.fov_deg, "must be in (0, 170)")
    _range(v.w, "views.w", source, 1e-4, 1e4)
    need(0 <= v.lesion_bias <= 1, "views.lesion_bias", v.lesion_bias, "must be in [0, 1]")
    need(0 <= v.min_skin <= 1, "views.min_skin", v.min_skin, "must be in [0, 1]")
    need(0 <= v.min_lesion <= 1, "views.min_lesion", v.min_lesion, "must be in [0, 1]")
    for k in ("ambient", "diffuse", "specular", "material_specular"):
        _range(getattr(v, k), f"views.{k}", source, 0, 10)
    _range(v.shininess, "views.shininess", source, 1e-3, 1e4)
    _range(v.light_offset, "views.light_offset", source, 0, 1e3)
    need(v.light_position in LIGHT_POSITIONS, "views.light_position", v.light_position,
         f"must be one of {LIGHT_POSITIONS}")
    need(v.attempts >= 1, "views.attempts", v.attempts, "must be >= 1")
    _range(v.wrap, "views.wrap", source, 0, 1)
    need(0 <= v.flash <= 1, "views.flash", v.flash, "must be in [0, 1]")
    _range(v.flash_diffuse, "views.flash_diffuse", source, 0, 10)
    _range(v.flash_specular, "views.flash_specular", source, 0, 10)
    need(0 <= v.ambient_tint <= 1, "views.ambient_tint", v.ambient_tint, "must be in [0, 1]")
    need(v.shading in SHADINGS, "views.shading", v.shading, f"must be one of {SHADINGS}")
    _range(v.roughness, "views.roughness", source, 0.02, 1)
    _range(v.oil, "views.oil", source, 0, 1)
    _range(v.relief, "views.relief", source, 0, 10)
    bad_kinds = [k for k in v.framing if k not in FRAMINGS]
    need(not bad_kinds and all(isinstance(x, (int, float)) and not isinstance(x, bool) and x >= 0
                               for x in v.framing.values()) and sum(v.framing.values()) > 0,
         "views.framing", v.framing, f"must map some of {FRAMINGS} to weights >= 0 (not all 0)")
    _range(v.closeup_fraction, "views.closeup_fraction", source, 1e-4, 1)
    need(0 <= v.closeup_tilt < 90, "views.closeup_tilt", v.closeup_tilt, "must be in [0, 90)")
    _range(v.closeup_w, "views.closeup_w", source, 1e-4, 1e4)
    need(0 <= v.closeup_flash <= 1, "views.closeup_flash", v.closeup_flash, "must be in [0, 1]")
    _range(v.regional_fill, "views.regional_fill", source, 0.05, 10)
    ph = cfg.photo
    _range(ph.aperture, "photo.aperture", source, 0, 1)
    need(0 <= ph.focus_jitter < 1, "photo.focus_jitter", ph.focus_jitter, "must be in [0, 1)")
    need(0 < ph.max_coc <= 64, "photo.max_coc", ph.max_coc, "must be in (0, 64]")
    _range(ph.motion_blur, "photo.motion_blur", source, 0, 64)
    _range(ph.shot_noise, "photo.shot_noise", source, 0, 1)
    _range(ph.read_noise, "photo.read_noise", source, 0, 1)
    _range(ph.white_balance, "photo.white_balance", source, -2, 2)
    _range(ph.tint, "photo.tint", source, -2, 2)
    _range(ph.exposure, "photo.exposure", source, -4, 4)
    _range(ph.vignetting, "photo.vignetting", source, 0, 1)
    _range(ph.chromatic_aberration, "photo.chromatic_aberration", source, 0, 16)
    q = ph.jpeg_quality
    _range(q, "photo.jpeg_quality", source, 0, 100)
    need(all(float(x).is_integer() for x in q) and (q == [0, 0] or q[0] >= 1), "photo.jpeg_quality", q,
         "must be [0, 0] (no JPEG) or integers in [1, 100]")
    _range(cfg.backgrounds.blur, "backgrounds.blur", source, 0, 50)
    need(cfg.backgrounds.count >= 1, "backgrounds.count", cfg.backgrounds.count, "must be >= 1")
    need(0 <= cfg.backgrounds.clinical <= 1, "backgrounds.clinical", cfg.backgrounds.clinical,
         "must be in [0, 1]")
    bad = [o for o in cfg.outputs if o not in OUTPUTS]
    need(not bad and cfg.outputs, "outputs", cfg.outputs, f"must be a non-empty subset of {list(OUTPUTS)}")
