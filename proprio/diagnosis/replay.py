"""The gap re-measured through the twin: held-out recordings replayed through the Drake twin (a base twin, and the
base twin with a diagnosis' patch), compared with the measured torque.

* **Motion.** The twin tracks a trajectory, so the replay builds one from the recording's *conditioned* q (the
  diagnosis' zero-phase conditioning, :mod:`proprio.conditioning`): a C² cubic spline through knots every
  ``1/(knots_per_cycle · max cutoff)`` seconds of the conditioned q (end slopes = conditioned q̇), knots clipped
  ``LIMIT_MARGIN`` inside the joint limits (the twin refuses a trajectory that leaves them, naming the joint); the
  twin starts on the trajectory, so there is no start-up transient. The twin then moves as the
  robot did, up to its controller's tracking error.
* **Noise.** The twin's τ is compared without its noise: the replay drops the ``torque_noise`` and
  ``encoder_noise`` effects and logs at its own step, exact stamps, nothing lost. What remains of the gap is then the
  data's own noise plus whatever the twin still lacks.
* **Log gaps.** A recording is replayed piece by piece: each stretch between two gaps of its log (dropouts longer
  than the conditioning's ``max_gap_s``, :func:`proprio.time_base.measured_segments`) is conditioned and replayed
  on its own, the twin starting on that stretch's trajectory. A replay never bridges a gap — that would move the twin
  through motion nobody measured and compare it with torques nobody measured. The replayed Recording holds the
  stretches on the recording's clock with the gaps left empty (``meta.segments_s``). Splitting rather than refusing:
  a dropout is common in a real log and the stretches around it are as good as any; only stretches no longer than
  ``2 · trim_s`` (nothing left to score) are skipped, and a recording with none left is refused.
* **Gap.** ``RMS(τ_meas − τ_twin)`` per joint on the same samples the diagnosis scores (the conditioned time base,
  ``trim_s`` dropped at both ends, no log gaps), τ_twin linearly interpolated onto those instants; ``τ_meas`` is the
  conditioned measured torque of the diagnosis' conditioning (raw τ on the uniform time base).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING, Sequence

import numpy as np

from proprio.conditioning import ConditionedSignals, ConditioningConfig
from proprio.time_base import measured_segments
from proprio.description import RobotDescription
from proprio.diagnosis.data import (DIAGNOSIS_CONDITIONING, MAX_TRIM_S, NOISE_EFFECTS, Conditioned, DiagnosisError,
                                    condition_all, kept, session_time)
from proprio.diagnosis.attribution import Attribution
from proprio.diagnosis.patch import Patch
from proprio.recording import Recording

if TYPE_CHECKING:                 # Drake is imported where the twin runs (the diagnosis package loads without it)
    from pydrake.trajectories import PiecewisePolynomial

    from proprio.diagrams.twin import TwinConfig

__all__ = ["ReplayGap", "replay_trajectory_of", "deterministic_twin", "replay_recording", "twin_gap", "replay_gap",
           "replay_patched", "offline_prediction", "LIMIT_MARGIN"]

LIMIT_MARGIN = 1e-3              # rad kept inside each joint limit by the replayed trajectory


@dataclass
class ReplayGap:
    """Held-out gap through the twin: per joint ``rms_before`` (base twin; ``None`` when not run) and
    ``rms_after`` (patched twin) [N·m], their all-joint totals ``sqrt(mean_j rms_j²)``, the offline prediction of
    the diagnosis (``predicted_before`` / ``predicted_after`` [n], ``None`` without one) and the replayed
    Recordings of the patched twin."""
    joint_names: list[str]
    rms_before: np.ndarray | None
    rms_after: np.ndarray
    predicted_before: np.ndarray | None
    predicted_after: np.ndarray | None
    recordings: list[Recording]

    @staticmethod
    def total(rms: np.ndarray | None) -> float | None:
        return None if rms is None else float(np.sqrt(np.mean(np.asarray(rms) ** 2)))

    @property
    def reduction(self) -> float | None:
        """Relative gap reduction through the twin, ``1 − after/before`` (all joints)."""
        b = self.total(self.rms_before)
        return None if b is None else 1.0 - self.total(self.rms_after) / b

    @property
    def predicted_reduction(self) -> float | None:
        """Relative gap reduction the diagnosis predicted offline (all joints)."""
        if self.predicted_before is None:
            return None
        return 1.0 - self.total(self.predicted_after) / self.total(self.predicted_before)

    def text(self) -> str:
        """One plain line: the gap through the twin before / after, and the offline prediction."""
        after = self.total(self.rms_after)
        out = "through the twin: "
        out += (f"before {self.total(self.rms_before):.3f}, after {after:.3f} N·m RMS"
                if self.rms_before is not None else f"{after:.3f} N·m RMS")
        if self.reduction is not None:
            out += f" ({_rms_change(self.reduction)})"
        if self.predicted_before is not None:
            out += (f"; offline prediction: before {self.total(self.predicted_before):.3f}, after "
                    f"{self.total(self.predicted_after):.3f} N·m RMS ({_rms_change(self.predicted_reduction)})")
        return out

    def table(self) -> str:
        """Markdown table per joint [N·m]: through the twin (before / after), and the offline prediction when there
        is one."""
        cols = [("twin before", self.rms_before), ("twin after", self.rms_after),
                ("predicted before", self.predicted_before), ("predicted after", self.predicted_after)]
        cols = [(h, a) for h, a in cols if a is not None]
        rows = ["| joint | " + " | ".join(h for h, _ in cols) + " |", "|---" * (len(cols) + 1) + "|"]
        for j, nm in enumerate(self.joint_names):
            rows.append(f"| {nm} | " + " | ".join(f"{a[j]:.3f}" for _, a in cols) + " |")
        return "\n".join(rows)


def replay_trajectory_of(cs: ConditionedSignals, robot: RobotDescription,
                         knots_per_cycle: float = 10.0) -> PiecewisePolynomial:
    """C² cubic spline through the conditioned q of ``cs`` (knots every ``1/(knots_per_cycle · max cutoff)`` s, at
    least every sample), clipped :data:`LIMIT_MARGIN` inside ``robot``'s joint limits; time as conditioned."""
    from pydrake.trajectories import PiecewisePolynomial

    if cs.q.shape[1] != robot.n:
        raise DiagnosisError(f"replay: the recording has {cs.q.shape[1]} joints, robot '{robot.name}' has {robot.n}")
    spacing = 1.0 / (knots_per_cycle * float(np.max(cs.cutoff_hz)))
    stride = max(1, int(round(spacing * cs.rate_hz)))
    idx = np.arange(0, cs.n_samples, stride)
    if idx[-1] != cs.n_samples - 1:
        idx = np.append(idx, cs.n_samples - 1)
    q = np.clip(cs.q[idx], robot.lower + LIMIT_MARGIN, robot.upper - LIMIT_MARGIN)
    return PiecewisePolynomial.CubicWithContinuousSecondDerivatives(cs.t[idx], q.T, cs.qd[idx[0]][:, None],
                                                                    cs.qd[idx[-1]][:, None])


