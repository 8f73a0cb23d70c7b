"""Triangle meshes with per-face UV indices (OBJ style) and textures.

A vertex may carry several UVs (at texture seams), so UVs have their own array and their
own per-face index array ``face_uvs``, exactly as in an OBJ file. Loading never merges or
reorders vertices: per-vertex data from elsewhere (anatomy labels in file order) stays
aligned.
"""
from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .errors import MeshError

__all__ = ["Mesh", "MeshError", "SkinSurface", "grid_faces"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SkinSurface:
    """What the skin shading's micro-detail needs from a body (shaders/skin.frag).

    params: H x W x 4 uint8 map in the body's UV space: relief, pores, hair density
    (0 none, 0.25 vellus only, up to 1 dense terminal hair), each 0..255, and the skin's
    surface lipids: oiliness or, in the lowest codes, dryness (assets.detail.lipid_codes).
    weight: H x W uint8 detail weight at the colour texture's resolution (255 healthy
    skin, 0 non-skin; uploaded as the colour texture's alpha), or None for 255.
    hair_coords: (F, 3, 2) float32 hair-flow coordinates of each face's corners (scene
    units; +s along the hairs), or None for no hair. hair_rgb: sRGB colour of terminal
    hair. unit: scene units per metre. scalp_hair: H x W uint8 coverage of the hair
    painted as non-skin on the head (0..255, at the colour texture's resolution), shaded
    as a mass of fibres with strands at the pixel's scale, or None for none; hair_curl:
    0 straight .. 1 coily, the course of those strands.
    """
    params: np.ndarray
    weight: np.ndarray | None = None
    hair_coords: np.ndarray | None = None
    hair_rgb: tuple = (60, 45, 35)
    unit: float = 1.0
    scalp_hair: np.ndarray | None = None
    hair_curl: float = 0.2


class Mesh:
    """vertices (V,3) float, faces (F,3) int, uvs (T,2) float, face_uvs (F,3) int,
    texture HxWx3 uint8 (row 0 = top of the image, v = 1 at the top), plus optional
    named extra textures (label maps) in ``textures``, the skin shading's inputs in
    ``skin`` (a SkinSurface), lesion decals in ``decals`` and ``occlusion`` (V,): the
    share of the room's ambient light reaching each vertex (glsynth.gl.occlusion;
    None: all of it), which the skin shading applies.
    """

    def __init__(self, vertices, faces, uvs=None, face_uvs=None, texture=None,
                 textures=None, vertex_labels=None, vertex_colors=None, name="mesh",
                 require_texture=True, skin=None, decals=None, occlusion=None):
        self.name = str(name)
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(faces)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
            raise MeshError(f"{self.name}: vertices must be a non-empty (V, 3) array, got shape {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
            raise MeshError(f"{self.name}: faces must be a non-empty (F, 3) array of triangles, got shape {f.shape}")
        if not np.issubdtype(f.dtype, np.integer):
            raise MeshError(f"{self.name}: faces must be integers, got dtype {f.dtype}")
        bad = ~np.isfinite(v).all(1)
        if bad.any():
            raise MeshError(f"{self.name}: {int(bad.sum())} vertices have NaN or inf coordinates "
                            f"(first at index {int(np.argmax(bad))})")
        if f.min() < 0 or f.max() >= len(v):
            raise MeshError(f"{self.name}: face indices out of range [0, {len(v) - 1}] "
                            f"(min {int(f.min())}, max {int(f.max())})")
        self.vertices, self.faces = v, f.astype(np.int64)

        if uvs is None:
            if require_texture:
                raise MeshError(f"{self.name}: mesh has no UV coordinates; create them with "
                                "glsynth.assets.uv.ensure_uvs (xatlas) or load a textured mesh")
            self.uvs = self.face_uvs = None
        else:
            t = np.asarray(uvs, dtype=np.float64)
            if t.ndim != 2 or t.shape[1] != 2:
                raise MeshError(f"{self.name}: uvs must be (T, 2), got shape {t.shape}")
            if not np.isfinite(t).all():
                raise MeshError(f"{self.name}: UV coordinates contain NaN or inf")
            ft = self.faces if face_uvs is None else np.asarray(face_uvs)
            if ft.shape != self.faces.shape:
                raise MeshError(f"{self.name}: face_uvs must have the shape of faces {self.faces.shape}, got {ft.shape}")
            if ft.min() < 0 or ft.max() >= len(t):
                raise MeshError(f"{self.name}: face_uvs indices out of range [0, {len(t) - 1}]")
            self.uvs, self.face_uvs = t, ft.astype(np.int64)

        if texture is None:
            if require_texture:
                raise MeshError(f"{self.name}: mesh has no texture image")
            self.texture = None
        else:
            self.texture = _as_rgb_texture(texture, self.name)
        self.textures = dict(textures or {})
        self.skin = skin
        self.decals = decals   # pipeline.decals.Decals: lesions at their own resolution
        if skin is not None and skin.hair_coords is not None and \
                np.shape(skin.hair_coords) != (len(self.faces), 3, 2):
            raise MeshError(f"{self.name}: hair_coords must be ({len(self.faces)}, 3, 2), "
                            f"got {np.shape(skin.hair_coords)}")
        self.occlusion = None
        if occlusion is not None:
            occ = np.asarray(occlusion, dtype=np.float32)
            if occ.shape != (len(v),):
                raise MeshError(f"{self.name}: occlusion must be one value per vertex ({len(v)},), "
                                f"got shape {occ.shape}")
            finite = np.isfinite(occ)
            if not (finite.all() and occ.min() >= 0 and occ.max() <= 1):
                span = f"[{occ[finite].min()}, {occ[finite].max()}]" if finite.any() else "none finite"
                raise MeshError(f"{self.name}: occlusion values must be finite and in [0, 1], got "
                                f"{span}, {int((~finite).sum())} NaN or inf")
            self.occlusion = occ
        self.vertex_labels = None if vertex_labels is None else np.asarray(vertex_labels)
        self.vertex_colors = None if vertex_colors is None else np.asarray(vertex_colors)
        if self.vertex_labels is not None and len(self.vertex_labels) != len(v):
            raise MeshError(f"{self.name}: {len(self.vertex_labels)} vertex labels for {len(v)} vertices")
        n_deg = int(self.degenerate_faces.sum())
        if n_deg:
            log.warning("%s: %d of %d faces are degenerate (zero area); they are kept and "
                        "render as nothing", self.name, n_deg, len(self.faces))

    # ---- derived geometry -----------------------------------------------------------
    @cached_property
    def _face_cross(self):
        a, b, c = (self.vertices[self.faces[:, i]] for i in range(3))
        return np.cross(b - a, c - a)

    @cached_property
    def face_areas(self) -> np.ndarray:
        return 0.5 * np.linalg.norm(self._face_cross, axis=1)

    @cached_property
    def degenerate_faces(self) -> np.ndarray:
        """Boolean mask of faces with (numerically) zero area."""
        scale = max(float(np.ptp(self.vertices, axis=0).max()), 1e-30)
        return self.face_areas <= 1e-14 * scale * scale

    @cached_property
    def face_normals(self) -> np.ndarray:
        """Unit face normals (F,3); zero for degenerate faces."""
        n = self._face_cross
        norm = np.linalg.norm(n, axis=1, keepdims=True)
        return np.where(norm > 0, n / np.maximum(norm, 1e-300), 0.0)

    @cached_property
    def vertex_normals(self) -> np.ndarray:
        """Area-weighted smooth vertex normals (V,3); +Y for isolated vertices."""
        acc = np.zeros_like(self.vertices)
        for i in range(3):
            np.add.at(acc, self.faces[:, i], self._face_cross)
        norm = np.linalg.norm(acc, axis=1, keepdims=True)
        out = np.where(norm > 0, acc / np.maximum(norm, 1e-300), 0.0)
        out[norm[:, 0] == 0] = (0.0, 1.0, 0.0)
        return out

    @cached_property
    def closed_orientation(self) -> int:
        """+1 when the mesh is closed with consistently outward-wound faces
        (counter-clockwise seen from outside), -1 when closed and wound inward, 0 otherwise
        (open, non-manifold or degenerate). Closed meshes seen from outside show only
        the faces turned towards the camera, so the renderer may cull the others."""
        f = self.faces
        if (f[:, 0] == f[:, 1]).any() or (f[:, 1] == f[:, 2]).any() or (f[:, 0] == f[:, 2]).any():
            return 0
        nv = len(self.vertices)
        n = np.int64(nv)
        directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        keys = directed[:, 0] * n + directed[:, 1]
        reverse = directed[:, 1] * n + directed[:, 0]
        keys.sort()
        # every directed edge once, and its reverse among them: a closed, consistently
        # oriented 2-manifold (each undirected edge in exactly two faces, opposite ways)
        if (keys[1:] == keys[:-1]).any():
            return 0
        pos = np.searchsorted(keys, reverse)
        if not (keys[np.minimum(pos, len(keys) - 1)] == reverse).all():
            return 0
        # every connected part must enclose a volume with the same sign: one part wound
        # inward would show its far side through its near side when culled
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components
        graph = coo_matrix((np.ones(len(directed)), (directed[:, 0], directed[:, 1])), shape=(nv, nv))
        _, part = connected_components(graph, directed=False)
        a, b, c = (self.vertices[f[:, i]] for i in range(3))
        volumes = np.bincount(part[f[:, 0]], weights=np.einsum("ij,ij->i", a, np.cross(b, c)))
        volumes = volumes[np.unique(part[f[:, 0]])]
        if (volumes > 0).all():
            return 1
        return -1 if (volumes < 0).all() else 0

    @cached_property
    def _face_longest_edge(self) -> np.ndarray:
        v, f = self.vertices, self.faces
        return np.max([np.linalg.norm(v[f[:, i]] - v[f[:, (i + 1) % 3]], axis=1) for i in range(3)], axis=0)

    def distance_to(self, point) -> float:
        """Exact distance from ``point`` to the surface (nearest point of any face).
        Only faces that could beat the nearest vertex are measured exactly: a face is
        no nearer than its nearest corner less its longest edge."""
        from trimesh.triangles import closest_point
        p = np.asarray(point, np.float64).reshape(3)
        corner = np.sqrt(((self.vertices - p) ** 2).sum(1))
        best = float(corner.min())
        # faces with a corner within (longest edge of all) of the best: a cheap superset
        maybe = np.flatnonzero((corner < best + self._face_longest_edge.max())[self.faces].any(1))
        near_faces = maybe[corner[self.faces[maybe]].min(1) - self._face_longest_edge[maybe] < best]
        if len(near_faces):
            tris = self.vertices[self.faces[near_faces]]
            hits = closest_point(tris, np.broadcast_to(p, (len(near_faces), 3)))
            best = min(best, float(np.sqrt(((hits - p) ** 2).sum(1).min())))
        return best

    @cached_property
    def bounds(self):
        return self.vertices.min(0), self.vertices.max(0)

    def copy_with(self, **changes) -> "Mesh":
        """A new Mesh with some arrays replaced (e.g. a blended texture)."""
        args = dict(vertices=self.vertices, faces=self.faces, uvs=self.uvs,
                    face_uvs=self.face_uvs, texture=self.texture, textures=self.textures,
                    vertex_labels=self.vertex_labels, vertex_colors=self.vertex_colors,
                    name=self.name, skin=self.skin, decals=self.decals, occlusion=self.occlusion)
        args.update(changes)
        return Mesh(**args)

    def __repr__(self):
        tex = None if self.texture is None else self.texture.shape
        return (f"Mesh({self.name!r}, vertices={len(self.vertices)}, faces={len(self.faces)}, "
                f"uvs={None if self.uvs is None else len(self.uvs)}, texture={tex})")

    # ---- loading ------------------------------------------------------------------
    @classmethod
    def load(cls, path, texture=None, require_texture=True) -> "Mesh":
        """Load OBJ (own parser: file order kept, per-face UVs), or anything trimesh reads.

        ``texture`` overrides the texture named by the material (path or array).
        """
        from .io.meshfile import load_mesh_arrays
        arrays = load_mesh_arrays(path)
        if texture is not None:
            arrays["texture"] = texture
        if isinstance(arrays.get("texture"), (str, os.PathLike)):
            from .io.images import read_rgb
            arrays["texture"] = read_rgb(arrays["texture"])
        try:
            return cls(name=str(path), require_texture=require_texture, **arrays)
        except MeshError as exc:
            raise MeshError(str(exc)) from None


def grid_faces(n: int) -> np.ndarray:
    """Faces of an n x n grid of vertices numbered row by row: two triangles per cell,
    (k, k+1, k+n+1) and (k, k+n+1, k+n), all turned the same way."""
    idx = np.arange(n * n).reshape(n, n)
    return np.concatenate([np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:]], -1).reshape(-1, 3),
                           np.stack([idx[:-1, :-1], idx[1:, 1:], idx[1:, :-1]], -1).reshape(-1, 3)])


def _as_rgb_texture(tex, name) -> np.ndarray:
    t = np.asarray(tex)
    if t.ndim == 2:
        t = np.repeat(t[..., None], 3, axis=2)
    if t.ndim != 3 or t.shape[2] not in (3, 4):
        raise MeshError(f"{name}: texture must be HxWx3 (RGB), got shape {t.shape}")
    t = t[..., :3]
    if t.dtype != np.uint8:
        if np.issubdtype(t.dtype, np.floating) and np.isfinite(t).all() and t.min() >= 0 and t.max() <= 1:
            t = np.round(t * 255).astype(np.uint8)
        else:
            raise MeshError(f"{name}: texture must be uint8 or float in [0, 1], got {t.dtype}")
    return np.ascontiguousarray(t)
