"""Data-quality findings: what is wrong with (or worth knowing about) a log before anything is fitted to it.

:func:`assess` looks at one :class:`~proprio.recording.Recording` and returns a :class:`DataQuality`: a list of
:class:`Finding` (severity ``info`` / ``warning`` / ``problem``, a short ``code``, a one-line message naming the
channel and joint(s), and the numbers behind it) plus the one-line summary of the signal conditioning
(:meth:`proprio.conditioning.ConditionedSignals.describe`). :func:`format_findings` gives fixed-width text (what
``proprio inspect`` and ``proprio identify`` print), :func:`findings_markdown` a table for the diagnosis report and
:meth:`DataQuality.to_dict` a JSON-ready form. Every check is vectorised over samples; loops run over joints only.

The checks and their thresholds (:class:`QualityThresholds`, units stated there):

``jitter`` (t)
    Time steps ``Δt``: min / median / max, RMS deviation from the median and the fraction of steps longer than
    ``jitter_factor`` (1.5) × median. *info* when the steps are not uniform; *warning* when more than
    ``jitter_warn_fraction`` (1 %) of the steps are that long or a step is shorter than half the median.
``gap`` (t)
    Steps longer than ``max(conditioning.max_gap_s, 1.5 × median)`` — the same rule by which
    :func:`proprio.conditioning.uniform_time_base` flags samples invalid, so the finding says what conditioning
    drops: count, missing time and where. *warning*; *problem* when more than ``gap_problem_fraction`` (10 %) of
    the duration is missing.
``duplicates`` (t)
    A Recording's time is strictly increasing, so duplicated stamps are merged where they enter: the CSV importer
    (:func:`proprio.recording.recording_from_csv`) averages the samples of a duplicated stamp and records the count in
    ``meta["duplicate_stamps"]``; this check reports it. *warning*.
``clipping`` (τ, needs a robot)
    ``|τ|`` *at* the effort limit — within ``clip_margin`` (1 %) of it on either side — in runs of at least
    ``clip_min_run`` (3) samples. *problem*.
``over_limit`` (τ, needs a robot)
    ``|τ|`` beyond ``(1 + clip_margin)`` × the effort limit: not clipping (a clipped signal sits at its limit) but a
    torque the robot is not rated for — a wrong limit in the description, another robot's data or a sensor fault.
    *warning*. (Beyond :data:`proprio.recording.PLAUSIBLE_LIMIT_FACTOR` × the limit the loader refuses the file.)
``flat_top`` (τ)
    Runs of at least ``flat_min_run`` (10) bit-identical samples at a joint's largest or smallest value, entered by a
    step larger than twice τ's quantisation step (a smooth quantised peak creeps in by one step; a saturated
    sensor or converter arrives with the signal's full slope). *problem*.
``quantised`` (q, τ)
    The step ``δ`` of which every non-zero ``|Δx|`` is an integer multiple (to ``quant_tolerance`` = 1 % of δ, for
    at least 98 % of the differences): the smallest non-zero ``|Δx|`` or its half or third. Reported when
    ``median |Δx| ≤ 1000 δ`` (a finer step is immaterial), in rad and degrees for q and N·m for τ. *info*; *warning*
    when more than ``quant_warn_zero_fraction`` (20 %) of the samples repeat their predecessor (a staircase that
    differences turn into spikes).
``tau_filtered`` (τ)
    A torque sensor's log carries a white-noise floor. From the Welch spectrum of ``Δτ`` on the raw samples (first
    differences pre-whiten, so window leakage from the large slow content cannot fake a floor), divided by the
    difference's ``4 sin²(π f h)``: the floor ``σ_floor = √(mean P(f ≥ fs/4) · fs/2)`` [N·m] and the fall-off
    ``median P[0.15 fs, 0.25 fs) / median P[0.4 fs, 0.5 fs]``. A joint is *filtered upstream* when its floor is
    below ``filtered_floor_ratio`` (1e-5, i.e. 100 dB, beyond a 16-bit converter's quantisation noise) of its
    signal RMS or the spectrum still falls by more than ``filtered_falloff`` (10×) across the upper band. The
    message gives the frequency above which the power stays ≥ 60 dB below its peak. *warning*: the sensor's noise
    and the filter's phase are not what the model sees.
``qd_lag`` / ``qd_gain`` / ``qd_consistent`` (q̇, when the Recording has one)
    The recorded q̇ against ``dq/dt`` from the conditioning path (:func:`proprio.conditioning.condition` with
    ``velocity = "q"``), both on its uniform grid, gaps and ``edge_fraction`` (5 %, at least ``1/min(cutoff)``) at
    each end dropped (upstream filters start up there). Per joint, the lag is the peak of their normalised
    cross-correlation within ``±max_lag_s`` (50 ms; every lag sees the same samples), refined by a parabola through
    the peak (sub-sample); positive means the recorded q̇ lags. Its standard error comes from the residual of
    ``q̇_rec ≈ g · q̇_ref(t − lag)`` (``σ² = Σe² / (g² Σ q̈_ref² N_eff)``, ``N_eff`` from the residual's lag-1
    autocorrelation); the pooled lag is the inverse-variance mean over joints (a slow joint, whose broad correlation
    peak hardly fixes a lag, counts little). The gain ``g`` is the least-squares factor. *warning* when the pooled
    ``|lag| > lag_warn_s`` (1 ms) and more than twice its standard error, or when a moving joint's
    ``|g − 1| > gain_warn`` (5 %); else *info*.
``qdd_noise`` (q̈)
    The RMS of the raw second difference of q (``np.gradient`` twice over the stamps, what a naive derivative gives)
    against the RMS of the conditioned q̈, with the conditioning's cutoffs and its estimated error ``σ(q̈)``: *info*
    when the raw one is more than ``qdd_noise_ratio`` (3×) larger. ``qdd_recorded`` (*info*): a q̈ channel exists;
    no stage uses it (no robot measures q̈).
"""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
import scipy.signal

