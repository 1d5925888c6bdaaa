"""The checks on the derivatives: a recorded q̇ against the conditioning path's dq/dt (lag, gain, consistency)
and the raw q̈'s noise against the conditioned one. The package docstring (:mod:`proprio.data_quality`) states them."""
from __future__ import annotations

import numpy as np
import scipy.signal

from proprio.conditioning import ConditionedSignals
from proprio.data_quality.checks import _g, _span, _which
from proprio.data_quality.findings import Finding, QualityThresholds
from proprio.recording import Recording

__all__ = ["velocity_findings", "acceleration_findings"]


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


def velocity_findings(rec: Recording, ref: ConditionedSignals, names: list[str], th: QualityThresholds) -> list[Finding]:
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


def acceleration_findings(rec: Recording, cs: ConditionedSignals, names: list[str], th: QualityThresholds) -> list[Finding]:
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
