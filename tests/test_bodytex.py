"""Real-scan loaders: the 3DBodyTex folder layout and generic meshes (xatlas UVs, baked
vertex colours).

Fixtures are written in the exact 3DBodyTex layout: an OBJ whose vertices are stored in
a shuffled order, with a texture seam (vertices with two UVs), an MTL naming the PNG
texture, an RGBA non-skin mask, float ``vertslabels_scan.npy`` and a Skin3D nevus CSV.
References: the arrays written to disk, cv2.remap for bilinear texture sampling, and
barycentric interpolation of vertex colours from the G-buffer.
"""
import json
import os

import cv2
import numpy as np
import pytest
import trimesh

import glsynth as gs
from glsynth.assets.bodytex import BodyError, load_bodytex, load_mesh_body, read_nevi
from glsynth.assets.uv import ensure_uvs

OBJ = "model_highres_0_normalized"
COLS, ROWS = 12, 6         # cylinder: COLS vertices round, ROWS rings
TEX_W, TEX_H = 64, 32


def cylinder(rng):
    """Vertices stored in a random order, UVs with a seam at u = 0 / 1, labels 1..16
    that are a function of the vertex position (so misalignment shows)."""
    ring, height = np.meshgrid(np.arange(COLS), np.arange(ROWS))
    ring, height = ring.ravel(), height.ravel()
    angle = 2 * np.pi * ring / COLS
    pos = np.c_[0.2 * np.cos(angle), 0.3 * height, 0.2 * np.sin(angle)]
    order = rng.permutation(len(pos))          # file index -> grid index
    file_of = np.argsort(order)                # grid index -> file index
    verts = pos[order]
    # UV grid has COLS + 1 columns: column COLS is the seam copy of column 0
    uv = np.array([[c / COLS, r / (ROWS - 1)] for r in range(ROWS) for c in range(COLS + 1)])
    faces, face_uvs = [], []
    for r in range(ROWS - 1):
        for c in range(COLS):
            g = [r * COLS + c, r * COLS + (c + 1) % COLS, (r + 1) * COLS + (c + 1) % COLS,
                 (r + 1) * COLS + c]
            t = [r * (COLS + 1) + c, r * (COLS + 1) + c + 1, (r + 1) * (COLS + 1) + c + 1,
                 (r + 1) * (COLS + 1) + c]
            for a, b, d in ((0, 1, 2), (0, 2, 3)):
                faces.append(file_of[[g[a], g[b], g[d]]])
                face_uvs.append([t[a], t[b], t[d]])
    return verts, np.array(faces), uv, np.array(face_uvs)


def label_of(v):
    """Anatomy label as a function of position: 1 + (5 - ring (0..5)) + 6 * (x > 0) ->
    1..12; the head (1) on the top ring, the feet (9, 10) lower down: +Y is up."""
    return 1 + (5 - np.rint(v[:, 1] / 0.3).astype(int)) + 6 * (v[:, 0] > 1e-9)


