"""The previewer's window: GLFW (the ``preview`` extra) with an OpenGL 3.3 core context."""
from __future__ import annotations

import os
import sys

from ..errors import UnavailableError
from ..optional import optional_import, require

glfw = optional_import("glfw", extra="preview", needed_by="glsynth preview")

NO_DISPLAY = ("glsynth preview needs a display: {reason}. On a machine without a screen run "
              "it under a virtual X server, e.g. `xvfb-run -a glsynth preview ...` (Debian "
              "package xvfb), or render offscreen with `glsynth generate` (EGL/OSMesa, no "
              "display needed).")


def open_window(width, height, title="glsynth preview", visible=True):
    """A GLFW window with a current OpenGL 3.3 core context; raises UnavailableError
    naming the problem when there is no display or no such context, and
    MissingDependencyError without glfw."""
    require(glfw)
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
