"""``glsynth train`` and ``glsynth evaluate`` (registered by glsynth.cli)."""
from __future__ import annotations

from ..errors import InputError


def set_threads(args):
    """torch's CPU threads from ``--threads`` (the train, evaluate and sim2real commands)."""
    if args.threads:
        import torch
        torch.set_num_threads(args.threads)


def cmd_train(args):
    from .trainer import train
    set_threads(args)
    if not args.data and not args.real_train:
        raise InputError("give --data (synthetic) and/or --real-train (real) folders")
    ck = train(args.data or [], args.out, size=args.size, epochs=args.epochs,
               batch_size=args.batch_size, lr=args.lr, device=args.device,
               time_limit=args.time_limit, resume=args.resume, seed=args.seed, init=args.init,
               workers=args.workers, width=args.width, depth=args.depth,
               save_every=args.save_every, progress=not args.quiet, val=args.val,
               val_layout=args.val_layout, val_every=args.val_every, real_train=args.real_train,
               real_layout=args.real_layout, real_ratio=args.real_ratio, ema=args.ema,
               cache_gb=args.cache_gb, skin_loss=args.skin_loss)
    h = ck["history"][-1] if ck["history"] else {}
    print(f"wrote {args.out}: epoch {ck['epoch']}/{ck['epochs_planned']}, step {ck['step']}, "
          f"{ck['n_parameters']} parameters" + (f", last epoch loss {h['loss']:.4f}" if h else "")
          + (f" (stopped: {ck['stopped']}; continue with --resume)" if ck.get("stopped") else ""))
    if ck.get("best"):
        from .trainer import best_path
        b = ck["best"]
        print(f"best on {args.val}: step {b['step']}, validation loss {b['loss']:.4f} -> {best_path(args.out)}")


def add_tta_argument(p):
    p.add_argument("--tta", default="d4", choices=("none", "flip", "d4"),
                   help="test-time augmentation: average the logits over the mirror image (flip) "
                        "or all eight flips and quarter turns (d4, the default); none: one view")


def add_skin_loss_argument(p):
    p.add_argument("--skin-loss", default="paper", choices=("paper", "exclusive"),
                   help="paper: the skin channel's Jaccard ignores lesion pixels (appendix C, the "
                        "default); exclusive: skin predicted on a lesion counts against it, as the "
                        "evaluation scores skin (neither lesion nor non-skin)")


def cmd_evaluate(args):
    from .evaluate import evaluate
    set_threads(args)
    s = evaluate(args.model, args.real, args.layout, args.out, device=args.device, size=args.size,
                 grid_n=args.grid, progress=not args.quiet, tta=args.tta)
    print_summary(s)
    print(f"wrote {args.out}/report.md, per_image.csv, grid.png")


def print_summary(s):
    for c, v in s["classes"].items():
        print(f"{c:8s} Jaccard {v['jaccard_mean']:.3f} ± {v['jaccard_std']:.3f}  "
              f"Dice {v['dice_mean']:.3f} ± {v['dice_std']:.3f}  ({v['n_empty_truth']}/{v['n']} empty truth)")
    d = s.get("detection") or {}
    if d.get("n_images"):
        print(f"boxes    AP_centroid {d['ap_centroid']:.3f}  AP50 {d['ap50']:.3f}  "
              f"box IoU {d['box_iou']:.3f}  ({d['n_images']} images with lesions)")


def register(sub):
    p = sub.add_parser("train", help="train the lesion/skin/non-skin + anatomy segmentation network")
    p.add_argument("--data", action="append", metavar="DIR",
                   help="glsynth generate output folder (repeatable)")
    p.add_argument("--out", required=True, help="checkpoint to write (e.g. model.pt)")
    p.add_argument("--size", type=int, default=256, help="training crop size in pixels (default 256)")
    p.add_argument("--epochs", type=int, default=10)
    p.add_argument("--batch-size", type=int, default=8)
    p.add_argument("--lr", type=float, default=2e-3)
    p.add_argument("--device", default="cpu", choices=("cpu", "cuda"))
    p.add_argument("--time-limit", type=float, default=None, metavar="MIN",
                   help="stop after this many minutes (checkpoint saved; continue with --resume)")
    p.add_argument("--resume", action="store_true", help="continue training the checkpoint in --out")
    p.add_argument("--init", default=None, help="initialise from a local checkpoint / state dict")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--width", type=float, default=1.0, help="channel width multiplier of the network")
    p.add_argument("--depth", type=int, default=0, help="extra blocks per encoder stage (default 0)")
    p.add_argument("--val", default=None, metavar="DIR",
                   help="real validation images: keep the checkpoint with the lowest validation "
                        "loss in <out>.best.pt (the paper's model selection)")
    p.add_argument("--val-layout", default="fitz17k", choices=("fitz17k", "pairs"))
    p.add_argument("--val-every", type=int, default=None, metavar="STEPS",
                   help="validate every STEPS steps (default: 8 times per epoch, at most every 250)")
    p.add_argument("--real-train", default=None, metavar="DIR",
                   help="real training images mixed into every batch (see --real-ratio)")
    p.add_argument("--real-layout", default="fitz17k", choices=("fitz17k", "pairs"))
    p.add_argument("--real-ratio", type=float, default=0.25,
                   help="share of real images in each batch with --real-train (default 0.25)")
    p.add_argument("--ema", type=float, default=0.999, metavar="DECAY",
                   help="validate and export an exponential moving average of the weights with "
                        "this decay (default 0.999, about the last 1,000 steps; 0: the last weights)")
    add_skin_loss_argument(p)
    p.add_argument("--workers", type=int, default=0, help="data loader processes (default 0)")
    p.add_argument("--cache-gb", type=float, default=4.0, metavar="GB",
                   help="keep up to GB of decoded training samples in memory (default 4; only "
                        "with --workers 0; 0: decode every sample every time)")
    p.add_argument("--save-every", type=float, default=5.0, metavar="MIN",
                   help="also checkpoint every MIN minutes within an epoch (default 5)")
    p.add_argument("--threads", type=int, default=None,
                   help="CPU threads for torch (default: torch's choice; use 1 on a busy machine)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    p.set_defaults(fn=cmd_train)
    p = sub.add_parser("evaluate", help="per-image Jaccard/Dice of a trained model on real images")
    p.add_argument("--model", required=True)
    p.add_argument("--real", required=True, help="folder of real images with masks")
    p.add_argument("--layout", required=True, choices=("fitz17k", "pairs"))
    p.add_argument("--out", required=True, help="report folder")
    p.add_argument("--device", default="cpu", choices=("cpu", "cuda"))
    p.add_argument("--size", type=int, default=None, help="shorter side (default: the training size)")
    p.add_argument("--grid", type=int, default=12, help="images in grid.png (default 12)")
    add_tta_argument(p)
    p.add_argument("--threads", type=int, default=None, help="CPU threads for torch")
    p.add_argument("-q", "--quiet", action="store_true")
    p.set_defaults(fn=cmd_evaluate)
