"""End-to-end pipeline: labels consistent on every sample, paste round trip, blending
behaviour, determinism, resume, COCO, config errors."""
import dataclasses
import json
import os
import signal
import subprocess
import sys
import time

import cv2
import numpy as np
import pytest
import torch

import glsynth as gs
from glsynth.config import ConfigError, load_config
from glsynth.io.images import read_image, read_rgb
from runs import SMALL, assert_same_folders, dataset_bytes, small_config
from shapes import plane


def image_lesion_folder(root, n=3, seed=0):
    """Lesion photographs with masks in the pairs layout (``X.png`` + ``X_segmentation.png``),
    here pictures of procedural conditions, so that the image path (paste, then blend)
    runs end to end."""
    from glsynth.io.images import write_png
    root.mkdir(parents=True, exist_ok=True)
    for i, les in enumerate(gs.assets.procedural_lesions(n, seed=seed, size=96,
                                                         kinds=["nevus", "psoriasis", "ulcer"])):
        write_png(root / f"lesion{i}.png", les.image)
        write_png(root / f"lesion{i}_segmentation.png", les.mask.astype(np.uint8) * 255)
    return root


@pytest.fixture(scope="module")
def dataset_args(tmp_path_factory):
    """SMALL with lesion photographs: the dataset below exercises paste + deep blend, and
    gloves, clothing or drapes at the edge of every close-up and regional view."""
    lesions = image_lesion_folder(tmp_path_factory.mktemp("lesions"))
    return SMALL + [f"lesions.source={lesions}", "lesions.layout=pairs", "backgrounds.edges=1"]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory, dataset_args):
    out = tmp_path_factory.mktemp("ds")
    gs.pipeline.generate(load_config(None, dataset_args), out)
    return out


def _samples(out):
    tgt = os.path.join(out, "targets")
    return sorted(f[:-5] for f in os.listdir(tgt) if f.endswith(".json"))


def test_every_sample_is_consistent(dataset):
    ids = _samples(dataset)
    assert len(ids) == 4
    seen_lesion, edges = False, []
    for sid in ids:
        meta = json.load(open(os.path.join(dataset, "targets", f"{sid}.json")))
        img = read_rgb(os.path.join(dataset, "images", f"{sid}.png"))
        sem = read_image(os.path.join(dataset, "targets", f"{sid}_semantic.png"))
        inst = read_image(os.path.join(dataset, "targets", f"{sid}_instances.png"))
        ana = read_image(os.path.join(dataset, "targets", f"{sid}_anatomy.png"))
        import tifffile
        depth = tifffile.imread(os.path.join(dataset, "targets", f"{sid}_depth.tiff"))
        assert img.shape == (128, 128, 3) and sem.dtype == np.uint8 and inst.dtype == np.uint16
        assert depth.dtype == np.float32 and np.isfinite(depth).all()
        assert set(np.unique(sem)) <= {0, 1, 2, 3}
        lesion = sem == 2
        seen_lesion |= bool(lesion.any())
        assert (inst[lesion] > 0).all() and (inst[~lesion] == 0).all()
        assert (ana[lesion] > 0).all() and (ana[sem > 0] > 0).all() and (ana[sem == 0] == 0).all()
        assert (depth[sem > 0] > 0).all()
        seen = depth != -1     # the body, and a frame-edge occluder at the focus distance
        if meta["background"]["edge"] is None:
            assert (seen == (sem > 0)).all()
        else:
            focus = np.linalg.norm(np.subtract(meta["camera"]["target"], meta["camera"]["eye"]))
            assert np.allclose(depth[seen & (sem == 0)], focus, rtol=1e-6)
        # the paper's 3-class target is a partition of the image
        from glsynth.dataformat import three_class
        three = three_class(sem)
        assert set(np.unique(three)) <= {0, 1, 2} and three.size == sem.size
        for l in meta["lesions"]:
            ys, xs = np.nonzero(inst == l["instance"])
            assert l["box"] == [xs.min(), ys.min(), xs.max() + 1, ys.max() + 1]
            assert l["area"] == len(xs)
            if "preset" in l["source"]:   # a procedural condition, drawn on this body's skin
                assert l["source"]["fitzpatrick"] == meta["body"]["fitzpatrick"]
                assert l["source"]["reference_fitzpatrick"] in range(1, 7)
            # where on the body it was placed (built-in bodies have part labels)
            from glsynth.dataformat import GROUP_NAMES
            assert l["source"]["body_region"] in set(GROUP_NAMES.values()) - {"background"}
        assert (meta["fractions"]["skin"]) >= 0.1
        edges.append(meta["background"]["edge"])
        if edges[-1] is not None:   # its pixels are background in every label (checked above)
            assert meta["camera"]["framing"] != "wild" and edges[-1]["kind"] in ("glove", "clothing", "drape", "hair")
        for key in ("eye", "target", "up", "fov_deg", "w", "point", "normal", "intrinsics"):
            assert key in meta["camera"]
    assert seen_lesion, "no lesion visible in any view"
    assert any(e is not None for e in edges), edges


