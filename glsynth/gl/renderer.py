"""The moderngl renderer: G-buffer, Phong shading (optionally supersampled) and exact
integer label passes.

Meshes and textures are uploaded once (cached per object) and rendered many times;
framebuffers are created once per size. ``render`` runs only the requested passes and
reads each requested buffer back once. Returned arrays have row 0 at the top.
"""
from __future__ import annotations

import enum
import logging
import weakref
from dataclasses import dataclass

import cv2
import moderngl
import numpy as np

from ..assets.detail import COARSE_CREASE_SCALE, FLAKE_PATCH_SCALE, MACRO_SCALE, MACRO_WEIGHT, XEROSIS_CODES
from ..assets.hairflow import t_scale_at_corners
from ..camera import Camera
from ..errors import InputError
from ..lighting import FALLOFF_NEAREST, Material, PointLight, check_lights
from ..mesh import Mesh
from ..resources import shader_source, with_defines
from .context import UnlockedGL, create_context, default_backend

log = logging.getLogger(__name__)

PASSES = ("gbuffer", "rgb", "labels")
GBUFFER_LAYERS = ("face_id", "depth", "bary", "uv")
MAX_LABEL_MAPS = 4  # one four-channel uint16 target
# texture units: 0 colour, 1 shadow map, 2-5 label maps, then the skin shading's
# parameter map, relief tile, hair tile, crease tile and (after the decals') mesoscale and
# flake tiles
SKIN_UNITS = (6, 7, 8, 9, 15, 16)
# lesion decals (shaders/decal.glsl): region map, per-decal info, colour, aux, ids
DECAL_UNITS = {"u_decal_region": 10, "u_decal_info": 11, "u_decal_colour": 12, "u_decal_aux": 13,
               "u_decal_ids": 14}
MAX_SUPERSAMPLE = 8


# ---- what the framebuffer and program caches are keyed by ----------------------------
class Target(enum.Enum):
    """A framebuffer layout (besides ``GBuffer`` and ``Msaa``), cached per size."""
    LABELS = "labels"      # four uint16 label channels + depth
    RGB = "rgb"            # float32 RGBA texture + depth: the shading pass
    RGB8 = "rgb8"          # unorm8 RGBA + depth: shading read back as rgba8
    RESOLVE = "resolve"    # float32 RGBA: the k x k supersampling downsample
    RESOLVE8 = "resolve8"  # unorm8 RGBA: the same, read back as rgba8
    DEPTH = "depth"        # depth only, read back (``Renderer.depth``)
    SHADOW = "shadow"      # depth texture sampled with comparison (shadow maps)


@dataclass(frozen=True)
class GBuffer:
    """The G-buffer framebuffer: face id and depth, the barycentric and UV targets
    unless ``bary_uv`` is False, then the label maps when ``labels``."""
    labels: bool = False
    bary_uv: bool = True


@dataclass(frozen=True)
class Msaa:
    """A multisampled unorm8 RGBA framebuffer (+ depth) that the shading draws into."""
    samples: int


@dataclass(frozen=True)
class GBufferProgram:
    """The program drawing into ``target`` (None: the labels pass alone, labels.frag)
    for a label layout from ``Renderer._bind_labels`` (None: without labels)."""
    target: GBuffer | None
    label_layout: tuple | None = None


@dataclass(frozen=True)
class PhongProgram:
    """The Phong shading program for a light count, with or without shadows and decals."""
    n_lights: int
    shadows: bool
    decals: bool = False


_U8_TO_HALF = (np.arange(256, dtype=np.float32) / 255).astype(np.float16)


def _half_float_texels(texture):
    """uint8 texels as float16 in [0, 1] through OpenCV's 256-entry table look-up (30x
    faster than converting and dividing; no wider temporary, so an 8192^2 texture
    needs no float32 or index copy). The array itself is uploaded (no bytes copy)."""
    return cv2.LUT(np.ascontiguousarray(texture), _U8_TO_HALF.reshape(256, 1))


def _texels(mesh) -> np.ndarray:
    """The colour texture as half floats, with the skin detail weight as alpha (1 without
    one), or where scalp hair covers more than the weight, minus its coverage
    (shaders/skin.frag)."""
    tex = mesh.texture
    skin = mesh.skin
    weight = None if skin is None else skin.weight
    scalp = None if skin is None else skin.scalp_hair
    for name, arr in (("skin detail weight", weight), ("scalp hair coverage", scalp)):
        if arr is not None and np.shape(arr) != tex.shape[:2]:
            raise ValueError(f"{mesh.name}: {name} {np.shape(arr)} does not match the "
                             f"texture {tex.shape[:2]}")
    out = np.empty(tex.shape[:2] + (4,), np.uint8)
    out[..., :3] = tex
    out[..., 3] = 255 if weight is None else weight
    out = _half_float_texels(out)
    if scalp is not None and weight is not None:   # (nothing covers more than 255)
        hair = scalp > weight
        out[..., 3][hair] = -_U8_TO_HALF[scalp[hair]]
    return out


def _set_units(prog, units: dict):
    """Point the program's samplers at their texture units (those it has)."""
    for name, unit in units.items():
        if name in prog:
            prog[name] = unit


def _set_uniforms(prog, values: dict):
    """Set the uniforms the program has (one that cannot change the result may be
    compiled out)."""
    for name, value in values.items():
        if name in prog:
            prog[name].value = value


def _upload_decals(ctx, decals) -> dict:
    """GL textures of a pipeline.decals.Decals: keyed by the sampler names of decal.glsl."""
    n, size = len(decals), decals.size
    info = np.zeros((n, 5, 4), np.float32)
    info[:, :3] = decals.projection
    info[:, 3, :3], info[:, 4, :3] = decals.axes[:, 0], decals.axes[:, 1]
    info[:, 3, 3] = decals.texel
    region = np.ascontiguousarray(decals.region, np.uint16)
    out = {"u_decal_region": ctx.texture((region.shape[1], region.shape[0]), 1, region, dtype="u2"),
           "u_decal_info": ctx.texture((5, n), 4, info, dtype="f4"),
           "u_decal_ids": ctx.texture_array((size, size, n), 1, np.ascontiguousarray(decals.instances),
                                            dtype="u2")}
    for name in ("u_decal_region", "u_decal_info", "u_decal_ids"):
        out[name].filter = (moderngl.NEAREST, moderngl.NEAREST)
    for name, arr in (("u_decal_colour", decals.colour), ("u_decal_aux", decals.aux)):
        # half floats: llvmpipe filters 8-bit textures with 8-bit weights, and in the skin
        # shading the coverage scales the relief and gloss, whose highlight magnifies that
        # error past 5/255 off glsynth.diff
        tex = ctx.texture_array((size, size, n), 4, _half_float_texels(arr.reshape(n * size, size, 4)),
                                dtype="f2")
        tex.build_mipmaps()
        tex.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        tex.repeat_x = tex.repeat_y = False
        out[name] = tex
    return out


