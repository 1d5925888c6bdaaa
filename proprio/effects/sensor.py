"""Other torque- and position-sensor effects: ripple, offset and gain, torque noise, encoder noise."""
from __future__ import annotations

import numpy as np

from proprio.effects.base import INF, TINY, EffectConfigError, JointEffect, diagonal_regressor
from proprio.signals import MotionSignals

__all__ = ["Ripple", "SensorOffsetGain", "TorqueNoise", "EncoderNoise"]


class Ripple(JointEffect):
    """Harmonic-drive torque ripple ``A sin(h·N·q + φ)`` [N·m]: its frequency ``h·N·|q̇|/2π`` follows joint speed.

    Fitted (linear) parameters ``sin_amplitude = A cos φ`` and ``cos_amplitude = A sin φ`` [N·m]; YAML may give
    ``amplitude`` + ``phase_deg`` instead. Settings ``gear_ratio`` N (100–160 on the iiwa) and ``harmonic`` h
    (cycles per wave-generator revolution, 2 for a harmonic drive).
    """
    name = "ripple"
    place = "sensor"
    linear = True
    parameters = {"sin_amplitude": (0.0, -INF, INF), "cos_amplitude": (0.0, -INF, INF)}
    settings = {"gear_ratio": (160.0, TINY, INF), "harmonic": (2.0, TINY, INF)}
    yaml_keys = ("amplitude", "phase_deg")      # converted by from_config (proprio.effects.schema)

    @classmethod
    def from_config(cls, block: dict | None, n: int) -> "JointEffect":
        block = dict(block or {})
        if "amplitude" in block:
            amp = np.asarray(block.pop("amplitude"), dtype=float)
            phase = np.radians(np.asarray(block.pop("phase_deg", 0.0), dtype=float))
            if np.any(amp < 0):
                raise EffectConfigError(f"ripple.amplitude must be >= 0, got {amp}")
            block["sin_amplitude"], block["cos_amplitude"] = amp * np.cos(phase), amp * np.sin(phase)
        return super().from_config(block, n)

    def _phase(self, s: MotionSignals) -> np.ndarray:
        return self.harmonic * self.gear_ratio * s.q

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        self._check_n(s)
        ph = self._phase(s)
        return self.sin_amplitude * np.sin(ph) + self.cos_amplitude * np.cos(ph)

    def regressor(self, s: MotionSignals) -> np.ndarray:
        self._check_n(s)
        ph = self._phase(s)
        return diagonal_regressor([np.sin(ph), np.cos(ph)])


class SensorOffsetGain(JointEffect):
    """Torque-sensor offset and gain error: contribution ``g·τ + o`` (measured = (1+g)·τ + o).

    Parameters ``offset`` o [N·m] and ``gain`` g [–] (relative); needs ``MotionSignals.tau``. A gain error is a few
    percent (prior σ 0.1): a fit that also corrects the rigid body cannot tell a common gain from a common mass
    scale, and the prior keeps the scale in the rigid body instead of a sensor reading half the torque.
    """
    name = "sensor_offset_gain"
    place = "sensor"
    linear = True
    parameters = {"gain": (0.0, -0.5, 0.5), "offset": (0.0, -INF, INF)}
    prior_std = {"gain": 0.1}

    def _tau(self, s: MotionSignals) -> np.ndarray:
        if s.tau is None:
            raise ValueError("sensor_offset_gain: MotionSignals.tau (the torque entering the sensor) is required")
        return s.tau

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        self._check_n(s)
        return self.gain * self._tau(s) + self.offset

    def regressor(self, s: MotionSignals) -> np.ndarray:
        self._check_n(s)
        return diagonal_regressor([self._tau(s), np.ones_like(s.q)])


class TorqueNoise(JointEffect):
    """White Gaussian torque-sensor noise, standard deviation ``std`` [N·m] per joint (needs a seeded ``rng``)."""
    name = "torque_noise"
    place = "sensor"
    linear = False
    parameters = {"std": (0.0, 0.0, INF)}

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        self._check_n(s)
        if rng is None:
            raise ValueError("torque_noise: a seeded rng (np.random.Generator) is required")
        return rng.standard_normal(s.q.shape) * self.std


class EncoderNoise(JointEffect):
    """Joint position sensor: white noise ``std`` [rad] then quantisation to ``resolution`` [rad] (0 = none).

    It contributes no torque; :meth:`measure` turns true positions into measured ones (YAML ``std_deg``,
    ``resolution_deg``).
    """
    name = "encoder_noise"
    place = "sensor"
    linear = False
    parameters = {"std": (0.0, 0.0, INF)}
    settings = {"resolution": (0.0, 0.0, INF)}

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        self._check_n(s)
        return np.zeros_like(s.q)

    def measure(self, q: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Measured positions ``[N,n]`` rad for true ``q``."""
        q_meas = q + rng.standard_normal(q.shape) * self.std
        res = self.resolution
        return np.where(res > 0, np.round(q_meas / np.where(res > 0, res, 1.0)) * res, q_meas)


