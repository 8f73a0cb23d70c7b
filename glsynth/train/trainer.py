"""Train ``SegNet`` on glsynth datasets with the paper's modified fuzzy Jaccard loss.

Seeded: the order of the samples in epoch e comes from (seed, e), the augmentation of
sample i in epoch e from (seed, e, i), the initial weights from the seed; a run that is
interrupted and resumed sees the same batches in the same order (the position within
the epoch is stored in the checkpoint). Checkpoints are written atomically (temporary
file in the same folder, then rename): at the end of every epoch, every
``save_every`` minutes, and when the time limit stops the run.
"""
from __future__ import annotations

import io
import logging
import math
import os
import time

import numpy as np
import torch

from ..dataset import SynthDataset
from ..errors import InputError, ModelFileError, UnavailableError
from ..io.images import write_bytes
from ..io.modelfile import load_torch_file
from . import data as D
from .loss import fuzzy_jaccard_loss, nevi_ignore_mask
from .model import SegNet, count_parameters

log = logging.getLogger(__name__)
FORMAT = "glsynth-segnet"


class TrainSet(torch.utils.data.Dataset):
    """glsynth dataset folders -> (image, seg target, anatomy target, ignore) tensors.

    Indexed by (epoch, i) so that augmentation depends only on (seed, epoch, i).
    """

    def __init__(self, roots, size=256, seed=0, augment=True):
        self.sets = [SynthDataset(r, targets=("three_class", "anatomy_groups")) for r in roots]
        self.index = [(k, j) for k, s in enumerate(self.sets) for j in range(len(s))]
        if not self.index:
            raise InputError(f"no samples in {', '.join(map(str, roots))}")
        self.size, self.seed, self.aug = size, seed, augment

    def __len__(self):
        return len(self.index)

    def load(self, i):
        k, j = self.index[i]
        item = self.sets[k][j]
        img = (item["image"].numpy().transpose(1, 2, 0) * 255).round().astype(np.uint8)
        seg = item["three_class"].numpy().astype(np.uint8)
        anat = item["anatomy_groups"].numpy().astype(np.uint8)
        nevi = nevi_ignore_mask(item["meta"], seg.shape).astype(np.uint8)
        return img, {"seg": seg, "anatomy": anat, "nevi": nevi}, item["id"]

    def __getitem__(self, key):
        epoch, i = key if isinstance(key, tuple) else (0, key)
        img, labels, _ = self.load(i)
        if self.aug:
            rng = np.random.default_rng([self.seed, epoch, i])
            img, labels = D.augment(rng, img, labels, self.size)
        else:
            img, labels = D.plain(img, labels, self.size)
        return (torch.from_numpy(D.normalise(img)),
                torch.from_numpy(labels["seg"].astype(np.int64)),
                torch.from_numpy(labels["anatomy"].astype(np.int64)),
                torch.from_numpy(labels["nevi"] == 1))


def save_checkpoint(path, state: dict):
    """torch.save, then an atomic, fsync-ed write of the bytes (glsynth.io.images)."""
    buf = io.BytesIO()
    torch.save(state, buf)
    write_bytes(path, buf.getbuffer(), durable=True)


def build_model(arch: dict) -> SegNet:
    return SegNet(n_seg=arch.get("n_seg", 3), n_anatomy=arch.get("n_anatomy", 8), width=arch.get("width", 1.0))


def read_checkpoint(path) -> dict:
    """A checkpoint written by ``train`` (read with weights_only: no code runs)."""
    ck = load_torch_file(path, "checkpoint")
    if not isinstance(ck, dict) or ck.get("format") != FORMAT:
        raise ModelFileError(f"{path}: not a glsynth segmentation checkpoint")
    return ck


def load_model(path, device="cpu"):
    """(model in eval mode, checkpoint dict) from a checkpoint written by ``train``."""
    ck = read_checkpoint(path)
    model = build_model(ck["arch"])
    model.load_state_dict(ck["model"])
    return model.to(device).eval(), ck


def init_weights(model, path):
    """Load matching weights from a local checkpoint (ours, or a plain state dict);
    parameters whose names or shapes differ keep their initial values."""
    ck = load_torch_file(path, "checkpoint or state dict")
    sd = ck.get("model", ck) if isinstance(ck, dict) else ck
    if not isinstance(sd, dict):
        raise ModelFileError(f"{path}: neither a glsynth checkpoint nor a state dict")
    own = model.state_dict()
    ok = {k: v for k, v in sd.items() if k in own and getattr(v, "shape", None) == own[k].shape}
    model.load_state_dict(ok, strict=False)
    log.info("--init %s: loaded %d of %d tensors", path, len(ok), len(own))
    return len(ok)


def _lr(base, step, total, warmup=20):
    if step < warmup:
        return base * (step + 1) / warmup
    t = min(1.0, (step - warmup) / max(1, total - warmup))
    return base * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * t)))


