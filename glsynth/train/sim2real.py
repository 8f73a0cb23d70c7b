"""``glsynth sim2real``: how well a config's synthetic data transfers to real photographs.

One command, one time budget: generate a dataset from the config (or reuse one), train
the segmentation network on it, pick the checkpoint on a real validation folder when one
is given (the paper's model selection), evaluate on the real folder (logits averaged
over the eight flips and quarter turns unless ``--tta`` says otherwise) and write
``report.md``, ``summary.json``, ``per_image.csv`` and ``grid.png``.

How the budget is split (``--gen-share``, default 0.3 of what the evaluation leaves):
generation pays a fixed cost per body (building, pasting, blending: 10-25 s on 2 CPU
cores) on top of each view, training a fixed cost per step. In the 30-minute run on 2
cores reported in the README, 30% gave 1,600 images in 509 s and the rest 3,955 steps
of batch 8 at 256 px, so the network saw each image ~20 times, each with fresh
augmentation. The share was set from that balance, not tuned against the real score
(tuning it to the 14 development photographs would only fit them). The data is made in parts of
``--bodies-per-part`` bodies, each an ordinary ``glsynth generate`` folder and a shard
of one run (``bodies.first`` = part x bodies per part, the config's seed): its bodies are
new, the procedural lesions dealt to them continue the run's sequence, in which every
round of as many lesions as there are presets holds each preset once (independent
seeds per part left 4-6 of the 21-22 presets out of a 30-minute run), and its backgrounds
are its own. Parts are made until the generation share is spent; the training length
in steps is planned from a short timing of real training steps and fitted again at
the run's epoch ends (longer only in the schedule's first half, shorter at any time),
so that the learning-rate schedule ends with the budget (the short timing alone
misjudged long runs by up to a quarter).

Resumable: each part, the training checkpoint and the plan live in ``OUT``; ``--resume``
continues where a run stopped and spends what is left of the budget.
"""
from __future__ import annotations

import json
import logging
import math
import os
import time

from ..dataformat import sample_ids
from ..errors import InputError, UnavailableError
from ..io.images import write_text

log = logging.getLogger(__name__)

PAPER = {"lesion": 0.61, "skin": 0.88, "nonskin": 0.60}
EVAL_RESERVE_S = 60.0     # at most this much kept back for the evaluation and the report


def _state_path(out):
    return os.path.join(out, "sim2real.json")


def _load_state(out):
    try:
        with open(_state_path(out)) as fh:
            return json.load(fh)
    except FileNotFoundError:
        return None


def _save_state(out, state):
    write_text(_state_path(out), json.dumps(state, indent=1, sort_keys=True))


def check_real(path, layout) -> int:
    """Read every image and mask of a real folder now (before any work is spent): a
    folder without usable images or a mask of the wrong size is an error naming it."""
    from .evaluate import read_real
    n = sum(1 for _ in read_real(path, layout))
    if n == 0:
        raise InputError(f"{path}: no usable real images in layout {layout!r}")
    return n


def _part_config(cfg, k, views_per_body, bodies_per_part):
    from ..config import from_dict
    raw = cfg.to_dict()
    raw["bodies"]["first"] = int(cfg.bodies.first) + k * int(bodies_per_part)
    raw["bodies"]["count"] = int(bodies_per_part)
    raw["views"]["per_body"] = int(views_per_body)
    return from_dict(raw, source=f"sim2real part {k}")


def generate_parts(cfg, out, seconds, views_per_body=80, bodies_per_part=2, state=None,
                   progress=True) -> list:
    """Generate dataset parts into ``out/data/part000``... until ``seconds`` are spent
    (a part is started only when the last one's duration still fits); returns the
    finished parts' folders. A part left unfinished by an interrupted run is resumed."""
    from ..pipeline import generate
    state = state if state is not None else {}
    parts = state.setdefault("parts", [])
    while True:
        if not parts or parts[-1].get("done"):
            spent = sum(p["seconds"] for p in parts)
            last = parts[-1]["seconds"] if parts else 0.0
            if seconds <= 0 or spent + last > seconds:
                break
            parts.append({"folder": os.path.join("data", f"part{len(parts):03d}"), "seconds": 0.0})
            _save_state(out, state)
        k, entry = len(parts) - 1, parts[-1]
        folder = os.path.join(out, entry["folder"])
        t0 = time.perf_counter()
        log.info("sim2real: generating %s", entry["folder"])
        manifest = generate(_part_config(cfg, k, views_per_body, bodies_per_part), folder,
                            resume=os.path.isdir(folder))
        entry.update(done=True, seconds=entry["seconds"] + time.perf_counter() - t0,
                     images=manifest["counts"]["images"])
        _save_state(out, state)
        if progress:
            total = sum(p["seconds"] for p in parts)
            print(f"sim2real: {entry['folder']}: {entry['images']} images in {entry['seconds']:.0f} s "
                  f"({total:.0f} of {seconds:.0f} s for generation)", flush=True)
    return [os.path.join(out, p["folder"]) for p in parts if p.get("done")]


