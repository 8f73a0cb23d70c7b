"""The GL renderer against independent references: closed-form geometry, trimesh ray
casting, pyrender's depth, and exact label look-ups. Runs once per GL backend."""
import os

import cv2
import numpy as np
import pytest

import glsynth as gs
from glsynth.gl.renderer import vertex_label_image
from glsynth.lighting import PointLight
from shapes import box, plane, ray_face_depth, skin_sheet, sphere

W_RANGE = (0.005, 0.01, 0.1, 1.0, 10.0, 100.0)


def _random_surface_camera(rng, mesh, w, width, height):
    """Camera from a random surface point along a direction near its normal."""
    f = rng.choice(len(mesh.faces), p=mesh.face_areas / mesh.face_areas.sum())
    b = rng.dirichlet((1, 1, 1))
    p = b @ mesh.vertices[mesh.faces[f]]
    n = mesh.face_normals[f] + rng.normal(scale=0.3, size=3)
    if n @ mesh.face_normals[f] < 0.3:
        n = mesh.face_normals[f]
    return gs.Camera.from_surface(p, n, w, width=width, height=height,
                                  fov_deg=rng.uniform(20, 60))


def _fg_samples(rng, out, n=300):
    rows, cols = np.nonzero(out["face_id"] >= 0)
    assert len(rows) > 0, "nothing rendered"
    idx = rng.choice(len(rows), size=min(n, len(rows)), replace=False)
    return rows[idx], cols[idx]


@pytest.mark.parametrize("shape", [plane, box])
@pytest.mark.parametrize("w", W_RANGE)
def test_depth_matches_closed_form(renderer, rng, shape, w):
    mesh = shape(rng)
    # far cameras look at a proportionally larger shape so that it covers pixels
    mesh = mesh.copy_with(vertices=mesh.vertices * max(1.0, w / 2))
    cam = _random_surface_camera(rng, mesh, w, renderer.width, renderer.height)
    out = renderer.render(mesh, cam, passes=("gbuffer",))
    rows, cols = _fg_samples(rng, out)
    face, depth = _nearest_hits(mesh, cam, rows, cols)
    assert np.isfinite(depth).mean() > 0.98
    gl_face, gl_depth = out["face_id"][rows, cols], out["depth"][rows, cols]
    # Where two faces meet, the rasteriser's fixed-point edge test may give the pixel to
    # the neighbour: allowed only when the neighbour holds a point within 1/64 pixel,
    # and the depth must then be that of the neighbour's plane within that 1/64 pixel
    # (on a face seen near edge-on, that span is wider than 1e-4 of the depth: 1.2e-4
    # at w=10, test seed 1615375841, where every other sample was within 5e-7).
    other = np.isfinite(depth) & (gl_face != face)
    plane_depth, _ = ray_face_depth(mesh, cam, rows, cols, np.maximum(gl_face, 0))
    near_edge = np.zeros(len(rows), bool)
    span = np.zeros(len(rows))
    for dr, dc in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        f, _ = _nearest_hits(mesh, cam, rows + dr / 64, cols + dc / 64)
        near_edge |= f == gl_face
        shifted, _ = ray_face_depth(mesh, cam, rows + dr / 64, cols + dc / 64, np.maximum(gl_face, 0))
        span = np.maximum(span, np.where(other, np.abs(shifted - plane_depth), 0.0))
    assert near_edge[other].all(), f"w={w}: pixels given to a face that does not cover them"
    assert other.mean() < 0.02
    expected = np.where(other, plane_depth, depth)
    ok = np.isfinite(depth)
    rel = (np.abs(gl_depth[ok] - expected[ok]) - span[ok]) / expected[ok]
    assert rel.max() <= 1e-4, f"w={w}: max relative depth error {rel.max():.2e}"
    assert (out["depth"][out["face_id"] < 0] == -1).all()


def _nearest_hits(mesh, cam, rows, cols):
    """Closed form: the nearest face each pixel ray hits inside its triangle (-1 for
    none) and its depth along the view axis (inf for none); exact for plane and box."""
    o, d = cam.pixel_rays(rows, cols)
    best, face = np.full(len(o), np.inf), np.full(len(o), -1)
    for fi in range(len(mesh.faces)):
        a, b_, c = mesh.vertices[mesh.faces[fi]]
        n = mesh.face_normals[fi]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((a - o) @ n) / (d @ n)
        hit = o + d * t[:, None]
        nearer = _inside_triangle(hit, a, b_, c, tol=1e-9) & (t > 0) & (t < best)
        best, face = np.where(nearer, t, best), np.where(nearer, fi, face)
    forward = np.subtract(cam.target, cam.eye)
    forward /= np.linalg.norm(forward)
    return face, best * (d @ forward)


def _inside_triangle(p, a, b, c, tol):
    v0, v1, v2 = b - a, c - a, p - a
    d00, d01, d11 = v0 @ v0, v0 @ v1, v1 @ v1
    d20, d21 = v2 @ v0, v2 @ v1
    den = d00 * d11 - d01 * d01
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    return (v >= -tol) & (w >= -tol) & (v + w <= 1 + tol)


