"""The simulation model under diagnosis (:class:`SimModel`: a robot description plus the joint effects it already
simulates) and recordings prepared for the diagnosis (:class:`GapData`: conditioned signals, residual, held-out
blocks). Every recording goes through the one conditioning path (:mod:`proprio.conditioning`): the residual is
``e = LP(τ_meas) − τ_sim(conditioned q, q̇, q̈)`` with the same zero-phase low-pass on both sides.

**Session clock.** Every recording is placed on the session clock by its ``meta["session_time_s"]`` (the session
time [s] at its t = 0, written by the twin; absent → 0):
the :class:`~proprio.signals.MotionSignals` the model and the candidates see have ``t + session_time_s``, so a
time-varying effect (``offset_drift``, ``friction_warmup``) is evaluated at the time the data were taken."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from proprio.description import RobotDescription
from proprio.dynamics import inverse_dynamics
from proprio.effects import JointEffect, ViscousCoulomb, resolve_effect, robot_friction
from proprio.identification.regressor import drive_identified, drive_torque
from proprio.conditioning import ConditionedSignals, ConditioningConfig, condition
from proprio.recording import Recording, validate_recording
from proprio.signals import MotionSignals

__all__ = ["DiagnosisError", "SimModel", "Conditioned", "condition_recordings", "GapData", "signals_of",
           "condition_all", "check_kept", "kept", "session_time", "session_motion", "NOISE_EFFECTS",
           "DIAGNOSIS_CONDITIONING", "identified_robot", "default_trim_s", "MAX_TRIM_S"]


NOISE_EFFECTS = ("torque_noise", "encoder_noise")
MIN_BLOCKS = 10
MIN_BLOCK_S = 0.25
MAX_FIT_SAMPLES = 4000
MAX_TRIM_S = 0.5         # s, the default trim per end of a recording long enough to afford it
TRIM_SHARE = 0.05        # the most of a recording's length the default trim takes per end beyond the settling


DIAGNOSIS_CONDITIONING = ConditioningConfig(tau_filter=False, decimate=True, velocity="auto")
"""The diagnosis conditions the motion (q̇, q̈ for the rigid body) but compares the raw τ_J: its effect candidates
(ripple, noise, hysteresis steps) model τ's whole band, and a zero-phase filter would only hide it. A log sampled far
faster than the arm moves (1–5 kHz) is decimated to ≈10× its motion band first (anti-aliased, zero phase:
:mod:`proprio.conditioning`), which keeps every candidate's band and makes long logs tractable. The robot's own q̇
is used where it logs one that is better than d/dt q (no lag, no more noise); the conditioning line says which."""


class DiagnosisError(ValueError):
    """Bad input to the gap diagnosis; the message names the offending argument."""


@dataclass(frozen=True)
class SimModel:
    """A simulation model: rigid-body description (+ its viscous/Coulomb friction, if it has any, applied link-side)
    and the joint effects it already simulates. ``predict`` is the deterministic τ_J it expects [N·m]; noise
    effects contribute nothing to the prediction, only to the expected residual variance."""
    robot: RobotDescription
    effects: tuple[JointEffect, ...] = ()

    def __post_init__(self) -> None:
        names = [e.name for e in self.effects]
        twice = sorted({k for k in names if names.count(k) > 1})
        if twice:
            raise DiagnosisError(f"effects: {twice} given more than once")
        if self.robot.has_friction and "viscous_coulomb" in names:
            raise DiagnosisError(f"effects: viscous_coulomb given twice — the robot description '{self.robot.name}' "
                                 "already has link friction (friction.viscous / friction.coulomb) and the effect list "
                                 "names viscous_coulomb; drop one of them")

    @classmethod
    def of(cls, model: "SimModel | RobotDescription") -> "SimModel":
        return model if isinstance(model, SimModel) else cls(model)

    @classmethod
    def from_names(cls, robot: RobotDescription, names: Sequence[str] = ()) -> "SimModel":
        """The model with the named effects (library names or plugin paths ``"package.module:Class"``) at their
        default parameters."""
        try:
            classes = [resolve_effect(k) for k in names]
        except ValueError as exc:
            raise DiagnosisError(f"effects: {exc}") from exc
        return cls(robot, tuple(c(robot.n) for c in classes))

    @property
    def robot_friction(self) -> ViscousCoulomb | None:
        """The description's link friction as the ``viscous_coulomb`` effect (the one law of
        :mod:`proprio.friction_law`), or ``None`` when the description has none."""
        return robot_friction(self.robot)

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
        tau = self.rigid_torque(s.q, s.qd, s.qdd)
        if drive_identified(self.robot):
            tau = tau + np.asarray(self.robot.drive.offset)          # a drive arm's constant drive offsets τ_0
        for eff in self.effects:
            if eff.place != "sensor":
                tau = tau + eff.torque(s)
        s_link = s.with_tau(tau)
        out = tau.copy()
        for eff in self.effects:
            if eff.place == "sensor" and eff.name not in NOISE_EFFECTS:
                out = out + eff.torque(s_link)
        return tau, out

    def rigid_torque(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """Rigid body + the description's link friction [N·m] (what the processing error propagates through); for a
        drive-torque arm (``drive.tau_kind: drive``) also its drive terms, rotor inertia on q̈ and motor friction on
        the coupled motor velocity (:func:`proprio.identification.regressor.drive_torque`, the identification's law)."""
        tau = inverse_dynamics(self.robot, q, qd, qdd) + drive_torque(self.robot, qd, qdd, None)
        friction = self.robot_friction
        return tau if friction is None else tau + friction.friction(qd)

    def smooth_torque(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """Rigid body + the description's viscous friction [N·m]: the smooth part of the model, through which the
        conditioning's derivative errors propagate (the processing floor). The Coulomb term ``F_c sign(q̇)`` is left
        out: its jump at a reversal is the model's own discontinuity, and a q̇ error flipping it would inflate the
        floor by ``2 F_c`` where the conditioning is not at fault."""
        tau = inverse_dynamics(self.robot, q, qd, qdd)
        if self.robot.has_friction:
            tau = tau + np.asarray(self.robot.friction_viscous) * qd
        return tau

    def noise_variance(self, s: MotionSignals, seed: int = 0) -> np.ndarray:
        """Variance per joint [(N·m)²] of the torque the model's noise effects add (0 without noise effects)."""
        var = np.zeros(self.robot.n)
        rng = np.random.default_rng(seed)
        for eff in self.effects:
            if eff.name == "torque_noise":
                var += np.var(eff.torque(s, rng=rng), axis=0)
        return var


def identified_robot(path: str | Path) -> tuple[RobotDescription, dict[str, dict[str, Any]]]:
    """An identified model ``.npz`` written by ``proprio identify`` (:mod:`proprio.identification.model_io`) as a
    simulation model under diagnosis: the robot description with the identified link inertials and viscous/Coulomb
    friction, and — when the identification fitted per-joint torque offsets [N·m] — the effect configuration
    ``{"sensor_offset_gain": {"offset": [...]}}`` that adds them (``{}`` otherwise). A file that is not such a model,
    or whose parameters are not a physical rigid body, raises :class:`DiagnosisError` naming the file."""
    from proprio.identification.model_io import load_model

    try:
        ident = load_model(path)
        robot = ident.description_identified()
    except (OSError, KeyError, ValueError) as exc:
        raise DiagnosisError(f"--model {path}: not a usable identified model ({exc}); a model that is not physically "
                             "consistent cannot be simulated: identify it with the SDP estimator") from exc
    offsets = np.asarray(ident.offsets, dtype=float)
    return robot, ({"sensor_offset_gain": {"offset": offsets.tolist()}} if np.any(offsets != 0) else {})


def signals_of(rec: Recording, config: ConditioningConfig = DIAGNOSIS_CONDITIONING) -> ConditionedSignals:
    """The conditioned signals of a Recording (:func:`proprio.conditioning.condition`); a Recording too short for the
    filter raises :class:`DiagnosisError` naming the problem."""
    try:
        return condition(rec, config)
    except ValueError as exc:
        raise DiagnosisError(str(exc)) from exc


def default_trim_s(cs: ConditionedSignals, config: ConditioningConfig = DIAGNOSIS_CONDITIONING) -> float:
    """The diagnosis' default trim per end of a conditioned recording [s]: :data:`MAX_TRIM_S`, but no more than
    :data:`TRIM_SHARE` of the recording's length — and never less than the zero-phase low-pass's settling
    (``edge_cycles`` periods of its lowest cutoff, the reach of the filter's padding). A recording of ≥ 10 s keeps
    0.5 s; a short one (the TX40's 3 s held-out tail) loses only what its filters need, not a third of its length."""
    settle = config.edge_cycles / float(np.min(cs.cutoff_hz))
    return float(min(MAX_TRIM_S, max(settle, TRIM_SHARE * float(cs.t[-1] - cs.t[0]))))


def kept(cs: ConditionedSignals, trim_s: float | None = None) -> np.ndarray:
    """``bool [N]``: the samples of a conditioned recording the diagnosis uses — ``trim_s`` [s] of filter start-up
    dropped at both ends (``None``: :func:`default_trim_s`), and none inside a gap of the log."""
    trim = default_trim_s(cs) if trim_s is None else trim_s
    return (cs.t >= cs.t[0] + trim) & (cs.t <= cs.t[-1] - trim) & cs.valid


def session_time(rec: Recording, role: str = "recording") -> float:
    """The session time [s] at the recording's t = 0: ``meta["session_time_s"]`` (absent → 0); a value that is not a
    finite number raises :class:`DiagnosisError` naming the field."""
    value = rec.meta.get("session_time_s", 0.0)
    try:
        out = float(value)
    except (TypeError, ValueError) as exc:
        raise DiagnosisError(f"{role}: meta.session_time_s must be a number of seconds, got {value!r}") from exc
    if not math.isfinite(out):
        raise DiagnosisError(f"{role}: meta.session_time_s must be finite, got {out}")
    return out


def session_motion(cs: ConditionedSignals, session_s: float) -> MotionSignals:
    """The conditioned motion of ``cs`` on the session clock: ``t + session_s`` [s] (its ``tau`` the conditioned
    measured torque)."""
    s = cs.motion()
    return MotionSignals(s.t + session_s, s.q, s.qd, s.qdd, s.tau)


def condition_all(recs: Sequence[Recording], config: ConditioningConfig, role: str) -> list[ConditionedSignals]:
    out = []
    for k, rec in enumerate(recs):
        try:
            out.append(condition(rec, config))
        except ValueError as exc:
            raise DiagnosisError(f"{role} recording {k}: {exc}") from exc
    return out


@dataclass(frozen=True)
class Conditioned:
    """The recordings of a diagnosis, conditioned once (:func:`condition_recordings`): the raw Recordings (``train``,
    ``holdout``; the data-quality check, the twin replay and the truth comparison read them), their conditioned
    signals (``train_cs``, ``holdout_cs``), the kept samples of each (``keep_*``, :func:`kept`), each recording's
    session time [s] (``session_*``), the seconds kept (``train_s``, ``holdout_s``), the trim [s] per end (``None``:
    each recording's default) and the conditioning ``config``. No held-out recordings: the training recordings are
    cross-validated over time blocks."""
    train: list[Recording]
    holdout: list[Recording]
    train_cs: list[ConditionedSignals]
    holdout_cs: list[ConditionedSignals]
    keep_train: list[np.ndarray]
    keep_holdout: list[np.ndarray]
    session_train: list[float]
    session_holdout: list[float]
    train_s: float
    holdout_s: float
    trim_s: float | None
    config: ConditioningConfig

    @property
    def recordings(self) -> list[Recording]:
        """Training then held-out Recordings."""
        return self.train + self.holdout

    @property
    def signals(self) -> list[ConditionedSignals]:
        """Their conditioned signals, in the same order."""
        return self.train_cs + self.holdout_cs

    @property
    def keep(self) -> list[np.ndarray]:
        return self.keep_train + self.keep_holdout

    @property
    def sessions(self) -> list[float]:
        return self.session_train + self.session_holdout


def check_kept(cs: ConditionedSignals, keep: np.ndarray, role: str, k: int) -> None:
    """A recording (or cross-validation piece) the diagnosis can use keeps ≥ 10 samples after trimming."""
    if keep.sum() < 10:
        raise DiagnosisError(f"{role} recording {k}: {cs.n_samples} samples ({cs.t[-1]:.2f} s) leave "
                             "nothing after trimming the filter start-up at each end")


def condition_recordings(model: SimModel, train: Sequence[Recording], holdout: Sequence[Recording] = (),
                         config: ConditioningConfig = DIAGNOSIS_CONDITIONING, trim_s: float | None = None,
                         progress: Callable[[str], None] | None = None) -> Conditioned:
    """Check the recordings against ``model``'s robot, condition each once (:mod:`proprio.conditioning`) and check
    there are enough data for the block test: with held-out recordings ≥ :data:`MIN_BLOCKS` blocks of
    :data:`MIN_BLOCK_S` s of them, without ≥ twice that of training data (two cross-validation folds). ``trim_s`` [s]
    per end (``None``: each recording's default, :func:`default_trim_s`). Raises :class:`DiagnosisError` on bad input
    (no recordings, joint-count mismatch, a recording the filters cannot take, too little data)."""
    n = model.robot.n
    if not train:
        raise DiagnosisError("recordings: need at least one training recording")
    for role, recs in (("training", train), ("holdout", holdout)):
        for k, r in enumerate(recs):
            if r.n_joints != n:
                raise DiagnosisError(f"{role} recording {k}: has {r.n_joints} joints but the model robot "
                                     f"'{model.robot.name}' has {n} (mismatched robots)")
            try:
                validate_recording(r, model.robot, source=f"{role} recording {k}")
            except ValueError as exc:
                raise DiagnosisError(f"{exc} (mismatched robots?)") from exc
    (progress or (lambda msg: None))("conditioning")
    sess_tr = [session_time(r, f"training recording {k}") for k, r in enumerate(train)]
    sess_h = [session_time(r, f"holdout recording {k}") for k, r in enumerate(holdout)]
    cond_tr = condition_all(train, config, "training")
    keep_tr = [kept(cs, trim_s) for cs in cond_tr]
    train_s = sum(float(k.sum()) / cs.rate_hz for cs, k in zip(cond_tr, keep_tr))
    trimmed = "the default trim" if trim_s is None else f"{trim_s:g} s"
    cond_h: list[ConditionedSignals] = []
    keep_h: list[np.ndarray] = []
    held_s = 0.0
    if holdout:
        cond_h = condition_all(holdout, config, "holdout")
        keep_h = [kept(cs, trim_s) for cs in cond_h]
        held_s = sum(float(k.sum()) / cs.rate_hz for cs, k in zip(cond_h, keep_h))
        if held_s < MIN_BLOCKS * MIN_BLOCK_S:
            raise DiagnosisError(f"holdout: {held_s:.2f} s of held-out data after trimming {trimmed} per end is too "
                                 f"short for the block test ({MIN_BLOCKS} blocks of ≥ {MIN_BLOCK_S} s)")
        for role, conds, keeps in (("training", cond_tr, keep_tr), ("holdout", cond_h, keep_h)):
            for k, (cs, kp) in enumerate(zip(conds, keeps)):
                check_kept(cs, kp, role, k)
    elif train_s < 2 * MIN_BLOCKS * MIN_BLOCK_S:
        raise DiagnosisError(f"training: {train_s:.2f} s of data after trimming {trimmed} per end; a diagnosis "
                             f"without --holdout cross-validates over time blocks and needs ≥ "
                             f"{2 * MIN_BLOCKS * MIN_BLOCK_S + 2 * (MAX_TRIM_S if trim_s is None else trim_s):.1f} s")
    return Conditioned(list(train), list(holdout), cond_tr, cond_h, keep_tr, keep_h, sess_tr, sess_h, train_s, held_s,
                       trim_s, config)


@dataclass
class GapData:
    """One set of conditioned recordings (training or held-out) prepared for the diagnosis: motion signals (their
    ``tau`` the modelled link-side torque), the conditioned measured τ, the model's τ, the residual ``e``, the kept
    sample indices, time stamps [s], the session time [s] at each recording's t = 0 (``session_s``; the signals' ``t``
    is on the session clock) and a cache of candidate designs."""
    conditioned: list[ConditionedSignals]
    signals: list[MotionSignals]
    tau: list[np.ndarray]
    tau_sim: list[np.ndarray]
    e: list[np.ndarray]
    fit_index: list[np.ndarray]
    groups: list[int]
    pieces: bool = False
    session_s: list[float] = field(default_factory=list)
    cache: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def build(cls, model: SimModel, conditioned: Sequence[ConditionedSignals], keep: Sequence[np.ndarray],
              role: str, groups: Sequence[int] | None = None, session_s: Sequence[float] | None = None) -> "GapData":
        """``keep [N_k] bool`` per recording: the samples to use (trimmed ends, no gaps); the training set is strided
        down to ``MAX_FIT_SAMPLES`` in total. ``groups``: for pieces cut from recordings (cross-validation blocks),
        the index of the recording each piece comes from. ``session_s``: the session time [s] at each recording's
        (piece's source recording's) t = 0 (default 0 each)."""
        session_s = [0.0] * len(conditioned) if session_s is None else [float(x) for x in session_s]
        if len(session_s) != len(conditioned):
            raise DiagnosisError(f"{role}: session_s has {len(session_s)} entries for {len(conditioned)} recordings")
        sigs, taus, sims, es, idx = [], [], [], [], []
        total = sum(int(k.sum()) for k in keep)
        stride = max(1, int(math.ceil(total / MAX_FIT_SAMPLES)))
        for k, (cs, kp) in enumerate(zip(conditioned, keep)):
            check_kept(cs, kp, role, k)
            s = session_motion(cs, session_s[k])
            link, sim = model.predict_parts(s)
            sigs.append(s.with_tau(link))     # candidates scale/load with the modelled, not the measured, torque
            taus.append(cs.tau)
            sims.append(sim)
            es.append(cs.tau - sim)
            idx.append(np.flatnonzero(kp)[::stride] if role == "training" else np.flatnonzero(kp))
        pieces = groups is not None
        return cls(list(conditioned), sigs, taus, sims, es, idx, list(groups) if pieces else list(range(len(idx))),
                   pieces, session_s)

    @property
    def times(self) -> list[np.ndarray]:
        """Time stamps [s] of the kept samples, per recording."""
        return [cs.t[i] for cs, i in zip(self.conditioned, self.fit_index)]

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
