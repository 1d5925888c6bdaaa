"""Sensor models of the twin: the link-side joint torque sensor and the joint position encoder.

Each model is the effect library's laws (:mod:`proprio.effects`), in two forms that call the same code:

* :class:`TorqueSensor` — the batch form over a whole motion ``[N, n]`` (the diagnosis' model
  :meth:`proprio.diagnosis.data.SimModel.predict_parts`, the offline gap benchmark);
* :class:`TorqueSensorSystem` (added by :func:`AddTorqueSensor`) and the encoder Diagram of :func:`AddEncoder` —
  the Drake Systems of the twin's Diagram (``proprio.diagrams.twin``), one sample per time step. The torque sensor
  keeps the state of the reversal-dependent effects (hysteresis, lost motion: :meth:`~proprio.effects.Hysteresis.step`)
  as discrete state and evaluates the memoryless ones (ripple, offset/gain, drift, plugins) by their ``torque`` on
  the one sample; the white noise comes from Drake's C++ ``RandomSource`` (seeded with the Diagram's random
  context) through :meth:`~proprio.effects.TorqueNoise.from_normal`. The encoder is
  :meth:`~proprio.effects.EncoderNoise.reading` in Drake's C++ primitives (``RandomSource``, ``Gain``, ``Adder``,
  ``WrapToSystem``). Tests: the System's output equals the batch form on the same inputs to 1e-12 N·m.

Torque sensor chain (thesis §2.1): ``τ_meas = (1 + g)·(τ_J + τ_hyst + τ_lost + τ_ripple) + o + o_d(t) + noise``,
i.e. the strain-gauge effects act on the transmitted τ_J, the gain/offset error on everything the gauge sees, a
drifting offset ``o_d`` (``offset_drift``, on the session clock ``MotionSignals.t``) adds to it, and white noise is
added last. Sensor-side plugins (:mod:`proprio.effects.plugins`) act with the strain-gauge effects, after the
library's, on the transmitted τ_J (``s.tau``); in the twin they are evaluated one sample at a time (a sensor-side
plugin is a function of the current sample: t, q, q̇, q̈, τ_J). Every contribution is returned separately (the
twin's ``tau_<effect>`` truth channels).
"""
from __future__ import annotations

import numpy as np
from pydrake.common import RandomDistribution
from pydrake.systems.framework import Context, Diagram, DiagramBuilder, DiscreteValues, LeafSystem
from pydrake.systems.primitives import Adder, Demultiplexer, Gain, MatrixGain, RandomSource, WrapToSystem

from proprio.effects import (EncoderNoise, JointEffect, OffsetDrift, SensorOffsetGain, TorqueNoise)
from proprio.signals import MotionSignals

