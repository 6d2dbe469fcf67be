"""Re-calibrating a trained model's latent: the gains change with the percentile, nothing else does."""

import numpy as np
import pytest
from vla_latent_controller.artifacts import load_model
from vla_latent_controller.model import LatentModel
from vla_latent_controller.testing import make_demos, make_pairs
from vla_latent_training.calibrate_cli import add_arguments
from vla_latent_training.config import TrainConfig


@pytest.mark.slow
def test_recalibration_at_the_trained_percentile_reproduces_the_gains_and_lower_shrinks_them(
        trained_model_dir, tmp_path):
    from vla_latent_training.recalibrate import recalibrate_model, recipe_of

    demos = make_demos(per_class=3, seed=1, T=30)  # the fixture's demonstrations
    before = load_model(trained_model_dir)
    trained_p = recipe_of(before.config).gain_percentile
    same = recalibrate_model(trained_model_dir, demos, tmp_path / "same", trained_p, pairs_fn=make_pairs,
                             log=lambda s: None)
    lower = recalibrate_model(trained_model_dir, demos, tmp_path / "lower", trained_p / 2,
                              pairs_fn=make_pairs, log=lambda s: None)
    g0 = before.config["latent"]["gain"]
    g_same = load_model(same).config["latent"]["gain"]
    g_low = load_model(lower).config["latent"]["gain"]
    assert set(g_same) == set(g0) == set(g_low)
    for c in g0:
        assert g_same[c] == pytest.approx(g0[c], rel=1e-5), c
        assert np.sign(g_low[c]) == np.sign(g0[c]) and abs(g_low[c]) < abs(g0[c]), c
    low = load_model(lower)
    assert low.config["hyper_parameters"]["gain_percentile"] == trained_p / 2
    assert low.config["latent"]["calibrated_on"]["demos"] == len(demos)
    for k, v in before.tensors.items():  # the networks are untouched
        assert np.array_equal(low.tensors[k], v), k
    demo = demos[0]
    m0, m1 = LatentModel.load(trained_model_dir), LatentModel.load(lower)
    for m in (m0, m1):
        m.decoder.set_context(m.context(demo.detection, demo.image_size))
    assert np.array_equal(m0.decoder.decode(demo.q[3], 0.3), m1.decoder.decode(demo.q[3], 0.3))


def test_recalibration_refuses_a_percentile_outside_0_100(random_model_dir, tmp_path):
    from vla_latent_training.recalibrate import recalibrate_model

    with pytest.raises(ValueError, match="percentile"):
        recalibrate_model(random_model_dir, make_demos(per_class=1, seed=1, T=30), tmp_path / "m", 0.0,
                          pairs_fn=make_pairs, log=lambda s: None)
    assert not (tmp_path / "m").exists()


def test_the_calibrate_cli_default_is_train_configs():
    import argparse

    p = argparse.ArgumentParser()
    add_arguments(p)
    args = p.parse_args(["--model", "m", "--bags", "b", "--out", "o"])
    assert args.gain_percentile == TrainConfig().gain_percentile