from proprio.conditioning import ConditionedSignals, ConditioningConfig, condition
from proprio.description import RobotDescription
from proprio.recording import Recording, RecordingError

__all__ = ["SEVERITIES", "Finding", "DataQuality", "QualityThresholds", "assess", "format_findings",
           "findings_markdown", "quantisation_step", "runs"]

SEVERITIES = ("info", "warning", "problem")
_RANK = {s: i for i, s in enumerate(SEVERITIES)}
_SYMBOL = {"t": "t", "q": "q", "tau": "τ", "qd": "q̇", "qdd": "q̈"}


@dataclass(frozen=True)
class QualityThresholds:
    """The thresholds of :func:`assess` (module docstring). Times in s, fractions of 1, ratios dimensionless."""
    jitter_factor: float = 1.5            # a step > this × median step is "long"
    jitter_warn_fraction: float = 0.01    # warn when more steps than this fraction are long
    gap_problem_fraction: float = 0.10    # a problem when gaps miss more than this fraction of the duration
    clip_margin: float = 0.01             # |τ| within this fraction of the effort limit counts as at the limit
    clip_min_run: int = 3                 # samples in a row at the limit
    flat_min_run: int = 10                # bit-identical samples in a row at a joint's extreme
    quant_tolerance: float = 0.01         # |Δx/δ − round(Δx/δ)| allowed, fraction of δ
    quant_fit_fraction: float = 0.98      # share of non-zero differences that must be multiples of δ
    quant_max_ratio: float = 1000.0       # report only when median |Δx| ≤ this × δ
    quant_warn_zero_fraction: float = 0.2
    filtered_floor_ratio: float = 1e-5    # white floor σ / signal RMS below this: filtered upstream
    filtered_falloff: float = 10.0        # median P in [0.15, 0.25) fs over [0.4, 0.5] fs above this: filtered
    min_spectrum_samples: int = 256
    max_lag_s: float = 0.05               # lags searched within ± this [s]
    edge_fraction: float = 0.05           # share of samples dropped at each end before the lag estimate
    lag_warn_s: float = 1e-3
    gain_warn: float = 0.05
    qdd_noise_ratio: float = 3.0


