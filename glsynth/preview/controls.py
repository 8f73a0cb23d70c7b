"""Keys and mouse of the previewer: GLFW events turned into the viewer's actions."""
from __future__ import annotations

import math

from .buffers import BUFFERS
from .navigation import orbit, pan, zoom
from .window import glfw

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
  C               print camera, lights and material as a JSON (= YAML) config snippet
  P               save a screenshot and all targets of the current view (--save-dir)
  H               this help;  Q / Esc quit"""

ORBIT_STEP = math.radians(10)
_ADJUST = {"a": "ambient", "d": "diffuse", "s": "specular", "m": "material_specular", "g": "shininess"}
_ARROWS = {"left": (-1, 0), "right": (1, 0), "up": (0, 1), "down": (0, -1)}


def apply_key(viewer, key: str, shift: bool) -> bool:
    """Do what key ``key`` ('n', '3', 'left', 'pageup', '+'...) asks of ``viewer``;
    False for a key without an action."""
    if key in [str(i + 1) for i in range(len(BUFFERS))]:
        viewer.set_buffer(BUFFERS[int(key) - 1])
    elif key == "b":
        viewer.set_buffer(BUFFERS[(BUFFERS.index(viewer.buffer) + (-1 if shift else 1)) % len(BUFFERS)])
    elif key in _ARROWS:
        dx, dy = _ARROWS[key]
        if shift:
            viewer.move_light(dx, dy, 0)
        else:
            viewer.set_camera(orbit(viewer.camera, dx * ORBIT_STEP, dy * ORBIT_STEP))
    elif key in ("pageup", "pagedown"):
        viewer.move_light(0, 0, -1 if key == "pageup" else 1)
    elif key in ("+", "-"):
        viewer.set_camera(zoom(viewer.camera, 0.8 if key == "+" else 1.25))
    elif key == "r":
        viewer.reset()
    elif key in _ADJUST:
        viewer.adjust(_ADJUST[key], not shift)
    elif key == "n":
        viewer.jump_to_lesion(-1 if shift else 1)
    elif key == "c":
        viewer.print_snippet()
    elif key == "p":
        viewer.save()
    elif key == "h":
        print(KEY_HELP, flush=True)
    elif key in ("q", "escape"):
        viewer.quit()
    else:
        return False
    viewer.dirty = True
    return True


# GLFW key -> our key name (letters and digits map to themselves)
_GLFW_NAMES = {"LEFT": "left", "RIGHT": "right", "UP": "up", "DOWN": "down", "PAGE_UP": "pageup",
               "PAGE_DOWN": "pagedown", "ESCAPE": "escape", "EQUAL": "+", "KP_ADD": "+",
               "MINUS": "-", "KP_SUBTRACT": "-", "TAB": "b"}


def key_name(key: int) -> str | None:
    for gname, ours in _GLFW_NAMES.items():
        if key == getattr(glfw, "KEY_" + gname):
            return ours
    if glfw.KEY_A <= key <= glfw.KEY_Z or glfw.KEY_0 <= key <= glfw.KEY_9:
        return chr(key).lower()
    return None


class Controls:
    """The window's event callbacks: keys by name, left drag orbits, right/middle or
    shift+left drag pans, the wheel zooms, a left click without dragging picks."""

    def __init__(self, viewer):
        self.viewer = viewer
        self.mouse = {"down": None, "moved": False, "last": (0.0, 0.0), "shift": False}

    def attach(self, window):
        glfw.set_key_callback(window, self.on_key)
        glfw.set_mouse_button_callback(window, self.on_mouse_button)
        glfw.set_cursor_pos_callback(window, self.on_cursor)
        glfw.set_scroll_callback(window, self.on_scroll)
        glfw.set_framebuffer_size_callback(window, self.on_resize)

    def on_key(self, win, key, scancode, action, mods):
        if action not in (glfw.PRESS, glfw.REPEAT):
            return
        name = key_name(key)
        if name is not None:
            apply_key(self.viewer, name, bool(mods & glfw.MOD_SHIFT))

    def _to_framebuffer(self, x, y):
        ww, wh = glfw.get_window_size(self.viewer.window)
        w, h = self.viewer.size
        return x * w / max(ww, 1), y * h / max(wh, 1)

    def on_mouse_button(self, win, button, action, mods):
        if action == glfw.PRESS:
            self.mouse.update(down=button, moved=False, last=glfw.get_cursor_pos(win),
                              shift=bool(mods & glfw.MOD_SHIFT))
        elif action == glfw.RELEASE:
            if button == glfw.MOUSE_BUTTON_LEFT and not self.mouse["moved"]:
                self.viewer.pick(*self._to_framebuffer(*glfw.get_cursor_pos(win)))
            self.mouse["down"] = None

    def on_cursor(self, win, x, y):
        m = self.mouse
        if m["down"] is None:
            return
        lx, ly = m["last"]
        dx, dy = self._to_framebuffer(x - lx, y - ly)
        if not m["moved"] and abs(dx) + abs(dy) < 3:
            return
        m["moved"], m["last"] = True, (x, y)
        cam = self.viewer.camera
        if m["down"] == glfw.MOUSE_BUTTON_LEFT and not m["shift"]:
            self.viewer.set_camera(orbit(cam, -dx * 0.01, dy * 0.01))
        else:
            self.viewer.set_camera(pan(cam, dx, dy))

    def on_scroll(self, win, dx, dy):
        self.viewer.set_camera(zoom(self.viewer.camera, 0.9 ** dy))

    def on_resize(self, win, w, h):
        if w >= 1 and h >= 1:
            self.viewer.resize(int(w), int(h))
