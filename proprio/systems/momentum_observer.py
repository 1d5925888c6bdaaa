"""De Luca's generalised-momentum observer (§3.1, the second way to τ_ext in :mod:`proprio.systems.observers`), and
:class:`DrakeArm`, the plant context both observers' per-step Systems evaluate.

With p = M(q) q̇ and Ṁ = C + Cᵀ, the link dynamics give ṗ = τ_J − τ_int + τ_ext + τ_g(q) + C(q, q̇)ᵀq̇, so the residual

    r = K_O ( p(t) − p(0) − ∫₀ᵗ (τ_J − τ_int + τ_g + Cᵀq̇ + r) ds )    obeys    ṙ = K_O (τ_ext − r),

a first-order low-pass of τ_ext with time constant 1/K_O per joint. The law is written once, as a discrete LTI
system (:func:`momentum_filter`): its matrices are the C++ ``LinearSystem`` of :class:`MomentumObserver` (the
Diagram, offline replay and the streaming :mod:`proprio.online` alike), and the batch form over samples
(:func:`momentum_observer`) evaluates the same matrices' recursion vectorised (:func:`filter_response`). τ_g is Drake's gravity generalised force (the *applied* gravity torque) and
Cᵀq̇ = Ṁq̇ − Cq̇ (a central difference of M along q̇ plus Drake's bias term).
"""
from __future__ import annotations

import math

import numpy as np
from pydrake.multibody.tree import JacobianWrtVariable
from pydrake.systems.framework import Context, Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.primitives import Demultiplexer, LinearSystem, Multiplexer
from scipy.signal import lfilter

from proprio.description import RobotDescription
from proprio.dynamics import inverse_dynamics
from proprio.kinematics import chain_geometry
from proprio.plant import DrakeRobot

__all__ = ["DrakeArm", "momentum_terms", "momentum_observer", "momentum_initial_state", "filter_response",
           "momentum_filter", "RigidBodyTermsSystem", "MomentumObserver"]


_FD_STEP = 1e-5   # [rad] central-difference step of M(q) along q̇ for Ṁq̇


