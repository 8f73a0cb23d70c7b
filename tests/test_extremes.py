"""Stiff and extreme cases: every one ends in finite, bounded output or in a clear error.

Cameras (w from 0.005 to 100, grazing views, normals along the up vector, w = 0 and a
camera touching the surface), broken geometry (degenerate faces, zero-area UV faces, UVs
outside [0, 1], duplicated vertices, flipped normals), texture sizes from 16^2 to 8192^2,
lesions of 3 pixels and lesions larger than the view, extreme lights, the blend loss at
1e-3 and 1e3 times the paper's weights in float32 and float64, bodies without skin,
lesion and background folders with nothing usable, a run killed while writing the
second body's views, and the "leave out" rules (outputs not requested are not written,
no lesions means no select/blend, nevi layers only with nevi).

Where the GL image can be checked against an independent path it is: the torch twin
``glsynth.diff.shade`` (same Phong terms, grid_sample lookup).
"""
import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
import tracemalloc
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
import torch

import glsynth as gs
from glsynth import diff
from glsynth.pipeline.bodies import TexelGeometry
from shapes import plane, ray_face_depth, skin_sheet, sphere

# ---------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------


def _check_outputs(out):
    """Finite, bounded G-buffer and RGB; depth > 0 exactly on the body, -1 off it."""
    fg = out["face_id"] >= 0
    for k in ("bary", "depth", "uv"):
        if k in out:
            assert np.isfinite(out[k]).all(), f"non-finite {k}"
    if "bary" in out:
        b = out["bary"][fg]
        assert (b >= -1e-4).all() and (b <= 1 + 1e-4).all()
    if "depth" in out:
        assert (out["depth"][fg] > 0).all()
        assert (out["depth"][~fg] == -1).all()
    if "rgb" in out:
        assert np.isfinite(out["rgb"]).all() and np.isfinite(out["alpha"]).all()
        assert out["rgb"].min() >= 0 and out["rgb"].max() <= 1
    return fg


def _gl_vs_torch(r, mesh, cam, lights, material=None, tol=2 / 255, frac=0.99):
    """GL 'rgb' against diff.shade on the same G-buffer; returns the max difference on
    the pixels both cover. Also checks the gradient to the texture is finite."""
    out = r.render(mesh, cam, passes=("gbuffer", "rgb"), lights=lights, material=material)
    fg = _check_outputs(out)
    tex = torch.tensor(mesh.texture / 255.0, dtype=torch.float64, requires_grad=True)
    img = diff.shade(out, mesh, tex, cam, lights=lights, material=material)
    img.sum().backward()
    assert torch.isfinite(img).all() and torch.isfinite(tex.grad).all()
    d = np.abs(img.detach().numpy() - out["rgb"]).max(-1)[fg]
    if fg.any():
        assert (d <= tol).mean() >= frac, f"GL vs torch: {np.quantile(d, 0.99) * 255:.2f}/255 at p99"
    return out, d


def _textured(mesh, rng, size=64):
    return mesh.copy_with(texture=(rng.random((size, size, 3)) * 255).astype(np.uint8))