def train(data, out, size=256, epochs=10, batch_size=8, lr=2e-3, weight_decay=1e-4,
          device="cpu", time_limit=None, resume=False, seed=0, init=None, workers=0,
          width=1.0, anatomy_weight=1.0, save_every=5.0, augment=True, progress=True,
          max_steps=None):
    """Train and write the checkpoint `out`; returns the final checkpoint dict.

    data: one folder or a list of ``glsynth generate`` folders. time_limit: minutes for
    this invocation (None: no limit). resume: continue from `out` (its stored settings
    win over size/batch/lr/width/seed given here). max_steps: stop after this many
    optimiser steps in this invocation (for tests).
    """
    out = os.fspath(out)
    roots = [os.fspath(d) for d in ([data] if isinstance(data, (str, os.PathLike)) else data)]
    if device == "cuda" and not torch.cuda.is_available():
        raise UnavailableError("--device cuda: CUDA is not available")
    ck = None
    if os.path.exists(out):
        if not resume:
            raise FileExistsError(f"{out} exists; pass --resume to continue it or choose another --out")
        ck = read_checkpoint(out)
        h = ck["hparams"]
        size, batch_size, lr, weight_decay = h["size"], h["batch_size"], h["lr"], h["weight_decay"]
        seed, width, anatomy_weight, augment = h["seed"], h["width"], h["anatomy_weight"], h["augment"]
    hparams = {"size": size, "batch_size": batch_size, "lr": lr, "weight_decay": weight_decay,
               "seed": seed, "width": width, "anatomy_weight": anatomy_weight, "augment": augment}
    torch.manual_seed(seed)
    ds = TrainSet(roots, size=size, seed=seed, augment=augment)
    model = SegNet(width=width)
    if ck is None and init:
        init_weights(model, init)
    opt = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=weight_decay)
    epoch, pos, step, history = 0, 0, 0, []
    if ck is not None:
        model.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        epoch, pos, step, history = ck["epoch"], ck["batch_in_epoch"], ck["step"], ck["history"]
        log.info("resuming %s at epoch %d, batch %d (step %d)", out, epoch, pos, step)
    model.to(device)
    for st in opt.state.values():
        for k, v in st.items():
            if torch.is_tensor(v) and k != "step":
                st[k] = v.to(device)
    n_batches = math.ceil(len(ds) / batch_size)
    total = epochs * n_batches
    t0, last_save, steps_here = time.time(), time.time(), 0
    stopped = None
    running = {"loss": [], "seg": [], "anatomy": []}

    def state(reason):
        return {"format": FORMAT, "version": 1, "arch": model.arch, "hparams": hparams,
                "model": {k: v.detach().cpu() for k, v in model.state_dict().items()},
                "optimizer": opt.state_dict(), "epoch": epoch, "batch_in_epoch": pos, "step": step,
                "epochs_planned": epochs, "history": history, "data": roots, "n_samples": len(ds),
                "n_parameters": count_parameters(model), "preprocessing": {
                    "colour_constancy": "shades_of_gray(p=6)", "mean": D.MEAN.tolist(),
                    "std": D.STD.tolist(), "resize": "shorter side = size"},
                "saved": reason, "torch": str(torch.__version__)}

    from tqdm import tqdm
    final = None
    while epoch < epochs and stopped is None:
        order = np.random.default_rng([seed, epoch]).permutation(len(ds))
        batches = [order[b * batch_size:(b + 1) * batch_size] for b in range(n_batches)]
        sampler = [[(epoch, int(i)) for i in b] for b in batches[pos:]]
        loader = torch.utils.data.DataLoader(ds, batch_sampler=sampler, num_workers=workers)
        model.train()
        bar = tqdm(loader, desc=f"epoch {epoch + 1}/{epochs}", initial=pos, total=n_batches,
                   unit="batch", disable=not progress, leave=False)
        for img, seg, anat, ign in bar:
            img, seg, anat, ign = (t.to(device) for t in (img, seg, anat, ign))
            for g in opt.param_groups:
                g["lr"] = _lr(lr, step, total)
            o = model(img)
            loss, parts = fuzzy_jaccard_loss(o["seg"], seg, o["anatomy"], anat, ign, anatomy_weight)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            step, pos, steps_here = step + 1, pos + 1, steps_here + 1
            running["loss"].append(float(loss.detach()))
            for k in ("seg", "anatomy"):
                running[k].append(parts.get(k, 0.0))
            bar.set_postfix(loss=f"{np.mean(running['loss'][-20:]):.3f}")
            now = time.time()
            if time_limit is not None and now - t0 >= time_limit * 60:
                stopped = "time limit"
            elif max_steps is not None and steps_here >= max_steps:
                stopped = "max steps"
            if stopped:
                break
            if save_every and now - last_save >= save_every * 60:
                save_checkpoint(out, state("periodic"))
                last_save = now
        bar.close()
        if pos >= n_batches:
            history.append({"epoch": epoch + 1, "step": step,
                            **{k: float(np.mean(v)) if v else None for k, v in running.items()},
                            "seconds": round(time.time() - t0, 1)})
            log.info("epoch %d: loss %.4f", epoch + 1, history[-1]["loss"])
            if progress:
                print(f"epoch {epoch + 1}/{epochs}: loss {history[-1]['loss']:.4f} "
                      f"(seg {history[-1]['seg']:.4f}, anatomy {history[-1]['anatomy']:.4f}) "
                      f"step {step}, {time.time() - t0:.0f} s", flush=True)
            running = {k: [] for k in running}
            epoch, pos = epoch + 1, 0
        final = state(stopped or "finished")
        save_checkpoint(out, final)
        last_save = time.time()
    if final is None:  # nothing left to do (already finished, or epochs=0)
        final = state("finished")
        save_checkpoint(out, final)
    final["stopped"] = stopped
    return final
