"""Sensor models of the twin: the link-side joint torque sensor and the joint position encoder.

Two forms of the same models (built from the :mod:`proprio.effects` classes the identification and gap
diagnosis fit):

* :class:`TorqueSensor` / :class:`PositionSensor` — vectorised over all samples of a logged motion. Neither sensor
  feeds back into the twin's motion (the tracking controller uses the plant state, as the iiwa's position loop uses
  its motor encoders), so the twin applies them to its 1 kHz log in one pass: exact and far cheaper than a Python
  system evaluated every 1 ms step.
* :class:`TorqueSensorSystem` — the streaming form, a Drake ``LeafSystem`` with the reversal/hysteresis state as
  discrete state (one vectorised update per step), for live diagrams; :func:`AddTorqueSensor` adds it with Drake's
  C++ ``RandomSource`` for the white noise. It reproduces :class:`TorqueSensor` sample by sample (tests).

Torque sensor chain (thesis §2.1): ``τ_meas = (1 + g)·(τ_J + τ_hyst + τ_lost + τ_ripple) + o + o_d(t) + noise``,
i.e. the strain-gauge effects act on the transmitted τ_J, the gain/offset error on everything the gauge sees, a
drifting offset ``o_d`` (``offset_drift``, on the session clock ``MotionSignals.t``) adds to it, and white noise is
added last. Sensor-side plugins (:mod:`proprio.effects.plugins`) act with the strain-gauge effects, after the
library's, on the transmitted τ_J (``s.tau``). Every contribution is returned separately (the twin's
``tau_<effect>`` truth channels). The streaming :class:`TorqueSensorSystem` models the library's time-invariant
effects only (it has no session clock) and refuses the others.
"""
from __future__ import annotations

import numpy as np
from pydrake.common import RandomDistribution
from pydrake.systems.framework import BasicVector, Context, DiagramBuilder, DiscreteValues, LeafSystem
from pydrake.systems.primitives import Adder, Gain, RandomSource

from proprio.effects import (EncoderNoise, Hysteresis, JointEffect, LostMotion, OffsetDrift, Ripple,
                             SensorOffsetGain, TorqueNoise)
from proprio.effects.dahl import DahlState, dahl_advance, dahl_start, dahl_value
from proprio.signals import MotionSignals

__all__ = ["TorqueSensor", "PositionSensor", "TorqueSensorSystem", "AddTorqueSensor"]

_GAUGE_ORDER = ("hysteresis", "lost_motion", "ripple")
_SENSOR_LIBRARY = ("sensor_offset_gain", "offset_drift", "torque_noise")   # library sensor effects past the gauge


class TorqueSensor:
    """The joint torque sensor: the sensor-side torque effects of a twin, applied in the physical order above."""

    def __init__(self, effects: list[JointEffect]):
        bad = [e.name for e in effects if e.place != "sensor" or isinstance(e, EncoderNoise)]
        if bad:
            raise ValueError(f"TorqueSensor: {bad} are not torque-sensor effects")
        by_name = {e.name: e for e in effects}
        library = set(_GAUGE_ORDER) | set(_SENSOR_LIBRARY)
        # the library's strain-gauge effects in their order, then sensor-side plugins in the config's order
        self.gauge = [by_name[k] for k in _GAUGE_ORDER if k in by_name] + \
            [e for e in effects if e.name not in library]
        self.offset_gain: SensorOffsetGain | None = by_name.get("sensor_offset_gain")
        self.drift: OffsetDrift | None = by_name.get("offset_drift")
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
        if self.drift is not None:
            parts[self.drift.name] = self.drift.torque(s, rng)
            seen = seen + parts[self.drift.name]
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


