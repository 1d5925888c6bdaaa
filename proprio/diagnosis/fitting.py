"""Fitting candidates to the training residual: weighted linear least squares for the linear ones, bounded
Levenberg–Marquardt (per joint) or trust-region least squares for the nonlinear ones, back-fitting for a set."""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy import optimize

from proprio.diagnosis.candidates.base import Candidate
from proprio.diagnosis.data import GapData

__all__ = ["Fit", "weighted_lstsq", "fit_candidates", "predict_candidates"]


@dataclass
class Fit:
    thetas: dict[str, np.ndarray]
    cov: dict[str, np.ndarray]


def weighted_lstsq(a: np.ndarray, y: np.ndarray, w: np.ndarray,
                   bounds: tuple[np.ndarray, np.ndarray] | None = None,
                   precision: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Weighted LS of ``y [M,n] ≈ a [M,n,p] θ`` with joint weights ``w [n]`` by the normal equations of the
    column-scaled problem (eigen-decomposition, directions below 1e-10 of the largest dropped); returns θ and
    (AᵀWA + P)⁺. ``precision`` ``[p]``: the diagonal P of a zero-mean Gaussian prior (``1/σ²``, 0: none), added
    as rows ``√P_i θ_i ≈ 0``. ``bounds`` (lower, upper ``[p]``): when the unconstrained θ leaves them (a negative
    Coulomb level, a negative mass), θ is the bounded LS solution instead (``scipy.optimize.lsq_linear``); the
    covariance stays the unconstrained one."""
    sw = np.sqrt(w)
    aw = (a * sw[None, :, None]).reshape(-1, a.shape[-1])
    yw = (y * sw[None, :]).reshape(-1)
    if precision is not None and np.any(precision > 0):
        rows = np.flatnonzero(precision > 0)
        prior = np.zeros((rows.size, aw.shape[1]))
        prior[np.arange(rows.size), rows] = np.sqrt(precision[rows])
        aw, yw = np.vstack([aw, prior]), np.concatenate([yw, np.zeros(rows.size)])
    scale = np.linalg.norm(aw, axis=0)
    scale[scale == 0] = 1.0
    g = (aw.T @ aw) / np.outer(scale, scale)
    lam, vec = np.linalg.eigh(g)
    keep = lam > 1e-10 * max(lam.max(), 1e-300)
    g_inv = (vec[:, keep] / lam[keep]) @ vec[:, keep].T
    theta = g_inv @ ((aw.T @ yw) / scale) / scale
    if bounds is not None:
        lo, hi = (np.asarray(b, dtype=float) for b in bounds)
        if np.any(theta < lo) or np.any(theta > hi):
            theta = optimize.lsq_linear(aw / scale, yw, bounds=(lo * scale, hi * scale), method="bvls").x / scale
    return theta, g_inv / np.outer(scale, scale)


def _fit_nonlinear(cand: Candidate, target: np.ndarray, data: GapData, w: np.ndarray,
                   starts: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Bounded nonlinear LS of one candidate on ``target [M,n]``; returns θ and (JᵀWJ)⁺ at the optimum.

    The Jacobian is by forward differences, grouped: parameters that act on different joints are perturbed
    together (one torque evaluation per parameter kind instead of per parameter)."""
    sw = np.sqrt(w)
    lo, hi = cand.bounds()
    n = target.shape[1]
    jp = cand.joint_of_param(n)
    if np.all(jp >= 0):
        kinds = len(jp) // n
        groups = [np.arange(k * n, (k + 1) * n) for k in range(kinds)] if len(jp) == kinds * n else \
            [np.array([i]) for i in range(len(jp))]
    else:
        groups = [np.array([i]) for i in range(len(jp))]

    def model(theta):
        return cand.torque(theta, data)

    def resid(theta):
        return ((target - model(theta)) * sw).reshape(-1)

    def jac(theta):
        base = model(theta)
        out = np.zeros((target.size, len(theta)))
        for grp in groups:
            h = 1e-6 * np.maximum(np.abs(theta[grp]), 1e-3)
            step_up = np.where(theta[grp] + h <= hi[grp], h, -h)
            th = theta.copy()
            th[grp] += step_up
            d = (model(th) - base) * sw                       # [M, n]
            for i, gi in enumerate(grp):
                col = np.zeros_like(d)
                if jp[gi] >= 0:
                    col[:, jp[gi]] = d[:, jp[gi]]
                else:
                    col = d
                out[:, gi] = -col.reshape(-1) / step_up[i]
        return out

    best = None
    for x0 in starts:
        x0 = np.asarray(x0, dtype=float).copy()
        span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
        x0 = np.clip(x0, lo + 1e-6 * span * np.isfinite(lo), hi - 1e-6 * span * np.isfinite(hi))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sol = optimize.least_squares(resid, x0, jac=jac, bounds=(lo, hi), x_scale="jac", max_nfev=40,
                                         method="trf", tr_solver="exact")
        if best is None or sol.cost < best.cost:
            best = sol
    j = np.asarray(best.jac)
    return best.x, np.linalg.pinv(j.T @ j, rcond=1e-10)


def _fit_separable(cand: Candidate, target: np.ndarray, data: GapData, w: np.ndarray,
                   starts: list[np.ndarray], iters: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """Bounded Levenberg–Marquardt for a candidate whose parameters act joint by joint (every library effect):
    the problem splits into one small ``K``-parameter problem per joint, solved for all joints at once (one torque
    evaluation per iterate and per parameter kind for the forward-difference Jacobian; steps accepted per joint).
    Returns θ and the block-diagonal (JᵀWJ)⁻¹."""
    lo, hi = cand.bounds()
    n = target.shape[1]
    k_kinds = cand.n_params // n
    lo, hi = lo.reshape(k_kinds, n), hi.reshape(k_kinds, n)
    span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)

    def clip(th):
        return np.clip(th, lo + 1e-9 * span * np.isfinite(lo), hi - 1e-9 * span * np.isfinite(hi))

    def model(th):
        return cand.torque(th.reshape(-1), data)

    def jacobian(th, base):
        jac = np.empty(target.shape + (k_kinds,))
        for k in range(k_kinds):
            h = 1e-6 * np.maximum(np.abs(th[k]), 1e-3)
            h = np.where(th[k] + h <= hi[k], h, -h)
            t2 = th.copy()
            t2[k] += h
            jac[:, :, k] = (model(t2) - base) / h
        return jac

    best_th, best_cost = None, None
    for x0 in starts:
        th = clip(np.asarray(x0, dtype=float).reshape(k_kinds, n).copy())
        pred = model(th)
        cost = ((target - pred) ** 2).sum(axis=0)
        lam = np.full(n, 1e-3)
        for _ in range(iters):
            jac = jacobian(th, pred)
            r = target - pred
            a = np.einsum("mjk,mjl->jkl", jac, jac)
            g = np.einsum("mjk,mj->jk", jac, r)
            d = np.einsum("jkk->jk", a) + 1e-12
            step = np.linalg.solve(a + lam[:, None, None] * d[:, :, None] * np.eye(k_kinds), g[..., None])[..., 0]
            th_new = clip(th + step.T)
            pred_new = model(th_new)
            cost_new = ((target - pred_new) ** 2).sum(axis=0)
            ok = cost_new < cost
            th = np.where(ok[None, :], th_new, th)
            pred = np.where(ok[None, :], pred_new, pred)
            gain = np.where(ok, (cost - cost_new) / np.maximum(cost, 1e-300), 0.0)
            cost = np.where(ok, cost_new, cost)
            lam = np.where(ok, lam / 3.0, lam * 4.0)
            if np.all((gain < 1e-6) & (ok | (lam > 1e6))):
                break
        if best_cost is None:
            best_th, best_cost = th.copy(), cost.copy()
        else:
            better = cost < best_cost
            best_th = np.where(better[None, :], th, best_th)
            best_cost = np.where(better, cost, best_cost)
    jac = jacobian(best_th, model(best_th))
    a = np.einsum("mjk,mjl->jkl", jac, jac) * w[:, None, None]
    cov = np.zeros((cand.n_params, cand.n_params))
    for j in range(n):
        idx = np.arange(k_kinds) * n + j
        cov[np.ix_(idx, idx)] = np.linalg.pinv(a[j], rcond=1e-10)
    return best_th.reshape(-1), cov


def fit_candidates(cands: list[Candidate], data: GapData, w: np.ndarray, init: dict[str, np.ndarray],
         sweeps: int = 3) -> Fit:
    """Joint fit of ``cands`` to the training residual: linear candidates exactly (one stacked LS), nonlinear ones
    by back-fitting (each on what the others leave), ``sweeps`` rounds."""
    e = data.residual
    lin = [c for c in cands if c.linear]
    nl = [c for c in cands if not c.linear]
    a = np.concatenate([c.cached_design(data) for c in lin], axis=-1) if lin else None
    bounds = tuple(np.concatenate(b) for b in zip(*(c.bounds() for c in lin))) if lin else None
    precision = np.concatenate([c.prior_precision() for c in lin]) if lin else None
    thetas = {c.name: init.get(c.name, c.starts(data)[0]) for c in nl}
    torques = {c.name: c.torque(thetas[c.name], data) if c.name in init else np.zeros_like(e) for c in nl}
    cov: dict[str, np.ndarray] = {}
    for _ in range(sweeps if nl else 1):
        lin_pred = np.zeros_like(e)
        if lin:
            beta, inv = weighted_lstsq(a, e - sum(torques.values(), np.zeros_like(e)), w, bounds, precision)
            lin_pred = a @ beta
            k = 0
            for c in lin:
                thetas[c.name] = beta[k:k + c.n_params]
                cov[c.name] = inv[k:k + c.n_params, k:k + c.n_params]
                k += c.n_params
        for c in nl:
            others = lin_pred + sum((t for k, t in torques.items() if k != c.name), np.zeros_like(e))
            starts = ([thetas[c.name]] if c.name in init else []) + c.starts(data)
            fitter = _fit_separable if np.all(c.joint_of_param(e.shape[1]) >= 0) else _fit_nonlinear
            thetas[c.name], cov[c.name] = fitter(c, e - others, data, w, starts)
            torques[c.name] = c.torque(thetas[c.name], data)
            init = {**init, c.name: thetas[c.name]}
    return Fit(thetas, cov)


def predict_candidates(cands: list[Candidate], fit: Fit, data: GapData) -> np.ndarray:
    out = np.zeros_like(data.residual)
    for c in cands:
        out += c.cached_design(data) @ fit.thetas[c.name] if c.linear else c.torque(fit.thetas[c.name], data)
    return out
