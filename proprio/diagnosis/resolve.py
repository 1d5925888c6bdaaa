"""The loop of issue #25 in one call: design the experiment of every tied set of a diagnosis, write it as a trajectory
file, and — with twin data — run it on the twin and diagnose again with the old recordings plus the new one
(``proprio diagnose ... --design-experiment`` / ``--resolve TWIN`` / ``--experiment REC``).

Which sets get an experiment (:func:`design_experiments`):

* every tied set (:func:`~proprio.diagnosis.selection.ambiguity.tied_sets`) — except one whose members were all named
  and whose held-out torques are uncorrelated (|r| < :data:`UNRELATED_CORRELATION` for every tied alternative): both
  stay in the twin and explain different parts, there is nothing to decide;
* with the training data given, every *confounded pair* of named effects
  (:func:`~proprio.diagnosis.discriminate.confounded_pairs`): both are kept, but their parameters trade off (the
  demo's mixture: hysteresis fitted with the Coulomb level, Coulomb ≈ 0). The experiment then separates their
  torques so that the re-diagnosis, which fits every named effect jointly on the old and the new data, can divide
  the shared torque between them.

After the experiment the named effects are fitted once more on the old and the new training data together by the
joint re-fit (:func:`refit_jointly`, :func:`~proprio.diagnosis.discriminate.joint_refit`): every joint's parameters of
the joint-by-joint effects in one problem, where the selection's back-fitting stops on the ridge between effects that
share a torque (the demo's Coulomb level taken by the hysteresis and the lost motion). Its parameters are printed per
confounded or tied effect next to the selection's and written to ``resolution.json`` (``refit``)."""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Sequence

import numpy as np

from proprio.diagnosis.selection.ambiguity import tied_sets
from proprio.conditioning import ConditioningConfig
from proprio.diagnosis.data import DIAGNOSIS_CONDITIONING, GapData, SimModel, condition_all, kept, session_time
from proprio.diagnosis.discriminate import (Experiment, Resolution, confounded_pairs, design_experiment, joint_refit,
                                            pair_set, split_passes)
from proprio.diagnosis.fitting import Fit
from proprio.diagnosis.attribution import Attribution
from proprio.io import atomic_write_text
from proprio.recording import Recording

if TYPE_CHECKING:
    from proprio.diagrams.twin import TwinConfig

__all__ = ["DesignedExperiment", "design_experiments", "training_data", "with_experiments", "run_on_twin",
           "write_resolution", "refit_jointly", "JointRefit", "UNRELATED_CORRELATION"]

UNRELATED_CORRELATION = 0.5   # |r| of the held-out torques below which two named tied effects explain different parts


@dataclass
class DesignedExperiment:
    """A tied set's experiment (``None``: no family member fits the limits without a collision) and its file."""
    members: list[str]
    experiment: Experiment | None
    path: Path | None = None
    recording: Recording | None = field(default=None, repr=False)

    def text(self) -> str:
        if self.experiment is None:
            return f"{' vs '.join(self.members)}: no motion of the family fits the limits without a collision."
        where = f" → {self.path}" if self.path is not None else ""
        return self.experiment.text() + where


def training_data(model: SimModel, train: Sequence[Recording],
                  conditioning: ConditioningConfig = DIAGNOSIS_CONDITIONING, trim_s: float = 0.5) -> GapData:
    """The training recordings prepared as the diagnosis prepares them (the same conditioning, trimming and
    session clock, :meth:`GapData.build`), for refitting the members of a confounded pair."""
    cond = condition_all(train, conditioning, "training")
    return GapData.build(model, cond, [kept(cs, trim_s) for cs in cond], "training",
                         session_s=[session_time(r, f"training recording {k}") for k, r in enumerate(train)])


def _unrelated(aset) -> bool:
    """A tied set of named effects whose held-out torques do not correlate (module docstring)."""
    return all(abs(a.correlation) < UNRELATED_CORRELATION for a in aset.alternatives if a.tied)