def test_coco_loads_with_pycocotools(dataset):
    coco_mod = pytest.importorskip("pycocotools.coco")
    from pycocotools import mask as mask_utils
    coco = coco_mod.COCO(os.path.join(dataset, "annotations.coco.json"))
    assert len(coco.getImgIds()) == 4
    for ann in coco.loadAnns(coco.getAnnIds()):
        img = coco.loadImgs(ann["image_id"])[0]
        m = coco.annToMask(ann)
        sid = img["glsynth_id"]
        inst = read_image(os.path.join(dataset, "targets", f"{sid}_instances.png"))
        assert (m.astype(bool) == (inst == ann["glsynth_instance"])).all()
        assert ann["area"] == int(m.sum())
        x, y, w, h = ann["bbox"]
        assert mask_utils.toBbox(mask_utils.encode(np.asfortranarray(m))).tolist() == [x, y, w, h]


def test_manifest_and_params(dataset):
    man = json.load(open(os.path.join(dataset, "manifest.json")))
    assert man["seed"] == 7 and man["counts"]["images"] == 4
    assert "llvmpipe" in man["gl_renderer"] or man["gl_renderer"]
    assert man["blend_features"].startswith("filters")
    for k in ("paste", "blend", "views", "total"):
        assert k in man["timings_seconds"]
    rows = open(os.path.join(dataset, "params.csv")).read().strip().splitlines()
    assert len(rows) == 5 and rows[0].startswith("id,")


def test_every_file_has_the_mode_the_umask_asks_for(dataset):
    """Not mkstemp's 0600: on shared storage the group must be able to read a dataset."""
    umask = os.umask(0)
    os.umask(umask)
    modes = {os.path.relpath(os.path.join(r, n), dataset): os.stat(os.path.join(r, n)).st_mode & 0o777
             for r, _, ns in os.walk(dataset) for n in ns}
    assert len(modes) > 20
    assert {k: oct(m) for k, m in modes.items() if m != 0o666 & ~umask} == {}


def test_torch_dataset_and_show(dataset, tmp_path):
    from glsynth.dataset import SynthDataset
    ds = SynthDataset(dataset, targets=("three_class", "anatomy_groups", "depth", "boxes"))
    item = ds[0]
    assert item["image"].shape == (3, 128, 128) and item["image"].dtype == torch.float32
    assert item["three_class"].max() <= 2 and item["anatomy_groups"].max() <= 7
    from glsynth.show import contact_sheet
    path = contact_sheet(dataset, tmp_path / "sheet.png", n=3)
    sheet = read_rgb(path)
    assert sheet.shape[0] == 5 * 256 and sheet.shape[1] == 3 * 256


def test_same_seed_same_bytes(dataset, dataset_args, tmp_path, monkeypatch):
    # the second run makes every background on the render thread (no prefetching)
    from glsynth.pipeline.stages import Generate2DViews
    monkeypatch.setattr(Generate2DViews, "prefetch_views", 0)
    gs.pipeline.generate(load_config(None, dataset_args), tmp_path / "again")
    assert_same_folders(dataset, tmp_path / "again")
    assert any(k.startswith("bodies/") and k.endswith("blend.json") for k in dataset_bytes(dataset))


