"""Warm start: a new detector begins from an existing one's weights (the backbone kept, the class head
resized to the new class list).

The source is a training checkpoint (`.safetensors`, exact) or an exported ONNX model such as the
shipped `vla_detector/models/detector.onnx`. The ONNX export folded every BatchNorm into the
convolution before it, so its weights give the network's function but not the BatchNorm statistics:
`net_from_onnx` sets each BatchNorm to pass the folded bias through (the same function in eval mode,
checked against ONNX Runtime), and `recalibrate_batchnorm` then gives the BatchNorms the statistics
of the new training images, so training (which normalises by batch statistics) starts from the
same function too. Nothing is loaded with pickle.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import torch
from onnx import numpy_helper
from torch import nn

from vla_detector_training.export import load_checkpoint
from vla_detector_training.model import DetectorNet, ExportWrapper, ModelConfig

HEAD_WEIGHT, HEAD_BIAS = "cls_head.1.weight", "cls_head.1.bias"


class WarmStartError(ValueError):
    """A source model that cannot be warm-started from (the message says why)."""


@dataclass
class Source:
    net: DetectorNet
    classes: list[str]
    path: Path
    from_onnx: bool  # BatchNorm statistics are not in the file: recalibrate on data


def load_source(path: str | os.PathLike) -> Source:
    """A checkpoint (.safetensors), an ONNX model (.onnx), or a training run folder holding either."""
    p = Path(path)
    if p.is_dir():
        found = [p / n for n in ("best.safetensors", "detector.onnx") if (p / n).is_file()]
        if not found:
            raise WarmStartError(f"{p}: no best.safetensors or detector.onnx to warm-start from")
        p = found[0]
    if not p.is_file():
        raise WarmStartError(f"{p}: no such model file")
    if p.suffix == ".safetensors":
        net, classes, _ = load_checkpoint(p)
        return Source(net, list(classes), p, from_onnx=False)
    if p.suffix == ".onnx":
        net, classes = net_from_onnx(p)
        return Source(net, classes, p, from_onnx=True)
    raise WarmStartError(f"{p}: expected a .safetensors checkpoint or an .onnx model")


def conv_call_order(net: DetectorNet) -> list[str]:
    """Names of the network's convolutions in the order its forward pass runs them (the order the
    ONNX exporter writes their nodes)."""
    order: list[str] = []
    hooks = [m.register_forward_pre_hook(lambda _m, _x, n=n: order.append(n))
             for n, m in net.named_modules() if isinstance(m, nn.Conv2d)]
    try:
        with torch.no_grad():
            net.eval()(torch.zeros(1, 3, net.cfg.input_height, net.cfg.input_width))
    finally:
        for h in hooks:
            h.remove()
    return order


def _onnx_config(path: Path, model: onnx.ModelProto, convs: list) -> tuple[ModelConfig, list[str]]:
    """The architecture and class names: from the JSON sidecar, else from the ONNX metadata."""
    meta = {p.key: p.value for p in model.metadata_props}
    side = path.with_suffix(".json")
    if side.is_file():
        doc = json.loads(side.read_text(encoding="utf-8"))
        if isinstance(doc.get("model"), dict) and doc.get("classes"):
            return ModelConfig.from_dict(doc["model"]), list(doc["classes"])
    if meta.get("format") != "vla_detector":
        raise WarmStartError(f"{path}: not a vla_detector model (an Ultralytics export cannot be "
                             "warm-started from; train from scratch or from a vla_detector model)")
    names = json.loads(meta["names"])
    classes = [names[k] for k in sorted(names, key=int)]
    h, w = json.loads(meta["imgsz"])
    width = int(convs[1].shape[0])  # the stem's second convolution has `width` channels
    return ModelConfig(num_classes=len(classes), width=width, input_width=w, input_height=h), classes


def net_from_onnx(path: str | os.PathLike) -> tuple[DetectorNet, list[str]]:
    """The torch network of an ONNX model this package exported, with the same eval-mode outputs."""
    path = Path(path)
    try:
        model = onnx.load(str(path))
    except Exception as e:  # noqa: BLE001 - onnx raises several types for an unreadable file
        raise WarmStartError(f"{path}: not a readable ONNX model: {e}") from None
    init = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer}
    nodes = [n for n in model.graph.node if n.op_type == "Conv"]
    try:
        convs = [(init[n.input[1]], init[n.input[2]] if len(n.input) > 2 else None) for n in nodes]
    except KeyError:
        raise WarmStartError(f"{path}: convolution weights are not stored as initializers") from None
    cfg, classes = _onnx_config(path, model, [w for w, _ in convs])
    net = DetectorNet(cfg)
    modules = dict(net.named_modules())
    order = conv_call_order(net)
    if len(order) != len(convs):
        raise WarmStartError(f"{path}: {len(convs)} convolutions, the network has {len(order)}")
    with torch.no_grad():
        for name, (weight, bias) in zip(order, convs):
            _set_folded_conv(path, modules, name, weight, bias)
    net.eval()
    _check_against_onnx(path, net)
    return net, classes


def _set_folded_conv(path: Path, modules: dict, name: str, weight: np.ndarray,
                     bias: np.ndarray | None) -> None:
    conv = modules[name]
    if tuple(conv.weight.shape) != weight.shape:
        raise WarmStartError(f"{path}: convolution {name} has shape {weight.shape}, the network "
                             f"{tuple(conv.weight.shape)} (another architecture)")
    conv.weight.copy_(torch.tensor(weight))
    bias_t = torch.tensor(bias) if bias is not None else torch.zeros(weight.shape[0])
    parent, _, index = name.rpartition(".")
    bn = modules.get(f"{parent}.{int(index) + 1}") if index.isdigit() else None
    if isinstance(bn, nn.BatchNorm2d):  # folded: the BatchNorm passes the folded bias through
        bn.weight.fill_(1.0)
        bn.bias.copy_(bias_t)
        bn.running_mean.zero_()
        bn.running_var.fill_(1.0 - bn.eps)
    elif conv.bias is not None:
        conv.bias.copy_(bias_t)


def _check_against_onnx(path: Path, net: DetectorNet) -> None:
    """The rebuilt network must reproduce the file's outputs (else the weights went to wrong layers)."""
    cfg = net.cfg
    x = torch.rand(1, 3, cfg.input_height, cfg.input_width, generator=torch.Generator().manual_seed(0))
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    want = sess.run(None, {sess.get_inputs()[0].name: x.numpy()})[0]
    with torch.no_grad():
        got = ExportWrapper(net).eval()(x).numpy()
    if got.shape != want.shape or not np.allclose(got, want, rtol=1e-3, atol=1e-2):
        raise WarmStartError(f"{path}: the rebuilt network does not reproduce the model's outputs")


