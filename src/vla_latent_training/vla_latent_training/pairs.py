"""Training pairs from a demonstration, as the paper makes them (plain NumPy).

For w = 1..10, a = q[t+w] - (q[t] + eps), with eps ~ N(0, sigma^2) drawn once per demonstration (the
paper's public code reuses one draw for all demonstrations: a bug).
"""
from __future__ import annotations

import numpy as np


def make_pairs(demo, rng: np.random.Generator, windows: int = 10,
               sigma: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """(q_noisy, actions): for w = 1..windows and every t, q[t] + eps and q[t+w] - (q[t] + eps).

    eps ~ N(0, sigma^2) (7,) is drawn once for this demonstration.
    """
    q = np.asarray(demo.q, dtype=np.float64)
    eps = rng.normal(0.0, sigma, size=q.shape[1])
    states, actions = [], []
    for w in range(1, windows + 1):
        if len(q) <= w:
            break
        noisy = q[:-w] + eps
        states.append(noisy)
        actions.append(q[w:] - noisy)
    if not states:
        empty = np.zeros((0, q.shape[1]))
        return empty, empty.copy()
    return np.concatenate(states), np.concatenate(actions)
