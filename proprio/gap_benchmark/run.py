"""The withheld-effect benchmark of the gap diagnosis (DESIGN.md "Gap diagnosis", step 5).

Each *case* generates data of a robot with some effect(s) present, and a simulation model without the withheld
one(s); :func:`proprio.diagnosis.selection.forward.attribute` is run without being told what was withheld.
Cases: every effect of the twin's library (``proprio/effects/``) plus rigid-body parameter error, payload
and signal lag, at several magnitudes and seeds; null cases (effects present in the data are also in the model);
two-effect cases. Scores: confusion matrix, top-1 / top-2 accuracy, null false-positive rate, and the error of the
predicted shrinkage (the diagnosis' own held-out SSE reduction after its first step) against the measured one
(the held-out SSE reduction when the model is given the true withheld effect, i.e. only the sensor noise remains).

The cases: :mod:`proprio.gap_benchmark.cases`; how their data are made:
:mod:`proprio.gap_benchmark.case_data`. Here: running a case
(:func:`run_case`), running many on the engine of :mod:`proprio.tasks` (local processes or Ray, resumable), and
scoring them (:func:`summarise`, :func:`write_results`). Out-of-library cases (a plugin effect no library candidate
expresses) are scored apart: flagged as structured-unexplained with no library effect above 5 % held-out gain, and
whether a hint (``Attribution.hints``) names the expected signal; time-varying cases by whether the diagnosis
detects the time dependence (``Attribution.time_variation``). Per case it also reports the held-out RMS after the
last step (``final_rms``) and the floor (``floor_rms``: the same model on held-out data made without the withheld
effects).
"""
from __future__ import annotations

import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from proprio.gap_benchmark.case_data import generate_case_data
from proprio.gap_benchmark.cases import (PROCESSING_TYPES, BenchmarkCase, expected_name, is_drive_case,
                                         is_open_world, is_time_varying)
from proprio.effects import EFFECTS
from proprio.io import atomic_write_text

__all__ = ["CaseResult", "run_case", "run_benchmark", "summarise", "write_results", "case_result_to_dict",
           "case_result_from_dict", "LEVEL_FINDINGS"]

LEVEL_FINDINGS = ("encoder_noise",)      # data-path findings by noise level, not by a held-out torque prediction

OPEN_LIBRARY_GAIN = 0.05      # an out-of-library case may name library effects up to this held-out gain


@dataclass
class CaseResult:
    case: BenchmarkCase
    top: list[str]
    steps: list[str]
    predicted_shrinkage: float
    measured_shrinkage: float
    seconds: float
    error: str = ""
    params: dict[str, Any] = field(default_factory=dict)
    processing: list[str] = field(default_factory=list)
    final_rms: float = float("nan")           # N·m: held-out residual RMS after the diagnosis' last step
    floor_rms: float = float("nan")           # N·m: the same model on held-out data made without the withheld effects
    structured: bool | None = None            # the remaining held-out residual is not white (None: old result file)
    physical_gains: dict[str, float] = field(default_factory=dict)   # held-out gain of every physical step named
    hints: list[list[Any]] | None = None      # [joint (0-based), signals, gain] per hint; None: no hints computed
    time_dependent: bool | None = None        # the time-variation test's verdict; None: an older result file


