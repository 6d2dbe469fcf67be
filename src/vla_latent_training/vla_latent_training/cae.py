"""The conditional autoencoder (CAE) of latent actions and the CNN context encoder (torch, training only).

Encoder [context, q, a] → 30 → tanh → 30 → tanh → z (1-D); decoder [context, q, z] → 30 → tanh → 30 →
tanh → a, as in the paper's public code. ``bounded`` puts a tanh on z so the stick's [-1, 1] can span it;
``signed`` makes the latent's sign the pair's direction (z = ±|tanh(·)|: demonstrated motion +, its
reverse −), so + means "do the task" in every context by construction.
"""

from __future__ import annotations

import warnings

import torch
from torch import nn
from vla_latent_controller.context import CNN_FEATURE_DIM, CNN_INPUT_SIZE


class _TanhFn(torch.autograd.Function):
    """tanh(x) computed as 2·sigmoid(2x) − 1: the same function, about twice as fast on CPU (torch's tanh
    kernel is the largest single cost of training these small MLPs)."""

    @staticmethod
    def forward(ctx, x: torch.Tensor) -> torch.Tensor:
        y = torch.sigmoid(x * 2.0).mul_(2.0).sub_(1.0)
        ctx.save_for_backward(y)
        return y

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> torch.Tensor:
        (y,) = ctx.saved_tensors
        return torch.ops.aten.tanh_backward(grad, y)


class Tanh(nn.Module):
    """Drop-in for nn.Tanh (no parameters, so state-dict names are unchanged)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return _TanhFn.apply(x)


def mlp(n_in: int, n_out: int, hidden: int = 30) -> nn.Sequential:
    """Linear → tanh → Linear → tanh → Linear; tensors named ``0``, ``2``, ``4`` as in the paper's code."""
    return nn.Sequential(
        nn.Linear(n_in, hidden), Tanh(), nn.Linear(hidden, hidden), Tanh(), nn.Linear(hidden, n_out)
    )


class CAE(nn.Module):
    """Conditional autoencoder; ``decoder`` alone is what the teleoperation controller runs."""

    def __init__(
        self,
        context_dim: int,
        n_joints: int = 7,
        latent_dim: int = 1,
        hidden: int = 30,
        bounded: bool = True,
        signed: bool = False,
    ):
        super().__init__()
        self.bounded, self.signed = bounded, signed
        self.encoder = mlp(context_dim + 2 * n_joints, latent_dim, hidden)
        self.decoder = mlp(context_dim + n_joints + latent_dim, n_joints, hidden)

    def encode(
        self, ctx: torch.Tensor, q: torch.Tensor, a: torch.Tensor, direction: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Latent of (context, q, a); ``direction`` (N, 1) of ±1 fixes the sign when ``signed``."""
        z = self.encoder(torch.cat([ctx, q, a], dim=-1))
        z = torch.tanh(z) if self.bounded else z
        if self.signed:
            z = z.abs() * (direction if direction is not None else 1.0)
        return z

    def decode(self, ctx: torch.Tensor, q: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        return self.decoder(torch.cat([ctx, q, z], dim=-1))

    def forward(
        self, ctx: torch.Tensor, q: torch.Tensor, a: torch.Tensor, direction: torch.Tensor | None = None
    ) -> torch.Tensor:
        return self.decode(ctx, q, self.encode(ctx, q, a, direction))


class ContextCNN(nn.Module):
    """Small conv net with max-pooling on a downscaled RGB image → dense feature vector (paper Sec. 4.1)."""

    def __init__(self, feature_dim: int = CNN_FEATURE_DIM, input_size: tuple[int, int] = CNN_INPUT_SIZE):
        super().__init__()
        w, h = input_size
        self.net = nn.Sequential(
            nn.Conv2d(3, 16, 5, padding=2),
            nn.ReLU(),
            nn.MaxPool2d(2),
            nn.Conv2d(16, 32, 3, padding=1),
            nn.ReLU(),
            nn.MaxPool2d(2),
            nn.Conv2d(32, 32, 3, padding=1),
            nn.ReLU(),
            nn.MaxPool2d(2),
            nn.Flatten(),
            nn.Linear(32 * (h // 8) * (w // 8), feature_dim),
            nn.Tanh(),
        )

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        return self.net(images)


def export_cnn_onnx(cnn: ContextCNN, path: str, input_size: tuple[int, int] = CNN_INPUT_SIZE) -> None:
    """Write the CNN as ONNX (input ``image`` (N, 3, h, w) float32 in [0, 1], output ``feature``)."""
    w, h = input_size
    cnn = cnn.eval()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            cnn,
            (torch.zeros(1, 3, h, w),),
            path,
            dynamo=False,
            input_names=["image"],
            output_names=["feature"],
            dynamic_axes={"image": {0: "n"}, "feature": {0: "n"}},
            opset_version=17,
        )
