"""Skin shading (shaders/skin.frag): the torch twin, micro-detail that does not alias and
stays off non-skin, no NaN from a flash at the lens, tiles that tile, hair coordinates."""
import dataclasses

import numpy as np
import pytest
import torch
import trimesh

import glsynth as gs
from glsynth import diff
from glsynth.assets import detail
from glsynth.assets.hairflow import hair_coordinates, hair_flow_quality, t_scale_at_corners
from glsynth.lighting import Material, PointLight
from glsynth.mesh import SkinSurface, grid_faces
from shapes import box, sphere, textured_view


def _skin_material(rng, **kw):
    return Material(model="skin", wrap=rng.uniform(0, 0.5), roughness=rng.uniform(0.2, 0.7),
                    oil=rng.uniform(0, 1), **kw)


@pytest.mark.parametrize("trial", range(6))
def test_torch_skin_reflectance_matches_gl(renderer, rng, trial):
    """The last two trials carry random per-vertex ambient occlusion."""
    mesh, tex, cam = textured_view(renderer, rng, sphere if trial % 2 == 0 else box, max_texture=200)
    if trial >= 4:
        mesh = mesh.copy_with(occlusion=rng.uniform(0, 1, len(mesh.vertices)))
    lights = []
    for _ in range(int(rng.integers(1, 3))):
        p = np.asarray(cam.eye) + rng.normal(scale=0.3, size=3)
        lights.append(PointLight(p, ambient=rng.uniform(0, 0.6), diffuse=rng.uniform(0.2, 1.5),
                                 falloff_distance=rng.choice([0.0, np.linalg.norm(p) * rng.uniform(0.3, 1.5)]),
                                 ambient_ground=rng.choice([1.0, rng.uniform(0, 1)])))
    lights.append(PointLight(cam.eye, ambient=0.0, diffuse=rng.uniform(0.2, 0.6),  # a flash
                             falloff_distance=np.linalg.norm(cam.eye) * rng.uniform(0.5, 1.2),
                             beam_axis=np.asarray(cam.target) - cam.eye, beam_exponent=rng.uniform(0, 30)))
    mat = _skin_material(rng, detail=False)
    out = renderer.render(mesh, cam, passes=("gbuffer", "rgb"), lights=lights, material=mat)
    img = diff.shade(out, mesh, torch.tensor(tex / 255.0, dtype=torch.float32), cam, lights, mat)
    fg = out["face_id"] >= 0
    assert fg.sum() > 100
    assert np.isfinite(out["rgb"]).all()
    err = np.abs(img.numpy() - out["rgb"])[fg]
    assert err.max() <= 2 / 255, f"max |torch - GL| = {err.max() * 255:.2f}/255"


def _skin_plane(rng, half=0.5, n=24, weight=None, params=(170, 200, 255, 150), tex_size=64, scalp=None):
    """A flat square (normal +Z, metres) with a uniform skin texture, skin parameters and
    hair coordinates along +x (scalp: optional scalp hair coverage, straight hair)."""
    xs = np.linspace(-half, half, n)
    xx, yy = np.meshgrid(xs, xs)
    v = np.stack([xx.ravel(), yy.ravel(), np.zeros(n * n)], 1)
    f = grid_faces(n)
    uv = (v[:, :2] + half) / (2 * half)
    tex = np.full((tex_size, tex_size, 3), (196, 150, 128), np.uint8)
    hair = v[f][..., :2].astype(np.float32)            # s = x, t = y
    prm = np.zeros((16, 16, 4), np.uint8)
    prm[:] = params
    skin = SkinSurface(prm, weight, hair, (40, 30, 25), scalp_hair=scalp, hair_curl=0.0)
    return gs.Mesh(v, f, uvs=uv, texture=tex, name="skin-plane", skin=skin)


def _look_down(renderer, w, x=0.0):
    return gs.Camera.look_at((x, 0.0, w), (x, 0.0, 0.0), up=(0, 1, 0), fov_deg=30,
                             width=renderer.width, height=renderer.height)


