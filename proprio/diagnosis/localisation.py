"""Where does the sim-to-real torque gap live? (DESIGN.md "Gap diagnosis", step 2.)

Given the residual ``e = τ_meas − τ_sim`` [N·m] of one or more Recordings, this module breaks the squared error
down by joint × motion regime and by frequency:

* **motion regimes** (each family partitions the samples, so a family's cells add up to the joint's share):
  joint speed ``|q̇_j|`` as a fraction of the joint's velocity limit; travel since the joint's last reversal
  ``|r_j|`` (the first degree after a reversal is the lost-motion / hysteresis window of §2.1); reach vs.
  exploration segments (from ``truth['segment']`` / ``meta['segments']`` when the Recording has them, else by
  speed); configuration region (joint position tercile of its range); payload (``meta['payload']`` mass);
* **frequency**: the Welch power spectrum of ``e`` in time [Hz] and an *order spectrum* — the periodogram of ``e``
  against the joint angle (``e`` resampled onto ``q`` by a Lomb–Scargle fit over the moving samples), which puts a
  ripple locked to the joint angle at a fixed order [cycles/rev] whatever the speed.

The *gap map* is the share of the total (all joints, all samples) squared error held by each joint × regime cell;
:func:`proprio.plots.gap.plot_gap_map` draws it as a heat map.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from scipy import signal

from proprio.diagnosis.data import Conditioned, SimModel, session_motion
from proprio.reversals import reversal_travel

__all__ = ["RegimeFamily", "GapMap", "Spectra", "Localisation", "regime_families", "gap_map", "spectra", "localise",
           "order_spectrum", "peak_orders"]

REVERSAL_WINDOW_RAD = np.radians(1.0)       # lost-motion window after a reversal (§2.1)
REVERSAL_DEADBAND = 1e-3                     # rad/s: |q̇| below this never counts as a direction change
HYSTERESIS_SATURATION_RAD = np.radians(6.0)  # hysteresis saturates after ≈6° of travel (§2.1, Fig. 2.5)
SPEED_EDGES = (0.0, 0.02, 0.10, 0.30, 0.60, np.inf)   # |q̇| / velocity limit
REACH_SPEED_FRACTION = 0.35                 # reach segments run at 60–90 %, exploration at 10–30 % (Table 2.3)


@dataclass(frozen=True)
class RegimeFamily:
    """One way of partitioning the samples: ``labels [N,n]`` integer bin per sample and joint (a sample-wide
    family repeats its label over the joints); ``names`` the bin names."""
    name: str
    names: tuple[str, ...]
    labels: np.ndarray


def _segment_labels(rec, qd: np.ndarray, vlim: np.ndarray) -> np.ndarray:
    """1 = reach, 0 = exploration, per sample: from the Recording's own segment labels when present, else by
    speed (any joint above ``REACH_SPEED_FRACTION`` of its limit, smoothed over 0.5 s)."""
    if rec is not None and "segment" in rec.truth:
        return (np.asarray(rec.truth["segment"]).reshape(len(qd), -1)[:, 0] > 0.5).astype(int)
    if rec is not None and isinstance(rec.meta.get("segments"), list):
        lab = np.zeros(len(qd), dtype=int)
        t = rec.t
        for seg in rec.meta["segments"]:
            if isinstance(seg, dict) and seg.get("kind") == "reach":
                lab[(t >= seg.get("t0", np.inf)) & (t < seg.get("t1", -np.inf))] = 1
        return lab
    fast = (np.abs(qd) / vlim).max(axis=1) > REACH_SPEED_FRACTION
    if rec is not None and len(qd) > 3:
        width = max(1, int(0.5 * rec.rate_hz))
        fast = np.convolve(fast.astype(float), np.ones(width) / width, mode="same") > 0.5
    return fast.astype(int)


def regime_families(q: np.ndarray, qd: np.ndarray, lower: np.ndarray, upper: np.ndarray, vlim: np.ndarray,
                    rec=None) -> list[RegimeFamily]:
    """The motion-regime partitions of one Recording's samples (see the module docstring)."""
    n_s, n = q.shape
    speed = np.abs(qd) / vlim
    sp = np.clip(np.digitize(speed, SPEED_EDGES[1:-1]), 0, len(SPEED_EDGES) - 2)
    sp_names = tuple(f"speed {100 * a:.0f}–{100 * b:.0f}%" if np.isfinite(b) else f"speed >{100 * a:.0f}%"
                     for a, b in zip(SPEED_EDGES[:-1], SPEED_EDGES[1:]))
    r = np.abs(reversal_travel(q, qd, REVERSAL_DEADBAND).r)
    rb = np.digitize(r, [REVERSAL_WINDOW_RAD, HYSTERESIS_SATURATION_RAD])
    seg = np.repeat(_segment_labels(rec, qd, vlim)[:, None], n, axis=1)
    pos = (q - lower) / np.maximum(upper - lower, 1e-9)
    cfg = np.clip(np.digitize(pos, [1 / 3, 2 / 3]), 0, 2)
    payload = rec.meta.get("payload") if rec is not None else None
    mass = float(payload.get("mass", 0.0)) if isinstance(payload, dict) else 0.0
    pay_name = f"payload {mass:g} kg" if mass > 0 else "no payload"
    return [
        RegimeFamily("speed", sp_names, sp),
        RegimeFamily("travel since reversal", ("|r|<1° (reversal window)", "|r| 1–6°", "|r|>6°"), rb),
        RegimeFamily("segment", ("exploration", "reach"), seg),
        RegimeFamily("configuration", ("q low third", "q mid third", "q high third"), cfg),
        RegimeFamily("payload", (pay_name,), np.zeros((n_s, n), dtype=int)),
    ]


