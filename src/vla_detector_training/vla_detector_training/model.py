"""A compact single-stage, anchor-free, centre-based detector (CenterNet/YOLOv8 family) in PyTorch.

Trained from scratch on a 2-core CPU, so it is small: a plain conv backbone down to stride 16, one
top-down fusion to stride 8, and one head at stride 8 predicting per cell a class heat map (a peak at
each object centre) and the box (centre offset from the cell, log width and height). Stride 8 at
320x240 gives a 40x30 grid; the regressed offset brings the centre to sub-pixel precision.

`DetectorNet.forward` returns raw maps for training; `ExportWrapper` decodes them inside the graph to
the Ultralytics YOLOv8 output layout `[1, 4 + nc, N]` (cx, cy, w, h in input pixels, then per-class
scores in [0, 1]), so one decoder reads our models and Ultralytics exports alike.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from torch import nn

STRIDE = 8


@dataclass
class ModelConfig:
    """Architecture hyper-parameters, saved beside the weights so a checkpoint rebuilds its model."""

    num_classes: int
    width: int = 32  # channels at stride 4; doubled at stride 8, x3 at stride 16
    input_width: int = 320
    input_height: int = 240

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> ModelConfig:
        return cls(**{k: int(v) for k, v in d.items() if k in cls.__dataclass_fields__})


def conv_bn(c_in: int, c_out: int, k: int = 3, s: int = 1) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(c_in, c_out, k, s, k // 2, bias=False), nn.BatchNorm2d(c_out), nn.ReLU(inplace=True)
    )


class Residual(nn.Module):
    """Two 3x3 convs with a skip: depth (receptive field) without hurting optimisation."""

    def __init__(self, c: int) -> None:
        super().__init__()
        self.a = conv_bn(c, c)
        self.b = nn.Sequential(nn.Conv2d(c, c, 3, 1, 1, bias=False), nn.BatchNorm2d(c))
        self.act = nn.ReLU(inplace=True)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.act(x + self.b(self.a(x)))


class DetectorNet(nn.Module):
    """Backbone (strides 2-16) + top-down fusion + head at stride 8."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.cfg = cfg
        w = cfg.width
        nc = cfg.num_classes
        self.stem = nn.Sequential(conv_bn(3, w // 2, 3, 2), conv_bn(w // 2, w, 3, 2))  # stride 4
        self.s4 = Residual(w)
        self.s8 = nn.Sequential(conv_bn(w, 2 * w, 3, 2), Residual(2 * w))
        self.s16 = nn.Sequential(conv_bn(2 * w, 3 * w, 3, 2), Residual(3 * w), Residual(3 * w))
        self.up = nn.Upsample(scale_factor=2, mode="nearest")
        self.fuse = nn.Sequential(conv_bn(5 * w, 2 * w, 1), conv_bn(2 * w, 2 * w))
        self.cls_head = nn.Sequential(conv_bn(2 * w, 2 * w), nn.Conv2d(2 * w, nc, 1))
        self.box_head = nn.Sequential(conv_bn(2 * w, 2 * w), nn.Conv2d(2 * w, 4, 1))
        # Start with a low foreground probability (focal-loss practice) so early training is stable.
        nn.init.constant_(self.cls_head[-1].bias, -4.6)
        nn.init.zeros_(self.box_head[-1].bias)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """x: (B, 3, H, W) RGB in [0, 1] -> (class logits (B, nc, H/8, W/8), box (B, 4, H/8, W/8)).

        Box channels: centre offset (dx, dy) from the cell centre in cells, log(w / 8), log(h / 8).
        """
        f4 = self.s4(self.stem(x))
        f8 = self.s8(f4)
        f16 = self.s16(f8)
        f = self.fuse(torch.cat([f8, self.up(f16)], dim=1))
        return self.cls_head(f), self.box_head(f)


def grid_centres(h: int, w: int, device=None) -> tuple[torch.Tensor, torch.Tensor]:
    """Cell-centre coordinates in cells, each (h, w)."""
    ys = torch.arange(h, dtype=torch.float32, device=device) + 0.5
    xs = torch.arange(w, dtype=torch.float32, device=device) + 0.5
    gy, gx = torch.meshgrid(ys, xs, indexing="ij")
    return gx, gy


def decode_boxes(box: torch.Tensor) -> torch.Tensor:
    """Raw box maps (B, 4, h, w) -> (B, 4, h, w) cx, cy, w, h in input pixels."""
    _, _, h, w = box.shape
    gx, gy = grid_centres(h, w, box.device)
    cx = (gx + box[:, 0]) * STRIDE
    cy = (gy + box[:, 1]) * STRIDE
    bw = torch.exp(box[:, 2].clamp(-6.0, 6.0)) * STRIDE
    bh = torch.exp(box[:, 3].clamp(-6.0, 6.0)) * STRIDE
    return torch.stack([cx, cy, bw, bh], dim=1)


def raw_to_output(cls_logits: torch.Tensor, box: torch.Tensor) -> torch.Tensor:
    """Raw maps -> YOLOv8 layout (B, 4 + nc, N): boxes in input pixels, then sigmoid class scores."""
    b, nc, h, w = cls_logits.shape
    boxes = decode_boxes(box).reshape(b, 4, h * w)
    return torch.cat([boxes, torch.sigmoid(cls_logits).reshape(b, nc, h * w)], dim=1)


class ExportWrapper(nn.Module):
    """Wraps a DetectorNet so its output is the YOLOv8 layout [B, 4 + nc, N] (N = cells)."""

    def __init__(self, net: DetectorNet) -> None:
        super().__init__()
        self.net = net

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        return raw_to_output(*self.net(images))


def count_parameters(net: nn.Module) -> int:
    return sum(p.numel() for p in net.parameters())
