"""Evaluate a trained model on real images: per-image Jaccard and Dice.

Ground truth:

* ``fitz17k`` layout (one folder per image: ``image.jpg`` + ``lesions.png`` +
  ``nonskin.png``): lesion = lesions.png, non-skin = nonskin.png (a missing nonskin.png
  means no non-skin pixels), skin = neither. Lesion, skin and non-skin are reported.
* ``pairs`` layout (image + lesion mask, e.g. ISIC, PH2, DermoFit): lesion only; the
  mask says nothing about skin vs non-skin, so only lesion scores are reported.

The prediction is the arg-max of the 3-class head's softmax, computed on the preprocessed
image (Shades of Gray, resize so that the shorter side is the training size, normalise),
averaged over the test-time views (``TTA``: none, a mirror image, or all eight flips and
quarter turns) and upsampled bilinearly to the original resolution, where it is scored.
Empty-mask conventions are those of ``glsynth.train.metrics`` (both empty: 1, included).
"""
from __future__ import annotations

import csv
import io
import json
import os

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from ..assets.lesions import load_lesions
from ..dataformat import THREE_CLASS_NAMES, THREE_CLASS_PALETTE
from ..errors import InputError
from ..io.images import ImageError, read_mask, read_rgb, write_png, write_text
from .data import preprocess
from .detection import detection_scores, mask_boxes
from .metrics import dice, jaccard
from .trainer import load_model

CLASSES = ("lesion", "skin", "nonskin")
PAPER = {"lesion": "0.61 ± 0.23", "skin": "0.88 ± 0.10", "nonskin": "0.60 ± 0.43"}


def real_samples(path, layout, with_meta=False):
    """[(id, image_path, {class: mask_path or None})] of a real evaluation folder (with
    ``with_meta``, a fourth element: the image's metadata, e.g. the CSV row's ``label``
    (diagnosis) and ``fitzpatrick``)."""
    lesions = load_lesions(path, layout=layout, lazy=True)
    out = []
    for e in lesions.entries:
        extra = (e.meta,) if with_meta else ()
        if layout == "fitz17k":
            ns = e.meta.get("nonskin_mask_path")
            les = e.meta.get("lesions_mask_path")
            les = les if les and os.path.isfile(les) else e.mask_paths[-1]
            out.append((e.id, e.image_path, {"lesion": les,
                                            "nonskin": ns if ns and os.path.isfile(ns) else None},
                        *extra))
        else:
            out.append((e.id, e.image_path, {"lesion": e.mask_paths[-1]}, *extra))
    return out


def read_real(path, layout):
    """Yield (id, RGB uint8, truth map) for every image of a real folder (``truth_map``
    codes); a folder without usable images or a mask that does not match its image is
    an error naming the folder or file."""
    for sid, img_path, masks in real_samples(path, layout):
        rgb = read_rgb(img_path)
        yield sid, rgb, truth_map(rgb.shape[:2], masks)


# Test-time augmentation: the views of an image whose predictions are averaged (flip,
# quarter turns). Training sees every flip and rotation, so each view is as valid as the
# image itself, and their mean is less noisy than any one of them.
TTA = {"none": [(False, 0)], "flip": [(False, 0), (True, 0)],
       "d4": [(f, r) for f in (False, True) for r in range(4)]}
TTA_TEXT = {"none": "one view", "flip": "logits averaged with the mirror image's",
            "d4": "logits averaged over the eight flips and quarter turns"}


def tta_views(tta: str) -> list:
    """``TTA[tta]``: (mirror, quarter turns) per view; an unknown name is an InputError."""
    if tta not in TTA:
        raise InputError(f"unknown test-time augmentation {tta!r} (expected one of {sorted(TTA)})")
    return TTA[tta]


