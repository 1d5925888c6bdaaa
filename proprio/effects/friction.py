"""Link-side friction, visible in τ_J and dissipative: viscous + Coulomb and Stribeck."""
from __future__ import annotations

import numpy as np

from proprio.effects.base import INF, TINY, JointEffect, diagonal_regressor
from proprio.signals import MotionSignals

__all__ = ["ViscousCoulomb", "Stribeck"]




class ViscousCoulomb(JointEffect):
    """Link-side friction ``τ_f = F_v q̇ + F_c tanh(q̇ / v_s)`` [N·m] (smooth sign, so ``τ_f q̇ ≥ 0`` always).

    Parameters ``viscous`` F_v [N·m·s/rad], ``coulomb`` F_c [N·m]; setting ``smooth_velocity`` v_s [rad/s].
    """
    name = "viscous_coulomb"
    place = "link"
    linear = True
    parameters = {"viscous": (0.0, 0.0, INF), "coulomb": (0.0, 0.0, INF)}
    settings = {"smooth_velocity": (0.02, TINY, INF)}

    def friction(self, qd: np.ndarray) -> np.ndarray:
        """τ_f [N·m] for joint velocities ``qd`` (``[n]`` or ``[N,n]``)."""
        v = self._values
        return v["viscous"] * qd + v["coulomb"] * np.tanh(qd / v["smooth_velocity"])

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        self._check_n(s)
        return self.friction(s.qd)

    def regressor(self, s: MotionSignals) -> np.ndarray:
        self._check_n(s)
        return diagonal_regressor([s.qd, np.tanh(s.qd / self.smooth_velocity)])


class Stribeck(JointEffect):
    """Extra static friction that fades with speed: ``F_s exp(−(q̇/v_st)²) tanh(q̇/v_s)`` [N·m] (dissipative).

    Parameters ``static`` F_s [N·m] (breakaway minus Coulomb level), ``stribeck_velocity`` v_st [rad/s]; setting
    ``smooth_velocity`` v_s [rad/s]. Add it to ``viscous_coulomb`` for the full Stribeck curve.
    """
    name = "stribeck"
    place = "link"
    linear = False
    parameters = {"static": (0.0, 0.0, INF), "stribeck_velocity": (0.05, TINY, INF)}
    settings = {"smooth_velocity": (0.02, TINY, INF)}

    def friction(self, qd: np.ndarray) -> np.ndarray:
        """τ_f [N·m] for joint velocities ``qd`` (``[n]`` or ``[N,n]``)."""
        v = self._values
        return v["static"] * np.exp(-(qd / v["stribeck_velocity"]) ** 2) * np.tanh(qd / v["smooth_velocity"])

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        self._check_n(s)
        return self.friction(s.qd)


