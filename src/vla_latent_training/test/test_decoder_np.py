import numpy as np
import torch
from vla_latent_controller.artifacts import load_model
from vla_latent_controller.decoder_np import LatentDecoder
from vla_latent_training.cae import CAE


def _torch_decoder(art):
    cfg = art.config
    k = cfg["dims"]["context"]
    cae = CAE(k, 7, 1, 30).double()
    cae.load_state_dict({n: torch.tensor(v, dtype=torch.float64) for n, v in art.tensors.items()})
    return cae, cfg


def test_numpy_decoder_equals_torch(random_model_dir):
    art = load_model(random_model_dir)
    cae, cfg = _torch_decoder(art)
    norm = cfg["normalisation"]
    mu, sd, sa = (np.array(norm[k]) for k in ("q_mean", "q_std", "a_scale"))
    dec = LatentDecoder(art.tensors, cfg)
    rng = np.random.default_rng(3)
    for _ in range(20):
        ctx = rng.uniform(0, 1, cfg["dims"]["context"])
        q = rng.uniform(-2, 2, 7)
        z = float(rng.uniform(-1, 1))
        dec.set_context(ctx)
        ours = dec.decode(q, z).copy()
        with torch.no_grad():
            ref = (
                cae.decode(
                    torch.tensor(ctx)[None], torch.tensor((q - mu) / sd)[None], torch.tensor([[z]])
                ).numpy()[0]
                * sa
            )
        np.testing.assert_allclose(ours, ref, atol=1e-6, rtol=0)
        zs = np.linspace(-1, 1, 5)
        batch = dec.decode_batch(q, zs)
        for i, zi in enumerate(zs):
            np.testing.assert_allclose(batch[i], dec.decode(q, zi), atol=1e-12)


def test_bad_context_rejected(random_model_dir):
    art = load_model(random_model_dir)
    dec = LatentDecoder(art.tensors, art.config)
    import pytest

    with pytest.raises(ValueError, match="expects"):
        dec.set_context(np.zeros(3))
    with pytest.raises(ValueError, match="NaN"):
        dec.set_context(np.full(art.config["dims"]["context"], np.nan))


def test_runtime_never_imports_torch(random_model_dir):
    import subprocess
    import sys

    code = (
        "import sys\n"
        "import vla_latent_controller.controller_node\n"
        "from vla_latent_controller.model import LatentModel\n"
        f"m = LatentModel.load({str(random_model_dir)!r})\n"
        "m.decoder.set_context([1, 0, 0, 0, 0, 0.5, 0.5]); m.decoder.decode([0.0] * 7, 0.5)\n"
        "assert 'torch' not in sys.modules, 'torch was imported'\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
