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
from proprio.diagnosis.report.document import Stages, write_report
from proprio.diagnosis.report.truth import TruthComparison
from proprio.diagnosis.report.verdict import make_verdict
from proprio.diagnosis.selection.forward import attribute_conditioned
from proprio.recording import Recording

if TYPE_CHECKING:
    from proprio.diagrams.twin import TwinConfig

__all__ = ["Diagnosis", "diagnose"]


@dataclass
class Diagnosis:
    """Everything :func:`diagnose` found; ``files`` maps a role (``report_md``, ``gap_map_png``, ...) to a path.
    ``verdict``: the one-sentence verdict the report opens with; ``explanation``: the plain-language details
    (:func:`~proprio.diagnosis.report.verdict.verdict_text`); ``failures``: one line per step that failed (its
    output missing, everything else written: :class:`~proprio.diagnosis.report.document.Stages`); ``advice``: what
    the person could do next. ``gap_map`` / ``spectra`` are ``None`` when the localisation failed."""
    gap_map: GapMap | None
    spectra: Spectra | None
    attribution: Attribution
    verdict: str
    files: dict[str, Path] = field(default_factory=dict)
    truth: TruthComparison | None = None      # twin data only: the twin's effects against what was named
    replay: ReplayGap | None = None           # the held-out gap through the twin (``diagnose(twin=...)``)
    explanation: str = ""
    failures: list[str] = field(default_factory=list)
    advice: list[str] = field(default_factory=list)


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
    prediction. Raises :class:`DiagnosisError` (a ``ValueError``) on bad input, before the attribution; a step that
    fails after it is a line of ``Diagnosis.failures`` (:class:`~proprio.diagnosis.report.document.Stages`)."""
    model = SimModel.of(model)
    out = Path(out_dir)
    say = progress or (lambda msg: None)
    if twin is not None and not holdout_recs:
        raise DiagnosisError("twin: the replay through the twin needs held-out recordings (--holdout)")
    data = condition_recordings(model, train_recs, holdout_recs, conditioning, trim_s, say)
    stages = Stages()                # every step but the conditioning and the attribution may fail without a loss
    where = stages.run("gap map and spectra", localise, model, data)
    att = attribute_conditioned(model, data, candidates, progress=say, plugins=plugins)
    verdict = make_verdict(att, where.gap_map if where is not None else None, tau_kind(model.robot),
                           sorted(model.effect_names))
    patch = stages.run("twin patch", make_patch, att, model, out / "twin_patch.yaml")
    replay = None
    if twin is not None and patch is not None:
        say("replaying the held-out recordings through the twin")
        replay = stages.run("replay through the twin", replay_patched, twin, patch, data, att)
    report = write_report(out, model, data, where, att, verdict, patch, replay, twin, stages)
    return Diagnosis(where.gap_map if where is not None else None, where.spectra if where is not None else None, att,
                     verdict.sentence, report.files, report.truth, replay, verdict.explanation, stages.failures,
                     verdict.advice)