@dataclass(frozen=True)
class Finding:
    """One finding: ``severity`` (``info`` / ``warning`` / ``problem``), a short ``code``, a one-line ``message``
    naming the ``channel`` (``t``, ``q``, ``tau``, ``qd``, ``qdd``) and ``joints``, and the numbers behind it
    (``values``, SI units, keys say which)."""
    severity: str
    code: str
    message: str
    channel: str
    joints: tuple[str, ...] = ()
    values: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.severity not in _RANK:
            raise ValueError(f"finding severity must be one of {SEVERITIES}, got {self.severity!r}")

    def to_dict(self) -> dict[str, Any]:
        return {"severity": self.severity, "code": self.code, "message": self.message, "channel": self.channel,
                "joints": list(self.joints), "values": _jsonable(self.values)}


@dataclass
class DataQuality:
    """The findings on one Recording (most severe first), the conditioning line and the Recording's ``source``."""
    findings: list[Finding]
    conditioning: str
    source: str = ""

    def at_least(self, severity: str) -> list[Finding]:
        """The findings of ``severity`` or worse."""
        return [f for f in self.findings if _RANK[f.severity] >= _RANK[severity]]

    @property
    def worst(self) -> str | None:
        """The most severe severity found, or None without findings."""
        return max((f.severity for f in self.findings), key=_RANK.__getitem__, default=None)

    def codes(self) -> set[str]:
        return {f.code for f in self.findings}

    def to_dict(self) -> dict[str, Any]:
        return {"source": self.source, "conditioning": self.conditioning,
                "findings": [f.to_dict() for f in self.findings]}

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=1, allow_nan=False)


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        return float(x) if np.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    return x


# ---- helpers ----------------------------------------------------------------------------------------------------

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


# ---- the checks ---------------------------------------------------------------------------------------------------

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


def _lag(x: np.ndarray, y: np.ndarray, max_lag: int) -> np.ndarray:
    """Normalised cross-correlation ``c[k]``, ``k = −max_lag … max_lag``, of ``x`` (inner samples) with ``y`` shifted
    by ``k`` samples: every lag uses the same ``x`` samples (no triangular overlap weighting, which would pull a
    broad peak towards 0), divided by the norm of the ``y`` samples it uses. ``c`` peaks at ``k = d`` when ``x``
    lags ``y`` by ``d`` samples."""
    n = x.shape[0]
    xi = x[max_lag:n - max_lag]
    z = scipy.signal.correlate(y, xi, mode="valid", method="fft")          # z[m] = Σ x[i+L] y[i+m]
    e = scipy.signal.correlate(y ** 2, np.ones(xi.size), mode="valid", method="fft")
    return (z / np.sqrt(np.maximum(e, 1e-300)))[::-1] * np.sqrt(np.sum(xi ** 2))


def _peak(c: np.ndarray, max_lag: int) -> float:
    """Sub-sample position of the maximum of ``c`` (a parabola through the peak and its neighbours), in samples
    from the centre."""
    k = int(np.argmax(c))
    frac = 0.0
    if 0 < k < c.size - 1:
        den = c[k - 1] - 2.0 * c[k] + c[k + 1]
        frac = 0.5 * (c[k - 1] - c[k + 1]) / den if den < 0 else 0.0
    return k - max_lag + frac


