"""``glsynth preview``: an interactive window on the offscreen renderer.

One code path: a GLFW window with an OpenGL 3.3 core context is made current, the
ordinary ``Renderer`` attaches to it (``backend="window"``) and renders offscreen exactly
as ``glsynth generate`` does (same shaders, same passes, same label logic from
``glsynth.pipeline.views``); the chosen buffer is then copied to the window's default
framebuffer with a framebuffer blit. What the window shows is therefore the dataset's
RGB image or a false-colour rendering of one of its label maps.

Mouse: left drag orbits (about the camera's up axis and right axis), right or middle
drag (or shift + left drag) pans, the wheel zooms; a left click without dragging prints
the clicked pixel's anatomy label, lesion id, semantic label and depth. Keys: see
``KEY_HELP`` (printed with ``H``) and docs/preview.md.

Non-interactive use (tests, scripts): ``--screenshot PATH --frames N [--camera JSON]``
renders N frames, reads the window's default framebuffer (what is on screen) and writes
it as a PNG; ``--keys`` replays key presses first (one per frame), e.g. ``--keys n,c``.
"""
from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import logging
import math
import os
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from .errors import InputError, UnavailableError

log = logging.getLogger(__name__)

# Displayable buffers, in key order (keys 1..8).
BUFFERS = ("rgb", "semantic", "instances", "anatomy", "anatomy_groups", "depth", "face_id", "uv")
SEMANTIC_NAMES = {0: "background", 1: "skin", 2: "lesion", 3: "non-skin"}
ANATOMY_NAMES = {0: "background", 1: "head", 2: "upper torso", 3: "lower torso", 4: "hips",
                 5: "upper leg left", 6: "upper leg right", 7: "lower leg left",
                 8: "lower leg right", 9: "foot left", 10: "foot right", 11: "upper arm left",
                 12: "upper arm right", 13: "lower arm left", 14: "lower arm right",
                 15: "hand left", 16: "hand right"}
ANATOMY_GROUP_NAMES = {0: "background", 1: "head", 2: "torso", 3: "hips", 4: "legs", 5: "feet",
                       6: "arms", 7: "hands"}

# False-colour palettes (uint8 RGB; index = label).
SEMANTIC_PALETTE = np.array([[0, 0, 0], [225, 185, 150], [220, 30, 40], [40, 90, 210]], np.uint8)
ANATOMY_PALETTE = np.array([
    [0, 0, 0], [230, 25, 75], [60, 180, 75], [255, 225, 25], [0, 130, 200], [245, 130, 48],
    [145, 30, 180], [70, 240, 240], [240, 50, 230], [210, 245, 60], [250, 190, 212],
    [0, 128, 128], [220, 190, 255], [170, 110, 40], [255, 250, 200], [128, 0, 0],
    [170, 255, 195]], np.uint8)
GROUP_PALETTE = np.array([[0, 0, 0], [230, 25, 75], [60, 180, 75], [255, 225, 25],
                          [0, 130, 200], [245, 130, 48], [145, 30, 180], [70, 240, 240]], np.uint8)

NO_DISPLAY = ("glsynth preview needs a display: {reason}. On a machine without a screen run "
              "it under a virtual X server, e.g. `xvfb-run -a glsynth preview ...` (Debian "
              "package xvfb), or render offscreen with `glsynth generate` (EGL/OSMesa, no "
              "display needed).")

KEY_HELP = """\
glsynth preview keys
  1..8 / B        buffer: 1 RGB, 2 semantic, 3 lesion instances, 4 anatomy (16),
                  5 anatomy groups (7), 6 depth, 7 face id, 8 UV  (B: next buffer)
  mouse           left drag orbit, right/middle or shift+left drag pan, wheel zoom,
                  left click: print anatomy, lesion id, semantic label and depth there
  arrows          orbit the camera; + / - zoom; R reset the view
  shift+arrows    move the light (in the camera's plane); PageUp/PageDown nearer/farther
  A / shift+A     light ambient up / down      D / shift+D  light diffuse up / down
  S / shift+S     light specular up / down     M / shift+M  material specular up / down
  G / shift+G     shininess up / down
  N / shift+N     next / previous lesion (camera from its surface point, as in views)
  C               print camera, light and material as a JSON (= YAML) config snippet
  P               save a screenshot and all targets of the current view (--save-dir)
  H               this help;  Q / Esc quit"""


# ---- false colours ----------------------------------------------------------------------
def id_colours(ids: np.ndarray) -> np.ndarray:
    """Distinct, deterministic colours for integer ids (golden-ratio hues); 0 / negative
    ids are black. Returns uint8 (..., 3)."""
    ids = np.asarray(ids).astype(np.int64)
    if ids.size and ids.max() < (1 << 20):
        lut = _id_lut(max(1 << 16, 1 << int(ids.max()).bit_length()))
        return lut[np.maximum(ids, 0)]
    return _id_colours(ids)


