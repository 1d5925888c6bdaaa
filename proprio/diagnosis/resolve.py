"""The loop of issue #25 in one call: design the experiment of every tied set of a diagnosis, write it as a trajectory
file, and — with twin data — run it on the twin and diagnose again with the old recordings plus the new one
(``proprio diagnose ... --design-experiment`` / ``--resolve TWIN`` / ``--experiment REC``).

Which sets get an experiment (:func:`design_experiments`):

* every tied set (:func:`~proprio.diagnosis.ambiguity.tied_sets`) — except one whose members were all named and
  whose held-out torques are uncorrelated (|r| < :data:`UNRELATED_CORRELATION` for every tied alternative): both
  stay in the twin and explain different parts, there is nothing to decide;
* with the training data given, every *confounded pair* of named effects
  (:func:`~proprio.diagnosis.discriminate.confounded_pairs`): both are kept, but their parameters trade off (the
  demo's mixture: hysteresis fitted with the Coulomb level, Coulomb ≈ 0). The experiment then separates their
  torques so that the re-diagnosis, which fits every named effect jointly on the old and the new data, can divide
  the shared torque between them."""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Sequence

from proprio.diagnosis.ambiguity import tied_sets
from proprio.conditioning import ConditioningConfig
from proprio.diagnosis.data import DIAGNOSIS_CONDITIONING, GapData, SimModel, condition_all, kept, session_time
from proprio.diagnosis.discriminate import (Experiment, Resolution, confounded_pairs, design_experiment, pair_set,
                                            split_passes)
from proprio.diagnosis.selection import Attribution
from proprio.io import atomic_write_text
from proprio.recording import Recording

if TYPE_CHECKING:
    from proprio.diagrams.twin import TwinConfig

__all__ = ["DesignedExperiment", "design_experiments", "training_data", "with_experiments", "run_on_twin",
           "write_resolution", "UNRELATED_CORRELATION"]

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


def write_resolution(path: str | Path, designed: Sequence[DesignedExperiment],
                     resolutions: Sequence[Resolution]) -> dict[str, Any]:
    """``resolution.json``: the experiments (family, score, file, per-member scores) and the resolutions."""
    doc = {"experiments": [{"members": d.members, "file": None if d.path is None else str(d.path),
                            **({} if d.experiment is None else {**d.experiment.meta(), "decides": d.experiment.decides,
                                                                 "family_scores": d.experiment.scores}),
                            "text": d.text()} for d in designed],
           "resolutions": [r.to_dict() for r in resolutions]}
    atomic_write_text(Path(path), json.dumps(doc, indent=1))
    return doc
