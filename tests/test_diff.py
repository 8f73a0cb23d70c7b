"""The torch texture path against the GL shading pass, and its gradients."""
import numpy as np
import pytest
import torch

import glsynth as gs
from glsynth import diff
from glsynth.lighting import Material, PointLight
from shapes import box, plane, sphere, textured_view


def _falloff(rng, position):
    """No fall-off, or a falloff distance of 0.3-1.5 times the light's distance to the
    origin (the scene's centre), so that parts of the surface are brighter than given."""
    return 0.0 if rng.random() < 0.3 else float(np.linalg.norm(position) * rng.uniform(0.3, 1.5))


def _random_lights(rng, cam, n):
    eye = np.asarray(cam.eye)
    out = []
    for _ in range(n):
        p = eye + rng.normal(scale=0.3, size=3)
        out.append(PointLight(p, ambient=rng.uniform(0, 0.99, 3), diffuse=rng.uniform(0.2, 0.99, 3),
                              specular=rng.uniform(0, 0.5, 3), falloff_distance=_falloff(rng, p),
                              ambient_ground=rng.choice([1.0, rng.uniform(0, 1)]),
                              beam_axis=np.asarray(cam.target) - p,   # a flash's beam, or none
                              beam_exponent=rng.choice([0.0, rng.uniform(0.5, 30)])))
    return out


@pytest.mark.parametrize("trial", range(4))
def test_torch_shading_matches_gl(renderer, rng, trial):
    mesh, tex, cam = textured_view(renderer, rng, sphere if trial % 2 == 0 else box, max_texture=300)
    lights = _random_lights(rng, cam, int(rng.integers(1, 4)))
    mat = Material(specular=rng.uniform(0, 0.6, 3), shininess=rng.uniform(1, 200))
    out = renderer.render(mesh, cam, passes=("gbuffer", "rgb"), lights=lights, material=mat)
    img = diff.shade(out, mesh, torch.tensor(tex / 255.0, dtype=torch.float32), cam, lights, mat)
    fg = out["face_id"] >= 0
    assert fg.sum() > 100
    err = np.abs(img.numpy() - out["rgb"])[fg]
    assert err.max() <= 2 / 255, f"max |torch - GL| = {err.max() * 255:.2f}/255"
    assert (img.numpy()[~fg] == 0).all()


@pytest.mark.parametrize("model", ["phong", "skin"])
def test_flash_falls_off_with_the_inverse_square(renderer, rng, model):
    # a flash at height h over a plane: a point r from it gets cos = h / r of the light
    # and (d0 / r)^2 of its intensity; a flash almost on the plane is capped at
    # (1 / FALLOFF_NEAREST)^2 = 16 times; its beam (straight down) gives (h / r)^k more
    from glsynth.lighting import FALLOFF_NEAREST
    mesh = plane(rng, size=4.0).copy_with(texture=np.full((8, 8, 3), 128, np.uint8))
    h = rng.uniform(0.05, 0.5)
    d0 = h * rng.choice([rng.uniform(0.5, 2.0), rng.uniform(4.5, 8.0)])
    cam = gs.Camera.look_at((0, 0, h), (0, 0, 0), up=(0, 1, 0), width=renderer.width,
                            height=renderer.height, fov_deg=rng.uniform(60, 100))
    e = 0.6 / (d0 / max(h, FALLOFF_NEAREST * d0)) ** 2        # at most 0.6 at the centre
    k = rng.choice([0.0, rng.uniform(1, 20)])
    lights = [PointLight(cam.eye, ambient=0.0, diffuse=e, specular=0.0, falloff_distance=d0,
                         beam_axis=(0, 0, -1), beam_exponent=k)]
    mat = Material(specular=0.0) if model == "phong" else Material(model="skin", roughness=1.0, detail=False)
    out = renderer.render(mesh, cam, passes=("gbuffer", "rgb"), lights=lights, material=mat)
    fg = out["face_id"] >= 0
    corners = mesh.vertices[mesh.faces[np.maximum(out["face_id"], 0)]]
    r = np.linalg.norm(np.einsum("hwk,hwkc->hwc", out["bary"], corners) - np.array([0, 0, h]), axis=-1)
    want = e * (h / r) ** (1 + k) * (d0 / np.maximum(r, FALLOFF_NEAREST * d0)) ** 2
    if model == "phong":
        got = out["rgb"][..., 0] / (128 / 255)
    else:  # linear light; GGX with roughness 1 adds a faint, nearly flat lobe: compare shapes
        lin = lambda c: diff.srgb_to_linear(torch.as_tensor(c, dtype=torch.float64)).numpy()  # noqa: E731
        got = lin(out["rgb"][..., 0]) / lin(128 / 255)
    rel = got[fg] / want[fg]
    if model == "skin":
        rel = rel / np.median(rel)
    assert np.abs(rel - 1).max() < 0.05, np.abs(rel - 1).max()
    img = diff.shade(out, mesh, torch.tensor(mesh.texture / 255.0, dtype=torch.float32), cam, lights, mat)
    assert np.abs(img.numpy() - out["rgb"])[fg].max() <= 2 / 255


