"""The post-render camera model (glsynth/pipeline/photo.py), wrap lighting (GL vs torch),
the extra 3D outputs (normals, UV, face ids) and the richer lighting of the views."""
import json
import os

import cv2
import numpy as np
import pytest
import torch

import glsynth as gs
from glsynth import diff
from glsynth.assets.colour import srgb_to_lab
from glsynth.config import ConfigError, PhotoConfig, load_config
from glsynth.lighting import Material, PointLight
from glsynth.pipeline import photo
from glsynth.pipeline.seeding import rng_for
from glsynth.pipeline.views import ambient_tint_from, camera_normals
from shapes import box, plane, sphere

RANGES = {"defocus": ("aperture", [0.002, 0.003]), "motion_blur": ("motion_blur", [2.0, 4.0]),
          "chromatic_aberration": ("chromatic_aberration", [1.0, 2.0]),
          "vignetting": ("vignetting", [0.2, 0.4]), "exposure": ("exposure", [0.3, 0.6]),
          "noise": ("shot_noise", [0.002, 0.004]), "white_balance": ("white_balance", [0.1, 0.2]),
          "auto_white_balance": ("auto_white_balance", [0.3, 0.6]),
          "tone": ("contrast", [0.2, 0.4]), "jpeg": ("jpeg_quality", [70, 90]),
          "watermark": ("watermark", 1.0)}


def _scene(rng, h=96, w=128):
    """A textured image (random blobs) and a depth map: body in the middle, background -1."""
    img = cv2.GaussianBlur((rng.random((h, w, 3)) * 255).astype(np.float32), (0, 0), 1.0)
    img = np.clip(img * 2 - 128, 0, 255).astype(np.uint8)
    depth = np.full((h, w), -1, np.float32)
    depth[10:-10, 10:-10] = np.linspace(0.3, 0.8, w - 20)[None, :]
    return img, depth


def _cfg(**ranges):
    """The camera model on with every effect off ([0, 0]) but those in ``ranges``."""
    off = {k: [0, 0] for k, v in vars(PhotoConfig()).items() if isinstance(v, list)}
    return PhotoConfig(**{**off, "watermark": 0.0, "enabled": True, **ranges})


@pytest.mark.parametrize("effect", sorted(RANGES))
def test_each_effect_zero_is_identity_nonzero_changes(effect, rng):
    img, depth = _scene(rng)
    if effect == "auto_white_balance":
        # uniform noise averages to grey, which a grey-world balance rightly leaves as it
        # is (seed 1837712870: bit-identical); give the frame a cast to correct
        img = (img * np.array([1.0, 0.85, 0.7])).astype(np.uint8)
    key, rng_range = RANGES[effect]
    zero = {"jpeg": [0, 0], "watermark": 0.0}.get(effect, [0.0, 0.0])
    p0 = photo.sample_params(_cfg(**{key: zero}), rng_for(1, "photo", 0, 0), 0.5, 1000.0)
    assert p0["effects"] == {}
    out0 = photo.apply(img, p0, depth)
    assert out0.dtype == np.uint8 and np.array_equal(out0, img)        # bit-exact
    p1 = photo.sample_params(_cfg(**{key: rng_range}), rng_for(1, "photo", 0, 0), 0.5, 1000.0)
    assert list(p1["effects"]) == [effect]
    out1 = photo.apply(img, p1, depth)
    assert out1.shape == img.shape and out1.dtype == np.uint8
    assert not np.array_equal(out1, img)


def test_disabled_and_all_zero_are_identity(rng):
    img, depth = _scene(rng)
    assert photo.sample_params(PhotoConfig(enabled=False), rng_for(0, "photo"), 1.0) == \
        {"enabled": False, "effects": {}}
    p = photo.sample_params(_cfg(), rng_for(0, "photo"), 1.0)
    assert photo.apply(img, p, depth) is img
    # the defaults of configs/default.yaml switch every effect on
    pc = load_config().photo
    p = photo.sample_params(pc, rng_for(0, "photo", 0, 0), 0.6)
    assert set(p["effects"]) >= {"noise", "jpeg", "white_balance"}


