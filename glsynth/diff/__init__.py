"""Differentiable texture path in torch, driven by the GL G-buffer.

Geometry is not differentiated: the G-buffer (face id, barycentrics) from
``Renderer.render(..., passes=("gbuffer",))`` fixes which surface point each pixel sees.
Everything after that is plain torch, so gradients flow from pixels to texels through
``grid_sample``. The four functions mirror nvdiffrast's split:

- ``interpolate``: per-vertex (or per-corner) attributes -> per-pixel values
- ``texture``: bilinear lookup of a texture at per-pixel UVs (same filter as the GL pass)
- ``phong``: the Phong terms of ``shaders/phong.frag``; ``skin_terms``: the skin
  reflectance of ``shaders/skin.frag`` (without its micro-detail, which is an appearance
  layer of the GL image that blending never optimises through)
- ``shade``: all of the above, the torch twin of the GL 'rgb' pass

Shapes: H x W image, B views, V vertices, F faces. Tensors may live on CPU or CUDA;
outputs follow the texture's device and dtype.
"""
from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

from ..lighting import Material, PointLight, ambient_gain, check_lights, direct_gain

__all__ = ["interpolate", "texture", "phong", "phong_terms", "skin_terms", "shade", "surface",
           "GBuffer", "srgb_to_linear", "linear_to_srgb"]


class GBuffer:
    """Torch view of one or more G-buffers: face_id (B,H,W) long, bary (B,H,W,3)."""

    def __init__(self, outs, device=None, dtype=torch.float32):
        outs = [outs] if isinstance(outs, dict) else list(outs)
        if not outs:
            raise ValueError("need at least one G-buffer")
        for o in outs:
            if "face_id" not in o or "bary" not in o:
                raise ValueError("G-buffer dict needs 'face_id' and 'bary' "
                                 "(render with passes=('gbuffer', ...))")
        self.face_id = torch.as_tensor(np.stack([o["face_id"] for o in outs]), device=device).long()
        self.bary = torch.as_tensor(np.stack([o["bary"] for o in outs]), device=device, dtype=dtype)
        self.mask = self.face_id >= 0


def interpolate(attr, faces, gbuf: GBuffer):
    """Barycentric interpolation of attributes.

    attr: (N, C) tensor; faces: (F, 3) long tensor indexing attr (vertex faces for
    per-vertex attributes, ``face_uvs`` for UVs). Returns (B, H, W, C); background
    pixels get 0.
    """
    fid = gbuf.face_id.clamp(min=0)
    corners = faces[fid]                           # B,H,W,3
    vals = attr[corners]                           # B,H,W,3,C
    out = (vals * gbuf.bary.to(attr.dtype)[..., None]).sum(-2)
    return out * gbuf.mask[..., None].to(out.dtype)


def _as_bchw(tex):
    if tex.dim() == 3:                       # H x W x C
        return tex.permute(2, 0, 1)[None]
    if tex.dim() == 4 and tex.shape[0] == 1:  # 1 x C x H x W
        return tex
    raise ValueError(f"texture must be HxWxC or 1xCxHxW, got shape {tuple(tex.shape)}")


def texture(tex, uv):
    """Bilinear texture lookup, identical to the GL sampler (LINEAR, clamp to edge).

    tex: HxWxC or 1xCxHxW float tensor (row 0 = top = v 1); uv: (B, H, W, 2) in [0, 1]
    (u right, v up). Returns (B, H, W, C). Texel centres sit at (i + 0.5) / size, which
    is grid_sample's ``align_corners=False``; 'border' padding is GL's clamp-to-edge.
    """
    t = _as_bchw(tex)
    b = uv.shape[0]
    grid = torch.stack([uv[..., 0] * 2 - 1, 1 - uv[..., 1] * 2], -1).to(t.dtype)
    out = F.grid_sample(t.expand(b, -1, -1, -1), grid, mode="bilinear",
                        padding_mode="border", align_corners=False)
    return out.permute(0, 2, 3, 1)


