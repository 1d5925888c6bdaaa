"""The one signal-conditioning path: from what a robot logs (jittered time stamps, encoder ``q``, ``τ_J``, perhaps its
own filtered ``q̇``; never ``q̈``) to the uniformly sampled ``q, q̇, q̈, τ`` every later stage uses (identify, diagnose,
estimate, the payload experiment, the learning datasets, the gap benchmark, the demo).

Steps, all vectorised over samples and joints:

1. **Time base.** A log with jittered stamps is *resampled* onto the uniform grid of its nominal step by cubic-spline
   interpolation (error ``≈ h⁴/384 · |q⁗|``, far below encoder noise even across an 8 ms step). Jittered stamps mean
   one of two things, and ``time_base`` says which: ``stamps`` — each sample was taken at its stamp (irregular
   sampling, e.g. a 150 Hz log of 6/7 ms steps from a 1 kHz controller); ``clock`` — the samples were taken on the
   controller's regular clock and the stamps carry the logging host's receive-time jitter, so each sample belongs to
   the grid index nearest its stamp (a missing index is a lost sample, filled by the spline). ``auto`` (default)
   takes the one under which ``q`` is smoother: the white floor of ``Δ²q/h²`` (step 2) must drop for ``clock`` by
   more than the floor estimate's own 95 % chance margin (``CLOCK_ALPHA``; a wrong stamp adds ``q̇·δt`` of noise; a
   wrong snap does the same; ≈ 2 % in variance for 20 s at 1 kHz, where a 10⁻⁴ rad encoder's floor drops only
   5–15 % on the clock). A step longer
   than ``max_gap_s`` is a *gap* (a dropout): the grid samples inside it are interpolated (``gap``) and flagged
   invalid (``valid``); so are, beside a gap lasting a cutoff period or more (where the fill is guesswork), the
   samples within ``edge_cycles`` periods of the lowest cutoff — the zero-phase filters of step 3 carry the fill that
   far. Every later stage drops the invalid samples. Duplicate stamps cannot reach this point: a Recording's time is
   strictly increasing (:func:`proprio.recording.recording_from_csv` averages duplicated stamps at import).
2. **Cutoff per joint** (:mod:`proprio.cutoff`). From the config, or ``auto``: the cutoff that minimises the
   estimated error of ``q̈`` (the signal the filter distorts plus the white floor it passes; the motion's spectrum
   taken on the uniform grid, the floor at the samples' own instants), bounded by the arm's physical motion band
   ``max_motion_hz``. **Decimation** (``decimate``, on in the diagnosis): a grid sampled more
   than ``oversampling ×`` faster than that band is decimated by the integer ``M`` behind a zero-phase anti-alias
   filter, ``q``, ``τ`` and the robot's ``q̇`` alike, before the low-pass; white τ noise keeps its density, so its
   variance drops by ``M`` (``tau_gain``).
3. **Zero-phase low-pass, then differentiation.** A Butterworth low-pass (``order``, forward–backward with
   ``scipy.signal.sosfiltfilt``, odd padding over ``edge_cycles`` periods of the cutoff) of ``q`` (or of the robot's
   own ``q̇`` when ``velocity: measured``), then second-order central differences (``np.gradient``) for ``q̇`` and
   ``q̈``. **τ gets the same low-pass per joint**, so a prediction computed from the conditioned motion and the
   measurement it is compared with have the same (zero-phase) transfer function.
4. **Its own error.** ``sigma_qd``, ``sigma_qdd`` [rad/s, rad/s²]: the white floor propagated through the filter and
   difference chain (the sum of the squared impulse response) combined with the signal the low-pass distorts
   (``Σ S (1 − G)²``: attenuated near and removed above the cutoff). Later stages turn them into torque
   (:func:`processing_torque_sigma`), so a gap the processing
   itself could explain is never reported as physics.

:func:`condition` returns a :class:`ConditionedSignals`; ``.describe()`` is the one line every output prints.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any, Sequence

import numpy as np
import scipy.signal
from scipy import stats

from proprio.cutoff import (cutoff_of_spectra, decimate, decimate_valid, decimation_factor, lost_power, noise_floor_dof,
                            spectra, tau_white_level, white_floor)
from proprio.recording import Recording, RecordingError
from proprio.time_base import clock_stamps, resample, uniform_time_base
from proprio.signals import MotionSignals

__all__ = ["ConditioningConfig", "ConditionedSignals", "condition", "zero_phase_lowpass",
           "processing_torque_sigma"]

CLOCK_ALPHA = 0.05
"""One-sided level of the time-base test (step 1): the samples go on the controller's clock when the white floor of q
under it is below the floor at the stamps by more than the floor estimate's own 95 % chance margin (``χ²_{D,α}/D``,
``D`` from :func:`~proprio.cutoff.noise_floor_dof`)."""


@dataclass(frozen=True)
class ConditioningConfig:
    """Settings of :func:`condition` (the ``conditioning:`` block of a config).

    ``cutoff_hz``: ``"auto"`` (per joint from the noise floor, module docstring), one number [Hz] or one per joint.
    ``velocity``: ``"q"`` (default) differentiates ``q`` — zero phase, whatever the robot did to its own q̇ (the LWR 4+
    files' q̇ lags by ≈3 ms, ``proprio inspect`` says so); ``"auto"`` uses the robot's own ``q̇`` when the Recording has
    one and it is better — no lag, no more noise than ``d/dt q`` (``velocity_source`` says which and why; its ``q̈``
    still comes from our filter); ``"measured"`` requires it. A Recording's ``qdd`` is
    never used: no robot measures it. ``tau_filter``: apply the same low-pass to τ (default) or leave it raw.
    ``time_base``: ``auto``, ``stamps`` or ``clock`` (module docstring, step 1). ``max_motion_hz`` [Hz]: the
    physical bound of the arm's motion band for the auto cutoff; ``decimate`` / ``oversampling``: decimation of a log
    sampled far faster than its motion band (module docstring, step 2).
    """
    cutoff_hz: str | float | tuple[float, ...] = "auto"
    order: int = 2
    edge_cycles: float = 3.0
    min_cutoff_hz: float = 1.0
    max_cutoff_fraction: float = 0.2
    velocity: str = "q"
    tau_filter: bool = True
    max_gap_s: float = 0.02
    time_base: str = "auto"
    max_motion_hz: float = 40.0
    decimate: bool = False
    oversampling: float = 10.0

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None, where: str = "conditioning") -> "ConditioningConfig":
        d = dict(d or {})
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"{where}: unknown key(s) {unknown}; known: {sorted(known)}")
        if isinstance(d.get("cutoff_hz"), list):
            d["cutoff_hz"] = tuple(float(x) for x in d["cutoff_hz"])
        cfg = cls(**d)
        cfg.check(where)
        return cfg

    def check(self, where: str = "conditioning") -> None:
        c = self.cutoff_hz
        if isinstance(c, str):
            if c != "auto":
                raise ValueError(f"{where}.cutoff_hz: 'auto', a number [Hz] or a list per joint, got {c!r}")
        elif not np.all(np.asarray(c, dtype=float) > 0):
            raise ValueError(f"{where}.cutoff_hz: must be > 0 Hz, got {c}")
        if self.order < 1 or self.edge_cycles < 0 or self.min_cutoff_hz <= 0 or self.max_gap_s <= 0:
            raise ValueError(f"{where}: order >= 1, edge_cycles >= 0, min_cutoff_hz > 0 and max_gap_s > 0 required")
        if not self.max_motion_hz > self.min_cutoff_hz or not self.oversampling >= 4:
            raise ValueError(f"{where}: max_motion_hz > min_cutoff_hz and oversampling >= 4 required")
        if not 0 < self.max_cutoff_fraction < 0.5:
            raise ValueError(f"{where}.max_cutoff_fraction must be in (0, 0.5) of the sample rate")
        if self.velocity not in ("auto", "q", "measured"):
            raise ValueError(f"{where}.velocity: 'auto', 'q' or 'measured', got {self.velocity!r}")
        if self.time_base not in ("auto", "stamps", "clock"):
            raise ValueError(f"{where}.time_base: 'auto', 'stamps' or 'clock', got {self.time_base!r}")


@dataclass
class ConditionedSignals:
    """Uniformly sampled, zero-phase conditioned signals of one Recording.

    ``t [N]`` s (uniform, from 0), ``q, qd, qdd, tau [N,n]`` (rad, rad/s, rad/s², N·m), ``valid [N]`` (False inside
    gaps of the original log and within the filters' reach of a long one: the samples every later stage may use),
    ``gap [N]`` (True inside gaps of the log: nothing was measured there; default ``~valid``), ``cutoff_hz [n]``,
    ``rate_hz``, the estimated white noise of ``q`` (``sigma_q [n]``, rad; ``sigma_q_dof``: the χ² degrees of freedom
    of ``sigma_q²``, :func:`noise_floor_dof`) and the estimated errors of the derivatives (``sigma_qd``,
    ``sigma_qdd [n]``), ``velocity_source``,
    ``tau_gain [n]`` (the factor by which the τ low-pass scales the variance of white noise: compare a noise level
    with the conditioned τ through it), ``notes`` (what was done to the time base) and ``sigma_tau [n]`` N·m: the
    white noise of the raw τ at the log's own rate and stamps, robustly (:func:`tau_white_level`); ``sigma_tau3 [n]``
    N·m: the same level from the third difference (equal to ``sigma_tau`` when the raw floor is white noise, below it
    when the floor is the motion's or a filtered τ's)."""
    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray
    valid: np.ndarray
    rate_hz: float
    cutoff_hz: np.ndarray
    sigma_q: np.ndarray
    sigma_q_dof: float
    sigma_qd: np.ndarray
    sigma_qdd: np.ndarray
    velocity_source: str
    auto_cutoff: bool
    tau_gain: np.ndarray
    notes: list[str] = field(default_factory=list)
    source: Recording | None = None
    gap: np.ndarray | None = None
    sigma_tau: np.ndarray | None = None
    sigma_tau3: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.gap is None:
            self.gap = ~np.asarray(self.valid, dtype=bool)

    @property
    def n_samples(self) -> int:
        return int(self.t.shape[0])

    def slice(self, i0: int, i1: int) -> "ConditionedSignals":
        """Samples ``i0:i1`` (time kept as it is; the filters ran on the whole recording, so a piece has no new
        edge transients)."""
        sl = slice(i0, i1)
        return ConditionedSignals(self.t[sl], self.q[sl], self.qd[sl], self.qdd[sl], self.tau[sl], self.valid[sl],
                                  self.rate_hz, self.cutoff_hz, self.sigma_q, self.sigma_q_dof, self.sigma_qd,
                                  self.sigma_qdd,
                                  self.velocity_source, self.auto_cutoff, self.tau_gain, list(self.notes), None,
                                  self.gap[sl], self.sigma_tau, self.sigma_tau3)

    def motion(self, tau: np.ndarray | None = None) -> MotionSignals:
        """The conditioned motion as the effect library's :class:`MotionSignals` (``tau`` defaults to the conditioned
        measured torque)."""
        return MotionSignals(self.t, self.q, self.qd, self.qdd, self.tau if tau is None else tau)

    def as_recording(self) -> Recording:
        """A Recording on the uniform grid whose ``qd``/``qdd`` are the conditioned estimates (``meta.conditioned``
        records how), for stages that take Recordings; truth channels and ``f_ext`` are resampled alongside."""
        src = self.source
        meta = dict(src.meta) if src is not None else {}
        meta.update(conditioned=self.summary(), rate_hz=self.rate_hz)
        extra: dict[str, Any] = {}
        if src is not None:
            t_src = src.t - src.t[0]
            if src.f_ext is not None:
                extra["f_ext"] = resample(t_src, src.f_ext, self.t)
            extra["truth"] = {k: resample(t_src, v, self.t) if np.issubdtype(v.dtype, np.floating) else v
                              for k, v in src.truth.items() if v.shape[:1] == src.t.shape}
        return Recording(t=self.t, q=self.q, tau=self.tau, qd=self.qd, qdd=self.qdd, meta=meta, **extra)

    def summary(self) -> dict[str, Any]:
        return {"rate_hz": self.rate_hz, "cutoff_hz": [float(x) for x in self.cutoff_hz],
                "auto_cutoff": self.auto_cutoff, "velocity_source": self.velocity_source,
                "sigma_qd": [float(x) for x in self.sigma_qd], "sigma_qdd": [float(x) for x in self.sigma_qdd],
                "invalid_samples": int((~self.valid).sum()), "gap_samples": int(self.gap.sum()),
                "notes": list(self.notes), "line": self.describe()}

    def describe(self) -> str:
        """One line for every output: time base, cutoffs (and whether chosen from the noise floor), q̇ source and the
        estimated derivative errors."""
        fc = ", ".join(f"{x:.3g}" for x in self.cutoff_hz)
        parts = [f"{self.rate_hz:.4g} Hz uniform grid" + (f" ({'; '.join(self.notes)})" if self.notes else ""),
                 f"zero-phase low-pass cutoff [{fc}] Hz ({'auto: noise floor' if self.auto_cutoff else 'config'})",
                 f"q̇ from {self.velocity_source}, q̈ by central differences",
                 f"est. error σ(q̇) ≤ {self.sigma_qd.max():.2g} rad/s, σ(q̈) ≤ {self.sigma_qdd.max():.2g} rad/s²"]
        return "conditioning: " + "; ".join(parts)


# ---- filtering ----------------------------------------------------------------------------------------------------

def zero_phase_lowpass(x: np.ndarray, rate_hz: float, cutoff_hz: float | np.ndarray, order: int = 2,
                       edge_cycles: float = 3.0) -> np.ndarray:
    """Butterworth low-pass of ``x [N, n]`` forward and backward (zero phase, ``sosfiltfilt``), one cutoff [Hz] per
    column or one for all, padded by odd extension over ``edge_cycles`` periods of the cutoff."""
    x = np.asarray(x, dtype=float)
    cut = np.broadcast_to(np.asarray(cutoff_hz, dtype=float), x.shape[1:2] or (1,))
    nyq = 0.5 * rate_hz
    if np.any(cut <= 0) or np.any(cut >= nyq):
        raise ValueError(f"cutoff {cut} Hz must lie in (0, {nyq:.6g}) Hz, the Nyquist frequency of {rate_hz:.6g} Hz")
    out = np.empty_like(x)
    for c in np.unique(cut):                                   # one filter per distinct cutoff, not per column
        cols = np.flatnonzero(cut == c) if x.ndim > 1 else slice(None)
        sos = scipy.signal.butter(order, c, fs=rate_hz, output="sos")
        pad = min(x.shape[0] - 1, int(np.ceil(edge_cycles * rate_hz / c)))
        out[..., cols] = scipy.signal.sosfiltfilt(sos, x[..., cols], axis=0, padlen=pad)
    return out


def _chain_gains(rate_hz: float, cutoff: float, order: int, edge_cycles: float) -> tuple[float, float, float]:
    """Noise gains (sum of squared impulse responses) of the chain q → low-pass → (q, d/dt, d²/dt²)."""
    h = 1.0 / rate_hz
    m = int(np.ceil(16 * rate_hz / cutoff)) | 1
    delta = np.zeros((2 * m + 1, 1))
    delta[m] = 1.0
    lp = zero_phase_lowpass(delta, rate_hz, cutoff, order, edge_cycles)
    d1 = np.gradient(lp, h, axis=0)
    d2 = np.gradient(d1, h, axis=0)
    return float((lp ** 2).sum()), float((d1 ** 2).sum()), float((d2 ** 2).sum())


# ---- the path ----------------------------------------------------------------------------------------------------

def _time_base(rec: Recording, t_u: np.ndarray, h: float, config: ConditioningConfig, notes: list[str]
               ) -> np.ndarray:
    """The instants [s, from 0] the samples were taken at (module docstring, step 1); notes which was used."""
    t = rec.t - rec.t[0]
    if config.time_base == "stamps" or t_u is t or np.array_equal(t_u, t):   # no jitter: stamps and clock agree
        return t
    clock = clock_stamps(t, h)
    if clock is None:
        if config.time_base == "clock":
            raise RecordingError("recording: conditioning.time_base = 'clock' but two stamps round to the same "
                                 f"tick of the {1e3 * h:.4g} ms clock; use 'stamps'")
        return t
    if config.time_base == "auto" and rec.n_samples >= 64:
        floor_stamps = white_floor(rec.q, 1.0 / h, t)
        floor_clock = white_floor(rec.q, 1.0 / h, clock)
        dof = noise_floor_dof(rec.n_samples)
        if not np.sum(floor_clock) < np.sum(floor_stamps) * stats.chi2.ppf(CLOCK_ALPHA, dof) / dof:
            return t
    elif config.time_base == "auto":
        return t
    notes.append("samples placed on the regular clock (stamps: receive-time jitter)")
    return clock


def condition(rec: Recording, config: ConditioningConfig = ConditioningConfig()) -> ConditionedSignals:
    """Condition one Recording (module docstring). Raises :class:`RecordingError` naming the problem when the
    Recording is too short for its filter or lacks a q̇ that ``velocity: measured`` requires."""
    config.check()
    n = rec.n_joints
    t_u, valid, h, notes = uniform_time_base(rec.t, config.max_gap_s)
    rate = 1.0 / h
    t_src = _time_base(rec, t_u, h, config, notes)
    dup = rec.meta.get("duplicate_stamps")
    if isinstance(dup, dict) and dup.get("stamps"):
        notes.append(f"{dup['stamps']} duplicated stamps ({dup.get('samples', '?')} rows) merged at import")
    q = resample(t_src, rec.q, t_u)
    tau = resample(t_src, rec.tau, t_u)
    if config.velocity == "measured" and rec.qd is None:
        raise RecordingError("recording: conditioning.velocity = 'measured' but the Recording has no 'qd' channel")
    use_qd = rec.qd is not None and config.velocity in ("auto", "measured")
    if config.cutoff_hz == "auto" and q.shape[0] < 64:
        raise RecordingError(f"recording: {q.shape[0]} samples are too few to estimate the noise floor "
                             "(conditioning.cutoff_hz = auto needs ≥ 64); give cutoff_hz explicitly")
    # the spectra once: the auto cutoff, the noise σ of q and the derivatives' lost signal all read them
    spec = spectra(rec.q, rate, t_src, config.max_motion_hz) if q.shape[0] >= 64 else None
    if config.cutoff_hz == "auto":
        cutoff, sigma_q = cutoff_of_spectra(spec, rate, config.min_cutoff_hz, config.max_cutoff_fraction,
                                            config.order, config.max_motion_hz)
    else:
        cutoff = np.broadcast_to(np.asarray(config.cutoff_hz, dtype=float), (n,)).copy()
        sigma_q = cutoff_of_spectra(spec, rate)[1] if spec is not None else np.zeros(n)
    if np.any(cutoff >= 0.5 * rate):
        raise RecordingError(f"recording: cutoff {cutoff.max():g} Hz is not below the Nyquist frequency "
                             f"{0.5 * rate:.6g} Hz of its {rate:.6g} Hz time base")
    lost = [lost_power(spec, cutoff, p, config.order) if spec is not None else np.zeros(n) for p in (1, 2)]
    qd_raw = resample(t_src, rec.qd, t_u) if use_qd else None
    m = decimation_factor(rate, cutoff, config.max_motion_hz, config.oversampling) \
        if config.decimate and q.shape[0] >= 64 else 1
    if m > 1:
        q, tau = decimate(q, m), decimate(tau, m)
        qd_raw = decimate(qd_raw, m) if use_qd else None
        valid = decimate_valid(valid, m)
        t_u = t_u[::m][:q.shape[0]]
        h, rate = h * m, rate / m
        notes.append(f"decimated ×{m} to {rate:.4g} Hz (motion band ≤ {max(cutoff.max(), config.max_motion_hz):.3g}"
                     " Hz)")
    need = int(np.ceil(3 * (config.order + 1))) + 1
    longest = int(np.ceil(rate / cutoff.min())) + 1
    if q.shape[0] < max(need, longest):
        raise RecordingError(f"recording: {q.shape[0]} samples ({q.shape[0] * h:.3g} s) are shorter than one period "
                             f"of the {cutoff.min():.3g} Hz cutoff; the derivative filter needs ≥ {max(need, longest)}")
    lp = lambda x: zero_phase_lowpass(x, rate, cutoff, config.order, config.edge_cycles)  # noqa: E731
    q_f = lp(q)
    gains = np.array([_chain_gains(rate, c, config.order, config.edge_cycles) for c in cutoff])     # [n, 3]
    sigma_grid = sigma_q ** 2 / m              # white noise keeps its density: σ² ∝ rate (step 2, decimation)
    qd = np.gradient(q_f, h, axis=0)
    velocity_source = "q"
    if use_qd:
        qd_robot = lp(qd_raw)
        better, why = (True, "") if config.velocity == "measured" else _robot_velocity_better(
            qd_robot, qd, h, tau_white_level(rec.qd) ** 2 / m * gains[:, 0], sigma_grid * gains[:, 1])
        if better:
            qd, velocity_source = qd_robot, "the robot's q̇ (low-passed)" + (f"; {why}" if why else "")
        else:
            velocity_source = f"q ({why})"
    qdd = np.gradient(qd, h, axis=0)
    gap = ~valid
    valid = _settled(gap, rate / float(cutoff.min()), int(np.ceil(config.edge_cycles * rate / float(cutoff.min()))),
                     notes)
    sigma_qd = np.sqrt(sigma_grid * gains[:, 1] + lost[0] ** 2)
    sigma_qdd = np.sqrt(sigma_grid * gains[:, 2] + lost[1] ** 2)
    tau_gain = (gains[:, 0] if config.tau_filter else np.ones(n)) / m
    return ConditionedSignals(t=t_u, q=q_f, qd=qd, qdd=qdd, tau=lp(tau) if config.tau_filter else tau, valid=valid,
                              rate_hz=rate, cutoff_hz=cutoff, sigma_q=sigma_q,
                              sigma_q_dof=noise_floor_dof(rec.n_samples) if rec.n_samples >= 64 else 0.0,
                              sigma_qd=sigma_qd,
                              sigma_qdd=sigma_qdd, velocity_source=velocity_source,
                              auto_cutoff=config.cutoff_hz == "auto",
                              tau_gain=tau_gain, notes=notes, source=rec, gap=gap,
                              sigma_tau=tau_white_level(rec.tau), sigma_tau3=tau_white_level(rec.tau, 3))


def _robot_velocity_better(qd_robot: np.ndarray, qd_q: np.ndarray, h: float, noise_robot: np.ndarray,
                           noise_q: np.ndarray) -> tuple[bool, str]:
    """Whether the robot's own low-passed q̇ ``[N, n]`` rad/s is better than ``d/dt`` of the low-passed q (``velocity:
    auto``), and why: it must not lag (the median over joints of the least-squares delay ``δ`` of
    ``q̇_robot(t) ≈ q̇_q(t − δ) ≈ q̇_q − δ q̈_q``, within half a step ``h`` [s]) and its white noise after the filter
    (``noise_robot [n]``, (rad/s)²) must not exceed that of the derivative (``noise_q [n]``) on average."""
    edge = slice(len(qd_q) // 20, len(qd_q) - len(qd_q) // 20)     # away from the filter's ends
    slope = np.gradient(qd_q, h, axis=0)[edge]
    lag = float(np.median(np.sum((qd_q[edge] - qd_robot[edge]) * slope, axis=0)
                          / np.maximum(np.sum(slope ** 2, axis=0), 1e-300)))
    if abs(lag) > 0.5 * h:
        return False, f"the robot's q̇ {'lags' if lag > 0 else 'leads'} by {1e3 * abs(lag):.2g} ms"
    if float(np.mean(noise_robot)) > float(np.mean(noise_q)):
        return False, "the robot's q̇ is noisier than d/dt q"
    return True, "no lag, no more noise than d/dt q"


def _settled(gap: np.ndarray, period: float, reach: int, notes: list[str]) -> np.ndarray:
    """``valid [N]``: not in a gap, nor within ``reach`` samples of a gap lasting at least ``period`` samples (one
    period of the lowest cutoff). Inside a shorter gap the spline follows the band the filters pass, so its fill is
    as good as a sample; across a longer one it is guesswork, which the zero-phase filters spread ``edge_cycles``
    periods to either side (module docstring, step 1)."""
    if not gap.any():
        return ~gap
    edges = np.flatnonzero(np.diff(np.r_[0, gap.astype(np.int8), 0]))
    starts, ends = edges[::2], edges[1::2]                         # gap runs gap[starts[k]:ends[k]]
    long_ = (ends - starts) >= period
    if not long_.any():
        return ~gap
    mark = np.zeros(gap.size + 1, dtype=int)
    np.add.at(mark, np.maximum(starts[long_] - reach, 0), 1)
    np.add.at(mark, np.minimum(ends[long_] + reach, gap.size), -1)
    valid = ~gap & (np.cumsum(mark[:-1]) == 0)
    notes.append(f"{int((~valid).sum() - gap.sum())} samples beside {int(long_.sum())} gap(s) longer than a cutoff "
                 f"period flagged too (the filters' reach, {reach} samples)")
    return valid


def processing_torque_sigma(torque: Any, signals: Sequence[ConditionedSignals], samples: int = 2000,
                            seed: int = 0) -> np.ndarray:
    """Per-joint σ [N·m] of the torque error the conditioning itself causes: ``torque(q, q̇, q̈) -> τ [N,n]`` evaluated
    with q̇, q̈ perturbed by their estimated errors (Gaussian, seeded) minus the unperturbed value, on up to
    ``samples`` samples spread over the recordings."""
    rng = np.random.default_rng(seed)
    q, qd, qdd, sd, sdd = [], [], [], [], []
    per = max(1, samples // max(len(signals), 1))
    for s in signals:
        idx = np.linspace(0, s.n_samples - 1, min(per, s.n_samples)).astype(int)
        q.append(s.q[idx]), qd.append(s.qd[idx]), qdd.append(s.qdd[idx])
        sd.append(np.broadcast_to(s.sigma_qd, (idx.size, s.q.shape[1])))
        sdd.append(np.broadcast_to(s.sigma_qdd, (idx.size, s.q.shape[1])))
    q, qd, qdd, sd, sdd = (np.concatenate(x) for x in (q, qd, qdd, sd, sdd))
    d = torque(q, qd + sd * rng.standard_normal(qd.shape), qdd + sdd * rng.standard_normal(qdd.shape)) \
        - torque(q, qd, qdd)
    return np.sqrt(np.mean(d ** 2, axis=0))