class TorqueSensorSystem(LeafSystem):
    """Streaming torque sensor (noise-free part of :class:`TorqueSensor`) for ``n`` joints, sampled every
    ``time_step``.

    Input ports: ``tau_J`` [n] N·m (true transmitted torque), ``link_state`` [2n] = [q; q̇]. Output port:
    ``tau_measured`` [n] N·m = ``(1+g)(τ_J + hysteresis + lost motion + ripple) + o``. Discrete state per joint
    (the online form of :func:`~proprio.effects.reversal_travel`): direction d, has-reversed flag,
    running max/min of q in the current segment, anchor, hysteresis value at the last reversal, and the previous
    sample's saturation level. The output at a sample uses the state updated with that sample (direct feedthrough).
    """
    _FIELDS = ("d", "reversed", "hi", "lo", "anchor", "tau_rev", "sat_prev")

    def __init__(self, n: int, effects: list[JointEffect], time_step: float = 1e-3):
        super().__init__()
        varying = [e.name for e in effects if e.time_varying]
        if varying:
            raise ValueError(f"TorqueSensorSystem: time-varying effect(s) {varying} need the session clock; "
                             "use the vectorised TorqueSensor")
        sensor = TorqueSensor([e for e in effects if not isinstance(e, TorqueNoise)])
        others = [e.name for e in sensor.gauge if e.name not in _GAUGE_ORDER]
        if others:
            raise ValueError(f"TorqueSensorSystem: {others} are not library effects; the streaming sensor models "
                             f"{list(_GAUGE_ORDER) + ['sensor_offset_gain', 'torque_noise']} (plugins: TorqueSensor)")
        by_type = {type(e): e for e in sensor.gauge}
        self.n = n
        self.hysteresis: Hysteresis | None = by_type.get(Hysteresis)
        self.lost_motion: LostMotion | None = by_type.get(LostMotion)
        self.ripple: Ripple | None = by_type.get(Ripple)
        self.offset_gain = sensor.offset_gain
        eps = [e.reversal_velocity for e in (self.hysteresis, self.lost_motion) if e is not None]
        if len(eps) == 2 and not np.array_equal(eps[0], eps[1]):
            raise ValueError("TorqueSensorSystem: hysteresis and lost_motion must share reversal_velocity")
        self._eps = eps[0] if eps else np.full(n, np.inf)
        # the hysteresis' Dahl law (ρ a third of its saturation travel); without one its level is 0 and ρ = ∞
        # leaves the carried value, 0, unchanged
        self._rho = self.hysteresis.saturation_travel / 3.0 if self.hysteresis is not None else np.full(n, np.inf)
        self._tau = self.DeclareVectorInputPort("tau_J", n)
        self._x = self.DeclareVectorInputPort("link_state", 2 * n)
        self._state = self.DeclareDiscreteState(len(self._FIELDS) * n)
        self.DeclarePeriodicDiscreteUpdateEvent(time_step, 0.0, self._update)
        self.DeclareInitializationDiscreteUpdateEvent(self._initialize)
        self.DeclareVectorOutputPort("tau_measured", n, self._output)

    def _unpack(self, v: np.ndarray) -> dict[str, np.ndarray]:
        return {k: v[i * self.n:(i + 1) * self.n] for i, k in enumerate(self._FIELDS)}

    def _sat(self, tau: np.ndarray) -> np.ndarray:
        h = self.hysteresis
        return h.saturation + h.load_gain * np.abs(tau) if h is not None else np.zeros(self.n)

    def _advance(self, st: dict[str, np.ndarray], q: np.ndarray, qd: np.ndarray, tau: np.ndarray
                 ) -> dict[str, np.ndarray]:
        """The state after taking in one sample (q, q̇, τ)."""
        new = dahl_advance(self._dahl(st), q, qd, self._sat(tau), self._rho, self._eps)
        flip = (new.d != st["d"]) & (st["d"] != 0)
        return {"d": new.d, "reversed": np.where(flip, 1.0, st["reversed"]), "hi": new.hi, "lo": new.lo,
                "anchor": new.anchor, "tau_rev": new.tau_rev, "sat_prev": new.level_prev}

    @staticmethod
    def _dahl(st: dict[str, np.ndarray]) -> DahlState:
        """The hysteresis' share of the state: the Dahl law's reversal state (:mod:`proprio.effects.dahl`)."""
        return DahlState(st["d"], st["hi"], st["lo"], st["anchor"], st["tau_rev"], st["sat_prev"])

    def _measure(self, st: dict[str, np.ndarray], q: np.ndarray, tau: np.ndarray) -> np.ndarray:
        r = q - st["anchor"]
        seen = tau.copy()
        if self.hysteresis is not None:
            seen += dahl_value(self._dahl(st), q, self._rho)
        if self.lost_motion is not None:
            lm = self.lost_motion
            amp = lm.amplitude + lm.load_gain * np.abs(tau)
            seen += -st["d"] * (1.0 + st["reversed"]) * amp * np.exp(-(np.abs(r) / lm.window) ** 6)
        if self.ripple is not None:
            ph = self.ripple.harmonic * self.ripple.gear_ratio * q
            seen += self.ripple.sin_amplitude * np.sin(ph) + self.ripple.cos_amplitude * np.cos(ph)
        if self.offset_gain is not None:
            seen = (1.0 + self.offset_gain.gain) * seen + self.offset_gain.offset
        return seen

    def _inputs(self, context: Context) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        x = self._x.Eval(context)
        return x[:self.n], x[self.n:], self._tau.Eval(context)

    def _initialize(self, context: Context, discrete_state: DiscreteValues) -> None:
        q, qd, tau = self._inputs(context)
        # the state *before* the first sample: the first sample then starts segment 0 at q0 without a reversal
        st = dahl_start(q, qd, self._sat(tau), self._eps)
        discrete_state.set_value(self._state, np.concatenate([st.d, np.zeros(self.n), st.hi, st.lo, st.anchor,
                                                              st.tau_rev, st.level_prev]))

    def _update(self, context: Context, discrete_state: DiscreteValues) -> None:
        q, qd, tau = self._inputs(context)
        st = self._advance(self._unpack(context.get_discrete_state(self._state).value()), q, qd, tau)
        discrete_state.set_value(self._state, np.concatenate([st[k] for k in self._FIELDS]))

    def _output(self, context: Context, output: BasicVector) -> None:
        q, qd, tau = self._inputs(context)
        st = self._advance(self._unpack(context.get_discrete_state(self._state).value()), q, qd, tau)
        output.SetFromVector(self._measure(st, q, tau))


