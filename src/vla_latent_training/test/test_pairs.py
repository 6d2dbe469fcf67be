"""Training pairs as the paper makes them, with the noise drawn once per demonstration."""
from types import SimpleNamespace

import numpy as np
from vla_latent_training.pairs import make_pairs


def _demo(T: int = 25) -> SimpleNamespace:
    t = np.arange(T) * 0.1
    return SimpleNamespace(t=t, q=np.stack([np.sin(t + k) for k in range(7)], axis=1))


def test_pairs_follow_the_paper():
    demo = _demo()
    q_noisy, actions = make_pairs(demo, np.random.default_rng(3))
    eps = np.random.default_rng(3).normal(0.0, 0.01, size=7)
    T = len(demo.q)
    assert len(q_noisy) == len(actions) == sum(T - w for w in range(1, 11))
    expected_states = np.concatenate([demo.q[:-w] + eps for w in range(1, 11)])
    expected_actions = np.concatenate([demo.q[w:] - (demo.q[:-w] + eps) for w in range(1, 11)])
    assert np.allclose(q_noisy, expected_states) and np.allclose(actions, expected_actions)
    # the noise is one draw per demonstration: the same eps in every pair of this demo
    assert np.allclose(q_noisy[:T - 1] - demo.q[:-1], eps)
    # ...and a different draw for the next demo from the same generator
    rng = np.random.default_rng(3)
    a, _ = make_pairs(demo, rng)
    b, _ = make_pairs(demo, rng)
    assert not np.allclose(a - b, 0)


def test_a_demo_shorter_than_a_window_gives_what_it_can():
    q_noisy, actions = make_pairs(_demo(3), np.random.default_rng(0))
    assert len(q_noisy) == len(actions) == 2 + 1
    q_noisy, actions = make_pairs(_demo(1), np.random.default_rng(0))
    assert q_noisy.shape == actions.shape == (0, 7)