def phong(texel, position, normal, eye, lights, material):
    """Phong shading as in ``shaders/phong.frag`` (display-referred, clamped to [0, 1]).

    texel, position, normal: (B, H, W, 3); eye: (B, 3). Normals are normalised here.
    """
    light_sum, spec_sum = phong_terms(position, normal, eye, lights, material)
    return (texel * light_sum + spec_sum).clamp(0, 1)


def phong_terms(position, normal, eye, lights, material):
    """The texture-independent Phong factors: ``colour = texel * light + specular``
    (diffuse with the material's wrap lighting, as in ``shaders/phong.frag``).
    Useful when several textures are shaded under the same view (blending)."""
    dt, dev = position.dtype, position.device
    n = F.normalize(normal, dim=-1, eps=1e-30)
    view_dir = F.normalize(eye[:, None, None, :] - position, dim=-1, eps=1e-20)
    light_sum = torch.zeros_like(position)
    spec_sum = torch.zeros_like(position)
    ks = torch.tensor(material.specular, dtype=dt, device=dev)
    wrap = float(getattr(material, "wrap", 0.0))
    for light in lights:
        lp = torch.tensor(light.position, dtype=dt, device=dev)
        to_light = lp - position
        l = F.normalize(to_light, dim=-1, eps=1e-20)
        gain = direct_gain(to_light, light)
        cos_nl = (n * l).sum(-1, keepdim=True)
        # wrap lighting (Material.wrap, 0 = Lambert): max((n.l + wrap) / (1 + wrap), 0)
        diffuse = ((cos_nl + wrap) / (1 + wrap)).clamp(min=0) if wrap else cos_nl.clamp(min=0)
        light_sum = light_sum + torch.tensor(light.ambient, dtype=dt, device=dev) \
            * ambient_gain(n[..., 1:2], light.ambient_ground) \
            + torch.tensor(light.diffuse, dtype=dt, device=dev) * gain * diffuse
        r = 2 * cos_nl * n - l
        rv = (r * view_dir).sum(-1, keepdim=True).clamp(min=0)
        spec = torch.tensor(light.specular, dtype=dt, device=dev) * gain * ks * rv.pow(material.shininess)
        spec_sum = spec_sum + torch.where(cos_nl > 0, spec, torch.zeros_like(spec))
    return light_sum, spec_sum


def srgb_to_linear(c):
    """The sRGB transfer curve inverted (IEC 61966-2-1), as skin.frag's to_linear."""
    return torch.where(c >= 0.04045, ((c.clamp(min=0) + 0.055) / 1.055) ** 2.4, c / 12.92)


def linear_to_srgb(c):
    """The sRGB transfer curve, as skin.frag's to_srgb (c in [0, 1])."""
    return torch.where(c >= 0.0031308, 1.055 * c.clamp(min=1e-12) ** (1 / 2.4) - 0.055, c * 12.92)


F0_SKIN = 0.028   # Fresnel reflectance of skin at normal incidence (refractive index ~1.4)
WRAP_RGB = (1.0, 0.6, 0.45)   # how far each channel's diffuse wraps, relative to Material.wrap


