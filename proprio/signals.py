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
from typing import Any

import numpy as np
import scipy.ndimage
import scipy.signal

__all__ = ["MotionSignals", "PreprocessConfig", "average_repetitions", "gaussian_moving_average", "differentiate", "preprocess"]


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


@dataclass(frozen=True)
class MotionSignals:
    """Link-side motion that effects are functions of (SI units, shapes ``[N]`` / ``[N, n]``).

    ``tau`` (optional) is the link-side torque the sensor sees before the effect is applied: the gain error scales
    it, and load-dependent amplitudes (``load_gain``) grow with ``|tau|``. The twin passes its true τ_J; a fit on
    measured data may pass the measured or modelled τ.
    """
    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.q.ndim != 2 or self.qd.shape != self.q.shape or self.qdd.shape != self.q.shape:
            raise ValueError(f"MotionSignals: q, qd, qdd must all be [N, n], got {self.q.shape}, {self.qd.shape}, "
                             f"{self.qdd.shape}")
        if self.t.shape != (self.q.shape[0],):
            raise ValueError(f"MotionSignals: t must be [N] = [{self.q.shape[0]}], got {self.t.shape}")
        if self.tau is not None and self.tau.shape != self.q.shape:
            raise ValueError(f"MotionSignals: tau must be {self.q.shape}, got {self.tau.shape}")

    @property
    def n(self) -> int:
        return int(self.q.shape[1])

    @classmethod
    def from_recording(cls, rec: Any, tau: np.ndarray | None = None) -> "MotionSignals":
        """Signals of a :class:`proprio.recording.Recording`: its ``qd``/``qdd`` if present, else central differences
        (``np.gradient``, second order inside). ``tau`` defaults to the recording's measured torque."""
        t = np.asarray(rec.t, dtype=float)
        q = np.asarray(rec.q, dtype=float)
        qd = np.asarray(rec.qd, dtype=float) if rec.qd is not None else np.gradient(q, t, axis=0)
        qdd = np.asarray(rec.qdd, dtype=float) if rec.qdd is not None else np.gradient(qd, t, axis=0)
        return cls(t=t, q=q, qd=qd, qdd=qdd, tau=np.asarray(rec.tau if tau is None else tau, dtype=float))

    def with_tau(self, tau: np.ndarray | None) -> "MotionSignals":
        return MotionSignals(self.t, self.q, self.qd, self.qdd, tau)
