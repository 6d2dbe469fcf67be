import json

import numpy as np
import pytest
from vla_latent_controller.artifacts import CONFIG_FILE, WEIGHTS_FILE, ModelError, load_model
from vla_latent_controller.model import LatentModel
from vla_latent_controller.testing import CLASSES, write_random_model


def test_roundtrip(random_model_dir):
    art = load_model(random_model_dir)
    assert art.encoder == "detector" and art.classes == list(CLASSES)
    assert art.tensors["decoder.0.weight"].shape == (30, 7 + 7 + 1)
    m = LatentModel(art)
    assert m.gain("bread") == 0.8 and not m.needs_image


def test_missing_dir_and_files(tmp_path):
    with pytest.raises(ModelError, match="not a directory"):
        load_model(tmp_path / "nope")
    with pytest.raises(ModelError, match="config.json: missing"):
        load_model(tmp_path)


def test_corrupt_weights_are_detected(random_model_dir):
    w = random_model_dir / WEIGHTS_FILE
    data = bytearray(w.read_bytes())
    data[-5] ^= 0xFF
    w.write_bytes(bytes(data))
    with pytest.raises(ModelError, match="sha256"):
        load_model(random_model_dir)


def test_truncated_weights_without_checksum(random_model_dir):
    cfg = json.loads((random_model_dir / CONFIG_FILE).read_text())
    del cfg["files"]["weights_sha256"]
    (random_model_dir / CONFIG_FILE).write_text(json.dumps(cfg))
    w = random_model_dir / WEIGHTS_FILE
    w.write_bytes(w.read_bytes()[:50])
    with pytest.raises(ModelError, match="corrupt safetensors"):
        load_model(random_model_dir)


def test_corrupt_json(random_model_dir):
    (random_model_dir / CONFIG_FILE).write_text("{not json")
    with pytest.raises(ModelError, match="corrupt JSON"):
        load_model(random_model_dir)


@pytest.mark.parametrize(
    "edit, match",
    [
        (lambda c: c.update(encoder="yolo"), "unknown encoder"),
        (lambda c: c["dims"].update(context=3), "dims.context"),
        (lambda c: c["normalisation"].update(q_std=[0.0] * 7), "positive"),
        (lambda c: c.pop("classes"), "missing key 'classes'"),
        (lambda c: c.update(format_version=99), "format_version"),
        (lambda c: c["latent"].update(default_gain=0), "default_gain"),
    ],
)
def test_inconsistent_config(random_model_dir, edit, match):
    p = random_model_dir / CONFIG_FILE
    cfg = json.loads(p.read_text())
    edit(cfg)
    p.write_text(json.dumps(cfg))
    with pytest.raises(ModelError, match=match):
        load_model(random_model_dir)


def test_shape_mismatch_between_config_and_weights(tmp_path):
    d = write_random_model(tmp_path / "m", classes=CLASSES[:3])
    cfg = json.loads((d / CONFIG_FILE).read_text())
    cfg["classes"] = list(CLASSES)
    cfg["dims"]["context"] = 7
    (d / CONFIG_FILE).write_text(json.dumps(cfg))
    with pytest.raises(ModelError, match="shape"):
        load_model(d)


def test_no_pickle_in_weights(random_model_dir):
    head = (random_model_dir / WEIGHTS_FILE).read_bytes()[:8]
    n = int.from_bytes(head, "little")
    header = json.loads((random_model_dir / WEIGHTS_FILE).read_bytes()[8 : 8 + n])
    assert all(v["dtype"] == "F32" for k, v in header.items() if k != "__metadata__")
    assert np.isfinite(load_model(random_model_dir).tensors["decoder.4.bias"]).all()