def _lap_energy(img):
    lum = img.mean(-1)
    return np.abs(lum[1:-1, 1:-1] * 4 - lum[:-2, 1:-1] - lum[2:, 1:-1] - lum[1:-1, :-2] - lum[1:-1, 2:]).mean()


def test_detail_does_not_alias_far_away(renderer, rng):
    """Far views with and without the relief, pores and speckle have the same mean colour
    (within 1/255): the tiles are mip-filtered to their mean and their albedo changes
    average out. Hair tints a far view (as it should) but adds no pixel noise: its
    high-frequency energy stays that of the image without detail."""
    no_hair = _skin_plane(rng, half=10.0, params=(255, 255, 0, 150))
    hairy = _skin_plane(rng, half=10.0, params=(255, 255, 255, 150))
    for w in (3.0, 8.0):
        cam = _look_down(renderer, w, x=rng.uniform(-2, 2))
        lights = [PointLight(np.asarray(cam.eye) + [0.3 * w, 0.2 * w, 0], ambient=0.3, diffuse=0.8)]
        imgs = []
        for mesh, det in ((no_hair, False), (no_hair, True), (hairy, True)):
            mat = Material(model="skin", roughness=0.45, oil=0.0, detail=det)
            imgs.append(renderer.render(mesh, cam, passes=("rgb",), lights=lights, material=mat)["rgb"] * 255)
        means = [im.reshape(-1, 3).mean(0) for im in imgs]
        assert np.abs(means[0] - means[1]).max() <= 1.0, (w, means)
        assert _lap_energy(imgs[2]) < _lap_energy(imgs[0]) + 1.0, (w, _lap_energy(imgs[2]))


def test_detail_shows_up_close(renderer, rng):
    """At a tenth of a millimetre per pixel the relief, pores and hair make texture
    that a body texture cannot (the reference: the same view without detail)."""
    mesh = _skin_plane(rng)
    cam = _look_down(renderer, 0.04, x=rng.uniform(-0.1, 0.1))
    lights = [PointLight(np.asarray(cam.eye) + [0.03, 0.03, 0], ambient=0.2, diffuse=0.9)]
    grads = []
    for det in (False, True):
        out = renderer.render(mesh, cam, passes=("rgb",), lights=lights,
                              material=Material(model="skin", detail=det))
        lum = out["rgb"].mean(-1)
        grads.append(np.abs(np.diff(lum, axis=1)).mean() / lum.mean())
    assert grads[1] > 10 * grads[0] and grads[1] > 0.01


def test_detail_and_hair_stay_off_non_skin(renderer, rng):
    """Where the detail weight is 0 (non-skin: clothing, scalp hair) the image does not
    depend on the skin parameters at all: no relief, pores or hair; where it is 255
    they change it."""
    weight = np.full((1024, 1024), 255, np.uint8)
    weight[:, :512] = 0                                 # u < 0.5: non-skin (x < 0)
    cam = _look_down(renderer, 0.05)
    lights = [PointLight(np.asarray(cam.eye) + [0.02, 0.03, 0], ambient=0.25, diffuse=0.9)]
    imgs = []
    for params in ((255, 255, 255, 255), (0, 0, 0, 0)):
        mesh = _skin_plane(rng, weight=weight, params=params, tex_size=1024)
        out = renderer.render(mesh, cam, passes=("rgb", "gbuffer"), lights=lights,
                              material=Material(model="skin"))
        imgs.append(out["rgb"])
    uv_u = out["uv"][..., 0]
    nonskin = (uv_u < 0.5 - 2 / 1024) & (out["face_id"] >= 0)   # beyond the bilinear edge
    skin = (uv_u > 0.5 + 2 / 1024) & (out["face_id"] >= 0)
    assert nonskin.sum() > 1000 and skin.sum() > 1000
    assert np.abs(imgs[0] - imgs[1])[nonskin].max() == 0
    assert np.abs(imgs[0] - imgs[1])[skin].mean() > 2 / 255


