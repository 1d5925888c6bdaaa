"""The diagnosis as one route (:func:`diagnose`): condition once → localise → attribute → verdict → patch → replay →
report, each step called once and in that order, each handing the next a named, typed value."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Sequence

from proprio.conditioning import ConditioningConfig
from proprio.description import RobotDescription
from proprio.diagnosis.attribution import Attribution
from proprio.diagnosis.candidates.drive import tau_kind
from proprio.diagnosis.data import DIAGNOSIS_CONDITIONING, DiagnosisError, SimModel, condition_recordings
from proprio.diagnosis.localisation import GapMap, Spectra, localise
from proprio.diagnosis.patch import make_patch
from proprio.diagnosis.replay import ReplayGap, replay_patched
from proprio.diagnosis.report.document import write_report
from proprio.diagnosis.report.truth import TruthComparison
from proprio.diagnosis.report.verdict import verdict_text
from proprio.diagnosis.selection.forward import attribute_conditioned
from proprio.recording import Recording

if TYPE_CHECKING:
    from proprio.diagrams.twin import TwinConfig

__all__ = ["Diagnosis", "diagnose"]


@dataclass
class Diagnosis:
    """Everything :func:`diagnose` found; ``files`` maps a role (``report_md``, ``gap_map_png``, ...) to a path."""
    gap_map: GapMap
    spectra: Spectra
    attribution: Attribution
    verdict: str
    files: dict[str, Path] = field(default_factory=dict)
    truth: TruthComparison | None = None      # twin data only: the twin's effects against what was named
    replay: ReplayGap | None = None           # the held-out gap through the twin (``diagnose(twin=...)``)


def diagnose(model: SimModel | RobotDescription, train_recs: Sequence[Recording],
             holdout_recs: Sequence[Recording], out_dir: str | Path, candidates: Sequence[str] | None = None,
             trim_s: float | None = None, progress: Callable[[str], None] | None = None,
             conditioning: ConditioningConfig = DIAGNOSIS_CONDITIONING, twin: TwinConfig | None = None,
             plugins: Sequence[str | type] = ()) -> Diagnosis:
    """Diagnose the torque gap of ``model`` on measured recordings and write the report to ``out_dir``.

    ``model``: a :class:`RobotDescription` (rigid body + its friction, if any) or a :class:`SimModel` (+ the effects
    the simulation already has); ``train_recs`` fit the candidate effects, ``holdout_recs`` score them (empty: the
    training recordings are cross-validated over time blocks, see
    :func:`~proprio.diagnosis.selection.forward.attribute`); ``candidates`` restricts the candidate set; ``plugins``
    adds user-defined effects (``"package.module:Class"``, :mod:`proprio.effects.plugins`) to it; ``trim_s`` [s] is
    dropped at both ends of every recording; ``conditioning`` the signal conditioning (:mod:`proprio.conditioning`).
    Writes ``report.md``, ``report.html``, ``gap_map.png``, ``spectra.png``, ``before_after.png``,
    ``diagnosis.json`` and ``twin_patch.yaml`` (:mod:`~proprio.diagnosis.patch`). ``twin``: a base twin config of
    the model's robot; the held-out recordings are then replayed through it and through it + the patch
    (:mod:`~proprio.diagnosis.replay`) and the report gives the gap through the twin next to the offline
    prediction. Raises :class:`DiagnosisError` (a ``ValueError``) on bad input."""
    model = SimModel.of(model)
    out = Path(out_dir)
    say = progress or (lambda msg: None)
    if twin is not None and not holdout_recs:
        raise DiagnosisError("twin: the replay through the twin needs held-out recordings (--holdout)")
    data = condition_recordings(model, train_recs, holdout_recs, conditioning, trim_s, say)
    where = localise(model, data)
    att = attribute_conditioned(model, data, candidates, progress=say, plugins=plugins)
    verdict = verdict_text(att, where.gap_map, tau_kind(model.robot))
    patch = make_patch(att, model, out / "twin_patch.yaml")
    replay = None
    if twin is not None:
        say("replaying the held-out recordings through the twin")
        replay = replay_patched(twin, patch, data, att)
    report = write_report(out, model, data, where, att, verdict, patch, replay, twin)
    return Diagnosis(where.gap_map, where.spectra, att, verdict, report.files, report.truth, replay)