@functools.lru_cache(maxsize=4)
def _id_lut(n):
    return _id_colours(np.arange(n))


def _id_colours(ids):
    hue = (ids * 0.618033988749895) % 1.0
    sat = 0.55 + 0.45 * ((ids * 7919) % 3) / 2.0
    val = 0.75 + 0.25 * ((ids * 104729) % 2)
    h6 = hue * 6.0
    i = np.floor(h6).astype(np.int64) % 6
    f = h6 - np.floor(h6)
    p, q, t = val * (1 - sat), val * (1 - sat * f), val * (1 - sat * (1 - f))
    table = [(val, t, p), (q, val, p), (p, val, t), (p, q, val), (t, p, val), (val, p, q)]
    rgb = np.zeros(ids.shape + (3,), np.float64)
    for k, (r, g, b) in enumerate(table):
        sel = i == k
        rgb[sel] = np.stack([r[sel], g[sel], b[sel]], -1)
    rgb[ids <= 0] = 0
    return np.round(rgb * 255).astype(np.uint8)


def colourise(name: str, layers: dict) -> np.ndarray:
    """The H x W x 3 uint8 image the window shows for buffer ``name`` of ``layers`` (the
    dict ``glsynth.pipeline.views.render_view`` returns)."""
    if name == "rgb":
        return np.ascontiguousarray(layers["rgba"][..., :3])  # over black
    if name == "semantic":
        return SEMANTIC_PALETTE[np.minimum(layers["semantic"], 3)]
    if name == "instances":
        return id_colours(layers["instances"])
    if name in ("anatomy", "anatomy_groups"):
        if "anatomy" not in layers:
            raise KeyError(f"{name}: this body has no anatomy labels")
        anat = np.minimum(layers["anatomy"], 16)
        if name == "anatomy":
            return ANATOMY_PALETTE[anat]
        from .dataformat import PART_GROUPS as ANATOMY_GROUPS
        return GROUP_PALETTE[ANATOMY_GROUPS[anat]]
    if name == "depth":
        d = layers["depth"]
        fg = d > 0
        out = np.zeros(d.shape + (3,), np.uint8)
        if fg.any():
            lo, hi = float(d[fg].min()), float(d[fg].max())
            t = (d - lo) / max(hi - lo, 1e-12)
            grey = np.round((1.0 - 0.85 * t) * 255).astype(np.uint8)  # near bright, far dark
            out[fg] = grey[fg][:, None]
        return out
    if name == "face_id":
        return id_colours(layers["face_id"].astype(np.int64) + 1)
    if name == "uv":
        uv = layers["uv"]
        fg = uv[..., 0] >= 0
        out = np.zeros(uv.shape[:2] + (3,), np.uint8)
        out[..., 0] = np.where(fg, np.round(np.clip(uv[..., 0], 0, 1) * 255), 0)
        out[..., 1] = np.where(fg, np.round(np.clip(uv[..., 1], 0, 1) * 255), 0)
        out[..., 2] = np.where(fg, 64, 0)
        return out
    raise InputError(f"unknown buffer {name!r}; choose from {', '.join(BUFFERS)}")


# ---- the scene --------------------------------------------------------------------------
@dataclass
class PreviewScene:
    """What the window shows: a body, its (blended) texture, lesion instance map and the
    placements of a ``glsynth generate`` run (empty without ``--blended``)."""

    body: object                  # glsynth.assets.Body
    mesh: object                  # body.mesh with the displayed texture
    instances: np.ndarray         # uint16 texture-space lesion ids
    placements: list = field(default_factory=list)   # dicts from placements.json
    body_id: str = "body"


def load_scene(args) -> PreviewScene:
    """The body and textures named by the command-line arguments."""
    from . import assets
    given = [n for n in ("body", "bodytex", "mesh") if getattr(args, n, None) is not None]
    if len(given) > 1:
        raise InputError(f"choose one of --body, --bodytex, --mesh (got {', '.join('--' + g for g in given)})")
    if args.blended is not None:
        if given:
            raise InputError("--blended takes its bodies from that run's config: choose one "
                             "with --body-id (e.g. --body-id body000), not --" + given[0])
        return _load_blended(args.blended, args.body_id)
    if args.body_id is not None:
        raise InputError("--body-id chooses a body of a --blended run; pass --blended DIR too")
    if given == ["bodytex"]:
        body, bid = assets.load_bodytex(args.bodytex), os.path.basename(os.path.normpath(args.bodytex))
    elif given == ["mesh"]:
        body = assets.load_mesh_body(args.mesh, texture_size=args.texture_size)
        bid = os.path.splitext(os.path.basename(args.mesh))[0]
    else:
        seed = 0 if args.body is None else args.body
        body, bid = assets.make_body(seed=seed, texture_size=args.texture_size), f"seed{seed}"
    h, w = body.mesh.texture.shape[:2]
    return PreviewScene(body, body.mesh, np.zeros((h, w), np.uint16), [], bid)


