"""Built-in anny bodies: anatomy labels, skin tones, non-skin mask, caching.

References are independent of the code under test: CIELAB from OpenCV's float sRGB ->
Lab conversion (D65), UV coverage from cv2.fillPoly, mesh connectivity from scipy.
Textures are 512 texels here to keep the suite fast.
"""
import time

import cv2
import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

pytest.importorskip("anny")

from glsynth import dataformat as fmt  # noqa: E402
from glsynth.assets.bodies import POSES, make_body  # noqa: E402

SIZE = 512
ITA_BANDS = {1: (55, 90), 2: (41, 55), 3: (28, 41), 4: (10, 28), 5: (-30, 10), 6: (-90, -30)}
BLUE = "royal-blue"


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("glsynth-cache")


@pytest.fixture(scope="module")
def default_body(cache):
    t0 = time.perf_counter()
    body = make_body(seed=0, pose="a-pose", texture_size=SIZE, cache_dir=cache)
    return body, time.perf_counter() - t0


@pytest.fixture(scope="module")
def tone_bodies(cache):
    return {f: make_body(seed=100 + f, fitzpatrick=f, texture_size=SIZE, cache_dir=cache,
                         clothing={"bottom": "shorts", "rgb": BLUE, "trim_rgb": BLUE})
            for f in range(1, 7)}


def _lab(rgb_uint8):
    img = np.asarray(rgb_uint8, np.float32).reshape(-1, 1, 3) / 255.0
    return cv2.cvtColor(img, cv2.COLOR_RGB2Lab).reshape(np.shape(rgb_uint8))


def _covered(mesh, size):
    """Texels whose centre lies well inside a UV triangle (eroded by one texel)."""
    img = np.zeros((size, size), np.uint8)
    tri = mesh.uvs[mesh.face_uvs] * [size, -size] + [0, size]
    pts = np.round(tri * 16).astype(np.int32)  # 4 fractional bits
    cv2.fillPoly(img, list(pts), 1, lineType=cv2.LINE_8, shift=4)
    return cv2.erode(img, np.ones((3, 3), np.uint8)).astype(bool)


def _components(n, faces):
    i, j = faces.ravel(), np.roll(faces, 1, axis=1).ravel()
    adj = sp.coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n)).tocsr()
    return adj + adj.T


def _vertex_texels(mesh, size):
    """(row, col) texel of each face corner, and the vertex it belongs to."""
    uv = mesh.uvs[mesh.face_uvs.ravel()]
    col = np.clip((uv[:, 0] * size).astype(int), 0, size - 1)
    row = np.clip(((1 - uv[:, 1]) * size).astype(int), 0, size - 1)
    return mesh.faces.ravel(), row, col


# ---- anatomy ------------------------------------------------------------------------
def test_all_16_labels_each_one_connected_region(default_body):
    body, _ = default_body
    labels, faces = body.anatomy, body.mesh.faces
    assert labels.dtype == np.uint8 and len(labels) == len(body.mesh.vertices)
    assert np.array_equal(body.mesh.vertex_labels, labels)
    assert set(np.unique(labels)) == set(range(1, 17))
    adj = _components(len(labels), faces)
    n_comp, comp = connected_components(adj, directed=False)
    main = comp == np.argmax(np.bincount(comp))
    # separate pieces (eyeballs, tongue) are part of the head
    assert np.all(labels[~main] == 1)
    for part in range(1, 17):
        keep = np.flatnonzero(main & (labels == part))
        sub = adj[keep][:, keep]
        n, _ = connected_components(sub, directed=False)
        assert n == 1, f"part {part} ({fmt.PART_NAMES[part]}) is split into {n} pieces"


def test_left_labels_on_the_bodys_left(default_body):
    body, _ = default_body
    v, labels = body.mesh.vertices, body.anatomy
    up = np.array([0.0, 1.0, 0.0])
    head = v[labels == 1]
    nose = head[np.argmax(head[:, 2])]
    # the body faces +Z: the nose is in front of the head, the toes in front of the heels
    assert nose[2] > head[:, 2].mean() + 0.05
    feet = v[np.isin(labels, (9, 10))]
    assert np.ptp(feet[:, 2]) > 0.15 and feet[:, 2].max() - v[:, 2].mean() > 0.08
    front = np.array([0.0, 0.0, 1.0])
    left = np.cross(up, front)   # a person facing +Z with +Y up has their left at +X
    assert np.allclose(left, [1, 0, 0])
    for l_part in (5, 7, 9, 11, 13, 15):
        xl = v[labels == l_part] @ left
        xr = v[labels == l_part + 1] @ left
        assert np.all(xl > 0) and np.all(xr < 0), fmt.PART_NAMES[l_part]
    # hands, arms, feet are symmetric: same number of vertices each side
    for l_part in (5, 7, 9, 11, 13, 15):
        assert (labels == l_part).sum() == (labels == l_part + 1).sum()


