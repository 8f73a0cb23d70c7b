"""Generate annotated 2D views of a blended body (paper section 3.3).

Cameras sit on random surface points (optionally lesions) at w in the configured range;
lights and material are sampled in the paper's ranges; cameras inside the mesh and
lights the mesh blocks are rejected by looking down the ray with the renderer itself;
views with too little skin (or lesion) are rejected. Each accepted view yields the
layers below; ``render_view`` renders only the passes the requested outputs need.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass, replace

import cv2
import numpy as np

from ..assets.backgrounds import NEAR_BACKDROPS
from ..assets.occluders import Occluder, sample_hair, sample_occluder
from ..camera import Camera
from ..dataformat import SEMANTIC_BACKGROUND, SEMANTIC_LESION, SEMANTIC_NONSKIN, SEMANTIC_SKIN
from ..errors import GlsynthError
from ..lighting import Material, PointLight, ambient_gain, beam_exponent_for, light_colour
from .photo import SRGB_TO_LINEAR, linear_to_srgb8, srgb_to_linear


@dataclass
class ViewScene:
    camera: Camera
    light: PointLight        # the room light (near the camera, random direction)
    material: Material
    centre: str              # 'lesion k' or 'surface'
    flash: PointLight | None = None   # optional flash at the camera
    # the surface point the camera looks at: when set, render_view rejects the view
    # unless it is the first surface on the central ray (camera outside, point not hidden)
    point: np.ndarray | None = None
    framing: str = "wild"    # views.framing kind: wild, closeup or regional
    # the room light's share at the camera's exposure (below 1 when the camera exposes
    # for its flash): the background photograph, lit by the room, is dimmed by it too
    room_exposure: float = 1.0
    # colour temperatures (K) of the room light, its ambient and the flash, when drawn
    # (views.light_kelvin), and the camera's white-balance gains for their mix
    kelvin: dict | None = None
    white_balance: tuple = (1.0, 1.0, 1.0)

    @property
    def lights(self) -> list:
        return [self.light] + ([self.flash] if self.flash is not None else [])


class Rejection(enum.Enum):
    """Why a sampled view is not used; the values name the counts of the run's
    manifest (``rejected_views``)."""
    ZERO_NORMAL = "zero normal"
    LIGHT_BLOCKED = "light blocked by the body"
    POINT_HIDDEN = "camera inside the mesh or the point is hidden"
    TOO_LITTLE_SKIN = "skin"        # views.min_skin
    TOO_LITTLE_LESION = "lesion"    # views.min_lesion


class ViewRejected(GlsynthError):
    """A sampled view is unusable; ``reason`` is a :class:`Rejection`, ``detail`` (in the
    message) the numbers behind it."""

    def __init__(self, reason: Rejection, detail: str = ""):
        super().__init__(f"{reason.value}: {detail}" if detail else reason.value)
        self.reason, self.detail = reason, detail


@dataclass
class LesionSite:
    """Where a lesion lies on the body: its texels' surface points and unit normals,
    and its surface area (scene units squared)."""
    points: np.ndarray
    normals: np.ndarray
    area: float


def choose_framing(rng, v, has_lesions: bool) -> str:
    """One of views.framing's kinds by weight (close-ups need a lesion). A config with
    only "wild" draws no random number, so the paper's scenes stay as they were."""
    weights = {k: float(x) for k, x in v.framing.items() if x > 0 and (k != "closeup" or has_lesions)}
    if not weights:
        return "wild"
    if list(weights) == ["wild"]:
        return "wild"
    kinds = list(weights)
    p = np.array([weights[k] for k in kinds])
    return kinds[int(rng.choice(len(kinds), p=p / p.sum()))]


def log_uniform(rng, bounds) -> float:
    """A log-uniform draw in [low, high]; low itself, with no draw, when they are equal."""
    lo, hi = bounds
    return float(lo) if lo == hi else float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def _tilted(normal, rng, max_deg):
    """``normal`` turned by up to ``max_deg`` (uniform in angle) about a random axis in the
    tangent plane."""
    n = normal / np.linalg.norm(normal)
    axis = np.cross(n, rng.normal(size=3))
    if np.linalg.norm(axis) < 1e-9:
        return n
    axis /= np.linalg.norm(axis)
    a = np.radians(rng.uniform(0, max_deg))
    return n * np.cos(a) + np.cross(axis, n) * np.sin(a)


def _wild_camera(mesh, lesion_sites, rng, v):
    """The paper's view: a surface point (a lesion's with probability views.lesion_bias)
    seen along its normal from w in views.w."""
    if lesion_sites and rng.random() < v.lesion_bias:
        k = int(rng.integers(len(lesion_sites)))
        site = lesion_sites[k]
        i = int(rng.integers(len(site.points)))
        point, normal, centre = site.points[i], site.normals[i], f"lesion {k + 1}"
    else:
        p = mesh.face_areas / mesh.face_areas.sum()
        f = rng.choice(len(p), p=p)
        bary = rng.dirichlet((1.0, 1.0, 1.0))
        point = bary @ mesh.vertices[mesh.faces[f]]
        normal = bary @ mesh.vertex_normals[mesh.faces[f]]
        centre = "surface"
    return point, normal, normal, rng.uniform(*v.w), centre, v.fov_deg


