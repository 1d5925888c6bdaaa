"""The §4.4 data protocol: Recordings → features at the model rate → windows of length T → 80/20 split.

1. Per Recording: the one conditioning path (:func:`proprio.conditioning.condition`) puts q and τ on the uniform
   grid of the log's nominal step and gives q̇, q̈ from q (zero-phase low-pass at ``cutoff_hz``, a number or ``auto``
   from the noise floor, then central differences; ``velocity: auto`` takes the robot's own q̇ where it logs one);
   optionally a zero-phase low-pass on the measured τ (the thesis trains on "post-processed" torques;
   ``tau_filter_hz``); ``trim_s`` cut from both ends (filter start-up transients).
2. Every ``decimate``-th grid sample kept (the thesis drops every second sample of its ≈150 Hz data → 75 Hz). The
   model rate is therefore ``grid rate / decimate``; the residual System runs at that rate. Samples inside a gap of
   the log (conditioning's ``valid``) never reach a window.
3. τ_RBD from any backbone ``(q, q̇, q̈) -> τ`` and the reversal encoding r on the decimated samples
   (35 features vec(τ_RBD, q, q̇, q̈, r), eq. 4.30).
4. Each Recording is cut into whole non-overlapping subsequences of T samples (the remainder < T is dropped);
   the validation split is a contiguous block at the END of each training Recording (its last ``val_fraction`` of
   the training share of its subsequences): early stopping and the never-worse fallback decide on motion later in
   time than anything they train on, not on random windows that share their neighbours' motion. The rest — the
   subsequence ORDER shuffled with ``seed`` (never the samples inside one) — is split ``1 − test_fraction`` /
   ``test_fraction``, so the test split is never seen during training. With separate test Recordings (e.g. LWR
   file 1), all their subsequences are the test split instead.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Sequence

import numpy as np

from proprio.conditioning import ConditionedSignals, ConditioningConfig, condition, zero_phase_lowpass
from proprio.learning.features import (DEFAULT_DEADBAND_DEG, R_MAX_DEG, TauRbdProvider, feature_matrix,
                                       rotational_displacement)
from proprio.learning.sections import section_from_dict
from proprio.recording import Recording

__all__ = ["DataConfig", "PreparedRecording", "Windows", "Split", "condition_for_training", "kept_samples",
           "prepare_recording", "make_split"]


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
    cutoff_hz: Any = "auto"                 # conditioning's low-pass of q [Hz]: a number, one per joint, or auto
    velocity: str = "q"                     # q̇ from q | auto: the robot's own q̇ where it logs one (conditioning)
    tau_filter_hz: float | None = None      # zero-phase low-pass on measured τ (None: raw)
    trim_s: float = 0.0                     # cut from both ends of every Recording [s]

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> "DataConfig":
        d = dict(d or {})
        if "derivatives" in d or "derivative_cutoff_hz" in d:
            raise ValueError("data: 'derivatives'/'derivative_cutoff_hz' are gone: q̇, q̈ always come from the "
                             "conditioning path; give 'cutoff_hz' (Hz or auto) instead (a model file with them was "
                             "trained on an older protocol: retrain it)")
        cfg = section_from_dict(cls, d, "data")
        cfg.conditioning().check("data")
        if cfg.decimate < 1 or cfg.window < 1:
            raise ValueError("data: decimate and window must be >= 1")
        if not 0 < cfg.test_fraction < 1 or not 0 <= cfg.val_fraction < 1:
            raise ValueError("data: test_fraction must be in (0, 1) and val_fraction in [0, 1)")
        return cfg

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def conditioning(self) -> ConditioningConfig:
        """The conditioning settings of step 1 (τ is low-passed separately, at ``tau_filter_hz``)."""
        c = self.cutoff_hz
        cut = c if isinstance(c, str) else tuple(float(x) for x in c) if isinstance(c, (list, tuple)) else float(c)
        return ConditioningConfig(cutoff_hz=cut, velocity=self.velocity, tau_filter=False)


@dataclass
class PreparedRecording:
    """One Recording at the model rate: ``features [N, 5n]`` (vec(τ_RBD, q, q̇, q̈, r)), target ``tau [N, n]``,
    ``valid [N]`` (False inside a gap of the log; None: all valid) and the conditioning line it was made with."""
    name: str
    t: np.ndarray
    features: np.ndarray
    tau: np.ndarray
    valid: np.ndarray | None = None
    conditioning: str = ""

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

    @property
    def conditioning(self) -> list[str]:
        """The conditioning line of every recording (printed by ``proprio train``)."""
        return [p.conditioning for p in self.recordings if p.conditioning]


def condition_for_training(rec: Recording, cfg: DataConfig) -> tuple[ConditionedSignals, np.ndarray]:
    """Step 1 for one Recording: its conditioned signals and the target τ [N·m] on the same uniform grid."""
    cs = condition(rec, cfg.conditioning())
    if cfg.tau_filter_hz is None:
        return cs, cs.tau
    if not 0 < cfg.tau_filter_hz < cs.rate_hz / 2:
        raise ValueError(f"data: tau_filter_hz = {cfg.tau_filter_hz} must lie in (0, {cs.rate_hz / 2:.1f}) Hz")
    return cs, zero_phase_lowpass(cs.tau, cs.rate_hz, cfg.tau_filter_hz)


def kept_samples(n_samples: int, rate_hz: float, cfg: DataConfig) -> np.ndarray:
    """Indices of the grid samples at the model rate: ``trim_s`` cut from both ends, then every ``decimate``-th
    sample (step 2 of the module docstring)."""
    trim = int(round(cfg.trim_s * rate_hz))
    return np.arange(trim, n_samples - trim, cfg.decimate)


def prepare_recording(rec: Recording, tau_rbd: TauRbdProvider, cfg: DataConfig, name: str = "recording"
                      ) -> PreparedRecording:
    """Steps 1–3 of the module docstring for one Recording."""
    cs, tau = condition_for_training(rec, cfg)
    keep = kept_samples(cs.n_samples, cs.rate_hz, cfg)
    if keep.size < 2:
        raise ValueError(f"{name}: only {keep.size} sample(s) left after trim_s = {cfg.trim_s} and decimate = "
                         f"{cfg.decimate}")
    q, qd, qdd, tau = cs.q[keep], cs.qd[keep], cs.qdd[keep], tau[keep]
    t_rbd = np.asarray(tau_rbd(q, qd, qdd), dtype=float)
    if t_rbd.shape != q.shape:
        raise ValueError(f"{name}: the tau_rbd provider returned shape {list(t_rbd.shape)}, expected {list(q.shape)}")
    r = rotational_displacement(q, cfg.reversal_deadband_deg, cfg.r_max_deg)
    return PreparedRecording(name=name, t=cs.t[keep], features=feature_matrix(t_rbd, q, qd, qdd, r), tau=tau,
                             valid=cs.valid[keep], conditioning=f"{name}: {cs.describe()}")


def _windows(recs: Sequence[PreparedRecording], T: int, offset: int = 0) -> Windows:
    feats, taus, origin = [], [], []
    for k, p in enumerate(recs):
        w = p.tau.shape[0] // T
        if w == 0:
            continue
        whole = np.ones(w, dtype=bool) if p.valid is None else p.valid[:w * T].reshape(w, T).all(axis=1)
        feats.append(p.features[:w * T].reshape(w, T, -1)[whole])
        taus.append(p.tau[:w * T].reshape(w, T, -1)[whole])
        origin.append(np.stack([np.full(w, k + offset), np.arange(w) * T], axis=1)[whole])
    if not feats:
        raise ValueError(f"data: no recording is as long as one window (window = {T} samples at the model rate)")
    return Windows(np.concatenate(feats), np.concatenate(taus), np.concatenate(origin))


def _end_blocks(origin: np.ndarray, share: float) -> np.ndarray:
    """Per recording (``origin[:, 0]``), the indices of its last ``round(share × its windows)`` windows by start
    (at least one where the share is > 0 and the recording has two windows or more): a contiguous block at its end."""
    picked = []
    for k in np.unique(origin[:, 0]):
        mine = np.flatnonzero(origin[:, 0] == k)
        n = int(round(share * len(mine)))
        n = min(max(n, 1 if share > 0 and len(mine) > 1 else 0), len(mine) - 1)
        picked.append(mine[np.argsort(origin[mine, 1])][len(mine) - n:])
    return np.sort(np.concatenate(picked)) if picked else np.zeros(0, dtype=int)


def make_split(train_recs: Sequence[PreparedRecording], cfg: DataConfig,
               test_recs: Sequence[PreparedRecording] = ()) -> Split:
    """Step 4 of the module docstring. The split depends only on the data, ``window`` and ``seed``."""
    rng = np.random.default_rng(cfg.seed)
    pool = _windows(train_recs, cfg.window)
    test_share = 0.0 if test_recs else cfg.test_fraction
    val_idx = _end_blocks(pool.origin, cfg.val_fraction * (1.0 - test_share))
    earlier = np.setdiff1d(np.arange(len(pool)), val_idx)
    order = earlier[rng.permutation(len(earlier))]
    if test_recs:
        test = _windows(test_recs, cfg.window, offset=len(train_recs))
        rest = order
    else:
        n_test = max(1, int(round(cfg.test_fraction * len(pool))))
        test, rest = pool.take(np.sort(order[:n_test])), order[n_test:]
    if len(rest) < 1:
        raise ValueError(f"data: only {len(pool)} window(s) of {cfg.window} samples — too few for a train/test split; "
                         "use more data or a shorter window")
    val, train = pool.take(val_idx), pool.take(rest)
    rates = [1.0 / float(np.median(np.diff(p.t))) for p in list(train_recs) + list(test_recs)]
    return Split(train=train, val=val, test=test, recordings=list(train_recs) + list(test_recs),
                 rate_hz=float(np.median(rates)))