def test_group_labels():
    labels = np.arange(17, dtype=np.uint8)
    expected = [0, 1, 2, 2, 3, 4, 4, 4, 4, 5, 5, 6, 6, 6, 6, 7, 7]
    assert fmt.group_labels(labels).tolist() == expected
    assert fmt.group_labels(labels.reshape(1, 17)).shape == (1, 17)
    # every part's group is named after it (upper torso -> torso, foot left -> feet...)
    stem = {"feet": "foot"}
    for part, name in fmt.PART_NAMES.items():
        group = fmt.GROUP_NAMES[fmt.PART_GROUPS[part]]
        assert stem.get(group, group.rstrip("s")) in name, (part, name, group)


def test_frame_units_and_pose(default_body):
    body, _ = default_body
    v = body.mesh.vertices
    assert abs(v[:, 1].min()) < 1e-9                      # standing on y = 0
    assert 1.4 < v[:, 1].max() < 2.05                      # metres
    pelvis = v[body.anatomy == 4].mean(0)
    assert abs(pelvis[0]) < 0.02 and abs(pelvis[2]) < 0.1
    assert body.meta["pose"] == "a-pose" and set(POSES) >= {"a-pose", "arms-down",
                                                            "arms-raised", "slight-turn"}


def test_explicit_arguments_override_only_their_part(default_body, cache):
    body, _ = default_body
    other = make_body(seed=0, pose="arms-raised", texture_size=SIZE, cache_dir=cache)
    assert other.meta["phenotype"] == body.meta["phenotype"]
    assert other.meta["ita"] == body.meta["ita"]
    hands = np.isin(body.anatomy, (15, 16))
    shoulders = body.mesh.vertices[np.isin(body.anatomy, (11, 12)), 1].max()
    assert body.mesh.vertices[hands, 1].max() < shoulders          # A-pose: hands low
    assert other.mesh.vertices[hands, 1].min() > shoulders         # raised: above
    assert np.array_equal(other.mesh.texture, body.mesh.texture)   # same skin


def test_seed_samples_phenotype_pose_and_look(tone_bodies):
    metas = [b.meta for b in tone_bodies.values()]
    for m in metas:
        ph = m["phenotype"]
        assert 0.6 <= ph["age"] <= 0.95                    # adults
        assert m["pose"] in POSES and m["sex"] in ("male", "female")
        assert (m["clothing"]["top"] == "sports-top") == (m["sex"] == "female")
    assert len({m["phenotype"]["weight"] for m in metas}) == len(metas)
    assert len({m["pose"] for m in metas}) > 1
    heights = [b.mesh.vertices[:, 1].max() for b in tone_bodies.values()]
    assert np.ptp(heights) > 0.03


# ---- skin tone ------------------------------------------------------------------------
def _healthy_skin(body, aperture_texels=0.0):
    """The texture's healthy-skin texels (sRGB); with an aperture, the texture blurred by
    a Gaussian of that sigma first, over healthy skin only."""
    m = body.mesh
    size = m.texture.shape[0]
    ok = _covered(m, size) & (body.nonskin == 0) & (m.textures["features"] == 0)
    for x0, y0, x1, y1 in body.nevi:
        ok[max(y0 - 2, 0):y1 + 2, max(x0 - 2, 0):x1 + 2] = False
    if not aperture_texels:
        return m.texture[ok]
    w = ok.astype(np.float32)
    blur = lambda x: cv2.GaussianBlur(x, (0, 0), aperture_texels)  # noqa: E731
    tex = blur(m.texture.astype(np.float32) * w[..., None]) / np.maximum(blur(w), 1e-6)[..., None]
    return np.clip(np.rint(tex[ok]), 0, 255).astype(np.uint8)


def test_ita_in_band_and_monotone(tone_bodies):
    medians = []
    for f, body in tone_bodies.items():
        assert body.meta["fitzpatrick"] == f
        lab = _lab(_healthy_skin(body))
        ita = np.degrees(np.arctan2(lab[:, 0] - 50.0, lab[:, 2]))
        med = float(np.median(ita))
        lo, hi = ITA_BANDS[f]
        assert lo < med <= hi, f"type {f}: median ITA {med:.1f} outside ({lo}, {hi}]"
        # most of the skin, not just the median, carries the requested tone, read as a
        # colorimeter reads it: over an aperture of ~8 mm (per texel, the millimetre
        # mottling of melanin, darker and yellower together, spreads ITA further)
        lab = _lab(_healthy_skin(body, aperture_texels=2.0))
        ita = np.degrees(np.arctan2(lab[:, 0] - 50.0, lab[:, 2]))
        assert np.mean((ita > lo) & (ita <= hi)) > 0.6
        assert abs(med - body.meta["ita"]) < 4.0
        medians.append(med)
    assert all(a > b for a, b in zip(medians, medians[1:])), medians


