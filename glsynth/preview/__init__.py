"""``glsynth preview``: an interactive window on the offscreen renderer.

A GLFW window (the ``preview`` extra) with an OpenGL 3.3 core context is made current,
the ordinary ``Renderer`` attaches to it (``backend="window"``) and renders offscreen;
the chosen buffer is uploaded and blitted to the window's default framebuffer.

What it shows, against what ``glsynth generate`` writes:

* RGB: the body shaded as a view is shaded (same shaders and passes, the config's
  ``views`` settings: shading model, multisampling, supersampling, shadows from the
  room light) over black. Not applied: the background behind the body and the camera
  model (``glsynth.pipeline.photo``: defocus, noise, white balance, JPEG...), so it
  equals a sample's ``rgba`` layer, not its ``images/<id>.png``.
* Lights and material are the previewer's own (a room light that follows the camera,
  the paper's Phong terms in the config's shading model) until a view snippet or a
  per-image record gives them (``--camera targets/<id>.json``: that sample's camera,
  room light, flash and material).
* Label buffers come from ``glsynth.pipeline.views.render_view``, as the dataset's do,
  without its rejection rules.

Roles: ``scene`` (what to show, read from the command line or a run folder),
``navigation`` (camera moves), ``buffers`` (false colours), ``window`` (GLFW),
``controls`` (keys and mouse), ``viewer`` (state and drawing), ``cli``.
Keys: ``KEY_HELP`` (printed with ``H``) and docs/preview.md.
"""
from .buffers import BUFFERS, colourise
from .cli import cmd_preview, parse_size, register
from .controls import KEY_HELP
from .navigation import orbit, overview_camera, pan, zoom
from .scene import PreviewScene, StartView, load_run_body, load_scene, parse_view
from .viewer import Viewer, default_material

__all__ = ["BUFFERS", "KEY_HELP", "PreviewScene", "StartView", "Viewer", "cmd_preview", "colourise",
           "default_material", "load_run_body", "load_scene", "orbit", "overview_camera", "pan",
           "parse_size", "parse_view", "register", "zoom"]
