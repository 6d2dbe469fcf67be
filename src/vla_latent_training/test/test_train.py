import json
from dataclasses import replace

import numpy as np
import pytest
import torch
from vla_common.detection import Detection
from vla_latent_controller.artifacts import CONFIG_FILE, load_model
from vla_latent_controller.context import preprocess_image
from vla_latent_controller.model import LatentModel
from vla_latent_controller.testing import CLASSES, class_direction, make_demos, make_pairs
from vla_latent_training.cae import CAE, ContextCNN, Tanh
from vla_latent_training.config import CTX_STD_FLOOR, POSITION_PRIOR_SCALE, position_affine, scaled_schedule
from vla_latent_training.inputs import prepare_demos
from vla_latent_training.train import TrainConfig, _fold_input_affine, train_model


def _cos(a, b):
    return float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))


@pytest.mark.slow
def test_trained_decoder_does_the_task_and_rests_at_zero(trained_model_dir):
    """On unseen positions, + does the demonstrated motion, - retraces it and z = 0 rests.

    Judged half-way along each demo, where the demos move fastest and both the forward and the
    reversed pairs were trained; from the start state only + is asked for (there is nothing to retrace
    yet, and the demos start slowly). Limits and, in brackets, the worst of 16 trainings of this
    fixture (seeds 0-9 with MKL_CBWR unset, 0-5 with MKL_CBWR=COMPATIBLE, AMD EPYC): cosine at the
    middle > 0.9 [0.976] for +, < -0.9 [-0.983] for -; rest / + speed < 0.2 [0.107]; cosine from the
    start > 0.8 [0.895]. The test of one seed passes with both kernel paths whatever mode training
    lands in (a few seeds saturate the latent: docs/history/training.md).
    """
    model = LatentModel.load(trained_model_dir)
    cfg = model.config
    assert cfg["training"]["demos_per_task"] == {f"{c}/push": 3 for c in CLASSES[:4]}
    assert len(cfg["fingerprint"]["sha256"]) == 64
    for demo in make_demos(per_class=2, seed=7, T=30):  # unseen positions
        model.decoder.set_context(model.context(demo.detection, demo.image_size))
        g = model.gain(demo.object_class)
        v = class_direction(demo.object_class)
        q_mid = demo.q[len(demo.q) // 2]
        fwd = model.decoder.decode(q_mid, g).copy()
        back = model.decoder.decode(q_mid, -g).copy()
        rest = model.decoder.decode(q_mid, 0.0).copy()
        assert _cos(fwd, v) > 0.9, demo.object_class  # + does the task
        assert _cos(back, v) < -0.9, demo.object_class  # - retraces it
        assert np.linalg.norm(rest) < 0.2 * np.linalg.norm(fwd)  # the z = 0 term
        assert _cos(model.decoder.decode(demo.q[0], g), v) > 0.8  # + from the start


@pytest.mark.slow
def test_paper_exact_switches_the_improvements_off(tmp_path):
    demos = make_demos(per_class=1)
    res = train_model(
        demos,
        TrainConfig.paper(epochs=3),
        classes=CLASSES,
        pairs_fn=make_pairs,
        progress=False,
        log=lambda s: None,
    )
    hp = res.config["hyper_parameters"]
    assert hp["paper_exact"] and hp["zero_weight"] == 0 and not hp["bounded_latent"] and not hp["normalise"]
    assert hp["lr"] == 0.01 and hp["step_size"] == 400 and hp["gamma"] == 0.1 and hp["batch_size"] == 6000
    assert res.config["normalisation"]["q_std"] == [1.0] * 7
    assert all(abs(g) == 1.0 for g in res.config["latent"]["gain"].values())
    assert res.config["training"]["pairs"] == res.config["training"]["forward_pairs"]  # no reversed pairs
    res.save(tmp_path / "m")
    assert json.loads((tmp_path / "m" / CONFIG_FILE).read_text())["encoder"] == "detector"


def test_prepare_demos_skips_with_reasons():
    demos = make_demos(per_class=1)
    demos[0].detection = None
    demos[1].detection = replace(demos[1].detection, class_id="teapot")
    demos[2].q = demos[2].q[:, :6]
    kept, skipped = prepare_demos(demos, "detector", CLASSES)
    assert len(kept) == 1
    reasons = " | ".join(r for _, r in skipped)
    assert "no recorded detection" in reasons and "'teapot' not in" in reasons and "shape" in reasons
    kept, skipped = prepare_demos(make_demos(per_class=1), "end_to_end", CLASSES)
    assert not kept and "first image" in skipped[0][1]


def test_detector_runs_when_the_demo_has_no_detection():
    class FakeDetector:
        classes = list(CLASSES)

        def detect(self, rgb):
            return [Detection("bread", 0.9, 300.0, 50.0, 10.0, 10.0, 0),
                    Detection("soda_can", 0.8, 100.0, 50.0, 10.0, 10.0, 1)]

    demos = make_demos(classes=["soda_can"], per_class=1, with_image=True)
    demos[0].detection = None
    kept, skipped = prepare_demos(demos, "detector", CLASSES, detector=FakeDetector())
    assert not skipped and kept[0].det.cx == 100.0 and kept[0].image_size == (640, 480)  # the demo's class


def test_no_usable_demos_is_a_clear_error():
    with pytest.raises(ValueError, match="no usable demos"):
        train_model(
            make_demos(per_class=1),
            TrainConfig(encoder="end_to_end", epochs=1),
            classes=CLASSES,
            pairs_fn=make_pairs,
            progress=False,
            log=lambda s: None,
        )


@pytest.mark.slow
@pytest.mark.parametrize("encoder", ["end_to_end", "localization"])
def test_cnn_encoders_export_onnx_matching_torch(tmp_path, encoder):
    demos = make_demos(per_class=1, with_image=True)
    res = train_model(
        demos,
        TrainConfig(encoder=encoder, epochs=3),
        classes=CLASSES,
        pairs_fn=make_pairs,
        progress=False,
        log=lambda s: None,
    )
    out = res.save(tmp_path / "m")
    art = load_model(out)
    assert art.cnn_path is not None and art.cnn_path.is_file()
    model = LatentModel(art)
    assert model.needs_image
    img = demos[0].first_image
    ctx = model.context(image=img, class_id="bread")
    assert ctx.shape == (art.config["dims"]["context"],)
    # the ONNX CNN reproduces the torch CNN the decoder was trained with
    cnn = ContextCNN()
    sd = {k.removeprefix("cnn."): torch.tensor(v) for k, v in art.tensors.items() if k.startswith("cnn.")}
    cnn.load_state_dict(sd)
    with torch.no_grad():
        ref = cnn(torch.tensor(preprocess_image(img))[None]).numpy()[0]
    np.testing.assert_allclose(ctx[: len(ref)], ref, atol=1e-5)


def test_fast_tanh_is_tanh():
    x = torch.linspace(-30, 30, 20001, dtype=torch.float64, requires_grad=True)
    y = Tanh()(x)
    torch.testing.assert_close(y, torch.tanh(x), atol=1e-15, rtol=0)
    y.sum().backward()
    torch.testing.assert_close(x.grad, 1 - torch.tanh(x.detach()) ** 2, atol=1e-15, rtol=0)


def test_folded_context_standardisation_takes_raw_contexts():
    """The saved decoder takes raw contexts: folding (c - mean) / std into the first layers gives the
    same outputs on raw inputs as the unfolded network on standardised ones."""
    torch.manual_seed(0)
    k = 7
    model = CAE(k, 7, 1, 30)
    mean = np.r_[np.zeros(5), 0.5, 0.6]
    std = np.r_[np.ones(5), 0.05, 0.1]
    ctx = torch.tensor(
        np.c_[np.eye(5)[[0, 3, 1]], np.random.default_rng(0).uniform(0.3, 0.8, (3, 2))], dtype=torch.float32
    )
    q, a, z = torch.randn(3, 7), torch.randn(3, 7), torch.randn(3, 1)
    norm = (ctx - torch.tensor(mean, dtype=torch.float32)) / torch.tensor(std, dtype=torch.float32)
    with torch.no_grad():
        want_dec, want_enc = model.decode(norm, q, z), model.encode(norm, q, a)
        _fold_input_affine(model, mean, std)
        got_dec, got_enc = model.decode(ctx, q, z), model.encode(ctx, q, a)
    assert torch.allclose(got_dec, want_dec, atol=1e-5)
    assert torch.allclose(got_enc, want_enc, atol=1e-5)
    assert not torch.allclose(model.decode(norm, q, z), want_dec, atol=1e-3)  # it did change


def test_min_steps_scales_epochs_and_lr_step_for_small_datasets():
    cfg = TrainConfig(epochs=100, step_size=40, batch_size=6000, min_steps=1000)
    assert scaled_schedule(cfg, 5_000) == (1000, 400)  # one batch an epoch: 10x the epochs
    assert scaled_schedule(cfg, 13_000) == (400, 160)  # three batches an epoch: 4x
    assert scaled_schedule(cfg, 60_000) == (100, 40)  # already 1000 updates
    assert scaled_schedule(TrainConfig(epochs=100, step_size=40), 5_000) == (100, 40)  # off by default
    with pytest.raises(ValueError, match="min_steps"):
        TrainConfig(min_steps=-1).validate()


def test_position_affine_divides_by_the_demos_spread_or_a_fixed_scale():
    xy = np.array([[0.40, 0.60], [0.50, 0.60], [0.60, 0.60]])
    mean, std = position_affine(xy, POSITION_PRIOR_SCALE)
    assert mean == pytest.approx([0.50, 0.60]) and std == pytest.approx([0.2887, 0.2887], abs=1e-4)
    mean, std = position_affine(xy, None)  # the demos' spread; y never moved: the floor
    assert std == pytest.approx([np.std([0.40, 0.50, 0.60]), CTX_STD_FLOOR])
    for bad in (0.0, -0.1, float("nan")):
        with pytest.raises(ValueError, match="position_scale"):
            TrainConfig(position_scale=bad).validate()


@pytest.mark.parametrize("scale", [None, 0.25])
def test_trained_detector_context_is_standardised_as_configured(scale):
    demos = make_demos(per_class=2)
    res = train_model(demos, TrainConfig(epochs=2, hidden=16, position_scale=scale), classes=CLASSES,
                      pairs_fn=make_pairs, progress=False, log=lambda s: None)
    std = res.config["normalisation"]["context_std"][-2:]
    xy = np.array([[d.detection.cx / d.image_size[0], d.detection.cy / d.image_size[1]] for d in demos])
    want = np.maximum(xy.std(0), 0.02) if scale is None else [scale, scale]
    assert std == pytest.approx(want)
    assert res.config["hyper_parameters"]["position_scale"] == scale


def test_training_windows_do_not_span_a_grasp():
    """A pick-and-place demo moves joint 1 up to the grasp, dwells while the hand closes, then
    joint 2: no training pair may lead from before the grasp to after it (the decoder then cut the
    corner and turned towards the carry short of the grasp point). Demos without hand events keep
    their windows whole."""
    from types import SimpleNamespace

    from vla_latent_training.inputs import DemoInput, hand_cuts
    from vla_latent_training.pairs import make_pairs as paper_pairs
    from vla_latent_training.train import build_pairs

    t = np.arange(40) * 0.1
    q = np.zeros((40, 7))
    q[:20, 0] = np.linspace(0.0, 0.5, 20)
    q[20:, 0] = 0.5
    q[25:, 1] = np.linspace(0.0, 0.4, 15)
    demo = SimpleNamespace(t=t, q=q, grasp_events=[(0.0, 1, ""), (1.93, 2, ""), (2.9, 3, "can")])
    assert hand_cuts(demo) == (20,)
    item = DemoInput("can/pick_place_west", "can", q, "bag", cuts=hand_cuts(demo))
    cfg = TrainConfig(sigma=0.0, reverse_pairs=False)
    pairs = build_pairs([item], cfg, paper_pairs, np.random.default_rng(0))
    spans = (np.abs(pairs.a[:, 0]) > 1e-9) & (np.abs(pairs.a[:, 1]) > 1e-9)
    assert not spans.any()
    assert pairs.per_demo == [len(pairs.q)] and len(pairs.q) > 0
    whole = build_pairs([item], replace(cfg, hand_segments=False), paper_pairs, np.random.default_rng(0))
    assert whole.n_forward == sum(40 - w for w in range(1, 11))
    assert ((np.abs(whole.a[:, 0]) > 1e-9) & (np.abs(whole.a[:, 1]) > 1e-9)).any()  # as before
    assert hand_cuts(SimpleNamespace(t=t, q=q, grasp_events=[])) == ()


def test_rest_samples_lead_windows_past_the_end_to_it_and_corrective_pairs_lead_back():
    """Issue 34: windows that reach past a demonstration's end lead to its last state (a held stick
    stops there); a corrective copy starts beside the pair's state and ends where the pair ends."""
    from vla_latent_training.inputs import DemoInput
    from vla_latent_training.pairs import make_pairs as paper_pairs
    from vla_latent_training.train import build_pairs

    q = np.zeros((30, 7))
    q[:, 0] = np.linspace(0.0, 0.6, 30)
    item = DemoInput("bread/push_east", "bread", q, "bag")
    cfg = TrainConfig(sigma=0.0, reverse_pairs=False)
    plain = build_pairs([item], cfg, paper_pairs, np.random.default_rng(0))
    rested = build_pairs([item], replace(cfg, rest_samples=10), paper_pairs, np.random.default_rng(0))
    assert rested.n_forward == plain.n_forward + sum(min(w, 10) + 10 - w for w in range(1, 11))
    ends = rested.q + rested.a
    near_end = rested.q[:, 0] > 0.6 - 0.21 - 1e-9           # the last 10 samples and the rest
    assert np.all(ends[near_end, 0] <= 0.6 + 1e-9)           # none leads beyond the end
    at_end = np.abs(rested.q[:, 0] - 0.6) < 1e-9
    assert at_end.sum() >= 10 and np.allclose(rested.a[at_end], 0.0)   # at the end: stay
    both = replace(cfg, reverse_pairs=True, corrective_copies=2, corrective_sigma=0.05)
    corrected = build_pairs([item], both, paper_pairs, np.random.default_rng(0))
    n = 2 * plain.n_forward                                   # forward and reversed
    assert len(corrected.q) == 3 * n and corrected.n_forward == plain.n_forward
    base_end = corrected.q[:n] + corrected.a[:n]
    for k in (1, 2):
        copy = slice(k * n, (k + 1) * n)
        np.testing.assert_allclose(corrected.q[copy] + corrected.a[copy], base_end, atol=1e-12)
        assert np.std(corrected.q[copy] - corrected.q[:n]) == pytest.approx(0.05, rel=0.1)
        assert np.array_equal(corrected.sign[copy], corrected.sign[:n])


def test_the_recipe_names_the_new_options_and_refuses_bad_values():
    cfg = TrainConfig(rest_samples=10, corrective_copies=3, corrective_sigma=0.03)
    assert "rest 10" in cfg.mode() and "corrective 3 x 0.03 rad" in cfg.mode()
    assert "rest" not in TrainConfig().mode()
    for bad in (dict(rest_samples=-1), dict(corrective_copies=-2), dict(corrective_sigma=0.0)):
        with pytest.raises(ValueError):
            TrainConfig(**bad).validate()
