"""The previewer's state and drawing: a Renderer attached to the window's context, the
camera, light and material, and the buffer on screen."""
from __future__ import annotations

import dataclasses
import json
import logging
import os
import time

import numpy as np

from .. import dataformat as fmt
from ..errors import InputError
from ..lighting import Material, PointLight
from .buffers import BUFFERS, colourise, layer_for
from .controls import Controls, apply_key
from .navigation import follow, overview_camera
from .window import glfw, open_window

log = logging.getLogger(__name__)

# The light's start terms: the paper's blending light (at the camera unless given).
LIGHT_TERMS = {"ambient": 0.5, "diffuse": 0.5, "specular": 0.025}
ALL_LABELS = ("semantic", "instances", "anatomy", "depth", "face_id", "uv")


def default_material(views) -> Material:
    """The material shown until one is given: the paper's Phong terms (specular 0.025,
    shininess 50) in the config's shading model, other terms at Material's defaults."""
    return Material(model=views.shading, detail=views.detail)


class Viewer:
    """A window, a Renderer attached to its context, and the view state: camera, a room
    light that follows the camera (and an optional flash at it), material, displayed
    buffer. ``lights``: [room light] or [room light, flash], as a per-image record has
    them. Use ``step()`` per frame or ``run()``."""

    def __init__(self, scene, width=1024, height=768, camera=None, lights=None, material=None,
                 buffer="rgb", save_dir="preview", visible=True):
        from ..gl.renderer import Renderer
        if buffer not in BUFFERS:
            raise InputError(f"unknown buffer {buffer!r}; choose from {', '.join(BUFFERS)}")
        if lights is not None and not 1 <= len(lights) <= 2:
            raise InputError(f"the previewer shows a room light and at most a flash, got {len(lights)} lights")
        self.glfw = glfw
        self.scene = scene
        self.window = open_window(width, height, visible=visible)
        fw, fh = glfw.get_framebuffer_size(self.window)
        self.size = (int(fw), int(fh))
        self.renderer = Renderer(*self.size, backend="window")
        self.ctx = self.renderer.ctx
        if scene.views.occlusion and scene.mesh.occlusion is None:  # as generate shades skin
            from ..gl.occlusion import cached_occlusion
            scene = self.scene = dataclasses.replace(
                scene, mesh=scene.mesh.copy_with(occlusion=cached_occlusion(self.renderer, scene.mesh)))
        self._display = None          # (texture, framebuffer) for numpy images
        self._cache = {}              # what: (key, result) of the last render
        self.camera = (camera.with_size(*self.size) if camera is not None
                       else overview_camera(scene.mesh, *self.size))
        self.home = self.camera
        room = lights[0] if lights else PointLight(self.camera.eye, **LIGHT_TERMS)
        self.room = room              # its fall-off and ambient_ground stay as recorded
        self.light_position = np.asarray(room.position, float)
        self.light_terms = {k: getattr(room, k) for k in LIGHT_TERMS}
        self.flash = lights[1] if lights and len(lights) > 1 else None
        self.material = material if material is not None else default_material(scene.views)
        self.buffer = buffer
        self.save_dir = save_dir
        self.lesion_index = -1
        self.frame_ms = 0.0
        self.dirty = True
        self.saved = 0
        self.controls = Controls(self)
        self.controls.attach(self.window)

    # ---- state ---------------------------------------------------------------------
    @property
    def light(self) -> PointLight:
        """The room light."""
        return dataclasses.replace(self.room, position=tuple(self.light_position), **self.light_terms)

    @property
    def lights(self) -> list:
        """The room light, and the flash (at the camera) when there is one."""
        if self.flash is None:
            return [self.light]
        return [self.light, dataclasses.replace(self.flash, position=self.camera.eye)]

    def snippet(self) -> dict:
        """The current camera, lights and material as config dicts (the keys of a
        per-image record)."""
        return {"camera": self.camera.to_dict(), "light": self.light.to_dict(),
                "lights": fmt.lights_record(self.lights), "material": self.material.to_dict(),
                "body": self.scene.body_id}

    def view_scene(self):
        from ..pipeline.views import ViewScene
        flash = self.lights[1] if self.flash is not None else None
        return ViewScene(self.camera, self.light, self.material, "preview", flash)

    def _cached(self, what, key, make):
        if what not in self._cache or self._cache[what][0] != key:
            self._cache[what] = (key, make())
        return self._cache[what][1]

    def layers(self, with_rgb=False, outputs=ALL_LABELS):
        """The label layers ``outputs`` (and RGB when asked) of the current view, from
        the same ``render_view`` that ``glsynth generate`` uses, with the scene's view
        settings but no rejection rule (every view is shown); cached until the view
        changes. Drawing asks only for the displayed buffer's layer; clicks and saves
        ask for all."""
        from ..pipeline import views as V
        outputs = tuple(outputs) + (("rgb", "normals") if with_rgb else ())
        v = dataclasses.replace(self.scene.views, min_skin=0.0, min_lesion=0.0)
        s = self.scene
        return self._cached("layers", (self.camera, tuple(self.lights), self.material, outputs),
                            lambda: V.render_view(self.renderer, s.body, s.mesh, s.instances, None,
                                                  self.view_scene(), v, outputs))

    def rgb(self) -> np.ndarray:
        """H x W x 3 uint8: the body shaded as ``glsynth generate`` shades a view (the
        scene's shading model, multisampling, supersampling and shadows), premultiplied
        by coverage, over black: the ``rgba`` layer before the background goes behind it
        and the camera model (glsynth.pipeline.photo) is applied."""
        v = self.scene.views

        def render():
            out = self.renderer.render(self.scene.mesh, self.camera, passes=("rgb",),
                                       lights=self.lights, material=self.material,
                                       supersample=v.supersample, multisample=v.multisample,
                                       shadows=v.shadows, buffers=("rgba8",))
            return np.ascontiguousarray(out["rgba8"][..., :3])
        return self._cached("rgb", (self.camera, tuple(self.lights), self.material), render)

    # ---- drawing ---------------------------------------------------------------------
    def draw(self):
        """Render the current buffer and copy it to the window's back buffer."""
        t0 = time.perf_counter()
        if self.buffer == "rgb":
            img = self.rgb()
        else:
            try:
                img = colourise(self.buffer, self.layers(outputs=(layer_for(self.buffer),)))
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
        glfw.set_window_title(self.window, f"glsynth preview | {self.scene.body_id} | {self.buffer} | "
                                           f"{self.frame_ms:.1f} ms ({fps:.0f} fps){lesion}")

    def step(self, force=False):
        """Draw a frame if anything changed (or ``force``) and show it."""
        if self.dirty or force:
            self.draw()
            glfw.swap_buffers(self.window)

    def run(self, frames=None, screenshot=None, keys=()):
        """Interactive loop, or (``frames``) a fixed number of frames, key presses in
        ``keys`` replayed one per frame first, then an optional screenshot of the last."""
        pending = list(keys)
        n = 0
        while not glfw.window_should_close(self.window):
            if pending:
                self.press(pending.pop(0))
            if frames is not None:
                self.draw()
                if n + 1 >= frames and not pending:
                    if screenshot:
                        from ..io.images import write_png
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
            glfw.destroy_window(self.window)
            glfw.terminate()
            self.window = None

    # ---- actions -----------------------------------------------------------------------
    def press(self, name):
        """Apply a key by name ('n', 'c', '3', 'shift+left', 'pageup'...), as the window does."""
        key = name.strip().lower()
        shift = key.startswith("shift+")
        apply_key(self, key[6:] if shift else key, shift)

    def set_camera(self, cam):
        """Move the camera; the room light keeps its place relative to it."""
        self.light_position = follow(self.light_position, self.camera, cam)
        self.camera = cam
        self.dirty = True

    def reset(self):
        """The start camera, with the light at it."""
        self.camera = self.home
        self.light_position = np.asarray(self.home.eye, float)
        self.dirty = True

    def resize(self, w, h):
        self.size = (w, h)
        self.camera = self.camera.with_size(w, h)
        self.home = self.home.with_size(w, h)
        self.dirty = True

    def quit(self):
        glfw.set_window_should_close(self.window, True)

    def set_buffer(self, name):
        if name not in BUFFERS:
            raise InputError(f"unknown buffer {name!r}; choose from {', '.join(BUFFERS)}")
        self.buffer = name
        self.dirty = True

    def jump_to_lesion(self, delta=1):
        """Camera of the next placed lesion: from its surface point, as views are made."""
        from ..camera import Camera
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
                "anatomy_name": fmt.ANATOMY_NAMES.get(anat) if anat is not None else None,
                "lesion": int(layers["instances"][row, col]), "semantic": sem,
                "semantic_name": fmt.SEMANTIC_NAMES.get(sem), "depth": float(layers["depth"][row, col]),
                "face_id": int(layers["face_id"][row, col])}
        print(f"pixel ({col}, {row}): anatomy {anat} ({info['anatomy_name']}), lesion {info['lesion']}, "
              f"semantic {sem} ({info['semantic_name']}), depth {info['depth']:.4f}", flush=True)
        return info

    def save(self):
        """Screenshot plus every target of the current view, written like a dataset
        sample (``glsynth.pipeline.writer.write_sample``) under ``save_dir``; the image
        is the body over black (no background, no camera model)."""
        from ..io.images import write_png
        from ..pipeline import views as V
        from ..pipeline.writer import write_sample
        layers = dict(self.layers(with_rgb=True))
        self.saved += 1
        sid = f"{self.scene.body_id}_preview{self.saved:04d}"
        h, w = layers["semantic"].shape
        layers["image"] = V.composite(layers["rgba"], np.zeros((h, w, 3), np.uint8), 0)
        meta = {"id": sid, "width": w, "height": h, "buffer_on_screen": self.buffer,
                "camera": fmt.camera_record(self.camera),
                "light": self.light.to_dict(), "material": self.material.to_dict(),
                "lights": fmt.lights_record(self.lights),
                "body": {"id": self.scene.body_id},
                "lesions": [{"instance": k, **region} for k, region in layers["regions"].items()],
                "box_convention": fmt.BOX_CONVENTION}
        outputs = ("rgb", "semantic", "instances", "anatomy", "depth", "normals", "uv", "face_id")
        write_sample(self.save_dir, sid, layers, meta, outputs)
        shot = os.path.join(self.save_dir, "screens", f"{sid}_{self.buffer}.png")
        self.draw()
        write_png(shot, self.read_screen())
        print(f"saved {sid} in {self.save_dir} (images/, targets/, screens/)", flush=True)
        return sid

    def adjust(self, what, up):
        """Step a light or material term up or down (clamped)."""
        f = 1.0 if up else -1.0
        if what in ("ambient", "diffuse", "specular"):
            step, hi = (0.01, 1.0) if what == "specular" else (0.05, 2.0)
            self.light_terms[what] = tuple(np.clip(np.add(self.light_terms[what], step * f), 0, hi).tolist())
        elif what == "material_specular":
            s = float(np.clip(np.mean(self.material.specular) + 0.01 * f, 0, 1))
            self.material = dataclasses.replace(self.material, specular=s)
        elif what == "shininess":
            s = float(np.clip(self.material.shininess * (1.25 if up else 0.8), 1, 1000))
            self.material = dataclasses.replace(self.material, shininess=s)
        else:
            raise InputError(f"unknown term {what!r}")
        log.info("%s", self.snippet())
        self.dirty = True

    def move_light(self, dx, dy, dz):
        """Move the light by fractions of the camera's distance in its frame (right, up,
        back)."""
        dist = float(np.linalg.norm(np.subtract(self.camera.target, self.camera.eye)))
        frame = self.camera.view_matrix()[:3, :3].T    # columns: right, up, back
        self.light_position = self.light_position + frame @ (np.array([dx, dy, dz]) * 0.1 * dist)
        self.dirty = True
