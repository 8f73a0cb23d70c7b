"""Gloved fingers, clothing and drapes at the frame's edge: drawn at the skin's scale,
lit from the view's light, and taken exactly out of every label."""
import types

import cv2
import numpy as np
import pytest

from glsynth.assets.occluders import Occluder, sample_occluder
from glsynth.dataformat import SEMANTIC_BACKGROUND, SEMANTIC_LESION, SEMANTIC_SKIN
from glsynth.pipeline.photo import linear_to_srgb8, srgb_to_linear
from glsynth.pipeline.views import draw_occluder, instance_regions, occlude

LOOSE = types.SimpleNamespace(min_skin=0.0, min_lesion=0.0)


def _layers(rng, shape=(96, 128)):
    """Random labels: skin everywhere, a few lesion discs with instance ids, random depth."""
    h, w = shape
    sem = np.full(shape, SEMANTIC_SKIN, np.uint8)
    inst = np.zeros(shape, np.uint16)
    for k in range(1, 4):
        cv2.circle(inst, (int(rng.integers(20, w - 20)), int(rng.integers(20, h - 20))), int(rng.integers(4, 12)), k, -1)
    sem[inst > 0] = SEMANTIC_LESION
    return {"semantic": sem, "instances": inst, "regions": instance_regions(inst),
            "depth": rng.uniform(0.1, 0.5, shape).astype(np.float32),
            "anatomy": rng.integers(1, 17, shape).astype(np.uint8),
            "face_id": rng.integers(0, 1000, shape).astype(np.int32),
            "uv": rng.uniform(0, 1, (h, w, 2)).astype(np.float32),
            "normals": rng.uniform(-1, 1, (h, w, 3)).astype(np.float32),
            "fractions": {}}


def _boxes(inst):
    out = {}
    for k in np.unique(inst[inst > 0]):
        ys, xs = np.nonzero(inst == k)
        out[int(k)] = {"box": [xs.min(), ys.min(), xs.max() + 1, ys.max() + 1], "area": len(xs)}
    return out


@pytest.mark.parametrize("kind", ["glove", "clothing", "drape"])
def test_occlude_takes_the_occluder_out_of_every_label(rng, kind):
    layers = _layers(rng)
    before = {k: v.copy() for k, v in layers.items() if isinstance(v, np.ndarray)}
    # lesions lie 20 px or more from the sides: an occluder reaching a fifth of the frame
    # in (wavy, turned) leaves most of each
    occ = sample_occluder(rng, layers["semantic"].shape, 0.3, (0.3, 0.4, 0.87), reach=(0.1, 0.15),
                          kinds={kind: 1})
    hidden = occ.mask
    assert 0 < hidden.mean() < 0.6
    assert occlude(layers, occ, LOOSE, 0.25)
    assert (layers["semantic"][hidden] == SEMANTIC_BACKGROUND).all()
    for name, off in {"instances": 0, "anatomy": 0, "face_id": -1, "depth": 0.25, "uv": -1, "normals": 0}.items():
        assert (layers[name][hidden] == off).all(), name
        assert (layers[name][~hidden] == before[name][~hidden]).all(), name
    assert layers["regions"] == _boxes(layers["instances"])
    n = hidden.size
    assert layers["fractions"]["skin"] == pytest.approx(np.mean(layers["semantic"] == SEMANTIC_SKIN))
    assert layers["fractions"]["lesion"] == pytest.approx(np.count_nonzero(layers["instances"]) / n)


def test_occlude_leaves_a_view_alone_when_it_would_hide_most_of_a_lesion(rng):
    layers = _layers(rng)
    layers["instances"][:] = 0
    cv2.rectangle(layers["instances"], (0, 0), (20, 95), 1, -1)     # a lesion along the left side
    layers["semantic"][:] = SEMANTIC_SKIN
    layers["semantic"][layers["instances"] > 0] = SEMANTIC_LESION
    before = {k: v.copy() for k, v in layers.items() if isinstance(v, np.ndarray)}
    shape = layers["semantic"].shape
    alpha = np.zeros(shape, np.float32)
    alpha[:, :30] = 1
    occ = Occluder("clothing", shape, (0, shape[0], 0, shape[1]), np.zeros(shape + (3,), np.float32), alpha,
                   np.ones(shape, np.float32))
    assert not occlude(layers, occ, LOOSE, 0.3)
    assert all((layers[k] == v).all() for k, v in before.items())
    # nor when the view's skin minimum would not survive
    alpha[:] = 0
    alpha[:, 60:] = 1
    assert not occlude(layers, occ, types.SimpleNamespace(min_skin=0.35, min_lesion=0.0), 0.3)   # 39 of 128 columns left
    assert occlude(layers, occ, types.SimpleNamespace(min_skin=0.25, min_lesion=0.0), 0.3)


def _frame(occ, box_array, fill):
    """A box-sized array of an occluder in a frame-sized one."""
    y0, y1, x0, x1 = occ.box
    out = np.full(occ.shape + box_array.shape[2:], fill, box_array.dtype)
    out[y0:y1, x0:x1] = box_array
    return out