def test_lipid_codes_put_sebum_and_dryness_on_one_axis(rng):
    """The parameter map's A channel: sebum from XEROSIS_CODES up, dryness below it;
    the code follows oiliness minus dryness, so it is continuous where one gives way
    to the other and a texel never codes both."""
    oil, dry = rng.uniform(0, 1, 500), rng.uniform(0, 1, 500)
    codes = detail.lipid_codes(oil, dry).astype(int)
    order = np.argsort(oil - dry)
    assert (np.diff(codes[order]) >= 0).all()
    assert list(detail.lipid_codes([0, 1, 0, 0.5], [0, 0, 1, 0.5])) == [detail.XEROSIS_CODES, 255, 0,
                                                                         detail.XEROSIS_CODES]
    step = np.abs(np.diff(detail.lipid_codes(np.linspace(0, 0.2, 201), 0.1).astype(int)))
    assert step.max() <= 2


def test_dry_skin_whitens_along_its_lines_up_close_and_evenly_far_away(renderer, rng):
    """Xerosis (the A channel's lowest code) on skin from fair to dark, against skin
    neither dry nor oily (code XEROSIS_CODES), the relief's shading off: up close the
    skin is lighter, in lines and patches (keratin flakes lift along the furrows): the
    lightening varies across the image, its coefficient of variation 0.63-0.75 over skin
    colours, against 0.21-0.24 for the same mean whitening laid evenly; far away, where
    the flakes average out, it is lighter by about as much and as even as the reference
    (mipmaps average their opacity)."""
    t = rng.uniform()                                   # from fair to dark skin
    colour = tuple(int(c) for c in (1 - t) * np.array([225, 185, 165]) + t * np.array([85, 50, 35]))
    meshes = {a: _skin_plane(rng, half=10.0, params=(170, 60, 0, a)) for a in (detail.XEROSIS_CODES, 0)}
    for m in meshes.values():
        m.texture[:] = colour
    gains = {}
    for w in (0.006, 6.0):
        cam = _look_down(renderer, w, x=rng.uniform(-2, 2))
        lights = [PointLight(np.asarray(cam.eye) + [0.4 * w, 0.3 * w, 0], ambient=0.3, diffuse=0.8)]
        mat = Material(model="skin", roughness=0.45, oil=0.5, relief=0.0)
        lum = {a: renderer.render(m, cam, passes=("rgb",), lights=lights, material=mat)["rgb"].mean(-1)
               for a, m in meshes.items()}
        normal, dry = lum[detail.XEROSIS_CODES], lum[0]
        gains[w] = dry.mean() / normal.mean()
        if w < 1:
            lift = dry - normal
            assert lift.std() > 0.45 * lift.mean(), (colour, lift.std() / lift.mean())
        else:
            assert _lap_energy(dry[..., None] * 255) < _lap_energy(normal[..., None] * 255) + 1.0
    assert gains[0.006] > 1.02 and abs(gains[6.0] / gains[0.006] - 1) < 0.05, (colour, gains)


