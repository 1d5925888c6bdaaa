"""The gap diagnosis as one call and one report: :func:`diagnose` localises the residual
(:mod:`~proprio.diagnosis.localisation`), attributes it (:mod:`~proprio.diagnosis.selection.forward`)
and writes ``report.md`` / ``report.html`` with the gap map, the ranked effects, per-joint before/after plots and a
plain-language verdict (all files written atomically).
"""
from __future__ import annotations

import html
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Sequence

import numpy as np

from proprio.data_quality import assess, findings_markdown
from proprio.description import RobotDescription
from proprio.conditioning import ConditioningConfig
from proprio.diagnosis.selection.ambiguity import ambiguity_markdown
from proprio.diagnosis.data import (DIAGNOSIS_CONDITIONING, DiagnosisError, SimModel, kept, session_motion, session_time,
                                    signals_of)
from proprio.diagnosis.localisation import (
    GapMap,
    Spectra,
    gap_map,
    regime_families,
    spectra,
)
from proprio.diagnosis.patch import patch_entries, twin_patch, write_twin_patch
from proprio.diagnosis.replay import ReplayGap, replay_gap
from proprio.diagnosis.attribution import Attribution
from proprio.diagnosis.selection.forward import attribute
from proprio.diagnosis.report.truth import TruthComparison, compare_to_truth, truth_summary
from proprio.diagnosis.candidates.drive import tau_kind
from proprio.diagnosis.report.verdict import data_and_processing_text, verdict_text
from proprio.io import atomic_write_text
from proprio.plots.gap import plot_before_after, plot_gap_map, plot_spectra
from proprio.recording import Recording
from proprio.timeseries_html import timeseries_html

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


def _localise(model: SimModel, recs: Sequence[Recording], trim_s: float | None,
              conditioning: ConditioningConfig) -> tuple[GapMap, Spectra]:
    es, fams, taus, qs, qds = [], [], [], [], []
    rob = model.robot
    for raw in recs:
        cs = signals_of(raw, conditioning)
        rec, s = cs.as_recording(), session_motion(cs, session_time(raw))
        keep = kept(cs, trim_s)
        e = (rec.tau - model.predict(s))[keep]
        fam = regime_families(s.q, s.qd, rob.lower, rob.upper, rob.velocity_limits, rec)
        fams.append([type(f)(f.name, f.names, f.labels[keep]) for f in fam])
        es.append(e)
        taus.append(rec.tau[keep])
        qs.append(s.q[keep])
        qds.append(s.qd[keep])
    rate = float(np.median([r.rate_hz for r in recs]))
    return gap_map(es, fams, taus, rob.joint_names), spectra(es, qs, qds, rate)


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


def _tables(att: Attribution) -> tuple[str, str, str]:
    rank = ["| candidate | held-out gain alone [%] | t (blocks) | parameters | significant |", "|---|---|---|---|---|"]
    for r in att.ranking:
        kind = " (data path)" if r.get("processing") else ""
        rank.append(f"| {r['name']}{kind} | {100 * r['gain']:.2f} | {r['t']:.1f} | {r['n_params']} | "
                    f"{'yes' if r['significant'] else 'no'} |")
    n = len(att.joint_names)
    shr = ["| step | " + " | ".join(att.joint_names) + " |", "|---" * (n + 1) + "|"]
    fmt_row = lambda rm: " | ".join(f"{x:.3f} ({100 * x / max(s, 1e-12):.1f} %)"  # noqa: E731
                                    for x, s in zip(rm, att.signal_rms))
    shr.append(f"| model | {fmt_row(att.rmse_before)} |")
    for st in att.steps:
        tie = f" (tied: {', '.join(st.tied)})" if st.tied else ""
        kind = " [data path]" if st.processing else ""
        shr.append(f"| + {st.name}{tie}{kind} | {fmt_row(st.rmse_after)} |")
    par = ["| effect | parameter | value | 95 % CI ± |", "|---|---|---|---|"]
    if att.steps:
        for name, (theta, ci, names) in att.steps[-1].params.items():
            if len(theta) > 3 * n:
                par.append(f"| {name} | {len(theta)} identifiable combinations | ‖δ‖ = {_fmt(np.linalg.norm(theta))}"
                           f" | median CI {_fmt(float(np.median(ci)))} |")
                continue
            for v, c, nm in zip(theta, ci, names):
                par.append(f"| {name} | {nm} | {_fmt(v)} | {_fmt(c)} |")
    return "\n".join(rank), "\n".join(shr), "\n".join(par)


