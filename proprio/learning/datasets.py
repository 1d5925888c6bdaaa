"""The §4.4 data protocol: Recordings → features at the model rate → windows of length T → 80/20 split.

1. Per Recording (at its own rate): q̇, q̈ from the Recording, or filtered central differences of q when it has
   none or ``derivatives: filtered`` (:func:`proprio.learning.features.filtered_derivatives`; a twin logs the TRUE
   q̇, q̈, a real robot does not); optionally a zero-phase low-pass on the measured τ
   (the thesis trains on "post-processed" torques; ``tau_filter_hz``); ``trim_s`` cut from both ends (filter
   start-up transients).
2. Every ``decimate``-th sample kept (the thesis drops every second sample of its ≈150 Hz data → 75 Hz). The model
   rate is therefore ``rate / decimate``; the residual System runs at that rate.
3. τ_RBD from any backbone ``(q, q̇, q̈) -> τ`` and the reversal encoding r on the decimated samples
   (35 features vec(τ_RBD, q, q̇, q̈, r), eq. 4.30).
4. Each Recording is cut into whole non-overlapping subsequences of T samples (the remainder < T is dropped);
   the subsequence ORDER is shuffled with ``seed`` (never the samples inside one) and split ``1 − test_fraction`` /
   ``test_fraction``; ``val_fraction`` of the training subsequences is held out for early stopping, so the test
   split is never seen during training. With separate test Recordings (e.g. LWR file 1), all their subsequences
   are the test split instead.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Sequence

import numpy as np
from scipy.signal import butter, filtfilt

from proprio.learning.features import (DEFAULT_DEADBAND_DEG, R_MAX_DEG, TauRbdProvider, feature_matrix,
                                       filtered_derivatives, rotational_displacement)
from proprio.learning.sections import section_from_dict
from proprio.recording import Recording

__all__ = ["DataConfig", "PreparedRecording", "Windows", "Split", "kept_samples", "prepare_recording", "make_split"]


@dataclass
class DataConfig:
    """Preprocessing and split settings (the ``data:`` section of a ``train_*.yaml``)."""
    decimate: int = 2                       # keep every k-th sample (thesis: 2)
    window: int = 100                       # subsequence length T [samples at the model rate]
    test_fraction: float = 0.2              # thesis: 80/20
    val_fraction: float = 0.1               # of the training subsequences, for early stopping
    seed: int = 0                           # shuffles the subsequence order
    reversal_deadband_deg: float = DEFAULT_DEADBAND_DEG
    r_max_deg: float = R_MAX_DEG
    derivatives: str = "auto"               # auto: the Recording's qd/qdd if present | filtered: always from q
    derivative_cutoff_hz: float = 5.0       # Butterworth cutoff of the filtered derivatives [Hz]
    tau_filter_hz: float | None = None      # zero-phase low-pass on measured τ (None: raw)
    trim_s: float = 0.0                     # cut from both ends of every Recording [s]

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> "DataConfig":
        cfg = section_from_dict(cls, d, "data")
        if cfg.derivatives not in ("auto", "filtered"):
            raise ValueError(f"data: derivatives must be 'auto' or 'filtered', got {cfg.derivatives!r}")
        if cfg.decimate < 1 or cfg.window < 1:
            raise ValueError("data: decimate and window must be >= 1")
        if not 0 < cfg.test_fraction < 1 or not 0 <= cfg.val_fraction < 1:
            raise ValueError("data: test_fraction must be in (0, 1) and val_fraction in [0, 1)")
        return cfg

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class PreparedRecording:
    """One Recording at the model rate: ``features [N, 5n]`` (vec(τ_RBD, q, q̇, q̈, r)), target ``tau [N, n]``."""
    name: str
    t: np.ndarray
    features: np.ndarray
    tau: np.ndarray

    @property
    def n_joints(self) -> int:
        return self.tau.shape[1]

    @property
    def tau_rbd(self) -> np.ndarray:
        return self.features[:, :self.n_joints]


@dataclass
class Windows:
    """Subsequences of T samples: ``features [W, T, 5n]``, ``tau [W, T, n]``, ``origin [W, 2]`` = (recording, start)."""
    features: np.ndarray
    tau: np.ndarray
    origin: np.ndarray

    def __len__(self) -> int:
        return self.features.shape[0]

    def take(self, idx: np.ndarray) -> "Windows":
        return Windows(self.features[idx], self.tau[idx], self.origin[idx])


@dataclass
class Split:
    """Train / validation / test subsequences plus the prepared recordings they were cut from."""
    train: Windows
    val: Windows
    test: Windows
    recordings: list[PreparedRecording]
    rate_hz: float


def _lowpass(x: np.ndarray, cutoff_hz: float, rate_hz: float, name: str) -> np.ndarray:
    if not 0 < cutoff_hz < rate_hz / 2:
        raise ValueError(f"data: {name} = {cutoff_hz} must lie in (0, {rate_hz / 2:.1f}) Hz")
    b, a = butter(2, cutoff_hz / (rate_hz / 2))
    return filtfilt(b, a, x, axis=0)


def kept_samples(rec: Recording, cfg: DataConfig) -> np.ndarray:
    """Indices of the samples of ``rec`` at the model rate: ``trim_s`` cut from both ends, then every
    ``decimate``-th sample (step 1 and 2 of the module docstring)."""
    trim = int(round(cfg.trim_s * rec.rate_hz))
    return np.arange(trim, rec.n_samples - trim, cfg.decimate)


def prepare_recording(rec: Recording, tau_rbd: TauRbdProvider, cfg: DataConfig, name: str = "recording"
                      ) -> PreparedRecording:
    """Steps 1–3 of the module docstring for one Recording."""
    rate = rec.rate_hz
    if cfg.derivatives == "auto" and rec.qd is not None and rec.qdd is not None:
        qd, qdd = rec.qd, rec.qdd
    else:
        qd, qdd = filtered_derivatives(rec.t, rec.q, cfg.derivative_cutoff_hz)
    tau = rec.tau if cfg.tau_filter_hz is None else _lowpass(rec.tau, cfg.tau_filter_hz, rate, "tau_filter_hz")
    keep = kept_samples(rec, cfg)
    if keep.size < 2:
        raise ValueError(f"{name}: only {keep.size} sample(s) left after trim_s = {cfg.trim_s} and decimate = "
                         f"{cfg.decimate}")
    q, qd, qdd, tau = rec.q[keep], qd[keep], qdd[keep], tau[keep]
    t_rbd = np.asarray(tau_rbd(q, qd, qdd), dtype=float)
    if t_rbd.shape != q.shape:
        raise ValueError(f"{name}: the tau_rbd provider returned shape {list(t_rbd.shape)}, expected {list(q.shape)}")
    r = rotational_displacement(q, cfg.reversal_deadband_deg, cfg.r_max_deg)
    return PreparedRecording(name=name, t=rec.t[keep], features=feature_matrix(t_rbd, q, qd, qdd, r), tau=tau)


def _windows(recs: Sequence[PreparedRecording], T: int, offset: int = 0) -> Windows:
    feats, taus, origin = [], [], []
    for k, p in enumerate(recs):
        w = p.tau.shape[0] // T
        if w == 0:
            continue
        feats.append(p.features[:w * T].reshape(w, T, -1))
        taus.append(p.tau[:w * T].reshape(w, T, -1))
        origin.append(np.stack([np.full(w, k + offset), np.arange(w) * T], axis=1))
    if not feats:
        raise ValueError(f"data: no recording is as long as one window (window = {T} samples at the model rate)")
    return Windows(np.concatenate(feats), np.concatenate(taus), np.concatenate(origin))


def make_split(train_recs: Sequence[PreparedRecording], cfg: DataConfig,
               test_recs: Sequence[PreparedRecording] = ()) -> Split:
    """Step 4 of the module docstring. The split depends only on the data, ``window`` and ``seed``."""
    rng = np.random.default_rng(cfg.seed)
    pool = _windows(train_recs, cfg.window)
    order = rng.permutation(len(pool))
    if test_recs:
        test = _windows(test_recs, cfg.window, offset=len(train_recs))
        rest = order
    else:
        n_test = max(1, int(round(cfg.test_fraction * len(pool))))
        test, rest = pool.take(np.sort(order[:n_test])), order[n_test:]
    n_val = int(round(cfg.val_fraction * len(rest)))
    if len(rest) - n_val < 1:
        raise ValueError(f"data: only {len(pool)} window(s) of {cfg.window} samples — too few for a train/test split; "
                         "use more data or a shorter window")
    val, train = pool.take(rest[:n_val]), pool.take(rest[n_val:])
    rates = [1.0 / float(np.median(np.diff(p.t))) for p in list(train_recs) + list(test_recs)]
    return Split(train=train, val=val, test=test, recordings=list(train_recs) + list(test_recs),
                 rate_hz=float(np.median(rates)))
