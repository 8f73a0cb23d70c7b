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

import cv2
import numpy as np
import torch

from .. import dataformat as fmt
from ..dataset import SynthDataset
from ..errors import InputError, ModelFileError, UnavailableError
from ..io.images import write_bytes
from ..io.modelfile import load_torch_file
from . import data as D
from .loss import SKIN_LOSSES, fuzzy_jaccard_loss, nevi_ignore_mask, seg_jaccard_loss
from .model import SegNet, count_parameters

log = logging.getLogger(__name__)
FORMAT = "glsynth-segnet"


class RealSet:
    """Real photographs with masks as training samples: target 0 lesion, 1 skin,
    2 non-skin from the Fitzpatrick17k layout's lesions.png / nonskin.png (``pairs``: the
    lesion mask only, everything else ignored); no anatomy (ignored). Images are decoded
    once and kept at up to 3x the training size (enough for the zoom augmentation)."""

    def __init__(self, root, layout="fitz17k", size=256):
        from .evaluate import read_real
        self.root, self.items = os.fspath(root), []
        for sid, rgb, truth in read_real(root, layout):
            keep = min(1.0, 3 * size / min(rgb.shape[:2]))
            if keep < 1:
                dsize = (round(rgb.shape[1] * keep), round(rgb.shape[0] * keep))
                rgb = cv2.resize(rgb, dsize, interpolation=cv2.INTER_AREA)
                truth = cv2.resize(truth, dsize, interpolation=cv2.INTER_NEAREST)
            truth = np.where(truth == 3, D.IGNORE, truth).astype(np.uint8)
            self.items.append((sid, rgb, truth))

    def __len__(self):
        return len(self.items)

    def load(self, i):
        sid, rgb, truth = self.items[i]
        none = np.full(truth.shape, D.IGNORE, np.uint8)
        return rgb, {"seg": truth, "anatomy": none, "nevi": np.zeros(truth.shape, np.uint8)}, sid


class TrainSet(torch.utils.data.Dataset):
    """glsynth dataset folders (and optionally a RealSet) -> (image, seg target, anatomy
    target, ignore) tensors.

    Indexed by (epoch, source, i), source 0 synthetic and 1 real, so that augmentation
    depends only on (seed, epoch, source, i) (synthetic samples: (seed, epoch, i)).
    Decoded synthetic samples (uint8 image and label maps) are kept in memory up to
    ``cache_gb``: a training run passes over the same images many times, and decoding
    their PNGs cost about a third of a CPU training step. The cache lives in the process
    that loads, so it pays with the default ``workers=0``.
    """

    def __init__(self, roots, size=256, seed=0, augment=True, real=None, cache_gb=4.0):
        self.sets = [SynthDataset(r, targets=("three_class", "anatomy_groups")) for r in roots]
        self.index = [(k, j) for k, s in enumerate(self.sets) for j in range(len(s))]
        self.real = real
        if not self.index and not (real and len(real)):
            raise InputError(f"no samples in {', '.join(map(str, roots)) or 'the training data'}")
        self.size, self.seed, self.aug = size, seed, augment
        self.cache, self.cache_left = {}, int(cache_gb * 2**30)

    def __len__(self):
        return len(self.index)

    def load(self, i):
        """(uint8 image, {"seg", "anatomy", "nevi"} uint8 maps, sample id) of sample i."""
        k, j = self.index[i]
        sid = self.sets[k].ids[j]
        if i in self.cache:
            img, seg, anat, nevi = self.cache[i]
        else:
            run = self.sets[k].run
            img = run.image(sid)
            seg = fmt.three_class(run.layer(sid, "semantic"))
            anat = fmt.group_labels(run.layer(sid, "anatomy"))
            nevi = nevi_ignore_mask(run.record(sid), seg.shape)
            nevi = nevi.astype(np.uint8) if nevi.any() else None
            size = img.nbytes + seg.nbytes + anat.nbytes + (nevi.nbytes if nevi is not None else 0)
            if size <= self.cache_left:
                for a in (img, seg, anat, nevi):
                    if a is not None:
                        a.flags.writeable = False   # shared by every later epoch: never edit
                self.cache[i], self.cache_left = (img, seg, anat, nevi), self.cache_left - size
        if nevi is None:
            nevi = np.zeros(seg.shape, np.uint8)
        return img, {"seg": seg, "anatomy": anat, "nevi": nevi}, sid

    def __getitem__(self, key):
        """key: (epoch, source, i) from ``epoch_batches``."""
        epoch, source, i = key
        img, labels, _ = self.real.load(i) if source else self.load(i)
        if self.aug:
            rng = np.random.default_rng([self.seed, epoch, i] if not source else [self.seed, epoch, 1, i])
            img, labels = D.augment(rng, img, labels, self.size)
        else:
            img, labels = D.plain(img, labels, self.size)
        return (torch.from_numpy(D.normalise(img)),
                torch.from_numpy(labels["seg"].astype(np.int64)),
                torch.from_numpy(labels["anatomy"].astype(np.int64)),
                torch.from_numpy(labels["nevi"] == 1))


