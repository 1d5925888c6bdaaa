"""Joint effects outside the library, shipped as plugins (:mod:`proprio.effects.plugins`) for the open-world gap
benchmark: effects a harmonic-drive torque-sensing arm can have that no library effect can express. They are not in
:data:`~proprio.effects.registry.EFFECTS`; the twin and the diagnosis reach them only through their plugin paths
``"proprio.effects.open_world:<Class>"``, exactly as a user's own effect.

==================== ======= ======================================================== ===========================
class                 place   contribution to the measured τ [N·m]                     hint signal (joint j)
==================== ======= ======================================================== ===========================
``TorqueCrossTalk``   sensor  ``c_j τ_J,j+1``: the strain gauge of joint j picks up      ``tau_<j+1>``
                              the neighbouring joint's torque (wiring, shared bridge)
``PositionFriction``  link    ``(a_j cos k_j q_j + b_j sin k_j q_j) tanh(q̇_j/v_s)``:    ``q_<j>``
                              Coulomb level varying along the stroke (seal / bearing
                              preload that is not round)
``CableSpring``       link    ``k_j (q_j+1 − q_ref,j)``: a dress pack (cables, hoses)     ``q_<j+1>``
                              routed across joint j+1 twists with it and loads joint j
``NeighbourDrag``     link    ``c_j tanh(q̇_j+1/v_s)``: cables crossing joint j+1 drag   ``qd_<j+1>``
                              on link j when joint j+1 turns
``ConfigurationTorque`` link   ``k_j (q_j − q_0,j) + c_j sin q_j``: a gravity-             ``q_<j>``
                              compensation spring and a cable's torque in the joint's
                              own angle — position, not history
==================== ======= ======================================================== ===========================

All five are linear in their fitted parameters (their ``regressor`` is exact). Link-side ones depend on q and q̇
only (the plugin contract for the twin's drive). Three of them couple neighbouring joints, which no library effect
does (each acts on its own joint). A spring in the joint's *own* angle (``ConfigurationTorque``) is locally what the
Dahl hysteresis with a long saturation travel looks like along one stroke; the diagnosis names a reversal effect only
when it explains more than a configuration-only torque does (:mod:`proprio.diagnosis.candidates.configuration`).
"""
from __future__ import annotations

import numpy as np

from proprio import friction_law
from proprio.effects.base import INF, TINY, JointEffect, diagonal_regressor
from proprio.effects.friction import SmoothFriction
from proprio.signals import MotionSignals

__all__ = ["TorqueCrossTalk", "PositionFriction", "CableSpring", "NeighbourDrag", "ConfigurationTorque"]


def _next_joint(x: np.ndarray) -> np.ndarray:
    """``[N,n]`` → column j holds column j+1 of ``x`` (zero for the last joint)."""
    out = np.zeros_like(x)
    out[:, :-1] = x[:, 1:]
    return out


class TorqueCrossTalk(JointEffect):
    """Torque-sensor cross-talk from the next joint: ``τ_meas,j += c_j τ_J,j+1`` (needs ``MotionSignals.tau``, the
    transmitted torque). Parameter ``coupling`` c_j [–] (the last joint has no next joint: its c has no effect)."""
    name = "torque_cross_talk"
    place = "sensor"
    linear = True
    parameters = {"coupling": (0.0, -0.5, 0.5)}

    def _neighbour(self, s: MotionSignals) -> np.ndarray:
        if s.tau is None:
            raise ValueError(f"{self.name}: MotionSignals.tau (the torque entering the sensors) is required")
        return _next_joint(s.tau)

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        self._check_n(s)
        return self.coupling * self._neighbour(s)

    def regressor(self, s: MotionSignals) -> np.ndarray:
        self._check_n(s)
        return diagonal_regressor([self._neighbour(s)])


