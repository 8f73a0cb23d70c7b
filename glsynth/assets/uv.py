"""UV atlases for meshes that have none (xatlas) and vertex colours baked into a texture.

    mesh = ensure_uvs(gs.Mesh.load("scan.ply", require_texture=False), texture_size=1024)

The vertex array and its order never change: xatlas splits vertices along chart seams,
but the split copies live only in the new UV array (``face_uvs`` indexes it, as in an
OBJ file), so per-vertex data such as anatomy labels stays aligned with ``vertices``.
"""
from __future__ import annotations

import logging
import time

import numpy as np
from scipy import ndimage

from ..errors import MeshError
from ..mesh import Mesh
from .skin import extend_raster, uv_raster

log = logging.getLogger(__name__)

DEFAULT_GREY = (180, 180, 180)


def ensure_uvs(mesh: Mesh, texture_size: int = 2048, padding: int = 4) -> Mesh:
    """``mesh`` with UVs and a texture.

    Without UVs, xatlas builds an atlas for a ``texture_size`` square texture with
    ``padding`` texels between charts. Without a texture, ``mesh.vertex_colors`` (V,3)
    uint8 are baked into a ``texture_size`` texture (a uniform grey texture when the
    mesh has no colours). A mesh with both is returned as is.
    """
    if mesh.uvs is not None and mesh.texture is not None:
        return mesh
    texture_size = int(texture_size)
    if texture_size < 16:
        raise ValueError(f"texture_size must be >= 16, got {texture_size}")
    uvs, face_uvs = mesh.uvs, mesh.face_uvs
    if uvs is None:
        uvs, face_uvs = atlas_uvs(mesh, texture_size, padding)
    texture = mesh.texture
    if texture is None:
        if mesh.vertex_colors is None:
            log.info("%s: no texture and no vertex colours; using a grey texture", mesh.name)
            texture = np.empty((texture_size, texture_size, 3), np.uint8)
            texture[:] = DEFAULT_GREY
        else:
            texture = bake_vertex_colors(mesh.faces, uvs, face_uvs, mesh.vertex_colors,
                                         texture_size, name=mesh.name)
    return mesh.copy_with(uvs=uvs, face_uvs=face_uvs, texture=texture)


def atlas_uvs(mesh: Mesh, texture_size: int = 2048, padding: int = 4):
    """xatlas UVs for ``mesh``: (uvs (T,2) float64 in [0,1], face_uvs (F,3) int64),
    face order kept."""
    import xatlas

    t0 = time.perf_counter()
    atlas = xatlas.Atlas()
    atlas.add_mesh(mesh.vertices.astype(np.float32), mesh.faces.astype(np.uint32))
    pack = xatlas.PackOptions()
    pack.resolution = int(texture_size)
    pack.padding = int(padding)
    pack.bilinear = True
    atlas.generate(pack_options=pack)
    if atlas.atlas_count != 1:
        raise MeshError(f"{mesh.name}: xatlas spread the UV charts over {atlas.atlas_count} "
                        "atlases; glsynth needs one texture (try a larger texture_size)")
    vmapping, indices, uvs = atlas.get_mesh(0)
    indices = indices.astype(np.int64)
    # glsynth relies on xatlas keeping the input face order and corner order
    if indices.shape != mesh.faces.shape or not np.array_equal(vmapping[indices], mesh.faces):
        raise MeshError(f"{mesh.name}: xatlas changed the face order; cannot keep per-vertex "
                        "data aligned")
    log.info("%s: xatlas made %d charts (%d UVs for %d vertices, %.0f%% used) in %.1f s",
             mesh.name, atlas.chart_count, len(uvs), len(mesh.vertices),
             100 * atlas.utilization, time.perf_counter() - t0)
    return np.clip(uvs.astype(np.float64), 0.0, 1.0), indices


def bake_vertex_colors(faces, uvs, face_uvs, colors, size: int, dilate: int = 4,
                       name="mesh") -> np.ndarray:
    """A ``size`` x ``size`` RGB uint8 texture (row 0 = v 1) holding the per-vertex
    ``colors`` (V,3) interpolated over each face in UV space.

    Texels up to ``dilate`` texels outside every face continue the nearest face's
    colour gradient (:func:`glsynth.assets.skin.extend_raster`; so bilinear sampling at
    chart borders neither reaches the background nor shows a seam), or where that face
    is a sliver copy the nearest painted texel; texels beyond take the mean colour.
    """
    colors = np.asarray(colors)
    if colors.ndim != 2 or colors.shape[1] < 3:
        raise MeshError(f"{name}: vertex colours must be (V, 3) or (V, 4), got {colors.shape}")
    colors = colors[:, :3].astype(np.float64)
    face_id, bary = uv_raster(uvs, face_uvs, size)
    if not (face_id >= 0).any():
        raise MeshError(f"{name}: no face covers a texel centre of a {size}x{size} texture")
    face_id, bary, _ = extend_raster(face_id, bary, uvs, face_uvs, width=dilate)
    covered = face_id >= 0
    corners = np.asarray(faces)[face_id[covered]]
    texture = np.empty((size, size, 3), np.float64)
    texture[covered] = np.einsum("nk,nkc->nc", bary[covered], colors[corners])
    dist, (rows, cols) = ndimage.distance_transform_edt(~covered, return_indices=True)
    near = ~covered & (dist <= dilate)
    texture[near] = texture[rows[near], cols[near]]
    texture[~covered & ~near] = texture[covered].mean(0)
    return np.clip(np.rint(texture), 0, 255).astype(np.uint8)