def epoch_batches(n_synth, n_real, batch_size, real_ratio, seed, epoch) -> list:
    """The batches of one epoch as lists of (source, index) keys (source 0 synthetic,
    1 real), drawn from (seed, epoch). An epoch is one pass over the synthetic samples;
    with real samples as well, each batch holds ``round(real_ratio * batch_size)`` of
    them (at least 1 and at most batch_size - 1), drawn without repeats until the real
    set is used up, then again. Without synthetic samples an epoch is one pass over the
    real ones."""
    if n_synth == 0 or (n_real and real_ratio >= 1):
        order = np.random.default_rng([seed, epoch, 1]).permutation(n_real)
        return [[(1, int(i)) for i in order[b:b + batch_size]] for b in range(0, n_real, batch_size)]
    order = np.random.default_rng([seed, epoch]).permutation(n_synth)
    if not n_real or real_ratio <= 0:
        return [[(0, int(i)) for i in order[b:b + batch_size]] for b in range(0, n_synth, batch_size)]
    k_real = int(min(max(round(real_ratio * batch_size), 1), batch_size - 1))
    k_synth = batch_size - k_real
    n_batches = math.ceil(n_synth / k_synth)
    rng = np.random.default_rng([seed, epoch, 1])
    real = np.concatenate([rng.permutation(n_real) for _ in range(math.ceil(n_batches * k_real / n_real))])
    return [[(0, int(i)) for i in order[b * k_synth:(b + 1) * k_synth]]
            + [(1, int(i)) for i in real[b * k_real:(b + 1) * k_real]] for b in range(n_batches)]


def save_checkpoint(path, state: dict):
    """torch.save, then an atomic, fsync-ed write of the bytes (glsynth.io.images)."""
    buf = io.BytesIO()
    torch.save(state, buf)
    write_bytes(path, buf.getbuffer(), durable=True)


def build_model(arch: dict) -> SegNet:
    return SegNet(n_seg=arch.get("n_seg", 3), n_anatomy=arch.get("n_anatomy", 8),
                  width=arch.get("width", 1.0), depth=arch.get("depth", 0))


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


class WeightAverage:
    """Exponential moving average of a model's weights (and batch-norm statistics),
    used for validation, checkpoint selection and the exported model.

    The last steps of a short CPU run move the weights a lot from batch to batch: two
    runs that differ only in their seed score very differently on real photographs.
    Averaging over roughly the last ``1 / (1 - decay)`` steps smooths that out. The decay
    ramps up as ``min(decay, (1 + step) / (10 + step))`` so that early averages are not
    dominated by the random initial weights."""

    def __init__(self, model, decay: float, state=None):
        """Start from ``state`` (a state dict, e.g. a checkpoint's average) or else from
        the model's current weights."""
        self.decay = float(decay)
        start = model.state_dict() if state is None else state
        self.state = {k: v.detach().clone() for k, v in start.items()}

    @torch.no_grad()
    def update(self, model, step: int):
        d = min(self.decay, (1 + step) / (10 + step))
        for k, v in model.state_dict().items():
            avg = self.state[k]
            if avg.is_floating_point():
                avg.mul_(d).add_(v.detach(), alpha=1 - d)
            else:  # batch counters
                avg.copy_(v)

    def swap(self, model):
        """Exchange the model's weights with the averaged ones (call again to undo)."""
        live = {k: v.detach().clone() for k, v in model.state_dict().items()}
        model.load_state_dict(self.state)
        self.state = live


