"""YOLO datasets: round trip, and every bad input reported with its file and line."""

import logging

import numpy as np
import pytest
from vla_detector_training.cli import main as cli_main
from vla_detector_training.dataset import (
    Box,
    DatasetError,
    label_path_for,
    load_data_config,
    load_split,
    read_image,
    write_data_config,
    write_sample,
)

NAMES = ["bread", "soda_can", "milk_carton"]


def make_dataset(root, n=3):
    rng = np.random.default_rng(0)
    for i in range(n):
        img = rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)
        write_sample(root, "train", f"im{i}", img, [Box(i % 3, 20.0, 16.0, 10.0, 8.0)])
    write_data_config(root, NAMES, ["train"])
    return root


def test_round_trip(tmp_path):
    make_dataset(tmp_path)
    cfg = load_data_config(tmp_path)
    assert cfg.names == NAMES and set(cfg.splits) == {"train"}
    samples = load_split(cfg, "train")
    assert len(samples) == 3
    s = samples[1]
    assert (s.width, s.height) == (64, 48)
    b = s.boxes[0]
    assert b.class_index == 1
    assert (b.cx, b.cy, b.w, b.h) == pytest.approx((20.0, 16.0, 10.0, 8.0), abs=1e-3)  # 6 decimals written
    assert label_path_for(s.image_path) == tmp_path / "labels" / "train" / "im1.txt"
    assert read_image(s.image_path).shape == (48, 64, 3)


def test_missing_label_file_means_no_objects_and_is_warned_about(tmp_path, caplog):
    make_dataset(tmp_path)
    (tmp_path / "labels" / "train" / "im0.txt").write_text("")  # a deliberate background image
    with caplog.at_level(logging.WARNING, logger="vla_detector_training"):
        assert load_split(load_data_config(tmp_path), "train")[0].boxes == []
    assert not caplog.records
    (tmp_path / "labels" / "train" / "im0.txt").unlink()
    (tmp_path / "labels" / "train" / "im2.txt").unlink()
    with caplog.at_level(logging.WARNING, logger="vla_detector_training"):
        samples = load_split(load_data_config(tmp_path), "train")
    assert samples[0].boxes == [] and samples[2].boxes == [] and len(samples[1].boxes) == 1
    [record] = caplog.records
    assert "2 of 3 images have no label file" in record.getMessage()
    assert "im0.png, im2.png" in record.getMessage() and "empty label file" in record.getMessage()


def test_ultralytics_names_mapping(tmp_path):
    make_dataset(tmp_path)
    (tmp_path / "data.yaml").write_text(
        "path: .\ntrain: images/train\nnames:\n  0: bread\n  1: soda_can\n  2: milk\n"
    )
    assert load_data_config(tmp_path).names == ["bread", "soda_can", "milk"]


@pytest.mark.parametrize(
    "line,message",
    [
        ("1 0.5 0.5 1.5 0.2", "w=1.5 out of range"),
        ("0 -0.2 0.5 0.1 0.1", "cx=-0.2 out of range"),
        ("0 0.95 0.5 0.2 0.2", "extends outside the image"),
        ("7 0.5 0.5 0.1 0.1", "unknown class id 7"),
        ("-1 0.5 0.5 0.1 0.1", "unknown class id -1"),
        ("1.5 0.5 0.5 0.1 0.1", "not an integer"),
        ("cat 0.5 0.5 0.1 0.1", "not an integer"),
        ("0 0.5 0.5 0.1", "expected 5 fields"),
        ("0 0.5 0.5 nan 0.1", "out of range"),
        ("0 0.5 0.5 0 0.1", "zero or negative size"),
        ("0 0.5 0.5 x 0.1", "must be numbers"),
    ],
)
def test_bad_labels_name_file_and_line(tmp_path, line, message):
    make_dataset(tmp_path)
    lbl = tmp_path / "labels" / "train" / "im2.txt"
    lbl.write_text("0 0.5 0.5 0.1 0.1\n\n" + line + "\n")
    with pytest.raises(DatasetError) as e:
        load_split(load_data_config(tmp_path), "train")
    assert f"{lbl}:3:" in str(e.value)
    assert message in str(e.value)


def test_unreadable_image_is_named(tmp_path):
    make_dataset(tmp_path)
    bad = tmp_path / "images" / "train" / "im1.png"
    bad.write_bytes(b"not a png")
    with pytest.raises(DatasetError, match=f"{bad}: unreadable image"):
        load_split(load_data_config(tmp_path), "train")
    with pytest.raises(DatasetError, match="unreadable image"):
        read_image(tmp_path / "nowhere.png")


def test_bad_data_yaml(tmp_path):
    with pytest.raises(DatasetError, match="data.yaml not found"):
        load_data_config(tmp_path)
    (tmp_path / "data.yaml").write_text("names: [a, b\n")
    with pytest.raises(DatasetError, match="invalid YAML"):
        load_data_config(tmp_path)
    (tmp_path / "data.yaml").write_text("train: images/train\n")
    with pytest.raises(DatasetError, match="'names'"):
        load_data_config(tmp_path)
    (tmp_path / "data.yaml").write_text("names: {0: a, 2: b}\n")
    with pytest.raises(DatasetError, match="without gaps"):
        load_data_config(tmp_path)
    (tmp_path / "data.yaml").write_text("names: [a]\ntrain: images/train\n")
    with pytest.raises(DatasetError, match="no 'val' split"):
        load_data_config(tmp_path).split_dir("val")
    with pytest.raises(DatasetError, match="image folder not found"):
        load_split(load_data_config(tmp_path), "train")


def test_cli_check_reports_errors(tmp_path, capsys):
    make_dataset(tmp_path)
    assert cli_main(["check", "--data", str(tmp_path)]) == 0
    assert "train: 3 images, 3 boxes" in capsys.readouterr().out
    (tmp_path / "labels" / "train" / "im0.txt").write_text("9 0.5 0.5 0.1 0.1\n")
    assert cli_main(["check", "--data", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "im0.txt:1: unknown class id 9" in err
