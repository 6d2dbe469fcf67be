"""The latent-action decoder φ(z, s) in pure NumPy for the control loop (no torch import).

The context is latched for an episode, so its contribution to the first layer, the state normalisation
and the action de-normalisation are folded into the weights once per latch (:meth:`set_context`). A call
is then three small mat-vecs on preallocated buffers.

What the controller commands is :meth:`LatentDecoder.velocity`, not the raw action: the action at latent
z is a chord of the demonstrations, q[t+w] - q[t], over a window w that grows with |z| (the training
pairs take w = 1..10 samples, up to 1 s), and the stick's full extent is the latent of the longest
chords (the 95th percentile of |z|). Commanded as a velocity, a 1 s chord aims where the demonstration
will be a second later: a held full stick cut the demonstrations' corners, turned toward the push 15-20
cm up and slid over the loaf instead of pushing it (issue 20). So the command keeps the chord's speed at
z, the demonstrated speed, and can take its direction from the chord at a fraction of z, a shorter
window that follows the demonstrated path. The controller's ``path_fraction`` (``TeleopParams``) says
which; 1 is the paper's command, the raw action.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np


class LatentDecoder:
    """φ([context, q, z]) → joint action (rad), from the ``decoder.*`` tensors and the model config."""

    def __init__(self, tensors: Mapping[str, np.ndarray], config: Mapping):
        d = config["dims"]
        self.context_dim, self.n, self.latent_dim = int(d["context"]), int(d["joints"]), int(d["latent"])
        if self.latent_dim != 1:
            raise ValueError(f"only a 1-D latent is supported, model has {self.latent_dim}")
        k, n = self.context_dim, self.n
        f64 = np.float64
        W1 = np.asarray(tensors["decoder.0.weight"], f64)
        self._b1 = np.asarray(tensors["decoder.0.bias"], f64)
        self._W2 = np.ascontiguousarray(tensors["decoder.2.weight"], f64)
        self._b2 = np.asarray(tensors["decoder.2.bias"], f64).copy()
        W3 = np.asarray(tensors["decoder.4.weight"], f64)
        b3 = np.asarray(tensors["decoder.4.bias"], f64)
        norm = config["normalisation"]
        mu = np.asarray(norm["q_mean"], f64)
        sd = np.asarray(norm["q_std"], f64)
        sa = np.asarray(norm["a_scale"], f64)
        self._Wc = np.ascontiguousarray(W1[:, :k])
        Wq = W1[:, k : k + n] / sd  # absorbs (q - mu) / sd
        self._A1 = np.ascontiguousarray(np.hstack([Wq, W1[:, k + n :]]))
        self._c1_base = self._b1 - Wq @ mu
        self._A3 = np.ascontiguousarray(W3 * sa[:, None])  # absorbs a = a_n * a_scale
        self._c3 = b3 * sa
        hidden = self._A1.shape[0]
        self._c1 = self._c1_base.copy()
        self._x = np.zeros(n + 1)
        self._h1 = np.empty(hidden)
        self._h2 = np.empty(hidden)
        self._out = np.empty(n)
        self.context: np.ndarray | None = None

    def set_context(self, ctx: np.ndarray) -> None:
        """Latch the context vector (length ``context_dim``); raises ValueError on a bad one."""
        c = np.asarray(ctx, np.float64).reshape(-1)
        if c.shape[0] != self.context_dim:
            raise ValueError(f"context has {c.shape[0]} values, the model expects {self.context_dim}")
        if not np.all(np.isfinite(c)):
            raise ValueError("context contains NaN or Inf")
        self._c1 = self._c1_base + self._Wc @ c
        self.context = c

    def decode(self, q: np.ndarray, z: float) -> np.ndarray:
        """Action for joint state ``q`` (n,) and latent ``z``. Returns an internal buffer: copy to keep it."""
        x = self._x
        x[:-1] = q
        x[-1] = z
        h1, h2, out = self._h1, self._h2, self._out
        np.dot(self._A1, x, out=h1)
        h1 += self._c1
        np.tanh(h1, out=h1)
        np.dot(self._W2, h1, out=h2)
        h2 += self._b2
        np.tanh(h2, out=h2)
        np.dot(self._A3, h2, out=out)
        out += self._c3
        return out

    def velocity(self, q: np.ndarray, z: float, path_fraction: float) -> np.ndarray:
        """The command (n,) for latent ``z`` at ``q`` (a new array): the speed of the chord at z in the
        direction of the chord at ``path_fraction`` x z (see the module docstring)."""
        chord = self.decode(q, z).copy()
        if path_fraction == 1.0:
            return chord
        return _with_speed_of(self.decode(q, path_fraction * z), chord)

    def velocity_batch(self, q: np.ndarray, zs: np.ndarray, path_fraction: float) -> np.ndarray:
        """:meth:`velocity` for N latents (N, n), e.g. a simulated teleoperator's grid."""
        zs = np.asarray(zs, np.float64).reshape(-1)
        chord = self.decode_batch(q, zs)
        if path_fraction == 1.0:
            return chord
        return _with_speed_of(self.decode_batch(q, path_fraction * zs), chord)

    def decode_batch(self, q: np.ndarray, zs: np.ndarray) -> np.ndarray:
        """Actions (N, n) for one state ``q`` and N latents (e.g. a simulated teleoperator's z grid)."""
        zs = np.asarray(zs, np.float64).reshape(-1, 1)
        X = np.hstack([np.broadcast_to(np.asarray(q, np.float64), (zs.shape[0], self.n)), zs])
        H = np.tanh(X @ self._A1.T + self._c1)
        H = np.tanh(H @ self._W2.T + self._b2)
        return H @ self._A3.T + self._c3


def _with_speed_of(path: np.ndarray, chord: np.ndarray) -> np.ndarray:
    """``path``'s direction at ``chord``'s speed, per row (a new array): the rule of :meth:`velocity`.
    A zero path gives zero; a NaN stays NaN (the controller core refuses it)."""
    speed = np.linalg.norm(chord, axis=-1, keepdims=True)
    norm = np.linalg.norm(path, axis=-1, keepdims=True)
    return np.divide(path * speed, norm, out=np.zeros_like(path), where=norm != 0.0)