@torch.no_grad()
def recalibrate_batchnorm(net: DetectorNet, images: torch.Tensor) -> None:
    """Give every BatchNorm the per-channel mean and variance of its input on `images`, keeping its
    eval-mode function (y - m) * s + b: the new running stats are those of the data, gamma and beta are
    chosen so the function is unchanged, and training mode (batch statistics) starts close to it."""
    stats: dict[nn.BatchNorm2d, tuple[torch.Tensor, torch.Tensor]] = {}

    def record(mod, inp):
        stats[mod] = (inp[0].mean((0, 2, 3)), inp[0].var((0, 2, 3), unbiased=False))

    hooks = [m.register_forward_pre_hook(record) for m in net.modules() if isinstance(m, nn.BatchNorm2d)]
    try:
        net.eval()(images)
    finally:
        for h in hooks:
            h.remove()
    for bn, (mean, var) in stats.items():
        scale = bn.weight / torch.sqrt(bn.running_var + bn.eps)  # s, kept
        bn.bias.add_((mean - bn.running_mean) * scale)  # b' = b + (m' - m) s
        bn.weight.copy_(scale * torch.sqrt(var + bn.eps))  # gamma' / sqrt(var' + eps) = s
        bn.running_mean.copy_(mean)
        bn.running_var.copy_(var)


def model_classes(old: Sequence[str] | None, new: Sequence[str], drop_old: bool) -> list[str]:
    """The warm-started model's classes: the old ones in their order (unless dropped), then the new
    ones it did not have."""
    out = [] if old is None or drop_old else list(old)
    out += [c for c in dict.fromkeys(new) if c not in out]
    return out


def resized(source: DetectorNet, old: Sequence[str], classes: Sequence[str], cfg: ModelConfig) -> DetectorNet:
    """A network for `classes` with every weight of `source` except the class head's last layer, whose
    rows are copied for the classes both know (new classes start as a fresh network's would)."""
    if (source.cfg.width, source.cfg.num_classes) != (cfg.width, len(old)):
        raise WarmStartError(f"width {cfg.width} / {len(old)} classes do not match the source's "
                             f"{source.cfg.width} / {source.cfg.num_classes}")
    net = DetectorNet(ModelConfig(len(classes), cfg.width, cfg.input_width, cfg.input_height))
    state = net.state_dict()
    src = source.state_dict()
    for k, v in src.items():
        if k not in (HEAD_WEIGHT, HEAD_BIAS):
            state[k] = v.clone()
    for i, c in enumerate(classes):
        if c in old:
            j = list(old).index(c)
            state[HEAD_WEIGHT][i] = src[HEAD_WEIGHT][j]
            state[HEAD_BIAS][i] = src[HEAD_BIAS][j]
    net.load_state_dict(state)
    return net
