"""configs/paper.yaml reproduces DermSynth3D where glsynth's defaults depart from it:
views not biased towards lesions, the original's light placement, deep blending at the
paper's weights, lesions never drawn above their source's resolution, and lesions kept
apart dilated region against dilated region."""
import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

import glsynth as gs
from glsynth.config import ConfigError, load_config
from glsynth.assets.colour import LINEAR_RGB_TO_XYZ
from glsynth.lighting import beam_gain, light_colour, planckian_xy
from glsynth.pipeline import views as V
from glsynth.pipeline.bodies import TexelGeometry
from glsynth.pipeline.paste import PasteSettings, Paster, paste_lesions
from glsynth.pipeline.seeding import rng_for
from glsynth.resources import config_dir
from shapes import plane, skin_sheet


def _blob(h=40, w=48, colour=(100, 60, 45)):
    yy, xx = np.mgrid[:h, :w]
    mask = np.hypot((yy - h / 2) / (h / 3), (xx - w / 2) / (w / 3)) < 1
    img = np.full((h, w, 3), 150, np.uint8)
    img[mask] = colour
    return SimpleNamespace(image=img, mask=mask, id="blob", meta={})


@pytest.fixture(scope="module")
def sheet():
    from gl_context import GL_BACKEND, get_renderer
    body = skin_sheet(np.random.default_rng(11), n=24, tex=1024, blur=3, amplitude=50)
    r = get_renderer(GL_BACKEND, 128, 128)
    return SimpleNamespace(body=body, r=r, tx=TexelGeometry.of(r, body.mesh))


def test_paper_preset_has_the_papers_settings():
    cfg = load_config(config_dir() / "paper.yaml")
    assert cfg.views.lesion_bias == 0 and cfg.views.light_position == "paper"
    assert cfg.views.light_offset == [0.0, 2.0]
    b = cfg.blend
    assert (b.method, b.steps, b.lr, b.content, b.style, b.gradient, b.tv) == \
        ("deep", 400, 0.005, 2.0, 1e6, 1e5, 1e-4)
    p = cfg.paste
    assert (p.view_size, p.fov_deg, p.w, p.max_depth_change) == (512, 30.0, [0.4, 0.6], 0.02)
    assert p.enlarge is False and p.overlap == "dilated"
    assert max(cfg.lesions.size) <= 1 / 3 + 1e-9
    v = cfg.views
    assert (v.size, v.fov_deg, v.w, v.ambient, v.diffuse, v.specular, v.material_specular,
            v.shininess, v.min_skin) == (512, 30.0, [0.1, 1.3], [0.2, 0.99], [0.2, 0.99], [0.0, 0.1],
                                         [0.0, 0.05], [30.0, 60.0], 0.1)
    assert v.flash == 0 and not v.shadows and v.wrap == [0.0, 0.0] and not cfg.photo.enabled
    # the paper's views and shading, none of glsynth's additions
    assert v.framing == {"wild": 1.0} and v.shading == "phong" and v.ambient_tint == 0
    assert "nevi" in cfg.outputs


@pytest.mark.parametrize("key,value", [("paste.overlap", "touching"), ("views.light_position", "sun"),
                                       ("paste.enlarge", "sometimes")])
def test_new_keys_are_validated(key, value):
    with pytest.raises(ConfigError, match=key):
        load_config(None, [f"{key}={value}"])


def test_lesions_are_never_drawn_above_their_source_resolution(sheet):
    """A 20-pixel lesion asked to cover 30-40% of a 128-pixel view: enlarge=False keeps
    it at 20 view pixels (scale 1), the default scales it up ~2x."""
    small = _blob(h=20, w=20)
    extent = max(np.ptp(np.nonzero(small.mask)[0]), np.ptp(np.nonzero(small.mask)[1])) + 1
    for enlarge in (False, True):
        s = PasteSettings(view_size=128, w=(0.35, 0.45), size=(0.3, 0.4), max_depth_change=0.05,
                          enlarge=enlarge)
        p = Paster(sheet.r, sheet.body, sheet.tx, s).place(small, rng_for(0, "scale", enlarge))
        assert p is not None
        x0, y0, x1, y1 = p.view_box
        if enlarge:
            assert p.scale > 1.5
        else:
            assert p.scale == 1.0 and max(x1 - x0, y1 - y0) <= extent * math.sqrt(2) + 2