@torch.no_grad()
def predict_probs(model, rgb: np.ndarray, size: int, device="cpu", tta="none") -> np.ndarray:
    """3 x H x W float32 softmax probabilities (lesion, skin, non-skin) at the image's own
    resolution: the logits of the ``tta`` views (``TTA``), each turned back, averaged,
    upsampled bilinearly, then the softmax."""
    views = tta_views(tta)
    x = torch.from_numpy(preprocess(rgb, size))[None].to(device)
    logits = 0
    for flip, turns in views:
        view = torch.rot90(x.flip(-1) if flip else x, turns, (-2, -1))
        y = torch.rot90(model(view)["seg"], -turns, (-2, -1))
        logits = logits + (y.flip(-1) if flip else y)
    logits = F.interpolate(logits / len(views), size=rgb.shape[:2], mode="bilinear", align_corners=False)
    return torch.softmax(logits, 1)[0].float().cpu().numpy()


def predict(model, rgb: np.ndarray, size: int, device="cpu", tta="none") -> np.ndarray:
    """HxW uint8 class map (0 lesion, 1 skin, 2 non-skin) at the image's own resolution."""
    return predict_probs(model, rgb, size, device, tta).argmax(0).astype(np.uint8)


def truth_map(shape, masks: dict) -> np.ndarray:
    """HxW uint8: 0 lesion, 1 skin, 2 non-skin; 3 = unknown (pairs: everything off the lesion)."""
    les = read_mask(masks["lesion"])
    if les.shape != tuple(shape):
        raise ImageError(f"{masks['lesion']}: mask {les.shape} does not match image {tuple(shape)}")
    if "nonskin" not in masks:
        t = np.full(shape, 3, np.uint8)
    else:
        t = np.ones(shape, np.uint8)
        if masks["nonskin"]:
            ns = read_mask(masks["nonskin"])
            if ns.shape != tuple(shape):
                raise ImageError(f"{masks['nonskin']}: mask {ns.shape} does not match image {tuple(shape)}")
            t[ns] = 2
    t[les] = 0  # a pixel marked both lesion and non-skin counts as lesion
    return t


def score(pred: np.ndarray, truth: np.ndarray, classes) -> dict:
    row = {}
    for c in classes:
        k = CLASSES.index(c)
        p, g = pred == k, truth == k
        row[f"{c}_jaccard"] = jaccard(p, g)
        row[f"{c}_dice"] = dice(p, g)
        row[f"{c}_truth_px"] = int(g.sum())
        row[f"{c}_pred_px"] = int(p.sum())
    return row


def _tile(img, h):
    s = h / img.shape[0]
    return cv2.resize(img, (max(1, int(round(img.shape[1] * s))), h), interpolation=cv2.INTER_AREA)


