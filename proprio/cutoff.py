"""The motion's band in a log of encoder ``q``: the white-noise floor, the per-joint low-pass cutoff that minimises
the error of ``q̈``, the error the cutoff leaves, and the decimation of a log sampled far faster than the arm moves
(step 2 of :mod:`proprio.conditioning`, which applies them).

**Cutoff per joint** (:func:`auto_cutoff`). The Welch spectrum ``P_q(f)`` of each joint's ``Δ²q`` and its
white-noise floor ``P_0`` (mean over the upper half of the band: encoder noise and quantisation) give the estimated
error of ``q̈`` for a cutoff ``f_c``: the signal the filter's magnitude ``G`` removes, ``∫ (2πf)⁴ (P_q − P_0)⁺
(1 − G)²``, plus the noise it passes, ``∫ (2πf)⁴ P_0 G²``; the cutoff minimises the sum (a Wiener-style trade-off)
within ``[min_cutoff_hz, min(max_cutoff_fraction · rate, max_motion_hz)]``. ``max_motion_hz`` (40 Hz) is the
physical bound of a manipulator's rigid-body motion: what ``q`` holds above it (drive and structure vibration, servo
chatter of a 5 kHz log) is counted neither as motion to keep nor as motion the filter distorts, so a fast log's
cutoff and its error estimate (:func:`lost_power`) follow the arm, not its vibrations. The rule is the physics of
the error the diagnosis sees: a torque model evaluated on the conditioned motion errs by ``M(q)`` times the q̈ error,
and both parts — the motion the filter removes (a structured error the effect candidates could mistake for physics)
and the differentiated noise it passes (what the data-path candidates would then explain) — enter that error alike.
The cutoff lies where the q̈ noise density ``(2πf)⁴ P_0`` meets the motion's acceleration spectrum.

Where the samples sit at unequal stamps (a jittered or lossy log), the floor ``P_0`` is taken at the stamps, the
motion's spectrum on the uniform grid (:func:`spectra`): the three-point ``Δ²q`` at unequal steps spreads white noise
down to 0 Hz, which at a 10⁻⁴ rad floor hid the whole motion of a 1 kHz twin log and dropped its cutoff to the 1 Hz
floor (issue 39: the conditioning then made a 0.79 N·m "before" gap of a 0.21 N·m one).

**Decimation** (:func:`decimation_factor`, :func:`decimate`): when the grid rate exceeds ``oversampling ×`` the
motion band (the largest of the cutoffs and ``max_motion_hz``) by a factor ``M ≥ 2``, the signals are decimated by
``M`` behind a zero-phase polyphase FIR anti-alias filter (``scipy.signal.resample_poly``): 20 s of 5 kHz become
20 s of ≈200 Hz, and an hour of logs stays tractable. White noise of density ``P`` keeps its density: its variance
drops by ``M``.

**The τ noise level** (:func:`tau_white_level`): the white noise of a raw τ log at its own rate, robust to motion.
"""
from __future__ import annotations

import math

import numpy as np
import scipy.signal

from proprio.time_base import resample

__all__ = ["auto_cutoff", "cutoff_of_spectra", "spectra", "white_floor", "lost_power", "noise_floor_dof", "decimation_factor", "decimate",
           "decimate_valid", "tau_white_level"]


def _second_difference(q: np.ndarray, rate_hz: float, t: np.ndarray | None) -> np.ndarray:
    """``Δ²q / h²`` [rad/s²] at the samples' own stamps ``t`` (the three-point formula for unequal steps), or on the
    uniform grid of ``rate_hz`` when ``t`` is None."""
    if t is None:
        return np.diff(q, n=2, axis=0) * rate_hz ** 2
    h = np.diff(np.asarray(t, dtype=float))[:, None]
    dq = np.diff(q, axis=0) / h
    return 2.0 * np.diff(dq, axis=0) / (h[1:] + h[:-1])