@dataclass
class GapMap:
    """Share of the total squared residual per joint × regime cell.

    ``columns`` are ``(family, bin)`` pairs; ``share [n, C]`` sums to the joint's share of the total within every
    family; ``concentration [n, C]`` is the cell's mean square over the joint's mean square (> 1: the error
    concentrates there); ``count [n, C]`` samples per cell; ``rmse [n]`` N·m and ``signal_rms [n]`` N·m per joint."""
    joint_names: list[str]
    columns: list[tuple[str, str]]
    share: np.ndarray
    concentration: np.ndarray
    count: np.ndarray
    rmse: np.ndarray
    signal_rms: np.ndarray

    def table(self, min_share: float = 0.0) -> str:
        """A Markdown table of the shares [%] (columns whose largest share is below ``min_share`` dropped)."""
        keep = [c for c in range(len(self.columns)) if self.share[:, c].max() >= min_share]
        head = "| joint | RMSE [N·m] | % of signal | " + " | ".join(f"{f}: {b}".replace("|", "\\|") for f, b in
                                                                   (self.columns[c] for c in keep)) + " |"
        rows = [head, "|" + "---|" * (3 + len(keep))]
        for j, name in enumerate(self.joint_names):
            pct = 100 * self.rmse[j] / max(self.signal_rms[j], 1e-12)
            cells = " | ".join(f"{100 * self.share[j, c]:.1f}" for c in keep)
            rows.append(f"| {name} | {self.rmse[j]:.3f} | {pct:.1f} | {cells} |")
        return "\n".join(rows)

    def hotspots(self, k: int = 5) -> list[tuple[str, str, str, float, float]]:
        """The ``k`` cells holding the largest share among those where the error concentrates (ratio > 1):
        ``(joint, family, bin, share, concentration)``."""
        fams = [f for f, _ in self.columns]
        out = []
        for j in range(len(self.joint_names)):
            for c, (f, b) in enumerate(self.columns):
                if fams.count(f) > 1 and self.concentration[j, c] > 1.0:
                    out.append((self.joint_names[j], f, b, float(self.share[j, c]), float(self.concentration[j, c])))
        return sorted(out, key=lambda x: -x[3] * x[4])[:k]


