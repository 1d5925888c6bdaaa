"""What the gap diagnosis returns (:func:`proprio.diagnosis.selection.forward.attribute`): the accepted steps, the
verdict's parts (undecided leader, stand-ins dropped, cross-validation, noise, residual structure, hints, time
dependence, encoder floor, ambiguity sets) in one :class:`Attribution`."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from proprio.diagnosis.candidates.base import Candidate
from proprio.diagnosis.encoder_floor import EncoderFloor
from proprio.diagnosis.hints import Hint
from proprio.diagnosis.model_terms import MissingTerm
from proprio.diagnosis.residual import NoiseFinding, ResidualStructure

__all__ = ["Step", "Undecided", "CrossValidation", "Superseded", "TimeVariation", "PositionOnly", "Attribution"]


@dataclass
class Step:
    """One accepted step: ``name`` (``tied`` lists the candidates that explain the same held-out variance),
    relative held-out gain, t statistic over blocks, per-joint held-out RMSE after the step [N·m], fitted
    parameters with 95 % CI half-widths. ``processing``: the step describes the data path (a processing candidate,
    or an effect whose held-out torque stays within the processing error), ``reason`` says which."""
    name: str
    tied: list[str]
    gain: float
    t_stat: float
    rmse_after: np.ndarray
    params: dict[str, tuple[np.ndarray, np.ndarray, list[str]]]
    processing: bool = False
    reason: str = ""


@dataclass
class Undecided:
    """The selection stopped while a physical candidate still lowered the held-out error by ``gain`` (≥ the minimum
    gain) with a t statistic ``t_stat`` below the significance bound ``t_crit`` over ``n_blocks`` blocks of
    ``block_s`` [s]: too little held-out data to decide. ``more_s`` [s]: the held-out seconds to add for the same
    effect to reach the bound (``t`` grows as √blocks)."""
    name: str
    gain: float
    t_stat: float
    t_crit: float
    n_blocks: int
    block_s: float

    @property
    def more_s(self) -> float:
        need = self.n_blocks * (self.t_crit / max(self.t_stat, 1e-9)) ** 2
        return float(max(need - self.n_blocks, 1.0) * self.block_s)


@dataclass
class CrossValidation:
    """How a single recording (no held-out one given) was cross-validated: alternate time blocks of ``block_s`` [s]
    train and score (2 folds, roles swapped); ``fold_top`` the physical effects each fold named, ``agreement`` the
    share of named effects both folds name (1.0 when both name nothing)."""
    block_s: float
    n_blocks: int
    fold_top: list[list[str]]
    agreement: float


@dataclass
class Superseded:
    """A physical effect the forward selection named at step ``step`` (1-based) that, in the context of the effects
    named with it (``context``), adds a held-out gain of only ``gain`` (< the minimum gain): a stand-in for them,
    dropped by the backward check (:mod:`proprio.diagnosis.selection.forward`, "Stand-ins")."""
    name: str
    step: int
    gain: float
    context: list[str]


@dataclass
class TimeVariation:
    """Result of the time-dependence test (:mod:`proprio.diagnosis.selection.time_variation`). ``joints [n] bool``:
    joints whose residual depends on the time the data were taken; ``p_value [n]``: per joint (Bonferroni over the two
    series, not over joints); ``kind``: what varies ("offset drift", "offset step between recordings", "friction
    change", joined by " + "; empty when nothing is detected); ``text``: one sentence for the report. ``change [n]``
    N·m: the range of the fitted time dependence over the data (the offset, or the Coulomb-like friction level);
    ``share [n]``: the fraction of the state-cleared residual variance it explains; ``span_s``: the session time the
    data cover [s]."""
    detected: bool
    joints: np.ndarray
    p_value: np.ndarray
    kind: str
    text: str
    change: np.ndarray = field(default_factory=lambda: np.zeros(0))
    share: np.ndarray = field(default_factory=lambda: np.zeros(0))
    span_s: float = 0.0
    joint_kinds: list[str] = field(default_factory=list)


@dataclass
class PositionOnly:
    """A candidate a configuration torque can pose as (hysteresis, lost motion, pre-sliding friction, a torque-sensor
    gain error: :data:`~proprio.diagnosis.candidates.configuration.POSITION_MIMICS`) that won a step with held-out gain
    ``gain`` while a configuration-only torque explains ``configuration`` (≥ ``gain``) and the candidate adds only
    ``beyond`` (t = ``t_stat``) to it: the residual depends on where the arm is, not on the motion's history (nor on
    the torque it carries) — set aside, not named (:mod:`proprio.diagnosis.candidates.configuration`)."""
    name: str
    gain: float
    beyond: float
    t_stat: float
    configuration: float

    def text(self, plain: dict[str, str]) -> str:
        """One sentence for the report."""
        head, not_on = (("Position, not torque", "the torque it carries") if self.name == "sensor_gain"
                        else ("Position, not history", "the reversals"))
        return (f"{head}: {plain.get(self.name, self.name)} would lower the held-out error by "
                f"{100 * self.gain:.0f} %, but a torque that depends on the configuration alone (the joint's own "
                f"angle) lowers it by {100 * self.configuration:.0f} % and beyond that torque it adds "
                f"{100 * self.beyond:.1f} % (t = {self.t_stat:.2g}) — the residual "
                f"depends on where the arm is, not on {not_on}: not named (see the hints on q).")


@dataclass
class Attribution:
    """Result of :func:`proprio.diagnosis.selection.forward.attribute`. ``fitted``: the selected candidates by name (their
    final parameters are the last step's ``params``), for :func:`proprio.diagnosis.patch.twin_patch`. ``encoder``:
    the data's position-noise floor against the model's encoder noise (:mod:`proprio.diagnosis.encoder_floor`; a
    data-path comparison over all the recordings). ``undecided``: the physical candidate still leading, without
    significance, where the selection stopped (:class:`Undecided`); ``below_floor``: ``(name, gain, rms)`` of
    physical candidates that won a step with a held-out torque (``rms`` N·m) within the processing error — not
    named, not filed as data path; ``superseded``: the stand-ins the backward check dropped (:class:`Superseded`);
    ``position_only``: reversal candidates set aside because a configuration-only torque explains what they did
    (:class:`PositionOnly`); ``missing_term``: the log seems to lack a term of the model (:class:`MissingTerm`:
    gravity, or the whole rigid-body torque — a drive that compensates it); ``data_path``: data-path steps the
    selection took before any physical one — the correction of the data, never step 1: ``rmse_before`` is then the
    held-out gap after them and ``rmse_raw`` [n] N·m the gap before them (``None`` when no data-path step came
    first)."""
    joint_names: list[str]
    steps: list[Step]
    ranking: list[dict[str, Any]]
    rmse_before: np.ndarray
    signal_rms: np.ndarray
    residual: ResidualStructure
    noise: list[NoiseFinding]
    candidates: list[str]
    holdout_e: list[np.ndarray]
    holdout_pred: list[np.ndarray]
    holdout_t: list[np.ndarray]
    processing_sigma: np.ndarray
    conditioning: list[str]
    data_seconds: tuple[float, float]
    block_s: float
    cv: "CrossValidation | None" = None
    fitted: dict[str, Candidate] = field(default_factory=dict)
    hints: list[Hint] = field(default_factory=list)
    time_variation: TimeVariation | None = None
    encoder: EncoderFloor | None = None
    undecided: Undecided | None = None
    below_floor: list[tuple[str, float, float]] = field(default_factory=list)
    ambiguity: list[Any] = field(default_factory=list)   # AmbiguitySet per named effect (diagnosis.ambiguity)
    superseded: list[Superseded] = field(default_factory=list)
    position_only: list[PositionOnly] = field(default_factory=list)
    data_path: list[Step] = field(default_factory=list)
    rmse_raw: np.ndarray | None = None
    missing_term: MissingTerm | None = None

    @property
    def physical_steps(self) -> list[Step]:
        return [s for s in self.steps if not s.processing]

    @property
    def processing_steps(self) -> list[Step]:
        """The data-path corrections (:attr:`data_path`) and the later processing steps."""
        return self.data_path + [s for s in self.steps if s.processing]

    def data_path_text(self) -> str:
        """One sentence for the verdict when a data-path correction came first (else ``""``): the gap before is
        reported after it."""
        if self.rmse_raw is None:
            return ""
        raw = float(np.sqrt((self.rmse_raw ** 2).mean()))
        now = float(np.sqrt((self.rmse_before ** 2).mean()))
        names = ", ".join(s.name for s in self.data_path)
        return (f"The gap is measured after the data-path correction ({names}, listed under the data path): "
                f"before it the held-out gap was {raw:.3g} N·m RMS, so the conditioning of the data — not the robot "
                f"— made {100 * (1 - (now / max(raw, 1e-300)) ** 2):.0f} % of that squared error.")

    @property
    def processing_findings(self) -> list[str]:
        """Names of every data-path finding, the report's "data and processing" section (never a cause): the
        processing steps in selection order, then ``encoder_noise`` when the data's position-noise floor is above
        the model's encoder noise (:mod:`proprio.diagnosis.encoder_floor`)."""
        out = [s.name for s in self.processing_steps]
        if self.encoder is not None and self.encoder.reported and self.encoder.name not in out:
            out.append(self.encoder.name)
        return out

    @property
    def selected(self) -> list[str]:
        """The physical effects and noise findings named (never a data-path step)."""
        return [s.name for s in self.physical_steps] + [f.name for f in self.noise]

    def top(self, k: int) -> list[str]:
        """The first ``k`` distinct physical names in attribution order, tied alternatives included after each
        step (data-path steps are reported apart, :attr:`processing_steps`)."""
        out: list[str] = []
        for s in self.physical_steps:
            for nm in [s.name] + s.tied:
                if nm not in out:
                    out.append(nm)
        for f in self.noise:
            if f.name not in out:
                out.append(f.name)
        return out[:k]