def _welch_length(m: int) -> int:
    """Welch segment length of the noise-floor spectrum of ``m`` second differences: ≈ m/8, a power of two ≥ 256."""
    return int(min(m, max(256, 2 ** int(np.floor(np.log2(max(m // 8, 2)))))))


def noise_floor_dof(n_samples: int) -> float:
    """Equivalent χ² degrees of freedom ``D`` of the white floor ``P_0`` (hence of ``σ_q²``) estimated from
    ``n_samples`` samples of q (:func:`auto_cutoff`): ``D·σ̂²/σ² ~ χ²_D``, so a confidence bound of the floor follows.

    Counted from the spectral estimate itself: each Welch bin (periodic Hann, 50 % overlap, ``M`` segments) has
    ``ν = 2M / (1 + 2 Σ_k (1 − k/M) ρ_k²)`` degrees of freedom (Welch 1967; ``ρ_k`` the overlap correlation of the
    window), and the mean over the ``K`` bins of the upper half of the band counts ``K_eff = K² / Σ_{i,l} r_{|i−l|}``
    independent bins (``r_l`` the correlation of periodogram ordinates ``l`` bins apart, ``|Σ w² e^{−2πi l n/L}|²`` /
    ``(Σ w²)²``); ``D = ν · K_eff`` (≈ n/2, the bound of 2 per independent frequency of the band)."""
    m = n_samples - 2
    if m < 4:
        return 0.0
    nper = _welch_length(m)
    step = nper - nper // 2
    segs = 1 + (m - nper) // step
    w = scipy.signal.get_window("hann", nper)
    lags = np.arange(1, segs)
    rho = np.array([float(w[k * step:] @ w[:nper - k * step]) for k in lags if k * step < nper]) / float(w @ w)
    nu = 2.0 * segs / (1.0 + 2.0 * float(np.sum((1.0 - lags[:rho.size] / segs) * rho ** 2)))
    r = np.abs(np.fft.fft(w ** 2)) ** 2 / float(w @ w) ** 2          # r_l at l = 0 .. nper-1 (r_0 = 1)
    k = int(np.sum(np.fft.rfftfreq(nper) >= 0.25))                  # bins f ≥ rate/4, as in white_floor
    lag = np.abs(np.arange(k)[:, None] - np.arange(k)[None, :])
    return float(nu * k ** 2 / r[lag].sum())


def _uniform_shape(f: np.ndarray, rate_hz: float) -> np.ndarray:
    """``|Δ²/h²|²`` at ``f`` [Hz] on a uniform grid of ``rate_hz``: ``16 sin⁴(π f h) / h⁴``, the shape of white noise's
    second-difference spectrum."""
    return 16.0 * np.sin(np.pi * f / rate_hz) ** 4 * rate_hz ** 4


def _unit_noise(n_samples: int) -> np.ndarray:
    """16 channels of unit white noise ``[n_samples, 16]`` (fixed seed): the noise whose spectrum through a log's own
    stamps or resampling gives the white floor's shape there (:func:`white_floor`, :func:`spectra`)."""
    return np.random.default_rng(0).standard_normal((n_samples, 16))


def _grid_second_difference(x: np.ndarray, rate_hz: float, t: np.ndarray) -> np.ndarray:
    """``Δ²x / h²`` [per s²] on the uniform grid of ``rate_hz`` from the first stamp, ``x [N, ...]`` resampled from its
    stamps ``t`` by the cubic spline."""
    grid = t[0] + np.arange(int(np.floor((t[-1] - t[0]) * rate_hz)) + 1) / rate_hz
    return np.diff(resample(t, x, grid), n=2, axis=0) * rate_hz ** 2


def white_floor(q: np.ndarray, rate_hz: float, t: np.ndarray | None = None) -> np.ndarray:
    """The white floor ``P_0 [n]`` [rad²/Hz] of ``q`` (encoder noise and quantisation; ``σ_q² = P_0 · rate / 2``):
    from the Welch spectrum of the raw second difference ``Δ²q / h²`` at the log's own stamps ``t`` when given (a
    resampled log's interpolated stretches would hide the noise), whose white part has a known shape —
    ``16 sin⁴(π f h) / h⁴`` on a uniform grid, at unequal steps that of unit white noise at the same stamps (fixed
    seed) — as the mean of the ratio over the upper half of the band, where arm motion has no power."""
    d2 = _second_difference(q, rate_hz, t)
    nper = _welch_length(d2.shape[0])
    f, p = scipy.signal.welch(d2, fs=rate_hz, nperseg=nper, detrend="constant", axis=0)
    if t is None:
        shape = _uniform_shape(f, rate_hz)
    else:
        unit = _unit_noise(q.shape[0])
        shape = scipy.signal.welch(_second_difference(unit, rate_hz, t), fs=rate_hz, nperseg=nper,
                                   detrend="constant", axis=0)[1].mean(axis=1) / (2.0 / rate_hz)
    top = f >= 0.25 * rate_hz
    return np.mean(p[top] / shape[top, None], axis=0)              # the mean: unbiased for white noise


def spectra(q: np.ndarray, rate_hz: float, t: np.ndarray | None = None, band_hz: float = np.inf
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Frequencies ``f [F]``, the q̈ signal spectrum ``S [F,n]`` and the q̈ noise spectrum ``N [F,n]`` [(rad/s²)²/Hz],
    and the white floor of q ``P_0 [n]`` [rad²/Hz].

    The floor ``P_0``: :func:`white_floor`, at the samples' own stamps. The spectra are those of the second difference
    (pre-whitened, so the window's leakage from the large low-frequency content of q does not pose as high-frequency
    signal). The signal ``S``: from ``Δ²q / h²`` on the uniform grid (q resampled from its stamps by the cubic
    spline), whose white noise has the shape of unit white noise through the same resampling — small at low
    frequency, where the motion is (``∝ f⁴``: the spline keeps constants) — whereas the three-point formula at
    jittered stamps turns white noise into a level that reaches down to 0 Hz (its weights change from sample to
    sample) and would bury the motion of a log with a high floor (10⁻⁴ rad at 1 kHz with 0.1 ms of jitter).
    Signal is counted only below the floor's band, below ``band_hz`` (the motion's physical band) and in bins at least
    three times the floor."""
    floor = white_floor(q, rate_hz, t)
    nper = _welch_length(q.shape[0] - 2)
    welch = lambda x: scipy.signal.welch(x, fs=rate_hz, nperseg=nper, detrend="constant", axis=0)  # noqa: E731
    if t is None:
        f, p = welch(_second_difference(q, rate_hz, None))
        shape = _uniform_shape(f, rate_hz)
    else:   # the motion on the uniform grid; its noise shape from unit white noise resampled alike (fixed seed)
        unit = _unit_noise(q.shape[0])
        f, both = welch(_grid_second_difference(np.column_stack([q, unit]), rate_hz, t))
        p, shape = both[:, :q.shape[1]], both[:, q.shape[1]:].mean(axis=1) / (2.0 / rate_hz)
    noise = floor[None, :] * (2 * np.pi * f[:, None]) ** 4          # q̈ noise through ideal differentiation
    white = floor[None, :] * shape[:, None]
    clear = (p > 3.0 * white) & (f[:, None] < min(0.25 * rate_hz, band_hz))   # chance bins of noise stay below 3×
    signal = np.where(clear, p - white, 0.0)                        # only bins clearly above the floor
    return f, signal, noise, floor


def auto_cutoff(q: np.ndarray, rate_hz: float, min_hz: float = 1.0, max_fraction: float = 0.2,
                t: np.ndarray | None = None, order: int = 2, max_motion_hz: float = 40.0
                ) -> tuple[np.ndarray, np.ndarray]:
    """Per-joint cutoff [Hz] minimising the estimated q̈ error (module docstring) and the white noise σ of q
    [rad] implied by the floor (``σ² = P_0 · rate / 2``); ``q`` at its own stamps ``t`` [s] when given: the
    :func:`spectra` of ``q`` through :func:`cutoff_of_spectra`."""
    return cutoff_of_spectra(spectra(q, rate_hz, t, max_motion_hz), rate_hz, min_hz, max_fraction, order,
                             max_motion_hz)


def cutoff_of_spectra(spec: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], rate_hz: float,
                      min_hz: float = 1.0, max_fraction: float = 0.2, order: int = 2, max_motion_hz: float = 40.0
                      ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`auto_cutoff` on spectra already taken (``spec`` = :func:`spectra`'s ``f, S, N, P_0``).

    The error of a cutoff ``f_c`` uses the zero-phase Butterworth's magnitude ``G(f) = 1 / (1 + (f/f_c)^{2·order})``:
    ``Σ_f S(f) (1 − G(f))² + N(f) G(f)²`` over 120 log-spaced candidates in ``[min_hz, min(max_fraction · rate,
    max_motion_hz)]``; signal above ``max_motion_hz`` (vibration, not arm motion) is not counted."""
    f, signal, noise, floor = spec
    sigma_q = np.sqrt(floor * rate_hz / 2.0)
    hi = min(max_fraction * rate_hz, max_motion_hz)
    if hi <= min_hz:
        return np.full(signal.shape[1], hi), sigma_q
    cands = np.geomspace(min_hz, hi, 120)
    g = 1.0 / (1.0 + (f[None, :] / cands[:, None]) ** (2 * order))            # [C, F]
    err = ((1.0 - g) ** 2) @ signal + (g ** 2) @ noise                         # [C, n]
    return cands[np.argmin(err, axis=0)], sigma_q


def lost_power(spec: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], cutoff: np.ndarray, power: int,
               order: int = 2) -> np.ndarray:
    """RMS of the ``power``-th derivative's signal that the low-pass distorts: ``Σ S(f) (1 − G(f))²`` with the
    zero-phase Butterworth's magnitude ``G`` (the signal term of the cutoff's error model, step 2: it counts the
    attenuation below the cutoff as well as the signal removed above it), from :func:`spectra`'s ``spec`` (whose
    ``band_hz`` bounds the motion counted)."""
    f, signal, _, _ = spec
    s = signal * (2 * np.pi * np.maximum(f[:, None], 1e-9)) ** (2 * power - 4)
    g = 1.0 / (1.0 + (f[:, None] / cutoff[None, :]) ** (2 * order))
    return np.sqrt(np.sum(s * (1.0 - g) ** 2, axis=0) * (f[1] - f[0]))


def tau_white_level(tau: np.ndarray, order: int = 2) -> np.ndarray:
    """Per-joint σ [N·m] of the white noise of a raw τ log ``[N, n]`` at its own rate: ``1.4826 · MAD(Δ²τ) / √6``
    (the second difference of white noise has variance ``6σ²``; the median ignores the bursts of fast motion and
    reversals, and ``Δ²`` the smooth torque of the motion). The level a noise finding may claim for the sensor.

    ``order`` k: the same from ``Δᵏτ`` (white noise: variance ``C(2k, k) σ²``). White noise gives the same level at
    every order; a floor made by the motion or by a filter upstream of the log (coloured) shrinks with the order."""
    d = np.diff(np.asarray(tau, dtype=float), n=order, axis=0)
    if d.shape[0] < 1:
        return np.zeros(np.shape(tau)[1])
    return 1.4826 * np.median(np.abs(d - np.median(d, axis=0)), axis=0) / np.sqrt(math.comb(2 * order, order))


def decimation_factor(rate_hz: float, cutoff: np.ndarray, max_motion_hz: float, oversampling: float) -> int:
    """The decimation factor ``M ≥ 1`` of a grid at ``rate_hz`` [Hz] (module docstring): the largest integer with
    ``rate / M ≥ oversampling × max(cutoffs, max_motion_hz)`` (cutoffs [Hz] per joint)."""
    band = max(float(np.max(cutoff)), max_motion_hz)
    return max(1, int(np.floor(rate_hz / (oversampling * band))))


def decimate(x: np.ndarray, m: int) -> np.ndarray:
    """``x [N, ...]`` decimated by ``m`` (samples ``0, m, 2m, …``) behind a zero-phase polyphase FIR anti-alias
    filter (``scipy.signal.resample_poly``, its edges padded by a line fit)."""
    return scipy.signal.resample_poly(np.asarray(x, dtype=float), 1, m, axis=0, padtype="line")


def decimate_valid(valid: np.ndarray, m: int) -> np.ndarray:
    """The gap flags on the decimated grid: a decimated sample is valid only when every fine sample within ``m`` of it
    is (the anti-alias filter's main lobe reaches that far)."""
    bad = np.convolve((~valid).astype(float), np.ones(2 * m + 1), mode="same") > 0
    return ~bad[::m]
