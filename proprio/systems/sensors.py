"""Sensor models of the twin: the link-side joint torque sensor and the joint position encoder.

Each model is the effect library's laws (:mod:`proprio.effects`), in two forms that call the same code:

* :class:`TorqueSensor` — the batch form over a whole motion ``[N, n]`` (the diagnosis' model
  :meth:`proprio.diagnosis.data.SimModel.predict_parts`, the offline gap benchmark);
* :class:`TorqueSensorSystem` and the encoder Diagram of :func:`AddEncoder` —
  the Drake Systems of the twin's Diagram (``proprio.diagrams.twin``). The torque sensor keeps the scan state of
  the reversal-dependent effects (hysteresis, lost motion: :meth:`~proprio.effects.Hysteresis.scan`) as discrete
  state and takes the time steps in blocks (:func:`AddSampleBank`: a C++ shift register collects them, one Python
  update per block instead of per step), evaluating the memoryless effects (ripple, offset/gain, drift, plugins) by their
  ``torque`` on the block; the white noise comes from Drake's C++ ``RandomSource`` (seeded with the Diagram's random
  context) through :meth:`~proprio.effects.TorqueNoise.from_normal`. The encoder is
  :meth:`~proprio.effects.EncoderNoise.reading` in Drake's C++ primitives (``RandomSource``, ``Gain``, ``Adder``,
  ``WrapToSystem``). Tests: the System's output equals the batch form on the same inputs to 1e-12 N·m.

Torque sensor chain (thesis §2.1): ``τ_meas = (1 + g)·(τ_J + τ_hyst + τ_lost + τ_ripple) + o + o_d(t) + noise``,
i.e. the strain-gauge effects act on the transmitted τ_J, the gain/offset error on everything the gauge sees, a
drifting offset ``o_d`` (``offset_drift``, on the session clock ``MotionSignals.t``) adds to it, and white noise is
added last. Sensor-side plugins (:mod:`proprio.effects.plugins`) act with the strain-gauge effects, after the
library's, on the transmitted τ_J (``s.tau``); in the twin they are evaluated block by block (a sensor-side plugin
is a function of each sample's t, q, q̇, q̈, τ_J, not of the samples before it). Every contribution is returned separately (the
twin's ``tau_<effect>`` truth channels).
"""
from __future__ import annotations

from typing import Callable

import numpy as np
import scipy.sparse
from pydrake.common import RandomDistribution
from pydrake.systems.framework import Context, Diagram, DiagramBuilder, DiscreteValues, LeafSystem, OutputPort
from pydrake.systems.primitives import (Adder, Demultiplexer, Gain, MatrixGain, Multiplexer, RandomSource,
                                        SparseMatrixGain, WrapToSystem, ZeroOrderHold)

from proprio.effects import EncoderNoise, JointEffect, OffsetDrift, SensorOffsetGain, TorqueNoise
from proprio.signals import MotionSignals

__all__ = ["TorqueSensor", "TorqueSensorSystem", "AddEncoder", "AddSampleBank", "block_update_offset",
           "block_times"]

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


def AddSampleBank(builder: DiagramBuilder, ports: list[OutputPort], block_steps: int, time_step: float,
                  name: str = "sample_bank") -> tuple[OutputPort, int]:
    """Add a shift register of C++ systems that keeps the last ``block_steps`` samples of ``ports``: a
    ``ZeroOrderHold`` (period ``time_step``, offset 0: it samples at the discrete plant's own instants, seeing what
    the plant sees) of ``[B·m]`` fed with ``[its own rows 2 … B; the new sample]`` by a ``SparseMatrixGain``. Between
    the time steps ``k`` and ``k + 1`` its output holds the samples of steps ``k − B + 1 … k``, oldest first (each
    ``[m]`` = the ports concatenated). A block System (:func:`block_update_offset`) reads it once per B steps.
    Returns ``(output port, m)``."""
    m = sum(port.size() for port in ports)
    size = block_steps * m
    sample = builder.AddSystem(Multiplexer([port.size() for port in ports]))
    sample.set_name(f"{name}_sample")
    for k, port in enumerate(ports):
        builder.Connect(port, sample.get_input_port(k))
    cat = builder.AddSystem(Multiplexer([size, m]))
    shift = builder.AddSystem(SparseMatrixGain(scipy.sparse.eye(size, size + m, k=m, format="csc")))
    hold = builder.AddSystem(ZeroOrderHold(time_step, size))
    hold.set_name(name)
    builder.Connect(hold.get_output_port(), cat.get_input_port(0))
    builder.Connect(sample.get_output_port(), cat.get_input_port(1))
    builder.Connect(cat.get_output_port(), shift.get_input_port())
    builder.Connect(shift.get_output_port(), hold.get_input_port())
    return hold.get_output_port(), m


def block_update_offset(block_steps: int, time_step: float, start_time: float = 0.0) -> float:
    """Offset [s] of the periodic update (period ``block_steps·time_step``) of a System reading an
    :func:`AddSampleBank`: half a step after each block's last step (between the plant's instants, so it never
    ties with them)."""
    return start_time + (block_steps - 0.5) * time_step


def block_times(context_time: float, block_steps: int, time_step: float, start_time: float = 0.0
                ) -> tuple[np.ndarray, np.ndarray]:
    """``(step indices, times [s])`` of the block a System reading an :func:`AddSampleBank` sees at
    ``context_time``."""
    last = int(round((context_time - start_time) / time_step - 0.5))
    steps = last - block_steps + 1 + np.arange(block_steps)
    return steps, start_time + steps * time_step