# ---------------------------------------------------------------------------------
# cameras
# ---------------------------------------------------------------------------------
@pytest.mark.parametrize("w", [0.005, 0.01, 10.0, 100.0])
def test_surface_camera_extreme_distances(renderer, rng, w):
    mesh = sphere(rng, radius=0.4)
    mesh = mesh.copy_with(vertices=mesh.vertices * max(1.0, w / 2))
    normal = rng.normal(size=3)
    normal /= np.linalg.norm(normal)
    point = normal * 0.4 * max(1.0, w / 2) * 0.999  # on the (faceted) sphere, roughly
    cam = gs.Camera.from_surface(point, normal, w, width=renderer.width, height=renderer.height)
    lights = [gs.PointLight(cam.eye)]
    out, _ = _gl_vs_torch(renderer, mesh, cam, lights)
    fg = out["face_id"] >= 0
    assert fg.mean() > 0.05
    # the look-at point is at distance ~w straight ahead
    h, wd = out["depth"].shape
    centre = out["depth"][h // 2 - 1:h // 2 + 1, wd // 2 - 1:wd // 2 + 1]
    assert (centre > 0).all()
    np.testing.assert_allclose(centre, w, rtol=0.05, atol=0.4 * 0.001 * max(1.0, w / 2) + 1e-4)


@pytest.mark.parametrize("w", [0.0, -0.1, float("nan"), float("inf")])
def test_camera_on_or_behind_the_surface_is_a_clear_error(w):
    with pytest.raises(ValueError, match="distance weight w must be > 0"):
        gs.Camera.from_surface((0, 0, 0), (0, 0, 1), w)
    with pytest.raises(ValueError, match="look-at direction"):
        gs.Camera.look_at((1, 2, 3), (1, 2, 3))


@pytest.mark.parametrize("w", [1e-5, 1e-4])
def test_tiny_w_renders_the_surface_under_the_camera(renderer, rng, w):
    mesh = plane(rng)
    cam = gs.Camera.from_surface((0.1, -0.2, 0.0), (0, 0, 1), w, width=renderer.width,
                                 height=renderer.height)
    out, _ = _gl_vs_torch(renderer, mesh, cam, [gs.PointLight(cam.eye)])
    assert (out["face_id"] >= 0).all(), "the plane fills the view of a camera touching it"
    np.testing.assert_allclose(out["depth"], w, rtol=1e-3)


def test_w_far_below_the_near_plane_floor_renders_fully_or_raises(renderer, rng):
    mesh = plane(rng)
    try:
        cam = gs.Camera.from_surface((0.1, -0.2, 0.0), (0, 0, 1), 1e-7, width=renderer.width,
                                     height=renderer.height)
        out = renderer.render(mesh, cam, passes=("gbuffer",))
    except ValueError as exc:
        assert "w" in str(exc) or "distance" in str(exc)
        return
    assert (out["face_id"] >= 0).all(), f"{(out['face_id'] < 0).mean():.0%} of the view lost"


@pytest.mark.parametrize("angle_deg", [85.0, 89.0, 89.9])
def test_grazing_views(renderer, rng, angle_deg):
    """Camera direction almost in the surface plane (n . view ~ cos(angle))."""
    mesh = plane(rng, size=4.0)
    a = np.radians(angle_deg)
    direction = np.array([np.sin(a), 0.0, np.cos(a)])
    cam = gs.Camera.from_surface((0, 0, 0), direction, 0.5, width=renderer.width, height=renderer.height)
    out, d = _gl_vs_torch(renderer, mesh, cam, [gs.PointLight(cam.eye)], tol=4 / 255, frac=0.97)
    assert (out["face_id"] >= 0).any()
    # depth is exact even at grazing incidence: closed form for the z = 0 plane
    rows, cols = np.nonzero(out["face_id"] >= 0)
    o, dirs = cam.pixel_rays(rows, cols)
    t = -o[:, 2] / dirs[:, 2]
    fwd = np.subtract(cam.target, cam.eye)
    fwd /= np.linalg.norm(fwd)
    expected = t * (dirs @ fwd)
    rel = np.abs(out["depth"][rows, cols] - expected) / expected
    assert np.quantile(rel, 0.99) < 1e-3


@pytest.mark.parametrize("ratio", [1e4, 1e5])
@pytest.mark.parametrize("w", [0.005, 0.1, 10.0, 100.0])
def test_depth_exact_on_faces_far_larger_than_w(renderer, rng, w, ratio):
    """A tilted square of two faces ``ratio`` times w wide, seen from w near its middle
    (a wall or floor a camera almost touches): its corners lie 1e4-1e5 times farther
    than the surface under the camera. Depth against the closed form of each pixel's
    ray meeting the plane (float64): interpolating the corners' depths lost up to 4
    digits here (relative error 1e-3)."""
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    base = plane(rng, size=ratio * w)
    origin = rng.normal(size=3) * 0.3
    mesh = base.copy_with(vertices=base.vertices @ q.T + origin)
    point = origin + q @ np.r_[rng.uniform(-0.3, 0.3, 2) * min(w, 1.0), 0.0]
    # tilted by at most ~37 degrees: the camera stays w cos(tilt) >= 0.8 w off the plane,
    # above the renderer's limit of 5e-6 of the depth range (up to ~0.7 ratio x w here);
    # steeper tilts at w = 0.005, ratio 1e5 fell below it and rightly raised
    normal = q[:, 2] + rng.normal(scale=0.3, size=3)
    normal = normal / np.linalg.norm(normal)
    normal = normal if normal @ q[:, 2] > 0.8 else q[:, 2]
    cam = gs.Camera.from_surface(point, normal, w, width=renderer.width, height=renderer.height,
                                 fov_deg=rng.uniform(20, 60))
    out, _ = _gl_vs_torch(renderer, mesh, cam, [gs.PointLight(cam.eye)])
    rows, cols = np.nonzero(out["face_id"] >= 0)
    assert len(rows) > 0.5 * out["face_id"].size
    expected, _ = ray_face_depth(mesh, cam, rows, cols, out["face_id"][rows, cols])
    rel = np.abs(out["depth"][rows, cols] - expected) / expected
    assert rel.max() <= 1e-4, f"relative depth error p99 {np.quantile(rel, 0.99):.1e} max {rel.max():.1e}"


@pytest.mark.parametrize("normal", [(0, 1, 0), (0, -1, 0), (1e-9, 1, 0), (0, 1, 1e-8)])
def test_normal_parallel_to_up(renderer, rng, normal):
    """A horizontal surface seen from straight above or below: the +Y up vector is
    parallel to the view, the camera must fall back to another up vector."""
    base = plane(rng)
    rot = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0.0]])  # z = 0 plane -> y = 0 plane
    mesh = base.copy_with(vertices=base.vertices @ rot.T)
    cam = gs.Camera.from_surface((0, 0, 0), normal, 0.7, width=renderer.width, height=renderer.height)
    m = cam.view_matrix()
    assert np.isfinite(m).all()
    np.testing.assert_allclose(m[:3, :3] @ m[:3, :3].T, np.eye(3), atol=1e-9)
    out, _ = _gl_vs_torch(renderer, mesh, cam, [gs.PointLight(cam.eye)])
    assert (out["face_id"] >= 0).mean() > 0.5
    h, w = out["depth"].shape
    np.testing.assert_allclose(out["depth"][h // 2, w // 2], 0.7, rtol=1e-3)
    # the same with an explicit up parallel to the view direction
    cam2 = gs.Camera.from_surface((0, 0, 0), normal, 0.7, width=renderer.width,
                                  height=renderer.height, up=normal)
    assert np.isfinite(cam2.view_matrix()).all()


# ---------------------------------------------------------------------------------
# broken geometry
# ---------------------------------------------------------------------------------
def test_only_degenerate_faces_render_nothing(renderer, rng):
    v = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0.5, 0.5, 0]], float)
    faces = np.array([[0, 1, 2], [3, 3, 3], [0, 0, 1]])  # collinear, a point, a segment
    mesh = gs.Mesh(v, faces, uvs=v[:, :2] / 2, texture=(rng.random((8, 8, 3)) * 255).astype(np.uint8))
    assert mesh.degenerate_faces.all()
    assert np.isfinite(mesh.vertex_normals).all() and np.isfinite(mesh.face_normals).all()
    cam = gs.Camera.look_at((0.5, 0.2, 2), (0.5, 0.2, 0), width=renderer.width, height=renderer.height)
    out, _ = _gl_vs_torch(renderer, mesh, cam, [gs.PointLight(cam.eye)])
    assert (out["face_id"] == -1).all() and (out["alpha"] == 0).all()
    tx = TexelGeometry.of(renderer, mesh)
    assert np.isfinite(tx.points).all() and np.isfinite(tx.normals).all()


