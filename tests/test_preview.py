"""glsynth preview: a GLFW window under an Xvfb server that the tests start themselves.

The window side runs in subprocesses (the CLI, or a small driver script using
``glsynth.preview.Viewer``): Mesa's GLX (window) and EGL (the references here) do not mix
well in one process. References are rendered offscreen in this process with the
ordinary ``Renderer`` (with the view settings of ``glsynth generate``'s embedded default
config) and compared with what the window's default framebuffer holds; a dataset sample
written by ``glsynth generate`` is compared with the preview of its record.
"""
import argparse
import json
import os
import random
import shutil
import subprocess
import sys
import time

import numpy as np
import pytest

from glsynth import dataformat as fmt
from glsynth import preview as P
from glsynth.camera import Camera
from glsynth.config import load_config
from glsynth.lighting import Material, PointLight

from gl_context import get_renderer

W, H = 320, 240
TEX = 512
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# what generate renders views with by default, and so what the previewer shows
VIEWS = load_config(None).views


# ---- fixtures ----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def xdisplay():
    """DISPLAY of a private Xvfb server (killed after the module's tests)."""
    exe = shutil.which("Xvfb")
    if exe is None:
        pytest.skip("Xvfb not found on PATH (Debian package 'xvfb'): preview tests need an X server")
    start = random.randint(100, 400)
    for n in list(range(start, 500)) + list(range(100, start)):
        if not (os.path.exists(f"/tmp/.X{n}-lock") or os.path.exists(f"/tmp/.X11-unix/X{n}")):
            break
    else:
        pytest.skip("no free X display number in :100..:499")
    proc = subprocess.Popen([exe, f":{n}", "-screen", "0", "1280x1024x24", "-nolisten", "tcp"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.time() + 20
    while not os.path.exists(f"/tmp/.X11-unix/X{n}"):
        if proc.poll() is not None or time.time() > deadline:
            err = proc.stderr.read().decode(errors="replace") if proc.poll() is not None else ""
            proc.kill()
            pytest.skip(f"Xvfb :{n} did not start: {err[-500:]}")
        time.sleep(0.05)
    try:
        yield f":{n}"
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _env(display):
    env = dict(os.environ, DISPLAY=display)
    env.pop("WAYLAND_DISPLAY", None)
    env["PYTHONPATH"] = ROOT + os.pathsep + env.get("PYTHONPATH", "")
    return env


def run_cli(display, *args, check=True):
    proc = subprocess.run([sys.executable, "-m", "glsynth.cli", "preview", *map(str, args)],
                          env=_env(display) if display else _no_display_env(), cwd=ROOT,
                          capture_output=True, text=True, timeout=400)
    if check and proc.returncode != 0:
        raise AssertionError(f"glsynth preview failed ({proc.returncode}):\n{proc.stdout}\n{proc.stderr}")
    return proc


def _no_display_env():
    env = dict(os.environ)
    env.pop("DISPLAY", None)
    env.pop("WAYLAND_DISPLAY", None)
    env["PYTHONPATH"] = ROOT + os.pathsep + env.get("PYTHONPATH", "")
    return env


@pytest.fixture(scope="module")
def body():
    from glsynth.assets import make_body
    return make_body(seed=0, texture_size=TEX)


def chest(body):
    """A front chest surface point and its normal (built-in bodies face +Z)."""
    v, n = body.mesh.vertices, body.mesh.vertex_normals
    ys = v[:, 1]
    band = (np.abs(v[:, 0]) < 0.08) & (ys > ys.min() + 0.70 * np.ptp(ys)) & (ys < ys.min() + 0.78 * np.ptp(ys))
    i = np.flatnonzero(band)[np.argmax(v[band, 2])]
    return v[i], n[i]


def chest_camera(body, w=0.6):
    p, n = chest(body)
    return Camera.from_surface(p, n, w, width=W, height=H)


def instance_map():
    """Texture-space lesion ids: 8x8 blocks of 64 texels, ids 1..64, some left empty."""
    r, c = np.mgrid[0:TEX, 0:TEX] // (TEX // 8)
    ids = (r * 8 + c + 1).astype(np.uint16)
    ids[(r + c) % 3 == 0] = 0
    return ids


def reference(body, cam, lights=None, material=None, mesh=None):
    """Offscreen render (EGL or OSMesa, this process) as generate renders a view, with
    the previewer's start light (the paper's, at the camera) and material."""
    r = get_renderer(os.environ.get("GLSYNTH_GL_BACKEND", "egl"), W, H)
    lights = lights or [PointLight(cam.eye, ambient=0.5, diffuse=0.5, specular=0.025)]
    material = material or Material(specular=0.025, shininess=50, model=VIEWS.shading,
                                    detail=VIEWS.detail)
    mesh = mesh or body.mesh
    if VIEWS.occlusion:  # the body's ambient occlusion, as generate and the previewer shade it
        from glsynth.gl.occlusion import cached_occlusion
        mesh = mesh.copy_with(occlusion=cached_occlusion(r, mesh))
    out = r.render(mesh, cam, passes=("rgb",), lights=lights, material=material,
                   supersample=VIEWS.supersample, multisample=VIEWS.multisample,
                   shadows=VIEWS.shadows, buffers=("rgba8",))
    return out["rgba8"][..., :3] / 255


def read_png(path):
    from glsynth.io.images import read_rgb
    return read_rgb(path).astype(np.float64) / 255


# ---- driver: the Viewer API in a subprocess --------------------------------------------------
DRIVER = r"""
import json, sys
import numpy as np
from glsynth import preview as P
from glsynth.assets import make_body
from glsynth.camera import Camera
cfg = json.loads(sys.argv[1])
body = make_body(seed=0, texture_size=cfg["tex"])
inst = np.load(cfg["instances"])
scene = P.PreviewScene(body, body.mesh, inst, cfg["placements"], "seed0")
v = P.Viewer(scene, cfg["w"], cfg["h"], camera=Camera.from_dict(cfg["camera"]), save_dir=cfg["save"])
out = {}
for name in P.BUFFERS:
    v.set_buffer(name)
    v.draw()
    out[name] = v.read_screen()
    v.glfw.swap_buffers(v.window)
    v.glfw.poll_events()
picks = [v.pick(x, y) for x, y in cfg["picks"]]
# mouse: a click (press + release without moving) picks the pixel under the cursor;
# a left drag orbits about the target, keeping the distance
glfw, win = v.glfw, v.window
glfw.set_cursor_pos(win, 100, 80)
glfw.poll_events()
cx, cy = glfw.get_cursor_pos(win)
c = v.controls
c.on_mouse_button(win, glfw.MOUSE_BUTTON_LEFT, glfw.PRESS, 0)
c.on_mouse_button(win, glfw.MOUSE_BUTTON_LEFT, glfw.RELEASE, 0)
before = v.camera
c.on_mouse_button(win, glfw.MOUSE_BUTTON_LEFT, glfw.PRESS, 0)
c.on_cursor(win, cx + 40, cy + 10)
c.on_mouse_button(win, glfw.MOUSE_BUTTON_LEFT, glfw.RELEASE, 0)
dragged = v.camera
c.on_scroll(win, 0, 2)
mouse = {"cursor": [cx, cy], "before": before.to_dict(), "dragged": dragged.to_dict(),
         "scrolled": v.camera.to_dict()}
v.set_camera(before)
v.set_buffer("rgb")
v.press("n")
v.draw()
out["lesion_jump"] = v.read_screen()
v.press("p")
np.savez(cfg["out"], **out)
json.dump({"picks": picks, "size": list(v.size), "jump_camera": v.camera.to_dict(),
           "mouse": mouse}, open(cfg["out"] + ".json", "w"))
v.close()
"""


@pytest.fixture(scope="module")
def driven(xdisplay, body, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("preview")
    np.save(tmp / "inst.npy", instance_map())
    cam = chest_camera(body, w=0.9)
    p, n = chest(body)
    lesion_cam = Camera.from_surface(p + np.array([0.05, 0.0, 0.0]), n, 0.4)
    cfg = {"tex": TEX, "w": W, "h": H, "instances": str(tmp / "inst.npy"), "camera": cam.to_dict(),
           "placements": [{"instance": 7, "lesion_id": "test", "camera": lesion_cam.to_dict()}],
           "picks": [[W // 2, H // 2], [5, 5], [W // 2 + 40, H // 2 + 30], [W // 3, 2 * H // 3]],
           "save": str(tmp / "save"), "out": str(tmp / "screens.npz")}
    script = tmp / "driver.py"
    script.write_text(DRIVER)
    proc = subprocess.run([sys.executable, str(script), json.dumps(cfg)], env=_env(xdisplay),
                          cwd=ROOT, capture_output=True, text=True, timeout=400)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    screens = dict(np.load(cfg["out"]))
    with open(cfg["out"] + ".json") as fh:
        info = json.load(fh)
    return {"screens": screens, "info": info, "camera": cam, "lesion_cam": lesion_cam, "cfg": cfg,
            "stdout": proc.stdout}


def offscreen_labels(body, cam):
    """Independent label truth for ``cam``: G-buffer + label textures, combined here."""
    from glsynth.gl.renderer import vertex_label_image
    r = get_renderer(os.environ.get("GLSYNTH_GL_BACKEND", "egl"), W, H)
    maps = {"instances": instance_map(), "nonskin": body.nonskin}
    if getattr(body, "anatomy_map", None) is not None:  # built-in bodies: per-texel anatomy
        maps["anatomy"] = body.anatomy_map
    out = r.render(body.mesh, cam, passes=("gbuffer", "labels"), label_textures=maps)
    fg = out["face_id"] >= 0
    lesion = fg & (out["instances"] > 0)
    nonskin = fg & (out["nonskin"] > 0) & ~lesion
    semantic = np.where(fg, 1, 0).astype(np.uint8)
    semantic[nonskin], semantic[lesion] = 3, 2
    return {"face_id": out["face_id"], "depth": out["depth"], "semantic": semantic,
            "instances": np.where(lesion, out["instances"], 0), "uv": out["uv"],
            "anatomy": out["anatomy"] if "anatomy" in maps else vertex_label_image(out, body.mesh, body.anatomy)}


def invert(screen, palette):
    """Label image from a false-colour screen (-1 where a colour is not in the palette)."""
    key = lambda a: (a[..., 0].astype(np.int64) << 16) | (a[..., 1].astype(np.int64) << 8) | a[..., 2]
    pal = key(np.asarray(palette))
    assert len(np.unique(pal)) == len(pal), "palette colours must be distinct"
    lut = dict(zip(pal.tolist(), range(len(pal))))
    k = key(screen)
    return np.vectorize(lambda x: lut.get(x, -1))(k)


# ---- tests ---------------------------------------------------------------------------------------
def test_screenshot_equals_offscreen_render(xdisplay, body, tmp_path):
    cam = chest_camera(body)
    shot = tmp_path / "shot.png"
    run_cli(xdisplay, "--body", 0, "--texture-size", TEX, "--size", f"{W}x{H}",
            "--camera", json.dumps(cam.to_dict()), "--screenshot", shot, "--frames", 2)
    img = read_png(shot)
    ref = reference(body, cam)
    assert img.shape == ref.shape == (H, W, 3)
    assert (ref.sum(-1) > 0).mean() > 0.5, "the view should be mostly body"
    assert np.abs(img - ref).max() <= 2 / 255 + 1e-9


def test_printed_snippet_reproduces_the_view(xdisplay, body, tmp_path):
    cam = chest_camera(body, w=1.5)
    cam_file = tmp_path / "cam.json"
    cam_file.write_text(json.dumps(cam.to_dict()))
    shot = tmp_path / "shot.png"
    # orbit, zoom, move the light, change ambient and shininess, then print the snippet
    proc = run_cli(xdisplay, "--body", 0, "--texture-size", TEX, "--size", f"{W}x{H}",
                   "--camera", cam_file, "--keys", "left,up,+,shift+right,shift+up,a,shift+d,g,m,c",
                   "--screenshot", shot, "--frames", 1)
    out = proc.stdout
    snippet = json.loads(out[out.index("{"):out.rindex("}") + 1])
    assert set(snippet) >= {"camera", "light", "material"}
    new_cam = Camera.from_dict(snippet["camera"])
    assert not np.allclose(new_cam.eye, cam.eye), "the orbit keys should have moved the camera"
    light = PointLight(**snippet["light"])
    assert not np.allclose(light.position, new_cam.eye), "shift+arrows should move the light"
    assert light.ambient[0] == pytest.approx(0.55) and light.diffuse[0] == pytest.approx(0.45)
    material = Material(**snippet["material"])
    assert material.shininess == pytest.approx(62.5)
    ref = reference(body, new_cam, [light], material)
    assert np.abs(read_png(shot) - ref).max() <= 2 / 255 + 1e-9
    # the snippet is also accepted back by --camera
    view = P.parse_view(json.dumps(snippet))
    assert view.camera.eye == new_cam.eye and view.lights[0].to_dict() == snippet["light"]
    assert view.material == material


def test_rgb_buffer_and_lesion_jump(driven, body):
    s = driven["screens"]
    ref = reference(body, driven["camera"])
    assert np.abs(s["rgb"] / 255 - ref).max() <= 2 / 255 + 1e-9
    jump = Camera.from_surface(driven["lesion_cam"].surface["point"], driven["lesion_cam"].surface["normal"],
                               driven["lesion_cam"].surface["w"], width=W, height=H)
    assert driven["info"]["jump_camera"]["eye"] == pytest.approx(list(jump.eye))
    # the window shows the placement texture... here the body texture: compare RGB
    assert np.abs(s["lesion_jump"] / 255 - reference(body, jump)).max() <= 2 / 255 + 1e-9


def test_label_buffers_match_offscreen_labels(driven, body):
    s = driven["screens"]
    truth = offscreen_labels(body, driven["camera"])
    fg = truth["face_id"] >= 0
    assert 0.3 < fg.mean() and (truth["semantic"] == 2).any() and (truth["semantic"] == 1).any()
    np.testing.assert_array_equal(invert(s["semantic"], fmt.SEMANTIC_PALETTE), truth["semantic"])
    np.testing.assert_array_equal(invert(s["anatomy"], fmt.ANATOMY_PALETTE), truth["anatomy"])
    np.testing.assert_array_equal(invert(s["anatomy_groups"], fmt.GROUP_PALETTE),
                                  fmt.PART_GROUPS[truth["anatomy"]])
    ids = np.arange(65)
    np.testing.assert_array_equal(invert(s["instances"], fmt.id_colours(ids)), truth["instances"])
    assert len(np.unique(truth["instances"])) > 3
    np.testing.assert_array_equal(s["face_id"], fmt.id_colours(truth["face_id"].astype(np.int64) + 1))
    # depth: black exactly off the body, brighter nearer
    np.testing.assert_array_equal(s["depth"].any(-1), truth["depth"] > 0)
    d, g = truth["depth"][fg], s["depth"][..., 0][fg].astype(float)
    assert np.corrcoef(d, g)[0, 1] < -0.99
    # uv: red = u, green = v on the body
    assert np.abs(s["uv"][..., 0][fg] / 255 - truth["uv"][..., 0][fg]).max() <= 1 / 255 + 1e-6
    assert np.abs(s["uv"][..., 1][fg] / 255 - truth["uv"][..., 1][fg]).max() <= 1 / 255 + 1e-6
    assert not s["uv"][~fg].any()


def test_click_reports_labels_and_depth(driven, body):
    truth = offscreen_labels(body, driven["camera"])
    picks = driven["info"]["picks"]
    assert any(p["semantic"] == 0 for p in picks) and any(p["semantic"] > 0 for p in picks)
    for p in picks:
        y, x = p["y"], p["x"]
        assert p["anatomy"] == truth["anatomy"][y, x]
        assert p["lesion"] == truth["instances"][y, x]
        assert p["semantic"] == truth["semantic"][y, x]
        assert p["depth"] == pytest.approx(float(truth["depth"][y, x]), rel=1e-5, abs=1e-6)
        assert f"pixel ({x}, {y}): anatomy {p['anatomy']}" in driven["stdout"]


def test_mouse_click_orbit_and_zoom(driven):
    m = driven["info"]["mouse"]
    x, y = (int(c) for c in m["cursor"])
    assert f"pixel ({x}, {y}):" in driven["stdout"], "a click prints the pixel under the cursor"
    dist = lambda c: np.linalg.norm(np.subtract(c["eye"], c["target"]))
    assert m["dragged"]["target"] == pytest.approx(m["before"]["target"])
    assert dist(m["dragged"]) == pytest.approx(dist(m["before"]))
    assert not np.allclose(m["dragged"]["eye"], m["before"]["eye"])
    assert dist(m["scrolled"]) == pytest.approx(dist(m["dragged"]) * 0.81)


def test_save_key_writes_screenshot_and_targets(driven):
    save = driven["cfg"]["save"]
    sid = "seed0_preview0001"
    for rel in (f"images/{sid}.png", f"targets/{sid}_semantic.png", f"targets/{sid}_instances.png",
                f"targets/{sid}_anatomy.png", f"targets/{sid}_depth.tiff", f"targets/{sid}.json",
                f"screens/{sid}_rgb.png"):
        assert os.path.isfile(os.path.join(save, rel)), rel
    with open(os.path.join(save, "targets", f"{sid}.json")) as fh:
        meta = json.load(fh)
    assert meta["camera"]["eye"] == pytest.approx(driven["info"]["jump_camera"]["eye"])
    assert meta["lesions"] and all(l["instance"] > 0 for l in meta["lesions"])


def test_blended_run_folder_and_lesion_jump(xdisplay, tmp_path):
    """--blended DIR --body-id: the run's body with its pasted texture; N jumps to the
    placement's surface camera."""
    from glsynth.config import load_config
    from glsynth.io.images import write_png
    from glsynth.pipeline.bodies import load_body
    cfg = load_config(None, ["bodies.count=1", f"bodies.texture_size={TEX}"])
    run = tmp_path / "run"
    bdir = run / "bodies" / "body000"
    bdir.mkdir(parents=True)
    (run / "manifest.json").write_text(json.dumps({"config": cfg.to_dict()}))
    body = load_body(cfg, "body000")
    inst = instance_map()
    tex = body.mesh.texture.copy()
    tex[inst == 5] = (200, 20, 20)
    write_png(bdir / "pasted.png", tex)
    write_png(bdir / "instances.png", inst)
    p, n = chest(body)
    cam = Camera.from_surface(p, n, 0.5)
    (bdir / "placements.json").write_text(json.dumps(
        [{"instance": 5, "lesion_id": "red", "camera": cam.to_dict()}]))
    shot = tmp_path / "shot.png"
    proc = run_cli(xdisplay, "--blended", run, "--body-id", "body000", "--size", f"{W}x{H}",
                   "--keys", "n", "--screenshot", shot, "--frames", 1)
    assert "lesion 5 (red)" in proc.stdout
    ref = reference(body, Camera.from_surface(p, n, 0.5, width=W, height=H),
                    mesh=body.mesh.copy_with(texture=tex))
    assert np.abs(read_png(shot) - ref).max() <= 2 / 255 + 1e-9
    with pytest.raises(FileNotFoundError, match="body999"):
        P.load_scene(argparse.Namespace(body=None, bodytex=None, mesh=None, blended=str(run),
                                        body_id="body999", texture_size=TEX))


def test_a_samples_record_reproduces_its_rendering(xdisplay, tmp_path):
    """--blended RUN --camera RUN/targets/<id>.json shows what generate rendered for that
    sample: its camera, room light (tinted ambient), flash and skin material, with the
    config's shading, multisampling and shadows. With the camera model off, the dataset
    image equals the screenshot wherever the body covers the whole pixel (elsewhere the
    background shows through, which the previewer leaves out)."""
    import cv2
    from glsynth.pipeline import generate
    run = tmp_path / "run"
    generate(load_config(None, ["bodies.count=1", f"bodies.texture_size={TEX}", "lesions.per_body=1",
                                "lesions.kinds=[nevus]", "views.per_body=1", "views.size=160", "views.flash=1.0",
                                "views.closeup_flash=1.0", "photo.enabled=false",
                                "backgrounds.count=1", "seed=5"]), run)
    folder = fmt.RunFolder(run)
    sid = folder.sample_ids()[0]
    record = folder.record(sid)
    assert len(record["lights"]) == 2 and record["material"]["model"] == VIEWS.shading == "skin"
    assert VIEWS.multisample > 1 and VIEWS.shadows
    shot = tmp_path / "shot.png"
    run_cli(xdisplay, "--blended", run, "--camera", fmt.record_path(run, sid), "--screenshot", shot,
            "--frames", 1)
    img, ref = read_png(shot), folder.image(sid) / 255
    assert img.shape == ref.shape == (160, 160, 3)
    covered = cv2.erode((folder.layer(sid, "semantic") > 0).astype(np.uint8), np.ones((5, 5))) > 0
    assert covered.mean() > 0.1
    assert np.abs(img - ref)[covered].max() <= 2 / 255 + 1e-9


def test_no_display_gives_a_clear_error(tmp_path):
    proc = run_cli(None, "--body", 0, "--screenshot", tmp_path / "x.png", check=False)
    assert proc.returncode == 2
    assert "needs a display" in proc.stderr and "xvfb-run -a glsynth preview" in proc.stderr
    assert "glsynth generate" in proc.stderr


# ---- no window needed ------------------------------------------------------------------------------
def test_parse_view_and_errors(tmp_path):
    cam = Camera.from_surface((0, 1, 0), (0, 0, 1), 0.5, width=64, height=64)
    view = P.parse_view(json.dumps(cam.to_dict()))
    assert view.camera == cam and view.lights is None and view.material is None and view.size is None
    f = tmp_path / "c.yaml"
    f.write_text("eye: [0, 1, 2]\ntarget: [0, 1, 0]\n")
    assert P.parse_view(str(f)).camera.eye == (0.0, 1.0, 2.0)
    with pytest.raises(ValueError, match="eye"):
        P.parse_view('{"fov_deg": 30}')
    with pytest.raises(ValueError, match="JSON or YAML"):
        P.parse_view("{not json: [")


def test_colourise_palettes():
    ids = fmt.id_colours(np.arange(1, 200))
    assert len({tuple(c) for c in ids}) == 199 and not fmt.id_colours(np.array([0, -1])).any()
    layers = {"semantic": np.array([[0, 1, 2, 3]], np.uint8)}
    np.testing.assert_array_equal(P.colourise("semantic", layers)[0], fmt.SEMANTIC_PALETTE)
    with pytest.raises(ValueError, match="unknown buffer"):
        P.colourise("normals", layers)


def test_bad_arguments():
    ns = argparse.Namespace(body=1, bodytex="x", mesh=None, blended=None, body_id=None, texture_size=64)
    with pytest.raises(ValueError, match="choose one of"):
        P.load_scene(ns)
    ns = argparse.Namespace(body=None, bodytex=None, mesh=None, blended="/nonexistent", body_id=None,
                            texture_size=64)
    with pytest.raises(FileNotFoundError, match="manifest.json"):
        P.load_scene(ns)
