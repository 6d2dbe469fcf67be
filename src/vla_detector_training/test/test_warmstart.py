"""Warm start: the shipped ONNX detector rebuilds as a torch network with the same outputs, the class
head is resized with the old classes' rows kept, and `train --init` trains a model with old + new
classes and reports AP per class."""

import json

import numpy as np
import onnxruntime as ort
import pytest
import torch
from drawn_datasets import COLOURS, H, W, draw_dataset
from vla_common.objects import OBJECT_CLASSES
from vla_detector.inference import default_model_path
from vla_detector_training.cli import build_parser, learning_rate
from vla_detector_training.cli import main as cli_main
from vla_detector_training.dataset import Box, write_data_config, write_sample
from vla_detector_training.export import load_checkpoint
from vla_detector_training.model import DetectorNet, ExportWrapper, ModelConfig
from vla_detector_training.train import ArrayData, relabel
from vla_detector_training.warmstart import (
    HEAD_BIAS,
    HEAD_WEIGHT,
    WarmStartError,
    load_source,
    model_classes,
    net_from_onnx,
    recalibrate_batchnorm,
    resized,
)

BLUE = (30, 40, 220)


def test_shipped_detector_rebuilds_from_its_onnx():
    path = default_model_path()
    net, classes = net_from_onnx(path)  # raises unless it reproduces the file's outputs
    assert classes == list(OBJECT_CLASSES) and (net.cfg.width, net.cfg.num_classes) == (24, 5)
    x = torch.rand(2, 3, 240, 320, generator=torch.Generator().manual_seed(1))
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    want = np.concatenate([sess.run(None, {"images": x[i : i + 1].numpy()})[0] for i in range(2)])
    with torch.no_grad():
        got = ExportWrapper(net).eval()(x).numpy()
    np.testing.assert_allclose(got, want, rtol=1e-3, atol=1e-2)
    # the BatchNorms get the data's statistics; the eval-mode function stays
    recalibrate_batchnorm(net, torch.rand(4, 3, 240, 320, generator=torch.Generator().manual_seed(2)))
    with torch.no_grad():
        again = ExportWrapper(net).eval()(x).numpy()
    np.testing.assert_allclose(again, got, rtol=1e-4, atol=1e-3)
    bn = net.stem[0][1]
    assert not torch.allclose(bn.running_var, torch.ones_like(bn.running_var))


def test_not_a_detector_is_refused(tmp_path):
    (tmp_path / "x.onnx").write_bytes(b"not onnx")
    with pytest.raises(WarmStartError, match="not a readable ONNX model"):
        load_source(tmp_path / "x.onnx")
    with pytest.raises(WarmStartError, match="no best.safetensors or detector.onnx"):
        load_source(tmp_path)


def test_head_resized_keeps_the_backbone_and_the_old_rows():
    torch.manual_seed(0)
    src = DetectorNet(ModelConfig(2, 8, W, H))
    with torch.no_grad():
        src.cls_head[1].bias.copy_(torch.tensor([1.5, -2.5]))
    classes = model_classes(["red", "green"], ["blue", "red"], drop_old=False)
    assert classes == ["red", "green", "blue"]
    net = resized(src, ["red", "green"], classes, ModelConfig(3, 8, W, H))
    a, b = src.state_dict(), net.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a if k not in (HEAD_WEIGHT, HEAD_BIAS))
    assert torch.equal(b[HEAD_WEIGHT][:2], a[HEAD_WEIGHT]) and b[HEAD_BIAS].tolist()[:2] == [1.5, -2.5]
    assert b[HEAD_BIAS][2].item() == pytest.approx(-4.6)  # a new class starts as a fresh head's
    dropped = model_classes(["red", "green"], ["blue", "red"], drop_old=True)
    assert dropped == ["blue", "red"]
    net = resized(src, ["red", "green"], dropped, ModelConfig(2, 8, W, H))
    assert net.state_dict()[HEAD_BIAS][1].item() == 1.5  # red's row, now at index 1