def test_near_degenerate_sliver_faces(renderer, rng):
    """Slivers with area ~1e-12 of the mesh: finite normals, barycentrics and shading."""
    base = sphere(rng, subdivisions=2)
    n = len(base.vertices)
    slivers = np.array([[0, 1, n], [2, 3, n + 1]])
    extra = np.vstack([base.vertices[[0, 2]] + 1e-7 * (base.vertices[[1, 3]] - base.vertices[[0, 2]])])
    mesh = gs.Mesh(np.vstack([base.vertices, extra]), np.vstack([base.faces, slivers]),
                   uvs=np.vstack([base.uvs, base.uvs[[0, 2]]]),
                   face_uvs=np.vstack([base.face_uvs, slivers]), texture=base.texture)
    cam = gs.Camera.look_at((0, 0, 1.2), (0, 0, 0), width=renderer.width, height=renderer.height)
    _gl_vs_torch(renderer, mesh, cam, [gs.PointLight(cam.eye)])
    assert np.isfinite(mesh.vertex_normals).all()


def test_zero_area_uv_faces(renderer, rng):
    """Faces whose three UVs coincide show one texel's colour, in GL and torch alike;
    the UV-space raster gives them no texels and finite barycentrics elsewhere."""
    base = sphere(rng, subdivisions=2)
    fuv = base.face_uvs.copy()
    collapse = np.arange(0, len(fuv), 3)
    fuv[collapse] = fuv[collapse, :1]
    mesh = base.copy_with(face_uvs=fuv)
    cam = gs.Camera.look_at((0, 0, 1.2), (0, 0, 0), width=renderer.width, height=renderer.height)
    out, _ = _gl_vs_torch(renderer, mesh, cam, [gs.PointLight(cam.eye, 1.0, 0.0, 0.0)],
                          material=gs.Material(0.0, 1.0))
    raster = renderer.render_uv_space(mesh, 64, 64)
    assert np.isfinite(raster["bary"]).all()
    assert not np.isin(raster["face_id"], collapse).any()


def test_uvs_outside_unit_square(renderer, rng):
    """UVs in [-1, 2]: GL clamps to the edge, grid_sample 'border' does the same."""
    base = plane(rng)
    mesh = base.copy_with(uvs=base.uvs * 3 - 1)
    cam = gs.Camera.look_at((0.05, -0.1, 2.2), (0, 0, 0), width=renderer.width, height=renderer.height)
    out, _ = _gl_vs_torch(renderer, mesh, cam, [gs.PointLight(cam.eye)])
    uv = out["uv"][out["face_id"] >= 0]
    assert uv.min() < -0.2 and uv.max() > 1.2
    tx = TexelGeometry.of(renderer, mesh)
    assert tx.covered.all() and np.isfinite(tx.points).all()


def test_duplicated_vertices_render_like_welded(renderer, rng):
    base = sphere(rng, subdivisions=2)
    corners = base.faces.reshape(-1)
    split = gs.Mesh(base.vertices[corners], np.arange(len(corners)).reshape(-1, 3),
                    uvs=base.uvs, face_uvs=base.face_uvs, texture=base.texture)
    # every vertex also duplicated in place (unused copies): normals stay defined
    doubled = gs.Mesh(np.vstack([base.vertices, base.vertices]), base.faces, uvs=base.uvs,
                      face_uvs=base.face_uvs, texture=base.texture)
    assert np.isfinite(doubled.vertex_normals).all() and np.isfinite(split.vertex_normals).all()
    cam = gs.Camera.look_at((0.2, 0.1, 1.3), (0, 0, 0), width=renderer.width, height=renderer.height)
    a = renderer.render(base, cam, passes=("gbuffer",))
    for m in (split, doubled):
        b, _ = _gl_vs_torch(renderer, m, cam, [gs.PointLight(cam.eye)])
        assert ((a["face_id"] >= 0) == (b["face_id"] >= 0)).mean() > 0.999
        fg = (a["face_id"] >= 0) & (b["face_id"] >= 0)
        np.testing.assert_allclose(b["depth"][fg], a["depth"][fg], rtol=1e-5)


def test_flipped_normals(renderer, rng):
    """Reversed winding: normals point inwards, the lit side gets ambient only; GL and
    torch agree and nothing is culled."""
    base = sphere(rng, subdivisions=2)
    flipped = base.copy_with(faces=base.faces[:, ::-1], face_uvs=base.face_uvs[:, ::-1])
    assert (np.einsum("ij,ij->i", flipped.vertex_normals, flipped.vertices) < 0).all()
    cam = gs.Camera.look_at((0, 0, 1.2), (0, 0, 0), width=renderer.width, height=renderer.height)
    light = [gs.PointLight(cam.eye, ambient=0.3, diffuse=0.7, specular=0.5)]
    a, _ = _gl_vs_torch(renderer, base, cam, light)
    b, _ = _gl_vs_torch(renderer, flipped, cam, light)
    assert ((a["face_id"] >= 0) == (b["face_id"] >= 0)).all()
    fg = b["face_id"] >= 0
    assert b["rgb"][fg].mean() < a["rgb"][fg].mean()


