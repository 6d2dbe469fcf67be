"""Training targets and loss of the centre-based detector (CenterNet / TTFNet style).

Each object puts a Gaussian peak (value 1 at the cell holding its centre) into its class's heat map;
the cells around the peak regress the box, weighted by the Gaussian, so the neighbours that NMS may
keep also predict the right box. Classification uses CenterNet's penalty-reduced focal loss; boxes
use L1 on centre offset and log size plus GIoU.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from vla_detector_training.model import STRIDE, decode_boxes

SIGMA_SCALE = 0.54 / 6  # TTFNet: sigma = alpha * size / 6, size in cells
MIN_SIGMA = 0.5  # cells
REG_MIN_WEIGHT = 0.2  # cells whose Gaussian value is below this do not regress the box


def build_targets(
    boxes: list[np.ndarray], classes: list[np.ndarray], num_classes: int, grid_h: int, grid_w: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per-image boxes (K, 4) cx, cy, w, h in input pixels -> (heat (B, nc, h, w), reg (B, 4, h, w),
    reg weight (B, h, w))."""
    b = len(boxes)
    heat = np.zeros((b, num_classes, grid_h, grid_w), dtype=np.float32)
    reg = np.zeros((b, 4, grid_h, grid_w), dtype=np.float32)
    wt = np.zeros((b, grid_h, grid_w), dtype=np.float32)
    gx = np.arange(grid_w, dtype=np.float32) + 0.5
    gy = np.arange(grid_h, dtype=np.float32) + 0.5
    for i in range(b):
        bx, cl = boxes[i], classes[i]
        if len(bx) == 0:
            continue
        # Larger objects first, so a smaller one in front wins the shared cells.
        for k in np.argsort(-(bx[:, 2] * bx[:, 3])):
            cx, cy, w, h = (float(v) / STRIDE for v in bx[k])
            if w <= 0 or h <= 0:
                continue
            sx, sy = max(MIN_SIGMA, SIGMA_SCALE * w), max(MIN_SIGMA, SIGMA_SCALE * h)
            g = np.exp(-((gx[None, :] - cx) ** 2) / (2 * sx * sx) - ((gy[:, None] - cy) ** 2) / (2 * sy * sy))
            ci = min(max(int(math.floor(cx)), 0), grid_w - 1)
            cj = min(max(int(math.floor(cy)), 0), grid_h - 1)
            g[cj, ci] = 1.0
            c = int(cl[k])
            heat[i, c] = np.maximum(heat[i, c], g)
            inside = (np.abs(gx[None, :] - cx) <= w / 2 + 0.5) & (np.abs(gy[:, None] - cy) <= h / 2 + 0.5)
            m = (g >= REG_MIN_WEIGHT) & inside
            m[cj, ci] = True
            reg[i, 0][m] = (cx - np.broadcast_to(gx[None, :], m.shape))[m]
            reg[i, 1][m] = (cy - np.broadcast_to(gy[:, None], m.shape))[m]
            reg[i, 2][m] = math.log(w)
            reg[i, 3][m] = math.log(h)
            wt[i][m] = g[m]
    return torch.from_numpy(heat), torch.from_numpy(reg), torch.from_numpy(wt)


def focal_loss(
    logits: torch.Tensor, heat: torch.Tensor, alpha: float = 2.0, beta: float = 4.0
) -> torch.Tensor:
    """CenterNet's penalty-reduced focal loss, normalised by the number of objects."""
    p = torch.sigmoid(logits).clamp(1e-4, 1 - 1e-4)
    pos = heat.eq(1.0).float()
    neg = 1.0 - pos
    pos_loss = -torch.log(p) * (1 - p) ** alpha * pos
    neg_loss = -torch.log(1 - p) * p**alpha * (1 - heat) ** beta * neg
    n = pos.sum().clamp(min=1.0)
    return (pos_loss.sum() + neg_loss.sum()) / n


def giou(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Generalised IoU of matching (N, 4) cx, cy, w, h boxes."""
    a1, a2 = a[:, :2] - a[:, 2:] / 2, a[:, :2] + a[:, 2:] / 2
    b1, b2 = b[:, :2] - b[:, 2:] / 2, b[:, :2] + b[:, 2:] / 2
    inter = (torch.min(a2, b2) - torch.max(a1, b1)).clamp(min=0).prod(1)
    union = a[:, 2:].prod(1) + b[:, 2:].prod(1) - inter
    iou = inter / union.clamp(min=1e-9)
    hull = (torch.max(a2, b2) - torch.min(a1, b1)).clamp(min=0).prod(1)
    return iou - (hull - union) / hull.clamp(min=1e-9)


def detection_loss(
    cls_logits: torch.Tensor, box: torch.Tensor, heat: torch.Tensor, reg: torch.Tensor, wt: torch.Tensor
) -> tuple[torch.Tensor, dict[str, float]]:
    """Total loss and its parts (for the progress bar)."""
    l_cls = focal_loss(cls_logits, heat)
    mask = wt > 0
    if mask.any():
        w = wt[mask]
        wsum = w.sum()
        pred = box.permute(0, 2, 3, 1)[mask]  # (M, 4)
        tgt = reg.permute(0, 2, 3, 1)[mask]
        l_off = ((pred[:, :2] - tgt[:, :2]).abs().sum(1) * w).sum() / wsum
        l_size = ((pred[:, 2:] - tgt[:, 2:]).abs().sum(1) * w).sum() / wsum
        pb = decode_boxes(box).permute(0, 2, 3, 1)[mask]
        gh, gw = box.shape[2:]
        ys, xs = torch.meshgrid(torch.arange(gh), torch.arange(gw), indexing="ij")
        cell = torch.stack([xs, ys], -1)[None].expand(box.shape[0], -1, -1, -1)[mask].float() + 0.5
        tb = torch.cat([(cell + tgt[:, :2]) * STRIDE, torch.exp(tgt[:, 2:]) * STRIDE], dim=1)
        l_giou = ((1 - giou(pb, tb)) * w).sum() / wsum
    else:
        l_off = l_size = l_giou = cls_logits.sum() * 0
    total = l_cls + 2.0 * l_off + 1.0 * l_size + 2.0 * l_giou
    parts = {
        k: float(v.detach()) for k, v in (("cls", l_cls), ("off", l_off), ("size", l_size), ("giou", l_giou))
    }
    return total, parts
