"""Preprocessing of excitation measurements (thesis §4.1, after eq. 4.21).

1. average the repetitions sample by sample (eq. 4.20–4.21);
2. Gaussian-weighted moving average of ``q`` and ``τ`` (window 10 samples, like MATLAB's ``smoothdata(...,
   'gaussian', 10)``: the window spans ±2.5 σ, i.e. σ = window / 5);
3. velocities and accelerations by central differences (``np.gradient`` on the time stamps);
4. each derivative low-pass filtered forward and backward by a first-order Butterworth (``scipy.signal.filtfilt``).

All parameters live in ``proprio/configs/excitation.yaml`` (section ``preprocessing``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.ndimage
import scipy.signal

__all__ = ["PreprocessConfig", "average_repetitions", "gaussian_moving_average", "differentiate", "preprocess"]


@dataclass(frozen=True)
class PreprocessConfig:
    """``window`` [samples] of the Gaussian moving average; ``cutoff_hz`` and ``order`` of the Butterworth filter
    applied to the differentiated signals."""
    window: int = 10
    cutoff_hz: float = 1.0
    order: int = 1

    @classmethod
    def from_dict(cls, d: dict) -> "PreprocessConfig":
        unknown = set(d) - {"window", "cutoff_hz", "order"}
        if unknown:
            raise ValueError(f"preprocessing: unknown keys {sorted(unknown)}")
        cfg = cls(**d)
        if cfg.window < 1 or cfg.cutoff_hz <= 0 or cfg.order < 1:
            raise ValueError(f"preprocessing: window >= 1, cutoff_hz > 0 and order >= 1 required, got {cfg}")
        return cfg


def average_repetitions(runs: list[np.ndarray]) -> np.ndarray:
    """Sample-wise mean of equally long repetitions ``[N, n]`` (eq. 4.20–4.21); shorter runs truncate all."""
    if not runs:
        raise ValueError("average_repetitions: no runs given")
    n_min = min(r.shape[0] for r in runs)
    return np.mean(np.stack([np.asarray(r, dtype=float)[:n_min] for r in runs]), axis=0)


def gaussian_moving_average(x: np.ndarray, window: int) -> np.ndarray:
    """Gaussian-weighted moving average along axis 0 over ``window`` samples (σ = window / 5)."""
    if window <= 1:
        return np.asarray(x, dtype=float)
    return scipy.ndimage.gaussian_filter1d(np.asarray(x, dtype=float), sigma=window / 5.0, axis=0, mode="nearest",
                                           truncate=2.5)


def differentiate(t: np.ndarray, x: np.ndarray, cfg: PreprocessConfig) -> np.ndarray:
    """Central difference of ``x [N, n]`` over ``t [N]`` s, then zero-phase Butterworth low-pass."""
    dx = np.gradient(x, t, axis=0)
    rate = 1.0 / np.median(np.diff(t))
    if cfg.cutoff_hz >= rate / 2:
        raise ValueError(f"preprocessing.cutoff_hz = {cfg.cutoff_hz} Hz is not below the Nyquist rate {rate / 2} Hz")
    b, a = scipy.signal.butter(cfg.order, cfg.cutoff_hz, fs=rate)
    return scipy.signal.filtfilt(b, a, dx, axis=0)


def preprocess(t: np.ndarray, q_runs: list[np.ndarray], tau_runs: list[np.ndarray],
               cfg: PreprocessConfig = PreprocessConfig()) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The §4.1 chain: average → smooth → differentiate twice → filter. Returns ``q, qd, qdd, tau [N, n]``."""
    q = gaussian_moving_average(average_repetitions(q_runs), cfg.window)
    tau = gaussian_moving_average(average_repetitions(tau_runs), cfg.window)
    t = np.asarray(t, dtype=float)[:q.shape[0]]
    qd = differentiate(t, q, cfg)
    qdd = differentiate(t, qd, cfg)
    return q, qd, qdd, tau