def skin_terms(position, normal, eye, lights, material, gloss=None, geometric=None, occlusion=None):
    """The skin reflectance of ``shaders/skin.frag`` without micro-detail, in linear
    light: ``colour = albedo * light + specular`` (then sRGB-encoded by the caller).
    Diffuse: wrap lighting, wider in red than in blue; specular: GGX with Smith masking
    and Schlick's Fresnel, each light's ``diffuse`` colour its intensity for both; the
    oiliness is ``material.oil / 2`` (as the shader's without detail); ``gloss``
    (B, H, W, 1) sharpens and raises the specular lobe (decals of moist lesions).
    ``normal`` may carry a lesion's relief, which shades every channel alike (the
    shader softens only the sub-millimetre micro-relief, which this path has not);
    ``geometric``, the surface's own normal, then sets the ambient light's gain;
    ``occlusion`` (B, H, W, 1), the share of ambient light reaching the point, scales it."""
    dt, dev = position.dtype, position.device
    n = F.normalize(normal, dim=-1, eps=1e-30)
    v = F.normalize(eye[:, None, None, :] - position, dim=-1, eps=1e-20)
    oil = 0.5 * material.oil
    gloss = torch.zeros_like(position[..., :1]) if gloss is None else gloss
    rough = material.roughness * (1 - 0.25 * oil)
    rough = rough + (0.2 - rough) * gloss               # moist or tense lesions (decals)
    a2 = rough ** 4
    k = 0.5 * rough ** 2
    nv = (n * v).sum(-1, keepdim=True).clamp(min=1e-4)
    wrap = material.wrap * torch.tensor(WRAP_RGB, dtype=dt, device=dev)
    light_sum = torch.zeros_like(position)
    spec_sum = torch.zeros_like(position)
    ng = n if geometric is None else F.normalize(geometric, dim=-1, eps=1e-30)
    occlusion = 1.0 if occlusion is None else occlusion
    for light in lights:
        lp = torch.tensor(light.position, dtype=dt, device=dev)
        to_light = lp - position
        l = F.normalize(to_light, dim=-1, eps=1e-20)
        nl = (n * l).sum(-1, keepdim=True)
        diffuse = ((nl + wrap) / (1 + wrap)).clamp(min=0)
        e = torch.tensor(light.diffuse, dtype=dt, device=dev) * direct_gain(to_light, light)
        light_sum = light_sum + torch.tensor(light.ambient, dtype=dt, device=dev) \
            * ambient_gain(ng[..., 1:2], light.ambient_ground) * occlusion + e * diffuse
        h = F.normalize(l + v, dim=-1, eps=1e-20)
        nh = (n * h).sum(-1, keepdim=True).clamp(min=0)
        d = nh * nh * (a2 - 1) + 1
        D = a2 / (math.pi * d * d)
        G = nl / (nl * (1 - k) + k) * nv / (nv * (1 - k) + k)
        Fr = F0_SKIN + (1 - F0_SKIN) * (1 - (v * h).sum(-1, keepdim=True)).clamp(0, 1) ** 5
        spec = e * (math.pi * D * Fr * G / (4 * nv) * (1 + 0.4 * oil + gloss))
        spec_sum = spec_sum + torch.where(nl > 0, spec, torch.zeros_like(spec))
    return light_sum, spec_sum


def shade(outs, mesh, tex, cameras, lights=None, material=None):
    """Torch twin of the GL 'rgb' pass (without supersampling).

    outs: a G-buffer dict (or a list of them, one per view); mesh: glsynth.Mesh;
    tex: float texture HxWx3 or 1x3xHxW in [0, 1] (may require grad); cameras: a Camera
    or a list matching ``outs``; lights: list of PointLight (default: one at each
    camera, the paper's blending light); material: Phong (default) or skin (its
    reflectance without micro-detail: compare with GL renders of
    ``Material(model="skin", detail=False)``). Returns (H, W, 3) for one view,
    (B, H, W, 3) for a list; background pixels are 0.
    """
    single = isinstance(outs, dict)
    cams = [cameras] if single or not isinstance(cameras, (list, tuple)) else list(cameras)
    gbuf = GBuffer(outs, device=tex.device, dtype=tex.dtype)
    if len(cams) == 1 and gbuf.face_id.shape[0] > 1:
        cams = cams * gbuf.face_id.shape[0]
    if len(cams) != gbuf.face_id.shape[0]:
        raise ValueError(f"{len(cams)} cameras for {gbuf.face_id.shape[0]} G-buffers")
    uv, pos, nrm = surface(gbuf, mesh, device=tex.device, dtype=tex.dtype)
    texel = texture(tex, uv)[..., :3]
    material = material or Material()
    decal, alpha, aux, geometric = None, None, None, None
    if getattr(mesh, "decals", None) is not None:
        geometric = nrm
        decal, alpha, aux, nrm = decal_lookup(mesh.decals, uv, pos, nrm, cams, gbuf.mask,
                                              relief=material.model == "skin")
    if material.model == "skin":
        eye = torch.tensor(np.array([c.eye for c in cams]), device=pos.device, dtype=pos.dtype)
        lights = check_lights(lights) if lights is not None else None
        gloss = None if aux is None else aux[..., 2:3] * alpha
        occ = None
        if mesh.occlusion is not None:
            occ = interpolate(torch.as_tensor(mesh.occlusion, device=pos.device, dtype=pos.dtype)[:, None],
                              torch.as_tensor(mesh.faces, device=pos.device), gbuf)
        terms = [skin_terms(pos[i:i + 1], nrm[i:i + 1], eye[i:i + 1], lights or [PointLight(c.eye)],
                            material, None if gloss is None else gloss[i:i + 1],
                            None if geometric is None else geometric[i:i + 1],
                            None if occ is None else occ[i:i + 1])
                 for i, c in enumerate(cams)]
        light, spec = torch.cat([t[0] for t in terms]), torch.cat([t[1] for t in terms])
        albedo = srgb_to_linear(texel)
        if decal is not None:
            albedo = albedo + (srgb_to_linear(decal) - albedo) * alpha
        img = linear_to_srgb((albedo * light + spec).clamp(0, 1))
    else:
        if decal is not None:
            texel = texel + (decal - texel) * alpha
        light, spec = lighting(pos, nrm, cams, lights, material)
        img = (texel * light + spec).clamp(0, 1)
    img = img * gbuf.mask[..., None].to(tex.dtype)
    return img[0] if single else img