def test_resume_after_kill(dataset, dataset_args, tmp_path):
    out = tmp_path / "killed"
    args = [sys.executable, "-m", "glsynth.cli", "generate", "--out", str(out)]
    for s in dataset_args:
        args += ["--set", s]
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.time() + 600
    # kill as the first sample's image is being written: the views render ~60 ms apart,
    # so the run is mid-way (waiting for a finished JSON let all 4 views finish first)
    while time.time() < deadline and proc.poll() is None:
        images = out / "images"
        if images.is_dir() and os.listdir(images):
            proc.send_signal(signal.SIGKILL)
            break
        time.sleep(0.005)
    proc.wait()
    done = _samples(out) if (out / "targets").is_dir() else []
    assert len(done) < 4, "run finished before it could be killed"
    # nothing half-written under a final name: every image decodes, every JSON parses
    # (temporaries of writes the kill interrupted may stay; resume removes them)
    for root, _, names in os.walk(out):
        for n in names:
            if n.startswith(".tmp-"):
                continue
            path = os.path.join(root, n)
            if n.endswith(".png"):
                assert read_image(path) is not None
            elif n.endswith(".json"):
                json.load(open(path))
    with pytest.raises(FileExistsError):
        gs.pipeline.generate(load_config(None, dataset_args), out)
    gs.pipeline.generate(load_config(None, dataset_args), out, resume=True)
    assert _samples(out) == _samples(dataset)
    assert not [n for r, _, ns in os.walk(out) for n in ns if n.startswith(".tmp-")]
    assert_same_folders(dataset, out, resumed=True)


@pytest.mark.parametrize("override,key", [
    ("blend.method=magic", "blend.method"), ("views.size=8", "views.size"),
    ("views.w=[1.0]", "views.w"), ("bodies.count=0", "bodies.count"),
    ("nonsense.key=1", "nonsense"), ("views.min_skin=2", "views.min_skin"),
    ("blend.style=-1", "blend.style"), ("outputs=[rgb, sparkles]", "outputs"),
])
def test_bad_config_names_the_key(override, key):
    with pytest.raises(ConfigError, match=key):
        small_config(override)


def test_cli_reports_config_errors(tmp_path, capsys):
    from glsynth.cli import main
    assert main(["generate", "--out", str(tmp_path), "--set", "views.per_body=-3"]) == 2
    assert "views.per_body" in capsys.readouterr().err


def test_depth_tiff_is_lossless_and_readable_by_opencv(tmp_path, rng):
    import tifffile
    from glsynth.pipeline.writer import write_depth
    depth = rng.uniform(0.05, 40.0, size=(61, 77)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.4] = -1.0
    depth[0, 0], depth[0, 1] = np.finfo(np.float32).tiny, np.float32(1e-30)
    path = tmp_path / "d.tiff"
    write_depth(path, depth)
    np.testing.assert_array_equal(tifffile.imread(path), depth)
    np.testing.assert_array_equal(read_image(path), depth)  # libtiff inside OpenCV



def test_composite_is_the_rounded_premultiplied_over(rng):
    """Body over background in uint8 equals the float formula rounded, on fresh
    random coverage (0 and 255 included) and premultiplied colours."""
    from glsynth.pipeline.views import composite
    for _ in range(10):
        h, w = rng.integers(1, 200, 2)
        alpha = rng.integers(0, 256, (h, w)).astype(np.uint8)
        alpha[rng.random((h, w)) < 0.3] = 0
        alpha[rng.random((h, w)) < 0.3] = 255
        rgb = np.floor(rng.integers(0, 256, (h, w, 3)) * (alpha[..., None] / 255)).astype(np.uint8)
        background = rng.integers(0, 256, (h, w, 3)).astype(np.uint8)
        expected = np.round(rgb + background * ((255 - alpha[..., None]) / 255))
        got = composite(np.dstack([rgb, alpha]), background, 0)
        assert got.dtype == np.uint8 and got.shape == (h, w, 3)
        np.testing.assert_array_equal(got, expected)

def test_expose_scales_light_in_linear_space(rng):
    """expose() is the sRGB transfer function undone, scaled and redone (within one code
    of the float formula, on fresh random pixels and gains); gain 1 is the same image."""
    from glsynth.pipeline.views import expose
    def srgb(x):
        return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.maximum(x, 0) ** (1 / 2.4) - 0.055)
    img = rng.integers(0, 256, (37, 53, 3)).astype(np.uint8)
    assert expose(img, 1.0) is img
    for gain in rng.uniform(0.02, 1.0, 5):
        s = img / 255.0
        lin = np.where(s <= 0.04045, s / 12.92, ((s + 0.055) / 1.055) ** 2.4)
        want = np.clip(np.rint(255 * srgb(lin * gain)), 0, 255)
        got = expose(img, gain)
        assert got.dtype == np.uint8 and np.abs(got - want).max() <= 1


