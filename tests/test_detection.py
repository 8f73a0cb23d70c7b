"""Lesion boxes from masks and the paper's detection metrics, against hand-worked cases."""
import numpy as np
import pytest

from glsynth.train.detection import (average_precision, box_iou, detection_scores, mask_boxes,
                                     match)


def test_mask_boxes_are_8_connected_components_with_mean_probability():
    m = np.zeros((10, 12), bool)
    m[1:3, 1:4] = True          # 6 px
    m[3, 4] = True              # touches the first one diagonally: same component
    m[6:9, 8:11] = True         # 9 px
    m[0, 11] = True             # 1 px
    prob = np.where(m, 0.5, 0.0)
    prob[6:9, 8:11] = 0.9
    boxes, scores = mask_boxes(m, prob, min_area=2)
    order = np.argsort(boxes[:, 0])
    assert boxes[order].tolist() == [[1, 1, 5, 4], [8, 6, 11, 9]]
    assert scores[order] == pytest.approx([0.5, 0.9])
    boxes, scores = mask_boxes(m)
    assert len(boxes) == 3 and np.all(scores == 1)


def test_box_iou_by_hand():
    a = [[0, 0, 10, 10]]
    b = [[5, 0, 15, 10], [20, 20, 30, 30], [0, 0, 10, 10]]
    assert box_iou(a, b)[0] == pytest.approx([50 / 150, 0.0, 1.0])


def test_average_precision_every_point_by_hand():
    # TP, FP, TP against 2 truths: precision 1, 1/2, 2/3 at recall 1/2, 1/2, 1
    # interpolated: 1 up to recall 1/2, then 2/3 -> AP = 0.5 * 1 + 0.5 * 2/3
    assert average_precision([1, 0, 1], 2) == pytest.approx(0.5 + 1 / 3)
    assert average_precision([0, 1], 1) == pytest.approx(0.5)
    assert average_precision([], 3) == 0.0
    assert np.isnan(average_precision([1], 0))


def test_greedy_matching_counts_duplicates_as_false_positives():
    truth = [[0, 0, 10, 10], [20, 20, 30, 30]]
    dets = [[0, 0, 10, 10], [1, 1, 11, 11], [21, 21, 29, 29], [50, 50, 60, 60]]
    scores = [0.9, 0.8, 0.7, 0.95]
    r = match(dets, scores, truth, "iou")
    # by falling score: far-away FP, TP, duplicate FP, TP
    assert r["tp"].tolist() == [0, 1, 0, 1]
    # precision 0, 1/2, 1/3, 1/2 at recall 0, 1/2, 1/2, 1 -> interpolated 1/2 up to recall 1
    assert r["ap"] == pytest.approx(0.5)
    # box IoU: each truth box's IoU with the first detection overlapping it most
    assert r["box_iou"] == pytest.approx((1.0 + 64 / 100) / 2)


def test_centroid_rule_accepts_what_iou_rejects():
    truth = [[10, 10, 20, 20]]
    big = [[0, 0, 30, 30]]           # contains the truth's centre and vice versa; IoU 1/9
    assert box_iou(big, truth)[0, 0] == pytest.approx(100 / 900)
    s = detection_scores(big, [0.8], truth)
    assert s["ap_centroid"] == 1.0 and s["ap50"] == 0.0
    assert s["box_iou"] == pytest.approx(1 / 9)
    # shifted so that the truth's centre (15, 15) is outside the detection: no match
    off = [[16, 0, 46, 30]]
    assert detection_scores(off, [0.8], truth)["ap_centroid"] == 0.0


def test_score_threshold_only_filters_the_thresholded_figures():
    truth = [[0, 0, 10, 10]]
    s = detection_scores([[0, 0, 10, 10]], [0.3], truth, score_threshold=0.5)
    assert s["ap_centroid"] == 1.0                 # AP uses every detection
    assert s["recall"] == 0.0 and s["box_iou"] == 0.0 and s["n_detections"] == 0
    assert np.isnan(detection_scores([], [], [])["ap_centroid"])  # no truth: no AP