def run_case(case: BenchmarkCase) -> CaseResult:
    """Generate, diagnose (not told what was withheld) and score one case."""
    from proprio.diagnosis.data import (DIAGNOSIS_CONDITIONING, SimModel, condition_all, kept, session_motion,
                                        session_time)
    from proprio.diagnosis.selection.forward import attribute

    t0 = time.perf_counter()
    try:
        data = generate_case_data(case)
    except ValueError as exc:                  # e.g. a twin whose friction is too stiff for its time step
        return CaseResult(case, [], [], float("nan"), float("nan"), time.perf_counter() - t0,
                          error=f"data: {exc}")
    n = data.robot.n
    model = SimModel(data.robot, tuple(EFFECTS[k](n, **data.model_params[k]) for k in data.model_effects))
    try:
        att = attribute(model, data.train, data.holdout)
    except ValueError as exc:
        return CaseResult(case, [], [], float("nan"), float("nan"), time.perf_counter() - t0, error=str(exc))
    e_h = np.concatenate(att.holdout_e)
    sse0 = float((e_h ** 2).sum())
    base = lambda nm: "sensor_offset_gain" if nm in ("sensor_offset", "sensor_gain") else nm  # noqa: E731
    pred = 0.0
    seq = att.data_path + att.steps            # every step, the data-path corrections first (as selected)
    raw = att.rmse_before if att.rmse_raw is None else att.rmse_raw
    if seq:
        # the diagnosis' own prediction: held-out shrinkage after the last step attributed to its top-1 effect
        first = base(seq[0].name)
        k = max(i for i, st in enumerate(seq) if base(st.name) == first)
        pred = 1.0 - float((seq[k].rmse_after ** 2).sum()) / float((raw ** 2).sum())
    # measured: what the model leaves on the same held-out data made without the withheld effects (noise, the
    # modelled effects and the processing error of the same measured channels stay)
    meas, floor_rms = 0.0, float("nan")
    if case.withheld and case.withheld != ("torque_noise",):
        floor = generate_case_data(case, omit_withheld=True).holdout
        cond = condition_all(floor, DIAGNOSIS_CONDITIONING, "holdout")
        e_floor = np.concatenate([(cs.tau - model.predict(session_motion(cs, session_time(r))))[kept(cs, 0.5)]
                                  for cs, r in zip(cond, floor)])
        meas = 1.0 - float((e_floor ** 2).sum()) / sse0
        floor_rms = float(np.sqrt(np.mean(e_floor ** 2)))
    final = att.steps[-1].rmse_after if att.steps else att.rmse_before
    top = []
    names = att.top(4)
    if set(case.withheld) & set(PROCESSING_TYPES):   # a data-path case: its answer is in the processing section
        names = att.processing_findings + names
    for name in names:                               # sub-candidates count as their library effect
        if base(name) not in top:
            top.append(base(name))
    tv = att.time_variation
    return CaseResult(case, top[:3], att.selected, pred, meas, time.perf_counter() - t0,
                      params={s.name: float(s.gain) for s in seq},
                      processing=att.processing_findings,
                      final_rms=float(np.sqrt(np.mean(final ** 2))), floor_rms=floor_rms,
                      structured=not att.residual.white,
                      physical_gains={s.name: float(s.gain) for s in att.physical_steps},
                      hints=[[int(h.joint), list(h.signals), float(h.gain)] for h in att.hints],
                      time_dependent=None if tv is None else bool(tv.detected))


def case_result_to_dict(r: CaseResult) -> dict[str, Any]:
    """JSON-able form of a result (floats exact; NaN as JSON's NaN)."""
    d = asdict(r)
    d["case"] = {**asdict(r.case), "withheld": list(r.case.withheld), "modelled": list(r.case.modelled)}
    return d


def case_result_from_dict(d: dict[str, Any]) -> CaseResult:
    c = d["case"]
    case = BenchmarkCase(**{**c, "withheld": tuple(c["withheld"]), "modelled": tuple(c["modelled"]),
                            "logger": tuple(tuple(kv) for kv in c.get("logger", ())),
                            "session_s": tuple(c.get("session_s", ()))})
    return CaseResult(**{**d, "case": case})