def test_a_flash_dims_a_room_background_but_not_a_drape(tmp_path):
    """The camera exposes for its flash: the room light and a room behind the patient come
    out at the flash_room draw (background pixels of two runs differing only in it
    differ by their ratio in linear light), while a drape against the patient, lit by the
    flash, keeps its brightness; the record says which."""
    from glsynth.assets.backgrounds import NEAR_BACKDROPS
    from glsynth.dataformat import SEMANTIC_BACKGROUND, RunFolder
    from glsynth.pipeline import views as V
    from glsynth.pipeline.views import expose
    runs = {}
    for k in (0.5, 0.1):
        out = tmp_path / f"k{k}"
        gs.Generate2DViews(small_config("views.flash=1", "views.framing={wild: 1}", f"views.flash_room=[{k}, {k}]",
                                        "views.light_kelvin=[0, 0]",
                                        "backgrounds.clinical=0", "backgrounds.blur=[0, 0]", "photo.enabled=false",
                                        "lesions.per_body=0"), out).synthesize_views(progress=False)
        runs[k] = RunFolder(out)
    seen = 0
    for sid in runs[0.5].sample_ids():
        bright, dim = runs[0.5], runs[0.1]
        assert bright.record(sid)["background"]["exposure"] == 0.5 and dim.record(sid)["background"]["exposure"] == 0.1
        bg = cv2.erode((bright.layer(sid, "semantic") == SEMANTIC_BACKGROUND).astype(np.uint8), np.ones((3, 3))) > 0
        if bg.sum() < 50:
            continue
        seen += 1
        # two roundings of uint8 apart: within 2 codes
        assert np.abs(expose(bright.image(sid), 0.2)[bg].astype(int) - dim.image(sid)[bg]).max() <= 2
        assert dim.image(sid)[bg].mean() < 0.6 * bright.image(sid)[bg].mean()
    assert seen >= 2
    scene = V.ViewScene(camera=None, light=None, material=None, centre="surface", room_exposure=0.2)
    assert V.background_exposure(scene, {"kind": "wall"}) == 0.2 and V.background_exposure(scene, {}) == 0.2
    assert all(V.background_exposure(scene, {"kind": k}) == 1.0 for k in NEAR_BACKDROPS)


@pytest.fixture
def renderer_spy(monkeypatch):
    """(made, closed): every Renderer made and every one closed, in order."""
    from glsynth.gl.renderer import Renderer
    made, closed = [], []
    init, close = Renderer.__init__, Renderer.close

    def spy_init(self, *a, **k):
        init(self, *a, **k)
        made.append(self)

    def spy_close(self):
        close(self)
        closed.append(self)

    monkeypatch.setattr(Renderer, "__init__", spy_init)
    monkeypatch.setattr(Renderer, "close", spy_close)
    return made, closed


def test_generate_releases_its_gl_context(tmp_path, monkeypatch, renderer_spy):
    """A process that calls generate repeatedly (API users, benchmarks) must not keep
    every run's GL context: llvmpipe holds ~0.2 GB of textures per body in each. Also
    when the run fails."""
    made, closed = renderer_spy
    gs.pipeline.generate(small_config("blend.method=paste", "views.per_body=1"), tmp_path / "a")
    assert made and closed == made
    from glsynth.pipeline import stages
    monkeypatch.setattr(stages.Generate2DViews, "synthesize_views",
                        lambda self, *a, **k: (_ for _ in ()).throw(RuntimeError("boom")))
    with pytest.raises(RuntimeError, match="boom"):
        gs.pipeline.generate(small_config("blend.method=paste", "views.per_body=1"), tmp_path / "b")
    assert len(made) == 2 and closed == made


def test_stages_release_the_renderer_they_make(tmp_path, renderer_spy):
    """The paper's one-line stage calls leave no GL context behind; a renderer passed
    in stays open for its owner."""
    from glsynth.gl.renderer import Renderer
    made, closed = renderer_spy
    cfg = small_config("blend.method=poisson", "views.per_body=1", "bodies.count=1")
    gs.SelectAndPaste(cfg, tmp_path).paste_on_locations()
    gs.BlendLesions(cfg, tmp_path).blend_lesions()
    views = gs.Generate2DViews(cfg, tmp_path)
    views.synthesize_views(progress=False)
    assert len(made) == 3 and closed == made
    cfg2 = small_config("blend.method=poisson", "views.per_body=2", "bodies.count=1")
    views.cfg = cfg2
    views.synthesize_views(progress=False)  # a second call makes (and releases) a new one
    assert len(made) == 4 and closed == made
    assert len(_samples(tmp_path)) == 2
    with Renderer(64, 64) as mine:
        gs.Generate2DViews(small_config("views.per_body=3", "bodies.count=1"), tmp_path,
                           renderer=mine).synthesize_views(progress=False)
        assert mine not in closed
    assert closed[-1] is mine