def time_train_steps(data, size, batch_size, width, depth, device, n=12, warmup=3) -> float:
    """Seconds per training step (data loading, augmentation, forward, backward), the
    median of ``n`` steps after ``warmup`` on ``data``. The steps draw from a pool of two
    batches' samples that the warm-up has decoded, as a long run's steps do from the
    training set's in-memory cache after its first epoch."""
    import numpy as np
    import torch
    from .loss import fuzzy_jaccard_loss
    from .model import SegNet
    from .trainer import TrainSet
    ds = TrainSet(data, size=size, seed=12345)
    model = SegNet(width=width, depth=depth).to(device)
    opt = torch.optim.AdamW(model.parameters(), lr=1e-4)
    times = []
    rng = np.random.default_rng(0)
    pool = rng.permutation(len(ds))[:2 * batch_size]
    warmup = max(warmup, math.ceil(len(pool) / batch_size))
    for i in range(warmup + n):
        t0 = time.perf_counter()
        keys = pool[np.arange(i * batch_size, (i + 1) * batch_size) % len(pool)]
        batch = [ds[(i, 0, int(j))] for j in keys]
        img, seg, anat, ign = (torch.stack(t).to(device) for t in zip(*batch))
        o = model(img)
        loss, _ = fuzzy_jaccard_loss(o["seg"], seg, o["anatomy"], anat, ign)
        opt.zero_grad()
        loss.backward()
        opt.step()
        if device == "cuda":
            torch.cuda.synchronize()
        if i >= warmup:
            times.append(time.perf_counter() - t0)
    return float(np.median(times))


