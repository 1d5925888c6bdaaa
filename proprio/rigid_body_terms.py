"""The rigid-body terms of the estimator at one sample, from ONE Drake plant context: the inverse dynamics τ_rigid,
the generalised momentum p = M(q)q̇, τ_g + Cᵀq̇ (the momentum observer's) and the contact point's Jacobian J(q) —
all on the same kinematics (:class:`RigidBodyTerms`, the law the Systems and the streaming estimator call).

Per sample: three mass matrices (at q ± h u for Ṁq̇ along u = q̇/‖q̇‖, and at q), Drake's inverse dynamics at zero
acceleration with gravity applied (``CalcInverseDynamics(q, q̇, 0)`` = Cq̇ − τ_g) and the Jacobian — nine
Python→Drake calls — then one compiled kernel (:func:`_combine`) for τ_rigid = M q̈ + (Cq̇ − τ_g) (= Drake's
``CalcInverseDynamics(q, q̇, q̈)`` to rounding), p = M q̇ and τ_g + Cᵀq̇ = Ṁq̇ − (Cq̇ − τ_g). The batched form
over samples is the numpy RNEA of :func:`proprio.momentum.momentum_terms` (same Ṁq̇ difference, :data:`FD_STEP`).
"""
from __future__ import annotations

import math

import numba
import numpy as np
from pydrake.multibody.tree import JacobianWrtVariable

from proprio.description import RobotDescription
from proprio.momentum import FD_STEP
from proprio.plant import DrakeRobot

__all__ = ["RigidBodyTerms"]


@numba.njit(cache=True)
def _combine(m_plus, m_minus, m, id0, qd, qdd, scale, tau_out, momentum_out):  # pragma: no cover (compiled)
    """``tau_out`` = M q̈ + id0, ``momentum_out`` = ``[M q̇; (M₊ − M₋) q̇ · scale − id0]`` with id0 = ID(q, q̇, 0) =
    Cq̇ − τ_g."""
    n = qd.shape[0]
    for i in range(n):
        mqdd, p, mdot = 0.0, 0.0, 0.0
        for j in range(n):
            mqdd += m[i, j] * qdd[j]
            p += m[i, j] * qd[j]
            mdot += (m_plus[i, j] - m_minus[i, j]) * qd[j]
        tau_out[i] = mqdd + id0[i]
        momentum_out[i] = p
        momentum_out[n + i] = mdot * scale - id0[i]


@numba.njit(cache=True)
def _displace(q, qd, step, plus_out, minus_out, state_out):  # pragma: no cover (compiled)
    """``‖q̇‖``, and ``q ± step·q̇/‖q̇‖`` into ``plus_out``/``minus_out`` (q when q̇ = 0), ``[q; q̇]`` into
    ``state_out``."""
    n = q.shape[0]
    speed = 0.0
    for j in range(n):
        speed += qd[j] * qd[j]
    speed = math.sqrt(speed)
    scale = step / speed if speed > 0 else 0.0
    for j in range(n):
        plus_out[j] = q[j] + qd[j] * scale
        minus_out[j] = q[j] - qd[j] * scale
        state_out[j] = q[j]
        state_out[n + j] = qd[j]
    return speed


class RigidBodyTerms(DrakeRobot):
    """The model robot's rigid-body terms per sample (module docstring) on one plant context.

    :meth:`calc_into` writes τ_rigid (n) N·m, the momentum terms ``[p (n) N·m·s; τ_g + Cᵀq̇ (n) N·m]`` and J (6n) —
    the Jacobian of ``contact_point`` [m, flange frame], rows [ω; v], world frame, row-major — into three vectors
    (e.g. the views of one :meth:`buffer` ``[τ_rigid; p; τ_g + Cᵀq̇; J]``, :meth:`split`).
    (One object per thread: the context and scratch are its own.)"""

    def __init__(self, desc: RobotDescription, contact_point: tuple[float, float, float] = (0.0, 0.0, 0.0)):
        super().__init__(desc)
        n = desc.n
        self._zero = np.zeros(self.plant.num_velocities())
        self._contact = np.asarray(contact_point, dtype=float)
        self._state, self._plus, self._minus = np.empty(2 * n), np.empty(n), np.empty(n)
        self.calc_into(np.zeros(n), np.full(n, 0.1), np.zeros(n), *self.split(self.buffer()))   # compile / load

    def buffer(self) -> np.ndarray:
        """A preallocated output vector ``[τ_rigid; p; τ_g + Cᵀq̇; J]`` (9n)."""
        return np.empty(9 * self.description.n)

    def split(self, buffer: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The views ``(τ_rigid, [p; τ_g + Cᵀq̇], J)`` of a :meth:`buffer` for :meth:`calc_into`."""
        n = self.description.n
        return buffer[:n], buffer[n:3 * n], buffer[3 * n:]

    def calc_into(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, tau_out: np.ndarray,
                  momentum_out: np.ndarray, jac_out: np.ndarray) -> None:
        """The terms for one sample ``q, qd, qdd [n]`` (rad, rad/s, rad/s²): τ_rigid into ``tau_out`` (n),
        ``[p; τ_g + Cᵀq̇]`` into ``momentum_out`` (2n), J row-major into ``jac_out`` (6n)."""
        if not self._in_order:
            self._calc_reindexed(q, qd, qdd, tau_out, momentum_out, jac_out)
            return
        plant, ctx = self.plant, self.context
        speed = _displace(q, qd, FD_STEP, self._plus, self._minus, self._state)
        if speed > 0:
            plant.SetPositions(ctx, self._plus)
            m_plus = plant.CalcMassMatrix(ctx)
            plant.SetPositions(ctx, self._minus)
            m_minus = plant.CalcMassMatrix(ctx)
        plant.SetPositionsAndVelocities(ctx, self._state)
        m = plant.CalcMassMatrix(ctx)
        plant.CalcForceElementsContribution(ctx, self._forces)       # gravity
        id0 = plant.CalcInverseDynamics(ctx, self._zero, self._forces)     # Cq̇ − τ_g
        if speed == 0:
            m_plus = m_minus = m
        _combine(m_plus, m_minus, m, id0, qd, qdd, speed / (2 * FD_STEP), tau_out, momentum_out)
        jac_out[:] = plant.CalcJacobianSpatialVelocity(ctx, JacobianWrtVariable.kV, self.flange, self._contact,
                                                        self._world, self._world).ravel()

    def _calc_reindexed(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, tau_out: np.ndarray,
                        momentum_out: np.ndarray, jac_out: np.ndarray) -> None:
        """:meth:`calc_into` for a plant whose state is not just the arm's joints in order (the same law)."""
        n = qd.shape[0]
        speed = float(np.linalg.norm(qd))
        m = self.mass_matrix(q)
        m_plus = m_minus = m
        if speed > 0:
            u = FD_STEP * qd / speed
            m_plus, m_minus = self.mass_matrix(q + u), self.mass_matrix(q - u)
        id0 = self.inverse_dynamics(q, qd, np.zeros(n))
        _combine(m_plus, m_minus, m, id0, qd, qdd, speed / (2 * FD_STEP), tau_out, momentum_out)
        jac_out[:] = self.flange_jacobian(q, self._contact).ravel()

    def momentum_terms(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``p = M(q)q̇`` [N·m·s] and ``τ_g(q) + C(q,q̇)ᵀq̇`` [N·m] for one sample."""
        n = qd.shape[0]
        tau, momentum, jac = self.split(self.buffer())
        self.calc_into(np.asarray(q, float), np.asarray(qd, float), np.zeros(n), tau, momentum, jac)
        return momentum[:n].copy(), momentum[n:].copy()