DECAL_SLOPE = 2.0   # pipeline.decals.SLOPE_RANGE


def _decal_pyramid(decals, name, device, dtype):
    """Mip levels (N x C x h x w tensors, 0..1) of the decal layers, each the 2x2 mean of
    the one before, rounded to half floats as GL stores every level of the half-float
    decal textures (without the rounding a sharp glossy highlight differs by 3/255);
    kept on the Decals object."""
    cache = decals.__dict__.setdefault("_torch_pyramids", {})
    key = (name, str(device), dtype)
    if key not in cache:
        def as_half(x):
            return x.to(torch.float16).to(dtype)
        arr = as_half(torch.as_tensor(getattr(decals, name), device=device).to(dtype) / 255.0)
        levels = [arr.permute(0, 3, 1, 2)]
        while levels[-1].shape[-1] > 1:
            levels.append(as_half(F.avg_pool2d(levels[-1], 2)))
        cache[key] = levels
    return cache[key]


def _sample_lod(levels, layer, st, lod):
    """Trilinear sample of one decal layer at st (N x 2, 0..1) and level of detail lod
    (N,), as GL's LINEAR_MIPMAP_LINEAR with an explicit level (textureLod)."""
    top = len(levels) - 1
    lod = lod.clamp(0, top)
    lo = lod.floor().long().clamp(max=top)
    frac = (lod - lo).unsqueeze(-1)
    grid = (st * 2 - 1).view(1, 1, -1, 2)
    out = torch.zeros(len(st), levels[0].shape[1], dtype=st.dtype, device=st.device)
    for lv in torch.unique(lo).tolist():
        sel = lo == lv
        g = grid[:, :, sel]
        a = F.grid_sample(levels[lv][layer:layer + 1], g, mode="bilinear", padding_mode="border",
                          align_corners=False)[0, :, 0].T
        b = F.grid_sample(levels[min(lv + 1, top)][layer:layer + 1], g, mode="bilinear",
                          padding_mode="border", align_corners=False)[0, :, 0].T
        out[sel] = a + (b - a) * frac[sel]
    return out


