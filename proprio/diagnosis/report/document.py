"""The report of a diagnosis, the last step of :func:`proprio.diagnosis.route.diagnose`: ``report.md`` /
``report.html``, the figures and ``diagnosis.json`` (all files written atomically).

**The report reads in a minute.** It opens with a summary — one sentence of verdict
(:func:`~proprio.diagnosis.report.verdict.verdict_sentence`) and a table, one row per named effect or finding
(:func:`~proprio.diagnosis.report.verdict.summary_rows`) — then the two figures (gap map, held-out residual before /
after), then the details, each section present only when it says something (:class:`Section`). The Markdown is the
source; ``report.html`` is that Markdown rendered by the ``markdown`` library into the Jinja2 template
``templates/report.html.j2`` (package data): tables escape their cells' pipes, so they render.

**A run that found something never ends in an error.** Every step after the attribution (the twin patch, the replay
through the twin, the figures, the truth comparison, the report files) — and the localisation before it — runs as a
stage (:class:`Stages`) whose failure is one line of ``Diagnosis.failures``, in the report's summary and, through the
CLI, on stderr, while everything else is written.
"""
from __future__ import annotations

import json
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Sequence

import numpy as np

from proprio.data_quality import assess, findings_markdown
from proprio.diagnosis.attribution import Attribution
from proprio.diagnosis.candidates.drive import tau_kind
from proprio.diagnosis.data import Conditioned, SimModel
from proprio.diagnosis.localisation import GapMap, Localisation, Spectra
from proprio.diagnosis.patch import Patch, PatchEntry
from proprio.diagnosis.replay import ReplayGap
from proprio.diagnosis.report.truth import TruthComparison, compare_to_truth, truth_summary
from proprio.diagnosis.report.verdict import (SummaryRow, Verdict, data_and_processing_text, effects_text, hint_texts,
                                              remains_text, summary_rows, where_text)
from proprio.diagnosis.selection.ambiguity import ambiguity_markdown
from proprio.io import atomic_write_text
from proprio.plots.gap import plot_before_after, plot_gap_map, plot_spectra
from proprio.recording import Recording
from proprio.timeseries_html import timeseries_html

if TYPE_CHECKING:
    from proprio.diagrams.twin import TwinConfig

__all__ = ["Stages", "Report", "write_report", "Section", "md_table", "render_html", "PARAM_UNITS"]