@pytest.mark.parametrize("w", W_RANGE)
def test_sphere_depth_faces_and_barycentrics(renderer, rng, w):
    mesh = sphere(rng, radius=rng.uniform(0.1, 1.0) * max(1.0, w / 2))
    cam = _random_surface_camera(rng, mesh, w, renderer.width, renderer.height)
    out = renderer.render(mesh, cam, passes=("gbuffer",))
    rows, cols = _fg_samples(rng, out)
    fid = out["face_id"][rows, cols]
    depth = out["depth"][rows, cols]
    bary = out["bary"][rows, cols].astype(np.float64)
    # depth: closed form of the ray hitting the reported face's plane, where the pixel
    # centre lies inside that face. Barycentrics are clamped to the triangle, so where
    # the rasteriser's fixed-point edge test takes a pixel just outside an almost
    # edge-on face (a silhouette) the point, and its depth, is the triangle's nearest.
    expected, hit = ray_face_depth(mesh, cam, rows, cols, fid)
    inside = (bary > 0).all(1)
    assert inside.mean() > 0.97
    rel = np.abs(depth - expected)[inside] / expected[inside]
    assert np.quantile(rel, 0.99) <= 1e-4 and rel.max() <= 1e-3
    # barycentrics: in [0, 1], sum to 1, and the point they give projects to the pixel
    # at the reported depth
    assert (bary >= 0).all() and (bary <= 1).all()
    np.testing.assert_allclose(bary.sum(1), 1, atol=1e-5)
    p = np.einsum("nk,nkj->nj", bary, mesh.vertices[mesh.faces[fid]])
    forward = np.subtract(cam.target, cam.eye) / np.linalg.norm(np.subtract(cam.target, cam.eye))
    np.testing.assert_allclose(depth, (p - cam.eye) @ forward, rtol=1e-4)
    px = cam.project(p)
    err = np.hypot(px[:, 0] - (cols + 0.5), px[:, 1] - (rows + 0.5))
    assert np.median(err) < 0.01 and np.quantile(err, 0.95) < 0.05
    # the back-projected hit lies on the reported face (inside its triangle)
    a, b, c = (mesh.vertices[mesh.faces[fid, i]] for i in range(3))
    inside = np.array([_inside_triangle(hit[i:i + 1], a[i], b[i], c[i], tol=1e-2)[0]
                       for i in range(len(fid))])
    assert inside.mean() > 0.99


def test_face_ids_match_trimesh_ray_casting(renderer, rng):
    trimesh = pytest.importorskip("trimesh")
    mesh = sphere(rng, radius=0.4, subdivisions=3)
    eye = rng.normal(size=3)
    eye = eye / np.linalg.norm(eye) * rng.uniform(1.0, 3.0)
    cam = gs.Camera.look_at(eye, rng.normal(scale=0.05, size=3), width=renderer.width,
                            height=renderer.height)
    out = renderer.render(mesh, cam, passes=("gbuffer",))
    rows, cols = np.nonzero(np.ones_like(out["face_id"], bool))
    idx = rng.choice(len(rows), 2000, replace=False)
    rows, cols = rows[idx], cols[idx]
    o, d = cam.pixel_rays(rows, cols)
    tm = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    tri = tm.ray.intersects_first(o, d)
    fid = out["face_id"][rows, cols]
    assert ((tri == -1) == (fid == -1)).mean() > 0.995  # silhouette pixels may differ
    both = (tri >= 0) & (fid >= 0)
    # a disagreement must be a pixel on a shared edge: the GL face still contains the hit
    same = tri[both] == fid[both]
    assert same.mean() > 0.98
    assert (out["face_id"][out["depth"] < 0] == -1).all()


@pytest.mark.skipif(os.environ.get("GLSYNTH_GL_BACKEND") == "osmesa",
                    reason="pyrender's pinned PyOpenGL 3.1.0 fails on OSMesa contexts; the "
                           "EGL run compares with pyrender and test_backends compares OSMesa with EGL")
def test_gl_depth_matches_pyrender(renderer, rng):
    pyrender = pytest.importorskip("pyrender")
    trimesh = pytest.importorskip("trimesh")
    mesh = sphere(rng, radius=0.5, subdivisions=3)
    eye = rng.normal(size=3)
    eye = eye / np.linalg.norm(eye) * rng.uniform(1.2, 4.0)
    cam = gs.Camera.look_at(eye, (0, 0, 0), width=renderer.width, height=renderer.height,
                            fov_deg=rng.uniform(25, 50))
    out = renderer.render(mesh, cam, passes=("gbuffer",))
    scene = pyrender.Scene()
    node = scene.add(pyrender.Mesh.from_trimesh(
        trimesh.Trimesh(mesh.vertices, mesh.faces, process=False), smooth=False))
    dist = np.linalg.norm(eye)
    pc = pyrender.PerspectiveCamera(yfov=np.radians(cam.fov_deg), aspectRatio=cam.aspect,
                                    znear=dist - 0.6, zfar=dist + 0.6)
    scene.add(pc, pose=np.linalg.inv(cam.view_matrix()))
    # The SEG flag turns pyrender's 4x MSAA off; with it on, its depth comes from a
    # sample away from the pixel centre (1e-3 relative off on slopes).
    ref = _pyrender_offscreen(cam.width, cam.height).render(
        scene, flags=pyrender.RenderFlags.DEPTH_ONLY | pyrender.RenderFlags.SEG,
        seg_node_map={node: (255, 255, 255)})
    both = (ref > 0) & (out["depth"] > 0)
    assert both.sum() > 0.9 * (ref > 0).sum()
    rel = np.abs(out["depth"][both] - ref[both]) / ref[both]
    assert np.quantile(rel, 0.999) <= 1e-4, f"relative depth difference {rel.max():.2e}"