class TorqueSensorSystem(LeafSystem):
    """The twin's joint torque sensor for ``n`` joints: every sensor-side effect of ``effects`` (not the encoder's),
    on blocks of ``block_steps`` time steps of ``time_step`` [s] from ``start_time`` [s] (module docstring).

    Input port ``samples`` [B·5n] (or [B·w] with ``row = (w, offset)``: its part starts at ``offset`` of each time
    step's row of ``w``): per time step ``[a; q; q̇; q̈; z]`` — ``a`` the transmitted torque τ_J [N·m] (or,
    with ``transmission``, what ``transmission(a, t, q, q̇, q̈)`` turns into τ_J, e.g. the plant's net actuation and
    :meth:`proprio.systems.joint_drive.JointDrive.sensed_torque`), link q [rad], q̇ [rad/s], q̈ [rad/s²], ``z``
    standard-normal draws for the noise — as :func:`AddSampleBank` hands them over. Output port ``record``
    [B·(2 + k)·n], per time step ``[τ_meas; τ_J; the contribution of each of the k effects in :attr:`names` order]``
    N·m, for the block the last update took in. Discrete state: the scan state of the reversal-dependent effects
    (:meth:`~proprio.effects.Hysteresis.scan`), started at rest at the first sample. The effects see the session clock
    ``t + session_time_s`` [s].
    """

    def __init__(self, n: int, effects: list[JointEffect], time_step: float = 1e-3, block_steps: int = 1,
                 session_time_s: float = 0.0, start_time: float = 0.0,
                 transmission: Callable[..., np.ndarray] | None = None, row: tuple[int, int] | None = None):
        super().__init__()
        sensor = TorqueSensor([e for e in effects if e.place == "sensor" and not isinstance(e, EncoderNoise)])
        self.n, self.sensor, self.block_steps = n, sensor, int(block_steps)
        self.time_step, self.session_time_s, self.start_time = float(time_step), float(session_time_s), start_time
        self.transmission = transmission
        self.names = [e.name for e in sensor.effects]
        self._stateful = [hasattr(e, "scan") for e in sensor.gauge]
        sizes = [e.state_size * n if st else 0 for e, st in zip(sensor.gauge, self._stateful)]
        self._slices = [slice(int(a), int(a + b)) for a, b in zip(np.cumsum([0] + sizes[:-1]), sizes)]
        self._row = row or (5 * n, 0)                                  # (width of a time step's row, offset)
        self._samples = self.DeclareVectorInputPort("samples", self.block_steps * self._row[0])
        self._state = self.DeclareDiscreteState(sum(sizes) + 1)          # + started flag
        self._record = self.DeclareDiscreteState(self.block_steps * (2 + len(self.names)) * n)
        self.DeclarePeriodicDiscreteUpdateEvent(self.block_steps * self.time_step,
                                                block_update_offset(self.block_steps, self.time_step, start_time),
                                                self._update)
        self.DeclareStateOutputPort("record", self._record)

    def measure_block(self, x: np.ndarray, s: MotionSignals, tau_j: np.ndarray, z: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
        """One block: from state ``x`` (empty or started) and samples ``s`` ``[B, n]`` with τ_J and noise draws
        ``z``, return ``(state after, τ_meas [B, n], contributions)``; the same laws, in the same order, as
        :meth:`TorqueSensor.measure`."""
        x = x.copy()
        if x[-1] == 0:                                               # first block: start at rest at sample 0
            for eff, st, sl in zip(self.sensor.gauge, self._stateful, self._slices):
                if st:
                    x[sl] = eff.initial_state(s.q[0], s.qd[0], tau_j[0])
            x[-1] = 1.0
        s = s.with_tau(tau_j)
        sensor, parts = self.sensor, []
        seen = tau_j.copy()
        for eff, st, sl in zip(sensor.gauge, self._stateful, self._slices):
            if st:
                x[sl], c = eff.scan(x[sl], s.q, s.qd, tau_j)
            else:
                c = eff.torque(s)
            parts.append(c)
            seen = seen + c
        if sensor.offset_gain is not None:
            parts.append(sensor.offset_gain.torque(s.with_tau(seen)))
            seen = seen + parts[-1]
        if sensor.drift is not None:
            parts.append(sensor.drift.torque(s))
            seen = seen + parts[-1]
        if sensor.noise is not None:
            parts.append(sensor.noise.from_normal(z))
            seen = seen + parts[-1]
        return x, seen, parts

    def _update(self, context: Context, discrete_state: DiscreteValues) -> None:
        n, b = self.n, self.block_steps
        width, first = self._row
        blk = self._samples.Eval(context).reshape(b, width)[:, first:first + 5 * n]
        a, q, qd, qdd, z = (blk[:, k * n:(k + 1) * n] for k in range(5))
        _, t = block_times(context.get_time(), b, self.time_step, self.start_time)
        tau_j = a if self.transmission is None else self.transmission(a, t, q, qd, qdd)
        s = MotionSignals(t + self.session_time_s, q, qd, qdd)
        x, seen, parts = self.measure_block(context.get_discrete_state(self._state).value(), s, tau_j, z)
        discrete_state.set_value(self._state, x)
        discrete_state.set_value(self._record, np.hstack([seen, tau_j, *parts]).ravel())


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
