"""Lesion sources (Fitzpatrick17k folders, ISIC / PH2 / images+masks pairs, procedural)
and the colour helpers they use."""
import logging
import math

import cv2
import numpy as np
import pytest
from scipy import ndimage

from glsynth.assets.colour import (fitzpatrick_from_ita, ita_degrees, ita_range, lab_to_srgb,
                                   shades_of_gray, srgb_to_lab)
from glsynth.assets.lesions import (KINDS, EmptyMaskError, Lesion, LesionError, crop_box,
                                    load_lesion, load_lesions, procedural_lesions)

H, W = 60, 80


def _photo(seed=0, h=H, w=W):
    rng = np.random.default_rng(seed)
    img = np.empty((h, w, 3), np.uint8)
    img[:] = (200, 150, 120)
    return np.clip(img + rng.integers(-20, 20, (h, w, 3)), 0, 255).astype(np.uint8)


def _rect(y0, y1, x0, x1, h=H, w=W):
    m = np.zeros((h, w), bool)
    m[y0:y1, x0:x1] = True
    return m


def _write(path, img):
    path.parent.mkdir(parents=True, exist_ok=True)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR if img.shape[2] == 3 else cv2.COLOR_RGBA2BGRA)
    assert cv2.imwrite(str(path), img)
    return path


def _rgba_white(mask):
    """DermSynth3D-style RGBA mask: RGB 0/255, alpha opaque."""
    m = np.zeros(mask.shape + (4,), np.uint8)
    m[mask, :3] = 255
    m[..., 3] = 255
    return m


def _rgba_alpha(mask):
    """RGBA mask that carries the label in the alpha channel only."""
    m = np.zeros(mask.shape + (4,), np.uint8)
    m[..., 3] = mask * 255
    return m


@pytest.fixture
def fitz(tmp_path):
    root = tmp_path / "fitz"
    # a1: image.jpg, RGBA masks, selected lesion is one of two lesions.
    lesions = _rect(10, 20, 10, 30) | _rect(30, 50, 40, 60)
    _write(root / "a1" / "image.jpg", _photo(1))
    _write(root / "a1" / "lesions.png", _rgba_white(lesions))
    _write(root / "a1" / "selected_lesion.png", _rgba_white(_rect(30, 50, 40, 60)))
    _write(root / "a1" / "nonskin.png", _rgba_alpha(_rect(0, 5, 0, W)))
    # b2: <id>.png image, grey masks, empty selected lesion -> falls back to lesions.png.
    _write(root / "b2" / "b2.png", _photo(2))
    _write(root / "b2" / "lesions.png", (_rect(20, 40, 20, 40) * 255).astype(np.uint8))
    _write(root / "b2" / "selected_lesion.png", np.zeros((H, W), np.uint8))
    _write(root / "b2" / "nonskin.png", np.zeros((H, W), np.uint8))
    # c3: masks but no image -> skipped.
    _write(root / "c3" / "lesions.png", (_rect(20, 40, 20, 40) * 255).astype(np.uint8))
    (root / "meta.csv").write_text(
        "name,label,three_partition_label,nine_partition_label,fitzpatrick,url\n"
        "a1.jpg,psoriasis,non-neoplastic,inflammatory,3,http://x/a1\n"
        "b2,melanoma,malignant,malignant melanoma,-1,http://x/b2\n")
    return root


def test_fitz17k_layout(fitz, caplog):
    caplog.set_level(logging.WARNING)
    ls = load_lesions(fitz, layout="fitz17k")
    assert len(ls) == 2 and ls.ids == ["a1", "b2"]
    assert ls.skipped == {"folders without an image": 1}
    assert any("skipped 1 folders without an image" in r.getMessage() for r in caplog.records)

    a1, b2 = ls[0], ls[1]
    # selected_lesion.png wins over lesions.png; crop = bbox + 25% margin.
    assert a1.meta["mask_path"].endswith("selected_lesion.png")
    assert a1.meta["crop"] == (35, 25, 65, 55)
    assert a1.image.shape == (30, 30, 3) and a1.image.dtype == np.uint8
    assert a1.mask.sum() == 20 * 20 and a1.mask[5:25, 5:25].all()
    # empty selected lesion: fall back to lesions.png
    assert b2.meta["mask_path"].endswith("lesions.png") and b2.mask.sum() == 400
    # CSV rows matched with and without extension; Fitzpatrick -1 means unknown.
    assert a1.meta["label"] == "psoriasis" and a1.meta["fitzpatrick"] == 3
    assert b2.meta["label"] == "melanoma" and b2.meta["fitzpatrick"] is None
    # Full-image ground truth is available for evaluation.
    assert a1.lesions_mask.shape == (H, W) and a1.lesions_mask.sum() == 200 + 400
    np.testing.assert_array_equal(a1.nonskin_mask, _rect(0, 5, 0, W))
    assert a1.full_image().shape == (H, W, 3)
    # Lazy loading gives the same lesions.
    lazy = load_lesions(fitz, layout="fitz17k", lazy=True)
    assert len(lazy) == 2
    np.testing.assert_array_equal(lazy[1].image, b2.image)


def test_fitz17k_annotator_subfolders_and_image_dir(tmp_path):
    root, images = tmp_path / "ann", tmp_path / "images"
    _write(root / "annotator1" / "x9" / "lesions.png", (_rect(20, 30, 20, 30) * 255).astype(np.uint8))
    _write(images / "x9.jpg", _photo(3))
    ls = load_lesions(root, image_dir=images)
    assert ls.ids == ["x9"] and ls[0].mask.sum() == 100
    # The same image annotated by a second annotator gets a distinct id.
    _write(root / "annotator2" / "x9" / "lesions.png", (_rect(20, 40, 20, 30) * 255).astype(np.uint8))
    ls = load_lesions(root, image_dir=images)
    assert ls.ids == ["annotator1/x9", "annotator2/x9"] and ls[1].mask.sum() == 200


def test_fitz17k_image_of_any_name(tmp_path):
    _write(tmp_path / "z1" / "photo.jpeg", _photo(4))
    _write(tmp_path / "z1" / "lesions.png", (_rect(20, 30, 20, 30) * 255).astype(np.uint8))
    assert load_lesions(tmp_path)[0].meta["image_path"].endswith("photo.jpeg")


def test_colour_constancy_flag(fitz):
    plain = load_lesions(fitz)[0]
    cc = load_lesions(fitz, colour_constancy=True)[0]
    x0, y0, x1, y1 = cc.meta["crop"]
    np.testing.assert_array_equal(cc.image, shades_of_gray(plain.full_image())[y0:y1, x0:x1])
    assert not np.array_equal(cc.image, plain.image)


@pytest.fixture
def pairs(tmp_path):
    root = tmp_path / "pairs"
    m = (_rect(15, 45, 20, 60) * 255).astype(np.uint8)
    # ISIC 2018: images and ground truth in sibling folders; superpixels are ignored.
    _write(root / "isic" / "ISIC2018_Task1-2_Training_Input" / "ISIC_0000001.jpg", _photo(4))
    _write(root / "isic" / "ISIC2018_Task1-2_Training_Input" / "ISIC_0000001_superpixels.png", _photo(5))
    _write(root / "isic" / "ISIC2018_Task1_Training_GroundTruth" / "ISIC_0000001_segmentation.png", m)
    # PH2
    _write(root / "ph2" / "IMD002" / "IMD002_Dermoscopic_Image" / "IMD002.bmp", _photo(6))
    _write(root / "ph2" / "IMD002" / "IMD002_lesion" / "IMD002_lesion.bmp", m)
    _write(root / "ph2" / "IMD002" / "IMD002_roi" / "IMD002_R1_Label4.bmp", m)
    # images/ + masks/ with and without a suffix, one image without mask.
    _write(root / "gen" / "images" / "x01.png", _photo(7))
    _write(root / "gen" / "masks" / "x01_mask.png", m)
    _write(root / "gen" / "images" / "x02.jpg", _photo(8))
    _write(root / "gen" / "masks" / "x02.png", _rgba_alpha(m > 0))
    _write(root / "gen" / "images" / "x03.jpg", _photo(9))
    return root


def test_pairs_layouts(pairs):
    ls = load_lesions(pairs, layout="pairs")
    assert sorted(ls.ids) == ["IMD002", "ISIC_0000001", "x01", "x02"]
    assert ls.skipped == {"images without a mask": 1}
    for les in ls:
        assert les.mask.sum() == 30 * 40 and les.image.shape == (46, 60, 3)  # margins 8 and 10 px
    assert load_lesions(pairs / "isic", layout="pairs").ids == ["ISIC_0000001"]
    ph2 = load_lesions(pairs / "ph2", layout="pairs")[0]
    assert ph2.meta["mask_path"].endswith("IMD002_lesion.bmp")


def test_unreadable_image(fitz):
    (fitz / "a1" / "image.jpg").write_bytes(b"not a jpeg")
    with pytest.raises(LesionError, match=r"a1.image\.jpg.*not a readable image"):
        load_lesions(fitz)
    with pytest.raises(LesionError, match="image.jpg"):
        load_lesions(fitz, lazy=True)[0]


def test_mask_size_mismatch(tmp_path):
    img = _write(tmp_path / "i.png", _photo())
    mask = _write(tmp_path / "m.png", np.full((H, W + 1), 255, np.uint8))
    with pytest.raises(LesionError, match=r"m\.png: mask size 81x60 differs from image .*i\.png size 80x60"):
        load_lesion(img, mask)


def test_empty_masks(fitz):
    img = fitz / "a1" / "image.jpg"
    empty = _write(fitz / "empty.png", np.zeros((H, W), np.uint8))
    with pytest.raises(EmptyMaskError, match="empty.png: mask is empty"):
        load_lesion(img, empty)
    # b2 with both masks empty is skipped from the set; with all empty nothing is usable.
    _write(fitz / "b2" / "lesions.png", np.zeros((H, W), np.uint8))
    ls = load_lesions(fitz)
    assert ls.ids == ["a1"] and ls.skipped["with empty lesion masks"] == 1
    with pytest.raises(LesionError, match="empty"):
        load_lesions(fitz, lazy=True)[1]
    for name in ("lesions.png", "selected_lesion.png"):
        _write(fitz / "a1" / name, np.zeros((H, W), np.uint8))
    with pytest.raises(LesionError, match=r"no usable lesions .*2 with empty lesion masks"):
        load_lesions(fitz)


def test_zero_usable_lesions(tmp_path):
    for name in ("p", "q"):
        _write(tmp_path / "src" / name / "lesions.png", np.full((H, W), 255, np.uint8))
    with pytest.raises(LesionError, match=r"src: no usable lesions .*2 folders without an image"):
        load_lesions(tmp_path / "src")
    (tmp_path / "empty").mkdir()
    with pytest.raises(LesionError, match="empty: no usable lesions"):
        load_lesions(tmp_path / "empty", layout="pairs")
    with pytest.raises(LesionError, match="not found"):
        load_lesions(tmp_path / "missing")
    with pytest.raises(LesionError, match="unknown lesion layout"):
        load_lesions(tmp_path / "src", layout="isic")


def test_border_warning(tmp_path, caplog):
    img = _write(tmp_path / "i.png", _photo())
    mask = _write(tmp_path / "m.png", (_rect(0, 20, 10, 30) * 255).astype(np.uint8))
    with caplog.at_level(logging.WARNING):
        les = load_lesion(img, mask)
    assert any("touches the image border" in r.getMessage() for r in caplog.records)
    assert les.meta["crop"] == (5, 0, 35, 25)
    caplog.clear()
    load_lesion(img, _write(tmp_path / "m2.png", (_rect(5, 20, 10, 30) * 255).astype(np.uint8)))
    assert not caplog.records


def test_lesion_checks_dtype_and_shape():
    with pytest.raises(LesionError, match="uint8"):
        Lesion(np.zeros((4, 4, 3), np.float32), np.ones((4, 4), bool), "f")
    with pytest.raises(LesionError, match="mask must be bool"):
        Lesion(np.zeros((4, 4, 3), np.uint8), np.ones((4, 4), np.uint8), "m")
    with pytest.raises(LesionError, match="mask must be bool"):
        Lesion(np.zeros((4, 4, 3), np.uint8), np.ones((4, 5), bool), "s")


def test_crop_box_clamps():
    assert crop_box(_rect(0, 8, 76, 80)) == (74, 0, 80, 10)


# --- procedural -------------------------------------------------------------------------

def test_procedural_deterministic():
    a = procedural_lesions(3, seed=3, size=96)
    b = procedural_lesions(5, seed=3, size=96)[:3]  # lesion i depends only on (seed, i)
    c = procedural_lesions(3, seed=4, size=96)
    for x, y, z in zip(a, b, c):
        np.testing.assert_array_equal(x.image, y.image)
        np.testing.assert_array_equal(x.mask, y.mask)
        for k in x.fields.f:
            np.testing.assert_array_equal(x.fields.f[k], y.fields.f[k])
        assert x.meta == y.meta and x.id == y.id
        assert not np.array_equal(x.image, z.image)