def _load_blended(folder, body_id) -> PreviewScene:
    from .config import from_dict
    from .io.images import read_image, read_rgb
    from .pipeline.bodies import load_body
    folder = os.fspath(folder)
    manifest = os.path.join(folder, "manifest.json")
    if not os.path.isfile(manifest):
        raise FileNotFoundError(f"--blended {folder}: no manifest.json (not a finished "
                                "`glsynth generate` output folder)")
    with open(manifest) as fh:
        raw = json.load(fh)
    if "config" not in raw:
        raise InputError(f"{manifest}: has no 'config' (the resolved run config)")
    cfg = from_dict(raw["config"], source=manifest)
    bodies_dir = os.path.join(folder, "bodies")
    available = sorted(d for d in os.listdir(bodies_dir)
                       if os.path.isdir(os.path.join(bodies_dir, d))) if os.path.isdir(bodies_dir) else []
    if not available:
        raise FileNotFoundError(f"--blended {folder}: no bodies/<id>/ folders (was the run made "
                                "with lesions.per_body = 0?)")
    body_id = body_id or available[0]
    if body_id not in available:
        raise FileNotFoundError(f"--blended {folder}: no body {body_id!r}; it has {', '.join(available)}")
    bdir = os.path.join(bodies_dir, body_id)
    body = load_body(cfg, body_id)
    tex_path = next((os.path.join(bdir, n) for n in ("blended.png", "pasted.png")
                     if os.path.isfile(os.path.join(bdir, n))), None)
    if tex_path is None:
        raise FileNotFoundError(f"{bdir}: neither blended.png nor pasted.png")
    texture = read_rgb(tex_path)
    hw = body.mesh.texture.shape[:2]
    if texture.shape[:2] != hw:
        raise InputError(f"{tex_path}: texture is {texture.shape[1]}x{texture.shape[0]} but body "
                         f"{body_id} has a {hw[1]}x{hw[0]} texture (config changed since the run?)")
    inst_path = os.path.join(bdir, "instances.png")
    if os.path.isfile(inst_path):
        instances = read_image(inst_path).astype(np.uint16)
        if instances.shape != hw:
            raise InputError(f"{inst_path}: instance map is {instances.shape[1]}x{instances.shape[0]}, "
                             f"texture is {hw[1]}x{hw[0]}")
    else:
        instances = np.zeros(hw, np.uint16)
    placements = []
    pl_path = os.path.join(bdir, "placements.json")
    if os.path.isfile(pl_path):
        with open(pl_path) as fh:
            placements = json.load(fh)
    return PreviewScene(body, body.mesh.copy_with(texture=texture), instances, placements, body_id)


# ---- cameras ------------------------------------------------------------------------------
def overview_camera(mesh, width, height, fov_deg=30.0):
    """The whole mesh from the front (+Z for built-in bodies), filling the window."""
    from .camera import Camera
    lo, hi = (np.asarray(b, float) for b in mesh.bounds)
    centre, ext = (lo + hi) / 2, hi - lo
    half = max(ext[1] / 2, ext[0] / 2 * height / width, 1e-6)
    dist = half / math.tan(math.radians(fov_deg) / 2) * 1.15 + ext[2] / 2
    return Camera.look_at(centre + np.array([0.0, 0.0, dist]), centre, fov_deg=fov_deg,
                          width=width, height=height)


def _rotate(v, axis, angle):
    """Rodrigues rotation of v about the unit axis."""
    axis = axis / np.linalg.norm(axis)
    c, s = math.cos(angle), math.sin(angle)
    return v * c + np.cross(axis, v) * s + axis * np.dot(axis, v) * (1 - c)


def orbit(cam, d_yaw, d_pitch):
    """Turn the eye about the target: yaw about the camera's up vector, pitch about its
    right vector (stopping short of the poles)."""
    from .camera import Camera
    eye, target, up = (np.asarray(v, float) for v in (cam.eye, cam.target, cam.up))
    off = _rotate(eye - target, up, d_yaw)
    right = np.cross(target - (target + off), up)
    if np.linalg.norm(right) > 1e-9 and d_pitch:
        new = _rotate(off, right, d_pitch)
        if abs(np.dot(new / np.linalg.norm(new), up / np.linalg.norm(up))) < 0.995:
            off = new
    return Camera.look_at(target + off, target, up, cam.fov_deg, cam.width, cam.height)


def zoom(cam, factor):
    from .camera import Camera
    eye, target = np.asarray(cam.eye, float), np.asarray(cam.target, float)
    off = (eye - target) * factor
    if np.linalg.norm(off) < 1e-4:
        return cam
    return Camera.look_at(target + off, target, cam.up, cam.fov_deg, cam.width, cam.height)