class DrakeArm(DrakeRobot):
    """A Drake plant context of the model robot for the Systems' per-step work: the flange Jacobian
    (``CalcJacobianSpatialVelocity``), inverse dynamics (``CalcInverseDynamics``) and the same p and τ_g + Cᵀq̇ as
    :func:`momentum_terms` from ``CalcMassMatrix`` and ``CalcInverseDynamics`` (τ_g − Cq̇ = −ID(q, q̇, 0))."""

    def __init__(self, desc: RobotDescription):
        super().__init__(desc)
        self._zero = np.zeros(self.plant.num_velocities())

    def momentum_terms(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``p = M(q)q̇`` [N·m·s] and ``τ_g(q) + C(q,q̇)ᵀq̇`` [N·m] for one sample (Cᵀq̇ = Ṁq̇ − Cq̇)."""
        if not self._in_order:
            return self._momentum_terms_reindexed(q, qd)
        p, beta = np.empty_like(qd, dtype=float), np.empty_like(qd, dtype=float)
        self._momentum_terms_into(np.concatenate((q, qd)), p, beta)
        return p, beta

    def _momentum_terms_into(self, state: np.ndarray, p_out: np.ndarray, beta_out: np.ndarray) -> None:
        """:meth:`momentum_terms` from ``state = [q; q̇]`` into ``p_out``, ``beta_out`` (joints in the plant's order);
        the context is left at (q, q̇) with the gravity forces in ``_forces``."""
        plant, ctx, n = self.plant, self.context, self._zero.shape[0]
        q, qd = state[:n], state[n:]
        speed = math.sqrt(float(qd @ qd))
        if speed > 0:
            u = qd * (_FD_STEP / speed)
            plant.SetPositions(ctx, q + u)
            m_plus = plant.CalcMassMatrix(ctx)
            plant.SetPositions(ctx, q - u)
            np.dot(m_plus - plant.CalcMassMatrix(ctx), qd, out=beta_out)
            beta_out *= speed / (2 * _FD_STEP)                         # Ṁq̇
        else:
            beta_out[:] = 0.0
        plant.SetPositionsAndVelocities(ctx, state)
        np.dot(plant.CalcMassMatrix(ctx), qd, out=p_out)
        plant.CalcForceElementsContribution(ctx, self._forces)       # gravity
        # τ_g − C q̇ = −ID(q, q̇, 0) with gravity applied: one call instead of CalcGravity… + CalcBiasTerm
        beta_out -= plant.CalcInverseDynamics(ctx, self._zero, self._forces)

    def rigid_body_terms_into(self, state: np.ndarray, p_flange: np.ndarray, p_out: np.ndarray,
                              beta_out: np.ndarray, jac_out: np.ndarray) -> None:
        """:meth:`momentum_terms` and the Jacobian ``[6,n]`` of the point ``p_flange`` [m, flange frame] (rows
        [ω; v], world frame) for ``state = [q; q̇]``, from the same context (which then holds q already), into
        ``p_out``, ``beta_out`` [n] and ``jac_out`` [6,n]."""
        n = self.description.n
        if not self._in_order:
            p_out[:], beta_out[:] = self._momentum_terms_reindexed(state[:n], state[n:])
            jac_out[:] = self.flange_jacobian(state[:n], p_flange)
            return
        self._momentum_terms_into(state, p_out, beta_out)
        jac_out[:] = self.plant.CalcJacobianSpatialVelocity(self.context, JacobianWrtVariable.kV, self.flange,
                                                            p_flange, self._world, self._world)

    def _momentum_terms_reindexed(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        speed = float(np.linalg.norm(qd))
        if speed > 0:
            u = _FD_STEP * qd / speed
            mdot_qd = (self.mass_matrix(q + u) - self.mass_matrix(q - u)) @ qd * (speed / (2 * _FD_STEP))
        else:
            mdot_qd = np.zeros_like(qd)
        m = self.mass_matrix(q)
        self._set(q, qd)
        v = self._v_index
        c_qd = self.plant.CalcBiasTerm(self.context)[v]
        tau_g = self.plant.CalcGravityGeneralizedForces(self.context)[v]
        return m @ qd, tau_g + mdot_qd - c_qd


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
    step = _FD_STEP * np.divide(qd, speed, out=np.zeros_like(qd), where=speed > 0)

    def m_qd(qq: np.ndarray) -> np.ndarray:
        return inverse_dynamics(desc, qq, zero, qd, geo) - inverse_dynamics(desc, qq, zero, zero, geo)

    mdot_qd = (m_qd(q + step) - m_qd(q - step)) * (speed / (2 * _FD_STEP))
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
    from its initial state :func:`momentum_initial_state` (:func:`filter_response`):

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
    return filter_response(momentum_filter(n, time_step, gain), u, momentum_initial_state(u[0]))


def momentum_initial_state(u0: np.ndarray) -> np.ndarray:
    """The filter state ``[0; p_0; −β_0]`` (3n) for the first input ``u0 = [p; τ_g + Cᵀq̇; τ_J; τ_int]`` (4n) of
    :func:`momentum_filter`: u_0 = 0, so r starts at 0 (the Diagram's :meth:`MomentumObserver.set_initial_state` and
    the batch :func:`momentum_observer` alike)."""
    n = u0.shape[0] // 4
    return np.concatenate((np.zeros(n), u0[:n], -(u0[n:2 * n] + u0[2 * n:3 * n] - u0[3 * n:])))


def filter_response(abcd: tuple[np.ndarray, ...], u: np.ndarray, x0: np.ndarray) -> np.ndarray:
    """The residual states ``r [N,n]`` after each input row ``u [N,4n]`` of the discrete system
    ``abcd = momentum_filter(...)`` started at ``x0`` — its recursion vectorised over samples. Its structure makes this
    exact: the rows of A past r are zero (the states ``[p_{k−1}; β_{k−1}] = B_d u_{k−1}`` hold the previous input),
    and A's r block is diagonal (the poles γ), so ``r_{k+1} = γ r_k + B_r u_k + A_rd B_d u_{k−1}``: one first-order
    ``lfilter`` per joint."""
    a, b = abcd[0], abcd[1]
    n = a.shape[0] // 3
    gamma = np.diag(a[:n, :n]).copy()
    if a[n:].any() or np.any(a[:n, :n] != np.diag(gamma)):
        raise ValueError("filter_response: not the momentum filter's structure (diagonal poles, delayed inputs)")
    delayed = np.vstack([x0[None, n:], u[:-1] @ b[n:].T])                # [p_{k−1}; β_{k−1}] at each sample
    drive = u @ b[:n].T + delayed @ a[:n, n:].T
    return np.stack([lfilter([1.0], [1.0, -gamma[j]], drive[:, j], zi=[gamma[j] * x0[j]])[0] for j in range(n)],
                    axis=1)


class RigidBodyTermsSystem(LeafSystem):
    """The model robot's rigid-body terms at one sample, from Drake's plant on a cached context: input ``state`` =
    ``[q; q̇]`` (2n: rad, rad/s); output ``terms`` = ``[p = M(q)q̇ (n, N·m·s); τ_g + Cᵀq̇ (n, N·m); J (6n)]`` with J
    the Jacobian of the contact point (``contact_point`` [m] in the flange frame; rows [ω; v], world frame, row-major)
    — what the momentum observer and the wrench map need, from one plant context per step
    (:meth:`DrakeArm.rigid_body_terms_into`). Direct feedthrough."""

    def __init__(self, desc: RobotDescription, contact_point: tuple[float, float, float] = (0.0, 0.0, 0.0)):
        LeafSystem.__init__(self)
        n = self.n = desc.n
        self._arm = DrakeArm(desc)
        self._contact = np.asarray(contact_point, dtype=float)
        self._state = self.DeclareVectorInputPort("state", 2 * n)
        self.DeclareVectorOutputPort("terms", 8 * n, self._calc)
        self.terms = np.empty(8 * n)
        self._p, self._beta, self._jac = self.terms[:n], self.terms[n:2 * n], self.terms[2 * n:].reshape(6, n)

    def calc(self, state: np.ndarray) -> np.ndarray:
        """The output for one sample ``state = [q; q̇]`` — the step function. It is written into this System's own
        buffer (:attr:`terms`, valid until the next call), which is returned."""
        self._arm.rigid_body_terms_into(state, self._contact, self._p, self._beta, self._jac)
        return self.terms

    def _calc(self, context, output) -> None:
        output.SetFromVector(self.calc(self._state.Eval(context)))


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


class MomentumObserver(Diagram):
    """De Luca's generalised-momentum observer as a sub-Diagram, updated every ``time_step`` (the data rate)::

        q, qd ──▶ Multiplexer ──▶ RigidBodyTermsSystem ─▶ Demux ─[p; τ_g + Cᵀq̇]─┐     (J ─▶ jacobian)
        tau_meas ──────────────────────────────────────┼──▶ Multiplexer ──▶ LinearSystem (C++, discrete) ──▶ tau_ext
        tau_int ───────────────────────────────────────┘                    (:func:`momentum_filter`)

    Input ports (size n): ``q`` [rad], ``qd`` [rad/s], ``tau_meas`` [N·m] (measured τ_J), ``tau_int`` [N·m] (the
    model's non-rigid-body torque; connect zeros for a pure rigid-body model). Output ports: ``tau_ext`` (n) [N·m],
    the residual r (the filter's state); ``jacobian`` (6n) the Jacobian of ``contact_point`` [m, flange frame] at q
    (rows [ω; v], world frame, row-major), computed with the momentum terms on the same plant context, for
    :class:`WrenchMap`. Its wrench is :class:`WrenchMap`'s ``wrench_momentum``. Same recursion as
    :func:`momentum_observer`; call :meth:`set_initial_state` once the first sample is on the inputs (r then
    starts at 0 exactly as offline; without it the first step sees p_{−1} = β_{−1} = 0, a large kick). As for any
    Drake discrete state, the update at t_k is visible from the next step on, so the output at t_k is r_{k−1}.
    """

    def __init__(self, desc: RobotDescription, time_step: float, gain: float | np.ndarray = 100.0,
                 contact_point: tuple[float, float, float] = (0.0, 0.0, 0.0)):
        Diagram.__init__(self)
        n = self.n = desc.n
        builder = DiagramBuilder()
        state = builder.AddNamedSystem("state", Multiplexer([n, n]))
        self.terms = builder.AddNamedSystem("terms", RigidBodyTermsSystem(desc, contact_point))
        split = builder.AddNamedSystem("split", Demultiplexer([2 * n, 6 * n]))
        mux = self._mux = builder.AddNamedSystem("stack", Multiplexer([2 * n, n, n]))
        self.filter = builder.AddNamedSystem("filter", LinearSystem(*momentum_filter(n, time_step, gain),
                                                                    float(time_step)))
        builder.ExportInput(state.get_input_port(0), "q")
        builder.ExportInput(state.get_input_port(1), "qd")
        builder.Connect(state.get_output_port(), self.terms.get_input_port())
        builder.Connect(self.terms.get_output_port(), split.get_input_port())
        builder.Connect(split.get_output_port(0), mux.get_input_port(0))
        builder.ExportOutput(split.get_output_port(1), "jacobian")
        builder.ExportInput(mux.get_input_port(1), "tau_meas")
        builder.ExportInput(mux.get_input_port(2), "tau_int")
        builder.Connect(mux.get_output_port(), self.filter.get_input_port())
        builder.ExportOutput(self.filter.get_output_port(), "tau_ext")
        builder.BuildInto(self)
        self.set_name("momentum_observer")

    def set_initial_state(self, context: Context) -> None:
        """Set the filter state from the inputs ``context`` (this System's context) sees now: the first sample."""
        u0 = np.asarray(self._mux.get_output_port().Eval(self.GetSubsystemContext(self._mux, context)))
        self.GetMutableSubsystemContext(self.filter, context).get_mutable_discrete_state_vector().SetFromVector(
            momentum_initial_state(u0))
