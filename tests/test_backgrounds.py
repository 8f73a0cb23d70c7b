"""Background sources: image folders and procedural rooms."""
import logging

import cv2
import numpy as np
import pytest

from glsynth.assets.backgrounds import (BackgroundError, fit_cover, load_backgrounds,
                                        procedural_backgrounds)

RED, BLUE = (255, 0, 0), (0, 0, 255)


def _write(path, rgb):
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    return path


def _halves(h, w):
    """Left half red, right half blue."""
    img = np.zeros((h, w, 3), np.uint8)
    img[:, : w // 2] = RED
    img[:, w // 2:] = BLUE
    return img


@pytest.fixture
def folder(tmp_path):
    root = tmp_path / "bg"
    _write(root / "a.png", _halves(100, 200))
    _write(root / "rooms" / "b.jpg", np.full((50, 40, 3), 128, np.uint8))
    _write(root / "rooms" / "c.bmp", np.full((30, 30, 3), 10, np.uint8))
    _write(root / "d.webp", np.full((20, 20, 3), 200, np.uint8))
    (root / "broken.jpg").write_bytes(b"\xff\xd8 truncated")
    (root / "notes.txt").write_text("not an image")
    return root


def test_folder_backgrounds(folder, caplog):
    with caplog.at_level(logging.WARNING):
        bg = load_backgrounds(folder)
    assert bg.ids == ["a", "d", "rooms/b", "rooms/c"]
    assert len(bg) == 4 and [p.endswith("broken.jpg") for p in bg.skipped] == [True]
    assert any("broken.jpg" in r.getMessage() and "skipped" in r.getMessage() for r in caplog.records)
    assert bg[0].shape == (100, 200, 3) and bg[0].dtype == np.uint8
    assert bg.meta[2]["path"].endswith("b.jpg")
    for i in range(len(bg)):
        out = bg.get(i, 64, 48)
        assert out.shape == (48, 64, 3) and out.dtype == np.uint8


def test_get_covers_and_centre_crops(folder):
    bg = load_backgrounds(folder)
    # 200x100 into 100x100: no scaling, the centre 100 columns are half red, half blue.
    sq = bg.get(0, 100, 100)
    assert (sq[:, :50] == RED).all() and (sq[:, 50:] == BLUE).all()
    # Upscaled to cover 300x300 (x3 -> 600x300), then the centre is cropped.
    big = bg.get(0, 300, 300)
    assert big.shape == (300, 300, 3)
    assert (big[:, :145] == RED).all() and (big[:, 155:] == BLUE).all()
    # A tall view of a wide image keeps the aspect (no stretching of the halves).
    tall = fit_cover(_halves(100, 200), 40, 100)
    assert tall.shape == (100, 40, 3)
    assert (tall[:, :20] == RED).all() and (tall[:, 20:] == BLUE).all()
    # Downscaled: 200x100 into 50x20 -> scale 0.25 -> 50x25, centre rows kept.
    small = fit_cover(_halves(100, 200), 50, 20)
    assert small.shape == (20, 50, 3) and (small[:, :24] == RED).all() and (small[:, 26:] == BLUE).all()
    with pytest.raises(BackgroundError, match="positive"):
        bg.get(0, 0, 10)


def test_folder_without_readable_images(tmp_path):
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "x.jpg").write_bytes(b"garbage")
    (bad / "y.png").write_bytes(b"")
    with pytest.raises(BackgroundError,
                       match=r"bad: no readable background images \(2 image files found, 2 unreadable"):
        load_backgrounds(bad)
    (tmp_path / "empty").mkdir()
    with pytest.raises(BackgroundError, match=r"empty: no readable background images \(0 image files"):
        load_backgrounds(tmp_path / "empty")
    with pytest.raises(BackgroundError, match="not found"):
        load_backgrounds(tmp_path / "missing")


def test_procedural_backgrounds_deterministic():
    a = procedural_backgrounds(4, seed=1, size=96)
    b = procedural_backgrounds(6, seed=1, size=96)
    c = procedural_backgrounds(4, seed=2, size=96)
    assert len(a) == 4 and len(set(a.ids)) == 4
    for i in range(4):
        np.testing.assert_array_equal(a[i], b[i])
        assert a.meta[i] == b.meta[i]
        assert not np.array_equal(a[i], c[i])
    assert not np.array_equal(a[0], a[1])


def test_procedural_backgrounds_look_like_rooms():
    bg = procedural_backgrounds(8, seed=0, size=128)
    for i in range(len(bg)):
        img, m = bg[i], bg.meta[i]
        assert img.shape == (128, 128, 3) and img.dtype == np.uint8
        assert m["source"] == "procedural" and m["seed"] == 0 and m["index"] == i
        assert img.std() > 5  # not a flat colour
        # Wall and floor differ: the horizon splits the picture into two regions.
        hz = int(m["horizon"] * 128)
        wall, floor = img[: hz - 10].reshape(-1, 3).mean(0), img[hz + 5:].reshape(-1, 3).mean(0)
        assert np.abs(wall - floor).max() > 5
    out = bg.get(3, 200, 100)
    assert out.shape == (100, 200, 3)
    with pytest.raises(BackgroundError):
        procedural_backgrounds(1, size=16)


def test_wide_blur_at_reduced_resolution_matches_the_full_blur(rng):
    import cv2
    from glsynth.assets.backgrounds import wide_blur
    for _ in range(20):
        h, w = rng.integers(100, 600, 2)
        mask = np.zeros((h, w), np.float32)
        y0, x0 = rng.integers(0, h // 2), rng.integers(0, w // 2)
        mask[y0:y0 + rng.integers(5, h // 2), x0:x0 + rng.integers(5, w // 2)] = 1
        sigma = float(rng.uniform(4, 50))
        full = cv2.GaussianBlur(mask, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
        assert np.abs(wide_blur(mask, sigma) - full).max() < 0.004, (sigma, h, w)


def test_fabric_comes_in_every_hue_skin_like_ones_included():
    """Clothing and curtains are dyed any colour: over 300 draws every 60-degree sector of
    CIELAB hue holds fabrics, most are muted (chroma under 30), and some are warm, dark
    and skin-like (hue 30-80 degrees, L* 20-60), as beside skin in clinical photographs."""
    from glsynth.assets.backgrounds import fabric_colour
    from glsynth.assets.colour import srgb_to_lab
    rng = np.random.default_rng()
    lab = srgb_to_lab(np.array([fabric_colour(rng) for _ in range(300)]) / 255.0)
    hue = np.degrees(np.arctan2(lab[:, 2], lab[:, 1])) % 360
    chroma = np.hypot(lab[:, 1], lab[:, 2])
    assert np.all(np.bincount((hue // 60).astype(int), minlength=6) >= 10)
    assert 0.5 < np.mean(chroma < 30) < 0.9
    warm_dark = (hue > 30) & (hue < 80) & (lab[:, 0] > 20) & (lab[:, 0] < 60) & (chroma > 10)
    assert warm_dark.sum() >= 5
    assert lab[:, 0].min() > 10 and lab[:, 0].max() < 90


def test_clinical_backdrops_come_in_their_shares_and_colours():
    """With clinical=1 every procedural background is a backdrop, each kind drawn in its
    share (within sampling error over 400) in a colour near its table's; black cloth is
    near-black (L* under 15) yet not a flat fill (its folds and weave show), and a sheet
    or couch paper is light."""
    from glsynth.assets.backgrounds import BACKDROP_SHARES, BACKDROPS
    from glsynth.assets.colour import srgb_to_lab
    bg = procedural_backgrounds(400, seed=3, size=64, clinical=1.0)
    kinds = [m["kind"] for m in bg.meta]
    for kind, share in BACKDROP_SHARES.items():
        got = kinds.count(kind) / len(kinds)
        assert abs(got - share) < 4 * np.sqrt(share * (1 - share) / len(kinds)), (kind, got)
    for i in [kinds.index(k) for k in BACKDROP_SHARES]:
        m, img = bg.meta[i], bg[i]
        if m["kind"] != "fabric":   # fabric: any dye (the next test)
            assert min(np.abs(np.subtract(m["colour"], c)).max() for c in BACKDROPS[m["kind"]]) < 40
        L = srgb_to_lab(img.reshape(-1, 3) / 255.0)[:, 0]
        if m["kind"] == "dark":
            assert np.median(L) < 15 and img.std() > 0.5, (np.median(L), img.std())
        if m["kind"] in ("sheet", "paper"):
            assert np.median(L) > 70
