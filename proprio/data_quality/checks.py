"""The checks on the recorded channels t, q and τ (time base, clipping, limits, flat tops, quantisation, an
upstream torque filter), with the run and quantisation-step helpers they share. The package docstring
(:mod:`proprio.data_quality`) states each check and its thresholds."""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np
import scipy.signal

from proprio.conditioning import ConditioningConfig
from proprio.data_quality.findings import _SYMBOL, Finding, QualityThresholds
from proprio.description import RobotDescription
from proprio.recording import Recording

__all__ = ["runs", "quantisation_step", "signal_findings"]


def runs(mask: np.ndarray, min_len: int = 1) -> np.ndarray:
    """Runs of True in the 1-D ``mask``: ``[k, 2]`` array of ``[start, stop)`` sample indices, runs of at least
    ``min_len`` samples only."""
    m = np.concatenate([[0], np.asarray(mask, dtype=np.int8), [0]])
    edges = np.diff(m)
    r = np.stack([np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)], axis=1)
    return r[(r[:, 1] - r[:, 0]) >= min_len]


def quantisation_step(x: np.ndarray, th: QualityThresholds = QualityThresholds()) -> float | None:
    """The step δ of which the non-zero sample-to-sample differences of the 1-D ``x`` are integer multiples
    (module docstring), or None when there is none worth reporting."""
    a = np.abs(np.diff(np.asarray(x, dtype=float)))
    a = a[a > 0]
    if a.size < 50:
        return None
    smallest = float(a.min())
    for k in (1, 2, 3):                       # the smallest difference may be two or three steps
        step = smallest / k
        r = a / step
        if np.mean(np.abs(r - np.rint(r)) <= th.quant_tolerance) >= th.quant_fit_fraction:
            return step if float(np.median(a)) <= th.quant_max_ratio * step else None
    return None


def _names(rec: Recording, robot: RobotDescription | None) -> list[str]:
    n = rec.n_joints
    return list(robot.joint_names) if robot is not None and robot.n == n else [f"j{i + 1}" for i in range(n)]


def _which(names: list[str], idx: Sequence[int] | np.ndarray) -> str:
    idx = list(idx)
    if len(idx) == len(names) and len(names) > 1:
        return f"all {len(names)} joints"
    return ", ".join(names[i] for i in idx)


def _g(x: float, digits: int = 3) -> str:
    return f"{x:.{digits}g}"


def _span(a: np.ndarray, fmt: str = ".2g") -> str:
    """``"lo–hi"`` of the values in ``a``, or one value when they print alike."""
    lo, hi = format(float(np.min(a)), fmt), format(float(np.max(a)), fmt)
    return lo if lo == hi else f"{lo}–{hi}"


def _times(t: np.ndarray, k: np.ndarray, most: int = 3) -> str:
    s = ", ".join(f"{t[i]:.3f}" for i in k[:most])
    return f"t = {s} s" + (" …" if k.size > most else "")


def _time_base(rec: Recording, cfg: ConditioningConfig, th: QualityThresholds) -> list[Finding]:
    t = rec.t
    dt = np.diff(t)
    med = float(np.median(dt))
    out: list[Finding] = []
    lo, hi = float(dt.min()), float(dt.max())
    if hi - lo > 1e-6 * med:
        long_ = dt > th.jitter_factor * med
        frac = float(long_.mean())
        rms = float(np.sqrt(np.mean((dt - med) ** 2)))
        warn = frac > th.jitter_warn_fraction or lo < 0.5 * med
        out.append(Finding(
            "warning" if warn else "info", "jitter",
            f"t: jittered steps {1e3 * lo:.3g}–{1e3 * hi:.3g} ms around {1e3 * med:.3g} ms (RMS deviation "
            f"{1e3 * rms:.2g} ms), {100 * frac:.2g} % of steps > {th.jitter_factor:g}× median, longest at "
            f"t = {t[int(np.argmax(dt))]:.3f} s; conditioning resamples onto a uniform grid", "t",
            values={"dt_min_s": lo, "dt_median_s": med, "dt_max_s": hi, "dt_rms_deviation_s": rms,
                    "long_step_fraction": frac, "long_steps": int(long_.sum())}))
    limit = max(cfg.max_gap_s, 1.5 * med)
    gaps = np.flatnonzero(dt > limit)
    if gaps.size:
        missing = float(np.sum(dt[gaps] - med))
        share = missing / max(rec.duration, 1e-12)
        out.append(Finding(
            "problem" if share > th.gap_problem_fraction else "warning", "gap",
            f"t: {gaps.size} gap(s) > {1e3 * limit:.3g} ms (longest {1e3 * dt[gaps].max():.3g} ms, "
            f"{missing:.3g} s = {100 * share:.2g} % missing) at {_times(t, gaps)}; conditioning drops the samples "
            "inside and within the filters' reach of them", "t",
            values={"gap_limit_s": limit, "gaps": int(gaps.size), "missing_s": missing, "missing_fraction": share,
                    "gap_start_s": t[gaps[:20]], "gap_length_s": dt[gaps[:20]]}))
    dup = rec.meta.get("duplicate_stamps")
    if isinstance(dup, dict) and dup.get("stamps", 0) > 0:
        out.append(Finding(
            "warning", "duplicates",
            f"t: {dup['stamps']} duplicated time stamp(s) ({dup.get('samples', '?')} samples) were averaged into one "
            f"sample each at import" + (f", first at t = {dup['first_t']:.3f} s" if "first_t" in dup else ""),
            "t", values=dict(dup)))
    return out


