"""A tiny model trains a few steps on a procedurally drawn dataset, exports, and ONNX matches torch."""

import json

import numpy as np
import onnxruntime as ort
import pytest
import torch
from drawn_datasets import NAMES, H, W, draw_dataset
from vla_detector.inference import Detector
from vla_detector_training.cli import main as cli_main
from vla_detector_training.export import load_checkpoint
from vla_detector_training.model import STRIDE, ExportWrapper
from vla_detector_training.targets import build_targets
from vla_detector_training.train import TrainConfig, parse_imgsz, train


@pytest.mark.slow
def test_tiny_training_exports_matching_onnx(tmp_path, capsys):
    data = draw_dataset(tmp_path / "data")
    out = tmp_path / "run"
    summary = train(
        TrainConfig(
            data=str(data),
            out=str(out),
            epochs=2,
            batch=8,
            width=8,
            input_width=W,
            input_height=H,
            progress=False,
        )
    )
    assert (out / "best.safetensors").is_file() and (out / "detector.onnx").is_file()
    side = json.loads((out / "detector.json").read_text())
    assert side["classes"] == NAMES and (side["input_width"], side["input_height"]) == (W, H)
    assert side["layout"] == "yolov8" and side["trained"]["train_images"] == 16
    assert summary["best_epoch"] in (1, 2)
    assert (out / "results.csv").read_text().count("\n") == 3  # header + 2 epochs

    net, classes, extra = load_checkpoint(out / "best.safetensors")
    assert classes == NAMES and extra["epoch"] == summary["best_epoch"]
    x = torch.rand(1, 3, H, W)
    with torch.no_grad():
        ref = ExportWrapper(net)(x).numpy()
    sess = ort.InferenceSession(str(out / "detector.onnx"), providers=["CPUExecutionProvider"])
    got = sess.run(None, {"images": x.numpy()})[0]
    assert got.shape == (1, 4 + len(NAMES), (W // STRIDE) * (H // STRIDE))
    np.testing.assert_allclose(got, ref, rtol=1e-4, atol=1e-3)

    det = Detector(out / "detector.onnx", score_threshold=0.0)
    assert det.classes == NAMES and det.input_size == (W, H) and det.layout == "yolov8"
    assert len(det.detect(np.zeros((H, W, 3), np.uint8))) > 0

    # evaluate and export through the CLI
    figures = tmp_path / "evaluation.json"
    assert cli_main(["evaluate", "--model", str(out / "detector.onnx"), "--data", str(data), "--quiet",
                     "--json", str(figures)]) == 0
    text = capsys.readouterr().out
    assert "mAP@0.5: " in text and "mAP@0.5:0.95: " in text and "mean centre error px: " in text
    fig = json.loads(figures.read_text())  # the printed figures, for programs
    assert f"mAP@0.5: {fig['map50']:.4f}" in text and set(fig["per_class_ap50"]) == set(NAMES)
    assert fig["images"] > 0 and fig["split"] in ("test", "val")
    assert (
        cli_main(["export", "--checkpoint", str(out / "best.safetensors"), "--out", str(tmp_path / "x.onnx")])
        == 0
    )
    assert Detector(tmp_path / "x.onnx").classes == NAMES


def test_targets_peak_at_object_centre():
    heat, reg, wt = build_targets([np.array([[20.0, 12.0, 16.0, 8.0]], np.float32)], [np.array([1])], 2, 6, 8)
    # centre (20, 12) px -> cell (2.5, 1.5) -> cell index x 2, y 1
    assert heat[0, 1, 1, 2] == 1.0 and heat[0, 0].max() == 0.0
    assert heat[0, 1].sum() > 1.0  # a Gaussian around the peak
    assert reg[0, :, 1, 2].tolist() == pytest.approx([0.0, 0.0, np.log(2.0), np.log(1.0)])
    assert wt[0, 1, 2] == 1.0 and (wt[0] > 0).sum() >= 1


def test_imgsz_parsing():
    assert parse_imgsz("320") == (320, 240)
    assert parse_imgsz("640x480") == (640, 480)
    with pytest.raises(ValueError, match="multiples of 16"):
        parse_imgsz("330x240")
    with pytest.raises(ValueError, match="expected W or WxH"):
        parse_imgsz("big")


def test_train_rejects_bad_dataset(tmp_path):
    data = draw_dataset(tmp_path / "data", n_train=2, n_val=1)
    (data / "labels" / "train" / "train1.txt").write_text("5 0.5 0.5 0.2 0.2\n")
    assert (
        cli_main(["train", "--data", str(data), "--out", str(tmp_path / "run"), "--epochs", "1", "--quiet"])
        == 2
    )
    assert not (tmp_path / "run" / "best.safetensors").exists()