def prefetched(batches, depth=2):
    """Iterate ``batches`` ``depth`` batches ahead in the pipeline's helper thread
    (``Prefetcher``): with ``workers=0`` the loader decodes and augments (OpenCV and
    NumPy, which release the GIL) while the network computes, instead of between its
    steps; the batches and their order are the same. Closing the generator (or leaving
    its loop) drops the batches not begun."""
    from ..pipeline.prefetch import Prefetcher
    it, end, pool = iter(batches), object(), Prefetcher()
    try:
        for k in range(depth):
            pool.start(k, next, it, end)
        k = 0
        while (b := pool.get(k, next, it, end)) is not end:
            pool.start(k + depth, next, it, end)
            yield b
            k += 1
    finally:
        pool.close()


def _lr(base, step, total, warmup=20):
    if step < warmup:
        return base * (step + 1) / warmup
    t = min(1.0, (step - warmup) / max(1, total - warmup))
    return base * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * t)))


class Validator:
    """Scores a model on real validation images (checkpoint selection, as the paper does:
    the lowest fuzzy Jaccard loss). Each image is preprocessed as ``evaluate`` does
    (shorter side = the training size) and its truth resized to match (nearest)."""

    def __init__(self, root, layout="fitz17k", size=256, skin_loss="paper"):
        from .evaluate import read_real
        self.root, self.items, self.skin_loss = os.fspath(root), [], skin_loss
        for sid, rgb, truth in read_real(root, layout):
            x = D.preprocess(rgb, size)
            t = cv2.resize(truth, (x.shape[2], x.shape[1]), interpolation=cv2.INTER_NEAREST)
            self.items.append((sid, torch.from_numpy(x), torch.from_numpy(t.astype(np.int64))))
        self.classes = ("lesion", "skin", "nonskin") if layout == "fitz17k" else ("lesion",)

    @torch.no_grad()
    def __call__(self, model, device="cpu") -> dict:
        """{"loss": mean per-image seg loss, class: mean per-image Jaccard}."""
        from .metrics import jaccard
        was_training = model.training
        model.eval()
        losses, js = [], {c: [] for c in self.classes}
        for _, x, t in self.items:
            logits = model(x[None].to(device))["seg"]
            target = torch.where(t == 3, torch.full_like(t, D.IGNORE), t)[None].to(device)
            losses.append(float(seg_jaccard_loss(torch.softmax(logits, 1), target, skin_loss=self.skin_loss)))
            pred = logits.argmax(1)[0].cpu().numpy()
            for k, c in enumerate(self.classes):
                js[c].append(jaccard(pred == k, t.numpy() == k))
        model.train(was_training)
        return {"loss": float(np.mean(losses)), **{c: float(np.mean(v)) for c, v in js.items()}}


def best_path(out) -> str:
    """Where the checkpoint chosen on the validation set goes: model.pt -> model.best.pt."""
    root, ext = os.path.splitext(os.fspath(out))
    return f"{root}.best{ext or '.pt'}"


