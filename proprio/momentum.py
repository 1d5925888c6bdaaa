"""De Luca's generalised-momentum observer (§3.1): the law, written once, below the Systems.

With p = M(q) q̇ and Ṁ = C + Cᵀ, the link dynamics give ṗ = τ_J − τ_int + τ_ext + τ_g(q) + C(q, q̇)ᵀq̇, so the residual

    r = K_O ( p(t) − p(0) − ∫₀ᵗ (τ_J − τ_int + τ_g + Cᵀq̇ + r) ds )    obeys    ṙ = K_O (τ_ext − r),

a first-order low-pass of τ_ext with time constant 1/K_O per joint. The update is a discrete LTI system
(:func:`momentum_filter`): its matrices are the C++ ``LinearSystem`` of
:class:`~proprio.systems.momentum_observer.MomentumObserver` and the streaming estimator's
:class:`~proprio.discrete_lti.DiscreteLti` step alike, and the batch form over samples (:func:`momentum_observer`)
steps the same matrices by the same compiled kernel in one loop (:meth:`~proprio.discrete_lti.DiscreteLti.response`). The rigid-body terms p and
τ_g + Cᵀq̇ come from Drake's plant per sample (:class:`proprio.rigid_body_terms.RigidBodyTerms`) or, batched, from
the numpy RNEA (:func:`momentum_terms`; Cᵀq̇ = Ṁq̇ − Cq̇, a central difference of M along q̇ of step
:data:`FD_STEP`, in both).
"""
from __future__ import annotations

import numpy as np

from proprio.description import RobotDescription
from proprio.discrete_lti import DiscreteLti
from proprio.dynamics import inverse_dynamics
from proprio.kinematics import chain_geometry

__all__ = ["FD_STEP", "momentum_terms", "momentum_observer", "momentum_initial_state", "momentum_filter"]

FD_STEP = 1e-5
"""[rad] central-difference step of M(q) along q̇ for Ṁq̇ (per sample and batched alike)."""