def run_benchmark(cases: list[BenchmarkCase], workers: int | None = None, progress: bool = True,
                  backend: str = "local", address: str | None = None, state_dir: str | Path | None = None
                  ) -> list[CaseResult]:
    """Run the cases through :func:`proprio.tasks.run_tasks`: ``backend="local"`` on ``workers`` processes of this
    machine (default ``os.cpu_count()``), ``"ray"`` on a local Ray instance or the cluster at ``address``. Every
    case carries its own seed, so the results do not depend on the backend or the worker count. ``state_dir``: one
    result file per finished case; a rerun with the same directory runs only the missing cases (default: a
    temporary directory, no resume). A case whose task fails is returned with ``error`` set (and the failure
    printed with its config) while the others' results are kept."""
    import sys
    import tempfile

    from proprio.tasks import Task, run_tasks

    if backend == "local":
        workers = workers or os.cpu_count() or 1
    tasks = [Task(c.name, run_case, {"case": c}, {"case": c.name, **asdict(c)}) for c in cases]
    with tempfile.TemporaryDirectory(prefix="gap-benchmark-") as tmp:
        run = run_tasks(tasks, state_dir if state_dir is not None else tmp,
                        store=lambda task, result: case_result_to_dict(result), backend=backend, address=address,
                        workers=workers, progress=progress, desc="gap-benchmark")
    if progress or run.failures:
        print(run.summary(), file=sys.stderr)
    failed = {f.key: f for f in run.failures}
    results = []
    for c in cases:
        if c.name in run.records:
            results.append(case_result_from_dict(run.records[c.name]))
        else:
            results.append(CaseResult(c, [], [], float("nan"), float("nan"), 0.0,
                                      error=f"task failed: {failed[c.name].error}" if c.name in failed
                                      else "task failed"))
    return results