def test_procedural_kinds_come_in_shuffled_rounds():
    """Every round of len(KINDS) lesions holds each preset once, and a set smaller than
    a round (sim2real's parts: 2 bodies x 3 lesions) draws other presets for other
    seeds, so that a run of small parts sees most presets."""
    from glsynth.assets.lesions import ProceduralLesions
    k = len(KINDS)
    bank = ProceduralLesions(2 * k, seed=11)
    for r in range(2):
        assert sorted(bank.kind(i) for i in range(r * k, (r + 1) * k)) == sorted(KINDS)
    seen = {ProceduralLesions(6, seed=s).kind(i) for s in range(12) for i in range(6)}
    assert len(seen) >= 0.8 * k    # 72 random draws leave ~0.5 of 22 presets unseen
    assert [bank.kind(i) for i in range(6)] == [ProceduralLesions(6, seed=11).kind(i) for i in range(6)]
    only = ProceduralLesions(5, seed=2, kinds=["nevus", "acne"])
    assert {only.kind(i) for i in range(5)} == {"nevus", "acne"}


@pytest.mark.parametrize("preset", KINDS)
def test_every_preset_on_every_skin_type(preset):
    """A non-empty outline inside the grid, instances that cover it, colours inside the
    skin model's gamut on all six skin types, and a visible change of the skin."""
    from glsynth.assets.chromophores import linear_rgb, skin_inverse
    from glsynth.assets.lesions import reference_skin
    from glsynth.assets.morphology import apply_to_skin, make_condition
    f = make_condition(preset, [7, 1], size=128)
    m = f.mask
    assert m.any() and not (m[0].any() or m[-1].any() or m[:, 0].any() or m[:, -1].any())
    assert ((f.instances > 0) == m).all()
    ids = np.unique(f.instances[f.instances > 0])
    assert ids.tolist() == list(range(1, len(ids) + 1))
    for k in ids:                   # one connected piece per instance, none a speck
        assert ndimage.label(f.instances == k)[1] == 1
        assert (f.instances == k).sum() * f.mm_per_px ** 2 >= 0.05
    for fitz in range(1, 7):
        skin = reference_skin(fitz, 128, np.random.default_rng(fitz))
        out = apply_to_skin(f, skin)
        assert out.shape == skin.shape and out.dtype == np.uint8
        # the chromophores the condition asks for stay inside sRGB's gamut
        mel, blood, _ = skin_inverse()(skin.reshape(-1, 3))
        v = {k: a.reshape(-1) for k, a in f.f.items()}
        lin = linear_rgb(np.clip(mel * v["melanin"] + v["melanin_add"], 0, 1),
                         np.clip(blood * v["blood"] + v["blood_add"], 0, 0.7),
                         v["oxygen"], v["bilirubin"], v["dermal_melanin"], v["epidermis"],
                         v["scatter"])
        assert lin.min() > -0.01 and lin.max() < 1.01, (preset, fitz, lin.min(), lin.max())
        change = np.abs(out.astype(int) - skin.astype(int)).sum(-1)
        assert change[m].mean() > 3 * max(change[~ndimage.binary_dilation(m, iterations=20)].mean(), 0.3) \
            or f.f["height"][m].std() > 0.05, (preset, fitz)