def AddTorqueSensor(builder: DiagramBuilder, n: int, effects: list[JointEffect], time_step: float = 1e-3,
                    name: str = "torque_sensor") -> tuple[TorqueSensorSystem, Adder]:
    """Add a :class:`TorqueSensorSystem` and, if ``effects`` has ``torque_noise``, Drake's C++ ``RandomSource``
    (Gaussian, sampled every ``time_step``) scaled by σ and added to its output. Returns ``(sensor, output)``
    where ``output.get_output_port()`` is the measured torque (seed the noise with
    ``diagram.SetRandomContext(context, RandomGenerator(seed))``)."""
    sensor = builder.AddSystem(TorqueSensorSystem(n, effects, time_step))
    sensor.set_name(name)
    adder = builder.AddSystem(Adder(2, n))
    adder.set_name(f"{name}_noise_sum")
    builder.Connect(sensor.GetOutputPort("tau_measured"), adder.get_input_port(0))
    noise = next((e for e in effects if isinstance(e, TorqueNoise)), None)
    std = noise.std if noise is not None else np.zeros(n)
    source = builder.AddSystem(RandomSource(RandomDistribution.kGaussian, n, time_step))
    gain = builder.AddSystem(Gain(std))
    builder.Connect(source.get_output_port(0), gain.get_input_port())
    builder.Connect(gain.get_output_port(), adder.get_input_port(1))
    return sensor, adder