def test_healthy_skin_is_even_at_centimetres(tone_bodies):
    """Healthy skin's colour varies from millimetre to millimetre, but only faintly: over
    ~2 mm apertures against its surroundings over ~2 cm (Gaussians of 0.5 and 6 texels
    at 512), the median CIELAB difference stays under 1.3, below the ~2.3 that an eye
    just notices; until 2026-12-01 it was 1.9-2.0 on light skin (p90 3.6-3.9), a
    reticulated rash of yellow-brown and pink blotches on every body. Not flat either:
    above 0.3."""
    for f, body in tone_bodies.items():
        m = body.mesh
        ok = _covered(m, SIZE) & (body.nonskin == 0) & (m.textures["features"] == 0)
        for x0, y0, x1, y1 in body.nevi:
            ok[max(y0 - 2, 0):y1 + 2, max(x0 - 2, 0):x1 + 2] = False
        w = ok.astype(np.float32)
        lab = _lab(m.texture[..., :3])

        def blur(x, sigma):
            den = np.maximum(cv2.GaussianBlur(w, (0, 0), sigma), 1e-6)[..., None]
            return cv2.GaussianBlur(x * w[..., None], (0, 0), sigma) / den

        local = blur(lab, 0.5) - blur(lab, 6.0)
        inside = cv2.erode(ok.astype(np.uint8), np.ones((13, 13), np.uint8)) > 0
        median = float(np.median(np.linalg.norm(local[inside], axis=1)))
        assert 0.3 < median < 1.3, (f, median)


def test_dark_skin_is_warm_brown_not_grey(tone_bodies):
    """Very dark skin measures b* ~12-18 (a deep warm brown, hue angle ~50-65 degrees);
    a locus falling to b* ~10 painted type VI skin grey, like dirt."""
    lab = _lab(_healthy_skin(tone_bodies[6]))
    L, a, b = np.median(lab, 0)
    assert L < 42 and b > 12.5 and 45 < np.degrees(np.arctan2(b, a)) < 70, (L, a, b)


def test_explicit_ita_wins_and_must_agree(cache):
    body = make_body(seed=5, ita=-40.0, texture_size=128, cache_dir=cache)
    assert body.meta["ita"] == -40.0 and body.meta["fitzpatrick"] == 6
    with pytest.raises(ValueError):
        make_body(seed=5, ita=-40.0, fitzpatrick=2, texture_size=128, cache_dir=cache)


# ---- non-skin ---------------------------------------------------------------------------
def test_nonskin_mask_covers_clothing(tone_bodies):
    for f, body in tone_bodies.items():
        m = body.mesh
        cov = _covered(m, m.texture.shape[0])
        lab = _lab(m.texture)
        blue = cov & (lab[..., 2] < -20)                   # the royal-blue garment
        skin = cov & (body.nonskin == 0)
        assert blue.mean() > 0.03, f"type {f}: no garment painted"
        assert body.nonskin[blue].mean() > 0.97
        # no garment colour on skin, and skin and garment differ in colour
        assert (lab[skin][:, 2] < -10).mean() < 0.002
        assert lab[skin][:, 2].mean() - lab[blue][:, 2].mean() > 30


def test_nonskin_mask_covers_hair_and_eyes(tone_bodies, default_body):
    bodies = list(tone_bodies.values()) + [default_body[0]]
    with_hair = [b for b in bodies if b.meta["look"]["hair"] != "none"]
    assert with_hair
    for body in bodies:
        m, size = body.mesh, body.mesh.texture.shape[0]
        vid, row, col = _vertex_texels(m, size)
        ns = body.nonskin[row, col]
        v = m.vertices[vid]
        lab = body.anatomy[vid]
        # eyeballs: the two small separate mesh pieces; they are non-skin
        n_comp, comp = connected_components(_components(len(m.vertices), m.faces), directed=False)
        sizes = np.bincount(comp)
        eyes = np.flatnonzero(sizes < 100)
        assert len(eyes) == 2
        for e in eyes:
            corners = np.isin(vid, np.flatnonzero(comp == e))
            assert ns[corners].mean() > 0.9
        eye = m.vertices[np.isin(comp, eyes)].mean(0)
        # back of the scalp: above the eyes, well behind them
        crown = (lab == 1) & (v[:, 1] > eye[1] + 0.03) & (v[:, 2] < eye[2] - 0.1)
        # the scalp hair is painted as non-skin and shaded as hair (SkinSurface.scalp_hair):
        # full coverage on the crown, hardly any on skin, none off the head
        scalp = m.skin.scalp_hair[row, col]
        if body.meta["look"]["hair"] != "none":
            assert ns[crown].mean() > 0.95
            assert np.mean(scalp[crown] > 200) > 0.95
        else:
            assert ns[crown].mean() < 0.05
        # (single hair tips reach a texel past the labelled hairline)
        assert np.mean(scalp[ns == 0] >= 128) < 1e-3 and np.all(scalp[lab != 1] == 0)
        # the cheeks (outer surface: facing forward, not the mouth's inside) are skin
        cheeks = (lab == 1) & (v[:, 2] > eye[2] - 0.02) & (v[:, 1] < eye[1] - 0.035) \
            & (v[:, 1] > eye[1] - 0.06) & (np.abs(v[:, 0] - eye[0]) > 0.03) \
            & (m.vertex_normals[vid][:, 2] > 0.5)
        if body.meta["look"]["beard"] != "full":
            assert cheeks.sum() > 20 and ns[cheeks].mean() < 0.1


