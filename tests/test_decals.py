"""Lesion decals (glsynth.pipeline.decals, shaders/decal.glsl): labels as sharp as a
full-resolution texture of the same data, the torch path agreeing with GL, relief that
changes shading and never labels."""
import math

import numpy as np
import pytest
import torch

import glsynth as gs
from glsynth import diff
from glsynth.lighting import Material, PointLight
from glsynth.pipeline.decals import Decals, projection_rows


def plane_with_decal(rng, d=128, tex=64, ids=None, colour=None, aux=None, region_size=32, scale=1.0):
    """The z = 0 square [-1, 1]^2 times ``scale`` (UV = (x / scale + 1) / 2, ...) with one
    decal seen from straight above that covers [-0.5, 0.5]^2 times ``scale`` with d x d
    pixels."""
    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float) * scale
    f = np.array([[0, 1, 2], [0, 2, 3]])
    texture = (rng.random((tex, tex, 3)) * 255).astype(np.uint8)
    half = math.tan(math.radians(30.0) / 2)
    cam = gs.Camera.look_at((0.0, 0.0, 0.5 * scale / half), (0.0, 0.0, 0.0), up=(0, 1, 0), fov_deg=30.0,
                            width=d, height=d)
    view = cam.view_matrix()
    region = np.zeros((region_size, region_size), np.uint16)
    q = region_size // 4
    region[q:3 * q, q:3 * q] = 1                          # texels over [-0.5, 0.5]^2
    if ids is None:
        ids = np.zeros((d, d), np.uint16)
        for k in range(1, 4):                             # three blobs, ids 3..5
            c = rng.uniform(0.2 * d, 0.8 * d, 2)
            yy, xx = np.mgrid[0:d, 0:d]
            ids[(yy - c[0]) ** 2 + (xx - c[1]) ** 2 < rng.uniform(0.05, 0.15) ** 2 * d * d] = k + 2
    if colour is None:
        colour = (rng.random((d, d, 4)) * 255).astype(np.uint8)
        colour[..., 3] = 255
    if aux is None:
        aux = np.full((d, d, 4), (128, 128, 0, 128), np.uint8)
    decals = Decals(region, projection_rows(cam)[None], np.stack([view[0, :3], -view[1, :3]])[None],
                    np.array([scale / d]), colour[None], aux[None], ids[None])
    mesh = gs.Mesh(v, f, uvs=(v[:, :2] / scale + 1) / 2, texture=texture, name="decal-plane", decals=decals)
    return mesh, decals


def random_view(renderer, rng, dist=(0.6, 2.0)):
    d = rng.normal(size=3) * np.array([0.4, 0.4, 0.0]) + np.array([0, 0, 1.0])
    eye = d / np.linalg.norm(d) * rng.uniform(*dist)
    return gs.Camera.look_at(eye, (rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2), 0.0), up=(0, 1, 0),
                             fov_deg=rng.uniform(25, 45), width=renderer.width, height=renderer.height)