def pan(cam, dx_px, dy_px):
    """Move eye and target together so the scene follows the mouse by (dx, dy) pixels
    at the target's distance."""
    from .camera import Camera
    eye, target = np.asarray(cam.eye, float), np.asarray(cam.target, float)
    view = cam.view_matrix()
    right, up = view[0, :3], view[1, :3]
    dist = np.linalg.norm(target - eye)
    per_px = 2 * dist * math.tan(math.radians(cam.fov_deg) / 2) / cam.height
    shift = (-dx_px * right + dy_px * up) * per_px
    return Camera.look_at(eye + shift, target + shift, cam.up, cam.fov_deg, cam.width, cam.height)


def parse_camera(text, width, height):
    """A Camera (and optional light / material dicts) from a JSON string or a JSON/YAML
    file holding a ``Camera.to_dict()`` dict, or the snippet the C key prints
    ({"camera": ..., "light": ..., "material": ...}). The window size wins over the
    dict's width/height."""
    from .camera import Camera
    src = "--camera"
    if os.path.isfile(text):
        src = text
        with open(text) as fh:
            text = fh.read()
    try:
        d = json.loads(text)
    except json.JSONDecodeError as exc:
        try:
            import yaml
            d = yaml.safe_load(text)
        except Exception:
            raise InputError(f"{src}: not JSON or YAML ({exc})") from None
    if not isinstance(d, dict):
        raise InputError(f"{src}: expected a camera dict (Camera.to_dict()), got {type(d).__name__}")
    cam_d = d.get("camera", d)
    if not isinstance(cam_d, dict) or "eye" not in cam_d or "target" not in cam_d:
        raise InputError(f"{src}: a camera needs 'eye' and 'target' (as Camera.to_dict() writes)")
    try:
        cam = Camera.from_dict(cam_d).with_size(width, height)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{src}: bad camera: {exc}") from None
    return cam, d.get("light"), d.get("material")


# ---- the window ----------------------------------------------------------------------------
def open_window(width, height, title="glsynth preview", visible=True):
    """A GLFW window with a current OpenGL 3.3 core context; raises RuntimeError naming
    the problem when there is no display or no such context."""
    import glfw
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise UnavailableError(NO_DISPLAY.format(reason="the DISPLAY environment variable is not set"))
    errors = []
    glfw.set_error_callback(lambda code, desc: errors.append(
        desc.decode(errors="replace") if isinstance(desc, bytes) else str(desc)))
    if not glfw.init():
        raise UnavailableError(NO_DISPLAY.format(
            reason=f"GLFW could not start ({errors[-1] if errors else 'glfw.init failed'}; "
                   f"DISPLAY={os.environ.get('DISPLAY')!r})"))
    glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 3)
    glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, 3)
    glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
    glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, True)
    glfw.window_hint(glfw.DOUBLEBUFFER, True)
    glfw.window_hint(glfw.VISIBLE, bool(visible))
    glfw.window_hint(glfw.RESIZABLE, True)
    win = glfw.create_window(int(width), int(height), title, None, None)
    if not win:
        glfw.terminate()
        raise UnavailableError(f"glsynth preview: could not open a {width}x{height} window with an "
                           f"OpenGL 3.3 core context ({errors[-1] if errors else 'unknown error'}); "
                           "use `glsynth generate` to render offscreen instead")
    glfw.make_context_current(win)
    glfw.swap_interval(0)
    return win