def test_beards_are_hair_labelled_non_skin_on_the_lower_face_only(cache):
    """A full beard covers the chin, the jaw and the lower cheeks (non-skin, shaded as
    hair); a moustache only the upper lip; above the eyes and on the nape the labels are
    those of the same body clean-shaven, which is skin on the chin and jaw."""
    def regions(beard):
        body = make_body(seed=5, phenotype={"gender": 0.0, "age": 0.75}, beard=beard, pose="a-pose",
                         texture_size=SIZE, cache_dir=cache)
        m, size = body.mesh, body.mesh.texture.shape[0]
        vid, row, col = _vertex_texels(m, size)
        v, nrm, lab = m.vertices[vid], m.vertex_normals[vid], body.anatomy[vid]
        n_comp, comp = connected_components(_components(len(m.vertices), m.faces), directed=False)
        sizes = np.bincount(comp)
        eye = m.vertices[np.isin(comp, np.flatnonzero(sizes < 100))].mean(0)
        head, front = lab == 1, nrm[:, 2] > 0.3
        dy = v[:, 1] - eye[1]
        chin = head & front & (np.abs(v[:, 0] - eye[0]) < 0.015) & (dy < -0.10) & (dy > -0.12)
        jaw = head & (np.abs(v[:, 0] - eye[0]) > 0.045) & (dy < -0.07) & (dy > -0.09) & (nrm[:, 1] < 0.3) \
            & (v[:, 2] > eye[2] - 0.08)
        upper = head & front & (dy > -0.01)                  # the eyes, brows, forehead
        nape = head & (v[:, 2] < eye[2] - 0.12) & (dy < -0.1) & (nrm[:, 2] < -0.5)
        ns, scalp = body.nonskin[row, col], m.skin.scalp_hair[row, col]
        assert chin.sum() > 5 and jaw.sum() > 5 and upper.sum() > 20 and nape.sum() > 5
        return {k: float(ns[r].mean()) for k, r in (("chin", chin), ("jaw", jaw), ("upper", upper),
                                                     ("nape", nape))}, float(np.mean(scalp[chin] > 128)), body

    full, hairy, body = regions("full")
    assert body.meta["look"]["beard"] == "full"
    assert full["chin"] > 0.9 and full["jaw"] > 0.8 and hairy > 0.8
    bare, _, _ = regions("none")
    assert bare["chin"] < 0.05 and bare["jaw"] < 0.05
    assert full["upper"] == bare["upper"] and full["nape"] < 0.05
    moustache, _, _ = regions("moustache")
    assert moustache["chin"] < 0.05 and moustache["jaw"] < 0.05
    with pytest.raises(ValueError, match="unknown beard 'mutton'"):
        make_body(seed=5, beard="mutton", texture_size=SIZE, cache_dir=cache)


def test_beards_are_drawn_for_adult_men_only_at_their_shares():
    from glsynth.assets.skin import BEARDS, sample_look
    rng = np.random.default_rng(3)
    men = [sample_look(rng, 30.0, False, 0.75).beard for _ in range(3000)]
    for style, share in BEARDS.items():
        assert abs(men.count(style) / len(men) - share) < 0.03, style
    assert {sample_look(rng, 30.0, True, 0.75).beard for _ in range(200)} == {"none"}
    assert {sample_look(rng, 30.0, False, 0.4).beard for _ in range(200)} == {"none"}
    # the beard is drawn after everything else: the rest of a look is as it was without it
    a = sample_look(np.random.default_rng(7), 30.0, False, 0.75)
    b = sample_look(np.random.default_rng(7), 30.0, False, 0.75, beard="goatee")
    assert b.beard == "goatee" and {**a.to_dict(), "beard": "goatee"} == b.to_dict()