def test_parameters_recorded_and_reproducible(rng):
    img, depth = _scene(rng)
    pc = load_config().photo
    a = photo.sample_params(pc, rng_for(3, "photo", "body", 2), 0.5)
    b = photo.sample_params(pc, rng_for(3, "photo", "body", 2), 0.5)
    c = photo.sample_params(pc, rng_for(3, "photo", "body", 3), 0.5)
    assert a == b and a != c
    recorded = json.loads(json.dumps(a))             # what the per-image JSON keeps
    assert np.array_equal(photo.apply(img, a, depth), photo.apply(img, recorded, depth))
    for name, params in a["effects"].items():
        assert all(np.isfinite(v).all() for v in params.values() if not isinstance(v, str)), name


def test_tone_is_the_s_curve_and_the_chroma_boost(rng):
    """Against a float reference: each channel through (1 - c) x + c x^2 (3 - 2x), then
    chroma scaled by 1 + s about the Rec. 601 luma; within rounding (the table rounds
    before the matrix). Greys stay grey, black, mid-grey and white stay put, mid-tones
    gain contrast, and saturation alone is an effect of its own."""
    img, _ = _scene(rng)
    c, s = rng.uniform(0.1, 0.5), rng.uniform(0.05, 0.3)
    x = img.astype(np.float64) / 255
    ref = 255 * ((1 - c) * x + c * x * x * (3 - 2 * x))
    luma = ref @ np.array([0.299, 0.587, 0.114])
    ref = np.clip(luma[..., None] + (1 + s) * (ref - luma[..., None]), 0, 255)
    out = photo.tone(img, c, s)
    assert out.dtype == np.uint8 and np.abs(out - ref).max() <= 1.5
    greys = np.repeat(np.array([0, 64, 128, 192, 255], np.uint8)[:, None, None], 3, -1)
    g = photo.tone(greys, c, s)[:, 0]
    assert (g == g[:, :1]).all() and g[0, 0] == 0 and g[4, 0] == 255 and abs(int(g[2, 0]) - 128) <= 1
    assert g[3, 0] > 192 and g[1, 0] < 64
    p = photo.sample_params(_cfg(saturation=[0.1, 0.2]), rng_for(1, "photo", 0, 0), 0.5, 1000.0)
    assert list(p["effects"]) == ["tone"] and p["effects"]["tone"]["contrast"] == 0
    chroma = lambda im: float(np.abs(im.astype(np.float64) - (im @ photo.LUMA)[..., None]).mean())  # noqa: E731
    assert chroma(photo.apply(img, p)) > chroma(img) * 1.05


def test_watermark_is_a_stamp_in_its_place_and_a_share_of_images(rng):
    """The publisher's stamp changes only the pixels of its text (and shadow), in the
    corner it names, towards its ink; the share of stamped images follows the config;
    long text is shrunk to fit the frame, and the stamp scales with the image."""
    img = np.full((240, 320, 3), 120, np.uint8) + (rng.random((240, 320, 3)) * 20).astype(np.uint8)
    p = dict(photo.sample_watermark(rng_for(int(rng.integers(1 << 30)), "wm")), place="bottom-left",
             opacity=1.0, shadow=False, rgb=[255, 255, 255], text="SFS", height=0.06, margin=0.03)
    out = photo.watermark(img, p)
    changed = np.abs(out.astype(int) - img).max(-1) > 0
    ys, xs = np.nonzero(changed)
    assert changed.sum() > 50 and changed.mean() < 0.05
    assert ys.min() > 240 * 0.8 and xs.max() < 320 * 0.4              # bottom-left corner
    assert (out[changed].astype(int) >= img[changed]).all()           # towards white ink
    assert out[changed].max() == 255                                  # opaque: the ink itself
    cap = ys.max() - ys.min() + 1
    assert 0.04 * 240 < cap < 0.09 * 240                              # ~6% of the height
    big = photo.watermark(cv2.resize(img, (640, 480)), p)
    bys = np.nonzero(np.abs(big.astype(int) - cv2.resize(img, (640, 480))).max(-1) > 0)[0]
    assert abs((bys.max() - bys.min() + 1) / cap - 2) < 0.3            # same stamp, twice the size
    wide = photo.watermark(img, dict(p, text="www." + "x" * 60 + ".com", height=0.05, place="centre"))
    xs = np.nonzero(np.abs(wide.astype(int) - img).max(-1) > 0)[1]
    assert xs.min() >= 0.04 * 320 and xs.max() <= 0.96 * 320          # shrunk into the frame
    shaded = photo.watermark(img, dict(p, shadow=True, opacity=0.7))
    assert (shaded.astype(int) < img - 5).any()                       # the drop shadow darkens
    pc = _cfg(watermark=0.3)
    n = sum("watermark" in photo.sample_params(pc, rng_for(7, "photo", 0, j), 0.5)["effects"]
            for j in range(400))
    assert 0.24 < n / 400 < 0.36
    assert not any("watermark" in photo.sample_params(_cfg(), rng_for(7, "photo", 0, j), 0.5)["effects"]
                   for j in range(50))


