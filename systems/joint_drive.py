"""The joint drive: motor torque command → torque acting on the links, with the motor side (series elasticity, motor
inertia, motor friction: hidden behind the torque sensor) and the link-side friction (visible in τ_J).

One Python :class:`JointDrive` ``LeafSystem`` does all per-step Python work of the twin, vectorised over the joints:

* **rigid drive** (no ``elasticity`` effect): the link receives ``u = τ_m − τ_f,link(q̇)``; the transmitted,
  sensed torque is ``τ_J = τ_m``.
* **elastic drive** (``elasticity`` effect, thesis eq. 3.6): discrete motor state ``[θ, θ̇]`` (rad, rad/s),
  ``B θ̈ = τ_m − τ_f,m(θ̇) − τ_s``, spring ``τ_s = K(θ − q) + D(θ̇ − q̇)``; the link receives
  ``u = τ_s − τ_f,link(q̇)`` and the sensor sees ``τ_J = τ_s``. The motor state is advanced with semi-implicit
  Euler at the plant's period.

Either way ``τ_J = u + τ_f,link`` and, from the link dynamics, ``τ_J = τ_rbd(q, q̇, q̈) + τ_f,link − Jᵀ f_ext``: the
twin recovers the true τ_J from the logged ``actuation`` port and q̇.

Friction is applied explicitly (from the state at the start of the step), which is stable while
``(c_j / M_jj)·dt < 2`` with ``c_j`` the friction's slope ``F_v + F_c/v_s (+ F_s/v_s)``; :func:`check_explicit_friction`
refuses configurations that violate it with margin.
"""
from __future__ import annotations

import numpy as np
from pydrake.systems.framework import BasicVector, Context, DiagramBuilder, DiscreteValues, LeafSystem

from proprio.systems.joint_effects import Elasticity, JointEffect, Stribeck, ViscousCoulomb

__all__ = ["JointDrive", "AddJointDrive", "check_explicit_friction", "friction_slope"]


def friction_slope(link_effects: list[JointEffect]) -> np.ndarray:
    """Largest ``∂τ_f/∂q̇`` [N·m·s/rad] per joint of the velocity-dependent link friction (at q̇ = 0)."""
    slope = 0.0
    for eff in link_effects:
        if isinstance(eff, ViscousCoulomb):
            slope = slope + eff.viscous + eff.coulomb / eff.smooth_velocity
        elif isinstance(eff, Stribeck):
            slope = slope + eff.static / eff.smooth_velocity
    return np.asarray(slope, dtype=float)


def check_explicit_friction(link_effects: list[JointEffect], mass_diagonal: np.ndarray, time_step: float) -> None:
    """Raise ``ValueError`` when explicit friction would make the discrete twin unstable (margin 2×)."""
    ratio = friction_slope(link_effects) * time_step / np.asarray(mass_diagonal)
    if np.any(ratio > 1.0):
        j = int(np.argmax(ratio))
        raise ValueError(f"link friction of joint {j + 1} is too stiff for time_step {time_step:g} s (slope·dt/M = "
                         f"{ratio[j]:.2f} > 1): raise smooth_velocity or lower the Coulomb level")


class JointDrive(LeafSystem):
    """Drive + link friction for ``n`` joints; the only per-step Python of the twin (one vectorised output).

    Input ports: ``motor_torque`` [n] N·m (the controller's command), ``link_state`` [2n] = [q; q̇] (plant state).
    Output ports: ``actuation`` [n] N·m = τ_J − τ_f,link (to the plant's actuation input) and, for the elastic
    drive, ``motor_state`` [2n] = [θ; θ̇]. τ_f,link is a function of the logged q̇ only, so the twin recomputes it
    (and τ_J = actuation + τ_f,link) from the log instead of logging a second Python port.
    """

    def __init__(self, n: int, link_effects: list[JointEffect], elasticity: Elasticity | None = None,
                 time_step: float = 1e-3):
        super().__init__()
        for eff in link_effects:
            if not isinstance(eff, (ViscousCoulomb, Stribeck)):
                raise ValueError(f"JointDrive: {eff.name} is not a link-side friction effect")
        self.n = n
        self.link_effects = list(link_effects)
        self.elasticity = elasticity
        self.time_step = time_step
        self._u_motor = self.DeclareVectorInputPort("motor_torque", n)
        self._u_link = self.DeclareVectorInputPort("link_state", 2 * n)
        if elasticity is not None:
            self._state = self.DeclareDiscreteState(2 * n)
            self.DeclarePeriodicDiscreteUpdateEvent(time_step, 0.0, self._update_motor)
            self.DeclareStateOutputPort("motor_state", self._state)
        self.DeclareVectorOutputPort("actuation", n, self._calc_actuation)

    def link_friction(self, qd: np.ndarray) -> np.ndarray:
        """τ_f,link [N·m] for velocities ``qd`` (``[n]`` or ``[N,n]``): the sum of the link friction effects."""
        out = np.zeros_like(qd)
        for eff in self.link_effects:
            out = out + eff.friction(qd)
        return out

    def _spring(self, context: Context, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        x = context.get_discrete_state(self._state).value()
        el = self.elasticity
        return el.stiffness * (x[:self.n] - q) + el.damping * (x[self.n:] - qd)

    def _calc_actuation(self, context: Context, output: BasicVector) -> None:
        x = self._u_link.Eval(context)
        if self.elasticity is None:
            tau_j = self._u_motor.Eval(context)
        else:
            tau_j = self._spring(context, x[:self.n], x[self.n:])
        output.SetFromVector(tau_j - self.link_friction(x[self.n:]))

    def _update_motor(self, context: Context, discrete_state: DiscreteValues) -> None:
        el = self.elasticity
        n = self.n
        x = context.get_discrete_state(self._state).value()
        link = self._u_link.Eval(context)
        tau_m = self._u_motor.Eval(context)
        tau_s = self._spring(context, link[:n], link[n:])
        theta_dot = x[n:] + self.time_step / el.motor_inertia * (tau_m - el.motor_friction(x[n:]) - tau_s)
        discrete_state.set_value(self._state, np.concatenate([x[:n] + self.time_step * theta_dot, theta_dot]))

    def set_motor_state(self, context: Context, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> None:
        """Start the elastic drive in equilibrium with link state (q, q̇) carrying torque ``tau``:
        θ = q + τ/K, θ̇ = q̇ (no-op for the rigid drive)."""
        if self.elasticity is not None:
            context.SetDiscreteState(self._state, np.concatenate([q + tau / self.elasticity.stiffness, qd]))


def AddJointDrive(builder: DiagramBuilder, n: int, link_effects: list[JointEffect],
                  elasticity: Elasticity | None = None, time_step: float = 1e-3,
                  name: str = "joint_drive") -> JointDrive:
    """Add a :class:`JointDrive` to ``builder`` (ports ``motor_torque``, ``link_state`` → ``actuation``)."""
    drive = builder.AddSystem(JointDrive(n, link_effects, elasticity, time_step))
    drive.set_name(name)
    return drive