def write_scan(folder, rng, labels_dtype=np.float32):
    os.makedirs(folder, exist_ok=True)
    v, f, uv, ft = cylinder(rng)
    with open(os.path.join(folder, OBJ + ".obj"), "w") as fh:
        fh.write(f"# 3DBodyTex-like test scan\nmtllib {OBJ}.mtl\n")
        fh.writelines(f"v {x:.9f} {y:.9f} {z:.9f}\n" for x, y, z in v)
        fh.writelines(f"vt {a:.9f} {b:.9f}\n" for a, b in uv)
        fh.write("usemtl material_0\n")
        fh.writelines("f " + " ".join(f"{i + 1}/{j + 1}" for i, j in zip(fi, ti)) + "\n"
                      for fi, ti in zip(f, ft))
    with open(os.path.join(folder, OBJ + ".mtl"), "w") as fh:
        fh.write(f"newmtl material_0\nKd 1 1 1\nmap_Kd {OBJ}.png\n")
    tex = (rng.random((TEX_H, TEX_W, 3)) * 255).astype(np.uint8)
    cv2.imwrite(os.path.join(folder, OBJ + ".png"), tex[..., ::-1])
    nonskin = np.zeros((TEX_H, TEX_W), bool)
    nonskin[:8, 10:30] = True
    rgba = np.zeros((TEX_H, TEX_W, 4), np.uint8)
    rgba[nonskin, :3] = 255
    rgba[..., 3] = 255  # opaque: the mask is in the colour channels
    cv2.imwrite(os.path.join(folder, "nonskin_mask.png"), rgba)
    np.save(os.path.join(folder, "vertslabels_scan.npy"), label_of(v).astype(labels_dtype)[:, None])
    with open(os.path.join(folder, "skin3d_nevi.csv"), "w") as fh:
        fh.write("filename,file_size,file_attributes,region_count,region_id,"
                 "region_shape_attributes,region_attributes\n")
        for k, (x, y, w, h) in enumerate([(3, 4, 5, 6), (40, 20, 4, 3)]):
            shape = json.dumps({"name": "rect", "x": x, "y": y, "width": w, "height": h})
            fh.write(f'{OBJ}.png,1,"{{}}",2,{k},"{shape.replace(chr(34), 2 * chr(34))}","{{}}"\n')
    return {"v": v, "f": f, "uv": uv, "ft": ft, "tex": tex, "nonskin": nonskin}


@pytest.fixture
def scan(tmp_path, rng):
    folder = tmp_path / "006-f-run"
    return folder, write_scan(folder, rng)


# ---- 3DBodyTex layout -------------------------------------------------------------------
def test_bodytex_keeps_file_order_labels_and_masks(scan):
    folder, ref = scan
    body = load_bodytex(folder)
    m = body.mesh
    np.testing.assert_allclose(m.vertices, ref["v"], atol=1e-8)
    np.testing.assert_array_equal(m.faces, ref["f"])
    np.testing.assert_array_equal(m.face_uvs, ref["ft"])
    np.testing.assert_array_equal(m.texture, ref["tex"])
    assert body.anatomy.dtype == np.uint8 and body.anatomy.shape == (len(ref["v"]),)
    np.testing.assert_array_equal(body.anatomy, label_of(m.vertices))
    assert m.vertex_labels is body.anatomy
    # the seam: a vertex on the u = 0 column is used with u = 0 and with u = 1
    seam = int(np.flatnonzero(np.isclose(m.vertices[:, 0], 0.2) & np.isclose(m.vertices[:, 1], 0.3))[0])
    us = {round(float(u), 6) for u in m.uvs[m.face_uvs[m.faces == seam], 0]}
    assert us == {0.0, 1.0}
    assert body.nonskin.dtype == np.uint8 and body.nonskin.shape == (TEX_H, TEX_W)
    np.testing.assert_array_equal(body.nonskin, ref["nonskin"].astype(np.uint8))
    assert m.textures["nonskin"] is body.nonskin
    assert body.nevi == [[3, 4, 8, 10], [40, 20, 44, 23]]
    assert body.meta["id"] == "006-f-run" and body.meta["source"] == "3dbodytex"
    json.dumps(body.meta)


def test_bodytex_alpha_mask_and_texture_fallback(scan):
    folder, ref = scan
    # no map_Kd: the PNG named like the OBJ is the texture
    (folder / f"{OBJ}.mtl").write_text("newmtl material_0\nKd 1 1 1\n")
    # the mask in the alpha channel of an otherwise white RGBA image
    rgba = np.full((TEX_H, TEX_W, 4), 255, np.uint8)
    rgba[..., 3] = np.where(ref["nonskin"], 255, 0)
    os.remove(folder / "nonskin_mask.png")
    cv2.imwrite(str(folder / "scan_non_skin.png"), rgba)
    body = load_bodytex(folder)
    np.testing.assert_array_equal(body.mesh.texture, ref["tex"])
    np.testing.assert_array_equal(body.nonskin, ref["nonskin"].astype(np.uint8))


