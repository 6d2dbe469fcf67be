"""Checkpoints (safetensors, never pickle) and ONNX export with a JSON sidecar.

The sidecar `detector.json` beside `detector.onnx` names the classes in index order, the input size
and the output layout; the same facts also go into the ONNX metadata (as Ultralytics does), so the
model file alone is enough when the sidecar is lost.
"""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path

import onnx
import torch
from safetensors import safe_open
from safetensors.torch import load_file, save_file

from vla_detector_training.model import DetectorNet, ExportWrapper, ModelConfig

OPSET = 17
FORMAT = "vla_detector"


def save_checkpoint(
    path: str | os.PathLike, net: DetectorNet, classes: list[str], extra: dict | None = None
) -> None:
    """Weights as safetensors; config, class names and training facts in its string metadata."""
    meta = {
        "format": FORMAT,
        "config": json.dumps(net.cfg.to_dict()),
        "classes": json.dumps(list(classes)),
        "extra": json.dumps(extra or {}),
    }
    state = {k: v.detach().contiguous().clone() for k, v in net.state_dict().items()}
    save_file(state, str(path), metadata=meta)


def load_checkpoint(path: str | os.PathLike) -> tuple[DetectorNet, list[str], dict]:
    """safetensors checkpoint -> (network in eval mode, class names, extra facts)."""
    with safe_open(str(path), framework="pt") as f:
        meta = f.metadata() or {}
    if meta.get("format") != FORMAT:
        raise ValueError(f"{path}: not a vla_detector checkpoint (metadata format={meta.get('format')!r})")
    cfg = ModelConfig.from_dict(json.loads(meta["config"]))
    net = DetectorNet(cfg)
    net.load_state_dict(load_file(str(path)))
    net.eval()
    return net, json.loads(meta["classes"]), json.loads(meta.get("extra", "{}"))


def export_onnx(
    net: DetectorNet, classes: list[str], out_path: str | os.PathLike, extra: dict | None = None
) -> Path:
    """Export to ONNX (output [1, 4 + nc, N], YOLOv8 layout) and write the JSON sidecar."""
    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    cfg = net.cfg
    wrapper = ExportWrapper(net).eval()
    x = torch.zeros(1, 3, cfg.input_height, cfg.input_width)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            wrapper,
            (x,),
            str(out),
            dynamo=False,
            opset_version=OPSET,
            input_names=["images"],
            output_names=["output0"],
            do_constant_folding=True,
        )
    model = onnx.load(str(out))
    meta = {
        "format": FORMAT,
        "names": json.dumps({i: n for i, n in enumerate(classes)}),
        "imgsz": json.dumps([cfg.input_height, cfg.input_width]),
        "layout": "yolov8",
        "stride": "8",
    }
    del model.metadata_props[:]
    for k, v in meta.items():
        model.metadata_props.add(key=k, value=v)
    onnx.checker.check_model(model)
    onnx.save(model, str(out))
    side = {
        "format": FORMAT,
        "classes": list(classes),
        "input_width": cfg.input_width,
        "input_height": cfg.input_height,
        "layout": "yolov8",
        "input": "images: float32 [1, 3, H, W] RGB in [0, 1], letterboxed (pad 114)",
        "output": "output0: float32 [1, 4 + nc, N]: cx, cy, w, h (input pixels), class scores",
        "model": cfg.to_dict(),
    }
    if extra:
        side.update(extra)
    out.with_suffix(".json").write_text(json.dumps(side, indent=2) + "\n", encoding="utf-8")
    return out