def gap_map(residuals: Sequence[np.ndarray], families: Sequence[list[RegimeFamily]], tau: Sequence[np.ndarray],
            joint_names: list[str]) -> GapMap:
    """Aggregate the per-recording residuals ``e [N_k,n]`` over their regime families (same family/bin layout in
    every recording, except the payload family whose bins are merged by name) into a :class:`GapMap`."""
    n = residuals[0].shape[1]
    columns: list[tuple[str, str]] = []
    for fams in families:
        for fam in fams:
            for b in fam.names:
                if (fam.name, b) not in columns:
                    columns.append((fam.name, b))
    sq = np.zeros((n, len(columns)))
    cnt = np.zeros((n, len(columns)))
    for e, fams in zip(residuals, families):
        e2 = e ** 2
        for fam in fams:
            for k, b in enumerate(fam.names):
                c = columns.index((fam.name, b))
                m = fam.labels == k
                sq[:, c] += (e2 * m).sum(axis=0)
                cnt[:, c] += m.sum(axis=0)
    e_all = np.concatenate(residuals)
    total = float((e_all ** 2).sum())
    joint_ms = (e_all ** 2).mean(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        conc = np.where(cnt > 0, sq / np.maximum(cnt, 1) / np.maximum(joint_ms[:, None], 1e-300), 0.0)
    sig = np.sqrt((np.concatenate(tau) ** 2).mean(axis=0))
    return GapMap(list(joint_names), columns, sq / max(total, 1e-300), conc, cnt, np.sqrt(joint_ms), sig)


@dataclass
class Spectra:
    """Frequency content of the residual per joint.

    ``freq [F]`` Hz and ``psd [F,n]`` (N·m)²/Hz: Welch spectrum over all recordings (averaged);
    ``orders [K]`` cycles/rev and ``order_power [K,n]`` (N·m)²: amplitude² of the best sinusoid of the joint angle
    at each order (Lomb–Scargle of e against q over the samples where the joint moves); ``peak_order [n]``,
    ``peak_order_share [n]``: the strongest order and the share of the moving-sample variance it explains;
    ``dominant_hz [n]``: the strongest *peak* of the Welch spectrum (NaN: none — see :func:`spectral_peaks`) and
    ``resolution_hz`` its bin width."""
    freq: np.ndarray
    psd: np.ndarray
    orders: np.ndarray
    order_power: np.ndarray
    peak_order: np.ndarray
    peak_order_share: np.ndarray
    dominant_hz: np.ndarray = field(default_factory=lambda: np.zeros(0))
    resolution_hz: float = float("nan")


SEGMENT_S = 2.0
"""Welch segment length [s] (rounded up to a power of two of samples): a 0.5 Hz resolution, fine enough for the
motion's own frequencies (the first bins of a 256-sample segment at 5 kHz are 19.5 Hz wide: every residual's
"dominant frequency" was that first bin)."""


def spectral_peaks(freq: np.ndarray, psd: np.ndarray, dof: float, alpha: float = 0.01, half_width: int = 8
                   ) -> np.ndarray:
    """The frequency [Hz] of the strongest peak per joint of a Welch spectrum ``psd [F,n]``, NaN where none: a bin
    is a peak when it is a local maximum, not one of the two lowest bins (DC and the first bin hold the detrended
    level and the window's leakage of the slow motion, never a peak) and above the median of ``half_width`` bins on
    *each* side (the larger of the two: a falling spectrum's bin is no peak against its left neighbours) by more
    than the χ² quantile of an estimate with ``dof`` degrees of freedom at ``1 − α/F`` (Bonferroni over the bins).
    ``dof``: the number of Welch segments — half the nominal 2 per segment, for the 50 % overlap and the noise of
    the neighbours' median (on white noise with a random walk: no false peak in 80 spectra; 2 per segment: 3)."""
    from numpy.lib.stride_tricks import sliding_window_view
    from scipy import stats

    n_f, n = psd.shape
    out = np.full(n, np.nan)
    if n_f < 5:
        return out
    h = half_width
    pad = np.concatenate([np.full((h, n), np.nan), psd, np.full((h, n), np.nan)])
    win = sliding_window_view(pad, h, axis=0)                       # win[i] = pad[i:i+h]
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)               # all-NaN windows at the edges
        left = np.nanmedian(win[:n_f], axis=-1)                      # psd[k-h:k]
        right = np.nanmedian(win[h + 1:h + 1 + n_f], axis=-1)        # psd[k+1:k+h+1]
    left[:2] = np.inf
    base = np.fmax(left, right)
    thr = stats.chi2.ppf(1 - alpha / n_f, dof) / dof
    local = np.zeros_like(psd, dtype=bool)
    local[1:-1] = (psd[1:-1] > psd[:-2]) & (psd[1:-1] >= psd[2:])
    ok = local & (psd > thr * base)
    ok[:2] = False
    for j in range(n):
        k = np.flatnonzero(ok[:, j])
        if len(k):
            out[j] = freq[k[np.argmax(psd[k, j])]]
    return out


