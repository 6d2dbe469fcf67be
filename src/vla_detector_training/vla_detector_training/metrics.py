"""Detection metrics: COCO-style mAP@0.5 and mAP@0.5:0.95, and the mean centre error in pixels.

mAP: per class, predictions of all images sorted by score are greedily matched to unmatched ground
truth of the same class and image at IoU >= t; AP is the area under the 101-point interpolated
precision-recall curve (COCO); mAP averages the classes that have ground truth. Centre error: mean
pixel distance between matched ground-truth and predicted centres at IoU >= 0.5, counting only
predictions above the deployment score threshold — the (x, y) the latent-action model receives.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

IOU_THRESHOLDS = np.round(np.arange(0.5, 0.96, 0.05), 2)


@dataclass
class ImageResult:
    """Ground truth and predictions of one image; boxes (N, 4) cx, cy, w, h in pixels."""

    gt_boxes: np.ndarray
    gt_classes: np.ndarray
    pred_boxes: np.ndarray
    pred_scores: np.ndarray
    pred_classes: np.ndarray


@dataclass
class Metrics:
    map50: float
    map50_95: float
    centre_error_px: float  # NaN when nothing matched
    precision: float  # at the score threshold, IoU 0.5
    recall: float
    per_class_ap50: dict[str, float]

    def lines(self) -> list[str]:
        return [
            f"mAP@0.5: {self.map50:.4f}",
            f"mAP@0.5:0.95: {self.map50_95:.4f}",
            f"mean centre error px: {self.centre_error_px:.3f}",
            f"precision: {self.precision:.4f}",
            f"recall: {self.recall:.4f}",
        ]


def xyxy(b: np.ndarray) -> np.ndarray:
    b = np.asarray(b, dtype=np.float64).reshape(-1, 4)
    return np.stack(
        [b[:, 0] - b[:, 2] / 2, b[:, 1] - b[:, 3] / 2, b[:, 0] + b[:, 2] / 2, b[:, 1] + b[:, 3] / 2], 1
    )


def iou_matrix(a_cxcywh: np.ndarray, b_cxcywh: np.ndarray) -> np.ndarray:
    """Pairwise IoU (len(a), len(b)) of cx, cy, w, h boxes."""
    a, b = xyxy(a_cxcywh), xyxy(b_cxcywh)
    lt = np.maximum(a[:, None, :2], b[None, :, :2])
    rb = np.minimum(a[:, None, 2:], b[None, :, 2:])
    inter = np.clip(rb - lt, 0, None).prod(axis=2)
    area_a = (a[:, 2:] - a[:, :2]).prod(axis=1)
    area_b = (b[:, 2:] - b[:, :2]).prod(axis=1)
    union = area_a[:, None] + area_b[None, :] - inter
    return np.where(union > 0, inter / np.maximum(union, 1e-12), 0.0)


def average_precision(tp: np.ndarray, scores: np.ndarray, n_gt: int) -> float:
    """COCO 101-point interpolated AP of one class at one IoU threshold."""
    if n_gt == 0:
        return float("nan")
    if len(tp) == 0:
        return 0.0
    order = np.argsort(-scores, kind="stable")
    tp = tp[order].astype(np.float64)
    ctp, cfp = np.cumsum(tp), np.cumsum(1 - tp)
    recall = ctp / n_gt
    precision = ctp / np.maximum(ctp + cfp, 1e-12)
    precision = np.maximum.accumulate(precision[::-1])[::-1]  # monotone envelope
    rs = np.linspace(0, 1, 101)
    idx = np.searchsorted(recall, rs, side="left")
    return float(np.where(idx < len(precision), precision[np.minimum(idx, len(precision) - 1)], 0.0).mean())


def _match(results: list[ImageResult], cls: int, thr: float, min_score: float = -np.inf):
    """Greedy matching of class `cls` at IoU >= thr: (tp flags, scores, centre distances, n_gt)."""
    items = []  # (score, image index, prediction index)
    n_gt = 0
    for i, r in enumerate(results):
        n_gt += int((r.gt_classes == cls).sum())
        for j in np.nonzero((r.pred_classes == cls) & (r.pred_scores >= min_score))[0]:
            items.append((float(r.pred_scores[j]), i, int(j)))
    items.sort(key=lambda t: -t[0])
    used = [np.zeros(len(r.gt_classes), dtype=bool) for r in results]
    ious = {}
    tp = np.zeros(len(items), dtype=bool)
    dists = []
    for k, (_, i, j) in enumerate(items):
        r = results[i]
        gt_idx = np.nonzero(r.gt_classes == cls)[0]
        if len(gt_idx) == 0:
            continue
        if i not in ious:
            ious[i] = iou_matrix(r.pred_boxes, r.gt_boxes[gt_idx]) if len(r.pred_boxes) else None
        iou = ious[i][j].copy()
        iou[used[i][gt_idx]] = -1
        best = int(np.argmax(iou))
        if iou[best] >= thr:
            used[i][gt_idx[best]] = True
            tp[k] = True
            g = r.gt_boxes[gt_idx[best]]
            dists.append(float(np.hypot(r.pred_boxes[j][0] - g[0], r.pred_boxes[j][1] - g[1])))
    scores = np.array([t[0] for t in items], dtype=np.float64)
    return tp, scores, dists, n_gt


def evaluate(results: list[ImageResult], class_names: list[str], score_threshold: float = 0.3) -> Metrics:
    """All metrics over a list of images. Predictions should be kept down to a low score (0.001)."""
    aps = np.full((len(class_names), len(IOU_THRESHOLDS)), np.nan)
    all_d: list[float] = []
    n_tp = n_pred = n_gt_all = 0
    for c in range(len(class_names)):
        for t, thr in enumerate(IOU_THRESHOLDS):
            tp, scores, _, n_gt = _match(results, c, float(thr))
            aps[c, t] = average_precision(tp, scores, n_gt)
        tp, _, d, n_gt = _match(results, c, 0.5, min_score=score_threshold)
        all_d += d
        n_tp += int(tp.sum())
        n_pred += len(tp)
        n_gt_all += n_gt
    has_gt = ~np.isnan(aps[:, 0])
    map50 = float(aps[has_gt, 0].mean()) if has_gt.any() else float("nan")
    map5095 = float(aps[has_gt].mean()) if has_gt.any() else float("nan")
    return Metrics(
        map50=map50,
        map50_95=map5095,
        centre_error_px=float(np.mean(all_d)) if all_d else float("nan"),
        precision=n_tp / n_pred if n_pred else float("nan"),
        recall=n_tp / n_gt_all if n_gt_all else float("nan"),
        per_class_ap50={class_names[c]: float(aps[c, 0]) for c in range(len(class_names)) if has_gt[c]},
    )
