"""Headless OpenGL contexts: EGL (default), OSMesa (fallback) or an existing window.

The backend is chosen by argument, else by the ``GLSYNTH_GL_BACKEND`` environment
variable, else EGL. Every context is OpenGL 3.3 core or newer.

EGL and OSMesa contexts are made by a loader object (glcontext's EGL backend, or
``_OSMesaLoader`` here: glcontext has no OSMesa backend) handed to moderngl's public
``moderngl.create_context(context=loader)``; the loader is kept in ``ctx.extra`` under
``LOADER_KEY``, which is how ``UnlockedGL`` finds GL functions to call itself.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import logging
import os

import glcontext
import moderngl

from ..errors import UnavailableError

log = logging.getLogger(__name__)

BACKENDS = ("egl", "osmesa", "window")
REQUIRED_GL = 330
LOADER_KEY = "glsynth_gl_loader"  # ctx.extra[LOADER_KEY]: the loader of a context made here

# What to install when a backend's library is missing (Debian/Ubuntu package names).
_DEBIAN_HINT = {
    "egl": "libegl1 libegl-mesa0 libgl1-mesa-dri",
    "osmesa": "libosmesa6",
}


class GLBackendError(UnavailableError):
    """No OpenGL context could be created with the requested backend."""


def default_backend() -> str:
    return os.environ.get("GLSYNTH_GL_BACKEND", "egl").strip().lower() or "egl"


def create_context(backend: str | None = None) -> moderngl.Context:
    """Create a moderngl context for ``backend`` ('egl', 'osmesa' or 'window').

    'window' attaches to the OpenGL context current on this thread (e.g. a GLFW window).
    Raises GLBackendError naming the backend, the missing library and the package to
    install when the context cannot be created.
    """
    backend = (backend or default_backend()).lower()
    if backend not in BACKENDS:
        raise GLBackendError(
            f"unknown GL backend {backend!r} (GLSYNTH_GL_BACKEND or argument); "
            f"choose one of {', '.join(BACKENDS)}")
    if backend == "egl":
        ctx = _create_egl()
    elif backend == "osmesa":
        ctx = _create_osmesa()
    else:
        ctx = moderngl.create_context(require=REQUIRED_GL)
    info = ctx.info
    log.info("GL backend %s: GL_RENDERER=%s GL_VERSION=%s", backend,
             info["GL_RENDERER"], info["GL_VERSION"])
    return ctx


class UnlockedGL:
    """The GL calls that wait or work long, called through ctypes, which releases
    Python's GIL for the call.

    moderngl holds the GIL through every call: through the waits in ``read_into`` and
    ``copy_framebuffer`` while llvmpipe's threads rasterise, and through a draw call,
    in which llvmpipe shades the vertices on the calling thread (~20 and ~7 ms per
    generated view). Other Python threads (a pipeline's writer threads) could not run
    meanwhile. ``finish`` waits for the queued work, so that the moderngl call after
    it finds it done. ``available`` is False (``finish`` is then ``ctx.finish``) for a
    context not made by ``create_context`` ('window' and contexts passed in: their
    loader is moderngl's own) or whose loader cannot give the functions."""

    _SIGNATURES = {"glFinish": (), "glUseProgram": ("u",), "glBindVertexArray": ("u",),
                   "glDrawArrays": ("u", "i", "i"), "glBindFramebuffer": ("u", "u"),
                   "glBlitFramebuffer": ("i",) * 8 + ("u", "u")}
    GL_TRIANGLES, GL_READ_FRAMEBUFFER, GL_DRAW_FRAMEBUFFER = 0x0004, 0x8CA8, 0x8CA9
    GL_COLOR_BUFFER_BIT, GL_NEAREST = 0x4000, 0x2600

    def __init__(self, ctx: moderngl.Context):
        loader = ctx.extra.get(LOADER_KEY) if isinstance(ctx.extra, dict) else None
        try:
            address = {name: loader.load_opengl_function(name) for name in self._SIGNATURES}
        except Exception:  # no loader of ours, or one without glcontext's interface
            address = {}
        self.available = bool(address) and all(address.values())
        self.finish = ctx.finish
        if self.available:
            types = {"u": ctypes.c_uint, "i": ctypes.c_int}
            self._gl = {name: ctypes.CFUNCTYPE(None, *(types[t] for t in sig))(address[name])
                        for name, sig in self._SIGNATURES.items()}
            self.finish = self._gl["glFinish"]

    def draw(self, vao: moderngl.VertexArray, ranges):
        """Draw triangles with ``vao`` and its program: (first vertex, count) per range,
        into the bound framebuffer."""
        self._gl["glUseProgram"](vao.program.glo)
        self._gl["glBindVertexArray"](vao.glo)
        for first, count in ranges:
            self._gl["glDrawArrays"](self.GL_TRIANGLES, first, count)

    def resolve(self, dst: moderngl.Framebuffer, src: moderngl.Framebuffer):
        """Average ``src``'s multisampled colour into ``dst`` (same size), as
        ``ctx.copy_framebuffer(dst, src)``; ``dst`` is bound afterwards."""
        w, h = src.size
        self._gl["glBindFramebuffer"](self.GL_READ_FRAMEBUFFER, src.glo)
        self._gl["glBindFramebuffer"](self.GL_DRAW_FRAMEBUFFER, dst.glo)
        self._gl["glBlitFramebuffer"](0, 0, w, h, 0, 0, w, h, self.GL_COLOR_BUFFER_BIT, self.GL_NEAREST)
        dst.use()  # moderngl binds GL_FRAMEBUFFER (both) and knows what is bound


def _create_egl() -> moderngl.Context:
    if ctypes.util.find_library("EGL") is None and not _loadable("libEGL.so.1"):
        raise GLBackendError(
            "GL backend 'egl': libEGL.so.1 not found; install the Debian packages "
            f"'{_DEBIAN_HINT['egl']}' (or your GPU driver's EGL), or set "
            "GLSYNTH_GL_BACKEND=osmesa")
    loader = None
    try:
        # glcontext's documented backend (it reads GLCONTEXT_DEVICE_INDEX: the GPU to use)
        loader = glcontext.get_backend_by_name("egl")(mode="standalone", glversion=REQUIRED_GL)
        return _with_loader(loader)
    except Exception as exc:  # glcontext raises bare Exceptions
        if loader is not None:
            loader.release()
        raise GLBackendError(
            f"GL backend 'egl': could not create an OpenGL {REQUIRED_GL // 100}."
            f"{REQUIRED_GL // 10 % 10} context ({exc}); install '{_DEBIAN_HINT['egl']}' "
            "for Mesa's software EGL, or set GLSYNTH_GL_BACKEND=osmesa") from exc


def _loadable(name: str) -> bool:
    try:
        ctypes.CDLL(name)
        return True
    except OSError:
        return False


# OSMesa constants from GL/osmesa.h
_OSMESA_FORMAT, _OSMESA_RGBA = 0x22, 0x1908
_OSMESA_DEPTH_BITS, _OSMESA_STENCIL_BITS, _OSMESA_ACCUM_BITS = 0x30, 0x31, 0x32
_OSMESA_PROFILE, _OSMESA_CORE_PROFILE = 0x33, 0x34
_OSMESA_MAJOR, _OSMESA_MINOR = 0x36, 0x37
_GL_UNSIGNED_BYTE = 0x1401


class _OSMesaLoader:
    """The loader object moderngl needs: resolves GL functions through OSMesa.

    moderngl's own glcontext package has no OSMesa backend, so we create the context
    with libOSMesa and hand moderngl ``OSMesaGetProcAddress``. Rendering goes to
    framebuffers objects; the 1x1 default buffer only satisfies MakeCurrent.
    """

    def __init__(self):
        name = ctypes.util.find_library("OSMesa") or "libOSMesa.so.8"
        try:
            lib = ctypes.CDLL(name)
        except OSError as exc:
            raise GLBackendError(
                f"GL backend 'osmesa': {name} not found ({exc}); install the Debian "
                f"package '{_DEBIAN_HINT['osmesa']}'") from exc
        lib.OSMesaCreateContextAttribs.restype = ctypes.c_void_p
        lib.OSMesaCreateContextAttribs.argtypes = [ctypes.POINTER(ctypes.c_int), ctypes.c_void_p]
        lib.OSMesaMakeCurrent.restype = ctypes.c_bool
        lib.OSMesaMakeCurrent.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint,
                                          ctypes.c_int, ctypes.c_int]
        lib.OSMesaGetProcAddress.restype = ctypes.c_void_p
        lib.OSMesaGetProcAddress.argtypes = [ctypes.c_char_p]
        lib.OSMesaDestroyContext.argtypes = [ctypes.c_void_p]
        attribs = (ctypes.c_int * 15)(
            _OSMESA_FORMAT, _OSMESA_RGBA, _OSMESA_DEPTH_BITS, 24, _OSMESA_STENCIL_BITS, 8,
            _OSMESA_ACCUM_BITS, 0, _OSMESA_PROFILE, _OSMESA_CORE_PROFILE,
            _OSMESA_MAJOR, REQUIRED_GL // 100, _OSMESA_MINOR, REQUIRED_GL // 10 % 10, 0)
        handle = lib.OSMesaCreateContextAttribs(attribs, None)
        if not handle:
            raise GLBackendError(
                f"GL backend 'osmesa': OSMesaCreateContextAttribs failed for a "
                f"{REQUIRED_GL // 100}.{REQUIRED_GL // 10 % 10} core context; "
                f"install a recent '{_DEBIAN_HINT['osmesa']}'")
        self._lib, self._handle = lib, handle
        self._buffer = ctypes.create_string_buffer(4)
        self.make_current()

    def make_current(self):
        if not self._lib.OSMesaMakeCurrent(self._handle, self._buffer, _GL_UNSIGNED_BYTE, 1, 1):
            raise GLBackendError("GL backend 'osmesa': OSMesaMakeCurrent failed")

    def load_opengl_function(self, name: str) -> int:
        return self._lib.OSMesaGetProcAddress(name.encode()) or 0

    def __enter__(self):
        self.make_current()

    def __exit__(self, *args):
        pass

    def release(self):
        if self._handle:
            self._lib.OSMesaDestroyContext(self._handle)
            self._handle = None


def _create_osmesa() -> moderngl.Context:
    loader = _OSMesaLoader()
    try:
        return _with_loader(loader)
    except Exception as exc:  # moderngl's ValueError for an old GL, or a loader failure
        loader.release()
        raise GLBackendError(f"GL backend 'osmesa': {exc}") from exc


def _with_loader(loader) -> moderngl.Context:
    """The moderngl context of ``loader`` (moderngl calls its ``load_opengl_function``,
    and its ``__enter__``/``__exit__``/``release`` where it has them), at least
    REQUIRED_GL, with the loader in ``ctx.extra``."""
    ctx = moderngl.create_context(require=REQUIRED_GL, context=loader)
    ctx.extra = {LOADER_KEY: loader}
    return ctx