def test_bodytex_optional_parts_absent(scan):
    folder, _ = scan
    for name in ("nonskin_mask.png", "vertslabels_scan.npy", "skin3d_nevi.csv"):
        os.remove(folder / name)
    body = load_bodytex(folder)
    assert body.anatomy is None and body.mesh.vertex_labels is None
    assert body.nevi == [] and not body.nonskin.any()


@pytest.mark.parametrize("header,row,expected", [
    ("x0,y0,x1,y1", "3,4,8,10", [3, 4, 8, 10]),
    ("xmin,ymin,xmax,ymax", "3,4,8,10", [3, 4, 8, 10]),
    ("x,y,w,h", "3,4,5,6", [3, 4, 8, 10]),
    ("X,Y,Width,Height", "60,28,10,10", [60, 28, 64, 32]),  # clipped to the texture
])
def test_nevi_csv_formats(tmp_path, header, row, expected):
    p = tmp_path / "nevi.csv"
    p.write_text(f"{header}\n{row}\n")
    assert read_nevi(p, (TEX_H, TEX_W)) == [expected]


def _labels_path(folder):
    return folder / "vertslabels_scan.npy"


@pytest.mark.parametrize("case,match", [
    ("count", r"vertslabels_scan\.npy: 71 anatomy labels for 72 mesh vertices"),
    ("range", r"vertslabels_scan\.npy: 1 labels outside 1\.\.16"),
    ("zero", r"vertslabels_scan\.npy: 1 labels outside 1\.\.16"),
    ("fraction", r"vertslabels_scan\.npy: 1 labels are not whole numbers"),
    ("nan", r"vertslabels_scan\.npy: 1 labels are not whole numbers"),
])
def test_bodytex_bad_labels(scan, case, match):
    folder, _ = scan
    labels = np.load(_labels_path(folder))
    if case == "count":
        labels = labels[:-1]
    else:
        labels[5] = {"range": 17.0, "zero": 0.0, "fraction": 2.5, "nan": np.nan}[case]
    np.save(_labels_path(folder), labels)
    with pytest.raises(BodyError, match=match):
        load_bodytex(folder)


def test_bodytex_bad_files(scan, tmp_path):
    folder, _ = scan
    cv2.imwrite(str(folder / "nonskin_mask.png"), np.zeros((TEX_H, TEX_W + 1), np.uint8))
    with pytest.raises(BodyError, match=r"nonskin_mask\.png: non-skin mask is 65x32 but the texture is 64x32"):
        load_bodytex(folder)
    os.remove(folder / "nonskin_mask.png")

    (folder / "skin3d_nevi.csv").write_text("a,b\n1,2\n")
    with pytest.raises(BodyError, match=r"skin3d_nevi\.csv: no box columns"):
        load_bodytex(folder)
    (folder / "skin3d_nevi.csv").write_text("x,y,w,h\n1,2,-3,4\n")
    with pytest.raises(BodyError, match=r"skin3d_nevi\.csv: row 2: empty box"):
        load_bodytex(folder)
    os.remove(folder / "skin3d_nevi.csv")

    os.remove(folder / f"{OBJ}.png")
    with pytest.raises(gs.MeshError, match=rf"{OBJ}\.mtl: texture '{OBJ}\.png' named by map_Kd not found"):
        load_bodytex(folder)
    (folder / f"{OBJ}.mtl").write_text("newmtl material_0\n")
    with pytest.raises(BodyError, match=rf"{OBJ}\.obj: no texture"):
        load_bodytex(folder)

    os.remove(folder / f"{OBJ}.obj")
    with pytest.raises(BodyError, match=rf"006-f-run: no {OBJ}\.obj"):
        load_bodytex(folder)
    with pytest.raises(BodyError, match="scan folder not found"):
        load_bodytex(tmp_path / "missing")


# ---- generic meshes: xatlas UVs and baked vertex colours ----------------------------------
RADIUS = 0.3


