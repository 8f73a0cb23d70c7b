"""Soft shadows from the main light: a blocker darkens what is behind it, only there."""
import numpy as np
import trimesh

import glsynth as gs
from glsynth.gl.renderer import Target
from shapes import random_texture


def _scene(rng):
    """A wall (the 'torso', z = 0) and a bar (the 'arm') 0.2 in front of it."""
    wall = trimesh.creation.box(extents=(1.2, 1.2, 0.02))
    bar = trimesh.creation.box(extents=(0.12, 0.8, 0.1))
    bar.apply_translation((0.0, 0.0, 0.25))
    m = trimesh.util.concatenate([wall, bar])
    v = np.asarray(m.vertices)
    uv = (v[:, :2] - v[:, :2].min(0)) / np.ptp(v[:, :2], 0)
    tex = np.full((16, 16, 3), 200, np.uint8)
    return gs.Mesh(v, m.faces, uvs=uv, texture=tex, name="wall+bar")


def test_blocked_light_darkens_only_the_shadowed_region(renderer, rng):
    mesh = _scene(rng)
    cam = gs.Camera.look_at((0.0, 0.0, 2.0), (0, 0, 0), width=renderer.width, height=renderer.height,
                            fov_deg=40)
    light = gs.PointLight((0.5, 0.0, 1.5), ambient=0.2, diffuse=0.8, specular=0.0)
    lit = renderer.render(mesh, cam, passes=("gbuffer", "rgb"), lights=[light], shadows=False)
    shad = renderer.render(mesh, cam, passes=("gbuffer", "rgb"), lights=[light], shadows=True)
    assert np.isfinite(shad["rgb"]).all()
    # where does the bar's shadow fall on the wall? intersect light->pixel with the bar
    rows, cols = np.nonzero(lit["face_id"] >= 0)
    o, d = cam.pixel_rays(rows, cols)
    t = lit["depth"][rows, cols] / (d @ np.array([0, 0, -1.0]))
    p = o + d * t[:, None]
    on_wall = np.abs(p[:, 2] - 0.01) < 1e-3
    lp = np.asarray(light.position)
    s = (0.3 - p[:, 2]) / (lp[2] - p[:, 2])  # where the ray to the light crosses z = 0.3
    q = p + (lp - p) * s[:, None]
    s2 = (0.2 - p[:, 2]) / (lp[2] - p[:, 2])
    q2 = p + (lp - p) * s2[:, None]
    blocked = on_wall & (np.abs(q[:, 0]) < 0.06) & (np.abs(q2[:, 0]) < 0.06) & (np.abs(q[:, 1]) < 0.38)
    free = on_wall & (np.minimum(np.abs(q[:, 0]), np.abs(q2[:, 0])) > 0.12)
    assert blocked.sum() > 50 and free.sum() > 50
    a = lit["rgb"][rows, cols].mean(1)
    b = shad["rgb"][rows, cols].mean(1)
    # in the umbra only the ambient term is left; away from it nothing changes
    np.testing.assert_allclose(b[blocked], 200 / 255 * 0.2, atol=0.02)
    assert (a[blocked] > b[blocked] + 0.1).all()
    np.testing.assert_allclose(b[free], a[free], atol=1e-6)


def test_shadows_off_computes_nothing(renderer, rng):
    mesh = _scene(rng)
    cam = gs.Camera.look_at((0.0, 0.0, 2.0), (0, 0, 0), width=renderer.width, height=renderer.height)
    before = {k for k in renderer._fbos if k[0] is Target.SHADOW}
    a = renderer.render(mesh, cam, passes=("rgb",), lights=[gs.PointLight((0.5, 0, 1.5))])
    assert {k for k in renderer._fbos if k[0] is Target.SHADOW} == before
    # and the image is the plain Phong image (no leftover state from a shadowed render)
    renderer.render(mesh, cam, passes=("rgb",), lights=[gs.PointLight((0.5, 0, 1.5))], shadows=True)
    b = renderer.render(mesh, cam, passes=("rgb",), lights=[gs.PointLight((0.5, 0, 1.5))])
    assert np.array_equal(a["rgb"], b["rgb"])
