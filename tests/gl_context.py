"""The tests' GL contexts: one per backend for the whole session, shared by the
``renderer`` fixture (conftest.py) and by tests that need other sizes.

The backend is GLSYNTH_GL_BACKEND (default egl). One process uses one backend: Mesa's
EGL and OSMesa share a dispatch table that libglvnd does not know about, so switching
between them in one thread confuses other libraries' contexts (pyrender's).
"""
import os

GL_BACKEND = os.environ.get("GLSYNTH_GL_BACKEND", "egl")
_renderers = {}


def get_renderer(backend=GL_BACKEND, width=128, height=96):
    """A Renderer of this size on the backend's one context."""
    from glsynth.gl.renderer import Renderer
    key = (backend, width, height)
    if key not in _renderers:
        base = next((r for (b, *_), r in _renderers.items() if b == backend), None)
        ctx = base.ctx if base is not None else None
        _renderers[key] = Renderer(width, height, backend=backend, ctx=ctx)
    return _renderers[key]
