"""Small meshes with known geometry for the tests."""
import numpy as np
import trimesh

import glsynth as gs
from glsynth.mesh import grid_faces


def random_texture(rng, h=64, w=64):
    return (rng.random((h, w, 3)) * 255).astype(np.uint8)


def plane(rng, size=2.0):
    """A square in the z = 0 plane, normal +Z, UVs spanning [0, 1]."""
    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float) * size / 2
    f = np.array([[0, 1, 2], [0, 2, 3]])
    uv = (v[:, :2] / size) + 0.5
    return gs.Mesh(v, f, uvs=uv, texture=random_texture(rng), name="plane")


def box(rng, extents=(0.6, 0.4, 0.5)):
    b = trimesh.creation.box(extents=extents)
    v = np.asarray(b.vertices)
    uv = (v[:, [0, 1]] - v[:, [0, 1]].min(0)) / np.ptp(v[:, [0, 1]], 0)
    return gs.Mesh(v, b.faces, uvs=uv, texture=random_texture(rng), name="box")


def sphere(rng, radius=0.3, subdivisions=4):
    s = trimesh.creation.icosphere(subdivisions, radius=radius)
    v = np.asarray(s.vertices)
    uv = np.c_[0.5 + 0.5 * v[:, 0] / radius, 0.5 + 0.5 * v[:, 1] / radius]
    return gs.Mesh(v, s.faces, uvs=uv, texture=random_texture(rng), name="sphere")


def textured_view(renderer, rng, shape, max_texture):
    """``shape(rng)`` with a random texture of random size (16 to max_texture texels a
    side), and a camera 0.8-3 away in a random direction, looking near the origin with a
    random field of view: (mesh, texture, camera)."""
    mesh = shape(rng)
    tex = (rng.random((int(rng.integers(16, max_texture)), int(rng.integers(16, max_texture)), 3)) * 255
           ).astype(np.uint8)
    d = rng.normal(size=3)
    eye = d / np.linalg.norm(d) * rng.uniform(0.8, 3.0)
    cam = gs.Camera.look_at(eye, rng.normal(scale=0.05, size=3), width=renderer.width,
                            height=renderer.height, fov_deg=rng.uniform(20, 60))
    return mesh.copy_with(texture=tex), tex, cam


def ray_face_depth(mesh, cam, rows, cols, face_ids):
    """Closed-form depth of the pixel rays hitting the plane of the given faces."""
    o, d = cam.pixel_rays(rows, cols)
    a = mesh.vertices[mesh.faces[face_ids, 0]]
    n = mesh.face_normals[face_ids]
    t = ((a - o) * n).sum(1) / (d * n).sum(1)
    hit = o + d * t[:, None]
    forward = np.asarray(cam.target) - np.asarray(cam.eye)
    forward /= np.linalg.norm(forward)
    return (hit - o) @ forward, hit


def skin_sheet(rng, n=40, tex=1024, blur=6.0, amplitude=60.0, nonskin=0):
    """A body stand-in: a gently curved sheet (a cylinder patch, n x n vertices) with a
    mottled skin texture, as the duck-typed Body the pipeline expects."""
    from types import SimpleNamespace

    import cv2
    u, v = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    theta = (u - 0.5) * 1.2
    verts = np.stack([0.5 * np.sin(theta), v * 0.6, 0.5 * np.cos(theta)], -1).reshape(-1, 3)
    faces = grid_faces(n)
    noise = cv2.GaussianBlur(rng.normal(size=(tex, tex)).astype(np.float32), (0, 0), blur)
    texture = np.clip(np.array([205, 160, 135], np.float32) + amplitude * noise[..., None], 0, 255)
    mesh = gs.Mesh(verts, faces, uvs=np.stack([u, v], -1).reshape(-1, 2),
                   texture=texture.astype(np.uint8), name="sheet")
    return SimpleNamespace(mesh=mesh, nonskin=np.full((tex, tex), nonskin, np.uint8), anatomy=None,
                           nevi=[], meta={})
