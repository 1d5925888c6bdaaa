"""What stays unexplained on the held-out data after the selection (:mod:`proprio.diagnosis.selection.forward`): its
structure per joint — Ljung–Box over time, held-out R² against the motion state, the part within the conditioning's own
error — and unmodelled white torque noise.

**White only when both tests agree.** A joint's residual is white when the Ljung–Box test finds no autocorrelation
(p ≥ :data:`WHITE_ALPHA`) *and* the motion state does not predict it on held-out data (R² ≤ :data:`WHITE_R2`). A
structured residual within the processing error is not taken for an effect outside the candidate set, but it is not
white either, so it is never reported as sensor noise nor patched as torque noise.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from proprio import friction_law
from proprio.diagnosis.data import GapData, SimModel
from proprio.effects import EFFECTS

__all__ = ["WHITE_ALPHA", "WHITE_R2", "NoiseFinding", "ResidualStructure", "residual_structure", "noise_findings",
           "split_by_recording"]

WHITE_ALPHA = 0.01          # Ljung–Box level below which a residual is autocorrelated
WHITE_R2 = 0.05             # held-out R² against the motion state above which a residual is predictable


@dataclass
class NoiseFinding:
    """Unmodelled white noise: ``rms [n]`` N·m per joint (0 on joints where the residual is structured or within
    the model's own noise)."""
    name: str
    rms: np.ndarray
    explanation: str


@dataclass
class ResidualStructure:
    """What stays unexplained on the held-out data: per joint RMSE [N·m], Ljung–Box p-value (lags 1..20 of the
    residual decimated to ≥ 0.05 s spacing), held-out R² of the residual against state features, and a verdict.
    ``within_processing [n]``: the residual's non-white part (its variance less the white part estimated from
    first differences) is within 1.5× the torque error the conditioning explains, so a joint's structure is not
    taken for an effect outside the candidate set. ``white_rms [n]`` N·m: the white part of the residual (from its
    first differences)."""
    rmse: np.ndarray
    ljung_box_p: np.ndarray
    r2_state: np.ndarray
    structured_time: np.ndarray
    structured_state: np.ndarray
    within_processing: np.ndarray
    white_rms: np.ndarray

    @property
    def white_joints(self) -> np.ndarray:
        """``bool [n]``: joints whose residual passes *both* whiteness tests (Ljung–Box p ≥ α and held-out R² against
        the state ≤ 0.05) — a structured residual within the processing error is not white."""
        return (self.ljung_box_p >= WHITE_ALPHA) & (self.r2_state <= WHITE_R2)

    @property
    def white(self) -> bool:
        """Every joint's residual is white by both tests (:attr:`white_joints`)."""
        return bool(self.white_joints.all())


def residual_structure(r_h: np.ndarray, r_tr: np.ndarray, train: GapData, hold: GapData,
                        rate: float, proc_sigma: np.ndarray) -> ResidualStructure:
    n = r_h.shape[1]
    step = max(1, int(round(0.05 * rate)))
    lb = np.ones(n)
    for j in range(n):
        ps = []
        for e_k in _series(r_h[:, j], hold):
            x = e_k[::step] - e_k[::step].mean()
            m = min(20, len(x) // 5)
            if m < 2 or x @ x <= 0:
                continue
            rho = np.array([x[:-k] @ x[k:] for k in range(1, m + 1)]) / (x @ x)
            q = len(x) * (len(x) + 2) * np.sum(rho ** 2 / (len(x) - np.arange(1, m + 1)))
            ps.append(stats.chi2.sf(q, m))
        lb[j] = min(ps) if ps else 1.0

    def feats(data: GapData) -> np.ndarray:
        f = [np.concatenate([s.q, s.qd, friction_law.smooth_sign(s.qd), s.qdd, np.sin(s.q), np.cos(s.q)], axis=1)
             for s in data.signals]
        f = data.stack(f)
        return np.concatenate([np.ones((len(f), 1)), f], axis=1)

    ft, fh = feats(train), feats(hold)
    r2 = np.zeros(n)
    for j in range(n):
        coef, *_ = np.linalg.lstsq(ft, r_tr[:, j], rcond=1e-8)
        res = r_h[:, j] - fh @ coef
        r2[j] = 1.0 - float(res @ res) / max(float(r_h[:, j] @ r_h[:, j]), 1e-300)
    series = _series(r_h, hold)
    white_var = sum((np.diff(s, axis=0) ** 2).sum(axis=0) / 2 for s in series) / \
        max(sum(len(s) - 1 for s in series), 1)
    structured_rms = np.sqrt(np.maximum((r_h ** 2).mean(axis=0) - white_var, 0.0))
    within = structured_rms <= 1.5 * proc_sigma
    return ResidualStructure(np.sqrt((r_h ** 2).mean(axis=0)), lb, r2, (lb < WHITE_ALPHA) & ~within,
                             (r2 > WHITE_R2) & ~within, within, np.sqrt(white_var))


def split_by_recording(x: np.ndarray, data: GapData) -> list[np.ndarray]:
    sizes = np.cumsum([len(i) for i in data.fit_index])[:-1]
    return np.split(x, sizes)


def _series(x: np.ndarray, data: GapData) -> list[np.ndarray]:
    """``x`` per source recording: pieces cut from one recording (cross-validation blocks) joined in time order."""
    parts = split_by_recording(x, data)
    groups: dict[int, list[np.ndarray]] = {}
    for g, part in zip(data.groups, parts):
        groups.setdefault(g, []).append(part)
    return [np.concatenate(v) for v in groups.values()]


def noise_findings(model: SimModel, structure: ResidualStructure, hold: GapData,
                    r_h: np.ndarray) -> list[NoiseFinding]:
    """Unmodelled noise: the remaining residual is white by both tests (:attr:`ResidualStructure.white_joints`; a
    structured residual is never noise, whatever its size) and larger than the model's own noise (variance ratio
    beyond the χ² 99.9 % bound of the sample variance, plus 20 % of slack). Its level is the residual's white part
    (first differences) less the model's noise, brought back to the log's own rate through ``tau_gain`` (a decimated
    τ keeps its noise density, not its variance), and never above the raw τ's own white level at that rate
    (``ConditionedSignals.sigma_tau``): a residual white on the conditioned grid but smooth in the raw log is
    unmodelled motion, not sensor noise: it is no finding when the raw level is below half of it, and a patch adds
    at most what a τ sample at the robot's rate has."""
    present = model.effect_names
    out = []
    white_j = structure.white_joints
    if not white_j.any():
        return out
    gain = np.mean([cs.tau_gain for cs in hold.conditioned], axis=0)
    expected = np.mean([model.noise_variance(s) * cs.tau_gain for s, cs in zip(hold.signals, hold.conditioned)],
                       axis=0)          # through the same processing as the conditioned τ
    var = (r_h ** 2).mean(axis=0)
    m = len(r_h)
    bound = expected * 1.2 * stats.chi2.ppf(0.999, m) / m + 1e-12
    excess = white_j & (var > bound)
    if not excess.any():
        return out
    if "torque_noise" not in present and "torque_noise" in EFFECTS:
        level = np.sqrt(np.maximum(np.minimum(var, structure.white_rms ** 2) - expected, 0.0) / gain)
        raw = [cs.sigma_tau for cs in hold.conditioned if cs.sigma_tau is not None]
        if raw:
            raw_level = np.sqrt(np.mean(np.square(raw), axis=0))
            excess &= raw_level >= 0.5 * level          # the raw τ must carry the noise the residual shows
            level = np.minimum(level, raw_level)
        if not excess.any():
            return out
        out.append(NoiseFinding("torque_noise", np.where(excess, level, 0.0),
                                "white residual above the model's noise level"))
    return out