def _local_contrast(gray):
    return float(np.abs(cv2.Laplacian(gray.astype(np.float32), cv2.CV_32F)).mean())


def test_defocus_sharp_at_focus_blurred_away_from_it(rng):
    h, w = 64, 256
    img = ((rng.random((h, w, 3)) > 0.5) * 200 + 30).astype(np.uint8)   # high-contrast noise
    depths = [1.0, 1.2, 2.0, 5.0]                                       # focus at 1.0
    depth = np.repeat(np.repeat(np.array(depths, np.float32), w // 4)[None], h, 0)
    params = {"enabled": True, "effects": {"defocus": {"kappa_px_m": 3.0, "focus_distance": 1.0,
                                                        "max_coc_px": 12.0}}}
    out = photo.apply(img, params, depth)
    q = w // 4
    pad = 8                                          # > the largest blur radius
    before = [_local_contrast(img[pad:-pad, i * q + pad:(i + 1) * q - pad].mean(-1)) for i in range(4)]
    after = [_local_contrast(out[pad:-pad, i * q + pad:(i + 1) * q - pad].mean(-1)) for i in range(4)]
    # at the focus distance: untouched, pixel for pixel
    assert np.array_equal(out[:, :q - pad], img[:, :q - pad])
    ratios = [a / b for a, b in zip(after, before)]
    assert ratios[0] == 1.0
    assert ratios[1] > ratios[2] > ratios[3] and ratios[3] < 0.5, ratios
    # the circle of confusion follows the thin lens: kappa * |d - s| / (d * s)
    coc = photo.coc_map(np.array([1.0, 2.0, 5.0, -1.0]), 3.0, 1.0, 12.0)
    assert np.allclose(coc, [0.0, 1.5, 2.4, 3.0])


def test_layered_defocus_equals_blurring_whole_images(rng):
    """Each blur layer is filtered only in the band of rows that use it; the result must
    equal blurring the whole image per layer and mixing by the radius (the definition)."""
    h, w = int(rng.integers(40, 90)), int(rng.integers(40, 90))
    lin = rng.random((h, w, 3)).astype(np.float32)
    depth = np.where(rng.random((h, w)) < 0.2, -1.0,
                     1.0 + np.cumsum(rng.normal(scale=0.05, size=(h, w)), 0)).astype(np.float32)
    kappa, focus, max_coc = rng.uniform(1, 6), float(rng.uniform(0.8, 1.5)), 12.0
    r = photo.coc_map(depth, kappa, focus, max_coc) / 2
    expect = np.zeros_like(lin)
    for k in range(int(np.ceil(r.max())) + 1):
        layer = lin if k == 0 else cv2.filter2D(lin, -1, photo.disc_kernel(k), borderType=cv2.BORDER_REFLECT)
        expect += layer * np.clip(1 - np.abs(r - k), 0, 1)[..., None]
    np.testing.assert_allclose(photo.defocus(lin, depth, kappa, focus, max_coc), expect, atol=2e-6)


@pytest.mark.parametrize("shot,read", [(0.01, 0.0), (0.0, 0.03), (0.004, 0.01)])
def test_noise_statistics_match_the_model(shot, read):
    x = float(photo.SRGB_TO_LINEAR[140])                # a flat mid-grey region
    lin = np.full((256, 256, 3), x, np.float32)
    noisy = photo.add_noise(lin, shot, read, seed=5)
    var = shot * x + read ** 2
    assert abs(noisy.mean() - x) < 4 * np.sqrt(var / noisy.size) + 1e-6
    assert noisy.var() == pytest.approx(var, rel=0.03)
    # end to end (sRGB in, 8-bit sRGB out): variance measured back in linear space,
    # within the 8-bit quantisation
    img = np.full((256, 256, 3), 140, np.uint8)
    p = {"enabled": True, "effects": {"noise": {"shot": shot, "read": read, "seed": 9}}}
    back = photo.SRGB_TO_LINEAR[photo.apply(img, p)]
    step = float(photo.SRGB_TO_LINEAR[141] - photo.SRGB_TO_LINEAR[140])
    assert back.var() == pytest.approx(var + step ** 2 / 12, rel=0.08)
    assert abs(back.mean() - x) < 2e-3


def test_noise_is_reproducible_from_its_seed_in_any_thread():
    from concurrent.futures import ThreadPoolExecutor
    lin = np.full((64, 80, 3), 0.3, np.float32)
    first = photo.add_noise(lin, 0.01, 0.01, seed=1234)
    with ThreadPoolExecutor(4) as pool:
        runs = list(pool.map(lambda s: photo.add_noise(lin, 0.01, 0.01, seed=s), [1234, 99, 1234, 99]))
    np.testing.assert_array_equal(runs[0], first)
    np.testing.assert_array_equal(runs[2], first)
    np.testing.assert_array_equal(runs[1], runs[3])
    assert not np.array_equal(runs[1], first)
    # uncorrelated across pixels and channels
    n = (first - 0.3).reshape(-1, 3)
    assert abs(np.corrcoef(n[:-1, 0], n[1:, 0])[0, 1]) < 0.05
    assert abs(np.corrcoef(n[:, 0], n[:, 2])[0, 1]) < 0.05


def test_white_balance_and_exposure_act_in_linear_space():
    img = np.full((8, 8, 3), 100, np.uint8)
    p = {"enabled": True, "effects": {"exposure": {"ev": 1.0},
                                      "white_balance": {"temperature": 0.0, "tint": 0.0,
                                                        "gains": [1.2, 1.0, 0.8]}}}
    out = photo.apply(img, p)
    lin = photo.SRGB_TO_LINEAR[100]
    expect = [photo.linear_to_srgb8(np.float32(lin * 2 * g)) for g in (1.2, 1.0, 0.8)]
    assert out[0, 0].tolist() == [int(e) for e in expect]


def test_grey_world_balance_takes_the_frame_mean_towards_grey(rng):
    """Random frames: the gains keep the mean's luminance, take its chromaticity the
    drawn share of the way (in log) to grey, and strength 0 is no change."""
    for _ in range(20):
        lin = (rng.random((32, 48, 3)) * rng.uniform(0.3, 1, 3)).astype(np.float32) * 0.9  # gains within bounds
        mean = lin[::4, ::4].reshape(-1, 3).astype(np.float64).mean(0)
        y = photo.LUMA_LINEAR @ mean
        k = rng.uniform(0, 1)
        g = photo.grey_world_gains(lin, k)
        assert np.isclose(photo.LUMA_LINEAR @ (mean * g), y)
        ratio = np.log(mean * g / y)                       # 0 for grey
        assert np.allclose(ratio - ratio.mean(), (1 - k) * (np.log(mean / y) - np.log(mean / y).mean()),
                           atol=1e-9)
        assert np.allclose(photo.grey_world_gains(lin, 0.0), 1.0)
    black = np.zeros((16, 16, 3), np.float32)               # no NaN on a black or one-primary frame
    red = np.zeros((16, 16, 3), np.float32)
    red[..., 0] = 0.5
    for frame in (black, red):
        g = photo.grey_world_gains(frame, 1.0)
        assert np.isfinite(g).all() and g.min() > 0 and g.max() / g.min() <= 16 * (1 + 1e-9)


def test_grey_world_balance_cools_skin_and_casts_it_off_a_red_plaque():
    """Skin filling the frame comes out less warm; the same skin beside a red plaque that
    fills most of the frame turns green (as in clinical photographs of large plaques),
    and clipped highlights do not steer the balance."""
    on = {"enabled": True, "effects": {"auto_white_balance": {"strength": 0.5}}}
    skin = np.full((40, 40, 3), (204, 153, 128), np.uint8)
    before, after = srgb_to_lab(skin[0, 0]), srgb_to_lab(photo.apply(skin, on)[0, 0])
    assert after[2] < before[2] - 5 and after[1] < before[1] - 4
    assert abs(after[0] - before[0]) < 1.5
    frame = np.full((40, 40, 3), (225, 190, 170), np.uint8)
    frame[:, :26] = (215, 120, 120)
    assert srgb_to_lab(frame[0, -1])[1] > 5 and srgb_to_lab(photo.apply(frame, on)[0, -1])[1] < 0
    glare = skin.copy()
    glare[:10] = 255
    assert np.allclose(photo.grey_world_gains(photo.srgb_to_linear(glare), 0.5),
                       photo.grey_world_gains(photo.srgb_to_linear(skin), 0.5), atol=1e-6)


def test_config_photo_keys_are_validated():
    with pytest.raises(ConfigError, match="photo.jpeg_quality"):
        load_config(None, ["photo.jpeg_quality=[50, 101]"])
    with pytest.raises(ConfigError, match="photo.aperture"):
        load_config(None, ["photo.aperture=[0.002, 0.001]"])
    with pytest.raises(ConfigError, match="views.wrap"):
        load_config(None, ["views.wrap=[0, 2]"])
    with pytest.raises(ConfigError, match="photo.bokeh"):
        load_config(None, ["photo.bokeh=1"])
    with pytest.raises(ConfigError, match="outputs"):
        load_config(None, ["outputs=[rgb, curvature]"])
    cfg = load_config(None, ["outputs=[rgb, normals, uv, face_id]"])
    assert cfg.outputs == ["rgb", "normals", "uv", "face_id"]


# ---- wrap lighting: GL vs torch ---------------------------------------------------------

@pytest.mark.parametrize("trial", range(3))
def test_wrap_lighting_torch_matches_gl(renderer, rng, trial):
    mesh = (sphere if trial % 2 == 0 else box)(rng)
    tex = (rng.random((64, 64, 3)) * 255).astype(np.uint8)
    mesh = mesh.copy_with(texture=tex)
    d = rng.normal(size=3)
    eye = d / np.linalg.norm(d) * rng.uniform(0.8, 3.0)
    cam = gs.Camera.look_at(eye, rng.normal(scale=0.05, size=3), width=renderer.width,
                            height=renderer.height, fov_deg=rng.uniform(20, 60))
    # the first light sits near the camera so the visible surface is lit (otherwise a box
    # face turned away from every light by more than the wrap angle shades the same either way)
    offsets = [rng.normal(scale=0.15 * np.linalg.norm(eye), size=3)] + \
        [rng.normal(scale=0.8, size=3) for _ in range(int(rng.integers(0, 3)))]
    lights = [PointLight(eye + o, ambient=rng.uniform(0, 0.5, 3), diffuse=rng.uniform(0.2, 0.99, 3),
                         specular=rng.uniform(0, 0.5, 3)) for o in offsets]
    mat = Material(specular=rng.uniform(0, 0.6, 3), shininess=rng.uniform(1, 200),
                   wrap=rng.uniform(0.2, 1.0))
    out = renderer.render(mesh, cam, passes=("gbuffer", "rgb"), lights=lights, material=mat)
    img = diff.shade(out, mesh, torch.tensor(tex / 255.0, dtype=torch.float32), cam, lights, mat)
    fg = out["face_id"] >= 0
    assert fg.sum() > 100
    err = np.abs(img.numpy() - out["rgb"])[fg]
    assert err.max() <= 2 / 255, f"max |torch - GL| = {err.max() * 255:.2f}/255"
    # the blending terms (texture-independent) agree too, and wrap did change them
    gbuf = diff.GBuffer(out)
    _, pos, nrm = diff.surface(gbuf, mesh)
    ls_wrap, _ = diff.lighting(pos, nrm, [cam], lights, mat)
    ls_plain, _ = diff.lighting(pos, nrm, [cam], lights, Material(mat.specular, mat.shininess))
    assert (ls_wrap - ls_plain)[0][torch.as_tensor(fg)].abs().max() > 0.01
    # and the GL pass really used wrap: without it the images differ
    plain = renderer.render(mesh, cam, passes=("rgb",), lights=lights,
                            material=Material(mat.specular, mat.shininess))
    assert np.abs(plain["rgb"] - out["rgb"])[fg].max() > 0.01


def test_wrap_zero_is_the_paper_shading(renderer, rng):
    mesh = sphere(rng)
    cam = gs.Camera.look_at((0, 0, 1.5), (0, 0, 0), width=renderer.width, height=renderer.height)
    lights = [PointLight((1.0, 0.5, 1.0))]
    a = renderer.render(mesh, cam, passes=("rgb",), lights=lights, material=Material())
    b = renderer.render(mesh, cam, passes=("rgb",), lights=lights, material=Material(wrap=0.0))
    assert np.array_equal(a["rgb"], b["rgb"])
    with pytest.raises(ValueError, match="wrap"):
        Material(wrap=-0.1)


# ---- extra 3D outputs ---------------------------------------------------------------------

def test_camera_normals_of_a_plane(renderer, rng):
    mesh = plane(rng, size=2.0)                     # normal +Z
    for eye in ((0.0, 0.0, 2.0), (1.2, 0.3, 1.0), (-0.5, -1.0, 1.5)):
        cam = gs.Camera.look_at(eye, (0, 0, 0), width=renderer.width, height=renderer.height)
        out = renderer.render(mesh, cam, passes=("gbuffer",))
        n = camera_normals(out, mesh, cam)
        fg = out["face_id"] >= 0
        expect = cam.view_matrix()[:3, :3] @ np.array([0.0, 0.0, 1.0])
        assert fg.sum() > 100
        assert np.abs(n[fg] - expect).max() < 1e-5
        assert (n[~fg] == 0).all()
        assert np.allclose(np.linalg.norm(n[fg], axis=-1), 1, atol=1e-5)


def test_ambient_tint_follows_the_background():
    bg = np.zeros((8, 8, 3), np.uint8)
    bg[...] = (200, 150, 100)
    t = ambient_tint_from(bg, 1.0)
    assert t[0] > t[1] > t[2] and np.mean(t) == pytest.approx(1.0)
    assert ambient_tint_from(bg, 0.0) == (1.0, 1.0, 1.0)


# ---- end to end: the camera model changes the RGB image only ----------------------------

SMALL = ["bodies.count=1", "bodies.texture_size=256", "lesions.per_body=1", "blend.method=paste",
         "views.per_body=2", "views.size=96", "views.supersample=1", "paste.view_size=128",
         "backgrounds.count=2", "seed=11", "outputs=[rgb, semantic, instances, anatomy, depth, normals, uv, face_id]",
         # small conditions: a body this small has no flat skin for the largest presets
         "lesions.kinds=[nevus, melanoma, bcc]"]


def test_photo_changes_only_the_image(tmp_path):
    from glsynth.io.images import read_image, read_rgb
    import tifffile
    runs = {}
    for name, extra in (("off", ["photo.enabled=false"]), ("on", ["photo.enabled=true", "photo.aperture=[0.002, 0.003]"])):
        out = tmp_path / name
        gs.pipeline.generate(load_config(None, SMALL + extra), out)
        runs[name] = out
    ids = sorted(f[:-5] for f in os.listdir(runs["on"] / "targets") if f.endswith(".json"))
    assert ids
    for sid in ids:
        for suffix in ("_semantic.png", "_instances.png", "_anatomy.png", "_depth.tiff",
                       "_normals.npy", "_uv.npy", "_face_id.npy"):
            a = (runs["off"] / "targets" / f"{sid}{suffix}").read_bytes()
            b = (runs["on"] / "targets" / f"{sid}{suffix}").read_bytes()
            assert a == b, f"{sid}{suffix} changed"
        off = read_rgb(str(runs["off"] / "images" / f"{sid}.png"))
        on = read_rgb(str(runs["on"] / "images" / f"{sid}.png"))
        assert not np.array_equal(off, on)
        meta = json.loads((runs["on"] / "targets" / f"{sid}.json").read_text())
        assert meta["photo"]["enabled"] and "defocus" in meta["photo"]["effects"]
        # the recorded parameters reproduce the image from the clean render
        depth = tifffile.imread(runs["on"] / "targets" / f"{sid}_depth.tiff")
        assert np.array_equal(photo.apply(off, meta["photo"], depth), on)
        # extra outputs: shapes, dtypes and conventions
        fid = np.load(runs["on"] / "targets" / f"{sid}_face_id.npy")
        nrm = np.load(runs["on"] / "targets" / f"{sid}_normals.npy")
        uv = np.load(runs["on"] / "targets" / f"{sid}_uv.npy")
        sem = read_image(str(runs["on"] / "targets" / f"{sid}_semantic.png"))
        assert fid.dtype == np.int32 and nrm.dtype == np.float16 and uv.dtype == np.float32
        assert ((fid >= 0) == (sem > 0)).all()
        assert (uv[fid < 0] == -1).all() and ((uv[fid >= 0] >= 0) & (uv[fid >= 0] <= 1)).all()
        body = fid >= 0
        assert np.allclose(np.linalg.norm(nrm[body].astype(np.float32), axis=-1), 1, atol=2e-3)
        assert (nrm[body][:, 2] > -0.2).mean() > 0.99        # visible surfaces face the camera
        cam = meta["camera"]
        k, m = np.array(cam["intrinsics"]), np.array(cam["world_to_camera_cv"])
        x = m @ np.r_[cam["target"], 1.0]
        u, v, _ = k @ (x[:3] / x[2])
        assert abs(u - meta["width"] / 2) < 1e-6 and abs(v - meta["height"] / 2) < 1e-6
        assert np.array(cam["world_to_camera"]).shape == (4, 4)


def test_a_share_of_images_carries_a_strong_colour_cast():
    """cast_share of the images draw white balance and tint from the cast ranges (and say
    so), the rest from the phone's; a strong green tint takes light skin's a* near grey."""
    pc = _cfg(white_balance=[-0.1, 0.1], tint=[-0.02, 0.02], cast_white_balance=[-0.6, 0.6],
              cast_tint=[-0.4, 0.4], cast_share=0.25)
    draws = [photo.sample_params(pc, rng_for(3, "photo", 0, j), 0.5)["effects"]["white_balance"]
             for j in range(800)]
    cast = np.array([d["cast"] for d in draws])
    assert 0.2 < cast.mean() < 0.3
    tint = np.abs([d["tint"] for d in draws])
    assert tint[~cast].max() <= 0.02 and np.percentile(tint[cast], 50) > 0.1
    skin = np.full((8, 8, 3), (204, 153, 128), np.uint8)
    green = {"enabled": True, "effects": {"white_balance": {"temperature": 0.0, "tint": 0.4, "cast": True,
                                                            "gains": [1.0, 2 ** 0.4, 1.0]}}}
    a = [cv2.cvtColor(x.astype(np.float32) / 255, cv2.COLOR_RGB2LAB)[0, 0, 1]
         for x in (skin, photo.apply(skin, green, np.ones((8, 8), np.float32)))]
    assert a[0] > 14 and a[1] < 7
