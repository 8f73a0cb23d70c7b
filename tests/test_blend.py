"""Paste round trip and blending on a simple textured surface with a synthetic lesion."""
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
import torch

import glsynth as gs
from glsynth.pipeline.blend import BlendError, BlendSettings, DeepBlender, blend_loss, gram
from glsynth.pipeline.poisson import poisson_blend
from glsynth.pipeline.bodies import TexelGeometry
from glsynth.pipeline.features import VGG16Features, make_extractor
from glsynth.pipeline.paste import PasteSettings, compose_lesion, paste_lesions, warp_lesion
from glsynth.pipeline.seeding import rng_for
from shapes import skin_sheet

VIEW = 256


def _skin_body(rng, tex=1024):
    return skin_sheet(rng, n=40, tex=tex, blur=6, amplitude=60)


def _lesion(rng, h=90, w=110):
    yy, xx = np.mgrid[:h, :w]
    r = np.hypot((yy - h / 2) / 30, (xx - w / 2) / 38)
    mask = r < 1 + 0.1 * np.sin(np.arctan2(yy - h / 2, xx - w / 2) * 5)
    img = np.empty((h, w, 3), np.float32)
    img[:] = (165, 118, 100)  # the photo's skin: darker and redder than the body's
    tex = cv2.GaussianBlur(rng.normal(size=(h, w)).astype(np.float32), (0, 0), 2)
    img[mask] = np.array([110, 62, 48]) + 40 * tex[mask][:, None]
    return SimpleNamespace(image=np.clip(img, 0, 255).astype(np.uint8), mask=mask, id="synthetic",
                           meta={})


@pytest.fixture(scope="module")
def scene(module_rng):
    rng = module_rng
    body = _skin_body(rng)
    r = gs.Renderer(VIEW, VIEW)
    tx = TexelGeometry.of(r, body.mesh)
    lesion = _lesion(rng)
    settings = PasteSettings(view_size=VIEW, w=(0.35, 0.45), size=(0.3, 0.4), max_depth_change=0.05)
    pasted = paste_lesions(r, body, tx, [lesion], settings, ("t",), int(rng.integers(1000)))
    assert len(pasted.placements) == 1
    return SimpleNamespace(body=body, r=r, tx=tx, lesion=lesion, pasted=pasted,
                           placement=pasted.placements[0], settings=settings)


UNLIT = [gs.PointLight((0, 0, 0), ambient=1.0, diffuse=0.0, specular=0.0)]


def _view(scene, texture, lights=UNLIT):
    p = scene.placement
    cam = gs.Camera.from_dict(p.camera)
    out = scene.r.render(scene.body.mesh.copy_with(texture=texture), cam, passes=("rgb", "gbuffer"),
                         lights=lights, material=gs.Material(0.0, 1.0))
    return out


def _placed_lesion(scene):
    """The lesion as composed in the placement view (a_x, a_s of the paper)."""
    p = scene.placement
    ys, xs = np.nonzero(scene.lesion.mask)
    extent = max(ys.max() - ys.min() + 1, xs.max() - xs.min() + 1)
    affine, _ = compose_lesion(scene.lesion, VIEW, p.scale * extent, p.flip_h, p.flip_v, p.angle_deg)
    return warp_lesion(scene.lesion, affine, VIEW)


