"""How healthy skin's colour varies over centimetres, in glsynth output against real photographs.

Per image, at 512 px on the shorter side, over healthy skin (glsynth: semantic label 1;
Fitzpatrick17k layout: neither lesion nor non-skin, kept 12 px from the lesion): CIELAB is
smoothed with a mask-normalised Gaussian (sigma 3% of the shorter side, so pores, hair and
noise drop out) and the spread of each channel is measured: the standard deviation of L*
divided by mean L* and the standard deviations of a* and b*. Also per image with a lesion,
its contrast: the mean Lab inside the lesion (eroded 3 px) minus that of the healthy skin
12-40 px outside it, as CIEDE76 and as the signed a* (redness) and L* differences. And
per image, how much of its healthy skin lies in deep shade: the share of those pixels
(unsmoothed) whose L* is below SHADE (0.6) times the image's median skin L*, a fifth of
the median's luminance or less (skin turning away from the light, a fold, a limb behind).
Printed are the 10th / 50th / 90th percentiles over images, the mean skin colour, and the
share of images with at least 5% of their skin in deep shade, for each folder. With
--by-kind, also the lesion contrast of each kind of lesion in glsynth output (its
instances in an image taken together, by the ``kind`` each image's record gives).

    python tools/skin_color_stats.py OUT_DIR [OUT_DIR ...] --real ../shared/realdev/fitz17k [--by-kind]
"""
import argparse
import collections
import json
import os

import cv2
import numpy as np

from glsynth import dataformat as fmt

REAL_MASKS = ("lesions.png", "nonskin.png", "selected_lesion.png")
SHORT = 512
SIGMA = 0.03 * SHORT
SHADE = 0.6