def _closeup_camera(lesion_sites, rng, v):
    """A clinical close-up: a lesion filling a share of the frame (log-uniform in
    views.closeup_fraction), seen within views.closeup_tilt of its normal, its centre off
    the image centre by up to a fifth of the frame. Below 1 the share is what the frame
    shows of the lesion (``frame_share``): a group of papules or plaques spread wider than
    the frame fills the share asked for, not the share its whole area would fill. Above 1
    the frame is that many times smaller than the lesion's area (part of a large plaque
    or eruption, running off the frame). The frame is never narrower than a log-uniform
    draw in views.closeup_min_width, from a 1:1 macro shot to a small lesion shown with
    skin round it (which then fills less of the frame); a frame narrower than
    views.fov_deg covers from the nearest distance (views.closeup_w) is had by narrowing
    the field of view, as a phone's telephoto lens or a crop does. Returns (point,
    normal, direction, w, centre, fov_deg)."""
    k = int(rng.integers(len(lesion_sites)))
    site = lesion_sites[k]
    frac = log_uniform(rng, v.closeup_fraction)
    min_width = log_uniform(rng, v.closeup_min_width)
    width = max(np.sqrt(site.area / frac), min_width)   # on the surface, by the lesion's area
    aim = site.points.mean(0) + rng.uniform(-0.2, 0.2, 3) * width
    i = int(np.argmin(np.sum((site.points - aim) ** 2, axis=1)))
    point, normal = site.points[i], site.normals[i]
    direction = _tilted(normal, rng, v.closeup_tilt)
    if frac < 1:
        width = _width_for_share(site, point, direction, frac, min_width, v)
    w, fov = _closeup_lens(width, v)
    return point, normal, direction, w, f"lesion {k + 1}", fov


def _closeup_lens(width, v):
    """(w, fov_deg) of a close-up framing ``width`` of skin: views.fov_deg from w in
    views.closeup_w, the field of view narrowed below the nearest distance."""
    w_wanted = width / (2 * np.tan(np.radians(v.fov_deg) / 2))
    w = float(np.clip(w_wanted, *v.closeup_w))
    fov = v.fov_deg
    if w_wanted < v.closeup_w[0]:
        fov = float(np.degrees(2 * np.arctan(width / (2 * w))))
    return w, fov


# lesion points a share is measured on (every k-th beyond): ~1 ms a frame
SHARE_POINTS = 20000