@pytest.mark.parametrize("radius_mm", [0.2, 1.5, 12.0])
def test_closeups_frame_a_lesion_at_the_requested_fraction(renderer, rng, radius_mm):
    """A disc lesion on a plane, seen square-on: its share of the rendered frame is the
    requested one; a lesion too small for the nearest distance narrows the field of
    view, and one too small for the narrowest frame (closeup_min_width) fills less."""
    from glsynth.pipeline import views as V
    frac = rng.uniform(0.05, 0.2)
    v = small_config(f"views.closeup_fraction=[{frac}, {frac}]", "views.closeup_tilt=0",
                     "views.closeup_min_width=[0.005, 0.005]").views
    r = radius_mm / 1000
    centre = np.r_[rng.uniform(-0.1, 0.1, 2), 0.0]
    a, d = rng.uniform(0, 2 * np.pi, 4000), r * np.sqrt(rng.uniform(0, 1, 4000))
    pts = centre + np.c_[d * np.cos(a), d * np.sin(a), np.zeros_like(a)]
    site = V.LesionSite(pts, np.tile([0.0, 0.0, 1.0], (len(pts), 1)), np.pi * r * r)
    point, normal, direction, w, _, fov = V._closeup_camera([site], rng, v)
    cam = gs.Camera.from_surface(point, direction, w, fov_deg=fov, width=renderer.width, height=renderer.height)
    out = renderer.render(plane(rng, size=1.0), cam, passes=("gbuffer",))
    mesh = plane(rng, size=1.0)
    p = np.einsum("hwk,hwkc->hwc", out["bary"], mesh.vertices[mesh.faces[np.maximum(out["face_id"], 0)]])
    assert (out["face_id"] >= 0).all()
    # the lesion's share of a square frame (views are square; this renderer may not be)
    got = (np.linalg.norm(p - centre, axis=-1) < r).mean() * renderer.width / renderer.height
    side = 2 * w * np.tan(np.radians(fov) / 2)                  # frame height on the plane
    assert abs(got - np.pi * r * r / side ** 2) < 0.1 * frac
    if radius_mm == 12.0:
        assert fov == v.fov_deg and abs(got - frac) < 0.1 * frac
    elif radius_mm == 1.5:
        assert w == v.closeup_w[0] and fov < v.fov_deg and abs(got - frac) < 0.1 * frac
    else:
        assert w == v.closeup_w[0] and abs(side - v.closeup_min_width[0]) < 1e-9 and got < 0.5 * frac