def _label_ids(arr: np.ndarray, what: str) -> np.ndarray:
    """Integer (or bool) label ids as uint16, or a ValueError naming ``what``."""
    if arr.dtype == np.bool_:
        arr = arr.astype(np.uint8)
    if not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"{what} must have an integer dtype, got {arr.dtype}")
    if arr.size and (arr.min() < 0 or arr.max() > 65535):
        raise ValueError(f"{what}: label ids must be in [0, 65535], got [{arr.min()}, {arr.max()}]")
    return arr.astype(np.uint16)


class _MeshOnGPU:
    """Unindexed corner buffer of one mesh (3 corners per face, in face order, each
    carrying its whole face: see shaders/face.glsl), with a vertex array per program
    made on first use, and a bounding box per run of ``FACES_PER_CHUNK`` faces for
    frustum culling."""

    # llvmpipe shades every vertex of a draw on the calling thread (~2 ms per 27k-face
    # body draw), though a close-up view shows a fifth of the body. Runs of faces
    # (in the mesh's own order, which keeps face ids and the z order of ties) whose
    # box lies outside the view are not drawn: ~40% of the faces are skipped per
    # generated view; 256 faces per run balances that against the draw calls.
    FACES_PER_CHUNK = 256

    _LAYOUT = {**{f"in_p{k}": "3f" for k in range(3)}, **{f"in_n{k}": "3f" for k in range(3)},
               **{f"in_uv{k}": "2f" for k in range(3)}, "in_plane": "4f"}

    @staticmethod
    def staged(mesh: Mesh) -> dict:
        """The CPU side of an upload (no GL, so any thread may make it): the corner
        buffer, the texture as half floats, and the mesh's cached properties that
        rendering reads (orientation, bounds, per-face edge lengths)."""
        n = len(mesh.faces)
        uv = (mesh.uvs[mesh.face_uvs] if mesh.uvs is not None else np.zeros((n, 3, 2)))
        corners = mesh.vertices[mesh.faces]
        # each face's plane (unit normal, offset), in float64 before rounding: the
        # G-buffer's depth is where a pixel's ray meets it (shaders/gbuffer.frag)
        normals = mesh.face_normals
        offsets = np.einsum("fk,fk->f", normals, corners.mean(1))
        face = np.concatenate([corners.reshape(n, 9), mesh.vertex_normals[mesh.faces].reshape(n, 9),
                               uv.reshape(n, 6), normals, offsets[:, None]], axis=1).astype(np.float32)
        _ = mesh.bounds, mesh.closed_orientation, mesh._face_longest_edge  # for clip planes
        # Half floats: llvmpipe filters 8-bit textures with 8-bit weights (up to ~2/255
        # off the torch path); float textures are filtered in float. Alpha carries the
        # skin shading's detail weight (SkinSurface.weight; 1 without one) or, negated,
        # the scalp hair's coverage (SkinSurface.scalp_hair).
        texels = None if mesh.texture is None else _texels(mesh)
        skin = mesh.skin
        hair = None
        if skin is not None and skin.hair_coords is not None:  # every corner carries its face's
            hc = np.asarray(skin.hair_coords, np.float32)
            t_scale = t_scale_at_corners(mesh.vertices, mesh.faces, hc)
            hair = np.repeat(np.concatenate([hc.reshape(n, 6), t_scale], axis=1), 3, axis=0).tobytes()
        return {"corners": np.repeat(face, 3, axis=0).tobytes(), "count": 3 * n, "texels": texels,
                "chunks": _MeshOnGPU._chunk_boxes(corners), "hair": hair}

    @classmethod
    def _chunk_boxes(cls, corners):
        """(centres, half extents) of the boxes around each run of FACES_PER_CHUNK faces
        (boxes, not spheres: a run is often a long thin strip of a part)."""
        if not len(corners):
            return np.zeros((0, 3)), np.zeros((0, 3))
        starts = np.arange(0, len(corners), cls.FACES_PER_CHUNK)
        lo = np.minimum.reduceat(corners.min(1), starts, axis=0)
        hi = np.maximum.reduceat(corners.max(1), starts, axis=0)
        return (lo + hi) / 2, (hi - lo) / 2

    def visible_ranges(self, planes):
        """(first vertex, vertex count) of the runs of faces whose boxes reach inside
        every one of ``planes`` (rows a, b, c, d: inside where a x + b y + c z + d >= 0);
        neighbours one run apart are drawn together."""
        centres, half = self.chunks
        # a box reaches a plane's inside when its corner farthest along the normal does
        reach = centres @ planes[:, :3].T + planes[:, 3] + half @ np.abs(planes[:, :3]).T
        vis = np.flatnonzero((reach >= 0).all(1))
        if not len(vis):
            return []
        breaks = np.flatnonzero(np.diff(vis) > 2)
        k, n = self.FACES_PER_CHUNK, self.count // 3
        return [(3 * a * k, 3 * (min((b + 1) * k, n) - a * k))
                for a, b in zip(np.r_[vis[0], vis[breaks + 1]], np.r_[vis[breaks], vis[-1]])]

    def __init__(self, ctx, mesh: Mesh, staged=None):
        staged = staged or self.staged(mesh)
        self.ctx = ctx
        self.closed_orientation = mesh.closed_orientation
        self.vbo = ctx.buffer(staged["corners"])
        self.count = staged["count"]
        self.chunks = staged["chunks"]
        self.vaos = {}
        self._corner_labels = {}  # id(vertex label array) -> (array, texture)
        self._clip_planes = {}    # eye -> (near, far)
        self.texture = None
        if mesh.texture is not None:
            h, w = mesh.texture.shape[:2]
            self.texture = ctx.texture((w, h), 4, staged["texels"], dtype="f2", alignment=2)
            self.texture.filter = (moderngl.LINEAR, moderngl.LINEAR)
            self.texture.repeat_x = self.texture.repeat_y = False  # clamp, like grid_sample 'border'
        self.hair_vbo = ctx.buffer(staged["hair"]) if staged.get("hair") else None
        # ambient occlusion at each face's corners (1: none), uploaded when a program needs it
        self._face_occlusion = (np.ones((len(mesh.faces), 3), np.float32) if mesh.occlusion is None
                                else mesh.occlusion[mesh.faces])
        self.occlusion_vbo = None
        self.decals = _upload_decals(ctx, mesh.decals) if getattr(mesh, "decals", None) is not None else None
        self.decal_size = float(mesh.decals.size) if self.decals is not None else 0.0
        self.params = None
        if mesh.skin is not None:
            prm = np.ascontiguousarray(mesh.skin.params, np.uint8)
            self.params = ctx.texture((prm.shape[1], prm.shape[0]), 4, prm.tobytes())
            self.params.filter = (moderngl.LINEAR, moderngl.LINEAR)
            self.params.repeat_x = self.params.repeat_y = False

    def vao(self, name, prog):
        vao = self.vaos.get(name)
        if vao is None:
            # skip unused attributes so that each program reads only what it needs
            attrs = [a for a in self._LAYOUT if a in prog]
            fmt = " ".join(f if a in attrs else f.replace("f", "x4") for a, f in self._LAYOUT.items())
            buffers = [(self.vbo, fmt, *attrs)]
            if "in_h0" in prog:  # hair-flow coordinates (and t's scale) live in a buffer of their own
                scale = "in_ht" in prog
                buffers.append((self.hair_vbo, "2f 2f 2f " + ("3f" if scale else "3x4"),
                                "in_h0", "in_h1", "in_h2", *(("in_ht",) if scale else ())))
            if "in_ao" in prog:  # every corner carries its face's three values
                if self.occlusion_vbo is None:
                    self.occlusion_vbo = self.ctx.buffer(np.repeat(self._face_occlusion, 3, axis=0).tobytes())
                buffers.append((self.occlusion_vbo, "3f", "in_ao"))
            vao = self.vaos[name] = self.ctx.vertex_array(prog, buffers)
        return vao

    def clip_planes(self, mesh: Mesh, camera: Camera) -> tuple:
        """``camera``'s near/far planes for this mesh (``Camera.clip_planes``), kept for
        the last few eye positions: they depend on the eye alone, and a view's passes
        and crops, its light probe and its shadow map share eyes (each new eye measures
        its distance to the surface, ~0.7 ms on a 27k-face body)."""
        if camera.near is not None and camera.far is not None:
            return camera.near, camera.far
        key = tuple(camera.eye)
        planes = self._clip_planes.get(key)
        if planes is None:
            if len(self._clip_planes) >= 8:
                self._clip_planes.pop(next(iter(self._clip_planes)))
            planes = self._clip_planes[key] = camera.clip_planes(
                *mesh.bounds, distance=mesh.distance_to(camera.eye))
        return planes

    def corner_labels(self, vertex_labels: np.ndarray, mesh: Mesh):
        """Texture of ``vertex_labels`` at each face corner (index face * 3 + corner,
        rows of 4096), uploaded once per label array (treated as immutable)."""
        entry = self._corner_labels.get(id(vertex_labels))
        if entry is not None and entry[0] is vertex_labels:
            return entry[1]
        if vertex_labels.shape != (len(mesh.vertices),):
            raise ValueError(f"{mesh.name}: vertex labels must be {len(mesh.vertices)} integers, "
                             f"got shape {vertex_labels.shape}")
        corners = _label_ids(vertex_labels, f"{mesh.name}: vertex labels")[mesh.faces].reshape(-1)
        width = 4096
        data = np.zeros(-(-len(corners) // width) * width, np.uint16)
        data[:len(corners)] = corners
        tex = self.ctx.texture((width, len(data) // width), 1, data.tobytes(), dtype="u2", alignment=2)
        tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        if entry is not None:
            entry[1].release()
        self._corner_labels[id(vertex_labels)] = (vertex_labels, tex)
        return tex

    def release(self):
        for _, tex in self._corner_labels.values():
            tex.release()
        for vao in self.vaos.values():
            vao.release()
        self.vbo.release()
        for obj in (self.texture, self.hair_vbo, self.occlusion_vbo, self.params, *(self.decals or {}).values()):
            if obj is not None:
                obj.release()

    def bind_decals(self):
        """Bind the decal textures to their units (DECAL_UNITS)."""
        for name, unit in DECAL_UNITS.items():
            self.decals[name].use(unit)


class Renderer:
    """Offscreen renderer. Images have the size of the camera they are rendered from;
    ``width`` x ``height`` is the size its framebuffers are first made for.

    backend: 'egl', 'osmesa', 'window' (attach to the current context), or None for
    ``GLSYNTH_GL_BACKEND`` (default 'egl'). ``ctx`` may pass an existing moderngl context.
    """

    frustum_culling = True  # skip runs of faces outside the view (_MeshOnGPU); same images

    def __init__(self, width=512, height=512, backend=None, ctx=None):
        if int(width) < 1 or int(height) < 1:
            raise ValueError(f"render size must be positive, got {width}x{height}")
        self.width, self.height = int(width), int(height)
        backend = (backend or default_backend()).lower()
        self._owns_ctx = ctx is None and backend != "window"  # 'window' attaches to another's
        self.ctx = ctx or create_context(backend)
        with self.ctx:  # a shared context need not be current on this thread
            self._setup()
        self._unlocked = UnlockedGL(self.ctx)

    def _setup(self):
        self.ctx.depth_clamp_range = (0.0, 1.0)  # enables GL_DEPTH_CLAMP (see Camera.clip_planes)
        # G-buffer and label programs (with or without labels, barycentrics and UV; per
        # label layout) and shading programs (per light count) are compiled on first
        # use: _gbuffer_program, _phong
        self.programs = {}
        self.programs["uvspace"] = self.ctx.program(
            vertex_shader=shader_source("uvspace.vert"), fragment_shader=shader_source("gbuffer.frag"))
        self.programs["shadow"] = self.ctx.program(vertex_shader=shader_source("shadow.vert"),
                                                   fragment_shader=shader_source("shadow.frag"))
        self._downsample = self.ctx.program(vertex_shader=shader_source("fullscreen.vert"),
                                            fragment_shader=shader_source("downsample.frag"))
        self._empty_vao = self.ctx.vertex_array(self._downsample, [])
        self._meshes = {}      # id(mesh) -> (weakref(mesh), _MeshOnGPU)
        self._staged = {}      # id(mesh) -> (weakref(mesh), _MeshOnGPU.staged(mesh))
        self._label_tex = {}   # id(array) -> (array, texture)
        self._fbos = {}
        self._tiles = None     # skin detail tiles (_detail_tiles)

    def _gbuffer_program(self, target: GBuffer | None, label_layout=None) -> GBufferProgram:
        """Key of the program for a draw into ``target`` (None: the labels alone) with
        ``label_layout`` = (maps, first per-corner slot, decal slot) from
        ``_bind_labels`` (see labels.glsl), compiled on first use."""
        name = GBufferProgram(target, label_layout)
        if name not in self.programs:
            layout = {} if label_layout is None else dict(zip(("LABEL_MAPS", "LABEL_CORNERS_FROM"),
                                                              label_layout[:2]))
            if label_layout is not None and label_layout[2] >= 0:
                layout["DECAL_SLOT"] = label_layout[2]
            if target is None:
                frag = with_defines(shader_source("labels.frag"), **layout)
            else:
                frag = with_defines(shader_source("gbuffer.frag"), LABELS=int(target.labels),
                                    BARY_UV=int(target.bary_uv), **layout)
            prog = self.ctx.program(vertex_shader=shader_source("mesh.vert"), fragment_shader=frag)
            _set_units(prog, {**{f"u_labels{i}": i + 2 for i in range(MAX_LABEL_MAPS)}, **DECAL_UNITS})
            self.programs[name] = prog
        return name

    def _phong(self, n_lights: int, shadows: bool, decals=False) -> PhongProgram:
        """Key of the shading program for this light count, shadow and decal setting,
        compiled on first use (see phong.frag for why the count is a compile-time
        constant)."""
        name = PhongProgram(n_lights, shadows, decals)
        if name not in self.programs:
            frag = with_defines(shader_source("phong.frag"), NUM_LIGHTS=n_lights, SHADOWS=shadows,
                                DECALS=decals, FALLOFF_NEAREST=float(FALLOFF_NEAREST))
            vert = with_defines(shader_source("mesh.vert"), SHADOWS=shadows)
            prog = self.ctx.program(vertex_shader=vert, fragment_shader=frag)
            _set_units(prog, {"u_shadow_map": 1, **DECAL_UNITS})
            self.programs[name] = prog
        return name

    def _skin(self, n_lights: int, shadows: bool, detail: bool, hair: bool, decals=False) -> tuple:
        """Key of the skin shading program for these settings (skin.frag), compiled on
        first use."""
        key = ("skin", n_lights, shadows, detail, hair, decals)
        if key not in self.programs:
            frag = with_defines(shader_source("skin.frag"), NUM_LIGHTS=n_lights, SHADOWS=shadows,
                                DETAIL=detail, HAIR=hair, DECALS=decals,
                                FALLOFF_NEAREST=float(FALLOFF_NEAREST))
            vert = shader_source("mesh.vert")
            vert = with_defines(vert, SHADOWS=shadows, OCCLUSION=1, **({"HAIR_COORDS": 1} if hair else {}))
            prog = self.ctx.program(vertex_shader=vert, fragment_shader=frag)
            _set_units(prog, {"u_shadow_map": 1, "u_params": SKIN_UNITS[0], "u_relief": SKIN_UNITS[1],
                              "u_hair": SKIN_UNITS[2], "u_crease": SKIN_UNITS[3], "u_meso": SKIN_UNITS[4],
                              "u_flakes": SKIN_UNITS[5],
                              **DECAL_UNITS})
            self.programs[key] = prog
        return key

    def _detail_tiles(self):
        """The relief, hair, crease, mesoscale and flake tiles (glsynth.assets.detail) as repeating, mipmapped
        textures, made on first use; and a 1x1 skin parameter map for meshes without
        a SkinSurface."""
        if self._tiles is None:
            from ..assets.detail import DEFAULT_PARAMS, detail_tiles
            t = detail_tiles()
            out = {}
            for name, img in (("relief", t.relief), ("hair", t.hair), ("crease", t.crease), ("meso", t.meso),
                              ("flakes", t.flakes)):
                tex = self.ctx.texture((img.shape[1], img.shape[0]), img.shape[2], np.ascontiguousarray(img).tobytes(),
                                       dtype="f2" if img.dtype == np.float16 else "f1")
                tex.build_mipmaps()
                # the nearest mip level, filtered bilinearly: half the texel reads of
                # trilinear (six lookups a pixel), and a still image shows no level seams
                tex.filter = (moderngl.LINEAR_MIPMAP_NEAREST, moderngl.LINEAR)
                tex.repeat_x = tex.repeat_y = True
                out[name] = tex
            out["params"] = self.ctx.texture((1, 1), 4, np.asarray(DEFAULT_PARAMS, np.uint8).tobytes())
            out["tiles"] = t
            out["pore_mean"] = float(t.relief[..., 3].astype(np.float64).mean())
            self._tiles = out
        return self._tiles

    @property
    def info(self) -> dict:
        return dict(self.ctx.info)

    # ---- resources --------------------------------------------------------------
    def stage(self, mesh: Mesh):
        """Prepare ``mesh``'s upload on the CPU now, from any thread (the GL upload at
        its first render then only copies): a pipeline loading the next body in a
        helper thread takes ~0.1 s of its first render off the render thread."""
        self._staged[id(mesh)] = (weakref.ref(mesh), _MeshOnGPU.staged(mesh))

    def _gpu_mesh(self, mesh: Mesh) -> _MeshOnGPU:
        entry = self._meshes.get(id(mesh))
        if entry is not None and entry[0]() is mesh:
            return entry[1]
        if entry is not None:
            entry[1].release()
        staged = self._staged.pop(id(mesh), None)
        staged = staged[1] if staged is not None and staged[0]() is mesh else None
        for key in [k for k, (ref, _) in list(self._staged.items()) if ref() is None]:
            self._staged.pop(key, None)  # meshes dropped before their first render
        gpu = _MeshOnGPU(self.ctx, mesh, staged)
        self._meshes[id(mesh)] = (weakref.ref(mesh, self._drop_mesh(id(mesh))), gpu)
        return gpu

    def _drop_mesh(self, key):
        def drop(_ref):
            entry = self._meshes.pop(key, None)
            if entry is not None:
                try:
                    entry[1].release()
                except Exception:  # context may already be gone at interpreter exit
                    pass
        return drop

    def _label_texture(self, labels: np.ndarray, in_use=()):
        """Upload an integer label map once; arrays are treated as immutable (see
        ``invalidate``). The cache is least-recently-used and never evicts a texture in
        ``in_use`` (ids of the maps the current render binds)."""
        entry = self._label_tex.pop(id(labels), None)
        if entry is not None and entry[0] is labels:
            self._label_tex[id(labels)] = entry  # most recently used last
            return entry[1]
        if entry is not None:
            entry[1].release()
        arr = np.asarray(labels)
        if arr.ndim != 2:
            raise ValueError(f"label texture must be a 2D integer array, got shape {arr.shape}")
        data = np.ascontiguousarray(_label_ids(arr, "label texture"))
        tex = self.ctx.texture((arr.shape[1], arr.shape[0]), 1, data.tobytes(), dtype="u2",
                               alignment=2)
        tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        for old in [k for k in self._label_tex if k not in in_use][:max(len(self._label_tex) - 15, 0)]:
            self._label_tex.pop(old)[1].release()
        self._label_tex[id(labels)] = (labels, tex)
        return tex

    def invalidate(self, obj):
        """Forget the GPU copy of a label array or mesh changed in place since it was
        rendered (uploads are cached by object identity)."""
        entry = self._label_tex.pop(id(obj), None)
        if entry is not None:
            entry[1].release()
        entry = self._meshes.pop(id(obj), None)
        if entry is not None:
            entry[1].release()

    def _fbo(self, kind, w, h):
        key = (kind, w, h)
        fbo = self._fbos.pop(key, None)
        if fbo is not None:
            self._fbos[key] = fbo  # most recently used last
            return fbo
        if len(self._fbos) >= 12:  # crops of many sizes: drop the least recently used
            self._release_fbo(self._fbos.pop(next(iter(self._fbos))))
        ctx = self.ctx
        depth = ctx.depth_renderbuffer((w, h))
        if isinstance(kind, GBuffer):  # face id, depth, [barycentrics, UV], [labels]
            colors = [ctx.renderbuffer((w, h), 1, dtype="i4"), ctx.renderbuffer((w, h), 1, dtype="f4")]
            if kind.bary_uv:
                colors += [ctx.renderbuffer((w, h), 4, dtype="f4"), ctx.renderbuffer((w, h), 2, dtype="f4")]
            if kind.labels:
                colors.append(ctx.renderbuffer((w, h), 4, dtype="u2"))
        elif kind is Target.LABELS:
            colors = [ctx.renderbuffer((w, h), 4, dtype="u2")]
        elif kind is Target.RGB:
            colors = [ctx.texture((w, h), 4, dtype="f4")]
        elif kind is Target.DEPTH:  # depth only, read back (see ``depth``)
            colors = []
        elif kind is Target.SHADOW:  # depth only, sampled with comparison + bilinear filtering
            colors, depth = [], ctx.depth_texture((w, h))
            depth.compare_func = "<="
            depth.filter = (moderngl.LINEAR, moderngl.LINEAR)
            depth.repeat_x = depth.repeat_y = False
        elif isinstance(kind, Msaa):
            samples = kind.samples
            # 8-bit samples: 0.5/255 at most off float32 before the resolve averages them
            # (into float32), below the 8-bit image's own rounding; llvmpipe shades into
            # unorm8 on its fast path (512^2 body view with shadows: ~4 core-ms less
            # than half floats)
            colors = [ctx.renderbuffer((w, h), 4, dtype="f1", samples=samples)]
            depth = ctx.depth_renderbuffer((w, h), samples=samples)
        elif kind is Target.RESOLVE:
            colors, depth = [ctx.renderbuffer((w, h), 4, dtype="f4")], None
        elif kind in (Target.RGB8, Target.RESOLVE8):  # 8-bit shading targets read back as rgba8
            colors = [ctx.renderbuffer((w, h), 4, dtype="f1")]
            depth = depth if kind is Target.RGB8 else None
        else:
            raise KeyError(kind)
        fbo = ctx.framebuffer(color_attachments=colors, depth_attachment=depth)
        self._fbos[key] = fbo
        return fbo

    # ---- rendering ----------------------------------------------------------------
    def render(self, mesh: Mesh, camera: Camera, passes=("gbuffer", "rgb"), lights=None,
               material=None, label_texture=None, label_textures=None, supersample=1,
               shadows=False, buffers=None, vertex_labels=None, multisample=0, decal_labels=None):
        """Render ``mesh`` from ``camera``.

        passes: any of 'gbuffer', 'rgb', 'labels'. Returns a dict of numpy arrays
        (H x W = camera.height x camera.width, row 0 at the top):
          gbuffer: face_id int32 (-1 background), bary float32 x3, depth float32
                   (view-space, > 0; -1 background), uv float32 x2
          rgb:     rgb float32 x3 in [0, 1], premultiplied by alpha (background samples
                   are black), alpha float32 (coverage, fractional with supersampling or
                   multisampling); ``shadows=True`` first renders a shadow map from the
                   first light (soft shadows on its diffuse and specular terms). With
                   ``buffers=("rgba8",)`` instead: rgba8, the same premultiplied RGB and
                   coverage as uint8 H x W x 4, resolved and read back at 8 bits (a
                   quarter of the bytes; the float result rounded, up to one level
                   off where a GL resolves MSAA samples differently)
          labels:  labels uint16 (from ``label_texture``) or one uint16 array per name
                   of ``label_textures`` (UV-space maps) and of ``vertex_labels``
                   (per-vertex integer arrays: each pixel takes the label of its face's
                   corner with the largest barycentric weight, as ``vertex_label_image``);
                   at most 4 per call
        ``supersample``: k x k shading samples per pixel, box-filtered (anti-aliases
        edges and texture minification). ``multisample``: MSAA samples per pixel (0 or 1:
        off; 2, 4, ... up to the GL's ``max_samples``): coverage at every sample, shading
        once per pixel, so edges are anti-aliased as well as by 2x2 supersampling at
        little more than the cost of one sample (a 512^2 body view with shadows on
        llvmpipe: ~25 vs ~33 ms; see docs/accuracy.md). Both may be combined.
        ``buffers``: the names above to read back (default: all that the passes make);
        the others are drawn but never copied to memory (face_id is always read with the
        G-buffer, rgb and alpha come together). ``decal_labels``: the name of the label
        map (of ``label_textures``) whose ids the mesh's lesion decals give wherever
        they cover the surface (``Mesh.decals``; outlines at the decals' resolution).
        A mesh with decals shows them in the rgb pass.
        """
        # Another library (pyrender, a GUI toolkit) may have made its own context
        # current since the last call: always draw in ours.
        with self.ctx:
            return self._render(mesh, camera, tuple(passes), lights, material, label_texture,
                                label_textures, supersample, shadows, buffers, vertex_labels,
                                multisample, decal_labels)

    def _render(self, mesh, camera, passes, lights, material, label_texture, label_textures,
                supersample, shadows=False, buffers=None, vertex_labels=None, multisample=0,
                decal_labels=None):
        unknown = set(passes) - set(PASSES)
        if unknown:
            raise ValueError(f"unknown pass(es) {sorted(unknown)}; choose from {PASSES}")
        want = None if buffers is None else set(buffers)
        size = (camera.width, camera.height)  # framebuffers are cached per size
        gpu = self._gpu_mesh(mesh)
        mats = self._matrices(gpu, mesh, camera)
        out = {}
        ctx = self.ctx
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.BLEND)
        labels = layout = None
        if "labels" in passes:
            labels, layout = self._bind_labels(gpu, mesh, label_texture, label_textures, vertex_labels,
                                               decal_labels)
        if want is not None:
            known = set(GBUFFER_LAYERS) | {"rgb", "alpha", "rgba8"} | set(labels or ())
            if want - known:
                raise ValueError(f"unknown buffer(s) {sorted(want - known)}; these passes make "
                                 f"{sorted(known)}")
        # Every draw is issued before the first read-back: llvmpipe rasterises a draw in
        # its threads while this thread shades the next one's vertices, and the shadow
        # map (drawn first) is ready when the shading draw samples it.
        if "rgb" in passes:
            if mesh.texture is None:
                raise ValueError(f"{mesh.name}: the rgb pass needs a texture")
            eight_bit = want is not None and "rgba8" in want
            if eight_bit and {"rgb", "alpha"} & want:
                raise ValueError("ask for rgb and alpha (float32) or rgba8, not both")
            self._check_sampling(supersample, multisample)  # before anything is drawn
            prog = self._shading_program(gpu, mesh, camera, lights, material, shadows)
        if "gbuffer" in passes:  # with the labels in the same draw when both are asked for
            read_gbuffer = self._draw_gbuffer(gpu, mats, size, labels, layout, want)
        elif labels is not None:
            read_labels = self._draw_labels(gpu, mats, labels, layout, size)
        if "rgb" in passes:
            read_rgb = self._draw_rgb(gpu, prog, mats, supersample, size, multisample, eight_bit)
        if "gbuffer" in passes:
            out.update(read_gbuffer())
        elif labels is not None:
            out.update(read_labels())
        if "rgb" in passes:
            out.update(read_rgb())
        return out

    @staticmethod
    def _matrices(gpu, mesh, camera):
        """The view and projection uniforms, and the frustum's side planes for culling
        (no near or far plane: depth clamping draws what lies before the near plane,
        and the far plane lies beyond the mesh)."""
        near, far = gpu.clip_planes(mesh, camera)
        view, proj = camera.view_matrix(), camera.projection_matrix(near, far)
        m = proj @ view  # world -> clip; a side plane is w +- x >= 0 or w +- y >= 0
        planes = np.stack([m[3] + m[0], m[3] - m[0], m[3] + m[1], m[3] - m[1]])
        # the view ray of GL window pixel (x, y) (pixel centres at +0.5, row 0 at the
        # bottom): ((x - cx) / f, (y - (h - cy)) / f, -1), as Camera.pixel_rays
        k = camera.intrinsics()
        f = k[0, 0]
        ray = np.array([1 / f, -k[0, 2] / f, 1 / f, (k[1, 2] - camera.height) / f])
        return {"u_view": view.T.astype("f4").tobytes(), "u_proj": proj.T.astype("f4").tobytes(),
                "u_eye": np.asarray(camera.eye, "f4").tobytes(), "u_pixel_ray": ray.astype("f4").tobytes(),
                "viewproj": m, "frustum": planes}

    SHADOW_SIZE = 1024

    def _shading_program(self, gpu, mesh, camera, lights, material, shadows):
        """The Phong program for these lights, with lights, material, eye, texture and
        (when ``shadows`` and the main light is away from the look-at point) the main
        light's shadow map set up."""
        lights = check_lights([PointLight(camera.eye)] if lights is None else lights)
        material = material or Material()
        target = np.asarray(camera.target)
        shadows = bool(shadows and np.linalg.norm(np.asarray(lights[0].position) - target) >= 1e-9)
        decals = gpu.decals is not None
        if material.model == "skin":
            detail = material.detail
            name = self._skin(len(lights), shadows, detail, detail and gpu.hair_vbo is not None, decals)
        else:
            name = self._phong(len(lights), shadows, decals)
        if decals:
            gpu.bind_decals()
            _set_uniforms(self.programs[name], {"u_decal_size": gpu.decal_size,
                                                "u_pixel_angle": 1.0 / float(camera.intrinsics()[1, 1])})
        if shadows:
            self._shadow_map(gpu, mesh, camera, lights[0], self.programs[name])
        self._set_shading(self.programs[name], gpu, camera, lights, material)
        if material.model == "skin":
            self._set_skin(self.programs[name], gpu, mesh, camera, material)
        return name

    def _set_skin(self, prog, gpu, mesh, camera, material):
        """The skin program's material and (with detail) its textures and scales."""
        values = {"u_roughness": material.roughness, "u_oil": material.oil,
                  "u_relief_amount": material.relief,
                  "u_pixel_angle": 1.0 / float(camera.intrinsics()[1, 1])}
        if "u_relief" in prog:
            tiles = self._detail_tiles()
            t, unit = tiles["tiles"], mesh.skin.unit if mesh.skin is not None else 1.0
            (gpu.params or tiles["params"]).use(SKIN_UNITS[0])
            tiles["relief"].use(SKIN_UNITS[1])
            tiles["hair"].use(SKIN_UNITS[2])
            tiles["crease"].use(SKIN_UNITS[3])
            tiles["meso"].use(SKIN_UNITS[4])
            tiles["flakes"].use(SKIN_UNITS[5])
            values.update(u_relief_period=t.relief_period * unit, u_relief_size=float(t.relief.shape[0]),
                          u_pore_mean=tiles["pore_mean"], u_macro_scale=MACRO_SCALE,
                          u_macro_weight=MACRO_WEIGHT, u_hair_period=t.hair_period * unit,
                          u_hair_size=float(t.hair.shape[0]), u_unit=unit,
                          u_crease_period=t.crease_period * unit, u_crease_size=float(t.crease.shape[0]),
                          u_coarse_crease_scale=COARSE_CREASE_SCALE, u_meso_period=t.meso_period * unit,
                          u_meso_size=float(t.meso.shape[0]), u_xerosis_codes=XEROSIS_CODES / 255.0,
                          u_flake_patch_scale=FLAKE_PATCH_SCALE)
            if mesh.skin is not None:
                values["u_hair_rgb"] = tuple(c / 255.0 for c in mesh.skin.hair_rgb)
                values["u_hair_curl"] = float(mesh.skin.hair_curl)
        _set_uniforms(prog, values)

    def _shadow_map(self, gpu, mesh, camera, light, prog):
        """Render ``light``'s shadow map and point the shading program ``prog`` at it."""
        target = np.asarray(camera.target)
        n = self.SHADOW_SIZE
        light_cam = Camera.look_at(light.position, target, fov_deg=100.0, width=n, height=n)
        mats = self._matrices(gpu, mesh, light_cam)
        fbo = self._fbo(Target.SHADOW, n, n)
        self._draw(gpu, "shadow", fbo, mats)
        fbo.depth_attachment.use(1)
        prog["u_light_viewproj"].write(mats["viewproj"].T.astype("f4").tobytes())
        prog["u_shadow_light"].value = tuple(light.position)
        prog["u_shadow_texel"].value = 2 * np.tan(np.radians(light_cam.fov_deg) / 2) / n

    @staticmethod
    def _set_shading(prog, gpu, camera, lights, material):
        """Lights, material, eye and texture of a Phong program made for len(lights)."""
        material = material or Material()
        for key, attr in (("u_light_pos", "position"), ("u_light_ambient", "ambient"),
                          ("u_light_diffuse", "diffuse"), ("u_light_specular", "specular"),
                          ("u_light_falloff", "falloff_distance"), ("u_light_ground", "ambient_ground"),
                          ("u_light_beam", "beam")):
            if key in prog:  # a term that is zero for every pixel may be compiled out
                prog[key].write(np.array([getattr(l, attr) for l in lights], "f4").tobytes())
        for key, value in (("u_mat_specular", material.specular), ("u_shininess", material.shininess),
                           ("u_wrap", material.wrap), ("u_eye", tuple(camera.eye))):
            if key in prog:
                prog[key].value = value
        gpu.texture.use(0)
        prog["u_texture"].value = 0

    def _read(self, fbo, attachment, components, dtype, np_dtype, window=None, flip=True):
        """One attachment as numpy, row 0 at the top (``flip=False``: as GL stores it,
        row 0 at the bottom); ``window`` = GL (x, y, w, h)."""
        w, h = fbo.size if window is None else window[2:]
        buf = np.empty((h, w, components) if components > 1 else (h, w), dtype=np_dtype)
        self._unlocked.finish()  # wait with the GIL released
        fbo.read_into(buf, viewport=window, components=components, attachment=attachment,
                      dtype=dtype, alignment=1)
        return np.ascontiguousarray(buf[::-1]) if flip else buf

    def _read_labels(self, fbo, attachment, names, want=None) -> dict:
        """The label maps of a four-channel label target, one contiguous array each."""
        names = [(i, n) for i, n in enumerate(names) if want is None or n in want]
        if not names:
            return {}
        raw = self._read(fbo, attachment, 4, "u2", np.uint16, flip=False)
        return {name: np.ascontiguousarray(raw[::-1, :, i]) for i, name in names}

    def _draw_gbuffer(self, gpu, mats, size, labels=None, label_layout=None, want=None):
        """Draw the G-buffer (and labels); returns the function that reads it back."""
        bary_uv = want is None or bool({"bary", "uv"} & want)
        target = GBuffer(labels=labels is not None, bary_uv=bary_uv)
        fbo = self._fbo(target, *size)
        # moderngl clears every attachment with the same value, so the shader writes
        # face id + 1 over a cleared 0; background depth is set to -1 from the face ids.
        name = self._gbuffer_program(target, label_layout)
        _set_uniforms(self.programs[name], {"u_decal_size": gpu.decal_size})
        self._draw(gpu, name, fbo, mats)
        return lambda: self._read_gbuffer(fbo, bary_uv, labels, want)

    def _read_gbuffer(self, fbo, bary_uv, labels, want):
        face = self._read(fbo, 0, 1, "i4", np.int32)
        face -= 1
        out = {"face_id": face}
        if want is None or "depth" in want:
            depth = out["depth"] = self._read(fbo, 1, 1, "f4", np.float32)
            depth[face < 0] = -1.0
        if want is None or "bary" in want:
            out["bary"] = np.ascontiguousarray(self._read(fbo, 2, 4, "f4", np.float32)[..., :3])
        if want is None or "uv" in want:
            out["uv"] = self._read(fbo, 3, 2, "f4", np.float32)
        if labels:
            out.update(self._read_labels(fbo, 4 if bary_uv else 2, labels, want))
        return out

    def _check_sampling(self, supersample, multisample):
        k, n = int(supersample), int(multisample)
        if not 1 <= k <= MAX_SUPERSAMPLE:
            raise ValueError(f"supersample must be in 1..{MAX_SUPERSAMPLE}, got {supersample}")
        if n < 0 or n > max(self.ctx.max_samples, 1) or (n > 1 and n & (n - 1)):
            raise InputError(f"multisample must be 0 or a power of two up to {self.ctx.max_samples} "
                             f"(the most {self.info.get('GL_RENDERER')} supports), got {multisample}")
        return k, n

    def _draw_rgb(self, gpu, prog, mats, supersample, size, multisample=0, eight_bit=False):
        """Draw with the shading program ``prog`` (``_shading_program``) and resolve;
        returns the function that reads the image back."""
        k, n = self._check_sampling(supersample, multisample)
        # 8-bit: resolve (average the samples) straight into unorm8, a quarter of the
        # read-back; the k x k downsample still reads float samples
        fbo = self._fbo(Target.RGB8 if eight_bit and k == 1 else Target.RGB, size[0] * k, size[1] * k)
        if n > 1:  # draw with MSAA, then resolve (average the samples) into the plain target
            msaa = self._fbo(Msaa(n), *fbo.size)
            self._draw(gpu, prog, msaa, mats)
            if self._unlocked.available:  # the GIL released while it waits and copies
                self._unlocked.resolve(fbo, msaa)
            else:
                self.ctx.copy_framebuffer(fbo, msaa)
        else:
            self._draw(gpu, prog, fbo, mats)
        if k > 1:
            src = fbo.color_attachments[0]
            fbo = self._fbo(Target.RESOLVE8 if eight_bit else Target.RESOLVE, *size)
            fbo.use()
            fbo.viewport = (0, 0, *size)
            self.ctx.disable(moderngl.DEPTH_TEST)
            src.use(0)
            self._downsample["u_source"].value = 0
            self._downsample["u_factor"].value = k
            self._empty_vao.render(moderngl.TRIANGLES, vertices=3)
            self.ctx.enable(moderngl.DEPTH_TEST)
        return lambda: self._read_rgb(fbo, eight_bit)

    def _read_rgb(self, fbo, eight_bit):
        if eight_bit:
            return {"rgba8": self._read(fbo, 0, 4, "f1", np.uint8)}
        rgba = self._read(fbo, 0, 4, "f4", np.float32, flip=False)  # flipped by the split
        return {"rgb": np.ascontiguousarray(rgba[::-1, :, :3]), "alpha": np.ascontiguousarray(rgba[::-1, :, 3])}

    def _bind_labels(self, gpu, mesh, label_texture, label_textures, vertex_labels,
                     decal_labels=None) -> tuple:
        """Upload (once) and bind the label maps of a render; returns their names and
        layout (number of maps, first per-vertex slot: those come last, the slot the
        lesion decals give or -1)."""
        if label_textures is None and label_texture is not None:
            label_textures = {"labels": label_texture}
        elif label_texture is not None:
            raise ValueError("pass either label_texture or label_textures, not both")
        items = list((label_textures or {}).items())
        per_vertex = list((vertex_labels or {}).items())
        if not 1 <= len(items) + len(per_vertex) <= MAX_LABEL_MAPS:
            raise ValueError(f"the labels pass takes 1 to {MAX_LABEL_MAPS} label maps "
                             "(label_texture=, label_textures= or vertex_labels=), got "
                             f"{len(items) + len(per_vertex)}")
        in_use = {id(arr) for _, arr in items}
        textures = [self._label_texture(arr, in_use) for _, arr in items]
        textures += [gpu.corner_labels(np.asarray(arr), mesh) for _, arr in per_vertex]
        for i in range(MAX_LABEL_MAPS):  # unused samplers still need a valid texture
            textures[min(i, len(textures) - 1)].use(i + 2)  # units 0, 1: colour, shadow map
        names = [name for name, _ in items + per_vertex]
        slot = -1
        if decal_labels is not None and gpu.decals is not None:
            if decal_labels not in names[:len(items)]:
                raise ValueError(f"decal_labels {decal_labels!r} is not one of the label maps {names}")
            slot = names.index(decal_labels)
            gpu.bind_decals()
        return names, (len(textures), len(items), slot)

    def _draw_labels(self, gpu, mats, names, label_layout, size):
        fbo = self._fbo(Target.LABELS, *size)
        name = self._gbuffer_program(None, label_layout)
        _set_uniforms(self.programs[name], {"u_decal_size": gpu.decal_size})
        self._draw(gpu, name, fbo, mats)
        return lambda: self._read_labels(fbo, 0, names)

    def _draw(self, gpu, prog_name, fbo, mats, clear=(0.0, 0.0, 0.0, 0.0), cull=True):
        """Draw the mesh with a program into ``fbo``. ``cull``: skip the faces turned
        away from the camera when the mesh is closed (``Mesh.closed_orientation``): seen
        from outside a closed surface the nearest face on every ray faces the camera,
        so images are unchanged and llvmpipe rasterises a body about 30% faster. Open
        meshes (scans with holes) draw both sides; a camera inside a closed mesh sees
        through it."""
        prog = self.programs[prog_name]
        for k, v in mats.items():
            if k.startswith("u_") and k in prog:  # not every program reads every uniform
                prog[k].write(v)
        fbo.use()
        fbo.viewport = (0, 0, *fbo.size)
        fbo.clear(*clear, depth=1.0)
        if cull and gpu.closed_orientation:
            self.ctx.enable(moderngl.CULL_FACE)
            self.ctx.cull_face = "back" if gpu.closed_orientation > 0 else "front"
        else:  # whatever another draw or library left enabled
            self.ctx.disable(moderngl.CULL_FACE)
        vao = gpu.vao(prog_name, prog)
        if "frustum" in mats and self.frustum_culling:
            ranges = gpu.visible_ranges(mats["frustum"])
        else:
            ranges = [(0, gpu.count)]
        if self._unlocked.available:
            self._unlocked.draw(vao, ranges)
        else:
            for first, count in ranges:
                vao.render(moderngl.TRIANGLES, vertices=count, first=first)
        self.ctx.disable(moderngl.CULL_FACE)  # full-screen passes (resolve) draw both sides

    def depth(self, mesh: Mesh, camera: Camera) -> np.ndarray:
        """View-space depth (float32 H x W, row 0 at the top, -1 on background) from the
        z-buffer of a depth-only draw: positions only, no colour targets, so about a
        third of the G-buffer's cost, for visibility probes. Relative error about
        ``depth / near * 2**-24`` (the G-buffer's depth is exact: each pixel's ray meets
        its face's plane, see shaders/gbuffer.frag)."""
        with self.ctx:
            gpu = self._gpu_mesh(mesh)
            near, far = gpu.clip_planes(mesh, camera)
            fbo = self._fbo(Target.DEPTH, camera.width, camera.height)
            self.ctx.enable(moderngl.DEPTH_TEST)
            self._draw(gpu, "shadow", fbo, self._matrices(gpu, mesh, camera))
            z = self._read(fbo, -1, 1, "f4", np.float32)  # the depth attachment
        ndc = 2.0 * z - 1.0  # invert the projection's depth mapping (window depth in [0, 1])
        view = (2.0 * near * far / (far + near - ndc * (far - near))).astype(np.float32)
        return np.where(z < 1.0, view, np.float32(-1.0))

    def render_uv_space(self, mesh: Mesh, width: int, height: int, box=None) -> dict:
        """Rasterise ``mesh`` in texture space at ``width`` x ``height`` texels.

        Returns face_id (int32, -1 where no face covers the texel centre) and bary
        (float32 x3) per texel, row 0 = v 1 (the texture's top row). With them a texel's
        3D position is ``bary @ vertices[faces[face_id]]``: the inverse of texturing,
        used to paint textures from 3D and to pull view pixels into texels.
        ``box`` = (x0, y0, x1, y1) texels (x1/y1 exclusive, row 0 at the top): rasterise
        and return only that window (the same values as the full raster's crop).
        """
        if mesh.uvs is None:
            raise ValueError(f"{mesh.name}: mesh has no UVs to rasterise")
        width, height = int(width), int(height)
        x0, y0, x1, y1 = (0, 0, width, height) if box is None else (int(b) for b in box)
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, width), min(y1, height)
        if x1 <= x0 or y1 <= y0:
            raise ValueError(f"UV-space box {box} is empty inside {width}x{height}")
        window = (x0, height - y1, x1 - x0, y1 - y0)  # GL rows count from the bottom
        with self.ctx:
            gpu = self._gpu_mesh(mesh)
            fbo = self._fbo(GBuffer(), width, height)
            self.ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
            fbo.scissor = window
            try:
                self._draw(gpu, "uvspace", fbo, {}, cull=False)  # UV-space winding is arbitrary
            finally:
                fbo.scissor = None
            face = self._read(fbo, 0, 1, "i4", np.int32, window)
            face -= 1
            bary = self._read(fbo, 2, 4, "f4", np.float32, window)[..., :3]
        return {"face_id": face, "bary": np.ascontiguousarray(bary)}

    @staticmethod
    def _release_fbo(fbo):
        for att in list(fbo.color_attachments) + [fbo.depth_attachment]:
            if att is not None:
                att.release()
        fbo.release()

    def release(self):
        for _, gpu in list(self._meshes.values()):
            gpu.release()
        self._meshes.clear()
        for _, tex in self._label_tex.values():
            tex.release()
        self._label_tex.clear()
        for fbo in self._fbos.values():
            self._release_fbo(fbo)
        self._fbos.clear()
        if self._tiles is not None:
            for name in ("relief", "hair", "crease", "meso", "params"):
                self._tiles[name].release()
            self._tiles = None

    def close(self):
        """Release every GL object this renderer made (``release`` and its programs)
        and, when it made its own context, the context (llvmpipe keeps a context's
        textures and framebuffers, ~0.2 GB per built-in body, until then). The
        renderer is unusable afterwards."""
        with self.ctx:
            self.release()
            for obj in [self._empty_vao, self._downsample, *self.programs.values()]:
                obj.release()
            self.programs.clear()
        if self._owns_ctx:
            self.ctx.release()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def vertex_label_image(out: dict, mesh: Mesh, vertex_labels=None) -> np.ndarray:
    """Per-vertex integer labels as an image, exact: each pixel takes the label of the
    face corner with the largest barycentric weight (0 on background). uint8/uint16."""
    labels = mesh.vertex_labels if vertex_labels is None else np.asarray(vertex_labels)
    if labels is None:
        raise ValueError(f"{mesh.name}: mesh has no vertex labels")
    face = out["face_id"]
    fg = face >= 0
    img = np.zeros(face.shape, dtype=labels.dtype)
    corner = np.argmax(out["bary"][fg], axis=1)
    img[fg] = labels[mesh.faces[face[fg], corner]]
    return img
