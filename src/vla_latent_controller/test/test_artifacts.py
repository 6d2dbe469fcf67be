import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from vla_latent_controller.artifacts import (
    CONFIG_FILE,
    WEIGHTS_FILE,
    ModelError,
    load_model,
    reseal_model,
    seal_config,
    sha256_file,
)
from vla_latent_controller.model import LatentModel
from vla_latent_controller.testing import CLASSES, READY, write_random_model

MODELS = Path(__file__).resolve().parents[1] / "models"
# sha256 of each shipped config.json as trained (format_version 1, before the config checksum existed)
SHIPPED_V1 = {
    "default": "48d1018f391251f2529e3dcaa79c966752e0b3cc8f5e31d84d4100ae0670b2a9",
    "cereal_box_circle": "4f9fc32623cc1b8f6021b1009c14ba2b48ba9880d34a740c27bf8ec7dbf6bde8",
    "cereal_box_push_south": "121855d4bf3dd6743c12ec30f78a4f2134117032bc9cee452aed8cfab615df0e",
    "cereal_box_push_south_east": "592adc61887ac8d073317a1114018fe469056e1855b7eea64d2785136dd0dd2b",
}


def edit_config(model_dir: Path, edit, seal: bool = True) -> None:
    """Change config.json; sealed: with a matching checksum, as a (careless) re-save would write it."""
    p = model_dir / CONFIG_FILE
    cfg = json.loads(p.read_text())
    edit(cfg)
    p.write_text(json.dumps(seal_config(cfg) if seal else cfg, indent=2))


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


def test_truncated_weights_with_a_matching_checksum(random_model_dir):
    w = random_model_dir / WEIGHTS_FILE
    w.write_bytes(w.read_bytes()[:50])
    edit_config(random_model_dir, lambda c: c["files"].update(weights_sha256=sha256_file(w)))
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
        (lambda c: c["normalisation"].update(q_std=[0.0] * 7), "q_std"),
        (lambda c: c.pop("classes"), "missing key 'classes'"),
        (lambda c: c["latent"].update(default_gain=0), "default_gain"),
    ],
)
def test_inconsistent_config(random_model_dir, edit, match):
    edit_config(random_model_dir, edit)
    with pytest.raises(ModelError, match=match):
        load_model(random_model_dir)


def test_unknown_format_version(random_model_dir):
    edit_config(random_model_dir, lambda c: c.update(format_version=99), seal=False)
    with pytest.raises(ModelError, match="format_version 99 unsupported"):
        load_model(random_model_dir)


def test_shape_mismatch_between_config_and_weights(tmp_path):
    d = write_random_model(tmp_path / "m", classes=CLASSES[:3])
    edit_config(d, lambda c: c.update(classes=list(CLASSES), dims={**c["dims"], "context": 7}))
    with pytest.raises(ModelError, match="shape"):
        load_model(d)


def test_no_pickle_in_weights(random_model_dir):
    head = (random_model_dir / WEIGHTS_FILE).read_bytes()[:8]
    n = int.from_bytes(head, "little")
    header = json.loads((random_model_dir / WEIGHTS_FILE).read_bytes()[8 : 8 + n])
    assert all(v["dtype"] == "F32" for k, v in header.items() if k != "__metadata__")
    assert np.isfinite(load_model(random_model_dir).tensors["decoder.4.bias"]).all()


def _set(section, key, value, i=None):
    def edit(c):
        target = c[section] if section else c
        if i is None:
            target[key] = value
        else:
            target[key][i] = value

    return edit


@pytest.mark.parametrize(
    "edit, match",
    [
        (_set("normalisation", "q_std", 1e-300, 2), "normalisation.q_std"),
        (_set("normalisation", "a_scale", 1e6, 0), "normalisation.a_scale"),
        (_set("normalisation", "q_mean", 1e9, 6), "normalisation.q_mean"),
        (_set("latent", "gain", {"bread": 1e300}), "latent.gain"),
        (_set("latent", "default_gain", -40.0), "latent.default_gain"),
        (_set("dims", "hidden", 10**6), "dims.hidden"),
        (_set(None, "joint_names", ["panda_joint1"] * 7), "joint_names"),
    ],
)
def test_implausible_numbers_are_refused(random_model_dir, edit, match):
    """Even with a matching checksum: numbers no trainer writes would move the arm wildly."""
    edit_config(random_model_dir, edit)
    with pytest.raises(ModelError, match=match):
        load_model(random_model_dir)


