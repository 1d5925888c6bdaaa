"""Sensor models of the twin: the link-side joint torque sensor and the joint position encoder.

Neither sensor feeds back into the twin's motion (the tracking controller uses the plant state, as the iiwa's
position loop uses its own high-resolution motor encoders), so both are applied to the logged true signals in one
vectorised pass over all samples — exact, and ~100× cheaper than a Python system evaluated every 1 ms step. They are
built from the same :mod:`proprio.systems.joint_effects` classes the identification and gap diagnosis fit.

Torque sensor chain (thesis §2.1): ``τ_meas = (1 + g)·(τ_J + τ_hyst + τ_lost + τ_ripple) + o + noise``, i.e. the
strain-gauge effects act on the transmitted τ_J, the gain/offset error on everything the gauge sees, and white
noise is added last. Every contribution is returned separately (the twin's ``tau_<effect>`` truth channels).
"""
from __future__ import annotations

import numpy as np

from proprio.systems.joint_effects import EncoderNoise, JointEffect, MotionSignals, SensorOffsetGain, TorqueNoise

__all__ = ["TorqueSensor", "PositionSensor"]

_GAUGE_ORDER = ("hysteresis", "lost_motion", "ripple")


class TorqueSensor:
    """The joint torque sensor: the sensor-side torque effects of a twin, applied in the physical order above."""

    def __init__(self, effects: list[JointEffect]):
        bad = [e.name for e in effects if e.place != "sensor" or isinstance(e, EncoderNoise)]
        if bad:
            raise ValueError(f"TorqueSensor: {bad} are not torque-sensor effects")
        by_name = {e.name: e for e in effects}
        self.gauge = [by_name[k] for k in _GAUGE_ORDER if k in by_name]
        self.offset_gain: SensorOffsetGain | None = by_name.get("sensor_offset_gain")
        self.noise: TorqueNoise | None = by_name.get("torque_noise")

    def measure(self, s: MotionSignals, tau_j: np.ndarray, rng: np.random.Generator
                ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Measured torque ``[N,n]`` N·m for true link motion ``s`` and true transmitted torque ``tau_j``, and the
        contribution of each effect (keys = effect names)."""
        s = s.with_tau(tau_j)
        parts: dict[str, np.ndarray] = {}
        seen = tau_j.copy()
        for eff in self.gauge:
            parts[eff.name] = eff.torque(s, rng)
            seen += parts[eff.name]
        if self.offset_gain is not None:
            parts[self.offset_gain.name] = self.offset_gain.torque(s.with_tau(seen), rng)
            seen = seen + parts[self.offset_gain.name]
        if self.noise is not None:
            parts[self.noise.name] = self.noise.torque(s, rng)
            seen = seen + parts[self.noise.name]
        return seen, parts


class PositionSensor:
    """The link-side joint position sensor: noise + quantisation (ideal without an ``encoder_noise`` effect)."""

    def __init__(self, encoder: EncoderNoise | None):
        self.encoder = encoder

    def measure(self, q: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Measured positions ``[N,n]`` rad."""
        return q.copy() if self.encoder is None else self.encoder.measure(q, rng)