def summarise(results: list[CaseResult]) -> tuple[dict[str, Any], str]:
    """Scores and a printable report (confusion matrix, accuracies, null FP rate, shrinkage error; for the
    out-of-library cases the share flagged as structured-unexplained and the hint accuracy, for the time-varying
    cases the share whose time dependence was detected)."""
    open_w = [r for r in results if is_open_world(r.case) and not r.error]
    timed = [r for r in results if is_time_varying(r.case) and not r.error]
    library = [r for r in results if not (is_open_world(r.case) or is_time_varying(r.case))]
    single = [r for r in library if len(r.case.withheld) == 1 and not r.error]
    null = [r for r in library if not r.case.withheld and not r.error]
    pair = [r for r in library if len(r.case.withheld) == 2 and not r.error]
    failed = [r for r in results if r.error]
    labels = sorted({r.case.withheld[0] for r in single})
    pred_labels = labels + ["(other)", "(none)"]
    conf = np.zeros((len(labels), len(pred_labels)), dtype=int)
    for r in single:
        i = labels.index(r.case.withheld[0])
        p = r.top[0] if r.top else "(none)"
        conf[i, pred_labels.index(p) if p in pred_labels else len(labels)] += 1
    top1 = np.mean([bool(r.top) and r.top[0] == expected_name(r.case) for r in single]) if single else float("nan")
    physical = [r for r in single if r.case.withheld[0] not in PROCESSING_TYPES]
    top1_phys = np.mean([bool(r.top) and r.top[0] == expected_name(r.case) for r in physical]) if physical \
        else float("nan")
    top2 = np.mean([expected_name(r.case) in r.top[:2] for r in single]) if single else float("nan")
    null_fp = np.mean([bool(r.steps) for r in null]) if null else float("nan")
    pair_both = np.mean([set(r.case.withheld) <= set(r.top[:3]) for r in pair]) if pair else float("nan")
    # a noise-level finding (extra encoder noise) predicts no held-out shrinkage: noise cannot be predicted away, so
    # its measured column only says what the extra noise costs
    shr = [(r.predicted_shrinkage, r.measured_shrinkage) for r in single
           if r.measured_shrinkage > 0.05 and r.top and r.top[0] == expected_name(r.case)
           and r.case.withheld[0] not in LEVEL_FINDINGS]
    rel = np.array([abs(p - m) / m for p, m in shr]) if shr else np.zeros(0)
    flagged = [_flagged_unexplained(r) for r in open_w]
    with_hints = [r for r in open_w if r.hints is not None]
    hinted = [_hint_names_signal(r) for r in with_hints]
    tested = [r for r in timed if r.time_dependent is not None]
    static = [r for r in results if r not in timed and r.time_dependent is not None]   # no time variation in the data
    open_scores = {"open_world": len(open_w),
                   "open_flagged_unexplained": float(np.mean(flagged)) if flagged else float("nan"),
                   "open_hint_names_signal": float(np.mean(hinted)) if hinted else float("nan"),
                   "open_hints_computed": len(with_hints), "time_varying": len(timed),
                   "time_dependence_detected": float(np.mean([r.time_dependent for r in tested])) if tested
                   else float("nan"), "time_variation_tested": len(tested),
                   "time_varying_top1": float(np.mean([bool(r.top) and r.top[0] in r.case.withheld for r in timed]))
                   if timed else float("nan"),
                   "time_dependence_on_static_cases": float(np.mean([r.time_dependent for r in static])) if static
                   else float("nan")}
    drive = [r for r in library if is_drive_case(r.case) and not r.error]
    drive_single = [r for r in drive if len(r.case.withheld) == 1]
    drive_null = [r for r in drive if not r.case.withheld]
    open_scores.update({
        "drive_cases": len(drive),
        "drive_top1": float(np.mean([bool(r.top) and r.top[0] == expected_name(r.case) for r in drive_single]))
        if drive_single else float("nan"),
        "drive_null_false_positive_rate": float(np.mean([bool(r.steps) for r in drive_null])) if drive_null
        else float("nan")})
    scores = {"cases": len(results), "single": len(single), "null": len(null), "pairs": len(pair),
              "failed": len(failed), "top1": float(top1), "top1_physical": float(top1_phys), "top2": float(top2), "null_false_positive_rate":
              float(null_fp), "pairs_both_found": float(pair_both),
              "shrinkage_rel_error_median": float(np.median(rel)) if rel.size else float("nan"),
              "shrinkage_rel_error_max": float(rel.max()) if rel.size else float("nan"),
              "shrinkage_within_20pct": float(np.mean(rel <= 0.2)) if rel.size else float("nan"),
              "effect_types": labels, **open_scores}
    w = max(len(x) for x in labels + ["withheld"]) + 1
    lines = ["Confusion matrix (rows: withheld effect, columns: top-1 attribution)", ""]
    short = [p[:6] for p in pred_labels]
    lines.append("withheld".ljust(w) + " ".join(s.rjust(6) for s in short))
    for i, lab in enumerate(labels):
        lines.append(lab.ljust(w) + " ".join(str(v).rjust(6) if v else ".".rjust(6) for v in conf[i]))
    lines += ["", f"single-effect cases: {len(single)}  top-1 {100 * top1:.1f} %  top-2 {100 * top2:.1f} %  (physical "
              f"effects only, {len(physical)}: top-1 {100 * top1_phys:.1f} %; data-path cases "
              f"{', '.join(PROCESSING_TYPES)} are scored on the processing section)",
              f"null cases: {len(null)}  false-positive rate {100 * null_fp:.1f} %  (data-path steps reported "
              f"apart in {sum(bool(r.processing) for r in null)})",
              f"physical cases with a data-path candidate as top-1: "
              f"{sum(bool(r.top) and r.top[0] in PROCESSING_TYPES for r in single if r.case.withheld[0] not in PROCESSING_TYPES)}",
              f"two-effect cases: {len(pair)}  both effects among the top 3: {100 * pair_both:.1f} %",
              f"shrinkage (correct top-1, measured > 5 %, noise-level findings {', '.join(LEVEL_FINDINGS)} "
              f"excluded: they predict none): median rel. error "
              f"{100 * scores['shrinkage_rel_error_median']:.1f} %, max {100 * scores['shrinkage_rel_error_max']:.1f}"
              f" %, within 20 %: {100 * scores['shrinkage_within_20pct']:.0f} % of {rel.size}"]
    pct = lambda x: "n/a" if np.isnan(x) else f"{100 * x:.0f} %"  # noqa: E731
    lines += [f"out-of-library cases: {len(open_w)}  flagged structured-unexplained with no library effect above "
              f"{100 * OPEN_LIBRARY_GAIN:.0f} % held-out gain: {pct(open_scores['open_flagged_unexplained'])} "
              f"(wanted ≥ 80 %)",
              "  hint names the right signal (one of the first 3 hints on the affected joint): "
              + (f"{pct(open_scores['open_hint_names_signal'])} of {len(with_hints)} (wanted ≥ 60 %)" if with_hints
                 else "not computed (result files written before hints)"),
              f"time-varying cases: {len(timed)}  time dependence detected: "
              + (f"{pct(open_scores['time_dependence_detected'])} of {len(tested)} (wanted ≥ 80 %)" if tested
                 else "not computed (result files written before the time-variation test)" if timed else "n/a")
              + (f"; withheld effect named first: {pct(open_scores['time_varying_top1'])}" if timed else ""),
              "  time dependence reported on cases without any (false alarms): "
              + (f"{pct(open_scores['time_dependence_on_static_cases'])} of {len(static)}" if static else "n/a")]
    if drive:
        lines.append(f"drive-torque family (no joint-torque sensor): {len(drive_single)} single-effect cases, top-1 "
                     f"{pct(open_scores['drive_top1'])} (wanted ≥ 90 %); {len(drive_null)} null cases, false-positive "
                     f"rate {pct(open_scores['drive_null_false_positive_rate'])} (wanted 0 %)")
    if open_w:
        lines += ["", "out-of-library case".ljust(34) + "expected  structured  library steps (gain)".ljust(56)
                  + "hints on the joint"]
        for r in open_w:
            lib = ", ".join(f"{k} {100 * g:.0f} %" for k, g in r.physical_gains.items()) or "none"
            hints = "n/a" if r.hints is None else "; ".join(
                "+".join(h[1]) for h in [h for h in r.hints if h[0] == r.case.open_joint][:3]) or "none"
            lines.append(r.case.name[:33].ljust(34) + f"{r.case.expected_signal:9s} {str(r.structured):11s} "
                         + lib[:44].ljust(45) + hints)
    if failed:
        lines.append(f"failed cases: {len(failed)}: " + "; ".join(f"{r.case.name}: {r.error}" for r in failed))
    lines += ["", "case".ljust(44) + "attribution (top 3)".ljust(52)
              + "pred.shr meas.shr final floor [N·m]  s"]
    for r in results:
        lines.append(r.case.name[:43].ljust(44) + (" > ".join(r.top) or "(nothing)")[:51].ljust(52)
                     + f"{r.predicted_shrinkage:8.3f} {r.measured_shrinkage:8.3f} {r.final_rms:5.3f} "
                     + f"{r.floor_rms:5.3f}       {r.seconds:4.0f}")
    return scores, "\n".join(lines)


