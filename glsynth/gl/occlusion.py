"""Ambient occlusion baked per vertex from depth maps.

The room's ambient light reaches a point from every direction its surface faces, less
those the body itself blocks: the armpit sees mostly arm and chest, the fold under a
breast or buttock, the ear's bowl, the skin between the fingers and thighs see little of
the room. ``bake_occlusion`` measures that share per vertex, once per body: the body's
depth is rendered from many directions (the GL depth-only pass, near-parallel
projection from far away), and a vertex counts as seeing a direction when nothing lies
in front of it in that direction's map. Each direction is weighted by the cosine to the
vertex normal, as diffuse light arriving from it is, so the result is the share of
cosine-weighted ambient light that arrives, 1 in the open and 0 in a closed cavity.
"""
from __future__ import annotations

import hashlib
import io
import logging
import math

import numpy as np

from ..camera import Camera
from ..mesh import Mesh

__all__ = ["bake_occlusion", "cached_occlusion", "sphere_directions", "stored_occlusion"]

log = logging.getLogger(__name__)

# what a body's bake uses (~0.8 s on llvmpipe for a 27k-face body, then cached): an open
# box's floor gets its analytic share within 0.07 (0.12 with 64 directions, whose few
# rays through a narrow opening make a deep fold's share jump between vertices)
DIRECTIONS = 128
MAP_SIZE = 256

# the depth maps are rendered from this many radii of the body away: rays within
# 1/DISTANCE radians of parallel, and depth still resolved to a few micrometres
DISTANCE = 40.0


def sphere_directions(n: int) -> np.ndarray:
    """``n`` unit vectors spread evenly over the sphere (a Fibonacci lattice)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = math.pi * (1.0 + math.sqrt(5.0)) * i
    r = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    return np.stack([r * np.cos(phi), z, r * np.sin(phi)], axis=1)


def bake_occlusion(renderer, mesh: Mesh, directions: int = DIRECTIONS, size: int = MAP_SIZE) -> np.ndarray:
    """Share of the ambient light reaching each vertex of ``mesh`` (float32 (V,), 0..1),
    from ``directions`` depth maps of ``size`` x ``size`` pixels. A mesh with open edges
    or degenerate faces works too (nothing it cannot rasterise blocks light)."""
    if directions < 6:
        raise ValueError(f"ambient occlusion needs at least 6 directions, got {directions}")
    geometry = Mesh(mesh.vertices, mesh.faces, name=f"{mesh.name} (geometry)", require_texture=False)
    lo, hi = geometry.bounds
    centre = (lo + hi) / 2
    radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-9)
    fov = 2.0 * math.degrees(math.atan(1.02 / DISTANCE))
    texel = 2.0 * radius * 1.02 / size                      # a map pixel on the body
    normals = geometry.vertex_normals
    # look up each vertex a texel and a half off its surface, or it occludes itself
    # where the map's pixel, wider than the mesh is curved, holds a nearer part of its
    # own face; the depth then has a texel of slack for the same reason
    probe = geometry.vertices + 1.5 * texel * normals
    seen = np.zeros(len(geometry.vertices))
    weight = np.zeros(len(geometry.vertices))
    for d in sphere_directions(directions):
        cosine = normals @ d
        facing = cosine > 0
        if not facing.any():
            continue
        eye = centre + d * DISTANCE * radius
        up = (0.0, 0.0, 1.0) if abs(d[1]) > 0.9 else (0.0, 1.0, 0.0)
        cam = Camera.look_at(eye, centre, up=up, fov_deg=fov, width=size, height=size,
                             near=(DISTANCE - 1.5) * radius, far=(DISTANCE + 1.5) * radius)
        depth = renderer.depth(geometry, cam)
        p = probe[facing]
        xy = np.floor(cam.project(p)).astype(np.int64)
        inside = (xy >= 0).all(1) & (xy < size).all(1)
        z = (p - eye) @ -d                                  # view depth along the axis
        front = np.full(len(p), np.inf)
        front[inside] = depth[xy[inside, 1], xy[inside, 0]]
        front[front < 0] = np.inf                           # map background: open
        visible = z <= front + texel
        seen[facing] += cosine[facing] * visible
        weight[facing] += cosine[facing]
    occlusion = np.where(weight > 0, seen / np.maximum(weight, 1e-12), 1.0)
    return occlusion.astype(np.float32)


def _cache_path(mesh: Mesh, cache_dir=None):
    from ..assets.bodies import cache_root
    digest = hashlib.sha1()
    for arr in (mesh.vertices, mesh.faces):
        digest.update(np.ascontiguousarray(arr).tobytes())
    digest.update(f"{DIRECTIONS} {MAP_SIZE} {DISTANCE}".encode())
    return cache_root(cache_dir) / "occlusion" / f"{digest.hexdigest()}.npy"


def stored_occlusion(mesh: Mesh, cache_dir=None) -> np.ndarray | None:
    """The occlusion ``cached_occlusion`` baked for this mesh's geometry, or None (no GL:
    any thread may ask)."""
    return _read(_cache_path(mesh, cache_dir), len(mesh.vertices))


def _read(path, n_vertices) -> np.ndarray | None:
    if not path.is_file():
        return None
    try:
        occ = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        log.warning("occlusion cache %s unusable (%s); baking it again", path, exc)
        return None
    if occ.shape != (n_vertices,) or occ.dtype != np.float32 or not np.isfinite(occ).all():
        log.warning("occlusion cache %s holds %s %s, not %d values; baking it again",
                    path, occ.dtype, occ.shape, n_vertices)
        return None
    return occ


def cached_occlusion(renderer, mesh: Mesh, cache_dir=None) -> np.ndarray:
    """``bake_occlusion`` of ``mesh`` at the default settings, kept on disk (under
    glsynth's cache, keyed by the mesh's vertices and faces), so that a body is baked
    once per machine however many runs view it."""
    from ..io.images import write_bytes
    path = _cache_path(mesh, cache_dir)   # (hashes the geometry: once per call)
    occ = _read(path, len(mesh.vertices))
    if occ is not None:
        return occ
    occ = bake_occlusion(renderer, mesh)
    buf = io.BytesIO()
    np.save(buf, occ)
    try:
        write_bytes(path, buf.getbuffer())
    except OSError as exc:
        log.warning("could not cache occlusion for %s: %s", mesh.name, exc)
    return occ