def vertex_colours(v):
    return np.clip(np.rint(127.5 + 127.5 * v / RADIUS), 0, 255).astype(np.uint8)


@pytest.fixture
def ply_sphere(tmp_path):
    s = trimesh.creation.icosphere(subdivisions=2, radius=RADIUS)
    s.visual = trimesh.visual.ColorVisuals(s, vertex_colors=vertex_colours(np.asarray(s.vertices)))
    path = tmp_path / "sphere.ply"
    s.export(path)
    return path, np.asarray(s.vertices), np.asarray(s.faces)


def test_xatlas_uvs_and_baked_colours(ply_sphere):
    path, verts, faces = ply_sphere
    size = 256
    body = load_mesh_body(path, texture_size=size)
    m = body.mesh
    np.testing.assert_allclose(m.vertices, verts, atol=1e-6)
    np.testing.assert_array_equal(m.faces, faces)
    assert body.anatomy is None and body.meta["uvs"] == "xatlas"
    assert m.texture.shape == (size, size, 3) and body.nonskin.shape == (size, size)
    assert m.face_uvs.shape == faces.shape
    assert m.uvs.min() >= 0 and m.uvs.max() <= 1
    tri = m.uvs[m.face_uvs]
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    uv_area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    assert (uv_area > 0).all(), "every face needs its own piece of texture"

    # bilinear samples of the texture at each corner's UV reproduce the vertex colour
    uv = m.uvs[m.face_uvs].reshape(-1, 2)
    mx = (uv[:, 0] * size - 0.5).astype(np.float32)[None]
    my = ((1 - uv[:, 1]) * size - 0.5).astype(np.float32)[None]
    sampled = cv2.remap(m.texture.astype(np.float32), mx, my, cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE)[0]
    expected = vertex_colours(verts)[faces.reshape(-1)].astype(np.float32)
    err = np.abs(sampled - expected)
    assert err.mean() < 1.0 and err.max() < 6, (err.mean(), err.max())


def test_baked_texture_renders_vertex_colours(ply_sphere, gl_backend):
    from gl_context import get_renderer
    path, verts, _ = ply_sphere
    body = load_mesh_body(path, texture_size=256)
    r = get_renderer(gl_backend, 64, 64)
    cam = gs.Camera.look_at((0.4, 0.3, 1.2), (0, 0, 0), width=64, height=64)
    flat = [gs.PointLight(cam.eye, ambient=1.0, diffuse=0.0, specular=0.0)]
    out = r.render(body.mesh, cam, passes=("gbuffer", "rgb"), lights=flat,
                   material=gs.Material(specular=0.0))
    assert r.ctx.error == "GL_NO_ERROR"
    fg = out["face_id"] >= 0
    assert 0.1 < fg.mean() < 0.9
    corners = body.mesh.faces[out["face_id"][fg]]
    expected = np.einsum("nk,nkc->nc", out["bary"][fg], vertex_colours(verts)[corners].astype(float))
    err = np.abs(out["rgb"][fg] * 255 - expected)
    assert err.mean() < 1.5 and np.percentile(err, 99) < 6, (err.mean(), err.max())


def test_generic_mesh_scaling_grey_and_errors(tmp_path, ply_sphere):
    s = trimesh.creation.icosphere(subdivisions=1, radius=0.5)
    path = tmp_path / "plain.off"
    s.export(path)
    body = load_mesh_body(path, scale_to_height=1.7, texture_size=64,
                          anatomy=np.full(len(s.vertices), 3.0))
    assert np.ptp(body.mesh.vertices[:, 1]) == pytest.approx(1.7)
    assert body.meta["scale"] == pytest.approx(1.7 / np.ptp(s.vertices[:, 1]))
    assert len(np.unique(body.mesh.texture.reshape(-1, 3), axis=0)) == 1  # grey
    np.testing.assert_array_equal(body.anatomy, 3)
    with pytest.raises(BodyError, match=r"anatomy labels: 3 anatomy labels for 42"):
        load_mesh_body(path, anatomy=[1, 2, 3], texture_size=64)
    with pytest.raises(BodyError, match=r"plain\.off: has no UVs, so the non-skin mask"):
        load_mesh_body(path, nonskin=tmp_path / "mask.png", texture_size=64)
    with pytest.raises(ValueError, match="scale_to_height"):
        load_mesh_body(path, scale_to_height=-1, texture_size=64)