_PYRENDER = {}


def _pyrender_offscreen(width, height):
    """One pyrender renderer for the whole run. Never deleted: pyrender's delete()
    calls eglTerminate on the process-wide default display, which would also end our
    own EGL context."""
    import pyrender
    key = (width, height)
    if key not in _PYRENDER:
        _PYRENDER[key] = pyrender.OffscreenRenderer(width, height)
    return _PYRENDER[key]


def test_label_pass_exact_integers(renderer, rng):
    mesh = plane(rng)
    th, tw = 40, 56
    blocks = rng.integers(0, 65536, size=(th // 4, tw // 8)).astype(np.uint16)
    labels = np.kron(blocks, np.ones((4, 8), np.uint16))
    cam = gs.Camera.look_at((rng.uniform(-.2, .2), rng.uniform(-.2, .2), rng.uniform(1.5, 3)),
                            (0, 0, 0), width=renderer.width, height=renderer.height)
    out = renderer.render(mesh, cam, passes=("gbuffer", "labels"), label_texture=labels)
    got = out["labels"]
    assert got.dtype == np.uint16
    fg = out["face_id"] >= 0
    assert (got[~fg] == 0).all()
    # expected: the texel under each pixel's interpolated UV
    u, v = out["uv"][..., 0], out["uv"][..., 1]
    tx, ty = u * tw, (1 - v) * th
    safe = fg & (np.abs(tx - np.round(tx)) > 1e-3) & (np.abs(ty - np.round(ty)) > 1e-3)
    exp = labels[np.clip(ty.astype(int), 0, th - 1), np.clip(tx.astype(int), 0, tw - 1)]
    assert (got[safe] == exp[safe]).all()
    assert set(np.unique(got[fg])) <= set(np.unique(labels))  # no blended values
    assert got.max() > 255


def test_several_label_textures_in_one_draw(renderer, rng):
    mesh = plane(rng)
    maps = {f"m{i}": rng.integers(0, 1000, size=(8, 8)).astype(np.uint16) for i in range(3)}
    cam = gs.Camera.look_at((0, 0, 2.5), (0, 0, 0), width=renderer.width, height=renderer.height)
    out = renderer.render(mesh, cam, passes=("labels",), label_textures=maps)
    single = {k: renderer.render(mesh, cam, passes=("labels",), label_texture=m)["labels"]
              for k, m in maps.items()}
    for k in maps:
        assert (out[k] == single[k]).all()


def test_gbuffer_and_labels_in_one_draw_equal_separate_draws(renderer, rng):
    from shapes import sphere
    mesh = sphere(rng)
    maps = {f"m{i}": rng.integers(0, 65536, size=(32, 32)).astype(np.uint16) for i in range(4)}
    eye = rng.normal(size=3)
    cam = gs.Camera.look_at(eye / np.linalg.norm(eye) * 3, (0, 0, 0), width=renderer.width,
                            height=renderer.height)
    both = renderer.render(mesh, cam, passes=("gbuffer", "labels"), label_textures=maps)
    gbuf = renderer.render(mesh, cam, passes=("gbuffer",))
    labels = renderer.render(mesh, cam, passes=("labels",), label_textures=maps)
    for k in ("face_id", "bary", "depth", "uv"):
        assert np.array_equal(both[k], gbuf[k]), k
    for k in maps:
        assert np.array_equal(both[k], labels[k]), k
    assert (both["m0"][both["face_id"] < 0] == 0).all()


def test_reads_back_only_the_requested_buffers(renderer, rng):
    from shapes import sphere
    mesh = sphere(rng)
    maps = {"a": rng.integers(0, 65536, size=(16, 16)).astype(np.uint16),
            "b": rng.integers(0, 65536, size=(16, 16)).astype(np.uint16)}
    cam = gs.Camera.look_at((0.2, 0.3, 2.0), (0, 0, 0), width=renderer.width, height=renderer.height)
    passes = ("gbuffer", "labels", "rgb")
    full = renderer.render(mesh, cam, passes=passes, label_textures=maps)
    some = renderer.render(mesh, cam, passes=passes, label_textures=maps, buffers=("depth", "b", "rgb"))
    assert set(some) == {"face_id", "depth", "b", "rgb", "alpha"}  # colour and coverage: one read
    for k in some:
        assert np.array_equal(some[k], full[k]), k
    assert (full["depth"][full["face_id"] < 0] == -1).all() and (full["depth"][full["face_id"] >= 0] > 0).all()
    with pytest.raises(ValueError, match="unknown buffer"):
        renderer.render(mesh, cam, passes=("gbuffer",), buffers=("normals",))


def test_vertex_labels_exact(renderer, rng):
    mesh = sphere(rng, subdivisions=2)
    labels = rng.integers(1, 17, size=len(mesh.vertices)).astype(np.uint8)
    cam = gs.Camera.look_at((0, 0, 1.5), (0, 0, 0), width=renderer.width, height=renderer.height)
    out = renderer.render(mesh, cam, passes=("gbuffer",))
    img = vertex_label_image(out, mesh, labels)
    fg = out["face_id"] >= 0
    assert (img[~fg] == 0).all() and (img[fg] >= 1).all()
    corners = mesh.faces[out["face_id"][fg]]
    assert np.all([img[fg][i] in labels[corners[i]] for i in range(0, fg.sum(), 97)])


@pytest.mark.parametrize("trial", range(3))
def test_vertex_labels_in_the_label_pass_equal_the_numpy_lookup(renderer, rng, trial):
    mesh = (sphere(rng, subdivisions=int(rng.integers(1, 5))) if trial != 1 else box(rng))
    vertex_labels = rng.integers(0, 65536, size=len(mesh.vertices)).astype(np.int64)
    nonskin = rng.integers(0, 3, size=(37, 53)).astype(np.uint8)
    d = rng.normal(size=3)
    cam = gs.Camera.look_at(d / np.linalg.norm(d) * rng.uniform(0.6, 2.0), rng.normal(scale=0.05, size=3),
                            width=renderer.width, height=renderer.height, fov_deg=rng.uniform(20, 60))
    out = renderer.render(mesh, cam, passes=("gbuffer", "labels"), label_textures={"nonskin": nonskin},
                          vertex_labels={"part": vertex_labels})
    np.testing.assert_array_equal(out["part"], vertex_label_image(out, mesh, vertex_labels))
    # the UV-space map in the same draw is unaffected, and the label pass alone agrees
    alone = renderer.render(mesh, cam, passes=("labels",), label_textures={"nonskin": nonskin},
                            vertex_labels={"part": vertex_labels})
    np.testing.assert_array_equal(alone["part"], out["part"])
    np.testing.assert_array_equal(alone["nonskin"], out["nonskin"])
    with pytest.raises(ValueError, match="vertex labels must be"):
        renderer.render(mesh, cam, passes=("labels",), vertex_labels={"part": vertex_labels[:-1]})




def test_every_label_layout_in_one_renderer(renderer, rng):
    """Programs are compiled per layout (number of maps, how many per vertex): every
    layout, drawn in random order through one renderer, gives each map its own labels."""
    mesh = sphere(rng, subdivisions=2)
    d = rng.normal(size=3)
    cam = gs.Camera.look_at(d / np.linalg.norm(d) * 1.8, (0, 0, 0), width=renderer.width,
                            height=renderer.height)
    gbuf = renderer.render(mesh, cam, passes=("gbuffer",))
    maps = [rng.integers(0, 65536, size=(23, 29)).astype(np.uint16) for _ in range(4)]
    per_vertex = [rng.integers(0, 65536, size=len(mesh.vertices)) for _ in range(4)]
    expected_uv = [renderer.render(mesh, cam, passes=("labels",), label_texture=m)["labels"] for m in maps]
    layouts = [(n, k) for n in range(1, 5) for k in range(n + 1)]
    for i in rng.permutation(len(layouts)):
        n, k = layouts[i]  # n maps, the last k of them per vertex
        textures = {f"t{j}": maps[j] for j in range(n - k)}
        vertex = {f"v{j}": per_vertex[j] for j in range(k)}
        for passes in (("labels",), ("gbuffer", "labels")):
            out = renderer.render(mesh, cam, passes=passes, label_textures=textures or None,
                                  vertex_labels=vertex or None)
            for j in range(n - k):
                np.testing.assert_array_equal(out[f"t{j}"], expected_uv[j], err_msg=f"layout {n, k}")
            for j in range(k):
                np.testing.assert_array_equal(out[f"v{j}"], vertex_label_image(gbuf, mesh, per_vertex[j]),
                                              err_msg=f"layout {n, k}")
def test_supersampled_rgb_and_alpha(renderer, rng):
    mesh = sphere(rng)
    cam = gs.Camera.look_at((0, 0, 1.2), (0, 0, 0), width=renderer.width, height=renderer.height)
    one = renderer.render(mesh, cam, passes=("rgb",), supersample=1)
    four = renderer.render(mesh, cam, passes=("rgb",), supersample=4)
    a1, a4 = one["alpha"], four["alpha"]
    assert set(np.unique(a1)) <= {0.0, 1.0}
    edge = (a4 > 0) & (a4 < 1)
    assert edge.sum() > 20  # fractional coverage along the silhouette
    interior = (a4 == 1) & (a1 == 1)
    assert np.abs(one["rgb"][interior] - four["rgb"][interior]).mean() < 0.05
    assert np.isfinite(four["rgb"]).all()


def test_framebuffers_and_programs_follow_their_typed_keys(renderer, rng):
    """A lean G-buffer (no barycentrics or UV) with labels has face id, depth and the
    label target; the MSAA framebuffer has the samples asked for; each key compiles and
    allocates its own program and framebuffer."""
    from glsynth.gl.renderer import GBuffer, GBufferProgram, Msaa, PhongProgram, Target
    mesh = sphere(rng)
    cam = gs.Camera.look_at((0.1, 0.2, 2.0), (0, 0, 0), width=renderer.width, height=renderer.height)
    maps = {"a": rng.integers(0, 9, size=(8, 8)).astype(np.uint16)}
    renderer.render(mesh, cam, passes=("gbuffer", "labels"), label_textures=maps, buffers=("depth", "a"))
    renderer.render(mesh, cam, passes=("labels",), label_textures=maps)
    renderer.render(mesh, cam, passes=("rgb",), multisample=4, lights=[gs.PointLight(cam.eye)] * 2)
    size = (renderer.width, renderer.height)
    lean = renderer._fbos[(GBuffer(labels=True, bary_uv=False), *size)]
    assert [a.dtype for a in lean.color_attachments] == ["i4", "f4", "u2"]
    full = renderer._fbo(GBuffer(labels=True), *size)
    assert [a.dtype for a in full.color_attachments] == ["i4", "f4", "f4", "f4", "u2"]
    assert renderer._fbos[(Msaa(4), *size)].color_attachments[0].samples == 4
    assert (Target.LABELS, *size) in renderer._fbos and (Target.RGB, *size) in renderer._fbos
    programs = set(renderer.programs)
    assert PhongProgram(2, shadows=False) in programs
    assert any(isinstance(k, GBufferProgram) and k.target is None for k in programs)        # labels alone
    assert any(isinstance(k, GBufferProgram) and k.target == GBuffer(True, False) for k in programs)
    assert not any(isinstance(k, str) and k not in ("uvspace", "shadow") for k in programs)


def test_multisampled_rgb_and_alpha(renderer, rng):
    import cv2
    mesh = sphere(rng) if rng.random() < 0.5 else box(rng)
    smooth = cv2.GaussianBlur(rng.random((64, 64, 3)).astype(np.float32), (0, 0), 3)  # skin-like
    smooth = (smooth - smooth.min()) / np.ptp(smooth)
    mesh = mesh.copy_with(texture=(smooth * 255).astype(np.uint8))
    d = rng.normal(size=3)
    # a random roll: a box seen face-on with its edges along pixel rows and columns can
    # leave every one of 4 sample positions on the same side of an edge
    cam = gs.Camera.look_at(d / np.linalg.norm(d) * rng.uniform(0.9, 2.0), rng.normal(scale=0.05, size=3),
                            up=rng.normal(size=3), width=renderer.width, height=renderer.height,
                            fov_deg=rng.uniform(30, 60))
    one = renderer.render(mesh, cam, passes=("rgb",))
    ref = renderer.render(mesh, cam, passes=("rgb",), supersample=8)
    msaa = renderer.render(mesh, cam, passes=("rgb",), multisample=4)
    a = msaa["alpha"]
    assert set(np.unique(a)) <= {0.0, 0.25, 0.5, 0.75, 1.0}
    edge = (ref["alpha"] > 0) & (ref["alpha"] < 1)
    assert edge.sum() > 20 and ((a > 0) & (a < 1)).sum() > 20
    assert np.abs(a - ref["alpha"])[edge].mean() < 0.2       # 4 samples vs 64
    err = lambda o, where: np.abs(o["rgb"] - ref["rgb"])[where].mean()
    # silhouettes: much closer to the reference than one sample per pixel (median ratio
    # 0.37 over 3,000 seeds). A box whose few edges all run near the standard 4-sample
    # pattern's weak directions (about 18 degrees off a pixel axis, one sense only), where
    # its samples project in two pairs, gets about 2 coverage levels, not 4: ratios up to
    # 0.65 there (4 boxes in 3,000 above 0.6; seed 268425281 failed CI at 0.603)
    assert err(msaa, edge) < 0.7 * err(one, edge)
    # inside, shading runs once per pixel at a point of the GL's choosing (llvmpipe: a
    # sample position, a quarter pixel off the centre): about as close as one sample
    inside = (ref["alpha"] == 1) & (a == 1)
    assert err(msaa, inside) <= max(3 * err(one, inside), 0.5 / 255)
    for bad in (3, 2 * renderer.ctx.max_samples, -1):
        with pytest.raises(ValueError, match="multisample"):
            renderer.render(mesh, cam, passes=("rgb",), multisample=bad)


def test_degenerate_faces_render(renderer, rng):
    base = sphere(rng, subdivisions=2)
    faces = np.vstack([base.faces, [[0, 0, 1], [2, 2, 2]]])  # zero-area faces
    mesh = gs.Mesh(base.vertices, faces, uvs=base.uvs, face_uvs=np.vstack([base.face_uvs, [[0, 0, 1], [2, 2, 2]]]),
                   texture=base.texture)
    assert mesh.degenerate_faces.sum() == 2
    cam = gs.Camera.look_at((0, 0, 1.5), (0, 0, 0), width=renderer.width, height=renderer.height)
    out = renderer.render(mesh, cam, passes=("gbuffer", "rgb"))
    assert np.isfinite(out["rgb"]).all() and np.isfinite(out["bary"]).all()
    assert out["face_id"].max() < len(base.faces)


def test_cropped_camera_renders_the_same_pixels(renderer, rng):
    mesh = sphere(rng)
    cam = gs.Camera.look_at(rng.normal(size=3) * 0.2 + (0, 0, 1.3), (0, 0, 0),
                            width=renderer.width, height=renderer.height)
    full = renderer.render(mesh, cam, passes=("gbuffer", "rgb"))
    x0, y0 = int(rng.integers(0, renderer.width - 40)), int(rng.integers(0, renderer.height - 30))
    crop = renderer.render(mesh, cam.crop(x0, y0, 40, 30), passes=("gbuffer", "rgb"))
    assert crop["face_id"].shape == (30, 40)
    # the off-axis projection snaps vertices differently, so a pixel centre on a shared
    # edge may fall to the neighbouring face; everything else is the same pixel
    same = crop["face_id"] == full["face_id"][y0:y0 + 30, x0:x0 + 40]
    assert same.mean() >= 0.99
    np.testing.assert_allclose(crop["depth"][same], full["depth"][y0:y0 + 30, x0:x0 + 40][same],
                               rtol=1e-5)
    assert np.abs(crop["rgb"] - full["rgb"][y0:y0 + 30, x0:x0 + 40])[same].max() <= 1 / 255


def _as_open(mesh):
    """The same mesh, drawn as if it were open (both sides of every face)."""
    copy = mesh.copy_with()
    copy.__dict__["closed_orientation"] = 0  # overrides the cached property
    return copy


@pytest.mark.parametrize("inward", [False, True])
def test_culling_closed_meshes_changes_nothing_seen_from_outside(renderer, rng, inward):
    mesh = sphere(rng) if rng.random() < 0.5 else box(rng)
    if inward:
        mesh = mesh.copy_with(faces=mesh.faces[:, ::-1], face_uvs=mesh.face_uvs[:, ::-1])
    assert mesh.closed_orientation == (-1 if inward else 1)
    for _ in range(3):
        d = rng.normal(size=3)
        cam = gs.Camera.look_at(d / np.linalg.norm(d) * rng.uniform(0.7, 3.0), rng.normal(scale=0.05, size=3),
                                width=renderer.width, height=renderer.height, fov_deg=rng.uniform(20, 60))
        culled = renderer.render(mesh, cam, passes=("gbuffer", "rgb"), supersample=2)
        both = renderer.render(_as_open(mesh), cam, passes=("gbuffer", "rgb"), supersample=2)
        # a pixel centre exactly on a silhouette edge may go to either face
        same = culled["face_id"] == both["face_id"]
        assert same.mean() >= 0.995 and (culled["face_id"] >= 0).sum() > 100
        np.testing.assert_array_equal(culled["depth"][same], both["depth"][same])
        # so may a subsample at the silhouette, where a back face shares the front face's
        # edge: there one of the four subsamples may take a neighbouring face's colour
        error = np.abs(culled["rgb"] - both["rgb"]).max(-1)
        partly_covered = ((culled["alpha"] > 0) & (culled["alpha"] < 1)).astype(np.uint8)
        silhouette = cv2.dilate(partly_covered, np.ones((3, 3), np.uint8)) > 0
        assert np.max(error[~silhouette], initial=0) <= 2 / 255
        assert np.max(error[silhouette], initial=0) <= 0.25 * 0.5
        assert np.sum(error[silhouette] > 2 / 255) <= 0.05 * silhouette.sum()
        np.testing.assert_array_equal(culled["alpha"], both["alpha"])


def test_open_meshes_show_their_inside(renderer, rng):
    """A box without its top, seen from above: the inside of the bottom and the walls
    (faces turned away from the camera) must be drawn."""
    b = box(rng)
    top = b.face_normals[:, 2] > 0.9
    mesh = gs.Mesh(b.vertices, b.faces[~top], uvs=b.uvs, face_uvs=b.face_uvs[~top], texture=b.texture)
    assert mesh.closed_orientation == 0
    cam = gs.Camera.look_at((0, 0, 1.5), (0, 0, 0), width=renderer.width, height=renderer.height)
    out = renderer.render(mesh, cam, passes=("gbuffer",))
    centre = out["face_id"][renderer.height // 2, renderer.width // 2]
    assert centre >= 0 and mesh.face_normals[centre][2] < -0.9  # the bottom, from inside


def test_supersampled_edges_composite_without_a_dark_fringe(renderer, rng):
    """A white, evenly lit sphere over a white background is white everywhere: the
    supersampled colour is premultiplied by coverage, and compositing must treat it so."""
    from glsynth.lighting import PointLight
    from glsynth.pipeline.views import composite
    mesh = sphere(rng).copy_with(texture=np.full((8, 8, 3), 255, np.uint8))
    cam = gs.Camera.look_at((0, 0, 1.0), (0, 0, 0), width=renderer.width, height=renderer.height)
    white = np.full((renderer.height, renderer.width, 3), 255, np.uint8)
    for aa in ({"supersample": 3}, {"multisample": 4}):
        out = renderer.render(mesh, cam, passes=("rgb",), **aa,
                              lights=[PointLight((0, 0, 1.0), ambient=1.0, diffuse=0.0, specular=0.0)])
        edge = (out["alpha"] > 0) & (out["alpha"] < 1)
        assert edge.sum() > 20
        np.testing.assert_allclose(out["rgb"][edge], np.repeat(out["alpha"][edge, None], 3, 1), atol=1e-6)
        rgba8 = renderer.render(mesh, cam, passes=("rgb",), **aa, buffers=("rgba8",),
                                lights=[PointLight((0, 0, 1.0), ambient=1.0, diffuse=0.0, specular=0.0)])
        assert (composite(rgba8["rgba8"], white, 0) == 255).all()


@pytest.mark.parametrize("aa", [{}, {"multisample": 4}, {"supersample": 2}, {"multisample": 4, "supersample": 2}])
def test_rgba8_is_the_float_shading_rounded(renderer, rng, aa):
    """``buffers=("rgba8",)`` resolves into 8 bits: the float result rounded (one more
    rounding where MSAA averages 8-bit samples), never anything else."""
    mesh = sphere(rng) if rng.random() < 0.5 else box(rng)
    d = rng.normal(size=3)
    cam = gs.Camera.look_at(d / np.linalg.norm(d) * rng.uniform(0.9, 2.0), rng.normal(scale=0.05, size=3),
                            up=rng.normal(size=3), width=renderer.width, height=renderer.height,
                            fov_deg=rng.uniform(30, 60))
    light = [PointLight(cam.eye + rng.normal(scale=0.3, size=3), ambient=0.3, diffuse=0.7, specular=0.2)]
    f = renderer.render(mesh, cam, passes=("rgb",), lights=light, shadows=True, **aa)
    u = renderer.render(mesh, cam, passes=("rgb",), lights=light, shadows=True, buffers=("rgba8",), **aa)["rgba8"]
    assert u.dtype == np.uint8 and u.shape == (renderer.height, renderer.width, 4)
    want = np.concatenate([f["rgb"], f["alpha"][..., None]], -1) * 255
    assert np.abs(u - want).max() <= 1.0
    assert np.abs(u - want).mean() < 0.3
    with pytest.raises(ValueError, match="not both"):
        renderer.render(mesh, cam, passes=("rgb",), buffers=("rgb", "rgba8"))


def test_uv_space_window_equals_the_crop_of_the_full_raster(renderer, rng):
    from glsynth.pipeline.bodies import TexelGeometry
    mesh = sphere(rng).copy_with(texture=np.zeros((200, 300, 3), np.uint8))
    full = renderer.render_uv_space(mesh, 300, 200)
    x0, y0 = int(rng.integers(0, 250)), int(rng.integers(0, 150))
    box = (x0, y0, x0 + int(rng.integers(1, 50)), y0 + int(rng.integers(1, 50)))
    win = renderer.render_uv_space(mesh, 300, 200, box=box)
    np.testing.assert_array_equal(win["face_id"], full["face_id"][box[1]:box[3], box[0]:box[2]])
    np.testing.assert_array_equal(win["bary"], full["bary"][box[1]:box[3], box[0]:box[2]])
    # and the texel geometry of a window is the full geometry's texels inside it
    only = rng.random((200, 300)) < 0.5
    a = TexelGeometry.of(renderer, mesh, only=only)
    b = TexelGeometry.of(renderer, mesh, only=only, box=box)
    inside = (a.rows >= box[1]) & (a.rows < box[3]) & (a.cols >= box[0]) & (a.cols < box[2])
    np.testing.assert_array_equal(b.rows, a.rows[inside])
    np.testing.assert_array_equal(b.cols, a.cols[inside])
    np.testing.assert_allclose(b.points, a.points[inside])
    # a later full raster is not clipped by the window
    np.testing.assert_array_equal(renderer.render_uv_space(mesh, 300, 200)["face_id"], full["face_id"])
    with pytest.raises(ValueError, match="empty"):
        renderer.render_uv_space(mesh, 300, 200, box=(10, 10, 10, 20))


@pytest.mark.parametrize("gap", [0.002, 1.0, 20.0])
def test_depth_only_draw_matches_the_gbuffer_depth(renderer, rng, gap):
    """``Renderer.depth`` (z-buffer, linearised) against the G-buffer's exact depth,
    from almost on the surface to far away (``gap``: camera to sphere surface)."""
    mesh = sphere(rng)  # radius 0.3
    d = rng.normal(size=3)
    eye = d / np.linalg.norm(d) * (0.3 + gap * (1 + 0.1 * rng.random()))
    fov = rng.uniform(20, 60) if gap < 10 else rng.uniform(0.8, 1.5)
    cam = gs.Camera.look_at(eye, rng.normal(scale=0.01, size=3), width=renderer.width,
                            height=renderer.height, fov_deg=fov)
    gbuffer = renderer.render(mesh, cam, passes=("gbuffer",))
    exact = gbuffer["depth"]
    z = renderer.depth(mesh, cam)
    assert z.shape == exact.shape and z.dtype == np.float32
    hit = exact > 0
    assert hit.sum() > 50 and np.mean(hit == (z > 0)) >= 0.998
    # The G-buffer clamps barycentrics: where the rasteriser's fixed-point edge test takes
    # a pixel just outside an almost edge-on triangle, its depth is that of the nearest
    # point on the triangle, while the z-buffer holds the triangle's plane at the pixel
    # ray. Compare where the pixel centre lies inside its triangle.
    inside = (gbuffer["bary"] > 0).all(-1)
    assert np.mean(inside[hit]) > 0.98
    both = hit & (z > 0) & inside
    np.testing.assert_allclose(z[both], exact[both], rtol=1e-3)
    assert (z[z <= 0] == -1).all()


def test_mesh_staged_in_another_thread_renders_the_same(renderer, rng):
    import threading
    mesh = sphere(rng)
    staged = mesh.copy_with()
    worker = threading.Thread(target=renderer.stage, args=(staged,))
    worker.start()
    worker.join()
    assert id(staged) in renderer._staged
    cam = gs.Camera.look_at(rng.normal(size=3) * 0.2 + (0, 0, 1.2), (0, 0, 0),
                            width=renderer.width, height=renderer.height)
    a = renderer.render(mesh, cam, passes=("gbuffer", "rgb"))
    b = renderer.render(staged, cam, passes=("gbuffer", "rgb"))
    assert id(staged) not in renderer._staged  # used by the upload, then dropped
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])


@pytest.mark.parametrize("w", [0.01, 0.3, 3.0])
@pytest.mark.parametrize("shape", ["sphere", "sheet"])
def test_frustum_culling_changes_no_pixel(renderer, rng, w, shape):
    """Runs of faces outside the view are skipped: every buffer, the shading with a
    shadow map (culled from the light), a crop and the depth-only draw are the same as
    drawing every face, while a close-up of a sheet (faces in row order, like a body's
    parts) draws a small part of it."""
    if shape == "sphere":
        mesh = sphere(rng, radius=0.5, subdivisions=5)  # 20k faces, icosphere order
    else:
        mesh = skin_sheet(rng, n=100, tex=64).mesh  # 20k faces, 0.6 m x 0.6 m
    cam = _random_surface_camera(rng, mesh, w, renderer.width, renderer.height)
    light = [PointLight(np.asarray(cam.eye) + rng.normal(scale=0.2, size=3), ambient=0.2, diffuse=0.8)]
    crop = cam.crop(int(rng.integers(0, 64)), int(rng.integers(0, 48)), 40, 30)

    def draw_all():
        out = renderer.render(mesh, cam, passes=("gbuffer", "rgb", "labels"), lights=light,
                              multisample=4, shadows=True, label_texture=np.arange(64 * 64).reshape(64, 64) % 7)
        out["crop"] = renderer.render(mesh, crop, passes=("gbuffer",))["face_id"]
        out["probe"] = renderer.depth(mesh, cam)
        return out
    culled = draw_all()
    try:
        renderer.frustum_culling = False
        full = draw_all()
    finally:
        del renderer.frustum_culling  # back to the class default
    for name in full:
        np.testing.assert_array_equal(culled[name], full[name], err_msg=name)
    if shape == "sheet":  # a close-up straight at the middle of the sheet
        i = len(mesh.vertices) // 2 + 50
        close = gs.Camera.from_surface(mesh.vertices[i], mesh.vertex_normals[i], 0.01,
                                       width=renderer.width, height=renderer.height, fov_deg=40)
        with renderer.ctx:
            gpu = renderer._gpu_mesh(mesh)
            drawn = sum(n for _, n in gpu.visible_ranges(renderer._matrices(gpu, mesh, close)["frustum"]))
        assert 0 < drawn < 0.2 * gpu.count  # 14%: the rows of faces through the view


def test_close_releases_an_owned_context_only(gl_backend, rng):
    import moderngl
    r = gs.Renderer(16, 16, backend=gl_backend)
    mesh = box(rng)
    cam = gs.Camera.look_at((0, 0, 3), (0, 0, 0), width=16, height=16)
    r.render(mesh, cam, passes=("gbuffer",))
    with r:  # the context manager closes it
        pass
    assert isinstance(r.ctx.mglo, moderngl.InvalidObject)  # moderngl's mark of a released object
    # a renderer on a context it was given leaves that context usable
    owner = gs.Renderer(16, 16, backend=gl_backend)
    guest = gs.Renderer(16, 16, ctx=owner.ctx)
    guest.render(mesh, cam, passes=("gbuffer",))
    guest.close()
    assert not isinstance(owner.ctx.mglo, moderngl.InvalidObject)
    assert (owner.render(mesh, cam, passes=("gbuffer",))["face_id"] >= 0).any()
    owner.close()


def test_gil_free_draws_and_waits_equal_moderngl_calls(renderer, rng, monkeypatch):
    """Draws and waits go through ctypes (the GIL released, so a pipeline's writer
    threads run meanwhile) on the headless backends; every pass gives the same bytes
    as moderngl's own calls."""
    assert renderer._unlocked.available, "glFinish/glDrawArrays not resolved for this context"
    from shapes import sphere
    mesh = sphere(rng)
    d = rng.normal(size=3)
    cam = gs.Camera.look_at(d / np.linalg.norm(d) * rng.uniform(1.2, 3.0), (0, 0, 0),
                            width=renderer.width, height=renderer.height)
    light = [gs.PointLight(np.asarray(cam.eye) + rng.normal(scale=0.3, size=3))]
    labels = {"m": rng.integers(0, 65536, size=(16, 16)).astype(np.uint16)}

    def render_all():
        out = renderer.render(mesh, cam, passes=("gbuffer", "labels", "rgb"), lights=light,
                              label_textures=labels, multisample=4, shadows=True)
        out["probe"] = renderer.depth(mesh, cam)
        return out

    unlocked = render_all()
    monkeypatch.setattr(renderer._unlocked, "available", False)
    monkeypatch.setattr(renderer._unlocked, "finish", renderer.ctx.finish)
    locked = render_all()
    assert set(unlocked) == set(locked)
    for k in locked:
        np.testing.assert_array_equal(unlocked[k], locked[k], err_msg=k)