def design_experiments(model: SimModel, att: Attribution, out_dir: str | Path | None = None,
                       progress: Callable[[str], None] | None = None,
                       train: GapData | None = None) -> list[DesignedExperiment]:
    """The experiment of every tied set of ``att`` and, with ``train`` (the diagnosis' training data,
    :func:`training_data`), of every confounded pair of named effects (module docstring;
    :func:`~proprio.diagnosis.discriminate.design_experiment`), written to ``out_dir/experiment_<A>_vs_<B>.npz``
    when it decides or serves a confounded pair (``out_dir`` given)."""
    say = progress or (lambda m: None)
    named = {a.effect for a in att.ambiguity}
    sets = [(a, False) for a in tied_sets(att.ambiguity) if not (set(a.members) <= named and _unrelated(a))]
    if train is not None:
        for aset, other in confounded_pairs(att.ambiguity):
            say(f"refitting {aset.effect} and {other} each alone in their place")
            sets.append((pair_set(aset, other, train), True))
    out = []
    for aset, mixed in sets:
        say(f"designing the experiment for {' vs '.join(aset.members)}")
        exp = design_experiment(model, aset, mixed=mixed)
        path = None
        if exp is not None and exp.worth_running and out_dir is not None:
            path = exp.save(Path(out_dir) / f"experiment_{'_vs_'.join(aset.members)}.npz")
        out.append(DesignedExperiment(list(aset.members), exp, path))
    return out


def with_experiments(train: Sequence[Recording], hold: Sequence[Recording], experiments: Sequence[Recording],
                     splits: Sequence[float | None] = ()) -> tuple[list[Recording], list[Recording]]:
    """The old recordings plus the experiments': the first pass of each (cut at ``splits[k]``, default the middle)
    joins the training recordings, the second the held-out ones (the training ones when there are none)."""
    train, hold = list(train), list(hold)
    for k, rec in enumerate(experiments):
        a, b = split_passes(rec, splits[k] if k < len(splits) else None)
        train.append(a)
        (hold if hold else train).append(b)
    return train, hold


def run_on_twin(twin: "TwinConfig", designed: Sequence[DesignedExperiment],
                progress: Callable[[str], None] | None = None) -> list[Recording]:
    """Run every deciding (or confounded-pair) experiment on ``twin`` (:func:`proprio.diagrams.twin.simulate_twin`);
    returns the recordings in order (each also kept on its :class:`DesignedExperiment`)."""
    from proprio.diagrams.twin import simulate_twin

    recs = []
    for d in designed:
        if d.experiment is None or not d.experiment.worth_running:
            continue
        (progress or (lambda m: None))(f"running the experiment for {' vs '.join(d.members)} on the twin")
        d.recording = simulate_twin(twin, d.experiment.trajectory, progress=False)
        recs.append(d.recording)
    return recs


@dataclass
class JointRefit:
    """The named effects re-fitted jointly (:func:`refit_jointly`): ``fit`` the joint re-fit, ``before`` the
    selection's parameters by name, ``effects`` the confounded or tied named effects whose parameters are reported,
    ``names`` every reported effect's parameter names (``"coulomb[1]"`` …), ``truth``: the same parameters of the
    effects that made twin data (scoring only; ``None`` for a robot's data)."""
    fit: Fit
    before: dict[str, np.ndarray]
    effects: list[str]
    names: dict[str, list[str]]
    truth: dict[str, np.ndarray] | None = None

    def rows(self) -> list[tuple[str, str, float, float, float | None]]:
        """``(effect, parameter, before, after, truth)`` of every torque-amplitude parameter of :attr:`effects`
        (the levels that trade off between them), per joint."""
        out = []
        for eff in self.effects:
            for k, p in enumerate(self.names[eff]):
                if p.split("[")[0] not in LEVEL_KEYS:
                    continue
                true = None if self.truth is None or eff not in self.truth or not np.isfinite(self.truth[eff][k]) \
                    else float(self.truth[eff][k])
                out.append((eff, p, float(self.before[eff][k]), float(self.fit.thetas[eff][k]), true))
        return out

    def text(self) -> str:
        """Per effect, the levels [N·m] after the joint re-fit (the selection's in brackets; the twin's when known)."""
        parts = []
        for eff in self.effects:
            rows = [r for r in self.rows() if r[0] == eff]
            vals = ", ".join(f"{p} {a:.3g} ({b:.3g}" + (f"; twin {t:.3g}, {100 * (a / t - 1):+.0f} %)"
                                                       if t is not None and abs(t) > 0 else ")")
                             for _, p, b, a, t in rows)
            parts.append(f"{eff}: {vals}")
        return ("joint re-fit of the named effects on all the training data (each joint's parameters of the "
                "joint-by-joint effects in one problem; the selection's fit in brackets) — " + "; ".join(parts))

    def to_dict(self) -> dict[str, Any]:
        return {"effects": self.effects, "text": self.text(),
                "levels": [{"effect": e, "parameter": p, "before": b, "after": a, "truth": t}
                           for e, p, b, a, t in self.rows()]}