def _min_gap_over_dilations(sheet, overlap, seed):
    """Smallest surface gap between two lesions' texels, in units of the sum of their
    dilation widths (dilation pixels at each placement's distance)."""
    s = PasteSettings(view_size=128, w=(0.35, 0.45), size=(0.16, 0.2), max_depth_change=0.05,
                      dilation=8, overlap=overlap, attempts=40)
    res = paste_lesions(sheet.r, sheet.body, sheet.tx, [_blob() for _ in range(16)], s, ("o",), seed)
    assert len(res.placements) >= 8
    ids = res.instances[sheet.tx.rows, sheet.tx.cols]
    pts = {p.instance: cKDTree(sheet.tx.points[ids == p.instance]) for p in res.placements}
    width = {p.instance: 2 * p.camera["w"] * math.tan(math.radians(15)) / 128 * s.dilation
             for p in res.placements}
    return min(pts[i].query(pts[j].data)[0].min() / (width[i] + width[j])
               for i in pts for j in pts if i < j)


@pytest.mark.parametrize("seed", [0, 3])
def test_dilated_lesions_do_not_overlap(sheet, seed):
    """overlap='dilated' (the original): two lesions are at least both dilation widths
    apart. The default only keeps the new lesion's dilated region off the old lesion,
    so packed lesions come closer (the control)."""
    assert _min_gap_over_dilations(sheet, "dilated", seed) >= 0.9
    assert _min_gap_over_dilations(sheet, "lesion", seed) < 0.9


def test_black_body_colours():
    """Planckian chromaticities against published ones (CIE illuminant A is a 2856 K black
    body under the older radiation constant, hence its looser bound); light colours keep
    a luminance of 1, are grey at 6504 K, warm below and bluish above."""
    for kelvin, xy, tol in ((2856, (0.44757, 0.40745), 1e-3), (5000, (0.3451, 0.3516), 3e-4),
                            (6504, (0.3135, 0.3236), 3e-4)):
        assert np.abs(np.subtract(planckian_xy(kelvin), xy)).max() < tol
    luma = LINEAR_RGB_TO_XYZ[1]
    assert np.allclose(light_colour(6504), 1)
    for kelvin in np.random.default_rng().uniform(1700, 20000, 8):
        c = light_colour(kelvin)
        assert luma @ c == pytest.approx(1) and (c >= 0).all()
        assert (c[0] > c[2]) == (kelvin < 6504)
    with pytest.raises(ValueError, match="colour temperature"):
        planckian_xy(1000)