def sim2real(cfg, real, layout, minutes, out, val=None, val_layout=None, resume=False, data=None,
             device=None, seed=0, size=256, width=1.0, depth=0, batch_size=8, lr=2e-3,
             gen_share=0.3, views_per_body=80, bodies_per_part=2, progress=True, tta="d4",
             skin_loss="paper") -> dict:
    """Run the yardstick; returns the summary dict (also written to ``out/summary.json``)."""
    import torch
    from .evaluate import evaluate
    from .trainer import best_path, train
    out = os.fspath(out)
    if minutes <= 0:
        raise InputError(f"--minutes must be > 0, got {minutes}")
    if not 0 <= gen_share < 1:
        raise InputError(f"--gen-share must be in [0, 1), got {gen_share}")
    device = device or ("cuda" if torch.cuda.is_available() else "cpu")
    val_layout = val_layout or layout
    state = _load_state(out)
    if state is not None and not resume:
        raise FileExistsError(f"{out}: a sim2real run is already there; pass --resume to continue "
                              "it, or choose another --out")
    if os.path.isdir(out) and os.listdir(out) and state is None:
        raise FileExistsError(f"{out}: folder is not empty and holds no sim2real run")
    n_real = check_real(real, layout)
    n_val = check_real(val, val_layout) if val else 0
    if val and os.path.realpath(val) == os.path.realpath(real):
        log.warning("--val is the --real folder: the checkpoint is chosen on the images it is "
                    "scored on, so the scores are optimistic")
    os.makedirs(out, exist_ok=True)
    budget = float(minutes) * 60.0
    if state is None:
        state = {"config": cfg.to_dict(), "minutes": float(minutes), "seed": int(seed),
                 "device": device, "size": size, "width": width, "depth": depth,
                 "batch_size": batch_size, "lr": lr, "gen_share": gen_share, "skin_loss": skin_loss,
                 "data": [os.fspath(d) for d in data] if data else None, "spent": {}}
        _save_state(out, state)
    spent = state["spent"]
    t_start = time.perf_counter()
    work = budget - min(EVAL_RESERVE_S, 0.1 * budget)

    # 1. data
    if state["data"]:
        folders = state["data"]
    else:
        folders = generate_parts(cfg, out, work * gen_share, views_per_body, bodies_per_part,
                                 state, progress)
        spent["generate"] = sum(p["seconds"] for p in state["parts"])
        _save_state(out, state)
        if not folders:
            raise UnavailableError(f"no data was generated within {minutes} minutes")
    n_images = sum(len(sample_ids(f)) for f in folders)

    # 2. training: a first plan of its steps from a timing of real steps, which the
    #    trainer fits again to the time left (fit_minutes)
    ckpt = os.path.join(out, "model.pt")
    train_budget = max(work - sum(spent.values()), 0.0)
    if "steps" not in state:
        t0 = time.perf_counter()
        per_step = time_train_steps(folders, size, batch_size, width, depth, device)
        spent["timing"] = time.perf_counter() - t0
        train_budget = max(work - sum(spent.values()), 0.0)
        state.update(seconds_per_step=per_step, steps=max(1, int(train_budget / per_step)))
        _save_state(out, state)
    t0 = time.perf_counter()
    if train_budget > 0 or not os.path.exists(ckpt):
        # the time limit only guards the budget when steps run slower than timed
        ck = train(folders, ckpt, size=size, batch_size=batch_size, lr=lr, device=device,
                   time_limit=max(train_budget, 1.0) * 1.05 / 60.0, resume=os.path.exists(ckpt),
                   seed=seed, width=width, depth=depth, val=val, val_layout=val_layout,
                   steps=state["steps"], fit_minutes=train_budget / 60.0, progress=progress,
                   save_every=2.0, skin_loss=state.get("skin_loss", "paper"))
        spent["train"] = spent.get("train", 0.0) + time.perf_counter() - t0
        _save_state(out, state)
    else:  # the budget is spent: evaluate what was trained
        from .trainer import load_model
        _, ck = load_model(ckpt)

    # 3. evaluation, with the checkpoint chosen on --val when there is one
    model_path = best_path(ckpt) if val and os.path.exists(best_path(ckpt)) else ckpt
    t0 = time.perf_counter()
    extra = {"sim2real": {
        "config": state["config"], "minutes": state["minutes"], "device": device,
        "images_generated": n_images, "data": folders, "training_steps": ck["step"],
        "planned_steps": state["steps"], "seconds_per_step": state.get("seconds_per_step"),
        "training_seconds": round(spent.get("train", 0.0), 1),
        "generation_seconds": round(spent.get("generate", 0.0), 1),
        "checkpoint": os.path.basename(model_path), "val": os.fspath(val) if val else None,
        "n_val_images": n_val, "best": ck.get("best"), "gen_share": gen_share,
        "size": size, "width": width, "depth": depth, "n_parameters": ck.get("n_parameters"),
        "ema": ck["hparams"].get("ema", 0.0), "skin_loss": ck["hparams"].get("skin_loss", "paper"),
        "seed": seed}}
    summary = evaluate(model_path, real, layout, out, device=device, progress=progress, extra=extra,
                       tta=tta)
    spent["evaluate"] = time.perf_counter() - t0
    summary["sim2real"]["total_seconds"] = round(sum(spent.values()), 1)
    summary["jaccard"] = {c: v["jaccard_mean"] for c, v in summary["classes"].items()}
    summary["jaccard_nonempty"] = {c: v["jaccard_nonempty_mean"] for c, v in summary["classes"].items()}
    summary["n_images"] = n_real
    write_text(os.path.join(out, "summary.json"), json.dumps(summary, indent=1))
    write_text(os.path.join(out, "report.md"), report_md(summary))
    _save_state(out, state)
    log.info("sim2real finished in %.0f s of this invocation", time.perf_counter() - t_start)
    return summary