def test_scalp_hair_shows_strands_up_close_and_none_far_away(renderer, rng):
    """Scalp hair (non-skin, SkinSurface.scalp_hair) gets strands at the pixel's scale:
    up close its half of the frame has several times the luminance gradient of the
    other half (non-skin without hair, the same texture), and they run along the hair
    flow (+x: more gradient across, along y). Far away they are filtered out: no more
    pixel noise than the hairless half."""
    size = 1024
    scalp = np.zeros((size, size), np.uint8)
    scalp[:, :size // 2] = 255                         # u < 0.5 (x < 0): scalp hair
    no_weight = np.zeros((size, size), np.uint8)
    mesh = _skin_plane(rng, weight=no_weight, tex_size=size, scalp=scalp)

    def gradients(w, light_offset):
        """|d lum/dx| and |d lum/dy| seen from w, and the hair and hairless pixels."""
        cam = _look_down(renderer, w, x=0.0)
        lights = [PointLight(np.asarray(cam.eye) + light_offset, ambient=0.25, diffuse=0.9)]
        out = renderer.render(mesh, cam, passes=("rgb", "gbuffer"), lights=lights,
                              material=Material(model="skin"))
        lum, u = out["rgb"].mean(-1), out["uv"][..., 0]
        hair = (u < 0.5 - 4 / size) & (out["face_id"] >= 0)
        cloth = (u > 0.5 + 4 / size) & (out["face_id"] >= 0)
        gx, gy = np.abs(np.diff(lum, axis=1))[:-1, :], np.abs(np.diff(lum, axis=0))[:, :-1]
        return gx, gy, hair[:-1, :-1], cloth[:-1, :-1]

    gx, gy, h, c = gradients(0.015, [0.01, 0.015, 0])   # 0.06 mm per pixel
    assert h.sum() > 1000 and c.sum() > 1000
    assert (gx + gy)[h].mean() > 5 * (gx + gy)[c].mean() and (gx + gy)[h].mean() > 0.005
    assert gy[h].mean() > 2 * gx[h].mean()             # strands lie along x
    # a head photographed from ~40 cm (0.8 mm per pixel): single hairs are filtered out,
    # but clumps and locks of hair keep the mass textured (smooth hair taught a model to
    # call real hair skin)
    w = 0.8e-3 * renderer.width / (2 * np.tan(np.radians(15)))
    gx, gy, h, c = gradients(w, [0.6 * w, w, 0])
    grad = gx + gy
    assert h.sum() > 500 and c.sum() > 500
    assert grad[h].mean() > 3 * grad[c].mean() and grad[h].mean() > 0.004, (grad[h].mean(), grad[c].mean())
    for w in (3.0, 8.0):
        cam = _look_down(renderer, w, x=rng.uniform(-0.3, 0.3))
        lights = [PointLight(np.asarray(cam.eye) + [0.3 * w, 0.2 * w, 0], ambient=0.3, diffuse=0.8)]
        imgs = []
        for cover in (scalp, None):
            mesh = _skin_plane(rng, half=10.0, weight=no_weight, tex_size=size, scalp=cover)
            imgs.append(renderer.render(mesh, cam, passes=("rgb",), lights=lights,
                                        material=Material(model="skin"))["rgb"] * 255)
        assert np.isfinite(imgs[0]).all()
        assert _lap_energy(imgs[0]) < _lap_energy(imgs[1]) + 1.0, (w, _lap_energy(imgs[0]))


def test_scalp_strands_keep_their_width_where_t_narrows(renderer, rng):
    """Towards the crown a unit of the hair-flow t covers ever less scalp (meridians
    converge). Strands keep their physical width there: with t scaled by a random
    factor from 1/6 to 6 the close-up's hair looks as it does at 1, about as much
    gradient across the strands and still running along them (faded out, as they
    were at t scaled by 4.5, the gradient fell to 0.44)."""
    size = 1024
    scalp = np.full((size, size), 255, np.uint8)
    no_weight = np.zeros((size, size), np.uint8)
    cam = _look_down(renderer, 0.015)                  # 0.06 mm per pixel
    lights = [PointLight(np.asarray(cam.eye) + [0.01, 0.015, 0], ambient=0.25, diffuse=0.9)]

    def gradients(t_scale):
        mesh = _skin_plane(rng, weight=no_weight, tex_size=size, scalp=scalp)
        hc = np.asarray(mesh.skin.hair_coords).copy()
        hc[..., 1] *= t_scale
        mesh.skin = dataclasses.replace(mesh.skin, hair_coords=hc)
        lum = renderer.render(mesh, cam, passes=("rgb",), lights=lights,
                              material=Material(model="skin"))["rgb"].mean(-1)
        return np.abs(np.diff(lum, axis=1)).mean(), np.abs(np.diff(lum, axis=0)).mean()

    gx1, gy1 = gradients(1.0)
    for t_scale in (np.exp(rng.uniform(np.log(2.5), np.log(6))), np.exp(-rng.uniform(np.log(2.5), np.log(6)))):
        gx, gy = gradients(t_scale)
        assert 0.6 < gy / gy1 < 1.6, (t_scale, gy / gy1)
        assert gy > 2 * gx, t_scale


def test_a_flash_at_the_lens_gives_no_nan(renderer, rng):
    """The light exactly at the eye makes v.h round above 1 (Fresnel's base below 0)."""
    mesh = _skin_plane(rng)
    for w in (0.03, 0.3):
        cam = _look_down(renderer, w, x=rng.uniform(-0.2, 0.2))
        for det in (False, True):
            out = renderer.render(mesh, cam, passes=("rgb",), lights=[PointLight(cam.eye, ambient=0.0)],
                                  material=Material(model="skin", oil=1.0, roughness=0.2, detail=det))
            assert np.isfinite(out["rgb"]).all()
            centre = out["rgb"][renderer.height // 2 - 5:renderer.height // 2 + 5,
                                renderer.width // 2 - 5:renderer.width // 2 + 5]
            assert centre.min() > 0.05          # lit, not black speckles


def test_tiles_wrap_seamlessly():
    t = detail.detail_tiles()
    for tile in (t.relief, t.hair, t.crease, t.meso, t.flakes):
        x = tile.astype(np.float32)
        inner = np.abs(np.diff(x, axis=1)).mean()
        across = np.abs(x[:, 0] - x[:, -1]).mean()       # the step from the last column to the first
        assert across < 2 * inner + 1.0
        inner = np.abs(np.diff(x, axis=0)).mean()
        across = np.abs(x[0] - x[-1]).mean()
        assert across < 2 * inner + 1.0
    for tile in (t.relief, t.crease, t.meso):
        r = tile.astype(np.float64)
        assert np.abs(r[..., :2].mean((0, 1))).max() < 1e-3   # no tilt on average
        assert abs(r[..., 2].mean()) < 1e-3                    # albedo change averages to 0
    blood = t.meso[..., 3].astype(np.float64)
    assert abs(blood.mean()) < 1e-3                            # and so does the blood mottle,
    # which only adds redness: the half of the noise below its mean is cut to one floor,
    # and the spots above it reach twice the noise's scaled spread (0.02)
    assert np.mean(blood == blood.min()) > 0.4 and np.ptp(blood) > 0.04


def _furrow_run(relief, direction, lag_px):
    """How far furrows of lines along ``direction`` (two integers) run on: the
    correlation, ``lag_px`` texels along that direction, of where the relief slopes
    across it (its magnitude, blurred over ~50 um)."""
    dx, dy = direction
    t = relief.astype(np.float32)
    across = np.abs(t[..., 0] * -dy + t[..., 1] * dx) / np.hypot(dx, dy)
    e = detail._wrap_blur(across, 6.0)
    e -= e.mean()
    j = int(round(lag_px / np.hypot(dx, dy)))
    return float((e * np.roll(e, (j * dy, j * dx), (0, 1))).mean() / (e * e).mean())


def test_skin_lines_cross_and_run_on(rng):
    """The relief's primary furrows are lines that cross and run on (the rhombic net
    of skin lines), not walls of cells meeting at Y junctions (cracked mud up close):
    0.6 mm along either primary family a furrow is still there (correlation 0.27-0.42
    over twelve seeds of a 512-texel tile; the Voronoi net it replaced, 0.01-0.11)."""
    tile, _ = detail._relief_tile(int(rng.integers(1_000_000)), size=512)
    lag = 600 / (detail.RELIEF_PERIOD * 1e6 / 512)
    runs = [_furrow_run(tile, d, lag) for d in ((2, 1), (2, -1))]
    assert np.mean(runs) > 0.18, runs


def test_line_families_tile_exactly(rng):
    """A line family tiles (the step from the last column or row to the first is no
    larger than steps inside: one of them, so at most a little over their largest; a
    family that did not tile would jump by up to half its spacing there), and a normal
    that would not tile is refused."""
    size = 256
    normal = tuple(int(x) for x in rng.integers(-3, 4, 2))
    normal = normal if normal != (0, 0) else (1, 2)
    dist, strength = detail._line_family(rng, size, rng.uniform(8, 40), normal, 0.3, 0.4)
    for d in (dist, strength):
        inner = max(np.abs(np.diff(d, axis=1)).max(), np.abs(np.diff(d, axis=0)).max())
        assert np.abs(d[:, 0] - d[:, -1]).max() <= 1.5 * inner
        assert np.abs(d[0] - d[-1]).max() <= 1.5 * inner
    with pytest.raises(ValueError, match="two integers"):
        detail._line_family(rng, size, 20.0, (0.55, 1), 0.3, 0.4)


def _surface_per_hair_coordinate(v, f, hc):
    """Per face, dp/d(s, t): the 3D edges times the inverse of the coordinate edges
    (3 x 2, columns along s and t)."""
    e = np.stack([v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]], -1)
    h = np.asarray(hc, np.float64)
    return e @ np.linalg.inv(np.stack([h[:, 1] - h[:, 0], h[:, 2] - h[:, 0]], -1))


def test_terminal_hair_tile_is_as_dense_and_crossed_as_a_hairy_forearm():
    """Each terminal group of the hair tile: ~14 hairs / cm2, 6-22 mm long (log-uniform,
    mean 12 mm: a shin's and a forearm's), ~70 um thick and thinner to the tip, so 8-14%
    of the tile is covered (the 4-14 mm hairs before 2026-12-06 covered 4-9%, sparse
    beside a real hairy shin); the strands leave the flow by ~30 degrees and bend along
    their length, so their directions spread 25-45 degrees round it (a tile of short
    hairs combed parallel covered 3% and spread 19). Vellus groups are finer and
    sparser in cover."""
    import cv2
    tile = detail._hair_tile(seed=0).astype(np.float32) / 255
    for g in range(4):
        c = tile[..., g]
        gx, gy = cv2.Sobel(c, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(c, cv2.CV_32F, 0, 1, ksize=3)
        m = np.hypot(gx, gy)
        resultant = abs((m * np.exp(2j * np.arctan2(gy, gx))).sum() / m.sum())   # doubled angles
        spread = np.degrees(np.sqrt(-2 * np.log(resultant)) / 2)
        cover = (c > 0.3).mean()
        if g < 2:
            assert 0.08 < cover < 0.14 and 25 < spread < 45, (g, cover, spread)
        else:
            assert 0.005 < cover < 0.03, (g, cover)


def test_hair_coordinates_follow_a_limb_isometrically():
    cyl = trimesh.creation.cylinder(radius=0.04, height=0.3, sections=48)
    v = np.asarray(cyl.vertices) @ np.array([[1, 0, 0], [0, 0, 1], [0, 1, 0]], float)  # axis along y
    v = v + np.array([0.4, 1.0, 0.0])                     # off to the side of the trunk
    labels = np.full(len(v), 13)
    f = np.asarray(cyl.faces)
    hc = hair_coordinates(v, f, labels)
    side = np.abs(cyl.face_normals[:, 2]) < 0.5          # the round side, not the caps
    h1, h2 = hc[:, 1] - hc[:, 0], hc[:, 2] - hc[:, 0]
    ok = side & (np.abs(h1[:, 0] * h2[:, 1] - h1[:, 1] * h2[:, 0]) > 1e-12)
    # dp/d(s, t) per face: unit columns, orthogonal on a cylinder
    J = _surface_per_hair_coordinate(v, f[ok], hc[ok])
    assert np.allclose(np.linalg.norm(J[..., 0], axis=-1), 1, atol=0.03)
    assert np.allclose(np.linalg.norm(J[..., 1], axis=-1), 1, atol=0.05)
    assert np.abs(np.einsum("nk,nk->n", J[..., 0], J[..., 1])).max() < 0.05
    # +s runs along the limb, away from the trunk side's... axis (here +-y): pure y
    assert np.allclose(np.abs(J[..., 0][:, 1]), 1, atol=0.03)


def test_scalp_hair_falls_from_the_crown_at_its_own_size(rng):
    """A head (a sphere with a neck below it) gets capsule coordinates: over the skull
    +s runs away from the crown along the surface at the tile's size (a vertical
    cylinder stretched it by 1 / cos of the latitude), t keeps its size at the skull's
    widest and narrows towards the crown as meridians do, and s runs on down the neck
    without a jump."""
    r = rng.uniform(0.075, 0.1)
    centre = np.array([rng.uniform(-0.05, 0.05), rng.uniform(1.5, 1.7), rng.uniform(-0.05, 0.05)])
    skull = trimesh.creation.icosphere(subdivisions=4, radius=r)
    neck = trimesh.creation.cylinder(radius=0.5 * r, height=1.2 * r, sections=32)
    neck.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    neck.apply_translation([0.0, -1.2 * r, 0.0])
    head = trimesh.util.concatenate([skull, neck])
    v, f = np.asarray(head.vertices) + centre, np.asarray(head.faces)
    hc = hair_coordinates(v, f, np.full(len(v), 1))
    c = v[f].mean(1) - centre
    polar = np.degrees(np.arctan2(np.linalg.norm(c[:, [0, 2]], axis=1), c[:, 1]))
    on_skull = np.arange(len(f)) < len(skull.faces)
    h1, h2 = hc[:, 1] - hc[:, 0], hc[:, 2] - hc[:, 0]
    ok = np.abs(h1[:, 0] * h2[:, 1] - h1[:, 1] * h2[:, 0]) > 1e-12
    cap = on_skull & ok & (polar > 15) & (polar < 85)
    J = _surface_per_hair_coordinate(v, f[cap], hc[cap])
    ls, lt = np.linalg.norm(J[..., 0], axis=-1), np.linalg.norm(J[..., 1], axis=-1)
    assert np.abs(ls - 1).max() < 0.05, np.abs(ls - 1).max()
    # t: a unit covers sin(polar) of it (narrowing towards the crown, full at the widest)
    assert np.abs(lt - np.sin(np.radians(polar[cap]))).max() < 0.05
    away = c[cap] / np.linalg.norm(c[cap], axis=1, keepdims=True)
    down_surface = np.array([0.0, -1.0, 0.0]) + away * away[:, 1:2]      # along the meridian
    down_surface /= np.linalg.norm(down_surface, axis=1, keepdims=True)
    assert np.einsum("nk,nk->n", J[..., 0] / ls[:, None], down_surface).min() > 0.97
    # the same scale of t at the corners, the mean of the faces round each vertex: one
    # value per vertex, whichever face it is read from (it must not jump at edges)
    corner = t_scale_at_corners(v, f, hc)
    per_vertex = np.full(len(v), np.nan)
    per_vertex[f.ravel()] = corner.ravel()
    assert np.allclose(per_vertex[f], corner)
    pv = v[f[cap]] - centre
    corner_polar = np.arctan2(np.linalg.norm(pv[..., [0, 2]], axis=-1), pv[..., 1])
    assert np.abs(corner[cap] - np.sin(corner_polar)).max() < 0.05
    # no seam between the skull and the neck: the skull's rim and the neck's top edge
    # (where they meet at the same radius below the equator) carry close s
    s_skull = hc[on_skull].reshape(-1, 2)[:, 0]
    assert abs(s_skull.min()) < 0.05 * r            # the crown is where s starts
    neck_s = hc[~on_skull].reshape(-1, 2)[:, 0]
    neck_y = v[f[~on_skull]].reshape(-1, 3)[:, 1] - centre[1]
    top = neck_y > neck_y.max() - 1e-9
    assert np.allclose(neck_s[top], r * np.pi / 2 - neck_y[top], atol=1e-6 * r)


def test_hair_fades_where_the_tile_would_stretch(rng):
    # a limb with hemispherical ends (height: between the spheres' centres): the cylinder
    # keeps the tile's size along its side, the ends turn across the axis (a coordinate
    # unit there covers ever more skin: 1 / sin of the angle from the pole)
    r, h = rng.uniform(0.03, 0.06), rng.uniform(0.2, 0.4)
    cap = trimesh.creation.capsule(height=h, radius=r, count=[48, 48])
    v = np.asarray(cap.vertices)[:, [0, 2, 1]] + np.array([0.4, 1.0, 0.0])   # axis along y
    f = np.asarray(cap.faces)
    q = hair_flow_quality(v, f, hair_coordinates(v, f, np.full(len(v), 13)))
    along = np.abs(v[:, 1] - 1.0)
    assert q.dtype == np.float32 and np.isfinite(q).all() and q.min() >= 0 and q.max() <= 1
    assert q[along <= h / 2 + 0.5 * r].min() > 0.99         # the side and the caps' rims
    assert q[along > h / 2 + 0.95 * r].max() < 0.01         # near the poles: no hair


def test_trunk_hair_runs_down_a_part_wider_than_tall(rng):
    # a lower torso wider than tall: its longest extent runs from side to side, but its
    # hair must still run down the body, around a vertical axis
    ell = trimesh.creation.icosphere(subdivisions=4)
    a = np.array([rng.uniform(0.15, 0.2), rng.uniform(0.08, 0.11), rng.uniform(0.1, 0.13)])
    v = np.asarray(ell.vertices) * a + np.array([0.0, 1.0, 0.0])
    f = np.asarray(ell.faces)
    hc = hair_coordinates(v, f, np.full(len(v), 3))
    c = v[f].mean(1)
    front = (np.abs(c[:, 1] - 1.0) < 0.3 * a[1]) & (c[:, 2] > 0.8 * a[2])   # chest-high front
    J = _surface_per_hair_coordinate(v, f[front], hc[front])
    ds = J[..., 0] / np.linalg.norm(J[..., 0], axis=-1, keepdims=True)
    # +s points down the surface: near "down" projected into each face's plane (the
    # front of an ellipsoid slopes, so +s is not straight down in 3D)
    n = np.cross(v[f[front, 1]] - v[f[front, 0]], v[f[front, 2]] - v[f[front, 0]])
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    down = np.array([0.0, -1.0, 0.0]) + n[:, 1:2] * n       # minus its normal component
    down /= np.linalg.norm(down, axis=-1, keepdims=True)
    assert np.einsum("nk,nk->n", ds, down).min() > 0.95     # 0.972 worst over 300 seeds
    assert np.abs(np.linalg.norm(J[..., 0], axis=-1) - 1).max() < 0.15   # at the tile's size


def test_wrinkles_run_across_the_hair_flow(renderer, rng):
    """Where the relief level is high (aged skin, knuckles) the crease tile's grooves lie
    along t, across the hair flow (around a limb): turning the hair-flow coordinates by
    90 degrees turns the image's dominant gradient with them; at ordinary skin's level
    (0.5) there are none, and the image does not depend on the coordinates' direction
    beyond the hair itself (no hair here)."""
    def render(params, along_y):
        mesh = _skin_plane(rng, params=params)
        if along_y:   # s = y, t = -x
            hc = np.asarray(mesh.skin.hair_coords)
            mesh.skin = dataclasses.replace(mesh.skin, hair_coords=np.stack([hc[..., 1], -hc[..., 0]], -1))
        cam = _look_down(renderer, 0.04, x=0.0)
        lights = [PointLight(np.asarray(cam.eye) + [0.02, 0.02, 0.01], ambient=0.2, diffuse=0.9)]
        lum = renderer.render(mesh, cam, passes=("rgb",), lights=lights,
                              material=Material(model="skin", oil=0.0))["rgb"].mean(-1)
        return lum, np.abs(np.diff(lum, axis=1)).mean() / np.abs(np.diff(lum, axis=0)).mean()

    old = (255, 0, 0, 0)
    _, along_x = render(old, False)
    _, along_y = render(old, True)
    assert along_x > 1.15 and along_y < 1 / 1.15, (along_x, along_y)
    ordinary = (128, 0, 0, 0)
    a, _ = render(ordinary, False)
    b, _ = render(ordinary, True)
    assert np.abs(a - b).max() < 1e-6