def test_mixed_light_is_white_balanced_at_the_viewed_point(renderer):
    """With coloured lights the camera balances for their mix at the viewed point: a grey
    plane comes out grey there whatever the temperatures; toward the frame's corners,
    where the flash's beam gives less, the warmer room light's colour shows."""
    mesh = plane(np.random.default_rng(2), size=4.0).copy_with(texture=np.full((8, 8, 3), 90, np.uint8))
    body = SimpleNamespace(mesh=mesh)
    v = dataclasses.replace(load_config().views, size=renderer.width, w=[0.2, 0.4], framing={"wild": 1.0},
                            flash=1.0, flash_corner=[0.3, 0.3], flash_room=[1.0, 1.0], shading="phong",
                            wrap=[0.0, 0.0],
                            specular=[0.0, 0.0], flash_specular=[0.0, 0.0], material_specular=[0.0, 0.0],
                            light_kelvin=[2700.0, 3500.0], flash_kelvin=[5500.0, 6000.0], light_mixed=0.5)
    seen = 0
    for seed in range(10):
        try:
            scene = V.sample_scene(body, [], np.random.default_rng(seed), v, renderer)
        except V.ViewRejected:
            continue
        assert set(scene.kelvin) == {"light", "ambient", "flash"}
        out = renderer.render(mesh, scene.camera, passes=("gbuffer", "rgb"), lights=scene.lights,
                              material=scene.material)
        rgb = out["rgb"]
        h, w = rgb.shape[:2]
        centre = rgb[h // 2 - 1:h // 2 + 1, w // 2 - 1:w // 2 + 1].mean((0, 1))
        assert np.ptp(centre) <= 2 / 255, centre * 255
        for y, x in ((0, 0), (0, w - 1), (h - 1, 0), (h - 1, w - 1)):
            if out["face_id"][y, x] >= 0:   # the plane, not past its edge
                assert rgb[y, x, 0] > 1.05 * rgb[y, x, 2], rgb[y, x] * 255
                seen += 1
    assert seen >= 12


def test_paper_light_placement(renderer):
    """The original's light: the camera position moved by up to 2 units along each axis,
    away from the surface point; at the camera when the body blocks it. A roof over the
    floor blocks lights more than 0.5 above the camera."""
    rng0 = np.random.default_rng(0)
    floor = plane(rng0, size=1.0)
    roof = plane(rng0, size=1.0)
    w = 0.4
    roof_v = roof.vertices + (0, 0, w + 0.5)
    mesh = gs.Mesh(np.r_[floor.vertices, roof_v], np.r_[floor.faces, roof.faces + 4],
                   uvs=np.r_[floor.uvs, roof.uvs], texture=floor.texture, name="floor+roof")
    body = SimpleNamespace(mesh=mesh)
    v = dataclasses.replace(load_config(config_dir() / "paper.yaml").views, size=64, w=[w, w])
    at_camera = moved = 0
    for seed in range(24):
        # a surface point on the floor under the roof, normal +Z
        rng = np.random.default_rng(seed)
        while True:
            scene = V.sample_scene(body, [], rng, v, renderer)
            if scene.point[2] < 1e-9:
                break
        eye, light = np.asarray(scene.camera.eye), np.asarray(scene.light.position)
        offset = (light - eye) * np.sign(eye - scene.point)
        if np.allclose(light, eye):
            at_camera += 1
            continue
        moved += 1
        assert (offset >= -1e-12).all() and (offset <= 2 + 1e-12).all()
        # light - eye is along +-x, +-y only where the camera is off the point in x, y
        assert np.allclose((light - eye)[:2], 0) and light[2] < w + 0.5
    assert at_camera and moved


def test_room_light_placement(renderer):
    """The default room light sits light_distance from the viewed point, light_angle off
    the camera's direction about it, above the point (+Y) more often than below; a light
    the body blocks rejects the scene. When the flash fires the room light is dimmed by a
    flash_room draw, never brightened, and the flash's beam, along the lens axis, lights
    the frame's corners with a flash_corner draw of what it gives the middle."""
    rng0 = np.random.default_rng(1)
    mesh = plane(rng0, size=1.0)
    body = SimpleNamespace(mesh=mesh)
    v = dataclasses.replace(load_config().views, size=64, w=[0.3, 0.6], framing={"wild": 1.0},
                            light_angle=[10.0, 60.0], light_distance=[0.5, 2.0],
                            flash=0.5, flash_room=[0.3, 0.6], flash_corner=[0.4, 0.7])
    above = below = blocked = flashed = 0
    for seed in range(60):
        rng = np.random.default_rng(seed)
        try:
            scene = V.sample_scene(body, [], rng, v, renderer)
        except V.ViewRejected as e:
            blocked += e.reason is V.Rejection.LIGHT_BLOCKED
            continue
        point, eye = scene.point, np.asarray(scene.camera.eye)
        to_light = np.asarray(scene.light.position) - point
        r = np.linalg.norm(to_light)
        assert 0.5 - 1e-9 <= r <= 2.0 + 1e-9
        cos = to_light @ (eye - point) / (r * np.linalg.norm(eye - point))
        assert np.cos(np.radians(60.0)) - 1e-9 <= cos <= np.cos(np.radians(10.0)) + 1e-9
        # with fall-off the light is as drawn at the point: its distance is the point's
        assert scene.light.falloff_distance == pytest.approx(r)
        above += to_light[1] > 0
        below += to_light[1] < 0
        if scene.flash is not None:
            flashed += 1
            assert scene.light.diffuse[0] <= 0.6 * v.diffuse[1] + 1e-12
            cam = scene.camera
            _, rays = cam.pixel_rays([cam.height // 2 - 0.5, -0.5], [cam.width // 2 - 0.5, -0.5])
            centre, corner = beam_gain(torch.tensor(-rays), scene.flash).ravel().tolist()
            assert centre == pytest.approx(1.0)
            assert 0.4 - 1e-6 <= corner <= 0.7 + 1e-6
    assert above > 2 * below and flashed
    # the plane (normal +Z) blocks nothing in front of it: a light drawn behind it would be
    assert blocked == 0