def spread(img_bgr, skin):
    """(L std / L mean, a std, b std, L mean, a mean, b mean) of the smoothed skin, or None."""
    lab = cv2.cvtColor(img_bgr.astype(np.float32) / 255.0, cv2.COLOR_BGR2LAB)
    m = skin.astype(np.float32)
    den = cv2.GaussianBlur(m, (0, 0), SIGMA)
    keep = (cv2.erode(skin.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0) & (den > 0.5)
    if keep.sum() < 2000:
        return None
    smooth = [cv2.GaussianBlur(lab[..., c] * m, (0, 0), SIGMA)[keep] / den[keep] for c in range(3)]
    L, a, b = smooth
    return (float(L.std() / max(L.mean(), 1.0)), float(a.std()), float(b.std()),
            float(L.mean()), float(a.mean()), float(b.mean()))


def contrast(img_bgr, lesion, skin):
    """The lesion's mean Lab minus that of the ring of skin 12-40 px outside it, or None."""
    lab = cv2.cvtColor(img_bgr.astype(np.float32) / 255.0, cv2.COLOR_BGR2LAB)
    inside = cv2.erode(lesion.astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
    grow = lambda r: cv2.dilate(lesion.astype(np.uint8), np.ones((2 * r + 1,) * 2, np.uint8)) > 0  # noqa: E731
    ring = grow(40) & ~grow(12) & skin
    if inside.sum() < 50 or ring.sum() < 200:
        return None
    return lab[inside].mean(0) - lab[ring].mean(0)


def shade(img_bgr, skin):
    """Share of the ``skin`` pixels whose L* is below SHADE x their median L*, or None."""
    if skin.sum() < 2000:
        return None
    L = cv2.cvtColor(img_bgr.astype(np.float32) / 255.0, cv2.COLOR_BGR2LAB)[..., 0][skin]
    return float((L < SHADE * np.median(L)).mean())


def _resized(img, *masks):
    h, w = masks[0].shape
    s = SHORT / min(h, w)
    size = (round(w * s), round(h * s))
    return (cv2.resize(img, size, interpolation=cv2.INTER_AREA),
            *(cv2.resize(m.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0 for m in masks))


def _semantic(folder, sid):
    sem = cv2.imread(fmt.layer_path(folder, sid, "semantic"), cv2.IMREAD_GRAYSCALE)
    if sem is None:
        raise SystemExit(f"{folder}: no semantic target for {sid}")
    return sem


def synthetic(folder):
    out = []
    for sid in fmt.sample_ids(folder):
        sem = _semantic(folder, sid)
        img, skin, lesion = _resized(cv2.imread(fmt.image_path(folder, sid)), sem == 1, sem == 2)
        out.append((spread(img, skin), contrast(img, lesion, skin), shade(img, skin)))
    return out


def by_kind(folder):
    """{lesion kind: [Lab contrast per image showing that kind]} over a glsynth output."""
    out = collections.defaultdict(list)
    for sid in fmt.sample_ids(folder):
        with open(fmt.record_path(folder, sid)) as fh:
            kinds = collections.defaultdict(list)
            for item in json.load(fh).get("lesions", []):
                kinds[item["source"].get("kind", "real")].append(item["instance"])
        if not kinds:
            continue
        sem = _semantic(folder, sid)
        ins = cv2.imread(fmt.layer_path(folder, sid, "instances"), cv2.IMREAD_UNCHANGED)
        # the image resized once, with the skin and each kind's lesion mask
        img, skin, *lesions = _resized(cv2.imread(fmt.image_path(folder, sid)), sem == 1,
                                       *(np.isin(ins, ids) for ids in kinds.values()))
        for kind, lesion in zip(kinds, lesions):
            c = contrast(img, lesion, skin)
            if c is not None:
                out[kind].append(c)
    return out


def report_kinds(name, kinds):
    print(f"{name}, lesion contrast by kind (median over images: dE, da*, dL*, db*):")
    for kind in sorted(kinds):
        d = np.array(kinds[kind])
        dE, dL, da, db = np.median(np.linalg.norm(d, axis=1)), *np.median(d, 0)
        print(f"  {kind:24s} {len(d):4d}  dE {dE:5.1f}  da* {da:5.1f}  dL* {dL:6.1f}  db* {db:5.1f}")


def real(folder):
    out = []
    for sub in sorted(os.listdir(folder)):
        p = os.path.join(folder, sub)
        names = [x for x in os.listdir(p) if x.lower().endswith((".jpg", ".jpeg", ".png"))
                 and x not in REAL_MASKS] if os.path.isdir(p) else []
        if not names:
            continue
        im = cv2.imread(os.path.join(p, names[0]))
        les = cv2.imread(os.path.join(p, "lesions.png"), cv2.IMREAD_GRAYSCALE) > 0
        ns = cv2.imread(os.path.join(p, "nonskin.png"), cv2.IMREAD_GRAYSCALE) > 0
        near = cv2.dilate(les.astype(np.uint8), np.ones((25, 25), np.uint8)) > 0
        img, healthy, lesion, skin = _resized(im, ~near & ~ns, les, ~les & ~ns)
        out.append((spread(img, healthy), contrast(img, lesion, skin), shade(img, healthy)))
    return out


def report(name, rows):
    spreads = [r[0] for r in rows if r[0] is not None]
    if not spreads:
        print(f"{name}: no image with enough healthy skin")
        return
    v = np.array(spreads)
    pct = lambda x: "/".join(f"{y:.3g}" for y in np.percentile(x, [10, 50, 90]))  # noqa: E731
    dLab = np.array([r[1] for r in rows if r[1] is not None]).reshape(-1, 3)
    dE = np.linalg.norm(dLab, axis=1)
    sh = np.array([r[2] for r in rows if r[2] is not None])
    lesion = (f"lesion dE ({len(dE)}) {pct(dE)}  da* {pct(dLab[:, 1])}  dL* {pct(dLab[:, 0])}"
              if len(dE) else "lesion dE (0) -")
    print(f"{name} ({len(v)} images): L std/mean {pct(v[:, 0])}  a* std {pct(v[:, 1])}  "
          f"b* std {pct(v[:, 2])}  mean Lab {v[:, 3].mean():.1f} {v[:, 4].mean():.1f} "
          f"{v[:, 5].mean():.1f}  {lesion}  "
          f"deep shade {pct(sh)}, {(sh >= 0.05).mean():.0%} of images at 5% or more")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("outputs", nargs="*", help="glsynth output folders")
    ap.add_argument("--real", action="append", default=[], help="folder in the Fitzpatrick17k layout")
    ap.add_argument("--by-kind", action="store_true", help="lesion contrast per kind of lesion")
    args = ap.parse_args()
    for r in args.real:
        report(r, real(r))
    for o in args.outputs:
        report(o, synthetic(o))
        if args.by_kind:
            report_kinds(o, by_kind(o))


if __name__ == "__main__":
    main()