def _hints_section(att: Attribution) -> str:
    """The hints beyond the library (:mod:`~proprio.diagnosis.hints`): a table and their plain-language lines."""
    head = ("Hints, not library effects: a sparse regression of the remaining residual of each structured (or, on the held-out data, "
            "shifted) joint on "
            "the measured and modelled signals (every joint's modelled τ, q, q̇, q̈, smooth sign(q̇), harmonics of q, "
            "time and a few products), fitted on the training data and kept only with a significant held-out gain.")
    if not att.hints:
        return head + ("\n\nNo hint: the remaining residual is white and centred on every joint, or no few terms "
                       "explain a significant share (≥ 5 %, block t-test) of it on the held-out data.")
    tab = ["| joint | terms (most important first) | signals | coefficients | held-out gain [%] | t (blocks) |",
           "|---|---|---|---|---|---|"]
    for h in att.hints:
        tab.append(f"| {att.joint_names[h.joint]} | {', '.join(h.terms)} | {', '.join(h.signals)} | "
                   f"{', '.join(_fmt(c) for c in h.coefficients)} | {100 * h.gain:.1f} | {h.t_stat:.1f} |")
    return "\n\n".join([head, "\n".join(tab)] + [h.text for h in att.hints])


def _time_table(att: Attribution) -> str:
    """The time-dependence test (:mod:`~proprio.diagnosis.selection.time_variation`): its sentence and a per-joint table."""
    tv = att.time_variation
    if tv is None:
        return "Not tested."
    rows = ["| joint | p-value | what varies | change [N·m] | share of the static model's residual [%] |",
            "|---|---|---|---|---|"]
    for j, nm in enumerate(att.joint_names):
        what = tv.joint_kinds[j] if tv.joints[j] else "—"
        rows.append(f"| {nm} | {tv.p_value[j]:.2g} | {what} | {tv.change[j]:.3g} | {100 * tv.share[j]:.1f} |")
    return tv.text[0].upper() + tv.text[1:] + ".\n\n" + "\n".join(rows)


def _md_to_html_table(md: str) -> str:
    rows = [r.strip().strip("|").split("|") for r in md.splitlines() if not r.startswith("|---")]
    out = ["<table>"]
    for k, cells in enumerate(rows):
        tag = "th" if k == 0 else "td"
        out.append("<tr>" + "".join(f"<{tag}>{html.escape(c.strip())}</{tag}>" for c in cells) + "</tr>")
    return "\n".join(out + ["</table>"])