def test_ensure_uvs_leaves_textured_mesh_alone(scan):
    folder, _ = scan
    m = load_bodytex(folder).mesh
    assert ensure_uvs(m) is m


# ---- scan folders as the paper uses them -------------------------------------------------
def _skin_coloured(folder, rgb):
    """Give a written scan a uniform skin colour (the non-skin patch stays random)."""
    tex = cv2.imread(str(folder / f"{OBJ}.png"))[..., ::-1].copy()
    nonskin = cv2.imread(str(folder / "nonskin_mask.png"), cv2.IMREAD_UNCHANGED)[..., 0] > 0
    tex[~nonskin] = rgb
    cv2.imwrite(str(folder / f"{OBJ}.png"), tex[..., ::-1])


def test_scans_are_chosen_to_span_skin_tone(tmp_path, rng, monkeypatch):
    """7 scans whose names sort opposite to their skin tone: 3 of them are the lightest,
    the middle and the darkest (the paper's choice of 50 scans over the ITA range), not
    the first 3 names; ITA is measured on skin texels only and cached."""
    from glsynth.assets import ita_degrees
    from glsynth.config import load_config
    from glsynth.pipeline import bodies as pb
    monkeypatch.setenv("GLSYNTH_CACHE", str(tmp_path / "cache"))
    root = tmp_path / "scans"
    greys = np.linspace(235, 60, 7).astype(np.uint8)       # lightest first
    colours = [(int(g), int(g * 0.78), int(g * 0.66)) for g in greys]
    for i, rgb in enumerate(colours):
        folder = root / f"{90 - i:03d}-scan"                   # lightest has the last name
        write_scan(folder, rng)
        _skin_coloured(folder, rgb)
    cfg = load_config(None, [f"bodies.source={root}", "bodies.count=3"])
    ids = pb.body_ids(cfg)
    assert ids == ["084-scan", "087-scan", "090-scan"]       # darkest, middle, lightest
    body = load_bodytex(root / "087-scan")
    assert body.meta["ita"] == pytest.approx(float(ita_degrees(np.array(colours[3], np.uint8))), abs=1e-9)
    # the second call reads the cache, not the scans
    monkeypatch.setattr("glsynth.assets.bodytex.load_bodytex", lambda f: pytest.fail("re-measured"))
    assert pb.body_ids(cfg) == ids
    cfg_all = load_config(None, [f"bodies.source={root}", "bodies.count=50"])
    assert pb.body_ids(cfg_all) == sorted(os.listdir(root))
    # two shards of 2 hold the scans of a run of 4, and every prefix spans the range
    shards = [pb.body_ids(load_config(None, [f"bodies.source={root}", "bodies.count=2", f"bodies.first={f}"]))
              for f in (0, 2)]
    four = pb.body_ids(load_config(None, [f"bodies.source={root}", "bodies.count=4"]))
    assert shards[0] == ["084-scan", "090-scan"] and sorted(shards[0] + shards[1]) == four
    with pytest.raises(FileNotFoundError, match="bodies.first"):
        pb.body_ids(load_config(None, [f"bodies.source={root}", "bodies.first=7"]))