def test_closeups_of_a_spread_group_frame_the_share_it_shows(renderer, rng):
    """A group of discs spread far wider than the frame its area alone would need (as
    pityriasis rosea or a psoriasis arrangement are): the close-up still shows the lesion
    over the requested share of the frame, within a tenth, where framing by the group's
    total area shows a fraction of it."""
    from glsynth.pipeline import views as V
    # below the ~0.5 the narrowest frame shows when its centre falls on a disc's edge
    frac = rng.uniform(0.15, 0.35)
    v = small_config(f"views.closeup_fraction=[{frac}, {frac}]", "views.closeup_tilt=0",
                     "views.closeup_min_width=[0.005, 0.005]").views
    r = rng.uniform(0.004, 0.008)
    # seven of the 6 x 6 cells, 5 cm apart, over 30 cm; jittered, never touching
    cells = rng.choice(36, 7, replace=False)
    centres = np.c_[np.c_[cells % 6, cells // 6] * 0.05 - 0.125 + rng.uniform(-0.015, 0.015, (7, 2)),
                    np.zeros(7)]
    n = 2800        # a disc's points: dense enough to measure the narrowest frame by
    a, d = rng.uniform(0, 2 * np.pi, 7 * n), r * np.sqrt(rng.uniform(0, 1, 7 * n))
    pts = centres.repeat(n, 0) + np.c_[d * np.cos(a), d * np.sin(a), np.zeros_like(a)]
    site = V.LesionSite(pts, np.tile([0.0, 0.0, 1.0], (len(pts), 1)), 7 * np.pi * r * r)
    point, normal, direction, w, _, fov = V._closeup_camera([site], rng, v)
    cam = gs.Camera.from_surface(point, direction, w, fov_deg=fov, width=renderer.width,
                                 height=renderer.height)
    mesh = plane(rng, size=1.0)
    out = renderer.render(mesh, cam, passes=("gbuffer",))
    p = np.einsum("hwk,hwkc->hwc", out["bary"], mesh.vertices[mesh.faces[np.maximum(out["face_id"], 0)]])
    x0 = (renderer.width - renderer.height) // 2          # the square frame of a view
    p = p[:, x0:x0 + renderer.height]
    inside = (np.linalg.norm(p[:, :, None] - centres[None, None], axis=-1) < r).any(-1)
    assert abs(inside.mean() - frac) < 0.1 * frac
    by_area = np.sqrt(site.area / frac)                 # the frame the whole group's area asks
    assert 2 * w * np.tan(np.radians(fov) / 2) < 0.9 * by_area


def test_closeups_of_small_lesions_range_from_macro_to_context(rng):
    """A lesion too small to fill its share of the narrowest frame is framed as wide as a
    log-uniform draw in closeup_min_width: macro shots and context shots alike, never
    outside the range; a lesion large enough for its share is framed by that share."""
    from glsynth.pipeline import views as V
    lo, hi = sorted(rng.uniform(0.01, 0.15, 2))
    v = small_config("views.closeup_fraction=[0.1, 0.1]", "views.closeup_tilt=0",
                     f"views.closeup_min_width=[{lo}, {hi}]", "views.closeup_w=[0.001, 100]").views
    flat = lambda r: V.LesionSite(np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]), np.pi * r * r)  # noqa: E731
    widths = []
    for _ in range(400):
        _, _, _, w, _, fov = V._closeup_camera([flat(1e-4)], rng, v)
        widths.append(2 * w * np.tan(np.radians(fov) / 2))
    u = (np.log(widths) - np.log(lo)) / (np.log(hi) - np.log(lo))   # uniform in [0, 1]
    assert u.min() > -1e-9 and u.max() < 1 + 1e-9
    assert np.allclose(np.quantile(u, [0.25, 0.5, 0.75]), [0.25, 0.5, 0.75], atol=0.08)
    big = 3 * hi                                   # the frame a disc needs to fill 0.1 of it
    _, _, _, w, _, fov = V._closeup_camera([flat(big * np.sqrt(0.1 / np.pi))], rng, v)
    assert abs(2 * w * np.tan(np.radians(fov) / 2) - big) < 1e-9 * big


def test_closeups_above_one_show_part_of_a_large_lesion(renderer, rng):
    """closeup_fraction above 1 asks for a frame smaller than the lesion: a large disc
    seen square-on then runs off every edge of the frame and covers nearly all of it.
    The fraction is of the frame's short side squared; the renderer's frame is 4:3 and
    the aim may stray a fifth of the short side on each surface axis, so the far long
    edge lies up to (2/3 + 0.2 * sqrt(2)) of the short side from the disc's centre:
    inside the disc only for fractions above about 2.84."""
    from glsynth.pipeline import views as V
    assert renderer.width * 3 == renderer.height * 4
    frac = rng.uniform(3.0, 4.5)
    v = small_config(f"views.closeup_fraction=[{frac}, {frac}]", "views.closeup_tilt=0",
                     "views.closeup_min_width=[0.015, 0.015]").views
    r = rng.uniform(0.04, 0.08)
    a, d = rng.uniform(0, 2 * np.pi, 4000), r * np.sqrt(rng.uniform(0, 1, 4000))
    pts = np.c_[d * np.cos(a), d * np.sin(a), np.zeros_like(a)]
    site = V.LesionSite(pts, np.tile([0.0, 0.0, 1.0], (len(pts), 1)), np.pi * r * r)
    point, normal, direction, w, _, fov = V._closeup_camera([site], rng, v)
    cam = gs.Camera.from_surface(point, direction, w, fov_deg=fov, width=renderer.width, height=renderer.height)
    mesh = plane(rng, size=1.0)
    out = renderer.render(mesh, cam, passes=("gbuffer",))
    p = np.einsum("hwk,hwkc->hwc", out["bary"], mesh.vertices[mesh.faces[np.maximum(out["face_id"], 0)]])
    inside = np.linalg.norm(p, axis=-1) < r
    side = 2 * w * np.tan(np.radians(fov) / 2)
    assert abs(np.pi * r * r / side ** 2 - frac) < 1e-6 * frac
    assert inside.mean() > 0.75
    for edge in (inside[0], inside[-1], inside[:, 0], inside[:, -1]):
        assert edge.any()