def _flagged_unexplained(r: CaseResult) -> bool:
    """An out-of-library case handled right: the residual stays structured and no library effect is named with
    more than :data:`OPEN_LIBRARY_GAIN` held-out gain."""
    return bool(r.structured) and all(g <= OPEN_LIBRARY_GAIN for g in r.physical_gains.values())


def _hint_names_signal(r: CaseResult) -> bool:
    """The case's expected signal is among the signals of one of the first 3 hints on its affected joint."""
    on_joint = [h for h in r.hints or [] if h[0] == r.case.open_joint][:3]
    return any(r.case.expected_signal in h[1] for h in on_joint)


def write_results(results: list[CaseResult], out_dir: str | Path) -> tuple[dict[str, Any], str]:
    """Summarise, print-ready text, and write ``benchmark.txt`` + ``benchmark.json`` atomically to ``out_dir``."""
    import json

    scores, text = summarise(results)
    out = Path(out_dir)
    atomic_write_text(out / "benchmark.txt", text + "\n")
    rows = [{"case": r.case.name, "source": "twin" if r.case.twin else "offline", "withheld": list(r.case.withheld), "magnitude": r.case.magnitude,
             "seed": r.case.seed, "modelled": list(r.case.modelled), "top": r.top, "selected": r.steps, "processing": r.processing,
             "predicted_shrinkage": r.predicted_shrinkage, "measured_shrinkage": r.measured_shrinkage,
             "final_rms": r.final_rms, "floor_rms": r.floor_rms, "seconds": r.seconds, "error": r.error,
             "structured": r.structured, "physical_gains": r.physical_gains, "open_joint": r.case.open_joint,
             "expected_signal": r.case.expected_signal, "hints": r.hints, "time_dependent": r.time_dependent}
            for r in results]
    atomic_write_text(out / "benchmark.json", json.dumps({"scores": scores, "cases": rows}, indent=1))
    return scores, text
