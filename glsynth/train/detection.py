"""Lesion boxes from a segmentation and the paper's detection metrics.

A segmenter becomes a detector by taking each 8-connected component of its lesion mask
as one lesion: its box, and as its confidence the mean lesion probability inside it.
The truth boxes come the same way from the true lesion mask (or from a dataset's boxes).

Per image, detections are matched to truth boxes greedily in order of falling
confidence, as in the PASCAL VOC evaluation the DermSynth3D code uses: each detection is
compared with the truth box it overlaps most (highest IoU); it is a true positive when
the match rule holds for that box and the box has not been taken by a more confident
detection, else a false positive. Two match rules:

* ``centroid`` (AP_centroid, Zhao et al.'s Skin3D): each box contains the other's
  centre, strictly inside; it judges where a lesion is rather than its exact extent;
* ``iou``: IoU > 0.5 (the usual AP50).

AP is the area under the precision-recall curve with every-point interpolation
(precision made non-increasing from the right). Box IoU is the mean over truth boxes of
the IoU of the detection first matched to them (0 for a truth box nobody overlaps), the
paper's "IoU". Boxes are ``[x0, y0, x1, y1]`` in pixels with exclusive ends. Images
without truth boxes have no AP and are left out of the means (counted separately).
"""
from __future__ import annotations

import cv2
import numpy as np


def mask_boxes(mask: np.ndarray, prob: np.ndarray | None = None, min_area: int = 1):
    """Boxes ``[x0, y0, x1, y1)`` (int) of the 8-connected components of ``mask`` with at
    least ``min_area`` pixels, and their scores: the mean of ``prob`` over each component
    (1.0 without ``prob``). Returns (boxes N x 4 int64, scores N float64)."""
    m = np.ascontiguousarray(np.asarray(mask, bool).view(np.uint8))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    keep = [k for k in range(1, n) if stats[k, cv2.CC_STAT_AREA] >= min_area]
    boxes = np.array([[stats[k, cv2.CC_STAT_LEFT], stats[k, cv2.CC_STAT_TOP],
                       stats[k, cv2.CC_STAT_LEFT] + stats[k, cv2.CC_STAT_WIDTH],
                       stats[k, cv2.CC_STAT_TOP] + stats[k, cv2.CC_STAT_HEIGHT]] for k in keep],
                     np.int64).reshape(-1, 4)
    if prob is None or not keep:
        return boxes, np.ones(len(keep))
    sums = np.bincount(labels.ravel(), weights=np.asarray(prob, np.float64).ravel(), minlength=n)
    return boxes, sums[keep] / stats[keep, cv2.CC_STAT_AREA]


def box_iou(a, b) -> np.ndarray:
    """IoU of every box in ``a`` (N x 4) with every box in ``b`` (M x 4): N x M."""
    a = np.asarray(a, np.float64).reshape(-1, 4)
    b = np.asarray(b, np.float64).reshape(-1, 4)
    lo = np.maximum(a[:, None, :2], b[None, :, :2])
    hi = np.minimum(a[:, None, 2:], b[None, :, 2:])
    inter = np.prod(np.clip(hi - lo, 0, None), axis=-1)
    area_a = np.prod(a[:, 2:] - a[:, :2], axis=1)
    area_b = np.prod(b[:, 2:] - b[:, :2], axis=1)
    union = area_a[:, None] + area_b[None, :] - inter
    return np.where(union > 0, inter / np.where(union > 0, union, 1), 0.0)


def contains_centre(outer, inner) -> bool:
    """True when ``inner``'s centre lies strictly inside ``outer``."""
    cx, cy = (inner[0] + inner[2]) / 2, (inner[1] + inner[3]) / 2
    return bool(outer[0] < cx < outer[2] and outer[1] < cy < outer[3])


def centroids_match(det, truth) -> bool:
    """Skin3D's rule: each box contains the other's centre."""
    return contains_centre(det, truth) and contains_centre(truth, det)


def average_precision(tp: np.ndarray, n_truth: int) -> float:
    """Every-point interpolated AP of detections already sorted by falling confidence
    (``tp``: 1 for a true positive, 0 for a false one)."""
    if n_truth == 0:
        return float("nan")
    tp = np.asarray(tp, np.float64)
    if not len(tp):
        return 0.0
    ctp, cfp = np.cumsum(tp), np.cumsum(1 - tp)
    recall = np.concatenate([[0.0], ctp / n_truth, [1.0]])
    precision = np.concatenate([[0.0], ctp / (ctp + cfp), [0.0]])
    precision = np.maximum.accumulate(precision[::-1])[::-1]  # non-increasing from the right
    steps = np.flatnonzero(np.diff(recall)) + 1
    return float(np.sum((recall[steps] - recall[steps - 1]) * precision[steps]))


def match(det_boxes, det_scores, truth_boxes, rule="centroid", score_threshold=0.0) -> dict:
    """Greedy matching of one image's detections (those scoring at least
    ``score_threshold``) to its truth boxes. Returns tp (per detection, by falling score),
    the AP, box IoU, precision, recall and counts."""
    if rule not in ("centroid", "iou"):
        raise ValueError(f"match rule must be 'centroid' or 'iou', got {rule!r}")
    det_boxes = np.asarray(det_boxes).reshape(-1, 4)
    det_scores = np.asarray(det_scores, np.float64).reshape(-1)
    truth_boxes = np.asarray(truth_boxes).reshape(-1, 4)
    keep = det_scores >= score_threshold
    order = np.argsort(-det_scores[keep], kind="stable")
    dets = det_boxes[keep][order]
    ious = box_iou(dets, truth_boxes)
    n_truth = len(truth_boxes)
    taken = np.zeros(n_truth, bool)       # matched by a true positive
    iou_seen = np.zeros(n_truth, bool)    # IoU recorded (first detection overlapping it most)
    tp = np.zeros(len(dets))
    iou_sum = 0.0
    for d in range(len(dets)):
        if n_truth == 0:
            break
        j = int(np.argmax(ious[d]))
        if ious[d, j] <= 0:
            continue  # overlaps no truth box (so contains no centre either): a false positive
        if not iou_seen[j]:
            iou_seen[j] = True
            iou_sum += ious[d, j]
        ok = ious[d, j] > 0.5 if rule == "iou" else centroids_match(dets[d], truth_boxes[j])
        if ok and not taken[j]:
            taken[j] = True
            tp[d] = 1
    n_tp = int(tp.sum())
    return {"tp": tp, "n_truth": n_truth, "n_detections": len(dets), "true_positives": n_tp,
            "ap": average_precision(tp, n_truth),
            "box_iou": iou_sum / n_truth if n_truth else float("nan"),
            "precision": n_tp / len(dets) if len(dets) else float("nan"),
            "recall": n_tp / n_truth if n_truth else float("nan")}


def detection_scores(det_boxes, det_scores, truth_boxes, score_threshold=0.5) -> dict:
    """The paper's per-image detection figures: AP_centroid and AP50 over every
    detection, and box IoU, precision and recall of the detections scoring at least
    ``score_threshold`` (centroid rule)."""
    every = match(det_boxes, det_scores, truth_boxes, "centroid")
    confident = match(det_boxes, det_scores, truth_boxes, "centroid", score_threshold)
    return {"ap_centroid": every["ap"],
            "ap50": match(det_boxes, det_scores, truth_boxes, "iou")["ap"],
            "box_iou": confident["box_iou"], "precision": confident["precision"],
            "recall": confident["recall"], "n_truth_boxes": every["n_truth"],
            "n_detections": confident["n_detections"]}