def _clipping(rec: Recording, names: list[str], robot: RobotDescription | None,
              th: QualityThresholds) -> list[Finding]:
    if robot is None or robot.n != rec.n_joints:
        return []
    lim = robot.effort_limits
    mag = np.abs(rec.tau)
    at = (mag >= (1.0 - th.clip_margin) * lim[None, :]) & (mag <= (1.0 + th.clip_margin) * lim[None, :])
    out = _over_limit(rec, names, mag, lim, th)
    hit, n_runs, n_samples, first = [], [], [], []
    for j in np.flatnonzero(at.any(axis=0)):
        r = runs(at[:, j], th.clip_min_run)
        if r.size:
            hit.append(int(j))
            n_runs.append(len(r))
            n_samples.append(int((r[:, 1] - r[:, 0]).sum()))
            first.append(float(rec.t[r[0, 0]]))
    if not hit:
        return out
    return out + [Finding(
        "problem", "clipping",
        f"τ {_which(names, hit)}: at the effort limit (±{', ±'.join(_g(lim[j]) for j in hit)} N·m, within "
        f"{100 * th.clip_margin:g} %) in {sum(n_runs)} run(s) of ≥ {th.clip_min_run} samples ({sum(n_samples)} "
        f"samples), first at t = {min(first):.3f} s", "tau", tuple(names[j] for j in hit),
        {"effort_limit_nm": [float(lim[j]) for j in hit], "runs": n_runs, "samples": n_samples, "first_t_s": first})]


def _over_limit(rec: Recording, names: list[str], mag: np.ndarray, lim: np.ndarray,
                th: QualityThresholds) -> list[Finding]:
    over = mag > (1.0 + th.clip_margin) * lim[None, :]
    hit = np.flatnonzero(over.any(axis=0))
    if not hit.size:
        return []
    ratio = (mag / lim[None, :]).max(axis=0)
    first = float(rec.t[int(np.argmax(over.any(axis=1)))])
    return [Finding(
        "warning", "over_limit",
        f"τ {_which(names, hit)}: {int(over.sum())} sample(s) beyond the effort limit (up to "
        f"{', '.join(f'{ratio[j]:.3g}×' for j in hit)} of ±{', ±'.join(_g(lim[j]) for j in hit)} N·m), first at "
        f"t = {first:.3f} s — not clipping (a clipped signal sits at its limit): a wrong limit in the robot "
        "description, another robot's data or a sensor fault?", "tau", tuple(names[j] for j in hit),
        {"effort_limit_nm": [float(lim[j]) for j in hit], "max_ratio": [float(ratio[j]) for j in hit],
         "samples": [int(over[:, j].sum()) for j in hit], "first_t_s": first})]


def _flat_top(rec: Recording, names: list[str], th: QualityThresholds) -> list[Finding]:
    hit, level, n_runs = [], [], []
    for j in range(rec.n_joints):
        x = rec.tau[:, j]
        step = quantisation_step(x, th) or 0.0
        for extreme in (x.max(), x.min()):
            r = runs(x == extreme, th.flat_min_run)               # maximal runs of identical samples at the extreme
            r = r[r[:, 0] > 0]
            r = r[np.abs(x[r[:, 0]] - x[r[:, 0] - 1]) > 2.0 * step]  # entered by more than a quantisation step
            if r.size:
                hit.append(j)
                level.append(float(extreme))
                n_runs.append(len(r))
                break
    if not hit:
        return []
    return [Finding(
        "problem", "flat_top",
        f"τ {_which(names, hit)}: flat-topped at {', '.join(f'{v:+.4g}' for v in level)} N·m in {sum(n_runs)} "
        f"run(s) of ≥ {th.flat_min_run} identical samples at the joint's extreme (saturated sensor or converter?)",
        "tau", tuple(names[j] for j in hit), {"level_nm": level, "runs": n_runs})]