class Stages:
    """The steps of a diagnosis that may fail without losing its answer (module docstring): :meth:`run` calls a step
    and, when it raises, keeps one line in :attr:`failures` and returns ``None``."""

    def __init__(self) -> None:
        self.failures: list[str] = []

    def run(self, what: str, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        """``fn(*args, **kwargs)``, or ``None`` with one line in :attr:`failures` when it raises."""
        try:
            return fn(*args, **kwargs)
        except Exception as exc:                  # noqa: BLE001 — the run keeps its answer (module docstring)
            where = traceback.extract_tb(exc.__traceback__)[-1]
            line = " ".join(f"{type(exc).__name__}: {exc}".split())
            self.failures.append(f"{what} failed, not written: {line[:300]} ({Path(where.filename).name}:"
                                 f"{where.lineno})")
            return None


@dataclass
class Section:
    """One details section of the report: ``title``, ``body`` (Markdown) and, for the HTML only, ``extra_html``
    (an interactive plot) after it."""
    title: str
    body: str
    extra_html: str = ""


PARAM_UNITS = {"viscous": "N·m·s/rad", "coulomb": "N·m", "static": "N·m", "stribeck_velocity": "rad/s",
               "saturation": "N·m", "load_gain": "1", "saturation_travel": "rad", "amplitude": "N·m", "window": "rad",
               "sin_amplitude": "N·m", "cos_amplitude": "N·m", "gain": "1", "offset": "N·m", "std": "N·m",
               "stiffness": "N·m/rad", "damping": "N·m·s/rad", "drift": "N·m", "time_constant": "s",
               "level": "N·m", "presliding_travel": "rad", "I_a": "kg·m²", "F_v,m": "N·m·s/rad", "F_c,m": "N·m",
               "share": "1", "compliance": "rad/(N·m)", "lag": "s", "m": "kg", "mass": "kg"}
"""Units of the fitted parameters by name (the part before ``[joint]``), SI; a rigid-body or payload parameter's
unit follows from its name (:func:`_unit`)."""


def _unit(name: str) -> str:
    key = name.split("[")[0]
    if key in PARAM_UNITS:
        return PARAM_UNITS[key]
    head = key.split("_")[0]
    if head in ("m", "mass"):
        return "kg"
    if head in ("mx", "my", "mz", "mc", "hx", "hy", "hz") or key.startswith("m·c"):
        return "kg·m"
    if head.startswith("I") or head.startswith("XX") or head.startswith("L"):
        return "kg·m²"
    return ""


def md_table(header: Sequence[str], rows: Sequence[Sequence[Any]], caption: str = "") -> str:
    r"""A Markdown table whose cells' pipes are escaped (``\|``: the ``markdown`` library's tables keep them in the
    cell); ``caption`` (which data the table covers) is a line above it."""
    esc = lambda x: str(x).replace("|", "\\|").replace("\n", " ")  # noqa: E731
    lines = ["| " + " | ".join(esc(h) for h in header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(esc(c) for c in r) + " |" for r in rows]
    return (f"{caption}\n\n" if caption else "") + "\n".join(lines)


def _plot_before_after(att: Attribution, path: Path) -> Path:
    e = att.holdout_e[0]
    rmse = np.array([att.rmse_before] + [s.rmse_after for s in att.steps])
    return plot_before_after(path, att.holdout_t[0], e, e - att.holdout_pred[0], att.joint_names,
                             [s.name for s in att.steps], rmse)


def _residual_html(att: Attribution) -> str:
    """The held-out residual before / after the added effects (the data of before_after.png) as a zoomable plot."""
    e = att.holdout_e[0]
    return timeseries_html(att.holdout_t[0], {"before": e, "after all added effects": e - att.holdout_pred[0]},
                           att.joint_names, title="Held-out residual τ_meas − τ_sim (first held-out recording)",
                           y_label="e [N·m]", element_id="residual")


def _fmt(x: float) -> str:
    return f"{x:.4g}"


def _held_out_words(att: Attribution) -> str:
    return (f"held-out data ({att.data_seconds[1]:.1f} s"
            + (", alternate time blocks of the one recording" if att.cv is not None else "") + ")")


def _ranking_table(att: Attribution) -> str:
    rows = [[r["name"] + (" (data path)" if r.get("processing") else ""), f"{100 * r['gain']:.2f}", f"{r['t']:.1f}",
             r["n_params"], "yes" if r["significant"] else "no"] for r in att.ranking]
    return md_table(["candidate", "held-out gain alone [%]", "t (blocks)", "parameters", "significant"], rows,
                    f"Each candidate alone against the model, step 1; {_held_out_words(att)}.")


def _shrink_table(att: Attribution) -> str:
    fmt = lambda rm: [f"{x:.3f} ({100 * x / max(s, 1e-12):.1f} %)" for x, s in zip(rm, att.signal_rms)]  # noqa: E731
    rows = [["model", *fmt(att.rmse_before)]]
    for st in att.steps:
        tie = f" (tied: {', '.join(st.tied)})" if st.tied else ""
        kind = " [data path]" if st.processing else ""
        rows.append([f"+ {st.name}{tie}{kind}", *fmt(st.rmse_after)])
    return md_table(["step", *att.joint_names], rows,
                    f"RMSE [N·m] (% of the signal RMS) per joint on the {_held_out_words(att)}, after each step.")


def _param_table(att: Attribution) -> str:
    """The final joint fit's parameters, one row per effect and parameter, one column per joint: value ± σ (σ = the
    95 % CI / 1.96) and the unit; "" when nothing was fitted."""
    if not att.steps or not att.steps[-1].params:
        return ""
    names_j = att.joint_names
    n = len(names_j)
    rows, other = [], []
    for name, (theta, ci, names) in att.steps[-1].params.items():
        theta, ci = np.asarray(theta, dtype=float), np.asarray(ci, dtype=float)
        if len(theta) > 3 * n:
            other.append(f"{name}: {len(theta)} identifiable combinations, ‖δ‖ = {_fmt(np.linalg.norm(theta))} "
                         f"(SI, mixed units; median σ {_fmt(float(np.median(ci)) / 1.96)}) — the corrected "
                         "inertials are in the patch's robot description.")
            continue
        per: dict[str, list[str]] = {}
        for v, c, nm in zip(theta, ci, names):
            key, _, joint = nm.partition("[")
            if joint.endswith("]") and joint[:-1].isdigit():
                per.setdefault(key, [""] * n)[int(joint[:-1]) - 1] = f"{_fmt(v)} ± {_fmt(c / 1.96)}"
            else:
                other.append(f"{name}: {nm} = {_fmt(v)} ± {_fmt(c / 1.96)} {_unit(nm)}".rstrip())
        rows += [[name, key, _unit(key) or "—", *[x or "—" for x in vals]] for key, vals in per.items()]
    out = ("The final joint fit on the training data: value ± σ (σ from the fit Jacobian, autocorrelation-corrected; "
           "95 % CI = ±1.96 σ).")
    if rows:
        out += "\n\n" + md_table(["effect", "parameter", "unit", *names_j], rows)
    return out + "".join(f"\n\n{line}" for line in other)


def _hints_section(att: Attribution, texts: list[str]) -> str:
    """The hints beyond the library (:mod:`~proprio.diagnosis.hints`): a table and their plain-language lines."""
    head = ("A sparse regression of the remaining residual of each structured (or shifted) joint on the measured and "
            "modelled signals (every joint's modelled τ, q, q̇, q̈, smooth sign(q̇), harmonics of q, time and a few "
            "products), fitted on the training data and kept only with a significant held-out gain — a hint about "
            "what the unexplained part follows, not a library effect.")
    rows = [[att.joint_names[h.joint], ", ".join(h.terms),
             ", ".join(f"{_fmt(c)} {u}".strip() for c, u in zip(h.coefficients, h.units or [""] * len(h.terms))),
             f"{h.rms:.3g}", f"{100 * h.gain:.1f}", f"{h.t_stat:.1f}"] for h in att.hints]
    tab = md_table(["joint", "terms (most important first)", "coefficients", "residual fitted [N·m RMS]",
                    "held-out gain [%]", "t (blocks)"], rows)
    return "\n\n".join([head, tab] + texts)


def _time_table(att: Attribution) -> str:
    """The time-dependence test (:mod:`~proprio.diagnosis.selection.time_variation`) when it found something:
    its sentence and the joints that vary; "" otherwise."""
    tv = att.time_variation
    if tv is None or not tv.detected:
        return ""
    rows = [[nm, f"{tv.p_value[j]:.2g}", tv.joint_kinds[j], f"{tv.change[j]:.3g}", f"{100 * tv.share[j]:.1f}"]
            for j, nm in enumerate(att.joint_names) if tv.joints[j]]
    return (tv.text[0].upper() + tv.text[1:] + ".\n\n"
            + md_table(["joint", "p-value", "what varies", "change [N·m]", "share of the static model's residual [%]"],
                       rows, "Over the session clock of all the recordings."))


MIN_ORDER_SHARE = 0.1
"""An order of the joint angle is shown in the report's frequency table from this share of the residual's variance
(a display choice: the ripple candidate, not this table, decides whether an order is an effect)."""


def _spectra_section(sp: Spectra, names: Sequence[str], seconds: float) -> str:
    rows = []
    for j, nm in enumerate(names):          # the joints where the spectra say something
        if not np.isfinite(sp.dominant_hz[j]) and sp.peak_order_share[j] < MIN_ORDER_SHARE:
            continue
        peak = "no peak" if not np.isfinite(sp.dominant_hz[j]) else f"{sp.dominant_hz[j]:.2f}"
        rows.append([nm, peak, f"{sp.peak_order[j]:.2f}", f"{100 * sp.peak_order_share[j]:.1f} %"])
    head = (f"The residual of the model as given over all {seconds:.1f} s of data (training and held-out). Welch "
            f"spectrum with a resolution of {sp.resolution_hz:.2g} Hz: a peak is a local maximum above its "
            "neighbourhood beyond the estimate's χ² spread, never in the two lowest bins (there the slow motion "
            "leaks); the order spectrum is against each joint's own angle.")
    if not np.isfinite(sp.dominant_hz).any():
        head += (f" No joint's spectrum has a peak: the residual's power lies at the motion's own low frequencies "
                 f"(below {2 * sp.resolution_hz:.2g} Hz) and falls from there.")
    if not rows:
        return "![spectra](spectra.png)\n\n" + head + (f" No joint's residual has an angle-locked order with "
                                                     f"{100 * MIN_ORDER_SHARE:.0f} % of its variance or more.")
    return "![spectra](spectra.png)\n\n" + head + "\n\n" + md_table(
        ["joint", "spectral peak [Hz]", "strongest order [cycles/rev]", "variance share of that order"], rows,
        f"Joints with a spectral peak or an order holding ≥ {100 * MIN_ORDER_SHARE:.0f} % of the variance.")


def _residual_table(att: Attribution) -> str:
    rs = att.residual
    rows = []
    for j, nm in enumerate(att.joint_names):
        v = "white" if rs.white_joints[j] else ("structured" if rs.structured_time[j] or rs.structured_state[j]
                                                 else "structured, within the conditioning error")
        r2 = f"{rs.r2_state[j]:.3f}" if rs.r2_state[j] >= 0 else "< 0 (not predictable)"
        rows.append([nm, f"{rs.rmse[j]:.3f}", f"{rs.ljung_box_p[j]:.3g}", r2, v])
    return md_table(["joint", "RMSE [N·m]", "Ljung–Box p", "held-out R² vs motion state", "verdict"], rows,
                    f"After every named effect, on the {_held_out_words(att)}.")


def render_html(title: str, verdict: str, summary: str, failures: Sequence[str], figures: Sequence[tuple[str, str]],
                sections: Sequence[Section]) -> str:
    """``report.html``: the Markdown of the summary table and of each section rendered by the ``markdown`` library
    (tables extension) into the Jinja2 template ``templates/report.html.j2``; ``figures`` are ``(file, caption)``."""
    import jinja2
    import markdown
    from markupsafe import Markup

    md = lambda text: markdown.markdown(text, extensions=["tables"])  # noqa: E731
    env = jinja2.Environment(loader=jinja2.PackageLoader("proprio.diagnosis.report", "templates"),
                             autoescape=jinja2.select_autoescape(["html", "j2"]))
    return env.get_template("report.html.j2").render(
        title=title, verdict=verdict, summary_html=Markup(md(summary)), failures=list(failures),
        figures=list(figures),
        sections=[{"title": sec.title, "html": Markup(md(sec.body) + sec.extra_html)}
                  for sec in sections])


@dataclass(frozen=True)
class Report:
    """What the report step wrote: ``files`` maps a role (``report_md``, ``gap_map_png``, ``twin_patch``, ...) to a
    path; ``truth``: twin data only, the twin's effects against what was named."""
    files: dict[str, Path]
    truth: TruthComparison | None


def write_report(out: Path, model: SimModel, data: Conditioned, where: Localisation | None, att: Attribution,
                 verdict: Verdict, patch: Patch | None, replay: ReplayGap | None, twin: TwinConfig | None,
                 stages: Stages) -> Report:
    """Write ``report.md``, ``report.html``, ``gap_map.png``, ``spectra.png``, ``before_after.png`` and
    ``diagnosis.json`` to ``out`` (atomically): the ``verdict`` and its summary table, the gap map (``where``), the
    ranked effects and their shrinkage (``att``), the twin ``patch``, the replay through the ``twin`` (if any), the data
    quality of every recording of ``data`` and, on twin data, the comparison with the twin's truth. Each part runs as
    a stage of ``stages`` (module docstring)."""
    kind = tau_kind(model.robot)
    gm = where.gap_map if where is not None else None
    sp = where.spectra if where is not None else None
    seconds = data.train_s + data.holdout_s
    entries: list[PatchEntry] = patch.entries if patch is not None else []
    patch_files: dict[str, Path] = patch.files if patch is not None else {}
    unmerged = patch.unmerged if patch is not None else []
    holdout_recs = data.holdout
    failures, advice = stages.failures, verdict.advice
    files: dict[str, Path] = {}
    for role, fn in (("gap_map_png", lambda: plot_gap_map(out / "gap_map.png", gm.share, gm.columns,
                                                          gm.joint_names) if gm is not None else None),
                     ("spectra_png", lambda: plot_spectra(out / "spectra.png", sp.freq, sp.psd, sp.orders,
                                                          sp.order_power, gm.joint_names) if sp is not None else None),
                     ("before_after_png", lambda: _plot_before_after(att, out / "before_after.png"))):
        path = stages.run(f"figure {role[:-4]}.png", fn)
        if path is not None:
            files[role] = path
    truth = stages.run("comparison with the twin's truth", compare_to_truth, att, model, holdout_recs)
    quality = stages.run("data quality", lambda: [
        (f"{role} {i + 1}", assess(r, model.robot, conditioning=data.config, conditioned=cs))
        for role, recs, conds in (("train", data.train, data.train_cs), ("held-out", data.holdout, data.holdout_cs))
        for i, (r, cs) in enumerate(zip(recs, conds))]) or []
    sections = _sections(att, model, kind, gm, sp, seconds, entries, unmerged, patch_files, quality, truth,
                         replay, twin, advice, holdout_recs, len(data.train))
    title = f"Sim-to-real gap diagnosis — {model.robot.name}"
    summary_md = md_table(SummaryRow.HEADER, [r.cells() for r in summary_rows(att, kind)])
    figures = [(f, cap) for role, f, cap in (
        ("gap_map_png", "gap_map.png", "Where the gap lies: share of the total squared residual of the model as "
                                       "given by joint and motion regime, over all the data (training and "
                                       "held-out)."),
        ("before_after_png", "before_after.png", "How far it shrinks: the residual on the first held-out recording "
                                                 "before and after the named effects, and the held-out RMSE per "
                                                 "step.")) if role in files]

    def write_files() -> None:
        md = (f"# {title}\n\n## Summary\n\n{verdict.sentence}\n\n{summary_md}\n\n"
              + "".join(f"**Not written:** {f}\n\n" for f in failures)
              + "".join(f"![{cap}]({f})\n\n" for f, cap in figures)
              + "\n\n".join(f"## {sec.title}\n\n{sec.body}" for sec in sections) + "\n")
        atomic_write_text(out / "report.md", md)
        atomic_write_text(out / "report.html",
                          render_html(title, verdict.sentence, summary_md, failures, figures, sections))
        files.update(report_md=out / "report.md", report_html=out / "report.html")

    summary = {"robot": model.robot.name, "model_effects": sorted(model.effect_names),
               "rmse_before": att.rmse_before.tolist(), "signal_rms": att.signal_rms.tolist(),
               "steps": [{"name": s.name, "tied": s.tied, "gain": s.gain, "t": s.t_stat,
                          "rmse_after": s.rmse_after.tolist(), "processing": s.processing,
                          "params": {k: {"names": nm, "value": th.tolist(), "ci95": ci.tolist()}
                                     for k, (th, ci, nm) in s.params.items()}} for s in att.steps],
               "ranking": att.ranking, "noise": [{"name": f.name, "rms": f.rms.tolist()} for f in att.noise],
               "ambiguity": [a.to_dict() for a in att.ambiguity],
               "processing": att.processing_findings,
               "encoder_floor": att.encoder.to_dict() if att.encoder is not None else None,
               "residual_white": att.residual.white, "white_joints": att.residual.white_joints.tolist(),
               "processing_sigma": att.processing_sigma.tolist(),
               "superseded": [{"name": x.name, "step": x.step, "gain": x.gain, "context": x.context}
                              for x in att.superseded],
               "missing_term": att.missing_term.to_dict() if att.missing_term is not None else None,
               "data_path": [{"name": s.name, "gain": s.gain, "t": s.t_stat, "rmse_after": s.rmse_after.tolist()}
                             for s in att.data_path],
               "rmse_raw": att.rmse_raw.tolist() if att.rmse_raw is not None else None,
               "position_only": [{"name": x.name, "gain": x.gain, "beyond": x.beyond, "t": x.t_stat,
                                  "configuration": x.configuration}
                                 for x in att.position_only],
               "undecided": None if att.undecided is None else {
                   "name": att.undecided.name, "gain": att.undecided.gain, "t": att.undecided.t_stat,
                   "t_crit": att.undecided.t_crit, "more_holdout_s": att.undecided.more_s},
               "hints": [h.to_dict() for h in att.hints], "verdict": verdict.sentence,
               "explanation": verdict.explanation, "advice": advice,
               "time_variation": None if att.time_variation is None else {
                   "detected": att.time_variation.detected, "joints": att.time_variation.joints.tolist(),
                   "p_value": att.time_variation.p_value.tolist(), "kind": att.time_variation.kind,
                   "change": att.time_variation.change.tolist(), "text": att.time_variation.text},
               "data_quality": [{"name": n, **q.to_dict()} for n, q in quality],
               "truth": truth_summary(truth) if truth is not None else None,
               "patch_unmerged": unmerged}
    if replay is not None:
        summary["twin_replay"] = {"twin": twin.name, "rms_before": replay.rms_before.tolist(),
                                  "rms_after": replay.rms_after.tolist(), "reduction": replay.reduction,
                                  "predicted_reduction": replay.predicted_reduction}
    stages.run("report", write_files)
    summary["failures"] = failures
    atomic_write_text(out / "diagnosis.json", json.dumps(summary, indent=1))
    files.update(json=out / "diagnosis.json", **patch_files)
    return Report(files, truth)



def _sections(att: Attribution, model: SimModel, kind: str, gm: GapMap | None, sp: Spectra | None, seconds: float,
              entries: list[PatchEntry], unmerged: Sequence[str], patch_files: dict[str, Path], quality: list,
              truth: Any,
              replay: ReplayGap | None, twin: Any, advice: list[str], holdout_recs: Sequence[Recording],
              n_train: int) -> list[Section]:
    """The details sections, each only when it says something (module docstring)."""
    out: list[Section] = []
    if advice:
        out.append(Section("Advice", "\n\n".join(advice)))
    where = where_text(att, gm)
    if gm is not None:
        where += "\n\n" + gm.table(min_share=0.002) + (
            f"\n\nShares [%] of the total squared residual of the model as given, over all {seconds:.1f} s of data "
            "(training and held-out); the RMSE column covers the same data (the summary's gap is the held-out data "
            "only).")
    out.append(Section("Where the gap lies", where))
    out.append(Section("Which effect", effects_text(att, kind) + "\n\n" + _ranking_table(att)))
    if att.steps:
        out.append(Section("How far it shrinks", _shrink_table(att), _residual_html(att)
                           + '<p><a href="before_after.png">static figure</a></p>'))
        out.append(Section("Which effects could take each other's place", ambiguity_markdown(att.ambiguity)))
    par = _param_table(att)
    if par:
        out.append(Section("Fitted parameters", par))
    out.append(Section("What remains unexplained", remains_text(att, kind) + "\n\n" + _residual_table(att)))
    if att.hints:
        out.append(Section("Hints beyond the library", _hints_section(att, hint_texts(att, kind,
                                                                                      sorted(model.effect_names)))))
    tv = _time_table(att)
    if tv:
        out.append(Section("When the data were taken: the gap changes over time", tv))
    if sp is not None and gm is not None:
        out.append(Section("Frequency content", _spectra_section(sp, gm.joint_names, seconds)))
    desc = (f"Model: {model.robot.name}"
            + (f" + {', '.join(sorted(model.effect_names))}" if model.effect_names else " (rigid body only)")
            + f". Training recordings: {n_train}, held-out: "
            + (f"{len(holdout_recs)}" if holdout_recs else "none (cross-validated over time blocks)") + ". "
            f"Candidates tested: {', '.join(att.candidates)}.")
    tv_line = ("" if att.time_variation is None or att.time_variation.detected else
               f"\n\nTime dependence: none found (the smallest Bonferroni-corrected p over the joints: "
               f"{float(np.min(att.time_variation.p_value)):.2g}).")
    out.append(Section("Data and processing", desc + "\n\n" + data_and_processing_text(att, kind) + tv_line))
    if quality:
        out.append(Section("Data quality of each recording (before any fitting)", findings_markdown(quality)))
    if patch_files:
        out.append(Section("The twin patch", _patch_text(entries, patch_files,
                                                         unmerged)))
    if truth is not None:
        out.append(Section("Against the twin's truth (scoring only: the diagnosis never reads it)",
                           truth.markdown(att.joint_names)))
    if replay is not None:
        out.append(Section("The gap through the twin",
                           f"The held-out recordings replayed through the base twin {twin.name} and the patched twin "
                           f"(no twin noise), RMS(τ_meas − τ_twin) per joint [N·m]: {replay.text()}.\n\n"
                           + replay.table()))
    return out


def _patch_text(entries: list, files: dict[str, Path], unmerged: Sequence[str] = ()) -> str:
    """The patch section: what went into ``twin_patch.yaml``, what did not and what could not be merged."""
    used = [e.name for e in entries if e.fragment is not None]
    left = [e.name for e in entries if e.fragment is None]
    out = (f"`{files['twin_patch'].name}` adds {', '.join(used)} to a base twin of this robot "
           "(`proprio simulate --twin BASE --patch twin_patch.yaml`)" if used else
           f"`{files['twin_patch'].name}` is empty: nothing physical was found")
    if "patch_robot" in files:
        out += f"; the corrected robot description is `{files['patch_robot'].name}`"
    out += "." + (f" Not in the patch: {', '.join(left)} (see the comments in the file)." if left else "")
    if unmerged:
        out += ("\n\nNot merged — two effects change the same value of the robot differently (the first one's is "
                "kept):\n\n" + "\n".join(f"- {line}" for line in unmerged))
    return out