@pytest.mark.parametrize("model", ["phong", "skin"])
def test_room_ambient_is_brighter_from_above(renderer, rng, model):
    # ambient alone on a sphere at the origin (normal = position / radius): a surface
    # facing down gets `ground` of what one facing up gets, linearly in between, and the
    # mean over all directions is the light's ambient
    from glsynth.lighting import ambient_gain
    g = rng.uniform(0, 1)
    up = rng.uniform(-1, 1, 100000)
    assert abs(ambient_gain(up, g).mean() - 1) < 0.01
    assert np.isclose(ambient_gain(-1.0, g) / ambient_gain(1.0, g), g)
    mesh = sphere(rng, subdivisions=5).copy_with(texture=np.full((8, 8, 3), 200, np.uint8))
    eye = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), 1.5])
    cam = gs.Camera.look_at(eye, (0, 0, 0), width=renderer.width, height=renderer.height)
    a = rng.uniform(0.2, 0.45)
    lights = [PointLight(eye, ambient=a, diffuse=0.0, specular=0.0, ambient_ground=g)]
    mat = Material(specular=0.0) if model == "phong" else Material(model="skin", detail=False)
    out = renderer.render(mesh, cam, passes=("gbuffer", "rgb"), lights=lights, material=mat)
    fg = out["face_id"] >= 0
    corners = mesh.vertices[mesh.faces[np.maximum(out["face_id"], 0)]]
    p = np.einsum("hwk,hwkc->hwc", out["bary"], corners)
    albedo = 200 / 255 if model == "phong" else ((200 / 255 + 0.055) / 1.055) ** 2.4   # skin: linear
    want = albedo * a * ambient_gain(p[..., 1] / 0.3, g)
    got = out["rgb"][..., 0]
    if model == "skin":
        got = diff.srgb_to_linear(torch.as_tensor(got, dtype=torch.float64)).numpy()
    assert np.abs(got - want)[fg].max() < 0.012
    img = diff.shade(out, mesh, torch.tensor(mesh.texture / 255.0, dtype=torch.float32), cam, lights, mat)
    assert np.abs(img.numpy() - out["rgb"])[fg].max() <= 2 / 255


def test_default_light_is_at_the_camera(renderer, rng):
    mesh = sphere(rng)
    cam = gs.Camera.look_at((0.1, 0.2, 1.3), (0, 0, 0), width=renderer.width, height=renderer.height)
    out = renderer.render(mesh, cam, passes=("gbuffer", "rgb"))
    tex = torch.tensor(mesh.texture / 255.0)
    img = diff.shade(out, mesh, tex, cam)
    fg = out["face_id"] >= 0
    assert np.abs(img.numpy() - out["rgb"])[fg].max() <= 2 / 255