def grid(rows, height=160, width=None):
    """rows: [(name, rgb, truth map, prediction map)] -> one RGB image, 3 columns."""
    tiles = []
    for name, rgb, t, p in rows:
        a = _tile(rgb, height)
        b = _tile(THREE_CLASS_PALETTE[t], height)
        c = _tile(THREE_CLASS_PALETTE[p], height)
        line = np.concatenate([a, np.full((height, 4, 3), 255, np.uint8), b,
                               np.full((height, 4, 3), 255, np.uint8), c], 1)
        cv2.putText(line, name[:40], (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1, cv2.LINE_AA)
        tiles.append(line)
    w = width or max(t.shape[1] for t in tiles)
    tiles = [np.pad(t, ((0, 4), (0, w - t.shape[1]), (0, 0)), constant_values=255) if t.shape[1] < w
             else np.pad(t[:, :w], ((0, 4), (0, 0), (0, 0)), constant_values=255) for t in tiles]
    head = np.full((22, w, 3), 255, np.uint8)
    cw = (w - 8) // 3
    for i, txt in enumerate(("image", "truth", "prediction")):
        cv2.putText(head, txt, (4 + i * cw, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    legend = np.full((22, w, 3), 255, np.uint8)
    x = 4
    for txt, col in zip((*THREE_CLASS_NAMES.values(), "unknown"), THREE_CLASS_PALETTE):
        legend[5:17, x:x + 12] = col
        cv2.putText(legend, txt, (x + 16, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
        x += 100
    return np.concatenate([head] + tiles + [legend], 0)


def _stats(vals):
    v = np.asarray(vals, float)
    return (float(v.mean()), float(v.std())) if v.size else (float("nan"), float("nan"))


def summarise(rows, classes):
    s = {}
    for c in classes:
        j = [r[f"{c}_jaccard"] for r in rows]
        d = [r[f"{c}_dice"] for r in rows]
        ne = [r[f"{c}_jaccard"] for r in rows if r[f"{c}_truth_px"] > 0]
        s[c] = {"jaccard_mean": _stats(j)[0], "jaccard_std": _stats(j)[1],
                "dice_mean": _stats(d)[0], "dice_std": _stats(d)[1],
                "jaccard_nonempty_mean": _stats(ne)[0], "jaccard_nonempty_std": _stats(ne)[1],
                "n": len(j), "n_empty_truth": len(j) - len(ne)}
    return s


def detection_row(probs: np.ndarray, truth: np.ndarray) -> dict:
    """The paper's box metrics for one image: lesion boxes from the connected components
    of the predicted lesion mask (confidence: mean lesion probability; components under
    1e-4 of the image are dropped as specks) against those of the true lesion mask."""
    pred = probs.argmax(0) == 0
    boxes, scores = mask_boxes(pred, probs[0], min_area=max(1, round(1e-4 * pred.size)))
    truth_boxes, _ = mask_boxes(truth == 0)
    return detection_scores(boxes, scores, truth_boxes)


DETECTION = ("ap_centroid", "ap50", "box_iou", "precision", "recall")


def summarise_detection(rows) -> dict:
    """Means over the images with at least one true lesion box (the others have no AP)."""
    with_truth = [r for r in rows if r.get("n_truth_boxes", 0) > 0]
    out = {"n_images": len(with_truth)}
    for k in DETECTION:
        vals = [r[k] for r in with_truth if not np.isnan(r[k])]
        out[k] = float(np.mean(vals)) if vals else float("nan")
        out[f"{k}_std"] = float(np.std(vals)) if vals else float("nan")
    return out


def breakdown(rows, key, classes) -> dict:
    """Mean per-image Jaccard of each class for each value of ``key`` (e.g. diagnosis)."""
    groups = {}
    for r in rows:
        if r.get(key) not in (None, ""):
            groups.setdefault(str(r[key]), []).append(r)
    return {g: {"n": len(rs), **{c: float(np.mean([r[f"{c}_jaccard"] for r in rs])) for c in classes}}
            for g, rs in sorted(groups.items())}


def evaluate(model_path, real, layout, out, device="cpu", size=None, grid_n=12, progress=True,
             extra=None, tta="d4"):
    """Score `model_path` on the real images in `real`; write report.md, per_image.csv,
    summary.json and grid.png to `out`. Returns the summary dict (``extra`` is merged
    into it before it is written). tta: ``TTA``'s views averaged per image."""
    if layout not in ("fitz17k", "pairs"):
        raise InputError(f"unknown layout {layout!r} (expected 'fitz17k' or 'pairs')")
    tta_views(tta)
    model, ck = load_model(model_path, device)
    size = int(size or ck["hparams"]["size"])
    samples = real_samples(real, layout, with_meta=True)
    classes = CLASSES if layout == "fitz17k" else ("lesion",)
    rows, shown = [], []
    from tqdm import tqdm
    for sid, img_path, masks, meta in tqdm(samples, desc="evaluate", unit="img", disable=not progress):
        rgb = read_rgb(img_path)
        truth = truth_map(rgb.shape[:2], masks)
        probs = predict_probs(model, rgb, size, device, tta)
        pred = probs.argmax(0).astype(np.uint8)
        rows.append({"id": sid, "image": img_path, "width": rgb.shape[1], "height": rgb.shape[0],
                     "diagnosis": meta.get("label") or "", "fitzpatrick": meta.get("fitzpatrick") or "",
                     **score(pred, truth, classes), **detection_row(probs, truth)})
        if len(shown) < grid_n:
            shown.append((sid, rgb, truth, pred))
    os.makedirs(out, exist_ok=True)
    buf = io.StringIO()
    wr = csv.DictWriter(buf, fieldnames=list(rows[0].keys()), lineterminator="\n")
    wr.writeheader()
    for r in rows:
        wr.writerow({k: (f"{v:.6f}" if isinstance(v, float) else v) for k, v in r.items()})
    write_text(os.path.join(out, "per_image.csv"), buf.getvalue())
    summary = {"model": os.fspath(model_path), "real": os.fspath(real), "layout": layout, "size": size,
               "tta": tta,
               "n_images": len(rows), "classes": summarise(rows, classes),
               "detection": summarise_detection(rows),
               "by_diagnosis": breakdown(rows, "diagnosis", classes),
               "by_fitzpatrick": breakdown(rows, "fitzpatrick", classes),
               "model_steps": ck.get("step"), "model_data": ck.get("data"), **(extra or {})}
    write_text(os.path.join(out, "summary.json"), json.dumps(summary, indent=1))
    write_png(os.path.join(out, "grid.png"), grid(shown))
    write_text(os.path.join(out, "report.md"), report_md(summary))
    return summary


def report_md(s):
    lines = [f"# Segmentation evaluation", "",
             f"- model: `{s['model']}` ({s['model_steps']} training steps on {s['model_data']})",
             f"- images: `{s['real']}` ({s['layout']} layout), {s['n_images']} images",
             f"- preprocessing: Shades of Gray (p=6), shorter side resized to {s['size']} px, "
             "ImageNet normalisation; " + TTA_TEXT[s.get("tta", "none")] + "; scored at the "
             "original resolution", "",
             "Per-image Jaccard (J) and Dice (D), mean ± std over images. Empty-mask convention: "
             "truth and prediction both empty → 1, truth empty but prediction not → 0; all images "
             "are included in the first columns; the last column leaves out images whose truth for "
             "that class is empty.", "",
             "| class | J mean ± std | D mean ± std | images with empty truth | J over non-empty truth | paper (Fitzpatrick17k, 25 images) |",
             "|---|---|---|---|---|---|"]
    for c, v in s["classes"].items():
        lines.append(f"| {c} | {v['jaccard_mean']:.3f} ± {v['jaccard_std']:.3f} | "
                     f"{v['dice_mean']:.3f} ± {v['dice_std']:.3f} | {v['n_empty_truth']} / {v['n']} | "
                     f"{v['jaccard_nonempty_mean']:.3f} ± {v['jaccard_nonempty_std']:.3f} | {PAPER[c]} |")
    d = s.get("detection")
    if d and d["n_images"]:
        lines += ["", "Lesion boxes from the connected components of the predicted lesion mask "
                  "(confidence: mean lesion probability) against those of the true mask, per image, "
                  f"mean ± std over the {d['n_images']} images with a true lesion: AP_centroid "
                  "(Skin3D's rule: each box contains the other's centre), AP50 (IoU > 0.5), and "
                  "box IoU, precision and recall of the boxes with confidence ≥ 0.5.", "",
                  "| AP_centroid | AP50 | box IoU | precision | recall |", "|---|---|---|---|---|",
                  "| " + " | ".join(f"{d[k]:.3f} ± {d[k + '_std']:.3f}" for k in DETECTION) + " |"]
    for key, title in (("by_diagnosis", "diagnosis"), ("by_fitzpatrick", "Fitzpatrick type")):
        groups = s.get(key) or {}
        if groups:
            cls = [c for c in CLASSES if c in next(iter(groups.values()))]
            lines += ["", f"Mean per-image Jaccard by {title}:", "",
                      f"| {title} | n | " + " | ".join(cls) + " |", "|---|---|" + "---|" * len(cls)]
            lines += [f"| {g} | {v['n']} | " + " | ".join(f"{v[c]:.3f}" for c in cls) + " |"
                      for g, v in groups.items()]
    lines += ["", "`per_image.csv` has every image's scores and pixel counts; `grid.png` shows "
              "image / truth / prediction (red lesion, green skin, blue non-skin, grey unknown)."]
    if s["layout"] == "pairs":
        lines += ["", "Pairs layout: the masks only mark the lesion, so skin and non-skin are not scored."]
    return "\n".join(lines) + "\n"