def test_body_hair_greys_later_than_scalp_hair(rng):
    """Under grey or white scalp hair the body hair is mostly pigmented: darker than the
    scalp hair, darker still on brown skin, and white scalp hair's lighter than grey's."""
    from glsynth.assets.bodies import body_hair_rgb
    from glsynth.assets.colour import srgb_to_lab
    from glsynth.assets.skin import HAIR_COLOURS
    L = lambda rgb: float(srgb_to_lab(np.asarray(rgb, np.uint8))[0])  # noqa: E731
    fair, brown = rng.uniform(20, 70), rng.uniform(-60, 0)
    for name, rgb in HAIR_COLOURS.items():
        body = body_hair_rgb({"hair_rgb": list(rgb), "ita": fair})
        assert L(body) < L(rgb), name                       # every body hair a little darker
        if name in ("grey", "white"):
            # mostly pigmented: nearer the dark-brown body hair than the scalp's colour
            assert L(body) - L(body_hair_rgb({"hair_rgb": HAIR_COLOURS["dark-brown"], "ita": fair})) \
                < 0.6 * (L(rgb) - L(HAIR_COLOURS["dark-brown"])), name
            assert L(body_hair_rgb({"hair_rgb": list(rgb), "ita": brown})) <= L(body), name
    grey, white = (L(body_hair_rgb({"hair_rgb": HAIR_COLOURS[n], "ita": fair})) for n in ("grey", "white"))
    assert grey + 5 < white


def test_closed_eyes_hide_the_eyeballs_and_move_only_the_lids(default_body, cache):
    """Closing the eyes folds the lids over the eyeballs (none of the eyeball's front is
    seen from the front, against hundreds of pixels with the eyes open); only vertices
    around the eyes move, and the skin texture is the neutral face's."""
    from gl_context import get_renderer
    from glsynth.assets.skin import _segment_mask
    from glsynth.camera import Camera
    body, _ = default_body
    assert body.meta["expression"]["eyeBlinkLeft"] <= 0.2         # seed 0: eyes open
    shut = make_body(seed=0, pose="a-pose", texture_size=SIZE, cache_dir=cache,
                     expression={"eyeBlinkLeft": 1.0, "eyeBlinkRight": 1.0})
    assert shut.meta["expression"] == {"eyeBlinkLeft": 1.0, "eyeBlinkRight": 1.0}
    assert np.array_equal(shut.mesh.texture, body.mesh.texture)
    v0, v1 = body.mesh.vertices, shut.mesh.vertices
    moved = np.linalg.norm(v1 - v0, axis=1) > 1e-4
    assert moved.sum() > 100
    assert (body.anatomy[moved] == 1).all()                         # the head
    assert np.ptp(v0[moved], axis=0).max() < 0.12      # two eyes' width, not the face
    eyeball = _segment_mask(SIZE, ["eye_front.L", "eye_front.R"])
    front = v0[v0[:, 1] > v0[:, 1].max() - 0.25, 2].max()           # of the head
    target = np.array([0.0, v0[moved, 1].mean(), front - 0.03])
    cam = Camera.look_at(eye=target + [0, 0, 0.4], target=target, fov_deg=20, width=256, height=256)
    seen = []
    for b in (body, shut):
        g = get_renderer(width=256, height=256).render(b.mesh, cam, passes=("gbuffer",))
        hit = g["face_id"] >= 0
        uv = g["uv"][hit]
        col = np.clip((uv[:, 0] * SIZE).astype(int), 0, SIZE - 1)
        row = np.clip(((1 - uv[:, 1]) * SIZE).astype(int), 0, SIZE - 1)
        seen.append(int(eyeball[row, col].sum()))
    assert seen[0] > 200 and seen[1] <= 0.02 * seen[0], seen
    with pytest.raises(ValueError, match="facial actions"):
        make_body(seed=0, texture_size=SIZE, cache_dir=cache, expression={"smile": 1.0})
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        make_body(seed=0, texture_size=SIZE, cache_dir=cache, expression={"eyeBlinkLeft": 2.0})


def test_expressions_are_drawn_at_their_shares():
    from glsynth.assets.bodies import EYES_CLOSED_SHARE, EYES_HALF_SHARE, sample_expression
    rng = np.random.default_rng(5)
    blinks = np.array([sample_expression(rng)["eyeBlinkLeft"] for _ in range(4000)])
    assert abs((blinks == 1.0).mean() - EYES_CLOSED_SHARE) < 0.025
    assert abs(((blinks > 0.4) & (blinks < 1)).mean() - EYES_HALF_SHARE) < 0.02
    assert ((blinks <= 0.2) | (blinks > 0.4)).all()


def test_nevi_are_small_dark_skin_spots(cache):
    body = make_body(seed=7, texture_size=1024, cache_dir=cache, clothing="none")
    m = body.mesh
    assert 1 <= len(body.nevi) <= 20
    L = _lab(m.texture)[..., 0]
    skin_L = np.median(L[body.nonskin == 0])
    for x0, y0, x1, y1 in body.nevi:
        assert 0 <= x0 < x1 <= 1024 and 0 <= y0 < y1 <= 1024
        assert (x1 - x0) <= 16 and (y1 - y0) <= 16
        assert body.nonskin[y0:y1, x0:x1].max() == 0
        assert L[y0:y1, x0:x1].min() < skin_L - 8
        assert m.textures["features"][y0:y1, x0:x1].any()


