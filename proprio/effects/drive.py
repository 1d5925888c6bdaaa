"""The motor side of the drive, hidden behind the torque sensor: motor inertia/friction and elasticity."""
from __future__ import annotations

import numpy as np

from proprio import friction_law
from proprio.effects.base import INF, TINY, JointEffect
from proprio.effects.friction import SmoothFriction
from proprio.signals import MotionSignals

__all__ = ["Motor", "Elasticity"]


class Motor(SmoothFriction):
    """The motor side of the drive, hidden behind the torque sensor: reflected motor inertia B and motor friction.
    Configured by the twin's top-level ``drive`` block; not in :data:`EFFECTS`, because it adds nothing to τ_J that
    a fit on torque data could find.

    Motor side ``B θ̈ = τ_m − τ_f,m(θ̇) − τ_J``. With a rigid drive (θ = q) Drake's plant carries B as reflected rotor
    inertia and the sensor sees ``τ_J = τ_m − τ_f,m − B q̈``; with ``elasticity`` the drive integrates θ. Either way
    τ_J = τ_rbd + τ_f,link − Jᵀ f_ext is fixed by the link motion, so :meth:`torque` is zero: these effects show up only
    through the motion (tracking error, inertia the controller must move).

    Parameters ``motor_inertia`` B [kg·m²] (link-side reflected, ``ρ² I_rotor``), ``motor_viscous`` [N·m·s/rad],
    ``motor_coulomb`` [N·m]; setting ``smooth_velocity`` [rad/s] (the law of :mod:`proprio.friction_law`).
    """
    name = "motor"
    place = "motor"
    linear = False
    parameters = {"motor_inertia": (0.0, 0.0, INF), "motor_viscous": (0.0, 0.0, INF),
                  "motor_coulomb": (0.0, 0.0, INF)}

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        self._check_n(s)
        return np.zeros_like(s.q)

    def friction(self, theta_dot: np.ndarray) -> np.ndarray:
        """Motor-side friction [N·m] (hidden from τ_J), dissipative, for motor velocities ``theta_dot`` [rad/s]."""
        v = self._values
        return friction_law.viscous_coulomb(theta_dot, v["motor_viscous"], v["motor_coulomb"], v["smooth_velocity"])


class Elasticity(JointEffect):
    """Series-elastic joint with a motor-side state (thesis eq. 3.6), simulated by ``proprio.systems.joint_drive``
    with the twin's ``drive`` block (:class:`Motor`: motor inertia B and motor friction); the spring is Drake's
    implicit PD-controlled actuator, so realistic stiffness is stable at 1 ms.

    Spring ``τ_s = K(θ − q) + D(θ̇ − q̇)`` between motor angle θ and link angle q drives the link and is what the
    sensor measures. The torque sensor sits on the link side, so τ_J is fully determined by the link motion
    (``τ_rbd + τ_f,link − Jᵀf_ext``): elasticity adds **nothing directly** to τ_J (:meth:`torque` is zero). It shows up
    in the data through the motion: a deflection ``τ/K`` of the link from the motor-side-controlled position, a
    tracking lag and a lightly damped resonance near ``√(K/μ)`` in q and hence in τ_rbd(q, q̇, q̈); and a motor-side
    position sensor would read θ ≠ q (the twin, like the iiwa, measures the link-side q).

    Parameters ``stiffness`` K [N·m/rad] (> 0), ``damping`` D [N·m·s/rad].
    """
    name = "elasticity"
    place = "motor"
    linear = False
    parameters = {"stiffness": (1e4, TINY, INF), "damping": (10.0, 0.0, INF)}

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        self._check_n(s)
        return np.zeros_like(s.q)


