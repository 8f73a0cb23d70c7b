"""Blend pasted lesions into the texture (paper section 3.2).

``deep``: optimise the lesion's texels T_b (initialised from T_p) through the torch
texture path with the paper's loss (content + style on CNN features, Laplacian
gradient term, total variation), over a padded box around the lesion, re-rasterising
only that box with GL from a camera perturbed at every step.

``poisson`` (``poisson.py``, which needs no torch) and ``paste`` (keep T_p) are the other
methods. Only texels under the lesion mask ever change.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from .. import diff
from ..camera import Camera
from ..config import BlendConfig
from ..errors import GlsynthError
from .paste import PastedTextures, Placement
from .poisson import crop_box

log = logging.getLogger(__name__)


class BlendError(GlsynthError, RuntimeError):
    """The blend produced a non-finite value or cannot run with these settings."""


_BLEND = BlendConfig()  # the keys' defaults (glsynth/config.py)


@dataclass
class BlendSettings:
    """What the deep blend reads: the ``blend`` keys (documented in glsynth/config.py;
    the defaults are the config's) and the float type it optimises in."""
    steps: int = _BLEND.steps
    lr: float = _BLEND.lr
    optimizer: str = _BLEND.optimizer
    content: float = _BLEND.content
    style: float = _BLEND.style
    gradient: float = _BLEND.gradient
    tv: float = _BLEND.tv
    pad: int = _BLEND.pad
    perturb_deg: float = _BLEND.perturb_deg
    perturb_w: float = _BLEND.perturb_w
    dtype: str = "float32"
    threads: int = _BLEND.threads   # torch threads while blending (see ``DeepBlender.blend``)

    @classmethod
    def from_config(cls, b: BlendConfig) -> BlendSettings:
        return cls(b.steps, b.lr, b.optimizer, b.content, b.style, b.gradient, b.tv, b.pad,
                   b.perturb_deg, b.perturb_w, threads=b.threads)

    @property
    def needs_features(self):
        return self.content > 0 or self.style > 0


_LAPLACE = torch.tensor([[0.0, 1.0, 0.0], [1.0, -4.0, 1.0], [0.0, 1.0, 0.0]])


def laplacian(x):
    """Per-channel 5-point Laplacian of (B, C, H, W), zero-padded."""
    k = _LAPLACE.to(x)[None, None].expand(x.shape[1], 1, 3, 3)
    return F.conv2d(x, k, padding=1, groups=x.shape[1])


def gram(f):
    """Gram matrix of (B, C, H, W) features normalised by C*H*W (Gatys et al.), so its
    entries stay O(feature^2) whatever the crop size: no overflow at lambda_s = 1e9."""
    b, c, h, w = f.shape
    f = f.reshape(b, c, h * w)
    return f @ f.transpose(1, 2) / (c * h * w)


def total_variation(x):
    """Anisotropic total variation of (B, C, H, W), *summed* over the crop (every
    channel and pixel pair), as DermSynth3D's code defines it: lambda_TV = 1e-4 is
    calibrated for a sum over a ~100-200 px crop, so a mean made the term ~1e5 times
    weaker than the paper's."""
    return (x[..., 1:, :] - x[..., :-1, :]).abs().sum() + (x[..., :, 1:] - x[..., :, :-1]).abs().sum()


def blend_loss(b, v_T, v_Tp, v_Td, m, s: BlendSettings, extractor):
    """Eq. 5 of the paper on (1, 3, H, W) crops; m is the lesion mask (1, 1, H, W).
    Returns (total, dict of unweighted terms). Terms with zero weight are not computed."""
    terms = {}
    if s.content > 0 or s.style > 0:
        fb_c, fb_s = extractor(b * m)
        if s.content > 0:
            with torch.no_grad():
                ft_c, _ = extractor(v_Tp * m)
            terms["content"] = F.mse_loss(fb_c, ft_c)
        if s.style > 0:
            with torch.no_grad():
                _, ft_s = extractor(v_T * m)
            terms["style"] = sum(F.mse_loss(gram(a), gram(t)) for a, t in zip(fb_s, ft_s)) / len(fb_s)
    if s.gradient > 0:
        # Zhang et al.'s target: the dilated lesion's Laplacian inside the mask, the
        # skin's outside. Masking after the Laplacian (as their code does) keeps the
        # mask's own edge out of the target; the dilated lesion T_d brings its
        # surrounding skin, so the boundary gradients are the photo's own.
        target = m * laplacian(v_Td) + (1 - m) * laplacian(v_T)
        terms["gradient"] = 0.5 * F.mse_loss(laplacian(b), target)
    if s.tv > 0:
        # over the composite crop, as the original: the lesion's own variation and its
        # step to the surrounding skin (the skin outside the mask is fixed)
        terms["tv"] = total_variation(b)
    weights = {"content": s.content, "style": s.style, "gradient": s.gradient, "tv": s.tv}
    total = sum(weights[k] * v for k, v in terms.items()) if terms else b.sum() * 0
    return total, terms


def perturbed_camera(placement: Placement, rng, s: BlendSettings) -> Camera:
    cam = Camera.from_dict(placement.camera)
    point = np.asarray(placement.camera["point"])
    normal = np.asarray(placement.camera["normal"])
    w = placement.camera["w"] * (1 + rng.uniform(-s.perturb_w, s.perturb_w))
    tilt = math.radians(rng.uniform(0, s.perturb_deg))
    ortho = np.cross(normal, rng.normal(size=3))
    ortho /= max(np.linalg.norm(ortho), 1e-12)
    direction = normal * math.cos(tilt) + ortho * math.sin(tilt)
    return Camera.from_surface(point, direction, w, fov_deg=cam.fov_deg, width=cam.width,
                               height=cam.height)


class DeepBlender:
    """Optimises T_b lesion by lesion (``blend``), sharing the float textures."""

    def __init__(self, renderer, mesh, pasted: PastedTextures, s: BlendSettings, extractor=None,
                 device="cpu"):
        self.r, self.mesh, self.pasted, self.s = renderer, mesh, pasted, s
        self.dtype = getattr(torch, s.dtype)
        self.device = torch.device(device)
        if s.needs_features and extractor is None:
            raise BlendError("content/style weights are non-zero but no feature extractor was given")
        self.extractor = extractor.to(self.device, self.dtype) if extractor is not None else None
        to_t = lambda a: torch.as_tensor(a, device=self.device).to(self.dtype) / 255  # noqa: E731
        self.T, self.Tp, self.Td = to_t(pasted.original), to_t(pasted.pasted), to_t(pasted.dilated)
        self.Tb = self.Tp.clone()
        self.history = {}

    def blend(self, placement: Placement, rng, torch_seed=0):
        """Optimise one lesion's texels; returns the per-step losses. Runs on ``threads``
        torch threads, whatever the process uses otherwise: torch's CPU convolutions
        and sums round differently for different thread counts, and a run must give
        the same texture for any number of workers (each gets a share of the cores)."""
        previous = torch.get_num_threads()
        torch.set_num_threads(self.s.threads)
        try:
            return self._blend(placement, rng, torch_seed)
        finally:
            torch.set_num_threads(previous)

    def _blend(self, placement: Placement, rng, torch_seed):
        s, k = self.s, placement.instance
        torch.manual_seed(torch_seed)
        tex_h, tex_w = self.pasted.instances.shape
        # the optimised texels: the lesion's box (+1 texel for bilinear footprints)
        tx0, ty0, tx1, ty1 = placement.texel_box
        tx0, ty0 = max(tx0 - 1, 0), max(ty0 - 1, 0)
        tx1, ty1 = min(tx1 + 1, tex_w), min(ty1 + 1, tex_h)
        keep = torch.as_tensor(self.pasted.instances[ty0:ty1, tx0:tx1] == k, device=self.device)
        keep = keep[..., None].to(self.dtype)
        base = self.Tb[ty0:ty1, tx0:tx1].clone()
        param = base.clone().requires_grad_(True)
        view = Camera.from_dict(placement.camera)
        cx0, cy0, cx1, cy1 = crop_box(placement, view.width, s.pad)
        if s.optimizer == "lbfgs":
            opt = torch.optim.LBFGS([param], lr=s.lr, max_iter=1, history_size=20,
                                    line_search_fn="strong_wolfe")
        else:
            opt = torch.optim.Adam([param], lr=s.lr)
        losses, t0 = [], time.perf_counter()
        for step in range(s.steps):
            cam = view if s.optimizer == "lbfgs" else perturbed_camera(placement, rng, s)
            batch = self._view_batch(cam.crop(cx0, cy0, cx1 - cx0, cy1 - cy0), k)
            if batch is None:
                continue

            def closure():
                opt.zero_grad()
                local = keep * param + (1 - keep) * base
                total, terms = self._loss(batch, local, (tx0, ty0, tx1, ty1))
                if not torch.isfinite(total):
                    raise BlendError(f"lesion {placement.lesion_id}: non-finite blend loss at step "
                                     f"{step} ({ {n: float(v.detach()) for n, v in terms.items()} })")
                total.backward()
                if not torch.isfinite(param.grad).all():
                    raise BlendError(f"lesion {placement.lesion_id}: non-finite gradient at step {step}")
                closure.terms = terms
                return total
            total = opt.step(closure)
            with torch.no_grad():
                param.clamp_(0, 1)
            losses.append({"step": step, "total": float(total.detach()),
                           **{n: float(v.detach()) for n, v in closure.terms.items()}})
        with torch.no_grad():
            self.Tb[ty0:ty1, tx0:tx1] = keep * param + (1 - keep) * base
        self.history[k] = {"losses": losses, "seconds": time.perf_counter() - t0}
        return losses

    def _view_batch(self, cam, k):
        out = self.r.render(self.mesh, cam, passes=("gbuffer", "labels"),
                            label_texture=self.pasted.instances)
        m = out["labels"] == k
        if not m.any():
            return None
        gbuf = diff.GBuffer(out, device=self.device, dtype=self.dtype)
        uv, pos, nrm = diff.surface(gbuf, self.mesh, device=self.device, dtype=self.dtype)
        light, spec = diff.lighting(pos, nrm, [cam])
        fg = gbuf.mask[..., None].to(self.dtype)
        shade = lambda t: ((t * light + spec).clamp(0, 1) * fg)  # noqa: E731
        with torch.no_grad():
            v = {name: shade(diff.texture(t, uv)) for name, t in
                 (("T", self.T), ("Tp", self.Tp), ("Td", self.Td))}
        mask = torch.as_tensor(m, device=self.device)[None, None].to(self.dtype)
        return {"uv": uv, "light": light, "spec": spec, "fg": fg, "m": mask, **v}

    def _loss(self, batch, local, box):
        tx0, ty0, tx1, ty1 = box
        tex_h, tex_w = self.pasted.instances.shape
        uv = batch["uv"]
        # sample the local box: texel index coords -> box-normalised grid
        gx = (uv[..., 0] * tex_w - tx0) / (tx1 - tx0) * 2 - 1
        gy = ((1 - uv[..., 1]) * tex_h - ty0) / (ty1 - ty0) * 2 - 1
        texel = F.grid_sample(local.permute(2, 0, 1)[None], torch.stack([gx, gy], -1),
                              mode="bilinear", padding_mode="border", align_corners=False)
        texel = texel.permute(0, 2, 3, 1)
        v_tb = (texel * batch["light"] + batch["spec"]).clamp(0, 1) * batch["fg"]
        nchw = lambda x: x.permute(0, 3, 1, 2)  # noqa: E731
        m = batch["m"]
        b = m * nchw(v_tb) + (1 - m) * nchw(batch["T"])
        return blend_loss(b, nchw(batch["T"]), nchw(batch["Tp"]), nchw(batch["Td"]), m, self.s,
                          self.extractor)

    def result(self) -> np.ndarray:
        return np.clip(np.round(self.Tb.detach().cpu().numpy() * 255), 0, 255).astype(np.uint8)