# ---- cache ----------------------------------------------------------------------------
def test_second_call_is_cached_and_identical(default_body, cache):
    first, _ = default_body
    t0 = time.perf_counter()
    again = make_body(seed=0, pose="a-pose", texture_size=SIZE, cache_dir=cache)
    elapsed = time.perf_counter() - t0
    assert elapsed < 2.0, f"cached make_body took {elapsed:.2f} s"
    for name in ("vertices", "faces", "uvs", "face_uvs", "texture", "vertex_labels"):
        a, b = getattr(first.mesh, name), getattr(again.mesh, name)
        assert a.dtype == b.dtype and np.array_equal(a, b), name
    assert np.array_equal(first.nonskin, again.nonskin)
    assert np.array_equal(first.anatomy, again.anatomy)
    assert first.nevi == again.nevi and first.meta == again.meta
    files = list((cache / "bodies").glob("*.npz"))
    assert files and not list((cache / "bodies").glob(".tmp-*"))


def test_texture_layout(default_body):
    body, _ = default_body
    m = body.mesh
    assert m.texture.shape == (SIZE, SIZE, 3) and m.texture.dtype == np.uint8
    assert body.nonskin.shape == (SIZE, SIZE) and body.nonskin.dtype == np.uint8
    assert set(np.unique(body.nonskin)) <= {0, 1}
    assert m.textures["nonskin"] is body.nonskin
    # padded: no black background left between UV islands
    assert (m.texture.sum(-1) == 0).mean() < 0.001


# ---- anatomy per texel ------------------------------------------------------------------
def _surface_samples(mesh, n=4, inset=0.04):
    """A grid of points in every face (barycentrics (n-i-j, i, j)/n, pulled ``inset`` of
    the way to the centroid) and the links between neighbours: inside a face, and across
    each mesh edge between the two faces' points along it (seams included). Returns
    (face, barycentrics, link rows, link cols)."""
    ij = np.array([(i, j) for i in range(n + 1) for j in range(n + 1 - i)])
    index = {tuple(p): k for k, p in enumerate(ij)}
    local = []
    for i, j in ij:
        for di, dj in ((1, 0), (0, 1), (-1, 1)):
            if (i + di, j + dj) in index:
                local.append((index[(i, j)], index[(i + di, j + dj)]))
    local = np.array(local)
    k, nf = len(ij), len(mesh.faces)
    b = np.c_[n - ij.sum(1), ij] / n
    b = (1 - inset) * b + inset / 3
    base = np.arange(nf)[:, None] * k
    rows, cols = (base + local[:, 0]).ravel(), (base + local[:, 1]).ravel()
    # points along each face edge (corner a -> corner b), keyed by the mesh edge
    keys, nodes = [], []
    for a, c in ((0, 1), (0, 2), (1, 2)):
        s = np.arange(n + 1)
        pts = [index[tuple(p)] for p in
               (np.c_[s, 0 * s] if (a, c) == (0, 1) else np.c_[0 * s, s] if (a, c) == (0, 2)
                else np.c_[n - s, s])]
        va, vc = mesh.faces[:, a], mesh.faces[:, c]
        t = np.where((va < vc)[:, None], s[None], n - s[None])
        keys.append(np.stack([np.broadcast_to(np.minimum(va, vc)[:, None], t.shape),
                              np.broadcast_to(np.maximum(va, vc)[:, None], t.shape), t], -1).reshape(-1, 3))
        nodes.append((base + np.array(pts)[None]).ravel())
    keys, nodes = np.concatenate(keys), np.concatenate(nodes)
    order = np.lexsort(keys.T[::-1])
    keys, nodes = keys[order], nodes[order]
    same = (keys[1:] == keys[:-1]).all(1)
    rows = np.r_[rows, nodes[:-1][same]]
    cols = np.r_[cols, nodes[1:][same]]
    return np.repeat(np.arange(nf), k), np.tile(b, (nf, 1)), rows, cols