def _quantisation(rec: Recording, names: list[str], th: QualityThresholds) -> list[Finding]:
    out: list[Finding] = []
    for ch, x, unit in (("q", rec.q, "rad"), ("tau", rec.tau, "N·m")):
        steps = [quantisation_step(x[:, j], th) for j in range(rec.n_joints)]
        hit = [j for j, s in enumerate(steps) if s is not None]
        if not hit:
            continue
        zero = np.mean(np.diff(x[:, hit], axis=0) == 0, axis=0)
        vals = np.array([steps[j] for j in hit])

        def show(s: float) -> str:
            return f"{s:.4g} {unit}" + (f" ({np.degrees(s):.3g}°)" if ch == "q" else "")
        if np.allclose(vals, vals[0], rtol=1e-3):
            what = f"in steps of {show(vals[0])} on {_which(names, hit)}"
        else:
            what = "in steps of " + ", ".join(f"{names[j]} {show(s)}" for j, s in zip(hit, vals))
        coarse = zero > th.quant_warn_zero_fraction
        msg = f"{_SYMBOL[ch]} quantised {what}"
        if coarse.any():
            msg += (f"; coarse on {_which(names, [hit[k] for k in np.flatnonzero(coarse)])}: up to "
                    f"{100 * zero.max():.2g} % of samples repeat the previous one")
        values: dict[str, Any] = {"step": vals, "unit": unit, "zero_step_fraction": zero}
        if ch == "q":
            values["step_deg"] = np.degrees(vals)
        out.append(Finding("warning" if coarse.any() else "info", "quantised", msg, ch,
                           tuple(names[j] for j in hit), values))
    return out


def _tau_spectrum(tau: np.ndarray, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """Frequencies [Hz] (without 0) and the Welch spectrum of τ [(N·m)²/Hz] per joint, from its first difference."""
    d = np.diff(tau, axis=0)
    nper = int(min(d.shape[0], max(256, 2 ** int(np.floor(np.log2(max(d.shape[0] // 8, 2)))))))
    f, p = scipy.signal.welch(d, fs=rate, nperseg=nper, detrend="constant", axis=0)
    f, p = f[1:], p[1:]
    return f, p / (4.0 * np.sin(np.pi * f / rate) ** 2)[:, None]


def _filtered(rec: Recording, names: list[str], th: QualityThresholds) -> list[Finding]:
    if rec.n_samples < th.min_spectrum_samples:
        return []
    rate = rec.rate_hz
    f, p = _tau_spectrum(rec.tau, rate)
    rms = np.maximum(rec.tau.std(axis=0), 1e-300)
    floor = np.sqrt(np.mean(p[f >= 0.25 * rate], axis=0) * rate / 2.0) / rms
    mid = np.median(p[(f >= 0.15 * rate) & (f < 0.25 * rate)], axis=0)
    top = np.median(p[f >= 0.4 * rate], axis=0)
    falloff = mid / np.maximum(top, 1e-300)
    flagged = np.flatnonzero((floor < th.filtered_floor_ratio) | (falloff > th.filtered_falloff))
    if not flagged.size:
        return []
    above = p > 1e-6 * p.max(axis=0)                               # ≥ 60 dB below the peak elsewhere
    last = np.array([f[np.flatnonzero(a)[-1]] if a.any() else f[0] for a in above.T])
    fl = flagged
    return [Finding(
        "warning", "tau_filtered",
        f"τ {_which(names, fl)}: low-pass filtered upstream — no white-noise floor (≤ {_g(floor[fl].max(), 2)} of "
        f"the signal RMS), the spectrum still falls {_span(falloff[fl])}× across the upper band and is ≥ 60 dB down "
        f"above {_span(last[fl])} Hz; its noise and phase are not the sensor's",
        "tau", tuple(names[j] for j in fl),
        {"floor_to_rms": floor[fl], "falloff": falloff[fl], "minus_60db_above_hz": last[fl],
         "floor_to_rms_all": floor, "falloff_all": falloff})]


def signal_findings(rec: Recording, names: list[str], robot: RobotDescription | None, conditioning: ConditioningConfig,
                    th: QualityThresholds) -> list[Finding]:
    """The findings on t, q and τ as recorded, in the order of the package docstring."""
    return (_time_base(rec, conditioning, th) + _clipping(rec, names, robot, th) + _flat_top(rec, names, th)
            + _quantisation(rec, names, th) + _filtered(rec, names, th))