def frame_share(site, point, direction, width, v) -> float:
    """The share of a square close-up frame, ``width`` of skin wide at ``point`` seen
    along ``direction``, that the lesion covers: the area of its surface points in the
    frame (each ``site.area / N``, foreshortened towards the camera and scaled by its
    depth), over the frame's; points facing away count for nothing, occlusion is
    ignored."""
    w, fov = _closeup_lens(width, v)
    eye = np.asarray(point, np.float64) + w * np.asarray(direction, np.float64) / np.linalg.norm(direction)
    step = max(1, len(site.points) // SHARE_POINTS)
    pts, nrm = site.points[::step], site.normals[::step]
    m = Camera.look_at(eye, point, fov_deg=fov).view_matrix()
    p = (pts - eye) @ m[:3, :3].T
    z = -p[:, 2]
    t = np.tan(np.radians(fov) / 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        inside = (z > 0) & (np.abs(p[:, 0]) < t * z) & (np.abs(p[:, 1]) < t * z)
        to_eye = eye - pts
        facing = np.einsum("ij,ij->i", nrm, to_eye) / np.linalg.norm(to_eye, axis=1)
        per_point = site.area / len(pts)
        covered = np.sum(np.where(inside, per_point * np.maximum(facing, 0) / z ** 2, 0.0))
    return float(covered / (2 * t) ** 2)


def _width_for_share(site, point, direction, share, min_width, v) -> float:
    """The frame width (on the skin) at which the lesion covers ``share`` of a close-up
    (``frame_share``), found by bisection in log width between min_width and the widest
    close-up (views.closeup_w's far end at views.fov_deg); min_width when the lesion
    fills less than its share even there (a lesion too small for it)."""
    lo = min_width
    hi = max(lo, 2 * v.closeup_w[1] * np.tan(np.radians(v.fov_deg) / 2))
    if frame_share(site, point, direction, lo, v) <= share:
        return lo
    if frame_share(site, point, direction, hi, v) >= share:
        return hi
    for _ in range(16):     # to ~0.01% of the width
        mid = np.sqrt(lo * hi)
        lo, hi = (mid, hi) if frame_share(site, point, direction, mid, v) > share else (lo, mid)
    # the lesion area in the frame at hi, over the share: exact when the whole lesion
    # lies in the frame (that area is then the same for any width between)
    covered = frame_share(site, point, direction, hi, v) * hi * hi
    return float(np.clip(np.sqrt(covered / share), lo, hi))


def _regional_camera(body, lesion_sites, rng, v):
    """A body part filling the frame: its width (its extent across its main axis) over the
    frame width in views.regional_fill, seen along the normal, so that a limb or the
    trunk runs across the whole frame as in a clinician's photograph of a region. With
    probability views.regional_lesion (when the body has lesions) the part is the one
    holding a lesion, centred near the lesion, as a clinician photographs an affected
    region; otherwise a part drawn by area, centred near its middle."""
    mesh, labels = body.mesh, body.mesh.vertex_labels
    if labels is None:
        return None
    centre = None
    if lesion_sites and rng.random() < v.regional_lesion:
        k_site = int(rng.integers(len(lesion_sites)))
        site = lesion_sites[k_site]
        j = int(rng.integers(len(site.points)))
        nearest = int(np.argmin(np.sum((mesh.vertices - site.points[j]) ** 2, axis=1)))
        if labels[nearest] > 0:
            k, centre = labels[nearest], f"lesion {k_site + 1}"
            point, normal = site.points[j], site.normals[j]
    if centre is None:
        parts = [k for k in np.unique(labels) if k > 0]
        areas = np.array([mesh.face_areas[labels[mesh.faces[:, 0]] == k].sum() for k in parts])
        k = parts[int(rng.choice(len(parts), p=areas / areas.sum()))]
    idx = np.flatnonzero(labels == k)
    pts = mesh.vertices[idx]
    c = pts.mean(0)
    axes = np.linalg.svd(pts - c, full_matrices=False)[2]
    width = float(np.ptp((pts - c) @ axes[1]))
    if centre is None:
        near = idx[np.argsort(np.sum((pts - c) ** 2, axis=1))[:max(1, len(idx) // 4)]]
        i = int(rng.choice(near))
        point, normal, centre = mesh.vertices[i], mesh.vertex_normals[i], f"part {int(k)}"
    fill = rng.uniform(*v.regional_fill)
    w = width / fill / (2 * np.tan(np.radians(v.fov_deg) / 2))
    return point, normal, normal, float(w), centre, v.fov_deg


def sample_scene(body, lesion_sites, rng, v, renderer, ambient_tint=None, drawn=None) -> ViewScene:
    """One camera + light(s) + material; raises ViewRejected when the light is blocked
    (whether the camera sees its point is checked on the view's own G-buffer by
    ``render_view``, which saves a draw per view). ``lesion_sites``: LesionSite per
    lesion. ``ambient_tint`` (RGB gains, see ``ambient_tint_from``) colours the room
    light's ambient term. Framing, wrap lighting, the flash and the skin material draw
    random numbers only when the config turns them on, so configs without them give the
    same scenes as before. ``drawn``: the mesh the views render (the body's geometry with
    the blended texture; default ``body.mesh``), which the light probe draws too: one
    upload per body, and the probe's near and far planes are the shadow map's (the
    renderer caches them per mesh and eye)."""
    mesh = body.mesh
    framing = choose_framing(rng, v, bool(lesion_sites))
    chosen = None
    if framing == "closeup":
        chosen = _closeup_camera(lesion_sites, rng, v)
    elif framing == "regional":
        chosen = _regional_camera(body, lesion_sites, rng, v)
    if chosen is None:
        framing = "wild"
        chosen = _wild_camera(mesh, lesion_sites, rng, v)
    point, normal, direction, w, centre, fov = chosen         # close-ups may zoom in
    if np.linalg.norm(normal) < 1e-9 or np.linalg.norm(direction) < 1e-9:
        raise ViewRejected(Rejection.ZERO_NORMAL)
    cam = Camera.from_surface(point, direction, w, fov_deg=fov, width=v.size, height=v.size)
    if direction is not normal:  # tilted: keep the surface's own normal in the record
        cam = Camera(cam.eye, cam.target, cam.up, cam.fov_deg, cam.width, cam.height, None, None,
                     {**cam.surface, "normal": (np.asarray(normal) / np.linalg.norm(normal)).tolist(),
                      "view_direction": cam.surface["normal"]})
    eye = np.asarray(cam.eye)
    sees = lambda p: np.linalg.norm(p - point) >= 1e-6 and sees_point(  # noqa: E731
        renderer, mesh if drawn is None else drawn,
        Camera.look_at(p, point, fov_deg=5.0, width=16, height=16), point)
    if v.light_position == "paper":
        # DermSynth3D's code: each axis moves the light up to light_offset[1] further on
        # the camera's side of the point; a light the body blocks goes to the camera
        light_pos = eye + np.sign(eye - point) * rng.uniform(*v.light_offset, size=3)
        light_pos = light_pos if sees(light_pos) else eye
    elif v.light_position == "room":
        # a ceiling lamp or a window: turned light_angle away from the camera about the
        # point, towards a direction that leans up (+Y) more often than down, so the light
        # grazes curved skin and the frame shades across as a room-lit photograph does
        to_eye = (eye - point) / np.linalg.norm(eye - point)
        lean = rng.normal(size=3) + np.array([0.0, 1.5, 0.0])
        lean -= to_eye * (lean @ to_eye)
        if np.linalg.norm(lean) < 1e-9:
            lean = np.cross(to_eye, [1.0, 0.0, 0.0])
        lean /= np.linalg.norm(lean)
        angle = np.radians(rng.uniform(*v.light_angle))
        light_pos = point + rng.uniform(*v.light_distance) * (np.cos(angle) * to_eye + np.sin(angle) * lean)
        if not sees(light_pos):
            raise ViewRejected(Rejection.LIGHT_BLOCKED)
    else:
        # light near the camera, in a random direction, unblocked on its way to the point
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        offset = rng.uniform(*v.light_offset)
        if framing == "closeup":
            offset = min(offset, 2 * w)  # a lamp or window beside the photographer, not metres off
        light_pos = eye + direction * offset
        if not sees(light_pos):
            raise ViewRejected(Rejection.LIGHT_BLOCKED)
    # One intensity per term for R, G and B alike: independent channels would tint the
    # skin green or purple, which no clinical photo shows.
    ambient = rng.uniform(*v.ambient)
    if ambient_tint is not None:
        ambient = ambient * np.asarray(ambient_tint, np.float64)
    # with fall-off the sampled intensities are those at the viewed point
    at_point = lambda p: float(np.linalg.norm(p - point)) if v.falloff else 0.0  # noqa: E731
    ground = float(rng.uniform(*v.ambient_ground)) if v.ambient_ground[0] < 1 else 1.0
    light = PointLight(light_pos, ambient=ambient, diffuse=rng.uniform(*v.diffuse),
                       specular=rng.uniform(*v.specular), falloff_distance=at_point(light_pos),
                       ambient_ground=ground)
    mat_spec, shininess = rng.uniform(*v.material_specular), rng.uniform(*v.shininess)
    wrap = float(rng.uniform(*v.wrap)) if v.wrap[1] > 0 else 0.0
    skin = {}
    if v.shading == "skin":
        skin = dict(model="skin", roughness=float(rng.uniform(*v.roughness)),
                    oil=float(rng.uniform(*v.oil)), relief=float(rng.uniform(*v.relief)),
                    detail=v.detail)
    material = Material(specular=mat_spec, shininess=shininess, wrap=wrap, **skin)
    flash, room_exposure = None, 1.0
    p_flash = v.closeup_flash if framing == "closeup" else v.flash
    if p_flash > 0 and rng.random() < p_flash:
        # a phone flash sits next to the lens: no ambient, the camera sees what it lights
        flash = PointLight(cam.eye, ambient=0.0, diffuse=rng.uniform(*v.flash_diffuse),
                           specular=rng.uniform(*v.flash_specular), falloff_distance=at_point(eye))
        if v.flash_corner != [1.0, 1.0]:
            # its beam along the lens axis, dimmer toward the frame's corners
            corner_deg = np.degrees(np.arctan(np.tan(np.radians(cam.fov_deg) / 2) * np.hypot(1, cam.aspect)))
            axis = np.asarray(cam.target, np.float64) - cam.eye
            flash = replace(flash, beam_axis=tuple(axis),
                            beam_exponent=beam_exponent_for(rng.uniform(*v.flash_corner), corner_deg))
        if v.flash_room != [1.0, 1.0]:
            # the camera exposes for its flash: the room light counts for less
            k = room_exposure = float(rng.uniform(*v.flash_room))
            light = replace(light, ambient=tuple(k * np.asarray(light.ambient)),
                            diffuse=tuple(k * np.asarray(light.diffuse)),
                            specular=tuple(k * np.asarray(light.specular)))
    scene = ViewScene(cam, light, material, centre, flash, point=np.asarray(point, np.float64),
                      framing=framing, room_exposure=room_exposure)
    if v.light_kelvin[1] > 0:   # drawn last: the scene's other draws stay as they were
        scene = _coloured_lights(scene, normal, rng, v)
    return scene


def _mired_uniform(rng, kelvin_range) -> float:
    """A colour temperature (K) drawn uniform in mired (1e6 / K), the scale on which
    equal steps look alike."""
    lo, hi = 1e6 / kelvin_range[1], 1e6 / kelvin_range[0]
    return 1e6 / rng.uniform(lo, hi)


def _coloured_lights(scene, normal, rng, v) -> ViewScene:
    """Black-body colours for the room light (views.light_kelvin), for its ambient (the
    same lamps, or with probability views.light_mixed a window or other lamps of their
    own temperature) and for the flash (views.flash_kelvin); then the camera's white
    balance for their mix at the viewed point, so that the point comes out neutral and
    the parts lit more by one source than the others take its colour, as mixed light
    does."""
    kelvin = {"light": _mired_uniform(rng, v.light_kelvin)}
    kelvin["ambient"] = _mired_uniform(rng, v.light_kelvin) if rng.random() < v.light_mixed else kelvin["light"]
    if scene.flash is not None:
        kelvin["flash"] = _mired_uniform(rng, v.flash_kelvin)
    colour = {k: light_colour(t) for k, t in kelvin.items()}
    n = np.asarray(normal, np.float64) / np.linalg.norm(normal)
    facing = lambda p: max(float(n @ (p - scene.point)) / np.linalg.norm(p - scene.point), 0.0)  # noqa: E731
    light = scene.light
    # each term as it reaches the viewed point (fall-off is 1 there by construction)
    energy = {"light": np.mean(light.diffuse) * facing(np.asarray(light.position)),
              "ambient": np.mean(light.ambient) * ambient_gain(n[1], light.ambient_ground)}
    if scene.flash is not None:
        energy["flash"] = np.mean(scene.flash.diffuse) * facing(np.asarray(scene.flash.position))
    total = sum(energy.values())
    mix = sum(energy[k] * colour[k] for k in energy) / total if total > 0 else colour["light"]
    gain = 1 / mix          # each colour has luminance 1, so the mix and its balance keep it
    light = replace(light, ambient=tuple(colour["ambient"] * gain * light.ambient),
                    diffuse=tuple(colour["light"] * gain * light.diffuse),
                    specular=tuple(colour["light"] * gain * light.specular))
    flash = scene.flash
    if flash is not None:
        flash = replace(flash, diffuse=tuple(colour["flash"] * gain * flash.diffuse),
                        specular=tuple(colour["flash"] * gain * flash.specular))
    return replace(scene, light=light, flash=flash, white_balance=tuple(gain.tolist()),
                   kelvin={k: round(t, 1) for k, t in kelvin.items()})


def ambient_tint_from(background, strength) -> tuple:
    """RGB gains (mean 1) that tint the ambient light towards the background's average
    colour, so the body sits in the room's light: ``1 + strength * (c / mean(c) - 1)``
    with each ratio clipped to [0.5, 1.5]."""
    c = np.asarray(cv2.mean(np.ascontiguousarray(background))[:3], np.float64)  # no float copy
    c = np.clip(c / max(c.mean(), 1e-6), 0.5, 1.5)
    return tuple((1 + float(strength) * (c - 1)).tolist())


def sees_point(renderer, mesh, cam, point) -> bool:
    """True when the first surface along the camera's central ray is ``point``."""
    crop = cam.crop(cam.width // 2 - 1, cam.height // 2 - 1, 2, 2)
    return _centre_is(renderer.depth(mesh, crop), cam, point)


def _centre_is(depth, cam, point) -> bool:
    """True when one of the 2x2 pixels at the centre of ``depth`` (cam's view depth;
    any size) lies at ``point``'s distance (2% tolerance)."""
    h, w = depth.shape
    d = depth[max(h // 2 - 1, 0):h // 2 + 1, max(w // 2 - 1, 0):w // 2 + 1]
    dist = float(np.linalg.norm(np.asarray(cam.eye) - point))
    return bool(((d > 0) & (np.abs(d - dist) <= 0.02 * dist + 1e-4)).any())


def buffers_for(outputs, labels) -> tuple:
    """The buffers a view's G-buffer + labels pass reads back: face ids, depth and the
    label maps always (they decide acceptance; depth drives defocus; anatomy is one of
    the maps when asked for), barycentrics only for normals, UV only when written."""
    need = ["face_id", "depth", *labels]
    if "normals" in outputs:
        need.append("bary")
    if "uv" in outputs:
        need.append("uv")
    return tuple(need)


def render_view(renderer, body, mesh_b, instances, nevi_map, scene: ViewScene, v, outputs):
    """Render one view; returns the layers dict (numpy) or raises ViewRejected. The
    G-buffer and labels decide acceptance. The shading pass (only when RGB is asked
    for) is drawn in the same call, so that llvmpipe rasterises each draw while the
    next one is set up (a rejected view, rare once the light probe passed, wastes it)."""
    labels = {"instances": instances, "nonskin": body.nonskin}
    if nevi_map is not None:
        labels["nevi"] = nevi_map
    # anatomy, drawn with the other labels: the body's per-texel map when it has one
    # (smooth part borders), else each pixel takes its nearest face corner's label
    parts = {}
    if "anatomy" in outputs and getattr(body, "anatomy_map", None) is not None:
        labels["anatomy"] = body.anatomy_map
    elif "anatomy" in outputs and body.anatomy is not None:
        parts = {"anatomy": body.anatomy}
    rgb = "rgb" in outputs
    out = renderer.render(mesh_b, scene.camera, passes=("gbuffer", "labels", "rgb") if rgb else
                          ("gbuffer", "labels"), label_textures=labels, vertex_labels=parts,
                          decal_labels="instances",
                          buffers=buffers_for(outputs, [*labels, *parts]) + (("rgba8",) if rgb else ()),
                          lights=scene.lights, material=scene.material, supersample=v.supersample,
                          multisample=v.multisample, shadows=v.shadows)
    if scene.point is not None and not _centre_is(out["depth"], scene.camera, scene.point):
        raise ViewRejected(Rejection.POINT_HIDDEN)
    # masks and counts in place on uint8/uint16 (this runs on the render thread)
    body_px = out["face_id"] >= 0
    lesion = body_px & (out["instances"] > 0)
    nonskin = body_px & (out["nonskin"] > 0) & ~lesion
    n = body_px.size
    counts = {"lesion": np.count_nonzero(lesion), "nonskin": np.count_nonzero(nonskin)}
    counts["skin"] = np.count_nonzero(body_px) - counts["lesion"] - counts["nonskin"]
    fractions = {name: float(c / n) for name, c in counts.items()}
    if fractions["skin"] < v.min_skin:
        raise ViewRejected(Rejection.TOO_LITTLE_SKIN,
                           f"{fractions['skin']:.3f} < views.min_skin {v.min_skin}")
    if fractions["lesion"] < v.min_lesion:
        raise ViewRejected(Rejection.TOO_LITTLE_LESION,
                           f"{fractions['lesion']:.3f} < views.min_lesion {v.min_lesion}")
    semantic = body_px.view(np.uint8) * np.uint8(SEMANTIC_SKIN)
    np.putmask(semantic, nonskin, SEMANTIC_NONSKIN)
    np.putmask(semantic, lesion, SEMANTIC_LESION)
    inst = out["instances"].astype(np.uint16)  # a copy
    np.putmask(inst, ~lesion, 0)
    layers = {"semantic": semantic, "instances": inst, "depth": out["depth"].astype(np.float32),
              "regions": instance_regions(inst), "fractions": fractions}
    if rgb:
        layers["rgba"] = out["rgba8"]  # premultiplied RGB + coverage, uint8
    if "anatomy" in out:
        layers["anatomy"] = out["anatomy"].astype(np.uint8)
    if "face_id" in outputs:
        layers["face_id"] = out["face_id"].astype(np.int32)
    if "uv" in outputs:
        layers["uv"] = np.where(body_px[..., None], out["uv"], -1).astype(np.float32)
    if "normals" in outputs:
        layers["normals"] = camera_normals(out, body.mesh, scene.camera)
    if nevi_map is not None:
        nevi = out["nevi"].astype(np.uint16)
        np.putmask(nevi, ~body_px | lesion, 0)
        layers["nevi_boxes"] = {k: r["box"] for k, r in instance_regions(nevi).items()}
        layers["nevi"] = nevi  # the paper's nevus target: the annotated boxes, rendered
    elif "nevi" in outputs:
        layers["nevi"] = np.zeros(body_px.shape, np.uint16)
    return layers


def edge_occluder(scene: ViewScene, shape, rng) -> Occluder:
    """Gloved fingers, clothing or a drape at the frame's edge, drawn at the scale of
    the skin the camera focuses on (``focus_distance``) and lit from the view's lights
    (each weighted by its diffuse strength; a flash lights from the camera)."""
    return sample_occluder(rng, shape, _mm_per_px(scene.camera), _light_in_view(scene))


# head views that may show a lock of hair: the head's share of the body in view
HAIR_HEAD_SHARE = 0.25
HAIR_IN_VIEW = 0.02   # short hair: the painted scalp hair's least share of the frame
HAIR_OFF_BODY = 0.3   # the most of a lock's outline that may lie over the background


def hair_occluder(scene: ViewScene, body, layers: dict, rng, share: float) -> Occluder | None:
    """With probability ``share``, a lock of the body's scalp hair over the frame's
    edge in a view of its head (a quarter of the body in view or more; any head in view
    for long hair, which falls over the neck and shoulders). Long hair comes from where
    the scalp's painted hair lies in the frame, else from the top of the head; short
    hair only from a side of the frame that the painted hair reaches, and no further
    than its length. None for a bald body, without an anatomy layer, or
    when more than ``HAIR_OFF_BODY`` of the lock would lie over the background."""
    look = (getattr(body, "meta", None) or {}).get("look") or {}
    anatomy = layers.get("anatomy")
    if look.get("hair", "none") == "none" or anatomy is None:
        return None
    long_hair = look["hair"] == "long"
    on_body = int((anatomy > 0).sum())
    head = anatomy == 1
    if not on_body or head.sum() < (0.05 if long_hair else HAIR_HEAD_SHARE) * on_body:
        return None
    hair_px = head & (layers["semantic"] == SEMANTIC_NONSKIN)
    hair_share = float(hair_px.mean())
    # short hair reaches the frame's edge only where the painted hair does: the side
    # with most of it along the border
    border = [hair_px[0].sum(), hair_px[:, -1].sum(), hair_px[-1].sum(), hair_px[:, 0].sum()]
    if not long_hair and (hair_share < HAIR_IN_VIEW or max(border) == 0):
        return None
    if rng.random() >= share:
        return None
    h, w = anatomy.shape
    if not long_hair:
        up, least = np.array([(0, -1), (1, 0), (0, 1), (-1, 0)][int(np.argmax(border))], float), 0.0
    elif hair_share >= HAIR_IN_VIEW:
        ys, xs = np.nonzero(hair_px)
        up, least = np.array([xs.mean() - w / 2, ys.mean() - h / 2]), 0.05 * max(h, w)
    else:   # the top of the head: world up in the image (x right, y down)
        d = scene.camera.view_matrix()[:3, :3] @ np.array([0.0, 1.0, 0.0])
        up, least = np.array([d[0], -d[1]]), 0.2
    if np.linalg.norm(up) < least:   # hair all round, or the head seen from above
        a = rng.uniform(0, 2 * np.pi)
        up = np.array([np.cos(a), np.sin(a)])
    occ = sample_hair(rng, (h, w), _mm_per_px(scene.camera), _light_in_view(scene), up / np.linalg.norm(up),
                      look["hair_rgb"], coily=look.get("hair_texture") == "coily", long_hair=long_hair)
    # drawn in the image plane, a lock over the background would hang in the air
    if occ is None or (layers["semantic"][occ.mask] == SEMANTIC_BACKGROUND).mean() > HAIR_OFF_BODY:
        return None
    return occ


def _light_in_view(scene: ViewScene) -> np.ndarray:
    """Unit direction towards the view's lights in the camera's frame (+x right, +y up,
    +z towards the camera), each weighted by its diffuse strength."""
    cam = scene.camera
    rot = cam.view_matrix()[:3, :3]
    towards = np.zeros(3)
    for light in scene.lights:
        d = rot @ (np.asarray(light.position) - np.asarray(cam.target))
        towards += np.mean(light.diffuse) * d / max(np.linalg.norm(d), 1e-9)
    return towards / np.linalg.norm(towards) if np.linalg.norm(towards) > 1e-9 else np.array([0, 0, 1.0])


def _mm_per_px(cam: Camera) -> float:
    """Millimetres of skin per pixel at the camera's focus."""
    return 1000 * focus_distance(cam) / float(cam.intrinsics()[1, 1])


def focus_distance(cam: Camera) -> float:
    """Where the camera focuses: its target, in view-space depth (scene units)."""
    return float(np.linalg.norm(np.subtract(cam.target, cam.eye)))


def draw_occluder(image: np.ndarray, occluder: Occluder) -> np.ndarray:
    """The occluder and its shadow on an 8-bit sRGB image, mixed in linear light inside
    its box (a new image)."""
    y0, y1, x0, x1 = occluder.box
    out = image.copy()
    under = srgb_to_linear(image[y0:y1, x0:x1]) * occluder.shadow[..., None]
    out[y0:y1, x0:x1] = linear_to_srgb8(under + (occluder.rgb - under) * occluder.alpha[..., None])
    return out


def occlude(layers: dict, occluder: Occluder, v, depth: float) -> bool:
    """Take the occluder's pixels out of the body's labels, in place: they become
    background (the body's surface is not seen there; the paper's 3-class target counts
    them as non-skin), and instances, anatomy, nevi, UV, normals and face ids are
    cleared there. Depth there becomes ``depth``, the occluder's own (it lies on the
    skin at the focus distance), so that defocus, which reads the depth layer, keeps it
    sharp and the recorded camera model reproduces the image.
    Returns False, changing nothing, when the view's skin or lesion minimum, or 70% of
    the lesion pixels, would not survive."""
    hidden = occluder.mask
    sem = layers["semantic"]
    kept = ~hidden
    n = sem.size
    skin = np.count_nonzero((sem == SEMANTIC_SKIN) & kept) / n
    lesion = np.count_nonzero((sem == SEMANTIC_LESION) & kept)
    if skin < v.min_skin or lesion / n < v.min_lesion or lesion < 0.7 * np.count_nonzero(sem == SEMANTIC_LESION):
        return False
    np.putmask(sem, hidden, SEMANTIC_BACKGROUND)
    clear = {"instances": 0, "anatomy": 0, "nevi": 0, "face_id": -1, "depth": depth, "uv": -1, "normals": 0}
    for name, value in clear.items():
        if name in layers:
            layers[name][hidden] = value
    layers["regions"] = instance_regions(layers["instances"])
    if "nevi_boxes" in layers:
        layers["nevi_boxes"] = {k: r["box"] for k, r in instance_regions(layers["nevi"]).items()}
    layers["fractions"] = {"lesion": float(lesion / n), "skin": float(skin),
                           "nonskin": float(np.count_nonzero(sem == SEMANTIC_NONSKIN) / n)}
    return True


def camera_normals(out, mesh, camera) -> np.ndarray:
    """Unit surface normals (H x W x 3 float32) in the camera's view space (the frame of
    ``Camera.view_matrix``: +x right, +y up, +z towards the camera, so visible surfaces
    have z > 0): vertex normals interpolated with the G-buffer's barycentrics (as the
    shading does), normalised and rotated; 0 off the body."""
    fid = out["face_id"]
    body_px = fid >= 0
    corners = mesh.faces[np.where(body_px, fid, 0)]                     # H,W,3
    n = np.einsum("hwk,hwkc->hwc", out["bary"].astype(np.float64), mesh.vertex_normals[corners])
    n = n @ camera.view_matrix()[:3, :3].T
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    n = np.where(body_px[..., None] & (norm > 0), n / np.maximum(norm, 1e-30), 0)
    return n.astype(np.float32)


def instance_regions(inst) -> dict:
    """{id: {"box": [x0, y0, x1, y1], "area": pixels}} of each non-zero id: minimal
    enclosing boxes, x1/y1 exclusive. Works on the rows and columns that hold ids."""
    rows, cols = np.flatnonzero(inst.any(1)), np.flatnonzero(inst.any(0))
    if not len(rows):
        return {}
    y0, x0 = int(rows[0]), int(cols[0])
    sub = inst[y0:rows[-1] + 1, x0:cols[-1] + 1]
    areas = np.bincount(sub.ravel())
    regions = {}
    for k in np.flatnonzero(areas[1:]) + 1:
        mask = sub == k
        ys, xs = np.flatnonzero(mask.any(1)), np.flatnonzero(mask.any(0))
        regions[int(k)] = {"box": [x0 + int(xs[0]), y0 + int(ys[0]), x0 + int(xs[-1]) + 1,
                                   y0 + int(ys[-1]) + 1], "area": int(areas[k])}
    return regions


def nevi_label_map(body):
    """uint16 texture with nevus i+1 painted in its box (None without nevi)."""
    if not body.nevi:
        return None
    h, w = body.nonskin.shape
    m = np.zeros((h, w), np.uint16)
    for i, (x0, y0, x1, y1) in enumerate(body.nevi):
        m[max(y0, 0):min(y1, h), max(x0, 0):min(x1, w)] = i + 1
    return m


def background_exposure(scene: ViewScene, background_meta: dict):
    """How bright the background comes out relative to its photograph: a room (or a
    wall) behind the patient has only the room's light, which a camera exposing for its
    flash records at ``scene.room_exposure`` and white-balanced for the light on the
    patient records in the room light's colour; a drape, sheet or clothing against the
    patient is lit as the skin is. A float, or RGB gains when the lights have colours."""
    if background_meta.get("kind") in NEAR_BACKDROPS:
        return 1.0
    if scene.kelvin is None:
        return scene.room_exposure
    colour = light_colour(scene.kelvin["light"]) * np.asarray(scene.white_balance)
    return (scene.room_exposure * colour).tolist()


def expose(image, gain):
    """An sRGB uint8 image with its light scaled by ``gain`` (in linear light; a float,
    or one per channel, R G B)."""
    gain = np.asarray(gain, np.float32)
    if (gain == 1.0).all():
        return image
    if gain.ndim == 0:
        return cv2.LUT(np.ascontiguousarray(image), linear_to_srgb8(SRGB_TO_LINEAR * gain))
    lut = linear_to_srgb8(SRGB_TO_LINEAR[:, None] * gain)   # 256 x 3, a column per channel
    return cv2.LUT(np.ascontiguousarray(image), lut.reshape(256, 1, 3))


def composite(rgba, background, blur_radius):
    """Body over the background (blurred with a Gaussian of the given radius), uint8.
    ``rgba`` is the renderer's premultiplied RGB and coverage (uint8, ``rgba8``): a
    pixel half covered by the body holds half its colour."""
    if blur_radius > 0:
        background = cv2.GaussianBlur(background, (0, 0), sigmaX=max(blur_radius, 1e-3))
    # in OpenCV's uint8 arithmetic (rounded products, saturating sums: the same bytes
    # as rounding the float sum, as the colour is whole) at 0.6x numpy's float time
    uncovered = cv2.bitwise_not(np.ascontiguousarray(rgba[..., 3]))
    behind = cv2.multiply(background, cv2.merge([uncovered] * 3), scale=1 / 255)
    return cv2.add(np.ascontiguousarray(rgba[..., :3]), behind)
