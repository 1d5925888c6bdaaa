"""The block test of the gap diagnosis (:mod:`proprio.diagnosis.selection.forward`, "Selection test"): each held-out
block's log-ratio of the weighted squared residual before and after a candidate, the one-sided t statistic over the
blocks, and the effective-sample-size factor of an autocorrelated residual for the fits' confidence intervals."""
from __future__ import annotations

import math

import numpy as np

__all__ = ["block_gain", "t_stat", "n_eff_factor"]


def block_gain(r_s: np.ndarray, delta: np.ndarray, w: np.ndarray, blk: np.ndarray, n_blk: int
               ) -> tuple[np.ndarray, float]:
    """Per block the log-ratio ``l_b = log(SSE_S,b / SSE_S+c,b)`` of the weighted squared residual (scale-free, so
    blocks of fast reaches and slow exploration weigh alike), and the overall relative gain ``G``."""
    before = np.bincount(blk, weights=((r_s ** 2) * w).sum(axis=1), minlength=n_blk)
    after = np.bincount(blk, weights=(((r_s - delta) ** 2) * w).sum(axis=1), minlength=n_blk)
    lb = np.log(np.maximum(before, 1e-300) / np.maximum(after, 1e-300))
    return lb, 1.0 - float(after.sum()) / max(float(before.sum()), 1e-300)


def t_stat(x: np.ndarray) -> float:
    """One-sample t statistic of the block values ``x`` against 0 (±inf when they do not scatter, 0 when all are 0)."""
    sd = float(np.std(x, ddof=1))
    if sd <= 0:
        return math.inf if x.mean() > 0 else (-math.inf if x.mean() < 0 else 0.0)
    return float(x.mean() / (sd / math.sqrt(len(x))))


def n_eff_factor(r: np.ndarray, max_lag: int = 200) -> float:
    """N / N_eff of an autocorrelated residual (Bartlett: 1 + 2 Σ ρ_k up to the first non-positive ρ), the
    factor by which the white-noise covariance of a fit understates its true covariance (averaged over joints)."""
    fac = []
    for col in r.T:
        x = col - col.mean()
        v = float(x @ x)
        if v <= 0:
            continue
        s = 1.0
        for k in range(1, min(max_lag, len(x) // 4)):
            rho = float(x[:-k] @ x[k:]) / v
            if rho <= 0:
                break
            s += 2 * rho
        fac.append(s)
    return float(np.mean(fac)) if fac else 1.0
