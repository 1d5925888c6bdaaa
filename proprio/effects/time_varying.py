"""Time-varying joint effects: their torque depends on the *session clock* ``MotionSignals.t`` [s] (the time since
the robot was switched on / the session started, not the time within one recording). The twin shifts every
recording's time by its config's ``session_time_s``; the diagnosis shifts each recording by its
``Recording.meta["session_time_s"]``, so a recording taken later sees the effect further along.

* :class:`OffsetDrift` (sensor side): a torque-sensor offset that settles from ``o0`` to ``o0 + Δo`` with time
  constant ``T`` (thermal drift of the strain gauges' bridge after switch-on).
* :class:`FrictionWarmup` (link side): the extra friction of a cold gearbox, viscous and Coulomb, that decays with
  time constant ``T`` as the lubricant warms up. Chosen over a dissipated-energy proxy because the twin's
  ``JointDrive`` evaluates friction per step from the link velocity alone (no energy state needed) and because the
  warm-up of a gearbox that is moved continuously, as in an excitation session, is close to exponential in time.
"""
from __future__ import annotations

import numpy as np

from proprio import friction_law
from proprio.effects.base import INF, JointEffect
from proprio.effects.friction import SmoothFriction
from proprio.signals import MotionSignals

__all__ = ["OffsetDrift", "FrictionWarmup"]


class OffsetDrift(JointEffect):
    """Drifting torque-sensor offset ``o(t) = o0 + Δo·(1 − exp(−t/T))`` [N·m] on the session clock ``t`` [s].

    Parameters ``offset`` o0 [N·m] (at session time 0), ``drift`` Δo [N·m] (the change still to come at t = 0),
    ``time_constant`` T [s]. Linear in ``offset`` and ``drift``, nonlinear in ``T``.
    """
    name = "offset_drift"
    place = "sensor"
    linear = False
    time_varying = True
    parameters = {"offset": (0.0, -INF, INF), "drift": (0.0, -INF, INF), "time_constant": (120.0, 1.0, 1e5)}

    def offset_at(self, t: np.ndarray) -> np.ndarray:
        """Offset ``[N, n]`` N·m at session times ``t [N]`` s."""
        return self.offset + self.drift * -np.expm1(-np.asarray(t, dtype=float)[:, None] / self.time_constant)

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        self._check_n(s)
        return self.offset_at(s.t)


class FrictionWarmup(SmoothFriction):
    """Cold-gearbox friction that fades as the joint warms up: ``exp(−t/T)·(F_v q̇ + F_c tanh(q̇/v_s))`` [N·m] on
    the session clock ``t`` [s], on top of the warm friction (``viscous_coulomb``), link side (dissipative).

    Parameters ``viscous`` F_v [N·m·s/rad] and ``coulomb`` F_c [N·m] (the excess at t = 0), ``time_constant`` T
    [s]; setting ``smooth_velocity`` v_s [rad/s].
    """
    name = "friction_warmup"
    place = "link"
    linear = False
    time_varying = True
    parameters = {"viscous": (0.0, 0.0, INF), "coulomb": (0.0, 0.0, INF), "time_constant": (120.0, 1.0, 1e5)}

    def friction(self, qd: np.ndarray, t: np.ndarray | float) -> np.ndarray:
        """τ_f [N·m] for velocities ``qd`` (``[n]`` or ``[N,n]``) at session time(s) ``t`` (scalar or ``[N]``) s."""
        t = np.asarray(t, dtype=float)
        cold = np.exp(-(t[..., None] if t.ndim else t) / self.time_constant)
        v = self._values
        return cold * friction_law.viscous_coulomb(qd, v["viscous"], v["coulomb"], v["smooth_velocity"])

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        self._check_n(s)
        return self.friction(s.qd, s.t)