# ---------------------------------------------------------------------------------
# textures
# ---------------------------------------------------------------------------------
@pytest.mark.parametrize("size", [16, 8192])
def test_texture_sizes(renderer, rng, size):
    base = plane(rng)
    if size <= 1024:
        tex = (rng.random((size, size, 3)) * 255).astype(np.uint8)
    else:  # 8192^2 RGB is 192 MiB: a cheap pattern, one render
        ramp = (np.arange(size, dtype=np.uint32) * 255 // (size - 1)).astype(np.uint8)
        tex = np.empty((size, size, 3), np.uint8)
        tex[..., 0] = ramp[None, :]
        tex[..., 1] = ramp[:, None]
        tex[..., 2] = 128
    mesh = base.copy_with(texture=tex)
    cam = gs.Camera.look_at((0.0, 0.0, 2.5), (0, 0, 0), width=renderer.width, height=renderer.height)
    light = [gs.PointLight(cam.eye, 1.0, 0.0, 0.0)]
    tracemalloc.start()
    try:
        out = renderer.render(mesh, cam, passes=("gbuffer", "rgb"), lights=light,
                              material=gs.Material(0.0, 1.0))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    fg = _check_outputs(out)
    assert fg.mean() > 0.5
    # host memory for the upload stays within a few copies of the texture
    assert peak < 6 * tex.nbytes + 64 * 2**20, f"peak {peak / 2**20:.0f} MiB for a {tex.nbytes / 2**20:.0f} MiB texture"
    if size == 8192:  # the ramp is reproduced: red follows u, green follows 1 - v
        uv = out["uv"][fg]
        np.testing.assert_allclose(out["rgb"][fg][:, 0], np.clip(uv[:, 0], 0, 1), atol=2 / 255)
        np.testing.assert_allclose(out["rgb"][fg][:, 1], np.clip(1 - uv[:, 1], 0, 1), atol=2 / 255)
        renderer.invalidate(mesh)  # free the 8192^2 GPU copy now
    else:
        _gl_vs_torch(renderer, mesh, cam, light, material=gs.Material(0.0, 1.0))


def test_label_texture_cache_never_drops_a_texture_in_use(renderer, rng):
    mesh = plane(rng)
    cam = gs.Camera.look_at((0, 0, 2.5), (0, 0, 0), width=renderer.width, height=renderer.height)
    keep = np.full((8, 8), 7, np.uint16)
    for i in range(20):
        fresh = np.full((8, 8), i + 1, np.uint16)
        out = renderer.render(mesh, cam, passes=("labels",), label_textures={"keep": keep, "fresh": fresh})
        assert out["fresh"].max() == i + 1
        assert out["keep"].max() == 7, f"call {i}: the long-lived label texture came back empty"


# ---------------------------------------------------------------------------------
# lights
# ---------------------------------------------------------------------------------
@pytest.mark.parametrize("case", ["zero_ambient", "zero_intensity", "shininess_1", "shininess_1000",
                                  "light_at_look_at", "light_on_surface_far"])
def test_extreme_lights(renderer, rng, case):
    mesh = _textured(sphere(rng, radius=0.4, subdivisions=3), rng)
    n = np.array([0.2, 0.3, 0.93])
    n /= np.linalg.norm(n)
    point = n * 0.4
    cam = gs.Camera.from_surface(point, n, 0.6, width=renderer.width, height=renderer.height)
    mat = gs.Material(0.05, 50.0)
    if case == "zero_ambient":
        light = gs.PointLight(cam.eye, ambient=0.0, diffuse=0.8, specular=0.1)
    elif case == "zero_intensity":
        light = gs.PointLight(cam.eye, ambient=0.0, diffuse=0.0, specular=0.0)
    elif case == "shininess_1":
        light, mat = gs.PointLight(cam.eye, 0.3, 0.5, 1.0), gs.Material(1.0, 1.0)
    elif case == "shininess_1000":
        light, mat = gs.PointLight(cam.eye, 0.3, 0.5, 1.0), gs.Material(1.0, 1000.0)
    elif case == "light_at_look_at":
        light = gs.PointLight(cam.target, 0.3, 0.7, 0.5)
    else:  # a light sitting exactly on a vertex of the surface
        light = gs.PointLight(mesh.vertices[0], 0.3, 0.7, 0.5)
    out, _ = _gl_vs_torch(renderer, mesh, cam, [light], material=mat, tol=2 / 255, frac=0.995)
    fg = out["face_id"] >= 0
    if case == "zero_intensity":
        assert (out["rgb"] == 0).all()
    if case == "zero_ambient":
        assert out["rgb"][fg].max() > 0


def test_invalid_lights_and_materials_are_clear_errors():
    with pytest.raises(ValueError, match="shininess"):
        gs.Material(0.1, 0.0)
    with pytest.raises(ValueError, match="light ambient"):
        gs.PointLight((0, 0, 0), ambient=-1)
    with pytest.raises(ValueError, match="light position"):
        gs.PointLight((0, np.nan, 0))


# ---------------------------------------------------------------------------------
# lesions: pasting extremes, blending at extreme weights and step counts
# ---------------------------------------------------------------------------------
def _sheet(rng, tex=256, nonskin=0):
    return skin_sheet(rng, n=24, tex=tex, blur=3, amplitude=50, nonskin=nonskin)


def _blob_lesion(rng, h=40, w=48, id_="blob"):
    yy, xx = np.mgrid[:h, :w]
    mask = np.hypot((yy - h / 2) / (h / 3), (xx - w / 2) / (w / 3)) < 1
    img = np.empty((h, w, 3), np.uint8)
    img[:] = (165, 118, 100)
    img[mask] = (100, 60, 45)
    return SimpleNamespace(image=img, mask=mask, id=id_, meta={})


@pytest.fixture(scope="module")
def small_scene():
    """A 64^2 placement view on a sheet with one pasted lesion: cheap blend steps."""
    from gl_context import GL_BACKEND, get_renderer
    from glsynth.pipeline.paste import PasteSettings, paste_lesions
    rng = np.random.default_rng(5)
    body = _sheet(rng)
    r = get_renderer(GL_BACKEND, 64, 64)
    tx = TexelGeometry.of(r, body.mesh)
    settings = PasteSettings(view_size=64, w=(0.35, 0.45), size=(0.3, 0.4), max_depth_change=0.05)
    pasted = paste_lesions(r, body, tx, [_blob_lesion(rng)], settings, ("x",), 3)
    return SimpleNamespace(r=r, body=body, tx=tx, pasted=pasted, placement=pasted.placements[0],
                           settings=settings)


def test_three_pixel_lesion_places_or_rejects(small_scene):
    from glsynth.pipeline.paste import PasteSettings, Paster
    from glsynth.pipeline.seeding import rng_for
    mask = np.zeros((9, 9), bool)
    mask[4, 3:6] = True  # three pixels
    img = np.full((9, 9, 3), 120, np.uint8)
    tiny = SimpleNamespace(image=img, mask=mask, id="three-px", meta={})
    sc = small_scene
    for size in ((0.3, 0.4), (0.005, 0.01)):  # scaled up, or kept at a few view pixels
        paster = Paster(sc.r, sc.body, sc.tx, PasteSettings(view_size=64, w=(0.35, 0.45), size=size,
                                                            max_depth_change=0.05, attempts=10))
        p = paster.place(tiny, rng_for(0, "tiny", str(size)))
        if p is not None:
            assert p.texels > 0 and (paster.result.instances == p.instance).sum() >= p.texels
        else:
            assert (paster.result.instances == 0).all()


def test_lesion_larger_than_the_view_is_rejected(small_scene):
    from glsynth.pipeline.paste import PasteError, PasteSettings, Paster, paste_lesions
    from glsynth.pipeline.seeding import rng_for
    sc = small_scene
    big = _blob_lesion(np.random.default_rng(0), 300, 340)
    big.mask[:] = True  # the lesion covers its whole (large) image
    settings = PasteSettings(view_size=64, w=(0.35, 0.45), size=(1.2, 1.5), max_depth_change=0.05,
                             attempts=5)
    t0 = time.perf_counter()
    assert Paster(sc.r, sc.body, sc.tx, settings).place(big, rng_for(0, "big")) is None
    with pytest.raises(PasteError, match="none of 1 lesions found a valid place"):
        paste_lesions(sc.r, sc.body, sc.tx, [big], settings, ("big",), 0)
    assert time.perf_counter() - t0 < 30


def test_spare_lesions_are_tried_when_none_drawn_fits(small_scene, monkeypatch):
    """A body that can hold none of its drawn lesions takes spares in turn until one
    fits; spares stay untouched when a drawn lesion fits; without any that fits, the
    error counts every lesion tried."""
    from glsynth.pipeline import paste as P
    sc = small_scene
    settings = dataclasses.replace(sc.settings, attempts=8)
    place = P.Paster.place
    tried = []

    def place_unless_unfit(self, lesion, rng):     # "unfit" lesions never find a place
        tried.append(lesion.id)
        return None if lesion.id.startswith("unfit") else place(self, lesion, rng)
    monkeypatch.setattr(P.Paster, "place", place_unless_unfit)
    blob = lambda id_: _blob_lesion(np.random.default_rng(1), id_=id_)
    pasted = P.paste_lesions(sc.r, sc.body, sc.tx, [blob("unfit-a"), blob("unfit-b")], settings,
                             ("s",), 0, spares=iter([blob("unfit-c"), blob("fits"), blob("later")]))
    assert [p.lesion_id for p in pasted.placements] == ["fits"]
    assert tried == ["unfit-a", "unfit-b", "unfit-c", "fits"]
    tried.clear()
    pasted = P.paste_lesions(sc.r, sc.body, sc.tx, [blob("first")], settings, ("s",), 0,
                             spares=iter([blob("spare")]))
    assert [p.lesion_id for p in pasted.placements] == ["first"] and tried == ["first"]
    with pytest.raises(P.PasteError, match="none of 3 lesions found a valid place"):
        P.paste_lesions(sc.r, sc.body, sc.tx, [blob("unfit-a")], settings, ("s",), 0,
                        spares=[blob("unfit-b"), blob("unfit-c")])


def test_body_without_skin_is_a_clear_error_without_retrying(small_scene):
    from glsynth.pipeline.paste import PasteError, PasteSettings, paste_lesions
    sc = small_scene
    body = _sheet(np.random.default_rng(1), nonskin=1)
    t0 = time.perf_counter()
    with pytest.raises(PasteError, match="no skin on this body"):
        paste_lesions(sc.r, body, sc.tx, [_blob_lesion(np.random.default_rng(2))],
                      PasteSettings(view_size=64, attempts=10**9), ("noskin",), 0)
    assert time.perf_counter() - t0 < 5


@pytest.mark.parametrize("scale", [1e-3, 1e3])
@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_blend_one_step_at_scaled_weights(small_scene, scale, dtype):
    from glsynth.pipeline.blend import BlendSettings, DeepBlender
    from glsynth.pipeline.features import make_extractor
    from glsynth.pipeline.seeding import rng_for
    sc = small_scene
    ext, _ = make_extractor("filters")
    s = BlendSettings(steps=1, content=2 * scale, style=1e6 * scale, gradient=1e5 * scale,
                      tv=1e-4 * scale, dtype=dtype)
    b = DeepBlender(sc.r, sc.body.mesh, sc.pasted, s, ext)
    losses = b.blend(sc.placement, rng_for(0, "one", dtype, str(scale)))
    assert len(losses) == 1 and all(np.isfinite(v) for v in losses[0].values())
    res = b.result()
    outside = sc.pasted.instances == 0
    assert (res[outside] == sc.pasted.pasted[outside]).all()


def test_blend_zero_steps_keeps_the_pasted_texture(small_scene):
    from glsynth.pipeline.blend import BlendSettings, DeepBlender
    from glsynth.pipeline.features import make_extractor
    from glsynth.pipeline.seeding import rng_for
    sc = small_scene
    b = DeepBlender(sc.r, sc.body.mesh, sc.pasted, BlendSettings(steps=0), make_extractor("filters")[0])
    assert b.blend(sc.placement, rng_for(0, "zero")) == []
    assert (b.result() == sc.pasted.pasted).all()


@pytest.mark.parametrize("scale,dtype,steps", [(1e3, "float32", 2000), (1e-3, "float64", 200)])
def test_blend_many_steps_stays_finite(small_scene, scale, dtype, steps):
    """Many Adam steps with the paper's stiff loss (style 1e6 x scale) on a tiny crop
    (64^2 placement view, ~20 px lesion). 2000 steps for the overflow-prone case
    (float32, weights x 1e3): ~15 ms a step on an idle 2-core CPU, ~30 s. The float64,
    x 1e-3 case runs 200 steps: at lr 0.005 they already move a texel by up to 1 (its
    whole range), and float64 cannot overflow where float32 did not. One torch thread:
    oversubscribed intra-op threads on a shared machine are 10x slower, not faster."""
    from glsynth.pipeline.blend import BlendSettings, DeepBlender
    from glsynth.pipeline.features import make_extractor
    from glsynth.pipeline.seeding import rng_for
    sc = small_scene
    s = BlendSettings(steps=steps, content=2 * scale, style=1e6 * scale, gradient=1e5 * scale,
                      tv=1e-4 * scale, dtype=dtype)
    b = DeepBlender(sc.r, sc.body.mesh, sc.pasted, s, make_extractor("filters")[0])
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        losses = b.blend(sc.placement, rng_for(0, "many"))
    finally:
        torch.set_num_threads(threads)
    assert len(losses) == steps
    totals = np.array([l["total"] for l in losses])
    assert np.isfinite(totals).all()
    for name in ("gradient", "style", "content", "tv"):
        assert np.isfinite([l[name] for l in losses]).all()
    assert totals[-10:].mean() <= 1.5 * totals[:10].mean(), "the blend diverged"
    tb = b.Tb.numpy()
    assert np.isfinite(tb).all() and tb.min() >= 0 and tb.max() <= 1


def test_gram_and_loss_gradients_finite_at_extreme_features():
    """Gram matrices of large activations in float32 at 1e3 x the paper's style weight."""
    from glsynth.pipeline.blend import BlendSettings, blend_loss
    from glsynth.pipeline.features import make_extractor
    ext, _ = make_extractor("filters")
    g = torch.Generator().manual_seed(0)
    b = (torch.rand(1, 3, 96, 96, generator=g) * 1.0).requires_grad_(True)
    v = torch.rand(1, 3, 96, 96, generator=g)
    m = (torch.rand(1, 1, 96, 96, generator=g) > 0.3).float()
    s = BlendSettings(content=2e3, style=1e9, gradient=1e8, tv=1e-1)
    total, terms = blend_loss(b, v, v.flip(-1), v.flip(-2), m, s, ext)
    total.backward()
    assert torch.isfinite(total) and torch.isfinite(b.grad).all()


# ---------------------------------------------------------------------------------
# assets with nothing usable
# ---------------------------------------------------------------------------------
def test_lesion_folder_without_usable_images(tmp_path):
    from glsynth.assets import LesionError, load_lesions
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(LesionError, match="no usable lesions"):
        load_lesions(empty, layout="pairs")
    pairs = tmp_path / "pairs"
    (pairs / "images").mkdir(parents=True)
    (pairs / "masks").mkdir()
    cv2.imwrite(str(pairs / "images" / "a.png"), np.full((20, 20, 3), 128, np.uint8))
    cv2.imwrite(str(pairs / "masks" / "a.png"), np.zeros((20, 20), np.uint8))  # empty mask
    with pytest.raises(LesionError, match=str(pairs)):
        load_lesions(pairs, layout="pairs")


def test_background_folder_of_unreadable_files(tmp_path):
    from glsynth.assets import BackgroundError, load_backgrounds
    for name in ("a.jpg", "b.png", "c.bmp"):
        (tmp_path / name).write_bytes(b"not an image at all" * 3)
    (tmp_path / "d.png").write_bytes(b"")
    with pytest.raises(BackgroundError, match="no readable background images"):
        load_backgrounds(tmp_path)


# ---------------------------------------------------------------------------------
# pipeline: leave-out rules and interrupted runs
# ---------------------------------------------------------------------------------
TINY = ["bodies.count=1", "bodies.texture_size=256", "views.per_body=2", "views.size=64",
        "views.supersample=1", "paste.view_size=128", "backgrounds.count=1", "seed=3",
        "blend.features=filters", "blend.steps=2"]


def test_no_lesions_and_rgb_only_leave_everything_else_out(tmp_path, monkeypatch):
    """lesions.per_body=0: no select/paste/blend work, no feature network; outputs=[rgb]:
    no target images and no label or depth files, and the renderer never shades
    anything it was not asked for."""
    import glsynth.pipeline.blend as blend
    import glsynth.pipeline.features as features
    import glsynth.pipeline.poisson as poisson
    from glsynth.config import load_config
    monkeypatch.setattr(features, "make_extractor", lambda *a, **k: pytest.fail("built a feature network"))
    monkeypatch.setattr(blend, "DeepBlender", lambda *a, **k: pytest.fail("constructed a DeepBlender"))
    monkeypatch.setattr(poisson, "poisson_blend", lambda *a, **k: pytest.fail("ran a Poisson blend"))
    cfg = load_config(None, TINY + ["lesions.per_body=0", "outputs=[rgb]", "blend.method=deep"])
    gs.pipeline.generate(cfg, tmp_path / "rgb")
    out = tmp_path / "rgb"
    assert not list(out.glob("bodies/*/placements.json"))
    assert not list(out.glob("bodies/*/blended.png"))
    imgs = sorted(os.listdir(out / "images"))
    assert len(imgs) == 2
    tgt = sorted(os.listdir(out / "targets"))
    assert tgt and all(n.endswith(".json") for n in tgt), tgt
    man = json.load(open(out / "manifest.json"))
    assert man["blend_features"] == "none"
    for n in tgt:
        meta = json.load(open(out / "targets" / n))
        assert meta["lesions"] == []


def test_a_poisson_run_never_imports_torch(tmp_path):
    """Only the deep blend uses torch; paste, Poisson blend and views leave it out (its
    import is ~1.3 s of every run's start-up). In a fresh interpreter, as a user runs."""
    script = ("import sys\nimport glsynth as gs\nfrom glsynth.config import load_config\n"
              f"cfg = load_config(None, {TINY + ['lesions.per_body=1', 'blend.method=poisson']!r})\n"
              f"gs.pipeline.generate(cfg, {str(tmp_path / 'p')!r})\n"
              "print('torch' in sys.modules)\n")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert list((tmp_path / "p").glob("bodies/*/blended.png")) and proc.stdout.split()[-1] == "False"


def test_labels_only_output_skips_shading(tmp_path, monkeypatch):
    from glsynth.config import load_config
    from glsynth.gl.renderer import Renderer
    seen = []
    orig = Renderer.render

    def spy(self, mesh, camera, passes=("gbuffer", "rgb"), **k):
        seen.append(tuple(passes))
        return orig(self, mesh, camera, passes=passes, **k)
    monkeypatch.setattr(Renderer, "render", spy)
    cfg = load_config(None, TINY + ["lesions.per_body=0", "outputs=[semantic, depth]"])
    gs.pipeline.generate(cfg, tmp_path / "lab")
    out = tmp_path / "lab"
    assert not (out / "images").exists() or not os.listdir(out / "images")
    names = os.listdir(out / "targets")
    assert any(n.endswith("_semantic.png") for n in names) and any(n.endswith("_depth.tiff") for n in names)
    assert not any(n.endswith(("_instances.png", "_anatomy.png")) for n in names)
    assert seen and not any("rgb" in p for p in seen)


def test_nevi_layers_only_with_nevi(small_scene):
    from glsynth.config import ViewsConfig
    from glsynth.pipeline import views as V
    sc = small_scene
    cam = gs.Camera.from_dict(sc.placement.camera)
    scene = V.ViewScene(cam, gs.PointLight(cam.eye), gs.Material(), "surface")
    v = ViewsConfig(size=64, min_skin=0.0)
    seen = []
    orig = sc.r.render

    class Spy:
        def __getattr__(self, k):
            return getattr(sc.r, k)

        def render(self, *a, **k):
            if "labels" in k.get("passes", ()):
                seen.append(sorted(k.get("label_textures", {})))
            return orig(*a, **k)
    body = sc.body
    assert V.nevi_label_map(body) is None
    layers = V.render_view(Spy(), body, body.mesh, sc.pasted.instances, None, scene, v, ["rgb", "semantic"])
    assert "nevi_boxes" not in layers and "nevi" not in seen[-1]
    # a body with one nevus under the lesion's view: the channel appears
    tx0, ty0, tx1, ty1 = sc.placement.texel_box
    with_nevi = SimpleNamespace(**{**vars(body), "nevi": [[max(tx0 - 40, 0), ty0, tx0, ty1]]})
    nevi = V.nevi_label_map(with_nevi)
    assert nevi is not None and nevi.max() == 1
    layers = V.render_view(Spy(), with_nevi, body.mesh, sc.pasted.instances, nevi, scene, v, ["rgb"])
    assert "nevi" in seen[-1] and "nevi_boxes" in layers


def test_views_whose_camera_does_not_see_its_point_are_rejected(small_scene):
    from glsynth.config import ViewsConfig
    from glsynth.pipeline import views as V
    sc = small_scene
    cam = gs.Camera.from_dict(sc.placement.camera)
    v = ViewsConfig(size=64, min_skin=0.0)
    target = np.asarray(cam.target, float)
    forward = (target - np.asarray(cam.eye)) / np.linalg.norm(target - np.asarray(cam.eye))
    seen = V.ViewScene(cam, gs.PointLight(cam.eye), gs.Material(), "surface", point=target)
    assert "semantic" in V.render_view(sc.r, sc.body, sc.body.mesh, sc.pasted.instances, None, seen, v,
                                       ["rgb", "semantic"])
    for point in (target + 0.05 * forward, target - 0.05 * forward):  # behind / before the surface
        hidden = V.ViewScene(cam, gs.PointLight(cam.eye), gs.Material(), "surface", point=point)
        with pytest.raises(V.ViewRejected, match="hidden") as info:
            V.render_view(sc.r, sc.body, sc.body.mesh, sc.pasted.instances, None, hidden, v, ["semantic"])
        assert info.value.reason is V.Rejection.POINT_HIDDEN


def test_views_of_a_body_without_skin_give_up_after_the_attempt_bound(tmp_path, monkeypatch, small_scene):
    """Every view is rejected (no skin): each sample gives up after views.attempts
    tries and nothing is written, instead of retrying forever."""
    import glsynth.pipeline.stages as stages
    from glsynth.config import load_config
    from glsynth.pipeline import views as V
    body = _sheet(np.random.default_rng(4), nonskin=1)
    monkeypatch.setattr(stages, "load_body", lambda cfg, body_id: body)
    cfg = load_config(None, TINY + ["lesions.per_body=0", "views.attempts=3", "views.w=[0.3, 0.5]"])
    stage = stages.Generate2DViews(cfg, tmp_path, renderer=small_scene.r)
    t0 = time.perf_counter()
    rejected = stage.synthesize_views(progress=False)
    assert time.perf_counter() - t0 < 60
    assert sum(rejected.values()) == 2 * 3, rejected
    assert "skin" in rejected and set(rejected) <= {r.value for r in V.Rejection}, rejected
    assert not (tmp_path / "targets").exists() or not os.listdir(tmp_path / "targets")


def test_rejections_are_counted_by_their_reason_not_their_message(tmp_path, monkeypatch, small_scene):
    """The count's key is the exception's reason code, whatever its message says."""
    import glsynth.pipeline.stages as stages
    from glsynth.config import load_config
    from glsynth.errors import GlsynthError
    from glsynth.pipeline import views as V
    sheet = _sheet(np.random.default_rng(4))
    monkeypatch.setattr(stages, "load_body", lambda cfg, body_id: sheet)
    reasons = iter([V.Rejection.TOO_LITTLE_LESION, V.Rejection.LIGHT_BLOCKED] * 10)

    def reject(*a, **k):
        reason = next(reasons)
        raise V.ViewRejected(reason, "0.010 < views.min_lesion 0.5 (see docs < here)")
    monkeypatch.setattr(stages.V, "sample_scene", reject)
    cfg = load_config(None, TINY + ["lesions.per_body=0", "views.attempts=2"])  # 2 views
    rejected = stages.Generate2DViews(cfg, tmp_path, renderer=small_scene.r).synthesize_views(progress=False)
    assert rejected == {"lesion": 2, "light blocked by the body": 2}
    err = V.ViewRejected(V.Rejection.TOO_LITTLE_SKIN, "0.02 < views.min_skin 0.1")
    assert isinstance(err, GlsynthError) and str(err) == "skin: 0.02 < views.min_skin 0.1"


def test_kill_during_second_body_views_then_resume(tmp_path):
    """SIGKILL while the second body's views are being written: no half-written file
    under a final name; --resume completes the run and leaves the first body's samples
    untouched."""
    out = tmp_path / "killed"
    sets = TINY + ["bodies.count=2", "lesions.per_body=1", "blend.method=paste", "views.per_body=3"]
    args = [sys.executable, "-m", "glsynth.cli", "generate", "--out", str(out)]
    for s in sets:
        args += ["--set", s]
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 300
    killed = False
    while time.time() < deadline and proc.poll() is None:
        tgt = out / "targets"
        if tgt.is_dir() and any(n.startswith("body001") for n in os.listdir(tgt)):
            proc.send_signal(signal.SIGKILL)
            killed = True
            break
        time.sleep(0.01)
    proc.wait()
    if not killed:
        assert proc.returncode == 0, "the run failed before its second body's views"
        pytest.skip("the run finished before the second body's views could be interrupted")
    done = sorted(n[:-5] for n in os.listdir(out / "targets") if n.endswith(".json"))
    assert len(done) < 6
    for root, _, names in os.walk(out):
        for n in names:
            if n.startswith(".tmp-"):
                continue
            p = os.path.join(root, n)
            if n.endswith(".png"):
                assert cv2.imread(p, cv2.IMREAD_UNCHANGED) is not None, p
            elif n.endswith(".json"):
                json.load(open(p))
    first = {n: (out / "targets" / n).read_bytes() for n in os.listdir(out / "targets")
             if n.startswith("body000") and n.endswith(".json")}
    from glsynth.config import load_config
    gs.pipeline.generate(load_config(None, sets), out, resume=True)
    final = sorted(n[:-5] for n in os.listdir(out / "targets") if n.endswith(".json"))
    assert final == [f"body{b:03d}_{j:04d}" for b in range(2) for j in range(3)]
    assert all((out / "targets" / n).read_bytes() == data for n, data in first.items())
    assert not [n for _, _, ns in os.walk(out) for n in ns if n.startswith(".tmp-")]
    coco = json.load(open(out / "annotations.coco.json"))
    assert len(coco["images"]) == 6