def _in_plane_normals(mask):
    """Outward unit normals of a silhouette from its distance transform's gradient."""
    # zeros around the frame: the distance is to the silhouette or the frame's edge
    dist = cv2.distanceTransform(np.pad(mask.astype(np.uint8), 1), cv2.DIST_L2, 5)[1:-1, 1:-1]
    gy, gx = np.gradient(cv2.GaussianBlur(dist, (0, 0), 1.0))
    norm = np.hypot(gx, gy) + 1e-9
    return -gx / norm, gy / norm, dist   # image y runs down; the camera's +y is up


def test_gloved_fingers_are_finger_sized_and_lit_from_the_light(rng):
    shape, mm_per_px = (240, 320), 0.25                          # a 6 x 8 cm close-up
    glove = lambda seed, light: sample_occluder(np.random.default_rng(seed), shape, mm_per_px,  # noqa: E731
                                                light, kinds={"glove": 1})
    seed = next(s for s in rng.integers(1 << 30, size=60) if glove(s, (0, 0, 1)).meta["fingers"] == 1)
    # light from either side of the finger, across its axis (it points from its side of
    # the frame towards the middle, well within 45 degrees of square to the side)
    across = np.array([1.0, 0.0] if glove(seed, (0, 0, 1)).meta["side"] in ("top", "bottom") else [0.0, 1.0])
    lit = {sx: glove(seed, (*(sx * 0.8 * across), 0.6)) for sx in (1, -1)}
    occ = lit[1]
    assert occ.kind == "glove" and (occ.mask == lit[-1].mask).all()   # the light moves no finger
    nx, ny, dist = _in_plane_normals(occ.mask)
    width_px = occ.meta["width_mm"] / mm_per_px
    assert 0.8 * width_px <= 2 * dist.max() <= 1.1 * width_px
    # the side of each finger facing the light is the brighter one
    lum = lambda o: _frame(o, o.rgb @ np.float32([0.3, 0.59, 0.11]), 0)  # noqa: E731
    inner = np.zeros(shape, bool)                                # away from the frame's edge
    m = int(width_px / 2)
    inner[m:-m, m:-m] = True
    flank = occ.mask & inner & (dist > 2) & (dist < 0.3 * width_px)
    change = (lum(lit[1]) - lum(lit[-1]))[flank]
    facing = (nx * across[0] + ny * across[1])[flank]
    assert np.corrcoef(change, facing)[0, 1] > 0.5
    # and each casts its shadow away from the light (image y runs down)
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
    towards = xx * across[0] - yy * across[1]
    darkening = {sx: (1 - _frame(o, o.shadow, 1)) * ~o.mask for sx, o in lit.items()}
    centre = {sx: (d * towards).sum() / d.sum() for sx, d in darkening.items()}
    assert centre[1] < centre[-1] - 2


@pytest.mark.parametrize("mm_per_px", [0.005, 0.1, 1.0, 20.0])
@pytest.mark.parametrize("light", [(0, 0, 1), (1, 0, 0), (0, -0.6, 0.8)])
def test_occluders_stay_finite_at_any_scale_and_light(rng, mm_per_px, light):
    for kind in ("glove", "clothing", "drape"):
        occ = sample_occluder(rng, (90, 120), mm_per_px, light, kinds={kind: 1})
        for a in (occ.rgb, occ.alpha, occ.shadow):
            assert np.isfinite(a).all()
        assert occ.alpha.min() >= 0 and occ.alpha.max() <= 1 and occ.shadow.min() > 0 and occ.shadow.max() <= 1
        assert occ.rgb.dtype == np.float32 and occ.rgb.shape == occ.alpha.shape + (3,) == occ.shadow.shape + (3,)
        assert 0 <= occ.rgb.min() and occ.rgb.max() <= 1
        assert occ.mask.any() and not occ.mask.all()


def test_an_occluder_covers_what_it_covers_and_shades_only_the_rest(rng):
    image = rng.integers(0, 256, (40, 50, 3)).astype(np.uint8)
    box = (5, 40, 10, 50)                                  # drawn in a box, not the frame
    rgb = rng.uniform(0, 1, (35, 40, 3)).astype(np.float32)     # linear light
    alpha = np.zeros((35, 40), np.float32)
    alpha[:, 15:] = 1                                      # covers columns 25 onwards
    occ = Occluder("drape", (40, 50), box, rgb, alpha, np.ones((35, 40), np.float32))
    assert occ.mask.sum() == 35 * 25 and occ.mask[5:, 25:].all()
    out = draw_occluder(image, occ)
    assert (out[~occ.mask] == image[~occ.mask]).all()     # unshaded, untouched
    assert (out[5:, 25:] == linear_to_srgb8(rgb[:, 15:])).all()
    # a quarter of the light left beneath it: a quarter in linear light
    occ.shadow[:] = 0.25
    dark = srgb_to_linear(draw_occluder(image, occ)[5:, 10:25])
    lit = srgb_to_linear(image[5:, 10:25])
    assert np.abs(dark - 0.25 * lit).max() < 0.01
    assert (draw_occluder(image, occ)[:5] == image[:5]).all()


def test_the_same_seed_draws_the_same_occluder():
    a, b = (sample_occluder(np.random.default_rng(5), (64, 80), 0.2, (0, 0, 1)) for _ in range(2))
    assert a.kind == b.kind and a.meta == b.meta
    assert all((x == y).all() for x, y in ((a.rgb, b.rgb), (a.alpha, b.alpha), (a.shadow, b.shadow)))
