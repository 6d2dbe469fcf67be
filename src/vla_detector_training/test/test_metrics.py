"""mAP and centre error on hand-made predictions with known answers."""

import numpy as np
import pytest
from vla_detector_training.metrics import ImageResult, average_precision, evaluate, iou_matrix

NAMES = ["a", "b"]


def img(gt, gtc, pred=None, scores=None, pc=None):
    gt = np.array(gt, float).reshape(-1, 4)
    pred = gt.copy() if pred is None else np.array(pred, float).reshape(-1, 4)
    return ImageResult(
        gt,
        np.array(gtc, int),
        pred,
        np.array(scores if scores is not None else [0.9] * len(pred)),
        np.array(pc if pc is not None else gtc, int),
    )


def test_perfect_predictions():
    m = evaluate([img([[10, 10, 8, 8], [30, 30, 10, 6]], [0, 1])], NAMES)
    assert m.map50 == pytest.approx(1.0) and m.map50_95 == pytest.approx(1.0)
    assert m.centre_error_px == pytest.approx(0.0) and m.precision == 1.0 and m.recall == 1.0


def test_shifted_centres_give_known_error_and_lower_strict_map():
    # 3-4-5 shift on a 40x40 box: IoU = (37*36)/(2*1600 - 37*36) = 0.713 -> counts at 0.5..0.7 only.
    m = evaluate([img([[50, 50, 40, 40]], [0], pred=[[53, 54, 40, 40]])], NAMES)
    assert m.centre_error_px == pytest.approx(5.0)
    assert m.map50 == pytest.approx(1.0)
    assert m.map50_95 == pytest.approx(5 / 10)  # thresholds 0.5, 0.55, 0.6, 0.65, 0.7 of 10


def test_false_positive_and_missed_object():
    r = img(
        [[10, 10, 8, 8], [30, 30, 8, 8]],
        [0, 0],
        pred=[[10, 10, 8, 8], [60, 60, 8, 8]],
        scores=[0.9, 0.95],
        pc=[0, 0],
    )
    m = evaluate([r], NAMES)
    assert m.precision == 0.5 and m.recall == 0.5
    # ranked FP then TP: precision at recall 0.5 is 0.5, recall 1 never reached -> AP = 0.5 * 51/101
    assert m.map50 == pytest.approx(0.5 * 51 / 101)
    assert list(m.per_class_ap50) == ["a"]  # class b has no ground truth: not averaged


def test_wrong_class_is_not_a_match():
    m = evaluate([img([[10, 10, 8, 8]], [0], pc=[1])], NAMES)
    assert m.map50 == 0.0 and np.isnan(m.centre_error_px)


def test_score_threshold_limits_centre_error_only():
    r = img([[10, 10, 8, 8]], [0], pred=[[11, 10, 8, 8]], scores=[0.2])
    m = evaluate([r], NAMES, score_threshold=0.3)
    assert m.map50 == pytest.approx(1.0) and np.isnan(m.centre_error_px) and m.recall == 0.0


def test_helpers():
    assert iou_matrix(np.array([[0, 0, 2, 2]]), np.array([[1, 0, 2, 2]]))[0, 0] == pytest.approx(1 / 3)
    assert np.isnan(average_precision(np.zeros(0, bool), np.zeros(0), 0))
    assert average_precision(np.zeros(0, bool), np.zeros(0), 3) == 0.0