def test_anatomy_texture_parts_are_connected_with_straight_borders(default_body):
    """Per-texel anatomy (what views render): on the surface, sampled through the
    texture, every part is one connected region; the trunk's borders are horizontal
    cuts of the average body's rest pose to within a texel, where the nearest-corner
    rule zigzags a face wide; and the borders are shorter than that rule's."""
    from glsynth.assets import bodies as B
    body, _ = default_body
    m, amap = body.mesh, body.anatomy_map
    assert amap.dtype == np.uint8 and amap.shape == (SIZE, SIZE)
    assert set(np.unique(amap)) == set(range(1, 17))
    face, b, rows, cols = _surface_samples(m)
    uv = np.einsum("nk,nkc->nc", b, m.uvs[m.face_uvs[face]])
    r = np.clip(((1 - uv[:, 1]) * SIZE).astype(int), 0, SIZE - 1)
    c = np.clip((uv[:, 0] * SIZE).astype(int), 0, SIZE - 1)
    lab = amap[r, c]
    n_comp, comp = connected_components(_components(len(m.vertices), m.faces), directed=False)
    main = comp[m.faces[face, 0]] == np.argmax(np.bincount(comp))
    assert (lab[~main] == 1).all()                        # eyeballs, tongue: head
    for part in range(1, 17):
        keep = np.flatnonzero(main & (lab == part))
        sel = np.zeros(len(lab), bool)
        sel[keep] = True
        link = sel[rows] & sel[cols]
        pos = np.full(len(lab), -1)
        pos[keep] = np.arange(len(keep))
        g = sp.coo_matrix((np.ones(link.sum()), (pos[rows[link]], pos[cols[link]])),
                          shape=(len(keep), len(keep)))
        n, _ = connected_components(g, directed=False)
        assert n == 1, f"part {part} ({fmt.PART_NAMES[part]}) is split into {n} pieces on the surface"
    # trunk cuts: rest-pose heights of texels on either side of the 2|3 and 3|4 borders
    st = B._static()
    tface, tbary = B._raster(SIZE)
    cov = tface >= 0
    height = np.zeros((SIZE, SIZE))
    height[cov] = np.einsum("nk,nk->n", tbary[cov], st["rest"][st["faces"][tface[cov]], 1])
    corner = np.zeros_like(amap)
    corner[cov] = st["labels"][st["faces"][tface[cov], np.argmax(tbary[cov], 1)]]
    texel_height = np.ptp(st["rest"][:, 1]) * 2 / SIZE    # ~6 mm: UV scale varies
    for upper, lower in ((2, 3), (3, 4)):
        for labels, limit in ((amap, texel_height / 4), (corner, None)):
            ok = cov & ~np.isin(tface, np.flatnonzero(~np.isin(st["labels"][st["faces"]], (2, 3, 4)).any(1)))
            overlap = height[ok & (labels == lower)].max() - height[ok & (labels == upper)].min()
            if limit is not None:
                assert overlap <= limit, f"{upper}|{lower} border off its plane by {overlap * 1000:.1f} mm"
            else:
                assert overlap > 2 * texel_height  # the face-corner rule's zigzag (the control)

    def border(labels):
        return ((labels[:, 1:] != labels[:, :-1]) & cov[:, 1:] & cov[:, :-1]).sum() + \
            ((labels[1:] != labels[:-1]) & cov[1:] & cov[:-1]).sum()
    assert border(amap) < 0.85 * border(corner)


def test_value_noise_against_a_pointwise_reference(rng):
    """skin.Noise3D (vectorised, 32-bit hashing) is the smoothstep-interpolated lattice
    noise of its permutation and values, computed here one point at a time."""
    from glsynth.assets.skin import Noise3D
    nz = Noise3D(int(rng.integers(2 ** 31)))
    perm, vals = nz.perm[:256].tolist(), nz.vals.tolist()

    def lattice(x, y, z):
        return vals[perm[(perm[(perm[x % 256] + y % 256) % 256] + z % 256) % 256]]

    freq = float(rng.uniform(1, 500))
    pts = rng.uniform(-2, 2, (200, 3))
    got = nz(pts, freq)
    for p, g in zip(pts, got):
        q = p * freq + nz.off
        i = np.floor(q).astype(int)
        f = q - i
        u = f * f * (3 - 2 * f)
        ref = sum((u[0] if dx else 1 - u[0]) * (u[1] if dy else 1 - u[1]) * (u[2] if dz else 1 - u[2])
                  * lattice(i[0] + dx, i[1] + dy, i[2] + dz)
                  for dx in (0, 1) for dy in (0, 1) for dz in (0, 1))
        assert abs(g - ref) < 1e-5