LEVEL_KEYS = ("coulomb", "saturation", "amplitude", "level", "static", "offset")
"""Parameters reported by :meth:`JointRefit.rows`: the levels that confounded effects trade between them."""


def refit_jointly(att: Attribution, train: GapData, truth: Sequence[Any] = ()) -> JointRefit | None:
    """The named effects of ``att`` re-fitted on ``train`` (the diagnosis' training data, :func:`training_data`, old
    recordings plus the experiments' first passes) by the joint re-fit
    (:func:`~proprio.diagnosis.discriminate.joint_refit`; without the selection's time-trend nuisance), started from
    each named effect's parameters as the selection fitted it; the reported effects are the named members of its
    confounded pairs and tied sets. ``truth``: the twin's effects
    (:class:`~proprio.effects.JointEffect`) when the data came from a twin, for scoring. ``None`` when nothing is
    named or no named effect is confounded or tied."""
    if not att.ambiguity:
        return None
    first = att.ambiguity[0]
    named = [a.effect for a in att.ambiguity]
    reported = sorted({m for a, other in confounded_pairs(att.ambiguity) for m in (a.effect, other)}
                      | {m for a in tied_sets(att.ambiguity) for m in a.members if m in named})
    if not reported:
        return None
    by_name = {k: c for a in att.ambiguity for k, c in a.candidates.items()}
    cands = [by_name[k] for k in named]
    init = {k: v for a in att.ambiguity for f in a.fits.values() for k, v in f.thetas.items() if k in named}
    before = {**init, **{a.effect: a.fits[a.effect].thetas[a.effect] for a in att.ambiguity if a.effect in a.fits}}
    fit = joint_refit(cands, train, first.weights, before)                 # each as the selection fitted it
    names = {k: by_name[k].param_names() for k in reported}
    params = {e.name: e.params() for e in truth}
    true = {k: np.array([_value(params[c.effect], x) for x in names[k]]) for k in reported
            for c in [by_name[k]] if getattr(c, "effect", None) in params}
    return JointRefit(fit, before, reported, names, true or None)


def _value(params: dict[str, np.ndarray], name: str) -> float:
    """The value of parameter ``name`` (``"coulomb[1]"``: key and 1-based joint) in an effect's ``params``; NaN when
    the effect has no such key."""
    key, joint = name[:-1].split("[")
    return float(params[key][int(joint) - 1]) if key in params else math.nan


def write_resolution(path: str | Path, designed: Sequence[DesignedExperiment],
                     resolutions: Sequence[Resolution], refit: JointRefit | None = None) -> dict[str, Any]:
    """``resolution.json``: the experiments (family, score, file, per-member scores), the resolutions and the joint
    re-fit of the named effects after the experiments (``refit``, :func:`refit_jointly`; null without one)."""
    doc = {"experiments": [{"members": d.members, "file": None if d.path is None else str(d.path),
                            **({} if d.experiment is None else {**d.experiment.meta(), "decides": d.experiment.decides,
                                                                 "family_scores": d.experiment.scores}),
                            "text": d.text()} for d in designed],
           "resolutions": [r.to_dict() for r in resolutions],
           "refit": None if refit is None else refit.to_dict()}
    atomic_write_text(Path(path), json.dumps(doc, indent=1))
    return doc