def momentum_terms(desc: RobotDescription, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Generalised momentum ``p = M(q) q̇`` and ``τ_g(q) + C(q,q̇)ᵀq̇`` (so that ṗ = τ_J − τ_int + τ_ext + that),
    vectorised with the batched RNEA: ``M v = ID(q,0,v) − ID(q,0,0)``, ``C q̇ = ID(q,q̇,0) − ID(q,0,0)``,
    ``τ_g = −ID(q,0,0)``, ``Ṁq̇`` by a central difference of ``M(q ± h u) q̇`` along ``u = q̇/‖q̇‖`` (h = 1e-5 rad;
    agrees with pinocchio's ``computeCoriolisMatrix`` to ~1e-8 N·m, see tests).

    Returns ``p [N,n]`` [N·m·s] and ``tau_g + Cᵀq̇ [N,n]`` [N·m].
    """
    q, qd = np.atleast_2d(np.asarray(q, float)), np.atleast_2d(np.asarray(qd, float))
    geo = chain_geometry(desc)
    zero = np.zeros_like(q)
    g = inverse_dynamics(desc, q, zero, zero, geo)                     # = −τ_g
    p = inverse_dynamics(desc, q, zero, qd, geo) - g
    c_qd = inverse_dynamics(desc, q, qd, zero, geo) - g
    speed = np.linalg.norm(qd, axis=1, keepdims=True)
    step = FD_STEP * np.divide(qd, speed, out=np.zeros_like(qd), where=speed > 0)

    def m_qd(qq: np.ndarray) -> np.ndarray:
        return inverse_dynamics(desc, qq, zero, qd, geo) - inverse_dynamics(desc, qq, zero, zero, geo)

    mdot_qd = (m_qd(q + step) - m_qd(q - step)) * (speed / (2 * FD_STEP))
    return p, -g + mdot_qd - c_qd


def _gains(gain: float | np.ndarray, n: int) -> np.ndarray:
    k = np.broadcast_to(np.asarray(gain, dtype=float), (n,)).copy()
    if not np.all(k > 0) or not np.all(np.isfinite(k)):
        raise ValueError(f"momentum observer gain K_O must be finite and > 0 per joint [1/s], got {gain}")
    return k


def momentum_observer(desc: RobotDescription, time_step: float, q: np.ndarray, qd: np.ndarray,
                      tau_meas: np.ndarray, tau_int: np.ndarray | None = None, gain: float | np.ndarray = 100.0
                      ) -> np.ndarray:
    """Offline generalised-momentum observer over uniformly sampled data: τ̂_ext ``[N,n]`` [N·m] — the recursion of
    :func:`momentum_filter` (the matrices the Diagram's ``LinearSystem`` steps), evaluated over all samples at once
    from its initial state :func:`momentum_initial_state`, stepped over the samples by the streaming estimator's
    compiled kernel (:meth:`~proprio.discrete_lti.DiscreteLti.response`):

        u_k = (p_k − p_{k−1})/Δt − ½(β_k + β_{k−1}),   β = τ_J − τ_int + τ_g + Cᵀq̇,
        r_k = γ r_{k−1} + (1 − γ) u_k,   γ = exp(−K_O Δt),   r_0 = 0,

    the exact discretisation of ṙ = K_O(τ_ext − r) with the mean τ_ext over each sample interval taken from the
    momentum balance (no accelerations). Row k is the filter's state r after sample k (the Diagram outputs it one
    sample later, Drake's discrete semantics).

    Args:
        desc: model description (rigid-body part). time_step: Δt [s]. q, qd: ``[N,n]`` [rad, rad/s].
        tau_meas: measured τ_J ``[N,n]``. tau_int: the model's non-rigid-body torque (e.g. link friction) or None.
        gain: K_O [1/s], scalar or per joint.
    """
    q = np.atleast_2d(np.asarray(q, float))
    n = q.shape[1]
    p, beta = momentum_terms(desc, q, qd)
    tau_int = np.zeros_like(p) if tau_int is None else np.broadcast_to(np.asarray(tau_int, float), p.shape)
    u = np.hstack([p, beta, np.broadcast_to(np.asarray(tau_meas, float), p.shape), tau_int])
    lti = DiscreteLti(*momentum_filter(n, time_step, gain))
    lti.x[:] = momentum_initial_state(u[0])
    r = lti.response(u)                                              # r_{k−1}: the state before each sample
    return np.vstack([r[1:], lti.x[None, :n]])                       # r_k: the state after each sample


def momentum_initial_state(u0: np.ndarray) -> np.ndarray:
    """The filter state ``[0; p_0; −β_0]`` (3n) for the first input ``u0 = [p; τ_g + Cᵀq̇; τ_J; τ_int]`` (4n) of
    :func:`momentum_filter`: u_0 = 0, so r starts at 0 (the Diagram's :meth:`MomentumObserver.set_initial_state` and
    the batch :func:`momentum_observer` alike)."""
    n = u0.shape[0] // 4
    return np.concatenate((np.zeros(n), u0[:n], -(u0[n:2 * n] + u0[2 * n:3 * n] - u0[3 * n:])))


def momentum_filter(n: int, time_step: float, gain: float | np.ndarray = 100.0
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(A, B, C, D)`` of the observer's recursion (:func:`momentum_observer`) as a discrete LTI system with input
    ``u = [p; τ_g + Cᵀq̇; τ_J; τ_int]`` (4n) and state ``x = [r; p_{k−1}; β_{k−1}]`` (3n), output ``y = r``:

        β_k = (τ_g + Cᵀq̇)_k + τ_J,k − τ_int,k,   u_k = (p_k − p_{k−1})/Δt − ½(β_k + β_{k−1}),
        r⁺ = γ r + (1 − γ) u_k,   p_{k−1}⁺ = p_k,   β_{k−1}⁺ = β_k,   γ = exp(−K_O Δt).

    Starting from ``x = [0; p_0; −β_0]`` makes u_0 = 0, i.e. r_0 = r_1... = the offline recursion's (r_0 = 0)."""
    if not time_step > 0:
        raise ValueError(f"MomentumObserver.time_step must be > 0 s, got {time_step}")
    gamma = np.exp(-_gains(gain, n) * time_step)
    g1 = np.diag(1.0 - gamma)
    eye, zero = np.eye(n), np.zeros((n, n))
    sel_beta = np.hstack([zero, eye, eye, -eye])                    # β from u
    sel_p = np.hstack([eye, zero, zero, zero])
    a = np.block([[np.diag(gamma), -g1 / time_step, -0.5 * g1], [zero, zero, zero], [zero, zero, zero]])
    b = np.vstack([g1 @ (sel_p / time_step - 0.5 * sel_beta), sel_p, sel_beta])
    c = np.hstack([eye, zero, zero])
    return a, b, c, np.zeros((n, 4 * n))