class PositionFriction(SmoothFriction):
    """Position-dependent Coulomb friction ``(a cos(k q) + b sin(k q)) tanh(q̇ / v_s)`` [N·m] (a friction level that
    varies along the stroke, with zero mean over a period: a library Coulomb term cannot take it).

    Parameters ``cos_amplitude`` a and ``sin_amplitude`` b [N·m]; settings ``order`` k [1/rad] and
    ``smooth_velocity`` v_s [rad/s]."""
    name = "position_friction"
    place = "link"
    linear = True
    parameters = {"cos_amplitude": (0.0, -INF, INF), "sin_amplitude": (0.0, -INF, INF)}
    settings = {"order": (3.0, TINY, INF), "smooth_velocity": (friction_law.SMOOTH_VELOCITY, TINY, INF)}

    def _columns(self, s: MotionSignals) -> list[np.ndarray]:
        sign = self.sign(s.qd)
        return [np.cos(self.order * s.q) * sign, np.sin(self.order * s.q) * sign]

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        self._check_n(s)
        c, si = self._columns(s)
        return self.cos_amplitude * c + self.sin_amplitude * si

    def regressor(self, s: MotionSignals) -> np.ndarray:
        self._check_n(s)
        return diagonal_regressor(self._columns(s))


class CableSpring(JointEffect):
    """A dress pack routed across joint j+1: it twists when joint j+1 turns and loads joint j like a torsion spring,
    ``k_j (q_j+1 − q_ref,j)`` [N·m] on joint j (the torque the drive must add to hold it).

    Parameter ``stiffness`` k_j [N·m/rad] (the last joint has no next joint); setting ``reference`` q_ref,j [rad]
    (YAML ``reference_deg``): the next joint's angle where the cables are relaxed."""
    name = "cable_spring"
    place = "link"
    linear = True
    parameters = {"stiffness": (0.0, -INF, INF)}
    settings = {"reference": (0.0, -INF, INF)}

    def _column(self, s: MotionSignals) -> np.ndarray:
        return (_next_joint(s.q) - self.reference) * (np.arange(self.n) < self.n - 1)

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        self._check_n(s)
        return self.stiffness * self._column(s)

    def regressor(self, s: MotionSignals) -> np.ndarray:
        self._check_n(s)
        return diagonal_regressor([self._column(s)])


class NeighbourDrag(SmoothFriction):
    """Drag of the cables crossing the next joint: ``c_j tanh(q̇_j+1 / v_s)`` [N·m] on joint j.

    Parameter ``drag`` c_j [N·m] (the last joint has no next joint); setting ``smooth_velocity`` v_s [rad/s]."""
    name = "neighbour_drag"
    place = "link"
    linear = True
    parameters = {"drag": (0.0, -INF, INF)}

    def _column(self, s: MotionSignals) -> np.ndarray:
        return self.sign(_next_joint(s.qd)) * (np.arange(self.n) < self.n - 1)

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        self._check_n(s)
        return self.drag * self._column(s)

    def regressor(self, s: MotionSignals) -> np.ndarray:
        self._check_n(s)
        return diagonal_regressor([self._column(s)])


class ConfigurationTorque(JointEffect):
    """``k_j (q_j − q_0,j) + c_j sin q_j`` [N·m]: a gravity-compensation spring (stiffness ``spring`` k [N·m/rad] about
    ``reference`` q_0 [rad], a setting) and a cable-like torque (``cable`` c [N·m]) in the joint's own angle — a torque
    of the configuration alone, no history."""
    name = "configuration_torque"
    place = "link"
    linear = True
    parameters = {"spring": (0.0, -INF, INF), "cable": (0.0, -INF, INF)}
    settings = {"reference": (0.0, -INF, INF)}

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        self._check_n(s)
        return self.spring * (s.q - self.reference) + self.cable * np.sin(s.q)

    def regressor(self, s: MotionSignals) -> np.ndarray:
        self._check_n(s)
        return diagonal_regressor([s.q - self.reference, np.sin(s.q)])