def decal_lookup(decals, uv, pos, nrm, cams, mask, relief=True):
    """The lesion decals (pipeline.decals.Decals) at each pixel, as shaders/decal.glsl
    samples them: colour (B,H,W,3) sRGB, coverage (B,H,W,1), aux (B,H,W,4) and, with
    ``relief``, the normal perturbed by the decal's relief slope (otherwise ``nrm``)."""
    dt, dev = pos.dtype, pos.device
    b, h, w = uv.shape[:3]
    colour = torch.zeros(b, h, w, 3, dtype=dt, device=dev)
    alpha = torch.zeros(b, h, w, 1, dtype=dt, device=dev)
    aux = torch.zeros(b, h, w, 4, dtype=dt, device=dev)
    aux[..., :2] = 128 / 255
    region = torch.as_tensor(decals.region.astype(np.int64), device=dev)
    rh, rw = region.shape
    col = (uv[..., 0] * rw).floor().long().clamp(0, rw - 1)
    row = ((1 - uv[..., 1]) * rh).floor().long().clamp(0, rh - 1)
    layer = torch.where(mask, region[row, col] - 1, torch.full_like(row, -1))
    cpy = {name: _decal_pyramid(decals, name, dev, dt) for name in ("colour", "aux")}
    n = F.normalize(nrm, dim=-1, eps=1e-30)
    grad = torch.zeros_like(pos)
    for bi, cam in enumerate(cams):
        eye = torch.tensor(cam.eye, dtype=dt, device=dev)
        fwd = F.normalize(torch.tensor(np.subtract(cam.target, cam.eye), dtype=dt, device=dev), dim=0)
        pixel_angle = 1.0 / float(cam.intrinsics()[1, 1])
        for k in torch.unique(layer[bi]).tolist():
            if k < 0:
                continue
            sel = layer[bi] == k
            p = pos[bi][sel]
            proj = torch.tensor(decals.projection[k], dtype=dt, device=dev)
            q = torch.cat([p, torch.ones_like(p[:, :1])], 1) @ proj.T
            st = q[:, :2] / q[:, 2:3] / decals.size
            v = F.normalize(eye - p, dim=-1, eps=1e-20)
            depth = (p - eye) @ fwd
            foot = depth * pixel_angle / (n[bi][sel] * v).sum(-1).abs().clamp(min=0.2)
            lod = torch.log2((foot / float(decals.texel[k])).clamp(min=1e-6))
            inside = ((st >= 0) & (st <= 1)).all(-1, keepdim=True).to(dt)
            c = _sample_lod(cpy["colour"], k, st, lod) * inside
            a = _sample_lod(cpy["aux"], k, st, lod)
            colour[bi][sel], alpha[bi][sel], aux[bi][sel] = c[:, :3], c[:, 3:4], a
            slope = (a[:, :2] * 255 - 128) / 127 * DECAL_SLOPE * c[:, 3:4]
            axes = torch.tensor(decals.axes[k], dtype=dt, device=dev)
            grad[bi][sel] = slope[:, :1] * axes[0] + slope[:, 1:2] * axes[1]
    if relief:
        grad = grad - n * (n * grad).sum(-1, keepdim=True)
        nrm = n - grad
    return colour, alpha, aux, nrm


def surface(gbuf: GBuffer, mesh, device=None, dtype=torch.float32):
    """Per-pixel UV (B,H,W,2), position and normal (B,H,W,3) of the visible surface."""
    faces = torch.as_tensor(mesh.faces, device=device)
    uv = interpolate(torch.as_tensor(mesh.uvs, device=device, dtype=dtype),
                     torch.as_tensor(mesh.face_uvs, device=device), gbuf)
    pos = interpolate(torch.as_tensor(mesh.vertices, device=device, dtype=dtype), faces, gbuf)
    nrm = interpolate(torch.as_tensor(mesh.vertex_normals, device=device, dtype=dtype), faces, gbuf)
    return uv, pos, nrm


def lighting(pos, nrm, cams, lights=None, material=None):
    """``phong_terms`` for a batch of views; lights=None puts the paper's blending light
    (ambient 0.5, diffuse 0.5, specular 0.025) at each camera."""
    material = material or Material()
    eye = torch.tensor(np.array([c.eye for c in cams]), device=pos.device, dtype=pos.dtype)
    if lights is not None:
        return phong_terms(pos, nrm, eye, check_lights(lights), material)
    terms = [phong_terms(pos[i:i + 1], nrm[i:i + 1], eye[i:i + 1], [PointLight(c.eye)], material)
             for i, c in enumerate(cams)]
    return torch.cat([t[0] for t in terms]), torch.cat([t[1] for t in terms])
