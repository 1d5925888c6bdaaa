"""The simulation model under diagnosis (:class:`SimModel`: a robot description plus the joint effects it already
simulates) and recordings prepared for the diagnosis (:class:`GapData`: signals, residual, held-out blocks)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from proprio.description import RobotDescription
from proprio.dynamics import inverse_dynamics
from proprio.effects import EFFECTS, JointEffect
from proprio.recording import Recording
from proprio.signals import MotionSignals

__all__ = ["DiagnosisError", "SimModel", "GapData", "signals_of", "NOISE_EFFECTS"]


NOISE_EFFECTS = ("torque_noise", "encoder_noise")
MIN_BLOCKS = 20
MIN_BLOCK_S = 0.5
MAX_FIT_SAMPLES = 4000


class DiagnosisError(ValueError):
    """Bad input to the gap diagnosis; the message names the offending argument."""




@dataclass(frozen=True)
class SimModel:
    """A simulation model: rigid-body description (+ its viscous/Coulomb friction, if it has any, applied link-side)
    and the joint effects it already simulates. ``predict`` is the deterministic τ_J it expects [N·m]; noise
    effects contribute nothing to the prediction, only to the expected residual variance."""
    robot: RobotDescription
    effects: tuple[JointEffect, ...] = ()

    @classmethod
    def of(cls, model: "SimModel | RobotDescription") -> "SimModel":
        return model if isinstance(model, SimModel) else cls(model)

    @classmethod
    def from_names(cls, robot: RobotDescription, names: Sequence[str] = ()) -> "SimModel":
        """The model with the named library effects at their default parameters."""
        bad = [k for k in names if k not in EFFECTS]
        if bad:
            raise DiagnosisError(f"effects: unknown effect(s) {bad}; the library has {sorted(EFFECTS)}")
        return cls(robot, tuple(EFFECTS[k](robot.n) for k in names))

    @property
    def effect_names(self) -> set[str]:
        names = {e.name for e in self.effects}
        if self.robot.has_friction:
            names.add("viscous_coulomb")
        return names

    def predict(self, s: MotionSignals) -> np.ndarray:
        """Deterministic τ_J [N·m]: rigid body + link-side friction/effects, then sensor effects applied to that
        link-side torque (never to the measured one: a fit must not see the measurement's own noise)."""
        return self.predict_parts(s)[1]

    def predict_parts(self, s: MotionSignals) -> tuple[np.ndarray, np.ndarray]:
        """``(link-side torque, sensor output)`` the model predicts, each ``[N,n]`` N·m."""
        tau = inverse_dynamics(self.robot, s.q, s.qd, s.qdd)
        if self.robot.has_friction:
            tau = tau + np.asarray(self.robot.friction_viscous) * s.qd \
                + np.asarray(self.robot.friction_coulomb) * np.sign(s.qd)
        for eff in self.effects:
            if eff.place != "sensor":
                tau = tau + eff.torque(s)
        s_link = s.with_tau(tau)
        out = tau.copy()
        for eff in self.effects:
            if eff.place == "sensor" and eff.name not in NOISE_EFFECTS:
                out = out + eff.torque(s_link)
        return tau, out

    def noise_variance(self, s: MotionSignals, seed: int = 0) -> np.ndarray:
        """Variance per joint [(N·m)²] of the torque the model's noise effects add (0 without noise effects)."""
        var = np.zeros(self.robot.n)
        rng = np.random.default_rng(seed)
        for eff in self.effects:
            if eff.name == "torque_noise":
                var += np.var(eff.torque(s, rng=rng), axis=0)
        return var


def signals_of(rec: Recording) -> MotionSignals:
    """Motion signals of a Recording (its own q̇, q̈ when present; otherwise the effect library's derivative
    filter, which needs the recording to be longer than the filter — a clear error says so)."""
    return MotionSignals.from_recording(rec)


@dataclass
class GapData:
    """One set of recordings (training or held-out) prepared for the diagnosis: motion signals, measured τ, the
    model residual ``e``, block labels for the held-out test and a cache of candidate designs."""
    recordings: list[Recording]
    signals: list[MotionSignals]
    tau: list[np.ndarray]
    tau_sim: list[np.ndarray]
    e: list[np.ndarray]
    fit_index: list[np.ndarray]
    cache: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def build(cls, model: SimModel, recs: Sequence[Recording], trim_s: float, role: str) -> "GapData":
        sigs, taus, sims, es, idx = [], [], [], [], []
        total = sum(r.n_samples for r in recs)
        stride = max(1, int(math.ceil(total / MAX_FIT_SAMPLES)))
        for k, rec in enumerate(recs):
            try:
                s = signals_of(rec)
            except ValueError as exc:
                raise DiagnosisError(f"{role} recording {k}: {exc}") from exc
            link, sim = model.predict_parts(s)
            s = s.with_tau(link)          # candidates scale/load with the modelled, not the measured, torque
            keep = (rec.t >= rec.t[0] + trim_s) & (rec.t <= rec.t[-1] - trim_s)
            if keep.sum() < 10:
                raise DiagnosisError(f"{role} recording {k}: {rec.n_samples} samples ({rec.duration:.2f} s) leave "
                                     f"nothing after trimming {trim_s} s of filter start-up at each end")
            sigs.append(s)
            taus.append(rec.tau)
            sims.append(sim)
            es.append(rec.tau - sim)
            idx.append(np.flatnonzero(keep)[::stride] if role == "training" else np.flatnonzero(keep))
        return cls(list(recs), sigs, taus, sims, es, idx)

    def stack(self, arrays: Sequence[np.ndarray]) -> np.ndarray:
        """Concatenate per-recording arrays ``[N_k, ...]`` at the kept samples."""
        return np.concatenate([a[i] for a, i in zip(arrays, self.fit_index)])

    @property
    def residual(self) -> np.ndarray:
        return self.stack(self.e)

    def blocks(self, n_blocks: int) -> np.ndarray:
        """Block label per kept sample: contiguous time blocks, never straddling two recordings."""
        sizes = np.array([len(i) for i in self.fit_index], dtype=float)
        per = np.maximum(2, np.round(n_blocks * sizes / sizes.sum())).astype(int)
        out, base = [], 0
        for m, k in zip(sizes.astype(int), per):
            out.append(base + np.minimum((np.arange(m) * k) // m, k - 1))
            base += k
        return np.concatenate(out)