def test_each_body_gets_its_own_procedural_lesions_and_a_shard_the_same(tmp_path):
    """A procedural bank holds per_body lesions for each body and deals them out: no
    lesion is pasted on two bodies (drawn at random, a quarter of them repeated another
    body's). A shard of the run (bodies.first) holds the same bodies with the same
    lesions, and backgrounds of its own."""
    from glsynth.pipeline.inputs import background_source
    opts = ("lesions.per_body=2", "lesions.resolution=96", "lesions.kinds=[nevus, pigmented_patch]")
    whole = small_config("bodies.count=3", *opts)
    gs.SelectAndPaste(whole, tmp_path / "whole").paste_on_locations()
    placed = {b: [p["lesion_id"] for p in json.load(open(tmp_path / "whole" / "bodies" / b / "placements.json"))]
              for b in ("body000", "body001", "body002")}
    ids = sum(placed.values(), [])
    assert len(ids) >= 4 and len(set(ids)) == len(ids), ids
    shard = small_config("bodies.count=1", "bodies.first=2", *opts)
    assert gs.pipeline.bodies.body_ids(shard) == ["body002"]
    gs.SelectAndPaste(shard, tmp_path / "shard").paste_on_locations()
    mine = json.load(open(tmp_path / "shard" / "bodies" / "body002" / "placements.json"))
    assert [p["lesion_id"] for p in mine] == placed["body002"]
    assert not set(background_source(shard).ids) & set(background_source(whole).ids)


@pytest.mark.slow
def test_multi_lesion_conditions_give_one_instance_each_with_exact_boxes(tmp_path):
    """Widespread conditions (acne, urticaria): each discrete lesion is its own instance,
    recorded with its preset, and every box is the exact extent of its instance's pixels;
    COCO holds one annotation per instance."""
    cfg = small_config("lesions.kinds=[acne, urticaria]", "blend.method=poisson",
                       "views.per_body=6", "views.framing={closeup: 1}", "lesions.resolution=192",
                       "lesions.decal_size=256")
    gs.pipeline.generate(cfg, tmp_path)
    placements = json.load(open(tmp_path / "bodies" / "body000" / "placements.json"))
    assert any(len(p["instance_ids"]) > 1 for p in placements)
    all_ids = [k for p in placements for k in p["instance_ids"]]
    assert len(all_ids) == len(set(all_ids))                       # ids never shared
    coco = json.load(open(tmp_path / "annotations.coco.json"))
    n_boxes = 0
    for sid in _samples(tmp_path):
        meta = json.load(open(tmp_path / "targets" / f"{sid}.json"))
        inst = read_image(tmp_path / "targets" / f"{sid}_instances.png")
        present = set(np.unique(inst[inst > 0]).tolist())
        assert {l["instance"] for l in meta["lesions"]} == present
        for l in meta["lesions"]:
            ys, xs = np.nonzero(inst == l["instance"])
            assert l["box"] == [int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1]
            assert l["area"] == len(ys) and l["source"]["preset"] in ("acne", "urticaria")
            n_boxes += 1
    assert n_boxes > 6
    assert len(coco["annotations"]) == n_boxes


