"""Mesh loading and validation, cameras and their matrices."""
import math

import numpy as np
import pytest

import glsynth as gs
from glsynth import MeshError


def _write_obj(tmp_path, text, mtl=None, png=True, name="m.obj"):
    p = tmp_path / name
    p.write_text(text)
    if mtl is not None:
        (tmp_path / "m.mtl").write_text(mtl)
    if png:
        import cv2
        cv2.imwrite(str(tmp_path / "tex.png"), np.full((8, 8, 3), 200, np.uint8))
    return p


OBJ_SEAM = """mtllib m.mtl
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
vt 0.5 0.5
f 1/1 2/2 3/3
f 1/5 3/3 4/4
"""


def test_obj_keeps_vertex_order_and_per_face_uvs(tmp_path):
    p = _write_obj(tmp_path, OBJ_SEAM, mtl="newmtl a\nmap_Kd tex.png\n")
    m = gs.Mesh.load(p)
    assert m.vertices.shape == (4, 3) and m.uvs.shape == (5, 2)
    np.testing.assert_array_equal(m.vertices[3], [0, 1, 0])
    np.testing.assert_array_equal(m.face_uvs, [[0, 1, 2], [4, 2, 3]])
    assert m.texture.shape == (8, 8, 3)


def test_obj_polygons_are_triangulated(tmp_path):
    p = _write_obj(tmp_path, "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nf 1/1 2/1 3/1 4/1\n",
                   mtl="map_Kd tex.png\n")
    assert gs.Mesh.load(p).faces.tolist() == [[0, 1, 2], [0, 2, 3]]


def test_glb_and_ply_through_trimesh(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    from PIL import Image
    box = trimesh.creation.box()
    uv = np.random.default_rng(0).random((len(box.vertices), 2))
    box.visual = trimesh.visual.TextureVisuals(uv=uv, image=Image.fromarray(np.full((4, 4, 3), 90, np.uint8)))
    box.export(tmp_path / "b.glb")
    m = gs.Mesh.load(tmp_path / "b.glb")
    assert len(m.faces) == 12 and m.texture.shape == (4, 4, 3)
    trimesh.creation.box().export(tmp_path / "b.ply")
    with pytest.raises(MeshError, match="b.ply.*no UV"):
        gs.Mesh.load(tmp_path / "b.ply")
    assert gs.Mesh.load(tmp_path / "b.ply", require_texture=False).uvs is None


@pytest.mark.parametrize("text,msg", [
    ("v 0 0 0\nv 1 0 0\nv nan 1 0\nvt 0 0\nf 1/1 2/1 3/1\n", "NaN or inf"),
    ("v 0 0 0\nv 1 0 0\nv 1 1 0\nvt 0 0\nf 1/1 2/1 9/1\n", "out of range"),
    ("v 0 0 0\nv 1 0 x\n", "malformed 'v' line"),
    ("v 0 0 0\n", "no faces"),
    ("v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\n", "no UV"),
])
def test_bad_obj_names_file_and_problem(tmp_path, text, msg):
    p = _write_obj(tmp_path, text, png=False)
    with pytest.raises(MeshError, match=msg) as e:
        gs.Mesh.load(p)
    assert "m.obj" in str(e.value)


def test_missing_texture_files_are_named(tmp_path):
    p = _write_obj(tmp_path, OBJ_SEAM, mtl="map_Kd gone.png\n", png=False)
    with pytest.raises(MeshError, match="gone.png"):
        gs.Mesh.load(p)
    p = _write_obj(tmp_path, OBJ_SEAM.replace("mtllib m.mtl\n", ""), png=False)
    with pytest.raises(MeshError, match="no texture"):
        gs.Mesh.load(p)
    with pytest.raises(MeshError, match="not found"):
        gs.Mesh.load(tmp_path / "absent.obj")


def test_degenerate_faces_are_counted(caplog):
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0]], float)
    m = gs.Mesh(v, [[0, 1, 2], [0, 1, 3], [1, 1, 2]], uvs=np.zeros((4, 2)),
                texture=np.zeros((2, 2, 3), np.uint8))
    assert m.degenerate_faces.tolist() == [False, True, True]
    assert "2 of 3 faces are degenerate" in caplog.text
    assert np.isfinite(m.vertex_normals).all() and np.isfinite(m.face_normals).all()


def test_normals_are_unit_and_outward():
    trimesh = pytest.importorskip("trimesh")
    s = trimesh.creation.icosphere(3)
    m = gs.Mesh(s.vertices, s.faces, require_texture=False)
    np.testing.assert_allclose(np.linalg.norm(m.vertex_normals, axis=1), 1, atol=1e-12)
    assert ((m.vertex_normals * s.vertices).sum(1) > 0.99).all()


@pytest.mark.parametrize("normal", [(0, 1, 0), (0, -1, 0), (0, 1e-9, 1), (1, 0, 0)])
def test_from_surface_places_eye_and_keeps_valid_up(normal, rng):
    p = rng.normal(size=3)
    w = float(rng.uniform(0.005, 100))
    cam = gs.Camera.from_surface(p, normal, w)
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    np.testing.assert_allclose(cam.eye, p + n * w, rtol=1e-12, atol=1e-12)
    v = cam.view_matrix()
    assert np.isfinite(v).all()
    np.testing.assert_allclose(v[:3, :3] @ v[:3, :3].T, np.eye(3), atol=1e-12)
    # the surface point is straight ahead at distance w
    np.testing.assert_allclose((v @ np.r_[p, 1])[:3], [0, 0, -w], atol=1e-9 * max(1, w))
    d = cam.to_dict()
    assert d["w"] == w and gs.Camera.from_dict(d).eye == cam.eye