class Viewer:
    """The previewer: a window, a Renderer attached to its context, and the view state
    (camera, light, material, displayed buffer). Use ``step()`` per frame or ``run()``."""

    def __init__(self, scene: PreviewScene, width=1024, height=768, camera=None, light=None,
                 material=None, buffer="rgb", save_dir="preview", visible=True):
        import glfw
        from .gl.renderer import Renderer
        from .lighting import Material
        self.glfw = glfw
        self.scene = scene
        self.window = open_window(width, height, visible=visible)
        fw, fh = glfw.get_framebuffer_size(self.window)
        self.size = (int(fw), int(fh))
        self.renderer = Renderer(*self.size, backend="window")
        self.ctx = self.renderer.ctx
        self._display = None          # (texture, framebuffer) for numpy images
        self._layers = None           # (key, layers) of the last full render
        self.camera = (camera.with_size(*self.size) if camera is not None
                       else overview_camera(scene.mesh, *self.size))
        self.home = self.camera
        # Light: ambient/diffuse/specular and an offset from the eye in the camera's frame
        # (right, up, back), so that it follows the camera; (0, 0, 0) = at the camera.
        self.ambient, self.diffuse, self.specular = 0.5, 0.5, 0.025
        self.light_offset = np.zeros(3)
        if light is not None:
            self._set_light_dict(light)
        m = material if isinstance(material, dict) else {}
        self.material = Material(specular=m.get("specular", 0.025), shininess=m.get("shininess", 50.0),
                                 wrap=m.get("wrap", 0.0))
        if buffer not in BUFFERS:
            raise InputError(f"unknown buffer {buffer!r}; choose from {', '.join(BUFFERS)}")
        self.buffer = buffer
        self.save_dir = save_dir
        self.lesion_index = -1
        self.frame_ms = 0.0
        self.dirty = True
        self.saved = 0
        self._mouse = {"down": None, "moved": False, "last": (0.0, 0.0), "shift": False}
        glfw.set_key_callback(self.window, self._on_key)
        glfw.set_mouse_button_callback(self.window, self._on_mouse_button)
        glfw.set_cursor_pos_callback(self.window, self._on_cursor)
        glfw.set_scroll_callback(self.window, self._on_scroll)
        glfw.set_framebuffer_size_callback(self.window, self._on_resize)

    # ---- state ---------------------------------------------------------------------
    @property
    def light(self):
        from .lighting import PointLight
        view = self.camera.view_matrix()
        frame = view[:3, :3].T          # columns: right, up, back in world space
        pos = np.asarray(self.camera.eye) + frame @ self.light_offset
        return PointLight(pos, ambient=self.ambient, diffuse=self.diffuse, specular=self.specular)

    def _set_light_dict(self, d):
        from .lighting import PointLight
        l = PointLight(d.get("position", self.camera.eye), ambient=d.get("ambient", 0.5),
                       diffuse=d.get("diffuse", 0.5), specular=d.get("specular", 0.025))
        self.ambient, self.diffuse, self.specular = (float(np.mean(getattr(l, k)))
                                                     for k in ("ambient", "diffuse", "specular"))
        frame = self.camera.view_matrix()[:3, :3]
        self.light_offset = frame @ (np.asarray(l.position) - np.asarray(self.camera.eye))

    def snippet(self) -> dict:
        """The current camera, light and material as config dicts."""
        return {"camera": self.camera.to_dict(), "light": self.light.to_dict(),
                "material": self.material.to_dict(), "body": self.scene.body_id}

    def view_scene(self):
        from .pipeline.views import ViewScene
        return ViewScene(self.camera, self.light, self.material, "preview")

    ALL_LABELS = ("semantic", "instances", "anatomy", "depth", "face_id", "uv")

    def layers(self, with_rgb=False, outputs=ALL_LABELS):
        """The label layers ``outputs`` (and RGB when asked) of the current view, from
        the same ``render_view`` that ``glsynth generate`` uses; cached until the view
        changes. Drawing asks only for the displayed buffer's layer (3x the frame rate
        of computing all of them); clicks and saves ask for all."""
        from .pipeline import views as V
        outputs = tuple(outputs) + (("rgb", "normals") if with_rgb else ())
        key = (self.camera, self.light, self.material, outputs)
        if self._layers is not None and self._layers[0] == key:
            return self._layers[1]
        # the view generator's settings, minus its rejection rules: every view is shown
        from .config import ViewsConfig
        v = dataclasses.replace(ViewsConfig(), min_skin=0.0, min_lesion=0.0, supersample=1)
        layers = V.render_view(self.renderer, self.scene.body, self.scene.mesh, self.scene.instances,
                               None, self.view_scene(), v, outputs)
        self._layers = (key, layers)
        return layers

    # ---- drawing ---------------------------------------------------------------------
    def draw(self):
        """Render the current buffer and copy it to the window's back buffer."""
        t0 = time.perf_counter()
        if self.buffer == "rgb":
            fbo = self.renderer.draw_rgb(self.scene.mesh, self.camera, lights=[self.light],
                                         material=self.material, dtype="f1")
        else:
            try:
                need = "anatomy" if self.buffer == "anatomy_groups" else self.buffer
                img = colourise(self.buffer, self.layers(outputs=(need,)))
            except KeyError as exc:
                log.warning("%s", exc.args[0])
                img = np.zeros(self.size[::-1] + (3,), np.uint8)
            fbo = self._show(img)
        with self.ctx:
            self.ctx.copy_framebuffer(self.ctx.screen, fbo)
            self.ctx.finish()
        self.frame_ms = (time.perf_counter() - t0) * 1000
        self.dirty = False
        self._title()

    def _show(self, img):
        w, h = self.size
        with self.ctx:
            if self._display is None or self._display[0].size != (w, h):
                if self._display is not None:
                    for o in self._display:
                        o.release()
                tex = self.ctx.texture((w, h), 4, dtype="f1")
                self._display = (tex, self.ctx.framebuffer(color_attachments=[tex]))
            rgba = np.empty((h, w, 4), np.uint8)
            rgba[..., :3] = img[::-1]   # GL rows go bottom-up
            rgba[..., 3] = 255
            self._display[0].write(rgba.tobytes())
        return self._display[1]

    def read_screen(self) -> np.ndarray:
        """The window's default framebuffer (glReadPixels of what is drawn there), as an
        H x W x 3 uint8 RGB array with row 0 at the top."""
        w, h = self.size
        with self.ctx:
            data = self.ctx.screen.read(viewport=(0, 0, w, h), components=3, alignment=1)
        return np.frombuffer(data, np.uint8).reshape(h, w, 3)[::-1].copy()

    def _title(self):
        fps = 1000.0 / self.frame_ms if self.frame_ms > 0 else float("inf")
        lesion = f" | lesion {self.lesion_index + 1}/{len(self.scene.placements)}" \
            if self.lesion_index >= 0 else ""
        self.glfw.set_window_title(
            self.window, f"glsynth preview | {self.scene.body_id} | {self.buffer} | "
                         f"{self.frame_ms:.1f} ms ({fps:.0f} fps){lesion}")

    def step(self, force=False):
        """Draw a frame if anything changed (or ``force``) and show it."""
        if self.dirty or force:
            self.draw()
            self.glfw.swap_buffers(self.window)

    def run(self, frames=None, screenshot=None, keys=()):
        """Interactive loop, or (``frames``) a fixed number of frames, key presses in
        ``keys`` replayed one per frame first, then an optional screenshot of the last."""
        glfw = self.glfw
        pending = list(keys)
        n = 0
        while not glfw.window_should_close(self.window):
            if pending:
                self.press(pending.pop(0))
            if frames is not None:
                self.draw()
                if n + 1 >= frames and not pending:
                    if screenshot:
                        from .io.images import write_png
                        write_png(screenshot, self.read_screen())
                        print(f"wrote {screenshot}")
                    glfw.swap_buffers(self.window)
                    break
                glfw.swap_buffers(self.window)
                glfw.poll_events()
                n += 1
                continue
            self.step()
            glfw.wait_events_timeout(0.5)

    def close(self):
        if self.window is not None:
            self.renderer.release()
            self.glfw.destroy_window(self.window)
            self.glfw.terminate()
            self.window = None

    # ---- actions -----------------------------------------------------------------------
    def set_camera(self, cam):
        self.camera = cam
        self.dirty = True

    def set_buffer(self, name):
        if name not in BUFFERS:
            raise InputError(f"unknown buffer {name!r}; choose from {', '.join(BUFFERS)}")
        self.buffer = name
        self.dirty = True

    def jump_to_lesion(self, delta=1):
        """Camera of the next placed lesion: from its surface point, as views are made."""
        from .camera import Camera
        pl = self.scene.placements
        if not pl:
            print("no lesions to jump to (pass --blended DIR of a `glsynth generate` run)")
            return None
        self.lesion_index = (self.lesion_index + delta) % len(pl)
        p = pl[self.lesion_index]
        c = p["camera"]
        if "point" in c and "normal" in c and "w" in c:
            cam = Camera.from_surface(c["point"], c["normal"], c["w"], fov_deg=c.get("fov_deg", 30.0),
                                      width=self.size[0], height=self.size[1])
        else:
            cam = Camera.from_dict(c).with_size(*self.size)
        self.set_camera(cam)
        print(f"lesion {p.get('instance', self.lesion_index + 1)} ({p.get('lesion_id')}): "
              f"camera at w = {c.get('w')}")
        return cam

    def print_snippet(self):
        text = "{\n" + ",\n".join(f" {json.dumps(k)}: {json.dumps(v)}"
                                   for k, v in self.snippet().items()) + "\n}"
        print(text, flush=True)
        return text

    def pick(self, x, y) -> dict:
        """Labels under framebuffer pixel (x = column, y = row from the top); printed."""
        w, h = self.size
        col, row = int(x), int(y)
        if not (0 <= col < w and 0 <= row < h):
            return {}
        layers = self.layers()
        anat = int(layers["anatomy"][row, col]) if "anatomy" in layers else None
        sem = int(layers["semantic"][row, col])
        info = {"x": col, "y": row, "anatomy": anat,
                "anatomy_name": ANATOMY_NAMES.get(anat) if anat is not None else None,
                "lesion": int(layers["instances"][row, col]), "semantic": sem,
                "semantic_name": SEMANTIC_NAMES.get(sem), "depth": float(layers["depth"][row, col]),
                "face_id": int(layers["face_id"][row, col])}
        print(f"pixel ({col}, {row}): anatomy {anat} ({info['anatomy_name']}), lesion {info['lesion']}, "
              f"semantic {sem} ({info['semantic_name']}), depth {info['depth']:.4f}", flush=True)
        return info

    def save(self):
        """Screenshot plus every target of the current view, written like a dataset
        sample (``glsynth.pipeline.writer.write_sample``) under ``save_dir``."""
        from .io.images import write_png
        from .pipeline import views as V
        from .pipeline.writer import write_sample
        layers = dict(self.layers(with_rgb=True))
        self.saved += 1
        sid = f"{self.scene.body_id}_preview{self.saved:04d}"
        h, w = layers["semantic"].shape
        layers["image"] = V.composite(layers["rgba"], np.zeros((h, w, 3), np.uint8), 0)
        cam = self.camera
        meta = {"id": sid, "width": w, "height": h, "buffer_on_screen": self.buffer,
                "camera": {**cam.to_dict(), "intrinsics": cam.intrinsics().tolist(),
                           "view_matrix": cam.view_matrix().tolist()},
                "light": self.light.to_dict(), "material": self.material.to_dict(),
                "lights": [{**self.light.to_dict(), "kind": "room"}],
                "body": {"id": self.scene.body_id},
                "lesions": [{"instance": k, **region} for k, region in layers["regions"].items()],
                "box_convention": "[x0, y0, x1, y1] pixels, x1/y1 exclusive"}
        outputs = ("rgb", "semantic", "instances", "anatomy", "depth", "normals", "uv", "face_id")
        write_sample(self.save_dir, sid, layers, meta, outputs)
        shot = os.path.join(self.save_dir, "screens", f"{sid}_{self.buffer}.png")
        self.draw()
        write_png(shot, self.read_screen())
        print(f"saved {sid} in {self.save_dir} (images/, targets/, screens/)", flush=True)
        return sid

    def adjust(self, what, up):
        """Step a light or material term up or down (clamped)."""
        from .lighting import Material
        f = 1.0 if up else -1.0
        if what == "ambient":
            self.ambient = float(np.clip(self.ambient + 0.05 * f, 0, 2))
        elif what == "diffuse":
            self.diffuse = float(np.clip(self.diffuse + 0.05 * f, 0, 2))
        elif what == "specular":
            self.specular = float(np.clip(self.specular + 0.01 * f, 0, 1))
        elif what == "material_specular":
            s = float(np.clip(np.mean(self.material.specular) + 0.01 * f, 0, 1))
            self.material = Material(s, self.material.shininess, self.material.wrap)
        elif what == "shininess":
            s = float(np.clip(self.material.shininess * (1.25 if up else 0.8), 1, 1000))
            self.material = Material(self.material.specular, s, self.material.wrap)
        log.info("%s", self.snippet())
        self.dirty = True

    def move_light(self, dx, dy, dz):
        """Move the light by fractions of the camera's distance in its frame."""
        dist = float(np.linalg.norm(np.subtract(self.camera.target, self.camera.eye)))
        self.light_offset = self.light_offset + np.array([dx, dy, dz]) * 0.1 * dist
        self.dirty = True

    # ---- input -------------------------------------------------------------------------
    def press(self, name):
        """Apply a key by name ('n', 'c', '3', 'shift+left', 'pageup'...), as the window does."""
        key = name.strip().lower()
        shift = key.startswith("shift+")
        self._action(key[6:] if shift else key, shift)

    _GLFW_NAMES = {"LEFT": "left", "RIGHT": "right", "UP": "up", "DOWN": "down", "PAGE_UP": "pageup",
                   "PAGE_DOWN": "pagedown", "ESCAPE": "escape", "EQUAL": "+", "KP_ADD": "+",
                   "MINUS": "-", "KP_SUBTRACT": "-", "TAB": "b"}

    def _on_key(self, win, key, scancode, action, mods):
        glfw = self.glfw
        if action not in (glfw.PRESS, glfw.REPEAT):
            return
        name = None
        for gname, ours in self._GLFW_NAMES.items():
            if key == getattr(glfw, "KEY_" + gname):
                name = ours
        if name is None and (glfw.KEY_A <= key <= glfw.KEY_Z or glfw.KEY_0 <= key <= glfw.KEY_9):
            name = chr(key).lower()
        if name is not None:
            self._action(name, bool(mods & glfw.MOD_SHIFT))

    def _action(self, key, shift):
        step = math.radians(10)
        if key in [str(i + 1) for i in range(len(BUFFERS))]:
            self.set_buffer(BUFFERS[int(key) - 1])
        elif key == "b":
            self.set_buffer(BUFFERS[(BUFFERS.index(self.buffer) + (-1 if shift else 1)) % len(BUFFERS)])
        elif key in ("left", "right", "up", "down"):
            d = {"left": (-1, 0), "right": (1, 0), "up": (0, 1), "down": (0, -1)}[key]
            if shift:
                self.move_light(d[0], d[1], 0)
            else:
                self.set_camera(orbit(self.camera, d[0] * step, d[1] * step))
        elif key in ("pageup", "pagedown"):
            self.move_light(0, 0, -1 if key == "pageup" else 1)
        elif key in ("+", "-"):
            self.set_camera(zoom(self.camera, 0.8 if key == "+" else 1.25))
        elif key == "r":
            self.set_camera(self.home)
            self.light_offset = np.zeros(3)
        elif key in ("a", "d", "s", "m", "g"):
            self.adjust({"a": "ambient", "d": "diffuse", "s": "specular", "m": "material_specular",
                         "g": "shininess"}[key], not shift)
        elif key == "n":
            self.jump_to_lesion(-1 if shift else 1)
        elif key == "c":
            self.print_snippet()
        elif key == "p":
            self.save()
        elif key == "h":
            print(KEY_HELP, flush=True)
        elif key in ("q", "escape"):
            self.glfw.set_window_should_close(self.window, True)
        else:
            return
        self.dirty = True

    def _cursor_to_fb(self, x, y):
        ww, wh = self.glfw.get_window_size(self.window)
        return x * self.size[0] / max(ww, 1), y * self.size[1] / max(wh, 1)

    def _on_mouse_button(self, win, button, action, mods):
        glfw = self.glfw
        if action == glfw.PRESS:
            self._mouse.update(down=button, moved=False, last=glfw.get_cursor_pos(win),
                               shift=bool(mods & glfw.MOD_SHIFT))
        elif action == glfw.RELEASE:
            if button == glfw.MOUSE_BUTTON_LEFT and not self._mouse["moved"]:
                self.pick(*self._cursor_to_fb(*glfw.get_cursor_pos(win)))
            self._mouse["down"] = None

    def _on_cursor(self, win, x, y):
        glfw = self.glfw
        m = self._mouse
        if m["down"] is None:
            return
        lx, ly = m["last"]
        dx, dy = self._cursor_to_fb(x - lx, y - ly)
        if not m["moved"] and abs(dx) + abs(dy) < 3:
            return
        m["moved"], m["last"] = True, (x, y)
        if m["down"] == glfw.MOUSE_BUTTON_LEFT and not m["shift"]:
            self.set_camera(orbit(self.camera, -dx * 0.01, dy * 0.01))
        else:
            self.set_camera(pan(self.camera, dx, dy))

    def _on_scroll(self, win, dx, dy):
        self.set_camera(zoom(self.camera, 0.9 ** dy))

    def _on_resize(self, win, w, h):
        if w < 1 or h < 1:
            return
        self.size = (int(w), int(h))
        self.camera = self.camera.with_size(*self.size)
        self.home = self.home.with_size(*self.size)
        self.dirty = True


