"""What stays unexplained on the held-out data after the selection (:mod:`proprio.diagnosis.selection.forward`): its
structure per joint — Ljung–Box over time, held-out R² against the motion state, the part within the conditioning's own
error — and unmodelled white torque noise.

**White only when both tests agree.** A joint's residual is white when the Ljung–Box test finds no autocorrelation
(p ≥ :data:`WHITE_ALPHA`) *and* the motion state does not predict it on held-out data (R² ≤ :data:`WHITE_R2`). A
structured residual within the processing error is not taken for an effect outside the candidate set, but it is not
white either: there the whiteness test cannot decide whether torque noise is unmodelled, and the raw τ's own white
floor, measured independently of the model, does (:func:`noise_findings`).
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
NOISE_SLACK = 1.2           # variance slack on the χ² 99.9 % bounds of the torque-noise rules (noise_findings)


@dataclass
class NoiseFinding:
    """Unmodelled white noise: ``rms [n]`` N·m per joint (0 on joints where neither rule of :func:`noise_findings`
    names it); ``explanation``: which rule(s) named it."""
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
    """Unmodelled torque noise, for a model without a torque-noise effect, by one of two rules per joint.

    **White residual.** The remaining residual is white by both tests (:attr:`ResidualStructure.white_joints`; a
    structured residual is never noise, whatever its size) and larger than the model's own noise (variance ratio
    beyond the χ² 99.9 % bound of the sample variance, plus 20 % of slack). Its level is the residual's white part
    (first differences) less the model's noise, brought back to the log's own rate through ``tau_gain`` (a decimated
    τ keeps its noise density, not its variance), and never above the raw τ's own white level at that rate
    (``ConditionedSignals.sigma_tau``): a residual white on the conditioned grid but smooth in the raw log is
    unmodelled motion, not sensor noise: it is no finding when the raw level is below half of it, and a patch adds
    at most what a τ sample at the robot's rate has.

    **Raw floor, where the whiteness test cannot decide.** On a joint whose residual is not white but whose structure
    lies within the conditioning's own error (:attr:`ResidualStructure.within_processing`), the structure may be
    the data path's own making (the low-pass takes the motion's fast part out of q̈), so the whiteness test cannot
    tell noise from it. There the white floor of the raw τ, measured independently of the model, decides
    (:func:`_raw_floor_joints`), and its level ``sigma_tau`` is the finding's σ."""
    if "torque_noise" in model.effect_names or "torque_noise" not in EFFECTS:
        return []
    n = r_h.shape[1]
    level, white_hit = np.zeros(n), np.zeros(n, dtype=bool)
    white_j = structure.white_joints
    raw = [cs.sigma_tau for cs in hold.conditioned if cs.sigma_tau is not None]
    raw_level = np.sqrt(np.mean(np.square(raw), axis=0)) if raw else None
    if white_j.any():
        gain = np.mean([cs.tau_gain for cs in hold.conditioned], axis=0)
        expected = np.mean([model.noise_variance(s) * cs.tau_gain
                            for s, cs in zip(hold.signals, hold.conditioned)], axis=0)   # as the conditioned τ
        var = (r_h ** 2).mean(axis=0)
        m = len(r_h)
        bound = expected * NOISE_SLACK * stats.chi2.ppf(0.999, m) / m + 1e-12
        white_hit = white_j & (var > bound)
        level = np.sqrt(np.maximum(np.minimum(var, structure.white_rms ** 2) - expected, 0.0) / gain)
        if raw_level is not None:
            white_hit &= raw_level >= 0.5 * level          # the raw τ must carry the noise the residual shows
            level = np.minimum(level, raw_level)
    floor_hit = _raw_floor_joints(structure, hold, len(r_h)) & ~white_hit
    if not (white_hit.any() or floor_hit.any()):
        return []
    why = []
    if white_hit.any():
        why.append("white residual above the model's noise level")
    if floor_hit.any():
        why.append("the raw τ's white floor where the residual's structure is within the conditioning error")
    rms = np.where(white_hit, level, np.where(floor_hit, raw_level if raw_level is not None else 0.0, 0.0))
    return [NoiseFinding("torque_noise", rms, "; ".join(why))]


def _raw_floor_joints(structure: ResidualStructure, hold: GapData, m: int) -> np.ndarray:
    """``bool [n]``: joints whose residual is structured only within the conditioning's error and whose raw τ floor
    is white noise, for a model without torque noise (:func:`noise_findings`).

    The model's own noise variance is 0 here, so "the raw level exceeds the model's" holds for any τ with a floor at
    all — a noise-free or filtered τ too (its Δ²τ floor is the motion's, or the filter's). The test is therefore that
    the floor is *white*: its levels from ``Δ²τ`` (``sigma_tau``, σ₂) and ``Δ³τ`` (``sigma_tau3``, σ₃), which white
    noise gives alike and a motion- or filter-made floor does not (smaller from ``Δ³τ``), agree within the χ² 99.9 %
    bound on the ``m`` held-out samples: neither of ``σ₂², σ₃²`` exceeds ``1.2 · χ²_{m, 0.999} / m`` times the other
    (each pooled over the held-out recordings). ``m`` counts the conditioned held-out grid, never more than the raw
    samples the levels come from, so the bound is wider than the raw count's. The 20 % slack (the white-residual and
    encoder-floor rules' own): both levels are medians of overlapping differences of the same samples, not sample
    variances; on white Gaussian noise their ratio exceeds the bare χ² bound in 0.3–1 % of draws (N = 300–30 000)
    instead of 0.1 %, the bound with the slack in none of 1000."""
    n = len(structure.rmse)
    pairs = [(cs.sigma_tau, cs.sigma_tau3) for cs in hold.conditioned
             if cs.sigma_tau is not None and cs.sigma_tau3 is not None]
    cand = structure.within_processing & ~structure.white_joints
    if not pairs or not cand.any() or m < 2:
        return np.zeros(n, dtype=bool)
    s2 = np.mean([p[0] ** 2 for p in pairs], axis=0)
    s3 = np.mean([p[1] ** 2 for p in pairs], axis=0)
    bound = NOISE_SLACK * stats.chi2.ppf(0.999, m) / m
    return cand & (s2 > 0) & (s2 <= bound * s3) & (s3 <= bound * s2)
