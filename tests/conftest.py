"""Shared fixtures: one GL context for the whole session, checked for GL errors around
every test (as moderngl's own test-suite does).

The backend is GLSYNTH_GL_BACKEND (default egl). One process uses one backend: Mesa's
EGL and OSMesa share a dispatch table that libglvnd does not know about, so switching
between them in one thread confuses other libraries' contexts (pyrender's).
test_backends.py reruns the renderer tests under OSMesa in a subprocess.
"""
import os

import numpy as np
import pytest

GL_BACKEND = os.environ.get("GLSYNTH_GL_BACKEND", "egl")
# pyrender, the independent reference, on the same kind of context as ours
os.environ.setdefault("PYOPENGL_PLATFORM", GL_BACKEND)
_renderers = {}


def get_renderer(backend, width=128, height=96):
    from glsynth.gl.renderer import Renderer
    key = (backend, width, height)
    if key not in _renderers:
        base = next((r for (b, *_), r in _renderers.items() if b == backend), None)
        ctx = base.ctx if base is not None else None
        _renderers[key] = Renderer(width, height, backend=backend, ctx=ctx)
    return _renderers[key]


@pytest.fixture
def gl_backend():
    return GL_BACKEND


@pytest.fixture
def renderer(gl_backend):
    r = get_renderer(gl_backend)
    r.ctx.error  # clear any stale error flag
    yield r
    assert r.ctx.error == "GL_NO_ERROR"


@pytest.fixture
def rng(request):
    """A fresh random generator per test; the seed is printed on failure and
    GLSYNTH_TEST_SEED replays it."""
    seed = int(os.environ.get("GLSYNTH_TEST_SEED") or int.from_bytes(os.urandom(4), "little"))
    request.node.user_properties.append(("seed", seed))
    print(f"random seed: {seed}")
    return np.random.default_rng(seed)
