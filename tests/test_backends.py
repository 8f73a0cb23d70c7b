"""Each GL backend works on its own and gives the same pictures."""
import os
import subprocess
import sys

import numpy as np
import pytest

import glsynth as gs
from glsynth.gl.context import GLBackendError, create_context
from shapes import sphere

HERE = os.path.dirname(__file__)


@pytest.mark.skipif(os.environ.get("GLSYNTH_GL_BACKEND") == "osmesa", reason="already on OSMesa")
def test_renderer_suite_passes_under_osmesa():
    env = dict(os.environ, GLSYNTH_GL_BACKEND="osmesa", PYOPENGL_PLATFORM="osmesa")
    files = [os.path.join(HERE, f) for f in ("test_renderer.py", "test_diff.py")]
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *files],
                          env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-2000:]
    assert " passed" in proc.stdout


@pytest.mark.parametrize("backend", ["egl", "osmesa"])
def test_contexts_come_from_moderngls_public_api(backend):
    """Each backend's context is ``moderngl.create_context(context=loader)``: the loader
    stays in ``ctx.extra``, where UnlockedGL finds its GL functions. In a process of its
    own (one backend per process, see gl_context.py)."""
    script = f"""
from glsynth.gl.context import LOADER_KEY, UnlockedGL, create_context
ctx = create_context({backend!r})
assert ctx.version_code >= 330 and UnlockedGL(ctx).available
assert hasattr(ctx.extra[LOADER_KEY], "load_opengl_function")
fbo = ctx.simple_framebuffer((4, 4))
fbo.use()
fbo.clear(0.0, 1.0, 0.0, 1.0)
assert fbo.read(components=3)[:3] == bytes([0, 255, 0]) and ctx.error == "GL_NO_ERROR"
ctx.release()
print("ok")
"""
    env = dict(os.environ, GLSYNTH_GL_BACKEND=backend, PYOPENGL_PLATFORM=backend)
    proc = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0 and proc.stdout.strip() == "ok", proc.stdout + proc.stderr[-3000:]


def test_unknown_backend_is_named():
    with pytest.raises(GLBackendError, match="unknown GL backend 'vulkan'"):
        create_context("vulkan")


def test_env_variable_selects_backend(monkeypatch):
    monkeypatch.setenv("GLSYNTH_GL_BACKEND", "nope")
    with pytest.raises(GLBackendError, match="GLSYNTH_GL_BACKEND"):
        create_context()


def test_missing_library_names_package(monkeypatch):
    import ctypes.util
    from glsynth.gl import context
    monkeypatch.setattr(ctypes.util, "find_library", lambda name: None)
    monkeypatch.setattr(context, "_loadable", lambda name: False)
    with pytest.raises(GLBackendError, match="libegl1 libegl-mesa0 libgl1-mesa-dri"):
        create_context("egl")
    real_cdll = context.ctypes.CDLL

    def no_osmesa(name, *a, **k):
        if "OSMesa" in name:
            raise OSError(f"{name}: cannot open shared object file")
        return real_cdll(name, *a, **k)
    monkeypatch.setattr(context.ctypes, "CDLL", no_osmesa)
    with pytest.raises(GLBackendError, match="libosmesa6"):
        create_context("osmesa")


@pytest.mark.skipif(os.environ.get("GLSYNTH_GL_BACKEND") == "osmesa", reason="compared from the EGL run")
def test_osmesa_and_egl_images_agree(rng):
    """Render in a subprocess with OSMesa and compare with EGL here."""
    seed = int(rng.integers(1 << 30))
    script = f"""
import numpy as np, sys
sys.path.insert(0, {HERE!r})
import glsynth as gs
from glsynth.gl.renderer import Renderer
from shapes import sphere
mesh = sphere(np.random.default_rng({seed}))
cam = gs.Camera.look_at((0.2, 0.3, 1.4), (0, 0, 0), width=96, height=80)
out = Renderer(96, 80, backend="osmesa").render(mesh, cam, passes=("gbuffer", "rgb"))
np.savez(sys.argv[1], **out)
"""
    import tempfile
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "o.npz")
        subprocess.run([sys.executable, "-c", script, path], check=True, timeout=300)
        ref = dict(np.load(path))
    from glsynth.gl.renderer import Renderer
    mesh = sphere(np.random.default_rng(seed))
    cam = gs.Camera.look_at((0.2, 0.3, 1.4), (0, 0, 0), width=96, height=80)
    out = Renderer(96, 80, backend="egl").render(mesh, cam, passes=("gbuffer", "rgb"))
    assert (out["face_id"] == ref["face_id"]).all()
    np.testing.assert_allclose(out["depth"], ref["depth"], rtol=1e-6)
    assert np.abs(out["rgb"] - ref["rgb"]).max() <= 1 / 255