def test_paste_round_trip_psnr(scene):
    p = scene.placement
    a_x, a_s = _placed_lesion(scene)
    inner = cv2.erode((a_s > 0.5).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    out = _view(scene, scene.pasted.pasted)
    err = out["rgb"][inner] - a_x[inner]
    psnr = 10 * np.log10(1.0 / np.mean(err ** 2))
    assert psnr >= 30, f"paste round trip PSNR {psnr:.1f} dB"
    # instance ids land where the lesion is
    lab = scene.r.render(scene.body.mesh, gs.Camera.from_dict(p.camera), passes=("labels",),
                         label_texture=scene.pasted.instances)["labels"]
    assert (lab[inner] == 1).mean() > 0.99


def test_only_lesion_texels_change(scene):
    outside = scene.pasted.instances == 0
    assert (scene.pasted.pasted[outside] == scene.pasted.original[outside]).all()
    blended = poisson_blend(scene.r, scene.body.mesh, scene.pasted, scene.tx)
    assert (blended[outside] == scene.pasted.pasted[outside]).all()


def _rings(scene):
    lab = scene.r.render(scene.body.mesh, gs.Camera.from_dict(scene.placement.camera),
                         passes=("labels",), label_texture=scene.pasted.instances)["labels"] > 0
    k = np.ones((5, 5), np.uint8)
    inner = lab & ~(cv2.erode(lab.astype(np.uint8), k) > 0)
    outer = (cv2.dilate(lab.astype(np.uint8), k) > 0) & ~lab
    return lab, inner, outer


def _seam_error(scene, texture):
    """How far the colour step across the lesion boundary (inner ring minus outer ring,
    unlit view) is from the photo's own step: a seamless blend keeps the photo's step
    and drops the offset between the photo's skin and the body's."""
    lab, inner, outer = _rings(scene)
    a_x, _ = _placed_lesion(scene)
    img = _view(scene, texture)["rgb"]
    step = lambda im: im[inner].mean(0) - im[outer].mean(0)  # noqa: E731
    return float(np.abs(step(img) - step(a_x)).mean()), img, lab


def test_poisson_blend_removes_the_seam(scene):
    err_paste, img_p, lab = _seam_error(scene, scene.pasted.pasted)
    blended = poisson_blend(scene.r, scene.body.mesh, scene.pasted, scene.tx)
    err_blend, img_b, _ = _seam_error(scene, blended)
    assert err_paste > 0.05  # the photo's skin differs from the body's
    assert err_blend < 0.5 * err_paste
    # the lesion's inner structure (its Laplacian) survives
    core = cv2.erode(lab.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
    lap = lambda im: cv2.Laplacian(im.mean(-1), cv2.CV_32F)  # noqa: E731
    corr = np.corrcoef(lap(img_b)[core], lap(img_p)[core])[0, 1]
    assert corr > 0.6, f"lesion detail lost (Laplacian correlation {corr:.2f})"


def test_deep_blend_at_paper_weights_is_finite_and_reduces_the_seam(scene):
    ext, desc = make_extractor("filters")
    s = BlendSettings(steps=80, perturb_deg=2.0)
    blender = DeepBlender(scene.r, scene.body.mesh, scene.pasted, s, ext)
    losses = blender.blend(scene.placement, rng_for(0, "t"))
    assert all(np.isfinite(l["total"]) for l in losses)
    assert losses[-1]["gradient"] < losses[0]["gradient"]
    blended = blender.result()
    err_paste, img_p, lab = _seam_error(scene, scene.pasted.pasted)
    err_blend, img_b, _ = _seam_error(scene, blended)
    assert err_blend < err_paste
    core = cv2.erode(lab.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
    assert np.abs(img_b[core] - img_p[core]).mean() < 0.15  # the interior stays the lesion
    outside = scene.pasted.instances == 0
    assert (blended[outside] == scene.pasted.pasted[outside]).all()


def test_deep_blend_does_not_depend_on_the_process_thread_count(scene):
    """Workers get a share of the cores; torch's convolutions and sums round differently
    on different thread counts, so the blend runs on its own fixed count (blend.threads)."""
    ext, _ = make_extractor("filters")
    results = []
    previous = torch.get_num_threads()
    try:
        for n in (1, 2, 3):
            torch.set_num_threads(n)
            blender = DeepBlender(scene.r, scene.body.mesh, scene.pasted, BlendSettings(steps=3), ext)
            losses = blender.blend(scene.placement, rng_for(5, "t"))
            results.append((blender.Tb.numpy().tobytes(), losses))
            assert torch.get_num_threads() == n  # restored
    finally:
        torch.set_num_threads(previous)
    assert all(r == results[0] for r in results[1:])


@pytest.mark.parametrize("scale", [1e-3, 1e3])
@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_deep_blend_stays_finite_for_scaled_weights(scene, scale, dtype):
    ext, _ = make_extractor("filters")
    s = BlendSettings(steps=3, content=2 * scale, style=1e6 * scale, gradient=1e5 * scale,
                      tv=1e-4 * scale, dtype=dtype)
    blender = DeepBlender(scene.r, scene.body.mesh, scene.pasted, s, ext)
    losses = blender.blend(scene.placement, rng_for(1, "t"))
    assert losses and all(np.isfinite(v) for l in losses for v in l.values())
    assert np.isfinite(blender.Tb.numpy()).all()


def test_no_feature_network_without_content_or_style(scene, monkeypatch):
    import glsynth.pipeline.features as features
    monkeypatch.setattr(features, "make_extractor", lambda *a, **k: pytest.fail("built a network"))
    s = BlendSettings(steps=2, content=0.0, style=0.0)
    assert not s.needs_features
    blender = DeepBlender(scene.r, scene.body.mesh, scene.pasted, s, None)
    losses = blender.blend(scene.placement, rng_for(2, "t"))
    assert "content" not in losses[0] and "style" not in losses[0]


def test_vgg16_loads_torchvision_state_dict(tmp_path, scene):
    net = VGG16Features()
    state = {k: torch.randn_like(v) * 0.05 for k, v in net.state_dict().items() if k.startswith("features")}
    state["classifier.0.weight"] = torch.zeros(4, 4)  # torchvision files carry the classifier too
    path = tmp_path / "vgg16-397923af.pth"
    torch.save(state, path)
    ext, desc = make_extractor("vgg16", str(path))
    assert desc.startswith("vgg16")
    torch.testing.assert_close(ext.features[0].weight, state["features.0.weight"])
    blender = DeepBlender(scene.r, scene.body.mesh, scene.pasted, BlendSettings(steps=2), ext)
    assert all(np.isfinite(l["total"]) for l in blender.blend(scene.placement, rng_for(3, "t")))
    bad = tmp_path / "bad.pth"
    torch.save({"features.0.weight": torch.zeros(1)}, bad)
    with pytest.raises(ValueError, match="not a VGG16 state dict"):
        make_extractor("vgg16", str(bad))
    with pytest.raises(FileNotFoundError, match="vgg_weights"):
        make_extractor("vgg16", str(tmp_path / "missing.pth"))


def test_total_variation_term_is_summed_over_the_crop():
    """The paper's lambda_TV = 1e-4 weighs a TV *summed* over the crop (DermSynth3D's
    code). Hand-computed: one lit pixel of 0.5 in the red channel of a 6 x 7 crop, its
    four neighbours 0 (4 x 0.5), plus a blue column step of 0.25 across 6 rows."""
    b = torch.zeros(1, 3, 6, 7)
    b[0, 0, 2, 3] = 0.5
    b[0, 2, :, 4:] = 0.25
    m = torch.zeros(1, 1, 6, 7)
    m[..., 1:5, 1:6] = 1
    s = BlendSettings(content=0.0, style=0.0, gradient=0.0, tv=1e-4)
    total, terms = blend_loss(b, b, b, b, m, s, None)
    assert float(terms["tv"]) == pytest.approx(4 * 0.5 + 6 * 0.25)
    assert float(total) == pytest.approx(1e-4 * 3.5)


def test_gram_does_not_overflow_for_large_features():
    f = torch.full((1, 64, 256, 256), 1e3)
    g = gram(f)
    assert torch.isfinite(g).all() and float(g.max()) == pytest.approx(1e6 / 64, rel=1e-4)


def test_blend_error_on_non_finite(scene, monkeypatch):
    s = BlendSettings(steps=1, content=0.0, style=0.0, gradient=float("inf"))
    blender = DeepBlender(scene.r, scene.body.mesh, scene.pasted, s, None)
    with pytest.raises(BlendError, match="non-finite"):
        blender.blend(scene.placement, rng_for(4, "t"))


def test_body_texels_are_kept_for_the_same_body_only(scene, rng):
    """``of_body`` gives what ``of`` gives, keeps it while the body's geometry is the
    same (a fresh load of the body included), and works it out anew for another body."""
    TexelGeometry.forget()
    a = TexelGeometry.of_body(scene.r, scene.body.mesh)
    again = scene.body.mesh.copy_with(texture=scene.body.mesh.texture.copy())
    assert TexelGeometry.of_body(scene.r, again) is a
    assert np.array_equal(a.points, scene.tx.points) and np.array_equal(a.rows, scene.tx.rows)
    moved = scene.body.mesh.copy_with(vertices=scene.body.mesh.vertices + rng.normal(0, 1e-3, 3))
    b = TexelGeometry.of_body(scene.r, moved)
    assert b is not a and np.allclose(b.points, a.points + (moved.vertices - scene.body.mesh.vertices)[0])
    TexelGeometry.forget()


def test_site_shares_name_presets_and_regions_and_sum_to_one():
    from glsynth.assets.morphology import PRESETS, SITES
    from glsynth.dataformat import GROUP_NAMES
    for preset, shares in SITES.items():
        assert preset in PRESETS
        assert set(shares) <= set(GROUP_NAMES.values()) - {"background"}
        assert sum(shares.values()) == pytest.approx(1.0)


def _labelled_sheet(n=30):
    """A wavy sheet whose vertex rows fall in three regions: head, upper torso, lower leg."""
    from glsynth.mesh import grid_faces
    u, v = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    verts = np.stack([u * 0.6, v * 0.6, 0.05 * np.sin(3 * u + 2 * v ** 2)], -1).reshape(-1, 3)
    rows = np.repeat(np.arange(n), n)
    labels = np.where(rows < n // 3, 1, np.where(rows < 2 * n // 3, 2, 7))
    texture = np.full((256, 256, 3), 180, np.uint8)
    mesh = gs.Mesh(verts, grid_faces(n), uvs=np.stack([u, v], -1).reshape(-1, 2), texture=texture,
                   vertex_labels=labels, name="labelled sheet")
    return SimpleNamespace(mesh=mesh, nonskin=np.zeros((256, 256), np.uint8), meta={})


def test_conditions_are_placed_in_their_usual_regions_by_share_then_area():
    from glsynth.assets.morphology import SITES
    from glsynth.dataformat import group_labels
    from glsynth.pipeline.paste import Paster
    body = _labelled_sheet()
    mesh = body.mesh
    group = group_labels(mesh.vertex_labels[mesh.faces[:, 0]])
    paster = Paster(None, body, None, PasteSettings(view_size=VIEW))
    area_p = mesh.face_areas / mesh.face_areas.sum()
    for preset in ("bcc", "ulcer", "pityriasis_rosea", "psoriasis"):
        p = paster.site_p(preset)
        shares = {g: SITES[preset].get(name, 0.0) for g, name in ((1, "head"), (2, "torso"), (4, "legs"))}
        total = sum(shares.values())
        for g, share in shares.items():
            sel = group == g
            assert p[sel].sum() == pytest.approx(share / total, abs=1e-9)
            if share:   # by area within the region
                assert np.allclose(p[sel] / p[sel].sum(), area_p[sel] / area_p[sel].sum())
    # no sites (a real lesion image, a preset placed anywhere) or body_sites off: by area
    assert paster.site_p(None) is paster.face_p
    assert paster.site_p("inflammatory_patch") is paster.face_p
    off = Paster(None, body, None, PasteSettings(view_size=VIEW, body_sites=False))
    assert off.site_p("bcc") is off.face_p
    assert np.allclose(off.face_p, area_p)


def test_an_eruption_spreads_further_draws_of_its_preset_round_its_first_lesion(rng):
    """lesions.eruption: the further lesions of an eruption are new draws of the first's
    preset (rebuilt from what their placements record), placed within the radius of the
    first on free skin, and all of them record the first's instance as their eruption."""
    from glsynth.assets.lesions import ProceduralLesions, lesion_from_meta
    body = _skin_body(rng, tex=512)
    body.meta = {"fitzpatrick": int(rng.integers(1, 7))}
    r = gs.Renderer(VIEW, VIEW)
    tx = TexelGeometry.of(r, body.mesh)
    seed = int(rng.integers(1 << 30))
    bank = ProceduralLesions(2, seed=seed, size=96, kinds=["pityriasis_rosea", "urticaria"])
    first = bank[int(rng.integers(2))]
    further = [bank.spread(first, j) for j in range(1, 4)]
    radius = float(rng.uniform(0.15, 0.25))
    settings = PasteSettings(view_size=VIEW, max_depth_change=0.05)
    res = paste_lesions(r, body, tx, [first], settings, ("t",), seed,
                        eruption=(lambda lesion: further if lesion is first else [], radius))
    p0, rest = res.placements[0], res.placements[1:]
    assert p0.lesion_id == first.id and len(rest) >= 1
    ids = [i for p in res.placements for i in p.ids]
    assert len(ids) == len(set(ids))                              # each lesion its own ids
    centres = body.mesh.vertices[body.mesh.faces].mean(1)
    slack = np.max(np.linalg.norm(centres[:, None] - body.mesh.vertices[body.mesh.faces], axis=-1))
    for p in res.placements:
        assert p.lesion_meta["eruption"] == p0.instance
    for p in rest:
        assert p.lesion_meta["preset"] == first.meta["preset"] and p.lesion_meta["copy"] >= 1
        gap = np.linalg.norm(np.subtract(p.camera["target"], p0.camera["target"]))
        assert gap < radius + slack
        again = lesion_from_meta(p.lesion_meta)
        drawn = further[p.lesion_meta["copy"] - 1]
        assert again.id == drawn.id == p.lesion_id
        assert np.array_equal(again.fields.mask, drawn.fields.mask)
        assert not np.array_equal(drawn.fields.mask, first.fields.mask)   # its own draw
    r.close()