def diagnose(model: SimModel | RobotDescription, train_recs: Sequence[Recording],
             holdout_recs: Sequence[Recording], out_dir: str | Path, candidates: Sequence[str] | None = None,
             trim_s: float | None = None, progress: Callable[[str], None] | None = None,
             conditioning: ConditioningConfig = DIAGNOSIS_CONDITIONING, twin: TwinConfig | None = None,
             plugins: Sequence[str | type] = ()) -> Diagnosis:
    """Diagnose the torque gap of ``model`` on measured recordings and write the report to ``out_dir``.

    ``model``: a :class:`RobotDescription` (rigid body + its friction, if any) or a :class:`SimModel` (+ the effects
    the simulation already has); ``train_recs`` fit the candidate effects, ``holdout_recs`` score them (empty: the
    training recordings are cross-validated over time blocks, see :func:`~proprio.diagnosis.selection.forward.attribute`);
    ``candidates`` restricts the candidate set; ``plugins`` adds user-defined effects (``"package.module:Class"``,
    :mod:`proprio.effects.plugins`) to it; ``trim_s`` [s] is dropped at both ends of every recording;
    ``conditioning`` the signal conditioning (:mod:`proprio.conditioning`).
    Writes ``report.md``, ``report.html``, ``gap_map.png``, ``spectra.png``, ``before_after.png``,
    ``diagnosis.json`` and ``twin_patch.yaml`` (:mod:`~proprio.diagnosis.patch`). ``twin``: a base twin config of
    the model's robot; the held-out recordings are then replayed through it and through it + the patch
    (:mod:`~proprio.diagnosis.replay`) and the report gives the gap through the twin next to the offline
    prediction. Raises :class:`DiagnosisError` (a ``ValueError``) on bad input."""
    from proprio.diagrams.twin import TwinConfig, merge_twin_patch

    model = SimModel.of(model)
    out = Path(out_dir)
    if twin is not None and not holdout_recs:
        raise DiagnosisError("twin: the replay through the twin needs held-out recordings (--holdout)")
    att = attribute(model, train_recs, holdout_recs, candidates=candidates, trim_s=trim_s, progress=progress,
                    conditioning=conditioning, plugins=plugins)
    entries = patch_entries(att)
    patch_files = write_twin_patch(att, model, out / "twin_patch.yaml", entries)
    replay = None
    if twin is not None:
        (progress or (lambda msg: None))("replaying the held-out recordings through the twin")
        patched = TwinConfig.from_dict(merge_twin_patch(twin.raw, twin_patch(att, model, entries)),
                                       f"{twin.name} + twin_patch.yaml")
        replay = replay_gap(patched, holdout_recs, base=twin, att=att, trim_s=trim_s, conditioning=conditioning)
    gm, sp = _localise(model, list(train_recs) + list(holdout_recs), trim_s, conditioning)
    verdict = verdict_text(att, gm, tau_kind(model.robot))
    files = {"gap_map_png": plot_gap_map(out / "gap_map.png", gm.share, gm.columns, gm.joint_names),
             "spectra_png": plot_spectra(out / "spectra.png", sp.freq, sp.psd, sp.orders, sp.order_power,
                                         gm.joint_names),
             "before_after_png": _plot_before_after(att, out / "before_after.png")}
    rank, shr, par = _tables(att)
    rs = att.residual
    resid = ["| joint | RMSE [N·m] | Ljung–Box p | held-out R² vs state | verdict |", "|---|---|---|---|---|"]
    for j, nm in enumerate(att.joint_names):
        v = "white" if rs.white_joints[j] else ("structured" if rs.structured_time[j] or rs.structured_state[j]
                                                 else "structured, within the conditioning error")
        resid.append(f"| {nm} | {rs.rmse[j]:.3f} | {rs.ljung_box_p[j]:.3g} | {rs.r2_state[j]:.3f} | {v} |")
    freq = ["| joint | dominant frequency [Hz] | strongest order [cycles/rev] | variance share of that order |",
            "|---|---|---|---|"]
    for j, nm in enumerate(gm.joint_names):
        freq.append(f"| {nm} | {sp.dominant_hz[j]:.2f} | {sp.peak_order[j]:.2f} | {100 * sp.peak_order_share[j]:.1f} % |")
    quality = [(f"{role} {i + 1}", assess(r, model.robot, conditioning=conditioning)) for role, recs in (("train", train_recs),
               ("held-out", holdout_recs)) for i, r in enumerate(recs)]
    sections = [
        ("Data quality of each recording (before any fitting)", findings_markdown(quality)),
        ("Verdict", verdict),
        ("Data and processing", data_and_processing_text(att, tau_kind(model.robot))),
        ("When the data were taken: time dependence of the gap", _time_table(att)),
        ("Where the gap lies: gap map (share of the total squared residual, %)",
         "![gap map](gap_map.png)\n\n" + gm.table(min_share=0.002)),
        ("Frequency content", "![spectra](spectra.png)\n\n" + "\n".join(freq)),
        ("Which effect: candidates ranked by held-out gain (each alone, step 1)", rank),
        ("How far it shrinks: held-out RMSE per joint [N·m] (% of signal RMS) after each added effect",
         shr + "\n\n![before/after](before_after.png)"),
        ("Which effects could take each other's place (ambiguity)", ambiguity_markdown(att.ambiguity)),
        ("Fitted parameters (final joint fit, 95 % CI from the fit Jacobian, autocorrelation-corrected)", par),
        ("What remains unexplained", "\n".join(resid)),
        ("The twin patch", _patch_text(entries, patch_files)),
        ("Hints beyond the library (not library effects)", _hints_section(att)),
    ]
    truth = compare_to_truth(att, model, holdout_recs)
    if truth is not None:
        sections.append(("Against the twin's truth (scoring only: the diagnosis never reads it)",
                         truth.markdown(att.joint_names)))
    if replay is not None:
        sections.append(("The gap through the twin: held-out recordings replayed through the base twin and the "
                         "patched twin (no twin noise), RMS(τ_meas − τ_twin) per joint [N·m]",
                         f"Twin `{twin.name}`: {replay.text()}.\n\n{replay.table()}"))
    title = f"Sim-to-real gap diagnosis — {model.robot.name}"
    sim_desc = (f"Model: `{model.robot.name}`"
                + (f" + {', '.join(sorted(model.effect_names))}" if model.effect_names else " (rigid body only)")
                + f". Training recordings: {len(train_recs)}, held-out: "
                + (f"{len(holdout_recs)}" if holdout_recs else "none (cross-validated over time blocks)") + ". "
                f"Candidates tested: {', '.join(att.candidates)}.")
    md = f"# {title}\n\n{sim_desc}\n\n" + "\n\n".join(f"## {h}\n\n{b}" for h, b in sections) + "\n"
    body = []
    for h, b in sections:
        chunks = []
        for para in b.split("\n\n"):
            if para.startswith("|"):
                chunks.append(_md_to_html_table(para))
            elif para.startswith("![before/after]"):     # interactive in the HTML report, the PNG beside it
                chunks.append(_residual_html(att) + '<p><a href="before_after.png">static figure</a></p>')
            elif para.startswith("!["):
                src = para[para.index("(") + 1:para.index(")")]
                chunks.append(f'<img src="{html.escape(src)}" style="max-width:100%">')
            else:
                chunks.append(f"<p>{html.escape(para)}</p>")
        body.append(f"<h2>{html.escape(h)}</h2>\n" + "\n".join(chunks))
    page = ("<!doctype html><html><head><meta charset='utf-8'><title>" + html.escape(title) + "</title><style>"
            "body{font-family:sans-serif;max-width:1100px;margin:auto}table{border-collapse:collapse;font-size:12px}"
            "td,th{border:1px solid #bbb;padding:2px 6px;text-align:right}</style></head><body>"
            f"<h1>{html.escape(title)}</h1><p>{html.escape(sim_desc)}</p>" + "\n".join(body) + "</body></html>")
    atomic_write_text(out / "report.md", md)
    atomic_write_text(out / "report.html", page)
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
               "residual_white": rs.white, "white_joints": rs.white_joints.tolist(),
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
                   "t_crit": att.undecided.t_crit, "more_holdout_s": att.undecided.more_s}, "hints": [h.to_dict() for h in att.hints], "verdict": verdict,
               "time_variation": None if att.time_variation is None else {
                   "detected": att.time_variation.detected, "joints": att.time_variation.joints.tolist(),
                   "p_value": att.time_variation.p_value.tolist(), "kind": att.time_variation.kind,
                   "change": att.time_variation.change.tolist(), "text": att.time_variation.text},
               "data_quality": [{"name": n, **q.to_dict()} for n, q in quality],
               "truth": truth_summary(truth) if truth is not None else None}
    if replay is not None:
        summary["twin_replay"] = {"twin": twin.name, "rms_before": replay.rms_before.tolist(),
                                  "rms_after": replay.rms_after.tolist(), "reduction": replay.reduction,
                                  "predicted_reduction": replay.predicted_reduction}
    atomic_write_text(out / "diagnosis.json", json.dumps(summary, indent=1))
    files.update(report_md=out / "report.md", report_html=out / "report.html", json=out / "diagnosis.json",
                 **patch_files)
    return Diagnosis(gm, sp, att, verdict, files, truth, replay)


def _patch_text(entries: list, files: dict[str, Path]) -> str:
    """The patch section: what went into ``twin_patch.yaml`` and what did not."""
    used = [e.name for e in entries if e.fragment is not None]
    left = [e.name for e in entries if e.fragment is None]
    out = (f"`{files['twin_patch'].name}` adds {', '.join(used)} to a base twin of this robot "
           "(`proprio simulate --twin BASE --patch twin_patch.yaml`)" if used else
           f"`{files['twin_patch'].name}` is empty: nothing physical was found")
    if "patch_robot" in files:
        out += f"; the corrected robot description is `{files['patch_robot'].name}`"
    out += "." + (f" Not in the patch: {', '.join(left)} (see the comments in the file)." if left else "")
    return out


__all__ += ["DiagnosisError"]