def _velocity(rec: Recording, ref: ConditionedSignals, names: list[str], th: QualityThresholds) -> list[Finding]:
    t_u, rate = ref.t, ref.rate_hz
    qd = np.stack([np.interp(t_u, rec.t - rec.t[0], rec.qd[:, j]) for j in range(rec.n_joints)], axis=1)
    max_lag = max(2, int(np.ceil(th.max_lag_s * rate)))
    edge = max(int(np.ceil(rate / float(ref.cutoff_hz.min()))), int(np.ceil(th.edge_fraction * t_u.size)),
               max_lag)
    sl = slice(edge - max_lag, t_u.size - edge + max_lag)       # drops start-up transients (upstream filters, ours)
    if t_u.size - 2 * edge < 4 * max_lag:
        return []
    # x: the recorded q̇, zero inside gaps (so those samples add nothing at any lag); y: the reference, intact, so
    # that every lag sees the same samples (a zero-padded y would pull the peak towards lag 0)
    keep = ref.valid[sl]
    x = np.where(keep[:, None], qd[sl] - qd[sl][keep].mean(axis=0), 0.0)
    y = ref.qd[sl] - ref.qd[sl][keep].mean(axis=0)
    n = rec.n_joints
    lag = np.array([_peak(_lag(x[:, j], y[:, j], max_lag), max_lag) for j in range(n)]) / rate
    # per joint: the reference shifted by its lag, the gain, and the lag's standard error from the residual
    # (σ_τ² = Σe² / (g² Σẏ² N_eff), N_eff = N (1 − ρ₁)/(1 + ρ₁) for the residual's lag-1 autocorrelation ρ₁)
    t_s = t_u[sl]
    y_sh = np.stack([np.interp(t_s - lag[j], t_s, y[:, j]) for j in range(n)], axis=1)[max_lag:-max_lag]
    yd = np.gradient(y_sh, 1.0 / rate, axis=0)
    xi, k = x[max_lag:-max_lag], keep[max_lag:-max_lag, None]
    y_sh, yd = np.where(k, y_sh, 0.0), np.where(k, yd, 0.0)
    gain = np.sum(xi * y_sh, axis=0) / np.maximum(np.sum(y_sh ** 2, axis=0), 1e-300)
    e = np.where(k, xi - gain * y_sh, 0.0)
    rho = np.clip(np.sum(e[1:] * e[:-1], axis=0) / np.maximum(np.sum(e ** 2, axis=0), 1e-300), -0.999, 0.999)
    n_eff = k.sum() * (1.0 - rho) / (1.0 + rho)
    sigma = np.sqrt(np.sum(e ** 2, axis=0) / np.maximum(gain ** 2 * np.sum(yd ** 2, axis=0) * n_eff, 1e-300))
    w = 1.0 / np.maximum(sigma, 1e-12) ** 2
    pooled, pooled_sigma = float(w @ lag / w.sum()), float(1.0 / np.sqrt(w.sum()))   # inverse-variance mean
    rms_ref = np.sqrt(np.sum(y_sh ** 2, axis=0) / k.sum())
    moving = rms_ref > 10.0 * ref.sigma_qd
    values = {"lag_s": pooled, "lag_sigma_s": pooled_sigma, "lag_per_joint_s": lag, "lag_sigma_per_joint_s": sigma,
              "gain_per_joint": gain, "moving": moving,
              "reference": "dq/dt from conditioning (velocity: q)"}
    out: list[Finding] = []
    m = np.flatnonzero(moving)
    if abs(pooled) > th.lag_warn_s and abs(pooled) > 2.0 * pooled_sigma:
        which = m if m.size else np.arange(rec.n_joints)
        out.append(Finding(
            "warning", "qd_lag",
            f"q̇ {_which(names, which)}: the recorded q̇ {'lags' if pooled > 0 else 'leads'} dq/dt by "
            f"{1e3 * abs(pooled):.2f} ± {1e3 * pooled_sigma:.2f} ms; it was filtered or delayed upstream "
            "(conditioning velocity: q avoids it)", "qd", tuple(names[j] for j in which), values))
    bad = m[np.abs(gain[m] - 1.0) > th.gain_warn]
    if bad.size:
        out.append(Finding(
            "warning", "qd_gain",
            f"q̇ {_which(names, bad)}: gain {', '.join(f'{gain[j]:.3f}' for j in bad)} against dq/dt "
            f"(more than {100 * th.gain_warn:g} % off: scaled or filtered q̇, or a units mismatch)", "qd",
            tuple(names[j] for j in bad), values))
    if not out:
        g = f", gain {_span(gain[m], '.3f')}" if m.size else ""
        out.append(Finding("info", "qd_consistent", f"q̇: consistent with dq/dt (lag {1e3 * pooled:.2f} ± "
                           f"{1e3 * pooled_sigma:.2f} ms{g})", "qd", tuple(names), values))
    return out