def train(data, out, size=256, epochs=10, batch_size=8, lr=2e-3, weight_decay=1e-4,
          device="cpu", time_limit=None, resume=False, seed=0, init=None, workers=0,
          width=1.0, depth=0, anatomy_weight=1.0, save_every=5.0, augment=True, progress=True,
          max_steps=None, val=None, val_layout="fitz17k", val_every=None, real_train=None,
          real_layout="fitz17k", real_ratio=0.25, steps=None, ema=0.999, cache_gb=4.0,
          fit_minutes=None, skin_loss="paper"):
    """Train and write the checkpoint `out`; returns the final checkpoint dict.

    data: one folder or a list of ``glsynth generate`` folders (may be empty with
    ``real_train``). time_limit: minutes for this invocation (None: no limit). resume:
    continue from `out` (its stored settings win over size/batch/lr/width/seed given
    here). max_steps: stop after this many optimiser steps in this invocation. steps: the
    whole run's length in optimiser steps (the learning-rate schedule ends there), instead
    of ``epochs`` passes over the data.
    ema: decay of the weight average (``WeightAverage``) that validation, the best
    checkpoint and the checkpoint's ``model`` use (0: the last weights). The raw weights
    are kept in ``train_model`` for --resume.
    val: a folder of real images (``val_layout``) scored every ``val_every`` steps
    (default: 8 times an epoch, at most every 250 steps) and at the end; the weights with
    the lowest validation loss are also written to ``best_path(out)``.
    fit_minutes: with ``steps``, fit the run's length to end within this many minutes
    of this invocation's start: at the end of each epoch from the second on, from the
    median time per step of the epochs after the first (which fills the sample cache);
    longer only while the schedule is in its first half, shorter at any time. A plan
    from a short timing misjudged long runs' steps by up to a quarter, and one fitted
    once, from the second epoch, left 40% of a yardstick's budget unused when another
    process slowed that epoch 4x. Fitted only in the first half, six of seven
    yardstick runs met the time limit at 80-96% of their plan, as steps slowed later.
    cache_gb: memory for decoded synthetic samples (``TrainSet``).
    skin_loss: "paper" (the skin channel ignores lesion pixels, appendix C) or
    "exclusive" (they count against skin, as the evaluation scores them; loss.py).
    real_train: a folder of real training images mixed into every batch at
    ``real_ratio`` (staged training: ``init`` from a synthetic-pretrained checkpoint
    with real images only).
    """
    out = os.fspath(out)
    roots = [os.fspath(d) for d in ([data] if isinstance(data, (str, os.PathLike)) else (data or []))]
    if device == "cuda" and not torch.cuda.is_available():
        raise UnavailableError("--device cuda: CUDA is not available")
    if not 0 <= real_ratio <= 1:
        raise InputError(f"real_ratio must be in [0, 1], got {real_ratio}")
    ck, fitted = None, False
    if os.path.exists(out):
        if not resume:
            raise FileExistsError(f"{out} exists; pass --resume to continue it or choose another --out")
        ck = read_checkpoint(out)
        h = ck["hparams"]
        size, batch_size, lr, weight_decay = h["size"], h["batch_size"], h["lr"], h["weight_decay"]
        seed, width, anatomy_weight, augment = h["seed"], h["width"], h["anatomy_weight"], h["augment"]
        depth, real_ratio = h.get("depth", 0), h.get("real_ratio", real_ratio)
        steps, ema, fitted = h.get("steps", steps), h.get("ema", 0.0), h.get("fitted", False)
        fit_minutes = None if fitted else fit_minutes
        skin_loss = h.get("skin_loss", "paper")
    hparams = {"size": size, "batch_size": batch_size, "lr": lr, "weight_decay": weight_decay,
               "seed": seed, "width": width, "depth": depth, "anatomy_weight": anatomy_weight,
               "augment": augment, "real_ratio": real_ratio, "steps": steps, "ema": ema,
               "fitted": fitted, "skin_loss": skin_loss}
    if not 0 <= ema < 1:
        raise InputError(f"ema must be in [0, 1), got {ema}")
    if skin_loss not in SKIN_LOSSES:
        raise InputError(f"skin_loss must be one of {SKIN_LOSSES}, got {skin_loss!r}")
    torch.manual_seed(seed)
    real = RealSet(real_train, real_layout, size) if real_train else None
    # loader processes start afresh each epoch, so a cache in them would only cost memory
    ds = TrainSet(roots, size=size, seed=seed, augment=augment, real=real,
                  cache_gb=cache_gb if workers == 0 else 0.0)
    validator = Validator(val, val_layout, size, skin_loss) if val else None
    model = SegNet(width=width, depth=depth)
    if ck is None and init:
        init_weights(model, init)
    opt = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=weight_decay)
    epoch, pos, step, history, val_history, best = 0, 0, 0, [], [], None
    average = None
    if ck is not None:
        model.load_state_dict(ck.get("train_model", ck["model"]))
        if ema:
            average = WeightAverage(model, ema, state=ck["model"])
        opt.load_state_dict(ck["optimizer"])
        epoch, pos, step, history = ck["epoch"], ck["batch_in_epoch"], ck["step"], ck["history"]
        val_history, best = ck.get("val_history", []), ck.get("best")
        log.info("resuming %s at epoch %d, batch %d (step %d)", out, epoch, pos, step)
    model.to(device)
    if ema and average is None:
        average = WeightAverage(model, ema)
    if average is not None:
        average.state = {k: v.to(device) for k, v in average.state.items()}
    for st in opt.state.values():
        for k, v in st.items():
            if torch.is_tensor(v) and k != "step":
                st[k] = v.to(device)
    n_real = len(real) if real else 0

    def plan(e):
        return epoch_batches(len(ds), n_real, batch_size, real_ratio, seed, e)
    n_batches = len(plan(0))
    if steps is not None:
        if steps < 1:
            raise ValueError(f"steps must be >= 1, got {steps}")
        epochs = math.ceil(steps / n_batches)
    total = epochs * n_batches if steps is None else steps
    if val_every is None:
        val_every = max(1, min(250, math.ceil(n_batches / 8)))
    t0, last_save, steps_here = time.time(), time.time(), 0
    epoch_ends = []   # (time, step) at the ends of this invocation's epochs
    stopped = None
    running = {"loss": [], "seg": [], "anatomy": []}

    def cpu(sd):
        return {k: v.detach().cpu() for k, v in sd.items()}

    def state(reason):
        weights = cpu(model.state_dict())
        raw = {"train_model": weights} if average is not None else {}
        return {"format": FORMAT, "version": 2, "arch": model.arch, "hparams": hparams,
                "model": cpu(average.state) if average is not None else weights, **raw,
                "optimizer": opt.state_dict(), "epoch": epoch, "batch_in_epoch": pos, "step": step,
                "epochs_planned": epochs, "history": history, "val_history": val_history,
                "best": best, "data": roots, "n_samples": len(ds), "n_real": n_real,
                "real_train": os.fspath(real_train) if real_train else None,
                "val": os.fspath(val) if val else None,
                "n_parameters": count_parameters(model), "preprocessing": {
                    "colour_constancy": "shades_of_gray(p=6)", "mean": D.MEAN.tolist(),
                    "std": D.STD.tolist(), "resize": "shorter side = size"},
                "saved": reason, "torch": str(torch.__version__)}

    def validate():
        """Score on the validation images; keep the best weights in best_path(out)."""
        nonlocal best
        if validator is None or (val_history and val_history[-1]["step"] == step):
            return
        if average is not None:
            average.swap(model)
        try:
            scores = validator(model, device)
        finally:
            if average is not None:
                average.swap(model)
        r = {"step": step, "epoch": epoch + pos / n_batches, **scores,
             "seconds": round(time.time() - t0, 1)}
        val_history.append(r)
        if best is None or r["loss"] < best["loss"]:
            best = dict(r)
            save_checkpoint(best_path(out), state("best on validation"))
        log.info("validation at step %d: loss %.4f %s", step, r["loss"],
                 " ".join(f"{c} {r[c]:.3f}" for c in validator.classes))

    from tqdm import tqdm
    final = None
    while epoch < epochs and stopped is None:
        sampler = [[(epoch, *key) for key in b] for b in plan(epoch)[pos:]]
        loader = torch.utils.data.DataLoader(ds, batch_sampler=sampler, num_workers=workers)
        model.train()
        batches = prefetched(loader) if workers == 0 else iter(loader)
        bar = tqdm(batches, desc=f"epoch {epoch + 1}/{epochs}", initial=pos, total=n_batches,
                   unit="batch", disable=not progress, leave=False)
        for img, seg, anat, ign in bar:
            img, seg, anat, ign = (t.to(device) for t in (img, seg, anat, ign))
            for g in opt.param_groups:
                g["lr"] = _lr(lr, step, total)
            o = model(img)
            loss, parts = fuzzy_jaccard_loss(o["seg"], seg, o["anatomy"], anat, ign, anatomy_weight, skin_loss)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            if average is not None:
                average.update(model, step)
            step, pos, steps_here = step + 1, pos + 1, steps_here + 1
            running["loss"].append(float(loss.detach()))
            for k in ("seg", "anatomy"):
                running[k].append(parts.get(k, 0.0))
            postfix = {"loss": f"{np.mean(running['loss'][-20:]):.3f}"}
            if best is not None:
                postfix["val"] = f"{best['loss']:.3f}"
            bar.set_postfix(postfix)
            now = time.time()
            if time_limit is not None and now - t0 >= time_limit * 60:
                stopped = "time limit"
            elif max_steps is not None and steps_here >= max_steps:
                stopped = "max steps"
            elif step >= total:
                break  # ``steps`` reached inside the last epoch
            if stopped:
                break
            if step % val_every == 0:
                validate()
            if save_every and now - last_save >= save_every * 60:
                save_checkpoint(out, state("periodic"))
                last_save = now
        bar.close()
        if workers == 0:
            batches.close()  # stops the prefetching thread when the loop left early
        if pos >= n_batches or step >= total:  # an epoch, or the planned steps, done
            history.append({"epoch": epoch + 1, "step": step,
                            **{k: float(np.mean(v)) if v else None for k, v in running.items()},
                            "seconds": round(time.time() - t0, 1)})
            log.info("epoch %d: loss %.4f", epoch + 1, history[-1]["loss"])
            if progress:
                print(f"epoch {epoch + 1}/{epochs}: loss {history[-1]['loss']:.4f} "
                      f"(seg {history[-1]['seg']:.4f}, anatomy {history[-1]['anatomy']:.4f}) "
                      f"step {step}, {time.time() - t0:.0f} s", flush=True)
            running = {k: [] for k in running}
            epoch_ends.append((time.time(), step))
            if fit_minutes and steps is not None and len(epoch_ends) >= 2:
                per_step = float(np.median([(tb - ta) / max(sb - sa, 1) for (ta, sa), (tb, sb)
                                            in zip(epoch_ends, epoch_ends[1:])]))
                left = fit_minutes * 60 - (epoch_ends[-1][0] - t0)
                fitted_total = max(step + 1, step + int(left / max(per_step, 1e-9)))
                # lengthened only in the schedule's first half (later the learning rate
                # would climb back), shortened at any epoch end: steps that slow down
                # late in a run otherwise meet the time limit with the schedule unfinished
                if step < total / 2 or fitted_total < total:
                    total = fitted_total
                    epochs = math.ceil(total / n_batches)
                    hparams.update(steps=total, fitted=True)
                    log.info("steps fitted to %.1f minutes left: %d in all", left / 60, total)
            epoch, pos = (epoch + 1, 0) if pos >= n_batches else (epochs, pos)
        validate()
        final = state(stopped or "finished")
        save_checkpoint(out, final)
        last_save = time.time()
    if final is None:  # nothing left to do (already finished, or epochs=0)
        validate()
        final = state("finished")
        save_checkpoint(out, final)
    final["stopped"] = stopped
    return final