def test_batched_views_and_channels_first(renderer, rng):
    mesh = sphere(rng)
    cams = [gs.Camera.look_at(e, (0, 0, 0), width=renderer.width, height=renderer.height)
            for e in ((0, 0, 1.2), (0.9, 0.3, 0.6), (-0.5, 0.8, 0.7))]
    outs = [renderer.render(mesh, c, passes=("gbuffer",)) for c in cams]
    tex = torch.tensor(mesh.texture / 255.0, dtype=torch.float32)
    batch = diff.shade(outs, mesh, tex.permute(2, 0, 1)[None], cams)
    assert batch.shape == (3, renderer.height, renderer.width, 3)
    for i, (o, c) in enumerate(zip(outs, cams)):
        single = diff.shade(o, mesh, tex, c)
        torch.testing.assert_close(batch[i], single)


def test_gradcheck_float64(renderer, rng):
    mesh = sphere(rng, subdivisions=2)
    cam = gs.Camera.look_at((0.0, 0.1, 1.0), (0, 0, 0), width=renderer.width, height=renderer.height)
    out = renderer.render(mesh, cam, passes=("gbuffer",))
    # a small crop keeps gradcheck's finite differences cheap
    r0, c0 = renderer.height // 2 - 3, renderer.width // 2 - 3
    crop = {k: v[r0:r0 + 6, c0:c0 + 6] for k, v in out.items()}
    tex = torch.tensor(rng.random((8, 8, 3)), dtype=torch.float64, requires_grad=True)
    lights = [PointLight(cam.eye, ambient=0.4, diffuse=0.5, specular=0.0)]  # no clamping at 1
    assert torch.autograd.gradcheck(lambda t: diff.shade(crop, mesh, t, cam, lights), (tex,),
                                    eps=1e-6, atol=1e-5)


def test_gradient_only_on_sampled_texels(renderer, rng):
    mesh = sphere(rng)
    th, tw = 64, 64
    cam = gs.Camera.look_at((0.2, 0.0, 1.0), (0, 0, 0), width=renderer.width, height=renderer.height)
    out = renderer.render(mesh, cam, passes=("gbuffer",))
    tex = torch.tensor(rng.random((th, tw, 3)), dtype=torch.float32, requires_grad=True)
    img = diff.shade(out, mesh, tex, cam, [PointLight(cam.eye, ambient=0.3, diffuse=0.3, specular=0.0)])
    img.sum().backward()
    grad = tex.grad.abs().sum(-1).numpy()
    # texels that some visible pixel's bilinear footprint touches
    fg = out["face_id"] >= 0
    uv = out["uv"][fg]
    x = uv[:, 0] * tw - 0.5
    y = (1 - uv[:, 1]) * th - 0.5
    touched = np.zeros((th, tw), bool)
    for dx in (0, 1):
        for dy in (0, 1):
            xi = np.clip(np.floor(x).astype(int) + dx, 0, tw - 1)
            yi = np.clip(np.floor(y).astype(int) + dy, 0, th - 1)
            touched[yi, xi] = True
    assert (grad[~touched] == 0).all()
    assert (grad[touched] > 0).mean() > 0.9
    assert (grad > 0).sum() < th * tw  # the back of the sphere gets nothing


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_shade_on_cuda_matches_cpu(renderer, rng):
    mesh = sphere(rng)
    cam = gs.Camera.look_at((0, 0, 1.3), (0, 0, 0), width=renderer.width, height=renderer.height)
    out = renderer.render(mesh, cam, passes=("gbuffer",))
    tex = torch.tensor(mesh.texture / 255.0, dtype=torch.float32)
    cpu = diff.shade(out, mesh, tex, cam)
    gpu = diff.shade(out, mesh, tex.cuda(), cam)
    torch.testing.assert_close(gpu.cpu(), cpu, atol=1e-5, rtol=1e-5)


def test_bad_texture_shape(renderer, rng):
    mesh = sphere(rng)
    cam = gs.Camera.look_at((0, 0, 1.3), (0, 0, 0), width=renderer.width, height=renderer.height)
    out = renderer.render(mesh, cam, passes=("gbuffer",))
    with pytest.raises(ValueError, match="texture must be"):
        diff.shade(out, mesh, torch.zeros(2, 3, 8, 8), cam)
    with pytest.raises(ValueError, match="gbuffer"):
        diff.shade({"rgb": out["face_id"]}, mesh, torch.zeros(8, 8, 3), cam)