def test_regional_views_frame_the_affected_part_by_its_size(rng):
    """A regional view frames a body part by its width (its width over
    views.regional_fill gives the frame width), so a limb fills the frame rather than
    floating in background; with views.regional_lesion it is the part holding a lesion,
    centred at the lesion."""
    from types import SimpleNamespace
    from glsynth.pipeline import views as V
    # two flat rectangular parts: 1 (0.4 x 0.1 m, a forearm) and 2 (0.6 x 0.3 m, a trunk)
    def rect(x0, lx, ly, n=12):
        xs, ys = np.meshgrid(np.linspace(x0, x0 + lx, n), np.linspace(0, ly, n))
        return np.c_[xs.ravel(), ys.ravel(), np.zeros(n * n)]
    verts = np.r_[rect(0.0, 0.4, 0.1), rect(1.0, 0.6, 0.3)]
    labels = np.r_[np.full(144, 1), np.full(144, 2)]
    faces = np.array([[a, a + 1, a + 12] for base in (0, 144) for a in range(base, base + 131) if a % 12 < 11])
    a, b, c = (verts[faces[:, i]] for i in range(3))
    mesh = SimpleNamespace(vertices=verts, faces=faces, vertex_labels=labels,
                           vertex_normals=np.tile([0.0, 0.0, 1.0], (len(verts), 1)),
                           face_areas=0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1))
    body = SimpleNamespace(mesh=mesh)
    site_pts = np.array([[0.30, 0.05, 0.0], [0.31, 0.05, 0.0]])
    site = V.LesionSite(site_pts, np.tile([0.0, 0.0, 1.0], (2, 1)), 1e-4)
    fill = rng.uniform(0.9, 1.8)
    v = small_config(f"views.regional_fill=[{fill}, {fill}]", "views.regional_lesion=1").views
    point, normal, direction, w, centre, fov = V._regional_camera(body, [site], rng, v)
    assert centre == "lesion 1" and any(np.allclose(point, p) for p in site_pts)
    np.testing.assert_allclose(w, 0.1 / fill / (2 * np.tan(np.radians(fov) / 2)), rtol=1e-6)
    # without the lesion preference: a part by area, near its middle, framed by its width
    v0 = dataclasses.replace(v, regional_lesion=0.0)
    for _ in range(10):
        point, _, _, w, centre, fov = V._regional_camera(body, [site], rng, v0)
        assert centre.startswith("part ")
        width = 0.1 if centre == "part 1" else 0.3
        np.testing.assert_allclose(w, width / fill / (2 * np.tan(np.radians(fov) / 2)), rtol=1e-6)


def test_an_eruption_is_recorded_and_framed_as_one_lesion(tmp_path, rng):
    """With lesions.eruption=1 a body's first eruptive condition spreads: its further
    lesions are recorded in the body's placements and each view's lesion list with the
    eruption they belong to, and close-ups frame the eruption as one lesion (their
    centre names one of the body's lesion sites, the eruption counted once)."""
    preset = str(rng.choice(["pityriasis_rosea", "urticaria", "psoriasis"]))
    # a further draw may find no place within the radius (logged, as for any lesion), and
    # a body may hold neither of its two large conditions (PasteError: a one-body run has
    # no spare lesions; seed 3459044992 drew two pityriasis roseas no place on its body
    # could take), so up to three bodies are tried; none of them spreading would be a bug
    from glsynth.pipeline.paste import PasteError
    members = []
    for attempt in range(3):
        out = tmp_path / f"run{attempt}"
        cfg = small_config("blend.method=paste", "lesions.eruption=1.0", "lesions.eruption_lesions=[2, 3]",
                           f"lesions.kinds=[{preset}]", "views.framing={closeup: 1.0}",
                           "views.per_body=6", f"seed={int(rng.integers(1000))}")
        try:
            gs.pipeline.generate(cfg, out)
        except PasteError:
            continue
        placements = json.loads((out / "bodies" / "body000" / "placements.json").read_text())
        placements = placements["placements"] if isinstance(placements, dict) else placements
        first = placements[0]     # every lesion is eruptive: the first placed one spreads
        members = [p for p in placements if p["lesion_meta"].get("eruption") == first["instance"]]
        if len(members) >= 2:
            break
    assert len(members) >= 2 and members[0] is first
    assert all(p["lesion_meta"]["preset"] == preset for p in placements)
    sites = len(placements) - len(members) + 1
    from glsynth.pipeline.bodies import load_body
    from glsynth.pipeline.paste import PastedTextures
    from glsynth.pipeline.stages import Generate2DViews
    instances, loaded = PastedTextures.load_instances(out / "bodies" / "body000")
    r = gs.Renderer(64, 64)
    mesh = load_body(cfg, "body000").mesh
    found = Generate2DViews._lesion_points(None, r, mesh, instances, loaded)
    for p in loaded:                                  # the same lesions, each on its own
        p.lesion_meta.pop("eruption", None)
    alone = Generate2DViews._lesion_points(None, r, mesh, instances, loaded)
    r.close()
    assert len(found) == sites and len(alone) == len(placements)
    merged = [alone[i] for i, p in enumerate(placements) if p in members]
    assert np.array_equal(found[0].points, np.concatenate([m.points for m in merged]))
    assert found[0].area == pytest.approx(sum(m.area for m in merged))
    for f in sorted((out / "targets").glob("*.json")):
        view = json.loads(f.read_text())
        assert view["camera"]["centre"] in {f"lesion {k}" for k in range(1, sites + 1)}
        for les in view["lesions"]:
            member = les["source"].get("eruption") == first["instance"]
            assert member == any(set(range(les["instance"], les["instance"] + 1)) & set(p["instance_ids"])
                                 for p in members)