@pytest.mark.parametrize("axis,sign", [(2, 1), (2, -1), (0, 1), (1, -1)])
def test_scan_up_axis_is_detected_and_recorded(tmp_path, rng, axis, sign):
    """The same scan stored with its height along +-Z, +X or -Y loads as the +Y-up
    original (vertices equal), and meta records the axis found."""
    folder = tmp_path / "upright"
    ref = write_scan(folder, rng)
    upright = load_bodytex(folder)
    assert upright.meta["up_axis"] == "+y" and np.array_equal(upright.meta["rotation"], np.eye(3))
    # rotate the file's vertices so that the body's up (+Y) points along sign * axis
    target = np.zeros(3)
    target[axis] = sign
    other = [a for a in range(3) if a != axis][0]
    rot = np.zeros((3, 3))
    rot[:, 1] = target                                     # +Y -> target
    rot[other, 0] = 1.0                                    # +X -> another axis
    rot[:, 2] = np.cross(rot[:, 0], rot[:, 1])             # right-handed
    lines = (folder / f"{OBJ}.obj").read_text().splitlines()
    v = iter(ref["v"] @ rot.T)
    out = [("v " + " ".join(f"{c:.9f}" for c in next(v))) if ln.startswith("v ") else ln for ln in lines]
    (folder / f"{OBJ}.obj").write_text("\n".join(out) + "\n")
    body = load_bodytex(folder)
    assert body.meta["up_axis"] == f"{'+' if sign > 0 else '-'}{'xyz'[axis]}"
    # up is +Y again: the head (label 1) on top; the turn about the up axis is free
    assert np.ptp(body.mesh.vertices[:, 1]) == pytest.approx(np.ptp(ref["v"][:, 1]))
    head, feet = body.anatomy == 1, np.isin(body.anatomy, (9, 10))
    assert body.mesh.vertices[head, 1].mean() > body.mesh.vertices[feet, 1].mean()
    np.testing.assert_allclose(body.mesh.vertices[:, 1], ref["v"][:, 1], atol=1e-8)
    r = np.asarray(body.meta["rotation"])
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)


def test_scan_nevi_are_a_pixel_target(tmp_path, rng):
    """Skin3D's nevus boxes of a scan folder rendered as a target (the paper's nevus
    mask): targets/{id}_nevi.png holds nevus ids exactly where the boxes are seen, the
    JSON's boxes are those of the mask, and the dataset loads it."""
    from glsynth.dataset import SynthDataset
    root = tmp_path / "scans"
    folder = root / "006-f-run"
    write_scan(folder, rng)
    # faces wound outwards (the fixture's face inwards), so that cameras sit outside
    lines = (folder / f"{OBJ}.obj").read_text().splitlines()
    (folder / f"{OBJ}.obj").write_text("\n".join(
        "f " + " ".join(ln.split()[1:][::-1]) if ln.startswith("f ") else ln for ln in lines) + "\n")
    # two large boxes (texels), so that most views see one
    (folder / "skin3d_nevi.csv").write_text("x0,y0,x1,y1\n0,8,30,32\n34,8,64,20\n")
    out = tmp_path / "out"
    cfg = gs.load_config(None, [f"bodies.source={root}", "lesions.per_body=0", "views.per_body=4",
                                "views.size=64", "views.min_skin=0.02", "views.w=[0.6, 1.2]",
                                "backgrounds.count=2", "outputs=[rgb, semantic, nevi]", "seed=3"])
    gs.pipeline.generate(cfg, out)
    ds = SynthDataset(out, targets=("semantic", "nevi"))
    assert len(ds) >= 3
    seen = 0
    for item in ds:
        nevi, semantic = item["nevi"].numpy(), item["semantic"].numpy()
        assert nevi.shape == semantic.shape and set(np.unique(nevi)) <= {0, 1, 2}
        assert (semantic[nevi > 0] != 0).all()              # only on the body
        boxes = {n["id"]: n["box"] for n in item["meta"]["nevi"]}
        assert sorted(boxes) == sorted(set(np.unique(nevi)) - {0})
        for k, (x0, y0, x1, y1) in boxes.items():
            ys, xs = np.nonzero(nevi == k)
            assert [xs.min(), ys.min(), xs.max() + 1, ys.max() + 1] == [x0, y0, x1, y1]
        seen += bool(boxes)
    assert seen, "no view saw a nevus"