def test_painting_in_blocks_on_threads_gives_the_one_call_values(rng, monkeypatch):
    """The painter's speed-ups change no value: noise and fbm computed in row blocks on
    threads equal one call over all rows (blocks of an odd size, the last one short);
    texel interpolation equals the barycentric sum; a segmentation mask equals the
    comparison of RGB triples it replaced."""
    import types

    from glsynth import rows
    from glsynth.assets import skin
    nz = skin.Noise3D(int(rng.integers(2 ** 31)))
    pts = rng.uniform(-2, 2, (5003, 3))
    freq = float(rng.uniform(1, 500))
    whole = (nz(pts, freq), nz.fbm(pts, freq, 3))
    monkeypatch.setattr(rows, "BLOCK_ROWS", 997)
    monkeypatch.setattr(rows.os, "cpu_count", lambda: 2)
    assert np.array_equal(nz(pts, freq), whole[0])
    assert np.array_equal(nz.fbm(pts, freq, 3), whole[1])

    n, nv = 4000, 300
    bary = rng.dirichlet(np.ones(3), n)
    corners = rng.integers(0, nv, (n, 3))
    tx = types.SimpleNamespace(bary=bary, corners=corners)
    for values in (rng.normal(size=nv), rng.normal(size=(nv, 3))):
        ref = np.einsum("nk,nk...->n...", bary, values[corners]).astype(np.float32)
        np.testing.assert_allclose(skin._Texels.interp(tx, values), ref, rtol=1e-6, atol=1e-6)

    _, colours = skin._segment_codes(256)
    img = skin._anny_map("segmentation/body_parts_segmentation.png", 256)[..., 2::-1]
    for labels in (["mouth_cavity", "tongue"], ["eye_front.L", "eye_back.L"]):
        ref = np.zeros(img.shape[:2], bool)
        for label in labels:
            ref |= np.all(img == np.asarray(colours[label], np.uint8), axis=-1)
        assert ref.any() and np.array_equal(skin._segment_mask(256, labels), ref)


def test_row_blocks_called_from_inside_a_block_do_not_deadlock():
    """by_rows called from inside one of its own blocks (as noise inside a condition
    applied in blocks would be) runs inline instead of waiting on its busy pool, and
    gives the one-call values. Run in a child process so that a deadlock fails the test
    by its timeout instead of hanging the suite."""
    import subprocess
    import sys
    code = """
import numpy as np
from glsynth import rows
rows.BLOCK_ROWS = 101
rows.os.cpu_count = lambda: 4
x = np.arange(5_000, dtype=float)
inner = lambda a: rows.by_rows(lambda b: np.sqrt(b), np.repeat(a, 3))[::3] + a
out = rows.by_rows(inner, x)
assert np.array_equal(out, np.sqrt(x) + x)
print("ok")
"""
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0 and run.stdout.strip() == "ok", run.stderr


def test_sun_exposed_skin_of_old_bodies_is_more_wrinkled(cache):
    """Photo-ageing: from young to old, the relief level (what brings out the shader's
    criss-cross wrinkles) rises more on the forearms than on the skin of the lower
    trunk, which clothing keeps out of the sun; melanin shields the dermis, so on black
    skin the forearms' extra rise is under half of that on fair skin."""
    extra = {}
    for ita in (60.0, -50.0):
        bodies = [make_body(seed=3, ita=ita, phenotype={"age": age}, pose="a-pose",
                            texture_size=128, cache_dir=cache, clothing="none")
                  for age in (0.6, 0.95)]
        rises = {}
        for name, parts in (("exposed", (13, 14)), ("covered", (3,))):
            levels = []
            for body in bodies:
                params = body.mesh.skin.params
                amap = cv2.resize(body.anatomy_map, params.shape[1::-1], interpolation=cv2.INTER_NEAREST)
                levels.append(np.median(params[..., 0][np.isin(amap, parts)].astype(float)))
            rises[name] = levels[1] - levels[0]
        assert rises["covered"] > 5 and rises["exposed"] > rises["covered"] + 5, (ita, rises)
        extra[ita] = rises["exposed"] - rises["covered"]
    assert extra[60.0] > 12 and extra[-50.0] < 0.5 * extra[60.0], extra


def test_old_bodies_have_dry_shins(cache):
    """Xerosis: an old body's shins are coded dry in the skin parameter map (its A channel
    below detail.XEROSIS_CODES), drier than its thighs; its face is not; a young body's
    shins are far less dry or not at all. (The bodies of the photo-ageing test above,
    from the cache.)"""
    from glsynth.assets.detail import XEROSIS_CODES
    codes = {}
    for age in (0.6, 0.95):
        body = make_body(seed=3, ita=60.0, phenotype={"age": age}, pose="a-pose", texture_size=128,
                         cache_dir=cache, clothing="none")
        params = body.mesh.skin.params
        amap = cv2.resize(body.anatomy_map, params.shape[1::-1], interpolation=cv2.INTER_NEAREST)
        codes[age] = {name: np.median(params[..., 3][np.isin(amap, parts)].astype(float))
                      for name, parts in (("shins", (7, 8)), ("thighs", (5, 6)), ("head", (1,)))}
    old, young = codes[0.95], codes[0.6]
    assert old["shins"] < 0.4 * XEROSIS_CODES and old["shins"] < old["thighs"] - 5, codes
    assert old["head"] >= XEROSIS_CODES and young["shins"] > old["shins"] + 10, codes