def test_skin_inverse_finds_the_nearest_model_colour_whatever_it_saw_before(rng):
    """The inverse's table is filled as colours first occur: each colour gets the grid
    point nearest its 6-bit bin's centre in CIELAB (brute force here), whichever calls
    came before, and the residual is the colour's own Lab minus that point's."""
    from glsynth.assets.chromophores import SkinInverse, srgb_to_lab
    inv = SkinInverse()
    skin = rng.integers([150, 90, 60], [256, 200, 160], (300, 3)).astype(np.uint8)
    anything = rng.integers(0, 256, (300, 3)).astype(np.uint8)
    for batch in (skin, anything, np.concatenate([anything[:50], skin[:50]])):
        mel, blood, resid = inv(batch[:, None])                 # an H x W x 3 image
        centres = (batch // 4 * 4 + 2).astype(np.uint8)
        d = ((srgb_to_lab(centres)[:, None] - inv.grid_lab[None]) ** 2).sum(-1)
        best = d.argmin(1)
        assert np.array_equal(mel[:, 0], inv.grid_mel[best]) and np.array_equal(blood[:, 0], inv.grid_blood[best])
        assert np.allclose(resid[:, 0], srgb_to_lab(batch) - inv.grid_lab[best])


def test_a_condition_applied_in_blocks_on_threads_equals_one_call(rng, monkeypatch):
    """Decals apply a condition to their pixels in row blocks on threads
    (glsynth.rows.by_rows): the same colours as one call at the same points, for a
    random preset on random skin (blocks of an odd size, the last one short)."""
    from glsynth import rows
    from glsynth.assets.morphology import PRESETS, apply_to_skin, make_condition
    preset = sorted(PRESETS)[int(rng.integers(len(PRESETS)))]
    f = make_condition(preset, [int(rng.integers(2 ** 31))], size=128)
    n = 20_011
    skin = rng.integers([120, 70, 40], [256, 200, 170], (n, 3)).astype(np.uint8)
    at = rng.uniform(-2, 130, (n, 2))
    whole = apply_to_skin(f, skin, at=at)
    monkeypatch.setattr(rows, "BLOCK_ROWS", 1_999)
    monkeypatch.setattr(rows.os, "cpu_count", lambda: 2)
    blocks = rows.by_rows(lambda s, a: apply_to_skin(f, s, at=a), skin, at)
    assert np.array_equal(blocks, whole), preset


@pytest.mark.parametrize("preset", ["ulcer", "kaposi_sarcoma", "inflammatory_patch"])
def test_an_outline_takes_in_the_visible_halo_round_its_lesion(rng, preset):
    """An annotator draws round all the visible change of a lesion: an ulcer's inflamed
    halo and macerated rim, the haemosiderin round a Kaposi sarcoma. Without it
    (halo_reach 0), over 60 seeds, a median 0.91 of the cells two out from an ulcer's
    outline were visibly changed (0.09 at least: a faint halo) and 0.45 round a Kaposi
    sarcoma; with it 0.02 and 0.08, 0.23 at most. The halo only adds to a preset's
    outline, and skin left as it is inside a lesion (a patch's spared islands) stays out."""
    from glsynth.assets import morphology as mo
    before = []
    for seed in rng.integers(2 ** 31, size=8 if preset == "ulcer" else 3):
        traced = mo.make_condition(preset, [int(seed)], size=192, halo_reach=0)
        drawn = mo.make_condition(preset, [int(seed)], size=192)
        assert (traced.mask <= drawn.mask).all() and (drawn.instances[drawn.mask] > 0).all()
        change = mo.visible_change(drawn)
        changed = change > mo.HALO_VISIBLE + 2
        share = []
        for f in (traced, drawn):
            ring = ndimage.binary_dilation(f.mask, iterations=2) & ~f.mask
            share.append(changed[ring].mean())
        before.append(share[0])
        assert share[1] < 0.35 and share[1] <= share[0] + 0.02, (preset, int(seed), share)
        # unchanged skin in the outline's holes, more than three cells from their edge:
        # the halo, judged on a coarser grid, may reach a few cells into a hole, and so
        # closes pockets up to 6 cells wide (seed 950122297: all of one 28 cells in
        # area); over 60 draws of the patch, none of the inside of a wider hole. A Kaposi
        # sarcoma has no spared islands: skin its satellites' halos close round is drawn
        # over by design (seeds 2133464345, 1265498922)
        holes = ndimage.binary_fill_holes(traced.mask) & ~traced.mask & (change < 1.0)
        inside = ndimage.binary_erosion(holes, iterations=3)
        if preset != "kaposi_sarcoma" and inside.any():
            assert drawn.mask[inside].mean() < 0.1, (preset, int(seed))
    if preset == "ulcer":
        assert np.mean(before) > 0.4, before


def test_lentigo_maligna_is_a_large_flat_mottled_brown_macule(rng):
    """Lentigo maligna is flat, several centimetres across, lighter on average than a
    melanoma and mottled: blotches from light tan to dark brown, not one even shade (as a
    cafe-au-lait macule is), its border fading out over millimetres in places."""
    from glsynth.assets.morphology import make_condition
    for seed in rng.integers(2 ** 31, size=6):
        lm = make_condition("lentigo_maligna", [int(seed)], size=256)
        mel = make_condition("melanoma", [int(seed)], size=256)
        patch = make_condition("pigmented_patch", [int(seed)], size=256)
        assert lm.params["extent_mm"] >= 15 and np.abs(lm.f["height"]).max() < 1e-3
        added = lm.f["melanin_add"][lm.mask]
        assert added.mean() < mel.f["melanin_add"][mel.mask].mean()
        spread = lambda f: np.subtract(*np.percentile(f.f["melanin_add"][f.mask], [90, 10])) \
            / np.median(f.f["melanin_add"][f.mask])
        # (over 150 seeds lentigo maligna spreads 1.09-2.3, median 1.5, and a pigmented
        # patch at most 0.36; a fresh draw in CI gave 0.92)
        assert spread(lm) > 0.8 and spread(lm) > 2 * spread(patch), (spread(lm), spread(patch))
        # ill-defined: a broad rim of faint pigment outside the outline (which takes in
        # the visible part of it; over 60 seeds 0.34-0.7 of the ring keeps 5% of the
        # median pigment)
        ring = ndimage.binary_dilation(lm.mask, iterations=4) & ~lm.mask
        assert np.mean(lm.f["melanin_add"][ring] > 0.05 * np.median(added)) > 0.25


def test_lentigo_maligna_ranges_from_a_faint_tan_stain_to_mid_brown(rng):
    """Lentigo maligna is often a faint tan stain, the way it is missed in the clinic,
    and at most mid brown with darker blotches. On Fitzpatrick III reference skin its
    median L* drop lies under 19.5 at the median of 24 draws and each draw still shows
    (over 200 seeds the drop spans 9-25, median 16.3, and 24-draw medians reach at
    most 19.7; the old tan-to-dark-brown draw had a median of 19.1 and never went under
    13.5)."""
    from glsynth.assets.lesions import reference_skin
    from glsynth.assets.morphology import apply_to_skin, make_condition
    skin = reference_skin(3, 256, np.random.default_rng(0))
    skin_L = srgb_to_lab(skin / 255.0)[..., 0]
    drops = []
    for seed in rng.integers(2 ** 31, size=24):
        lm = make_condition("lentigo_maligna", [int(seed)], size=256)
        on_skin = srgb_to_lab(apply_to_skin(lm, skin) / 255.0)[..., 0][lm.mask]
        drops.append(np.median(skin_L[lm.mask]) - np.median(on_skin))
    assert min(drops) > 6 and max(drops) < 32, drops
    assert np.median(drops) < 19.5, drops


def test_psoriasis_scale_ranges_from_thick_plates_to_a_thin_film(rng):
    """A psoriatic plaque's scale is not always the thick silvery crust of an untreated
    elbow: treated or moisturised plaques keep a thin scale through which the salmon-red
    shows. Over 24 draws the mean scale over the plaque reaches under 0.235 and over
    0.38 (over 200 seeds it spans 0.125-0.52; the old draw, always heavy, never went
    under 0.24)."""
    from glsynth.assets.morphology import make_condition
    cover = []
    for seed in rng.integers(2 ** 31, size=24):
        p = make_condition("psoriasis", [int(seed)], size=256)
        assert 0.25 <= p.params["scale_cover"] <= 1.0
        cover.append(float(p.f["scale"][p.mask].mean()))
    assert min(cover) < 0.235 and max(cover) > 0.38, cover


def test_melanoma_is_one_compact_irregular_lesion_not_an_ink_blot(rng):
    """A melanoma's outline is irregular (notched, lobed, asymmetric) but compact: one
    region without holes, filling 80-98% of its convex hull. (Over 300 draws the old
    warped disc left specks or holes in 94 and filled its hull by 0.87 at the median,
    petals and fingers; the lobed oval fills 0.83-0.97, median 0.92.)"""
    from glsynth.assets.morphology import make_condition
    solidity = []
    for seed in rng.integers(2 ** 31, size=8):
        f = make_condition("melanoma", [int(seed)], size=256)
        assert ndimage.label(f.mask)[1] == 1 and np.array_equal(ndimage.binary_fill_holes(f.mask), f.mask)
        assert f.instances.max() == 1 and f.params["lobes"] in (1, 2)
        contours, _ = cv2.findContours(f.mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        solidity.append(f.mask.sum() / cv2.contourArea(cv2.convexHull(contours[0])))
    assert 0.8 < min(solidity) and max(solidity) < 0.98, solidity
    assert np.median(solidity) > 0.88, solidity


def test_morphea_is_a_blanched_smooth_plaque_or_a_depressed_brown_patch(rng):
    """Active morphea's core has lost blood and skin markings (ivory, bound-down skin);
    burnt-out morphea is a brown patch, sunk a little, its skin markings kept."""
    from glsynth.assets.morphology import make_condition
    seen = set()
    for seed in rng.integers(2 ** 31, size=30):
        f = make_condition("morphea", [int(seed)], size=128)
        stage = f.params["stage"]
        seen.add(stage)
        d = ndimage.distance_transform_edt(f.mask)
        core = d > 0.5 * d.max()
        assert core.sum() > 50
        assert np.median(f.f["blood"][~f.mask]) > 0.95
        if stage == "active":
            assert np.median(f.f["blood"][core]) < 0.6 and np.median(f.f["detail"][core]) < 0.5
        else:
            assert np.median(f.f["melanin_add"][core]) > 0.02 and np.median(f.f["height"][core]) < -0.03
            assert np.median(f.f["detail"][core]) > 0.9
    assert seen == {"active", "burnt-out"}


def test_porokeratosis_rings_have_a_darker_keratotic_rim(rng):
    """Many small annular lesions, each rimmed by a thin raised, scaly, darker ridge."""
    from glsynth.assets.morphology import make_condition
    for seed in rng.integers(2 ** 31, size=3):
        # at most 60 mm across, so that even a 1.5 mm ring covers enough cells to measure
        f = make_condition("porokeratosis", [int(seed)], size=512, extent_mm=float(rng.uniform(30, 60)))
        ids = [k for k in range(1, int(f.instances.max()) + 1) if (f.instances == k).sum() > 200]
        assert len(ids) >= 5
        rimmed = 0
        for k in ids:
            m = f.instances == k
            rim = ndimage.binary_dilation(m, iterations=2) & ~ndimage.binary_erosion(m, iterations=2)
            inner = ndimage.binary_erosion(m, iterations=6)
            if inner.sum() < 10:
                continue
            outside = ndimage.binary_dilation(m, iterations=8) & ~ndimage.binary_dilation(m, iterations=4) \
                & (f.instances == 0)
            # darker than both the centre and the skin round it; the ridge is ~1.5 cells inside
            # a 4-cell band, so it shows in the band's top few percent (the 75th percentile
            # missed it on ~3% of rings)
            around = max(np.median(f.f["melanin"][inner]), np.median(f.f["melanin"][outside]))
            rimmed += np.percentile(f.f["melanin"][rim], 95) > 1.4 * around \
                and f.f["scale"][rim].max() > 0.3 and f.f["height"][rim].mean() > f.f["height"][inner].mean()
        assert rimmed == len(ids), (rimmed, len(ids))


def test_erythema_darkens_more_than_it_reddens_on_dark_skin():
    """The same inflammation: pink on light skin, a darker, less red change on dark skin."""
    from glsynth.assets.lesions import reference_skin
    from glsynth.assets.morphology import Builder, Canvas, apply_to_skin
    b = Builder(Canvas(np.random.default_rng(0), 128, 40.0))
    disc = b.weight(b.c.shape("round", 12.0, irregular=0.0, warp=0.0), 1.0)
    b.erythema(disc, 3.0)                                     # inflammation only
    f = b.fields(40.0)
    ring = disc > 0.9
    changes = {}
    for fitz in (1, 6):
        skin = reference_skin(fitz, 128, np.random.default_rng(0))
        lab0, lab1 = srgb_to_lab(skin[ring]), srgb_to_lab(apply_to_skin(f, skin)[ring])
        changes[fitz] = (lab1 - lab0).mean(0)                # dL, da, db
    assert changes[1][1] > 4                                  # light skin: a* up (red)
    assert changes[6][1] < 0.5 * changes[1][1]                # dark skin: much less red
    assert changes[6][0] < 0                                   # and darker


def test_a_flushed_skin_keeps_its_flush_over_a_condition(rng):
    """Skin redder than a healthy dermis' blood explains (a body's flush, a* 11-16) keeps
    that redness over a condition: added vessels redden it nearly as much as the same skin
    without the flush (the model saturates: on top of the 8-10% blood the inverse reads,
    they reddened it half as much); blanching still takes the flush away, melanin still
    hides it, and empty fields leave the skin as it was."""
    from glsynth.assets.colour import lab_to_srgb
    from glsynth.assets.morphology import Builder, Canvas, apply_to_skin

    def a_star_change(skin_lab, edit=None):
        b = Builder(Canvas(np.random.default_rng(0), 64, 20.0))
        disc = b.weight(b.c.shape("round", 6.0, irregular=0.0, warp=0.0), 1.0)
        if edit:
            edit(b, disc)
        rgb = np.clip(np.rint(lab_to_srgb(np.asarray([skin_lab], np.float64)) * 255), 0, 255).astype(np.uint8)
        skin = np.tile(rgb, (64, 64, 1))
        out = apply_to_skin(b.fields(20.0), skin)
        if edit is None:
            assert np.abs(out.astype(int) - skin).max() <= 1              # nothing: unchanged
        return (srgb_to_lab(out[disc > 0.95]).mean(0) - srgb_to_lab(rgb)[0])[1]

    def darker(b, disc):
        b.f["melanin_add"] += 0.3 * disc

    ratios = []
    for _ in range(4):
        L, b_star = rng.uniform(60, 72), rng.uniform(14, 20)
        flushed, even = (L, rng.uniform(11, 16), b_star), (L, 5.5, b_star)
        a_star_change(flushed)
        red_flushed = a_star_change(flushed, lambda b, disc: b.erythema(disc, 3.0))
        red_even = a_star_change(even, lambda b, disc: b.erythema(disc, 3.0))
        assert red_even > 8
        ratios.append(red_flushed / red_even)
        assert a_star_change(flushed, lambda b, disc: b.erythema(disc, -0.7)) < -2.5   # blanched
        shown = (flushed[1] + a_star_change(flushed, darker)) - (even[1] + a_star_change(even, darker))
        assert shown < 0.7 * (flushed[1] - even[1]), shown                              # hidden
    # over 60 draws: 0.81-1.04 (saturating, as before: 0.53-0.81, mean 0.7)
    assert np.mean(ratios) > 0.8, ratios


def test_kubelka_munk_layer_matches_the_hyperbolic_form(rng):
    """The one-exponential layer formula equals Kubelka-Munk's sinh/cosh form (evaluated in
    float64 where it does not overflow), and stays finite and in [0, 1] for thick layers."""
    from glsynth.assets.chromophores import _km_layer
    K = np.exp(rng.uniform(np.log(1e-3), np.log(2e4), 5000))
    S = rng.uniform(5.0, 300.0, 5000)
    d = np.exp(rng.uniform(np.log(1e-6), np.log(0.05), 5000))
    b = np.sqrt(((S + K) / S) ** 2 - 1)
    x = b * S * d
    ok = x < 300
    x = np.where(ok, x, 0.0)
    den = (S + K) / S * np.sinh(x) + b * np.cosh(x)
    r, t = _km_layer(K.astype(np.float32), S.astype(np.float32), d.astype(np.float32))
    # float32: within 5e-5 absolute (an 8-bit colour step is 4e-3), 2e-4 relative
    np.testing.assert_allclose(r[ok], (np.sinh(x) / den)[ok], rtol=2e-4, atol=5e-5)
    np.testing.assert_allclose(t[ok], (b / den)[ok], rtol=2e-4, atol=5e-5)
    assert np.isfinite(r).all() and np.isfinite(t).all() and (~ok).any()
    assert (r >= 0).all() and (r <= 1).all() and (t >= 0).all() and (r + t <= 1 + 1e-5).all()
    # a vanishing layer is transparent and unreflecting
    r0, t0 = _km_layer(np.float32(10.0), np.float32(50.0), np.float32(0.0))
    assert r0 == 0 and t0 == 1


def test_skin_colour_is_the_same_in_blocks_and_at_once(rng):
    """The spectral model works through large fields in blocks; a field's colours do not
    depend on where the block boundaries fall."""
    from glsynth.assets import chromophores
    n = chromophores._BLOCK * 2 + 123
    params = [rng.uniform(0, 0.4, n), rng.uniform(0, 0.8, n), rng.uniform(0, 1, n),
              rng.uniform(0, 2, n), rng.uniform(0, 0.2, n), rng.uniform(0, 3, n)]
    whole = chromophores.linear_rgb(*params)
    assert whole.shape == (n, 3) and np.isfinite(whole).all()
    idx = np.sort(rng.choice(n, 200, replace=False))
    one_by_one = np.stack([chromophores.linear_rgb(*(p[i] for p in params)) for i in idx])
    np.testing.assert_allclose(whole[idx], one_by_one, atol=1e-6)


@pytest.mark.parametrize("fitz", [1, 3, 6])
def test_reference_skin_lies_in_its_fitzpatrick_band(fitz):
    for les in procedural_lesions(2, seed=5, size=96, kinds=["nevus"], fitzpatrick=fitz):
        assert les.meta["fitzpatrick"] == fitz
        far = ~ndimage.binary_dilation(les.mask, iterations=10)
        assert fitzpatrick_from_ita(float(np.median(ita_degrees(les.image[far])))) == fitz


def test_procedural_bad_arguments():
    with pytest.raises(ValueError, match="kinds"):
        procedural_lesions(1, kinds=["chilblain"])
    with pytest.raises(ValueError, match="Fitzpatrick"):
        procedural_lesions(1, fitzpatrick=7)


# --- colour ----------------------------------------------------------------------------

def test_shades_of_gray_equalises_minkowski_means():
    rng = np.random.default_rng(0)
    img = np.clip(rng.normal((150, 110, 70), 25, (64, 64, 3)), 0, 255).astype(np.uint8)
    for p in (1, 6):
        out = shades_of_gray(img, p=p).astype(np.float64)
        e = np.mean(out ** p, axis=(0, 1)) ** (1 / p)
        assert np.ptp(e) / e.mean() < 0.01, e
    before = np.mean(img.astype(float) ** 6, axis=(0, 1)) ** (1 / 6)
    assert np.ptp(before) / before.mean() > 0.3  # the test image really has a cast
    with pytest.raises(ValueError):
        shades_of_gray(img.astype(np.float32))


def test_shades_of_gray_matches_the_pixel_formula(rng):
    """The histogram shortcut against the formula applied to the pixels themselves."""
    for k in range(6):
        shape = (int(rng.integers(1, 90)), int(rng.integers(1, 90)), 3)
        img = (rng.random(shape) ** rng.uniform(0.3, 3, 3) * 255).astype(np.uint8)
        if k == 5:
            img[..., 1] = 0  # no estimate possible: unchanged
        p = rng.choice([1.0, 2.5, 6.0])
        x = img.astype(np.float64)
        e = np.mean(x ** p, axis=(0, 1)) ** (1 / p)
        want = img if np.any(e <= 0) else np.clip(np.rint(x * np.sqrt(np.mean(e ** 2)) / e), 0, 255)
        np.testing.assert_array_equal(shades_of_gray(img, p=p), want.astype(np.uint8))


def test_lab_and_ita_known_colours():
    # Published CIELAB (D65) values of the sRGB primaries, white and black.
    rgb = np.array([[255, 0, 0], [0, 0, 255], [255, 255, 255], [0, 0, 0]], np.uint8)
    ref = np.array([[53.2408, 80.0925, 67.2032], [32.2970, 79.1875, -107.8602],
                    [100, 0, 0], [0, 0, 0]])
    np.testing.assert_allclose(srgb_to_lab(rgb), ref, atol=2e-3)
    np.testing.assert_allclose(ita_degrees(rgb[:3]),
                               [math.degrees(math.atan2(3.2408, 67.2032)),
                                math.degrees(math.atan2(-17.703, -107.8602)), 90.0], atol=1e-2)
    # Skin-like colours built from Lab with a chosen ITA come back with that ITA.
    for ita in (60.0, 45.0, 20.0, -10.0, -45.0):
        lab = [50 + 25 * math.sin(math.radians(ita)), 12, 25 * math.cos(math.radians(ita))]
        rgb8 = np.rint(lab_to_srgb(lab) * 255).astype(np.uint8)
        assert abs(float(ita_degrees(rgb8)) - ita) < 1.0
    # Agrees with OpenCV's float conversion on random colours.
    x = np.random.default_rng(1).integers(0, 256, (200, 3)).astype(np.uint8)
    cv = cv2.cvtColor(x[None].astype(np.float32) / 255, cv2.COLOR_RGB2LAB)[0]
    np.testing.assert_allclose(srgb_to_lab(x), cv, atol=0.5)


def test_fitzpatrick_bands():
    ita = [70, 55.1, 55, 41.1, 41, 28.1, 28, 10.1, 10, -29.9, -30, -60]
    assert fitzpatrick_from_ita(ita).tolist() == [1, 1, 2, 2, 3, 3, 4, 4, 5, 5, 6, 6]
    assert fitzpatrick_from_ita(30.0) == 3
    for t in range(1, 7):
        lo, hi = ita_range(t)
        assert fitzpatrick_from_ita((lo + hi) / 2) == t
    assert ita_range(2) == (41.0, 55.0)
    with pytest.raises(ValueError):
        ita_range(0)


@pytest.mark.parametrize("fitz", range(1, 7))
def test_an_erosion_is_raw_red_on_every_skin_type(fitz):
    """Where the epidermis is gone the vascular papillary dermis shows: redder (a*) than
    the skin around it, and than a dermis without that blood would be."""
    from glsynth.assets import morphology as M
    from glsynth.assets.colour import srgb_to_lab
    from glsynth.assets.lesions import reference_skin
    rng = np.random.default_rng(fitz)
    b = M.Builder(M.Canvas(rng, 64, 20.0))
    w = M.smoothstep(-0.5, 0.5, b.c.shape("round", 5.0, irregular=0.0, warp=0.0))
    b.erode(w, 0.1)
    fields = b.fields(20.0)
    skin = reference_skin(fitz, 64, rng)
    lab = srgb_to_lab(M.apply_to_skin(fields, skin).reshape(-1, 3) / 255.0).reshape(64, 64, 3)
    fields.f["blood_add"][:] = 0.0       # the same erosion without the dermis' blood
    pale = srgb_to_lab(M.apply_to_skin(fields, skin).reshape(-1, 3) / 255.0).reshape(64, 64, 3)
    core, around = w > 0.99, w < 0.01
    assert np.median(lab[core][:, 1]) > np.median(lab[around][:, 1]) + 5
    assert np.median(lab[core][:, 1]) > np.median(pale[core][:, 1]) + 5


def test_blood_in_vessels_flattens_the_soret_band_so_blood_rich_skin_is_crimson(rng):
    """Blood packed in vessels: its absorption is unchanged where blood is nearly clear,
    never more than a vessel can take up (1 / 2R), and never grows less as blood absorbs
    more; so haemoglobin's Soret band is flattened and an eroded, blood-rich bed keeps
    some blue: crimson (CIELAB hue below 30 deg), not orange (spread evenly: 34 deg)."""
    from glsynth.assets import chromophores as C
    mu = np.sort(10 ** rng.uniform(-3, 5, 200))
    packed = C._packed(mu)
    np.testing.assert_allclose(packed[mu < 1e-2], mu[mu < 1e-2], rtol=1e-4)
    assert (packed <= mu * (1 + 1e-12)).all() and (packed <= (1 + 1e-9) / (2 * C.VESSEL_CM)).all()
    assert (np.diff(packed) >= -1e-9 * packed[1:]).all()
    bed = srgb_to_lab(C.skin_rgb(0.01, 0.5, 0.8, epidermis=0.0, scatter=0.3))
    assert math.degrees(math.atan2(bed[2], bed[1])) < 30 and bed[1] > 30, bed


def test_the_chromophore_model_reaches_measured_skin_and_darkens_it_along_that_locus(rng):
    """Skin colours on the measured ITA locus (skin.skin_lab), from very light to very
    dark (every 5 degrees, and at random ITA): the model's nearest (melanin, blood) lies
    within a few CIEDE76 of each (2.5 on average over the range), with blood a healthy
    dermis holds (under 12%), and a little more melanin moves the colour as darker skin
    types differ: b* changes by at most 0.7 times as much as L* on light and mid skin
    (Jacques's in-vitro lambda^-3.33 gave -1.0 at ITA 45, where the locus has -0.23:
    pigmented lesions came out orange)."""
    from glsynth.assets.chromophores import melanin_slope, skin_inverse
    from glsynth.assets.skin import skin_lab
    inv = skin_inverse()
    grid = np.arange(-40.0, 66.0, 5.0)
    errors = []
    for ita in np.r_[grid, rng.uniform(-40, 65, 8)]:
        lab = skin_lab(ita)
        i = int(np.argmin(((inv.grid_lab - lab) ** 2).sum(-1)))
        error = float(np.linalg.norm(inv.grid_lab[i] - lab))
        assert error < 4.5 and inv.grid_blood[i] < 0.12, (ita, error, inv.grid_blood[i])
        errors.append(error)
        if ita > 15:
            darker = skin_lab(ita - 3) - lab
            locus = darker[2] / darker[0]
            slope = melanin_slope(lab)[1]
            assert -0.7 < slope < 0 and abs(slope - locus) < 0.45, (ita, slope, locus)
    assert np.mean(errors[:len(grid)]) < 2.5, errors


def test_less_dermal_scattering_deepens_the_red_of_blood():
    """Collagen-poor, vessel-rich tissue (granulation, a pyogenic granuloma) scatters less:
    the same blood reads darker and redder than in normal dermis, towards the cherry red of
    real vascular lesions, which the normal dermis cannot reach at any blood volume."""
    from glsynth.assets.chromophores import skin_rgb, skin_rgb_fast
    normal = srgb_to_lab(skin_rgb(0.02, 0.6, 0.8, epidermis=0.0))
    vascular = srgb_to_lab(skin_rgb(0.02, 0.6, 0.8, epidermis=0.0, scatter=0.2))
    assert vascular[0] < normal[0] - 8 and vascular[1] > normal[1] + 8
    full_blood = srgb_to_lab(skin_rgb(0.02, 1.0, 0.8, epidermis=0.0))
    assert vascular[1] > full_blood[1] + 4
    # the table path agrees with the exact model where scattering is changed
    np.testing.assert_allclose(skin_rgb_fast([0.02, 0.02], [0.6, 0.1], 0.8, scatter=[0.2, 1.0]),
                               skin_rgb([0.02, 0.02], [0.6, 0.1], 0.8, scatter=[0.2, 1.0]), atol=2 / 255)


@pytest.mark.parametrize("preset,min_a", [("pyogenic_granuloma", 35), ("ulcer", 31)])
def test_vascular_lesions_are_deep_red(preset, min_a):
    """A pyogenic granuloma and an ulcer's granulating bed on fair skin: dark, saturated
    red (CIELAB a* above 35, L* below 50), not the salmon pink of skin with more blood
    (a* ~20-25, L* ~60). The ulcer's bed is partly under yellow slough, which lowers its
    median a* (33-38 over draws), so it is held to 31."""
    from glsynth.assets.lesions import reference_skin
    from glsynth.assets.morphology import apply_to_skin, make_condition
    for seed in ([3, 1], [4, 1], [5, 1]):
        f = make_condition(preset, seed, size=128)
        lab = srgb_to_lab(apply_to_skin(f, reference_skin(2, 128, np.random.default_rng(0))))
        d = ndimage.distance_transform_edt(f.mask)        # the bed: the inner part of the outline
        core = (d > 0.4 * d.max()) & (f.f["crust"] < 0.05) & (f.f["scale"] < 0.05)
        assert core.sum() > 50
        a, L = np.median(lab[core][:, 1]), np.median(lab[core][:, 0])
        assert a > min_a and L < 50, (seed, np.median(lab[core], 0))


def test_ulcer_slough_ranges_from_yellow_to_grey_white_fibrin(rng):
    """Slough is yellow to tan in some ulcers, the grey-white of wet fibrin in others
    (sheets of it over a pyoderma's or a venous ulcer's bed): each ulcer's slough colour
    lies between the two, greyer the more fibrinous, and always light."""
    from glsynth.assets.morphology import CRUST_COLOURS, FIBRIN_GREY, make_condition
    lab = lambda rgb: srgb_to_lab(np.array([[rgb]], np.uint8))[0, 0]         # noqa: E731
    chroma = lambda rgb: float(np.hypot(*lab(rgb)[1:]))                       # noqa: E731
    assert chroma(FIBRIN_GREY) < 6 < 25 < chroma(CRUST_COLOURS["slough"])
    rows = []
    for seed in rng.integers(2 ** 31, size=8):
        f = make_condition("ulcer", [int(seed)], size=96)
        rows.append((f.params["fibrinous"], chroma(f.crust_rgb), lab(f.crust_rgb)[0]))
    rows = np.array(sorted(rows))
    assert (np.diff(rows[:, 1]) <= 0.5).all() and (rows[:, 2] > 75).all(), np.round(rows, 2)


def test_ulcer_floor_lies_below_the_skin_under_pale_slough(rng):
    """An ulcer's floor lies below the skin round it (its granules and slough never lift
    it above), deepest for pyoderma gangrenosum and pressure ulcers; its slough is pale
    yellow-white to grey-white, far lighter and less red than the granulating bed it
    lies on (where no film of fibrin covers it): yellow slough has b* above a*, the
    grey-white of wet fibrin may take a pink tinge from the bed (b* down to a* - 8;
    -4.9 at worst over 77 draws), never more red than a* 18 (14.3); all three kinds
    occur."""
    from glsynth.assets.lesions import reference_skin
    from glsynth.assets.morphology import apply_to_skin, make_condition
    depth = {}
    for seed in rng.integers(2 ** 31, size=24):
        f = make_condition("ulcer", [int(seed)], size=96)
        d = ndimage.distance_transform_edt(f.mask)
        floor = np.median(f.f["height"][d > 0.6 * d.max()])
        around = np.median(f.f["height"][~ndimage.binary_dilation(f.mask, iterations=3)])
        assert floor < around - 0.15, (seed, f.params, floor, around)
        depth.setdefault(f.params["kind"], []).append(around - floor)
        slough = f.f["crust"] > 0.5
        bed = f.mask & (f.f["crust"] < 0.05) & (f.f["scale"] < 0.05) & (f.f["epidermis"] < 0.1)
        if slough.sum() > 20:
            lab = srgb_to_lab(apply_to_skin(f, reference_skin(2, 96, np.random.default_rng(int(seed)))))
            (l_s, a_s, b_s), (l_b, a_b, _) = np.median(lab[slough], 0), np.median(lab[bed], 0)
            tinge = 8 if f.params["fibrinous"] > 0.5 else 0
            assert l_s > l_b + 6 and a_s < min(a_b - 15, 18) and b_s > a_s - tinge, (seed, lab[slough].mean(0))
    assert set(depth) == {"venous", "pressure", "pyoderma"}, depth
    assert np.median(depth["venous"]) < min(np.median(depth["pressure"]), np.median(depth["pyoderma"]))


def test_ulcer_bed_is_speckled_not_a_coat_of_red(rng):
    """A granulating bed photographs as red granule tops through a pale film of fibrin
    over part of it. Over draws, deep red (a* above 30) covers a median 15-70% of the
    floor (slough left out) and a* spreads widely across it (median p90 - p10 above
    18). Before the film, red covered ~85% and the spread was ~15: one coat of red."""
    from glsynth.assets.lesions import reference_skin
    from glsynth.assets.morphology import apply_to_skin, make_condition
    red, spread = [], []
    for seed in rng.integers(2 ** 31, size=12):
        f = make_condition("ulcer", [int(seed)], size=128)
        lab = srgb_to_lab(apply_to_skin(f, reference_skin(2, 128, np.random.default_rng(int(seed)))))
        d = ndimage.distance_transform_edt(f.mask)
        floor = (d > 0.3 * d.max()) & (f.f["crust"] < 0.7) & (f.f["epidermis"] < 0.1)
        a = lab[floor][:, 1]
        red.append(np.mean(a > 30))
        spread.append(np.subtract(*np.percentile(a, [90, 10])))
    assert 0.15 < np.median(red) < 0.7 and np.median(spread) > 18, (red, spread)


def test_pyogenic_granuloma_is_a_crimson_dome(rng):
    """A pyogenic granuloma rises to its centre (a dome, not a flat-topped button, whose
    top would mirror a flash) and is crimson: red with little yellow (a* well above b*).
    Its surface is smooth: the skin's markings are gone from it and its lobules dip
    broadly into each other (narrow clefts with the markings on made a wax seal of it:
    99th percentile of |Laplacian| x R^2 / height over 12 draws 33-174, median ~100;
    now a median of ~15 over 40 draws, 3 of them above 80 where crust or erosion meets it)."""
    from glsynth.assets.lesions import reference_skin
    from glsynth.assets.morphology import apply_to_skin, make_condition
    tops, bends = [], []
    for seed in rng.integers(2 ** 31, size=8):
        f = make_condition("pyogenic_granuloma", [int(seed)], size=192)
        d = ndimage.distance_transform_edt(f.mask)
        h = f.f["height"]
        centre, middle, rim = d > 0.8 * d.max(), (d > 0.4 * d.max()) & (d < 0.6 * d.max()), \
            (d > 0.05 * d.max()) & (d < 0.2 * d.max())
        assert np.median(h[centre]) > np.median(h[middle]) > np.median(h[rim]) > 0
        tops.append((h > 0.95 * h[f.mask].max()).sum() / f.mask.sum())
        lab = srgb_to_lab(apply_to_skin(f, reference_skin(2, 192, np.random.default_rng(int(seed)))))
        core = ndimage.binary_erosion(f.mask, iterations=4) & (f.f["crust"] < 0.05) & (f.f["scale"] < 0.05)
        a, b = np.median(lab[core][:, 1]), np.median(lab[core][:, 2])
        assert a > 33 and a > 1.6 * b, (a, b)
        smooth = (d > 0.2 * d.max()) & ndimage.binary_erosion(f.f["crust"] < 0.02, iterations=3)
        assert np.median(f.f["detail"][smooth]) < 0.3
        px, R = f.extent_mm / 192, f.params["extent_mm"] / 2
        lap = ndimage.laplace(h.astype(np.float64)) / px ** 2
        bends.append(np.percentile(np.abs(lap[smooth]), 99) * R ** 2 / h[f.mask].max())
    assert np.median(bends) < 80, bends
    # a button's flat top: 13-21% of its area within 5% of its highest point (a dome: ~4%,
    # more where crust or a lobe stands highest)
    assert np.median(tops) < 0.1, tops


def test_pyogenic_granuloma_collarette_rings_part_of_the_base(rng):
    """Where a pyogenic granuloma has a collarette, the scale lies round part of its base:
    over draws, a median of at least a tenth of the base's directions (36 sectors) holds
    none (~0.25 now). A full ring (0 sectors free, as until 2026-12-08) read as a white
    outline drawn round every one."""
    from glsynth.assets.morphology import make_condition
    free = []
    for seed in rng.integers(2 ** 31, size=24):
        f = make_condition("pyogenic_granuloma", [int(seed)], size=160)
        if not f.params["collarette"]:
            continue
        m = f.mask
        cy, cx = ndimage.center_of_mass(m)
        yy, xx = np.mgrid[:m.shape[0], :m.shape[1]]
        base = ndimage.binary_dilation(m, iterations=4) & ~ndimage.binary_erosion(m, iterations=6)
        sector = ((np.arctan2(yy - cy, xx - cx)[base] + np.pi) / (2 * np.pi) * 36).astype(int) % 36
        most = np.zeros(36)
        np.maximum.at(most, sector, f.f["scale"][base])
        assert most.max() > 0.2, seed                     # a collarette, not nothing
        free.append(np.mean(most < 0.05))
    assert len(free) >= 4 and np.median(free) >= 0.1, free


def test_old_crust_is_darker_and_uneven():
    """Crust is not a flat coat of paint: its colour varies across it and darkens where
    it is thick or old, towards dried blood's brown-red."""
    from glsynth.assets import morphology as M
    from glsynth.assets.lesions import reference_skin
    b = M.Builder(M.Canvas(np.random.default_rng(4), 128, 20.0))
    w = M.smoothstep(-0.5, 0.5, b.c.shape("round", 8.0, irregular=0.0, warp=0.0))
    b.crust(w, 1.0, "honey")
    f = b.fields(20.0)
    lab = srgb_to_lab(M.apply_to_skin(f, reference_skin(2, 128, np.random.default_rng(0))))
    crusted = f.f["crust"] > 0.7
    dark, light = crusted & (f.f["crust_dark"] > 0.5), crusted & (f.f["crust_dark"] < 0.2)
    assert dark.sum() > 30 and light.sum() > 30
    assert np.median(lab[dark][:, 0]) < np.median(lab[light][:, 0]) - 10
    assert lab[crusted][:, 0].std() > 5


def test_scale_lies_in_plates_split_by_fissures():
    """Scale is plates of keratin with fine fissures between them: within a plate the
    coverage is nearly even, and it drops along the plate edges, where the plaque shows."""
    from glsynth.assets import morphology as M
    b = M.Builder(M.Canvas(np.random.default_rng(9), 256, 20.0))
    w = np.ones((256, 256), np.float32)
    b.scale(w, 1.0, 1.5)
    wall, thickness, _ = b.cells(1.5)
    cover = b.f["scale"]
    edge, inner = wall < 0.01, wall > 0.2
    assert cover[edge].mean() < 0.7 * cover[inner].mean()
    # plates: ~(20 mm / 1.5 mm)^2 of them, each one thickness
    n_plates = len(np.unique(thickness))
    assert 100 < n_plates < 300, n_plates
    assert 0.3 < (cover > 0.2).mean() < 0.95


def test_heavy_scale_sheds_in_patches_of_whole_plates(rng):
    """Where psoriatic scale has come off, it has come off over a patch of neighbouring
    plates (single plates missing at random read as confetti): a shed plate's
    neighbours are shed far more often than plates are overall."""
    from glsynth.assets import morphology as M
    ratios = []
    for seed in rng.integers(2 ** 31, size=10):
        b = M.Builder(M.Canvas(np.random.default_rng(int(seed)), 256, 20.0))
        b.scale(np.ones((256, 256), np.float32), 0.8, 1.5)
        wall, _, plate = b.cells(1.5)
        inner = wall > 0.2
        count = np.bincount(plate[inner], minlength=plate.max() + 1)
        mean = np.bincount(plate[inner], b.f["scale"][inner], minlength=len(count)) / np.maximum(count, 1)
        whole = count >= 10
        shed = whole & (mean < 0.25)
        a = np.concatenate([plate[:, :-1].ravel(), plate[:-1].ravel()])
        c = np.concatenate([plate[:, 1:].ravel(), plate[1:].ravel()])
        pairs = np.unique(np.stack([a, c], 1)[a != c], axis=0)
        pairs = pairs[whole[pairs[:, 0]] & whole[pairs[:, 1]]]
        assert 0.03 < shed[whole].mean() < 0.5
        both = (shed[pairs[:, 0]] & shed[pairs[:, 1]]).sum() / shed[pairs[:, 0]].sum()
        ratios.append(both / shed[whole].mean())
    assert np.median(ratios) > 1.55, ratios   # plates shed one by one: 1.0-1.5


def test_light_scale_is_a_haze_not_loose_dots(rng):
    """Light scale whitens most of a plaque a little (a powdery film with a few flakes),
    rather than leaving a few bright flakes on bare skin."""
    from glsynth.assets import morphology as M
    b = M.Builder(M.Canvas(np.random.default_rng(int(rng.integers(2 ** 31))), 256, 30.0))
    b.scale(np.ones((256, 256), np.float32), 0.2, 0.8)
    cover = b.f["scale"]
    assert (cover > 0.08).mean() > 0.6 and cover.mean() < 0.35, ((cover > 0.08).mean(), cover.mean())


def test_urticaria_wheals_swell_as_domes(rng):
    """A wheal is oedema: its surface rises smoothly towards its middle (a plateau with a
    step at its edge showed only an outline where melanin hides the flare)."""
    from glsynth.assets.morphology import make_condition
    rising = []
    for seed in rng.integers(2 ** 31, size=6):
        f = make_condition("urticaria", [int(seed)], size=256)
        for k in range(1, int(f.instances.max()) + 1):
            m = f.instances == k
            if m.sum() < 400:
                continue
            d = ndimage.distance_transform_edt(m)
            outer = m & (d > 0.2 * d.max()) & (d < 0.4 * d.max())
            inner = m & (d > 0.7 * d.max())
            rising.append(np.median(f.f["height"][inner]) > 1.2 * np.median(f.f["height"][outer]))
    assert len(rising) >= 6 and np.mean(rising) >= 0.7, rising


def test_lichen_planus_papules_are_violaceous_flat_topped_and_striated(rng):
    from glsynth.assets.morphology import make_condition
    for seed in rng.integers(2 ** 31, size=4):
        f = make_condition("lichen_planus", [int(seed)], size=256)
        core = ndimage.binary_erosion(f.mask, iterations=2)
        assert core.sum() > 30
        assert np.median(f.f["oxygen"][core]) < 0.55                  # poorly oxygenated: violaceous
        assert np.median(f.f["dermal_melanin"][core]) > 0.004          # pigment dropped into the dermis
        h = f.f["height"][core]
        assert np.percentile(h, 75) - np.percentile(h, 25) < 0.05 and np.median(h) > 0.05  # flat tops
        assert (f.f["scale"][core] > 0.1).mean() > 0.02                 # Wickham's striae
        if f.params["arrangement"] == "grouped":
            assert f.instances.max() >= 5


def test_lichen_planus_plaques_keep_a_papules_dermal_pigment_where_papules_merge(rng):
    """Where papules merge into a plaque, its dermal melanin is that of its most
    pigmented papule (at most 0.02 x 1.2), not their sum: summed (as until 2026-12-08,
    99th percentile 0.02-0.09 over confluent draws) it turned plaques blue-black."""
    from glsynth.assets.morphology import make_condition
    seen = 0
    for seed in rng.integers(2 ** 31, size=24):
        f = make_condition("lichen_planus", [int(seed)], size=128)
        if f.params["arrangement"] != "confluent":
            continue
        seen += 1
        assert f.f["dermal_melanin"].max() <= 0.0241, seed
    assert seen >= 2


def test_inflammatory_patch_is_red_and_one_instance_per_patch(rng):
    from glsynth.assets.morphology import make_condition
    for seed in rng.integers(2 ** 31, size=4):
        f = make_condition("inflammatory_patch", [int(seed)], size=256)
        assert np.median(f.f["blood_add"][f.mask]) > 0.08
        assert np.median(f.f["blood_add"][~ndimage.binary_dilation(f.mask, iterations=15)]) < 0.01
        for k in range(1, int(f.instances.max()) + 1):
            assert ndimage.label(f.instances == k)[1] == 1


def _fine_variation(values, mask, mm_per_px):
    """Spread of ``values`` under a millimetre across, over their mean, inside ``mask``;
    on a grid that draws the puncta further apart than that (``puncta_mm``), under
    their spacing."""
    from glsynth.assets.morphology import puncta_mm
    fine = values - cv2.GaussianBlur(values, (0, 0), max(1.0, puncta_mm(mm_per_px)) / mm_per_px)
    return fine[mask].std() / values[mask].mean()


@pytest.mark.parametrize("extent_mm", [20.0, 60.0, 250.0])
def test_inflamed_erythema_is_blotched_and_stippled_with_its_mean_kept(rng, extent_mm):
    """The stippling of an inflammatory erythema has mean 1, stays positive and varies
    both under a millimetre (puncta) and over millimetres (blotches) at any grid scale
    (at 512 cells over 20, 60 and 250 mm: fine spread 0.45-0.50, blotches 0.27-0.32);
    an erythema laid out by it adds the same blood on average as an even one, over a
    patch many blotches wide (over 200 draws a patch filling most of the canvas keeps
    its mean within 0.027; a disc 9 mm across on the 20 mm canvas holds too few
    blotches and strayed by up to 0.12, failing a quarter of runs)."""
    from glsynth.assets import morphology as mo
    canvas = mo.Canvas(np.random.default_rng(int(rng.integers(2 ** 31))), 512, extent_mm)
    s = mo.Builder(canvas).stippling()
    px = canvas.px
    assert abs(s.mean() - 1) < 1e-4 and s.min() > 0.05
    assert 0.3 < _fine_variation(s, np.ones_like(s, bool), px) < 0.7
    blotches = cv2.GaussianBlur(s, (0, 0), 0.7 / px) - cv2.GaussianBlur(s, (0, 0), 8 / px)
    assert 0.15 < blotches.std() < 0.5
    w = np.clip(1.5 - np.hypot(canvas.x, canvas.y) / (0.6 * extent_mm), 0, 1).astype(np.float32)
    added = []
    for stipple in (0.0, 0.8):
        b = mo.Builder(canvas)
        b.erythema(w, 2.0, stipple=stipple)
        added.append(float(b.f["blood_add"].sum()))
    assert abs(added[1] / added[0] - 1) < 0.05, added


@pytest.mark.parametrize("preset", ["inflammatory_patch", "psoriasis", "tinea", "pityriasis_rosea"])
def test_dermatoses_are_not_an_even_wash_of_red(rng, preset):
    """Up close a dermatitis' redness is mottled and dotted: the blood added inside the
    outline varies under a millimetre by a share of its mean. Over 40 draws each, with
    the stippling its median was 0.40-0.43 (0.25 the least, in an inflammatory patch); as
    an even wash it was 0.09-0.21 (0.37 the most). A mean over six draws above 0.27
    fails an even wash and passes the stippling but for about one run in 10,000. (The
    spread used to be taken under a millimetre even on grids of up to 2 mm a cell, whose
    puncta are 3 mm: 0.7% of inflammatory patches fell below 0.15, one run in 25.)"""
    from glsynth.assets.morphology import make_condition
    spread = []
    for seed in rng.integers(2 ** 31, size=6):
        f = make_condition(preset, [int(seed)], size=256)
        inside = f.mask & (f.f["blood_add"] > 0.05)
        spread.append(_fine_variation(f.f["blood_add"], inside, f.mm_per_px))
    assert np.mean(spread) > 0.27 and min(spread) > 0.15, spread


def test_eczema_excoriations_lie_under_dark_dried_blood(rng):
    """Scratches are crusted with dark dried blood along their length, not raw orange
    erosions showing between a few lumps of crust."""
    from glsynth.assets.morphology import CRUST_COLOURS, make_condition
    crusted = []
    for seed in rng.integers(2 ** 31, size=40):    # (not every eczema is scratched)
        f = make_condition("eczema", [int(seed)], size=256)
        eroded = f.f["epidermis"] < 0.5
        if eroded.sum() > 5:
            crusted.append(np.median(f.f["crust"][eroded]) > 0.45)
        assert f.crust_rgb == CRUST_COLOURS["haemorrhagic"]
        if len(crusted) == 4:
            break
    assert len(crusted) == 4 and all(crusted), crusted


def test_spots_match_the_nearest_spot_everywhere(rng):
    """The windowed many-spot distance equals a brute-force maximum over all spots within
    each spot's reach."""
    from glsynth.assets import morphology as M
    c = M.Canvas(np.random.default_rng(int(rng.integers(2 ** 31))), 96, 30.0)
    centres = rng.uniform(-14, 14, (25, 2))
    radii = rng.uniform(0.3, 2.0, 25)
    sd, index = M.spots(c, centres, radii, irregular=0.0, reach=3.0)
    d = radii[:, None, None] - np.hypot(c.x[None] - centres[:, 0, None, None], c.y[None] - centres[:, 1, None, None])
    # where the nearest spot's window covers the cell (within 3 radii of its centre), the
    # windowed value is the maximum over all spots
    near = d.max(0) >= -2.0 * radii[d.argmax(0)]
    assert near.mean() > 0.3
    np.testing.assert_allclose(sd[near], d.max(0)[near], atol=1e-4)
    assert (index[near] == d.argmax(0)[near]).all()
    assert np.isfinite(sd).all() and sd.min() >= -3.0 * radii.max() - 1e-6


def test_purpura_is_purple_and_comes_as_petechiae_papules_or_a_bruise(rng):
    """Blood outside the vessels reads purple on light skin: darker, redder and less
    yellow than the skin around it. An old bruise (age 0.7 and more) may turn yellow
    overall, but its yellow sits at the rim, where the blood is thin and broken down.
    Petechiae are many pinpoint instances; palpable purpura is raised; a bruise is flat."""
    from glsynth.assets.lesions import reference_skin
    from glsynth.assets.morphology import apply_to_skin, make_condition
    seen = {}
    for seed in rng.integers(2 ** 31, size=60):
        f = make_condition("purpura", [int(seed)], size=256)
        kind = f.params["kind"]
        if kind in seen:
            continue
        seen[kind] = f
        skin = reference_skin(2, 256, np.random.default_rng(int(seed)))
        lab, base = srgb_to_lab(apply_to_skin(f, skin)), srgb_to_lab(skin)
        blood = f.f["blood_add"]
        core = f.mask & (blood > 0.6 * blood.max()) & (f.f["crust"] < 0.05)
        around = np.median(base[~ndimage.binary_dilation(f.mask, iterations=5)], 0)
        dl = np.median(lab[core], 0) - around
        assert dl[0] < -8 and dl[1] > 5, (kind, dl)
        if kind == "ecchymosis" and f.params["age"] >= 0.7:
            rim = f.mask & (blood < 0.3 * blood.max())
            rim_yellow = np.median(lab[rim], 0)[2] - around[2]
            assert rim_yellow > 0 and dl[2] < rim_yellow - 3, (f.params, dl, rim_yellow)
        else:
            assert dl[2] < 0, (f.params, dl)
        flat = f.f["height"][f.mask].max() < 0.01
        if kind == "petechiae":
            areas = ndimage.sum(f.mask, f.instances, range(1, f.instances.max() + 1)) * f.mm_per_px ** 2
            assert f.instances.max() >= 4 and np.median(areas) < np.pi * 1.2 ** 2 and flat
        elif kind == "palpable":
            assert not flat
        else:
            assert flat
    assert set(seen) == {"petechiae", "palpable", "ecchymosis"}


def test_telangiectasia_is_fine_red_lines_outlined_by_the_area_they_occupy(rng):
    """Small extents are spider angiomas: legs radiating from a central punctum, found in
    most directions around it; larger ones a leg patch or facial telangiectasia. The
    vessels are thin lines, redder than the skin between them, a minority of the outline,
    which is the one area they occupy (one instance) and holds nearly all of them."""
    from glsynth.assets.lesions import reference_skin
    from glsynth.assets.morphology import apply_to_skin, make_condition
    seen = set()
    extents = [8, 12, 16, 80] + rng.uniform(20, 58, 16).tolist()   # facial or leg: 0.45 / 0.55
    for seed, extent in zip(rng.integers(2 ** 31, size=len(extents)), extents):
        f = make_condition("telangiectasia", [int(seed)], size=256, extent_mm=extent)
        kind = f.params["kind"]
        seen.add(kind)
        assert (kind == "spider") == (extent < 18) and (kind == "leg" or extent < 60)
        assert f.instances.max() == 1
        blood = f.f["blood_add"]                         # the vessels stand out of any flush
        lines = blood - ndimage.median_filter(blood, 9) > 0.04
        assert lines.sum() > 20 and lines.sum() < 0.3 * f.mask.sum(), (kind, lines.sum(), f.mask.sum())
        assert (lines & f.mask).sum() > 0.95 * lines.sum(), kind
        lab = srgb_to_lab(apply_to_skin(f, reference_skin(2, 256, np.random.default_rng(int(seed)))))
        between = f.mask & ~ndimage.binary_dilation(lines, iterations=3)
        # facial telangiectasia lies on a flush, so its lines stand less far out of the skin
        # between them: a* 4.75 above at the least over 147 draws (median 8.4), 4.57 in one
        # draw of CI; legs 7.3 and spiders 10 at the least
        margin = 3.0 if kind == "facial" else 5.0
        assert np.median(lab[lines][:, 1]) > np.median(lab[between][:, 1]) + margin, kind
        if kind == "spider":
            legs = lines & (np.hypot(*np.meshgrid(np.arange(256) - 127.5, np.arange(256) - 127.5))
                            * f.mm_per_px > 1.5)
            ys, xs = np.nonzero(legs)
            octants = np.unique(((np.arctan2(ys - 127.5, xs - 127.5) + np.pi) / (np.pi / 4)).astype(int) % 8)
            assert len(octants) >= 5, octants
    assert seen == {"spider", "leg", "facial"}


def test_discoid_lupus_has_a_scaly_dark_rim_around_a_pale_scar_with_plugs(rng):
    """Discoid lupus: the rim is raised, scalier and darker than the centre (more
    melanin), the centre is depigmented, and it holds follicular plugs, small separate
    dots of keratin, mostly in the active border: the scar keeps few of them (separate
    dots per area, over ten draws: under 0.2 of the lesion's plugs; 0.07-0.10 measured,
    ~0.42 with every plug kept, as neighbours merge).
    On type VI skin the rim reads darker than the scar (most of it: islands of pigment
    stay, and one may sit at the very centre)."""
    from glsynth.assets.lesions import reference_skin
    from glsynth.assets.morphology import apply_to_skin, make_condition
    in_scar, expected = 0, 0.0
    for seed in rng.integers(2 ** 31, size=10):
        f = make_condition("lupus", [int(seed)], size=256)
        d = ndimage.distance_transform_edt(f.mask)
        rim, centre, scar = f.mask & (d < 0.15 * d.max()), d > 0.75 * d.max(), d > 0.5 * d.max()
        m = f.f["melanin"]
        # (the scar as a whole: an island of pigment may fill the few centre pixels; from
        # half the depth in, as the scar drawn 0.7 of the radius wide reaches there fully:
        # from 0.4 in, 2 of 301 draws took in the rim's pigmented edge and failed)
        assert np.median(m[rim]) > 1.2 and np.median(m[scar]) < 1.0     # islands of pigment stay
        assert (m[scar] < 0.5).mean() > 0.2                                 # a depigmented scar
        assert np.median(f.f["height"][rim]) > np.median(f.f["height"][centre])
        assert np.mean(f.f["scale"][rim] > 0.2) > np.mean(f.f["scale"][centre] > 0.2)
        core = d > 0.75 * d.max()
        plugs, n = ndimage.label(f.f["scale"] * core > 0.5)
        assert n == 0 or np.bincount(plugs.ravel())[1:].max() < 0.01 * f.mask.sum(), n
        in_scar += n
        expected += f.params["follicular_plugs"] * core.sum() / f.mask.sum()
        skin = reference_skin(6, 256, np.random.default_rng(int(seed)))
        lum = srgb_to_lab(apply_to_skin(f, skin))[..., 0]
        assert np.median(lum[rim]) < np.percentile(lum[scar], 75) - 10
    assert 0 < in_scar < 0.2 * expected, (in_scar, expected)


def test_discoid_lupus_scars_burn_out_pale(rng):
    """An active discoid lupus lesion's centre stays red; an old one's is a fibrosed,
    ivory to pink-white scar with little blood. Over 16 draws on type II skin, the four
    most scarred centres are redder than the skin around them by less than the four
    least scarred (by 3.7-8.7 a* over 30 sets of draws), and are about as light as it
    (mean L* difference -0.8 to +4.4; the least scarred -9.3 to -2.7)."""
    from glsynth.assets.lesions import reference_skin
    from glsynth.assets.morphology import apply_to_skin, make_condition
    rows = []
    for seed in rng.integers(2 ** 31, size=16):
        f = make_condition("lupus", [int(seed)], size=160)
        d = ndimage.distance_transform_edt(f.mask)
        centre = d > 0.75 * d.max()
        around = ndimage.binary_dilation(f.mask, iterations=8) & ~ndimage.binary_dilation(f.mask, iterations=3)
        lab = srgb_to_lab(apply_to_skin(f, reference_skin(2, 160, np.random.default_rng(int(seed)))))
        rows.append((f.params["scarred"], np.median(lab[centre][:, 1]) - np.median(lab[around][:, 1]),
                     np.median(lab[centre][:, 0]) - np.median(lab[around][:, 0])))
    rows = np.array(sorted(rows))
    active, burnt = rows[:4], rows[-4:]
    assert active[:, 1].mean() - burnt[:, 1].mean() > 2.5, np.round(rows, 2)
    assert burnt[:, 2].mean() > -3 and active[:, 2].mean() < burnt[:, 2].mean(), np.round(rows, 2)


def test_vessel_trees_fork_and_taper_and_cover_their_drawn_area(rng):
    """An unbranched vessel covers w L (plus its round ends), also where it is narrower
    than a cell (drawn fainter), and is its full width from its start. A tree of depth d
    covers at most the summed area of its tapering branches, w L (1 + 2 0.65 0.75 + ...),
    and at least 0.6 of it: branches may cross and share cells (0.67-1.00 over 800
    draws). Coverage stays in 0..1."""
    from glsynth.assets import morphology as M
    for width, cells in ((0.3, 1024), (0.3, 96)):
        c = M.Canvas(np.random.default_rng(int(rng.integers(2 ** 31))), cells, 40.0)
        heading = rng.uniform(0, 2 * np.pi)
        start = -6.0 * np.array([np.cos(heading), np.sin(heading)])
        cov = M.vessel_tree(c, [start], [heading], width, 12.0, depth=3)
        assert np.isfinite(cov).all() and cov.min() >= 0 and cov.max() <= 1 + 1e-6
        expected = width * 12.0 * sum((2 * 0.65 * 0.75) ** k for k in range(4))
        area = cov.sum() * c.px ** 2
        assert 0.6 * expected < area < 1.1 * expected, (cells, area, expected)
        cov = M.vessel_tree(c, [start], [heading], width, 12.0, depth=0)
        assert 0.97 * width * 12.0 < cov.sum() * c.px ** 2 < 1.08 * width * 12.0, (cells, cov.sum() * c.px ** 2)
        if cells == 1024:   # an unbranched vessel's first millimetre is its full width
            near = np.hypot(c.x - start[0], c.y - start[1]) < 1.0
            assert 0.8 * width < cov[near].sum() * c.px ** 2 < 1.3 * width


def test_nodular_bcc_is_a_smooth_pearly_dome_with_a_rolled_border(rng):
    """A nodular BCC stands highest at its rolled border (a slight central dell), has
    lost the skin's markings, is only softly glossy, and is pale pink rather than dark
    red; a superficial one is a thin plaque."""
    from glsynth.assets.lesions import reference_skin
    from glsynth.assets.morphology import apply_to_skin, make_condition
    seen, rolled = set(), []
    for seed in rng.integers(2 ** 31, size=24):
        f = make_condition("bcc", [int(seed)], size=192)
        seen.add(f.params["subtype"])
        d = ndimage.distance_transform_edt(f.mask)
        h = f.f["height"]
        if f.params["subtype"] == "superficial":
            assert h.max() < 0.3
            continue
        centre, ring = d > 0.8 * d.max(), (d > 0.15 * d.max()) & (d < 0.5 * d.max())
        # (a lobule can stand as high as the border in some draws)
        rolled.append(np.median(h[ring]) > np.median(h[centre]))
        assert f.params["ulcer"] or np.median(h[centre]) > 0.2
        intact = f.mask & (f.f["epidermis"] > 0.9) & (f.f["crust"] < 0.05)
        assert np.median(f.f["detail"][intact]) < 0.6 and f.f["gloss"][intact].max() <= 0.45
        skin = reference_skin(2, 192, np.random.default_rng(int(seed)))
        dl = np.median(srgb_to_lab(apply_to_skin(f, skin))[intact], 0) - np.median(srgb_to_lab(skin)[~f.mask], 0)
        assert dl[0] > -10 and 2 < dl[1] < 15, dl
    assert seen == {"nodular", "superficial"}
    assert np.mean(rolled) >= 0.8, rolled


def test_no_condition_is_cut_off_at_its_grid_edge(rng):
    """Every preset's outline stays inside the band where the grid fades its fields out,
    so no lesion has a straight edge where its grid ended (a wide vitiligo, an
    ill-defined lentigo maligna or eczema were cut there in most draws)."""
    from glsynth.assets.morphology import PRESETS, make_condition
    size = 96
    edge = np.minimum.reduce([np.arange(size), np.arange(size)[::-1]])
    band = np.minimum.outer(edge, edge) < 0.06 * size
    for preset in PRESETS:
        for seed in rng.integers(2 ** 31, size=3):
            f = make_condition(preset, [int(seed)], size=size)
            assert f.mask.any() and not (f.mask & band).any(), (preset, int(seed))


def test_pityriasis_rosea_has_a_central_herald_patch_with_a_red_edge_and_paler_centre(rng):
    """The herald patch sits at the centre, is the largest oval, and (like its daughters)
    is salmon at its edge and paler inside; the daughters stay clear of it. Salmon, not
    mauve: the colour the edge adds to light skin leans to yellow (a hue angle of the
    a*, b* change around 9 degrees; with deoxygenated blood it was around 1, and
    negative on a third of skins)."""
    from glsynth.assets.lesions import reference_skin
    from glsynth.assets.morphology import apply_to_skin, make_condition
    hues = []
    for seed in rng.integers(2 ** 31, size=4):
        f = make_condition("pityriasis_rosea", [int(seed)], size=256)
        n = int(f.instances.max())
        assert n >= 1 + min(f.params["daughters"], 1)    # (daughters may overlap one another)
        areas = ndimage.sum(f.mask, f.instances, range(1, n + 1))
        herald = f.instances == 1 + int(np.argmax(areas))
        assert herald[128, 128] and areas.max() > 2 * np.delete(areas, np.argmax(areas)).max(initial=0)
        lab = srgb_to_lab(apply_to_skin(f, reference_skin(2, 256, np.random.default_rng(int(seed)))))
        d = ndimage.distance_transform_edt(herald)
        edge, centre = herald & (d > 0.1 * d.max()) & (d < 0.35 * d.max()), d > 0.7 * d.max()
        assert np.median(lab[edge, 1]) > np.median(lab[centre, 1]) + 3, seed
        assert np.median(lab[centre, 1]) > np.median(lab[~ndimage.binary_dilation(f.mask, iterations=5), 1])
        for fitz in (1, 2, 3):
            lab = srgb_to_lab(apply_to_skin(f, reference_skin(fitz, 256, np.random.default_rng(int(seed)))))
            change = np.median(lab[edge], 0) - np.median(lab[~ndimage.binary_dilation(f.mask, iterations=5)], 0)
            hues.append(np.degrees(np.arctan2(change[2], change[1])))
    assert np.median(hues) > 4, np.round(hues)


def test_vitiligo_is_a_whole_white_patch_some_trichrome_or_repigmenting(rng):
    """Vitiligo loses melanin (milky white on brown skin, L* far above it), is outlined
    as one patch with its repigmenting islands inside (not holes in the mask), and only
    some patches are trichrome or repigmenting."""
    from glsynth.assets.lesions import reference_skin
    from glsynth.assets.morphology import apply_to_skin, make_condition
    kinds = set()
    for seed in rng.integers(2 ** 31, size=16):
        f = make_condition("vitiligo", [int(seed)], size=128)
        kinds.add((f.params["trichrome"], f.params["repigmenting"]))
        holes = lambda m: ndimage.label(ndimage.binary_fill_holes(m) & ~m)[1]
        if f.params["repigmenting"]:     # its dots pierce the white, not the outline
            dots = holes(f.mask & (f.f["melanin"] < 0.5))
            assert holes(f.mask) == 0 and dots > 2, (holes(f.mask), dots)
        core = ndimage.distance_transform_edt(f.mask) > 4
        lab = srgb_to_lab(apply_to_skin(f, reference_skin(5, 128, np.random.default_rng(int(seed)))))
        lab0 = srgb_to_lab(reference_skin(5, 128, np.random.default_rng(int(seed))))
        assert np.median(lab[core, 0]) > np.median(lab0[~f.mask, 0]) + 15
    # which kinds occur, over more (coarse) draws: with 16 alone, all plain or repigmenting
    # came up about once in 60 seeds
    for seed in rng.integers(2 ** 31, size=48):
        f = make_condition("vitiligo", [int(seed)], size=48)
        kinds.add((f.params["trichrome"], f.params["repigmenting"]))
    assert len(kinds) >= 3 and (False, False) in kinds


def test_seborrhoeic_keratosis_is_stuck_on_with_dark_keratin_in_its_fissures(rng):
    """A seborrhoeic keratosis stands above the skin over all of it, and the fissures
    between its ridges (its lowest parts) hold more pigmented keratin than the ridges:
    at least 23% more in 80 draws (without the fissures' keratin, about as much)."""
    from glsynth.assets.morphology import make_condition
    for seed in rng.integers(2 ** 31, size=4):
        f = make_condition("seborrhoeic_keratosis", [int(seed)], size=256)
        core = ndimage.binary_erosion(f.mask, iterations=4)
        h, mel = f.f["height"][core], f.f["melanin_add"][core]
        assert np.percentile(h, 5) > 0.1
        low, high = h < np.percentile(h, 15), h > np.percentile(h, 85)
        assert np.median(mel[low]) > 1.1 * np.median(mel[high]), seed


def _lightness_drop(f, seed):
    """How far the median L* of condition ``f`` on type II reference skin lies below
    that of the skin round it (more than 4 cells out)."""
    from glsynth.assets.colour import srgb_to_lab
    from glsynth.assets.lesions import reference_skin
    from glsynth.assets.morphology import apply_to_skin
    L = srgb_to_lab(apply_to_skin(f, reference_skin(2, f.size, np.random.default_rng(seed))))[..., 0]
    return np.median(L[~ndimage.binary_dilation(f.mask, iterations=4)]) - np.median(L[f.mask])


def test_naevi_are_tan_to_dark_brown_or_skin_coloured_domes(rng):
    """Junctional naevi are flat, tan to dark brown; compound ones raised in the middle
    and darker; intradermal ones domes nearly the skin's colour. On type II skin in 120
    draws the median L* drops by 8-43 / 17-48 / 3-15 (until 2026-12-07 every naevus
    dropped by 28-49). A third of naevi drop by under 12 and a third by over 25 (1,500
    draws); 48 draws hold at least a twentieth of each (test seed 3054071738 drew only 5
    intradermal naevi and 3 drops under 12, 0.0625, which failed the tenth asked until
    then; at 0.05 a bootstrap puts a failure below 1 in 10,000)."""
    from glsynth.assets.morphology import make_condition
    drop, raised = {}, {}
    for seed in rng.integers(2 ** 31, size=48):
        f = make_condition("nevus", [int(seed)], size=96)
        kind = f.params["type"]
        drop.setdefault(kind, []).append(_lightness_drop(f, seed))
        raised.setdefault(kind, []).append(f.f["height"][f.mask].max())
    assert set(drop) == {"junctional", "compound", "intradermal"}
    assert max(raised["junctional"]) == 0 and min(raised["compound"] + raised["intradermal"]) > 0.25
    assert 0 < min(drop["intradermal"]) and max(drop["intradermal"]) < 18
    assert min(drop["junctional"] + drop["compound"]) > 5 and np.median(drop["compound"]) > 20
    spread = np.concatenate(list(drop.values()))
    assert (spread < 12).mean() > 0.05 and (spread > 25).mean() > 0.05


def test_seborrhoeic_keratoses_range_from_light_tan_to_dark_brown(rng):
    """On type II skin, a seborrhoeic keratosis's median L* lies 9-46 below the skin's
    (5th-95th percentile of 96 draws), 31% within 15 and 29% more than 30 below (until
    2026-12-07 none within 15, 81% more than 30 below: nearly all black-brown)."""
    from glsynth.assets.morphology import make_condition
    drop = np.array([_lightness_drop(make_condition("seborrhoeic_keratosis", [int(seed)], size=96), seed)
                     for seed in rng.integers(2 ** 31, size=64)])
    assert (drop < 15).mean() >= 0.12 and (drop > 30).mean() >= 0.1
    assert 10 < np.median(drop) < 30 and drop.min() > 0


def test_warts_are_rough_keratotic_papules_flecked_with_black_dots(rng):
    """A wart is raised, under keratin over most of it, interrupts the skin's lines, and
    carries black dots (clotted capillaries) inside its outline and nowhere outside."""
    from glsynth.assets.morphology import make_condition
    for seed in rng.integers(2 ** 31, size=6):
        f = make_condition("wart", [int(seed)], size=256)
        m = f.mask
        assert np.median(f.f["height"][m]) > 0.1 and (f.f["scale"][m] > 0.05).mean() > 0.8
        assert np.median(f.f["detail"][m]) < 0.5
        dots = f.f["crust_dark"] > 0.5
        assert dots.any() and not (dots & ~ndimage.binary_dilation(m, iterations=3)).any()
        assert f.params["arrangement"] != "mosaic" or f.instances.max() >= 1


def test_keloids_are_smooth_shiny_domes_higher_inside_than_at_the_edge(rng):
    """Raised well above its edge, but never taller than 0.6 of its half-width (1-4 mm on
    every band made narrow ones pills standing on the skin)."""
    from glsynth.assets.morphology import make_condition
    for seed in rng.integers(2 ** 31, size=8):
        f = make_condition("keloid", [int(seed)], size=256)
        m = f.mask
        d = ndimage.distance_transform_edt(m)
        h = f.f["height"]
        top, edge = h[d > 0.7 * d.max()].mean(), h[(d > 0) & (d < 0.1 * d.max())].mean()
        half_width = d.max() * f.extent_mm / f.size
        assert top > min(0.8, 0.4 * half_width) and top > 2 * edge, (top, edge, half_width)
        assert h.max() < 0.75 * half_width + 0.1, (h.max(), half_width)
        assert np.median(f.f["detail"][m]) < 0.3 and np.median(f.f["gloss"][m]) > 0.1


def test_keloids_end_round_not_in_points(rng):
    """A long keloid without claws is a band with rounded ends: near each end (0.8-0.85
    of its half-length from the middle) it is still most of its width. A long ellipse's
    dome ran out to two points, a lozenge: 0-0.58 of the width there, median 0.40 (37
    draws, all aspects), against 0.55-0.90, median ~0.75, for the band (aspect under 0.45)."""
    from glsynth.assets.morphology import make_condition
    ratios = []
    for seed in rng.integers(2 ** 31, size=80):
        if len(ratios) == 4:
            break
        f = make_condition("keloid", [int(seed)], size=128)
        if f.params["claws"] or f.params["aspect"] > 0.45:
            continue
        pts = np.argwhere(f.mask).astype(np.float64)
        pts -= pts.mean(0)
        axes = np.linalg.svd(pts, full_matrices=False)[2]
        u, v = pts @ axes[0], pts @ axes[1]
        far = np.abs(u).max()
        middle = np.ptp(v[np.abs(u) < 0.3 * far])
        near_ends = (np.abs(u) >= 0.8 * far) & (np.abs(u) < 0.85 * far)
        ratios.append(min(np.ptp(v[near_ends & (u * side > 0)]) for side in (-1, 1)) / middle)
    assert len(ratios) >= 2 and np.median(ratios) > 0.6 and min(ratios) > 0.4, np.round(ratios, 3)


def test_keloids_are_plateaus_not_tubes(rng):
    """A keloid's top is flat, its shoulders steep: share of the lesion within 20% of its
    highest point, median 0.47 over 240 draws (5-95%: 0.40-0.54); a dome over the band,
    which rose to a tube with a fold along its middle, gave median 0.38 (0.29-0.47 over
    120). The median of 24 draws falls to 0.42 in fewer than one run in 3,000 (6 draws
    against 0.43 failed one run in 50, as in CI on 2026-12-01, seed 3893121992); the
    tube's never reaches it."""
    from glsynth.assets.morphology import make_condition
    shares = []
    for seed in rng.integers(2 ** 31, size=24):
        f = make_condition("keloid", [int(seed)], size=128)
        h, m = f.f["height"], f.mask > 0
        shares.append((h[m] >= 0.8 * h[m].max()).mean())
    assert np.median(shares) > 0.42, np.round(shares, 3)


def test_herpes_vesicles_are_glistening_pale_domes_on_a_red_base_one_instance_per_cluster(rng):
    """Vesicle clusters: the red base is outlined, one instance per cluster (clusters
    that touch merge); vesicles are domes that glisten and hold less of the base's
    added blood; crusted clusters carry crust instead."""
    from glsynth.assets.morphology import make_condition
    kinds = set()
    for seed in rng.integers(2 ** 31, size=6):
        f = make_condition("herpes", [int(seed)], size=256)
        kinds.add(f.params["kind"])
        assert 1 <= f.instances.max() <= f.params["clusters"]
        m = f.mask
        assert np.median(f.f["blood_add"][m]) > 0.1                       # the red base
        dome = f.f["height"] > 0.2
        assert (dome & m).sum() > 0.9 * dome.sum() > 0
        wet = f.f["gloss"] > 0.5
        if wet.any():
            assert np.median(f.f["blood_add"][wet]) < np.median(f.f["blood_add"][m & ~dome])
        else:
            assert f.f["crust"][dome].mean() > 0.1
    assert kinds == {"simplex", "zoster"} or len(kinds) == 1


def test_kaposi_sarcoma_is_violaceous_on_light_skin_and_darker_on_dark_skin(rng):
    """Poorly oxygenated blood and haemosiderin: on type II skin the lesion turns redder
    and not yellower (violaceous, where erythema leans to yellow); on type VI it is darker
    than the skin round it."""
    from glsynth.assets.lesions import reference_skin
    from glsynth.assets.morphology import apply_to_skin, make_condition
    for seed in rng.integers(2 ** 31, size=3):
        f = make_condition("kaposi_sarcoma", [int(seed)], size=256)
        inner = ndimage.binary_erosion(f.mask, iterations=2)
        outside = ~ndimage.binary_dilation(f.mask, iterations=12)
        for fitz, check in ((2, lambda d: d[1] > 5 and d[2] < 2), (6, lambda d: d[0] < -2)):
            skin = reference_skin(fitz, 256, np.random.default_rng(int(seed)))
            lab = srgb_to_lab(apply_to_skin(f, skin))
            d = np.median(lab[inner], 0) - np.median(lab[outside], 0)
            assert check(d), (fitz, np.round(d, 1))


def test_outline_specks_join_the_lesion_they_touch_or_leave_the_mask():
    """A region of an outline under 0.05 mm^2 is no lesion: one that touches another
    lesion becomes part of it, a lone one leaves the mask, and a small but real papule
    stays its own instance (granuloma annulare's seed 1501369465 left two 1-cell specks
    beside its ring until 2026-12-02)."""
    from glsynth.assets import morphology as M
    b = M.Builder(M.Canvas(np.random.default_rng(0), 100, 10.0))      # 0.1 mm cells
    yy, xx = np.mgrid[:100, :100]
    b.outline((np.hypot(yy - 50, xx - 40) < 20).astype(np.float32))   # lesion 1
    speck = np.zeros((100, 100), np.float32)
    speck[50, 60] = speck[10, 90] = 1                                 # a nick, a lone speck
    b.outline(speck)                                                  # lesion 2
    b.outline((np.hypot(yy - 85, xx - 85) < 2).astype(np.float32))    # a 0.4 mm papule
    M._relabel(b)
    assert b.instances.max() == 2
    assert b.instances[50, 60] == b.instances[50, 40] == 1 and b.mask[50, 60]
    assert b.instances[10, 90] == 0 and not b.mask[10, 90]
    assert b.instances[85, 85] == 2 and ((b.instances > 0) == b.mask).all()
    f = M.make_condition("granuloma_annulare", [1501369465], size=256)
    assert f.instances.max() == 1


def test_granuloma_annulare_is_a_raised_ring_without_scale_outlined_with_its_centre(rng):
    """A ring of low papules: no wall round it (the relief's slope stays below 1.2, where
    a ring raised as one band rose 0.3-0.5 mm within a cell or two), no scale, outlined
    with its centre."""
    from glsynth.assets.morphology import make_condition
    for seed in rng.integers(2 ** 31, size=3):
        f = make_condition("granuloma_annulare", [int(seed)], size=256)
        assert f.instances.max() == 1 and (ndimage.binary_fill_holes(f.mask) == f.mask).all()
        d = ndimage.distance_transform_edt(f.mask)
        assert f.f["height"][d > 0.8 * d.max()].max() < 0.05 < f.f["height"][f.mask].max()
        assert f.f["scale"].max() == 0
        gy, gx = np.gradient(f.f["height"] / f.mm_per_px)
        assert np.hypot(gx, gy).max() < 1.2


def test_granuloma_annulare_papules_merge_into_a_beaded_band(rng):
    """The ring's papules coalesce into one raised band that they bead, not a string of
    separate domes: over the raised ring, the relief's departure from itself blurred by
    0.3 of the ring's width is 0.12-0.26 of its mean (separate domes until 2026-12-01
    gave 0.30-0.34)."""
    from glsynth.assets.morphology import make_condition
    for seed in rng.integers(2 ** 31, size=4):
        f = make_condition("granuloma_annulare", [int(seed)], size=256)
        h = f.f["height"].astype(np.float32)
        ring = h > 0.25 * h.max()
        smooth = cv2.GaussianBlur(h, (0, 0), 0.3 * f.params["ring_mm"] / f.mm_per_px)
        beading = np.abs(h - smooth)[ring].mean() / h[ring].mean()
        assert 0.12 < beading < 0.26, (int(seed), beading)


def test_dome_is_round_topped_without_a_crease_along_its_middle(rng):
    """A dome over a long oval: highest on the middle, sloping to zero just past the edge,
    and smooth across its crest (the raw distance to the edge kinks there, which shading
    showed as a fold)."""
    from glsynth.assets.morphology import dome
    n = 200
    a, b = rng.uniform(60, 90), rng.uniform(15, 30)
    y, x = np.mgrid[:n, :n] - n / 2 + 0.5
    inside = (x / a) ** 2 + (y / b) ** 2 < 1
    h = dome(inside)
    far = ndimage.distance_transform_edt(~inside) > b
    assert h.max() == pytest.approx(1) and (h[far] < 0.01).all() and h[~inside].max() < 0.25
    assert h[n // 2, n // 2] > 0.95
    col = n // 2 + int(0.6 * a)              # a cut across the crest, off the top (the rounding
    across = h[:, col][inside[:, col]].astype(np.float64)           # hides a kink at the top)
    bend = np.abs(np.diff(across, 2))
    crest = int(np.argmax(across)) - 1
    assert bend[crest - 2:crest + 3].max() < 2 * np.median(bend[len(bend) // 4:3 * len(bend) // 4])


def test_actinic_keratoses_are_scaly_red_patches(rng):
    """Red (added blood) and scaly over their outline. Scale is patchy, so its mean over
    the outline is 0.037-0.08 or more (150 draws; 7% under 0.05, which this test used to
    demand, so a run of three draws failed about one time in five); a preset without
    scale has 0. The added blood's median over the outline is 0.06-0.14 over 100 draws,
    but a wide halo can pull it lower (seed 914443624: 0.048), so it must pass 0.03."""
    from glsynth.assets.morphology import make_condition
    for seed in rng.integers(2 ** 31, size=3):
        f = make_condition("actinic_keratosis", [int(seed)], size=256)
        m = f.mask
        assert np.median(f.f["blood_add"][m]) > 0.03 and f.f["scale"][m].mean() > 0.025, seed


def test_acne_mixes_inflamed_lesions_with_unlabelled_comedones(rng):
    """Acne is not one kind of red dome: over a few draws there are papules, pustules and
    nodules; a pustule's head is paler and yellower than the red papule round it; open
    comedones darken pores away from the outlined lesions, and stay skin."""
    from glsynth.assets.lesions import reference_skin
    from glsynth.assets.morphology import apply_to_skin, make_condition
    counts = {"papules": 0, "pustules": 0, "nodules": 0}
    for seed in rng.integers(2 ** 31, size=8):
        # 512 cells, the default resolution: on 256 an 11 cm field's cells (0.43 mm) can
        # fall between all its open comedones (0.24-0.6 mm across)
        f = make_condition("acne", [int(seed)], size=512)
        for k in counts:
            counts[k] += f.params[k]
        away = ~ndimage.binary_dilation(f.mask, iterations=6)
        # with only ten or so comedones, the open ones can all lie near lesions (seed
        # 94013731: 10, none 6 cells clear of an outline)
        if f.params["comedones"] >= 20:
            assert np.count_nonzero(away & (f.f["melanin_add"] > 0.1)) > 0, f.params
        head, red = f.f["scale"] > 0.3, f.mask & (f.f["scale"] < 0.02) & (f.f["melanin_add"] < 0.01)
        if head.sum() > 10:
            lab = srgb_to_lab(apply_to_skin(f, reference_skin(2, 512, np.random.default_rng(int(seed)))))
            (l_h, a_h, b_h), (l_r, a_r, _) = np.median(lab[head], 0), np.median(lab[red], 0)
            assert l_h > l_r + 5 and a_h < a_r - 5 and b_h > 10, (np.median(lab[head], 0), np.median(lab[red], 0))
    assert min(counts.values()) > 0, counts


def test_pigmented_patch_is_light_brown_on_fair_and_dark_skin(rng):
    """A cafe-au-lait macule or post-inflammatory patch is light to mid brown: L* about
    5-20 below the skin round it, on fair skin and on dark skin alike (an added amount of
    melanin alone hardly shows on type V). Added melanin of 0.03-0.14 made them 14-38
    below on types I-III."""
    from glsynth.assets.lesions import reference_skin
    from glsynth.assets.morphology import apply_to_skin, make_condition
    drops = {2: [], 5: []}
    for seed in rng.integers(2 ** 31, size=12):
        f = make_condition("pigmented_patch", [int(seed)], size=128)
        inner = ndimage.binary_erosion(f.mask, iterations=2)
        ring = ndimage.binary_dilation(f.mask, iterations=5) & ~f.mask
        for fitz in drops:
            skin = reference_skin(fitz, 128, np.random.default_rng(int(seed)))
            lab = cv2.cvtColor(apply_to_skin(f, skin).astype(np.float32) / 255, cv2.COLOR_RGB2LAB)
            drops[fitz].append(np.median(lab[ring][:, 0]) - np.median(lab[inner][:, 0]))
    # (over 300 seeds the medians are 14.1 on type II, 15.2 on type V, 23.2 at most,
    # since melanin's slope was fitted to measured skin (2026-12-06; 10.7 and 13.2 over 90
    # before, ~22 on type II before the presets were made lighter). Medians of 12 draws
    # stay within 9.0-19.7 and 9.7-19.9 in 9,999 of 10,000 sets)
    for fitz, d in drops.items():
        assert 3 < min(d) and max(d) < 26 and 6 < np.median(d) < 21, (fitz, np.round(d, 1))


def test_inflammatory_patches_can_hold_unlabelled_islands_of_spared_skin(rng, monkeypatch):
    """Patch-stage mycosis fungoides and other eruptions leave islands of normal skin in
    a large patch; the outline leaves them out and they carry none of the redness of any
    of the patches. (Other holes are allowed some: a bay closed off between overlapping
    ill-defined patches keeps their fading edges' redness.)"""
    from glsynth.assets import morphology
    placed = []
    spare = morphology._spared_islands
    monkeypatch.setattr(morphology, "_spared_islands", lambda *a: placed.append(spare(*a)) or placed[-1])
    seen = 0
    for seed in rng.integers(2 ** 31, size=60):
        placed.clear()
        f = morphology.make_condition("inflammatory_patch", [int(seed)], size=192)
        if not f.params["islands"]:
            continue
        islands = ndimage.binary_fill_holes(f.mask) & (placed[-1] > 0.7)   # the draw kept
        if islands.sum() < 10:   # an island that reached the patch's edge is a notch
            continue
        seen += 1
        assert not f.mask[islands].any()
        blood = f.f["blood_add"]
        assert np.median(blood[islands]) < 0.3 * np.median(blood[f.mask]), seen
        if seen == 3:
            break
    assert seen >= 2