def deterministic_twin(config: TwinConfig) -> TwinConfig:
    """``config`` without its noise effects, logging every time step with exact stamps and nothing lost."""
    config = config.with_effects([e for e in config.effects if e.name not in NOISE_EFFECTS])
    return config.with_logger(rate_hz=1.0 / config.time_step, stamp_jitter_ms=0.0, dropout_prob=0.0,
                              channels=("q", "tau"), qd_filter_hz=None)


def replay_recording(config: TwinConfig, cs: ConditionedSignals, progress: bool = False) -> Recording:
    """The twin (without noise, :func:`deterministic_twin`) along the conditioned motion of ``cs``; its ``t`` is on
    the clock of ``cs.t``."""
    from proprio.diagrams.twin import simulate_twin

    det = deterministic_twin(config)
    rec = simulate_twin(det, replay_trajectory_of(cs, det.robot), progress=progress)
    return dataclasses.replace(rec, t=rec.t + cs.t[0])


def twin_gap(twin_recs: Sequence[Recording], conditioned: Sequence[ConditionedSignals], trim_s: float | None
             ) -> np.ndarray:
    """Per joint ``RMS(τ_meas − τ_twin)`` [N·m] over the kept samples of all recordings (τ_twin interpolated onto
    the conditioned instants)."""
    sq, count = 0.0, 0
    for rec, cs in zip(twin_recs, conditioned):
        k = kept(cs, trim_s)
        t = cs.t[k]
        tau_twin = np.stack([np.interp(t, rec.t, rec.tau[:, j]) for j in range(rec.tau.shape[1])], axis=1)
        e = cs.tau[k] - tau_twin
        sq = sq + (e ** 2).sum(axis=0)
        count += len(t)
    return np.sqrt(sq / max(count, 1))


def offline_prediction(att: Attribution) -> tuple[np.ndarray, np.ndarray]:
    """``(before, after)`` per joint [N·m]: the held-out RMSE of the model and after the last *physical* step (what
    a patch can reach; data-path steps are not in it)."""
    after = att.rmse_before
    for s in att.steps:
        if not s.processing:
            after = s.rmse_after
    return att.rmse_before, after