def report_md(s) -> str:
    """The yardstick's report: the run, the per-image Jaccard table beside the paper's,
    then the evaluation's own sections (boxes, per diagnosis)."""
    from .evaluate import report_md as eval_md
    r = s["sim2real"]
    lines = ["# Sim-to-real: synthetic training, real evaluation", "",
             f"- real images: `{s['real']}` ({s['layout']} layout), {s['n_images']} images",
             f"- budget: {r['minutes']:g} min on {r['device']}: generation "
             f"{r['generation_seconds']:.0f} s ({r['images_generated']} images), training "
             f"{r['training_seconds']:.0f} s ({r['training_steps']} steps of "
             f"{r.get('seconds_per_step') or float('nan'):.3f} s), total {r['total_seconds']:.0f} s",
             f"- network: SegNet width {r['width']:g}, depth {r['depth']}, "
             f"{r['n_parameters']} parameters, input {r['size']} px, seed {r['seed']}, "
             f"skin loss {r.get('skin_loss', 'paper')}",
             f"- checkpoint: `{r['checkpoint']}`" + (
                 f" (lowest loss on `{r['val']}`, {r['n_val_images']} images, at step "
                 f"{r['best']['step']})" if r.get("best") and r["checkpoint"].endswith(".best.pt")
                 else " (the last one)"), "",
             "| class | Jaccard, mean over images | over non-empty truth | paper (Fitzpatrick17k) |",
             "|---|---|---|---|"]
    for c, v in s["classes"].items():
        lines.append(f"| {c} | {v['jaccard_mean']:.3f} ± {v['jaccard_std']:.3f} | "
                     f"{v['jaccard_nonempty_mean']:.3f} ({v['n'] - v['n_empty_truth']} images) | "
                     f"{PAPER[c]:.2f} |")
    tail = eval_md(s).split("\n", 1)[1]   # the evaluation's sections without its title
    return "\n".join(lines) + "\n\n## Evaluation details\n" + tail


def register(sub):
    from .cli import add_skin_loss_argument, add_tta_argument
    p = sub.add_parser("sim2real", help="generate, train and evaluate on real photographs "
                                        "within a time budget (the sim-to-real yardstick)")
    p.add_argument("--config", default=None, help="YAML config (default: the embedded default)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="config override (repeatable)")
    p.add_argument("--real", required=True, help="folder of real images with masks")
    p.add_argument("--layout", default="fitz17k", choices=("fitz17k", "pairs"))
    p.add_argument("--minutes", type=float, required=True, help="the whole budget, in minutes")
    p.add_argument("--out", required=True, help="run folder (data, checkpoints, report)")
    p.add_argument("--val", default=None, help="real validation folder for checkpoint selection")
    p.add_argument("--val-layout", default=None, choices=("fitz17k", "pairs"),
                   help="layout of --val (default: --layout)")
    p.add_argument("--resume", action="store_true", help="continue the run in --out")
    p.add_argument("--data", action="append", metavar="DIR",
                   help="reuse these glsynth datasets instead of generating (repeatable)")
    p.add_argument("--device", default=None, choices=("cpu", "cuda"),
                   help="default: cuda when available")
    p.add_argument("--seed", type=int, default=0, help="training seed (the config has its own)")
    p.add_argument("--size", type=int, default=256, help="training input size")
    p.add_argument("--width", type=float, default=1.0, help="network width multiplier")
    p.add_argument("--depth", type=int, default=0, help="extra blocks per encoder stage")
    p.add_argument("--gen-share", type=float, default=0.3,
                   help="share of the budget spent generating (default 0.3)")
    p.add_argument("--views-per-body", type=int, default=80)
    p.add_argument("--bodies-per-part", type=int, default=2)
    p.add_argument("--threads", type=int, default=None, help="CPU threads for torch")
    add_tta_argument(p)
    add_skin_loss_argument(p)
    p.add_argument("-q", "--quiet", action="store_true")
    p.set_defaults(fn=cmd_sim2real)


def cmd_sim2real(args):
    from ..config import load_config
    from .cli import print_summary, set_threads
    set_threads(args)
    cfg = load_config(args.config, args.set or ())
    s = sim2real(cfg, args.real, args.layout, args.minutes, args.out, val=args.val,
                 val_layout=args.val_layout, resume=args.resume, data=args.data, device=args.device,
                 seed=args.seed, size=args.size, width=args.width, depth=args.depth,
                 gen_share=args.gen_share, views_per_body=args.views_per_body,
                 bodies_per_part=args.bodies_per_part, progress=not args.quiet, tta=args.tta,
                 skin_loss=args.skin_loss)
    print_summary(s)
    print(f"wrote {args.out}/report.md, summary.json, per_image.csv, grid.png")