def test_an_unbounded_latent_may_have_larger_gains(random_model_dir):
    edit_config(random_model_dir, lambda c: c["latent"].update(bounded=False, default_gain=-40.0))
    assert load_model(random_model_dir).config["latent"]["default_gain"] == -40.0


@pytest.mark.parametrize(
    "edit",
    [
        _set("normalisation", "q_std", 1e-300, 2),
        _set("latent", "default_gain", 0.81),
        _set("files", "weights_sha256", "0" * 64),
        lambda c: c["hyper_parameters"].update(note="edited"),
    ],
)
def test_an_edited_config_fails_its_checksum(random_model_dir, edit):
    edit_config(random_model_dir, edit, seal=False)
    with pytest.raises(ModelError, match="config_sha256"):
        load_model(random_model_dir)


def test_an_unsealed_model_is_refused_until_resealed(random_model_dir):
    def unseal(c):
        c["format_version"] = 1
        del c["files"]["config_sha256"]

    edit_config(random_model_dir, unseal, seal=False)
    with pytest.raises(ModelError, match="reseal"):
        load_model(random_model_dir)
    reseal_model(random_model_dir)
    assert load_model(random_model_dir).config["format_version"] == 2


def test_reseal_refuses_implausible_numbers(random_model_dir):
    def unseal_and_break(c):
        c["format_version"] = 1
        del c["files"]["config_sha256"]
        c["normalisation"]["a_scale"][0] = 1e6

    edit_config(random_model_dir, unseal_and_break, seal=False)
    with pytest.raises(ModelError, match="a_scale"):
        reseal_model(random_model_dir)


# Set in a shipped model's latent after it was trained and sealed: the command's path fraction measured
# for it (issue 20; model.LatentModel.path_fraction). The decoder does not read it.
CALIBRATED_LATER = ("path_fraction", "path_fraction_measured")


def _unsealed_text(cfg: dict) -> str:
    """The config as it was before the seal: format_version 1 and no config_sha256, same key order,
    without what was calibrated later."""
    old = json.loads(json.dumps(cfg))
    old["format_version"] = 1
    del old["files"]["config_sha256"]
    for key in CALIBRATED_LATER:
        old["latent"].pop(key, None)
    return json.dumps(old, indent=2, allow_nan=False) + "\n"


@pytest.mark.parametrize("name", sorted(SHIPPED_V1))
def test_shipped_models_were_resealed_without_changing_a_number(name, tmp_path):
    """The shipped config.json minus its seal is byte for byte the trained file (its sha256 from before
    the seal), and a model loaded from that file decodes bit-identically to the sealed one."""
    sealed = load_model(MODELS / name)
    before = _unsealed_text(sealed.config)
    assert hashlib.sha256(before.encode()).hexdigest() == SHIPPED_V1[name]
    old = tmp_path / name
    shutil.copytree(MODELS / name, old)
    (old / CONFIG_FILE).write_text(before)
    reseal_model(old)
    assert _unsealed_text(load_model(old).config) == before   # the seal changed no number
    if not any(k in sealed.config["latent"] for k in CALIBRATED_LATER):
        assert (old / CONFIG_FILE).read_text() == (MODELS / name / CONFIG_FILE).read_text()
    a, b = LatentModel.load(MODELS / name), LatentModel.load(old)
    rng = np.random.default_rng(0)
    for cls in a.classes:
        ctx = np.r_[np.eye(len(a.classes))[a.classes.index(cls)], rng.uniform(0.2, 0.8, 2)]
        a.decoder.set_context(ctx)
        b.decoder.set_context(ctx)
        for _ in range(20):
            q, z = READY + rng.normal(0, 0.3, 7), rng.uniform(-1, 1)
            assert a.decoder.decode(q, z).tobytes() == b.decoder.decode(q, z).tobytes()