__all__ = ["TorqueSensor", "TorqueSensorSystem", "AddTorqueSensor", "AddEncoder"]

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

    @property
    def effects(self) -> list[JointEffect]:
        """All effects in the order they act (gauge, offset/gain, drift, noise)."""
        return self.gauge + [e for e in (self.offset_gain, self.drift, self.noise) if e is not None]

    def measure(self, s: MotionSignals, tau_j: np.ndarray, rng: np.random.Generator | None = None
                ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Measured torque ``[N,n]`` N·m for true link motion ``s`` and true transmitted torque ``tau_j``, and the
        contribution of each effect (keys = effect names). ``rng`` is needed only with ``torque_noise``."""
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


class TorqueSensorSystem(LeafSystem):
    """The twin's joint torque sensor for ``n`` joints: every sensor-side effect of ``effects`` (not the encoder's),
    one sample every ``time_step`` [s] (module docstring).

    Input ports: ``tau_J`` [n] N·m (true transmitted torque), ``link_state`` [2n] = [q; q̇] (rad, rad/s), ``qdd`` [n]
    rad/s², ``noise`` [n] (standard-normal draws, e.g. a ``RandomSource``). Output ports (sample and hold: the
    sample taken at the last update, i.e. the previous time step): ``tau_measured`` [n] N·m and ``record``
    [(2 + k)·n] = [τ_meas; τ_J; the contribution of each of the k effects in :attr:`names` order] N·m. Discrete
    state: the per-step state of the stateful effects (:meth:`~proprio.effects.Hysteresis.step`). The effects see
    the session clock ``context time + session_time_s`` [s].
    """

    def __init__(self, n: int, effects: list[JointEffect], time_step: float = 1e-3, session_time_s: float = 0.0):
        super().__init__()
        sensor = TorqueSensor([e for e in effects if e.place == "sensor" and not isinstance(e, EncoderNoise)])
        self.n = n
        self.sensor = sensor
        self.names = [e.name for e in sensor.effects]
        self.session_time_s = float(session_time_s)
        self._stateful = [hasattr(e, "step") for e in sensor.gauge]
        sizes = [e.state_size * n if st else 0 for e, st in zip(sensor.gauge, self._stateful)]
        self._slices = [slice(a, a + b) for a, b in zip(np.cumsum([0] + sizes[:-1]), sizes)]
        self._tau = self.DeclareVectorInputPort("tau_J", n)
        self._x = self.DeclareVectorInputPort("link_state", 2 * n)
        self._qdd = self.DeclareVectorInputPort("qdd", n)
        self._z = self.DeclareVectorInputPort("noise", n)
        self._effect_state = self.DeclareDiscreteState(max(sum(sizes), 1))
        self._measured = self.DeclareDiscreteState(n)
        self._record = self.DeclareDiscreteState((2 + len(self.names)) * n)
        self.DeclarePeriodicDiscreteUpdateEvent(time_step, 0.0, self._update)
        self.DeclareInitializationDiscreteUpdateEvent(self._initialize)
        self.DeclareStateOutputPort("tau_measured", self._measured)
        self.DeclareStateOutputPort("record", self._record)

    def _inputs(self, context: Context) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        x = self._x.Eval(context)
        return x[:self.n], x[self.n:], self._tau.Eval(context)

    def _initialize(self, context: Context, discrete_state: DiscreteValues) -> None:
        q, qd, tau = self._inputs(context)
        x = np.zeros(discrete_state.get_vector(self._effect_state).size())
        for eff, st, sl in zip(self.sensor.gauge, self._stateful, self._slices):
            if st:
                x[sl] = eff.initial_state(q, qd, tau)
        discrete_state.set_value(self._effect_state, x)

    def _update(self, context: Context, discrete_state: DiscreteValues) -> None:
        q, qd, tau = self._inputs(context)
        x = context.get_discrete_state(self._effect_state).value().copy()
        s = MotionSignals(np.array([context.get_time() + self.session_time_s]), q[None], qd[None],
                          self._qdd.Eval(context)[None], tau[None])
        sensor, parts = self.sensor, []
        seen = tau.copy()
        for eff, st, sl in zip(sensor.gauge, self._stateful, self._slices):
            if st:
                x[sl], c = eff.step(x[sl], q, qd, tau)
            else:
                c = eff.torque(s)[0]
            parts.append(c)
            seen = seen + c
        if sensor.offset_gain is not None:
            parts.append(sensor.offset_gain.torque(s.with_tau(seen[None]))[0])
            seen = seen + parts[-1]
        if sensor.drift is not None:
            parts.append(sensor.drift.torque(s)[0])
            seen = seen + parts[-1]
        if sensor.noise is not None:
            parts.append(sensor.noise.from_normal(self._z.Eval(context)))
            seen = seen + parts[-1]
        discrete_state.set_value(self._effect_state, x)
        discrete_state.set_value(self._measured, seen)
        discrete_state.set_value(self._record, np.concatenate([seen, tau, *parts]))


def AddTorqueSensor(builder: DiagramBuilder, n: int, effects: list[JointEffect], time_step: float = 1e-3,
                    session_time_s: float = 0.0, name: str = "torque_sensor") -> TorqueSensorSystem:
    """Add a :class:`TorqueSensorSystem` and Drake's C++ ``RandomSource`` (Gaussian, one draw per ``time_step``)
    feeding its ``noise`` port (seed: ``diagram.SetRandomContext(context, RandomGenerator(seed))``)."""
    sensor = builder.AddSystem(TorqueSensorSystem(n, effects, time_step, session_time_s))
    sensor.set_name(name)
    source = builder.AddSystem(RandomSource(RandomDistribution.kGaussian, n, time_step))
    source.set_name(f"{name}_noise")
    builder.Connect(source.get_output_port(0), sensor.GetInputPort("noise"))
    return sensor


def AddEncoder(builder: DiagramBuilder, n: int, encoder: EncoderNoise | None, time_step: float = 1e-3,
               name: str = "encoder") -> Diagram:
    """Add the joint position encoder: a Diagram of Drake C++ systems computing
    :meth:`~proprio.effects.EncoderNoise.reading` (``x = q + std·z``, ``x − wrap(x)`` into ``[−res/2, res/2)``) with
    ``z`` from a Gaussian ``RandomSource`` (one draw per ``time_step``); ideal (``q``) without an encoder effect.
    Input port ``link_state`` [2n] = [q; q̇]; output port ``q_measured`` [n] rad."""
    std = np.zeros(n) if encoder is None else encoder.std
    res = np.zeros(n) if encoder is None else encoder.resolution
    sub = DiagramBuilder()
    split = sub.AddSystem(Demultiplexer([n, n]))
    source = sub.AddSystem(RandomSource(RandomDistribution.kGaussian, n, time_step))
    source.set_name("noise")
    scale = sub.AddSystem(Gain(std))
    noisy = sub.AddSystem(Adder(2, n))
    sub.Connect(source.get_output_port(0), scale.get_input_port())
    sub.Connect(split.get_output_port(0), noisy.get_input_port(0))
    sub.Connect(scale.get_output_port(), noisy.get_input_port(1))
    wrap = sub.AddSystem(WrapToSystem(n))
    for j in np.flatnonzero(res > 0):
        wrap.set_interval(int(j), -0.5 * float(res[j]), 0.5 * float(res[j]))
    drop = sub.AddSystem(MatrixGain(-np.diag((res > 0).astype(float))))      # − wrap(x) where quantised
    quantised = sub.AddSystem(Adder(2, n))
    sub.Connect(noisy.get_output_port(), wrap.get_input_port())
    sub.Connect(wrap.get_output_port(), drop.get_input_port())
    sub.Connect(noisy.get_output_port(), quantised.get_input_port(0))
    sub.Connect(drop.get_output_port(), quantised.get_input_port(1))
    sub.ExportInput(split.get_input_port(), "link_state")
    sub.ExportOutput(quantised.get_output_port(), "q_measured")
    encoder_system = builder.AddSystem(sub.Build())
    encoder_system.set_name(name)
    return encoder_system