def test_relabel_maps_names_and_drops_unknown_classes():
    data = ArrayData(np.zeros((2, 4, 4, 3), np.uint8), [np.ones((2, 4), np.float32), np.zeros((0, 4))],
                     [np.array([0, 1]), np.array([], np.int64)])
    out = relabel(data, ["blue", "grey"], ["red", "green", "blue"])
    assert out.classes[0].tolist() == [2] and out.boxes[0].shape == (1, 4) and len(out.classes[1]) == 0


def draw_new_dataset(root, n_train=12, n_val=4, seed=5):
    """Blue (a class the first model lacks) and red rectangles; data.yaml names [blue, red]."""
    rng = np.random.default_rng(seed)
    for split, n in (("train", n_train), ("val", n_val)):
        for i in range(n):
            img = rng.integers(90, 140, (H, W, 3), dtype=np.uint8)
            boxes = []
            for c, colour in enumerate((BLUE, COLOURS[0])):
                bw, bh = rng.integers(8, 20), rng.integers(8, 20)
                x, y = rng.integers(0, W - bw), rng.integers(0, H - bh)
                img[y : y + bh, x : x + bw] = colour
                boxes.append(Box(c, x + bw / 2, y + bh / 2, float(bw), float(bh)))
            write_sample(root, split, f"{split}{i}", img, boxes)
    write_data_config(root, ["blue", "red"], ["train", "val"])
    return root


@pytest.mark.slow
def test_train_init_adds_classes_and_reports_ap_per_class(tmp_path, capsys):
    base = ["--imgsz", f"{W}x{H}", "--width", "8", "--batch", "8", "--epochs", "1", "--quiet"]
    old = draw_dataset(tmp_path / "old")
    assert cli_main(["train", "--data", str(old), "--out", str(tmp_path / "run1"), *base]) == 0
    new = draw_new_dataset(tmp_path / "new")
    capsys.readouterr()
    rc = cli_main(["train", "--data", str(new), "--out", str(tmp_path / "run2"),
                   "--init", str(tmp_path / "run1" / "detector.onnx"), *base])
    assert rc == 0
    out = capsys.readouterr().out
    side = json.loads((tmp_path / "run2" / "detector.json").read_text())
    assert side["classes"] == ["red", "green", "blue"]  # the old classes kept, the new one appended
    assert side["trained"]["init"].endswith("detector.onnx")
    assert set(side["trained"]["val"]["ap50_per_class"]) == {"red", "blue"}  # the classes val has
    assert "AP@0.5 red: " in out and "AP@0.5 blue: " in out and "AP@0.5 green: no validation boxes" in out
    assert "warm start from" in out
    rc = cli_main(["train", "--data", str(new), "--out", str(tmp_path / "run3"), "--init",
                   str(tmp_path / "run1"), "--drop-old-classes", *base])  # the run folder: its checkpoint
    assert rc == 0
    _, classes, _ = load_checkpoint(tmp_path / "run3" / "best.safetensors")
    assert classes == ["blue", "red"]


def test_fine_tuning_has_its_own_default_learning_rate():
    def lr(*flags):
        return learning_rate(build_parser().parse_args(["train", "--data", "d", "--out", "o", *flags]))

    assert lr() == 3e-3 and lr("--init", "shipped") == 1e-3 and lr("--init", "m.onnx", "--lr", "0.01") == 0.01


def test_drop_old_classes_needs_init(tmp_path, capsys):
    data = draw_new_dataset(tmp_path / "new", n_train=2, n_val=1)
    assert cli_main(["train", "--data", str(data), "--out", str(tmp_path / "r"), "--drop-old-classes"]) == 2
    assert "--drop-old-classes needs --init" in capsys.readouterr().err


@pytest.mark.slow
def test_mix_synth_adds_renders_of_the_scene(tmp_path):
    data = draw_new_dataset(tmp_path / "new", n_train=4, n_val=2)
    rc = cli_main(["train", "--data", str(data), "--out", str(tmp_path / "run"), "--imgsz", "160x128",
                   "--width", "8", "--epochs", "1", "--mix-synth", "10", "--quiet"])
    assert rc == 0
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["classes"] == ["blue", "red", *OBJECT_CLASSES]  # the renders' classes appended
    assert summary["train_images"] == 4 + 9  # one render of ten went to validation
    assert len(list((tmp_path / "run" / "mix_synth_s0_n10" / "images" / "train").iterdir())) == 9