# ---- command line --------------------------------------------------------------------------
def _size(text):
    try:
        w, h = (int(v) for v in text.lower().split("x"))
        if w < 1 or h < 1:
            raise ValueError
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, e.g. 1024x768, got {text!r}") from None
    return w, h


def register(subparsers):
    p = subparsers.add_parser(
        "preview", help="interactive window: orbit a body, switch buffers, inspect labels",
        description="Interactive OpenGL preview of a body with the offscreen renderer "
                    "(press H in the window for the keys). Needs a display (or xvfb-run -a).")
    src = p.add_argument_group("what to show (default --body 0)")
    src.add_argument("--body", type=int, default=None, metavar="SEED", help="built-in body from this seed")
    src.add_argument("--bodytex", default=None, metavar="FOLDER", help="a 3DBodyTex-layout scan folder")
    src.add_argument("--mesh", default=None, metavar="FILE", help="any textured mesh (OBJ, PLY, GLB...)")
    src.add_argument("--blended", default=None, metavar="DIR",
                     help="a `glsynth generate` output folder: show a body with its blended lesions")
    src.add_argument("--body-id", default=None, help="the body of the --blended run (default: the first)")
    src.add_argument("--texture-size", type=int, default=1024,
                     help="texture size of built-in bodies and re-atlased meshes (default 1024)")
    p.add_argument("--size", type=_size, default=(1024, 768), metavar="WxH", help="window size (1024x768)")
    p.add_argument("--buffer", choices=BUFFERS, default="rgb", help="buffer shown first")
    p.add_argument("--camera", default=None, metavar="JSON",
                   help="start camera: JSON string or file with a Camera.to_dict() dict (or the C-key snippet)")
    p.add_argument("--save-dir", default="preview", help="where P saves screenshots and targets (./preview)")
    auto = p.add_argument_group("non-interactive mode")
    auto.add_argument("--screenshot", default=None, metavar="PATH",
                      help="after --frames frames, save the window's framebuffer as PNG and exit")
    auto.add_argument("--frames", type=int, default=None, help="render this many frames, then exit")
    auto.add_argument("--keys", default="", help="keys to press first, one per frame, comma-separated "
                                                  "(e.g. 'n,3,shift+left,c')")
    p.set_defaults(fn=cmd_preview)


def cmd_preview(args):
    if args.frames is not None and args.frames < 1:
        raise InputError(f"--frames must be >= 1, got {args.frames}")
    if args.texture_size < 16:
        raise InputError(f"--texture-size must be >= 16, got {args.texture_size}")
    frames = args.frames if args.frames is not None else (1 if args.screenshot else None)
    cam = light = material = None
    if args.camera:
        cam, light, material = parse_camera(args.camera, *args.size)
    scene = load_scene(args)
    viewer = Viewer(scene, *args.size, camera=cam, light=light, material=material,
                    buffer=args.buffer, save_dir=args.save_dir)
    try:
        if frames is None:
            print(KEY_HELP, flush=True)
        keys = [k.strip() for k in args.keys.split(",") if k.strip()]
        viewer.run(frames=frames, screenshot=args.screenshot, keys=keys)
    finally:
        viewer.close()