def replay_gap(patched: TwinConfig, holdout: Sequence[Recording], base: TwinConfig | None = None,
               att: Attribution | None = None, trim_s: float | None = None,
               conditioning: ConditioningConfig = DIAGNOSIS_CONDITIONING, progress: bool = False,
               conditioned: Sequence[ConditionedSignals] = ()) -> ReplayGap:
    """Replay ``holdout`` through ``patched`` (and ``base``, for the gap before) and measure the gap (module
    docstring); ``att`` adds the diagnosis' offline prediction. Raises :class:`DiagnosisError` on a joint-count
    mismatch or no recordings. ``trim_s`` [s] per end (``None``: each recording's default, :func:`kept`).
    ``conditioned``: the recordings already conditioned by ``conditioning`` (one per recording, or none): a recording
    without a gap in its log is then replayed from them rather than conditioned again."""
    if not holdout:
        raise DiagnosisError("replay: need at least one held-out recording")
    for k, r in enumerate(holdout):
        if r.n_joints != patched.robot.n:
            raise DiagnosisError(f"replay: held-out recording {k} has {r.n_joints} joints, the twin's robot "
                                 f"'{patched.robot.name}' has {patched.robot.n}")
    pieces, offsets, owner, whole = [], [], [], []
    span = MAX_TRIM_S if trim_s is None else trim_s
    for k, r in enumerate(holdout):
        kept_ranges = [(a, b) for a, b in measured_segments(r, conditioning.max_gap_s)
                       if r.t[b - 1] - r.t[a] > 2 * span]
        if not kept_ranges:
            raise DiagnosisError(f"replay: held-out recording {k} has no stretch between the gaps of its log longer "
                                 f"than 2 × trim = {2 * span:g} s; nothing measured to replay")
        for a, b in kept_ranges:
            pieces.append(r.slice(a, b))
            offsets.append(float(r.t[a] - r.t[0]))
            owner.append(k)
            whole.append(conditioned[k] if conditioned and (a, b) == (0, r.n_samples) else None)
    fresh = iter(condition_all([p for p, cs in zip(pieces, whole) if cs is None], conditioning, "holdout"))
    cond = [cs if cs is not None else next(fresh) for cs in whole]
    # each piece at its own session time, so a time-varying effect of the patch acts as when it was recorded
    sessions = [session_time(holdout[k], f"held-out recording {k}") + off for k, off in zip(owner, offsets)]
    after_pieces = [_shifted(replay_recording(patched.with_session_time(t0), cs, progress), off)
                    for cs, t0, off in zip(cond, sessions, offsets)]
    before = None
    if base is not None:
        before = twin_gap([_shifted(replay_recording(base.with_session_time(t0), cs, progress), off)
                           for cs, t0, off in zip(cond, sessions, offsets)], _shifted_signals(cond, offsets), trim_s)
    pb, pa = offline_prediction(att) if att is not None else (None, None)
    after_recs = [_joined([p for p, o in zip(after_pieces, owner) if o == k]) for k in range(len(holdout))]
    return ReplayGap(patched.robot.joint_names, before, twin_gap(after_pieces, _shifted_signals(cond, offsets), trim_s),
                     pb, pa, after_recs)


def _shifted(rec: Recording, offset_s: float) -> Recording:
    """``rec`` with its time moved by ``offset_s`` [s] (a piece back onto its recording's clock)."""
    return dataclasses.replace(rec, t=rec.t + offset_s)


def _shifted_signals(cond: Sequence[ConditionedSignals], offsets: Sequence[float]) -> list[ConditionedSignals]:
    return [dataclasses.replace(cs, t=cs.t + off) for cs, off in zip(cond, offsets)]


def _joined(pieces: Sequence[Recording]) -> Recording:
    """The replayed pieces of one recording as one Recording on its clock, the gaps between them left empty
    (``meta.segments_s``: ``[start, end]`` [s] of each piece)."""
    if len(pieces) == 1:
        rec = pieces[0]
        return dataclasses.replace(rec, meta={**rec.meta, "segments_s": [[float(rec.t[0]), float(rec.t[-1])]]})
    cat = lambda name: None if getattr(pieces[0], name) is None else np.concatenate(  # noqa: E731
        [getattr(p, name) for p in pieces])
    truth = {k: np.concatenate([p.truth[k] for p in pieces]) for k in pieces[0].truth
             if all(k in p.truth for p in pieces)}
    meta = {**pieces[0].meta, "segments_s": [[float(p.t[0]), float(p.t[-1])] for p in pieces]}
    return Recording(t=cat("t"), q=cat("q"), tau=cat("tau"), qd=cat("qd"), qdd=cat("qdd"), f_ext=cat("f_ext"),
                     truth=truth, meta=meta)


def _rms_change(reduction: float) -> str:
    """``RMS −65.2 %`` for a reduction of 0.652, ``RMS +20.0 %`` for a growth."""
    return f"RMS {'−' if reduction >= 0 else '+'}{100 * abs(reduction):.1f} %"


def replay_patched(twin: TwinConfig, patch: Patch, data: Conditioned, att: Attribution) -> ReplayGap:
    """The held-out recordings of ``data`` replayed through the base ``twin`` and through it + ``patch``
    (:func:`replay_gap`)."""
    from proprio.diagrams.twin import TwinConfig, merge_twin_patch

    patched = TwinConfig.from_dict(merge_twin_patch(twin.raw, patch.twin_patch), f"{twin.name} + twin_patch.yaml")
    return replay_gap(patched, data.holdout, base=twin, att=att, trim_s=data.trim_s, conditioning=data.config,
                      conditioned=data.holdout_cs)