def test_decal_labels_equal_a_full_resolution_texture(renderer, rng):
    """The decal's ids, read through the region map and the projection, give the same
    label pixels as a label texture at the decal's resolution holding the same ids."""
    d = 128
    mesh, decals = plane_with_decal(rng, d=d)
    full = np.zeros((2 * d, 2 * d), np.uint16)            # texel i covers x in [-1 + i/d, ...)
    full[d // 2:d // 2 + d, d // 2:d // 2 + d] = decals.instances[0]
    coarse = np.zeros((32, 32), np.uint16)                 # what a body texture would hold
    for _ in range(3):
        for _ in range(20):          # a close random view may miss all three blobs: redraw
            cam = random_view(renderer, rng)
            b = renderer.render(mesh.copy_with(decals=None), cam, passes=("labels",),
                                label_textures={"instances": full})["instances"]
            if (b > 0).sum() > 200:
                break
        assert (b > 0).sum() > 200, "20 random views saw no blob"
        a = renderer.render(mesh, cam, passes=("labels",), label_textures={"instances": coarse},
                            decal_labels="instances")["instances"]
        differ = a != b
        assert differ.mean() < 0.002, f"{differ.sum()} of {differ.size} label pixels differ"
        # the few that differ lie on an edge between ids (rounding of the same boundary)
        edge = np.zeros_like(differ)
        edge[1:-1, 1:-1] = (b[1:-1, 1:-1] != b[:-2, 1:-1]) | (b[1:-1, 1:-1] != b[2:, 1:-1]) | \
            (b[1:-1, 1:-1] != b[1:-1, :-2]) | (b[1:-1, 1:-1] != b[1:-1, 2:])
        edge = np.maximum.reduce([np.roll(edge, s, a_) for s in (-1, 0, 1) for a_ in (0, 1)])
        assert edge[differ].all()


@pytest.mark.parametrize("model", ["phong", "skin"])
def test_torch_matches_gl_with_decals(renderer, rng, model):
    """Decal colour, coverage, relief and gloss through glsynth.diff agree with the GL
    shading within 2/255, magnified and minified (mipmapped) alike."""
    d = 256
    colour = (rng.random((d, d, 4)) * 255).astype(np.uint8)
    yy, xx = np.mgrid[0:d, 0:d] / d
    colour[..., 3] = np.clip(255 * (1.5 - 3 * np.hypot(yy - 0.5, xx - 0.5)), 0, 255).astype(np.uint8)
    aux = np.empty((d, d, 4), np.uint8)
    aux[..., 0] = 128 + (40 * np.sin(12 * xx)).astype(np.int64)
    aux[..., 1] = 128 + (40 * np.cos(9 * yy)).astype(np.int64)
    aux[..., 2] = (255 * xx).astype(np.uint8)
    aux[..., 3] = 128
    mesh, _ = plane_with_decal(rng, d=d, colour=colour, aux=aux)
    mat = Material() if model == "phong" else Material(model="skin", detail=False, wrap=0.2)
    for dist in ((0.5, 0.8), (2.0, 4.0)):                  # decal magnified / minified
        cam = random_view(renderer, rng, dist)
        lights = [PointLight(np.asarray(cam.eye) + rng.normal(scale=0.3, size=3), ambient=0.3, diffuse=0.7)]
        out = renderer.render(mesh, cam, passes=("gbuffer", "rgb"), lights=lights, material=mat)
        img = diff.shade(out, mesh, torch.tensor(mesh.texture / 255.0, dtype=torch.float32), cam, lights, mat)
        fg = out["face_id"] >= 0
        err = np.abs(img.numpy() - out["rgb"])[fg]
        assert err.max() <= 2 / 255, f"{model} at {dist}: max |torch - GL| {err.max() * 255:.2f}/255"


def test_relief_changes_shading_but_not_labels(renderer, rng):
    d = 128
    flat, decals = plane_with_decal(rng, d=d)
    aux = decals.aux[0].copy()
    aux[..., 0] = 128 + (60 * np.sin(np.arange(d) / 3.0))[None, :].astype(np.int64)
    bumpy, _ = plane_with_decal(rng, d=d, ids=decals.instances[0], colour=decals.colour[0], aux=aux)
    bumpy = bumpy.copy_with(texture=flat.texture)
    cam = random_view(renderer, rng, (0.6, 1.0))
    light = [PointLight(np.asarray(cam.eye) + [0.5, 0.3, 0.0], ambient=0.2, diffuse=0.9)]
    coarse = np.zeros((32, 32), np.uint16)
    outs = [renderer.render(m, cam, passes=("labels", "rgb"), label_textures={"instances": coarse},
                            decal_labels="instances", lights=light,
                            material=Material(model="skin", detail=False)) for m in (flat, bumpy)]
    assert (outs[0]["instances"] == outs[1]["instances"]).all()
    assert np.abs(outs[0]["rgb"] - outs[1]["rgb"]).mean() > 2 / 255


def test_body_hair_lies_across_a_lesion(gl_backend, rng):
    """Terminal hairs rooted around a lesion lie across it: over a smooth lesion decal
    (micro-relief visibility 0.2, a stretched nodule) on hairy skin, hair changes the
    image at least 0.4 times as much as on the skin around (0.6-0.75; it was 0.02: the lesion's
    smoothness switched terminal hair off, a hairless patch that real hairy skin does not
    show). The reference is the same view with hair density 0."""
    from gl_context import get_renderer

    from glsynth.mesh import SkinSurface
    renderer = get_renderer(gl_backend, 256, 256)
    d, scale = 256, rng.uniform(0.015, 0.025)               # a 1.5-2.5 cm lesion
    colour = np.empty((d, d, 4), np.uint8)
    colour[:] = (200, 160, 140, 255)                         # the skin's own colour
    aux = np.full((d, d, 4), (128, 128, 0, round(255 * 0.2 / 2.0)), np.uint8)
    plane, _ = plane_with_decal(rng, d=d, colour=colour, aux=aux, scale=scale)
    plane = plane.copy_with(texture=np.full((64, 64, 3), (200, 160, 140), np.uint8))
    cam = gs.Camera.look_at((0.0, 0.0, 1.2 * scale / math.tan(math.radians(15))), (0.0, 0.0, 0.0),
                            up=(0, 1, 0), fov_deg=30.0, width=256, height=256)
    light = [PointLight(np.asarray(cam.eye) + scale * np.array([0.5, 0.8, 0.5]), ambient=0.2, diffuse=0.9)]
    hair_st = plane.vertices[plane.faces][..., :2].astype(np.float32)
    imgs = []
    for density in (255, 0):
        prm = np.zeros((16, 16, 4), np.uint8)
        prm[:] = (140, 80, density, 80)
        mesh = plane.copy_with(skin=SkinSurface(prm, None, hair_st, (50, 35, 28), hair_curl=0.0))
        imgs.append(renderer.render(mesh, cam, passes=("rgb",), lights=light,
                                    material=Material(model="skin", detail=True))["rgb"])
    change = np.abs(imgs[0] - imgs[1]).mean(-1)
    r = np.abs(np.mgrid[0:256, 0:256] + 0.5 - 128).max(0) / 128 * 1.2 * scale   # |x|, |y| max
    inside, around = change[r < 0.4 * scale].mean(), change[(r > 0.6 * scale) & (r < scale)].mean()
    assert around > 0.02 and inside > 0.4 * around, (inside, around)


def test_condition_decal_hides_the_texture_copy_of_its_outline(rng):
    """Pasting also paints a procedural condition into the body texture, at texel
    resolution; a close-up must show the decal's sharp outline and clean skin around it,
    not that coarse copy bleeding past the edge (it showed as a dark halo with a pale rim
    inside it). Rendered over the pasted texture and over the original one, the decal's
    surroundings look the same."""
    import cv2

    from glsynth.assets.lesions import ProceduralLesions
    from glsynth.pipeline.bodies import TexelGeometry
    from glsynth.pipeline.decals import build_decals
    from glsynth.pipeline.paste import PasteSettings, paste_lesions
    from shapes import skin_sheet

    size = 256
    r = gs.Renderer(size, size)
    body = skin_sheet(rng, tex=512, amplitude=10)
    tx = TexelGeometry.of(r, body.mesh)
    lesion = ProceduralLesions(1, seed=int(rng.integers(1000)), size=128, kinds=["melanoma"],
                               fitzpatrick=int(rng.integers(1, 7)))[0]
    settings = PasteSettings(view_size=size, w=(0.05, 0.06), size=(0.3, 0.5), max_depth_change=0.05)
    pasted = paste_lesions(r, body, tx, [lesion], settings, ("halo",), int(rng.integers(1000)))
    p = pasted.placements[0]
    decals = build_decals(r, body.mesh, tx, pasted.original, pasted.pasted, pasted.pasted,
                          pasted.placements, lambda _: lesion, size=512)
    cam = gs.Camera.from_dict(p.camera)                   # the placement view: 5-6 cm wide
    unlit = [PointLight((0, 0, 0), ambient=1.0, diffuse=0.0, specular=0.0)]
    on = {name: r.render(body.mesh.copy_with(texture=t, decals=decals), cam, passes=("rgb", "labels"),
                         lights=unlit, material=Material(0.0, 1.0),
                         label_textures={"instances": np.zeros(t.shape[:2], np.uint16)},
                         decal_labels="instances")
          for name, t in (("pasted", pasted.pasted), ("original", pasted.original))}
    lesion_px = on["pasted"]["instances"] > 0
    assert 0.02 < lesion_px.mean() < 0.9
    # a band of one and a half body texels (0.6 m / 512) outside the outline, in view pixels
    view_w = 2 * np.linalg.norm(np.subtract(cam.eye, cam.target)) * math.tan(math.radians(cam.fov_deg) / 2)
    texel_px = size / view_w * 0.6 / 512
    dist = cv2.distanceTransform((~lesion_px).astype(np.uint8), cv2.DIST_L2, 5)
    band = (dist > 0) & (dist <= 1.5 * texel_px)
    assert band.sum() > 100, (band.sum(), texel_px)
    diff_ = np.abs(on["pasted"]["rgb"] - on["original"]["rgb"]).max(-1)
    # (without the widened coverage: up to 25-70 levels darker next to the outline)
    assert diff_[band].mean() < 0.1 / 255 and diff_[band].max() <= 1 / 255, \
        (diff_[band].mean() * 255, diff_[band].max() * 255)


def test_a_condition_records_the_skin_type_it_is_drawn_on(rng):
    """A procedural condition is drawn on the body's own skin, not on the reference swatch
    it was made on: its placement (and so each view's lesion record) gives the body's
    Fitzpatrick type, and the swatch's as reference_fitzpatrick."""
    from glsynth.assets.lesions import ProceduralLesions
    from glsynth.pipeline.bodies import TexelGeometry
    from glsynth.pipeline.paste import PasteSettings, paste_lesions
    from shapes import skin_sheet

    reference = int(rng.integers(1, 7))
    own = reference % 6 + 1
    with gs.Renderer(128, 128) as r:
        body = skin_sheet(rng, tex=256, amplitude=10)
        body.meta = {"fitzpatrick": own}
        tx = TexelGeometry.of(r, body.mesh)
        lesion = ProceduralLesions(1, seed=int(rng.integers(1000)), size=64, fitzpatrick=reference)[0]
        settings = PasteSettings(view_size=128, w=(0.05, 0.06), size=(0.3, 0.5), max_depth_change=0.05)
        pasted = paste_lesions(r, body, tx, [lesion], settings, ("skin type",), int(rng.integers(1000)))
    meta = pasted.placements[0].lesion_meta
    assert lesion.meta["fitzpatrick"] == reference
    assert meta["fitzpatrick"] == own and meta["reference_fitzpatrick"] == reference


def test_a_texel_shows_the_decal_that_covers_it_most(rng):
    """Where two decals' coverage overlaps (a small lesion in the fading edge of a large
    one), each texel takes the decal that covers it more, whichever was built first: the
    small lesion is not cut off along body texels. Margin rings only take free texels."""
    from glsynth.pipeline.decals import _mark_region

    n = 24
    rows, cols = np.mgrid[0:n, 0:n]
    seen = (rows.ravel(), cols.ravel(), cols.ravel(), rows.ravel())   # decal pixel = texel
    faint = np.zeros((n, n), np.uint8)
    faint[:, : n // 2 + 4] = rng.integers(1, 60)                      # a large lesion's fading edge
    small = np.zeros((n, n), np.uint8)
    r0, c0 = rng.integers(4, n - 8, 2)
    small[r0:r0 + 4, c0:c0 + 4] = 255                                 # a small lesion
    small[r0 - 1:r0 + 5, c0 - 1:c0 + 5] = np.maximum(small[r0 - 1:r0 + 5, c0 - 1:c0 + 5], 30)
    want = np.where(small > faint, 2, np.where(faint > 0, 1, np.where(small > 0, 2, 0)))
    # at equal coverage the decal built first keeps the texel (seed 2979197531 drew the
    # fading edge at 30, the small lesion's rim)
    tie = (small == faint) & (small > 0)
    for order in ((1, 2), (2, 1)):
        region = np.zeros((n, n), np.uint16)
        owner = np.zeros((n, n), np.uint8)
        for layer in order:
            _mark_region(region, owner, layer, seen, faint if layer == 1 else small, margin=1)
        core = want > 0
        assert (region[core] == np.where(tie, order[0], want)[core]).all(), order
        # the ring around the small lesion's coverage goes to it where it is free (not
        # the large one's, nor in the large one's own ring)
        ring = ((want == 0) & (np.abs(rows - (r0 + 1.5)) <= 3.5) & (np.abs(cols - (c0 + 1.5)) <= 3.5)
                & (cols > n // 2 + 4))
        assert (region[ring] == 2).all(), order