def order_spectrum(e: np.ndarray, q: np.ndarray, qd: np.ndarray, orders: np.ndarray,
                   min_speed: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Order spectrum of one joint: amplitude² [(N·m)²] of the best fit ``a sin(k q) + b cos(k q)`` for each order
    ``k`` [cycles/rev] in ``orders``, over the samples where ``|q̇| > min_speed`` (the residual resampled onto the
    joint angle — Lomb–Scargle with the angle as the abscissa). Returns ``(power [K], variance of e there)``."""
    m = np.abs(qd) > min_speed
    if m.sum() < 20:
        return np.zeros(len(orders)), 0.0
    x, y = q[m], e[m] - e[m].mean()
    return _lombscargle(x, y, np.asarray(orders, dtype=float)) * 4.0 / len(y), float(np.var(y))


def _lombscargle(x: np.ndarray, y: np.ndarray, freqs: np.ndarray) -> np.ndarray:
    """``scipy.signal.lombscargle(x, y, freqs, normalize=False)`` (no floating mean) in ``O(N·K)`` flops without its
    ``[N, K]`` temporaries (gigabytes for a long log). From the two sums ``Y₁(ω) = mean y e^{iωx}`` and ``Z₂(ω) =
    mean e^{2iωx}``: ``τ = arg Z₂ / 2``, ``YC + i·YS = Y₁ e^{−iτ}``, ``CC = (1 + |Z₂|)/2``, ``SS = 1 − CC`` and the
    power ``N/2 · (YC²/CC + YS²/SS)`` — Lomb–Scargle's own formulas. On a uniform grid of ``freqs`` (every caller's)
    the sums are complex matrix products (:func:`_fourier_sums`)."""
    steps = np.diff(freqs)
    if freqs.size < 2 or not np.allclose(steps, steps[0], rtol=1e-9, atol=0.0):
        return signal.lombscargle(x, y, freqs, normalize=False)
    y1 = _fourier_sums(x, y, freqs[0], steps[0], freqs.size)
    z2 = _fourier_sums(2.0 * x, np.ones_like(y), freqs[0], steps[0], freqs.size)
    yt = y1 * np.exp(-0.5j * np.angle(z2))
    tiny = np.finfo(float).epsneg
    cc = np.maximum(0.5 * (1.0 + np.abs(z2)), tiny)
    ss = np.maximum(1.0 - cc, tiny)
    return 0.5 * x.size * (yt.real ** 2 / cc + yt.imag ** 2 / ss)


def _fourier_sums(x: np.ndarray, y: np.ndarray, f0: float, df: float, k: int, chunk: int = 8192) -> np.ndarray:
    """``mean_n y_n e^{i (f0 + m·df) x_n}`` for ``m = 0 … k−1``: with ``B ≈ √k`` and ``ω = f0 + b·B·df + j·df``
    the sum is ``Σ_n (y_n e^{i(f0 + bB·df)x_n}) · e^{ij·df·x_n}``, one ``[b, n] × [n, j]`` product per chunk of
    samples; both factors are running products of one exponential each (``e^{iB·df·x}``, ``e^{i·df·x}``), a
    rounding error of ≈ √k ulp."""
    block = max(1, int(np.ceil(np.sqrt(k))))
    n_blocks = -(-k // block)
    out = np.zeros(n_blocks * block, dtype=complex)
    for c in range(0, x.size, chunk):                       # chunks of samples bound the temporaries
        xc = x[c:c + chunk]
        a = np.empty((xc.size, n_blocks), dtype=complex)
        a[:, 0] = y[c:c + chunk] * np.exp(1j * f0 * xc)
        a[:, 1:] = np.exp(1j * block * df * xc)[:, None]
        w = np.empty((xc.size, block), dtype=complex)
        w[:, 0] = 1.0
        w[:, 1:] = np.exp(1j * df * xc)[:, None]
        out += (np.cumprod(a, axis=1).T @ np.cumprod(w, axis=1)).reshape(-1)
    return out[:k] / x.size


def peak_orders(e: np.ndarray, q: np.ndarray, qd: np.ndarray, max_order: float = 400.0,
                min_speed: float = 0.05, min_order: float = 1.0) -> np.ndarray:
    """Per joint, the order [cycles/rev] of the strongest angle-locked sinusoid in ``e`` (coarse grid of 0.5, then
    refined to 0.005 around the peak; the peak of a long sweep is located far more finely than its width)."""
    n = e.shape[1]
    coarse = np.arange(min_order, max_order + 0.5, 0.5)
    out = np.full(n, 2.0 * 160.0)
    sub = slice(None, None, max(1, len(e) // 3000))
    for j in range(n):
        pw, _ = order_spectrum(e[sub, j], q[sub, j], qd[sub, j], coarse, min_speed)
        if not pw.any():
            continue
        k0 = coarse[int(np.argmax(pw))]
        fine = np.arange(max(0.5, k0 - 1.0), k0 + 1.0, 0.005)
        pf, _ = order_spectrum(e[sub, j], q[sub, j], qd[sub, j], fine, min_speed)
        out[j] = fine[int(np.argmax(pf))]
    return out


def spectra(residuals: Sequence[np.ndarray], qs: Sequence[np.ndarray], qds: Sequence[np.ndarray], rate_hz: float,
            max_order: float = 400.0, min_speed: float = 0.05) -> Spectra:
    """Welch spectrum of e and its order spectrum against each joint's angle (see :class:`Spectra`).

    The order spectrum uses the samples with ``|q̇| > min_speed`` rad/s; orders from 1 to ``max_order``
    cycles/rev in steps fine enough to resolve the swept angle (1/(4·span) cycles/rad)."""
    n = residuals[0].shape[1]
    nper = int(min(2 ** int(np.ceil(np.log2(max(SEGMENT_S * rate_hz, 8.0)))), min(len(e) for e in residuals)))
    psds, segments = [], 0
    for e in residuals:
        f, p = signal.welch(e, fs=rate_hz, nperseg=nper, axis=0, detrend="constant")
        psds.append(p)
        segments += max(1, 2 * len(e) // nper - 1)                  # 50 % overlap (scipy's default)
    psd = np.mean(psds, axis=0)
    dominant = spectral_peaks(f, psd, dof=float(segments))
    e_all, q_all, qd_all = (np.concatenate(x) for x in (residuals, qs, qds))
    orders = np.arange(1.0, max_order + 0.25, 0.25)
    power = np.zeros((len(orders), n))
    peak, share = np.zeros(n), np.zeros(n)
    for j in range(n):
        pw, var = order_spectrum(e_all[:, j], q_all[:, j], qd_all[:, j], orders, min_speed)
        power[:, j] = pw
        if pw.any():
            k = int(np.argmax(pw))
            peak[j] = orders[k]
            share[j] = 0.5 * pw[k] / max(var, 1e-300)
    return Spectra(f, psd, orders, power, peak, np.clip(share, 0.0, 1.0), dominant, float(f[1] - f[0]))


@dataclass(frozen=True)
class Localisation:
    """*Where* the gap lies, before any effect is fitted: the gap map by joint × motion regime and the residual's
    frequency content, over all recordings (training and held-out)."""
    gap_map: GapMap
    spectra: Spectra


def localise(model: SimModel, data: Conditioned) -> Localisation:
    """The model residual ``e = τ_meas − τ_sim`` of every conditioned recording of ``data`` at its kept samples,
    mapped by joint × regime (:func:`gap_map`) and by frequency (:func:`spectra`, at the recordings' median rate)."""
    es, fams, taus, qs, qds = [], [], [], [], []
    rob = model.robot
    for cs, t0, keep in zip(data.signals, data.sessions, data.keep):
        rec, s = cs.as_recording(), session_motion(cs, t0)
        e = (rec.tau - model.predict(s))[keep]
        fam = regime_families(s.q, s.qd, rob.lower, rob.upper, rob.velocity_limits, rec)
        fams.append([type(f)(f.name, f.names, f.labels[keep]) for f in fam])
        es.append(e)
        taus.append(rec.tau[keep])
        qs.append(s.q[keep])
        qds.append(s.qd[keep])
    rate = float(np.median([r.rate_hz for r in data.recordings]))
    return Localisation(gap_map(es, fams, taus, rob.joint_names), spectra(es, qs, qds, rate))
