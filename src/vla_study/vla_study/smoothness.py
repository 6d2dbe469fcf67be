"""Smoothness of an end-effector path: SPARC and log dimensionless jerk.

SPARC, the spectral arc length (Balasubramanian, Melendez-Calderon, Roby-Brami & Burdet 2015, J.
NeuroEng. Rehabil. 12:112): the arc length of the normalised speed spectrum up to an adaptive cut-off;
closer to 0 is smoother, jagged stop-and-go paths are more negative. LDLJ (Hogan & Sternad 2009):
-ln(T^3 / v_peak^2 * integral |jerk|^2 dt); more negative is less smooth. Both are independent of the
movement's size and length, so latent and end-effector paths compare directly.
"""
from __future__ import annotations

import numpy as np


def speed_profile(path: np.ndarray, times: np.ndarray) -> np.ndarray:
    path, times = np.asarray(path, float), np.asarray(times, float)
    if len(path) < 3:
        return np.zeros(0)
    # a repeated stamp (two joint_states with one time) would divide by zero: the first of them stays
    later = np.concatenate([[True], np.diff(times) > 0])
    path, times = path[later], times[later]
    if len(path) < 3:
        return np.zeros(0)
    return np.linalg.norm(np.gradient(path, times, axis=0), axis=1)


STILL = 1e-9   # m/s: a hand slower than this all along did not move (numerical noise of a resting arm)


def sparc(speed: np.ndarray, fs: float, pad_level: int = 4, fc: float = 10.0, amp_th: float = 0.05) -> float:
    """Spectral arc length of a speed profile sampled at fs Hz (the authors' reference algorithm); NaN
    for a hand that did not move (its spectrum is noise)."""
    speed = np.asarray(speed, float)
    if len(speed) < 3 or not np.all(np.isfinite(speed)) or not np.any(speed > STILL):
        return float("nan")
    nfft = int(2 ** (np.ceil(np.log2(len(speed))) + pad_level))
    f = np.arange(0, fs, fs / nfft)
    mag = np.abs(np.fft.fft(speed, nfft))
    mag = mag / max(mag.max(), 1e-12)
    keep = f <= fc
    f, mag = f[keep], mag[keep]
    above = np.nonzero(mag >= amp_th)[0]
    f, mag = f[: above[-1] + 1], mag[: above[-1] + 1]
    if len(f) < 2:
        return 0.0
    df = np.diff(f) / (f[-1] - f[0])
    return float(-np.sum(np.sqrt(df ** 2 + np.diff(mag) ** 2)))


def log_dimensionless_jerk(path: np.ndarray, times: np.ndarray) -> float:
    path, times = np.asarray(path, float), np.asarray(times, float)
    if len(path) < 5:
        return float("nan")
    v = np.gradient(path, times, axis=0)
    jerk = np.gradient(np.gradient(v, times, axis=0), times, axis=0)
    vpeak = float(np.linalg.norm(v, axis=1).max())
    duration = float(times[-1] - times[0])
    if vpeak <= 0 or duration <= 0:
        return float("nan")
    integral = float(np.trapezoid(np.sum(jerk ** 2, axis=1), times))
    return float(-np.log(max(duration ** 3 / vpeak ** 2 * integral, 1e-12)))


def path_length(path: np.ndarray) -> float:
    path = np.asarray(path, float)
    return float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum()) if len(path) > 1 else 0.0
