"""Torque-sensor effects that depend on the reversal travel r: hysteresis and lost motion."""
from __future__ import annotations

import math

import numpy as np

from proprio.effects.base import INF, TINY, JointEffect, motion_reversal_travel
from proprio.effects.dahl import DahlEffect
from proprio.reversals import ReversalTravel
from proprio.signals import MotionSignals

__all__ = ["Hysteresis", "LostMotion", "MAX_LOAD_GAIN"]

MAX_LOAD_GAIN = 0.1
"""Upper bound of ``load_gain`` [–]: the loop amplitude grows by at most 10 % of the load torque (the calibrated twin
has 2 %, Fig. 2.5's gravity-loaded joints); a fit beyond it is a light joint's loop taken for a load law."""


class Hysteresis(DahlEffect):
    """Torque-sensor hysteresis vs. joint travel since the last reversal (thesis §2.1, Fig. 2.5).

    The Dahl law of :mod:`proprio.effects.dahl` (the rate-independent solution of ``dτ/dr = σ(1 − τ/(d·τ_sat))``):
    ``τ_h = d·τ_sat + (τ_rev − d·τ_sat)·exp(−|r| / ρ)`` with ``d`` the segment's direction, ``r`` the reversal
    travel and ``τ_rev`` the value at the reversal (continuous across reversals; a fresh start is the virgin
    state τ_rev = 0). ``ρ = saturation_travel / 3`` so τ_h is within 5 % of saturation after ``saturation_travel``
    (6° → slope after 6° is e⁻³ ≈ 5 % of the slope at the reversal). Dahl was chosen over Bouc–Wen (more
    parameters, same loop shape for this purpose) and Preisach/Maxwell-slip (many elements) because two
    parameters per joint reproduce the thesis' loop and can be fitted from one triangular experiment.

    Parameters ``saturation`` τ_sat [N·m], ``load_gain`` [–] (τ_sat grows by ``load_gain·|τ|``, for the
    gravity-loaded joints 2/4), ``saturation_travel`` [rad] (YAML ``saturation_travel_deg``); setting
    ``reversal_velocity`` [rad/s] (deadband of the reversal detection).
    """
    name = "hysteresis"
    place = "sensor"
    linear = False
    parameters = {"saturation": (0.0, 0.0, INF), "load_gain": (0.0, 0.0, MAX_LOAD_GAIN),
                  "saturation_travel": (math.radians(6.0), TINY, INF)}
    settings = {"reversal_velocity": (2e-3, 0.0, INF)}

    @property
    def rho(self) -> np.ndarray:
        """``ρ = saturation_travel / 3`` [rad] per joint."""
        return self.saturation_travel / 3.0

    def dahl_level(self, s: MotionSignals) -> np.ndarray:
        return self._load_scale(s, self.saturation, self.load_gain)


class LostMotion(JointEffect):
    """Lost motion after a reversal: for ≈``window`` of travel the direction-dependent part of τ has not flipped.

    ``τ_lm = −d·c·A·exp(−(|r|/W)⁶)`` with ``d`` the new direction, ``r`` the reversal travel, ``A = amplitude +
    load_gain·|τ|`` the direction-dependent torque level that lags, ``c = 2`` after a reversal (the level flips from
    −dA to +dA) and ``c = 1`` when starting from standstill. With ``A`` equal to the Coulomb level the measured
    torque "barely changes" within the window (thesis §4 intro: absent changes of torque within ≈1° after
    reversals), then the full flip appears; the profile is flat (< 2 % change) up to W/2 and has released half
    of the flip at 0.94 W.

    Parameters ``amplitude`` A [N·m], ``load_gain`` [–], ``window`` W [rad] (YAML ``window_deg``); setting
    ``reversal_velocity`` [rad/s].
    """
    name = "lost_motion"
    place = "sensor"
    linear = False
    parameters = {"amplitude": (0.0, 0.0, INF), "load_gain": (0.0, 0.0, MAX_LOAD_GAIN),
                  "window": (math.radians(1.0), TINY, INF)}
    settings = {"reversal_velocity": (2e-3, 0.0, INF)}

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None,
               travel: ReversalTravel | None = None) -> np.ndarray:
        self._check_n(s)
        rt = travel or motion_reversal_travel(s, self.reversal_velocity)
        amp = self._load_scale(s, self.amplitude, self.load_gain)
        flip = np.where(rt.segment > 0, 2.0, 1.0)
        return -rt.direction * flip * amp * np.exp(-(np.abs(rt.r) / self.window) ** 6)