def _acceleration(rec: Recording, cs: ConditionedSignals, names: list[str], th: QualityThresholds) -> list[Finding]:
    out: list[Finding] = []
    raw = np.gradient(np.gradient(rec.q, rec.t, axis=0), rec.t, axis=0)
    raw_rms = np.sqrt(np.mean(raw ** 2, axis=0))
    v = cs.valid
    rms = np.sqrt(np.mean(cs.qdd[v] ** 2, axis=0))
    ratio = raw_rms / np.maximum(rms, 1e-300)
    values = {"raw_rms_rad_s2": raw_rms, "conditioned_rms_rad_s2": rms, "sigma_qdd_rad_s2": cs.sigma_qdd,
              "cutoff_hz": cs.cutoff_hz}
    noisy = np.flatnonzero(ratio > th.qdd_noise_ratio)
    if noisy.size:
        j = int(np.argmax(ratio))
        out.append(Finding(
            "info", "qdd_noise",
            f"q̈ {_which(names, noisy)}: raw second differences of q are noise — RMS {_g(raw_rms[j])} vs "
            f"{_g(rms[j])} rad/s² conditioned on {names[j]} ({ratio[j]:.2g}×; cutoff {_span(cs.cutoff_hz, '.3g')} "
            f"Hz, est. σ(q̈) ≤ {_g(cs.sigma_qdd.max(), 2)} rad/s²)",
            "qdd", tuple(names[j] for j in noisy), values))
    if rec.qdd is not None:
        out.append(Finding("info", "qdd_recorded",
                           "q̈: the Recording carries a q̈ channel; no stage uses it (no robot measures q̈: "
                           "conditioning differentiates q)", "qdd", tuple(names)))
    return out


# ---- the entry point ----------------------------------------------------------------------------------------------

def assess(rec: Recording, robot: RobotDescription | None = None,
           conditioning: ConditioningConfig = ConditioningConfig(),
           thresholds: QualityThresholds = QualityThresholds()) -> DataQuality:
    """All data-quality findings on ``rec`` (module docstring), most severe first. ``robot`` names the joints and
    gives the effort limits for ``clipping``; ``conditioning`` is the configuration whose line is reported (and
    whose q̈ is compared); ``thresholds`` the limits of each check."""
    th = thresholds
    names = _names(rec, robot)
    found = (_time_base(rec, conditioning, th) + _clipping(rec, names, robot, th) + _flat_top(rec, names, th)
             + _quantisation(rec, names, th) + _filtered(rec, names, th))
    try:
        cs = condition(rec, conditioning)
        line = cs.describe()
    except RecordingError as exc:
        cs, line = None, f"conditioning: not possible ({exc})"
        found.append(Finding("warning", "conditioning", f"q: {exc}", "q"))
    if cs is not None:
        found += _acceleration(rec, cs, names, th)
        if rec.qd is not None:
            ref = cs if cs.velocity_source == "q" else condition(rec, dataclasses.replace(conditioning, velocity="q"))
            found += _velocity(rec, ref, names, th)
    found.sort(key=lambda f: -_RANK[f.severity])                  # stable: checks keep their order within a level
    return DataQuality(found, line, str(rec.meta.get("source", "")))


def format_findings(dq: DataQuality, min_severity: str = "info", title: str | None = None,
                    conditioning: bool = True) -> str:
    """Fixed-width text: an optional title line, one line per finding of ``min_severity`` or worse
    (``SEVERITY  code  message``) and the conditioning line."""
    lines = [title] if title else []
    shown = dq.at_least(min_severity)
    for f in shown:
        lines.append(f"  {f.severity.upper():<8} {f.code:<14} {f.message}")
    if not shown:
        lines.append("  no findings" + ("" if min_severity == "info" else f" of severity {min_severity} or worse"))
    if conditioning:
        lines.append(f"  {dq.conditioning}")
    return "\n".join(lines)


def findings_markdown(items: Sequence[tuple[str, DataQuality]], min_severity: str = "info") -> str:
    """A markdown table of the findings of several Recordings (``(name, DataQuality)`` pairs), then one paragraph
    per Recording with its conditioning line — for the top of the diagnosis report."""
    rows = ["| recording | severity | finding | what |", "|---|---|---|---|"]
    for name, dq in items:
        shown = dq.at_least(min_severity)
        if not shown:
            rows.append(f"| {name} | — | — | no findings |")
        for f in shown:
            rows.append(f"| {name} | {f.severity} | {f.code} | {f.message.replace('|', '/')} |")
    paras = [f"{name}{f' ({dq.source})' if dq.source else ''} — {dq.conditioning}" for name, dq in items]
    return "\n".join(rows) + "\n\n" + "\n\n".join(paras)
