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

from ..lighting import Material, PointLight, check_lights

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
        l = F.normalize(lp - position, dim=-1, eps=1e-20)
        cos_nl = (n * l).sum(-1, keepdim=True)
        # wrap lighting (Material.wrap, 0 = Lambert): max((n.l + wrap) / (1 + wrap), 0)
        diffuse = ((cos_nl + wrap) / (1 + wrap)).clamp(min=0) if wrap else cos_nl.clamp(min=0)
        light_sum = light_sum + torch.tensor(light.ambient, dtype=dt, device=dev) \
            + torch.tensor(light.diffuse, dtype=dt, device=dev) * diffuse
        r = 2 * cos_nl * n - l
        rv = (r * view_dir).sum(-1, keepdim=True).clamp(min=0)
        spec = torch.tensor(light.specular, dtype=dt, device=dev) * ks * rv.pow(material.shininess)
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


def skin_terms(position, normal, eye, lights, material):
    """The skin reflectance of ``shaders/skin.frag`` without micro-detail, in linear
    light: ``colour = albedo * light + specular`` (then sRGB-encoded by the caller).
    Diffuse: wrap lighting, wider in red than in blue; specular: GGX with Smith masking
    and Schlick's Fresnel, each light's ``diffuse`` colour its intensity for both; the
    oiliness is ``material.oil / 2`` (the map's value of a mesh without a SkinSurface
    is the shader's business; without detail the shader uses the same)."""
    dt, dev = position.dtype, position.device
    n = F.normalize(normal, dim=-1, eps=1e-30)
    v = F.normalize(eye[:, None, None, :] - position, dim=-1, eps=1e-20)
    oil = 0.5 * material.oil
    rough = material.roughness * (1 - 0.25 * oil)
    a2 = rough ** 4
    k = 0.5 * rough ** 2
    nv = (n * v).sum(-1, keepdim=True).clamp(min=1e-4)
    wrap = material.wrap * torch.tensor(WRAP_RGB, dtype=dt, device=dev)
    light_sum = torch.zeros_like(position)
    spec_sum = torch.zeros_like(position)
    for light in lights:
        lp = torch.tensor(light.position, dtype=dt, device=dev)
        l = F.normalize(lp - position, dim=-1, eps=1e-20)
        nl = (n * l).sum(-1, keepdim=True)
        diffuse = ((nl + wrap) / (1 + wrap)).clamp(min=0)
        e = torch.tensor(light.diffuse, dtype=dt, device=dev)
        light_sum = light_sum + torch.tensor(light.ambient, dtype=dt, device=dev) + e * diffuse
        h = F.normalize(l + v, dim=-1, eps=1e-20)
        nh = (n * h).sum(-1, keepdim=True).clamp(min=0)
        d = nh * nh * (a2 - 1) + 1
        D = a2 / (math.pi * d * d)
        G = nl / (nl * (1 - k) + k) * nv / (nv * (1 - k) + k)
        Fr = F0_SKIN + (1 - F0_SKIN) * (1 - (v * h).sum(-1, keepdim=True)).clamp(0, 1) ** 5
        spec = e * (math.pi * D * Fr * G / (4 * nv) * (1 + 0.4 * oil))
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
    if material.model == "skin":
        eye = torch.tensor(np.array([c.eye for c in cams]), device=pos.device, dtype=pos.dtype)
        lights = check_lights(lights) if lights is not None else None
        terms = [skin_terms(pos[i:i + 1], nrm[i:i + 1], eye[i:i + 1],
                            lights or [PointLight(c.eye)], material) for i, c in enumerate(cams)]
        light, spec = torch.cat([t[0] for t in terms]), torch.cat([t[1] for t in terms])
        img = linear_to_srgb((srgb_to_linear(texel) * light + spec).clamp(0, 1))
    else:
        light, spec = lighting(pos, nrm, cams, lights, material)
        img = (texel * light + spec).clamp(0, 1)
    img = img * gbuf.mask[..., None].to(tex.dtype)
    return img[0] if single else img


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
