"""Point lights and materials (Phong, skin) shared by the GL shaders and the torch path."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def _rgb(value, what):
    a = np.broadcast_to(np.asarray(value, dtype=np.float64), (3,)).copy()
    if not np.isfinite(a).all() or (a < 0).any():
        raise ValueError(f"{what} must be finite and >= 0, got {np.asarray(value).tolist()}")
    return tuple(a.tolist())


@dataclass(frozen=True)
class PointLight:
    """A point light: position (scene units) and RGB ambient/diffuse/specular colours
    (a scalar means grey). The paper's blending light: ambient 0.5, diffuse 0.5,
    specular 0.025 at the camera.

    ``falloff_distance`` 0 (the paper's) lights every point alike whatever its distance;
    above 0 the direct terms (not ambient) are as given at that distance and fall off
    with the inverse square of the distance (``falloff_gain``), so a flash lights a
    limb's near side more than the sides turning away from it.

    ``beam_exponent`` 0 (the paper's) sends light alike in every direction; above 0 the
    direct terms are also scaled by ``cos(angle off beam_axis)^beam_exponent``
    (``beam_gain``), the beam of a phone's LED flash, brighter in the middle of the
    frame than at its corners.

    ``ambient_ground`` 1 (the paper's) is ambient light alike from every direction;
    below 1 it is a room's: a surface facing down (-Y, the floor) gets that share of
    what one facing up (+Y, the ceiling) gets, in between by its normal, keeping
    ``ambient`` as the mean over all directions (``ambient_gain``)."""

    position: tuple
    ambient: tuple = (0.5, 0.5, 0.5)
    diffuse: tuple = (0.5, 0.5, 0.5)
    specular: tuple = (0.025, 0.025, 0.025)
    falloff_distance: float = 0.0
    ambient_ground: float = 1.0
    beam_axis: tuple = (0.0, 0.0, -1.0)
    beam_exponent: float = 0.0

    def __post_init__(self):
        p = np.asarray(self.position, dtype=np.float64).reshape(3)
        if not np.isfinite(p).all():
            raise ValueError(f"light position must be finite, got {p.tolist()}")
        object.__setattr__(self, "position", tuple(p.tolist()))
        for name in ("ambient", "diffuse", "specular"):
            object.__setattr__(self, name, _rgb(getattr(self, name), f"light {name}"))
        d = float(self.falloff_distance)
        if not (np.isfinite(d) and d >= 0):
            raise ValueError(f"light falloff_distance must be finite and >= 0, got {self.falloff_distance}")
        object.__setattr__(self, "falloff_distance", d)
        g = float(self.ambient_ground)
        if not (np.isfinite(g) and 0 <= g <= 1):
            raise ValueError(f"light ambient_ground must be in [0, 1], got {self.ambient_ground}")
        object.__setattr__(self, "ambient_ground", g)
        k = float(self.beam_exponent)
        if not (np.isfinite(k) and k >= 0):
            raise ValueError(f"light beam_exponent must be finite and >= 0, got {self.beam_exponent}")
        object.__setattr__(self, "beam_exponent", k)
        axis = np.asarray(self.beam_axis, dtype=np.float64).reshape(3)
        norm = np.linalg.norm(axis)
        if not (np.isfinite(axis).all() and norm > 0):
            raise ValueError(f"light beam_axis must be a finite non-zero vector, got {axis.tolist()}")
        object.__setattr__(self, "beam_axis", tuple((axis / norm).tolist()))

    @property
    def beam(self):
        """(axis x, y, z, exponent), as the shaders take it."""
        return self.beam_axis + (self.beam_exponent,)

    def to_dict(self):
        out = {"position": list(self.position), "ambient": list(self.ambient),
               "diffuse": list(self.diffuse), "specular": list(self.specular)}
        if self.falloff_distance > 0:
            out["falloff_distance"] = self.falloff_distance
        if self.ambient_ground < 1:
            out["ambient_ground"] = self.ambient_ground
        if self.beam_exponent > 0:
            out.update(beam_axis=list(self.beam_axis), beam_exponent=self.beam_exponent)
        return out


# Inverse-square gain of a light, capped where a surface comes within a quarter of the
# falloff distance (a point almost at the lamp would otherwise reach infinity); the
# renderer passes it to the shaders (shaders/light.glsl).
FALLOFF_NEAREST = 0.25


def ambient_gain(up, ground):
    """The ambient share of a surface whose normal has ``up`` (its +Y component, -1..1)
    under a light with ``ambient_ground`` ``ground``: from 2 g / (1 + g) facing down to
    2 / (1 + g) facing up, mean 1 over all directions; 1 when ground is 1."""
    if ground >= 1:
        return 1.0
    return (ground + (1 - ground) * (0.5 + 0.5 * up)) * (2 / (1 + ground))


def falloff_gain(distance, falloff_distance):
    """(falloff_distance / distance)^2, the distance clipped below at FALLOFF_NEAREST
    times falloff_distance; 1 when falloff_distance is 0. ``distance``: a numpy array
    or torch tensor."""
    if falloff_distance <= 0:
        return 1.0
    return (falloff_distance / distance.clip(min=FALLOFF_NEAREST * falloff_distance)) ** 2


def beam_gain(to_light, light):
    """``cos(angle between the light's beam_axis and the ray from the light)`` raised to
    its ``beam_exponent`` (a cosine below 1e-6 counts as 1e-6); 1 when the exponent is 0.
    ``to_light``: (..., 3) torch tensor from the surface to the light; returns (..., 1)."""
    if light.beam_exponent <= 0:
        return 1.0
    axis = to_light.new_tensor(light.beam_axis)
    cos = -(to_light * axis).sum(-1, keepdim=True) / to_light.norm(dim=-1, keepdim=True).clamp(min=1e-20)
    return cos.clamp(min=1e-6) ** light.beam_exponent


def direct_gain(to_light, light):
    """The share of a point light's direct intensity that reaches a surface point:
    ``falloff_gain`` times ``beam_gain``. ``to_light``: (..., 3) torch tensor from the
    surface to the light; returns (..., 1) or the float 1."""
    return falloff_gain(to_light.norm(dim=-1, keepdim=True), light.falloff_distance) \
        * beam_gain(to_light, light)


def beam_exponent_for(corner_ratio, corner_angle_deg):
    """The beam exponent that lights a direction ``corner_angle_deg`` off the axis with
    ``corner_ratio`` (0-1] of the axis's intensity (a flash's fall-off to the frame's
    corners): ln(ratio) / ln(cos(angle))."""
    if not 0 < corner_ratio <= 1:
        raise ValueError(f"beam corner ratio must be in (0, 1], got {corner_ratio}")
    if not 0 < corner_angle_deg < 90:
        raise ValueError(f"beam corner angle must be in (0, 90) degrees, got {corner_angle_deg}")
    return float(np.log(corner_ratio) / np.log(np.cos(np.radians(corner_angle_deg))))


WHITE_KELVIN = 6504.0   # the colour temperature whose light comes out grey (sRGB's D65)


def planckian_xy(kelvin):
    """CIE 1931 (x, y) of a black body at ``kelvin`` (1667-25000 K), by the cubic fits of
    Kim et al. (2002) to the Planckian locus."""
    t = float(kelvin)
    if not 1667 <= t <= 25000:
        raise ValueError(f"colour temperature must be in [1667, 25000] K, got {kelvin}")
    if t <= 4000:
        x = -0.2661239e9 / t**3 - 0.2343589e6 / t**2 + 0.8776956e3 / t + 0.179910
    else:
        x = -3.0258469e9 / t**3 + 2.1070379e6 / t**2 + 0.2226347e3 / t + 0.240390
    if t <= 2222:
        y = -1.1063814 * x**3 - 1.34811020 * x**2 + 2.18555832 * x - 0.20219683
    elif t <= 4000:
        y = -0.9549476 * x**3 - 1.37418593 * x**2 + 2.09137015 * x - 0.16748867
    else:
        y = 3.0817580 * x**3 - 5.87338670 * x**2 + 3.75112997 * x - 0.37001483
    return x, y


def light_colour(kelvin):
    """Linear-sRGB colour of a black-body light at ``kelvin`` as a camera balanced for
    WHITE_KELVIN records it, scaled to a luminance (Rec. 709 Y) of 1: warm below,
    bluish above, (1, 1, 1) at WHITE_KELVIN (below about 1,900 K, outside sRGB's gamut,
    blue is clipped at 0)."""
    from .assets.colour import LINEAR_RGB_TO_XYZ, XYZ_TO_LINEAR_RGB   # (the package imports lighting)

    def rgb(t):
        x, y = planckian_xy(t)
        return XYZ_TO_LINEAR_RGB @ np.array([x / y, 1.0, (1 - x - y) / y])
    c = np.maximum(rgb(kelvin) / rgb(WHITE_KELVIN), 0.0)
    return c / (LINEAR_RGB_TO_XYZ[1] @ c)


MODELS = ("phong", "skin")


@dataclass(frozen=True)
class Material:
    """A surface's reflectance.

    ``model`` "phong" (the paper's): specular colour and shininess exponent (paper:
    0.025, 50), and ``wrap`` for skin-like wrap lighting: the diffuse factor is
    ``max((n.l + wrap) / (1 + wrap), 0)`` (0 = plain Lambert, the paper's shading;
    about 0.2-0.5 imitates the light that subsurface scattering carries past the
    terminator). The specular term stays gated by ``n.l > 0``.

    ``model`` "skin" (shaders/skin.frag, glsynth.diff): in linear light, wrap diffuse
    that is wider and softer in red than in blue, a GGX specular lobe of ``roughness``
    with Fresnel, sharpened and raised by sebum (``oil`` 0..1 scales the body's
    oiliness map); each light's ``diffuse`` colour is its intensity for both terms
    (its ``specular`` and the material's ``specular``/``shininess`` are Phong's). With
    ``detail``, the body's micro-relief (scaled by ``relief``) and hair, when the mesh
    carries a SkinSurface."""

    specular: tuple = (0.025, 0.025, 0.025)
    shininess: float = 50.0
    wrap: float = 0.0
    model: str = "phong"
    roughness: float = 0.4
    oil: float = 0.5
    relief: float = 1.0
    detail: bool = True

    def __post_init__(self):
        object.__setattr__(self, "specular", _rgb(self.specular, "material specular"))
        if not (np.isfinite(self.shininess) and self.shininess > 0):
            raise ValueError(f"material shininess must be > 0, got {self.shininess}")
        object.__setattr__(self, "shininess", float(self.shininess))
        if not (np.isfinite(self.wrap) and 0 <= self.wrap <= 1):
            raise ValueError(f"material wrap must be in [0, 1], got {self.wrap}")
        object.__setattr__(self, "wrap", float(self.wrap))
        if self.model not in MODELS:
            raise ValueError(f"material model must be one of {MODELS}, got {self.model!r}")
        for name, lo, hi in (("roughness", 0.02, 1.0), ("oil", 0.0, 1.0), ("relief", 0.0, 10.0)):
            value = getattr(self, name)
            if not (np.isfinite(value) and lo <= value <= hi):
                raise ValueError(f"material {name} must be in [{lo}, {hi}], got {value}")
            object.__setattr__(self, name, float(value))
        object.__setattr__(self, "detail", bool(self.detail))

    def to_dict(self):
        out = {"specular": list(self.specular), "shininess": self.shininess, "wrap": self.wrap,
               "model": self.model}
        if self.model == "skin":
            out.update(roughness=self.roughness, oil=self.oil, relief=self.relief, detail=self.detail)
        return out


MAX_LIGHTS = 8


def check_lights(lights):
    lights = list(lights)
    if not lights:
        raise ValueError("shading needs at least one light")
    if len(lights) > MAX_LIGHTS:
        raise ValueError(f"at most {MAX_LIGHTS} lights are supported, got {len(lights)}")
    for l in lights:
        if not isinstance(l, PointLight):
            raise TypeError(f"lights must be PointLight, got {type(l).__name__}")
    return lights
