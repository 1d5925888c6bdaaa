"""The wrench solve of the observers (eq. 3.12): ``Jᵀ w = τ_ext`` by a weighted, adaptively damped least squares —
the law, written once, for one sample (:class:`WrenchSolver`, the Systems' and the streaming estimator's per-step
solve) and over samples (:func:`wrench_from_joint_torque`, :func:`jacobian_wrench`, the batch path), both the same
compiled kernel (numba, :func:`_solve_into`).

    w = argmin ‖W^½ (Jᵀ w − τ_ext)‖² + λ² ‖w‖²,   λ² = λ_max² (1 − (σ_min/ε)²) if σ_min < ε else 0,

σ the singular values of ``W^½ Jᵀ`` (σ² the eigenvalues of ``J W Jᵀ``). The kernel forms the k×k matrix ``J W Jᵀ``
and takes one of two ways:

* away from singularities (the common case, found by the Cholesky factorisation of ``J W Jᵀ − ε²I`` succeeding,
  i.e. σ_min > ε): λ = 0, the Cholesky factor L of ``J W Jᵀ`` gives w for every torque vector and ∏σ = ∏ diag(L);
* otherwise the eigen-decomposition: σ_min, the damping λ², ``w = V diag(1/(σ² + λ²)) Vᵀ J W τ``.

Forming J W Jᵀ squares the condition number, harmless here (σ_max/ε ≈ 10² → 10⁴). Our Jacobian rows are [ω; v]
(Drake's order); they are taken in [v; ω] order so that the unknown is ``w = [f; m]``. Force-only mode (3-D) solves
with J_v alone and reports zero moment: a payload exerts no moment about its own CoM, so put the contact point there.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from proprio.description import RobotDescription
from proprio.kinematics import ChainGeometry, chain_geometry, point_jacobian

__all__ = ["WrenchMapping", "WrenchSolver", "wrench_from_joint_torque", "jacobian_wrench"]

_VW = [3, 4, 5, 0, 1, 2]   # rows of our [ω; v] Jacobian in [v; ω] order, so that Jᵀ[f; m] = τ


@dataclass(frozen=True)
class WrenchMapping:
    """How joint torques are mapped to a Cartesian wrench (eq. 3.12).

    Attributes:
        force_only: solve for the 3-D force only (moment reported as 0); right when the contact point is the CoM of
            a payload or a point contact.
        sigma_threshold: ε — below this smallest singular value of ``W^½ Jᵀ`` the estimate is flagged unreliable
            and damping starts [m in force-only mode; mixed m / 1 for 6-D since J_v is in m and J_ω unitless].
        damping_max: λ_max, the damping reached at an exact singularity (same units as the singular values).
        joint_weights: per-joint weights W (e.g. 1/σ² of each torque sensor's noise); None = all ones.
        contact_point: the point where the wrench acts, in the flange frame [m] (default: the flange origin).
    """
    force_only: bool = False
    sigma_threshold: float = 0.02
    damping_max: float = 0.02
    joint_weights: tuple[float, ...] | None = None
    contact_point: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if not self.sigma_threshold > 0:
            raise ValueError(f"WrenchMapping.sigma_threshold must be > 0, got {self.sigma_threshold}")
        if not self.damping_max >= 0:
            raise ValueError(f"WrenchMapping.damping_max must be >= 0, got {self.damping_max}")
        if self.joint_weights is not None and not np.all(np.asarray(self.joint_weights) > 0):
            raise ValueError(f"WrenchMapping.joint_weights must all be > 0, got {self.joint_weights}")


@numba.njit(cache=True)
def _solve_into(jac, tau_ext, rows, sqrt_w, eps, damping_max, wrench_out, flags_out):  # pragma: no cover (compiled)
    """The law for one configuration: ``jac [6,n]`` (rows [ω; v], world), ``tau_ext [m,n]`` [N·m] → the wrenches
    ``[f; m]`` into ``wrench_out [m,6]`` (moment 0 in force-only mode, ``rows`` = the [v] rows) and ``[∏σ,
    unreliable (1.0/0.0)]`` into ``flags_out [2]``."""
    k, n, m = rows.shape[0], jac.shape[1], tau_ext.shape[0]
    a = np.empty((k, n))                                  # W^½-weighted J, rows [v; ω] or [v]
    for i in range(k):
        for j in range(n):
            a[i, j] = jac[rows[i], j] * sqrt_w[j]
    aat = np.empty((k, k))
    for i in range(k):
        for l in range(i + 1):
            s = 0.0
            for j in range(n):
                s += a[i, j] * a[l, j]
            aat[i, l] = s
            aat[l, i] = s
    b = np.empty((m, k))                                  # J W τ per torque vector
    for c in range(m):
        for i in range(k):
            s = 0.0
            for j in range(n):
                s += a[i, j] * (tau_ext[c, j] * sqrt_w[j])
            b[c, i] = s
    wrench_out[:, :] = 0.0
    # Cholesky of J W Jᵀ − ε²I: it exists iff σ_min > ε (no damping)
    shifted = True
    low = np.zeros((k, k))
    for sweep in range(2):                                # sweep 0: J W Jᵀ − ε²I; sweep 1: J W Jᵀ
        shift = eps * eps if sweep == 0 else 0.0
        for j in range(k):
            d = aat[j, j] - shift
            for p in range(j):
                d -= low[j, p] * low[j, p]
            if not d > 0.0:
                shifted = False
                break
            low[j, j] = math.sqrt(d)
            for i in range(j + 1, k):
                s = aat[i, j]
                for p in range(j):
                    s -= low[i, p] * low[j, p]
                low[i, j] = s / low[j, j]
        if not shifted:
            break
    if shifted:
        manip = 1.0
        for j in range(k):
            manip *= low[j, j]
        y = np.empty(k)
        for c in range(m):                                # L Lᵀ w = J W τ
            for i in range(k):
                s = b[c, i]
                for p in range(i):
                    s -= low[i, p] * y[p]
                y[i] = s / low[i, i]
            for i in range(k - 1, -1, -1):
                s = y[i]
                for p in range(i + 1, k):
                    s -= low[p, i] * wrench_out[c, p]
                wrench_out[c, i] = s / low[i, i]
        flags_out[0] = manip
        flags_out[1] = 0.0
        return
    lam, v = np.linalg.eigh(aat)                          # J W Jᵀ = V diag(σ²) Vᵀ, ascending
    s_min = math.sqrt(max(lam[0], 0.0))
    prod = 1.0
    for j in range(k):
        prod *= lam[j]
    flags_out[0] = math.sqrt(prod) if lam[0] > 0 else 0.0            # ∏σ (0 if σ_min = 0)
    unreliable = s_min < eps                              # (not when σ_min = ε to rounding)
    damping = damping_max * damping_max * (1.0 - (s_min / eps) ** 2) if unreliable else 0.0
    flags_out[1] = 1.0 if unreliable else 0.0
    for c in range(m):
        for i in range(k):
            s = 0.0
            for p in range(k):                            # (Vᵀ J W τ)_p / (σ_p² + λ²), then V ·
                t = 0.0
                for q in range(k):
                    t += v[q, p] * b[c, q]
                s += v[i, p] * t / (lam[p] + damping)
            wrench_out[c, i] = s


@numba.njit(cache=True)
def _solve_batch(jac, tau_ext, rows, sqrt_w, eps, damping_max, wrench_out, flags_out):  # pragma: no cover
    """:func:`_solve_into` for each sample: ``jac [N,6,n]``, ``tau_ext [N,n]`` → ``wrench_out [N,6]``,
    ``flags_out [N,2]``."""
    for i in range(jac.shape[0]):
        _solve_into(jac[i], tau_ext[i:i + 1], rows, sqrt_w, eps, damping_max, wrench_out[i:i + 1], flags_out[i])


def _sqrt_weights(mapping: WrenchMapping, n: int) -> np.ndarray:
    if mapping.joint_weights is None:
        return np.ones(n)
    sqrt_w = np.sqrt(np.asarray(mapping.joint_weights, float))
    if sqrt_w.shape != (n,):
        raise ValueError(f"WrenchMapping.joint_weights has {sqrt_w.size} entries, the arm has {n} joints")
    return sqrt_w


class WrenchSolver:
    """The wrench solve for ONE configuration (module docstring), for the per-step Systems and the streaming
    estimator: :meth:`solve_into` maps several torque vectors through the same factorisation (both observers share
    J(q)); ``solver(jac [6,n], tau_ext [n])`` returns ``[f; m (6), manipulability, unreliable]``. Building it
    compiles (or loads from numba's cache) and runs the kernel once, so the first control cycle is not the
    compile."""

    def __init__(self, mapping: WrenchMapping, n: int):
        self.mapping = mapping
        self.rows = np.array(_VW[:3] if mapping.force_only else _VW, dtype=np.int64)
        self.sqrt_w = _sqrt_weights(mapping, n)
        self.eps, self.damping_max = float(mapping.sigma_threshold), float(mapping.damping_max)
        jac, out = np.zeros((6, n)), np.empty((2, 6))                   # warm both branches (σ_min = 0 and > ε)
        jac[:, :min(n, 6)] = np.eye(6)[:, :min(n, 6)]
        for j in (0.0 * jac, jac):
            self.solve_into(j, np.ones((2, n)), out, np.empty(2))

    def solve_into(self, jac: np.ndarray, tau_ext: np.ndarray, wrench_out: np.ndarray, flags_out: np.ndarray
                   ) -> None:
        """``jac [6,n]`` (rows [ω; v], world frame, of the contact point) and ``tau_ext [m,n]`` [N·m] → the wrenches
        ``[f; m]`` (N, N·m) into ``wrench_out [m,6]`` and ``[manipulability ∏σ, unreliable 1.0/0.0]`` into
        ``flags_out [2]``."""
        _solve_into(jac, tau_ext, self.rows, self.sqrt_w, self.eps, self.damping_max, wrench_out, flags_out)

    def __call__(self, jac: np.ndarray, tau_ext: np.ndarray) -> np.ndarray:
        out = np.empty(8)
        self.solve_into(np.ascontiguousarray(jac, dtype=float), np.asarray(tau_ext, dtype=float).reshape(1, -1),
                        out[:6].reshape(1, 6), out[6:])
        return out


def wrench_from_joint_torque(jac: np.ndarray, tau_ext: np.ndarray, mapping: WrenchMapping = WrenchMapping()
                             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Solve ``Jᵀ w = τ_ext`` for the wrench over samples (eq. 3.12, the module's law sample by sample).

    Args:
        jac: geometric Jacobians ``[N,6,n]`` of the contact point, rows [ω; v], world frame.
        tau_ext: external joint torques ``[N,n]`` [N·m] (= τ_dyn − τ_J).
        mapping: solver options.

    Returns:
        ``wrench [N,6]`` = [f; m] (N, N·m; moment 0 in force-only mode), ``manipulability [N]`` = ∏σ_i =
        √det(J W Jᵀ) of the solved system (Yoshikawa), ``unreliable [N]`` bool (σ_min < ε).
    """
    jac = np.ascontiguousarray(jac, dtype=float)
    tau_ext = np.ascontiguousarray(tau_ext, dtype=float)
    rows = np.array(_VW[:3] if mapping.force_only else _VW, dtype=np.int64)
    wrench, flags = np.empty((jac.shape[0], 6)), np.empty((jac.shape[0], 2))
    _solve_batch(jac, tau_ext, rows, _sqrt_weights(mapping, jac.shape[2]), float(mapping.sigma_threshold),
                 float(mapping.damping_max), wrench, flags)
    return wrench, flags[:, 0], flags[:, 1] > 0.5
def jacobian_wrench(desc: RobotDescription | ChainGeometry, q: np.ndarray, tau_meas: np.ndarray,
                    tau_dyn: np.ndarray, mapping: WrenchMapping = WrenchMapping()
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The Jacobian wrench observer, vectorised over samples: ``f̂ = J⁻ᵀ(q) (τ_dyn − τ_meas)`` (eq. 3.12).

    Args:
        desc: robot description (or its precomputed :class:`ChainGeometry`) for the flange Jacobian.
        q: joint positions ``[N,n]`` [rad]; tau_meas: measured τ_J ``[N,n]`` [N·m]; tau_dyn: model torque ``[N,n]``.
        mapping: pseudo-inverse options (:class:`WrenchMapping`).

    Returns:
        ``(wrench, manipulability, unreliable)``: the wrench ``[N,6]`` (fx, fy, fz [N], mx, my, mz [N·m]) on the
        robot at the contact point, world frame; the manipulability ``[N]``; ``unreliable`` ``[N]`` bool.
    """
    geo = desc if isinstance(desc, ChainGeometry) else chain_geometry(desc)
    q = np.atleast_2d(np.asarray(q, dtype=float))
    tau_ext = np.atleast_2d(np.asarray(tau_dyn, dtype=float)) - np.atleast_2d(np.asarray(tau_meas, dtype=float))
    if tau_ext.shape != q.shape:
        raise ValueError(f"jacobian_wrench: q, tau_meas and tau_dyn must have the same shape [N,n], got q {q.shape}, "
                         f"tau_dyn − tau_meas {tau_ext.shape}")
    jac = point_jacobian(geo, q, np.asarray(mapping.contact_point, dtype=float))
    return wrench_from_joint_torque(jac, tau_ext, mapping)


