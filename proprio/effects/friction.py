"""Link-side friction, visible in τ_J and dissipative: viscous + Coulomb, Stribeck and load-dependent Coulomb."""
from __future__ import annotations

from typing import Any

import numpy as np

from proprio import friction_law
from proprio.description import RobotDescription
from proprio.effects.base import INF, TINY, JointEffect, diagonal_regressor
from proprio.signals import MotionSignals

__all__ = ["SmoothFriction", "ViscousCoulomb", "Stribeck", "LoadFriction", "robot_friction", "MAX_FRICTION_LOAD_GAIN"]

MAX_FRICTION_LOAD_GAIN = 0.2
"""Upper bound of the load-dependent friction's ``load_gain`` [-]: 20 % of the transmitted torque (harmonic drives
reported up to a few % — Wolf & Iskandar; the bound keeps the twin's inversion :func:`proprio.friction_law.load_from_net`
far from its pole at 1)."""


class SmoothFriction(JointEffect):
    """A friction effect whose Coulomb sign is the law of :mod:`proprio.friction_law`: its ``smooth_velocity``
    setting [rad/s] defaults to the library default :data:`proprio.friction_law.SMOOTH_VELOCITY` read when the effect
    is built (the class table shows the default at import)."""
    settings = {"smooth_velocity": (friction_law.SMOOTH_VELOCITY, TINY, INF)}

    def __init__(self, n: int, **params: Any) -> None:
        params.setdefault("smooth_velocity", friction_law.SMOOTH_VELOCITY)
        super().__init__(n, **params)

    def sign(self, qd: np.ndarray) -> np.ndarray:
        """The smooth sign ``tanh(q̇ / v_s)`` [-] of velocities ``qd`` [rad/s] (``[n]`` or ``[N,n]``)."""
        return friction_law.smooth_sign(qd, self._values["smooth_velocity"])


class ViscousCoulomb(SmoothFriction):
    """Link-side friction ``τ_f = F_v q̇ + F_c tanh(q̇ / v_s)`` [N·m] (:func:`proprio.friction_law.viscous_coulomb`;
    smooth sign, so ``τ_f q̇ ≥ 0`` always). A robot description's ``friction`` block is this effect
    (:func:`robot_friction`).

    Parameters ``viscous`` F_v [N·m·s/rad], ``coulomb`` F_c [N·m]; setting ``smooth_velocity`` v_s [rad/s].
    """
    name = "viscous_coulomb"
    place = "link"
    linear = True
    parameters = {"viscous": (0.0, 0.0, INF), "coulomb": (0.0, 0.0, INF)}

    def friction(self, qd: np.ndarray) -> np.ndarray:
        """τ_f [N·m] for joint velocities ``qd`` [rad/s] (``[n]`` per step or ``[N,n]``)."""
        v = self._values
        return friction_law.viscous_coulomb(qd, v["viscous"], v["coulomb"], v["smooth_velocity"])

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        self._check_n(s)
        return self.friction(s.qd)

    def regressor(self, s: MotionSignals) -> np.ndarray:
        self._check_n(s)
        return diagonal_regressor([s.qd, self.sign(s.qd)])


def robot_friction(robot: RobotDescription) -> ViscousCoulomb | None:
    """The ``viscous_coulomb`` effect of a robot description's link friction (``friction.viscous`` /
    ``friction.coulomb``) at the library's smoothing, or ``None`` when the description has no friction."""
    if not robot.has_friction:
        return None
    return ViscousCoulomb(robot.n, viscous=list(robot.friction_viscous), coulomb=list(robot.friction_coulomb))


class Stribeck(SmoothFriction):
    """Extra static friction that fades with speed: ``F_s exp(−(q̇/v_st)²) tanh(q̇/v_s)`` [N·m] (dissipative).

    Parameters ``static`` F_s [N·m] (breakaway minus Coulomb level), ``stribeck_velocity`` v_st [rad/s]; setting
    ``smooth_velocity`` v_s [rad/s]. Add it to ``viscous_coulomb`` for the full Stribeck curve.
    """
    name = "stribeck"
    place = "link"
    linear = False
    parameters = {"static": (0.0, 0.0, INF), "stribeck_velocity": (0.05, TINY, INF)}

    def friction(self, qd: np.ndarray) -> np.ndarray:
        """τ_f [N·m] for joint velocities ``qd`` (``[n]`` or ``[N,n]``)."""
        v = self._values
        return v["static"] * np.exp(-(qd / v["stribeck_velocity"]) ** 2) * self.sign(qd)

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        self._check_n(s)
        return self.friction(s.qd)




class LoadFriction(SmoothFriction):
    """Load-dependent Coulomb friction ``(F_c0 + k |τ_J|) tanh(q̇ / v_s)`` [N·m]
    (:func:`proprio.friction_law.load_coulomb`): the Coulomb level of a harmonic drive grows with the link-side torque
    ``τ_J`` its gear transmits (``MotionSignals.tau``; the load is the joint's own link torque, also for a coupled
    wrist — :mod:`proprio.friction_law`). Linear in its parameters; dissipative.

    Parameters ``coulomb`` F_c0 [N·m] (the level at no load), ``load_gain`` k [-]; setting ``smooth_velocity`` v_s
    [rad/s]. Needs ``MotionSignals.tau``.
    """
    name = "load_friction"
    place = "link"
    linear = True
    parameters = {"coulomb": (0.0, 0.0, INF), "load_gain": (0.0, 0.0, MAX_FRICTION_LOAD_GAIN)}

    def _load(self, s: MotionSignals) -> np.ndarray:
        if s.tau is None:
            raise ValueError(f"{self.name}: MotionSignals.tau (the link-side joint torque, the load) is required")
        return s.tau

    def friction(self, qd: np.ndarray, tau_load: np.ndarray) -> np.ndarray:
        """τ_f [N·m] for joint velocities ``qd`` [rad/s] and link torques ``tau_load`` [N·m] (``[n]`` or ``[N,n]``)."""
        v = self._values
        return friction_law.load_coulomb(qd, v["coulomb"], v["load_gain"], tau_load, v["smooth_velocity"])

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        self._check_n(s)
        return self.friction(s.qd, self._load(s))

    def regressor(self, s: MotionSignals) -> np.ndarray:
        self._check_n(s)
        sgn = self.sign(s.qd)
        return diagonal_regressor([sgn, sgn * np.abs(self._load(s))])