def test_projection_matches_intrinsics(rng):
    cam = gs.Camera.look_at(rng.normal(size=3) * 3, rng.normal(size=3) * 0.1, fov_deg=37, width=200, height=120)
    pts = np.asarray(cam.target) + rng.normal(scale=0.2, size=(50, 3))
    near, far = cam.clip_planes(pts.min(0), pts.max(0))
    clip = (cam.projection_matrix(near, far) @ cam.view_matrix() @ np.c_[pts, np.ones(50)].T).T
    ndc = clip[:, :3] / clip[:, 3:]
    px = np.c_[(ndc[:, 0] + 1) / 2 * 200, (1 - ndc[:, 1]) / 2 * 120]
    np.testing.assert_allclose(px, cam.project(pts), atol=1e-9)
    assert (np.abs(ndc[:, 2]) <= 1).all()
    k = cam.intrinsics()
    assert math.isclose(k[1, 1], 60 / math.tan(math.radians(18.5)))


@pytest.mark.parametrize("w", [0.005, 100.0])
def test_clip_planes_keep_close_and_far_cameras_precise(w):
    lo, hi = np.array([-0.5, 0, -0.2]), np.array([0.5, 1.8, 0.2])
    cam = gs.Camera.from_surface((0, 1, 0.2), (0, 0, 1), w)
    near, far = cam.clip_planes(lo, hi)
    assert near < w and far > w + 0.4 and far / near <= 1e5 + 1


def test_near_plane_stays_in_front_of_a_face_nearer_than_its_corners(rng):
    """A camera just above the middle of a big triangle, looking away along it: the
    closest vertex, the look-at point and the bounding box are all far, the face is not.
    ``Mesh.distance_to`` finds it, so the near plane stays in front of the face."""
    size, gap = rng.uniform(0.5, 2.0), rng.uniform(1e-3, 1e-2)
    # a second face reaches above the camera, so the bounding box gives no bound either
    tri = gs.Mesh([[0, 0, 0], [size, 0, 0], [0, size, 0], [0, 0, size]], [[0, 1, 2], [0, 1, 3]],
                  require_texture=False)
    eye = np.array([size / 3, size / 3, gap])
    cam = gs.Camera.look_at(eye, eye + (5.0, 5.0, -0.01))
    assert math.isclose(tri.distance_to(eye), gap, rel_tol=1e-9)
    near, far = cam.clip_planes(*tri.bounds, distance=tri.distance_to(eye))
    assert near < gap < far
    unbounded, _ = cam.clip_planes(*tri.bounds, vertices=tri.vertices)
    assert unbounded > gap  # what the vertices alone would give


def test_distance_to_matches_every_face_measured(rng):
    trimesh = pytest.importorskip("trimesh")
    tm = trimesh.creation.icosphere(2, radius=rng.uniform(0.2, 1.0))
    tm.vertices += rng.normal(scale=0.02, size=tm.vertices.shape)
    mesh = gs.Mesh(tm.vertices, tm.faces, require_texture=False)
    for p in rng.normal(size=(20, 3)) * rng.uniform(0.1, 2.0, size=(20, 1)):
        hits = trimesh.triangles.closest_point(mesh.vertices[mesh.faces], np.tile(p, (len(mesh.faces), 1)))
        assert math.isclose(mesh.distance_to(p), np.linalg.norm(hits - p, axis=1).min(), rel_tol=1e-9,
                            abs_tol=1e-12)


def test_bad_camera_inputs():
    with pytest.raises(ValueError, match="non-zero"):
        gs.Camera.look_at((0, 0, 0), (0, 0, 0))
    with pytest.raises(ValueError, match="w must be > 0"):
        gs.Camera.from_surface((0, 0, 0), (0, 0, 1), 0.0)
    with pytest.raises(ValueError, match="finite"):
        gs.Camera.from_surface((0, 0, 0), (np.nan, 0, 1), 1.0)
    with pytest.raises(ValueError, match="fov_deg"):
        gs.Camera.look_at((0, 0, 1), (0, 0, 0), fov_deg=0)


def test_closed_orientation_tells_closed_outward_inward_and_open_meshes():
    trimesh = pytest.importorskip("trimesh")
    s = trimesh.creation.icosphere(2)
    v, f = np.asarray(s.vertices), np.asarray(s.faces)
    assert gs.Mesh(v, f, require_texture=False).closed_orientation == 1
    assert gs.Mesh(v, f[:, ::-1], require_texture=False).closed_orientation == -1
    assert gs.Mesh(v, f[1:], require_texture=False).closed_orientation == 0        # a hole
    # two separate closed parts (a body and its eyes) are closed
    two = np.concatenate([v, v * 0.3 + 3]), np.concatenate([f, f + len(v)])
    assert gs.Mesh(*two, require_texture=False).closed_orientation == 1
    # each part closed, but one wound inward: culling would show its far side
    mixed = np.concatenate([f, f[:, ::-1] + len(v)])
    assert gs.Mesh(two[0], mixed, require_texture=False).closed_orientation == 0
    # a face repeated (an edge in three faces) and a collapsed face are not closed
    assert gs.Mesh(v, np.concatenate([f, f[:1]]), require_texture=False).closed_orientation == 0
    collapsed = f.copy()
    collapsed[0, 1] = collapsed[0, 0]
    assert gs.Mesh(v, collapsed, require_texture=False).closed_orientation == 0
    # one face flipped inside a closed surface: not consistently oriented
    bad = f.copy()
    bad[5] = bad[5, ::-1]
    assert gs.Mesh(v, bad, require_texture=False).closed_orientation == 0
